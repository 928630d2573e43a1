//! Binding of piv-core: `piv`, `piv_at`, `piv_final_points`, `render_particles`,
//! `window_response`.
//!
//! Frames may be uint8, uint16, float32 or float64 (both of one dtype); they are read in place
//! (no copy for C-contiguous arrays). All work runs with the GIL released.

use crate::errors::{invalid, PyRspivErr};
use crate::frames::{frames, with_frames};
use ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use piv_core::{Grid, GridField, PivError, PivField, PivSettings, Predictor};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The settings of a call: the JSON object of the one vocabulary (`rspiv.PivSettings.to_json`,
/// parsed by `piv_core::PivSettings::from_json`).
pub(crate) fn settings(text: &str) -> PyResult<PivSettings> {
    Ok(PivSettings::from_json(text).map_err(PyRspivErr::from)?)
}

pub(crate) fn field_dict<'py>(py: Python<'py>, f: PivField) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("x", f.x.into_pyarray(py))?;
    d.set_item("y", f.y.into_pyarray(py))?;
    d.set_item("u", f.u.into_pyarray(py))?;
    d.set_item("v", f.v.into_pyarray(py))?;
    d.set_item("peak_ratio", f.peak_ratio.into_pyarray(py))?;
    d.set_item("coef", f.coef.into_pyarray(py))?;
    d.set_item("sigma_u", f.sigma_u.into_pyarray(py))?;
    d.set_item("sigma_v", f.sigma_v.into_pyarray(py))?;
    d.set_item("valid", f.valid.into_pyarray(py))?;
    d.set_item("replaced", f.replaced.into_pyarray(py))?;
    d.set_item("peak_choice", f.peak_choice.into_pyarray(py))?;
    d.set_item("masked", f.masked.into_pyarray(py))?;
    d.set_item("particle_diameter", f.particle_diameter)?;
    match f.grid {
        Some(g) => d.set_item("grid", (g.x0, g.y0, g.dx, g.dy))?,
        None => d.set_item("grid", py.None())?,
    }
    Ok(d)
}

/// Multipass PIV on a regular grid; returns a dict of arrays (see `rspiv.piv`).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, settings, mask=None))]
fn piv<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    settings: &str,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = self::settings(settings)?;
    let fr = frames(frame_a, frame_b)?;
    let mask = mask.as_ref().map(|m| m.as_array());
    let field = with_frames(py, &fr, |r| Ok(r.piv(mask, &s)?))?;
    field_dict(py, field)
}

/// Method II's PIV in one call: the passes but the last on the regular grid (the predictor),
/// the last at the points (x, y) on the same prepared frames (see
/// `piv_core::piv_with_final_points`). Returns the final field's dict with the predictor's
/// dict (or None for one pass) under "predictor".
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, x, y, settings, mask=None))]
fn piv_final_points<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    x: PyReadonlyArray2<'py, f64>,
    y: PyReadonlyArray2<'py, f64>,
    settings: &str,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = self::settings(settings)?;
    let fr = frames(frame_a, frame_b)?;
    let (xv, yv) = (x.as_array(), y.as_array());
    let mask = mask.as_ref().map(|m| m.as_array());
    let (pred, field) = with_frames(py, &fr, |r| Ok(r.piv_final_points(xv, yv, mask, &s)?))?;
    let d = field_dict(py, field)?;
    match pred {
        Some(p) => d.set_item("predictor", field_dict(py, p)?)?,
        None => d.set_item("predictor", py.None())?,
    }
    Ok(d)
}

/// PIV at given points (arrays x, y of one shape) with a predictor; returns a dict of arrays.
/// `settings` gives the sub-pixel fit, interpolation and validation (its passes and
/// deformation are not used: `windows` and `iterations` are the passes at the points).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, x, y, windows, settings, iterations=1, predictor_u=None,
    predictor_v=None, field_grid=None, field_u=None, field_v=None, mask=None))]
