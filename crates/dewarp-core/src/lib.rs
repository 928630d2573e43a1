//! dewarp-core: lens-distortion calibration and correction for planar (2C-2D) PIV.
//!
//! Coordinates: pixel frame with x = column, y = row, origin at the centre of the top-left
//! pixel, y growing downward. "Object px" is the dewarped image's pixel frame.

pub mod error;
pub mod fit;
pub mod grid;
pub mod lm;
pub mod mapping;
pub mod markers;
pub mod models;
pub mod montecarlo;
pub mod remap;
pub mod target;

pub use error::DewarpError;
pub use fit::{fit_mapping, FitOptions, FitWorkspace};
pub use mapping::Mapping;
pub use models::{eval_normalized, Model};
