//! Rendering off the async runtime: a bounded pool shared by HTTP requests and stream sessions,
//! each render a core quality [`Plan`] applied to one view.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use lumigraph_core::bake::Baker;
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::{Gpu, GpuError};
use lumigraph_core::lod::LodError;
use lumigraph_core::page_cache::PageFrameStats;
use lumigraph_core::quality::{Decision, Plan, Quality, QualityError};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::Renderer;
use lumigraph_core::two_plane_render::TwoPlaneRenderer;
use lumigraph_core::view::View;
use tokio::sync::{Semaphore, mpsc};

use super::assets::{AssetField, LoadedAsset};
use super::budget::{Charge, MemoryBudget, frame_bytes};
use super::error::AppError;

/// The plan of `quality` for `asset`; a conflict or a missing calibration is a 422 with the
/// core's text.
pub fn plan(quality: &Quality, asset: &LoadedAsset) -> Result<Plan, AppError> {
    quality.plan(&asset.header).map_err(quality_error)
}

/// Maps a core quality error: a bad request is 422, a device or asset failure 500.
pub fn quality_error(err: QualityError) -> AppError {
    match err {
        QualityError::Render(e) | QualityError::Lod(LodError::Render(e)) => render_error(e),
        other => AppError::Invalid(other.to_string()),
    }
}

/// The device and everything built on it. When the device is lost the whole engine is
/// replaced by one on a new device ([`RenderPool::replace_engine`]) and the assets are uploaded
/// again.
pub struct Engine {
    /// 0 for the first device, then one more for every replacement.
    pub generation: u64,
    /// The light-field renderer.
    pub renderer: Arc<Renderer>,
    /// The two-plane light-field renderer (pipelines compiled on first use).
    pub two_plane: Arc<TwoPlaneRenderer>,
    /// The baker (server-side bakes).
    pub baker: Baker,
    /// The mesh rasterizer (bake calibration).
    pub reference: ReferenceRenderer,
}

impl Engine {
    /// Builds the pipelines on `gpu` (blocking: compiles shaders).
    pub fn new(gpu: Arc<Gpu>, generation: u64) -> Self {
        Self {
            generation,
            renderer: Arc::new(Renderer::new(Arc::clone(&gpu))),
            two_plane: Arc::new(TwoPlaneRenderer::new(Arc::clone(&gpu))),
            baker: Baker::new(Arc::clone(&gpu)),
            reference: ReferenceRenderer::new(gpu),
        }
    }

    /// The device.
    pub fn gpu(&self) -> &Arc<Gpu> {
        self.renderer.gpu()
    }
}

/// Renders on a bounded number of blocking threads; queued work beyond a cap is refused, and
/// every frame is charged to the server's memory budget while it is served.
pub struct RenderPool {
    engine: std::sync::RwLock<Arc<Engine>>,
    /// Told the generation of an engine whose device was found lost.
    lost: mpsc::Sender<u64>,
    workers: Arc<Semaphore>,
    queue: Arc<Semaphore>,
    budget: Arc<MemoryBudget>,
    memory_wait: Duration,
    activity: Arc<Mutex<Activity>>,
}

/// A rendered frame with its timing.
pub struct Rendered {
    /// The frame.
    pub frame: Frame,
    /// Wall-clock render time including queueing on the device, milliseconds.
    pub render_ms: f64,
    /// What the plan decided for the view.
    pub decision: Decision,
    /// The paging of an asset rendered through the page cache.
    pub pages: Option<PageFrameStats>,
    /// The frame's share of the memory budget: keep it until the frame is encoded.
    pub memory: Charge,
}

/// Whether the render path moves: requests in the pool and when it last made progress.
#[derive(Debug, Default)]
struct Activity {
    /// Requests queued or rendering.
    in_flight: usize,
    /// When `in_flight` last rose from zero.
    busy_since: Option<Instant>,
    /// When a render last completed (successfully or not).
    last_done: Option<Instant>,
}

impl Activity {
    /// How long requests have waited with no render completing, at `now`; `None` when idle.
    fn stalled_for(&self, now: Instant) -> Option<Duration> {
        if self.in_flight == 0 {
            return None;
        }
        let since = match (self.busy_since, self.last_done) {
            (Some(busy), Some(done)) => busy.max(done),
            (Some(t), None) | (None, Some(t)) => t,
            (None, None) => return None,
        };
        Some(now.saturating_duration_since(since))
    }
}

