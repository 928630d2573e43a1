//! The particle images a frame holds, counted block by block: the background and noise of
//! each block, and the particle images standing out of them (the seeding density a recording
//! check turns into particles per window).
//!
//! Each block of `block` x `block` px (the last row and column of blocks take what is left) is
//! measured from its own pixels, masked ones (mask `true`) left out:
//!
//! - **background** `b` and **noise** `s`: the mean and sigma of a Gaussian through two
//!   quantiles of the block's values, at `pa = max(0.25, f + 0.05)` and `pb = min(pa + 0.25,
//!   (pa + 1) / 2)` where `f` is the share of values at the block's minimum (a background
//!   clipped at zero puts half its values there; particle images cover the top of the
//!   distribution, about 15 % of the pixels at 0.03 particles per px of 2.5 px diameter). The
//!   noise is at least [`MIN_NOISE`]; a block with [`MAX_FLOOR`] or more of its values at its
//!   minimum has that minimum as background and [`MIN_NOISE`] as noise;
//! - **top**: the 99.5th percentile, the bright particle images' level; the **median**.
//!
//! The frame's signal is the median over the measured blocks of `top - b`. A **particle image**
//! is a pixel standing above `b + max(k s, rel * signal)` of its block that is the maximum of
//! its 3 x 3 neighbourhood: higher than the neighbours before it in raster order, at least as
//! high as those after it (a plateau of equal values counts once). It is **saturated** at or
//! above `full`. The frame's outermost pixel ring and masked pixels are never counted; a block
//! with fewer than half its pixels unmasked is not measured (NaN, count 0).
//!
//! Intensities are in the frame's counts, lengths in px. Two particle images closer than about
//! their diameter merge into one maximum, so the count is under the particles present by a
//! share that grows with the source density; the caller (`rspiv.recording`) states and
//! corrects it.

use crate::error::{PivError, Result};
use image_core::Pixel;
use ndarray::{s, ArrayView2};
use rayon::prelude::*;

/// The smallest noise sigma (counts): the rounding of integer counts (1/sqrt(12)).
pub const MIN_NOISE: f32 = 0.29;

/// A block with at least this share of its values at its minimum is clipped or blank: its
/// background is that minimum and its noise [`MIN_NOISE`].
pub const MAX_FLOOR: f64 = 0.85;

/// What [`measure`] found in each block, row-major over `(rows, cols)` blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct Seeding {
    /// Blocks along y and along x.
    pub rows: usize,
    pub cols: usize,
    /// The block's side (px).
    pub block: usize,
    /// Background `b` (counts; NaN where not measured).
    pub background: Vec<f32>,
    /// Noise sigma `s` (counts; NaN where not measured).
    pub noise: Vec<f32>,
    /// The 99.5th percentile (counts; NaN where not measured).
    pub top: Vec<f32>,
    /// The median (counts; NaN where not measured).
    pub median: Vec<f32>,
    /// The particle images counted in the block.
    pub peaks: Vec<u32>,
    /// The sum of their heights above `b` (counts).
    pub heights: Vec<f64>,
    /// Those of them at or above `full` (saturated).
    pub saturated: Vec<u32>,
    /// The block's pixels that were searched (unmasked, off the frame's outer ring).
    pub searched: Vec<u32>,
    /// The frame's signal: the median of `top - b` over the measured blocks (counts).
    pub signal: f32,
}

