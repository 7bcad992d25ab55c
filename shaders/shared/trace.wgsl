// Ray tracing through the mesh's BVH (closest hit, or any hit for shadow rays) and DESIGN §9's
// shadow test, shared by the bake ray tracer and the reference rasterizer. The including module
// binds `vertices`, `triangles` and `nodes`.

struct BvhNode {
    min: vec3<f32>,
    left_or_first: u32,
    max: vec3<f32>,
    count: u32,
}

const STACK_SIZE: u32 = 64u;

struct Hit {
    t: f32,
    triangle: u32,
    b1: f32,
    b2: f32,
}

fn safe_inverse(d: f32) -> f32 {
    if abs(d) < 1e-30 {
        return select(-1e30, 1e30, d >= 0.0);
    }
    return 1.0 / d;
}

fn box_entry(o: vec3<f32>, inv_d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>, t_max: f32) -> f32 {
    let t0 = (lo - o) * inv_d;
    let t1 = (hi - o) * inv_d;
    let near = max(max(min(t0.x, t1.x), min(t0.y, t1.y)), min(t0.z, t1.z));
    let far = min(min(max(t0.x, t1.x), max(t0.y, t1.y)), max(t0.z, t1.z));
    if near <= far && far >= 0.0 && near <= t_max {
        return max(near, 0.0);
    }
    return -1.0;
}

// Closest hit along o + t·d for t in (0, t_max]; Möller–Trumbore, edges widened by 1e-6
// (relative) so rays through shared edges never slip between two triangles. `any`: stop at the
// first hit found (a shadow ray's question), not the closest. `front_only`: skip triangles
// seen from behind (their corners clockwise from o; det ≤ 0), else both sides count.
fn trace(o: vec3<f32>, d: vec3<f32>, t_max: f32, any: bool, front_only: bool) -> Hit {
    var hit = Hit(t_max, 0xffffffffu, 0.0, 0.0);
    let inv_d = vec3<f32>(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    var stack: array<u32, STACK_SIZE>;
    var sp = 0u;
    var node_index = 0u;
    loop {
        let node = nodes[node_index];
        if node.count > 0u {
            for (var i = 0u; i < node.count; i++) {
                let ti = node.left_or_first + i;
                let tri = triangles[ti];
                let p0 = vertices[tri.v.x].position;
                let e1 = vertices[tri.v.y].position - p0;
                let e2 = vertices[tri.v.z].position - p0;
                let pv = cross(d, e2);
                let det = dot(e1, pv);
                if abs(det) > 1e-20 && (det > 0.0 || !front_only) {
                    let inv_det = 1.0 / det;
                    let tv = o - p0;
                    let b1 = dot(tv, pv) * inv_det;
                    let qv = cross(tv, e1);
                    let b2 = dot(d, qv) * inv_det;
                    let t = dot(e2, qv) * inv_det;
                    let eps = -1e-6;
                    if b1 >= eps && b2 >= eps && b1 + b2 <= 1.0 - eps && t > 1e-7 && t < hit.t {
                        hit = Hit(t, ti, b1, b2);
                        if any {
                            return hit;
                        }
                    }
                }
            }
        } else {
            let left = node.left_or_first;
            let a = nodes[left];
            let b = nodes[left + 1u];
            let ta = box_entry(o, inv_d, a.min, a.max, hit.t);
            let tb = box_entry(o, inv_d, b.min, b.max, hit.t);
            if ta >= 0.0 && tb >= 0.0 {
                // Visit the nearer child first; the other waits on the stack.
                let first = select(left + 1u, left, ta <= tb);
                let second = select(left, left + 1u, ta <= tb);
                if sp < STACK_SIZE {
                    stack[sp] = second;
                    sp++;
                }
                node_index = first;
                continue;
            } else if ta >= 0.0 {
                node_index = left;
                continue;
            } else if tb >= 0.0 {
                node_index = left + 1u;
                continue;
            }
        }
        if sp == 0u {
            break;
        }
        sp--;
        node_index = stack[sp];
    }
    return hit;
}

// DESIGN §9's shadow term V at hit point `p` of triangle `triangle`, seen along a ray from
// `origin`: 1 where the ray from p + 1e-4·r·n_g towards the light `light` (unit) meets no
// triangle, else 0; n_g is the face's geometric normal turned towards `origin`. Positions are
// in the light-field frame, where the bounding radius r is 1/√2: the offset is 1e-4/√2.
const SHADOW_OFFSET: f32 = 7.0710678e-5;

fn light_visibility(p: vec3<f32>, triangle: u32, origin: vec3<f32>, light: vec3<f32>) -> f32 {
    let tri = triangles[triangle];
    let a = vertices[tri.v.x].position;
    let face = cross(vertices[tri.v.y].position - a, vertices[tri.v.z].position - a);
    let len = length(face);
    // A degenerate face (no area, so no normal) casts its ray from the point itself.
    var n_g = select(vec3<f32>(0.0), face / len, len > 1e-30);
    if dot(n_g, origin - p) < 0.0 {
        n_g = -n_g;
    }
    let hit = trace(p + SHADOW_OFFSET * n_g, light, 1e30, true, false);
    return select(1.0, 0.0, hit.triangle != 0xffffffffu);
}
