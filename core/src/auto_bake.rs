//! A bake that models only what the scene requires (`lumigraph bake --auto`).
//!
//! [`calibrate`] bakes the scene thrice at low resolution ([`CALIBRATION_RESOLUTIONS`], all 642
//! cameras, whose first 12/42/162 are the coarser sets) and renders every camera count × depth
//! precision (8-bit depth by requantizing at upload) on [`AUTO_VIEWS`] calibration views against
//! the rasterized mesh, with the render knobs at their defaults. [`QualityModel::fit`] turns the
//! measurements into a model of masked PSNR and asset bytes over the whole grid of settings:
//!
//! - quality, per camera count C and depth precision b: the mean squared error of the masked
//!   PSNR `MSE = 255² · 10^(−PSNR/10)` falls with map resolution N as
//!   `MSE(N) = floor_{C,b} + scale_{C,b} · N^−γ_{C,b}` (the floor is what the camera count
//!   leaves: parallax between cameras, shading not in the maps; the `N^−γ` term is the
//!   silhouette band and texel interpolation). Three resolutions fix the three terms per
//!   curve: γ from the ratio of the error drops, then floor and scale through the two higher
//!   points. γ is not universal: on the cow from 64 to 384 px it measured 1.5 at 12 cameras,
//!   1.2 at 42 and 1.0 at 162, so a fixed exponent mispredicts by up to 0.5 dB at 2× the
//!   calibration resolution.
//! - size, per camera count and depth precision: the stored bytes of the first C cameras grow
//!   as `k · N^p` between the two calibration resolutions (zstd pages compress better as maps
//!   grow, so p < 2).
//!
//! [`QualityModel::choose`] serves an [`AutoTarget`] from the model: the fewest predicted bytes
//! reaching a target masked PSNR, or the best predicted masked PSNR within a byte budget; a
//! target no setting meets gets the closest setting with [`Reach`] saying which way it missed.
//! [`auto_bake`] then bakes that setting alone. For a target PSNR it measures the bake on
//! [`AUTO_TUNING_VIEWS`] tuning views, and when that lies outside [`TUNING_BAND_DB`] of the
//! target it corrects the model by the measured error ([`QualityModel::choose_corrected`]) and
//! bakes the corrected choice, at most [`MAX_AUTO_BAKES`] bakes in all. The kept bake is
//! measured on [`AUTO_VIEWS`] held-out views used by neither the calibration nor the tuning, so
//! its report says how well the model and its correction predicted.
//!
//! Views ([`auto_views`]): a masked PSNR differs by ±2.5 dB from one random orbit view to the
//! next (silhouette length), so two sets of 12 random views can differ by 2 dB in their mean.
//! The calibration and held-out sets are therefore the even and odd points of one Fibonacci
//! spiral on the evaluation sphere: disjoint, interleaved, each covering the sphere evenly; the
//! tuning set is a spiral of its own, turned against that one.

use serde::{Deserialize, Serialize};

use crate::asset::{AssetFile, Channel, Provenance};
use crate::bake::{BakeError, BakeOptions, Baker};
use crate::frame::Frame;
use crate::geometry::CAMERA_COUNTS;
use crate::gpu::mesh::GpuMesh;
use crate::mesh::Mesh;
use crate::metrics::{self, MetricsError};
use crate::reference::{ReferenceError, ReferenceRenderer};
use crate::render::{RenderError, RenderOptions, Renderer, UploadOptions};
use crate::shading::Shading;
use crate::view::{EVALUATION_DISTANCE_RADII, EVALUATION_YFOV_DEG, View};

/// Map resolutions of the two calibration bakes, pixels.
pub const CALIBRATION_RESOLUTIONS: [u32; 3] = [64, 128, 192];
/// Cameras baked at 8-bit depth to measure how that depth compresses (their first this many).
pub const DEPTH8_SIZE_CAMERAS: u32 = 42;
/// Smallest map resolution the choice considers, pixels.
pub const AUTO_MIN_RESOLUTION: u32 = 64;
/// Largest map resolution the choice considers, pixels: twice the highest calibration
/// resolution, as far as the model is trusted to extrapolate.
pub const AUTO_MAX_RESOLUTION: u32 = 384;
/// Spacing of the map resolutions the choice considers, pixels.
pub const AUTO_RESOLUTION_STEP: u32 = 16;
/// Exponent γ of the resolution term of the quality model when the three calibration points
/// do not determine one (error not falling, or not convex in `N^−γ`).
pub const DEFAULT_RESOLUTION_EXPONENT: f64 = 1.25;
/// Range of the fitted exponent γ.
pub const RESOLUTION_EXPONENT_RANGE: (f64, f64) = (0.5, 2.5);
/// Views of the calibration, and again of the held-out measurement.
pub const AUTO_VIEWS: usize = 24;
/// Side of the calibration and held-out views, pixels (the evaluation default).
pub const AUTO_VIEW_SIZE: u32 = 256;
/// How close to a target PSNR the measured masked PSNR must land for the target to count as
/// met, dB (the acceptance bound).
pub const TARGET_TOLERANCE_DB: f64 = 0.5;
/// How far above a target PSNR the first choice aims, dB. Measured on held-out views, the model
/// erred by −0.71…+0.59 dB over the dev meshes and the demo (extrapolation beyond the
/// calibration resolutions; the view sets); the tuning loop corrects the rest.
pub const PREDICTION_MARGIN_DB: f64 = 0.2;
/// Views of the tuning measurement: a third view set, disjoint from the calibration and the
/// held-out ones, on which each bake of a target PSNR is measured to correct the model.
pub const AUTO_TUNING_VIEWS: usize = 40;
/// Most bakes for a target PSNR: the model's choice and up to two corrected ones.
pub const MAX_AUTO_BAKES: usize = 3;
/// Where a bake's tuning measurement must lie, relative to the target PSNR, dB, for it to be
/// kept without a correction: inside the acceptance bound by a margin for the difference between
/// the tuning and held-out view sets.
pub const TUNING_BAND_DB: (f64, f64) = (-0.1, 0.35);
/// How far above the target a corrected choice aims, dB (the middle of [`TUNING_BAND_DB`]).
pub const CORRECTED_MARGIN_DB: f64 = 0.12;
/// Target masked PSNR of `--auto` when no target is given, dB.
pub const DEFAULT_TARGET_PSNR: f64 = 27.0;
/// Highest target PSNR accepted, dB (the metrics cap a view's PSNR at 100 dB).
pub const MAX_TARGET_PSNR: f64 = 100.0;

const PEAK_SQUARED: f64 = 255.0 * 255.0;

