//! Fitting the mapping models to point pairs.
//!
//! [`fit_mapping`] is the accurate, validating path (pixel input, a [`Mapping`] out): P3 by
//! Householder QR (it is linear in its coefficients), R1/R2 from the linearised (DLT-style)
//! solution by QR refined by Levenberg-Marquardt on the normalised geometric residuals (by
//! variable projection, the refit's solver at tight tolerances), then residual statistics and
//! the coefficient covariance `s^2 (J^T J)^-1`.
//!
//! [`FitWorkspace`] is the fast, allocation-free refit in normalised coordinates for the Monte
//! Carlo study: normal equations with Cholesky for P3, LM with a structured `J^T J` and an
//! optional warm start for R1/R2.

use crate::error::{DewarpError, Result};
use crate::lm::{self, LeastSquaresProblem, LmConfig};
use crate::mapping::{FitStats, Mapping};
use crate::models::{eval_coeff_jacobian, eval_normalized, p3_basis, Model};
use ndarray::ArrayView2;

/// Options of [`fit_mapping`].
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// Index of the central marker (the origin of both normalised frames). Default: the object
    /// point nearest the centroid of the object points.
    pub center_index: Option<usize>,
    /// The normalising scale `s` in px. Default: `max |x_o|` over the object points (the
    /// paper's `x_o_max`).
    pub scale: Option<f64>,
    /// Levenberg-Marquardt settings for R1/R2. Default: [`LmConfig::tight`] (reference-quality).
    pub lm: LmConfig,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            center_index: None,
            scale: None,
            lm: LmConfig::tight(),
        }
    }
}

fn invalid(msg: String) -> DewarpError {
    DewarpError::InvalidInput(msg)
}

/// Read an `(N, 2)` array of points, checking its shape and values.
fn read_points(name: &str, a: ArrayView2<f64>) -> Result<Vec<[f64; 2]>> {
    if a.ncols() != 2 {
        return Err(invalid(format!(
            "{name} must have shape (N, 2), got ({}, {})",
            a.nrows(),
            a.ncols()
        )));
    }
    let mut out = Vec::with_capacity(a.nrows());
    for (i, row) in a.rows().into_iter().enumerate() {
        let (x, y) = (row[0], row[1]);
        if !(x.is_finite() && y.is_finite()) {
            return Err(invalid(format!(
                "{name} point {i} is not finite ({x}, {y})"
            )));
        }
        out.push([x, y]);
    }
    Ok(out)
}

/// First pair of (near-)coincident points, if any (tolerance `tol` in the points' unit).
fn find_duplicate(pts: &[[f64; 2]], tol: f64) -> Option<(usize, usize)> {
    let mut idx: Vec<usize> = (0..pts.len()).collect();
    idx.sort_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]));
    for (k, &i) in idx.iter().enumerate() {
        for &j in &idx[k + 1..] {
            if pts[j][0] - pts[i][0] > tol {
                break;
            }
            if (pts[j][1] - pts[i][1]).abs() <= tol {
                return Some((i.min(j), i.max(j)));
            }
        }
    }
    None
}

/// True if the points lie (numerically) on one straight line.
fn collinear(pts: &[[f64; 2]]) -> bool {
    let n = pts.len() as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p[0] / n, b + p[1] / n));
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    // smallest / largest eigenvalue of the scatter matrix
    let disc = ((sxx - syy) * (sxx - syy) / 4.0 + sxy * sxy).sqrt();
    let lmax = tr / 2.0 + disc;
    let lmin = if lmax > 0.0 { det / lmax } else { 0.0 };
    lmax <= 0.0 || lmin <= 1e-10 * lmax
}

