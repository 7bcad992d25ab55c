//! `lumigraph bench animation`: playback cost of an animated asset (`bake --animation`): frames
//! rendered in turn, as a player advances them, against the static base frame, interleaved on
//! the same views; with the frames' storage and GPU memory.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::deform::{self, AnimationInfo};
use lumigraph_core::render::{RenderOptions, Renderer};
use lumigraph_core::view::evaluation_views;
use serde::Serialize;

use super::common::gpu;

/// `lumigraph bench animation`.
#[derive(Debug, Args)]
pub struct AnimationArgs {
    /// An asset baked with `--animation`.
    pub asset: PathBuf,
    /// Random orbit views.
    #[arg(long, default_value_t = 3)]
    pub views: usize,
    /// Side of the square views in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Static and playing frames per view, interleaved; the medians are kept.
    #[arg(long, default_value_t = 24)]
    pub repeats: usize,
    /// Seed of the views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, Serialize)]
struct Report {
    asset: String,
    adapter: String,
    animation: String,
    frames: usize,
    fps: f64,
    mean_stored_fraction: f64,
    asset_bytes: u64,
    gpu_bytes: u64,
    static_ms: f64,
    playing_ms: f64,
    playing_over_static: f64,
}

pub(super) fn bench_animation(args: &AnimationArgs) -> Result<()> {
    if args.views == 0 || args.views > 100 || args.repeats == 0 || args.repeats > 1000 {
        bail!("--views 1..=100 and --repeats 1..=1000");
    }
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let header = asset.header().clone();
    let animation = AnimationInfo::of(&header)
        .context("the asset has no animation: bake it with --animation")?;
    let storage = deform::storage(&asset)?;
    let mean_stored_fraction =
        storage.iter().map(|s| s.fraction).sum::<f64>() / storage.len().max(1) as f64;
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let field = renderer.upload(&asset)?;
    let frame = &header.frame;
    let views = evaluation_views(frame.center, frame.radius, args.views, args.seed, args.size);
    let (mut still, mut playing) = (Vec::new(), Vec::new());
    let mut next = 0usize;
    for view in &views {
        renderer.render(&field, view, &RenderOptions::default())?;
        for _ in 0..args.repeats {
            let t = Instant::now();
            renderer.render(&field, view, &RenderOptions::default())?;
            still.push(t.elapsed().as_secs_f64() * 1e3);
            next = (next + 1) % animation.states.len();
            let state = animation.states[next];
            let options = RenderOptions {
                state: (state != 0).then_some(state),
                ..RenderOptions::default()
            };
            let t = Instant::now();
            renderer.render(&field, view, &options)?;
            playing.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let (s, p) = (median(still), median(playing));
    let report = Report {
        asset: args.asset.display().to_string(),
        adapter: gpu.adapter_summary(),
        animation: animation.name.clone(),
        frames: animation.states.len(),
        fps: animation.fps,
        mean_stored_fraction,
        asset_bytes: asset.file_len(),
        gpu_bytes: field.gpu_bytes,
        static_ms: s,
        playing_ms: p,
        playing_over_static: p / s,
    };
    println!(
        "{}: animation {:?}, {} frames at {} fps, frames store {:.1} % of the pages on average; \
         {:.1} MiB on disk, {:.0} MiB on the device; {} views of {}² on {}",
        report.asset,
        report.animation,
        report.frames,
        report.fps,
        100.0 * report.mean_stored_fraction,
        report.asset_bytes as f64 / 1_048_576.0,
        report.gpu_bytes as f64 / 1_048_576.0,
        args.views,
        args.size,
        report.adapter
    );
    println!(
        "frame ms: static {s:.2}, playing {p:.2} ({:.3}×)",
        report.playing_over_static
    );
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &json))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
