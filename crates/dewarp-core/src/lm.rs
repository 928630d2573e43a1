//! A Levenberg-Marquardt solver for nonlinear least squares, generic over a residual/Jacobian
//! trait, written for rspiv (mapping fits, 2D Gaussian peak fits, Monte Carlo refits).
//!
//! Minimises `cost(p) = sum_i r_i(p)^2`. Each iteration solves the damped normal equations
//! `(J^T J + lambda D^2) delta = -J^T r` by Cholesky, with Marquardt's scaling `D = diag`
//! of the running maximum of the Jacobian's column norms (as MINPACK's `mode = 1`). The damping
//! follows the gain ratio `rho = actual / predicted reduction` (Nielsen's update); the initial
//! damping is chosen so that the first scaled step is no longer than
//! `initial_step_factor * ||D p0||` (MINPACK's `factor`).
//!
//! Stopping rules are MINPACK's (`lmder`):
//! - `Ftol`: both the actual and the predicted relative reductions of the cost are at most `ftol`
//!   (and `rho <= 2`);
//! - `Xtol`: the scaled step `||D delta||` is at most `xtol * ||D p||`;
//! - `Gtol`: the cosine of the angle between `r` and every column of `J` is at most `gtol`;
//! - `MaxEvals`: `max_evals` residual evaluations (`0` means `100 * (n + 1)`);
//! - `SmallFtol`/`SmallXtol`/`SmallGtol`: the tolerance is below what double precision can
//!   resolve; the current point is as good as it gets (MINPACK's info 6, 7, 8).
//!
//! Problems may override [`LeastSquaresProblem::normal_equations`] to assemble `J^T J` and
//! `J^T r` directly from their structure (the mapping fits do): the solver never needs `J`
//! itself. The solver keeps its buffers between solves: once sized, a solve allocates nothing
//! (use [`LmSolver::solve_in_place`]; [`LmSolver::solve`] only allocates the returned vector).

use crate::error::{DewarpError, Result};

/// A nonlinear least-squares problem: residuals `r(p)` and their Jacobian.
pub trait LeastSquaresProblem {
    /// Number of parameters `n`.
    fn n_params(&self) -> usize;
    /// Number of residuals `m` (at least `n`).
    fn n_residuals(&self) -> usize;
    /// Residuals `r(p)` written into `r` (length `n_residuals`).
    fn residuals(&self, p: &[f64], r: &mut [f64]);
    /// Jacobian `dr_i/dp_j`, row-major `n_residuals x n_params`, written into `jac`.
    fn jacobian(&self, p: &[f64], jac: &mut [f64]);
    /// `J^T J` (row-major `n x n`, both triangles) and `J^T r` at `p`, where `r` holds the
    /// residuals at `p`. The default evaluates [`jacobian`](Self::jacobian) into `jac_scratch`
    /// (length `m * n`) and multiplies; override it when the structure allows a cheaper sum.
    fn normal_equations(
        &self,
        p: &[f64],
        r: &[f64],
        jac_scratch: &mut [f64],
        jtj: &mut [f64],
        jtr: &mut [f64],
    ) {
        let (m, n) = (self.n_residuals(), self.n_params());
        self.jacobian(p, jac_scratch);
        jtj[..n * n].fill(0.0);
        jtr[..n].fill(0.0);
        for i in 0..m {
            let row = &jac_scratch[i * n..(i + 1) * n];
            let ri = r[i];
            for a in 0..n {
                let ja = row[a];
                jtr[a] += ja * ri;
                let out = &mut jtj[a * n..a * n + a + 1];
                for b in 0..=a {
                    out[b] += ja * row[b];
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                jtj[b * n + a] = jtj[a * n + b];
            }
        }
    }

    /// True when the accepted parameters `p` can no longer lead to an answer the caller keeps
    /// (a fit drifting out of its data): the solver stops there with
    /// [`Termination::Abandoned`] instead of spending its evaluations. Default: never.
    fn abandon(&self, _p: &[f64]) -> bool {
        false
    }
}

/// Tolerances and limits. `Default` is MINPACK's.
#[derive(Clone, Debug)]
pub struct LmConfig {
    /// Relative reduction of the cost below which the solver stops.
    pub ftol: f64,
    /// Relative scaled step below which the solver stops.
    pub xtol: f64,
    /// Cosine between residuals and Jacobian columns below which the solver stops.
    pub gtol: f64,
    /// Maximum number of residual evaluations; `0` means `100 * (n + 1)`.
    pub max_evals: usize,
    /// Bound of the first scaled step, relative to `||D p0||` (or absolute if `p0 = 0`).
    pub initial_step_factor: f64,
}

impl Default for LmConfig {
    fn default() -> Self {
        LmConfig {
            ftol: 1.49012e-8,
            xtol: 1.49012e-8,
            gtol: 0.0,
            max_evals: 0,
            initial_step_factor: 100.0,
        }
    }
}

impl LmConfig {
    /// Tolerances at the limit of double precision (reference-quality fits).
    pub fn tight() -> Self {
        LmConfig {
            ftol: 1e-15,
            xtol: 1e-15,
            gtol: 0.0,
            max_evals: 0,
            initial_step_factor: 100.0,
        }
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// Relative cost reduction at most `ftol`.
    Ftol,
    /// Relative scaled step at most `xtol`.
    Xtol,
    /// Both of the above.
    FtolAndXtol,
    /// Residuals orthogonal to the Jacobian's columns within `gtol`.
    Gtol,
    /// The evaluation budget was used up (not converged).
    MaxEvals,
    /// `ftol` is too small: no further reduction of the cost is possible.
    SmallFtol,
    /// `xtol` is too small: no further improvement of the parameters is possible.
    SmallXtol,
    /// `gtol` is too small: the residuals are orthogonal to the Jacobian to machine precision.
    SmallGtol,
    /// The residuals are exactly zero.
    ZeroResidual,
    /// [`LeastSquaresProblem::abandon`] said the fit cannot be kept (not converged).
    Abandoned,
}

impl Termination {
    /// True for every reason except `MaxEvals` and `Abandoned`.
    pub fn converged(self) -> bool {
        !matches!(self, Termination::MaxEvals | Termination::Abandoned)
    }

