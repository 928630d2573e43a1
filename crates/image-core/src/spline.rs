//! Unser's recursive B-spline prefilter (Unser 1999, IEEE Signal Proc. Mag. 16), mirror
//! (whole-sample symmetric) boundaries.
//!
//! [`prefilter`] turns an image's samples, in place, into the coefficients whose B-spline of the
//! given order ([`SplineOrder`]) passes through the samples: interpolating them with
//! [`crate::bspline_weights`] (cubic) or [`crate::bspline5_weights`] (quintic) returns the pixels
//! exactly. Each pole is one causal and one anticausal recursion per line; the causal initial
//! sum is truncated where `|z|^k < 1e-8` and exact (one mirror period) for short lines. Rows run
//! in parallel, eight at a time interleaved (the recursions are serial chains along a line);
//! columns in parallel strips of 64, each copied into a contiguous buffer.

use crate::kernels::mirror;
use crate::{zeroed_frame, Pixel};
use ndarray::parallel::prelude::*;
use rayon::prelude::*;

/// The order of the B-spline whose coefficients [`prefilter`] computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SplineOrder {
    /// Cubic (one pole, `sqrt(3) - 2`; 4 x 4 taps).
    Cubic,
    /// Quintic (two poles; 6 x 6 taps).
    Quintic,
}

/// Poles of the cubic B-spline prefilter.
const BSPLINE3_POLES: [f32; 1] = [-0.267_949_2]; // sqrt(3) - 2
/// Poles of the quintic B-spline prefilter (roots of z^4 + 26 z^3 + 66 z^2 + 26 z + 1 inside
/// the unit circle).
const BSPLINE5_POLES: [f32; 2] = [-0.430_575_35, -0.043_096_29];

impl SplineOrder {
    fn poles(self) -> &'static [f32] {
        match self {
            SplineOrder::Cubic => &BSPLINE3_POLES,
            SplineOrder::Quintic => &BSPLINE5_POLES,
        }
    }
}

/// Number of terms of the mirror-boundary initial sum for pole `z` (`|z|^k < 1e-8`).
fn horizon(z: f32, n: usize) -> usize {
    let k = ((1e-8f64).ln() / (z.abs() as f64).ln()).ceil() as usize;
    k.clamp(1, n)
}

/// Overall gain of the prefilter, `prod (1 - z)(1 - 1/z)` (6 for cubic, 120 for quintic).
fn gain(poles: &[f32]) -> f32 {
    poles
        .iter()
        .map(|&z| (1.0 - z as f64) * (1.0 - 1.0 / z as f64))
        .product::<f64>() as f32
}

/// The causal initial value `sum_k z^k c[k]` of a line of `n` values `c(k)` with mirror
/// boundaries: truncated where `|z|^k < 1e-8`, exact (over one mirror period) for short lines.
fn causal_init(z: f32, n: usize, c: impl Fn(usize) -> f32) -> f32 {
    let hz = horizon(z, usize::MAX);
    if hz < n {
        let (mut acc, mut zk) = (0.0f32, 1.0f32);
        for k in 0..hz {
            acc += zk * c(k);
            zk *= z;
        }
        return acc;
    }
    let period = 2 * n - 2;
    let (mut acc, mut zk) = (0.0f64, 1.0f64);
    for k in 0..period {
        acc += zk * c(mirror(k as isize, n)) as f64;
        zk *= z as f64;
    }
    (acc / (1.0 - zk)) as f32
}

/// One causal + anticausal recursion of pole `z` along a line (mirror boundaries), without the
/// gain.
fn prefilter_1d(c: &mut [f32], z: f32) {
    let n = c.len();
    if n < 2 {
        return;
    }
    c[0] = causal_init(z, n, |k| c[k]);
    for k in 1..n {
        c[k] += z * c[k - 1];
    }
    c[n - 1] = z / (z * z - 1.0) * (c[n - 1] + z * c[n - 2]);
    for k in (0..n - 1).rev() {
        c[k] = z * (c[k + 1] - c[k]);
    }
}

