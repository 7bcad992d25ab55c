//! Mesh loading through the public API: one generated file per format, every error class,
//! robustness against truncated, garbage and mutated input, the bounding sphere, and the real
//! dev fixtures (bunny, cow, spot).
//!
//! Tolerances: positions and colours that are exact in the file are compared with 1e-6
//! (f32 rounding of values like 0.5 or 1/255 multiples); computed unit normals with 1e-6 (f32
//! rounding of an f64-normalized vector).

mod common;

use std::fmt::Write as _;
use std::io::Cursor;
use std::path::Path;
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use lumigraph_core::mesh::{
    DEFAULT_BASE_COLOR, MAX_TEXTURE_PX, Material, Mesh, MeshError, MeshFormat, Texture, load_mesh,
    load_mesh_from_bytes,
};
use proptest::prelude::*;
use serde_json::json;

const EPS: f32 = 1e-6;

// ---------------------------------------------------------------------------------------------
// Helpers

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> std::path::PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write test file");
    path
}

fn assert_close<const N: usize>(got: [f32; N], expected: [f32; N], what: &str) {
    for (g, e) in got.iter().zip(expected) {
        assert!(
            (g - e).abs() <= EPS,
            "{what}: got {got:?}, expected {expected:?}"
        );
    }
}

/// The vertex at `position` (exact match), to check attributes without relying on order.
fn vertex_at(mesh: &Mesh, position: [f32; 3]) -> usize {
    mesh.positions
        .iter()
        .position(|p| p.iter().zip(position).all(|(a, b)| (a - b).abs() <= EPS))
        .unwrap_or_else(|| panic!("no vertex at {position:?} in {:?}", mesh.positions))
}

/// A PNG whose pixel (x, y) is (40x + 1, 60y + 2, 7, 255 - x): distinct, exact bytes.
fn png_bytes(width: u32, height: u32) -> Vec<u8> {
    let image = image::RgbaImage::from_fn(width, height, |x, y| {
        image::Rgba([(40 * x + 1) as u8, (60 * y + 2) as u8, 7, (255 - x) as u8])
    });
    let mut out = Cursor::new(Vec::new());
    image
        .write_to(&mut out, image::ImageFormat::Png)
        .expect("encode PNG");
    out.into_inner()
}

fn expected_png_pixels(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::new();
    for y in 0..height {
        for x in 0..width {
            out.extend([(40 * x + 1) as u8, (60 * y + 2) as u8, 7, (255 - x) as u8]);
        }
    }
    out
}

/// Appends little-endian f32s.
fn put_le(out: &mut Vec<u8>, values: &[f32]) {
    for v in values {
        out.extend(v.to_le_bytes());
    }
}

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Regular tetrahedron, outward winding; the expected normal at each vertex is its direction.
fn tetrahedron() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let positions = vec![
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ];
    let mut triangles = vec![[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]];
    for tri in &mut triangles {
        let p = |i: u32| Vec3::from(positions[i as usize]);
        let n = (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0]));
        if n.dot(p(tri[0])) < 0.0 {
            tri.swap(1, 2);
        }
    }
    (positions, triangles)
}

/// Unit cube [0,1]^3 as 12 outward triangles over 8 corners.
fn cube() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let positions: Vec<[f32; 3]> = (0..8)
        .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut triangles = Vec::new();
    for q in quads {
        for tri in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
            let p = |i: u32| Vec3::from(positions[i as usize]);
            let n = (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0]));
            let outward = n.dot(p(tri[0]) - Vec3::splat(0.5)) > 0.0;
            triangles.push(if outward {
                tri
            } else {
                [tri[0], tri[2], tri[1]]
            });
        }
    }
    (positions, triangles)
}

fn assert_outward_unit_normals(mesh: &Mesh, center: [f32; 3]) {
    for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
        let n = Vec3::from(*n);
        assert!((n.length() - 1.0).abs() < EPS, "normal {n} not unit");
        assert!(
            n.dot(Vec3::from(*p) - Vec3::from(center)) > 0.0,
            "normal {n} at {p:?} points inward"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Format detection

#[test]
fn format_from_path_and_extension() {
    assert_eq!(
        MeshFormat::from_path(Path::new("a/b.GLTF")).unwrap(),
        MeshFormat::Gltf
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("x.glb")).unwrap(),
        MeshFormat::Glb
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("x.Obj")).unwrap(),
        MeshFormat::Obj
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("x.ply")).unwrap(),
        MeshFormat::Ply
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("x.STL")).unwrap(),
        MeshFormat::Stl
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("x.off")).unwrap(),
        MeshFormat::Off
    );
    assert_eq!(MeshFormat::from_extension(".ply"), Some(MeshFormat::Ply));
    assert_eq!(MeshFormat::from_extension("fbx"), None);
    assert!(matches!(
        MeshFormat::from_path(Path::new("x.fbx")),
        Err(MeshError::UnknownFormat(_))
    ));
    assert!(matches!(
        MeshFormat::from_path(Path::new("noext")),
        Err(MeshError::UnknownFormat(_))
    ));
    assert!(matches!(
        load_mesh(Path::new("model.xyz")),
        Err(MeshError::UnknownFormat(_))
    ));
}

#[test]
fn missing_file_is_io_error() {
    let err = load_mesh(Path::new("/nonexistent/lumigraph/mesh.off")).unwrap_err();
    assert!(matches!(err, MeshError::Io { .. }), "{err}");
    assert!(err.to_string().contains("/nonexistent/lumigraph/mesh.off"));
}

// ---------------------------------------------------------------------------------------------
// glTF / GLB

/// Geometry of the test quad: 4 vertices in z = 0, CCW seen from +z, normals +z, UVs, RGBA8
/// colours, two triangles (u16 indices). Returns the buffer bytes.
fn quad_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for p in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ] {
        put_le(&mut b, &p);
    }
    for _ in 0..4 {
        put_le(&mut b, &[0.0, 0.0, 1.0]);
    }
    for uv in [[0.0f32, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]] {
        put_le(&mut b, &uv);
    }
    b.extend([
        255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 51,
    ]);
    for i in [0u16, 1, 2, 0, 2, 3] {
        b.extend(i.to_le_bytes());
    }
    assert_eq!(b.len(), 156);
    b
}

/// glTF JSON for the quad (three primitives: textured, no material, lines) under `nodes`;
/// `buffer` and `image` are the buffer and image objects. Buffer view 5 covers `png_len` bytes
/// after the geometry, where GLB tests put the PNG (unused otherwise).
fn quad_gltf(
    buffer: &serde_json::Value,
    image: &serde_json::Value,
    png_len: usize,
    nodes: &serde_json::Value,
) -> serde_json::Value {
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2, "COLOR_0": 3}, "indices": 4, "material": 0},
            {"attributes": {"POSITION": 0}, "indices": 4},
            {"attributes": {"POSITION": 0}, "indices": 4, "mode": 1}
        ]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 0.75], "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}],
        "images": [image],
        "buffers": [buffer],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 32},
            {"buffer": 0, "byteOffset": 128, "byteLength": 16},
            {"buffer": 0, "byteOffset": 144, "byteLength": 12},
            {"buffer": 0, "byteOffset": 156, "byteLength": png_len.max(1)}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5121, "normalized": true, "count": 4, "type": "VEC4"},
            {"bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ]
    })
}

/// Parent translates by (1,2,3); child rotates 90° about x and scales by 2, and holds the mesh.
fn transformed_nodes() -> serde_json::Value {
    let h = std::f32::consts::FRAC_1_SQRT_2;
    json!([
        {"translation": [1.0, 2.0, 3.0], "children": [1]},
        {"rotation": [h, 0.0, 0.0, h], "scale": [2.0, 2.0, 2.0], "mesh": 0}
    ])
}

fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut json_bytes = serde_json::to_vec(json).unwrap();
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((json_bytes.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(json_bytes);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out
}

/// Checks the loaded transformed quad: two primitives (textured + default material), the
/// line primitive skipped.
fn check_transformed_quad(mesh: &Mesh) {
    // Primitive 0 and 1 each contribute the 4 vertices and 2 triangles; mode 1 (lines) is skipped.
    assert_eq!(mesh.vertex_count(), 8);
    assert_eq!(mesh.triangle_count(), 4);
    // world = T(1,2,3) · Rx(90°) · S(2): (x, y, 0) -> (1 + 2x, 2, 3 + 2y).
    for (i, expected) in [
        [1.0, 2.0, 3.0],
        [3.0, 2.0, 3.0],
        [3.0, 2.0, 5.0],
        [1.0, 2.0, 5.0],
    ]
    .into_iter()
    .enumerate()
    {
        assert_close(mesh.positions[i], expected, "transformed position");
        assert_close(
            mesh.positions[i + 4],
            expected,
            "transformed position (second primitive)",
        );
    }
    // The normal +z rotates to -y.
    for n in &mesh.normals {
        assert_close(*n, [0.0, -1.0, 0.0], "normal");
    }
    let uvs = mesh.uvs.as_ref().expect("uvs");
    assert_close(uvs[1], [1.0, 0.0], "uv 1 (glTF convention kept)");
    assert_close(uvs[5], [0.0, 0.0], "uv of a primitive without UVs");
    let colors = mesh.colors.as_ref().expect("colors");
    assert_close(colors[0], [1.0, 0.0, 0.0, 1.0], "colour 0");
    assert_close(colors[3], [1.0, 1.0, 1.0, 0.2], "colour 3 (51/255)");
    assert_close(colors[6], [1.0; 4], "colour of a primitive without colours");
    assert_eq!(mesh.materials.len(), 2);
    assert_eq!(
        mesh.materials[0],
        Material {
            base_color_factor: [0.5, 0.25, 1.0, 0.75],
            base_color_texture: Some(0)
        }
    );
    assert_eq!(
        mesh.materials[1],
        Material {
            base_color_factor: DEFAULT_BASE_COLOR,
            base_color_texture: None
        }
    );
    assert_eq!(mesh.triangle_materials, vec![0, 0, 1, 1]);
    assert_eq!(mesh.textures.len(), 1);
    assert_eq!(
        mesh.textures[0],
        Texture {
            width: 3,
            height: 2,
            rgba8: expected_png_pixels(3, 2)
        }
    );
    // Winding stays CCW seen from outside: face normals agree with the vertex normals.
    for tri in &mesh.triangles {
        let p = |i: u32| Vec3::from(mesh.positions[i as usize]);
        let face = (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0]));
        assert!(face.dot(Vec3::new(0.0, -1.0, 0.0)) > 0.0);
    }
}

#[test]
fn gltf_file_with_external_buffer_and_percent_encoded_image() {
    let dir = tempfile::tempdir().unwrap();
    let png = png_bytes(3, 2);
    write(dir.path(), "quad data.bin", quad_buffer());
    write(dir.path(), "my tex.png", &png);
    let doc = quad_gltf(
        &json!({"uri": "quad%20data.bin", "byteLength": 156}),
        &json!({"uri": "my%20tex.png"}),
        1,
        &transformed_nodes(),
    );
    let path = write(dir.path(), "scene.gltf", serde_json::to_vec(&doc).unwrap());
    let mesh = load_mesh(&path).unwrap();
    check_transformed_quad(&mesh);
}

#[test]
fn glb_from_bytes_with_image_in_buffer_view() {
    let png = png_bytes(3, 2);
    let mut bin = quad_buffer();
    bin.extend(&png);
    let doc = quad_gltf(
        &json!({"byteLength": bin.len()}),
        &json!({"bufferView": 5, "mimeType": "image/png"}),
        png.len(),
        &transformed_nodes(),
    );
    let bytes = glb(&doc, &bin);
    let mesh = load_mesh_from_bytes(&bytes, MeshFormat::Glb).unwrap();
    check_transformed_quad(&mesh);
    // The same bytes as a file.
    let dir = tempfile::tempdir().unwrap();
    let from_file = load_mesh(&write(dir.path(), "quad.GLB", &bytes)).unwrap();
    assert_eq!(from_file, mesh);
}

/// A GLB header declaring a total length below its own 12 bytes (every value 0..12) is a clear
/// error: the `gltf` crate would subtract past zero (found by `scripts/fuzz.sh`, target
/// `mesh_gltf`).
#[test]
fn glb_declaring_less_than_its_header_is_refused() {
    let doc = quad_gltf(
        &json!({"byteLength": quad_buffer().len()}),
        &json!({"bufferView": 5, "mimeType": "image/png"}),
        0,
        &transformed_nodes(),
    );
    let valid = glb(&doc, &quad_buffer());
    for declared in 0u32..12 {
        let mut bytes = valid.clone();
        bytes[8..12].copy_from_slice(&declared.to_le_bytes());
        let err = load_mesh_from_bytes(&bytes, MeshFormat::Glb).expect_err("refused");
        assert!(
            err.to_string().contains("fewer than its own 12"),
            "{declared}: {err}"
        );
    }
}

#[test]
fn gltf_from_bytes_with_data_uris() {
    let png = png_bytes(3, 2);
    let doc = quad_gltf(
        &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
        &json!({"uri": format!("data:image/png;base64,{}", base64(&png))}),
        1,
        &transformed_nodes(),
    );
    let mesh = load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf).unwrap();
    check_transformed_quad(&mesh);
}

#[test]
fn gltf_upload_with_external_reference_is_rejected() {
    let doc = quad_gltf(
        &json!({"uri": "quad.bin", "byteLength": 156}),
        &json!({"uri": "tex.png"}),
        1,
        &transformed_nodes(),
    );
    let err =
        load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf).unwrap_err();
    assert!(
        matches!(err, MeshError::Parse { format: "glTF", .. }),
        "{err}"
    );
    assert!(err.to_string().contains("embed"), "{err}");
}

#[test]
fn gltf_mirrored_node_keeps_outward_winding_and_computed_normals() {
    // Primitive 1 (no normals) under a mirror in x: its computed normals must still face +z,
    // which needs the winding flip.
    let doc = quad_gltf(
        &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
        &json!({"uri": format!("data:image/png;base64,{}", base64(&png_bytes(3, 2)))}),
        1,
        &json!([{"scale": [-1.0, 1.0, 1.0], "mesh": 0}]),
    );
    let mesh = load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf).unwrap();
    for n in &mesh.normals {
        assert_close(*n, [0.0, 0.0, 1.0], "normal under mirror");
    }
    assert_close(mesh.positions[1], [-1.0, 0.0, 0.0], "mirrored position");
}

#[test]
fn gltf_strip_fan_and_no_scene() {
    let mut b = Vec::new();
    for p in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 2.0, 0.0],
    ] {
        put_le(&mut b, &p);
    }
    let doc = json!({
        "asset": {"version": "2.0"},
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": 0}, "mode": 5},
            {"attributes": {"POSITION": 0}, "mode": 6}
        ]}],
        "buffers": [{"uri": format!("data:application/octet-stream;base64,{}", base64(&b)), "byteLength": 60}],
        "bufferViews": [{"buffer": 0, "byteLength": 60}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 5, "type": "VEC3", "min": [0, 0, 0], "max": [1, 2, 0]}]
    });
    let mesh = load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf).unwrap();
    // Strip of 5 vertices: 3 triangles; fan of 5: 3 triangles (fan triangle 2 (0,3,4) is valid).
    assert_eq!(&mesh.triangles[..3], &[[0, 1, 2], [1, 3, 2], [2, 3, 4]]);
    assert_eq!(&mesh.triangles[3..], &[[6, 7, 5], [7, 8, 5], [8, 9, 5]]);
    // Every strip triangle faces +z (alternate winding handled).
    for tri in &mesh.triangles[..3] {
        let p = |i: u32| Vec3::from(mesh.positions[i as usize]);
        assert!((p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0])).z > 0.0);
    }
}

