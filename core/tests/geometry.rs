//! Integration tests for `geometry`.

#![allow(
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::float_cmp,
    clippy::many_single_char_names,
    clippy::doc_markdown,
    clippy::manual_midpoint,
    reason = "test code: exact float comparisons and small casts are intentional"
)]

use glam::{DVec3, Vec2, Vec3};
use lumigraph_core::geometry::*;
use proptest::prelude::*;
use std::collections::{HashMap, HashSet};
use std::f64::consts::PI;

// ---------------------------------------------------------------------------
// helpers
// ---------------------------------------------------------------------------

/// Deterministic SplitMix64 RNG.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [-1, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
    /// Uniform direction on the sphere (rejection sampling).
    fn dir(&mut self) -> Vec3 {
        loop {
            let v = DVec3::new(self.unit(), self.unit(), self.unit());
            let l2 = v.length_squared();
            if l2 > 1e-4 && l2 <= 1.0 {
                return (v / l2.sqrt()).as_vec3();
            }
        }
    }
}

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

fn det3(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    a.dot(b.cross(c))
}

fn tri_pos(set: &CameraSet, t: usize) -> [DVec3; 3] {
    set.triangles[t].v.map(|i| d(set.positions[i as usize]))
}

/// Minimum raw edge determinant of unit `p` w.r.t. triangle `t`.
fn min_edge_det(set: &CameraSet, t: usize, p: DVec3) -> f64 {
    let [a, b, c] = tri_pos(set, t);
    det3(a, b, p).min(det3(b, c, p)).min(det3(c, a, p))
}

fn check_located(set: &CameraSet, dir: Vec3, level: u32, loc: &Located) {
    let range = set.level_range(level);
    let t = loc.triangle as usize;
    assert!(
        range.contains(&t),
        "triangle {t} not in level {level} range"
    );
    assert_eq!(loc.cameras, set.triangles[t].v);
    let p = d(dir).normalize();
    let m = min_edge_det(set, t, p);
    assert!(
        m >= -1e-6,
        "dir {dir:?} not inside triangle {t} (min det {m})"
    );
    let sum: f32 = loc.weights.iter().sum();
    assert!((sum - 1.0).abs() <= 1e-6, "weights sum {sum}");
    assert!(loc.weights.iter().all(|&w| w >= 0.0));
    let rec: DVec3 = (0..3)
        .map(|i| d(set.positions[loc.cameras[i] as usize]) * f64::from(loc.weights[i]))
        .sum();
    let err = (rec.normalize() - p).length();
    assert!(err <= 1e-5, "reconstruction error {err} for {dir:?}");
}

// ---------------------------------------------------------------------------
// camera sets
// ---------------------------------------------------------------------------

#[test]
fn counts_and_levels() {
    assert_eq!(CAMERA_COUNTS, [12, 42, 162, 642]);
    assert_eq!(MAX_LEVEL, 3);
    for (l, &n) in CAMERA_COUNTS.iter().enumerate() {
        assert_eq!(level_for_camera_count(n), Some(l as u32));
    }
    for n in [0, 1, 11, 13, 43, 641, 643, 2562, u32::MAX] {
        assert_eq!(level_for_camera_count(n), None);
    }
    let set = camera_set();
    assert!(std::ptr::eq(set, camera_set()), "camera_set must be shared");
    assert_eq!(set.positions.len(), 642);
    assert_eq!(set.triangles.len(), 1700);
    assert_eq!(set.level_range(0), 0..20);
    assert_eq!(set.level_range(1), 20..100);
    assert_eq!(set.level_range(2), 100..420);
    assert_eq!(set.level_range(3), 420..1700);
    assert_eq!(set.level_range(99), 420..1700, "levels clamp to MAX_LEVEL");
    for l in 0..=MAX_LEVEL {
        let n = CAMERA_COUNTS[l as usize] as usize;
        assert_eq!(set.positions_for_level(l).len(), n);
        assert_eq!(set.positions_for_level(l), &set.positions[..n]);
        assert_eq!(set.level_triangles(l).len(), 20 * 4usize.pow(l));
    }
    assert_eq!(std::mem::size_of::<HierTriangle>(), 16);
}

