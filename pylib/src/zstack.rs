//! `import_zstack`: a microscope z-stack (a file, a folder of slices or a numpy array) into a
//! two-plane light field (docs/zstack.md).

use std::path::PathBuf;

use lumigraph_core::zstack::{self, Composite, ZStack, ZStackOptions};
use pyo3::exceptions::{PyFileNotFoundError, PyValueError};
use pyo3::prelude::*;

use crate::arrays;
use crate::lightfield::{PyLightField, import_target, open_import};

/// Native z-stack import (the Python `import_zstack` documents it and checks the types).
#[pyfunction]
#[pyo3(signature = (stack, *, spacing, grid, angle, composite, window, opacity, depth_threshold, output))]
pub fn import_zstack(
    py: Python<'_>,
    stack: &Bound<'_, PyAny>,
    spacing: Option<[f64; 3]>,
    grid: [u32; 2],
    angle: f64,
    composite: &str,
    window: Option<[f64; 2]>,
    opacity: f64,
    depth_threshold: f64,
    output: Option<PathBuf>,
) -> PyResult<PyLightField> {
    let composite: Composite = composite.parse().map_err(PyValueError::new_err)?;
    let options = ZStackOptions {
        grid,
        angle_deg: angle,
        composite,
        window,
        opacity,
        depth_threshold,
    };
    options
        .validate()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let (stack, source) = if let Ok(path) = stack.extract::<PathBuf>() {
        if !path.exists() {
            return Err(PyFileNotFoundError::new_err(format!(
                "{} does not exist",
                path.display()
            )));
        }
        let read = py
            .detach(|| zstack::read_stack(&path, spacing))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        (read, path)
    } else {
        let (size, bits, voxels) = arrays::zstack(stack, "stack")?;
        let made = ZStack::new(size, bits, spacing.unwrap_or([1.0; 3]), voxels)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let [x, y, z] = size;
        (made, PathBuf::from(format!("array {x}x{y}x{z}")))
    };
    let target = import_target(output.as_deref(), "zstack");
    py.detach(|| zstack::import_zstack(&stack, &source, &options, &target, &mut |_, _| {}))
        .map_err(|e| PyValueError::new_err(format!("cannot import the z-stack: {e}")))?;
    open_import(py, target, output.is_some())
}
