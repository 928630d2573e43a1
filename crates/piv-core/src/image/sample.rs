//! The window samplers: integer copy, constant sub-pixel shift and per-pixel deformation of a
//! window pair, and the deformation of a whole frame pair.

use super::field::*;
use super::{Img, Pixel, LANES};
use image_core::kernels::{floor_i, mirror};

/// How a window pair is sampled: top-left pixel position of the window (may be fractional), the
/// constant displacement `(du, dv)` and an optional displacement field added per pixel.
/// Frame A is sampled at `p - d(p)/2`, frame B at `p + d(p)/2` (symmetric, second order).
pub struct WindowSpec<'f> {
    pub left: f64,
    pub top: f64,
    pub du: f64,
    pub dv: f64,
    pub field: Option<&'f GridField>,
}

/// The images a window pair is read from: the frames themselves (integer positions) and the
/// images interpolated with kernel `wf` at fractional positions (the frames for Keys, their
/// B-spline coefficients for B-splines).
pub struct Source<'s, 'a, 'c, T: Pixel, U: Pixel, W> {
    pub a: &'s Img<'a, T>,
    pub b: &'s Img<'a, T>,
    pub ia: &'s Img<'c, U>,
    pub ib: &'s Img<'c, U>,
    /// The kernel, `Fn(f32) -> [f32; N]` (see [`crate::image::Weights`]).
    pub wf: W,
}

/// Tolerance (px) of the inside test of [`inside`].
pub(crate) const INSIDE_EPS: f64 = 1e-6;

/// Is the position (x, y) inside the image, `[-0.5, width - 0.5] x [-0.5, height - 0.5]` (the
/// area of its pixels, README's convention)?
#[inline(always)]
pub fn inside(x: f64, y: f64, width: usize, height: usize) -> bool {
    // `&`, not `&&`: four comparisons without branches (vectorises in the deformation's loops)
    (x >= -0.5 - INSIDE_EPS)
        & (y >= -0.5 - INSIDE_EPS)
        & (x <= width as f64 - 0.5 + INSIDE_EPS)
        & (y <= height as f64 - 0.5 + INSIDE_EPS)
}

/// Sample the window pair into `wa`, `wb` (row-major, `h` rows of `w`). A pixel whose sample
/// position (after offset and deformation) lies outside the image (see [`inside`]) is set to
/// NaN in its window, so that the caller can leave it out of the correlation (see
/// [`crate::multipass`]). Returns `true` when every sample of both windows is inside.
pub fn sample_pair<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    spec: &WindowSpec<'_>,
    wa: &mut [f32],
    wb: &mut [f32],
) -> bool {
    let (iw, ih) = (src.a.width, src.a.height);
    let (rw, rh) = ((w - 1) as f64, (h - 1) as f64);
    match spec.field {
        None => {
            let (ax, ay) = (spec.left - spec.du / 2.0, spec.top - spec.dv / 2.0);
            let (bx, by) = (spec.left + spec.du / 2.0, spec.top + spec.dv / 2.0);
            let in_a = inside(ax, ay, iw, ih) && inside(ax + rw, ay + rh, iw, ih);
            let in_b = inside(bx, by, iw, ih) && inside(bx + rw, by + rh, iw, ih);
            sample_shift(src.a, src.ia, src.wf, w, h, ax, ay, wa);
            sample_shift(src.b, src.ib, src.wf, w, h, bx, by, wb);
            for (ok, x0, y0, win) in [(in_a, ax, ay, &mut *wa), (in_b, bx, by, &mut *wb)] {
                if !ok {
                    for r in 0..h {
                        for c in 0..w {
                            if !inside(x0 + c as f64, y0 + r as f64, iw, ih) {
                                win[r * w + c] = f32::NAN;
                            }
                        }
                    }
                }
            }
            in_a && in_b
        }
        Some(f) => match sample_field_sep(src, w, h, spec, f, wa, wb) {
            Some(ok) => ok,
            // a window or source span beyond the stack lines (a wildly varying field)
            None => sample_field_2d(src, w, h, spec, f, wa, wb),
        },
    }
}

