//! `lumigraph bench import`: the import of external renders (seed 000 §3.4) measured against a
//! direct bake. The mesh's reference renders (shading as given, shadows included) from the
//! directions of an icosphere camera set, perspective, around the bounding sphere, are written
//! as `import-views` reads them, imported, and the imported light field is scored beside a
//! direct bake of the mesh (same cameras, resolution and shading) on random orbit views against
//! the reference.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::{AssetFile, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker};
use lumigraph_core::geometry;
use lumigraph_core::import_views::{self, ImportOptions};
use lumigraph_core::metrics::{self, MeanComparison};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::evaluation_views;
use serde::Serialize;

use super::args::ShadingArgs;
use super::common::{gpu, load_source, progress_bar};

/// `lumigraph bench import`.
#[derive(Debug, Args)]
pub struct ImportArgs {
    /// Mesh (omit with --demo).
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// The built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// External views: the first N directions of the camera set (12, 42, 162), comma-separated
    /// counts to compare.
    #[arg(long, value_delimiter = ',', default_value = "12,42")]
    pub input_views: Vec<u32>,
    /// Side of the square external views in pixels.
    #[arg(long, default_value_t = 512)]
    pub input_size: u32,
    /// Cameras of the light fields.
    #[arg(long, default_value_t = 162)]
    pub cameras: u32,
    /// Map resolution of the light fields.
    #[arg(long, default_value_t = 256)]
    pub resolution: u32,
    /// Largest relative depth jump inside a relief surface.
    #[arg(long, default_value_t = import_views::DEFAULT_MAX_DEPTH_JUMP)]
    pub max_depth_jump: f32,
    /// Smallest |cos| between a relief surface and the ray to its view's eye: surfaces seen
    /// more obliquely are left to the views that see them better (0 keeps every surface).
    #[arg(long, default_value_t = import_views::DEFAULT_MIN_FACING, allow_hyphen_values = true)]
    pub min_facing: f32,
    /// Shading of the external renders (and of the direct bake and the reference).
    #[command(flatten)]
    pub shading: ShadingArgs,
    /// Random orbit views (DESIGN §3 evaluation views) for the scores.
    #[arg(long, default_value_t = 6)]
    pub views: usize,
    /// Side of the square evaluation views.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Seed of the evaluation views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the external renders here (default: a temporary folder).
    #[arg(long)]
    pub keep: Option<PathBuf>,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, Serialize)]
struct Row {
    /// External views imported (0: the direct bake).
    input_views: u32,
    relief_triangles: usize,
    build_ms: f64,
    bake_ms: f64,
    asset_bytes: u64,
    score: MeanComparison,
}

#[derive(Debug, Serialize)]
struct Report {
    source: String,
    adapter: String,
    cameras: u32,
    resolution: u32,
    input_size: u32,
    shadows: bool,
    rows: Vec<Row>,
}

