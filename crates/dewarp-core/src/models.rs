//! The mapping models object -> image in normalised coordinates (DESIGN.md "Mapping models",
//! paper section 3.1 with its typos fixed).
//!
//! Normalised coordinates: `p_hat = (P - P_c) / s`, both point sets centred on the central
//! marker and divided by one scale `s` (the paper's `x_o_max`). A model maps an object point
//! `(x, y)` (normalised) to an image point `(f_x, f_y)` (normalised).
//!
//! Coefficient layouts (the order of the coefficient vectors everywhere in rspiv):
//!
//! - **R1** (8 free): `[a11, a12, a13, a21, a22, a23, a31, a32]`,
//!   `f_x = (a11 x + a12 y + a13) / D`, `f_y = (a21 x + a22 y + a23) / D`,
//!   `D = a31 x + a32 y + 1`.
//! - **R2** (17 free, a33 = 1 fixes the gauge): `[a11..a16, a21..a26, a31, a32, a34, a35, a36]`,
//!   numerators `a_k1 x + a_k2 y + a_k3 + a_k4 x^2 + a_k5 x y + a_k6 y^2`, shared denominator
//!   `D = a31 x + a32 y + 1 + a34 x^2 + a35 x y + a36 y^2`. (The paper counts 18 coefficients,
//!   which includes the fixed a33; only 17 are free.)
//! - **P3** (20 free): `[a01..a10, a11..a20]`, each axis a full cubic over the basis
//!   `[1, x, y, x^2, x y, y^2, x^3, x^2 y, x y^2, y^3]`.

use crate::error::{DewarpError, Result};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// A mapping model (object -> image).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// First-order rational (projective), 8 free coefficients.
    R1,
    /// Second-order rational with a shared denominator, 17 free coefficients.
    R2,
    /// Bicubic polynomial, 20 coefficients; linear in its coefficients.
    P3,
}

/// Largest number of coefficients of any model (for fixed-size scratch arrays).
pub const MAX_PARAMS: usize = 20;

impl Model {
    /// Number of free coefficients.
    pub fn n_params(self) -> usize {
        match self {
            Model::R1 => 8,
            Model::R2 => 17,
            Model::P3 => 20,
        }
    }

    /// Lower-case name: "r1", "r2" or "p3".
    pub fn name(self) -> &'static str {
        match self {
            Model::R1 => "r1",
            Model::R2 => "r2",
            Model::P3 => "p3",
        }
    }

    /// Smallest number of point pairs a fit needs: more residuals (2 per point) than free
    /// coefficients, so that the residual variance (and the covariance) is defined; for P3,
    /// whose axes decouple, more points than the 10 coefficients of one axis.
    pub fn min_points(self) -> usize {
        match self {
            Model::R1 => 5,
            Model::R2 => 9,
            Model::P3 => 11,
        }
    }

    /// Coefficients of the identity map in this model.
    pub fn identity(self) -> Vec<f64> {
        let mut c = vec![0.0; self.n_params()];
        match self {
            Model::R1 => {
                c[0] = 1.0;
                c[4] = 1.0;
            }
            Model::R2 => {
                c[0] = 1.0;
                c[7] = 1.0;
            }
            Model::P3 => {
                c[1] = 1.0;
                c[12] = 1.0;
            }
        }
        c
    }

    /// All models.
    pub const ALL: [Model; 3] = [Model::R1, Model::R2, Model::P3];
}

impl fmt::Display for Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Model {
    type Err = DewarpError;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "r1" => Ok(Model::R1),
            "r2" => Ok(Model::R2),
            "p3" => Ok(Model::P3),
            _ => Err(DewarpError::InvalidInput(format!(
                "unknown mapping model {s:?} (expected \"r1\", \"r2\" or \"p3\")"
            ))),
        }
    }
}

/// The bicubic basis `[1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3]`.
#[inline(always)]
pub fn p3_basis(x: f64, y: f64) -> [f64; 10] {
    let (xx, xy, yy) = (x * x, x * y, y * y);
    [1.0, x, y, xx, xy, yy, xx * x, xx * y, x * yy, yy * y]
}

/// The R2 numerator basis `[x, y, 1, x^2, xy, y^2]`.
#[inline(always)]
pub fn r2_num_basis(x: f64, y: f64) -> [f64; 6] {
    [x, y, 1.0, x * x, x * y, y * y]
}

/// The R2 denominator basis without its constant: `[x, y, x^2, xy, y^2]`.
#[inline(always)]
pub fn r2_den_basis(x: f64, y: f64) -> [f64; 5] {
    [x, y, x * x, x * y, y * y]
}

#[inline(always)]
fn dot<const N: usize>(a: &[f64], b: &[f64; N]) -> f64 {
    let mut s = 0.0;
    for k in 0..N {
        s += a[k] * b[k];
    }
    s
}

