//! Volumes from Python: `reference_volume` ray-casts a numpy array or a volume file directly
//! (DESIGN §9, `lumigraph_core::volume::raycast`), the ground truth for volume light fields;
//! `bake_volume` bakes one into a semi-transparent light field on the GPU
//! (`lumigraph_core::volume::bake`).

use lumigraph_core::asset::{LayerDesc, Provenance};
use lumigraph_core::layers::LayerOpacities;
use lumigraph_core::volume::bake::{VolumeBakeError, VolumeBakeOptions};
use lumigraph_core::volume::layers::{VolumeLayer, reference_layers};

use lumigraph_core::volume::raycast::{RaycastOptions, raycast};
use lumigraph_core::volume::tf::{PRESETS, TransferFunction};
use lumigraph_core::volume::{LoadOptions, Volume, VolumeError};
use pyo3::exceptions::{PyFileNotFoundError, PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::frame::PyFrame;
use crate::lightfield::PyLightField;
use crate::{arrays, engines, errors, view};

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

/// The layers of a multi light field: a list of ``{"name", "tf", "opacity"}`` dicts (a dict
/// holding such a list under "layers", or its JSON, also works); TF file names resolve
/// against the working directory.
fn parse_layers(layers: &Bound<'_, PyAny>) -> PyResult<Vec<VolumeLayer>> {
    let py = layers.py();
    let text: String = if let Ok(text) = layers.extract::<String>() {
        text
    } else if layers.is_instance_of::<pyo3::types::PyList>()
        || layers.is_instance_of::<pyo3::types::PyTuple>()
    {
        let wrapped = pyo3::types::PyDict::new(py);
        wrapped.set_item(
            "layers",
            pyo3::types::PyList::new(py, layers.try_iter()?.collect::<PyResult<Vec<_>>>()?)?,
        )?;
        py.import("json")?
            .call_method1("dumps", (wrapped,))?
            .extract()?
    } else if layers.is_instance_of::<pyo3::types::PyDict>() {
        py.import("json")?
            .call_method1("dumps", (layers,))?
            .extract()?
    } else {
        return Err(PyTypeError::new_err(
            "layers must be a list of {\"name\", \"tf\", \"opacity\"} dicts (or its JSON)",
        ));
    };
    VolumeLayer::parse(&text, std::path::Path::new("."))
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Exactly one of `tf` and `layers`, as layers.
fn tf_or_layers(
    tf: Option<&Bound<'_, PyAny>>,
    layers: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<VolumeLayer>> {
    match (tf, layers) {
        (Some(tf), None) => Ok(vec![VolumeLayer::single(&parse_tf(tf)?)]),
        (None, Some(layers)) => parse_layers(layers),
        (Some(_), Some(_)) => Err(PyValueError::new_err(
            "give tf or layers, not both: each layer names its own tf",
        )),
        (None, None) => Err(PyValueError::new_err(
            "a volume needs tf (a preset, dict or JSON) or layers",
        )),
    }
}

/// A volume from a path or a numpy array, and its name for the provenance (a file's name and
/// the SHA-256 of its bytes; an array's shape).
fn load_volume(
    py: Python<'_>,
    volume: &Bound<'_, PyAny>,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    labels: bool,
) -> PyResult<(Volume, Provenance)> {
    if let Ok(path) = volume.extract::<std::path::PathBuf>() {
        if origin.is_some() {
            return Err(PyValueError::new_err(
                "origin applies to arrays; a volume file carries its own",
            ));
        }
        let loaded = py
            .detach(|| Volume::load(&path, &LoadOptions { labels, spacing }))
            .map_err(|e| volume_error(&e))?;
        let sha = py.detach(|| std::fs::read(&path).map(|b| lumigraph_core::bake::sha256_hex(&b)));
        let provenance = Provenance {
            source_name: path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            ),
            source_sha256: sha.unwrap_or_default(),
            ..Provenance::default()
        };
        return Ok((loaded, provenance));
    }
    let (dims, voxels) = arrays::volume(volume, "volume", labels)?;
    let s = spacing.unwrap_or([1.0; 3]);
    let affine = [[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]];
    let loaded = Volume::from_values(dims, voxels, affine, origin.unwrap_or([0.0; 3]))
        .map_err(|e| volume_error(&e))?;
    let provenance = Provenance {
        source_name: format!("array {}x{}x{}", dims[0], dims[1], dims[2]),
        ..Provenance::default()
    };
    Ok((loaded, provenance))
}

/// Native volume bake (the Python wrapper documents it).
#[pyfunction]
#[pyo3(signature = (volume, *, tf, layers, spacing, origin, labels, shade, step, depth_threshold, light, ambient, cameras, resolution, depth_bits, progress, color_codec = None, depth_codec = None))]
pub fn bake_volume(
    py: Python<'_>,
    volume: &Bound<'_, PyAny>,
    tf: Option<&Bound<'_, PyAny>>,
    layers: Option<&Bound<'_, PyAny>>,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    labels: bool,
    shade: bool,
    step: Option<f64>,
    depth_threshold: f64,
    light: [f64; 3],
    ambient: f64,
    cameras: u32,
    resolution: u32,
    depth_bits: u8,
    progress: Option<Py<PyAny>>,
    color_codec: Option<String>,
    depth_codec: Option<String>,
) -> PyResult<PyLightField> {
    if let Some(callback) = &progress
        && !callback.bind(py).is_callable()
    {
        return Err(PyTypeError::new_err(
            "progress must be a bool or a callable(done, total)",
        ));
    }
    let (color_codec, depth_codec) =
        crate::lightfield::codecs(color_codec.as_deref(), depth_codec.as_deref())?;
    let layers = tf_or_layers(tf, layers)?;
    let (volume, provenance) = load_volume(py, volume, spacing, origin, labels)?;
    let options = VolumeBakeOptions {
        cameras,
        resolution,
        depth_bits,
        raycast: RaycastOptions {
            step,
            shade,
            light,
            ambient,
            depth_threshold,
        },
        color_codec,
        depth_codec,
    };
    let (bytes, callback_error) = py.detach(|| {
        let baker =
            engines::volume_baker().map_err(|e| errors::BakeError::new_err(e.to_string()))?;
        // As in `bake_mesh`: the callback's first exception is raised after the bake.
        let mut callback_error: Option<PyErr> = None;
        let mut report = |done: u32, total: u32| {
            if let (Some(callback), None) = (&progress, &callback_error) {
                Python::attach(|py| {
                    if let Err(e) = callback.call1(py, (done, total)) {
                        callback_error = Some(e);
                    }
                });
            }
        };
        let (bytes, _) = baker
            .bake_layers_to_bytes(&volume, &layers, &options, &provenance, &mut report)
            .map_err(|e| match e {
                VolumeBakeError::Options(e) => errors::bake(&e),
                VolumeBakeError::Gpu(e) => errors::BakeError::new_err(e.to_string()),
                VolumeBakeError::Asset(e) => errors::asset(&e, None),
                other => PyValueError::new_err(other.to_string()),
            })?;
        PyResult::Ok((bytes, callback_error))
    })?;
    if let Some(error) = callback_error {
        return Err(error);
    }
    PyLightField::from_encoded(py, bytes)
}

/// Native direct ray cast (the Python wrapper documents it).
#[pyfunction]
#[pyo3(signature = (volume, view, *, tf, layers, opacities, spacing, origin, labels, shade, step, depth_threshold, light, ambient))]
pub fn reference_volume(
    py: Python<'_>,
    volume: &Bound<'_, PyAny>,
    view: &Bound<'_, PyAny>,
    tf: Option<&Bound<'_, PyAny>>,
    layers: Option<&Bound<'_, PyAny>>,
    opacities: Option<std::collections::BTreeMap<String, f32>>,
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
    let layered = layers.is_some();
    let layers = tf_or_layers(tf, layers)?;
    if opacities.is_some() && !layered {
        return Err(PyValueError::new_err("opacities apply with layers"));
    }
    let descs: Vec<LayerDesc> = layers
        .iter()
        .map(|l| LayerDesc {
            name: l.name.clone(),
            default_opacity: l.opacity,
        })
        .collect();
    let requested = LayerOpacities(opacities.unwrap_or_default());
    requested.validate().map_err(PyValueError::new_err)?;
    let opacities = requested.resolve(&descs).map_err(PyValueError::new_err)?;
    let (volume, _) = load_volume(py, volume, spacing, origin, labels)?;
    let options = RaycastOptions {
        step,
        shade,
        light,
        ambient,
        depth_threshold,
    };
    if layered {
        let frame = py
            .detach(|| reference_layers(&volume, &layers, &view, &options, &opacities))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        return Ok(PyFrame::new(frame, None));
    }
    let image = py
        .detach(|| raycast(&volume, &layers[0].tf, &view, &options))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(PyFrame::new(image.to_frame(), None))
}
