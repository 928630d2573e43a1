//! Multigrid / multipass PIV (Willert & Gharib 1991; Soria 1996) on a regular grid
//! ([`piv`]) and at arbitrary image positions with given predictors ([`piv_at`]).
//!
//! Each pass correlates windows `w` px wide (along x) by `h` px tall (along y). From the second
//! pass on (and on every extra iteration of a pass) the windows follow the predictor, the
//! previous validated field interpolated bilinearly:
//! - [`Mode::Deform`]: symmetric image deformation; frame A is sampled at `p - d(p)/2` and frame
//!   B at `p + d(p)/2` with `d` the predictor at every pixel (quintic B-spline by default,
//!   cubic B-spline or Keys bicubic as options, see [`Interpolation`]). The predictor is first
//!   averaged over the pass's window ([`GridField::window_average`]): the residual a deformed
//!   window measures is the window mean of `true - predictor`, so a predictor that varies
//!   inside the window (noise of the previous pass at the grid spacing) would otherwise stay in
//!   the result and grow with every iteration (Scarano 2002's instability); with the filter a
//!   vector is `mean_W(predictor)` + residual and the iterations converge;
//! - [`Mode::Offset`]: symmetric sub-pixel window offset by the predictor at the window centre.
//!
//! On the regular grid of [`piv`] the deformation is applied to the whole frame pair once per
//! iteration (one interpolation per pixel) and the windows are copied from the deformed pair; at
//! arbitrary points ([`piv_at`]) the first correlation with a field predictor reads the windows
//! from the pair deformed once (a common sub-pixel shift of both windows, see
//! [`Predictor::Field`]); later iterations sample each window on its own.
//!
//! After every iteration the vectors go through the normalised median test (and an optional
//! peak-ratio threshold); rejected ones are replaced from their neighbours. Vectors inside the
//! mask are neither computed nor used as neighbours; they are filled for the predictor only and
//! reported as NaN.
//!
//! Windows that cannot be correlated are never reported `valid` (the same rule in [`piv`] and
//! [`piv_at`], applied by [`signal_fraction`] to every window pair before it is correlated):
//! - a window of either frame with a sample outside the image after its offset and
//!   deformation (a sample position outside `[-0.5, width - 0.5] x [-0.5, height - 0.5]`; on
//!   the regular grid, a deformed-frame pixel whose source lies outside the frame);
//! - a window pair of which more than a quarter ([`MIN_SIGNAL_FRACTION`]) is blank: blocks of
//!   2-4 px constant or of (near) zero variance in either frame, such as the zero fill of a
//!   dewarped frame. A window with less blank area is correlated over its signal part only
//!   (the blank part, and the fill next to it, neutralised in both windows);
//! - a window whose content has (near) zero variance in either frame (see
//!   [`Correlator::correlate`]).
//!
//! Such vectors get `valid = false`, `replaced = true` and a value interpolated from their
//! valid neighbours (used as the predictor of the next pass), `peak_ratio = coef = 0`.

mod field;
mod frames;
mod points;
mod regular;
mod settings;
#[cfg(test)]
mod tests;
mod window;

pub use field::PivField;
pub use frames::BLANK_VARIANCE;
pub use points::{piv_at, piv_with_final_points, Predictor};
pub use regular::piv;
pub use settings::{Interpolation, Mode, Pass, PivSettings};
pub use window::MIN_SIGNAL_FRACTION;
