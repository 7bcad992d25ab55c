//! The speed/accuracy trade-off sweep (issue #5, `lumigraph bench tradeoff`).
//!
//! A [`Grid`] lists values of every quality knob — cameras (discrete LOD), step, tolerance (as a
//! multiple of the step), marching method, depth precision and output resolution. [`sweep`]
//! renders the same random orbit views with every combination, compares each frame with the
//! rasterized mesh (DESIGN §3 metrics) and returns one [`Point`] per setting: mean ms per frame,
//! fetches per pixel and the mean masked PSNR / SSIM / depth error. [`pareto_front`] marks the
//! settings no other setting beats on both time and masked PSNR; [`write_csv`] writes them.

use std::io::Write;
use std::path::Path;

use serde::Serialize;

use crate::asset::{AssetError, AssetFile, Channel, Encoding};
use crate::frame::Frame;
use crate::geometry::{self, CAMERA_COUNTS};
use crate::gpu::mesh::GpuMesh;
use crate::metrics::{self, Comparison, MetricsError};
use crate::reference::{ReferenceError, ReferenceRenderer};
use crate::render::{DEFAULT_GUIDE, Method, RenderError, RenderOptions, Renderer, UploadOptions};
use crate::shading::Shading;
use crate::view::View;

/// Errors of the sweep.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TradeoffError {
    /// A grid value is out of range.
    #[error("trade-off grid: {0}")]
    Grid(String),
    /// A light-field render failed.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// A reference render failed.
    #[error(transparent)]
    Reference(#[from] ReferenceError),
    /// A comparison failed.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// A render goal (target PSNR or time budget) is invalid or cannot be served.
    #[error("{0}")]
    Goal(String),
    /// The bake before a calibration failed.
    #[error(transparent)]
    Bake(#[from] crate::bake::BakeError),
    /// The baked asset could not be read back or re-encoded.
    #[error(transparent)]
    Asset(#[from] AssetError),
    /// A device upload failed.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// Writing the CSV failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
}

/// Depth precision an asset stores: 8 for 8-bit depth, 16 otherwise.
fn stored_depth_bits(asset: &AssetFile) -> u8 {
    if asset.header().encoding(Channel::Depth) == Some(Encoding::R8) {
        8
    } else {
        16
    }
}

/// The values of every knob to sweep; the sweep renders their Cartesian product.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Grid {
    /// Camera counts (12, 42, 162, 642; at most the asset's).
    pub cameras: Vec<u32>,
    /// Steps in bounding-sphere diameters.
    pub steps: Vec<f32>,
    /// Tolerances as multiples of the step (seed 000 §3.1: below 0.5 leaves gaps).
    pub tolerance_factors: Vec<f32>,
    /// Marching methods.
    pub methods: Vec<Method>,
    /// Coarse-to-fine factors of the default method (0 = off; the fixed method always runs
    /// unguided, once).
    pub guides: Vec<u32>,
    /// Depth precision: 8 and/or 16 (16 only for 16-bit assets).
    pub depth_bits: Vec<u8>,
    /// Output sizes (square frames, pixels).
    pub sizes: Vec<u32>,
}

impl Grid {
    /// The default sweep for an asset: every camera count it holds from 12 up, steps 1/16–1/64,
    /// tolerance ½ and 1 step, both methods (the default one with its default guide), its depth precision and 8 bits, 256²
    /// and 512². 96–192 settings.
    pub fn default_for(asset: &AssetFile) -> Grid {
        let max_level = usize::from(asset.header().geometry.camera_level).min(3);
        Grid {
            cameras: CAMERA_COUNTS[..=max_level].to_vec(),
            steps: vec![1.0 / 16.0, 1.0 / 32.0, 1.0 / 64.0],
            tolerance_factors: vec![0.5, 1.0],
            methods: vec![Method::Default, Method::Fixed],
            guides: vec![DEFAULT_GUIDE],
            depth_bits: if stored_depth_bits(asset) == 16 {
                vec![16, 8]
            } else {
                vec![8]
            },
            sizes: vec![256, 512],
        }
    }

    /// Number of settings: the product of the list lengths, where each default method counts
    /// once per guide and the fixed method once.
    pub fn len(&self) -> usize {
        let methods: usize = self
            .methods
            .iter()
            .map(|&m| {
                if m == Method::Fixed {
                    1
                } else {
                    self.guides.len()
                }
            })
            .sum();
        self.cameras.len()
            * self.steps.len()
            * self.tolerance_factors.len()
            * methods
            * self.depth_bits.len()
            * self.sizes.len()
    }

    /// The guides `method` runs with.
    fn guides_of(&self, method: Method) -> Vec<u32> {
        if method == Method::Fixed {
            vec![0]
        } else {
            self.guides.clone()
        }
    }

    /// Whether any list is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Checks every value against the asset before any rendering.
    ///
    /// # Errors
    /// [`TradeoffError::Grid`] naming the bad value.
    pub fn validate(&self, asset: &AssetFile) -> Result<(), TradeoffError> {
        let bad = |m: String| Err(TradeoffError::Grid(m));
        if self.is_empty() {
            return bad("every knob needs at least one value".to_owned());
        }
        if self.len() > 10_000 {
            return bad(format!("{} settings: at most 10000", self.len()));
        }
        let max_level = u32::from(asset.header().geometry.camera_level);
        for &c in &self.cameras {
            match geometry::level_for_camera_count(c) {
                Some(l) if l <= max_level => {}
                _ => {
                    return bad(format!(
                        "cameras {c}: use 12, 42, 162 or 642, at most the asset's {}",
                        CAMERA_COUNTS[max_level.min(3) as usize]
                    ));
                }
            }
        }
        for &step in &self.steps {
            RenderOptions {
                step: Some(step),
                ..RenderOptions::default()
            }
            .resolve(max_level)
            .map_err(|e| TradeoffError::Grid(e.to_string()))?;
        }
        for &f in &self.tolerance_factors {
            if !(f.is_finite() && f > 0.0 && f <= 16.0) {
                return bad(format!(
                    "tolerance factor {f} must be finite and in (0, 16] steps"
                ));
            }
            for &step in &self.steps {
                let tolerance = f * step;
                if tolerance > 1.0 {
                    return bad(format!(
                        "tolerance {f} × step {step} exceeds 1 bounding diameter"
                    ));
                }
            }
        }
        let stored = stored_depth_bits(asset);
        for &b in &self.depth_bits {
            if b != 8 && b != 16 {
                return bad(format!("depth bits {b}: use 8 or 16"));
            }
            if b > stored {
                return bad("depth bits 16: the asset stores 8-bit depth".to_owned());
            }
        }
        for &s in &self.sizes {
            if s == 0 || s > 4096 {
                return bad(format!("size {s}: use 1 to 4096 pixels"));
            }
        }
        for &g in &self.guides {
            RenderOptions {
                guide: Some(g),
                ..RenderOptions::default()
            }
            .resolve(max_level)
            .map_err(|e| TradeoffError::Grid(e.to_string()))?;
        }
        Ok(())
    }
}

/// One setting of the sweep.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Setting {
    /// Cameras used.
    pub cameras: u32,
    /// Step, bounding diameters.
    pub step: f32,
    /// Tolerance, bounding diameters.
    pub tolerance: f32,
    /// Method.
    pub method: Method,
    /// Coarse-to-fine factor (0 = off).
    pub guide: u32,
    /// Depth precision, bits.
    pub depth_bits: u8,
    /// Output size, pixels (square).
    pub size: u32,
}

