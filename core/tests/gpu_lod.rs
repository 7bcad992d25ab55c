//! Automatic LOD on the GPU: the calibration's silhouette error predicts
//! what a render measures against the mesh, and a level switch cross-fades instead of popping.

use std::sync::{Arc, OnceLock};

use lumigraph_core::asset::{AssetFile, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker};
use lumigraph_core::calibration::{Calibration, CalibrationPoint};
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::lod::{Ladder, LodPolicy};
use lumigraph_core::mesh::{Mesh, demo_mesh};
use lumigraph_core::metrics;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer};
use lumigraph_core::scene::{Scene, Transform};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::View;

struct Ctx {
    renderer: Renderer,
    reference: ReferenceRenderer,
    mesh: Mesh,
    asset: AssetFile,
    /// The encoded asset (for scene files).
    bytes: Vec<u8>,
    calibration: Calibration,
}

/// The demo baked with 42 cameras at 64 px and calibrated (as `lumigraph bake` does).
fn ctx() -> &'static Ctx {
    static CTX: OnceLock<Ctx> = OnceLock::new();
    CTX.get_or_init(|| {
        let gpu: Arc<Gpu> = Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)");
        let baker = Baker::new(gpu.clone());
        let renderer = Renderer::new(gpu.clone());
        let reference = ReferenceRenderer::new(gpu);
        let mesh = demo_mesh().expect("demo");
        let options = BakeOptions {
            cameras: 42,
            resolution: 64,
            ..Default::default()
        };
        let baked = lumigraph_core::calibration::bake_calibrated(
            &baker,
            &renderer,
            &reference,
            &mesh,
            &options,
            &Provenance::default(),
            &mut |_, _| {},
        )
        .expect("calibrated bake");
        let bytes = baked.bytes.clone();
        let asset = AssetFile::from_bytes(baked.bytes).expect("asset");
        let stored = Calibration::from_quality(asset.header().quality.as_ref())
            .expect("readable")
            .expect("stored");
        // Stored as JSON in the header: equal up to float printing (last-digit rounding).
        assert_eq!(stored.points.len(), baked.calibration.points.len());
        for (a, b) in stored.points.iter().zip(&baked.calibration.points) {
            let (ea, eb) = (
                a.silhouette_error.expect("a"),
                b.silhouette_error.expect("b"),
            );
            assert!((ea - eb).abs() <= 1e-12 * eb, "{ea} vs {eb}");
        }
        Ctx {
            renderer,
            reference,
            mesh,
            asset,
            bytes,
            calibration: baked.calibration,
        }
    })
}

/// A view of the asset whose bounding sphere projects to `px` pixels across in a `size²` frame.
fn view_at(asset: &AssetFile, px: f64, size: u32, azimuth: f64) -> View {
    let frame = &asset.header().frame;
    let (c, r) = (frame.center, frame.radius);
    let f = f64::from(size) / 2.0 / 20f64.to_radians().tan();
    let d = r * (1.0 + (2.0 * f / px).powi(2)).sqrt();
    let dir = [azimuth.cos() * 0.8, 0.45, azimuth.sin() * 0.8];
    let n = dir.iter().map(|x| x * x).sum::<f64>().sqrt();
    View::look_at(
        [
            c[0] + d * dir[0] / n,
            c[1] + d * dir[1] / n,
            c[2] + d * dir[2] / n,
        ],
        c,
        40.0,
        size,
        size,
    )
}