/// The per-pixel 2D sampler of a window pair deformed by a field (see [`sample_pair`]):
/// `N x N` taps and one field evaluation per pixel. The reference of
/// [`sample_field_sep`] and its fallback.
pub(crate) fn sample_field_2d<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    spec: &WindowSpec<'_>,
    f: &GridField,
    wa: &mut [f32],
    wb: &mut [f32],
) -> bool {
    let (iw, ih) = (src.a.width, src.a.height);
    let mut ok = true;
    for r in 0..h {
        let y = spec.top + r as f64;
        let row_y = f.row(y);
        let (ra, rb) = (&mut wa[r * w..(r + 1) * w], &mut wb[r * w..(r + 1) * w]);
        for (c, (oa, ob)) in ra.iter_mut().zip(rb.iter_mut()).enumerate() {
            let x = spec.left + c as f64;
            let (fu, fv) = f.at_row(&row_y, x);
            let hu = 0.5 * (fu + spec.du);
            let hv = 0.5 * (fv + spec.dv);
            let (xa, ya, xb, yb) = (x - hu, y - hv, x + hu, y + hv);
            *oa = if inside(xa, ya, iw, ih) {
                src.ia.interp(xa, ya, src.wf)
            } else {
                ok = false;
                f32::NAN
            };
            *ob = if inside(xb, yb, iw, ih) {
                src.ib.interp(xb, yb, src.wf)
            } else {
                ok = false;
                f32::NAN
            };
        }
    }
    ok
}

/// Longest window row and source line (px) of [`sample_field_sep`] (stack buffers).
pub(crate) const FIELD_LINE: usize = 512;

/// A window pair deformed by a field, sampled separably as [`super::deform_pair`] does for a whole
/// frame: output pixel `p` of frame A takes the interpolant at `p - d(p) / 2`, of frame B at
/// `p + d(p) / 2` (`d` = field + `(du, dv)`).
///
/// Per window row the field is evaluated once per output pixel (shared by both frames).
/// Then, per frame, every source column `i` the row's taps reach is interpolated along y
/// (`N` taps) at the vertical displacement of the output pixel whose source column is `i`
/// (`x = i -+ d_x(i) / 2`, the field linear between the row's pixels and extrapolated
/// linearly beyond them), and the row of these values is interpolated along x (`N` taps) at
/// each pixel's source position: `2 N` taps per pixel (plus `N` per extra column) instead of
/// `N^2`. It equals the 2D interpolation up to the change of the vertical displacement across
/// the taps times the tap distance (second order, as [`super::deform_pair`], the deformation of
/// Method I's regular grid; exact when `d_y` does not vary along x).
///
/// Pixels whose source lies outside the image are NaN. Returns `Some(all inside)`, or `None`
/// (nothing meaningful written) when a window row or a source span exceeds [`FIELD_LINE`]
/// px or is not finite.
pub(crate) fn sample_field_sep<
    T: Pixel,
    U: Pixel,
    W: Fn(f32) -> [f32; N] + Copy,
    const N: usize,
>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    spec: &WindowSpec<'_>,
    f: &GridField,
    wa: &mut [f32],
    wb: &mut [f32],
) -> Option<bool> {
    if !(2..=FIELD_LINE).contains(&w) {
        return None;
    }
    let (iw, ih) = (src.a.width, src.a.height);
    let o = (N / 2 - 1) as isize;
    let mut hu = [0.0f64; FIELD_LINE];
    let mut hv = [0.0f64; FIELD_LINE];
    let mut line = [0.0f32; FIELD_LINE];
    let mut ok = true;
    let left = spec.left;
    for r in 0..h {
        let y = spec.top + r as f64;
        let row_y = f.row(y);
        for c in 0..w {
            let (fu, fv) = f.at_row(&row_y, left + c as f64);
            hu[c] = 0.5 * (fu + spec.du);
            hv[c] = 0.5 * (fv + spec.dv);
        }
        // half the field at the fractional output column t (linear between the row's pixels)
        let lin = |a: &[f64; FIELD_LINE], t: f64| {
            let k = (floor_i(t).clamp(0, w as isize - 2)) as usize;
            a[k] + (t - k as f64) * (a[k + 1] - a[k])
        };
        for (img, sign, out) in [(src.ia, -1.0, &mut *wa), (src.ib, 1.0, &mut *wb)] {
            let orow = &mut out[r * w..(r + 1) * w];
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for (c, &u) in hu[..w].iter().enumerate() {
                let xs = left + c as f64 + sign * u;
                lo = lo.min(xs);
                hi = hi.max(xs);
            }
            if !(lo.is_finite() && hi.is_finite()) || hi - lo > FIELD_LINE as f64 {
                return None;
            }
            let i0 = floor_i(lo) - o;
            let len = (floor_i(hi) + N as isize - o - i0) as usize;
            if len > FIELD_LINE {
                return None;
            }
            // 1. the source columns along y
            for (k, t) in line[..len].iter_mut().enumerate() {
                let i = (i0 + k as isize) as f64;
                let xo = i - sign * lin(&hu, i - left);
                let ys = y + sign * lin(&hv, xo - left);
                *t = img.column_interp(mirror(i0 + k as isize, iw), ys, src.wf);
            }
            // 2. the row along x
            for (c, v) in orow.iter_mut().enumerate() {
                let (xs, ys) = (left + c as f64 + sign * hu[c], y + sign * hv[c]);
                if !inside(xs, ys, iw, ih) {
                    ok = false;
                    *v = f32::NAN;
                    continue;
                }
                let ix = floor_i(xs);
                let wx = (src.wf)((xs - ix as f64) as f32);
                let s0 = (ix - o - i0) as usize;
                *v = wx.iter().zip(&line[s0..s0 + N]).map(|(a, b)| a * b).sum();
            }
        }
    }
    Some(ok)
}

