//! The service's shared state: its configuration, the GPU pipelines, the asset store, the render
//! pool, bake jobs and metrics, behind one cheaply cloned [`AppState`].

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use anyhow::Context as _;
use axum::http::{HeaderMap, header};
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::gpu::Gpu;
use tokio::sync::{Semaphore, mpsc, watch};

use super::assets::{self, AssetLimits, AssetStore, LoadError, LoadedAsset, Reservation};
use super::budget::MemoryBudget;
use super::content_store::{ContentStore, StoreError};
use super::error::AppError;
use super::jobs::{self, BakeWork, Job, Jobs, MAX_JOBS};
use super::journal::{JobSpec, Journal, Recovery};
use super::metrics::Metrics;
use super::render_pool::{Engine, RenderPool};

/// Settings of `lumigraph serve`.
#[derive(Clone, Debug)]
pub struct ServeConfig {
    /// Folder of `.lfa` assets (created if missing); uploads and bakes are written here.
    pub assets_dir: PathBuf,
    /// Address to listen on. Without a token only loopback addresses are accepted.
    pub addr: SocketAddr,
    /// Bearer token required for uploads, bakes and deletes; `None` = no auth, loopback only.
    pub token: Option<String>,
    /// Most concurrent WebSocket sessions; more get 503.
    pub max_sessions: usize,
    /// Largest width or height of a rendered view.
    pub max_px: u32,
    /// Renders running on the device at once.
    pub render_workers: usize,
    /// HTTP renders allowed to wait for a worker; more get 503.
    pub max_queued_renders: usize,
    /// Largest `.lfa` upload in bytes.
    pub max_upload_bytes: u64,
    /// Largest mesh upload (the whole multipart body) in bytes.
    pub max_mesh_bytes: u64,
    /// Largest JSON body in bytes.
    pub max_json_bytes: usize,
    /// Most bytes one asset may decode to (every image of every layer and state, from its
    /// header); larger uploads get 413 and larger files in the folder are skipped.
    pub max_asset_decoded_bytes: u64,
    /// Most texture memory, in bytes, the loaded assets may take together (GPU memory; host
    /// memory on a software adapter); an upload or bake beyond it gets 413 or fails.
    pub asset_memory_budget: u64,
    /// Most bytes the whole server may hold in the accounted uses: loaded assets' textures,
    /// frames in flight and their encode buffers. A render that would exceed it waits up to
    /// `memory_wait`, then gets 503 with `Retry-After`; must be at least
    /// `asset_memory_budget`.
    pub memory_budget: u64,
    /// Longest wait for the memory budget before a request is refused with 503.
    pub memory_wait: Duration,
    /// Readiness fails when requests have waited for a render this long without any render
    /// completing (a stuck render path).
    pub render_stall_timeout: Duration,
    /// Per-request timeout (uploads included).
    pub request_timeout: Duration,
    /// Longest wait for a request's headers (from the connection's start or its previous
    /// response); a slower client is disconnected.
    pub header_timeout: Duration,
    /// Longest pause between two pieces of a request body (uploads included); past it the
    /// request fails with 408.
    pub body_idle_timeout: Duration,
    /// Longest time to receive a whole JSON render body; past it the request fails with 408.
    pub body_deadline: Duration,
    /// Most connections one client address holds at once; more get 429.
    pub max_connections_per_client: usize,
    /// A stream session that receives no message for this long is closed (1008).
    pub stream_idle_timeout: Duration,
    /// Default time a stream view must rest before the full-quality frame is sent.
    pub rest_delay: Duration,
    /// Bake the built-in demo scene into `demo.lfa` when the folder holds no asset.
    pub bake_demo_if_empty: bool,
    /// Options of that demo bake.
    pub demo_bake: BakeOptions,
    /// The content-addressed store replicas share (`file:///path` or `s3://bucket[/prefix]`),
    /// or `None` for the assets folder alone.
    pub store: Option<String>,
    /// Most bytes this replica's cache of the store keeps (`ASSETS/.store-cache`).
    pub store_cache_bytes: u64,
    /// The page cache of each two-plane light field whose resident textures exceed its budget
    /// (`--cache-mib`, `--prefetch`, `--pages-per-frame`): such an asset is charged the cache's
    /// bytes and renders through it; `None`: every asset is resident.
    pub page_cache: Option<lumigraph_core::page_cache::CacheConfig>,
}

