//! GPU tests of light states (DESIGN §9, `lumigraph_core::light`): a bake for a proxy of light
//! directions, relit renders at and between them checked against bakes and reference renders
//! with the same light.

mod common;

use std::sync::{Arc, OnceLock};

use glam::DVec3;
use lumigraph_core::asset::{AssetFile, Channel, ImageKey, Provenance};
use lumigraph_core::bake::{BakeError, BakeOptions, Baker};
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::light::{self, Blend, LightDirection, LightError, LightStates};
use lumigraph_core::mesh::Mesh;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderError, RenderOptions, Renderer, Switches};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::View;

struct Ctx {
    baker: Baker,
    /// The default blend ([`Blend::Normal`]).
    renderer: Renderer,
    spherical: Renderer,
    planar: Renderer,
    /// The default blend without shadow rays (`Switches::shadow_rays` off).
    no_rays: Renderer,
    reference: ReferenceRenderer,
}

fn ctx() -> &'static Ctx {
    static CTX: OnceLock<Ctx> = OnceLock::new();
    CTX.get_or_init(|| {
        let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
        let switches = |light_blend| Switches {
            pass_timing: false,
            light_blend,
            ..Switches::default()
        };
        Ctx {
            baker: Baker::new(gpu.clone()),
            renderer: Renderer::with_switches(gpu.clone(), switches(Blend::Normal)),
            spherical: Renderer::with_switches(gpu.clone(), switches(Blend::Spherical)),
            planar: Renderer::with_switches(gpu.clone(), switches(Blend::Planar)),
            no_rays: Renderer::with_switches(
                gpu.clone(),
                Switches {
                    shadow_rays: false,
                    ..switches(Blend::Normal)
                },
            ),
            reference: ReferenceRenderer::new(gpu),
        }
    })
}

/// The ground quad under a floating box of the shadow tests: shadows on the ground move with
/// the light.
fn scene() -> Mesh {
    common::shadow_scene().0
}

/// A UV sphere of radius 1 (smooth normals): convex, so no point shadows another and relighting
/// errs only at the terminator.
fn sphere() -> Mesh {
    let (rings, segments) = (48u32, 96u32);
    let mut positions = Vec::new();
    for i in 0..=rings {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let phi = std::f32::consts::TAU * j as f32 / segments as f32;
            positions.push([
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            ]);
        }
    }
    let mut triangles = Vec::new();
    for i in 0..rings {
        for j in 0..segments {
            let at = |i: u32, j: u32| i * segments + j % segments;
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    Mesh::from_arrays(positions, triangles, None).expect("sphere")
}

fn bake(mesh: &Mesh, options: &BakeOptions) -> AssetFile {
    let bytes = ctx()
        .baker
        .bake_to_bytes(mesh, options, &Provenance::default(), &mut |_, _| {})
        .expect("bake");
    AssetFile::from_bytes(bytes).expect("baked asset opens")
}

/// The scene baked at 162 cameras × 128 px with shadows, and with `lights` light states.
fn shadow_bake(lights: Option<u32>, light: [f32; 3]) -> AssetFile {
    bake(
        &scene(),
        &BakeOptions {
            cameras: 162,
            resolution: 128,
            shading: Shading {
                light,
                shadows: true,
                ..Shading::default()
            },
            lights,
            ..Default::default()
        },
    )
}

fn view() -> View {
    View::look_at([3.0, 3.5, 4.0], [0.0, 0.0, 0.0], 40.0, 160, 160)
}

fn lit(light: DVec3) -> RenderOptions {
    RenderOptions {
        light: Some(LightDirection(light.to_array())),
        ..RenderOptions::default()
    }
}

/// Mean absolute difference per colour component (8-bit codes) over pixels both frames cover.
fn mean_diff(a: &Frame, b: &Frame) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for p in 0..a.depth.len() {
        if !(a.depth[p].is_finite() && b.depth[p].is_finite()) {
            continue;
        }
        for c in 0..3 {
            sum += (f64::from(a.color[4 * p + c]) - f64::from(b.color[4 * p + c])).abs();
        }
        n += 3;
    }
    assert!(n > 3 * 5000, "{n} components covered");
    sum / n as f64
}

