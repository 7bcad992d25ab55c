//! Two-plane capture on the GPU (DESIGN §9): off-axis cameras on the uv plane image exactly the
//! st texels, record the first surface beyond the camera (between the planes and beyond st
//! alike) and store `|hit − C| / |S − C|`, checked against CPU ray-plane intersections.

use std::sync::Arc;

use glam::DVec3;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::Mesh;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::shading::Shading;
use lumigraph_core::two_plane::{self, TwoPlanes};

/// Planes facing +z: uv at z = 2 (3 × 2 cameras over 1 × 0.5), st at z = 0 (32 × 16 texels over
/// 2 × 1): the separation is 2.
const PLANES: &str = r#"{"right": [1, 0, 0], "up": [0, 1, 0],
    "uv": {"center": [0, 0, 2], "size": [1, 0.5], "grid": [3, 2]},
    "st": {"center": [0, 0, 0], "size": [2, 1], "resolution": [32, 16]}}"#;

/// Stored depth of f32 z-depths divided by the separation: a few f32 ulps of depths up to 3
/// world units (the renderer writes world z-depth as f32).
const DEPTH_TOLERANCE: f64 = 1e-5;

/// Positions, triangles and vertex colours of a piece of a mesh.
type Part = (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<[f32; 4]>);

/// A quad in the plane z = `z` over `[x0, x1] × [-3, 3]`, facing +z, in one colour.
fn quad(z: f32, x0: f32, x1: f32, color: [f32; 4], first: u32) -> Part {
    (
        vec![[x0, -3.0, z], [x1, -3.0, z], [x1, 3.0, z], [x0, 3.0, z]],
        vec![[first, first + 1, first + 2], [first, first + 2, first + 3]],
        vec![color; 4],
    )
}

fn mesh(quads: &[Part]) -> Mesh {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let mut colors = Vec::new();
    for (p, t, c) in quads {
        positions.extend_from_slice(p);
        triangles.extend_from_slice(t);
        colors.extend_from_slice(c);
    }
    Mesh::from_arrays(positions, triangles, Some(colors)).expect("mesh")
}

fn unlit() -> Shading {
    Shading {
        unlit: true,
        ..Shading::default()
    }
}

