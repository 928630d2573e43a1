//! Binding of piv-core: `piv`, `piv_at`, `piv_final_points`, `render_particles`.
//!
//! Frames may be uint8, uint16, float32 or float64 (both of one dtype); they are read in place
//! (no copy for C-contiguous arrays). All work runs with the GIL released.

use crate::errors::{invalid_input, piv_err};
use ndarray::{Array2, ArrayView2};
use numpy::{Element, IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use piv_core::{
    Grid, GridField, Interpolation, Mode, Pass, PivError, PivField, PivSettings, Pixel, Predictor,
    SubPixel,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn settings(
    py: Python<'_>,
    deformation: &str,
    subpixel: &str,
    interpolation: &str,
    validate: bool,
    median_eps: f64,
    median_threshold: f64,
    min_peak_ratio: f64,
) -> PyResult<PivSettings> {
    let interpolation = match interpolation {
        "bspline" => Interpolation::BSpline,
        "bspline3" => Interpolation::BSpline3,
        "keys" | "bicubic" => Interpolation::Keys,
        other => {
            return Err(invalid_input(
                py,
                format!("interpolation {other:?}: use \"bspline\", \"bspline3\" or \"keys\""),
            ))
        }
    };
    let mode = match deformation {
        "symmetric" | "deform" => Mode::Deform,
        "offset" => Mode::Offset,
        other => {
            return Err(invalid_input(
                py,
                format!("deformation {other:?}: use \"symmetric\" or \"offset\""),
            ))
        }
    };
    let subpixel = match subpixel {
        "gauss3" => SubPixel::Gauss3,
        "gauss2d" => SubPixel::Gauss2d,
        other => {
            return Err(invalid_input(
                py,
                format!("subpixel {other:?}: use \"gauss3\" or \"gauss2d\""),
            ))
        }
    };
    Ok(PivSettings {
        passes: Vec::new(),
        mode,
        subpixel,
        interpolation,
        validate,
        median_eps,
        median_threshold,
        min_peak_ratio,
    })
}

/// One [`Pass`] per window size, from the per-pass lists of the Python call.
fn passes(
    py: Python<'_>,
    windows: &[(usize, usize)],
    overlaps: &[f64],
    iterations: &[usize],
) -> PyResult<Vec<Pass>> {
    if overlaps.len() != windows.len() || iterations.len() != windows.len() {
        return Err(invalid_input(
            py,
            "windows, overlaps and iterations must have one entry per pass",
        ));
    }
    Ok(windows
        .iter()
        .zip(overlaps)
        .zip(iterations)
        .map(|((&(w, h), &overlap), &iterations)| Pass {
            w,
            h,
            overlap,
            iterations,
        })
        .collect())
}

fn field_dict<'py>(py: Python<'py>, f: PivField) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("x", f.x.into_pyarray(py))?;
    d.set_item("y", f.y.into_pyarray(py))?;
    d.set_item("u", f.u.into_pyarray(py))?;
    d.set_item("v", f.v.into_pyarray(py))?;
    d.set_item("peak_ratio", f.peak_ratio.into_pyarray(py))?;
    d.set_item("coef", f.coef.into_pyarray(py))?;
    d.set_item("valid", f.valid.into_pyarray(py))?;
    d.set_item("replaced", f.replaced.into_pyarray(py))?;
    d.set_item("masked", f.masked.into_pyarray(py))?;
    match f.grid {
        Some(g) => d.set_item("grid", (g.x0, g.y0, g.dx, g.dy))?,
        None => d.set_item("grid", py.None())?,
    }
    Ok(d)
}

/// The frames as views of one pixel type.
enum Frames<'py> {
    U8(PyReadonlyArray2<'py, u8>, PyReadonlyArray2<'py, u8>),
    U16(PyReadonlyArray2<'py, u16>, PyReadonlyArray2<'py, u16>),
    F32(PyReadonlyArray2<'py, f32>, PyReadonlyArray2<'py, f32>),
    F64(PyReadonlyArray2<'py, f64>, PyReadonlyArray2<'py, f64>),
}

