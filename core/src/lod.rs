//! Automatic level of detail (seed 000 §3.1).
//!
//! A light field renders at a discrete level (12/42/162/642 cameras, all from one asset) and a
//! continuous one (the march step; the tolerance follows it as step / 2). Seed 000 picks them
//! from the object's distance; here the pick is made from what distance changes, the object's
//! *projected diameter* `P` in pixels (its bounding sphere seen from the eye, so distance, field
//! of view and output size all count), under a quality floor:
//!
//! - Every calibrated setting (the asset's quality report, [`Calibration`]) carries its mean
//!   silhouette displacement `e` in bounding diameters, measured against the mesh at bake time.
//!   At projected size `P` that setting's predicted silhouette error is `e · P` pixels.
//! - The floor is `e · P ≤ max_error_px` (default 1 px), optionally with `masked PSNR ≥
//!   min_psnr`, and by default within 2 dB of the most accurate level's calibrated masked PSNR
//!   (`max_psnr_drop`). Only settings on the Pareto front of (cost, silhouette error) are candidates.
//!   Of those that meet the floor, the cheapest (calibrated ms per pixel) is chosen; settings
//!   within 10 % of the cheapest count as equally cheap and the most accurate of them wins, so
//!   timing noise does not pick a worse level. When none meets it (a large object), the
//!   cheapest of those within 10 % of the smallest error is chosen.
//! - Masked PSNR alone cannot drive LOD: with one ray per pixel it barely depends on the output
//!   size (BENCHMARKS.md: ±0.15 dB between 256² and 512²). A pixel-space error does.
//! - No popping: as `P` grows towards the size where the chosen setting stops meeting the
//!   floor, the frame dissolves into the next setting over a band of sizes
//!   ([`LodPolicy::blend_band`], default the last 15 %): a smoothstep weight `w` of the pixels,
//!   picked by a 4×4 ordered-dither pattern, render with the next setting in the same single
//!   pass ([`Renderer::render_blend`]), so the band costs no extra render and the image
//!   changes a few pixels at a time as `P` changes (tested against a hard switch).
//! - Explicit settings override: a pinned camera count or step restricts the choice to it (the
//!   step's nearest calibrated value stands for it in the predictions); a pinned tolerance or
//!   coarse-to-fine `guide` is passed through.

use serde::{Deserialize, Serialize};

use crate::calibration::Calibration;
use crate::frame::Frame;
use crate::render::{GpuLightField, Method, RenderError, RenderOptions, Renderer};
use crate::view::View;

/// Default bound on the predicted silhouette error, pixels.
pub const DEFAULT_MAX_ERROR_PX: f64 = 1.0;
/// Default largest drop of calibrated masked PSNR below the most accurate level, dB.
pub const DEFAULT_MAX_PSNR_DROP: f64 = 2.0;
/// Default cross-fade band: the last 15 % of projected sizes before a switch.
pub const DEFAULT_BLEND_BAND: f64 = 0.15;
/// Settings whose calibrated cost is within this factor of the cheapest count as equally cheap:
/// camera count changes lavapipe's time per frame by ±7 % (BENCHMARKS.md), which is noise.
const COST_TIE: f64 = 1.10;
/// When no setting meets the bound, errors within this factor of the smallest count as equally
/// accurate (4 calibration views do not resolve finer), and the cheapest of them is chosen.
const ERROR_TIE: f64 = 1.10;

/// Errors of automatic LOD.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LodError {
    /// The policy or the pinned knobs cannot be served.
    #[error("automatic LOD: {0}")]
    Policy(String),
    /// A render failed.
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// What automatic LOD must keep.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LodPolicy {
    /// Largest predicted silhouette error, pixels.
    pub max_error_px: f64,
    /// Optional floor on the calibrated masked PSNR, dB.
    pub min_psnr: Option<f64>,
    /// Largest drop of calibrated masked PSNR below the most accurate level's, dB (default 2;
    /// `null` or infinity: no limit). Masked PSNR hardly depends on the object's size, so
    /// this keeps interior colour errors of coarse levels in check where the pixel bound alone
    /// would allow them.
    pub max_psnr_drop: Option<f64>,
    /// Cross-fade band below each switch, as a fraction of the switch's projected size
    /// (0 = hard switches).
    pub blend_band: f64,
}

