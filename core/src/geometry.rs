//! Sphere geometry for the light-field camera rig.
//!
//! This module contains the purely geometric building blocks of lumigraph:
//!
//! * **Nested icosphere camera sets** ([`CameraSet`], [`camera_set`]): camera
//!   positions on the unit sphere at subdivision levels `0..=MAX_LEVEL` with
//!   12, 42, 162 and 642 cameras. The level-`L` camera set is always a prefix of
//!   the level-`L+1` set, and the spherical triangles of every level form a
//!   hierarchy (each triangle has four contiguous children).
//! * **Triangle lookup** ([`CameraSet::locate`]): find the camera triangle that
//!   contains a direction and the central-projection barycentric weights of its
//!   three cameras.
//! * **Camera local frames** ([`camera_frame`]) and the **parabolic map**
//!   ([`parabolic_forward`], [`parabolic_inverse`]) that parameterises the
//!   hemisphere seen by a camera, plus texel/uv conversion helpers.
//! * **Depth encoding** ([`encode_depth_u16`], [`decode_depth_u16`] and the `u8`
//!   variants) with a reserved "no hit" code.
//! * **Ray/sphere intersection** ([`ray_sphere`]) and the chord helper
//!   ([`chord_length`]).
//!
//! Conventions: GPU-facing data is `f32` ([`Vec3`], [`Vec2`]); construction and
//! intersection code that needs precision works in `f64` ([`DVec3`]).
//! Functions never panic on user input; degenerate inputs (zero or non-finite
//! vectors, out-of-range levels) produce documented, defined results.

#![allow(
    clippy::many_single_char_names,
    reason = "geometry code follows the usual math notation"
)]

use std::collections::HashMap;
use std::ops::Range;
use std::sync::OnceLock;

use glam::{DVec2, DVec3, Vec2, Vec3};

// ---------------------------------------------------------------------------
// Camera sets
// ---------------------------------------------------------------------------

/// Number of cameras (sphere vertices) at each subdivision level `0..=MAX_LEVEL`.
pub const CAMERA_COUNTS: [u32; 4] = [12, 42, 162, 642];

/// Highest supported subdivision level.
pub const MAX_LEVEL: u32 = 3;

/// Number of spherical triangles at each subdivision level (`20 * 4^level`).
pub const TRIANGLE_COUNTS: [u32; 4] = [20, 80, 320, 1280];

/// Sentinel stored in [`HierTriangle::first_child`] for leaf triangles
/// (all triangles of level [`MAX_LEVEL`]).
pub const NO_CHILD: u32 = u32::MAX;

/// Returns the subdivision level whose camera set has exactly `n` cameras, or
/// `None` if `n` is not one of [`CAMERA_COUNTS`].
#[must_use]
pub fn level_for_camera_count(n: u32) -> Option<u32> {
    CAMERA_COUNTS
        .iter()
        .position(|&c| c == n)
        .and_then(|i| u32::try_from(i).ok())
}

/// One spherical triangle of the camera hierarchy (GPU-compatible layout, 16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HierTriangle {
    /// Indices into [`CameraSet::positions`] of the three corners, counter-clockwise
    /// seen from outside the sphere (`det(v0, v1, v2) > 0`).
    pub v: [u32; 3],
    /// Index into [`CameraSet::triangles`] of the first of the four contiguous
    /// children, or [`NO_CHILD`] (`u32::MAX`) for leaves at level [`MAX_LEVEL`].
    ///
    /// For a triangle `(v0, v1, v2)` with edge midpoints `m01`, `m12`, `m20`
    /// the children are, in order: `(v0, m01, m20)`, `(m01, v1, m12)`,
    /// `(m20, m12, v2)` (the three corner children) and `(m01, m12, m20)`
    /// (the middle child).
    pub first_child: u32,
}

/// Result of [`CameraSet::locate`]: the containing triangle and camera weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Located {
    /// Index into [`CameraSet::triangles`] (inside the requested level's range).
    pub triangle: u32,
    /// Camera indices (indices into [`CameraSet::positions`]), equal to the
    /// triangle's `v`.
    pub cameras: [u32; 3],
    /// Central-projection barycentric weights of `cameras`: non-negative and
    /// summing to 1.
    pub weights: [f32; 3],
}