/// Errors of the automatic bake.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AutoBakeError {
    /// Both a target PSNR and a byte budget were given.
    #[error("give a target PSNR or a byte budget (max bytes), not both")]
    ConflictingTargets,
    /// A target PSNR that is not a finite number in (0, 100] dB.
    #[error("target PSNR {0} dB must be a finite number above 0 and at most 100")]
    TargetPsnr(f64),
    /// A byte budget of zero.
    #[error("max bytes must be at least 1")]
    MaxBytes,
    /// The calibration measured nothing usable (no view saw the mesh, or a sample is missing).
    #[error("the calibration could not measure {0}")]
    Unmeasurable(String),
    /// A bake failed.
    #[error(transparent)]
    Bake(#[from] BakeError),
    /// A render failed.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// A reference render failed.
    #[error(transparent)]
    Reference(#[from] ReferenceError),
    /// A comparison failed.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// A baked asset could not be read back.
    #[error(transparent)]
    Asset(#[from] crate::asset::AssetError),
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// The render calibration of the chosen bake failed.
    #[error(transparent)]
    Calibration(#[from] crate::calibration::CalibrationError),
}

/// What the automatic bake aims for.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutoTarget {
    /// The fewest bytes whose masked PSNR reaches this many dB.
    TargetPsnr(f64),
    /// The best masked PSNR within this many asset bytes.
    MaxBytes(u64),
}

impl AutoTarget {
    /// The target of the optional flags: at most one; none is [`DEFAULT_TARGET_PSNR`].
    ///
    /// # Errors
    /// [`AutoBakeError::ConflictingTargets`] for both; the value errors of [`Self::validate`].
    pub fn from_flags(
        target_psnr: Option<f64>,
        max_bytes: Option<u64>,
    ) -> Result<AutoTarget, AutoBakeError> {
        let target = match (target_psnr, max_bytes) {
            (Some(_), Some(_)) => return Err(AutoBakeError::ConflictingTargets),
            (Some(db), None) => AutoTarget::TargetPsnr(db),
            (None, Some(bytes)) => AutoTarget::MaxBytes(bytes),
            (None, None) => AutoTarget::TargetPsnr(DEFAULT_TARGET_PSNR),
        };
        target.validate()?;
        Ok(target)
    }

    /// Checks the value.
    ///
    /// # Errors
    /// [`AutoBakeError::TargetPsnr`] (NaN, infinite, ≤ 0 or > 100 dB), [`AutoBakeError::MaxBytes`]
    /// (zero).
    pub fn validate(self) -> Result<(), AutoBakeError> {
        match self {
            AutoTarget::TargetPsnr(db)
                if !(db.is_finite() && db > 0.0 && db <= MAX_TARGET_PSNR) =>
            {
                Err(AutoBakeError::TargetPsnr(db))
            }
            AutoTarget::MaxBytes(0) => Err(AutoBakeError::MaxBytes),
            _ => Ok(()),
        }
    }
}

/// One calibration measurement of quality.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct QualitySample {
    /// Cameras rendered.
    pub cameras: u32,
    /// Map resolution baked, pixels.
    pub resolution: u32,
    /// Depth precision rendered.
    pub depth_bits: u8,
    /// Mean masked PSNR over the calibration views, dB.
    pub masked_psnr: f64,
}

/// One calibration measurement of size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SizeSample {
    /// Cameras counted (the first this many of the bake).
    pub cameras: u32,
    /// Map resolution baked, pixels.
    pub resolution: u32,
    /// Depth precision.
    pub depth_bits: u8,
    /// Stored bytes of those cameras' pages plus their share of header and index.
    pub bytes: f64,
}

/// `MSE(N) = floor + scale · N^−γ` of one camera count and depth precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct QualityCurve {
    /// Cameras.
    pub cameras: u32,
    /// Depth precision.
    pub depth_bits: u8,
    /// Exponent γ of the resolution term.
    pub exponent: f64,
    /// Error left at infinite resolution, squared 8-bit steps (≥ 0).
    pub floor_mse: f64,
    /// Coefficient of `N^−γ` (≥ 0).
    pub scale: f64,
}

impl QualityCurve {
    /// Fits the curve through three (resolution, masked PSNR) points of increasing resolution:
    /// γ such that the model's error drops between them have the measured ratio (bisection
    /// over [`RESOLUTION_EXPONENT_RANGE`], [`DEFAULT_RESOLUTION_EXPONENT`] when the drops are
    /// not both positive), then floor and scale through the two higher points. The curve never
    /// rises in error with resolution, and the floor is never negative (either bound taken
    /// through the highest point).
    fn fit(cameras: u32, depth_bits: u8, points: [(u32, f64); 3]) -> QualityCurve {
        let mse = |db: f64| PEAK_SQUARED * 10f64.powf(-db / 10.0);
        let [(n0, m0), (n1, m1), (n2, m2)] = points.map(|(n, db)| (f64::from(n), mse(db)));
        let exponent = {
            let measured = (m0 - m1) / (m1 - m2);
            // (n0^−γ − n1^−γ) / (n1^−γ − n2^−γ) grows with γ.
            let model = |g: f64| (n0.powf(-g) - n1.powf(-g)) / (n1.powf(-g) - n2.powf(-g));
            let (mut lo, mut hi) = RESOLUTION_EXPONENT_RANGE;
            if !(m0 > m1 && m1 > m2 && measured.is_finite()) {
                DEFAULT_RESOLUTION_EXPONENT
            } else if measured <= model(lo) {
                lo
            } else if measured >= model(hi) {
                hi
            } else {
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if model(mid) < measured {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            }
        };
        let (t1, t2) = (n1.powf(-exponent), n2.powf(-exponent));
        let mut scale = (m1 - m2) / (t1 - t2);
        let mut floor = m2 - scale * t2;
        if !(scale >= 0.0) {
            scale = 0.0;
            floor = m2;
        } else if floor < 0.0 {
            floor = 0.0;
            scale = m2 / t2;
        }
        QualityCurve {
            cameras,
            depth_bits,
            exponent,
            floor_mse: floor,
            scale,
        }
    }

    /// Predicted masked PSNR at `resolution`, dB (capped like the metrics, at 100 dB).
    pub fn psnr(&self, resolution: u32) -> f64 {
        let mse = self.floor_mse + self.scale * f64::from(resolution).powf(-self.exponent);
        (10.0 * (PEAK_SQUARED / mse).log10()).min(MAX_TARGET_PSNR)
    }
}

/// `bytes(N) = k · N^p` of one camera count and depth precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SizeCurve {
    /// Cameras.
    pub cameras: u32,
    /// Depth precision.
    pub depth_bits: u8,
    /// Bytes at 1 px.
    pub k: f64,
    /// Exponent, clamped to [1, 2.5] (pages cannot shrink with resolution, nor grow faster than
    /// their texels and index).
    pub p: f64,
}

impl SizeCurve {
    fn fit(cameras: u32, depth_bits: u8, low: (u32, f64), high: (u32, f64)) -> SizeCurve {
        let p =
            ((high.1 / low.1).ln() / (f64::from(high.0) / f64::from(low.0)).ln()).clamp(1.0, 2.5);
        let p = if p.is_finite() { p } else { 2.0 };
        SizeCurve {
            cameras,
            depth_bits,
            k: high.1 / f64::from(high.0).powf(p),
            p,
        }
    }

    /// Predicted asset bytes at `resolution`.
    pub fn bytes(&self, resolution: u32) -> u64 {
        (self.k * f64::from(resolution).powf(self.p)).round() as u64
    }
}

/// The model of masked PSNR and bytes over the settings (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct QualityModel {
    /// One quality curve per camera count × depth precision.
    pub quality: Vec<QualityCurve>,
    /// One size curve per camera count × depth precision.
    pub size: Vec<SizeCurve>,
}

/// One setting with its predictions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Prediction {
    /// Cameras.
    pub cameras: u32,
    /// Map resolution, pixels.
    pub resolution: u32,
    /// Depth precision.
    pub depth_bits: u8,
    /// Predicted masked PSNR on views like the calibration's, dB.
    pub predicted_psnr: f64,
    /// Predicted asset bytes.
    pub predicted_bytes: u64,
}

impl Prediction {
    /// The bake options of this setting with `shading`.
    pub fn bake_options(&self, shading: Shading) -> BakeOptions {
        BakeOptions {
            cameras: self.cameras,
            resolution: self.resolution,
            shading,
            depth_bits: self.depth_bits,
            lights: None,
            one_sided: false,
            color_codec: None,
            depth_codec: None,
        }
    }
}

