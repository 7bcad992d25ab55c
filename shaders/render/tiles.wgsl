// The coarse-to-fine grid and the tile pass (`cs_tiles`, a pipeline of its own), which lists the
// 4×4 quads a guided pass marches and the flat ones the interior pass shades (docs/marcher.md).
//
// From the generated preamble: TILE_LIST_LENGTHS, count_work.

// Where fine pixel p's sample lies in the coarse pass, in coarse pixels (guided passes; coarse
// pixel (i, j) samples at (i, j)). A coarse pass's jitter is the frame's in its own pixels, so
// this holds for jittered frames too.
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

// The frame's 4×4 quads per row and per column.
fn frame_quads() -> vec2<u32> {
    return (vec2<u32>(params.width, params.height) + 3u) / 4u;
}

// Appends quad `entry` to list `list` (0: to march, 1: flat, 2: given back), whose k-th entry
// lives at `tiles[first + step · k]`, and counts a workgroup for every fourth (every
// `interior_group_quads`-th of the flat ones).
fn list_quad(list: u32, first: u32, step: i32, entry: u32) {
    let k = atomicAdd(&tile_dispatch[TILE_LIST_LENGTHS + list], 1u);
    if k % select(4u, params.interior_group_quads, list == 1u) == 0u {
        atomicAdd(&tile_dispatch[3u * list], 1u);
    }
    atomicStore(&tiles[u32(i32(first) + step * i32(k))], entry);
}

// Compaction for a guided pass (the frame's, or a coarse pass guided by a pre-coarse one), one
// invocation per 4×4 quad of its output: a quad is kept when some pixel of it has a coarse
// neighbour that hit or passed near a surface, i.e. when the guided pass would march some pixel
// of it (see `guided_bounds` in main.wgsl). On lavapipe only work never dispatched costs
// nothing (docs/marcher.md).
//
// A kept quad is flat when `interior_curvature` > 0, every coarse pixel around it hit, and no
// second difference of their z-depths along x or y exceeds `interior_curvature`: no silhouette
// or occlusion edge crosses it (a depth jump is a large second difference), and bilinear
// interpolation between the coarse depths is within an eighth of the bound per axis of any
// smooth surface through them. Flat quads go to the interior pass, which does not march.
// Quads rather than the 8×8 tiles of a workgroup: a tile along an edge held pixels that needed
// no march, and marched them.
// The coarse neighbourhood the tile pass reads per quad: 4×4, or 3×3 where every quad's pixels
// have the same nearest coarse pixel (`quads_share_nearest_coarse` in render/guide.rs), so that
// its neighbourhood spans 3×3 at most.
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
    // The interior pass's work, counted here once per quad rather than by its pixels (one atomic
    // add per quad, not per pixel): each pixel of a flat quad inside the
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