/// Sample a `w` x `h` window whose top-left pixel sits at (x0, y0) (constant shift): straight
/// from `img` at integer positions, else from `interp` with kernel `wf`.
pub(crate) fn sample_shift<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N], const N: usize>(
    img: &Img<'_, T>,
    interp: &Img<'_, U>,
    wf: W,
    w: usize,
    h: usize,
    x0: f64,
    y0: f64,
    out: &mut [f32],
) {
    let fx = x0.floor();
    let fy = y0.floor();
    let tx = x0 - fx;
    let ty = y0 - fy;
    const EPS: f64 = 1e-9;
    let int_x = !(EPS..=1.0 - EPS).contains(&tx);
    let int_y = !(EPS..=1.0 - EPS).contains(&ty);
    if int_x && int_y {
        let ix = x0.round() as isize;
        let iy = y0.round() as isize;
        let inside = ix >= 0
            && iy >= 0
            && ix + w as isize <= img.width as isize
            && iy + h as isize <= img.height as isize;
        if inside {
            let s = img.slice();
            for r in 0..h {
                let base = (iy as usize + r) * img.width + ix as usize;
                for (o, p) in out[r * w..(r + 1) * w].iter_mut().zip(&s[base..base + w]) {
                    *o = p.to_f32();
                }
            }
        } else {
            for r in 0..h {
                for c in 0..w {
                    out[r * w + c] = img.get(ix + c as isize, iy + r as isize);
                }
            }
        }
        return;
    }
    let wx = wf(tx as f32);
    let wy = wf(ty as f32);
    let o = (N / 2 - 1) as isize;
    let (ix, iy) = (fx as isize - o, fy as isize - o);
    if !shift_separable(interp, &wx, &wy, w, h, ix, iy, out) {
        shift_per_pixel(interp, &wx, &wy, w, h, ix, iy, out);
    }
}

/// Longest window row (px) of [`shift_separable`] (its ring of `N` rows is on the stack).
pub(crate) const SHIFT_LINE: usize = 128;

/// The window of a constant sub-pixel shift, pixel by pixel: the `N x N` taps whose top-left
/// is `(ix + c, iy + r)` (mirrored beyond the image). The reference of [`shift_separable`] and
/// its fallback.
#[allow(clippy::too_many_arguments)]
pub(crate) fn shift_per_pixel<U: Pixel, const N: usize>(
    interp: &Img<'_, U>,
    wx: &[f32; N],
    wy: &[f32; N],
    w: usize,
    h: usize,
    ix: isize,
    iy: isize,
    out: &mut [f32],
) {
    for r in 0..h {
        for c in 0..w {
            out[r * w + c] = interp.taps(ix + c as isize, iy + r as isize, wx, wy);
        }
    }
}

/// The window of a constant sub-pixel shift, separably: the weights are the same for every
/// pixel, so each source row's horizontal sums are computed once (kept in a ring of the last
/// `N` rows) and each output row is the vertical sum of `N` of them: `(2h + N - 1) N` taps
/// per column instead of `h N^2`, in loops over the columns that vectorise. Bit for bit
/// [`shift_per_pixel`] (the same products summed in the same order). Returns false, writing
/// nothing, when a tap lies outside the image, the window is wider than [`SHIFT_LINE`] or the
/// kernel has more than 6 taps (the caller falls back to [`shift_per_pixel`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn shift_separable<U: Pixel, const N: usize>(
    interp: &Img<'_, U>,
    wx: &[f32; N],
    wy: &[f32; N],
    w: usize,
    h: usize,
    ix: isize,
    iy: isize,
    out: &mut [f32],
) -> bool {
    let inside = ix >= 0
        && iy >= 0
        && ix as usize + w + N - 1 <= interp.width
        && iy as usize + h + N - 1 <= interp.height;
    if !inside || w > SHIFT_LINE || N > 6 {
        return false;
    }
    let (s, stride) = (interp.slice(), interp.width);
    let (ix, iy) = (ix as usize, iy as usize);
    // the thread's ring (every slot is filled before it is read: no zeroing per window)
    thread_local! {
        static RING: std::cell::RefCell<Vec<f32>> = std::cell::RefCell::new(vec![0.0; 6 * SHIFT_LINE]);
    }
    RING.with_borrow_mut(|ring| {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                unsafe { ring_sums_avx2(s, stride, (ix, iy), wx, wy, (w, h), ring, out) };
                return;
            }
        }
        ring_sums(s, stride, (ix, iy), wx, wy, (w, h), ring, out)
    });
    true
}

