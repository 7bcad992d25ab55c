// Compositing the layers of a multi light field on the GPU (DESIGN §9, seed 002 §6–§7): every
// visible layer's marcher output (premultiplied RGBA8 and the depth of the maps' surface each
// pixel met) lies in a stack, one frame per layer; this pass sorts each pixel's fragments by
// depth (or keeps their order along the ray, for depth layers) and blends them front to back
// with the runtime opacities, `C += (1 − A)·o_i·C_i`, `A += (1 − A)·o_i·α_i`. The rule, the
// rounding and the depth output are `crate::layers::composite`'s, which the tests hold it to.

// The most layers one pass composites (`render::composite::MAX_GPU_LAYERS`).
const MAX_LAYERS: u32 = 16u;
// No fragment index yet.
const NONE: i32 = -1;
// "No depth": after every real depth (the CPU's +inf; WGSL has no infinity literal).
const FAR: f32 = 3.0e38;

struct CompositeParams {
    width: u32,
    height: u32,
    // Layers in the stack (1 to MAX_LAYERS), in the asset's order.
    count: u32,
    // 1: sort each pixel's fragments by depth (ties keep the stack order); 0: the stack order.
    by_depth: u32,
    // 1: the layers hold premultiplied RGBA (a translucent field); 0: opaque hits, whose
    // fragments are the pixels with a depth.
    translucent: u32,
    // 1: every layer opaque at opacity 1: the nearest fragment as it is, no blending.
    nearest_only: u32,
    // τ_d: the composite's depth is the first fragment's at which A reaches it.
    depth_threshold: f32,
    pad: u32,
    // Runtime opacity per stacked layer, four per vector.
    opacities: array<vec4<f32>, 4>,
}

@group(0) @binding(0) var<uniform> params: CompositeParams;
@group(0) @binding(1) var<storage, read> stack_color: array<u32>;
@group(0) @binding(2) var<storage, read> stack_depth: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<f32>;

fn opacity(layer: u32) -> f32 {
    return params.opacities[layer / 4u][layer % 4u];
}

// Half away from zero, as Rust's `f32::round` (WGSL's `round` is half to even).
fn round_code(x: f32) -> u32 {
    return u32(clamp(floor(x + 0.5), 0.0, 255.0));
}

// One layer's fragment at the pixel: premultiplied RGBA8 (alpha 255 for an opaque layer's hit)
// and depth (FAR for none); `present` false where the layer shows nothing there.
struct Fragment {
    px: u32,
    z: f32,
    present: bool,
}

fn fragment(layer: u32, p: u32, pixels: u32) -> Fragment {
    var px = stack_color[layer * pixels + p];
    let raw = stack_depth[layer * pixels + p];
    // The marcher writes −1 (a marched miss) or 0 (a pixel a compacted pass skipped).
    let z = select(FAR, raw, raw > 0.0);
    var present = (px >> 24u) != 0u;
    if params.translucent == 0u {
        present = z < FAR;
        px |= 0xff000000u;
    }
    return Fragment(px, z, present && opacity(layer) > 0.0);
}

// Front-to-back accumulation: premultiplied colour, opacity, and the depth of the fragment at
// which the opacity reached τ_d (FAR until then).
struct Blend {
    c: vec3<f32>,
    a: f32,
    z: f32,
}

// Adds `f` at opacity `o`; true once the pixel is saturated (what follows cannot show).
fn add(blend: ptr<function, Blend>, f: Fragment, o: f32) -> bool {
    let rgba = vec4<f32>(
        f32(f.px & 0xffu),
        f32((f.px >> 8u) & 0xffu),
        f32((f.px >> 16u) & 0xffu),
        f32(f.px >> 24u),
    );
    let w = (1.0 - (*blend).a) * o / 255.0;
    (*blend).c += w * rgba.rgb;
    (*blend).a += w * rgba.a;
    // A fragment with no depth leaves the depth to a later one.
    if (*blend).a >= params.depth_threshold && (*blend).z >= FAR {
        (*blend).z = f.z;
    }
    return (*blend).a >= 1.0 - 0.5 / 255.0;
}

@compute @workgroup_size(64, 1, 1)
fn cs_composite(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let pixels = params.width * params.height;
    for (var k = 0u; k < 16u; k += 1u) {
        let p = group.x * 1024u + k * 64u + lane;
        if p < pixels {
            composite_pixel(p, pixels);
        }
    }
}

fn composite_pixel(p: u32, pixels: u32) {
    let count = min(params.count, MAX_LAYERS);
    out_color[p] = 0u;
    out_depth[p] = -1.0;
    var blend = Blend(vec3<f32>(0.0), 0.0, FAR);
    if params.by_depth == 0u {
        // Ray order: the stack's order.
        for (var i = 0u; i < count; i += 1u) {
            let f = fragment(i, p, pixels);
            if f.present && add(&blend, f, opacity(i)) {
                break;
            }
        }
    } else {
        // Depth order without a per-pixel array (private arrays are slow on CPU drivers):
        // each step takes the nearest fragment after the previous one in (depth, stack index)
        // order, so equal depths keep the stack's order.
        var prev_z = -1.0;
        var prev = NONE;
        for (var step = 0u; step < count; step += 1u) {
            var best = NONE;
            var best_f = Fragment(0u, FAR, false);
            for (var i = 0u; i < count; i += 1u) {
                let f = fragment(i, p, pixels);
                let after = f.z > prev_z || (f.z == prev_z && i32(i) > prev);
                if f.present && after && (best == NONE || f.z < best_f.z) {
                    best = i32(i);
                    best_f = f;
                }
            }
            if best == NONE {
                break;
            }
            if params.nearest_only != 0u {
                out_color[p] = best_f.px;
                out_depth[p] = best_f.z;
                return;
            }
            if add(&blend, best_f, opacity(u32(best))) {
                break;
            }
            prev_z = best_f.z;
            prev = best;
        }
    }
    let alpha = round_code(255.0 * blend.a);
    if alpha < 1u {
        return;
    }
    let scale = 255.0 / blend.a;
    out_color[p] = round_code(blend.c.r * scale) | (round_code(blend.c.g * scale) << 8u)
        | (round_code(blend.c.b * scale) << 16u) | (alpha << 24u);
    out_depth[p] = select(-1.0, blend.z, blend.z < FAR);
}