/// Where the target lies against what the settings reach.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reach {
    /// Some setting is predicted to meet the target closely.
    Within,
    /// The target PSNR is above every setting's prediction: the best one is chosen.
    AboveBest,
    /// The target PSNR is below even the smallest setting's prediction: the smallest one is
    /// chosen, and overshoots.
    BelowSmallest,
    /// The byte budget is below the smallest setting's predicted size: the smallest one is
    /// chosen, and exceeds it.
    BudgetTooSmall,
}

/// The chosen setting.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AutoChoice {
    /// The setting and the model's predictions.
    pub setting: Prediction,
    /// Correction added to the model's PSNR prediction from the tuning measurements of earlier
    /// bakes of this scene, dB (0 for the model's own choice).
    pub correction_db: f64,
    /// Where the target lies; anything but [`Reach::Within`] is the closest setting.
    pub reach: Reach,
}

impl AutoChoice {
    /// A sentence for a target outside what any setting reaches, naming the closest setting.
    pub fn message(&self, target: AutoTarget) -> Option<String> {
        let s = &self.setting;
        let what = format!(
            "{} cameras, {} px, {}-bit depth: {:.2} dB, {} bytes predicted",
            s.cameras,
            s.resolution,
            s.depth_bits,
            s.predicted_psnr + self.correction_db,
            s.predicted_bytes
        );
        match (self.reach, target) {
            (Reach::Within, _) => None,
            (Reach::AboveBest, AutoTarget::TargetPsnr(db)) => Some(format!(
                "target {db} dB is above what any setting reaches for this scene; baked the best \
                 ({what})"
            )),
            (Reach::BelowSmallest, AutoTarget::TargetPsnr(db)) => Some(format!(
                "target {db} dB is below what the smallest setting reaches for this scene; baked \
                 the smallest ({what})"
            )),
            (Reach::BudgetTooSmall, AutoTarget::MaxBytes(bytes)) => Some(format!(
                "max bytes {bytes} is below the smallest setting's size for this scene; baked the \
                 smallest ({what})"
            )),
            (reach, _) => Some(format!("{reach:?}: baked {what}")),
        }
    }
}

/// The map resolutions the choice considers.
pub fn candidate_resolutions() -> impl Iterator<Item = u32> {
    (AUTO_MIN_RESOLUTION..=AUTO_MAX_RESOLUTION).step_by(AUTO_RESOLUTION_STEP as usize)
}

impl QualityModel {
    /// Fits the model to calibration samples: for every camera count × depth precision with
    /// samples at every one of [`CALIBRATION_RESOLUTIONS`], one quality curve and one size
    /// curve (a power law through the two higher resolutions).
    ///
    /// # Errors
    /// [`AutoBakeError::Unmeasurable`] when a sample is missing or not finite and positive.
    pub fn fit(
        quality: &[QualitySample],
        size: &[SizeSample],
    ) -> Result<QualityModel, AutoBakeError> {
        let [low, mid, high] = CALIBRATION_RESOLUTIONS;
        let mut model = QualityModel {
            quality: Vec::new(),
            size: Vec::new(),
        };
        for cameras in CAMERA_COUNTS {
            for depth_bits in [8, 16] {
                let what = |kind: &str, n: u32| {
                    AutoBakeError::Unmeasurable(format!(
                        "the {kind} of {cameras} cameras at {n} px with {depth_bits}-bit depth \
                         (do the calibration views see the mesh?)"
                    ))
                };
                let psnr_at = |n: u32| {
                    quality
                        .iter()
                        .find(|s| {
                            (s.cameras, s.resolution, s.depth_bits) == (cameras, n, depth_bits)
                        })
                        .map(|s| s.masked_psnr)
                        .filter(|db| db.is_finite() && *db > 0.0)
                        .ok_or_else(|| what("masked PSNR", n))
                };
                let bytes_at = |n: u32| {
                    size.iter()
                        .find(|s| {
                            (s.cameras, s.resolution, s.depth_bits) == (cameras, n, depth_bits)
                        })
                        .map(|s| s.bytes)
                        .filter(|b| b.is_finite() && *b > 0.0)
                        .ok_or_else(|| what("size", n))
                };
                model.quality.push(QualityCurve::fit(
                    cameras,
                    depth_bits,
                    [
                        (low, psnr_at(low)?),
                        (mid, psnr_at(mid)?),
                        (high, psnr_at(high)?),
                    ],
                ));
                model.size.push(SizeCurve::fit(
                    cameras,
                    depth_bits,
                    (mid, bytes_at(mid)?),
                    (high, bytes_at(high)?),
                ));
            }
        }
        Ok(model)
    }

    /// Every setting the choice considers, with its predictions.
    pub fn predictions(&self) -> Vec<Prediction> {
        let mut out = Vec::new();
        for (quality, size) in self.quality.iter().zip(&self.size) {
            for resolution in candidate_resolutions() {
                out.push(Prediction {
                    cameras: quality.cameras,
                    resolution,
                    depth_bits: quality.depth_bits,
                    predicted_psnr: quality.psnr(resolution),
                    predicted_bytes: size.bytes(resolution),
                });
            }
        }
        out
    }

    /// The setting for `target`: the fewest predicted bytes whose prediction reaches a target
    /// PSNR plus [`PREDICTION_MARGIN_DB`] (ties: the higher PSNR), or the highest predicted PSNR
    /// within a byte budget (ties: fewer bytes). Outside what any setting reaches: the closest
    /// setting, with its [`Reach`] (above the best when no prediction reaches the target itself).
    ///
    /// # Errors
    /// The value errors of [`AutoTarget::validate`]; [`AutoBakeError::Unmeasurable`] for an
    /// empty model.
    pub fn choose(&self, target: AutoTarget) -> Result<AutoChoice, AutoBakeError> {
        self.choose_corrected(target, PREDICTION_MARGIN_DB, &|_| 0.0)
    }

    /// [`Self::choose`] with `correction` (dB, per setting) added to every PSNR prediction and
    /// the target PSNR aimed at `margin` above.
    ///
    /// # Errors
    /// As [`Self::choose`].
    pub fn choose_corrected(
        &self,
        target: AutoTarget,
        margin: f64,
        correction: &dyn Fn(&Prediction) -> f64,
    ) -> Result<AutoChoice, AutoBakeError> {
        target.validate()?;
        let all: Vec<Prediction> = self
            .predictions()
            .into_iter()
            .map(|p| Prediction {
                predicted_psnr: p.predicted_psnr + correction(&p),
                ..p
            })
            .collect();
        let by_bytes = |a: &&Prediction, b: &&Prediction| {
            a.predicted_bytes
                .cmp(&b.predicted_bytes)
                .then(b.predicted_psnr.total_cmp(&a.predicted_psnr))
        };
        let by_psnr = |a: &&Prediction, b: &&Prediction| {
            a.predicted_psnr
                .total_cmp(&b.predicted_psnr)
                .then(b.predicted_bytes.cmp(&a.predicted_bytes))
        };
        let smallest = all.iter().min_by(by_bytes);
        let (pick, reach) = match target {
            AutoTarget::TargetPsnr(db) => {
                match all
                    .iter()
                    .filter(|p| p.predicted_psnr >= db + margin)
                    .min_by(by_bytes)
                {
                    Some(p)
                        if smallest == Some(p)
                            && p.predicted_psnr - margin > db + TARGET_TOLERANCE_DB =>
                    {
                        (Some(p), Reach::BelowSmallest)
                    }
                    Some(p) => (Some(p), Reach::Within),
                    None => {
                        // Within the margin of the best: still the setting to bake, and in reach.
                        let best = all.iter().max_by(by_psnr);
                        let reach = if best.is_some_and(|b| b.predicted_psnr >= db) {
                            Reach::Within
                        } else {
                            Reach::AboveBest
                        };
                        (best, reach)
                    }
                }
            }
            AutoTarget::MaxBytes(budget) => {
                match all
                    .iter()
                    .filter(|p| p.predicted_bytes <= budget)
                    .max_by(by_psnr)
                {
                    Some(p) => (Some(p), Reach::Within),
                    None => (smallest, Reach::BudgetTooSmall),
                }
            }
        };
        let corrected = *pick.ok_or_else(|| {
            AutoBakeError::Unmeasurable("any setting (the model is empty)".to_owned())
        })?;
        let correction_db = correction(&corrected);
        Ok(AutoChoice {
            setting: Prediction {
                predicted_psnr: corrected.predicted_psnr - correction_db,
                ..corrected
            },
            correction_db,
            reach,
        })
    }
}

