//! The vector field of a PIV evaluation, its validation and replacement after every iteration,
//! and its assembly.

use super::settings::*;
use crate::correlate::Peak;
use crate::grid::Grid;
use crate::image::GridField;
use crate::validate::{median_test, neighbour_median, replace, residual};
use crate::weighting::Weighting;
use ndarray::{Array2, Axis};
use rayon::prelude::*;

/// A vector field. All arrays have the same shape (ny, nx).
#[derive(Debug, Clone)]
pub struct PivField {
    /// The regular grid of the vectors (`None` for [`super::piv_at`]).
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
    /// Standard uncertainty (one sigma) of `u` and `v`, px, of every valid vector from the
    /// statistics of its last correlation (Wieneke 2015, see
    /// [`crate::correlate::Correlator::uncertainty`]): the uncertainty of the peak the vector
    /// comes from, its variance pooled with its valid 3 x 3 neighbours' (`pooled`), widened by
    /// the chance that this peak is not the particles' ([`ambiguity_variance`]); NaN where the
    /// vector is not valid (replaced, masked) or the estimate has no maximum.
    pub sigma_u: Array2<f64>,
    pub sigma_v: Array2<f64>,
    /// Passed the final validation.
    pub valid: Array2<bool>,
    /// Rejected and replaced by interpolation from neighbours.
    pub replaced: Array2<bool>,
    /// The correlation peak a valid vector comes from: 1 the highest, 2 or 3 the second or
    /// third (the highest failed the median test, see `peak_candidates` in
    /// [`PivSettings`]); 0 where not from a peak (interpolated or masked).
    pub peak_choice: Array2<u8>,
    /// Not computed: inside the mask, or the centre outside the image.
    pub masked: Array2<bool>,
    /// The particle images' e^-2 diameter (px of the frames correlated, as recorded) along x
    /// and y, from the correlation peaks of the first pass
    /// ([`crate::particle_size::particle_diameter`]); NaN where not measured.
    pub particle_diameter: (f64, f64),
}

impl PivField {
    /// The part of a grid field whose first point is its point `(column, row)` = `at`, on
    /// `grid` (a grid of the same steps, inside this field's).
    pub fn cut(self, at: (usize, usize), grid: Grid) -> PivField {
        let s = ndarray::s![at.1..at.1 + grid.ny, at.0..at.0 + grid.nx];
        PivField {
            grid: Some(grid),
            x: self.x.slice(s).to_owned(),
            y: self.y.slice(s).to_owned(),
            u: self.u.slice(s).to_owned(),
            v: self.v.slice(s).to_owned(),
            peak_ratio: self.peak_ratio.slice(s).to_owned(),
            coef: self.coef.slice(s).to_owned(),
            sigma_u: self.sigma_u.slice(s).to_owned(),
            sigma_v: self.sigma_v.slice(s).to_owned(),
            valid: self.valid.slice(s).to_owned(),
            replaced: self.replaced.slice(s).to_owned(),
            peak_choice: self.peak_choice.slice(s).to_owned(),
            masked: self.masked.slice(s).to_owned(),
            particle_diameter: self.particle_diameter,
        }
    }

    /// The field moved by `(dx, dy)` px: its `x`, `y` and grid origin (a field computed on a
    /// crop whose pixel `(0, 0)` is the frame's `(dx, dy)`, put back in the frame's px).
    pub fn moved(mut self, dx: f64, dy: f64) -> PivField {
        self.x.mapv_inplace(|x| x + dx);
        self.y.mapv_inplace(|y| y + dy);
        if let Some(g) = &mut self.grid {
            g.x0 += dx;
            g.y0 += dy;
        }
        self
    }