/// The nested icosphere camera sets and their triangle hierarchy.
///
/// Obtain the shared instance with [`camera_set`].
///
/// # Vertex order
///
/// The 12 level-0 cameras are the normalised icosahedron vertices, with
/// `φ = (1 + √5) / 2`, in this fixed order:
///
/// | index | vertex | index | vertex | index | vertex |
/// |---|---|---|---|---|---|
/// | 0 | `(-1,  φ, 0)` | 4 | `(0, -1,  φ)` | 8  | `( φ, 0, -1)` |
/// | 1 | `( 1,  φ, 0)` | 5 | `(0,  1,  φ)` | 9  | `( φ, 0,  1)` |
/// | 2 | `(-1, -φ, 0)` | 6 | `(0, -1, -φ)` | 10 | `(-φ, 0, -1)` |
/// | 3 | `( 1, -φ, 0)` | 7 | `(0,  1, -φ)` | 11 | `(-φ, 0,  1)` |
///
/// Level `L + 1` appends the normalised midpoints of the level-`L` edges: the
/// level-`L` triangles are visited in order and, for each, the edges
/// `v0–v1`, `v1–v2`, `v2–v0` in that order; a midpoint is appended the first
/// time its edge is seen (each edge midpoint is created exactly once).
/// Midpoints are computed in `f64` from the `f64` parent positions and then
/// cast to `f32`.
#[derive(Debug, Clone)]
pub struct CameraSet {
    /// All 642 camera positions (unit vectors). The level-`L` set is the first
    /// `CAMERA_COUNTS[L]` entries.
    pub positions: Vec<Vec3>,
    /// All 1700 triangles of all levels; level `L` occupies
    /// [`CameraSet::level_range`]`(L)`.
    pub triangles: Vec<HierTriangle>,
    /// Double-precision positions (same order as `positions`).
    positions_f64: Vec<DVec3>,
    /// Unit inward edge normals per triangle: `normalize(v0×v1)`,
    /// `normalize(v1×v2)`, `normalize(v2×v0)`.
    edge_normals: Vec<[DVec3; 3]>,
}

/// Returns the lazily built, shared [`CameraSet`].
#[must_use]
pub fn camera_set() -> &'static CameraSet {
    static SET: OnceLock<CameraSet> = OnceLock::new();
    SET.get_or_init(CameraSet::build)
}

/// The unnormalised icosahedron vertices in the documented order.
fn icosahedron_vertices() -> [DVec3; 12] {
    let phi = f64::midpoint(1.0, 5.0_f64.sqrt());
    [
        DVec3::new(-1.0, phi, 0.0),
        DVec3::new(1.0, phi, 0.0),
        DVec3::new(-1.0, -phi, 0.0),
        DVec3::new(1.0, -phi, 0.0),
        DVec3::new(0.0, -1.0, phi),
        DVec3::new(0.0, 1.0, phi),
        DVec3::new(0.0, -1.0, -phi),
        DVec3::new(0.0, 1.0, -phi),
        DVec3::new(phi, 0.0, -1.0),
        DVec3::new(phi, 0.0, 1.0),
        DVec3::new(-phi, 0.0, -1.0),
        DVec3::new(-phi, 0.0, 1.0),
    ]
}

/// The 20 icosahedron faces (counter-clockwise from outside for the vertex
/// order of [`icosahedron_vertices`]).
const ICOSAHEDRON_FACES: [[u32; 3]; 20] = [
    [0, 11, 5],
    [0, 5, 1],
    [0, 1, 7],
    [0, 7, 10],
    [0, 10, 11],
    [1, 5, 9],
    [5, 11, 4],
    [11, 10, 2],
    [10, 7, 6],
    [7, 1, 8],
    [3, 9, 4],
    [3, 4, 2],
    [3, 2, 6],
    [3, 6, 8],
    [3, 8, 9],
    [4, 9, 5],
    [2, 4, 11],
    [6, 2, 10],
    [8, 6, 7],
    [9, 8, 1],
];

/// Scalar triple product `det(a, b, c) = a · (b × c)`.
#[inline]
fn det3(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    a.dot(b.cross(c))
}

/// Clamps a level to `0..=MAX_LEVEL` and returns it as an index.
#[inline]
fn level_index(level: u32) -> usize {
    // MAX_LEVEL is 3, so the clamped value always fits in usize.
    level.min(MAX_LEVEL) as usize
}

