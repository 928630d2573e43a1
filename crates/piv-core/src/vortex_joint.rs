//! Neighbouring Lamb-Oseen vortices fitted together: the kernel of `rspiv.fit_oseen`'s joint
//! fits.
//!
//! A single-vortex fit ([`crate::vortex_fit`]) takes a neighbour's velocity across its patch
//! into its own model: the neighbour's uniform part goes into the convection, its gradient
//! bends the fitted core. Two exact vortices of one core radius `r_c` three radii apart are
//! fitted 16 % off (like sense) and 9 % (opposite); from four radii apart within 0.8 %
//! (`tests/test_vortices.py`). The caller groups the kept single fits whose centres lie
//! closer than that (`rspiv.vortices.OSEEN_CROWDED` mean core radii, chained) and this module
//! fits each group's vortices at once, to the union of their patches, with one background.
//!
//! The model, in the image's y-up frame (`X = dx j`, `Y = -dy i`; `v_up = -v`), has four
//! parameters per vortex `m` (its centre `(xc_m, yc_m)` px, circulation `Gamma_m` px^2 per
//! pair, `log r_c,m`) and the group's convection `(uc, vc)` (px per pair), with
//! [`OseenSettings::shear`] also a uniform background shear `S = dU/dY` about the group's
//! reference height `Y_ref` (the mean of the single fits' centres):
//!
//! `u = uc + S (Y - Y_ref) + sum_m u_m`, `v_up = vc + sum_m v_m`, each `(u_m, v_m)` the
//! Lamb-Oseen vortex of [`crate::vortex_fit`] about its centre.
//!
//! The single fits are the starting point. A group's joint fit is kept when every vortex
//! still turns with its core, moved at most two core radii (at least a grid step) from its
//! core's centroid, has `r_c` between a third of a grid step and its patch's radius, no two of
//! one sense came closer than their mean core radius (they became one vortex), and the fit
//! explains at least [`OSEEN_MIN_FIT`] of the union's velocity variance about the fitted
//! background. Otherwise the single fits stand (the caller flags them as crowded). Groups of
//! more than [`OSEEN_JOINT_MAX`] vortices are left to their single fits.

use crate::error::Result;
use crate::vortex_fit::{check, decay, OseenCore, OseenFit, OseenSettings, OSEEN_MIN_FIT};
use dewarp_core::lm::{LeastSquaresProblem, LmConfig, LmSolver};
use ndarray::ArrayView2;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Groups of more vortices than this are not fitted jointly (4 vortices: 18-19 parameters).
pub const OSEEN_JOINT_MAX: usize = 4;

/// One vortex of a group: the core it was found as, and its single fit (kept).
#[derive(Clone, Copy, Debug)]
pub struct JointMember {
    pub core: OseenCore,
    pub fit: OseenFit,
}

/// A group's patch (the union of its members'), in the y-up frame, and the limits of each
/// member's parameters.
#[derive(Default)]
struct Group {
    px: Vec<f64>,
    py: Vec<f64>,
    pu: Vec<f64>,
    pv: Vec<f64>,
    /// Per member: `log r_c` held in `[lo, hi]`; a fit beyond `abandon_lrc`, or whose centre
    /// lies beyond `abandon_dist` of `(x0, y0)` (the core's centroid), is abandoned.
    lo: Vec<f64>,
    hi: Vec<f64>,
    abandon_lrc: Vec<f64>,
    abandon_dist: Vec<f64>,
    x0: Vec<f64>,
    y0: Vec<f64>,
    shear: bool,
    y_ref: f64,
}

impl Group {
    fn members(&self) -> usize {
        self.lo.len()
    }

