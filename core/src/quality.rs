//! The quality request: how to render, in one type every front speaks.
//!
//! A [`Quality`] is explicit knobs (cameras, step, tolerance, method, guide), or a goal
//! (`target_psnr` / `budget_ms`, served by the asset's [`Calibration`]), or automatic LOD
//! (`auto_lod` with its floors and blend, [`crate::lod`]). [`Quality::validate`] decides every
//! conflict once; [`Quality::plan`] turns the request and an asset's header into a [`Plan`];
//! [`Plan::render`] renders a view with it and returns the frame with the [`Decision`] taken.
//! The CLI flags, the HTTP body, the stream's sticky settings and the Python keyword arguments
//! are this type's fields: a knob added here reaches every front.
//!
//! ```text
//!  Quality ──validate──▶ plan(header) ──▶ Plan { Options | Goal(calibration) | Lod(ladder)
//!                                                 | TwoPlane(options) }
//!                                            ├──render(renderer, field, view)──▶ Frame + Decision
//!                                            └──render_two_plane(..)──────────▶ Frame + Decision
//! ```

use std::sync::Arc;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::asset::AssetHeader;
use crate::calibration::{Calibration, CalibrationError, Choice, Goal};
use crate::frame::Frame;
use crate::layers::{LayerImage, LayerOpacities};
use crate::lod::{
    DEFAULT_BLEND_BAND, DEFAULT_MAX_PSNR_DROP, Ladder, LodDecision, LodError, LodPolicy,
};
use crate::refine::{self, RefineError};
use crate::render::{GpuLightField, Method, RenderError, RenderOptions, Renderer, ResolvedOptions};
use crate::two_plane_render::{GpuTwoPlane, TwoPlaneOptions, TwoPlaneRenderer, UvFilter};
use crate::view::View;

/// Highest icosphere level an asset can hold: knob ranges are checked against it before an
/// asset is known.
const MAX_LEVEL: u32 = 3;

/// Errors of a quality request: one variant, and one text, per conflict.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum QualityError {
    /// `target_psnr` and `budget_ms` together.
    #[error("give target_psnr or budget_ms, not both")]
    BothGoals,
    /// A goal with `auto_lod`.
    #[error("automatic LOD: give auto_lod or target_psnr / budget_ms, not both")]
    LodWithGoal,
    /// `lod_min_psnr`, `lod_max_psnr_drop` or `lod_blend` without `auto_lod`.
    #[error("automatic LOD: lod_min_psnr / lod_max_psnr_drop / lod_blend need auto_lod")]
    FloorsWithoutLod,
    /// A goal with explicit knobs: the calibration measured its settings with the default
    /// method, tolerance step / 2 and guide 4, so a goal decides all of them (a kept `guide`
    /// would change the time the prediction promises).
    #[error(
        "target_psnr / budget_ms choose lod, step, tolerance, method and guide: do not send them \
         too (clear them first where they were set before)"
    )]
    GoalWithKnobs,
    /// A goal or automatic LOD on an asset baked without calibration.
    #[error(
        "the asset has no calibration: re-bake it with calibration on (`lumigraph bake` without \
         --no-calibrate, POST /v1/bake with calibrate=true, bake_mesh(calibrate=True) in Python) \
         to render with {0}"
    )]
    NoCalibration(&'static str),
    /// Quality options sent with a scene, whose objects carry their own.
    #[error(
        "quality options do not apply to a scene: set \"options\" / \"auto_lod\" per light-field \
         object in the scene file (docs/scene.md)"
    )]
    Scene,
    /// Layer opacities out of range, or naming a layer the asset does not have.
    #[error("layers: {0}")]
    Layers(String),
    /// An unknown state, or a light state asked for by name.
    #[error("state: {0}")]
    State(String),
    /// A time or frame the asset's animation does not have, or none to show.
    #[error("animation: {0}")]
    Animation(String),
    /// The request is not a JSON object of quality fields.
    #[error("invalid quality options: {0}")]
    Json(String),
    /// A knob out of range, a bad view or a failed render.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// A goal out of range or a calibration that cannot serve it.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// An automatic-LOD policy out of range or with no level left.
    #[error(transparent)]
    Lod(#[from] LodError),
    /// A still-refinement sample count out of range.
    #[error(transparent)]
    Refine(#[from] RefineError),
    /// Options of one kind of light field asked of another (spherical knobs of a two-plane
    /// asset, or the reverse).
    #[error("{0}")]
    Kind(String),
}

/// How to render: explicit knobs, a goal, or automatic LOD (see the module doc). Every field is
/// optional; absent knobs take the method's defaults.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Quality {
    /// Cameras to use: 12, 42, 162 or 642 (or a level 0-3), at most the asset's; default all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub lod: Option<u32>,
    /// March step in bounding-sphere diameters, in [1/4096, 1] (default 1/32; fixed: 1/64).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub step: Option<f32>,
    /// Depth agreement tolerance in bounding-sphere diameters, in (0, 1] (default step / 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tolerance: Option<f32>,
    /// Marching method: default (the accelerated marcher) or fixed (the fixed-step baseline).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    #[cfg_attr(feature = "openapi", schema(inline))]
    pub method: Option<Method>,
    /// Coarse-to-fine factor of the default method, 2-16 (0 = off; default 4): a coarse pass
    /// renders every F-th pixel per axis and bounds each pixel's march (BENCHMARKS.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "F", allow_hyphen_values = true)
    )]
    pub guide: Option<u32>,
    /// Goal: the cheapest setting the asset's calibration predicts to reach this masked PSNR
    /// (dB), chosen per frame size; excludes the knobs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub target_psnr: Option<f64>,
    /// Goal: the most accurate setting the calibration predicts to render within this many
    /// milliseconds at the frame's size; excludes the knobs and target_psnr.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub budget_ms: Option<f64>,
    /// Automatic LOD: per view, the cheapest cameras and step whose calibrated silhouette error
    /// at the object's projected size stays under PX pixels (bare flag: 1); lod / step given
    /// as well stay pinned; cross-fades near switches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(
            long,
            value_name = "PX",
            num_args = 0..=1,
            require_equals = true,
            default_missing_value = "1",
            allow_hyphen_values = true
        )
    )]
    pub auto_lod: Option<f64>,
    /// With auto_lod: only settings whose calibrated masked PSNR reaches DB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "DB", allow_hyphen_values = true)
    )]
    pub lod_min_psnr: Option<f64>,
    /// With auto_lod: only settings within DB of the most accurate level's calibrated masked
    /// PSNR (default 2; inf: no limit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "DB", allow_hyphen_values = true)
    )]
    pub lod_max_psnr_drop: Option<f64>,
    /// With auto_lod: cross-fade band below each switch, as a fraction of the projected size
    /// (default 0.15; 0 = hard switches).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "FRACTION", allow_hyphen_values = true)
    )]
    pub lod_blend: Option<f64>,
    /// Still refinement: accumulate this many jittered sub-pixel samples per pixel into an
    /// anti-aliased frame, rejecting stray wrong-surface samples (1..=256; default 1 = a single
    /// sample). Frames of a moving stream view stay single-sample (docs/refine.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "SAMPLES", allow_hyphen_values = true)
    )]
    pub refine: Option<u32>,
    /// Runtime opacity per named layer of a multi light field, each in [0, 1]
    /// (`skin=0.3,bone=1`; JSON: `{"skin": 0.3, "bone": 1}`); layers not named keep the
    /// asset's default. Layers composite per pixel in depth order (DESIGN §9); depth layers in
    /// their order along the ray.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "NAME=OPACITY,...", allow_hyphen_values = true)
    )]
    #[cfg_attr(feature = "openapi", schema(value_type = Option<std::collections::BTreeMap<String, f32>>))]
    pub layers: Option<LayerOpacities>,
    /// Relight with this world-space light direction (towards the light; `X,Y,Z`, JSON
    /// `[x, y, z]`), blended from the asset's light states (an asset baked with `--lights`;
    /// DESIGN §9). Absent: the light the asset was baked with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)
    )]
    #[cfg_attr(feature = "openapi", schema(value_type = Option<[f64; 3]>))]
    pub light: Option<crate::light::LightDirection>,
    /// Render this named state of the asset: a deformation state (baked with `--state
    /// NAME=MESH2`). Absent or `base`: the base state. Light states are not chosen by name:
    /// `light` relights from them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAME"))]
    pub state: Option<String>,
    /// Show the animation frame at this time, seconds from the animation's start (an asset
    /// baked with `--animation`): the last frame at or before it. Excludes `frame` and `state`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "SECONDS", allow_hyphen_values = true)
    )]
    pub time: Option<f64>,
    /// Show this animation frame (0 = the first). Excludes `time` and `state`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "N", allow_hyphen_values = true)
    )]
    pub frame: Option<u32>,
    /// Two-plane light fields: how the cameras around a ray's uv crossing combine when
    /// `aperture` is 0: nearest, bilinear (default), dither or depth (depth-corrected;
    /// docs/two_plane.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, value_name = "FILTER"))]
    #[cfg_attr(feature = "openapi", schema(value_type = Option<String>))]
    pub uv_filter: Option<UvFilter>,
    /// Two-plane light fields: the focal plane, a signed distance in world units from the st
    /// plane towards the uv plane (default 0: the st plane; DESIGN §9).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub focus: Option<f64>,
    /// Two-plane light fields: synthetic aperture radius in uv cells (default 0: the pinhole
    /// view through `uv_filter`). A wide aperture draws a bounded set of cameras per frame;
    /// `refine` N averages N draws (the full aperture as N grows).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub aperture: Option<f64>,
}

