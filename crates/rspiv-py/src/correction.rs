//! Binding of correction-core: Method I and Method II in one native call each (the path the
//! standalone engine runs too). The Python facade (`rspiv.correction`) checks and wraps.

use crate::errors::PyRspivErr;
use crate::frames::{frames, with_frames};
use crate::mapping::PyMapping;
use crate::piv::{field_dict, settings};
use correction_core::{DisplacementMapping, ZeroFill};
use numpy::PyReadonlyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Method I: dewarp the pair (and mask) through `mapping`, then the multipass PIV; returns the
/// field's dict (object px).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, mapping, settings, object_shape=None, mask=None, zero_fill="mask"))]
fn method_one<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    mapping: PyRef<'py, PyMapping>,
    settings: &str,
    object_shape: Option<(usize, usize)>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
    zero_fill: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let s = self::settings(settings)?;
    let zero_fill: ZeroFill = zero_fill.parse().map_err(PyRspivErr::from)?;
    let fr = frames(frame_a, frame_b)?;
    let mask = mask.as_ref().map(|m| m.as_array());
    let m = &mapping.inner;
    let field = with_frames(py, &fr, |r| {
        Ok(r.method_one(m, &s, object_shape, mask, zero_fill)?)
    })?;
    field_dict(py, field)
}

/// Method II: the predictor passes on the raw frames, the last pass at the images of the object
/// grid, displacements mapped back (`mapping_mode` "full" or "positions"); returns the field's
/// dict on the object grid (object px).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, mapping, settings, mapping_mode="full", object_shape=None, mask=None))]
fn method_two<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    mapping: PyRef<'py, PyMapping>,
    settings: &str,
    mapping_mode: &str,
    object_shape: Option<(usize, usize)>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = self::settings(settings)?;
    let mode: DisplacementMapping = mapping_mode.parse().map_err(PyRspivErr::from)?;
    let fr = frames(frame_a, frame_b)?;
    let mask = mask.as_ref().map(|m| m.as_array());
    let m = &mapping.inner;
    let field = with_frames(py, &fr, |r| {
        Ok(r.method_two(m, &s, mode, object_shape, mask)?)
    })?;
    field_dict(py, field)
}

/// Register the correction functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(method_one, m)?)?;
    m.add_function(wrap_pyfunction!(method_two, m)?)?;
    Ok(())
}
