// Render: depth-corrected ray casting through a spherical light field (seed 000 §2) — `fixed` (the seed's fixed-step search) and the default edge-aware, refined marcher.

struct RenderParams {
    eye: vec3<f32>,
    width: u32,
    right: vec3<f32>,
    height: u32,
    up: vec3<f32>,
    focal_px: f32,
    forward: vec3<f32>,
    level: u32,
    step: f32,
    tolerance: f32,
    max_steps: u32,
    method: u32,
    resolution: f32,
    depth_scale: f32,
    edge_gap: f32,
    refine_iterations: u32,
    front_mass: f32,
    // Weight of the second setting (`*_b`): a pixel whose 4×4 ordered-dither threshold is below
    // it renders with that setting (a dithered cross-fade between two levels in one pass).
    blend: f32,
    // Coarse-to-fine guidance (0 = off): this pass is `coarse_factor` times finer than the
    // coarse pass whose z-depths `coarse` holds (coarse_width × coarse_height, −1 = miss).
    coarse_factor: u32,
    // Non-zero in a coarse pass: its pixel's half-width as an angle, times the guide's reach,
    // so a miss that passed close to a surface is marked near, with where it first did: its
    // depth output is −2 − z for that z-depth (−1 for a miss far from every surface).
    near_scale: f32,
    // Box around every surface point the maps hold (see `visible_box` in render.rs).
    box_min: vec3<f32>,
    // Non-zero in a compacted guided pass: workgroup w renders the 4×4 quads `tiles[4w..4w + 4]`
    // (see `cs_tiles`) instead of the w-th 8×8 tile of the frame; 2 in the pass that marches the
    // quads the interior pass gave back (`tiles[quad count + 4w..]`).
    tiled: u32,
    box_max: vec3<f32>,
    // Non-zero in a compacted guided pass whose flat quads take the interior pass (see
    // `cs_tiles`): the largest second difference of coarse z-depths between neighbours that a
    // flat quad may hold (z units).
    interior_curvature: f32,
    level_b: u32,
    step_b: f32,
    tolerance_b: f32,
    max_steps_b: u32,
    method_b: u32,
    coarse_width: u32,
    coarse_height: u32,
    // Pixels per row of the output buffers (a coarse pass pads rows for a texture copy).
    row_stride: u32,
    // Quads per workgroup of the interior pass: 4, or 16 when it shades 2×2 blocks of pixels
    // (ROLE 4).
    interior_group_quads: u32,
    // Guided passes: the step of the pass guiding this one, in this pass's steps (the coarse
    // passes step 1.5 times longer than the frame's: `COARSE_STEP_SCALE` in render.rs).
    guide_step_ratio: f32,
    // Sub-pixel shift of every ray, in this pass's pixels (0 but for still-frame refinement).
    jitter: vec2<f32>,
}

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(2) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>, 4>;
// The coarse pass's results (guided passes), two per pixel: x its z-depth (−1 a miss, or 0
// where a compacted coarse pass skipped the pixel; −2 − z a near miss that first came near a
// surface at z-depth z), y for a near miss the z-depth where it last did (1e30: unknown). A
// coarse pass writes them as pairs to `out_depth`. A texture, because lavapipe reads a storage
// buffer one lane at a time.
@group(0) @binding(4) var coarse: texture_2d<f32>;
// The 4×4 quads a guided pass renders (x | y << 16, in quads; twice the frame's quad count),
// the indirect dispatch sizes (x, 1, 1) of the passes that render them, four quads per
// workgroup, and the lists' lengths. `cs_tiles` lists the quads to march from the front of
// `tiles` (workgroups in `tile_dispatch[0]`, quads in `[9]`) and the flat quads for the interior
// pass from the back of its first half (`[3]`, `[10]`); the interior pass lists the flat quads
// it gives back to be marched in the second half (`[6]`, `[11]`), and sets the top bit of a
// flat quad's entry once it has.
@group(0) @binding(5) var<storage, read_write> tiles: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read_write> tile_dispatch: array<atomic<u32>, 12>;

// Uniform, not storage, buffers: lavapipe reads a storage buffer one lane at a time, a uniform
// one as a vector gather (the frame time halved). The sizes come from the camera set
// (shaders.rs `render_source`).
// The cameras: position and the index of the world axis their frame is built from (`camera`).
@group(1) @binding(0) var<uniform> cameras: array<vec4<f32>, CAMERA_COUNT>;
@group(1) @binding(1) var<uniform> hierarchy: array<HierTriangle, TRIANGLE_COUNT>;
// The level-MAX_LEVEL triangle of each direction (octahedral map; `locate`).
@group(1) @binding(5) var direction_lookup: texture_2d<u32>;
@group(1) @binding(2) var color_maps: texture_2d_array<f32>;
@group(1) @binding(3) var footprints: texture_2d_array<u32>;
@group(1) @binding(4) var linear_sampler: sampler;

const METHOD_FIXED: u32 = 0u;

// Pipeline specialisation. Lavapipe runs 8 pixels in SIMD lockstep and executes every branch of
// an `if` for them, taken or not, so code a pass cannot use is compiled out instead of skipped:
// METHODS is the marching methods this pipeline serves (1 = fixed, 2 = default, 3 = both, per
// pixel). ROLE: 0 for a plain pass (not guided, guiding nothing); 1 for the marching passes of a
// guided frame at full resolution (the guided pass and the pass over the quads the interior pass
// gives back); 2 for the interior pass of a guided frame (`shade_interior`); 3 for its coarse
// passes (pre-coarse and coarse, which their parameters tell apart: `guided_pass`), which mark
// near misses and need no colour; 4 for the interior pass shading a 2×2 block of pixels per
// invocation (`shade_interior_block`). Lavapipe runs all of a pipeline's code for every 8-pixel batch,
// so code for another role costs every batch: the coarse passes without the shading code are
// 0.3–0.4 ms faster per 512² demo frame. (A pipeline of its own per pass once made lavapipe
// evict and rebuild shaders every frame — it keeps only so many LLVM instructions of compiled
// shaders — but that was a branch on uniform values alone, below; none is rebuilt now.)
override METHODS: u32 = 3u;
override ROLE: u32 = 0u;

// Lavapipe (Mesa 22.3) rebuilds a shader each time its parameters are bound anew when an `if`
// or a loop bound depends on uniform values alone ("uniform inlining", with no cache of what it
// built): a pipeline holding one was rebuilt every frame, from Mesa's shader cache (about 3 ms)
// or, without one, by LLVM (0.7 s). So a decision on parameters alone goes through
// `per_invocation`, which ties it to the invocation in a way no compiler can fold. A naga test
// (tests/shaders.rs) finds any branch left on uniform values alone, `&&` and `||` included.
var<private> g_invocation: u32;

