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
/// The light-field marcher (compute).
pub const RENDER: &str = concat!(
    include_str!("../../shaders/shared/lightfield.wgsl"),
    include_str!("../../shaders/render.wgsl")
);

/// Every pipeline module, by name (validated by a CPU-only naga test).
pub const ALL: [(&str, &str); 3] = [("bake", BAKE), ("reference", REFERENCE), ("render", RENDER)];