#[test]
fn level0_vertex_order_is_documented_icosahedron() {
    let phi = (1.0 + 5.0_f64.sqrt()) / 2.0;
    let expected = [
        (-1.0, phi, 0.0),
        (1.0, phi, 0.0),
        (-1.0, -phi, 0.0),
        (1.0, -phi, 0.0),
        (0.0, -1.0, phi),
        (0.0, 1.0, phi),
        (0.0, -1.0, -phi),
        (0.0, 1.0, -phi),
        (phi, 0.0, -1.0),
        (phi, 0.0, 1.0),
        (-phi, 0.0, -1.0),
        (-phi, 0.0, 1.0),
    ];
    let set = camera_set();
    for (i, &(x, y, z)) in expected.iter().enumerate() {
        let e = DVec3::new(x, y, z).normalize();
        assert!((d(set.positions[i]) - e).length() < 1e-7, "vertex {i}");
    }
}

#[test]
fn positions_unit_and_distinct() {
    let set = camera_set();
    for p in &set.positions {
        assert!((p.length() - 1.0).abs() < 1e-6);
    }
    let mut min = f32::INFINITY;
    for i in 0..set.positions.len() {
        for j in i + 1..set.positions.len() {
            min = min.min(set.positions[i].distance(set.positions[j]));
        }
    }
    assert!(min > 0.1, "min pairwise distance {min}");
}

#[test]
fn hierarchy_is_nested_and_consistent() {
    let set = camera_set();
    for l in 0..=MAX_LEVEL {
        let n = CAMERA_COUNTS[l as usize];
        for (j, t) in set.level_triangles(l).iter().enumerate() {
            assert!(
                t.v.iter().all(|&v| v < n),
                "level {l} tri uses vertex >= {n}"
            );
            if l == MAX_LEVEL {
                assert_eq!(t.first_child, NO_CHILD);
                assert_eq!(t.first_child, u32::MAX);
                continue;
            }
            let next = set.level_range(l + 1);
            let fc = t.first_child as usize;
            assert_eq!(
                fc,
                next.start + 4 * j,
                "children contiguous, in parent order"
            );
            let ch: Vec<[u32; 3]> = (fc..fc + 4).map(|c| set.triangles[c].v).collect();
            let [v0, v1, v2] = t.v;
            // corners of corner children are the parent's corners
            assert_eq!(ch[0][0], v0);
            assert_eq!(ch[1][1], v1);
            assert_eq!(ch[2][2], v2);
            let (m01, m12, m20) = (ch[0][1], ch[1][2], ch[0][2]);
            assert_eq!(ch[1][0], m01);
            assert_eq!(ch[2][0], m20);
            assert_eq!(ch[2][1], m12);
            assert_eq!(ch[3], [m01, m12, m20]);
            let n_next = CAMERA_COUNTS[l as usize + 1];
            for (m, a, b) in [(m01, v0, v1), (m12, v1, v2), (m20, v2, v0)] {
                assert!(
                    (n..n_next).contains(&m),
                    "midpoint {m} not new at level {}",
                    l + 1
                );
                let e = (d(set.positions[a as usize]) + d(set.positions[b as usize])).normalize();
                assert!((d(set.positions[m as usize]) - e).length() < 1e-6);
            }
        }
    }
}

#[test]
fn each_edge_midpoint_created_exactly_once() {
    let set = camera_set();
    for l in 0..MAX_LEVEL {
        let mut edge_mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut edge_uses: HashMap<(u32, u32), u32> = HashMap::new();
        for t in set.level_triangles(l) {
            let ch = set.triangles[t.first_child as usize].v;
            let mids = [(t.v[0], t.v[1], ch[1]), (t.v[2], t.v[0], ch[2])];
            let m12 = set.triangles[t.first_child as usize + 1].v[2];
            for (a, b, m) in mids.into_iter().chain([(t.v[1], t.v[2], m12)]) {
                let key = (a.min(b), a.max(b));
                *edge_uses.entry(key).or_default() += 1;
                if let Some(&old) = edge_mid.get(&key) {
                    assert_eq!(old, m, "edge {key:?} has two midpoints");
                } else {
                    edge_mid.insert(key, m);
                }
            }
        }
        assert!(edge_uses.values().all(|&c| c == 2), "closed manifold");
        let new: HashSet<u32> = edge_mid.values().copied().collect();
        let expected: HashSet<u32> =
            (CAMERA_COUNTS[l as usize]..CAMERA_COUNTS[l as usize + 1]).collect();
        assert_eq!(new.len(), edge_mid.len());
        assert_eq!(new, expected);
    }
}

