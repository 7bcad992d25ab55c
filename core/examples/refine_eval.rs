//! Measures still-frame refinement on an asset: for each of `--views` orbit views (as `lumigraph
//! eval` chooses them), a single-sample frame and refined frames of each `--samples` count,
//! measured against the supersampled reference (`--factor`² samples per pixel) and, for the
//! single-sample frame, the plain reference; prints one JSON report. Wrong-surface pixels are
//! counted against the depth at the pixel's centre (`wrong_surface_px`) and against every
//! sample inside the pixel (`wrong_surface_footprint_px`: a surface the pixel does not contain).
//!
//! ```text
//! cargo run --release -p lumigraph_core --example refine_eval -- ASSET.lfa (--mesh MESH | --demo)
//!     [--views 12] [--size 512] [--seed 0] [--samples 8,16] [--factor 5]
//! ```

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use lumigraph_core::asset::AssetFile;
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::metrics::{self, Comparison};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::refine;
use lumigraph_core::render::{RenderOptions, Renderer};
use serde_json::json;

struct Args {
    asset: PathBuf,
    mesh: Option<PathBuf>,
    views: usize,
    size: u32,
    seed: u64,
    samples: Vec<u32>,
    factor: u32,
}

fn parse() -> Result<Args> {
    let mut args = Args {
        asset: PathBuf::new(),
        mesh: None,
        views: 12,
        size: 512,
        seed: 0,
        samples: vec![8, 16],
        factor: 5,
    };
    let (mut asset, mut demo) = (None, false);
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = || it.next().with_context(|| format!("{arg} needs a value"));
        match arg.as_str() {
            "--mesh" => args.mesh = Some(value()?.into()),
            "--demo" => demo = true,
            "--views" => args.views = value()?.parse()?,
            "--size" => args.size = value()?.parse()?,
            "--seed" => args.seed = value()?.parse()?,
            "--factor" => args.factor = value()?.parse()?,
            "--samples" => {
                args.samples = value()?
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()?;
            }
            _ if asset.is_none() && !arg.starts_with("--") => asset = Some(arg.into()),
            _ => bail!("unknown argument {arg}"),
        }
    }
    args.asset = asset.context("give ASSET.lfa")?;
    if args.mesh.is_some() == demo {
        bail!("give --mesh MESH or --demo");
    }
    if args.views == 0 {
        bail!("--views must be at least 1");
    }
    Ok(args)
}

/// Per-view numbers of one way of rendering.
#[derive(Default)]
struct Series {
    against_supersampled: Vec<Comparison>,
    footprint_wrong: Vec<u64>,
    render_ms: Vec<f64>,
    total_ms: Vec<f64>,
}

impl Series {
    fn push(&mut self, comparison: Comparison, footprint_wrong: u64, frame: &Frame, total_ms: f64) {
        self.against_supersampled.push(comparison);
        self.footprint_wrong.push(footprint_wrong);
        self.render_ms.push(frame.stats.render_ms);
        self.total_ms.push(total_ms);
    }

    fn report(&self, samples: u32) -> serde_json::Value {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        json!({
            "samples": samples,
            "frames": samples,
            "render_ms": mean(&self.render_ms),
            "total_ms": mean(&self.total_ms),
            "wrong_surface_px": self.against_supersampled.iter().map(|c| c.wrong_surface_px).collect::<Vec<_>>(),
            "wrong_surface_footprint_px": &self.footprint_wrong,
            "mean_wrong_surface_footprint_px": mean(&self.footprint_wrong.iter().map(|&n| n as f64).collect::<Vec<_>>()),
            "mean": metrics::mean_comparison(&self.against_supersampled),
        })
    }
}

fn main() -> Result<()> {
    let args = parse()?;
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open {}", args.asset.display()))?;
    let header = asset.header().clone();
    let bake_options: BakeOptions =
        serde_json::from_value(header.provenance.bake_options.clone()).unwrap_or_default();
    let mesh = match &args.mesh {
        Some(path) => lumigraph_core::mesh::load_mesh(path)?,
        None => lumigraph_core::mesh::demo_mesh()?,
    };
    let gpu = Gpu::shared()?;
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu);
    let field = renderer.upload(&asset)?;
    let gpu_mesh = reference.upload(&mesh)?;
    let views = lumigraph_core::view::random_orbit_views(
        header.frame.center,
        2.5 * header.frame.radius,
        args.views,
        args.seed,
        40.0,
        args.size,
    );
    let options = RenderOptions::default();
    let shading = bake_options.shading;
    // Warm up: the first dispatch pays shader compilation.
    renderer.render(&field, &views[0], &options)?;
    let mut single = Series::default();
    let mut single_plain = Vec::new();
    let mut refined: Vec<Series> = args.samples.iter().map(|_| Series::default()).collect();
    for view in &views {
        let truth = reference.render(&gpu_mesh, view, &shading)?;
        let (supersampled, footprint) =
            reference.render_supersampled_footprint(&gpu_mesh, view, &shading, args.factor)?;
        let off_footprint = |frame: &Frame| {
            metrics::wrong_surface_footprint_px(&frame.depth, &supersampled.depth, &footprint)
        };
        let start = Instant::now();
        let frame = renderer.render(&field, view, &options)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        single_plain.push(metrics::compare(&frame, &truth)?);
        single.push(
            metrics::compare(&frame, &supersampled)?,
            off_footprint(&frame)?,
            &frame,
            ms,
        );
        for (series, &samples) in refined.iter_mut().zip(&args.samples) {
            let start = Instant::now();
            let frame: Frame = refine::refine(samples, |jitter| -> Result<Frame> {
                Ok(renderer.render_jittered(&field, view, &options, &options, 0.0, jitter)?)
            })?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            series.push(
                metrics::compare(&frame, &supersampled)?,
                off_footprint(&frame)?,
                &frame,
                ms,
            );
        }
    }
    let report = json!({
        "asset": args.asset.display().to_string(),
        "cameras": header.camera_count(),
        "resolution": header.image_size()[0],
        "views": args.views,
        "size": args.size,
        "seed": args.seed,
        "supersample_factor": args.factor,
        "single_vs_reference": {
            "wrong_surface_px": single_plain.iter().map(|c| c.wrong_surface_px).collect::<Vec<_>>(),
            "mean": metrics::mean_comparison(&single_plain),
        },
        "single": single.report(1),
        "refined": refined.iter().zip(&args.samples).map(|(s, &n)| s.report(n)).collect::<Vec<_>>(),
    });
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
