//! correction-core: distortion correction of planar PIV, one native path for each method.
//!
//! The calibration's [`Mapping`](dewarp_core::Mapping) maps object px (the dewarped frame) to
//! image px (the raw sensor): `x = F(X)`, its rotation included. Both methods give vectors on the
//! regular object grid of the last pass ([`piv_core::Grid::for_windows`] on the object shape),
//! displacements in object px:
//!
//! - [`method_one`] (Method I): both frames (and the mask) dewarped through `F` (Keys bicubic,
//!   the map on a coarse grid within 1e-3 px, zero outside the sensor), then the regular
//!   multipass PIV of the dewarped pair; object px imaged outside the sensor are masked
//!   ([`ZeroFill::Mask`]) or left to the blank-window rule ([`ZeroFill::Keep`]).
//! - [`method_two`] (Method II): the predictor passes (all but the last) on the raw frames, the
//!   last pass at the images `F(X)` of the object grid points, and each measured image
//!   displacement `d` mapped back: [`DisplacementMapping::Full`] through the exact inverse,
//!   `D = F^-1(x + d/2) - F^-1(x - d/2)`, or [`DisplacementMapping::Positions`] (the paper's
//!   correction, `D = d`).
//!
//! The Python API (`rspiv.correction`) and the standalone engine (`rspiv-engine piv
//! --calibration cal.json --method I|II`) both call these functions, so the two give the same
//! vectors. Coordinates: the pixel frame of the README (x = column, y = row down, origin at the
//! centre of the top-left pixel).

pub mod error;
mod method;
mod method_one;
mod method_two;

pub use error::{CorrectionError, Result};
pub use method::{DisplacementMapping, Method, ZeroFill};
pub use method_one::{dewarp_pair, dewarp_region, method_one, DewarpedPair};
pub use method_two::{map_displacements, map_sigmas, method_two, object_grid, object_grid_ring};
