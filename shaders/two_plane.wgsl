
// Every camera resident (appended to shaders/shared/two_plane.wgsl): one texture-array layer
// per camera.
@group(0) @binding(1) var colors: texture_2d_array<f32>;
@group(0) @binding(2) var depths: texture_2d_array<f32>;
// Bilinear, clamp to edge: the st lookup inside one camera's layer.
@group(0) @binding(5) var linear: sampler;

// Bilinear colour of camera `layer` at continuous texel `ji` (the sampler clamps the outer half
// texel to the edge texel): premultiplied (a miss is (0, 0, 0, 0)).
fn color_at(layer: u32, ji: vec2<f32>) -> vec4<f32> {
    let uv = (ji + vec2<f32>(0.5)) / vec2<f32>(params.res);
    return textureSampleLevel(colors, linear, uv, layer, 0.0);
}

// Stored depth of texel `p` (inside the image).
fn depth_texel(layer: u32, p: vec2<i32>) -> f32 {
    return textureLoad(depths, p, layer, 0).r;
}

// Stored depth of the texel nearest `ji` (clamped to the image).
fn depth_at(layer: u32, ji: vec2<f32>) -> f32 {
    let hi = vec2<f32>(params.res) - vec2<f32>(1.0);
    return depth_texel(layer, vec2<i32>(round(clamp(ji, vec2<f32>(0.0), hi))));
}

// Off: the depth-corrected march reads every sample (the reference the skips are tested against).
override DEPTH_PYRAMID: bool = true;

// Smallest stored depth of camera `layer` over texels `lo`..=`hi` (inside the image), or less:
// at most 2 × 2 texels of the depth pyramid's level whose blocks are at least as wide as the
// range (mip level l holds the smallest depth of its 2^l × 2^l block, the last row and column
// also what is left of an odd side: texel t lies in block min(t >> l, size − 1)).
fn depth_bound(layer: u32, lo: vec2<i32>, hi: vec2<i32>) -> f32 {
    let extent = u32(max(hi.x - lo.x, hi.y - lo.y));
    // The pyramid's levels and their sizes follow from the image's (on lavapipe, clamping to
    // `textureDimensions` at a level dropped blocks).
    let top = 31u - countLeadingZeros(max(params.res.x, params.res.y));
    let level = min(select(0u, 32u - countLeadingZeros(extent), extent > 0u), top);
    let last = vec2<i32>(max(params.res >> vec2<u32>(level), vec2<u32>(1u))) - vec2<i32>(1);
    let b0 = min(lo >> vec2<u32>(level), last);
    let b1 = min(hi >> vec2<u32>(level), last);
    return min(
        min(textureLoad(depths, b0, layer, level).r, textureLoad(depths, vec2<i32>(b1.x, b0.y), layer, level).r),
        min(textureLoad(depths, vec2<i32>(b0.x, b1.y), layer, level).r, textureLoad(depths, b1, layer, level).r),
    );
}

fn pixel_lod(o: vec3<f32>, xk: f32, yk: f32, ps: vec3<f32>) {}

fn pixel_done(gid: vec3<u32>) {}
