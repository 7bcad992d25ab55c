//! `lumigraph_core`: the one render core behind the `lumigraph` CLI, the service and the Python
//! bindings.
//!
//! Data flow (DESIGN §1):
//!
//! ```text
//!  mesh::Mesh ──bake::bake_spherical──▶ asset::AssetFile (.lfa)  ──render::Renderer──▶ frame::Frame
//!      │                                                                                  │
//!      └──────────── reference::ReferenceRenderer (ground truth) ──▶ frame::Frame ──metrics::compare
//! ```
//!
//! - [`view::View`] is the camera every front speaks (DESIGN §3); [`frame::Frame`] is what every
//!   renderer returns: RGBA8 colour, z-depth in world units (`+inf` = no hit) and stats.
//! - [`mesh`] loads glTF/GLB, OBJ, PLY, STL, OFF into one validated [`mesh::Mesh`] and generates
//!   the built-in demo scene.
//! - [`geometry`] holds the light-field math: nested icosphere camera sets with their triangle
//!   hierarchy, parabolic maps, depth encoding.
//! - [`asset`] is the `.lfa` container (docs/format.md): a validating reader and an atomic writer.
//! - [`gpu`] owns the one headless wgpu device per process; [`bake`], [`render`] and
//!   [`reference`](mod@reference) are its pipelines, built once and reused. WGSL lives in `shaders/` and is
//!   embedded at build time ([`shaders`]).
//! - [`metrics`] implements DESIGN §3's metrics (cross-checked against scikit-image);
//!   [`tradeoff`] sweeps every quality knob and measures its cost and error.
//! - [`calibration`] measures a scene's error against cost at bake time and serves goals
//!   (target PSNR, time budget) from it.
//! - [`auto_bake`] chooses cameras, map resolution and depth bits for a target masked PSNR or
//!   byte budget from a quick low-resolution calibration, bakes that and measures it.
//! - [`lod`] chooses cameras and step from an object's projected size under a quality floor.
//! - [`refine`] accumulates jittered sub-pixel samples of a resting view into an anti-aliased
//!   still, rejecting stray samples.
//! - [`quality`] is the one quality request every front speaks (knobs, a goal or automatic LOD):
//!   it plans against an asset and renders a view, returning the frame and the decision.
//! - [`layers`] holds runtime layer opacities and the depth-ordered compositing of layers and
//!   scene objects (DESIGN §9).
//! - [`light`] holds light states: an asset baked for a proxy of light directions, relit for any
//!   direction between them (DESIGN §9).
//! - [`scene`] composites light-field instances and meshes, each with its own transform, by depth.

/// The vector types of core's public API (directions, positions), for callers without their own
/// `glam` dependency.
pub use glam;

pub mod asset;
pub mod auto_bake;
pub mod bake;
pub mod calibration;
pub mod deform;
pub mod frame;
mod fsutil;
pub mod geometry;
pub mod gpu;
pub mod image_io;
pub mod import_views;
pub mod layers;
pub mod lenslet;
pub mod light;
pub mod lod;
pub mod mesh;
pub mod metrics;
pub mod page_cache;
pub mod quality;
pub mod reference;
pub mod refine;
pub mod render;
pub mod scene;
pub mod shaders;
pub mod shading;
pub mod tradeoff;
pub mod two_plane;
pub mod two_plane_io;
pub mod two_plane_render;
pub mod view;
pub mod volume;
pub mod zstack;

pub use fsutil::{atomic_write, sync_dir, temp_target};

/// Deterministic pseudo-random numbers for unit tests: Marsaglia's xorshift64 from `state`
/// (non-zero), each call the next state.
#[cfg(test)]
pub(crate) fn xorshift(mut state: u64) -> impl FnMut() -> u64 {
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    }
}
