//! Multigrid / multipass PIV (Willert & Gharib 1991; Soria 1996) on a regular grid
//! ([`piv`]) and at arbitrary image positions with given predictors ([`piv_at`]).
//!
//! Each pass correlates windows `w` px wide (along x) by `h` px tall (along y). From the second
//! pass on (and on every extra iteration of a pass) the windows follow the predictor, the
//! previous validated field interpolated bilinearly:
//! - [`Mode::Deform`]: symmetric image deformation; frame A is sampled at `p - d(p)/2` and frame
//!   B at `p + d(p)/2` with `d` the predictor at every pixel (cubic B-spline by default, Keys
//!   bicubic as an option, see [`Interpolation`]);
//! - [`Mode::Offset`]: symmetric sub-pixel window offset by the predictor at the window centre.
//!
//! On the regular grid of [`piv`] the deformation is applied to the whole frame pair once per
//! iteration (one interpolation per pixel) and the windows are copied from the deformed pair; at
//! arbitrary points ([`piv_at`]) each window is sampled on its own.
//!
//! After every iteration the vectors go through the normalised median test (and an optional
//! peak-ratio threshold); rejected ones are replaced from their neighbours. Vectors inside the
//! mask are neither computed nor used as neighbours; they are filled for the predictor only and
//! reported as NaN.
//!
//! Windows that cannot be correlated are never reported `valid`: a window of either frame that
//! is not entirely inside the image after its offset and deformation (the sample position of
//! every pixel in `[-0.5, width - 0.5] x [-0.5, height - 0.5]`; on the regular grid, a window
//! holding a deformed-frame pixel whose source lies outside the frame), and a window whose content has (near) zero variance in either frame
//! (zero fill of a dewarped frame, blank regions; see [`Correlator::correlate`]). Such vectors
//! get `valid = false`, `replaced = true` and a value interpolated from their valid neighbours
//! (used as the predictor of the next pass), `peak_ratio = coef = 0`.

use crate::correlate::{Correlator, Peak, SubPixel};
use crate::error::{PivError, Result};
use crate::grid::Grid;
use crate::image::{
    bspline_coeffs, bspline_weights, deform_pair, keys_weights, sample_pair, GridField, Img, Pixel,
    Source, WindowSpec,
};
use crate::validate::{median_test, replace};
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

/// How the windows follow the predictor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// Full symmetric image deformation (cubic interpolation, see [`Interpolation`]).
    #[default]
    Deform,
    /// Symmetric sub-pixel window offset.
    Offset,
}

/// Interpolation of the frames at the fractional positions of deformed or offset windows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Cubic B-spline on prefiltered coefficients (default): flat frequency response, no
    /// measurable sub-pixel bias on 2-3 px particles.
    #[default]
    BSpline,
    /// Keys cubic convolution (a = -0.5, 16 neighbours): cheaper to set up, but biases the
    /// residual displacement by a few hundredths of a pixel on small particles.
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
fn sweep<T: Pixel, U: Pixel>(
    src: &Source<'_, '_, '_, T, U>,
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
                c
            },
            |c, k| {
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
                if !sample_pair(src, w, h, &spec, wa, wb) {
                    // a window reaching past the image edge is not correlated
                    return Peak::FAILED;
                }
                c.correlate(sub)
            },
        )
        .collect()
}

/// The frames and their interpolants; `sweep` over them.
struct Frames<'a, T: Pixel> {
    a: Img<'a, T>,
    b: Img<'a, T>,
    coeffs: Option<(Img<'static, f32>, Img<'static, f32>)>,
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
        let coeffs = match interp {
            Interpolation::BSpline => Some((bspline_coeffs(&a), bspline_coeffs(&b))),
            Interpolation::Keys => None,
        };
        let floor = (BLANK_VARIANCE * frame_variance(&a).max(frame_variance(&b))) as f32;
        Ok(Frames {
            a,
            b,
            coeffs,
            floor,
        })
    }

    /// The frames deformed symmetrically by `f` (see [`deform_pair`]).
    fn deformed(&self, f: &GridField) -> Frames<'static, f32> {
        let (a, b) = match &self.coeffs {
            Some((ca, cb)) => deform_pair(ca, cb, bspline_weights, f),
            None => deform_pair(&self.a, &self.b, keys_weights, f),
        };
        Frames {
            a,
            b,
            coeffs: None,
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
        match &self.coeffs {
            Some((ca, cb)) => {
                let src = Source {
                    a: &self.a,
                    b: &self.b,
                    ia: ca,
                    ib: cb,
                    wf: bspline_weights,
                };
                sweep(&src, w, h, xs, ys, du, dv, skip, base, sub, self.floor)
            }
            None => {
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
    let grids = s
        .passes
        .iter()
        .map(|p| Grid::for_windows(dim.1, dim.0, p.w, p.h, p.overlap))
        .collect::<Result<Vec<_>>>()?;
    let frames = Frames::new(frame_a, frame_b, s.interpolation)?;
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
            .map(|(&x, &y)| excluded(&mask, dim, x, y))
            .collect();
        for _ in 0..pass.iterations {
            // predictor at the centres
            let (pu, pv): (Vec<f64>, Vec<f64>) = match &pred {
                Some(f) => xs.iter().zip(&ys).map(|(&x, &y)| f.at(x, y)).unzip(),
                None => (vec![0.0; n], vec![0.0; n]),
            };
            let zeros = vec![0.0; n];
            let (du, dv, base) = match s.mode {
                Mode::Deform => (&zeros, &zeros, pred.as_ref()),
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
    /// deformed by it (symmetric, cubic interpolation).
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
    check_mask(&mask, dim)?;
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
    let frames = Frames::new(frame_a, frame_b, settings.interpolation)?;
    let shape = x.dim();
    let n = x.len();
    let xs: Vec<f64> = x.iter().copied().collect();
    let ys: Vec<f64> = y.iter().copied().collect();
    let skip: Vec<bool> = xs
        .iter()
        .zip(&ys)
        .map(|(&x, &y)| excluded(&mask, dim, x, y))
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
    for &(w, h) in windows {
        for _ in 0..iterations {
            let peaks = frames.sweep(w, h, &xs, &ys, &du, &dv, &skip, base, settings.subpixel);
            let mut u = Array2::from_shape_fn(shape, |(j, i)| {
                let k = j * shape.1 + i;
                bu[k] + du[k] + peaks[k].dx
            });
            let mut v = Array2::from_shape_fn(shape, |(j, i)| {
                let k = j * shape.1 + i;
                bv[k] + dv[k] + peaks[k].dy
            });
            let (valid, replaced) = validate_replace(&mut u, &mut v, &peaks, &skip, &settings);
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
            // (windows straddling the fill edge are correlated: see `Correlator::correlate`)
        }
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
