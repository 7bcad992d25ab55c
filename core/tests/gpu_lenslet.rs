//! Lenslet import (docs/two_plane.md, "Lenslet import"): a synthetic plenoptic image whose
//! views are known comes back view for view; the dev set's real light-field microscope image
//! (napari-LF's GUV example, with its dark and radiometry frames) is imported and refocused on
//! the GPU, where a focus measure against the focal depth has one clear maximum; missing or bad
//! calibrations and mismatched frames fail with clear errors.

mod common;

use std::path::Path;
use std::sync::Arc;

use lumigraph_core::asset::{AssetFile, Channel, ImageKey};
use lumigraph_core::gpu::Gpu;
use lumigraph_core::lenslet::{self, LensletCalibration};
use lumigraph_core::two_plane_render::{TwoPlaneOptions, TwoPlaneRenderer};
use lumigraph_core::view::View;

fn gpu() -> Arc<Gpu> {
    Gpu::shared().expect("a GPU adapter (install mesa-vulkan-drivers)")
}

fn write_grey16(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> f64) {
    let pixels: Vec<u16> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| (f(x, y).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    let image =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, pixels).expect("image");
    image.save(path).expect("save");
}

/// The lenslet images of a synthetic camera: pitch 10 px (a whole number, so that view
/// sampling lands on pixel centres), lenslet (n1, n2) centred at (10·n1 + 4.5, 10·n2 + 4.5);
/// the pixel at offset (du, dv) ∈ {−4.5 … 4.5} of a lenslet is view (du + 4.5, dv + 4.5)
/// seeing scene value `scene(n1, n2, view)`. The radiometry is flat inside each cell but a dark
/// one-pixel border (the lattice), the dark frame a constant 0.02.
const PITCH: u32 = 10;

fn scene(n1: u32, n2: u32, a: u32, b: u32) -> f64 {
    0.1 + 0.4 * f64::from((n1 * 7 + n2 * 3) % 11) / 10.0 + 0.02 * f64::from(a + 2 * b) / 3.0
}

fn synthetic(dir: &Path, lenslets: u32) {
    let side = PITCH * lenslets;
    let cell = |x: u32, y: u32| (x / PITCH, y / PITCH, x % PITCH, y % PITCH);
    let border = |u: u32, v: u32| u == 0 || v == 0 || u == PITCH - 1 || v == PITCH - 1;
    write_grey16(&dir.join("raw.tif"), side, side, |x, y| {
        let (n1, n2, u, v) = cell(x, y);
        // The raw value is the scene value × the radiometry, plus the dark level.
        let radiometry = if border(u, v) { 0.05 } else { 0.8 };
        0.02 + radiometry * scene(n1, n2, u, v)
    });
    write_grey16(&dir.join("radiometry.tif"), side, side, |x, y| {
        let (_, _, u, v) = cell(x, y);
        0.02 + if border(u, v) { 0.05 } else { 0.8 }
    });
    write_grey16(&dir.join("dark.tif"), side, side, |_, _| 0.02);
    let calibration = LensletCalibration {
        image: "raw.tif".into(),
        radiometry: "radiometry.tif".into(),
        dark: Some("dark.tif".into()),
        pitch_um: 65.0,
        pixel_size_um: 6.5,
        magnification: 20.0,
        na: 0.5,
        medium_index: 1.0,
    };
    std::fs::write(
        dir.join("lenslet.json"),
        serde_json::to_vec(&calibration).expect("json"),
    )
    .expect("write");
}

