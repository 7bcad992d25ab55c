// Spherical light-field data shared by the marchers: cameras, the icosphere triangle hierarchy and the triangle lookup of seed 000 §2.

struct Camera {
    position: vec4<f32>,
    x: vec4<f32>,
    y: vec4<f32>,
    z: vec4<f32>,
}

struct HierTriangle {
    v: vec3<u32>,
    first_child: u32,
}

struct Located {
    cameras: vec3<u32>,
    weights: vec3<f32>,
}

// The triangle of `level` met by unit direction p, with central-projection barycentric weights.
// Level 0: the best of the 20 icosahedron faces by their unit edge normals (`locate_level0`,
// generated from the same camera set the CPU uses, see shaders.rs). Each finer
// level: the parent's middle child unless p lies outside one of its edges, then the corner child
// across that edge (`split_normals`, 3 per parent). No camera data is read until the end —
// buffer loads are what a lookup costs on lavapipe.
fn locate(p: vec3<f32>, level: u32) -> Located {
    let best = locate_level0(p);
    var level_start = 0u;
    var local = best;
    var count = 20u;
    for (var l = 0u; l < level; l++) {
        let t = level_start + local;
        let s = vec3<f32>(dot(split_normals[3u * t].xyz, p), dot(split_normals[3u * t + 1u].xyz, p), dot(split_normals[3u * t + 2u].xyz, p));
        var child = 3u;
        if min(min(s.x, s.y), s.z) < 0.0 {
            child = select(select(2u, 1u, s.y <= s.z), 0u, s.x <= s.y && s.x <= s.z);
        }
        level_start += count;
        count *= 4u;
        local = 4u * local + child;
    }
    let t = hierarchy[level_start + local];
    let v0 = cameras[t.v.x].position.xyz;
    let v1 = cameras[t.v.y].position.xyz;
    let v2 = cameras[t.v.z].position.xyz;
    var w = max(vec3<f32>(dot(p, cross(v1, v2)), dot(v0, cross(p, v2)), dot(v0, cross(v1, p))), vec3<f32>(0.0));
    let sum = w.x + w.y + w.z;
    if sum > 0.0 {
        w = w / sum;
    } else {
        w = vec3<f32>(1.0, 0.0, 0.0);
    }
    return Located(t.v, w);
}

// Line o + t·d (|d| = 1) against the sphere |x| = radius: both roots, or (1, -1) when missed.
fn sphere_roots(o: vec3<f32>, d: vec3<f32>, radius: f32) -> vec2<f32> {
    let b = dot(o, d);
    let closest = o - b * d;
    let h = radius * radius - dot(closest, closest);
    if h < 0.0 {
        return vec2<f32>(1.0, -1.0);
    }
    let s = sqrt(h);
    return vec2<f32>(-b - s, -b + s);
}