impl Quality {
    /// The keys of a quality request, as its JSON spells them: what a front splits off a flat
    /// body or keyword dict before [`Quality::from_json_map`].
    pub const FIELDS: &[&str] = &[
        "lod",
        "step",
        "tolerance",
        "method",
        "guide",
        "target_psnr",
        "budget_ms",
        "auto_lod",
        "lod_min_psnr",
        "lod_max_psnr_drop",
        "lod_blend",
        "refine",
        "layers",
        "light",
        "state",
        "time",
        "frame",
        "uv_filter",
        "focus",
        "aperture",
    ];

    /// The request of a JSON object holding only quality keys (`null` = absent).
    ///
    /// # Errors
    /// [`QualityError::Json`] for an unknown key or a value of the wrong type.
    pub fn from_json_map(
        map: serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self, QualityError> {
        serde_json::from_value(serde_json::Value::Object(map.clone())).map_err(|whole| {
            // serde's message does not say which key was bad: find it by parsing each alone.
            for (key, value) in map {
                let one = serde_json::Map::from_iter([(key.clone(), value)]);
                if let Err(e) = serde_json::from_value::<Quality>(serde_json::Value::Object(one)) {
                    let text = e.to_string();
                    let named = format!("`{key}`");
                    return QualityError::Json(if text.contains(&named) {
                        text
                    } else {
                        format!("{named}: {text}")
                    });
                }
            }
            QualityError::Json(whole.to_string())
        })
    }

    /// Removes the quality keys ([`Quality::FIELDS`]) from a flat JSON object (a request body,
    /// keyword arguments) and parses them; the front's own keys stay in `map`.
    ///
    /// # Errors
    /// As [`Quality::from_json_map`].
    pub fn take_from(
        map: &mut serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self, QualityError> {
        let mut own = serde_json::Map::new();
        for key in Self::FIELDS {
            if let Some(value) = map.remove(*key) {
                own.insert((*key).to_owned(), value);
            }
        }
        Self::from_json_map(own)
    }

    /// The explicit knobs as render options (absent: the method's defaults).
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: self.lod,
            step: self.step,
            tolerance: self.tolerance,
            method: self.method.unwrap_or_default(),
            guide: self.guide,
            light: self.light,
            state: None,
        }
    }