impl Default for LodPolicy {
    fn default() -> Self {
        Self {
            max_error_px: DEFAULT_MAX_ERROR_PX,
            min_psnr: None,
            max_psnr_drop: Some(DEFAULT_MAX_PSNR_DROP),
            blend_band: DEFAULT_BLEND_BAND,
        }
    }
}

impl LodPolicy {
    /// The policy of the optional request fields every front takes (`auto_lod` = the bound in
    /// pixels, then the PSNR floor, PSNR drop and blend band, defaults where absent), or
    /// `None` without `auto_lod`. `has_goal`: a `target_psnr` / `budget_ms` came too.
    ///
    /// # Errors
    /// [`LodError::Policy`] for a floor or band without `auto_lod`, `auto_lod` with a goal, or
    /// a value out of range ([`LodPolicy::validate`]).
    pub fn from_parts(
        auto_lod: Option<f64>,
        min_psnr: Option<f64>,
        max_psnr_drop: Option<f64>,
        blend_band: Option<f64>,
        has_goal: bool,
    ) -> Result<Option<LodPolicy>, LodError> {
        let Some(max_error_px) = auto_lod else {
            if min_psnr.is_some() || max_psnr_drop.is_some() || blend_band.is_some() {
                return Err(LodError::Policy(
                    "lod_min_psnr / lod_max_psnr_drop / lod_blend need auto_lod".to_owned(),
                ));
            }
            return Ok(None);
        };
        if has_goal {
            return Err(LodError::Policy(
                "give auto_lod or target_psnr / budget_ms, not both".to_owned(),
            ));
        }
        let policy = LodPolicy {
            max_error_px,
            min_psnr,
            max_psnr_drop: Some(max_psnr_drop.unwrap_or(DEFAULT_MAX_PSNR_DROP)),
            blend_band: blend_band.unwrap_or(DEFAULT_BLEND_BAND),
        };
        policy.validate()?;
        Ok(Some(policy))
    }

    /// Checks the ranges.
    ///
    /// # Errors
    /// [`LodError::Policy`] naming the bad field.
    pub fn validate(&self) -> Result<(), LodError> {
        if !(self.max_error_px.is_finite() && self.max_error_px > 0.0) {
            return Err(LodError::Policy(format!(
                "max_error_px {} must be finite and positive",
                self.max_error_px
            )));
        }
        if let Some(db) = self.min_psnr
            && !(db.is_finite() && db > 0.0)
        {
            return Err(LodError::Policy(format!(
                "min_psnr {db} dB must be finite and positive"
            )));
        }
        if let Some(db) = self.max_psnr_drop
            && !(db >= 0.0)
        {
            return Err(LodError::Policy(format!(
                "max_psnr_drop {db} dB must be non-negative (infinity: no limit)"
            )));
        }
        if !(self.blend_band.is_finite() && (0.0..=1.0).contains(&self.blend_band)) {
            return Err(LodError::Policy(format!(
                "blend_band {} must be in [0, 1]",
                self.blend_band
            )));
        }
        Ok(())
    }
}

/// Checks that the knobs pinned with automatic LOD leave it a choice: it chooses among
/// default-method settings.
///
/// # Errors
/// [`LodError::Policy`] for a pinned fixed method.
pub fn check_pinned(pinned: &RenderOptions) -> Result<(), LodError> {
    if pinned.method == Method::Default {
        Ok(())
    } else {
        Err(LodError::Policy(
            "it chooses among default-method settings: drop method=fixed or pin the lod and step \
             yourself"
                .to_owned(),
        ))
    }
}

