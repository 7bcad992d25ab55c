//! numpy input conversion: any array-like is passed through `numpy.asarray`, its dtype kind and
//! shape are checked (wrong kind → `TypeError`, wrong shape or values → `ValueError`, each naming
//! the argument and what to pass instead), then it is made C-contiguous in the dtype the core
//! needs. Non-contiguous or differently typed but compatible input is converted, never rejected.

use numpy::{PyArrayDyn, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyAny;

/// `numpy.asarray(obj)` with its dtype kind (`f`, `i`, `u`, `b`, ...), dtype name and shape.
struct Loose<'py> {
    array: Bound<'py, PyAny>,
    kind: char,
    dtype: String,
    shape: Vec<usize>,
}

fn loose<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Loose<'py>> {
    let py = obj.py();
    let numpy = py.import("numpy")?;
    let array = numpy.call_method1("asarray", (obj,)).map_err(|e| {
        PyTypeError::new_err(format!(
            "{name} must be a numpy array or nested sequence of numbers: {e}"
        ))
    })?;
    let dtype = array.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    let shape: Vec<usize> = array.getattr("shape")?.extract()?;
    Ok(Loose {
        kind: kind.chars().next().unwrap_or('O'),
        dtype: dtype.str()?.to_string(),
        array,
        shape,
    })
}

fn shape_text(shape: &[usize]) -> String {
    let parts: Vec<String> = shape.iter().map(ToString::to_string).collect();
    if parts.len() == 1 {
        format!("({},)", parts[0])
    } else {
        format!("({})", parts.join(", "))
    }
}

/// C-contiguous copy (or view) in the given numpy dtype, flattened.
fn contiguous<T: numpy::Element + Clone>(
    array: &Bound<'_, PyAny>,
    dtype: &str,
) -> PyResult<Vec<T>> {
    let py = array.py();
    let numpy = py.import("numpy")?;
    let kwargs = pyo3::types::PyDict::new(py);
    kwargs.set_item("dtype", dtype)?;
    let converted = numpy.call_method("ascontiguousarray", (array,), Some(&kwargs))?;
    let typed = converted.cast_into::<PyArrayDyn<T>>()?;
    let readonly = typed.readonly();
    Ok(readonly.as_slice()?.to_vec())
}

fn require_real(l: &Loose<'_>, name: &str) -> PyResult<()> {
    if matches!(l.kind, 'f' | 'i' | 'u') {
        Ok(())
    } else {
        Err(PyTypeError::new_err(format!(
            "{name} must hold real numbers (float or int), got dtype {}",
            l.dtype
        )))
    }
}

/// An `(N, COLS)` array of real numbers as f32 rows.
pub fn float_rows<const COLS: usize>(
    obj: &Bound<'_, PyAny>,
    name: &str,
) -> PyResult<Vec<[f32; COLS]>> {
    let l = loose(obj, name)?;
    require_real(&l, name)?;
    if l.shape.len() != 2 || l.shape[1] != COLS {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, {COLS}), got {}",
            shape_text(&l.shape)
        )));
    }
    let flat: Vec<f32> = contiguous(&l.array, "float32")?;
    Ok(flat
        .chunks_exact(COLS)
        .map(|c| std::array::from_fn(|k| c[k]))
        .collect())
}

/// An `(M, 3)` array of non-negative integer vertex indices.
pub fn triangles(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[u32; 3]>> {
    let l = loose(obj, name)?;
    if !matches!(l.kind, 'i' | 'u') {
        return Err(PyTypeError::new_err(format!(
            "{name} must be an integer array of vertex indices, got dtype {} \
             (convert with .astype(np.int64) if the values are whole numbers)",
            l.dtype
        )));
    }
    if l.shape.len() != 2 || l.shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (M, 3) (triangles only), got {}",
            shape_text(&l.shape)
        )));
    }
    let flat: Vec<i64> = if l.dtype == "uint64" {
        let wide: Vec<u64> = contiguous(&l.array, "uint64")?;
        wide.into_iter()
            .map(|v| i64::try_from(v).unwrap_or(i64::MAX))
            .collect()
    } else {
        contiguous(&l.array, "int64")?
    };
    let mut out = Vec::with_capacity(flat.len() / 3);
    for (t, c) in flat.chunks_exact(3).enumerate() {
        let mut tri = [0_u32; 3];
        for (k, &v) in c.iter().enumerate() {
            tri[k] = u32::try_from(v).map_err(|_| {
                PyValueError::new_err(format!(
                    "{name}[{t}] holds vertex index {v}: indices must be in 0..2**32"
                ))
            })?;
        }
        out.push(tri);
    }
    Ok(out)
}