#[test]
fn gltf_specular_glossiness_diffuse_is_the_base_colour() {
    let mut doc = quad_gltf(
        &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
        &json!({"uri": format!("data:image/png;base64,{}", base64(&png_bytes(3, 2)))}),
        1,
        &json!([{"mesh": 0}]),
    );
    doc["extensionsUsed"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
    doc["materials"][0] = json!({"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.1, 0.2, 0.3, 1.0]}}});
    let mesh = load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf).unwrap();
    assert_eq!(
        mesh.materials[0],
        Material {
            base_color_factor: [0.1, 0.2, 0.3, 1.0],
            base_color_texture: None
        }
    );
    assert!(mesh.textures.is_empty(), "unused images are not decoded");
}

#[test]
fn gltf_errors() {
    let good = quad_gltf(
        &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
        &json!({"uri": format!("data:image/png;base64,{}", base64(&png_bytes(3, 2)))}),
        1,
        &transformed_nodes(),
    );
    let load = |doc: &serde_json::Value| {
        load_mesh_from_bytes(&serde_json::to_vec(doc).unwrap(), MeshFormat::Gltf)
    };
    assert!(load(&good).is_ok());

    // Hostile accessor count: must fail before allocating.
    let mut hostile = good.clone();
    hostile["accessors"][0]["count"] = json!(4_000_000_000u64);
    assert!(matches!(load(&hostile), Err(MeshError::Parse { .. })));
    // A view-less accessor claiming billions of zeros.
    let mut viewless = good.clone();
    viewless["accessors"][0] = json!({"componentType": 5126, "count": 3_000_000_000u64, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]});
    assert!(matches!(load(&viewless), Err(MeshError::Parse { .. })));
    // Buffer view past the end of its buffer.
    let mut overrun = good.clone();
    overrun["bufferViews"][4]["byteLength"] = json!(1000);
    assert!(matches!(load(&overrun), Err(MeshError::Parse { .. })));
    // Index out of range.
    let mut bad_index = good.clone();
    bad_index["accessors"][4]["count"] = json!(3);
    bad_index["bufferViews"][4] = json!({"buffer": 0, "byteOffset": 0, "byteLength": 6});
    // Indices now read 0x0000, 0x0000, 0x0000 (position bytes): degenerate, not out of range;
    // point the view at the colour bytes instead: 0x00ff = 255.
    bad_index["bufferViews"][4] = json!({"buffer": 0, "byteOffset": 128, "byteLength": 6});
    assert!(matches!(
        load(&bad_index),
        Err(MeshError::IndexOutOfRange { vertex: 255, .. })
    ));
    // Wrong accessor type for POSITION.
    let mut wrong_type = good.clone();
    wrong_type["accessors"][0]["type"] = json!("VEC2");
    assert!(matches!(load(&wrong_type), Err(MeshError::Parse { .. })));
    // Truncated buffer.
    let mut short = good.clone();
    short["buffers"][0]["byteLength"] = json!(400);
    assert!(matches!(load(&short), Err(MeshError::Parse { .. })));
    // Undecodable image.
    let mut bad_image = good.clone();
    bad_image["images"][0]["uri"] = json!(format!(
        "data:image/png;base64,{}",
        base64(b"not a png at all")
    ));
    assert!(matches!(load(&bad_image), Err(MeshError::Texture { .. })));
    // Bad percent-encoding in a relative URI (the gltf crate's importer would panic here).
    let dir = tempfile::tempdir().unwrap();
    let mut bad_uri = good.clone();
    bad_uri["buffers"][0]["uri"] = json!("%FF%FE.bin");
    let path = write(
        dir.path(),
        "bad.gltf",
        serde_json::to_vec(&bad_uri).unwrap(),
    );
    assert!(matches!(load_mesh(&path), Err(MeshError::Parse { .. })));
    // Missing external buffer file.
    let mut missing = good.clone();
    missing["buffers"][0]["uri"] = json!("missing.bin");
    let path = write(
        dir.path(),
        "missing.gltf",
        serde_json::to_vec(&missing).unwrap(),
    );
    assert!(matches!(load_mesh(&path), Err(MeshError::Io { .. })));
    // Instancing bomb: many nodes sharing one mesh; refused before any geometry is read.
    let mut bomb = good.clone();
    bomb["scenes"][0]["nodes"] = json!((0..3000).collect::<Vec<_>>());
    bomb["nodes"] = json!(vec![json!({"mesh": 0}); 3000]);
    bomb["accessors"][0]["count"] = json!(12_000);
    let err = load(&bomb).unwrap_err();
    assert!(err.to_string().contains("instantiates"), "{err}");
    // Images the `gltf` crate's `Image::source` would panic on.
    let mut no_source = good.clone();
    no_source["images"][0] = json!({});
    assert!(matches!(load(&no_source), Err(MeshError::Parse { .. })));
    let mut bad_position = good.clone();
    bad_position["meshes"][0]["primitives"][1]["attributes"]["POSITION"] = json!(99);
    assert!(matches!(load(&bad_position), Err(MeshError::Parse { .. })));
    let mut view_without_mime = good.clone();
    view_without_mime["images"][0] = json!({"bufferView": 3});
    assert!(matches!(
        load(&view_without_mime),
        Err(MeshError::Texture { .. })
    ));
    // Node cycle: must terminate.
    let mut cycle = good.clone();
    cycle["nodes"] = json!([{"children": [1], "mesh": 0}, {"children": [0]}]);
    let _ = load(&cycle);
    // No triangles at all (only the line primitive).
    let mut lines_only = good;
    lines_only["meshes"][0]["primitives"] =
        json!([{"attributes": {"POSITION": 0}, "indices": 4, "mode": 1}]);
    assert!(matches!(load(&lines_only), Err(MeshError::Empty)));
}

// ---------------------------------------------------------------------------------------------
// OBJ

const OBJ_WITH_MATERIALS: &str = "\
# quad, then two triangles with materials
mtllib mats.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
vt 0 0
vt 1 0
vt 1 0.25
vt 0 1
vn 0 0 2
f 1/1/1 2/2/1 3/3/1 4/4/1
usemtl red
f 1/1/1 5/4/1 2/2/1
usemtl textured
f 1/1/1 2/2/1 -1/-1/-1
";

const MTL: &str = "\
newmtl red
Kd 1 0 0
d 0.5
newmtl textured
Kd 0.5 0.5 0.5
map_Kd -s 1 1 1 tex.png
";

#[test]
fn obj_with_mtl_kd_and_map_kd() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "mats.mtl", MTL);
    write(dir.path(), "tex.png", png_bytes(2, 3));
    let mesh = load_mesh(&write(dir.path(), "model.obj", OBJ_WITH_MATERIALS)).unwrap();
    // Quad -> 2 triangles, plus 2 triangles.
    assert_eq!(mesh.triangle_count(), 4);
    assert_eq!(mesh.materials.len(), 3);
    let by_tri: Vec<&Material> = mesh
        .triangle_materials
        .iter()
        .map(|&m| &mesh.materials[m as usize])
        .collect();
    assert_eq!(by_tri[0].base_color_factor, DEFAULT_BASE_COLOR);
    assert_eq!(by_tri[1].base_color_factor, DEFAULT_BASE_COLOR);
    assert_eq!(
        *by_tri[2],
        Material {
            base_color_factor: [1.0, 0.0, 0.0, 0.5],
            base_color_texture: None
        }
    );
    assert_eq!(by_tri[3].base_color_factor, [0.5, 0.5, 0.5, 1.0]);
    let texture = by_tri[3].base_color_texture.expect("map_Kd texture");
    assert_eq!(
        mesh.textures[texture as usize],
        Texture {
            width: 2,
            height: 3,
            rgba8: expected_png_pixels(2, 3)
        }
    );
    // UVs flipped: vt (1, 0.25) -> (1, 0.75); normals normalized.
    let uvs = mesh.uvs.as_ref().unwrap();
    let v = vertex_at(&mesh, [1.0, 1.0, 0.0]);
    assert_close(uvs[v], [1.0, 0.75], "flipped uv");
    for n in &mesh.normals {
        assert_close(*n, [0.0, 0.0, 1.0], "normalized normal");
    }
    assert!(mesh.colors.is_none());
}

