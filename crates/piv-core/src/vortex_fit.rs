//! Lamb-Oseen vortices fitted to the vectors about vortex cores (Carlier & Stanislas 2005,
//! J. Fluid Mech. 535): the kernel of `rspiv.fit_oseen`.
//!
//! The model, in the image's y-up frame (`X = dx j`, `Y = -dy i` for column `j`, row `i`;
//! `v_up = -v`), has six parameters per core: the centre `(xc, yc)` (px), the circulation
//! `Gamma` (px^2 per pair, positive counter-clockwise), `log r_c` (the core radius, px) and the
//! convection `(uc, vc)` (px per pair, y up):
//!
//! `u_theta(r) = Gamma / (2 pi r) (1 - exp(-r^2 / r_c^2))` about the centre, plus `(uc, vc)`.
//!
//! With [`OseenSettings::shear`], a seventh parameter adds a uniform background shear
//! `S = dU/dY` (px per pair per px, y up) about the centre: `u += S (Y - yc)`, as Stanislas,
//! Perret & Foucaut (2008, J. Fluid Mech. 602) fit the vortices of a boundary layer, where the
//! local shear the vortex sits in would otherwise bend the fitted core. A uniform shear is not
//! a rotation the Oseen vortex can take up: `v` holds the rotation, `u` the shear.
//!
//! Each core is fitted on its own (cores in parallel) by the Levenberg-Marquardt solver of
//! `dewarp_core::lm`, to the valid vectors within `reach` core radii of its centroid (at least
//! two grid steps). A fit drifting to a core wider than twice its patch, or to a centre four
//! times as far as a kept fit may move, is abandoned (a patch in solid-body rotation crawls
//! there). What a caller keeps is [`OseenFit::ok`]; see [`fit_cores`].

use crate::error::{PivError, Result};
use dewarp_core::lm::{LeastSquaresProblem, LmConfig, LmSolver};
use ndarray::ArrayView2;
use rayon::prelude::*;
use std::f64::consts::PI;

/// A fit is kept when it explains at least this share of its patch's velocity variance about
/// its own convection (a vortex through the PIV: 0.997; OpenPIV's `test10` vortex: 0.87-0.92;
/// vortices planted on turbulence: 0.7-0.9; cores of noise: median 0.2).
pub const OSEEN_MIN_FIT: f64 = 0.7;

/// A core with fewer valid vectors in its patch is not fitted (14 residuals for 6 parameters).
pub const OSEEN_MIN_VECTORS: usize = 7;

/// One vortex core to fit: its centroid in grid steps (`col` along x, `row` down), the radius
/// of its thresholded area (px) and its sense of rotation (+1 or -1, in the caller's frame).
#[derive(Clone, Copy, Debug)]
pub struct OseenCore {
    pub col: f64,
    pub row: f64,
    pub radius: f64,
    pub sign: f64,
}

/// The grid and the fit's limits.
#[derive(Clone, Copy, Debug)]
pub struct OseenSettings {
    /// Grid spacing along x and y, px (> 0).
    pub dx: f64,
    pub dy: f64,
    /// The patch's radius in core radii (> 0).
    pub reach: f64,
    /// +1 or -1: turns the circulation of the y-up frame into the caller's (the cores' sign).
    pub orient: f64,
    /// Model evaluations per core at most (>= 1).
    pub max_evals: usize,
    /// Fit a uniform background shear `dU/dY` with the vortex (module docs).
    pub shear: bool,
}

