//! Rendering new views from a spherical light field on the GPU (seed 000 §2, DESIGN §4).
//!
//! [`Renderer`] holds the compute pipeline (built once); [`GpuLightField`] holds one asset's
//! colour and depth maps as 2D texture arrays plus its cameras and triangle hierarchy; a render
//! fills a [`Frame`] with colour, z-depth in world units and stats.
//!
//! Two methods: [`Method::Fixed`] is the seed's fixed-step search with bilinear depth (the
//! baseline); [`Method::Default`] marches coarse steps with an edge-aware depth lookup and
//! accepts a bisection-refined crossing only where a camera's estimate is continuous across it.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::asset::{AssetError, AssetFile, Channel, Encoding, ImageKey};
use crate::frame::{Frame, FrameStats};
use crate::geometry::{self, CAMERA_COUNTS};
use crate::gpu::{Gpu, GpuError, array_view, texture_array};
use crate::view::{DEFAULT_MAX_VIEW_PX, View, ViewError};

/// Default step of the fixed method, in units of the bounding-sphere diameter (64 steps across).
pub const DEFAULT_FIXED_STEP: f32 = 1.0 / 64.0;
/// Default coarse step of the default method, in bounding-sphere diameters (32 steps across).
pub const DEFAULT_REFINED_STEP: f32 = 1.0 / 32.0;
/// Smallest step accepted (bounds the work per pixel: at most 1/step samples).
pub const MIN_STEP: f32 = 1.0 / 4096.0;
/// Bisection iterations of the default method (then a secant step in the last bracket). Three
/// beat five on every fixture (162 cameras, 6 views at 512², guide 4; masked PSNR bunny
/// 26.11 → 26.30 dB, cow 23.29 → 23.37, spot 26.41 → 26.60, demo 27.24 → 27.61; fewer
/// mismatched mask pixels; median depth error unchanged at 1.9e-4 r on bunny) in less time:
/// the continuity test then judges a wider final bracket, which rejects fewer true surfaces
/// beside a silhouette. One is too few (bunny: 19.9 dB, 5× the mismatched pixels).
const REFINE_ITERATIONS: u32 = 3;
/// Bisection iterations of the coarse passes (pre-coarse and coarse) of a guided frame, whose
/// depths only bound the finer pass's marches (with a quarter step of margin) and decide which
/// quads are flat. Two against three (eval, bunny / cow / spot / demo, masked PSNR): at 512², 6
/// views, 28.18 / 24.78 / 28.81 / 28.20 dB against 28.11 / 24.75 / 28.76 / 28.14, with 4–27
/// fewer mismatched mask pixels per view; at 256², 12 views, within ±0.015 dB; fetches per
/// pixel −0.4…−0.7 %; in-process the demo's frame −0.2 ms. One is too few (spot at 512²:
/// 26.75 dB).
const COARSE_REFINE_ITERATIONS: u32 = 2;
/// Step of the coarse passes (pre-coarse and coarse) of a guided frame, in steps of the frame's
/// setting. A pixel next to a coarse near miss marches from one coarse step before where the
/// miss first came near (render.wgsl `guide_step_ratio`), as the coarse ray sampled that far
/// apart. Measured (eval, two coarse bisection iterations; masked PSNR bunny / cow / spot /
/// demo), 1.5 against 1: at 512², 6 views, 28.21 / 24.90 / 28.91 / 28.18 dB against 28.18 /
/// 24.78 / 28.81 / 28.20, up to 34 fewer mismatched pixels per view (the demo: as many); at
/// 256², 12 views, −0.05…+0.11 dB; fetches per pixel −2…−4 %; in-process, the demo's coarse
/// passes −0.37 ms and its frame pass +0.1 ms. At 1024², 3 views, against three iterations at
/// 1: +0.10…+0.32 dB. 1.75 (with the frame's step as that margin) lost up to 0.14 dB at 512²
/// against 1.5, and 2 loses 2.5–3 dB on bunny, spot and demo at 512², with either margin:
/// the coarse rays then step over the band in which a ray counts as near a surface
/// (`GUIDE_REACH`).
const COARSE_STEP_SCALE: f32 = 1.5;
/// Depth gap (in normalized map depth) above which a 2×2 footprint is split into layers.
const EDGE_GAP: f32 = 0.05;
/// Bilinear weight the front layer of a split footprint needs to be chosen. Above 0.5 because a
/// pixel is covered when any of its three cameras finds a crossing: the union of three
/// half-texel-accurate silhouettes is biased outwards, and a front layer that must hold 60 % of
/// the weight cancels that bias. Measured (12 views, 256-px maps, masked PSNR, 0.5 → 0.6):
/// bunny 162 cams 25.45 → 26.23 dB, bunny 42 25.63 → 26.03, cow 162 22.64 → 23.16,
/// demo 162 26.85 → 27.46; 0.7 and 0.8 were worse again on the bunny (26.14, 25.24). With
/// sub-texel silhouettes ([`edge_codes`]) it matters less, as the edge texels place most
/// silhouettes (bunny: 28.48, 28.49, 28.32 dB at 0.5, 0.6, 0.7).
const FRONT_MASS: f32 = 0.6;

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
}

/// Marching method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
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
}

/// Largest coarse-to-fine factor ([`RenderOptions::guide`]).
pub const MAX_GUIDE: u32 = 16;
/// Coarse-to-fine factor of the default method when none is given: at 512² on the fixtures it
/// takes 0.36–0.48× of the unguided time at equal masked PSNR (BENCHMARKS.md).
pub const DEFAULT_GUIDE: u32 = 4;

/// Options of [`Renderer::upload_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UploadOptions {
    /// Depth precision to render with: `None` = as stored, `Some(8)` requantizes 16-bit depth.
    pub depth_bits: Option<u8>,
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

