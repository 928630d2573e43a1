//! Monte Carlo sensitivity study of a mapping (paper section 4).
//!
//! For each of `n` samples: every image point is perturbed by independent normal noise of
//! standard deviation `sigma_image_px` per axis, every object point by `sigma_object_px`,
//! except the central marker, which stays fixed (the paper keeps `P_ic = P_oc = (0, 0)` in
//! normalised coordinates); both sets are normalised with the nominal centre and scale; the
//! model is refitted ([`FitWorkspace`], R1/R2 warm-started from the nominal solution); and each
//! marker's residual `eps_j = F_n(P_O,j,n) - P_I,j,n` (fitted minus measured, the sign
//! convention of [`crate::mapping::FitStats`], image px) is accumulated.
//!
//! Reproducibility: samples are processed in fixed chunks of [`CHUNK`] samples; chunk `c` draws
//! from `ChaCha8Rng::seed_from_u64(seed)` with stream `c`, and the per-chunk floating-point
//! sums are merged in chunk order, so a result depends on `seed` only, not on the number of
//! threads. Counts and histograms are integers (order-free).
//!
//! Per marker the result holds the mean residual, its 2 x 2 covariance, the 99 % radius (the
//! radius about zero holding 99 % of the residuals, from a fine radial histogram: resolution
//! `r_max / 1024`, linear within a bin), the fractions within 1 and 2 px, and optionally a 2D histogram (the JPDF of
//! the paper's Fig. 9) and all samples.

use crate::error::{DewarpError, Result};
use crate::fit::FitWorkspace;
use crate::models::{eval_normalized, Model};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Samples per RNG stream / reduction chunk.
pub const CHUNK: usize = 2048;
/// Radial histogram bins per marker (small enough to stay in cache: 91 markers x 4 KiB).
const RADIAL_BINS: usize = 1024;

/// Inputs of [`monte_carlo`].
#[derive(Debug, Clone)]
pub struct MonteCarloConfig {
    pub model: Model,
    /// Number of samples.
    pub n: usize,
    /// Per-axis standard deviation of the image points (px).
    pub sigma_image_px: f64,
    /// Per-axis standard deviation of the object points (px).
    pub sigma_object_px: f64,
    /// Index of the central (fixed) marker.
    pub centre_index: usize,
    /// Normalising scale (px); `None`: `max |x_o|` over the object points.
    pub scale: Option<f64>,
    pub seed: u64,
    /// Bins per axis of the optional per-marker 2D histogram (0: none) and its half range (px).
    pub hist_bins: usize,
    pub hist_half_range_px: f64,
    /// Keep every residual (n x m x 2, f32).
    pub keep_samples: bool,
    /// Worker threads (`None`: the global rayon pool).
    pub threads: Option<usize>,
}

/// Output of [`monte_carlo`]; arrays are per marker, in input order.
#[derive(Debug, Clone, PartialEq)]
pub struct MonteCarloResult {
    /// Samples that entered the statistics (n minus failed refits).
    pub n_ok: usize,
    pub n_failed: usize,
    pub mean: Vec<[f64; 2]>,
    /// Covariance (xx, xy, yy), px^2.
    pub cov: Vec<[f64; 3]>,
    pub radius99: Vec<f64>,
    pub within1: Vec<f64>,
    pub within2: Vec<f64>,
    /// Residual of the nominal (unperturbed) fit, px.
    pub nominal: Vec<[f64; 2]>,
    /// `m * bins * bins` counts, row-major (marker, y bin, x bin), or empty.
    pub hist: Vec<u32>,
    /// `n_ok * m * 2` residuals, or empty.
    pub samples: Vec<f32>,
}

struct ChunkOut {
    sums: Vec<f64>, // per marker: sx, sy, sxx, sxy, syy
    n_ok: usize,
    samples: Vec<f32>,
}

/// One rayon fold's chunk outputs (with their chunk numbers) and integer counts.
type FoldPart = (Vec<(usize, ChunkOut)>, Option<Counts>);