impl ServeConfig {
    /// Defaults for `assets_dir` and `addr`, no token.
    pub fn new(assets_dir: impl Into<PathBuf>, addr: SocketAddr) -> Self {
        Self {
            assets_dir: assets_dir.into(),
            addr,
            token: None,
            max_sessions: 64,
            max_px: 4096,
            render_workers: 2,
            max_queued_renders: 64,
            max_upload_bytes: 4 << 30,
            max_mesh_bytes: 512 << 20,
            max_json_bytes: 64 << 10,
            max_asset_decoded_bytes: default_asset_memory_budget(),
            asset_memory_budget: default_asset_memory_budget(),
            memory_budget: default_memory_budget(),
            memory_wait: Duration::from_secs(2),
            render_stall_timeout: Duration::from_secs(60),
            request_timeout: Duration::from_secs(600),
            header_timeout: Duration::from_secs(10),
            body_idle_timeout: Duration::from_secs(30),
            body_deadline: Duration::from_secs(30),
            max_connections_per_client: 128,
            stream_idle_timeout: Duration::from_secs(300),
            rest_delay: Duration::from_millis(250),
            bake_demo_if_empty: true,
            demo_bake: BakeOptions::default(),
            store: None,
            store_cache_bytes: 8 << 30,
            page_cache: None,
        }
    }

    /// [`Self::new`] with the token read from `LUMIGRAPH_TOKEN` (unset or empty = none).
    pub fn from_env(assets_dir: impl Into<PathBuf>, addr: SocketAddr) -> Self {
        let mut config = Self::new(assets_dir, addr);
        config.token = std::env::var("LUMIGRAPH_TOKEN")
            .ok()
            .filter(|t| !t.is_empty());
        config.store = std::env::var("LUMIGRAPH_STORE")
            .ok()
            .filter(|t| !t.is_empty());
        config
    }
}

/// The machine's memory as this process may use it: `MemTotal` of `/proc/meminfo`, or the
/// cgroup's `memory.max` (a container's limit) where that is lower; 8 GiB where neither can be
/// read.
pub fn machine_memory_bytes() -> u64 {
    const FALLBACK: u64 = 8 << 30;
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| mem_total_bytes(&text));
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|text| text.trim().parse::<u64>().ok());
    match (total, cgroup) {
        (Some(t), Some(c)) => t.min(c),
        (Some(t), None) => t,
        (None, Some(c)) => c,
        (None, None) => FALLBACK,
    }
}

/// Half of [`machine_memory_bytes`]: the default memory budget of the loaded assets and the
/// default largest decoded asset.
pub fn default_asset_memory_budget() -> u64 {
    machine_memory_bytes() / 2
}

/// Three quarters of [`machine_memory_bytes`]: the default memory budget of the whole server
/// (the rest is left to the process's code, the driver and the system).
pub fn default_memory_budget() -> u64 {
    machine_memory_bytes() / 4 * 3
}

/// `MemTotal` of a `/proc/meminfo` text, in bytes.
fn mem_total_bytes(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut words = line.split_whitespace().skip(1);
    let value: u64 = words.next()?.parse().ok()?;
    match words.next() {
        Some("kB") => value.checked_mul(1024),
        None => Some(value),
        Some(_) => None,
    }
}

/// The folder, inside the assets folder, of this replica's cache of the store.
pub const STORE_CACHE_DIR: &str = ".store-cache";

/// Seconds between two attempts to reach a store that failed at start-up.
const STORE_RETRY: Duration = Duration::from_secs(5);

/// A held store lock of one asset id; the map entry goes when no one else holds or waits for it.
pub(crate) struct StoreIdGuard {
    state: std::sync::Weak<Inner>,
    id: String,
    guard: Option<tokio::sync::OwnedMutexGuard<()>>,
}

impl Drop for StoreIdGuard {
    fn drop(&mut self) {
        drop(self.guard.take());
        if let Some(inner) = self.state.upgrade() {
            let mut locks = inner
                .store_locks
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            // Two references (the map's and the guard's, now released) mean no one waits.
            if locks
                .get(&self.id)
                .is_some_and(|l| Arc::strong_count(l) == 1)
            {
                locks.remove(&self.id);
            }
        }
    }
}

