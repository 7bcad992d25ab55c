//! `Frame`: one rendered image (colour, depth, coverage, stats) as numpy arrays.

use std::sync::Arc;

use lumigraph_core::frame::Frame;
use numpy::{IntoPyArray, PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A rendered image (DESIGN §3). Frames are immutable; every array property returns a new
/// numpy array (a copy), so it is safe to modify.
///
/// Attributes:
///     color: (H, W, 4) uint8 RGBA, display values without a gamma curve; outside coverage the
///         render's background (default transparent black).
///     depth: (H, W) float32 z-depth along the view's forward axis, world units; +inf where
///         nothing is hit.
///     coverage: (H, W) bool, True where the object is hit (``np.isfinite(depth)``).
///     stats: dict with ``render_ms`` (GPU work plus readback, ms), ``rays`` (pixels whose ray
///         met the bounding sphere), ``steps`` and ``fetches`` (march steps and texture fetches,
///         0 where the renderer does not count them).
#[pyclass(name = "Frame", module = "lumigraph", frozen)]
pub struct PyFrame {
    pub frame: Arc<Frame>,
}

impl PyFrame {
    pub fn new(frame: Frame, background: Option<[u8; 4]>) -> Self {
        let frame = match background {
            Some(bg) => Frame {
                color: frame.with_background(bg),
                ..frame
            },
            None => frame,
        };
        Self {
            frame: Arc::new(frame),
        }
    }
}

/// A background colour: 3 or 4 integers in 0..=255 (RGB gets alpha 255).
pub fn parse_background(obj: &Bound<'_, PyAny>) -> PyResult<[u8; 4]> {
    let values: Vec<i64> = obj.extract().map_err(|_| {
        PyTypeError::new_err("background must be a sequence of 3 or 4 integers in 0..255 (RGB[A])")
    })?;
    if !matches!(values.len(), 3 | 4) || values.iter().any(|v| !(0..=255).contains(v)) {
        return Err(PyValueError::new_err(format!(
            "background {values:?} must be 3 or 4 integers in 0..255 (RGB[A])"
        )));
    }
    Ok([
        values[0] as u8,
        values[1] as u8,
        values[2] as u8,
        values.get(3).map_or(255, |&a| a as u8),
    ])
}

#[pymethods]
impl PyFrame {
    /// (H, W, 4) uint8 RGBA colour (a copy).
    #[getter]
    fn color<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let f = &self.frame;
        f.color
            .clone()
            .into_pyarray(py)
            .reshape([f.height as usize, f.width as usize, 4])
    }

    /// (H, W) float32 z-depth in world units, +inf where nothing is hit (a copy).
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let f = &self.frame;
        f.depth
            .clone()
            .into_pyarray(py)
            .reshape([f.height as usize, f.width as usize])
    }

    /// (H, W) bool, True where the object is hit.
    #[getter]
    fn coverage<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<bool>>> {
        let f = &self.frame;
        f.coverage()
            .into_pyarray(py)
            .reshape([f.height as usize, f.width as usize])
    }

    /// Render statistics: render_ms (float, ms), rays, steps, fetches (int).
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.frame.stats;
        let d = PyDict::new(py);
        d.set_item("render_ms", s.render_ms)?;
        d.set_item("rays", s.rays)?;
        d.set_item("steps", s.steps)?;
        d.set_item("fetches", s.fetches)?;
        Ok(d)
    }

    /// Image width in pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.frame.width
    }

    /// Image height in pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.frame.height
    }

    /// Number of covered pixels.
    #[getter]
    fn covered_px(&self) -> usize {
        self.frame.covered_count()
    }

    fn __repr__(&self) -> String {
        let f = &self.frame;
        format!(
            "Frame({}x{}, covered_px={}, render_ms={:.2})",
            f.width,
            f.height,
            f.covered_count(),
            f.stats.render_ms
        )
    }
}