impl Setting {
    /// The render options of this setting.
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: Some(self.cameras),
            step: Some(self.step),
            tolerance: Some(self.tolerance),
            method: self.method,
            guide: Some(self.guide),
        }
    }
}

/// A measured setting.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Point {
    /// The setting.
    #[serde(flatten)]
    pub setting: Setting,
    /// Mean render time per frame, ms (dispatch + readback).
    pub ms_per_frame: f64,
    /// Mean texture fetches per pixel (counted by the shader).
    pub fetches_per_pixel: f64,
    /// Mean masked PSNR, dB (DESIGN §3).
    pub masked_psnr: f64,
    /// Mean PSNR over the whole frame, dB.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean number of pixels covered in one mask only.
    pub mask_mismatch_px: f64,
    /// Mean silhouette displacement, pixels: pixels covered in one mask only over the length
    /// of the reference silhouette ([`metrics::silhouette_px`]), summed over the views.
    pub silhouette_error_px: f64,
    /// Mean of the per-view median depth error, in bounding radii.
    pub depth_median_r: f64,
    /// On the Pareto front of (ms per frame ↓, masked PSNR ↑).
    pub pareto: bool,
}

/// What the sweep needs: the pipelines, the asset, the source mesh on the GPU and its shading.
pub struct SweepInputs<'a> {
    /// The light-field renderer.
    pub renderer: &'a Renderer,
    /// The reference rasterizer.
    pub reference: &'a ReferenceRenderer,
    /// The asset.
    pub asset: &'a AssetFile,
    /// The asset's source mesh, uploaded.
    pub mesh: &'a GpuMesh,
    /// The shading the asset was baked with.
    pub shading: &'a Shading,
    /// The views at unit size; each is rendered at every grid size (same eye and field of view).
    pub views: &'a [View],
    /// Renders per view and setting; the fastest is timed (all give the same image).
    pub repeats: u32,
}

