// Two-plane light-field renderer (DESIGN §9, docs/two_plane.md): one compute pass, one
// invocation per pixel. Every position is relative to the st plane's centre (f32 keeps
// precision near the light field whatever its world placement).
//
// A pixel ray is inside the light field when it meets the closed uv rectangle at t_uv ≥ 0 and
// the closed st rectangle at t_st > t_uv; elsewhere the pixel is empty (coverage 0).
// Camera (a, b) holds the colour (straight RGBA8, alpha 1 on a hit, 0 elsewhere) and the
// stored depth d = |hit − C| / |S − C| (+inf: no hit) of the line from C through every st
// texel. A point at height h above st (along the normal, towards uv) on such a line has
// d = 1 − h / D (D the plane separation), so a stored depth is a height h = D·(1 − d).

struct Params {
    eye: vec3<f32>,
    focus: f32,
    forward: vec3<f32>,
    focal_px: f32,
    view_right: vec3<f32>,
    aperture: f32,
    view_up: vec3<f32>,
    dither_amp: f32,
    normal: vec3<f32>,
    separation: f32,
    right: vec3<f32>,
    h_hi: f32,
    up: vec3<f32>,
    h_lo: f32,
    uv_center: vec3<f32>,
    tolerance: f32,
    uv_size: vec2<f32>,
    st_size: vec2<f32>,
    grid: vec2<u32>,
    res: vec2<u32>,
    size: vec2<u32>,
    pad1: u32,
    steps: u32,
    background: u32,
    sample_budget: u32,
    frame_index: u32,
    pad0: u32,
}

// One pipeline per mode (pipeline-overridable constants): a branch on uniform values alone makes
// lavapipe rebuild the shader whenever the uniform buffer is bound (core/tests/shaders.rs).
// MODE: the uv filter; APERTURE: a synthetic aperture (any MODE).
override MODE: u32 = 1u;
override APERTURE: bool = false;

const MODE_NEAREST: u32 = 0u;
const MODE_BILINEAR: u32 = 1u;
const MODE_DITHER: u32 = 2u;
const MODE_DEPTH: u32 = 3u;
// Bisection steps after the march brackets a surface: the height error shrinks 16×.
const REFINE: u32 = 4u;
// Samples of the depth-corrected march whose segment is tested against the depth pyramid at
// once: a block whose lowest sample lies above every surface its segment projects to is
// skipped whole.
const BLOCK: u32 = 8u;
const INF_BITS: u32 = 0x7f800000u;

// The cameras' images are read through `color_at`, `depth_at` and `depth_texel`, defined by the
// file appended to this one: shaders/two_plane.wgsl (every camera a texture-array layer) or
// shaders/two_plane_paged.wgsl (pages in a cache, found through an index table). Where the
// appended file sets `DEPTH_PYRAMID`, its `depth_bound` bounds the stored depth over a box of
// texels and the depth-corrected march skips what lies above every surface. The appended
// file's `pixel_lod` sees each pixel inside the light field before it is shaded (the paged one
// chooses its level there) and `pixel_done` after.
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(3) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<u32>;

// How many st texels pixel (xk, yk) of the view (ray from `o` meeting st at `ps`) spans: the
// larger of the distances, in texels, to where its right and lower neighbours' rays meet st.
fn st_footprint(o: vec3<f32>, xk: f32, yk: f32, ps: vec3<f32>) -> f32 {
    let step = 1.0 / params.focal_px;
    let eh = dot(o, params.normal);
    let r = vec2<f32>(params.res) / params.st_size;
    var widest = 0.0;
    for (var k = 0u; k < 2u; k++) {
        let dk = select(vec2<f32>(xk + step, yk), vec2<f32>(xk, yk - step), k == 1u);
        let d = dk.x * params.view_right + dk.y * params.view_up + params.forward;
        let along = dot(d, params.normal);
        if !(along < 0.0) {
            return 3.4e38;
        }
        let delta = o - (eh / along) * d - ps;
        widest = max(widest, length(vec2<f32>(dot(delta, params.right), dot(delta, params.up)) * r));
    }
    return widest;
}

