//! Marker detection on a calibration-target image, with a per-marker uncertainty.
//!
//! Pipeline (bright dots on a darker background; pass `dark = true` for dark dots):
//!
//! 1. **Size.** The dot size (standard deviation `s` of a Gaussian blob, px) is taken from the
//!    caller or estimated from the brightest blob of a block-averaged copy (half-maximum radius
//!    / 1.1774).
//! 2. **Coarse detection.** The image is block-averaged by `d = max(1, floor(s / 2.5))` (47 MP
//!    stays memory-light and fast) and cross-correlated, by FFT (rustfft, zero padding against
//!    wrap-around), with a zero-mean template: a Gaussian dot of standard deviation `s / d`, or a
//!    cross of arm length `6 s / d` and arm width `s / d`. A zero-mean template ignores smooth
//!    background and illumination. Peaks are local maxima over a `(2r+1)^2` neighbourhood above
//!    both `threshold` x the strongest peak and `min_snr` x the robust (MAD) noise of the
//!    correlation.
//! 3. **Sub-pixel fit.** Around each peak, at full resolution in a window of half-width
//!    `ceil(2.5 s)`, the model `b0 + bx xw + by yw + A exp(-((x-x0)^2 + (y-y0)^2) / (2 w^2))`
//!    (7 parameters, a plane for the uneven illumination) is fitted to the pixel values by
//!    the project's Levenberg-Marquardt ([`crate::lm`], MINPACK stopping rules) on normal
//!    equations accumulated pixel by pixel (7 x 7, no per-pixel storage). The covariance
//!    of (x0, y0) is the heteroscedasticity-consistent sandwich estimate
//!    `(J^T J)^-1 (sum r_k^2 J_k^T J_k) (J^T J)^-1 * n / (n - 7)`, valid under shot noise whose
//!    variance grows with the signal. For crosses (arms longer than the window) the blob term is
//!    the brighter of two perpendicular Gaussian bars, `A max(exp(-dx^2/2w^2), exp(-dy^2/2w^2))`;
//!    `size_px` is then the bar's Gaussian sigma.
//!    Fits that diverge (centre moving more than `s`, width outside `[0.3 s, 3 s]`, amplitude of
//!    the wrong sign) are dropped; duplicates closer than `s` are merged.

use crate::error::{DewarpError, Result};
use crate::lm::{LeastSquaresProblem, LmConfig, LmSolver};
use image_core::fast_len;
pub use image_core::Pixel;
use nalgebra::SMatrix;
use ndarray::{Array2, ArrayView2, Axis};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// The shape of the markers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkerKind {
    /// Round dots.
    Dot,
    /// Crosses (+).
    Cross,
}

impl std::str::FromStr for MarkerKind {
    type Err = DewarpError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "dot" => Ok(Self::Dot),
            "cross" => Ok(Self::Cross),
            _ => Err(DewarpError::InvalidInput(format!(
                "marker kind {s:?} is not one of \"dot\", \"cross\""
            ))),
        }
    }
}

/// Options of [`detect_markers`].
#[derive(Debug, Clone, PartialEq)]
pub struct DetectOptions {
    /// Marker shape.
    pub kind: MarkerKind,
    /// Dot size as a Gaussian standard deviation in px; `None` estimates it.
    pub size_px: Option<f64>,
    /// Keep correlation peaks above this fraction of the strongest peak.
    pub threshold: f64,
    /// Keep correlation peaks above this multiple of the correlation's robust noise.
    pub min_snr: f64,
    /// Markers darker than the background.
    pub dark: bool,
}

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            kind: MarkerKind::Dot,
            size_px: None,
            threshold: 0.25,
            min_snr: 8.0,
            dark: false,
        }
    }
}

/// One detected marker (image px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    pub x: f64,
    pub y: f64,
    /// Standard uncertainty of x and y (px) and their covariance (px^2).
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub cov_xy: f64,
    /// Fitted blob amplitude (counts) and width (px).
    pub amplitude: f64,
    pub width: f64,
    /// Normalised correlation strength of the coarse peak.
    pub strength: f64,
}

/// Result of [`detect_markers`].
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub markers: Vec<Marker>,
    /// Dot size used (Gaussian sigma, px).
    pub size_px: f64,
    /// Block-averaging factor of the coarse detection.
    pub downsample: usize,
}

