//! `lumigraph healthcheck`: asks a running service's `/readyz` whether it is ready, for
//! container `HEALTHCHECK`s and probes that have no HTTP client of their own. Exit status 0 when
//! the answer is 200, else an `error: …` line naming the status and the service's reason.

use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use http_body_util::{BodyExt, Empty};
use hyper::body::Bytes;
use hyper_util::rt::TokioIo;

/// `lumigraph healthcheck`.
#[derive(Debug, Args)]
pub struct HealthcheckArgs {
    /// Address the service listens on (as given to `lumigraph serve --addr`).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: SocketAddr,
    /// Seconds to wait for the whole answer (connecting included).
    #[arg(long, default_value = "5", value_parser = super::serve::parse_seconds)]
    pub timeout_secs: Duration,
}

/// Longest `/readyz` body read, bytes (its JSON is far shorter).
const MAX_BODY: usize = 64 << 10;

pub(super) fn healthcheck(args: &HealthcheckArgs) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let (status, body) = runtime.block_on(async {
        tokio::time::timeout(args.timeout_secs, readyz(args.addr))
            .await
            .map_err(|_| {
                anyhow::anyhow!(
                    "no answer from http://{}/readyz within {:.1} s",
                    args.addr,
                    args.timeout_secs.as_secs_f64()
                )
            })?
    })?;
    let text = String::from_utf8_lossy(&body);
    if status != hyper::StatusCode::OK {
        // The service's error body says why (`{"error": {"kind", "message"}}`).
        let why = serde_json::from_slice::<serde_json::Value>(&body)
            .ok()
            .and_then(|v| v["error"]["message"].as_str().map(str::to_owned))
            .unwrap_or_else(|| text.trim().to_owned());
        bail!("http://{}/readyz answered {status}: {why}", args.addr);
    }
    println!("ready: {}", text.trim());
    Ok(())
}

async fn readyz(addr: SocketAddr) -> Result<(hyper::StatusCode, Vec<u8>)> {
    let stream = tokio::net::TcpStream::connect(addr)
        .await
        .with_context(|| format!("cannot connect to {addr} (is `lumigraph serve` running?)"))?;
    let (mut sender, connection) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
        .await
        .context("HTTP handshake")?;
    tokio::spawn(connection);
    let request = hyper::Request::get("/readyz")
        .header(hyper::header::HOST, addr.to_string())
        .body(Empty::<Bytes>::new())
        .context("building the request")?;
    let response = sender
        .send_request(request)
        .await
        .context("sending GET /readyz")?;
    let status = response.status();
    let mut body = Vec::new();
    let mut incoming = response.into_body();
    while let Some(frame) = incoming.frame().await {
        if let Ok(data) = frame.context("reading the answer")?.into_data() {
            body.extend_from_slice(&data);
            if body.len() > MAX_BODY {
                bail!("the /readyz answer is longer than {MAX_BODY} bytes");
            }
        }
    }
    Ok((status, body))
}
