//! `View`: the DESIGN §3 pinhole view, and the parser that accepts a `View` or a dict.

use lumigraph_core::view::{DEFAULT_MAX_VIEW_PX, View, random_orbit_views};
use numpy::{IntoPyArray, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyMapping};

use crate::errors;

const FIELDS: [&str; 6] = ["eye", "target", "up", "yfov_deg", "width", "height"];

/// View(*, eye, target, up=(0.0, 1.0, 0.0), yfov_deg, width, height)
///
/// A pinhole camera in the mesh's own world coordinates (DESIGN §3), validated on creation.
///
/// Args:
///     eye: camera position (x, y, z), world units.
///     target: point looked at, world units; must differ from ``eye``.
///     up: approximate up direction; made orthogonal to the viewing direction; must not be
///         parallel to it. Default +y.
///     yfov_deg: vertical field of view in degrees, in (0, 180).
///     width, height: image size in pixels, 1..8192 each.
///
/// Pixel (i, j) (row i from the top, column j) looks along
/// ``normalize(x*right + y*true_up + forward)`` with ``x = (j+0.5-W/2)/f``,
/// ``y = -(i+0.5-H/2)/f``, ``f = (H/2)/tan(yfov/2)`` (see :meth:`ray_directions`).
/// Every function that takes a view also accepts a dict with these keys (``up`` optional).
///
/// Raises:
///     ValueError: a non-finite number, eye == target, up parallel to the view direction,
///         yfov outside (0, 180) or a size outside 1..8192.
///     TypeError: a field of the wrong type (e.g. a float width).
#[pyclass(name = "View", module = "lumigraph", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyView {
    pub view: View,
}

impl PyView {
    fn checked(view: View) -> PyResult<Self> {
        view.basis(DEFAULT_MAX_VIEW_PX)
            .map_err(|e| errors::view(&e))?;
        Ok(Self { view })
    }
}

fn field<'py, T: for<'a> FromPyObjectOwned<'py>>(
    value: &Bound<'py, PyAny>,
    name: &str,
    expected: &str,
) -> PyResult<T> {
    value.extract::<T>().map_err(|_| {
        let type_name = value
            .get_type()
            .name()
            .map_or_else(|_| "?".to_owned(), |n| n.to_string());
        PyTypeError::new_err(format!(
            "view field `{name}` must be {expected}, got {type_name}: {}",
            value
                .repr()
                .map_or_else(|_| "?".to_owned(), |r| r.to_string())
        ))
    })
}

use pyo3::conversion::FromPyObjectOwned;

fn vec3(value: &Bound<'_, PyAny>, name: &str) -> PyResult<[f64; 3]> {
    field::<[f64; 3]>(value, name, "a sequence of 3 numbers")
}

/// Parses a `View` or a mapping with the DESIGN §3 keys; unknown keys are rejected.
pub fn parse_view(obj: &Bound<'_, PyAny>) -> PyResult<View> {
    if let Ok(view) = obj.cast::<PyView>() {
        return Ok(view.get().view.clone());
    }
    let Ok(mapping) = obj.cast::<PyMapping>() else {
        let type_name = obj
            .get_type()
            .name()
            .map_or_else(|_| "?".to_owned(), |n| n.to_string());
        return Err(PyTypeError::new_err(format!(
            "a view must be a lumigraph.View or a dict with keys eye, target, up, yfov_deg, \
             width, height; got {type_name}"
        )));
    };
    for key in mapping.keys()?.iter() {
        let key: String = key
            .extract()
            .map_err(|_| PyTypeError::new_err("view dict keys must be strings"))?;
        if !FIELDS.contains(&key.as_str()) {
            return Err(PyValueError::new_err(format!(
                "unknown view field `{key}`: a view has eye, target, up, yfov_deg, width, height"
            )));
        }
    }
    let get = |key: &str| -> PyResult<Bound<'_, PyAny>> {
        if mapping.contains(key)? {
            mapping.get_item(key)
        } else {
            Err(PyValueError::new_err(format!(
                "view is missing the field `{key}`"
            )))
        }
    };
    let up = if mapping.contains("up")? {
        vec3(&mapping.get_item("up")?, "up")?
    } else {
        [0.0, 1.0, 0.0]
    };
    let view = View {
        eye: vec3(&get("eye")?, "eye")?,
        target: vec3(&get("target")?, "target")?,
        up,
        yfov_deg: field(&get("yfov_deg")?, "yfov_deg", "a number")?,
        width: field(&get("width")?, "width", "an integer in 1..8192")?,
        height: field(&get("height")?, "height", "an integer in 1..8192")?,
    };
    view.basis(DEFAULT_MAX_VIEW_PX)
        .map_err(|e| errors::view(&e))?;
    Ok(view)
}

/// Parses one view or an iterable of views.
pub fn parse_views(obj: &Bound<'_, PyAny>) -> PyResult<Vec<View>> {
    if obj.cast::<PyView>().is_ok() || obj.cast::<PyMapping>().is_ok() {
        return Err(PyTypeError::new_err(
            "render_many takes a list of views; use render() for one view",
        ));
    }
    obj.try_iter()
        .map_err(|_| PyTypeError::new_err("views must be an iterable of View objects or dicts"))?
        .map(|item| parse_view(&item?))
        .collect()
}

