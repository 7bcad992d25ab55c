//! Volumes from Python: `reference_volume` ray-casts a numpy array or a volume file directly
//! (DESIGN §9, `lumigraph_core::volume::raycast`), the ground truth for volume light fields.

use lumigraph_core::volume::raycast::{RaycastOptions, raycast};
use lumigraph_core::volume::tf::{PRESETS, TransferFunction};
use lumigraph_core::volume::{LoadOptions, Volume, VolumeError};
use pyo3::exceptions::{PyFileNotFoundError, PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::frame::PyFrame;
use crate::{arrays, view};

fn volume_error(error: &VolumeError) -> PyErr {
    match error {
        VolumeError::Io { path, source } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(format!("no such volume file: {}", path.display()))
        }
        other => PyValueError::new_err(other.to_string()),
    }
}

/// A preset name, a JSON string, or a dict/list (serialized with `json.dumps`).
fn parse_tf(tf: &Bound<'_, PyAny>) -> PyResult<TransferFunction> {
    let text: String = if let Ok(text) = tf.extract::<String>() {
        if PRESETS.contains(&text.as_str()) {
            return TransferFunction::preset(&text)
                .map_err(|e| PyValueError::new_err(e.to_string()));
        }
        if !text.trim_start().starts_with('{') {
            return Err(PyValueError::new_err(format!(
                "tf {text:?} is neither a preset ({}) nor transfer-function JSON",
                PRESETS.join(", ")
            )));
        }
        text
    } else if tf.is_instance_of::<pyo3::types::PyDict>() {
        tf.py()
            .import("json")?
            .call_method1("dumps", (tf,))?
            .extract()?
    } else {
        return Err(PyTypeError::new_err(
            "tf must be a preset name, a JSON string or a dict with \"points\" or \"labels\"",
        ));
    };
    TransferFunction::from_json(&text).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Native direct ray cast (the Python wrapper documents it).
#[pyfunction]
#[pyo3(signature = (volume, view, *, tf, spacing, origin, labels, shade, step, depth_threshold, light, ambient))]
pub fn reference_volume(
    py: Python<'_>,
    volume: &Bound<'_, PyAny>,
    view: &Bound<'_, PyAny>,
    tf: &Bound<'_, PyAny>,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    labels: bool,
    shade: bool,
    step: Option<f64>,
    depth_threshold: f64,
    light: [f64; 3],
    ambient: f64,
) -> PyResult<PyFrame> {
    let view = view::parse_view(view)?;
    let tf = parse_tf(tf)?;
    let volume = if let Ok(path) = volume.extract::<std::path::PathBuf>() {
        if origin.is_some() {
            return Err(PyValueError::new_err(
                "origin applies to arrays; a volume file carries its own",
            ));
        }
        py.detach(|| Volume::load(&path, &LoadOptions { labels, spacing }))
            .map_err(|e| volume_error(&e))?
    } else {
        let (dims, voxels) = arrays::volume(volume, "volume", labels)?;
        let s = spacing.unwrap_or([1.0; 3]);
        let affine = [[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]];
        Volume::from_values(dims, voxels, affine, origin.unwrap_or([0.0; 3]))
            .map_err(|e| volume_error(&e))?
    };
    let options = RaycastOptions {
        step,
        shade,
        light,
        ambient,
        depth_threshold,
    };
    let image = py
        .detach(|| raycast(&volume, &tf, &view, &options))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(PyFrame::new(image.to_frame(), None))
}
