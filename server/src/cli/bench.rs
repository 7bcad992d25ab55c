//! `lumigraph bench tradeoff`: the quality knobs swept, speed against accuracy.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use lumigraph_core::asset::AssetFile;
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{Method, Renderer};
use lumigraph_core::tradeoff::{self, Grid, SweepInputs};
use lumigraph_core::view::evaluation_views;

use super::args::parse_fraction;
use super::common::{gpu, load_source, progress_bar};
use super::plot;

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
    /// Relight an asset baked with --lights at proxy directions, proxy-triangle centres and
    /// random lights against the reference with that light (the error split into the light
    /// field's and the light interpolation's, planar weights beside), and time relit frames
    /// against static ones.
    Lights(super::bench_lights::LightsArgs),
    /// Dent a mesh by given depths and bake the dents as deformation states: the fraction of
    /// pages each stores (with the bake-noise controls: the mesh unchanged and reordered), and
    /// each state's quality against the dented mesh beside a plain bake of it.
    States(super::bench_states::StatesArgs),
    /// Render a mesh's reference from the camera set's directions, import the renders
    /// (`import-views`) and score the imported light field beside a direct bake.
    Import(super::bench_import::ImportArgs),
    /// Playback cost of an asset baked with --animation: frames rendered in turn against the
    /// static frame, interleaved.
    Animation(super::bench_animation::AnimationArgs),
    /// Capture a mesh into two-plane light fields (uv grids × st resolutions) and score every
    /// uv filter against the reference over the valid region from views beyond the uv plane,
    /// with pinhole, 5×5-aperture and accumulated full-aperture timings.
    TwoPlane(super::bench_two_plane::TwoPlaneArgs),
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

pub(super) fn bench_tradeoff(args: &TradeoffArgs) -> Result<()> {
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
    let bake_options = BakeOptions::of(&header);
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let frame = &header.frame;
    let views = evaluation_views(frame.center, frame.radius, args.views, args.seed, 1);
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
        header.camera_count(),
        header.image_size()[0],
        args.views
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
