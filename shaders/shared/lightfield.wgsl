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

// Smallest signed edge test of p against the spherical triangle (a, b, c), each normalised to the
// sine of the angular distance so that scores of different triangles compare (largest = best).
fn containment(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, p: vec3<f32>) -> f32 {
    let nab = cross(a, b);
    let nbc = cross(b, c);
    let nca = cross(c, a);
    return min(min(dot(nab, p) / length(nab), dot(nbc, p) / length(nbc)), dot(nca, p) / length(nca));
}

// The triangle of `level` met by unit direction p (descending from the 20 level-0 triangles), with
// central-projection barycentric weights.
fn locate(p: vec3<f32>, level: u32) -> Located {
    var best = 0u;
    var best_score = -1e30;
    for (var i = 0u; i < 20u; i++) {
        let t = hierarchy[i];
        let s = containment(cameras[t.v.x].position.xyz, cameras[t.v.y].position.xyz, cameras[t.v.z].position.xyz, p);
        if s > best_score {
            best_score = s;
            best = i;
        }
    }
    for (var l = 0u; l < level; l++) {
        let first = hierarchy[best].first_child;
        best_score = -1e30;
        for (var c = 0u; c < 4u; c++) {
            let t = hierarchy[first + c];
            let s = containment(cameras[t.v.x].position.xyz, cameras[t.v.y].position.xyz, cameras[t.v.z].position.xyz, p);
            if s > best_score {
                best_score = s;
                best = first + c;
            }
        }
    }
    let t = hierarchy[best];
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
