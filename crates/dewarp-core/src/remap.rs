//! Image remap with Keys bicubic interpolation (Method I: dewarp the images, then PIV).
//!
//! For every output ("object") pixel `(x, y)` a coordinate map gives the source ("image")
//! position `(sx, sy) = map(x, y)` in the pixel frame of the input image (x = column, y = row,
//! origin at the centre of the top-left pixel). The output value is the input image interpolated
//! at `(sx, sy)` with the Keys (1981) cubic-convolution kernel, `a = -0.5`, over the 4 x 4
//! neighbouring pixels.
//!
//! Conventions fixed here:
//!
//! - **Zero outside the image.** The sensor covers `[-0.5, w - 0.5] x [-0.5, h - 0.5]` (the
//!   footprint of its pixels). A source position outside that rectangle, or a non-finite one,
//!   gives the fill value (0 by default). Inside it, the kernel's neighbours beyond the border
//!   are replicated from the edge pixel, so the border pixels are not darkened by zeros.
//! - **Full precision.** Source coordinates are kept in `f64`; the fractional position enters the
//!   kernel weights without quantisation (OpenCV quantises it to 1/32 px). Weights and the
//!   accumulation are `f32` (relative rounding ~1e-7, far below any 12-16 bit intensity step).
//! - **Exactness.** At integer positions the weights are exactly (0, 1, 0, 0): the identity map
//!   returns the image exactly.
//! - **Map sampling.** The map is evaluated per pixel ([`MapSampling::Exact`]), on a coarse grid
//!   every `k` px with bilinear interpolation between nodes ([`MapSampling::Grid`]), or on the
//!   coarsest grid whose interpolation error, measured against the exact map at every cell centre
//!   and every edge midpoint, is within a tolerance ([`MapSampling::Auto`], default 1e-3 px).
//!   For a smooth lens map the bilinear error `~ k^2 |F''| / 8` peaks at those points.
//!
//! Rows are processed in parallel (rayon); each task owns one coordinate scratch buffer for its
//! block of rows (no per-pixel allocation). On x86-64 CPUs with AVX2 and FMA (detected at run
//! time) 8 output pixels are interpolated at once (gathers, fused multiply-adds); pixels near the
//! border and the tail of a row take the scalar path, with the same conventions. The two paths
//! agree to float32 rounding (FMA), so a pixel's value may differ in the last bits depending on
//! whether it falls in a SIMD block.

use crate::error::{DewarpError, Result};
use ndarray::{Array2, ArrayView2, ArrayViewMut2, Axis};
use rayon::prelude::*;

/// Rows per parallel task (one scratch allocation per task).
const ROWS_PER_TASK: usize = 8;
/// Coarsest grid step tried by [`MapSampling::Auto`].
const AUTO_START_STEP: usize = 128;

mod sealed {
    pub trait Sealed {}
    impl Sealed for u16 {}
    impl Sealed for f32 {}
}

/// Memory layout of an input pixel type (selects the SIMD gather).
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelKind {
    U16,
    F32,
}

/// An input pixel type (`u16` or `f32`; sealed): converted to `f32` for interpolation.
pub trait Sample: sealed::Sealed + Copy + Send + Sync + 'static {
    /// The type's layout; the SIMD path reads the pixels through it.
    #[doc(hidden)]
    const KIND: PixelKind;
    /// The value as `f32`.
    fn to_f32(self) -> f32;
}

impl Sample for u16 {
    const KIND: PixelKind = PixelKind::U16;
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}

impl Sample for f32 {
    const KIND: PixelKind = PixelKind::F32;
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

/// An output pixel type, built from the interpolated `f32` value.
pub trait OutSample: Copy + Send + Sync + Default + 'static {
    /// Convert an interpolated value (rounded and clamped for integer types).
    fn from_f32(v: f32) -> Self;
}

impl OutSample for f32 {
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
}

impl OutSample for u16 {
    /// Round half up (away from zero for the non-negative values that survive), clamp to
    /// `[0, 65535]` (NaN -> 0).
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        // `as` truncates toward zero, saturates and maps NaN to 0; for v >= -0.5 truncating
        // v + 0.5 is rounding half up, below that the result is 0 either way.
        (v + 0.5) as u16
    }
}

/// How the coordinate map is sampled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MapSampling {
    /// Evaluate the map at every output pixel.
    Exact,
    /// Evaluate the map every `step` px and interpolate bilinearly in between.
    Grid {
        /// Grid step in output px (>= 1; 1 means exact).
        step: usize,
    },
    /// The coarsest grid (step 128, 64, ... 2) whose bilinear error at every cell centre and edge
    /// midpoint is within `tol` px; exact evaluation if none is.
    Auto {
        /// Maximum interpolation error of the map in px (> 0).
        tol: f64,
    },
}

impl Default for MapSampling {
    fn default() -> Self {
        MapSampling::Auto { tol: 1e-3 }
    }
}