fn frames<'py>(a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>) -> PyResult<Frames<'py>> {
    fn both<'py, T: Element>(
        a: &Bound<'py, PyAny>,
        b: &Bound<'py, PyAny>,
    ) -> Option<(PyReadonlyArray2<'py, T>, PyReadonlyArray2<'py, T>)> {
        Some((a.extract().ok()?, b.extract().ok()?))
    }
    if let Some((x, y)) = both::<u16>(a, b) {
        return Ok(Frames::U16(x, y));
    }
    if let Some((x, y)) = both::<f32>(a, b) {
        return Ok(Frames::F32(x, y));
    }
    if let Some((x, y)) = both::<f64>(a, b) {
        return Ok(Frames::F64(x, y));
    }
    if let Some((x, y)) = both::<u8>(a, b) {
        return Ok(Frames::U8(x, y));
    }
    Err(invalid_input(
        a.py(),
        "frame_a and frame_b must be 2D arrays of one dtype among uint8, uint16, float32, float64",
    ))
}

/// Run `f` on the frames' views with the GIL released.
fn with_frames<R: Send>(
    py: Python<'_>,
    fr: &Frames<'_>,
    f: impl Fn(&dyn Runner) -> Result<R, PivError> + Send + Sync,
) -> PyResult<R> {
    let res = match fr {
        Frames::U8(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::U16(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::F32(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::F64(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
    };
    res.map_err(|e| piv_err(py, e))
}

/// Object-safe entry points over one frame pair of any pixel type.
trait Runner: Sync {
    fn piv(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<PivField, PivError>;
    fn piv_at(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        pred: Predictor<'_>,
        mask: Option<ArrayView2<'_, bool>>,
        windows: &[(usize, usize)],
        iterations: usize,
        s: &PivSettings,
    ) -> Result<PivField, PivError>;
    fn piv_final_points(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<(Option<PivField>, PivField), PivError>;
}

impl<T: Pixel> Runner for (ArrayView2<'_, T>, ArrayView2<'_, T>) {
    fn piv(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<PivField, PivError> {
        piv_core::piv(self.0, self.1, mask, s)
    }
    fn piv_at(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        pred: Predictor<'_>,
        mask: Option<ArrayView2<'_, bool>>,
        windows: &[(usize, usize)],
        iterations: usize,
        s: &PivSettings,
    ) -> Result<PivField, PivError> {
        piv_core::piv_at(self.0, self.1, x, y, pred, mask, windows, iterations, s)
    }
    fn piv_final_points(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<(Option<PivField>, PivField), PivError> {
        piv_core::piv_with_final_points(self.0, self.1, x, y, mask, s)
    }
}

/// Multipass PIV on a regular grid; returns a dict of arrays (see `rspiv.piv`).
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, windows, overlaps, iterations, deformation="symmetric",
    subpixel="gauss3", interpolation="bspline", validate=true, median_eps=0.1,
    median_threshold=2.0, min_peak_ratio=0.0, mask=None))]
fn piv<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    windows: Vec<(usize, usize)>,
    overlaps: Vec<f64>,
    iterations: Vec<usize>,
    deformation: &str,
    subpixel: &str,
    interpolation: &str,
    validate: bool,
    median_eps: f64,
    median_threshold: f64,
    min_peak_ratio: f64,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut s = settings(
        py,
        deformation,
        subpixel,
        interpolation,
        validate,
        median_eps,
        median_threshold,
        min_peak_ratio,
    )?;
    s.passes = passes(py, &windows, &overlaps, &iterations)?;
    let fr = frames(frame_a, frame_b)?;
    let mask = mask.as_ref().map(|m| m.as_array());
    let field = with_frames(py, &fr, |r| r.piv(mask, &s))?;
    field_dict(py, field)
}

/// Method II's PIV in one call: the passes but the last on the regular grid (the predictor),
/// the last at the points (x, y) on the same prepared frames (see
/// `piv_core::piv_with_final_points`). Returns the final field's dict with the predictor's
/// dict (or None for one pass) under "predictor".
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, x, y, windows, overlaps, iterations, deformation="symmetric",
    subpixel="gauss3", interpolation="bspline", validate=true, median_eps=0.1,
    median_threshold=2.0, min_peak_ratio=0.0, mask=None))]
fn piv_final_points<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    x: PyReadonlyArray2<'py, f64>,
    y: PyReadonlyArray2<'py, f64>,
    windows: Vec<(usize, usize)>,
    overlaps: Vec<f64>,
    iterations: Vec<usize>,
    deformation: &str,
    subpixel: &str,
    interpolation: &str,
    validate: bool,
    median_eps: f64,
    median_threshold: f64,
    min_peak_ratio: f64,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut s = settings(
        py,
        deformation,
        subpixel,
        interpolation,
        validate,
        median_eps,
        median_threshold,
        min_peak_ratio,
    )?;
    s.passes = passes(py, &windows, &overlaps, &iterations)?;
    let fr = frames(frame_a, frame_b)?;
    let (xv, yv) = (x.as_array(), y.as_array());
    let mask = mask.as_ref().map(|m| m.as_array());
    let (pred, field) = with_frames(py, &fr, |r| r.piv_final_points(xv, yv, mask, &s))?;
    let d = field_dict(py, field)?;
    match pred {
        Some(p) => d.set_item("predictor", field_dict(py, p)?)?,
        None => d.set_item("predictor", py.None())?,
    }
    Ok(d)
}