/// Per-vertex colours `(N, 3)` or `(N, 4)`: uint8 in 0..=255, or floats in [0, 1]. Returns RGBA
/// floats in [0, 1] (alpha 1 when absent).
pub fn colors(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f32; 4]>> {
    let l = loose(obj, name)?;
    require_real(&l, name)?;
    if l.shape.len() != 2 || !matches!(l.shape[1], 3 | 4) {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, 3) or (N, 4) (RGB or RGBA per vertex), got {}",
            shape_text(&l.shape)
        )));
    }
    let cols = l.shape[1];
    // A divisor, not a reciprocal factor: `c / 255` is what numpy's `colors / 255` gives.
    let divisor = if l.kind == 'f' {
        1.0
    } else if l.dtype == "uint8" {
        255.0
    } else {
        return Err(PyTypeError::new_err(format!(
            "{name} must be uint8 (0..255) or float (0..1), got dtype {}",
            l.dtype
        )));
    };
    let flat: Vec<f32> = contiguous(&l.array, "float32")?;
    let mut out = Vec::with_capacity(flat.len() / cols);
    for (i, c) in flat.chunks_exact(cols).enumerate() {
        let mut rgba = [1.0_f32; 4];
        for k in 0..cols {
            let v = c[k] / divisor;
            if !(0.0..=1.0).contains(&v) {
                return Err(PyValueError::new_err(format!(
                    "{name}[{i}] = {:?} is outside [0, 1] (float colours are 0..1, uint8 0..255)",
                    &c[..cols]
                )));
            }
            rgba[k] = v;
        }
        out.push(rgba);
    }
    Ok(out)
}

/// An image `(H, W, 3)` or `(H, W, 4)` of uint8 as RGBA8 bytes (alpha 255 when absent).
/// `float_ok` also accepts floats in [0, 1] (rounded to 8 bits), for textures.
pub fn rgba8(obj: &Bound<'_, PyAny>, name: &str, float_ok: bool) -> PyResult<(u32, u32, Vec<u8>)> {
    let l = loose(obj, name)?;
    if l.shape.len() != 3 || !matches!(l.shape[2], 3 | 4) {
        return Err(PyValueError::new_err(format!(
            "{name} must be an image of shape (H, W, 3) or (H, W, 4), got {}",
            shape_text(&l.shape)
        )));
    }
    let (h, w, cols) = (l.shape[0], l.shape[1], l.shape[2]);
    let (Ok(height), Ok(width)) = (u32::try_from(h), u32::try_from(w)) else {
        return Err(PyValueError::new_err(format!("{name} is too large")));
    };
    let bytes: Vec<u8> = if l.dtype == "uint8" {
        contiguous(&l.array, "uint8")?
    } else if float_ok && l.kind == 'f' {
        let values: Vec<f32> = contiguous(&l.array, "float32")?;
        if let Some(bad) = values.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(PyValueError::new_err(format!(
                "{name} holds {bad}: float images must be in [0, 1]"
            )));
        }
        values.iter().map(|v| (v * 255.0).round() as u8).collect()
    } else {
        let hint = if float_ok {
            "uint8 (0..255) or float (0..1)"
        } else {
            "uint8"
        };
        return Err(PyTypeError::new_err(format!(
            "{name} must be {hint} RGB(A), got dtype {} \
             (for floats in [0, 1] use (x * 255).round().astype(np.uint8))",
            l.dtype
        )));
    };
    if cols == 4 {
        return Ok((width, height, bytes));
    }
    let mut rgba = Vec::with_capacity(h * w * 4);
    for px in bytes.chunks_exact(3) {
        rgba.extend_from_slice(px);
        rgba.push(255);
    }
    Ok((width, height, rgba))
}

/// A boolean mask `(H, W)`.
pub fn mask(obj: &Bound<'_, PyAny>, name: &str, width: u32, height: u32) -> PyResult<Vec<bool>> {
    let l = loose(obj, name)?;
    if l.kind != 'b' {
        return Err(PyTypeError::new_err(format!(
            "{name} must be a boolean array, got dtype {} (use e.g. np.isfinite(depth))",
            l.dtype
        )));
    }
    check_hw(&l.shape, name, width, height)?;
    contiguous(&l.array, "bool")
}

