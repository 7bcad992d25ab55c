//! The paged two-plane renderer (`page_cache`): frames through a cache equal the fully resident
//! ones bit for bit wherever no page is missing; the fully resident paged frames match the
//! resident renderer; the predictive policy faults less than LRU on a fast trace; bad budgets
//! and corrupt pages are refused.

use std::sync::Arc;

use lumigraph_core::asset::{AssetFile, AssetHeader, Channel, ImageKey, Provenance, encode_asset};
use lumigraph_core::page_cache::{CacheConfig, PageSummary, PagedTwoPlane, Prefetch, needed_pages};
use lumigraph_core::render::RenderError;
use lumigraph_core::two_plane::TwoPlanes;
use lumigraph_core::two_plane_render::{TwoPlaneOptions, TwoPlaneRenderer, UvFilter};
use lumigraph_core::view::View;

mod common;

use common::{gpu, small_planes as planes, square_view as view};

/// A light field on [`common::small_planes`] (5×4 cameras of 64×48 texels) in pages of 16: 12
/// pages per camera, 240 in all. Smooth colours that differ per camera, a few empty texels, and
/// a checkerboard of two depths (surfaces at two heights: the depth-corrected filter marches
/// between them).
fn asset_bytes(planes: &TwoPlanes) -> Vec<u8> {
    let header =
        AssetHeader::new_two_plane(*planes, 16, Provenance::default()).expect("a valid header");
    let [nu, nv] = planes.uv.grid;
    let [ns, nt] = planes.st.resolution;
    let mut images = Vec::new();
    for b in 0..nv {
        for a in 0..nu {
            let mut c = Vec::new();
            let mut d = Vec::new();
            for i in 0..nt {
                for j in 0..ns {
                    let (af, bf, fi, fj) = (f64::from(a), f64::from(b), f64::from(i), f64::from(j));
                    let hit = (i + 3 * j + a) % 29 != 0;
                    let px = [
                        (128.0 + 100.0 * (0.2 * fj + 0.7 * af).sin()).round() as u8,
                        (128.0 + 100.0 * (0.15 * fi - 0.5 * bf).cos()).round() as u8,
                        (40.0 + 30.0 * af + 20.0 * bf).round() as u8,
                        255,
                    ];
                    c.extend_from_slice(&if hit { px } else { [0; 4] });
                    let depth = if !hit {
                        f32::INFINITY
                    } else if (i / 8 + j / 8) % 2 == 0 {
                        0.55
                    } else {
                        0.7
                    };
                    d.extend_from_slice(&depth.to_le_bytes());
                }
            }
            let camera = b * nu + a;
            images.push((ImageKey::new(0, 0, camera, Channel::Color), c));
            images.push((ImageKey::new(0, 0, camera, Channel::Depth), d));
        }
    }
    encode_asset(header, images).expect("encode")
}

fn asset(planes: &TwoPlanes) -> Arc<AssetFile> {
    Arc::new(AssetFile::from_bytes(asset_bytes(planes)).expect("read back"))
}

/// Checks `frame` against `reference` bit for bit (colour and depth) at every pixel `stats` does
/// not mark degraded or overview; returns how many pixels were compared and how many were not.
fn exact_where_not_degraded(
    frame: &lumigraph_core::frame::Frame,
    reference: &lumigraph_core::frame::Frame,
    stats: &lumigraph_core::page_cache::PageFrameStats,
    what: &str,
) -> (usize, usize) {
    let (mut exact, mut degraded) = (0, 0);
    for p in 0..frame.pixel_count() {
        if stats.degraded_mask[p] || stats.overview_mask[p] {
            degraded += 1;
            continue;
        }
        exact += 1;
        assert_eq!(
            (&frame.color[4 * p..4 * p + 4], frame.depth[p].to_bits()),
            (
                &reference.color[4 * p..4 * p + 4],
                reference.depth[p].to_bits()
            ),
            "{what}: pixel {p}"
        );
    }
    (exact, degraded)
}

/// A renderer, the fully resident cache of [`asset`] (the reference) and a cache of
/// `budget_kib` KiB with `prefetch` loading at most `pages_per_frame` pages a frame.
fn whole_and_cached(
    budget_kib: u64,
    prefetch: Prefetch,
    pages_per_frame: u32,
) -> (TwoPlaneRenderer, PagedTwoPlane, PagedTwoPlane) {
    let asset = asset(&planes());
    let renderer = TwoPlaneRenderer::new(gpu());
    let whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    let config = CacheConfig {
        budget_bytes: Some(budget_kib * 1024),
        prefetch,
        pages_per_frame,
        overview: false,
    };
    let cached = PagedTwoPlane::open(&renderer, asset, config).expect("open cache");
    (renderer, whole, cached)
}