/// Options of [`remap`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemapOptions {
    /// Output shape `(height, width)`; `None` means the input's shape.
    pub out_shape: Option<(usize, usize)>,
    /// How the map is sampled.
    pub sampling: MapSampling,
    /// Value of output pixels whose source lies outside the image.
    pub fill: f32,
}

impl Default for RemapOptions {
    fn default() -> Self {
        RemapOptions {
            out_shape: None,
            sampling: MapSampling::default(),
            fill: 0.0,
        }
    }
}

/// Keys cubic-convolution weights (a = -0.5) for the neighbours at offsets -1, 0, 1, 2 of a
/// sample at fractional position `t` in `[0, 1)`.
#[inline(always)]
pub fn keys_weights(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// The Keys kernel (a = -0.5) itself, `W(s)` for a signed distance `s` in px.
pub fn keys_kernel(s: f64) -> f64 {
    let s = s.abs();
    if s < 1.0 {
        (1.5 * s - 2.5) * s * s + 1.0
    } else if s < 2.0 {
        ((-0.5 * s + 2.5) * s - 4.0) * s + 2.0
    } else {
        0.0
    }
}

/// A source of source-image coordinates, one output row at a time.
trait RowCoords: Sync {
    /// Fill `sx`, `sy` (length = output width) with the source position of each pixel of row `y`.
    fn fill_row(&self, y: usize, sx: &mut [f64], sy: &mut [f64]);
}

/// Per-pixel evaluation of a closure.
struct ExactCoords<'a, F>(&'a F);

impl<F> RowCoords for ExactCoords<'_, F>
where
    F: Fn(f64, f64) -> (f64, f64) + Sync,
{
    fn fill_row(&self, y: usize, sx: &mut [f64], sy: &mut [f64]) {
        let yf = y as f64;
        for (x, (ox, oy)) in sx.iter_mut().zip(sy.iter_mut()).enumerate() {
            let (a, b) = (self.0)(x as f64, yf);
            *ox = a;
            *oy = b;
        }
    }
}

/// Precomputed per-pixel coordinate arrays (like OpenCV's `map1`, `map2`).
struct ArrayCoords<'a, C> {
    map_x: ArrayView2<'a, C>,
    map_y: ArrayView2<'a, C>,
}

impl<C: Copy + Into<f64> + Sync> RowCoords for ArrayCoords<'_, C> {
    fn fill_row(&self, y: usize, sx: &mut [f64], sy: &mut [f64]) {
        for (o, &v) in sx.iter_mut().zip(self.map_x.row(y).iter()) {
            *o = v.into();
        }
        for (o, &v) in sy.iter_mut().zip(self.map_y.row(y).iter()) {
            *o = v.into();
        }
    }
}

/// The map evaluated on a coarse grid of nodes `(i * step, j * step)`, interpolated bilinearly.
#[derive(Debug, Clone)]
pub struct CoordGrid {
    step: usize,
    height: usize,
    width: usize,
    nx: usize,
    ny: usize,
    /// Node values, row-major `[j * nx + i]`.
    gx: Vec<f64>,
    gy: Vec<f64>,
    /// Largest interpolation error (px) measured at the check points, if checked.
    checked_error: Option<f64>,
}

impl CoordGrid {
    /// Evaluate `map` on the nodes of a grid with `step` px covering an output of
    /// `height x width` px (the last node lies at or beyond the last pixel).
    pub fn build<F>(map: &F, height: usize, width: usize, step: usize) -> Result<CoordGrid>
    where
        F: Fn(f64, f64) -> (f64, f64) + Sync,
    {
        if step == 0 {
            return Err(DewarpError::InvalidInput(
                "remap grid step must be >= 1".to_string(),
            ));
        }
        if height == 0 || width == 0 {
            return Err(DewarpError::InvalidInput(format!(
                "remap output shape {height}x{width} is empty"
            )));
        }
        let nx = (width - 1).div_ceil(step) + 1;
        let ny = (height - 1).div_ceil(step) + 1;
        let nodes: Vec<(f64, f64)> = (0..nx * ny)
            .into_par_iter()
            .map(|k| map(((k % nx) * step) as f64, ((k / nx) * step) as f64))
            .collect();
        let (gx, gy) = nodes.into_iter().unzip();
        Ok(CoordGrid {
            step,
            height,
            width,
            nx,
            ny,
            gx,
            gy,
            checked_error: None,
        })
    }

    /// The coarsest grid (step `start`, `start / 2`, ... down to 2) whose interpolation error at
    /// every cell centre and every edge midpoint is at most `tol` px; `None` if even step 2 fails
    /// (evaluate exactly then).
    pub fn auto<F>(map: &F, height: usize, width: usize, tol: f64) -> Result<Option<CoordGrid>>
    where
        F: Fn(f64, f64) -> (f64, f64) + Sync,
    {
        if !(tol > 0.0 && tol.is_finite()) {
            return Err(DewarpError::InvalidInput(format!(
                "remap map tolerance must be a positive number of px, got {tol}"
            )));
        }
        let mut step = AUTO_START_STEP.min(height.max(width).next_power_of_two().max(2));
        while step >= 2 {
            let mut grid = CoordGrid::build(map, height, width, step)?;
            let err = grid.max_error(map);
            if err <= tol {
                grid.checked_error = Some(err);
                return Ok(Some(grid));
            }
            step /= 2;
        }
        Ok(None)
    }