#[test]
fn obj_texture_with_windows_path_and_missing_texture() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("maps")).unwrap();
    write(&dir.path().join("maps"), "wood.png", png_bytes(1, 1));
    write(
        dir.path(),
        "mats.mtl",
        "newmtl red\nKd 1 0 0\nmap_Kd maps\\wood.png\nnewmtl textured\nmap_Kd nowhere.png\n",
    );
    let mesh = load_mesh(&write(dir.path(), "model.obj", OBJ_WITH_MATERIALS)).unwrap();
    let red = &mesh.materials[mesh.triangle_materials[2] as usize];
    assert_eq!(red.base_color_texture, Some(0));
    assert_eq!(mesh.textures[0].rgba8, expected_png_pixels(1, 1));
    // Missing texture: a warning; the material keeps its factor (Kd absent: 0.8 grey).
    let textured = &mesh.materials[mesh.triangle_materials[3] as usize];
    assert_eq!(*textured, Material::default());
}

#[test]
fn obj_missing_mtl_is_a_warning_and_bytes_have_no_materials() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_mesh(&write(dir.path(), "model.obj", OBJ_WITH_MATERIALS)).unwrap();
    assert_eq!(mesh.materials, vec![Material::default()]);
    let from_bytes = load_mesh_from_bytes(OBJ_WITH_MATERIALS.as_bytes(), MeshFormat::Obj).unwrap();
    assert_eq!(from_bytes.materials, vec![Material::default()]);
    assert_eq!(from_bytes.triangle_count(), 4);
}

#[test]
fn obj_vertex_colors_and_computed_normals() {
    let (positions, triangles) = tetrahedron();
    let mut text = String::new();
    for (i, p) in positions.iter().enumerate() {
        writeln!(
            text,
            "v {} {} {} {} 0.5 0",
            p[0],
            p[1],
            p[2],
            i as f32 / 4.0
        )
        .unwrap();
    }
    for t in &triangles {
        writeln!(text, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
    }
    let mesh = load_mesh_from_bytes(text.as_bytes(), MeshFormat::Obj).unwrap();
    let colors = mesh.colors.as_ref().unwrap();
    for (i, p) in positions.iter().enumerate() {
        let v = vertex_at(&mesh, *p);
        assert_close(colors[v], [i as f32 / 4.0, 0.5, 0.0, 1.0], "obj colour");
        let expected = Vec3::from(*p).normalize();
        assert_close(
            mesh.normals[v],
            expected.to_array(),
            "computed tetrahedron normal",
        );
    }
}

#[test]
fn obj_errors() {
    // Face refers to a vertex that does not exist.
    assert!(
        load_mesh_from_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", MeshFormat::Obj).is_err()
    );
    // Hostile relative indices (would overflow inside tobj).
    for face in [
        "f 1/-5 2/-5 3/-5",
        "f -9 -8 -7",
        "f 0 1 2",
        "f 1/9223372036854775807 2 3",
    ] {
        let text = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{face}\n");
        let err = load_mesh_from_bytes(text.as_bytes(), MeshFormat::Obj).unwrap_err();
        assert!(
            matches!(err, MeshError::Parse { format: "OBJ", .. }),
            "{face}: {err}"
        );
    }
    // NaN position.
    let err = load_mesh_from_bytes(b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormat::Obj)
        .unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::NonFinite {
                attribute: "position",
                ..
            }
        ),
        "{err}"
    );
    // No faces.
    assert!(matches!(
        load_mesh_from_bytes(b"v 0 0 0\n", MeshFormat::Obj),
        Err(MeshError::Empty)
    ));
    // Malformed mtl next to the file is an error, not silently ignored.
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "mats.mtl", "newmtl red\nKd one two three\n");
    assert!(load_mesh(&write(dir.path(), "model.obj", OBJ_WITH_MATERIALS)).is_err());
}

// ---------------------------------------------------------------------------------------------
// PLY

const PLY_ASCII: &str = "\
ply
format ascii 1.0
comment a unit quad with normals, byte colours, s/t coordinates
element vertex 4
property float x
property float y
property float z
property float nx
property float ny
property float nz
property uchar red
property uchar green
property uchar blue
property uchar alpha
property float s
property float t
element face 1
property list uchar int vertex_indices
end_header
0 0 0 0 0 1 255 0 0 255 0 0
1 0 0 0 0 1 0 255 0 128 1 0
1 1 0 0 0 1 0 0 255 255 1 0.25
0 1 0 0 0 1 51 102 153 255 0 1
4 0 1 2 3
";

#[test]
fn ply_ascii_with_normals_colors_uvs_and_quads() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_mesh(&write(dir.path(), "quad.ply", PLY_ASCII)).unwrap();
    assert_eq!(mesh.vertex_count(), 4);
    assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    let colors = mesh.colors.as_ref().unwrap();
    assert_close(colors[1], [0.0, 1.0, 0.0, 128.0 / 255.0], "uchar colour");
    assert_close(colors[3], [0.2, 0.4, 0.6, 1.0], "uchar colour");
    let uvs = mesh.uvs.as_ref().unwrap();
    assert_close(uvs[2], [1.0, 0.75], "flipped t");
    assert_close(mesh.normals[0], [0.0, 0.0, 1.0], "file normal");
    assert_eq!(mesh.materials, vec![Material::default()]);
}

/// Binary PLY of the tetrahedron with float colours, an extra `edge` element to skip, and
/// face indices of type `list uchar uint` (little endian) or `list uchar ushort` named
/// `vertex_index` (big endian, double positions).
fn ply_binary(little_endian: bool) -> Vec<u8> {
    let (positions, triangles) = tetrahedron();
    let mut out = Vec::new();
    let header = if little_endian {
        "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float red\nproperty float green\nproperty float blue\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nelement face 4\nproperty list uchar uint vertex_indices\nend_header\n"
    } else {
        "ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nproperty ushort red\nproperty ushort green\nproperty ushort blue\nelement face 4\nproperty list uchar ushort vertex_index\nend_header\n"
    };
    out.extend(header.as_bytes());
    for (i, p) in positions.iter().enumerate() {
        // Exact in both f32 and 16-bit: multiples of 0.2 are multiples of 13107/65535.
        let color = [i as f32 * 0.2, 1.0, 0.6];
        if little_endian {
            put_le(&mut out, p);
            put_le(&mut out, &color);
        } else {
            for &c in p {
                out.extend(f64::from(c).to_be_bytes());
            }
            for c in color {
                out.extend(((c * 65535.0).round() as u16).to_be_bytes());
            }
        }
    }
    if little_endian {
        out.extend(0i32.to_le_bytes());
        out.extend(1i32.to_le_bytes());
    }
    for t in &triangles {
        out.push(3);
        for &i in t {
            if little_endian {
                out.extend(i.to_le_bytes());
            } else {
                out.extend((i as u16).to_be_bytes());
            }
        }
    }
    out
}

#[test]
fn ply_binary_both_endiannesses() {
    let (positions, triangles) = tetrahedron();
    for little_endian in [true, false] {
        let mesh = load_mesh_from_bytes(&ply_binary(little_endian), MeshFormat::Ply).unwrap();
        assert_eq!(mesh.positions, positions);
        assert_eq!(mesh.triangles, triangles);
        let colors = mesh.colors.as_ref().unwrap();
        for (i, c) in colors.iter().enumerate() {
            assert_close(*c, [i as f32 * 0.2, 1.0, 0.6, 1.0], "binary colour");
        }
        for (p, n) in positions.iter().zip(&mesh.normals) {
            assert_close(*n, Vec3::from(*p).normalize().to_array(), "computed normal");
        }
    }
}