    /// How the vectors that are not masked came about: `(first, second, third, interpolated)`
    /// = from the highest correlation peak, the second, the third, or replaced from their
    /// neighbours.
    pub fn peak_counts(&self) -> (usize, usize, usize, usize) {
        let mut n = [0usize; 4];
        for ((&c, &m), &r) in self
            .peak_choice
            .iter()
            .zip(&self.masked)
            .zip(&self.replaced)
        {
            match (m, r, c) {
                (true, _, _) => {}
                (false, true, _) => n[3] += 1,
                (false, false, 1..=3) => n[c as usize - 1] += 1,
                _ => {}
            }
        }
        (n[0], n[1], n[2], n[3])
    }

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

/// The outcome of [`validate_replace`].
pub(crate) struct Validation {
    pub valid: Array2<bool>,
    pub replaced: Array2<bool>,
    pub peak_choice: Array2<u8>,
}

/// The part of a vector that a deformed window reports of its deformation field: the field's
/// mean over the window, top-hat ([`GridField::window_mean_at`]) or weighted as the
/// correlation weighs the window's pixels ([`GridField::weighted_mean_at`], see
/// [`crate::weighting`]); the residual the window measures is the same mean of `true - d`,
/// so the vector is the window's mean of the true field whatever the deformation `d`.
pub(crate) struct WindowMean {
    w: usize,
    h: usize,
    weights: Option<(Vec<f64>, Vec<f64>)>,
}

impl WindowMean {
    pub(crate) fn new(w: usize, h: usize, weighting: Weighting) -> WindowMean {
        let weights = (weighting != Weighting::TopHat)
            .then(|| (weighting.pixel_weights(w), weighting.pixel_weights(h)));
        WindowMean { w, h, weights }
    }