    /// A short lower-case name ("ftol", "xtol", ...).
    pub fn name(self) -> &'static str {
        match self {
            Termination::Ftol => "ftol",
            Termination::Xtol => "xtol",
            Termination::FtolAndXtol => "ftol+xtol",
            Termination::Gtol => "gtol",
            Termination::MaxEvals => "max_evals",
            Termination::SmallFtol => "small_ftol",
            Termination::SmallXtol => "small_xtol",
            Termination::SmallGtol => "small_gtol",
            Termination::ZeroResidual => "zero_residual",
            Termination::Abandoned => "abandoned",
        }
    }
}

/// Result of a solve.
#[derive(Clone, Debug)]
pub struct LmReport {
    /// Final parameters.
    pub params: Vec<f64>,
    /// Sum of squared residuals at `params`.
    pub cost: f64,
    /// Residual evaluations.
    pub n_evals: usize,
    /// Jacobian (normal-equation) evaluations.
    pub n_jac_evals: usize,
    /// Why the solver stopped.
    pub termination: Termination,
}

/// Result of [`LmSolver::solve_in_place`] (the parameters are left in the caller's slice).
#[derive(Clone, Copy, Debug)]
pub struct LmSummary {
    /// Sum of squared residuals at the final parameters.
    pub cost: f64,
    /// Residual evaluations.
    pub n_evals: usize,
    /// Jacobian (normal-equation) evaluations.
    pub n_jac_evals: usize,
    /// Why the solver stopped.
    pub termination: Termination,
}

/// Levenberg-Marquardt solver with a reusable workspace.
#[derive(Default, Debug, Clone)]
pub struct LmSolver {
    r: Vec<f64>,
    r_new: Vec<f64>,
    jac: Vec<f64>,
    jtj: Vec<f64>,
    jtr: Vec<f64>,
    a: Vec<f64>,
    diag: Vec<f64>,
    step: Vec<f64>,
    p_new: Vec<f64>,
}

const EPS: f64 = f64::EPSILON;

fn check_cfg(cfg: &LmConfig) -> Result<()> {
    let ok = |v: f64| v.is_finite() && v >= 0.0;
    if !(ok(cfg.ftol) && ok(cfg.xtol) && ok(cfg.gtol)) {
        return Err(DewarpError::InvalidInput(format!(
            "LM tolerances must be finite and non-negative (ftol {}, xtol {}, gtol {})",
            cfg.ftol, cfg.xtol, cfg.gtol
        )));
    }
    if !(cfg.initial_step_factor.is_finite() && cfg.initial_step_factor > 0.0) {
        return Err(DewarpError::InvalidInput(format!(
            "LM initial_step_factor must be positive, got {}",
            cfg.initial_step_factor
        )));
    }
    Ok(())
}

/// In-place Cholesky factorisation of the symmetric positive definite `n x n` matrix `a`
/// (lower triangle used and overwritten by L). Returns false if not positive definite.
pub(crate) fn cholesky_in_place(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if d <= 0.0 || !d.is_finite() {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    true
}

/// Solve `L L^T x = b` in place (`l` from [`cholesky_in_place`]).
pub(crate) fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
}

fn sumsq(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

fn scaled_norm(d: &[f64], v: &[f64]) -> f64 {
    d.iter()
        .zip(v)
        .map(|(a, b)| (a * b) * (a * b))
        .sum::<f64>()
        .sqrt()
}

impl LmSolver {
    /// An empty solver; buffers grow on the first solve.
    pub fn new() -> Self {
        Self::default()
    }

    fn size(&mut self, m: usize, n: usize, need_jac: bool) {
        let grow = |v: &mut Vec<f64>, len: usize| {
            if v.len() < len {
                v.resize(len, 0.0);
            }
        };
        grow(&mut self.r, m);
        grow(&mut self.r_new, m);
        if need_jac {
            grow(&mut self.jac, m * n);
        }
        grow(&mut self.jtj, n * n);
        grow(&mut self.a, n * n);
        grow(&mut self.jtr, n);
        grow(&mut self.diag, n);
        grow(&mut self.step, n);
        grow(&mut self.p_new, n);
    }

    /// Minimise from `p0`; returns the report with the final parameters.
    pub fn solve<P: LeastSquaresProblem>(
        &mut self,
        problem: &P,
        p0: &[f64],
        cfg: &LmConfig,
    ) -> Result<LmReport> {
        let mut p = p0.to_vec();
        let s = self.solve_in_place(problem, &mut p, cfg)?;
        Ok(LmReport {
            params: p,
            cost: s.cost,
            n_evals: s.n_evals,
            n_jac_evals: s.n_jac_evals,
            termination: s.termination,
        })
    }

    /// Minimise starting from (and overwriting) `p`. Allocation-free once the workspace has
    /// been sized for this problem's dimensions.
    pub fn solve_in_place<P: LeastSquaresProblem>(
        &mut self,
        problem: &P,
        p: &mut [f64],
        cfg: &LmConfig,
    ) -> Result<LmSummary> {
        let (m, n) = (problem.n_residuals(), problem.n_params());
        check_cfg(cfg)?;
        if n == 0 || p.len() != n {
            return Err(DewarpError::InvalidInput(format!(
                "LM: {} starting parameters for a problem with {n} parameters",
                p.len()
            )));
        }
        if m < n {
            return Err(DewarpError::InvalidInput(format!(
                "LM: {m} residuals cannot determine {n} parameters"
            )));
        }
        if p.iter().any(|v| !v.is_finite()) {
            return Err(DewarpError::InvalidInput(
                "LM: starting parameters contain NaN or inf".into(),
            ));
        }
        // The default normal_equations needs the dense Jacobian scratch; size it always (it is
        // reused, so this costs one allocation per solver, not per solve).
        self.size(m, n, true);
        let max_evals = if cfg.max_evals == 0 {
            100 * (n + 1)
        } else {
            cfg.max_evals
        };

        let LmSolver {
            r,
            r_new,
            jac,
            jtj,
            jtr,
            a,
            diag,
            step,
            p_new,
        } = self;
        let (r, r_new) = (&mut r[..m], &mut r_new[..m]);
        let (jtj, jtr, a) = (&mut jtj[..n * n], &mut jtr[..n], &mut a[..n * n]);
        let (diag, step, p_new) = (&mut diag[..n], &mut step[..n], &mut p_new[..n]);
        let jac = &mut jac[..m * n];

        problem.residuals(p, r);
        let mut n_evals = 1;
        let mut n_jac = 0;
        let mut cost = sumsq(r);
        if !cost.is_finite() {
            return Err(DewarpError::InvalidInput(
                "LM: residuals at the starting parameters are NaN or inf".into(),
            ));
        }
        let mut lambda = 0.0;
        let mut nu = 2.0;
        let mut first = true;
        let summary = |cost, n_evals, n_jac, termination| LmSummary {
            cost,
            n_evals,
            n_jac_evals: n_jac,
            termination,
        };

        loop {
            if cost == 0.0 {
                return Ok(summary(cost, n_evals, n_jac, Termination::ZeroResidual));
            }
            problem.normal_equations(p, r, jac, jtj, jtr);
            n_jac += 1;

            // Marquardt scaling: running maximum of the column norms.
            for j in 0..n {
                let cn = jtj[j * n + j].max(0.0).sqrt();
                if first {
                    diag[j] = if cn == 0.0 { 1.0 } else { cn };
                } else {
                    diag[j] = diag[j].max(cn);
                }
            }
            // Gradient test (cosine between r and the columns of J).
            let fnorm = cost.sqrt();
            let mut gnorm: f64 = 0.0;
            for j in 0..n {
                let cn = jtj[j * n + j].max(0.0).sqrt();
                if cn != 0.0 {
                    gnorm = gnorm.max((jtr[j] / (cn * fnorm)).abs());
                }
            }
            if gnorm <= cfg.gtol {
                return Ok(summary(cost, n_evals, n_jac, Termination::Gtol));
            }
            if gnorm <= EPS {
                return Ok(summary(cost, n_evals, n_jac, Termination::SmallGtol));
            }

            if first {
                // Initial damping: the smallest lambda in a geometric sweep whose scaled step
                // fits within initial_step_factor * ||D p||.
                let xnorm = scaled_norm(diag, p);
                let delta = if xnorm > 0.0 {
                    cfg.initial_step_factor * xnorm
                } else {
                    cfg.initial_step_factor
                };
                lambda = 0.0;
                let mut trial = 1e-12;
                loop {
                    if solve_damped(jtj, jtr, diag, lambda, a, step, n)
                        && scaled_norm(diag, step) <= delta
                    {
                        break;
                    }
                    lambda = trial;
                    trial *= 10.0;
                    if lambda > 1e16 {
                        break;
                    }
                }
                first = false;
            }

            // Inner loop: try steps until one reduces the cost.
            loop {
                if !solve_damped(jtj, jtr, diag, lambda, a, step, n) {
                    // Singular even with damping: raise the damping.
                    lambda = if lambda == 0.0 { 1e-9 } else { lambda * nu };
                    nu *= 2.0;
                    if lambda > 1e30 {
                        return Err(DewarpError::InvalidInput(
                            "LM: the Jacobian is singular (parameters not determined by the data)"
                                .into(),
                        ));
                    }
                    continue;
                }
                for j in 0..n {
                    p_new[j] = p[j] + step[j];
                }
                problem.residuals(p_new, r_new);
                n_evals += 1;
                let cost_new = sumsq(r_new);
                // Predicted reduction of the linear model: -2 d^T g - d^T JtJ d.
                let mut dg = 0.0;
                let mut dad = 0.0;
                for a_ in 0..n {
                    dg += step[a_] * jtr[a_];
                    let mut s = 0.0;
                    for b in 0..n {
                        s += jtj[a_ * n + b] * step[b];
                    }
                    dad += step[a_] * s;
                }
                let pred = (-2.0 * dg - dad).max(0.0);
                let prered = pred / cost;
                let actred = if cost_new.is_finite() {
                    1.0 - cost_new / cost
                } else {
                    -1.0
                };
                let rho = if pred > 0.0 {
                    (cost - cost_new) / pred
                } else {
                    0.0
                };
                let pnorm = scaled_norm(diag, step);

                let accepted = cost_new.is_finite() && cost_new < cost;
                if accepted {
                    p.copy_from_slice(p_new);
                    r.copy_from_slice(r_new);
                    cost = cost_new;
                    let t = 2.0 * rho - 1.0;
                    lambda *= (1.0_f64 / 3.0).max(1.0 - t * t * t);
                    nu = 2.0;
                } else {
                    lambda = if lambda == 0.0 {
                        // Gauss-Newton step failed: start damping at a scale-aware value.
                        let mut mx: f64 = 0.0;
                        for j in 0..n {
                            mx = mx.max(jtj[j * n + j] / (diag[j] * diag[j]));
                        }
                        1e-3 * mx.max(EPS)
                    } else {
                        lambda * nu
                    };
                    nu *= 2.0;
                }

                // MINPACK's convergence tests.
                let xnorm = scaled_norm(diag, p);
                let ftol_ok = actred.abs() <= cfg.ftol && prered <= cfg.ftol && rho <= 2.0;
                let xtol_ok = pnorm <= cfg.xtol * xnorm;
                match (ftol_ok, xtol_ok) {
                    (true, true) => {
                        return Ok(summary(cost, n_evals, n_jac, Termination::FtolAndXtol))
                    }
                    (true, false) => return Ok(summary(cost, n_evals, n_jac, Termination::Ftol)),
                    (false, true) => return Ok(summary(cost, n_evals, n_jac, Termination::Xtol)),
                    _ => {}
                }
                if n_evals >= max_evals {
                    return Ok(summary(cost, n_evals, n_jac, Termination::MaxEvals));
                }
                if actred.abs() <= EPS && prered <= EPS && rho <= 2.0 {
                    return Ok(summary(cost, n_evals, n_jac, Termination::SmallFtol));
                }
                if pnorm <= EPS * xnorm {
                    return Ok(summary(cost, n_evals, n_jac, Termination::SmallXtol));
                }
                if cost == 0.0 {
                    return Ok(summary(cost, n_evals, n_jac, Termination::ZeroResidual));
                }
                if accepted {
                    if problem.abandon(p) {
                        return Ok(summary(cost, n_evals, n_jac, Termination::Abandoned));
                    }
                    break;
                }
            }
        }
    }
}

/// Solve `(JtJ + lambda D^2) step = -jtr`; false if not positive definite.
fn solve_damped(
    jtj: &[f64],
    jtr: &[f64],
    diag: &[f64],
    lambda: f64,
    a: &mut [f64],
    step: &mut [f64],
    n: usize,
) -> bool {
    a[..n * n].copy_from_slice(&jtj[..n * n]);
    for j in 0..n {
        a[j * n + j] += lambda * diag[j] * diag[j];
    }
    if !cholesky_in_place(a, n) {
        return false;
    }
    for j in 0..n {
        step[j] = -jtr[j];
    }
    cholesky_solve(a, n, step);
    step.iter().all(|v| v.is_finite())
}

/// Minimise with a fresh solver (see [`LmSolver::solve`]).
pub fn minimize<P: LeastSquaresProblem>(
    problem: &P,
    p0: &[f64],
    cfg: &LmConfig,
) -> Result<LmReport> {
    LmSolver::new().solve(problem, p0, cfg)
}

/// Parameter covariance `s^2 (J^T J)^-1` with `s^2 = cost / (m - n)`, from the row-major
/// `n_residuals x n_params` Jacobian at the solution. Returned row-major `n x n`.
pub fn covariance(jac: &[f64], n_residuals: usize, n_params: usize, cost: f64) -> Result<Vec<f64>> {
    let (m, n) = (n_residuals, n_params);
    if jac.len() != m * n {
        return Err(DewarpError::InvalidInput(format!(
            "covariance: Jacobian has {} entries, expected {m} x {n}",
            jac.len()
        )));
    }
    if m <= n {
        return Err(DewarpError::InvalidInput(format!(
            "covariance: {m} residuals for {n} parameters leave no degrees of freedom"
        )));
    }
    let mut jtj = vec![0.0; n * n];
    for i in 0..m {
        let row = &jac[i * n..(i + 1) * n];
        for a in 0..n {
            for b in 0..=a {
                jtj[a * n + b] += row[a] * row[b];
            }
        }
    }
    covariance_from_jtj(&mut jtj, n, cost / (m - n) as f64)
}

/// `s2 * (JtJ)^-1` from the lower triangle of `jtj` (overwritten). Equilibrated (scaled to a
/// unit diagonal) before the Cholesky factorisation for accuracy.
pub(crate) fn covariance_from_jtj(jtj: &mut [f64], n: usize, s2: f64) -> Result<Vec<f64>> {
    let mut sc = vec![0.0; n];
    for j in 0..n {
        let d = jtj[j * n + j];
        if d <= 0.0 || !d.is_finite() {
            return Err(DewarpError::InvalidInput(format!(
                "covariance: parameter {j} does not affect the residuals"
            )));
        }
        sc[j] = 1.0 / d.sqrt();
    }
    for a in 0..n {
        for b in 0..=a {
            jtj[a * n + b] *= sc[a] * sc[b];
        }
    }
    if !cholesky_in_place(jtj, n) {
        return Err(DewarpError::InvalidInput(
            "covariance: J^T J is singular (parameters not determined by the data)".into(),
        ));
    }
    // (L L^T)^-1 = L^-T L^-1: the lower-triangular inverse of L (forward substitution of the
    // unit vectors, whose leading zeros are skipped), then its Gram product by symmetry:
    // ~n^3 / 3 flops instead of n solves of 2 n^2 each.
    let l = &*jtj;
    let mut li = vec![0.0; n * n];
    for j in 0..n {
        li[j * n + j] = 1.0 / l[j * n + j];
        for i in j + 1..n {
            let mut acc = 0.0;
            for k in j..i {
                acc -= l[i * n + k] * li[k * n + j];
            }
            li[i * n + j] = acc / l[i * n + i];
        }
    }
    let mut inv = vec![0.0; n * n];
    for a in 0..n {
        for b in 0..=a {
            let mut acc = 0.0;
            for k in a..n {
                acc += li[k * n + a] * li[k * n + b];
            }
            let v = acc * sc[a] * sc[b] * s2;
            inv[a * n + b] = v;
            inv[b * n + a] = v;
        }
    }
    Ok(inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10 (y - x^2), 1 - x); minimum (1, 1), cost 0.
    struct Rosenbrock;
    impl LeastSquaresProblem for Rosenbrock {
        fn n_params(&self) -> usize {
            2
        }
        fn n_residuals(&self) -> usize {
            2
        }
        fn residuals(&self, p: &[f64], r: &mut [f64]) {
            r[0] = 10.0 * (p[1] - p[0] * p[0]);
            r[1] = 1.0 - p[0];
        }
        fn jacobian(&self, p: &[f64], j: &mut [f64]) {
            j[0] = -20.0 * p[0];
            j[1] = 10.0;
            j[2] = -1.0;
            j[3] = 0.0;
        }
    }

    /// Exponential decay y = a exp(-b t) + c sampled without noise: exact answer known.
    struct ExpFit {
        t: Vec<f64>,
        y: Vec<f64>,
    }
    impl LeastSquaresProblem for ExpFit {
        fn n_params(&self) -> usize {
            3
        }
        fn n_residuals(&self) -> usize {
            self.t.len()
        }
        fn residuals(&self, p: &[f64], r: &mut [f64]) {
            for i in 0..self.t.len() {
                r[i] = p[0] * (-p[1] * self.t[i]).exp() + p[2] - self.y[i];
            }
        }
        fn jacobian(&self, p: &[f64], j: &mut [f64]) {
            for i in 0..self.t.len() {
                let e = (-p[1] * self.t[i]).exp();
                j[i * 3] = e;
                j[i * 3 + 1] = -p[0] * self.t[i] * e;
                j[i * 3 + 2] = 1.0;
            }
        }
    }

    /// Linear regression y = a + b t with residual noise: closed-form answer and covariance.
    struct Line {
        t: Vec<f64>,
        y: Vec<f64>,
    }
    impl LeastSquaresProblem for Line {
        fn n_params(&self) -> usize {
            2
        }
        fn n_residuals(&self) -> usize {
            self.t.len()
        }
        fn residuals(&self, p: &[f64], r: &mut [f64]) {
            for i in 0..self.t.len() {
                r[i] = p[0] + p[1] * self.t[i] - self.y[i];
            }
        }
        fn jacobian(&self, _p: &[f64], j: &mut [f64]) {
            for i in 0..self.t.len() {
                j[i * 2] = 1.0;
                j[i * 2 + 1] = self.t[i];
            }
        }
    }

    #[test]
    fn rosenbrock_reaches_the_minimum() {
        let rep = minimize(&Rosenbrock, &[-1.2, 1.0], &LmConfig::tight()).unwrap();
        assert!((rep.params[0] - 1.0).abs() < 1e-10, "{:?}", rep);
        assert!((rep.params[1] - 1.0).abs() < 1e-10, "{:?}", rep);
        assert!(rep.termination.converged());
    }

    #[test]
    fn exponential_fit_recovers_exact_parameters() {
        let t: Vec<f64> = (0..30).map(|i| i as f64 * 0.2).collect();
        let y = t.iter().map(|&t| 2.5 * (-0.7 * t).exp() + 0.3).collect();
        let prob = ExpFit { t, y };
        let mut solver = LmSolver::new();
        let rep = solver
            .solve(&prob, &[1.0, 0.1, 0.0], &LmConfig::default())
            .unwrap();
        for (a, b) in rep.params.iter().zip([2.5, 0.7, 0.3]) {
            assert!((a - b).abs() < 1e-7, "{:?}", rep);
        }
        // Reuse of the workspace gives the identical answer.
        let rep2 = solver
            .solve(&prob, &[1.0, 0.1, 0.0], &LmConfig::default())
            .unwrap();
        assert_eq!(rep.params, rep2.params);
    }

    #[test]
    fn max_evals_is_reported() {
        let cfg = LmConfig {
            max_evals: 3,
            ..LmConfig::tight()
        };
        let rep = minimize(&Rosenbrock, &[-1.2, 1.0], &cfg).unwrap();
        assert_eq!(rep.termination, Termination::MaxEvals);
        assert!(rep.n_evals <= 3);
    }

    #[test]
    fn gtol_is_reported() {
        let t: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, &t)| 1.0 + 2.0 * t + if i % 2 == 0 { 0.1 } else { -0.1 })
            .collect();
        let cfg = LmConfig {
            gtol: 1e-6,
            ftol: 0.0,
            xtol: 0.0,
            ..LmConfig::default()
        };
        let rep = minimize(&Line { t, y }, &[0.0, 0.0], &cfg).unwrap();
        assert_eq!(rep.termination, Termination::Gtol);
    }