/// Which half of the view spiral.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewSet {
    /// The even points: what the calibration measures.
    Calibration,
    /// The odd points: what the chosen bake is measured on.
    HeldOut,
}

/// [`AUTO_VIEWS`] views of [`AUTO_VIEW_SIZE`]² looking at `center` from the evaluation
/// distance (2.5 radii, 40°): one half of a Fibonacci spiral of 2 × [`AUTO_VIEWS`] points
/// (module docs).
pub fn auto_views(center: [f64; 3], radius: f64, set: ViewSet) -> Vec<View> {
    let total = 2 * AUTO_VIEWS;
    let first = usize::from(set == ViewSet::HeldOut);
    (first..total)
        .step_by(2)
        .map(|i| spiral_view(center, radius, i, total, 0.0))
        .collect()
}

/// Azimuth by which the tuning spiral is turned against the calibration one, radians (about
/// half the golden angle, so that no tuning view falls near a calibration or held-out one).
const TUNING_SPIRAL_TURN: f64 = 1.2;

/// The [`AUTO_TUNING_VIEWS`] views of the tuning measurement: a Fibonacci spiral of its own
/// (another point count, turned by `TUNING_SPIRAL_TURN`) at the distance and field of view of
/// [`auto_views`].
pub fn tuning_views(center: [f64; 3], radius: f64) -> Vec<View> {
    (0..AUTO_TUNING_VIEWS)
        .map(|i| spiral_view(center, radius, i, AUTO_TUNING_VIEWS, TUNING_SPIRAL_TURN))
        .collect()
}

/// Point `i` of a Fibonacci spiral of `total` points, turned by `turn` about +y, as a view.
fn spiral_view(center: [f64; 3], radius: f64, i: usize, total: usize, turn: f64) -> View {
    let golden_angle = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let y = 1.0 - (2.0 * i as f64 + 1.0) / total as f64;
    let s = (1.0 - y * y).max(0.0).sqrt();
    let phi = golden_angle * i as f64 + turn;
    let distance = EVALUATION_DISTANCE_RADII * radius;
    let eye = [
        center[0] + distance * s * phi.cos(),
        center[1] + distance * y,
        center[2] + distance * s * phi.sin(),
    ];
    // +y up unless the eye is (almost) straight above or below.
    let up = if y.abs() > 0.99 {
        [0.0, 0.0, 1.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    View {
        eye,
        target: center,
        up,
        yfov_deg: EVALUATION_YFOV_DEG,
        width: AUTO_VIEW_SIZE,
        height: AUTO_VIEW_SIZE,
    }
}

/// Mean masked PSNR of `asset` rendered with `cameras` (all knobs else at their defaults) at
/// `depth_bits` against `truths` of `views`.
fn measure_psnr(
    renderer: &Renderer,
    asset: &AssetFile,
    depth_bits: u8,
    cameras: &[u32],
    views: &[View],
    truths: &[Frame],
) -> Result<Vec<f64>, AutoBakeError> {
    let field = renderer.upload_with(
        asset,
        &UploadOptions {
            depth_bits: Some(depth_bits),
            base_state_only: true,
        },
    )?;
    let mut out = Vec::with_capacity(cameras.len());
    for &c in cameras {
        let options = RenderOptions {
            lod: Some(c),
            ..RenderOptions::default()
        };
        let mut comparisons = Vec::with_capacity(views.len());
        for (view, truth) in views.iter().zip(truths) {
            let frame = renderer.render(&field, view, &options)?;
            comparisons.push(metrics::compare(&frame, truth)?);
        }
        let mean = metrics::mean_comparison(&comparisons).map_or(f64::NAN, |m| m.masked_psnr);
        out.push(mean);
    }
    Ok(out)
}

/// Stored bytes of the first `cameras` cameras' pages of `channel` in `asset`.
fn channel_bytes(asset: &AssetFile, cameras: u32, channel: Channel) -> f64 {
    asset
        .index()
        .iter()
        .filter(|e| e.key.camera < cameras && e.key.channel == channel)
        .map(|e| f64::from(e.length))
        .sum()
}

/// What the calibration measured, and its model.
#[derive(Clone, Debug, Serialize)]
pub struct AutoCalibration {
    /// Quality measurements.
    pub quality: Vec<QualitySample>,
    /// Size measurements.
    pub size: Vec<SizeSample>,
    /// The fitted model.
    pub model: QualityModel,
    /// Calibration time (bakes and renders), ms.
    pub calibrate_ms: f64,
    /// Centre of the scene's bounding sphere (the asset frame's), which the views look at.
    pub center: [f64; 3],
    /// Radius of the scene's bounding sphere.
    pub radius: f64,
}

/// Stages of [`auto_bake`], for progress output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AutoStage {
    /// Calibration bake `index` of `total` (cameras done, cameras total).
    CalibrationBake {
        /// Which bake, from 1.
        index: usize,
        /// Of how many.
        total: usize,
        /// Cameras done.
        done: u32,
        /// Cameras of the bake.
        cameras: u32,
    },
    /// Rendering the calibration views.
    Measuring,
    /// The final bake (cameras done, cameras total).
    Bake {
        /// Cameras done.
        done: u32,
        /// Cameras of the bake.
        cameras: u32,
    },
    /// Measuring bake `bake` (from 1) on the tuning views.
    Tuning {
        /// Which bake, from 1.
        bake: usize,
    },
    /// Measuring the chosen bake on the held-out views (and its render calibration).
    Verifying,
}

/// Calibrates `mesh` for the automatic bake (module docs).
///
/// # Errors
/// [`AutoBakeError`] from the bakes, renders or the fit.
pub fn calibrate(
    baker: &Baker,
    renderer: &Renderer,
    reference: &ReferenceRenderer,
    mesh: &Mesh,
    gpu_mesh: &GpuMesh,
    shading: &Shading,
    source: &Provenance,
    progress: &mut dyn FnMut(AutoStage),
) -> Result<AutoCalibration, AutoBakeError> {
    let start = std::time::Instant::now();
    let all_cameras = CAMERA_COUNTS[CAMERA_COUNTS.len() - 1];
    let bakes: Vec<(u32, u32, u8)> = CALIBRATION_RESOLUTIONS
        .iter()
        .flat_map(|&n| [(all_cameras, n, 16), (DEPTH8_SIZE_CAMERAS, n, 8)])
        .collect();
    let total = bakes.len();
    let mut assets = Vec::with_capacity(total);
    for (i, &(cameras, resolution, depth_bits)) in bakes.iter().enumerate() {
        let options = BakeOptions {
            cameras,
            resolution,
            shading: *shading,
            depth_bits,
            lights: None,
            one_sided: false,
            color_codec: None,
            depth_codec: None,
        };
        let bytes = baker.bake_to_bytes(mesh, &options, source, &mut |done, cameras| {
            progress(AutoStage::CalibrationBake {
                index: i + 1,
                total,
                done,
                cameras,
            });
        })?;
        assets.push(AssetFile::from_bytes(bytes)?);
    }
    progress(AutoStage::Measuring);
    let frame = &assets[0].header().frame;
    let views = auto_views(frame.center, frame.radius, ViewSet::Calibration);
    let truths: Vec<Frame> = views
        .iter()
        .map(|v| reference.render(gpu_mesh, v, shading))
        .collect::<Result<_, _>>()?;
    let mut quality = Vec::new();
    let mut size = Vec::new();
    for pair in assets.chunks_exact(2) {
        let (full, depth8) = (&pair[0], &pair[1]);
        let resolution = full.header().image_size()[0];
        for depth_bits in [16, 8] {
            let psnr = measure_psnr(renderer, full, depth_bits, &CAMERA_COUNTS, &views, &truths)?;
            for (&cameras, masked_psnr) in CAMERA_COUNTS.iter().zip(psnr) {
                quality.push(QualitySample {
                    cameras,
                    resolution,
                    depth_bits,
                    masked_psnr,
                });
            }
        }
        // Pages are stored per camera and channel; header and index are shared out per camera.
        let pages: f64 = full.index().iter().map(|e| f64::from(e.length)).sum();
        let overhead_per_camera =
            (full.file_len() as f64 - pages).max(0.0) / f64::from(all_cameras);
        let depth8_ratio = channel_bytes(depth8, DEPTH8_SIZE_CAMERAS, Channel::Depth)
            / channel_bytes(full, DEPTH8_SIZE_CAMERAS, Channel::Depth).max(1.0);
        for cameras in CAMERA_COUNTS {
            let color = channel_bytes(full, cameras, Channel::Color);
            let depth16 = channel_bytes(full, cameras, Channel::Depth);
            let overhead = overhead_per_camera * f64::from(cameras);
            size.push(SizeSample {
                cameras,
                resolution,
                depth_bits: 16,
                bytes: color + depth16 + overhead,
            });
            size.push(SizeSample {
                cameras,
                resolution,
                depth_bits: 8,
                bytes: color + depth16 * depth8_ratio + overhead,
            });
        }
    }
    let model = QualityModel::fit(&quality, &size)?;
    Ok(AutoCalibration {
        quality,
        size,
        model,
        calibrate_ms: start.elapsed().as_secs_f64() * 1e3,
        center: frame.center,
        radius: frame.radius,
    })
}

/// What [`auto_bake`] reports.
#[derive(Clone, Debug, Serialize)]
pub struct AutoBakeReport {
    /// The target.
    pub target: AutoTarget,
    /// The chosen setting with its predictions, and where the target lies.
    pub choice: AutoChoice,
    /// Mean masked PSNR of the chosen bake on [`AUTO_VIEWS`] held-out views, dB.
    pub measured_psnr: f64,
    /// Measured minus predicted masked PSNR, dB (the model's error on this scene; the
    /// prediction without the tuning correction).
    pub prediction_error_db: f64,
    /// Every bake made, in order, with its tuning measurement; the kept one is `choice`.
    pub bakes: Vec<BakeAttempt>,
    /// Bytes of the asset written.
    pub asset_bytes: u64,
    /// Whether the target was met as measured: the held-out masked PSNR within
    /// [`TARGET_TOLERANCE_DB`] of a target PSNR, or the asset within the byte budget.
    pub target_met: bool,
    /// Why the target could not be met, for a target outside what any setting reaches.
    pub message: Option<String>,
    /// Calibration time, ms.
    pub calibrate_ms: f64,
    /// Final bake time, ms.
    pub bake_ms: f64,
    /// Held-out measurement (and render calibration) time, ms.
    pub verify_ms: f64,
    /// The calibration's measurements and model.
    pub calibration: AutoCalibration,
}

/// One bake of the automatic bake and what it measured on the tuning views.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BakeAttempt {
    /// The setting, its predictions and correction.
    pub choice: AutoChoice,
    /// Mean masked PSNR on the [`AUTO_TUNING_VIEWS`] tuning views, dB (`None` for a byte
    /// budget, which is not tuned on quality).
    pub tuning_psnr: Option<f64>,
    /// Bytes of the baked asset (before the report and render calibration are attached).
    pub bytes: u64,
    /// Bake time, ms.
    pub bake_ms: f64,
}