fn camera_pos(a: u32, b: u32) -> vec3<f32> {
    let g = vec2<f32>(params.grid);
    let x = (f32(a) + 0.5) / g.x - 0.5;
    let y = 0.5 - (f32(b) + 0.5) / g.y;
    return params.uv_center + x * params.uv_size.x * params.right + y * params.uv_size.y * params.up;
}

// Where the line from camera `c` through `q` meets st, as continuous texel coordinates
// (column j, row i); texel (i, j) at integer values. `st` receives the point itself.
struct Lookup {
    ji: vec2<f32>,
    st: vec3<f32>,
    ok: bool,
}

fn lookup(c: vec3<f32>, q: vec3<f32>) -> Lookup {
    let towards = q - c;
    let along = dot(towards, params.normal);
    var out: Lookup;
    out.ok = along < 0.0;
    let u = -params.separation / select(-1.0, along, out.ok);
    let s = c + u * towards;
    out.st = s;
    let r = vec2<f32>(params.res);
    out.ji = vec2<f32>(
        (dot(s, params.right) / params.st_size.x + 0.5) * r.x - 0.5,
        (0.5 - dot(s, params.up) / params.st_size.y) * r.y - 0.5,
    );
    return out;
}

// Every camera reads the focal point `q` on a line through its own uv position, and these
// lines meet st at `u·q + (1 − u)·C` with the same `u = D / (D − h_q)` for all: the texel
// column is affine in the camera column a alone, the row in b alone.
// ji(a, b) = origin + (a·step.x, b·step.y).
struct Fan {
    origin: vec2<f32>,
    step: vec2<f32>,
}

fn fan(q: vec3<f32>) -> Fan {
    let u = params.separation / (params.separation - dot(q, params.normal));
    let c0 = camera_pos(0u, 0u);
    let s = u * q + (1.0 - u) * c0;
    let r = vec2<f32>(params.res);
    var f: Fan;
    f.origin = vec2<f32>(
        (dot(s, params.right) / params.st_size.x + 0.5) * r.x - 0.5,
        (0.5 - dot(s, params.up) / params.st_size.y) * r.y - 0.5,
    );
    let g = vec2<f32>(params.grid);
    f.step = (1.0 - u) * vec2<f32>(
        params.uv_size.x / g.x * r.x / params.st_size.x,
        params.uv_size.y / g.y * r.y / params.st_size.y,
    );
    return f;
}

// The st point of continuous texel coordinates.
fn st_point(ji: vec2<f32>) -> vec3<f32> {
    let r = vec2<f32>(params.res);
    let x = (ji.x + 0.5) / r.x - 0.5;
    let y = 0.5 - (ji.y + 0.5) / r.y;
    return x * params.st_size.x * params.right + y * params.st_size.y * params.up;
}

// Whether continuous texel coordinates lie on the st rectangle (its outer half texel included).
fn on_st(ji: vec2<f32>) -> bool {
    let r = vec2<f32>(params.res);
    return all(ji >= vec2<f32>(-0.5)) && all(ji <= r - vec2<f32>(0.5));
}

// The point of the ray at height `h` above st.
fn at_height(o: vec3<f32>, d: vec3<f32>, h: f32) -> vec3<f32> {
    let t = (h - dot(o, params.normal)) / dot(d, params.normal);
    return o + t * d;
}

// Height of the surface camera (a, b) sees through the point `q`; −inf where it sees nothing
// or `q` projects off its image.
fn surface_height(a: u32, b: u32, q: vec3<f32>) -> f32 {
    return surface_height_of(camera_pos(a, b), b * params.grid.x + a, q);
}

fn surface_height_of(c: vec3<f32>, layer: u32, q: vec3<f32>) -> f32 {
    let l = lookup(c, q);
    let d = depth_at(layer, l.ji);
    let seen = l.ok && on_st(l.ji) && d < 3.0e38;
    return select(-3.0e38, params.separation * (1.0 - d), seen);
}

