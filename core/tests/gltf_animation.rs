//! glTF animations sampled into frames (`mesh::load_animation`): an animated scene built in
//! code (node translation with linear keys, rotation with step keys, morph-target weights and a
//! two-joint skin whose second joint turns with a cubic spline) posed exactly, the Debian glTF
//! samples (a morph-target cube, a simple skin), and bad input as errors.

mod common;

use base64::Engine as _;
use lumigraph_core::mesh::{MeshError, load_animation};
use serde_json::json;

/// Little-endian f32s as bytes.
fn f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Appends `bytes` to the buffer (4-byte aligned) as a buffer view and an accessor; returns
/// the accessor index.
fn accessor(
    buffer: &mut Vec<u8>,
    views: &mut Vec<serde_json::Value>,
    accessors: &mut Vec<serde_json::Value>,
    bytes: &[u8],
    (kind, component, count): (&str, u32, usize),
    extra: &serde_json::Value,
) -> usize {
    while !buffer.len().is_multiple_of(4) {
        buffer.push(0);
    }
    views.push(json!({"buffer": 0, "byteOffset": buffer.len(), "byteLength": bytes.len()}));
    buffer.extend_from_slice(bytes);
    let mut a = json!({"bufferView": views.len() - 1, "componentType": component, "count": count, "type": kind});
    if let (Some(a), Some(extra)) = (a.as_object_mut(), extra.as_object()) {
        for (k, v) in extra {
            a.insert(k.clone(), v.clone());
        }
    }
    accessors.push(a);
    accessors.len() - 1
}