/// One calibrated setting automatic LOD can choose.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Level {
    /// Cameras.
    pub cameras: u32,
    /// Step, bounding diameters (the pinned step when one is pinned).
    pub step: f32,
    /// Mean silhouette displacement, bounding diameters.
    pub silhouette_error: f64,
    /// Calibrated render time, ms per million pixels.
    pub ms_per_mpx: f64,
    /// Calibrated masked PSNR, dB.
    pub masked_psnr: f64,
}

impl Level {
    /// Largest projected diameter (pixels) at which this level keeps `max_error_px`.
    fn max_projected_px(&self, max_error_px: f64) -> f64 {
        if self.silhouette_error > 0.0 {
            max_error_px / self.silhouette_error
        } else {
            f64::INFINITY
        }
    }
}

/// The levels a policy chooses from, built once per asset and policy.
#[derive(Clone, Debug, PartialEq)]
pub struct Ladder {
    levels: Vec<Level>,
    policy: LodPolicy,
    tolerance: Option<f32>,
    guide: Option<u32>,
}

/// What automatic LOD decided for one frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LodDecision {
    /// Projected diameter of the bounding sphere, pixels.
    pub projected_px: f64,
    /// The chosen level.
    pub level: Level,
    /// Its predicted silhouette error at this size, pixels.
    pub error_px: f64,
    /// Whether some level meets the floor (else the cheapest of the most accurate ones).
    pub met: bool,
    /// The level being faded in (inside a blend band), with its weight in (0, 1].
    pub blend: Option<(Level, f64)>,
}

impl LodDecision {
    /// Predicted render time at `pixels` output pixels (inside a blend band, the levels'
    /// times weighted by their share of the pixels).
    pub fn predicted_ms(&self, pixels: u64) -> f64 {
        let mpx = pixels as f64 / 1e6;
        match self.blend {
            Some((next, w)) => ((1.0 - w) * self.level.ms_per_mpx + w * next.ms_per_mpx) * mpx,
            None => self.level.ms_per_mpx * mpx,
        }
    }
}

