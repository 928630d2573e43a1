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
//!   On the SIMD grid path (below) the positions inside one grid cell are `f32` offsets from an
//!   integer base, `(x0 - floor(x0)) + dx * m`: error ~1e-6 px (a few 1e-6 px for cells of
//!   128 px), far below the grid's own 1e-3 px tolerance -- still no quantisation.
//! - **Exactness.** At integer positions the weights are exactly (0, 1, 0, 0): the identity map
//!   returns the image exactly.
//! - **Map sampling.** The map is evaluated per pixel ([`MapSampling::Exact`]), on a coarse grid
//!   every `k` px with bilinear interpolation between nodes ([`MapSampling::Grid`]), or on the
//!   coarsest grid whose interpolation error, measured against the exact map at every cell centre
//!   and every edge midpoint, is within a tolerance ([`MapSampling::Auto`], default 1e-3 px).
//!   For a smooth lens map the bilinear error `~ k^2 |F''| / 8` peaks at those points.
//!
//! Rows are processed in parallel (rayon), each row in spans of 512 px whose coordinates
//! stay in a per-task scratch in L1 (no per-pixel allocation). On x86-64 CPUs with AVX2 and FMA
//! (detected at run time) 8 output pixels are interpolated at once:
//!
//! - **Contiguous taps.** For a near-identity lens map, 8 consecutive output pixels have source
//!   positions in one row band (same `floor(sy)`) at consecutive columns
//!   (`floor(sx_k) = floor(sx_0) + k`); their 16 taps are then 16 contiguous 8-pixel loads
//!   (rows `-1..=2`, column shifts `-1..=2`) weighted per lane. Otherwise (strong distortion,
//!   a row boundary crossed inside the block: ~2 % of the blocks for the paper's lens) the taps
//!   are gathered per lane. Both give the same sum.
//! - **Grid coordinates in the kernel.** With a coarse grid whose step is a multiple of 8, the
//!   map is linear along each cell of a row and the kernel computes the positions itself (no
//!   coordinate arrays); a cell whose end points lie well inside the image skips the per-block
//!   border test.
//! - **Borders.** Blocks with a pixel whose neighbourhood leaves the image (or NaN) and the tail
//!   of a span take the scalar path, with the same conventions. The paths agree to float32
//!   rounding (FMA, summation order), so a pixel's value may differ in the last bits depending
//!   on the path.
//!
//! The output array is allocated zeroed (fresh pages, no memset) and, on Linux, advised to use
//! transparent huge pages: the first write to a 47 MP output then costs ~100 page faults
//! instead of ~50 000.

use crate::error::{DewarpError, Result};
pub use image_core::{keys_kernel, keys_weights, Pixel, PixelKind};
use ndarray::{Array2, ArrayView2, ArrayViewMut2, Axis};
use rayon::prelude::*;

/// Rows per parallel task (one scratch allocation per task).
const ROWS_PER_TASK: usize = 8;
/// Output pixels per coordinate span (a multiple of 8, the SIMD block).
const SPAN: usize = 512;
/// Coarsest grid step tried by [`MapSampling::Auto`].
const AUTO_START_STEP: usize = 128;

/// Memory layout of an output pixel type (selects the SIMD store).
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutKind {
    F32,
    U16,
    /// Any other type: stored one value at a time through [`OutSample::from_f32`].
    Other,
}

/// An output pixel type, built from the interpolated `f32` value.
pub trait OutSample: Copy + Send + Sync + Default + 'static {
    /// The type's layout; the SIMD path stores through it (`Other`: scalar stores).
    #[doc(hidden)]
    const OUT_KIND: OutKind = OutKind::Other;
    /// Convert an interpolated value (rounded and clamped for integer types).
    fn from_f32(v: f32) -> Self;
}

impl OutSample for f32 {
    const OUT_KIND: OutKind = OutKind::F32;
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
}

impl OutSample for u16 {
    const OUT_KIND: OutKind = OutKind::U16;
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

/// A source of source-image coordinates, one span of an output row at a time.
trait RowCoords: Sync {
    /// Fill `sx`, `sy` (same length) with the source positions of the pixels
    /// `x0 .. x0 + sx.len()` of output row `y`.
    fn fill_span(&self, y: usize, x0: usize, sx: &mut [f64], sy: &mut [f64]);

