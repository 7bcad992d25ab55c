//! `lumigraph_server`: the `lumigraph` binary's library half — the CLI commands and the render
//! service (axum/tokio) built on `lumigraph_core`.

pub mod cli;
pub mod service;
