// The marcher's entry point (`cs_main`): one pixel per invocation (or a 2×2 block in the
// interior pass), in the role its pipeline was built for (docs/marcher.md).
//
// From the generated preamble: BOUNDING_RADIUS, ROLE_*, TILED_*, TILE_LIST_LENGTHS, count_work.

// A neighbourhood of nine hits is two layers (an occlusion edge) when the gap between the depths
// below and above their midrange exceeds both layers' own spreads by BIMODAL_GAP steps.
const BIMODAL_GAP: f32 = 2.0;

// Coarse-to-fine (the `guide` knob): the 3×3 coarse pixels around fine pixel p bound where its
// surface can be on its ray, whose z-depth grows by `z_rate` per unit of t. Returns [t_in, t_out]
// narrowed to that, and where the march may take longer steps (1e30: nowhere); t_in > t_out when
// the pixel need not march: all nine missed far from any surface, so does it. Else it marches
// from before the nearest of their hits and near passes to past the farthest hit (or to the end
// of the box, next to a near miss).
fn guided_bounds(p: vec2<u32>, z_rate: f32, t_in: f32, t_out: f32) -> vec3<f32> {
    let cw = i32(params.coarse_width);
    let ch = i32(params.coarse_height);
    let nearest = coarse_nearest(p);
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
            let q = clamp(nearest + vec2<i32>(dx, dy), vec2<i32>(0), vec2<i32>(cw - 1, ch - 1));
            let c = textureLoad(coarse, q, 0);
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
        return vec3<f32>(1.0, -1.0, 1e30);
    }
    var lo = 1e30;
    var hi = -1e30;
    var stride_from = 1e30;
    if z_min <= z_max {
        // Hits: a quarter step of margin (the coarse depths are accurate to far less) plus
        // the neighbourhood's own depth spread: on a steep or curved surface this pixel's
        // depth can lie beyond its neighbours' range. Where some neighbours missed (a
        // silhouette), three more steps past the farthest hit. At an occlusion edge (nine hits
        // in two layers, see BIMODAL_GAP) the spread is the gap between the layers, not a
        // curvature: the margin before the front layer and past the back one is that layer's
        // own spread (docs/marcher.md).
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
        // A neighbour passed close to a surface without finding it (a thin feature between
        // the coarse samples, or an object's edge): march from one of its steps before where
        // it first came near (it sampled that far apart) to the end of the box, not only to
        // where it last came near: this pixel can pass beside that surface and hit one behind
        // it that no neighbour came near. Past that, with longer steps (`FAR_STRIDE`).
        lo = min(lo, near_min / z_rate - g_step * params.guide_step_ratio);
        stride_from = max(hi, near_max / z_rate + NEAR_PAST * g_step);
        hi = 1e30;
    }
    return vec3<f32>(max(t_in, lo), min(t_out, hi), stride_from);
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) global_id: vec3<u32>, @builtin(workgroup_id) group_id: vec3<u32>, @builtin(local_invocation_id) local_id: vec3<u32>) {
    g_invocation = global_id.x;
    // Which pixel of its 8×8 tile an invocation renders (a compacted pass maps the workgroup
    // onto four listed quads below, each batch a 4×2 half of one): each 8-lane batch takes a
    // 4×2 block of pixels, whose marches are more alike than a row's (docs/marcher.md).
    let lane = vec2<u32>((local_id.y % 2u) * 4u + local_id.x % 4u, (local_id.y / 2u) * 2u + local_id.x / 4u);
    var gid = vec3<u32>(group_id.xy * 8u + lane, 0u);
    var slot = 0u;
    let interior = interior_role();
    if interior || ((ROLE == ROLE_GUIDED || ROLE == ROLE_COARSE) && per_invocation(params.tiled != TILED_GRID)) {
        // Quads to march from the front of the list, flat ones from the back of its first half,
        // given-back ones from its second half (see `tiles`); four quads per workgroup, each
        // 8-lane batch a 4×2 half of one (ROLE_INTERIOR_BLOCKS: sixteen quads, each batch two,
        // each invocation a 2×2 block).
        let grid = frame_quads();
        let quad_count = grid.x * grid.y;
        let invocation = local_id.y * 8u + local_id.x;
        let per_quad = select(16u, 4u, ROLE == ROLE_INTERIOR_BLOCKS);
        let k = (64u / per_quad) * group_id.x + invocation / per_quad;
        var list = 0u;
        slot = k;
        if interior {
            list = 1u;
            slot = quad_count - 1u - k;
        } else if per_invocation(params.tiled == TILED_GIVEN_BACK) {
            list = 2u;
            slot = quad_count + k;
        }
        if k >= atomicLoad(&tile_dispatch[TILE_LIST_LENGTHS + list]) {
            return;
        }
        let quad = atomicLoad(&tiles[slot]) & 0x7fffffffu;
        let within = invocation % per_quad;
        let in_quad = select(vec2<u32>(within % 4u, within / 4u), vec2<u32>(within % 2u, within / 2u) * 2u, ROLE == ROLE_INTERIOR_BLOCKS);
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
    let d = pixel_ray(pixel_centre(gid.xy));
    let o = params.eye;
    // z-depth per unit of t along this ray.
    let z_rate = dot(d, params.forward) * params.depth_scale;
    if ROLE == ROLE_INTERIOR {
        shade_interior(gid.xy, index, o, d, z_rate, slot);
        return;
    }
    if ROLE == ROLE_INTERIOR_BLOCKS {
        shade_interior_block(gid.xy, index, o, slot);
        return;
    }
    // A coarse pass grows the sphere and box by its reach at their far side and marches what
    // they bound, so a ray passing just outside them is marked near where it comes near a
    // surface (a fine pixel beside it may hit), like any other, rather than marking every ray
    // that meets the grown sphere or box near (docs/marcher.md). The march stays inside the
    // camera sphere, where the cameras can tell; when the
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
            let guided = guided_bounds(gid.xy, z_rate, t_in, t_out);
            t_in = guided.x;
            t_out = guided.y;
            stride_from = guided.z;
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
        if ROLE == ROLE_COARSE {
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
