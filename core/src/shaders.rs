//! WGSL sources, embedded at build time from `shaders/`. Each pipeline's module is its file with
//! the shared code it needs prepended (WGSL has no includes).

/// The bake ray tracer (compute).
pub const BAKE: &str = concat!(
    include_str!("../../shaders/shared/mesh.wgsl"),
    include_str!("../../shaders/shared/trace.wgsl"),
    include_str!("../../shaders/bake.wgsl")
);
/// The volume ray caster of volume bakes (compute).
pub const VOLUME_BAKE: &str = include_str!("../../shaders/volume_bake.wgsl");
/// The compositing of a multi light field's layers (compute).
pub const COMPOSITE: &str = include_str!("../../shaders/composite.wgsl");
/// The two-plane light-field renderer (compute), every camera resident.
pub const TWO_PLANE: &str = concat!(
    include_str!("../../shaders/shared/two_plane.wgsl"),
    include_str!("../../shaders/two_plane.wgsl")
);
/// The two-plane light-field renderer (compute) reading pages through a cache.
pub const TWO_PLANE_PAGED: &str = concat!(
    include_str!("../../shaders/shared/two_plane.wgsl"),
    include_str!("../../shaders/two_plane_paged.wgsl")
);
/// The reference rasterizer (vertex + fragment).
pub const REFERENCE: &str = concat!(
    include_str!("../../shaders/shared/mesh.wgsl"),
    include_str!("../../shaders/shared/trace.wgsl"),
    include_str!("../../shaders/reference.wgsl")
);

/// The marcher's files, by stage, in the order `render::shader_source` joins them after the light-field
/// helpers (`shaders/shared/lightfield.wgsl`) (docs/marcher.md).
pub const RENDER_FILES: [(&str, &str); 6] = [
    ("params", include_str!("../../shaders/render/params.wgsl")),
    ("probe", include_str!("../../shaders/render/probe.wgsl")),
    ("march", include_str!("../../shaders/render/march.wgsl")),
    ("shade", include_str!("../../shaders/render/shade.wgsl")),
    ("tiles", include_str!("../../shaders/render/tiles.wgsl")),
    ("main", include_str!("../../shaders/render/main.wgsl")),
];

/// The light-field helpers the marcher's stages build on.
pub const LIGHTFIELD: &str = include_str!("../../shaders/shared/lightfield.wgsl");

/// The bake, reference and composite modules, by name and full source (validated by a CPU-only naga test;
/// the marcher's is assembled by [`crate::render::shader_source`]).
pub fn all() -> Vec<(&'static str, String)> {
    vec![
        ("bake", BAKE.to_owned()),
        ("reference", REFERENCE.to_owned()),
        ("volume_bake", VOLUME_BAKE.to_owned()),
        ("composite", COMPOSITE.to_owned()),
        ("two_plane", TWO_PLANE.to_owned()),
        ("two_plane_paged", TWO_PLANE_PAGED.to_owned()),
    ]
}
