//! `lumigraph import-zstack`: a microscope z-stack (multi-page TIFF or a folder of slices) into
//! a two-plane light field synthesised from it (docs/zstack.md).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use lumigraph_core::zstack::{self, Composite, ZStackOptions};

use super::args::{parse_f64s, parse_size_pair, parse_size_triple, parse_vec3_f64};
use super::common::progress_bar;

/// `lumigraph import-zstack`.
#[derive(Debug, Args)]
pub struct ImportZStackArgs {
    /// A multi-page TIFF, or a folder of single-slice TIFFs or PNGs ordered by the numbers in
    /// their names; 8- or 16-bit grey.
    #[arg(required_unless_present = "demo", conflicts_with = "demo")]
    pub stack: Option<PathBuf>,
    /// Instead of a stack: a synthetic fluorescence specimen of WxHxD voxels (filaments and
    /// beads, 16-bit, 0.2 x 0.2 x 1 um).
    #[arg(long, value_name = "WxHxD", value_parser = parse_size_triple)]
    pub demo: Option<[u32; 3]>,
    /// Output asset (.lfa).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Voxel spacing X,Y,Z (instead of ImageJ's metadata, else 1,1,1).
    #[arg(long, value_parser = parse_vec3_f64, value_name = "SX,SY,SZ")]
    pub spacing: Option<[f64; 3]>,
    /// Camera grid NUxNV.
    #[arg(long, value_parser = parse_size_pair, default_value = "9x9")]
    pub grid: [u32; 2],
    /// Half-angle of the cameras' cone, degrees.
    #[arg(long, default_value_t = zstack::DEFAULT_ANGLE_DEG)]
    pub angle: f64,
    /// How a ray's samples combine: mip (maximum intensity) or over (emission-absorption).
    #[arg(long, default_value = "mip")]
    pub composite: String,
    /// Grey values mapped to black and white, LO,HI (default: the 0.1 and 99.9 percentiles).
    #[arg(long, value_name = "LO,HI", value_parser = parse_f64s::<2>)]
    pub window: Option<[f64; 2]>,
    /// over: opacity per slice at full intensity.
    #[arg(long, default_value_t = zstack::DEFAULT_OPACITY)]
    pub opacity: f64,
    /// mip: fraction of the window a ray's maximum must reach to store its depth (else the
    /// middle slice's plane).
    #[arg(long, default_value_t = zstack::DEFAULT_DEPTH_THRESHOLD)]
    pub depth_threshold: f64,
}

pub(super) fn import_zstack(args: &ImportZStackArgs) -> Result<()> {
    let composite: Composite = args
        .composite
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?;
    let options = ZStackOptions {
        grid: args.grid,
        angle_deg: args.angle,
        composite,
        window: args.window,
        opacity: args.opacity,
        depth_threshold: args.depth_threshold,
    };
    options.validate()?;
    let (stack, source) = match (&args.stack, args.demo) {
        (Some(path), _) => (
            zstack::read_stack(path, args.spacing)
                .with_context(|| format!("cannot read the z-stack {}", path.display()))?,
            path.clone(),
        ),
        (None, Some(size)) => {
            let mut stack = zstack::demo_stack(size).context("the demo stack")?;
            if let Some(spacing) = args.spacing {
                stack =
                    zstack::ZStack::new(stack.size, stack.bits, spacing, stack.voxels().to_vec())?;
            }
            let [w, h, d] = size;
            (stack, PathBuf::from(format!("demo-{w}x{h}x{d}")))
        }
        (None, None) => anyhow::bail!("give a stack or --demo WxHxD"),
    };
    let [nu, nv] = args.grid;
    let bar = progress_bar(u64::from(nu * nv), "synthesising cameras");
    let report = zstack::import_zstack(&stack, &source, &options, &args.output, &mut |done, _| {
        bar.set_position(u64::from(done));
    })
    .with_context(|| format!("cannot import {}", source.display()))?;
    bar.finish_and_clear();
    let [nx, ny, nz] = report.size;
    let [sx, sy, sz] = report.spacing;
    let p = &report.planes;
    println!(
        "z-stack {nx}x{ny}x{nz} at {} bits, spacing {sx} x {sy} x {sz}, window {} to {}: {}x{} \
         cameras {:.4} above the middle slice, +-{} deg ({composite:?}), {:.0} ms: {}",
        report.bits,
        report.window[0],
        report.window[1],
        p.uv.grid[0],
        p.uv.grid[1],
        p.uv.center[2],
        args.angle,
        report.ms,
        args.output.display()
    );
    Ok(())
}