/// Dot product with four independent partial sums (the additions pipeline instead of waiting
/// on one another; rounding differs from a sequential sum only in the last bits).
#[inline]
fn dot(u: &[f64], v: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (uc, ur) = u.split_at(u.len() - u.len() % 4);
    let (vc, vr) = v.split_at(uc.len());
    for (a, b) in uc.chunks_exact(4).zip(vc.chunks_exact(4)) {
        for l in 0..4 {
            acc[l] += a[l] * b[l];
        }
    }
    let tail: f64 = ur.iter().zip(vr).map(|(a, b)| a * b).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Householder QR of `A` (`m x n`, column-major in `cols`: column `j` at
/// `cols[j * m..(j + 1) * m]`), the reflections applied to `B` (`m x k`, column-major in `rhs`).
/// Column-major keeps every dot product and update a contiguous slice. On return `cols` holds
/// `R` above its diagonal (the diagonal in the returned vector) and `rhs` holds `Q^T B`; `None`
/// if `A` is rank-deficient (a column's remaining norm below `1e-10` of its original norm).
pub(crate) fn householder(
    cols: &mut [f64],
    m: usize,
    n: usize,
    rhs: &mut [f64],
) -> Option<Vec<f64>> {
    let mut rdiag = vec![0.0; n];
    for j in 0..n {
        let (done, rest) = cols.split_at_mut((j + 1) * m);
        let v = &mut done[j * m..];
        let col_norm0 = dot(v, v).sqrt();
        let norm = dot(&v[j..], &v[j..]).sqrt();
        if col_norm0 == 0.0 || norm <= 1e-10 * col_norm0 {
            return None;
        }
        let alpha = if v[j] > 0.0 { -norm } else { norm };
        // v = a[j..m, j] - alpha e1, stored in place
        v[j] -= alpha;
        let v = &v[j..];
        let vnorm2 = dot(v, v);
        rdiag[j] = alpha;
        if vnorm2 == 0.0 {
            continue;
        }
        let reflect = |col: &mut [f64]| {
            let col = &mut col[j..];
            let f = 2.0 * dot(v, col) / vnorm2;
            col.iter_mut().zip(v).for_each(|(c, vi)| *c -= f * vi);
        };
        rest.chunks_exact_mut(m).for_each(reflect);
        rhs.chunks_exact_mut(m).for_each(reflect);
    }
    Some(rdiag)
}

/// Solve `R x = y` for the `R` that [`householder`] left in `cols`/`rdiag` (`y`: `n` values).
fn back_substitute(cols: &[f64], m: usize, rdiag: &[f64], y: &[f64], x: &mut [f64]) {
    let n = rdiag.len();
    for j in (0..n).rev() {
        let mut acc = y[j];
        for l in j + 1..n {
            acc -= cols[l * m + j] * x[l];
        }
        x[j] = acc / rdiag[j];
    }
}

/// Least squares `min ||A x - B||` by Householder QR ([`householder`]: `A` column-major in
/// `cols`, `B` (`m x k`) column-major in `rhs`, both overwritten). Returns `x` row-major
/// `n x k`, or `None` if `A` is rank-deficient or the solution is not finite.
pub(crate) fn lstsq_qr(
    cols: &mut [f64],
    m: usize,
    n: usize,
    rhs: &mut [f64],
    k: usize,
) -> Option<Vec<f64>> {
    let rdiag = householder(cols, m, n, rhs)?;
    let mut x = vec![0.0; n * k];
    let mut xc = vec![0.0; n];
    for c in 0..k {
        back_substitute(cols, m, &rdiag, &rhs[c * m..c * m + n], &mut xc);
        for j in 0..n {
            x[j * k + c] = xc[j];
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Least squares of the rational models' block structure, for both axes at once:
/// `min sum_axis || S a_axis + P_axis d - t_axis ||` over the axes' own coefficients `a_x`,
/// `a_y` (`q` each) and the shared `d` (`r`), with `S` (`N x q`, column-major in `shared`)
/// common to both axes. `per_axis` holds, per axis (x, then y), the `r` columns of `P_axis`
/// and then `t_axis` (column-major, `N` each). Block elimination: the QR of `S` projects both
/// axes onto its orthogonal complement, where only `d` remains (one QR of `2 (N - q) x r`);
/// `a_axis` follows from `R a = (Q^T t)_top - (Q^T P)_top d`. The same solution as the QR of
/// the whole `2N x (2q + r)` system at a fraction of its flops. Returns the coefficients in
/// the models' order (`a_x`, `a_y`, `d`), `None` if rank-deficient or not finite.
fn rational_lstsq(
    shared: &mut [f64],
    per_axis: &mut [f64],
    npts: usize,
    q: usize,
    r: usize,
) -> Option<[f64; 20]> {
    let m = npts;
    let rdiag = householder(shared, m, q, per_axis)?;
    let mb = m - q;
    let mut pcols = vec![0.0; 2 * mb * r];
    let mut t = vec![0.0; 2 * mb];
    for axis in 0..2 {
        let base = axis * (r + 1);
        for c in 0..r {
            let dst = c * 2 * mb + axis * mb;
            pcols[dst..dst + mb].copy_from_slice(&per_axis[(base + c) * m + q..(base + c + 1) * m]);
        }
        t[axis * mb..(axis + 1) * mb]
            .copy_from_slice(&per_axis[(base + r) * m + q..(base + r + 1) * m]);
    }
    let d = lstsq_qr(&mut pcols, 2 * mb, r, &mut t, 1)?;
    let mut c = [0.0; 20];
    let mut top = [0.0; 6];
    for axis in 0..2 {
        let base = axis * (r + 1);
        for (a, v) in top[..q].iter_mut().enumerate() {
            *v = per_axis[(base + r) * m + a]
                - (0..r)
                    .map(|k| per_axis[(base + k) * m + a] * d[k])
                    .sum::<f64>();
        }
        back_substitute(
            shared,
            m,
            &rdiag,
            &top[..q],
            &mut c[axis * q..(axis + 1) * q],
        );
    }
    c[2 * q..2 * q + r].copy_from_slice(&d);
    c.iter().all(|v| v.is_finite()).then_some(c)
}

/// Numerator and denominator sizes `(q, r)` of R1/R2 (`D = 1 + psi . d`).
fn rational_sizes(model: Model) -> (usize, usize) {
    match model {
        Model::R1 => (3, 2),
        _ => (6, 5),
    }
}

/// The linearised (DLT) solution of R1/R2: `N(x) - t D'(x) = t` per axis with `D = 1 + D'`
/// (`t` the image coordinate), in least squares by [`rational_lstsq`] (`S = phi`,
/// `P = -t psi`). Coefficients in the model's order; `None` when degenerate.
fn dlt_start(model: Model, obj: &[[f64; 2]], img: &[[f64; 2]]) -> Option<[f64; 20]> {
    let (q, r) = rational_sizes(model);
    let m = obj.len();
    let mut phi = vec![0.0; m * q];
    let mut per_axis = vec![0.0; m * 2 * (r + 1)];
    for (j, (o, i)) in obj.iter().zip(img).enumerate() {
        let (ph, ps) = varpro::rational_bases(model, o[0], o[1]);
        for a in 0..q {
            phi[a * m + j] = ph[a];
        }
        for (axis, t) in [i[0], i[1]].into_iter().enumerate() {
            let base = axis * (r + 1);
            for c in 0..r {
                per_axis[(base + c) * m + j] = -t * ps[c];
            }
            per_axis[(base + r) * m + j] = t;
        }
    }
    rational_lstsq(&mut phi, &mut per_axis, m, q, r)
}

/// One Gauss-Newton step of R1/R2 at `c`: `min || J delta + res ||` with the Jacobian's
/// block structure (numerator columns `phi / D` for both axes, denominator columns
/// `-f psi / D`), by [`rational_lstsq`]. The step, `None` when degenerate.
fn gauss_newton_step(
    model: Model,
    obj: &[[f64; 2]],
    img: &[[f64; 2]],
    c: &[f64],
) -> Option<[f64; 20]> {
    let (q, r) = rational_sizes(model);
    let m = obj.len();
    let mut s = vec![0.0; m * q];
    let mut per_axis = vec![0.0; m * 2 * (r + 1)];
    for (j, (o, i)) in obj.iter().zip(img).enumerate() {
        let (ph, ps) = varpro::rational_bases(model, o[0], o[1]);
        let den = 1.0 + (0..r).map(|k| c[2 * q + k] * ps[k]).sum::<f64>();
        let inv = 1.0 / den;
        for a in 0..q {
            s[a * m + j] = ph[a] * inv;
        }
        for axis in 0..2 {
            let f = (0..q).map(|a| c[axis * q + a] * ph[a]).sum::<f64>() * inv;
            let base = axis * (r + 1);
            for k in 0..r {
                per_axis[(base + k) * m + j] = -f * ps[k] * inv;
            }
            per_axis[(base + r) * m + j] = i[axis] - f;
        }
    }
    rational_lstsq(&mut s, &mut per_axis, m, q, r)
}

/// Nonzero coefficient indices of the x and y rows of the coefficient Jacobian.
fn sparsity(model: Model) -> (&'static [usize], &'static [usize]) {
    match model {
        Model::R1 => (&[0, 1, 2, 6, 7], &[3, 4, 5, 6, 7]),
        Model::R2 => (
            &[0, 1, 2, 3, 4, 5, 12, 13, 14, 15, 16],
            &[6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16],
        ),
        Model::P3 => (
            &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9],
            &[10, 11, 12, 13, 14, 15, 16, 17, 18, 19],
        ),
    }
}

/// The normalised fitting problem: residuals `F(obj_hat_j) - img_hat_j`, interleaved x, y.
pub struct MappingProblem<'a> {
    /// Model to fit.
    pub model: Model,
    /// Normalised object points.
    pub obj: &'a [[f64; 2]],
    /// Normalised image points.
    pub img: &'a [[f64; 2]],
}

impl LeastSquaresProblem for MappingProblem<'_> {
    fn n_params(&self) -> usize {
        self.model.n_params()
    }
    fn n_residuals(&self) -> usize {
        2 * self.obj.len()
    }
    fn residuals(&self, p: &[f64], r: &mut [f64]) {
        for (j, (o, i)) in self.obj.iter().zip(self.img).enumerate() {
            let (fx, fy) = eval_normalized(self.model, p, o[0], o[1]);
            r[2 * j] = fx - i[0];
            r[2 * j + 1] = fy - i[1];
        }
    }
    fn jacobian(&self, p: &[f64], jac: &mut [f64]) {
        let n = self.model.n_params();
        for (j, o) in self.obj.iter().enumerate() {
            let (rx, ry) = jac[2 * j * n..(2 * j + 2) * n].split_at_mut(n);
            eval_coeff_jacobian(self.model, p, o[0], o[1], rx, ry);
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
        let n = self.model.n_params();
        let (ix, iy) = sparsity(self.model);
        jtj[..n * n].fill(0.0);
        jtr[..n].fill(0.0);
        let mut jx = [0.0; crate::models::MAX_PARAMS];
        let mut jy = [0.0; crate::models::MAX_PARAMS];
        // the x rows and the y rows each touch only their own `q <= 11` coefficients: their
        // Gram blocks are accumulated compactly (no scattered indexing in the loop over the
        // points), then added into J^T J
        const Q: usize = 11;
        let (qx, qy) = (ix.len(), iy.len());
        let mut gxx = [0.0; Q * Q];
        let mut gyy = [0.0; Q * Q];
        let mut rx = [0.0; Q];
        let mut ry = [0.0; Q];
        let accumulate = |gram: &mut [f64; Q * Q], rt: &mut [f64; Q], g: &[f64], res: f64| {
            for (a, &ga) in g.iter().enumerate() {
                rt[a] += ga * res;
                let row = &mut gram[a * Q..a * Q + a + 1];
                row.iter_mut().zip(g).for_each(|(o, gb)| *o += ga * gb);
            }
        };
        // P3: the x and y rows are the same basis on disjoint coefficients, so the two Gram
        // blocks are equal; accumulate one
        let shared = self.model == Model::P3;
        let mut g = [0.0; Q];
        for (j, o) in self.obj.iter().enumerate() {
            eval_coeff_jacobian(self.model, p, o[0], o[1], &mut jx, &mut jy);
            for (a, &i) in ix.iter().enumerate() {
                g[a] = jx[i];
            }
            accumulate(&mut gxx, &mut rx, &g[..qx], r[2 * j]);
            for (a, &i) in iy.iter().enumerate() {
                g[a] = jy[i];
            }
            if shared {
                let res = r[2 * j + 1];
                ry.iter_mut()
                    .zip(&g[..qy])
                    .for_each(|(t, ga)| *t += ga * res);
            } else {
                accumulate(&mut gyy, &mut ry, &g[..qy], r[2 * j + 1]);
            }
        }
        let gyy = if shared { &gxx } else { &gyy };
        for (gram, rt, idx) in [(&gxx, &rx, ix), (gyy, &ry, iy)] {
            for (a, &ia) in idx.iter().enumerate() {
                jtr[ia] += rt[a];
                for (b, &ib) in idx[..=a].iter().enumerate() {
                    jtj[ia * n + ib] += gram[a * Q + b];
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                jtj[b * n + a] = jtj[a * n + b];
            }
        }
    }
}

/// Residual statistics in image px from residuals (fitted minus measured).
fn stats_of(model: Model, res: &[[f64; 2]]) -> FitStats {
    let n = res.len().max(1) as f64;
    let mut st = FitStats {
        model,
        n_points: res.len(),
        max_abs_px: [0.0; 2],
        mean_px: [0.0; 2],
        rms_px: [0.0; 2],
        cost: 0.0,
        termination: String::new(),
        n_evals: 0,
    };
    for r in res {
        for a in 0..2 {
            st.max_abs_px[a] = st.max_abs_px[a].max(r[a].abs());
            st.mean_px[a] += r[a] / n;
            st.rms_px[a] += r[a] * r[a] / n;
        }
    }
    st.rms_px = [st.rms_px[0].sqrt(), st.rms_px[1].sqrt()];
    st
}

/// Sum of squared normalised residuals of `c` and a bound on its rounding error (each residual
/// `f - t` carries about `eps (|f| + |t|)`).
fn cost_and_noise(model: Model, c: &[f64], obj: &[[f64; 2]], img: &[[f64; 2]]) -> (f64, f64) {
    let (mut cost, mut noise) = (0.0, 0.0);
    for (o, i) in obj.iter().zip(img) {
        let (fx, fy) = eval_normalized(model, c, o[0], o[1]);
        let (rx, ry) = (fx - i[0], fy - i[1]);
        cost += rx * rx + ry * ry;
        noise += rx.abs() * (fx.abs() + i[0].abs()) + ry.abs() * (fy.abs() + i[1].abs());
    }
    (cost, 2.0 * f64::EPSILON * noise)
}

/// Gauss-Newton steps on all coefficients of R1/R2 from variable projection's optimum, each by
/// the QR of the Jacobian ([`gauss_newton_step`]: conditioned like `J`, not `J^T J`). Variable
/// projection forms its reduced Hessian explicitly (a Schur complement), which loses digits along R2's
/// nearly degenerate numerator/denominator direction, where the cost is flat to rounding but
/// the coefficients, and with them the covariance, are not (the gradient there is left at
/// ~1e-7 of its scale; after one step it is at rounding). A step is kept when it does not
/// raise the cost beyond its rounding error; at most two, and none after a step below 1e-13 of
/// the coefficients (their rounding). Returns the steps taken.
fn polish_gauss_newton(model: Model, obj: &[[f64; 2]], img: &[[f64; 2]], c: &mut [f64]) -> usize {
    let (mut cost, mut noise) = cost_and_noise(model, c, obj, img);
    let mut steps = 0;
    while steps < 2 {
        let Some(delta) = gauss_newton_step(model, obj, img, c) else {
            break;
        };
        let trial: Vec<f64> = c.iter().zip(&delta).map(|(a, d)| a + d).collect();
        let (cost_t, noise_t) = cost_and_noise(model, &trial, obj, img);
        if !cost_t.is_finite() || cost_t > cost + noise {
            break;
        }
        let size = delta
            .iter()
            .zip(c.iter())
            .map(|(d, a)| (d / a.abs().max(1e-3)).abs())
            .fold(0.0, f64::max);
        c.copy_from_slice(&trial);
        (cost, noise) = (cost_t, noise_t);
        steps += 1;
        if size <= 1e-13 {
            break;
        }
    }
    steps
}

fn degenerate(model: Model) -> DewarpError {
    invalid(format!(
        "the points do not determine the {model} coefficients (degenerate geometry: too few \
         distinct points or points on a line/conic)"
    ))
}

/// Fit `model` to the point pairs `object_px` -> `image_px` (both `(N, 2)`, px).
pub fn fit_mapping(
    object_px: ArrayView2<f64>,
    image_px: ArrayView2<f64>,
    model: Model,
    opts: &FitOptions,
) -> Result<Mapping> {
    let obj_px = read_points("object points", object_px)?;
    let img_px = read_points("image points", image_px)?;
    if obj_px.len() != img_px.len() {
        return Err(invalid(format!(
            "object points ({}) and image points ({}) differ in number",
            obj_px.len(),
            img_px.len()
        )));
    }
    let npts = obj_px.len();
    if npts < model.min_points() {
        return Err(invalid(format!(
            "model {model} has {} coefficients and needs at least {} points, got {npts}",
            model.n_params(),
            model.min_points()
        )));
    }
    let extent = |p: &[[f64; 2]]| {
        p.iter()
            .fold(0.0_f64, |m, q| m.max(q[0].abs()).max(q[1].abs()))
            .max(1.0)
    };
    for (name, pts) in [("object", &obj_px), ("image", &img_px)] {
        if let Some((i, j)) = find_duplicate(pts, 1e-9 * extent(pts)) {
            return Err(invalid(format!(
                "{name} points {i} and {j} coincide (duplicate points)"
            )));
        }
        if collinear(pts) {
            return Err(invalid(format!("{name} points are collinear")));
        }
    }
    let ci = match opts.center_index {
        Some(i) if i < npts => i,
        Some(i) => {
            return Err(invalid(format!(
                "center_index {i} is out of range for {npts} points"
            )))
        }
        None => {
            let n = npts as f64;
            let (mx, my) = obj_px
                .iter()
                .fold((0.0, 0.0), |(a, b), p| (a + p[0] / n, b + p[1] / n));
            let d2 = |p: &[f64; 2]| (p[0] - mx).powi(2) + (p[1] - my).powi(2);
            (0..npts)
                .min_by(|&a, &b| d2(&obj_px[a]).total_cmp(&d2(&obj_px[b])))
                .unwrap_or(0)
        }
    };
    let scale = match opts.scale {
        Some(s) if s.is_finite() && s > 0.0 => s,
        Some(s) => {
            return Err(invalid(format!(
                "scale must be positive and finite, got {s}"
            )))
        }
        None => {
            let s = obj_px.iter().fold(0.0_f64, |m, p| m.max(p[0].abs()));
            if s <= 0.0 {
                return Err(invalid(
                    "scale: max |x| of the object points is zero; pass a scale".into(),
                ));
            }
            s
        }
    };
    let co = obj_px[ci];
    let cim = img_px[ci];
    let obj: Vec<[f64; 2]> = obj_px
        .iter()
        .map(|p| [(p[0] - co[0]) / scale, (p[1] - co[1]) / scale])
        .collect();
    let img: Vec<[f64; 2]> = img_px
        .iter()
        .map(|p| [(p[0] - cim[0]) / scale, (p[1] - cim[1]) / scale])
        .collect();

    let n = model.n_params();
    let m = 2 * npts;
    let (coeffs, termination, n_evals) = match model {
        Model::P3 => {
            // column-major: basis term c of point j at a[c * npts + j]; rhs x then y
            let mut a = vec![0.0; npts * 10];
            let mut b = vec![0.0; npts * 2];
            for (j, (o, i)) in obj.iter().zip(&img).enumerate() {
                for (c, v) in p3_basis(o[0], o[1]).into_iter().enumerate() {
                    a[c * npts + j] = v;
                }
                b[j] = i[0];
                b[npts + j] = i[1];
            }
            let x = lstsq_qr(&mut a, npts, 10, &mut b, 2).ok_or_else(|| degenerate(model))?;
            let mut c = vec![0.0; 20];
            for k in 0..10 {
                c[k] = x[2 * k];
                c[10 + k] = x[2 * k + 1];
            }
            (c, "linear".to_string(), 0)
        }
        Model::R1 | Model::R2 => {
            let mut c = dlt_start(model, &obj, &img).ok_or_else(|| degenerate(model))?;
            // Levenberg-Marquardt by variable projection (the Monte Carlo refit's solver at
            // `opts.lm`'s tolerances): the numerators eliminated, the exact reduced Hessian on
            // the 2 (R1) or 5 (R2) denominator coefficients; the optimum of a full LM on all
            // coefficients (tested) in a fraction of its time. The QR start (rather than the
            // refit's normal equations) saves it iterations at tight tolerances.
            let rep = varpro::varpro_rational(model, &obj, &img, &mut c, &opts.lm)?;
            if !rep.termination.converged() {
                return Err(DewarpError::NotConverged(format!(
                    "fitting {model}: Levenberg-Marquardt used {} evaluations without converging",
                    rep.n_evals
                )));
            }
            let polish = polish_gauss_newton(model, &obj, &img, &mut c[..n]);
            (
                c[..n].to_vec(),
                rep.termination.name().to_string(),
                rep.n_evals + polish,
            )
        }
    };
    // Residuals in px, statistics, covariance.
    let mut res = Vec::with_capacity(npts);
    let mut cost = 0.0;
    for (o, i) in obj.iter().zip(&img) {
        let (fx, fy) = eval_normalized(model, &coeffs, o[0], o[1]);
        if !(fx.is_finite() && fy.is_finite()) {
            return Err(degenerate(model));
        }
        cost += (fx - i[0]).powi(2) + (fy - i[1]).powi(2);
        res.push([(fx - i[0]) * scale, (fy - i[1]) * scale]);
    }
    let prob = MappingProblem {
        model,
        obj: &obj,
        img: &img,
    };
    // J^T J from the Jacobian's sparsity (the x rows touch only the x coefficients, the y rows
    // the y ones: P3's J^T J is two 10 x 10 blocks), the same sums as the dense product.
    if m <= n {
        return Err(degenerate(model));
    }
    let mut jtj = vec![0.0; n * n];
    let mut jtr = vec![0.0; n];
    prob.normal_equations(&coeffs, &vec![0.0; m], &mut [], &mut jtj, &mut jtr);
    let covariance = lm::covariance_from_jtj(&mut jtj, n, cost / (m - n) as f64)
        .map_err(|_| degenerate(model))?;
    let mut stats = stats_of(model, &res);
    stats.cost = cost;
    stats.termination = termination;
    stats.n_evals = n_evals;
    Ok(Mapping {
        model,
        coefficients: coeffs,
        centre_object: co,
        centre_image: cim,
        scale,
        rotation: 0.0,
        stats,
        covariance,
        residuals: res,
    })
}

#[cfg(test)]
mod tests;
mod varpro;
mod workspace;

pub use workspace::FitWorkspace;
