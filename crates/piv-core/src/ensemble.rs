//! Ensemble correlation (Delnoij et al. 1999; Meinhart, Wereley & Santiago 2000): the
//! correlation planes of many frame pairs summed window by window before the peak is found, so
//! that windows far too small (or too thin) for one pair still give the mean displacement, and
//! the shape of the summed peak gives the displacement's probability density, hence the
//! Reynolds stresses (Scharnowski, Hain & Kähler 2012, Exp. Fluids 52).
//!
//! # The accumulator
//!
//! For `n` windows (`w` x `h` px, w along x) at points `(x, y)` (pixel frame), each offset
//! symmetrically by `(du, dv)` (the mean displacement predictor: frame A sampled at
//! `p - d/2`, frame B at `p + d/2`, interpolated as [`Interpolation`] says), [`accumulate`]
//! adds, for one pair, to each window's row of the accumulator ([`Layout`], f64):
//! - the normalised cross-correlation plane of the pair's window (the plane of
//!   [`Correlator::plane`]: lags `-sx-1 ..= sx+1` by `-sy-1 ..= sy+1`, `sx = max(w/2 - 1, 1)`),
//!   so every pair counts alike whatever its brightness;
//! - optionally the auto-correlation planes of frame A's and frame B's windows (the particle
//!   image's own correlation, whose width the cross peak carries on top of the displacement
//!   spread; both frames, because interpolation at their two fractional offsets smooths them
//!   differently and the cross peak carries one of each);
//! - the number of planes added to each.
//!
//! Windows whose centre is masked or outside the image, whose samples reach outside the image,
//! or that are blank (the rules of [`crate::multipass`]) are not added. The accumulator is a
//! plain sum: two accumulators of the same windows merge by adding them (shards, workers), and
//! the result does not depend on the order of the pairs beyond f64 rounding.
//!
//! # The result
//!
//! [`peaks`] divides each sum by its count and fits the peak: the integer maximum of the
//! cross plane within the search range, the plane divided by the windows' overlap fraction at
//! each lag (as [`crate::correlate::find_peak`]), a weighted least-squares 2D Gaussian on
//! `ln R` over the 5 x 5 lags around it (values above 2 % of the peak; weights `R^2`) as the
//! start of a Gaussian-on-a-constant-baseline fit to the whole plane (the baseline is the dip
//! that per-window mean removal leaves). Its centre is the mean displacement (residual to the
//! offset), its covariance `C` the peak's. The auto peak is fitted alike around lag 0. The zero
//! lag is left out of both fits: the camera noise correlates with itself there in the auto
//! planes, and the same estimator on both planes keeps their shape errors alike (a Gaussian is
//! not the exact shape of a pixel-integrated particle's correlation: on pairs without any
//! displacement spread `C_cross - C_auto` is 0.00-0.03 px^2 instead of 0). The displacement
//! covariance within the window is `C_cross - C_auto` (px^2): the cross peak is the auto peak
//! convolved with the displacement PDF. It still holds the spread of the mean displacement
//! over the window (a gradient `J` adds `J diag(w^2, h^2) J^T / 12`), which the caller removes
//! with the mean field's gradient.
//!
//! Accuracy on pairs moved as a whole by Gaussian random displacements (the unit test): the
//! mean within 0.012 px, the covariances within 13 % (16 x 4 px windows; 9 % at 32 x 16). Summed
//! over whole rows of windows (the Python face's `result(rows=True)`, a boundary layer's
//! streamwise homogeneity) the near-wall mean and stresses meet the synthetic boundary layer's
//! exact statistics (`rspiv.ensemble`); single-pixel ensemble correlation is
//! [`crate::ensemble_pixel`].

use crate::correlate::Correlator;
use crate::error::{PivError, Result};
use crate::image::{GridField, Pixel};
use crate::multipass::{check_mask, check_pair, excluded_point, Frames, Interpolation};
use ndarray::ArrayView2;
use rayon::prelude::*;

