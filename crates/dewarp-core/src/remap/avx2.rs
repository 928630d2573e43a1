//! The Keys kernel on 8 output pixels at a time: coordinates in f64, weights and sums in
//! f32 with FMA, source pixels fetched with AVX2 gathers. Pixels whose 4 x 4 neighbourhood
//! is not entirely inside the image (or whose position is outside it, or NaN) go through
//! the scalar [`super::scalar::interp_row`], so the results follow the same conventions.
use super::coords::CoordGrid;
use super::scalar::interp_row as scalar_row;
use super::{OutKind, OutSample, Pixel, PixelKind};
use std::arch::x86_64::*;

#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn weights(t: __m256) -> [__m256; 4] {
    // Register-only intrinsics (the function has AVX2 + FMA enabled).
    let t2 = _mm256_mul_ps(t, t);
    let t3 = _mm256_mul_ps(t2, t);
    let c = _mm256_set1_ps;
    // -0.5 t3 + t2 - 0.5 t
    let w0 = _mm256_fmadd_ps(c(-0.5), t3, _mm256_fmadd_ps(c(-0.5), t, t2));
    // 1.5 t3 - 2.5 t2 + 1
    let w1 = _mm256_fmadd_ps(c(1.5), t3, _mm256_fmadd_ps(c(-2.5), t2, c(1.0)));
    // -1.5 t3 + 2 t2 + 0.5 t
    let w2 = _mm256_fmadd_ps(
        c(-1.5),
        t3,
        _mm256_fmadd_ps(c(2.0), t2, _mm256_mul_ps(c(0.5), t)),
    );
    // 0.5 t3 - 0.5 t2
    let w3 = _mm256_mul_ps(c(0.5), _mm256_sub_ps(t3, t2));
    [w0, w1, w2, w3]
}

/// Gather slot `s` of the u16 path reads pixel `U16_SLOTS[s]`: the transposes of 4 x 4
/// blocks within 128-bit lanes then return pixels 0..8 in order.
const U16_SLOTS: [i32; 8] = [0, 1, 4, 5, 2, 3, 6, 7];

/// Pixels `off + 0..4` of each lane as f32 (for u16, `off` permuted by `U16_SLOTS`).
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn gather4<T: Pixel>(data: *const T, off: __m256i) -> [__m256; 4] {
    // SAFETY (caller): every lane's `off .. off + 4` lies inside `data`.
    unsafe {
        match T::KIND {
            PixelKind::U16 => {
                // Two 4-lane 64-bit gathers at u16 granularity (scale 2), each lane the
                // 4 pixels off .. off + 3; `off` arrives permuted (see `U16_SLOTS`) so that
                // the 4 x 4 transposes below give the pixels in natural lane order.
                let p = data as *const i64;
                let g0 = _mm256_i32gather_epi64::<2>(p, _mm256_castsi256_si128(off));
                let g1 = _mm256_i32gather_epi64::<2>(p, _mm256_extracti128_si256::<1>(off));
                let z = _mm256_setzero_si256();
                let a = _mm256_unpacklo_epi16(g0, z); // slots 0 | 2, taps as i32
                let b = _mm256_unpackhi_epi16(g0, z); // slots 1 | 3
                let c = _mm256_unpacklo_epi16(g1, z); // slots 4 | 6
                let d = _mm256_unpackhi_epi16(g1, z); // slots 5 | 7
                let ab_lo = _mm256_unpacklo_epi32(a, b);
                let ab_hi = _mm256_unpackhi_epi32(a, b);
                let cd_lo = _mm256_unpacklo_epi32(c, d);
                let cd_hi = _mm256_unpackhi_epi32(c, d);
                [
                    _mm256_cvtepi32_ps(_mm256_unpacklo_epi64(ab_lo, cd_lo)),
                    _mm256_cvtepi32_ps(_mm256_unpackhi_epi64(ab_lo, cd_lo)),
                    _mm256_cvtepi32_ps(_mm256_unpacklo_epi64(ab_hi, cd_hi)),
                    _mm256_cvtepi32_ps(_mm256_unpackhi_epi64(ab_hi, cd_hi)),
                ]
            }
            PixelKind::F32 => {
                let p = data as *const f32;
                [
                    _mm256_i32gather_ps::<4>(p, off),
                    _mm256_i32gather_ps::<4>(p.add(1), off),
                    _mm256_i32gather_ps::<4>(p.add(2), off),
                    _mm256_i32gather_ps::<4>(p.add(3), off),
                ]
            }
            PixelKind::U8 | PixelKind::F64 => {
                // No gather of these layouts: the lanes are read one by one.
                let mut lanes = [0i32; 8];
                _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, off);
                let mut taps = [[0.0f32; 8]; 4];
                for (j, &o) in lanes.iter().enumerate() {
                    for (k, t) in taps.iter_mut().enumerate() {
                        t[j] = (*data.add(o as usize + k)).to_f32();
                    }
                }
                [
                    _mm256_loadu_ps(taps[0].as_ptr()),
                    _mm256_loadu_ps(taps[1].as_ptr()),
                    _mm256_loadu_ps(taps[2].as_ptr()),
                    _mm256_loadu_ps(taps[3].as_ptr()),
                ]
            }
        }
    }
}