impl Ladder {
    /// The levels of `calibration` usable under `policy` with at most `max_cameras` cameras,
    /// restricted by the knobs `pinned` sets (`lod`, `step`; `tolerance` is passed through).
    ///
    /// # Errors
    /// [`LodError::Policy`] for a bad policy, a pinned fixed method, a calibration without
    /// silhouette errors (made before they were measured) or no level left.
    pub fn new(
        calibration: &Calibration,
        policy: &LodPolicy,
        max_cameras: u32,
        pinned: &RenderOptions,
    ) -> Result<Ladder, LodError> {
        policy.validate()?;
        check_pinned(pinned)?;
        let max_level = crate::geometry::level_for_camera_count(max_cameras)
            .ok_or_else(|| LodError::Policy(format!("{max_cameras} is not a camera count")))?;
        let resolved = pinned.resolve(max_level)?;
        let pinned_cameras = pinned.lod.map(|_| resolved.cameras);
        let pinned_step = pinned.step.map(|_| resolved.step);
        let mut candidates: Vec<Level> = calibration
            .points
            .iter()
            .filter_map(|p| {
                let e = p.silhouette_error?;
                let usable = e.is_finite()
                    && e >= 0.0
                    && p.ms_per_mpx.is_finite()
                    && p.ms_per_mpx > 0.0
                    && p.masked_psnr.is_finite()
                    && p.cameras <= max_cameras
                    && pinned_cameras.is_none_or(|c| c == p.cameras)
                    && policy.min_psnr.is_none_or(|db| p.masked_psnr >= db);
                usable.then_some(Level {
                    cameras: p.cameras,
                    step: p.step,
                    silhouette_error: e,
                    ms_per_mpx: p.ms_per_mpx,
                    masked_psnr: p.masked_psnr,
                })
            })
            .collect();
        if calibration
            .points
            .iter()
            .all(|p| p.silhouette_error.is_none())
        {
            return Err(LodError::Policy(
                "the asset's calibration predates silhouette errors: re-bake it (calibration \
                 on) to use automatic LOD"
                    .to_owned(),
            ));
        }
        if let Some(step) = pinned_step {
            // The calibrated step nearest (in ratio) to the pinned one stands for it.
            let ratio = |s: f32| (f64::from(s) / f64::from(step)).ln().abs();
            if let Some(nearest) = candidates
                .iter()
                .map(|l| l.step)
                .min_by(|a, b| ratio(*a).total_cmp(&ratio(*b)))
            {
                candidates.retain(|l| l.step == nearest);
                for l in &mut candidates {
                    l.step = step;
                }
            }
        }
        // Only the Pareto front of (cost, error): a level another one beats on both never
        // helps, and dropping it keeps the ladder from alternating between camera counts.
        let cost: Vec<f64> = candidates.iter().map(|l| l.ms_per_mpx).collect();
        let accuracy: Vec<f64> = candidates.iter().map(|l| -l.silhouette_error).collect();
        let front = crate::tradeoff::pareto_front(&cost, &accuracy);
        let mut on_front = front.iter();
        candidates.retain(|_| on_front.next().copied().unwrap_or(false));
        // Levels costlier than the cheapest one within ERROR_TIE of the smallest error buy an
        // accuracy the calibration cannot resolve: drop them, so that level is the top one.
        let best = candidates
            .iter()
            .map(|l| l.silhouette_error)
            .fold(f64::INFINITY, f64::min);
        if let Some(top_cost) = candidates
            .iter()
            .filter(|l| l.silhouette_error <= best * ERROR_TIE)
            .map(|l| l.ms_per_mpx)
            .min_by(f64::total_cmp)
        {
            candidates.retain(|l| l.ms_per_mpx <= top_cost);
        }
        // The PSNR floor relative to the top level (the most accurate one left).
        if let (Some(drop), Some(top)) = (
            policy.max_psnr_drop,
            candidates.iter().min_by(|a, b| {
                a.silhouette_error
                    .total_cmp(&b.silhouette_error)
                    .then(a.ms_per_mpx.total_cmp(&b.ms_per_mpx))
            }),
        ) {
            let floor = top.masked_psnr - drop;
            candidates.retain(|l| l.masked_psnr >= floor);
        }
        if candidates.is_empty() {
            return Err(LodError::Policy(
                "no calibrated setting is left under the pinned knobs and the PSNR floor"
                    .to_owned(),
            ));
        }
        Ok(Ladder {
            levels: candidates,
            policy: *policy,
            tolerance: pinned.tolerance,
            guide: pinned.guide,
        })
    }

    /// The levels, in calibration order.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// The level for projected size `px` and whether it meets the floor.
    fn pick(&self, px: f64) -> (usize, bool) {
        let bound = self.policy.max_error_px;
        let feasible: Vec<usize> = (0..self.levels.len())
            .filter(|&i| self.levels[i].silhouette_error * px <= bound)
            .collect();
        let most_accurate = |set: &mut dyn Iterator<Item = usize>| {
            set.min_by(|&a, &b| {
                let (la, lb) = (&self.levels[a], &self.levels[b]);
                la.silhouette_error
                    .total_cmp(&lb.silhouette_error)
                    .then(la.ms_per_mpx.total_cmp(&lb.ms_per_mpx))
            })
        };
        let cheapest = feasible
            .iter()
            .map(|&i| self.levels[i].ms_per_mpx)
            .min_by(f64::total_cmp);
        match cheapest {
            Some(cost) => {
                let mut ties = feasible
                    .iter()
                    .copied()
                    .filter(|&i| self.levels[i].ms_per_mpx <= cost * COST_TIE);
                (most_accurate(&mut ties).unwrap_or(feasible[0]), true)
            }
            None => (
                most_accurate(&mut (0..self.levels.len())).unwrap_or(0),
                false,
            ),
        }
    }

