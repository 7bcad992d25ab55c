//! `lumigraph.metrics`: the core's metrics (DESIGN §3) on Frames or numpy images.

use lumigraph_core::frame::Frame;
use lumigraph_core::metrics;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays;
use crate::errors;
use crate::frame::PyFrame;

/// An RGBA8 image from a Frame or an (H, W, 3|4) uint8 array.
fn image(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(u32, u32, Vec<u8>)> {
    if let Ok(frame) = obj.cast::<PyFrame>() {
        let f = &frame.get().frame;
        return Ok((f.width, f.height, f.color.clone()));
    }
    arrays::rgba8(obj, name, false)
}

fn same_size(a: (u32, u32), b: (u32, u32)) -> PyResult<()> {
    if a == b {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "image sizes differ: {}x{} vs {}x{} (width x height)",
            a.0, a.1, b.0, b.1
        )))
    }
}

fn pair(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<(u32, u32, Vec<u8>, Vec<u8>)> {
    let (wa, ha, ia) = image(a, "a")?;
    let (wb, hb, ib) = image(b, "b")?;
    same_size((wa, ha), (wb, hb))?;
    Ok((wa, ha, ia, ib))
}

/// psnr(a, b, *, mask=None) -> float
///
/// PSNR in dB of two 8-bit images on R, G, B with data range 255 (alpha ignored): equal to
/// ``skimage.metrics.peak_signal_noise_ratio(a[..., :3], b[..., :3], data_range=255)``, or over
/// the pixels where ``mask`` (H, W) bool is True. ``a`` and ``b`` are Frames or (H, W, 3|4)
/// uint8 arrays. ``inf`` when they agree on every compared value (and for an empty mask).
#[pyfunction]
#[pyo3(signature = (a, b, *, mask = None))]
fn psnr(
    py: Python<'_>,
    a: &Bound<'_, PyAny>,
    b: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
) -> PyResult<f64> {
    let (w, h, ia, ib) = pair(a, b)?;
    let mask = mask.map(|m| arrays::mask(m, "mask", w, h)).transpose()?;
    py.detach(|| metrics::psnr(&ia, &ib, w, h, mask.as_deref()))
        .map_err(|e| errors::metrics(&e))
}

fn coverage(
    obj: &Bound<'_, PyAny>,
    explicit: Option<&Bound<'_, PyAny>>,
    name: &str,
    w: u32,
    h: u32,
) -> PyResult<Vec<bool>> {
    match (obj.cast::<PyFrame>(), explicit) {
        (_, Some(mask)) => arrays::mask(mask, name, w, h),
        (Ok(frame), None) => Ok(frame.get().frame.coverage()),
        (Err(_), None) => Err(PyTypeError::new_err(format!(
            "masked_psnr on arrays needs {name}=(H, W) bool (or pass Frames, which carry coverage)"
        ))),
    }
}

/// masked_psnr(test, reference, *, test_coverage=None, reference_coverage=None) -> float
///
/// PSNR in dB over the union of the two coverage masks (DESIGN §3: the harsher number, used for
/// every quality target): pixels covered by either image. Frames carry their coverage; for
/// arrays pass both masks as (H, W) bool.
#[pyfunction]
#[pyo3(signature = (test, reference, *, test_coverage = None, reference_coverage = None))]
fn masked_psnr(
    py: Python<'_>,
    test: &Bound<'_, PyAny>,
    reference: &Bound<'_, PyAny>,
    test_coverage: Option<&Bound<'_, PyAny>>,
    reference_coverage: Option<&Bound<'_, PyAny>>,
) -> PyResult<f64> {
    let (w, h, it, ir) = pair(test, reference)?;
    let ct = coverage(test, test_coverage, "test_coverage", w, h)?;
    let cr = coverage(reference, reference_coverage, "reference_coverage", w, h)?;
    let union: Vec<bool> = ct.iter().zip(&cr).map(|(a, b)| *a || *b).collect();
    py.detach(|| metrics::psnr(&it, &ir, w, h, Some(&union)))
        .map_err(|e| errors::metrics(&e))
}

/// ssim(a, b) -> float
///
/// Mean SSIM on R, G, B, exactly ``skimage.metrics.structural_similarity(a[..., :3], b[..., :3],
/// channel_axis=-1, data_range=255)`` (7×7 uniform window). In [-1, 1]; images must be at least
/// 7×7. ``a`` and ``b`` are Frames or (H, W, 3|4) uint8 arrays.
#[pyfunction]
fn ssim(py: Python<'_>, a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<f64> {
    let (w, h, ia, ib) = pair(a, b)?;
    py.detach(|| metrics::ssim(&ia, &ib, w, h))
        .map_err(|e| errors::metrics(&e))
}

/// mae(a, b) -> float
///
/// Mean absolute difference per R, G, B component over the whole image, in 8-bit steps
/// (0..255). ``a`` and ``b`` are Frames or (H, W, 3|4) uint8 arrays.
#[pyfunction]
fn mae(py: Python<'_>, a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<f64> {
    let (w, h, ia, ib) = pair(a, b)?;
    py.detach(|| metrics::mae(&ia, &ib, w, h))
        .map_err(|e| errors::metrics(&e))
}

fn depth_of(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(u32, u32, Vec<f32>)> {
    if let Ok(frame) = obj.cast::<PyFrame>() {
        let f = &frame.get().frame;
        return Ok((f.width, f.height, f.depth.clone()));
    }
    arrays::depth(obj, name)
}

/// depth_error(test, reference) -> dict
///
/// Absolute z-depth error in world units over the pixels both cover (finite depth in both):
/// ``{"count", "median", "mean", "max", "p95"}`` (numpy's median and linear 95th percentile;
/// NaN when no pixel is covered by both). Frames or (H, W) float depth arrays (+inf = no hit).
#[pyfunction]
fn depth_error<'py>(
    py: Python<'py>,
    test: &Bound<'py, PyAny>,
    reference: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let (wt, ht, dt) = depth_of(test, "test")?;
    let (wr, hr, dr) = depth_of(reference, "reference")?;
    same_size((wt, ht), (wr, hr))?;
    let stats = py
        .detach(|| metrics::depth_errors(&dt, &dr))
        .map_err(|e| errors::metrics(&e))?;
    let d = PyDict::new(py);
    d.set_item("count", stats.count)?;
    d.set_item("median", stats.median)?;
    d.set_item("mean", stats.mean)?;
    d.set_item("max", stats.max)?;
    d.set_item("p95", stats.p95)?;
    Ok(d)
}

fn frame_of(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<std::sync::Arc<Frame>> {
    obj.cast::<PyFrame>()
        .map(|f| f.get().frame.clone())
        .map_err(|_| PyTypeError::new_err(format!("{name} must be a lumigraph.Frame")))
}

/// compare(test, reference) -> dict
///
/// Every DESIGN §3 number for two Frames of the same view: ``psnr``, ``masked_psnr`` (union of
/// coverage), ``intersection_psnr``, ``ssim``, ``mae``, ``mask_mismatch_px``, ``union_px``,
/// ``intersection_px`` and ``depth`` (as :func:`depth_error`). What ``lumigraph eval`` reports.
#[pyfunction]
fn compare<'py>(
    py: Python<'py>,
    test: &Bound<'py, PyAny>,
    reference: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let t = frame_of(test, "test")?;
    let r = frame_of(reference, "reference")?;
    let comparison = py
        .detach(|| metrics::compare(&t, &r))
        .map_err(|e| errors::metrics(&e))?;
    // Through JSON, with the core's own encoding of non-finite numbers turned back into floats.
    let d = PyDict::new(py);
    d.set_item("psnr", comparison.psnr)?;
    d.set_item("masked_psnr", comparison.masked_psnr)?;
    d.set_item("intersection_psnr", comparison.intersection_psnr)?;
    d.set_item("ssim", comparison.ssim)?;
    d.set_item("mae", comparison.mae)?;
    d.set_item("mask_mismatch_px", comparison.mask_mismatch_px)?;
    d.set_item("union_px", comparison.union_px)?;
    d.set_item("intersection_px", comparison.intersection_px)?;
    let depth = PyDict::new(py);
    depth.set_item("count", comparison.depth.count)?;
    depth.set_item("median", comparison.depth.median)?;
    depth.set_item("mean", comparison.depth.mean)?;
    depth.set_item("max", comparison.depth.max)?;
    depth.set_item("p95", comparison.depth.p95)?;
    d.set_item("depth", depth)?;
    Ok(d.into_any())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(psnr, m)?)?;
    m.add_function(wrap_pyfunction!(masked_psnr, m)?)?;
    m.add_function(wrap_pyfunction!(ssim, m)?)?;
    m.add_function(wrap_pyfunction!(mae, m)?)?;
    m.add_function(wrap_pyfunction!(depth_error, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    Ok(())
}
