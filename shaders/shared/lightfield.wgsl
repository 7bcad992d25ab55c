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
// `direction_lookup` holds, for each texel of an octahedral map of directions, the level-MAX_LEVEL
// triangle holding the texel's centre (`CameraSet::direction_lookup`, built by the CPU geometry);
// its ancestor at `level` is found by index. One texel load instead of a descent of the
// hierarchy, which read three edge normals per level: buffer and texture loads are what a lookup
// costs on lavapipe (a 512² frame 0.7–1.6 ms faster on the bunny and the demo). A direction within
// DIRECTION_LOOKUP_REACH (0.0042 rad) of a triangle's edge may get the neighbour across it: its
// weights, clamped to that edge, are then off by about that distance over the triangle's height
// (measured over 60 000 directions, vertices and edges among them: at most 0.012 at level 2,
// 0.026 at level 3; `shader_lookup_finds_the_triangle_within_its_reach` in render.rs).
fn locate(p: vec3<f32>, level: u32) -> Located {
    let q = p / max(abs(p.x) + abs(p.y) + abs(p.z), 1e-30);
    // The lower hemisphere is folded out into the corners of the square.
    let folded = (vec2<f32>(1.0) - abs(q.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), q.xy >= vec2<f32>(0.0));
    let uv = select(q.xy, folded, q.z < 0.0);
    let size = i32(DIRECTION_LOOKUP_SIZE);
    let texel = clamp(vec2<i32>(floor((uv * 0.5 + 0.5) * f32(size))), vec2<i32>(0), vec2<i32>(size - 1));
    let finest = textureLoad(direction_lookup, texel, 0).x;
    let l = min(level, MAX_LEVEL);
    // Triangle k of a level has children 4k..4k + 3 in the next; level l starts after
    // 20 (4^l − 1) / 3 triangles.
    let local = finest >> (2u * (MAX_LEVEL - l));
    let level_start = 20u * ((1u << (2u * l)) - 1u) / 3u;
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