/// Evaluate a model at a normalised object point: returns the normalised image point.
/// `coeffs` must hold `model.n_params()` values (longer slices use the leading ones).
#[inline]
pub fn eval_normalized(model: Model, coeffs: &[f64], x: f64, y: f64) -> (f64, f64) {
    let c = coeffs;
    match model {
        Model::R1 => {
            let d = c[6] * x + c[7] * y + 1.0;
            (
                (c[0] * x + c[1] * y + c[2]) / d,
                (c[3] * x + c[4] * y + c[5]) / d,
            )
        }
        Model::R2 => {
            let phi = r2_num_basis(x, y);
            let psi = r2_den_basis(x, y);
            let d = 1.0 + dot(&c[12..17], &psi);
            (dot(&c[0..6], &phi) / d, dot(&c[6..12], &phi) / d)
        }
        Model::P3 => {
            let b = p3_basis(x, y);
            (dot(&c[0..10], &b), dot(&c[10..20], &b))
        }
    }
}

/// Value and Jacobian with respect to the (normalised) coordinates:
/// `((f_x, f_y), [[df_x/dx, df_x/dy], [df_y/dx, df_y/dy]])`.
#[inline]
pub fn eval_coord_jacobian(
    model: Model,
    coeffs: &[f64],
    x: f64,
    y: f64,
) -> ((f64, f64), [[f64; 2]; 2]) {
    let c = coeffs;
    match model {
        Model::R1 => {
            let d = c[6] * x + c[7] * y + 1.0;
            let nx = c[0] * x + c[1] * y + c[2];
            let ny = c[3] * x + c[4] * y + c[5];
            let (fx, fy) = (nx / d, ny / d);
            (
                (fx, fy),
                [
                    [(c[0] - fx * c[6]) / d, (c[1] - fx * c[7]) / d],
                    [(c[3] - fy * c[6]) / d, (c[4] - fy * c[7]) / d],
                ],
            )
        }
        Model::R2 => {
            let phi = r2_num_basis(x, y);
            let psi = r2_den_basis(x, y);
            // d phi / dx, d phi / dy
            let phx = [1.0, 0.0, 0.0, 2.0 * x, y, 0.0];
            let phy = [0.0, 1.0, 0.0, 0.0, x, 2.0 * y];
            let psx = [1.0, 0.0, 2.0 * x, y, 0.0];
            let psy = [0.0, 1.0, 0.0, x, 2.0 * y];
            let d = 1.0 + dot(&c[12..17], &psi);
            let (dx, dy) = (dot(&c[12..17], &psx), dot(&c[12..17], &psy));
            let fx = dot(&c[0..6], &phi) / d;
            let fy = dot(&c[6..12], &phi) / d;
            (
                (fx, fy),
                [
                    [
                        (dot(&c[0..6], &phx) - fx * dx) / d,
                        (dot(&c[0..6], &phy) - fx * dy) / d,
                    ],
                    [
                        (dot(&c[6..12], &phx) - fy * dx) / d,
                        (dot(&c[6..12], &phy) - fy * dy) / d,
                    ],
                ],
            )
        }
        Model::P3 => {
            let b = p3_basis(x, y);
            let (xx, xy, yy) = (x * x, x * y, y * y);
            let bx = [0.0, 1.0, 0.0, 2.0 * x, y, 0.0, 3.0 * xx, 2.0 * xy, yy, 0.0];
            let by = [0.0, 0.0, 1.0, 0.0, x, 2.0 * y, 0.0, xx, 2.0 * xy, 3.0 * yy];
            (
                (dot(&c[0..10], &b), dot(&c[10..20], &b)),
                [
                    [dot(&c[0..10], &bx), dot(&c[0..10], &by)],
                    [dot(&c[10..20], &bx), dot(&c[10..20], &by)],
                ],
            )
        }
    }
}