    /// The model's `(u, v_up)` at point `k`; with `jac`, its derivatives in every parameter
    /// written into the two rows `ju`, `jv`.
    fn eval(&self, p: &[f64], k: usize, jac: Option<(&mut [f64], &mut [f64])>) -> (f64, f64) {
        let nm = self.members();
        let (x, y) = (self.px[k], self.py[k]);
        let sh = if self.shear { p[4 * nm + 2] } else { 0.0 };
        let mut mu = p[4 * nm] + sh * (y - self.y_ref);
        let mut mv = p[4 * nm + 1];
        let mut rows = jac;
        for m in 0..nm {
            let t = &p[4 * m..4 * m + 4];
            let lrc = t[3].clamp(self.lo[m], self.hi[m]);
            let held = lrc != t[3];
            let rc2 = (2.0 * lrc).exp();
            let (ddx, ddy) = (x - t[0], y - t[1]);
            let gam = t[2];
            let (f, df, e) = decay((ddx * ddx + ddy * ddy) / rc2);
            let phi = f / (2.0 * PI * rc2); // u_theta / (Gamma r)
            mu -= gam * phi * ddy;
            mv += gam * phi * ddx;
            if let Some((ju, jv)) = rows.as_mut() {
                let phq = df / (2.0 * PI * rc2 * rc2); // d phi / d r^2
                let phl = if held { 0.0 } else { -e / (PI * rc2) }; // d phi / d log r_c
                ju[4 * m..4 * m + 4].copy_from_slice(&[
                    2.0 * gam * ddx * ddy * phq,
                    gam * (2.0 * ddy * ddy * phq + phi),
                    -phi * ddy,
                    -gam * ddy * phl,
                ]);
                jv[4 * m..4 * m + 4].copy_from_slice(&[
                    -gam * (2.0 * ddx * ddx * phq + phi),
                    -2.0 * gam * ddx * ddy * phq,
                    phi * ddx,
                    gam * ddx * phl,
                ]);
            }
        }
        if let Some((ju, jv)) = rows {
            ju[4 * nm..4 * nm + 2].copy_from_slice(&[1.0, 0.0]);
            jv[4 * nm..4 * nm + 2].copy_from_slice(&[0.0, 1.0]);
            if self.shear {
                ju[4 * nm + 2] = y - self.y_ref;
                jv[4 * nm + 2] = 0.0;
            }
        }
        (mu, mv)
    }
}

impl LeastSquaresProblem for Group {
    fn n_params(&self) -> usize {
        4 * self.members() + 2 + usize::from(self.shear)
    }
    fn n_residuals(&self) -> usize {
        2 * self.px.len()
    }
    fn residuals(&self, p: &[f64], r: &mut [f64]) {
        for k in 0..self.px.len() {
            let (mu, mv) = self.eval(p, k, None);
            r[2 * k] = mu - self.pu[k];
            r[2 * k + 1] = mv - self.pv[k];
        }
    }
    fn jacobian(&self, p: &[f64], jac: &mut [f64]) {
        let n = self.n_params();
        for k in 0..self.px.len() {
            let (ju, jv) = jac[2 * n * k..2 * n * (k + 1)].split_at_mut(n);
            self.eval(p, k, Some((ju, jv)));
        }
    }
    fn abandon(&self, p: &[f64]) -> bool {
        (0..self.members()).any(|m| {
            p[4 * m + 3] > self.abandon_lrc[m]
                || (p[4 * m] - self.x0[m]).hypot(p[4 * m + 1] - self.y0[m]) > self.abandon_dist[m]
        })
    }
}

/// Fit each group of kept single fits jointly (module docs), groups in parallel.
///
/// `u`, `v`, `valid` and `s` are those of [`crate::vortex_fit::fit_cores`]; `groups` lists the
/// members of each group (their cores and single fits, `ok`). Returns per group its members'
/// joint fits in the order given (`ok` true, in the units of [`OseenFit`]; `u` is the
/// convection at the member's own centre, `shear` the group's), or None where the joint fit
/// was not kept, the group has fewer than two or more than [`OSEEN_JOINT_MAX`] members, or its
/// patch holds fewer than two residuals per parameter.
///
/// # Errors
/// `PivError::InvalidInput` for the settings [`crate::vortex_fit::fit_cores`] refuses.
pub fn fit_groups(
    u: ArrayView2<f64>,
    v: ArrayView2<f64>,
    valid: ArrayView2<bool>,
    groups: &[Vec<JointMember>],
    s: &OseenSettings,
) -> Result<Vec<Option<Vec<OseenFit>>>> {
    check(&u, &v, &valid, s)?;
    Ok(groups
        .par_iter()
        .map_init(
            || (Group::default(), LmSolver::new()),
            |(g, solver), members| fit_group(&u, &v, &valid, members, s, g, solver),
        )
        .collect())
}