/// Floor of 4 + 4 f64 lanes as 8 i32 lanes, and the fractional parts as 8 f32 lanes.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn split(a: __m256d, b: __m256d) -> (__m256i, __m256) {
    // Register-only intrinsics (the function has AVX2 + FMA enabled).
    let fa = _mm256_floor_pd(a);
    let fb = _mm256_floor_pd(b);
    let i = _mm256_set_m128i(_mm256_cvttpd_epi32(fb), _mm256_cvttpd_epi32(fa));
    let t = _mm256_set_m128(
        _mm256_cvtpd_ps(_mm256_sub_pd(b, fb)),
        _mm256_cvtpd_ps(_mm256_sub_pd(a, fa)),
    );
    (i, t)
}

/// All 4 lanes of `v` within `[lo, hi]` (false for NaN).
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn all_in(v: __m256d, lo: __m256d, hi: __m256d) -> bool {
    // Register-only intrinsics (the function has AVX2 + FMA enabled).
    let m = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_GE_OQ>(v, lo),
        _mm256_cmp_pd::<_CMP_LE_OQ>(v, hi),
    );
    _mm256_movemask_pd(m) == 0xF
}

/// [`CoordGrid`]'s span filler with the AVX2 linear fill inlined.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn grid_span(
    grid: &CoordGrid,
    y: usize,
    x0: usize,
    sx: &mut [f64],
    sy: &mut [f64],
) {
    // SAFETY: this function has AVX2 and FMA enabled (caller's contract).
    grid.span_with(y, x0, sx, sy, |out, a, d| unsafe { fill_linear(out, a, d) });
}

/// `out[m] = a + d * m`, 4 lanes at a time.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn fill_linear(out: &mut [f64], a: f64, d: f64) {
    let n = out.len();
    let (av, dv) = (_mm256_set1_pd(a), _mm256_set1_pd(d));
    let four = _mm256_set1_pd(4.0);
    let mut t = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0);
    let mut m = 0;
    while m + 4 <= n {
        // SAFETY: m + 4 <= n.
        unsafe { _mm256_storeu_pd(out.as_mut_ptr().add(m), _mm256_fmadd_pd(dv, t, av)) };
        t = _mm256_add_pd(t, four);
        m += 4;
    }
    for (k, o) in out[m..].iter_mut().enumerate() {
        *o = d.mul_add((m + k) as f64, a);
    }
}

/// 8 consecutive pixels `p .. p + 8` of a row as f32.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn load8<T: Pixel>(p: *const T) -> __m256 {
    // SAFETY (caller): `p .. p + 8` lies inside the image.
    unsafe {
        match T::KIND {
            PixelKind::U16 => {
                _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(_mm_loadu_si128(p as *const __m128i)))
            }
            PixelKind::F32 => _mm256_loadu_ps(p as *const f32),
            PixelKind::U8 | PixelKind::F64 => {
                let mut v = [0.0f32; 8];
                for (k, x) in v.iter_mut().enumerate() {
                    *x = (*p.add(k)).to_f32();
                }
                _mm256_loadu_ps(v.as_ptr())
            }
        }
    }
}