/// Block statistics and particle images of `img` (module docs): blocks of `block` px, a
/// particle image stands above `b + max(k * s, rel * signal)`. Errors on a block under 8 px,
/// a frame under 3 x 3 px, a mask of another shape, `k` or `rel` negative or not finite, or a
/// value that is not finite.
pub fn measure<T: Pixel>(
    img: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    block: usize,
    k: f32,
    rel: f32,
    full: f32,
) -> Result<Seeding> {
    let Blocks {
        rows,
        cols,
        background,
        noise,
        top,
        median,
        signal,
    } = blocks(img, mask, block, k, rel)?;
    let (h, w) = img.dim();
    // 2. the particle images above each block's threshold
    let counted: Vec<Vec<(u32, f64, u32, u32)>> = (0..rows)
        .into_par_iter()
        .map(|r| {
            let (y0, y1) = ((r * block).max(1), ((r + 1) * block).min(h - 1));
            (0..cols)
                .map(|c| {
                    let i = r * cols + c;
                    let b = background[i];
                    if !b.is_finite() {
                        return (0, 0.0, 0, 0);
                    }
                    let thr = threshold(b, noise[i], signal, k, rel);
                    let (x0, x1) = ((c * block).max(1), ((c + 1) * block).min(w - 1));
                    let (mut n, mut sum, mut searched, mut sat) = (0u32, 0.0f64, 0u32, 0u32);
                    for y in y0..y1 {
                        let row = img.row(y);
                        let out = mask.as_ref().map(|m| m.row(y));
                        for x in x0..x1 {
                            if out.as_ref().is_some_and(|m| m[x]) {
                                continue;
                            }
                            searched += 1;
                            let v = row[x].to_f32();
                            if v > thr && is_peak(&img, y, x, v) {
                                n += 1;
                                sum += (v - b) as f64;
                                sat += u32::from(v >= full);
                            }
                        }
                    }
                    (n, sum, searched, sat)
                })
                .collect()
        })
        .collect();
    let mut peaks = Vec::with_capacity(rows * cols);
    let mut heights = Vec::with_capacity(rows * cols);
    let mut searched = Vec::with_capacity(rows * cols);
    let mut saturated = Vec::with_capacity(rows * cols);
    for (n, s, m, f) in counted.into_iter().flatten() {
        saturated.push(f);
        peaks.push(n);
        heights.push(s);
        searched.push(m);
    }
    Ok(Seeding {
        rows,
        cols,
        block,
        background,
        noise,
        top,
        median,
        peaks,
        heights,
        saturated,
        searched,
        signal,
    })
}

/// Each block's background, noise, top and median and the frame's signal (module docs): the
/// first half of [`measure`], shared with [`crate::ptv::detect`], which finds the particle
/// images itself. Errors as [`measure`] does.
pub(crate) struct Blocks {
    pub rows: usize,
    pub cols: usize,
    pub background: Vec<f32>,
    pub noise: Vec<f32>,
    pub top: Vec<f32>,
    pub median: Vec<f32>,
    pub signal: f32,
}

/// The block statistics of `img` (module docs; [`Blocks`]).
pub(crate) fn blocks<T: Pixel>(
    img: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    block: usize,
    k: f32,
    rel: f32,
) -> Result<Blocks> {
    let (h, w) = img.dim();
    if block < 8 {
        return Err(PivError::InvalidInput(format!(
            "block must be at least 8 px, got {block}"
        )));
    }
    if h < 3 || w < 3 {
        return Err(PivError::InvalidInput(format!(
            "the frame ({h} x {w}) is too small to search for particle images"
        )));
    }
    if !(k.is_finite() && k >= 0.0 && rel.is_finite() && rel >= 0.0) {
        return Err(PivError::InvalidInput(format!(
            "the threshold factors must be finite and >= 0, got k = {k}, rel = {rel}"
        )));
    }
    if let Some(m) = &mask {
        if m.dim() != (h, w) {
            return Err(PivError::InvalidInput(format!(
                "mask ({} x {}) differs in shape from the frame ({h} x {w})",
                m.nrows(),
                m.ncols()
            )));
        }
    }
    let rows = h.div_ceil(block);
    let cols = w.div_ceil(block);
    // 1. each block's background, noise and top
    let stats: Vec<Result<Vec<[f32; 4]>>> = (0..rows)
        .into_par_iter()
        .map_init(Vec::<f32>::new, |vals, r| {
            let (y0, y1) = (r * block, ((r + 1) * block).min(h));
            (0..cols)
                .map(|c| {
                    let (x0, x1) = (c * block, ((c + 1) * block).min(w));
                    vals.clear();
                    let not_finite = |x: usize, y: usize| {
                        PivError::InvalidInput(format!(
                            "the frame holds a value that is not finite at (x {x}, y {y})"
                        ))
                    };
                    for y in y0..y1 {
                        let row = img.slice(s![y, x0..x1]);
                        match &mask {
                            None => {
                                for (j, &v) in row.iter().enumerate() {
                                    if !v.is_finite_px() {
                                        return Err(not_finite(x0 + j, y));
                                    }
                                    vals.push(v.to_f32());
                                }
                            }
                            Some(m) => {
                                let out = m.slice(s![y, x0..x1]);
                                for (j, (&v, &o)) in row.iter().zip(out.iter()).enumerate() {
                                    if o {
                                        continue;
                                    }
                                    if !v.is_finite_px() {
                                        return Err(not_finite(x0 + j, y));
                                    }
                                    vals.push(v.to_f32());
                                }
                            }
                        }
                    }
                    if 2 * vals.len() < (y1 - y0) * (x1 - x0) {
                        return Ok([f32::NAN; 4]);
                    }
                    Ok(block_stats(vals))
                })
                .collect()
        })
        .collect();
    let mut background = Vec::with_capacity(rows * cols);
    let mut noise = Vec::with_capacity(rows * cols);
    let mut top = Vec::with_capacity(rows * cols);
    let mut median = Vec::with_capacity(rows * cols);
    for row in stats {
        for [b, s, t, m] in row? {
            median.push(m);
            background.push(b);
            noise.push(s);
            top.push(t);
        }
    }
    let mut spread: Vec<f32> = background
        .iter()
        .zip(&top)
        .filter(|(b, _)| b.is_finite())
        .map(|(b, t)| t - b)
        .collect();
    let signal = if spread.is_empty() {
        f32::NAN
    } else {
        let m = spread.len() / 2;
        *spread.select_nth_unstable_by(m, f32::total_cmp).1
    };
    Ok(Blocks {
        rows,
        cols,
        background,
        noise,
        top,
        median,
        signal,
    })
}