#[test]
fn a_bake_with_lights_stores_colour_per_proxy_direction_and_shares_the_base_depth() {
    let asset = shadow_bake(Some(12), [0.3, 1.0, 0.2]);
    let header = asset.header();
    // base, ambient, normal, 12 directions.
    assert_eq!(header.states.len(), 15);
    let states = LightStates::of(header)
        .expect("valid")
        .expect("light states");
    assert_eq!(
        (states.count, states.ambient, states.normal),
        (12, 1, Some(2))
    );
    let key = |state, channel| ImageKey::new(0, state, 5, channel);
    assert!(asset.has_image(key(states.direct[3], Channel::Color)));
    assert!(!asset.has_image(key(states.direct[3], Channel::Depth)));
    assert_eq!(
        BakeOptions::of(header).lights,
        Some(12),
        "recorded in the bake options"
    );
    // The ambient part is albedo · ambient wherever the base state has a hit: 0.8 · 0.25; the
    // normal state holds the shading normal: the ground's +y (within the 16-bit octahedral
    // encoding's 1e-4 rad) or a box's smoothed one, unit either way.
    let (mut hits, mut ground) = (0, 0);
    for camera in 0..header.camera_count() {
        let key = |state, channel| ImageKey::new(0, state, camera, channel);
        let ambient = asset
            .read_image(key(states.ambient, Channel::Color))
            .expect("ambient");
        let normals = asset
            .read_image(key(states.normal.expect("normals"), Channel::Color))
            .expect("normals");
        let base_depth = asset
            .read_image(key(0, Channel::Depth))
            .expect("base depth");
        for (texel, px) in ambient.chunks_exact(4).enumerate() {
            let depth = u16::from_le_bytes([base_depth[2 * texel], base_depth[2 * texel + 1]]);
            if depth == u16::MAX {
                assert_eq!(px, [0, 0, 0, 0]);
                continue;
            }
            hits += 1;
            assert_eq!(px, [51, 51, 51, 255], "camera {camera} texel {texel}");
            let n = light::decode_normal(
                normals[4 * texel..4 * texel + 4]
                    .try_into()
                    .expect("a texel"),
            );
            assert!((n.length() - 1.0).abs() < 1e-9);
            if (n - DVec3::Y).length() < 1e-3 {
                ground += 1;
                assert!((n - DVec3::Y).length() < 1e-4, "{n}");
            }
        }
    }
    assert!(
        hits > 50_000 && ground > hits / 2,
        "{hits} hits, {ground} on the ground"
    );
}

#[test]
fn relit_at_a_proxy_direction_matches_a_bake_with_that_light() {
    let asset = shadow_bake(Some(12), [0.3, 1.0, 0.2]);
    let field = ctx().renderer.upload(&asset).expect("upload");
    let dirs = light::proxy_directions(12).expect("proxy");
    // Two proxy directions above the ground, one from the side (the box shadows the ground).
    for d in dirs.iter().filter(|d| d.y > 0.2).take(2) {
        let relit = ctx()
            .renderer
            .render(&field, &view(), &lit(*d))
            .expect("relit");
        let plain_asset = shadow_bake(None, d.as_vec3().to_array());
        let plain_field = ctx().renderer.upload(&plain_asset).expect("upload");
        let plain = ctx()
            .renderer
            .render(&plain_field, &view(), &RenderOptions::default())
            .expect("plain");
        // Same depth maps, so the same surface per pixel; the colour is the sum of two
        // rounded parts instead of one rounded whole: at most 1 code per texel, blended.
        assert_eq!(relit.depth, plain.depth, "light {d}");
        let worst = common::max_code_diff(&relit.color, &plain.color);
        assert!(worst <= 1, "light {d}: {worst} codes");
    }
}

