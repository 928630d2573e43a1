//! Binding of piv-core's particle tracking (`piv_core::ptv`): the particle images of one
//! frame with their sub-pixel centres, and the pairing of A's with B's through a predictor,
//! for the Python facade `rspiv.ptv`.

use crate::errors::{invalid, PyRspivErr};
use crate::frames::with_frame;
use crate::piv::grid_field;
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The particle images of `frame` (`piv_core::ptv::detect`): blocks of `block` px, threshold
/// `b + max(k s, rel signal)`, saturation at `full` (None: never). A dict of 1D arrays `x`,
/// `y` (px), `height` (counts above the background), `diameter_x`, `diameter_y`, `sigma_x`,
/// `sigma_y` (px, NaN where the centroid was used), `saturated`. `frame` is uint8, uint16, float32 or float64,
/// read in place; `mask` True = excluded.
#[pyfunction]
#[pyo3(signature = (frame, block, k, rel, full=None, mask=None))]
fn detect_particles<'py>(
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
        let p = py
            .detach(|| {
                piv_core::ptv::detect(view, mask, block, k, rel, full.unwrap_or(f32::INFINITY))
            })
            .map_err(PyRspivErr::from)?;
        let d = PyDict::new(py);
        d.set_item("x", p.x.into_pyarray(py))?;
        d.set_item("y", p.y.into_pyarray(py))?;
        d.set_item("height", p.height.into_pyarray(py))?;
        d.set_item("diameter_x", p.diameter_x.into_pyarray(py))?;
        d.set_item("diameter_y", p.diameter_y.into_pyarray(py))?;
        d.set_item("sigma_x", p.sigma_x.into_pyarray(py))?;
        d.set_item("sigma_y", p.sigma_y.into_pyarray(py))?;
        d.set_item("saturated", p.saturated.into_pyarray(py))?;
        Ok(d)
    })
}

/// Each particle image of A's partner in B (int64 index or -1) and its status (uint8:
/// `piv_core::ptv::track`'s MATCHED 0, NONE 1, SEVERAL 2, CLAIMED 3, NO_PREDICTOR 4), A's
/// images predicted at `(ax + du, ay + dv)` and searched within `radius` px. The arrays are
/// contiguous float64.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[allow(clippy::type_complexity)]
fn track_particles<'py>(
    py: Python<'py>,
    ax: PyReadonlyArray1<'py, f64>,
    ay: PyReadonlyArray1<'py, f64>,
    bx: PyReadonlyArray1<'py, f64>,
    by: PyReadonlyArray1<'py, f64>,
    du: PyReadonlyArray1<'py, f64>,
    dv: PyReadonlyArray1<'py, f64>,
    radius: f64,
) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<u8>>)> {
    let (ax, ay, bx, by) = (
        ax.as_slice()?,
        ay.as_slice()?,
        bx.as_slice()?,
        by.as_slice()?,
    );
    let (du, dv) = (du.as_slice()?, dv.as_slice()?);
    let m = py
        .detach(|| piv_core::ptv::track(ax, ay, bx, by, du, dv, radius))
        .map_err(PyRspivErr::from)?;
    Ok((m.partner.into_pyarray(py), m.status.into_pyarray(py)))
}

/// The displacements `(u, v)` at a set of points.
type Displacements<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// A regular-grid field `(x0, y0, dx, dy)`, `u`, `v` (finite, steps > 0) at the points
/// `(x, y)`: bilinear, constant beyond the outer nodes (`piv_core::GridField::at`, the PIV's own
/// predictor). The point arrays are contiguous float64 of one length.
#[pyfunction]
fn field_at<'py>(
    py: Python<'py>,
    field_grid: (f64, f64, f64, f64),
    field_u: PyReadonlyArray2<'py, f64>,
    field_v: PyReadonlyArray2<'py, f64>,
    x: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
) -> PyResult<Displacements<'py>> {
    let field = grid_field(Some(field_grid), Some(&field_u), Some(&field_v))?
        .expect("a grid, u and v were given");
    let (x, y) = (x.as_slice()?, y.as_slice()?);
    if x.len() != y.len() {
        return Err(invalid(format!(
            "field_at: {} x values and {} y values",
            x.len(),
            y.len()
        )));
    }
    let (u, v): (Vec<f64>, Vec<f64>) = py.detach(|| {
        use rayon::prelude::*;
        x.par_iter()
            .zip(y.par_iter())
            .map(|(&px, &py)| field.at(px, py))
            .unzip()
    });
    Ok((u.into_pyarray(py), v.into_pyarray(py)))
}

/// Register the particle-tracking functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(detect_particles, m)?)?;
    m.add_function(wrap_pyfunction!(track_particles, m)?)?;
    m.add_function(wrap_pyfunction!(field_at, m)?)?;
    Ok(())
}
