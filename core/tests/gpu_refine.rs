//! GPU tests (lavapipe in CI) of still-frame refinement on the demo knot: one sample is the plain
//! render; refined stills add no wrong-surface pixels and come closer to the supersampled
//! reference than single-sample frames do.

use std::sync::{Arc, OnceLock};

use lumigraph_core::asset::{AssetFile, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker};
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::demo_mesh;
use lumigraph_core::metrics;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::refine::{self, RefineError};
use lumigraph_core::render::{GpuLightField, RenderError, RenderOptions, Renderer};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::View;

struct Ctx {
    renderer: Renderer,
    reference: ReferenceRenderer,
    field: GpuLightField,
    mesh: lumigraph_core::gpu::mesh::GpuMesh,
    asset: AssetFile,
}

/// The demo baked at 162 cameras × 128 px, uploaded to both renderers once.
fn ctx() -> &'static Ctx {
    static CTX: OnceLock<Ctx> = OnceLock::new();
    CTX.get_or_init(|| {
        let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
        let mesh = demo_mesh().expect("demo");
        let options = BakeOptions {
            cameras: 162,
            resolution: 128,
            ..Default::default()
        };
        let bytes = Baker::new(gpu.clone())
            .bake_to_bytes(&mesh, &options, &Provenance::default(), &mut |_, _| {})
            .expect("bake");
        let asset = AssetFile::from_bytes(bytes).expect("baked asset opens");
        let renderer = Renderer::new(gpu.clone());
        let field = renderer.upload(&asset).expect("upload");
        let reference = ReferenceRenderer::new(gpu);
        let mesh = reference.upload(&mesh).expect("upload mesh");
        Ctx {
            renderer,
            reference,
            field,
            mesh,
            asset,
        }
    })
}

fn refined(view: &View, options: &RenderOptions, samples: u32) -> anyhow::Result<Frame> {
    let c = ctx();
    refine::refine(samples, |jitter| {
        Ok(c.renderer
            .render_jittered(&c.field, view, options, options, 0.0, jitter)?)
    })
}

fn orbit_views(count: usize, size: u32) -> Vec<View> {
    let frame = &ctx().asset.header().frame;
    lumigraph_core::view::random_orbit_views(frame.center, 2.5 * frame.radius, count, 7, 40.0, size)
}

#[test]
fn one_sample_is_the_plain_render() {
    let c = ctx();
    let options = RenderOptions::default();
    for view in orbit_views(2, 96) {
        let plain = c
            .renderer
            .render(&c.field, &view, &options)
            .expect("render");
        let zero = c
            .renderer
            .render_jittered(&c.field, &view, &options, &options, 0.0, [0.0, 0.0])
            .expect("render");
        assert_eq!(
            (zero.color, zero.depth),
            (plain.color.clone(), plain.depth.clone())
        );
        let one = refined(&view, &options, 1).expect("refine");
        assert_eq!((one.color, one.depth), (plain.color, plain.depth));
    }
    let view = &orbit_views(1, 32)[0];
    for bad in [[0.6, 0.0], [0.0, -0.51], [f32::NAN, 0.0]] {
        let out = c
            .renderer
            .render_jittered(&c.field, view, &options, &options, 0.0, bad);
        assert!(matches!(out, Err(RenderError::Option(_))), "{bad:?}");
    }
    let error = refined(view, &options, 0).expect_err("0 samples");
    assert_eq!(
        error.downcast_ref::<RefineError>(),
        Some(&RefineError::Samples(0))
    );
}

#[test]
fn jitter_moves_the_image_by_the_jitter() {
    // Jitter ±¼ pixel of a view samples the rays of the view twice as large through the same
    // image plane: pixel (i, j) at jitter (¼, −¼) is pixel (2i, 2j + 1) of the double view (its
    // centre 2j + 0.5 + 2·¼ and 2i + 0.5 − 2·¼), up to the marcher's error where surfaces meet
    // (within 1 % of z on all but 2 % of the pixels both cover).
    let c = ctx();
    let options = RenderOptions::default();
    let view = orbit_views(1, 64).remove(0);
    let double = View {
        width: 128,
        height: 128,
        ..view.clone()
    };
    let big = c
        .renderer
        .render(&c.field, &double, &options)
        .expect("render");
    let mut half = c
        .renderer
        .render_jittered(&c.field, &view, &options, &options, 0.0, [0.25, -0.25])
        .expect("render");
    let picked: Vec<f32> = (0..64)
        .flat_map(|i| (0..64).map(move |j| (i, j)))
        .map(|(i, j)| big.depth[2 * i * 128 + 2 * j + 1])
        .collect();
    let (mut both, mut off) = (0, 0);
    for (a, b) in half.depth.iter().zip(&picked) {
        if a.is_finite() && b.is_finite() {
            both += 1;
            off += usize::from((a - b).abs() > 0.01 * b);
        }
    }
    assert!(both > 500 && off * 50 <= both, "{off} of {both}");
    // And it is not the unshifted image.
    half.depth.iter_mut().for_each(|z| *z = z.min(1e30));
    let plain = c
        .renderer
        .render(&c.field, &view, &options)
        .expect("render");
    assert_ne!(
        half.depth,
        plain.depth.iter().map(|z| z.min(1e30)).collect::<Vec<_>>()
    );
}