    /// The decision for an object of projected diameter `px` pixels.
    pub fn decide(&self, px: f64) -> LodDecision {
        let px = if px.is_nan() {
            f64::INFINITY
        } else {
            px.max(0.0)
        };
        let (i, met) = self.pick(px);
        let level = self.levels[i];
        let mut blend = None;
        let band = self.policy.blend_band;
        if met && px.is_finite() && band > 0.0 {
            // The next switch above: the smallest size past which the pick changes (picks
            // only change where some level stops meeting the floor).
            let mut thresholds: Vec<f64> = self
                .levels
                .iter()
                .map(|l| l.max_projected_px(self.policy.max_error_px))
                .filter(|t| t.is_finite() && *t >= px)
                .collect();
            thresholds.sort_by(f64::total_cmp);
            for t in thresholds {
                let (j, _) = self.pick(t * (1.0 + 1e-9));
                if j != i {
                    let start = t / (1.0 + band);
                    if px > start {
                        let x = ((px - start) / (t - start)).clamp(0.0, 1.0);
                        blend = Some((self.levels[j], x * x * (3.0 - 2.0 * x)));
                    }
                    break;
                }
            }
        }
        LodDecision {
            projected_px: px,
            level,
            error_px: level.silhouette_error * px,
            met,
            blend,
        }
    }

    /// The decision for `view` of `field` (its bounding sphere in world units).
    ///
    /// # Errors
    /// [`RenderError::View`] for an invalid view.
    pub fn decide_view(&self, field: &GpuLightField, view: &View) -> Result<LodDecision, LodError> {
        let basis = view.basis(u32::MAX).map_err(RenderError::from)?;
        Ok(self.decide(basis.projected_diameter_px(field.center, field.radius)))
    }

    /// The render options of a level (default method, pinned tolerance and guide if any).
    pub fn options(&self, level: &Level) -> RenderOptions {
        RenderOptions {
            lod: Some(level.cameras),
            step: Some(level.step),
            tolerance: self.tolerance,
            method: Method::Default,
            guide: self.guide,
            light: None,
            state: None,
        }
    }

    /// Renders `view` as `decision` says; inside a blend band, one pass in which the fraction
    /// `weight` of pixels (an ordered-dither pattern) renders with the next level.
    ///
    /// # Errors
    /// [`RenderError`] from the renders.
    pub fn render(
        &self,
        renderer: &Renderer,
        field: &GpuLightField,
        view: &View,
        decision: &LodDecision,
    ) -> Result<Frame, LodError> {
        let a = self.options(&decision.level);
        Ok(match decision.blend {
            Some((next, w)) => {
                renderer.render_blend(field, view, &a, &self.options(&next), w as f32)?
            }
            None => renderer.render(field, view, &a)?,
        })
    }