/// One asset on the GPU. Cheap to share (`Arc`) between threads.
pub struct GpuLightField {
    /// World units per light-field unit.
    pub scale: f64,
    /// Bounding-sphere centre, world units.
    pub center: DVec3,
    /// Bounding radius, world units.
    pub radius: f64,
    /// Icosphere level baked.
    pub max_level: u32,
    /// Map resolution.
    pub resolution: u32,
    /// Bytes of texture memory used.
    pub gpu_bytes: u64,
    /// Axis-aligned box (light-field units) holding every surface point any camera saw, grown
    /// by the maps' texel footprint: the default marcher clips rays to it (empty when nothing
    /// was seen).
    pub visible_box: [[f32; 3]; 2],
    group: wgpu::BindGroup,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RenderParams {
    eye: [f32; 3],
    width: u32,
    right: [f32; 3],
    height: u32,
    up: [f32; 3],
    focal_px: f32,
    forward: [f32; 3],
    level: u32,
    step: f32,
    tolerance: f32,
    max_steps: u32,
    method: u32,
    resolution: f32,
    depth_scale: f32,
    edge_gap: f32,
    refine_iterations: u32,
    front_mass: f32,
    blend: f32,
    coarse_factor: u32,
    near_scale: f32,
    box_min: [f32; 3],
    tiled: u32,
    box_max: [f32; 3],
    interior_curvature: f32,
    level_b: u32,
    step_b: f32,
    tolerance_b: f32,
    max_steps_b: u32,
    method_b: u32,
    coarse_width: u32,
    coarse_height: u32,
    row_stride: u32,
    interior_group_quads: u32,
    guide_step_ratio: f32,
    jitter: [f32; 2],
}
const _: () = assert!(std::mem::size_of::<RenderParams>() == 192);

/// One setting as the shader takes it: level, step and tolerance in light-field units,
/// step bound, method code.
struct ShaderSetting {
    level: u32,
    step: f32,
    tolerance: f32,
    max_steps: u32,
    method: u32,
}

/// The bounding sphere's diameter in light-field units (radius `1/√2`, the camera sphere's 1):
/// what steps and tolerances are fractions of.
const BOUNDING_DIAMETER: f32 = std::f32::consts::SQRT_2;

/// The march's step limit for `step` (light-field units): the bounding sphere's diameter in
/// steps, plus two.
fn max_steps_for(step: f32) -> u32 {
    (BOUNDING_DIAMETER / step).ceil() as u32 + 2
}

impl ShaderSetting {
    fn of(resolved: &ResolvedOptions) -> Self {
        let step = resolved.step * BOUNDING_DIAMETER;
        ShaderSetting {
            level: resolved.level,
            step,
            tolerance: resolved.tolerance * BOUNDING_DIAMETER,
            max_steps: max_steps_for(step),
            method: u32::from(resolved.method != Method::Fixed),
        }
    }
}

/// Per-size output buffers, reused between frames of the same size: the frame's own, and the
/// coarse pass's (its colour is scratch, its depth guides the frame; both share the counters).
struct Targets {
    width: u32,
    height: u32,
    uniform: wgpu::Buffer,
    color: wgpu::Buffer,
    depth: wgpu::Buffer,
    counters: wgpu::Buffer,
    /// Where the results are copied to be mapped; `None` where `color`, `depth` and `counters`
    /// are mapped themselves (a CPU adapter: `Gpu::maps_primary_buffers`).
    readback: Option<wgpu::Buffer>,
    group: wgpu::BindGroup,
    /// Parameters and bind group of the pass that marches the flat quads the interior pass
    /// gave back.
    given_back_uniform: wgpu::Buffer,
    given_back_group: wgpu::BindGroup,
    /// The coarse pass that guides the frame, and the coarser one that guides it.
    coarse: CoarseLevel,
    pre: CoarseLevel,
    /// The indirect dispatch size of a compacted guided pass (counted in `tile_dispatch` as
    /// `cs_tiles` lists the quads in a buffer only the bind groups hold, copied to `tile_args`:
    /// one buffer cannot be bound as storage and read as dispatch arguments by the same pass).
    tile_dispatch: wgpu::Buffer,
    tile_args: wgpu::Buffer,
    /// `tile_dispatch`'s starting values, copied in before each tile listing.
    tile_reset: wgpu::Buffer,
}

/// One coarse pass's buffers: its parameters, its results (rows of [`coarse_stride`] pixels, two
/// floats each, render.wgsl `coarse`; its colour is scratch) and their copy as a texture, which
/// the next finer pass reads, and its bind group (which binds the texture of the pass guiding
/// it).
struct CoarseLevel {
    uniform: wgpu::Buffer,
    depth: wgpu::Buffer,
    texture: wgpu::Texture,
    group: wgpu::BindGroup,
}

/// Ratio of a guided frame's coarse pass to the pre-coarse pass that guides it in turn: an
/// unguided coarse pass marches every ray over the whole box and cost a quarter of a 512²
/// frame; guided, its rays march a few steps like the frame's.
const PRE_FACTOR: u32 = 4;

/// How close (in coarse pixels, as seen from the eye) a coarse ray must pass to a surface some
/// camera sees for its miss to count as near: the fine pixels around it then march from a step
/// before where it first came near to the end of the box.
/// Two coarse pixels cover the 3×3 neighbourhood each fine pixel reads.
const GUIDE_REACH: f32 = 2.0;

/// [`Renderer::pipeline`] methods: the fixed baseline, the default marcher, both (per pixel).
const PIPELINE_FIXED: u32 = 1;
const PIPELINE_DEFAULT: u32 = 2;
const PIPELINE_BOTH: u32 = 3;
/// [`Renderer::pipeline`] roles (render.wgsl `ROLE`): a plain pass (not guided, guiding
/// nothing); a full-resolution marching pass of a guided frame (its guided pass, the pass over
/// the quads the interior pass gave back); the interior pass over the flat quads `cs_tiles`
/// lists; the coarse passes of a guided frame (pre-coarse and coarse), which need no shading;
/// the interior pass shading a 2×2 block of pixels per invocation (see
/// [`INTERIOR_BLOCK_REACH`]).
const ROLE_PLAIN: u32 = 0;
const ROLE_GUIDED: u32 = 1;
const ROLE_INTERIOR: u32 = 2;
const ROLE_COARSE: u32 = 3;
const ROLE_INTERIOR_BLOCKS: u32 = 4;

/// The interior pass shades a 2×2 block of pixels per invocation with the cameras of the
/// triangle met by the ray through the block's centre (render.wgsl `shade_interior_block`)
/// where the angle between any of its pixels' entries into the camera sphere and the centre
/// ray's cannot exceed this (radians): the direction lookup's own reach
/// ([`geometry::DIRECTION_LOOKUP_REACH`]), so a pixel lies no further outside the triangle whose
/// weights it takes than the lookup alone may put it, plus that much again. For an eye at
/// distance `e` from the centre (light-field units, camera sphere radius 1), rays at most
/// `√2/2` pixel (`0.71 / focal_px` rad) from the centre ray meet the camera sphere at most
/// `e + 1` along them, and an interior pixel's ray passes within the bounding sphere (radius
/// `1/√2`), so it meets the camera sphere at least 45° from grazing: the angle is at most
/// `√2 · (e + 1) · 0.71 / focal_px = (e + 1) / focal_px` ([`interior_block_angle`]; a test
/// checks it on sampled rays). At 512² and 40° (focal 703 px) that holds up to `e` = 1.95
/// (2.76 bounding radii from the centre).
const INTERIOR_BLOCK_REACH: f64 = geometry::DIRECTION_LOOKUP_REACH;

/// The bound of [`INTERIOR_BLOCK_REACH`] for an eye at distance `eye` from the centre
/// (light-field units) and a focal length of `focal_px` pixels.
fn interior_block_angle(eye: f64, focal_px: f64) -> f64 {
    (eye + 1.0) / focal_px
}

/// Whether the centres of every 2×2 block of pixels (`(2i, 2j)` to `(2i + 1, 2j + 1)`) of a
/// `width`×`height` frame guided at `factor` lie in one cell between four coarse pixels, which
/// the interior pass then loads once per block (render.wgsl `shade_interior_block`). Pixel `p`'s
/// centre lies at `(p + 0.5 − width/2)/factor + coarse/2 − 0.5` coarse pixels (render.wgsl
/// `coarse_position`); when `width` is `factor · coarse`, a cell boundary (an integer `n`)
/// falls at `p = factor·n + factor/2 − 0.5`, which is odd minus a half when `factor` is a
/// multiple of 4: between an odd pixel and the next even one, never inside a block, and half a
/// fine pixel from both (a sixteenth of a cell or more up to factor 8, far above f32
/// rounding). The same holds per row. For factors 2 and 4 no other size keeps every block in
/// one cell with its centres off the cells' boundaries; for larger factors a few more would (a
/// test checks the rule with the shader's f32 arithmetic).
fn blocks_share_coarse_cells(width: u32, height: u32, factor: u32) -> bool {
    factor >= 4
        && factor.is_multiple_of(4)
        && width.is_multiple_of(factor)
        && height.is_multiple_of(factor)
}

/// Whether all pixels of every 4×4 quad (render.wgsl `frame_quads`) of a `width`×`height` frame
/// guided at `factor` have the same nearest coarse pixel (render.wgsl `coarse_nearest`): the tile
/// pass then reads the 3×3 coarse pixels around each quad instead of 4×4 (render.wgsl
/// `TILE_SPAN`). The same rule as [`blocks_share_coarse_cells`]: when `width` is
/// `factor · coarse`, the fine pixels nearest to coarse pixel `n` are `factor·n` to
/// `factor·n + factor − 1`, whole quads when `factor` is a multiple of 4, each centre at least
/// half a fine pixel from the midpoint between two coarse pixels (tested with the shader's f32
/// arithmetic).
fn quads_share_nearest_coarse(width: u32, height: u32, factor: u32) -> bool {
    blocks_share_coarse_cells(width, height, factor)
}

/// [`Renderer::set_interior_blocks`] settings.
const BLOCKS_AUTOMATIC: u8 = 0;
const BLOCKS_OFF: u8 = 1;
const BLOCKS_ON: u8 = 2;

/// Largest second difference of a flat quad's coarse z-depths (render.wgsl `cs_tiles`), in
/// tolerances: bilinear interpolation between them is then within an eighth of it per axis of
/// a smooth surface through them, at most one tolerance in all. There the cameras' colours
/// still get some weight (full weight within half a tolerance), a depth that far off shifts
/// where each camera is read by about a tenth of a texel, and the interior pass's Newton step
/// corrects the depth it reports. Measured (eval, 6 views at 512², 162 cameras): 4 against 1
/// takes about 3 % less time at the same masked PSNR (±0.01 dB on the four fixtures) and
/// median depth error (±1 %); p95 depth error rises by up to 5 %.
const INTERIOR_CURVATURE: f32 = 4.0;

/// Coarse-pass size for a frame guided with `factor`, or `None` when guidance is off or the
/// frame is too small (under 4 coarse pixels a side).
fn coarse_size(width: u32, height: u32, factor: u32) -> Option<(u32, u32)> {
    (factor >= 2 && width >= 4 * factor && height >= 4 * factor)
        .then(|| (width.div_ceil(factor), height.div_ceil(factor)))
}

/// Environment variable that makes a renderer created while it is set time every frame's passes
/// (logged at `info` level on the `lumigraph_core::render` target): each pass is then submitted
/// and waited for on its own, which costs a little time, so leave it off for benchmarks of
/// whole frames.
pub const PASS_TIMING_VARIABLE: &str = "LUMIGRAPH_PASS_TIMING";

/// Per-pass timing of one frame ([`PASS_TIMING_VARIABLE`]): when on, [`PassTimer::split`]
/// submits what the encoder holds, waits, and logs the time since the previous split.
struct PassTimer {
    on: bool,
    last: Instant,
    passes: Vec<(&'static str, f64)>,
}

impl PassTimer {
    fn new(on: bool) -> PassTimer {
        PassTimer {
            on,
            last: Instant::now(),
            passes: Vec::new(),
        }
    }

    fn split(
        &mut self,
        gpu: &Gpu,
        encoder: wgpu::CommandEncoder,
        pass: &'static str,
    ) -> Result<wgpu::CommandEncoder, GpuError> {
        if !self.on {
            return Ok(encoder);
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.wait()?;
        self.passes
            .push((pass, self.last.elapsed().as_secs_f64() * 1e3));
        self.last = Instant::now();
        Ok(gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render"),
            }))
    }

    /// Logs the passes, the last one being the readback.
    fn finish(&mut self, width: u32, height: u32) {
        if self.on {
            self.passes
                .push(("readback", self.last.elapsed().as_secs_f64() * 1e3));
            let passes: Vec<String> = self
                .passes
                .iter()
                .map(|(pass, ms)| format!("{pass} {ms:.2} ms"))
                .collect();
            tracing::info!("{width}×{height} frame passes: {}", passes.join(", "));
        }
    }
}

/// The 8×8 tiles (workgroups) of a pass over `width` × `height` pixels, per row and per column.
fn tile_grid(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(8), height.div_ceil(8))
}

/// The 4×4 quads a compacted pass over `width` × `height` pixels lists (render.wgsl
/// `cs_tiles`), per row and per column.
fn quad_grid(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(4), height.div_ceil(4))
}

/// Bytes of a compacted guided frame's indirect dispatch sizes: three (x, y, z) triples (the
/// quads to march, the flat quads, the flat quads given back to be marched; four quads per
/// workgroup), then the three lists' lengths in quads (render.wgsl `tile_dispatch`).
const TILE_ARGS_SIZE: u64 = 48;
/// Byte offsets of the second and third triple.
const INTERIOR_ARGS: u64 = 12;
const GIVEN_BACK_ARGS: u64 = 24;

/// Most workgroups (four listed quads each) a compacted guided pass may dispatch: its indirect
/// dispatch counts them along one axis, whose size every device allows up to 65 535 (frames up
/// to about 2048²; a larger frame is guided without compaction).
const MAX_TILES: u32 = 65_535;

/// Pixels per row of a coarse pass's output: a multiple of 64, so that its rows (8 bytes a
/// pixel) meet the 256-byte row alignment of a buffer-to-texture copy.
fn coarse_stride(width: u32) -> u32 {
    width.div_ceil(64) * 64
}

/// How a compute pass counts its workgroups.
#[derive(Clone, Copy)]
enum Workgroups<'a> {
    /// A `columns` × `rows` grid.
    Grid(u32, u32),
    /// (x, y, z) read from a buffer at a byte offset.
    Indirect(&'a wgpu::Buffer, u64),
}

/// Records one compute pass of the marcher: `pipeline` with `frame` as bind group 0 and the
/// light field's `field` as group 1.
fn record_pass(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    (frame, field): (&wgpu::BindGroup, &wgpu::BindGroup),
    workgroups: Workgroups,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, frame, &[]);
    pass.set_bind_group(1, field, &[]);
    match workgroups {
        Workgroups::Grid(columns, rows) => pass.dispatch_workgroups(columns, rows, 1),
        Workgroups::Indirect(buffer, offset) => pass.dispatch_workgroups_indirect(buffer, offset),
    }
}

/// One entry point of the marcher's module as a compute pipeline, with its override constants.
fn compute_pipeline(
    device: &wgpu::Device,
    (layout, module): (&wgpu::PipelineLayout, &wgpu::ShaderModule),
    (label, entry_point): (&str, &str),
    constants: &[(&str, f64)],
) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        module,
        entry_point: Some(entry_point),
        compilation_options: wgpu::PipelineCompilationOptions {
            constants,
            ..Default::default()
        },
        cache: None,
    })
}