/// Renders every setting of `grid`; `progress(done, total)` after each setting.
///
/// # Errors
/// [`TradeoffError`] for a bad grid or any failed render or comparison.
pub fn sweep(
    inputs: &SweepInputs<'_>,
    grid: &Grid,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<Point>, TradeoffError> {
    grid.validate(inputs.asset)?;
    if inputs.views.is_empty() {
        return Err(TradeoffError::Grid("no views".to_owned()));
    }
    let total = grid.len();
    let radius = inputs.asset.header().frame.radius;
    let mut points = Vec::with_capacity(total);
    for &bits in &grid.depth_bits {
        let field = inputs.renderer.upload_with(
            inputs.asset,
            &UploadOptions {
                depth_bits: Some(bits),
            },
        )?;
        for &size in &grid.sizes {
            let views: Vec<View> = inputs
                .views
                .iter()
                .map(|v| View {
                    width: size,
                    height: size,
                    ..v.clone()
                })
                .collect();
            let truths: Vec<Frame> = views
                .iter()
                .map(|v| inputs.reference.render(inputs.mesh, v, inputs.shading))
                .collect::<Result<_, _>>()?;
            // Warm-up: the first frame at a size allocates its targets.
            inputs
                .renderer
                .render(&field, &views[0], &RenderOptions::default())?;
            for &cameras in &grid.cameras {
                for &step in &grid.steps {
                    for &factor in &grid.tolerance_factors {
                        for &method in &grid.methods {
                            for guide in grid.guides_of(method) {
                                let setting = Setting {
                                    cameras,
                                    step,
                                    tolerance: factor * step,
                                    method,
                                    guide,
                                    depth_bits: bits,
                                    size,
                                };
                                points.push(measure(
                                    inputs, &field, &views, &truths, setting, radius,
                                )?);
                                progress(points.len(), total);
                            }
                        }
                    }
                }
            }
        }
    }
    let cost: Vec<f64> = points.iter().map(|p| p.ms_per_frame).collect();
    let quality: Vec<f64> = points.iter().map(|p| p.masked_psnr).collect();
    for (p, on) in points.iter_mut().zip(pareto_front(&cost, &quality)) {
        p.pareto = on;
    }
    Ok(points)
}

fn measure(
    inputs: &SweepInputs<'_>,
    field: &crate::render::GpuLightField,
    views: &[View],
    truths: &[Frame],
    setting: Setting,
    radius: f64,
) -> Result<Point, TradeoffError> {
    let options = setting.options();
    let mut comparisons: Vec<Comparison> = Vec::with_capacity(views.len());
    let (mut ms, mut fetches) = (0.0, 0.0);
    let (mut mismatch, mut silhouette) = (0_u64, 0_u64);
    for (view, truth) in views.iter().zip(truths) {
        let mut frame = inputs.renderer.render(field, view, &options)?;
        for _ in 1..inputs.repeats.max(1) {
            let again = inputs.renderer.render(field, view, &options)?;
            if again.stats.render_ms < frame.stats.render_ms {
                frame = again;
            }
        }
        ms += frame.stats.render_ms;
        fetches += frame.stats.fetches as f64 / frame.pixel_count().max(1) as f64;
        let comparison = metrics::compare(&frame, truth)?;
        mismatch += comparison.mask_mismatch_px;
        silhouette += metrics::silhouette_px(truth);
        comparisons.push(comparison);
    }
    let n = views.len() as f64;
    let mean = metrics::mean_comparison(&comparisons)
        .ok_or_else(|| TradeoffError::Grid("no views".to_owned()))?;
    Ok(Point {
        setting,
        ms_per_frame: ms / n,
        fetches_per_pixel: fetches / n,
        masked_psnr: mean.masked_psnr,
        psnr: mean.psnr,
        ssim: mean.ssim,
        mask_mismatch_px: mean.mask_mismatch_px,
        silhouette_error_px: mismatch as f64 / silhouette.max(1) as f64,
        depth_median_r: mean.depth.median / radius.max(f64::MIN_POSITIVE),
        pareto: false,
    })
}

/// Marks the points no other point dominates: point `i` is on the front unless some `j` has
/// `cost[j] ≤ cost[i]` and `quality[j] ≥ quality[i]`, one of them strictly. Points with a NaN
/// are never on the front and never dominate. Of exact duplicates, the first is kept.
pub fn pareto_front(cost: &[f64], quality: &[f64]) -> Vec<bool> {
    let n = cost.len().min(quality.len());
    let valid = |i: usize| !cost[i].is_nan() && !quality[i].is_nan();
    // Sort by cost ascending, then quality descending; sweep keeping the best quality so far.
    let mut order: Vec<usize> = (0..n).filter(|&i| valid(i)).collect();
    order.sort_by(|&a, &b| {
        cost[a]
            .total_cmp(&cost[b])
            .then(quality[b].total_cmp(&quality[a]))
            .then(a.cmp(&b))
    });
    let mut on = vec![false; cost.len()];
    let mut best = f64::NEG_INFINITY;
    for i in order {
        if quality[i] > best {
            on[i] = true;
            best = quality[i];
        }
    }
    on
}

/// The CSV header of [`write_csv`].
pub const CSV_HEADER: &str = "cameras,step,tolerance,method,guide,depth_bits,size,ms_per_frame,fetches_per_pixel,masked_psnr,psnr,ssim,mask_mismatch_px,silhouette_error_px,depth_median_r,pareto";

/// Writes the points as CSV (atomically; one row per setting, [`CSV_HEADER`] first).
///
/// # Errors
/// [`TradeoffError::Io`].
pub fn write_csv(path: &Path, points: &[Point]) -> Result<(), TradeoffError> {
    crate::atomic_write(path, |w| {
        writeln!(w, "{CSV_HEADER}")?;
        for p in points {
            let s = &p.setting;
            writeln!(
                w,
                "{},{},{},{},{},{},{},{:.3},{:.2},{:.3},{:.3},{:.5},{:.1},{:.4},{:.3e},{}",
                s.cameras,
                s.step,
                s.tolerance,
                s.method,
                s.guide,
                s.depth_bits,
                s.size,
                p.ms_per_frame,
                p.fetches_per_pixel,
                p.masked_psnr,
                p.psnr,
                p.ssim,
                p.mask_mismatch_px,
                p.silhouette_error_px,
                p.depth_median_r,
                p.pareto
            )?;
        }
        Ok::<(), std::io::Error>(())
    })
    .map_err(|source| TradeoffError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// A bake with its calibration attached (see [`bake_calibrated`]).
pub struct CalibratedBake {
    /// The encoded asset, calibration in its quality report.
    pub bytes: Vec<u8>,
    /// The calibration.
    pub calibration: Calibration,
    /// Bake time, ms.
    pub bake_ms: f64,
    /// Calibration time, ms.
    pub calibrate_ms: f64,
}

/// Bakes `mesh` in memory, measures its [`Calibration`] against the mesh and attaches it:
/// what `lumigraph bake`, the service's bakes and `bake_mesh(calibrate=True)` store.
///
/// # Errors
/// [`TradeoffError`] from the bake, the calibration renders or the re-encoding.
pub fn bake_calibrated(
    baker: &crate::bake::Baker,
    renderer: &Renderer,
    reference: &ReferenceRenderer,
    mesh: &crate::mesh::Mesh,
    options: &crate::bake::BakeOptions,
    source: &crate::asset::Provenance,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CalibratedBake, TradeoffError> {
    let start = std::time::Instant::now();
    let bytes = baker.bake_to_bytes(mesh, options, source, progress)?;
    let bake_ms = start.elapsed().as_secs_f64() * 1e3;
    let asset = AssetFile::from_bytes(bytes)?;
    let gpu_mesh = reference.upload(mesh)?;
    let calibration = Calibration::measure(
        renderer,
        reference,
        &asset,
        &gpu_mesh,
        &options.shading,
        &renderer.gpu().adapter_summary(),
        &mut |_, _| {},
    )?;
    let bytes = calibration.attach(&asset)?;
    Ok(CalibratedBake {
        bytes,
        calibration,
        bake_ms,
        calibrate_ms: start.elapsed().as_secs_f64() * 1e3 - bake_ms,
    })
}

/// Output size of the calibration renders (square, pixels).
pub const CALIBRATION_SIZE: u32 = 256;
/// Random orbit views per calibration setting.
pub const CALIBRATION_VIEWS: usize = 4;
/// Steps the calibration measures (bounding diameters).
pub const CALIBRATION_STEPS: [f32; 4] = [1.0 / 8.0, 1.0 / 16.0, 1.0 / 32.0, 1.0 / 64.0];

/// A scene's error against cost, measured at bake time (issue #5 item 5) and stored in the
/// asset's quality report under `"calibration"`: the default method at every camera count the
/// asset holds × [`CALIBRATION_STEPS`], on [`CALIBRATION_VIEWS`] random orbit views of
/// [`CALIBRATION_SIZE`]².
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Calibration frame side, pixels.
    pub size: u32,
    /// Views per setting.
    pub views: usize,
    /// The adapter the times were measured on.
    pub adapter: String,
    /// One point per setting.
    pub points: Vec<CalibrationPoint>,
}

/// One calibrated setting.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationPoint {
    /// Cameras.
    pub cameras: u32,
    /// Step, bounding diameters (tolerance: step / 2).
    pub step: f32,
    /// Mean render time per million pixels, ms.
    pub ms_per_mpx: f64,
    /// Mean masked PSNR, dB.
    pub masked_psnr: f64,
    /// Mean median depth error, bounding radii.
    pub depth_median_r: f64,
    /// Mean silhouette displacement in bounding-sphere diameters: the calibration's
    /// [`Point::silhouette_error_px`] over the bounding sphere's projected diameter in its
    /// views. Times an object's projected diameter in pixels, it predicts the setting's
    /// silhouette error in pixels (what automatic LOD bounds, [`crate::lod`]). Absent in
    /// calibrations made before it was measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub silhouette_error: Option<f64>,
}

/// What a render should meet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Goal {
    /// The cheapest setting predicted to reach this masked PSNR (dB).
    TargetPsnr(f64),
    /// The most accurate setting predicted to fit this time per frame (ms).
    BudgetMs(f64),
}

impl Goal {
    /// The goal of an optional target PSNR and an optional time budget (at most one).
    ///
    /// # Errors
    /// [`TradeoffError::Goal`] when both are given. The values themselves are checked by
    /// [`Calibration::choose`].
    pub fn from_pair(
        target_psnr: Option<f64>,
        budget_ms: Option<f64>,
    ) -> Result<Option<Goal>, TradeoffError> {
        match (target_psnr, budget_ms) {
            (Some(_), Some(_)) => Err(TradeoffError::Goal(
                "give target_psnr or budget_ms, not both".to_owned(),
            )),
            (Some(db), None) => Ok(Some(Goal::TargetPsnr(db))),
            (None, Some(ms)) => Ok(Some(Goal::BudgetMs(ms))),
            (None, None) => Ok(None),
        }
    }
}

/// The setting chosen for a goal, with its predictions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Choice {
    /// Cameras.
    pub cameras: u32,
    /// Step, bounding diameters.
    pub step: f32,
    /// Predicted masked PSNR, dB (the calibrated value; masked PSNR barely depends on the
    /// output size: ±0.15 dB between 256² and 512² in BENCHMARKS.md).
    pub predicted_psnr: f64,
    /// Predicted ms per frame at the requested size (calibrated ms per pixel × pixels).
    pub predicted_ms: f64,
    /// Whether some setting was predicted to meet the goal (else the closest one is chosen).
    pub met: bool,
}

