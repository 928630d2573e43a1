//! The blurred-disc profile: a uniform disc of radius `R` convolved with an isotropic Gaussian
//! point-spread function of standard deviation `w` (px), normalised to 1 at the centre of an
//! infinitely large disc. This is how a printed dot appears through a lens: flat-topped when
//! `R >> w`, a Gaussian of standard deviation `w` in the limit `R -> 0` (up to amplitude).
//!
//! With `a = rho / w` (distance from the disc centre) and `b = R / w`, the profile is
//! `P(rho) = 1 - Q1(a, b)` (Marcum Q-function), whose derivatives are closed forms:
//!
//! - `dP/da = -b exp(-(a^2 + b^2) / 2) I1(a b)`,
//! - `dP/db =  b exp(-(a^2 + b^2) / 2) I0(a b)`,
//! - `P(0) = 1 - exp(-b^2 / 2)`,
//!
//! evaluated with the exponentially scaled Bessel functions `i0e(z) = exp(-z) I0(z)`,
//! `i1e(z) = exp(-z) I1(z)` so that `exp(-(a^2 + b^2) / 2) I(a b) = exp(-(a - b)^2 / 2) ie(a b)`
//! never overflows. `P` itself is tabulated once per `(R, w)` on a grid of step `h = w / 16`
//! (Simpson's rule on `dP/drho` from `P(0)`) and read by cubic Hermite interpolation with the
//! exact slopes: error `O(h^4)`, below 1e-7 of the amplitude.

/// `exp(-z) I0(z)` for `z >= 0` (Abramowitz & Stegun 9.8.1-9.8.2, relative error < 6e-7).
pub(crate) fn i0e(z: f64) -> f64 {
    if z < 3.75 {
        let t = (z / 3.75) * (z / 3.75);
        let i0 = 1.0
            + t * (3.515_622_9
                + t * (3.089_942_4
                    + t * (1.206_749_2 + t * (0.265_973_2 + t * (0.036_076_8 + t * 0.004_581_3)))));
        i0 * (-z).exp()
    } else {
        let t = 3.75 / z;
        let p = 0.398_942_28
            + t * (0.013_285_92
                + t * (0.002_253_19
                    + t * (-0.001_575_65
                        + t * (0.009_162_81
                            + t * (-0.020_577_06
                                + t * (0.026_355_37 + t * (-0.016_476_33 + t * 0.003_923_77)))))));
        p / z.sqrt()
    }
}

/// `exp(-z) I1(z) / z` for `z >= 0` (finite at 0: 1/2; A&S 9.8.3-9.8.4, relative error < 6e-7).
pub(crate) fn i1e_over_z(z: f64) -> f64 {
    if z < 3.75 {
        let t = (z / 3.75) * (z / 3.75);
        let r = 0.5
            + t * (0.878_905_94
                + t * (0.514_988_69
                    + t * (0.150_849_34
                        + t * (0.026_587_33 + t * (0.003_015_32 + t * 0.000_324_11)))));
        r * (-z).exp()
    } else {
        let t = 3.75 / z;
        let p = 0.398_942_28
            + t * (-0.039_880_24
                + t * (-0.003_620_18
                    + t * (0.001_638_01
                        + t * (-0.010_315_55
                            + t * (0.022_829_67
                                + t * (-0.028_953_12 + t * (0.017_876_54 - t * 0.004_200_59)))))));
        p / (z * z.sqrt())
    }
}

/// The derivatives of the profile at distance `rho` from the centre of a disc `(radius, w)`:
/// `(dP/drho / rho, dP/dR, dP/dw)`. `dP/drho / rho` is finite at `rho = 0` (the centre
/// derivatives are `-(dP/drho / rho) * (x - x0)`, no division by `rho`).
#[inline(always)]
pub(crate) fn disc_slopes(rho: f64, radius: f64, w: f64) -> (f64, f64, f64) {
    let iw = 1.0 / w;
    let (a, b) = (rho * iw, radius * iw);
    let z = a * b;
    let e = (-0.5 * (a - b) * (a - b)).exp();
    let i1z = i1e_over_z(z);
    let i0 = i0e(z);
    // dP/drho = (1/w) dP/da = -(b/w) e i1e(z) = -(b/w) e z i1z, and z / rho = b / w.
    let slope_over_rho = -(b * iw) * (b * iw) * e * i1z;
    let d_r = b * iw * e * i0;
    // dP/dw = dP/da (-a/w) + dP/db (-b/w) = (b/w) e (a i1e(z) - b i0e(z)).
    let d_w = b * iw * e * (a * z * i1z - b * i0);
    (slope_over_rho, d_r, d_w)
}