/// The row of one window in the accumulator: `cross[cw * ch]`, `auto[cw * ch]`, `n_cross`,
/// `n_auto` (all f64).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// Plane width (lags along x) and height.
    pub cw: usize,
    pub ch: usize,
}

impl Layout {
    /// The layout for `w` x `h` windows.
    pub fn new(w: usize, h: usize) -> Layout {
        let (cw, ch) = Correlator::plane_shape(w, h);
        Layout { cw, ch }
    }

    /// Values per window.
    pub fn stride(&self) -> usize {
        2 * self.cw * self.ch + 2
    }
}

/// The windows of an ensemble: size, centres and offsets (one per window).
#[derive(Debug, Clone, Copy)]
pub struct Windows<'a> {
    pub w: usize,
    pub h: usize,
    pub x: &'a [f64],
    pub y: &'a [f64],
    pub du: &'a [f64],
    pub dv: &'a [f64],
}

impl Windows<'_> {
    /// Windows of at least 2 x 2 px; centres and offsets of one length, finite.
    pub fn check(&self) -> Result<()> {
        if self.w < 2 || self.h < 2 {
            return Err(PivError::InvalidInput(format!(
                "ensemble window {} x {} px is too small (at least 2 x 2)",
                self.w, self.h
            )));
        }
        let n = self.x.len();
        if self.y.len() != n || self.du.len() != n || self.dv.len() != n {
            return Err(PivError::InvalidInput(format!(
                "ensemble windows: x ({}), y ({}), du ({}) and dv ({}) differ in length",
                n,
                self.y.len(),
                self.du.len(),
                self.dv.len()
            )));
        }
        let all = self.x.iter().chain(self.y).chain(self.du).chain(self.dv);
        if all.into_iter().any(|v| !v.is_finite()) {
            return Err(PivError::InvalidInput(
                "ensemble windows: a centre or offset is NaN or infinite".into(),
            ));
        }
        Ok(())
    }
}

/// Add one frame pair to the accumulator `acc` (`n` rows of [`Layout::stride`]), every window
/// offset by its `(du, dv)` and, with `field`, deformed by that field (frame A sampled at
/// `p - (d + f(p))/2`, B at `p + (d + f(p))/2`: the mean field's variation inside the window
/// then does not widen the peak); the auto planes too when `auto`. Returns the number of windows added. Errors: frames of
/// different shapes or with NaN/inf, a mask of another shape, windows larger than the image,
/// bad windows ([`Windows::check`]), an accumulator of the wrong length.
pub fn accumulate<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    win: &Windows<'_>,
    field: Option<&GridField>,
    interpolation: Interpolation,
    auto: bool,
    acc: &mut [f64],
) -> Result<usize> {
    win.check()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    check_mask(&mask, dim)?;
    if win.w > dim.1 || win.h > dim.0 {
        return Err(PivError::InvalidInput(format!(
            "ensemble window {} x {} px (w x h) is larger than the image ({} x {} px)",
            win.w, win.h, dim.1, dim.0
        )));
    }
    let lay = Layout::new(win.w, win.h);
    let stride = lay.stride();
    let n = win.x.len();
    if acc.len() != n * stride {
        return Err(PivError::InvalidInput(format!(
            "ensemble accumulator holds {} values, {} windows of {} x {} need {}",
            acc.len(),
            n,
            win.w,
            win.h,
            n * stride
        )));
    }
    let skip: Vec<bool> = (0..n)
        .map(|k| excluded_point(&mask, dim, win.x[k], win.y[k]))
        .collect();
    let frames = Frames::new(frame_a, frame_b, interpolation)?;
    let np = lay.cw * lay.ch;
    let used = frames.sweep_into(
        win.w,
        win.h,
        (win.x, win.y),
        (win.du, win.dv),
        field,
        &skip,
        acc,
        stride,
        |c, row| {
            if !c.correlate_plane() {
                return;
            }
            let (cross, rest) = row.split_at_mut(np);
            for (o, &v) in cross.iter_mut().zip(c.plane().0) {
                *o += v as f64;
            }
            rest[np] += 1.0;
            if auto {
                // both frames' windows: interpolation at the two fractional offsets smooths
                // them differently, and the cross peak carries one of each
                c.cb.copy_from_slice(&c.wb);
                for pass in 0..2 {
                    if pass == 0 {
                        c.wb.copy_from_slice(&c.wa);
                    } else {
                        c.wa.copy_from_slice(&c.cb);
                        c.wb.copy_from_slice(&c.cb);
                    }
                    if c.correlate_plane() {
                        for (o, &v) in rest[..np].iter_mut().zip(c.plane().0) {
                            *o += v as f64;
                        }
                        rest[np + 1] += 1.0;
                    }
                }
            }
        },
    );
    Ok(used)
}

