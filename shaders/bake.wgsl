// Bake: for every texel of every camera's parabolic map, trace the texel's ray through a BVH to its exact first hit and store shaded colour and depth.

struct BakeParams {
    resolution: u32,
    first_camera: u32,
    camera_count: u32,
    pad: u32,
    shading: Shading,
}

// Camera k: position on the unit sphere and its local frame (z = -position: the recorded hemisphere's pole).
struct Camera {
    position: vec4<f32>,
    x: vec4<f32>,
    y: vec4<f32>,
    z: vec4<f32>,
}

struct BvhNode {
    min: vec3<f32>,
    left_or_first: u32,
    max: vec3<f32>,
    count: u32,
}

@group(0) @binding(0) var<uniform> params: BakeParams;
@group(0) @binding(1) var<storage, read> cameras: array<Camera>;
@group(0) @binding(2) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(3) var<storage, read_write> out_depth: array<f32>;

@group(1) @binding(0) var<storage, read> vertices: array<Vertex>;
@group(1) @binding(1) var<storage, read> triangles: array<Triangle>;
@group(1) @binding(2) var<storage, read> nodes: array<BvhNode>;
@group(1) @binding(3) var<storage, read> materials: array<Material>;
@group(1) @binding(4) var mesh_texture: texture_2d_array<f32>;
@group(1) @binding(5) var mesh_sampler: sampler;

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

// Closest hit along o + t·d for t in (0, t_max]; Möller–Trumbore without culling, edges widened
// by 1e-6 (relative) so rays through shared edges never slip between two triangles.
fn trace(o: vec3<f32>, d: vec3<f32>, t_max: f32) -> Hit {
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
                if abs(det) > 1e-20 {
                    let inv_det = 1.0 / det;
                    let tv = o - p0;
                    let b1 = dot(tv, pv) * inv_det;
                    let qv = cross(tv, e1);
                    let b2 = dot(d, qv) * inv_det;
                    let t = dot(e2, qv) * inv_det;
                    let eps = -1e-6;
                    if b1 >= eps && b2 >= eps && b1 + b2 <= 1.0 - eps && t > 1e-7 && t < hit.t {
                        hit = Hit(t, ti, b1, b2);
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

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.resolution;
    if gid.x >= n || gid.y >= n || gid.z >= params.camera_count {
        return;
    }
    let out_index = (gid.z * n + gid.y) * n + gid.x;
    let cam = cameras[params.first_camera + gid.z];
    // Texel (row a = y, column b = x) centre in the parabolic map.
    let uv = (vec2<f32>(f32(gid.x), f32(gid.y)) + 0.5) / f32(n) * 2.0 - 1.0;
    let q = dot(uv, uv);
    let rz = (1.0 - q) / (1.0 + q);
    let r = vec3<f32>(uv * (1.0 + rz), rz);
    // The chord from the camera to the unit sphere along this direction is 2·r_z (|p| = 1).
    let chord = 2.0 * rz;
    out_color[out_index] = 0u;
    out_depth[out_index] = 1.0;
    if chord <= 0.0 {
        return;
    }
    let w = normalize(cam.x.xyz * r.x + cam.y.xyz * r.y + cam.z.xyz * r.z);
    let o = cam.position.xyz;
    let hit = trace(o, w, chord);
    if hit.triangle == 0xffffffffu {
        return;
    }
    let tri = triangles[hit.triangle];
    let v0 = vertices[tri.v.x];
    let v1 = vertices[tri.v.y];
    let v2 = vertices[tri.v.z];
    let b0 = 1.0 - hit.b1 - hit.b2;
    let n_interp = normalize(v0.normal * b0 + v1.normal * hit.b1 + v2.normal * hit.b2);
    let uv_hit = vec2<f32>(v0.u, v0.v) * b0 + vec2<f32>(v1.u, v1.v) * hit.b1 + vec2<f32>(v2.u, v2.v) * hit.b2;
    let vc = v0.color.rgb * b0 + v1.color.rgb * hit.b1 + v2.color.rgb * hit.b2;
    let albedo = albedo_of(materials[tri.material], uv_hit, vc, mesh_texture, mesh_sampler);
    let color = shade(albedo, n_interp, -w, params.shading);
    out_color[out_index] = pack4x8unorm(vec4<f32>(color, 1.0));
    out_depth[out_index] = hit.t / chord;
}
