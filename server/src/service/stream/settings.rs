//! Sticky per-session settings and their validation against the asset.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use lumigraph_core::lod::Ladder;
use lumigraph_core::render::RenderOptions;
use lumigraph_core::tradeoff::{Calibration, Goal};
use serde::{Deserialize, Serialize};

use crate::service::assets::LoadedAsset;
use crate::service::codecs::ColorFormat;
use crate::service::render_pool::{Knobs, goal_calibration, lod_ladder};

/// Sticky per-session settings; each `settings` message overrides the fields it names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// Cameras of full-quality frames: 12, 42, 162 or 642 (absent: all of the asset's).
    pub lod: Option<u32>,
    /// March step in bounding-sphere diameters (absent: the method's default).
    pub step: Option<f32>,
    /// Depth tolerance in bounding-sphere diameters (absent: step / 2).
    pub tolerance: Option<f32>,
    /// `default` or `fixed`.
    pub method: Option<lumigraph_core::render::Method>,
    /// Coarse-to-fine factor of the default method (2–16, 0 = off; absent: 4).
    pub guide: Option<u32>,
    /// Codec of full-quality (resting) frames: `png`, `webp` (lossless) or `jpeg`.
    pub still_codec: ColorFormat,
    /// JPEG quality of full-quality frames.
    pub still_quality: u8,
    /// Send reduced frames while the view changes; `false` = every frame at full quality.
    pub interactive: bool,
    /// Codec of interactive frames.
    pub interactive_codec: ColorFormat,
    /// JPEG quality of interactive frames.
    pub interactive_quality: u8,
    /// Fixed resolution scale of interactive frames in [0.1, 1]; absent = chosen from the
    /// measured render speed to hold `target_fps`.
    pub interactive_scale: Option<f32>,
    /// Camera count of interactive frames (absent: the full-quality `lod`).
    pub interactive_lod: Option<u32>,
    /// Frame rate the adaptive interactive scale aims for, 1..=120.
    pub target_fps: f32,
    /// How long the view must rest before the full-quality frame, 0..=10000 ms.
    pub rest_ms: u32,
    /// Frames sent but not acknowledged before the server waits: 1 or 2.
    pub max_in_flight: u32,
    /// RGBA8 where nothing is hit (JPEG: the matte colour).
    pub background: [u8; 4],
    /// Opacity per layer name, in [0, 1].
    pub layers: BTreeMap<String, f32>,
    /// Named state of the asset (lighting, animation frame); absent = the base state.
    pub state: Option<String>,
    /// Full-quality frames use the cheapest setting the asset's calibration predicts to reach
    /// this masked PSNR (dB), chosen per frame size; excludes `lod`/`step`/`tolerance`/`method`.
    #[serde(default)]
    pub target_psnr: Option<f64>,
    /// Full-quality frames use the most accurate setting predicted to render within this many
    /// ms at the frame's size; excludes the knobs and `target_psnr`.
    #[serde(default)]
    pub budget_ms: Option<f64>,
    /// Automatic LOD for every frame (interactive frames, smaller, may take coarser levels):
    /// the bound on the predicted silhouette error in pixels; the knobs stay pinned; excludes
    /// `target_psnr` / `budget_ms`.
    #[serde(default)]
    pub auto_lod: Option<f64>,
    /// With `auto_lod`: only settings whose calibrated masked PSNR reaches this (dB).
    #[serde(default)]
    pub lod_min_psnr: Option<f64>,
    /// With `auto_lod`: only settings within this many dB of the most accurate level (default 2).
    #[serde(default)]
    pub lod_max_psnr_drop: Option<f64>,
    /// With `auto_lod`: cross-fade band below each switch (fraction of the projected size).
    #[serde(default)]
    pub lod_blend: Option<f64>,
}

impl Settings {
    pub(super) fn defaults(rest: Duration) -> Self {
        Self {
            lod: None,
            step: None,
            tolerance: None,
            method: None,
            guide: None,
            still_codec: ColorFormat::Jpeg,
            still_quality: 90,
            interactive: true,
            interactive_codec: ColorFormat::Jpeg,
            interactive_quality: 50,
            interactive_scale: None,
            interactive_lod: None,
            target_fps: 20.0,
            rest_ms: u32::try_from(rest.as_millis()).unwrap_or(u32::MAX),
            max_in_flight: 2,
            background: [0; 4],
            layers: BTreeMap::new(),
            state: None,
            target_psnr: None,
            budget_ms: None,
            auto_lod: None,
            lod_min_psnr: None,
            lod_max_psnr_drop: None,
            lod_blend: None,
        }
    }
}

/// Settings checked against the asset, with the core options precomputed.
#[derive(Clone, Debug)]
pub(super) struct Effective {
    pub(super) settings: Settings,
    pub(super) still_options: RenderOptions,
    pub(super) interactive_options: RenderOptions,
    /// Cameras of each kind of frame, for the header.
    pub(super) still_cameras: u32,
    pub(super) interactive_cameras: u32,
    /// Opacity of layer 0 (the one rendered), multiplied into alpha.
    pub(super) opacity: f32,
    /// A quality or time goal for full-quality frames, with the calibration that serves it.
    pub(super) goal: Option<(Goal, Arc<Calibration>)>,
    /// Automatic LOD for every frame.
    pub(super) ladder: Option<Arc<Ladder>>,
}