/// Shared state of every handler and session.
#[derive(Clone)]
pub struct AppState {
    pub(super) inner: Arc<Inner>,
}

pub(super) struct Inner {
    pub(super) config: ServeConfig,
    pub(super) adapter: String,
    pub(super) assets: AssetStore,
    pub(super) pool: RenderPool,
    pub(super) budget: Arc<MemoryBudget>,
    /// Reports of lost devices, taken by the recovery task that [`AppState::load_assets`]
    /// starts.
    pub(super) lost_reports: std::sync::Mutex<Option<mpsc::Receiver<u64>>>,
    /// Set while a lost device is being replaced: what `/readyz` says.
    pub(super) recovering: std::sync::Mutex<Option<String>>,
    pub(super) bake_slot: Semaphore,
    pub(super) jobs: Jobs,
    /// The durable side of `jobs`, in the assets folder.
    pub(super) journal: Journal,
    /// Unfinished jobs read back from the journal, run by [`AppState::load_assets`].
    pub(super) resumed: Mutex<Vec<Resumed>>,
    pub(super) metrics: Metrics,
    pub(super) ready: AtomicBool,
    /// The shared content-addressed store, when configured.
    pub(super) store: Option<ContentStore>,
    /// Why the store keeps the service from being ready (unreachable, credentials refused,
    /// a corrupt object): what `/readyz` says while [`AppState::load_assets`] retries.
    pub(super) store_failure: std::sync::Mutex<Option<String>>,
    /// One lock per asset id that is being fetched from, published to or deleted from the
    /// store: concurrent first uses of one asset fetch and load it once, and a delete or an
    /// upload never interleaves with a fetch of the same id. Other ids do not wait.
    pub(super) store_locks:
        std::sync::Mutex<std::collections::HashMap<String, Arc<tokio::sync::Mutex<()>>>>,
    pub(super) sessions: Arc<Semaphore>,
    pub(super) shutdown: watch::Sender<bool>,
}

/// An unfinished job read back from the journal at start-up.
pub(super) struct Resumed {
    job: Arc<Job>,
    spec: JobSpec,
    how: Resume,
}

/// How a resumed job goes on.
enum Resume {
    /// Bake it again, holding the claim on its asset id.
    Bake(Reservation),
    /// Its asset file exists: the bake finished and the server stopped before recording it.
    Written,
    /// Another resumed job writes the same asset (only a damaged journal says so).
    Conflict(String),
}

impl AppState {
    /// Builds the pipelines on `gpu` (blocking: compiles shaders) and reads the job journal of
    /// the assets folder back: finished jobs are reported again, unfinished ones are queued
    /// (and their asset ids claimed) to run once [`Self::load_assets`] has loaded the folder.
    ///
    /// # Errors
    /// The journal folder exists but cannot be listed; creating the pipelines fails.
    pub fn new(config: ServeConfig, gpu: Arc<Gpu>) -> anyhow::Result<Self> {
        let adapter = gpu.adapter_summary();
        let engine = Engine::new(gpu, 0);
        let (lost_tx, lost_rx) = mpsc::channel(1);
        anyhow::ensure!(
            config.asset_memory_budget <= config.memory_budget,
            "the asset memory budget ({}) must not exceed the server's memory budget ({}): \
             lower --asset-memory-budget or raise --memory-budget",
            assets::describe_bytes(config.asset_memory_budget),
            assets::describe_bytes(config.memory_budget),
        );
        let budget = MemoryBudget::new(config.memory_budget);
        let pool = RenderPool::new(
            engine,
            config.render_workers,
            config.max_queued_renders,
            Arc::clone(&budget),
            config.memory_wait,
            lost_tx,
        );
        let (shutdown, _) = watch::channel(false);
        let journal = Journal::new(&config.assets_dir);
        let recovery = journal
            .recover(MAX_JOBS)
            .with_context(|| format!("reading the job journal {}", journal.dir().display()))?;
        let store = config
            .store
            .as_deref()
            .map(|url| {
                ContentStore::open(
                    url,
                    config.assets_dir.join(STORE_CACHE_DIR),
                    config.store_cache_bytes,
                )
            })
            .transpose()?;
        let state = Self {
            inner: Arc::new(Inner {
                store,
                store_failure: std::sync::Mutex::new(None),
                store_locks: std::sync::Mutex::default(),
                assets: AssetStore::new(
                    config.assets_dir.clone(),
                    AssetLimits {
                        max_decoded_bytes: config.max_asset_decoded_bytes,
                        memory_budget: config.asset_memory_budget,
                        page_cache: config.page_cache,
                    },
                    Arc::clone(&budget),
                ),
                budget,
                sessions: Arc::new(Semaphore::new(config.max_sessions)),
                config,
                adapter,
                pool,
                lost_reports: std::sync::Mutex::new(Some(lost_rx)),
                recovering: std::sync::Mutex::new(None),
                bake_slot: Semaphore::new(1),
                jobs: Jobs::default(),
                journal,
                resumed: Mutex::default(),
                metrics: Metrics::new(),
                ready: AtomicBool::new(false),
                shutdown,
            }),
        };
        state.restore_jobs(recovery);
        Ok(state)
    }