impl CameraSet {
    /// Builds the full hierarchy (called once by [`camera_set`]).
    #[allow(
        clippy::cast_possible_truncation,
        reason = "all counts are bounded by 1700 triangles / 642 vertices"
    )]
    fn build() -> Self {
        let mut pos: Vec<DVec3> = icosahedron_vertices()
            .iter()
            .map(|v| v.normalize())
            .collect();
        pos.reserve(CAMERA_COUNTS[MAX_LEVEL as usize] as usize - pos.len());

        let total_tris: usize = TRIANGLE_COUNTS.iter().map(|&c| c as usize).sum();
        let mut tris: Vec<HierTriangle> = Vec::with_capacity(total_tris);
        for f in ICOSAHEDRON_FACES {
            let mut v = f;
            // Defensive: enforce counter-clockwise winding from outside.
            if det3(pos[v[0] as usize], pos[v[1] as usize], pos[v[2] as usize]) < 0.0 {
                v.swap(1, 2);
            }
            tris.push(HierTriangle {
                v,
                first_child: NO_CHILD,
            });
        }

        let mut level_start = 0usize;
        for level in 0..MAX_LEVEL as usize {
            let level_end = level_start + TRIANGLE_COUNTS[level] as usize;
            let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
            let mut midpoint = |a: u32, b: u32, pos: &mut Vec<DVec3>| -> u32 {
                let key = (a.min(b), a.max(b));
                *midpoints.entry(key).or_insert_with(|| {
                    let m = (pos[a as usize] + pos[b as usize]).normalize();
                    pos.push(m);
                    (pos.len() - 1) as u32
                })
            };
            for t in level_start..level_end {
                let [v0, v1, v2] = tris[t].v;
                let m01 = midpoint(v0, v1, &mut pos);
                let m12 = midpoint(v1, v2, &mut pos);
                let m20 = midpoint(v2, v0, &mut pos);
                tris[t].first_child = tris.len() as u32;
                for v in [
                    [v0, m01, m20],
                    [m01, v1, m12],
                    [m20, m12, v2],
                    [m01, m12, m20],
                ] {
                    tris.push(HierTriangle {
                        v,
                        first_child: NO_CHILD,
                    });
                }
            }
            debug_assert_eq!(pos.len(), CAMERA_COUNTS[level + 1] as usize);
            level_start = level_end;
        }

        let edge_normals = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.v.map(|i| pos[i as usize]);
                [
                    a.cross(b).normalize(),
                    b.cross(c).normalize(),
                    c.cross(a).normalize(),
                ]
            })
            .collect();

        Self {
            positions: pos.iter().map(|p| p.as_vec3()).collect(),
            triangles: tris,
            positions_f64: pos,
            edge_normals,
        }
    }

    /// Range of [`CameraSet::triangles`] holding the triangles of `level`
    /// (level 0: `0..20`, 1: `20..100`, 2: `100..420`, 3: `420..1700`).
    ///
    /// Levels above [`MAX_LEVEL`] are clamped to [`MAX_LEVEL`].
    #[must_use]
    pub fn level_range(&self, level: u32) -> Range<usize> {
        let l = level_index(level);
        let start: usize = TRIANGLE_COUNTS[..l].iter().map(|&c| c as usize).sum();
        start..start + TRIANGLE_COUNTS[l] as usize
    }

    /// The camera positions of `level` (the first `CAMERA_COUNTS[level]`
    /// positions). Levels above [`MAX_LEVEL`] are clamped to [`MAX_LEVEL`].
    #[must_use]
    pub fn positions_for_level(&self, level: u32) -> &[Vec3] {
        &self.positions[..CAMERA_COUNTS[level_index(level)] as usize]
    }

    /// The triangles of `level`. Levels above [`MAX_LEVEL`] are clamped to
    /// [`MAX_LEVEL`].
    #[must_use]
    pub fn level_triangles(&self, level: u32) -> &[HierTriangle] {
        &self.triangles[self.level_range(level)]
    }

    /// Containment score of unit direction `p` for triangle `t`: the minimum
    /// over the three edges of the sine of the signed angular distance to the
    /// edge's great circle. Non-negative iff `p` is inside (or on the boundary).
    #[inline]
    fn score(&self, t: usize, p: DVec3) -> f64 {
        let [n0, n1, n2] = self.edge_normals[t];
        n0.dot(p).min(n1.dot(p)).min(n2.dot(p))
    }

    /// Builds the [`Located`] result for triangle `t` and unit direction `p`.
    #[allow(
        clippy::cast_possible_truncation,
        reason = "triangle indices are < 1700; weights are intentionally narrowed to f32"
    )]
    fn located(&self, t: usize, p: DVec3) -> Located {
        let tri = self.triangles[t];
        let [a, b, c] = tri.v.map(|i| self.positions_f64[i as usize]);
        let raw = [det3(p, b, c), det3(a, p, c), det3(a, b, p)].map(|w| w.max(0.0));
        let sum = raw[0] + raw[1] + raw[2];
        let weights = if sum > 0.0 && sum.is_finite() {
            raw.map(|w| (w / sum) as f32)
        } else {
            // Unreachable for a containing triangle; fall back to the nearest corner.
            let d = [a.dot(p), b.dot(p), c.dot(p)];
            let mut best = 0;
            for i in 1..3 {
                if d[i] > d[best] {
                    best = i;
                }
            }
            let mut w = [0.0; 3];
            w[best] = 1.0;
            w
        };
        Located {
            triangle: t as u32,
            cameras: tri.v,
            weights,
        }
    }

    /// Result returned for degenerate directions: the first triangle of the
    /// level with all weight on its first camera.
    fn degenerate(&self, level: u32) -> Located {
        let t = self.level_range(level).start;
        let tri = self.triangles[t];
        Located {
            // t < 1700, always fits.
            triangle: u32::try_from(t).unwrap_or(0),
            cameras: tri.v,
            weights: [1.0, 0.0, 0.0],
        }
    }

    /// Normalises `dir` in `f64`; `None` for zero, subnormal-underflowing or
    /// non-finite directions.
    fn unit_dir(dir: Vec3) -> Option<DVec3> {
        let d = dir.as_dvec3();
        if !d.is_finite() {
            return None;
        }
        let len = d.length();
        (len > 0.0 && len.is_finite()).then(|| d / len)
    }

    /// Finds the triangle of `level` containing direction `dir` and the
    /// central-projection barycentric weights of its three cameras.
    ///
    /// The search descends the hierarchy from the 20 level-0 triangles; at each
    /// step the candidate whose minimum (normalised) signed edge test is largest
    /// is chosen, so directions on edges or vertices and tiny rounding errors
    /// always yield a triangle.
    ///
    /// Weights are `w_i ∝ (det(p,v1,v2), det(v0,p,v2), det(v0,v1,p))`, clamped to
    /// `≥ 0` and normalised to sum to 1; hence `Σ w_i v_i` is parallel to `dir`.
    ///
    /// `dir` need not be normalised (any finite non-zero magnitude works,
    /// including subnormal or huge components). If `dir` is zero or has a NaN
    /// or infinite component, the result is the first triangle of the level
    /// (`level_range(level).start`) with weights `[1, 0, 0]`.
    /// Levels above [`MAX_LEVEL`] are clamped to [`MAX_LEVEL`].
    #[must_use]
    pub fn locate(&self, dir: Vec3, level: u32) -> Located {
        let Some(p) = Self::unit_dir(dir) else {
            return self.degenerate(level);
        };
        let target = level_index(level);
        let mut candidates = 0..TRIANGLE_COUNTS[0] as usize;
        let mut best = 0;
        for l in 0..=target {
            let mut best_score = f64::NEG_INFINITY;
            best = candidates.start;
            for t in candidates.clone() {
                let s = self.score(t, p);
                if s > best_score {
                    best_score = s;
                    best = t;
                }
            }
            if l < target {
                let first = self.triangles[best].first_child as usize;
                candidates = first..first + 4;
            }
        }
        self.located(best, p)
    }

    /// Same contract as [`CameraSet::locate`], but tests every triangle of the
    /// level and picks the one with the largest containment score. Intended
    /// for tests and validation (O(number of triangles)).
    #[must_use]
    pub fn locate_brute_force(&self, dir: Vec3, level: u32) -> Located {
        let Some(p) = Self::unit_dir(dir) else {
            return self.degenerate(level);
        };
        let range = self.level_range(level);
        let mut best = range.start;
        let mut best_score = f64::NEG_INFINITY;
        for t in range {
            let s = self.score(t, p);
            if s > best_score {
                best_score = s;
                best = t;
            }
        }
        self.located(best, p)
    }
}

