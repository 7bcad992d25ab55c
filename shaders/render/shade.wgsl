// Shading a hit from its three cameras, and the interior pass, which shades flat quads without
// marching.
//
// From the generated preamble: nothing but what params.wgsl lists.

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
// convex surface (docs/marcher.md). `z_rate`: the ray's z-depth per unit of t.
fn shade(o: vec3<f32>, d: vec3<f32>, z_rate: f32, t: f32, loc: Located, c0: Camera, c1: Camera, c2: Camera, newton: bool) -> Shaded {
    let x = o + t * d;
    var color = vec4<f32>(0.0);
    var total = 0.0;
    var fallback = vec4<f32>(0.0);
    var fallback_f = 1e30;
    // The largest step back (f / rate) of a fully agreeing camera; none yet.
    var correction = -1e30;
    var fetches = 0u;
    // Contested texels' parts in a relit frame (`RelitTexel`), blended as the colour.
    var soft = vec3<f32>(0.0);
    var full = vec3<f32>(0.0);
    var contested = 0.0;
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
        var parts = RelitTexel(vec4<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0.0);
        if edge_aware && per_invocation(params.lit != 0u) {
            parts = relit_layer_color(k, pb.tc, pb.layer_weights);
            c = parts.color;
            fetches += LAYER_SHADE_FETCHES;
        } else if edge_aware {
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
        soft += w * parts.soft;
        full += w * parts.full;
        contested += w * parts.contested;
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
    // Where the proxy lights disagree on the shadow, a shadow ray through the light field
    // decides it (`shadow_visible`).
    if (total > 1e-6) & (contested > 1e-6) & per_invocation(params.shadow_rays != 0u) {
        let shadow = shadow_visible(o + t_out * d);
        fetches += shadow.fetches;
        let visible = select(0.0, 1.0, shadow.visible);
        color = vec4<f32>(clamp(color.rgb + (visible * full - soft) / total, vec3<f32>(0.0), vec3<f32>(1.0)), color.a);
    }
    let z = t_out * z_rate;
    // A translucent field's maps hold premultiplied colour and opacity: both are blended alike
    // and kept; an opaque field's hits are opaque.
    let alpha = select(1.0, color.a, params.premultiplied != 0u);
    return Shaded(pack4x8unorm(vec4<f32>(color.rgb, alpha)), z, fetches, total > 1e-6);
}

struct Shadow {
    visible: bool,
    fetches: u32,
}

// Whether point x (a surface point the eye's march found) sees the frame's light: the ray from
// outside the camera sphere towards x, against the light (`-params.light_dir`), marched through
// the light field like an eye's ray, meets no surface more than SHADOW_CLEARANCE steps before
// x. The cameras around the light's direction see that ray's surfaces as an eye there would.
fn shadow_visible(x: vec3<f32>) -> Shadow {
    let d = -params.light_dir.xyz;
    // x lies inside the unit camera sphere, so o lies outside it, and x at t = 2.
    let o = x - 2.0 * d;
    let sphere = sphere_roots(o, d, BOUNDING_RADIUS);
    let box = box_roots(o, d, params.box_min, params.box_max);
    let t_in = max(sphere.x, box.x);
    let t_out = min(min(sphere.y, box.y), 2.0 - SHADOW_CLEARANCE * g_step);
    if t_in >= t_out {
        return Shadow(true, 0u);
    }
    let loc = locate(sphere_entry(o, d), g_level);
    let eye_step = g_step;
    g_step = SHADOW_STEP_SCALE * eye_step;
    let m = march_refined(o, d, t_in, t_out, 1e30, loc.cameras, loc.weights, camera(loc.cameras.x), camera(loc.cameras.y), camera(loc.cameras.z));
    g_step = eye_step;
    return Shadow(!m.hit, m.fetches);
}

// The interior pass (ROLE_INTERIOR): a pixel of a flat quad (see `cs_tiles`) takes the z-depth
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

// The interior pass with a 2×2 block of pixels per invocation (ROLE_INTERIOR_BLOCKS): they take
// the cameras of the triangle met by the ray through the block's centre, each weighing them by
// its own direction, so the triangle lookup and the cameras' frames serve all four. A pixel
// whose direction
// lies outside that triangle is off by at most the angle between its entry into the camera
// sphere and the centre ray's, as a direction near a triangle's edge is off with the lookup
// itself (`locate`); the renderer uses blocks only where that angle cannot exceed the lookup's
// reach (`INTERIOR_BLOCK_REACH` in render/guide.rs). The four pixels' centres also lie in one
// cell between the same four coarse pixels (the renderer uses blocks only where the coarse grid
// makes that so: `blocks_share_coarse_cells` in render/guide.rs), which are loaded once for the
// block: each pixel interpolates between them with its own weights, as `interior_t` would.
fn shade_interior_block(gid: vec2<u32>, index: u32, o: vec3<f32>, slot: u32) {
    let loc = locate(sphere_entry(o, pixel_ray(vec2<f32>(gid) + 1.0 + params.jitter)), g_level);
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
    let d = pixel_ray(pixel_centre(p));
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

// How far before the shaded point (in steps) a shadow ray's surface must lie to shadow it: the
// eye's and the shadow ray's marches each place a surface within the tolerance (half a step).
const SHADOW_CLEARANCE: f32 = 1.0;
// A shadow ray's step, in the eye's steps: it only has to find whether a surface lies before
// the point, not where (docs/marcher.md, "Relit frames").
const SHADOW_STEP_SCALE: f32 = 2.0;

// What `shade` counts per camera for an edge-aware pixel: one footprint and four colour loads.
const LAYER_SHADE_FETCHES: u32 = 5u;
// What `shade` counts for an interior pixel: three cameras, edge-aware.
const INTERIOR_FETCHES: u32 = 3u * LAYER_SHADE_FETCHES;
