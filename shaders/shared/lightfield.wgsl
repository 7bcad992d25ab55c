// Spherical light-field data for the marcher: cameras, the icosphere triangle hierarchy and the triangle lookup of seed 000 §2.

// A camera's position on the unit sphere and its frame (z = −position: the pole of the
// hemisphere it records).
struct Camera {
    position: vec3<f32>,
    x: vec3<f32>,
    y: vec3<f32>,
    z: vec3<f32>,
}

// Camera k, its frame derived from its position as `geometry::camera_frame` derives it: z the
// unit vector towards the centre, x = normalize(a × z) for the world axis a that rule picks
// (its index in `cameras[k].w`, chosen on the CPU in f64, so f32 cannot break a tie otherwise),
// y = z × x. Derived, not loaded: the nine floats of a frame cost more to gather than to
// compute (docs/marcher.md); the frame differs from the CPU's f64 one by f32 rounding (below
// 1e-6, tests).
fn camera(k: u32) -> Camera {
    let p = cameras[k];
    let z = -normalize(p.xyz);
    let a = vec3<f32>(vec3<f32>(p.w) == vec3<f32>(0.0, 1.0, 2.0));
    let x = normalize(cross(a, z));
    return Camera(p.xyz, x, cross(z, x), z);
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
// hierarchy, which read three edge normals per level: loads are what a lookup costs on lavapipe
// (docs/marcher.md). A direction within
// DIRECTION_LOOKUP_REACH (0.0042 rad) of a triangle's edge may get the neighbour across it: its
// weights, clamped to that edge, are then off by about that distance over the triangle's height
// (`shader_lookup_finds_the_triangle_within_its_reach` in render/upload.rs bounds it).
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
    return Located(t.v, triangle_weights(p, cameras[t.v.x].xyz, cameras[t.v.y].xyz, cameras[t.v.z].xyz));
}

// Central-projection barycentric weights of unit direction p in the triangle of unit vertices
// v0, v1, v2, clamped to the triangle (a direction outside it, within the lookup's reach, takes
// the weights of the nearest point of the edge it lies beyond, about).
fn triangle_weights(p: vec3<f32>, v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>) -> vec3<f32> {
    var w = max(vec3<f32>(dot(p, cross(v1, v2)), dot(v0, cross(p, v2)), dot(v0, cross(v1, p))), vec3<f32>(0.0));
    let sum = w.x + w.y + w.z;
    if sum > 0.0 {
        w = w / sum;
    } else {
        w = vec3<f32>(1.0, 0.0, 0.0);
    }
    return w;
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
