//! Binding of the mapping models: `fit_mapping`, the `NativeMapping` class, and a bench entry
//! timing the allocation-free refit. The Python facade (`rspiv.mapping`) validates and wraps.

use crate::errors::{invalid, PyRspivErr};
use dewarp_core::{FitOptions, FitWorkspace, Mapping, Model};
use ndarray::{Array1, Array2, Array3, ArrayView2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::time::Instant;

/// Inverse-map result: (object points, converged flag per point).
type InverseResult<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<bool>>);

fn check_n2(name: &str, a: &ArrayView2<f64>) -> PyResult<()> {
    if a.ncols() != 2 {
        return Err(invalid(format!(
            "{name} must have shape (N, 2), got ({}, {})",
            a.nrows(),
            a.ncols()
        )));
    }
    Ok(())
}

fn parse_model(model: &str) -> PyResult<Model> {
    model
        .parse::<Model>()
        .map_err(|e| PyRspivErr::from(e).into())
}

/// A fitted mapping object px -> image px (native half of `rspiv.Mapping`).
#[pyclass(name = "NativeMapping", module = "rspiv._rspiv", frozen)]
pub struct PyMapping {
    pub(crate) inner: Mapping,
}

#[pymethods]
impl PyMapping {
    /// Object px -> image px for an (N, 2) array.
    fn forward<'py>(
        &self,
        py: Python<'py>,
        pts: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let v = pts.as_array();
        check_n2("points", &v)?;
        let out = py.detach(|| self.inner.forward_many(v));
        Ok(out.into_pyarray(py))
    }

    /// d(image px)/d(object px) at each of (N, 2) object points: (N, 2, 2).
    fn forward_jacobian<'py>(
        &self,
        py: Python<'py>,
        pts: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let v = pts.as_array();
        check_n2("points", &v)?;
        let out = py.detach(|| {
            let mut out = Array3::zeros((v.nrows(), 2, 2));
            for (k, r) in v.rows().into_iter().enumerate() {
                let j = self.inner.forward_jacobian(r[0], r[1]);
                for a in 0..2 {
                    for b in 0..2 {
                        out[[k, a, b]] = j[a][b];
                    }
                }
            }
            out
        });
        Ok(out.into_pyarray(py))
    }

    /// Image px -> object px for an (N, 2) array: (points, converged flags).
    fn inverse<'py>(
        &self,
        py: Python<'py>,
        pts: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<InverseResult<'py>> {
        let v = pts.as_array();
        check_n2("points", &v)?;
        let (out, ok) = py.detach(|| self.inner.inverse_many(v));
        Ok((out.into_pyarray(py), Array1::from(ok).into_pyarray(py)))
    }

    /// A copy with the rotation set to `theta_rad` (radians, replacing the previous one).
    fn with_rotation(&self, theta_rad: f64) -> PyMapping {
        PyMapping {
            inner: self.inner.with_rotation(theta_rad),
        }
    }

    /// The mapping as JSON text (with format tag and version).
    fn to_json(&self) -> String {
        self.inner.to_json()
    }

    /// Parse JSON written by `to_json`.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<PyMapping> {
        let inner = Mapping::from_json(text).map_err(PyRspivErr::from)?;
        Ok(PyMapping { inner })
    }

    #[getter]
    fn model(&self) -> &'static str {
        self.inner.model.name()
    }

    #[getter]
    fn coefficients<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from(self.inner.coefficients.clone()).into_pyarray(py)
    }

    #[getter]
    fn centre_object(&self) -> (f64, f64) {
        (self.inner.centre_object[0], self.inner.centre_object[1])
    }

    #[getter]
    fn centre_image(&self) -> (f64, f64) {
        (self.inner.centre_image[0], self.inner.centre_image[1])
    }

    #[getter]
    fn scale(&self) -> f64 {
        self.inner.scale
    }

    #[getter]
    fn rotation(&self) -> f64 {
        self.inner.rotation
    }

    #[getter]
    fn residuals<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let r = &self.inner.residuals;
        let mut a = Array2::zeros((r.len(), 2));
        for (k, p) in r.iter().enumerate() {
            a[[k, 0]] = p[0];
            a[[k, 1]] = p[1];
        }
        a.into_pyarray(py)
    }

    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let p = self.inner.model.n_params();
        let c = &self.inner.covariance;
        let a = if c.len() == p * p {
            Array2::from_shape_vec((p, p), c.clone()).map_err(|e| invalid(e.to_string()))?
        } else {
            Array2::from_elem((p, p), f64::NAN)
        };
        Ok(a.into_pyarray(py))
    }

    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.inner.stats;
        let d = PyDict::new(py);
        d.set_item("max_abs_px", (s.max_abs_px[0], s.max_abs_px[1]))?;
        d.set_item("mean_px", (s.mean_px[0], s.mean_px[1]))?;
        d.set_item("rms_px", (s.rms_px[0], s.rms_px[1]))?;
        d.set_item("n_points", s.n_points)?;
        d.set_item("model", s.model.name())?;
        d.set_item("cost", s.cost)?;
        d.set_item("termination", s.termination.as_str())?;
        d.set_item("n_evals", s.n_evals)?;
        Ok(d)
    }
}

