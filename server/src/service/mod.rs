//! The render service (DESIGN §7): HTTP API, WebSocket frame streaming and the web viewer.
//!
//! - [`ServeConfig`] → [`serve`] binds, loads the assets folder (baking the demo scene when it
//!   holds no asset) and serves [`app`] until Ctrl-C or SIGTERM.
//! - [`AppState`] (cheap to clone) holds the [`assets::AssetStore`] (each asset uploaded to the
//!   GPU once), the [`render_pool::RenderPool`] (a bounded set of blocking render threads
//!   shared by every request and session), bake [`jobs`] (kept across restarts by the
//!   [`journal`]) and the Prometheus [`metrics`].
//! - [`http`] has the `/v1` handlers, [`stream`] the `/v1/stream` sessions (protocol in
//!   `docs/protocol.md`), [`viewer`] the page at `/`.

pub mod assets;
pub mod budget;
pub mod codecs;
pub mod content_store;
pub mod error;
pub mod http;
pub mod jobs;
pub mod journal;
pub mod listen;
pub mod metrics;
pub mod openapi;
pub mod render_pool;
pub mod render_query;
pub mod state;
pub mod stream;
pub mod viewer;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context as _;
use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::http::StatusCode;
use axum::routing::{get, post};
use lumigraph_core::gpu::Gpu;
use tokio::net::TcpListener;
use tower_http::timeout::{RequestBodyTimeoutLayer, TimeoutLayer};
use tower_http::trace::TraceLayer;

pub use state::{AppState, ServeConfig};

/// The router: every route with its layers (tracing outermost, then timeout, body limits and a
/// global concurrency limit).
pub fn app(state: AppState) -> Router {
    let config = state.config();
    let json_limit = config.max_json_bytes;
    let mesh_limit = usize::try_from(config.max_mesh_bytes).unwrap_or(usize::MAX);
    let timeout = config.request_timeout;
    Router::new()
        .route("/", get(viewer::index))
        .route("/viewer.js", get(viewer::script))
        .route("/reproject.js", get(viewer::reproject_script))
        .route("/healthz", get(http::healthz))
        .route("/readyz", get(http::readyz))
        .route("/metrics", get(http::metrics))
        .route("/openapi.json", get(openapi::openapi_json))
        .route(
            "/v1/assets",
            get(http::list_assets).post(http::upload_asset),
        )
        .route(
            "/v1/assets/{id}",
            get(http::get_asset).delete(http::delete_asset),
        )
        .route(
            "/v1/assets/{id}/render",
            post(http::render_asset)
                .layer(axum::middleware::from_fn_with_state(
                    state.clone(),
                    read_body_within_deadline,
                ))
                .get(http::render_link),
        )
        .route(
            "/v1/bake",
            post(http::bake).layer(DefaultBodyLimit::max(mesh_limit)),
        )
        .route("/v1/jobs/{id}", get(http::get_job))
        .route("/v1/stream", get(stream::stream))
        .fallback(http::not_found)
        .method_not_allowed_fallback(http::method_not_allowed)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            http::count_errors,
        ))
        .layer(DefaultBodyLimit::max(json_limit))
        .layer(RequestBodyTimeoutLayer::new(config.body_idle_timeout))
        .layer(tower::limit::ConcurrencyLimitLayer::new(1024))
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            timeout,
        ))
        .layer(TraceLayer::new_for_http())
        .with_state(state)
}

/// Reads a small (JSON) body whole within [`ServeConfig::body_deadline`] before the handler
/// runs: a client that trickles its body cannot hold a request slot for longer than that.
/// 408 past the deadline, 413 past the JSON size limit.
async fn read_body_within_deadline(
    axum::extract::State(state): axum::extract::State<AppState>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::response::IntoResponse as _;
    let config = state.config();
    let (parts, body) = request.into_parts();
    let read =
        http_body_util::BodyExt::collect(http_body_util::Limited::new(body, config.max_json_bytes));
    match tokio::time::timeout(config.body_deadline, read).await {
        Ok(Ok(collected)) => {
            let body = axum::body::Body::from(collected.to_bytes());
            next.run(axum::extract::Request::from_parts(parts, body))
                .await
        }
        Ok(Err(err)) => {
            let too_large = err.is::<http_body_util::LengthLimitError>();
            if too_large {
                error::AppError::TooLarge {
                    limit: config.max_json_bytes as u64,
                }
                .into_response()
            } else {
                error::AppError::Rejected {
                    status: StatusCode::REQUEST_TIMEOUT,
                    message: format!("reading the request body failed: {err}"),
                }
                .into_response()
            }
        }
        Err(_) => error::AppError::Rejected {
            status: StatusCode::REQUEST_TIMEOUT,
            message: format!(
                "the request body did not arrive within {} s",
                config.body_deadline.as_secs_f64()
            ),
        }
        .into_response(),
    }
}

/// How long in-flight HTTP requests may run on after a shutdown signal.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(8);