/// A request counted in [`Activity`] until dropped (also when its future is cancelled).
struct InFlight {
    activity: Arc<Mutex<Activity>>,
}

impl InFlight {
    fn enter(activity: &Arc<Mutex<Activity>>, now: Instant) -> Self {
        let mut a = activity.lock().unwrap_or_else(PoisonError::into_inner);
        if a.in_flight == 0 {
            a.busy_since = Some(now);
        }
        a.in_flight += 1;
        Self {
            activity: Arc::clone(activity),
        }
    }

    fn completed(&self, now: Instant) {
        self.activity
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .last_done = Some(now);
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        let mut a = self.activity.lock().unwrap_or_else(PoisonError::into_inner);
        a.in_flight = a.in_flight.saturating_sub(1);
    }
}

/// The render path's state for readiness.
#[derive(Clone, Copy, Debug)]
pub struct PoolHealth {
    /// Requests queued or rendering now.
    pub in_flight: usize,
    /// How long they have waited with no render completing (`None` when idle).
    pub stalled_for: Option<Duration>,
}

impl RenderPool {
    /// A pool running at most `workers` renders at once with at most `max_queued` waiting,
    /// charging each frame to `budget` (waiting up to `memory_wait` for it).
    pub fn new(
        engine: Engine,
        workers: usize,
        max_queued: usize,
        budget: Arc<MemoryBudget>,
        memory_wait: Duration,
        lost: mpsc::Sender<u64>,
    ) -> Self {
        Self {
            engine: std::sync::RwLock::new(Arc::new(engine)),
            lost,
            workers: Arc::new(Semaphore::new(workers.max(1))),
            queue: Arc::new(Semaphore::new(workers.max(1) + max_queued)),
            budget,
            memory_wait,
            activity: Arc::default(),
        }
    }

    /// The current engine.
    pub fn engine(&self) -> Arc<Engine> {
        Arc::clone(&self.engine.read().unwrap_or_else(PoisonError::into_inner))
    }

    /// The current renderer (for uploads).
    pub fn renderer(&self) -> Arc<Renderer> {
        Arc::clone(&self.engine().renderer)
    }

    /// Puts `engine` (on a new device) in place of the current one; renders already running
    /// finish (or fail) on the old one.
    pub fn replace_engine(&self, engine: Engine) {
        *self.engine.write().unwrap_or_else(PoisonError::into_inner) = Arc::new(engine);
    }

    /// Checks whether `engine`'s device is lost; if so, reports it for recovery and returns
    /// the 503 that the request in flight gets.
    pub fn device_lost(&self, engine: &Engine) -> Option<AppError> {
        let why = engine.gpu().lost()?;
        // Full: a report is already pending.
        let _ = self.lost.try_send(engine.generation);
        Some(lost_error(&why))
    }

    /// Requests in the pool and how long they have waited without progress.
    pub fn health(&self) -> PoolHealth {
        let a = self.activity.lock().unwrap_or_else(PoisonError::into_inner);
        PoolHealth {
            in_flight: a.in_flight,
            stalled_for: a.stalled_for(Instant::now()),
        }
    }