/// The fitted ensemble peak of one window ([`peaks`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnsemblePeak {
    /// Mean displacement relative to the window's offset, px.
    pub dx: f64,
    pub dy: f64,
    /// Covariance `(xx, yy, xy)` of the cross-correlation peak, px^2.
    pub cross: (f64, f64, f64),
    /// Covariance of the auto-correlation peak (NaN without auto planes), px^2.
    pub auto: (f64, f64, f64),
    /// Centre `(x, y)` of the auto-correlation peak relative to the zero lag, px (NaN without
    /// auto planes): 0 where the particles are spread evenly about the window or row; next to a
    /// wall, the mean offset of the particles it sees (those beyond the wall are missing).
    pub auto_centre: (f64, f64),
    /// Height of the mean normalised cross plane at its integer maximum.
    pub coef: f64,
    /// The summed cross plane's clarity ([`peak_ratio`]; NaN when no plane was added).
    pub peak_ratio: f64,
    /// Planes summed (cross, auto).
    pub count: (f64, f64),
    /// The fit succeeded: planes added, a maximum inside the search range, a peak that is a
    /// Gaussian maximum (negative-definite curvature), and a clear one (`peak_ratio` at least
    /// [`MIN_PEAK_RATIO`]).
    pub ok: bool,
}

impl EnsemblePeak {
    const FAILED: EnsemblePeak = EnsemblePeak {
        dx: f64::NAN,
        dy: f64::NAN,
        cross: (f64::NAN, f64::NAN, f64::NAN),
        auto: (f64::NAN, f64::NAN, f64::NAN),
        auto_centre: (f64::NAN, f64::NAN),
        coef: 0.0,
        peak_ratio: f64::NAN,
        count: (0.0, 0.0),
        ok: false,
    };
}

/// Fit every window's summed planes in `acc` (see the module docs).
pub fn peaks(acc: &[f64], w: usize, h: usize) -> Result<Vec<EnsemblePeak>> {
    let lay = Layout::new(w, h);
    let stride = lay.stride();
    if acc.len() % stride != 0 {
        return Err(PivError::InvalidInput(format!(
            "ensemble accumulator of {} values is not whole rows of {} ({} x {} windows)",
            acc.len(),
            stride,
            w,
            h
        )));
    }
    Ok(acc
        .par_chunks(stride)
        .map(|row| fit_row(row, lay, w, h))
        .collect())
}