#[test]
fn triangles_ccw_and_tile_sphere() {
    let set = camera_set();
    for l in 0..=MAX_LEVEL {
        let mut area = 0.0;
        for t in set.level_range(l) {
            let [a, b, c] = tri_pos(set, t);
            let det = det3(a, b, c);
            assert!(det > 0.0, "triangle {t} not CCW");
            // Van Oosterom–Strackee spherical excess
            area += 2.0 * det.atan2(1.0 + a.dot(b) + b.dot(c) + c.dot(a));
        }
        assert!((area - 4.0 * PI).abs() < 1e-4, "level {l} area {area}");
    }
}

// ---------------------------------------------------------------------------
// locate
// ---------------------------------------------------------------------------

#[test]
fn locate_matches_brute_force_random() {
    let set = camera_set();
    let mut rng = Rng(0x1234_5678);
    for _ in 0..20_000 {
        let dir = rng.dir();
        for l in 0..=MAX_LEVEL {
            let fast = set.locate(dir, l);
            let brute = set.locate_brute_force(dir, l);
            check_located(set, dir, l, &fast);
            check_located(set, dir, l, &brute);
            // Unless the point is (numerically) on a shared edge, the triangles agree.
            let p = d(dir).normalize();
            if min_edge_det(set, brute.triangle as usize, p) > 1e-6 {
                assert_eq!(fast.triangle, brute.triangle, "dir {dir:?} level {l}");
                assert_eq!(fast.weights, brute.weights);
            }
        }
    }
}

#[test]
fn locate_at_vertices() {
    let set = camera_set();
    for l in 0..=MAX_LEVEL {
        for (i, &p) in set.positions_for_level(l).iter().enumerate() {
            for dir in [p, p * 3.5, p * 1e-30, p * 1e30] {
                let loc = set.locate(dir, l);
                check_located(set, dir, l, &loc);
                let k = loc
                    .cameras
                    .iter()
                    .position(|&c| c as usize == i)
                    .unwrap_or_else(|| panic!("vertex {i} not among cameras at level {l}"));
                assert!(loc.weights[k] >= 1.0 - 1e-5, "weight {}", loc.weights[k]);
            }
        }
    }
}

#[test]
fn locate_at_edge_midpoints() {
    let set = camera_set();
    for l in 0..=MAX_LEVEL {
        for t in set.level_triangles(l) {
            for e in 0..3 {
                let (a, b) = (t.v[e], t.v[(e + 1) % 3]);
                let m = (d(set.positions[a as usize]) + d(set.positions[b as usize]))
                    .normalize()
                    .as_vec3();
                let loc = set.locate(m, l);
                check_located(set, m, l, &loc);
                let mut w = loc.weights;
                w.sort_by(f32::total_cmp);
                assert!(w[0] < 1e-5, "{w:?}");
                assert!(
                    (w[1] - 0.5).abs() < 1e-5 && (w[2] - 0.5).abs() < 1e-5,
                    "{w:?}"
                );
                // the two half weights belong to the edge's endpoints
                for (k, &c) in loc.cameras.iter().enumerate() {
                    if c != a && c != b {
                        assert!(loc.weights[k] < 1e-5);
                    }
                }
            }
        }
    }
}

#[test]
fn locate_scale_invariant_extremes() {
    let set = camera_set();
    let mut rng = Rng(99);
    for _ in 0..500 {
        let dir = rng.dir();
        for l in 0..=MAX_LEVEL {
            let base = set.locate(dir, l);
            for s in [1e-30_f32, 1e-20, 1e20, 1e30] {
                let loc = set.locate(dir * s, l);
                assert_eq!(loc.triangle, base.triangle);
                for k in 0..3 {
                    assert!((loc.weights[k] - base.weights[k]).abs() < 1e-6);
                }
            }
        }
    }
    // components straddling many orders of magnitude and subnormals
    for dir in [
        Vec3::new(1e-30, -1e-30, 1e-30),
        Vec3::new(1e30, 1e30, -1e30),
        Vec3::new(1e-40, 0.0, 0.0),
        Vec3::new(f32::MAX, f32::MAX, f32::MAX),
        Vec3::new(f32::MIN_POSITIVE, -f32::MAX, 1.0),
    ] {
        for l in 0..=MAX_LEVEL {
            check_located(set, dir, l, &set.locate(dir, l));
        }
    }
}