    /// Renders `view` of `asset` as `plan` says (through a page cache: waiting for the pages the
    /// frame loads with `wait_for_pages`, else at once with those on the device); 503 when the
    /// queue is full or the memory
    /// budget stays taken, 413 when the frame alone exceeds the budget.
    pub async fn render(
        &self,
        asset: Arc<LoadedAsset>,
        view: View,
        plan: Plan,
        wait_for_pages: bool,
    ) -> Result<Rendered, AppError> {
        let _queued = self.queue.clone().try_acquire_owned().map_err(|_| {
            AppError::Unavailable("the render queue is full; retry shortly".to_owned())
        })?;
        let in_flight = InFlight::enter(&self.activity, Instant::now());
        let memory = self
            .budget
            .charge(
                frame_bytes(view.width, view.height),
                self.memory_wait,
                &format!("a {}×{} frame", view.width, view.height),
            )
            .await?;
        let _worker = self
            .workers
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| AppError::Unavailable("the service is shutting down".to_owned()))?;
        let engine = self.engine();
        if let Some(lost) = self.device_lost(&engine) {
            return Err(lost);
        }
        if !Arc::ptr_eq(asset.field.gpu(), engine.gpu()) {
            return Err(AppError::Unavailable(
                "the asset is being uploaded again to a new GPU device; retry shortly".to_owned(),
            ));
        }
        let engine_now = Arc::clone(&engine);
        let result = tokio::task::spawn_blocking(move || {
            let start = Instant::now();
            let rendered = match &asset.field {
                AssetField::Spherical(field) => plan
                    .render(&engine_now.renderer, field, &view)
                    .map(|r| (r, None)),
                AssetField::TwoPlane(field) => plan
                    .render_two_plane(&engine_now.two_plane, field, &view)
                    .map(|r| (r, None)),
                AssetField::Paged(field) => {
                    // The cache logs the pages that fail to read: under the asset's id.
                    let _asset = tracing::warn_span!("paged", asset = %asset.id).entered();
                    plan.render_two_plane_paged(
                        &engine_now.two_plane,
                        &mut field.lock(),
                        &view,
                        wait_for_pages,
                    )
                    .map(|(r, pages)| (r, Some(pages)))
                }
            };
            (rendered, start.elapsed().as_secs_f64() * 1e3)
        })
        .await
        .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("render task failed")))?;
        in_flight.completed(Instant::now());
        let (rendered, render_ms) = result;
        let (rendered, pages) = match rendered {
            Ok(rendered) => rendered,
            Err(err) => {
                return Err(self
                    .device_lost(&engine)
                    .unwrap_or_else(|| quality_error(err)));
            }
        };
        Ok(Rendered {
            frame: rendered.frame,
            render_ms,
            decision: rendered.decision,
            pages,
            memory,
        })
    }
}

/// The 503 of a request that met a lost device.
pub fn lost_error(why: &str) -> AppError {
    AppError::Unavailable(format!(
        "the GPU device was lost ({why}); the server is opening a new one and uploading the \
         assets again: retry shortly"
    ))
}

/// Whether a core render error is a lost device.
pub fn is_device_lost(err: &lumigraph_core::render::RenderError) -> bool {
    matches!(
        err,
        lumigraph_core::render::RenderError::Gpu(GpuError::DeviceLost(_))
    )
}

/// Maps a core render error: invalid requests are 422, everything else 500.
pub fn render_error(err: lumigraph_core::render::RenderError) -> AppError {
    use lumigraph_core::render::RenderError;
    match err {
        RenderError::View(e) => AppError::Invalid(e.to_string()),
        RenderError::Option(message) => AppError::Invalid(message),
        RenderError::Light(e) => AppError::Invalid(e.to_string()),
        other => AppError::Internal(anyhow::Error::new(other).context("render failed")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_idle_pool_is_never_stalled() {
        let now = Instant::now();
        let idle = Activity {
            in_flight: 0,
            busy_since: Some(now),
            last_done: None,
        };
        assert_eq!(idle.stalled_for(now + Duration::from_secs(3600)), None);
    }

    #[test]
    fn a_stall_counts_from_the_later_of_busy_and_last_completion() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        // Idle for an hour, then a request: the stall counts from its arrival.
        let a = Activity {
            in_flight: 1,
            busy_since: Some(t0 + s(3600)),
            last_done: Some(t0),
        };
        assert_eq!(a.stalled_for(t0 + s(3605)), Some(s(5)));
        // Busy for a minute with a render completing 2 s ago: moving.
        let b = Activity {
            in_flight: 3,
            busy_since: Some(t0),
            last_done: Some(t0 + s(58)),
        };
        assert_eq!(b.stalled_for(t0 + s(60)), Some(s(2)));
    }

    #[test]
    fn in_flight_guards_count_requests_and_completions() {
        let activity = Arc::new(Mutex::new(Activity::default()));
        let t0 = Instant::now();
        let first = InFlight::enter(&activity, t0);
        let second = InFlight::enter(&activity, t0 + Duration::from_secs(1));
        {
            let a = activity.lock().expect("lock");
            assert_eq!(a.in_flight, 2);
            assert_eq!(a.busy_since, Some(t0), "busy since the first request");
        }
        first.completed(t0 + Duration::from_secs(2));
        drop(first);
        drop(second);
        let a = activity.lock().expect("lock");
        assert_eq!(a.in_flight, 0);
        assert_eq!(a.last_done, Some(t0 + Duration::from_secs(2)));
        assert_eq!(a.stalled_for(t0 + Duration::from_secs(100)), None);
    }
}