fn block_mean<T: Pixel>(img: ArrayView2<T>, d: usize, sign: f64) -> Array2<f64> {
    let (h, w) = img.dim();
    let (hc, wc) = (h / d, w / d);
    let mut out = Array2::<f64>::zeros((hc, wc));
    let inv = sign / (d * d) as f64;
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(yc, mut row)| {
            for dy in 0..d {
                let src = img.row(yc * d + dy);
                for xc in 0..wc {
                    let mut s = 0.0;
                    for dx in 0..d {
                        s += src[xc * d + dx].to_f64();
                    }
                    row[xc] += s * inv;
                }
            }
        });
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    median_mut(&mut v)
}

/// Median of a slice (reordered in place); 0 if empty.
fn median_mut(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    v[k]
}

/// Median and MAD-based standard deviation of (a subsample of) an array.
fn robust_stats(a: &Array2<f64>) -> (f64, f64) {
    let n = a.len();
    let step = (n / 200_000).max(1);
    let sample: Vec<f64> = a.iter().step_by(step).copied().collect();
    let med = median(sample.clone());
    let mad = median(sample.iter().map(|v| (v - med).abs()).collect());
    (med, 1.4826 * mad)
}

/// Estimate the dot size (Gaussian sigma, full-resolution px) from the brightest blob.
fn estimate_size<T: Pixel>(img: ArrayView2<T>, sign: f64) -> Result<f64> {
    let (h, w) = img.dim();
    let d0 = (h.max(w) / 1024).max(1);
    let raw = block_mean(img, d0, sign);
    let (hc, wc) = raw.dim();
    // 3x3 box smoothing against single hot pixels.
    let mut sm = Array2::<f64>::zeros((hc, wc));
    for y in 0..hc {
        for x in 0..wc {
            let (mut s, mut c) = (0.0, 0.0);
            for yy in y.saturating_sub(1)..(y + 2).min(hc) {
                for xx in x.saturating_sub(1)..(x + 2).min(wc) {
                    s += raw[[yy, xx]];
                    c += 1.0;
                }
            }
            sm[[y, x]] = s / c;
        }
    }
    let (bg, noise) = robust_stats(&sm);
    let (mut by, mut bx, mut bv) = (0, 0, f64::NEG_INFINITY);
    for ((y, x), v) in sm.indexed_iter() {
        if *v > bv {
            bv = *v;
            by = y;
            bx = x;
        }
    }
    if bv.is_nan() || bv - bg <= 10.0 * noise.max(1e-9) {
        return Err(DewarpError::InvalidInput(
            "marker detection: the image has no bright blobs above its noise (blank image?)".into(),
        ));
    }
    let half = bg + 0.5 * (bv - bg);
    let mut radii = Vec::with_capacity(4);
    for (ddx, ddy) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
        let (mut x, mut y, mut prev) = (bx as i64, by as i64, bv);
        let mut steps = 0.0;
        loop {
            let (nx, ny) = (x + ddx, y + ddy);
            if nx < 0 || ny < 0 || nx >= wc as i64 || ny >= hc as i64 {
                break;
            }
            let v = sm[[ny as usize, nx as usize]];
            if v < half {
                steps += (prev - half) / (prev - v).max(1e-12);
                radii.push(steps);
                break;
            }
            prev = v;
            steps += 1.0;
            x = nx;
            y = ny;
        }
    }
    if radii.is_empty() {
        return Err(DewarpError::InvalidInput(
            "marker detection: cannot estimate the marker size (no blob edge found)".into(),
        ));
    }
    // The 3x3 smoothing and block averaging widen the blob a little: subtract in quadrature.
    let r = radii.iter().sum::<f64>() / radii.len() as f64;
    let s_coarse = (r / 1.1774).powi(2) - 2.0 / 3.0 - 1.0 / 12.0;
    Ok((s_coarse.max(0.25).sqrt() * d0 as f64).max(1.0))
}

/// In-place 2D FFT of a row-major (h, w) complex buffer.
fn fft2(
    buf: &mut [Complex<f64>],
    h: usize,
    w: usize,
    inverse: bool,
    planner: &mut FftPlanner<f64>,
) {
    let row_fft = if inverse {
        planner.plan_fft_inverse(w)
    } else {
        planner.plan_fft_forward(w)
    };
    let col_fft = if inverse {
        planner.plan_fft_inverse(h)
    } else {
        planner.plan_fft_forward(h)
    };
    buf.par_chunks_mut(w).for_each(|row| row_fft.process(row));
    let mut t = vec![Complex::new(0.0, 0.0); h * w];
    t.par_chunks_mut(h).enumerate().for_each(|(x, col)| {
        for y in 0..h {
            col[y] = buf[y * w + x];
        }
        col_fft.process(col);
    });
    buf.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            row[x] = t[x * h + y];
        }
    });
}

