//! Errors of correction-core: the errors of the two cores it runs, and its own input checks.

use thiserror::Error;

/// Every failure correction-core reports. Messages are one line and name the problem.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CorrectionError {
    /// Input that cannot be used (shapes, names of methods or mapping modes).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The calibration side (mapping, remap).
    #[error(transparent)]
    Dewarp(#[from] dewarp_core::DewarpError),
    /// The PIV side.
    #[error(transparent)]
    Piv(#[from] piv_core::PivError),
}

pub type Result<T> = std::result::Result<T, CorrectionError>;