#[test]
fn ply_errors() {
    let bad_index = PLY_ASCII.replace("4 0 1 2 3", "3 0 1 7");
    assert!(matches!(
        load_mesh_from_bytes(bad_index.as_bytes(), MeshFormat::Ply),
        Err(MeshError::IndexOutOfRange {
            vertex: 7,
            vertex_count: 4,
            ..
        })
    ));
    let negative = PLY_ASCII.replace("4 0 1 2 3", "3 0 1 -2");
    assert!(matches!(
        load_mesh_from_bytes(negative.as_bytes(), MeshFormat::Ply),
        Err(MeshError::Parse { .. })
    ));
    let hostile = PLY_ASCII.replace("element vertex 4", "element vertex 1000000000000");
    assert!(matches!(
        load_mesh_from_bytes(hostile.as_bytes(), MeshFormat::Ply),
        Err(MeshError::Parse { .. })
    ));
    // A binary count near 2^63 must be refused before anything is allocated for it (found by
    // fuzzing: the payload parser reserved the declared count and aborted).
    for ascii in [false, true] {
        let text = if ascii {
            PLY_ASCII.to_owned()
        } else {
            String::from_utf8_lossy(&ply_binary(true)).into_owned()
        };
        let Some(at) = text.find("element face ") else {
            panic!("no face element")
        };
        let end = at + text[at..].find('\n').expect("line end");
        let mut bytes = if ascii {
            PLY_ASCII.as_bytes().to_vec()
        } else {
            ply_binary(true)
        };
        bytes.splice(at..end, b"element face 9223372036854775007".iter().copied());
        let err = load_mesh_from_bytes(&bytes, MeshFormat::Ply).expect_err("refused");
        assert!(err.to_string().contains("more than the file's"), "{err}");
    }
    let no_xyz = PLY_ASCII
        .replace("property float z\n", "")
        .replace("0 0 0 0 0 1", "0 0 0 0 1");
    assert!(load_mesh_from_bytes(no_xyz.as_bytes(), MeshFormat::Ply).is_err());
    let points = PLY_ASCII
        .replace("element face 1", "element face 0")
        .replace("4 0 1 2 3\n", "");
    assert!(matches!(
        load_mesh_from_bytes(points.as_bytes(), MeshFormat::Ply),
        Err(MeshError::Empty)
    ));
    // A binary file whose one face claims a 4-billion-entry index list.
    let mut huge_list = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n".to_vec();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        put_le(&mut huge_list, &p);
    }
    huge_list.extend(u32::MAX.to_le_bytes());
    huge_list.extend([0u8; 12]);
    assert!(matches!(
        load_mesh_from_bytes(&huge_list, MeshFormat::Ply),
        Err(MeshError::Parse { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// STL

fn stl_ascii(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> String {
    let mut out = String::from("solid test\n");
    for t in triangles {
        out += "  facet normal 0 0 0\n    outer loop\n";
        for &i in t {
            let p = positions[i as usize];
            writeln!(out, "      vertex {} {} {}", p[0], p[1], p[2]).unwrap();
        }
        out += "    endloop\n  endfacet\n";
    }
    out + "endsolid test\n"
}

fn stl_binary(positions: &[[f32; 3]], triangles: &[[u32; 3]], header: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..header.len()].copy_from_slice(header);
    out.extend((triangles.len() as u32).to_le_bytes());
    for t in triangles {
        out.extend([0u8; 12]);
        for &i in t {
            put_le(&mut out, &positions[i as usize]);
        }
        out.extend([0u8; 2]);
    }
    out
}

#[test]
fn stl_ascii_tetrahedron_normals() {
    let (positions, triangles) = tetrahedron();
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_mesh(&write(
        dir.path(),
        "tet.stl",
        stl_ascii(&positions, &triangles),
    ))
    .unwrap();
    assert_eq!(mesh.vertex_count(), 4, "vertices deduplicated");
    assert_eq!(mesh.triangle_count(), 4);
    for p in &positions {
        let v = vertex_at(&mesh, *p);
        assert_close(
            mesh.normals[v],
            Vec3::from(*p).normalize().to_array(),
            "tetrahedron normal",
        );
    }
    assert!(mesh.colors.is_none() && mesh.uvs.is_none());
    // `solid` without a name is ASCII too.
    let unnamed = stl_ascii(&positions, &triangles).replacen("solid test", "solid", 1);
    assert_eq!(
        load_mesh_from_bytes(unnamed.as_bytes(), MeshFormat::Stl)
            .unwrap()
            .triangle_count(),
        4
    );
}

#[test]
fn stl_binary_cube_even_with_solid_header() {
    let (positions, triangles) = cube();
    for header in [
        &b"binary cube"[..],
        &b"solid cube written by a careless exporter"[..],
    ] {
        let mesh =
            load_mesh_from_bytes(&stl_binary(&positions, &triangles, header), MeshFormat::Stl)
                .unwrap();
        assert_eq!(mesh.vertex_count(), 8);
        assert_eq!(mesh.triangle_count(), 12);
        assert_outward_unit_normals(&mesh, [0.5; 3]);
    }
}

#[test]
fn stl_errors() {
    let (positions, triangles) = cube();
    let mut hostile = stl_binary(&positions, &triangles, b"x");
    hostile[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let err = load_mesh_from_bytes(&hostile, MeshFormat::Stl).unwrap_err();
    assert!(
        matches!(err, MeshError::Parse { format: "STL", .. }),
        "{err}"
    );
    assert!(load_mesh_from_bytes(b"tiny", MeshFormat::Stl).is_err());
    // A truncated binary file whose header starts with `solid`.
    let solid = stl_binary(&positions, &triangles, b"solid but binary");
    let err = load_mesh_from_bytes(&solid[..solid.len() - 7], MeshFormat::Stl).unwrap_err();
    assert!(err.to_string().contains("truncated"), "{err}");
    let empty = stl_binary(&positions, &[], b"x");
    assert!(matches!(
        load_mesh_from_bytes(&empty, MeshFormat::Stl),
        Err(MeshError::Empty)
    ));
    let bad_ascii = "solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 zero\n";
    assert!(load_mesh_from_bytes(bad_ascii.as_bytes(), MeshFormat::Stl).is_err());
}

// ---------------------------------------------------------------------------------------------
// OFF

const OFF_CUBE: &str = "\
# a unit cube of quads
OFF # header comment

# counts, then a blank line
8 6 12

0 0 0
1 0 0   # comment after a vertex
0 1 0
1 1 0
0 0 1
1 0 1
0 1 1
1 1 1
# faces
4 0 2 3 1
4 4 5 7 6
4 0 1 5 4
4 2 6 7 3
4 0 4 6 2
4 1 3 7 5 # face comment
";

#[test]
fn off_cube_with_comments() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = load_mesh(&write(dir.path(), "cube.off", OFF_CUBE)).unwrap();
    assert_eq!(mesh.vertex_count(), 8);
    assert_eq!(mesh.triangle_count(), 12);
    assert_eq!(&mesh.triangles[..2], &[[0, 2, 3], [0, 3, 1]]);
    assert_outward_unit_normals(&mesh, [0.5; 3]);
    assert!(mesh.colors.is_none());
    // Counts on the header line.
    let inline = "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2";
    assert_eq!(
        load_mesh_from_bytes(inline.as_bytes(), MeshFormat::Off)
            .unwrap()
            .triangle_count(),
        1
    );
}

#[test]
fn coff_int_and_float_colors_noff_normals() {
    let ints = "COFF\n# colours as bytes\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0\n0 1 0 51 102 153 128\n3 0 1 2 255 255 255\n";
    let mesh = load_mesh_from_bytes(ints.as_bytes(), MeshFormat::Off).unwrap();
    let colors = mesh.colors.as_ref().unwrap();
    assert_close(colors[0], [1.0, 0.0, 0.0, 1.0], "byte colour");
    assert_close(colors[1], [0.0, 1.0, 0.0, 1.0], "byte colour without alpha");
    assert_close(colors[2], [0.2, 0.4, 0.6, 128.0 / 255.0], "byte colour");

    let floats = "COFF\n3 1 0\n0 0 0 1 0 0 1\n1 0 0 0 1 0 0.5\n0 1 0 0.2 0.4 0.6\n3 0 1 2\n";
    let colors = load_mesh_from_bytes(floats.as_bytes(), MeshFormat::Off)
        .unwrap()
        .colors
        .unwrap();
    assert_close(colors[0], [1.0, 0.0, 0.0, 1.0], "float colour");
    assert_close(colors[1], [0.0, 1.0, 0.0, 0.5], "float colour");
    assert_close(
        colors[2],
        [0.2, 0.4, 0.6, 1.0],
        "float colour without alpha",
    );

    let noff = "CNOFF\n3 1 0\n0 0 0 0 0 3 1 1 1\n1 0 0 0 0 3 1 1 1\n0 1 0 0 0 -3 1 1 1\n3 0 1 2\n";
    let mesh = load_mesh_from_bytes(noff.as_bytes(), MeshFormat::Off).unwrap();
    assert_close(mesh.normals[0], [0.0, 0.0, 1.0], "file normal");
    assert_close(mesh.normals[2], [0.0, 0.0, -1.0], "file normal kept");

    let st = "STOFF\n3 1 0\n0 0 0 0 0.25\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n";
    let uvs = load_mesh_from_bytes(st.as_bytes(), MeshFormat::Off)
        .unwrap()
        .uvs
        .unwrap();
    assert_close(uvs[0], [0.0, 0.75], "flipped t");
}

#[test]
fn off_errors() {
    let load = |text: &str| load_mesh_from_bytes(text.as_bytes(), MeshFormat::Off);
    assert!(matches!(
        load("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n"),
        Err(MeshError::Empty)
    ));
    assert!(matches!(
        load("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n"),
        Err(MeshError::IndexOutOfRange {
            vertex: 9,
            vertex_count: 3,
            ..
        })
    ));
    assert!(matches!(
        load("OFF\n3 1 0\nnan 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        Err(MeshError::NonFinite {
            attribute: "position",
            index: 0
        })
    ));
    assert!(matches!(
        load("OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n"),
        Err(MeshError::AllDegenerate)
    ));
    // Hostile counts: an error at once, no allocation attempt.
    let started = Instant::now();
    let err = load("OFF\n1000000000000 1000000000000 0\n0 0 0\n").unwrap_err();
    assert!(
        matches!(err, MeshError::Parse { format: "OFF", .. }),
        "{err}"
    );
    assert!(err.to_string().contains("truncated"), "{err}");
    assert!(started.elapsed() < Duration::from_secs(1));
    assert!(load("OFF\n18446744073709551615 1 0\n").is_err());
    assert!(load("OFF\n-3 1 0\n").is_err());
    // Truncated: fewer vertices or faces than claimed; a face shorter than its count.
    assert!(matches!(
        load("OFF\n3 1 0\n0 0 0\n1 0 0\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(
        load("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(
        load("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(
        load("4OFF\n3 1 0\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(load("OFF BINARY\n"), Err(MeshError::Parse { .. })));
    assert!(matches!(
        load("COFF\n3 1 0\n0 0 0 1 0\n1 0 0 1 0\n0 1 0 1 0\n3 0 1 2\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(
        load("hello world\n"),
        Err(MeshError::Parse { .. })
    ));
    assert!(matches!(load(""), Err(MeshError::Parse { .. })));
}

// ---------------------------------------------------------------------------------------------
// Mesh::from_arrays and Mesh::finish

#[test]
fn from_arrays_validates() {
    let (positions, triangles) = tetrahedron();
    let mesh = Mesh::from_arrays(positions.clone(), triangles.clone(), None).unwrap();
    assert_eq!(mesh.materials, vec![Material::default()]);
    assert_eq!(mesh.triangle_materials, vec![0; 4]);
    for (p, n) in positions.iter().zip(&mesh.normals) {
        assert_close(*n, Vec3::from(*p).normalize().to_array(), "computed normal");
    }
    let colors = vec![[2.0, 0.5, -1.0, 1.0]; 4];
    let mesh = Mesh::from_arrays(positions.clone(), triangles.clone(), Some(colors)).unwrap();
    assert_eq!(
        mesh.colors.unwrap()[0],
        [1.0, 0.5, 0.0, 1.0],
        "colours clamped to [0,1]"
    );

    assert!(matches!(
        Mesh::from_arrays(positions.clone(), vec![], None),
        Err(MeshError::Empty)
    ));
    let mut nan = positions.clone();
    nan[2][1] = f32::NAN;
    assert!(matches!(
        Mesh::from_arrays(nan, triangles.clone(), None),
        Err(MeshError::NonFinite {
            attribute: "position",
            index: 2
        })
    ));
    let mut inf = positions.clone();
    inf[3][0] = f32::INFINITY;
    assert!(matches!(
        Mesh::from_arrays(inf, triangles.clone(), None),
        Err(MeshError::NonFinite { .. })
    ));
    assert!(matches!(
        Mesh::from_arrays(positions.clone(), vec![[0, 1, 4]], None),
        Err(MeshError::IndexOutOfRange {
            triangle: 0,
            vertex: 4,
            vertex_count: 4
        })
    ));
    assert!(matches!(
        Mesh::from_arrays(
            positions.clone(),
            triangles.clone(),
            Some(vec![[1.0; 4]; 3])
        ),
        Err(MeshError::AttributeLength {
            attribute: "colors",
            got: 3,
            expected: 4
        })
    ));
    let mut bad_color = vec![[1.0; 4]; 4];
    bad_color[1][3] = f32::NAN;
    assert!(matches!(
        Mesh::from_arrays(positions.clone(), triangles.clone(), Some(bad_color)),
        Err(MeshError::NonFinite {
            attribute: "color",
            index: 1
        })
    ));
    // Degenerate only: repeated index and collinear.
    let line = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    assert!(matches!(
        Mesh::from_arrays(line, vec![[0, 1, 2], [0, 0, 1]], None),
        Err(MeshError::AllDegenerate)
    ));
    // Degenerate triangles are dropped, the rest kept.
    let mut mixed = triangles.clone();
    mixed.insert(1, [0, 0, 1]);
    let mesh = Mesh::from_arrays(positions, mixed, None).unwrap();
    assert_eq!(mesh.triangles, triangles);
}

#[test]
fn finish_repairs_normals_and_checks_materials_and_textures() {
    let (positions, triangles) = tetrahedron();
    let base = Mesh::from_arrays(positions.clone(), triangles.clone(), None).unwrap();

    // A zero and a NaN normal are recomputed; a non-unit one is normalized.
    let mut mesh = base.clone();
    mesh.normals = vec![
        [0.0; 3],
        [f32::NAN, 0.0, 0.0],
        [0.0, 5.0, 0.0],
        [0.0, 0.0, -1.0],
    ];
    let mesh = mesh.finish().unwrap();
    assert_close(
        mesh.normals[0],
        Vec3::from(positions[0]).normalize().to_array(),
        "recomputed",
    );
    assert_close(
        mesh.normals[1],
        Vec3::from(positions[1]).normalize().to_array(),
        "recomputed",
    );
    assert_close(mesh.normals[2], [0.0, 1.0, 0.0], "normalized");
    assert_close(mesh.normals[3], [0.0, 0.0, -1.0], "kept");

    let mut mesh = base.clone();
    mesh.normals.pop();
    assert!(matches!(
        mesh.finish(),
        Err(MeshError::AttributeLength {
            attribute: "normals",
            ..
        })
    ));
    let mut mesh = base.clone();
    mesh.uvs = Some(vec![[0.0, f32::INFINITY]; 4]);
    assert!(matches!(
        mesh.finish(),
        Err(MeshError::NonFinite {
            attribute: "uv",
            index: 0
        })
    ));
    let mut mesh = base.clone();
    mesh.triangle_materials[2] = 5;
    assert!(matches!(mesh.finish(), Err(MeshError::Parse { .. })));
    let mut mesh = base.clone();
    mesh.materials.clear();
    assert_eq!(mesh.finish().unwrap().materials, vec![Material::default()]);
    let mut mesh = base.clone();
    mesh.materials[0].base_color_texture = Some(0);
    assert!(matches!(mesh.finish(), Err(MeshError::Parse { .. })));

    // Textures: size mismatch is an error; an oversized one is downscaled keeping aspect.
    let mut mesh = base.clone();
    mesh.textures.push(Texture {
        width: 2,
        height: 2,
        rgba8: vec![0; 15],
    });
    assert!(matches!(
        mesh.finish(),
        Err(MeshError::Texture { index: 0, .. })
    ));
    let mut mesh = base;
    let (w, h) = (MAX_TEXTURE_PX * 2 + 2, 6);
    mesh.textures.push(Texture {
        width: w,
        height: h,
        rgba8: vec![200; (w * h * 4) as usize],
    });
    mesh.materials[0].base_color_texture = Some(0);
    let mesh = mesh.finish().unwrap();
    let t = &mesh.textures[0];
    assert_eq!((t.width, t.height), (MAX_TEXTURE_PX, 3));
    assert_eq!(t.rgba8.len(), (t.width * t.height * 4) as usize);
    assert!(
        t.rgba8.iter().all(|&b| b == 200),
        "uniform image stays uniform"
    );
}

// ---------------------------------------------------------------------------------------------
// Robustness: truncation, garbage, mutation (never a panic)

/// One valid sample per format.
fn samples() -> Vec<(MeshFormat, Vec<u8>)> {
    let (positions, triangles) = cube();
    let png = png_bytes(3, 2);
    let mut bin = quad_buffer();
    bin.extend(&png);
    let glb_doc = quad_gltf(
        &json!({"byteLength": bin.len()}),
        &json!({"bufferView": 5, "mimeType": "image/png"}),
        png.len(),
        &transformed_nodes(),
    );
    let gltf_doc = quad_gltf(
        &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
        &json!({"uri": format!("data:image/png;base64,{}", base64(&png))}),
        1,
        &transformed_nodes(),
    );
    vec![
        (MeshFormat::Glb, glb(&glb_doc, &bin)),
        (MeshFormat::Gltf, serde_json::to_vec(&gltf_doc).unwrap()),
        (MeshFormat::Obj, OBJ_WITH_MATERIALS.as_bytes().to_vec()),
        (MeshFormat::Ply, PLY_ASCII.as_bytes().to_vec()),
        (MeshFormat::Ply, ply_binary(true)),
        (MeshFormat::Ply, ply_binary(false)),
        (
            MeshFormat::Stl,
            stl_ascii(&positions, &triangles).into_bytes(),
        ),
        (
            MeshFormat::Stl,
            stl_binary(&positions, &triangles, b"binary"),
        ),
        (MeshFormat::Off, OFF_CUBE.as_bytes().to_vec()),
    ]
}

#[test]
fn samples_load() {
    for (format, bytes) in samples() {
        load_mesh_from_bytes(&bytes, format).unwrap_or_else(|e| panic!("{format}: {e}"));
    }
}

#[test]
fn truncated_files_never_panic_and_mostly_fail() {
    for (format, bytes) in samples() {
        for len in 0..bytes.len() {
            let _ = load_mesh_from_bytes(&bytes[..len], format);
        }
        // Cut in half: every format with structure notices (OBJ has none: half an OBJ is an OBJ,
        // but here half the file loses the vertices the later faces use).
        let half = &bytes[..bytes.len() / 2];
        assert!(
            load_mesh_from_bytes(half, format).is_err(),
            "{format}: half a file loaded"
        );
    }
}

#[test]
fn garbage_bytes_fail_for_every_format() {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let garbage: Vec<u8> = (0..4096)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 24) as u8
        })
        .collect();
    for format in MeshFormat::ALL {
        for bytes in [&garbage[..], &garbage[..100], b"", b"\0\0\0\0"] {
            assert!(
                load_mesh_from_bytes(bytes, format).is_err(),
                "{format} accepted garbage"
            );
        }
    }
}

/// Every JSON pointer in `value` (object keys without `/` or `~`).
fn json_pointers(value: &serde_json::Value, prefix: &str, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Object(map) => {
            for (key, child) in map {
                let pointer = format!("{prefix}/{key}");
                out.push(pointer.clone());
                json_pointers(child, &pointer, out);
            }
        }
        serde_json::Value::Array(items) => {
            for (i, child) in items.iter().enumerate() {
                let pointer = format!("{prefix}/{i}");
                out.push(pointer.clone());
                json_pointers(child, &pointer, out);
            }
        }
        _ => {}
    }
}

/// Fuzz cases per robustness property: `LUMIGRAPH_FUZZ_CASES` (default 96) for longer runs.
fn fuzz_cases() -> u32 {
    std::env::var("LUMIGRAPH_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(96)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: fuzz_cases(), ..ProptestConfig::default() })]

    /// Random byte edits of valid files give a mesh or an error, never a panic.
    #[test]
    fn mutated_files_never_panic(
        sample in 0usize..9,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..8),
    ) {
        let (format, mut bytes) = samples().swap_remove(sample);
        for (at, value, kind) in edits {
            let i = at.index(bytes.len().max(1));
            match kind {
                0 if i < bytes.len() => bytes[i] = value,
                1 => bytes.insert(i.min(bytes.len()), value),
                _ if i < bytes.len() => { bytes.remove(i); }
                _ => {}
            }
        }
        if let Ok(mesh) = load_mesh_from_bytes(&bytes, format) {
            prop_assert!(mesh.triangle_count() > 0);
            prop_assert_eq!(mesh.normals.len(), mesh.vertex_count());
            prop_assert!(mesh.bounding_sphere().radius > 0.0);
        }
    }

    /// Structure-aware glTF fuzzing: replace or remove JSON values (indices, counts, offsets,
    /// types, URIs) of a valid document; the `gltf` crate's validation does not catch everything
    /// its accessors assume.
    #[test]
    fn mutated_gltf_json_never_panics(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), 0usize..12), 1..5),
        binary in any::<bool>(),
    ) {
        let png = png_bytes(3, 2);
        let mut bin = quad_buffer();
        bin.extend(&png);
        let mut doc = if binary {
            quad_gltf(&json!({"byteLength": bin.len()}), &json!({"bufferView": 5, "mimeType": "image/png"}), png.len(), &transformed_nodes())
        } else {
            quad_gltf(
                &json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&quad_buffer())), "byteLength": 156}),
                &json!({"uri": format!("data:image/png;base64,{}", base64(&png))}),
                1,
                &transformed_nodes(),
            )
        };
        for (at, kind) in edits {
            let mut pointers = Vec::new();
            json_pointers(&doc, "", &mut pointers);
            let pointer = at.get(&pointers).clone();
            let replacement = [
                json!(null), json!(0), json!(1), json!(-1), json!(3), json!(4_294_967_295u64),
                json!(18_446_744_073_709_551_615u64), json!(1.5), json!("x"), json!([]), json!({}),
            ];
            if let Some(value) = replacement.get(kind) {
                if let Some(slot) = doc.pointer_mut(&pointer) {
                    *slot = value.clone();
                }
            } else if let Some((parent, key)) = pointer.rsplit_once('/')
                && let Some(serde_json::Value::Object(map)) = doc.pointer_mut(parent)
            {
                map.remove(key);
            }
        }
        let result = if binary {
            load_mesh_from_bytes(&glb(&doc, &bin), MeshFormat::Glb)
        } else {
            load_mesh_from_bytes(&serde_json::to_vec(&doc).unwrap(), MeshFormat::Gltf)
        };
        if let Ok(mesh) = result {
            prop_assert!(mesh.triangle_count() > 0);
        }
    }

    /// Token-level fuzzing of the text formats: numbers and keywords replaced by hostile ones
    /// (negative, zero, huge, NaN, overflowing indices and counts).
    #[test]
    fn mutated_text_tokens_never_panic(
        sample in prop::sample::select(vec![2usize, 3, 6, 8]),
        edits in proptest::collection::vec((any::<prop::sample::Index>(), 0usize..16), 1..6),
    ) {
        const HOSTILE: [&str; 16] = [
            "-1", "0", "1", "-5", "4294967295", "4294967296", "-9223372036854775808",
            "18446744073709551616", "nan", "inf", "1e39", "3.5", "#", "f", "v", "-2147483648",
        ];
        let (format, bytes) = samples().swap_remove(sample);
        let text = String::from_utf8(bytes).unwrap();
        let mut lines: Vec<Vec<String>> =
            text.lines().map(|l| l.split(' ').map(str::to_owned).collect()).collect();
        for (at, token) in edits {
            let slots: Vec<(usize, usize)> = lines
                .iter()
                .enumerate()
                .flat_map(|(i, l)| (0..l.len()).map(move |j| (i, j)))
                .collect();
            let (i, j) = *at.get(&slots);
            lines[i][j] = HOSTILE[token].to_owned();
        }
        let text: String = lines.iter().map(|l| l.join(" ") + "\n").collect();
        if let Ok(mesh) = load_mesh_from_bytes(text.as_bytes(), format) {
            prop_assert!(mesh.triangle_count() > 0);
            prop_assert!(mesh.bounding_sphere().radius > 0.0);
        }
    }

    /// Arbitrary bytes never panic.
    #[test]
    fn arbitrary_bytes_never_panic(format in 0usize..6, bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = load_mesh_from_bytes(&bytes, MeshFormat::ALL[format]);
    }
}

