//! `lumigraph bench two-plane`: a mesh captured into two-plane light fields over uv grids × st
//! resolutions, each rendered with every uv filter from views beyond the uv plane and scored
//! against the reference rasterizer over the valid region; pinhole, 5×5-aperture and
//! full-aperture timings beside.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::frame::Frame;
use lumigraph_core::image_io;
use lumigraph_core::metrics;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::shading::Shading;
use lumigraph_core::two_plane::{self, TwoPlanes};
use lumigraph_core::two_plane_render::{
    TwoPlaneOptions, TwoPlaneRenderer, UvFilter, evaluation_views, restrict, valid_region,
};
use serde::Serialize;

use super::common::{gpu, load_source};

/// `lumigraph bench two-plane`.
#[derive(Debug, Args)]
pub struct TwoPlaneArgs {
    /// Mesh file (omit with --demo).
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// Use the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// uv grids, NUxNV, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8x8,17x17", value_parser = super::args::parse_size_pair)]
    pub grids: Vec<[u32; 2]>,
    /// st resolutions, NSxNT, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "256x256,512x512", value_parser = super::args::parse_size_pair)]
    pub st_res: Vec<[u32; 2]>,
    /// Planes fitted along this axis (the side of the cameras), X,Y,Z.
    #[arg(long, default_value = "0,0,1", value_parser = super::args::parse_vec3_f64, allow_hyphen_values = true)]
    pub axis: [f64; 3],
    /// Views beyond the uv plane.
    #[arg(long, default_value_t = 4)]
    pub views: usize,
    /// Side of the square views in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Timed renders per view and mode (the median is kept), after one warm-up.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Colour pages block-compressed (kept compressed on a device that samples BC).
    #[arg(long, value_enum, default_value_t = super::bake::ColorCodec::Raw)]
    pub color_codec: super::bake::ColorCodec,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, Serialize)]
struct Row {
    grid: [u32; 2],
    st_resolution: [u32; 2],
    filter: String,
    masked_psnr: f64,
    ssim: f64,
    wrong_surface_px: f64,
    valid_px: f64,
    ms: f64,
    /// The `.lfa` file's bytes and the device bytes of its textures.
    asset_bytes: u64,
    gpu_bytes: u64,
    /// Mean bytes of the frame as the stream sends it: JPEG at the interactive quality (50),
    /// JPEG at the still quality (90), lossless WebP (black background).
    jpeg50_bytes: f64,
    jpeg90_bytes: f64,
    webp_bytes: f64,
}

#[derive(Debug, Serialize)]
struct ApertureRow {
    grid: [u32; 2],
    st_resolution: [u32; 2],
    aperture: f64,
    cameras_per_pixel: u32,
    ms: f64,
    accumulated_frames: u32,
    accumulated_ms: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    source: String,
    color_codec: String,
    adapter: String,
    views: usize,
    size: u32,
    rows: Vec<Row>,
    apertures: Vec<ApertureRow>,
}

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    let n = xs.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        xs[n / 2]
    } else {
        f64::midpoint(xs[n / 2 - 1], xs[n / 2])
    }
}

/// Renders `repeats` + 1 times; the first frame and the median time of the others.
fn timed(
    renderer: &TwoPlaneRenderer,
    field: &lumigraph_core::two_plane_render::GpuTwoPlane,
    view: &lumigraph_core::view::View,
    options: &TwoPlaneOptions,
    repeats: usize,
) -> Result<(Frame, f64)> {
    let frame = renderer.render(field, view, options)?;
    let mut times = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        times.push(renderer.render(field, view, options)?.stats.render_ms);
    }
    Ok((frame, median(times)))
}

