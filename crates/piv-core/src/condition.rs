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
//! 4. **smoothing** (`smooth_sigma = s` px, at most [`MAX_SMOOTH_SIGMA`]): `I <- G_s * I`,
//!    the same sampled Gaussian (truncated at 3 s, mirror boundaries): particle images under
//!    2 px across, which lock every sub-pixel fit towards whole pixels
//!    ([`crate::particle_size`]), are widened (their squared e^-2 diameter grows by about `16
//!    s^2`: 0.5 px takes 1.5 px to 2.5 px) at the cost of some random error;
//! 5. **intensity capping** (`cap_sigma = k`): `I <- min(I, mean + k std)` over the frame
//!    (Shavit, Lowe & Steinbuck 2007, Exp. Fluids 42, with the mean in place of the median), so
//!    that a few bright particles or a residual glare do not dominate a window;
//! 6. **min-max normalisation** (`min_max_window = n` px): the local minimum and maximum over
//!    about `n` x `n` px, each smoothed over about `n` x `n` px, and
//!    `I <- (I - min) / max(max - min, 1e-6 * (global max - global min))` clipped to `[0, 1]`:
//!    particles of every brightness and in every part of the sheet get the same contrast. The
//!    envelopes are computed on cells of `c = round(n / 3)` px (3 x 3 cells span `n` px): the
//!    minimum and maximum of each cell, the extreme over each cell's 3 x 3 cells (`3c` px), the
//!    mean of that over 3 x 3 cells, and bilinear interpolation between the cell centres to
//!    every pixel. The envelopes vary smoothly over `n` px and need nothing finer: this costs
//!    two passes over the frame instead of a running filter's many.
//!
//! Units: intensities in the frame's counts until step 6, dimensionless after it; lengths in px.
//! Pixel frame of the crate (x = column, y = row).

use crate::error::{PivError, Result};
#[cfg(test)]
use crate::gaussian_filter::{gaussian_taps, mirror};
use crate::gaussian_filter::{high_pass, smooth};
use image_core::Pixel;
use ndarray::{Array2, ArrayView2, ArrayViewMut2};
use rayon::prelude::*;

/// The widest smoothing ([`Conditioning::smooth_sigma`], px): a Gaussian of 2 px turns
/// particle images of 2 px into 8 px ones; more is a mistake (a high-pass sigma given as the
/// smoothing?).
pub const MAX_SMOOTH_SIGMA: f32 = 2.0;

