//! WGSL sources, embedded at build time from `shaders/`. Each pipeline's module is its file with
//! the shared code it needs prepended (WGSL has no includes).

/// Mesh layout and shading shared by baking and the reference rasterizer.
pub const MESH_SHARED: &str = include_str!("../../shaders/shared/mesh.wgsl");
/// Light-field sampling helpers shared by the marchers.
pub const LIGHTFIELD_SHARED: &str = include_str!("../../shaders/shared/lightfield.wgsl");

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
/// The light-field marcher (compute), without its generated constants (see [`render_source`]).
pub const RENDER: &str = concat!(
    include_str!("../../shaders/shared/lightfield.wgsl"),
    include_str!("../../shaders/render.wgsl")
);

/// The marcher's full source: [`RENDER`] plus constants from [`crate::geometry`] (the camera
/// set's sizes, for the uniform arrays, and the direction lookup's), and `count_work`, which adds
/// an invocation's work to the frame's counters: with `subgroups` (the device has
/// `wgpu::Features::SUBGROUP`), summed over the subgroup first, one atomic add per subgroup
/// instead of one per invocation (on lavapipe, invocations on both cores adding to the same
/// counters cost about 0.6 ms of an 18 ms 512² frame).
pub fn render_source(subgroups: bool) -> String {
    use crate::geometry::{DIRECTION_LOOKUP_SIZE, MAX_LEVEL};
    let set = crate::geometry::camera_set();
    let mut out = format!(
        "const CAMERA_COUNT: u32 = {}u;\nconst TRIANGLE_COUNT: u32 = {}u;\n\
         const MAX_LEVEL: u32 = {MAX_LEVEL}u;\nconst DIRECTION_LOOKUP_SIZE: u32 = {DIRECTION_LOOKUP_SIZE}u;\n",
        set.positions.len(),
        set.triangles.len()
    );
    out.push_str(if subgroups {
        COUNT_WORK_SUBGROUPS
    } else {
        COUNT_WORK_ATOMICS
    });
    out.push_str(RENDER);
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