/// Rows filtered together by [`rows_interleaved`]: one SIMD lane of 8 `f32` per row.
const LANES: usize = 8;

/// The recursions of `poles` along each row of `rows` (whole rows of `w` values): groups of
/// [`LANES`] rows interleaved in `buf` (`buf[k][l]` = row `l`'s value `k`) so that every step of
/// the recursions runs on 8 independent rows at once instead of waiting on the one before it
/// (a row's recursion is a serial chain). Each row gets exactly the operations of
/// [`prefilter_1d`], in the same order: the result is bit for bit the row-by-row one. Short
/// rows (the exact mirror-period initial sum) and a last group of fewer rows go row by row.
fn rows_interleaved(rows: &mut [f32], w: usize, poles: &[f32], buf: &mut Vec<[f32; LANES]>) {
    let short = poles.iter().any(|&z| horizon(z, usize::MAX) >= w);
    if w < 2 || short || rows.len() != LANES * w {
        for row in rows.chunks_exact_mut(w.max(1)) {
            for &z in poles {
                prefilter_1d(row, z);
            }
        }
        return;
    }
    buf.clear();
    buf.resize(w, [0.0; LANES]);
    for (l, row) in rows.chunks_exact(w).enumerate() {
        for (b, &v) in buf.iter_mut().zip(row) {
            b[l] = v;
        }
    }
    for &z in poles {
        one_pole_lanes(buf, z);
    }
    for (l, row) in rows.chunks_exact_mut(w).enumerate() {
        for (v, b) in row.iter_mut().zip(buf.iter()) {
            *v = b[l];
        }
    }
}

/// [`prefilter_1d`] of pole `z` on [`LANES`] interleaved lines of `c.len()` values, longer
/// than the causal sum's horizon (its truncated form).
#[inline(always)]
fn one_pole_lanes(c: &mut [[f32; LANES]], z: f32) {
    let n = c.len();
    let (mut acc, mut zk) = ([0.0f32; LANES], 1.0f32);
    for ck in &c[..horizon(z, usize::MAX)] {
        for (a, &v) in acc.iter_mut().zip(ck) {
            *a += zk * v;
        }
        zk *= z;
    }
    c[0] = acc;
    for k in 1..n {
        let p = c[k - 1];
        for (v, &q) in c[k].iter_mut().zip(&p) {
            *v += z * q;
        }
    }
    let p = c[n - 2];
    for (v, &q) in c[n - 1].iter_mut().zip(&p) {
        *v = z / (z * z - 1.0) * (*v + z * q);
    }
    for k in (0..n - 1).rev() {
        let nx = c[k + 1];
        for (v, &q) in c[k].iter_mut().zip(&nx) {
            *v = z * (q - *v);
        }
    }
}

/// The recursions of `poles` along the columns of a row-major `w`-wide image, each value
/// multiplied by `gain` as it is written back: strips of 64 columns in parallel, each copied
/// row by row into a contiguous buffer and filtered there.
fn prefilter_columns(c: &mut [f32], w: usize, h: usize, poles: &[f32], gain: f32) {
    const STRIP: usize = 64;
    let mut view = ndarray::ArrayViewMut2::from_shape((h, w), c).expect("shape");
    view.axis_chunks_iter_mut(ndarray::Axis(1), STRIP)
        .into_par_iter()
        .for_each(|mut strip| {
            let sw = strip.ncols();
            let mut buf = vec![0.0f32; sw * h];
            for (b, row) in buf.chunks_exact_mut(sw).zip(strip.rows()) {
                match row.as_slice() {
                    Some(r) => b.copy_from_slice(r),
                    None => b.iter_mut().zip(row).for_each(|(d, &v)| *d = v),
                }
            }
            for &z in poles {
                columns_one_pole(&mut buf, sw, h, z);
            }
            for (mut row, b) in strip.rows_mut().into_iter().zip(buf.chunks_exact(sw)) {
                row.iter_mut().zip(b).for_each(|(d, &v)| *d = v * gain);
            }
        });
}

