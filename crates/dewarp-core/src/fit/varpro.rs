//! Variable projection for the rational models (R1/R2): the numerators eliminated, LM on the
//! denominator coefficients (used by [`super::FitWorkspace`]).

use super::*;
use crate::error::Result;
use crate::lm::{self, cholesky_in_place, cholesky_solve, LmConfig};
use crate::models::{r2_den_basis, Model};

/// Bases of the rational models: numerator `phi` (q terms) and denominator without its
/// constant `psi` (r terms).
#[inline(always)]
pub(crate) fn rational_bases(model: Model, x: f64, y: f64) -> ([f64; 6], [f64; 5]) {
    match model {
        Model::R1 => ([x, y, 1.0, 0.0, 0.0, 0.0], [x, y, 0.0, 0.0, 0.0]),
        _ => (crate::models::r2_num_basis(x, y), r2_den_basis(x, y)),
    }
}

/// State of one variable-projection evaluation: the denominators' Gram factor and the
/// optimal numerators for the current denominator coefficients.
pub(crate) struct Projection {
    /// Cholesky factor of `G = sum phi phi^T / D^2` (q x q, row stride 6).
    l: [f64; 36],
    ax: [f64; 6],
    ay: [f64; 6],
    cost: f64,
    /// Bound on the rounding error of `cost` (each residual `f - t` carries about
    /// `eps (|f| + |t|)`, so the cost about `2 eps sum |r| (|f| + |t|)`): cost changes below
    /// it are not resolved.
    noise: f64,
}

/// For denominator coefficients `d`, the least-squares numerators (both axes share the Gram
/// matrix) and the resulting cost. `None` if the Gram matrix is singular or values blow up.
pub(crate) fn project<const Q: usize, const R: usize>(
    model: Model,
    d: &[f64],
    obj: &[[f64; 2]],
    img: &[[f64; 2]],
) -> Option<Projection> {
    let (q, r) = (Q, R);
    let mut g = [0.0; 36];
    let mut bx = [0.0; 6];
    let mut by = [0.0; 6];
    for (o, i) in obj.iter().zip(img) {
        let (phi, psi) = rational_bases(model, o[0], o[1]);
        let mut den = 1.0;
        for k in 0..r {
            den += d[k] * psi[k];
        }
        let inv = 1.0 / den;
        let w = inv * inv;
        for a in 0..q {
            let pa = phi[a];
            bx[a] += pa * i[0] * inv;
            by[a] += pa * i[1] * inv;
            let wa = w * pa;
            for b in 0..=a {
                g[a * 6 + b] += wa * phi[b];
            }
        }
    }
    // Cholesky with row stride 6 (copy into a dense q x q, factor, copy back)
    let mut dense = [0.0; 36];
    for a in 0..q {
        for b in 0..=a {
            dense[a * q + b] = g[a * 6 + b];
        }
    }
    if !cholesky_in_place(&mut dense[..q * q], q) {
        return None;
    }
    cholesky_solve(&dense[..q * q], q, &mut bx[..q]);
    cholesky_solve(&dense[..q * q], q, &mut by[..q]);
    let mut l = [0.0; 36];
    l[..q * q].copy_from_slice(&dense[..q * q]);
    let mut cost = 0.0;
    let mut noise = 0.0;
    for (o, i) in obj.iter().zip(img) {
        let (phi, psi) = rational_bases(model, o[0], o[1]);
        let mut den = 1.0;
        for k in 0..r {
            den += d[k] * psi[k];
        }
        let (mut nx, mut ny) = (0.0, 0.0);
        for a in 0..q {
            nx += bx[a] * phi[a];
            ny += by[a] * phi[a];
        }
        let (fx, fy) = (nx / den, ny / den);
        let (rx, ry) = (fx - i[0], fy - i[1]);
        cost += rx * rx + ry * ry;
        noise += rx.abs() * (fx.abs() + i[0].abs()) + ry.abs() * (fy.abs() + i[1].abs());
    }
    cost.is_finite().then_some(Projection {
        l,
        ax: bx,
        ay: by,
        cost,
        noise: 2.0 * f64::EPSILON * noise,
    })
}

/// Levenberg-Marquardt with variable projection (Golub-Pereyra) for the rational models: the
/// numerators are linear in their coefficients and are eliminated, so LM iterates on the
/// denominator coefficients only (2 for R1, 5 for R2). The damped step uses the exact Hessian
/// of the reduced cost (the Schur complement of the full Newton Hessian), which converges
/// quadratically where Gauss-Newton crawls along R2's nearly degenerate numerator/denominator
/// direction; the MINPACK stopping rules apply to the reduced problem. `coeffs` holds the start (only its denominator part is used) and receives
/// the full solution. Allocation-free.
pub(crate) fn varpro_rational(
    model: Model,
    obj: &[[f64; 2]],
    img: &[[f64; 2]],
    coeffs: &mut [f64; 20],
    cfg: &LmConfig,
) -> Result<lm::LmSummary> {
    match model {
        Model::R1 => varpro_impl::<3, 2>(model, obj, img, coeffs, cfg),
        _ => varpro_impl::<6, 5>(model, obj, img, coeffs, cfg),
    }
}