/// The level a particle image stands above in a block of background `b` and noise `s`:
/// `b + max(k s, rel signal)` (`rel signal` counts as 0 when the frame's signal is not
/// measured). Shared with [`crate::ptv::detect`].
pub(crate) fn threshold(b: f32, s: f32, signal: f32, k: f32, rel: f32) -> f32 {
    let floor = if signal.is_finite() {
        rel * signal
    } else {
        0.0
    };
    b + (k * s).max(floor)
}

/// Order statistics of one slice, each selected within the part of the slice between the
/// ranks already selected (`select_nth_unstable` leaves every value before a selected rank at
/// most, and every one after at least, its value): a handful of quantiles of a block cost
/// about two passes over it instead of one pass each. No allocation.
struct Ranks<'a> {
    vals: &'a mut [f32],
    /// Ranks selected so far, ascending (the first `len`).
    done: [usize; 8],
    len: usize,
}

impl Ranks<'_> {
    /// The value at quantile `p` (the rank nearest `(n - 1) p`, ascending).
    fn at(&mut self, p: f64) -> f32 {
        let n = self.vals.len();
        let i = ((((n - 1) as f64) * p.clamp(0.0, 1.0)).round() as usize).min(n - 1);
        let done = &self.done[..self.len];
        let k = done.partition_point(|&d| d < i);
        if done.get(k) == Some(&i) {
            return self.vals[i];
        }
        let lo = if k == 0 { 0 } else { done[k - 1] + 1 };
        let hi = done.get(k).copied().unwrap_or(n);
        self.vals[lo..hi].select_nth_unstable_by(i - lo, f32::total_cmp);
        if self.len < self.done.len() {
            self.done.copy_within(k..self.len, k + 1);
            self.done[k] = i;
            self.len += 1;
        }
        self.vals[i]
    }
}

/// `[b, s, top]` of a block's values (module docs); reorders `vals`.
fn block_stats(vals: &mut [f32]) -> [f32; 4] {
    let n = vals.len();
    let mut ranks = Ranks {
        vals,
        done: [0; 8],
        len: 0,
    };
    let median = ranks.at(0.5);
    let top = ranks.at(0.995);
    let lo = ranks.at(0.0);
    let floor = ranks.vals.iter().filter(|&&x| x <= lo).count() as f64 / n as f64;
    if floor >= MAX_FLOOR {
        // (nearly) all one value: a clipped or blank block
        return [lo, MIN_NOISE, top, median];
    }
    // two quantiles of the background above the clipped floor: a Gaussian's mean and sigma
    let pa = (floor + 0.05).max(0.25);
    let pb = (pa + 0.25).min(0.5 * (pa + 1.0));
    let (qa, qb) = (ranks.at(pa) as f64, ranks.at(pb) as f64);
    let (za, zb) = (probit(pa), probit(pb));
    let s = (((qb - qa) / (zb - za)) as f32).max(MIN_NOISE);
    let b = (qa - s as f64 * za) as f32;
    [b, s, top, median]
}

