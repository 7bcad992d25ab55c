//! The `lumigraph` command line: `bake`, `render`, `reference`, `eval`, `info`, `bench` (and
//! `serve`).
//!
//! Every command validates its input before touching the GPU and reports any failure as one
//! line (`error: …`) with a non-zero exit status; nothing here panics on bad input.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use lumigraph_core::asset::{AssetFile, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker, sha256_hex};
use lumigraph_core::calibration::{self, Calibration, Choice, Goal};
use lumigraph_core::frame::Frame;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::lod::{Ladder, Level, LodDecision, LodPolicy};
use lumigraph_core::mesh::{Mesh, demo_mesh, load_mesh};
use lumigraph_core::metrics::{self, Comparison};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{Method, RenderOptions, Renderer};
use lumigraph_core::scene::Scene;
use lumigraph_core::shading::Shading;
use lumigraph_core::tradeoff::{self, Grid, SweepInputs};
use lumigraph_core::view::{View, random_orbit_views};

mod plot;

/// lumigraph: bake, render, evaluate and serve light fields.
#[derive(Debug, Parser)]
#[command(name = "lumigraph", version, about, propagate_version = true)]
pub struct Cli {
    /// The command.
    #[command(subcommand)]
    pub command: Command,
}

/// Commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Bake a mesh (glTF/GLB, OBJ, PLY, STL, OFF) or the built-in demo into a spherical light field.
    Bake(BakeArgs),
    /// Render views of a light-field asset.
    Render(RenderArgs),
    /// Rasterize a mesh directly with the same view and shading (ground truth).
    Reference(ReferenceArgs),
    /// Compare light-field renders against reference renders of the source mesh.
    Eval(EvalArgs),
    /// Print an asset's header (and verify every page).
    Info(InfoArgs),
    /// Benchmarks: `bench tradeoff` sweeps the quality knobs (speed against accuracy).
    Bench(BenchArgs),
    /// Serve the HTTP/WebSocket render service and the web viewer (bakes the demo on first start).
    Serve(ServeArgs),
}

/// `lumigraph serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Folder of `.lfa` assets (created if missing; the demo is baked into it when empty).
    #[arg(long, default_value = "assets")]
    pub assets: PathBuf,
    /// Address to listen on (without LUMIGRAPH_TOKEN only loopback addresses are allowed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: std::net::SocketAddr,
    /// Most concurrent WebSocket sessions.
    #[arg(long, default_value_t = 64)]
    pub max_sessions: usize,
    /// Largest rendered width or height in pixels.
    #[arg(long, default_value_t = 4096)]
    pub max_px: u32,
}

/// Shading flags shared by `bake` and `reference` (DESIGN §3).
#[derive(Debug, Args, Clone)]
pub struct ShadingArgs {
    /// Light direction X,Y,Z (world space; normalized).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light: Option<[f32; 3]>,
    /// Ambient term in [0, 1].
    #[arg(long, allow_hyphen_values = true)]
    pub ambient: Option<f32>,
    /// Specular term KS,SHININESS.
    #[arg(long, value_parser = parse_pair, allow_hyphen_values = true)]
    pub specular: Option<(f32, f32)>,
    /// Unlit: colour = albedo.
    #[arg(long)]
    pub unlit: bool,
}

impl ShadingArgs {
    fn to_shading(&self) -> Result<Shading> {
        let mut shading = Shading::default();
        if let Some(light) = self.light {
            shading.light = light;
        }
        if let Some(ambient) = self.ambient {
            shading.ambient = ambient;
        }
        shading.specular = self.specular;
        shading.unlit = self.unlit;
        shading.validate()?;
        Ok(shading)
    }
}

