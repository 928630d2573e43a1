//! Binding of correction-core: Method I and Method II in one native call each (the path the
//! standalone engine runs too). The Python facade (`rspiv.correction`) checks and wraps.

use crate::errors::PyRspivErr;
use crate::frames::{frames, with_frames};
use crate::mapping::PyMapping;
use crate::piv::{field_dict, settings};
use correction_core::{DisplacementMapping, ZeroFill};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
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

/// A grid `(x0, y0, dx, dy, nx, ny)`, the place `(column, row)` of another in it, and that
/// one's `(nx, ny)`.
type GridIn = (
    (f64, f64, f64, f64, usize, usize),
    (usize, usize),
    (usize, usize),
);

/// The grid the final pass of `settings` runs on, on an object frame of `shape` (rows,
/// columns; `correction_core::object_grid_ring`: with the rings around its `roi`), the place
/// of the field's own grid (`correction_core::object_grid`) in it and its size.
#[pyfunction]
fn object_grid(shape: (usize, usize), settings: &str) -> PyResult<GridIn> {
    let s = self::settings(settings)?;
    let r = correction_core::object_grid_ring(shape, &s).map_err(PyRspivErr::from)?;
    let g = r.grid;
    Ok((
        (g.x0, g.y0, g.dx, g.dy, g.nx, g.ny),
        r.at,
        (r.inner.nx, r.inner.ny),
    ))
}

/// The frames' region read around the points `(x, y)` for `settings` (`piv_core::Roi::around`
/// with `piv_core::roi_margin`) on frames of `shape` (rows, columns): `(x0, y0, x1, y1)`, or
/// None when no point is finite and inside.
#[pyfunction]
fn region_around(
    x: PyReadonlyArray1<'_, f64>,
    y: PyReadonlyArray1<'_, f64>,
    settings: &str,
    shape: (usize, usize),
) -> PyResult<Option<(usize, usize, usize, usize)>> {
    let s = self::settings(settings)?;
    let (x, y) = (x.as_array(), y.as_array());
    let (xs, ys) = (x.to_vec(), y.to_vec());
    let r = piv_core::Roi::around(&xs, &ys, piv_core::roi_margin(&s), shape);
    Ok(r.map(|r| (r.x0, r.y0, r.x1, r.y1)))
}

/// Register the correction functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(method_one, m)?)?;
    m.add_function(wrap_pyfunction!(method_two, m)?)?;
    m.add_function(wrap_pyfunction!(object_grid, m)?)?;
    m.add_function(wrap_pyfunction!(region_around, m)?)?;
    Ok(())
}
