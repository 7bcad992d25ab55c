// Volume bake: for every texel of every camera's parabolic map, ray-cast the volume along the
// texel's exact ray with DESIGN §9's sampling, transfer function, compositing and shading, and
// store premultiplied RGBA and a normalized depth (core/src/volume/bake.rs; the CPU twin of each
// step is core/src/volume/raycast.rs, which the tests hold every texel against).

struct VolumeBakeParams {
    resolution: u32,
    first_camera: u32,
    camera_count: u32,
    // 1: a label volume (nearest voxel, label colours); 0: scalar (trilinear, points).
    labels: u32,
    // world − origin = center + scale · p for a light-field point p (no rotation).
    center: vec3<f32>,
    scale: f32,
    // Rows of M⁻¹ (index space from world offsets); w unused.
    inv_m0: vec4<f32>,
    inv_m1: vec4<f32>,
    inv_m2: vec4<f32>,
    // World position of voxel (0, 0, 0)'s centre: 0, since the host sends ray origins (`center`)
    // relative to it, formed in f64 (bake.rs `shared_params`).
    origin: vec3<f32>,
    // Sample spacing Δ, world units.
    step: f32,
    // Voxels along i, j, k.
    dims: vec3<f32>,
    // Δ / ref_step: the exponent of the opacity correction.
    step_ratio: f32,
    // World-space direction towards the light (unit).
    light: vec3<f32>,
    ambient: f32,
    // Gradient offsets along world x, y, z (row norms of M).
    spacing: vec3<f32>,
    // |∇S|·min(spacing) below this keeps the TF colour (1e−6·(max S − min S)).
    flat_below: f32,
    // τ_d: the accumulated opacity that places the depth.
    depth_threshold: f32,
    shade: u32,
    // Entries of `tf`.
    tf_count: u32,
    // Depth layers (raycast.rs SplitRule): 0 whole rays, 1 split where the whole ray's A
    // reaches each boundary, 2 where the sampled value does, 3 at the first `split_count`
    // transitions between visible labels; `segment` is the one kept.
    split_mode: u32,
    segment: u32,
    split_count: u32,
    pad0: u32,
    pad1: u32,
    splits: array<vec4<f32>, 4>,
}

// A transfer-function entry: a scalar point (value, rgba) or a label (label, rgba); sorted by
// value.
struct TfEntry {
    value: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
    rgba: vec4<f32>,
}

// Camera k: position on the unit sphere and its local frame (z = −position: the recorded
// hemisphere's pole), as in bake.wgsl.
struct BakeCamera {
    position: vec4<f32>,
    x: vec4<f32>,
    y: vec4<f32>,
    z: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: VolumeBakeParams;
@group(0) @binding(1) var<storage, read> cameras: array<BakeCamera>;
@group(0) @binding(2) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(3) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(4) var<storage, read> tf: array<TfEntry>;
@group(0) @binding(5) var volume: texture_3d<f32>;

// Accumulated opacity at which a ray stops (raycast.rs EARLY_STOP_ALPHA).
const EARLY_STOP_ALPHA: f32 = 0.995;

fn voxel(i: vec3<i32>) -> f32 {
    return textureLoad(volume, i, 0).x;
}

fn to_index(w: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(params.inv_m0.xyz, w), dot(params.inv_m1.xyz, w), dot(params.inv_m2.xyz, w));
}

// T at index-space u: trilinear, the index clamped to the edge voxels.
fn trilinear(u: vec3<f32>) -> f32 {
    let last = params.dims - 1.0;
    let x = clamp(u, vec3<f32>(0.0), last);
    let f0 = floor(x);
    let fr = x - f0;
    let i0 = vec3<i32>(f0);
    let i1 = min(i0 + 1, vec3<i32>(last));
    let c00 = mix(voxel(i0), voxel(vec3<i32>(i1.x, i0.y, i0.z)), fr.x);
    let c10 = mix(voxel(vec3<i32>(i0.x, i1.y, i0.z)), voxel(vec3<i32>(i1.x, i1.y, i0.z)), fr.x);
    let c01 = mix(voxel(vec3<i32>(i0.x, i0.y, i1.z)), voxel(vec3<i32>(i1.x, i0.y, i1.z)), fr.x);
    let c11 = mix(voxel(vec3<i32>(i0.x, i1.y, i1.z)), voxel(i1), fr.x);
    return mix(mix(c00, c10, fr.y), mix(c01, c11, fr.y), fr.z);
}

// The nearest voxel's value: clamp(floor(u + ½)).
fn nearest(u: vec3<f32>) -> f32 {
    let i = clamp(floor(u + 0.5), vec3<f32>(0.0), params.dims - 1.0);
    return voxel(vec3<i32>(i));
}

