//! The built-in demo scene: a trefoil-knot tube, generated in code.
//!
//! Chosen because it is what light fields find hard: non-convex, it occludes itself from every
//! side (silhouettes cross the object, so depth edges fall inside the image, not just at its
//! rim), and it is coloured twice over: a hue ramp in the vertex colours along the knot times a
//! checker texture around and along the tube, so resampling errors show up in colour metrics.

use std::f64::consts::TAU;

use glam::DVec3;

use super::{Material, Mesh, MeshError, Texture};
use crate::asset::Provenance;

/// Source name in the provenance of assets baked from the demo.
pub const DEMO_SOURCE_NAME: &str = "demo:trefoil";

/// Segments along the knot.
const SEGMENTS_ALONG: u32 = 360;
/// Segments around the tube.
const SEGMENTS_AROUND: u32 = 24;
/// Tube radius (the knot's centre line spans about ±3 units).
const TUBE_RADIUS: f64 = 0.55;
/// Checker texture size (width × height) and cell count.
const TEXTURE_W: u32 = 512;
const TEXTURE_H: u32 = 64;
const CHECKS_ALONG: u32 = 48;
const CHECKS_AROUND: u32 = 6;

/// Centre line of the trefoil knot at parameter `t` in `[0, 2π)`.
fn knot(t: f64) -> DVec3 {
    DVec3::new(
        t.sin() + 2.0 * (2.0 * t).sin(),
        t.cos() - 2.0 * (2.0 * t).cos(),
        -(3.0 * t).sin(),
    )
}

/// Unit tangent of the centre line (analytic derivative).
fn knot_tangent(t: f64) -> DVec3 {
    DVec3::new(
        t.cos() + 4.0 * (2.0 * t).cos(),
        -t.sin() + 4.0 * (2.0 * t).sin(),
        -3.0 * (3.0 * t).cos(),
    )
    .normalize()
}

/// A smooth, periodic frame around the centre line: the position vector with its tangential
/// part removed is never parallel to the tangent for this knot (|p|² = 5 − 4 cos 3t ≥ 1), so the
/// frame has no seam and needs no parallel transport.
fn knot_frame(t: f64) -> (DVec3, DVec3, DVec3) {
    let tangent = knot_tangent(t);
    let p = knot(t);
    let normal = (p - tangent * p.dot(tangent)).normalize();
    let binormal = tangent.cross(normal);
    (tangent, normal, binormal)
}

/// Hue ramp in [0,1] RGB.
fn hue(h: f64) -> [f32; 4] {
    let h6 = (h.rem_euclid(1.0)) * 6.0;
    let x = 1.0 - (h6 % 2.0 - 1.0).abs();
    let (r, g, b) = match h6 as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    // Lift towards white so no channel is black (keeps shading visible in every channel).
    let lift = |c: f64| (0.35 + 0.65 * c) as f32;
    [lift(r), lift(g), lift(b), 1.0]
}

fn checker_texture() -> Texture {
    let mut rgba8 = Vec::with_capacity((TEXTURE_W * TEXTURE_H * 4) as usize);
    for y in 0..TEXTURE_H {
        for x in 0..TEXTURE_W {
            let cx = x * CHECKS_ALONG / TEXTURE_W;
            let cy = y * CHECKS_AROUND / TEXTURE_H;
            let value = if (cx + cy).is_multiple_of(2) {
                255
            } else {
                140
            };
            rgba8.extend_from_slice(&[value, value, value, 255]);
        }
    }
    Texture {
        width: TEXTURE_W,
        height: TEXTURE_H,
        rgba8,
    }
}

/// The demo mesh: a trefoil-knot tube of 17,280 triangles, about 7 × 6.5 × 2.7 units.
///
/// # Errors
/// Never in practice; the generated mesh goes through [`Mesh::finish`] like every input.
pub fn demo_mesh() -> Result<Mesh, MeshError> {
    let ring = SEGMENTS_AROUND + 1;
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut colors = Vec::new();
    for i in 0..=SEGMENTS_ALONG {
        let s = f64::from(i) / f64::from(SEGMENTS_ALONG);
        let t = s * TAU;
        let centre = knot(t);
        let (_, normal, binormal) = knot_frame(t);
        let color = hue(s * 3.0);
        for j in 0..=SEGMENTS_AROUND {
            let a = f64::from(j) / f64::from(SEGMENTS_AROUND) * TAU;
            let radial = normal * a.cos() + binormal * a.sin();
            let p = centre + radial * TUBE_RADIUS;
            positions.push(p.as_vec3().to_array());
            normals.push(radial.as_vec3().to_array());
            uvs.push([s as f32, f64::from(j) as f32 / SEGMENTS_AROUND as f32]);
            colors.push(color);
        }
    }
    let mut triangles = Vec::new();
    for i in 0..SEGMENTS_ALONG {
        for j in 0..SEGMENTS_AROUND {
            let a = i * ring + j;
            let b = (i + 1) * ring + j;
            // The around direction (normal → binormal = tangent × normal) crossed with the along
            // direction (tangent) is the outward radial, so (a, a+1, b+1) is counter-clockwise
            // seen from outside (checked by a test).
            triangles.push([a, a + 1, b + 1]);
            triangles.push([a, b + 1, b]);
        }
    }
    let triangle_materials = vec![0; triangles.len()];
    Mesh {
        positions,
        normals,
        uvs: Some(uvs),
        colors: Some(colors),
        triangles,
        triangle_materials,
        materials: vec![Material {
            base_color_factor: [1.0; 4],
            base_color_texture: Some(0),
        }],
        textures: vec![checker_texture()],
    }
    .finish()
}

/// The provenance of an asset baked from `demo`, the mesh [`demo_mesh`] returns: source
/// [`DEMO_SOURCE_NAME`] and the SHA-256 of its geometry, so every front records the demo alike.
pub fn demo_provenance(demo: &Mesh) -> Provenance {
    Provenance {
        source_name: DEMO_SOURCE_NAME.to_owned(),
        source_sha256: demo.geometry_sha256(),
        ..Provenance::default()
    }
}