pub(crate) fn varpro_impl<const Q: usize, const R: usize>(
    model: Model,
    obj: &[[f64; 2]],
    img: &[[f64; 2]],
    coeffs: &mut [f64; 20],
    cfg: &LmConfig,
) -> Result<lm::LmSummary> {
    let (q, r) = (Q, R);
    let n = 2 * q + r;
    let max_evals = if cfg.max_evals == 0 {
        100 * (n + 1)
    } else {
        cfg.max_evals
    };
    let mut d = [0.0; 5];
    d[..r].copy_from_slice(&coeffs[2 * q..n]);
    let mut cur = project::<Q, R>(model, &d, obj, img).ok_or_else(|| degenerate(model))?;
    let mut n_evals = 1;
    let mut n_jac = 0;
    let mut lambda = 0.0_f64;
    let mut nu = 2.0;
    let mut diag = [0.0; 5];
    let mut first = true;
    let finish = |cur: &Projection, d: &[f64; 5], coeffs: &mut [f64; 20]| {
        coeffs[..q].copy_from_slice(&cur.ax[..q]);
        coeffs[q..2 * q].copy_from_slice(&cur.ay[..q]);
        coeffs[2 * q..n].copy_from_slice(&d[..r]);
    };
    loop {
        if cur.cost == 0.0 {
            finish(&cur, &d, coeffs);
            return Ok(lm::LmSummary {
                cost: 0.0,
                n_evals,
                n_jac_evals: n_jac,
                termination: lm::Termination::ZeroResidual,
            });
        }
        // Reduced normal equations: S = C - Bx^T G^-1 Bx - By^T G^-1 By, gradient gd.
        let mut bxm = [0.0; 30]; // q x r, stride 5
        let mut bym = [0.0; 30];
        let mut c = [0.0; 25];
        let mut gd = [0.0; 5];
        for (o, i) in obj.iter().zip(img) {
            let (phi, psi) = rational_bases(model, o[0], o[1]);
            let mut den = 1.0;
            for k in 0..r {
                den += d[k] * psi[k];
            }
            let inv = 1.0 / den;
            let (mut nx, mut ny) = (0.0, 0.0);
            for a in 0..q {
                nx += cur.ax[a] * phi[a];
                ny += cur.ay[a] * phi[a];
            }
            let (fx, fy) = (nx * inv, ny * inv);
            let (rx, ry) = (fx - i[0], fy - i[1]);
            let w = inv * inv;
            // Exact Hessian of the reduced cost (Newton): the Gauss-Newton blocks plus the
            // second-derivative terms sum r d2r, whose a-d block is -r phi psi^T / D^2 and
            // whose d-d block is 2 r f psi psi^T / D^2.
            let (wfx, wfy) = (w * (fx + rx), w * (fy + ry));
            let wff = w * (fx * fx + fy * fy + 2.0 * (rx * fx + ry * fy));
            let gr = inv * (fx * rx + fy * ry);
            for b in 0..r {
                let pb = psi[b];
                gd[b] -= gr * pb;
                for a in 0..q {
                    bxm[a * 5 + b] -= wfx * phi[a] * pb;
                    bym[a * 5 + b] -= wfy * phi[a] * pb;
                }
                for a in 0..=b {
                    c[b * 5 + a] += wff * psi[a] * pb;
                }
            }
        }
        n_jac += 1;
        // S = C - sum_axes B^T G^-1 B
        let mut smat = [0.0; 25];
        for b in 0..r {
            for a in 0..=b {
                smat[b * 5 + a] = c[b * 5 + a];
            }
        }
        for bm in [&bxm, &bym] {
            let mut col = [0.0; 6];
            for b in 0..r {
                for a in 0..q {
                    col[a] = bm[a * 5 + b];
                }
                cholesky_solve(&cur.l[..q * q], q, &mut col[..q]);
                for b2 in 0..=b {
                    let mut sdot = 0.0;
                    for a in 0..q {
                        sdot += bm[a * 5 + b2] * col[a];
                    }
                    smat[b * 5 + b2] -= sdot;
                }
            }
        }
        for b in 0..r {
            for a in 0..b {
                smat[a * 5 + b] = smat[b * 5 + a];
            }
        }
        // Marquardt scaling and the gradient test
        let fnorm = cur.cost.sqrt();
        let mut gnorm: f64 = 0.0;
        for k in 0..r {
            let cn = smat[k * 5 + k].max(0.0).sqrt();
            diag[k] = if first {
                if cn == 0.0 {
                    1.0
                } else {
                    cn
                }
            } else {
                diag[k].max(cn)
            };
            if cn != 0.0 {
                gnorm = gnorm.max((gd[k] / (cn * fnorm)).abs());
            }
        }
        first = false;
        let summary = |cost, n_evals, n_jac, t| lm::LmSummary {
            cost,
            n_evals,
            n_jac_evals: n_jac,
            termination: t,
        };
        if gnorm <= cfg.gtol || gnorm <= f64::EPSILON {
            finish(&cur, &d, coeffs);
            let t = if gnorm <= cfg.gtol {
                lm::Termination::Gtol
            } else {
                lm::Termination::SmallGtol
            };
            return Ok(summary(cur.cost, n_evals, n_jac, t));
        }
        loop {
            let mut a = [0.0; 25];
            for i in 0..r {
                for j in 0..r {
                    a[i * r + j] = smat[i * 5 + j];
                }
                a[i * r + i] += lambda * diag[i] * diag[i];
            }
            let mut step = [0.0; 5];
            let ok = cholesky_in_place(&mut a[..r * r], r);
            if !ok {
                lambda = if lambda == 0.0 { 1e-9 } else { lambda * nu };
                nu *= 2.0;
                if lambda > 1e30 {
                    return Err(degenerate(model));
                }
                continue;
            }
            for k in 0..r {
                step[k] = -gd[k];
            }
            cholesky_solve(&a[..r * r], r, &mut step[..r]);
            let mut dg = 0.0;
            let mut sds = 0.0;
            for i in 0..r {
                dg += step[i] * gd[i];
                let mut t = 0.0;
                for j in 0..r {
                    t += smat[i * 5 + j] * step[j];
                }
                sds += step[i] * t;
            }
            let pred = (-2.0 * dg - sds).max(0.0);
            if lambda == 0.0 && pred <= cur.noise {
                // The full Newton step promises less than the cost's rounding error: this is
                // the optimum to double precision (further trials would only compare noise).
                finish(&cur, &d, coeffs);
                return Ok(summary(
                    cur.cost,
                    n_evals,
                    n_jac,
                    lm::Termination::SmallFtol,
                ));
            }
            let mut dn = d;
            for k in 0..r {
                dn[k] += step[k];
            }
            let trial = project::<Q, R>(model, &dn, obj, img);
            n_evals += 1;
            let cost_new = trial.as_ref().map_or(f64::INFINITY, |t| t.cost);
            let prered = pred / cur.cost;
            let actred = if cost_new.is_finite() {
                1.0 - cost_new / cur.cost
            } else {
                -1.0
            };
            let rho = if pred > 0.0 {
                (cur.cost - cost_new) / pred
            } else {
                0.0
            };
            let pnorm = (0..r)
                .map(|k| (diag[k] * step[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            let accepted = cost_new < cur.cost;
            if accepted {
                d = dn;
                cur = trial.ok_or_else(|| degenerate(model))?;
                let t = 2.0 * rho - 1.0;
                lambda *= (1.0_f64 / 3.0).max(1.0 - t * t * t);
                nu = 2.0;
            } else {
                lambda = if lambda == 0.0 {
                    let mut mx: f64 = 0.0;
                    for k in 0..r {
                        mx = mx.max(smat[k * 5 + k] / (diag[k] * diag[k]));
                    }
                    1e-3 * mx.max(f64::EPSILON)
                } else {
                    lambda * nu
                };
                nu *= 2.0;
            }
            let xnorm = (0..r).map(|k| (diag[k] * d[k]).powi(2)).sum::<f64>().sqrt();
            let ftol_ok = actred.abs() <= cfg.ftol && prered <= cfg.ftol && rho <= 2.0;
            let xtol_ok = pnorm <= cfg.xtol * xnorm;
            let term = match (ftol_ok, xtol_ok) {
                (true, true) => Some(lm::Termination::FtolAndXtol),
                (true, false) => Some(lm::Termination::Ftol),
                (false, true) => Some(lm::Termination::Xtol),
                _ if n_evals >= max_evals => Some(lm::Termination::MaxEvals),
                _ if actred.abs() <= f64::EPSILON && prered <= f64::EPSILON && rho <= 2.0 => {
                    Some(lm::Termination::SmallFtol)
                }
                _ if pnorm <= f64::EPSILON * xnorm => Some(lm::Termination::SmallXtol),
                _ => None,
            };
            if let Some(t) = term {
                finish(&cur, &d, coeffs);
                return Ok(summary(cur.cost, n_evals, n_jac, t));
            }
            if accepted {
                break;
            }
        }
    }
}

#[cfg(test)]
#[path = "varpro_tests.rs"]
mod tests;