// ---------------------------------------------------------------------------------------------
// Bounding sphere

/// Exact minimal enclosing ball (Welzl), the reference for the 5 % bound.
fn welzl(points: &[DVec3]) -> (DVec3, f64) {
    fn ball(boundary: &[DVec3]) -> (DVec3, f64) {
        match *boundary {
            [] => (DVec3::ZERO, -1.0),
            [a] => (a, 0.0),
            [a, b] => ((a + b) / 2.0, a.distance(b) / 2.0),
            [a, b, c] => {
                let (ab, ac) = (b - a, c - a);
                let n = ab.cross(ac);
                let center = a
                    + (ac.length_squared() * n.cross(ab) + ab.length_squared() * ac.cross(n))
                        / (2.0 * n.length_squared());
                (center, center.distance(a))
            }
            [a, b, c, d] => {
                let m = glam::DMat3::from_cols(b - a, c - a, d - a).transpose();
                let rhs = DVec3::new(
                    (b - a).length_squared(),
                    (c - a).length_squared(),
                    (d - a).length_squared(),
                ) / 2.0;
                let center = a + m.inverse() * rhs;
                (center, center.distance(a))
            }
            _ => unreachable!(),
        }
    }
    fn recurse(points: &[DVec3], boundary: &mut Vec<DVec3>) -> (DVec3, f64) {
        if points.is_empty() || boundary.len() == 4 {
            return ball(boundary);
        }
        let (p, rest) = points.split_last().unwrap();
        let (c, r) = recurse(rest, boundary);
        if r >= 0.0 && p.distance(c) <= r * (1.0 + 1e-12) + 1e-12 {
            return (c, r);
        }
        boundary.push(*p);
        let result = recurse(rest, boundary);
        boundary.pop();
        result
    }
    recurse(points, &mut Vec::new())
}