    /// The two-plane options of the request (absent: the defaults).
    pub fn two_plane_options(&self) -> TwoPlaneOptions {
        let mut options = TwoPlaneOptions::default();
        if let Some(filter) = self.uv_filter {
            options.uv_filter = filter;
        }
        if let Some(focus) = self.focus {
            options.focus = focus;
        }
        if let Some(aperture) = self.aperture {
            options.aperture = aperture;
        }
        options
    }

    /// The two-plane keys set, by name.
    fn two_plane_keys(&self) -> Vec<&'static str> {
        [
            ("uv_filter", self.uv_filter.is_some()),
            ("focus", self.focus.is_some()),
            ("aperture", self.aperture.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect()
    }

    /// The keys set that only spherical light fields take, by name.
    fn spherical_keys(&self) -> Vec<&'static str> {
        [
            ("lod", self.lod.is_some()),
            ("step", self.step.is_some()),
            ("tolerance", self.tolerance.is_some()),
            ("method", self.method.is_some()),
            ("guide", self.guide.is_some()),
            ("target_psnr", self.target_psnr.is_some()),
            ("budget_ms", self.budget_ms.is_some()),
            ("auto_lod", self.auto_lod.is_some()),
            ("lod_min_psnr", self.lod_min_psnr.is_some()),
            ("lod_max_psnr_drop", self.lod_max_psnr_drop.is_some()),
            ("lod_blend", self.lod_blend.is_some()),
            ("layers", self.layers.is_some()),
            ("light", self.light.is_some()),
            ("state", self.state.is_some()),
            ("time", self.time.is_some()),
            ("frame", self.frame.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect()
    }

    /// Whether any explicit knob is set.
    fn has_knobs(&self) -> bool {
        self.lod.is_some()
            || self.step.is_some()
            || self.tolerance.is_some()
            || self.method.is_some()
            || self.guide.is_some()
    }

    /// The goal, if one is asked for (after [`Quality::validate`]: at most one).
    fn goal(&self) -> Option<Goal> {
        match (self.target_psnr, self.budget_ms) {
            (Some(db), _) => Some(Goal::TargetPsnr(db)),
            (None, Some(ms)) => Some(Goal::BudgetMs(ms)),
            (None, None) => None,
        }
    }

    /// The automatic-LOD policy, if `auto_lod` is set (defaults for absent floors and band).
    fn policy(&self) -> Option<LodPolicy> {
        self.auto_lod.map(|max_error_px| LodPolicy {
            max_error_px,
            min_psnr: self.lod_min_psnr,
            max_psnr_drop: Some(self.lod_max_psnr_drop.unwrap_or(DEFAULT_MAX_PSNR_DROP)),
            blend_band: self.lod_blend.unwrap_or(DEFAULT_BLEND_BAND),
        })
    }

    /// Checks every conflict and every range that needs no asset, in this order: both goals,
    /// a goal with auto_lod, floors without auto_lod, a goal with knobs, then the values.
    ///
    /// # Errors
    /// The [`QualityError`] of the first conflict or bad value.
    pub fn validate(&self) -> Result<(), QualityError> {
        let goal = self.target_psnr.is_some() || self.budget_ms.is_some();
        if self.target_psnr.is_some() && self.budget_ms.is_some() {
            return Err(QualityError::BothGoals);
        }
        if goal && self.auto_lod.is_some() {
            return Err(QualityError::LodWithGoal);
        }
        if self.auto_lod.is_none()
            && (self.lod_min_psnr.is_some()
                || self.lod_max_psnr_drop.is_some()
                || self.lod_blend.is_some())
        {
            return Err(QualityError::FloorsWithoutLod);
        }
        if goal && self.has_knobs() {
            return Err(QualityError::GoalWithKnobs);
        }
        if let Some(goal) = self.goal() {
            goal.validate()?;
        }
        let options = self.options();
        if let Some(policy) = self.policy() {
            policy.validate()?;
            crate::lod::check_pinned(&options)?;
        }
        options.resolve(MAX_LEVEL)?;
        if let Some(samples) = self.refine {
            refine::validate_samples(samples)?;
        }
        if let Some(layers) = &self.layers {
            layers.validate().map_err(QualityError::Layers)?;
        }
        if let Some(light) = &self.light {
            light.unit().map_err(RenderError::from)?;
        }
        let named = [
            self.time.is_some(),
            self.frame.is_some(),
            self.state.is_some(),
        ];
        if named.iter().filter(|&&b| b).count() > 1 {
            return Err(QualityError::Animation(
                "give one of time, frame and state".to_owned(),
            ));
        }
        if let Some(t) = self.time
            && !(t.is_finite() && t >= 0.0)
        {
            return Err(QualityError::Animation(format!(
                "time {t}: give a finite time ≥ 0 in seconds"
            )));
        }
        self.two_plane_options().validate()?;
        Ok(())
    }

    /// The quality of frames while a stream's view moves: the knobs and automatic LOD apply;
    /// a goal does not (it is chosen for resting frames, whose size it predicts for).
    #[must_use]
    pub fn for_motion(&self) -> Quality {
        Quality {
            target_psnr: None,
            budget_ms: None,
            refine: None,
            ..self.clone()
        }
    }

    /// Checks that no quality option comes with a scene: its light-field objects carry their
    /// own (docs/scene.md).
    ///
    /// # Errors
    /// [`QualityError::Scene`] when any field is set.
    pub fn check_scene(&self) -> Result<(), QualityError> {
        if *self == Quality::default() {
            Ok(())
        } else {
            Err(QualityError::Scene)
        }
    }

    /// The plan of this request for an asset: the knobs checked against its cameras, or its
    /// calibration read for a goal or automatic LOD.
    ///
    /// # Errors
    /// [`QualityError`] for a conflict, a bad value, a missing or malformed calibration, or no
    /// automatic-LOD level left.
    pub fn plan(&self, header: &AssetHeader) -> Result<Plan, QualityError> {
        self.validate()?;
        if let Some(planes) = header.two_plane() {
            let spherical = self.spherical_keys();
            if !spherical.is_empty() {
                return Err(QualityError::Kind(format!(
                    "{} apply to spherical light fields; a two-plane light field takes \
                     uv_filter, focus, aperture and refine",
                    spherical.join(", ")
                )));
            }
            return Ok(Plan {
                strategy: Strategy::TwoPlane(self.two_plane_options()),
                opacities: Vec::new(),
                state: None,
                quality: self.clone(),
                max_level: 0,
                max_cameras: planes.camera_count(),
                center: DVec3::from(header.frame.center),
                radius: header.frame.radius,
            });
        }
        let two_plane = self.two_plane_keys();
        if !two_plane.is_empty() {
            return Err(QualityError::Kind(format!(
                "{} apply to two-plane light fields; this asset is {}",
                two_plane.join(", "),
                header.kind.name()
            )));
        }
        let max_level = u32::from(header.camera_level().unwrap_or(0));
        let max_cameras = header.camera_count();
        let options = self.options();
        options.resolve(max_level)?;
        let calibration = |how: &'static str| -> Result<Calibration, QualityError> {
            Calibration::of(header)?.ok_or(QualityError::NoCalibration(how))
        };
        let strategy = if let Some(policy) = self.policy() {
            let ladder = Ladder::new(&calibration("auto_lod")?, &policy, max_cameras, &options)?;
            Strategy::Lod(Arc::new(ladder))
        } else if let Some(goal) = self.goal() {
            Strategy::Goal {
                goal,
                calibration: Arc::new(calibration("target_psnr / budget_ms")?),
            }
        } else {
            Strategy::Options(options)
        };
        if self.light.is_some()
            && crate::light::LightStates::of(header)
                .map_err(RenderError::from)?
                .is_none()
        {
            return Err(RenderError::from(crate::light::LightError::NoLightStates).into());
        }
        let opacities = self
            .layers
            .clone()
            .unwrap_or_default()
            .resolve(&header.layers)
            .map_err(QualityError::Layers)?;
        let state = match (self.time, self.frame) {
            (None, None) => crate::deform::state_index(header, self.state.as_deref())
                .map_err(QualityError::State)?,
            (time, frame) => {
                let animation = crate::deform::AnimationInfo::of(header).ok_or_else(|| {
                    QualityError::Animation(
                        "the asset has no animation: bake it with --animation".to_owned(),
                    )
                })?;
                let frame = match (time, frame) {
                    (Some(t), _) => animation.frame_at(t).map_err(QualityError::Animation)?,
                    (None, Some(f)) => f,
                    (None, None) => 0,
                };
                let s = animation
                    .state_of_frame(frame)
                    .map_err(QualityError::Animation)?;
                (s != 0).then_some(s)
            }
        };
        Ok(Plan {
            state,
            strategy,
            opacities,
            quality: self.clone(),
            max_level,
            max_cameras,
            center: DVec3::from(header.frame.center),
            radius: header.frame.radius,
        })
    }
}

/// How a plan picks each view's settings.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub enum Strategy {
    /// These options for every view.
    Options(RenderOptions),
    /// The calibration's choice for the goal at each view's size.
    Goal {
        /// The goal.
        goal: Goal,
        /// The asset's calibration.
        calibration: Arc<Calibration>,
    },
    /// The ladder's choice for each view's projected size (one blended pass inside a band).
    Lod(Arc<Ladder>),
    /// A two-plane light field's options ([`Plan::render_two_plane`]).
    TwoPlane(TwoPlaneOptions),
}

