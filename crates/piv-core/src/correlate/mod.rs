//! FFT cross-correlation of one window pair, zero-padded (linear, no wrap-around inside the
//! search range), normalised by the window energies, with peak finding, sub-pixel estimation,
//! peak ratio and correlation coefficient.
//!
//! A window is `w` px wide (along x, columns) and `h` px tall (along y, rows). Both real windows
//! travel through one complex 2D FFT (`a + i b`); the cross-spectrum `conj(A) B` is separated
//! from it by Hermitian symmetry, and one inverse FFT gives the correlation
//! `R(tx, ty) = sum a(x, y) b(x + tx, y + ty) / sqrt(E_a E_b)` (means removed), whose peak is
//! the displacement of B relative to A. `R` is real, so its spectrum is Hermitian: only the
//! columns `kx = 0 ..= pw/2` are formed and inverted along y, and the lag rows the peak search
//! needs are inverted along x two at a time (`r1 + i r2` from the Hermitian extensions of their
//! half spectra), about half the inverse work of a full complex transform. On x86-64 with AVX2
//! the loops around the FFTs run in 8 lanes (same arithmetic, same results). The padded size is
//! the smallest 2^a 3^b 5^c length `>= w + w/2` (and likewise for `h`), which keeps every lag `|t| <= w/2` free of wrap-around.
//! The peak is searched in `|tx| <= w/2 - 1`, `|ty| <= h/2 - 1`.
//!
//! FFT plans are cached per padded shape and shared between threads ([`plans`]); each thread
//! owns a [`Correlator`] (its scratch buffers), so correlating a window allocates nothing.
//!
//! The files: the plane (FFT plans, the correlator's transforms and normalisation) in
//! `plane.rs`, the peak search and sub-pixel estimators in `peak.rs`, the per-vector
//! uncertainty from the correlation statistics in `uncertainty.rs`; the outcome types and
//! the correlator itself here.

use rustfft::num_complex::Complex32;
use std::sync::Arc;

mod peak;
mod plane;
mod uncertainty;

pub use peak::{find_peak, gauss3};
pub use plane::{plans, Plans};

/// Sub-pixel peak estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SubPixel {
    /// Independent 3-point Gaussian fits along x and y (parabolic where a value is <= 0).
    #[default]
    Gauss3,
    /// Least-squares 2D Gaussian over the 3 x 3 neighbourhood (9 points, Nobach & Honkanen
    /// 2005), which also handles elliptic peaks tilted by a shear; falls back to `Gauss3`
    /// where a value is <= 0.
    Gauss2d,
}

/// The outcome of correlating one window pair. Equality is field by field, with the
/// uncertainties compared as values where both are numbers and as equal where both are NaN
/// (not estimated).
#[derive(Debug, Clone, Copy)]
pub struct Peak {
    /// Displacement of B relative to A along x, px (sub-pixel).
    pub dx: f64,
    /// Displacement along y, px.
    pub dy: f64,
    /// Normalised correlation at the integer peak (correlation coefficient, <= 1).
    pub coef: f64,
    /// Highest peak over the second-highest local maximum (>= 1; capped at 1000).
    pub ratio: f64,
    /// `false` when a window was blank (zero variance) or the highest value of the search
    /// region is not a local maximum (the peak lies beyond the search range).
    pub ok: bool,
    /// The second and third highest local maxima of the plane (outside the primary peak's
    /// 3 x 3 neighbourhood and each other's), sub-pixel as the primary: the candidates that
    /// the validation tries when the primary peak fails the median test
    /// ([`crate::multipass`]). [`AltPeak::NONE`] where the plane has fewer maxima.
    pub alt: [AltPeak; 2],
    /// Standard uncertainty (one sigma) of `dx` and `dy`, px, from the correlation statistics
    /// (`uncertainty.rs`, Wieneke 2015); NaN unless asked for ([`Correlator::uncertainty`]) and the
    /// peak is `ok`.
    pub sigma: (f64, f64),
    /// Standard deviation (px) along x and y of the Gaussian through the peak's three values
    /// on each axis (the plane divided by the windows' overlap, as the 3-point fit sees it):
    /// the correlation peak's width, `sqrt(2)` times the particle images' own (a Gaussian
    /// particle image of e^-2 diameter `d`, as recorded, gives `d / (2 sqrt(2))`), broadened
    /// by a displacement that varies across the window. NaN where the three values are not all
    /// positive or not a maximum, and for [`Peak::FAILED`].
    pub width: (f64, f64),
}

