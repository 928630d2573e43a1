//! Multigrid / multipass PIV (Willert & Gharib 1991; Soria 1996) on a regular grid
//! ([`piv`]) and at arbitrary image positions with given predictors ([`piv_at`]).
//!
//! Each pass correlates windows `w` px wide (along x) by `h` px tall (along y). From the second
//! pass on (and on every extra iteration of a pass) the windows follow the predictor, the
//! previous validated field interpolated bilinearly:
//! - [`Mode::Deform`]: symmetric image deformation; frame A is sampled at `p - d(p)/2` and frame
//!   B at `p + d(p)/2` with `d` the deformation field at every pixel (quintic B-spline by
//!   default, cubic B-spline or Keys bicubic as options, see [`Interpolation`]). The
//!   deformation field is the latest validated field averaged over the pass's window
//!   ([`crate::image::GridField::window_average`]), which keeps the noise of the previous estimate (at the
//!   grid spacing) out of the deformed particle images. The residual a deformed window pair
//!   measures is the window mean of `true - d` (particles matched by `d`, the rest seen as the
//!   residual), so a vector is reported as the window mean of the deformation field at its
//!   centre ([`crate::image::GridField::window_mean_at`]) plus the residual: `mean_W(d) + mean_W(true - d)
//!   = mean_W(true)` + the correlation's own error, whatever `d` is. Adding the residual to
//!   the point value `d(centre)` instead (the classic predictor-corrector) adds `d(centre) -
//!   mean_W(d)` to every vector, which sharpens the response to curved fields but feeds the
//!   previous estimate's noise back with a gain of up to 1.25 per iteration (Scarano 2002,
//!   Schrijer & Scarano 2008): more iterations then raise the error. Here they converge: the
//!   deformation only reduces the correlation's error (in-window gradients, loss of pairs);
//!   the extra iterations of a pass are under-relaxed ([`RELAXATION`]: each moves the
//!   estimate 0.4 of the way to the new one), which removes the alternation the
//!   particle-weighted residual leaves, so no iteration is less accurate than the one before;
//!   and the spatial response is fixed, that of the top-hat window: a displacement `A sin(2 pi
//!   y / L)` is recovered with the amplitude `A sinc(h / L)` (`sinc(t) = sin(pi t) / (pi t)`;
//!   `w / L` along x): 0.900 at `L = 4 h`, 0.955 at `6 h`, 0.974 at `8 h`, for any number of
//!   passes and iterations (tested against the synthetic sine in `tests.rs`). With a
//!   tapered weighting window ([`PivSettings::weighting`], [`crate::weighting`]) both means
//!   are weighted as the correlation weighs the window's pixels
//!   ([`crate::GridField::weighted_mean_at`]) and the response is the weighting's
//!   ([`crate::weighting::Weighting::response`]);
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
//! [`piv_at`], applied by `window.rs`'s `signal_fraction` to every window pair before it is correlated):
//! - a window of either frame with a sample outside the image after its offset and
//!   deformation (a sample position outside `[-0.5, width - 0.5] x [-0.5, height - 0.5]`; on
//!   the regular grid, a deformed-frame pixel whose source lies outside the frame);
//! - a window pair of which more than a quarter ([`MIN_SIGNAL_FRACTION`]) is blank: blocks of
//!   2-4 px constant or of (near) zero variance in either frame, such as the zero fill of a
//!   dewarped frame. A window with less blank area is correlated over its signal part only
//!   (the blank part, and the fill next to it, neutralised in both windows);
//! - a window whose content has (near) zero variance in either frame (see
//!   [`crate::Correlator::correlate`]).
//!
//! Such vectors get `valid = false`, `replaced = true` and a value interpolated from their
//! valid neighbours (used as the predictor of the next pass), `peak_ratio = coef = 0`.

mod field;
mod frames;
mod points;
mod regular;
mod roi;
mod settings;
#[cfg(test)]
mod tests;
mod window;

pub use field::{ambiguity_variance, PivField, AMBIGUITY_RATE, AMBIGUITY_SCALE, RELAXATION};
pub(crate) use frames::Frames;
pub use frames::BLANK_VARIANCE;
pub use points::{piv_at, piv_with_final_points, Predictor};
pub use regular::{piv, piv_cropped};
pub use roi::{margin as roi_margin, RingGrid, Roi, RINGS as ROI_RINGS};
pub use settings::{Interpolation, Mode, Pass, PivSettings};
pub use window::MIN_SIGNAL_FRACTION;
pub(crate) use window::{check_mask, check_pair, excluded as excluded_point};
