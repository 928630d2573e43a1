//! The Gaussian filters of the image conditioning ([`crate::condition`], steps 3 and 4): the
//! high-pass `I <- I - G_s * I` and the smoothing `I <- G_s * I`, with `G_s` the sampled
//! Gaussian of standard deviation `s` px (truncated at 3 s, normalised, mirror boundaries),
//! separable: in place, rows in parallel bands, no scratch frame.

use rayon::prelude::*;

/// Whole-sample mirror index into `0..n` (n >= 1).
#[inline]
pub(crate) fn mirror(i: isize, n: usize) -> usize {
    image_core::kernels::mirror(i, n)
}

/// The normalised Gaussian taps of sigma `s` (truncated at 3 s): `(taps, radius)`.
pub(crate) fn gaussian_taps(sigma: f32) -> (Vec<f32>, usize) {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f32 = k.iter().sum();
    (k.iter().map(|v| v / norm).collect(), r as usize)
}

/// Outputs summed at a time in registers by [`gauss_row`] and [`low_removed`].
const LANES: usize = 16;

/// Horizontal Gaussian of one row (mirror boundaries): the interior [`LANES`] outputs at a
/// time, each the sum `0 + k_0 s_0 + k_1 s_1 + ...` in tap order in registers (one pass over
/// the row), the `r` samples at each end with mirrored taps.
#[inline(always)]
fn gauss_row(k: &[f32], r: usize, src: &[f32], dst: &mut [f32]) {
    let n = src.len();
    if n > 2 * r {
        let m = n - 2 * r;
        let mut chunks = dst[r..r + m].chunks_exact_mut(LANES);
        let mut i0 = 0;
        for o in &mut chunks {
            let mut acc = [0.0f32; LANES];
            for (j, &kj) in k.iter().enumerate() {
                let s = &src[i0 + j..i0 + j + LANES];
                for (a, &v) in acc.iter_mut().zip(s) {
                    *a += kj * v;
                }
            }
            o.copy_from_slice(&acc);
            i0 += LANES;
        }
        for (l, o) in chunks.into_remainder().iter_mut().enumerate() {
            let mut acc = 0.0f32;
            for (j, &kj) in k.iter().enumerate() {
                acc += kj * src[i0 + l + j];
            }
            *o = acc;
        }
    }
    // every sample not written above is within r of an end
    for i in (0..n).filter(|&i| i < r || i + r >= n) {
        let mut acc = 0.0f32;
        for (j, &kj) in k.iter().enumerate() {
            acc += kj * src[mirror(i as isize + j as isize - r as isize, n)];
        }
        dst[i] = acc;
    }
}

/// Rows per band of [`filter`]: one thread's run of rows.
const PASS_BAND: usize = 128;

/// High-pass in place: `buf -= G_sigma * buf` (step 3 of [`crate::condition`]); see
/// [`filter`].
pub(crate) fn high_pass(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    filter::<false>(buf, w, h, sigma)
}

/// Smoothing in place: `buf = G_sigma * buf` (step 4 of [`crate::condition`]); see
/// [`filter`].
pub(crate) fn smooth(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    filter::<true>(buf, w, h, sigma)
}