/// `lumigraph bake`.
#[derive(Debug, Args)]
pub struct BakeArgs {
    /// Mesh file (omit with --demo).
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// Bake the built-in demo scene (a trefoil-knot tube).
    #[arg(long)]
    pub demo: bool,
    /// Output asset (.lfa).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Cameras: 12, 42, 162 or 642.
    #[arg(long, default_value_t = 162, allow_hyphen_values = true)]
    pub cameras: u32,
    /// Parabolic map resolution in pixels.
    #[arg(long, default_value_t = 256, allow_hyphen_values = true)]
    pub resolution: u32,
    /// Depth precision: 8 or 16 bits.
    #[arg(long, default_value_t = 16, allow_hyphen_values = true)]
    pub depth_bits: u8,
    /// Shading.
    #[command(flatten)]
    pub shading: ShadingArgs,
    /// Skip the calibration (error against cost of this scene, stored in the asset's quality
    /// report for `render --target-psnr / --budget-ms`; a few seconds on lavapipe).
    #[arg(long)]
    pub no_calibrate: bool,
}

/// One view file or a list of views.
#[derive(Debug, Args)]
#[group(required = true, multiple = false)]
pub struct ViewArgs {
    /// A JSON view (DESIGN §3).
    #[arg(long)]
    pub view: Option<PathBuf>,
    /// A JSON list of views; OUT becomes a folder of 000.png, 001.png, …
    #[arg(long)]
    pub views: Option<PathBuf>,
}

/// Quality knobs of `render` and `eval`.
#[derive(Debug, Args, Clone)]
pub struct QualityArgs {
    /// Cameras to use (12, 42, 162, 642; at most the asset's).
    #[arg(long, allow_hyphen_values = true)]
    pub lod: Option<u32>,
    /// Step in bounding-sphere diameters.
    #[arg(long, allow_hyphen_values = true)]
    pub step: Option<f32>,
    /// Tolerance in bounding-sphere diameters (default step/2).
    #[arg(long, allow_hyphen_values = true)]
    pub tolerance: Option<f32>,
    /// Marching method: default or fixed.
    #[arg(long, default_value = "default")]
    pub method: Method,
    /// Coarse-to-fine factor of the default method (2–16; 0 = off; default 4): a coarse pass
    /// renders every F-th pixel per axis and bounds each pixel's march (4: 0.22–0.38× the
    /// unguided time at 512², same masked PSNR on the fixtures).
    #[arg(long, value_name = "F", allow_hyphen_values = true)]
    pub guide: Option<u32>,
    /// Pick the cheapest setting the asset's calibration predicts to reach this masked PSNR (dB).
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["lod", "step", "tolerance", "method", "budget_ms"])]
    pub target_psnr: Option<f64>,
    /// Pick the most accurate setting the calibration predicts to render within this time (ms).
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["lod", "step", "tolerance", "method"])]
    pub budget_ms: Option<f64>,
    /// Automatic LOD: per view, the cheapest cameras and step whose calibrated silhouette error
    /// at the object's projected size stays under PX pixels (`--auto-lod` = 1 px); a --lod or
    /// --step given as well is kept. Cross-fades near switches (no popping).
    #[arg(long, value_name = "PX", num_args = 0..=1, require_equals = true, default_missing_value = "1", allow_hyphen_values = true, conflicts_with_all = ["target_psnr", "budget_ms"])]
    pub auto_lod: Option<f64>,
    /// With --auto-lod: only settings whose calibrated masked PSNR reaches DB.
    #[arg(
        long,
        value_name = "DB",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_min_psnr: Option<f64>,
    /// With --auto-lod: only settings within DB of the most accurate level's calibrated masked
    /// PSNR (default 2; inf: no limit).
    #[arg(
        long,
        value_name = "DB",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_max_psnr_drop: Option<f64>,
    /// With --auto-lod: cross-fade band below each switch, as a fraction of the projected size
    /// (default 0.15; 0 = hard switches).
    #[arg(
        long,
        value_name = "FRACTION",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_blend: Option<f64>,
}

impl QualityArgs {
    /// The goal (`--target-psnr` / `--budget-ms`, exclusive by clap) with the asset's
    /// calibration, read once; an error says how to get a calibration.
    fn goal(&self, asset: &AssetFile) -> Result<Option<(Goal, Calibration)>> {
        let Some(goal) = Goal::from_pair(self.target_psnr, self.budget_ms)? else {
            return Ok(None);
        };
        let calibration = calibration_for(asset, "--target-psnr / --budget-ms need")?;
        Ok(Some((goal, calibration)))
    }