/// The lattice of the synthetic camera is found to 0.01 px; the lenslets whose cell lies
/// wholly on the sensor are imported (the outer ring is cut), 10 × 10 views each; every view's
/// texel is the devignetted scene value up to the 8-bit scale (1.5 codes: the 16-bit input
/// quantization, the division and the rounding), and border samples (radiometry under 10 %) are
/// empty; the planes follow the calibration.
#[test]
fn a_synthetic_plenoptic_image_comes_back_view_for_view() {
    let dir = tempfile::tempdir().expect("dir");
    synthetic(dir.path(), 16);
    let out = dir.path().join("lf.lfa");
    let report = lenslet::import_lenslet(dir.path(), &out, &mut |_, _| {}).expect("import");
    let [p1, p2] = report.grid.pitch();
    assert!(
        (p1 - 10.0).abs() < 0.01 && (p2 - 10.0).abs() < 0.01,
        "{p1} {p2}"
    );
    assert!(report.grid.rotation_deg().abs() < 0.01);
    assert_eq!(report.views, 10);
    assert_eq!(
        report.lenslets,
        [14, 14],
        "the cells cut by the border are left out"
    );
    let asset = AssetFile::open(&out).expect("open");
    let planes = *asset.header().two_plane().expect("two-plane");
    assert_eq!(planes.uv.grid, [10, 10]);
    assert_eq!(planes.st.resolution, [14, 14]);
    // 65 µm / 20 per texel; uv 100 st widths away, 2·D·NA/n wide.
    assert!((planes.st.size[0] - 14.0 * 3.25).abs() < 1e-9);
    assert!((planes.uv.center[2] - 100.0 * 14.0 * 3.25).abs() < 1e-6);
    assert!((planes.uv.size[0] - 2.0 * planes.uv.center[2] * 0.5).abs() < 1e-6);
    assert!(!lumigraph_core::two_plane::has_captured_depth(
        asset.header()
    ));
    // Texel (0, 0) is the lenslet centred at (10·n1 + 4.5, 10·n2 + 4.5).
    let [x0, y0] = report.first_lenslet;
    let cell0 = [((x0 - 4.5) / 10.0).round(), ((y0 - 4.5) / 10.0).round()];
    assert!((x0 - (10.0 * cell0[0] + 4.5)).abs() < 0.05, "{x0}");
    assert!((y0 - (10.0 * cell0[1] + 4.5)).abs() < 0.05, "{y0}");
    assert_eq!(cell0, [1.0, 1.0], "the first whole cell");
    let cell0 = [1u32, 1u32];
    let (mut checked, mut worst) = (0, 0.0f64);
    for b in 1..9u32 {
        for a in 1..9u32 {
            let bytes = asset
                .read_image(ImageKey::new(0, 0, b * 10 + a, Channel::Color))
                .expect("view");
            for t in 0..14u32 {
                for s in 0..14u32 {
                    let p = 4 * (t * 14 + s) as usize;
                    let got = f64::from(bytes[p]);
                    let want = 255.0
                        * (scene(cell0[0] + s, cell0[1] + t, a, b) / f64::from(report.scale))
                            .min(1.0);
                    worst = worst.max((got - want).abs());
                    assert_eq!(bytes[p + 3], 255);
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, 64 * 196);
    assert!(worst <= 1.5, "worst {worst} codes");
    // View (0, 0) samples the dark border of every cell: empty.
    let corner = asset
        .read_image(ImageKey::new(0, 0, 0, Channel::Color))
        .expect("view");
    assert!(corner.chunks_exact(4).all(|p| p == [0, 0, 0, 0]));
}

/// The dev set's light-field microscope image: the lattice is found at the nominal pitch (100
/// µm lenslets on 6.5 µm pixels: 15.38 px) within 0.3 %, nearly unrotated, with 15 × 15 views
/// of 26 × 26 lenslets. Refocused with the full aperture (R = 7 cells, 16 stratified draws
/// averaged) from −12 to +12 µm, the normalised gradient energy of the vesicle's image rises
/// to one maximum and falls (every step away from it lower), the maximum at least 4× the
/// sweep's ends and inside it.
#[test]
fn the_real_lenslet_image_refocuses_with_one_clear_maximum() {
    let dir = common::fixtures_dir().join("lightfield/GUVExperim1");
    let out_dir = tempfile::tempdir().expect("dir");
    let out = out_dir.path().join("guv.lfa");
    let report = lenslet::import_lenslet(&dir, &out, &mut |_, _| {}).expect("import");
    for p in report.grid.pitch() {
        assert!((p / (100.0 / 6.5) - 1.0).abs() < 0.003, "pitch {p}");
    }
    assert!(report.grid.rotation_deg().abs() < 0.5);
    assert_eq!(report.views, 15);
    assert_eq!(report.lenslets, [26, 26]);
    assert!(report.valid_fraction > 0.9, "{}", report.valid_fraction);

    let asset = AssetFile::open(&out).expect("open");
    let renderer = TwoPlaneRenderer::new(gpu());
    let field = renderer.upload(&asset).expect("upload");
    let planes = field.planes;
    let st = planes.st.size[0];
    let distance = planes.uv.center[2];
    // The st square fills the frame from 1.5 plane separations away.
    let yfov = 2.0 * (0.45 * st / (1.5 * distance)).atan().to_degrees();
    let view = View {
        eye: [0.0, 0.0, 1.5 * distance],
        target: [0.0; 3],
        up: [0.0, 1.0, 0.0],
        yfov_deg: yfov,
        width: 160,
        height: 160,
    };
    let focuses: Vec<f64> = (-6..=6).map(|i| 2.0 * f64::from(i)).collect();
    let energy: Vec<f64> = focuses
        .iter()
        .map(|&focus| {
            let options = TwoPlaneOptions {
                focus,
                aperture: 7.0,
                ..TwoPlaneOptions::default()
            };
            let frame = renderer
                .render_accumulated(&field, &view, &options, 16)
                .expect("render");
            gradient_energy(&frame)
        })
        .collect();
    let (peak, max) = energy
        .iter()
        .enumerate()
        .fold((0, 0.0), |b, (i, &e)| if e > b.1 { (i, e) } else { b });
    assert!(
        peak > 0 && peak + 1 < energy.len(),
        "maximum at an end: {energy:?}"
    );
    for i in 0..energy.len() - 1 {
        if i < peak {
            assert!(
                energy[i] < energy[i + 1],
                "not rising before the peak: {energy:?}"
            );
        } else {
            assert!(
                energy[i] > energy[i + 1],
                "not falling after the peak: {energy:?}"
            );
        }
    }
    assert!(
        max > 4.0 * energy[0] && max > 4.0 * energy[energy.len() - 1],
        "{energy:?}"
    );
}

/// Mean squared central-difference gradient of the grey image over the covered pixels whose
/// neighbours are covered, over the squared mean grey (independent of brightness).
fn gradient_energy(frame: &lumigraph_core::frame::Frame) -> f64 {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let grey = |x: usize, y: usize| {
        let p = 4 * (y * w + x);
        (0..3).map(|k| f64::from(frame.color[p + k])).sum::<f64>() / 3.0
    };
    let covered = |x: usize, y: usize| frame.color[4 * (y * w + x) + 3] > 0;
    let (mut sum, mut mean, mut n) = (0.0, 0.0, 0usize);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if !(covered(x - 1, y) && covered(x + 1, y) && covered(x, y - 1) && covered(x, y + 1)) {
                continue;
            }
            let gx = grey(x + 1, y) - grey(x - 1, y);
            let gy = grey(x, y + 1) - grey(x, y - 1);
            sum += gx * gx + gy * gy;
            mean += grey(x, y);
            n += 1;
        }
    }
    assert!(n > w * h / 2, "{n} covered pixels");
    let mean = mean / n as f64;
    sum / n as f64 / (mean * mean)
}

#[test]
fn missing_or_bad_calibrations_and_frames_fail_clearly() {
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("x.lfa");
    let run = |source: &Path| {
        lenslet::import_lenslet(source, &out, &mut |_, _| {})
            .expect_err("fails")
            .to_string()
    };
    // No calibration at all.
    std::fs::create_dir(dir.path().join("bare")).expect("dir");
    write_grey16(&dir.path().join("bare/raw.tif"), 40, 40, |_, _| 0.5);
    let err = run(&dir.path().join("bare/raw.tif"));
    assert!(
        err.contains("needs its calibration") && err.contains("lenslet.json"),
        "{err}"
    );
    // A calibration with a bad value, an unknown key, a pitch of under 3 px.
    synthetic(dir.path(), 8);
    let json = std::fs::read_to_string(dir.path().join("lenslet.json")).expect("read");
    for (from, to, needle) in [
        ("\"na\":0.5", "\"na\":1.5", "below the medium index"),
        ("\"na\":0.5", "\"na\":0.5,\"focal\":3", "unknown field"),
        ("\"pitch_um\":65.0", "\"pitch_um\":13.0", "3 to 256 pixels"),
        (
            "\"magnification\":20.0",
            "\"magnification\":-1",
            "magnification",
        ),
    ] {
        assert!(json.contains(from), "{json}");
        std::fs::write(dir.path().join("lenslet.json"), json.replace(from, to)).expect("write");
        let err = run(dir.path());
        assert!(err.contains(needle), "{to}: {err}");
    }
    std::fs::write(dir.path().join("lenslet.json"), &json).expect("write");
    // A wrong nominal pitch finds no grid; a radiometry frame of another size; a missing dark.
    std::fs::write(
        dir.path().join("lenslet.json"),
        json.replace("\"pitch_um\":65.0", "\"pitch_um\":45.5"),
    )
    .expect("write");
    assert!(run(dir.path()).contains("no lenslet grid"));
    std::fs::write(dir.path().join("lenslet.json"), &json).expect("write");
    write_grey16(&dir.path().join("dark.tif"), 30, 30, |_, _| 0.0);
    let err = run(dir.path());
    assert!(err.contains("dark.tif") && err.contains("30 x 30"), "{err}");
    std::fs::remove_file(dir.path().join("dark.tif")).expect("remove");
    assert!(run(dir.path()).contains("dark.tif"));
    // A file that is not an image.
    std::fs::write(dir.path().join("radiometry.tif"), b"not a tiff").expect("write");
    assert!(run(dir.path()).contains("radiometry.tif"));
    assert!(!out.exists(), "a failed import leaves no file");
}