/// A quality request planned for one asset: cheap to clone and to share between threads.
#[derive(Clone, Debug)]
pub struct Plan {
    strategy: Strategy,
    /// Opacity of every layer of the asset, in its order.
    opacities: Vec<f32>,
    /// The deformation state rendered (`None`: the base state).
    state: Option<u16>,
    quality: Quality,
    max_level: u32,
    max_cameras: u32,
    center: DVec3,
    radius: f64,
}

/// What a plan decided for one view, with the predictions behind it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Decision {
    /// The settings the frame renders with (inside a blend band, those of most pixels).
    pub settings: ResolvedOptions,
    /// The calibrated choice, for a goal.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub choice: Option<Choice>,
    /// The automatic-LOD decision, with `auto_lod`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lod: Option<LodDecision>,
    /// The options of a two-plane light field's frame, and the aperture draws it averages.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub two_plane: Option<TwoPlaneDecision>,
}

/// What a two-plane frame rendered with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TwoPlaneDecision {
    /// uv filter.
    pub uv_filter: UvFilter,
    /// Focal plane, world units from st towards uv.
    pub focus: f64,
    /// Aperture radius in uv cells.
    pub aperture: f64,
    /// Stratified aperture draws averaged.
    pub draws: u32,
}

/// A rendered view with the decision behind it.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// The frame.
    pub frame: Frame,
    /// What was decided.
    pub decision: Decision,
}

impl Decision {
    /// Cameras the frame renders with.
    pub fn cameras(&self) -> u32 {
        self.settings.cameras
    }

    /// The decision as (name, value) pairs in the form every front reports (HTTP sends each as
    /// an `X-` header): the calibrated choice of a goal, or the automatic-LOD decision; none
    /// for explicit knobs.
    pub fn report(&self) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        if let Some(c) = &self.choice {
            out.extend([
                ("chosen-cameras", c.cameras.to_string()),
                ("chosen-step", c.step.to_string()),
                ("predicted-psnr", format!("{:.3}", c.predicted_psnr)),
                ("predicted-ms", format!("{:.3}", c.predicted_ms)),
                ("goal-met", c.met.to_string()),
            ]);
        }
        if let Some(t) = &self.two_plane {
            out.extend([
                ("uv-filter", t.uv_filter.name().to_owned()),
                ("focus", t.focus.to_string()),
                ("aperture", t.aperture.to_string()),
                ("aperture-draws", t.draws.to_string()),
            ]);
        }
        if let Some(d) = &self.lod {
            out.extend([
                ("projected-px", format!("{:.2}", d.projected_px)),
                ("chosen-cameras", d.level.cameras.to_string()),
                ("chosen-step", d.level.step.to_string()),
                ("predicted-error-px", format!("{:.3}", d.error_px)),
                ("predicted-psnr", format!("{:.3}", d.level.masked_psnr)),
                ("goal-met", d.met.to_string()),
            ]);
            if let Some((next, w)) = d.blend {
                out.push((
                    "lod-blend",
                    format!("{},{},{w:.4}", next.cameras, next.step),
                ));
            }
        }
        out
    }
}

