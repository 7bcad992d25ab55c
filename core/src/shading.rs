//! The DESIGN §3 shading options shared by baking and the reference renderer.

use serde::{Deserialize, Serialize};

/// Default light direction before normalization (DESIGN §3).
pub const DEFAULT_LIGHT: [f32; 3] = [0.3, 1.0, 0.5];
/// Default ambient term.
pub const DEFAULT_AMBIENT: f32 = 0.25;

/// Invalid shading options.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ShadingError {
    /// The light direction is zero or not finite.
    #[error("light direction {0:?} must be finite and non-zero")]
    BadLight([f32; 3]),
    /// Ambient outside [0, 1].
    #[error("ambient {0} must be in [0, 1]")]
    BadAmbient(f32),
    /// Specular coefficient or exponent out of range.
    #[error("specular ks={ks} shininess={shininess}: need 0 ≤ ks ≤ 1 and 0 < shininess ≤ 10000")]
    BadSpecular {
        /// Coefficient.
        ks: f32,
        /// Exponent.
        shininess: f32,
    },
}

/// `color = albedo·(ambient + (1-ambient)·V·max(0, n·light)) + ks·V·max(0, n·h)^shininess`, V = 1
/// without shadows (DESIGN §3, §9).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Shading {
    /// World-space light direction (normalized when used).
    pub light: [f32; 3],
    /// Ambient term in [0, 1].
    pub ambient: f32,
    /// Optional specular `(ks, shininess)`.
    pub specular: Option<(f32, f32)>,
    /// `color = albedo`.
    pub unlit: bool,
    /// DESIGN §9's shadow term: the light is tested for occlusion from every shaded point
    /// (baked texel and reference pixel alike); off by default, and then left out of the JSON
    /// (assets baked without it record what they did before).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub shadows: bool,
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            light: DEFAULT_LIGHT,
            ambient: DEFAULT_AMBIENT,
            specular: None,
            unlit: false,
            shadows: false,
        }
    }
}

/// The WGSL `Shading` struct (`shaders/shared/mesh.wgsl`): 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct GpuShading {
    pub light: [f32; 3],
    pub ambient: f32,
    pub ks: f32,
    pub shininess: f32,
    /// `SHADE_*` in mesh.wgsl: 0 the whole colour, 1 unlit, 2 the ambient part, 3 the rest, 4
    /// the shading normal (encoded).
    pub mode: u32,
    pub shadows: u32,
}

/// Which part of the colour a shading pass produces (`Shading.mode` in mesh.wgsl).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ShadePart {
    /// The whole DESIGN §3 colour (or the albedo when unlit).
    Whole,
    /// `albedo · ambient` alone.
    Ambient,
    /// The light's terms alone: `albedo·(1−ambient)·V·max(0, n·ℓ) + ks·V·max(0, n·h)^s`.
    Direct,
    /// Not a colour: the shading normal, octahedral with 16 bits per coordinate in the RGBA8
    /// texel (docs/format.md §8.6).
    Normal,
}
const _: () = assert!(std::mem::size_of::<GpuShading>() == 32);

impl Shading {
    /// Checks every field.
    ///
    /// # Errors
    /// [`ShadingError`] naming the bad field.
    pub fn validate(&self) -> Result<(), ShadingError> {
        let l = self.light;
        let len2 = l[0] * l[0] + l[1] * l[1] + l[2] * l[2];
        if !l.iter().all(|x| x.is_finite()) || !(len2 > 1e-20) || !len2.is_finite() {
            return Err(ShadingError::BadLight(l));
        }
        if !(0.0..=1.0).contains(&self.ambient) {
            return Err(ShadingError::BadAmbient(self.ambient));
        }
        if let Some((ks, shininess)) = self.specular
            && !((0.0..=1.0).contains(&ks) && shininess > 0.0 && shininess <= 10_000.0)
        {
            return Err(ShadingError::BadSpecular { ks, shininess });
        }
        Ok(())
    }

    /// The unit light direction.
    pub fn light_dir(&self) -> [f32; 3] {
        let l = glam::DVec3::from(self.light.map(f64::from)).normalize_or(glam::DVec3::Y);
        l.as_vec3().to_array()
    }

    pub(crate) fn to_gpu(self) -> GpuShading {
        self.part_to_gpu(ShadePart::Whole)
    }

    /// [`Shading::to_gpu`] producing only `part` of the colour (an unlit shading stays unlit).
    pub(crate) fn part_to_gpu(self, part: ShadePart) -> GpuShading {
        let (ks, shininess) = self.specular.unwrap_or((0.0, 1.0));
        let mode = match (self.unlit, part) {
            (true, _) => 1,
            (false, ShadePart::Whole) => 0,
            (false, ShadePart::Ambient) => 2,
            (false, ShadePart::Direct) => 3,
            (false, ShadePart::Normal) => 4,
        };
        GpuShading {
            light: self.light_dir(),
            ambient: self.ambient,
            ks,
            shininess,
            mode,
            shadows: u32::from(self.shadows && !self.unlit),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shadows_are_off_by_default_and_only_written_when_on() {
        // Assets baked without shadows record the shading JSON they always did.
        let plain = serde_json::to_value(Shading::default()).expect("serializes");
        assert!(plain.get("shadows").is_none(), "{plain}");
        let on = Shading {
            shadows: true,
            ..Shading::default()
        };
        let json = serde_json::to_value(on).expect("serializes");
        assert_eq!(json["shadows"], serde_json::Value::Bool(true));
        assert_eq!(serde_json::from_value::<Shading>(json).expect("parses"), on);
        let old: Shading = serde_json::from_str(r#"{"light": [0, 1, 0], "ambient": 0.3}"#)
            .expect("shading without the field");
        assert!(!old.shadows);
        // On the GPU: unlit shading has no light to shadow.
        assert_eq!(on.to_gpu().shadows, 1);
        let unlit = Shading { unlit: true, ..on };
        assert_eq!(unlit.to_gpu().shadows, 0);
        assert_eq!(Shading::default().to_gpu().shadows, 0);
    }
}
