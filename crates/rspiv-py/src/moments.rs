//! Central sums of orders 3-8 per vector (`piv_core::moments`): the arrays live in NumPy
//! (`rspiv.stats.FieldAccumulator`) and are added to in place with the GIL released.

use crate::errors::{invalid, PyRspivErr};
use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray1};
use pyo3::prelude::*;

/// Add one sample per position to `hm` (`ORDERS` x n, float64, C-contiguous: M_3 .. M_8) in
/// place; `m2`, `n_old` are M_2 and the counts before the sample, `delta` the sample minus the
/// mean before it (0 where no sample is added).
#[pyfunction]
fn moments_add<'py>(
    py: Python<'py>,
    hm: &Bound<'py, PyArray2<f64>>,
    m2: PyReadonlyArray1<'py, f64>,
    n_old: PyReadonlyArray1<'py, i64>,
    delta: PyReadonlyArray1<'py, f64>,
) -> PyResult<()> {
    let mut rw = hm
        .try_readwrite()
        .map_err(|_| invalid("hm is borrowed elsewhere"))?;
    let sums = rw
        .as_slice_mut()
        .map_err(|_| invalid("hm must be a C-contiguous float64 array"))?;
    let (m2, n_old, delta) = (m2.as_slice()?, n_old.as_slice()?, delta.as_slice()?);
    py.detach(|| piv_core::moments::add_sample(sums, m2, n_old, delta))
        .map_err(PyRspivErr::from)?;
    Ok(())
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("MOMENT_ORDERS", piv_core::moments::ORDERS)?;
    m.add_function(wrap_pyfunction!(moments_add, m)?)?;
    Ok(())
}
