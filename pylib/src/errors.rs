//! The one mapping from core errors to Python exceptions (STYLE: one conversion per boundary).
//!
//! Bad arguments (views, options, shading, array contents) are `ValueError` (or `TypeError` for
//! wrong types, raised by argument extraction); unreadable or corrupt assets are `AssetError`;
//! device failures are `BakeError` / `RenderError` for the call that hit them. Malformed meshes
//! are `MeshError`, a `ValueError`.

use lumigraph_core::asset::AssetError as CoreAssetError;
use lumigraph_core::auto_bake::AutoBakeError;
use lumigraph_core::bake::BakeError as CoreBakeError;
use lumigraph_core::gpu::GpuError;
use lumigraph_core::mesh::MeshError as CoreMeshError;
use lumigraph_core::metrics::MetricsError;
use lumigraph_core::reference::ReferenceError;
use lumigraph_core::render::RenderError as CoreRenderError;
use lumigraph_core::shading::ShadingError;
use lumigraph_core::view::ViewError;
use pyo3::exceptions::{PyException, PyFileNotFoundError, PyValueError};
use pyo3::prelude::*;

pyo3::create_exception!(
    lumigraph,
    LumigraphError,
    PyException,
    "Base class of lumigraph's own errors."
);
pyo3::create_exception!(
    lumigraph,
    AssetError,
    LumigraphError,
    "A light-field asset (.lfa) cannot be read or written: not an asset, a newer format \
     version, truncated, or corrupt (checksum mismatch)."
);
pyo3::create_exception!(
    lumigraph,
    BakeError,
    LumigraphError,
    "Baking failed on the device (for example no GPU/Vulkan driver, or a device limit)."
);
pyo3::create_exception!(
    lumigraph,
    RenderError,
    LumigraphError,
    "Rendering failed on the device (for example no GPU/Vulkan driver, or a device limit)."
);
pyo3::create_exception!(
    lumigraph,
    MeshError,
    PyValueError,
    "A mesh cannot be loaded or is invalid (no triangles, NaN positions, indices out of range)."
);

fn chain(error: &dyn std::error::Error) -> String {
    let mut message = error.to_string();
    let mut source = error.source();
    while let Some(inner) = source {
        message.push_str(": ");
        message.push_str(&inner.to_string());
        source = inner.source();
    }
    message
}

/// Asset errors; a missing file is `FileNotFoundError` like every other Python file API.
pub fn asset(error: &CoreAssetError, path: Option<&str>) -> PyErr {
    if let CoreAssetError::Io(io) = error
        && io.kind() == std::io::ErrorKind::NotFound
    {
        let what = path.unwrap_or("the asset file");
        return PyFileNotFoundError::new_err(format!("no such light-field asset: {what}"));
    }
    let message = chain(error);
    match path {
        Some(path) => AssetError::new_err(format!("{path}: {message}")),
        None => AssetError::new_err(message),
    }
}

pub fn mesh(error: &CoreMeshError) -> PyErr {
    if let CoreMeshError::Io { source, path } = error
        && source.kind() == std::io::ErrorKind::NotFound
    {
        return PyFileNotFoundError::new_err(format!("no such mesh file: {path}"));
    }
    MeshError::new_err(chain(error))
}

pub fn view(error: &ViewError) -> PyErr {
    PyValueError::new_err(error.to_string())
}

pub fn shading(error: &ShadingError) -> PyErr {
    PyValueError::new_err(error.to_string())
}

pub fn bake(error: &CoreBakeError) -> PyErr {
    match error {
        CoreBakeError::BadCameras(n) => PyValueError::new_err(format!(
            "cameras={n} is not an icosphere camera count: use 12, 42, 162 or 642"
        )),
        CoreBakeError::BadResolution(_)
        | CoreBakeError::BadDepthBits(_)
        | CoreBakeError::Lights(_)
        | CoreBakeError::LightsUnlit
        | CoreBakeError::Deform(_)
        | CoreBakeError::StatesWithLights
        | CoreBakeError::BadCodec(_) => PyValueError::new_err(error.to_string()),
        CoreBakeError::Shading(e) => shading(e),
        other => BakeError::new_err(chain(other)),
    }
}

/// Automatic bakes: bad targets are `ValueError`, bake errors as [`bake`], the rest `BakeError`.
pub fn auto_bake(error: &AutoBakeError) -> PyErr {
    match error {
        AutoBakeError::ConflictingTargets
        | AutoBakeError::TargetPsnr(_)
        | AutoBakeError::MaxBytes => PyValueError::new_err(error.to_string()),
        AutoBakeError::Bake(e) => bake(e),
        other => BakeError::new_err(format!("automatic bake failed: {}", chain(other))),
    }
}

pub fn render(error: &CoreRenderError) -> PyErr {
    match error {
        CoreRenderError::View(e) => view(e),
        CoreRenderError::Option(message) => PyValueError::new_err(message.clone()),
        CoreRenderError::Light(e) => PyValueError::new_err(e.to_string()),
        CoreRenderError::Asset(e) => asset(e, None),
        other => RenderError::new_err(chain(other)),
    }
}

pub fn gpu_for_render(error: &GpuError) -> PyErr {
    RenderError::new_err(chain(error))
}

pub fn reference(error: &ReferenceError) -> PyErr {
    match error {
        ReferenceError::View(e) => view(e),
        ReferenceError::Shading(e) => shading(e),
        other => RenderError::new_err(chain(other)),
    }
}

pub fn metrics(error: &MetricsError) -> PyErr {
    PyValueError::new_err(error.to_string())
}
