//! The sub-pixel fit of one marker: a blob model plus a plane over a window of pixels, solved by
//! the project's Levenberg-Marquardt ([`crate::lm`]), with a heteroscedasticity-consistent
//! (sandwich) covariance of the centre.
//!
//! Parameters `p = [A, x0, y0, w, b0, bx, by, R, ax, ay]` (`R` only for discs, `ax, ay` only for
//! tilted discs); model `b0 + bx xw + by yw + A (1 + ax xw + ay yw) g(x, y)` with
//! `xw = (x - xc) / sc`, `yw = (y - yc) / sc` (the plane in window-normalised coordinates) and
//! the profile `g`:
//!
//! - [`Profile::Gauss`]: `exp(-(dx^2 + dy^2) / 2w^2)` (7 parameters);
//! - [`Profile::Cross`]: `max(exp(-dx^2 / 2w^2), exp(-dy^2 / 2w^2))`, the brighter of two
//!   perpendicular Gaussian bars (7 parameters);
//! - [`Profile::Disc`]: a disc of radius `R` blurred by a Gaussian of standard deviation `w`
//!   ([`super::disc`]; 8 parameters). It holds the Gaussian as its `R -> 0` limit and the flat
//!   top of a printed dot, so its residuals are noise, not misfit, and the sandwich covariance
//!   (built from the residuals) is then honest.
//! - [`Profile::DiscTilted`]: the disc under an illumination gradient: its flat top tilts with
//!   the light (`ax, ay`; 10 parameters) while its edges stay put, so the geometric centre is
//!   recovered free of the gradient's bias. Used for flat-topped discs only (radius >= 6 blur):
//!   on a Gaussian-like blob a tilt is a shift, and the two cannot be told apart.
//!
//! Residuals `model - sign * pixel`, row-major over the window `[ya, yb] x [xa, xb]`
//! (inclusive); for discs only its pixels within the window's half-width of its centre (the
//! square's corners are background that only costs time: ~21 % of the pixels).

use super::disc::DiscTable;
use crate::lm::{LeastSquaresProblem, LmConfig, LmSolver};
use image_core::Pixel;
use nalgebra::DMatrix;
use ndarray::ArrayView2;
use std::cell::RefCell;

/// The blob model of a fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Profile {
    Gauss,
    Cross,
    Disc,
    DiscTilted,
}

impl Profile {
    fn n_params(self) -> usize {
        match self {
            Profile::Gauss | Profile::Cross => 7,
            Profile::Disc => 8,
            Profile::DiscTilted => 10,
        }
    }

    fn is_disc(self) -> bool {
        matches!(self, Profile::Disc | Profile::DiscTilted)
    }
}

/// A converged, plausible fit.
pub(crate) struct FitOut {
    pub p: [f64; 10],
    /// Covariance of (x0, y0), px^2.
    pub cov: [[f64; 2]; 2],
    /// Gaussian fits: the flat-top score test statistic (`BlobProblem::flat_top_score`);
    /// 0 for the other profiles.
    pub flat_top: f64,
}

/// Per-worker scratch of [`fit_blob`]: the LM solver, a border buffer and the disc table, and
/// the evaluation budget of each fit (0: the LM default, `100 (n + 1)`).
#[derive(Default)]
pub(crate) struct BlobScratch {
    solver: LmSolver,
    border: Vec<f64>,
    table: DiscTable,
    pub max_evals: usize,
    /// Window half-width in units of `s` (at least 2.5, the default; beyond it at most 8 px
    /// more) and its cap in px (0: none; half the lattice pitch keeps the neighbours out of a
    /// dense lattice's fits).
    pub hw_factor: f64,
    pub max_hw: usize,
}

impl BlobScratch {
    /// Scratch whose fits give up after `max_evals` evaluations (the sample fits of the size
    /// and profile choice: a Gaussian converges in a few tens, a misfit is evidence enough).
    pub(crate) fn with_budget(max_evals: usize) -> Self {
        Self {
            max_evals,
            ..Self::default()
        }
    }

    /// Scratch whose windows never exceed `max_hw` px (0: no cap) and reach `hw_factor` s.
    pub(crate) fn windows(mut self, hw_factor: f64, max_hw: usize) -> Self {
        self.hw_factor = hw_factor;
        self.max_hw = max_hw;
        self
    }
}

struct BlobProblem<'a, T: Pixel> {
    img: ArrayView2<'a, T>,
    xa: usize,
    xb: usize,
    ya: usize,
    yb: usize,
    xc: f64,
    yc: f64,
    sc: f64,
    sign: f64,
    profile: Profile,
    table: RefCell<DiscTable>,
}