/// The scene: node 0 a unit box (corners 0..1) with one morph target (+1 x on its top
/// corners), moving along x (linear keys 0 → 2 over 1 s), turning 90° about y at 0.5 s (step
/// keys) and morphing (weight 0 → 1 over 1 s); node 1 a skinned strip along y (y = 0..2, its
/// upper vertices bound to joint node 3, which sits at y = 1 under the root joint node 2 and
/// turns 90° about z over 1 s, cubic spline keys with zero tangents).
fn animated_gltf(with_animation: bool) -> Vec<u8> {
    let (mut buffer, mut views, mut accessors) = (Vec::new(), Vec::new(), Vec::new());
    let corners: Vec<f32> = (0..8)
        .flat_map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
        .collect();
    let box_positions = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&corners),
        ("VEC3", 5126, 8),
        &json!({"min": [0, 0, 0], "max": [1, 1, 1]}),
    );
    let target: Vec<f32> = (0..8)
        .flat_map(|i| [if (i >> 1) & 1 == 1 { 1.0 } else { 0.0 }, 0.0, 0.0])
        .collect();
    let box_target = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&target),
        ("VEC3", 5126, 8),
        &json!({"min": [0, 0, 0], "max": [1, 0, 0]}),
    );
    let faces: [[u16; 4]; 6] = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let indices: Vec<u8> = faces
        .iter()
        .flat_map(|f| [f[0], f[1], f[2], f[0], f[2], f[3]])
        .flat_map(u16::to_le_bytes)
        .collect();
    let box_indices = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &indices,
        ("SCALAR", 5123, 36),
        &json!({}),
    );
    // The strip: x ∈ {0, 0.2}, y ∈ {0, 1, 2}; rows 0-1 on joint 0 (node 2), row 2 on joint 1.
    let strip: Vec<f32> = (0..6)
        .flat_map(|i| [0.2 * (i % 2) as f32, (i / 2) as f32, 0.0])
        .collect();
    let strip_positions = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&strip),
        ("VEC3", 5126, 6),
        &json!({"min": [0, 0, 0], "max": [0.2, 2, 0]}),
    );
    let joints: Vec<u8> = (0..6).flat_map(|i| [u8::from(i >= 4), 0, 0, 0]).collect();
    let strip_joints = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &joints,
        ("VEC4", 5121, 6),
        &json!({}),
    );
    let weights: Vec<f32> = (0..6).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
    let strip_weights = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&weights),
        ("VEC4", 5126, 6),
        &json!({}),
    );
    let strip_indices: Vec<u8> = [0u16, 1, 3, 0, 3, 2, 2, 3, 5, 2, 5, 4]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let strip_idx = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &strip_indices,
        ("SCALAR", 5123, 12),
        &json!({}),
    );
    // Inverse bind matrices: joint 0 at the origin, joint 1 at y = 1 (column-major).
    let mut ibm = vec![0.0f32; 32];
    for m in 0..2 {
        for d in 0..4 {
            ibm[16 * m + 5 * d] = 1.0;
        }
    }
    ibm[16 + 13] = -1.0;
    let inverse_binds = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&ibm),
        ("MAT4", 5126, 2),
        &json!({}),
    );
    let times = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[0.0, 1.0]),
        ("SCALAR", 5126, 2),
        &json!({"min": [0], "max": [1]}),
    );
    let step_times = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[0.0, 0.5]),
        ("SCALAR", 5126, 2),
        &json!({"min": [0], "max": [0.5]}),
    );
    let moves = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[0.0, 0.0, 0.0, 2.0, 0.0, 0.0]),
        ("VEC3", 5126, 2),
        &json!({}),
    );
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let turns = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, h, 0.0, h]),
        ("VEC4", 5126, 2),
        &json!({}),
    );
    let morphs = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[0.0, 1.0]),
        ("SCALAR", 5126, 2),
        &json!({}),
    );
    // Cubic spline: per key in-tangent, value, out-tangent (zero tangents).
    let bends = accessor(
        &mut buffer,
        &mut views,
        &mut accessors,
        &f32s(&[
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, h, h, 0.0, 0.0, 0.0, 0.0,
        ]),
        ("VEC4", 5126, 6),
        &json!({}),
    );
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&buffer)
    );
    let mut doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0, "name": "box"},
            {"mesh": 1, "skin": 0, "name": "strip"},
            {"children": [3], "name": "root joint"},
            {"translation": [0, 1, 0], "name": "elbow"}
        ],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": box_positions}, "indices": box_indices,
                             "targets": [{"POSITION": box_target}]}], "weights": [0.0]},
            {"primitives": [{"attributes": {"POSITION": strip_positions, "JOINTS_0": strip_joints,
                             "WEIGHTS_0": strip_weights}, "indices": strip_idx}]}
        ],
        "skins": [{"joints": [2, 3], "inverseBindMatrices": inverse_binds}],
        "buffers": [{"byteLength": buffer.len(), "uri": uri}],
        "bufferViews": views,
        "accessors": accessors,
    });
    if with_animation {
        doc["animations"] = json!([{
            "name": "walk",
            "samplers": [
                {"input": times, "output": moves, "interpolation": "LINEAR"},
                {"input": step_times, "output": turns, "interpolation": "STEP"},
                {"input": times, "output": morphs, "interpolation": "LINEAR"},
                {"input": times, "output": bends, "interpolation": "CUBICSPLINE"}
            ],
            "channels": [
                {"sampler": 0, "target": {"node": 0, "path": "translation"}},
                {"sampler": 1, "target": {"node": 0, "path": "rotation"}},
                {"sampler": 2, "target": {"node": 0, "path": "weights"}},
                {"sampler": 3, "target": {"node": 3, "path": "rotation"}}
            ]
        }]);
    }
    serde_json::to_vec(&doc).expect("json")
}