/// `P(rho)` of one `(radius, w)` tabulated on `[0, rho_max]`, with its derivatives.
#[derive(Debug, Clone, Default)]
pub(crate) struct DiscTable {
    radius: f64,
    w: f64,
    h: f64,
    /// `P`, `dP/drho`, `dP/dR` and `dP/dw` at `k h`.
    p: Vec<f64>,
    g: Vec<f64>,
    d_r: Vec<f64>,
    d_w: Vec<f64>,
}

impl DiscTable {
    /// Tabulate for `(radius, w)` up to at least `rho_max` (no work if already tabulated for
    /// the same disc over a long enough range).
    pub(crate) fn ensure(&mut self, radius: f64, w: f64, rho_max: f64) {
        let covered = (self.p.len().saturating_sub(1)) as f64 * self.h;
        if self.radius == radius && self.w == w && covered >= rho_max && !self.p.is_empty() {
            return;
        }
        self.radius = radius;
        self.w = w;
        self.h = (w / 16.0).max(1e-3);
        let n = (rho_max / self.h).ceil() as usize + 2;
        for v in [&mut self.p, &mut self.g, &mut self.d_r, &mut self.d_w] {
            v.clear();
        }
        let slope = |rho: f64| disc_slopes(rho, radius, w).0 * rho;
        let b = radius / w;
        let mut p = -(-0.5 * b * b).exp_m1();
        let mut g0 = 0.0;
        let (_, dr0, dw0) = disc_slopes(0.0, radius, w);
        self.p.push(p);
        self.g.push(g0);
        self.d_r.push(dr0);
        self.d_w.push(dw0);
        for k in 1..n {
            let r1 = k as f64 * self.h;
            let gm = slope(r1 - 0.5 * self.h);
            let (so, dr, dw) = disc_slopes(r1, radius, w);
            let g1 = so * r1;
            p += self.h / 6.0 * (g0 + 4.0 * gm + g1);
            self.p.push(p);
            self.g.push(g1);
            self.d_r.push(dr);
            self.d_w.push(dw);
            g0 = g1;
        }
    }

    /// `(P, dP/drho / rho, dP/dR, dP/dw)` at `rho`: `P` and its slope from the cubic Hermite
    /// interpolant (the slope is the interpolant's own derivative, so the Jacobian is the
    /// model's), `dP/dR` and `dP/dw` interpolated quadratically (relative error ~1e-4, enough for
    /// the Levenberg-Marquardt steps and the covariance). Below one table step the slope comes
    /// from the closed form (finite `dP/drho / rho` at the centre). 0 beyond the table.
    #[inline(always)]
    pub(crate) fn value_and_slopes(&self, rho: f64) -> (f64, f64, f64, f64) {
        let u = rho / self.h;
        let k = u as usize;
        if k + 1 >= self.p.len() {
            return (*self.p.last().unwrap_or(&0.0), 0.0, 0.0, 0.0);
        }
        let t = u - k as f64;
        let t2 = t * t;
        let t3 = t2 * t;
        let (p0, p1) = (self.p[k], self.p[k + 1]);
        let (m0, m1) = (self.h * self.g[k], self.h * self.g[k + 1]);
        let value = (2.0 * t3 - 3.0 * t2 + 1.0) * p0
            + (t3 - 2.0 * t2 + t) * m0
            + (-2.0 * t3 + 3.0 * t2) * p1
            + (t3 - t2) * m1;
        let slope_over_rho = if k == 0 {
            disc_slopes(rho, self.radius, self.w).0
        } else {
            let dt = (6.0 * t2 - 6.0 * t) * p0
                + (3.0 * t2 - 4.0 * t + 1.0) * m0
                + (-6.0 * t2 + 6.0 * t) * p1
                + (3.0 * t2 - 2.0 * t) * m1;
            dt / (self.h * rho)
        };
        // Quadratic (Lagrange) through k, k+1, k+2 (k-1, k, k+1 at the table's end).
        let (j, s) = if k + 2 < self.p.len() {
            (k, t)
        } else {
            (k - 1, t + 1.0)
        };
        let (l0, l1, l2) = (
            0.5 * (s - 1.0) * (s - 2.0),
            s * (2.0 - s),
            0.5 * s * (s - 1.0),
        );
        let d_r = l0 * self.d_r[j] + l1 * self.d_r[j + 1] + l2 * self.d_r[j + 2];
        let d_w = l0 * self.d_w[j] + l1 * self.d_w[j + 1] + l2 * self.d_w[j + 2];
        (value, slope_over_rho, d_r, d_w)
    }