impl<T: Pixel> BlobProblem<'_, T> {
    /// A disc's window is the disc of radius `sc` about the window centre (the square's corners
    /// hold only background): row `y`'s columns `[a, b]` within the square.
    #[inline(always)]
    fn disc_row(&self, y: usize) -> (usize, usize) {
        let dy = y as f64 - self.yc;
        let half = (self.sc * self.sc - dy * dy).max(0.0).sqrt().floor();
        let a = (self.xc - half).max(self.xa as f64) as usize;
        let b = (self.xc + half).min(self.xb as f64) as usize;
        (a, b.max(a))
    }

    /// Calls `f(k, r_k, J_k)` for every pixel `k` of the window, with the residual and, if
    /// `want_jac`, its gradient `dr_k/dp` (zeros otherwise; the first `n_params` entries used).
    #[inline(always)]
    fn for_each_pixel(&self, p: &[f64], want_jac: bool, mut f: impl FnMut(usize, f64, &[f64; 10])) {
        let mut j = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let mut k = 0;
        if self.profile.is_disc() {
            let tilted = self.profile == Profile::DiscTilted;
            let (ax, ay) = if tilted { (p[8], p[9]) } else { (0.0, 0.0) };
            // The model is even in R and w: evaluate at |R|, |w| and flip the derivatives.
            let (radius, sr) = (p[7].abs(), p[7].signum());
            let (w, sw) = (p[3].abs().max(0.05), p[3].signum());
            let corner_x = (self.xa as f64 - p[1])
                .abs()
                .max((self.xb as f64 - p[1]).abs());
            let corner_y = (self.ya as f64 - p[2])
                .abs()
                .max((self.yb as f64 - p[2]).abs());
            let mut table = self.table.borrow_mut();
            table.ensure(radius, w, corner_x.hypot(corner_y) + 1.0);
            for y in self.ya..=self.yb {
                let dy = y as f64 - p[2];
                let yw = (y as f64 - self.yc) / self.sc;
                let (xa, xb) = self.disc_row(y);
                for x in xa..=xb {
                    let dx = x as f64 - p[1];
                    let rho = dx.hypot(dy);
                    let xw = (x as f64 - self.xc) / self.sc;
                    let t = 1.0 + ax * xw + ay * yw;
                    let at = p[0] * t;
                    let (g, slope_over_rho, d_r, d_w) = if want_jac {
                        table.value_and_slopes(rho)
                    } else {
                        (table.value(rho), 0.0, 0.0, 0.0)
                    };
                    let m = p[4] + p[5] * xw + p[6] * yw + at * g;
                    let r = m - self.sign * self.img[[y, x]].to_f64();
                    if want_jac {
                        j[0] = t * g;
                        // d/dx0 of P(|p - c|) = -(dP/drho / rho) dx.
                        j[1] = -at * slope_over_rho * dx;
                        j[2] = -at * slope_over_rho * dy;
                        j[3] = at * d_w * sw;
                        j[5] = xw;
                        j[6] = yw;
                        j[7] = at * d_r * sr;
                        if tilted {
                            j[8] = p[0] * g * xw;
                            j[9] = p[0] * g * yw;
                        }
                    }
                    f(k, r, &j);
                    k += 1;
                }
            }
            return;
        }
        let inv2 = 1.0 / (p[3] * p[3]);
        let cross = self.profile == Profile::Cross;
        for y in self.ya..=self.yb {
            let dy = y as f64 - p[2];
            let ey = (-0.5 * dy * dy * inv2).exp();
            let yw = (y as f64 - self.yc) / self.sc;
            for x in self.xa..=self.xb {
                let dx = x as f64 - p[1];
                let ex = (-0.5 * dx * dx * inv2).exp();
                // Dot: g = ex ey. Cross (inside its arms): the brighter of the two bars,
                // g = max(ex, ey); (gx, gy) select the centre derivatives.
                let (g, gx, gy) = if !cross {
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

    /// `J^T J`, the sandwich's meat `sum r_k^2 J_k^T J_k` and the sum of squared residuals.
    fn jtj_meat_ssr(&self, p: &[f64]) -> (DMatrix<f64>, DMatrix<f64>, f64) {
        let n = self.profile.n_params();
        let mut jtj = DMatrix::<f64>::zeros(n, n);
        let mut meat = DMatrix::<f64>::zeros(n, n);
        let mut ssr = 0.0;
        self.for_each_pixel(p, true, |_, r, j| {
            let r2 = r * r;
            ssr += r2;
            for a in 0..n {
                for b in 0..=a {
                    let jj = j[a] * j[b];
                    jtj[(a, b)] += jj;
                    meat[(a, b)] += r2 * jj;
                }
            }
        });
        jtj.fill_upper_triangle_with_lower_triangle();
        meat.fill_upper_triangle_with_lower_triangle();
        (jtj, meat, ssr)
    }
}

impl<T: Pixel> BlobProblem<'_, T> {
    /// Score test of a Gaussian fit against a flat-topped (disc) profile: with
    /// `z = g t^2`, `t = rho^2 / 2w^2` (the shape a disc adds to a Gaussian beyond a change of
    /// width, its `R^4` term), `T = (r . z)^2 / (s^2 |z_perp|^2)` where `z_perp` is `z` with
    /// its projection on the Jacobian's columns removed and `s^2 = SSR / (n - 7)`. Under a
    /// Gaussian profile `T` follows a chi-square of one degree of freedom.
    fn flat_top_score(&self, p: &[f64]) -> f64 {
        let inv2 = 1.0 / (p[3] * p[3]);
        let mut jtj = DMatrix::<f64>::zeros(7, 7);
        let mut jtz = DMatrix::<f64>::zeros(7, 1);
        let (mut ztz, mut rtz, mut ssr, mut n) = (0.0, 0.0, 0.0, 0.0f64);
        let width = self.xb - self.xa + 1;
        self.for_each_pixel(p, true, |k, r, j| {
            // j[0] is g for the Gaussian; pixel k of the (square) window is row-major.
            let g = j[0];
            let dx = (self.xa + k % width) as f64 - p[1];
            let dy = (self.ya + k / width) as f64 - p[2];
            let t = 0.5 * (dx * dx + dy * dy) * inv2;
            let z = g * t * t;
            for a in 0..7 {
                jtz[a] += j[a] * z;
                for b in 0..=a {
                    jtj[(a, b)] += j[a] * j[b];
                }
            }
            ztz += z * z;
            rtz += r * z;
            ssr += r * r;
            n += 1.0;
        });
        jtj.fill_upper_triangle_with_lower_triangle();
        let Some(inv) = jtj.try_inverse() else {
            return f64::INFINITY;
        };
        let zperp2 = ztz - (jtz.transpose() * inv * &jtz)[(0, 0)];
        let s2 = ssr / (n - 7.0).max(1.0);
        if !(zperp2 > 0.0 && s2 > 0.0) {
            return 0.0;
        }
        rtz * rtz / (s2 * zperp2)
    }
}

impl<T: Pixel> LeastSquaresProblem for BlobProblem<'_, T> {
    fn n_params(&self) -> usize {
        self.profile.n_params()
    }

    fn n_residuals(&self) -> usize {
        if self.profile.is_disc() {
            (self.ya..=self.yb)
                .map(|y| {
                    let (a, b) = self.disc_row(y);
                    b + 1 - a
                })
                .sum()
        } else {
            (self.xb - self.xa + 1) * (self.yb - self.ya + 1)
        }
    }

    fn residuals(&self, p: &[f64], r: &mut [f64]) {
        self.for_each_pixel(p, false, |k, rk, _| r[k] = rk);
    }

    fn jacobian(&self, p: &[f64], jac: &mut [f64]) {
        let n = self.profile.n_params();
        self.for_each_pixel(p, true, |k, _, j| {
            jac[n * k..n * k + n].copy_from_slice(&j[..n])
        });
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
        let n = self.profile.n_params();
        let mut a_ = [0.0; 100];
        let mut g = [0.0; 10];
        self.for_each_pixel(p, true, |_, r, j| {
            for a in 0..n {
                g[a] += j[a] * r;
                for b in 0..=a {
                    a_[a * n + b] += j[a] * j[b];
                }
            }
        });
        for a in 0..n {
            for b in 0..a {
                a_[b * n + a] = a_[a * n + b];
            }
        }
        jtj[..n * n].copy_from_slice(&a_[..n * n]);
        jtr[..n].copy_from_slice(&g[..n]);
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

/// Fit one marker near `(x0, y0)` with a blob of size `s` (Gaussian sigma, px) in a window of
/// half-width `ceil(2.5 s)` or the scratch's `hw_factor s` (a disc: at least `1.4 R0 + 4`,
/// `R0` its half-maximum radius), never beyond the scratch's `max_hw`;
/// `None` if the fit fails or is implausible (centre moved more than
/// `max(s, 2)`, width outside `[0.3 s, 3 s]` (Gaussian) or `[0.05, 3 s]` with radius below
/// `4 s` (disc), amplitude of the wrong sign).
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit_blob<T: Pixel>(
    img: ArrayView2<T>,
    x0: f64,
    y0: f64,
    s: f64,
    sign: f64,
    profile: Profile,
    scratch: &mut BlobScratch,
) -> Option<FitOut> {
    let (h, w) = img.dim();
    let (cx, cy) = (x0.round() as i64, y0.round() as i64);
    let window = |hw: i64| {
        (
            (cx - hw).max(0) as usize,
            ((cx + hw).min(w as i64 - 1)) as usize,
            (cy - hw).max(0) as usize,
            ((cy + hw).min(h as i64 - 1)) as usize,
        )
    };
    let border_median = |(xa, xb, ya, yb): (usize, usize, usize, usize), buf: &mut Vec<f64>| {
        buf.clear();
        for y in ya..=yb {
            for x in [xa, xb] {
                buf.push(sign * img[[y, x]].to_f64());
            }
        }
        for x in xa..=xb {
            for y in [ya, yb] {
                buf.push(sign * img[[y, x]].to_f64());
            }
        }
        super::coarse::median_mut(buf)
    };
    let pk = sign
        * img[[
            (cy.clamp(0, h as i64 - 1)) as usize,
            (cx.clamp(0, w as i64 - 1)) as usize,
        ]]
        .to_f64();
    // Initial guess: background from the median of the window's border, amplitude from the
    // pixel at the peak; a disc's radius from the area above half that amplitude in a window
    // of half-width 3.5 s, and its window then reaches 1.4 R + 4 px (the blurred edge and a
    // ring of background).
    let cap = |hw: i64| match scratch.max_hw {
        0 => hw,
        m => hw.min(m as i64),
    };
    // The scratch's wider factor adds at most 8 px (a small disc's flat top and its ring).
    let base = 2.5 * s;
    let mut hw = cap(base
        .max((scratch.hw_factor * s).min(base + 8.0))
        .ceil()
        .max(3.0) as i64);
    let mut p = [0.0, x0, y0, s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    if profile.is_disc() {
        let wide = window(cap((3.5 * s).ceil().max(4.0) as i64));
        let b0 = border_median(wide, &mut scratch.border);
        let half = b0 + 0.5 * (pk - b0);
        let mut above = 0usize;
        for y in wide.2..=wide.3 {
            for x in wide.0..=wide.1 {
                above += usize::from(sign * img[[y, x]].to_f64() > half);
            }
        }
        let r0 = (above as f64 / std::f64::consts::PI).sqrt().max(0.5);
        p[7] = r0;
        p[3] = (0.25 * r0).clamp(0.5, s.max(0.5));
        hw = cap(hw.max((1.4 * r0 + 4.0).ceil() as i64));
    }
    let (xa, xb, ya, yb) = window(hw);
    if xb < xa + 4 || yb < ya + 4 {
        return None;
    }
    let b0 = border_median((xa, xb, ya, yb), &mut scratch.border);
    p[0] = pk - b0;
    p[4] = b0;
    if p[0].is_nan() || p[0] <= 0.0 {
        return None;
    }
    let problem = BlobProblem {
        img,
        xa,
        xb,
        ya,
        yb,
        xc: cx as f64,
        yc: cy as f64,
        sc: hw as f64,
        sign,
        profile,
        table: RefCell::new(std::mem::take(&mut scratch.table)),
    };
    let n = problem.n_residuals();
    let np = profile.n_params();
    let solved = scratch.solver.solve_in_place(
        &problem,
        &mut p[..np],
        &LmConfig {
            max_evals: scratch.max_evals,
            ..blob_lm_config()
        },
    );
    let mut problem = problem;
    let out = (|| {
        let summary = solved.ok()?;
        // The model is even in the width (and a disc's radius): report them positive.
        p[3] = p[3].abs();
        p[7] = p[7].abs();
        let width_ok = if profile.is_disc() {
            p[3] >= 0.05 && p[3] < 3.0 * s && p[7] < 4.0 * s
        } else {
            p[3] > 0.3 * s && p[3] < 3.0 * s
        };
        let plausible = summary.termination.converged()
            && p.iter().all(|v| v.is_finite())
            && p[0] > 0.0
            && width_ok
            && (p[1] - x0).hypot(p[2] - y0) <= s.max(2.0)
            && p[1] >= 0.0
            && p[2] >= 0.0
            && p[1] <= (w - 1) as f64
            && p[2] <= (h - 1) as f64;
        if !plausible {
            return None;
        }
        // Sandwich covariance (heteroscedasticity-consistent), with the small-sample factor.
        let (jtj, meat, _) = problem.jtj_meat_ssr(&p);
        let inv = jtj.try_inverse()?;
        let cov = &inv * meat * &inv * (n as f64 / (n as f64 - np as f64).max(1.0));
        let c = [[cov[(1, 1)], cov[(1, 2)]], [cov[(2, 1)], cov[(2, 2)]]];
        if !(c[0][0] > 0.0 && c[1][1] > 0.0) {
            return None;
        }
        let flat_top = if profile == Profile::Gauss {
            problem.flat_top_score(&p)
        } else {
            0.0
        };
        Some(FitOut {
            p,
            cov: c,
            flat_top,
        })
    })();
    scratch.table = std::mem::take(problem.table.get_mut());
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn blob_jacobian_and_normal_equations_match_central_differences() {
        // A blob on a tilted background with a deterministic texture, fitted from a point away
        // from the optimum (every profile).
        let img = Array2::from_shape_fn((23, 25), |(y, x)| {
            let (dx, dy) = (x as f64 - 12.3, y as f64 - 10.8);
            300.0
                + 4.0 * x as f64
                + 1500.0 * (-(dx * dx + dy * dy) / 18.0).exp()
                + ((x * 7 + y * 13) % 11) as f64
        });
        for profile in [
            Profile::Gauss,
            Profile::Cross,
            Profile::Disc,
            Profile::DiscTilted,
        ] {
            let pb = BlobProblem {
                img: img.view(),
                xa: 2,
                xb: 22,
                ya: 1,
                yb: 20,
                xc: 12.0,
                yc: 11.0,
                sc: 10.0,
                sign: 1.0,
                profile,
                table: RefCell::new(DiscTable::default()),
            };
            let (m, n) = (pb.n_residuals(), pb.n_params());
            if profile.is_disc() {
                // The disc's window: pixels within 10 px of (12, 11), clipped to the square.
                let inside = (1..=20usize)
                    .flat_map(|y| (2..=22usize).map(move |x| (x, y)))
                    .filter(|&(x, y)| {
                        let dy = y as f64 - 11.0;
                        let half = (100.0 - dy * dy).max(0.0).sqrt().floor();
                        (x as f64 - 12.0).abs() <= half
                    })
                    .count();
                assert_eq!(m, inside);
            } else {
                assert_eq!(m, 21 * 20);
            }
            let p = [
                1400.0, 12.37, 10.61, 3.2, 310.0, 35.0, -4.0, 2.7, 0.03, -0.02,
            ];
            let mut jac = vec![0.0; m * n];
            pb.jacobian(&p[..n], &mut jac);
            let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
            for c in 0..n {
                let hstep = 1e-5 * p[c].abs().max(1.0);
                let (mut pp, mut pm) = (p, p);
                let (pp, pm) = (&mut pp[..n], &mut pm[..n]);
                pp[c] += hstep;
                pm[c] -= hstep;
                pb.residuals(pp, &mut rp);
                pb.residuals(pm, &mut rm);
                // The disc's profile is tabulated (Simpson + Hermite, error ~1e-7), its dP/dR
                // and dP/dw interpolated quadratically (~1e-4): looser bounds.
                let tol = match (profile.is_disc(), c) {
                    (true, 3 | 7) => 5e-4,
                    (true, _) => 1e-5,
                    _ => 1e-6,
                };
                let scale = (0..m).map(|i| jac[i * n + c].abs()).fold(0.0, f64::max);
                assert!(scale > 0.0);
                for i in 0..m {
                    let num = (rp[i] - rm[i]) / (2.0 * hstep);
                    let err = (num - jac[i * n + c]).abs();
                    assert!(
                        err <= tol * scale,
                        "{profile:?} param {c} pixel {i}: {num} vs {}",
                        jac[i * n + c]
                    );
                }
            }
            // The pixel-by-pixel normal equations equal J^T J and J^T r from the dense J.
            let mut r = vec![0.0; m];
            pb.residuals(&p[..n], &mut r);
            let (mut jtj, mut jtr) = ([0.0; 100], [0.0; 10]);
            pb.normal_equations(&p[..n], &r, &mut [], &mut jtj, &mut jtr);
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
            let (bread, meat, ssr) = pb.jtj_meat_ssr(&p[..n]);
            let ssr_direct: f64 = r.iter().map(|v| v * v).sum();
            assert!((ssr - ssr_direct).abs() <= 1e-9 * ssr_direct);
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
}