impl Plan {
    /// How the plan picks settings.
    pub fn strategy(&self) -> &Strategy {
        &self.strategy
    }

    /// The request the plan was made from.
    pub fn quality(&self) -> &Quality {
        &self.quality
    }

    /// The geometry state the plan renders (`None`: the base state).
    pub fn state(&self) -> Option<u16> {
        self.state
    }

    /// The same plan rendering another geometry state (an animation frame a player advances
    /// to; `None` or 0: the base state). The caller names a state of the same asset.
    #[must_use]
    pub fn with_state(&self, state: Option<u16>) -> Plan {
        Plan {
            state: state.filter(|&s| s != 0),
            ..self.clone()
        }
    }

    /// The decision for `view`, without rendering.
    ///
    /// # Errors
    /// [`QualityError`] for a bad view or a goal the calibration cannot serve.
    pub fn decide(&self, view: &View) -> Result<Decision, QualityError> {
        self.job(view).map(|(decision, _)| decision)
    }

    /// The decision for `view` and the render it asks for.
    fn job(&self, view: &View) -> Result<(Decision, Job), QualityError> {
        // The light and the state apply whatever the strategy chose.
        let light = |mut options: RenderOptions| {
            options.light = self.quality.light;
            options.state = self.state;
            options
        };
        let (decision, job) = self.job_unlit(view)?;
        let job = match job {
            Job::Single(a) => Job::Single(light(a)),
            Job::Blend(a, b, w) => Job::Blend(light(a), light(b), w),
        };
        Ok((decision, job))
    }

    /// [`Plan::job`] before its light is set.
    fn job_unlit(&self, view: &View) -> Result<(Decision, Job), QualityError> {
        Ok(match &self.strategy {
            Strategy::Options(options) => (
                Decision {
                    settings: options.resolve(self.max_level)?,
                    choice: None,
                    lod: None,
                    two_plane: None,
                },
                Job::Single(*options),
            ),
            Strategy::TwoPlane(_) => {
                return Err(QualityError::Kind(
                    "this plan is for a two-plane light field: render it with the two-plane \
                     renderer"
                        .to_owned(),
                ));
            }
            Strategy::Goal { goal, calibration } => {
                let choice =
                    calibration.choose(*goal, view.width, view.height, self.max_cameras)?;
                let options = choice.options();
                (
                    Decision {
                        settings: options.resolve(self.max_level)?,
                        choice: Some(choice),
                        lod: None,
                        two_plane: None,
                    },
                    Job::Single(options),
                )
            }
            Strategy::Lod(ladder) => {
                let basis = view.basis(u32::MAX).map_err(RenderError::from)?;
                let d = ladder.decide(basis.projected_diameter_px(self.center, self.radius));
                let options = ladder.options(&d.level);
                let job = match d.blend {
                    Some((next, w)) => Job::Blend(options, ladder.options(&next), w as f32),
                    None => Job::Single(options),
                };
                (
                    Decision {
                        settings: options.resolve(self.max_level)?,
                        choice: None,
                        lod: Some(d),
                        two_plane: None,
                    },
                    job,
                )
            }
        })
    }

    /// Renders `view` of `field` (the asset the plan was made for) as the plan decides.
    ///
    /// # Errors
    /// [`QualityError`] for a bad view, a goal the calibration cannot serve or a failed render.
    pub fn render(
        &self,
        renderer: &Renderer,
        field: &GpuLightField,
        view: &View,
    ) -> Result<Rendered, QualityError> {
        let (decision, job) = self.job(view)?;
        let (a, b, weight) = match job {
            Job::Single(options) => (options, options, 0.0),
            Job::Blend(a, b, weight) => (a, b, weight),
        };
        let opacities = &self.opacities;
        let frame = match self.quality.refine {
            None | Some(1) => {
                renderer.render_layered(field, view, (&a, &b, weight), [0.0; 2], opacities)?
            }
            Some(samples) => refine::refine(samples, |jitter| {
                renderer
                    .render_layered(field, view, (&a, &b, weight), jitter, opacities)
                    .map_err(QualityError::from)
            })?,
        };
        Ok(Rendered { frame, decision })
    }

    /// The two-plane options of a plan made for a two-plane light field.
    pub fn two_plane(&self) -> Option<&TwoPlaneOptions> {
        match &self.strategy {
            Strategy::TwoPlane(options) => Some(options),
            _ => None,
        }
    }

    /// Renders `view` of a two-plane `field` (the asset the plan was made for): one draw of
    /// the aperture, or the average of `refine` draws.
    ///
    /// # Errors
    /// [`QualityError::Kind`] for a plan made for a spherical asset; a bad view or a failed
    /// render.
    pub fn render_two_plane(
        &self,
        renderer: &TwoPlaneRenderer,
        field: &GpuTwoPlane,
        view: &View,
    ) -> Result<Rendered, QualityError> {
        let (options, draws) = self.two_plane_job()?;
        let frame = renderer.render_accumulated(field, view, options, draws)?;
        Ok(Rendered {
            frame,
            decision: Self::two_plane_decision(field.planes.camera_count(), options, draws),
        })
    }

