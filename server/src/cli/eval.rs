//! `lumigraph eval`: light-field renders against reference renders of the source mesh, or of
//! the source volume ray-cast directly (`--volume`).

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

use lumigraph_core::volume::bake::VolumeBaker;
use lumigraph_core::volume::layers::{VolumeLayer, reference_layers};
use lumigraph_core::volume::raycast::{RaycastOptions, raycast};
use lumigraph_core::volume::tf::TransferFunction;
use lumigraph_core::volume::{LoadOptions, Volume};

use super::common::{gpu, load_source, progress_bar, read_view_file};
use super::render::VolumeArgs;

/// `lumigraph eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Light-field asset (.lfa).
    pub asset: PathBuf,
    /// Source mesh of the asset.
    #[arg(
        long,
        required_unless_present_any = ["demo", "volume"],
        conflicts_with_all = ["demo", "volume"]
    )]
    pub mesh: Option<PathBuf>,
    /// Source volume of a volume asset: the reference is its direct ray cast (DESIGN §9) with
    /// the transfer function and options the asset was baked with, or those given here.
    #[arg(long, conflicts_with = "demo")]
    pub volume: Option<PathBuf>,
    /// Transfer function and ray-cast options of --volume (default: the asset's own).
    #[command(flatten)]
    pub volume_args: EvalVolumeArgs,
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
    /// With --volume: also ray-cast each view directly on the GPU with the bake's integration
    /// and score it against the reference (the floor under the light field's error), timing it.
    #[arg(long, requires = "volume")]
    pub floor: bool,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The ray-cast flags of `eval --volume`: those of `reference VOLUME`, with the sample spacing
/// as `--ray-step` (`--step` is the light-field marcher's).
#[derive(Debug, Args)]
pub struct EvalVolumeArgs {
    /// Transfer function of the reference: a JSON file, or a preset (ct-bone, ct-skin,
    /// mri-brain). Default: the one the asset was baked with.
    #[arg(long)]
    pub tf: Option<String>,
    /// Read the volume as integer labels.
    #[arg(long)]
    pub labels: bool,
    /// Gradient shading in the reference.
    #[arg(long)]
    pub shade: bool,
    /// The reference's sample spacing along the ray, world units (default: the bake's).
    #[arg(long)]
    pub ray_step: Option<f64>,
    /// Accumulated opacity that places the reference's depth (default: the bake's).
    #[arg(long)]
    pub depth_threshold: Option<f64>,
    /// Voxel spacing SX,SY,SZ of a .npy volume (default 1,1,1).
    #[arg(long, value_parser = super::args::parse_vec3_f64, allow_hyphen_values = true)]
    pub spacing: Option<[f64; 3]>,
}

impl EvalVolumeArgs {
    fn as_volume_args(&self) -> VolumeArgs {
        VolumeArgs {
            tf: self.tf.clone(),
            labels: self.labels,
            shade: self.shade,
            step: self.ray_step,
            depth_threshold: self.depth_threshold,
            spacing: self.spacing,
        }
    }
}