/// The light-field render pipeline; one per process, shared by threads.
pub struct Renderer {
    gpu: Arc<Gpu>,
    module: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
    /// Specialised pipelines, built on first use: index `5 · (methods − 1) + role` (see
    /// [`Renderer::pipeline`]).
    pipelines: [std::sync::OnceLock<wgpu::ComputePipeline>; 15],
    /// Tile compaction of guided passes (render.wgsl `cs_tiles`), on unless a test turns it
    /// off ([`Renderer::set_tile_compaction`]).
    /// Index 1 where the quads share their nearest coarse pixel ([`quads_share_nearest_coarse`]):
    /// it reads 3×3 coarse pixels per quad, not 4×4.
    tiles_pipelines: [wgpu::ComputePipeline; 2],
    compaction: std::sync::atomic::AtomicBool,
    /// Whether compacted guided passes send flat quads to the interior pass (on unless a test
    /// turns it off, [`Renderer::set_interior`]).
    interior: std::sync::atomic::AtomicBool,
    /// Whether the interior pass shades 2×2 blocks: [`BLOCKS_AUTOMATIC`] (by
    /// [`INTERIOR_BLOCK_REACH`]) unless a test forces it ([`Renderer::set_interior_blocks`]).
    interior_blocks: std::sync::atomic::AtomicU8,
    /// The tile pass reads 4×4 coarse pixels per quad even where 3×3 would do
    /// ([`Renderer::set_wide_tile_reads`], for tests).
    wide_tile_reads: std::sync::atomic::AtomicBool,
    /// Per-pass timing ([`PASS_TIMING_VARIABLE`] at creation, or
    /// [`Renderer::set_pass_timing`]).
    pass_timing: std::sync::atomic::AtomicBool,
    frame_layout: wgpu::BindGroupLayout,
    field_layout: wgpu::BindGroupLayout,
    linear: wgpu::Sampler,
    camera_buffer: wgpu::Buffer,
    hierarchy_buffer: wgpu::Buffer,
    /// [`geometry::CameraSet::direction_lookup`] (`locate` in the marcher).
    lookup_view: wgpu::TextureView,
    /// Reusable targets; the lock also serializes frames on the one queue.
    targets: Mutex<Option<Targets>>,
    max_px: u32,
}

fn buffer_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn texture_entry(binding: u32, filterable: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    }
}

