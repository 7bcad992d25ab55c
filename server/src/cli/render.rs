//! `lumigraph render` (an asset or a scene) and `lumigraph reference` (the ground truth: the
//! rasterized mesh, or the ray-cast volume), with their shared view and output handling.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::frame::Frame;
use lumigraph_core::quality::{Quality, Rendered};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::Renderer;
use lumigraph_core::scene::Scene;
use lumigraph_core::view::View;
use lumigraph_core::volume::layers::{VolumeLayer, reference_layers};
use lumigraph_core::volume::raycast::{RaycastOptions, raycast};
use lumigraph_core::volume::tf::{PRESETS, TransferFunction};
use lumigraph_core::volume::{LoadOptions, Volume, VolumeFormat};

use super::args::{DepthArgs, ShadingArgs, ViewArgs, describe_decision};
use super::common::{gpu, load_source, read_view_file};

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
    /// Quality: knobs, a goal or automatic LOD.
    #[command(flatten)]
    pub quality: Quality,
    /// Two-plane light fields.
    #[command(flatten)]
    pub two_plane: TwoPlaneArgs,
    /// Paged rendering of two-plane light fields larger than memory.
    #[command(flatten)]
    pub cache: CacheArgs,
}

/// The flags of paged rendering (docs/two_plane.md "Paged rendering"): a cache budget, its
/// policy, and a camera trace replayed through it.
#[derive(Debug, Args)]
pub struct CacheArgs {
    /// Replay a camera trace: a JSON list of frames, each a view (DESIGN §3) plus optional
    /// `focus` and `aperture`; OUT becomes a folder of 000.png, 001.png, … Without
    /// --cache-mib every page is resident (the reference frames).
    #[arg(long, value_name = "TRACE.json", group = "ViewArgs")]
    pub trace: Option<PathBuf>,
    /// Render through a paged cache of M MiB of device memory (slots and the coarse level).
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    pub cache_mib: Option<f64>,
    /// The cache's policy: none (on demand, FIFO eviction), lru, or predict (seed 003's
    /// probability-based prefetch by dead reckoning).
    #[arg(long, default_value = "lru", requires = "cache_mib")]
    pub prefetch: lumigraph_core::page_cache::Prefetch,
    /// Most pages loaded per frame.
    #[arg(long, value_name = "B", default_value_t = lumigraph_core::page_cache::DEFAULT_PAGES_PER_FRAME)]
    pub pages_per_frame: u32,
    /// Write per-frame faults, degraded pixels, pages loaded and times (JSON).
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// Frames do not wait for the pages they load: a reader thread reads them while the frame
    /// renders with the pages on the device (the coarse level elsewhere), and they arrive for
    /// later frames, as in an interactive viewer. Without it each frame waits for its pages.
    #[arg(long, requires = "cache_mib")]
    pub async_loads: bool,
    /// Pixels that span 2 or more st texels read the full-resolution pages like every other
    /// pixel, instead of a downsampled level (the page levels 2×, 4×, … below the coarse
    /// factor F, and the coarse level itself from F on: the overview a zoomed-out view needs
    /// fewer or no pages for).
    #[arg(long, requires = "cache_mib")]
    pub no_overview: bool,
}

impl CacheArgs {
    fn given(&self) -> bool {
        self.trace.is_some() || self.cache_mib.is_some() || self.report.is_some()
    }
}

/// The `--report` of a paged run.
#[derive(serde::Serialize)]
struct CacheReport<'a> {
    frames: &'a [lumigraph_core::page_cache::PageFrameStats],
    summary: lumigraph_core::page_cache::PageSummary,
    cache: CacheDescription,
}

#[derive(serde::Serialize)]
struct CacheDescription {
    prefetch: Option<String>,
    pages_per_frame: u32,
    async_loads: bool,
    overview: bool,
    budget_mib: Option<f64>,
    device_mib: f64,
    resident_asset_mib: f64,
    slots: u32,
    pages: u32,
    page_size: u32,
    coarse_factor: u32,
    page_levels: u32,
    level_pages: u32,
    level_file_mib: f64,
}