/// One pole's causal + anticausal recursion along the columns of `buf` (`h` rows of `sw`).
fn columns_one_pole(buf: &mut [f32], sw: usize, h: usize, z: f32) {
    // causal initialisation: row 0 = sum_k z^k row k (mirror boundary)
    for col in 0..sw {
        buf[col] = causal_init(z, h, |k| buf[k * sw + col]);
    }
    for y in 1..h {
        let (prev, cur) = buf[(y - 1) * sw..(y + 1) * sw].split_at_mut(sw);
        for (x, p) in cur.iter_mut().zip(prev.iter()) {
            *x += z * p;
        }
    }
    let g = z / (z * z - 1.0);
    {
        let (prev, last) = buf[(h - 2) * sw..h * sw].split_at_mut(sw);
        for (x, p) in last.iter_mut().zip(prev.iter()) {
            *x = g * (*x + z * p);
        }
    }
    for y in (0..h - 1).rev() {
        let (cur, next) = buf[y * sw..(y + 2) * sw].split_at_mut(sw);
        for (x, n) in cur.iter_mut().zip(next.iter()) {
            *x = z * (n - *x);
        }
    }
}

/// Replace the samples of a row-major `h` x `w` image `c` (`c.len() == w * h`) by their
/// B-spline coefficients of `order`, in place (rows, then columns, then the gain of both axes;
/// an axis of one pixel has none: its lines are left as they are).
///
/// # Panics
/// If `c.len() != w * h` (a programming error of the caller, not bad data).
pub fn prefilter(c: &mut [f32], w: usize, h: usize, order: SplineOrder) {
    assert_eq!(c.len(), w * h, "prefilter: buffer is not w * h");
    filter_2d(c, w, h, order, |_| {});
}

/// The B-spline coefficients of `order` of the row-major `h` x `w` image `src` (its pixels
/// as `f32`), as [`prefilter`] computes them in place, in a new buffer that is cheap to first
/// touch ([`crate::zeroed_frame`]); each group of rows is converted just before its
/// recursions, while it is in cache.
///
/// # Panics
/// If `src.len() != w * h` (a programming error of the caller, not bad data).
pub fn prefilter_from<T: Pixel>(src: &[T], w: usize, h: usize, order: SplineOrder) -> Vec<f32> {
    assert_eq!(src.len(), w * h, "prefilter_from: image is not w * h");
    let mut c = zeroed_frame(w * h);
    filter_2d(&mut c, w, h, order, |(g, rows): (usize, &mut [f32])| {
        let (at, n) = (g * LANES * w, rows.len());
        for (d, &s) in rows.iter_mut().zip(&src[at..at + n]) {
            *d = s.to_f32();
        }
    });
    c
}

