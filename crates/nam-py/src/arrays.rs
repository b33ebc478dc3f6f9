//! numpy arrays in and out: validated `N×K` float rows, photos, and results as ndarray.

use ndarray::{Array1, Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// Rows of `K` values from an `N×K` array-like. A C-contiguous float32 array is read in place;
/// anything else (float64, a list, a strided view) is converted by numpy first. Errors name
/// the argument: a wrong shape or a NaN/Inf is a `ValueError`, a non-numeric input a
/// `TypeError`.
pub fn rows<const K: usize>(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<[f32; K]>> {
    let array = float32_array(name, obj)?;
    let Ok(array) = array.cast::<PyArray2<f32>>() else {
        let shape = array
            .cast::<PyUntypedArray>()
            .map(|a| a.shape().to_vec())
            .unwrap_or_default();
        return Err(PyValueError::new_err(format!(
            "{name} must be an N×{K} array, got shape {shape:?}"
        )));
    };
    let shape = array.shape();
    if shape[1] != K {
        return Err(PyValueError::new_err(format!(
            "{name} must be an N×{K} array, got shape {shape:?}"
        )));
    }
    let view = array.readonly();
    let flat = view
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    if let Some(k) = flat.iter().position(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{name}: row {} holds {}, every value must be finite",
            k / K,
            flat[k]
        )));
    }
    Ok(flat
        .chunks_exact(K)
        .map(|r| std::array::from_fn(|i| r[i]))
        .collect())
}

/// `obj` as a C-contiguous float32 numpy array (numpy returns `obj` itself when it already is
/// one: no copy).
fn float32_array<'py>(name: &str, obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    contiguous(obj, Some("float32"))
        .map_err(|e| PyTypeError::new_err(format!("{name} must be an array of numbers: {e}")))
}

/// `numpy.ascontiguousarray(obj, dtype)`.
fn contiguous<'py>(obj: &Bound<'py, PyAny>, dtype: Option<&str>) -> PyResult<Bound<'py, PyAny>> {
    let np = obj.py().import("numpy")?;
    np.call_method1("ascontiguousarray", (obj, dtype))
}

/// Checks that every batch argument has the same number of rows.
pub fn same_rows(lens: &[(&str, usize)]) -> PyResult<usize> {
    let n = lens[0].1;
    match lens.iter().find(|(_, m)| *m != n) {
        None => Ok(n),
        Some((name, m)) => Err(PyValueError::new_err(format!(
            "{} has {n} rows but {name} has {m}; every argument needs one row per query",
            lens[0].0
        ))),
    }
}

/// The pixels of a photo array, `H×W×3`, copied out of numpy.
pub enum PhotoPixels {
    /// 8-bit sRGB-encoded.
    Srgb8(Vec<u8>),
    /// Linear radiance.
    Linear(Vec<f32>),
}

/// Reads an `H×W×3` uint8 (sRGB-encoded) or float32 (linear) array: `(height, width, pixels)`.
pub fn photo(obj: &Bound<'_, PyAny>) -> PyResult<(usize, usize, PhotoPixels)> {
    let obj = &contiguous(obj, None)?;
    if let Ok(a) = obj.cast::<PyUntypedArray>()
        && !matches!(a.shape(), [_, _, 3])
    {
        return Err(PyValueError::new_err(format!(
            "photo must be an H×W×3 array (RGB), got shape {:?}",
            a.shape()
        )));
    }
    let shape_of = |shape: &[usize]| (shape[0], shape[1]);
    if let Ok(a) = obj.cast::<PyArray3<u8>>() {
        let (h, w) = shape_of(a.shape());
        return Ok((h, w, PhotoPixels::Srgb8(a.to_vec()?)));
    }
    if let Ok(a) = obj.cast::<PyArray3<f32>>() {
        let (h, w) = shape_of(a.shape());
        return Ok((h, w, PhotoPixels::Linear(a.to_vec()?)));
    }
    let dtype = obj
        .getattr("dtype")
        .map(|d| d.to_string())
        .unwrap_or_else(|_| obj.get_type().to_string());
    Err(PyTypeError::new_err(format!(
        "photo must be a numpy array of uint8 (sRGB-encoded, as a PNG stores it) or float32 \
         (linear radiance), got {dtype}"
    )))
}

/// `N×K` f32 results as a numpy array.
pub fn out_rows<'py, const K: usize>(
    py: Python<'py>,
    rows: Vec<[f32; K]>,
) -> Bound<'py, PyArray2<f32>> {
    let n = rows.len();
    let flat: Vec<f32> = rows.into_iter().flatten().collect();
    Array2::from_shape_vec((n, K), flat)
        .expect("n·K values")
        .into_pyarray(py)
}

/// `N` f32 results as a numpy array.
pub fn out_values<'py>(py: Python<'py>, values: Vec<f32>) -> Bound<'py, PyArray1<f32>> {
    Array1::from_vec(values).into_pyarray(py)
}

/// An `H×W×3` image as a numpy array.
pub fn out_image<'py>(
    py: Python<'py>,
    h: usize,
    w: usize,
    rgb: Vec<f32>,
) -> Bound<'py, PyArray3<f32>> {
    Array3::from_shape_vec((h, w, 3), rgb)
        .expect("H·W·3 values")
        .into_pyarray(py)
}
