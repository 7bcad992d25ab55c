//! The public options of a render: method, quality knobs and their resolution, errors.

use serde::{Deserialize, Serialize};

use crate::asset::AssetError;
use crate::geometry::{self, CAMERA_COUNTS};
use crate::gpu::GpuError;
use crate::view::ViewError;

/// Default step of the fixed method, in units of the bounding-sphere diameter (64 steps across).
pub const DEFAULT_FIXED_STEP: f32 = 1.0 / 64.0;
/// Default coarse step of the default method, in bounding-sphere diameters (32 steps across).
pub const DEFAULT_REFINED_STEP: f32 = 1.0 / 32.0;
/// Smallest step accepted (bounds the work per pixel: at most 1/step samples).
pub const MIN_STEP: f32 = 1.0 / 4096.0;

/// Errors while rendering.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The view is invalid.
    #[error(transparent)]
    View(#[from] ViewError),
    /// A quality option is out of range.
    #[error("{0}")]
    Option(String),
    /// The asset cannot be used.
    #[error(transparent)]
    Asset(#[from] AssetError),
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A bad light, or a light asked of an asset without light states.
    #[error(transparent)]
    Light(#[from] crate::light::LightError),
}

/// Marching method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", try_from = "String")]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub enum Method {
    /// Seed 000's fixed-step search with bilinear depth (baseline).
    Fixed,
    /// Edge-aware depth, coarse steps, bisection-refined crossings accepted where a camera agrees.
    #[default]
    Default,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fixed" => Ok(Method::Fixed),
            "default" => Ok(Method::Default),
            _ => Err(format!("unknown method `{s}`: use fixed or default")),
        }
    }
}

/// Parsed as [`std::str::FromStr`] does, so a bad name gets the same error text from JSON as
/// from a command-line flag.
impl TryFrom<String> for Method {
    type Error = String;
    fn try_from(name: String) -> Result<Self, String> {
        name.parse()
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Fixed => "fixed",
            Method::Default => "default",
        })
    }
}

/// Quality knobs of a render; `None` means the method's default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderOptions {
    /// Cameras to use: 12, 42, 162 or 642 (at most the asset's count), or a level 0–3.
    pub lod: Option<u32>,
    /// Step in bounding-sphere diameters.
    pub step: Option<f32>,
    /// Tolerance in bounding-sphere diameters (default: step / 2, seed 000 §3.1).
    pub tolerance: Option<f32>,
    /// Marching method.
    pub method: Method,
    /// Coarse-to-fine guidance, default method only: first render every `guide`-th pixel per
    /// axis (2–16), and let their hits bound each pixel's march. A pixel whose 3×3 coarse
    /// neighbours all missed far from any surface is skipped (and a 4×4 quad of such pixels
    /// is never dispatched); where one passed close to a surface (a thin feature between the
    /// samples), the pixel marches from a step before where that neighbour first came close.
    /// Flat 4×4 quads (every coarse neighbour hit, a smooth depth between them) are shaded at
    /// depths interpolated between the coarse hits, without marching, unless no camera agrees
    /// there. The coarse pass is guided the same way by one 4×
    /// coarser, when that has at least 4 pixels a side. 0: off; `None`: [`DEFAULT_GUIDE`] for
    /// the default method, off for the fixed baseline.
    pub guide: Option<u32>,
    /// Relight with this world-space light direction, blending the asset's light states
    /// ([`crate::light`]); `None`: the base colour (the bake's own light).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light: Option<crate::light::LightDirection>,
    /// Render this deformation state (an index into the asset's states, [`crate::deform`]);
    /// `None`: the base state. Set from a state name by [`crate::quality::Plan`]; not part of
    /// the JSON form.
    #[serde(skip)]
    pub state: Option<u16>,
}

/// Largest coarse-to-fine factor ([`RenderOptions::guide`]).
pub const MAX_GUIDE: u32 = 16;
/// Coarse-to-fine factor of the default method when none is given: a fraction of the unguided
/// time at equal masked PSNR (BENCHMARKS.md).
pub const DEFAULT_GUIDE: u32 = 4;