#[test]
fn locate_degenerate_inputs() {
    let set = camera_set();
    for dir in [
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::new(f32::NAN, 1.0, 0.0),
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(0.0, f32::NEG_INFINITY, 1.0),
    ] {
        for l in 0..=MAX_LEVEL + 2 {
            for loc in [set.locate(dir, l), set.locate_brute_force(dir, l)] {
                let start = set.level_range(l).start;
                assert_eq!(loc.triangle as usize, start);
                assert_eq!(loc.cameras, set.triangles[start].v);
                assert_eq!(loc.weights, [1.0, 0.0, 0.0]);
            }
        }
    }
    // Levels above MAX_LEVEL clamp.
    let dir = Vec3::new(0.3, -0.2, 0.9);
    assert_eq!(set.locate(dir, 7), set.locate(dir, MAX_LEVEL));
}

proptest! {
    #[test]
    fn prop_locate_valid(x in -1.0f32..1.0, y in -1.0f32..1.0, z in -1.0f32..1.0, l in 0u32..=3) {
        let dir = Vec3::new(x, y, z);
        prop_assume!(dir.length() > 1e-3);
        let set = camera_set();
        let loc = set.locate(dir, l);
        check_located(set, dir, l, &loc);
    }
}

// ---------------------------------------------------------------------------
// direction lookup
// ---------------------------------------------------------------------------

#[test]
fn octahedral_texels_round_trip_and_stay_within_reach() {
    // Every texel: its centre maps back to it (f32, as the shader computes it), and its corners
    // and edge midpoints (the farthest points of a texel; the map is continuous across the fold)
    // lie within DIRECTION_LOOKUP_REACH of its centre.
    let n = DIRECTION_LOOKUP_SIZE;
    let mut farthest = 0.0f64;
    for j in 0..n {
        for i in 0..n {
            let c = octahedral_direction(i, j, n);
            assert_eq!(octahedral_texel(c.as_vec3(), n), (i, j));
            for (di, dj) in [
                (0.0, 0.0),
                (0.5, 0.0),
                (1.0, 0.0),
                (0.0, 0.5),
                (1.0, 0.5),
                (0.0, 1.0),
                (0.5, 1.0),
                (1.0, 1.0),
            ] {
                let uv = glam::DVec2::new(
                    (f64::from(i) + di) / f64::from(n) * 2.0 - 1.0,
                    (f64::from(j) + dj) / f64::from(n) * 2.0 - 1.0,
                );
                farthest = farthest.max(c.angle_between(octahedral_unfold(uv)));
            }
        }
    }
    assert!(
        farthest <= DIRECTION_LOOKUP_REACH,
        "a texel reaches {farthest} rad from its centre"
    );
    assert!(
        farthest > 0.9 * DIRECTION_LOOKUP_REACH,
        "the bound {DIRECTION_LOOKUP_REACH} is loose: {farthest}"
    );
    // Degenerate directions still give a texel inside the map.
    for p in [
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::INFINITY,
        Vec3::new(f32::NEG_INFINITY, 0.0, 1.0),
    ] {
        let (i, j) = octahedral_texel(p, n);
        assert!(i < n && j < n);
    }
}