#[test]
fn calibration_silhouette_error_predicts_the_measured_one() {
    let ctx = ctx();
    let points = &ctx.calibration.points;
    assert_eq!(points.len(), 2 * 4, "12 and 42 cameras × 4 steps");
    for p in points {
        let e = p.silhouette_error.expect("measured");
        // Bounding diameters: the silhouette moves by well under a tenth of the object.
        assert!(e.is_finite() && e > 0.0 && e < 0.1, "{p:?}");
    }
    let field = ctx.renderer.upload(&ctx.asset).expect("upload");
    let gpu_mesh = ctx.reference.upload(&ctx.mesh).expect("mesh");
    let ladder = Ladder::new(
        &ctx.calibration,
        &LodPolicy::default(),
        42,
        &RenderOptions::default(),
    )
    .expect("ladder");
    // Three sizes × three views: the mean measured silhouette error (pixels covered in one
    // mask only over the reference silhouette's length) against the mean prediction. The
    // calibration used 4 other views at 256², so per-view scatter is large; the mean must agree
    // within half the prediction plus 0.3 px (sub-pixel rounding of a point-sampled silhouette).
    for px in [40.0, 80.0, 140.0] {
        let (mut predicted, mut measured) = (0.0, 0.0);
        for k in 0..3 {
            let view = view_at(&ctx.asset, px, 160, 0.4 + 2.1 * f64::from(k));
            let (frame, decision) = ladder
                .render_auto(&ctx.renderer, &field, &view)
                .expect("render");
            assert!((decision.projected_px - px).abs() < 1e-6 * px);
            let truth = ctx
                .reference
                .render(&gpu_mesh, &view, &Shading::default())
                .expect("reference");
            let c = metrics::compare(&frame, &truth).expect("compare");
            predicted += decision.error_px / 3.0;
            measured +=
                c.mask_mismatch_px as f64 / metrics::silhouette_px(&truth).max(1) as f64 / 3.0;
        }
        eprintln!("{px} px: predicted {predicted:.3} px, measured {measured:.3} px");
        assert!(
            (measured - predicted).abs() <= 0.5 * predicted + 0.3,
            "{px} px: predicted {predicted:.3} px, measured {measured:.3} px"
        );
    }
}

/// Mean absolute RGB difference per pixel (0–255).
fn mean_diff(a: &Frame, b: &Frame) -> f64 {
    let sum: u64 = a
        .color
        .chunks_exact(4)
        .zip(b.color.chunks_exact(4))
        .map(|(x, y)| (0..3).map(|c| u64::from(x[c].abs_diff(y[c]))).sum::<u64>())
        .sum();
    sum as f64 / (3 * a.pixel_count()) as f64
}

#[test]
fn level_switches_cross_fade_instead_of_popping() {
    let ctx = ctx();
    let field = ctx.renderer.upload(&ctx.asset).expect("upload");
    // Two levels far apart, switching at 100 px: 12 cameras with step 1/8 up to 100 px, then
    // 42 cameras with step 1/32.
    let point = |cameras, step, e, ms| CalibrationPoint {
        cameras,
        step,
        ms_per_mpx: ms,
        masked_psnr: 25.0,
        depth_median_r: 1e-3,
        silhouette_error: Some(e),
    };
    let calibration = Calibration {
        points: vec![
            point(12, 1.0 / 8.0, 0.01, 600.0),
            point(42, 1.0 / 32.0, 0.002, 1000.0),
        ],
        ..ctx.calibration.clone()
    };
    // One fixed view; the projected size given to the ladder sweeps 80 → 101 px in 1 % steps,
    // so every difference between frames comes from the level, none from motion.
    let view = view_at(&ctx.asset, 100.0, 128, 0.7);
    let sizes: Vec<f64> = (0..=25)
        .map(|k| 80.0 * 1.01_f64.powi(k))
        .filter(|&p| p < 101.0)
        .collect();
    let sweep = |band: f64| -> (Vec<Frame>, usize) {
        let ladder = Ladder::new(
            &calibration,
            &LodPolicy {
                blend_band: band,
                ..LodPolicy::default()
            },
            42,
            &RenderOptions::default(),
        )
        .expect("ladder");
        let mut blended = 0;
        let frames = sizes
            .iter()
            .map(|&px| {
                let d = ladder.decide(px);
                blended += usize::from(d.blend.is_some());
                ladder
                    .render(&ctx.renderer, &field, &view, &d)
                    .expect("render")
            })
            .collect();
        (frames, blended)
    };
    let (hard, hard_blended) = sweep(0.0);
    let (soft, soft_blended) = sweep(0.15);
    assert_eq!(hard_blended, 0);
    assert!(soft_blended >= 10, "{soft_blended} blended sizes");
    let level_gap = mean_diff(&hard[0], &hard[hard.len() - 1]);
    // The two levels differ visibly (else this test could not fail).
    assert!(level_gap > 0.5, "levels differ by {level_gap}");
    let max_step = |frames: &[Frame]| {
        frames
            .windows(2)
            .map(|w| mean_diff(&w[0], &w[1]))
            .fold(0.0, f64::max)
    };
    let (hard_jump, soft_jump) = (max_step(&hard), max_step(&soft));
    eprintln!(
        "levels differ by {level_gap:.3}; largest step: hard {hard_jump:.3}, soft {soft_jump:.3}"
    );
    // A hard switch changes the whole difference in one step.
    assert!(hard_jump > 0.9 * level_gap, "{hard_jump} vs {level_gap}");
    // The dissolve spreads it over the band: smoothstep's steepest 1 % step over a 15 % band
    // moves the weight by about 1.5 × 0.01 / 0.13 ≈ 0.12, and the ordered dither switches that
    // share of the pixels (in sixteenths, so up to 2/16 per step); 0.25 leaves room.
    assert!(soft_jump < 0.25 * level_gap, "{soft_jump} vs {level_gap}");
    // Both ends agree with the pure levels.
    assert_eq!(soft[0].color, hard[0].color);
    assert_eq!(soft[soft.len() - 1].color, hard[hard.len() - 1].color);
    // And the projection helper agrees with the view's own geometry.
    let basis = view.basis(4096).expect("view");
    let px = basis.projected_diameter_px(field.center, field.radius);
    assert!((px - 100.0).abs() < 1e-6, "{px}");
}