/// Cross-correlate `img` with a zero-mean `tpl` (odd sizes, centred); output has `img`'s shape.
fn correlate(img: &Array2<f64>, tpl: &Array2<f64>) -> Array2<f64> {
    let (h, w) = img.dim();
    let (th, tw) = tpl.dim();
    let (ph, pw) = (fast_len(h + th - 1), fast_len(w + tw - 1));
    let mean = img.mean().unwrap_or(0.0);
    let mut a = vec![Complex::new(0.0, 0.0); ph * pw];
    for ((y, x), v) in img.indexed_iter() {
        a[y * pw + x] = Complex::new(v - mean, 0.0);
    }
    let mut b = vec![Complex::new(0.0, 0.0); ph * pw];
    // Template placed so that out[y, x] = sum_{u, v} img[y + u - cy, x + v - cx] tpl[u, v].
    let (cy, cx) = (th / 2, tw / 2);
    for ((u, v), t) in tpl.indexed_iter() {
        let yy = (u as isize - cy as isize).rem_euclid(ph as isize) as usize;
        let xx = (v as isize - cx as isize).rem_euclid(pw as isize) as usize;
        b[yy * pw + xx] = Complex::new(*t, 0.0);
    }
    let mut planner = FftPlanner::new();
    fft2(&mut a, ph, pw, false, &mut planner);
    fft2(&mut b, ph, pw, false, &mut planner);
    a.par_iter_mut()
        .zip(b.par_iter())
        .for_each(|(p, q)| *p *= q.conj());
    fft2(&mut a, ph, pw, true, &mut planner);
    let norm = 1.0 / (ph * pw) as f64;
    let mut out = Array2::<f64>::zeros((h, w));
    for ((y, x), o) in out.indexed_iter_mut() {
        *o = a[y * pw + x].re * norm;
    }
    out
}

fn template(kind: MarkerKind, s: f64) -> Array2<f64> {
    let half = (3.0 * s).ceil().max(2.0) as usize;
    let n = 2 * half + 1;
    let mut t = Array2::<f64>::zeros((n, n));
    for ((y, x), v) in t.indexed_iter_mut() {
        let (dx, dy) = (x as f64 - half as f64, y as f64 - half as f64);
        *v = match kind {
            MarkerKind::Dot => (-(dx * dx + dy * dy) / (2.0 * s * s)).exp(),
            MarkerKind::Cross => {
                let arm = |a: f64, b: f64| {
                    (-(a * a) / (2.0 * s * s)).exp() * f64::from(b.abs() <= 3.0 * s)
                };
                arm(dx, dy).max(arm(dy, dx))
            }
        };
    }
    let m = t.mean().unwrap_or(0.0);
    t.mapv_inplace(|v| v - m);
    let nrm = t.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    t.mapv_inplace(|v| v / nrm);
    t
}

struct FitOut {
    p: [f64; 7],
    cov: [[f64; 2]; 2],
}

/// The 7-parameter blob model over one window of pixels, as a least-squares problem for the
/// project's LM ([`crate::lm`]). Parameters `p = [A, x0, y0, w, b0, bx, by]`; model
/// `b0 + bx xw + by yw + A g(x, y)` with `xw = (x - xc) / sc`, `yw = (y - yc) / sc` (the plane
/// in window-normalised coordinates) and `g = exp(-(dx^2 + dy^2) / 2w^2)` for a dot or
/// `max(exp(-dx^2 / 2w^2), exp(-dy^2 / 2w^2))` for a cross. Residuals `model - sign * pixel`,
/// row-major over the window `[ya, yb] x [xa, xb]` (inclusive).
struct GaussBlobProblem<'a, T: Pixel> {
    img: ArrayView2<'a, T>,
    xa: usize,
    xb: usize,
    ya: usize,
    yb: usize,
    xc: f64,
    yc: f64,
    sc: f64,
    sign: f64,
    cross: bool,
}