    /// Puts the jobs of the journal back in the job list (see [`Self::new`]).
    fn restore_jobs(&self, recovery: Recovery) {
        for record in recovery.finished {
            let (_, forgotten) = self.inner.jobs.restore(record.status);
            self.forget_jobs(&forgotten);
        }
        let mut resumed = Vec::with_capacity(recovery.pending.len());
        for spec in recovery.pending {
            let (job, forgotten) =
                self.inner
                    .jobs
                    .create(spec.id.clone(), spec.asset.clone(), spec.options.cameras);
            self.forget_jobs(&forgotten);
            let how = if self.inner.assets.path_for(&spec.asset).exists() {
                Resume::Written
            } else {
                match self.inner.assets.reserve(&spec.asset) {
                    Ok(reservation) => Resume::Bake(reservation),
                    Err(err) => Resume::Conflict(err.to_string()),
                }
            };
            resumed.push(Resumed { job, spec, how });
        }
        if !resumed.is_empty() {
            tracing::info!(
                jobs = resumed.len(),
                "resuming the unfinished bake jobs of the journal"
            );
        }
        *self
            .inner
            .resumed
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = resumed;
    }

    /// Removes the journal records of jobs the job list forgot.
    pub(crate) fn forget_jobs(&self, ids: &[String]) {
        for id in ids {
            if let Err(err) = self.inner.journal.forget(id) {
                tracing::warn!(job = id, error = %err, "cannot remove a forgotten job's record");
            }
        }
    }

    /// The job journal.
    pub(crate) fn journal(&self) -> &Journal {
        &self.inner.journal
    }

    /// The configuration.
    pub fn config(&self) -> &ServeConfig {
        &self.inner.config
    }

    /// The asset store.
    pub fn assets(&self) -> &AssetStore {
        &self.inner.assets
    }

    /// The shared content-addressed store, when configured.
    pub fn store(&self) -> Option<&ContentStore> {
        self.inner.store.as_ref()
    }