#[test]
fn relit_between_proxy_lights_approaches_the_reference_better_than_planar_weights() {
    let mesh = ctx().reference.upload(&scene()).expect("mesh");
    // Lights at the centres of the proxy's triangles, where blending errs most. The ones well
    // above the ground light all of it from all three directions, so that planar weights lose
    // 20 % (12 lights) or 6.8 % (42) of its diffuse term there, and the spherical blend none.
    let mut blended_error = Vec::new();
    for count in [12, 42] {
        let asset = shadow_bake(Some(count), [0.3, 1.0, 0.2]);
        let field = ctx().renderer.upload(&asset).expect("upload");
        let planar_field = ctx().planar.upload(&asset).expect("upload");
        let spherical_field = ctx().spherical.upload(&asset).expect("upload");
        let no_rays_field = ctx().no_rays.upload(&asset).expect("upload");
        let dirs = light::proxy_directions(count).expect("proxy");
        let lights: Vec<DVec3> = light::centroid_lights(count)
            .expect("centroids")
            .into_iter()
            .filter(|&l| {
                let b = light::blend_for(count, l, Blend::Spherical).expect("blend");
                b.directions.iter().all(|&i| dirs[i as usize].y > 0.3)
            })
            .take(2)
            .collect();
        assert_eq!(lights.len(), 2);
        let mut sum = 0.0;
        for &l in &lights {
            let shading = Shading {
                light: l.as_vec3().to_array(),
                shadows: true,
                ..Shading::default()
            };
            let reference = ctx()
                .reference
                .render(&mesh, &view(), &shading)
                .expect("reference");
            let render = |renderer: &Renderer, field| {
                renderer.render(field, &view(), &lit(l)).expect("relit")
            };
            let normal = render(&ctx().renderer, &field);
            let spherical = render(&ctx().spherical, &spherical_field);
            let planar = render(&ctx().planar, &planar_field);
            let no_rays = render(&ctx().no_rays, &no_rays_field);
            // The light field's own error: a bake with exactly this light.
            let exact_asset = shadow_bake(None, shading.light);
            let exact_field = ctx().renderer.upload(&exact_asset).expect("upload");
            let exact = ctx()
                .renderer
                .render(&exact_field, &view(), &RenderOptions::default())
                .expect("exact");
            let (e0, en, er, es, ep) = (
                mean_diff(&exact, &reference),
                mean_diff(&normal, &reference),
                mean_diff(&no_rays, &reference),
                mean_diff(&spherical, &reference),
                mean_diff(&planar, &reference),
            );
            eprintln!(
                "{count} lights, light {l}: exact bake {e0:.2}, normal {en:.2}, without shadow \
                 rays {er:.2}, spherical {es:.2}, planar {ep:.2}"
            );
            // Blended, the three lights' shadows differ from the true one (ghost shadows);
            // the shadow rays decide where they disagree, which brings the frame to the
            // quality of a bake with exactly this light (within half a code: its shadow
            // edges are the texels', a ray's are the pixel's, and neither is always closer).
            // The normal's cosine ratio removes the terminator's error, planar weights also
            // darken every lit pixel.
            assert!(
                en < e0 + 0.5,
                "{count} lights, light {l}: {en:.2} vs {e0:.2}"
            );
            assert!(
                en < er - 0.2,
                "{count} lights, light {l}: with shadow rays {en:.2}, without {er:.2}"
            );
            assert!(
                er < es + 0.2,
                "{count} lights, light {l}: {er:.2} vs {es:.2}"
            );
            assert!(
                ep > en + 3.0,
                "{count} lights, light {l}: normal {en:.2}, planar {ep:.2}"
            );
            sum += er - e0;
        }
        blended_error.push(sum / 2.0);
    }
    // More light directions: closer shadows, less error where the blend alone decides.
    assert!(
        blended_error[1] < 0.6 * blended_error[0],
        "interpolation error without shadow rays {blended_error:?} (12, 42 lights)"
    );
}

