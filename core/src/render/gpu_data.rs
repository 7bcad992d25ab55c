//! The GPU mirror of a render's parameters (`RenderParams`, shaders/render/params.wgsl) and the
//! tuning constants the marcher takes through it.

use super::options::{Method, ResolvedOptions};

/// Bisection iterations of the default method (then a secant step in the last bracket): three
/// beat five on every fixture, as the continuity test then judges a wider final bracket, which
/// rejects fewer true surfaces beside a silhouette; one is too few (docs/marcher.md).
pub(super) const REFINE_ITERATIONS: u32 = 3;
/// Depth gap (in normalized map depth) above which a 2×2 footprint is split into layers.
pub(super) const EDGE_GAP: f32 = 0.05;
/// Bilinear weight the front layer of a split footprint needs to be chosen. Above 0.5 because a
/// pixel is covered when any of its three cameras finds a crossing: the union of three
/// half-texel-accurate silhouettes is biased outwards, and a front layer that must hold 60 % of
/// the weight cancels that bias (docs/marcher.md).
pub(super) const FRONT_MASS: f32 = 0.6;

/// The parameters of one pass, as shaders/render/params.wgsl declares them (a naga test checks
/// every member's offset: [`render_params_layout`]).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct RenderParams {
    pub(super) eye: [f32; 3],
    pub(super) width: u32,
    pub(super) right: [f32; 3],
    pub(super) height: u32,
    pub(super) up: [f32; 3],
    pub(super) focal_px: f32,
    pub(super) forward: [f32; 3],
    pub(super) level: u32,
    pub(super) step: f32,
    pub(super) tolerance: f32,
    pub(super) max_steps: u32,
    pub(super) method: u32,
    pub(super) resolution: f32,
    pub(super) depth_scale: f32,
    pub(super) edge_gap: f32,
    pub(super) refine_iterations: u32,
    pub(super) front_mass: f32,
    pub(super) blend: f32,
    pub(super) coarse_factor: u32,
    pub(super) near_scale: f32,
    pub(super) box_min: [f32; 3],
    pub(super) tiled: u32,
    pub(super) box_max: [f32; 3],
    pub(super) interior_curvature: f32,
    pub(super) level_b: u32,
    pub(super) step_b: f32,
    pub(super) tolerance_b: f32,
    pub(super) max_steps_b: u32,
    pub(super) method_b: u32,
    pub(super) coarse_width: u32,
    pub(super) coarse_height: u32,
    pub(super) row_stride: u32,
    pub(super) interior_group_quads: u32,
    pub(super) guide_step_ratio: f32,
    /// Sub-pixel offset of every sample, in this pass's pixels (x right, y down).
    pub(super) jitter: [f32; 2],
    /// 1 for a translucent light field (premultiplied RGBA maps): the output keeps the blended
    /// alpha; 0: every hit is opaque.
    pub(super) premultiplied: u32,
    /// 1: relit from the light states with `light_weights`; 0: the base colour.
    pub(super) lit: u32,
    /// 1: a shadow ray decides where the proxy lights disagree on a relit texel's shadow
    /// (an asset baked with shadows and normals).
    pub(super) shadow_rays: u32,
    pub(super) pad2: u32,
    /// Weights of the three proxy lights' direct parts; w 1: scaled by the stored normal's
    /// cosine ratio (`Blend::Normal`), 0: as they are.
    pub(super) light_weights: [f32; 4],
    /// The frame's light (unit, asset frame; w unused).
    pub(super) light_dir: [f32; 4],
    /// The three proxy lights' directions (unit, asset frame; w unused).
    pub(super) light_a: [f32; 4],
    pub(super) light_b: [f32; 4],
    pub(super) light_c: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<RenderParams>() == 288);

/// One setting as the shader takes it: level, step and tolerance in light-field units,
/// step bound, method.
pub(super) struct ShaderSetting {
    pub(super) level: u32,
    pub(super) step: f32,
    pub(super) tolerance: f32,
    pub(super) max_steps: u32,
    pub(super) method: Method,
}

/// The bounding sphere's diameter in light-field units (radius `1/√2`, the camera sphere's 1):
/// what steps and tolerances are fractions of.
pub(super) const BOUNDING_DIAMETER: f32 = std::f32::consts::SQRT_2;

/// The march's step limit for `step` (light-field units): the bounding sphere's diameter in
/// steps, plus two.
pub(super) fn max_steps_for(step: f32) -> u32 {
    (BOUNDING_DIAMETER / step).ceil() as u32 + 2
}

impl ShaderSetting {
    pub(super) fn of(resolved: &ResolvedOptions) -> Self {
        let step = resolved.step * BOUNDING_DIAMETER;
        ShaderSetting {
            level: resolved.level,
            step,
            tolerance: resolved.tolerance * BOUNDING_DIAMETER,
            max_steps: max_steps_for(step),
            method: resolved.method,
        }
    }
}

