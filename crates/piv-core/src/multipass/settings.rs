//! The settings of a PIV evaluation: passes, how windows follow the predictor, interpolation,
//! validation.

use crate::correlate::SubPixel;
use crate::error::{PivError, Result};

/// How the windows follow the predictor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// Full symmetric image deformation (B-spline interpolation, see [`Interpolation`]).
    #[default]
    Deform,
    /// Symmetric sub-pixel window offset.
    Offset,
}

/// Interpolation of the frames at the fractional positions of deformed or offset windows.
///
/// Interpolating a sub-pixel shift of 2-3 px particles (whose spectrum reaches the Nyquist
/// frequency) shifts them by slightly less or more than asked; the symmetric deformation
/// moves each frame by `d/2`, so the residual measured in the deformed pair carries a bias that
/// is periodic in the fractional part of `d/2` (zero at 0 and 0.5). With 2.5 px particles its
/// amplitude is about 0.018 px for the cubic B-spline, 0.006 px for the quintic one and a few
/// 0.01 px for Keys. Across a field whose displacement varies it shows up as random error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Quintic B-spline on prefiltered coefficients (default, 6 x 6 taps).
    #[default]
    BSpline,
    /// Cubic B-spline on prefiltered coefficients (4 x 4 taps).
    BSpline3,
    /// Keys cubic convolution (a = -0.5, 4 x 4 pixels, no prefilter).
    Keys,
}

/// One pass: window `w` px wide (x) by `h` px tall (y), fractional overlap, iterations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    pub w: usize,
    pub h: usize,
    pub overlap: f64,
    pub iterations: usize,
}

impl Pass {
    /// A pass of `w` x `h` windows (w along x), 50 % overlap, one iteration.
    pub fn new(w: usize, h: usize) -> Pass {
        Pass {
            w,
            h,
            overlap: 0.5,
            iterations: 1,
        }
    }
}

/// Settings of a PIV evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct PivSettings {
    /// Passes from coarse to fine (the grid of the last one is the output grid).
    pub passes: Vec<Pass>,
    pub mode: Mode,
    pub subpixel: SubPixel,
    pub interpolation: Interpolation,
    /// Run the normalised median test (replacement of failed correlations always happens).
    pub validate: bool,
    /// Normalised median test: noise level epsilon (px), 0.1.
    pub median_eps: f64,
    /// Normalised median test: threshold, 2.
    pub median_threshold: f64,
    /// Vectors whose peak ratio is below this are rejected (0 disables the test).
    pub min_peak_ratio: f64,
}

impl Default for PivSettings {
    fn default() -> Self {
        PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 32), Pass::new(32, 8)],
            mode: Mode::Deform,
            subpixel: SubPixel::Gauss3,
            interpolation: Interpolation::BSpline,
            validate: true,
            median_eps: 0.1,
            median_threshold: 2.0,
            min_peak_ratio: 0.0,
        }
    }
}

impl PivSettings {
    pub(crate) fn check(&self) -> Result<()> {
        if self.passes.is_empty() {
            return Err(PivError::InvalidInput("passes is empty".into()));
        }
        for p in &self.passes {
            if p.iterations == 0 {
                return Err(PivError::InvalidInput(format!(
                    "pass {} x {} has 0 iterations",
                    p.w, p.h
                )));
            }
            if p.w < 4 || p.h < 4 {
                return Err(PivError::InvalidInput(format!(
                    "window {} x {} px is too small (at least 4 x 4)",
                    p.w, p.h
                )));
            }
        }
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        if !ok(self.median_eps) || !ok(self.median_threshold) || !ok(self.min_peak_ratio) {
            return Err(PivError::InvalidInput(
                "median_eps, median_threshold and min_peak_ratio must be finite and >= 0".into(),
            ));
        }
        Ok(())
    }
}