/// A depth image `(H, W)` of real numbers as f32 (`+inf` = no hit).
pub fn depth(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(u32, u32, Vec<f32>)> {
    let l = loose(obj, name)?;
    if l.kind != 'f' {
        return Err(PyTypeError::new_err(format!(
            "{name} must be a float depth image (+inf where nothing is hit), got dtype {}",
            l.dtype
        )));
    }
    if l.shape.len() != 2 {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (H, W), got {}",
            shape_text(&l.shape)
        )));
    }
    let height = u32::try_from(l.shape[0]).map_err(|_| PyValueError::new_err("too large"))?;
    let width = u32::try_from(l.shape[1]).map_err(|_| PyValueError::new_err("too large"))?;
    Ok((width, height, contiguous(&l.array, "float32")?))
}

fn check_hw(shape: &[usize], name: &str, width: u32, height: u32) -> PyResult<()> {
    if shape != [height as usize, width as usize] {
        return Err(PyValueError::new_err(format!(
            "{name} has shape {}, expected ({height}, {width}) to match the images",
            shape_text(shape)
        )));
    }
    Ok(())
}

/// A 3-D volume array, shape `(nz, ny, nx)` (indexed `[k, j, i]`): `((nx, ny, nz), values)`
/// with i fastest, as f32 (real dtypes) or, with `labels`, as u32 (integer or bool dtypes,
/// every value ≥ 0).
pub fn volume(
    obj: &Bound<'_, PyAny>,
    name: &str,
    labels: bool,
) -> PyResult<([u32; 3], lumigraph_core::volume::Voxels)> {
    use lumigraph_core::volume::Voxels;
    let l = loose(obj, name)?;
    let [nz, ny, nx] = l.shape[..] else {
        return Err(PyValueError::new_err(format!(
            "{name} must be a 3-D array of shape (nz, ny, nx), got shape {}",
            shape_text(&l.shape)
        )));
    };
    let limit = lumigraph_core::volume::MAX_SIDE as usize;
    if [nx, ny, nz].iter().any(|&d| d == 0 || d > limit) {
        return Err(PyValueError::new_err(format!(
            "{name} has shape {}: every side must be 1..={limit}",
            shape_text(&l.shape)
        )));
    }
    let dims = [nx as u32, ny as u32, nz as u32];
    if labels {
        if !matches!(l.kind, 'i' | 'u' | 'b') {
            return Err(PyTypeError::new_err(format!(
                "{name} with labels=True must hold integers, got dtype {}",
                l.dtype
            )));
        }
        let values: Vec<i64> = contiguous(&l.array, "int64")?;
        if let Some(n) = values
            .iter()
            .position(|&v| v < 0 || v > i64::from(u32::MAX))
        {
            return Err(PyValueError::new_err(format!(
                "{name}[{}, {}, {}] is {}: labels must be in 0..={}",
                n / (nx * ny),
                (n / nx) % ny,
                n % nx,
                values[n],
                u32::MAX
            )));
        }
        return Ok((
            dims,
            Voxels::Labels(values.into_iter().map(|v| v as u32).collect()),
        ));
    }
    require_real(&l, name)?;
    Ok((dims, Voxels::Scalar(contiguous(&l.array, "float32")?)))
}

/// A z-stack array, shape `(nz, ny, nx)` (slices of rows, row 0 on top), `uint8` or `uint16`:
/// `((nx, ny, nz), bits, values)` with x fastest.
pub fn zstack(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<([u32; 3], u8, Vec<u16>)> {
    let l = loose(obj, name)?;
    let [nz, ny, nx] = l.shape[..] else {
        return Err(PyValueError::new_err(format!(
            "{name} must be a 3-D array of shape (nz, ny, nx), got shape {}",
            shape_text(&l.shape)
        )));
    };
    let bits = match l.dtype.as_str() {
        "uint8" => 8,
        "uint16" => 16,
        other => {
            return Err(PyTypeError::new_err(format!(
                "{name} must be uint8 or uint16 (a microscope's grey values), got dtype {other}"
            )));
        }
    };
    let side = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
    let size = [side(nx), side(ny), side(nz)];
    // The core checks the sizes before anything is copied.
    lumigraph_core::zstack::ZStack::check_size(size)
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    Ok((size, bits, contiguous(&l.array, "uint16")?))
}