/// `render` of a two-plane asset through the paged cache (`--cache-mib`, `--trace`).
fn render_paged(args: &RenderArgs, asset: AssetFile) -> Result<()> {
    use lumigraph_core::page_cache::{
        CacheConfig, PageSummary, PagedTwoPlane, TraceFrame, parse_trace,
    };
    let cache = &args.cache;
    if args.two_plane.given() {
        bail!("--accumulate and --stereo do not combine with --trace or --cache-mib");
    }
    let plan = args.quality.plan(asset.header())?;
    let base = plan
        .two_plane()
        .copied()
        .context("paged rendering is for two-plane light fields")?;
    let (frames, many): (Vec<TraceFrame>, bool) = if let Some(path) = &cache.trace {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read trace {}", path.display()))?;
        (
            parse_trace(&text, &base).with_context(|| format!("bad trace {}", path.display()))?,
            true,
        )
    } else {
        let (views, many) = read_views(&args.views)?;
        let frames = views
            .into_iter()
            .map(|view| TraceFrame {
                view,
                focus: None,
                aperture: None,
            })
            .collect();
        (frames, many)
    };
    check_depth_path(&args.depth, many)?;
    let config = match cache.cache_mib {
        None => CacheConfig::whole(),
        Some(mib) => {
            if !(mib.is_finite() && mib > 0.0) {
                bail!("--cache-mib {mib}: give a positive number of MiB");
            }
            if cache.pages_per_frame == 0 {
                bail!("--pages-per-frame 0: give at least 1");
            }
            CacheConfig {
                overview: !cache.no_overview,
                ..CacheConfig::with_mib(mib, cache.prefetch, cache.pages_per_frame)
            }
        }
    };
    let renderer = lumigraph_core::two_plane_render::TwoPlaneRenderer::new(gpu()?);
    let asset = std::sync::Arc::new(asset);
    let mut field = PagedTwoPlane::open(&renderer, asset, config)
        .with_context(|| format!("cannot open asset {} through a cache", args.asset.display()))?;
    let mib = |b: u64| b as f64 / 1_048_576.0;
    println!(
        "cache: {} slots of {}x{} ({:.1} MiB on the device with a {}x coarse level) for {} pages ({:.1} MiB resident), {} page levels above the full resolution ({} pages, {:.1} MiB in a temporary file)",
        field.slots,
        field.grid.page_size,
        field.grid.page_size,
        mib(field.bytes),
        field.coarse_factor,
        field.grid.total(),
        mib(field.full_bytes),
        field.grid.levels - 1,
        field.grid.all_pages() - field.grid.total(),
        mib(field.level_file_bytes())
    );
    let mut stats = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let (frame, s) = if cache.async_loads {
            field.render_nowait(&renderer, &f.view, &f.options(&base))?
        } else {
            field.render(&renderer, &f.view, &f.options(&base))?
        };
        if let Some(e) = s.read_errors.first() {
            bail!("frame {i}: {e}");
        }
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        println!(
            "frame {i:03}: {:.2} ms, {} faults, {} pages loaded, {} px degraded, {} px overview",
            s.ms, s.faults, s.pages_loaded, s.degraded_px, s.overview_px
        );
        stats.push(s);
    }
    let summary = PageSummary::of(&stats);
    println!(
        "{} frames: {} faults, {} pages loaded, {} px degraded, {} px overview, {:.2} ms mean",
        summary.frames,
        summary.faults,
        summary.pages_loaded,
        summary.degraded_px,
        summary.overview_px,
        summary.mean_ms
    );
    if let Some(path) = &cache.report {
        let report = CacheReport {
            frames: &stats,
            summary,
            cache: CacheDescription {
                prefetch: config.budget_bytes.map(|_| config.prefetch.to_string()),
                pages_per_frame: config.pages_per_frame,
                async_loads: cache.async_loads,
                overview: config.overview,
                budget_mib: cache.cache_mib,
                device_mib: mib(field.bytes),
                resident_asset_mib: mib(field.full_bytes),
                slots: field.slots,
                pages: field.grid.total(),
                page_size: field.grid.page_size,
                coarse_factor: field.coarse_factor,
                page_levels: field.grid.levels - 1,
                level_pages: field.grid.all_pages() - field.grid.total(),
                level_file_mib: mib(field.level_file_bytes()),
            },
        };
        let text = serde_json::to_string_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, text.as_bytes()))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// The flags of a two-plane light field besides its quality options (`--uv-filter`, `--focus`,
/// `--aperture`; DESIGN §9, docs/two_plane.md).
#[derive(Debug, Args)]
pub struct TwoPlaneArgs {
    /// Average this many of a wide aperture's stratified draws (the view at rest; the same as
    /// --refine for a two-plane light field).
    #[arg(long, value_name = "N", allow_hyphen_values = true)]
    pub accumulate: Option<u32>,
    /// Render a stereo pair side by side (left | right), the eyes BASELINE world units apart
    /// along the view's right axis.
    #[arg(long, value_name = "BASELINE", allow_hyphen_values = true)]
    pub stereo: Option<f64>,
}

