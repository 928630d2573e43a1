//! Sources of source-image coordinates: the map per pixel, coordinate arrays, and the map on a
//! coarse grid interpolated bilinearly ([`CoordGrid`], with its automatic step).

use super::*;
use crate::error::{DewarpError, Result};
use ndarray::ArrayView2;

/// A source of source-image coordinates, one span of an output row at a time.
pub(crate) trait RowCoords: Sync {
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
pub(crate) struct ExactCoords<'a, F>(pub(crate) &'a F);

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
pub(crate) struct ArrayCoords<'a, C> {
    pub(crate) map_x: ArrayView2<'a, C>,
    pub(crate) map_y: ArrayView2<'a, C>,
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
    pub(crate) fn span_with(
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
    pub(crate) fn cells(
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