    /// Grid step in output px.
    pub fn step(&self) -> usize {
        self.step
    }

    /// The error measured when [`CoordGrid::auto`] chose this grid.
    pub fn checked_error(&self) -> Option<f64> {
        self.checked_error
    }

    /// Bilinearly interpolated map at output position `(x, y)` (px).
    pub fn eval(&self, x: f64, y: f64) -> (f64, f64) {
        let s = self.step as f64;
        let fx = (x / s).clamp(0.0, (self.nx - 1) as f64);
        let fy = (y / s).clamp(0.0, (self.ny - 1) as f64);
        let i = (fx.floor() as usize).min(self.nx.saturating_sub(2));
        let j = (fy.floor() as usize).min(self.ny.saturating_sub(2));
        let tx = fx - i as f64;
        let ty = fy - j as f64;
        let i1 = (i + 1).min(self.nx - 1);
        let j1 = (j + 1).min(self.ny - 1);
        let lerp2 = |g: &[f64]| {
            let a = g[j * self.nx + i] * (1.0 - tx) + g[j * self.nx + i1] * tx;
            let b = g[j1 * self.nx + i] * (1.0 - tx) + g[j1 * self.nx + i1] * tx;
            a * (1.0 - ty) + b * ty
        };
        (lerp2(&self.gx), lerp2(&self.gy))
    }

    /// Largest distance (px) between the interpolated and the exact map over every cell centre
    /// and every edge midpoint inside the output.
    pub fn max_error<F>(&self, map: &F) -> f64
    where
        F: Fn(f64, f64) -> (f64, f64) + Sync,
    {
        let h = self.step as f64 / 2.0;
        let (wmax, hmax) = ((self.width - 1) as f64, (self.height - 1) as f64);
        (0..self.ny)
            .into_par_iter()
            .map(|j| {
                let mut worst = 0.0f64;
                for i in 0..self.nx {
                    let x0 = (i * self.step) as f64;
                    let y0 = (j * self.step) as f64;
                    for (x, y) in [(x0 + h, y0 + h), (x0 + h, y0), (x0, y0 + h)] {
                        if x > wmax || y > hmax {
                            continue;
                        }
                        let (ex, ey) = map(x, y);
                        let (ax, ay) = self.eval(x, y);
                        let d = (ex - ax).hypot(ey - ay);
                        // A non-finite map value counts as an unbounded error.
                        worst = if d.is_nan() {
                            f64::INFINITY
                        } else {
                            worst.max(d)
                        };
                    }
                }
                worst
            })
            .reduce(|| 0.0, f64::max)
    }
}

impl RowCoords for CoordGrid {
    fn fill_row(&self, y: usize, sx: &mut [f64], sy: &mut [f64]) {
        let step = self.step;
        let j = (y / step).min(self.ny.saturating_sub(2));
        let j1 = (j + 1).min(self.ny - 1);
        let ty = (y - j * step) as f64 / step as f64;
        let inv = 1.0 / step as f64;
        let row = |g: &[f64], i: usize| g[j * self.nx + i] * (1.0 - ty) + g[j1 * self.nx + i] * ty;
        let w = sx.len();
        let mut x = 0;
        let mut i = 0;
        while x < w {
            let i1 = (i + 1).min(self.nx - 1);
            let (ax0, ax1) = (row(&self.gx, i), row(&self.gx, i1));
            let (ay0, ay1) = (row(&self.gy, i), row(&self.gy, i1));
            let (dx, dy) = ((ax1 - ax0) * inv, (ay1 - ay0) * inv);
            let end = (x + step).min(w);
            let (cx, cy) = (&mut sx[x..end], &mut sy[x..end]);
            for (m, (ox, oy)) in cx.iter_mut().zip(cy.iter_mut()).enumerate() {
                let t = m as f64;
                *ox = ax0 + dx * t;
                *oy = ay0 + dy * t;
            }
            x = end;
            i += 1;
        }
    }
}

/// The image as a contiguous row-major slice (borrowed when possible).
fn contiguous<'a, T: Sample>(image: &'a ArrayView2<'a, T>) -> std::borrow::Cow<'a, [T]> {
    match image.as_slice() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => std::borrow::Cow::Owned(image.iter().copied().collect()),
    }
}