/// A red half-plane between the planes (z = 0.5, x < 0) in front of a green plane beyond st
/// (z = −1): every texel's line meets the red one first where it crosses z = 0.5 at x < 0
/// (stored depth 0.75), else the green one (stored depth 1.5).
#[test]
fn capture_records_the_first_surface_beyond_the_camera_at_its_stored_depth() {
    let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
    let reference = ReferenceRenderer::new(gpu);
    let planes = TwoPlanes::from_json(PLANES).expect("planes");
    let red = [1.0, 0.0, 0.0, 1.0];
    let green = [0.0, 1.0, 0.0, 1.0];
    let scene = mesh(&[
        quad(0.5, -3.0, 0.0, red, 0),
        quad(-1.0, -3.0, 3.0, green, 4),
    ]);
    let gpu_mesh = reference.upload(&scene).expect("upload");
    let mut calls = Vec::new();
    let frames = two_plane::capture(&reference, &gpu_mesh, &planes, &unlit(), &mut |d, t| {
        calls.push((d, t));
    })
    .expect("capture");
    assert_eq!(frames.len(), 6);
    assert_eq!(calls.last(), Some(&(6, 6)));
    let mut checked = 0;
    for b in 0..2 {
        for a in 0..3 {
            let frame = &frames[(b * 3 + a) as usize];
            assert_eq!((frame.width, frame.height), (32, 16));
            let c = planes.camera(a, b);
            for i in 0..16 {
                for j in 0..32 {
                    let s = planes.st_point(i, j);
                    // Where the line crosses the red plane; skip texels whose footprint there
                    // straddles its edge at x = 0 (a texel is 1/16 wide at st, 3/4 of it there).
                    let on_red = c + 0.75 * (s - c);
                    if on_red.x.abs() < 0.06 {
                        continue;
                    }
                    let k = (i * 32 + j) as usize;
                    let depth = f64::from(frame.depth[k]);
                    let rgba = &frame.color[k * 4..k * 4 + 4];
                    // Unlit: the vertex colour times the default base colour (0.8).
                    let (want, colour) = if on_red.x < 0.0 {
                        (0.75, [204, 0, 0, 255])
                    } else {
                        (1.5, [0, 204, 0, 255])
                    };
                    assert!(
                        (depth - want).abs() < DEPTH_TOLERANCE,
                        "camera ({a}, {b}) texel ({i}, {j}): depth {depth}, want {want}"
                    );
                    assert_eq!(rgba, colour, "camera ({a}, {b}) texel ({i}, {j})");
                    // The stored depth puts the hit on the surface.
                    let hit = planes.hit(a, b, i, j, depth);
                    let z = if want < 1.0 { 0.5 } else { -1.0 };
                    assert!((hit.z - z).abs() < 1e-4, "{hit}");
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 6 * 32 * 16 * 8 / 10, "{checked} texels checked");
}

/// A plane tilted through the st plane (z = 0.8·x, from z = −0.8 to 0.8 across st): the capture
/// sees it between the planes and beyond st, and every texel's stored depth puts its hit on it;
/// an empty line (a mesh that does not cover the texel) stores +inf with zero alpha.
#[test]
fn a_surface_crossing_the_st_plane_is_captured_on_both_sides() {
    let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
    let reference = ReferenceRenderer::new(gpu);
    let planes = TwoPlanes::from_json(PLANES).expect("planes");
    // Vertices on z = 0.8·x over x ∈ [−1.2, 1.2], y ∈ [−0.4, 0.4] (narrower than st in y, so
    // rows near the top and bottom of st miss it).
    let slope = 0.8_f32;
    let corners = [[-1.2_f32, -0.4], [1.2, -0.4], [1.2, 0.4], [-1.2, 0.4]];
    let positions: Vec<[f32; 3]> = corners.iter().map(|&[x, y]| [x, y, slope * x]).collect();
    let scene = Mesh::from_arrays(positions, vec![[0, 1, 2], [0, 2, 3]], None).expect("mesh");
    let gpu_mesh = reference.upload(&scene).expect("upload");
    let frames = two_plane::capture(&reference, &gpu_mesh, &planes, &unlit(), &mut |_, _| {})
        .expect("capture");
    let normal = DVec3::new(-f64::from(slope), 0.0, 1.0).normalize();
    let (mut before, mut beyond, mut empty) = (0, 0, 0);
    for b in 0..2 {
        for a in 0..3 {
            let frame = &frames[(b * 3 + a) as usize];
            let c = planes.camera(a, b);
            for i in 0..16 {
                for j in 0..32 {
                    let k = (i * 32 + j) as usize;
                    let depth = f64::from(frame.depth[k]);
                    let s = planes.st_point(i, j);
                    // The CPU intersection of the line C + t·(S − C) with the plane through the
                    // origin: t = −(C·n) / ((S − C)·n); inside the quad with a margin of more
                    // than a texel's footprint, or outside it by as much; else skipped.
                    let t = -c.dot(normal) / (s - c).dot(normal);
                    let p = c + t * (s - c);
                    let margin = 0.1;
                    let inside = t > 0.0 && p.x.abs() < 1.2 - margin && p.y.abs() < 0.4 - margin;
                    let outside = t <= 0.0 || p.x.abs() > 1.2 + margin || p.y.abs() > 0.4 + margin;
                    if outside {
                        assert!(depth.is_infinite(), "({a},{b}) ({i},{j}): {depth}");
                        assert_eq!(frame.color[k * 4 + 3], 0);
                        empty += 1;
                    } else if inside {
                        assert!(
                            (depth - t).abs() < DEPTH_TOLERANCE,
                            "({a},{b}) ({i},{j}): {depth} vs {t}"
                        );
                        let hit = planes.hit(a, b, i, j, depth);
                        assert!(
                            hit.dot(normal).abs() < 1e-4,
                            "({a},{b}) ({i},{j}): {hit} off the plane"
                        );
                        if depth < 1.0 {
                            before += 1;
                        } else {
                            beyond += 1;
                        }
                    }
                }
            }
        }
    }
    assert!(
        before > 500 && beyond > 500 && empty > 0,
        "{before} {beyond} {empty}"
    );
}

#[test]
fn capture_refuses_invalid_planes() {
    let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
    let reference = ReferenceRenderer::new(gpu);
    let scene = mesh(&[quad(0.0, -1.0, 1.0, [1.0; 4], 0)]);
    let gpu_mesh = reference.upload(&scene).expect("upload");
    let mut planes = TwoPlanes::from_json(PLANES).expect("planes");
    planes.uv.center[2] = -2.0;
    let err = two_plane::capture(&reference, &gpu_mesh, &planes, &unlit(), &mut |_, _| {})
        .expect_err("uv behind st");
    assert!(err.to_string().contains("uv plane must lie"), "{err}");
}