    /// [`Ladder::decide_view`] then [`Ladder::render`].
    ///
    /// # Errors
    /// As those.
    pub fn render_auto(
        &self,
        renderer: &Renderer,
        field: &GpuLightField,
        view: &View,
    ) -> Result<(Frame, LodDecision), LodError> {
        let decision = self.decide_view(field, view)?;
        let frame = self.render(renderer, field, view, &decision)?;
        Ok((frame, decision))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::test_point as point;

    /// A calibration shaped like the measured ones: coarser steps are cheaper and less accurate,
    /// more cameras cost about the same and are more accurate.
    fn calibration() -> Calibration {
        let mut points = Vec::new();
        for (ci, cameras) in [12, 42, 162].into_iter().enumerate() {
            for (si, step) in [1.0 / 8.0, 1.0 / 16.0, 1.0 / 32.0, 1.0 / 64.0]
                .into_iter()
                .enumerate()
            {
                let e = 0.004 * 2f64.powi(-(si as i32)) + 0.008 / f64::from(1 + ci as u32);
                let ms = 300.0 * (1.0 + si as f64) + 3.0 * ci as f64;
                let psnr = 20.0 + 2.0 * ci as f64 + si as f64;
                points.push(point(cameras, step, e, ms, psnr));
            }
        }
        Calibration {
            size: 256,
            views: 4,
            adapter: "test".to_owned(),
            points,
        }
    }

    /// The default policy without the PSNR-drop floor (the synthetic PSNRs span 7 dB).
    fn no_drop() -> LodPolicy {
        LodPolicy {
            max_psnr_drop: None,
            ..LodPolicy::default()
        }
    }

    fn ladder(policy: &LodPolicy, pinned: &RenderOptions) -> Ladder {
        Ladder::new(&calibration(), policy, 162, pinned).expect("ladder")
    }

    #[test]
    fn decisions_meet_the_floor_and_never_coarsen_as_objects_grow() {
        let policy = no_drop();
        let l = ladder(&policy, &RenderOptions::default());
        let mut previous_error = f64::INFINITY;
        let mut switches = 0;
        let mut last = None;
        for k in 0..400 {
            let px = 4.0 * 1.02_f64.powi(k);
            let d = l.decide(px);
            if d.met {
                assert!(d.error_px <= policy.max_error_px + 1e-12, "{d:?}");
            } else {
                // Nothing meets the floor: the most accurate level.
                let best = l
                    .levels()
                    .iter()
                    .map(|x| x.silhouette_error)
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(d.level.silhouette_error, best);
            }
            assert!(
                d.level.silhouette_error <= previous_error,
                "coarser at {px}: {d:?}"
            );
            previous_error = d.level.silhouette_error;
            if last != Some((d.level.cameras, d.level.step.to_bits())) {
                switches += 1;
                last = Some((d.level.cameras, d.level.step.to_bits()));
            }
        }
        // The sweep crosses several levels (small objects get the cheap step, big ones the
        // accurate setting).
        assert!(switches >= 3, "{switches} switches");
        let small = l.decide(8.0);
        assert_eq!(small.level.step, 1.0 / 8.0);
        assert!(small.met);
        let huge = l.decide(1e6);
        assert!(!huge.met);
        assert_eq!((huge.level.cameras, huge.level.step), (162, 1.0 / 64.0));
        // NaN and the eye inside the sphere (infinite size) take the most accurate level.
        assert_eq!(l.decide(f64::NAN).level, huge.level);
        assert_eq!(l.decide(f64::INFINITY).level, huge.level);
        assert_eq!(l.decide(-3.0).level, l.decide(0.0).level);
    }

    #[test]
    fn blend_weights_are_continuous_across_switches() {
        let policy = no_drop();
        let l = ladder(&policy, &RenderOptions::default());
        // Effective (colour) weight of each level as a function of size: continuous means
        // consecutive sizes 0.1 % apart move every level's weight by little.
        let weights = |d: &LodDecision| {
            let mut w = std::collections::BTreeMap::new();
            let fade = d.blend.map_or(0.0, |(_, x)| x);
            *w.entry((d.level.cameras, d.level.step.to_bits()))
                .or_insert(0.0) += 1.0 - fade;
            if let Some((n, x)) = d.blend {
                *w.entry((n.cameras, n.step.to_bits())).or_insert(0.0) += x;
            }
            w
        };
        let mut previous = weights(&l.decide(10.0));
        let mut blended = 0;
        let mut px = 10.0;
        while px < 2000.0 {
            px *= 1.001;
            let d = l.decide(px);
            blended += usize::from(d.blend.is_some());
            let now = weights(&d);
            let keys: std::collections::BTreeSet<_> =
                previous.keys().chain(now.keys()).copied().collect();
            for k in keys {
                let a = previous.get(&k).copied().unwrap_or(0.0);
                let b = now.get(&k).copied().unwrap_or(0.0);
                // Smoothstep over a 25 % band moves at most 1.5 × 0.1 % / (0.25 / 1.25) per
                // step ≈ 0.0075; 0.02 leaves room for the 1e-9 nudges at thresholds.
                assert!(
                    (a - b).abs() < 0.02,
                    "jump at {px}: {previous:?} -> {now:?}"
                );
            }
            previous = now;
        }
        assert!(blended > 100, "{blended} blended sizes");
        // With no band, switches are hard.
        let hard = ladder(
            &LodPolicy {
                blend_band: 0.0,
                ..policy
            },
            &RenderOptions::default(),
        );
        assert!((1..2000).all(|p| hard.decide(f64::from(p)).blend.is_none()));
    }

    #[test]
    fn pinned_knobs_and_floors_restrict_the_choice() {
        let pinned_cams = ladder(
            &no_drop(),
            &RenderOptions {
                lod: Some(42),
                ..RenderOptions::default()
            },
        );
        assert!(pinned_cams.levels().iter().all(|l| l.cameras == 42));
        // A level 0-3 pins too.
        let by_level = ladder(
            &no_drop(),
            &RenderOptions {
                lod: Some(0),
                ..RenderOptions::default()
            },
        );
        assert!(by_level.levels().iter().all(|l| l.cameras == 12));
        let pinned_step = ladder(
            &no_drop(),
            &RenderOptions {
                step: Some(0.03),
                tolerance: Some(0.02),
                ..RenderOptions::default()
            },
        );
        assert!(pinned_step.levels().iter().all(|l| l.step == 0.03));
        // The nearest calibrated step (1/32) stood for 0.03.
        assert!(
            pinned_step.levels().iter().all(|l| calibration()
                .points
                .iter()
                .any(|p| p.cameras == l.cameras
                    && p.step == 1.0 / 32.0
                    && p.silhouette_error == Some(l.silhouette_error)))
        );
        let o = pinned_step.options(&pinned_step.levels()[0]);
        assert_eq!((o.step, o.tolerance), (Some(0.03), Some(0.02)));
        let floor = ladder(
            &LodPolicy {
                min_psnr: Some(25.0),
                ..LodPolicy::default()
            },
            &RenderOptions::default(),
        );
        assert!(floor.levels().iter().all(|l| l.masked_psnr >= 25.0));
        assert!(!floor.levels().is_empty());
    }

    #[test]
    fn dominated_and_needlessly_costly_levels_are_dropped() {
        let c = Calibration {
            size: 256,
            views: 4,
            adapter: "test".to_owned(),
            points: vec![
                point(12, 1.0 / 8.0, 0.008, 600.0, 21.0),
                // Dominated by the next one (costlier and less accurate).
                point(12, 1.0 / 16.0, 0.005, 800.0, 23.0),
                point(42, 1.0 / 8.0, 0.004, 650.0, 23.5),
                point(162, 1.0 / 32.0, 0.0016, 1000.0, 27.0),
                // 5 % more accurate than the level above at 1.5× its cost: dropped.
                point(42, 1.0 / 64.0, 0.00153, 1500.0, 28.0),
            ],
        };
        let l = Ladder::new(&c, &no_drop(), 162, &RenderOptions::default()).expect("ladder");
        let kept: Vec<(u32, f32)> = l.levels().iter().map(|x| (x.cameras, x.step)).collect();
        assert_eq!(
            kept,
            vec![(12, 1.0 / 8.0), (42, 1.0 / 8.0), (162, 1.0 / 32.0)]
        );
        // A large object takes the top level, not the costlier one.
        let d = l.decide(5000.0);
        assert!(!d.met);
        assert_eq!((d.level.cameras, d.level.step), (162, 1.0 / 32.0));
        // The default 2 dB drop below the top level (27 dB) leaves only levels ≥ 25 dB.
        let floor =
            Ladder::new(&c, &LodPolicy::default(), 162, &RenderOptions::default()).expect("ladder");
        let kept: Vec<(u32, f32)> = floor.levels().iter().map(|x| (x.cameras, x.step)).collect();
        assert_eq!(kept, vec![(162, 1.0 / 32.0)]);
        let wide = Ladder::new(
            &c,
            &LodPolicy {
                max_psnr_drop: Some(4.0),
                ..LodPolicy::default()
            },
            162,
            &RenderOptions::default(),
        )
        .expect("ladder");
        assert_eq!(wide.levels().len(), 2, "42 × 1/8 at 23.5 dB joins");
        let unlimited = LodPolicy {
            max_psnr_drop: Some(f64::INFINITY),
            ..LodPolicy::default()
        };
        assert!(Ladder::new(&c, &unlimited, 162, &RenderOptions::default()).is_ok());
    }

    #[test]
    fn policies_from_request_fields() {
        assert_eq!(
            LodPolicy::from_parts(None, None, None, None, true).ok(),
            Some(None)
        );
        assert_eq!(
            LodPolicy::from_parts(Some(0.5), None, None, None, false).ok(),
            Some(Some(LodPolicy {
                max_error_px: 0.5,
                ..LodPolicy::default()
            }))
        );
        for (auto, blend, goal, needle) in [
            (None, Some(0.1), false, "need auto_lod"),
            (Some(1.0), None, true, "not both"),
            (Some(f64::NAN), None, false, "max_error_px"),
            (Some(1.0), Some(3.0), false, "blend_band"),
        ] {
            let err = LodPolicy::from_parts(auto, None, None, blend, goal).expect_err(needle);
            assert!(err.to_string().contains(needle), "{err}");
        }
    }

    #[test]
    fn bad_policies_and_calibrations_are_refused() {
        let c = calibration();
        let none = RenderOptions::default();
        for bad in [
            LodPolicy {
                max_error_px: 0.0,
                ..LodPolicy::default()
            },
            LodPolicy {
                max_error_px: f64::NAN,
                ..LodPolicy::default()
            },
            LodPolicy {
                max_error_px: f64::INFINITY,
                ..LodPolicy::default()
            },
            LodPolicy {
                min_psnr: Some(f64::NAN),
                ..LodPolicy::default()
            },
            LodPolicy {
                blend_band: -0.1,
                ..LodPolicy::default()
            },
            LodPolicy {
                max_psnr_drop: Some(-1.0),
                ..LodPolicy::default()
            },
            LodPolicy {
                max_psnr_drop: Some(f64::NAN),
                ..LodPolicy::default()
            },
            LodPolicy {
                blend_band: 2.0,
                ..LodPolicy::default()
            },
        ] {
            assert!(matches!(
                Ladder::new(&c, &bad, 162, &none),
                Err(LodError::Policy(_))
            ));
        }
        let fixed = RenderOptions {
            method: Method::Fixed,
            ..RenderOptions::default()
        };
        assert!(Ladder::new(&c, &no_drop(), 162, &fixed).is_err());
        let too_high = LodPolicy {
            min_psnr: Some(99.0),
            ..LodPolicy::default()
        };
        assert!(Ladder::new(&c, &too_high, 162, &none).is_err());
        let mut old = c.clone();
        for p in &mut old.points {
            p.silhouette_error = None;
        }
        let err = Ladder::new(&old, &no_drop(), 162, &none).expect_err("old");
        assert!(err.to_string().contains("re-bake"), "{err}");
        // The asset's camera count bounds the levels.
        let small = Ladder::new(&c, &no_drop(), 42, &none).expect("ladder");
        assert!(small.levels().iter().all(|l| l.cameras <= 42));
        assert!(Ladder::new(&c, &no_drop(), 43, &none).is_err());
    }
}