/// Serves `state` on `listener` until `shutdown` resolves, then lets in-flight HTTP requests
/// finish (at most `SHUTDOWN_GRACE`) and stream sessions finish their frame and close (at most
/// 10 s).
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let router = app(state.clone());
    let on_shutdown = state.clone();
    let shutdown_started = Arc::new(tokio::sync::Notify::new());
    let started = Arc::clone(&shutdown_started);
    let config = state.config();
    let limits = listen::ConnectionLimits {
        header_timeout: config.header_timeout,
        max_per_client: config.max_connections_per_client,
    };
    let server = listen::serve(listener, router, limits, async move {
        shutdown.await;
        tracing::info!("shutting down: finishing in-flight frames");
        on_shutdown.begin_shutdown();
        started.notify_one();
    });
    // In-flight HTTP requests get a bounded grace period: a client stalled mid-upload must not
    // keep SIGTERM from ending the process until the request timeout.
    let deadline = async move {
        shutdown_started.notified().await;
        tokio::time::sleep(SHUTDOWN_GRACE).await;
    };
    tokio::select! {
        () = server => {}
        () = deadline => tracing::warn!(
            "HTTP requests still open {} s after shutdown began: closing them",
            SHUTDOWN_GRACE.as_secs()
        ),
    }
    let all = u32::try_from(state.config().max_sessions).unwrap_or(u32::MAX);
    let sessions = Arc::clone(&state.inner.sessions);
    if tokio::time::timeout(Duration::from_secs(10), sessions.acquire_many(all))
        .await
        .is_err()
    {
        tracing::warn!("stream sessions did not close within 10 s");
    }
    Ok(())
}

/// `lumigraph serve`: opens the device, binds `config.addr`, loads (or bakes) the assets in
/// the background (`/readyz` turns 200 when done) and serves until Ctrl-C or SIGTERM.
pub async fn serve(config: ServeConfig) -> anyhow::Result<()> {
    if config.token.is_none() && !config.addr.ip().is_loopback() {
        anyhow::bail!(
            "refusing to listen on {} without a token: set LUMIGRAPH_TOKEN to serve beyond this \
             machine, or use a loopback address such as 127.0.0.1",
            config.addr
        );
    }
    std::fs::create_dir_all(&config.assets_dir)
        .with_context(|| format!("creating the assets folder {}", config.assets_dir.display()))?;
    if let Some(url) = &config.store {
        let cache = config.assets_dir.join(state::STORE_CACHE_DIR);
        if let Err(err) = content_store::ContentStore::open(url, cache, config.store_cache_bytes) {
            return serve_unready(config.addr, err.to_string()).await;
        }
    }
    let gpu = match tokio::task::spawn_blocking(Gpu::shared).await? {
        Ok(gpu) => gpu,
        // Alive but never ready, with the reason in the log and in /readyz: an orchestrator
        // keeps the replica out of rotation and shows why, instead of a crash loop.
        Err(err) => return serve_unready(config.addr, format!("cannot open the GPU: {err}")).await,
    };
    tracing::info!(adapter = gpu.adapter_summary(), "device ready");
    let addr = config.addr;
    let state = tokio::task::spawn_blocking(move || AppState::new(config, gpu)).await??;
    let listener = TcpListener::bind(addr)
        .await
        .with_context(|| format!("binding {addr}"))?;
    let local = listener.local_addr()?;
    tracing::info!("lumigraph serving on http://{local}/ (viewer), API at http://{local}/v1");
    let loader = state.clone();
    tokio::spawn(async move {
        if let Err(err) = loader.load_assets().await {
            tracing::error!(
                error = format!("{err:#}"),
                "loading assets failed; /readyz stays 503"
            );
        }
    });
    run(listener, state, shutdown_signal()).await
}

/// Serves `/healthz` (200) and, for every other path, `/readyz` included, 503 with `reason`,
/// until Ctrl-C or SIGTERM: what `serve` does when it cannot start (no usable GPU adapter, e.g.
/// `LUMIGRAPH_ADAPTER=gpu` on a machine with only a software rasterizer).
async fn serve_unready(addr: std::net::SocketAddr, reason: String) -> anyhow::Result<()> {
    tracing::error!(reason = %reason, "not ready: /readyz answers 503 until restarted with a working configuration");
    let listener = TcpListener::bind(addr)
        .await
        .with_context(|| format!("binding {addr}"))?;
    let reason = Arc::new(reason);
    let app = Router::new()
        .route("/healthz", get(http::healthz))
        .fallback(move || {
            let reason = reason.clone();
            async move { error::AppError::Unavailable(format!("not ready: {reason}")) }
        });
    axum::serve(listener, app)
        .with_graceful_shutdown(shutdown_signal())
        .await
        .context("serving")
}

/// Resolves on Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if let Err(err) = tokio::signal::ctrl_c().await {
            tracing::warn!(%err, "cannot listen for Ctrl-C");
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut signal) => {
                signal.recv().await;
            }
            Err(err) => {
                tracing::warn!(%err, "cannot listen for SIGTERM");
                std::future::pending::<()>().await;
            }
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = terminate => {},
    }
}