fn fit_row(row: &[f64], lay: Layout, w: usize, h: usize) -> EnsemblePeak {
    let (cw, ch) = (lay.cw, lay.ch);
    let np = cw * ch;
    let (nc, na) = (row[2 * np], row[2 * np + 1]);
    if nc <= 0.0 {
        return EnsemblePeak::FAILED;
    }
    let (hx, hy) = ((cw / 2) as f64, (ch / 2) as f64);
    // the mean plane divided by the overlap fraction at each lag
    let unbiased = |plane: &[f64], n: f64, c: usize, r: usize| {
        let ox = 1.0 - (c as f64 - hx).abs() / w as f64;
        let oy = 1.0 - (r as f64 - hy).abs() / h as f64;
        plane[r * cw + c] / n / (ox * oy)
    };
    let cross = &row[..np];
    // integer maximum inside the one-lag border
    let (mut pc, mut pr, mut best) = (0, 0, f64::NEG_INFINITY);
    for r in 1..ch - 1 {
        for c in 1..cw - 1 {
            let v = cross[r * cw + c];
            if v > best {
                (pc, pr, best) = (c, r, v);
            }
        }
    }
    let coef = best / nc;
    let ratio = peak_ratio(cross, cw);
    if ratio.is_nan() || ratio < MIN_PEAK_RATIO {
        return EnsemblePeak {
            coef,
            peak_ratio: ratio,
            count: (nc, na),
            ..EnsemblePeak::FAILED
        };
    }
    let Some((mx, my, cov)) =
        baseline_fit(|c, r| unbiased(cross, nc, c, r), cw, ch, (pc, pr), true)
    else {
        return EnsemblePeak {
            coef,
            peak_ratio: ratio,
            count: (nc, na),
            ..EnsemblePeak::FAILED
        };
    };
    let (auto_centre, auto) = if na > 0.0 {
        let plane = &row[np..2 * np];
        let centre = (cw / 2, ch / 2);
        split_fit(baseline_fit(
            |c, r| unbiased(plane, na, c, r),
            cw,
            ch,
            centre,
            true,
        ))
    } else {
        split_fit(None)
    };
    EnsemblePeak {
        dx: pc as f64 - hx + mx,
        dy: pr as f64 - hy + my,
        cross: cov,
        auto,
        auto_centre,
        coef,
        peak_ratio: ratio,
        count: (nc, na),
        ok: true,
    }
}

/// A summed cross peak must stand this many times above its plane's next local maximum
/// ([`peak_ratio`]) to count: measured on synthetic particle pairs 23 or more for 64 x 4 px
/// windows of 60 pairs, 3.1 or more for 32 x 8 px windows of 2 pairs, 21 or more for
/// single-pixel rows of 40 pairs; at most 2.3 for frames of noise alone (1-100 pairs).
pub const MIN_PEAK_RATIO: f64 = 3.0;

/// The primary peak ratio of a summed plane (`cw` columns, row-major): its highest strict
/// local maximum (over the 8 neighbours inside the plane) over the next highest, both less the
/// plane's median; infinite with a single local maximum above the median, NaN for a plane
/// without values.
pub fn peak_ratio(plane: &[f64], cw: usize) -> f64 {
    let ch = plane.len().checked_div(cw).unwrap_or(0);
    if ch == 0 {
        return f64::NAN;
    }
    let mut sorted = plane.to_vec();
    sorted.sort_unstable_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let (mut first, mut second) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    for r in 0..ch {
        for c in 0..cw {
            let v = plane[r * cw + c];
            let local = (r.saturating_sub(1)..(r + 2).min(ch)).all(|j| {
                (c.saturating_sub(1)..(c + 2).min(cw))
                    .all(|i| (j == r && i == c) || v > plane[j * cw + i])
            });
            if local {
                let a = v - median;
                if a > first {
                    (first, second) = (a, first);
                } else if a > second {
                    second = a;
                }
            }
        }
    }
    if second > 0.0 {
        first / second
    } else {
        f64::INFINITY
    }
}

/// A peak fit's centre and covariance apart, NaN for a failed fit.
pub(crate) fn split_fit(fit: Option<(f64, f64, (f64, f64, f64))>) -> ((f64, f64), (f64, f64, f64)) {
    fit.map_or(
        ((f64::NAN, f64::NAN), (f64::NAN, f64::NAN, f64::NAN)),
        |(x, y, cv)| ((x, y), cv),
    )
}

