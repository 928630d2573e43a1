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

use crate::correlate::{Correlator, Peak, SubPixel};
use crate::error::{PivError, Result};
use crate::grid::Grid;
use crate::image::{
    bspline5_coeffs, bspline5_weights, bspline_coeffs, bspline_weights, deform_pair, keys_weights,
    sample_pair, GridField, Img, Pixel, Source, WindowSpec,
};
use crate::validate::{median_test, replace};
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

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
    fn check(&self) -> Result<()> {
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

/// A vector field. All arrays have the same shape (ny, nx).
#[derive(Debug, Clone)]
pub struct PivField {
    /// The regular grid of the vectors (`None` for [`piv_at`]).
    pub grid: Option<Grid>,
    /// Window centres, px (pixel frame).
    pub x: Array2<f64>,
    pub y: Array2<f64>,
    /// Displacement along x (right) and y (down), px; NaN where `masked`.
    pub u: Array2<f64>,
    pub v: Array2<f64>,
    /// Peak ratio of the last correlation (0 where not computed).
    pub peak_ratio: Array2<f64>,
    /// Correlation coefficient (normalised peak height) of the last correlation.
    pub coef: Array2<f64>,
    /// Passed the final validation.
    pub valid: Array2<bool>,
    /// Rejected and replaced by interpolation from neighbours.
    pub replaced: Array2<bool>,
    /// Not computed: inside the mask, or the centre outside the image.
    pub masked: Array2<bool>,
}

impl PivField {
    /// The field as a predictor (only for grid fields).
    pub fn to_grid_field(&self) -> Option<GridField> {
        let grid = self.grid?;
        let fill = |a: &Array2<f64>| a.mapv(|x| if x.is_finite() { x } else { 0.0 });
        let mut u = fill(&self.u);
        let mut v = fill(&self.v);
        let good = self.masked.mapv(|m| !m);
        replace(&mut u, &mut v, &good);
        Some(GridField { grid, u, v })
    }
}

fn check_pair<T: Pixel>(a: &ArrayView2<T>, b: &ArrayView2<T>) -> Result<()> {
    if a.dim() != b.dim() {
        return Err(PivError::InvalidInput(format!(
            "frame_a ({} x {}) and frame_b ({} x {}) differ in shape (rows x columns)",
            a.nrows(),
            a.ncols(),
            b.nrows(),
            b.ncols()
        )));
    }
    Ok(())
}

fn check_mask(mask: &Option<ArrayView2<'_, bool>>, dim: (usize, usize)) -> Result<()> {
    if let Some(m) = mask {
        if m.dim() != dim {
            return Err(PivError::InvalidInput(format!(
                "mask ({} x {}) differs in shape from the frames ({} x {})",
                m.nrows(),
                m.ncols(),
                dim.0,
                dim.1
            )));
        }
    }
    Ok(())
}

/// Is the point (x, y) not to be computed (mask or outside the image)?
fn excluded(mask: &Option<ArrayView2<'_, bool>>, dim: (usize, usize), x: f64, y: f64) -> bool {
    let (h, w) = dim;
    if !(x.is_finite() && y.is_finite())
        || x < -0.5
        || y < -0.5
        || x > w as f64 - 0.5
        || y > h as f64 - 0.5
    {
        return true;
    }
    match mask {
        Some(m) => {
            let i = (x.round() as usize).min(w - 1);
            let j = (y.round() as usize).min(h - 1);
            m[[j, i]]
        }
        None => false,
    }
}

/// One correlation sweep over a list of points: `base` (deformation field) and per-point extra
/// displacement `du`, `dv`. Returns the peaks (FAILED where `skip`).
fn sweep<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy + Sync, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    xs: &[f64],
    ys: &[f64],
    du: &[f64],
    dv: &[f64],
    skip: &[bool],
    base: Option<&GridField>,
    sub: SubPixel,
    floor: f32,
) -> Vec<Peak> {
    let hw = (w as f64 - 1.0) / 2.0;
    let hh = (h as f64 - 1.0) / 2.0;
    (0..xs.len())
        .into_par_iter()
        .map_init(
            || {
                let mut c = Correlator::new(w, h);
                c.min_var = floor;
                (c, FillScratch::new(w * h))
            },
            |(c, keep), k| {
                if skip[k] {
                    return Peak::FAILED;
                }
                let spec = WindowSpec {
                    left: xs[k] - hw,
                    top: ys[k] - hh,
                    du: du[k],
                    dv: dv[k],
                    field: base,
                };
                let (wa, wb) = (&mut c.wa, &mut c.wb);
                // samples outside the image come back NaN: not correlated
                sample_pair(src, w, h, &spec, wa, wb);
                if signal_fraction(wa, wb, keep, w, h, floor) < MIN_SIGNAL_FRACTION {
                    return Peak::FAILED;
                }
                c.correlate(sub)
            },
        )
        .collect()
}

/// Blocks of a window: `(number, size)` along an axis of `n` px: blocks of an eighth of the
/// window, 2 to 4 px (more for windows above 64 px: at most 16 blocks), the last one taking
/// the remainder.
fn blocks(n: usize) -> (usize, usize) {
    let size = (n / 8).clamp(2, 4).max(n.div_ceil(16)).min(n);
    (n / size, size)
}

/// Minimum and maximum of the block `x0..x1` x `y0..y1` of a `w`-wide window of finite values,
/// kept in 4 independent lanes (blocks are 2-8 px wide): no serial min/max dependency chain.
#[inline]
fn block_range(
    win: &[f32],
    w: usize,
    (x0, x1): (usize, usize),
    (y0, y1): (usize, usize),
) -> (f32, f32) {
    let mut lo = [f32::INFINITY; 4];
    let mut hi = [f32::NEG_INFINITY; 4];
    for r in y0..y1 {
        let mut it = win[r * w + x0..r * w + x1].chunks_exact(4);
        for c in &mut it {
            for k in 0..4 {
                lo[k] = if c[k] < lo[k] { c[k] } else { lo[k] };
                hi[k] = if c[k] > hi[k] { c[k] } else { hi[k] };
            }
        }
        for (k, &v) in it.remainder().iter().enumerate() {
            lo[k] = if v < lo[k] { v } else { lo[k] };
            hi[k] = if v > hi[k] { v } else { hi[k] };
        }
    }
    let l = lo
        .iter()
        .fold(f32::INFINITY, |a, &v| if v < a { v } else { a });
    let h = hi
        .iter()
        .fold(f32::NEG_INFINITY, |a, &v| if v > a { v } else { a });
    (l, h)
}

/// A window pair needs signal over at least this fraction of its area (see
/// [`signal_fraction`]); otherwise it is not correlated (`valid = false`).
pub const MIN_SIGNAL_FRACTION: f64 = 0.75;

/// No NaN or infinity in `x` (a finite sum, 8 accumulators; the values are pixel levels).
fn all_finite(x: &[f32]) -> bool {
    let mut acc = [0.0f32; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            acc[k] += c[k];
        }
    }
    (acc.iter().sum::<f32>() + it.remainder().iter().sum::<f32>()).is_finite()
}

/// Scratch of [`signal_fraction`] for `w * h` windows.
struct FillScratch {
    keep: Vec<bool>,
    stack: Vec<usize>,
}

impl FillScratch {
    fn new(n: usize) -> FillScratch {
        FillScratch {
            keep: vec![true; n],
            stack: Vec::with_capacity(n),
        }
    }
}