/// Which conditioning steps run, with their parameters (`None` or 0: off). See the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Conditioning {
    /// Hot-pixel factor `f` (> 1), e.g. 3.
    pub hot_pixels: Option<f32>,
    /// High-pass Gaussian sigma in px (> 0), e.g. 4.
    pub high_pass_sigma: Option<f32>,
    /// Smoothing Gaussian sigma in px (> 0, at most [`MAX_SMOOTH_SIGMA`]), e.g. 0.5.
    pub smooth_sigma: Option<f32>,
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
        if let Some(s) = self.smooth_sigma {
            if !(s.is_finite() && s > 0.0 && s <= MAX_SMOOTH_SIGMA) {
                return bad(format!(
                    "smooth sigma {s} px must be in (0, {MAX_SMOOTH_SIGMA}] (it widens the \
                     particle images: 0.4-0.7 px against peak locking)"
                ));
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
/// shape, NaN/inf pixels, or parameters out of range. After a NaN/inf error the frame may
/// already hold the background subtraction (the check is fused with it); callers condition a
/// copy, or use [`conditioned`] (what `rspiv.preprocess.condition` calls).
pub fn condition(
    mut img: ArrayViewMut2<'_, f32>,
    c: &Conditioning,
    background: Option<ArrayView2<'_, f32>>,
) -> Result<()> {
    c.check()?;
    let (h, w) = img.dim();
    check_shapes((h, w), &background)?;
    let buf = img
        .as_slice_mut()
        .ok_or_else(|| PivError::InvalidInput("image must be C-contiguous".into()))?;
    let bg = background.as_ref().map(|b| b.as_standard_layout());
    let bs = bg.as_ref().map(|b| b.as_slice().expect("standard layout"));
    // the finite check (and the subtraction when nothing comes before it) in one pass
    let fused = if c.hot_pixels.is_none() { bs } else { None };
    let finite = buf
        .par_chunks_mut(CHUNK)
        .enumerate()
        .map(|(k, v)| {
            let mut ok = true;
            match fused {
                Some(b) => {
                    for (v, &b) in v.iter_mut().zip(&b[k * CHUNK..]) {
                        ok &= v.is_finite();
                        *v = (*v - b).max(0.0);
                    }
                }
                None => v.iter().for_each(|v| ok &= v.is_finite()),
            }
            ok
        })
        .reduce(|| true, |a, b| a && b);
    remaining_steps(buf, w, h, c, finite, bs, fused.is_some())
}

/// The conditioned copy of a frame of any pixel type as a new `f32` array (module docs): the
/// conversion to `f32` fused with the finite check (float pixels only; integers are always
/// finite) and, without hot pixels, with the background subtraction: one pass fewer than
/// copying first and calling [`condition`].
///
/// # Errors
/// As [`condition`].
pub fn conditioned<T: Pixel>(
    img: ArrayView2<'_, T>,
    c: &Conditioning,
    background: Option<ArrayView2<'_, f32>>,
) -> Result<Array2<f32>> {
    let (h, w) = img.dim();
    let mut out =
        Array2::from_shape_vec((h, w), image_core::zeroed_frame(h * w)).expect("h * w values");
    conditioned_into(img, out.view_mut(), c, background)?;
    Ok(out)
}

/// [`conditioned`] into a given C-contiguous `f32` frame of the same shape (its contents are
/// overwritten; a caller's allocator may be faster to first touch than a fresh `Vec`: numpy's
/// uses huge pages for large arrays, which the Python binding relies on).
///
/// # Errors
/// As [`condition`], and for an output of another shape or not C-contiguous.
pub fn conditioned_into<T: Pixel>(
    img: ArrayView2<'_, T>,
    mut out: ArrayViewMut2<'_, f32>,
    c: &Conditioning,
    background: Option<ArrayView2<'_, f32>>,
) -> Result<()> {
    c.check()?;
    let (h, w) = img.dim();
    check_shapes((h, w), &background)?;
    if out.dim() != (h, w) {
        return Err(PivError::InvalidInput(format!(
            "output {:?} differs in shape from the frame {:?}",
            out.dim(),
            (h, w)
        )));
    }
    let img = img.as_standard_layout();
    let src = img.as_slice().expect("standard layout");
    let bg = background.as_ref().map(|b| b.as_standard_layout());
    let bs = bg.as_ref().map(|b| b.as_slice().expect("standard layout"));
    let buf = out
        .as_slice_mut()
        .ok_or_else(|| PivError::InvalidInput("output must be C-contiguous".into()))?;
    // convert (and subtract the background when nothing comes before it)
    let fused = if c.hot_pixels.is_none() { bs } else { None };
    let finite = buf
        .par_chunks_mut(CHUNK)
        .zip(src.par_chunks(CHUNK))
        .enumerate()
        .map(|(k, (d, s))| {
            let mut ok = true;
            match fused {
                Some(b) => {
                    for ((d, &s), &b) in d.iter_mut().zip(s).zip(&b[k * CHUNK..]) {
                        ok &= s.is_finite_px();
                        *d = (s.to_f32() - b).max(0.0);
                    }
                }
                None => {
                    for (d, &s) in d.iter_mut().zip(s) {
                        ok &= s.is_finite_px();
                        *d = s.to_f32();
                    }
                }
            }
            ok
        })
        .reduce(|| true, |a, b| a && b);
    remaining_steps(buf, w, h, c, finite, bs, fused.is_some())
}

/// Pixels per parallel chunk of the first pass.
const CHUNK: usize = 1 << 16;

/// After the first pass over an `f32` frame (`finite`: no NaN/inf seen): the hot pixels and the
/// background subtraction unless `subtracted` (fused into that pass, possible only without hot
/// pixels), then [`later_steps`].
fn remaining_steps(
    buf: &mut [f32],
    w: usize,
    h: usize,
    c: &Conditioning,
    finite: bool,
    background: Option<&[f32]>,
    subtracted: bool,
) -> Result<()> {
    if !finite {
        return Err(PivError::InvalidInput(
            "image contains NaN or infinite pixel values".into(),
        ));
    }
    if !subtracted {
        if let Some(f) = c.hot_pixels {
            remove_hot_pixels(buf, w, h, f);
        }
        if let Some(b) = background {
            buf.par_iter_mut()
                .zip(b.par_iter())
                .for_each(|(v, &b)| *v = (*v - b).max(0.0));
        }
    }
    later_steps(buf, w, h, c);
    Ok(())
}

/// A non-empty frame and a background of its shape.
fn check_shapes((h, w): (usize, usize), background: &Option<ArrayView2<'_, f32>>) -> Result<()> {
    if h == 0 || w == 0 {
        return Err(PivError::InvalidInput(format!(
            "image is empty ({h} x {w})"
        )));
    }
    if let Some(b) = background {
        if b.dim() != (h, w) {
            return Err(PivError::InvalidInput(format!(
                "background {:?} differs in shape from the frame {:?}",
                b.dim(),
                (h, w)
            )));
        }
    }
    Ok(())
}

/// Steps 3-6 (high-pass, smoothing, cap, min-max normalisation), each when switched on.
fn later_steps(buf: &mut [f32], w: usize, h: usize, c: &Conditioning) {
    if let Some(s) = c.high_pass_sigma {
        high_pass(buf, w, h, s);
    }
    if let Some(s) = c.smooth_sigma {
        smooth(buf, w, h, s);
    }
    if let Some(k) = c.cap_sigma {
        let (mean, std) = mean_std(buf);
        let top = (mean + k as f64 * std) as f32;
        buf.par_iter_mut().for_each(|v| *v = v.min(top));
    }
    if let Some(n) = c.min_max_window {
        min_max_normalise(buf, w, h, n);
    }
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

/// Rows per band of [`remove_hot_pixels`]: one thread's run of rows.
const HOT_BAND: usize = 64;

/// Hot pixels (module docs, step 1); border pixels use their neighbours inside the image.
/// Bands of [`HOT_BAND`] rows in parallel, each row from the original values of its
/// neighbours: the row above kept before it was changed, the rows next to a band boundary
/// copied before any band starts (no copy of the frame).
fn remove_hot_pixels(buf: &mut [f32], w: usize, h: usize, factor: f32) {
    let nb = h.div_ceil(HOT_BAND);
    // per band: its first row, then its last row, as they are before any change
    let mut edges = vec![0.0f32; 2 * nb * w];
    for (b, e) in edges.chunks_exact_mut(2 * w).enumerate() {
        let (first, last) = (b * HOT_BAND, ((b + 1) * HOT_BAND).min(h) - 1);
        e[..w].copy_from_slice(&buf[first * w..(first + 1) * w]);
        e[w..].copy_from_slice(&buf[last * w..(last + 1) * w]);
    }
    let edge = |b: usize, last: bool| &edges[(2 * b + last as usize) * w..][..w];
    buf.par_chunks_mut(HOT_BAND * w).enumerate().for_each_init(
        || (vec![f32::NEG_INFINITY; w], vec![0.0f32; w], vec![0.0f32; w]),
        |(m, above, keep), (b, band)| {
            let rows = band.len() / w;
            for i in 0..rows {
                let y = b * HOT_BAND + i;
                let (head, tail) = band.split_at_mut((i + 1) * w);
                let row = &mut head[i * w..];
                let below = if i + 1 < rows {
                    Some(&tail[..w])
                } else {
                    (y + 1 < h).then(|| edge(b + 1, false))
                };
                let up = match (i, y) {
                    (_, 0) => None,
                    (0, _) => Some(edge(b - 1, true)),
                    _ => Some(&above[..]),
                };
                let step = ([up, below], factor);
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU supports AVX2 (checked just above)
                    unsafe { hot_row_avx2(step, row, m, keep) };
                } else {
                    hot_row(step, row, m, keep);
                }
                #[cfg(not(target_arch = "x86_64"))]
                hot_row(step, row, m, keep);
                // the row as it was is the next row's neighbour above
                std::mem::swap(above, keep);
            }
        },
    );
}

/// [`hot_row`] compiled for AVX2: the same operations in 8 lanes, the same results.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn hot_row_avx2(
    step: ([Option<&[f32]>; 2], f32),
    row: &mut [f32],
    m: &mut [f32],
    keep: &mut [f32],
) {
    hot_row(step, row, m, keep)
}

/// One row of [`remove_hot_pixels`]: `rows` the original rows above and below `row` (`None`
/// beyond the frame), `m` scratch, `keep` receives `row` as it was.
///
/// `m[x]`, the brightest of the 8 neighbours inside the frame, is taken in one fixed order:
/// the row above (its pixels at `x`, `x - 1`, `x + 1`), the row below likewise, then the row's
/// own `x - 1` and `x + 1` (`gt` keeps its second argument on ties and NaN, so the order is
/// part of the result). Every value is stored unconditionally: written as in-place updates
/// (`m[x] = gt(m[x], v)`), the loops compiled to masked stores, slow on AMD cores.
#[inline(always)]
fn hot_row(
    (rows, factor): ([Option<&[f32]>; 2], f32),
    row: &mut [f32],
    m: &mut [f32],
    keep: &mut [f32],
) {
    let gt = |a: f32, b: f32| if a > b { a } else { b };
    let w = row.len();
    keep.copy_from_slice(row);
    let mid = &*keep;
    let (n, r0, r1): (usize, &[f32], &[f32]) = match rows {
        [Some(a), Some(b)] => (2, a, b),
        [Some(a), None] | [None, Some(a)] => (1, a, a),
        [None, None] => (0, mid, mid),
    };
    // the general rule (edges): `gt(-inf, v) = v`, so a row's first term starts the maximum
    let at = |x: usize| {
        let mut acc = f32::NEG_INFINITY;
        for nb in [r0, r1].into_iter().take(n) {
            acc = gt(acc, nb[x]);
            if x > 0 {
                acc = gt(acc, nb[x - 1]);
            }
            if x + 1 < w {
                acc = gt(acc, nb[x + 1]);
            }
        }
        if x > 0 {
            acc = gt(acc, mid[x - 1]);
        }
        if x + 1 < w {
            acc = gt(acc, mid[x + 1]);
        }
        acc
    };
    if w > 2 {
        let k = w - 2;
        let (l, c, r) = (&mid[..k], &mid[2..], &mut m[1..w - 1]);
        let (a0, a1, a2) = (&r0[..k], &r0[1..k + 1], &r0[2..]);
        let (b0, b1, b2) = (&r1[..k], &r1[1..k + 1], &r1[2..]);
        match n {
            2 => {
                for i in 0..k {
                    let t = gt(gt(a1[i], a0[i]), a2[i]);
                    let t = gt(gt(gt(t, b1[i]), b0[i]), b2[i]);
                    r[i] = gt(gt(t, l[i]), c[i]);
                }
            }
            1 => {
                for i in 0..k {
                    let t = gt(gt(a1[i], a0[i]), a2[i]);
                    r[i] = gt(gt(t, l[i]), c[i]);
                }
            }
            _ => {
                for i in 0..k {
                    r[i] = gt(gt(f32::NEG_INFINITY, l[i]), c[i]);
                }
            }
        }
    }
    m[0] = at(0);
    m[w - 1] = at(w - 1);
    for ((v, &m), &k) in row.iter_mut().zip(m.iter()).zip(mid) {
        let hot = k > 0.0 && m > f32::NEG_INFINITY && k > factor * gt(m, 0.0);
        *v = if hot { m } else { k };
    }
}

/// The cell size of the min-max normalisation for an `n` px window: 3 x 3 cells span about
/// `n` px (`round(n / 3)`, at least 1).
fn cell_size(n: usize) -> usize {
    ((n + 1) / 3).max(1)
}

/// The minimum and maximum of every `c` x `c` cell of the frame (the last cells clipped at the
/// frame's edge), row-major `(ch, cw)`: one pass over the frame, rows in parallel bands of `c`.
fn cell_extremes(buf: &[f32], w: usize, h: usize, c: usize) -> (Vec<f32>, Vec<f32>, usize, usize) {
    let (cw, ch) = (w.div_ceil(c), h.div_ceil(c));
    let mut lo = vec![0.0f32; cw * ch];
    let mut hi = vec![0.0f32; cw * ch];
    lo.par_chunks_mut(cw)
        .zip(hi.par_chunks_mut(cw))
        .enumerate()
        .for_each_init(
            || (vec![0.0f32; w], vec![0.0f32; w]),
            |(rmin, rmax), (cy, (l, u))| {
                // elementwise extremes over the band's rows, then per cell along the row
                let rows = &buf[cy * c * w..((cy + 1) * c).min(h) * w];
                rmin.copy_from_slice(&rows[..w]);
                rmax.copy_from_slice(&rows[..w]);
                for row in rows.chunks_exact(w).skip(1) {
                    for ((a, b), &v) in rmin.iter_mut().zip(rmax.iter_mut()).zip(row) {
                        *a = if v < *a { v } else { *a };
                        *b = if v > *b { v } else { *b };
                    }
                }
                for (((l, u), a), b) in l
                    .iter_mut()
                    .zip(u.iter_mut())
                    .zip(rmin.chunks(c))
                    .zip(rmax.chunks(c))
                {
                    *l = a.iter().fold(f32::INFINITY, |m, &v| m.min(v));
                    *u = b.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
                }
            },
        );
    (lo, hi, cw, ch)
}

/// `out[i] = op(x[i - 1], x[i], x[i + 1])` over one line, clipped at the ends: `edge` gives
/// the value of the two-element windows at the ends (and `single` of a one-element line).
#[inline]
fn three_tap(
    x: &[f32],
    out: &mut [f32],
    op: impl Fn(f32, f32, f32) -> f32,
    edge: impl Fn(f32, f32) -> f32,
    single: impl Fn(f32) -> f32,
) {
    let n = x.len();
    if n == 1 {
        out[0] = single(x[0]);
        return;
    }
    out[0] = edge(x[0], x[1]);
    out[n - 1] = edge(x[n - 2], x[n - 1]);
    for (((o, &a), &b), &c) in out[1..n - 1].iter_mut().zip(x).zip(&x[1..]).zip(&x[2..]) {
        *o = op(a, b, c);
    }
}

/// A clipped 3 x 3 filter of a `cw` x `ch` grid, separably: [`three_tap`] along x, then along
/// y (rows in parallel).
fn three_by_three<O, E>(src: &[f32], dst: &mut [f32], cw: usize, ch: usize, op: O, edge: E)
where
    O: Fn(f32, f32, f32) -> f32 + Sync + Copy,
    E: Fn(f32, f32) -> f32 + Sync + Copy,
{
    let mut t = vec![0.0f32; cw * ch];
    t.par_chunks_mut(cw)
        .zip(src.par_chunks(cw))
        .for_each(|(o, r)| three_tap(r, o, op, edge, |a| a));
    dst.par_chunks_mut(cw).enumerate().for_each(|(j, o)| {
        let row = |jj: usize| &t[jj * cw..(jj + 1) * cw];
        if ch == 1 {
            o.copy_from_slice(row(0));
        } else if j == 0 || j == ch - 1 {
            let (a, b) = if j == 0 {
                (row(0), row(1))
            } else {
                (row(ch - 2), row(ch - 1))
            };
            for ((o, &a), &b) in o.iter_mut().zip(a).zip(b) {
                *o = edge(a, b);
            }
        } else {
            let (a, b, c) = (row(j - 1), row(j), row(j + 1));
            for (((o, &a), &b), &c) in o.iter_mut().zip(a).zip(b).zip(c) {
                *o = op(a, b, c);
            }
        }
    });
}

/// The extreme (`max` or min) of each cell's 3 x 3 neighbourhood of cells (clipped at the
/// edges), then the mean over each cell's 3 x 3 neighbourhood (clipped): the envelope at the
/// cell centres (a clipped 3 x 3 window is a rectangle, so both go separably).
fn smooth_envelope(cells: &[f32], cw: usize, ch: usize, max: bool) -> Vec<f32> {
    let mut ext = vec![0.0f32; cw * ch];
    if max {
        let m2 = |a: f32, b: f32| a.max(b);
        three_by_three(cells, &mut ext, cw, ch, move |a, b, c| m2(m2(a, b), c), m2);
    } else {
        let m2 = |a: f32, b: f32| a.min(b);
        three_by_three(cells, &mut ext, cw, ch, move |a, b, c| m2(m2(a, b), c), m2);
    }
    let mut env = vec![0.0f32; cw * ch];
    three_by_three(
        &ext,
        &mut env,
        cw,
        ch,
        |a, b, c| (a + b + c) * (1.0 / 3.0),
        |a, b| 0.5 * (a + b),
    );
    env
}

/// Linear interpolation weights between cell centres (`(t + 0.5) c - 0.5` px) for the pixels
/// `0..len`: the lower cell and the weight of the upper one, constant beyond the first and last
/// centres.
fn cell_lerp(len: usize, cells: usize, c: usize) -> Vec<(usize, f32)> {
    (0..len)
        .map(|p| {
            let t = ((p as f32 + 0.5) / c as f32 - 0.5).clamp(0.0, (cells - 1) as f32);
            let i = (t.floor() as usize).min(cells.saturating_sub(2));
            (i, if cells > 1 { t - i as f32 } else { 0.0 })
        })
        .collect()
}

/// Min-max normalisation (module docs, step 6): the envelopes at the cell centres
/// ([`cell_extremes`], [`smooth_envelope`]) interpolated bilinearly to every pixel. The rows
/// between two rows of cell centres form a band (groups of bands in parallel): the centre rows
/// are interpolated along x once, and each pixel row of a band is the vectorised linear blend
/// of its two. Two passes over the frame; extra memory: the cell grids (`2 / c^2` of the
/// frame) and four rows per task.
fn min_max_normalise(buf: &mut [f32], w: usize, h: usize, n: usize) {
    let c = cell_size(n);
    let (lo, hi, cw, ch) = cell_extremes(buf, w, h, c);
    let gmin = lo.iter().fold(f32::INFINITY, |m, &v| m.min(v));
    let gmax = hi.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    let floor = (1e-6 * (gmax - gmin)).max(f32::MIN_POSITIVE);
    let (lo, hi) = (
        smooth_envelope(&lo, cw, ch, false),
        smooth_envelope(&hi, cw, ch, true),
    );
    let xs = cell_lerp(w, cw, c);
    let ys = cell_lerp(h, ch, c);
    // bands of rows sharing their lower cell-centre row
    let mut bands: Vec<(usize, usize, &mut [f32])> = Vec::new();
    let mut rest = buf;
    let mut y = 0;
    while y < h {
        let j = ys[y].0;
        let y1 = (y..h).find(|&yy| ys[yy].0 != j).unwrap_or(h);
        let (band, tail) = std::mem::take(&mut rest).split_at_mut((y1 - y) * w);
        bands.push((j, y, band));
        rest = tail;
        y = y1;
    }
    // one envelope row interpolated along x: runs of pixels between two cell centres share
    // their cells (a contiguous blend per run, no per-pixel index)
    let fx: Vec<f32> = xs.iter().map(|&(_, f)| f).collect();
    let mut runs: Vec<(usize, usize, usize)> = Vec::with_capacity(cw);
    for (x, &(i, _)) in xs.iter().enumerate() {
        match runs.last_mut() {
            Some(r) if r.2 == i => r.1 = x + 1,
            _ => runs.push((x, x + 1, i)),
        }
    }
    let along_x = |env: &[f32], j: usize, out: &mut [f32]| {
        let cells = &env[j * cw..(j + 1) * cw];
        for &(x0, x1, i) in &runs {
            let a = cells[i];
            let d = cells[(i + 1).min(cw - 1)] - a;
            for (o, &f) in out[x0..x1].iter_mut().zip(&fx[x0..x1]) {
                *o = a + d * f;
            }
        }
    };
    // groups of consecutive bands per task: a band's upper centre row is the next band's
    // lower one, interpolated once
    let group = bands
        .len()
        .div_ceil(4 * rayon::current_num_threads())
        .max(1);
    bands.par_chunks_mut(group).for_each(|g| {
        let (mut l0, mut l1) = (vec![0.0f32; w], vec![0.0f32; w]);
        let (mut u0, mut u1) = (vec![0.0f32; w], vec![0.0f32; w]);
        let mut have = usize::MAX; // the centre row held in l1/u1
        for (j, y0, band) in g.iter_mut() {
            let (j, j1) = (*j, (*j + 1).min(ch - 1));
            if have == j {
                std::mem::swap(&mut l0, &mut l1);
                std::mem::swap(&mut u0, &mut u1);
            } else {
                along_x(&lo, j, &mut l0);
                along_x(&hi, j, &mut u0);
            }
            along_x(&lo, j1, &mut l1);
            along_x(&hi, j1, &mut u1);
            have = j1;
            for (r, row) in band.chunks_exact_mut(w).enumerate() {
                let fy = ys[*y0 + r].1;
                let blend = row.iter_mut().zip(&l0).zip(&l1).zip(&u0).zip(&u1);
                for ((((v, &a), &b), &p), &q) in blend {
                    let l = a + (b - a) * fy;
                    let u = p + (q - p) * fy;
                    *v = ((*v - l) / (u - l).max(floor)).clamp(0.0, 1.0);
                }
            }
        }
    });
}

#[cfg(test)]
#[path = "condition_tests.rs"]
mod tests;