    /// The mean of `f` over the window centred at `(x, y)`.
    pub(crate) fn at(&self, f: &GridField, x: f64, y: f64) -> (f64, f64) {
        match &self.weights {
            None => f.window_mean_at(x, y, self.w, self.h),
            Some((px, py)) => f.weighted_mean_at(x, y, px, py),
        }
    }
}

/// Under-relaxation of the extra iterations of a pass: the `k + 1`-th estimate is the `k`-th
/// moved by `RELAXATION` times its change, `x_{k+1} = x_k + RELAXATION (g(x_k) - x_k)`, where
/// `g(x_k)` is the validated field correlated with the windows deformed by `x_k` (`relax`).
///
/// The plain iteration `x_{k+1} = g(x_k)` converges, but alternately: its error about the fixed
/// point changes sign with a gain of about -0.27 (2048 x 1024 pair, 16 px: RMS 0.0452, 0.0441,
/// 0.0444, 0.0443, 0.0444 px for 1-5 iterations; the particle-weighted window mean of the
/// deformation field does not cancel the predictor's part exactly, see the module notes), so
/// the third iteration is worse than the second; at 8 px, where a few percent of the vectors
/// switch peaks from one iteration to the next, by 2-3 %. With a gain `-r` the relaxed error
/// about the fixed point is multiplied by `1 - RELAXATION (1 + r)` per iteration, 0.49 here:
/// no sign change, so each iteration is at least as accurate as the one before, and the extra
/// iterations average the peak switching out. Same pair, 1-4 iterations: 16 px 0.0452, 0.0447,
/// 0.0445, 0.0444; 12 px 0.0637, 0.0634, 0.0633, 0.0633; 8 px 0.1207, 0.1158, 0.1148, 0.1151;
/// 32 x 8 0.0454, 0.0449, 0.0446, 0.0446 (0.5 let the 8 px error rise again at the third
/// iteration on some seeds, 0.3 converges more slowly). The unrelaxed second iteration (0.0441
/// at 16 px) lies below the fixed point it alternates about: more iterations cannot keep that.
/// The spatial response is unchanged (a blend of fields with the top-hat response has it). The
/// first iteration of a pass (predictor from the coarser pass, another grid) is not relaxed.
pub const RELAXATION: f64 = 0.4;

/// `new = prev + RELAXATION (new - prev)`, element by element (see [`RELAXATION`]).
pub(crate) fn relax(new: &mut Array2<f64>, prev: &Array2<f64>) {
    new.zip_mut_with(prev, |a, &b| *a = b + RELAXATION * (*a - b));
}

/// `Array2::from_shape_fn(dim, f)` with the values computed in parallel (in the same places:
/// `f(j, i)` at row `j`, column `i`); for the per-vector arrays of a field, which read the
/// large `Peak` of every window (a 47 MP pair's last pass: 730,513 of them).
pub(crate) fn par_grid<T: Send>(
    dim: (usize, usize),
    f: impl Fn(usize, usize) -> T + Sync + Send,
) -> Array2<T> {
    let nx = dim.1.max(1);
    let v: Vec<T> = (0..dim.0 * dim.1)
        .into_par_iter()
        .map(|k| f(k / nx, k % nx))
        .collect();
    Array2::from_shape_vec(dim, v).expect("dim.0 * dim.1 values")
}

/// Validate (optionally), try the second and third peaks of rejected vectors, and replace the
/// rest from their neighbours. `u`, `v` hold each vector's primary peak (predictor + residual).
pub(crate) fn validate_replace(
    u: &mut Array2<f64>,
    v: &mut Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    s: &PivSettings,
) -> Validation {
    let dim = u.dim();
    let (u0, v0) = (&*u, &*v);
    let usable = par_grid(dim, |j, i| {
        let k = j * dim.1 + i;
        let p = &peaks[k];
        !skip[k]
            && p.ok
            && p.ratio >= s.min_peak_ratio
            && u0[[j, i]].is_finite()
            && v0[[j, i]].is_finite()
    });
    let mut peak_choice = usable.mapv(u8::from);
    let good = if s.validate {
        let mut usable = usable;
        let mut good;
        // the median test, then the other peaks of the rejected vectors (and of those whose
        // highest peak lies on the search border or under the peak-ratio threshold) against
        // the same neighbours; a vector recovered so is a neighbour in the next round, which
        // may reveal outliers that a cluster of them hid (at most 4 rounds)
        let mut round = 0;
        loop {
            let out = median_test(u, v, &usable, s.median_eps, s.median_threshold);
            good = Array2::from_shape_fn(dim, |ji| usable[ji] && !out[ji]);
            round += 1;
            if s.peak_candidates < 2 || round > 4 {
                break;
            }
            let mut alt = Vec::new();
            for ((j, i), g) in good.indexed_iter() {
                let k = j * dim.1 + i;
                let p = &peaks[k];
                if *g || skip[k] || peak_choice[[j, i]] > 1 {
                    continue;
                }
                if !(u[[j, i]].is_finite() && v[[j, i]].is_finite()) {
                    continue;
                }
                let (u0, v0) = (u[[j, i]] - p.dx, v[[j, i]] - p.dy);
                for (a, c) in p.alt.iter().take(s.peak_candidates - 1).zip(2u8..) {
                    if !a.exists() || a.coef <= 0.0 {
                        break;
                    }
                    let cand = (u0 + a.dx, v0 + a.dy);
                    match residual(u, v, &good, (j, i), cand, s.median_eps) {
                        Some(r) if r <= s.median_threshold => {
                            alt.push((j, i, cand, c));
                            break;
                        }
                        Some(_) => {}
                        None => break,
                    }
                }
            }
            if alt.is_empty() {
                break;
            }
            for (j, i, (cu, cv), c) in alt {
                u[[j, i]] = cu;
                v[[j, i]] = cv;
                usable[[j, i]] = true;
                peak_choice[[j, i]] = c;
            }
        }
        good
    } else {
        usable
    };
    replace(u, v, &good);
    let replaced = par_grid(dim, |j, i| !good[[j, i]] && !skip[j * dim.1 + i]);
    for (c, g) in peak_choice.iter_mut().zip(good.iter()) {
        if !g {
            *c = 0;
        }
    }
    Validation {
        valid: good,
        replaced,
        peak_choice,
    }
}

/// The uncertainties of the vectors that took their second or third correlation peak: the
/// final sweep estimates only the highest peak's ([`crate::correlate::Uncertainty::Peak`]: the
/// alternatives are rarely used and cost twice as much again), so the windows of those few
/// vectors (centres `xs`, `ys`, offsets `du`, `dv` of the sweep) are correlated once more
/// with [`crate::correlate::Uncertainty::AllPeaks`] by `again(x, y, du, dv, skip)` (the same
/// windows give the same peaks) and their alternatives' sigmas copied into `peaks`.
pub(crate) fn fill_alt_sigmas(
    peaks: &mut [Peak],
    checked: &Validation,
    (xs, ys, du, dv): (&[f64], &[f64], &[f64], &[f64]),
    again: impl FnOnce(&[f64], &[f64], &[f64], &[f64], &[bool]) -> Vec<Peak>,
) {
    let need: Vec<usize> = checked
        .peak_choice
        .iter()
        .zip(checked.valid.iter())
        .enumerate()
        .filter(|(_, (&c, &ok))| ok && c >= 2)
        .map(|(k, _)| k)
        .collect();
    if need.is_empty() {
        return;
    }
    let pick = |a: &[f64]| need.iter().map(|&k| a[k]).collect::<Vec<f64>>();
    let (x, y, u, v) = (pick(xs), pick(ys), pick(du), pick(dv));
    for (k, p) in need
        .iter()
        .zip(again(&x, &y, &u, &v, &vec![false; need.len()]))
    {
        for (mine, theirs) in peaks[*k].alt.iter_mut().zip(p.alt) {
            if mine.dx == theirs.dx && mine.dy == theirs.dy {
                mine.sigma = theirs.sigma;
            }
        }
    }
}

/// Chance that the highest correlation peak is not the particles' when it is `ratio` times
/// the second: `AMBIGUITY_SCALE * exp(-AMBIGUITY_RATE * (ratio - 1))`, at most 1.
pub const AMBIGUITY_SCALE: f64 = 0.8;
/// See [`AMBIGUITY_SCALE`].
pub const AMBIGUITY_RATE: f64 = 3.0;

/// The variance, px^2, that a possibly wrong peak adds to a vector's uncertainty (one
/// component): `p max(d^2, p s^2)`, with `p` the chance that the highest peak is a noise peak
/// at this peak `ratio` ([`AMBIGUITY_SCALE`], [`AMBIGUITY_RATE`]), `d` the vector's difference
/// from the median of its valid 3 x 3 neighbours (its error if the peak is wrong and the
/// neighbours right) and `s` the second peak's offset from the first (its error if the peak
/// is wrong and the second one right, which is likely only when the two are near equal:
/// hence the second `p`; overlapping windows of a sparse image share their particles and so
/// their wrong peaks, and the neighbours alone can agree with a wrong vector). Pass `s = 0`
/// where there is no second peak or the vector does not come from the highest.
///
/// Wieneke's estimate is the uncertainty of the peak's position; it says nothing of a window
/// whose highest peak is a chance alignment of unpaired particles (a sparse or noisy window
/// that passed the median test among noisy neighbours). The peak ratio tells how likely that
/// is (Charonko & Vlachos 2013, Meas. Sci. Technol. 24 065301). Measured on synthetic pairs
/// with exact truth (final windows 32 x 8 and 16 x 16, 0.01-0.05 ppp, 1.5-4 px, noise 0-10 %,
/// 0-0.05 px/px, 80,000 vectors): the fraction of vectors off by more than 0.5 px is 0.55-0.66
/// at ratios 1-1.2, 0.28-0.43 at 1.2-1.5, 0.07-0.09 at 1.5-2, 0.018 at 2-2.5 and 0.005 at
/// 2.5-3, which the two constants follow for both window shapes and two seeds. Vectors with a
/// ratio above 3 are hardly widened.
pub fn ambiguity_variance(ratio: f64, d: f64, second: f64) -> f64 {
    let p = (AMBIGUITY_SCALE * (-AMBIGUITY_RATE * (ratio - 1.0).max(0.0)).exp()).min(1.0);
    p * (d * d).max(p * second * second)
}

pub(crate) fn finish(
    grid: Option<Grid>,
    x: Array2<f64>,
    y: Array2<f64>,
    mut u: Array2<f64>,
    mut v: Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    particle_diameter: (f64, f64),
    Validation {
        valid,
        replaced,
        peak_choice,
    }: Validation,
) -> PivField {
    let dim = u.dim();
    let masked = par_grid(dim, |j, i| skip[j * dim.1 + i]);
    for ((uu, vv), &m) in u.iter_mut().zip(v.iter_mut()).zip(masked.iter()) {
        if m {
            *uu = f64::NAN;
            *vv = f64::NAN;
        }
    }
    let peak_ratio = par_grid(dim, |j, i| peaks[j * dim.1 + i].ratio);
    let coef = par_grid(dim, |j, i| peaks[j * dim.1 + i].coef);
    let sigma = |axis: usize| {
        par_grid(dim, |j, i| {
            let p = &peaks[j * dim.1 + i];
            let s = match (valid[[j, i]], peak_choice[[j, i]]) {
                (true, 1) => p.sigma,
                (true, 2) => p.alt[0].sigma,
                (true, 3) => p.alt[1].sigma,
                _ => (f64::NAN, f64::NAN),
            };
            if axis == 0 {
                s.0
            } else {
                s.1
            }
        })
    };
    let (mut sigma_u, mut sigma_v) = (pooled(&sigma(0)), pooled(&sigma(1)));
    // the wrong-peak variance, rows in parallel (each vector reads only the fields)
    let (u_, v_) = (&u, &v);
    sigma_u
        .axis_iter_mut(Axis(0))
        .into_par_iter()
        .zip(sigma_v.axis_iter_mut(Axis(0)))
        .enumerate()
        .for_each(|(j, (mut ru, mut rv))| {
            for (i, (su, sv)) in ru.iter_mut().zip(rv.iter_mut()).enumerate() {
                if !(su.is_finite() && sv.is_finite()) {
                    continue;
                }
                let p = &peaks[j * dim.1 + i];
                let (du, dv) = neighbour_median(u_, v_, &valid, (j, i))
                    .map_or((0.0, 0.0), |(mu, mv)| (u_[[j, i]] - mu, v_[[j, i]] - mv));
                let (au, av) = if peak_choice[[j, i]] == 1 && p.alt[0].exists() {
                    (p.alt[0].dx - p.dx, p.alt[0].dy - p.dy)
                } else {
                    (0.0, 0.0)
                };
                *su = (*su * *su + ambiguity_variance(p.ratio, du, au)).sqrt();
                *sv = (*sv * *sv + ambiguity_variance(p.ratio, dv, av)).sqrt();
            }
        });
    PivField {
        grid,
        x,
        y,
        u,
        v,
        peak_ratio,
        coef,
        sigma_u,
        sigma_v,
        valid,
        replaced,
        peak_choice,
        masked,
        particle_diameter,
    }
}

/// The per-vector uncertainties pooled over the 3 x 3 neighbourhood: `sqrt(mean sigma^2)` over
/// the finite ones (the vector's own included: the valid vectors); NaN stays NaN.
///
/// Wieneke's estimate of one window comes from the scatter of the contributions of its few
/// particle images (2.6 in a 32 x 8 window at 0.01 ppp, 8 in one at 0.03 ppp along its 8
/// rows): it scatters itself by tens of percent, and `error / sigma` then has heavier tails
/// than a normal distribution (at 32 x 8 only 59 % of the v errors within one sigma where
/// the RMS of sigma matched the errors' to 5-15 %). The neighbours' estimates measure the same
/// statistics (images, particle size, noise, gradients change over many windows): their mean
/// variance is the estimate with a fraction of that scatter. A vector's own wrong-peak chance
/// is added after ([`ambiguity_variance`]), not pooled.
fn pooled(sigma: &Array2<f64>) -> Array2<f64> {
    let (ny, nx) = sigma.dim();
    let mut out = Array2::from_elem((ny, nx), f64::NAN);
    // rows in parallel: each value reads only `sigma`
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(j, mut row)| {
            for (i, o) in row.iter_mut().enumerate() {
                if !sigma[[j, i]].is_finite() {
                    continue;
                }
                let (mut s2, mut n) = (0.0, 0usize);
                for jj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
                    for ii in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
                        let x = sigma[[jj, ii]];
                        if x.is_finite() {
                            s2 += x * x;
                            n += 1;
                        }
                    }
                }
                *o = (s2 / n as f64).sqrt();
            }
        });
    out
}