/// Store 8 interpolated values as `O` (rounded and clamped for `u16`, as `from_f32`).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn store8<O: OutSample>(v: __m256, out: &mut [O]) {
    debug_assert!(out.len() >= 8);
    // SAFETY (caller): `out` holds at least 8 values; `OUT_KIND` names `O`'s layout.
    unsafe {
        match O::OUT_KIND {
            OutKind::F32 => _mm256_storeu_ps(out.as_mut_ptr() as *mut f32, v),
            OutKind::U16 => {
                // (v + 0.5) truncated, saturated to [0, 65535], NaN -> 0: `min` returns its
                // second operand (NaN) for NaN, whose conversion is i32::MIN, which the
                // unsigned pack saturates to 0 like negatives.
                let r = _mm256_min_ps(
                    _mm256_set1_ps(65535.0),
                    _mm256_add_ps(v, _mm256_set1_ps(0.5)),
                );
                let p = _mm256_packus_epi32(_mm256_cvttps_epi32(r), _mm256_setzero_si256());
                let q = _mm256_permute4x64_epi64::<0b1000>(p);
                _mm_storeu_si128(out.as_mut_ptr() as *mut __m128i, _mm256_castsi256_si128(q));
            }
            OutKind::Other => {
                let mut tmp = [0.0f32; 8];
                _mm256_storeu_ps(tmp.as_mut_ptr(), v);
                for (o, t) in out.iter_mut().zip(tmp) {
                    *o = O::from_f32(t);
                }
            }
        }
    }
}

/// Loop-invariant constants of the kernel for one image.
#[derive(Clone, Copy)]
struct Consts {
    xlo: __m256d,
    xhi: __m256d,
    ylo: __m256d,
    yhi: __m256d,
    wv: __m256i,
    lanes: __m256i,
    ok: bool,
}

#[inline]
#[target_feature(enable = "avx2,fma")]
fn consts(h: usize, w: usize) -> Consts {
    // The whole 4 x 4 neighbourhood inside the image: floor(x) in [1, w - 3], i.e.
    // x in [1, w - 2) -- tested on x itself, so NaN and far-away points fail too.
    Consts {
        xlo: _mm256_set1_pd(1.0),
        xhi: _mm256_set1_pd(w as f64 - 2.0 - 1e-9),
        ylo: _mm256_set1_pd(1.0),
        yhi: _mm256_set1_pd(h as f64 - 2.0 - 1e-9),
        wv: _mm256_set1_epi32(w as i32),
        lanes: _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        ok: w >= 4 && h >= 4,
    }
}

/// Interpolate the 8 pixels at source positions `(xa | xb, ya | yb)` into `out[..8]`;
/// returns whether the block took the contiguous-load path.
///
/// Per block of 8 output pixels whose 4 x 4 neighbourhoods all lie inside the image:
///
/// - if the 8 source positions fall in one source row band (same `floor(sy)`) at consecutive
///   columns (`floor(sx_k) = floor(sx_0) + k`) -- the normal case of a near-identity lens
///   map -- the 16 taps of the 8 pixels are 16 contiguous 8-pixel loads (row `r`, column
///   shift `c`), weighted per lane;
/// - otherwise (strong distortion, a row or column boundary crossed inside the block) the
///   taps are gathered per lane.
///
/// Both give the same Keys sum per pixel (horizontal, then vertical), with per-lane weights.
/// Blocks with a pixel near or beyond the border (or NaN) go through the scalar kernel.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `data` is the `h x w` row-major image with
/// `data.len() < i32::MAX / 2`, `k` = `consts(h, w)`; `out` holds at least 8 values.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn block8<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    k: &Consts,
    (xa, xb, ya, yb): (__m256d, __m256d, __m256d, __m256d),
    fill: O,
    out: &mut [O],
) -> bool {
    // SAFETY: caller's contract; the neighbourhood test guards every load and gather.
    unsafe {
        let inside = k.ok
            && all_in(xa, k.xlo, k.xhi)
            && all_in(xb, k.xlo, k.xhi)
            && all_in(ya, k.ylo, k.yhi)
            && all_in(yb, k.ylo, k.yhi);
        if !inside {
            let (mut sx, mut sy) = ([0.0f64; 8], [0.0f64; 8]);
            _mm256_storeu_pd(sx.as_mut_ptr(), xa);
            _mm256_storeu_pd(sx.as_mut_ptr().add(4), xb);
            _mm256_storeu_pd(sy.as_mut_ptr(), ya);
            _mm256_storeu_pd(sy.as_mut_ptr().add(4), yb);
            scalar_row(data, h, w, &sx, &sy, fill, &mut out[..8]);
            return false;
        }
        let (ix, tx) = split(xa, xb);
        let (iy, ty) = split(ya, yb);
        taps(data, w, k, (ix, tx, iy, ty), out)
    }
}