// ---------------------------------------------------------------------------
// Direction lookup (the marcher's triangle search)
// ---------------------------------------------------------------------------

/// Texels per side of the marcher's octahedral direction lookup
/// ([`CameraSet::direction_lookup`]): 1024² texels of 2 bytes (2 MiB); no direction lies more
/// than [`DIRECTION_LOOKUP_REACH`] from its texel's centre. (512² renders as fast on lavapipe
/// but doubles the reach.)
pub const DIRECTION_LOOKUP_SIZE: u32 = 1024;

/// An upper bound on the angle (radians) between a direction and the centre of the
/// [`DIRECTION_LOOKUP_SIZE`]² octahedral texel holding it: half a texel's diagonal where the
/// map stretches most, 0.00414 measured (the tests check it over every texel's corners and
/// edge midpoints).
pub const DIRECTION_LOOKUP_REACH: f64 = 0.0042;

/// The unit direction at the centre of texel `(i, j)` of an `n` × `n` octahedral map: the
/// square `[-1, 1]²` holds the upper hemisphere (z ≥ 0) as the octahedron `|x| + |y| + z = 1`
/// inside its diamond `|u| + |v| ≤ 1`, and the lower one folded out into its four corners.
#[must_use]
pub fn octahedral_direction(i: u32, j: u32, n: u32) -> DVec3 {
    let n = f64::from(n.max(1));
    octahedral_unfold(DVec2::new(
        (f64::from(i) + 0.5) / n * 2.0 - 1.0,
        (f64::from(j) + 0.5) / n * 2.0 - 1.0,
    ))
}

