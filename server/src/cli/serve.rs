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
    /// Most GPU memory the loaded assets may take together (host memory on a software
    /// adapter), in bytes or with a K, M, G or T suffix (powers of 1024); uploads and bakes
    /// beyond it are refused with 413. At most the memory budget. Default: two thirds of the
    /// memory budget. On a discrete GPU set it at most to the GPU's memory.
    #[arg(long, value_parser = parse_bytes)]
    pub asset_memory_budget: Option<u64>,
    /// Most bytes the whole server may hold in loaded assets, frames in flight and their encode
    /// buffers, same units; a render beyond it waits up to 2 s, then gets 503 with
    /// `Retry-After`. Default: three quarters of the machine's memory (or of the container's
    /// cgroup limit).
    #[arg(long, value_parser = parse_bytes)]
    pub memory_budget: Option<u64>,
    /// Seconds requests may wait for a render with no render completing before `/readyz`
    /// reports the render path as stuck (503).
    #[arg(long, default_value = "60", value_parser = parse_seconds)]
    pub render_stall_secs: std::time::Duration,
    /// Most bytes one asset may decode to (every image of every layer and state, read from its
    /// header before anything is decoded), same units. Default: the memory budget.
    #[arg(long, value_parser = parse_bytes)]
    pub max_asset_decoded_bytes: Option<u64>,
    /// The content-addressed asset store replicas share: `file:///ABS/PATH` or
    /// `s3://BUCKET[/PREFIX]` (credentials, region and endpoint from AWS_ACCESS_KEY_ID,
    /// AWS_SECRET_ACCESS_KEY, AWS_REGION, AWS_ENDPOINT_URL). Uploads and bakes are published to
    /// it, assets it names are fetched (and verified) on start and on first use. Default:
    /// LUMIGRAPH_STORE, else none (the assets folder alone).
    #[arg(long)]
    pub store: Option<String>,
    /// Most bytes this replica's cache of the store keeps (in ASSETS/.store-cache), same units;
    /// the least recently used files no loaded asset holds are evicted first.
    #[arg(long, default_value = "8G", value_parser = parse_bytes)]
    pub store_cache_bytes: u64,
    /// Render each two-plane light field whose resident textures exceed M MiB through a paged
    /// cache of M MiB of device memory (its slots and coarse level; docs/two_plane.md "Paged
    /// rendering"): the asset is charged M MiB instead of its whole size.
    #[arg(long, value_name = "M")]
    pub cache_mib: Option<f64>,
    /// The page cache's policy: none (on demand), lru, or predict (prefetch by dead reckoning
    /// over the frames each cache rendered).
    #[arg(long, default_value = "lru", requires = "cache_mib")]
    pub prefetch: lumigraph_core::page_cache::Prefetch,
    /// Most pages a frame loads into the page cache.
    #[arg(long, value_name = "B", default_value_t = lumigraph_core::page_cache::DEFAULT_PAGES_PER_FRAME, value_parser = clap::value_parser!(u32).range(1..), requires = "cache_mib")]
    pub pages_per_frame: u32,
}

/// A positive, finite number of seconds, at most a day.
pub(super) fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 86_400.0 => {
            Ok(std::time::Duration::from_secs_f64(v))
        }
        _ => Err(format!("`{s}` is not a number of seconds in (0, 86400]")),
    }
}

/// A byte count: digits with an optional K, M, G or T suffix (powers of 1024; `KiB`, `KB`
/// and `k` are read the same).
fn parse_bytes(text: &str) -> Result<u64, String> {
    let text = text.trim();
    let digits = text
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(text.len());
    let (number, suffix) = text.split_at(digits);
    let number: u64 = number
        .parse()
        .map_err(|_| format!("{text:?} is not a byte count such as 8G or 1073741824"))?;
    let shift = match suffix
        .trim()
        .trim_end_matches(['B', 'b'])
        .trim_end_matches('i')
        .to_ascii_uppercase()
        .as_str()
    {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => return Err(format!("{text:?}: the unit must be K, M, G or T")),
    };
    number
        .checked_mul(1 << shift)
        .ok_or_else(|| format!("{text:?} is too large"))
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
    if let Some(budget) = args.memory_budget {
        config.memory_budget = budget;
    }
    // The asset budget defaults to two thirds of the server's (half the machine's memory when
    // neither is given).
    config.asset_memory_budget = args
        .asset_memory_budget
        .unwrap_or(config.memory_budget / 3 * 2);
    config.render_stall_timeout = args.render_stall_secs;
    if let Some(store) = &args.store {
        config.store = Some(store.clone());
    }
    config.store_cache_bytes = args.store_cache_bytes;
    config.max_asset_decoded_bytes = args
        .max_asset_decoded_bytes
        .unwrap_or(config.asset_memory_budget);
    if let Some(mib) = args.cache_mib {
        anyhow::ensure!(
            mib.is_finite() && mib > 0.0,
            "--cache-mib {mib}: give a positive number of MiB"
        );
        config.page_cache = Some(lumigraph_core::page_cache::CacheConfig::with_mib(
            mib,
            args.prefetch,
            args.pages_per_frame,
        ));
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(crate::service::serve(config))
}

#[cfg(test)]
mod tests {
    use super::parse_bytes;

    #[test]
    fn byte_counts() {
        assert_eq!(parse_bytes("1073741824"), Ok(1 << 30));
        assert_eq!(parse_bytes("8G"), Ok(8 << 30));
        assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
        assert_eq!(parse_bytes("3k"), Ok(3 << 10));
        assert_eq!(parse_bytes("2 TB"), Ok(2 << 40));
        for bad in [
            "",
            "G",
            "1.5G",
            "-1",
            "4X",
            "99999999999999999999",
            "20000000T",
        ] {
            assert!(parse_bytes(bad).is_err(), "{bad:?}");
        }
    }
}
