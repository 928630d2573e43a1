//! Ensemble correlation (`piv_core::ensemble`): the accumulator lives in a NumPy array owned by
//! Python (`rspiv.ensemble.EnsembleAccumulator`), added to in place with the GIL released.

use crate::errors::{invalid, PyRspivErr};
use crate::frames::{frames, with_frames};
use crate::piv::grid_field;
use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use piv_core::ensemble::{peaks, EnsemblePeak, Layout, Windows};
use piv_core::ensemble_pixel::PixelBand;
use piv_core::Interpolation;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Mutex;

/// Values per window of the accumulator for `w` x `h` windows.
#[pyfunction]
fn ensemble_stride(w: usize, h: usize) -> usize {
    Layout::new(w, h).stride()
}

/// Add one frame pair to `acc` (n x stride, float64, C-contiguous) in place, the windows offset
/// by (du, dv) and deformed by the grid field (field_grid, field_u, field_v) when given; returns
/// the number of windows added.
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, x, y, du, dv, window, acc, auto=true, mask=None,
    interpolation="bspline", field_grid=None, field_u=None, field_v=None))]
#[allow(clippy::too_many_arguments)]
fn ensemble_add<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    x: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
    du: PyReadonlyArray1<'py, f64>,
    dv: PyReadonlyArray1<'py, f64>,
    window: (usize, usize),
    acc: &Bound<'py, PyArray2<f64>>,
    auto: bool,
    mask: Option<PyReadonlyArray2<'py, bool>>,
    interpolation: &str,
    field_grid: Option<(f64, f64, f64, f64)>,
    field_u: Option<PyReadonlyArray2<'py, f64>>,
    field_v: Option<PyReadonlyArray2<'py, f64>>,
) -> PyResult<usize> {
    let interp: Interpolation = interpolation.parse().map_err(PyRspivErr::from)?;
    let field = grid_field(field_grid, field_u.as_ref(), field_v.as_ref())?;
    let fr = frames(frame_a, frame_b)?;
    let mut rw = acc
        .try_readwrite()
        .map_err(|_| invalid("acc is borrowed elsewhere"))?;
    let slice = rw
        .as_slice_mut()
        .map_err(|_| invalid("acc must be a C-contiguous float64 array"))?;
    let cell = Mutex::new(slice);
    let (x, y, du, dv) = (x.as_slice()?, y.as_slice()?, du.as_slice()?, dv.as_slice()?);
    let win = Windows {
        w: window.0,
        h: window.1,
        x,
        y,
        du,
        dv,
    };
    let mask = mask.as_ref().map(|m| m.as_array());
    with_frames(py, &fr, |r| {
        let mut acc = cell.lock().unwrap_or_else(|e| e.into_inner());
        Ok(r.ensemble_add(mask, &win, field.as_ref(), interp, auto, &mut acc)?)
    })
}

/// The fitted peaks of an accumulator: a dict of 1D arrays (see `piv_core::ensemble::peaks`).
#[pyfunction]
fn ensemble_peaks<'py>(
    py: Python<'py>,
    acc: PyReadonlyArray2<'py, f64>,
    window: (usize, usize),
) -> PyResult<Bound<'py, PyDict>> {
    let a = acc
        .as_slice()
        .map_err(|_| invalid("acc must be C-contiguous"))?;
    let res = py
        .detach(|| peaks(a, window.0, window.1))
        .map_err(PyRspivErr::from)?;
    peaks_dict(py, &res)
}

/// Fitted peaks as a dict of 1D arrays: `dx, dy, cxx, cyy, cxy, axx, ayy, axy, coef, count,
/// count_auto, ok`.
fn peaks_dict<'py>(py: Python<'py>, res: &[EnsemblePeak]) -> PyResult<Bound<'py, PyDict>> {
    let col = |f: &dyn Fn(&EnsemblePeak) -> f64| res.iter().map(f).collect::<Vec<f64>>();
    let d = PyDict::new(py);
    d.set_item("dx", col(&|p| p.dx).into_pyarray(py))?;
    d.set_item("dy", col(&|p| p.dy).into_pyarray(py))?;
    d.set_item("cxx", col(&|p| p.cross.0).into_pyarray(py))?;
    d.set_item("cyy", col(&|p| p.cross.1).into_pyarray(py))?;
    d.set_item("cxy", col(&|p| p.cross.2).into_pyarray(py))?;
    d.set_item("axx", col(&|p| p.auto.0).into_pyarray(py))?;
    d.set_item("ayy", col(&|p| p.auto.1).into_pyarray(py))?;
    d.set_item("axy", col(&|p| p.auto.2).into_pyarray(py))?;
    d.set_item("adx", col(&|p| p.auto_centre.0).into_pyarray(py))?;
    d.set_item("ady", col(&|p| p.auto_centre.1).into_pyarray(py))?;
    d.set_item("coef", col(&|p| p.coef).into_pyarray(py))?;
    d.set_item("peak_ratio", col(&|p| p.peak_ratio).into_pyarray(py))?;
    d.set_item("count", col(&|p| p.count.0).into_pyarray(py))?;
    d.set_item("count_auto", col(&|p| p.count.1).into_pyarray(py))?;
    d.set_item(
        "ok",
        res.iter()
            .map(|p| p.ok)
            .collect::<Vec<bool>>()
            .into_pyarray(py),
    )?;
    Ok(d)
}