/// The unit direction at point `uv` of the octahedral square `[-1, 1]²`.
#[must_use]
pub fn octahedral_unfold(uv: DVec2) -> DVec3 {
    let z = 1.0 - uv.x.abs() - uv.y.abs();
    let sign = |x: f64| if x >= 0.0 { 1.0 } else { -1.0 };
    let (x, y) = if z < 0.0 {
        (
            (1.0 - uv.y.abs()) * sign(uv.x),
            (1.0 - uv.x.abs()) * sign(uv.y),
        )
    } else {
        (uv.x, uv.y)
    };
    DVec3::new(x, y, z).normalize()
}

/// The texel `(i, j)` of an `n` × `n` octahedral map holding direction `p`, computed as the
/// marcher does (`locate` in `shaders/shared/lightfield.wgsl`), in `f32`. Zero and non-finite
/// directions give some texel inside the map.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss,
    reason = "the texel is clamped to the map before the conversion"
)]
pub fn octahedral_texel(p: Vec3, n: u32) -> (u32, u32) {
    let q = p / (p.x.abs() + p.y.abs() + p.z.abs()).max(1e-30);
    let sign = |x: f32| if x >= 0.0 { 1.0 } else { -1.0 };
    let uv = if q.z < 0.0 {
        Vec2::new((1.0 - q.y.abs()) * sign(q.x), (1.0 - q.x.abs()) * sign(q.y))
    } else {
        Vec2::new(q.x, q.y)
    };
    let last = n.max(1) - 1;
    let texel = |c: f32| {
        let t = ((c * 0.5 + 0.5) * n as f32).floor();
        if t.is_nan() {
            0
        } else {
            (t.max(0.0) as u32).min(last)
        }
    };
    (texel(uv.x), texel(uv.y))
}