    /// Why the store keeps the service from being ready, if it does.
    pub fn store_failure(&self) -> Option<String> {
        self.inner
            .store_failure
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// The asset `id`: loaded already, or (with a store) fetched, verified and loaded from the
    /// store on first use.
    ///
    /// # Errors
    /// 404 when neither this replica nor the store has it; 503 before start-up loading is
    /// done, when the store fails or holds a corrupt object; 413 when the asset exceeds a
    /// limit.
    pub async fn asset(&self, id: &str) -> Result<Arc<LoadedAsset>, AppError> {
        match self.inner.assets.get(id) {
            // Until start-up loading is done an unknown id may be one not loaded yet.
            Err(AppError::NotFound(_)) if !self.is_ready() => {
                Err(AppError::Unavailable(match self.store_failure() {
                    Some(reason) => format!("not ready: {reason}"),
                    None => "loading assets; retry shortly".to_owned(),
                }))
            }
            Err(AppError::NotFound(message)) if self.inner.store.is_some() => {
                self.load_from_store(id, message).await
            }
            other => other,
        }
    }

    /// Holds the store lock of `id` until the guard drops (see [`Inner::store_locks`]).
    pub(crate) async fn lock_store_id(&self, id: &str) -> StoreIdGuard {
        let lock = Arc::clone(
            self.inner
                .store_locks
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .entry(id.to_owned())
                .or_default(),
        );
        let guard = lock.lock_owned().await;
        StoreIdGuard {
            state: Arc::downgrade(&self.inner),
            id: id.to_owned(),
            guard: Some(guard),
        }
    }

    /// Fetches, verifies and loads `id` from the store in a task of its own, so that a request
    /// that gives up (timeout, disconnect) does not abandon a download others wait for.
    async fn load_from_store(
        &self,
        id: &str,
        not_found: String,
    ) -> Result<Arc<LoadedAsset>, AppError> {
        let state = self.clone();
        let owned = id.to_owned();
        tokio::spawn(async move { state.load_from_store_now(&owned, not_found).await })
            .await
            .map_err(|e| AppError::Internal(e.into()))?
    }

    async fn load_from_store_now(
        &self,
        id: &str,
        not_found: String,
    ) -> Result<Arc<LoadedAsset>, AppError> {
        let Some(store) = &self.inner.store else {
            return Err(AppError::NotFound(not_found));
        };
        let _one = self.lock_store_id(id).await;
        if let Ok(asset) = self.inner.assets.get(id) {
            return Ok(asset);
        }
        let unavailable = |err: StoreError| {
            tracing::error!(id, error = %err, "cannot fetch an asset from the store");
            match err {
                StoreError::TooLarge { .. } => AppError::OverLimit(err.to_string()),
                err => AppError::Unavailable(err.to_string()),
            }
        };
        let Some(record) = store.resolve(id).await.map_err(unavailable)? else {
            return Err(AppError::NotFound(not_found));
        };
        let path = store
            .fetch(id, &record, &self.cached_in_use())
            .await
            .map_err(unavailable)?;
        let state = self.clone();
        let owned = id.to_owned();
        let loaded = tokio::task::spawn_blocking(move || {
            let engine = state.inner.pool.engine();
            assets::load_file(&state.inner.assets, &engine, &owned, &path).map_err(|e| (e, engine))
        })
        .await
        .map_err(|e| AppError::Internal(e.into()))?;
        let asset = loaded.map_err(|(err, engine)| match err {
            LoadError::OverLimit(message) => AppError::OverLimit(message),
            LoadError::Busy(message) => AppError::Unavailable(message),
            other => self.inner.pool.device_lost(&engine).unwrap_or_else(|| {
                tracing::error!(id, error = %other, "an asset of the store cannot be loaded");
                AppError::Unavailable(format!(
                    "asset {id:?} of the store cannot be loaded: {other}"
                ))
            }),
        })?;
        // An upload or bake of this id may have been inserted meanwhile: it wins.
        if let Ok(asset) = self.inner.assets.get(id) {
            return Ok(asset);
        }
        tracing::info!(id, sha256 = record.sha256, "asset loaded from the store");
        self.inner.assets.insert(asset);
        self.inner.metrics.set_assets(self.inner.assets.len());
        self.inner.assets.get(id)
    }

    /// The cached store files that loaded assets use (never evicted).
    fn cached_in_use(&self) -> std::collections::HashSet<PathBuf> {
        self.inner.assets.paths().into_iter().collect()
    }

    /// Fetches and loads every asset the store names that is not loaded, while the cache has
    /// room (the rest load on first use); the first store failure or corrupt object ends it (a
    /// record that is not a record is logged and skipped).
    async fn load_store_names(&self, ids: &[String]) -> Result<(), StoreError> {
        let Some(store) = &self.inner.store else {
            return Ok(());
        };
        let mut room = store.cache_limit();
        for id in ids {
            if self.inner.assets.contains(id) {
                continue;
            }
            let record = match store.resolve(id).await {
                Ok(Some(record)) => record,
                Ok(None) => continue,
                // One bad record costs its own asset, not every replica's readiness.
                Err(err @ StoreError::BadRecord { .. }) => {
                    tracing::error!(id, error = %err, "skipping an asset the store names badly");
                    continue;
                }
                Err(err) => return Err(err),
            };
            if record.bytes > room {
                tracing::info!(
                    id,
                    bytes = record.bytes,
                    "the store cache is full: this asset loads on first use"
                );
                continue;
            }
            room -= record.bytes;
            let path = store.fetch(id, &record, &self.cached_in_use()).await?;
            self.load_files(vec![(id.clone(), path)]).await;
        }
        Ok(())
    }

    /// Records why the store keeps the service from being ready, logging a new reason once.
    fn note_store_failure(&self, reason: String) {
        let mut failure = self
            .inner
            .store_failure
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if failure.as_deref() != Some(reason.as_str()) {
            tracing::error!(reason = %reason, "not ready: the asset store fails; retrying every {} s", STORE_RETRY.as_secs());
            *failure = Some(reason);
        }
    }

    /// Runs `attempt` until it succeeds, every [`STORE_RETRY`], with each new failure in the
    /// log and in `/readyz`.
    async fn until_store_works<T, F, Fut>(&self, mut attempt: F) -> T
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T, StoreError>>,
    {
        loop {
            match attempt().await {
                Ok(value) => {
                    if self.store_failure().is_some() {
                        tracing::info!("the asset store works again");
                    }
                    *self
                        .inner
                        .store_failure
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner) = None;
                    return value;
                }
                Err(err) => {
                    self.note_store_failure(err.to_string());
                    tokio::time::sleep(STORE_RETRY).await;
                }
            }
        }
    }