/// The asset of an automatic bake and its report.
pub struct AutoBake {
    /// The encoded asset (with the render calibration in its quality report when asked for,
    /// and the report under `"auto_bake"`).
    pub bytes: Vec<u8>,
    /// The report.
    pub report: AutoBakeReport,
}

/// Engines of an automatic bake.
pub struct AutoEngines<'a> {
    /// The baker.
    pub baker: &'a Baker,
    /// The light-field renderer.
    pub renderer: &'a Renderer,
    /// The reference rasterizer.
    pub reference: &'a ReferenceRenderer,
}

/// Calibrates, chooses the setting for `target`, bakes it, measures it on held-out views and
/// (with `render_calibration`) attaches the render calibration of [`crate::calibration`], as
/// every `lumigraph bake` does. A byte budget the written asset overshoots (the size model's
/// error) is retried up to twice with the budget scaled down by the overshoot.
///
/// # Errors
/// [`AutoBakeError`] for a bad target (before any GPU work) or any failed step.
pub fn auto_bake(
    engines: &AutoEngines<'_>,
    mesh: &Mesh,
    shading: &Shading,
    target: AutoTarget,
    source: &Provenance,
    render_calibration: bool,
    progress: &mut dyn FnMut(AutoStage),
) -> Result<AutoBake, AutoBakeError> {
    target.validate()?;
    shading.validate().map_err(BakeError::from)?;
    let gpu_mesh = engines.reference.upload(mesh)?;
    let calibration = calibrate(
        engines.baker,
        engines.renderer,
        engines.reference,
        mesh,
        &gpu_mesh,
        shading,
        source,
        progress,
    )?;
    let mut choice = calibration.model.choose(target)?;
    let mut bakes: Vec<BakeAttempt> = Vec::new();
    let mut assets: Vec<AssetFile> = Vec::new();
    // The tuning views and their reference images (a target PSNR only).
    let tuning: (Vec<View>, Vec<Frame>) = if matches!(target, AutoTarget::TargetPsnr(_)) {
        let views = tuning_views(calibration.center, calibration.radius);
        let truths = views
            .iter()
            .map(|v| engines.reference.render(&gpu_mesh, v, shading))
            .collect::<Result<Vec<_>, _>>()?;
        (views, truths)
    } else {
        (Vec::new(), Vec::new())
    };
    loop {
        let bake_start = std::time::Instant::now();
        let options = choice.setting.bake_options(*shading);
        let bytes = engines
            .baker
            .bake_to_bytes(mesh, &options, source, &mut |done, cameras| {
                progress(AutoStage::Bake { done, cameras });
            })?;
        let bake_ms = bake_start.elapsed().as_secs_f64() * 1e3;
        let asset_len = bytes.len() as u64;
        let asset = AssetFile::from_bytes(bytes)?;
        let mut attempt = BakeAttempt {
            choice,
            tuning_psnr: None,
            bytes: asset_len,
            bake_ms,
        };
        let next = match target {
            // A budget the written asset overshoots (the size model's error) is retried with
            // the budget scaled down by the overshoot.
            AutoTarget::MaxBytes(budget) => {
                if asset_len > budget && choice.reach == Reach::Within {
                    let scaled = (budget as f64 * budget as f64 / asset_len as f64) as u64;
                    Some(
                        calibration
                            .model
                            .choose(AutoTarget::MaxBytes(scaled.max(1)))?,
                    )
                    .filter(|retry| retry.reach == Reach::Within)
                } else {
                    None
                }
            }
            // A target PSNR: measured on the tuning views; outside the tuning band, the model
            // is corrected by what the bakes so far measured and the choice made again.
            AutoTarget::TargetPsnr(db) => {
                progress(AutoStage::Tuning {
                    bake: bakes.len() + 1,
                });
                let measured = measure_psnr(
                    engines.renderer,
                    &asset,
                    choice.setting.depth_bits,
                    &[choice.setting.cameras],
                    &tuning.0,
                    &tuning.1,
                )?[0];
                attempt.tuning_psnr = Some(measured);
                let off = measured - db;
                if (TUNING_BAND_DB.0..=TUNING_BAND_DB.1).contains(&off)
                    || choice.reach != Reach::Within
                {
                    None
                } else {
                    let mut tried = bakes.clone();
                    tried.push(attempt);
                    let correction = tuning_correction(&tried);
                    Some(calibration.model.choose_corrected(
                        target,
                        CORRECTED_MARGIN_DB,
                        &correction,
                    )?)
                }
            }
        };
        bakes.push(attempt);
        assets.push(asset);
        match next {
            Some(next)
                if bakes.len() < MAX_AUTO_BAKES
                    && !bakes.iter().any(|b| same_setting(&b.choice, &next)) =>
            {
                choice = next;
            }
            _ => break,
        }
    }
    let kept = keep_bake(target, &bakes);
    let choice = bakes[kept].choice;
    let asset = assets.swap_remove(kept);
    let bake_ms = bakes.iter().map(|b| b.bake_ms).sum();
    {
        progress(AutoStage::Verifying);
        let verify_start = std::time::Instant::now();
        let frame = &asset.header().frame;
        let views = auto_views(frame.center, frame.radius, ViewSet::HeldOut);
        let truths: Vec<Frame> = views
            .iter()
            .map(|v| engines.reference.render(&gpu_mesh, v, shading))
            .collect::<Result<_, _>>()?;
        let measured_psnr = measure_psnr(
            engines.renderer,
            &asset,
            choice.setting.depth_bits,
            &[choice.setting.cameras],
            &views,
            &truths,
        )?[0];
        let encoded = if render_calibration {
            let render = crate::calibration::Calibration::measure(
                engines.renderer,
                engines.reference,
                &asset,
                &gpu_mesh,
                shading,
                &engines.renderer.gpu().adapter_summary(),
                &mut |_, _| {},
            )?;
            AssetFile::from_bytes(render.attach(&asset)?)?
        } else {
            asset
        };
        let verify_ms = verify_start.elapsed().as_secs_f64() * 1e3;
        let mut report = AutoBakeReport {
            target,
            choice,
            measured_psnr,
            prediction_error_db: measured_psnr - choice.setting.predicted_psnr,
            bakes,
            asset_bytes: 0,
            target_met: false,
            message: choice.message(target),
            calibrate_ms: calibration.calibrate_ms,
            bake_ms,
            verify_ms,
            calibration: calibration.clone(),
        };
        // The report goes into the asset. For a byte budget, whether it is met depends on the
        // encoded size: encoded first as met, and again as not met when that is over budget
        // (one byte longer, so still over).
        report.target_met = match target {
            AutoTarget::TargetPsnr(db) => (measured_psnr - db).abs() <= TARGET_TOLERANCE_DB,
            AutoTarget::MaxBytes(_) => true,
        };
        let mut bytes = attach_report(&encoded, &report)?;
        if let AutoTarget::MaxBytes(budget) = target
            && bytes.len() as u64 > budget
        {
            report.target_met = false;
            bytes = attach_report(&encoded, &report)?;
        }
        report.asset_bytes = bytes.len() as u64;
        Ok(AutoBake { bytes, report })
    }
}

