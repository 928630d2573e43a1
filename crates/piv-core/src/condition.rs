//! Image conditioning before the correlation: what a lab's recordings need and synthetic ones do
//! not (glare at the wall, uneven or drifting sheet light, hot pixels, particles of very
//! different brightness).
//!
//! [`condition`] applies, in this order and each only when switched on in [`Conditioning`], to
//! one frame held as `f32` (in place, no copy; rows in parallel, no per-pixel allocation):
//!
//! 1. **hot pixels** (`hot_pixels = f`): a pixel brighter than `f` times the brightest of its 8
//!    neighbours (and than 0) is an isolated sensor defect, not a particle (a particle image of
//!    >= 1.5 px lights its neighbours): it takes the value of that brightest neighbour;
//! 2. **background** (a background image given): `I <- max(I - B, 0)`; the background is
//!    estimated over the run by the caller (the minimum or mean of the frames, per frame A and
//!    B, see `rspiv.preprocess.Background`);
//! 3. **high-pass** (`high_pass_sigma = s` px): `I <- I - G_s * I` with `G_s` a Gaussian of
//!    standard deviation `s` (truncated at 3 s, mirror boundaries): removes what varies slower
//!    than ~`2 pi s` px (glare lines, light gradients) and keeps particle images of a few px
//!    (transfer `1 - exp(-2 pi^2 s^2 f^2)` at `f` cycles/px). The result is signed and not
//!    clipped: clipping at 0 would turn most of the background into exact zeros, which the
//!    correlator's blank-window rule (`multipass`) takes for the zero fill of a dewarped frame;
//!    the correlation is mean-free, so the sign costs nothing;
//! 4. **intensity capping** (`cap_sigma = k`): `I <- min(I, mean + k std)` over the frame
//!    (Shavit, Lowe & Steinbuck 2007, Exp. Fluids 42, with the mean in place of the median), so
//!    that a few bright particles or a residual glare do not dominate a window;
//! 5. **min-max normalisation** (`min_max_window = n` px): the local minimum and maximum over
//!    an `n` x `n` neighbourhood, each smoothed by an `n` x `n` box, and
//!    `I <- (I - min) / max(max - min, 1e-6 * (global max - global min))` clipped to `[0, 1]`:
//!    particles of every brightness and in every part of the sheet get the same contrast.
//!
//! Units: intensities in the frame's counts until step 5, dimensionless after it; lengths in px.
//! Pixel frame of the crate (x = column, y = row).

use crate::error::{PivError, Result};
use ndarray::{ArrayView2, ArrayViewMut2};
use rayon::prelude::*;

/// Which conditioning steps run, with their parameters (`None` or 0: off). See the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Conditioning {
    /// Hot-pixel factor `f` (> 1), e.g. 3.
    pub hot_pixels: Option<f32>,
    /// High-pass Gaussian sigma in px (> 0), e.g. 4.
    pub high_pass_sigma: Option<f32>,
    /// Intensity cap at `mean + k std` (k > 0), e.g. 2.
    pub cap_sigma: Option<f32>,
    /// Min-max normalisation window in px (>= 3), e.g. 15.
    pub min_max_window: Option<usize>,
}

impl Conditioning {
    fn check(&self) -> Result<()> {
        let bad = |m: String| Err(PivError::InvalidInput(m));
        if let Some(f) = self.hot_pixels {
            if !(f.is_finite() && f > 1.0) {
                return bad(format!("hot_pixels factor {f} must be > 1"));
            }
        }
        if let Some(s) = self.high_pass_sigma {
            if !(s.is_finite() && s > 0.0) {
                return bad(format!("high_pass sigma {s} px must be > 0"));
            }
        }
        if let Some(k) = self.cap_sigma {
            if !(k.is_finite() && k > 0.0) {
                return bad(format!("cap {k} (in standard deviations) must be > 0"));
            }
        }
        if let Some(n) = self.min_max_window {
            if n < 3 {
                return bad(format!("min_max window {n} px must be >= 3"));
            }
        }
        Ok(())
    }
}

