//! The `lumigraph` command line: `bake`, `render`, `reference`, `eval`, `info`, `bench` (and
//! `serve`, `healthcheck`).
//!
//! Every command validates its input before touching the GPU and reports any failure as one
//! line (`error: …`) with a non-zero exit status; nothing here panics on bad input.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod args;
mod bake;
mod bench;
mod bench_animation;
mod bench_import;
mod bench_lights;
mod bench_states;
mod bench_two_plane;
mod common;
mod eval;
mod healthcheck;
mod import_views;
mod info;
mod plot;
mod render;
mod serve;
mod two_plane_io;
mod zstack;

pub use args::{DepthArgs, ShadingArgs, ViewArgs};
pub use bake::BakeArgs;
pub use bench::{BenchArgs, BenchCommand, TradeoffArgs};
pub use eval::EvalArgs;
pub use healthcheck::HealthcheckArgs;
pub use info::InfoArgs;
pub use render::{ReferenceArgs, RenderArgs};
pub use serve::ServeArgs;

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
    /// Turn external renders (perspective colour + unfiltered z-depth images with their DESIGN
    /// §3 views) into a spherical light field through depth reliefs (seed 000 §3.4).
    ImportViews(import_views::ImportViewsArgs),
    /// Import a folder of images on a camera grid (or the Stanford archive layout) as a
    /// two-plane light field.
    Import(two_plane_io::ImportArgs),
    /// Synthesise a two-plane light field from a microscope z-stack (multi-page TIFF or a
    /// folder of slices).
    ImportZstack(zstack::ImportZStackArgs),
    /// Export a two-plane light field as per-camera images (+ depth) or the plenoptic mosaic.
    Export(two_plane_io::ExportArgs),
    /// Benchmarks: `bench tradeoff` sweeps the quality knobs (speed against accuracy).
    Bench(BenchArgs),
    /// Serve the HTTP/WebSocket render service and the web viewer (bakes the demo on first start).
    Serve(ServeArgs),
    /// Ask a running service whether it is ready (`GET /readyz`): exit status 0 when it is, for
    /// container health checks.
    Healthcheck(HealthcheckArgs),
}

/// Runs a parsed command.
///
/// # Errors
/// Any failure, with context, for `main` to print as one line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Bake(args) => bake::bake(&args),
        Command::Render(args) => render::render(&args),
        Command::Reference(args) => render::reference(&args),
        Command::Eval(args) => eval::eval(&args),
        Command::Info(args) => info::info(&args),
        Command::ImportViews(args) => import_views::import_views(&args),
        Command::Import(args) => two_plane_io::import(&args),
        Command::ImportZstack(args) => zstack::import_zstack(&args),
        Command::Export(args) => two_plane_io::export(&args),
        Command::Bench(args) => match args.command {
            BenchCommand::Tradeoff(args) => bench::bench_tradeoff(&args),
            BenchCommand::Lights(args) => bench_lights::bench_lights(&args),
            BenchCommand::States(args) => bench_states::bench_states(&args),
            BenchCommand::Import(args) => bench_import::bench_import(&args),
            BenchCommand::Animation(args) => bench_animation::bench_animation(&args),
            BenchCommand::TwoPlane(args) => bench_two_plane::bench_two_plane(&args),
        },
        Command::Serve(args) => serve::serve(&args),
        Command::Healthcheck(args) => healthcheck::healthcheck(&args),
    }
}