    /// [`Self::render_two_plane`] through a paged cache: the frame and its paging stats (the
    /// draws' merged). `wait`: the frame waits for the pages it plans to load (a still);
    /// otherwise it renders at once and they arrive for later frames (an interactive view,
    /// [`crate::page_cache::PagedTwoPlane::render_nowait`]).
    ///
    /// # Errors
    /// As [`Self::render_two_plane`].
    pub fn render_two_plane_paged(
        &self,
        renderer: &TwoPlaneRenderer,
        field: &mut crate::page_cache::PagedTwoPlane,
        view: &View,
        wait: bool,
    ) -> Result<(Rendered, crate::page_cache::PageFrameStats), QualityError> {
        let (options, draws) = self.two_plane_job()?;
        let (frame, stats) = field.render_accumulated(renderer, view, options, draws, wait)?;
        let rendered = Rendered {
            frame,
            decision: Self::two_plane_decision(field.planes.camera_count(), options, draws),
        };
        Ok((rendered, stats))
    }

    /// A two-plane plan's options and aperture draws.
    fn two_plane_job(&self) -> Result<(&TwoPlaneOptions, u32), QualityError> {
        let options = self.two_plane().ok_or_else(|| {
            QualityError::Kind(
                "this plan is for a spherical light field, not a two-plane one".to_owned(),
            )
        })?;
        Ok((options, self.quality.refine.unwrap_or(1)))
    }

    /// What a two-plane render of `cameras` cameras decided.
    fn two_plane_decision(cameras: u32, options: &TwoPlaneOptions, draws: u32) -> Decision {
        Decision {
            settings: ResolvedOptions {
                level: 0,
                cameras,
                step: 0.0,
                tolerance: 0.0,
                method: Method::Default,
                guide: 0,
            },
            choice: None,
            lod: None,
            two_plane: Some(TwoPlaneDecision {
                uv_filter: options.uv_filter,
                focus: options.focus,
                aperture: options.aperture,
                draws,
            }),
        }
    }

    /// The opacity of every layer of the asset the plan was made for, in its order.
    pub fn opacities(&self) -> &[f32] {
        &self.opacities
    }

    /// Renders every layer of `field` for `view` as the plan decides, uncomposited: each
    /// layer's premultiplied colour and sort depth (a scene composites them with its other
    /// objects, [`crate::layers::composite`]). Single-sample (a scene's objects do not refine).
    ///
    /// # Errors
    /// As [`Plan::render`].
    pub fn render_layers(
        &self,
        renderer: &Renderer,
        field: &GpuLightField,
        view: &View,
    ) -> Result<(Vec<LayerImage>, Decision), QualityError> {
        let (decision, job) = self.job(view)?;
        let (a, b, weight) = match job {
            Job::Single(options) => (options, options, 0.0),
            Job::Blend(a, b, weight) => (a, b, weight),
        };
        let images = renderer.render_layer_images(
            field,
            view,
            (&a, &b, weight),
            [0.0; 2],
            &self.opacities,
        )?;
        Ok((images, decision))
    }
}

/// One render a decision asks for.
#[derive(Clone, Copy, Debug)]
enum Job {
    /// One setting for every pixel.
    Single(RenderOptions),
    /// A blend band: the fraction `weight` of pixels (an ordered dither) with the second.
    Blend(RenderOptions, RenderOptions, f32),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::test_point as point;

    fn full() -> Quality {
        Quality {
            lod: Some(42),
            step: Some(0.25),
            tolerance: Some(0.125),
            method: Some(Method::Fixed),
            guide: Some(0),
            target_psnr: Some(20.0),
            budget_ms: Some(5.0),
            auto_lod: Some(1.0),
            lod_min_psnr: Some(20.0),
            lod_max_psnr_drop: Some(2.0),
            lod_blend: Some(0.1),
            refine: Some(4),
            layers: Some("skin=0.5".parse().expect("opacities")),
            light: Some(crate::light::LightDirection([0.0, 1.0, 0.0])),
            state: Some("dent".to_owned()),
            time: Some(0.5),
            frame: Some(3),
            uv_filter: Some(UvFilter::Depth),
            focus: Some(0.25),
            aperture: Some(1.5),
        }
    }

    #[test]
    fn refine_is_checked_and_left_out_of_moving_frames() {
        for bad in [0, refine::MAX_SAMPLES + 1] {
            let q = Quality {
                refine: Some(bad),
                ..Quality::default()
            };
            assert!(
                matches!(q.validate(), Err(QualityError::Refine(_))),
                "{bad}"
            );
        }
        let q = Quality {
            lod: Some(42),
            refine: Some(8),
            ..Quality::default()
        };
        assert!(q.validate().is_ok());
        let moving = q.for_motion();
        assert_eq!(moving.refine, None);
        assert_eq!(moving.lod, Some(42));
    }

    fn parse(json: serde_json::Value) -> Result<Quality, QualityError> {
        match json {
            serde_json::Value::Object(map) => Quality::from_json_map(map),
            other => panic!("not an object: {other}"),
        }
    }

