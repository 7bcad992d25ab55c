//! The speed/accuracy trade-off sweep (`lumigraph bench tradeoff`).
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

use crate::asset::{AssetFile, Channel, Encoding};
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
pub(crate) fn stored_depth_bits(asset: &AssetFile) -> u8 {
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
        let max_level = usize::from(asset.header().camera_level().unwrap_or(0)).min(3);
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
        let max_level = u32::from(asset.header().camera_level().unwrap_or(0));
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
            light: None,
            state: None,
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
                // The sweep measures the base state only.
                base_state_only: true,
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

#[cfg(test)]
mod tests {
    use super::*;

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
