//! Binding of piv-core's seeding count (`piv_core::seeding`): each block's background, noise
//! and particle images of one frame, for the Python facade `rspiv.recording`.

use crate::errors::PyRspivErr;
use crate::frames::with_frame;
use ndarray::Array2;
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Each `block` px block's background, noise, top, median, particle images counted above
/// `b + max(k s, rel signal)`, their summed heights and those at `full` or above (saturated;
/// None: none), and the pixels searched, as
/// `(rows, cols)` arrays; and the frame's `signal` (`piv_core::seeding::measure`). `frame` is
/// uint8, uint16, float32 or float64, read in place; `mask` True = excluded.
#[pyfunction]
#[pyo3(signature = (frame, block, k, rel, full=None, mask=None))]
fn seeding<'py>(
    py: Python<'py>,
    frame: &Bound<'py, PyAny>,
    block: usize,
    k: f32,
    rel: f32,
    full: Option<f32>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mask = mask.as_ref().map(|m| m.as_array());
    with_frame!(frame, |view| {
        let s = py
            .detach(|| {
                piv_core::seeding::measure(view, mask, block, k, rel, full.unwrap_or(f32::INFINITY))
            })
            .map_err(PyRspivErr::from)?;
        fn grid<T>(shape: (usize, usize), v: Vec<T>) -> Array2<T> {
            Array2::from_shape_vec(shape, v).expect("rows x cols blocks")
        }
        let shape = (s.rows, s.cols);
        let d = PyDict::new(py);
        d.set_item("background", grid(shape, s.background).into_pyarray(py))?;
        d.set_item("noise", grid(shape, s.noise).into_pyarray(py))?;
        d.set_item("top", grid(shape, s.top).into_pyarray(py))?;
        d.set_item("median", grid(shape, s.median).into_pyarray(py))?;
        d.set_item("saturated", grid(shape, s.saturated).into_pyarray(py))?;
        d.set_item("peaks", grid(shape, s.peaks).into_pyarray(py))?;
        d.set_item("heights", grid(shape, s.heights).into_pyarray(py))?;
        d.set_item("searched", grid(shape, s.searched).into_pyarray(py))?;
        d.set_item("signal", s.signal)?;
        d.set_item("block", s.block)?;
        Ok(d)
    })
}

/// Register the seeding function in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(seeding, m)?)?;
    m.add("MIN_NOISE", piv_core::seeding::MIN_NOISE)?;
    Ok(())
}