fn write(name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("lumigraph-anim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write");
    path
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

#[test]
fn an_animated_scene_is_posed_exactly_at_every_frame() {
    let path = write("walk.gltf", &animated_gltf(true));
    let anim = load_animation(&path, None, 2.0).expect("animation");
    assert_eq!(anim.name, "walk");
    assert_eq!((anim.duration, anim.fps, anim.frames.len()), (1.0, 2.0, 3));
    // Box corners are vertices 0..8, the strip's 8..14.
    let boxed = |frame: usize, corner: usize| anim.frames[frame].positions[corner];
    let strip = |frame: usize, vertex: usize| anim.frames[frame].positions[8 + vertex];
    // t = 0: at rest.
    assert!(close(boxed(0, 7), [1.0, 1.0, 1.0]));
    assert!(close(strip(0, 5), [0.2, 2.0, 0.0]));
    // t = 0.5: moved 1 along x; turned 90° about y (the step key at 0.5 applies); morphed half
    // way (top corners +0.5 x before the turn). Corner 3 = (1, 1, 0) → (1.5, 1, 0) morphed,
    // turned about y: (x, z) → (z, −x) = (0, −1.5), then moved: (1, 1, −1.5).
    assert!(close(boxed(1, 3), [1.0, 1.0, -1.5]), "{:?}", boxed(1, 3));
    // Corner 0 stays at the node origin: (1, 0, 0).
    assert!(close(boxed(1, 0), [1.0, 0.0, 0.0]), "{:?}", boxed(1, 0));
    // The elbow at t = 0.5: the cubic spline with zero tangents is at smoothstep(0.5) = 0.5 of
    // the way, normalized: 45° about z. The strip's top (0.2, 2) turns about (0, 1).
    let angle = std::f32::consts::FRAC_PI_4;
    let turned = |x: f32, y: f32| {
        [
            x * angle.cos() - y * angle.sin(),
            1.0 + x * angle.sin() + y * angle.cos(),
            0.0,
        ]
    };
    assert!(
        close(strip(1, 5), turned(0.2, 1.0)),
        "{:?} vs {:?}",
        strip(1, 5),
        turned(0.2, 1.0)
    );
    // Rows on the root joint do not move.
    assert!(close(strip(1, 3), [0.2, 1.0, 0.0]));
    // t = 1: moved 2, fully morphed, the elbow at 90°: the top (0.2, 2) → (−1, 1.2).
    assert!(close(boxed(2, 3), [2.0, 1.0, -2.0]), "{:?}", boxed(2, 3));
    assert!(close(strip(2, 5), [-1.0, 1.2, 0.0]), "{:?}", strip(2, 5));
    // Asked by name, at another rate: 1 / 0.25 + 1 frames.
    let named = load_animation(&path, Some("walk"), 4.0).expect("animation");
    assert_eq!(named.frames.len(), 5);
    assert_eq!(named.frames[2].positions, anim.frames[1].positions);
}

#[test]
fn bad_animations_are_errors() {
    let path = write("walk-errors.gltf", &animated_gltf(true));
    let message = |r: Result<_, MeshError>| {
        r.map(|_: lumigraph_core::mesh::AnimationFrames| ())
            .expect_err("error")
            .to_string()
    };
    let m = message(load_animation(&path, Some("run"), 2.0));
    assert!(
        m.contains("no animation \"run\"") && m.contains("walk"),
        "{m}"
    );
    for fps in [0.0, -1.0, f64::NAN, f64::INFINITY, 5000.0] {
        let m = message(load_animation(&path, None, fps));
        assert!(m.contains("fps"), "{fps}: {m}");
    }
    // 1 s at 1000 fps: 1001 frames, more than an asset holds.
    let m = message(load_animation(&path, None, 1000.0));
    assert!(m.contains("frames") && m.contains("256"), "{m}");
    let still = write("still.gltf", &animated_gltf(false));
    let m = message(load_animation(&still, None, 2.0));
    assert!(m.contains("no animation"), "{m}");
    let off = write("box.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    let m = message(load_animation(&off, None, 2.0));
    assert!(m.contains("glTF"), "{m}");
    // Key times that go back are refused.
    let mut doc: serde_json::Value = serde_json::from_slice(&animated_gltf(true)).expect("json");
    // Key times read from a VEC4 accessor: refused.
    doc["animations"][0]["samplers"][0]["input"] =
        json!(doc["animations"][0]["samplers"][1]["output"]);
    let bad = write("bad-keys.gltf", &serde_json::to_vec(&doc).expect("json"));
    assert!(load_animation(&bad, None, 2.0).is_err());
}

#[test]
fn the_debian_samples_animate() {
    let fixtures = common::fixtures_dir();
    let cube = load_animation(&fixtures.join("anim/AnimatedMorphCube.gltf"), None, 4.0)
        .expect("morph cube");
    assert!(cube.frames.len() > 10, "{}", cube.frames.len());
    assert!(
        cube.frames
            .iter()
            .any(|f| f.positions != cube.frames[0].positions)
    );
    let skin = load_animation(&fixtures.join("anim/simple_skin.gltf"), None, 4.0).expect("skin");
    assert!(skin.frames.len() > 10, "{}", skin.frames.len());
    // The skin bends and comes back: some frame differs from the first, and the sphere of
    // every frame stays within a few times the first's.
    assert!(
        skin.frames
            .iter()
            .any(|f| f.positions != skin.frames[0].positions)
    );
    let r0 = skin.frames[0].bounding_sphere().radius;
    assert!(
        skin.frames
            .iter()
            .all(|f| f.bounding_sphere().radius < 3.0 * r0)
    );
}