/// Interpolate one output row from its source coordinates.
#[inline]
fn interp_row<T: Sample, O: OutSample>(
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
#[inline]
fn interp_row_best<T: Sample, O: OutSample>(
    data: &[T],
    h: usize,
    w: usize,
    sx: &[f64],
    sy: &[f64],
    fill: O,
    out: &mut [O],
) {
    #[cfg(target_arch = "x86_64")]
    {
        // The SIMD kernel indexes with i32 lanes.
        if data.len() < (i32::MAX as usize) / 2
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked above); the kernel reads `data`
            // only at indices it has bounds-checked (see `avx2::interp_row`).
            unsafe { avx2::interp_row(data, h, w, sx, sy, fill, out) };
            return;
        }
    }
    interp_row(data, h, w, sx, sy, fill, out);
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! The Keys kernel on 8 output pixels at a time: coordinates in f64, weights and sums in
    //! f32 with FMA, source pixels fetched with AVX2 gathers. Pixels whose 4 x 4 neighbourhood
    //! is not entirely inside the image (or whose position is outside it, or NaN) go through
    //! the scalar [`super::interp_row`], so the results follow the same conventions.
    use super::{interp_row as scalar_row, OutSample, PixelKind, Sample};
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
    unsafe fn gather4<T: Sample>(data: *const T, off: __m256i) -> [__m256; 4] {
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

    /// # Safety
    /// The CPU must support AVX2 and FMA; `data` is the `h x w` row-major image with
    /// `data.len() < i32::MAX / 2`; `sx`, `sy` and `out` have one length.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn interp_row<T: Sample, O: OutSample>(
        data: &[T],
        h: usize,
        w: usize,
        sx: &[f64],
        sy: &[f64],
        fill: O,
        out: &mut [O],
    ) {
        let n = out.len().min(sx.len()).min(sy.len());
        let full = n - n % 8;
        // The whole 4 x 4 neighbourhood inside the image: floor(x) in [1, w - 3], i.e.
        // x in [1, w - 2) -- tested on x itself, so NaN and far-away points fail too.
        let (xlo, xhi) = (_mm256_set1_pd(1.0), _mm256_set1_pd(w as f64 - 2.0 - 1e-9));
        let (ylo, yhi) = (_mm256_set1_pd(1.0), _mm256_set1_pd(h as f64 - 2.0 - 1e-9));
        let wv = _mm256_set1_epi32(w as i32);
        let one = _mm256_set1_epi32(1);
        let mut tmp = [0.0f32; 8];
        let mut i = 0;
        while i < full {
            // SAFETY: i + 8 <= n; the neighbourhood test below guards every gather.
            unsafe {
                let xa = _mm256_loadu_pd(sx.as_ptr().add(i));
                let xb = _mm256_loadu_pd(sx.as_ptr().add(i + 4));
                let ya = _mm256_loadu_pd(sy.as_ptr().add(i));
                let yb = _mm256_loadu_pd(sy.as_ptr().add(i + 4));
                let inside = w >= 4
                    && h >= 4
                    && all_in(xa, xlo, xhi)
                    && all_in(xb, xlo, xhi)
                    && all_in(ya, ylo, yhi)
                    && all_in(yb, ylo, yhi);
                if !inside {
                    scalar_row(
                        data,
                        h,
                        w,
                        &sx[i..i + 8],
                        &sy[i..i + 8],
                        fill,
                        &mut out[i..i + 8],
                    );
                    i += 8;
                    continue;
                }
                let (ix, tx) = split(xa, xb);
                let (iy, ty) = split(ya, yb);
                let wx = weights(tx);
                let wy = weights(ty);
                // Offset of the top-left neighbour: (iy - 1) * w + ix - 1.
                let mut off = _mm256_add_epi32(
                    _mm256_mullo_epi32(_mm256_sub_epi32(iy, one), wv),
                    _mm256_sub_epi32(ix, one),
                );
                if T::KIND == PixelKind::U16 {
                    let idx = _mm256_loadu_si256(U16_SLOTS.as_ptr() as *const __m256i);
                    off = _mm256_permutevar8x32_epi32(off, idx);
                }
                let mut acc = [_mm256_setzero_ps(); 4];
                for wr in wy {
                    let p = gather4(data.as_ptr(), off);
                    for k in 0..4 {
                        acc[k] = _mm256_fmadd_ps(wr, p[k], acc[k]);
                    }
                    off = _mm256_add_epi32(off, wv);
                }
                let v = _mm256_fmadd_ps(
                    acc[3],
                    wx[3],
                    _mm256_fmadd_ps(
                        acc[2],
                        wx[2],
                        _mm256_fmadd_ps(acc[1], wx[1], _mm256_mul_ps(acc[0], wx[0])),
                    ),
                );
                _mm256_storeu_ps(tmp.as_mut_ptr(), v);
            }
            for k in 0..8 {
                out[i + k] = O::from_f32(tmp[k]);
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
    }
}

fn remap_rows<T: Sample, O: OutSample, C: RowCoords>(
    image: ArrayView2<T>,
    coords: &C,
    fill: O,
    mut out: ArrayViewMut2<O>,
) {
    let (h, w) = image.dim();
    let data = contiguous(&image);
    let data: &[T] = &data;
    let ow = out.ncols();
    out.axis_chunks_iter_mut(Axis(0), ROWS_PER_TASK)
        .into_par_iter()
        .enumerate()
        .for_each(|(chunk, mut rows)| {
            let mut sx = vec![0.0f64; ow];
            let mut sy = vec![0.0f64; ow];
            for (k, mut orow) in rows.axis_iter_mut(Axis(0)).enumerate() {
                coords.fill_row(chunk * ROWS_PER_TASK + k, &mut sx, &mut sy);
                match orow.as_slice_mut() {
                    Some(o) => interp_row_best(data, h, w, &sx, &sy, fill, o),
                    None => {
                        let mut tmp = vec![O::default(); ow];
                        interp_row_best(data, h, w, &sx, &sy, fill, &mut tmp);
                        orow.iter_mut().zip(tmp).for_each(|(a, b)| *a = b);
                    }
                }
            }
        });
}

fn check_image<T>(image: &ArrayView2<T>) -> Result<()> {
    let (h, w) = image.dim();
    if h == 0 || w == 0 {
        return Err(DewarpError::InvalidInput(format!(
            "remap input image {h}x{w} is empty"
        )));
    }
    Ok(())
}

fn out_dims<T>(image: &ArrayView2<T>, opts: &RemapOptions) -> Result<(usize, usize)> {
    let shape = opts.out_shape.unwrap_or(image.dim());
    if shape.0 == 0 || shape.1 == 0 {
        return Err(DewarpError::InvalidInput(format!(
            "remap output shape {}x{} is empty",
            shape.0, shape.1
        )));
    }
    Ok(shape)
}

/// Remap `image` into a new array: `out[y, x] = image(map(x, y))`, Keys bicubic.
///
/// `map` takes an output (object) position `(x, y)` in px and returns the source (image)
/// position `(sx, sy)` in px. The output type `O` is `f32` or `u16` (rounded, clamped).
/// The map sampling follows `opts.sampling` (see the module docs).
///
/// # Errors
/// [`DewarpError::InvalidInput`] for an empty image or output shape, a grid step of 0 or a
/// non-positive tolerance.
pub fn remap<T, O, F>(image: ArrayView2<T>, map: &F, opts: &RemapOptions) -> Result<Array2<O>>
where
    T: Sample,
    O: OutSample,
    F: Fn(f64, f64) -> (f64, f64) + Sync,
{
    check_image(&image)?;
    let shape = out_dims(&image, opts)?;
    let mut out = Array2::<O>::default(shape);
    remap_into(image, map, opts.sampling, opts.fill, out.view_mut())?;
    Ok(out)
}

/// Like [`remap`] but writes into `out` (its shape is the output shape).
///
/// # Errors
/// As [`remap`].
pub fn remap_into<T, O, F>(
    image: ArrayView2<T>,
    map: &F,
    sampling: MapSampling,
    fill: f32,
    out: ArrayViewMut2<O>,
) -> Result<()>
where
    T: Sample,
    O: OutSample,
    F: Fn(f64, f64) -> (f64, f64) + Sync,
{
    check_image(&image)?;
    let (oh, ow) = out.dim();
    if oh == 0 || ow == 0 {
        return Err(DewarpError::InvalidInput(format!(
            "remap output shape {oh}x{ow} is empty"
        )));
    }
    let fill = O::from_f32(fill);
    match sampling {
        MapSampling::Exact | MapSampling::Grid { step: 1 } => {
            remap_rows(image, &ExactCoords(map), fill, out)
        }
        MapSampling::Grid { step } => {
            let grid = CoordGrid::build(map, oh, ow, step)?;
            remap_rows(image, &grid, fill, out)
        }
        MapSampling::Auto { tol } => match CoordGrid::auto(map, oh, ow, tol)? {
            Some(grid) => remap_rows(image, &grid, fill, out),
            None => remap_rows(image, &ExactCoords(map), fill, out),
        },
    }
    Ok(())
}

/// Remap with precomputed per-pixel source coordinates `map_x[y, x]`, `map_y[y, x]` (px, `f32`
/// or `f64`), whose common shape is the output shape.
///
/// # Errors
/// [`DewarpError::InvalidInput`] for an empty image or maps of different or empty shapes.
pub fn remap_with_coords<T, O, C>(
    image: ArrayView2<T>,
    map_x: ArrayView2<C>,
    map_y: ArrayView2<C>,
    fill: f32,
) -> Result<Array2<O>>
where
    T: Sample,
    O: OutSample,
    C: Copy + Into<f64> + Sync,
{
    check_image(&image)?;
    if map_x.dim() != map_y.dim() {
        return Err(DewarpError::InvalidInput(format!(
            "remap coordinate maps differ in shape: map_x {:?}, map_y {:?}",
            map_x.dim(),
            map_y.dim()
        )));
    }
    let (oh, ow) = map_x.dim();
    if oh == 0 || ow == 0 {
        return Err(DewarpError::InvalidInput(format!(
            "remap coordinate maps {oh}x{ow} are empty"
        )));
    }
    let mut out = Array2::<O>::default((oh, ow));
    let coords = ArrayCoords { map_x, map_y };
    remap_rows(image, &coords, O::from_f32(fill), out.view_mut());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    /// A smooth analytic image: low-frequency sinusoids and a Gaussian.
    fn analytic(x: f64, y: f64) -> f64 {
        1000.0
            + 300.0 * (2.0 * std::f64::consts::PI * x / 47.0 + 0.3).sin()
            + 200.0 * (2.0 * std::f64::consts::PI * y / 31.0 - 1.1).cos()
            + 150.0 * (2.0 * std::f64::consts::PI * (x + y) / 59.0).sin()
            + 400.0 * (-((x - 70.0).powi(2) + (y - 40.0).powi(2)) / (2.0 * 15.0f64.powi(2))).exp()
    }

    fn render(h: usize, w: usize, f: impl Fn(f64, f64) -> f64) -> Array2<f32> {
        Array2::from_shape_fn((h, w), |(y, x)| f(x as f64, y as f64) as f32)
    }

    /// A lens-like map: rotation, scale, pincushion and decentring (object -> image px).
    fn lens(x: f64, y: f64) -> (f64, f64) {
        let (cx, cy) = (64.3, 48.7);
        let (dx, dy) = (x - cx, y - cy);
        let r2 = (dx * dx + dy * dy) / (80.0 * 80.0);
        let (c, s) = (0.03f64.cos(), 0.03f64.sin());
        let k = 1.0 + 0.004 * r2;
        let px = k * dx + 0.5e-3 * dx * dy / 80.0;
        let py = k * dy;
        (cx + 0.7 + c * px - s * py, cy - 0.4 + s * px + c * py)
    }

    #[test]
    fn keys_weights_match_kernel_and_partition_unity() {
        for k in 0..=20 {
            let t = k as f64 / 20.0 * 0.999;
            let w = keys_weights(t as f32);
            let exact = [
                keys_kernel(t + 1.0),
                keys_kernel(t),
                keys_kernel(t - 1.0),
                keys_kernel(t - 2.0),
            ];
            for i in 0..4 {
                assert!((w[i] as f64 - exact[i]).abs() < 1e-6, "t={t} i={i}");
            }
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
        assert_eq!(keys_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn identity_map_returns_image_exactly() {
        let img =
            Array2::from_shape_fn((37, 53), |(y, x)| ((x * 7919 + y * 104729) % 65536) as u16);
        let id = |x: f64, y: f64| (x, y);
        for sampling in [
            MapSampling::Exact,
            MapSampling::Grid { step: 16 },
            MapSampling::Auto { tol: 1e-3 },
        ] {
            let opts = RemapOptions {
                sampling,
                ..Default::default()
            };
            let out: Array2<u16> = remap(img.view(), &id, &opts).unwrap();
            assert_eq!(out, img);
            let outf: Array2<f32> = remap(img.view(), &id, &opts).unwrap();
            assert!(outf.iter().zip(img.iter()).all(|(a, b)| *a == *b as f32));
        }
    }

    #[test]
    fn integer_shift_is_exact_with_zero_fill() {
        let img = render(30, 40, analytic);
        let map = |x: f64, y: f64| (x + 3.0, y - 2.0);
        let out: Array2<f32> = remap(img.view(), &map, &RemapOptions::default()).unwrap();
        for ((y, x), &v) in out.indexed_iter() {
            let (sx, sy) = (x as i64 + 3, y as i64 - 2);
            if sx >= 40 || sy < 0 {
                assert_eq!(v, 0.0, "({x},{y}) outside");
            } else {
                assert_eq!(v, img[(sy as usize, sx as usize)]);
            }
        }
    }

    #[test]
    fn zero_fill_outside_and_footprint_inside() {
        let img = Array2::<f32>::from_elem((10, 12), 500.0);
        // Points just inside the footprint [-0.5, w-0.5] get the (replicated) constant; beyond
        // it the fill value.
        let pts = [(-0.49, 3.0), (11.49, 3.0), (4.0, -0.5), (4.0, 9.5)];
        let outside = [
            (-0.51, 3.0),
            (11.51, 3.0),
            (4.0, -0.6),
            (4.0, 9.6),
            (f64::NAN, 1.0),
        ];
        let coords_x =
            Array2::from_shape_fn(
                (1, 9),
                |(_, i)| if i < 4 { pts[i].0 } else { outside[i - 4].0 },
            );
        let coords_y =
            Array2::from_shape_fn(
                (1, 9),
                |(_, i)| if i < 4 { pts[i].1 } else { outside[i - 4].1 },
            );
        let out: Array2<f32> =
            remap_with_coords(img.view(), coords_x.view(), coords_y.view(), 0.0).unwrap();
        for i in 0..4 {
            assert!(
                (out[(0, i)] - 500.0).abs() < 1e-3,
                "inside {i}: {}",
                out[(0, i)]
            );
        }
        for i in 4..9 {
            assert_eq!(out[(0, i)], 0.0, "outside {i}");
        }
        let out7: Array2<f32> =
            remap_with_coords(img.view(), coords_x.view(), coords_y.view(), 7.0).unwrap();
        assert_eq!(out7[(0, 8)], 7.0);
    }

    /// Max error of a sub-pixel shift of sinusoids with wavelength `lam` (px).
    fn shift_error(lam: f64) -> f64 {
        let k = 2.0 * std::f64::consts::PI / lam;
        let f = |x: f64, y: f64| 100.0 * (k * x + 0.2).sin() * (0.5 * k * y).cos();
        let img = render(64, 64, f);
        let (ddx, ddy) = (0.37, -0.81);
        let map = move |x: f64, y: f64| (x + ddx, y + ddy);
        let out: Array2<f32> = remap(img.view(), &map, &RemapOptions::default()).unwrap();
        let mut worst = 0.0f64;
        for y in 4..60 {
            for x in 4..60 {
                let e = (out[(y, x)] as f64 - f(x as f64 + ddx, y as f64 + ddy)).abs();
                worst = worst.max(e);
            }
        }
        worst / 100.0
    }

    #[test]
    fn subpixel_shift_converges_at_third_order() {
        // Keys (a = -0.5) is third-order accurate: the error of a band-limited signal falls
        // as (1/lambda)^3. Doubling the wavelength divides it by ~8.
        let e16 = shift_error(16.0);
        let e32 = shift_error(32.0);
        let e64 = shift_error(64.0);
        assert!(e16 < 2e-3, "e16 {e16}");
        let (r1, r2) = (e16 / e32, e32 / e64);
        assert!(r1 > 6.0 && r1 < 10.0, "ratio {r1}");
        assert!(r2 > 6.0 && r2 < 10.0, "ratio {r2}");
    }

    #[test]
    fn analytic_warp_matches_analytic_image() {
        let (h, w) = (96, 128);
        let img = render(h, w, analytic);
        for sampling in [MapSampling::Exact, MapSampling::Auto { tol: 1e-3 }] {
            let opts = RemapOptions {
                sampling,
                ..Default::default()
            };
            let out: Array2<f32> = remap(img.view(), &lens, &opts).unwrap();
            let mut worst = 0.0f64;
            for y in 3..h - 3 {
                for x in 3..w - 3 {
                    let (sx, sy) = lens(x as f64, y as f64);
                    if sx < 2.0 || sy < 2.0 || sx > w as f64 - 3.0 || sy > h as f64 - 3.0 {
                        continue;
                    }
                    worst = worst.max((out[(y, x)] as f64 - analytic(sx, sy)).abs());
                }
            }
            // Shortest wavelength 31 px, amplitudes <= 400: Keys' third-order error is ~1e-4 of
            // the amplitude per term (see the convergence test), ~0.04 in all (measured 0.042);
            // the grid adds <= 1e-3 px of map error times |grad| (<= ~60 per px).
            let bound = if sampling == MapSampling::Exact {
                0.06
            } else {
                0.06 + 0.06
            };
            assert!(worst < bound, "{sampling:?}: worst {worst}");
        }
    }

    #[test]
    fn auto_grid_is_within_tolerance_everywhere() {
        let (h, w) = (400, 600);
        // Stronger curvature than `lens`, on a larger output.
        let map = |x: f64, y: f64| {
            let (dx, dy) = (x - 300.0, y - 200.0);
            let r2 = (dx * dx + dy * dy) / 1e5;
            (
                x + 0.5 * r2 * dx / 300.0,
                y + 0.5 * r2 * dy / 300.0 + 1e-6 * dx * dx * dy / 10.0,
            )
        };
        let grid = CoordGrid::auto(&map, h, w, 1e-3).unwrap().unwrap();
        assert!(grid.step() >= 2 && grid.step() < 128);
        let mut worst = 0.0f64;
        for y in (0..h).step_by(3) {
            for x in (0..w).step_by(5) {
                let (ex, ey) = map(x as f64, y as f64);
                let (ax, ay) = grid.eval(x as f64, y as f64);
                worst = worst.max((ex - ax).hypot(ey - ay));
            }
        }
        assert!(worst <= 1e-3, "worst {worst} at step {}", grid.step());
        // The row filler agrees with eval.
        let mut sx = vec![0.0; w];
        let mut sy = vec![0.0; w];
        for y in [0, 1, 63, 199, h - 1] {
            grid.fill_row(y, &mut sx, &mut sy);
            for x in 0..w {
                let (ax, ay) = grid.eval(x as f64, y as f64);
                assert!((sx[x] - ax).abs() < 1e-9 && (sy[x] - ay).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn linear_map_grid_is_exact_and_matches_exact_sampling() {
        let img = render(50, 70, analytic);
        let map = |x: f64, y: f64| (0.98 * x + 0.01 * y + 0.3, -0.01 * x + 1.01 * y - 0.2);
        let a: Array2<f32> = remap(
            img.view(),
            &map,
            &RemapOptions {
                sampling: MapSampling::Exact,
                ..Default::default()
            },
        )
        .unwrap();
        let b: Array2<f32> = remap(
            img.view(),
            &map,
            &RemapOptions {
                sampling: MapSampling::Grid { step: 16 },
                ..Default::default()
            },
        )
        .unwrap();
        let d = a
            .iter()
            .zip(b.iter())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f32::max);
        assert!(d < 1e-2, "{d}");
    }

    #[test]
    fn u16_output_rounds_and_clamps() {
        assert_eq!(<u16 as OutSample>::from_f32(2.5), 3);
        assert_eq!(<u16 as OutSample>::from_f32(2.49), 2);
        assert_eq!(<u16 as OutSample>::from_f32(-3.0), 0);
        assert_eq!(<u16 as OutSample>::from_f32(70000.0), 65535);
        assert_eq!(<u16 as OutSample>::from_f32(f32::NAN), 0);
    }

    #[test]
    fn non_contiguous_input_and_output_shape() {
        let big = render(40, 60, analytic);
        let view = big.slice(ndarray::s![..;2, ..;2]);
        let map = |x: f64, y: f64| (x + 0.5, y + 0.25);
        let opts = RemapOptions {
            out_shape: Some((7, 9)),
            ..Default::default()
        };
        let out: Array2<f32> = remap(view, &map, &opts).unwrap();
        let owned = view.to_owned();
        let ref_out: Array2<f32> = remap(owned.view(), &map, &opts).unwrap();
        assert_eq!(out.dim(), (7, 9));
        assert_eq!(out, ref_out);
    }

    #[test]
    fn simd_kernel_agrees_with_scalar_kernel() {
        // Random positions inside, on the border and outside the image, some NaN; row lengths
        // that are not multiples of 8.
        let (h, w) = (23usize, 37usize);
        let img16 =
            Array2::from_shape_fn((h, w), |(y, x)| ((x * 7919 + y * 104_729) % 4096) as u16);
        let img32 = img16.mapv(|v| v as f32 * 0.37 - 100.0);
        let mut state = 12345u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [1usize, 7, 8, 9, 61, 64] {
            let mut sx: Vec<f64> = (0..n).map(|_| -3.0 + (w as f64 + 6.0) * rnd()).collect();
            let sy: Vec<f64> = (0..n).map(|_| -3.0 + (h as f64 + 6.0) * rnd()).collect();
            if n > 5 {
                sx[3] = f64::NAN;
            }
            let d16 = img16.as_slice().unwrap();
            let d32 = img32.as_slice().unwrap();
            let mut a = vec![0.0f32; n];
            let mut b = vec![0.0f32; n];
            interp_row(d16, h, w, &sx, &sy, -1.0f32, &mut a);
            interp_row_best(d16, h, w, &sx, &sy, -1.0f32, &mut b);
            for k in 0..n {
                assert!(
                    (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
                    "u16 {k}: {} {}",
                    a[k],
                    b[k]
                );
            }
            interp_row(d32, h, w, &sx, &sy, -1.0f32, &mut a);
            interp_row_best(d32, h, w, &sx, &sy, -1.0f32, &mut b);
            for k in 0..n {
                assert!(
                    (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
                    "f32 {k}: {} {}",
                    a[k],
                    b[k]
                );
            }
            let mut c = vec![0u16; n];
            let mut e = vec![0u16; n];
            interp_row(d16, h, w, &sx, &sy, 0u16, &mut c);
            interp_row_best(d16, h, w, &sx, &sy, 0u16, &mut e);
            for k in 0..n {
                assert!((c[k] as i32 - e[k] as i32).abs() <= 1, "u16 out {k}");
            }
        }
        // Fully inside: the SIMD lanes are exercised (every position in the fast region).
        let n = 64;
        let sx: Vec<f64> = (0..n).map(|_| 1.0 + (w as f64 - 3.1) * rnd()).collect();
        let sy: Vec<f64> = (0..n).map(|_| 1.0 + (h as f64 - 3.1) * rnd()).collect();
        let mut a = vec![0.0f32; n];
        let mut b = vec![0.0f32; n];
        interp_row(img16.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, &mut a);
        interp_row_best(img16.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, &mut b);
        for k in 0..n {
            assert!(
                (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
                "inside {k}"
            );
        }
    }

    #[test]
    fn invalid_inputs_are_errors() {
        let img = Array2::<u16>::zeros((4, 4));
        let id = |x: f64, y: f64| (x, y);
        let e = remap::<u16, f32, _>(
            img.view(),
            &id,
            &RemapOptions {
                out_shape: Some((0, 3)),
                ..Default::default()
            },
        );
        assert!(e.is_err());
        let e = remap::<u16, f32, _>(
            img.view(),
            &id,
            &RemapOptions {
                sampling: MapSampling::Grid { step: 0 },
                ..Default::default()
            },
        );
        assert!(e.is_err());
        let e = remap::<u16, f32, _>(
            img.view(),
            &id,
            &RemapOptions {
                sampling: MapSampling::Auto { tol: -1.0 },
                ..Default::default()
            },
        );
        assert!(e.is_err());
        let empty = Array2::<u16>::zeros((0, 4));
        assert!(remap::<u16, f32, _>(empty.view(), &id, &RemapOptions::default()).is_err());
        let mx = Array2::<f64>::zeros((2, 3));
        let my = Array2::<f64>::zeros((3, 2));
        assert!(remap_with_coords::<u16, f32, f64>(img.view(), mx.view(), my.view(), 0.0).is_err());
    }
}