fn per_invocation(decision: bool) -> bool {
    // `&`, not `&&`: a short-circuit `&&` is itself a branch on `decision` alone.
    return decision & (g_invocation != 0xffffffffu);
}

// A coarse pass marks near misses for the pass it guides.
fn coarse_pass() -> bool {
    return ROLE == 3u && per_invocation(params.near_scale > 0.0);
}

// A coarse pass's depths bound a guided pass's marches.
fn guided_pass() -> bool {
    return (ROLE == 1u || ROLE == 3u) && per_invocation(params.coarse_factor != 0u);
}

// The interior pass of a guided frame, one pixel per invocation or two.
fn interior_role() -> bool {
    return ROLE == 2u || ROLE == 4u;
}

// Whether this pixel marches with the fixed-step baseline.
fn is_fixed() -> bool {
    return METHODS == 1u || (METHODS == 3u && g_method == METHOD_FIXED);
}

// This pixel's setting: the first one of `params`, or the `*_b` one (see `blend`).
var<private> g_level: u32;
var<private> g_step: f32;
var<private> g_tolerance: f32;
var<private> g_max_steps: u32;
var<private> g_method: u32;

// 4×4 ordered-dither (Bayer) rank of a pixel, 0..15: bits of (x ^ y) and y interleaved,
// reversed. Every 4×4 block holds each rank once.
fn bayer4(p: vec2<u32>) -> u32 {
    let a = (p.x ^ p.y) & 3u;
    let b = p.y & 3u;
    return ((a & 1u) << 3u) | ((b & 1u) << 2u) | (((a >> 1u) & 1u) << 1u) | ((b >> 1u) & 1u);
}
const BOUNDING_RADIUS: f32 = 0.70710678;
// A pixel next to a near miss marches to the end of the box, but with steps FAR_STRIDE times
// longer from NEAR_PAST steps past where its near-miss neighbours last came near a surface (and
// past the range of its neighbours' hits); see `guided_pass` in `cs_main`. Measured (12 views at
// 256², masked PSNR): (NEAR_PAST, FAR_STRIDE) = (3, 2), (1, 4) and (0, 4) within ±0.02 dB on
// the four fixtures; (3, 8) too, but (3, 16) −0.17 dB and (1, 6) −0.08 dB on the cow.
const NEAR_PAST: f32 = 1.0;
const FAR_STRIDE: f32 = 4.0;
// A neighbourhood of nine hits is two layers (an occlusion edge) when the gap between the depths
// below and above their midrange exceeds both layers' own spreads by BIMODAL_GAP steps.
const BIMODAL_GAP: f32 = 2.0;

// One camera's view of a point x: where it projects and what its depth map says there.
struct Probe {
    // f = |x − p| − D·chord: < 0 in front of the surface the camera sees, > 0 behind it.
    f: f32,
    // Continuous texel coordinates of the projection.
    tc: vec2<f32>,
    // Bilinear weights of the 2×2 footprint restricted to the chosen layer's hit texels (not
    // normalized): the colour's.
    layer_weights: vec4<f32>,
}

fn project(cam: Camera, x: vec3<f32>) -> vec4<f32> {
    let q = x - cam.position;
    let len = length(q);
    let qz = dot(q, cam.z);
    // uv = r.xy / (1 + r.z) for the unit direction r = q / |q|, with one division.
    let uv = vec2<f32>(dot(q, cam.x), dot(q, cam.y)) / max(len + qz, 1e-6 * max(len, 1e-12));
    let tc = (uv + 1.0) * 0.5 * params.resolution;
    // (texel x, texel y, |x − p|, chord 2·r_z)
    return vec4<f32>(tc, len, 2.0 * qz / max(len, 1e-12));
}

// Edge codes: a no-hit texel beside the silhouette has footprint code
// EDGE_BASE + (e level << 9 | depth level) (`edge_codes` in render.rs): the silhouette passes
// e = (e level + 0.5) / EDGE_E_LEVELS texel from its hit neighbours' centres, and depth level / 511
// extends the surface from them through the silhouette to its centre.
const EDGE_BASE: u32 = 57343u;
const EDGE_CODES: u32 = 8192u;
const EDGE_E_LEVELS: u32 = 16u;