// The number of entries whose value is ≤ v (entries sorted by value).
fn entries_at_or_below(v: f32) -> u32 {
    var lo = 0u;
    var hi = params.tf_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if tf[mid].value <= v {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// Scalar TF: piecewise linear, clamped at the ends; at a step the later point wins.
fn tf_scalar(v: f32) -> vec4<f32> {
    let upper = entries_at_or_below(v);
    if upper == 0u {
        return tf[0].rgba;
    }
    if upper >= params.tf_count {
        return tf[params.tf_count - 1u].rgba;
    }
    let lo = tf[upper - 1u];
    let hi = tf[upper];
    return mix(lo.rgba, hi.rgba, (v - lo.value) / (hi.value - lo.value));
}

// Label TF: the label's colour, or empty.
fn tf_label(v: f32) -> vec4<f32> {
    let label = round(v);
    let upper = entries_at_or_below(label);
    if upper > 0u && tf[upper - 1u].value == label {
        return tf[upper - 1u].rgba;
    }
    return vec4<f32>(0.0);
}

// 1 − (1 − a)^(Δ/ref_step).
fn opacity_for_step(a: f32) -> f32 {
    if a >= 1.0 {
        return 1.0;
    }
    if a <= 0.0 {
        return 0.0;
    }
    return 1.0 - exp2(params.step_ratio * log2(1.0 - a));
}

// ambient + (1 − ambient)·|∇S·ℓ| / |∇S|, central differences one spacing along each world axis;
// 1 where the gradient is flat.
fn shade_factor(u: vec3<f32>) -> f32 {
    let h = params.spacing;
    // World offset h_a·ê_a in index space: h_a times column a of M⁻¹.
    let cx = vec3<f32>(params.inv_m0.x, params.inv_m1.x, params.inv_m2.x) * h.x;
    let cy = vec3<f32>(params.inv_m0.y, params.inv_m1.y, params.inv_m2.y) * h.y;
    let cz = vec3<f32>(params.inv_m0.z, params.inv_m1.z, params.inv_m2.z) * h.z;
    let g = vec3<f32>(
        (trilinear(u + cx) - trilinear(u - cx)) / (2.0 * h.x),
        (trilinear(u + cy) - trilinear(u - cy)) / (2.0 * h.y),
        (trilinear(u + cz) - trilinear(u - cz)) / (2.0 * h.z),
    );
    let norm = length(g);
    if norm * min(min(h.x, h.y), h.z) < params.flat_below || norm == 0.0 {
        return 1.0;
    }
    return params.ambient + (1.0 - params.ambient) * abs(dot(g, params.light)) / norm;
}

struct Cast {
    rgba: vec4<f32>,
    // The depth sample's t, and where A crossed τ_d within its slab (raycast.rs RaySample).
    t_depth: f32,
    t_cross: f32,
    t_mean: f32,
}

// Boundary k of a split ray.
fn split_at(k: u32) -> f32 {
    return params.splits[k / 4u][k % 4u];
}

// The ray eye + t·dir (dir unit, world units): DESIGN §9's integration. For a depth layer, only
// the samples of its segment are gathered (as a ray that starts empty there), while the split
// events and the early stop follow the whole ray's opacity (raycast.rs `march`).
fn march_ray(eye: vec3<f32>, dir: vec3<f32>) -> Cast {
    var out = Cast(vec4<f32>(0.0), -1.0, -1.0, -1.0);
    let u0 = to_index(eye - params.origin);
    let ud = to_index(dir);
    // Slab test against [−½, dims − ½] per index axis.
    var t_in = -3.0e38;
    var t_out = 3.0e38;
    for (var a = 0u; a < 3u; a++) {
        let lo = -0.5;
        let hi = params.dims[a] - 0.5;
        if ud[a] == 0.0 {
            if u0[a] < lo || u0[a] > hi {
                return out;
            }
            continue;
        }
        let t1 = (lo - u0[a]) / ud[a];
        let t2 = (hi - u0[a]) / ud[a];
        t_in = max(t_in, min(t1, t2));
        t_out = min(t_out, max(t1, t2));
    }
    let t0 = max(t_in, 0.0);
    if !(t0 < t_out) {
        return out;
    }
    var c = vec3<f32>(0.0);
    // This segment's A (the whole ray's when it is not split) and the whole ray's A.
    var acc = 0.0;
    var whole = 0.0;
    var weighted_t = 0.0;
    var current = 0u;
    // The last visible label met (split mode 3); −1: none yet.
    var last_label = -1.0;
    let labels = params.labels != 0u;
    for (var k = 0u; ; k++) {
        let t = t0 + (f32(k) + 0.5) * params.step;
        if t >= t_out {
            break;
        }
        let u = u0 + ud * t;
        var value: f32;
        var rgba: vec4<f32>;
        if labels {
            value = nearest(u);
            rgba = tf_label(value);
        } else {
            value = trilinear(u);
            rgba = tf_scalar(value);
        }
        let alpha = opacity_for_step(rgba.a);
        if params.split_mode == 3u && alpha > 0.0 {
            // A new label starts the next segment with this sample.
            if last_label >= 0.0 && value != last_label && current < params.split_count {
                current += 1u;
            }
            last_label = value;
            if current > params.segment {
                break;
            }
        }
        if alpha > 0.0 {
            if current == params.segment {
                var rgb = rgba.rgb;
                if params.shade != 0u {
                    rgb *= shade_factor(u);
                }
                c += (1.0 - acc) * alpha * rgb;
                weighted_t += (1.0 - acc) * alpha * t;
                let before = acc;
                acc += (1.0 - acc) * alpha;
                if acc >= params.depth_threshold && out.t_depth < 0.0 {
                    out.t_depth = t;
                    let f = clamp((params.depth_threshold - before) / (acc - before), 0.0, 1.0);
                    out.t_cross = t - 0.5 * params.step + params.step * f;
                }
            }
            whole += (1.0 - whole) * alpha;
            if whole >= EARLY_STOP_ALPHA {
                break;
            }
        }
        if params.split_mode == 1u || params.split_mode == 2u {
            loop {
                if current >= params.split_count {
                    break;
                }
                let b = split_at(current);
                let fired = select(value >= b, whole >= b, params.split_mode == 1u);
                if !fired {
                    break;
                }
                current += 1u;
            }
            if current > params.segment {
                break;
            }
        }
    }
    out.rgba = vec4<f32>(c, acc);
    if acc > 0.0 {
        out.t_mean = weighted_t / acc;
    }
    return out;
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.resolution;
    if gid.x >= n || gid.y >= n || gid.z >= params.camera_count {
        return;
    }
    let out_index = (gid.z * n + gid.y) * n + gid.x;
    let cam = cameras[params.first_camera + gid.z];
    // Texel (row y, column x) centre in the parabolic map, its direction and the chord from the
    // camera to the unit sphere along it (2·r_z, since |p| = 1).
    let uv = (vec2<f32>(f32(gid.x), f32(gid.y)) + 0.5) / f32(n) * 2.0 - 1.0;
    let q = dot(uv, uv);
    let rz = (1.0 - q) / (1.0 + q);
    let r = vec3<f32>(uv * (1.0 + rz), rz);
    let w = normalize(cam.x.xyz * r.x + cam.y.xyz * r.y + cam.z.xyz * r.z);
    let chord = 2.0 * rz * params.scale;
    out_color[out_index] = 0u;
    out_depth[out_index] = 1.0;
    if chord <= 0.0 {
        return;
    }
    let ray = march_ray(params.center + params.scale * cam.position.xyz, w);
    // Coverage is round(255·A) ≥ 1; below it the texel is empty.
    if ray.rgba.a * 255.0 < 0.5 {
        return;
    }
    // Depth: where A crossed τ_d (interpolated within the sample's slab, so the stored surface
    // is smooth); a ray that stays fainter keeps the opacity-weighted mean of its samples, so
    // that its haze is reprojected from where it lies.
    let t = select(ray.t_mean, ray.t_cross, ray.t_depth >= 0.0);
    out_color[out_index] = pack4x8unorm(ray.rgba);
    out_depth[out_index] = clamp(t / chord, 0.0, 1.0);
}

// The direct render of a DESIGN §3 view (VolumeBaker::render_view): the same integration along
// each pixel's ray, unquantized. Here `params.center` is the eye, `params.resolution` the width
// and `params.camera_count` the height; `view_rays[p]` holds pixel p's unit direction and its
// z rate (forward · direction), computed on the CPU as the reference computes them.
@group(0) @binding(6) var<storage, read> view_rays: array<vec4<f32>>;
// Premultiplied RGBA and z-depth (−1 where A never reached τ_d) per pixel.
@group(0) @binding(7) var<storage, read_write> view_out: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> view_depth: array<f32>;

@compute @workgroup_size(8, 8, 1)
fn cs_view(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.resolution || gid.y >= params.camera_count {
        return;
    }
    let i = gid.y * params.resolution + gid.x;
    let r = view_rays[i];
    let ray = march_ray(params.center, r.xyz);
    view_out[i] = ray.rgba;
    view_depth[i] = select(-1.0, ray.t_depth * r.w, ray.t_depth >= 0.0);
}