    #[test]
    fn line_fit_and_covariance_match_closed_form() {
        let t: Vec<f64> = (0..12).map(|i| i as f64 * 0.5).collect();
        let noise = [
            0.1, -0.2, 0.05, 0.3, -0.1, 0.0, 0.2, -0.25, 0.15, -0.05, 0.1, -0.3,
        ];
        let y: Vec<f64> = t
            .iter()
            .zip(noise)
            .map(|(&t, e)| 1.0 + 2.0 * t + e)
            .collect();
        let n = t.len() as f64;
        let (st, sy) = (t.iter().sum::<f64>(), y.iter().sum::<f64>());
        let stt = t.iter().map(|v| v * v).sum::<f64>();
        let sty = t.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>();
        let det = n * stt - st * st;
        let b = (n * sty - st * sy) / det;
        let a = (sy - b * st) / n;
        let prob = Line {
            t: t.clone(),
            y: y.clone(),
        };
        let rep = minimize(&prob, &[0.0, 0.0], &LmConfig::tight()).unwrap();
        assert!((rep.params[0] - a).abs() < 1e-12 && (rep.params[1] - b).abs() < 1e-12);
        let mut jac = vec![0.0; t.len() * 2];
        prob.jacobian(&rep.params, &mut jac);
        let cov = covariance(&jac, t.len(), 2, rep.cost).unwrap();
        let s2 = rep.cost / (n - 2.0);
        let exact = [s2 * stt / det, -s2 * st / det, -s2 * st / det, s2 * n / det];
        for (c, e) in cov.iter().zip(exact) {
            assert!((c - e).abs() <= 1e-12 * e.abs().max(1e-3), "{c} vs {e}");
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(minimize(&Rosenbrock, &[f64::NAN, 1.0], &LmConfig::default()).is_err());
        assert!(minimize(&Rosenbrock, &[1.0], &LmConfig::default()).is_err());
        let cfg = LmConfig {
            ftol: -1.0,
            ..LmConfig::default()
        };
        assert!(minimize(&Rosenbrock, &[0.0, 0.0], &cfg).is_err());
        assert!(covariance(&[1.0, 2.0], 1, 2, 1.0).is_err());
    }
}