    /// Interpolate the span `x0 .. x0 + out.len()` of row `y` straight from the source's own
    /// representation when it has a faster way than per-pixel coordinates; returns whether it
    /// did (otherwise the caller fills coordinates and runs the row kernel).
    #[allow(clippy::too_many_arguments)]
    fn interp_span<T: Pixel, O: OutSample>(
        &self,
        _y: usize,
        _x0: usize,
        _data: &[T],
        _h: usize,
        _w: usize,
        _fill: O,
        _out: &mut [O],
    ) -> bool {
        false
    }

    /// Fill a whole row (`sx.len()` = output width).
    #[cfg(test)]
    fn fill_row(&self, y: usize, sx: &mut [f64], sy: &mut [f64]) {
        self.fill_span(y, 0, sx, sy);
    }
}

/// Per-pixel evaluation of a closure.
struct ExactCoords<'a, F>(&'a F);

impl<F> RowCoords for ExactCoords<'_, F>
where
    F: Fn(f64, f64) -> (f64, f64) + Sync,
{
    fn fill_span(&self, y: usize, x0: usize, sx: &mut [f64], sy: &mut [f64]) {
        let yf = y as f64;
        for (x, (ox, oy)) in sx.iter_mut().zip(sy.iter_mut()).enumerate() {
            let (a, b) = (self.0)((x0 + x) as f64, yf);
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
    fn fill_span(&self, y: usize, x0: usize, sx: &mut [f64], sy: &mut [f64]) {
        let span = x0..x0 + sx.len();
        let rx = self.map_x.row(y);
        let ry = self.map_y.row(y);
        if let (Some(rx), Some(ry)) = (rx.as_slice(), ry.as_slice()) {
            // Contiguous rows: plain slice loops (vectorised conversions).
            for (o, &v) in sx.iter_mut().zip(&rx[span.clone()]) {
                *o = v.into();
            }
            for (o, &v) in sy.iter_mut().zip(&ry[span]) {
                *o = v.into();
            }
            return;
        }
        for (o, &v) in sx
            .iter_mut()
            .zip(self.map_x.row(y).slice(ndarray::s![span.clone()]).iter())
        {
            *o = v.into();
        }
        for (o, &v) in sy
            .iter_mut()
            .zip(self.map_y.row(y).slice(ndarray::s![span]).iter())
        {
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
                        // Distances of ~1e-3 px: no overflow concern, sqrt is enough.
                        let d = ((ex - ax).powi(2) + (ey - ay).powi(2)).sqrt();
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
    fn fill_span(&self, y: usize, x0: usize, sx: &mut [f64], sy: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked above).
                unsafe { avx2::grid_span(self, y, x0, sx, sy) };
                return;
            }
        }
        self.span_with(y, x0, sx, sy, |out, a, d| {
            for (m, o) in out.iter_mut().enumerate() {
                *o = a + d * m as f64;
            }
        });
    }

    /// With AVX2 and cells of a multiple of 8 px, the cell-linear coordinates go straight into
    /// the SIMD kernel (no coordinate scratch).
    fn interp_span<T: Pixel, O: OutSample>(
        &self,
        y: usize,
        x0: usize,
        data: &[T],
        h: usize,
        w: usize,
        fill: O,
        out: &mut [O],
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if self.step % 8 == 0
                && data.len() < (i32::MAX as usize) / 2
                && std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked above), `data` is the `h x w`
                // image (see `remap_rows`) and small enough for i32 offsets.
                unsafe { avx2::interp_grid_span(self, y, x0, data, h, w, fill, out) };
                return true;
            }
        }
        let _ = (y, x0, data, h, w, fill, out);
        false
    }
}