// Depth at a projection. `edge_aware` splits the 2×2 footprint at its largest depth gap (above
// `edge_gap`) and keeps the front layer where it holds enough of the bilinear weight, else the
// back one, so no lookup ever returns a depth interpolated between a surface and what lies behind
// its silhouette (DESIGN §4). Edge texels place the silhouette between texel centres where the
// bake found it, and extend the front layer's depth to it (sub-texel silhouettes: bunny, 162
// cameras, 12 views at 256², masked PSNR 26.57 → 28.49 dB, SSIM 0.970 → 0.979, 338 → 198
// mismatched mask pixels per view).
fn probe(cam: Camera, k: u32, x: vec3<f32>, edge_aware: bool) -> Probe {
    let pr = project(cam, x);
    let tc = pr.xy;
    // The whole 2×2 footprint in one load: texel (x, y) of `footprints` holds the 16-bit depth
    // codes of texels (x, y), (x+1, y), (x, y+1), (x+1, y+1) — on lavapipe one load costs what
    // one bilinear sample does, while four loads or a gather cost four to eight times more.
    let n = i32(params.resolution);
    let base = clamp(vec2<i32>(floor(tc - 0.5)), vec2<i32>(0), vec2<i32>(n - 1));
    let codes = textureLoad(footprints, base, k, 0);
    // Edge texels (no hit, beside the silhouette) read as no hit (1) for the split.
    let rel = codes - vec4<u32>(EDGE_BASE);
    let edge = rel < vec4<u32>(EDGE_CODES);
    let d = select(vec4<f32>(codes) * (1.0 / 65535.0), vec4<f32>(1.0), edge);
    let fr = fract(tc - 0.5);
    let bw = vec4<f32>((1.0 - fr.x) * (1.0 - fr.y), fr.x * (1.0 - fr.y), (1.0 - fr.x) * fr.y, fr.x * fr.y);
    // Written without `if`: lavapipe runs an `if`'s body whatever the condition, then merges
    // every value it assigned; as selects, the split costs what its arithmetic does, and a march
    // probe computes no colour weights (a 512² demo frame 0.5–1.0 ms faster).
    let lo = min(min(d.x, d.y), min(d.z, d.w));
    let hi = max(max(d.x, d.y), max(d.z, d.w));
    let split = edge_aware & (hi - lo > params.edge_gap);
    let front = d <= vec4<f32>(0.5 * (lo + hi));
    // The front layer's share of the footprint: a front texel counts 1, a back one 0, an edge
    // texel sigma = 1 − (1 − front_mass) / e, so that between it and a front texel the share
    // falls to `front_mass` exactly at the silhouette, e of the way from the front texel.
    // The interior pass (ROLE 2 and 4: flat quads, no silhouette near the eye's ray) reads edge
    // texels as plain no hit: the same pixels (bunny and demo, 12 views at 256², masked PSNR
    // within 0.002 dB), 1.9 ms less per 512² bunny frame.
    let edges = edge & vec4<bool>(!interior_role());
    let sigma = vec4<f32>(1.0) - ((1.0 - params.front_mass) * f32(EDGE_E_LEVELS)) / (vec4<f32>(rel >> vec4<u32>(9u)) + 0.5);
    let share = select(select(vec4<f32>(0.0), sigma, edges), vec4<f32>(1.0), front);
    let chosen = dot(bw, share) >= params.front_mass;
    // Colour from the chosen layer's hits (`layer_color` normalizes); depth in the front layer
    // from its hits and edge texels, whose extrapolated depths make the surface recede to the
    // silhouette's depth. Unsplit: the whole footprint.
    let layer = select(!front, front, chosen);
    let color_weights = select(bw, bw * vec4<f32>(layer), split);
    let kept = select(vec4<f32>(0.0), bw, layer | (edges & vec4<bool>(chosen)));
    let layer_d = select(d, vec4<f32>(rel & vec4<u32>(511u)) * (1.0 / 511.0), edges & vec4<bool>(chosen));
    let depth = select(dot(bw, d), dot(kept, layer_d) / max(kept.x + kept.y + kept.z + kept.w, 1e-12), split);
    return Probe(pr.z - depth * pr.w, tc, color_weights);
}

// Colour of camera k at texel coordinates tc from the footprint texels with the given weights,
// normalized by their sum
// (four loads: a bilinear sample could mix colours across a silhouette). Measured (bunny, 162
// cameras, 12 views at 256²): one bilinear sample instead scores +0.5 dB masked PSNR, but only
// by darkening silhouette pixels towards the background; inside both masks it loses 3.3 dB
// (36.9 → 33.6) and MAE rises 17 %.
fn layer_color(k: u32, tc: vec2<f32>, bw: vec4<f32>) -> vec4<f32> {
    let n = i32(params.resolution);
    let base = vec2<i32>(floor(tc - 0.5));
    let i0 = clamp(base, vec2<i32>(0), vec2<i32>(n - 1));
    let i1 = clamp(base + 1, vec2<i32>(0), vec2<i32>(n - 1));
    let sum = bw.x * textureLoad(color_maps, vec2<i32>(i0.x, i0.y), k, 0)
        + bw.y * textureLoad(color_maps, vec2<i32>(i1.x, i0.y), k, 0)
        + bw.z * textureLoad(color_maps, vec2<i32>(i0.x, i1.y), k, 0)
        + bw.w * textureLoad(color_maps, vec2<i32>(i1.x, i1.y), k, 0);
    return sum / max(bw.x + bw.y + bw.z + bw.w, 1e-12);
}

fn bilinear_color(k: u32, tc: vec2<f32>) -> vec4<f32> {
    return textureSampleLevel(color_maps, linear_sampler, tc / params.resolution, k, 0.0);
}

struct March {
    t: f32,
    hit: bool,
    fetches: u32,
    steps: u32,
    // The first t where the ray came near a surface some camera sees (|f| / t, an angle seen
    // from the eye, below `near_scale`; coarse passes only): 1e30 if it never did.
    near_first: f32,
    // The last t where it did (coarse passes only): −1e30 if it never did.
    near_last: f32,
}

// Seed 000 §2: fixed steps; stop at the first sample where any camera's estimate agrees within
// the tolerance (bilinear depth).
fn march_fixed(o: vec3<f32>, d: vec3<f32>, t_in: f32, t_out: f32, cams: vec3<u32>, c0: Camera, c1: Camera, c2: Camera) -> March {
    var m = March(t_in, false, 0u, 0u, 1e30, -1e30);
    var t = t_in;
    for (var s = 0u; s < g_max_steps; s++) {
        if t > t_out {
            break;
        }
        let x = o + t * d;
        m.steps += 1u;
        m.fetches += 3u;
        let f = vec3<f32>(probe(c0, cams.x, x, false).f, probe(c1, cams.y, x, false).f, probe(c2, cams.z, x, false).f);
        if min(min(abs(f.x), abs(f.y)), abs(f.z)) < g_tolerance {
            m.t = t;
            m.hit = true;
            return m;
        }
        t += g_step;
    }
    return m;
}

fn probe_camera(cams: vec3<u32>, c0: Camera, c1: Camera, c2: Camera, i: u32, x: vec3<f32>) -> f32 {
    var cam = c0;
    if i == 1u {
        cam = c1;
    } else if i == 2u {
        cam = c2;
    }
    return probe(cam, cams[i], x, true).f;
}