/// A render of a view (the reference's, or the direct GPU ray cast's).
type FrameOf = Box<dyn Fn(&View) -> Result<lumigraph_core::frame::Frame>>;

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
    /// Mean wall-clock time of the reference renders.
    mean_reference_ms: f64,
    /// With --floor: the mean of the direct GPU ray casts against the reference, and their time.
    mean_floor: Option<metrics::MeanComparison>,
    mean_direct_ms: Option<f64>,
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
    /// Fraction of the frame the reference covers (a full-frame MAE scales with it).
    footprint: f64,
    /// The automatic-LOD decision (with --auto-lod): predicted beside measured.
    lod: Option<LodDecision>,
    /// Wall-clock time of the reference render (the CPU ray cast of a volume).
    reference_ms: f64,
    /// With --floor: the GPU's direct ray cast against the reference, and its wall-clock time.
    floor: Option<Comparison>,
    direct_ms: Option<f64>,
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
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let mut direct_of: Option<FrameOf> = None;
    let truth_of: FrameOf = if let Some(path) = &args.volume {
        let flags = args.volume_args.as_volume_args();
        let (volume, tf, options) = volume_reference(path, &flags, &header)?;
        // A multi light field is held to its layers' ray casts composited with the same
        // opacities (lumigraph_core::volume::layers::reference_layers).
        let recorded_layers = header.provenance.bake_options.get("layers");
        if let (Some(layers), None) = (recorded_layers, &flags.tf) {
            // TF layers record their list, depth layers the whole split (an object).
            let text = if layers.is_object() {
                layers.to_string()
            } else {
                serde_json::json!({ "layers": layers }).to_string()
            };
            let layers =
                VolumeLayer::parse(&text, Path::new(".")).context("the asset's recorded layers")?;
            if args.floor {
                bail!("--floor measures a single-layer volume asset; this one has layers");
            }
            let opacities = plan.opacities().to_vec();
            Box::new(move |view| {
                Ok(reference_layers(
                    &volume, &layers, view, &options, &opacities,
                )?)
            })
        } else {
            if args.floor {
                let baker = VolumeBaker::new(gpu.clone());
                let direct = baker.prepare_direct(&volume, &tf, &options)?;
                direct_of = Some(Box::new(move |view| {
                    Ok(baker.render_view(&direct, view)?.to_frame())
                }));
            }
            Box::new(move |view| Ok(raycast(&volume, &tf, view, &options)?.to_frame()))
        }
    } else {
        if args.volume_args.as_volume_args().given() {
            bail!(
                "--tf, --labels, --shade, --ray-step, --depth-threshold and --spacing need --volume"
            );
        }
        let (mesh, _) = load_source(args.mesh.as_deref(), args.demo)?;
        let reference = ReferenceRenderer::new(gpu);
        let gpu_mesh = reference.upload(&mesh)?;
        Box::new(move |view| Ok(reference.render(&gpu_mesh, view, &bake_options.shading)?))
    };
    let field = renderer
        .upload(&asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    // Warm up: the first dispatch pays shader compilation.
    plan.render(&renderer, &field, &views[0])?;
    if let Some(direct_of) = &direct_of {
        direct_of(&views[0])?;
    }
    let bar = progress_bar(views.len() as u64, "evaluating views");
    let mut rows = Vec::with_capacity(views.len());
    for (index, view) in views.iter().enumerate() {
        let Rendered { frame, decision } = plan.render(&renderer, &field, view)?;
        let lod = decision.lod;
        let start = std::time::Instant::now();
        let truth = truth_of(view)?;
        let reference_ms = start.elapsed().as_secs_f64() * 1e3;
        let (floor, direct_ms) = match &direct_of {
            Some(direct_of) => {
                let start = std::time::Instant::now();
                let direct = direct_of(view)?;
                let ms = start.elapsed().as_secs_f64() * 1e3;
                (Some(metrics::compare(&direct, &truth)?), Some(ms))
            }
            None => (None, None),
        };
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
            footprint: truth.covered_count() as f64 / truth.pixel_count().max(1) as f64,
            lod,
            reference_ms,
            floor,
            direct_ms,
            comparison,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let comparisons: Vec<Comparison> = rows.iter().map(|r| r.comparison.clone()).collect();
    let mean_ms = rows.iter().map(|r| r.ms).sum::<f64>() / rows.len() as f64;
    let mean_fetches_per_pixel =
        rows.iter().map(|r| r.fetches_per_pixel).sum::<f64>() / rows.len() as f64;
    let floors: Vec<Comparison> = rows.iter().filter_map(|r| r.floor.clone()).collect();
    let direct: Vec<f64> = rows.iter().filter_map(|r| r.direct_ms).collect();
    let mean_reference_ms = rows.iter().map(|r| r.reference_ms).sum::<f64>() / rows.len() as f64;
    let report = EvalReport {
        mean_reference_ms,
        mean_floor: metrics::mean_comparison(&floors),
        mean_direct_ms: (!direct.is_empty())
            .then(|| direct.iter().sum::<f64>() / direct.len() as f64),
        asset: args.asset.display().to_string(),
        cameras: header.camera_count(),
        resolution: header.image_size()[0],
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
    println!(
        "reference render: {:.1} ms per view",
        report.mean_reference_ms
    );
    if let (Some(f), Some(ms)) = (&report.mean_floor, report.mean_direct_ms) {
        println!(
            "floor (direct GPU ray cast against the reference): masked PSNR {:.2} dB, PSNR {:.2} \
             dB, MAE {:.3}, {:.1} ms per view",
            f.masked_psnr, f.psnr, f.mae, ms
        );
    }
}

/// The volume, transfer function and ray-cast options of `eval --volume`: the flags where
/// given, else what the asset's provenance records of its bake.
fn volume_reference(
    path: &Path,
    flags: &VolumeArgs,
    header: &lumigraph_core::asset::AssetHeader,
) -> Result<(Volume, TransferFunction, RaycastOptions)> {
    let recorded = &header.provenance.bake_options;
    if recorded.get("source").and_then(serde_json::Value::as_str) != Some("volume")
        && flags.tf.is_none()
    {
        bail!("the asset was not baked from a volume: give --tf to compare it with one");
    }
    if flags.tf.is_some() {
        let shading = super::args::ShadingArgs::default();
        return flags.load(path, &shading);
    }
    let tf = recorded
        .get("tf")
        .map(|tf| TransferFunction::from_json(&tf.to_string()))
        .transpose()?
        .context("the asset records no transfer function: give --tf")?;
    let labels =
        flags.labels || recorded.get("labels").and_then(serde_json::Value::as_bool) == Some(true);
    let volume = Volume::load(
        path,
        &LoadOptions {
            labels,
            spacing: flags.spacing,
        },
    )
    .with_context(|| format!("cannot load {}", path.display()))?;
    let defaults = RaycastOptions::default();
    let number = |key: &str| recorded.get(key).and_then(serde_json::Value::as_f64);
    let options = RaycastOptions {
        step: flags.step.or_else(|| number("step")),
        shade: flags.shade
            || recorded.get("shade").and_then(serde_json::Value::as_bool) == Some(true),
        light: recorded
            .get("light")
            .and_then(|l| serde_json::from_value(l.clone()).ok())
            .unwrap_or(defaults.light),
        ambient: number("ambient").unwrap_or(defaults.ambient),
        depth_threshold: flags
            .depth_threshold
            .or_else(|| number("depth_threshold"))
            .unwrap_or(defaults.depth_threshold),
    };
    Ok((volume, tf, options))
}
