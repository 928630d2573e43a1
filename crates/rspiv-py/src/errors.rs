#![allow(dead_code)] // helpers used by the feature modules as they land
//! Core errors -> Python exceptions.
//!
//! The exception classes are defined in Python (`rspiv.errors`) so that one class hierarchy
//! serves Rust and Python alike: `InvalidInputError(RspivError, ValueError)` and
//! `ConvergenceError(RspivError, ArithmeticError)`. They are looked up once and cached.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static CONVERGENCE: PyOnceLock<Py<PyType>> = PyOnceLock::new();

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

/// An `rspiv.InvalidInputError` carrying `msg` (a `ValueError` if the class cannot be found).
pub fn invalid_input(py: Python<'_>, msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    match class(py, &INVALID_INPUT, "InvalidInputError") {
        Ok(cls) => PyErr::from_type(cls, msg),
        Err(_) => PyValueError::new_err(msg),
    }
}

/// An `rspiv.ConvergenceError` carrying `msg`.
pub fn convergence(py: Python<'_>, msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    match class(py, &CONVERGENCE, "ConvergenceError") {
        Ok(cls) => PyErr::from_type(cls, msg),
        Err(_) => pyo3::exceptions::PyArithmeticError::new_err(msg),
    }
}

/// Map a dewarp-core error to a Python exception.
pub fn dewarp_err(py: Python<'_>, e: dewarp_core::DewarpError) -> PyErr {
    match e {
        dewarp_core::DewarpError::InvalidInput(msg) => invalid_input(py, msg),
        dewarp_core::DewarpError::NotConverged(msg) => convergence(py, msg),
        dewarp_core::DewarpError::Io(msg) => pyo3::exceptions::PyOSError::new_err(msg),
    }
}

/// Map a piv-core error to a Python exception.
pub fn piv_err(py: Python<'_>, e: piv_core::PivError) -> PyErr {
    match e {
        piv_core::PivError::InvalidInput(msg) => invalid_input(py, msg),
    }
}