/// Every mode: the four uv filters and a refocused aperture.
fn modes() -> Vec<TwoPlaneOptions> {
    let mut out: Vec<TwoPlaneOptions> = UvFilter::ALL
        .into_iter()
        .map(|uv_filter| TwoPlaneOptions {
            uv_filter,
            ..TwoPlaneOptions::default()
        })
        .collect();
    out.push(TwoPlaneOptions {
        focus: 0.4,
        aperture: 1.0,
        ..TwoPlaneOptions::default()
    });
    out
}

/// A pan: the eye moves across the uv plane at `speed` world units per frame, looking at a
/// quarter of the st plane in front of it.
fn pan(frames: usize, speed: f64, size: u32) -> Vec<View> {
    (0..frames)
        .map(|k| {
            let x = -0.45 + speed * k as f64;
            view([x, 0.1, 2.6], [1.6 * x, 0.0, 0.0], 16.0, size)
        })
        .collect()
}

/// The fully resident paged renderer against the resident one: colour within 2 codes and the
/// same coverage on 99 % of the pixels (the resident sampler's bilinear weights are 8-bit fixed
/// point on lavapipe, the paged renderer's are f32), and no frame degraded or loading pages.
#[test]
fn fully_resident_paged_frames_match_the_resident_renderer() {
    let planes = planes();
    let asset = asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let resident = renderer.upload(&asset).expect("upload");
    let mut whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    assert_eq!(whole.resident_pages(), whole.grid.total());
    assert_eq!(whole.depth_range, resident.depth_range);
    for options in modes() {
        for v in [
            view([0.05, -0.1, 3.0], [0.1, 0.0, 0.0], 40.0, 48),
            view([-0.3, 0.2, 2.4], [-0.2, 0.1, 0.0], 30.0, 48),
        ] {
            let (paged, stats) = whole.render(&renderer, &v, &options).expect("paged");
            assert_eq!(
                (stats.degraded_px, stats.pages_loaded, stats.faults > 0),
                (0, 0, false)
            );
            let plain = renderer.render(&resident, &v, &options).expect("resident");
            let mut off = 0;
            for (p, q) in paged.color.chunks_exact(4).zip(plain.color.chunks_exact(4)) {
                let close = p.iter().zip(q).all(|(x, y)| x.abs_diff(*y) <= 2);
                if !close || (p[3] == 0) != (q[3] == 0) {
                    off += 1;
                }
            }
            assert!(
                off * 100 <= paged.pixel_count(),
                "{options:?}: {off} of {} pixels differ",
                paged.pixel_count()
            );
            assert!(
                stats.pages_touched > 0 && stats.projection_missed == 0,
                "{stats:?}"
            );
        }
    }
}

/// A cache of a quarter of the pages, loading 6 per frame: on a pan, every pixel the shader did
/// not flag as degraded equals the fully resident frame's bit for bit (colour and depth), some
/// pixels are degraded and many are not (the comparison is not vacuous), and the projection predicts every page
/// a frame touches.
#[test]
fn frames_through_a_small_cache_equal_resident_frames_wherever_no_page_is_missing() {
    let planes = planes();
    let asset = asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let mut whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    let views = pan(8, 0.12, 40);
    for policy in Prefetch::ALL {
        let mut degraded = 0;
        let mut exact = 0;
        for options in modes() {
            let config = CacheConfig {
                budget_bytes: Some(128 * 1024),
                prefetch: policy,
                pages_per_frame: 6,
                overview: false,
            };
            let mut cached =
                PagedTwoPlane::open(&renderer, Arc::clone(&asset), config).expect("open cache");
            assert!(
                cached.slots * 4 <= cached.grid.total() + 4,
                "{} slots",
                cached.slots
            );
            assert!(
                cached.bytes <= 128 * 1024 + 16 * 16 * 8 * 4,
                "{} bytes",
                cached.bytes
            );
            for v in &views {
                let (reference, _) = whole.render(&renderer, v, &options).expect("whole");
                let (frame, stats) = cached.render(&renderer, v, &options).expect("cached");
                assert!(stats.pages_loaded <= 6);
                assert_eq!(
                    stats.degraded_mask.iter().filter(|&&d| d).count() as u64,
                    stats.degraded_px
                );
                let (e, d) = exact_where_not_degraded(
                    &frame,
                    &reference,
                    &stats,
                    &format!("{policy} {options:?}"),
                );
                exact += e;
                degraded += d;
            }
        }
        assert!(
            degraded > 1000 && exact > 1000,
            "{policy}: {degraded} degraded, {exact} exact"
        );
    }
}