#[test]
fn refined_stills_approach_the_supersampled_reference() {
    // Among a few orbit views, the one whose single-sample frame has the most wrong-surface
    // pixels (where tubes occlude each other); single-sample frames are measured against the
    // plain reference, refined ones against the 5×5 supersampled reference.
    let c = ctx();
    let options = RenderOptions::default();
    let shading = Shading::default();
    let mut worst: Option<(u64, View, Frame, Frame)> = None;
    for view in orbit_views(6, 160) {
        let single = c
            .renderer
            .render(&c.field, &view, &options)
            .expect("render");
        let truth = c
            .reference
            .render(&c.mesh, &view, &shading)
            .expect("reference");
        let wrong = metrics::compare(&single, &truth)
            .expect("compare")
            .wrong_surface_px;
        if worst.as_ref().is_none_or(|w| wrong > w.0) {
            worst = Some((wrong, view, single, truth));
        }
    }
    let (single_wrong, view, single, _) = worst.expect("views");
    assert!(
        single_wrong >= 10,
        "too few wrong-surface pixels to test: {single_wrong}"
    );
    let (supersampled, footprint) = c
        .reference
        .render_supersampled_footprint(&c.mesh, &view, &shading, 5)
        .expect("supersampled reference");
    assert_eq!(footprint.depth.len(), 25 * single.depth.len());
    let refined = refined(&view, &options, 16).expect("refine");
    let r = metrics::compare(&refined, &supersampled).expect("compare");
    let s = metrics::compare(&single, &supersampled).expect("compare");
    // A surface the pixel does not contain is a subset of a depth off from the centre's (the
    // supersampled depth is one of the footprint's samples).
    for (frame, centre) in [(&single, &s), (&refined, &r)] {
        let in_footprint =
            metrics::wrong_surface_footprint_px(&frame.depth, &supersampled.depth, &footprint)
                .expect("footprint");
        assert!(in_footprint <= centre.wrong_surface_px);
    }
    eprintln!(
        "wrong-surface px: single {single_wrong}, refined {}; SSIM vs supersampled: single {:.4}, refined {:.4}; PSNR {:.2} → {:.2} dB",
        r.wrong_surface_px, s.ssim, r.ssim, s.psnr, r.psnr
    );
    // Most wrong-surface pixels here are the marcher's own error at occlusion edges and grazing
    // silhouettes, shared by the jittered samples around them, so refinement must not add any
    // (docs/refine.md); it does not remove most of them either.
    assert!(
        r.wrong_surface_px <= single_wrong,
        "{} vs {single_wrong}",
        r.wrong_surface_px
    );
    assert!(r.ssim > s.ssim + 0.005, "{} vs {}", r.ssim, s.ssim);
    assert!(r.psnr > s.psnr, "{} vs {}", r.psnr, s.psnr);
}

#[test]
fn the_supersampled_reference_of_factor_one_is_the_reference() {
    let c = ctx();
    let shading = Shading::default();
    let view = orbit_views(1, 48).remove(0);
    let plain = c
        .reference
        .render(&c.mesh, &view, &shading)
        .expect("reference");
    let one = c
        .reference
        .render_supersampled(&c.mesh, &view, &shading, 1)
        .expect("reference");
    assert_eq!(
        (one.color, one.depth),
        (plain.color.clone(), plain.depth.clone())
    );
    assert!(
        c.reference
            .render_supersampled(&c.mesh, &view, &shading, 0)
            .is_err()
    );
    // Odd factors keep the centre sample: coverage may only change at the silhouette, and
    // depth wherever covered stays within 1 % of the plain reference's except at a few edges.
    let three = c
        .reference
        .render_supersampled(&c.mesh, &view, &shading, 3)
        .expect("reference");
    let cmp = metrics::compare(&three, &plain).expect("compare");
    assert!(cmp.wrong_surface_px * 100 <= cmp.intersection_px, "{cmp:?}");
    assert!(
        cmp.mask_mismatch_px <= metrics::silhouette_px(&plain),
        "{cmp:?}"
    );
}