impl CameraSet {
    /// The marcher's triangle lookup: for each texel of an `n` × `n` octahedral map of
    /// directions ([`octahedral_direction`]), row by row, the index within level
    /// [`MAX_LEVEL`] of the triangle holding the texel's centre. Its ancestor at level `l` is
    /// triangle `index >> 2 (MAX_LEVEL − l)` of that level (the children of triangle `k` of a
    /// level are triangles `4k..4k + 4` of the next).
    ///
    /// One texel load replaces the marcher's descent of the hierarchy, which read three edge
    /// normals per level. A direction less than [`DIRECTION_LOOKUP_REACH`] from a triangle's
    /// edge may find the neighbour across it; its weights there, clamped to the edge, differ
    /// from the exact ones by at most about that distance over the triangle's height (the
    /// tests bound it).
    #[must_use]
    #[allow(
        clippy::cast_possible_truncation,
        reason = "level-3 triangle indices are < 1280"
    )]
    pub fn direction_lookup(&self, n: u32) -> Vec<u16> {
        let range = self.level_range(MAX_LEVEL);
        let mut out = Vec::with_capacity((n as usize) * (n as usize));
        // Neighbouring texels mostly share a triangle: try the previous one first.
        let mut last: Option<usize> = None;
        for j in 0..n {
            for i in 0..n {
                let p = octahedral_direction(i, j, n);
                let t = match last {
                    Some(t) if self.score(t, p) > 1e-9 => t,
                    _ => self.locate(p.as_vec3(), MAX_LEVEL).triangle as usize,
                };
                last = Some(t);
                out.push((t - range.start) as u16);
            }
        }
        out
    }
}

// ---------------------------------------------------------------------------
// Camera local frame
// ---------------------------------------------------------------------------

/// Local frame `[x, y, z]` of the camera at position `p` (need not be unit).
///
/// * `z = -normalize(p)`: the hemisphere opposite the camera (looking through
///   the sphere's centre) is the `+z` pole of the local frame.
/// * `x = normalize(cross(a, z))` where `a` is the world axis least aligned
///   with `z` (smallest `|z_i|`; ties prefer x, then y, then z). Since
///   `|z_a| ≤ 1/√3`, the cross product is always well-conditioned.
/// * `y = cross(z, x)`.
///
/// The frame is orthonormal and right-handed (`cross(x, y) = z`). It is
/// computed in `f64` and is a deterministic function of `p`. For a zero or
/// non-finite `p` the world frame `[X, Y, Z]` is returned.
#[must_use]
pub fn camera_frame(p: Vec3) -> [Vec3; 3] {
    let d = p.as_dvec3();
    let len = d.length();
    if !(d.is_finite() && len > 0.0 && len.is_finite()) {
        return [Vec3::X, Vec3::Y, Vec3::Z];
    }
    let z = -d / len;
    let axis = [DVec3::X, DVec3::Y, DVec3::Z][camera_frame_axis(p)];
    let x = axis.cross(z).normalize();
    let y = z.cross(x);
    [x.as_vec3(), y.as_vec3(), z.as_vec3()]
}

/// The world axis (0 = x, 1 = y, 2 = z) that [`camera_frame`] crosses with the camera's `z`
/// at position `p`: the one least aligned with it, ties broken in f64 as there. The marcher
/// derives each frame from the position and this index (shared/lightfield.wgsl `camera`), so a tie
/// that f32 would break otherwise cannot give it another frame. 0 for a zero or non-finite
/// `p`.
#[must_use]
pub fn camera_frame_axis(p: Vec3) -> usize {
    let d = p.as_dvec3();
    let len = d.length();
    if !(d.is_finite() && len > 0.0 && len.is_finite()) {
        return 0;
    }
    let az = (-d / len).abs();
    if az.x <= az.y && az.x <= az.z {
        0
    } else if az.y <= az.z {
        1
    } else {
        2
    }
}

// ---------------------------------------------------------------------------
// Parabolic map
// ---------------------------------------------------------------------------

/// Smallest denominator `1 + r.z` used by [`parabolic_forward`].
pub const PARABOLIC_EPS: f32 = 1e-6;

/// Parabolic map of a unit local-frame direction `r` to `uv`:
/// `(r.x, r.y) / (1 + r.z)`.
///
/// The hemisphere `r.z ≥ 0` maps into the closed unit disk (pole → origin,
/// rim `r.z = 0` → unit circle). Directions with `r.z < 0` map outside the
/// disk and remain well defined while `1 + r.z > PARABOLIC_EPS`; below that the
/// denominator is clamped to [`PARABOLIC_EPS`], so the result is finite (but
/// meaningless) for finite input. `r` is assumed unit length (not normalised
/// here). Computed in `f64`.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn parabolic_forward(r: Vec3) -> Vec2 {
    let r = r.as_dvec3();
    let denom = (1.0 + r.z).max(f64::from(PARABOLIC_EPS));
    Vec2::new((r.x / denom) as f32, (r.y / denom) as f32)
}