/// Fit a mapping model to point pairs (both (N, 2), px).
#[pyfunction]
#[pyo3(signature = (object_px, image_px, model = "p3", center_index = None, scale = None))]
fn fit_mapping<'py>(
    py: Python<'py>,
    object_px: PyReadonlyArray2<'py, f64>,
    image_px: PyReadonlyArray2<'py, f64>,
    model: &str,
    center_index: Option<usize>,
    scale: Option<f64>,
) -> PyResult<PyMapping> {
    let model = parse_model(model)?;
    let (o, i) = (object_px.as_array(), image_px.as_array());
    let opts = FitOptions {
        center_index,
        scale,
        ..FitOptions::default()
    };
    let m = py
        .detach(|| dewarp_core::fit_mapping(o, i, model, &opts))
        .map_err(PyRspivErr::from)?;
    Ok(PyMapping { inner: m })
}

/// Seconds per refit of the allocation-free `FitWorkspace::fit_normalized` (mean over
/// `repeats` fits on one core). `obj_hat`, `img_hat`: K stacked data sets of `n_points`
/// normalised points each, shape (K * n_points, 2), fitted in turn; `warm_start`: coefficients
/// R1/R2 start from (else each fit starts from the linearised solution).
#[pyfunction]
#[pyo3(signature = (model, obj_hat, img_hat, n_points, repeats = 1000, warm_start = None))]
fn bench_fit_normalized<'py>(
    py: Python<'py>,
    model: &str,
    obj_hat: PyReadonlyArray2<'py, f64>,
    img_hat: PyReadonlyArray2<'py, f64>,
    n_points: usize,
    repeats: usize,
    warm_start: Option<Vec<f64>>,
) -> PyResult<f64> {
    let model = parse_model(model)?;
    let (o, i) = (obj_hat.as_array(), img_hat.as_array());
    check_n2("obj_hat", &o)?;
    check_n2("img_hat", &i)?;
    if n_points == 0 || o.nrows() != i.nrows() || o.nrows() % n_points != 0 {
        return Err(invalid(format!(
                "obj_hat ({}) and img_hat ({}) must hold the same whole number of sets of {n_points} points",
                o.nrows(),
                i.nrows()
            ),
        ));
    }
    let to_vec = |a: &ArrayView2<f64>| -> Vec<[f64; 2]> {
        a.rows().into_iter().map(|r| [r[0], r[1]]).collect()
    };
    let (ov, iv) = (to_vec(&o), to_vec(&i));
    let sets = ov.len() / n_points;
    let res = py.detach(|| -> dewarp_core::error::Result<f64> {
        let mut ws = FitWorkspace::new();
        let warm = warm_start.as_deref();
        // one untimed fit sizes the workspace
        ws.fit_normalized(model, &ov[..n_points], &iv[..n_points], warm)?;
        let n = repeats.max(1);
        let t0 = Instant::now();
        for k in 0..n {
            let s = (k % sets) * n_points;
            let r = ws.fit_normalized(model, &ov[s..s + n_points], &iv[s..s + n_points], warm)?;
            std::hint::black_box(r);
        }
        Ok(t0.elapsed().as_secs_f64() / n as f64)
    });
    res.map_err(|e| PyRspivErr::from(e).into())
}

/// Register the mapping classes and functions.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyMapping>()?;
    m.add_function(wrap_pyfunction!(fit_mapping, m)?)?;
    m.add_function(wrap_pyfunction!(bench_fit_normalized, m)?)?;
    Ok(())
}
