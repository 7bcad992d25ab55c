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
}

pub(super) fn serve(args: &ServeArgs) -> Result<()> {
    let mut config = crate::service::ServeConfig::from_env(&args.assets, args.addr);
    config.max_sessions = args.max_sessions;
    config.max_px = args.max_px;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(crate::service::serve(config))
}
