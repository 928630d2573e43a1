//! Binding of the calibration pieces of dewarp-core: `render_target`, `detect_markers`,
//! `index_grid`, `monte_carlo`. The Python facade (`rspiv.calibration`, `rspiv.montecarlo`,
//! `rspiv.synth.target`) validates, orchestrates and documents.

use crate::errors::{invalid, PyRspivErr};
use dewarp_core::markers::{DetectOptions, Detection, DotProfile, MarkerKind, Pixel};
use dewarp_core::montecarlo::{MonteCarloConfig, MonteCarloResult};
use dewarp_core::target::{Polygon, TargetScene};
use dewarp_core::Model;
use ndarray::{Array1, Array2, Array3, ArrayView2};
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Render a synthetic target (uint16); see `dewarp_core::target`.
#[pyfunction]
#[pyo3(signature = (height, width, centres, sigma_px, amplitude, background = 200.0,
    gradient = (0.08, -0.05), vignetting = 0.15, gain = 0.5, read_noise = 4.0,
    full_scale = 4095.0, seed = 0, radius_px = None, plate = 0.0, sides = None,
    orientation_rad = None))]
fn render_target<'py>(
    py: Python<'py>,
    height: usize,
    width: usize,
    centres: PyReadonlyArray2<'py, f64>,
    sigma_px: PyReadonlyArray1<'py, f64>,
    amplitude: PyReadonlyArray1<'py, f64>,
    background: f64,
    gradient: (f64, f64),
    vignetting: f64,
    gain: f64,
    read_noise: f64,
    full_scale: f64,
    seed: u64,
    radius_px: Option<PyReadonlyArray1<'py, f64>>,
    plate: f64,
    sides: Option<PyReadonlyArray1<'py, u32>>,
    orientation_rad: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<Bound<'py, PyArray2<u16>>> {
    let scene = TargetScene {
        plate,
        background,
        gradient,
        vignetting,
        gain,
        read_noise,
        full_scale,
        seed,
    };
    let (c, s, a) = (
        centres.as_array(),
        sigma_px.as_array(),
        amplitude.as_array(),
    );
    let r = radius_px.as_ref().map(|r| r.as_array());
    // Printed polygons (fiducials): `sides` 0 is a round marker.
    let shapes: Option<Vec<Option<Polygon>>> = match (&sides, &orientation_rad) {
        (None, None) => None,
        (Some(n), o) => {
            let n = n.as_array();
            let o = o.as_ref().map(|o| o.as_array());
            if o.is_some_and(|o| o.len() != n.len()) {
                return Err(invalid(format!(
                    "render_target: {} sides but {} orientations",
                    n.len(),
                    o.map_or(0, |o| o.len())
                )));
            }
            Some(
                n.iter()
                    .enumerate()
                    .map(|(k, &m)| {
                        (m != 0).then(|| Polygon {
                            sides: m,
                            angle: o.map_or(0.0, |o| o[k]),
                        })
                    })
                    .collect(),
            )
        }
        (None, Some(_)) => return Err(invalid("render_target: orientation_rad without sides")),
    };
    let img = py
        .detach(|| {
            dewarp_core::target::render_target_shapes(
                height,
                width,
                c,
                s,
                a,
                r,
                shapes.as_deref(),
                &scene,
            )
        })
        .map_err(PyRspivErr::from)?;
    Ok(img.into_pyarray(py))
}

fn detect<T: Pixel + numpy::Element>(
    py: Python<'_>,
    a: &Bound<'_, PyAny>,
    opts: &DetectOptions,
) -> PyResult<Option<dewarp_core::error::Result<Detection>>> {
    let Ok(arr) = a.extract::<PyReadonlyArray2<'_, T>>() else {
        return Ok(None);
    };
    let v: ArrayView2<T> = arr.as_array();
    Ok(Some(
        py.detach(|| dewarp_core::markers::detect_markers(v, opts)),
    ))
}

/// Detect markers; returns a dict of arrays (see `rspiv._rspiv.pyi`).
#[pyfunction]
#[pyo3(signature = (image, marker = "dot", size_px = None, threshold = 0.25, min_snr = 8.0,
    dark = None, profile = "auto"))]
