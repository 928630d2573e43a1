//! The binding's one error type: core errors -> Python exceptions (the polars-python pattern).
//!
//! [`PyRspivErr`] wraps an error of any core (dewarp-core, piv-core, correction-core) or a
//! message of the binding's own argument checks; `From` conversions let call sites write
//! `.map_err(PyRspivErr::from)?` (or `?` where the function returns `Result<_, PyRspivErr>`),
//! and `From<PyRspivErr> for PyErr` picks the exception. The exception classes are defined in
//! Python (`rspiv.errors`) so that one class hierarchy serves Rust and Python alike:
//! `InvalidInputError(RspivError, ValueError)` for bad input, `ConvergenceError(RspivError,
//! ArithmeticError)` for an iteration that did not converge, `OSError` for files. They are
//! looked up once and cached.

use pyo3::exceptions::{PyArithmeticError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static CONVERGENCE: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// An error on its way to Python.
#[derive(Debug)]
pub enum PyRspivErr {
    /// Input that cannot be used (-> `rspiv.InvalidInputError`).
    InvalidInput(String),
    /// An iteration that did not converge (-> `rspiv.ConvergenceError`).
    NotConverged(String),
    /// A file that cannot be read or written (-> `OSError`).
    Io(String),
}

impl From<dewarp_core::DewarpError> for PyRspivErr {
    fn from(e: dewarp_core::DewarpError) -> Self {
        match e {
            dewarp_core::DewarpError::InvalidInput(m) => PyRspivErr::InvalidInput(m),
            dewarp_core::DewarpError::NotConverged(m) => PyRspivErr::NotConverged(m),
            dewarp_core::DewarpError::Io(m) => PyRspivErr::Io(m),
        }
    }
}

impl From<piv_core::PivError> for PyRspivErr {
    fn from(e: piv_core::PivError) -> Self {
        match e {
            piv_core::PivError::InvalidInput(m) => PyRspivErr::InvalidInput(m),
        }
    }
}

impl From<correction_core::CorrectionError> for PyRspivErr {
    fn from(e: correction_core::CorrectionError) -> Self {
        match e {
            correction_core::CorrectionError::InvalidInput(m) => PyRspivErr::InvalidInput(m),
            correction_core::CorrectionError::Dewarp(e) => e.into(),
            correction_core::CorrectionError::Piv(e) => e.into(),
        }
    }
}

fn class<'py>(
    py: Python<'py>,
    cell: &'static PyOnceLock<Py<PyType>>,
    name: &str,
) -> PyResult<Bound<'py, PyType>> {
    let ty = cell.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let cls = py.import("rspiv.errors")?.getattr(name)?;
        Ok(cls.cast_into::<PyType>()?.unbind())
    })?;
    Ok(ty.bind(py).clone())
}

impl From<PyRspivErr> for PyErr {
    fn from(e: PyRspivErr) -> PyErr {
        Python::attach(|py| match e {
            PyRspivErr::InvalidInput(msg) => match class(py, &INVALID_INPUT, "InvalidInputError") {
                Ok(cls) => PyErr::from_type(cls, msg),
                Err(_) => PyValueError::new_err(msg),
            },
            PyRspivErr::NotConverged(msg) => match class(py, &CONVERGENCE, "ConvergenceError") {
                Ok(cls) => PyErr::from_type(cls, msg),
                Err(_) => PyArithmeticError::new_err(msg),
            },
            PyRspivErr::Io(msg) => PyOSError::new_err(msg),
        })
    }
}

/// An `rspiv.InvalidInputError` carrying `msg` (the binding's own argument checks).
pub fn invalid(msg: impl Into<String>) -> PyErr {
    PyRspivErr::InvalidInput(msg.into()).into()
}