#[pymethods]
impl PyView {
    #[new]
    #[pyo3(signature = (*, eye, target, up = [0.0, 1.0, 0.0], yfov_deg, width, height))]
    fn new(
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        yfov_deg: f64,
        width: u32,
        height: u32,
    ) -> PyResult<Self> {
        Self::checked(View {
            eye,
            target,
            up,
            yfov_deg,
            width,
            height,
        })
    }

    /// View.from_dict(d) -> View
    ///
    /// Builds a view from a dict with the DESIGN §3 keys (``up`` optional, unknown keys
    /// rejected with ValueError).
    #[staticmethod]
    fn from_dict(d: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(Self {
            view: parse_view(d)?,
        })
    }

    /// View.from_json(text) -> View
    ///
    /// Parses the JSON object the CLI and the service read (DESIGN §3). Numbers are read by
    /// Python's ``json`` (exact float round trip), then checked as :meth:`from_dict` does.
    #[staticmethod]
    fn from_json(py: Python<'_>, text: &str) -> PyResult<Self> {
        let value = py
            .import("json")?
            .call_method1("loads", (text,))
            .map_err(|e| PyValueError::new_err(format!("invalid view JSON: {e}")))?;
        Ok(Self {
            view: parse_view(&value)?,
        })
    }

    /// to_dict() -> dict
    ///
    /// The view as a dict with the DESIGN §3 keys (tuples for vectors).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let v = &self.view;
        d.set_item("eye", (v.eye[0], v.eye[1], v.eye[2]))?;
        d.set_item("target", (v.target[0], v.target[1], v.target[2]))?;
        d.set_item("up", (v.up[0], v.up[1], v.up[2]))?;
        d.set_item("yfov_deg", v.yfov_deg)?;
        d.set_item("width", v.width)?;
        d.set_item("height", v.height)?;
        Ok(d)
    }

    /// to_json() -> str
    ///
    /// The view as the JSON object the CLI and the service read.
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.view).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// ray_directions() -> numpy.ndarray
    ///
    /// Unit world-space direction of every pixel's centre ray, shape (height, width, 3), float64,
    /// exactly as the renderers use them (DESIGN §3). Rays start at ``eye``; the z-depth of a
    /// hit at distance t is ``t * dot(direction, forward)``.
    fn ray_directions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let basis = self
            .view
            .basis(DEFAULT_MAX_VIEW_PX)
            .map_err(|e| errors::view(&e))?;
        let (w, h) = (self.view.width, self.view.height);
        let mut out = Vec::with_capacity(w as usize * h as usize * 3);
        for i in 0..h {
            for j in 0..w {
                out.extend_from_slice(&basis.pixel_dir(i, j).to_array());
            }
        }
        out.into_pyarray(py).reshape([h as usize, w as usize, 3])
    }

    /// Unit viewing direction ``normalize(target - eye)``.
    #[getter]
    fn forward(&self) -> PyResult<(f64, f64, f64)> {
        let b = self
            .view
            .basis(DEFAULT_MAX_VIEW_PX)
            .map_err(|e| errors::view(&e))?;
        Ok((b.forward.x, b.forward.y, b.forward.z))
    }

    /// Camera position, world units.
    #[getter]
    fn eye(&self) -> (f64, f64, f64) {
        let e = self.view.eye;
        (e[0], e[1], e[2])
    }

    /// Point looked at, world units.
    #[getter]
    fn target(&self) -> (f64, f64, f64) {
        let t = self.view.target;
        (t[0], t[1], t[2])
    }

    /// Approximate up direction.
    #[getter]
    fn up(&self) -> (f64, f64, f64) {
        let u = self.view.up;
        (u[0], u[1], u[2])
    }

    /// Vertical field of view, degrees.
    #[getter]
    fn yfov_deg(&self) -> f64 {
        self.view.yfov_deg
    }

    /// Image width, pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.view.width
    }

    /// Image height, pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.view.height
    }

    fn __repr__(&self) -> String {
        let v = &self.view;
        format!(
            "View(eye={:?}, target={:?}, up={:?}, yfov_deg={}, width={}, height={})",
            v.eye, v.target, v.up, v.yfov_deg, v.width, v.height
        )
    }
}

/// orbit_views(center, distance, n, *, seed=0, yfov_deg=40.0, size=256) -> list[View]
///
/// ``n`` views with the eye uniformly random on a sphere of radius ``distance`` (world units)
/// around ``center``, looking at ``center``, +y up (+z when looking straight down or up); the
/// views the CLI's ``eval`` uses (there ``distance`` = 2.5 × the bounding radius). Deterministic
/// for a given ``seed``. ``size`` is width and height in pixels.
#[pyfunction]
#[pyo3(signature = (center, distance, n, *, seed = 0, yfov_deg = 40.0, size = 256))]
pub fn orbit_views(
    center: [f64; 3],
    distance: f64,
    n: usize,
    seed: u64,
    yfov_deg: f64,
    size: u32,
) -> PyResult<Vec<PyView>> {
    if !(distance.is_finite() && distance > 0.0) {
        return Err(PyValueError::new_err(format!(
            "distance {distance} must be finite and > 0"
        )));
    }
    random_orbit_views(center, distance, n, seed, yfov_deg, size)
        .into_iter()
        .map(PyView::checked)
        .collect()
}