/// The standard normal quantile of `p` in (0, 1), by bisection of the CDF (to 1e-12).
fn probit(p: f64) -> f64 {
    let (mut lo, mut hi) = (-9.0f64, 9.0f64);
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if image_core::special::normal_cdf(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Is `v` at (y, x) the maximum of its 3 x 3 neighbourhood (ties to the later pixels in raster
/// order)? (y, x) is off the frame's outer ring.
#[inline(always)]
pub(crate) fn is_peak<T: Pixel>(img: &ArrayView2<'_, T>, y: usize, x: usize, v: f32) -> bool {
    for (dy, dx) in [(-1isize, -1isize), (-1, 0), (-1, 1), (0, -1)] {
        let (yy, xx) = ((y as isize + dy) as usize, (x as isize + dx) as usize);
        if img[[yy, xx]].to_f32() >= v {
            return false;
        }
    }
    for (dy, dx) in [(0isize, 1isize), (1, -1), (1, 0), (1, 1)] {
        let (yy, xx) = ((y as isize + dy) as usize, (x as isize + dx) as usize);
        if img[[yy, xx]].to_f32() > v {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    /// A background of mean `mean` and sigma 20 counts, rounded and clipped at 0 like a
    /// camera's counts (the quantiles are whole counts: a sigma of a few counts is measured to
    /// about a count).
    fn noisy(h: usize, w: usize, mean: f32, seed: u64) -> Array2<f32> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = Normal::new(mean, 20.0f32).unwrap();
        Array2::from_shape_fn((h, w), |_| n.sample(&mut rng).round().max(0.0))
    }

    /// Isolated spots and a plateau on a noisy background are each counted once, in their
    /// block; the background and noise come back from the quantiles, also when the background
    /// is clipped at zero; a saturated spot is counted as such.
    #[test]
    fn isolated_peaks_are_counted_once_in_their_block() {
        let (h, w) = (64, 96);
        for (mean, seed) in [(100.0f32, 1u64), (0.0, 2)] {
            let mut img = noisy(h, w, mean, seed);
            let spots = [(5usize, 5usize), (10, 40), (40, 20), (50, 70), (20, 90)];
            for &(y, x) in &spots {
                img[[y, x]] = 1000.0;
            }
            // a 2 x 2 plateau counts once
            for (y, x) in [(30, 60), (30, 61), (31, 60), (31, 61)] {
                img[[y, x]] = 800.0;
            }
            let s = measure(img.view(), None, 32, 6.0, 0.0, 1000.0).unwrap();
            assert_eq!((s.rows, s.cols), (2, 3));
            // (5, 5); (10, 40) and the plateau; (20, 90); (40, 20); none; (50, 70)
            assert_eq!(s.peaks, vec![1, 2, 1, 1, 0, 1], "mean {mean}");
            assert_eq!(s.saturated, vec![1, 1, 1, 1, 0, 1]);
            for (&b, &n) in s.background.iter().zip(&s.noise) {
                assert!((b - mean).abs() < 3.0, "mean {mean}: background {b}");
                // two quantiles of 1024 values: about 8 % sampling error per block
                assert!((n - 20.0).abs() < 5.0, "mean {mean}: noise {n}");
            }
            let mean_noise = s.noise.iter().sum::<f32>() / 6.0;
            assert!(
                (mean_noise - 20.0).abs() < 1.6,
                "mean {mean}: noise {mean_noise}"
            );
        }
    }

    /// A masked spot is not counted; a mostly masked block is not measured; shapes are checked.
    #[test]
    fn masks_and_bad_input() {
        let (h, w) = (32, 64);
        let mut img = Array2::<u16>::from_elem((h, w), 50);
        img[[10, 10]] = 900;
        img[[10, 40]] = 900;
        let mut mask = Array2::<bool>::from_elem((h, w), false);
        mask[[10, 40]] = true;
        let s = measure(img.view(), Some(mask.view()), 32, 4.0, 0.0, 900.0).unwrap();
        assert_eq!(s.peaks, vec![1, 0]);
        let all = Array2::<bool>::from_elem((h, w), true);
        let s = measure(img.view(), Some(all.view()), 32, 4.0, 0.0, 900.0).unwrap();
        assert!(s.background.iter().all(|b| b.is_nan()));
        assert_eq!(s.peaks, vec![0, 0]);
        assert!(s.signal.is_nan());
        assert!(measure(img.view(), None, 4, 4.0, 0.0, 900.0).is_err());
        assert!(measure(
            img.view(),
            Some(mask.slice(ndarray::s![..8, ..])),
            32,
            4.0,
            0.0,
            900.0
        )
        .is_err());
        // a blank frame (every value at the minimum) counts nothing, in every block
        let blank = Array2::<u8>::zeros((40, 40));
        let s = measure(blank.view(), None, 16, 4.0, 0.1, 255.0).unwrap();
        assert_eq!(s.peaks, vec![0; 9]);
        assert!(s.noise.iter().all(|&n| n == MIN_NOISE));
        let mut f = Array2::<f32>::zeros((16, 16));
        f[[3, 3]] = f32::NAN;
        let e = measure(f.view(), None, 8, 4.0, 0.0, f32::INFINITY).unwrap_err();
        assert!(e.to_string().contains("not finite at (x 3, y 3)"), "{e}");
    }
}
