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
    mode: u32,
    steps: u32,
    background: u32,
    sample_budget: u32,
    frame_index: u32,
    pad0: u32,
}

const MODE_NEAREST: u32 = 0u;
const MODE_BILINEAR: u32 = 1u;
const MODE_DITHER: u32 = 2u;
const MODE_DEPTH: u32 = 3u;
// Bisection steps after the march brackets a surface: the height error shrinks 16×.
const REFINE: u32 = 4u;
const INF_BITS: u32 = 0x7f800000u;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var colors: texture_2d_array<f32>;
@group(0) @binding(2) var depths: texture_2d_array<f32>;
@group(0) @binding(3) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<u32>;

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

// Bilinear colour of camera `layer` at continuous texel `ji`, the outer half texel clamped to
// the edge texel: premultiplied (a miss is (0, 0, 0, 0)).
fn color_at(layer: u32, ji: vec2<f32>) -> vec4<f32> {
    let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
    let p = clamp(ji, vec2<f32>(0.0), hi);
    let p0 = floor(p);
    let f = p - p0;
    let i0 = vec2<i32>(p0);
    let i1 = vec2<i32>(min(p0 + vec2<f32>(1.0), hi));
    let c00 = textureLoad(colors, vec2<i32>(i0.x, i0.y), layer, 0);
    let c10 = textureLoad(colors, vec2<i32>(i1.x, i0.y), layer, 0);
    let c01 = textureLoad(colors, vec2<i32>(i0.x, i1.y), layer, 0);
    let c11 = textureLoad(colors, vec2<i32>(i1.x, i1.y), layer, 0);
    return mix(mix(c00, c10, f.x), mix(c01, c11, f.x), f.y);
}

// Stored depth of the texel nearest `ji` (clamped to the image).
fn depth_at(layer: u32, ji: vec2<f32>) -> f32 {
    let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
    let p = vec2<i32>(round(clamp(ji, vec2<f32>(0.0), hi)));
    return textureLoad(depths, p, layer, 0).r;
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
    let l = lookup(camera_pos(a, b), q);
    let d = depth_at(b * params.grid.x + a, l.ji);
    let seen = l.ok && on_st(l.ji) && d < 3.0e38;
    return select(-3.0e38, params.separation * (1.0 - d), seen);
}

fn hash(x: u32) -> u32 {
    var v = x * 747796405u + 2891336453u;
    let w = ((v >> ((v >> 28u) + 4u)) ^ v) * 277803737u;
    return (w >> 22u) ^ w;
}

// The 4×4 Bayer rank of a pixel, 0..15.
fn bayer4(p: vec2<u32>) -> u32 {
    let x = p.x & 3u;
    let y = p.y & 3u;
    let m = array<u32, 16>(0u, 8u, 2u, 10u, 12u, 4u, 14u, 6u, 3u, 11u, 1u, 9u, 15u, 7u, 13u, 5u);
    return m[y * 4u + x];
}

struct Accum {
    color: vec4<f32>,
    weight: f32,
    // The camera with the largest weight whose lookup hit something: its surface gives the
    // pixel's depth.
    best_w: f32,
    best_hit: vec3<f32>,
}