/// Inverse parabolic map: `uv` to the unit local-frame direction
/// `r_z = (1 − u² − v²) / (1 + u² + v²)`, `r_x = u (1 + r_z)`, `r_y = v (1 + r_z)`.
///
/// Continuous on the whole plane; points outside the unit disk give `r_z < 0`
/// (tending to `-z` at infinity). The result is unit length for every finite
/// `uv` (computed in `f64`). NaN input gives NaN output.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn parabolic_inverse(uv: Vec2) -> Vec3 {
    let uv: DVec2 = uv.as_dvec2();
    let s = uv.length_squared();
    let inv = 1.0 / (1.0 + s);
    // 1 + r_z = 2 / (1 + s), which avoids cancellation near the rim.
    let rz = (1.0 - s) * inv;
    let k = 2.0 * inv;
    let r = DVec3::new(uv.x * k, uv.y * k, rz);
    // Re-normalise to remove the last rounding error (and keep the unit-length
    // guarantee after narrowing to f32).
    let len = r.length();
    if len > 0.0 && len.is_finite() {
        (r / len).as_vec3()
    } else {
        r.as_vec3()
    }
}

/// The 4-neighbours of texel `i` (row-major) of an `n×n` map that lie inside it, in the order
/// +x, −x, +y, −y (the directions of the bake's `cs_edges` pairs).
pub(crate) fn texel_neighbours(i: usize, n: usize) -> [Option<usize>; 4] {
    let (x, y) = (i % n, i / n);
    [
        (x + 1 < n).then(|| i + 1),
        (x > 0).then(|| i - 1),
        (y + 1 < n).then(|| i + n),
        (y > 0).then(|| i - n),
    ]
}

/// `uv` of the centre of texel (row `a`, column `b`) of an `n × n` parabolic
/// map: `u = (b + 0.5) / n · 2 − 1`, `v = (a + 0.5) / n · 2 − 1`.
///
/// `n = 0` is treated as `n = 1`.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn texel_center_uv(a: u32, b: u32, n: u32) -> Vec2 {
    let n = f64::from(n.max(1));
    let u = (f64::from(b) + 0.5) / n * 2.0 - 1.0;
    let v = (f64::from(a) + 0.5) / n * 2.0 - 1.0;
    Vec2::new(u as f32, v as f32)
}

/// Continuous texel coordinates of `uv` in an `n × n` map:
/// `x = (u + 1) / 2 · n` (column axis), `y = (v + 1) / 2 · n` (row axis), so
/// the centre of texel (row `a`, column `b`) is at `(b + 0.5, a + 0.5)`.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn uv_to_texel_coords(uv: Vec2, n: u32) -> Vec2 {
    let n = f64::from(n);
    let uv = uv.as_dvec2();
    Vec2::new(
        ((uv.x + 1.0) * 0.5 * n) as f32,
        ((uv.y + 1.0) * 0.5 * n) as f32,
    )
}

// ---------------------------------------------------------------------------
// Depth encoding
// ---------------------------------------------------------------------------

/// 16-bit depth code reserved for "no hit".
pub const NO_HIT_U16: u16 = u16::MAX;
/// 8-bit depth code reserved for "no hit".
pub const NO_HIT_U8: u8 = u8::MAX;

/// Shared quantiser: `min(round(max(d, 0) · scale), scale − 1)` for hits, `None` for no hit.
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "value is rounded and clamped to 0..=max_hit before the cast"
)]
fn quantise_depth(d: f32, scale: f64) -> Option<u32> {
    if !d.is_finite() || d >= 1.0 {
        return None;
    }
    let q = (f64::from(d).max(0.0) * scale).round().min(scale - 1.0);
    Some(q as u32)
}