    /// The automatic-LOD ladder (`--auto-lod`) of the asset's calibration, if asked for.
    fn ladder(&self, asset: &AssetFile) -> Result<Option<Ladder>> {
        // clap already refuses the floors without --auto-lod and --auto-lod with a goal.
        let Some(policy) = LodPolicy::from_parts(
            self.auto_lod,
            self.lod_min_psnr,
            self.lod_max_psnr_drop,
            self.lod_blend,
            false,
        )?
        else {
            return Ok(None);
        };
        Ok(Some(Ladder::new(
            &calibration_for(asset, "--auto-lod needs")?,
            &policy,
            asset.header().geometry.camera_count,
            &self.options(),
        )?))
    }

    fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: self.lod,
            step: self.step,
            tolerance: self.tolerance,
            method: self.method,
            guide: self.guide,
        }
    }
}

/// Depth output flags.
#[derive(Debug, Args)]
pub struct DepthArgs {
    /// Write depth (.npy or .exr; with --views a folder of 000.npy, …).
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Depth format inside a --depth folder: npy or exr.
    #[arg(long, default_value = "npy", value_parser = ["npy", "exr"])]
    pub depth_format: String,
}

/// `lumigraph render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Light-field asset (.lfa), or a scene (.json: light-field instances and meshes, each
    /// with its own transform, composited by depth; docs/scene.md).
    pub asset: PathBuf,
    /// Views.
    #[command(flatten)]
    pub views: ViewArgs,
    /// Output PNG (or folder with --views).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Depth output.
    #[command(flatten)]
    pub depth: DepthArgs,
    /// Quality knobs.
    #[command(flatten)]
    pub quality: QualityArgs,
}

/// `lumigraph reference`.
#[derive(Debug, Args)]
pub struct ReferenceArgs {
    /// Mesh file (omit with --demo).
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// Use the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// Views.
    #[command(flatten)]
    pub views: ViewArgs,
    /// Output PNG (or folder with --views).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Depth output.
    #[command(flatten)]
    pub depth: DepthArgs,
    /// Shading.
    #[command(flatten)]
    pub shading: ShadingArgs,
}

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
    /// Quality knobs.
    #[command(flatten)]
    pub quality: QualityArgs,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// `lumigraph bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// The benchmark.
    #[command(subcommand)]
    pub command: BenchCommand,
}

/// Benchmarks.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Sweep cameras × step × tolerance × method × depth bits × output size against the source
    /// mesh; write tradeoff.csv, tradeoff.json and pareto.png (ms/frame against masked PSNR).
    Tradeoff(TradeoffArgs),
}

/// `lumigraph bench tradeoff`. Lists are comma-separated; steps accept fractions (`1/32`).
#[derive(Debug, Args)]
pub struct TradeoffArgs {
    /// Light-field asset (.lfa).
    pub asset: PathBuf,
    /// Source mesh of the asset.
    #[arg(long, required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// The asset was baked from the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// Output folder (default out/tradeoff/ASSET_STEM).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Random orbit views per setting.
    #[arg(long, default_value_t = 4)]
    pub views: usize,
    /// Seed of the random views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Renders per view and setting; the fastest is timed.
    #[arg(long, default_value_t = 1)]
    pub repeats: u32,
    /// Camera counts (default: 12 up to the asset's).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub cameras: Option<Vec<u32>>,
    /// Steps in bounding diameters (default 1/16,1/32,1/64).
    #[arg(long, value_delimiter = ',', value_parser = parse_fraction, allow_hyphen_values = true)]
    pub steps: Option<Vec<f32>>,
    /// Tolerances as multiples of the step (default 0.5,1).
    #[arg(long, value_delimiter = ',', value_parser = parse_fraction, allow_hyphen_values = true)]
    pub tolerances: Option<Vec<f32>>,
    /// Methods (default default,fixed).
    #[arg(long, value_delimiter = ',')]
    pub methods: Option<Vec<Method>>,
    /// Coarse-to-fine factors of the default method (default 4; 0 = off; e.g. 0,4).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub guides: Option<Vec<u32>>,
    /// Depth bits (default 16,8 for a 16-bit asset).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub depth_bits: Option<Vec<u8>>,
    /// Output sizes in pixels, square (default 256,512).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub sizes: Option<Vec<u32>>,
}