impl CoordGrid {
    /// The span `x0 .. x0 + sx.len()` of row `y`: within each grid cell the map is linear in
    /// x, `fill(out, a, d)` writes `out[m] = a + d * m`.
    #[inline(always)]
    fn span_with(
        &self,
        y: usize,
        x0: usize,
        sx: &mut [f64],
        sy: &mut [f64],
        fill: impl Fn(&mut [f64], f64, f64),
    ) {
        self.cells(y, x0, sx.len(), |a, b, ax, dx, ay, dy| {
            fill(&mut sx[a..b], ax, dx);
            fill(&mut sy[a..b], ay, dy);
        });
    }

    /// The span `x0 .. x0 + n` of row `y` cut at the grid's cell boundaries: for each piece,
    /// `f(a, b, ax, dx, ay, dy)` with the piece's pixels `x0 + a .. x0 + b` at source positions
    /// `(ax + dx * m, ay + dy * m)`, `m = 0 .. b - a`.
    #[inline(always)]
    fn cells(
        &self,
        y: usize,
        x0: usize,
        n: usize,
        mut f: impl FnMut(usize, usize, f64, f64, f64, f64),
    ) {
        let step = self.step;
        let j = (y / step).min(self.ny.saturating_sub(2));
        let j1 = (j + 1).min(self.ny - 1);
        let ty = (y - j * step) as f64 / step as f64;
        let inv = 1.0 / step as f64;
        let (r0, r1) = (j * self.nx, j1 * self.nx);
        let row = |g: &[f64], i: usize| g[r0 + i] * (1.0 - ty) + g[r1 + i] * ty;
        let end_all = x0 + n;
        let mut x = x0;
        // Columns past the last node (out_shape wider than the grid) extrapolate the last cell.
        let mut i = (x0 / step).min(self.nx.saturating_sub(2));
        let mut ax0 = row(&self.gx, i);
        let mut ay0 = row(&self.gy, i);
        while x < end_all {
            let i1 = (i + 1).min(self.nx - 1);
            let (ax1, ay1) = (row(&self.gx, i1), row(&self.gy, i1));
            let (dx, dy) = ((ax1 - ax0) * inv, (ay1 - ay0) * inv);
            let cell_end = if i + 2 >= self.nx {
                end_all
            } else {
                ((i + 1) * step).min(end_all)
            };
            // Pixel x lies at m = x - i * step px from the cell's left node.
            let m0 = (x - i * step) as f64;
            f(x - x0, cell_end - x0, ax0 + dx * m0, dx, ay0 + dy * m0, dy);
            (ax0, ay0) = (ax1, ay1);
            x = cell_end;
            i += 1;
        }
    }
}

/// The image as a contiguous row-major slice (borrowed when possible).
fn contiguous<'a, T: Pixel>(image: &'a ArrayView2<'a, T>) -> std::borrow::Cow<'a, [T]> {
    match image.as_slice() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => std::borrow::Cow::Owned(image.iter().copied().collect()),
    }
}

