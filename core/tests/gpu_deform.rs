//! Deformation states on the GPU: baked beside the base mesh, each stores only the pages that
//! differ from the base state (none for an unchanged or reordered mesh: the bake is
//! deterministic), reads back as a plain bake of its mesh in the base frame, keeps cameras that
//! see the change only as a moved shadow, renders by name through the quality request, and
//! refuses bad states.

mod common;

use std::sync::{Arc, OnceLock};

use lumigraph_core::asset::{AssetFile, Channel, ImageKey, Provenance};
use lumigraph_core::bake::{BakeError, BakeOptions, Baker, StateBake};
use lumigraph_core::deform::{self, DeformError, StateMesh};
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::Mesh;
use lumigraph_core::metrics;
use lumigraph_core::quality::{Quality, QualityError};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer, UploadOptions};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::View;

struct Ctx {
    baker: Baker,
    renderer: Renderer,
    reference: ReferenceRenderer,
}

fn ctx() -> &'static Ctx {
    static CTX: OnceLock<Ctx> = OnceLock::new();
    CTX.get_or_init(|| {
        let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
        Ctx {
            baker: Baker::new(gpu.clone()),
            renderer: Renderer::new(gpu.clone()),
            reference: ReferenceRenderer::new(gpu),
        }
    })
}

/// The ground quad (±2, y = 0) and a box standing on it at x ∈ [lo, lo + 0.5], z ∈ [−1.3,
/// −0.8], 0.5 high, behind a wall (x ∈ [−2, 2], z = −0.5, 0.9 high): the ground's ±2 corners
/// bound every variant, so all share one bounding sphere.
fn yard(box_x: f32) -> Mesh {
    let mut positions = vec![
        [-2.0, 0.0, -2.0],
        [-2.0, 0.0, 2.0],
        [2.0, 0.0, 2.0],
        [2.0, 0.0, -2.0],
    ];
    let mut triangles = vec![[0, 1, 2], [0, 2, 3]];
    common::push_box(
        (&mut positions, &mut triangles),
        [-2.0, 0.0, -0.55],
        [2.0, 0.9, -0.5],
    );
    common::push_box(
        (&mut positions, &mut triangles),
        [box_x, 0.0, -1.3],
        [box_x + 0.5, 0.5, -0.8],
    );
    Mesh::from_arrays(positions, triangles, None).expect("yard")
}

/// 162 cameras × 64 px, shadows from a low light along +x (shadows run along −x on the ground).
fn options() -> BakeOptions {
    BakeOptions {
        cameras: 162,
        resolution: 64,
        shading: Shading {
            light: [0.8, 0.35, 0.0],
            shadows: true,
            ..Shading::default()
        },
        ..BakeOptions::default()
    }
}

fn state<'a>(name: &'a str, mesh: &'a Mesh) -> StateMesh<'a> {
    StateMesh {
        name,
        mesh,
        source_name: name,
        source_sha256: "",
        params: None,
    }
}

