// Probing one camera: where a point projects into its map and what its depth says there.
//
// From the generated preamble: EDGE_BASE, EDGE_CODES, EDGE_E_LEVELS, EDGE_DEPTH_LEVELS,
// EDGE_DEPTH_BITS, EDGE_DEPTH_STEP (render/upload.rs `edge_codes`).

// One camera's view of a point x: where it projects and what its depth map says there.
struct Probe {
    // f = |x − p| − D·chord: < 0 in front of the surface the camera sees, > 0 behind it.
    f: f32,
    // Continuous texel coordinates of the projection.
    tc: vec2<f32>,
    // Bilinear weights of the 2×2 footprint restricted to the chosen layer's hit texels (not
    // normalized): the colour's.
    layer_weights: vec4<f32>,
}

fn project(cam: Camera, x: vec3<f32>) -> vec4<f32> {
    let q = x - cam.position;
    let len = length(q);
    let qz = dot(q, cam.z);
    // uv = r.xy / (1 + r.z) for the unit direction r = q / |q|, with one division.
    let uv = vec2<f32>(dot(q, cam.x), dot(q, cam.y)) / max(len + qz, 1e-6 * max(len, 1e-12));
    let tc = (uv + 1.0) * 0.5 * params.resolution;
    // (texel x, texel y, |x − p|, chord 2·r_z)
    return vec4<f32>(tc, len, 2.0 * qz / max(len, 1e-12));
}

// Edge codes: a no-hit texel beside the silhouette has footprint code
// EDGE_BASE + (e level << EDGE_DEPTH_BITS | depth level) (`edge_codes` in render/upload.rs): the
// silhouette passes e = (e level + 0.5) / EDGE_E_LEVELS texel from its hit neighbours' centres,
// and depth level · EDGE_DEPTH_STEP extends the surface from them through the silhouette to its
// centre.

// Depth at a projection. `edge_aware` splits the 2×2 footprint at its largest depth gap (above
// `edge_gap`) and keeps the front layer where it holds enough of the bilinear weight, else the
// back one, so no lookup ever returns a depth interpolated between a surface and what lies behind
// its silhouette (DESIGN §4). Edge texels place the silhouette between texel centres where the
// bake found it, and extend the front layer's depth to it (docs/marcher.md).
fn probe(cam: Camera, k: u32, x: vec3<f32>, edge_aware: bool) -> Probe {
    let pr = project(cam, x);
    let tc = pr.xy;
    // The whole 2×2 footprint in one load: texel (x, y) of `footprints` holds the 16-bit depth
    // codes of texels (x, y), (x+1, y), (x, y+1), (x+1, y+1): one load, not four or a gather.
    let n = i32(params.resolution);
    let base = clamp(vec2<i32>(floor(tc - 0.5)), vec2<i32>(0), vec2<i32>(n - 1));
    let codes = textureLoad(footprints, base, k, 0);
    // Edge texels (no hit, beside the silhouette) read as no hit (1) for the split.
    let rel = codes - vec4<u32>(EDGE_BASE);
    let edge = rel < vec4<u32>(EDGE_CODES);
    let d = select(vec4<f32>(codes) * (1.0 / 65535.0), vec4<f32>(1.0), edge);
    let fr = fract(tc - 0.5);
    let bw = vec4<f32>((1.0 - fr.x) * (1.0 - fr.y), fr.x * (1.0 - fr.y), (1.0 - fr.x) * fr.y, fr.x * fr.y);
    // Written as selects, without `if`: an `if` costs its body on lavapipe (docs/marcher.md).
    let lo = min(min(d.x, d.y), min(d.z, d.w));
    let hi = max(max(d.x, d.y), max(d.z, d.w));
    let split = edge_aware & (hi - lo > params.edge_gap);
    let front = d <= vec4<f32>(0.5 * (lo + hi));
    // The front layer's share of the footprint: a front texel counts 1, a back one 0, an edge
    // texel sigma = 1 − (1 − front_mass) / e, so that between it and a front texel the share
    // falls to `front_mass` exactly at the silhouette, e of the way from the front texel.
    // The interior pass (flat quads, no silhouette near the eye's ray) reads edge texels as plain
    // no hit: the same pixels, in less time.
    let edges = edge & vec4<bool>(!interior_role());
    let sigma = vec4<f32>(1.0) - ((1.0 - params.front_mass) * f32(EDGE_E_LEVELS)) / (vec4<f32>(rel >> vec4<u32>(EDGE_DEPTH_BITS)) + 0.5);
    let share = select(select(vec4<f32>(0.0), sigma, edges), vec4<f32>(1.0), front);
    let chosen = dot(bw, share) >= params.front_mass;
    // Colour from the chosen layer's hits (`layer_color` normalizes); depth in the front layer
    // from its hits and edge texels, whose extrapolated depths make the surface recede to the
    // silhouette's depth. Unsplit: the whole footprint.
    let layer = select(!front, front, chosen);
    let color_weights = select(bw, bw * vec4<f32>(layer), split);
    let kept = select(vec4<f32>(0.0), bw, layer | (edges & vec4<bool>(chosen)));
    let layer_d = select(d, vec4<f32>(rel & vec4<u32>(EDGE_DEPTH_LEVELS - 1u)) * EDGE_DEPTH_STEP, edges & vec4<bool>(chosen));
    let depth = select(dot(bw, d), dot(kept, layer_d) / max(kept.x + kept.y + kept.z + kept.w, 1e-12), split);
    return Probe(pr.z - depth * pr.w, tc, color_weights);
}