#[test]
fn bad_lights_and_light_requests_are_clear_errors() {
    let plain = shadow_bake(None, [0.3, 1.0, 0.2]);
    let field = ctx().renderer.upload(&plain).expect("upload");
    let err = ctx()
        .renderer
        .render(&field, &view(), &lit(DVec3::Y))
        .expect_err("no light states");
    assert!(
        matches!(err, RenderError::Light(LightError::NoLightStates)),
        "{err}"
    );
    for bad in [[0.0; 3], [f64::NAN, 1.0, 0.0], [f64::INFINITY, 0.0, 0.0]] {
        let options = RenderOptions {
            light: Some(LightDirection(bad)),
            ..RenderOptions::default()
        };
        let err = ctx()
            .renderer
            .render(&field, &view(), &options)
            .expect_err("bad light");
        assert!(matches!(err, RenderError::Light(_)), "{bad:?}: {err}");
    }
    let bake_err = |options: BakeOptions| {
        ctx()
            .baker
            .bake_to_bytes(&scene(), &options, &Provenance::default(), &mut |_, _| {})
            .expect_err("refused")
    };
    assert!(matches!(
        bake_err(BakeOptions {
            lights: Some(13),
            ..Default::default()
        }),
        BakeError::Lights(LightError::BadCount(13))
    ));
    assert!(matches!(
        bake_err(BakeOptions {
            lights: Some(12),
            shading: Shading {
                unlit: true,
                ..Shading::default()
            },
            ..Default::default()
        }),
        BakeError::LightsUnlit
    ));
}

#[test]
fn a_scene_instance_relights_with_the_light_carried_into_its_frame() {
    use lumigraph_core::scene::{Rotation, Scene, Transform};
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = ctx()
        .baker
        .bake_to_bytes(
            &scene(),
            &BakeOptions {
                cameras: 42,
                resolution: 64,
                shading: Shading {
                    shadows: true,
                    ..Shading::default()
                },
                lights: Some(12),
                ..Default::default()
            },
            &Provenance::default(),
            &mut |_, _| {},
        )
        .expect("bake");
    std::fs::write(dir.path().join("lit.lfa"), &bytes).expect("write");
    let world_light = [1.0, 0.6, 0.2];
    let scene_file = dir.path().join("scene.json");
    let text = serde_json::json!({"objects": [{
        "type": "lightfield",
        "asset": "lit.lfa",
        "transform": {"rotation": {"axis": [0, 1, 0], "degrees": 90}},
        "options": {"light": world_light},
    }]});
    std::fs::write(&scene_file, text.to_string()).expect("write");
    let loaded = Scene::load(&scene_file, &ctx().renderer, &ctx().reference).expect("scene");
    let in_scene = loaded
        .render(&ctx().renderer, &ctx().reference, &view())
        .expect("scene render");
    // The instance alone, in its own frame: the view and the light turned back by 90°.
    let placement = Transform {
        rotation: Some(Rotation {
            axis: [0.0, 1.0, 0.0],
            degrees: 90.0,
        }),
        ..Transform::default()
    }
    .similarity()
    .expect("similarity");
    let local_view = placement.view_to_local(&view());
    let asset = AssetFile::from_bytes(bytes).expect("asset");
    let field = ctx().renderer.upload(&asset).expect("upload");
    let local_light = placement.to_local(DVec3::from(world_light)); // no translation or scale
    let alone = ctx()
        .renderer
        .render(&field, &local_view, &lit(local_light))
        .expect("alone");
    let unturned = ctx()
        .renderer
        .render(&field, &local_view, &lit(DVec3::from(world_light)))
        .expect("unturned");
    let worst = |a: &Frame, b: &Frame| common::max_code_diff(&a.color, &b.color);
    // Compositing one opaque layer keeps its colours (one code of rounding).
    assert!(
        worst(&in_scene, &alone) <= 1,
        "{}",
        worst(&in_scene, &alone)
    );
    assert!(
        worst(&in_scene, &unturned) > 40,
        "the light turned with the instance"
    );
}

