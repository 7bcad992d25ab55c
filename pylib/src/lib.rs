//! `lumigraph_py`: the native module `lumigraph._lumigraph` behind the Python package `lumigraph`
//! (DESIGN §8). It is a thin front over `lumigraph_core`: no rendering or format logic lives here.
//!
//! Types a reader meets first and how data flows between them:
//!
//! ```text
//!  numpy arrays / file ──Mesh──▶ bake() ──▶ LightField (AssetFile + lazily uploaded GpuLightField)
//!                          │                          │ render(View) (GIL released)
//!                          └── reference_render(View) ┴──▶ Frame (core Frame; numpy on access)
//! ```
//!
//! - `view::PyView` wraps `view::View` (DESIGN §3); every function that takes a view also takes
//!   a dict with the same keys.
//! - `mesh::PyMesh` holds an `Arc<Mesh>` plus its provenance and, once used by the reference
//!   renderer, its GPU upload.
//! - `lightfield::PyLightField` holds the validated asset and its GPU textures.
//! - `frame::PyFrame` holds an `Arc<Frame>`; `.color`, `.depth`, `.coverage` build numpy arrays.
//! - `metrics` exposes `lumigraph_core::metrics` on contiguous numpy arrays; the Python module
//!   `lumigraph.metrics` converts user input to those.
//! - `errors` is the one mapping from core errors to Python exceptions.
//!
//! The GPU device and the three pipelines (baker, renderer, reference renderer) are created once
//! per process (`engines`) and shared by every thread; bake and render run with the GIL
//! released (`py.detach`).

// pyo3 extracts arguments by value (`PathBuf`, `Vec`, `Py<PyAny>`); borrowing them is not an option.
#![allow(clippy::needless_pass_by_value)]

mod arrays;
mod engines;
mod errors;
mod frame;
mod lightfield;
mod mesh;
mod metrics;
mod view;
mod volume;
mod zstack;

use pyo3::prelude::*;

/// The native module. Everything public is re-exported by `lumigraph/__init__.py`.
#[pymodule]
fn _lumigraph(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // On import, before the module starts any thread: keeps Mesa quiet without XDG_RUNTIME_DIR.
    lumigraph_core::gpu::ensure_runtime_dir();
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("LumigraphError", py.get_type::<errors::LumigraphError>())?;
    m.add("AssetError", py.get_type::<errors::AssetError>())?;
    m.add("BakeError", py.get_type::<errors::BakeError>())?;
    m.add("RenderError", py.get_type::<errors::RenderError>())?;
    m.add("MeshError", py.get_type::<errors::MeshError>())?;
    m.add_class::<view::PyView>()?;
    m.add_class::<mesh::PyMesh>()?;
    m.add_class::<frame::PyFrame>()?;
    m.add_class::<lightfield::PyLightField>()?;
    m.add_function(wrap_pyfunction!(view::orbit_views, m)?)?;
    m.add_function(wrap_pyfunction!(lightfield::bake, m)?)?;
    m.add_function(wrap_pyfunction!(lightfield::bake_two_plane, m)?)?;
    m.add_function(wrap_pyfunction!(lightfield::import_lightfield, m)?)?;
    m.add_function(wrap_pyfunction!(zstack::import_zstack, m)?)?;
    m.add_function(wrap_pyfunction!(mesh::reference_render, m)?)?;
    m.add_function(wrap_pyfunction!(volume::reference_volume, m)?)?;
    m.add_function(wrap_pyfunction!(volume::bake_volume, m)?)?;
    m.add_function(wrap_pyfunction!(engines::device_info, m)?)?;
    metrics::register(m)?;
    Ok(())
}
