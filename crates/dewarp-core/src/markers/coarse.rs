//! The coarse stage of marker detection: block averaging, the zero-mean template, FFT
//! cross-correlation, robust statistics and the marker-size estimate.

use super::MarkerKind;
use image_core::{fast_len, Pixel};
use ndarray::{Array2, ArrayView2, Axis};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

pub(crate) fn block_mean<T: Pixel>(img: ArrayView2<T>, d: usize, sign: f64) -> Array2<f64> {
    let (h, w) = img.dim();
    let (hc, wc) = (h / d, w / d);
    let mut out = Array2::<f64>::zeros((hc, wc));
    let inv = sign / (d * d) as f64;
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(yc, mut row)| {
            for dy in 0..d {
                let src = img.row(yc * d + dy);
                for xc in 0..wc {
                    let mut s = 0.0;
                    for dx in 0..d {
                        s += src[xc * d + dx].to_f64();
                    }
                    row[xc] += s * inv;
                }
            }
        });
    out
}

pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    median_mut(&mut v)
}

/// Median of a slice (reordered in place); 0 if empty.
pub(crate) fn median_mut(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    v[k]
}

/// Median and MAD-based standard deviation of (a subsample of) an array.
pub(crate) fn robust_stats(a: &Array2<f64>) -> (f64, f64) {
    robust_stats_of(a.iter().copied(), a.len())
}

fn robust_stats_of(values: impl Iterator<Item = f64>, n: usize) -> (f64, f64) {
    let step = (n / 200_000).max(1);
    let sample: Vec<f64> = values.step_by(step).collect();
    let med = median(sample.clone());
    let mad = median(sample.iter().map(|v| (v - med).abs()).collect());
    (med, 1.4826 * mad)
}

/// The noise of a correlation with a unit-norm template (`corr`) of a block-averaged image
/// (`coarse`, block `d`): the smaller of the correlation's robust spread (inflated where
/// markers cover much of the image: a dense lattice is structure, not noise) and the pixel
/// noise read from horizontal differences of `coarse` (`MAD / sqrt 2`; edges are a minority),
/// for integer counts (`integer`) never below their quantisation noise averaged over `d^2`
/// pixels (an image whose background is exactly 0 has no spread at all).
pub(crate) fn correlation_noise(
    coarse: &Array2<f64>,
    corr: &Array2<f64>,
    d: usize,
    integer: bool,
) -> f64 {
    let (_, spread) = robust_stats(corr);
    let (h, w) = coarse.dim();
    let diffs = (0..h).flat_map(|y| (1..w).map(move |x| coarse[[y, x]] - coarse[[y, x - 1]]));
    let (_, dn) = robust_stats_of(diffs, h * w.saturating_sub(1));
    let floor = if integer {
        (1.0f64 / 12.0).sqrt() / d as f64
    } else {
        1e-300
    };
    spread.min(dn / std::f64::consts::SQRT_2).max(floor)
}

/// In-place 2D FFT of a row-major (h, w) complex buffer.
fn fft2(
    buf: &mut [Complex<f64>],
    h: usize,
    w: usize,
    inverse: bool,
    planner: &mut FftPlanner<f64>,
) {
    let row_fft = if inverse {
        planner.plan_fft_inverse(w)
    } else {
        planner.plan_fft_forward(w)
    };
    let col_fft = if inverse {
        planner.plan_fft_inverse(h)
    } else {
        planner.plan_fft_forward(h)
    };
    buf.par_chunks_mut(w).for_each(|row| row_fft.process(row));
    let mut t = vec![Complex::new(0.0, 0.0); h * w];
    t.par_chunks_mut(h).enumerate().for_each(|(x, col)| {
        for y in 0..h {
            col[y] = buf[y * w + x];
        }
        col_fft.process(col);
    });
    buf.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            row[x] = t[x * h + y];
        }
    });
}

/// Cross-correlate `img` with a zero-mean `tpl` (odd sizes, centred); output has `img`'s shape.
pub(crate) fn correlate(img: &Array2<f64>, tpl: &Array2<f64>) -> Array2<f64> {
    let (h, w) = img.dim();
    let (th, tw) = tpl.dim();
    let (ph, pw) = (fast_len(h + th - 1), fast_len(w + tw - 1));
    let mean = img.mean().unwrap_or(0.0);
    let mut a = vec![Complex::new(0.0, 0.0); ph * pw];
    for ((y, x), v) in img.indexed_iter() {
        a[y * pw + x] = Complex::new(v - mean, 0.0);
    }
    let mut b = vec![Complex::new(0.0, 0.0); ph * pw];
    // Template placed so that out[y, x] = sum_{u, v} img[y + u - cy, x + v - cx] tpl[u, v].
    let (cy, cx) = (th / 2, tw / 2);
    for ((u, v), t) in tpl.indexed_iter() {
        let yy = (u as isize - cy as isize).rem_euclid(ph as isize) as usize;
        let xx = (v as isize - cx as isize).rem_euclid(pw as isize) as usize;
        b[yy * pw + xx] = Complex::new(*t, 0.0);
    }
    let mut planner = FftPlanner::new();
    fft2(&mut a, ph, pw, false, &mut planner);
    fft2(&mut b, ph, pw, false, &mut planner);
    a.par_iter_mut()
        .zip(b.par_iter())
        .for_each(|(p, q)| *p *= q.conj());
    fft2(&mut a, ph, pw, true, &mut planner);
    let norm = 1.0 / (ph * pw) as f64;
    let mut out = Array2::<f64>::zeros((h, w));
    for ((y, x), o) in out.indexed_iter_mut() {
        *o = a[y * pw + x].re * norm;
    }
    out
}