impl Renderer {
    /// Builds the pipeline and uploads the icosphere cameras and hierarchy.
    pub fn new(gpu: Arc<Gpu>) -> Renderer {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(
                crate::shaders::render_source(device.features().contains(wgpu::Features::SUBGROUP))
                    .into(),
            ),
        });
        let storage = wgpu::BufferBindingType::Storage { read_only: false };
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render frame"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, storage),
                buffer_entry(2, storage),
                buffer_entry(3, storage),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                buffer_entry(5, storage),
                buffer_entry(6, storage),
            ],
        });
        let field_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light field"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, wgpu::BufferBindingType::Uniform),
                texture_entry(2, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&frame_layout), Some(&field_layout)],
            immediate_size: 0,
        });
        let sampler = |label, filter| {
            device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some(label),
                address_mode_u: wgpu::AddressMode::ClampToEdge,
                address_mode_v: wgpu::AddressMode::ClampToEdge,
                mag_filter: filter,
                min_filter: filter,
                ..Default::default()
            })
        };
        let linear = sampler("light-field linear", wgpu::FilterMode::Linear);
        let set = geometry::camera_set();
        // Each camera's position and the axis its frame is built from (render.wgsl `camera`).
        let cameras: Vec<[f32; 4]> = set
            .positions
            .iter()
            .map(|p| [p.x, p.y, p.z, geometry::camera_frame_axis(*p) as f32])
            .collect();
        let hierarchy: Vec<[u32; 4]> = set
            .triangles
            .iter()
            .map(|t| [t.v[0], t.v[1], t.v[2], t.first_child])
            .collect();
        // Uniform buffers (render.wgsl says why). The largest, the hierarchy, is 27 KiB (the
        // cameras 10 KiB): within every Vulkan, Metal and DX12 device's 64 KiB; a smaller limit
        // fails pipeline creation with a GPU error at the first frame, so say which limit it is
        // here.
        let largest = std::mem::size_of_val(cameras.as_slice())
            .max(std::mem::size_of_val(hierarchy.as_slice())) as u64;
        let limit = gpu.device.limits().max_uniform_buffer_binding_size;
        if largest > limit {
            tracing::error!(
                "the marcher needs {largest}-byte uniform buffers; this device allows {limit}"
            );
        }
        let uniform = |label, contents: &[u8]| {
            use wgpu::util::DeviceExt;
            gpu.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage: wgpu::BufferUsages::UNIFORM,
                })
        };
        let camera_buffer = uniform("icosphere cameras", bytemuck::cast_slice(&cameras));
        let hierarchy_buffer = uniform("icosphere hierarchy", bytemuck::cast_slice(&hierarchy));
        let lookup_view = direction_lookup_texture(&gpu);
        let max_px = DEFAULT_MAX_VIEW_PX.min(gpu.device.limits().max_texture_dimension_2d);
        let tiles_pipelines = [4.0, 3.0].map(|span| {
            compute_pipeline(
                device,
                (&layout, &module),
                ("render tiles", "cs_tiles"),
                &[("TILE_SPAN", span)],
            )
        });
        let renderer = Renderer {
            gpu,
            module,
            layout,
            pipelines: Default::default(),
            tiles_pipelines,
            compaction: std::sync::atomic::AtomicBool::new(true),
            interior: std::sync::atomic::AtomicBool::new(true),
            interior_blocks: std::sync::atomic::AtomicU8::new(BLOCKS_AUTOMATIC),
            wide_tile_reads: std::sync::atomic::AtomicBool::new(false),
            pass_timing: std::sync::atomic::AtomicBool::new(
                std::env::var_os(PASS_TIMING_VARIABLE).is_some(),
            ),
            frame_layout,
            field_layout,
            linear,
            camera_buffer,
            hierarchy_buffer,
            lookup_view,
            targets: Mutex::new(None),
            max_px,
        };
        // The default method's guided pipelines serve most frames: build them now, not in the
        // first frame.
        renderer.pipeline(PIPELINE_DEFAULT, ROLE_GUIDED);
        renderer.pipeline(PIPELINE_DEFAULT, ROLE_INTERIOR);
        renderer.pipeline(PIPELINE_DEFAULT, ROLE_COARSE);
        renderer.pipeline(PIPELINE_DEFAULT, ROLE_INTERIOR_BLOCKS);
        renderer
    }

    /// The marcher specialised for `methods` (1 = fixed, 2 = default, 3 = both, per pixel) and
    /// `role` ([`ROLE_PLAIN`], [`ROLE_GUIDED`], [`ROLE_INTERIOR`], [`ROLE_COARSE`],
    /// [`ROLE_INTERIOR_BLOCKS`]), built on first use. Lavapipe executes both sides of every
    /// branch for its 8-pixel batches, so each pass runs a pipeline holding only the code it can
    /// take (render.wgsl's `METHODS` and `ROLE`).
    fn pipeline(&self, methods: u32, role: u32) -> &wgpu::ComputePipeline {
        let index = (5 * (methods.clamp(1, 3) - 1) + role.min(4)) as usize;
        self.pipelines[index].get_or_init(|| {
            compute_pipeline(
                &self.gpu.device,
                (&self.layout, &self.module),
                ("render", "cs_main"),
                &[("METHODS", f64::from(methods)), ("ROLE", f64::from(role))],
            )
        })
    }

    /// Turns the tile compaction of guided passes on (the default) or off: for tests, which
    /// check that it changes no pixel.
    #[doc(hidden)]
    pub fn set_tile_compaction(&self, enabled: bool) {
        self.compaction
            .store(enabled, std::sync::atomic::Ordering::Relaxed);
    }

    /// Turns the interior pass of compacted guided frames on (the default) or off: for tests,
    /// which compare it with marching every pixel.
    #[doc(hidden)]
    pub fn set_interior(&self, enabled: bool) {
        self.interior
            .store(enabled, std::sync::atomic::Ordering::Relaxed);
    }

    /// Forces the interior pass's 2×2 blocks on (`Some(true)`) or off (`Some(false)`) instead
    /// of choosing them by [`INTERIOR_BLOCK_REACH`] (`None`, the default): for tests. Forced on,
    /// they are still used only where the frame's coarse grid allows them
    /// ([`blocks_share_coarse_cells`]).
    #[doc(hidden)]
    pub fn set_interior_blocks(&self, blocks: Option<bool>) {
        let value = match blocks {
            None => BLOCKS_AUTOMATIC,
            Some(false) => BLOCKS_OFF,
            Some(true) => BLOCKS_ON,
        };
        self.interior_blocks
            .store(value, std::sync::atomic::Ordering::Relaxed);
    }

    /// Makes the tile pass read 4×4 coarse pixels per quad even where the quads share their
    /// nearest coarse pixel and 3×3 would do ([`quads_share_nearest_coarse`]): for tests.
    #[doc(hidden)]
    pub fn set_wide_tile_reads(&self, wide: bool) {
        self.wide_tile_reads
            .store(wide, std::sync::atomic::Ordering::Relaxed);
    }

    /// Turns per-pass timing on or off (see [`PASS_TIMING_VARIABLE`], which sets it when the
    /// renderer is created).
    pub fn set_pass_timing(&self, enabled: bool) {
        self.pass_timing
            .store(enabled, std::sync::atomic::Ordering::Relaxed);
    }

    /// The device.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// Uploads an asset's base state and first layer (all cameras) as texture arrays.
    ///
    /// # Errors
    /// [`RenderError::Asset`] for unreadable images, [`RenderError::Gpu`] for device limits.
    pub fn upload(&self, asset: &AssetFile) -> Result<GpuLightField, RenderError> {
        self.upload_with(asset, &UploadOptions::default())
    }

    /// [`Renderer::upload`] with options: `depth_bits: Some(8)` requantizes a 16-bit asset's
    /// depth to the 8-bit codes an 8-bit bake stores (the depth-precision knob of the
    /// trade-off sweep, without a second bake).
    ///
    /// # Errors
    /// As [`Renderer::upload`]; [`RenderError::Option`] for depth bits other than 8 or 16, or
    /// 16 bits asked of an 8-bit asset (precision cannot be added back).
    pub fn upload_with(
        &self,
        asset: &AssetFile,
        options: &UploadOptions,
    ) -> Result<GpuLightField, RenderError> {
        let header = asset.header();
        let n = header.geometry.resolution_px;
        let cameras = header.geometry.camera_count;
        let max_level = u32::from(header.geometry.camera_level);
        let depth_encoding = header
            .encoding(Channel::Depth)
            .ok_or_else(|| AssetError::Header("no depth channel".to_owned()))?;
        let requantize_8 = match (options.depth_bits, depth_encoding) {
            (None, _) | (Some(8), Encoding::R8) => false,
            (Some(8), _) => true,
            (Some(16), Encoding::R8) => {
                return Err(RenderError::Option(
                    "depth bits 16 asked of an asset that stores 8-bit depth".to_owned(),
                ));
            }
            (Some(16), _) => false,
            (Some(b), _) => {
                return Err(RenderError::Option(format!("depth bits {b}: use 8 or 16")));
            }
        };
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if n > limit {
            return Err(GpuError::Limit {
                what: "map resolution",
                needed: n.into(),
                limit: limit.into(),
            }
            .into());
        }
        self.gpu.check_layers(Gpu::padded_layers(cameras))?;
        let mut colors = Vec::with_capacity(cameras as usize);
        let mut depths = Vec::with_capacity(cameras as usize);
        let mut visible = VisibleBox::default();
        let positions = &geometry::camera_set().positions;
        for k in 0..cameras {
            colors.push(asset.read_image(ImageKey::new(0, 0, k, Channel::Color))?);
            let raw = asset.read_image(ImageKey::new(0, 0, k, Channel::Depth))?;
            let codes: Vec<u16> = match depth_encoding {
                Encoding::R16 => raw
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect(),
                Encoding::R8 => raw
                    .iter()
                    .map(|&v| {
                        geometry::encode_depth_u16(if v == geometry::NO_HIT_U8 {
                            1.0
                        } else {
                            geometry::decode_depth_u8(v)
                        })
                    })
                    .collect(),
                _ => raw
                    .chunks_exact(4)
                    .map(|c| {
                        geometry::encode_depth_u16(
                            f32::from_le_bytes([c[0], c[1], c[2], c[3]]).max(0.0),
                        )
                    })
                    .collect(),
            };
            let codes = if requantize_8 {
                codes.into_iter().map(requantize_u16_to_u8).collect()
            } else {
                codes
            };
            visible.add_map(&codes, n as usize, positions[k as usize]);
            let codes = edge_codes(&codes, &mut colors[k as usize], n as usize);
            depths.push(footprint_texels(&codes, n as usize));
        }
        let color_refs: Vec<&[u8]> = colors.iter().map(Vec::as_slice).collect();
        let depth_refs: Vec<&[u8]> = depths.iter().map(Vec::as_slice).collect();
        let color_tex = texture_array(
            &self.gpu,
            "light-field colour",
            wgpu::TextureFormat::Rgba8Unorm,
            n,
            n,
            &color_refs,
        );
        let depth_tex = texture_array(
            &self.gpu,
            "light-field depth footprints",
            wgpu::TextureFormat::Rgba16Uint,
            n,
            n,
            &depth_refs,
        );
        let gpu_bytes = u64::from(Gpu::padded_layers(cameras)) * u64::from(n) * u64::from(n) * 12;
        let color_view = array_view(&color_tex);
        let depth_view = array_view(&depth_tex);
        let group = self
            .gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("light field"),
                layout: &self.field_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.camera_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.hierarchy_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(&color_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: wgpu::BindingResource::TextureView(&depth_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: wgpu::BindingResource::Sampler(&self.linear),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: wgpu::BindingResource::TextureView(&self.lookup_view),
                    },
                ],
            });
        let frame = &header.frame;
        Ok(GpuLightField {
            scale: frame.world_from_lf_scale(),
            center: DVec3::from(frame.center),
            radius: frame.radius,
            max_level,
            resolution: n,
            gpu_bytes,
            visible_box: visible.finish(n, requantize_8 || depth_encoding == Encoding::R8),
            group,
        })
    }

    fn targets_for(&self, width: u32, height: u32) -> Targets {
        let device = &self.gpu.device;
        let pixels = u64::from(width) * u64::from(height);
        // Sized for the finest coarse pass (factor 2), so any factor fits.
        let (coarse_w, coarse_h) = coarse_size(width, height, 2).unwrap_or((1, 1));
        let (pre_w, pre_h) = coarse_size(coarse_w, coarse_h, PRE_FACTOR).unwrap_or((1, 1));
        let depth_texture = |label, width, height| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rg32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let coarse_texture = depth_texture("coarse depth", coarse_w, coarse_h);
        let pre_texture = depth_texture("pre-coarse depth", pre_w, pre_h);
        let coarse_view = coarse_texture.create_view(&wgpu::TextureViewDescriptor::default());
        let pre_view = pre_texture.create_view(&wgpu::TextureViewDescriptor::default());
        let make = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        // On a CPU adapter the results are mapped where the shaders wrote them: the copy to a
        // staging buffer cost 0.2–0.3 ms of a 512² frame on lavapipe, about 1.5 % of a guided
        // demo frame (BENCHMARKS.md).
        let direct = self.gpu.maps_primary_buffers();
        let mapped = if direct {
            wgpu::BufferUsages::MAP_READ
        } else {
            wgpu::BufferUsages::empty()
        };
        let out = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | mapped;
        let uniform_usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let params_size = std::mem::size_of::<RenderParams>() as u64;
        let uniform = make("render params", params_size, uniform_usage);
        // Cleared before a compacted pass.
        let cleared = out | wgpu::BufferUsages::COPY_DST;
        let color = make("render colour", pixels * 4, cleared);
        let depth = make("render depth", pixels * 4, cleared);
        let counters = make("render counters", 16, out | wgpu::BufferUsages::COPY_DST);
        let readback = (!direct).then(|| {
            make(
                "render readback",
                pixels * 8 + 16,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            )
        });
        let (columns, rows) = quad_grid(width, height);
        // Two lists (render.wgsl `tiles`).
        let tiles = make(
            "render tiles",
            2 * u64::from(columns) * u64::from(rows) * 4,
            wgpu::BufferUsages::STORAGE,
        );
        let tile_dispatch = make(
            "render tile dispatch",
            TILE_ARGS_SIZE,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        );
        let tile_args = make(
            "render tile dispatch arguments",
            TILE_ARGS_SIZE,
            wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_DST,
        );
        // Three dispatch sizes (x, 1, 1), none counted yet: the quads to march, the flat quads,
        // the flat quads given back; then their three lengths, 0.
        let tile_reset = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("render tile dispatch reset"),
                contents: bytemuck::cast_slice(&[0u32, 1, 1, 0, 1, 1, 0, 1, 1, 0, 0, 0]),
                usage: wgpu::BufferUsages::COPY_SRC,
            })
        };
        // Every pass binds the depth texture of the pass guiding it (any, if none) and the tile
        // list; only a guided pass reads them.
        let group = |label, entries: [&wgpu::Buffer; 4], guide: &wgpu::TextureView| {
            let mut entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .enumerate()
                .map(|(binding, buffer)| wgpu::BindGroupEntry {
                    binding: binding as u32,
                    resource: buffer.as_entire_binding(),
                })
                .collect();
            entries.push(wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::TextureView(guide),
            });
            entries.push(wgpu::BindGroupEntry {
                binding: 5,
                resource: tiles.as_entire_binding(),
            });
            entries.push(wgpu::BindGroupEntry {
                binding: 6,
                resource: tile_dispatch.as_entire_binding(),
            });
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.frame_layout,
                entries: &entries,
            })
        };
        let frame_group = group(
            "render frame",
            [&uniform, &color, &depth, &counters],
            &coarse_view,
        );
        // The pass marching the quads the interior pass gave back: the frame's, but for its
        // parameters (`tiled` = 2).
        let given_back_uniform = make("render given-back params", params_size, uniform_usage);
        let given_back_group = group(
            "render given back",
            [&given_back_uniform, &color, &depth, &counters],
            &coarse_view,
        );
        let level = |name: &'static str, w: u32, h: u32, texture: wgpu::Texture, guide| {
            let pixels = u64::from(coarse_stride(w)) * u64::from(h);
            let uniform = make(name, params_size, uniform_usage);
            let color = make(name, pixels * 4, out);
            // Cleared before a compacted pass.
            let depth = make(name, pixels * 8, out | wgpu::BufferUsages::COPY_DST);
            let group = group(name, [&uniform, &color, &depth, &counters], guide);
            CoarseLevel {
                uniform,
                depth,
                texture,
                group,
            }
        };
        let coarse = level("coarse pass", coarse_w, coarse_h, coarse_texture, &pre_view);
        let pre = level("pre-coarse pass", pre_w, pre_h, pre_texture, &pre_view);
        Targets {
            width,
            height,
            uniform,
            color,
            depth,
            counters,
            readback,
            group: frame_group,
            given_back_uniform,
            given_back_group,
            coarse,
            pre,
            tile_dispatch,
            tile_args,
            tile_reset,
        }
    }

    /// Records a quad listing (`cs_tiles`, one invocation per 4×4 quad of a `width` × `height`
    /// pass guided at `factor`, in 8×8 workgroups) for the pass whose bind group is `group`,
    /// leaving its indirect dispatch sizes in `targets.tile_args`.
    fn list_tiles(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        targets: &Targets,
        group: &wgpu::BindGroup,
        field_group: &wgpu::BindGroup,
        (width, height, factor): (u32, u32, u32),
    ) {
        let (columns, rows) = quad_grid(width, height);
        encoder.copy_buffer_to_buffer(
            &targets.tile_reset,
            0,
            &targets.tile_dispatch,
            0,
            TILE_ARGS_SIZE,
        );
        record_pass(
            encoder,
            "render tiles",
            &self.tiles_pipelines[usize::from(
                quads_share_nearest_coarse(width, height, factor)
                    && !self
                        .wide_tile_reads
                        .load(std::sync::atomic::Ordering::Relaxed),
            )],
            (group, field_group),
            Workgroups::Grid(columns.div_ceil(8), rows.div_ceil(8)),
        );
        encoder.copy_buffer_to_buffer(
            &targets.tile_dispatch,
            0,
            &targets.tile_args,
            0,
            TILE_ARGS_SIZE,
        );
    }

    /// Renders `view` (world coordinates) from `field`.
    ///
    /// # Errors
    /// [`RenderError::View`] / [`RenderError::Option`] for bad input, [`RenderError::Gpu`].
    pub fn render(
        &self,
        field: &GpuLightField,
        view: &View,
        options: &RenderOptions,
    ) -> Result<Frame, RenderError> {
        self.render_blend(field, view, options, options, 0.0)
    }

    /// Renders `view` with a dithered cross-fade between two settings in one pass: a pixel
    /// whose 4×4 ordered-dither threshold `(rank + ½) / 16` is below `weight` renders with `b`,
    /// every other pixel with `a` (automatic LOD's transition, [`crate::lod`]). `weight` 0 is
    /// [`Renderer::render`] with `a`; 1 is with `b`.
    ///
    /// # Errors
    /// As [`Renderer::render`]; [`RenderError::Option`] for a weight outside [0, 1].
    pub fn render_blend(
        &self,
        field: &GpuLightField,
        view: &View,
        a: &RenderOptions,
        b: &RenderOptions,
        weight: f32,
    ) -> Result<Frame, RenderError> {
        self.render_jittered(field, view, a, b, weight, [0.0; 2])
    }

    /// [`Renderer::render_blend`] with every pixel's ray moved by `jitter` pixels: pixel (i, j)
    /// samples column `j + 0.5 + jitter[0]`, row `i + 0.5 + jitter[1]` (coarse passes move by
    /// the same amount of the frame's pixels), for sub-pixel sampling ([`crate::refine`]).
    ///
    /// # Errors
    /// As [`Renderer::render_blend`]; [`RenderError::Option`] for a jitter component that is not
    /// finite or outside [-0.5, 0.5].
    pub fn render_jittered(
        &self,
        field: &GpuLightField,
        view: &View,
        a: &RenderOptions,
        b: &RenderOptions,
        weight: f32,
        jitter: [f32; 2],
    ) -> Result<Frame, RenderError> {
        let basis = view.basis(self.max_px)?;
        if !(weight.is_finite() && (0.0..=1.0).contains(&weight)) {
            return Err(RenderError::Option(format!(
                "blend weight {weight} must be in [0, 1]"
            )));
        }
        if !jitter
            .iter()
            .all(|j| j.is_finite() && (-0.5..=0.5).contains(j))
        {
            return Err(RenderError::Option(format!(
                "jitter {jitter:?} must be finite and in [-0.5, 0.5] pixels"
            )));
        }
        let resolved_a = a.resolve(field.max_level)?;
        let first = ShaderSetting::of(&resolved_a);
        let second = ShaderSetting::of(&b.resolve(field.max_level)?);
        let start = Instant::now();
        let lf_eye = (basis.eye - field.center) / field.scale;
        if !lf_eye.is_finite() {
            return Err(RenderError::View(ViewError::NotFinite("eye")));
        }
        let params = RenderParams {
            eye: lf_eye.as_vec3().to_array(),
            width: view.width,
            right: basis.right.as_vec3().to_array(),
            height: view.height,
            up: basis.true_up.as_vec3().to_array(),
            focal_px: basis.focal_px as f32,
            forward: basis.forward.as_vec3().to_array(),
            level: first.level,
            step: first.step,
            tolerance: first.tolerance,
            max_steps: first.max_steps,
            method: first.method,
            resolution: field.resolution as f32,
            depth_scale: field.scale as f32,
            edge_gap: EDGE_GAP,
            refine_iterations: REFINE_ITERATIONS,
            front_mass: FRONT_MASS,
            blend: weight,
            coarse_factor: 0,
            near_scale: 0.0,
            box_min: field.visible_box[0],
            tiled: 0,
            box_max: field.visible_box[1],
            interior_curvature: 0.0,
            level_b: second.level,
            step_b: second.step,
            tolerance_b: second.tolerance,
            max_steps_b: second.max_steps,
            method_b: second.method,
            coarse_width: 0,
            coarse_height: 0,
            row_stride: view.width,
            interior_group_quads: 4,
            guide_step_ratio: 1.0,
            jitter,
        };
        // Coarse-to-fine (`guide`, the first setting's): a coarse pass renders every
        // guide-th pixel per axis, and its depths bound each pixel's march (render.wgsl).
        let guided = first.method != 0 && second.method != 0;
        let factor = resolved_a.guide;
        let coarse = coarse_size(view.width, view.height, factor).filter(|_| guided);
        let pixels = u64::from(view.width) * u64::from(view.height);
        let mut guard = self
            .targets
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if guard
            .as_ref()
            .is_none_or(|t| (t.width, t.height) != (view.width, view.height))
        {
            *guard = Some(self.targets_for(view.width, view.height));
        }
        let Some(targets) = guard.as_ref() else {
            return Err(GpuError::Operation("render targets missing".to_owned()).into());
        };
        let gpu = &self.gpu;
        let methods = match (first.method, second.method) {
            (0, 0) => PIPELINE_FIXED,
            (a, b) if a != 0 && b != 0 => PIPELINE_DEFAULT,
            _ => PIPELINE_BOTH,
        };
        let mut fine = params;
        // The coarse passes, coarsest first, with their sizes and focal lengths: the frame's
        // coarse pass is guided in turn by a pre-coarse pass PRE_FACTOR times coarser.
        let mut levels: Vec<(&CoarseLevel, (u32, u32), f32)> = Vec::new();
        if let Some((cw, ch)) = coarse {
            let focal = params.focal_px / factor as f32;
            if let Some(pre) = coarse_size(cw, ch, PRE_FACTOR) {
                levels.push((&targets.pre, pre, focal / PRE_FACTOR as f32));
            }
            levels.push((&targets.coarse, (cw, ch), focal));
            fine.coarse_factor = factor;
            fine.coarse_width = cw;
            fine.coarse_height = ch;
            fine.guide_step_ratio = COARSE_STEP_SCALE;
        }
        // A guided pass is compacted: `cs_tiles` lists the 4×4 quads with some pixel to march
        // and the pass runs one workgroup per four listed quads; the rest of its output stays cleared
        // (a miss). Lavapipe would run every instruction for a skipped pixel anyway. The frame's
        // pass and a coarse pass guided by a pre-coarse one are compacted alike.
        let (columns, rows) = tile_grid(view.width, view.height);
        let (quad_columns, quad_rows) = quad_grid(view.width, view.height);
        let tiled = coarse.is_some()
            && (u64::from(quad_columns) * u64::from(quad_rows)).div_ceil(4) <= u64::from(MAX_TILES)
            && self.compaction.load(std::sync::atomic::Ordering::Relaxed);
        for (i, &(level, (w, h), focal)) in levels.iter().enumerate() {
            let mut level_params = RenderParams {
                width: w,
                height: h,
                focal_px: focal,
                near_scale: GUIDE_REACH / focal,
                refine_iterations: COARSE_REFINE_ITERATIONS,
                step: params.step * COARSE_STEP_SCALE,
                max_steps: max_steps_for(params.step * COARSE_STEP_SCALE),
                step_b: params.step_b * COARSE_STEP_SCALE,
                max_steps_b: max_steps_for(params.step_b * COARSE_STEP_SCALE),
                row_stride: coarse_stride(w),
                // The same image-plane shift, in this pass's pixels.
                jitter: params.jitter.map(|j| j * focal / params.focal_px),
                ..params
            };
            if let Some(&(_, (gw, gh), _)) = i.checked_sub(1).and_then(|g| levels.get(g)) {
                level_params.coarse_factor = PRE_FACTOR;
                level_params.coarse_width = gw;
                level_params.coarse_height = gh;
                level_params.tiled = u32::from(tiled);
            }
            gpu.queue
                .write_buffer(&level.uniform, 0, bytemuck::bytes_of(&level_params));
        }
        fine.tiled = u32::from(tiled);
        // Flat quads skip the march (default method only: the fixed baseline marches every
        // pixel it renders).
        let interior = tiled
            && methods == PIPELINE_DEFAULT
            && self.interior.load(std::sync::atomic::Ordering::Relaxed);
        let blocks = blocks_share_coarse_cells(view.width, view.height, factor)
            && match self
                .interior_blocks
                .load(std::sync::atomic::Ordering::Relaxed)
            {
                BLOCKS_OFF => false,
                BLOCKS_ON => true,
                _ => interior_block_angle(lf_eye.length(), basis.focal_px) <= INTERIOR_BLOCK_REACH,
            };
        if blocks {
            // 16 quads per workgroup: 4 invocations each (render.wgsl `cs_main`).
            fine.interior_group_quads = 16;
        }
        if interior {
            fine.interior_curvature =
                INTERIOR_CURVATURE * first.tolerance.min(second.tolerance) * field.scale as f32;
        }
        if interior {
            let given_back = RenderParams { tiled: 2, ..fine };
            gpu.queue.write_buffer(
                &targets.given_back_uniform,
                0,
                bytemuck::bytes_of(&given_back),
            );
        }
        gpu.queue
            .write_buffer(&targets.uniform, 0, bytemuck::bytes_of(&fine));
        gpu.queue.write_buffer(&targets.counters, 0, &[0u8; 16]);
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render"),
            });
        let mut timer = PassTimer::new(self.pass_timing.load(std::sync::atomic::Ordering::Relaxed));
        encoder = timer.split(gpu, encoder, "uploads")?;
        for (i, &(level, (cw, ch), _)) in levels.iter().enumerate() {
            // Every coarse pass marks near misses; all but the coarsest are guided, and
            // compacted with the frame (the pixels it skips read as far misses, cleared to 0).
            let (level_columns, level_rows) = tile_grid(cw, ch);
            let compact = tiled && i > 0;
            if compact {
                encoder.clear_buffer(&level.depth, 0, None);
                self.list_tiles(
                    &mut encoder,
                    targets,
                    &level.group,
                    &field.group,
                    (cw, ch, PRE_FACTOR),
                );
            }
            record_pass(
                &mut encoder,
                "render coarse",
                self.pipeline(methods, ROLE_COARSE),
                (&level.group, &field.group),
                if compact {
                    Workgroups::Indirect(&targets.tile_args, 0)
                } else {
                    Workgroups::Grid(level_columns, level_rows)
                },
            );
            encoder.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer: &level.depth,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(8 * coarse_stride(cw)),
                        rows_per_image: Some(ch),
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &level.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d {
                    width: cw,
                    height: ch,
                    depth_or_array_layers: 1,
                },
            );
            let name = if i + 1 < levels.len() {
                "pre-coarse"
            } else {
                "coarse"
            };
            encoder = timer.split(gpu, encoder, name)?;
        }
        if tiled {
            encoder.clear_buffer(&targets.color, 0, Some(pixels * 4));
            encoder.clear_buffer(&targets.depth, 0, Some(pixels * 4));
            self.list_tiles(
                &mut encoder,
                targets,
                &targets.group,
                &field.group,
                (view.width, view.height, factor),
            );
            encoder = timer.split(gpu, encoder, "tiles")?;
        }
        let role = if coarse.is_some() {
            ROLE_GUIDED
        } else {
            ROLE_PLAIN
        };
        record_pass(
            &mut encoder,
            "render",
            self.pipeline(methods, role),
            (&targets.group, &field.group),
            if tiled {
                Workgroups::Indirect(&targets.tile_args, 0)
            } else {
                Workgroups::Grid(columns, rows)
            },
        );
        encoder = timer.split(gpu, encoder, "frame")?;
        if interior {
            record_pass(
                &mut encoder,
                "render interior",
                self.pipeline(
                    methods,
                    if blocks {
                        ROLE_INTERIOR_BLOCKS
                    } else {
                        ROLE_INTERIOR
                    },
                ),
                (&targets.group, &field.group),
                Workgroups::Indirect(&targets.tile_args, INTERIOR_ARGS),
            );
            encoder.copy_buffer_to_buffer(
                &targets.tile_dispatch,
                GIVEN_BACK_ARGS,
                &targets.tile_args,
                GIVEN_BACK_ARGS,
                12,
            );
            record_pass(
                &mut encoder,
                "render given back",
                self.pipeline(methods, ROLE_GUIDED),
                (&targets.given_back_group, &field.group),
                Workgroups::Indirect(&targets.tile_args, GIVEN_BACK_ARGS),
            );
            encoder = timer.split(gpu, encoder, "interior")?;
        }
        let split = (pixels * 4) as usize;
        if let Some(readback) = &targets.readback {
            encoder.copy_buffer_to_buffer(&targets.color, 0, readback, 0, pixels * 4);
            encoder.copy_buffer_to_buffer(&targets.depth, 0, readback, pixels * 4, pixels * 4);
            encoder.copy_buffer_to_buffer(&targets.counters, 0, readback, pixels * 8, 16);
        }
        gpu.queue.submit([encoder.finish()]);
        let read = |color: &[u8], depth: &[u8], counters: &[u8]| {
            let depth: Vec<f32> = depth
                .chunks_exact(4)
                .map(|c| {
                    let z = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                    // Misses: −1 where marched, 0 where a compacted pass cleared (a hit has
                    // z > 0).
                    if z <= 0.0 { f32::INFINITY } else { z }
                })
                .collect();
            let counters: Vec<u32> = counters
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            (color.to_vec(), depth, counters)
        };
        let (color, depth, counters) = match &targets.readback {
            Some(readback) => gpu.map_read_with(readback, |bytes| {
                read(
                    &bytes[..split],
                    &bytes[split..2 * split],
                    &bytes[2 * split..2 * split + 16],
                )
            })?,
            None => gpu.map_read_many(
                &[&targets.color, &targets.depth, &targets.counters],
                |bytes| read(bytes[0], bytes[1], bytes[2]),
            )?,
        };
        drop(guard);
        let render_ms = start.elapsed().as_secs_f64() * 1e3;
        timer.finish(view.width, view.height);
        Ok(Frame {
            width: view.width,
            height: view.height,
            color,
            depth,
            stats: FrameStats {
                render_ms,
                rays: u64::from(counters[2]),
                steps: u64::from(counters[1]),
                fetches: u64::from(counters[0]),
            },
        })
    }
}