/// The Keys sum of 8 pixels with integer positions `ix`, `iy` and fractions `tx`, `ty`
/// (in `[0, 1]`), stored into `out[..8]`; returns whether the contiguous path was taken.
///
/// # Safety
/// As [`block8`], and every lane's 4 x 4 neighbourhood lies inside the image
/// (`ix` in `[1, w - 3]`, `iy` in `[1, h - 3]`).
#[inline(always)]
unsafe fn taps<T: Pixel, O: OutSample>(
    data: &[T],
    w: usize,
    k: &Consts,
    (ix, tx, iy, ty): (__m256i, __m256, __m256i, __m256),
    out: &mut [O],
) -> bool {
    // SAFETY: caller's contract (neighbourhoods inside the image).
    unsafe {
        let wx = weights(tx);
        let wy = weights(ty);
        let ix0 = _mm256_cvtsi256_si32(ix);
        let iy0 = _mm256_cvtsi256_si32(iy);
        let same = _mm256_and_si256(
            _mm256_cmpeq_epi32(ix, _mm256_add_epi32(_mm256_set1_epi32(ix0), k.lanes)),
            _mm256_cmpeq_epi32(iy, _mm256_set1_epi32(iy0)),
        );
        let contiguous = _mm256_movemask_epi8(same) == -1;
        let v = if contiguous {
            // Rows iy0 - 1 .. iy0 + 2, columns ix0 - 1 .. ix0 + 10: inside the image
            // since every lane passed the neighbourhood test (ix0 + 7 = ix_7 <= w - 3).
            let mut p = data.as_ptr().add((iy0 as usize - 1) * w + ix0 as usize - 1);
            let mut acc = _mm256_setzero_ps();
            for wr in wy {
                let hsum = _mm256_fmadd_ps(
                    wx[3],
                    load8(p.add(3)),
                    _mm256_fmadd_ps(
                        wx[2],
                        load8(p.add(2)),
                        _mm256_fmadd_ps(wx[1], load8(p.add(1)), _mm256_mul_ps(wx[0], load8(p))),
                    ),
                );
                acc = _mm256_fmadd_ps(wr, hsum, acc);
                p = p.add(w);
            }
            acc
        } else {
            // Offset of the top-left neighbour: (iy - 1) * w + ix - 1.
            let one = _mm256_set1_epi32(1);
            let mut off = _mm256_add_epi32(
                _mm256_mullo_epi32(_mm256_sub_epi32(iy, one), k.wv),
                _mm256_sub_epi32(ix, one),
            );
            if T::KIND == PixelKind::U16 {
                let idx = _mm256_loadu_si256(U16_SLOTS.as_ptr() as *const __m256i);
                off = _mm256_permutevar8x32_epi32(off, idx);
            }
            let mut acc = _mm256_setzero_ps();
            for wr in wy {
                let p = gather4(data.as_ptr(), off);
                let hsum = _mm256_fmadd_ps(
                    wx[3],
                    p[3],
                    _mm256_fmadd_ps(
                        wx[2],
                        p[2],
                        _mm256_fmadd_ps(wx[1], p[1], _mm256_mul_ps(wx[0], p[0])),
                    ),
                );
                acc = _mm256_fmadd_ps(wr, hsum, acc);
                off = _mm256_add_epi32(off, k.wv);
            }
            acc
        };
        store8(v, out);
        contiguous
    }
}