fn piv_at<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    x: PyReadonlyArray2<'py, f64>,
    y: PyReadonlyArray2<'py, f64>,
    windows: Vec<(usize, usize)>,
    settings: &str,
    iterations: usize,
    predictor_u: Option<PyReadonlyArray2<'py, f64>>,
    predictor_v: Option<PyReadonlyArray2<'py, f64>>,
    field_grid: Option<(f64, f64, f64, f64)>,
    field_u: Option<PyReadonlyArray2<'py, f64>>,
    field_v: Option<PyReadonlyArray2<'py, f64>>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = self::settings(settings)?;
    let gf = grid_field(field_grid, field_u.as_ref(), field_v.as_ref())?;
    let pu = predictor_u.as_ref().map(|a| a.as_array());
    let pv = predictor_v.as_ref().map(|a| a.as_array());
    let pred = match (&gf, pu, pv) {
        (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
            return Err(invalid(
                "give either per-point predictors or a predictor field, not both",
            ))
        }
        (Some(f), None, None) => Predictor::Field(f),
        (None, Some(u), Some(v)) => Predictor::PerPoint { u, v },
        (None, None, None) => Predictor::Zero,
        _ => {
            return Err(invalid(
                "predictor_u and predictor_v must be given together",
            ))
        }
    };
    let fr = frames(frame_a, frame_b)?;
    let (xv, yv) = (x.as_array(), y.as_array());
    let mask = mask.as_ref().map(|m| m.as_array());
    let field = with_frames(py, &fr, |r| {
        Ok(r.piv_at(xv, yv, pred, mask, &windows, iterations, &s)?)
    })?;
    field_dict(py, field)
}

/// Render Gaussian particles integrated over the pixel area into a uint16 image.
#[pyfunction]
#[pyo3(signature = (height, width, x, y, intensity, diameter, noise_sigma, max_count=4095, seed=0))]
fn render_particles<'py>(
    py: Python<'py>,
    height: usize,
    width: usize,
    x: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
    intensity: PyReadonlyArray1<'py, f64>,
    diameter: PyReadonlyArray1<'py, f64>,
    noise_sigma: f64,
    max_count: u16,
    seed: u64,
) -> PyResult<Bound<'py, PyArray2<u16>>> {
    let (x, y, i, d) = (
        x.as_array(),
        y.as_array(),
        intensity.as_array(),
        diameter.as_array(),
    );
    let res: Result<Array2<u16>, PivError> = py.detach(|| {
        let xs = x.as_standard_layout();
        let ys = y.as_standard_layout();
        let is = i.as_standard_layout();
        let ds = d.as_standard_layout();
        piv_core::render_particles(
            height,
            width,
            xs.as_slice().expect("contiguous"),
            ys.as_slice().expect("contiguous"),
            is.as_slice().expect("contiguous"),
            ds.as_slice().expect("contiguous"),
            noise_sigma,
            max_count,
            seed,
        )
    });
    Ok(res.map_err(PyRspivErr::from)?.into_pyarray(py))
}

/// The regular-grid field `(x0, y0, dx, dy)` with `u`, `v` of one shape (all three or none),
/// checked: a non-empty shape, positive steps, finite values.
pub(crate) fn grid_field(
    field_grid: Option<(f64, f64, f64, f64)>,
    field_u: Option<&PyReadonlyArray2<'_, f64>>,
    field_v: Option<&PyReadonlyArray2<'_, f64>>,
) -> PyResult<Option<GridField>> {
    Ok(match (field_grid, field_u, field_v) {
        (Some((x0, y0, dx, dy)), Some(fu), Some(fv)) => {
            let (u, v) = (
                fu.as_array().as_standard_layout().into_owned(),
                fv.as_array().as_standard_layout().into_owned(),
            );
            if u.dim() != v.dim() || u.is_empty() || !(dx > 0.0 && dy > 0.0) {
                return Err(invalid(
                    "predictor field: u and v must share a non-empty shape and the grid steps be > 0",
                ));
            }
            if u.iter().chain(v.iter()).any(|p| !p.is_finite()) {
                return Err(invalid("predictor field contains NaN or inf"));
            }
            let (ny, nx) = u.dim();
            Some(GridField {
                grid: Grid {
                    x0,
                    y0,
                    dx,
                    dy,
                    nx,
                    ny,
                },
                u,
                v,
            })
        }
        (None, None, None) => None,
        _ => {
            return Err(invalid(
                "predictor field needs field_grid, field_u and field_v together",
            ))
        }
    })
}

/// The amplitude ratio with which an `n`-px window weighted by `weighting` returns a sine
/// displacement of wavelength `wavelength` px along its axis (`piv_core::weighting`).
#[pyfunction]
fn window_response(weighting: &str, n: usize, wavelength: f64) -> PyResult<f64> {
    let wt: piv_core::Weighting = weighting.parse().map_err(PyRspivErr::from)?;
    if n == 0 || !(wavelength.is_finite() && wavelength > 0.0) {
        return Err(invalid(format!(
            "window_response: window {n} px and wavelength {wavelength} px must be > 0"
        )));
    }
    Ok(wt.response(n, wavelength))
}