/// The bounding sphere's radius in light-field units.
const BOUNDING_RADIUS: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// A setting's method as `RenderParams.method` holds it (WGSL `METHOD_*`).
pub(super) const fn method_code(method: Method) -> u32 {
    match method {
        Method::Fixed => 0,
        Method::Default => 1,
    }
}

/// The marching methods a pipeline serves (WGSL override `METHODS`, codes `METHODS_*`): lavapipe
/// runs every branch, so a pass holds only the code its pixels can take (docs/marcher.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum MethodSet {
    /// The fixed baseline only.
    Fixed = 1,
    /// The default marcher only.
    Default = 2,
    /// Both, chosen per pixel (a blend between a fixed and a default setting).
    Both = 3,
}

impl MethodSet {
    pub(super) const ALL: [MethodSet; 3] = [MethodSet::Fixed, MethodSet::Default, MethodSet::Both];

    /// The set serving pixels of settings `a` and `b`.
    pub(super) fn of(a: Method, b: Method) -> MethodSet {
        match (a, b) {
            (Method::Fixed, Method::Fixed) => MethodSet::Fixed,
            (Method::Default, Method::Default) => MethodSet::Default,
            _ => MethodSet::Both,
        }
    }

    /// The WGSL code.
    pub(super) const fn code(self) -> u32 {
        self as u32
    }
}

/// What a marcher pass does (WGSL override `ROLE`, codes `ROLE_*`; docs/marcher.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    /// Not guided, guiding nothing.
    Plain = 0,
    /// A full-resolution marching pass of a guided frame: the guided pass, and the pass over
    /// the quads the interior pass gave back.
    Guided = 1,
    /// The interior pass over the flat quads `cs_tiles` lists, one pixel per invocation.
    Interior = 2,
    /// The coarse passes of a guided frame (pre-coarse and coarse), which need no shading.
    Coarse = 3,
    /// The interior pass shading a 2×2 block of pixels per invocation
    /// ([`super::guide::INTERIOR_BLOCK_REACH`]).
    InteriorBlocks = 4,
}

impl Role {
    pub(super) const ALL: [Role; 5] = [
        Role::Plain,
        Role::Guided,
        Role::Interior,
        Role::Coarse,
        Role::InteriorBlocks,
    ];

    /// The WGSL code.
    pub(super) const fn code(self) -> u32 {
        self as u32
    }
}

/// Which quads a pass renders (`RenderParams.tiled`, WGSL `TILED_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Tiling {
    /// Its whole 8×8 tile grid.
    Grid = 0,
    /// The quads `cs_tiles` listed to march.
    Listed = 1,
    /// The flat quads the interior pass gave back.
    GivenBack = 2,
}

impl Tiling {
    const ALL: [Tiling; 3] = [Tiling::Grid, Tiling::Listed, Tiling::GivenBack];

    /// The WGSL code.
    pub(super) const fn code(self) -> u32 {
        self as u32
    }
}

/// The WGSL constants the marcher shares with this module, for the generated preamble
/// ([`shader_source`]): written once, here.
pub(crate) fn wgsl_constants() -> String {
    use super::targets::{COUNTER_WORDS, TILE_DISPATCH_WORDS, TILE_LIST_LENGTHS};
    use super::upload::{EDGE_BASE, EDGE_CODES, EDGE_DEPTH_LEVELS, EDGE_E_LEVELS, edge_depth_step};
    use std::fmt::Write;
    // An f32 as a literal WGSL reads back to the same value (its exact f64 expansion).
    let float = |x: f32| format!("{:?}", f64::from(x));
    let mut out = String::new();
    let mut line = |name: &str, ty: &str, value: String| {
        let _ = writeln!(out, "const {name}: {ty} = {value};");
    };
    line("EDGE_BASE", "u32", format!("{EDGE_BASE}u"));
    line("EDGE_CODES", "u32", format!("{EDGE_CODES}u"));
    line("EDGE_E_LEVELS", "u32", format!("{EDGE_E_LEVELS}u"));
    line("EDGE_DEPTH_LEVELS", "u32", format!("{EDGE_DEPTH_LEVELS}u"));
    line(
        "EDGE_DEPTH_BITS",
        "u32",
        format!("{}u", EDGE_DEPTH_LEVELS.trailing_zeros()),
    );
    line("EDGE_DEPTH_STEP", "f32", float(edge_depth_step()));
    line("BOUNDING_RADIUS", "f32", float(BOUNDING_RADIUS));
    line(
        "TILE_DISPATCH_WORDS",
        "u32",
        format!("{TILE_DISPATCH_WORDS}u"),
    );
    line("TILE_LIST_LENGTHS", "u32", format!("{TILE_LIST_LENGTHS}u"));
    line("COUNTER_WORDS", "u32", format!("{COUNTER_WORDS}u"));
    for method in [Method::Fixed, Method::Default] {
        let name = format!("METHOD_{}", method.to_string().to_uppercase());
        line(&name, "u32", format!("{}u", method_code(method)));
    }
    for set in MethodSet::ALL {
        let name = format!("METHODS_{}", format!("{set:?}").to_uppercase());
        line(&name, "u32", format!("{}u", set.code()));
    }
    for role in Role::ALL {
        line(
            &format!("ROLE_{}", screaming(&format!("{role:?}"))),
            "u32",
            format!("{}u", role.code()),
        );
    }
    for tiling in Tiling::ALL {
        line(
            &format!("TILED_{}", screaming(&format!("{tiling:?}"))),
            "u32",
            format!("{}u", tiling.code()),
        );
    }
    out
}

