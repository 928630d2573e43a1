//! Binding of the Keys-bicubic remap (Method I dewarp): `dewarp_image` through a native mapping,
//! `remap_coords` through precomputed coordinate arrays. The Python facade (`rspiv.dewarp`)
//! validates and converts dtypes.

use crate::errors::{invalid, PyRspivErr};
use crate::mapping::PyMapping;
use dewarp_core::remap::{remap, remap_with_coords, MapSampling, OutSample, Pixel, RemapOptions};
use dewarp_core::{DewarpError, Mapping};
use ndarray::{Array2, ArrayView2};
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::prelude::*;

enum Img<'py> {
    U16(PyReadonlyArray2<'py, u16>),
    F32(PyReadonlyArray2<'py, f32>),
}

fn image<'py>(a: &Bound<'py, PyAny>) -> PyResult<Img<'py>> {
    if let Ok(v) = a.extract::<PyReadonlyArray2<'py, u16>>() {
        return Ok(Img::U16(v));
    }
    if let Ok(v) = a.extract::<PyReadonlyArray2<'py, f32>>() {
        return Ok(Img::F32(v));
    }
    Err(invalid("image must be a 2D uint16 or float32 array"))
}

#[derive(Clone, Copy)]
enum OutType {
    F32,
    U16,
}

fn out_type(s: &str) -> PyResult<OutType> {
    match s {
        "float32" => Ok(OutType::F32),
        "uint16" => Ok(OutType::U16),
        _ => Err(invalid(format!(
            "out_dtype must be 'float32' or 'uint16', got {s:?}"
        ))),
    }
}

fn to_py<'py, O: OutSample + numpy::Element>(
    py: Python<'py>,
    r: Result<Array2<O>, DewarpError>,
) -> PyResult<Bound<'py, PyAny>> {
    Ok(r.map_err(PyRspivErr::from)?.into_pyarray(py).into_any())
}

/// Run `f` over the typed image view for the requested output type, GIL released.
macro_rules! dispatch {
    ($py:expr, $img:expr, $out:expr, |$v:ident| $body:expr) => {{
        match ($img, $out) {
            (Img::U16(a), OutType::F32) => {
                let $v: ArrayView2<u16> = a.as_array();
                let r: Result<Array2<f32>, DewarpError> = $py.detach(|| $body);
                to_py($py, r)
            }
            (Img::U16(a), OutType::U16) => {
                let $v: ArrayView2<u16> = a.as_array();
                let r: Result<Array2<u16>, DewarpError> = $py.detach(|| $body);
                to_py($py, r)
            }
            (Img::F32(a), OutType::F32) => {
                let $v: ArrayView2<f32> = a.as_array();
                let r: Result<Array2<f32>, DewarpError> = $py.detach(|| $body);
                to_py($py, r)
            }
            (Img::F32(a), OutType::U16) => {
                let $v: ArrayView2<f32> = a.as_array();
                let r: Result<Array2<u16>, DewarpError> = $py.detach(|| $body);
                to_py($py, r)
            }
        }
    }};
}

fn sampling(name: &str, tol: f64, step: usize) -> PyResult<MapSampling> {
    match name {
        "auto" => Ok(MapSampling::Auto { tol }),
        "exact" => Ok(MapSampling::Exact),
        "grid" => Ok(MapSampling::Grid { step }),
        _ => Err(invalid(format!(
            "sampling must be 'auto', 'exact' or 'grid', got {name:?}"
        ))),
    }
}

fn through_mapping<T: Pixel, O: OutSample>(
    img: ArrayView2<T>,
    mapping: &Mapping,
    opts: &RemapOptions,
) -> Result<Array2<O>, DewarpError> {
    let map = |x: f64, y: f64| mapping.forward(x, y);
    remap(img, &map, opts)
}

/// Dewarp an image: out[y, x] = image(F(x, y)), F the mapping (object px -> image px, rotation
/// included; the `NativeMapping` object itself, no re-parsing); Keys bicubic, zero outside
/// the image.
#[pyfunction]
#[pyo3(signature = (image, mapping, out_shape=None, sampling="auto", tol=1e-3, step=16, fill=0.0, out_dtype="float32"))]
fn dewarp_image<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    mapping: PyRef<'py, PyMapping>,
    out_shape: Option<(usize, usize)>,
    sampling: &str,
    tol: f64,
    step: usize,
    fill: f32,
    out_dtype: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let img = self::image(image)?;
    let out = out_type(out_dtype)?;
    let mapping = &mapping.inner;
    let opts = RemapOptions {
        out_shape,
        sampling: self::sampling(sampling, tol, step)?,
        fill,
    };
    dispatch!(py, img, out, |v| through_mapping(v, mapping, &opts))
}

enum Coords<'py> {
    F64(PyReadonlyArray2<'py, f64>, PyReadonlyArray2<'py, f64>),
    F32(PyReadonlyArray2<'py, f32>, PyReadonlyArray2<'py, f32>),
}

/// Remap with precomputed source coordinates map_x[y, x], map_y[y, x] (image px, float32 or
/// float64); the maps' shape is the output shape.
#[pyfunction]
#[pyo3(signature = (image, map_x, map_y, fill=0.0, out_dtype="float32"))]
fn remap_coords<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    map_x: &Bound<'py, PyAny>,
    map_y: &Bound<'py, PyAny>,
    fill: f32,
    out_dtype: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let img = self::image(image)?;
    let out = out_type(out_dtype)?;
    let coords = if let (Ok(a), Ok(b)) = (map_x.extract(), map_y.extract()) {
        Coords::F64(a, b)
    } else if let (Ok(a), Ok(b)) = (map_x.extract(), map_y.extract()) {
        Coords::F32(a, b)
    } else {
        return Err(invalid(
            "map_x and map_y must be 2D arrays of one dtype, float64 or float32",
        ));
    };
    match coords {
        Coords::F64(a, b) => {
            let (mx, my) = (a.as_array(), b.as_array());
            dispatch!(py, img, out, |v| remap_with_coords(v, mx, my, fill))
        }
        Coords::F32(a, b) => {
            let (mx, my) = (a.as_array(), b.as_array());
            dispatch!(py, img, out, |v| remap_with_coords(v, mx, my, fill))
        }
    }
}

/// Register the remap functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(dewarp_image, m)?)?;
    m.add_function(wrap_pyfunction!(remap_coords, m)?)?;
    Ok(())
}
