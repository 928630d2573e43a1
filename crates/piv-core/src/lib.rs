//! piv-core: multigrid/multipass FFT cross-correlation PIV.
//!
//! Coordinates: pixel frame with x = column, y = row, origin at the centre of the top-left
//! pixel, y growing downward; displacements (u, v) follow the same axes, in pixels.

pub mod error;

pub use error::PivError;