/// `CamelCase` as `SCREAMING_SNAKE_CASE`.
fn screaming(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

/// `RenderParams`' members, by name, with their byte offsets: what the WGSL struct of the same
/// name must match (checked with naga by a test).
#[doc(hidden)]
pub fn render_params_layout() -> Vec<(&'static str, usize)> {
    use std::mem::offset_of;
    macro_rules! members {
        ($($field:ident),* $(,)?) => {{
            // Every member listed: the pattern is exhaustive.
            let _ = |params: RenderParams| {
                let RenderParams { $($field: _),* } = params;
            };
            vec![$((stringify!($field), offset_of!(RenderParams, $field))),*]
        }};
    }
    members![
        eye,
        width,
        right,
        height,
        up,
        focal_px,
        forward,
        level,
        step,
        tolerance,
        max_steps,
        method,
        resolution,
        depth_scale,
        edge_gap,
        refine_iterations,
        front_mass,
        blend,
        coarse_factor,
        near_scale,
        box_min,
        tiled,
        box_max,
        interior_curvature,
        level_b,
        step_b,
        tolerance_b,
        max_steps_b,
        method_b,
        coarse_width,
        coarse_height,
        row_stride,
        interior_group_quads,
        guide_step_ratio,
        jitter,
        premultiplied,
        lit,
        shadow_rays,
        pad2,
        light_weights,
        light_dir,
        light_a,
        light_b,
        light_c,
    ]
}

/// The marcher's full source: a generated preamble, then the light-field helpers and
/// [`crate::shaders::RENDER_FILES`]. The preamble holds the
/// camera set's sizes (for the uniform arrays) and the direction lookup's from
/// [`crate::geometry`], the constants Rust and WGSL share from this module (edge codes,
/// bounding radius, method, role and tiling codes), and `count_work`, which adds an
/// invocation's work to the frame's counters: with `subgroups` (the device has
/// `wgpu::Features::SUBGROUP`), summed over the subgroup first, one atomic add per subgroup
/// instead of one per invocation on both cores.
pub fn shader_source(subgroups: bool) -> String {
    use crate::geometry::{DIRECTION_LOOKUP_SIZE, MAX_LEVEL};
    let set = crate::geometry::camera_set();
    let mut out = format!(
        "const CAMERA_COUNT: u32 = {}u;\nconst TRIANGLE_COUNT: u32 = {}u;\n\
         const MAX_LEVEL: u32 = {MAX_LEVEL}u;\nconst DIRECTION_LOOKUP_SIZE: u32 = {DIRECTION_LOOKUP_SIZE}u;\n",
        set.positions.len(),
        set.triangles.len()
    );
    out.push_str(&wgsl_constants());
    out.push_str(if subgroups {
        COUNT_WORK_SUBGROUPS
    } else {
        COUNT_WORK_ATOMICS
    });
    out.push_str(crate::shaders::LIGHTFIELD);
    for (_, source) in crate::shaders::RENDER_FILES {
        out.push_str(source);
    }
    out
}

/// [`shader_source`]'s `count_work` with subgroup operations.
const COUNT_WORK_SUBGROUPS: &str = "fn count_work(fetches: u32, steps: u32, rays: u32) {
    let f = subgroupAdd(fetches);
    let s = subgroupAdd(steps);
    let r = subgroupAdd(rays);
    if subgroupExclusiveAdd(1u) == 0u {
        atomicAdd(&counters[0], f);
        atomicAdd(&counters[1], s);
        atomicAdd(&counters[2], r);
    }
}
";

/// [`shader_source`]'s `count_work` without them.
const COUNT_WORK_ATOMICS: &str = "fn count_work(fetches: u32, steps: u32, rays: u32) {
    atomicAdd(&counters[0], fetches);
    atomicAdd(&counters[1], steps);
    atomicAdd(&counters[2], rays);
}
";