// Default: coarse steps with edge-aware depth; a camera whose estimate changes sign from in
// front (f < 0) to behind (f ≥ 0) brackets a crossing, refined by bisection; the crossing is
// accepted only where that camera's f is continuous across the final bracket (its jump is below
// the tolerance) — a silhouette jump is a phantom, not a surface.
//
// Shaped for lavapipe, which runs 8 pixels in SIMD lockstep: an `if` costs its body whether or
// not any lane takes it, and a loop runs as often as its slowest lane (at least once). So the
// step loop holds only the three probes and stops at the first bracket; bisection runs after it,
// on one camera (the bracketing one whose secant estimate is earliest), and a rejected bracket
// excludes that camera and retries the same step before marching on.
fn march_refined(o: vec3<f32>, d: vec3<f32>, t_in: f32, t_out: f32, stride_from: f32, cams: vec3<u32>, weights: vec3<f32>, c0: Camera, c1: Camera, c2: Camera) -> March {
    var m = March(t_in, false, 0u, 0u, 1e30, -1e30);
    // The current step is [t_prev, t]. The march starts one step before t_in, "behind" every
    // surface (f > 0: no bracket), so its first step samples t_in itself.
    var t_prev = t_in - g_step;
    var t = t_prev;
    var f = vec3<f32>(1.0);
    var f_prev = f;
    var excluded = vec3<bool>(false);
    for (var attempt = 0u; attempt < g_max_steps + 3u; attempt++) {
        // March to the first step some non-excluded camera brackets.
        var cam = 3u;
        for (var s = 0u; s <= g_max_steps; s++) {
            // Secant estimate of each bracketing camera's crossing; the earliest wins.
            let bracket = (f_prev < vec3<f32>(0.0)) & (f >= vec3<f32>(0.0)) & !excluded;
            let frac = -f_prev / max(f - f_prev, vec3<f32>(1e-12));
            let est = select(vec3<f32>(2.0), frac, bracket);
            if bracket.x || bracket.y || bracket.z {
                cam = select(select(2u, 1u, est.y <= est.z), 0u, est.x <= est.y && est.x <= est.z);
                break;
            }
            if t >= t_out || m.steps > g_max_steps {
                break;
            }
            t_prev = t;
            f_prev = f;
            excluded = vec3<bool>(false);
            t = min(max(t_prev + select(g_step, FAR_STRIDE * g_step, t_prev > stride_from), t_in), t_out);
            let x = o + t * d;
            m.steps += 1u;
            f = vec3<f32>(probe_camera(cams, c0, c1, c2, 0u, x), probe_camera(cams, c0, c1, c2, 1u, x), probe_camera(cams, c0, c1, c2, 2u, x));
            m.fetches += 3u;
            let af = abs(f);
            let near = min(min(af.x, af.y), af.z) < params.near_scale * max(t, 1e-6);
            m.near_first = select(m.near_first, min(m.near_first, t), near);
            m.near_last = select(m.near_last, max(m.near_last, t), near);
        }
        if cam == 3u {
            break;
        }
        var lo = t_prev;
        var hi = t;
        var f_lo = f_prev[cam];
        var f_hi = f[cam];
        // A per-lane trip count: a batch of pixels with no bracket runs this loop once, not
        // refine_iterations times.
        let iterations = select(0u, params.refine_iterations, cam < 3u);
        for (var it = 0u; it < iterations; it++) {
            let mid = 0.5 * (lo + hi);
            let f_mid = probe_camera(cams, c0, c1, c2, cam, o + mid * d);
            m.fetches += 1u;
            if f_mid < 0.0 {
                lo = mid;
                f_lo = f_mid;
            } else {
                hi = mid;
                f_hi = f_mid;
            }
        }
        if f_hi - f_lo < g_tolerance {
            m.t = lo + (hi - lo) * (-f_lo) / max(f_hi - f_lo, 1e-12);
            m.hit = true;
            break;
        }
        excluded[cam] = true;
    }
    return m;
}

// Where fine pixel p's centre lies in the coarse pass, in coarse pixels (guided passes; coarse
// pixel (i, j) has its centre at (i, j)).
fn coarse_position(p: vec2<u32>) -> vec2<f32> {
    let f = f32(params.coarse_factor);
    let half_fine = 0.5 * vec2<f32>(f32(params.width), f32(params.height));
    let half_coarse = 0.5 * vec2<f32>(f32(params.coarse_width), f32(params.coarse_height));
    return (vec2<f32>(p) + 0.5 - half_fine) / f + half_coarse - 0.5;
}

// The coarse pixel nearest to fine pixel p's centre.
fn coarse_nearest(p: vec2<u32>) -> vec2<i32> {
    return vec2<i32>(round(coarse_position(p)));
}

// Line o + t·d (|d| = 1) against the box [lo, hi] (slab test): the entry and exit t, entry > exit
// when missed. Near-zero direction components are replaced by ±1e-20 so every product stays
// finite.
fn box_roots(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    let dd = select(d, select(vec3<f32>(1e-20), vec3<f32>(-1e-20), d < vec3<f32>(0.0)), abs(d) < vec3<f32>(1e-20));
    let t0 = (lo - o) / dd;
    let t1 = (hi - o) / dd;
    let near = min(t0, t1);
    let far = max(t0, t1);
    return vec2<f32>(max(max(near.x, near.y), near.z), min(min(far.x, far.y), far.z));
}

// The frame's 4×4 quads per row and per column.
fn frame_quads() -> vec2<u32> {
    return (vec2<u32>(params.width, params.height) + 3u) / 4u;
}

// Appends quad `entry` to list `list` (0: to march, 1: flat, 2: given back), whose k-th entry
// lives at `tiles[first + step · k]`, and counts a workgroup for every fourth (every
// `interior_group_quads`-th of the flat ones).
fn list_quad(list: u32, first: u32, step: i32, entry: u32) {
    let k = atomicAdd(&tile_dispatch[9u + list], 1u);
    if k % select(4u, params.interior_group_quads, list == 1u) == 0u {
        atomicAdd(&tile_dispatch[3u * list], 1u);
    }
    atomicStore(&tiles[u32(i32(first) + step * i32(k))], entry);
}

// A hit's colour (packed), z-depth and texture fetches, and whether some camera agreed with it.
struct Shaded {
    color: u32,
    z: f32,
    fetches: u32,
    agreed: bool,
}