/// Weighted least-squares fit of `ln R = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2` over the
/// lags within 2 of `(pc, pr)` (inside the plane) whose value exceeds 2 % of the centre's,
/// weights `R^2` (the variance of `ln R` goes as `1 / R^2`); the centre value is left out when
/// `skip_centre`. Returns the Gaussian's centre relative to `(pc, pr)` and its covariance
/// `(xx, yy, xy)`, or `None` when too few values or the curvature is not negative definite.
fn gauss_fit(
    at: &impl Fn(usize, usize) -> f64,
    cw: usize,
    ch: usize,
    (pc, pr): (usize, usize),
    skip_centre: bool,
) -> Option<(f64, f64, (f64, f64, f64))> {
    let top = if skip_centre {
        // the largest neighbour stands for the (noise-free) height
        let mut m = f64::NEG_INFINITY;
        for (dc, dr) in [(-1isize, 0isize), (1, 0), (0, -1), (0, 1)] {
            let (c, r) = (pc as isize + dc, pr as isize + dr);
            if c >= 0 && r >= 0 && (c as usize) < cw && (r as usize) < ch {
                m = m.max(at(c as usize, r as usize));
            }
        }
        m
    } else {
        at(pc, pr)
    };
    if top.is_nan() || top <= 0.0 {
        return None;
    }
    let mut ata = [[0.0f64; 6]; 6];
    let mut atb = [0.0f64; 6];
    let mut used = 0;
    for dr in -2isize..=2 {
        for dc in -2isize..=2 {
            let (c, r) = (pc as isize + dc, pr as isize + dr);
            if c < 0 || r < 0 || c as usize >= cw || r as usize >= ch {
                continue;
            }
            if skip_centre && dc == 0 && dr == 0 {
                continue;
            }
            let v = at(c as usize, r as usize);
            if v.is_nan() || v <= 0.02 * top {
                continue;
            }
            let (x, y) = (dc as f64, dr as f64);
            let basis = [1.0, x, y, x * x, x * y, y * y];
            let wt = (v / top) * (v / top);
            let l = v.ln();
            for i in 0..6 {
                for j in 0..6 {
                    ata[i][j] += wt * basis[i] * basis[j];
                }
                atb[i] += wt * basis[i] * l;
            }
            used += 1;
        }
    }
    if used < 6 {
        return None;
    }
    let c = solve(ata, atb)?;
    // ln R = -1/2 (p - m)^T S^-1 (p - m) + const: S^-1 = -[[2 c3, c4], [c4, 2 c5]]
    let (a, b, d) = (-2.0 * c[3], -c[4], -2.0 * c[5]);
    let det = a * d - b * b;
    if !(a > 0.0 && det > 0.0) {
        return None;
    }
    let (sxx, syy, sxy) = (d / det, a / det, -b / det);
    // the centre: S (c1, c2)
    let (mx, my) = (sxx * c[1] + sxy * c[2], sxy * c[1] + syy * c[2]);
    if !(mx.abs() <= 2.0 && my.abs() <= 2.0) {
        return None;
    }
    Some((mx, my, (sxx, syy, sxy)))
}