/// Encodes a normalised depth `d` (`|hit − p| / |r − p|`, 0 = at the camera,
/// 1 = at the far sphere) to 16 bits.
///
/// Hits `d ∈ [0, 1)` map to `min(round(d · 65535), 65534)` (negative values clamp to 0);
/// "no hit" — `d ≥ 1`, NaN or ±∞ — maps to [`NO_HIT_U16`] (65535), as `docs/format.md` §8.4
/// specifies. Decoding is the plain unorm `v / 65535`, so a GPU `R16Unorm` texture reads the
/// same value. Clamping hits below 65535 keeps the maximum code for misses only. The
/// quantisation error for hits is at most `0.5 / 65535` (up to `1 / 65535` for the few hits
/// with `d > 65534.5 / 65535`; objects lie inside radius `1/√2`, so real hits have `d < 0.86`).
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "quantise_depth returns ≤ 65534"
)]
pub fn encode_depth_u16(d: f32) -> u16 {
    quantise_depth(d, f64::from(NO_HIT_U16)).map_or(NO_HIT_U16, |q| q as u16)
}

/// Decodes a 16-bit depth: `v / 65535` ([`NO_HIT_U16`] → `1.0`, no hit).
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn decode_depth_u16(v: u16) -> f32 {
    if v == NO_HIT_U16 {
        1.0
    } else {
        (f64::from(v) / f64::from(NO_HIT_U16)) as f32
    }
}

/// 8-bit variant of [`encode_depth_u16`]: hits map to `min(round(d · 255), 254)`, "no hit"
/// (`d ≥ 1`, NaN, ±∞) to [`NO_HIT_U8`] (255). The quantisation error for hits below
/// `254.5 / 255` is at most `0.5 / 255`.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "quantise_depth returns ≤ 254"
)]
pub fn encode_depth_u8(d: f32) -> u8 {
    quantise_depth(d, f64::from(NO_HIT_U8)).map_or(NO_HIT_U8, |q| q as u8)
}

/// Decodes an 8-bit depth: `v / 255` ([`NO_HIT_U8`] → `1.0`, no hit).
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn decode_depth_u8(v: u8) -> f32 {
    if v == NO_HIT_U8 {
        1.0
    } else {
        (f64::from(v) / f64::from(NO_HIT_U8)) as f32
    }
}

// ---------------------------------------------------------------------------
// Intersections
// ---------------------------------------------------------------------------

/// Intersects the line `origin + t · dir` with the sphere `|x − center| = radius`.
///
/// Returns both roots `(t0, t1)` with `t0 ≤ t1` (either may be negative; a
/// tangent line gives `t0 == t1`), in units of `dir` (`dir` need not be unit).
/// Returns `None` if the line misses the sphere or for invalid input: any
/// non-finite component, zero `dir`, or negative / non-finite `radius`.
///
/// Numerically stable: the discriminant is computed from the squared distance
/// between the centre and the line (no catastrophic cancellation for distant
/// origins), and the roots use the `q = −(b ± √Δ)` form.
#[must_use]
pub fn ray_sphere(origin: DVec3, dir: DVec3, center: DVec3, radius: f64) -> Option<(f64, f64)> {
    if !(origin.is_finite() && dir.is_finite() && center.is_finite() && radius.is_finite())
        || radius < 0.0
    {
        return None;
    }
    let a = dir.length_squared();
    if !(a > 0.0 && a.is_finite()) {
        return None;
    }
    let oc = origin - center;
    let b = oc.dot(dir); // half of the usual b
    let c = oc.length_squared() - radius * radius;
    // Vector from the centre to the closest point of the line.
    let l = oc - dir * (b / a);
    let disc = a * (radius * radius - l.length_squared()); // = b² − a·c
    if disc.is_nan() || disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let q = -(b + sq.copysign(b));
    let (t0, t1) = if q == 0.0 {
        // b == 0 and disc == 0: tangent at the origin.
        (0.0, 0.0)
    } else {
        (q / a, c / q)
    };
    if !(t0.is_finite() && t1.is_finite()) {
        return None;
    }
    Some(if t0 <= t1 { (t0, t1) } else { (t1, t0) })
}

/// Chord parameter for a camera on the unit sphere: for unit camera position
/// `p` and unit world-space direction `w`, the ray `p + t · w` meets the unit
/// sphere again at `t = −2 · dot(p, w)` (which is also the chord length since
/// `w` is unit).
///
/// The value is positive for directions pointing into the sphere and `≤ 0` for
/// directions pointing outwards (no second intersection ahead of the camera).
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    reason = "f64 → f32 output by design"
)]
pub fn chord_length(p: Vec3, w: Vec3) -> f32 {
    (-2.0 * p.as_dvec3().dot(w.as_dvec3())) as f32
}