/// The fraction of a window pair's area that carries signal; 0 when a sample lies outside the
/// frame; the pixels without signal are neutralised.
///
/// - A window pair with a sample outside the frame (NaN, see [`sample_pair`]) is not
///   correlated: returns 0.
/// - The window (`h` rows of `w`) is split into about 8 x 8 blocks of 2 to 4 px a side (see
///   [`blocks`]). A block that is constant, or whose per-pixel variance is
///   `<= floor + 1e-8 mean^2 + 1e-12`, in either window is blank: zero fill of a dewarped
///   frame, a blank or saturated region. The signal fraction is the area fraction of the
///   other blocks.
/// - When it is at least [`MIN_SIGNAL_FRACTION`] the pair is correlated over its signal part
///   only: the blank blocks, and the pixels of the blocks next to them that are connected to
///   them through values equal in both windows to the blank ones (the rest of a fill that a
///   block boundary cuts), are set in both windows to the mean of that window's other
///   pixels, so that they drop out of the mean-free correlation and the fill's stationary
///   edge does not pull the peak towards zero displacement.
///
/// With deformation, the fill edge moves against the particles in the deformed pair (each
/// frame is shifted by half the displacement) and is no longer stationary: a window part-way
/// into the fill keeps a bias of a few 0.01 px towards minus the displacement; give a mask to
/// drop such vectors. With no blank block the windows are untouched and 1 is returned. Particle images with
/// camera noise have no blank block. A fill narrower than a block (under 4 px of a 32 px
/// window) is not detected and is correlated with the rest (its edge biases the vector by a
/// few 0.01 px). Clean images (background subtracted and clipped at zero) have 4 x 4 px
/// blocks empty in both frames at 0.03 particles/px with a probability of about 5 %: such
/// blocks are neutralised (the background next to them too), and a window is flagged only
/// when a quarter of it is empty (with a probability far below 1e-3).
fn signal_fraction(
    wa: &mut [f32],
    wb: &mut [f32],
    scratch: &mut FillScratch,
    w: usize,
    h: usize,
    floor: f32,
) -> f64 {
    if !(all_finite(wa) && all_finite(wb)) {
        return 0.0;
    }
    let ((nbx, bw), (nby, bh)) = (blocks(w), blocks(h));
    let span = |b: usize, nb: usize, size: usize, len: usize| {
        (b * size, if b + 1 == nb { len } else { (b + 1) * size })
    };
    let blank = |win: &[f32], (x0, x1): (usize, usize), (y0, y1): (usize, usize)| {
        let m = ((x1 - x0) * (y1 - y0)) as f64;
        // the variance is at least range^2 / (2 m), with the range of any subset: most blocks
        // are decided by their first row
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for rows in [(y0, y0 + 1), (y0 + 1, y1)] {
            let (l, u) = block_range(win, w, (x0, x1), rows);
            (lo, hi) = (lo.min(l), hi.max(u));
            let (range, top) = ((hi - lo) as f64, lo.abs().max(hi.abs()) as f64);
            if range * range > 2.0 * m * (floor as f64 + 1e-8 * top * top + 1e-12) {
                return false;
            }
        }
        if lo == hi {
            return true;
        }
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for r in y0..y1 {
            for &v in &win[r * w + x0..r * w + x1] {
                let v = v as f64;
                s += v;
                s2 += v * v;
            }
        }
        let mean = s / m;
        let var = (s2 / m - mean * mean).max(0.0);
        var <= floor as f64 + 1e-8 * mean * mean + 1e-12
    };
    // blank flags of the (at most 16 x 16) blocks
    let mut is_blank = [false; 256];
    let mut blank_px = 0usize;
    for by in 0..nby {
        let ys = span(by, nby, bh, h);
        for bx in 0..nbx {
            let xs = span(bx, nbx, bw, w);
            if blank(wa, xs, ys) || blank(wb, xs, ys) {
                is_blank[by * nbx + bx] = true;
                blank_px += (xs.1 - xs.0) * (ys.1 - ys.0);
            }
        }
    }
    if blank_px == 0 {
        return 1.0;
    }
    let fraction = 1.0 - blank_px as f64 / (w * h) as f64;
    if fraction < MIN_SIGNAL_FRACTION {
        return fraction;
    }
    let block_of = |i: usize| {
        let (r, c) = (i / w, i % w);
        ((r / bh).min(nby - 1), (c / bw).min(nbx - 1))
    };
    let next_to_blank = |(by, bx): (usize, usize)| {
        (by.saturating_sub(1)..=(by + 1).min(nby - 1))
            .any(|j| (bx.saturating_sub(1)..=(bx + 1).min(nbx - 1)).any(|i| is_blank[j * nbx + i]))
    };
    let FillScratch { keep, stack } = scratch;
    stack.clear();
    for (i, k) in keep.iter_mut().enumerate() {
        let (by, bx) = block_of(i);
        *k = !is_blank[by * nbx + bx];
        if !*k {
            stack.push(i);
        }
    }
    // the fill beyond the blank blocks: 4-connected, equal values, blocks next to blank ones
    while let Some(i) = stack.pop() {
        let (r, c) = (i / w, i % w);
        let nb = [
            (r > 0).then(|| i - w),
            (r + 1 < h).then(|| i + w),
            (c > 0).then(|| i - 1),
            (c + 1 < w).then(|| i + 1),
        ];
        for j in nb.into_iter().flatten() {
            if keep[j] && wa[j] == wa[i] && wb[j] == wb[i] && next_to_blank(block_of(j)) {
                keep[j] = false;
                stack.push(j);
            }
        }
    }
    let kept = keep.iter().filter(|&&k| k).count().max(1);
    for win in [&mut *wa, &mut *wb] {
        let s: f64 = win
            .iter()
            .zip(keep.iter())
            .filter(|(_, &k)| k)
            .map(|(&v, _)| v as f64)
            .sum();
        let m = (s / kept as f64) as f32;
        for (v, &k) in win.iter_mut().zip(keep.iter()) {
            if !k {
                *v = m;
            }
        }
    }
    fraction
}

/// The interpolation images of a frame pair.
enum Coeffs {
    /// Quintic B-spline coefficients.
    Quintic(Img<'static, f32>, Img<'static, f32>),
    /// Cubic B-spline coefficients.
    Cubic(Img<'static, f32>, Img<'static, f32>),
    /// Keys on the frames themselves.
    Keys,
}

/// The frames and their interpolants; `sweep` over them.
struct Frames<'a, T: Pixel> {
    a: Img<'a, T>,
    b: Img<'a, T>,
    interp: Interpolation,
    /// The interpolation images, computed on first use (windows on integer positions need
    /// none).
    coeffs: std::sync::OnceLock<Coeffs>,
    /// Per-pixel variance below which a window counts as blank: [`BLANK_VARIANCE`] times the
    /// larger variance of the two frames.
    floor: f32,
}

/// A window whose per-pixel variance is below this fraction of its frame's variance is blank
/// (zero fill of a dewarped frame, including the interpolation's ringing next to its edge;
/// regions without signal): it is not correlated. Camera noise alone is far above it.
pub const BLANK_VARIANCE: f64 = 1e-6;

