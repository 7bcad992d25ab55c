//! Bounding spheres: Ritter's algorithm, refined (see [`Mesh::bounding_sphere`]).
//!
//! 1. Ritter: the initial diameter is the farthest-apart pair among the extreme points along
//!    13 directions (EPOS-26, Larsson 2008), then one growing pass over all points.
//! 2. Iterative refinement (Ericson, *Real-Time Collision Detection* §4.3.5): shrink the best
//!    sphere and grow it again over the points in another order, keeping the smallest.
//! 3. Core-set refinement: the exact minimal sphere (Welzl's algorithm with Gärtner's
//!    move-to-front heuristic) of a small set of points — the extreme points, plus the farthest
//!    point outside after each round — until no point lies outside. This reaches the minimal
//!    sphere up to rounding in a few rounds of O(n).
//!
//! Every stage yields a sphere around all points, the smallest is kept, and its radius is
//! recomputed as the largest distance from its centre, so containment never depends on the
//! numerics of the refinement.
//!
//! [`Mesh::bounding_sphere`]: crate::mesh::Mesh::bounding_sphere

use glam::DVec3;

use crate::mesh::BoundingSphere;

/// Directions whose extreme points seed Ritter's initial diameter and the core set (axes, face
/// diagonals, space diagonals).
const EXTREME_DIRECTIONS: [[f64; 3]; 13] = [
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 1.0, 1.0],
    [1.0, 1.0, -1.0],
    [1.0, -1.0, 1.0],
    [1.0, -1.0, -1.0],
    [1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, 1.0, -1.0],
];

/// Shrink factors of Ericson's refinement passes, one pass each.
const REFINE_SHRINK: [f64; 8] = [0.95, 0.97, 0.98, 0.99, 0.95, 0.97, 0.995, 0.999];

/// Most rounds of the core-set refinement (each adds one point; a handful is typical).
const MAX_CORE_ROUNDS: usize = 64;

/// Relative slack for "inside" tests during refinement (the final radius is exact anyway).
const INSIDE_SLACK: f64 = 1e-12;

/// The bounding sphere of `points`; see the module documentation.
pub(super) fn bounding_sphere_of(points: &[DVec3]) -> BoundingSphere {
    let Some(&first) = points.first() else {
        return BoundingSphere {
            center: DVec3::ZERO,
            radius: f64::MIN_POSITIVE,
        };
    };

    // 1. Ritter, seeded with the widest pair of extreme points.
    let mut extremes = Vec::with_capacity(2 * EXTREME_DIRECTIONS.len());
    let (mut lo, mut hi, mut widest) = (first, first, -1.0);
    for dir in EXTREME_DIRECTIONS.map(DVec3::from) {
        let (mut min_p, mut max_p) = (first, first);
        let (mut min_d, mut max_d) = (first.dot(dir), first.dot(dir));
        for &p in points {
            let d = p.dot(dir);
            if d < min_d {
                (min_d, min_p) = (d, p);
            }
            if d > max_d {
                (max_d, max_p) = (d, p);
            }
        }
        extremes.extend([min_p, max_p]);
        let span = min_p.distance_squared(max_p);
        if span > widest {
            (widest, lo, hi) = (span, min_p, max_p);
        }
    }
    let mut best = Sphere {
        center: (lo + hi) * 0.5,
        radius: lo.distance(hi) * 0.5,
    };
    best.grow_over(points, 0, 1);
    best.radius = farthest(points, best.center).1;

    // 2. Shrink and regrow in scrambled orders.
    let n = points.len();
    for (pass, shrink) in REFINE_SHRINK.iter().enumerate() {
        let mut candidate = Sphere {
            center: best.center,
            radius: best.radius * shrink,
        };
        candidate.grow_over(points, pass.wrapping_mul(7919) % n, coprime_step(n, pass));
        candidate.radius = farthest(points, candidate.center).1;
        if candidate.radius < best.radius {
            best = candidate;
        }
    }

    // 3. Exact minimal sphere of a growing core set.
    if let Some(candidate) = core_set_sphere(points, extremes)
        && candidate.radius < best.radius
    {
        best = candidate;
    }

    let radius = best.radius * (1.0 + 1e-9);
    BoundingSphere {
        center: best.center,
        radius: if radius > 0.0 {
            radius
        } else {
            f64::MIN_POSITIVE
        },
    }
}

#[derive(Clone, Copy, Debug)]
struct Sphere {
    center: DVec3,
    radius: f64,
}

impl Sphere {
    /// Ritter's growing pass, visiting `points[(start + k * step) % n]`: each point outside
    /// moves and grows the sphere just enough to hold the old sphere and the point.
    fn grow_over(&mut self, points: &[DVec3], start: usize, step: usize) {
        let n = points.len();
        if n == 0 {
            return;
        }
        let mut index = start % n;
        for _ in 0..n {
            if let Some(&p) = points.get(index) {
                let offset = p - self.center;
                let distance = offset.length();
                if distance > self.radius {
                    let new_radius = (self.radius + distance) * 0.5;
                    self.center += offset * ((new_radius - self.radius) / distance);
                    self.radius = new_radius;
                }
            }
            index = (index + step) % n;
        }
    }
}

/// The point farthest from `center` and its distance.
fn farthest(points: &[DVec3], center: DVec3) -> (DVec3, f64) {
    let mut best = (center, 0.0);
    for &p in points {
        let d = p.distance_squared(center);
        if d > best.1 {
            best = (p, d);
        }
    }
    (best.0, best.1.sqrt())
}

