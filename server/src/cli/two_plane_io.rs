//! `lumigraph import` (an image grid or the Stanford archive layout into a two-plane light
//! field) and `lumigraph export` (a two-plane light field back to images or the seed's mosaic).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::two_plane::TwoPlanes;
use lumigraph_core::two_plane_io::{self, GridLayout};

use super::common::progress_bar;

/// `lumigraph import`.
#[derive(Debug, Args)]
pub struct ImportArgs {
    /// A folder of PNGs, one per camera: `grid` reads the last two whole numbers of each name
    /// as its row and column (`003_012.png`), `stanford` the first two (`out_03_12_….png`);
    /// an optional `planes.json` places the planes and a `.npy` beside each PNG gives its depth
    /// (docs/two_plane.md, "Import and export").
    pub source: PathBuf,
    /// Output asset (.lfa).
    #[arg(short, long)]
    pub output: PathBuf,
    /// How the files name their camera: grid or stanford; or lenslet: SOURCE is a raw
    /// plenoptic image (or its folder) with a calibration beside it, lenslet.json or
    /// napari-LF's metadata.txt, naming the radiometry and dark frames and the optics
    /// (docs/two_plane.md, "Lenslet import").
    #[arg(long, default_value = "grid")]
    pub layout: String,
    /// The planes (DESIGN §9's JSON), instead of the folder's planes.json or the default
    /// placement.
    #[arg(long, value_name = "PLANES.json")]
    pub planes: Option<PathBuf>,
}

/// `lumigraph export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// A two-plane light-field asset (.lfa).
    pub asset: PathBuf,
    /// Write the seed's plenoptic texture: every camera's image tiled by (u, v) into one PNG.
    #[arg(
        long,
        value_name = "OUT.png",
        conflicts_with = "images",
        required_unless_present = "images"
    )]
    pub mosaic: Option<PathBuf>,
    /// Write every camera as ROW_COL.png with its depth as ROW_COL.npy, and planes.json: what
    /// `import --layout grid` reads back bit for bit.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
}

/// `import --layout lenslet`.
fn import_lenslet(args: &ImportArgs) -> Result<()> {
    if args.planes.is_some() {
        bail!(
            "--planes does not apply to --layout lenslet: the planes follow from the \
             calibration (docs/two_plane.md, \"Lenslet import\")"
        );
    }
    let bar = progress_bar(0, "resampling views");
    let report =
        lumigraph_core::lenslet::import_lenslet(&args.source, &args.output, &mut |done, total| {
            bar.set_length(u64::from(total));
            bar.set_position(u64::from(done));
        })
        .with_context(|| format!("cannot import {}", args.source.display()))?;
    bar.finish_and_clear();
    let g = &report.grid;
    let [p1, p2] = g.pitch();
    println!(
        "lenslet grid: pitch {p1:.3} x {p2:.3} px, rotation {:.3} deg, a centre at ({:.2}, \
         {:.2}) px, lattice contrast {:.3} / {:.3}",
        g.rotation_deg(),
        g.origin[0],
        g.origin[1],
        g.contrast[0],
        g.contrast[1]
    );
    println!(
        "imported {}x{} views of {}x{} lenslets ({:.1} % of samples inside the pupil; 255 = \
         {:.4} devignetted; st texel {:.4} um, focus in um above the native focal plane): {}",
        report.views,
        report.views,
        report.lenslets[0],
        report.lenslets[1],
        100.0 * report.valid_fraction,
        report.scale,
        report.planes.st.size[0] / f64::from(report.lenslets[0]),
        args.output.display()
    );
    Ok(())
}

pub(super) fn import(args: &ImportArgs) -> Result<()> {
    if args.layout == "lenslet" {
        return import_lenslet(args);
    }
    let layout: GridLayout = args
        .layout
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?;
    let planes = match &args.planes {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the planes file {}", path.display()))?;
            Some(
                TwoPlanes::from_json(&text)
                    .with_context(|| format!("bad planes in {}", path.display()))?,
            )
        }
        None => None,
    };
    if !args.source.is_dir() {
        bail!("{} is not a folder of images", args.source.display());
    }
    let bar = progress_bar(0, "importing cameras");
    let report = two_plane_io::import_grid(
        &args.source,
        layout,
        planes,
        &args.output,
        &mut |done, total| {
            bar.set_length(u64::from(total));
            bar.set_position(u64::from(done));
        },
    )
    .with_context(|| format!("cannot import {}", args.source.display()))?;
    bar.finish_and_clear();
    println!(
        "imported {}x{} cameras of {}x{} px ({}; planes {}): {}",
        report.grid[0],
        report.grid[1],
        report.resolution[0],
        report.resolution[1],
        if report.depth {
            "with depth"
        } else {
            "no depth: stored on the st plane"
        },
        if report.planes_from_file || args.planes.is_some() {
            "as given"
        } else {
            "by default"
        },
        args.output.display()
    );
    Ok(())
}

pub(super) fn export(args: &ExportArgs) -> Result<()> {
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    if let Some(path) = &args.mosaic {
        let (w, h, rgba) = two_plane_io::mosaic(&asset)?;
        lumigraph_core::image_io::write_png_rgba8(path, w, h, &rgba)
            .with_context(|| format!("cannot write {}", path.display()))?;
        println!("wrote the {w}x{h} px mosaic: {}", path.display());
    }
    if let Some(dir) = &args.images {
        let n = two_plane_io::export_images(&asset, dir)?;
        println!(
            "wrote {n} cameras (PNG + depth .npy) and planes.json into {}",
            dir.display()
        );
    }
    Ok(())
}
