//! Rendering off the async runtime: a bounded pool shared by HTTP requests and stream sessions,
//! each render a core quality [`Plan`] applied to one view.

use std::sync::Arc;
use std::time::Instant;

use lumigraph_core::frame::Frame;
use lumigraph_core::lod::LodError;
use lumigraph_core::quality::{Decision, Plan, Quality, QualityError};
use lumigraph_core::render::Renderer;
use lumigraph_core::view::View;
use tokio::sync::Semaphore;

use super::assets::LoadedAsset;
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

/// Renders on a bounded number of blocking threads; queued work beyond a cap is refused.
pub struct RenderPool {
    renderer: Arc<Renderer>,
    workers: Arc<Semaphore>,
    queue: Arc<Semaphore>,
}

/// A rendered frame with its timing.
pub struct Rendered {
    /// The frame.
    pub frame: Frame,
    /// Wall-clock render time including queueing on the device, milliseconds.
    pub render_ms: f64,
    /// What the plan decided for the view.
    pub decision: Decision,
}

impl RenderPool {
    /// A pool running at most `workers` renders at once with at most `max_queued` waiting.
    pub fn new(renderer: Arc<Renderer>, workers: usize, max_queued: usize) -> Self {
        Self {
            renderer,
            workers: Arc::new(Semaphore::new(workers.max(1))),
            queue: Arc::new(Semaphore::new(workers.max(1) + max_queued)),
        }
    }

    /// The renderer (for uploads).
    pub fn renderer(&self) -> &Arc<Renderer> {
        &self.renderer
    }

    /// Renders `view` of `asset` as `plan` says; 503 when the queue is full.
    pub async fn render(
        &self,
        asset: Arc<LoadedAsset>,
        view: View,
        plan: Plan,
    ) -> Result<Rendered, AppError> {
        let _queued = self.queue.clone().try_acquire_owned().map_err(|_| {
            AppError::Unavailable("the render queue is full; retry shortly".to_owned())
        })?;
        let _worker = self
            .workers
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| AppError::Unavailable("the service is shutting down".to_owned()))?;
        let renderer = Arc::clone(&self.renderer);
        let result = tokio::task::spawn_blocking(move || {
            let start = Instant::now();
            let rendered = plan
                .render(&renderer, &asset.field, &view)
                .map_err(quality_error);
            (rendered, start.elapsed().as_secs_f64() * 1e3)
        })
        .await
        .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("render task failed")))?;
        let (rendered, render_ms) = result;
        let rendered = rendered?;
        Ok(Rendered {
            frame: rendered.frame,
            render_ms,
            decision: rendered.decision,
        })
    }
}

/// Maps a core render error: invalid requests are 422, everything else 500.
pub fn render_error(err: lumigraph_core::render::RenderError) -> AppError {
    use lumigraph_core::render::RenderError;
    match err {
        RenderError::View(e) => AppError::Invalid(e.to_string()),
        RenderError::Option(message) => AppError::Invalid(message),
        other => AppError::Internal(anyhow::Error::new(other).context("render failed")),
    }
}