/// The Gaussian of `buf` (`SMOOTH`) or `buf` less it (the high-pass), in place. The rows in
/// bands of [`PASS_BAND`] in parallel: the horizontal blur of each band's rows into a buffer
/// of the thread's, then per row the vertical blur of those (into a row buffer), which
/// replaces the row or is subtracted from it. The rows within `r` (the kernel's radius) of a
/// band boundary, which the bands on either side read, are blurred before any band changes
/// its rows and shared. The same sums in the same order as blurring the whole frame first,
/// without a scratch frame.
fn filter<const SMOOTH: bool>(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    let (k, r) = gaussian_taps(sigma);
    let blur = |s: &[f32], d: &mut [f32]| {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above)
            return unsafe { gauss_row_avx2(&k, r, s, d) };
        }
        gauss_row(&k, r, s, d)
    };
    // the shared rows: within r of an interior band boundary, blurred first
    let mut slot = vec![usize::MAX; h];
    let mut shared_rows = Vec::new();
    for y0 in (PASS_BAND..h).step_by(PASS_BAND) {
        for y in y0.saturating_sub(r)..(y0 + r).min(h) {
            if slot[y] == usize::MAX {
                slot[y] = shared_rows.len();
                shared_rows.push(y);
            }
        }
    }
    let mut shared = vec![0.0f32; shared_rows.len() * w];
    shared
        .par_chunks_mut(w)
        .zip(&shared_rows)
        .for_each(|(d, &y)| blur(&buf[y * w..(y + 1) * w], d));
    buf.par_chunks_mut(PASS_BAND * w).enumerate().for_each_init(
        || (vec![0.0f32; PASS_BAND * w], vec![0.0f32; w]),
        |(own, low), (b, band)| {
            let y0 = b * PASS_BAND;
            for (i, row) in band.chunks_exact(w).enumerate() {
                if slot[y0 + i] == usize::MAX {
                    blur(row, &mut own[i * w..(i + 1) * w]);
                }
            }
            let blurred = |yy: usize| match slot[yy] {
                usize::MAX => &own[(yy - y0) * w..][..w],
                s => &shared[s * w..][..w],
            };
            for (i, row) in band.chunks_exact_mut(w).enumerate() {
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU supports AVX2 (checked just above)
                    unsafe { low_removed_avx2::<SMOOTH>(&k, r, &blurred, (y0 + i, h), row, low) };
                    continue;
                }
                low_removed::<SMOOTH>(&k, r, &blurred, (y0 + i, h), row, low)
            }
        },
    );
}

/// Most taps [`low_removed`] sums in registers (sigma up to 10 px); wider kernels sum row
/// by row into `low`.
const MAX_TAPS: usize = 63;

/// Row `y` of [`filter`] (of `h` rows): the vertical Gaussian of the horizontally blurred
/// rows (`blurred(row index)`), `0 + k_0 b_0 + k_1 b_1 + ...` in tap order, subtracted from
/// `row` (or in its place, `SMOOTH`): [`LANES`] columns at a time in registers, or (more than
/// [`MAX_TAPS`] taps) tap by tap into `low`; the same sums either way.
#[inline(always)]
fn low_removed<'a, const SMOOTH: bool>(
    k: &[f32],
    r: usize,
    blurred: &impl Fn(usize) -> &'a [f32],
    (y, h): (usize, usize),
    row: &mut [f32],
    low: &mut [f32],
) {
    let tap = |j: usize| blurred(mirror(y as isize + j as isize - r as isize, h));
    if k.len() > MAX_TAPS {
        low.fill(0.0);
        for (j, &kj) in k.iter().enumerate() {
            for (o, &s) in low.iter_mut().zip(tap(j)) {
                *o += kj * s;
            }
        }
        for (v, &l) in row.iter_mut().zip(low.iter()) {
            *v = if SMOOTH { l } else { *v - l };
        }
        return;
    }
    let mut src: [&[f32]; MAX_TAPS] = [&[]; MAX_TAPS];
    for (j, s) in src.iter_mut().enumerate().take(k.len()) {
        *s = tap(j);
    }
    let src = &src[..k.len()];
    let mut chunks = row.chunks_exact_mut(LANES);
    let mut x0 = 0;
    for o in &mut chunks {
        let mut acc = [0.0f32; LANES];
        for (&kj, s) in k.iter().zip(src) {
            for (a, &v) in acc.iter_mut().zip(&s[x0..x0 + LANES]) {
                *a += kj * v;
            }
        }
        for (v, a) in o.iter_mut().zip(acc) {
            *v = if SMOOTH { a } else { *v - a };
        }
        x0 += LANES;
    }
    for (l, v) in chunks.into_remainder().iter_mut().enumerate() {
        let mut acc = 0.0f32;
        for (&kj, s) in k.iter().zip(src) {
            acc += kj * s[x0 + l];
        }
        *v = if SMOOTH { acc } else { *v - acc };
    }
}

/// [`low_removed`] compiled for AVX2 (no FMA: the same results).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn low_removed_avx2<'a, const SMOOTH: bool>(
    k: &[f32],
    r: usize,
    blurred: &impl Fn(usize) -> &'a [f32],
    at: (usize, usize),
    row: &mut [f32],
    low: &mut [f32],
) {
    low_removed::<SMOOTH>(k, r, blurred, at, row, low)
}

/// [`gauss_row`] compiled for AVX2 (no FMA: the same results).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gauss_row_avx2(k: &[f32], r: usize, src: &[f32], dst: &mut [f32]) {
    gauss_row(k, r, src, dst)
}