/// [`ring_sums`] compiled for AVX2 (8 lanes instead of 4; no FMA, so the sums are the
/// same products added in the same order, bit for bit the portable build's).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn ring_sums_avx2<U: Pixel, const N: usize>(
    s: &[U],
    stride: usize,
    at: (usize, usize),
    wx: &[f32; N],
    wy: &[f32; N],
    size: (usize, usize),
    ring: &mut [f32],
    out: &mut [f32],
) {
    ring_sums(s, stride, at, wx, wy, size, ring, out)
}

/// The body of [`shift_separable`] (checked there) with the ring `ring` (`6 SHIFT_LINE` values).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn ring_sums<U: Pixel, const N: usize>(
    s: &[U],
    stride: usize,
    (ix, iy): (usize, usize),
    wx: &[f32; N],
    wy: &[f32; N],
    (w, h): (usize, usize),
    ring: &mut [f32],
    out: &mut [f32],
) {
    // the horizontal sums of source row `iy + k` into ring slot `k % N` (a function, not a
    // closure, so that it is compiled with the caller's target features); each sum starts
    // from 0.0 + the first product, as the per-pixel path's does, without a call to zero it;
    // 8 columns at a time summed over all taps in registers, stored once
    #[inline(always)]
    fn horizontal<U: Pixel, const N: usize>(src: &[U], wx: &[f32; N], dst: &mut [f32]) {
        let w = dst.len();
        let src = &src[..w + N - 1];
        let mut chunks = dst.chunks_exact_mut(LANES);
        for (c, d) in (&mut chunks).enumerate() {
            let p = &src[c * LANES..][..LANES + N - 1];
            let mut acc = [0.0f32; LANES];
            for l in 0..LANES {
                acc[l] = 0.0 + wx[0] * p[l].to_f32();
            }
            for j in 1..N {
                for l in 0..LANES {
                    acc[l] += wx[j] * p[j + l].to_f32();
                }
            }
            d.copy_from_slice(&acc);
        }
        let x0 = w - w % LANES;
        for (x, d) in (x0..).zip(chunks.into_remainder()) {
            let mut a = 0.0 + wx[0] * src[x].to_f32();
            for j in 1..N {
                a += wx[j] * src[x + j].to_f32();
            }
            *d = a;
        }
    }
    let row_at = |k: usize| &s[(iy + k) * stride + ix..][..w + N - 1];
    for k in 0..N - 1 {
        horizontal(row_at(k), wx, &mut ring[(k % N) * w..][..w]);
    }
    for (r, row) in out[..h * w].chunks_exact_mut(w).enumerate() {
        let k = r + N - 1;
        horizontal(row_at(k), wx, &mut ring[(k % N) * w..][..w]);
        // the output row: the vertical sums of the ring's rows r ..= r + N - 1, 8 columns at
        // a time in registers, in the same order (0.0 + the first product, then the others)
        let slot = |j: usize| &ring[((r + j) % N) * w..][..w];
        let mut chunks = row.chunks_exact_mut(LANES);
        for (c, o) in (&mut chunks).enumerate() {
            let x = c * LANES;
            let t = &slot(0)[x..x + LANES];
            let mut acc = [0.0f32; LANES];
            for l in 0..LANES {
                acc[l] = 0.0 + wy[0] * t[l];
            }
            for (j, &b) in wy.iter().enumerate().skip(1) {
                let t = &slot(j)[x..x + LANES];
                for l in 0..LANES {
                    acc[l] += b * t[l];
                }
            }
            o.copy_from_slice(&acc);
        }
        let x0 = w - w % LANES;
        for (x, o) in (x0..).zip(chunks.into_remainder()) {
            let mut a = 0.0 + wy[0] * slot(0)[x];
            for (j, &b) in wy.iter().enumerate().skip(1) {
                a += b * slot(j)[x];
            }
            *o = a;
        }
    }
}