/// Values per row of a single-pixel accumulator with lags +-rx x +-ry.
#[pyfunction]
fn pixel_stride(rx: usize, ry: usize) -> usize {
    piv_core::ensemble_pixel::stride(rx, ry)
}

/// Add one frame pair to the single-pixel accumulator `acc` (rows x stride, float64,
/// C-contiguous) in place (`piv_core::ensemble_pixel::accumulate`); returns the segments added.
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, seg, nseg, x0, lags, y, du, dv, acc, auto=true,
    mask=None, interpolation="bspline"))]
#[allow(clippy::too_many_arguments)]
fn pixel_add<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    seg: usize,
    nseg: usize,
    x0: f64,
    lags: (usize, usize),
    y: PyReadonlyArray1<'py, f64>,
    du: PyReadonlyArray1<'py, f64>,
    dv: PyReadonlyArray1<'py, f64>,
    acc: &Bound<'py, PyArray2<f64>>,
    auto: bool,
    mask: Option<PyReadonlyArray2<'py, bool>>,
    interpolation: &str,
) -> PyResult<usize> {
    let interp: Interpolation = interpolation.parse().map_err(PyRspivErr::from)?;
    let fr = frames(frame_a, frame_b)?;
    let mut rw = acc
        .try_readwrite()
        .map_err(|_| invalid("acc is borrowed elsewhere"))?;
    let slice = rw
        .as_slice_mut()
        .map_err(|_| invalid("acc must be a C-contiguous float64 array"))?;
    let cell = Mutex::new(slice);
    let band = PixelBand {
        seg,
        nseg,
        x0,
        rx: lags.0,
        ry: lags.1,
        y: y.as_slice()?,
        du: du.as_slice()?,
        dv: dv.as_slice()?,
    };
    let mask = mask.as_ref().map(|m| m.as_array());
    with_frames(py, &fr, |r| {
        let mut acc = cell.lock().unwrap_or_else(|e| e.into_inner());
        Ok(r.pixel_add(mask, &band, interp, auto, &mut acc)?)
    })
}

/// The fitted row peaks of a single-pixel accumulator (dict as `ensemble_peaks`).
#[pyfunction]
fn pixel_peaks<'py>(
    py: Python<'py>,
    acc: PyReadonlyArray2<'py, f64>,
    lags: (usize, usize),
) -> PyResult<Bound<'py, PyDict>> {
    let a = acc
        .as_slice()
        .map_err(|_| invalid("acc must be C-contiguous"))?;
    let res = py
        .detach(|| piv_core::ensemble_pixel::peaks(a, lags.0, lags.1))
        .map_err(PyRspivErr::from)?;
    peaks_dict(py, &res)
}

/// Two 1D float64 arrays.
type Pair<'py> = (
    Bound<'py, numpy::PyArray1<f64>>,
    Bound<'py, numpy::PyArray1<f64>>,
);

/// The mean of a grid field's bilinear interpolant over each `w` x `h` window centred at
/// `(x, y)` (`piv_core::GridField::window_mean_at`): the part of a window's displacement that
/// deforming it by the field accounts for. Returns `(u, v)`.
#[pyfunction]
fn grid_field_window_mean<'py>(
    py: Python<'py>,
    field_grid: (f64, f64, f64, f64),
    field_u: PyReadonlyArray2<'py, f64>,
    field_v: PyReadonlyArray2<'py, f64>,
    x: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
    window: (usize, usize),
) -> PyResult<Pair<'py>> {
    let f = grid_field(Some(field_grid), Some(&field_u), Some(&field_v))?.expect("all three given");
    let (x, y) = (x.as_slice()?, y.as_slice()?);
    if x.len() != y.len() {
        return Err(invalid("x and y differ in length"));
    }
    let (u, v): (Vec<f64>, Vec<f64>) = py.detach(|| {
        x.iter()
            .zip(y)
            .map(|(&x, &y)| f.window_mean_at(x, y, window.0, window.1))
            .unzip()
    });
    Ok((u.into_pyarray(py), v.into_pyarray(py)))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(grid_field_window_mean, m)?)?;
    m.add(
        "ENSEMBLE_MIN_PEAK_RATIO",
        piv_core::ensemble::MIN_PEAK_RATIO,
    )?;
    m.add_function(wrap_pyfunction!(ensemble_stride, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble_add, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble_peaks, m)?)?;
    m.add_function(wrap_pyfunction!(pixel_stride, m)?)?;
    m.add_function(wrap_pyfunction!(pixel_add, m)?)?;
    m.add_function(wrap_pyfunction!(pixel_peaks, m)?)?;
    Ok(())
}