fn same_setting(a: &AutoChoice, b: &AutoChoice) -> bool {
    let key = |c: &AutoChoice| {
        (
            c.setting.cameras,
            c.setting.resolution,
            c.setting.depth_bits,
        )
    };
    key(a) == key(b)
}

/// The correction of the model's PSNR prediction from tuned bakes, per setting: the mean
/// measured-minus-predicted error of the bakes with the same camera count and depth precision,
/// else the same camera count, else all of them (the model's error is mostly its extrapolation
/// per curve, and a scene-wide offset otherwise).
fn tuning_correction(bakes: &[BakeAttempt]) -> impl Fn(&Prediction) -> f64 + use<> {
    let errors: Vec<(u32, u8, f64)> = bakes
        .iter()
        .filter_map(|b| {
            b.tuning_psnr.map(|t| {
                let s = &b.choice.setting;
                (s.cameras, s.depth_bits, t - s.predicted_psnr)
            })
        })
        .collect();
    move |p: &Prediction| {
        let mean = |keep: &dyn Fn(&(u32, u8, f64)) -> bool| {
            let picked: Vec<f64> = errors.iter().filter(|e| keep(e)).map(|e| e.2).collect();
            (!picked.is_empty()).then(|| picked.iter().sum::<f64>() / picked.len() as f64)
        };
        mean(&|e| e.0 == p.cameras && e.1 == p.depth_bits)
            .or_else(|| mean(&|e| e.0 == p.cameras))
            .or_else(|| mean(&|_| true))
            .unwrap_or(0.0)
    }
}

/// Which of the bakes to keep. A target PSNR: the fewest bytes among those whose tuning
/// measurement lies in [`TUNING_BAND_DB`] of the target; failing that, the one closest to
/// [`CORRECTED_MARGIN_DB`] above it (ties: fewer bytes). A byte budget: the last bake (each
/// retry is smaller).
fn keep_bake(target: AutoTarget, bakes: &[BakeAttempt]) -> usize {
    let last = bakes.len().saturating_sub(1);
    let AutoTarget::TargetPsnr(db) = target else {
        return last;
    };
    let tuned: Vec<(usize, f64, u64)> = bakes
        .iter()
        .enumerate()
        .filter_map(|(i, b)| b.tuning_psnr.map(|t| (i, t - db, b.bytes)))
        .collect();
    let in_band = tuned
        .iter()
        .filter(|(_, off, _)| (TUNING_BAND_DB.0..=TUNING_BAND_DB.1).contains(off))
        .min_by_key(|(_, _, bytes)| *bytes);
    let closest = || {
        tuned.iter().min_by(|a, b| {
            (a.1 - CORRECTED_MARGIN_DB)
                .abs()
                .total_cmp(&(b.1 - CORRECTED_MARGIN_DB).abs())
                .then(a.2.cmp(&b.2))
        })
    };
    in_band.or_else(closest).map_or(last, |t| t.0)
}

