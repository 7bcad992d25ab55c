//! `lumigraph info`: an asset's header, every page verified.

use lumigraph_core::asset::Geometry;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use lumigraph_core::asset::AssetFile;

use crate::service::assets::describe_bytes;

/// `lumigraph info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Light-field asset (.lfa).
    pub asset: PathBuf,
}

pub(super) fn info(args: &InfoArgs) -> Result<()> {
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
    match &h.geometry {
        Geometry::Spherical(g) => println!(
            "spherical light field: {} cameras (level {}), {}×{} px parabolic maps",
            g.camera_count, g.camera_level, g.resolution_px, g.resolution_px
        ),
        Geometry::TwoPlane(g) => {
            let p = &g.planes;
            println!(
                "two-plane light field: {}×{} cameras on a {}×{} uv rectangle, {}×{} px images \
                 of a {}×{} st rectangle, {} apart",
                p.uv.grid[0],
                p.uv.grid[1],
                p.uv.size[0],
                p.uv.size[1],
                p.st.resolution[0],
                p.st.resolution[1],
                p.st.size[0],
                p.st.size[1],
                p.separation()
            );
        }
    }
    println!(
        "decoded size: {} (every image of {} layer(s) × {} state(s)); GPU memory when served: {}",
        describe_bytes(h.decoded_bytes()),
        h.layers.len(),
        h.states.len(),
        describe_bytes(lumigraph_core::render::field_bytes(h))
    );
    match lumigraph_core::light::LightStates::of(h) {
        Ok(Some(lights)) => {
            let stored: u64 = asset
                .index()
                .iter()
                .filter(|e| e.key.state != 0)
                .map(|e| u64::from(e.length))
                .sum();
            let per_camera = h
                .image_bytes(lumigraph_core::asset::Channel::Color)
                .unwrap_or(0);
            println!(
                "light states: {} directions + ambient + normals (colour channel only; depth is the base state's): \
                 {} per light state per camera decoded, {} stored for all of them",
                lights.count,
                describe_bytes(per_camera),
                describe_bytes(stored)
            );
        }
        Ok(None) => {}
        Err(e) => println!("light states: unusable ({e})"),
    }
    if let Some(animation) = lumigraph_core::deform::AnimationInfo::of(h) {
        println!(
            "animation {:?}: {} frames at {} fps over {:.3} s (render --time SECONDS or --frame N)",
            animation.name,
            animation.states.len(),
            animation.fps,
            animation.duration
        );
    }
    for state in lumigraph_core::deform::storage(&asset)? {
        println!(
            "state {:?}: {}, stores {:.2} % of the pages ({} of {}, {} of {} cameras), {}",
            state.name,
            if h.states[usize::from(state.index)]
                .params
                .contains_key(lumigraph_core::deform::ANIMATION_KEY)
            {
                "animation frame"
            } else {
                "deformation"
            },
            100.0 * state.fraction,
            state.stored_pages,
            state.total_pages,
            state.cameras,
            h.camera_count(),
            describe_bytes(state.stored_bytes)
        );
    }
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