impl Choice {
    /// The render options of the choice (default method, tolerance step / 2).
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: Some(self.cameras),
            step: Some(self.step),
            tolerance: None,
            method: Method::Default,
            guide: None,
        }
    }
}

impl Calibration {
    /// Measures the calibration of `inputs.asset` (its views are replaced by the calibration
    /// views around the asset's bounding sphere).
    ///
    /// # Errors
    /// [`TradeoffError`] from the sweep.
    pub fn measure(
        renderer: &Renderer,
        reference: &ReferenceRenderer,
        asset: &AssetFile,
        mesh: &GpuMesh,
        shading: &Shading,
        adapter: &str,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Calibration, TradeoffError> {
        let frame = &asset.header().frame;
        let views = crate::view::random_orbit_views(
            frame.center,
            2.5 * frame.radius,
            CALIBRATION_VIEWS,
            0,
            40.0,
            CALIBRATION_SIZE,
        );
        let max_level = usize::from(asset.header().geometry.camera_level).min(3);
        let grid = Grid {
            cameras: CAMERA_COUNTS[..=max_level].to_vec(),
            steps: CALIBRATION_STEPS.to_vec(),
            tolerance_factors: vec![0.5],
            methods: vec![Method::Default],
            guides: vec![DEFAULT_GUIDE],
            depth_bits: vec![stored_depth_bits(asset)],
            sizes: vec![CALIBRATION_SIZE],
        };
        let inputs = SweepInputs {
            renderer,
            reference,
            asset,
            mesh,
            shading,
            views: &views,
            repeats: 1,
        };
        let mpx = f64::from(CALIBRATION_SIZE).powi(2) / 1e6;
        let projected = crate::lod::projected_diameter_px(
            &views[0].basis(u32::MAX).map_err(RenderError::from)?,
            frame.center.into(),
            frame.radius,
        );
        let points = sweep(&inputs, &grid, progress)?
            .into_iter()
            .map(|p| CalibrationPoint {
                cameras: p.setting.cameras,
                step: p.setting.step,
                ms_per_mpx: p.ms_per_frame / mpx,
                masked_psnr: p.masked_psnr,
                depth_median_r: p.depth_median_r,
                silhouette_error: Some(p.silhouette_error_px / projected),
            })
            .collect();
        Ok(Calibration {
            size: CALIBRATION_SIZE,
            views: CALIBRATION_VIEWS,
            adapter: adapter.to_owned(),
            points,
        })
    }

    /// The asset with this calibration in its quality report (under `"calibration"`, other
    /// keys kept), re-encoded in memory.
    ///
    /// # Errors
    /// [`AssetError`] for an unreadable page or a header over the format's limit.
    pub fn attach(&self, asset: &AssetFile) -> Result<Vec<u8>, AssetError> {
        let mut header = asset.header().clone();
        let mut quality = match header.quality.take() {
            Some(serde_json::Value::Object(map)) => map,
            _ => serde_json::Map::new(),
        };
        quality.insert(
            "calibration".to_owned(),
            serde_json::to_value(self).map_err(|e| AssetError::Header(e.to_string()))?,
        );
        header.quality = Some(serde_json::Value::Object(quality));
        let mut keys: Vec<crate::asset::ImageKey> = asset.index().iter().map(|e| e.key).collect();
        keys.sort_unstable();
        keys.dedup();
        let images = keys
            .into_iter()
            .map(|k| asset.read_image(k).map(|bytes| (k, bytes)))
            .collect::<Result<Vec<_>, _>>()?;
        crate::asset::encode_asset(header, images)
    }

    /// The calibration in an asset's quality report, if any.
    ///
    /// # Errors
    /// [`TradeoffError::Goal`] when a report is there but malformed.
    pub fn from_quality(
        quality: Option<&serde_json::Value>,
    ) -> Result<Option<Calibration>, TradeoffError> {
        match quality.and_then(|q| q.get("calibration")) {
            None => Ok(None),
            Some(value) => serde_json::from_value(value.clone())
                .map(Some)
                .map_err(|e| TradeoffError::Goal(format!("malformed calibration: {e}"))),
        }
    }

    /// Picks the setting for `goal` at `width × height` among points with at most
    /// `max_cameras` cameras.
    ///
    /// # Errors
    /// [`TradeoffError::Goal`] for a non-finite or non-positive goal, or no usable point.
    pub fn choose(
        &self,
        goal: Goal,
        width: u32,
        height: u32,
        max_cameras: u32,
    ) -> Result<Choice, TradeoffError> {
        match goal {
            Goal::TargetPsnr(db) if !(db.is_finite() && db > 0.0) => {
                return Err(TradeoffError::Goal(format!(
                    "target PSNR {db} dB must be finite and positive"
                )));
            }
            Goal::BudgetMs(ms) if !(ms.is_finite() && ms > 0.0) => {
                return Err(TradeoffError::Goal(format!(
                    "budget {ms} ms must be finite and positive"
                )));
            }
            _ => {}
        }
        let mpx = f64::from(width) * f64::from(height) / 1e6;
        let usable: Vec<(CalibrationPoint, f64)> = self
            .points
            .iter()
            .filter(|p| {
                p.cameras <= max_cameras
                    && p.ms_per_mpx.is_finite()
                    && p.masked_psnr.is_finite()
                    && RenderOptions {
                        step: Some(p.step),
                        ..RenderOptions::default()
                    }
                    .resolve(3)
                    .is_ok()
            })
            .map(|p| (*p, p.ms_per_mpx * mpx))
            .collect();
        let by_ms =
            |a: &&(CalibrationPoint, f64), b: &&(CalibrationPoint, f64)| a.1.total_cmp(&b.1);
        let by_psnr = |a: &&(CalibrationPoint, f64), b: &&(CalibrationPoint, f64)| {
            a.0.masked_psnr.total_cmp(&b.0.masked_psnr)
        };
        let (pick, met) = match goal {
            Goal::TargetPsnr(db) => {
                match usable
                    .iter()
                    .filter(|(p, _)| p.masked_psnr >= db)
                    .min_by(by_ms)
                {
                    Some(p) => (Some(p), true),
                    None => (usable.iter().max_by(by_psnr), false),
                }
            }
            Goal::BudgetMs(ms) => match usable.iter().filter(|(_, t)| *t <= ms).max_by(by_psnr) {
                Some(p) => (Some(p), true),
                None => (usable.iter().min_by(by_ms), false),
            },
        };
        let (point, predicted_ms) = pick.ok_or_else(|| {
            TradeoffError::Goal("the calibration holds no usable setting".to_owned())
        })?;
        Ok(Choice {
            cameras: point.cameras,
            step: point.step,
            predicted_psnr: point.masked_psnr,
            predicted_ms: *predicted_ms,
            met,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calibration() -> Calibration {
        let point = |cameras, step, ms_per_mpx, masked_psnr| CalibrationPoint {
            cameras,
            step,
            ms_per_mpx,
            masked_psnr,
            depth_median_r: 1e-3,
            silhouette_error: None,
        };
        Calibration {
            size: 256,
            views: 4,
            adapter: "test".to_owned(),
            points: vec![
                point(12, 1.0 / 16.0, 500.0, 23.0),
                point(42, 1.0 / 16.0, 600.0, 25.5),
                point(162, 1.0 / 16.0, 700.0, 26.0),
                point(162, 1.0 / 32.0, 900.0, 27.0),
                point(642, 1.0 / 64.0, 2000.0, 28.0),
            ],
        }
    }

    #[test]
    fn calibration_picks_the_cheapest_setting_for_a_target() {
        let c = calibration();
        // 512² = 0.262144 Mpx.
        let pick = c
            .choose(Goal::TargetPsnr(25.8), 512, 512, 162)
            .expect("choice");
        assert_eq!((pick.cameras, pick.step, pick.met), (162, 1.0 / 16.0, true));
        assert!((pick.predicted_ms - 700.0 * 0.262_144).abs() < 1e-9);
        // Unreachable with 162 cameras: the best there is, flagged.
        let pick = c
            .choose(Goal::TargetPsnr(27.5), 512, 512, 162)
            .expect("choice");
        assert_eq!((pick.cameras, pick.met), (162, false));
        assert_eq!(pick.predicted_psnr, 27.0);
        // With 642 cameras in the asset it is reachable.
        let pick = c
            .choose(Goal::TargetPsnr(27.5), 512, 512, 642)
            .expect("choice");
        assert_eq!((pick.cameras, pick.met), (642, true));
    }

    #[test]
    fn calibration_picks_the_best_setting_within_a_budget() {
        let c = calibration();
        // 200 ms at 512²: up to 762 ms/Mpx → 162 cameras at 1/16 (700).
        let pick = c
            .choose(Goal::BudgetMs(200.0), 512, 512, 642)
            .expect("choice");
        assert_eq!((pick.cameras, pick.step, pick.met), (162, 1.0 / 16.0, true));
        // A smaller frame affords more.
        let pick = c
            .choose(Goal::BudgetMs(200.0), 256, 256, 642)
            .expect("choice");
        assert_eq!((pick.cameras, pick.met), (642, true));
        // Too tight: the fastest, flagged.
        let pick = c
            .choose(Goal::BudgetMs(1.0), 512, 512, 642)
            .expect("choice");
        assert_eq!((pick.cameras, pick.met), (12, false));
        assert_eq!(
            Goal::from_pair(Some(20.0), None).expect("one"),
            Some(Goal::TargetPsnr(20.0))
        );
        assert_eq!(Goal::from_pair(None, None).expect("none"), None);
        assert!(Goal::from_pair(Some(20.0), Some(5.0)).is_err());
        for bad in [
            Goal::BudgetMs(0.0),
            Goal::BudgetMs(f64::NAN),
            Goal::TargetPsnr(-3.0),
            Goal::TargetPsnr(f64::INFINITY),
        ] {
            assert!(c.choose(bad, 512, 512, 642).is_err(), "{bad:?}");
        }
        // Stored and read back through the quality report.
        let q = serde_json::json!({"calibration": serde_json::to_value(&c).expect("json")});
        assert_eq!(Calibration::from_quality(Some(&q)).expect("ok"), Some(c));
        assert_eq!(Calibration::from_quality(None).expect("ok"), None);
        let bad = serde_json::json!({"calibration": {"size": "x"}});
        assert!(Calibration::from_quality(Some(&bad)).is_err());
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        //            0     1     2     3     4     5
        let cost = [10.0, 20.0, 15.0, 30.0, 20.0, 5.0];
        let quality = [20.0, 25.0, 19.0, 24.0, 25.0, 10.0];
        // 2 is dominated by 0 (cheaper and better); 3 by 1; 4 duplicates 1 (first kept).
        assert_eq!(
            pareto_front(&cost, &quality),
            vec![true, true, false, false, false, true]
        );
    }

    #[test]
    fn pareto_front_ignores_nan_and_handles_edges() {
        assert!(pareto_front(&[], &[]).is_empty());
        assert_eq!(pareto_front(&[1.0], &[1.0]), vec![true]);
        // A NaN point neither joins nor blocks the front; an infinite PSNR (identical
        // images) is the best quality there is.
        let on = pareto_front(
            &[1.0, f64::NAN, 2.0, 3.0],
            &[5.0, 100.0, 6.0, f64::INFINITY],
        );
        assert_eq!(on, vec![true, false, true, true]);
        // Equal cost: only the better quality survives.
        assert_eq!(pareto_front(&[1.0, 1.0], &[2.0, 3.0]), vec![false, true]);
    }

    #[test]
    fn pareto_front_matches_brute_force() {
        // Against the definition, on pseudo-random points with many ties.
        let mut raw = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = || (raw() % 16) as f64;
        for _ in 0..200 {
            let n = 12;
            let cost: Vec<f64> = (0..n).map(|_| next()).collect();
            let quality: Vec<f64> = (0..n).map(|_| next()).collect();
            let on = pareto_front(&cost, &quality);
            for i in 0..n {
                let dominated = (0..n).any(|j| {
                    j != i
                        && cost[j] <= cost[i]
                        && quality[j] >= quality[i]
                        && (cost[j] < cost[i] || quality[j] > quality[i])
                });
                let duplicate_before =
                    (0..i).any(|j| cost[j] == cost[i] && quality[j] == quality[i]);
                assert_eq!(
                    on[i],
                    !dominated && !duplicate_before,
                    "{cost:?} {quality:?}"
                );
            }
        }
    }
}
