//! Errors of piv-core.

use thiserror::Error;

/// Every failure piv-core reports. Messages are one line and name the problem.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PivError {
    /// Input data that cannot be used (shapes, NaN, windows larger than the image...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
}

pub type Result<T> = std::result::Result<T, PivError>;
