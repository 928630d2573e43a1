//! Binding of piv-core's Lamb-Oseen fit (`piv_core::vortex_fit`) for the Python facade
//! `rspiv.fit_oseen`, which checks the arguments, finds each core's centroid in grid steps and
//! maps the fitted centres back to the caller's coordinates.

use crate::errors::{invalid, PyRspivErr};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2};
use piv_core::vortex_fit::{fit_cores, OseenCore, OseenSettings};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Fit every core (`col`, `row` in grid steps, `radius` px, `sign` +-1) to the field `u`, `v`
/// (pixel frame) where `valid`, with a background shear if `shear`; returns a dict of per-core
/// arrays `col`, `row`, `radius`, `circulation`, `u`, `v`, `shear`, `fit` (float64) and `ok`
/// (bool) (`piv_core::vortex_fit::OseenFit`).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn oseen_fit<'py>(
    py: Python<'py>,
    u: PyReadonlyArray2<'py, f64>,
    v: PyReadonlyArray2<'py, f64>,
    valid: PyReadonlyArray2<'py, bool>,
    col: PyReadonlyArray1<'py, f64>,
    row: PyReadonlyArray1<'py, f64>,
    radius: PyReadonlyArray1<'py, f64>,
    sign: PyReadonlyArray1<'py, f64>,
    dx: f64,
    dy: f64,
    reach: f64,
    orient: f64,
    max_evals: usize,
    shear: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (col, row) = (col.as_array(), row.as_array());
    let (radius, sign) = (radius.as_array(), sign.as_array());
    let n = col.len();
    if row.len() != n || radius.len() != n || sign.len() != n {
        return Err(invalid(
            "oseen: the cores' col, row, radius and sign differ in length",
        ));
    }
    let cores: Vec<OseenCore> = (0..n)
        .map(|k| OseenCore {
            col: col[k],
            row: row[k],
            radius: radius[k],
            sign: sign[k],
        })
        .collect();
    let s = OseenSettings {
        dx,
        dy,
        reach,
        orient,
        max_evals,
        shear,
    };
    let (u, v, valid) = (u.as_array(), v.as_array(), valid.as_array());
    let fits = py
        .detach(|| fit_cores(u, v, valid, &cores, &s))
        .map_err(PyRspivErr::from)?;
    let d = PyDict::new(py);
    let column = |f: fn(&piv_core::vortex_fit::OseenFit) -> f64| -> Vec<f64> {
        fits.iter().map(f).collect()
    };
    d.set_item("col", column(|f| f.col).into_pyarray(py))?;
    d.set_item("row", column(|f| f.row).into_pyarray(py))?;
    d.set_item("radius", column(|f| f.radius).into_pyarray(py))?;
    d.set_item("circulation", column(|f| f.circulation).into_pyarray(py))?;
    d.set_item("u", column(|f| f.u).into_pyarray(py))?;
    d.set_item("v", column(|f| f.v).into_pyarray(py))?;
    d.set_item("shear", column(|f| f.shear).into_pyarray(py))?;
    d.set_item("fit", column(|f| f.fit).into_pyarray(py))?;
    let ok: Vec<bool> = fits.iter().map(|f| f.ok).collect();
    d.set_item("ok", ok.into_pyarray(py))?;
    Ok(d)
}

/// Register the fit in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(oseen_fit, m)?)?;
    m.add("OSEEN_MIN_FIT", piv_core::vortex_fit::OSEEN_MIN_FIT)?;
    m.add("OSEEN_MIN_VECTORS", piv_core::vortex_fit::OSEEN_MIN_VECTORS)?;
    Ok(())
}