// The highest surface camera `layer` (at `c`) stores anywhere the ray's points between heights
// `h_top` and `h_bottom` project to (−3e38 where it stores none): a march sample in between
// that lies above it cannot be at or below the surface there, so skipping it changes nothing.
// The projection of the segment is the segment between its ends' projections (both ends on the
// camera's side of the uv plane, so every point between is too); the texels `depth_at` reads
// lie in the box of its ends, clamped, one texel wider for rounding. Where an end is not
// clearly on the camera's side (within a thousandth of the separation of the uv plane, the
// side of a projection to near infinity is rounding's choice), the bound is the uv plane's
// height (no sample lies above it).
fn height_bound(c: vec3<f32>, layer: u32, o: vec3<f32>, d: vec3<f32>, h_top: f32, h_bottom: f32) -> f32 {
    let a = lookup(c, at_height(o, d, h_top));
    let b = lookup(c, at_height(o, d, h_bottom));
    let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
    let lo_t = vec2<i32>(floor(clamp(min(a.ji, b.ji), vec2<f32>(0.0), hi)));
    let hi_t = vec2<i32>(ceil(clamp(max(a.ji, b.ji), vec2<f32>(0.0), hi)));
    let last = vec2<i32>(params.res) - vec2<i32>(1);
    let nearest = depth_bound(layer, max(lo_t - vec2<i32>(1), vec2<i32>(0)), min(hi_t + vec2<i32>(1), last));
    let bound = select(-3.0e38, params.separation * (1.0 - nearest), nearest < 3.0e38);
    return select(params.separation, bound, a.ok && b.ok && h_top < 0.999 * params.separation);
}

fn hash(x: u32) -> u32 {
    var v = x * 747796405u + 2891336453u;
    let w = ((v >> ((v >> 28u) + 4u)) ^ v) * 277803737u;
    return (w >> 22u) ^ w;
}

// The 4×4 Bayer rank of a pixel, 0..15 (rows 0 8 2 10 / 12 4 14 6 / 3 11 1 9 / 15 7 13 5):
// the bits of x ⊕ y and y interleaved, reversed.
fn bayer4(p: vec2<u32>) -> u32 {
    let a = (p.x ^ p.y) & 3u;
    let b = p.y & 3u;
    return ((a & 1u) << 3u) | ((b & 1u) << 2u) | (a & 2u) | ((b & 2u) >> 1u);
}

struct Accum {
    color: vec4<f32>,
    weight: f32,
    // The camera with the largest weight and where it was read: its surface gives the
    // pixel's depth.
    best_w: f32,
    best_cam: vec2<u32>,
    best_ji: vec2<f32>,
}

fn add_camera(acc: ptr<function, Accum>, a: u32, b: u32, f: Fan, w: f32) {
    let ji = f.origin + vec2<f32>(f32(a), f32(b)) * f.step;
    (*acc).color += w * color_at(b * params.grid.x + a, ji);
    (*acc).weight += w;
    if w > (*acc).best_w {
        (*acc).best_w = w;
        (*acc).best_cam = vec2<u32>(a, b);
        (*acc).best_ji = ji;
    }
}

// The surface the camera with the largest weight stores where it was read: its nearest texel,
// else the nearest finite depth of the 2×2 texels around the lookup (a silhouette texel whose
// blend is covered). `ok` false where all four miss.
struct Best {
    hit: vec3<f32>,
    ok: bool,
}

fn best_surface(acc: Accum) -> Best {
    let a = acc.best_cam.x;
    let b = acc.best_cam.y;
    let c = camera_pos(a, b);
    let layer = b * params.grid.x + a;
    var d = depth_at(layer, acc.best_ji);
    if !(d < 3.0e38) {
        let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
        let p0 = vec2<i32>(floor(clamp(acc.best_ji, vec2<f32>(0.0), hi)));
        let p1 = vec2<i32>(min(vec2<f32>(p0) + vec2<f32>(1.0), hi));
        d = min(
            min(depth_texel(layer, p0), depth_texel(layer, vec2<i32>(p1.x, p0.y))),
            min(depth_texel(layer, vec2<i32>(p0.x, p1.y)), depth_texel(layer, p1)),
        );
    }
    var out: Best;
    out.ok = d < 3.0e38;
    out.hit = c + select(0.0, d, out.ok) * (st_point(acc.best_ji) - c);
    return out;
}