    /// The server's memory budget.
    pub fn budget(&self) -> &Arc<MemoryBudget> {
        &self.inner.budget
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    /// Whether startup loading has finished.
    pub fn is_ready(&self) -> bool {
        self.inner.ready.load(Ordering::Acquire)
    }

    /// The render pool and its engine (device, renderer, baker).
    pub fn pool(&self) -> &RenderPool {
        &self.inner.pool
    }

    pub(crate) fn jobs(&self) -> &Jobs {
        &self.inner.jobs
    }

    pub(crate) fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.inner.shutdown.subscribe()
    }

    /// Tells stream sessions to finish their current frame and close.
    pub fn begin_shutdown(&self) {
        self.inner.shutdown.send_replace(true);
    }

    /// Whether [`Self::begin_shutdown`] was called.
    pub(crate) fn is_shutting_down(&self) -> bool {
        *self.inner.shutdown.borrow()
    }

    /// Checks the bearer token when one is configured.
    pub(crate) fn authorize(&self, headers: &HeaderMap) -> Result<(), AppError> {
        let Some(token) = &self.inner.config.token else {
            return Ok(());
        };
        let given = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        match given {
            Some(given) if constant_time_eq(given.as_bytes(), token.as_bytes()) => Ok(()),
            _ => Err(AppError::Unauthorized),
        }
    }

    /// Removes temporary files an interrupted upload or bake left in the assets folder, settles
    /// the resumed jobs whose asset was written before the server stopped, loads every `*.lfa`
    /// there (files that fail or exceed a limit are logged and skipped), bakes the demo scene
    /// first when configured and the folder holds none, marks the service ready, then queues
    /// the other resumed jobs.
    pub async fn load_assets(&self) -> anyhow::Result<()> {
        let dir = self.inner.config.assets_dir.clone();
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("creating the assets folder {}", dir.display()))?;
        self.inner
            .assets
            .remove_leftovers()
            .with_context(|| format!("reading {}", dir.display()))?;
        let resumed = std::mem::take(
            &mut *self
                .inner
                .resumed
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        let mut to_bake = Vec::new();
        for Resumed { job, spec, how } in resumed {
            match how {
                Resume::Bake(reservation) => to_bake.push((job, reservation, spec)),
                Resume::Written => {
                    let path = self.inner.assets.path_for(&job.asset);
                    let outcome = tokio::task::spawn_blocking(move || written_report(&path))
                        .await
                        .unwrap_or_else(|e| Err(format!("checking the baked asset panicked: {e}")));
                    let outcome = match outcome {
                        Ok(report) => {
                            let path = self.inner.assets.path_for(&job.asset);
                            jobs::publish_baked(self, &job, &path)
                                .await
                                .map(|()| report)
                        }
                        Err(message) => Err(message),
                    };
                    if outcome.is_ok() {
                        job.progress(spec.options.cameras, spec.options.cameras);
                    }
                    jobs::record_finished(self, &job, outcome, None).await;
                }
                Resume::Conflict(message) => {
                    jobs::record_finished(self, &job, Err(message), None).await;
                }
            }
        }
        let mut found = self
            .inner
            .assets
            .scan()
            .with_context(|| format!("reading {}", dir.display()))?;
        let named = match &self.inner.store {
            Some(store) => self.until_store_works(|| store.list_names()).await,
            None => Vec::new(),
        };
        if found.is_empty() && named.is_empty() && self.inner.config.bake_demo_if_empty {
            let path = self.inner.assets.path_for("demo");
            self.bake_demo(path.clone()).await?;
            found.push(("demo".to_owned(), path));
        }
        self.load_files(found).await;
        if self.inner.store.is_some() {
            self.until_store_works(|| self.load_store_names(&named))
                .await;
        }
        self.start_recovery_task();
        self.inner.ready.store(true, Ordering::Release);
        for (job, reservation, spec) in to_bake {
            tracing::info!(job = job.id, asset = job.asset, "bake job resumed");
            jobs::spawn(
                self.clone(),
                job,
                reservation,
                BakeWork { spec, mesh: None },
            );
        }
        Ok(())
    }