/// Per-pixel variance of a frame (f64 accumulation, rows in parallel).
fn frame_variance<T: Pixel>(img: &Img<'_, T>) -> f64 {
    let n = (img.width * img.height) as f64;
    let (s, s2) = img
        .slice()
        .par_chunks(img.width.max(1))
        .map(|row| {
            row.iter().fold((0.0f64, 0.0f64), |(s, s2), p| {
                let v = p.to_f32() as f64;
                (s + v, s2 + v * v)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let m = s / n;
    (s2 / n - m * m).max(0.0)
}

impl<'a, T: Pixel> Frames<'a, T> {
    fn new(a: ArrayView2<'a, T>, b: ArrayView2<'a, T>, interp: Interpolation) -> Result<Self> {
        let a = Img::new(a, "frame_a")?;
        let b = Img::new(b, "frame_b")?;
        let floor = (BLANK_VARIANCE * frame_variance(&a).max(frame_variance(&b))) as f32;
        Ok(Frames {
            a,
            b,
            interp,
            coeffs: std::sync::OnceLock::new(),
            floor,
        })
    }

    fn coeffs(&self) -> &Coeffs {
        self.coeffs.get_or_init(|| match self.interp {
            Interpolation::BSpline => {
                let (ca, cb) =
                    rayon::join(|| bspline5_coeffs(&self.a), || bspline5_coeffs(&self.b));
                Coeffs::Quintic(ca, cb)
            }
            Interpolation::BSpline3 => {
                Coeffs::Cubic(bspline_coeffs(&self.a), bspline_coeffs(&self.b))
            }
            Interpolation::Keys => Coeffs::Keys,
        })
    }

    /// The frames deformed symmetrically by `f` (see [`deform_pair`]).
    fn deformed(&self, f: &GridField) -> Frames<'static, f32> {
        let (a, b) = match self.coeffs() {
            Coeffs::Quintic(ca, cb) => deform_pair(ca, cb, bspline5_weights, f),
            Coeffs::Cubic(ca, cb) => deform_pair(ca, cb, bspline_weights, f),
            Coeffs::Keys => deform_pair(&self.a, &self.b, keys_weights, f),
        };
        Frames {
            a,
            b,
            interp: Interpolation::Keys,
            coeffs: std::sync::OnceLock::from(Coeffs::Keys),
            floor: self.floor,
        }
    }

    fn sweep(
        &self,
        w: usize,
        h: usize,
        xs: &[f64],
        ys: &[f64],
        du: &[f64],
        dv: &[f64],
        skip: &[bool],
        base: Option<&GridField>,
        sub: SubPixel,
    ) -> Vec<Peak> {
        // windows on integer positions are plain copies: no interpolation images needed
        let int = |p: f64| p == p.round();
        let (hw, hh) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let integer = base.is_none()
            && (0..xs.len()).all(|k| {
                skip[k]
                    || (int(xs[k] - hw - du[k] / 2.0)
                        && int(ys[k] - hh - dv[k] / 2.0)
                        && int(xs[k] - hw + du[k] / 2.0)
                        && int(ys[k] - hh + dv[k] / 2.0))
            });
        let coeffs = if integer {
            &Coeffs::Keys
        } else {
            self.coeffs()
        };
        match coeffs {
            Coeffs::Quintic(ca, cb) => {
                let src = Source {
                    a: &self.a,
                    b: &self.b,
                    ia: ca,
                    ib: cb,
                    wf: bspline5_weights,
                };
                sweep(&src, w, h, xs, ys, du, dv, skip, base, sub, self.floor)
            }
            Coeffs::Cubic(ca, cb) => {
                let src = Source {
                    a: &self.a,
                    b: &self.b,
                    ia: ca,
                    ib: cb,
                    wf: bspline_weights,
                };
                sweep(&src, w, h, xs, ys, du, dv, skip, base, sub, self.floor)
            }
            Coeffs::Keys => {
                let src = Source {
                    a: &self.a,
                    b: &self.b,
                    ia: &self.a,
                    ib: &self.b,
                    wf: keys_weights,
                };
                sweep(&src, w, h, xs, ys, du, dv, skip, base, sub, self.floor)
            }
        }
    }
}

/// Validate (optionally) and replace; returns (valid, replaced).
fn validate_replace(
    u: &mut Array2<f64>,
    v: &mut Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    s: &PivSettings,
) -> (Array2<bool>, Array2<bool>) {
    let dim = u.dim();
    let usable = Array2::from_shape_fn(dim, |(j, i)| {
        let k = j * dim.1 + i;
        let p = &peaks[k];
        !skip[k]
            && p.ok
            && p.ratio >= s.min_peak_ratio
            && u[[j, i]].is_finite()
            && v[[j, i]].is_finite()
    });
    let good = if s.validate {
        let out = median_test(u, v, &usable, s.median_eps, s.median_threshold);
        Array2::from_shape_fn(dim, |ji| usable[ji] && !out[ji])
    } else {
        usable
    };
    replace(u, v, &good);
    let replaced = Array2::from_shape_fn(dim, |(j, i)| !good[[j, i]] && !skip[j * dim.1 + i]);
    (good, replaced)
}

fn finish(
    grid: Option<Grid>,
    x: Array2<f64>,
    y: Array2<f64>,
    mut u: Array2<f64>,
    mut v: Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    valid: Array2<bool>,
    replaced: Array2<bool>,
) -> PivField {
    let dim = u.dim();
    let masked = Array2::from_shape_fn(dim, |(j, i)| skip[j * dim.1 + i]);
    for ((uu, vv), &m) in u.iter_mut().zip(v.iter_mut()).zip(masked.iter()) {
        if m {
            *uu = f64::NAN;
            *vv = f64::NAN;
        }
    }
    let peak_ratio = Array2::from_shape_fn(dim, |(j, i)| peaks[j * dim.1 + i].ratio);
    let coef = Array2::from_shape_fn(dim, |(j, i)| peaks[j * dim.1 + i].coef);
    PivField {
        grid,
        x,
        y,
        u,
        v,
        peak_ratio,
        coef,
        valid,
        replaced,
        masked,
    }
}

/// Multipass PIV of a frame pair on the regular grid of the last pass.
///
/// `mask` (same shape as the frames, `true` = excluded) removes the vectors whose centre falls
/// on a masked pixel. Errors: frames of different shapes, NaN/inf pixels, windows larger than the
/// image, bad settings.
pub fn piv<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
) -> Result<PivField> {
    s.check()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    check_mask(&mask, dim)?;
    let grids = grids_of(s, dim)?;
    let frames = Frames::new(frame_a, frame_b, s.interpolation)?;
    grid_passes(&frames, dim, &mask, s, grids)
}

/// The grids of the passes of `s` on frames of shape `dim` (rows, columns).
fn grids_of(s: &PivSettings, dim: (usize, usize)) -> Result<Vec<Grid>> {
    s.passes
        .iter()
        .map(|p| Grid::for_windows(dim.1, dim.0, p.w, p.h, p.overlap))
        .collect()
}

/// The passes of [`piv`] on prepared frames (inputs checked, `grids` from [`grids_of`]).
fn grid_passes<T: Pixel>(
    frames: &Frames<'_, T>,
    dim: (usize, usize),
    mask: &Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
    grids: Vec<Grid>,
) -> Result<PivField> {
    let mut pred: Option<GridField> = None;
    let mut last = None;
    for (pass, grid) in s.passes.iter().zip(grids) {
        let n = grid.len();
        let mut xs = Vec::with_capacity(n);
        let mut ys = Vec::with_capacity(n);
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = grid.xy(j, i);
                xs.push(x);
                ys.push(y);
            }
        }
        let skip: Vec<bool> = xs
            .iter()
            .zip(&ys)
            .map(|(&x, &y)| excluded(mask, dim, x, y))
            .collect();
        for _ in 0..pass.iterations {
            // the deformation predictor: the latest field averaged over this pass's window
            // (see the module notes)
            let cur = match (&pred, s.mode) {
                (Some(f), Mode::Deform) => Some(f.window_average(pass.w, pass.h)),
                (p, _) => p.clone(),
            };
            // predictor at the centres
            let (pu, pv): (Vec<f64>, Vec<f64>) = match &cur {
                Some(f) => xs.iter().zip(&ys).map(|(&x, &y)| f.at(x, y)).unzip(),
                None => (vec![0.0; n], vec![0.0; n]),
            };
            let zeros = vec![0.0; n];
            let (du, dv, base) = match s.mode {
                Mode::Deform => (&zeros, &zeros, cur.as_ref()),
                Mode::Offset => (&pu, &pv, None),
            };
            let peaks = match base {
                // grid windows sit on integer positions: deform the whole pair once, then the
                // windows are plain copies
                Some(f) => frames
                    .deformed(f)
                    .sweep(pass.w, pass.h, &xs, &ys, du, dv, &skip, None, s.subpixel),
                None => frames.sweep(pass.w, pass.h, &xs, &ys, du, dv, &skip, None, s.subpixel),
            };
            let mut u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let k = j * grid.nx + i;
                pu[k] + peaks[k].dx
            });
            let mut v = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let k = j * grid.nx + i;
                pv[k] + peaks[k].dy
            });
            let (valid, replaced) = validate_replace(&mut u, &mut v, &peaks, &skip, s);
            pred = Some(GridField {
                grid,
                u: u.clone(),
                v: v.clone(),
            });
            last = Some((u, v, peaks, valid, replaced));
        }
        if let Some((u, v, peaks, valid, replaced)) = last.take() {
            if std::ptr::eq(pass, s.passes.last().expect("non-empty")) {
                let x = Array2::from_shape_vec((grid.ny, grid.nx), xs).expect("shape");
                let y = Array2::from_shape_vec((grid.ny, grid.nx), ys).expect("shape");
                return Ok(finish(
                    Some(grid),
                    x,
                    y,
                    u,
                    v,
                    &peaks,
                    &skip,
                    valid,
                    replaced,
                ));
            }
        }
    }
    Err(PivError::InvalidInput("passes is empty".into()))
}