pub(super) fn bench_two_plane(args: &TwoPlaneArgs) -> Result<()> {
    if !(1..=100).contains(&args.views) || !(1..=100).contains(&args.repeats) {
        bail!("--views and --repeats: 1..=100");
    }
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let reference = ReferenceRenderer::new(gpu.clone());
    let renderer = TwoPlaneRenderer::new(gpu.clone());
    let gpu_mesh = reference.upload(&mesh)?;
    let shading = Shading::default();
    let path = std::env::temp_dir().join(format!(
        "lumigraph-bench-two-plane-{}.lfa",
        std::process::id()
    ));
    let result = sweep(
        args,
        args.axis,
        (&reference, &renderer, &gpu_mesh),
        &shading,
        &provenance,
        &path,
    );
    let _ = std::fs::remove_file(&path);
    let (rows, apertures) = result?;
    let report = Report {
        source: provenance.source_name,
        color_codec: format!("{:?}", args.color_codec).to_lowercase(),
        adapter: gpu.adapter_summary(),
        views: args.views,
        size: args.size,
        rows,
        apertures,
    };
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &json))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// Every grid × resolution of `args`: the quality rows and the aperture timings.
fn sweep(
    args: &TwoPlaneArgs,
    axis: [f64; 3],
    (reference, renderer, gpu_mesh): (
        &ReferenceRenderer,
        &TwoPlaneRenderer,
        &lumigraph_core::gpu::mesh::GpuMesh,
    ),
    shading: &Shading,
    provenance: &lumigraph_core::asset::Provenance,
    path: &std::path::Path,
) -> Result<(Vec<Row>, Vec<ApertureRow>)> {
    let mut rows = Vec::new();
    let mut apertures = Vec::new();
    for &grid in &args.grids {
        for &res in &args.st_res {
            let planes: TwoPlanes = two_plane::fit_planes(
                lumigraph_core::glam::DVec3::from(gpu_mesh.frame.center),
                gpu_mesh.frame.radius,
                lumigraph_core::glam::DVec3::from(axis),
                grid,
                res,
            )?;
            two_plane::bake_to_file_with(
                reference,
                gpu_mesh,
                &planes,
                shading,
                provenance.clone(),
                args.color_codec.block(),
                path,
                &mut |_, _| {},
            )?;
            let asset = AssetFile::open(path)?;
            let field = renderer.upload(&asset)?;
            let asset_bytes = std::fs::metadata(path).map_or(0, |m| m.len());
            let views = evaluation_views(&planes, args.views, args.size, args.seed);
            let mut truths = Vec::with_capacity(views.len());
            for view in &views {
                let region = valid_region(&planes, view)?;
                let truth = reference.render(gpu_mesh, view, shading)?;
                truths.push((region.clone(), restrict(&truth, &region, [0; 4])));
            }
            for filter in UvFilter::ALL {
                let options = TwoPlaneOptions {
                    uv_filter: filter,
                    ..TwoPlaneOptions::default()
                };
                let (mut psnr, mut ssim, mut wrong, mut valid, mut ms) =
                    (0.0, 0.0, 0.0, 0.0, Vec::new());
                let mut bytes = [0.0f64; 3];
                for (view, (region, truth)) in views.iter().zip(&truths) {
                    let (frame, t) = timed(renderer, &field, view, &options, args.repeats)?;
                    let rgba = frame.with_background([0, 0, 0, 255]);
                    let (w, h) = (frame.width, frame.height);
                    bytes[0] += image_io::encode_jpeg(w, h, &rgba, 50, [0; 3])?.len() as f64;
                    bytes[1] += image_io::encode_jpeg(w, h, &rgba, 90, [0; 3])?.len() as f64;
                    bytes[2] += image_io::encode_webp_lossless(w, h, &rgba)?.len() as f64;
                    let frame = restrict(&frame, region, [0; 4]);
                    let c = metrics::compare(&frame, truth)?;
                    psnr += c.masked_psnr;
                    ssim += c.ssim;
                    wrong += c.wrong_surface_px as f64;
                    valid += region.iter().filter(|&&v| v).count() as f64;
                    ms.push(t);
                }
                let n = views.len() as f64;
                let row = Row {
                    grid,
                    st_resolution: res,
                    filter: filter.name().to_owned(),
                    masked_psnr: psnr / n,
                    ssim: ssim / n,
                    wrong_surface_px: wrong / n,
                    valid_px: valid / n,
                    ms: median(ms),
                    asset_bytes,
                    gpu_bytes: field.bytes,
                    jpeg50_bytes: bytes[0] / n,
                    jpeg90_bytes: bytes[1] / n,
                    webp_bytes: bytes[2] / n,
                };
                println!(
                    "{}x{} cameras, {}x{} st, {:>8}: masked PSNR {:.2} dB, SSIM {:.4}, wrong \
                     surface {:.0} px of {:.0} valid, {:.2} ms, JPEG 50 / 90 / WebP {:.0} / \
                     {:.0} / {:.0} bytes",
                    grid[0],
                    grid[1],
                    res[0],
                    res[1],
                    row.filter,
                    row.masked_psnr,
                    row.ssim,
                    row.wrong_surface_px,
                    row.valid_px,
                    row.ms,
                    row.jpeg50_bytes,
                    row.jpeg90_bytes,
                    row.webp_bytes
                );
                rows.push(row);
            }
            // A 5×5 aperture (R = 2) and the full aperture (R = half the grid) accumulated
            // from stratified draws of the default budget.
            let full = f64::from(grid[0].max(grid[1])) / 2.0;
            for (aperture, frames) in [(2.0, 1u32), (full, 16)] {
                let mut ms = Vec::new();
                let mut total = Vec::new();
                for view in &views {
                    let options = TwoPlaneOptions {
                        aperture,
                        ..TwoPlaneOptions::default()
                    };
                    let (_, t) = timed(renderer, &field, view, &options, args.repeats)?;
                    ms.push(t);
                    let mut sum = 0.0;
                    for index in 0..frames {
                        let options = TwoPlaneOptions {
                            frame_index: index,
                            ..options
                        };
                        sum += renderer.render(&field, view, &options)?.stats.render_ms;
                    }
                    total.push(sum);
                }
                // Cameras with weight: |Δ| < R + ½ per axis.
                let side = (2.0 * aperture + 1.0)
                    .ceil()
                    .min(f64::from(grid[0].max(grid[1]))) as u32;
                let row = ApertureRow {
                    grid,
                    st_resolution: res,
                    aperture,
                    cameras_per_pixel: (side * side).min(TwoPlaneOptions::default().sample_budget),
                    ms: median(ms),
                    accumulated_frames: frames,
                    accumulated_ms: median(total),
                };
                println!(
                    "{}x{} cameras, {}x{} st, aperture {}: {:.2} ms per frame ({} cameras per \
                     pixel at most); {} frames accumulated in {:.1} ms",
                    grid[0],
                    grid[1],
                    res[0],
                    res[1],
                    aperture,
                    row.ms,
                    row.cameras_per_pixel,
                    frames,
                    row.accumulated_ms
                );
                apertures.push(row);
            }
        }
    }
    Ok((rows, apertures))
}
