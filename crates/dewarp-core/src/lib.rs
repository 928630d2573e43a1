//! dewarp-core: lens-distortion calibration and correction for planar (2C-2D) PIV.
//!
//! Coordinates: pixel frame with x = column, y = row, origin at the centre of the top-left
//! pixel, y growing downward. "Object px" is the dewarped image's pixel frame.

pub mod error;

pub use error::DewarpError;