impl TwoPlaneArgs {
    fn given(&self) -> bool {
        self.accumulate.is_some() || self.stereo.is_some()
    }
}

/// `view` with the eye and target moved by `offset` world units along its right axis.
fn shifted(view: &View, offset: f64) -> Result<View> {
    let basis = view.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)?;
    let shift = basis.right * offset;
    let mut out = view.clone();
    for (e, s) in out.eye.iter_mut().zip(shift.to_array()) {
        *e += s;
    }
    for (t, s) in out.target.iter_mut().zip(shift.to_array()) {
        *t += s;
    }
    Ok(out)
}

/// `render` of a two-plane asset.
fn render_two_plane(
    args: &RenderArgs,
    asset: &AssetFile,
    views: &[View],
    many: bool,
) -> Result<()> {
    let mut quality = args.quality.clone();
    if let Some(draws) = args.two_plane.accumulate {
        let most = lumigraph_core::two_plane_render::MAX_DRAWS;
        if !(1..=most).contains(&draws) {
            bail!("--accumulate {draws}: give 1..={most} draws");
        }
        if quality.refine.is_some() {
            bail!(
                "give --accumulate or --refine, not both (they are the same for a two-plane asset)"
            );
        }
        quality.refine = Some(draws);
    }
    let plan = quality.plan(asset.header())?;
    let renderer = lumigraph_core::two_plane_render::TwoPlaneRenderer::new(gpu()?);
    let field = renderer
        .upload(asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    let render = |view: &View| -> Result<Frame> {
        Ok(plan.render_two_plane(&renderer, &field, view)?.frame)
    };
    for (i, view) in views.iter().enumerate() {
        let frame = match args.two_plane.stereo {
            None => render(view)?,
            Some(baseline) => {
                if !(baseline.is_finite() && baseline >= 0.0) {
                    bail!("--stereo {baseline}: give a finite baseline ≥ 0");
                }
                let left = render(&shifted(view, -0.5 * baseline)?)?;
                let right = render(&shifted(view, 0.5 * baseline)?)?;
                side_by_side(&left, &right)
            }
        };
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        println!(
            "view {i:03}: {:.2} ms ({} px covered)",
            frame.stats.render_ms,
            frame.covered_count()
        );
    }
    Ok(())
}

/// Two frames of one size as one twice as wide: `left | right`.
fn side_by_side(left: &Frame, right: &Frame) -> Frame {
    let (w, h) = (left.width as usize, left.height as usize);
    let mut color = Vec::with_capacity(8 * w * h);
    let mut depth = Vec::with_capacity(2 * w * h);
    for row in 0..h {
        color.extend_from_slice(&left.color[4 * row * w..4 * (row + 1) * w]);
        color.extend_from_slice(&right.color[4 * row * w..4 * (row + 1) * w]);
        depth.extend_from_slice(&left.depth[row * w..(row + 1) * w]);
        depth.extend_from_slice(&right.depth[row * w..(row + 1) * w]);
    }
    let mut stats = left.stats.clone();
    stats.render_ms += right.stats.render_ms;
    Frame {
        width: left.width * 2,
        height: left.height,
        color,
        depth,
        translucent: false,
        stats,
    }
}

/// `lumigraph reference`.
#[derive(Debug, Args)]
pub struct ReferenceArgs {
    /// Mesh file (omit with --demo), or a volume (.nii, .nii.gz, .npy, .mha, .mhd, .nrrd,
    /// .nhdr, .inr, .inr.gz, .vti), ray-cast directly with --tf (docs/volumes.md).
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
    /// Volume ray casting.
    #[command(flatten)]
    pub volume: VolumeArgs,
    /// A volume's layers (LAYERS.json, as `bake --layers` takes it) instead of --tf: each
    /// layer is ray-cast with its TF (and segment, for depth layers) and the layers are
    /// composited in depth order (depth layers: in their order along the ray).
    #[arg(long, value_name = "LAYERS.json")]
    pub layers: Option<PathBuf>,
    /// With --layers: runtime opacities (the renderer's `--layers` values); layers not named
    /// keep the file's opacity.
    #[arg(long, value_name = "NAME=OPACITY,...", requires = "layers")]
    pub opacity: Option<lumigraph_core::layers::LayerOpacities>,
}

/// The flags of a volume (DESIGN §9).
#[derive(Debug, Args)]
pub struct VolumeArgs {
    /// Transfer function of a volume: a JSON file, or a preset (ct-bone, ct-skin, mri-brain).
    #[arg(long)]
    pub tf: Option<String>,
    /// Read the volume as integer labels (nearest-voxel sampling, a label TF).
    #[arg(long)]
    pub labels: bool,
    /// Gradient shading of a scalar volume (--light, --ambient).
    #[arg(long)]
    pub shade: bool,
    /// Sample spacing along the ray, world units (default: half the TF's reference step).
    #[arg(long)]
    pub step: Option<f64>,
    /// Accumulated opacity that places the depth, in (0, 1] (default 0.5).
    #[arg(long)]
    pub depth_threshold: Option<f64>,
    /// Voxel spacing SX,SY,SZ of a .npy volume (default 1,1,1).
    #[arg(long, value_parser = super::args::parse_vec3_f64, allow_hyphen_values = true)]
    pub spacing: Option<[f64; 3]>,
}

impl VolumeArgs {
    /// Whether any volume-only flag was given.
    pub(super) fn given(&self) -> bool {
        self.tf.is_some()
            || self.labels
            || self.shade
            || self.step.is_some()
            || self.depth_threshold.is_some()
            || self.spacing.is_some()
    }
}

/// Reads `--view` / `--views`; returns the views and whether OUT is a folder.
fn read_views(args: &ViewArgs) -> Result<(Vec<View>, bool)> {
    let (path, many) = match (&args.view, &args.views) {
        (Some(p), _) => (p, false),
        (None, Some(p)) => (p, true),
        (None, None) => bail!("give --view VIEW.json or --views VIEWS.json"),
    };
    let views = read_view_file(path)?;
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

pub(super) fn render(args: &RenderArgs) -> Result<()> {
    if args.cache.given() {
        let asset = AssetFile::open(&args.asset)
            .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
        if asset.header().two_plane().is_none() {
            bail!(
                "--trace, --cache-mib and --report apply to two-plane light fields; {} is {}",
                args.asset.display(),
                asset.header().kind.name()
            );
        }
        return render_paged(args, asset);
    }
    let (views, many) = read_views(&args.views)?;
    check_depth_path(&args.depth, many)?;
    if args
        .asset
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        if args.two_plane.given() {
            bail!("--accumulate and --stereo apply to two-plane light-field assets, not to scenes");
        }
        return render_scene(args, &views, many);
    }
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    if asset.header().two_plane().is_some() {
        return render_two_plane(args, &asset, &views, many);
    }
    if args.two_plane.given() {
        bail!(
            "--accumulate and --stereo apply to two-plane light fields; {} is {}",
            args.asset.display(),
            asset.header().kind.name()
        );
    }
    let plan = args.quality.plan(asset.header())?;
    let renderer = Renderer::new(gpu()?);
    let field = renderer
        .upload(&asset)
        .with_context(|| format!("cannot load asset {}", args.asset.display()))?;
    for (i, view) in views.iter().enumerate() {
        let Rendered { frame, decision } = plan.render(&renderer, &field, view)?;
        write_outputs(&frame, i, many, &args.output, &args.depth)?;
        let pixels = u64::from(view.width) * u64::from(view.height);
        match describe_decision(&decision, pixels) {
            Some(text) => println!(
                "view {i:03}: {text}; measured {:.2} ms ({} px covered)",
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
    args.quality.check_scene()?;
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

pub(super) fn reference(args: &ReferenceArgs) -> Result<()> {
    if let Some(path) = &args.mesh
        && is_volume_path(path)
    {
        return reference_volume(path, args);
    }
    if args.volume.given() || args.layers.is_some() {
        bail!(
            "--tf, --labels, --shade, --step, --depth-threshold and --spacing apply to volumes only"
        );
    }
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

impl VolumeArgs {
    /// [`VolumeArgs::load`] with the layers of `layers_file` (LAYERS.json) instead of `--tf`,
    /// or the one layer of `--tf` without it.
    pub(super) fn load_layers(
        &self,
        path: &Path,
        shading: &ShadingArgs,
        layers_file: Option<&Path>,
    ) -> Result<(Volume, Vec<VolumeLayer>, RaycastOptions)> {
        let Some(file) = layers_file else {
            let (volume, tf, options) = self.load(path, shading)?;
            return Ok((volume, vec![VolumeLayer::single(&tf)], options));
        };
        if self.tf.is_some() {
            bail!("give --tf or --layers, not both: each layer names its own TF");
        }
        let text = std::fs::read_to_string(file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        let base = file.parent().unwrap_or_else(|| Path::new("."));
        let layers = VolumeLayer::parse(&text, base).with_context(|| file.display().to_string())?;
        let (volume, _, options) = self.load_with_tf(path, shading, layers[0].tf.clone())?;
        Ok((volume, layers, options))
    }

    /// The transfer function of `--tf` (a preset or a JSON file), the volume at `path` and the
    /// ray-cast options of these flags and `shading`'s `--light` and `--ambient`; refuses the
    /// mesh-only shading flags.
    pub(super) fn load(
        &self,
        path: &Path,
        shading: &ShadingArgs,
    ) -> Result<(Volume, TransferFunction, RaycastOptions)> {
        let Some(tf_arg) = &self.tf else {
            bail!(
                "a volume needs --tf TF.json or a preset ({})",
                PRESETS.join(", ")
            );
        };
        let tf = if PRESETS.contains(&tf_arg.as_str()) {
            TransferFunction::preset(tf_arg)?
        } else {
            let text = std::fs::read_to_string(tf_arg).with_context(|| {
                format!(
                    "--tf {tf_arg}: not a preset ({}) and not a readable file",
                    PRESETS.join(", ")
                )
            })?;
            TransferFunction::from_json(&text).with_context(|| format!("--tf {tf_arg}"))?
        };
        self.load_with_tf(path, shading, tf)
    }

    /// The volume at `path` and these flags' ray-cast options, with `tf`.
    fn load_with_tf(
        &self,
        path: &Path,
        shading: &ShadingArgs,
        tf: TransferFunction,
    ) -> Result<(Volume, TransferFunction, RaycastOptions)> {
        if shading.unlit || shading.specular.is_some() {
            bail!("--unlit and --specular apply to meshes; a volume's colour comes from its --tf");
        }
        if shading.shadows {
            bail!(
                "--shadows applies to meshes (a shadow ray through their triangles); a volume is shaded by its gradient (--shade)"
            );
        }
        let volume = Volume::load(
            path,
            &LoadOptions {
                labels: self.labels,
                spacing: self.spacing,
            },
        )
        .with_context(|| format!("cannot load {}", path.display()))?;
        let defaults = RaycastOptions::default();
        let options = RaycastOptions {
            step: self.step,
            shade: self.shade,
            light: shading.light.map_or(defaults.light, |l| l.map(f64::from)),
            ambient: shading.ambient.map_or(defaults.ambient, f64::from),
            depth_threshold: self.depth_threshold.unwrap_or(defaults.depth_threshold),
        };
        Ok((volume, tf, options))
    }
}

/// Whether `path` names a volume file (by its extension).
pub(super) fn is_volume_path(path: &Path) -> bool {
    VolumeFormat::from_name(&path.to_string_lossy()).is_some()
}

/// `lumigraph reference VOLUME --tf ...`: the direct ray cast (lumigraph_core::volume::raycast).
fn reference_volume(path: &Path, args: &ReferenceArgs) -> Result<()> {
    let (views, many) = read_views(&args.views)?;
    check_depth_path(&args.depth, many)?;
    if let Some(file) = &args.layers {
        let (volume, layers, options) = args.volume.load_layers(path, &args.shading, Some(file))?;
        let descs: Vec<lumigraph_core::asset::LayerDesc> = layers
            .iter()
            .map(|l| lumigraph_core::asset::LayerDesc {
                name: l.name.clone(),
                default_opacity: l.opacity,
            })
            .collect();
        let opacities = args
            .opacity
            .clone()
            .unwrap_or_default()
            .resolve(&descs)
            .map_err(anyhow::Error::msg)?;
        for (i, view) in views.iter().enumerate() {
            let start = std::time::Instant::now();
            let frame = reference_layers(&volume, &layers, view, &options, &opacities)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            write_outputs(&frame, i, many, &args.output, &args.depth)?;
            println!(
                "view {i:03}: {ms:.2} ms ({} px covered, {} layers, {} samples)",
                frame.covered_count(),
                layers.len(),
                frame.stats.steps
            );
        }
        return Ok(());
    }
    let (volume, tf, options) = args.volume.load(path, &args.shading)?;
    for (i, view) in views.iter().enumerate() {
        let start = std::time::Instant::now();
        let image = raycast(&volume, &tf, view, &options)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        write_outputs(&image.to_frame(), i, many, &args.output, &args.depth)?;
        let covered = image.coverage().iter().filter(|&&c| c).count();
        println!(
            "view {i:03}: {ms:.2} ms ({covered} px covered, {} samples)",
            image.samples
        );
    }
    Ok(())
}