/// Whether a field's frames correlate (`piv_core::validate::correlation_check`): `(uncorrelated,
/// message)`, `uncorrelated` true when the field is no measurement, `message` the one-line
/// warning (also for a field that correlates only in part) or None. `local`: the grid's local
/// test too (a field on a grid, rows along axis 0). `masked`: the windows masked (not counted
/// among those too blank to correlate); None: nothing masked.
#[pyfunction]
#[pyo3(signature = (peak_ratio, valid, local, masked=None))]
fn correlation_check(
    py: Python<'_>,
    peak_ratio: PyReadonlyArray2<'_, f64>,
    valid: PyReadonlyArray2<'_, bool>,
    local: bool,
    masked: Option<PyReadonlyArray2<'_, bool>>,
) -> PyResult<(bool, Option<String>)> {
    let (r, v) = (peak_ratio.as_array(), valid.as_array());
    let m = masked.as_ref().map(|m| m.as_array());
    for (name, dim) in [("valid", Some(v.dim())), ("masked", m.map(|m| m.dim()))] {
        match dim {
            Some(d) if d != r.dim() => {
                return Err(invalid(format!(
                    "correlation_check: peak_ratio {:?} and {name} {d:?} differ in shape",
                    r.dim()
                )))
            }
            _ => {}
        }
    }
    let c = py.detach(|| piv_core::validate::correlation_check(r, v, m, local));
    let gone = matches!(c, piv_core::validate::Correlation::Uncorrelated(_));
    Ok((gone, c.message().map(str::to_string)))
}

/// The particle images' e^-2 diameter `(x, y)` px of a frame pair as recorded, from up to
/// 4096 windows of `window` `(w, h)` px side by side, the backgrounds of frames A and B
/// subtracted when given (`piv_core::particle_size::measure`).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, window, mask=None, background_a=None, background_b=None))]
fn particle_diameter<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    window: (usize, usize),
    mask: Option<PyReadonlyArray2<'py, bool>>,
    background_a: Option<PyReadonlyArray2<'py, f32>>,
    background_b: Option<PyReadonlyArray2<'py, f32>>,
) -> PyResult<(f64, f64)> {
    let fr = frames(frame_a, frame_b)?;
    let mask = mask.as_ref().map(|m| m.as_array());
    let bg = match (&background_a, &background_b) {
        (Some(a), Some(b)) => Some((a.as_array(), b.as_array())),
        (None, None) => None,
        _ => {
            return Err(invalid(
                "give both backgrounds (frame A's and frame B's) or neither",
            ))
        }
    };
    with_frames(py, &fr, |r| Ok(r.particle_diameter(window, mask, bg)?))
}

/// The one-line peak-locking warning for particle images of e^-2 diameter `(dx, dy)` px
/// (`piv_core::particle_size::peak_locking_warning`): None from `MIN_PARTICLE_DIAMETER` on, or
/// when not measured (NaN).
#[pyfunction]
fn peak_locking_warning(diameter_x: f64, diameter_y: f64) -> Option<String> {
    piv_core::particle_size::peak_locking_warning((diameter_x, diameter_y))
}

/// Register the PIV functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(correlation_check, m)?)?;
    m.add(
        "MIN_MEDIAN_PEAK_RATIO",
        piv_core::validate::MIN_MEDIAN_PEAK_RATIO,
    )?;
    m.add("MAX_BLANK_FRACTION", piv_core::validate::MAX_BLANK_FRACTION)?;
    m.add(
        "MAX_REPLACED_FRACTION",
        piv_core::validate::MAX_REPLACED_FRACTION,
    )?;
    m.add("BLANK_EDGE", piv_core::validate::BLANK_EDGE)?;
    m.add_function(wrap_pyfunction!(peak_locking_warning, m)?)?;
    m.add_function(wrap_pyfunction!(particle_diameter, m)?)?;
    m.add(
        "MIN_PARTICLE_DIAMETER",
        piv_core::particle_size::MIN_PARTICLE_DIAMETER,
    )?;
    m.add_function(wrap_pyfunction!(piv, m)?)?;
    m.add_function(wrap_pyfunction!(piv_at, m)?)?;
    m.add_function(wrap_pyfunction!(piv_final_points, m)?)?;
    m.add_function(wrap_pyfunction!(render_particles, m)?)?;
    m.add_function(wrap_pyfunction!(window_response, m)?)?;
    Ok(())
}
