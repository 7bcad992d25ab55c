//! Rendering off the async runtime: a bounded pool shared by HTTP requests and stream sessions,
//! and the quality glue that turns a request's knobs, goal or automatic LOD into a [`Plan`].

use std::sync::Arc;
use std::time::Instant;

use lumigraph_core::frame::Frame;
use lumigraph_core::lod::{Ladder, LodDecision, LodError, LodPolicy};
use lumigraph_core::render::{Method, RenderOptions, Renderer};
use lumigraph_core::tradeoff::{Calibration, Goal, TradeoffError};
use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};
use tokio::sync::Semaphore;

use super::assets::LoadedAsset;
use super::error::AppError;

/// The quality knobs of a render (DESIGN §4), all optional.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Knobs {
    /// Camera count to reconstruct from: 12, 42, 162 or 642 (or a level 0-3), at most the
    /// asset's.
    pub lod: Option<u32>,
    /// March step in bounding-sphere diameters (method default when absent).
    pub step: Option<f32>,
    /// Depth agreement tolerance in bounding-sphere diameters (default step / 2).
    pub tolerance: Option<f32>,
    /// `default` (the accelerated marcher) or `fixed` (the seed's fixed-step baseline).
    #[schema(value_type = Option<String>)]
    pub method: Option<Method>,
    /// Coarse-to-fine factor of the default method (2–16, 0 = off; absent: 4): a coarse pass
    /// bounds each pixel's march (same masked PSNR in less time, BENCHMARKS.md).
    pub guide: Option<u32>,
}

impl Knobs {
    /// Validates the knobs against `asset` and builds the core options.
    pub fn to_options(&self, asset: &LoadedAsset) -> Result<RenderOptions, AppError> {
        let options = RenderOptions {
            lod: self.lod,
            step: self.step,
            tolerance: self.tolerance,
            method: self.method.unwrap_or_default(),
            guide: self.guide,
        };
        options
            .resolve(asset.field.max_level)
            .map_err(render_error)?;
        Ok(options)
    }
}

/// The goal of a render request or stream session: `target_psnr` or `budget_ms` (at most one,
/// and then none of the knobs), with the asset's calibration that serves it. `None` when
/// neither is given. Goal values are checked when a setting is chosen.
pub fn goal_calibration(
    target_psnr: Option<f64>,
    budget_ms: Option<f64>,
    knobs: &Knobs,
    asset: &LoadedAsset,
) -> Result<Option<(Goal, Arc<Calibration>)>, AppError> {
    let invalid = |e: TradeoffError| AppError::Invalid(e.to_string());
    let Some(goal) = Goal::from_pair(target_psnr, budget_ms).map_err(invalid)? else {
        return Ok(None);
    };
    if *knobs != Knobs::default() {
        return Err(AppError::Invalid(
            "target_psnr / budget_ms choose lod, step, tolerance and method: do not send them too \
             (in a stream session, clear them with null)"
                .to_owned(),
        ));
    }
    let calibration = asset_calibration(asset, "by target_psnr or budget_ms")?;
    Ok(Some((goal, Arc::new(calibration))))
}

/// The asset's calibration, or an error saying how to get one to render `how`.
fn asset_calibration(asset: &LoadedAsset, how: &str) -> Result<Calibration, AppError> {
    Calibration::from_quality(asset.header.quality.as_ref())
        .map_err(|e| AppError::Invalid(e.to_string()))?
        .ok_or_else(|| {
            AppError::Invalid(format!(
                "asset {} has no calibration: bake it with calibrate=true (the default of POST \
                 /v1/bake and `lumigraph bake`) to render {how}",
                asset.id
            ))
        })
}

/// The automatic-LOD ladder of a render request or stream session (`auto_lod` = the bound on
/// the predicted silhouette error in pixels, with an optional PSNR floor and blend band); the
/// knobs sent as well stay pinned. `None` without `auto_lod`.
pub fn lod_ladder(
    auto_lod: Option<f64>,
    lod_min_psnr: Option<f64>,
    lod_max_psnr_drop: Option<f64>,
    lod_blend: Option<f64>,
    knobs: &Knobs,
    has_goal: bool,
    asset: &LoadedAsset,
) -> Result<Option<Arc<Ladder>>, AppError> {
    let Some(policy) = LodPolicy::from_parts(
        auto_lod,
        lod_min_psnr,
        lod_max_psnr_drop,
        lod_blend,
        has_goal,
    )
    .map_err(lod_error)?
    else {
        return Ok(None);
    };
    let options = knobs.to_options(asset)?;
    Ladder::new(
        &asset_calibration(asset, "with auto_lod")?,
        &policy,
        asset.header.geometry.camera_count,
        &options,
    )
    .map(|l| Some(Arc::new(l)))
    .map_err(lod_error)
}

fn lod_error(err: LodError) -> AppError {
    match err {
        LodError::Render(e) => render_error(e),
        other => AppError::Invalid(other.to_string()),
    }
}

/// What a render runs: fixed options, or automatic LOD.
#[derive(Clone, Debug)]
pub enum Plan {
    /// These options.
    Options(RenderOptions),
    /// The ladder's choice for the view's projected size (two renders inside a blend band).
    Lod(Arc<Ladder>),
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
    /// The automatic-LOD decision, for [`Plan::Lod`].
    pub lod: Option<LodDecision>,
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
            let frame = match plan {
                Plan::Options(options) => renderer
                    .render(&asset.field, &view, &options)
                    .map(|f| (f, None))
                    .map_err(render_error),
                Plan::Lod(ladder) => ladder
                    .render_auto(&renderer, &asset.field, &view)
                    .map(|(f, d)| (f, Some(d)))
                    .map_err(lod_error),
            };
            (frame, start.elapsed().as_secs_f64() * 1e3)
        })
        .await
        .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("render task failed")))?;
        let (frame, render_ms) = result;
        let (frame, lod) = frame?;
        Ok(Rendered {
            frame,
            render_ms,
            lod,
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
