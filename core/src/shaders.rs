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

/// The marcher's full source: [`RENDER`] plus `locate_level0`, an unrolled test of the 20
/// level-0 icosphere triangles against their unit edge normals as literals (generated from
/// [`crate::geometry::camera_set`], so GPU lookup and CPU geometry cannot disagree; a constant
/// array indexed in a loop is copied per access by some drivers, which cost lavapipe 6×), and
/// `count_work`, which adds an invocation's work to the frame's counters: with `subgroups`
/// (the device has `wgpu::Features::SUBGROUP`), summed over the subgroup first, one atomic add
/// per subgroup instead of one per invocation (on lavapipe, invocations on both cores adding
/// to the same counters cost about 0.6 ms of an 18 ms 512² frame).
pub fn render_source(subgroups: bool) -> String {
    use std::fmt::Write;
    let set = crate::geometry::camera_set();
    // Uniform arrays need constant sizes: the camera set's.
    let split_count = set.level_range(2).end * 3;
    let mut out = format!(
        "const CAMERA_COUNT: u32 = {}u;\nconst TRIANGLE_COUNT: u32 = {}u;\nconst SPLIT_COUNT: u32 = {split_count}u;\n",
        set.positions.len(),
        set.triangles.len()
    );
    out.push_str(
        "fn locate_level0(p: vec3<f32>) -> u32 {\n    var best = 0u;\n    var best_score = -1e30;\n    var s: f32;\n",
    );
    for (index, t) in set.level_triangles(0).iter().enumerate() {
        let [a, b, c] = t.v.map(|i| set.positions[i as usize].as_dvec3());
        let dots: Vec<String> = [(a, b), (b, c), (c, a)]
            .iter()
            .map(|(p, q)| {
                let n = p.cross(*q).normalize();
                format!("dot(vec3<f32>({:e}, {:e}, {:e}), p)", n.x, n.y, n.z)
            })
            .collect();
        let _ = writeln!(
            out,
            "    s = min(min({}, {}), {});\n    if s > best_score {{ best_score = s; best = {index}u; }}",
            dots[0], dots[1], dots[2]
        );
    }
    out.push_str("    return best;\n}\n");
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