#[test]
fn scene_instances_choose_their_own_level() {
    let ctx = ctx();
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("cal.lfa"), &ctx.bytes).expect("write");
    let field = ctx.renderer.upload(&ctx.asset).expect("upload");
    let frame = &ctx.asset.header().frame;
    let (c, r) = (frame.center, frame.radius);
    // A near instance at the asset's place and a far one 40 radii behind it.
    let far_shift = [0.0, 0.0, -40.0 * r];
    let view = View::look_at([c[0], c[1], c[2] + 3.0 * r], c, 40.0, 128, 128);
    let transforms = [
        Transform::default(),
        Transform {
            translation: far_shift,
            ..Transform::default()
        },
    ];
    let ladder = Ladder::new(
        &ctx.calibration,
        &LodPolicy {
            blend_band: 0.0,
            ..LodPolicy::default()
        },
        42,
        &RenderOptions::default(),
    )
    .expect("ladder");
    let decisions: Vec<_> = transforms
        .iter()
        .map(|t| {
            let local = t.similarity().expect("similarity").view_to_local(&view);
            ladder.decide_view(&field, &local).expect("decide")
        })
        .collect();
    assert!(decisions[0].projected_px > 10.0 * decisions[1].projected_px);
    // The far instance, small on screen, takes a level at least as coarse.
    assert!(decisions[1].level.silhouette_error >= decisions[0].level.silhouette_error);
    let object = |t: [f64; 3], extra: &str| {
        format!(
            r#"{{"type": "lightfield", "asset": "cal.lfa", "transform": {{"translation": [{}, {}, {}]}}, {extra}}}"#,
            t[0], t[1], t[2]
        )
    };
    let auto = r#""auto_lod": {"blend_band": 0}"#;
    let scene_auto = format!(
        r#"{{"objects": [{}, {}]}}"#,
        object([0.0; 3], auto),
        object(far_shift, auto)
    );
    let pinned = |d: &lumigraph_core::lod::LodDecision| {
        format!(
            r#""options": {{"lod": {}, "step": {}}}"#,
            d.level.cameras, d.level.step
        )
    };
    let scene_pinned = format!(
        r#"{{"objects": [{}, {}]}}"#,
        object([0.0; 3], &pinned(&decisions[0])),
        object(far_shift, &pinned(&decisions[1]))
    );
    let render = |json: &str| {
        Scene::from_json(json, dir.path(), &ctx.renderer, &ctx.reference)
            .expect("scene")
            .render(&ctx.renderer, &ctx.reference, &view)
            .expect("render")
    };
    let (a, b) = (render(&scene_auto), render(&scene_pinned));
    assert!(a.covered_count() > 100);
    assert_eq!(a.color, b.color);
    assert_eq!(a.depth, b.depth);
    // Bad policies name the object.
    let bad = format!(
        r#"{{"objects": [{}]}}"#,
        object([0.0; 3], r#""auto_lod": {"max_error_px": -1}"#)
    );
    let err = Scene::from_json(&bad, dir.path(), &ctx.renderer, &ctx.reference)
        .err()
        .expect("refused");
    assert!(err.to_string().contains("object 0"), "{err}");
    assert!(err.to_string().contains("max_error_px"), "{err}");
}

