//! The process-wide GPU device and pipelines, created on first use and shared by every thread
//! (building a pipeline costs shader compilation; the device is one per process, DESIGN §6).

use std::sync::{Arc, OnceLock};

use lumigraph_core::bake::Baker;
use lumigraph_core::gpu::{Gpu, GpuError};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::Renderer;
use lumigraph_core::two_plane_render::TwoPlaneRenderer;
use lumigraph_core::volume::bake::VolumeBaker;
use pyo3::prelude::*;

static BAKER: OnceLock<Baker> = OnceLock::new();
static RENDERER: OnceLock<Renderer> = OnceLock::new();
static REFERENCE: OnceLock<ReferenceRenderer> = OnceLock::new();
static VOLUME_BAKER: OnceLock<VolumeBaker> = OnceLock::new();
static TWO_PLANE: OnceLock<TwoPlaneRenderer> = OnceLock::new();

/// The shared device (`Gpu::shared` remembers a failure, so a missing driver is reported on
/// every call with the same message).
pub fn gpu() -> Result<Arc<Gpu>, GpuError> {
    Gpu::shared()
}

/// The baker; call with the GIL released.
pub fn baker() -> Result<&'static Baker, GpuError> {
    if let Some(baker) = BAKER.get() {
        return Ok(baker);
    }
    let gpu = gpu()?;
    Ok(BAKER.get_or_init(|| Baker::new(gpu)))
}

/// The volume baker; call with the GIL released.
pub fn volume_baker() -> Result<&'static VolumeBaker, GpuError> {
    if let Some(baker) = VOLUME_BAKER.get() {
        return Ok(baker);
    }
    let gpu = gpu()?;
    Ok(VOLUME_BAKER.get_or_init(|| VolumeBaker::new(gpu)))
}

/// The light-field renderer; call with the GIL released.
pub fn renderer() -> Result<&'static Renderer, GpuError> {
    if let Some(renderer) = RENDERER.get() {
        return Ok(renderer);
    }
    let gpu = gpu()?;
    Ok(RENDERER.get_or_init(|| Renderer::new(gpu)))
}

/// The two-plane light-field renderer; call with the GIL released.
pub fn two_plane_renderer() -> Result<&'static TwoPlaneRenderer, GpuError> {
    if let Some(renderer) = TWO_PLANE.get() {
        return Ok(renderer);
    }
    let gpu = gpu()?;
    Ok(TWO_PLANE.get_or_init(|| TwoPlaneRenderer::new(gpu)))
}

/// The reference rasterizer; call with the GIL released.
pub fn reference() -> Result<&'static ReferenceRenderer, GpuError> {
    if let Some(reference) = REFERENCE.get() {
        return Ok(reference);
    }
    let gpu = gpu()?;
    Ok(REFERENCE.get_or_init(|| ReferenceRenderer::new(gpu)))
}

/// device_info() -> str
///
/// One line naming the GPU adapter lumigraph renders on (for example
/// "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, CPU)" on a CPU-only machine with Mesa lavapipe).
/// The backend is chosen by the environment variable ``LUMIGRAPH_BACKEND``
/// (vulkan | gl | metal | dx12 | auto).
///
/// Raises:
///     RenderError: no adapter could be opened (the message names the package to install).
#[pyfunction]
pub fn device_info(py: Python<'_>) -> PyResult<String> {
    py.detach(gpu)
        .map(|gpu| gpu.adapter_summary())
        .map_err(|e| crate::errors::gpu_for_render(&e))
}