/// `lumigraph info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Light-field asset (.lfa).
    pub asset: PathBuf,
}

fn parse_floats(s: &str, n: usize) -> Result<Vec<f32>, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != n {
        return Err(format!("expected {n} comma-separated numbers, got `{s}`"));
    }
    parts
        .iter()
        .map(|p| match p.parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(format!("`{p}` is not a finite number")),
        })
        .collect()
}

/// A finite number or a fraction `a/b`.
fn parse_fraction(s: &str) -> Result<f32, String> {
    let value = match s.split_once('/') {
        Some((a, b)) => {
            let a: f64 = a
                .trim()
                .parse()
                .map_err(|_| format!("`{s}` is not a number"))?;
            let b: f64 = b
                .trim()
                .parse()
                .map_err(|_| format!("`{s}` is not a number"))?;
            a / b
        }
        None => s
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("`{s}` is not a number"))?,
    };
    if value.is_finite() {
        Ok(value as f32)
    } else {
        Err(format!("`{s}` is not a finite number"))
    }
}

fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let v = parse_floats(s, 3)?;
    Ok([v[0], v[1], v[2]])
}

fn parse_pair(s: &str) -> Result<(f32, f32), String> {
    let v = parse_floats(s, 2)?;
    Ok((v[0], v[1]))
}

/// Runs a parsed command.
///
/// # Errors
/// Any failure, with context, for `main` to print as one line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Bake(args) => bake(&args),
        Command::Render(args) => render(&args),
        Command::Reference(args) => reference(&args),
        Command::Eval(args) => eval(&args),
        Command::Info(args) => info(&args),
        Command::Bench(args) => match args.command {
            BenchCommand::Tradeoff(args) => bench_tradeoff(&args),
        },
        Command::Serve(args) => serve(&args),
    }
}

fn gpu() -> Result<Arc<Gpu>> {
    Ok(Gpu::shared()?)
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    let style = ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ({elapsed}, eta {eta})")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar.set_message(what.to_owned());
    bar
}

/// Loads the mesh argument or the demo, with provenance.
fn load_source(mesh: Option<&Path>, demo: bool) -> Result<(Mesh, Provenance)> {
    if demo || mesh.is_none() {
        let mesh = demo_mesh()?;
        let bytes = bytemuck_positions(&mesh);
        return Ok((
            mesh,
            Provenance {
                source_name: "demo:trefoil".to_owned(),
                source_sha256: sha256_hex(&bytes),
                ..Default::default()
            },
        ));
    }
    let path = mesh.unwrap_or(Path::new(""));
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mesh = load_mesh(path)?;
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    Ok((
        mesh,
        Provenance {
            source_name: name,
            source_sha256: sha256_hex(&bytes),
            ..Default::default()
        },
    ))
}

fn bytemuck_positions(mesh: &Mesh) -> Vec<u8> {
    mesh.positions
        .iter()
        .flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes()))
        .collect()
}

fn bake(args: &BakeArgs) -> Result<()> {
    let options = BakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        shading: args.shading.to_shading()?,
        depth_bits: args.depth_bits,
    };
    options.validate()?;
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let baker = Baker::new(gpu.clone());
    let bar = progress_bar(u64::from(options.cameras), "baking cameras");
    if !args.no_calibrate {
        return bake_calibrated(args, &options, &mesh, &provenance, &baker, &gpu, &bar);
    }
    let report = baker.bake_to_file(
        &mesh,
        &options,
        &provenance,
        &args.output,
        &mut |done, _| bar.set_position(u64::from(done)),
    )?;
    bar.finish_and_clear();
    println!(
        "baked {} cameras at {} px from {} triangles in {:.0} ms: {} ({:.1} MiB)",
        report.cameras,
        report.resolution,
        report.triangles,
        report.bake_ms,
        args.output.display(),
        report.asset_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}