#[test]
fn blended_render_dithers_between_two_settings_in_one_pass() {
    let ctx = ctx();
    let field = ctx.renderer.upload(&ctx.asset).expect("upload");
    let view = view_at(&ctx.asset, 100.0, 96, 1.9);
    // Unguided, so that each pixel's march depends on its own setting only and the blend can be
    // checked bit for bit (a guided blend bounds marches by a coarse pass of mixed settings).
    let a = RenderOptions {
        lod: Some(12),
        step: Some(1.0 / 8.0),
        guide: Some(0),
        ..RenderOptions::default()
    };
    let b = RenderOptions {
        lod: Some(42),
        step: Some(1.0 / 32.0),
        guide: Some(0),
        ..RenderOptions::default()
    };
    let r = &ctx.renderer;
    let fa = r.render(&field, &view, &a).expect("a");
    let fb = r.render(&field, &view, &b).expect("b");
    let blend = |w: f32| r.render_blend(&field, &view, &a, &b, w).expect("blend");
    // Weights 0 and 1 are the plain renders, bit for bit.
    let (b0, b1) = (blend(0.0), blend(1.0));
    assert_eq!((&b0.color, &b0.depth), (&fa.color, &fa.depth));
    assert_eq!((&b1.color, &b1.depth), (&fb.color, &fb.depth));
    // In between, every pixel is exactly a's or b's, and b's pixels follow the 4×4 ordered
    // dither: rank (x ^ y, y interleaved and bit-reversed) + ½ below 16·w.
    let bayer = |x: usize, y: usize| {
        let (p, q) = ((x ^ y) & 3, y & 3);
        ((p & 1) << 3) | ((q & 1) << 2) | (((p >> 1) & 1) << 1) | ((q >> 1) & 1)
    };
    for w in [0.25_f32, 0.5, 0.8] {
        let f = blend(w);
        let width = f.width as usize;
        let mut from_b = 0;
        let mut differing = 0_usize;
        for k in 0..f.depth.len() {
            let use_b = (bayer(k % width, k / width) as f32 + 0.5) / 16.0 < w;
            let src = if use_b { &fb } else { &fa };
            assert_eq!(
                f.color[4 * k..4 * k + 4],
                src.color[4 * k..4 * k + 4],
                "pixel {k}"
            );
            assert_eq!(f.depth[k].to_bits(), src.depth[k].to_bits(), "pixel {k}");
            if fa.color[4 * k..4 * k + 4] != fb.color[4 * k..4 * k + 4] {
                differing += 1;
                from_b += usize::from(use_b);
            }
        }
        let share = from_b as f64 / differing.max(1) as f64;
        assert!(differing > 50, "{differing}");
        assert!((share - f64::from(w)).abs() < 0.15, "w {w}: share {share}");
    }
    for bad in [-0.1, 1.5, f32::NAN] {
        let err = r
            .render_blend(&field, &view, &a, &b, bad)
            .expect_err("refused");
        assert!(err.to_string().contains("blend weight"), "{err}");
    }
}
