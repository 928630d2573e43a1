//! Binding of piv-core's image conditioning: `condition` works in place on a float32 frame the
//! Python facade (`rspiv.preprocess`) has copied once.

use crate::errors::PyRspivErr;
use numpy::{PyReadonlyArray2, PyReadwriteArray2};
use piv_core::Conditioning;
use pyo3::prelude::*;

/// Condition `frame` (float32, C-contiguous, written in place): hot pixels, background,
/// high-pass, intensity cap, min-max normalisation (each off when None).
#[pyfunction]
#[pyo3(signature = (frame, hot_pixels=None, high_pass=None, cap=None, min_max=None, background=None))]
fn condition(
    py: Python<'_>,
    mut frame: PyReadwriteArray2<'_, f32>,
    hot_pixels: Option<f32>,
    high_pass: Option<f32>,
    cap: Option<f32>,
    min_max: Option<usize>,
    background: Option<PyReadonlyArray2<'_, f32>>,
) -> PyResult<()> {
    let c = Conditioning {
        hot_pixels,
        high_pass_sigma: high_pass,
        cap_sigma: cap,
        min_max_window: min_max,
    };
    let view = frame.as_array_mut();
    let bg = background.as_ref().map(|b| b.as_array());
    py.detach(|| piv_core::condition(view, &c, bg))
        .map_err(PyRspivErr::from)?;
    Ok(())
}

/// Register the conditioning function in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(condition, m)?)?;
    Ok(())
}
