//! A fitted mapping object px -> image px: forward map, exact inverse by Newton, rotation, JSON.
//!
//! With `c_o`, `c_i` the centres (object px, image px), `s` the scale and `F` the model in
//! normalised coordinates, the mapping is
//! `P_i = c_i + s R(theta) F((P_o - c_o) / s)` (paper eq. for dewarping with rotation).

use crate::error::{DewarpError, Result};
use crate::models::{eval_coord_jacobian, eval_normalized, Model};
use ndarray::{Array2, ArrayView2, Zip};
use serde::{Deserialize, Serialize};

/// Format tag and version of the JSON files.
pub const FORMAT_TAG: &str = "rspiv-mapping";
/// Current version of the JSON format.
pub const FORMAT_VERSION: u32 = 1;

/// Tolerance (image px) within which the inverse map counts as converged.
pub const INVERSE_TOL_PX: f64 = 1e-6;

/// Residual statistics of a fit (image px; residual = fitted minus measured).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitStats {
    /// Model fitted.
    pub model: Model,
    /// Number of point pairs.
    pub n_points: usize,
    /// Largest |residual| per axis (x, y), px.
    pub max_abs_px: [f64; 2],
    /// Mean residual per axis, px.
    pub mean_px: [f64; 2],
    /// Root-mean-square residual per axis, px.
    pub rms_px: [f64; 2],
    /// Sum of squared residuals in normalised units (the LM cost).
    pub cost: f64,
    /// How the solver stopped ("linear" for P3).
    pub termination: String,
    /// Residual evaluations of LM (0 for P3).
    pub n_evals: usize,
}

/// A fitted mapping object px -> image px.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Mapping {
    /// The model.
    pub model: Model,
    /// Coefficients in normalised coordinates (layout: see [`crate::models`]).
    pub coefficients: Vec<f64>,
    /// Object point of the central marker (object px).
    pub centre_object: [f64; 2],
    /// Image point of the central marker (image px).
    pub centre_image: [f64; 2],
    /// Normalising scale `s` (px).
    pub scale: f64,
    /// Rotation `theta` (radians) applied after the model, in normalised image coordinates.
    pub rotation: f64,
    /// Residual statistics of the fit.
    pub stats: FitStats,
    /// Coefficient covariance `s^2 (J^T J)^-1`, row-major `P x P` (normalised units).
    pub covariance: Vec<f64>,
    /// Residuals of the fit per point, image px (fitted minus measured), without rotation.
    pub residuals: Vec<[f64; 2]>,
}

#[derive(Serialize)]
struct FileOut<'a> {
    format: &'static str,
    version: u32,
    #[serde(flatten)]
    mapping: &'a Mapping,
}

#[derive(Deserialize)]
struct FileIn {
    #[serde(flatten)]
    mapping: Mapping,
}

impl Mapping {
    /// Object px -> image px (rotation included).
    #[inline]
    pub fn forward(&self, x: f64, y: f64) -> (f64, f64) {
        let s = self.scale;
        let (fx, fy) = eval_normalized(
            self.model,
            &self.coefficients,
            (x - self.centre_object[0]) / s,
            (y - self.centre_object[1]) / s,
        );
        let (sn, cs) = self.rotation.sin_cos();
        (
            self.centre_image[0] + s * (cs * fx - sn * fy),
            self.centre_image[1] + s * (sn * fx + cs * fy),
        )
    }