fn detect_markers<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    marker: &str,
    size_px: Option<f64>,
    threshold: f64,
    min_snr: f64,
    dark: Option<bool>,
    profile: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let kind: MarkerKind = marker.parse().map_err(PyRspivErr::from)?;
    let profile: DotProfile = profile.parse().map_err(PyRspivErr::from)?;
    let opts = DetectOptions {
        kind,
        size_px,
        threshold,
        min_snr,
        dark,
        profile,
    };
    let res = match detect::<u16>(py, image, &opts)? {
        Some(r) => r,
        None => match detect::<u8>(py, image, &opts)? {
            Some(r) => r,
            None => match detect::<f32>(py, image, &opts)? {
                Some(r) => r,
                None => match detect::<f64>(py, image, &opts)? {
                    Some(r) => r,
                    None => {
                        return Err(invalid(
                            "image must be a 2D array of uint8, uint16, float32 or float64",
                        ))
                    }
                },
            },
        },
    };
    let det = res.map_err(PyRspivErr::from)?;
    let n = det.markers.len();
    let mut pos = Array2::<f64>::zeros((n, 2));
    let mut cov = Array3::<f64>::zeros((n, 2, 2));
    let mut amp = Array1::<f64>::zeros(n);
    let mut width = Array1::<f64>::zeros(n);
    let mut radius = Array1::<f64>::zeros(n);
    let mut strength = Array1::<f64>::zeros(n);
    for (k, m) in det.markers.iter().enumerate() {
        pos[[k, 0]] = m.x;
        pos[[k, 1]] = m.y;
        cov[[k, 0, 0]] = m.sigma_x * m.sigma_x;
        cov[[k, 1, 1]] = m.sigma_y * m.sigma_y;
        cov[[k, 0, 1]] = m.cov_xy;
        cov[[k, 1, 0]] = m.cov_xy;
        amp[k] = m.amplitude;
        width[k] = m.width;
        radius[k] = m.radius;
        strength[k] = m.strength;
    }
    let d = PyDict::new(py);
    d.set_item("image_px", pos.into_pyarray(py))?;
    d.set_item("cov_px2", cov.into_pyarray(py))?;
    d.set_item("amplitude", amp.into_pyarray(py))?;
    d.set_item("width_px", width.into_pyarray(py))?;
    d.set_item("strength", strength.into_pyarray(py))?;
    d.set_item("size_px", det.size_px)?;
    d.set_item("radius_px", radius.into_pyarray(py))?;
    let rej = Array2::from_shape_fn((det.rejected.len(), 2), |(k, a)| det.rejected[k][a]);
    d.set_item("rejected_px", rej.into_pyarray(py))?;
    d.set_item("downsample", det.downsample)?;
    d.set_item("profile", det.profile)?;
    d.set_item("dark", det.dark)?;
    if let Some(sv) = &det.survey {
        d.set_item("survey_lattice", sv.n_lattice)?;
        d.set_item("survey_detected", sv.n_detected)?;
        d.set_item("survey_snr", sv.snr)?;
    }
    Ok(d)
}

/// `touching_share` on an image of element type `T`, or None when `a` is not one.
fn touching<T: Pixel + numpy::Element>(
    py: Python<'_>,
    a: &Bound<'_, PyAny>,
    pts: &[[f64; 2]],
    idx: &[Option<(i32, i32)>],
    amp: &[f64],
    dark: bool,
) -> Option<Option<(f64, usize)>> {
    let arr = a.extract::<PyReadonlyArray2<'_, T>>().ok()?;
    let v: ArrayView2<T> = arr.as_array();
    Some(py.detach(|| dewarp_core::markers::touching_share(v, pts, idx, amp, dark)))
}

/// Median share of the segments between lattice neighbours as dark as the dots
/// (`dewarp_core::markers::touching_share`): `(share, pairs)` or None under 8 pairs. `index`
/// (N, 2): each point's lattice site (i, j), NaN for none.
#[pyfunction]
#[pyo3(signature = (image, image_px, index, amplitude, dark))]
fn touching_share<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    image_px: PyReadonlyArray2<'py, f64>,
    index: PyReadonlyArray2<'py, f64>,
    amplitude: PyReadonlyArray1<'py, f64>,
    dark: bool,
) -> PyResult<Option<(f64, usize)>> {
    let pts = points("image_px", &image_px)?;
    let iv = index.as_array();
    let amp = amplitude.as_array().to_vec();
    if iv.dim() != (pts.len(), 2) || amp.len() != pts.len() {
        return Err(invalid(format!(
            "index must be ({n}, 2) and amplitude ({n},) for {n} points, got {:?} and {}",
            iv.dim(),
            amp.len(),
            n = pts.len()
        )));
    }
    let idx: Vec<Option<(i32, i32)>> = iv
        .outer_iter()
        .map(|r| {
            (r[0].is_finite() && r[1].is_finite())
                .then(|| (r[0].round() as i32, r[1].round() as i32))
        })
        .collect();
    let (p, i, a) = (&pts[..], &idx[..], &amp[..]);
    touching::<u16>(py, image, p, i, a, dark)
        .or_else(|| touching::<u8>(py, image, p, i, a, dark))
        .or_else(|| touching::<f32>(py, image, p, i, a, dark))
        .or_else(|| touching::<f64>(py, image, p, i, a, dark))
        .ok_or_else(|| invalid("image must be a 2D array of uint8, uint16, float32 or float64"))
}