#[test]
fn the_normal_blend_relights_a_convex_object_as_a_bake_with_that_light() {
    // No shadows on a convex sphere: between proxy lights only the terminator can err, where
    // some of the three lights face away. The stored normal's cosine ratio makes it exact, so
    // the relit frame is a bake with that light to within the light field's own error; the
    // spherical weights overshoot there and planar ones also darken the lit side.
    let view = View::look_at([2.2, 1.2, 2.6], [0.0, 0.0, 0.0], 40.0, 160, 160);
    let options = |light: [f32; 3], lights| BakeOptions {
        cameras: 162,
        resolution: 128,
        shading: Shading {
            light,
            ..Shading::default()
        },
        lights,
        ..Default::default()
    };
    let asset = bake(&sphere(), &options([0.3, 1.0, 0.5], Some(12)));
    let field = ctx().renderer.upload(&asset).expect("upload");
    let spherical_field = ctx().spherical.upload(&asset).expect("upload");
    let planar_field = ctx().planar.upload(&asset).expect("upload");
    for l in light::centroid_lights(12)
        .expect("centroids")
        .into_iter()
        .take(4)
    {
        let exact_asset = bake(&sphere(), &options(l.as_vec3().to_array(), None));
        let exact_field = ctx().renderer.upload(&exact_asset).expect("upload");
        let exact = ctx()
            .renderer
            .render(&exact_field, &view, &RenderOptions::default())
            .expect("exact");
        let normal = ctx()
            .renderer
            .render(&field, &view, &lit(l))
            .expect("relit");
        let spherical = ctx()
            .spherical
            .render(&spherical_field, &view, &lit(l))
            .expect("relit");
        let planar = ctx()
            .planar
            .render(&planar_field, &view, &lit(l))
            .expect("relit");
        let (en, es, ep) = (
            mean_diff(&normal, &exact),
            mean_diff(&spherical, &exact),
            mean_diff(&planar, &exact),
        );
        let worst = common::max_code_diff(&normal.color, &exact.color);
        eprintln!("light {l}: normal {en:.3} (worst {worst}), spherical {es:.3}, planar {ep:.3}");
        // Rounding of the parts (1 code each) and of the 16-bit normal; texels blended across
        // the silhouette may differ a little more.
        assert!(
            en < 0.3 && worst <= 2,
            "light {l}: {en:.3} codes, worst {worst}"
        );
        assert!(
            es > en + 0.5 && ep > en + 3.0,
            "light {l}: {en:.3} {es:.3} {ep:.3}"
        );
    }
}

#[test]
fn an_upload_without_light_states_costs_the_base_memory_and_renders_the_base_alike() {
    use lumigraph_core::render::UploadOptions;
    let asset = shadow_bake(Some(12), [0.3, 1.0, 0.2]);
    let full = ctx().renderer.upload(&asset).expect("upload");
    let base = ctx()
        .renderer
        .upload_with(
            &asset,
            &UploadOptions {
                base_state_only: true,
                ..UploadOptions::default()
            },
        )
        .expect("upload");
    // Ambient, normals and 12 lights: 14 RGBA8 arrays of 162 cameras (163 layers, padded for
    // GL) at 128².
    assert_eq!(full.gpu_bytes - base.gpu_bytes, 14 * 163 * 128 * 128 * 4);
    let options = RenderOptions::default();
    assert_eq!(
        ctx()
            .renderer
            .render(&full, &view(), &options)
            .expect("full")
            .color,
        ctx()
            .renderer
            .render(&base, &view(), &options)
            .expect("base")
            .color
    );
    let err = ctx()
        .renderer
        .render(&base, &view(), &lit(DVec3::Y))
        .expect_err("no light states uploaded");
    assert!(
        matches!(err, RenderError::Light(LightError::NoLightStates)),
        "{err}"
    );
}
