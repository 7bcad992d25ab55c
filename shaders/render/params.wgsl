// Parameters, bindings and pipeline specialisation of the light-field marcher (docs/marcher.md).
//
// Generated preamble (core/src/shaders.rs `render_source`, from Rust; prepended to
// shared/lightfield.wgsl and render/{params,probe,march,shade,tiles,main}.wgsl, joined in that
// order): CAMERA_COUNT, TRIANGLE_COUNT, MAX_LEVEL, DIRECTION_LOOKUP_SIZE; EDGE_BASE, EDGE_CODES,
// EDGE_E_LEVELS, EDGE_DEPTH_LEVELS; BOUNDING_RADIUS; METHOD_FIXED, METHOD_DEFAULT;
// METHODS_FIXED, METHODS_DEFAULT, METHODS_BOTH; ROLE_PLAIN, ROLE_GUIDED, ROLE_INTERIOR,
// ROLE_COARSE, ROLE_INTERIOR_BLOCKS; TILED_GRID, TILED_LISTED, TILED_GIVEN_BACK;
// TILE_DISPATCH_WORDS, TILE_LIST_LENGTHS, COUNTER_WORDS; fn count_work(fetches, steps, rays).

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
    // Box around every surface point the maps hold (see `VisibleBox` in render/upload.rs).
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
    // (ROLE_INTERIOR_BLOCKS).
    interior_group_quads: u32,
    // Guided passes: the step of the pass guiding this one, in this pass's steps (the coarse
    // passes step longer than the frame's: `COARSE_STEP_SCALE` in render/guide.rs).
    guide_step_ratio: f32,
    // Sub-pixel offset of every sample, in this pass's pixels: pixel (i, j) samples the image at
    // (j + 0.5 + jitter.x, i + 0.5 + jitter.y) (`pixel_centre`).
    jitter: vec2<f32>,
    // 1 for a translucent light field (premultiplied RGBA maps, e.g. a volume): the output
    // keeps the blended (premultiplied) colour and alpha; 0: every hit is opaque.
    premultiplied: u32,
    // 1: relit from the light states (`color_texel`), with `light_weights` (x, y, z) on
    // `light_a_maps`, `light_b_maps`, `light_c_maps` (core/src/light.rs); 0: the base colour.
    lit: u32,
    // 1: in a relit frame of an asset baked with shadows, a shadow ray decides where the proxy
    // lights disagree (`shadow_visible`).
    shadow_rays: u32,
    pad2: u32,
    // w 1: the blend is scaled by the stored normal's cosine ratio (`blend_direct`).
    light_weights: vec4<f32>,
    // The frame's light and the three proxy lights (unit, asset frame).
    light_dir: vec4<f32>,
    light_a: vec4<f32>,
    light_b: vec4<f32>,
    light_c: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read_write> out_color: array<u32>;
@group(0) @binding(2) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>, COUNTER_WORDS>;
// The coarse pass's results (guided passes), two per pixel: x its z-depth (−1 a miss, or 0
// where a compacted coarse pass skipped the pixel; −2 − z a near miss that first came near a
// surface at z-depth z), y for a near miss the z-depth where it last did (1e30: unknown). A
// coarse pass writes them as pairs to `out_depth`. A texture: see docs/marcher.md.
@group(0) @binding(4) var coarse: texture_2d<f32>;
// The 4×4 quads a guided pass renders (x | y << 16, in quads; twice the frame's quad count),
// the indirect dispatch sizes (x, 1, 1) of the passes that render them, four quads per
// workgroup, and from TILE_LIST_LENGTHS the lists' lengths. `cs_tiles` lists the quads to march
// from the front of `tiles` (workgroups in `tile_dispatch[0]`, quads in `[9]`) and the flat
// quads for the interior pass from the back of its first half (`[3]`, `[10]`); the interior pass
// lists the flat quads it gives back to be marched in the second half (`[6]`, `[11]`), and sets
// the top bit of a flat quad's entry once it has (docs/marcher.md).
@group(0) @binding(5) var<storage, read_write> tiles: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read_write> tile_dispatch: array<atomic<u32>, TILE_DISPATCH_WORDS>;

// Uniform, not storage, buffers (docs/marcher.md); their sizes come from the camera set.
// The cameras: position and the index of the world axis their frame is built from (`camera`).
@group(1) @binding(0) var<uniform> cameras: array<vec4<f32>, CAMERA_COUNT>;
@group(1) @binding(1) var<uniform> hierarchy: array<HierTriangle, TRIANGLE_COUNT>;
// The level-MAX_LEVEL triangle of each direction (octahedral map; `locate`).
@group(1) @binding(5) var direction_lookup: texture_2d<u32>;
@group(1) @binding(2) var color_maps: texture_2d_array<f32>;
@group(1) @binding(3) var footprints: texture_2d_array<u32>;
@group(1) @binding(4) var linear_sampler: sampler;
// Light states (`params.lit`): the ambient part, the shading normals and the direct parts of the
// three proxy lights around the frame's light; the base colour maps stand in for all five
// otherwise (and for the normals of an asset without them).
@group(1) @binding(6) var ambient_maps: texture_2d_array<f32>;
@group(1) @binding(7) var normal_maps: texture_2d_array<f32>;
@group(1) @binding(8) var light_a_maps: texture_2d_array<f32>;
@group(1) @binding(9) var light_b_maps: texture_2d_array<f32>;
@group(1) @binding(10) var light_c_maps: texture_2d_array<f32>;

// Pipeline specialisation: lavapipe runs every branch an 8-lane batch meets, so code a pass
// cannot use is compiled out instead of skipped (docs/marcher.md). METHODS: the marching
// methods this pipeline serves (METHODS_*); ROLE: what the pass does (ROLE_*, `Role` in
// render/gpu_data.rs).
override METHODS: u32 = METHODS_BOTH;
override ROLE: u32 = ROLE_PLAIN;

// A decision on parameters alone goes through `per_invocation`, which ties it to the
// invocation in a way no compiler can fold: lavapipe rebuilds a shader whose branch depends on
// uniform values alone each time its parameters are bound (docs/marcher.md). A naga test
// (tests/shaders.rs) finds any branch left on uniform values alone, `&&` and `||` included.
var<private> g_invocation: u32;

fn per_invocation(decision: bool) -> bool {
    // `&`, not `&&`: a short-circuit `&&` is itself a branch on `decision` alone.
    return decision & (g_invocation != 0xffffffffu);
}

// A coarse pass marks near misses for the pass it guides.
fn coarse_pass() -> bool {
    return ROLE == ROLE_COARSE && per_invocation(params.near_scale > 0.0);
}

// A coarse pass's depths bound a guided pass's marches.
fn guided_pass() -> bool {
    return (ROLE == ROLE_GUIDED || ROLE == ROLE_COARSE) && per_invocation(params.coarse_factor != 0u);
}

// The interior pass of a guided frame, one pixel per invocation or two.
fn interior_role() -> bool {
    return ROLE == ROLE_INTERIOR || ROLE == ROLE_INTERIOR_BLOCKS;
}

// Whether this pixel marches with the fixed-step baseline.
fn is_fixed() -> bool {
    return METHODS == METHODS_FIXED || (METHODS == METHODS_BOTH && g_method == METHOD_FIXED);
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

// Where pixel p samples the image, in pixels from its top-left corner (DESIGN §3, moved by
// `jitter`).
fn pixel_centre(p: vec2<u32>) -> vec2<f32> {
    return vec2<f32>(p) + 0.5 + params.jitter;
}