fn points(name: &str, a: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<[f64; 2]>> {
    let v = a.as_array();
    if v.ncols() != 2 {
        return Err(invalid(format!(
            "{name} must have shape (N, 2), got {:?}",
            a.shape()
        )));
    }
    Ok(v.rows().into_iter().map(|r| [r[0], r[1]]).collect())
}

/// Index points on a square grid; returns (index (N, 2) int32, found (N,) bool, origin, a1, a2).
#[pyfunction]
#[pyo3(signature = (points_px, centre, tol = 0.3))]
#[allow(clippy::type_complexity)]
fn index_grid<'py>(
    py: Python<'py>,
    points_px: PyReadonlyArray2<'py, f64>,
    centre: (f64, f64),
    tol: f64,
) -> PyResult<(
    Bound<'py, PyArray2<i32>>,
    Bound<'py, numpy::PyArray1<bool>>,
    usize,
    (f64, f64),
    (f64, f64),
)> {
    let p = points("points_px", &points_px)?;
    let g = py
        .detach(|| dewarp_core::grid::index_grid(&p, [centre.0, centre.1], tol))
        .map_err(PyRspivErr::from)?;
    let n = p.len();
    let mut idx = Array2::<i32>::zeros((n, 2));
    let mut found = Array1::<bool>::from_elem(n, false);
    for (k, v) in g.index.iter().enumerate() {
        if let Some((i, j)) = v {
            idx[[k, 0]] = *i;
            idx[[k, 1]] = *j;
            found[k] = true;
        }
    }
    Ok((
        idx.into_pyarray(py),
        found.into_pyarray(py),
        g.origin,
        (g.a1[0], g.a1[1]),
        (g.a2[0], g.a2[1]),
    ))
}

/// Monte Carlo study of a mapping; returns a dict (see `rspiv._rspiv.pyi`).
#[pyfunction]
#[pyo3(signature = (object_px, image_px, model, n, sigma_image_px, sigma_object_px,
    centre_index, scale = None, seed = 0, hist_bins = 0, hist_half_range_px = 2.0,
    keep_samples = false, threads = None))]
fn monte_carlo<'py>(
    py: Python<'py>,
    object_px: PyReadonlyArray2<'py, f64>,
    image_px: PyReadonlyArray2<'py, f64>,
    model: &str,
    n: usize,
    sigma_image_px: f64,
    sigma_object_px: f64,
    centre_index: usize,
    scale: Option<f64>,
    seed: u64,
    hist_bins: usize,
    hist_half_range_px: f64,
    keep_samples: bool,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let model: Model = model.parse().map_err(PyRspivErr::from)?;
    let o = points("object_px", &object_px)?;
    let i = points("image_px", &image_px)?;
    let cfg = MonteCarloConfig {
        model,
        n,
        sigma_image_px,
        sigma_object_px,
        centre_index,
        scale,
        seed,
        hist_bins,
        hist_half_range_px,
        keep_samples,
        threads,
    };
    let r: MonteCarloResult = py
        .detach(|| dewarp_core::montecarlo::monte_carlo(&o, &i, &cfg))
        .map_err(PyRspivErr::from)?;
    let m = o.len();
    let to2 = |v: &[[f64; 2]]| Array2::from_shape_fn((v.len(), 2), |(k, j)| v[k][j]);
    let cov = Array3::from_shape_fn((m, 2, 2), |(k, a, b)| match (a, b) {
        (0, 0) => r.cov[k][0],
        (1, 1) => r.cov[k][2],
        _ => r.cov[k][1],
    });
    let d = PyDict::new(py);
    d.set_item("n_ok", r.n_ok)?;
    d.set_item("n_failed", r.n_failed)?;
    d.set_item("mean_px", to2(&r.mean).into_pyarray(py))?;
    d.set_item("cov_px2", cov.into_pyarray(py))?;
    d.set_item("radius99_px", Array1::from(r.radius99).into_pyarray(py))?;
    d.set_item("within1", Array1::from(r.within1).into_pyarray(py))?;
    d.set_item("within2", Array1::from(r.within2).into_pyarray(py))?;
    d.set_item("nominal_px", to2(&r.nominal).into_pyarray(py))?;
    if hist_bins > 0 {
        let h = Array3::from_shape_vec((m, hist_bins, hist_bins), r.hist)
            .map_err(|e| invalid(e.to_string()))?;
        d.set_item("hist", h.into_pyarray(py))?;
    }
    if keep_samples {
        let s = Array3::from_shape_vec((r.n_ok, m, 2), r.samples)
            .map_err(|e| invalid(e.to_string()))?;
        d.set_item("samples", s.into_pyarray(py))?;
    }
    Ok(d)
}

/// Register the calibration functions.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render_target, m)?)?;
    m.add_function(wrap_pyfunction!(detect_markers, m)?)?;
    m.add_function(wrap_pyfunction!(index_grid, m)?)?;
    m.add_function(wrap_pyfunction!(touching_share, m)?)?;
    m.add("TOUCH_SHARE", dewarp_core::markers::TOUCH_SHARE)?;
    m.add_function(wrap_pyfunction!(monte_carlo, m)?)?;
    Ok(())
}