    /// Loads `files` (id, path) into the store on the current device, logging and skipping
    /// those that fail or exceed a limit.
    async fn load_files(&self, files: Vec<(String, PathBuf)>) {
        for (id, path) in files {
            let state = self.clone();
            let loaded = tokio::task::spawn_blocking(move || {
                let engine = state.inner.pool.engine();
                assets::load_file(&state.inner.assets, &engine, &id, &path)
                    .map_err(|e| (id, path, e))
            })
            .await;
            match loaded {
                Ok(Ok(asset)) => {
                    tracing::info!(
                        id = asset.id,
                        cameras = asset.header.camera_count(),
                        resolution_px = asset.header.image_size()[0],
                        "asset loaded"
                    );
                    self.inner.assets.insert(asset);
                }
                Ok(Err((id, path, err))) => {
                    tracing::warn!(id, path = %path.display(), error = format!("{err:#}"), "skipping an asset that cannot be loaded");
                }
                Err(err) => tracing::error!(error = %err, "an asset load task failed"),
            }
        }
        self.inner.metrics.set_assets(self.inner.assets.len());
    }

    /// Starts (once) the task that replaces a lost device: it holds the state weakly and ends
    /// with it.
    fn start_recovery_task(&self) {
        let Some(mut reports) = self
            .inner
            .lost_reports
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take()
        else {
            return;
        };
        let weak = Arc::downgrade(&self.inner);
        tokio::spawn(async move {
            while let Some(generation) = reports.recv().await {
                let Some(inner) = weak.upgrade() else {
                    return;
                };
                AppState { inner }.recover(generation).await;
            }
        });
    }