// An RGBA8 texel of the normal maps: the octahedral point with 16 bits per coordinate that the
// bake stores (bake.wgsl `oct_encode16`), as a unit vector.
fn oct_decode16(t: vec4<f32>) -> vec3<f32> {
    let b = round(t * 255.0);
    let p = vec2<f32>(b.x * 256.0 + b.y, b.z * 256.0 + b.w) / 65535.0 * 2.0 - 1.0;
    var n = vec3<f32>(p, 1.0 - abs(p.x) - abs(p.y));
    let fold = max(-n.z, 0.0);
    n.x += select(fold, -fold, n.x >= 0.0);
    n.y += select(fold, -fold, n.y >= 0.0);
    return normalize(n);
}

// Texel p of camera k in a relit frame (core/src/light.rs): ambient + Σ w_i · direct_i over the
// three proxy lights around the frame's light, with `Blend::Normal` (`light_weights.w` 1) scaled
// by the stored shading normal's cosine ratio max(0, n·ℓ) / Σ w_i max(0, n·ℓ_i), which is at most
// 1 (w ≥ 0 and Σ w_i ℓ_i = ℓ), 1 where all three lights face the texel, and exact at a
// terminator (0 where none does); clamped as the bake clamps a colour. Alpha: the ambient map's
// (1 at hits, as the base colour's).
//
// Where the proxy lights that weigh in disagree on the texel's shadow (some lit, some facing it
// but dark), the blend is a penumbra the truth does not have: `contested` holds that texel's
// blended direct part (`soft`) and its direct part with the light unshadowed (`full`: the
// lit proxies' albedo · (1 − ambient), max(0, n·ℓ_i) divided out, times max(0, n·ℓ)), for the
// shadow ray of `shade` to choose between (`params.shadow_rays`).
struct RelitTexel {
    color: vec4<f32>,
    soft: vec3<f32>,
    full: vec3<f32>,
    contested: f32,
}

// An 8-bit direct part at or below this is dark: shadowed, facing away or black.
const DARK_DIRECT: f32 = 0.5 / 255.0;
// A proxy light that faces the texel counts as shadowing it only where the lit proxies say it
// would show at least this much direct light unshadowed (a dark albedo cannot tell).
const SHADOW_EVIDENCE: f32 = 2.0 / 255.0;

