//! [`FitWorkspace`]: the fast, allocation-free refit in normalised coordinates (Monte Carlo).

use super::varpro::varpro_rational;
use super::*;
use crate::error::{DewarpError, Result};
use crate::lm::{self, cholesky_in_place, cholesky_solve, LmConfig};
use crate::models::{p3_basis, r2_den_basis, Model};

/// Reusable, allocation-free refits in normalised coordinates (Monte Carlo).
///
/// P3: normal equations `(Phi^T Phi) c = Phi^T b` by Cholesky (both axes share `Phi`).
/// R1/R2: Levenberg-Marquardt with variable projection (the numerators are eliminated; LM runs
/// on the 2 or 5 denominator coefficients; default MINPACK tolerances, see
/// [`FitWorkspace::config`]) from the denominator of `warm_start` if given (e.g. the
/// unperturbed solution), else from the linearised (DLT) solution. It reaches the same optimum
/// as [`fit_mapping`]'s full LM (tested) in fewer, cheaper iterations.
#[derive(Clone, Debug)]
pub struct FitWorkspace {
    coeffs: [f64; 20],
    gram: [f64; 17 * 17],
    rhs: [f64; 20],
    /// LM settings for R1/R2 refits.
    pub config: LmConfig,
    /// Summary of the last LM refit (None for P3).
    pub last: Option<lm::LmSummary>,
}

impl Default for FitWorkspace {
    fn default() -> Self {
        Self::new()
    }
}

impl FitWorkspace {
    /// A workspace with MINPACK's default tolerances.
    pub fn new() -> Self {
        FitWorkspace {
            coeffs: [0.0; 20],
            gram: [0.0; 17 * 17],
            rhs: [0.0; 20],
            config: LmConfig::default(),
            last: None,
        }
    }

    /// Refit `model` to normalised point pairs; returns the coefficients (valid until the next
    /// call). Errors on mismatched lengths, too few points, singular systems and LM failure to
    /// converge.
    pub fn fit_normalized(
        &mut self,
        model: Model,
        obj_hat: &[[f64; 2]],
        img_hat: &[[f64; 2]],
        warm_start: Option<&[f64]>,
    ) -> Result<&[f64]> {
        let npts = obj_hat.len();
        if img_hat.len() != npts {
            return Err(invalid(format!(
                "object points ({npts}) and image points ({}) differ in number",
                img_hat.len()
            )));
        }
        if npts < model.min_points() {
            return Err(invalid(format!(
                "model {model} needs at least {} points, got {npts}",
                model.min_points()
            )));
        }
        let n = model.n_params();
        self.last = None;
        match model {
            Model::P3 => {
                let g = &mut self.gram[..100];
                g.fill(0.0);
                let mut bx = [0.0; 10];
                let mut by = [0.0; 10];
                for (o, i) in obj_hat.iter().zip(img_hat) {
                    let phi = p3_basis(o[0], o[1]);
                    for a in 0..10 {
                        let pa = phi[a];
                        bx[a] += pa * i[0];
                        by[a] += pa * i[1];
                        for b in 0..=a {
                            g[a * 10 + b] += pa * phi[b];
                        }
                    }
                }
                if !cholesky_in_place(g, 10) {
                    return Err(degenerate(model));
                }
                cholesky_solve(g, 10, &mut bx);
                cholesky_solve(g, 10, &mut by);
                self.coeffs[..10].copy_from_slice(&bx);
                self.coeffs[10..20].copy_from_slice(&by);
            }
            Model::R1 | Model::R2 => {
                match warm_start {
                    Some(w) if w.len() == n => self.coeffs[..n].copy_from_slice(w),
                    Some(w) => {
                        return Err(invalid(format!(
                            "warm start has {} coefficients, model {model} has {n}",
                            w.len()
                        )))
                    }
                    None => self.dlt_normal(model, obj_hat, img_hat)?,
                }
                let s = varpro_rational(model, obj_hat, img_hat, &mut self.coeffs, &self.config)?;
                self.last = Some(s);
                if !s.termination.converged() {
                    return Err(DewarpError::NotConverged(format!(
                        "refit of {model} did not converge in {} evaluations",
                        s.n_evals
                    )));
                }
            }
        }
        Ok(&self.coeffs[..n])
    }

    /// Linearised start for R1/R2 by the normal equations of the DLT system (no allocation).
    fn dlt_normal(&mut self, model: Model, obj: &[[f64; 2]], img: &[[f64; 2]]) -> Result<()> {
        let n = model.n_params();
        let (ix, iy) = sparsity(model);
        let g = &mut self.gram[..n * n];
        g.fill(0.0);
        let rhs = &mut self.rhs[..n];
        rhs.fill(0.0);
        let mut row = [0.0; 11];
        for (o, i) in obj.iter().zip(img) {
            let (x, y) = (o[0], o[1]);
            for (axis, idx) in [(0usize, ix), (1usize, iy)] {
                let t = i[axis];
                match model {
                    Model::R1 => {
                        row[..5].copy_from_slice(&[x, y, 1.0, -t * x, -t * y]);
                    }
                    _ => {
                        let phi = crate::models::r2_num_basis(x, y);
                        let psi = r2_den_basis(x, y);
                        row[..6].copy_from_slice(&phi);
                        for k in 0..5 {
                            row[6 + k] = -t * psi[k];
                        }
                    }
                }
                for a in 0..idx.len() {
                    rhs[idx[a]] += row[a] * t;
                    for b in 0..=a {
                        g[idx[a] * n + idx[b]] += row[a] * row[b];
                    }
                }
            }
        }
        if !cholesky_in_place(g, n) {
            return Err(degenerate(model));
        }
        cholesky_solve(g, n, rhs);
        self.coeffs[..n].copy_from_slice(rhs);
        Ok(())
    }
}
