// Bake: for every texel of every camera's parabolic map, trace the texel's ray through a BVH to its exact first hit and store shaded colour and depth.

struct BakeParams {
    resolution: u32,
    first_camera: u32,
    camera_count: u32,
    // 1: `cs_main` records each texel's hit in `hits` for the light states' `cs_shade` passes.
    // Bit 0: record each texel's hit (light states shade from them); bit 1: trace front faces
    // only (depth reliefs of imported views).
    flags: u32,
    shading: Shading,
}

// Camera k: position on the unit sphere and its local frame (z = -position: the recorded hemisphere's pole).
struct BakeCamera {
    position: vec4<f32>,
    x: vec4<f32>,
    y: vec4<f32>,
    z: vec4<f32>,
}


@group(0) @binding(0) var<uniform> params: BakeParams;
@group(0) @binding(1) var<storage, read> cameras: array<BakeCamera>;
@group(0) @binding(2) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(3) var<storage, read_write> out_depth: array<f32>;
// Per texel: triangle (0xffffffff: none), t, b1, b2 (bit patterns of f32).
@group(0) @binding(4) var<storage, read_write> hits: array<vec4<u32>>;

@group(1) @binding(0) var<storage, read> vertices: array<Vertex>;
@group(1) @binding(1) var<storage, read> triangles: array<Triangle>;
@group(1) @binding(2) var<storage, read> nodes: array<BvhNode>;
@group(1) @binding(3) var<storage, read> materials: array<Material>;
@group(1) @binding(4) var mesh_texture: texture_2d_array<f32>;
@group(1) @binding(5) var mesh_sampler: sampler;

// The ray of parabolic-map point uv (in [-1, 1]²) of camera `cam`: unit direction w and the chord
// from the camera to the unit sphere along it (≤ 0 beyond the recorded hemisphere).
struct MapRay {
    w: vec3<f32>,
    chord: f32,
}

fn map_ray(cam: BakeCamera, uv: vec2<f32>) -> MapRay {
    let q = dot(uv, uv);
    let rz = (1.0 - q) / (1.0 + q);
    let r = vec3<f32>(uv * (1.0 + rz), rz);
    // The chord from the camera to the unit sphere along this direction is 2·r_z (|p| = 1).
    return MapRay(normalize(cam.x.xyz * r.x + cam.y.xyz * r.y + cam.z.xyz * r.z), 2.0 * rz);
}

// Centre of texel (column x, row y) in the parabolic map.
fn texel_uv(x: u32, y: u32, n: u32) -> vec2<f32> {
    return (vec2<f32>(f32(x), f32(y)) + 0.5) / f32(n) * 2.0 - 1.0;
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
    let ray = map_ray(cam, texel_uv(gid.x, gid.y, n));
    let chord = ray.chord;
    let w = ray.w;
    out_color[out_index] = 0u;
    out_depth[out_index] = 1.0;
    if (params.flags & 1u) != 0u {
        hits[out_index] = vec4<u32>(0xffffffffu, 0u, 0u, 0u);
    }
    if chord <= 0.0 {
        return;
    }
    let o = cam.position.xyz;
    let hit = trace(o, w, chord, false, (params.flags & 2u) != 0u);
    if hit.triangle == 0xffffffffu {
        return;
    }
    if (params.flags & 1u) != 0u {
        hits[out_index] = vec4<u32>(hit.triangle, bitcast<u32>(hit.t), bitcast<u32>(hit.b1), bitcast<u32>(hit.b2));
    }
    out_color[out_index] = shade_hit(o, w, hit.triangle, hit.t, hit.b1, hit.b2);
    out_depth[out_index] = hit.t / chord;
}

// The packed colour of the hit at t on ray o + t·w (triangle `index`, barycentrics b1, b2),
// shaded with `params.shading`.
fn shade_hit(o: vec3<f32>, w: vec3<f32>, index: u32, t: f32, b1: f32, b2: f32) -> u32 {
    let hit = Hit(t, index, b1, b2);
    let tri = triangles[hit.triangle];
    let v0 = vertices[tri.v.x];
    let v1 = vertices[tri.v.y];
    let v2 = vertices[tri.v.z];
    let b0 = 1.0 - hit.b1 - hit.b2;
    let n_interp = normalize(v0.normal * b0 + v1.normal * hit.b1 + v2.normal * hit.b2);
    let uv_hit = vec2<f32>(v0.u, v0.v) * b0 + vec2<f32>(v1.u, v1.v) * hit.b1 + vec2<f32>(v2.u, v2.v) * hit.b2;
    let vc = v0.color.rgb * b0 + v1.color.rgb * hit.b1 + v2.color.rgb * hit.b2;
    if params.shading.mode == SHADE_NORMAL {
        return oct_encode16(n_interp);
    }
    let albedo = albedo_of(materials[tri.material], uv_hit, vc, mesh_texture, mesh_sampler);
    var visibility = 1.0;
    if params.shading.shadows != 0u {
        visibility = light_visibility(o + hit.t * w, hit.triangle, o, params.shading.light);
    }
    let color = shade(albedo, n_interp, -w, params.shading, visibility);
    return pack4x8unorm(vec4<f32>(color, 1.0));
}