/// [`prefilter`] of `c`, with `fill((group, rows))` writing each group of [`LANES`] rows'
/// values just before the group's recursions.
fn filter_2d(
    c: &mut [f32],
    w: usize,
    h: usize,
    order: SplineOrder,
    fill: impl Fn((usize, &mut [f32])) + Sync,
) {
    let poles = order.poles();
    let w = w.max(1);
    let row_poles: &[f32] = if w >= 2 { poles } else { &[] };
    c.par_chunks_mut(LANES * w)
        .enumerate()
        .for_each_init(Vec::new, |buf, (g, rows)| {
            fill((g, &mut *rows));
            rows_interleaved(rows, w, row_poles, buf);
        });
    let g = (if w >= 2 { gain(poles) } else { 1.0 }) * (if h >= 2 { gain(poles) } else { 1.0 });
    if h >= 2 {
        prefilter_columns(c, w, h, poles, g);
    } else {
        c.par_chunks_mut(1 << 16)
            .for_each(|ch| ch.iter_mut().for_each(|x| *x *= g));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::{bspline5_weights, bspline_weights};

    /// The coefficients interpolated at pixel (x, y) with an `N`-tap kernel (mirror taps).
    fn at<const N: usize>(
        c: &[f32],
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        wf: fn(f32) -> [f32; N],
    ) -> f32 {
        let k = wf(0.0);
        let o = (N / 2 - 1) as isize;
        let mut acc = 0.0;
        for (r, wy) in k.iter().enumerate() {
            for (q, wx) in k.iter().enumerate() {
                let yy = mirror(y as isize - o + r as isize, h);
                let xx = mirror(x as isize - o + q as isize, w);
                acc += wy * wx * c[yy * w + xx];
            }
        }
        acc
    }

    #[test]
    fn coefficients_interpolate_the_samples_for_both_orders() {
        let (w, h) = (23, 9);
        let img: Vec<f32> = (0..w * h)
            .map(|i| ((i * 7919) % 101) as f32 + 0.25 * (i / w) as f32)
            .collect();
        for order in [SplineOrder::Cubic, SplineOrder::Quintic] {
            let mut c = img.clone();
            prefilter(&mut c, w, h, order);
            for y in 0..h {
                for x in 0..w {
                    let v = match order {
                        SplineOrder::Cubic => at(&c, w, h, x, y, bspline_weights),
                        SplineOrder::Quintic => at(&c, w, h, x, y, bspline5_weights),
                    };
                    let e = img[y * w + x];
                    assert!(
                        (v - e).abs() < 2e-3 * e.abs().max(1.0),
                        "{order:?} {x} {y} {v} {e}"
                    );
                }
            }
        }
    }

    /// The straightforward filter: every row, then every column, one line at a time, then
    /// the gain.
    fn reference(img: &[f32], w: usize, h: usize, order: SplineOrder) -> Vec<f32> {
        let mut c = img.to_vec();
        let poles = order.poles();
        for row in c.chunks_exact_mut(w) {
            for &z in poles {
                prefilter_1d(row, z);
            }
        }
        for x in 0..w {
            let mut col: Vec<f32> = (0..h).map(|y| c[y * w + x]).collect();
            for &z in poles {
                prefilter_1d(&mut col, z);
            }
            for (y, v) in col.into_iter().enumerate() {
                c[y * w + x] = v;
            }
        }
        let g = (if w >= 2 { gain(poles) } else { 1.0 }) * (if h >= 2 { gain(poles) } else { 1.0 });
        c.iter_mut().for_each(|x| *x *= g);
        c
    }

    #[test]
    fn interleaved_rows_and_the_converting_filter_match_line_by_line_bit_for_bit() {
        // groups of 8 rows and a shorter last group, rows longer and shorter than the causal
        // sum's horizon (~22 values), strips of 64 columns and a narrower last strip
        for (w, h) in [(150, 19), (97, 8), (12, 17), (70, 1), (1, 30), (3, 3)] {
            let img: Vec<u16> = (0..w * h).map(|i| ((i * 7919) % 4093) as u16).collect();
            let f: Vec<f32> = img.iter().map(|&v| v as f32).collect();
            for order in [SplineOrder::Cubic, SplineOrder::Quintic] {
                let want = reference(&f, w, h, order);
                let mut c = f.clone();
                prefilter(&mut c, w, h, order);
                assert_eq!(c, want, "{w} x {h} {order:?} in place");
                assert_eq!(
                    prefilter_from(&img, w, h, order),
                    want,
                    "{w} x {h} {order:?}"
                );
            }
        }
    }

    #[test]
    fn single_pixel_lines_are_left_alone() {
        let mut c = vec![3.0f32, 5.0, 7.0];
        prefilter(&mut c, 3, 1, SplineOrder::Cubic);
        let g = gain(&BSPLINE3_POLES);
        assert!((g - 6.0).abs() < 1e-5);
        let mut d = vec![4.0f32];
        prefilter(&mut d, 1, 1, SplineOrder::Quintic);
        assert_eq!(d, vec![4.0]);
    }
}