fn sphere_of_points(points: &[[f32; 3]]) -> Mesh {
    // Triangles over consecutive points, so that every point is referenced.
    let n = points.len() as u32;
    let triangles = (0..n).map(|i| [i, (i + 1) % n, (i + 2) % n]).collect();
    Mesh {
        positions: points.to_vec(),
        triangles,
        ..Mesh::default()
    }
}

#[test]
fn bounding_sphere_of_cube() {
    let (positions, triangles) = cube();
    let mesh = Mesh::from_arrays(positions.clone(), triangles, None).unwrap();
    let sphere = mesh.bounding_sphere();
    let minimal = 3f64.sqrt() / 2.0;
    assert!(
        sphere.radius >= minimal && sphere.radius <= minimal * 1.05,
        "radius {}",
        sphere.radius
    );
    assert!(sphere.center.distance(DVec3::splat(0.5)) < 0.05);
    for p in &positions {
        assert!(DVec3::from(p.map(f64::from)).distance(sphere.center) <= sphere.radius);
    }
}

#[test]
fn bounding_sphere_ignores_unreferenced_vertices() {
    let (mut positions, triangles) = tetrahedron();
    positions.push([100.0, 100.0, 100.0]);
    let mesh = Mesh::from_arrays(positions, triangles, None).unwrap();
    assert!(mesh.bounding_sphere().radius < 2.0);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn bounding_sphere_contains_all_and_is_near_minimal(
        points in proptest::collection::vec(prop::array::uniform3(-100.0f32..100.0), 3..150),
        scale in prop::array::uniform3(0.01f32..10.0),
    ) {
        let points: Vec<[f32; 3]> = points.iter().map(|p| [p[0] * scale[0], p[1] * scale[1], p[2] * scale[2]]).collect();
        let mesh = sphere_of_points(&points);
        let sphere = mesh.bounding_sphere();
        let exact: Vec<DVec3> = points.iter().map(|p| DVec3::from(p.map(f64::from))).collect();
        let (_, minimal) = welzl(&exact);
        prop_assert!(sphere.radius > 0.0);
        for p in &exact {
            prop_assert!(p.distance(sphere.center) <= sphere.radius, "{p} outside");
        }
        prop_assert!(sphere.radius <= minimal * 1.05 + 1e-9, "radius {} vs minimal {minimal}", sphere.radius);
        prop_assert!(sphere.radius >= minimal * (1.0 - 1e-6), "radius {} below minimal {minimal}", sphere.radius);
    }

    #[test]
    fn bounding_sphere_of_points_on_a_sphere(
        directions in proptest::collection::vec(prop::array::uniform3(-1.0f64..1.0), 4..100),
        center in prop::array::uniform3(-1000.0f64..1000.0),
    ) {
        let points: Vec<[f32; 3]> = directions
            .iter()
            .filter_map(|d| DVec3::from(*d).try_normalize())
            .map(|d| (DVec3::from(center) + d * 5.0).as_vec3().to_array())
            .collect();
        prop_assume!(points.len() >= 3);
        let mesh = sphere_of_points(&points);
        let sphere = mesh.bounding_sphere();
        let exact: Vec<DVec3> = points.iter().map(|p| DVec3::from(p.map(f64::from))).collect();
        let (_, minimal) = welzl(&exact);
        for p in &exact {
            prop_assert!(p.distance(sphere.center) <= sphere.radius);
        }
        prop_assert!(sphere.radius <= minimal * 1.05 + 1e-9, "radius {} vs minimal {minimal}", sphere.radius);
    }
}