struct Counts {
    radial: Vec<u32>,
    within: Vec<[u64; 2]>,
    hist: Vec<u32>,
}

fn invalid(msg: String) -> DewarpError {
    DewarpError::InvalidInput(msg)
}

/// Run the Monte Carlo study; see the module documentation.
pub fn monte_carlo(
    obj_px: &[[f64; 2]],
    img_px: &[[f64; 2]],
    cfg: &MonteCarloConfig,
) -> Result<MonteCarloResult> {
    let m = obj_px.len();
    if img_px.len() != m {
        return Err(invalid(format!(
            "monte carlo: {m} object points but {} image points",
            img_px.len()
        )));
    }
    if m < cfg.model.min_points() {
        return Err(invalid(format!(
            "monte carlo: model {} needs at least {} markers, got {m}",
            cfg.model.name(),
            cfg.model.min_points()
        )));
    }
    if cfg.centre_index >= m {
        return Err(invalid(format!(
            "monte carlo: centre index {} out of range for {m} markers",
            cfg.centre_index
        )));
    }
    if cfg.n == 0 {
        return Err(invalid("monte carlo: n must be > 0".into()));
    }
    for (name, v) in [
        ("sigma_image_px", cfg.sigma_image_px),
        ("sigma_object_px", cfg.sigma_object_px),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(invalid(format!(
                "monte carlo: {name} = {v} must be finite and >= 0"
            )));
        }
    }
    if cfg.hist_bins > 0 && !(cfg.hist_half_range_px.is_finite() && cfg.hist_half_range_px > 0.0) {
        return Err(invalid(
            "monte carlo: histogram half range must be > 0".into(),
        ));
    }
    if cfg.hist_bins > 1024 {
        return Err(invalid(
            "monte carlo: at most 1024 histogram bins per axis".into(),
        ));
    }
    if cfg.keep_samples && cfg.n.saturating_mul(m) > 200_000_000 {
        return Err(invalid(format!(
            "monte carlo: keeping {} x {m} samples would need more than 1.6 GB",
            cfg.n
        )));
    }
    if obj_px
        .iter()
        .chain(img_px)
        .any(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(invalid("monte carlo: non-finite marker position".into()));
    }
    let co = obj_px[cfg.centre_index];
    let ci = img_px[cfg.centre_index];
    let s = match cfg.scale {
        Some(s) if s.is_finite() && s > 0.0 => s,
        Some(s) => return Err(invalid(format!("monte carlo: scale {s} must be > 0"))),
        None => obj_px
            .iter()
            .map(|p| p[0].abs())
            .fold(0.0, f64::max)
            .max(1e-300),
    };
    let obj_hat: Vec<[f64; 2]> = obj_px
        .iter()
        .map(|p| [(p[0] - co[0]) / s, (p[1] - co[1]) / s])
        .collect();
    let img_hat: Vec<[f64; 2]> = img_px
        .iter()
        .map(|p| [(p[0] - ci[0]) / s, (p[1] - ci[1]) / s])
        .collect();
    let model = cfg.model;
    let mut ws0 = FitWorkspace::new();
    let nominal_coeffs = ws0
        .fit_normalized(model, &obj_hat, &img_hat, None)?
        .to_vec();
    let nominal: Vec<[f64; 2]> = (0..m)
        .map(|j| {
            let (fx, fy) = eval_normalized(model, &nominal_coeffs, obj_hat[j][0], obj_hat[j][1]);
            [(fx - img_hat[j][0]) * s, (fy - img_hat[j][1]) * s]
        })
        .collect();
    let spread = (cfg.sigma_image_px.powi(2) + cfg.sigma_object_px.powi(2)).sqrt();
    let r_max = nominal.iter().map(|r| r[0].hypot(r[1])).fold(0.0, f64::max) + 12.0 * spread + 1e-6;
    let rbin = RADIAL_BINS as f64 / r_max;
    let n_chunks = cfg.n.div_ceil(CHUNK);
    let (si, so) = (cfg.sigma_image_px / s, cfg.sigma_object_px / s);
    let hb = cfg.hist_bins;
    let hscale = if hb > 0 {
        hb as f64 / (2.0 * cfg.hist_half_range_px)
    } else {
        0.0
    };

    let new_counts = || Counts {
        radial: vec![0; m * RADIAL_BINS],
        within: vec![[0; 2]; m],
        hist: vec![0; m * hb * hb],
    };
    let run_chunk =
        |c: usize, st: &mut (FitWorkspace, Vec<[f64; 2]>, Vec<[f64; 2]>, Counts)| -> ChunkOut {
            let (ws, o, im, counts) = st;
            let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
            rng.set_stream(c as u64);
            let len = CHUNK.min(cfg.n - c * CHUNK);
            let mut sums = vec![0.0; m * 5];
            let mut samples = Vec::new();
            if cfg.keep_samples {
                samples.reserve(len * m * 2);
            }
            let mut n_ok = 0;
            let warm = match model {
                Model::P3 => None,
                _ => Some(nominal_coeffs.as_slice()),
            };
            for _ in 0..len {
                for j in 0..m {
                    let z: [f64; 4] = [
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                    ];
                    if j == cfg.centre_index {
                        o[j] = obj_hat[j];
                        im[j] = img_hat[j];
                    } else {
                        o[j] = [obj_hat[j][0] + so * z[0], obj_hat[j][1] + so * z[1]];
                        im[j] = [img_hat[j][0] + si * z[2], img_hat[j][1] + si * z[3]];
                    }
                }
                let Ok(coeffs) = ws.fit_normalized(model, o, im, warm) else {
                    continue;
                };
                n_ok += 1;
                for j in 0..m {
                    let (fx, fy) = eval_normalized(model, coeffs, o[j][0], o[j][1]);
                    let (ex, ey) = ((fx - im[j][0]) * s, (fy - im[j][1]) * s);
                    let sm = &mut sums[5 * j..5 * j + 5];
                    sm[0] += ex;
                    sm[1] += ey;
                    sm[2] += ex * ex;
                    sm[3] += ex * ey;
                    sm[4] += ey * ey;
                    let r = (ex * ex + ey * ey).sqrt();
                    let b = ((r * rbin) as usize).min(RADIAL_BINS - 1);
                    counts.radial[j * RADIAL_BINS + b] += 1;
                    if r <= 1.0 {
                        counts.within[j][0] += 1;
                    }
                    if r <= 2.0 {
                        counts.within[j][1] += 1;
                    }
                    if hb > 0 {
                        let bx = (ex + cfg.hist_half_range_px) * hscale;
                        let by = (ey + cfg.hist_half_range_px) * hscale;
                        if bx >= 0.0 && by >= 0.0 && (bx as usize) < hb && (by as usize) < hb {
                            counts.hist[(j * hb + by as usize) * hb + bx as usize] += 1;
                        }
                    }
                    if cfg.keep_samples {
                        samples.push(ex as f32);
                        samples.push(ey as f32);
                    }
                }
            }
            ChunkOut {
                sums,
                n_ok,
                samples,
            }
        };

    let work = || {
        let init = || {
            (
                FitWorkspace::new(),
                vec![[0.0; 2]; m],
                vec![[0.0; 2]; m],
                new_counts(),
            )
        };
        // Each rayon fold keeps its own state and integer counts; chunk outputs are put back
        // in chunk order before the floating-point merge.
        let parts: Vec<FoldPart> = (0..n_chunks)
            .into_par_iter()
            .fold(
                || (Vec::new(), None),
                |(mut v, st), c| {
                    let mut st = st.unwrap_or_else(init);
                    let out = run_chunk(c, &mut st);
                    v.push((c, out));
                    (v, Some(st))
                },
            )
            .map(|(v, st)| (v, st.map(|s| s.3)))
            .collect();
        let mut outs = Vec::with_capacity(n_chunks);
        let mut counts = Vec::new();
        for (v, c) in parts {
            outs.extend(v);
            counts.extend(c);
        }
        outs.sort_by_key(|x| x.0);
        let outs: Vec<ChunkOut> = outs.into_iter().map(|x| x.1).collect();
        (outs, counts)
    };
    let (outs, counts) = match cfg.threads {
        Some(t) => {
            if t == 0 {
                return Err(invalid("monte carlo: threads must be >= 1".into()));
            }
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .map_err(|e| invalid(format!("monte carlo: cannot start {t} threads: {e}")))?;
            pool.install(work)
        }
        None => work(),
    };
    let mut total = new_counts();
    for c in &counts {
        for (a, b) in total.radial.iter_mut().zip(&c.radial) {
            *a += b;
        }
        for (a, b) in total.within.iter_mut().zip(&c.within) {
            a[0] += b[0];
            a[1] += b[1];
        }
        for (a, b) in total.hist.iter_mut().zip(&c.hist) {
            *a += b;
        }
    }
    let mut sums = vec![0.0; m * 5];
    let mut n_ok = 0;
    let mut samples = Vec::new();
    for o in &outs {
        for (a, b) in sums.iter_mut().zip(&o.sums) {
            *a += b;
        }
        n_ok += o.n_ok;
    }
    if cfg.keep_samples {
        samples.reserve(n_ok * m * 2);
        for o in outs {
            samples.extend_from_slice(&o.samples);
        }
    }
    if n_ok == 0 {
        return Err(DewarpError::NotConverged(format!(
            "monte carlo: all {} refits of {} failed",
            cfg.n,
            model.name()
        )));
    }
    let nf = n_ok as f64;
    let mut mean = Vec::with_capacity(m);
    let mut cov = Vec::with_capacity(m);
    let mut radius99 = Vec::with_capacity(m);
    let mut within1 = Vec::with_capacity(m);
    let mut within2 = Vec::with_capacity(m);
    let target = (0.99 * nf).ceil() as u64;
    for j in 0..m {
        let sm = &sums[5 * j..5 * j + 5];
        let (mx, my) = (sm[0] / nf, sm[1] / nf);
        mean.push([mx, my]);
        let dof = (nf - 1.0).max(1.0);
        cov.push([
            (sm[2] - nf * mx * mx) / dof,
            (sm[3] - nf * mx * my) / dof,
            (sm[4] - nf * my * my) / dof,
        ]);
        let mut acc = 0u64;
        let mut r99 = r_max;
        for (b, &c) in total.radial[j * RADIAL_BINS..(j + 1) * RADIAL_BINS]
            .iter()
            .enumerate()
        {
            let before = acc;
            acc += c as u64;
            if acc >= target {
                // Linear interpolation of the cumulative count within the bin.
                let f = (target - before) as f64 / (c as f64).max(1.0);
                r99 = (b as f64 + f) / rbin;
                break;
            }
        }
        radius99.push(r99);
        within1.push(total.within[j][0] as f64 / nf);
        within2.push(total.within[j][1] as f64 / nf);
    }
    Ok(MonteCarloResult {
        n_ok,
        n_failed: cfg.n - n_ok,
        mean,
        cov,
        radius99,
        within1,
        within2,
        nominal,
        hist: total.hist,
        samples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> (Vec<[f64; 2]>, Vec<[f64; 2]>, usize) {
        let mut o = Vec::new();
        let mut im = Vec::new();
        let mut c = 0;
        for j in -3..=3 {
            for i in -6..=6 {
                if i == 0 && j == 0 {
                    c = o.len();
                }
                let (x, y) = (2000.0 + 150.0 * i as f64, 1000.0 + 150.0 * j as f64);
                let (dx, dy) = ((x - 2000.0) / 1000.0, (y - 1000.0) / 1000.0);
                let r2 = dx * dx + dy * dy;
                o.push([x, y]);
                im.push([
                    x + 3.0 * dx * r2 + 0.5 * dy,
                    y + 3.0 * dy * r2 + 0.2 * dx * dx,
                ]);
            }
        }
        (o, im, c)
    }

    fn cfg(model: Model, threads: Option<usize>) -> MonteCarloConfig {
        MonteCarloConfig {
            model,
            n: 3 * CHUNK + 17,
            sigma_image_px: 0.057,
            sigma_object_px: 0.38,
            centre_index: 0,
            scale: None,
            seed: 7,
            hist_bins: 16,
            hist_half_range_px: 2.0,
            keep_samples: true,
            threads,
        }
    }

    #[test]
    fn identical_on_one_and_two_threads_and_matches_theory() {
        let (o, im, c) = grid();
        let mut a = cfg(Model::P3, Some(1));
        a.centre_index = c;
        let mut b = a.clone();
        b.threads = Some(2);
        let ra = monte_carlo(&o, &im, &a).unwrap();
        let rb = monte_carlo(&o, &im, &b).unwrap();
        assert_eq!(ra, rb);
        assert_eq!(ra.n_ok, a.n);
        assert_eq!(ra.samples.len(), a.n * o.len() * 2);
        // The distortion is cubic: P3 fits it exactly, so the mean residual is ~0 and the
        // per-axis variance is below the input variance (the fit absorbs part of the noise).
        let input = 0.057f64.powi(2) + 0.38f64.powi(2);
        for j in 0..o.len() {
            assert!(ra.nominal[j][0].abs() < 1e-6 && ra.nominal[j][1].abs() < 1e-6);
            assert!(ra.mean[j][0].abs() < 0.02 && ra.mean[j][1].abs() < 0.02);
            if j != c {
                assert!(
                    ra.cov[j][0] < input && ra.cov[j][0] > 0.5 * input,
                    "{:?}",
                    ra.cov[j]
                );
            }
            assert!(ra.within2[j] >= ra.within1[j]);
            assert!(ra.radius99[j] < 2.0);
        }
        // Mean and covariance agree with the kept samples.
        let m = o.len();
        let j = 5;
        let xs: Vec<f64> = (0..ra.n_ok)
            .map(|k| ra.samples[(k * m + j) * 2] as f64)
            .collect();
        let mx = xs.iter().sum::<f64>() / xs.len() as f64;
        assert!((mx - ra.mean[j][0]).abs() < 1e-6);
        let mut rs: Vec<f64> = (0..ra.n_ok)
            .map(|k| {
                let (x, y) = (
                    ra.samples[(k * m + j) * 2] as f64,
                    ra.samples[(k * m + j) * 2 + 1] as f64,
                );
                x.hypot(y)
            })
            .collect();
        rs.sort_by(f64::total_cmp);
        let q = rs[(0.99 * rs.len() as f64).ceil() as usize - 1];
        assert!(
            (q - ra.radius99[j]).abs() < 0.01,
            "{q} vs {}",
            ra.radius99[j]
        );
        let w1 = rs.iter().filter(|r| **r <= 1.0).count() as f64 / rs.len() as f64;
        assert!((w1 - ra.within1[j]).abs() < 1e-9);
    }

    #[test]
    fn r2_is_deterministic_too() {
        let (o, im, c) = grid();
        let mut a = cfg(Model::R2, Some(1));
        a.n = 300;
        a.centre_index = c;
        a.keep_samples = false;
        let mut b = a.clone();
        b.threads = Some(2);
        assert_eq!(
            monte_carlo(&o, &im, &a).unwrap(),
            monte_carlo(&o, &im, &b).unwrap()
        );
    }

    #[test]
    fn bad_inputs() {
        let (o, im, _) = grid();
        let mut a = cfg(Model::P3, None);
        a.centre_index = 1000;
        assert!(monte_carlo(&o, &im, &a).is_err());
        a.centre_index = 0;
        a.sigma_image_px = -1.0;
        assert!(monte_carlo(&o, &im, &a).is_err());
        a.sigma_image_px = 0.1;
        assert!(monte_carlo(&o[..5], &im[..5], &a).is_err());
        a.n = 0;
        assert!(monte_carlo(&o, &im, &a).is_err());
    }
}