/// Options of [`super::Renderer::upload_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UploadOptions {
    /// Depth precision to render with: `None` = as stored, `Some(8)` requantizes 16-bit depth.
    pub depth_bits: Option<u8>,
    /// Upload the base state only, leaving light and deformation states on the host: for work
    /// that never relights or deforms (the trade-off sweep, the bake-time calibration), which
    /// then costs the base state's memory.
    pub base_state_only: bool,
}

/// The resolved settings a render used.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ResolvedOptions {
    /// Icosphere level.
    pub level: u32,
    /// Cameras.
    pub cameras: u32,
    /// Step in bounding-sphere diameters.
    pub step: f32,
    /// Tolerance in bounding-sphere diameters.
    pub tolerance: f32,
    /// Method.
    pub method: Method,
    /// Coarse-to-fine factor (0 = off).
    pub guide: u32,
}

impl RenderOptions {
    /// Resolves defaults and checks ranges against an asset with `max_level`.
    ///
    /// # Errors
    /// [`RenderError::Option`] naming the bad knob.
    pub fn resolve(&self, max_level: u32) -> Result<ResolvedOptions, RenderError> {
        let level = match self.lod {
            None => max_level,
            Some(l) if l <= 3 => l,
            Some(n) => geometry::level_for_camera_count(n).ok_or_else(|| {
                RenderError::Option(format!(
                    "lod {n} is not a camera count (12, 42, 162, 642) or a level 0-3"
                ))
            })?,
        };
        if level > max_level {
            return Err(RenderError::Option(format!(
                "lod {} cameras exceeds the asset's {} cameras",
                CAMERA_COUNTS[level as usize], CAMERA_COUNTS[max_level as usize]
            )));
        }
        let default_step = if self.method == Method::Fixed {
            DEFAULT_FIXED_STEP
        } else {
            DEFAULT_REFINED_STEP
        };
        let step = self.step.unwrap_or(default_step);
        if !step.is_finite() || !(MIN_STEP..=1.0).contains(&step) {
            return Err(RenderError::Option(format!(
                "step {step} must be finite and in [{MIN_STEP}, 1] bounding diameters"
            )));
        }
        if let Some(light) = self.light {
            light.unit()?;
        }
        let tolerance = self.tolerance.unwrap_or(step / 2.0);
        if !(tolerance.is_finite() && tolerance > 0.0 && tolerance <= 1.0) {
            return Err(RenderError::Option(format!(
                "tolerance {tolerance} must be finite and in (0, 1] bounding diameters"
            )));
        }
        let guide = self.guide.unwrap_or(match self.method {
            Method::Fixed => 0,
            Method::Default => DEFAULT_GUIDE,
        });
        if guide != 0 && !(2..=MAX_GUIDE).contains(&guide) {
            return Err(RenderError::Option(format!(
                "guide {guide}: use 0 (off) or a coarse factor 2 to {MAX_GUIDE}"
            )));
        }
        if guide != 0 && self.method == Method::Fixed {
            return Err(RenderError::Option(
                "guide applies to the default method, not the fixed baseline".to_owned(),
            ));
        }
        Ok(ResolvedOptions {
            level,
            cameras: CAMERA_COUNTS[level as usize],
            step,
            tolerance,
            method: self.method,
            guide,
        })
    }
}