/// A secondary correlation peak (see [`Peak::alt`]); equality as [`Peak`]'s.
#[derive(Debug, Clone, Copy)]
pub struct AltPeak {
    /// Displacement along x and y, px (sub-pixel), as [`Peak::dx`], [`Peak::dy`].
    pub dx: f64,
    pub dy: f64,
    /// Normalised correlation at the peak; `-inf` for [`AltPeak::NONE`].
    pub coef: f64,
    /// Standard uncertainty of `dx`, `dy` as [`Peak::sigma`].
    pub sigma: (f64, f64),
}

/// Equal uncertainties: equal numbers, or both NaN (not estimated).
fn same_sigma(a: (f64, f64), b: (f64, f64)) -> bool {
    let eq = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
    eq(a.0, b.0) && eq(a.1, b.1)
}

impl PartialEq for AltPeak {
    fn eq(&self, o: &Self) -> bool {
        self.dx == o.dx && self.dy == o.dy && self.coef == o.coef && same_sigma(self.sigma, o.sigma)
    }
}

impl PartialEq for Peak {
    fn eq(&self, o: &Self) -> bool {
        self.dx == o.dx
            && self.dy == o.dy
            && self.coef == o.coef
            && self.ratio == o.ratio
            && self.ok == o.ok
            && self.alt == o.alt
            && same_sigma(self.sigma, o.sigma)
            && same_sigma(self.width, o.width)
    }
}

impl AltPeak {
    /// No such peak.
    pub const NONE: AltPeak = AltPeak {
        dx: 0.0,
        dy: 0.0,
        coef: f64::NEG_INFINITY,
        sigma: (f64::NAN, f64::NAN),
    };

    /// Is there such a peak?
    pub fn exists(&self) -> bool {
        self.coef.is_finite()
    }
}

impl Peak {
    /// A failed correlation.
    pub const FAILED: Peak = Peak {
        dx: 0.0,
        dy: 0.0,
        coef: 0.0,
        ratio: 0.0,
        ok: false,
        alt: [AltPeak::NONE; 2],
        sigma: (f64::NAN, f64::NAN),
        width: (f64::NAN, f64::NAN),
    };
}

/// Which peaks of a correlation get their uncertainty ([`Correlator::uncertainty`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Uncertainty {
    /// None (the sigmas stay NaN).
    #[default]
    Off,
    /// The highest peak.
    Peak,
    /// The highest peak and the alternatives ([`Peak::alt`]).
    AllPeaks,
}

/// Per-thread correlation engine for one window shape; reuse it for every window.
pub struct Correlator {
    /// Window width (px along x).
    pub w: usize,
    /// Window height (px along y).
    pub h: usize,
    /// Peak search half-ranges.
    sx: usize,
    sy: usize,
    plans: Arc<Plans>,
    buf: Vec<Complex32>,
    buf2: Vec<Complex32>,
    scratch: Vec<Complex32>,
    /// Window of frame A, row-major `h` x `w`; fill it before [`Correlator::correlate`].
    pub wa: Vec<f32>,
    /// Window of frame B.
    pub wb: Vec<f32>,
    corr: Vec<f32>,
    /// Scratch plane of the peak search (`cw * (ch + 1)` values).
    hm: Vec<f32>,
    cw: usize,
    ch: usize,
    /// Per-pixel variance at or below which a window is blank and not correlated (besides the
    /// relative floor of [`Correlator::correlate`]); 0 by default.
    pub min_var: f32,
    /// Which peaks get their uncertainty (see [`Uncertainty`]); off by default.
    pub uncertainty: Uncertainty,
    /// The windows with their means removed (for the uncertainty); scratch of `w * h` values
    /// otherwise (the ensemble keeps frame B's window in `cb`).
    pub(crate) ca: Vec<f32>,
    pub(crate) cb: Vec<f32>,
    /// The weighting window ([`Correlator::set_weighting`]): for anything but the top-hat its
    /// `w * h` pixel weights and the overlap of the weighted windows at the plane's lags (f64
    /// for the uncertainty, f32 for the sub-pixel fit); empty for the top-hat.
    wgt: Vec<f32>,
    ovx: Vec<f64>,
    ovy: Vec<f64>,
    ovx32: Vec<f32>,
    ovy32: Vec<f32>,
}

#[cfg(test)]
mod tests;