fn relit_texel(p: vec2<i32>, k: u32) -> RelitTexel {
    let w = params.light_weights;
    let a = textureLoad(ambient_maps, p, k, 0);
    let da = textureLoad(light_a_maps, p, k, 0).rgb;
    let db = textureLoad(light_b_maps, p, k, 0).rgb;
    let dc = textureLoad(light_c_maps, p, k, 0).rgb;
    let direct = w.x * da + w.y * db + w.z * dc;
    let n = oct_decode16(textureLoad(normal_maps, p, k, 0));
    let cosines = max(vec3<f32>(0.0), vec3<f32>(dot(n, params.light_a.xyz), dot(n, params.light_b.xyz), dot(n, params.light_c.xyz)));
    let denominator = dot(w.xyz, cosines);
    let cos_l = max(dot(n, params.light_dir.xyz), 0.0);
    let ratio = select(0.0, min(cos_l / max(denominator, 1e-6), 1.0), denominator > 1e-6);
    let c = min(a.rgb + direct * select(1.0, ratio, w.w > 0.5), vec3<f32>(1.0));
    let ambient = min(a.rgb, vec3<f32>(1.0));
    // The proxies that weigh in and are lit; the albedo · (1 − ambient) they agree on.
    let brightest = vec3<f32>(max(max(da.r, da.g), da.b), max(max(db.r, db.g), db.b), max(max(dc.r, dc.g), dc.b));
    let weighs = w.xyz > vec3<f32>(0.0);
    let lit = weighs & (brightest > vec3<f32>(DARK_DIRECT)) & (cosines > vec3<f32>(0.0));
    let lw = select(vec3<f32>(0.0), w.xyz, lit);
    let k_rgb = (lw.x * da + lw.y * db + lw.z * dc) / max(dot(lw, cosines), 1e-6);
    let k_max = max(max(k_rgb.r, k_rgb.g), k_rgb.b);
    let shadowed = weighs & !lit & (cosines * k_max > vec3<f32>(SHADOW_EVIDENCE));
    // Read only with shadow rays, which need the normal (`light_weights.w` 1).
    let contested = any(lit) & any(shadowed);
    let full = min(a.rgb + k_rgb * cos_l, vec3<f32>(1.0)) - ambient;
    return RelitTexel(vec4<f32>(c, a.a), c - ambient, full, select(0.0, 1.0, contested));
}

// Texel p of camera k's colour map: the base state's, or in a relit frame (`params.lit`)
// `relit_texel`.
fn color_texel(p: vec2<i32>, k: u32) -> vec4<f32> {
    if per_invocation(params.lit == 0u) {
        return textureLoad(color_maps, p, k, 0);
    }
    return relit_texel(p, k).color;
}

// Colour of camera k at texel coordinates tc from the footprint texels with the given weights,
// normalized by their sum (four texels: a bilinear sample would mix colours across a
// silhouette; docs/marcher.md).
fn layer_color(k: u32, tc: vec2<f32>, bw: vec4<f32>) -> vec4<f32> {
    let f = footprint(tc);
    let sum = bw.x * color_texel(f.xy, k)
        + bw.y * color_texel(f.zy, k)
        + bw.z * color_texel(f.xw, k)
        + bw.w * color_texel(f.zw, k);
    return sum / max(bw.x + bw.y + bw.z + bw.w, 1e-12);
}

// The 2×2 footprint of texel coordinates tc, clamped to the map: (x, y) its first texel, (z, w)
// its last; the texels in `Probe::layer_weights`' order are xy, zy, xw, zw.
fn footprint(tc: vec2<f32>) -> vec4<i32> {
    let last = vec2<i32>(i32(params.resolution) - 1);
    let base = vec2<i32>(floor(tc - 0.5));
    return vec4<i32>(clamp(base, vec2<i32>(0), last), clamp(base + 1, vec2<i32>(0), last));
}

// `layer_color` in a relit frame, with the footprint's contested parts (`RelitTexel`) blended
// alike.
fn relit_layer_color(k: u32, tc: vec2<f32>, bw: vec4<f32>) -> RelitTexel {
    let f = footprint(tc);
    let t0 = relit_texel(f.xy, k);
    let t1 = relit_texel(f.zy, k);
    let t2 = relit_texel(f.xw, k);
    let t3 = relit_texel(f.zw, k);
    let inv = 1.0 / max(bw.x + bw.y + bw.z + bw.w, 1e-12);
    let wc = bw * vec4<f32>(t0.contested, t1.contested, t2.contested, t3.contested) * inv;
    return RelitTexel(
        (bw.x * t0.color + bw.y * t1.color + bw.z * t2.color + bw.w * t3.color) * inv,
        wc.x * t0.soft + wc.y * t1.soft + wc.z * t2.soft + wc.w * t3.soft,
        wc.x * t0.full + wc.y * t1.full + wc.z * t2.full + wc.w * t3.full,
        wc.x + wc.y + wc.z + wc.w,
    );
}

// The fixed baseline's colour: one bilinear sample; in a relit frame, the four texels'
// `relit_texel`s with bilinear weights (each texel's normal shades its own colour).
fn bilinear_color(k: u32, tc: vec2<f32>) -> vec4<f32> {
    if per_invocation(params.lit == 0u) {
        return textureSampleLevel(color_maps, linear_sampler, tc / params.resolution, k, 0.0);
    }
    let f = fract(tc - 0.5);
    return layer_color(k, tc, vec4<f32>((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y));
}