/// One core's fit. `col`, `row` in grid steps, `radius` px, `circulation` px^2 per pair in the
/// caller's frame (`orient`), `u`, `v` the convection in the pixel frame (v down, px per pair);
/// NaN unless `ok`. `fit` is the share of the patch's velocity variance about the convection
/// the model explains (NaN for a core not fitted); with the background shear, the variance
/// about the convection and the fitted shear, so that a shear alone explains nothing. `shear`
/// is the fitted background's `du/dy` in the pixel frame (rows down: `-S`), px per pair per
/// px, NaN without [`OseenSettings::shear`]. `ok`: the fit turns with the core, its
/// centre moved at most two core radii (at least one grid step) from the centroid, `r_c` lies
/// between a third of a grid step and the patch's radius, and `fit >= OSEEN_MIN_FIT`.
#[derive(Clone, Copy, Debug)]
pub struct OseenFit {
    pub col: f64,
    pub row: f64,
    pub radius: f64,
    pub circulation: f64,
    pub u: f64,
    pub v: f64,
    pub shear: f64,
    pub fit: f64,
    pub ok: bool,
}

impl OseenFit {
    const NONE: OseenFit = OseenFit {
        col: f64::NAN,
        row: f64::NAN,
        radius: f64::NAN,
        circulation: f64::NAN,
        u: f64::NAN,
        v: f64::NAN,
        shear: f64::NAN,
        fit: f64::NAN,
        ok: false,
    };
}

/// `(1 - exp(-s)) / s`, its derivative in `s` and `exp(-s)` (series where `s` is small).
#[inline]
pub(crate) fn decay(s: f64) -> (f64, f64, f64) {
    let e = (-s).exp();
    if s < 1e-4 {
        (1.0 - s / 2.0 + s * s / 6.0, -0.5 + s / 3.0 - s * s / 8.0, e)
    } else {
        ((1.0 - e) / s, (e * (s + 1.0) - 1.0) / (s * s), e)
    }
}

/// One core's patch: points `(X, Y)` in the y-up frame and their velocities `(u, v_up)`.
#[derive(Default)]
struct Patch {
    px: Vec<f64>,
    py: Vec<f64>,
    pu: Vec<f64>,
    pv: Vec<f64>,
    /// `log r_c` is held in `[lo, hi]`; a fit beyond `abandon_lrc` or `abandon_dist` from
    /// `(x0, y0)` is abandoned.
    lo: f64,
    hi: f64,
    abandon_lrc: f64,
    abandon_dist: f64,
    x0: f64,
    y0: f64,
    /// Whether the seventh parameter (the background shear) is fitted.
    shear: bool,
}

/// The parameters' terms shared by every point: `Gamma`, `r_c^2`, whether `log r_c` is
/// held at a bound (its derivative is then 0) and the background shear (0 without it).
#[derive(Clone, Copy)]
struct Terms {
    gam: f64,
    rc2: f64,
    held: bool,
    shear: f64,
}

impl Patch {
    #[inline]
    fn terms(&self, t: &[f64]) -> Terms {
        let lrc = t[3].clamp(self.lo, self.hi);
        Terms {
            gam: t[2],
            rc2: (2.0 * lrc).exp(),
            held: lrc != t[3],
            shear: if self.shear { t[6] } else { 0.0 },
        }
    }

    /// The model's velocity at point `k`.
    #[inline]
    fn velocity(&self, t: &[f64], c: Terms, k: usize) -> (f64, f64) {
        let (ddx, ddy) = (self.px[k] - t[0], self.py[k] - t[1]);
        let (f, _, _) = decay((ddx * ddx + ddy * ddy) / c.rc2);
        let gphi = c.gam * f / (2.0 * PI * c.rc2); // Gamma u_theta / (Gamma r)
        (t[4] + (c.shear - gphi) * ddy, t[5] + gphi * ddx)
    }