/// The Gaussian on a constant baseline, `R = B + A exp(-q / 2)` with `q = (p - m)^T P (p - m)`,
/// fitted by Gauss-Newton (Levenberg-damped) to every lag of the plane (the zero lag left out
/// when `skip_centre`), started from [`gauss_fit`] with `B = 0`. The baseline is the
/// windows' mean removal: a window's own mean takes the peak's share of the signal with it, a
/// constant dip of about `peak volume / window area` that a log fit without it reads as a
/// narrower peak (-20 % of the variance in 16 x 4 px windows). Returns the centre relative to
/// `(pc, pr)` and the covariance `P^-1`; the log fit's result if the refinement fails.
pub(crate) fn baseline_fit(
    at: impl Fn(usize, usize) -> f64,
    cw: usize,
    ch: usize,
    (pc, pr): (usize, usize),
    skip_centre: bool,
) -> Option<(f64, f64, (f64, f64, f64))> {
    let start = gauss_fit(&at, cw, ch, (pc, pr), skip_centre)?;
    let (mx, my, (sxx, syy, sxy)) = start;
    let det = sxx * syy - sxy * sxy;
    // parameters: A, mx, my, Pxx, Pyy, Pxy, B
    let amp = {
        let v = at(pc, pr);
        let n = if skip_centre {
            at((pc + 1).min(cw - 1), pr)
        } else {
            v
        };
        n.max(1e-12)
    };
    let mut p = [amp, mx, my, syy / det, sxx / det, -sxy / det, 0.0];
    let model = |p: &[f64; 7], x: f64, y: f64| {
        let (dx, dy) = (x - p[1], y - p[2]);
        let q = p[3] * dx * dx + p[4] * dy * dy + 2.0 * p[5] * dx * dy;
        let e = (-0.5 * q).exp();
        (p[6] + p[0] * e, e, dx, dy)
    };
    let lags: Vec<(f64, f64, f64)> = (0..ch)
        .flat_map(|r| (0..cw).map(move |c| (c, r)))
        .filter(|&(c, r)| !(skip_centre && c == pc && r == pr))
        .map(|(c, r)| (c as f64 - pc as f64, r as f64 - pr as f64, at(c, r)))
        .filter(|t| t.2.is_finite())
        .collect();
    let cost = |p: &[f64; 7]| -> f64 {
        lags.iter()
            .map(|&(x, y, v)| (model(p, x, y).0 - v).powi(2))
            .sum()
    };
    let mut c0 = cost(&p);
    let mut lambda = 1e-3;
    for _ in 0..50 {
        let mut jtj = [[0.0f64; 7]; 7];
        let mut jtr = [0.0f64; 7];
        for &(x, y, v) in &lags {
            let (f, e, dx, dy) = model(&p, x, y);
            let ae = p[0] * e;
            let g = [
                e,
                ae * (p[3] * dx + p[5] * dy),
                ae * (p[4] * dy + p[5] * dx),
                -0.5 * ae * dx * dx,
                -0.5 * ae * dy * dy,
                -ae * dx * dy,
                1.0,
            ];
            let r = v - f;
            for i in 0..7 {
                for j in 0..7 {
                    jtj[i][j] += g[i] * g[j];
                }
                jtr[i] += g[i] * r;
            }
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut m = jtj;
            for (i, row) in m.iter_mut().enumerate() {
                row[i] *= 1.0 + lambda;
            }
            let Some(step) = solve(m, jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut q = p;
            for i in 0..7 {
                q[i] += step[i];
            }
            let c1 = cost(&q);
            if c1.is_finite() && c1 < c0 {
                let done = c0 - c1 <= 1e-12 * c0;
                (p, c0) = (q, c1);
                lambda = (lambda / 10.0).max(1e-9);
                improved = !done;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let (a, b, d) = (p[3], p[5], p[4]);
    let det = a * d - b * b;
    if !(p[0] > 0.0 && a > 0.0 && det > 0.0 && p[1].abs() <= 2.0 && p[2].abs() <= 2.0) {
        return Some(start);
    }
    Some((p[1], p[2], (d / det, a / det, -b / det)))
}

/// Solve the N x N system by Gaussian elimination with partial pivoting; `None` if
/// singular.
fn solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for col in 0..N {
        let piv = (col..N).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].is_nan() || a[piv][col].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in col + 1..N {
            let f = a[r][col] / a[col][col];
            for k in col..N {
                a[r][k] -= f * a[col][k];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = [0.0; N];
    for r in (0..N).rev() {
        let s: f64 = (r + 1..N).map(|k| a[r][k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render_particles;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// A 2D Gaussian sampled on the lags is fitted exactly.
    #[test]
    fn gaussian_fit_is_exact_on_a_gaussian() {
        let (cw, ch) = (15, 9);
        let (mx, my, sxx, syy, sxy) = (0.3, -0.2, 1.7, 0.9, 0.4);
        let det = sxx * syy - sxy * sxy;
        let g = |c: usize, r: usize| {
            let (x, y) = (c as f64 - 7.0 - mx, r as f64 - 4.0 - my);
            let q = (syy * x * x - 2.0 * sxy * x * y + sxx * y * y) / det;
            (-0.5 * q).exp()
        };
        let (x, y, cov) = gauss_fit(&g, cw, ch, (7, 4), false).unwrap();
        assert!((x - mx).abs() < 1e-9 && (y - my).abs() < 1e-9, "{x} {y}");
        assert!((cov.0 - sxx).abs() < 1e-9 && (cov.1 - syy).abs() < 1e-9);
        assert!((cov.2 - sxy).abs() < 1e-9, "{cov:?}");
        let (_, _, cov) = gauss_fit(&g, cw, ch, (7, 4), true).unwrap();
        assert!((cov.0 - sxx).abs() < 1e-9 && (cov.2 - sxy).abs() < 1e-9);
        // on a baseline, without the centre: the refined fit recovers the Gaussian
        let gb = |c: usize, r: usize| g(c, r) - 0.08;
        let (x, _, cov) = baseline_fit(gb, cw, ch, (7, 4), true).unwrap();
        assert!(
            (x - mx).abs() < 1e-6 && (cov.0 - sxx).abs() < 1e-6 && (cov.2 - sxy).abs() < 1e-6,
            "{cov:?}"
        );
    }

    /// Pairs moved as a whole by Gaussian random displacements: the ensemble gives their mean
    /// and covariance (cross minus auto) where one pair's 16 x 4 window cannot.
    #[test]
    fn mean_and_covariance_of_random_uniform_displacements() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (h, w) = (64usize, 96usize);
        let (mu, mv, su, sv, rho) = (1.3, -0.4, 0.6, 0.35, -0.5);
        let nu = Normal::new(0.0, 1.0).unwrap();
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..5)
            .flat_map(|j| (0..7).map(move |i| (16.0 + 10.0 * i as f64, 12.0 + 10.0 * j as f64)))
            .unzip();
        let n = xs.len();
        let (du, dv) = (vec![mu; n], vec![mv; n]);
        let (ww, wh) = (16, 4);
        let win = Windows {
            w: ww,
            h: wh,
            x: &xs,
            y: &ys,
            du: &du,
            dv: &dv,
        };
        let stride = Layout::new(ww, wh).stride();
        let mut acc = vec![0.0; n * stride];
        let (mut s1, mut s2, mut s11, mut s22, mut s12) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let pairs = 400;
        for k in 0..pairs {
            let (g1, g2): (f64, f64) = (nu.sample(&mut rng), nu.sample(&mut rng));
            let (u, v) = (
                mu + su * g1,
                mv + sv * (rho * g1 + (1.0 - rho * rho).sqrt() * g2),
            );
            (s1, s2) = (s1 + u, s2 + v);
            (s11, s22, s12) = (s11 + u * u, s22 + v * v, s12 + u * v);
            let np = (0.04 * ((h + 20) * (w + 20)) as f64) as usize;
            let (mut xa, mut ya, mut xb, mut yb, mut it) = (vec![], vec![], vec![], vec![], vec![]);
            for _ in 0..np {
                let x = rng.random::<f64>() * (w + 20) as f64 - 10.0;
                let y = rng.random::<f64>() * (h + 20) as f64 - 10.0;
                xa.push(x - u / 2.0);
                ya.push(y - v / 2.0);
                xb.push(x + u / 2.0);
                yb.push(y + v / 2.0);
                it.push(2000.0 + 1000.0 * rng.random::<f64>());
            }
            let a = render_particles(h, w, &xa, &ya, &it, &[2.5], 40.0, 4095, 2 * k).unwrap();
            let b = render_particles(h, w, &xb, &yb, &it, &[2.5], 40.0, 4095, 2 * k + 1).unwrap();
            let used = accumulate(
                a.view(),
                b.view(),
                None,
                &win,
                None,
                Interpolation::BSpline,
                k < 100,
                &mut acc,
            )
            .unwrap();
            assert_eq!(used, n);
        }
        let m = pairs as f64;
        let (eu, ev) = (s1 / m, s2 / m);
        let cuu = s11 / m - eu * eu;
        let cvv = s22 / m - ev * ev;
        let cuv = s12 / m - eu * ev;
        let res = peaks(&acc, ww, wh).unwrap();
        let (mut gu, mut gv, mut guu, mut gvv, mut guv) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for p in &res {
            assert!(p.ok && p.count == (pairs as f64, 200.0), "{p:?}");
            gu += mu + p.dx;
            gv += mv + p.dy;
            guu += p.cross.0 - p.auto.0;
            gvv += p.cross.1 - p.auto.1;
            guv += p.cross.2 - p.auto.2;
        }
        let k = res.len() as f64;
        let (gu, gv, guu, gvv, guv) = (gu / k, gv / k, guu / k, gvv / k, guv / k);
        println!("mean {gu:.4} {gv:.4} vs {eu:.4} {ev:.4}; cov {guu:.4} {gvv:.4} {guv:.4} vs {cuu:.4} {cvv:.4} {cuv:.4}");
        // measured: mean within 0.012 px; covariances -13 %, -0.5 %, -13 % (16 x 4 windows;
        // -9 %, +6 %, -5 % at 32 x 16): the Gaussian fit's shape error, not yet the 10 %
        // the near-wall stresses need (issue 13)
        assert!((gu - eu).abs() < 0.02 && (gv - ev).abs() < 0.02);
        assert!((guu / cuu - 1.0).abs() < 0.15, "uu {guu} vs {cuu}");
        assert!((gvv / cvv - 1.0).abs() < 0.1, "vv {gvv} vs {cvv}");
        assert!((guv / cuv - 1.0).abs() < 0.15, "uv {guv} vs {cuv}");
    }

    /// The primary peak ratio against hand-computed planes: two strict local maxima over the
    /// median; a plateau is no maximum; one maximum is infinitely clear; an empty plane NaN.
    #[test]
    fn peak_ratio_of_known_planes() {
        // 3 x 5, median 1: maxima 9 (centre) and 4 (a corner, two neighbours)
        #[rustfmt::skip]
        let plane = [
            4.0, 1.0, 1.0, 1.0, 1.0,
            1.0, 1.0, 9.0, 1.0, 1.0,
            0.0, 0.0, 1.0, 0.0, 0.0,
        ];
        assert_eq!(peak_ratio(&plane, 5), 8.0 / 3.0);
        let mut one = plane;
        one[0] = 1.0; // the corner no longer above its neighbours (a plateau of 1s)
        assert_eq!(peak_ratio(&one, 5), f64::INFINITY);
        assert!(peak_ratio(&[], 5).is_nan());
        assert!(peak_ratio(&plane, 5) < MIN_PEAK_RATIO); // two peaks this close: not clear
    }

    #[test]
    fn bad_input_is_one_line() {
        let a = ndarray::Array2::<u16>::zeros((32, 32));
        let (x, y, d) = ([16.0], [16.0], [0.0]);
        let mut win = Windows {
            w: 16,
            h: 1,
            x: &x,
            y: &y,
            du: &d,
            dv: &d,
        };
        let mut acc = vec![0.0; Layout::new(16, 4).stride()];
        let run = |win: &Windows<'_>, acc: &mut [f64]| {
            let e = accumulate(
                a.view(),
                a.view(),
                None,
                win,
                None,
                Interpolation::BSpline,
                false,
                acc,
            );
            e.unwrap_err().to_string()
        };
        assert!(run(&win, &mut acc).contains("too small"));
        win.h = 4;
        assert!(run(&win, &mut acc[1..]).contains("accumulator holds"));
        win.w = 64;
        assert!(run(&win, &mut acc).contains("larger than the image"));
    }
}
