
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

fn pixel_lod(o: vec3<f32>, xk: f32, yk: f32, ps: vec3<f32>) {}

fn pixel_done(gid: vec3<u32>) {}