    /// The model's velocity at point `k` and its derivatives in the first six parameters
    /// (`u`'s in the shear, the seventh, is `Y - yc`; `v`'s is 0).
    #[inline]
    fn eval(&self, t: &[f64], c: Terms, k: usize) -> (f64, f64, [f64; 6], [f64; 6]) {
        let (ddx, ddy) = (self.px[k] - t[0], self.py[k] - t[1]);
        let (gam, rc2) = (c.gam, c.rc2);
        let (f, df, e) = decay((ddx * ddx + ddy * ddy) / rc2);
        let phi = f / (2.0 * PI * rc2); // u_theta / (Gamma r)
        let phq = df / (2.0 * PI * rc2 * rc2); // d phi / d r^2
        let phl = if c.held { 0.0 } else { -e / (PI * rc2) }; // d phi / d log r_c
        let mu = t[4] + (c.shear - gam * phi) * ddy;
        let mv = t[5] + gam * phi * ddx;
        let ju = [
            2.0 * gam * ddx * ddy * phq,
            gam * (2.0 * ddy * ddy * phq + phi) - c.shear,
            -phi * ddy,
            -gam * ddy * phl,
            1.0,
            0.0,
        ];
        let jv = [
            -gam * (2.0 * ddx * ddx * phq + phi),
            -2.0 * gam * ddx * ddy * phq,
            phi * ddx,
            gam * ddx * phl,
            0.0,
            1.0,
        ];
        (mu, mv, ju, jv)
    }
}

impl Patch {
    /// `J^T J` and `J^T r` of the first `N` parameters (6, or 7 with the shear), summed point
    /// by point without the Jacobian (`N` a constant: the loops unroll).
    fn sums<const N: usize>(&self, p: &[f64], r: &[f64], jtj: &mut [f64], jtr: &mut [f64]) {
        let mut a = [[0.0f64; N]; N];
        let mut g = [0.0f64; N];
        let c = self.terms(p);
        for k in 0..self.px.len() {
            let (_, _, ju, jv) = self.eval(p, c, k);
            let ddy = self.py[k] - p[1]; // d u / d shear
            for (six, seventh, rk) in [(ju, ddy, r[2 * k]), (jv, 0.0, r[2 * k + 1])] {
                let mut row = [0.0f64; N];
                row[..6].copy_from_slice(&six);
                if N == 7 {
                    row[6] = seventh;
                }
                for i in 0..N {
                    g[i] += row[i] * rk;
                    for j in 0..=i {
                        a[i][j] += row[i] * row[j];
                    }
                }
            }
        }
        for i in 0..N {
            jtr[i] = g[i];
            for j in 0..=i {
                jtj[N * i + j] = a[i][j];
                jtj[N * j + i] = a[i][j];
            }
        }
    }
}

impl LeastSquaresProblem for Patch {
    fn n_params(&self) -> usize {
        6 + usize::from(self.shear)
    }
    fn n_residuals(&self) -> usize {
        2 * self.px.len()
    }
    fn residuals(&self, p: &[f64], r: &mut [f64]) {
        let c = self.terms(p);
        for k in 0..self.px.len() {
            let (mu, mv) = self.velocity(p, c, k);
            r[2 * k] = mu - self.pu[k];
            r[2 * k + 1] = mv - self.pv[k];
        }
    }
    fn jacobian(&self, p: &[f64], jac: &mut [f64]) {
        let c = self.terms(p);
        let n = self.n_params();
        for k in 0..self.px.len() {
            let (_, _, ju, jv) = self.eval(p, c, k);
            let row = &mut jac[2 * n * k..2 * n * (k + 1)];
            row[..6].copy_from_slice(&ju);
            row[n..n + 6].copy_from_slice(&jv);
            if self.shear {
                row[6] = self.py[k] - p[1];
                row[13] = 0.0;
            }
        }
    }
    fn normal_equations(
        &self,
        p: &[f64],
        r: &[f64],
        _jac_scratch: &mut [f64],
        jtj: &mut [f64],
        jtr: &mut [f64],
    ) {
        if self.shear {
            self.sums::<7>(p, r, jtj, jtr)
        } else {
            self.sums::<6>(p, r, jtj, jtr)
        }
    }
    fn abandon(&self, p: &[f64]) -> bool {
        p[3] > self.abandon_lrc || (p[0] - self.x0).hypot(p[1] - self.y0) > self.abandon_dist
    }
}