/// Running bounds of the surface points the depth maps hold (light-field units).
struct VisibleBox {
    lo: glam::Vec3,
    hi: glam::Vec3,
}

impl Default for VisibleBox {
    fn default() -> Self {
        VisibleBox {
            lo: glam::Vec3::splat(f32::INFINITY),
            hi: glam::Vec3::splat(f32::NEG_INFINITY),
        }
    }
}

impl VisibleBox {
    /// Adds every hit texel of one camera's `n×n` map: the point `p + d·chord·w` of the
    /// texel centre's direction `w` (the parabolic inverse in the camera frame).
    fn add_map(&mut self, codes: &[u16], n: usize, camera: glam::Vec3) {
        let [fx, fy, fz] = geometry::camera_frame(camera);
        let scale = 2.0 / n as f32;
        for (row, line) in codes.chunks_exact(n).enumerate() {
            let v = (row as f32 + 0.5) * scale - 1.0;
            for (col, &code) in line.iter().enumerate() {
                if code == geometry::NO_HIT_U16 {
                    continue;
                }
                let u = (col as f32 + 0.5) * scale - 1.0;
                let s = u * u + v * v;
                let inv = 1.0 / (1.0 + s);
                let (rx, ry, rz) = (2.0 * u * inv, 2.0 * v * inv, (1.0 - s) * inv);
                if rz <= 0.0 {
                    continue;
                }
                let w = fx * rx + fy * ry + fz * rz;
                // Chord of a unit-sphere camera along w: −2 p·w = 2 r_z.
                let x = camera + w * (geometry::decode_depth_u16(code) * 2.0 * rz);
                self.lo = self.lo.min(x);
                self.hi = self.hi.max(x);
            }
        }
    }