    /// Why the service is not ready while it replaces a lost device.
    pub(crate) fn recovering(&self) -> Option<String> {
        self.inner
            .recovering
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    fn set_recovering(&self, why: Option<String>) {
        *self
            .inner
            .recovering
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = why;
    }

    /// Replaces the engine of `generation`, whose device is lost: opens a new device (retrying
    /// with back-off while none opens), builds the pipelines, and uploads every loaded asset
    /// again from its file. Readiness fails meanwhile; requests in flight on the old device
    /// fail with 503.
    async fn recover(&self, generation: u64) {
        if self.inner.pool.engine().generation != generation {
            return; // Already replaced.
        }
        let why = self.inner.pool.engine().gpu().lost().unwrap_or_default();
        tracing::error!(generation, why, "the GPU device is lost: opening a new one");
        self.set_recovering(Some(format!(
            "the GPU device was lost ({why}); opening a new one and uploading the assets again"
        )));
        self.inner.metrics.device_lost();
        let mut delay = Duration::from_millis(250);
        let engine = loop {
            let opened = tokio::task::spawn_blocking(move || {
                Gpu::new().map(|gpu| Engine::new(Arc::new(gpu), generation + 1))
            })
            .await;
            match opened {
                Ok(Ok(engine)) => break engine,
                Ok(Err(err)) => {
                    tracing::error!(error = %err, "cannot open a new GPU device; retrying");
                }
                Err(err) => tracing::error!(error = %err, "the device task failed; retrying"),
            }
            if self.is_shutting_down() {
                return;
            }
            tokio::time::sleep(delay).await;
            delay = (delay * 2).min(Duration::from_secs(30));
        };
        tracing::info!(
            adapter = engine.gpu().adapter_summary(),
            "new GPU device ready"
        );
        self.inner.pool.replace_engine(engine);
        // Every asset lives on the lost device: drop them all (their memory is given back as
        // the requests holding them fail) and upload them again from their files.
        let files = self.inner.assets.take_all();
        self.load_files(files).await;
        self.inner.assets.end_reload();
        self.set_recovering(None);
        tracing::info!(
            assets = self.inner.assets.len(),
            "recovered from the device loss"
        );
    }

    /// Bakes `mesh`, measures its calibration (error against cost, for `target_psnr` /
    /// `budget_ms` renders) and writes the asset to `path` atomically. Blocking.
    pub(crate) fn bake_calibrated(
        &self,
        mesh: &lumigraph_core::mesh::Mesh,
        options: &BakeOptions,
        source: &lumigraph_core::asset::Provenance,
        path: &std::path::Path,
        progress: &mut dyn FnMut(u32, u32),
    ) -> anyhow::Result<lumigraph_core::calibration::CalibratedBake> {
        let engine = self.pool().engine();
        let baked = lumigraph_core::calibration::bake_calibrated(
            &engine.baker,
            &engine.renderer,
            &engine.reference,
            mesh,
            options,
            source,
            progress,
        )?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &baked.bytes))
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(baked)
    }

    async fn bake_demo(&self, path: PathBuf) -> anyhow::Result<()> {
        let state = self.clone();
        let options = self.inner.config.demo_bake;
        tracing::info!(path = %path.display(), cameras = options.cameras, resolution_px = options.resolution, "no asset found: baking the built-in demo scene");
        tokio::task::spawn_blocking(move || -> anyhow::Result<()> {
            let mesh = lumigraph_core::mesh::demo_mesh().context("building the demo mesh")?;
            let source = lumigraph_core::mesh::demo_provenance(&mesh);
            let mut last_decile = 0;
            let mut progress = |done: u32, total: u32| {
                let decile = (done * 10).checked_div(total).unwrap_or(10);
                if decile > last_decile {
                    last_decile = decile;
                    tracing::info!("baking demo: {done}/{total} cameras");
                }
            };
            let baked = state
                .bake_calibrated(&mesh, &options, &source, &path, &mut progress)
                .context("baking the demo scene")?;
            tracing::info!(
                bake_ms = baked.bake_ms,
                calibrate_ms = baked.calibrate_ms,
                asset_bytes = baked.bytes.len(),
                "demo scene baked and calibrated"
            );
            Ok(())
        })
        .await?
    }
}

/// The report of a resumed job whose asset file was written before the server stopped, once
/// the file verifies (every page checksum); why not otherwise (the file is left for the folder
/// scan, which skips it with a warning).
fn written_report(path: &std::path::Path) -> Result<serde_json::Value, String> {
    let file = lumigraph_core::asset::AssetFile::open(path)
        .and_then(|file| file.verify_all().map(|()| file))
        .map_err(|e| format!("the baked asset cannot be read: {e}"))?;
    let header = file.header();
    Ok(serde_json::json!({
        "cameras": header.camera_count(),
        "resolution": header.image_size()[0],
        "asset_bytes": file.file_len(),
        "resumed": true,
    }))
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// A random id like `job-3f9c0a12b4d5e6f7`.
pub(crate) fn random_id(prefix: &str) -> String {
    format!("{prefix}-{:016x}", rand::random::<u64>())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_total_from_meminfo() {
        let text = "MemTotal:       131072000 kB\nMemFree:        1000 kB\n";
        assert_eq!(mem_total_bytes(text), Some(131_072_000 * 1024));
        assert_eq!(mem_total_bytes("MemFree: 1 kB\n"), None);
        assert_eq!(mem_total_bytes("MemTotal: many kB\n"), None);
        assert!(default_asset_memory_budget() > 0);
    }

    #[test]
    fn token_comparison() {
        assert!(constant_time_eq(b"abc", b"abc"));
        assert!(!constant_time_eq(b"abc", b"abd"));
        assert!(!constant_time_eq(b"abc", b"ab"));
    }
}