pub(super) fn validate_settings(
    settings: Settings,
    asset: &LoadedAsset,
) -> Result<Effective, String> {
    let s = &settings;
    for (name, codec) in [
        ("still_codec", s.still_codec),
        ("interactive_codec", s.interactive_codec),
    ] {
        if codec == ColorFormat::None {
            return Err(format!("{name} must be png, jpeg or webp"));
        }
    }
    for (name, q) in [
        ("still_quality", s.still_quality),
        ("interactive_quality", s.interactive_quality),
    ] {
        if !(1..=100).contains(&q) {
            return Err(format!("{name} must be in 1..=100, got {q}"));
        }
    }
    if let Some(scale) = s.interactive_scale
        && !(scale.is_finite() && (0.1..=1.0).contains(&scale))
    {
        return Err(format!(
            "interactive_scale must be in [0.1, 1], got {scale}"
        ));
    }
    if !(s.target_fps.is_finite() && (1.0..=120.0).contains(&s.target_fps)) {
        return Err(format!(
            "target_fps must be in [1, 120], got {}",
            s.target_fps
        ));
    }
    if s.rest_ms > 10_000 {
        return Err(format!("rest_ms must be in 0..=10000, got {}", s.rest_ms));
    }
    if !(1..=2).contains(&s.max_in_flight) {
        return Err(format!(
            "max_in_flight must be 1 or 2, got {}",
            s.max_in_flight
        ));
    }
    let header = &asset.header;
    let mut opacity = header.layers.first().map_or(1.0, |l| l.default_opacity);
    for (name, &value) in &s.layers {
        let Some(index) = header.layers.iter().position(|l| &l.name == name) else {
            let names: Vec<&str> = header.layers.iter().map(|l| l.name.as_str()).collect();
            return Err(format!(
                "the asset has no layer {name:?} (layers: {names:?})"
            ));
        };
        if !(value.is_finite() && (0.0..=1.0).contains(&value)) {
            return Err(format!(
                "opacity of layer {name:?} must be in [0, 1], got {value}"
            ));
        }
        if index == 0 {
            opacity = value;
        }
    }
    if let Some(state) = &s.state {
        match header.states.iter().position(|st| &st.name == state) {
            None => {
                let names: Vec<&str> = header.states.iter().map(|st| st.name.as_str()).collect();
                return Err(format!(
                    "the asset has no state {state:?} (states: {names:?})"
                ));
            }
            Some(0) => {}
            Some(_) => {
                return Err(format!(
                    "rendering state {state:?} is not supported yet: only the base state renders"
                ));
            }
        }
    }
    let knobs = Knobs {
        lod: s.lod,
        step: s.step,
        tolerance: s.tolerance,
        method: s.method,
        guide: s.guide,
    };
    let ladder = lod_ladder(
        s.auto_lod,
        s.lod_min_psnr,
        s.lod_max_psnr_drop,
        s.lod_blend,
        &knobs,
        s.target_psnr.is_some() || s.budget_ms.is_some(),
        asset,
    )
    .map_err(|e| e.to_string())?;
    let goal =
        goal_calibration(s.target_psnr, s.budget_ms, &knobs, asset).map_err(|e| e.to_string())?;
    if let Some((goal, calibration)) = &goal {
        // Checks the goal's value now rather than at the first frame.
        calibration
            .choose(*goal, 64, 64, asset.header.geometry.camera_count)
            .map_err(|e| e.to_string())?;
    }
    let still_options = knobs.to_options(asset).map_err(|e| e.to_string())?;
    let interactive_options = Knobs {
        lod: s.interactive_lod.or(s.lod),
        ..knobs
    }
    .to_options(asset)
    .map_err(|e| e.to_string())?;
    let cameras = |o: &RenderOptions| o.resolve(asset.field.max_level).map_or(0, |r| r.cameras);
    Ok(Effective {
        still_cameras: cameras(&still_options),
        interactive_cameras: cameras(&interactive_options),
        still_options,
        interactive_options,
        opacity,
        settings,
        goal,
        ladder,
    })
}

/// Applies the fields of a `settings` message to `current`.
pub(super) fn merge_settings(
    current: &Settings,
    patch: serde_json::Value,
) -> Result<Settings, String> {
    let serde_json::Value::Object(patch) = patch else {
        return Err("a settings message must be a JSON object".to_owned());
    };
    let mut merged = serde_json::to_value(current).map_err(|e| e.to_string())?;
    if let serde_json::Value::Object(merged) = &mut merged {
        for (key, value) in patch {
            merged.insert(key, value);
        }
    }
    serde_json::from_value(merged).map_err(|e| format!("invalid settings: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_merge_keeps_unnamed_fields() {
        let current = Settings::defaults(Duration::from_millis(250));
        let merged = merge_settings(
            &current,
            serde_json::json!({"lod": 42, "still_codec": "png"}),
        )
        .unwrap();
        assert_eq!(merged.lod, Some(42));
        assert_eq!(merged.still_codec, ColorFormat::Png);
        assert_eq!(merged.interactive_quality, 50);
        assert!(merge_settings(&current, serde_json::json!({"bogus": 1})).is_err());
    }
}
