//! The scalar Keys kernel over one row of source coordinates, and the dispatch to the AVX2
//! kernel where the CPU has it.

use super::*;
use ndarray::ArrayView2;

/// The image as a contiguous row-major slice (borrowed when possible).
pub(crate) fn contiguous<'a, T: Pixel>(image: &'a ArrayView2<'a, T>) -> std::borrow::Cow<'a, [T]> {
    match image.as_slice() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => std::borrow::Cow::Owned(image.iter().copied().collect()),
    }
}

/// Interpolate one output row from its source coordinates.
#[inline]
pub(crate) fn interp_row<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    sx: &[f64],
    sy: &[f64],
    fill: O,
    out: &mut [O],
) {
    let (xlo, xhi) = (-0.5, w as f64 - 0.5);
    let (ylo, yhi) = (-0.5, h as f64 - 0.5);
    let fast_x = w.saturating_sub(3) as isize; // ix in [1, w - 3]
    let fast_y = h.saturating_sub(3) as isize;
    for ((o, &x), &y) in out.iter_mut().zip(sx.iter()).zip(sy.iter()) {
        // Also rejects NaN.
        if !(x >= xlo && x <= xhi && y >= ylo && y <= yhi) {
            *o = fill;
            continue;
        }
        // x, y >= -0.5 here, so truncation after a +2 shift is floor (no libm call).
        let ix = (x + 2.0) as isize - 2;
        let iy = (y + 2.0) as isize - 2;
        let wx = keys_weights((x - ix as f64) as f32);
        let wy = keys_weights((y - iy as f64) as f32);
        let v = if ix >= 1 && ix <= fast_x && iy >= 1 && iy <= fast_y {
            // Vertical pass first on 4-wide rows (vectorises), then one horizontal dot.
            let base = (iy as usize - 1) * w + ix as usize - 1;
            let mut acc = [0.0f32; 4];
            for (r, &wr) in wy.iter().enumerate() {
                let s: &[T; 4] = data[base + r * w..base + r * w + 4]
                    .try_into()
                    .expect("four-pixel slice");
                for i in 0..4 {
                    acc[i] += wr * s[i].to_f32();
                }
            }
            acc[0] * wx[0] + acc[1] * wx[1] + acc[2] * wx[2] + acc[3] * wx[3]
        } else {
            // Border: replicate the edge pixels.
            let cx = |k: isize| (ix + k).clamp(0, w as isize - 1) as usize;
            let cy = |k: isize| (iy + k).clamp(0, h as isize - 1) as usize;
            let xs = [cx(-1), cx(0), cx(1), cx(2)];
            let mut acc = [0.0f32; 4];
            for (r, &wr) in wy.iter().enumerate() {
                let row = &data[cy(r as isize - 1) * w..][..w];
                for i in 0..4 {
                    acc[i] += wr * row[xs[i]].to_f32();
                }
            }
            acc[0] * wx[0] + acc[1] * wx[1] + acc[2] * wx[2] + acc[3] * wx[3]
        };
        *o = O::from_f32(v);
    }
}

/// [`interp_row`] through the AVX2 + FMA kernel when the CPU has it (8 pixels at a time).
/// Returns the number of 8-pixel blocks that took the contiguous-load path (0 without AVX2).
#[inline]
pub(crate) fn interp_row_best<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    sx: &[f64],
    sy: &[f64],
    fill: O,
    out: &mut [O],
) -> usize {
    #[cfg(target_arch = "x86_64")]
    {
        // The SIMD kernel indexes with i32 lanes.
        if data.len() < (i32::MAX as usize) / 2
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked above); the kernel reads `data`
            // only at indices it has bounds-checked (see `avx2::interp_row`).
            return unsafe { avx2::interp_row(data, h, w, sx, sy, fill, out) };
        }
    }
    interp_row(data, h, w, sx, sy, fill, out);
    0
}
