//! Thin PyO3 binding: converts arrays (`PyReadonlyArray2` -> `ArrayView2`, `into_pyarray`
//! back), releases the GIL (`py.detach`) around all work and maps core errors to the Python
//! exceptions of `rspiv.errors`. No algorithm lives here.

use pyo3::prelude::*;

mod calibration;
mod condition;
mod correction;
mod ensemble;
mod errors;
mod frames;
mod mapping;
mod moments;
mod piv;
mod ptv;
mod remap;
mod seeding;
mod vortices;

#[pymodule]
fn _rspiv(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    piv::register(m)?;
    mapping::register(m)?;
    calibration::register(m)?;
    remap::register(m)?;
    correction::register(m)?;
    condition::register(m)?;
    ensemble::register(m)?;
    moments::register(m)?;
    ptv::register(m)?;
    seeding::register(m)?;
    vortices::register(m)?;
    Ok(())
}
