
// Cameras paged through a cache (appended to shaders/shared/two_plane.wgsl; docs/two_plane.md
// "Paged rendering"). Each camera image is cut into pages of P × P texels (the asset's pages); a
// resident page sits in a slot of the cache atlas (tiles of P × P in texture-array layers, row by
// row), and
// the index table maps page → slot. A texel of a page that is not resident reads the always
// resident coarse level instead (each camera downsampled F×: mean colour, nearest depth of each
// F × F block), and the pixel counts as degraded. Every page a pixel reads (resident or not)
// gets this frame's stamp in `touched`: the pages the frame needed.
//
// Overview, a page pyramid: a pixel that spans at least F st texels (`st_footprint`) reads the
// coarse level alone, bilinearly (it is a box-filtered copy, the right level for such a pixel)
// and needs no page; a pixel spanning 2^l to 2^(l+1) texels (1 ≤ l, 2^l < F) reads page level
// l, every camera downsampled 2^l× (mean colour, nearest depth of each block), cut into pages of
// the same side and paged like the full resolution (level 0), with ids after level 0's. Both
// count as overview pixels, not degraded ones (a level pixel is degraded where one of its
// level's pages is missing). Level 0 and the page levels share one lookup path, so a frame with
// pixels at several levels runs the page lookups once per texel, not once per level (a CPU
// adapter runs every side of a divergent branch).
//
// Each texel is looked up in its own page, so the bilinear 2×2 footprint and the 2×2 depth
// footprint read across page borders correctly without gutters; the common case (all four
// texels in one page) looks the page up once. A texel's value is the same whichever slot holds
// its page, so a frame equals the fully resident one bit for bit wherever nothing is missing.

struct Paging {
    // Page side P = 1 << page_shift (a power of two, DESIGN §5).
    page_shift: u32,
    // Coarse level: factor F = 1 << coarse_shift and its size.
    coarse_shift: u32,
    coarse_res: vec2<u32>,
    stamp: u32,
    // Pixels spanning this many st texels or more read the coarse level (overview): F, or
    // +inf with the overview off (a comparison, not a branch on the uniform).
    overview_min: f32,
    // Words of each per-pixel mask.
    mask_words: u32,
    // Page levels (level 0 included), and the footprint from which a pixel reads level 1 and
    // up: 2, or +inf without levels.
    levels: u32,
    level_min: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    // Per level (0: the full resolution): first page id, pages per image row, pages per image,
    // image size (width in bits 0–15, height in 16–31).
    level_info: array<vec4<u32>, 8>,
}
const NOT_RESIDENT: u32 = 0xffffffffu;

@group(0) @binding(1) var slot_colors: texture_2d_array<f32>;
@group(0) @binding(2) var slot_depths: texture_2d_array<f32>;
@group(0) @binding(5) var<uniform> paging: Paging;
@group(0) @binding(6) var<storage, read> page_table: array<u32>;
@group(0) @binding(7) var coarse_colors: texture_2d_array<f32>;
@group(0) @binding(8) var coarse_depths: texture_2d_array<f32>;
// Per page: the stamp of the last frame that read it.
@group(0) @binding(9) var<storage, read_write> touched: array<u32>;
// [0]: degraded pixels, [1]: overview pixels; then one bit per pixel (row-major) set where the
// pixel is degraded, then one where it is overview (`paging.mask_words` words each).
@group(0) @binding(10) var<storage, read_write> degraded_px: array<atomic<u32>>;

// Whether any pixel of the frame may be an overview pixel: the pipeline is specialised per
// frame (the projection bounds the frame's footprints), so a frame that cannot have one skips
// the footprint test.
override OVERVIEW: bool = true;

var<private> degraded: bool = false;
// Whether the pixel reads the coarse level alone, and otherwise its page level (0: the full
// resolution).
var<private> coarse: bool = false;
var<private> level: u32 = 0u;

// The depth-corrected march reads every sample (pages hold no depth pyramid).
const DEPTH_PYRAMID: bool = false;

fn depth_bound(layer: u32, lo: vec2<i32>, hi: vec2<i32>) -> f32 {
    return 0.0;
}

fn pixel_lod(o: vec3<f32>, xk: f32, yk: f32, ps: vec3<f32>) {
    if OVERVIEW {
        let fp = st_footprint(o, xk, yk, ps);
        coarse = fp >= paging.overview_min;
        // Level l for 2^l ≤ fp < 2^(l+1) (log2 is exact at powers of two), at most the last
        // paged level.
        let l = u32(max(floor(log2(min(fp, 1.0e30))), 0.0));
        level = select(0u, min(l, paging.levels - 1u), fp >= paging.level_min && !coarse);
    }
}

// Bilinear colour of the coarse level of camera `layer` at full-resolution texel `ji`.
fn coarse_color_at(layer: u32, ji: vec2<f32>) -> vec4<f32> {
    let scale = 1.0 / f32(1u << paging.coarse_shift);
    let hi = vec2<f32>(paging.coarse_res) - vec2<f32>(1.0);
    let x = clamp((ji + vec2<f32>(0.5)) * scale - vec2<f32>(0.5), vec2<f32>(0.0), hi);
    let t0 = vec2<i32>(floor(x));
    let t1 = min(t0 + vec2<i32>(1), vec2<i32>(paging.coarse_res) - vec2<i32>(1));
    let f = x - floor(x);
    let c00 = textureLoad(coarse_colors, t0, layer, 0);
    let c10 = textureLoad(coarse_colors, vec2<i32>(t1.x, t0.y), layer, 0);
    let c01 = textureLoad(coarse_colors, vec2<i32>(t0.x, t1.y), layer, 0);
    let c11 = textureLoad(coarse_colors, t1, layer, 0);
    return mix(mix(c00, c10, f.x), mix(c01, c11, f.x), f.y);
}

