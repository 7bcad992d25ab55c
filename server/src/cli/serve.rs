//! `lumigraph serve`: the HTTP/WebSocket render service on a tokio runtime.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

/// `lumigraph serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Folder of `.lfa` assets (created if missing; the demo is baked into it when empty).
    #[arg(long, default_value = "assets")]
    pub assets: PathBuf,
    /// Address to listen on (without LUMIGRAPH_TOKEN only loopback addresses are allowed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: std::net::SocketAddr,
    /// Most concurrent WebSocket sessions.
    #[arg(long, default_value_t = 64)]
    pub max_sessions: usize,
    /// Largest rendered width or height in pixels.
    #[arg(long, default_value_t = 4096)]
    pub max_px: u32,
    /// Most connections one client address holds at once; more are answered 429.
    #[arg(long, default_value_t = 128, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_connections_per_client: u32,
    /// Seconds a client has to send a request's headers; a slower one is disconnected.
    #[arg(long, default_value = "10", value_parser = parse_seconds)]
    pub header_timeout_secs: std::time::Duration,
    /// Longest pause in seconds between two pieces of a request body (uploads included), and
    /// the time to send a whole render body; past either the request fails with 408.
    #[arg(long, default_value = "30", value_parser = parse_seconds)]
    pub body_timeout_secs: std::time::Duration,
    /// Seconds a stream session may go without a client message before it is closed (1008).
    #[arg(long, default_value = "300", value_parser = parse_seconds)]
    pub stream_idle_secs: std::time::Duration,
}

/// A positive, finite number of seconds, at most a day.
fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 86_400.0 => {
            Ok(std::time::Duration::from_secs_f64(v))
        }
        _ => Err(format!("`{s}` is not a number of seconds in (0, 86400]")),
    }
}

pub(super) fn serve(args: &ServeArgs) -> Result<()> {
    let mut config = crate::service::ServeConfig::from_env(&args.assets, args.addr);
    config.max_sessions = args.max_sessions;
    config.max_px = args.max_px;
    config.max_connections_per_client = args.max_connections_per_client as usize;
    config.header_timeout = args.header_timeout_secs;
    config.body_idle_timeout = args.body_timeout_secs;
    config.body_deadline = args.body_timeout_secs;
    config.stream_idle_timeout = args.stream_idle_secs;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(crate::service::serve(config))
}