impl<T: Pixel> GaussBlobProblem<'_, T> {
    /// Calls `f(k, r_k, J_k)` for every pixel `k` of the window, with the residual and, if
    /// `want_jac`, its gradient `dr_k/dp` (zeros otherwise).
    #[inline(always)]
    fn for_each_pixel(&self, p: &[f64], want_jac: bool, mut f: impl FnMut(usize, f64, &[f64; 7])) {
        let inv2 = 1.0 / (p[3] * p[3]);
        let mut j = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        let mut k = 0;
        for y in self.ya..=self.yb {
            let dy = y as f64 - p[2];
            let ey = (-0.5 * dy * dy * inv2).exp();
            let yw = (y as f64 - self.yc) / self.sc;
            for x in self.xa..=self.xb {
                let dx = x as f64 - p[1];
                let ex = (-0.5 * dx * dx * inv2).exp();
                // Dot: g = ex ey. Cross (inside its arms): the brighter of the two bars,
                // g = max(ex, ey); (gx, gy) select the centre derivatives.
                let (g, gx, gy) = if !self.cross {
                    (ex * ey, 1.0, 1.0)
                } else if ex >= ey {
                    (ex, 1.0, 0.0)
                } else {
                    (ey, 0.0, 1.0)
                };
                let xw = (x as f64 - self.xc) / self.sc;
                let m = p[4] + p[5] * xw + p[6] * yw + p[0] * g;
                let r = m - self.sign * self.img[[y, x]].to_f64();
                if want_jac {
                    let ag = p[0] * g * inv2;
                    j[0] = g;
                    j[1] = ag * dx * gx;
                    j[2] = ag * dy * gy;
                    j[3] = ag * (dx * dx * gx + dy * dy * gy) / p[3];
                    j[5] = xw;
                    j[6] = yw;
                }
                f(k, r, &j);
                k += 1;
            }
        }
    }

    /// `J^T J` and the sandwich's meat `sum r_k^2 J_k^T J_k` at `p` (lower triangles filled).
    fn jtj_and_meat(&self, p: &[f64]) -> (SMatrix<f64, 7, 7>, SMatrix<f64, 7, 7>) {
        let mut jtj = SMatrix::<f64, 7, 7>::zeros();
        let mut meat = SMatrix::<f64, 7, 7>::zeros();
        self.for_each_pixel(p, true, |_, r, j| {
            let r2 = r * r;
            for a in 0..7 {
                for b in 0..=a {
                    let jj = j[a] * j[b];
                    jtj[(a, b)] += jj;
                    meat[(a, b)] += r2 * jj;
                }
            }
        });
        for a in 0..7 {
            for b in 0..a {
                jtj[(b, a)] = jtj[(a, b)];
                meat[(b, a)] = meat[(a, b)];
            }
        }
        (jtj, meat)
    }
}

impl<T: Pixel> LeastSquaresProblem for GaussBlobProblem<'_, T> {
    fn n_params(&self) -> usize {
        7
    }

    fn n_residuals(&self) -> usize {
        (self.xb - self.xa + 1) * (self.yb - self.ya + 1)
    }

    fn residuals(&self, p: &[f64], r: &mut [f64]) {
        self.for_each_pixel(p, false, |k, rk, _| r[k] = rk);
    }

    fn jacobian(&self, p: &[f64], jac: &mut [f64]) {
        self.for_each_pixel(p, true, |k, _, j| jac[7 * k..7 * k + 7].copy_from_slice(j));
    }

    /// Accumulates `J^T J` and `J^T r` pixel by pixel: `J` is never stored.
    fn normal_equations(
        &self,
        p: &[f64],
        _r: &[f64],
        _jac_scratch: &mut [f64],
        jtj: &mut [f64],
        jtr: &mut [f64],
    ) {
        let mut a_ = [0.0; 49];
        let mut g = [0.0; 7];
        self.for_each_pixel(p, true, |_, r, j| {
            for a in 0..7 {
                g[a] += j[a] * r;
                for b in 0..=a {
                    a_[a * 7 + b] += j[a] * j[b];
                }
            }
        });
        for a in 0..7 {
            for b in 0..a {
                a_[b * 7 + a] = a_[a * 7 + b];
            }
        }
        jtj[..49].copy_from_slice(&a_);
        jtr[..7].copy_from_slice(&g);
    }
}

