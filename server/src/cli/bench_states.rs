//! `lumigraph bench states`: deformation states of a mesh. Dents of given depths (fractions of
//! the bounding radius) are baked as states of the mesh, with two controls that measure the
//! bake's noise (the mesh itself, and the mesh with its triangles in reverse order, which
//! rebuilds the BVH); reported: the fraction of pages each state stores at each page size, and
//! each dent's render quality against the reference of the dented mesh beside a plain bake of
//! the dented mesh with the same settings.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::{AssetFile, Channel, ImageKey, Provenance};
use lumigraph_core::bake::{BakeOptions, Baker, StateBake};
use lumigraph_core::deform::{self, StateMesh};
use lumigraph_core::glam::Vec3;
use lumigraph_core::mesh::Mesh;
use lumigraph_core::metrics::{self, MeanComparison};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer};
use lumigraph_core::view::evaluation_views;
use serde::Serialize;

use super::args::ShadingArgs;
use super::common::{gpu, load_source, progress_bar};

/// `lumigraph bench states`.
#[derive(Debug, Args)]
pub struct StatesArgs {
    /// Mesh to dent (omit with --demo).
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// Dent the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// Dent depths as fractions of the bounding radius, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0.02,0.05,0.10")]
    pub dents: Vec<f32>,
    /// Dent the surface farthest along this direction (among vertices whose normal is within
    /// 45° of it).
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        default_value = "0,0.5,1",
        allow_hyphen_values = true
    )]
    pub toward: Vec<f32>,
    /// Radius of the dented patch as a fraction of the bounding radius.
    #[arg(long, default_value_t = 0.2)]
    pub footprint: f32,
    /// Page sides to bake the states at, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "32,128")]
    pub page_sizes: Vec<u32>,
    /// Cameras.
    #[arg(long, default_value_t = 162)]
    pub cameras: u32,
    /// Map resolution in pixels.
    #[arg(long, default_value_t = 256)]
    pub resolution: u32,
    /// Shading of the bakes and the reference.
    #[command(flatten)]
    pub shading: ShadingArgs,
    /// Random orbit views (DESIGN §3 evaluation views) for the quality.
    #[arg(long, default_value_t = 3)]
    pub views: usize,
    /// Side of the square views in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Seed of the views.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, Serialize)]
struct StateRow {
    state: String,
    page_size: u32,
    fraction: f64,
    cameras: u32,
    /// Cameras storing colour pages but no depth page: they see the change only in shading
    /// (a moved shadow, a changed normal), not in geometry.
    colour_only_cameras: u32,
    stored_bytes: u64,
}

#[derive(Debug, Serialize)]
struct QualityRow {
    state: String,
    /// The state rendered from the asset with states, against the dented mesh's reference.
    state_render: MeanComparison,
    /// A plain bake of the dented mesh (its own frame), against the same reference.
    plain_bake: MeanComparison,
}

#[derive(Debug, Serialize)]
struct Report {
    source: String,
    /// GPU memory of the asset with every state (32-px pages), and of its base state alone.
    gpu_bytes: u64,
    base_gpu_bytes: u64,
    /// Median frame times of the base state and of a state, interleaved on the same views.
    base_ms: f64,
    state_ms: f64,
    adapter: String,
    cameras: u32,
    resolution: u32,
    shadows: bool,
    dent_at: [f32; 3],
    footprint: f32,
    radius: f64,
    base_bytes: u64,
    storage: Vec<StateRow>,
    quality: Vec<QualityRow>,
}