// Adds the four cameras around the continuous camera coordinates `cell` with their bilinear
// weights (the last row and column clamped), each read through the fan `q`.
fn add_bilinear(acc: ptr<function, Accum>, cell: vec2<f32>, q: Fan) {
    let c0 = vec2<u32>(floor(cell));
    let c1 = min(c0 + vec2<u32>(1u), params.grid - vec2<u32>(1u));
    let f = cell - floor(cell);
    add_camera(acc, c0.x, c0.y, q, (1.0 - f.x) * (1.0 - f.y));
    add_camera(acc, c1.x, c0.y, q, f.x * (1.0 - f.y));
    add_camera(acc, c0.x, c1.y, q, (1.0 - f.x) * f.y);
    add_camera(acc, c1.x, c1.y, q, f.x * f.y);
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.size.x || gid.y >= params.size.y {
        return;
    }
    shade_pixel(gid);
    pixel_done(gid);
}

fn shade_pixel(gid: vec3<u32>) {
    let idx = gid.y * params.size.x + gid.x;
    out_color[idx] = params.background;
    out_depth[idx] = INF_BITS;

    let half = vec2<f32>(params.size) * 0.5;
    let xk = (f32(gid.x) + 0.5 - half.x) / params.focal_px;
    let yk = -(f32(gid.y) + 0.5 - half.y) / params.focal_px;
    let o = params.eye;
    let d = normalize(xk * params.view_right + yk * params.view_up + params.forward);

    // Inside the light field: the closed uv rectangle at t_uv ≥ 0, the closed st rectangle at
    // t_st > t_uv.
    let along = dot(d, params.normal);
    let eh = dot(o, params.normal);
    let t_uv = (params.separation - eh) / along;
    let t_st = -eh / along;
    if !(along < 0.0 && t_uv >= 0.0 && t_st > t_uv) {
        return;
    }
    let pu = o + t_uv * d - params.uv_center;
    let uv = vec2<f32>(dot(pu, params.right) / params.uv_size.x + 0.5, 0.5 - dot(pu, params.up) / params.uv_size.y);
    let ps = o + t_st * d;
    let st = vec2<f32>(dot(ps, params.right) / params.st_size.x + 0.5, 0.5 - dot(ps, params.up) / params.st_size.y);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) || any(st < vec2<f32>(0.0)) || any(st > vec2<f32>(1.0)) {
        return;
    }
    pixel_lod(o, xk, yk, ps);
    let g = vec2<f32>(params.grid);
    let cell = clamp(uv * g - vec2<f32>(0.5), vec2<f32>(0.0), g - vec2<f32>(1.0));
    let last = params.grid - vec2<u32>(1u);

    var acc: Accum;
    acc.color = vec4<f32>(0.0);
    acc.weight = 0.0;
    acc.best_w = -1.0;
    acc.best_cam = vec2<u32>(0u);
    acc.best_ji = vec2<f32>(0.0);
    var surface = false;
    var hit = vec3<f32>(0.0);

    if APERTURE {
        // Synthetic aperture: the cameras within R cells of the nearest one per axis (2R + 1
        // when R is whole), weighted by a box with a half-cell linear edge either side of
        // |Δ| = R + ½ (the weights move smoothly with the view, and at most (2R + 1)² cameras
        // have weight), each read at the focal plane's point.
        let q = fan(at_height(o, d, params.focus));
        let r = params.aperture;
        let lo = vec2<u32>(max(ceil(cell - vec2<f32>(r + 0.5)), vec2<f32>(0.0)));
        let hi = vec2<u32>(min(floor(cell + vec2<f32>(r + 0.5)), g - vec2<f32>(1.0)));
        let count = (hi - lo + vec2<u32>(1u));
        let total = count.x * count.y;
        // A stratified subset when the aperture holds more cameras than the budget: the
        // window is cut into strata and one camera per stratum is drawn (a new draw every
        // frame index), weighted by its stratum's size, so that accumulating frames converges
        // to the full aperture.
        let budget = max(params.sample_budget, 1u);
        if total <= budget {
            for (var b = lo.y; b <= hi.y; b++) {
                for (var a = lo.x; a <= hi.x; a++) {
                    let w = clamp(r + 0.5 - abs(f32(a) - cell.x), 0.0, 1.0) * clamp(r + 0.5 - abs(f32(b) - cell.y), 0.0, 1.0);
                    if w > 0.0 {
                        add_camera(&acc, a, b, q, w);
                    }
                }
            }
        } else {
            let side = max(u32(floor(sqrt(f32(budget)))), 1u);
            let strata = vec2<u32>(min(side, count.x), min(side, count.y));
            for (var sy = 0u; sy < strata.y; sy++) {
                for (var sx = 0u; sx < strata.x; sx++) {
                    let x0 = lo.x + sx * count.x / strata.x;
                    let x1 = lo.x + (sx + 1u) * count.x / strata.x;
                    let y0 = lo.y + sy * count.y / strata.y;
                    let y1 = lo.y + (sy + 1u) * count.y / strata.y;
                    let h = hash(params.frame_index * 7919u + (sy * strata.x + sx) * 104729u + 17u);
                    let a = x0 + (h & 0xffffu) % (x1 - x0);
                    let b = y0 + (h >> 16u) % (y1 - y0);
                    let w = clamp(r + 0.5 - abs(f32(a) - cell.x), 0.0, 1.0) * clamp(r + 0.5 - abs(f32(b) - cell.y), 0.0, 1.0);
                    if w > 0.0 {
                        add_camera(&acc, a, b, q, w * f32((x1 - x0) * (y1 - y0)));
                    }
                }
            }
            // Normalised by the whole window's weight (separable), not the drawn cameras':
            // each draw is then an unbiased estimate of the full aperture's premultiplied
            // colour, and frames average to it.
            var wa = 0.0;
            for (var a = lo.x; a <= hi.x; a++) {
                wa += clamp(r + 0.5 - abs(f32(a) - cell.x), 0.0, 1.0);
            }
            var wb = 0.0;
            for (var b = lo.y; b <= hi.y; b++) {
                wb += clamp(r + 0.5 - abs(f32(b) - cell.y), 0.0, 1.0);
            }
            acc.weight = wa * wb;
        }
    } else if MODE == MODE_DEPTH {
        // Depth-corrected: march the ray through the nearest camera's depth map to the
        // surface it sees, then read every camera around the ray's uv crossing where the ray
        // meets that surface, keeping those that see the same surface there.
        let n = vec2<u32>(round(cell));
        // The ray's depth range projects to a short segment of the nearest camera's image
        // (the parallax of at most half a cell): two steps per texel of it suffice.
        let c0 = camera_pos(n.x, n.y);
        let seg = lookup(c0, at_height(o, d, params.h_hi)).ji - lookup(c0, at_height(o, d, params.h_lo)).ji;
        let texels = max(abs(seg.x), abs(seg.y));
        let steps = clamp(u32(ceil(2.0 * texels)) + 1u, 2u, max(params.steps, 2u));
        let dh = (params.h_hi - params.h_lo) / f32(steps);
        let layer0 = n.y * params.grid.x + n.x;
        var h_prev = params.h_hi;
        var found = false;
        var below = params.h_hi;
        // Samples k = 0..=steps at heights h_hi − k·dh. Those above the highest surface the
        // camera stores along the whole segment are skipped first (one sample early, for
        // rounding), then blocks of BLOCK samples above every surface their own segment
        // meets: the march finds the same sample as one that reads every depth.
        var k = 0u;
        if DEPTH_PYRAMID {
            let top = height_bound(c0, layer0, o, d, params.h_hi, params.h_lo);
            k = u32(clamp(floor((params.h_hi - top) / dh) - 1.0, 0.0, f32(steps + 1u)));
            if k > 0u {
                h_prev = params.h_hi - f32(k - 1u) * dh;
            }
        }
        loop {
            if found || k > steps {
                break;
            }
            let k_end = min(k + BLOCK - 1u, steps);
            let h_end = params.h_hi - f32(k_end) * dh;
            if DEPTH_PYRAMID && h_end > height_bound(c0, layer0, o, d, params.h_hi - f32(k) * dh, h_end) {
                h_prev = h_end;
                k = k_end + 1u;
                continue;
            }
            for (; k <= k_end; k++) {
                let h = params.h_hi - f32(k) * dh;
                let hs = surface_height_of(c0, layer0, at_height(o, d, h));
                // The first sample at or below the surface, close to it: where the ray passed
                // behind a silhouette (the depth jumps) the gap is large, and the march goes on.
                if h <= hs && hs - h <= params.tolerance + dh {
                    found = true;
                    below = h;
                    break;
                }
                h_prev = h;
            }
        }
        if found {
            // Bisect between the last sample above the surface and the first below it.
            var above = h_prev;
            for (var r = 0u; r < REFINE; r++) {
                let mid = 0.5 * (above + below);
                if mid <= surface_height_of(c0, layer0, at_height(o, d, mid)) {
                    below = mid;
                } else {
                    above = mid;
                }
            }
        }
        let h_star = below;
        hit = at_height(o, d, h_star);
        surface = found;
        // The four cameras around the uv crossing, read once for both outcomes (a device that
        // runs both sides of a branch, as lavapipe does, would read them twice): where the
        // march found a surface, each is read where the ray meets it and joins the blend if
        // the surface it sees there is within the tolerance of the marched one, the nearest
        // camera alone where none of them has coverage; where the nearest camera sees no
        // surface along the ray (it may be hidden from it), the plain bilinear blend at the
        // focal plane decides.
        let q = fan(select(at_height(o, d, params.focus), hit, found));
        let lo = vec2<u32>(floor(cell));
        let hi = min(lo + vec2<u32>(1u), last);
        let f = cell - floor(cell);
        var nearest = vec4<f32>(0.0);
        for (var i = 0u; i < 4u; i++) {
            let right = (i & 1u) != 0u;
            let lower = i >= 2u;
            let a = select(lo.x, hi.x, right);
            let b = select(lo.y, hi.y, lower);
            let w = select(1.0 - f.x, f.x, right) * select(1.0 - f.y, f.y, lower);
            let ji = q.origin + vec2<f32>(f32(a), f32(b)) * q.step;
            let color = color_at(b * params.grid.x + a, ji);
            let agrees = w > 0.0 && abs(surface_height(a, b, hit) - h_star) <= params.tolerance;
            let wa = select(w, select(0.0, w, agrees), found);
            acc.color += wa * color;
            acc.weight += wa;
            if wa > acc.best_w {
                acc.best_w = wa;
                acc.best_cam = vec2<u32>(a, b);
                acc.best_ji = ji;
            }
            nearest = select(nearest, color, a == n.x && b == n.y);
        }
        let lone = select(0.0, 1.0, found && acc.color.a <= 0.0);
        acc.color += lone * nearest;
        acc.weight += lone;
    } else {
        let q = fan(at_height(o, d, params.focus));
        if MODE == MODE_BILINEAR {
            add_bilinear(&acc, cell, q);
        } else {
            var pick = cell;
            if MODE == MODE_DITHER {
                // Seed 001 §3.1: the uv coordinate moves by the pixel's Bayer threshold, in
                // (−½, ½) cells times the amplitude, along a hashed diagonal (±1, ±1).
                let threshold = (f32(bayer4(gid.xy)) + 0.5) / 16.0 - 0.5;
                let hsh = hash(gid.x * 73856093u ^ gid.y * 19349663u);
                let dir = vec2<f32>(select(-1.0, 1.0, (hsh & 1u) != 0u), select(-1.0, 1.0, (hsh & 2u) != 0u));
                pick = clamp(cell + threshold * params.dither_amp * dir, vec2<f32>(0.0), g - vec2<f32>(1.0));
            }
            let n = vec2<u32>(round(pick));
            add_camera(&acc, n.x, n.y, q, 1.0);
        }
    }

    // Coverage: half the (normalised) weight on hits (the silhouette of the bilinear st lookup). Colour is un-premultiplied: the blend of hits only.
    let alpha = acc.color.a / max(acc.weight, 1e-20);
    let covered = alpha >= 0.5;
    if !covered {
        return;
    }
    if !surface {
        // A covered pixel has a depth: where the highest-weighted camera sees nothing around
        // its lookup (the others carry the coverage at a silhouette), the pixel stays empty.
        let best = best_surface(acc);
        if !best.ok {
            return;
        }
        hit = best.hit;
    }
    let rgb = acc.color.rgb / acc.color.a;
    out_color[idx] = pack4x8unorm(vec4<f32>(rgb, 1.0));
    out_depth[idx] = bitcast<u32>(dot(hit - o, params.forward));
}