    /// The box grown by a margin covering what a lookup can return beyond the texel centres:
    /// one texel of angle (≤ 2/n rad per texel at the rim) at chord ≤ 2, doubled, plus the
    /// depth quantization (8-bit: 1/255 of a chord ≤ 2), plus 0.01 for f32 rounding. An empty
    /// map gives an empty box (lo > hi), which no ray enters.
    fn finish(&self, n: u32, eight_bit: bool) -> [[f32; 3]; 2] {
        if self.lo.cmpgt(self.hi).any() {
            return [[1.0; 3], [-1.0; 3]];
        }
        let quantization = if eight_bit {
            2.0 / 255.0
        } else {
            2.0 / 65535.0
        };
        let margin = 8.0 / n.max(1) as f32 + quantization + 0.01;
        [(self.lo - margin).to_array(), (self.hi + margin).to_array()]
    }
}

/// The 16-bit code of the depth an 8-bit bake would store for a 16-bit code (no hit stays no
/// hit). The extra rounding of the 16-bit code moves the 8-bit decision only for depths within
/// 1/131070 of an 8-bit rounding boundary.
fn requantize_u16_to_u8(code: u16) -> u16 {
    if code == geometry::NO_HIT_U16 {
        return code;
    }
    let d8 = geometry::encode_depth_u8(geometry::decode_depth_u16(code));
    geometry::encode_depth_u16(geometry::decode_depth_u8(d8))
}

/// First footprint code of a no-hit texel beside the silhouette ([`edge_codes`]); hit codes are
/// capped below it (every hit of a valid asset has depth < 0.854, code ≤ 55 962).
const EDGE_BASE: u16 = u16::MAX - EDGE_CODES;
/// Edge codes: `EDGE_BASE + (e level << 9 | depth level)`, up to 65 534 (no-hit is 65 535).
const EDGE_CODES: u16 = EDGE_E_LEVELS * EDGE_DEPTH_LEVELS;
/// Levels of the silhouette position e in an edge code: e = (level + 0.5) / 16 texel.
const EDGE_E_LEVELS: u16 = 16;
/// Levels of the extrapolated depth in an edge code: depth = level / 511.
const EDGE_DEPTH_LEVELS: u16 = 512;

/// Folds the sub-texel silhouettes of a camera's `n×n` colour map into its depth codes, where
/// `probe` (render.wgsl) reads them in the same load as the depths. A no-hit texel with alpha
/// A > 0 lies beside the silhouette, which passes e = A / 255 texel spacings from the centres of
/// its hit 4-neighbours at depth code R | G << 8 (docs/format.md §8.5). It gets code
/// `EDGE_BASE + e level · 512 + depth level`, where the depth is the line from its neighbours'
/// mean depth through the silhouette's depth (at e) extended to its own centre: bilinear weights
/// over the footprint then reproduce the surface receding to the silhouette instead of a flat
/// skirt in front of it. Its colour becomes 0, as the format has no-hit colour; a texel without a
/// hit neighbour (no silhouette to place) stays plain no hit.
fn edge_codes(codes: &[u16], color: &mut [u8], n: usize) -> Vec<u16> {
    let mut out: Vec<u16> = codes
        .iter()
        .map(|&c| {
            if c == geometry::NO_HIT_U16 {
                c
            } else {
                c.min(EDGE_BASE - 1)
            }
        })
        .collect();
    for (i, texel) in color.chunks_exact_mut(4).enumerate().take(codes.len()) {
        if codes[i] != geometry::NO_HIT_U16 || texel[3] == 0 {
            continue;
        }
        let (a, silhouette) = (texel[3], u16::from_le_bytes([texel[0], texel[1]]));
        texel.copy_from_slice(&[0; 4]);
        let (sum, count) = geometry::texel_neighbours(i, n)
            .into_iter()
            .flatten()
            .filter_map(|j| codes.get(j).copied())
            .filter(|&c| c != geometry::NO_HIT_U16)
            .fold((0.0_f64, 0_u32), |(sum, count), c| {
                (sum + f64::from(c) / 65535.0, count + 1)
            });
        if count == 0 {
            continue;
        }
        let near = sum / f64::from(count);
        let e_level = (f64::from(a) / 255.0 * f64::from(EDGE_E_LEVELS)).floor() as u16;
        let e_level = e_level.min(EDGE_E_LEVELS - 1);
        // The position the shader decodes, so that its bilinear depth meets the silhouette's
        // exactly there.
        let e = (f64::from(e_level) + 0.5) / f64::from(EDGE_E_LEVELS);
        let silhouette = f64::from(silhouette.min(geometry::NO_HIT_U16 - 1)) / 65535.0;
        let extrapolated = (near + (silhouette - near) / e).clamp(0.0, 1.0);
        let depth_level = (extrapolated * f64::from(EDGE_DEPTH_LEVELS - 1)).round() as u16;
        out[i] = EDGE_BASE + e_level * EDGE_DEPTH_LEVELS + depth_level;
    }
    out
}

/// Packs a camera's `n×n` depth codes into footprint texels: texel `(x, y)` holds the codes of
/// `(x, y)`, `(x+1, y)`, `(x, y+1)`, `(x+1, y+1)` (clamped at the border), as `Rgba16Uint` bytes.
fn footprint_texels(codes: &[u16], n: usize) -> Vec<u8> {
    let at = |x: usize, y: usize| {
        codes
            .get(y.min(n - 1) * n + x.min(n - 1))
            .copied()
            .unwrap_or(geometry::NO_HIT_U16)
    };
    let mut out = Vec::with_capacity(n * n * 8);
    for y in 0..n {
        for x in 0..n {
            for code in [at(x, y), at(x + 1, y), at(x, y + 1), at(x + 1, y + 1)] {
                out.extend_from_slice(&code.to_le_bytes());
            }
        }
    }
    out
}

/// The marcher's direction lookup ([`geometry::CameraSet::direction_lookup`] at
/// [`geometry::DIRECTION_LOOKUP_SIZE`]), built once per process.
fn direction_lookup() -> &'static [u16] {
    static LOOKUP: std::sync::OnceLock<Vec<u16>> = std::sync::OnceLock::new();
    LOOKUP.get_or_init(|| geometry::camera_set().direction_lookup(geometry::DIRECTION_LOOKUP_SIZE))
}