/// A wide aperture accumulated over several stratified draws (what a view at rest shows, and
/// what `serve` renders for `refine`) through a small cache: equal to the fully resident
/// accumulation bit for bit wherever no draw was degraded, and the merged stats count every
/// draw's loads.
#[test]
fn accumulated_apertures_through_a_cache_equal_resident_ones_where_not_degraded() {
    let (renderer, mut whole, mut cached) = whole_and_cached(320, Prefetch::Predict, 16);
    let options = TwoPlaneOptions {
        focus: 0.3,
        aperture: 3.0,
        sample_budget: 9,
        ..TwoPlaneOptions::default()
    };
    let (mut exact, mut degraded) = (0, 0);
    for v in pan(4, 0.1, 40) {
        let (reference, _) = whole
            .render_accumulated(&renderer, &v, &options, 4, true)
            .expect("whole");
        let (frame, stats) = cached
            .render_accumulated(&renderer, &v, &options, 4, true)
            .expect("cached");
        assert!(stats.pages_loaded <= 4 * 16, "{}", stats.pages_loaded);
        assert_eq!(
            stats.bytes_uploaded,
            u64::from(stats.pages_loaded) * 16 * 16 * 8,
            "RGBA8 and f32 texels of 16x16 pages"
        );
        let (e, d) = exact_where_not_degraded(&frame, &reference, &stats, "accumulated");
        exact += e;
        degraded += d;
    }
    assert!(
        exact > 1000 && degraded > 100,
        "{exact} exact, {degraded} degraded"
    );
    assert!(
        matches!(
            cached.render_accumulated(&renderer, &pan(1, 0.0, 40)[0], &options, 0, true),
            Err(RenderError::Option(_))
        ),
        "0 draws"
    );
}