    fn error(json: &serde_json::Value) -> String {
        match parse(json.clone()).and_then(|q| q.validate()) {
            Ok(()) => panic!("{json} was accepted"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn fields_are_the_serialized_keys() {
        let value = serde_json::to_value(full()).expect("json");
        let keys: Vec<&str> = value
            .as_object()
            .expect("object")
            .keys()
            .map(String::as_str)
            .collect();
        let mut fields = Quality::FIELDS.to_vec();
        fields.sort_unstable();
        let mut keys = keys;
        keys.sort_unstable();
        assert_eq!(keys, fields);
        // Round trip, and the default serializes to an empty object.
        assert_eq!(parse(value).expect("parses"), full());
        assert_eq!(
            serde_json::to_value(Quality::default()).expect("json"),
            serde_json::json!({})
        );
    }

    #[test]
    fn json_maps_split_and_refuse_unknown_keys() {
        let mut body = serde_json::json!({"view": 1, "lod": 12, "method": "fixed", "guide": null,
                                          "format": "png"})
        .as_object()
        .cloned()
        .expect("object");
        let q = Quality::take_from(&mut body).expect("quality");
        assert_eq!(
            q,
            Quality {
                lod: Some(12),
                method: Some(Method::Fixed),
                ..Quality::default()
            }
        );
        let rest: Vec<&str> = body.keys().map(String::as_str).collect();
        assert_eq!(rest, ["format", "view"]);
        for bad in [
            serde_json::json!({"zoom": 1}),
            serde_json::json!({"lod": "many"}),
            serde_json::json!({"method": "fast"}),
        ] {
            assert!(
                matches!(parse(bad.clone()), Err(QualityError::Json(_))),
                "{bad}"
            );
        }
        // The bad key is named, and a method gets the text its flag gets.
        let text = |v: serde_json::Value| parse(v).map(|_| ()).unwrap_err().to_string();
        assert!(text(serde_json::json!({"lod": 42, "step": "fine"})).contains("`step`"));
        assert!(
            text(serde_json::json!({"method": "fast"}))
                .contains("unknown method `fast`: use fixed or default")
        );
    }

    #[test]
    fn every_conflict_has_one_error() {
        use serde_json::json;
        let cases = [
            (json!({"target_psnr": 20, "budget_ms": 5}), "not both"),
            (
                json!({"target_psnr": 20, "budget_ms": 5, "auto_lod": 1}),
                "give target_psnr or budget_ms, not both",
            ),
            (
                json!({"auto_lod": 1, "budget_ms": 5}),
                "give auto_lod or target_psnr / budget_ms, not both",
            ),
            (json!({"lod_blend": 0.1}), "need auto_lod"),
            (json!({"lod_min_psnr": 20}), "need auto_lod"),
            (json!({"lod_max_psnr_drop": 1, "lod": 12}), "need auto_lod"),
            (json!({"target_psnr": 27, "guide": 8}), "do not send them"),
            (json!({"budget_ms": 5, "lod": 12}), "do not send them"),
            (
                json!({"budget_ms": 5, "method": "default"}),
                "do not send them",
            ),
            (json!({"target_psnr": -1}), "target PSNR -1 dB"),
            (json!({"budget_ms": 0}), "budget 0 ms"),
            (json!({"auto_lod": 0}), "max_error_px"),
            (json!({"auto_lod": 1, "lod_blend": 2}), "blend_band"),
            (json!({"auto_lod": 1, "lod_min_psnr": -3}), "min_psnr"),
            (json!({"auto_lod": 1, "method": "fixed"}), "default-method"),
            (json!({"guide": 1}), "guide 1"),
            (json!({"guide": 4, "method": "fixed"}), "default method"),
            (json!({"step": 0}), "step 0"),
            (json!({"tolerance": 2}), "tolerance 2"),
            (json!({"lod": 7}), "lod 7"),
        ];
        for (json, needle) in cases {
            let text = error(&json);
            assert!(text.contains(needle), "{json}: {text}");
        }
        for ok in [
            json!({}),
            json!({"lod": 42, "step": 0.0625, "tolerance": 0.03, "method": "fixed", "guide": 0}),
            json!({"target_psnr": 25}),
            json!({"budget_ms": 10}),
            json!({"auto_lod": 1, "lod": 42, "guide": 8, "lod_blend": 0}),
            json!({"auto_lod": 2, "lod_min_psnr": 20, "lod_max_psnr_drop": 1e300}),
        ] {
            parse(ok.clone())
                .and_then(|q| q.validate())
                .unwrap_or_else(|e| panic!("{ok}: {e}"));
        }
    }

    #[test]
    fn motion_drops_the_goal_and_scenes_take_no_options() {
        let goal = Quality {
            target_psnr: Some(25.0),
            ..Quality::default()
        };
        assert_eq!(goal.for_motion(), Quality::default());
        let lod = Quality {
            auto_lod: Some(1.0),
            lod: Some(42),
            ..Quality::default()
        };
        assert_eq!(lod.for_motion(), lod);
        assert!(Quality::default().check_scene().is_ok());
        assert!(matches!(goal.check_scene(), Err(QualityError::Scene)));
    }

    /// A header of a 162-camera asset (unit sphere at the origin), with a calibration or not.
    fn header(calibrated: bool) -> AssetHeader {
        let mut header = AssetHeader::new_spherical(
            2,
            32,
            crate::asset::LfFrame {
                center: [0.0; 3],
                radius: 1.0,
            },
            crate::asset::Encoding::R16,
            crate::asset::Provenance::default(),
        )
        .expect("header");
        if calibrated {
            let calibration = Calibration {
                size: 256,
                views: 4,
                adapter: "test".to_owned(),
                points: vec![
                    point(12, 1.0 / 16.0, 0.02, 500.0, 23.0),
                    point(42, 1.0 / 16.0, 0.01, 600.0, 25.5),
                    point(162, 1.0 / 32.0, 0.004, 900.0, 27.0),
                ],
            };
            header.quality = Some(serde_json::json!({
                "calibration": serde_json::to_value(&calibration).expect("json")
            }));
        }
        header
    }

    #[test]
    fn plans_decide_as_the_request_says() {
        let view = View::look_at([0.0, 0.0, 5.0], [0.0; 3], 40.0, 512, 512);
        // Knobs: resolved against the asset, no predictions.
        let plan = Quality {
            lod: Some(42),
            ..Quality::default()
        }
        .plan(&header(false))
        .expect("plan");
        let d = plan.decide(&view).expect("decision");
        assert_eq!((d.cameras(), d.settings.guide), (42, 4));
        assert!(d.report().is_empty());
        // Too many cameras for the asset.
        let too_many = Quality {
            lod: Some(642),
            ..Quality::default()
        };
        assert!(matches!(
            too_many.plan(&header(true)),
            Err(QualityError::Render(_))
        ));
        // A goal: the cheapest setting reaching 25 dB, rendered as calibrated (guide 4).
        let plan = Quality {
            target_psnr: Some(25.0),
            ..Quality::default()
        }
        .plan(&header(true))
        .expect("plan");
        let d = plan.decide(&view).expect("decision");
        let choice = d.choice.expect("choice");
        assert_eq!((choice.cameras, choice.met), (42, true));
        assert_eq!(
            (d.settings.cameras, d.settings.step, d.settings.guide),
            (42, 1.0 / 16.0, 4)
        );
        assert!((choice.predicted_ms - 600.0 * 0.262_144).abs() < 1e-9);
        let report = d.report();
        assert_eq!(report[0], ("chosen-cameras", "42".to_owned()));
        assert_eq!(report[4], ("goal-met", "true".to_owned()));
        // Automatic LOD: the object is 2·f·r/√(d²−r²) px across; the cheapest level whose
        // error stays under 5 px there.
        let plan = Quality {
            auto_lod: Some(5.0),
            lod_blend: Some(0.0),
            lod_max_psnr_drop: Some(f64::INFINITY),
            ..Quality::default()
        }
        .plan(&header(true))
        .expect("plan");
        let d = plan.decide(&view).expect("decision");
        let lod = d.lod.expect("lod decision");
        let px = view
            .basis(u32::MAX)
            .expect("view")
            .projected_diameter_px(DVec3::ZERO, 1.0);
        assert!((lod.projected_px - px).abs() < 1e-9);
        let want = if 0.02 * px <= 5.0 {
            12
        } else if 0.01 * px <= 5.0 {
            42
        } else {
            162
        };
        assert_eq!((d.cameras(), lod.level.cameras), (want, want));
        assert!(d.report().iter().any(|(k, _)| *k == "projected-px"));
        // No calibration: one error naming how to get one.
        for q in [
            Quality {
                budget_ms: Some(10.0),
                ..Quality::default()
            },
            Quality {
                auto_lod: Some(1.0),
                ..Quality::default()
            },
        ] {
            let e = q.plan(&header(false)).expect_err("no calibration");
            assert!(matches!(e, QualityError::NoCalibration(_)), "{e}");
            assert!(e.to_string().contains("calibrate=true"), "{e}");
        }
    }

    /// A two-plane header: 4×3 cameras of 16×8 px.
    fn two_plane_header() -> AssetHeader {
        let planes = crate::two_plane_io::default_planes([4, 3], [16, 8]);
        AssetHeader::new_two_plane(planes, 16, crate::asset::Provenance::default()).expect("header")
    }

    #[test]
    fn two_plane_plans_take_their_keys_and_refuse_the_marchers() {
        let tp = two_plane_header();
        let plan = Quality {
            uv_filter: Some(UvFilter::Dither),
            focus: Some(-0.25),
            aperture: Some(1.5),
            refine: Some(4),
            ..Quality::default()
        }
        .plan(&tp)
        .expect("two-plane plan");
        let options = plan.two_plane().expect("two-plane options");
        assert_eq!(options.uv_filter, UvFilter::Dither);
        assert_eq!((options.focus, options.aperture), (-0.25, 1.5));
        // The spherical renderer refuses a two-plane plan, by kind.
        let view = View::look_at([0.0, 0.0, 5.0], [0.0; 3], 40.0, 64, 64);
        assert!(matches!(plan.decide(&view), Err(QualityError::Kind(_))));
        // Defaults: bilinear, focus 0, pinhole.
        let plain = Quality::default().plan(&tp).expect("plan");
        assert_eq!(plain.two_plane(), Some(&TwoPlaneOptions::default()));
        // Every spherical key is named in the refusal.
        let err = Quality {
            lod: Some(12),
            light: Some(crate::light::LightDirection([0.0, 1.0, 0.0])),
            ..Quality::default()
        }
        .plan(&tp)
        .expect_err("spherical keys");
        let text = err.to_string();
        assert!(matches!(err, QualityError::Kind(_)), "{text}");
        assert!(text.contains("lod, light apply to spherical"), "{text}");
        // And the reverse: two-plane keys on a spherical asset.
        let err = Quality {
            focus: Some(1.0),
            aperture: Some(2.0),
            ..Quality::default()
        }
        .plan(&header(false))
        .expect_err("two-plane keys");
        assert!(
            err.to_string().contains(
                "focus, aperture apply to two-plane light fields; this asset is spherical"
            ),
            "{err}"
        );
        // Values are checked before any asset: NaN focus, an aperture out of range.
        for bad in [
            Quality {
                focus: Some(f64::NAN),
                ..Quality::default()
            },
            Quality {
                aperture: Some(-1.0),
                ..Quality::default()
            },
            Quality {
                aperture: Some(crate::two_plane_render::MAX_APERTURE + 1.0),
                ..Quality::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        // A moving stream frame drops the accumulated draws, nothing else.
        let moving = Quality {
            aperture: Some(3.0),
            refine: Some(16),
            ..Quality::default()
        }
        .for_motion();
        assert_eq!((moving.aperture, moving.refine), (Some(3.0), None));
    }
}

#[cfg(all(test, feature = "clap"))]
mod clap_tests {
    use clap::Parser;

    use super::*;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        quality: Quality,
    }

    fn parse(args: &[&str]) -> Quality {
        Cli::try_parse_from(std::iter::once("lumigraph").chain(args.iter().copied()))
            .unwrap_or_else(|e| panic!("{args:?}: {e}"))
            .quality
    }

    #[test]
    fn flags_keep_their_names_and_syntax() {
        assert_eq!(parse(&[]), Quality::default());
        assert_eq!(parse(&["--auto-lod"]).auto_lod, Some(1.0));
        assert_eq!(parse(&["--auto-lod=2.5"]).auto_lod, Some(2.5));
        let q = parse(&[
            "--lod",
            "42",
            "--step",
            "0.0625",
            "--tolerance",
            "0.03",
            "--method",
            "fixed",
            "--guide",
            "0",
            "--target-psnr",
            "27",
            "--budget-ms",
            "9",
            "--lod-min-psnr",
            "20",
            "--lod-max-psnr-drop",
            "inf",
            "--lod-blend",
            "0",
        ]);
        assert_eq!(q.method, Some(Method::Fixed));
        assert_eq!(q.lod_max_psnr_drop, Some(f64::INFINITY));
        // Conflicts are not clap's: the core decides them, with the same text everywhere.
        assert!(matches!(q.validate(), Err(QualityError::BothGoals)));
        assert!(
            Cli::try_parse_from(["lumigraph", "--method", "fast"]).is_err(),
            "unknown method"
        );
    }
}