/// Condition `img` in place (module docs), with an optional background of the same shape.
///
/// # Errors
/// [`PivError::InvalidInput`] for a non-contiguous or empty image, a background of another
/// shape, NaN/inf pixels, or parameters out of range.
pub fn condition(
    mut img: ArrayViewMut2<'_, f32>,
    c: &Conditioning,
    background: Option<ArrayView2<'_, f32>>,
) -> Result<()> {
    c.check()?;
    let (h, w) = img.dim();
    if h == 0 || w == 0 {
        return Err(PivError::InvalidInput(format!(
            "image is empty ({h} x {w})"
        )));
    }
    if let Some(b) = &background {
        if b.dim() != (h, w) {
            return Err(PivError::InvalidInput(format!(
                "background {:?} differs in shape from the frame {:?}",
                b.dim(),
                (h, w)
            )));
        }
    }
    let buf = img
        .as_slice_mut()
        .ok_or_else(|| PivError::InvalidInput("image must be C-contiguous".into()))?;
    if buf.par_iter().any(|v| !v.is_finite()) {
        return Err(PivError::InvalidInput(
            "image contains NaN or infinite pixel values".into(),
        ));
    }
    if let Some(f) = c.hot_pixels {
        remove_hot_pixels(buf, w, h, f);
    }
    if let Some(b) = background {
        let b = b.as_standard_layout();
        let bs = b.as_slice().expect("standard layout");
        buf.par_iter_mut()
            .zip(bs.par_iter())
            .for_each(|(v, &b)| *v = (*v - b).max(0.0));
    }
    if let Some(s) = c.high_pass_sigma {
        high_pass(buf, w, h, s);
    }
    if let Some(k) = c.cap_sigma {
        let (mean, std) = mean_std(buf);
        let top = (mean + k as f64 * std) as f32;
        buf.par_iter_mut().for_each(|v| *v = v.min(top));
    }
    if let Some(n) = c.min_max_window {
        min_max_normalise(buf, w, h, n);
    }
    Ok(())
}

/// Mean and standard deviation (f64 accumulation, chunks in parallel).
fn mean_std(buf: &[f32]) -> (f64, f64) {
    let (s, s2) = buf
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter().fold((0.0f64, 0.0f64), |(s, s2), &v| {
                let v = v as f64;
                (s + v, s2 + v * v)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let n = buf.len() as f64;
    let mean = s / n;
    (mean, (s2 / n - mean * mean).max(0.0).sqrt())
}

/// Hot pixels (module docs, step 1); border pixels use their neighbours inside the image.
/// Reads a copy of the frame (one extra frame of memory), rows in parallel.
fn remove_hot_pixels(buf: &mut [f32], w: usize, h: usize, factor: f32) {
    let src = buf.to_vec();
    buf.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let up = &src[y.saturating_sub(1) * w..][..w];
        let mid = &src[y * w..][..w];
        let down = &src[(y + 1).min(h - 1) * w..][..w];
        let (has_up, has_down) = (y > 0, y + 1 < h);
        for (x, v) in row.iter_mut().enumerate() {
            if *v <= 0.0 {
                continue;
            }
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let mut m = f32::NEG_INFINITY;
            for xx in x0..=x1 {
                if has_up {
                    m = m.max(up[xx]);
                }
                if has_down {
                    m = m.max(down[xx]);
                }
                if xx != x {
                    m = m.max(mid[xx]);
                }
            }
            if m > f32::NEG_INFINITY && *v > factor * m.max(0.0) {
                *v = m;
            }
        }
    });
}

/// Whole-sample mirror index into `0..n` (n >= 1).
#[inline]
fn mirror(i: isize, n: usize) -> usize {
    image_core::kernels::mirror(i, n)
}

/// The normalised Gaussian taps of sigma `s` (truncated at 3 s): `(taps, radius)`.
fn gaussian_taps(sigma: f32) -> (Vec<f32>, usize) {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f32 = k.iter().sum();
    (k.iter().map(|v| v / norm).collect(), r as usize)
}

/// `dst` row = `f(src row)` for every row (rows in parallel, no allocation).
fn rows_into(src: &[f32], dst: &mut [f32], w: usize, f: impl Fn(&[f32], &mut [f32]) + Sync) {
    dst.par_chunks_mut(w)
        .zip(src.par_chunks(w))
        .for_each(|(d, s)| f(s, d));
}

/// Horizontal Gaussian of one row (mirror boundaries): the interior as `2r + 1` passes of
/// `dst += k_j * shifted src` (vectorised), the `r` samples at each end with mirrored taps.
fn gauss_row(k: &[f32], r: usize, src: &[f32], dst: &mut [f32]) {
    let n = src.len();
    dst.fill(0.0);
    if n > 2 * r {
        let m = n - 2 * r;
        for (j, &kj) in k.iter().enumerate() {
            dst[r..r + m]
                .iter_mut()
                .zip(&src[j..j + m])
                .for_each(|(d, &s)| *d += kj * s);
        }
    }
    for i in (0..n).filter(|&i| i < r || i + r >= n) {
        let mut acc = 0.0f32;
        for (j, &kj) in k.iter().enumerate() {
            acc += kj * src[mirror(i as isize + j as isize - r as isize, n)];
        }
        dst[i] = acc;
    }
}