/// The asset re-encoded with a summary of `report` under `"auto_bake"` in its quality report:
/// target, choice (setting, predictions, correction, reach), the bakes with their tuning
/// PSNRs, held-out masked PSNR and views, whether the target was met and why not.
fn attach_report(
    asset: &AssetFile,
    report: &AutoBakeReport,
) -> Result<Vec<u8>, crate::asset::AssetError> {
    let mut header = asset.header().clone();
    let mut quality = match header.quality.take() {
        Some(serde_json::Value::Object(map)) => map,
        _ => serde_json::Map::new(),
    };
    quality.insert(
        "auto_bake".to_owned(),
        serde_json::json!({
            "target": report.target,
            "choice": report.choice,
            "bakes": report.bakes,
            "measured_psnr": report.measured_psnr,
            "held_out_views": AUTO_VIEWS,
            "target_met": report.target_met,
            "message": report.message,
        }),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of a scene whose error is `floor(C) + 4e4 · N^−1.25` exactly, sizes
    /// `C · N^1.8 / 10` (16-bit) and 0.8 of that (8-bit); 8-bit depth costs 0.1 dB.
    fn samples() -> (Vec<QualitySample>, Vec<SizeSample>) {
        let mut quality = Vec::new();
        let mut size = Vec::new();
        for (i, cameras) in CAMERA_COUNTS.into_iter().enumerate() {
            let floor = 200.0 / (1.0 + i as f64);
            for resolution in CALIBRATION_RESOLUTIONS {
                let mse = floor + 4e4 * f64::from(resolution).powf(-1.25);
                let db = 10.0 * (PEAK_SQUARED / mse).log10();
                for (depth_bits, penalty, share) in [(16, 0.0, 1.0), (8, 0.1, 0.8)] {
                    quality.push(QualitySample {
                        cameras,
                        resolution,
                        depth_bits,
                        masked_psnr: db - penalty,
                    });
                    size.push(SizeSample {
                        cameras,
                        resolution,
                        depth_bits,
                        bytes: share * f64::from(cameras) * f64::from(resolution).powf(1.8) / 10.0,
                    });
                }
            }
        }
        (quality, size)
    }

    fn model() -> QualityModel {
        let (q, s) = samples();
        QualityModel::fit(&q, &s).expect("model")
    }

    #[test]
    fn the_fit_recovers_the_model_it_states() {
        let m = model();
        let curve = m
            .quality
            .iter()
            .find(|c| (c.cameras, c.depth_bits) == (162, 16))
            .expect("curve");
        // Exact data: the fit is exact up to rounding.
        assert!((curve.exponent - 1.25).abs() < 1e-9, "{curve:?}");
        assert!((curve.floor_mse - 200.0 / 3.0).abs() < 1e-6, "{curve:?}");
        assert!((curve.scale - 4e4).abs() < 1e-4, "{curve:?}");
        let size = m
            .size
            .iter()
            .find(|c| (c.cameras, c.depth_bits) == (42, 8))
            .expect("size");
        assert!((size.p - 1.8).abs() < 1e-9);
        let expected = 0.8 * 42.0 * 300f64.powf(1.8) / 10.0;
        assert!((size.bytes(300) as f64 - expected).abs() <= 1.0);
    }

    #[test]
    fn predictions_are_monotonic_in_resolution_and_cameras() {
        let m = model();
        for curve in &m.quality {
            let psnr: Vec<f64> = candidate_resolutions().map(|n| curve.psnr(n)).collect();
            assert!(psnr.windows(2).all(|w| w[1] >= w[0]), "{curve:?}");
        }
        for size in &m.size {
            let bytes: Vec<u64> = candidate_resolutions().map(|n| size.bytes(n)).collect();
            assert!(bytes.windows(2).all(|w| w[1] >= w[0]), "{size:?}");
        }
        // Noisy samples (higher resolution measured worse) still give a non-increasing error.
        let flat = QualityCurve::fit(42, 16, [(64, 23.0), (128, 25.0), (192, 24.0)]);
        assert_eq!(flat.scale, 0.0);
        assert_eq!(flat.exponent, DEFAULT_RESOLUTION_EXPONENT);
        assert!((flat.psnr(512) - 24.0).abs() < 1e-9 && (flat.psnr(64) - 24.0).abs() < 1e-9);
        // A fall steeper than any γ in range is clamped and never predicts a negative floor.
        let steep = QualityCurve::fit(42, 16, [(64, 10.0), (128, 15.0), (192, 30.0)]);
        assert!(steep.floor_mse >= 0.0 && steep.psnr(512) > 30.0 && steep.psnr(512).is_finite());
        // Higher targets never choose fewer bytes or a lower prediction.
        let mut last = (0, 0.0);
        for target in [20.0, 22.0, 24.0, 26.0, 28.0, 30.0, 32.0] {
            let c = m
                .choose(AutoTarget::TargetPsnr(target))
                .expect("choice")
                .setting;
            assert!(
                c.predicted_bytes >= last.0 && c.predicted_psnr >= last.1,
                "{target}: {c:?}"
            );
            last = (c.predicted_bytes, c.predicted_psnr);
        }
        // Larger budgets never choose a lower prediction.
        let mut last = 0.0;
        for budget in [10_000_u64, 100_000, 1_000_000, 10_000_000, 100_000_000] {
            let c = m
                .choose(AutoTarget::MaxBytes(budget))
                .expect("choice")
                .setting;
            assert!(c.predicted_psnr >= last, "{budget}: {c:?}");
            last = c.predicted_psnr;
        }
    }

    #[test]
    fn a_target_gets_the_fewest_bytes_that_reach_it() {
        let m = model();
        let target = 27.0;
        let choice = m.choose(AutoTarget::TargetPsnr(target)).expect("choice");
        assert_eq!(choice.reach, Reach::Within);
        assert!(choice.setting.predicted_psnr >= target);
        assert!(choice.setting.predicted_psnr >= target + PREDICTION_MARGIN_DB);
        assert!(choice.message(AutoTarget::TargetPsnr(target)).is_none());
        for p in m.predictions() {
            if p.predicted_psnr >= target + PREDICTION_MARGIN_DB {
                assert!(
                    p.predicted_bytes >= choice.setting.predicted_bytes,
                    "{p:?} beats {choice:?}"
                );
            }
        }
        let budget = 2_000_000;
        let choice = m.choose(AutoTarget::MaxBytes(budget)).expect("choice");
        assert_eq!(choice.reach, Reach::Within);
        assert!(choice.setting.predicted_bytes <= budget);
        for p in m.predictions() {
            if p.predicted_bytes <= budget {
                assert!(
                    p.predicted_psnr <= choice.setting.predicted_psnr,
                    "{p:?} beats {choice:?}"
                );
            }
        }
    }

    #[test]
    fn targets_out_of_reach_get_the_closest_setting_flagged() {
        let m = model();
        let all = m.predictions();
        let best = all
            .iter()
            .map(|p| p.predicted_psnr)
            .fold(f64::MIN, f64::max);
        let smallest = all.iter().map(|p| p.predicted_bytes).min().expect("some");
        let high = m
            .choose(AutoTarget::TargetPsnr(best + 5.0))
            .expect("choice");
        assert_eq!(high.reach, Reach::AboveBest);
        assert_eq!(high.setting.predicted_psnr, best);
        let message = high
            .message(AutoTarget::TargetPsnr(best + 5.0))
            .expect("message");
        assert!(
            message.contains("above what any setting reaches"),
            "{message}"
        );
        let low = m.choose(AutoTarget::TargetPsnr(1.0)).expect("choice");
        assert_eq!(low.reach, Reach::BelowSmallest);
        assert_eq!(low.setting.predicted_bytes, smallest);
        let tiny = m.choose(AutoTarget::MaxBytes(1)).expect("choice");
        assert_eq!(tiny.reach, Reach::BudgetTooSmall);
        assert_eq!(tiny.setting.predicted_bytes, smallest);
        assert!(
            tiny.message(AutoTarget::MaxBytes(1))
                .expect("message")
                .contains("max bytes 1")
        );
    }

    #[test]
    fn calibration_and_held_out_views_are_disjoint_and_even() {
        let calibration = auto_views([1.0, 2.0, 3.0], 2.0, ViewSet::Calibration);
        let held_out = auto_views([1.0, 2.0, 3.0], 2.0, ViewSet::HeldOut);
        assert_eq!(
            (calibration.len(), held_out.len()),
            (AUTO_VIEWS, AUTO_VIEWS)
        );
        for set in [&calibration, &held_out] {
            let mut mean = glam::DVec3::ZERO;
            for v in set {
                let d = glam::DVec3::from(v.eye) - glam::DVec3::new(1.0, 2.0, 3.0);
                // On the evaluation sphere (5 = 2.5 radii), rounding only.
                assert!((d.length() - 5.0).abs() < 1e-9);
                mean += d / 5.0;
            }
            // Even coverage: the mean direction of 24 spiral points is near the centre (a
            // random set of 24 has |mean| ≈ 0.2; the spiral's is below 0.05).
            assert!((mean / AUTO_VIEWS as f64).length() < 0.05, "{mean}");
        }
        // Disjoint: no held-out eye within 0.1 radii of a calibration eye.
        for h in &held_out {
            for c in &calibration {
                let gap = glam::DVec3::from(h.eye).distance(glam::DVec3::from(c.eye));
                assert!(gap > 0.2, "{:?} {:?}", h.eye, c.eye);
            }
        }
        // The tuning set: as even, and disjoint from both (no eye within 0.05 radii).
        let tuning = tuning_views([1.0, 2.0, 3.0], 2.0);
        assert_eq!(tuning.len(), AUTO_TUNING_VIEWS);
        let mut mean = glam::DVec3::ZERO;
        for t in &tuning {
            let d = glam::DVec3::from(t.eye) - glam::DVec3::new(1.0, 2.0, 3.0);
            assert!((d.length() - 5.0).abs() < 1e-9);
            mean += d / 5.0;
            for other in calibration.iter().chain(&held_out) {
                let gap = glam::DVec3::from(t.eye).distance(glam::DVec3::from(other.eye));
                assert!(gap > 0.1, "{:?} {:?}", t.eye, other.eye);
            }
        }
        assert!((mean / AUTO_TUNING_VIEWS as f64).length() < 0.05, "{mean}");
    }

    fn attempt(m: &QualityModel, cameras: u32, resolution: u32, tuned: f64) -> BakeAttempt {
        let setting = m
            .predictions()
            .into_iter()
            .find(|p| (p.cameras, p.resolution, p.depth_bits) == (cameras, resolution, 8))
            .expect("a candidate setting");
        BakeAttempt {
            choice: AutoChoice {
                setting,
                correction_db: 0.0,
                reach: Reach::Within,
            },
            tuning_psnr: Some(setting.predicted_psnr + tuned),
            bytes: setting.predicted_bytes,
            bake_ms: 1.0,
        }
    }

    /// A bake that measured 1 dB below its prediction moves the corrected choice to a setting
    /// the model predicts 1 dB higher (the same curve's error applies to it), and one that
    /// measured 1 dB above to a smaller one; the reported prediction stays the model's.
    #[test]
    fn the_tuning_correction_moves_the_choice_by_the_measured_error() {
        let m = model();
        let target = AutoTarget::TargetPsnr(27.0);
        let first = m.choose(target).expect("choice");
        let s = first.setting;
        for error in [-1.0, 1.0] {
            let tried = [attempt(&m, s.cameras, s.resolution, error)];
            let correction = tuning_correction(&tried);
            // Same camera count: that curve's error; other counts: the mean (here the same).
            for p in m.predictions().iter().filter(|p| p.depth_bits == 8) {
                assert!((correction(p) - error).abs() < 1e-12, "{p:?}");
            }
            let corrected = m
                .choose_corrected(target, CORRECTED_MARGIN_DB, &correction)
                .expect("corrected choice");
            assert_eq!(corrected.reach, Reach::Within);
            assert!((corrected.correction_db - error).abs() < 1e-12);
            let aimed = corrected.setting.predicted_psnr + corrected.correction_db;
            assert!(aimed >= 27.0 + CORRECTED_MARGIN_DB, "{corrected:?}");
            if error < 0.0 {
                assert!(corrected.setting.predicted_bytes > s.predicted_bytes);
            } else {
                assert!(corrected.setting.predicted_bytes < s.predicted_bytes);
            }
            // The fewest corrected bytes reaching the aim.
            for p in m.predictions() {
                if p.predicted_psnr + correction(&p) >= 27.0 + CORRECTED_MARGIN_DB {
                    assert!(p.predicted_bytes >= corrected.setting.predicted_bytes);
                }
            }
        }
        // Per curve: a second bake's error on another camera count is that count's own.
        let other = CAMERA_COUNTS
            .into_iter()
            .find(|&c| c != s.cameras)
            .expect("another count");
        let tried = [
            attempt(&m, s.cameras, s.resolution, -0.6),
            attempt(&m, other, 128, 0.4),
        ];
        let correction = tuning_correction(&tried);
        let on = |cameras| {
            m.predictions()
                .into_iter()
                .find(|p| p.cameras == cameras && p.depth_bits == 8)
                .map(|p| correction(&p))
                .expect("prediction")
        };
        assert!((on(s.cameras) + 0.6).abs() < 1e-12);
        assert!((on(other) - 0.4).abs() < 1e-12);
    }

    /// The kept bake: the fewest bytes inside the tuning band, else the one closest to the aim.
    #[test]
    fn the_kept_bake_is_the_smallest_in_the_band_else_the_closest() {
        let m = model();
        let target = 27.0;
        let with = |cameras, resolution, tuned_off: f64| {
            let mut a = attempt(&m, cameras, resolution, 0.0);
            a.tuning_psnr = Some(target + tuned_off);
            a
        };
        let big_in_band = with(162, 256, 0.3);
        let small_in_band = with(42, 256, 0.0);
        let out_high = with(642, 384, 0.8);
        let t = AutoTarget::TargetPsnr(target);
        assert_eq!(keep_bake(t, &[out_high, big_in_band, small_in_band]), 2);
        assert_eq!(keep_bake(t, &[small_in_band, big_in_band]), 0);
        // None in the band: the closest to the aim, whichever side.
        let low = with(12, 64, -0.3);
        assert_eq!(keep_bake(t, &[out_high, low]), 1);
        assert_eq!(keep_bake(t, &[with(12, 64, -0.9), out_high]), 1);
        // A byte budget keeps the last (smallest) retry.
        let mut budget = [out_high, small_in_band];
        for b in &mut budget {
            b.tuning_psnr = None;
        }
        assert_eq!(keep_bake(AutoTarget::MaxBytes(1), &budget), 1);
    }

    #[test]
    fn bad_and_conflicting_targets_are_refused() {
        let m = model();
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -3.0, 100.5] {
            assert!(
                matches!(
                    m.choose(AutoTarget::TargetPsnr(bad)),
                    Err(AutoBakeError::TargetPsnr(_))
                ),
                "{bad}"
            );
            assert!(AutoTarget::from_flags(Some(bad), None).is_err(), "{bad}");
        }
        assert!(matches!(
            m.choose(AutoTarget::MaxBytes(0)),
            Err(AutoBakeError::MaxBytes)
        ));
        assert!(matches!(
            AutoTarget::from_flags(Some(27.0), Some(1000)),
            Err(AutoBakeError::ConflictingTargets)
        ));
        assert_eq!(
            AutoTarget::from_flags(None, None).expect("default"),
            AutoTarget::TargetPsnr(DEFAULT_TARGET_PSNR)
        );
        assert_eq!(
            AutoTarget::from_flags(None, Some(5)).expect("bytes"),
            AutoTarget::MaxBytes(5)
        );
        // A missing or unmeasured sample names what is missing.
        let (mut q, s) = samples();
        q[3].masked_psnr = f64::NAN;
        let err = QualityModel::fit(&q, &s).expect_err("NaN sample");
        assert!(err.to_string().contains("masked PSNR"), "{err}");
        let (q, _) = samples();
        assert!(QualityModel::fit(&q, &[]).is_err());
    }
}
