//! `lumigraph bake`: a mesh or the demo into a light-field asset, calibrated unless told not to;
//! or a volume through a transfer function (`--tf`).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::ProgressBar;
use lumigraph_core::asset::{BlockCodec, Provenance};
use lumigraph_core::auto_bake::{self, AutoEngines, AutoStage, AutoTarget};
use lumigraph_core::bake::{BakeOptions, Baker, StateBake};
use lumigraph_core::calibration;
use lumigraph_core::deform::StateMesh;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::Mesh;
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::Renderer;

use lumigraph_core::bake::sha256_hex;
use lumigraph_core::volume::bake::{VolumeBakeOptions, VolumeBaker};

use super::args::ShadingArgs;
use super::common::{gpu, load_source, progress_bar};
use super::render::{VolumeArgs, is_volume_path};

/// `lumigraph bake`.
#[derive(Debug, Args)]
pub struct BakeArgs {
    /// Mesh file (omit with --demo), or a volume (.nii, .nii.gz, .npy, .mha, .mhd, .nrrd, .nhdr,
    /// .inr, .inr.gz, .vti) baked through --tf (docs/volumes.md).
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
    /// Colour pages: raw RGBA8 texels, or block-compressed (bc1: 4 bits per texel, bc7: 8;
    /// docs/format.md §7.1). Both drop the edge texels (§8.5). Spherical and two-plane bakes;
    /// volumes take bc7 (their colour is premultiplied and semi-transparent: bc1 keeps 1-bit
    /// alpha only).
    #[arg(long, value_enum, default_value_t = ColorCodec::Raw, conflicts_with = "auto")]
    pub color_codec: ColorCodec,
    /// Depth pages: r16 (the default; as --depth-bits 16), r8 (as --depth-bits 8) or bc4 (8-bit
    /// codes block-compressed to 4 bits per texel). Spherical bakes, meshes and volumes.
    #[arg(long, value_enum, conflicts_with_all = ["depth_bits", "auto"])]
    pub depth_codec: Option<DepthCodec>,
    /// Shading.
    #[command(flatten)]
    pub shading: ShadingArgs,
    /// Light states: also bake the colour for each of N light directions (12, 42 or 162, a
    /// nested icosphere in the asset frame), the ambient part alone and the shading normals,
    /// sharing the base depth, so that `render --light X,Y,Z` relights the asset (DESIGN §9;
    /// with --shadows the shadows move with the light). Memory: (N + 2) × cameras ×
    /// resolution² × 4 bytes more.
    #[arg(
        long,
        value_name = "N",
        allow_hyphen_values = true,
        conflicts_with = "auto"
    )]
    pub lights: Option<u32>,
    /// A deformation state: MESH2 (any topology, inside the base mesh's bounding sphere) baked
    /// in the base's frame, storing only the pages whose colour or depth differ from the base
    /// (exactly: the bake is deterministic). Repeat for more states; render with `--state
    /// NAME`; `info` lists what each stores.
    #[arg(
        long = "state",
        value_name = "NAME=MESH2",
        conflicts_with_all = ["auto", "lights", "demo"]
    )]
    pub states: Vec<String>,
    /// Bake a glTF animation (NAME, or the file's first): the scene posed at every 1/FPS s
    /// (node transforms, morph targets, skins) as frame states sharing one bounding sphere,
    /// frame 0 the base state; each frame stores only the pages that differ from frame 0.
    /// Render with `--time SECONDS` or `--frame N`. At most 256 frames.
    #[arg(
        long,
        value_name = "NAME",
        num_args = 0..=1,
        default_missing_value = "",
        conflicts_with_all = ["auto", "lights", "demo", "states"]
    )]
    pub animation: Option<String>,
    /// Frames per second of --animation.
    #[arg(
        long,
        default_value_t = 24.0,
        requires = "animation",
        allow_hyphen_values = true
    )]
    pub fps: f64,
    /// Skip the calibration (error against cost of this scene, stored in the asset's quality
    /// report for `render --target-psnr / --budget-ms`; a few seconds on lavapipe).
    #[arg(long)]
    pub no_calibrate: bool,
    /// Choose cameras, map resolution and depth bits for this scene from a quick
    /// low-resolution calibration (target: --target-psnr, default 27 dB, or --max-bytes), bake
    /// that and measure it on held-out views; excludes --cameras, --resolution, --depth-bits.
    #[arg(long, conflicts_with_all = ["cameras", "resolution", "depth_bits"])]
    pub auto: bool,
    /// With --auto: the masked PSNR (dB) to reach with the fewest bytes.
    #[arg(
        long,
        requires = "auto",
        conflicts_with = "max_bytes",
        allow_hyphen_values = true
    )]
    pub target_psnr: Option<f64>,
    /// With --auto: the asset size in bytes within which to reach the best masked PSNR.
    #[arg(long, requires = "auto", allow_hyphen_values = true)]
    pub max_bytes: Option<u64>,
    /// With --auto: print the report as JSON on stdout.
    #[arg(long, requires = "auto")]
    pub json: bool,
    /// Volume ray casting.
    #[command(flatten)]
    pub volume: VolumeArgs,
    /// A volume multi light field, instead of --tf: one layer per transfer function of
    /// LAYERS.json (names, TFs, default opacities), or depth layers that split every ray of one
    /// TF where its opacity or value reaches given boundaries (docs/volumes.md, "Layers").
    /// Render with `--layers NAME=OPACITY,...`.
    #[arg(long, value_name = "LAYERS.json")]
    pub layers: Option<PathBuf>,
    /// A two-plane light field instead of a spherical one: the planes of PLANES.json (DESIGN
    /// §9), or `auto` to fit them to the mesh's bounding sphere along --axis (printed). One
    /// off-axis camera per uv grid cell captures colour and depth (docs/two_plane.md).
    #[arg(
        long,
        value_name = "PLANES.json|auto",
        conflicts_with_all = ["auto", "lights", "states", "animation", "layers"]
    )]
    pub two_plane: Option<String>,
    /// With `--two-plane auto`: the direction from the object towards the cameras.
    #[arg(
        long,
        value_name = "X,Y,Z",
        default_value = "0,0,1",
        value_parser = super::args::parse_vec3_f64,
        allow_hyphen_values = true
    )]
    pub axis: [f64; 3],
    /// With `--two-plane auto`: the uv camera grid, NUxNV.
    #[arg(long, value_name = "NUxNV", default_value = "8x8", value_parser = super::args::parse_size_pair)]
    pub grid: [u32; 2],
    /// With `--two-plane auto`: every camera's st resolution, NSxNT.
    #[arg(long, value_name = "NSxNT", default_value = "256x256", value_parser = super::args::parse_size_pair)]
    pub st_res: [u32; 2],
}