    /// `d(image px) / d(object px)` at an object point: `[[dxi/dxo, dxi/dyo], [dyi/dxo, dyi/dyo]]`.
    #[inline]
    pub fn forward_jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let s = self.scale;
        let (_, j) = eval_coord_jacobian(
            self.model,
            &self.coefficients,
            (x - self.centre_object[0]) / s,
            (y - self.centre_object[1]) / s,
        );
        let (sn, cs) = self.rotation.sin_cos();
        [
            [cs * j[0][0] - sn * j[1][0], cs * j[0][1] - sn * j[1][1]],
            [sn * j[0][0] + cs * j[1][0], sn * j[0][1] + cs * j[1][1]],
        ]
    }

    /// Image px -> object px by Newton's method on the analytic Jacobian, started from the
    /// inverse of the model's linear part at the centre. Returns the object point, whether it
    /// converged (|forward(result) - (x, y)| <= [`INVERSE_TOL_PX`]), and that residual (px).
    pub fn inverse_checked(&self, x: f64, y: f64) -> ((f64, f64), bool, f64) {
        let s = self.scale;
        let (sn, cs) = self.rotation.sin_cos();
        let (dx, dy) = (
            (x - self.centre_image[0]) / s,
            (y - self.centre_image[1]) / s,
        );
        // target in the model's (unrotated) normalised image frame
        let (tx, ty) = (cs * dx + sn * dy, -sn * dx + cs * dy);
        let c = &self.coefficients;
        let m = self.model;
        // start: invert the linear part of F at the origin
        let ((f0x, f0y), j0) = eval_coord_jacobian(m, c, 0.0, 0.0);
        let det0 = j0[0][0] * j0[1][1] - j0[0][1] * j0[1][0];
        let (mut u, mut v) = if det0.abs() > 1e-12 && det0.is_finite() {
            let (rx, ry) = (tx - f0x, ty - f0y);
            (
                (j0[1][1] * rx - j0[0][1] * ry) / det0,
                (-j0[1][0] * rx + j0[0][0] * ry) / det0,
            )
        } else {
            (tx, ty)
        };
        let stop = 1e-11 / s; // normalised residual at which Newton stops
        let ((mut fx, mut fy), mut j) = eval_coord_jacobian(m, c, u, v);
        let mut g = ((fx - tx).powi(2) + (fy - ty).powi(2)).sqrt();
        for _ in 0..60 {
            if g.is_nan() || g <= stop {
                break; // converged (or NaN, caught below)
            }
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det == 0.0 || !det.is_finite() {
                break;
            }
            let (rx, ry) = (tx - fx, ty - fy);
            let du = (j[1][1] * rx - j[0][1] * ry) / det;
            let dv = (-j[1][0] * rx + j[0][0] * ry) / det;
            // backtracking: accept the first step length that reduces the residual
            let mut alpha = 1.0;
            let mut improved = false;
            for _ in 0..30 {
                let (un, vn) = (u + alpha * du, v + alpha * dv);
                let ((gx, gy), jn) = eval_coord_jacobian(m, c, un, vn);
                let gn = ((gx - tx).powi(2) + (gy - ty).powi(2)).sqrt();
                if gn < g {
                    (u, v, fx, fy, j, g) = (un, vn, gx, gy, jn, gn);
                    improved = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !improved {
                break;
            }
        }
        let (ox, oy) = (self.centre_object[0] + s * u, self.centre_object[1] + s * v);
        let res_px = g * s;
        let ok = res_px.is_finite() && res_px <= INVERSE_TOL_PX && ox.is_finite() && oy.is_finite();
        ((ox, oy), ok, res_px)
    }

    /// Image px -> object px; an error naming the point if Newton does not converge to
    /// [`INVERSE_TOL_PX`].
    pub fn inverse(&self, x: f64, y: f64) -> Result<(f64, f64)> {
        let (p, ok, res) = self.inverse_checked(x, y);
        if ok {
            Ok(p)
        } else {
            Err(DewarpError::NotConverged(format!(
                "inverse map did not converge at image point ({x}, {y}) px (residual {res:.3e} px)"
            )))
        }
    }

    /// Forward map of every row of an `(N, 2)` array (parallel). Rows of an array without two
    /// columns come back as NaN.
    pub fn forward_many(&self, pts: ArrayView2<f64>) -> Array2<f64> {
        let mut out = Array2::from_elem((pts.nrows(), 2), f64::NAN);
        if pts.ncols() < 2 {
            return out;
        }
        Zip::from(out.rows_mut())
            .and(pts.rows())
            .par_for_each(|mut o, p| {
                let (x, y) = self.forward(p[0], p[1]);
                o[0] = x;
                o[1] = y;
            });
        out
    }

    /// Inverse map of every row of an `(N, 2)` array (parallel), with a converged flag per row
    /// (rows that did not converge hold Newton's last iterate).
    pub fn inverse_many(&self, pts: ArrayView2<f64>) -> (Array2<f64>, Vec<bool>) {
        let n = pts.nrows();
        let mut out = Array2::from_elem((n, 2), f64::NAN);
        let mut ok = vec![false; n];
        if pts.ncols() < 2 {
            return (out, ok);
        }
        let mut okarr = ndarray::Array1::from_elem(n, false);
        Zip::from(out.rows_mut())
            .and(&mut okarr)
            .and(pts.rows())
            .par_for_each(|mut o, k, p| {
                let ((x, y), conv, _) = self.inverse_checked(p[0], p[1]);
                o[0] = x;
                o[1] = y;
                *k = conv;
            });
        ok.iter_mut().zip(okarr.iter()).for_each(|(a, b)| *a = *b);
        (out, ok)
    }

    /// A copy with the rotation set to `theta_rad` (replacing any previous rotation).
    pub fn with_rotation(&self, theta_rad: f64) -> Mapping {
        let mut m = self.clone();
        m.rotation = theta_rad;
        m
    }

    /// Serialise with the format tag and version.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(&FileOut {
            format: FORMAT_TAG,
            version: FORMAT_VERSION,
            mapping: self,
        })
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// Parse and validate a mapping written by [`to_json`](Self::to_json).
    pub fn from_json(s: &str) -> Result<Mapping> {
        let bad = |msg: String| DewarpError::InvalidInput(format!("mapping JSON: {msg}"));
        let v: serde_json::Value =
            serde_json::from_str(s).map_err(|e| bad(format!("not valid JSON ({e})")))?;
        let tag = v.get("format").and_then(|t| t.as_str());
        if tag != Some(FORMAT_TAG) {
            return Err(bad(format!(
                "not an rspiv mapping (format tag {:?}, expected {FORMAT_TAG:?})",
                tag.unwrap_or("missing")
            )));
        }
        match v.get("version").and_then(|t| t.as_u64()) {
            Some(x) if x == FORMAT_VERSION as u64 => {}
            Some(x) => {
                return Err(bad(format!(
                    "unsupported format version {x} (this rspiv reads version {FORMAT_VERSION})"
                )))
            }
            None => return Err(bad("missing or invalid format version".into())),
        }
        let f: FileIn = serde_json::from_value(v).map_err(|e| bad(format!("{e}")))?;
        let m = f.mapping;
        let p = m.model.n_params();
        if m.coefficients.len() != p {
            return Err(bad(format!(
                "model {} needs {p} coefficients, file has {}",
                m.model,
                m.coefficients.len()
            )));
        }
        if !m.covariance.is_empty() && m.covariance.len() != p * p {
            return Err(bad(format!(
                "covariance has {} entries, expected {p} x {p}",
                m.covariance.len()
            )));
        }
        let finite = m.coefficients.iter().all(|x| x.is_finite())
            && m.centre_object.iter().all(|x| x.is_finite())
            && m.centre_image.iter().all(|x| x.is_finite())
            && m.rotation.is_finite();
        if !finite {
            return Err(bad("non-finite coefficients, centres or rotation".into()));
        }
        if !(m.scale.is_finite() && m.scale > 0.0) {
            return Err(bad(format!("scale must be positive, got {}", m.scale)));
        }
        if m.stats.model != m.model {
            return Err(bad("stats.model differs from model".into()));
        }
        if m.residuals.len() != m.stats.n_points {
            return Err(bad(format!(
                "{} residuals for n_points = {}",
                m.residuals.len(),
                m.stats.n_points
            )));
        }
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{fit_mapping, FitOptions};
    use ndarray::Array2;

    fn pincushion(k: f64) -> (Array2<f64>, Array2<f64>) {
        // radial distortion with k such that the corner moves by `k` relative
        let pitch = 19.51 * 34.538;
        let (cx, cy) = (4431.5, 2643.5);
        let rc2 = cx * cx + cy * cy;
        let mut obj = Array2::zeros((91, 2));
        let mut img = Array2::zeros((91, 2));
        for j in 0..7 {
            for i in 0..13 {
                let (x, y) = (cx + (i as f64 - 6.0) * pitch, cy + (j as f64 - 3.0) * pitch);
                let (dx, dy) = (x - cx, y - cy);
                let f = 1.0 + k * (dx * dx + dy * dy) / rc2;
                let k_ = j * 13 + i;
                obj[[k_, 0]] = x;
                obj[[k_, 1]] = y;
                img[[k_, 0]] = cx + 3.0 + f * dx + 1e-4 * dy;
                img[[k_, 1]] = cy - 2.0 + f * dy;
            }
        }
        (obj, img)
    }

    #[test]
    fn inverse_round_trips_over_the_sensor() {
        for model in Model::ALL {
            for k in [0.0033, 0.01, -0.01] {
                let (obj, img) = pincushion(k);
                let m = fit_mapping(obj.view(), img.view(), model, &FitOptions::default())
                    .unwrap()
                    .with_rotation(0.04_f64.to_radians());
                let mut worst: f64 = 0.0;
                for yy in (0..=5288).step_by(331) {
                    for xx in (0..=8864).step_by(443) {
                        let (x, y) = (xx as f64, yy as f64);
                        let (o, ok, _) = m.inverse_checked(x, y);
                        assert!(ok, "{model} k={k}: no convergence at ({x}, {y})");
                        let (bx, by) = m.forward(o.0, o.1);
                        worst = worst.max((bx - x).abs()).max((by - y).abs());
                    }
                }
                assert!(worst < 1e-6, "{model} k={k}: round trip {worst} px");
            }
        }
    }

    #[test]
    fn forward_jacobian_matches_central_differences() {
        let (obj, img) = pincushion(0.01);
        for model in Model::ALL {
            let m = fit_mapping(obj.view(), img.view(), model, &FitOptions::default())
                .unwrap()
                .with_rotation(0.3);
            for &(x, y) in &[(100.0, 200.0), (8000.0, 5000.0), (4400.0, 2600.0)] {
                let j = m.forward_jacobian(x, y);
                let h = 1e-2;
                let (a, b) = (m.forward(x + h, y), m.forward(x - h, y));
                let (c, d) = (m.forward(x, y + h), m.forward(x, y - h));
                let num = [
                    [(a.0 - b.0) / (2.0 * h), (c.0 - d.0) / (2.0 * h)],
                    [(a.1 - b.1) / (2.0 * h), (c.1 - d.1) / (2.0 * h)],
                ];
                for r in 0..2 {
                    for s in 0..2 {
                        let tol = 1e-6 * j[r][s].abs().max(1e-2);
                        assert!((j[r][s] - num[r][s]).abs() < tol, "{model} {r}{s}");
                    }
                }
            }
        }
    }

    #[test]
    fn parallel_many_agree_with_single_points() {
        let (obj, img) = pincushion(0.0033);
        let m = fit_mapping(obj.view(), img.view(), Model::R2, &FitOptions::default()).unwrap();
        let f = m.forward_many(obj.view());
        for (k, r) in obj.rows().into_iter().enumerate() {
            let (x, y) = m.forward(r[0], r[1]);
            assert_eq!((f[[k, 0]], f[[k, 1]]), (x, y));
        }
        let (inv, ok) = m.inverse_many(f.view());
        assert!(ok.iter().all(|&b| b));
        for (a, b) in inv.iter().zip(obj.iter()) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn inverse_reports_points_without_a_preimage() {
        // R1 with a pole inside the plane: a point beyond the horizon has no preimage.
        let (obj, img) = pincushion(0.0);
        let mut m = fit_mapping(obj.view(), img.view(), Model::R1, &FitOptions::default()).unwrap();
        // strong perspective: denominator vanishes at x_hat = -2
        m.coefficients = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0];
        // x_i = x/(1+x/2) < 2 for every x > -2: the image point x_hat = 2.5 has no preimage there
        let far = m.centre_image[0] + 2.5 * m.scale;
        let e = m.inverse(far, m.centre_image[1]).unwrap_err();
        assert!(matches!(e, DewarpError::NotConverged(_)), "{e}");
        assert!(e.to_string().contains("did not converge"));
        let (_, ok) = m.inverse_many(ndarray::array![[far, m.centre_image[1]]].view());
        assert_eq!(ok, vec![false]);
    }

    #[test]
    fn json_round_trip_and_rejection() {
        let (obj, img) = pincushion(0.0033);
        let m = fit_mapping(obj.view(), img.view(), Model::P3, &FitOptions::default())
            .unwrap()
            .with_rotation(-0.001);
        let s = m.to_json();
        let back = Mapping::from_json(&s).unwrap();
        assert_eq!(back, m);
        for (bad, what) in [
            ("{", "not valid JSON"),
            ("[1, 2]", "format tag"),
            ("{\"format\": \"other\", \"version\": 1}", "format tag"),
            (
                &s.replace("\"version\": 1", "\"version\": 99"),
                "version 99",
            ),
            (
                &s.replace("\"model\": \"p3\"", "\"model\": \"r2\""),
                "coefficients",
            ),
            (&s.replace("\"scale\": ", "\"scale\": -"), "scale"),
        ] {
            let e = Mapping::from_json(bad).unwrap_err();
            assert!(e.to_string().contains(what), "{what}: {e}");
        }
    }
}