/// Value and Jacobian with respect to the coefficients at one normalised object point:
/// `jx[k] = d f_x / d c_k`, `jy[k] = d f_y / d c_k` (both of length `model.n_params()`).
/// Returns `(f_x, f_y)`.
#[inline]
pub fn eval_coeff_jacobian(
    model: Model,
    coeffs: &[f64],
    x: f64,
    y: f64,
    jx: &mut [f64],
    jy: &mut [f64],
) -> (f64, f64) {
    let c = coeffs;
    let n = model.n_params();
    jx[..n].fill(0.0);
    jy[..n].fill(0.0);
    match model {
        Model::R1 => {
            let d = c[6] * x + c[7] * y + 1.0;
            let fx = (c[0] * x + c[1] * y + c[2]) / d;
            let fy = (c[3] * x + c[4] * y + c[5]) / d;
            let phi = [x / d, y / d, 1.0 / d];
            jx[0..3].copy_from_slice(&phi);
            jy[3..6].copy_from_slice(&phi);
            jx[6] = -fx * x / d;
            jx[7] = -fx * y / d;
            jy[6] = -fy * x / d;
            jy[7] = -fy * y / d;
            (fx, fy)
        }
        Model::R2 => {
            let phi = r2_num_basis(x, y);
            let psi = r2_den_basis(x, y);
            let d = 1.0 + dot(&c[12..17], &psi);
            let fx = dot(&c[0..6], &phi) / d;
            let fy = dot(&c[6..12], &phi) / d;
            let inv = 1.0 / d;
            for k in 0..6 {
                jx[k] = phi[k] * inv;
                jy[6 + k] = phi[k] * inv;
            }
            for k in 0..5 {
                jx[12 + k] = -fx * psi[k] * inv;
                jy[12 + k] = -fy * psi[k] * inv;
            }
            (fx, fy)
        }
        Model::P3 => {
            let b = p3_basis(x, y);
            jx[0..10].copy_from_slice(&b);
            jy[10..20].copy_from_slice(&b);
            (dot(&c[0..10], &b), dot(&c[10..20], &b))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_coeffs(model: Model) -> Vec<f64> {
        match model {
            Model::R1 => vec![1.01, 0.02, 0.003, -0.015, 0.99, -0.002, 0.03, -0.02],
            Model::R2 => vec![
                1.01, 0.02, 0.003, 0.01, -0.02, 0.015, -0.015, 0.99, -0.002, 0.02, 0.01, -0.03,
                0.03, -0.02, 0.05, -0.04, 0.06,
            ],
            Model::P3 => vec![
                0.001, 1.002, 0.003, 0.01, -0.02, 0.005, 0.03, 0.001, 0.02, -0.004, -0.002, 0.004,
                0.998, -0.01, 0.006, 0.02, 0.002, 0.03, -0.001, 0.025,
            ],
        }
    }

    fn rel_close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * a.abs().max(b.abs()).max(1e-3)
    }

    #[test]
    fn names_and_parse() {
        for m in Model::ALL {
            assert_eq!(m.name().parse::<Model>().unwrap(), m);
            assert_eq!(m.name().to_uppercase().parse::<Model>().unwrap(), m);
            assert_eq!(m.identity().len(), m.n_params());
        }
        let e = "p4".parse::<Model>().unwrap_err();
        assert!(e.to_string().contains("unknown mapping model"));
    }

    #[test]
    fn identity_is_identity() {
        for m in Model::ALL {
            let c = m.identity();
            let (fx, fy) = eval_normalized(m, &c, 0.3, -0.2);
            assert!((fx - 0.3).abs() < 1e-15 && (fy + 0.2).abs() < 1e-15);
        }
    }

    #[test]
    fn coeff_jacobian_matches_central_differences() {
        for m in Model::ALL {
            let c = sample_coeffs(m);
            let n = m.n_params();
            let (mut jx, mut jy) = (vec![0.0; n], vec![0.0; n]);
            for &(x, y) in &[(0.41, -0.23), (-0.47, 0.2), (0.1, 0.05), (-0.3, -0.24)] {
                let v = eval_coeff_jacobian(m, &c, x, y, &mut jx, &mut jy);
                let v0 = eval_normalized(m, &c, x, y);
                assert!((v.0 - v0.0).abs() < 1e-15 && (v.1 - v0.1).abs() < 1e-15);
                for k in 0..n {
                    let h = 1e-5 * c[k].abs().max(1e-2);
                    let mut cp = c.clone();
                    cp[k] += h;
                    let p = eval_normalized(m, &cp, x, y);
                    cp[k] -= 2.0 * h;
                    let q = eval_normalized(m, &cp, x, y);
                    let (dx, dy) = ((p.0 - q.0) / (2.0 * h), (p.1 - q.1) / (2.0 * h));
                    assert!(
                        rel_close(jx[k], dx, 1e-6),
                        "{m} dfx/dc{k}: {} vs {dx}",
                        jx[k]
                    );
                    assert!(
                        rel_close(jy[k], dy, 1e-6),
                        "{m} dfy/dc{k}: {} vs {dy}",
                        jy[k]
                    );
                }
            }
        }
    }

    #[test]
    fn coord_jacobian_matches_central_differences() {
        for m in Model::ALL {
            let c = sample_coeffs(m);
            for &(x, y) in &[(0.41, -0.23), (-0.47, 0.2), (0.1, 0.05), (-0.3, -0.24)] {
                let (v, j) = eval_coord_jacobian(m, &c, x, y);
                let v0 = eval_normalized(m, &c, x, y);
                assert!((v.0 - v0.0).abs() < 1e-15 && (v.1 - v0.1).abs() < 1e-15);
                let h = 1e-5;
                let px = eval_normalized(m, &c, x + h, y);
                let qx = eval_normalized(m, &c, x - h, y);
                let py = eval_normalized(m, &c, x, y + h);
                let qy = eval_normalized(m, &c, x, y - h);
                let num = [
                    [(px.0 - qx.0) / (2.0 * h), (py.0 - qy.0) / (2.0 * h)],
                    [(px.1 - qx.1) / (2.0 * h), (py.1 - qy.1) / (2.0 * h)],
                ];
                for a in 0..2 {
                    for b in 0..2 {
                        assert!(
                            rel_close(j[a][b], num[a][b], 1e-6),
                            "{m} J[{a}][{b}]: {} vs {}",
                            j[a][b],
                            num[a][b]
                        );
                    }
                }
            }
        }
    }
}
