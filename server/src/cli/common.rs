//! What several commands share: the GPU, progress bars, the mesh source and its provenance.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use lumigraph_core::asset::Provenance;
use lumigraph_core::bake::sha256_hex;
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::{Mesh, demo_mesh, demo_provenance, load_mesh};
use lumigraph_core::view::View;

pub(super) fn gpu() -> Result<Arc<Gpu>> {
    Ok(Gpu::shared()?)
}

pub(super) fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    let style = ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ({elapsed}, eta {eta})")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar.set_message(what.to_owned());
    bar
}

/// Loads the mesh argument or the demo, with provenance.
pub(super) fn load_source(mesh: Option<&Path>, demo: bool) -> Result<(Mesh, Provenance)> {
    if demo || mesh.is_none() {
        let mesh = demo_mesh()?;
        let provenance = demo_provenance(&mesh);
        return Ok((mesh, provenance));
    }
    let path = mesh.unwrap_or(Path::new(""));
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mesh = load_mesh(path)?;
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    Ok((
        mesh,
        Provenance {
            source_name: name,
            source_sha256: sha256_hex(&bytes),
            ..Default::default()
        },
    ))
}

/// The views of a view file (one view or a list, DESIGN §3 JSON); an empty list is an error.
pub(super) fn read_view_file(path: &Path) -> Result<Vec<View>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read view file {}", path.display()))?;
    let views =
        View::parse_many(&text).with_context(|| format!("bad view file {}", path.display()))?;
    if views.is_empty() {
        bail!("{} holds no views", path.display());
    }
    Ok(views)
}