fn add_camera(acc: ptr<function, Accum>, a: u32, b: u32, q: vec3<f32>, w: f32) {
    let c = camera_pos(a, b);
    let l = lookup(c, q);
    let layer = b * params.grid.x + a;
    let col = color_at(layer, l.ji);
    (*acc).color += w * col;
    (*acc).weight += w;
    let d = depth_at(layer, l.ji);
    if d < 3.0e38 && w > (*acc).best_w {
        (*acc).best_w = w;
        (*acc).best_hit = c + d * (l.st - c);
    }
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.size.x || gid.y >= params.size.y {
        return;
    }
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
    let g = vec2<f32>(params.grid);
    let cell = clamp(uv * g - vec2<f32>(0.5), vec2<f32>(0.0), g - vec2<f32>(1.0));
    let last = params.grid - vec2<u32>(1u);

    var acc: Accum;
    acc.color = vec4<f32>(0.0);
    acc.weight = 0.0;
    acc.best_w = -1.0;
    acc.best_hit = vec3<f32>(0.0);
    var surface = false;
    var hit = vec3<f32>(0.0);

    if params.aperture > 0.0 {
        // Synthetic aperture: every camera within R cells per axis, weighted by a box of
        // width 2R + 1 with a one-cell linear edge, each read at the focal plane's point.
        let q = at_height(o, d, params.focus);
        let r = params.aperture;
        let lo = vec2<u32>(max(ceil(cell - vec2<f32>(r + 1.0)), vec2<f32>(0.0)));
        let hi = vec2<u32>(min(floor(cell + vec2<f32>(r + 1.0)), g - vec2<f32>(1.0)));
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
                    let w = clamp(r + 1.0 - abs(f32(a) - cell.x), 0.0, 1.0) * clamp(r + 1.0 - abs(f32(b) - cell.y), 0.0, 1.0);
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
                    let w = clamp(r + 1.0 - abs(f32(a) - cell.x), 0.0, 1.0) * clamp(r + 1.0 - abs(f32(b) - cell.y), 0.0, 1.0);
                    if w > 0.0 {
                        add_camera(&acc, a, b, q, w * f32((x1 - x0) * (y1 - y0)));
                    }
                }
            }
        }
    } else if params.mode == MODE_DEPTH {
        // Depth-corrected: march the ray through the nearest camera's depth map to the
        // surface it sees, then read every camera around the ray's uv crossing where the ray
        // meets that surface, keeping those that see the same surface there.
        let n = vec2<u32>(round(cell));
        let steps = max(params.steps, 1u);
        let dh = (params.h_hi - params.h_lo) / f32(steps);
        var h_prev = params.h_hi;
        var found = false;
        var above = params.h_hi;
        var below = params.h_hi;
        for (var k = 0u; k <= steps; k++) {
            let h = params.h_hi - f32(k) * dh;
            if h <= surface_height(n.x, n.y, at_height(o, d, h)) {
                // Bracketed between the last point above the surface and this one; bisect.
                above = h_prev;
                below = h;
                for (var r = 0u; r < REFINE; r++) {
                    let mid = 0.5 * (above + below);
                    if mid <= surface_height(n.x, n.y, at_height(o, d, mid)) {
                        below = mid;
                    } else {
                        above = mid;
                    }
                }
                // A true crossing ends on the surface; where the ray passed behind a
                // silhouette (the depth jumps), the gap stays large: march on.
                if surface_height(n.x, n.y, at_height(o, d, below)) - below <= params.tolerance {
                    found = true;
                    break;
                }
            }
            h_prev = h;
        }
        if found {
            let h_star = below;
            hit = at_height(o, d, h_star);
            surface = true;
            let c0 = vec2<u32>(floor(cell));
            let c1 = min(c0 + vec2<u32>(1u), last);
            let f = cell - floor(cell);
            let corners = array<vec2<u32>, 4>(c0, vec2<u32>(c1.x, c0.y), vec2<u32>(c0.x, c1.y), c1);
            let weights = array<f32, 4>((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
            for (var i = 0u; i < 4u; i++) {
                let cam = corners[i];
                let hs = surface_height(cam.x, cam.y, hit);
                if abs(hs - h_star) <= params.tolerance && weights[i] > 0.0 {
                    add_camera(&acc, cam.x, cam.y, hit, weights[i]);
                }
            }
            if acc.color.a <= 0.0 {
                add_camera(&acc, n.x, n.y, hit, 1.0);
            }
        }
    } else {
        let q = at_height(o, d, params.focus);
        if params.mode == MODE_BILINEAR {
            let c0 = vec2<u32>(floor(cell));
            let c1 = min(c0 + vec2<u32>(1u), last);
            let f = cell - floor(cell);
            add_camera(&acc, c0.x, c0.y, q, (1.0 - f.x) * (1.0 - f.y));
            add_camera(&acc, c1.x, c0.y, q, f.x * (1.0 - f.y));
            add_camera(&acc, c0.x, c1.y, q, (1.0 - f.x) * f.y);
            add_camera(&acc, c1.x, c1.y, q, f.x * f.y);
        } else {
            var pick = cell;
            if params.mode == MODE_DITHER {
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
    let rgb = acc.color.rgb / acc.color.a;
    out_color[idx] = pack4x8unorm(vec4<f32>(rgb, 1.0));
    if !surface {
        hit = acc.best_hit;
        if acc.best_w < 0.0 {
            return;
        }
    }
    out_depth[idx] = bitcast<u32>(dot(hit - o, params.forward));
}