/// Modes of a [`super::Renderer`], fixed at construction ([`super::Renderer::with_switches`]).
/// The defaults serve every product path; tests switch parts of the marcher off to check that
/// they change no pixel, or what they change (docs/marcher.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Switches {
    /// Guided passes march only the 4×4 quads the tile pass lists (on by default).
    pub tile_compaction: bool,
    /// Compacted guided frames send flat quads to the interior pass instead of marching them
    /// (on by default).
    pub interior: bool,
    /// Whether the interior pass shades 2×2 blocks of pixels per invocation.
    pub interior_blocks: InteriorBlocks,
    /// The tile pass reads 4×4 coarse pixels per quad even where 3×3 would do (off by default).
    pub wide_tile_reads: bool,
    /// Times every frame's passes and logs them (default: whether
    /// [`super::PASS_TIMING_VARIABLE`] is set when the switches are made).
    pub pass_timing: bool,
    /// Where a multi light field's visible layers composite.
    pub compositing: Compositing,
    /// How a relit frame blends the light states around its light (env
    /// [`LIGHT_BLEND_VARIABLE`] = `normal` | `spherical` | `planar` when the switches are made;
    /// the last two are for measuring).
    pub light_blend: crate::light::Blend,
    /// In a relit frame of an asset baked with shadows, a shadow ray through the light field
    /// decides the texels where the proxy lights disagree on the shadow (on by default; env
    /// [`SHADOW_RAYS_VARIABLE`] = `0` turns it off when the switches are made, for measuring).
    pub shadow_rays: bool,
}

/// Environment variable that turns [`Switches::shadow_rays`] off (`0`).
pub const SHADOW_RAYS_VARIABLE: &str = "LUMIGRAPH_SHADOW_RAYS";

/// Environment variable choosing [`Switches::light_blend`].
pub const LIGHT_BLEND_VARIABLE: &str = "LUMIGRAPH_LIGHT_BLEND";

impl Default for Switches {
    fn default() -> Self {
        Switches {
            tile_compaction: true,
            interior: true,
            interior_blocks: InteriorBlocks::Automatic,
            wide_tile_reads: false,
            pass_timing: std::env::var_os(super::PASS_TIMING_VARIABLE).is_some(),
            compositing: Compositing::from_env(),
            light_blend: match std::env::var(LIGHT_BLEND_VARIABLE).as_deref() {
                Ok("planar") => crate::light::Blend::Planar,
                Ok("spherical") => crate::light::Blend::Spherical,
                _ => crate::light::Blend::Normal,
            },
            shadow_rays: std::env::var(SHADOW_RAYS_VARIABLE).as_deref() != Ok("0"),
        }
    }
}

/// [`Switches::compositing`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compositing {
    /// On the GPU where the adapter is hardware; on the CPU where it is a software rasterizer,
    /// whose compute passes run on the same cores as the CPU composite and cost more there
    /// (BENCHMARKS.md, "Three layers").
    #[default]
    Automatic,
    /// On the GPU: the layers go to a stack on the device and one pass composites them; one
    /// readback (shaders/composite.wgsl).
    Gpu,
    /// On the CPU: every layer is read back and [`crate::layers::composite`] blends them, as
    /// scenes do.
    Cpu,
}

/// Environment variable that picks [`Compositing`] for renderers made while it is set:
/// `auto`, `gpu` or `cpu` (for measuring one against the other on the same adapter).
pub const COMPOSITING_VARIABLE: &str = "LUMIGRAPH_COMPOSITE";

impl Compositing {
    /// [`COMPOSITING_VARIABLE`]'s choice; [`Compositing::Automatic`] where it is unset, or
    /// not one of the three (with a warning).
    pub fn from_env() -> Compositing {
        let Some(value) = std::env::var_os(COMPOSITING_VARIABLE) else {
            return Compositing::Automatic;
        };
        match value.to_str().map(str::trim) {
            Some("gpu") => Compositing::Gpu,
            Some("cpu") => Compositing::Cpu,
            Some("auto") => Compositing::Automatic,
            _ => {
                tracing::warn!(
                    "{COMPOSITING_VARIABLE}={value:?} is not auto, gpu or cpu: compositing where \
                     the adapter suits"
                );
                Compositing::Automatic
            }
        }
    }
}

/// [`Switches::interior_blocks`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum InteriorBlocks {
    /// Where a block's pixels cannot lie further from its centre ray's triangle than the
    /// direction lookup's reach, and the frame's coarse grid keeps every block in one cell.
    #[default]
    Automatic,
    /// Never.
    Off,
    /// Wherever the frame's coarse grid keeps every block in one cell.
    On,
}