/// Interpolate one row from per-pixel source coordinates; returns the number of 8-pixel
/// blocks that took the contiguous-load path (for tests). See [`block8`].
///
/// # Safety
/// The CPU must support AVX2 and FMA; `data` is the `h x w` row-major image with
/// `data.len() < i32::MAX / 2`; `sx`, `sy` and `out` have one length.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn interp_row<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    sx: &[f64],
    sy: &[f64],
    fill: O,
    out: &mut [O],
) -> usize {
    let n = out.len().min(sx.len()).min(sy.len());
    let full = n - n % 8;
    let k = consts(h, w);
    let mut contiguous = 0;
    let mut i = 0;
    while i < full {
        // SAFETY: i + 8 <= n; caller's contract for the rest.
        unsafe {
            let v = (
                _mm256_loadu_pd(sx.as_ptr().add(i)),
                _mm256_loadu_pd(sx.as_ptr().add(i + 4)),
                _mm256_loadu_pd(sy.as_ptr().add(i)),
                _mm256_loadu_pd(sy.as_ptr().add(i + 4)),
            );
            contiguous += block8(data, h, w, &k, v, fill, &mut out[i..i + 8]) as usize;
        }
        i += 8;
    }
    if full < n {
        scalar_row(
            data,
            h,
            w,
            &sx[full..n],
            &sy[full..n],
            fill,
            &mut out[full..n],
        );
    }
    contiguous
}

/// Interpolate `out.len()` consecutive pixels whose source positions are linear in the
/// pixel index `m`: `(ax + dx * m, ay + dy * m)` (one cell of a coarse map grid, computed
/// exactly as [`CoordGrid`]'s span filler does); returns the contiguous block count.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `data` is the `h x w` row-major image with
/// `data.len() < i32::MAX / 2`.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn interp_linear<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    k: &Consts,
    (ax, dx, ay, dy): (f64, f64, f64, f64),
    fill: O,
    out: &mut [O],
) -> usize {
    let n = out.len();
    let full = n - n % 8;
    // Whole cell (its full 8-pixel blocks) well inside the image: positions linear in m,
    // so the two end points bound them all (0.01 px margin covers the f32 offsets below).
    let (xe, ye) = (
        dx.mul_add(full.saturating_sub(1) as f64, ax),
        dy.mul_add(full.saturating_sub(1) as f64, ay),
    );
    let within = |a: f64, b: f64, len: usize| {
        let (lo, hi) = (1.01, len as f64 - 2.01);
        a >= lo && a <= hi && b >= lo && b <= hi
    };
    // Offsets up to 1024 px keep the f32 rounding below ~1.2e-4 px (a lens map's cells
    // move by a few tens of px); anything more extreme takes the f64 path.
    let short = (dx * full as f64).abs() <= 1024.0 && (dy * full as f64).abs() <= 1024.0;
    if k.ok && full > 0 && short && within(ax, xe, w) && within(ay, ye, h) {
        // Positions as f32 offsets from an integer base, (ax - bx) + dx * m, |offset| <=
        // 1025 px: f32 error <= ~1.2e-4 px, ~4e-6 px for a near-identity map on 32 px cells
        // (the map itself is good to the grid tolerance, 1e-3 px); no quantisation.
        let (bx, by) = (ax.floor(), ay.floor());
        let (bxv, byv) = (_mm256_set1_epi32(bx as i32), _mm256_set1_epi32(by as i32));
        let (fax, fay) = (
            _mm256_set1_ps((ax - bx) as f32),
            _mm256_set1_ps((ay - by) as f32),
        );
        let (dxf, dyf) = (_mm256_set1_ps(dx as f32), _mm256_set1_ps(dy as f32));
        let eight = _mm256_set1_ps(8.0);
        let mut t = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let mut contiguous = 0;
        let mut i = 0;
        while i < full {
            let fx = _mm256_fmadd_ps(dxf, t, fax);
            let fy = _mm256_fmadd_ps(dyf, t, fay);
            let (flx, fly) = (_mm256_floor_ps(fx), _mm256_floor_ps(fy));
            let ix = _mm256_add_epi32(bxv, _mm256_cvttps_epi32(flx));
            let iy = _mm256_add_epi32(byv, _mm256_cvttps_epi32(fly));
            let (tx, ty) = (_mm256_sub_ps(fx, flx), _mm256_sub_ps(fy, fly));
            // SAFETY: every position lies in [1, len - 2) (end points checked above with a
            // margin larger than the f32 offset error): neighbourhoods inside the image.
            contiguous +=
                unsafe { taps(data, w, k, (ix, tx, iy, ty), &mut out[i..i + 8]) } as usize;
            t = _mm256_add_ps(t, eight);
            i += 8;
        }
        linear_tail(data, h, w, (ax, dx, ay, dy), fill, full, out);
        return contiguous;
    }
    let (axv, dxv) = (_mm256_set1_pd(ax), _mm256_set1_pd(dx));
    let (ayv, dyv) = (_mm256_set1_pd(ay), _mm256_set1_pd(dy));
    let (four, eight) = (_mm256_set1_pd(4.0), _mm256_set1_pd(8.0));
    let mut t = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0);
    let mut contiguous = 0;
    let mut i = 0;
    while i + 8 <= n {
        let t4 = _mm256_add_pd(t, four);
        let v = (
            _mm256_fmadd_pd(dxv, t, axv),
            _mm256_fmadd_pd(dxv, t4, axv),
            _mm256_fmadd_pd(dyv, t, ayv),
            _mm256_fmadd_pd(dyv, t4, ayv),
        );
        // SAFETY: i + 8 <= n; caller's contract for the rest.
        contiguous += unsafe { block8(data, h, w, k, v, fill, &mut out[i..i + 8]) } as usize;
        t = _mm256_add_pd(t, eight);
        i += 8;
    }
    linear_tail(data, h, w, (ax, dx, ay, dy), fill, i, out);
    contiguous
}

