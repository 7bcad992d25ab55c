//! Rendering and encoding off the async runtime: a bounded pool shared by HTTP requests and
//! stream sessions, and the codecs both speak.

use std::sync::Arc;
use std::time::Instant;

use lumigraph_core::calibration::{Calibration, CalibrationError, Goal};
use lumigraph_core::frame::Frame;
use lumigraph_core::image_io;
use lumigraph_core::lod::{Ladder, LodDecision, LodError, LodPolicy};
use lumigraph_core::render::{Method, RenderOptions, Renderer};
use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};
use tokio::sync::Semaphore;

use super::assets::LoadedAsset;
use super::error::AppError;

/// Colour codec of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ColorFormat {
    /// Lossless 8-bit RGBA PNG.
    #[default]
    Png,
    /// Baseline JPEG, composited over the background (no alpha).
    Jpeg,
    /// Lossless WebP with alpha.
    Webp,
    /// No colour image (only depth).
    None,
}

impl ColorFormat {
    /// MIME type.
    pub fn mime(self) -> &'static str {
        match self {
            ColorFormat::Png => "image/png",
            ColorFormat::Jpeg => "image/jpeg",
            ColorFormat::Webp => "image/webp",
            ColorFormat::None => "application/octet-stream",
        }
    }

    /// Label used in metrics and the stream header.
    pub fn name(self) -> &'static str {
        match self {
            ColorFormat::Png => "png",
            ColorFormat::Jpeg => "jpeg",
            ColorFormat::Webp => "webp",
            ColorFormat::None => "none",
        }
    }
}

/// Depth codec of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum DepthFormat {
    /// NumPy `.npy`, float32, shape (height, width), `inf` where nothing is hit.
    Npy,
    /// OpenEXR, one float32 channel `Z`, `inf` where nothing is hit.
    Exr,
    /// 16-bit grey PNG: `round((d - near) / (far - near) · 65534)`, 65535 = no hit; `near` and
    /// `far` are the smallest and largest finite depths, sent as `X-Depth-Near`/`X-Depth-Far`.
    Png16,
}

impl DepthFormat {
    /// MIME type.
    pub fn mime(self) -> &'static str {
        match self {
            DepthFormat::Npy => "application/x-npy",
            DepthFormat::Exr => "image/x-exr",
            DepthFormat::Png16 => "image/png",
        }
    }
}

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
    let invalid = |e: CalibrationError| AppError::Invalid(e.to_string());
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

/// How a colour frame is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoding {
    /// The codec.
    pub format: ColorFormat,
    /// JPEG quality 1..=100 (ignored by lossless codecs).
    pub quality: u8,
    /// RGBA written where nothing is hit (JPEG: its RGB is the matte).
    pub background: [u8; 4],
}

/// Encodes a frame's colour (blocking).
pub fn encode_color(frame: &Frame, encoding: Encoding) -> Result<Vec<u8>, image_io::ImageIoError> {
    let rgba = frame.with_background(encoding.background);
    let [r, g, b, _] = encoding.background;
    match encoding.format {
        ColorFormat::Png => image_io::encode_png_rgba8(frame.width, frame.height, &rgba),
        ColorFormat::Jpeg => image_io::encode_jpeg(
            frame.width,
            frame.height,
            &rgba,
            encoding.quality,
            [r, g, b],
        ),
        ColorFormat::Webp => image_io::encode_webp_lossless(frame.width, frame.height, &rgba),
        ColorFormat::None => Ok(Vec::new()),
    }
}

/// An encoded depth image and, for `png16`, the depth range it maps.
pub struct EncodedDepth {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// `(near, far)` of a `png16` image.
    pub range: Option<(f32, f32)>,
}

/// Encodes a frame's depth (blocking).
pub fn encode_depth(frame: &Frame, format: DepthFormat) -> Result<EncodedDepth, AppError> {
    let encode_err = |e: image_io::ImageIoError| {
        AppError::Internal(anyhow::Error::new(e).context("encoding depth"))
    };
    match format {
        DepthFormat::Npy => Ok(EncodedDepth {
            bytes: image_io::encode_depth_npy(frame.width, frame.height, &frame.depth)
                .map_err(encode_err)?,
            range: None,
        }),
        DepthFormat::Exr => Ok(EncodedDepth {
            bytes: image_io::encode_depth_exr(frame.width, frame.height, &frame.depth)
                .map_err(encode_err)?,
            range: None,
        }),
        DepthFormat::Png16 => {
            let (near, far) = frame
                .depth
                .iter()
                .filter(|d| d.is_finite())
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &d| {
                    (lo.min(d), hi.max(d))
                });
            let (near, far) = if near.is_finite() {
                (near, far)
            } else {
                (0.0, 0.0)
            };
            let span = far - near;
            let values: Vec<u16> = frame
                .depth
                .iter()
                .map(|&d| {
                    if !d.is_finite() {
                        u16::MAX
                    } else if span > 0.0 {
                        (((d - near) / span) * 65534.0).round().clamp(0.0, 65534.0) as u16
                    } else {
                        0
                    }
                })
                .collect();
            let image = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
                frame.width,
                frame.height,
                values,
            )
            .ok_or_else(|| {
                AppError::Internal(anyhow::anyhow!(
                    "depth buffer size does not match the frame"
                ))
            })?;
            let mut bytes = Vec::new();
            image
                .write_to(
                    &mut std::io::Cursor::new(&mut bytes),
                    image::ImageFormat::Png,
                )
                .map_err(|e| {
                    AppError::Internal(anyhow::Error::new(e).context("encoding 16-bit depth PNG"))
                })?;
            Ok(EncodedDepth {
                bytes,
                range: Some((near, far)),
            })
        }
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

/// Runs a blocking encode off the runtime and times it.
pub async fn encode_blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, AppError> + Send + 'static,
) -> Result<(T, f64), AppError> {
    tokio::task::spawn_blocking(move || {
        let start = Instant::now();
        work().map(|out| (out, start.elapsed().as_secs_f64() * 1e3))
    })
    .await
    .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("encode task failed")))?
}