/// The predictor of [`piv_at`].
#[derive(Debug, Clone, Copy)]
pub enum Predictor<'a> {
    /// No predictor (zero displacement).
    Zero,
    /// One displacement per point (same shape as the points), px: the windows are offset
    /// symmetrically (sub-pixel) by it.
    PerPoint {
        u: ArrayView2<'a, f64>,
        v: ArrayView2<'a, f64>,
    },
    /// A regular-grid field (e.g. a previous [`piv`] on the same frames): the windows are
    /// deformed by it (symmetric, see [`Interpolation`]). The first correlation deforms the
    /// whole pair once on the pixel lattice (as [`piv`] does) and reads each window at its
    /// fractional position from the deformed pair with Keys: both windows of a pair are
    /// shifted by the same fraction, a linear shift-invariant filter applied to both, which
    /// widens the correlation peak but does not move it (the interpolation bias that the
    /// quintic B-spline keeps small is a bias of the relative shift of the two frames). It
    /// costs one interpolation per pixel plus a constant-shift copy per window, instead of a
    /// deformed interpolation per pixel and overlapping window. Later iterations (a per-point
    /// residual offset on top of the field) sample each window on its own.
    Field(&'a GridField),
}

/// Multipass PIV at arbitrary image positions `(x, y)` (pixel frame, arrays of one shape
/// (ny, nx)) with a given predictor: for each window of `windows` (`(w, h)`, w along x) in turn,
/// and `iterations` times each, every point's window pair is displaced by the current
/// displacement (the predictor's deformation plus a per-point symmetric offset) and the residual
/// is added. Between iterations the points are validated as a (ny, nx) grid of neighbours when
/// `s.validate` (give nx = 1 or ny = 1 only if neighbours along the line are meaningful).
/// `s.passes` and `s.mode` are ignored: `windows` gives the passes, and a `Field` predictor
/// means deformation. Points whose centre lies outside the image or in the mask are not computed.
/// Used by Method II (PIV on the raw frames at the images of an object grid).
pub fn piv_at<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    predictor: Predictor<'_>,
    mask: Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    s: &PivSettings,
) -> Result<PivField> {
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    let settings = check_at(dim, &x, &y, &predictor, &mask, windows, iterations, s)?;
    let frames = Frames::new(frame_a, frame_b, settings.interpolation)?;
    at_points(
        &frames, dim, x, y, predictor, &mask, windows, iterations, &settings,
    )
}

/// Check the inputs of [`piv_at`] other than the frames; returns its settings.
fn check_at(
    dim: (usize, usize),
    x: &ArrayView2<'_, f64>,
    y: &ArrayView2<'_, f64>,
    predictor: &Predictor<'_>,
    mask: &Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    s: &PivSettings,
) -> Result<PivSettings> {
    check_mask(mask, dim)?;
    if x.dim() != y.dim() {
        return Err(PivError::InvalidInput(format!(
            "points: x {:?} and y {:?} differ in shape",
            x.dim(),
            y.dim()
        )));
    }
    if windows.is_empty() || iterations == 0 {
        return Err(PivError::InvalidInput(
            "piv_at needs at least one window and one iteration".into(),
        ));
    }
    let mut settings = s.clone();
    settings.passes = windows.iter().map(|&(w, h)| Pass::new(w, h)).collect();
    settings.check()?;
    for &(w, h) in windows {
        if w > dim.1 || h > dim.0 {
            return Err(PivError::InvalidInput(format!(
                "window {w} x {h} px (w x h) is larger than the image ({} x {} px)",
                dim.1, dim.0
            )));
        }
    }
    if let Predictor::PerPoint { u, v } = predictor {
        if u.dim() != x.dim() || v.dim() != x.dim() {
            return Err(PivError::InvalidInput(format!(
                "predictor shape {:?} differs from the points' {:?}",
                u.dim(),
                x.dim()
            )));
        }
        if u.iter().chain(v.iter()).any(|p| !p.is_finite()) {
            return Err(PivError::InvalidInput(
                "predictor contains NaN or inf".into(),
            ));
        }
    }
    Ok(settings)
}