// Unit vector n as an octahedral map point with 16 bits per coordinate, in the bytes R, G
// (x: high, low) and B, A (y: high, low) of an RGBA8 texel (docs/format.md §8.6; the renderer's
// `oct_decode16` inverts it, within 3e-5 rad).
fn oct_encode16(n: vec3<f32>) -> u32 {
    var p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    if n.z < 0.0 {
        let s = select(vec2<f32>(-1.0), vec2<f32>(1.0), p >= vec2<f32>(0.0));
        p = (vec2<f32>(1.0) - abs(p.yx)) * s;
    }
    let q = vec2<u32>(round(clamp(p * 0.5 + 0.5, vec2<f32>(0.0), vec2<f32>(1.0)) * 65535.0));
    return (q.x >> 8u) | ((q.x & 255u) << 8u) | ((q.y >> 8u) << 16u) | ((q.y & 255u) << 24u);
}

// A light state's colour pass: every texel that `cs_main` found a hit for (in `hits`) shaded
// again with this pass's `params.shading` (another light, or one part of the colour), without
// tracing the texel's ray again; texels without a hit get 0, as the base colour's no-hit texels
// hold once the renderer has read their silhouettes.
@compute @workgroup_size(8, 8, 1)
fn cs_shade(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.resolution;
    if gid.x >= n || gid.y >= n || gid.z >= params.camera_count {
        return;
    }
    let out_index = (gid.z * n + gid.y) * n + gid.x;
    let h = hits[out_index];
    if h.x == 0xffffffffu {
        out_color[out_index] = 0u;
        return;
    }
    let cam = cameras[params.first_camera + gid.z];
    let ray = map_ray(cam, texel_uv(gid.x, gid.y, n));
    out_color[out_index] = shade_hit(cam.position.xyz, ray.w, h.x, bitcast<f32>(h.y), bitcast<f32>(h.z), bitcast<f32>(h.w));
}

// Bisection steps of `cs_edges`: the silhouette lies within 2^-7 texel of the final bracket's
// midpoint (the alpha byte holds 1/255; lumigraph's renderer keeps 1/16).
const EDGE_ITERATIONS: u32 = 6u;

// Normalized depth of camera `cam`'s first hit through map point uv, or −1 where it hits nothing.
fn covered_depth(cam: BakeCamera, uv: vec2<f32>) -> f32 {
    let ray = map_ray(cam, uv);
    if ray.chord <= 0.0 {
        return -1.0;
    }
    let hit = trace(cam.position.xyz, ray.w, ray.chord, false, (params.flags & 2u) != 0u);
    return select(hit.t / ray.chord, -1.0, hit.triangle == 0xffffffffu);
}

// `cs_edges`'s work, listed by the CPU from `cs_main`'s depths (`edge_pairs` in bake.rs): one
// entry per no-hit texel and hit 4-neighbour of it, the texel as an index into the batch's
// outputs (camera · n² + row · n + column) in bits 0–29 and the neighbour's direction in bits
// 30–31 (+x, −x, +y, −y); and per entry, the crossing found.
@group(2) @binding(0) var<storage, read> edge_pairs: array<u32>;
@group(2) @binding(1) var<storage, read_write> edge_crossings: array<vec2<f32>>;

// Sub-texel silhouettes (docs/format.md §8.5), run after `cs_main`, one invocation per listed
// pair (lavapipe runs every instruction for every lane, so a pass over all texels would trace for
// all of them): bisection on the segment from the hit neighbour's centre to the no-hit texel's
// finds where the neighbour's ray stops hitting the mesh. Output: how far along the segment
// (texel spacings, 0–1) and the normalized depth of the last hit before it (the silhouette's
// depth); the CPU averages them per texel into its colour.
@compute @workgroup_size(64, 1, 1)
fn cs_edges(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= arrayLength(&edge_pairs) {
        return;
    }
    let n = params.resolution;
    let entry = edge_pairs[gid.x];
    let out_index = entry & 0x3fffffffu;
    let direction = entry >> 30u;
    let camera = out_index / (n * n);
    let layer = camera * n * n;
    let texel = vec2<i32>(vec2<u32>((out_index - layer) % n, (out_index - layer) / n));
    let offset = select(vec2<i32>(select(-1, 1, direction == 0u), 0), vec2<i32>(0, select(-1, 1, direction == 2u)), direction >= 2u);
    let p = clamp(texel + offset, vec2<i32>(0), vec2<i32>(i32(n) - 1));
    let cam = cameras[params.first_camera + camera];
    let own = texel_uv(u32(texel.x), u32(texel.y), n);
    let hit_uv = texel_uv(u32(p.x), u32(p.y), n);
    var lo = 0.0;
    var hi = 1.0;
    var depth = out_depth[layer + u32(p.y) * n + u32(p.x)];
    for (var it = 0u; it < EDGE_ITERATIONS; it++) {
        let mid = 0.5 * (lo + hi);
        let dm = covered_depth(cam, mix(hit_uv, own, mid));
        if dm >= 0.0 {
            lo = mid;
            depth = dm;
        } else {
            hi = mid;
        }
    }
    edge_crossings[gid.x] = vec2<f32>(0.5 * (lo + hi), depth);
}