#[test]
fn direction_lookup_holds_each_texel_centres_triangle_and_its_ancestors() {
    let set = camera_set();
    let n = 256;
    let lookup = set.direction_lookup(n);
    assert_eq!(lookup.len(), (n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let c = octahedral_direction(i, j, n);
            let finest = u32::from(lookup[(j * n + i) as usize]);
            for level in 0..=MAX_LEVEL {
                let local = finest >> (2 * (MAX_LEVEL - level));
                let t = set.level_range(level).start + local as usize;
                assert!(set.level_range(level).contains(&t));
                assert!(
                    min_edge_det(set, t, c) >= -1e-9,
                    "texel ({i}, {j}): level {level} triangle {t} does not hold its centre"
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------
// camera frame
// ---------------------------------------------------------------------------

fn check_frame(p: Vec3) {
    let [x, y, z] = camera_frame(p);
    for v in [x, y, z] {
        assert!((v.length() - 1.0).abs() < 1e-6, "{p:?}");
    }
    assert!(x.dot(y).abs() < 1e-6 && y.dot(z).abs() < 1e-6 && z.dot(x).abs() < 1e-6);
    assert!((x.cross(y) - z).length() < 1e-6, "right-handed for {p:?}");
    assert!(
        (d(z) + d(p).normalize()).length() < 1e-6,
        "z = -normalize(p)"
    );
    assert_eq!(camera_frame(p), [x, y, z], "deterministic");
}

#[test]
fn camera_frames_all_cameras_and_axes() {
    for &p in &camera_set().positions {
        check_frame(p);
    }
    for p in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
        check_frame(p);
        check_frame(p * 1e-20);
    }
    // +z pole of the local frame is opposite the camera
    assert_eq!(camera_frame(Vec3::Z)[2], -Vec3::Z);
    // tie-breaking: p = -Z → z = +Z; x-axis is least aligned (tie x/y) → a = X
    let [x, y, _] = camera_frame(-Vec3::Z);
    assert!((x - Vec3::X.cross(Vec3::Z)).length() < 1e-7);
    assert!((y - Vec3::Z.cross(x)).length() < 1e-7);
    // degenerate
    assert_eq!(camera_frame(Vec3::ZERO), [Vec3::X, Vec3::Y, Vec3::Z]);
    assert_eq!(camera_frame(Vec3::NAN), [Vec3::X, Vec3::Y, Vec3::Z]);
}

proptest! {
    #[test]
    fn prop_camera_frame(x in -1.0f32..1.0, y in -1.0f32..1.0, z in -1.0f32..1.0) {
        let p = Vec3::new(x, y, z);
        prop_assume!(p.length() > 1e-3);
        check_frame(p);
    }
}

// ---------------------------------------------------------------------------
// parabolic map
// ---------------------------------------------------------------------------

proptest! {
    #[test]
    fn prop_parabolic_uv_round_trip(r in 0.0f32..=1.0, a in 0.0f32..std::f32::consts::TAU) {
        let uv = Vec2::new(r * a.cos(), r * a.sin());
        let back = parabolic_forward(parabolic_inverse(uv));
        prop_assert!((back - uv).length() <= 1e-6, "{uv:?} -> {back:?}");
    }

    #[test]
    fn prop_parabolic_dir_round_trip(x in -1.0f32..1.0, y in -1.0f32..1.0, z in 0.0f32..1.0) {
        let r = Vec3::new(x, y, z);
        prop_assume!(r.length() > 1e-3);
        let r = r.normalize();
        let uv = parabolic_forward(r);
        prop_assert!(uv.length() <= 1.0 + 1e-6);
        let back = parabolic_inverse(uv);
        prop_assert!((back - r).length() <= 1e-6, "{r:?} -> {back:?}");
    }

    #[test]
    fn prop_parabolic_inverse_unit(u in -1e4f32..1e4, v in -1e4f32..1e4) {
        let r = parabolic_inverse(Vec2::new(u, v));
        prop_assert!((r.length() - 1.0).abs() <= 1e-6);
        let inside = u * u + v * v <= 1.0;
        let ok = if inside { r.z >= 0.0 } else { r.z <= 1e-6 };
        prop_assert!(ok);
    }
}

#[test]
fn parabolic_rim_and_pole() {
    assert_eq!(parabolic_forward(Vec3::Z), Vec2::ZERO);
    assert!((parabolic_inverse(Vec2::ZERO) - Vec3::Z).length() < 1e-7);
    for k in 0..360 {
        let a = (k as f32).to_radians();
        // exact rim
        let r = Vec3::new(a.cos(), a.sin(), 0.0).normalize();
        let uv = parabolic_forward(r);
        assert!((uv.length() - 1.0).abs() < 1e-6);
        assert!((parabolic_inverse(uv) - r).length() < 1e-6);
        // approaching the rim
        for zz in [1e-3_f32, 1e-5, 1e-7] {
            let r = Vec3::new(a.cos(), a.sin(), zz).normalize();
            assert!((parabolic_inverse(parabolic_forward(r)) - r).length() < 1e-6);
        }
        let uv = Vec2::new(a.cos(), a.sin());
        assert!(parabolic_inverse(uv).z.abs() < 1e-6);
        assert!((parabolic_forward(parabolic_inverse(uv)) - uv).length() < 1e-6);
    }
    // outside the disk: r.z < 0, still unit and invertible
    let uv = Vec2::new(1.5, -0.5);
    let r = parabolic_inverse(uv);
    assert!(r.z < 0.0 && (r.length() - 1.0).abs() < 1e-6);
    assert!((parabolic_forward(r) - uv).length() < 1e-5);
    // extremes: finite results, no panic
    for uv in [
        Vec2::splat(1e30),
        Vec2::splat(f32::MAX),
        Vec2::new(f32::MAX, 0.0),
    ] {
        let r = parabolic_inverse(uv);
        assert!(
            r.is_finite() && (r.length() - 1.0).abs() < 1e-6,
            "{uv:?} -> {r:?}"
        );
    }
    assert!(parabolic_forward(-Vec3::Z).is_finite());
    assert!(parabolic_inverse(Vec2::NAN).is_nan());
}

#[test]
fn texel_mapping_round_trip() {
    assert_eq!(texel_center_uv(0, 0, 2), Vec2::new(-0.5, -0.5));
    assert_eq!(texel_center_uv(0, 1, 2), Vec2::new(0.5, -0.5));
    assert_eq!(texel_center_uv(1, 0, 2), Vec2::new(-0.5, 0.5));
    assert_eq!(texel_center_uv(0, 0, 1), Vec2::ZERO);
    assert_eq!(texel_center_uv(0, 0, 0), Vec2::ZERO, "n = 0 acts as 1");
    assert_eq!(uv_to_texel_coords(Vec2::new(-1.0, -1.0), 64), Vec2::ZERO);
    assert_eq!(
        uv_to_texel_coords(Vec2::new(1.0, 1.0), 64),
        Vec2::splat(64.0)
    );
    for n in [1u32, 2, 7, 64, 255, 1024, 4096] {
        let step = (n / 37).max(1);
        for a in (0..n).step_by(step as usize) {
            for b in (0..n).step_by(step as usize) {
                let uv = texel_center_uv(a, b, n);
                assert!(uv.x > -1.0 && uv.x < 1.0 && uv.y > -1.0 && uv.y < 1.0);
                let tc = uv_to_texel_coords(uv, n);
                let want = Vec2::new(b as f32 + 0.5, a as f32 + 0.5);
                let tol = 1e-6 * n as f32 + 1e-6;
                assert!(
                    (tc - want).abs().max_element() <= tol,
                    "n={n} a={a} b={b} {tc:?}"
                );
                assert_eq!(tc.floor(), Vec2::new(b as f32, a as f32));
            }
        }
    }
}

// ---------------------------------------------------------------------------
// depth encoding
// ---------------------------------------------------------------------------

proptest! {
    #[test]
    fn prop_depth_u16_error(dep in 0.0f32..0.9999) {
        let code = encode_depth_u16(dep);
        prop_assert!(code < NO_HIT_U16);
        let exact = (f64::from(code) / 65535.0 - f64::from(dep)).abs();
        prop_assert!(exact <= 0.5 / 65535.0 + 1e-15);
        let dec = (f64::from(decode_depth_u16(code)) - f64::from(dep)).abs();
        prop_assert!(dec <= 0.5 / 65535.0 + 1e-7);
    }

    #[test]
    fn prop_depth_u8_error(dep in 0.0f32..0.998) {
        let code = encode_depth_u8(dep);
        prop_assert!(code < NO_HIT_U8);
        let exact = (f64::from(code) / 255.0 - f64::from(dep)).abs();
        prop_assert!(exact <= 0.5 / 255.0 + 1e-12);
        let dec = (f64::from(decode_depth_u8(code)) - f64::from(dep)).abs();
        prop_assert!(dec <= 0.5 / 255.0 + 1e-7);
    }
}

#[test]
fn depth_codes() {
    assert_eq!(NO_HIT_U16, 65535);
    assert_eq!(NO_HIT_U8, 255);
    for miss in [
        1.0,
        1.0001,
        2.0,
        f32::MAX,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ] {
        assert_eq!(encode_depth_u16(miss), NO_HIT_U16, "{miss}");
        assert_eq!(encode_depth_u8(miss), NO_HIT_U8, "{miss}");
    }
    for neg in [-0.0, -1e-30, -0.5, -1e30, f32::MIN] {
        assert_eq!(encode_depth_u16(neg), 0);
        assert_eq!(encode_depth_u8(neg), 0);
    }
    assert_eq!(encode_depth_u16(0.0), 0);
    assert_eq!(encode_depth_u16(0.5), 32768);
    // just below the far sphere is still a hit
    assert_eq!(encode_depth_u16(1.0 - f32::EPSILON), 65534);
    assert_eq!(encode_depth_u8(0.999), 254);
    assert_eq!(decode_depth_u16(NO_HIT_U16), 1.0);
    assert_eq!(decode_depth_u8(NO_HIT_U8), 1.0);
    assert_eq!(decode_depth_u16(0), 0.0);
    assert!(decode_depth_u16(65534) < 1.0);
    assert!(decode_depth_u8(254) < 1.0);
    for v in 0..=65534u16 {
        assert_eq!(encode_depth_u16(decode_depth_u16(v)), v);
    }
    for v in 0..=254u8 {
        assert_eq!(encode_depth_u8(decode_depth_u8(v)), v);
    }
}

// ---------------------------------------------------------------------------
// intersections
// ---------------------------------------------------------------------------

fn on_sphere(o: DVec3, dir: DVec3, c: DVec3, r: f64, t: f64, tol: f64) {
    let dist = (o + dir * t - c).length();
    assert!((dist - r).abs() <= tol, "t={t} dist={dist} r={r}");
}

#[test]
fn ray_sphere_cases() {
    let c = DVec3::ZERO;
    // origin on the sphere
    assert_eq!(ray_sphere(DVec3::X, -DVec3::X, c, 1.0), Some((0.0, 2.0)));
    assert_eq!(ray_sphere(DVec3::X, DVec3::X, c, 1.0), Some((-2.0, 0.0)));
    // inside
    assert_eq!(ray_sphere(c, DVec3::Y, c, 1.0), Some((-1.0, 1.0)));
    assert_eq!(ray_sphere(c, DVec3::Y * 2.0, c, 1.0), Some((-0.5, 0.5)));
    // tangent / grazing
    let o = DVec3::new(-5.0, 1.0, 0.0);
    assert_eq!(ray_sphere(o, DVec3::X, c, 1.0), Some((5.0, 5.0)));
    assert_eq!(
        ray_sphere(DVec3::new(-5.0, 1.0 + 1e-9, 0.0), DVec3::X, c, 1.0),
        None
    );
    let (t0, t1) = ray_sphere(DVec3::new(-5.0, 1.0 - 1e-12, 0.0), DVec3::X, c, 1.0).unwrap();
    assert!(t0 <= t1 && (t0 - 5.0).abs() < 1e-5 && (t1 - 5.0).abs() < 1e-5);
    // tangent at the origin
    assert_eq!(ray_sphere(DVec3::Y, DVec3::X, c, 1.0), Some((0.0, 0.0)));
    // far away
    let o = DVec3::new(-1e6, 0.5, 0.0);
    let (t0, t1) = ray_sphere(o, DVec3::X, c, 1.0).unwrap();
    let h = 0.75_f64.sqrt();
    assert!(
        (t0 - (1e6 - h)).abs() < 1e-9 && (t1 - (1e6 + h)).abs() < 1e-9,
        "{t0} {t1}"
    );
    on_sphere(o, DVec3::X, c, 1.0, t0, 1e-9);
    on_sphere(o, DVec3::X, c, 1.0, t1, 1e-9);
    // far away, oblique, non-unit dir, offset centre
    let cc = DVec3::new(3.0, -2.0, 7.0);
    let o = cc + DVec3::new(1e6, -2e6, 5e5);
    let dir = ((cc + DVec3::new(0.1, 0.2, -0.3)) - o) * 1e-3;
    let (t0, t1) = ray_sphere(o, dir, cc, 1.0).unwrap();
    assert!(t0 < t1 && t0 > 0.0);
    on_sphere(o, dir, cc, 1.0, t0, 1e-8);
    on_sphere(o, dir, cc, 1.0, t1, 1e-8);
    // pointing away: both roots negative
    let (t0, t1) = ray_sphere(DVec3::new(0.0, 0.0, 3.0), DVec3::Z, c, 1.0).unwrap();
    assert_eq!((t0, t1), (-4.0, -2.0));
    // zero radius
    assert_eq!(ray_sphere(-DVec3::X, DVec3::X, c, 0.0), Some((1.0, 1.0)));
    // invalid input
    assert_eq!(ray_sphere(DVec3::NAN, DVec3::X, c, 1.0), None);
    assert_eq!(ray_sphere(c, DVec3::new(f64::NAN, 0.0, 0.0), c, 1.0), None);
    assert_eq!(ray_sphere(c, DVec3::X, DVec3::NAN, 1.0), None);
    assert_eq!(ray_sphere(c, DVec3::X, c, f64::NAN), None);
    assert_eq!(ray_sphere(c, DVec3::X, c, f64::INFINITY), None);
    assert_eq!(ray_sphere(c, DVec3::X, c, -1.0), None);
    assert_eq!(ray_sphere(c, DVec3::ZERO, c, 1.0), None);
    assert_eq!(
        ray_sphere(DVec3::splat(f64::INFINITY), DVec3::X, c, 1.0),
        None
    );
    // miss
    assert_eq!(
        ray_sphere(DVec3::new(0.0, 2.0, 0.0), DVec3::X, c, 1.0),
        None
    );
}

proptest! {
    #[test]
    fn prop_ray_sphere_roots_on_sphere(
        ox in -100.0f64..100.0, oy in -100.0f64..100.0, oz in -100.0f64..100.0,
        dx in -1.0f64..1.0, dy in -1.0f64..1.0, dz in -1.0f64..1.0,
        r in 0.01f64..50.0,
    ) {
        let o = DVec3::new(ox, oy, oz);
        let dir = DVec3::new(dx, dy, dz);
        prop_assume!(dir.length() > 1e-3);
        let c = DVec3::new(1.0, -2.0, 0.5);
        if let Some((t0, t1)) = ray_sphere(o, dir, c, r) {
            prop_assert!(t0 <= t1);
            let scale = (o - c).length() + r;
            for t in [t0, t1] {
                let dist = (o + dir * t - c).length();
                prop_assert!((dist - r).abs() <= 1e-9 * scale, "dist {} r {}", dist, r);
            }
        } else {
            // a miss means the line's distance to the centre exceeds the radius
            let oc = o - c;
            let l = oc - dir * (oc.dot(dir) / dir.length_squared());
            prop_assert!(l.length() >= r * (1.0 - 1e-12));
        }
    }

    #[test]
    fn prop_chord_length(u in -1.0f32..1.0, v in -1.0f32..1.0, cam in 0usize..642) {
        let uv = Vec2::new(u, v);
        prop_assume!(uv.length() <= 1.0);
        let p = camera_set().positions[cam];
        let [x, y, z] = camera_frame(p);
        let r = parabolic_inverse(uv);
        let w = x * r.x + y * r.y + z * r.z;
        let t = chord_length(p, w);
        // hemisphere opposite the camera: chord = 2 r.z >= 0
        prop_assert!(t >= -1e-6);
        prop_assert!((t - 2.0 * r.z).abs() < 1e-5);
        prop_assert!(((p + w * t).length() - 1.0).abs() < 1e-5);
        // Sum of the two line/sphere roots is -2 p·w / |w|² (robust to p, w being
        // unit only up to f32 rounding, which shifts individual tiny roots).
        if let Some((t0, t1)) = ray_sphere(d(p), d(w), DVec3::ZERO, 1.0) {
            let sum = (t0 + t1) * d(w).length_squared();
            prop_assert!((f64::from(t) - sum).abs() < 1e-6, "t {} roots {} {}", t, t0, t1);
        }
    }
}
