//! Errors of dewarp-core.

use thiserror::Error;

/// Every failure dewarp-core reports. Messages are one line and name the problem.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DewarpError {
    /// Input data that cannot be used (shapes, NaN, too few points, degenerate geometry...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
}

pub type Result<T> = std::result::Result<T, DewarpError>;