// Shades the point at t on ray o + t·d: the three cameras' colours, each weighted by its
// barycentric weight and by its agreement with the point (seed 000 §2). With `newton`, the
// z-depth written is corrected by one Newton step towards the earliest surface crossing among
// the cameras that fully agree (|f| within half the tolerance): a camera's f is how far the
// point lies behind the surface it sees, along that camera's ray, which moves at rate
// dot(d, u) as t does (u the camera ray; the slope of the depth map ignored), floored at 0.2 so
// a grazing camera ray cannot throw the step far. The earliest crossing, like the marcher's
// first bracket, is the least biased: a depth map interpolated between texels lies behind a
// convex surface. (Measured, eval on 6 views at 512²: median depth error 1.7e-4 r on the bunny
// and 5.5e-4 r on the demo, against 2.5e-4 and 1.1e-3 with the weighted mean of the cameras'
// steps, and 1.9e-4 and 6.5e-4 where every pixel is marched.) `z_rate`: the ray's z-depth per
// unit of t.
fn shade(o: vec3<f32>, d: vec3<f32>, z_rate: f32, t: f32, loc: Located, c0: Camera, c1: Camera, c2: Camera, newton: bool) -> Shaded {
    let x = o + t * d;
    var color = vec4<f32>(0.0);
    var total = 0.0;
    var fallback = vec4<f32>(0.0);
    var fallback_f = 1e30;
    // The largest step back (f / rate) of a fully agreeing camera; none yet.
    var correction = -1e30;
    var fetches = 0u;
    for (var i = 0u; i < 3u; i++) {
        let k = loc.cameras[i];
        let edge_aware = !is_fixed();
        var cam = c0;
        if i == 1u {
            cam = c1;
        } else if i == 2u {
            cam = c2;
        }
        let pb = probe(cam, k, x, edge_aware);
        var c: vec4<f32>;
        if edge_aware {
            c = layer_color(k, pb.tc, pb.layer_weights);
            fetches += LAYER_SHADE_FETCHES;
        } else {
            c = bilinear_color(k, pb.tc);
            fetches += 2u;
        }
        // Agreement: full weight within half the tolerance, fading to zero at the tolerance.
        let agree = clamp(2.0 - 2.0 * abs(pb.f) / g_tolerance, 0.0, 1.0);
        let w = loc.weights[i] * agree;
        color += w * c;
        total += w;
        if newton && agree >= 1.0 && loc.weights[i] > 0.0 {
            correction = max(correction, pb.f / max(dot(d, normalize(x - cam.position)), 0.2));
        }
        if abs(pb.f) < fallback_f {
            fallback_f = abs(pb.f);
            fallback = c;
        }
    }
    var t_out = t;
    if total > 1e-6 {
        color = color / total;
        if newton && correction > -1e29 {
            t_out = t - correction;
        }
    } else {
        color = fallback;
    }
    let z = t_out * z_rate;
    return Shaded(pack4x8unorm(vec4<f32>(color.rgb, 1.0)), z, fetches, total > 1e-6);
}

// The interior pass (ROLE 2): a pixel of a flat quad (see `cs_tiles`) takes the z-depth
// interpolated between its four nearest coarse pixels, all hits, instead of marching, and is
// shaded there; one Newton step (`shade`) corrects the depth it reports. Where no camera agrees
// with the interpolated point (a gap or an edge narrower than the coarse pixels, which their
// depths cannot show), the quad is given back: listed once, it is marched by the next pass.
fn shade_interior(gid: vec2<u32>, index: u32, o: vec3<f32>, d: vec3<f32>, z_rate: f32, slot: u32) {
    let loc = locate(sphere_entry(o, d), g_level);
    let shaded = shade(o, d, z_rate, interior_t(gid, z_rate), loc, camera(loc.cameras.x), camera(loc.cameras.y), camera(loc.cameras.z), true);
    out_color[index] = shaded.color;
    out_depth[index] = shaded.z;
    // Its work is counted by `cs_tiles`, per quad.
    if !shaded.agreed {
        give_back(slot);
    }
}

// The interior pass with a 2×2 block of pixels per invocation (ROLE 4): they take the cameras
// of the triangle met by the ray through the block's centre, each weighing them by its own
// direction, so the triangle lookup and the cameras' frames serve all four (per 512² demo frame
// the interior pass 6.0 → 4.8 ms; two pixels per invocation: 5.0 ms). A pixel whose direction
// lies outside that triangle is off by at most the angle between its entry into the camera
// sphere and the centre ray's, as a direction near a triangle's edge is off with the lookup
// itself (`locate`); the renderer uses blocks only where that angle cannot exceed the lookup's
// reach (`INTERIOR_BLOCK_REACH` in render.rs). The four pixels' centres also lie in one cell
// between the same four coarse pixels (the renderer uses blocks only where the coarse grid
// makes that so: `blocks_share_coarse_cells` in render.rs), which are loaded once for the
// block: each pixel interpolates between them with its own weights, as `interior_t` would
// (3.7 → 3.2 ms per 512² demo frame).
fn shade_interior_block(gid: vec2<u32>, index: u32, o: vec3<f32>, slot: u32) {
    let loc = locate(sphere_entry(o, pixel_ray(vec2<f32>(gid) + 1.0)), g_level);
    let c0 = camera(loc.cameras.x);
    let c1 = camera(loc.cameras.y);
    let c2 = camera(loc.cameras.z);
    let cell = coarse_cell(gid);
    let a = shade_block_pixel(gid, o, loc.cameras, c0, c1, c2, cell);
    let b = shade_block_pixel(gid + vec2<u32>(1u, 0u), o, loc.cameras, c0, c1, c2, cell);
    let c = shade_block_pixel(gid + vec2<u32>(0u, 1u), o, loc.cameras, c0, c1, c2, cell);
    let e = shade_block_pixel(gid + vec2<u32>(1u, 1u), o, loc.cameras, c0, c1, c2, cell);
    // The block's right column or bottom row lies outside a frame of odd width or height.
    let right = gid.x + 1u < params.width;
    let below = gid.y + 1u < params.height;
    out_color[index] = a.color;
    out_depth[index] = a.z;
    if right {
        out_color[index + 1u] = b.color;
        out_depth[index + 1u] = b.z;
    }
    if below {
        out_color[index + params.row_stride] = c.color;
        out_depth[index + params.row_stride] = c.z;
    }
    if right & below {
        out_color[index + params.row_stride + 1u] = e.color;
        out_depth[index + params.row_stride + 1u] = e.z;
    }
    let agreed = a.agreed & (b.agreed | !right) & (c.agreed | !below) & (e.agreed | !(right & below));
    if !agreed {
        give_back(slot);
    }
}

// One pixel of an interior block: shaded with the block's cameras, weighed by its own direction,
// at the z-depth interpolated in the block's coarse cell.
fn shade_block_pixel(p: vec2<u32>, o: vec3<f32>, cams: vec3<u32>, c0: Camera, c1: Camera, c2: Camera, cell: vec4<f32>) -> Shaded {
    let d = pixel_ray(vec2<f32>(p) + 0.5);
    let z_rate = dot(d, params.forward) * params.depth_scale;
    let loc = Located(cams, triangle_weights(sphere_entry(o, d), c0.position, c1.position, c2.position));
    return shade(o, d, z_rate, cell_t(cell, p, z_rate), loc, c0, c1, c2, true);
}

