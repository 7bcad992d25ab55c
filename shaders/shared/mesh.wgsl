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

// `light` is a unit world-space direction; ks = 0 disables the specular term; `shadows` 1: the
// light is tested for occlusion (DESIGN §9, shared/trace.wgsl `light_visibility`).
struct Shading {
    light: vec3<f32>,
    ambient: f32,
    ks: f32,
    shininess: f32,
    unlit: u32,
    shadows: u32,
}

// DESIGN §3 with §9's shadow term V (`visibility`, 1 without shadows):
// color = albedo·(ambient + (1-ambient)·V·max(0, n·light)) + ks·V·max(0, n·h)^shininess,
// h = normalize(light + v), v towards the capturing camera; unlit: color = albedo.
fn shade(albedo: vec3<f32>, n: vec3<f32>, v: vec3<f32>, s: Shading, visibility: f32) -> vec3<f32> {
    if s.unlit != 0u {
        return clamp(albedo, vec3<f32>(0.0), vec3<f32>(1.0));
    }
    var c = albedo * (s.ambient + (1.0 - s.ambient) * visibility * max(dot(n, s.light), 0.0));
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