/// Bakes in memory, measures the scene's calibration (calibration::Calibration) and writes the
/// asset with it in the quality report, atomically.
fn bake_calibrated(
    args: &BakeArgs,
    options: &BakeOptions,
    mesh: &Mesh,
    provenance: &Provenance,
    baker: &Baker,
    gpu: &Arc<Gpu>,
    bar: &ProgressBar,
) -> Result<()> {
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let baked = calibration::bake_calibrated(
        baker,
        &renderer,
        &reference,
        mesh,
        options,
        provenance,
        &mut |done, total| {
            bar.set_position(u64::from(done));
            if done == total {
                bar.set_message("calibrating error against cost");
            }
        },
    )?;
    bar.finish_and_clear();
    lumigraph_core::atomic_write(&args.output, |w| std::io::Write::write_all(w, &baked.bytes))
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    println!(
        "baked {} cameras at {} px from {} triangles in {:.0} ms, calibrated {} settings in {:.0} ms: {} ({:.1} MiB)",
        options.cameras,
        options.resolution,
        mesh.triangles.len(),
        baked.bake_ms,
        baked.calibration.points.len(),
        baked.calibrate_ms,
        args.output.display(),
        baked.bytes.len() as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}

/// The asset's calibration, or an error that starts with `flags_need` and says how to get one.
fn calibration_for(asset: &AssetFile, flags_need: &str) -> Result<Calibration> {
    Calibration::from_quality(asset.header().quality.as_ref())?.ok_or_else(|| {
        anyhow::anyhow!(
            "{flags_need} the asset's calibration, which this asset lacks (baked with \
             --no-calibrate, by the Python API or the service): re-bake it with `lumigraph bake`"
        )
    })
}

/// The calibrated choice for `goal` at the view's size.
fn choose(
    asset: &AssetFile,
    (goal, calibration): &(Goal, Calibration),
    view: &View,
) -> Result<Choice> {
    Ok(calibration.choose(
        *goal,
        view.width,
        view.height,
        asset.header().geometry.camera_count,
    )?)
}

fn describe(choice: &Choice) -> String {
    format!(
        "chose {} cameras, step 1/{:.0} (default method): predicted masked PSNR {:.2} dB, {:.1} ms{}",
        choice.cameras,
        1.0 / choice.step,
        choice.predicted_psnr,
        choice.predicted_ms,
        if choice.met {
            ""
        } else {
            " (no calibrated setting meets the goal: the closest one)"
        }
    )
}

fn describe_level(level: &Level) -> String {
    format!("{} cameras, step 1/{:.0}", level.cameras, 1.0 / level.step)
}

fn describe_lod(d: &LodDecision, pixels: u64) -> String {
    let blend = match d.blend {
        Some((next, w)) => format!(
            ", cross-fading {:.0} % into {}",
            100.0 * w,
            describe_level(&next)
        ),
        None => String::new(),
    };
    format!(
        "auto LOD: object {:.0} px across → {}{blend}: predicted silhouette error {:.2} px{}, \
         masked PSNR {:.2} dB, {:.1} ms",
        d.projected_px,
        describe_level(&d.level),
        d.error_px,
        if d.met {
            ""
        } else {
            " (no setting meets the bound: the most accurate)"
        },
        d.level.masked_psnr,
        d.predicted_ms(pixels)
    )
}

/// Reads `--view` / `--views`; returns the views and whether OUT is a folder.
fn read_views(args: &ViewArgs) -> Result<(Vec<View>, bool)> {
    let (path, many) = match (&args.view, &args.views) {
        (Some(p), _) => (p, false),
        (None, Some(p)) => (p, true),
        (None, None) => bail!("give --view VIEW.json or --views VIEWS.json"),
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read view file {}", path.display()))?;
    let views =
        View::parse_many(&text).with_context(|| format!("bad view file {}", path.display()))?;
    if views.is_empty() {
        bail!("{} holds no views", path.display());
    }
    if !many && views.len() != 1 {
        bail!(
            "{} holds {} views: use --views for a list",
            path.display(),
            views.len()
        );
    }
    for (i, v) in views.iter().enumerate() {
        v.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)
            .with_context(|| format!("view {i} in {}", path.display()))?;
    }
    Ok((views, many))
}

fn write_outputs(
    frame: &Frame,
    index: usize,
    many: bool,
    output: &Path,
    depth: &DepthArgs,
) -> Result<()> {
    let (color_path, depth_path) = if many {
        std::fs::create_dir_all(output)
            .with_context(|| format!("cannot create {}", output.display()))?;
        let depth_path = match &depth.depth {
            Some(dir) => {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
                Some(dir.join(format!("{index:03}.{}", depth.depth_format)))
            }
            None => None,
        };
        (output.join(format!("{index:03}.png")), depth_path)
    } else {
        (output.to_path_buf(), depth.depth.clone())
    };
    lumigraph_core::image_io::write_png_rgba8(&color_path, frame.width, frame.height, &frame.color)
        .with_context(|| format!("cannot write {}", color_path.display()))?;
    if let Some(path) = depth_path {
        lumigraph_core::image_io::write_depth(&path, frame.width, frame.height, &frame.depth)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

fn check_depth_path(depth: &DepthArgs, many: bool) -> Result<()> {
    if let (Some(path), false) = (&depth.depth, many) {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if ext != "npy" && ext != "exr" {
            bail!("--depth {}: use a .npy or .exr path", path.display());
        }
    }
    Ok(())
}

fn render(args: &RenderArgs) -> Result<()> {
    let (views, many) = read_views(&args.views)?;
    check_depth_path(&args.depth, many)?;
    if args
        .asset
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return render_scene(args, &views, many);
    }
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let options = args.quality.options();
    options.resolve(u32::from(asset.header().geometry.camera_level))?;
    let renderer = Renderer::new(gpu()?);
    let field = renderer
        .upload(&asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    let goal = args.quality.goal(&asset)?;
    let ladder = args.quality.ladder(&asset)?;
    for (i, view) in views.iter().enumerate() {
        if let Some(ladder) = &ladder {
            let (frame, decision) = ladder.render_auto(&renderer, &field, view)?;
            write_outputs(&frame, i, many, &args.output, &args.depth)?;
            println!(
                "view {i:03}: {}; measured {:.2} ms ({} px covered)",
                describe_lod(&decision, u64::from(view.width) * u64::from(view.height)),
                frame.stats.render_ms,
                frame.covered_count()
            );
            continue;
        }
        let choice = goal.as_ref().map(|g| choose(&asset, g, view)).transpose()?;
        let options = choice.map_or(options, |c| c.options());
        let frame = renderer.render(&field, view, &options)?;
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        match choice {
            Some(c) => println!(
                "view {i:03}: {}; measured {:.2} ms ({} px covered)",
                describe(&c),
                frame.stats.render_ms,
                frame.covered_count()
            ),
            None => println!(
                "view {i:03}: {:.2} ms ({} px covered)",
                frame.stats.render_ms,
                frame.covered_count()
            ),
        }
    }
    Ok(())
}

fn render_scene(args: &RenderArgs, views: &[View], many: bool) -> Result<()> {
    let q = &args.quality;
    if q.lod.is_some()
        || q.step.is_some()
        || q.tolerance.is_some()
        || q.method != Method::Default
        || q.auto_lod.is_some()
    {
        bail!(
            "quality flags do not apply to a scene: set \"options\" per light-field object in {}",
            args.asset.display()
        );
    }
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu);
    let scene = Scene::load(&args.asset, &renderer, &reference)?;
    println!(
        "scene {}: {} objects, {} light-field assets and {} meshes on the GPU",
        args.asset.display(),
        scene.objects(),
        scene.uploaded_fields(),
        scene.uploaded_meshes()
    );
    for (i, view) in views.iter().enumerate() {
        let frame = scene.render(&renderer, &reference, view)?;
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        println!(
            "view {i:03}: {:.2} ms ({} px covered)",
            frame.stats.render_ms,
            frame.covered_count()
        );
    }
    Ok(())
}

fn reference(args: &ReferenceArgs) -> Result<()> {
    let shading = args.shading.to_shading()?;
    let (views, many) = read_views(&args.views)?;
    check_depth_path(&args.depth, many)?;
    let (mesh, _) = load_source(args.mesh.as_deref(), args.demo)?;
    let renderer = ReferenceRenderer::new(gpu()?);
    let gpu_mesh = renderer.upload(&mesh)?;
    for (i, view) in views.iter().enumerate() {
        let frame = renderer.render(&gpu_mesh, view, &shading)?;
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        println!(
            "view {i:03}: {:.2} ms ({} px covered)",
            frame.stats.render_ms,
            frame.covered_count()
        );
    }
    Ok(())
}

/// Default eval views: eye on a sphere of 2.5× the bounding radius, looking at the centre.
fn eval_views(args: &EvalArgs, asset: &AssetFile) -> Result<Vec<View>> {
    if let Ok(n) = args.views.parse::<usize>() {
        if n == 0 || n > 10_000 {
            bail!("--views {n}: give 1 to 10000 random views or a JSON file");
        }
        if args.size == 0 || args.size > 4096 {
            bail!("--size {}: give 1 to 4096 pixels", args.size);
        }
        let frame = &asset.header().frame;
        return Ok(random_orbit_views(
            frame.center,
            2.5 * frame.radius,
            n,
            args.seed,
            40.0,
            args.size,
        ));
    }
    let path = Path::new(&args.views);
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read view file {}", path.display()))?;
    let views =
        View::parse_many(&text).with_context(|| format!("bad view file {}", path.display()))?;
    if views.is_empty() {
        bail!("{} holds no views", path.display());
    }
    Ok(views)
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

fn eval(args: &EvalArgs) -> Result<()> {
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let header = asset.header().clone();
    let views = eval_views(args, &asset)?;
    for (i, v) in views.iter().enumerate() {
        v.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)
            .with_context(|| format!("view {i}"))?;
    }
    // With a goal, the calibration chooses (for the first view's size) and the report sets
    // the prediction beside the measurement.
    let choice = match args.quality.goal(&asset)? {
        Some(goal) => Some(choose(&asset, &goal, &views[0])?),
        None => None,
    };
    let ladder = args.quality.ladder(&asset)?;
    let options = choice.map_or_else(|| args.quality.options(), |c| c.options());
    let settings = options.resolve(u32::from(header.geometry.camera_level))?;
    // The reference must shade exactly as the bake did.
    let bake_options: BakeOptions =
        serde_json::from_value(header.provenance.bake_options.clone()).unwrap_or_default();
    let (mesh, _) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu);
    let field = renderer
        .upload(&asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    let gpu_mesh = reference.upload(&mesh)?;
    // Warm up: the first dispatch pays shader compilation.
    renderer.render(&field, &views[0], &options)?;
    let bar = progress_bar(views.len() as u64, "evaluating views");
    let mut rows = Vec::with_capacity(views.len());
    for (index, view) in views.iter().enumerate() {
        let (frame, lod) = match &ladder {
            Some(ladder) => {
                let (frame, decision) = ladder.render_auto(&renderer, &field, view)?;
                (frame, Some(decision))
            }
            None => (renderer.render(&field, view, &options)?, None),
        };
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

/// What `bench tradeoff` writes beside the CSV.
#[derive(Debug, serde::Serialize)]
struct TradeoffReport<'a> {
    asset: String,
    source: String,
    adapter: String,
    date_unix_s: u64,
    views: usize,
    seed: u64,
    repeats: u32,
    grid: &'a Grid,
    points: &'a [tradeoff::Point],
}

fn bench_tradeoff(args: &TradeoffArgs) -> Result<()> {
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let header = asset.header().clone();
    let defaults = Grid::default_for(&asset);
    let grid = Grid {
        cameras: args.cameras.clone().unwrap_or(defaults.cameras),
        steps: args.steps.clone().unwrap_or(defaults.steps),
        tolerance_factors: args
            .tolerances
            .clone()
            .unwrap_or(defaults.tolerance_factors),
        methods: args.methods.clone().unwrap_or(defaults.methods),
        guides: args.guides.clone().unwrap_or(defaults.guides),
        depth_bits: args.depth_bits.clone().unwrap_or(defaults.depth_bits),
        sizes: args.sizes.clone().unwrap_or(defaults.sizes),
    };
    grid.validate(&asset)?;
    if args.views == 0 || args.views > 1000 {
        bail!("--views {}: give 1 to 1000", args.views);
    }
    if args.repeats == 0 || args.repeats > 100 {
        bail!("--repeats {}: give 1 to 100", args.repeats);
    }
    let stem = args
        .asset
        .file_stem()
        .map_or_else(|| "asset".to_owned(), |s| s.to_string_lossy().into_owned());
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("out/tradeoff").join(&stem));
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let bake_options: BakeOptions =
        serde_json::from_value(header.provenance.bake_options.clone()).unwrap_or_default();
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let frame = &header.frame;
    let views = random_orbit_views(
        frame.center,
        2.5 * frame.radius,
        args.views,
        args.seed,
        40.0,
        1,
    );
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let gpu_mesh = reference.upload(&mesh)?;
    let inputs = SweepInputs {
        renderer: &renderer,
        reference: &reference,
        asset: &asset,
        mesh: &gpu_mesh,
        shading: &bake_options.shading,
        views: &views,
        repeats: args.repeats,
    };
    let bar = progress_bar(grid.len() as u64, "sweeping settings");
    let points = tradeoff::sweep(&inputs, &grid, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    let csv = out.join("tradeoff.csv");
    tradeoff::write_csv(&csv, &points)?;
    let report = TradeoffReport {
        asset: args.asset.display().to_string(),
        source: provenance.source_name.clone(),
        adapter: gpu.adapter_summary(),
        date_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        views: args.views,
        seed: args.seed,
        repeats: args.repeats,
        grid: &grid,
        points: &points,
    };
    let json_path = out.join("tradeoff.json");
    let json = serde_json::to_vec_pretty(&report)?;
    lumigraph_core::atomic_write(&json_path, |w| std::io::Write::write_all(w, &json))
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    let png = out.join("pareto.png");
    let title = format!(
        "{stem}: {} cameras, {} px maps, {} views/setting — speed against accuracy",
        header.geometry.camera_count, header.geometry.resolution_px, args.views
    );
    plot::pareto_png(&png, &title, &points)?;
    let mut front: Vec<&tradeoff::Point> = points.iter().filter(|p| p.pareto).collect();
    front.sort_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame));
    println!(
        "{} settings on {}; Pareto front (ms per frame ↑, masked PSNR ↑):",
        points.len(),
        gpu.adapter_summary()
    );
    println!(
        "cameras  step     tol/step  method   bits  size  ms/frame  fetches/px  masked_psnr  ssim"
    );
    for p in front {
        let s = &p.setting;
        println!(
            "{:>7}  1/{:<5.0}  {:>8.2}  {:<7}  {:>4}  {:>4}  {:>8.1}  {:>10.1}  {:>11.2}  {:.4}",
            s.cameras,
            1.0 / s.step,
            s.tolerance / s.step,
            s.method,
            s.depth_bits,
            s.size,
            p.ms_per_frame,
            p.fetches_per_pixel,
            p.masked_psnr,
            p.ssim
        );
    }
    println!(
        "wrote {}, {} and {}",
        csv.display(),
        json_path.display(),
        png.display()
    );
    Ok(())
}

fn info(args: &InfoArgs) -> Result<()> {
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    // Every page's checksum is verified, so `info` doubles as an integrity check.
    asset
        .verify_all()
        .with_context(|| format!("asset {} is corrupt", args.asset.display()))?;
    let h = asset.header();
    println!(
        "{}: lumigraph asset v{}, {} bytes, all page checksums ok",
        args.asset.display(),
        h.format_version,
        asset.file_len()
    );
    println!(
        "spherical light field: {} cameras (level {}), {}×{} px parabolic maps",
        h.geometry.camera_count,
        h.geometry.camera_level,
        h.geometry.resolution_px,
        h.geometry.resolution_px
    );
    println!(
        "bounding sphere: centre {:?}, radius {}",
        h.frame.center, h.frame.radius
    );
    println!(
        "source: {} ({} triangles), baked in {:.0} ms",
        h.provenance.source_name, h.provenance.triangles, h.provenance.bake_ms
    );
    println!("{}", serde_json::to_string_pretty(h)?);
    Ok(())
}

fn serve(args: &ServeArgs) -> Result<()> {
    let mut config = crate::service::ServeConfig::from_env(&args.assets, args.addr);
    config.max_sessions = args.max_sessions;
    config.max_px = args.max_px;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(crate::service::serve(config))
}
