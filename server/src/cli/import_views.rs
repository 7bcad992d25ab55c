//! `lumigraph import-views`: external renders (perspective colour + unfiltered z-depth, DESIGN
//! §3 views) into a spherical light field through depth reliefs (seed 000 §3.4;
//! `lumigraph_core::import_views`).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use lumigraph_core::asset::Provenance;
use lumigraph_core::bake::{BakeOptions, Baker, sha256_hex};
use lumigraph_core::import_views::{self, DEFAULT_MAX_DEPTH_JUMP, ImportOptions};
use lumigraph_core::shading::Shading;

use super::common::{gpu, progress_bar};

/// `lumigraph import-views`.
#[derive(Debug, Args)]
pub struct ImportViewsArgs {
    /// Folder with `views.json` (a JSON list of DESIGN §3 views) and, for view i, `iii.png`
    /// (colour) and `iii.npy` or `iii.exr` (z-depth along the view's forward axis, +inf where
    /// nothing was hit): what `lumigraph reference MESH --views views.json -o DIR --depth DIR`
    /// writes, or any renderer that follows the convention.
    pub views_dir: PathBuf,
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
    /// Largest relative depth difference between neighbouring pixels joined into one surface;
    /// a larger jump is a silhouette.
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH_JUMP, allow_hyphen_values = true)]
    pub max_depth_jump: f32,
    /// Smallest |cos| between a relief surface and the ray to its view's eye: surfaces seen
    /// more obliquely are left to the views that see them better (0 keeps every surface).
    #[arg(long, default_value_t = import_views::DEFAULT_MIN_FACING, allow_hyphen_values = true)]
    pub min_facing: f32,
}

pub(super) fn import_views(args: &ImportViewsArgs) -> Result<()> {
    let options = BakeOptions {
        cameras: args.cameras,
        resolution: args.resolution,
        // The images carry their renderer's shading: the bake copies their colours.
        shading: Shading {
            unlit: true,
            ..Shading::default()
        },
        depth_bits: args.depth_bits,
        lights: None,
        // Each relief faces its view; its back belongs to the views on the other side.
        one_sided: true,
        color_codec: None,
        depth_codec: None,
    };
    options.validate()?;
    let images = import_views::read_views(&args.views_dir)?;
    let mesh = import_views::relief_mesh(
        &images,
        &ImportOptions {
            max_depth_jump: args.max_depth_jump,
            min_facing: args.min_facing,
        },
    )?;
    let list = std::fs::read(args.views_dir.join("views.json"))
        .with_context(|| format!("cannot read {}", args.views_dir.display()))?;
    let provenance = Provenance {
        source_name: format!(
            "views:{}",
            args.views_dir.file_name().map_or_else(
                || args.views_dir.display().to_string(),
                |n| n.to_string_lossy().into_owned()
            )
        ),
        source_sha256: sha256_hex(&list),
        ..Provenance::default()
    };
    let baker = Baker::new(gpu()?);
    let bar = progress_bar(u64::from(options.cameras), "baking the reliefs");
    let report = baker.bake_to_file(
        &mesh,
        &options,
        &provenance,
        &args.output,
        &mut |done, _| bar.set_position(u64::from(done)),
    )?;
    bar.finish_and_clear();
    println!(
        "imported {} views ({} relief triangles) into {} cameras at {} px in {:.0} ms: {} ({:.1} MiB)",
        images.len(),
        mesh.triangles.len(),
        report.cameras,
        report.resolution,
        report.bake_ms,
        args.output.display(),
        report.asset_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}