/// A step coprime to `n`, different per `pass`, so that `(start + k * step) % n` visits every
/// index once in a scrambled order.
fn coprime_step(n: usize, pass: usize) -> usize {
    const CANDIDATES: [usize; 4] = [1, 7919, 104_729, 15_485_863];
    if n <= 2 {
        return 1;
    }
    let mut step = CANDIDATES[pass % CANDIDATES.len()] % n;
    if pass % 2 == 1 {
        step = n - step.max(1);
    }
    while step == 0 || gcd(step, n) != 1 {
        step = (step + 1) % n;
    }
    step
}

fn gcd(mut a: usize, mut b: usize) -> usize {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// Core-set refinement: the minimal sphere of `core`, grown by the farthest outside point
/// until none is outside. `None` if the numerics fail (degenerate input); the caller then keeps
/// the refined Ritter sphere.
fn core_set_sphere(points: &[DVec3], mut core: Vec<DVec3>) -> Option<Sphere> {
    core.sort_by(|a, b| {
        a.to_array()
            .partial_cmp(&b.to_array())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    core.dedup();
    let mut result = None;
    for _ in 0..MAX_CORE_ROUNDS {
        let ball = minimal_ball(&mut core)?;
        if !(ball.center.is_finite() && ball.radius_squared.is_finite()) {
            return result;
        }
        let (far, distance) = farthest(points, ball.center);
        result = Some(Sphere {
            center: ball.center,
            radius: distance,
        });
        if distance * distance <= ball.radius_squared * (1.0 + INSIDE_SLACK) {
            break;
        }
        // Put the new point first: move-to-front processes it early.
        core.insert(0, far);
    }
    result
}

/// A ball as centre and squared radius (negative: the empty ball).
#[derive(Clone, Copy, Debug)]
struct Ball {
    center: DVec3,
    radius_squared: f64,
}

impl Ball {
    const EMPTY: Ball = Ball {
        center: DVec3::ZERO,
        radius_squared: -1.0,
    };

    fn contains(&self, p: DVec3) -> bool {
        p.distance_squared(self.center) <= self.radius_squared * (1.0 + INSIDE_SLACK)
    }
}

/// The exact minimal ball of `points` (reordered by move-to-front), `None` when empty.
fn minimal_ball(points: &mut Vec<DVec3>) -> Option<Ball> {
    if points.is_empty() {
        return None;
    }
    let mut boundary = Vec::with_capacity(4);
    let end = points.len();
    Some(move_to_front(points, end, &mut boundary))
}

/// Gärtner's move-to-front Welzl: the minimal ball of `points[..end]` with `boundary` on its
/// surface.
fn move_to_front(points: &mut Vec<DVec3>, end: usize, boundary: &mut Vec<DVec3>) -> Ball {
    let mut ball = ball_through(boundary);
    if boundary.len() == 4 {
        return ball;
    }
    for i in 0..end {
        let Some(&p) = points.get(i) else { break };
        if !ball.contains(p) {
            boundary.push(p);
            ball = move_to_front(points, i, boundary);
            boundary.pop();
            points.remove(i);
            points.insert(0, p);
        }
    }
    ball
}

/// The smallest ball with every point of `boundary` (at most 4) on its surface: its centre is
/// the circumcentre in their affine hull. An affinely dependent boundary (degenerate: e.g. four
/// coplanar points) falls back to the ball through all but the last point.
fn ball_through(boundary: &[DVec3]) -> Ball {
    let Some((&origin, rest)) = boundary.split_first() else {
        return Ball::EMPTY;
    };
    if rest.is_empty() {
        return Ball {
            center: origin,
            radius_squared: 0.0,
        };
    }
    // centre = origin + Σ λ_j q_j with 2 q_i·(Σ λ_j q_j) = q_i·q_i, q_i = p_i - origin.
    let q: Vec<DVec3> = rest.iter().map(|&p| p - origin).collect();
    let k = q.len();
    let mut system = [[0.0f64; 4]; 3];
    for (i, qi) in q.iter().enumerate() {
        for (j, qj) in q.iter().enumerate() {
            system[i][j] = 2.0 * qi.dot(*qj);
        }
        system[i][k] = qi.length_squared();
    }
    match solve(&mut system, k) {
        Some(lambda) => {
            let offset = q
                .iter()
                .zip(lambda)
                .fold(DVec3::ZERO, |acc, (qi, l)| acc + *qi * l);
            Ball {
                center: origin + offset,
                radius_squared: offset.length_squared(),
            }
        }
        None => ball_through(boundary.get(..boundary.len() - 1).unwrap_or_default()),
    }
}

/// Solves the k×k system in `m` (augmented column k) by Gaussian elimination with partial
/// pivoting; `None` if it is (nearly) singular.
fn solve(m: &mut [[f64; 4]; 3], k: usize) -> Option<[f64; 3]> {
    let scale = m
        .iter()
        .take(k)
        .flat_map(|row| row.iter().take(k))
        .fold(0.0f64, |a, &v| a.max(v.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..k {
        let pivot = (col..k).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        if m[pivot][col].abs() <= 1e-12 * scale {
            return None;
        }
        m.swap(col, pivot);
        let pivot_row = m[col];
        for (row, values) in m.iter_mut().enumerate().take(k) {
            if row != col {
                let factor = values[col] / pivot_row[col];
                for (value, p) in values.iter_mut().zip(pivot_row).skip(col).take(k + 1 - col) {
                    *value -= factor * p;
                }
            }
        }
    }
    let mut x = [0.0; 3];
    for (i, xi) in x.iter_mut().enumerate().take(k) {
        *xi = m[i][k] / m[i][i];
    }
    Some(x)
}