/// Interpolate one output row from its source coordinates.
#[inline]
fn interp_row<T: Pixel, O: OutSample>(
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
fn interp_row_best<T: Pixel, O: OutSample>(
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

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! The Keys kernel on 8 output pixels at a time: coordinates in f64, weights and sums in
    //! f32 with FMA, source pixels fetched with AVX2 gathers. Pixels whose 4 x 4 neighbourhood
    //! is not entirely inside the image (or whose position is outside it, or NaN) go through
    //! the scalar [`super::interp_row`], so the results follow the same conventions.
    use super::{interp_row as scalar_row, CoordGrid, OutKind, OutSample, Pixel, PixelKind};
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
    pub(super) unsafe fn grid_span(
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
    pub(super) unsafe fn store8<O: OutSample>(v: __m256, out: &mut [O]) {
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
    pub(super) unsafe fn interp_row<T: Pixel, O: OutSample>(
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
    pub(super) unsafe fn interp_grid_span<T: Pixel, O: OutSample>(
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
}

fn remap_rows<T: Pixel, O: OutSample, C: RowCoords>(
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
            // Coordinates are produced and consumed one span at a time: the scratch stays in
            // L1 (SPAN is a multiple of the 8-pixel SIMD block).
            let mut sx = [0.0f64; SPAN];
            let mut sy = [0.0f64; SPAN];
            let mut tmp = [O::default(); SPAN];
            for (k, mut orow) in rows.axis_iter_mut(Axis(0)).enumerate() {
                let y = chunk * ROWS_PER_TASK + k;
                let mut x0 = 0;
                while x0 < ow {
                    let n = SPAN.min(ow - x0);
                    let (cx, cy) = (&mut sx[..n], &mut sy[..n]);
                    let mut o = orow.slice_mut(ndarray::s![x0..x0 + n]);
                    match o.as_slice_mut() {
                        Some(o) => {
                            if !coords.interp_span(y, x0, data, h, w, fill, o) {
                                coords.fill_span(y, x0, cx, cy);
                                interp_row_best(data, h, w, cx, cy, fill, o);
                            }
                        }
                        None => {
                            let t = &mut tmp[..n];
                            if !coords.interp_span(y, x0, data, h, w, fill, t) {
                                coords.fill_span(y, x0, cx, cy);
                                interp_row_best(data, h, w, cx, cy, fill, t);
                            }
                            o.iter_mut().zip(t.iter()).for_each(|(a, b)| *a = *b);
                        }
                    }
                    x0 += n;
                }
            }
        });
}

/// An output array of default (zero) values. `vec![zero; n]` of a primitive type allocates
/// zeroed memory (`calloc`: fresh pages, no memset pass), which the remap then writes once.
fn zeroed_out<O: OutSample>(shape: (usize, usize)) -> Array2<O> {
    let v = vec![O::default(); shape.0 * shape.1];
    advise_huge_pages(&v);
    Array2::from_shape_vec(shape, v).expect("shape matches the length")
}

/// Ask Linux to back a large, not yet touched buffer with transparent huge pages (2 MiB): the
/// remap's first write to a 47 MP output then takes ~100 page faults instead of ~50 000 (with
/// THP in `madvise` mode, the usual default). Advisory only: failure changes nothing.
fn advise_huge_pages<O>(v: &[O]) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        const PAGE: usize = 4096;
        const MADV_HUGEPAGE: i32 = 14;
        unsafe extern "C" {
            fn madvise(addr: *mut std::ffi::c_void, len: usize, advice: i32) -> i32;
        }
        let bytes = std::mem::size_of_val(v);
        if bytes < 2 * HUGE {
            return;
        }
        let start = (v.as_ptr() as usize).next_multiple_of(PAGE);
        let end = (v.as_ptr() as usize + bytes) / PAGE * PAGE;
        if end > start {
            // SAFETY: [start, end) lies inside the allocation of `v` and is page aligned;
            // MADV_HUGEPAGE changes neither the contents nor the validity of the memory.
            unsafe {
                madvise(start as *mut std::ffi::c_void, end - start, MADV_HUGEPAGE);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
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
    T: Pixel,
    O: OutSample,
    F: Fn(f64, f64) -> (f64, f64) + Sync,
{
    check_image(&image)?;
    let shape = out_dims(&image, opts)?;
    let mut out = zeroed_out::<O>(shape);
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
    T: Pixel,
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
    T: Pixel,
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
    let mut out = zeroed_out::<O>((oh, ow));
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

    /// Keys interpolation in f64 straight from the kernel definition: zero outside the
    /// footprint `[-0.5, w - 0.5] x [-0.5, h - 0.5]`, edge pixels replicated inside it.
    fn reference_keys(img: &Array2<u16>, x: f64, y: f64) -> f64 {
        let (h, w) = img.dim();
        if !(x >= -0.5 && x <= w as f64 - 0.5 && y >= -0.5 && y <= h as f64 - 0.5) {
            return 0.0;
        }
        let (fx, fy) = (x.floor(), y.floor());
        let mut v = 0.0;
        for r in -1..=2 {
            let yy = ((fy as i64 + r).clamp(0, h as i64 - 1)) as usize;
            let wy = keys_kernel(y - (fy + r as f64));
            for c in -1..=2 {
                let xx = ((fx as i64 + c).clamp(0, w as i64 - 1)) as usize;
                v += wy * keys_kernel(x - (fx + c as f64)) * img[(yy, xx)] as f64;
            }
        }
        v
    }

    /// Runs `interp_row_best` over every row of `map` (output `oh x ow`); returns the output and
    /// the number of contiguous-load blocks.
    fn run_best(
        img: &Array2<u16>,
        oh: usize,
        ow: usize,
        map: impl Fn(f64, f64) -> (f64, f64),
    ) -> (Array2<f32>, usize) {
        let (h, w) = img.dim();
        let mut out = Array2::<f32>::zeros((oh, ow));
        let mut blocks = 0;
        for y in 0..oh {
            let (sx, sy): (Vec<f64>, Vec<f64>) = (0..ow).map(|x| map(x as f64, y as f64)).unzip();
            let o = out.row_mut(y).into_slice().unwrap();
            blocks += interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, o);
        }
        (out, blocks)
    }

    fn random_image(h: usize, w: usize, seed: u64) -> Array2<u16> {
        let mut state = seed;
        Array2::from_shape_fn((h, w), |_| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) % 4096) as u16
        })
    }

    /// Largest |fast - reference| over the output.
    fn max_dev(img: &Array2<u16>, out: &Array2<f32>, map: impl Fn(f64, f64) -> (f64, f64)) -> f64 {
        out.indexed_iter()
            .map(|((y, x), &v)| {
                let (sx, sy) = map(x as f64, y as f64);
                (v as f64 - reference_keys(img, sx, sy)).abs()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn contiguous_fast_path_matches_reference_keys() {
        // A near-identity lens-like map (scale, rotation, pincushion) shifted so that parts of
        // the output fall on the image border and outside it (zero fill); a random 12-bit image,
        // where neighbouring taps are uncorrelated (worst case for rounding).
        let (h, w) = (70usize, 203usize);
        let img = random_image(h, w, 7);
        let map = |x: f64, y: f64| {
            let (dx, dy) = (x - 100.0, y - 35.0);
            let k = 1.0 + 2e-6 * (dx * dx + dy * dy);
            let (s, c) = (0.004f64.sin(), 0.004f64.cos());
            let (px, py) = (1.003 * k * dx, k * dy);
            (100.0 + 2.3 + c * px - s * py, 35.0 - 2.3 + s * px + c * py)
        };
        let (out, blocks) = run_best(&img, h, w, map);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // Most 8-pixel blocks (25 per row) take the contiguous path.
            assert!(blocks > h * 25 * 2 / 3, "contiguous blocks {blocks}");
        }
        let _ = blocks;
        // f32 weights and sums on values up to 4095: rounding ~1e-7 relative, a few 1e-4 counts.
        let dev = max_dev(&img, &out, map);
        assert!(dev < 2e-3, "max deviation {dev} counts");
        // The shift puts the last 2-3 columns and the first row outside the footprint: fill.
        assert!(out.row(0).iter().all(|&v| v == 0.0));
        assert!(out.column(w - 1).iter().all(|&v| v == 0.0));
        assert!(out.row(h / 2).iter().filter(|&&v| v != 0.0).count() > w - 5);
    }

    #[test]
    fn strong_distortion_falls_back_to_gathers_correctly() {
        // Source columns 1.7 px apart and rows changing along the output row: no block of 8
        // has consecutive columns in one row band, every block takes the gather path.
        let (h, w) = (40usize, 90usize);
        let img = random_image(h, w, 11);
        let map = |x: f64, y: f64| (1.7 * x - 0.2 * y + 3.1, 0.35 * x + 0.5 * y + 1.2);
        let (out, blocks) = run_best(&img, 30, 48, map);
        assert_eq!(blocks, 0);
        let dev = max_dev(&img, &out, map);
        assert!(dev < 2e-3, "max deviation {dev} counts");
        assert!(out.iter().filter(|&&v| v != 0.0).count() > 30 * 48 / 2);
        // Mixed: a map that is contiguous on the left and stretched on the right of each row.
        let mixed = |x: f64, y: f64| {
            let sx = if x < 40.0 {
                x + 0.3
            } else {
                40.3 + 1.4 * (x - 40.0)
            };
            (sx, y + 0.01 * x + 0.6)
        };
        let (out, blocks) = run_best(&img, 30, 64, mixed);
        assert!(blocks > 0 && blocks < 30 * 8, "contiguous blocks {blocks}");
        let dev = max_dev(&img, &out, mixed);
        assert!(dev < 2e-3, "max deviation {dev} counts");
        // Mirrored and strongly stretched maps through `remap` on a grid of step 16 (the fused
        // grid path with f32 offsets, or the f64 path where offsets get long): against the
        // reference at the grid's positions.
        for map in [
            (|x: f64, y: f64| (80.0 - 0.9 * x, 2.0 + 0.8 * y + 0.01 * x))
                as fn(f64, f64) -> (f64, f64),
            |x: f64, y: f64| (3.0 + 40.0 * x, 5.0 + 0.5 * y),
            |x: f64, y: f64| (2.5 + 0.02 * x, 1.5 + 0.3 * y + 0.001 * x * x),
        ] {
            let opts = RemapOptions {
                out_shape: Some((30, 96)),
                sampling: MapSampling::Grid { step: 16 },
                ..Default::default()
            };
            let out: Array2<f32> = remap(img.view(), &map, &opts).unwrap();
            let grid = CoordGrid::build(&map, 30, 96, 16).unwrap();
            let dev = max_dev(&img, &out, |x, y| grid.eval(x, y));
            assert!(dev < 0.03, "max deviation {dev} counts");
            assert!(out.iter().any(|&v| v != 0.0));
        }
    }

    #[test]
    fn simd_u16_store_rounds_like_from_f32() {
        let vals = [
            -3.0f32, -0.6, -0.5, -0.49, 0.0, 0.49, 0.5, 2.5, 1234.5001, 65534.5, 65535.49, 65535.6,
            70000.0, 3e9, -3e9,
        ];
        // Through the whole kernel: an f32 image holding the values, identity map (weights
        // exactly 0, 1, 0, 0) so the interpolated value is the pixel itself.
        let (h, w) = (8usize, vals.len() + 8);
        let img = Array2::from_shape_fn((h, w), |(_, x)| {
            if (4..4 + vals.len()).contains(&x) {
                vals[x - 4]
            } else {
                1.0
            }
        });
        let mut out = vec![0u16; w - 8];
        let sx: Vec<f64> = (0..w - 8).map(|x| (x + 4) as f64).collect();
        let sy = vec![3.0; w - 8];
        let blocks = interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0u16, &mut out);
        for (k, &v) in vals.iter().enumerate() {
            assert_eq!(out[k], <u16 as OutSample>::from_f32(v), "value {v}");
        }
        // Non-finite values straight through the SIMD store.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            assert_eq!(blocks, vals.len() / 8);
            let v = [
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                -0.0,
                0.5,
                1.49,
                9.5,
                -7.0,
            ];
            let mut o = [7u16; 8];
            // SAFETY: AVX2 and FMA are available (checked above); `o` holds 8 values.
            unsafe {
                use std::arch::x86_64::_mm256_loadu_ps;
                avx2::store8(_mm256_loadu_ps(v.as_ptr()), &mut o);
            }
            for k in 0..8 {
                assert_eq!(o[k], <u16 as OutSample>::from_f32(v[k]), "value {}", v[k]);
            }
        }
        let _ = blocks;
    }

    #[test]
    fn spans_and_strided_output_agree_with_whole_rows() {
        let map = |x: f64, y: f64| {
            let (dx, dy) = (x - 300.0, y - 200.0);
            let r2 = (dx * dx + dy * dy) / 1e5;
            (x + 0.5 * r2 * dx / 300.0, y + 0.5 * r2 * dy / 300.0)
        };
        let (h, w) = (40, 1100);
        let grid = CoordGrid::build(&map, h, w, 16).unwrap();
        let (mut sx, mut sy) = (vec![0.0; w], vec![0.0; w]);
        for y in [0, 17, h - 1] {
            grid.fill_row(y, &mut sx, &mut sy);
            for x0 in [0usize, 5, 16, 511, 512, 1000] {
                let n = (w - x0).min(300);
                let (mut px, mut py) = (vec![0.0; n], vec![0.0; n]);
                grid.fill_span(y, x0, &mut px, &mut py);
                for k in 0..n {
                    let (ax, ay) = grid.eval((x0 + k) as f64, y as f64);
                    assert!((px[k] - sx[x0 + k]).abs() < 1e-9 && (px[k] - ax).abs() < 1e-9);
                    assert!((py[k] - sy[x0 + k]).abs() < 1e-9 && (py[k] - ay).abs() < 1e-9);
                }
            }
        }
        // Output rows longer than a span, written through a strided view.
        let img = random_image(60, 1100, 3);
        let opts = RemapOptions {
            out_shape: Some((h, w)),
            ..Default::default()
        };
        let a: Array2<f32> = remap(img.view(), &map, &opts).unwrap();
        let mut big = Array2::<f32>::zeros((h, 2 * w));
        let view = big.slice_mut(ndarray::s![.., ..;2]);
        remap_into(img.view(), &map, opts.sampling, 0.0, view).unwrap();
        assert_eq!(big.slice(ndarray::s![.., ..;2]), a);
        // Against the reference at the auto grid's interpolated map (what `remap` samples).
        let auto = CoordGrid::auto(&map, h, w, 1e-3).unwrap().unwrap();
        let dev = max_dev(&img, &a, |x, y| auto.eval(x, y));
        // f32 position offsets on the fused grid path: see grid_cells_kernel_equals_coordinate_path.
        assert!(dev < 0.03, "max deviation {dev} counts");
    }

    #[test]
    fn grid_cells_kernel_equals_coordinate_path() {
        // The fused grid path (cell-linear coordinates straight into the kernel) against
        // coordinates filled per span and the row kernel: the same positions, so the same bits.
        // Output wider than the image and shifted: border, outside and partial blocks included.
        let img = random_image(90, 300, 5);
        let (oh, ow) = (70usize, 331usize);
        let map = |x: f64, y: f64| {
            let (dx, dy) = (x - 150.0, y - 45.0);
            let k = 1.0 + 3e-6 * (dx * dx + dy * dy);
            (
                150.0 - 4.2 + k * dx + 0.002 * dy,
                45.0 + 6.1 + k * dy - 0.002 * dx,
            )
        };
        let (h, w) = img.dim();
        for step in [8usize, 16, 24, 64, 4] {
            let grid = CoordGrid::build(&map, oh, ow, step).unwrap();
            for y in [0usize, 1, 33, oh - 1] {
                for (x0, n) in [(0usize, ow), (5, 200), (64, 267)] {
                    let mut a = vec![0.0f32; n];
                    let fused = grid.interp_span(y, x0, img.as_slice().unwrap(), h, w, 0.0, &mut a);
                    let (mut sx, mut sy) = (vec![0.0; n], vec![0.0; n]);
                    grid.fill_span(y, x0, &mut sx, &mut sy);
                    let mut b = vec![0.0f32; n];
                    interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0.0, &mut b);
                    if fused {
                        // Inside the image the fused path takes positions as f32 offsets from
                        // an integer base (<= ~4e-6 px from the f64 positions at 32 px from
                        // the cell start); the Keys interpolant of random 12-bit data changes
                        // by < 6000 counts/px, plus f32 sum rounding (~2e-3): < 0.03 counts.
                        for (p, q) in a.iter().zip(&b) {
                            assert!((p - q).abs() <= 0.03, "step {step} row {y}: {p} {q}");
                        }
                    } else {
                        // Steps that are not a multiple of 8 (or no AVX2) take the other path.
                        assert!(step % 8 != 0 || !cfg!(target_arch = "x86_64") || a == b);
                    }
                    let mut c = vec![0u16; n];
                    let fused16 =
                        grid.interp_span(y, x0, img.as_slice().unwrap(), h, w, 0u16, &mut c);
                    if fused16 {
                        let mut d = vec![0u16; n];
                        interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0u16, &mut d);
                        // Rounded: equal but for values within 0.03 of a half-integer.
                        assert!(c.iter().zip(&d).all(|(p, q)| p.abs_diff(*q) <= 1));
                    }
                }
            }
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
