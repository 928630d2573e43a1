//! Errors of dewarp-core.

use thiserror::Error;

/// Every failure dewarp-core reports. Messages are one line and name the problem.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DewarpError {
    /// Input data that cannot be used (shapes, NaN, too few points, degenerate geometry...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// An iterative method (the inverse map, a fit) did not converge; the message says where.
    #[error("not converged: {0}")]
    NotConverged(String),
    /// Reading or writing a file failed; the message names the file.
    #[error("i/o error: {0}")]
    Io(String),
}

pub type Result<T> = std::result::Result<T, DewarpError>;
