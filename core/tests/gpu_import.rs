//! Import of external renders (seed 000 §3.4) on the GPU: a mesh's reference renders (colour
//! and z-depth, with shadows) from 12 directions, turned into depth reliefs and baked unlit,
//! render like a direct bake of the mesh against the reference.

mod common;

use std::sync::{Arc, OnceLock};

use lumigraph_core::asset::{AssetFile, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker};
use lumigraph_core::gpu::Gpu;
use lumigraph_core::import_views::{ImportOptions, ViewImage, relief_mesh, surround_views};
use lumigraph_core::metrics;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::evaluation_views;

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

#[test]
fn imported_renders_match_a_direct_bake_of_their_mesh() {
    let c = ctx();
    let (mesh, _) = common::shadow_scene();
    let shading = Shading {
        light: [0.5, 1.0, 0.3],
        shadows: true,
        ..Shading::default()
    };
    let gpu_mesh = c.reference.upload(&mesh).expect("mesh");
    let sphere = mesh.bounding_sphere();
    // External renders: the 12 icosahedron directions, 2.5 r away, 192².
    let images: Vec<ViewImage> = surround_views(sphere.center, sphere.radius, 12, 192)
        .into_iter()
        .map(|view| {
            let frame = c
                .reference
                .render(&gpu_mesh, &view, &shading)
                .expect("reference");
            ViewImage {
                view,
                color: frame.color,
                depth: frame.depth,
            }
        })
        .collect();
    let relief = relief_mesh(&images, &ImportOptions::default()).expect("relief");
    let options = BakeOptions {
        cameras: 42,
        resolution: 128,
        shading,
        ..BakeOptions::default()
    };
    let bake = |mesh, options: &BakeOptions| {
        let bytes = c
            .baker
            .bake_to_bytes(mesh, options, &Provenance::default(), &mut |_, _| {})
            .expect("bake");
        let asset = AssetFile::from_bytes(bytes).expect("asset");
        c.renderer.upload(&asset).expect("upload")
    };
    let imported = bake(
        &relief,
        &BakeOptions {
            shading: Shading {
                unlit: true,
                ..Shading::default()
            },
            one_sided: true,
            color_codec: None,
            depth_codec: None,
            ..options
        },
    );
    let direct = bake(&mesh, &options);
    let views = evaluation_views(sphere.center.to_array(), sphere.radius, 3, 1, 160);
    let (mut ours, mut theirs) = (0.0, 0.0);
    for view in &views {
        let truth = c
            .reference
            .render(&gpu_mesh, view, &shading)
            .expect("reference");
        let score = |field| {
            let frame = c
                .renderer
                .render(field, view, &RenderOptions::default())
                .expect("render");
            metrics::compare(&frame, &truth).expect("compare")
        };
        let (a, b) = (score(&imported), score(&direct));
        // The shadows came with the images: same coverage to a few pixels.
        assert!(
            a.mask_mismatch_px as f64
                <= b.mask_mismatch_px as f64 + 0.01 * truth.covered_count() as f64,
            "{a:?} {b:?}"
        );
        ours += a.masked_psnr / 3.0;
        theirs += b.masked_psnr / 3.0;
    }
    // Resampled twice (image → relief → maps), the import stays within 1.5 dB of the direct
    // bake (measured: BENCHMARKS.md, "Import of external renders").
    eprintln!("import {ours:.2} dB, direct {theirs:.2} dB");
    assert!(
        ours > theirs - 1.5 && ours > 22.0,
        "import {ours:.2} dB, direct {theirs:.2} dB"
    );
}
