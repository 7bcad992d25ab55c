//! WGSL sources, embedded at build time from `shaders/`. Each pipeline's module is its file with
//! the shared code it needs prepended (WGSL has no includes).

/// The bake ray tracer (compute).
pub const BAKE: &str = concat!(
    include_str!("../../shaders/shared/mesh.wgsl"),
    include_str!("../../shaders/bake.wgsl")
);
/// The reference rasterizer (vertex + fragment).
pub const REFERENCE: &str = concat!(
    include_str!("../../shaders/shared/mesh.wgsl"),
    include_str!("../../shaders/reference.wgsl")
);

/// The marcher's files, by stage, in the order [`render_source`] joins them after the light-field
/// helpers (`shaders/shared/lightfield.wgsl`) (docs/marcher.md).
pub const RENDER_FILES: [(&str, &str); 6] = [
    ("params", include_str!("../../shaders/render/params.wgsl")),
    ("probe", include_str!("../../shaders/render/probe.wgsl")),
    ("march", include_str!("../../shaders/render/march.wgsl")),
    ("shade", include_str!("../../shaders/render/shade.wgsl")),
    ("tiles", include_str!("../../shaders/render/tiles.wgsl")),
    ("main", include_str!("../../shaders/render/main.wgsl")),
];

/// The marcher's full source: a generated preamble, then the light-field helpers and
/// [`RENDER_FILES`]. The preamble holds the
/// camera set's sizes (for the uniform arrays) and the direction lookup's from
/// [`crate::geometry`], the constants Rust and WGSL share from [`crate::render`] (edge codes,
/// bounding radius, method, role and tiling codes), and `count_work`, which adds an
/// invocation's work to the frame's counters: with `subgroups` (the device has
/// `wgpu::Features::SUBGROUP`), summed over the subgroup first, one atomic add per subgroup
/// instead of one per invocation on both cores.
pub fn render_source(subgroups: bool) -> String {
    use crate::geometry::{DIRECTION_LOOKUP_SIZE, MAX_LEVEL};
    let set = crate::geometry::camera_set();
    let mut out = format!(
        "const CAMERA_COUNT: u32 = {}u;\nconst TRIANGLE_COUNT: u32 = {}u;\n\
         const MAX_LEVEL: u32 = {MAX_LEVEL}u;\nconst DIRECTION_LOOKUP_SIZE: u32 = {DIRECTION_LOOKUP_SIZE}u;\n",
        set.positions.len(),
        set.triangles.len()
    );
    out.push_str(&crate::render::wgsl_constants());
    out.push_str(if subgroups {
        COUNT_WORK_SUBGROUPS
    } else {
        COUNT_WORK_ATOMICS
    });
    out.push_str(include_str!("../../shaders/shared/lightfield.wgsl"));
    for (_, source) in RENDER_FILES {
        out.push_str(source);
    }
    out
}

/// [`render_source`]'s `count_work` with subgroup operations.
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

/// [`render_source`]'s `count_work` without them.
const COUNT_WORK_ATOMICS: &str = "fn count_work(fetches: u32, steps: u32, rays: u32) {
    atomicAdd(&counters[0], fetches);
    atomicAdd(&counters[1], steps);
    atomicAdd(&counters[2], rays);
}
";

/// Every pipeline module, by name and full source (validated by a CPU-only naga test).
pub fn all() -> Vec<(&'static str, String)> {
    vec![
        ("bake", BAKE.to_owned()),
        ("reference", REFERENCE.to_owned()),
        ("render", render_source(false)),
        ("render (subgroups)", render_source(true)),
    ]
}