pub(super) fn bench_import(args: &ImportArgs) -> Result<()> {
    if args.views == 0 || args.views > 100 {
        bail!("--views 1..=100");
    }
    if args.input_views.is_empty()
        || args
            .input_views
            .iter()
            .any(|n| !geometry::CAMERA_COUNTS[..3].contains(n))
    {
        bail!("--input-views: counts among 12, 42, 162");
    }
    let (mesh, source) = load_source(args.mesh.as_deref(), args.demo)?;
    let shading: Shading = args.shading.to_shading()?;
    let options = BakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        shading,
        ..BakeOptions::default()
    };
    options.validate()?;
    let gpu = gpu()?;
    let baker = Baker::new(gpu.clone());
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let gpu_mesh = reference.upload(&mesh)?;
    let sphere = mesh.bounding_sphere();
    let center = sphere.center;
    let radius = sphere.radius;
    let eval = evaluation_views(center.to_array(), radius, args.views, args.seed, args.size);
    let truths = eval
        .iter()
        .map(|v| reference.render(&gpu_mesh, v, &shading))
        .collect::<Result<Vec<_>, _>>()?;
    let score = |asset: &AssetFile| -> Result<MeanComparison> {
        let field = renderer.upload(asset)?;
        let mut out = Vec::new();
        for (view, truth) in eval.iter().zip(&truths) {
            let frame = renderer.render(&field, view, &RenderOptions::default())?;
            out.push(metrics::compare(&frame, truth)?);
        }
        metrics::mean_comparison(&out).context("no views")
    };
    let bar = progress_bar(args.input_views.len() as u64 + 1, "importing");
    let mut rows = Vec::new();
    let start = Instant::now();
    let direct = baker.bake_to_bytes(&mesh, &options, &Provenance::default(), &mut |_, _| {})?;
    let bake_ms = start.elapsed().as_secs_f64() * 1e3;
    let asset_bytes = direct.len() as u64;
    rows.push(Row {
        input_views: 0,
        relief_triangles: mesh.triangles.len(),
        build_ms: 0.0,
        bake_ms,
        asset_bytes,
        score: score(&AssetFile::from_bytes(direct)?)?,
    });
    bar.inc(1);
    let temp = std::env::temp_dir().join(format!("lumigraph-import-{}", std::process::id()));
    for &count in &args.input_views {
        let dir = match &args.keep {
            Some(keep) => keep.join(format!("views-{count}")),
            None => temp.join(format!("views-{count}")),
        };
        std::fs::create_dir_all(&dir)?;
        // Perspective views from the camera set's directions, 2.5 r away, 40° (the sphere
        // fills about 60 % of the height): what an external renderer would be asked for.
        let views = import_views::surround_views(center, radius, count as usize, args.input_size);
        for (i, view) in views.iter().enumerate() {
            let frame = reference.render(&gpu_mesh, view, &shading)?;
            lumigraph_core::image_io::write_png_rgba8(
                &dir.join(format!("{i:03}.png")),
                frame.width,
                frame.height,
                &frame.color,
            )?;
            lumigraph_core::image_io::write_depth_npy(
                &dir.join(format!("{i:03}.npy")),
                frame.width,
                frame.height,
                &frame.depth,
            )?;
        }
        std::fs::write(dir.join("views.json"), serde_json::to_vec_pretty(&views)?)?;
        let start = Instant::now();
        let images = import_views::read_views(&dir)?;
        let relief = import_views::relief_mesh(
            &images,
            &ImportOptions {
                max_depth_jump: args.max_depth_jump,
                min_facing: args.min_facing,
            },
        )?;
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        let unlit = BakeOptions {
            shading: Shading {
                unlit: true,
                ..Shading::default()
            },
            one_sided: true,
            color_codec: None,
            depth_codec: None,
            ..options
        };
        let start = Instant::now();
        let bytes = baker.bake_to_bytes(&relief, &unlit, &Provenance::default(), &mut |_, _| {})?;
        let bake_ms = start.elapsed().as_secs_f64() * 1e3;
        rows.push(Row {
            input_views: count,
            relief_triangles: relief.triangles.len(),
            build_ms,
            bake_ms,
            asset_bytes: bytes.len() as u64,
            score: score(&AssetFile::from_bytes(bytes)?)?,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    if args.keep.is_none() {
        let _ = std::fs::remove_dir_all(&temp);
    }
    let report = Report {
        source: source.source_name,
        adapter: gpu.adapter_summary(),
        cameras: args.cameras,
        resolution: args.resolution,
        input_size: args.input_size,
        shadows: shading.shadows,
        rows,
    };
    println!(
        "{}: {} cameras × {} px, external views {}², shadows {}, on {}",
        report.source,
        report.cameras,
        report.resolution,
        report.input_size,
        report.shadows,
        report.adapter
    );
    println!("input      triangles  build ms  bake ms  MiB   masked  ∩ masks  wrong px  SSIM");
    for r in &report.rows {
        let name = if r.input_views == 0 {
            "direct".to_owned()
        } else {
            format!("{} views", r.input_views)
        };
        println!(
            "{:<9} {:>10}  {:>8.0}  {:>7.0}  {:>4.1}  {:>6.2}  {:>7.2}  {:>8.0}  {:.4}",
            name,
            r.relief_triangles,
            r.build_ms,
            r.bake_ms,
            r.asset_bytes as f64 / 1_048_576.0,
            r.score.masked_psnr,
            r.score.intersection_psnr,
            r.score.wrong_surface_px,
            r.score.ssim
        );
    }
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &json))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