/// [`direction_lookup`] as a texture.
fn direction_lookup_texture(gpu: &Gpu) -> wgpu::TextureView {
    use wgpu::util::DeviceExt;
    let n = geometry::DIRECTION_LOOKUP_SIZE;
    gpu.device
        .create_texture_with_data(
            &gpu.queue,
            &wgpu::TextureDescriptor {
                label: Some("icosphere direction lookup"),
                size: wgpu::Extent3d {
                    width: n,
                    height: n,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R16Uint,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            bytemuck::cast_slice(direction_lookup()),
        )
        .create_view(&wgpu::TextureViewDescriptor::default())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use std::f64::consts::FRAC_1_SQRT_2;

    /// The shader's `locate`, replayed on the CPU in f32 with the same lookup: the triangle
    /// and the weights of its cameras.
    fn locate_like_shader(p: Vec3, level: u32) -> (usize, [u32; 3], [f32; 3]) {
        let set = geometry::camera_set();
        let n = geometry::DIRECTION_LOOKUP_SIZE;
        let lookup = direction_lookup();
        let (i, j) = geometry::octahedral_texel(p, n);
        let finest = u32::from(lookup[(j * n + i) as usize]);
        let l = level.min(geometry::MAX_LEVEL);
        let local = finest >> (2 * (geometry::MAX_LEVEL - l));
        let level_start = 20 * ((1u32 << (2 * l)) - 1) / 3;
        let t = (level_start + local) as usize;
        let v = set.triangles[t].v;
        (t, v, weights_like_shader(p, v))
    }

    /// The shader's `triangle_weights` in f32: direction `p`'s central-projection barycentric
    /// weights in the triangle of cameras `v`, clamped to it.
    fn weights_like_shader(p: Vec3, v: [u32; 3]) -> [f32; 3] {
        let [v0, v1, v2] = v.map(|k| geometry::camera_set().positions[k as usize]);
        let w = Vec3::new(
            p.dot(v1.cross(v2)),
            v0.dot(p.cross(v2)),
            v0.dot(v1.cross(p)),
        )
        .max(Vec3::ZERO);
        let sum = w.x + w.y + w.z;
        (if sum > 0.0 { w / sum } else { Vec3::X }).to_array()
    }

    /// Uniform pseudo-random numbers in [−1, 1) from `seed`.
    fn signed_uniform(seed: u64) -> impl FnMut() -> f32 {
        let mut raw = crate::xorshift(seed);
        move || (raw() >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    }

    /// `count` random unit directions drawn from `next` (uniform in [−1, 1] per axis).
    fn random_directions(next: &mut impl FnMut() -> f32, count: usize) -> Vec<Vec3> {
        (0..count)
            .map(|_| Vec3::new(next(), next(), next()).normalize())
            .collect()
    }

    /// Every icosphere triangle's cameras and edge midpoints (all levels), triangle by
    /// triangle: where a lookup or a triangle's weights can go wrong.
    fn vertices_and_edge_midpoints() -> Vec<Vec3> {
        let set = geometry::camera_set();
        set.triangles
            .iter()
            .flat_map(|t| {
                let [a, b, c] = t.v.map(|k| set.positions[k as usize]);
                [
                    a,
                    (a + b).normalize(),
                    (b + c).normalize(),
                    (c + a).normalize(),
                ]
            })
            .collect()
    }

    /// The smallest height of a `level` triangle over any of its edges, as the sine of the
    /// angle from that edge's great circle to the opposite camera.
    fn smallest_height(level: u32) -> f32 {
        let set = geometry::camera_set();
        set.triangles[set.level_range(level)]
            .iter()
            .flat_map(|t| {
                let [a, b, c] = t.v.map(|k| set.positions[k as usize]);
                [(a, b, c), (b, c, a), (c, a, b)]
                    .map(|(x, y, z)| x.cross(y).normalize().dot(z).abs())
            })
            .fold(f32::INFINITY, f32::min)
    }

    /// `probe`'s decoding of an edge code (render.wgsl): (e, extrapolated depth), in f32 as there.
    fn decode_edge_like_shader(code: u16) -> (f32, f32) {
        let rel = u32::from(code.wrapping_sub(EDGE_BASE));
        assert!(rel < u32::from(EDGE_CODES));
        let e = ((rel >> 9) as f32 + 0.5) / f32::from(EDGE_E_LEVELS);
        let depth = (rel & 511) as f32 * (1.0 / 511.0);
        (e, depth)
    }

    #[test]
    fn edge_codes_place_the_silhouette_and_extend_the_depth() {
        // A 4×2 map: row 0 = hit (depth 0.4), edge texel (e = 100/255, silhouette depth 0.5),
        // plain no hit, an edge texel with no hit neighbour; row 1 = a hit whose code lies in
        // the edge range (capped), then no hits with alpha 0.
        let n = 4;
        let code = |d: f64| (d * 65535.0).round() as u16;
        let no = geometry::NO_HIT_U16;
        let codes = vec![code(0.4), no, no, no, 60_000, no, no, no];
        let mut color = vec![0u8; 32];
        color[..4].copy_from_slice(&[10, 20, 30, 255]);
        let sil = code(0.5).to_le_bytes();
        color[4..8].copy_from_slice(&[sil[0], sil[1], 0, 100]);
        color[12..16].copy_from_slice(&[sil[0], sil[1], 0, 77]);
        color[16..20].copy_from_slice(&[1, 2, 3, 255]);
        let out = edge_codes(&codes, &mut color, n);
        // Hits keep their codes and colours, capped below the edge range.
        assert_eq!(out[0], codes[0]);
        assert_eq!(out[4], EDGE_BASE - 1);
        assert_eq!(&color[..4], &[10, 20, 30, 255]);
        // Plain no-hit texels stay; an edge texel without a hit 4-neighbour (texel 3: its
        // neighbours are texels 2 and 7) becomes plain no hit; edge colours are cleared.
        assert_eq!((out[2], out[3], out[5]), (no, no, no));
        assert_eq!(&color[4..8], &[0; 4]);
        assert_eq!(&color[12..16], &[0; 4]);
        // Texel 1: its neighbours are texel 0 (hit, 0.4), texel 2 and texel 5 (no hit).
        assert!((EDGE_BASE..no).contains(&out[1]));
        let (e, depth) = decode_edge_like_shader(out[1]);
        // e: 100/255 = 0.392 lies in level 6 of 16 (0.375–0.4375), decoded at its middle.
        assert_eq!(e, 6.5 / 16.0);
        // The line from 0.4 (at the hit centre) through 0.5 (at e) reaches 0.4 + 0.1 / e at this
        // texel's centre; within half a depth level (0.5 / 511) plus f32 rounding.
        let want = 0.4 + 0.1 / f64::from(e);
        assert!(
            (f64::from(depth) - want).abs() <= 0.5 / 511.0 + 1e-5,
            "{depth} vs {want}"
        );
        // Every code round-trips: all e levels and depth levels decode to themselves.
        for e_level in 0..EDGE_E_LEVELS {
            for depth_level in [0, 1, 295, EDGE_DEPTH_LEVELS - 1] {
                let c = EDGE_BASE + e_level * EDGE_DEPTH_LEVELS + depth_level;
                assert!(c < no);
                let (e, d) = decode_edge_like_shader(c);
                assert_eq!(e, (f32::from(e_level) + 0.5) / 16.0);
                let want = f32::from(depth_level) / f32::from(EDGE_DEPTH_LEVELS - 1);
                assert!((d - want).abs() < 1e-6, "{c}: {d} vs {want}");
            }
        }
        // Extrapolation is clamped to [0, 1]: a silhouette far behind a near hit at e ≈ 0.
        let mut color = vec![0u8; 16];
        let far = code(0.85).to_le_bytes();
        color[4..8].copy_from_slice(&[far[0], far[1], 0, 1]);
        let out = edge_codes(&[code(0.1), no, no, no], &mut color, 2);
        assert_eq!(decode_edge_like_shader(out[1]).1, 1.0);
    }

    #[test]
    fn requantized_depth_equals_an_8_bit_bake() {
        // Exact: for every 16-bit hit code, the requantized code decodes to the 8-bit code an
        // 8-bit bake of the same depth stores, except within 1/131070 of a rounding boundary.
        let mut off_boundary = 0;
        for code in 0..geometry::NO_HIT_U16 {
            let d = geometry::decode_depth_u16(code);
            let want =
                geometry::encode_depth_u16(geometry::decode_depth_u8(geometry::encode_depth_u8(d)));
            let got = requantize_u16_to_u8(code);
            let frac = (f64::from(d) * 255.0).fract();
            if (frac - 0.5).abs() > 1.0 / 256.0 {
                off_boundary += 1;
                assert_eq!(got, want, "code {code}");
            }
            // Within 0.5/255 (+ f32 rounding) of the 16-bit depth below 254.5/255, as the
            // format promises; above, the last hit code 254 is up to 1/255 away.
            let err = (geometry::decode_depth_u16(got) - d).abs();
            let bound = if d < 254.5 / 255.0 { 0.5 } else { 1.0 } / 255.0 + 1e-6;
            assert!(err <= bound, "code {code}: {err}");
        }
        assert!(off_boundary > 60_000);
        assert_eq!(
            requantize_u16_to_u8(geometry::NO_HIT_U16),
            geometry::NO_HIT_U16
        );
    }

    /// The largest difference, over the cameras of both, between the weights the shader's
    /// lookup gives direction `p` at `level` and the exact ones of [`geometry::CameraSet::locate`],
    /// and how far (sine of the angle) `p` lies outside the triangle the lookup found.
    fn lookup_error(p: Vec3, level: u32) -> (f32, f32) {
        lookup_error_at(p, p, level)
    }

    /// [`lookup_error`] for a direction `p` weighed in the triangle the shader finds for
    /// another, `c` (an interior block's centre, render.wgsl `shade_interior_block`).
    fn lookup_error_at(c: Vec3, p: Vec3, level: u32) -> (f32, f32) {
        let set = geometry::camera_set();
        let (t, cams, _) = locate_like_shader(c, level);
        assert!(
            set.level_range(level).contains(&t),
            "level {level}: triangle {t}"
        );
        let w = weights_like_shader(p, cams);
        let exact = set.locate(p, level);
        let weight_of = |cams: &[u32; 3], w: &[f32; 3], k: u32| {
            cams.iter()
                .zip(w)
                .filter(|(c, _)| **c == k)
                .map(|(_, w)| *w)
                .sum::<f32>()
        };
        let worst = cams
            .iter()
            .chain(&exact.cameras)
            .map(|&k| {
                (weight_of(&cams, &w, k) - weight_of(&exact.cameras, &exact.weights, k)).abs()
            })
            .fold(0.0f32, f32::max);
        let [a, b, c] = cams.map(|k| set.positions[k as usize]);
        let outside = [(a, b), (b, c), (c, a)]
            .iter()
            .map(|(x, y)| -x.cross(*y).normalize().dot(p))
            .fold(f32::NEG_INFINITY, f32::max);
        (worst, outside)
    }

    #[test]
    fn shader_lookup_finds_the_triangle_within_its_reach() {
        // Random directions, and the places a lookup can go wrong: the cameras (vertices), the
        // midpoints of every level's edges, points just beside both, the octahedral map's fold
        // (z = 0), its axes and its corners (the poles).
        let mut next = signed_uniform(0x2545_f491_4f6c_dd1d);
        let mut points = random_directions(&mut next, 20_000);
        for q in vertices_and_edge_midpoints() {
            points.push(q);
            for _ in 0..4 {
                let jitter = Vec3::new(next(), next(), next()) * 3e-3;
                points.push((q + jitter).normalize());
            }
        }
        for k in 0..2000 {
            let a = k as f32 / 2000.0 * std::f32::consts::TAU;
            points.push(Vec3::new(a.cos(), a.sin(), 0.0));
            points.push(Vec3::new(a.cos(), a.sin(), 1e-7).normalize());
            points.push(Vec3::new(a.cos(), a.sin(), -1e-7).normalize());
        }
        points.extend([Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z]);
        // A direction lies within DIRECTION_LOOKUP_REACH of its texel's centre, which its
        // triangle holds, so it lies at most that far outside it (sine, plus f32 rounding).
        let reach = geometry::DIRECTION_LOOKUP_REACH.sin() as f32 + 1e-5;
        // Weights: a point δ outside its triangle, across an edge, gets the weights of the
        // nearest point of that edge, where the exact triangle gives its opposite camera
        // about δ / h of weight (h: the height over that edge, as a sine); the weights of the
        // edge's cameras move by as much. Bound: 2 · reach / the smallest height of the
        // level's triangles.
        for level in 0..=3u32 {
            let height = smallest_height(level);
            let bound = 2.0 * reach / height;
            let (mut worst_w, mut worst_out) = (0.0f32, f32::NEG_INFINITY);
            for &p in &points {
                let (w, out) = lookup_error(p, level);
                worst_w = worst_w.max(w);
                worst_out = worst_out.max(out);
            }
            eprintln!(
                "level {level}: weights off by up to {worst_w} (bound {bound}, smallest height \
                 {height}), outside by up to {worst_out}"
            );
            assert!(
                worst_out <= reach,
                "level {level}: {worst_out} outside (reach {reach})"
            );
            assert!(
                worst_w <= bound,
                "level {level}: weights off by {worst_w} (bound {bound})"
            );
        }
    }

    /// The shader's `camera`, replayed on the CPU in f32: the frame of a camera at `p` built
    /// from the world axis of index `axis`.
    fn camera_like_shader(p: Vec3, axis: f32) -> [Vec3; 3] {
        let z = -p.normalize();
        let a = Vec3::select(
            Vec3::splat(axis).cmpeq(Vec3::new(0.0, 1.0, 2.0)),
            Vec3::ONE,
            Vec3::ZERO,
        );
        let x = a.cross(z).normalize();
        [x, z.cross(x), z]
    }

    #[test]
    fn shader_derives_the_camera_frames_of_the_bake() {
        // Every camera of the set (642, all levels): the frame the marcher derives from the
        // position and the axis index the renderer uploads equals the CPU's f64 frame, which
        // the bake rendered with, to f32 rounding (bound 1e-6 per component of the unit
        // vectors: a 256-texel map's texel spans about 0.008 rad, so a ten-thousandth of one).
        let set = geometry::camera_set();
        let mut worst = 0.0f32;
        for &p in &set.positions {
            let axis = geometry::camera_frame_axis(p) as f32;
            let derived = camera_like_shader(p, axis);
            let exact = geometry::camera_frame(p);
            for (d, e) in derived.iter().zip(&exact) {
                worst = worst.max((*d - *e).abs().max_element());
            }
        }
        eprintln!("derived frames off by up to {worst}");
        assert!(worst <= 1e-6, "{worst}");
        // The axis index is the one the frame was built from: x is perpendicular to it.
        for &p in &set.positions {
            let axis = geometry::camera_frame_axis(p);
            let [x, _, _] = geometry::camera_frame(p);
            assert!(x[axis].abs() <= 1e-6, "{p}: axis {axis}, x {x}");
        }
    }

    #[test]
    fn coarse_alignment_holds_where_the_rules_say() {
        // render.wgsl `coarse_position` in f32, as the shader computes it.
        let position = |p: u32, width: u32, factor: u32| -> f32 {
            let coarse = width.div_ceil(factor);
            (p as f32 + 0.5 - 0.5 * width as f32) / factor as f32 + 0.5 * coarse as f32 - 0.5
        };
        let mut conservative = 0;
        for factor in 2..=12 {
            for width in 4 * factor..=1100 {
                // Pairs (2m, 2m + 1) inside the frame whose centres lie in different cells.
                let straddling = (0..width / 2)
                    .filter(|m| 2 * m + 1 < width)
                    .filter(|m| {
                        position(2 * m, width, factor).floor()
                            != position(2 * m + 1, width, factor).floor()
                    })
                    .count();
                // How close a centre comes to a cell boundary (in cells).
                let margin = (0..width)
                    .map(|p| {
                        let c = position(p, width, factor);
                        (c - c.round()).abs()
                    })
                    .fold(f32::INFINITY, f32::min);
                if !blocks_share_coarse_cells(width, width, factor) {
                    // Exact for factors up to 4: every size refused has a straddling block or
                    // a centre on a boundary, where rounding decides its cell.
                    let qualifies = straddling == 0 && margin > 1e-3;
                    assert!(factor > 4 || !qualifies, "width {width}, factor {factor}");
                    conservative += usize::from(qualifies);
                    continue;
                }
                assert_eq!(straddling, 0, "width {width}, factor {factor}");
                // Quads: one nearest coarse pixel (`coarse_nearest`: WGSL's `round`, ties to
                // even) for all four pixels of a quad's row, each centre at least half a fine
                // pixel from the midpoint between two coarse pixels.
                assert!(quads_share_nearest_coarse(width, width, factor));
                for q in 0..width / 4 {
                    let nearest = position(4 * q, width, factor).round_ties_even();
                    for p in 4 * q..4 * q + 4 {
                        let c = position(p, width, factor);
                        assert_eq!(
                            c.round_ties_even(),
                            nearest,
                            "width {width}, factor {factor}"
                        );
                        assert!(
                            0.5 - (c - nearest).abs() >= 0.5 / factor as f32 - 1e-4,
                            "width {width}, factor {factor}, pixel {p}"
                        );
                    }
                }
                // Every centre at least half a fine pixel from a cell boundary (less 1e-4 of a
                // cell for f32 rounding): a division done as a multiplication by the reciprocal,
                // or any other rounding, cannot move a centre across one.
                assert!(
                    margin >= 0.5 / factor as f32 - 1e-4,
                    "width {width}, factor {factor}: {margin}"
                );
            }
        }
        // The rule refuses frames whose blocks would straddle a cell: a width not a multiple of
        // the factor, or a factor not a multiple of 4.
        for (width, factor) in [(510, 4), (514, 4), (512, 2), (516, 6), (518, 8)] {
            assert!(!blocks_share_coarse_cells(width, width, factor));
            let straddling = (0..width / 2).any(|m| {
                position(2 * m, width, factor).floor() != position(2 * m + 1, width, factor).floor()
            });
            assert!(straddling, "width {width}, factor {factor}");
        }
        eprintln!("sizes the rule refuses though they would do (factors 5–12): {conservative}");
        // Both axes: a frame qualifies only when both sides do.
        assert!(blocks_share_coarse_cells(512, 256, 4));
        assert!(!blocks_share_coarse_cells(512, 510, 4));
    }

    #[test]
    fn interior_blocks_meet_the_camera_sphere_within_the_bound() {
        // The rays of a 2×2 block of pixels and the ray through its centre, all passing within
        // the bounding sphere (as an interior pixel's does), from eyes near and far, outside
        // and inside the camera sphere, at several focal lengths: where each pixel's ray enters
        // the camera sphere lies within `interior_block_angle` of where the centre ray does
        // (f64).
        let mut raw = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = || (raw() >> 11) as f64 / (1u64 << 53) as f64;
        let entry = |o: glam::DVec3, d: glam::DVec3| -> Option<glam::DVec3> {
            let b = o.dot(d);
            let h = 1.0 - (o - b * d).length_squared();
            (h >= 0.0).then(|| (o + (-b - h.sqrt()) * d).normalize())
        };
        let within = |o: glam::DVec3, d: glam::DVec3| (o - o.dot(d) * d).length() <= FRAC_1_SQRT_2;
        let mut worst = 0.0f64;
        let mut checked = 0;
        for &eye in &[0.8, 1.05, 1.77, 3.0, 10.0, 100.0] {
            for &focal in &[50.0, 352.0, 703.0, 2000.0] {
                let bound = interior_block_angle(eye, focal);
                for _ in 0..400 {
                    // An eye at distance `eye`, looking at a random point of the bounding
                    // sphere: the block's centre ray; its pixels' rays half a pixel off it
                    // along two perpendicular image axes.
                    let random = |next: &mut dyn FnMut() -> f64| {
                        glam::DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize()
                    };
                    let o = random(&mut next) * eye;
                    let target = random(&mut next) * next().cbrt() * FRAC_1_SQRT_2;
                    let centre = (target - o).normalize();
                    let (right, up) = centre.any_orthonormal_pair();
                    let Some(ec) = entry(o, centre) else {
                        continue;
                    };
                    for (sx, sy) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                        let d = (centre + (right * sx + up * sy) / focal).normalize();
                        if !within(o, d) {
                            continue;
                        }
                        let Some(e) = entry(o, d) else {
                            continue;
                        };
                        let angle = e.angle_between(ec);
                        worst = worst.max(angle / bound);
                        assert!(
                            angle <= bound,
                            "eye {eye}, focal {focal}: {angle} > {bound}"
                        );
                        checked += 1;
                    }
                }
            }
        }
        eprintln!("{checked} pixels, the angle at most {worst} of the bound");
        assert!(checked > 20_000, "{checked}");
        // At 512² and 40° the blocks cover the benchmarks' eyes (2.5 bounding radii).
        let focal_512 = 256.0 / 20f64.to_radians().tan();
        assert!(interior_block_angle(2.5 * FRAC_1_SQRT_2, focal_512) <= INTERIOR_BLOCK_REACH);
    }

    #[test]
    fn interior_block_weights_stay_within_twice_the_lookups_error() {
        // A pixel of an interior block takes the weights of the triangle found for the block's
        // centre, at most INTERIOR_BLOCK_REACH away, which may itself lie up to
        // DIRECTION_LOOKUP_REACH outside the centre's triangle: the pixel lies at most the sum
        // outside the triangle it is weighed in, and its weights are off by at most that sum
        // over the triangle's height, twice (as in the lookup's own test), per level. Centres
        // at random, at the cameras and at edge midpoints; pixels at the full angle in 8
        // directions around them.
        let mut next = signed_uniform(0x5851_f42d_4c95_7f2d);
        let mut centres = random_directions(&mut next, 4000);
        centres.extend(vertices_and_edge_midpoints());
        let angle = INTERIOR_BLOCK_REACH as f32;
        let reach = (geometry::DIRECTION_LOOKUP_REACH + INTERIOR_BLOCK_REACH).sin() as f32 + 1e-5;
        for level in 0..=3u32 {
            let height = smallest_height(level);
            let bound = 2.0 * reach / height;
            let (mut worst_w, mut worst_out) = (0.0f32, f32::NEG_INFINITY);
            for &c in &centres {
                let (u, v) = c.any_orthonormal_pair();
                for k in 0..8 {
                    let a = k as f32 * std::f32::consts::FRAC_PI_4;
                    let p =
                        (c * angle.cos() + (u * a.cos() + v * a.sin()) * angle.sin()).normalize();
                    let (w, out) = lookup_error_at(c, p, level);
                    worst_w = worst_w.max(w);
                    worst_out = worst_out.max(out);
                }
            }
            eprintln!(
                "level {level}: weights off by up to {worst_w} (bound {bound}), outside by up \
                 to {worst_out} (reach {reach})"
            );
            assert!(worst_out <= reach, "level {level}: {worst_out} > {reach}");
            assert!(worst_w <= bound, "level {level}: {worst_w} > {bound}");
        }
    }
}