// Where a page lives: its slot's atlas layer and the texel of its corner; `ok` false when the
// page is not resident. The index table holds the slot's place packed (tile column in bits 0–7,
// row in 8–15, layer in 16–31): shifts and masks only, no integer division per fetch (the CPU
// driver runs divisions lane by lane).
struct Slot {
    ok: bool,
    layer: i32,
    origin: vec2<i32>,
}

// The level's image size.
fn level_size(info: vec4<u32>) -> vec2<u32> {
    return vec2<u32>(info.w & 0xffffu, info.w >> 16u);
}

// The slot of camera `layer`'s page holding texel `t` of the level of table entry `info`
// (recorded as touched).
fn resolve(info: vec4<u32>, layer: u32, t: vec2<u32>) -> Slot {
    let pc = t >> vec2<u32>(paging.page_shift);
    let page = info.x + layer * info.z + pc.y * info.y + pc.x;
    touched[page] = paging.stamp;
    let slot = page_table[page];
    var s: Slot;
    s.ok = slot != NOT_RESIDENT;
    s.layer = i32(slot >> 16u);
    s.origin = vec2<i32>(vec2<u32>(slot & 0xffu, (slot >> 8u) & 0xffu) << vec2<u32>(paging.page_shift));
    return s;
}

// Texel `t`'s offset inside its page.
fn in_page(t: vec2<u32>) -> vec2<i32> {
    return vec2<i32>(t & vec2<u32>((1u << paging.page_shift) - 1u));
}

// The coarse texel holding texel `t` of the pixel's level.
fn coarse_texel(t: vec2<u32>) -> vec2<i32> {
    return vec2<i32>(min(t >> vec2<u32>(paging.coarse_shift - level), paging.coarse_res - vec2<u32>(1u)));
}

fn color_in(s: Slot, layer: u32, t: vec2<u32>) -> vec4<f32> {
    if s.ok {
        return textureLoad(slot_colors, s.origin + in_page(t), s.layer, 0);
    }
    degraded = true;
    return textureLoad(coarse_colors, coarse_texel(t), layer, 0);
}

// Bilinear colour of camera `layer` at continuous full-resolution texel `ji` (clamped to the
// image, as the resident sampler's clamp to edge does), from the pixel's level: premultiplied
// (a miss is (0, 0, 0, 0)).
fn color_at(layer: u32, ji: vec2<f32>) -> vec4<f32> {
    if coarse {
        return coarse_color_at(layer, ji);
    }
    let info = paging.level_info[level];
    let size = level_size(info);
    // The level's continuous texel (the full resolution's own at level 0, bit for bit).
    let scale = 1.0 / f32(1u << level);
    let xl = select((ji + vec2<f32>(0.5)) * scale - vec2<f32>(0.5), ji, level == 0u);
    let x = clamp(xl, vec2<f32>(0.0), vec2<f32>(size) - vec2<f32>(1.0));
    let t0 = vec2<u32>(floor(x));
    let t1 = min(t0 + vec2<u32>(1u), size - vec2<u32>(1u));
    let f = x - floor(x);
    let s00 = resolve(info, layer, t0);
    var s10 = s00;
    var s01 = s00;
    var s11 = s00;
    if any((t0 >> vec2<u32>(paging.page_shift)) != (t1 >> vec2<u32>(paging.page_shift))) {
        s10 = resolve(info, layer, vec2<u32>(t1.x, t0.y));
        s01 = resolve(info, layer, vec2<u32>(t0.x, t1.y));
        s11 = resolve(info, layer, t1);
    }
    let c00 = color_in(s00, layer, t0);
    let c10 = color_in(s10, layer, vec2<u32>(t1.x, t0.y));
    let c01 = color_in(s01, layer, vec2<u32>(t0.x, t1.y));
    let c11 = color_in(s11, layer, t1);
    return mix(mix(c00, c10, f.x), mix(c01, c11, f.x), f.y);
}

// Stored depth of full-resolution texel `p` (inside the image): at a page level, the nearest
// depth of the level texel's block holding it.
fn depth_texel(layer: u32, p: vec2<i32>) -> f32 {
    let t = vec2<u32>(p);
    if coarse {
        return textureLoad(coarse_depths, vec2<i32>(min(t >> vec2<u32>(paging.coarse_shift), paging.coarse_res - vec2<u32>(1u))), layer, 0).r;
    }
    let tl = t >> vec2<u32>(level);
    let s = resolve(paging.level_info[level], layer, tl);
    if s.ok {
        return textureLoad(slot_depths, s.origin + in_page(tl), s.layer, 0).r;
    }
    degraded = true;
    return textureLoad(coarse_depths, coarse_texel(tl), layer, 0).r;
}

// Stored depth of the texel nearest `ji` (clamped to the image).
fn depth_at(layer: u32, ji: vec2<f32>) -> f32 {
    let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
    return depth_texel(layer, vec2<i32>(round(clamp(ji, vec2<f32>(0.0), hi))));
}

fn pixel_done(gid: vec3<u32>) {
    let overview = coarse || level > 0u;
    if degraded || overview {
        let idx = gid.y * params.size.x + gid.x;
        let which = select(0u, 1u, overview);
        atomicAdd(&degraded_px[which], 1u);
        atomicOr(&degraded_px[2u + which * paging.mask_words + idx / 32u], 1u << (idx % 32u));
    }
}
