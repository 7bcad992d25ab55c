// Mesh data layout and the DESIGN §3 shading model, shared by the bake ray tracer and the reference rasterizer.

struct Vertex {
    position: vec3<f32>,
    u: f32,
    normal: vec3<f32>,
    v: f32,
    color: vec4<f32>,
}

struct Triangle {
    v: vec3<u32>,
    material: u32,
}

struct Material {
    factor: vec4<f32>,
    texture: i32,
    pad0: i32,
    pad1: i32,
    pad2: i32,
}

// `light` is a unit world-space direction; ks = 0 disables the specular term; `mode` (SHADE_*)
// picks the whole colour, the albedo, or one of its two parts (light states store them apart,
// core/src/light.rs); `shadows` 1: the light is tested for occlusion (DESIGN §9,
// shared/trace.wgsl `light_visibility`).
struct Shading {
    light: vec3<f32>,
    ambient: f32,
    ks: f32,
    shininess: f32,
    mode: u32,
    shadows: u32,
}

// `Shading.mode`: the whole colour; the albedo (unlit); only `albedo·ambient`; only the rest
// (the light's diffuse and specular terms), so that the whole colour is their sum.
const SHADE_FULL: u32 = 0u;
const SHADE_UNLIT: u32 = 1u;
const SHADE_AMBIENT: u32 = 2u;
const SHADE_DIRECT: u32 = 3u;
// The bake's light states also store the shading normal (bake.wgsl `oct_encode16`).
const SHADE_NORMAL: u32 = 4u;

// DESIGN §3 with §9's shadow term V (`visibility`, 1 without shadows):
// color = albedo·(ambient + (1-ambient)·V·max(0, n·light)) + ks·V·max(0, n·h)^shininess,
// h = normalize(light + v), v towards the capturing camera; unlit: color = albedo. Each part
// alone (SHADE_AMBIENT, SHADE_DIRECT) is clamped like the whole.
fn shade(albedo: vec3<f32>, n: vec3<f32>, v: vec3<f32>, s: Shading, visibility: f32) -> vec3<f32> {
    if s.mode == SHADE_UNLIT {
        return clamp(albedo, vec3<f32>(0.0), vec3<f32>(1.0));
    }
    if s.mode == SHADE_AMBIENT {
        return clamp(albedo * s.ambient, vec3<f32>(0.0), vec3<f32>(1.0));
    }
    let ambient = select(s.ambient, 0.0, s.mode == SHADE_DIRECT);
    var c = albedo * (ambient + (1.0 - s.ambient) * visibility * max(dot(n, s.light), 0.0));
    if s.ks > 0.0 {
        let h = normalize(s.light + v);
        c += vec3<f32>(s.ks * visibility * pow(max(dot(n, h), 0.0), s.shininess));
    }
    return clamp(c, vec3<f32>(0.0), vec3<f32>(1.0));
}

// Albedo = base-colour texture × vertex colour × material factor (texture sampled at level 0,
// bilinear, repeat — identical in the baker and the reference).
fn albedo_of(m: Material, uv: vec2<f32>, vertex_color: vec3<f32>, tex: texture_2d_array<f32>, samp: sampler) -> vec3<f32> {
    var t = vec3<f32>(1.0);
    if m.texture >= 0 {
        t = textureSampleLevel(tex, samp, uv, m.texture, 0.0).rgb;
    }
    return t * vertex_color * m.factor.rgb;
}