/// The median of `v` (reordered; mean of the middle two for an even count).
fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let (_, &mut hi, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        return hi;
    }
    let lo = v[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    0.5 * (lo + hi)
}

pub(crate) fn check(
    u: &ArrayView2<f64>,
    v: &ArrayView2<f64>,
    valid: &ArrayView2<bool>,
    s: &OseenSettings,
) -> Result<()> {
    if v.dim() != u.dim() || valid.dim() != u.dim() {
        return Err(PivError::InvalidInput(format!(
            "oseen: u {:?}, v {:?} and valid {:?} must have one shape",
            u.dim(),
            v.dim(),
            valid.dim()
        )));
    }
    if !(s.dx > 0.0 && s.dy > 0.0 && s.reach > 0.0) {
        return Err(PivError::InvalidInput(format!(
            "oseen: dx, dy and reach must be > 0, got {}, {}, {}",
            s.dx, s.dy, s.reach
        )));
    }
    if s.orient != 1.0 && s.orient != -1.0 {
        return Err(PivError::InvalidInput(format!(
            "oseen: orient must be +1 or -1, got {}",
            s.orient
        )));
    }
    if s.max_evals == 0 {
        return Err(PivError::InvalidInput(
            "oseen: max_evals must be >= 1".into(),
        ));
    }
    Ok(())
}

/// Fit a Lamb-Oseen vortex to the vectors about each core (module docs), cores in parallel.
///
/// `u`, `v` are the field in the pixel frame (v down, px per pair) on a grid of `dx` x `dy` px
/// whose column `j`, row `i` lies at `(dx j, dy i)`; `valid` the vectors that enter (with
/// finite `u`, `v`). A core whose centroid is not finite, or whose patch holds fewer than
/// [`OSEEN_MIN_VECTORS`] vectors, is not fitted.
///
/// # Errors
/// `PivError::InvalidInput` for fields of different shapes, a spacing or reach not > 0,
/// `orient` not +-1 or `max_evals` of 0.
pub fn fit_cores(
    u: ArrayView2<f64>,
    v: ArrayView2<f64>,
    valid: ArrayView2<bool>,
    cores: &[OseenCore],
    s: &OseenSettings,
) -> Result<Vec<OseenFit>> {
    check(&u, &v, &valid, s)?;
    let cfg = LmConfig {
        ftol: 1e-10,
        xtol: 1e-10,
        gtol: 0.0,
        max_evals: s.max_evals,
        initial_step_factor: 100.0,
    };
    Ok(cores
        .par_iter()
        .map_init(
            || (Patch::default(), LmSolver::new(), Vec::new()),
            |(patch, solver, scratch), core| {
                fit_one(&u, &v, &valid, core, s, &cfg, patch, solver, scratch)
            },
        )
        .collect())
}