// The z-depths of the four coarse pixels around fine pixel p's centre: (x, y) the cell's top
// row, left to right, (z, w) its bottom row.
fn coarse_cell(p: vec2<u32>) -> vec4<f32> {
    let base = vec2<i32>(floor(coarse_position(p)));
    let last = vec2<i32>(i32(params.coarse_width) - 1, i32(params.coarse_height) - 1);
    return vec4<f32>(
        textureLoad(coarse, clamp(base, vec2<i32>(0), last), 0).x,
        textureLoad(coarse, clamp(base + vec2<i32>(1, 0), vec2<i32>(0), last), 0).x,
        textureLoad(coarse, clamp(base + vec2<i32>(0, 1), vec2<i32>(0), last), 0).x,
        textureLoad(coarse, clamp(base + vec2<i32>(1, 1), vec2<i32>(0), last), 0).x,
    );
}

// The ray parameter of fine pixel p, whose centre lies in coarse cell `cell` (`coarse_cell`):
// the z-depth interpolated between the cell's coarse pixels (all hits in a flat quad), over the
// ray's z-depth per unit of t.
fn cell_t(cell: vec4<f32>, p: vec2<u32>, z_rate: f32) -> f32 {
    let cc = coarse_position(p);
    let fr = cc - floor(cc);
    let z = mix(mix(cell.x, cell.y, fr.x), mix(cell.z, cell.w, fr.x), fr.y);
    return max(z / z_rate, 0.0);
}

// The interior pass's ray parameter for fine pixel p (one pixel per invocation).
fn interior_t(p: vec2<u32>, z_rate: f32) -> f32 {
    return cell_t(coarse_cell(p), p, z_rate);
}

// Lists a flat quad the interior pass could not shade (no camera agreed with some pixel) once,
// to be marched by the next pass.
fn give_back(slot: u32) {
    let entry = atomicOr(&tiles[slot], 0x80000000u);
    if entry < 0x80000000u {
        let grid = frame_quads();
        list_quad(2u, grid.x * grid.y, 1, entry);
    }
}

// The eye ray through point p of the image (in pixels from its top-left corner: pixel (i, j)
// has its centre at (i + 0.5, j + 0.5)), moved by the pass's jitter, unit.
fn pixel_ray(p: vec2<f32>) -> vec3<f32> {
    let q = p + params.jitter;
    let px = (q.x - 0.5 * f32(params.width)) / params.focal_px;
    let py = -(q.y - 0.5 * f32(params.height)) / params.focal_px;
    return normalize(px * params.right + py * params.up + params.forward);
}

// The line o + t·d's first intersection with the camera sphere, as a direction from its centre:
// it picks the three cameras (seed 000 §2), and exists whenever the line meets the bounding
// sphere inside it.
fn sphere_entry(o: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    let cs = sphere_roots(o, d, 1.0);
    return normalize(o + cs.x * d);
}

// What `shade` counts per camera for an edge-aware pixel: one footprint and four colour loads.
const LAYER_SHADE_FETCHES: u32 = 5u;
// What `shade` counts for an interior pixel: three cameras, edge-aware.
const INTERIOR_FETCHES: u32 = 3u * LAYER_SHADE_FETCHES;

// Compaction for a guided pass (the frame's, or a coarse pass guided by a pre-coarse one), one
// invocation per 4×4 quad of its output: a quad is kept when some pixel of it has a coarse
// neighbour that hit or passed near a surface, i.e. when the guided pass would march some pixel
// of it (see `guided_pass` in `cs_main`). Lavapipe runs every instruction of a shader for every
// pixel, early `return` or not, so skipping a pixel saves nothing; only work never dispatched
// costs nothing. (The coarse pass of a 512² frame with nothing in view: 2.0–3.1 ms
// uncompacted.)
//
// A kept quad is flat when `interior_curvature` > 0, every coarse pixel around it hit, and no
// second difference of their z-depths along x or y exceeds `interior_curvature`: no silhouette
// or occlusion edge crosses it (a depth jump is a large second difference), and bilinear
// interpolation between the coarse depths is within an eighth of the bound per axis of any
// smooth surface through them. Flat quads go to the interior pass, which does not march.
// Quads rather than the 8×8 tiles of a workgroup: a tile along an edge held pixels that needed
// no march, and marched them (one demo view at 512²: 792 of its 2536 quads had nine hits
// around every pixel, 276 no pixel to march; eval, 6 views at 512², 4 interleaved runs, demo
// 24.7 → 22.0 ms, bunny 20.9 → 19.2).
// The coarse neighbourhood the tile pass reads per quad: 4×4, or 3×3 where every quad's pixels
// have the same nearest coarse pixel (`quads_share_nearest_coarse` in render.rs), so that its
// neighbourhood spans 3×3 at most (the 512² demo frame's tile pass 0.73 → 0.62 ms).
override TILE_SPAN: i32 = 4;