    /// `P(rho)` by cubic Hermite interpolation (0 beyond the table).
    #[inline(always)]
    pub(crate) fn value(&self, rho: f64) -> f64 {
        let u = rho / self.h;
        let k = u as usize;
        if k + 1 >= self.p.len() {
            return *self.p.last().unwrap_or(&0.0);
        }
        let t = u - k as f64;
        let t2 = t * t;
        let t3 = t2 * t;
        let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
        let h10 = t3 - 2.0 * t2 + t;
        let h01 = -2.0 * t3 + 3.0 * t2;
        let h11 = t3 - t2;
        h00 * self.p[k]
            + h10 * self.h * self.g[k]
            + h01 * self.p[k + 1]
            + h11 * self.h * self.g[k + 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: the disc supersampled on a fine grid, convolved with the Gaussian.
    fn brute(rho: f64, radius: f64, w: f64) -> f64 {
        let n = 1600;
        let lim = radius;
        let d = 2.0 * lim / n as f64;
        let mut s = 0.0;
        for iy in 0..n {
            let y = -lim + (iy as f64 + 0.5) * d;
            for ix in 0..n {
                let x = -lim + (ix as f64 + 0.5) * d;
                if x * x + y * y <= radius * radius {
                    let r2 = (x - rho) * (x - rho) + y * y;
                    s += (-0.5 * r2 / (w * w)).exp();
                }
            }
        }
        s * d * d / (2.0 * std::f64::consts::PI * w * w)
    }

    #[test]
    fn bessel_functions_match_series() {
        // Power series of I0 and I1 summed to convergence.
        for &z in &[0.0, 0.3, 1.0, 3.7, 3.8, 7.5, 20.0, 80.0] {
            let (mut i0, mut i1, mut t0, mut t1) = (0.0, 0.0, 1.0, z / 2.0);
            for k in 0..400 {
                i0 += t0;
                i1 += t1;
                let kf = k as f64 + 1.0;
                t0 *= z * z / (4.0 * kf * kf);
                t1 *= z * z / (4.0 * kf * (kf + 1.0));
            }
            let e = (-z).exp();
            assert!((i0e(z) - i0 * e).abs() <= 6e-7 * i0 * e, "i0e({z})");
            if z > 0.0 {
                let r = i1 * e / z;
                assert!((i1e_over_z(z) - r).abs() <= 6e-7 * r, "i1e/z({z})");
            }
        }
        assert!((i1e_over_z(0.0) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn table_matches_a_brute_force_convolution() {
        for &(radius, w) in &[(2.0, 1.0), (10.0, 1.2), (0.8, 1.0)] {
            let mut t = DiscTable::default();
            t.ensure(radius, w, radius + 8.0 * w);
            for &rho in &[
                0.0,
                0.5 * radius,
                radius - 0.3,
                radius,
                radius + 0.7,
                radius + 2.5,
            ] {
                let b = brute(rho, radius, w);
                assert!(
                    (t.value(rho) - b).abs() < 2e-4,
                    "R {radius} w {w} rho {rho}"
                );
            }
        }
    }

    #[test]
    fn slopes_match_central_differences() {
        let mut t = DiscTable::default();
        for &(rho, radius, w) in &[
            (0.7, 3.0, 1.1),
            (3.2, 3.0, 0.9),
            (6.0, 2.0, 1.5),
            (0.0, 2.0, 1.0),
        ] {
            let e = 1e-5;
            let val = |r: f64, rr: f64, ww: f64, t: &mut DiscTable| {
                t.ensure(rr, ww, 20.0);
                t.value(r)
            };
            let (sr, dr, dw) = disc_slopes(rho, radius, w);
            let num_r = (val(rho + e, radius, w, &mut t) - val((rho - e).abs(), radius, w, &mut t))
                / (2.0 * e);
            let num_rr =
                (val(rho, radius + e, w, &mut t) - val(rho, radius - e, w, &mut t)) / (2.0 * e);
            let num_w =
                (val(rho, radius, w + e, &mut t) - val(rho, radius, w - e, &mut t)) / (2.0 * e);
            if rho > 0.0 {
                assert!((sr * rho - num_r).abs() < 1e-5, "slope at {rho}");
            }
            assert!(
                (dr - num_rr).abs() < 1e-5,
                "dP/dR at {rho}: {dr} vs {num_rr}"
            );
            assert!((dw - num_w).abs() < 1e-5, "dP/dw at {rho}: {dw} vs {num_w}");
        }
    }
}