/// PIV at given points (arrays x, y of one shape) with a predictor; returns a dict of arrays.
#[pyfunction]
#[pyo3(signature = (frame_a, frame_b, x, y, windows, iterations=1, predictor_u=None,
    predictor_v=None, field_grid=None, field_u=None, field_v=None, subpixel="gauss3",
    interpolation="bspline", validate=true, median_eps=0.1, median_threshold=2.0, min_peak_ratio=0.0, mask=None))]
fn piv_at<'py>(
    py: Python<'py>,
    frame_a: &Bound<'py, PyAny>,
    frame_b: &Bound<'py, PyAny>,
    x: PyReadonlyArray2<'py, f64>,
    y: PyReadonlyArray2<'py, f64>,
    windows: Vec<(usize, usize)>,
    iterations: usize,
    predictor_u: Option<PyReadonlyArray2<'py, f64>>,
    predictor_v: Option<PyReadonlyArray2<'py, f64>>,
    field_grid: Option<(f64, f64, f64, f64)>,
    field_u: Option<PyReadonlyArray2<'py, f64>>,
    field_v: Option<PyReadonlyArray2<'py, f64>>,
    subpixel: &str,
    interpolation: &str,
    validate: bool,
    median_eps: f64,
    median_threshold: f64,
    min_peak_ratio: f64,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = settings(
        py,
        "symmetric",
        subpixel,
        interpolation,
        validate,
        median_eps,
        median_threshold,
        min_peak_ratio,
    )?;
    let gf: Option<GridField> = match (field_grid, &field_u, &field_v) {
        (Some((x0, y0, dx, dy)), Some(fu), Some(fv)) => {
            let (u, v) = (
                fu.as_array().as_standard_layout().into_owned(),
                fv.as_array().as_standard_layout().into_owned(),
            );
            if u.dim() != v.dim() || u.is_empty() || !(dx > 0.0 && dy > 0.0) {
                return Err(invalid_input(
                    py,
                    "predictor field: u and v must share a non-empty shape and the grid steps be > 0",
                ));
            }
            if u.iter().chain(v.iter()).any(|p| !p.is_finite()) {
                return Err(invalid_input(py, "predictor field contains NaN or inf"));
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
            return Err(invalid_input(
                py,
                "predictor field needs field_grid, field_u and field_v together",
            ))
        }
    };
    let pu = predictor_u.as_ref().map(|a| a.as_array());
    let pv = predictor_v.as_ref().map(|a| a.as_array());
    let pred = match (&gf, pu, pv) {
        (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
            return Err(invalid_input(
                py,
                "give either per-point predictors or a predictor field, not both",
            ))
        }
        (Some(f), None, None) => Predictor::Field(f),
        (None, Some(u), Some(v)) => Predictor::PerPoint { u, v },
        (None, None, None) => Predictor::Zero,
        _ => {
            return Err(invalid_input(
                py,
                "predictor_u and predictor_v must be given together",
            ))
        }
    };
    let fr = frames(frame_a, frame_b)?;
    let (xv, yv) = (x.as_array(), y.as_array());
    let mask = mask.as_ref().map(|m| m.as_array());
    let field = with_frames(py, &fr, |r| {
        r.piv_at(xv, yv, pred, mask, &windows, iterations, &s)
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
    Ok(res.map_err(|e| piv_err(py, e))?.into_pyarray(py))
}

/// Register the PIV functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(piv, m)?)?;
    m.add_function(wrap_pyfunction!(piv_at, m)?)?;
    m.add_function(wrap_pyfunction!(piv_final_points, m)?)?;
    m.add_function(wrap_pyfunction!(render_particles, m)?)?;
    Ok(())
}