@compute @workgroup_size(8, 8, 1)
fn cs_tiles(@builtin(global_invocation_id) gid: vec3<u32>) {
    let grid = frame_quads();
    if any(gid.xy >= grid) {
        return;
    }
    let last = vec2<i32>(i32(params.coarse_width) - 1, i32(params.coarse_height) - 1);
    let first_px = gid.xy * 4u;
    let last_px = min(first_px + 3u, vec2<u32>(params.width - 1u, params.height - 1u));
    // Every coarse pixel a pixel of the quad reads: its 3×3 neighbourhood, which holds the four
    // it interpolates between.
    let lo = clamp(coarse_nearest(first_px) - 1, vec2<i32>(0), last);
    let hi = clamp(coarse_nearest(last_px) + 1, vec2<i32>(0), last);
    let size = hi - lo + 1;
    // At most 4×4 coarse pixels (a quad spans at most 1.5 coarse pixels for a coarse factor of
    // 2 or more), read as TILE_SPAN × TILE_SPAN with coordinates clamped to the neighbourhood:
    // constant loops, unrolled, so the depths stay in registers.
    var keep = false;
    var all_hit = true;
    var z: array<f32, 16>;
    for (var j = 0; j < TILE_SPAN; j++) {
        for (var i = 0; i < TILE_SPAN; i++) {
            let v = textureLoad(coarse, min(lo + vec2<i32>(i, j), hi), 0).x;
            // Not a far miss (−1, or 0 where a compacted coarse pass skipped the pixel): a hit
            // (> 0) or a near miss (≤ −2).
            keep = keep | !((v <= 0.0) & (v > -1.5));
            all_hit = all_hit & (v > 0.0);
            z[j * 4 + i] = v;
        }
    }
    var bumpy = false;
    for (var j = 0; j < TILE_SPAN; j++) {
        for (var i = 1; i < TILE_SPAN - 1; i++) {
            let along_x = abs(z[j * 4 + i - 1] + z[j * 4 + i + 1] - 2.0 * z[j * 4 + i]);
            bumpy = bumpy | ((i + 1 < size.x) & (j < size.y) & (along_x > params.interior_curvature));
            let along_y = abs(z[(i - 1) * 4 + j] + z[(i + 1) * 4 + j] - 2.0 * z[i * 4 + j]);
            bumpy = bumpy | ((i + 1 < size.y) & (j < size.x) & (along_y > params.interior_curvature));
        }
    }
    // `&`, not `&&` (see `per_invocation`).
    let flat = keep & (params.interior_curvature > 0.0) & all_hit & !bumpy;
    // The interior pass's work, counted here once per quad rather than by its pixels (lavapipe:
    // 0.7 of the bunny's 6.9 ms interior pass at 512²): each pixel of a flat quad inside the
    // frame is one ray shaded with INTERIOR_FETCHES fetches.
    let pixels = select(0u, (last_px.x - first_px.x + 1u) * (last_px.y - first_px.y + 1u), flat);
    count_work(INTERIOR_FETCHES * pixels, 0u, pixels);
    if keep {
        let quad = gid.x | (gid.y << 16u);
        if flat {
            list_quad(1u, grid.x * grid.y - 1u, -1, quad);
        } else {
            list_quad(0u, 0u, 1, quad);
        }
    }
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) global_id: vec3<u32>, @builtin(workgroup_id) group_id: vec3<u32>, @builtin(local_invocation_id) local_id: vec3<u32>) {
    g_invocation = global_id.x;
    // Which pixel of its 8×8 tile an invocation renders (a compacted pass maps the workgroup
    // onto four listed quads below, each batch a 4×2 half of one). Lavapipe runs a workgroup as 8-lane
    // SIMD batches of consecutive invocations, one row of the tile each, and a batch marches
    // as long as its slowest lane; each batch takes a 4×2 block of pixels instead, whose
    // marches are more alike (lane-steps of the guided pass −16 % on the bunny, −18 % on the
    // demo, one view at 512²; guided and coarse passes 7–11 % faster in all, the same pixels).
    let lane = vec2<u32>((local_id.y % 2u) * 4u + local_id.x % 4u, (local_id.y / 2u) * 2u + local_id.x / 4u);
    var gid = vec3<u32>(group_id.xy * 8u + lane, 0u);
    var slot = 0u;
    let interior = interior_role();
    if interior || ((ROLE == 1u || ROLE == 3u) && per_invocation(params.tiled != 0u)) {
        // Quads to march from the front of the list, flat ones from the back of its first half,
        // given-back ones from its second half (see `tiles`); four quads per workgroup, each
        // 8-lane batch a 4×2 half of one (ROLE 4: sixteen quads, each batch two, each
        // invocation a 2×2 block; smaller workgroups of fewer quads each made the pass
        // 0.3–0.5 ms slower on the demo).
        let grid = frame_quads();
        let quad_count = grid.x * grid.y;
        let invocation = local_id.y * 8u + local_id.x;
        let per_quad = select(16u, 4u, ROLE == 4u);
        let k = (64u / per_quad) * group_id.x + invocation / per_quad;
        var list = 0u;
        slot = k;
        if interior {
            list = 1u;
            slot = quad_count - 1u - k;
        } else if per_invocation(params.tiled == 2u) {
            list = 2u;
            slot = quad_count + k;
        }
        if k >= atomicLoad(&tile_dispatch[9u + list]) {
            return;
        }
        let quad = atomicLoad(&tiles[slot]) & 0x7fffffffu;
        let within = invocation % per_quad;
        let in_quad = select(vec2<u32>(within % 4u, within / 4u), vec2<u32>(within % 2u, within / 2u) * 2u, ROLE == 4u);
        gid = vec3<u32>(vec2<u32>(quad & 0xffffu, quad >> 16u) * 4u + in_quad, 0u);
    }
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let index = gid.y * params.row_stride + gid.x;
    let use_b = (f32(bayer4(gid.xy)) + 0.5) / 16.0 < params.blend;
    g_level = select(params.level, params.level_b, use_b);
    g_step = select(params.step, params.step_b, use_b);
    g_tolerance = select(params.tolerance, params.tolerance_b, use_b);
    g_max_steps = select(params.max_steps, params.max_steps_b, use_b);
    g_method = select(params.method, params.method_b, use_b);
    // A coarse pass writes two values per pixel (see `coarse`).
    let di = select(index, 2u * index, coarse_pass());
    out_color[index] = 0u;
    out_depth[di] = -1.0;
    if coarse_pass() {
        out_depth[di + 1u] = -1.0;
    }
    let d = pixel_ray(vec2<f32>(gid.xy) + 0.5);
    let o = params.eye;
    // z-depth per unit of t along this ray.
    let z_rate = dot(d, params.forward) * params.depth_scale;
    if ROLE == 2u {
        shade_interior(gid.xy, index, o, d, z_rate, slot);
        return;
    }
    if ROLE == 4u {
        shade_interior_block(gid.xy, index, o, slot);
        return;
    }
    // A coarse pass grows the sphere and box by its reach at their far side and marches what
    // they bound, so a ray passing just outside them is marked near where it comes near a
    // surface (a fine pixel beside it may hit), like any other. (Marking every ray that met
    // the grown sphere or box near, without marching it, sent a ring of tiles along the
    // sphere's and box's outlines to the guided pass: bunny, one view at 512², 1039 → 431
    // marched tiles; frame 10–20 % faster on the four fixtures, masked PSNR −0.003 to
    // +0.03 dB.) The march stays inside the camera sphere, where the cameras can tell; when the
    // reach takes the grown sphere beyond it (a far eye), a ray meeting the grown sphere and box
    // is marked near from where it enters them, as before, unless the march finds a surface.
    let grow = select(0.0, params.near_scale * (length(o) + BOUNDING_RADIUS), coarse_pass());
    var reach_t = 1e30;
    if coarse_pass() && BOUNDING_RADIUS + grow > 1.0 {
        let gs = sphere_roots(o, d, BOUNDING_RADIUS + grow);
        let gb = box_roots(o, d, params.box_min - vec3<f32>(grow), params.box_max + vec3<f32>(grow));
        let g_in = max(max(gs.x, gb.x), 0.0);
        if g_in <= min(gs.y, gb.y) {
            reach_t = g_in;
            out_depth[di] = -2.0 - g_in * z_rate;
            out_depth[di + 1u] = 1e30;
        }
    }
    let bounds = sphere_roots(o, d, min(BOUNDING_RADIUS + grow, 1.0));
    if bounds.y < 0.0 || bounds.x > bounds.y {
        return;
    }
    var t_in = max(bounds.x, 0.0);
    var stride_from = 1e30;
    var t_out = bounds.y;
    if !is_fixed() {
        // Clip to the visible box. The fixed baseline keeps the seed's sphere.
        let box = box_roots(o, d, params.box_min - vec3<f32>(grow), params.box_max + vec3<f32>(grow));
        t_in = max(t_in, box.x);
        t_out = min(t_out, box.y);
        if t_in > t_out {
            return;
        }
        if guided_pass() {
            // Coarse-to-fine (the `guide` knob): the 3×3 coarse pixels around this one bound
            // where its surface can be. All nine missed far from any surface: so does this
            // pixel. Else march from before the nearest of their hits and near passes to past
            // the farthest hit (or to the end of the box, next to a near miss).
            let cw = i32(params.coarse_width);
            let ch = i32(params.coarse_height);
            let nearest = coarse_nearest(gid.xy);
            var z_min = 1e30;
            var z_max = -1e30;
            var near_min = 1e30;
            var near_max = -1e30;
            var misses = 0u;
            var near_misses = 0u;
            // Unrolled, so the nine depths stay in registers.
            var depths: array<f32, 9>;
            for (var dy = -1; dy <= 1; dy++) {
                for (var dx = -1; dx <= 1; dx++) {
                    let p = clamp(nearest + vec2<i32>(dx, dy), vec2<i32>(0), vec2<i32>(cw - 1, ch - 1));
                    let c = textureLoad(coarse, p, 0);
                    let z = c.x;
                    depths[(dy + 1) * 3 + dx + 1] = z;
                    if z < -1.5 {
                        near_misses += 1u;
                        near_min = min(near_min, -2.0 - z);
                        near_max = max(near_max, c.y);
                    } else if z <= 0.0 {
                        misses += 1u;
                    } else {
                        z_min = min(z_min, z);
                        z_max = max(z_max, z);
                    }
                }
            }
            if misses == 9u {
                return;
            }
            var lo = 1e30;
            var hi = -1e30;
            if z_min <= z_max {
                // Hits: a quarter step of margin (the coarse depths are accurate to far less)
                // plus the neighbourhood's own depth spread: on a steep or curved surface this
                // pixel's depth can lie beyond its neighbours' range. Where some neighbours
                // missed (a silhouette), three more steps past the farthest hit. (A full step
                // of margin marches one more step per pixel for nothing: bunny 26.30 dB with
                // it, 26.32 without.) At an occlusion edge (nine hits in two layers, see
                // BIMODAL_GAP) the spread is the gap between the layers, not a curvature: the
                // margin before the front layer and past the back one is that layer's own spread
                // (one demo view at 512²: the frame pass's lane-steps −4.5 %; masked PSNR
                // −0.004…+0.03 dB on the four fixtures at 256² and 512²). Not where some
                // neighbours missed: there it cost 12 more mismatched pixels per demo view.
                let mid = 0.5 * (z_min + z_max);
                var front_max = -1e30;
                var back_min = 1e30;
                for (var k = 0; k < 9; k++) {
                    let z = depths[k];
                    front_max = select(front_max, max(front_max, z), z <= mid);
                    back_min = select(back_min, min(back_min, z), z > mid);
                }
                let front_spread = front_max - z_min;
                let back_spread = z_max - back_min;
                let layers = (misses + near_misses == 0u) & (back_min - front_max > max(front_spread, back_spread) + BIMODAL_GAP * g_step * z_rate);
                let spread = z_max - z_min;
                let margin_front = 0.25 * g_step + select(spread, front_spread, layers) / z_rate;
                let margin_back = 0.25 * g_step + select(spread, back_spread, layers) / z_rate;
                lo = z_min / z_rate - margin_front;
                hi = z_max / z_rate + margin_back + select(0.0, 3.0 * g_step, misses + near_misses > 0u);
            }
            if near_misses > 0u {
                // A neighbour passed close to a surface without finding it (a thin feature
                // between the coarse samples, or an object's edge): march from one of its steps
                // before where it first came near (it sampled that far apart) to the end of the
                // box.
                // Not only to where it last came near: this pixel can pass beside that surface
                // and hit one behind it that no neighbour came near, which the cameras, seeing
                // the first surface, do not show (cow, 12 views at 256²: 24.77 dB and 268
                // mismatched pixels with that bound, even 6 steps past it; 24.96 dB and 258
                // without). Past that, with longer steps (`FAR_STRIDE`): the same masked PSNR
                // on the four fixtures; with (NEAR_PAST, FAR_STRIDE) = (1, 4) instead of (3, 2),
                // the frame pass's lane-steps −6 % (one demo view at 512²).
                lo = min(lo, near_min / z_rate - g_step * params.guide_step_ratio);
                stride_from = max(hi, near_max / z_rate + NEAR_PAST * g_step);
                hi = 1e30;
            }
            t_in = max(t_in, lo);
            t_out = min(t_out, hi);
            if t_in > t_out {
                return;
            }
        }
    }
    let loc = locate(sphere_entry(o, d), g_level);
    // Each camera's frame is derived once per pixel, not once per probe.
    let c0 = camera(loc.cameras.x);
    let c1 = camera(loc.cameras.y);
    let c2 = camera(loc.cameras.z);
    var m: March;
    if is_fixed() {
        m = march_fixed(o, d, t_in, t_out, loc.cameras, c0, c1, c2);
    } else {
        m = march_refined(o, d, t_in, t_out, stride_from, loc.cameras, loc.weights, c0, c1, c2);
    }
    var fetches = m.fetches;
    let near_t = min(m.near_first, reach_t);
    if coarse_pass() && !m.hit && near_t < 1e29 {
        out_depth[di] = -2.0 - near_t * z_rate;
        out_depth[di + 1u] = select(m.near_last * z_rate, 1e30, reach_t < 1e29);
    }
    if m.hit {
        if ROLE == 3u {
            // A coarse pass's depth is the march's (shading without a Newton step would not
            // move it); nothing reads its colour.
            out_depth[di] = m.t * z_rate;
        } else {
            let shaded = shade(o, d, z_rate, m.t, loc, c0, c1, c2, false);
            out_color[index] = shaded.color;
            out_depth[di] = shaded.z;
            fetches += shaded.fetches;
        }
    }
    // Work counters (`count_work`, generated: see shaders.rs).
    count_work(fetches, m.steps, 1u);
}