/// The vertex farthest along `toward` from the centre among those whose normal is within 45° of
/// it: an outward-facing surface, where a dent reads as a dent rather than a cut through a thin
/// part.
fn dent_site(mesh: &Mesh, center: Vec3, toward: Vec3) -> Vec3 {
    mesh.positions
        .iter()
        .zip(&mesh.normals)
        .filter(|(_, n)| Vec3::from(**n).dot(toward) > std::f32::consts::FRAC_1_SQRT_2)
        .map(|(p, _)| (Vec3::from(*p), toward.dot(Vec3::from(*p) - center)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(center, |(p, _)| p)
}

pub(super) fn bench_states(args: &StatesArgs) -> Result<()> {
    if args.views == 0 || args.views > 100 {
        bail!("--views 1..=100");
    }
    if args.dents.is_empty()
        || args
            .dents
            .iter()
            .any(|d| !d.is_finite() || *d <= 0.0 || *d > 0.5)
    {
        bail!("--dents: fractions of the radius in (0, 0.5]");
    }
    if !(args.footprint.is_finite() && args.footprint > 0.0 && args.footprint <= 1.0) {
        bail!("--footprint: a fraction of the radius in (0, 1]");
    }
    let (mesh, source) = load_source(args.mesh.as_deref(), args.demo)?;
    let options = BakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        shading: args.shading.to_shading()?,
        ..BakeOptions::default()
    };
    options.validate()?;
    let sphere = mesh.bounding_sphere();
    let radius = sphere.radius;
    let center = sphere.center.as_vec3();
    let toward = match args.toward[..] {
        [x, y, z] if Vec3::new(x, y, z).length() > 0.0 && Vec3::new(x, y, z).is_finite() => {
            Vec3::new(x, y, z).normalize()
        }
        _ => bail!("--toward X,Y,Z: a non-zero finite direction"),
    };
    let site = dent_site(&mesh, center, toward);
    let footprint = args.footprint * radius as f32;
    let mut reordered = mesh.clone();
    reordered.triangles.reverse();
    reordered.triangle_materials.reverse();
    let mut meshes: Vec<(String, Mesh)> = vec![
        ("unchanged".to_owned(), mesh.clone()),
        ("reordered".to_owned(), reordered),
    ];
    for &d in &args.dents {
        let dented = deform::dent(&mesh, site.to_array(), footprint, d * radius as f32)?;
        meshes.push((format!("dent_{:.0}pct", 100.0 * d), dented));
    }
    let state_meshes: Vec<StateMesh<'_>> = meshes
        .iter()
        .map(|(name, m)| StateMesh {
            name,
            mesh: m,
            source_name: "",
            source_sha256: "",
            params: None,
        })
        .collect();
    let gpu = gpu()?;
    let baker = Baker::new(gpu.clone());
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let bake = |states: &StateBake<'_>, mesh: &Mesh| -> Result<AssetFile> {
        let bytes = baker.bake_states_to_bytes(
            mesh,
            states,
            &options,
            &Provenance::default(),
            &mut |_, _| {},
        )?;
        Ok(AssetFile::from_bytes(bytes)?)
    };
    let bar = progress_bar(
        (args.page_sizes.len() + 2 * args.dents.len()) as u64,
        "baking states",
    );
    let mut storage = Vec::new();
    let mut asset_for_quality = None;
    let mut base_bytes = 0;
    for &page_size in &args.page_sizes {
        let asset = bake(
            &StateBake {
                meshes: &state_meshes,
                page_size,
                ..StateBake::default()
            },
            &mesh,
        )?;
        for s in deform::storage(&asset)? {
            let colour_only_cameras = (0..args.cameras)
                .filter(|&k| {
                    let pages = |c| asset.stored_pages(ImageKey::new(0, s.index, k, c));
                    pages(Channel::Color) > 0 && pages(Channel::Depth) == 0
                })
                .count() as u32;
            storage.push(StateRow {
                state: s.name,
                page_size,
                fraction: s.fraction,
                cameras: s.cameras,
                colour_only_cameras,
                stored_bytes: s.stored_bytes,
            });
        }
        if asset_for_quality.is_none() {
            base_bytes = asset
                .index()
                .iter()
                .filter(|e| e.key.state == 0)
                .map(|e| u64::from(e.length))
                .sum();
            asset_for_quality = Some(asset);
        }
        bar.inc(1);
    }
    let asset = asset_for_quality.context("give at least one --page-sizes")?;
    let field = renderer.upload(&asset)?;
    let views = evaluation_views(
        [
            f64::from(center.x),
            f64::from(center.y),
            f64::from(center.z),
        ],
        radius,
        args.views,
        args.seed,
        args.size,
    );
    // Frame time: the base state and the deepest dent, interleaved, the medians.
    let deepest = Some(meshes.len() as u16);
    let (mut base_ms, mut state_ms) = (Vec::new(), Vec::new());
    for view in &views {
        for _ in 0..6 {
            for (state, out) in [(None, &mut base_ms), (deepest, &mut state_ms)] {
                let options = RenderOptions {
                    state,
                    ..RenderOptions::default()
                };
                let t = std::time::Instant::now();
                renderer.render(&field, view, &options)?;
                out.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let base_only = renderer.upload_with(
        &asset,
        &lumigraph_core::render::UploadOptions {
            base_state_only: true,
            ..Default::default()
        },
    )?;
    let (gpu_bytes, base_gpu_bytes) = (field.gpu_bytes, base_only.gpu_bytes);
    drop(base_only);
    let mut quality = Vec::new();
    for (i, (name, dented)) in meshes.iter().enumerate().skip(2) {
        let plain = bake(&StateBake::default(), dented)?;
        bar.inc(1);
        let plain_field = renderer.upload(&plain)?;
        let gpu_mesh = reference.upload(dented)?;
        let (mut ours, mut theirs) = (Vec::new(), Vec::new());
        for view in &views {
            let truth = reference.render(&gpu_mesh, view, &options.shading)?;
            let state = renderer.render(
                &field,
                view,
                &RenderOptions {
                    state: Some(i as u16 + 1),
                    ..RenderOptions::default()
                },
            )?;
            let plain = renderer.render(&plain_field, view, &RenderOptions::default())?;
            ours.push(metrics::compare(&state, &truth)?);
            theirs.push(metrics::compare(&plain, &truth)?);
        }
        quality.push(QualityRow {
            state: name.clone(),
            state_render: metrics::mean_comparison(&ours).context("no views")?,
            plain_bake: metrics::mean_comparison(&theirs).context("no views")?,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let report = Report {
        source: source.source_name,
        gpu_bytes,
        base_gpu_bytes,
        base_ms: median(base_ms),
        state_ms: median(state_ms),
        adapter: gpu.adapter_summary(),
        cameras: args.cameras,
        resolution: args.resolution,
        shadows: options.shading.shadows,
        dent_at: site.to_array(),
        footprint: args.footprint,
        radius,
        base_bytes,
        storage,
        quality,
    };
    println!(
        "{}: {} cameras × {} px, shadows {}, dent at {:?} over {:.2} r, on {}",
        report.source,
        report.cameras,
        report.resolution,
        report.shadows,
        report.dent_at,
        report.footprint,
        report.adapter
    );
    println!(
        "frame ms: base {:.2}, state {:.2}; GPU memory {:.1} MiB with the states, {:.1} MiB the base alone",
        report.base_ms,
        report.state_ms,
        report.gpu_bytes as f64 / 1_048_576.0,
        report.base_gpu_bytes as f64 / 1_048_576.0
    );
    println!(
        "state          page  stored %  cameras  colour only  stored KiB (base {:.0} KiB)",
        base_bytes as f64 / 1024.0
    );
    for r in &report.storage {
        println!(
            "{:<13} {:>5}  {:>8.2}  {:>7}  {:>11}  {:>10.1}",
            r.state,
            r.page_size,
            100.0 * r.fraction,
            r.cameras,
            r.colour_only_cameras,
            r.stored_bytes as f64 / 1024.0
        );
    }
    println!("state          state masked  plain masked  Δ dB   state wrong px  plain wrong px");
    for q in &report.quality {
        println!(
            "{:<13} {:>12.2}  {:>12.2}  {:>5.2}  {:>14.0}  {:>14.0}",
            q.state,
            q.state_render.masked_psnr,
            q.plain_bake.masked_psnr,
            q.state_render.masked_psnr - q.plain_bake.masked_psnr,
            q.state_render.wrong_surface_px,
            q.plain_bake.wrong_surface_px
        );
    }
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &json))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
