//! Binding of piv-core's image conditioning: `conditioned` returns a new float32 frame from a
//! frame of any pixel type (the conversion fused with the first steps), what the Python facade
//! `rspiv.preprocess` uses.

use crate::errors::PyRspivErr;
use crate::frames::with_frame;
use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray2};
use piv_core::Conditioning;
use pyo3::prelude::*;

/// A new conditioned float32 copy of `frame` (uint8, uint16, float32 or float64, read in
/// place): hot pixels, background, high-pass, smoothing, intensity cap, min-max normalisation
/// (each off when None).
#[pyfunction]
#[pyo3(signature = (frame, hot_pixels=None, high_pass=None, cap=None, min_max=None, background=None,
    smooth=None))]
#[allow(clippy::too_many_arguments)]
fn conditioned<'py>(
    py: Python<'py>,
    frame: &Bound<'py, PyAny>,
    hot_pixels: Option<f32>,
    high_pass: Option<f32>,
    cap: Option<f32>,
    min_max: Option<usize>,
    background: Option<PyReadonlyArray2<'py, f32>>,
    smooth: Option<f32>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let c = Conditioning {
        hot_pixels,
        high_pass_sigma: high_pass,
        smooth_sigma: smooth,
        cap_sigma: cap,
        min_max_window: min_max,
    };
    let bg = background.as_ref().map(|b| b.as_array());
    with_frame!(frame, |view| {
        // numpy's allocator (huge pages for large arrays: first touch is cheap)
        // SAFETY: every element is written by `conditioned_into` before it is read.
        let out = unsafe { PyArray2::<f32>::new(py, view.dim(), false) };
        {
            let mut rw = out.readwrite();
            let ov = rw.as_array_mut();
            py.detach(|| piv_core::conditioned_into(view, ov, &c, bg))
                .map_err(PyRspivErr::from)?;
        }
        Ok(out)
    })
}

/// Register the conditioning function in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(conditioned, m)?)?;
    Ok(())
}
