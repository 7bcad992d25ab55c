//! `lumigraph eval`: light-field renders against reference renders of the source mesh.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::calibration::Choice;
use lumigraph_core::lod::LodDecision;
use lumigraph_core::metrics::{self, Comparison};
use lumigraph_core::quality::{Quality, Rendered};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::Renderer;

use super::args::{describe, describe_lod};
use lumigraph_core::view::{View, evaluation_views};

use super::common::{gpu, load_source, progress_bar, read_view_file};

/// `lumigraph eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Light-field asset (.lfa).
    pub asset: PathBuf,
    /// Source mesh of the asset.
    #[arg(long, required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// The asset was baked from the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// A number of random views (default 12) or a JSON list of views.
    #[arg(long, default_value = "12")]
    pub views: String,
    /// Seed of the random views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Size of the random views in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Quality: knobs, a goal or automatic LOD.
    #[command(flatten)]
    pub quality: Quality,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Default eval views: the evaluation orbit around the asset's bounding sphere.
fn eval_views(args: &EvalArgs, asset: &AssetFile) -> Result<Vec<View>> {
    if let Ok(n) = args.views.parse::<usize>() {
        if n == 0 || n > 10_000 {
            bail!("--views {n}: give 1 to 10000 random views or a JSON file");
        }
        if args.size == 0 || args.size > 4096 {
            bail!("--size {}: give 1 to 4096 pixels", args.size);
        }
        let frame = &asset.header().frame;
        return Ok(evaluation_views(
            frame.center,
            frame.radius,
            n,
            args.seed,
            args.size,
        ));
    }
    let path = Path::new(&args.views);
    read_view_file(path)
}

/// Per-view and mean results of `eval`.
#[derive(Debug, serde::Serialize)]
struct EvalReport {
    asset: String,
    cameras: u32,
    resolution: u32,
    asset_bytes: u64,
    /// Bounding radius in world units (depth errors are in world units).
    radius: f64,
    settings: lumigraph_core::render::ResolvedOptions,
    views: Vec<EvalView>,
    mean: Option<metrics::MeanComparison>,
    mean_ms: f64,
    mean_fetches_per_pixel: f64,
    /// The calibrated choice (with --target-psnr / --budget-ms): predicted beside measured.
    choice: Option<Choice>,
}

#[derive(Debug, serde::Serialize)]
struct EvalView {
    index: usize,
    ms: f64,
    fetches_per_pixel: f64,
    /// Output pixels.
    pixels: u64,
    /// Pixels covered in one mask only over the reference's silhouette length.
    silhouette_error_px: f64,
    /// The automatic-LOD decision (with --auto-lod): predicted beside measured.
    lod: Option<LodDecision>,
    #[serde(flatten)]
    comparison: Comparison,
}

pub(super) fn eval(args: &EvalArgs) -> Result<()> {
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let header = asset.header().clone();
    let views = eval_views(args, &asset)?;
    for (i, v) in views.iter().enumerate() {
        v.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)
            .with_context(|| format!("view {i}"))?;
    }
    // The report sets the first view's settings and, with a goal, its prediction beside the
    // measurement.
    let plan = args.quality.plan(&header)?;
    let first = plan.decide(&views[0])?;
    let (settings, choice) = (first.settings, first.choice);
    // The reference must shade exactly as the bake did.
    let bake_options = BakeOptions::of(&header);
    let (mesh, _) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu);
    let field = renderer
        .upload(&asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    let gpu_mesh = reference.upload(&mesh)?;
    // Warm up: the first dispatch pays shader compilation.
    plan.render(&renderer, &field, &views[0])?;
    let bar = progress_bar(views.len() as u64, "evaluating views");
    let mut rows = Vec::with_capacity(views.len());
    for (index, view) in views.iter().enumerate() {
        let Rendered { frame, decision } = plan.render(&renderer, &field, view)?;
        let lod = decision.lod;
        let truth = reference.render(&gpu_mesh, view, &bake_options.shading)?;
        let comparison = metrics::compare(&frame, &truth)?;
        let silhouette_error_px =
            comparison.mask_mismatch_px as f64 / metrics::silhouette_px(&truth).max(1) as f64;
        let fetches_per_pixel =
            frame.stats.fetches as f64 / (f64::from(view.width) * f64::from(view.height));
        rows.push(EvalView {
            index,
            ms: frame.stats.render_ms,
            fetches_per_pixel,
            pixels: u64::from(view.width) * u64::from(view.height),
            silhouette_error_px,
            lod,
            comparison,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let comparisons: Vec<Comparison> = rows.iter().map(|r| r.comparison.clone()).collect();
    let mean_ms = rows.iter().map(|r| r.ms).sum::<f64>() / rows.len() as f64;
    let mean_fetches_per_pixel =
        rows.iter().map(|r| r.fetches_per_pixel).sum::<f64>() / rows.len() as f64;
    let report = EvalReport {
        asset: args.asset.display().to_string(),
        cameras: header.geometry.camera_count,
        resolution: header.geometry.resolution_px,
        asset_bytes: asset.file_len(),
        radius: header.frame.radius,
        settings,
        mean: metrics::mean_comparison(&comparisons),
        views: rows,
        mean_ms,
        mean_fetches_per_pixel,
        choice,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_eval_table(&report);
    }
    Ok(())
}

fn print_eval_table(report: &EvalReport) {
    println!(
        "{} — {} cameras (using {}), {} px maps, method {}, step {:.4}, tolerance {:.4}",
        report.asset,
        report.cameras,
        report.settings.cameras,
        report.resolution,
        report.settings.method,
        report.settings.step,
        report.settings.tolerance
    );
    println!("view  masked_psnr  psnr    inter_psnr  ssim    mae    mismatch_px  depth_med     ms");
    for row in &report.views {
        let c = &row.comparison;
        if let Some(d) = &row.lod {
            println!(
                "      {}; measured silhouette error {:.2} px",
                describe_lod(d, row.pixels),
                row.silhouette_error_px
            );
        }
        println!(
            "{:>4}  {:>11.2}  {:>6.2}  {:>10.2}  {:>6.4}  {:>5.2}  {:>11}  {:>9.2e}  {:>7.2}",
            row.index,
            c.masked_psnr,
            c.psnr,
            c.intersection_psnr,
            c.ssim,
            c.mae,
            c.mask_mismatch_px,
            c.depth.median,
            row.ms
        );
    }
    if let (Some(c), Some(m)) = (&report.choice, &report.mean) {
        println!(
            "{}; measured masked PSNR {:.2} dB, {:.1} ms",
            describe(c),
            m.masked_psnr,
            report.mean_ms
        );
    }
    if let Some(m) = &report.mean {
        println!(
            "mean  {:>11.2}  {:>6.2}  {:>10.2}  {:>6.4}  {:>5.2}  {:>11.1}  {:>9.2e}  {:>7.2}",
            m.masked_psnr,
            m.psnr,
            m.intersection_psnr,
            m.ssim,
            m.mae,
            m.mask_mismatch_px,
            m.depth.median,
            report.mean_ms
        );
    }
}