pub(crate) fn template(kind: MarkerKind, s: f64) -> Array2<f64> {
    let half = (3.0 * s).ceil().max(2.0) as usize;
    let n = 2 * half + 1;
    let mut t = Array2::<f64>::zeros((n, n));
    for ((y, x), v) in t.indexed_iter_mut() {
        let (dx, dy) = (x as f64 - half as f64, y as f64 - half as f64);
        *v = match kind {
            MarkerKind::Dot => (-(dx * dx + dy * dy) / (2.0 * s * s)).exp(),
            MarkerKind::Cross => {
                let arm = |a: f64, b: f64| {
                    (-(a * a) / (2.0 * s * s)).exp() * f64::from(b.abs() <= 3.0 * s)
                };
                arm(dx, dy).max(arm(dy, dx))
            }
        };
    }
    let m = t.mean().unwrap_or(0.0);
    t.mapv_inplace(|v| v - m);
    let nrm = t.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    t.mapv_inplace(|v| v / nrm);
    t
}

/// Local maxima of `sign * corr` over `(2r+1)^2` neighbourhoods at or above `thr`, as
/// `(row, column, sign * value)` (ties go to the first in row-major order).
pub(crate) fn local_maxima(
    corr: &Array2<f64>,
    sign: f64,
    thr: f64,
    r: usize,
) -> Vec<(usize, usize, f64)> {
    let (hc, wc) = corr.dim();
    (0..hc)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..wc).filter_map(move |x| {
                let v = sign * corr[[y, x]];
                if v < thr {
                    return None;
                }
                for yy in y.saturating_sub(r)..(y + r + 1).min(hc) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(wc) {
                        let u = sign * corr[[yy, xx]];
                        if u > v || (u == v && (yy, xx) < (y, x)) {
                            return None;
                        }
                    }
                }
                Some((y, x, v))
            })
        })
        .collect()
}

/// Whether the pixel type holds integer counts (quantised).
pub(crate) fn is_integer<T: Pixel>() -> bool {
    matches!(
        T::KIND,
        image_core::PixelKind::U8 | image_core::PixelKind::U16
    )
}

/// Correlate `img` with the marker template of `kind` at size `sc` ([`template`]): for dots the
/// template is a Gaussian minus its mean, separable, so the correlation is computed in space as
/// `(sum_uv g(u) g(v) J - m sum_uv J) / |t|` with `J` the mean-free image (zero outside, as the
/// FFT's zero padding): two 1D passes and a box sum, `O(taps)` per pixel and no FFT buffers
/// (a 47 MP frame at block size 1 needed 1.5 GB of complex buffers). Crosses (not separable)
/// go through [`correlate`]. Equal to [`correlate`] with [`template`] to rounding.
pub(crate) fn correlate_marker(img: &Array2<f64>, kind: MarkerKind, sc: f64) -> Array2<f64> {
    if kind != MarkerKind::Dot {
        return correlate(img, &template(kind, sc));
    }
    let half = (3.0 * sc).ceil().max(2.0) as usize;
    let taps = 2 * half + 1;
    let g: Vec<f64> = (0..taps)
        .map(|k| {
            let u = k as f64 - half as f64;
            (-(u * u) / (2.0 * sc * sc)).exp()
        })
        .collect();
    let sum_g: f64 = g.iter().sum();
    let sum_g2: f64 = g.iter().map(|v| v * v).sum();
    let n_t = (taps * taps) as f64;
    let m = sum_g * sum_g / n_t;
    let nrm = (sum_g2 * sum_g2 - sum_g.powi(4) / n_t).max(1e-300).sqrt();
    let (h, w) = img.dim();
    let mean = img.mean().unwrap_or(0.0);
    // Horizontal pass: Gaussian and box sums of each row (zero beyond the edges).
    let mut hg = Array2::<f64>::zeros((h, w));
    let mut hb = Array2::<f64>::zeros((h, w));
    hg.axis_iter_mut(Axis(0))
        .into_par_iter()
        .zip(hb.axis_iter_mut(Axis(0)))
        .enumerate()
        .for_each(|(y, (mut og, mut ob))| {
            let row = img.row(y);
            let j: Vec<f64> = row.iter().map(|v| v - mean).collect();
            let mut run = 0.0;
            for x in 0..(half.min(w)) {
                run += j[x];
            }
            for x in 0..w {
                if x + half < w {
                    run += j[x + half];
                }
                if x > half {
                    run -= j[x - half - 1];
                }
                ob[x] = run;
                let lo = x.saturating_sub(half);
                let hi = (x + half).min(w - 1);
                og[x] = j[lo..=hi]
                    .iter()
                    .zip(&g[lo + half - x..])
                    .map(|(a, b)| a * b)
                    .sum();
            }
        });
    // Vertical pass: Gaussian of the Gaussian rows, box of the box rows.
    let mut out = Array2::<f64>::zeros((h, w));
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(y, mut o)| {
            let lo = y.saturating_sub(half);
            let hi = (y + half).min(h - 1);
            for yy in lo..=hi {
                let gy = g[yy + half - y];
                let (rg, rb) = (hg.row(yy), hb.row(yy));
                for x in 0..w {
                    o[x] += gy * rg[x] - m * rb[x];
                }
            }
            o.mapv_inplace(|v| v / nrm);
        });
    out
}