/// The passes of [`piv_at`] on prepared frames (inputs checked by [`check_at`]).
fn at_points<T: Pixel>(
    frames: &Frames<'_, T>,
    dim: (usize, usize),
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    predictor: Predictor<'_>,
    mask: &Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    settings: &PivSettings,
) -> Result<PivField> {
    let shape = x.dim();
    let n = x.len();
    let xs: Vec<f64> = x.iter().copied().collect();
    let ys: Vec<f64> = y.iter().copied().collect();
    let skip: Vec<bool> = xs
        .iter()
        .zip(&ys)
        .map(|(&x, &y)| excluded(mask, dim, x, y))
        .collect();
    let (base, mut du, mut dv): (Option<&GridField>, Vec<f64>, Vec<f64>) = match predictor {
        Predictor::Zero => (None, vec![0.0; n], vec![0.0; n]),
        Predictor::PerPoint { u, v } => (
            None,
            u.iter().copied().collect(),
            v.iter().copied().collect(),
        ),
        Predictor::Field(f) => (Some(f), vec![0.0; n], vec![0.0; n]),
    };
    let (bu, bv): (Vec<f64>, Vec<f64>) = match base {
        Some(f) => xs.iter().zip(&ys).map(|(&x, &y)| f.at(x, y)).unzip(),
        None => (vec![0.0; n], vec![0.0; n]),
    };
    let mut last = None;
    // the pair deformed once by the field predictor (see `Predictor::Field`)
    let mut deformed: Option<Frames<'static, f32>> = None;
    for &(w, h) in windows {
        for _ in 0..iterations {
            let no_offset = du.iter().chain(&dv).all(|&d| d == 0.0);
            let peaks =
                match base {
                    Some(f) if no_offset => deformed
                        .get_or_insert_with(|| frames.deformed(f))
                        .sweep(w, h, &xs, &ys, &du, &dv, &skip, None, settings.subpixel),
                    _ => frames.sweep(w, h, &xs, &ys, &du, &dv, &skip, base, settings.subpixel),
                };
            let mut u = Array2::from_shape_fn(shape, |(j, i)| {
                let k = j * shape.1 + i;
                bu[k] + du[k] + peaks[k].dx
            });
            let mut v = Array2::from_shape_fn(shape, |(j, i)| {
                let k = j * shape.1 + i;
                bv[k] + dv[k] + peaks[k].dy
            });
            let (valid, replaced) = validate_replace(&mut u, &mut v, &peaks, &skip, settings);
            for k in 0..n {
                let (j, i) = (k / shape.1, k % shape.1);
                du[k] = u[[j, i]] - bu[k];
                dv[k] = v[[j, i]] - bv[k];
            }
            last = Some((u, v, peaks, valid, replaced));
        }
    }
    let (u, v, peaks, valid, replaced) = last.expect("at least one iteration");
    Ok(finish(
        None,
        x.to_owned(),
        y.to_owned(),
        u,
        v,
        &peaks,
        &skip,
        valid,
        replaced,
    ))
}