fn bake_states(
    base: &Mesh,
    states: &[StateMesh<'_>],
    options: &BakeOptions,
) -> Result<AssetFile, BakeError> {
    let bytes = bake_state_bytes(base, states, options)?;
    Ok(AssetFile::from_bytes(bytes).expect("baked asset opens"))
}

/// [`bake_states`]'s file bytes.
fn bake_state_bytes(
    base: &Mesh,
    states: &[StateMesh<'_>],
    options: &BakeOptions,
) -> Result<Vec<u8>, BakeError> {
    ctx().baker.bake_states_to_bytes(
        base,
        &StateBake {
            meshes: states,
            page_size: 16,
            ..StateBake::default()
        },
        options,
        &Provenance::default(),
        &mut |_, _| {},
    )
}

#[test]
fn a_state_stores_only_changed_pages_and_reads_as_a_plain_bake_of_its_mesh() {
    let base = yard(-0.25);
    let moved = yard(0.6);
    let mut reordered = base.clone();
    reordered.triangles.reverse();
    let asset = bake_states(
        &base,
        &[
            state("same", &base),
            state("reordered", &reordered),
            state("moved", &moved),
        ],
        &options(),
    )
    .expect("bake");
    let header = asset.header();
    assert_eq!(header.format_version, 4, "partial images need version 4");
    assert_eq!(header.page_size, 16);
    let storage = deform::storage(&asset).expect("storage");
    let names: Vec<&str> = storage.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["same", "reordered", "moved"]);
    // The bake is deterministic, whatever the triangle order: nothing differs.
    assert_eq!(storage[0].stored_pages, 0, "{storage:?}");
    assert_eq!(storage[1].stored_pages, 0, "{storage:?}");
    let moved_storage = &storage[2];
    assert!(
        moved_storage.fraction > 0.0 && moved_storage.fraction < 0.35,
        "{moved_storage:?}"
    );

    // The moved state reads, page for page, as the base of a bake of the moved yard (same
    // frame: the ground's corners bound both).
    let plain = bake_states(&moved, &[], &options()).expect("plain bake");
    assert_eq!(plain.header().frame, header.frame);
    for camera in 0..162 {
        for channel in [Channel::Color, Channel::Depth] {
            assert_eq!(
                asset
                    .read_image(ImageKey::new(0, 3, camera, channel))
                    .expect("state image"),
                plain
                    .read_image(ImageKey::new(0, 0, camera, channel))
                    .expect("plain image"),
                "camera {camera} {channel:?}"
            );
        }
    }

    // Cameras that see the move only as its shadow (the box is behind the wall or the ground
    // for them; the shadow on the ground is not): without shadows the move changes nothing
    // they see, and with shadows they store colour pages and no depth page. They are kept.
    let unshadowed = BakeOptions {
        shading: Shading {
            shadows: false,
            ..options().shading
        },
        ..options()
    };
    let flat = bake_states(&base, &[state("moved", &moved)], &unshadowed).expect("bake");
    let pages = |asset: &AssetFile, state: u16, k: u32, c: Channel| {
        asset.stored_pages(ImageKey::new(0, state, k, c))
    };
    let shadow_only: Vec<u32> = (0..162)
        .filter(|&k| {
            pages(&flat, 1, k, Channel::Color) + pages(&flat, 1, k, Channel::Depth) == 0
                && pages(&asset, 3, k, Channel::Color) > 0
        })
        .collect();
    assert!(
        !shadow_only.is_empty(),
        "no camera sees the move only as a shadow"
    );
    for &k in &shadow_only {
        assert_eq!(pages(&asset, 3, k, Channel::Depth), 0, "camera {k}");
    }
}

#[test]
fn a_state_renders_by_name_like_its_mesh_and_unknown_states_are_errors() {
    let base = yard(-0.25);
    let moved = yard(0.6);
    let options = BakeOptions {
        resolution: 128,
        ..options()
    };
    let asset = bake_states(&base, &[state("moved", &moved)], &options).expect("bake");
    let c = ctx();
    let field = c.renderer.upload(&asset).expect("upload");
    assert_eq!(field.deformation_states(), vec![1]);
    // A whole copy of the base state's maps per state on the device.
    let base_only = c
        .renderer
        .upload_with(
            &asset,
            &UploadOptions {
                base_state_only: true,
                ..UploadOptions::default()
            },
        )
        .expect("upload");
    assert_eq!(field.gpu_bytes, 2 * base_only.gpu_bytes);

    // From behind the wall, where the box shows.
    let view = View::look_at([1.5, 2.5, -4.0], [0.3, 0.2, -1.0], 45.0, 160, 160);
    let render = |name: Option<&str>| {
        let plan = Quality {
            state: name.map(str::to_owned),
            ..Quality::default()
        }
        .plan(asset.header())
        .expect("plan");
        plan.render(&c.renderer, &field, &view)
            .expect("render")
            .frame
    };
    let truth = |mesh: &Mesh| {
        let gpu_mesh = c.reference.upload(mesh).expect("mesh");
        c.reference
            .render(&gpu_mesh, &view, &options.shading)
            .expect("reference")
    };
    let (base_truth, moved_truth) = (truth(&base), truth(&moved));
    let score = |frame, truth| metrics::compare(frame, truth).expect("compare").masked_psnr;
    let base_frame = render(None);
    let named_base = render(Some("base"));
    let moved_frame = render(Some("moved"));
    assert_eq!(base_frame.color, named_base.color, "`base` names state 0");
    // Each state matches its own mesh far better than the other's (the box moved 0.85 units).
    let (on_base, on_moved) = (
        score(&base_frame, &base_truth),
        score(&moved_frame, &moved_truth),
    );
    assert!(on_base > 24.0 && on_moved > 24.0, "{on_base} {on_moved}");
    let crossed = (
        score(&moved_frame, &base_truth),
        score(&base_frame, &moved_truth),
    );
    assert!(
        crossed.0 < on_moved - 3.0 && crossed.1 < on_base - 3.0,
        "each state should match its own mesh: {on_base} {on_moved} {crossed:?}"
    );
    // The same state through RenderOptions (what the plan sets) draws the same frame.
    let direct = c
        .renderer
        .render(
            &field,
            &view,
            &RenderOptions {
                state: Some(1),
                ..RenderOptions::default()
            },
        )
        .expect("render");
    assert_eq!(direct.color, moved_frame.color);

    // Unknown names list the asset's states; a state the upload left out is an error.
    let err = Quality {
        state: Some("dent".to_owned()),
        ..Quality::default()
    }
    .plan(asset.header())
    .expect_err("unknown state");
    assert!(matches!(err, QualityError::State(_)), "{err}");
    assert!(
        err.to_string().contains("base, moved"),
        "the message lists the states: {err}"
    );
    let err = c
        .renderer
        .render(
            &base_only,
            &view,
            &RenderOptions {
                state: Some(1),
                ..RenderOptions::default()
            },
        )
        .expect_err("not uploaded");
    assert!(err.to_string().contains("state 1"), "{err}");
}

#[test]
fn scene_instances_of_one_asset_show_the_states_they_name() {
    use lumigraph_core::scene::{Scene, SceneError};
    let base = yard(-0.25);
    let moved = yard(0.6);
    let bytes = bake_state_bytes(&base, &[state("moved", &moved)], &options()).expect("bake");
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("yard.lfa"), &bytes).expect("write");
    let asset = AssetFile::from_bytes(bytes).expect("baked asset opens");
    let c = ctx();
    let field = c.renderer.upload(&asset).expect("upload");
    let view = View::look_at([1.5, 2.5, -4.0], [0.3, 0.2, -1.0], 45.0, 96, 96);
    let alone = |name: Option<&str>| {
        Quality {
            state: name.map(str::to_owned),
            ..Quality::default()
        }
        .plan(asset.header())
        .expect("plan")
        .render(&c.renderer, &field, &view)
        .expect("render")
        .frame
    };
    let scene = |object: serde_json::Value| {
        let text = serde_json::json!({"objects": [object]}).to_string();
        Scene::from_json(&text, dir.path(), &c.renderer, &c.reference)
    };
    for name in [None, Some("moved")] {
        let mut object = serde_json::json!({"type": "lightfield", "asset": "yard.lfa"});
        if let Some(name) = name {
            object["state"] = name.into();
        }
        let frame = scene(object)
            .expect("scene")
            .render(&c.renderer, &c.reference, &view)
            .expect("scene render");
        // One opaque layer composited keeps its colours: at most one code of rounding.
        let worst = common::max_code_diff(&frame.color, &alone(name).color);
        assert!(worst <= 1, "{name:?}: {worst} codes");
    }
    assert!(common::max_code_diff(&alone(None).color, &alone(Some("moved")).color) > 40);
    // An unknown state, and a time on an asset without an animation, name the object.
    for (key, value, needle) in [
        ("state", serde_json::json!("dent"), "base, moved"),
        ("time", serde_json::json!(0.5), "animation"),
    ] {
        let mut object = serde_json::json!({"type": "lightfield", "asset": "yard.lfa"});
        object[key] = value;
        let err = scene(object).err().expect("refused");
        assert!(matches!(err, SceneError::Quality { index: 0, .. }), "{err}");
        assert!(err.to_string().contains(needle), "{err}");
    }
}