fn fit_group(
    u: &ArrayView2<f64>,
    v: &ArrayView2<f64>,
    valid: &ArrayView2<bool>,
    members: &[JointMember],
    s: &OseenSettings,
    g: &mut Group,
    solver: &mut LmSolver,
) -> Option<Vec<OseenFit>> {
    let nm = members.len();
    if !(2..=OSEEN_JOINT_MAX).contains(&nm)
        || members
            .iter()
            .any(|m| !(m.fit.ok && m.core.col.is_finite() && m.core.row.is_finite()))
    {
        return None;
    }
    let (ny, nx) = u.dim();
    let (dx, dy) = (s.dx, s.dy);
    for b in [
        &mut g.px,
        &mut g.py,
        &mut g.pu,
        &mut g.pv,
        &mut g.lo,
        &mut g.hi,
        &mut g.abandon_lrc,
        &mut g.abandon_dist,
        &mut g.x0,
        &mut g.y0,
    ] {
        b.clear();
    }
    // each member's patch as a single fit has it (`reach` core radii of its centroid, at
    // least two grid steps), and the limits of its parameters
    let mut big = Vec::with_capacity(nm);
    let mut reach_px = Vec::with_capacity(nm);
    for m in members {
        let b = (s.reach * m.core.radius).max(2.0 * dx.max(dy));
        big.push(b);
        reach_px.push(m.core.radius.max(dx.max(dy)));
        g.lo.push((dx.min(dy) / 100.0).ln());
        g.hi.push((100.0 * b).ln());
        g.abandon_lrc.push((2.0 * b).ln());
        g.abandon_dist.push(4.0 * m.core.radius.max(dx.max(dy)));
        g.x0.push(dx * m.core.col);
        g.y0.push(-dy * m.core.row);
    }
    // the union of the patches, each vector once
    let (mut ilo, mut ihi, mut jlo, mut jhi) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
    for (m, b) in members.iter().zip(&big) {
        let (hj, hi) = ((b / dx).ceil() as i64, (b / dy).ceil() as i64);
        let (j0, i0) = (m.core.col.round() as i64, m.core.row.round() as i64);
        ilo = ilo.min(i0 - hi);
        ihi = ihi.max(i0 + hi);
        jlo = jlo.min(j0 - hj);
        jhi = jhi.max(j0 + hj);
    }
    for i in ilo.max(0)..=ihi.min(ny as i64 - 1) {
        for j in jlo.max(0)..=jhi.min(nx as i64 - 1) {
            let (iu, ju) = (i as usize, j as usize);
            let (xp, yp) = (dx * j as f64, -dy * i as f64);
            let (uu, vv) = (u[[iu, ju]], v[[iu, ju]]);
            let inside = (0..nm).any(|m| (xp - g.x0[m]).hypot(yp - g.y0[m]) <= big[m]);
            if inside && valid[[iu, ju]] && uu.is_finite() && vv.is_finite() {
                g.px.push(xp);
                g.py.push(yp);
                g.pu.push(uu);
                g.pv.push(-vv);
            }
        }
    }
    g.shear = s.shear;
    let n = g.n_params();
    if g.n_residuals() < 2 * n {
        return None;
    }
    // the single fits as the start; one background, their mean
    let mut p = vec![0.0; n];
    let (mut uc, mut vc, mut sh, mut yref) = (0.0, 0.0, 0.0, 0.0);
    for (k, m) in members.iter().enumerate() {
        let f = &m.fit;
        p[4 * k..4 * k + 4].copy_from_slice(&[
            dx * f.col,
            -dy * f.row,
            f.circulation * s.orient,
            f.radius.ln(),
        ]);
        uc += f.u / nm as f64;
        vc -= f.v / nm as f64;
        yref -= dy * f.row / nm as f64;
        if s.shear && f.shear.is_finite() {
            sh -= f.shear / nm as f64;
        }
    }
    g.y_ref = yref;
    p[4 * nm] = uc;
    p[4 * nm + 1] = vc;
    if s.shear {
        p[4 * nm + 2] = sh;
    }
    let cfg = LmConfig {
        ftol: 1e-10,
        xtol: 1e-10,
        gtol: 0.0,
        max_evals: s.max_evals.saturating_mul(nm),
        initial_step_factor: 100.0,
    };
    let cost = solver.solve_in_place(&*g, &mut p, &cfg).ok()?.cost;
    let (uc, vc) = (p[4 * nm], p[4 * nm + 1]);
    let sh = if s.shear { p[4 * nm + 2] } else { 0.0 };
    let mut su = 0.0; // the variance about the fitted background, which the vortices explain
    for k in 0..g.px.len() {
        su += (g.pu[k] - uc - sh * (g.py[k] - g.y_ref)).powi(2) + (g.pv[k] - vc).powi(2);
    }
    let fit = 1.0 - cost / su;
    if !(cost.is_finite() && fit.is_finite() && fit >= OSEEN_MIN_FIT) {
        return None;
    }
    let mut out = Vec::with_capacity(nm);
    for (k, m) in members.iter().enumerate() {
        let [xc, yc, gam, lrc] = [p[4 * k], p[4 * k + 1], p[4 * k + 2], p[4 * k + 3]];
        let rc = lrc.clamp(g.lo[k], g.hi[k]).exp();
        let moved = (xc - g.x0[k]).hypot(yc - g.y0[k]);
        let kept = gam != 0.0
            && gam.signum() * s.orient == m.core.sign
            && moved <= 2.0 * reach_px[k]
            && rc >= dx.min(dy) / 3.0
            && rc <= big[k];
        if !kept {
            return None;
        }
        out.push(OseenFit {
            col: xc / dx,
            row: -yc / dy,
            radius: rc,
            circulation: gam * s.orient,
            u: uc + sh * (yc - g.y_ref),
            v: -vc,
            shear: if s.shear { -sh } else { f64::NAN },
            fit,
            ok: true,
        });
    }
    // two of one sense closer than their mean core radius: the fit made one vortex of them
    for a in 0..nm {
        for b in a + 1..nm {
            let (fa, fb) = (&out[a], &out[b]);
            let apart = (dx * (fa.col - fb.col)).hypot(dy * (fa.row - fb.row));
            if fa.circulation.signum() == fb.circulation.signum()
                && apart < 0.5 * (fa.radius + fb.radius)
            {
                return None;
            }
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vortex_fit::fit_cores;
    use ndarray::Array2;

    /// Exact vortices `(xc, yc, Gamma, r_c)` (y up, px) on a grid of `d` px (pixel frame, v
    /// down) on the convection `conv` and the shear `sh` (`u += sh Y`, y up).
    fn field(
        ny: usize,
        nx: usize,
        d: f64,
        vx: &[(f64, f64, f64, f64)],
        conv: (f64, f64),
        sh: f64,
    ) -> (Array2<f64>, Array2<f64>) {
        let (mut u, v) = crate::vortex_fit::tests::field(ny, nx, d, vx, conv);
        for ((i, _), uu) in u.indexed_iter_mut() {
            *uu += sh * (-d * i as f64);
        }
        (u, v)
    }

    fn settings(d: f64, shear: bool) -> OseenSettings {
        OseenSettings {
            dx: d,
            dy: d,
            reach: 2.5,
            orient: 1.0,
            max_evals: 100,
            shear,
        }
    }

    /// The core a threshold finds about each vortex (centroid and radius off), single fits.
    fn singles(
        u: &Array2<f64>,
        v: &Array2<f64>,
        d: f64,
        vx: &[(f64, f64, f64, f64)],
        s: &OseenSettings,
    ) -> Vec<JointMember> {
        let cores: Vec<OseenCore> = vx
            .iter()
            .map(|&(xc, yc, g, rc)| OseenCore {
                col: xc / d + 0.4,
                row: -yc / d - 0.3,
                radius: 0.8 * rc,
                sign: g.signum(),
            })
            .collect();
        let valid = Array2::from_elem(u.dim(), true);
        let fits = fit_cores(u.view(), v.view(), valid.view(), &cores, s).unwrap();
        cores
            .into_iter()
            .zip(fits)
            .map(|(core, fit)| JointMember { core, fit })
            .collect()
    }

    #[test]
    fn neighbouring_vortices_are_recovered_together() {
        // two vortices three core radii apart, both senses, two directions, with and without a
        // background shear: the single fits are off by several per cent, the joint one exact
        let d = 2.0;
        for sh in [0.0, 0.004] {
            for like in [true, false] {
                for (ax, ay) in [(1.0, 0.0), (0.6, 0.8)] {
                    let (rc, sep) = (8.0, 24.0);
                    let g2 = if like { 260.0 } else { -260.0 };
                    let vx = [
                        (90.0, -70.0, 260.0, rc),
                        (90.0 + sep * ax, -70.0 - sep * ay, g2, rc),
                    ];
                    let (u, v) = field(80, 110, d, &vx, (0.3, -0.2), sh);
                    let s = settings(d, sh != 0.0);
                    let members = singles(&u, &v, d, &vx, &s);
                    assert!(members.iter().all(|m| m.fit.ok), "{members:?}");
                    let worst = members
                        .iter()
                        .zip(&vx)
                        .map(|(m, t)| (m.fit.radius / t.3 - 1.0).abs())
                        .fold(0.0, f64::max);
                    assert!(worst > 0.01, "singles too good to test: {worst}");
                    let valid = Array2::from_elem(u.dim(), true);
                    let got = fit_groups(u.view(), v.view(), valid.view(), &[members], &s)
                        .unwrap()
                        .pop()
                        .unwrap()
                        .expect("joint fit kept");
                    for (f, &(xc, yc, g, rc)) in got.iter().zip(&vx) {
                        assert!(
                            (f.col * d - xc).abs() < 1e-5 && (-f.row * d - yc).abs() < 1e-5,
                            "{f:?}"
                        );
                        assert!((f.circulation / g - 1.0).abs() < 1e-6, "{f:?}");
                        assert!((f.radius / rc - 1.0).abs() < 1e-6, "{f:?}");
                        // the convection at its own centre
                        assert!((f.u - (0.3 + sh * yc)).abs() < 1e-6, "{f:?}");
                        assert!((f.v + 0.2).abs() < 1e-6 && f.fit > 1.0 - 1e-9, "{f:?}");
                        if sh != 0.0 {
                            assert!((f.shear + sh).abs() < 1e-8, "{f:?}");
                        } else {
                            assert!(f.shear.is_nan());
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn groups_not_fitted_jointly() {
        let d = 2.0;
        let vx = [(90.0, -70.0, 260.0, 8.0), (114.0, -70.0, -260.0, 8.0)];
        let (u, v) = field(80, 110, d, &vx, (0.3, -0.2), 0.0);
        let s = settings(d, false);
        let members = singles(&u, &v, d, &vx, &s);
        let valid = Array2::from_elem(u.dim(), true);
        let lone = vec![members[0]];
        let mut unkept = members.clone();
        unkept[1].fit.ok = false;
        let five = vec![members[0]; OSEEN_JOINT_MAX + 1];
        // the cores' senses against the vortices': the fit cannot turn with them
        let mut turned = members.clone();
        for m in &mut turned {
            m.core.sign = -m.core.sign;
        }
        let none = Array2::from_elem(u.dim(), false);
        for (groups, vd) in [
            (vec![lone], valid.view()),
            (vec![unkept], valid.view()),
            (vec![five], valid.view()),
            (vec![turned], valid.view()),
            (vec![members.clone()], none.view()),
        ] {
            let got = fit_groups(u.view(), v.view(), vd, &groups, &s).unwrap();
            assert!(got[0].is_none(), "{got:?}");
        }
        let bad = OseenSettings { dx: 0.0, ..s };
        let e = fit_groups(u.view(), v.view(), valid.view(), &[members], &bad).unwrap_err();
        assert!(!e.to_string().contains('\n') && e.to_string().contains("oseen"));
    }
}
