//! Sticky per-session settings and their validation against the asset.

use std::time::Duration;

use lumigraph_core::quality::{Plan, Quality};
use serde::{Deserialize, Serialize};

use crate::service::codecs::ColorFormat;
use lumigraph_core::asset::AssetHeader;

/// Sticky per-session settings; each `settings` message overrides the fields it names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
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
    /// Adapt to the measured link (acks with `received_ms`): `interactive_quality` and the
    /// interactive scale become ceilings lowered while the link cannot carry `target_fps`, and a
    /// lossless `still_codec` falls back to JPEG at `still_quality` when it would arrive late.
    /// `false`: the settings exactly.
    pub adaptive: bool,
    /// How long the view must rest before the full-quality frame, 0..=10000 ms.
    pub rest_ms: u32,
    /// Frames sent but not acknowledged before the server waits: 1 or 2.
    pub max_in_flight: u32,
    /// RGBA8 where nothing is hit (JPEG: the matte colour).
    pub background: [u8; 4],
    /// Append each frame's depth and view to its header (the depth extension), so the client
    /// can reproject the frame to a newer camera while the next one is on its way.
    pub depth: bool,
    /// Play the asset's animation (an asset baked with `--animation`): frames advance at its
    /// rate on the server's clock, looping, whether the view moves or rests (the quality keys
    /// `time`, `frame` and `state` are ignored meanwhile); every frame's header says which
    /// animation frame it shows (the animation extension).
    pub playing: bool,
    /// The quality request (core `Quality`) as its JSON keys, layer opacities (`layers`)
    /// included: a message's quality key sets it, `null` clears it. Resting frames render with it; moving frames with its motion
    /// quality (`Quality::for_motion`, `interactive_lod` replacing `lod` without `auto_lod`).
    #[serde(skip)]
    pub quality: serde_json::Map<String, serde_json::Value>,
}

impl Settings {
    pub(super) fn defaults(rest: Duration) -> Self {
        Self {
            still_codec: ColorFormat::Jpeg,
            still_quality: 90,
            interactive: true,
            interactive_codec: ColorFormat::Jpeg,
            interactive_quality: 50,
            interactive_scale: None,
            interactive_lod: None,
            target_fps: 20.0,
            adaptive: true,
            rest_ms: u32::try_from(rest.as_millis()).unwrap_or(u32::MAX),
            max_in_flight: 2,
            background: [0; 4],
            depth: false,
            playing: false,
            quality: serde_json::Map::new(),
        }
    }
}

/// Settings checked against the asset, with the core options precomputed.
#[derive(Clone, Debug)]
pub(super) struct Effective {
    pub(super) settings: Settings,
    /// The plan of resting (full-quality) frames.
    pub(super) still: Plan,
    /// The plan of interactive frames while the view moves.
    pub(super) motion: Plan,
    /// The asset's animation, if it has one.
    pub(super) animation: Option<lumigraph_core::deform::AnimationInfo>,
}

pub(super) fn validate_settings(
    settings: Settings,
    header: &AssetHeader,
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
    let animation = lumigraph_core::deform::AnimationInfo::of(header);
    if s.playing && animation.is_none() {
        return Err("playing: the asset has no animation (bake it with --animation)".to_owned());
    }
    let mut quality_keys = s.quality.clone();
    if s.playing {
        // The player picks the frame.
        for key in ["time", "frame", "state"] {
            quality_keys.remove(key);
        }
    }
    let quality = Quality::from_json_map(quality_keys).map_err(|e| e.to_string())?;
    let mut moving = quality.for_motion();
    let still = if header.two_plane().is_some() {
        if s.interactive_lod.is_some() {
            return Err(
                "interactive_lod applies to spherical light fields, not to this two-plane one"
                    .to_owned(),
            );
        }
        // Without a uv filter asked for, resting frames are depth-corrected where depth was
        // captured and moving ones bilinear: dither inflates every codec's frames, and the
        // depth-corrected filter costs 3× bilinear's time for the same bytes (BENCHMARKS.md,
        // "Two-plane light fields").
        let mut resting = quality.clone();
        if resting.uv_filter.is_none() && lumigraph_core::two_plane::has_captured_depth(header) {
            resting.uv_filter = Some(lumigraph_core::two_plane_render::UvFilter::Depth);
        }
        resting.plan(header).map_err(|e| e.to_string())?
    } else {
        if moving.auto_lod.is_none() {
            moving.lod = s.interactive_lod.or(moving.lod);
        }
        quality.plan(header).map_err(|e| e.to_string())?
    };
    let motion = moving.plan(header).map_err(|e| e.to_string())?;
    Ok(Effective {
        settings,
        still,
        motion,
        animation,
    })
}

impl Settings {
    /// The settings as the client sees them: every field, the quality keys at the top level.
    pub(super) fn to_json(&self) -> serde_json::Value {
        let mut value = serde_json::to_value(self).unwrap_or_default();
        if let serde_json::Value::Object(map) = &mut value {
            map.extend(self.quality.clone());
        }
        value
    }
}

/// Applies the fields of a `settings` message to `current`.
pub(super) fn merge_settings(
    current: &Settings,
    patch: serde_json::Value,
) -> Result<Settings, String> {
    let serde_json::Value::Object(patch) = patch else {
        return Err("a settings message must be a JSON object".to_owned());
    };
    let mut quality = current.quality.clone();
    let mut merged = serde_json::to_value(current).map_err(|e| e.to_string())?;
    if let serde_json::Value::Object(merged) = &mut merged {
        for (key, value) in patch {
            if Quality::FIELDS.contains(&key.as_str()) {
                if value.is_null() {
                    quality.remove(&key);
                } else {
                    quality.insert(key, value);
                }
            } else {
                merged.insert(key, value);
            }
        }
    }
    let mut settings: Settings =
        serde_json::from_value(merged).map_err(|e| format!("invalid settings: {e}"))?;
    settings.quality = quality;
    Ok(settings)
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
        assert_eq!(merged.quality.get("lod"), Some(&serde_json::json!(42)));
        let cleared = merge_settings(&merged, serde_json::json!({"lod": null})).unwrap();
        assert!(cleared.quality.is_empty());
        assert_eq!(merged.still_codec, ColorFormat::Png);
        assert_eq!(merged.interactive_quality, 50);
        assert!(merge_settings(&current, serde_json::json!({"bogus": 1})).is_err());
    }

    #[test]
    fn playing_needs_an_animation() {
        let header = lumigraph_core::asset::AssetHeader::new_spherical(
            0,
            16,
            lumigraph_core::asset::LfFrame {
                center: [0.0; 3],
                radius: 1.0,
            },
            lumigraph_core::asset::Encoding::R16,
            lumigraph_core::asset::Provenance::default(),
        )
        .expect("header");
        let current = Settings::defaults(Duration::from_millis(250));
        let playing = merge_settings(&current, serde_json::json!({"playing": true})).unwrap();
        let err = validate_settings(playing, &header).expect_err("no animation");
        assert!(
            err.contains("playing") && err.contains("no animation"),
            "{err}"
        );
        assert!(validate_settings(current, &header).is_ok());
    }
}