/// For every output row `y` (in parallel): `out(y, row)` gets the rows `y - r ..= y + r` of
/// `src` (mirrored beyond the image) one at a time with their offset `j - r` through
/// `acc(out_row, src_row, j)`, after `init(out_row)`. Whole rows at a time: contiguous and
/// vectorised, no column gathers.
fn vertical(
    src: &[f32],
    out: &mut [f32],
    w: usize,
    h: usize,
    r: usize,
    init: impl Fn(&mut [f32]) + Sync,
    acc: impl Fn(&mut [f32], &[f32], usize) + Sync,
) {
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        init(o);
        for j in 0..=2 * r {
            let yy = mirror(y as isize + j as isize - r as isize, h);
            acc(o, &src[yy * w..(yy + 1) * w], j);
        }
    });
}

/// Separable Gaussian blur of `buf` into `out` (`tmp`: scratch of the same size).
pub(crate) fn gaussian_blur_into(
    buf: &[f32],
    tmp: &mut [f32],
    out: &mut [f32],
    w: usize,
    h: usize,
    sigma: f32,
) {
    let (k, r) = gaussian_taps(sigma);
    rows_into(buf, tmp, w, |s, d| gauss_row(&k, r, s, d));
    vertical(
        tmp,
        out,
        w,
        h,
        r,
        |o| o.fill(0.0),
        |o, s, j| {
            let kj = k[j];
            o.iter_mut().zip(s).for_each(|(o, s)| *o += kj * s);
        },
    );
}

/// High-pass in place: `buf -= G_sigma * buf` (module docs, step 3).
fn high_pass(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    let mut tmp = vec![0.0f32; buf.len()];
    let mut low = vec![0.0f32; buf.len()];
    gaussian_blur_into(buf, &mut tmp, &mut low, w, h, sigma);
    buf.par_iter_mut()
        .zip(low.par_iter())
        .for_each(|(v, &l)| *v -= l);
}

/// Running minimum (`max = false`) or maximum of one row over a centred window of `n`
/// samples clipped at the ends (the clipped window's extreme equals that of the window over
/// the edge-replicated row): `n` passes of elementwise min/max over shifted slices.
fn extreme_row(src: &[f32], dst: &mut [f32], n: usize, max: bool) {
    let len = src.len();
    let half = (n / 2) as isize;
    dst.copy_from_slice(src);
    for off in -half..=half {
        if off == 0 {
            continue;
        }
        // dst[i] op= src[clamp(i + off)]
        let (lo, hi) = if off > 0 {
            (0, len.saturating_sub(off as usize))
        } else {
            ((-off) as usize, len)
        };
        let shifted = |i: usize| (i as isize + off) as usize;
        if lo < hi {
            let s = &src[shifted(lo)..shifted(lo) + (hi - lo)];
            let d = &mut dst[lo..hi];
            if max {
                d.iter_mut().zip(s).for_each(|(d, &s)| *d = d.max(s));
            } else {
                d.iter_mut().zip(s).for_each(|(d, &s)| *d = d.min(s));
            }
        }
    }
}

/// Box mean of one row over a centred window of `n` samples clipped at the ends (prefix sums
/// in f64).
fn mean_row(src: &[f32], dst: &mut [f32], n: usize) {
    let len = src.len();
    let half = n / 2;
    let mut acc = 0.0f64;
    // the running sum over [lo, hi)
    let (mut lo, mut hi) = (0usize, 0usize);
    for (i, d) in dst.iter_mut().enumerate() {
        let want_hi = (i + half + 1).min(len);
        let want_lo = i.saturating_sub(half);
        while hi < want_hi {
            acc += src[hi] as f64;
            hi += 1;
        }
        while lo < want_lo {
            acc -= src[lo] as f64;
            lo += 1;
        }
        *d = (acc / (hi - lo) as f64) as f32;
    }
}