/// Tolerances of the blob fit: MINPACK's defaults tightened so that the centre is converged
/// far below its noise (~0.01 px) whatever its absolute image coordinate.
fn blob_lm_config() -> LmConfig {
    LmConfig {
        ftol: 1e-10,
        xtol: 1e-10,
        ..LmConfig::default()
    }
}

/// Fit the 7-parameter Gaussian + plane model in a window with the project's LM (`solver` and
/// `border` are per-worker scratch); `None` if the fit fails or is implausible.
#[allow(clippy::too_many_arguments)]
fn fit_blob<T: Pixel>(
    img: ArrayView2<T>,
    x0: f64,
    y0: f64,
    s: f64,
    sign: f64,
    cross: bool,
    solver: &mut LmSolver,
    border: &mut Vec<f64>,
) -> Option<FitOut> {
    let (h, w) = img.dim();
    let hw = (2.5 * s).ceil().max(3.0) as i64;
    let (cx, cy) = (x0.round() as i64, y0.round() as i64);
    let (xa, xb) = (
        (cx - hw).max(0) as usize,
        ((cx + hw).min(w as i64 - 1)) as usize,
    );
    let (ya, yb) = (
        (cy - hw).max(0) as usize,
        ((cy + hw).min(h as i64 - 1)) as usize,
    );
    if xb < xa + 4 || yb < ya + 4 {
        return None;
    }
    let problem = GaussBlobProblem {
        img,
        xa,
        xb,
        ya,
        yb,
        xc: cx as f64,
        yc: cy as f64,
        sc: hw as f64,
        sign,
        cross,
    };
    let n = problem.n_residuals();
    // Initial guess: background from the median of the window's border, amplitude from the
    // pixel at the peak.
    border.clear();
    for y in ya..=yb {
        for x in [xa, xb] {
            border.push(sign * img[[y, x]].to_f64());
        }
    }
    for x in xa..=xb {
        for y in [ya, yb] {
            border.push(sign * img[[y, x]].to_f64());
        }
    }
    let b0 = median_mut(border);
    let pk = sign
        * img[[
            (cy.clamp(0, h as i64 - 1)) as usize,
            (cx.clamp(0, w as i64 - 1)) as usize,
        ]]
        .to_f64();
    let mut p = [pk - b0, x0, y0, s, b0, 0.0, 0.0];
    if p[0].is_nan() || p[0] <= 0.0 {
        return None;
    }
    let summary = solver
        .solve_in_place(&problem, &mut p, &blob_lm_config())
        .ok()?;
    // The model is even in the width: report it positive.
    p[3] = p[3].abs();
    let plausible = summary.termination.converged()
        && p.iter().all(|v| v.is_finite())
        && p[0] > 0.0
        && p[3] > 0.3 * s
        && p[3] < 3.0 * s
        && (p[1] - x0).hypot(p[2] - y0) <= s.max(2.0)
        && p[1] >= 0.0
        && p[2] >= 0.0
        && p[1] <= (w - 1) as f64
        && p[2] <= (h - 1) as f64;
    if !plausible {
        return None;
    }
    // Sandwich covariance (heteroscedasticity-consistent), with the small-sample factor.
    let (jtj, meat) = problem.jtj_and_meat(&p);
    let inv = jtj.try_inverse()?;
    let cov = inv * meat * inv * (n as f64 / (n as f64 - 7.0).max(1.0));
    let c = [[cov[(1, 1)], cov[(1, 2)]], [cov[(2, 1)], cov[(2, 2)]]];
    if !(c[0][0] > 0.0 && c[1][1] > 0.0) {
        return None;
    }
    Some(FitOut { p, cov: c })
}

