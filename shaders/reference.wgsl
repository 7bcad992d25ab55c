// Reference: direct rasterization of the source mesh with the DESIGN §3 view and shading — the ground truth for every quality number.

struct ReferenceParams {
    eye: vec3<f32>,
    width: f32,
    right: vec3<f32>,
    height: f32,
    up: vec3<f32>,
    focal_px: f32,
    forward: vec3<f32>,
    near: f32,
    depth_scale: f32,
    // Vertical focal length and the principal point's offset from the image centre (pixels,
    // +x right, +y up): a DESIGN §3 view has focal_y_px = focal_px and a centred principal point;
    // two-plane cameras are off-axis.
    focal_y_px: f32,
    center_px: vec2<f32>,
    shading: Shading,
}

@group(0) @binding(0) var<uniform> params: ReferenceParams;

@group(1) @binding(0) var<storage, read> vertices: array<Vertex>;
@group(1) @binding(1) var<storage, read> triangles: array<Triangle>;
@group(1) @binding(2) var<storage, read> nodes: array<BvhNode>;
@group(1) @binding(3) var<storage, read> materials: array<Material>;
@group(1) @binding(4) var mesh_texture: texture_2d_array<f32>;
@group(1) @binding(5) var mesh_sampler: sampler;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) color: vec3<f32>,
    @location(4) @interpolate(flat) material: u32,
    @location(5) @interpolate(flat) triangle: u32,
}

@vertex
fn vs_main(@builtin(vertex_index) vertex_index: u32) -> VertexOut {
    let tri = triangles[vertex_index / 3u];
    let corner = vertex_index % 3u;
    let vi = select(select(tri.v.z, tri.v.y, corner == 1u), tri.v.x, corner == 0u);
    let v = vertices[vi];
    let q = v.position - params.eye;
    let z = dot(q, params.forward);
    // Pixel convention of DESIGN §3: x = (j+0.5−W/2)/f ⇒ NDC x = x·f/(W/2); off-axis, the pixel
    // offset is centre + f·x, so NDC·z = (f·x_view + centre·z)/(W/2). Reverse-Z with an infinite
    // far plane: depth = near / z, so precision is best where it matters.
    let x_ndc_w = (dot(q, params.right) * params.focal_px + params.center_px.x * z) / (0.5 * params.width);
    let y_ndc_w = (dot(q, params.up) * params.focal_y_px + params.center_px.y * z) / (0.5 * params.height);
    var out: VertexOut;
    out.clip = vec4<f32>(x_ndc_w, y_ndc_w, params.near, z);
    out.position = v.position;
    out.normal = v.normal;
    out.uv = vec2<f32>(v.u, v.v);
    out.color = v.color.rgb;
    out.material = tri.material;
    out.triangle = vertex_index / 3u;
    return out;
}

struct FragmentOut {
    @location(0) color: vec4<f32>,
    @location(1) depth: f32,
}

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    let n = normalize(in.normal);
    let view_dir = normalize(params.eye - in.position);
    let albedo = albedo_of(materials[in.material], in.uv, in.color, mesh_texture, mesh_sampler);
    var out: FragmentOut;
    var visibility = 1.0;
    if params.shading.shadows != 0u {
        visibility = light_visibility(in.position, in.triangle, params.eye, params.shading.light);
    }
    out.color = vec4<f32>(shade(albedo, n, view_dir, params.shading, visibility), 1.0);
    out.depth = dot(in.position - params.eye, params.forward) * params.depth_scale;
    return out;
}