/// Pixels `from..` (fewer than 8) of a span whose source positions are linear in the pixel
/// index `m` (`x = ax + m dx`, `y = ay + m dy`), through the scalar kernel.
fn linear_tail<T: Pixel, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    (ax, dx, ay, dy): (f64, f64, f64, f64),
    fill: O,
    from: usize,
    out: &mut [O],
) {
    let n = out.len();
    if from >= n {
        return;
    }
    let (mut sx, mut sy) = ([0.0f64; 8], [0.0f64; 8]);
    for m in from..n {
        sx[m - from] = dx.mul_add(m as f64, ax);
        sy[m - from] = dy.mul_add(m as f64, ay);
    }
    let r = n - from;
    scalar_row(data, h, w, &sx[..r], &sy[..r], fill, &mut out[from..n]);
}

/// [`CoordGrid`]'s coordinates fed straight into the kernel, one grid cell at a time (no
/// coordinate scratch); same positions as `grid_span` + [`interp_row`].
///
/// # Safety
/// The CPU must support AVX2 and FMA; `data` is the `h x w` row-major image with
/// `data.len() < i32::MAX / 2`; `out` is the span `x0 .. x0 + out.len()` of row `y`.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn interp_grid_span<T: Pixel, O: OutSample>(
    grid: &CoordGrid,
    y: usize,
    x0: usize,
    data: &[T],
    h: usize,
    w: usize,
    fill: O,
    out: &mut [O],
) -> usize {
    let k = consts(h, w);
    let mut contiguous = 0;
    grid.cells(y, x0, out.len(), |a, b, ax, dx, ay, dy| {
        // SAFETY: this function has AVX2 and FMA enabled; caller's contract.
        contiguous +=
            unsafe { interp_linear(data, h, w, &k, (ax, dx, ay, dy), fill, &mut out[a..b]) };
    });
    contiguous
}