/// `--color-codec`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ColorCodec {
    /// RGBA8 texels.
    Raw,
    /// BC1 blocks.
    Bc1,
    /// BC7 blocks.
    Bc7,
}

impl ColorCodec {
    pub(super) fn block(self) -> Option<BlockCodec> {
        match self {
            ColorCodec::Raw => None,
            ColorCodec::Bc1 => Some(BlockCodec::Bc1),
            ColorCodec::Bc7 => Some(BlockCodec::Bc7),
        }
    }
}

/// `--depth-codec`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DepthCodec {
    /// 16-bit codes.
    R16,
    /// 8-bit codes.
    R8,
    /// 8-bit codes in BC4 blocks.
    Bc4,
}

impl BakeArgs {
    /// Depth bits and block codec: `--depth-codec` where given, else `--depth-bits` codes.
    fn depth_storage(&self) -> (u8, Option<BlockCodec>) {
        match self.depth_codec {
            None => (self.depth_bits, None),
            Some(DepthCodec::R16) => (16, None),
            Some(DepthCodec::R8) => (8, None),
            Some(DepthCodec::Bc4) => (8, Some(BlockCodec::Bc4)),
        }
    }
}

/// `--two-plane PLANES.json|auto`: captures the mesh (or demo) into a two-plane asset.
fn bake_two_plane(args: &BakeArgs, planes_arg: &str) -> Result<()> {
    use lumigraph_core::two_plane::{self, TwoPlanes};
    if args.depth_codec.is_some() {
        anyhow::bail!("--depth-codec applies to spherical bakes; two-plane depth is stored as f32");
    }
    let shading = args.shading.to_shading()?;
    let (mesh, mut provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let reference = ReferenceRenderer::new(gpu);
    let gpu_mesh = reference
        .upload(&mesh)
        .context("cannot upload the mesh to the GPU")?;
    let planes = if planes_arg == "auto" {
        let planes = two_plane::fit_planes(
            lumigraph_core::glam::DVec3::from(gpu_mesh.frame.center),
            gpu_mesh.frame.radius,
            lumigraph_core::glam::DVec3::from(args.axis),
            args.grid,
            args.st_res,
        )
        .context("cannot fit planes to the mesh")?;
        println!(
            "planes fitted to the bounding sphere (centre {:?}, radius {}): {}",
            gpu_mesh.frame.center,
            gpu_mesh.frame.radius,
            serde_json::to_string(&planes)?
        );
        planes
    } else {
        let path = std::path::Path::new(planes_arg);
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the planes file {}", path.display()))?;
        TwoPlanes::from_json(&text).with_context(|| format!("bad planes in {}", path.display()))?
    };
    provenance.bake_options = serde_json::json!({
        "two_plane": planes,
        "shading": shading,
    });
    if let Some(codec) = args.color_codec.block() {
        provenance.bake_options["color_codec"] = serde_json::json!(codec);
    }
    env!("CARGO_PKG_VERSION").clone_into(&mut provenance.lumigraph_version);
    provenance.triangles = mesh.triangles.len() as u64;
    provenance.vertices = mesh.positions.len() as u64;
    provenance.created_unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let bar = progress_bar(u64::from(planes.camera_count()), "capturing cameras");
    let report = two_plane::bake_to_file_with(
        &reference,
        &gpu_mesh,
        &planes,
        &shading,
        provenance,
        args.color_codec.block(),
        &args.output,
        &mut |done, _| bar.set_position(u64::from(done)),
    )?;
    bar.finish_and_clear();
    println!(
        "baked a two-plane light field: {}x{} cameras of {}x{} px in {:.0} ms, {:.1} % of texels \
         hit: {} ({:.1} MiB)",
        planes.uv.grid[0],
        planes.uv.grid[1],
        report.resolution[0],
        report.resolution[1],
        report.bake_ms,
        100.0 * report.coverage,
        args.output.display(),
        report.asset_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}

pub(super) fn bake(args: &BakeArgs) -> Result<()> {
    if let Some(planes) = &args.two_plane {
        if args.mesh.as_deref().is_some_and(is_volume_path) || args.volume.given() {
            anyhow::bail!("--two-plane captures meshes; volumes bake spherical light fields");
        }
        return bake_two_plane(args, planes);
    }
    if let Some(path) = &args.mesh
        && is_volume_path(path)
    {
        return bake_volume(path, args);
    }
    if args.volume.given() || args.layers.is_some() {
        if !args.states.is_empty() || args.animation.is_some() {
            anyhow::bail!("--state and --animation bake states of meshes, not of volumes");
        }
        if args.lights.is_some() {
            anyhow::bail!("--lights relights meshes; volumes take one light (--shade)");
        }
        anyhow::bail!(
            "--tf, --layers, --labels, --shade, --step, --depth-threshold and --spacing apply to \
             volumes only"
        );
    }
    if args.auto {
        return bake_auto(args);
    }
    let (depth_bits, depth_codec) = args.depth_storage();
    let options = BakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        shading: args.shading.to_shading()?,
        depth_bits,
        lights: args.lights,
        one_sided: false,
        color_codec: args.color_codec.block(),
        depth_codec,
    };
    options.validate()?;
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    if let Some(name) = &args.animation {
        return bake_animation(args, &options, name, &provenance);
    }
    let state_sources = load_states(&args.states)?;
    let state_meshes: Vec<StateMesh<'_>> = state_sources
        .iter()
        .map(|(name, mesh, source)| StateMesh {
            name,
            mesh,
            source_name: &source.source_name,
            source_sha256: &source.source_sha256,
            params: None,
        })
        .collect();
    let states = StateBake {
        meshes: &state_meshes,
        ..StateBake::default()
    };
    bake_mesh_states(
        args,
        &options,
        (&mesh, &states),
        &provenance,
        "baking cameras",
    )?;
    print_states(&args.output)
}

/// Bakes `mesh` with `states` into `args.output`: calibrated unless `--no-calibrate`, with a
/// progress bar labelled `label`, and prints what the bake made.
fn bake_mesh_states(
    args: &BakeArgs,
    options: &BakeOptions,
    (mesh, states): (&Mesh, &StateBake<'_>),
    provenance: &Provenance,
    label: &str,
) -> Result<()> {
    let gpu = gpu()?;
    let baker = Baker::new(gpu.clone());
    let bar = progress_bar(u64::from(options.cameras), label);
    if !args.no_calibrate {
        return bake_calibrated(
            args,
            options,
            (mesh, states),
            provenance,
            &baker,
            &gpu,
            &bar,
        );
    }
    let report = baker.bake_states_to_file(
        mesh,
        states,
        options,
        provenance,
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

/// `--animation`: the frames as states of frame 0, in the frame around all of them.
fn bake_animation(
    args: &BakeArgs,
    options: &BakeOptions,
    name: &str,
    provenance: &Provenance,
) -> Result<()> {
    let path = args
        .mesh
        .as_deref()
        .context("--animation needs a glTF file")?;
    let animation =
        lumigraph_core::mesh::load_animation(path, (!name.is_empty()).then_some(name), args.fps)
            .with_context(|| format!("cannot sample the animation of {}", path.display()))?;
    let layout = lumigraph_core::deform::AnimationLayout::new(&animation);
    let state_meshes = layout.state_meshes(
        &animation.frames,
        &provenance.source_name,
        &provenance.source_sha256,
    );
    let states = layout.state_bake(&state_meshes);
    bake_mesh_states(
        args,
        options,
        (&animation.frames[0], &states),
        provenance,
        &format!("baking {} frames", animation.frames.len()),
    )?;
    println!(
        "animation {:?}: {} frames at {} fps over {:.3} s",
        animation.name,
        animation.frames.len(),
        animation.fps,
        animation.duration
    );
    print_states(&args.output)
}

/// The meshes of `--state NAME=MESH2` flags, with their provenance.
fn load_states(flags: &[String]) -> Result<Vec<(String, Mesh, Provenance)>> {
    flags
        .iter()
        .map(|flag| {
            let Some((name, path)) = flag.split_once('=') else {
                anyhow::bail!("--state {flag:?}: give NAME=MESH2");
            };
            if name.is_empty() || path.is_empty() {
                anyhow::bail!("--state {flag:?}: give NAME=MESH2 with a name and a mesh file");
            }
            let (mesh, source) = load_source(Some(std::path::Path::new(path)), false)
                .with_context(|| format!("state {name:?}"))?;
            Ok((name.to_owned(), mesh, source))
        })
        .collect()
}

/// Prints what each deformation state of the asset at `path` stores.
fn print_states(path: &std::path::Path) -> Result<()> {
    let asset = lumigraph_core::asset::AssetFile::open(path)
        .with_context(|| format!("cannot reopen {}", path.display()))?;
    for state in lumigraph_core::deform::storage(&asset)? {
        println!(
            "state {:?}: stores {:.2} % of the pages ({} of {} cameras touched)",
            state.name,
            100.0 * state.fraction,
            state.cameras,
            asset.header().camera_count()
        );
    }
    Ok(())
}

/// Bakes in memory, measures the scene's calibration (calibration::Calibration) and writes the
/// asset with it in the quality report, atomically.
fn bake_calibrated(
    args: &BakeArgs,
    options: &BakeOptions,
    (mesh, states): (&Mesh, &StateBake<'_>),
    provenance: &Provenance,
    baker: &Baker,
    gpu: &Arc<Gpu>,
    bar: &ProgressBar,
) -> Result<()> {
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let baked = calibration::bake_states_calibrated(
        baker,
        &renderer,
        &reference,
        (mesh, states),
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

/// `--auto`: calibrate, choose, bake, verify (lumigraph_core::auto_bake), with progress on
/// stderr and the report on stdout.
fn bake_auto(args: &BakeArgs) -> Result<()> {
    let target = AutoTarget::from_flags(args.target_psnr, args.max_bytes)?;
    let shading = args.shading.to_shading()?;
    shading.validate()?;
    let (mesh, provenance) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let baker = Baker::new(gpu.clone());
    let renderer = Renderer::new(gpu.clone());
    let reference = ReferenceRenderer::new(gpu.clone());
    let engines = AutoEngines {
        baker: &baker,
        renderer: &renderer,
        reference: &reference,
    };
    let bar = progress_bar(1, "calibrating");
    let baked = auto_bake::auto_bake(
        &engines,
        &mesh,
        &shading,
        target,
        &provenance,
        !args.no_calibrate,
        &mut |stage| match stage {
            AutoStage::CalibrationBake {
                index,
                total,
                done,
                cameras,
            } => {
                bar.set_length(u64::from(cameras));
                bar.set_position(u64::from(done));
                bar.set_message(format!("calibration bake {index}/{total}"));
            }
            AutoStage::Measuring => bar.set_message("measuring the calibration views"),
            AutoStage::Bake { done, cameras } => {
                bar.set_length(u64::from(cameras));
                bar.set_position(u64::from(done));
                bar.set_message("baking the chosen setting");
            }
            AutoStage::Tuning { bake } => {
                bar.set_message(format!("measuring bake {bake} on the tuning views"));
            }
            AutoStage::Verifying => bar.set_message("measuring held-out views"),
        },
    )?;
    bar.finish_and_clear();
    lumigraph_core::atomic_write(&args.output, |w| std::io::Write::write_all(w, &baked.bytes))
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    let report = &baked.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        let s = &report.choice.setting;
        let goal = match target {
            AutoTarget::TargetPsnr(db) => format!("target {db} dB"),
            AutoTarget::MaxBytes(bytes) => format!("max {bytes} bytes"),
        };
        println!(
            "auto ({goal}): chose {} cameras, {} px, {}-bit depth; predicted {:.2} dB, {} bytes; \
             measured {:.2} dB on {} held-out views; asset {} bytes: {}; target {}",
            s.cameras,
            s.resolution,
            s.depth_bits,
            s.predicted_psnr,
            s.predicted_bytes,
            report.measured_psnr,
            auto_bake::AUTO_VIEWS,
            report.asset_bytes,
            args.output.display(),
            if report.target_met { "met" } else { "NOT met" },
        );
        if report.choice.correction_db != 0.0 {
            println!(
                "  corrected on the tuning views by {:+.2} dB: predicted {:.2} dB",
                report.choice.correction_db,
                s.predicted_psnr + report.choice.correction_db
            );
        }
        for (i, bake) in report.bakes.iter().enumerate() {
            let b = &bake.choice.setting;
            if let Some(tuned) = bake.tuning_psnr {
                println!(
                    "  bake {}: {} cameras, {} px, {}-bit depth, {} bytes: {tuned:.2} dB on {} \
                     tuning views",
                    i + 1,
                    b.cameras,
                    b.resolution,
                    b.depth_bits,
                    bake.bytes,
                    auto_bake::AUTO_TUNING_VIEWS
                );
            }
        }
        println!(
            "calibrated in {:.0} ms, baked in {:.0} ms, verified in {:.0} ms",
            report.calibrate_ms, report.bake_ms, report.verify_ms
        );
    }
    if let Some(message) = &report.message {
        eprintln!("warning: {message}");
    }
    Ok(())
}

/// `lumigraph bake VOLUME --tf ...`: the GPU ray cast into the cameras' maps
/// (lumigraph_core::volume::bake). Volume assets are not calibrated: the calibration measures
/// against the mesh reference.
fn bake_volume(path: &std::path::Path, args: &BakeArgs) -> Result<()> {
    if !args.states.is_empty() || args.animation.is_some() {
        anyhow::bail!("--state and --animation bake states of meshes, not of volumes");
    }
    if args.lights.is_some() {
        anyhow::bail!("--lights relights meshes; volumes take one light (--shade)");
    }
    if args.auto {
        anyhow::bail!(
            "--auto chooses settings for meshes; give a volume --cameras and --resolution"
        );
    }
    let (volume, layers, raycast) =
        args.volume
            .load_layers(path, &args.shading, args.layers.as_deref())?;
    let (depth_bits, depth_codec) = args.depth_storage();
    let options = VolumeBakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        depth_bits,
        raycast,
        color_codec: args.color_codec.block(),
        depth_codec,
    };
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let provenance = Provenance {
        source_name: path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        ),
        source_sha256: sha256_hex(&bytes),
        ..Default::default()
    };
    drop(bytes);
    let baker = VolumeBaker::new(gpu()?);
    let bar = progress_bar(
        u64::from(options.cameras) * layers.len() as u64,
        "ray-casting cameras",
    );
    let report = baker.bake_layers_to_file(
        &volume,
        &layers,
        &options,
        &provenance,
        &args.output,
        &mut |done, _| bar.set_position(u64::from(done)),
    )?;
    bar.finish_and_clear();
    let [nx, ny, nz] = volume.dims;
    println!(
        "baked {} cameras{} at {} px from a {nx}x{ny}x{nz} volume (step {:.4}) in {:.0} ms, \
         {:.1} % of texels covered: {} ({:.1} MiB)",
        report.cameras,
        if layers.len() > 1 {
            format!(" × {} layers", layers.len())
        } else {
            String::new()
        },
        report.resolution,
        report.step,
        report.bake_ms,
        100.0 * report.covered_fraction,
        args.output.display(),
        report.asset_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}