// ---------------------------------------------------------------------------------------------
// Real meshes (dev fixtures)

fn load_fixture(name: &str, triangles: usize, vertices: usize) -> Mesh {
    let path = common::fixtures_dir().join("mesh").join(name);
    let started = Instant::now();
    let mesh = load_mesh(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    let elapsed = started.elapsed();
    eprintln!(
        "{name}: {} triangles, {} vertices in {elapsed:?}",
        mesh.triangle_count(),
        mesh.vertex_count()
    );
    // Generous for unoptimized test builds on 2 shared cores; release loads are ~10x faster.
    assert!(elapsed < Duration::from_secs(20), "{name} took {elapsed:?}");
    assert_eq!(mesh.triangle_count(), triangles, "{name} triangles");
    assert_eq!(mesh.vertex_count(), vertices, "{name} vertices");
    assert_eq!(mesh.normals.len(), vertices);
    let sphere = mesh.bounding_sphere();
    for p in &mesh.positions {
        assert!(DVec3::from(p.map(f64::from)).distance(sphere.center) <= sphere.radius);
    }
    mesh
}

#[test]
fn real_bunny_off() {
    load_fixture("bunny00.off", 75_408, 37_706);
}

#[test]
fn real_cow_off() {
    load_fixture("cow.off", 5_804, 2_904);
}

#[test]
fn real_spot_ply() {
    load_fixture("spot.ply", 5_856, 2_930);
}