/// Detect the markers of a calibration-target image; see the module documentation.
pub fn detect_markers<T: Pixel>(image: ArrayView2<T>, opts: &DetectOptions) -> Result<Detection> {
    let (h, w) = image.dim();
    if h < 16 || w < 16 {
        return Err(DewarpError::InvalidInput(format!(
            "marker detection: image of {h} x {w} px is too small"
        )));
    }
    let valid = opts.threshold > 0.0 && opts.threshold < 1.0 && opts.min_snr > 0.0;
    if !valid {
        return Err(DewarpError::InvalidInput(
            "marker detection: threshold must lie in (0, 1) and min_snr be > 0".into(),
        ));
    }
    if image.iter().any(|v| !v.to_f64().is_finite()) {
        return Err(DewarpError::InvalidInput(
            "marker detection: image contains NaN or inf".into(),
        ));
    }
    let sign = if opts.dark { -1.0 } else { 1.0 };
    let s = match opts.size_px {
        Some(s) if s.is_finite() && s > 0.0 => s,
        Some(s) => {
            return Err(DewarpError::InvalidInput(format!(
                "marker detection: marker size {s} px must be > 0"
            )))
        }
        None => estimate_size(image, sign)?,
    };
    if s * 6.0 > h.min(w) as f64 {
        return Err(DewarpError::InvalidInput(format!(
            "marker detection: marker size {s:.1} px is too large for a {h} x {w} image"
        )));
    }
    let d = ((s / 2.5).floor() as usize).max(1);
    let coarse = block_mean(image, d, sign);
    let sc = s / d as f64;
    let tpl = template(opts.kind, sc);
    let corr = correlate(&coarse, &tpl);
    let (_, noise) = robust_stats(&corr);
    let (hc, wc) = corr.dim();
    let r = ((1.5 * sc).round() as usize).max(1);
    let cmax = corr.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let thr = (opts.threshold * cmax).max(opts.min_snr * noise.max(1e-300));
    if cmax.is_nan() || cmax <= thr {
        return Err(DewarpError::InvalidInput(
            "marker detection: no marker-like peaks found (blank image or wrong marker kind)"
                .into(),
        ));
    }
    let peaks: Vec<(usize, usize, f64)> = (0..hc)
        .into_par_iter()
        .flat_map_iter(|y| {
            let corr = &corr;
            (0..wc).filter_map(move |x| {
                let v = corr[[y, x]];
                if v < thr {
                    return None;
                }
                for yy in y.saturating_sub(r)..(y + r + 1).min(hc) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(wc) {
                        let u = corr[[yy, xx]];
                        if u > v || (u == v && (yy, xx) < (y, x)) {
                            return None;
                        }
                    }
                }
                Some((y, x, v))
            })
        })
        .collect();
    let off = 0.5 * (d as f64 - 1.0);
    let sub = |a: f64, b: f64, c: f64| {
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    // One LM solver and one border buffer per rayon job: no allocation per marker once sized.
    let mut markers: Vec<Marker> = peaks
        .par_iter()
        .map_init(
            || (LmSolver::new(), Vec::new()),
            |(solver, border), &(y, x, v)| {
                let fx = if x > 0 && x + 1 < wc {
                    sub(corr[[y, x - 1]], v, corr[[y, x + 1]])
                } else {
                    0.0
                };
                let fy = if y > 0 && y + 1 < hc {
                    sub(corr[[y - 1, x]], v, corr[[y + 1, x]])
                } else {
                    0.0
                };
                let x0 = (x as f64 + fx) * d as f64 + off;
                let y0 = (y as f64 + fy) * d as f64 + off;
                let cross = opts.kind == MarkerKind::Cross;
                let f = fit_blob(image, x0, y0, s, sign, cross, solver, border)?;
                Some(Marker {
                    x: f.p[1],
                    y: f.p[2],
                    sigma_x: f.cov[0][0].sqrt(),
                    sigma_y: f.cov[1][1].sqrt(),
                    cov_xy: f.cov[0][1],
                    amplitude: sign * f.p[0],
                    width: f.p[3],
                    strength: v / cmax,
                })
            },
        )
        .flatten()
        .collect();
    // Merge duplicates (two peaks converging on one blob): keep the stronger.
    markers.sort_by(|a, b| b.strength.total_cmp(&a.strength));
    let mut kept: Vec<Marker> = Vec::with_capacity(markers.len());
    for m in markers {
        if kept.iter().all(|k| (k.x - m.x).hypot(k.y - m.y) > s) {
            kept.push(m);
        }
    }
    if kept.is_empty() {
        return Err(DewarpError::InvalidInput(
            "marker detection: no marker survived the sub-pixel fit".into(),
        ));
    }
    kept.sort_by(|a, b| a.y.total_cmp(&b.y).then(a.x.total_cmp(&b.x)));
    Ok(Detection {
        markers: kept,
        size_px: s,
        downsample: d,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::target::{render_target, TargetScene};
    use ndarray::Array1;

    fn scene_img(pts: &[(f64, f64)], s: f64, h: usize, w: usize, seed: u64) -> Array2<u16> {
        let c = Array2::from_shape_fn(
            (pts.len(), 2),
            |(k, j)| if j == 0 { pts[k].0 } else { pts[k].1 },
        );
        let sig = Array1::from_elem(pts.len(), s);
        let amp = Array1::from_elem(pts.len(), 2500.0);
        // No illumination gradient: it shifts a blob's apparent centre by g s^2 (a real effect,
        // exaggerated on this tiny image), and this test checks the fit against the noise.
        let scene = TargetScene {
            seed,
            gradient: (0.0, 0.0),
            vignetting: 0.0,
            ..Default::default()
        };
        render_target(h, w, c.view(), sig.view(), amp.view(), &scene).unwrap()
    }

    #[test]
    fn finds_dots_with_subpixel_accuracy_and_honest_sigma() {
        let mut pts = Vec::new();
        for j in 0..4 {
            for i in 0..5 {
                pts.push((
                    30.0 + 45.0 * i as f64 + 0.37 * j as f64,
                    25.0 + 40.0 * j as f64 + 0.21 * i as f64,
                ));
            }
        }
        let mut err2 = 0.0;
        let mut sig2 = 0.0;
        let mut n = 0.0;
        for seed in 0..3 {
            let img = scene_img(&pts, 4.0, 180, 250, seed);
            let det = detect_markers(img.view(), &DetectOptions::default()).unwrap();
            assert_eq!(det.markers.len(), pts.len());
            assert!((det.size_px - 4.0).abs() < 1.0, "size {}", det.size_px);
            for p in &pts {
                let m = det.markers.iter().min_by(|a, b| {
                    (a.x - p.0)
                        .hypot(a.y - p.1)
                        .total_cmp(&(b.x - p.0).hypot(b.y - p.1))
                });
                let m = m.unwrap();
                err2 += (m.x - p.0).powi(2) + (m.y - p.1).powi(2);
                sig2 += m.sigma_x.powi(2) + m.sigma_y.powi(2);
                n += 1.0;
            }
        }
        let (rms, sig) = ((err2 / n).sqrt(), (sig2 / n).sqrt());
        assert!(rms < 0.05, "rms {rms}");
        assert!(
            sig / rms < 1.5 && rms / sig < 1.5,
            "sigma {sig} vs error {rms}"
        );
    }

    #[test]
    fn finds_crosses() {
        // Crosses: two perpendicular bars of Gaussian profile (sigma 2 px), arms 12 px long.
        let pts = [(30.3, 28.6), (80.7, 29.1), (31.2, 78.4), (81.5, 79.8)];
        let img = Array2::from_shape_fn((110, 115), |(y, x)| {
            let mut v = 100.0;
            for &(cx, cy) in &pts {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                let bar = |a: f64, b: f64| {
                    (-(a * a) / 8.0).exp() * (1.0 / (1.0 + (-(12.0 - b.abs()) * 2.0).exp()))
                };
                v += 1500.0 * bar(dx, dy).max(bar(dy, dx));
            }
            v
        });
        let o = DetectOptions {
            kind: MarkerKind::Cross,
            size_px: Some(2.0),
            ..Default::default()
        };
        let det = detect_markers(img.view(), &o).unwrap();
        assert_eq!(det.markers.len(), 4);
        for (m, p) in det.markers.iter().zip(pts.iter()) {
            assert!(
                (m.x - p.0).abs() < 0.05 && (m.y - p.1).abs() < 0.05,
                "{m:?} vs {p:?}"
            );
        }
    }

    #[test]
    fn blob_jacobian_and_normal_equations_match_central_differences() {
        // A blob on a tilted background with a deterministic texture, fitted from a point away
        // from the optimum (both model variants).
        let img = Array2::from_shape_fn((23, 25), |(y, x)| {
            let (dx, dy) = (x as f64 - 12.3, y as f64 - 10.8);
            300.0
                + 4.0 * x as f64
                + 1500.0 * (-(dx * dx + dy * dy) / 18.0).exp()
                + ((x * 7 + y * 13) % 11) as f64
        });
        for cross in [false, true] {
            let pb = GaussBlobProblem {
                img: img.view(),
                xa: 2,
                xb: 22,
                ya: 1,
                yb: 20,
                xc: 12.0,
                yc: 11.0,
                sc: 10.0,
                sign: 1.0,
                cross,
            };
            let (m, n) = (pb.n_residuals(), pb.n_params());
            assert_eq!(m, 21 * 20);
            let p = [1400.0, 12.37, 10.61, 3.2, 310.0, 35.0, -4.0];
            let mut jac = vec![0.0; m * n];
            pb.jacobian(&p, &mut jac);
            let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
            for c in 0..n {
                let hstep = 1e-5 * p[c].abs().max(1.0);
                let (mut pp, mut pm) = (p, p);
                pp[c] += hstep;
                pm[c] -= hstep;
                pb.residuals(&pp, &mut rp);
                pb.residuals(&pm, &mut rm);
                let scale = (0..m).map(|i| jac[i * n + c].abs()).fold(0.0, f64::max);
                assert!(scale > 0.0);
                for i in 0..m {
                    let num = (rp[i] - rm[i]) / (2.0 * hstep);
                    let err = (num - jac[i * n + c]).abs();
                    assert!(
                        err <= 1e-6 * scale,
                        "cross {cross} param {c} pixel {i}: {num} vs {}",
                        jac[i * n + c]
                    );
                }
            }
            // The pixel-by-pixel normal equations equal J^T J and J^T r from the dense J.
            let mut r = vec![0.0; m];
            pb.residuals(&p, &mut r);
            let (mut jtj, mut jtr) = ([0.0; 49], [0.0; 7]);
            pb.normal_equations(&p, &r, &mut [], &mut jtj, &mut jtr);
            for a in 0..n {
                let g: f64 = (0..m).map(|i| jac[i * n + a] * r[i]).sum();
                assert!((g - jtr[a]).abs() <= 1e-9 * g.abs().max(1.0), "jtr {a}");
                for b in 0..n {
                    let v: f64 = (0..m).map(|i| jac[i * n + a] * jac[i * n + b]).sum();
                    assert!(
                        (v - jtj[a * n + b]).abs() <= 1e-9 * v.abs().max(1.0),
                        "jtj {a} {b}"
                    );
                }
            }
            // The sandwich's bread and meat are full symmetric matrices (both triangles).
            let (bread, meat) = pb.jtj_and_meat(&p);
            for a in 0..n {
                for b in 0..n {
                    let v: f64 = (0..m).map(|i| jac[i * n + a] * jac[i * n + b]).sum();
                    let w: f64 = (0..m)
                        .map(|i| r[i] * r[i] * jac[i * n + a] * jac[i * n + b])
                        .sum();
                    assert!(
                        (v - bread[(a, b)]).abs() <= 1e-9 * v.abs().max(1.0),
                        "bread {a} {b}"
                    );
                    assert!(
                        (w - meat[(a, b)]).abs() <= 1e-9 * w.abs().max(1.0),
                        "meat {a} {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn blank_and_bad_inputs_are_errors() {
        let img = scene_img(&[], 3.0, 64, 64, 0);
        assert!(detect_markers(img.view(), &DetectOptions::default()).is_err());
        let o = DetectOptions {
            size_px: Some(-1.0),
            ..Default::default()
        };
        let img = scene_img(&[(30.0, 30.0)], 3.0, 64, 64, 0);
        assert!(detect_markers(img.view(), &o).is_err());
        let tiny = Array2::<f64>::zeros((4, 4));
        assert!(detect_markers(tiny.view(), &DetectOptions::default()).is_err());
    }

    #[test]
    fn fft_correlation_matches_direct_sum() {
        let img = Array2::from_shape_fn((9, 11), |(y, x)| ((y * 7 + x * 3) % 5) as f64);
        let tpl = template(MarkerKind::Dot, 1.0);
        let c = correlate(&img, &tpl);
        let mean = img.mean().unwrap();
        let (th, tw) = tpl.dim();
        for y in 0..9 {
            for x in 0..11 {
                let mut s = 0.0;
                for u in 0..th {
                    for v in 0..tw {
                        let (yy, xx) = (
                            y as isize + u as isize - (th / 2) as isize,
                            x as isize + v as isize - (tw / 2) as isize,
                        );
                        if yy >= 0 && xx >= 0 && yy < 9 && xx < 11 {
                            s += (img[[yy as usize, xx as usize]] - mean) * tpl[[u, v]];
                        }
                    }
                }
                assert!((s - c[[y, x]]).abs() < 1e-9);
            }
        }
    }
}
