// Rays and the two marchers: the fixed-step baseline and the default refined march.
//
// From the generated preamble: nothing but what params.wgsl lists (it reads the per-pixel
// setting `g_*` and the rays' `params`).

// A pixel next to a near miss marches to the end of the box, but with steps FAR_STRIDE times
// longer from NEAR_PAST steps past where its near-miss neighbours last came near a surface (and
// past the range of its neighbours' hits): see `guided_bounds` in main.wgsl and docs/marcher.md.
const NEAR_PAST: f32 = 1.0;
const FAR_STRIDE: f32 = 4.0;

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
// Shaped for lavapipe's lockstep batches (docs/marcher.md): the step loop holds only the three
// probes and stops at the first bracket; bisection runs after it,
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

// The eye ray through point p of the image (in pixels from its top-left corner: pixel (i, j)
// samples it at `pixel_centre`), unit.
fn pixel_ray(p: vec2<f32>) -> vec3<f32> {
    let px = (p.x - 0.5 * f32(params.width)) / params.focal_px;
    let py = -(p.y - 0.5 * f32(params.height)) / params.focal_px;
    return normalize(px * params.right + py * params.up + params.forward);
}

// The line o + t·d's first intersection with the camera sphere, as a direction from its centre:
// it picks the three cameras (seed 000 §2), and exists whenever the line meets the bounding
// sphere inside it.
fn sphere_entry(o: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    let cs = sphere_roots(o, d, 1.0);
    return normalize(o + cs.x * d);
}