/// Method II's PIV in one call on one prepared frame pair: the passes of `s` but the last run
/// as [`piv`] on the regular grid (the predictor), then the last pass (its window and
/// iterations; its overlap is ignored) runs as [`piv_at`] at the image points `(x, y)` with that
/// field as predictor: deformed by it ([`Predictor::Field`]) for [`Mode::Deform`], offset by
/// it interpolated at each point ([`Predictor::PerPoint`]) for [`Mode::Offset`]. The frames'
/// interpolation coefficients and variance are computed once for both stages. Vectors of the
/// predictor that are not computed (mask) take the mean of the computed ones.
///
/// Gives the same vectors as [`piv`] with the first passes followed by [`piv_at`] with that
/// predictor. Returns `(predictor, final)`; `predictor` is `None` when `s` has one pass (the
/// final pass then has no predictor).
pub fn piv_with_final_points<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
) -> Result<(Option<PivField>, PivField)> {
    s.check()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    let last = *s.passes.last().expect("checked: non-empty");
    let windows = [(last.w, last.h)];
    // the final pass's checks before any work (the predictor shape is checked below)
    let settings_at = check_at(
        dim,
        &x,
        &y,
        &Predictor::Zero,
        &mask,
        &windows,
        last.iterations,
        s,
    )?;
    let mut first = s.clone();
    first.passes.pop();
    let grids = grids_of(&first, dim)?;
    let frames = Frames::new(frame_a, frame_b, s.interpolation)?;
    if first.passes.is_empty() {
        let f = at_points(
            &frames,
            dim,
            x,
            y,
            Predictor::Zero,
            &mask,
            &windows,
            last.iterations,
            &settings_at,
        )?;
        return Ok((None, f));
    }
    let pred = grid_passes(&frames, dim, &mask, &first, grids)?;
    let grid = pred.grid.expect("grid passes give a grid field");
    let fill = |a: &Array2<f64>| {
        let (sum, n) = a
            .iter()
            .filter(|p| p.is_finite())
            .fold((0.0, 0usize), |(s, n), &p| (s + p, n + 1));
        let m = if n > 0 { sum / n as f64 } else { 0.0 };
        a.mapv(|p| if p.is_finite() { p } else { m })
    };
    let gf = GridField {
        grid,
        u: fill(&pred.u),
        v: fill(&pred.v),
    };
    let f = match s.mode {
        Mode::Deform => at_points(
            &frames,
            dim,
            x,
            y,
            Predictor::Field(&gf),
            &mask,
            &windows,
            last.iterations,
            &settings_at,
        )?,
        Mode::Offset => {
            let finite = |p: f64| if p.is_finite() { p } else { 0.0 };
            let (pu, pv): (Vec<f64>, Vec<f64>) = x
                .iter()
                .zip(y.iter())
                .map(|(&x, &y)| {
                    let (u, v) = gf.at(x, y);
                    (finite(u), finite(v))
                })
                .unzip();
            let pu = Array2::from_shape_vec(x.dim(), pu).expect("shape");
            let pv = Array2::from_shape_vec(x.dim(), pv).expect("shape");
            at_points(
                &frames,
                dim,
                x,
                y,
                Predictor::PerPoint {
                    u: pu.view(),
                    v: pv.view(),
                },
                &mask,
                &windows,
                last.iterations,
                &settings_at,
            )?
        }
    };
    Ok((Some(pred), f))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render_particles;
    use rand::{Rng, SeedableRng};

    /// A particle pair moved by `disp(x, y)` (evaluated at the midpoint).
    fn pair(
        h: usize,
        w: usize,
        disp: impl Fn(f64, f64) -> (f64, f64),
    ) -> (Array2<u16>, Array2<u16>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = (0.03 * ((h + 20) * (w + 20)) as f64) as usize;
        let (mut xa, mut ya, mut xb, mut yb, mut it) = (vec![], vec![], vec![], vec![], vec![]);
        for _ in 0..n {
            let x = rng.random::<f64>() * (w + 20) as f64 - 10.0;
            let y = rng.random::<f64>() * (h + 20) as f64 - 10.0;
            let (u, v) = disp(x, y);
            xa.push(x - u / 2.0);
            ya.push(y - v / 2.0);
            xb.push(x + u / 2.0);
            yb.push(y + v / 2.0);
            it.push(2000.0 + 1000.0 * rng.random::<f64>());
        }
        let a = render_particles(h, w, &xa, &ya, &it, &[2.5], 40.0, 4095, 1).unwrap();
        let b = render_particles(h, w, &xb, &yb, &it, &[2.5], 40.0, 4095, 2).unwrap();
        (a, b)
    }

    fn rms(f: &PivField, disp: impl Fn(f64, f64) -> (f64, f64)) -> (f64, f64) {
        let mut s = 0.0;
        let mut m = 0.0;
        for ((x, y), (u, v)) in f.x.iter().zip(&f.y).zip(f.u.iter().zip(&f.v)) {
            let (tu, tv) = disp(*x, *y);
            s += (u - tu).powi(2) + (v - tv).powi(2);
            m += (u - tu) + (v - tv);
        }
        let n = f.u.len() as f64;
        ((s / n).sqrt(), m / n)
    }

    #[test]
    fn uniform_subpixel_displacement_multipass() {
        let d = |_: f64, _: f64| (0.3, -0.7);
        let (a, b) = pair(160, 160, d);
        let mut s = PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 32)],
            ..PivSettings::default()
        };
        for mode in [Mode::Deform, Mode::Offset] {
            s.mode = mode;
            let f = piv(a.view(), b.view(), None, &s).unwrap();
            let (e, bias) = rms(&f, d);
            assert!(
                e < 0.05 && bias.abs() < 0.02,
                "{mode:?} rms {e} bias {bias}"
            );
            assert!(f.valid.iter().filter(|&&v| v).count() as f64 > 0.9 * f.u.len() as f64);
        }
    }

    #[test]
    fn piv_at_with_exact_predictor_keeps_it() {
        let d = |_: f64, _: f64| (4.4, 1.3);
        let (a, b) = pair(128, 128, d);
        let x = Array2::from_shape_fn((3, 4), |(_, i)| 30.0 + 20.0 * i as f64 + 0.25);
        let y = Array2::from_shape_fn((3, 4), |(j, _)| 40.0 + 20.0 * j as f64 - 0.4);
        let u = Array2::from_elem((3, 4), 4.4);
        let v = Array2::from_elem((3, 4), 1.3);
        let s = PivSettings::default();
        let pred = Predictor::PerPoint {
            u: u.view(),
            v: v.view(),
        };
        let f = piv_at(
            a.view(),
            b.view(),
            x.view(),
            y.view(),
            pred,
            None,
            &[(32, 32)],
            1,
            &s,
        )
        .unwrap();
        let (e, _) = rms(&f, d);
        assert!(e < 0.05, "rms {e}");
    }

    /// The one-call Method II path equals `piv` of the first passes followed by `piv_at` with
    /// that field (deformed) or its values at the points (offset), and measures the truth.
    #[test]
    fn final_points_in_one_call_equal_the_two_calls() {
        let d = |x: f64, y: f64| (3.0 + 0.02 * y, 1.0 - 0.01 * x);
        let (a, b) = pair(160, 200, d);
        // fractional points, some near the edge, one outside the image and one masked
        let x = Array2::from_shape_fn((6, 9), |(j, i)| 10.3 + 22.0 * i as f64 + 0.7 * j as f64);
        let mut y = Array2::from_shape_fn((6, 9), |(j, i)| 12.6 + 27.0 * j as f64 - 0.3 * i as f64);
        y[[0, 0]] = -5.0;
        let mut mask = Array2::from_elem((160, 200), false);
        mask.slice_mut(ndarray::s![60..70, 100..115]).fill(true);
        for mode in [Mode::Deform, Mode::Offset] {
            let s = PivSettings {
                passes: vec![Pass::new(48, 48), Pass::new(32, 32), Pass::new(32, 8)],
                mode,
                ..PivSettings::default()
            };
            let (pred, one) = piv_with_final_points(
                a.view(),
                b.view(),
                x.view(),
                y.view(),
                Some(mask.view()),
                &s,
            )
            .unwrap();
            let pred = pred.unwrap();
            let mut first = s.clone();
            first.passes.pop();
            let p2 = piv(a.view(), b.view(), Some(mask.view()), &first).unwrap();
            assert!(p2
                .u
                .iter()
                .zip(&pred.u)
                .all(|(p, q)| p == q || p.is_nan() && q.is_nan()));
            // the two-call path of rspiv.method2: masked predictor vectors take the mean
            let mean = |a: &Array2<f64>| {
                let f: Vec<f64> = a.iter().copied().filter(|p| p.is_finite()).collect();
                f.iter().sum::<f64>() / f.len() as f64
            };
            let (mu, mv) = (mean(&p2.u), mean(&p2.v));
            assert!(p2.masked.iter().any(|&m| m));
            let gf = GridField {
                grid: p2.grid.unwrap(),
                u: p2.u.mapv(|p| if p.is_finite() { p } else { mu }),
                v: p2.v.mapv(|p| if p.is_finite() { p } else { mv }),
            };
            let pu = Array2::from_shape_fn(x.dim(), |ji| gf.at(x[ji], y[ji]).0);
            let pv = Array2::from_shape_fn(x.dim(), |ji| gf.at(x[ji], y[ji]).1);
            let pr = match mode {
                Mode::Deform => Predictor::Field(&gf),
                Mode::Offset => Predictor::PerPoint {
                    u: pu.view(),
                    v: pv.view(),
                },
            };
            let two = piv_at(
                a.view(),
                b.view(),
                x.view(),
                y.view(),
                pr,
                Some(mask.view()),
                &[(32, 8)],
                1,
                &s,
            )
            .unwrap();
            let same = |p: &Array2<f64>, q: &Array2<f64>| {
                p.iter()
                    .zip(q)
                    .all(|(p, q)| p == q || p.is_nan() && q.is_nan())
            };
            assert!(same(&one.u, &two.u) && same(&one.v, &two.v), "{mode:?}");
            assert_eq!(one.valid, two.valid);
            assert_eq!(one.masked, two.masked);
            assert!(one.masked[[0, 0]]);
            let (e, n) = worst_valid(&one, d);
            assert!(n > 30 && e < 0.15, "{mode:?}: worst {e} over {n}");
        }
        // one pass: no predictor
        let s = PivSettings {
            passes: vec![Pass::new(32, 32)],
            ..PivSettings::default()
        };
        let (pred, _) =
            piv_with_final_points(a.view(), b.view(), x.view(), y.view(), None, &s).unwrap();
        assert!(pred.is_none());
        // bad points
        let y2 = Array2::zeros((2, 2));
        assert!(piv_with_final_points(a.view(), b.view(), x.view(), y2.view(), None, &s).is_err());
    }

    /// Largest error of the valid vectors against `disp`, and the number of valid ones.
    fn worst_valid(f: &PivField, disp: impl Fn(f64, f64) -> (f64, f64)) -> (f64, usize) {
        let mut worst = 0.0f64;
        let mut n = 0;
        for ((x, y), ((u, v), ok)) in f.x.iter().zip(&f.y).zip(f.u.iter().zip(&f.v).zip(&f.valid)) {
            if *ok {
                let (tu, tv) = disp(*x, *y);
                worst = worst.max((u - tu).abs()).max((v - tv).abs());
                n += 1;
            }
        }
        (worst, n)
    }

    #[test]
    fn piv_at_windows_past_the_edge_are_invalid() {
        // uniform flow; points from well inside to beyond the right and bottom edges
        let d = |_: f64, _: f64| (3.0, 2.0);
        let (a, b) = pair(128, 128, d);
        let xs = [
            40.0, 80.0, 100.0, 110.0, 114.0, 115.0, 116.0, 116.5, 127.4, 130.0,
        ];
        let x = Array2::from_shape_fn((1, xs.len()), |(_, i)| xs[i]);
        let y = Array2::from_shape_fn((1, xs.len()), |(_, i)| 20.0 + 10.0 * i as f64);
        let s = PivSettings {
            validate: false,
            ..PivSettings::default()
        };
        let u = Array2::from_elem(x.dim(), 3.0);
        let v = Array2::from_elem(x.dim(), 2.0);
        let (w, h) = (24usize, 24usize);
        for pred in [
            Predictor::Zero,
            Predictor::PerPoint {
                u: u.view(),
                v: v.view(),
            },
        ] {
            let (pu, pv) = match pred {
                Predictor::Zero => (0.0, 0.0),
                _ => (3.0, 2.0),
            };
            let f = piv_at(
                a.view(),
                b.view(),
                x.view(),
                y.view(),
                pred,
                None,
                &[(w, h)],
                1,
                &s,
            )
            .unwrap();
            for i in 0..xs.len() {
                let (cx, cy) = (f.x[[0, i]], f.y[[0, i]]);
                let (l, t) = (cx - (w as f64 - 1.0) / 2.0, cy - (h as f64 - 1.0) / 2.0);
                let fits = |dx: f64, dy: f64| {
                    l + dx >= -0.5
                        && t + dy >= -0.5
                        && l + dx + (w - 1) as f64 <= 127.5
                        && t + dy + (h - 1) as f64 <= 127.5
                };
                let expect = fits(-pu / 2.0, -pv / 2.0) && fits(pu / 2.0, pv / 2.0);
                assert_eq!(f.valid[[0, i]], expect, "{pred:?} point {i} ({cx}, {cy})");
                if !expect {
                    assert!(!f.valid[[0, i]] && (f.masked[[0, i]] || f.replaced[[0, i]]));
                    assert_eq!(f.coef[[0, i]], 0.0);
                }
            }
            // centre beyond the image: not computed
            assert!(f.masked[[0, xs.len() - 1]] && f.u[[0, xs.len() - 1]].is_nan());
            let (worst, n) = worst_valid(&f, d);
            assert!(n >= 4 && worst < 0.1, "{pred:?}: {n} valid, worst {worst}");
        }
    }

    #[test]
    fn deformed_windows_past_the_edge_are_invalid() {
        // a 6 px shift: after the first pass the deformed border windows sample 3 px outside
        let d = |_: f64, _: f64| (6.0, -5.0);
        let (a, b) = pair(128, 128, d);
        let s = PivSettings {
            passes: vec![Pass::new(32, 32), Pass::new(32, 32)],
            ..PivSettings::default()
        };
        let f = piv(a.view(), b.view(), None, &s).unwrap();
        let (ny, nx) = f.u.dim();
        for j in 0..ny {
            for i in 0..nx {
                let edge = i == 0 || j == 0 || i == nx - 1 || j == ny - 1;
                // the grid windows touch the image border: the deformation pushes the edge
                // rows/columns out of the image
                let (l, t) = (f.x[[j, i]] - 15.5, f.y[[j, i]] - 15.5);
                let out = l < 2.5 || t < 2.0 || l + 31.0 > 127.0 - 2.5 || t + 31.0 > 127.0 - 2.0;
                if out {
                    assert!(!f.valid[[j, i]] && f.replaced[[j, i]], "({j}, {i})");
                }
                if !edge {
                    assert!(f.valid[[j, i]], "({j}, {i})");
                }
            }
        }
        let (worst, n) = worst_valid(&f, d);
        assert!(n >= 9 && worst < 0.1, "{n} valid, worst {worst}");
    }

    #[test]
    fn zero_filled_half_is_blank_and_vectors_clear_of_it_are_right() {
        let d = |_: f64, _: f64| (1.5, 0.5);
        let (mut a, mut b) = pair(128, 160, d);
        a.slice_mut(ndarray::s![.., 80..]).fill(0);
        b.slice_mut(ndarray::s![.., 80..]).fill(0);
        for passes in [
            vec![Pass::new(32, 32)],
            vec![Pass::new(32, 32), Pass::new(16, 16)],
        ] {
            let s = PivSettings {
                passes,
                ..PivSettings::default()
            };
            let f = piv(a.view(), b.view(), None, &s).unwrap();
            let hw = (s.passes.last().unwrap().w as f64 - 1.0) / 2.0;
            let mut clear = f.clone();
            for (((x, ok), c), cl) in
                f.x.iter()
                    .zip(&f.valid)
                    .zip(&f.coef)
                    .zip(clear.valid.iter_mut())
            {
                // windows entirely inside the zero fill, also after the deformation by 0.75 px
                // and the interpolation kernel (2 px): blank, not correlated
                if x - hw - 0.75 - 2.0 >= 80.0 - 0.5 {
                    assert!(!ok && *c == 0.0, "x {x}");
                }
                // windows clear of the fill (3 px margin for the interpolation kernel)
                *cl = *ok && x + hw + 0.75 + 3.0 < 80.0;
            }
            let (worst, n) = worst_valid(&clear, d);
            assert!(n >= 6 && worst < 0.1, "{n} clear valid, worst {worst}");
            // windows straddling the fill edge: see the next test
        }
    }

    #[test]
    fn windows_reaching_into_zero_fill_are_flagged_or_correlated_over_the_image_part() {
        let d = |_: f64, _: f64| (1.5, 0.5);
        let (a, b) = pair(128, 224, d);
        let (mut af, mut bf) = (a.clone(), b.clone());
        af.slice_mut(ndarray::s![.., 150..]).fill(0);
        bf.slice_mut(ndarray::s![.., 150..]).fill(0);
        let s = PivSettings {
            passes: vec![Pass::new(32, 32)],
            ..PivSettings::default()
        };
        let r = piv(a.view(), b.view(), None, &s).unwrap();
        let f = piv(af.view(), bf.view(), None, &s).unwrap();
        let (mut straddling, mut mean_u) = (0, 0.0);
        for ((j, i), &x) in f.x.indexed_iter() {
            let left = x - 15.5;
            let in_fill = (left + 32.0 - 150.0).clamp(0.0, 32.0) / 32.0;
            // blocks of 4 columns entirely in the fill are blank
            let blank = (0..8).filter(|k| left + 4.0 * *k as f64 >= 150.0).count() as f64 / 8.0;
            assert_eq!(f.valid[[j, i]], blank <= 0.25, "x {x}");
            if in_fill == 0.0 {
                assert_eq!(f.u[[j, i]], r.u[[j, i]]);
                assert_eq!(f.v[[j, i]], r.v[[j, i]]);
            } else if f.valid[[j, i]] {
                straddling += 1;
                mean_u += f.u[[j, i]];
            }
        }
        // not pulled towards 0 by the stationary fill edge; single-pass 32 x 32 vectors scatter
        // by up to 0.15 px, as the ones clear of the fill. (Correlated over 3/4 of their width
        // they keep part of the in-plane loss bias, which `find_peak`'s overlap correction
        // removes for the full width only: about -0.03 px at 1.5 px displacement.)
        let mean_u = mean_u / straddling as f64;
        assert!(
            straddling >= 4 && (mean_u - 1.5).abs() < 0.05,
            "{straddling} {mean_u}"
        );
        let (worst, n) = worst_valid(&f, d);
        assert!(n >= 20 && worst < 0.2, "{n} valid, worst {worst}");
        // piv_at at the same points: the same vectors
        let g = piv_at(
            af.view(),
            bf.view(),
            f.x.view(),
            f.y.view(),
            Predictor::Zero,
            None,
            &[(32, 32)],
            1,
            &s,
        )
        .unwrap();
        assert_eq!(g.valid, f.valid);
        assert_eq!(g.u, f.u);
        // with deformation: windows mostly in the fill flagged, the ones clear of it right
        // (those part-way in keep a bias of a few 0.01 px: in the deformed pair the fill edge
        // moves against the particles, see `signal_fraction`)
        let s = PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 32)],
            ..PivSettings::default()
        };
        let m = piv(af.view(), bf.view(), None, &s).unwrap();
        let mut clear = m.clone();
        for ((j, i), &x) in m.x.indexed_iter() {
            if x - 15.5 + 16.0 >= 150.0 {
                assert!(!m.valid[[j, i]], "x {x}");
            }
            clear.valid[[j, i]] = m.valid[[j, i]] && x + 16.0 <= 150.0;
        }
        let (worst, n) = worst_valid(&clear, d);
        assert!(n >= 40 && worst < 0.1, "{n} {worst}");
    }

    #[test]
    fn signal_fraction_rule() {
        let (w, h) = (16, 8);
        let mut scratch = FillScratch::new(w * h);
        let noise = |k: usize| ((k * 7919) % 97) as f32;
        let mut wa: Vec<f32> = (0..w * h).map(noise).collect();
        let mut wb: Vec<f32> = (0..w * h).map(|k| noise(k + 3)).collect();
        let (a0, b0) = (wa.clone(), wb.clone());
        // all signal: untouched
        assert_eq!(
            signal_fraction(&mut wa, &mut wb, &mut scratch, w, h, 0.0),
            1.0
        );
        assert_eq!((&wa, &wb), (&a0, &b0));
        // the right 5 columns zero in both (a fill cut by the 2 px blocks): two block columns
        // blank, the column next to them neutralised through equal values
        for r in 0..h {
            for c in 11..16 {
                wa[r * w + c] = 0.0;
                wb[r * w + c] = 0.0;
            }
        }
        let f = signal_fraction(&mut wa, &mut wb, &mut scratch, w, h, 0.0);
        assert_eq!(f, 0.75);
        let sig = |v: &[f32]| {
            (0..h)
                .flat_map(|r| (0..11).map(move |c| r * w + c))
                .map(|k| v[k] as f64)
                .sum::<f64>()
                / (11 * h) as f64
        };
        let (ma, mb) = (sig(&a0), sig(&b0));
        for r in 0..h {
            for c in 0..w {
                let k = r * w + c;
                if c >= 11 {
                    assert!((wa[k] as f64 - ma).abs() < 1e-3 && (wb[k] as f64 - mb).abs() < 1e-3);
                } else {
                    assert_eq!((wa[k], wb[k]), (a0[k], b0[k]));
                }
            }
        }
        // half blank: not correlated
        for r in 0..h {
            wa[r * w..r * w + 8].fill(5.0);
        }
        assert!(signal_fraction(&mut wa, &mut wb, &mut scratch, w, h, 0.0) < MIN_SIGNAL_FRACTION);
        // a sample outside the frame: not correlated
        let (mut wa, mut wb) = (a0.clone(), b0.clone());
        wb[17] = f32::NAN;
        assert_eq!(
            signal_fraction(&mut wa, &mut wb, &mut scratch, w, h, 0.0),
            0.0
        );
    }

    #[test]
    fn quintic_deformation_leaves_less_interpolation_bias_than_cubic() {
        // d/2 = 0.25 px: the worst case of the interpolation bias
        let d = |_: f64, _: f64| (0.5, 0.5);
        let (a, b) = pair(192, 192, d);
        let mut bias = vec![];
        for interpolation in [Interpolation::BSpline, Interpolation::BSpline3] {
            let s = PivSettings {
                passes: vec![Pass::new(64, 64), Pass::new(32, 32)],
                interpolation,
                ..PivSettings::default()
            };
            let f = piv(a.view(), b.view(), None, &s).unwrap();
            let n = f.u.len() as f64;
            let bu = f.u.iter().map(|u| u - 0.5).sum::<f64>() / n;
            let bv = f.v.iter().map(|v| v - 0.5).sum::<f64>() / n;
            bias.push(bu.abs().max(bv.abs()));
        }
        assert!(bias[0] < 0.01 && bias[0] < 0.6 * bias[1], "{bias:?}");
    }

    /// The field predictor's first correlation reads the windows from the pair deformed once
    /// (a common sub-pixel shift of both windows): as accurate against the truth as sampling
    /// each deformed window on its own, with the same outside-the-image rule in the interior.
    #[test]
    fn field_predictor_on_the_deformed_pair_matches_per_window_sampling() {
        let d = |x: f64, y: f64| (5.3 + 0.01 * y, -2.7 + 0.008 * x);
        let (a, b) = pair(160, 240, d);
        let grid = Grid::for_windows(240, 160, 16, 16, 0.5).unwrap();
        let field = GridField {
            grid,
            u: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let (x, y) = grid.xy(j, i);
                d(x, y).0
            }),
            v: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let (x, y) = grid.xy(j, i);
                d(x, y).1
            }),
        };
        let x = Array2::from_shape_fn((12, 10), |(j, i)| 30.37 + 19.1 * i as f64 + 0.13 * j as f64);
        let y = Array2::from_shape_fn((12, 10), |(j, i)| 20.71 + 10.3 * j as f64 - 0.21 * i as f64);
        let s = PivSettings::default();
        let fast = piv_at(
            a.view(),
            b.view(),
            x.view(),
            y.view(),
            Predictor::Field(&field),
            None,
            &[(32, 8)],
            1,
            &s,
        )
        .unwrap();
        // the per-window sampler on the same points
        let frames = Frames::new(a.view(), b.view(), Interpolation::BSpline).unwrap();
        let (xs, ys): (Vec<f64>, Vec<f64>) =
            (x.iter().copied().collect(), y.iter().copied().collect());
        let n = xs.len();
        let zeros = vec![0.0; n];
        let skip = vec![false; n];
        let peaks = frames.sweep(
            32,
            8,
            &xs,
            &ys,
            &zeros,
            &zeros,
            &skip,
            Some(&field),
            s.subpixel,
        );
        let (mut e_fast, mut e_slow, mut diff, mut m) = (0.0, 0.0, 0.0f64, 0);
        for k in 0..n {
            let (tu, tv) = d(xs[k], ys[k]);
            let (bu, bv) = field.at(xs[k], ys[k]);
            let (fu, fv) = (fast.u.as_slice().unwrap()[k], fast.v.as_slice().unwrap()[k]);
            assert_eq!(fast.valid.as_slice().unwrap()[k], peaks[k].ok, "point {k}");
            if !peaks[k].ok {
                continue;
            }
            let (su, sv) = (bu + peaks[k].dx, bv + peaks[k].dy);
            e_fast += (fu - tu).powi(2) + (fv - tv).powi(2);
            e_slow += (su - tu).powi(2) + (sv - tv).powi(2);
            diff = diff.max((fu - su).abs().max((fv - sv).abs()));
            m += 1;
        }
        let (e_fast, e_slow) = ((e_fast / m as f64).sqrt(), (e_slow / m as f64).sqrt());
        println!("rms fast {e_fast} per-window {e_slow}; largest difference {diff}; {m} valid");
        assert!(m > 100, "{m}");
        assert!(
            e_fast < 0.05 && e_fast < 1.2 * e_slow + 0.005,
            "{e_fast} vs {e_slow}"
        );
        assert!(diff < 0.05, "largest difference {diff}");
    }

    #[test]
    fn mask_and_bad_input() {
        let (a, b) = pair(96, 96, |_, _| (1.0, 0.0));
        let mut mask = Array2::from_elem((96, 96), false);
        mask.slice_mut(ndarray::s![.., ..40]).fill(true);
        let mut s = PivSettings {
            passes: vec![Pass::new(32, 32)],
            ..PivSettings::default()
        };
        let f = piv(a.view(), b.view(), Some(mask.view()), &s).unwrap();
        for ((x, m), u) in f.x.iter().zip(&f.masked).zip(&f.u) {
            assert_eq!(*m, x.round() < 40.0);
            assert_eq!(u.is_nan(), *m);
        }
        let small = Array2::<u16>::zeros((96, 90));
        assert!(piv(a.view(), small.view(), None, &s).is_err());
        s.passes = vec![Pass::new(128, 32)];
        let e = piv(a.view(), b.view(), None, &s).unwrap_err();
        assert!(e.to_string().contains("larger than the image"), "{e}");
    }
}
