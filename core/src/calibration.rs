//! A scene's error against cost, measured at bake time and stored in the asset.
//!
//! [`Calibration::measure`] runs a small [`crate::tradeoff`] sweep (the default method at every
//! camera count the asset holds × [`CALIBRATION_STEPS`]) against the source mesh;
//! [`bake_calibrated`] bakes and attaches it to the asset's quality report. A [`Goal`] (a target
//! masked PSNR or a time budget) is then served by [`Calibration::choose`], and automatic LOD
//! ([`crate::lod`]) builds its ladder from the same points.

use serde::Serialize;

use crate::asset::{AssetError, AssetFile, AssetHeader};
use crate::geometry::CAMERA_COUNTS;
use crate::gpu::mesh::GpuMesh;
use crate::reference::{ReferenceError, ReferenceRenderer};
use crate::render::{DEFAULT_GUIDE, Method, RenderError, RenderOptions, Renderer};
use crate::shading::Shading;
use crate::tradeoff::{Grid, SweepInputs, TradeoffError, stored_depth_bits, sweep};
use crate::view::evaluation_views;

/// Errors of calibrations and goals.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CalibrationError {
    /// Both a target PSNR and a time budget were given.
    #[error("give target_psnr or budget_ms, not both")]
    BothGoals,
    /// A target PSNR that is not finite and positive.
    #[error("target PSNR {0} dB must be finite and positive")]
    TargetPsnr(f64),
    /// A time budget that is not finite and positive.
    #[error("budget {0} ms must be finite and positive")]
    BudgetMs(f64),
    /// No calibrated point can be used (none finite, or none within the asset's cameras).
    #[error("the calibration holds no usable setting")]
    NoUsableSetting,
    /// The asset's quality report holds a calibration that does not parse.
    #[error("malformed calibration: {0}")]
    Malformed(String),
    /// No setting could be measured: every error came out undefined, because the calibration
    /// views, framed on the bounding sphere, see none of the mesh's surface (e.g. one vertex far
    /// from the rest makes the sphere so large that the object covers no pixel).
    #[error(
        "the calibration could not measure any setting: its views around the bounding sphere \
         (centre {center:?}, radius {radius} world units) see no surface of the mesh; remove \
         outlying vertices, or bake without calibration"
    )]
    Unmeasurable {
        /// Bounding-sphere centre, world units.
        center: [f64; 3],
        /// Bounding-sphere radius, world units.
        radius: f64,
    },
    /// The calibration sweep failed.
    #[error(transparent)]
    Sweep(#[from] TradeoffError),
    /// A render of the calibration failed.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// A reference render of the calibration failed.
    #[error(transparent)]
    Reference(#[from] ReferenceError),
    /// The bake before a calibration failed.
    #[error(transparent)]
    Bake(#[from] crate::bake::BakeError),
    /// The baked asset could not be read back or re-encoded.
    #[error(transparent)]
    Asset(#[from] AssetError),
    /// A device upload failed.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

/// Coarse-to-fine factor of the calibrated settings: the default method's default, the guide
/// every [`Choice`] renders with.
pub const CALIBRATION_GUIDE: u32 = DEFAULT_GUIDE;

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
/// [`CalibrationError`] from the bake, the calibration renders or the re-encoding.
pub fn bake_calibrated(
    baker: &crate::bake::Baker,
    renderer: &Renderer,
    reference: &ReferenceRenderer,
    mesh: &crate::mesh::Mesh,
    options: &crate::bake::BakeOptions,
    source: &crate::asset::Provenance,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CalibratedBake, CalibrationError> {
    bake_states_calibrated(
        baker,
        renderer,
        reference,
        (mesh, &crate::bake::StateBake::default()),
        options,
        source,
        progress,
    )
}

/// [`bake_calibrated`] with deformation states ([`crate::bake::Baker::bake_states_to_bytes`]);
/// the calibration measures the base state.
///
/// # Errors
/// As [`bake_calibrated`].
pub fn bake_states_calibrated(
    baker: &crate::bake::Baker,
    renderer: &Renderer,
    reference: &ReferenceRenderer,
    (mesh, states): (&crate::mesh::Mesh, &crate::bake::StateBake<'_>),
    options: &crate::bake::BakeOptions,
    source: &crate::asset::Provenance,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CalibratedBake, CalibrationError> {
    let start = std::time::Instant::now();
    let bytes = baker.bake_states_to_bytes(mesh, states, options, source, progress)?;
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

/// A scene's error against cost, measured at bake time and stored in the
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
    /// [`crate::tradeoff::Point::silhouette_error_px`] over the bounding sphere's projected diameter in its
    /// views. Times an object's projected diameter in pixels, it predicts the setting's
    /// silhouette error in pixels (what automatic LOD bounds, [`crate::lod`]). Absent in
    /// calibrations made before it was measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub silhouette_error: Option<f64>,
}

impl CalibrationPoint {
    /// Whether every value of the point is a finite number (what JSON can store and goals use).
    pub fn is_measured(&self) -> bool {
        self.ms_per_mpx.is_finite()
            && self.masked_psnr.is_finite()
            && self.depth_median_r.is_finite()
            && self.silhouette_error.is_none_or(f64::is_finite)
    }
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
    /// [`CalibrationError::BothGoals`] when both are given. The values themselves are checked
    /// by [`Goal::validate`].
    pub fn from_pair(
        target_psnr: Option<f64>,
        budget_ms: Option<f64>,
    ) -> Result<Option<Goal>, CalibrationError> {
        match (target_psnr, budget_ms) {
            (Some(_), Some(_)) => Err(CalibrationError::BothGoals),
            (Some(db), None) => Ok(Some(Goal::TargetPsnr(db))),
            (None, Some(ms)) => Ok(Some(Goal::BudgetMs(ms))),
            (None, None) => Ok(None),
        }
    }

    /// Checks the goal's value.
    ///
    /// # Errors
    /// [`CalibrationError::TargetPsnr`] / [`CalibrationError::BudgetMs`] for a non-finite or
    /// non-positive value.
    pub fn validate(self) -> Result<(), CalibrationError> {
        match self {
            Goal::TargetPsnr(db) if !(db.is_finite() && db > 0.0) => {
                Err(CalibrationError::TargetPsnr(db))
            }
            Goal::BudgetMs(ms) if !(ms.is_finite() && ms > 0.0) => {
                Err(CalibrationError::BudgetMs(ms))
            }
            _ => Ok(()),
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
    /// The render options of the choice: the calibrated setting exactly as it was measured
    /// (default method, tolerance step / 2, guide [`CALIBRATION_GUIDE`]). A goal decides every
    /// knob the prediction depends on, so none is taken from the request
    /// ([`crate::quality::Quality::validate`] refuses a goal sent with knobs).
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: Some(self.cameras),
            step: Some(self.step),
            tolerance: None,
            method: Method::Default,
            guide: Some(CALIBRATION_GUIDE),
            light: None,
            state: None,
        }
    }
}

impl Calibration {
    /// Measures the calibration of `inputs.asset` (its views are replaced by the calibration
    /// views around the asset's bounding sphere).
    ///
    /// # Errors
    /// [`CalibrationError`] from the sweep.
    pub fn measure(
        renderer: &Renderer,
        reference: &ReferenceRenderer,
        asset: &AssetFile,
        mesh: &GpuMesh,
        shading: &Shading,
        adapter: &str,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Calibration, CalibrationError> {
        let frame = &asset.header().frame;
        let views = evaluation_views(
            frame.center,
            frame.radius,
            CALIBRATION_VIEWS,
            0,
            CALIBRATION_SIZE,
        );
        let max_level = usize::from(asset.header().camera_level().unwrap_or(0)).min(3);
        let grid = Grid {
            cameras: CAMERA_COUNTS[..=max_level].to_vec(),
            steps: CALIBRATION_STEPS.to_vec(),
            tolerance_factors: vec![0.5],
            methods: vec![Method::Default],
            guides: vec![CALIBRATION_GUIDE],
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
        let projected = views[0]
            .basis(u32::MAX)
            .map_err(RenderError::from)?
            .projected_diameter_px(frame.center.into(), frame.radius);
        // A setting whose error is undefined (nothing seen) is left out: JSON has no NaN, and
        // no goal could use it. With none left, the asset would carry a calibration no render
        // can use, so the bake is refused instead.
        let points: Vec<CalibrationPoint> = sweep(&inputs, &grid, progress)?
            .into_iter()
            .map(|p| CalibrationPoint {
                cameras: p.setting.cameras,
                step: p.setting.step,
                ms_per_mpx: p.ms_per_frame / mpx,
                masked_psnr: p.masked_psnr,
                depth_median_r: p.depth_median_r,
                silhouette_error: Some(p.silhouette_error_px / projected).filter(|e| e.is_finite()),
            })
            .filter(CalibrationPoint::is_measured)
            .collect();
        if points.is_empty() {
            return Err(CalibrationError::Unmeasurable {
                center: frame.center,
                radius: frame.radius,
            });
        }
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
        crate::asset::with_header(asset, header)
    }

    /// The calibration in an asset's quality report, if any.
    ///
    /// # Errors
    /// [`CalibrationError::Malformed`] when a report is there but malformed.
    pub fn from_quality(
        quality: Option<&serde_json::Value>,
    ) -> Result<Option<Calibration>, CalibrationError> {
        match quality.and_then(|q| q.get("calibration")) {
            None => Ok(None),
            Some(value) => {
                check_no_unmeasured_values(value)?;
                serde_json::from_value(value.clone())
                    .map(Some)
                    .map_err(|e| CalibrationError::Malformed(e.to_string()))
            }
        }
    }

    /// The calibration stored in an asset's header, if any.
    ///
    /// # Errors
    /// [`CalibrationError::Malformed`] when a report is there but malformed.
    pub fn of(header: &AssetHeader) -> Result<Option<Calibration>, CalibrationError> {
        Self::from_quality(header.quality.as_ref())
    }

    /// Picks the setting for `goal` at `width × height` among points with at most
    /// `max_cameras` cameras.
    ///
    /// # Errors
    /// [`CalibrationError`] for a non-finite or non-positive goal, or no usable point.
    pub fn choose(
        &self,
        goal: Goal,
        width: u32,
        height: u32,
        max_cameras: u32,
    ) -> Result<Choice, CalibrationError> {
        goal.validate()?;
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
        let (point, predicted_ms) = pick.ok_or(CalibrationError::NoUsableSetting)?;
        Ok(Choice {
            cameras: point.cameras,
            step: point.step,
            predicted_psnr: point.masked_psnr,
            predicted_ms: *predicted_ms,
            met,
        })
    }
}

/// Names the first required value stored as `null` in a calibration's points: what earlier
/// versions wrote for an error they could not measure (NaN), which no goal can use.
fn check_no_unmeasured_values(calibration: &serde_json::Value) -> Result<(), CalibrationError> {
    let Some(points) = calibration
        .get("points")
        .and_then(serde_json::Value::as_array)
    else {
        return Ok(());
    };
    for (i, point) in points.iter().enumerate() {
        let Some(fields) = point.as_object() else {
            continue;
        };
        // `silhouette_error` is optional: null there reads as absent.
        let missing: Vec<&str> = fields
            .iter()
            .filter(|(name, value)| value.is_null() && name.as_str() != "silhouette_error")
            .map(|(name, _)| name.as_str())
            .collect();
        if !missing.is_empty() {
            return Err(CalibrationError::Malformed(format!(
                "point {i} ({} cameras, step {}) has no {}: the bake could not measure it; bake \
                 the asset again (this version refuses such a bake)",
                fields.get("cameras").unwrap_or(&serde_json::Value::Null),
                fields.get("step").unwrap_or(&serde_json::Value::Null),
                missing.join(" and "),
            )));
        }
    }
    Ok(())
}

/// A calibration point for unit tests: `cameras` × `step`, silhouette error `e` px, `ms` per
/// megapixel, masked PSNR `psnr`.
#[cfg(test)]
pub(crate) fn test_point(cameras: u32, step: f32, e: f64, ms: f64, psnr: f64) -> CalibrationPoint {
    CalibrationPoint {
        cameras,
        step,
        ms_per_mpx: ms,
        masked_psnr: psnr,
        depth_median_r: 1e-3,
        silhouette_error: Some(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unmeasured_values_are_named_on_read_and_never_written() {
        let mut value = serde_json::to_value(calibration()).unwrap();
        value["points"][1]["masked_psnr"] = serde_json::Value::Null;
        value["points"][1]["depth_median_r"] = serde_json::Value::Null;
        let quality = serde_json::json!({ "calibration": value });
        let err = Calibration::from_quality(Some(&quality)).unwrap_err();
        let message = err.to_string();
        assert!(matches!(err, CalibrationError::Malformed(_)), "{message}");
        for part in ["point 1", "masked_psnr", "bake the asset again"] {
            assert!(message.contains(part), "{part:?} not in {message:?}");
        }
        // A null silhouette error is an absent one.
        let mut value = serde_json::to_value(calibration()).unwrap();
        value["points"][0]["silhouette_error"] = serde_json::Value::Null;
        let quality = serde_json::json!({ "calibration": value });
        assert!(Calibration::from_quality(Some(&quality)).unwrap().is_some());
        // What measure keeps is what JSON can hold.
        let mut point = calibration().points[0];
        assert!(point.is_measured());
        point.masked_psnr = f64::NAN;
        assert!(!point.is_measured());
        point.masked_psnr = 30.0;
        point.silhouette_error = Some(f64::INFINITY);
        assert!(!point.is_measured());
    }

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
}