#[test]
fn bad_states_are_refused_before_anything_is_baked() {
    let base = yard(-0.25);
    // Beyond the ground's corners: outside the base's bounding sphere.
    let mut outside = base.clone();
    for p in &mut outside.positions {
        if p[1] > 0.6 {
            p[1] = 3.5;
        }
    }
    let err = bake_states(&base, &[state("tall", &outside)], &options()).expect_err("outside");
    assert!(
        matches!(err, BakeError::Deform(DeformError::Outside { .. })),
        "{err}"
    );
    assert!(err.to_string().contains("bounding sphere"), "{err}");
    for (names, why) in [
        (&["base"][..], "base state"),
        (&["a", "a"][..], "twice"),
        (&[""][..], "empty"),
    ] {
        let states: Vec<StateMesh<'_>> = names.iter().map(|n| state(n, &base)).collect();
        let err = bake_states(&base, &states, &options()).expect_err(why);
        assert!(
            matches!(err, BakeError::Deform(DeformError::BadName(..))),
            "{why}: {err}"
        );
    }
    let lit = BakeOptions {
        lights: Some(12),
        ..options()
    };
    let err = bake_states(&base, &[state("same", &base)], &lit).expect_err("lights");
    assert!(matches!(err, BakeError::StatesWithLights), "{err}");
    // A light state is not a state to render by name.
    let lit_asset = bake_states(&base, &[], &lit).expect("light states");
    let err = Quality {
        state: Some("ambient".to_owned()),
        ..Quality::default()
    }
    .plan(lit_asset.header())
    .expect_err("light state by name");
    assert!(err.to_string().contains("light"), "{err}");
}
