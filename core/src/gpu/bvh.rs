//! A bounding-volume hierarchy over triangles (binned surface-area heuristic), built on the CPU
//! and traversed by the bake shader to find the exact first hit of every texel's ray.

use glam::Vec3;

/// Triangles per leaf at most.
const MAX_LEAF: usize = 4;
/// SAH bins per axis.
const BINS: usize = 16;

/// One node as the shader reads it (`struct BvhNode` in `shaders/bake.wgsl`): 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BvhNode {
    /// Box minimum.
    pub min: [f32; 3],
    /// Internal node: index of the left child (the right one follows it). Leaf: first triangle.
    pub left_or_first: u32,
    /// Box maximum.
    pub max: [f32; 3],
    /// Triangles in a leaf; 0 for internal nodes.
    pub count: u32,
}
const _: () = assert!(std::mem::size_of::<BvhNode>() == 32);

/// The hierarchy and the triangle order its leaves refer to.
pub struct Bvh {
    /// Nodes; node 0 is the root.
    pub nodes: Vec<BvhNode>,
    /// `order[i]` = original index of the i-th triangle in leaf order.
    pub order: Vec<u32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };
    fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    fn merge(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec3::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// Builds the hierarchy for triangles given as three corners each.
pub fn build(corners: &[[Vec3; 3]]) -> Bvh {
    let boxes: Vec<Aabb> = corners
        .iter()
        .map(|t| {
            let mut b = Aabb::EMPTY;
            for p in t {
                b.grow(*p);
            }
            b
        })
        .collect();
    let centroids: Vec<Vec3> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
    let mut order: Vec<u32> = (0..u32::try_from(corners.len()).unwrap_or(u32::MAX)).collect();
    let mut nodes = vec![BvhNode::default()];
    // Explicit stack: (node index, start, end) — no recursion depth limit on adversarial input.
    let mut stack = vec![(0usize, 0usize, order.len())];
    while let Some((node, start, end)) = stack.pop() {
        let mut bounds = Aabb::EMPTY;
        let mut cbounds = Aabb::EMPTY;
        for &t in &order[start..end] {
            bounds.merge(&boxes[t as usize]);
            cbounds.grow(centroids[t as usize]);
        }
        nodes[node].min = bounds.min.to_array();
        nodes[node].max = bounds.max.to_array();
        let count = end - start;
        let split = if count > MAX_LEAF {
            best_split(&order[start..end], &boxes, &centroids, &cbounds)
        } else {
            None
        };
        let Some((axis, position)) = split else {
            nodes[node].left_or_first = start as u32;
            nodes[node].count = count as u32;
            continue;
        };
        let slice = &mut order[start..end];
        let mut i = 0;
        let mut j = slice.len();
        while i < j {
            if centroids[slice[i] as usize][axis] < position {
                i += 1;
            } else {
                j -= 1;
                slice.swap(i, j);
            }
        }
        let mid = if i == 0 || i == slice.len() {
            slice.len() / 2
        } else {
            i
        };
        let left = nodes.len();
        nodes.push(BvhNode::default());
        nodes.push(BvhNode::default());
        nodes[node].left_or_first = left as u32;
        nodes[node].count = 0;
        stack.push((left, start, start + mid));
        stack.push((left + 1, start + mid, end));
    }
    Bvh { nodes, order }
}

/// The SAH-best (axis, centroid position) split, or `None` when a leaf is cheaper.
#[allow(
    clippy::needless_range_loop,
    reason = "axis indexes Vec3 components, not a slice"
)]
fn best_split(
    tris: &[u32],
    boxes: &[Aabb],
    centroids: &[Vec3],
    cbounds: &Aabb,
) -> Option<(usize, f32)> {
    let mut best: Option<(f32, usize, f32)> = None;
    for axis in 0..3 {
        let lo = cbounds.min[axis];
        let hi = cbounds.max[axis];
        if hi - lo <= f32::EPSILON * hi.abs().max(1.0) {
            continue;
        }
        let mut bins = [(Aabb::EMPTY, 0usize); BINS];
        let scale = BINS as f32 / (hi - lo);
        for &t in tris {
            let b = (((centroids[t as usize][axis] - lo) * scale) as usize).min(BINS - 1);
            bins[b].0.merge(&boxes[t as usize]);
            bins[b].1 += 1;
        }
        let mut left_area = [0.0f32; BINS];
        let mut left_count = [0usize; BINS];
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for i in 0..BINS - 1 {
            acc.merge(&bins[i].0);
            n += bins[i].1;
            left_area[i] = acc.area();
            left_count[i] = n;
        }
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for i in (1..BINS).rev() {
            acc.merge(&bins[i].0);
            n += bins[i].1;
            let cost = left_area[i - 1] * left_count[i - 1] as f32 + acc.area() * n as f32;
            if left_count[i - 1] > 0 && n > 0 && best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, lo + i as f32 / scale));
            }
        }
    }
    let (cost, axis, pos) = best?;
    let mut parent = Aabb::EMPTY;
    for &t in tris {
        parent.merge(&boxes[t as usize]);
    }
    // Leaf cost = intersecting every triangle; traversal cost ~1 triangle test.
    let leaf_cost = parent.area() * tris.len() as f32;
    if tris.len() > 32 || cost + parent.area() < leaf_cost {
        Some((axis, pos))
    } else {
        None
    }
}