/// The local minimum or maximum over `n` x `n` (clipped at the borders) smoothed by an `n` x
/// `n` box (clipped): `env` gets it, `tmp` is scratch.
fn envelope(
    buf: &[f32],
    tmp: &mut [f32],
    env: &mut [f32],
    w: usize,
    h: usize,
    n: usize,
    max: bool,
) {
    let r = n / 2;
    rows_into(buf, tmp, w, |s, d| extreme_row(s, d, n, max));
    // vertical extreme over rows clamped to the image (replicating the edge rows leaves the
    // extreme of the clipped window unchanged)
    env.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        o.copy_from_slice(&tmp[y0 * w..(y0 + 1) * w]);
        for yy in y0 + 1..=y1 {
            let s = &tmp[yy * w..(yy + 1) * w];
            if max {
                o.iter_mut().zip(s).for_each(|(o, &s)| *o = o.max(s));
            } else {
                o.iter_mut().zip(s).for_each(|(o, &s)| *o = o.min(s));
            }
        }
    });
    rows_into(env, tmp, w, |s, d| mean_row(s, d, n));
    env.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        o.fill(0.0);
        for yy in y0..=y1 {
            o.iter_mut()
                .zip(&tmp[yy * w..(yy + 1) * w])
                .for_each(|(o, &s)| *o += s);
        }
        let inv = 1.0 / (y1 - y0 + 1) as f32;
        o.iter_mut().for_each(|o| *o *= inv);
    });
}