/// The projection of a view (`needed_pages`) holds every page the shader touches, for every
/// mode, on views inside, across and beyond the planes' region.
#[test]
fn projected_pages_cover_the_pages_frames_touch() {
    let planes = planes();
    let asset = asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let mut whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    let mut views = pan(6, 0.18, 40);
    views.push(view([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 50.0, 40));
    views.push(view([0.9, 0.7, 2.2], [0.5, 0.3, 0.0], 25.0, 40));
    for options in modes() {
        for v in &views {
            let (_, stats) = whole.render(&renderer, v, &options).expect("render");
            assert_eq!(stats.projection_missed, 0, "{options:?} {v:?}");
            let projected = needed_pages(
                &planes,
                &whole.grid,
                whole.depth_range,
                v,
                &options,
                8,
                None,
            )
            .expect("ok")
            .pages;
            assert_eq!(projected.len() as u32, stats.pages_projected);
        }
    }
}

/// On a fast pan the predictive policy (dead reckoning) faults at least 30 % less than LRU; at
/// rest no policy faults once the view's pages are in.
#[test]
fn prediction_faults_less_than_lru_on_a_fast_pan() {
    let planes = planes();
    let asset = asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let options = TwoPlaneOptions::default();
    let run = |policy: Prefetch, views: &[View]| {
        let config = CacheConfig {
            budget_bytes: Some(160 * 1024),
            prefetch: policy,
            pages_per_frame: 24,
            overview: false,
        };
        let mut cached =
            PagedTwoPlane::open(&renderer, Arc::clone(&asset), config).expect("open cache");
        let stats: Vec<_> = views
            .iter()
            .map(|v| cached.render(&renderer, v, &options).expect("render").1)
            .collect();
        stats
    };
    let fast = pan(10, 0.09, 40);
    let lru = PageSummary::of(&run(Prefetch::Lru, &fast));
    let predict = PageSummary::of(&run(Prefetch::Predict, &fast));
    assert!(
        predict.faults * 10 < lru.faults * 7,
        "predict {} faults, LRU {}",
        predict.faults,
        lru.faults
    );
    // At rest: the first frames fault until the view's pages (49, 24 loaded per frame) are
    // in, then none do.
    let still = vec![fast[3].clone(); 6];
    for policy in Prefetch::ALL {
        let faults: Vec<u32> = run(policy, &still).iter().map(|s| s.faults).collect();
        assert!(faults[0] > 0, "{policy}: {faults:?}");
        assert!(faults[3..].iter().all(|&f| f == 0), "{policy}: {faults:?}");
    }
}

#[test]
fn bad_budgets_and_corrupt_pages_are_refused() {
    let planes = planes();
    let renderer = TwoPlaneRenderer::new(gpu());
    let tiny = CacheConfig {
        budget_bytes: Some(1024),
        prefetch: Prefetch::Lru,
        pages_per_frame: 8,
        overview: false,
    };
    match PagedTwoPlane::open(&renderer, asset(&planes), tiny) {
        Err(RenderError::Option(m)) => assert!(m.contains("holds no"), "{m}"),
        other => panic!("a 1 KiB cache: {:?}", other.err()),
    }
    // A flipped byte in the page data: the checksum of that page fails when the cache opens.
    let mut bytes = asset_bytes(&planes);
    bytes[200] ^= 0x5a;
    let corrupt = Arc::new(AssetFile::from_bytes(bytes).expect("header and index intact"));
    match PagedTwoPlane::open(&renderer, corrupt, CacheConfig::whole()) {
        Err(RenderError::Asset(e)) => assert!(!e.to_string().is_empty()),
        other => panic!("a corrupt page: {:?}", other.err()),
    }
}

/// Frames that do not wait for their pages (`render_nowait`): the first renders at once from the
/// coarse level alone, the pages arrive from the reader thread for later frames, and a view
/// held still converges to the fully resident frame, every pixel that is not degraded equal to
/// it bit for bit on the way. A waiting frame after them takes the pages still being read.
#[test]
fn frames_that_do_not_wait_for_pages_converge_to_the_resident_frame() {
    let (renderer, mut whole, mut cached) = whole_and_cached(320, Prefetch::Lru, 6);
    let options = TwoPlaneOptions::default();
    let v = &pan(1, 0.0, 40)[0];
    let (reference, _) = whole.render(&renderer, v, &options).expect("whole");
    let (_, stats) = cached.render_nowait(&renderer, v, &options).expect("first");
    assert_eq!(
        stats.pages_loaded, 0,
        "nothing arrived before the first frame"
    );
    assert_eq!(
        stats.pages_pending, 6,
        "the frame's planned pages are being read"
    );
    assert_eq!(
        stats.faults, stats.pages_touched,
        "no page on the device yet"
    );
    assert!(stats.degraded_px > 0);
    let mut frames = 1;
    let converged = loop {
        std::thread::sleep(std::time::Duration::from_millis(20));
        let (frame, stats) = cached.render_nowait(&renderer, v, &options).expect("frame");
        frames += 1;
        exact_where_not_degraded(&frame, &reference, &stats, &format!("frame {frames}"));
        if stats.degraded_px == 0 && stats.pages_pending == 0 || frames > 60 {
            break stats.degraded_px == 0;
        }
    };
    assert!(converged, "still degraded after {frames} frames");
    assert!(frames > 2, "6 pages a frame cannot load the view at once");
    // A moved view: its pages are asked for without waiting, then a waiting frame takes them.
    let moved = &pan(2, 0.3, 40)[1];
    let (_, asked) = cached
        .render_nowait(&renderer, moved, &options)
        .expect("moved");
    let (_, waited) = cached.render(&renderer, moved, &options).expect("waited");
    assert_eq!(waited.pages_pending, 0);
    assert!(
        waited.pages_loaded >= asked.pages_pending,
        "{asked:?} then {waited:?}"
    );
}

/// A page that fails to read in the background (the file corrupted under an open cache) is
/// reported by a later frame and stays missing: that frame is degraded, nothing panics, and
/// the pages that read well still render.
#[test]
fn a_page_failing_to_read_in_the_background_degrades_later_frames() {
    let planes = planes();
    let bytes = asset_bytes(&planes);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("paged.lfa");
    std::fs::write(&path, &bytes).expect("write");
    let asset = Arc::new(AssetFile::open(&path).expect("open"));
    let renderer = TwoPlaneRenderer::new(gpu());
    let config = CacheConfig {
        budget_bytes: Some(320 * 1024),
        prefetch: Prefetch::Lru,
        pages_per_frame: 64,
        overview: false,
    };
    let mut cached = PagedTwoPlane::open(&renderer, asset, config).expect("open");
    // Every page's bytes flipped on disk (the header and index are in memory).
    let mut corrupt = bytes.clone();
    for b in &mut corrupt[bytes.len() / 10..bytes.len() * 9 / 10] {
        *b ^= 0xa5;
    }
    std::fs::write(&path, &corrupt).expect("corrupt");
    let v = &pan(1, 0.0, 40)[0];
    let options = TwoPlaneOptions::default();
    let (_, first) = cached.render_nowait(&renderer, v, &options).expect("first");
    assert!(first.pages_pending > 0);
    std::thread::sleep(std::time::Duration::from_millis(50));
    let (frame, later) = cached.render(&renderer, v, &options).expect("later");
    assert!(!later.read_errors.is_empty(), "{later:?}");
    assert!(later.degraded_px > 0);
    assert!(
        frame.depth.iter().any(|d| d.is_finite()),
        "the coarse level shows"
    );
}

/// Overview pixels (spanning the coarse factor F or more st texels) read the coarse level and
/// need no page: a zoomed-out view touches, projects and loads none; as the same view grows
/// the overview gives way to the page levels and then to the full-resolution pages pixel by
/// pixel, the full-resolution pages are exact where read, and the projection still covers every
/// page touched (of every level).
#[test]
fn overview_pixels_read_the_coarse_level_and_need_no_page() {
    let planes = planes();
    let asset = asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let mut whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    let config = CacheConfig {
        budget_bytes: Some(160 * 1024),
        prefetch: Prefetch::Lru,
        pages_per_frame: 64,
        overview: true,
    };
    let mut cached = PagedTwoPlane::open(&renderer, asset, config).expect("open cache");
    assert_eq!(cached.coarse_factor, 8);
    let options = TwoPlaneOptions::default();
    let mut mixed = 0;
    let straight = |size| view([0.1, 0.05, 4.0], [0.0, 0.0, 0.0], 30.0, size);
    // Oblique: the st texels a pixel spans grow across the frame.
    let oblique = |size| view([-0.5, 0.0, 3.0], [1.0, 0.0, 0.0], 40.0, size);
    for (name, v) in [
        ("straight", straight(6)),
        ("straight", straight(16)),
        ("oblique", oblique(8)),
        ("oblique", oblique(9)),
        ("oblique", oblique(10)),
        ("oblique", oblique(11)),
        ("oblique", oblique(16)),
        // Below 2 texels a pixel (page level 0) on part of the frame.
        ("straight", straight(40)),
        ("oblique", oblique(40)),
    ] {
        let size = v.width;
        // Twice: the second frame has every page it reads.
        cached.render(&renderer, &v, &options).expect("render");
        let (frame, stats) = cached.render(&renderer, &v, &options).expect("render");
        let (reference, _) = whole.render(&renderer, &v, &options).expect("whole");
        let covered = frame.depth.iter().filter(|d| d.is_finite()).count() as u64;
        assert!(covered > 0);
        assert_eq!(stats.projection_missed, 0, "size {size}");
        assert_eq!(
            stats.overview_mask.iter().filter(|&&o| o).count() as u64,
            stats.overview_px
        );
        exact_where_not_degraded(&frame, &reference, &stats, &format!("size {size}"));
        if name == "straight" && size == 6 {
            // 11 texels a pixel and more: nothing touched, projected or loaded.
            assert_eq!(stats.overview_px, covered);
            assert_eq!(
                (stats.pages_touched, stats.pages_projected, stats.faults),
                (0, 0, 0)
            );
            // The coarse level is the same image box-filtered: close to the full one.
            let diff: u64 = frame
                .color
                .iter()
                .zip(&reference.color)
                .map(|(a, b)| u64::from(a.abs_diff(*b)))
                .sum();
            let mean = diff as f64 / (4 * covered) as f64;
            assert!(mean < 12.0, "mean colour difference {mean:.2} codes");
        }
        if stats.overview_px > 0 && stats.overview_px < covered {
            mixed += 1;
        }
    }
    assert!(mixed > 0, "no size mixed overview and paged pixels");
}

/// A light field on [`common::small_planes`] in pages of 16 whose colour is a ramp in the
/// texel's column and row (red 2j, green 2i, blue per camera) over a constant depth: the mean
/// of any 2^l × 2^l block is the ramp at the block's centre, a whole code, so a page level read
/// bilinearly gives what the full resolution gives (away from the image's border, where each
/// level clamps to its own last texel).
fn ramp_asset(planes: &TwoPlanes) -> Arc<AssetFile> {
    let header =
        AssetHeader::new_two_plane(*planes, 16, Provenance::default()).expect("a valid header");
    let [nu, nv] = planes.uv.grid;
    let [ns, nt] = planes.st.resolution;
    let mut images = Vec::new();
    for camera in 0..nu * nv {
        let mut c = Vec::new();
        let mut d = Vec::new();
        for i in 0..nt {
            for j in 0..ns {
                c.extend_from_slice(&[(2 * j) as u8, (2 * i) as u8, (10 * camera) as u8, 255]);
                d.extend_from_slice(&0.6f32.to_le_bytes());
            }
        }
        images.push((ImageKey::new(0, 0, camera, Channel::Color), c));
        images.push((ImageKey::new(0, 0, camera, Channel::Depth), d));
    }
    Arc::new(AssetFile::from_bytes(encode_asset(header, images).expect("encode")).expect("read"))
}

/// Page levels: zoomed-out views (2 to 8 st texels a pixel, the coarse factor 8) read levels 1
/// and 2 through the cache. Away from the image's border, every pixel is within 1 code of the
/// fully resident frame in each uv filter (the ramp's block means are exact; f32 bilinear
/// weights at two scales may round a half code apart), no pixel is degraded once the pages are
/// loaded, the projection predicts every page touched, and the frame touches fewer pages than
/// the same view at full resolution.
#[test]
fn page_levels_read_downsampled_pages_within_a_code_and_fewer_of_them() {
    let planes = planes();
    let asset = ramp_asset(&planes);
    let renderer = TwoPlaneRenderer::new(gpu());
    let mut whole =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), CacheConfig::whole()).expect("open");
    let config = |overview| CacheConfig {
        budget_bytes: Some(160 * 1024),
        prefetch: Prefetch::Lru,
        pages_per_frame: 1000,
        overview,
    };
    let mut levels =
        PagedTwoPlane::open(&renderer, Arc::clone(&asset), config(true)).expect("open");
    let mut flat = PagedTwoPlane::open(&renderer, asset, config(false)).expect("open");
    assert_eq!((levels.coarse_factor, levels.grid.levels), (8, 3));
    assert_eq!(flat.grid.levels, 1);
    // The border margin: 2F texels, in codes (2 per texel) of red and green.
    let margin = 2 * 2 * 8;
    let mut compared = 0;
    for filter in [UvFilter::Nearest, UvFilter::Bilinear, UvFilter::Depth] {
        let options = TwoPlaneOptions {
            uv_filter: filter,
            focus: 0.6,
            ..TwoPlaneOptions::default()
        };
        for v in [
            view([0.1, 0.05, 4.0], [0.0, 0.0, 0.0], 30.0, 12),
            view([0.1, 0.05, 4.0], [0.0, 0.0, 0.0], 30.0, 24),
            view([0.1, 0.05, 4.0], [0.0, 0.0, 0.0], 30.0, 32),
            view([-0.5, 0.0, 3.0], [1.0, 0.0, 0.0], 40.0, 16),
            view([-0.5, 0.0, 3.0], [1.0, 0.0, 0.0], 40.0, 28),
        ] {
            levels.render(&renderer, &v, &options).expect("render");
            let (frame, stats) = levels.render(&renderer, &v, &options).expect("render");
            let (reference, _) = whole.render(&renderer, &v, &options).expect("whole");
            flat.render(&renderer, &v, &options).expect("render");
            let (_, full) = flat.render(&renderer, &v, &options).expect("render");
            let what = format!("{filter:?} {}px", v.width);
            assert_eq!(stats.degraded_px, 0, "{what}");
            assert_eq!(stats.projection_missed, 0, "{what}");
            assert!(stats.overview_px > 0, "{what}: no pixel read a level");
            assert!(
                stats.pages_touched < full.pages_touched,
                "{what}: {} pages touched with levels, {} without",
                stats.pages_touched,
                full.pages_touched
            );
            for p in 0..frame.pixel_count() {
                let (a, b) = (
                    &frame.color[4 * p..4 * p + 4],
                    &reference.color[4 * p..4 * p + 4],
                );
                let inside = b[3] == 255
                    && (margin..=126 - margin).contains(&b[0])
                    && (margin..=94 - margin).contains(&b[1]);
                if !inside {
                    continue;
                }
                compared += 1;
                assert!(
                    a.iter().zip(b).all(|(x, y)| x.abs_diff(*y) <= 1),
                    "{what}: pixel {p}: {a:?} against {b:?}"
                );
            }
        }
    }
    assert!(compared > 300, "{compared} pixels compared");
}