#[allow(clippy::too_many_arguments)]
fn fit_one(
    u: &ArrayView2<f64>,
    v: &ArrayView2<f64>,
    valid: &ArrayView2<bool>,
    core: &OseenCore,
    s: &OseenSettings,
    cfg: &LmConfig,
    patch: &mut Patch,
    solver: &mut LmSolver,
    scratch: &mut Vec<f64>,
) -> OseenFit {
    let (ny, nx) = u.dim();
    let (dx, dy) = (s.dx, s.dy);
    if !(core.col.is_finite() && core.row.is_finite() && core.radius.is_finite()) {
        return OseenFit::NONE;
    }
    // the patch: valid vectors within `big` px of the centroid
    let big = (s.reach * core.radius).max(2.0 * dx.max(dy));
    let (x0, y0) = (dx * core.col, -dy * core.row);
    let (hj, hi) = ((big / dx).ceil() as i64, (big / dy).ceil() as i64);
    let (j0, i0) = (core.col.round() as i64, core.row.round() as i64);
    for b in [&mut patch.px, &mut patch.py, &mut patch.pu, &mut patch.pv] {
        b.clear();
    }
    for i in (i0 - hi).max(0)..=(i0 + hi).min(ny as i64 - 1) {
        for j in (j0 - hj).max(0)..=(j0 + hj).min(nx as i64 - 1) {
            let (iu, ju) = (i as usize, j as usize);
            let (xp, yp) = (dx * j as f64, -dy * i as f64);
            let (uu, vv) = (u[[iu, ju]], v[[iu, ju]]);
            if (xp - x0).powi(2) + (yp - y0).powi(2) <= big * big
                && valid[[iu, ju]]
                && uu.is_finite()
                && vv.is_finite()
            {
                patch.px.push(xp);
                patch.py.push(yp);
                patch.pu.push(uu);
                patch.pv.push(-vv);
            }
        }
    }
    let cnt = patch.px.len();
    if cnt < OSEEN_MIN_VECTORS {
        return OseenFit::NONE;
    }
    // first guesses: the centroid, the core's radius, the patch's median convection and its
    // largest r u_theta (the circulation the patch holds)
    scratch.clear();
    scratch.extend_from_slice(&patch.pu);
    let uc0 = median(scratch);
    scratch.clear();
    scratch.extend_from_slice(&patch.pv);
    let vc0 = median(scratch);
    let mut ru: f64 = 0.0;
    for k in 0..cnt {
        let c = (patch.px[k] - x0) * (patch.pv[k] - vc0) - (patch.py[k] - y0) * (patch.pu[k] - uc0);
        ru = ru.max(c.abs());
    }
    let reach_px = core.radius.max(dx.max(dy)); // a kept fit's centre moves at most twice it
    patch.lo = (dx.min(dy) / 100.0).ln();
    patch.hi = (100.0 * big).ln();
    patch.abandon_lrc = (2.0 * big).ln();
    patch.abandon_dist = 4.0 * reach_px;
    patch.x0 = x0;
    patch.y0 = y0;
    patch.shear = s.shear;
    let mut t = [
        x0,
        y0,
        2.0 * PI * ru * core.sign * s.orient,
        core.radius.max(0.5 * dx.min(dy)).ln(),
        uc0,
        vc0,
        0.0,
    ];
    let n = patch.n_params();
    let cost = match solver.solve_in_place(&*patch, &mut t[..n], cfg) {
        Ok(summary) => summary.cost,
        Err(_) => return OseenFit::NONE, // singular: the patch does not determine a vortex
    };
    let [xc, yc, gam, lrc, uc, vc, sh] = t;
    let rc = lrc.clamp(patch.lo, patch.hi).exp();
    // the variance about the fitted background (convection and shear), which the vortex explains
    let mut su = 0.0;
    for k in 0..cnt {
        su += (patch.pu[k] - uc - sh * (patch.py[k] - yc)).powi(2) + (patch.pv[k] - vc).powi(2);
    }
    let fit = 1.0 - cost / su;
    let moved = (xc - x0).hypot(yc - y0);
    let ok = cost.is_finite()
        && fit.is_finite()
        && gam.signum() * s.orient == core.sign
        && gam != 0.0
        && moved <= 2.0 * reach_px
        && rc >= dx.min(dy) / 3.0
        && rc <= big
        && fit >= OSEEN_MIN_FIT;
    if !ok {
        return OseenFit {
            fit,
            ..OseenFit::NONE
        };
    }
    OseenFit {
        col: xc / dx,
        row: -yc / dy,
        radius: rc,
        circulation: gam * s.orient,
        u: uc,
        v: -vc,
        shear: if s.shear { -sh } else { f64::NAN },
        fit,
        ok,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use ndarray::Array2;

    /// The closed-form vortex on a grid (pixel frame, v down).
    pub(crate) fn field(
        ny: usize,
        nx: usize,
        d: f64,
        vx: &[(f64, f64, f64, f64)],
        conv: (f64, f64),
    ) -> (Array2<f64>, Array2<f64>) {
        let mut u = Array2::from_elem((ny, nx), conv.0);
        let mut v = Array2::from_elem((ny, nx), conv.1);
        for ((i, j), uu) in u.indexed_iter_mut() {
            let (x, y) = (d * j as f64, -d * i as f64);
            for &(xc, yc, gam, rc) in vx {
                let (ddx, ddy) = (x - xc, y - yc);
                let s = (ddx * ddx + ddy * ddy) / (rc * rc);
                let g = gam * decay(s).0 / (2.0 * PI * rc * rc);
                *uu -= g * ddy;
                v[[i, j]] -= g * ddx; // v_up = +g ddx, v = -v_up
            }
        }
        (u, v)
    }

    /// The core a threshold finds about the vortex `(xc, yc, Gamma, r_c)` (y up, px: its
    /// centroid and radius off the vortex's own) on a grid of `d` px, and the fit's settings.
    fn core_and_settings(
        d: f64,
        (xc, yc, g, rc): (f64, f64, f64, f64),
        shear: bool,
    ) -> (OseenCore, OseenSettings) {
        let core = OseenCore {
            col: xc / d + 0.6,
            row: -yc / d - 0.4,
            radius: 0.8 * rc,
            sign: g.signum(),
        };
        let s = OseenSettings {
            dx: d,
            dy: d,
            reach: 2.5,
            orient: 1.0,
            max_evals: 100,
            shear,
        };
        (core, s)
    }

    /// A fit kept, with the vortex `(xc, yc, Gamma, r_c)` (y up, px) on the convection
    /// `(0.3, -0.2)` of `field` to 1e-6, and all of the patch's variance explained.
    fn assert_exact(f: &OseenFit, d: f64, (xc, yc, g, rc): (f64, f64, f64, f64)) {
        assert!(f.ok, "{f:?}");
        assert!(
            (f.col * d - xc).abs() < 1e-6 && (-f.row * d - yc).abs() < 1e-6,
            "{f:?}"
        );
        assert!((f.circulation / g - 1.0).abs() < 1e-6, "{f:?}");
        assert!((f.radius / rc - 1.0).abs() < 1e-6, "{f:?}");
        assert!(
            (f.u - 0.3).abs() < 1e-6 && (f.v + 0.2).abs() < 1e-6,
            "{f:?}"
        );
        assert!(f.fit > 1.0 - 1e-9, "{f:?}");
    }

    #[test]
    fn exact_vortices_are_recovered() {
        // one vortex per field (another's far field would enter the patch), both senses
        let d = 4.0;
        for (xc, yc, g, rc) in [(100.0, -80.0, 300.0, 10.0), (160.0, -150.0, -180.0, 7.0)] {
            let (u, v) = field(60, 90, d, &[(xc, yc, g, rc)], (0.3, -0.2));
            let valid = Array2::from_elem(u.dim(), true);
            let (core, s) = core_and_settings(d, (xc, yc, g, rc), false);
            let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
            assert_exact(&f, d, (xc, yc, g, rc));
            // the frame turned over: the circulation changes sign; a fit against the core's
            // sense of rotation is not kept
            let turned = OseenCore {
                sign: -core.sign,
                ..core
            };
            let flip = OseenSettings { orient: -1.0, ..s };
            let f = fit_cores(u.view(), v.view(), valid.view(), &[turned], &flip).unwrap()[0];
            assert!(f.ok && (f.circulation / -g - 1.0).abs() < 1e-6, "{f:?}");
            let f = fit_cores(u.view(), v.view(), valid.view(), &[turned], &s).unwrap()[0];
            assert!(!f.ok && f.radius.is_nan() && f.fit > 0.99, "{f:?}");
        }
    }

    #[test]
    fn a_vortex_in_a_background_shear_is_recovered() {
        let d = 4.0;
        let (xc, yc, g, rc, sh) = (120.0, -100.0, 260.0, 9.0, 0.05);
        let sheared = |vx: &[(f64, f64, f64, f64)]| {
            let (mut u, v) = field(60, 90, d, vx, (0.3, -0.2));
            for ((i, _), uu) in u.indexed_iter_mut() {
                *uu += sh * (-d * i as f64 - yc); // u += S (Y - yc), y up
            }
            (u, v)
        };
        let (u, v) = sheared(&[(xc, yc, g, rc)]);
        let valid = Array2::from_elem(u.dim(), true);
        let (core, s) = core_and_settings(d, (xc, yc, g, rc), true);
        let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
        assert_exact(&f, d, (xc, yc, g, rc));
        // du/dy with rows down: -S
        assert!((f.shear + sh).abs() < 1e-8, "{f:?}");
        // without the shear in the model the same vortex is fitted wrong
        let plain = OseenSettings { shear: false, ..s };
        let f0 = fit_cores(u.view(), v.view(), valid.view(), &[core], &plain).unwrap()[0];
        assert!(f0.shear.is_nan(), "{f0:?}");
        let bias = (f0.radius / rc - 1.0)
            .abs()
            .max((f0.circulation / g - 1.0).abs());
        assert!(!f0.ok || bias > 0.05, "{f0:?}");
        // an exact vortex without a shear: the shear fitted is 0
        let (u, v) = field(60, 90, d, &[(xc, yc, g, rc)], (0.3, -0.2));
        let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
        assert!(
            f.ok && f.shear.abs() < 1e-8 && (f.radius / rc - 1.0).abs() < 1e-6,
            "{f:?}"
        );
        // a shear alone, with a little noise, is no vortex: the shear explains it, not the core
        let (mut u, mut v) = sheared(&[]);
        for ((i, j), uu) in u.indexed_iter_mut() {
            *uu += 0.01 * ((7 * i + 3 * j) as f64).sin();
            v[[i, j]] += 0.01 * ((5 * i + 11 * j) as f64).cos();
        }
        let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
        assert!(!f.ok && f.fit < 0.1, "{f:?}");
    }

    #[test]
    fn uniform_flow_and_too_few_vectors_are_not_kept() {
        let u = Array2::from_elem((20, 20), 1.0);
        let v = Array2::from_elem((20, 20), 0.0);
        let mut valid = Array2::from_elem((20, 20), true);
        let core = OseenCore {
            col: 10.0,
            row: 10.0,
            radius: 4.0,
            sign: 1.0,
        };
        let s = OseenSettings {
            dx: 1.0,
            dy: 1.0,
            reach: 2.5,
            orient: 1.0,
            max_evals: 50,
            shear: false,
        };
        let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
        assert!(!f.ok);
        valid.fill(false);
        let f = fit_cores(u.view(), v.view(), valid.view(), &[core], &s).unwrap()[0];
        assert!(!f.ok && f.fit.is_nan());
        let nan = OseenCore {
            col: f64::NAN,
            ..core
        };
        assert!(!fit_cores(u.view(), v.view(), valid.view(), &[nan], &s).unwrap()[0].ok);
    }

    #[test]
    fn bad_settings_are_refused_in_one_line() {
        let u = Array2::<f64>::zeros((4, 5));
        let valid = Array2::from_elem((4, 5), true);
        let good = OseenSettings {
            dx: 1.0,
            dy: 1.0,
            reach: 2.5,
            orient: 1.0,
            max_evals: 10,
            shear: false,
        };
        let other = Array2::<f64>::zeros((5, 4));
        for (vv, s) in [
            (other.view(), good),
            (u.view(), OseenSettings { dx: 0.0, ..good }),
            (
                u.view(),
                OseenSettings {
                    orient: 2.0,
                    ..good
                },
            ),
            (
                u.view(),
                OseenSettings {
                    max_evals: 0,
                    ..good
                },
            ),
        ] {
            let e = fit_cores(u.view(), vv, valid.view(), &[], &s).unwrap_err();
            assert!(!e.to_string().contains('\n') && e.to_string().contains("oseen"));
        }
    }

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
    }
}