/// Min-max normalisation (module docs, step 5). Peak memory: three extra frames of f32.
fn min_max_normalise(buf: &mut [f32], w: usize, h: usize, n: usize) {
    let mut tmp = vec![0.0f32; buf.len()];
    let mut lo = vec![0.0f32; buf.len()];
    let mut hi = vec![0.0f32; buf.len()];
    envelope(buf, &mut tmp, &mut lo, w, h, n, false);
    envelope(buf, &mut tmp, &mut hi, w, h, n, true);
    let (gmin, gmax) = buf
        .par_iter()
        .fold(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |(a, b), &v| (a.min(v), b.max(v)),
        )
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |x, y| (x.0.min(y.0), x.1.max(y.1)),
        );
    let floor = (1e-6 * (gmax - gmin)).max(f32::MIN_POSITIVE);
    buf.par_iter_mut()
        .zip(lo.par_iter().zip(hi.par_iter()))
        .for_each(|(v, (&l, &u))| *v = ((*v - l) / (u - l).max(floor)).clamp(0.0, 1.0));
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    fn run(img: &Array2<f32>, c: &Conditioning, bg: Option<&Array2<f32>>) -> Array2<f32> {
        let mut out = img.clone();
        condition(out.view_mut(), c, bg.map(|b| b.view())).unwrap();
        out
    }

    #[test]
    fn nothing_switched_on_changes_nothing() {
        let img = Array2::from_shape_fn((9, 13), |(y, x)| (x * 7 + y * 3) as f32);
        assert_eq!(run(&img, &Conditioning::default(), None), img);
    }

    #[test]
    fn background_is_subtracted_and_clipped_at_zero() {
        let img = Array2::from_shape_fn((5, 6), |(y, x)| (10 * y + x) as f32);
        let bg = Array2::from_elem((5, 6), 12.0f32);
        let out = run(&img, &Conditioning::default(), Some(&bg));
        for ((y, x), &v) in out.indexed_iter() {
            assert_eq!(v, ((10 * y + x) as f32 - 12.0).max(0.0));
        }
    }

    #[test]
    fn hot_pixels_are_replaced_and_particles_kept() {
        let mut img = Array2::from_elem((12, 12), 10.0f32);
        img[[3, 4]] = 4000.0; // a hot pixel: isolated
                              // a particle of ~2 px: its neighbours are lit
        for (y, x, v) in [
            (8, 8, 900.0),
            (8, 9, 600.0),
            (9, 8, 600.0),
            (7, 8, 500.0),
            (8, 7, 450.0),
        ] {
            img[[y, x]] = v;
        }
        let c = Conditioning {
            hot_pixels: Some(3.0),
            ..Default::default()
        };
        let out = run(&img, &c, None);
        assert_eq!(out[[3, 4]], 10.0);
        assert_eq!(out[[8, 8]], 900.0);
        assert_eq!(out.iter().filter(|&&v| v != 10.0).count(), 5);
    }

    #[test]
    fn high_pass_removes_smooth_light_and_keeps_particles() {
        // a linear gradient plus a glare line (a wide Gaussian ridge) plus particles
        let particle = |x: f64, y: f64| {
            let mut s = 0.0;
            for (px, py) in [(20.0, 30.0), (45.5, 12.25), (60.0, 50.0)] {
                s += 1000.0 * (-((x - px) * (x - px) + (y - py) * (y - py)) / 2.0).exp();
            }
            s
        };
        let smooth = |x: f64, y: f64| 200.0 + 2.0 * x + 400.0 * (-(y - 40.0).powi(2) / 800.0).exp();
        let img = Array2::from_shape_fn((80, 96), |(y, x)| {
            (smooth(x as f64, y as f64) + particle(x as f64, y as f64)) as f32
        });
        let c = Conditioning {
            high_pass_sigma: Some(4.0),
            ..Default::default()
        };
        let out = run(&img, &c, None);
        // away from particles (and the mirrored border) what is left of the smooth light is
        // a few counts out of ~600; a particle keeps most of its peak
        let far = out[[70, 80]];
        assert!(far.abs() < 5.0, "{far}");
        assert!(out[[30, 20]] > 700.0, "{}", out[[30, 20]]);
        assert!(out[[50, 60]] > 700.0, "{}", out[[50, 60]]);
    }

    #[test]
    fn cap_limits_bright_pixels_at_mean_plus_k_std() {
        let img = Array2::from_shape_fn(
            (10, 10),
            |(y, x)| if x == 5 && y == 5 { 1000.0 } else { 1.0 },
        );
        let c = Conditioning {
            cap_sigma: Some(2.0),
            ..Default::default()
        };
        let out = run(&img, &c, None);
        let (mean, std) = mean_std(img.as_slice().unwrap());
        let top = (mean + 2.0 * std) as f32;
        assert!((out[[5, 5]] - top).abs() < 1e-3 && out[[0, 0]] == 1.0);
    }

    #[test]
    fn min_max_gives_equal_contrast_to_dim_and_bright_regions() {
        // the same particle pattern at two brightness levels (left dim, right 10x)
        let pattern = |x: usize, y: usize| if (x * 7 + y * 13) % 11 == 0 { 1.0 } else { 0.0 };
        let img = Array2::from_shape_fn((40, 80), |(y, x)| {
            let gain = if x < 40 { 50.0 } else { 500.0 };
            20.0 + gain * pattern(x, y)
        });
        let c = Conditioning {
            min_max_window: Some(9),
            ..Default::default()
        };
        let out = run(&img, &c, None);
        let mean_lit = |x0: usize, x1: usize| {
            let (mut s, mut n) = (0.0, 0);
            for y in 10..30 {
                for x in x0..x1 {
                    if pattern(x, y) > 0.0 {
                        s += out[[y, x]];
                        n += 1;
                    }
                }
            }
            s / n as f32
        };
        let (dim, bright) = (mean_lit(8, 30), mean_lit(50, 72));
        assert!((dim - bright).abs() < 0.02, "{dim} {bright}");
        assert!(out.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn running_filters_match_brute_force() {
        let src: Vec<f32> = (0..37).map(|i| ((i * 7919) % 23) as f32).collect();
        for n in [3, 4, 9, 40] {
            let (mut a, mut b, mut m) = (vec![0.0; 37], vec![0.0; 37], vec![0.0; 37]);
            extreme_row(&src, &mut a, n, false);
            extreme_row(&src, &mut b, n, true);
            mean_row(&src, &mut m, n);
            for i in 0..37usize {
                let lo = i.saturating_sub(n / 2);
                let hi = (i + n / 2 + 1).min(37);
                let win = &src[lo..hi];
                assert_eq!(a[i], win.iter().cloned().fold(f32::INFINITY, f32::min));
                assert_eq!(b[i], win.iter().cloned().fold(f32::NEG_INFINITY, f32::max));
                let mean = win.iter().map(|&v| v as f64).sum::<f64>() / win.len() as f64;
                assert!((m[i] as f64 - mean).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn bad_input() {
        let mut img = Array2::from_elem((4, 4), 1.0f32);
        let c = Conditioning {
            min_max_window: Some(2),
            ..Default::default()
        };
        assert!(condition(img.view_mut(), &c, None)
            .unwrap_err()
            .to_string()
            .contains(">= 3"));
        let bg = Array2::from_elem((3, 4), 1.0f32);
        let e = condition(img.view_mut(), &Conditioning::default(), Some(bg.view())).unwrap_err();
        assert!(e.to_string().contains("differs in shape"));
        img[[1, 1]] = f32::NAN;
        assert!(condition(img.view_mut(), &Conditioning::default(), None).is_err());
    }
}
