//! Image access for the correlator: a borrowed, row-contiguous view of `u8`, `u16`, `f32` or
//! `f64` pixels (no copy when the caller's array is in standard layout), and the window
//! samplers (integer copy, constant sub-pixel shift, per-pixel deformation) with separable
//! interpolation kernels: quintic B-spline (6 x 6 coefficients, the default of the PIV
//! engine), cubic B-spline or Keys bicubic (a = -0.5, 4 x 4 pixels); taps beyond the image
//! are mirrored (whole-sample symmetric).
//!
//! Pixel frame: x = column, y = row, origin at the centre of the top-left pixel, y down.

use crate::error::{PivError, Result};
pub use image_core::kernels::{bspline5_weights, bspline_weights, keys_weights, Weights};
use image_core::kernels::{floor_i, mirror};
use image_core::spline::{prefilter, SplineOrder};
pub use image_core::Pixel;
use ndarray::parallel::prelude::*;
use ndarray::{ArrayView2, CowArray, Ix2};
use rayon::prelude::*;

/// A row-major image borrowed from an `ArrayView2` (copied only if the view is not in standard
/// layout).
pub struct Img<'a, T: Pixel> {
    data: CowArray<'a, T, Ix2>,
    /// Width in pixels (number of columns).
    pub width: usize,
    /// Height in pixels (number of rows).
    pub height: usize,
}

impl<'a, T: Pixel> Img<'a, T> {
    /// Wrap a view; `name` appears in error messages. Rejects empty images and NaN/inf.
    pub fn new(view: ArrayView2<'a, T>, name: &str) -> Result<Self> {
        let (height, width) = view.dim();
        if height == 0 || width == 0 {
            return Err(PivError::InvalidInput(format!(
                "{name} is empty ({height} x {width} pixels)"
            )));
        }
        let data = if view.is_standard_layout() {
            CowArray::from(view)
        } else {
            CowArray::from(view.as_standard_layout().into_owned())
        };
        let img = Img {
            data,
            width,
            height,
        };
        let bad = img
            .slice()
            .par_chunks(1 << 16)
            .any(|c| c.iter().any(|p| !p.is_finite_px()));
        if bad {
            return Err(PivError::InvalidInput(format!(
                "{name} contains NaN or infinite pixel values"
            )));
        }
        Ok(img)
    }

    /// The pixels in row-major order.
    #[inline(always)]
    pub fn slice(&self) -> &[T] {
        self.data.as_slice().expect("standard layout")
    }

    /// The value at integer (x, y), zero outside the image.
    #[inline(always)]
    pub fn get(&self, x: isize, y: isize) -> f32 {
        if x < 0 || y < 0 || x >= self.width as isize || y >= self.height as isize {
            0.0
        } else {
            self.slice()[y as usize * self.width + x as usize].to_f32()
        }
    }

    /// Keys bicubic value at a real position (mirror-extended at the borders).
    #[inline(always)]
    pub fn bicubic(&self, x: f64, y: f64) -> f32 {
        self.interp(x, y, keys_weights)
    }

    /// Value at a real position with the separable `N`-tap kernel `wf` (taps
    /// `floor - (N/2 - 1) ..= floor + N/2`); taps beyond the image are mirrored (whole-sample
    /// symmetric extension, the boundary rule of [`bspline_coeffs`]).
    #[inline(always)]
    pub fn interp<const N: usize, W: Fn(f32) -> [f32; N]>(&self, x: f64, y: f64, wf: W) -> f32 {
        let ix = floor_i(x);
        let iy = floor_i(y);
        let wx = wf((x - ix as f64) as f32);
        let wy = wf((y - iy as f64) as f32);
        let o = (N / 2 - 1) as isize;
        self.taps(ix - o, iy - o, &wx, &wy)
    }

    /// Apply separable weights to the N x N neighbourhood whose top-left pixel is (ix, iy)
    /// (mirrored beyond the image).
    #[inline(always)]
    fn taps<const N: usize>(&self, ix: isize, iy: isize, wx: &[f32; N], wy: &[f32; N]) -> f32 {
        let w = self.width as isize;
        let h = self.height as isize;
        let s = self.slice();
        if ix >= 0 && iy >= 0 && ix + N as isize <= w && iy + N as isize <= h {
            let mut acc = 0.0f32;
            for (r, wyr) in wy.iter().enumerate() {
                let base = (iy as usize + r) * self.width + ix as usize;
                let row = &s[base..base + N];
                let mut v = 0.0f32;
                for (wxc, p) in wx.iter().zip(row) {
                    v += wxc * p.to_f32();
                }
                acc += wyr * v;
            }
            acc
        } else {
            let mut acc = 0.0f32;
            for (r, wyr) in wy.iter().enumerate() {
                let row = mirror(iy + r as isize, self.height) * self.width;
                let mut v = 0.0f32;
                for (c, wxc) in wx.iter().enumerate() {
                    v += wxc * s[row + mirror(ix + c as isize, self.width)].to_f32();
                }
                acc += wyr * v;
            }
            acc
        }
    }
}

impl<T: Pixel> Img<'_, T> {
    /// Column `i` interpolated along y at `y` with kernel `wf` (rows mirrored beyond the
    /// image).
    #[inline(always)]
    fn column_interp<W: Fn(f32) -> [f32; N], const N: usize>(
        &self,
        i: usize,
        y: f64,
        wf: W,
    ) -> f32 {
        let iy = floor_i(y);
        let wy = wf((y - iy as f64) as f32);
        let j0 = iy - (N / 2 - 1) as isize;
        let s = self.slice();
        if j0 >= 0 && j0 as usize + N <= self.height {
            let base = j0 as usize * self.width + i;
            wy.iter()
                .enumerate()
                .map(|(k, a)| a * s[base + k * self.width].to_f32())
                .sum()
        } else {
            wy.iter()
                .enumerate()
                .map(|(k, a)| a * s[mirror(j0 + k as isize, self.height) * self.width + i].to_f32())
                .sum()
        }
    }
}

/// B-spline coefficients of an image of `order` (image-core's prefilter, mirror boundaries).
fn spline_coeffs<T: Pixel>(img: &Img<'_, T>, order: SplineOrder) -> Img<'static, f32> {
    let (w, h) = (img.width, img.height);
    let mut c: Vec<f32> = img.slice().par_iter().map(|p| p.to_f32()).collect();
    prefilter(&mut c, w, h, order);
    let arr = ndarray::Array2::from_shape_vec((h, w), c).expect("shape");
    Img {
        data: CowArray::from(arr),
        width: w,
        height: h,
    }
}

/// Cubic B-spline coefficients of an image (Unser's recursive prefilter, mirror boundaries):
/// sampling them with [`bspline_weights`] interpolates the image exactly at the pixels.
pub fn bspline_coeffs<T: Pixel>(img: &Img<'_, T>) -> Img<'static, f32> {
    spline_coeffs(img, SplineOrder::Cubic)
}

/// Quintic B-spline coefficients of an image (two-pole recursive prefilter, mirror
/// boundaries): sampling them with [`bspline5_weights`] interpolates the image exactly at the
/// pixels. Its frequency response is closer to the ideal one than the cubic's: on 2-3 px
/// particles the sub-pixel shift of a deformed window is biased by about a third as much.
pub fn bspline5_coeffs<T: Pixel>(img: &Img<'_, T>) -> Img<'static, f32> {
    spline_coeffs(img, SplineOrder::Quintic)
}

/// A displacement field on a regular grid, interpolated bilinearly (constant beyond the outer
/// grid points). Used as the predictor of a pass and for image deformation.
#[derive(Debug, Clone)]
pub struct GridField {
    /// The grid of the field.
    pub grid: crate::grid::Grid,
    /// x displacement (px) per grid point, shape (ny, nx).
    pub u: ndarray::Array2<f64>,
    /// y displacement (px) per grid point, shape (ny, nx).
    pub v: ndarray::Array2<f64>,
}

impl GridField {
    /// Interpolation index and weight along one axis.
    #[inline(always)]
    fn axis(p: f64, p0: f64, step: f64, n: usize) -> (usize, usize, f64) {
        if n == 1 {
            return (0, 0, 0.0);
        }
        let t = (p - p0) / step;
        if t <= 0.0 {
            (0, 0, 0.0)
        } else if t >= (n - 1) as f64 {
            (n - 1, n - 1, 0.0)
        } else {
            let i = t as usize; // t > 0: the cast is the floor
            (i, i + 1, t - i as f64)
        }
    }

    /// The y-interpolation state of row `y` for [`Self::at_row`].
    #[inline]
    pub fn row(&self, y: f64) -> (usize, usize, f64) {
        let g = &self.grid;
        Self::axis(y, g.y0, g.dy, g.ny)
    }

    /// Displacement at (x, y) with the row state of `y` from [`Self::row`].
    #[inline(always)]
    pub fn at_row(&self, row: &(usize, usize, f64), x: f64) -> (f64, f64) {
        let g = &self.grid;
        let (i0, i1, tx) = Self::axis(x, g.x0, g.dx, g.nx);
        let (j0, j1, ty) = *row;
        let nx = g.nx;
        let (us, vs) = (
            self.u.as_slice().expect("standard layout"),
            self.v.as_slice().expect("standard layout"),
        );
        let bl = |a: &[f64]| {
            let top = a[j0 * nx + i0] * (1.0 - tx) + a[j0 * nx + i1] * tx;
            let bot = a[j1 * nx + i0] * (1.0 - tx) + a[j1 * nx + i1] * tx;
            top * (1.0 - ty) + bot * ty
        };
        (bl(us), bl(vs))
    }

    /// The field averaged over a `w` x `h` px window (top-hat, the pixel areas
    /// `[x - w/2, x + w/2] x [y - h/2, y + h/2]`) of its bilinear interpolant, at every grid
    /// point: the displacement a window centred there measures when the frames move by this
    /// field. Used to filter a pass's predictor with the window of the pass (see
    /// [`crate::multipass`]). Beyond the outer grid points the field is constant, as in
    /// [`Self::at`].
    pub fn window_average(&self, w: usize, h: usize) -> GridField {
        let g = &self.grid;
        let wx = tophat_weights(w as f64, g.dx, g.nx);
        let wy = tophat_weights(h as f64, g.dy, g.ny);
        let filt = |a: &ndarray::Array2<f64>| {
            let (ny, nx) = (g.ny as isize, g.nx as isize);
            let rows = ndarray::Array2::from_shape_fn((g.ny, g.nx), |(j, i)| {
                wx.iter()
                    .map(|&(o, wt)| wt * a[[j, (i as isize + o).clamp(0, nx - 1) as usize]])
                    .sum::<f64>()
            });
            ndarray::Array2::from_shape_fn((g.ny, g.nx), |(j, i)| {
                wy.iter()
                    .map(|&(o, wt)| wt * rows[[(j as isize + o).clamp(0, ny - 1) as usize, i]])
                    .sum::<f64>()
            })
        };
        GridField {
            grid: self.grid,
            u: filt(&self.u),
            v: filt(&self.v),
        }
    }

    /// Displacement (u, v) at (x, y).
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        let g = &self.grid;
        let (i0, i1, tx) = Self::axis(x, g.x0, g.dx, g.nx);
        let (j0, j1, ty) = Self::axis(y, g.y0, g.dy, g.ny);
        let bl = |a: &ndarray::Array2<f64>| {
            let top = a[[j0, i0]] * (1.0 - tx) + a[[j0, i1]] * tx;
            let bot = a[[j1, i0]] * (1.0 - tx) + a[[j1, i1]] * tx;
            top * (1.0 - ty) + bot * ty
        };
        (bl(&self.u), bl(&self.v))
    }
}

/// Weights `(node offset, weight)` of the grid nodes (spacing `step`, `n` of them) in the mean
/// of their linear interpolant over `[-win/2, win/2]` around a node; `[(0, 1)]` for a single
/// node. They sum to one.
fn tophat_weights(win: f64, step: f64, n: usize) -> Vec<(isize, f64)> {
    if n < 2 || step.is_nan() || step <= 0.0 || win.is_nan() || win <= 0.0 {
        return vec![(0, 1.0)];
    }
    // integral of the unit hat (support [-1, 1]) from -inf to x
    let hat_int = |x: f64| {
        if x <= -1.0 {
            0.0
        } else if x <= 0.0 {
            0.5 * (x + 1.0) * (x + 1.0)
        } else if x <= 1.0 {
            1.0 - 0.5 * (1.0 - x) * (1.0 - x)
        } else {
            1.0
        }
    };
    let a = 0.5 * win / step;
    let reach = a.ceil() as isize + 1;
    (-reach..=reach)
        .map(|j| {
            (
                j,
                (hat_int(a - j as f64) - hat_int(-a - j as f64)) / (2.0 * a),
            )
        })
        .filter(|&(_, wt)| wt > 0.0)
        .collect()
}

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
    /// The kernel, `Fn(f32) -> [f32; N]` (see [`Weights`]).
    pub wf: W,
}

/// Tolerance (px) of the inside test of [`inside`].
const INSIDE_EPS: f64 = 1e-6;

/// Is the position (x, y) inside the image, `[-0.5, width - 0.5] x [-0.5, height - 0.5]` (the
/// area of its pixels, README's convention)?
#[inline(always)]
pub fn inside(x: f64, y: f64, width: usize, height: usize) -> bool {
    x >= -0.5 - INSIDE_EPS
        && y >= -0.5 - INSIDE_EPS
        && x <= width as f64 - 0.5 + INSIDE_EPS
        && y <= height as f64 - 0.5 + INSIDE_EPS
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
fn sample_field_2d<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
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
const FIELD_LINE: usize = 512;

/// A window pair deformed by a field, sampled separably as [`deform_pair`] does for a whole
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
/// the taps times the tap distance (second order, as [`deform_pair`], the deformation of
/// Method I's regular grid; exact when `d_y` does not vary along x).
///
/// Pixels whose source lies outside the image are NaN. Returns `Some(all inside)`, or `None`
/// (nothing meaningful written) when a window row or a source span exceeds [`FIELD_LINE`]
/// px or is not finite.
fn sample_field_sep<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
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

/// Deform a whole frame pair symmetrically by the field `f`: `A'(p) = A(p - f(p)/2)`,
/// `B'(p) = B(p + f(p)/2)`, sampled from `ia`, `ib` with kernel `wf` (rows in parallel). Windows
/// of a regular grid are then plain copies of the deformed images, which costs one
/// interpolation per pixel instead of one per pixel and overlapping window. A pixel whose
/// source position lies outside its frame (see [`inside`]) is set to NaN, as in
/// [`sample_pair`].
///
/// The separable kernel is applied in two 1D passes per output row (`2 N` taps per pixel
/// instead of `N^2`): first every column `i` of the source is interpolated along y at
/// `y -+ f_y(i +- f_x(i)/2)/2`, the vertical displacement of the output pixel whose source
/// column is `i`; then the row of these values is interpolated along x at `x -+ f_x(x)/2`.
/// This equals the 2D interpolation up to the change of the field across the `N` taps times
/// the displacement (second order: below 1e-4 px for a field varying by 0.01 px/px).
pub fn deform_pair<U: Pixel, W: Fn(f32) -> [f32; N] + Copy + Sync, const N: usize>(
    ia: &Img<'_, U>,
    ib: &Img<'_, U>,
    wf: W,
    f: &GridField,
) -> (Img<'static, f32>, Img<'static, f32>) {
    let (w, h) = (ia.width, ia.height);
    let mut da = vec![0.0f32; w * h];
    let mut db = vec![0.0f32; w * h];
    let g = &f.grid;
    // the x interpolation state of every column, shared by all rows
    let cols: Vec<(usize, usize, f64)> = (0..w)
        .map(|x| GridField::axis(x as f64, g.x0, g.dx, g.nx))
        .collect();
    let (us, vs) = (
        f.u.as_slice().expect("standard layout"),
        f.v.as_slice().expect("standard layout"),
    );
    da.par_chunks_mut(w)
        .zip(db.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || {
                (
                    vec![0.0f64; g.nx],
                    vec![0.0f64; g.nx],
                    vec![0.0f32; w],
                    vec![0.0f32; w],
                )
            },
            |(ur, vr, ta, tb), (y, (ra, rb))| {
                let yf = y as f64;
                // half the field interpolated to this row at every grid column
                let (j0, j1, ty) = f.row(yf);
                for i in 0..g.nx {
                    let (k0, k1) = (j0 * g.nx + i, j1 * g.nx + i);
                    ur[i] = 0.5 * (us[k0] * (1.0 - ty) + us[k1] * ty);
                    vr[i] = 0.5 * (vs[k0] * (1.0 - ty) + vs[k1] * ty);
                }
                let half = |&(i0, i1, tx): &(usize, usize, f64)| {
                    (
                        ur[i0] * (1.0 - tx) + ur[i1] * tx,
                        vr[i0] * (1.0 - tx) + vr[i1] * tx,
                    )
                };
                let half_v_at = |x: f64| half(&GridField::axis(x, g.x0, g.dx, g.nx)).1;
                // 1. columns along y
                for (i, (oa, ob)) in ta.iter_mut().zip(tb.iter_mut()).enumerate() {
                    let hu = half(&cols[i]).0;
                    let xi = i as f64;
                    *oa = ia.column_interp(i, yf - half_v_at(xi + hu), wf);
                    *ob = ib.column_interp(i, yf + half_v_at(xi - hu), wf);
                }
                // 2. the row along x
                for (x, ((oa, ob), c)) in ra.iter_mut().zip(rb.iter_mut()).zip(&cols).enumerate() {
                    let xf = x as f64;
                    let (hu, hv) = half(c);
                    let (xa, ya, xb, yb) = (xf - hu, yf - hv, xf + hu, yf + hv);
                    *oa = if inside(xa, ya, w, h) {
                        line_interp(ta, xa, wf)
                    } else {
                        f32::NAN
                    };
                    *ob = if inside(xb, yb, w, h) {
                        line_interp(tb, xb, wf)
                    } else {
                        f32::NAN
                    };
                }
            },
        );
    let wrap = |v: Vec<f32>| Img {
        data: CowArray::from(ndarray::Array2::from_shape_vec((h, w), v).expect("shape")),
        width: w,
        height: h,
    };
    (wrap(da), wrap(db))
}

/// Interpolate the line `t` at position `x` with kernel `wf` (mirrored beyond its ends).
#[inline(always)]
fn line_interp<W: Fn(f32) -> [f32; N], const N: usize>(t: &[f32], x: f64, wf: W) -> f32 {
    let ix = floor_i(x);
    let wx = wf((x - ix as f64) as f32);
    let i0 = ix - (N / 2 - 1) as isize;
    if i0 >= 0 && i0 as usize + N <= t.len() {
        let row = &t[i0 as usize..i0 as usize + N];
        wx.iter().zip(row).map(|(a, b)| a * b).sum()
    } else {
        wx.iter()
            .enumerate()
            .map(|(k, a)| a * t[mirror(i0 + k as isize, t.len())])
            .sum()
    }
}

/// Sample a `w` x `h` window whose top-left pixel sits at (x0, y0) (constant shift): straight
/// from `img` at integer positions, else from `interp` with kernel `wf`.
fn sample_shift<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N], const N: usize>(
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
    for r in 0..h {
        for c in 0..w {
            out[r * w + c] = interp.taps(ix + c as isize, iy + r as isize, &wx, &wy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    /// Largest difference between the separable sampler of field-deformed windows
    /// ([`sample_pair`]) and the per-pixel 2D interpolation, over windows inside and past every
    /// edge, quintic and cubic B-spline; the outside pixels (NaN) must be the same. The field
    /// is `(6.3 + gx x - 0.008 y, -2.2 + gy x + 0.01 y)`.
    fn separable_vs_2d(gx: f64, gy: f64) -> f32 {
        use crate::grid::Grid;
        let (iw, ih) = (120usize, 90usize);
        let a = Array2::from_shape_fn((ih, iw), |(y, x)| {
            let (x, y) = (x as f64, y as f64);
            (1000.0 + 400.0 * (0.9 * x).sin() * (0.7 * y + 0.3).cos() + 3.0 * x) as f32
        });
        let b = a.mapv(|p| 0.5 * p + 100.0);
        let (ia, ib) = (
            Img::new(a.view(), "a").unwrap(),
            Img::new(b.view(), "b").unwrap(),
        );
        let grid = Grid::for_windows(iw, ih, 16, 16, 0.5).unwrap();
        let field = GridField {
            grid,
            u: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let (x, y) = grid.xy(j, i);
                6.3 + gx * x - 0.008 * y
            }),
            v: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
                let (x, y) = grid.xy(j, i);
                -2.2 + gy * x + 0.01 * y
            }),
        };
        let (c5a, c5b) = (bspline5_coeffs(&ia), bspline5_coeffs(&ib));
        let (c3a, c3b) = (bspline_coeffs(&ia), bspline_coeffs(&ib));
        let src5 = Source {
            a: &ia,
            b: &ib,
            ia: &c5a,
            ib: &c5b,
            wf: bspline5_weights,
        };
        let src3 = Source {
            a: &ia,
            b: &ib,
            ia: &c3a,
            ib: &c3b,
            wf: bspline_weights,
        };
        let (w, h) = (32usize, 8usize);
        let (mut worst, mut n_nan) = (0.0f32, 0);
        let mut compare = |p: &[f32], q: &[f32]| {
            for (p, q) in p.iter().zip(q) {
                assert_eq!(p.is_nan(), q.is_nan());
                if p.is_nan() {
                    n_nan += 1;
                } else {
                    worst = worst.max((p - q).abs());
                }
            }
        };
        for &(left, top) in &[
            (40.3, 30.7),
            (-2.6, 20.2),
            (95.1, 84.9),
            (50.5, -1.4),
            (0.0, 0.0),
        ] {
            let spec = WindowSpec {
                left,
                top,
                du: 0.35,
                dv: -0.2,
                field: Some(&field),
            };
            let mut s = [vec![0.0f32; w * h], vec![0.0f32; w * h]];
            let mut r = [vec![0.0f32; w * h], vec![0.0f32; w * h]];
            let [sa, sb] = &mut s;
            let [ra, rb] = &mut r;
            let ok_s = sample_pair(&src5, w, h, &spec, sa, sb);
            let ok_r = sample_field_2d(&src5, w, h, &spec, &field, ra, rb);
            assert_eq!(ok_s, ok_r);
            compare(sa, ra);
            compare(sb, rb);
            let ok_s = sample_pair(&src3, w, h, &spec, sa, sb);
            let ok_r = sample_field_2d(&src3, w, h, &spec, &field, ra, rb);
            assert_eq!(ok_s, ok_r);
            compare(sa, ra);
            compare(sb, rb);
        }
        assert!(n_nan > 0);
        worst
    }

    /// The separable sampler equals the 2D interpolation when the vertical displacement does
    /// not change along x (every tap column then has the exact vertical position: f32
    /// rounding only, the image is ~1000 counts), and otherwise differs by an amount
    /// proportional to that change (the second-order term of [`sample_field_sep`]).
    #[test]
    fn separable_field_windows_match_2d_interpolation() {
        let exact = separable_vs_2d(0.01, 0.0);
        assert!(exact < 2e-3, "{exact}");
        let e1 = separable_vs_2d(0.01, -0.006);
        let e2 = separable_vs_2d(0.01, -0.003);
        let ratio = e1 / e2;
        assert!((1.7..2.3).contains(&ratio), "{e1} {e2}");
        // 0.006 px/px: below a 2e-3 px shift of the 360 counts/px steepest slope
        assert!(e1 < 0.72, "{e1}");
    }

    #[test]
    fn bicubic_reproduces_quadratic_inside() {
        let a = Array2::from_shape_fn((20, 20), |(y, x)| {
            (0.1 * (x as f64) * (x as f64) + 2.0 * y as f64) as f32
        });
        let img = Img::new(a.view(), "a").unwrap();
        let v = img.bicubic(7.3, 9.6);
        let exact = 0.1 * 7.3f64 * 7.3 + 2.0 * 9.6;
        // Keys a=-0.5 is third-order accurate: exact for quadratics
        assert!((v as f64 - exact).abs() < 1e-3, "{v} {exact}");
    }

    #[test]
    fn bspline_coefficients_interpolate_the_pixels() {
        let a = Array2::from_shape_fn((13, 17), |(y, x)| {
            ((x * 7 + y * 3) % 11) as f32 + 0.5 * y as f32
        });
        let img = Img::new(a.view(), "a").unwrap();
        let c = bspline_coeffs(&img);
        for y in 2..11 {
            for x in 2..15 {
                let v = c.interp(x as f64, y as f64, bspline_weights);
                assert!((v - a[[y, x]]).abs() < 1e-3, "{x} {y} {v} {}", a[[y, x]]);
            }
        }
        let w = bspline_weights(0.37);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn quintic_bspline_interpolates_and_reproduces_polynomials() {
        let poly = |x: f64, y: f64| 0.02 * x * x * x - 0.3 * x * y + 0.5 * y * y + 2.0 * x + 7.0;
        let a = Array2::from_shape_fn((40, 48), |(y, x)| poly(x as f64, y as f64) as f32);
        let img = Img::new(a.view(), "a").unwrap();
        let c = bspline5_coeffs(&img);
        // exact at the pixels (also at the border: mirror boundaries)
        for y in 0..40 {
            for x in 0..48 {
                let v = c.interp(x as f64, y as f64, bspline5_weights);
                let e = a[[y, x]];
                assert!((v - e).abs() < 2e-3 * e.abs().max(1.0), "{x} {y} {v} {e}");
            }
        }
        // between the pixels, away from the border: cubic polynomials are reproduced (the
        // mirror boundary's influence decays as 0.43^k)
        for &(x, y) in &[(20.3, 17.6), (24.5, 20.5), (30.9, 15.05), (17.25, 25.75)] {
            let v = c.interp(x, y, bspline5_weights) as f64;
            let e = poly(x, y);
            assert!((v - e).abs() < 1e-3 * e.abs(), "{x} {y} {v} {e}");
        }
        let w = bspline5_weights(0.37);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert_eq!(bspline5_weights(0.0)[5], 0.0);
        // first moment: the weights reproduce the position
        let m: f32 = w
            .iter()
            .enumerate()
            .map(|(k, wk)| (k as f32 - 2.0) * wk)
            .sum();
        assert!((m - 0.37).abs() < 1e-6, "{m}");
    }

    #[test]
    fn interpolation_near_the_border_is_mirrored_not_zero() {
        let a = Array2::from_elem((12, 12), 100.0f32);
        let img = Img::new(a.view(), "a").unwrap();
        for c in [bspline5_coeffs(&img), bspline_coeffs(&img)] {
            for &(x, y) in &[(-0.5, 3.0), (0.2, -0.4), (11.5, 11.3), (5.5, 11.49)] {
                let v5 = c.interp(x, y, bspline5_weights);
                let v3 = c.interp(x, y, bspline_weights);
                assert!((v5 - 100.0).abs() < 1e-3 || (v3 - 100.0).abs() < 1e-3);
            }
        }
        let c5 = bspline5_coeffs(&img);
        assert!((c5.interp(-0.5, -0.5, bspline5_weights) - 100.0).abs() < 1e-3);
        assert!((img.bicubic(-0.5, 11.5) - 100.0).abs() < 1e-3);
        assert_eq!(mirror(-1, 5), 1);
        assert_eq!(mirror(5, 5), 3);
        assert_eq!(mirror(-9, 5), 1);
        assert_eq!(mirror(3, 1), 0);
    }

    #[test]
    fn window_average_keeps_linear_fields_and_averages_noise() {
        let grid = crate::grid::Grid::for_windows(200, 120, 32, 32, 0.5).unwrap();
        let lin = |x: f64, y: f64| 0.01 * x - 0.02 * y + 1.0;
        let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            let (x, y) = grid.xy(j, i);
            lin(x, y)
        });
        let f = GridField {
            grid,
            u: u.clone(),
            v: -u.clone(),
        };
        let g = f.window_average(32, 32);
        // interior nodes: the top-hat mean of a linear function is its centre value
        for j in 1..grid.ny - 1 {
            for i in 1..grid.nx - 1 {
                assert!((g.u[[j, i]] - u[[j, i]]).abs() < 1e-12);
                assert!((g.v[[j, i]] + u[[j, i]]).abs() < 1e-12);
            }
        }
        // 32 px windows on a 16 px grid: weights 1/4, 1/2, 1/4 per axis
        let w = tophat_weights(32.0, 16.0, 5);
        assert_eq!(w, vec![(-1, 0.25), (0, 0.5), (1, 0.25)]);
        let w = tophat_weights(32.0, 24.0, 5);
        assert!((w.iter().map(|p| p.1).sum::<f64>() - 1.0).abs() < 1e-12);
        assert_eq!(tophat_weights(32.0, 16.0, 1), vec![(0, 1.0)]);
    }

    #[test]
    fn separable_deformation_matches_the_2d_interpolation() {
        let (h, w) = (64, 80);
        let a = Array2::from_shape_fn((h, w), |(y, x)| {
            let (x, y) = (x as f64, y as f64);
            (1000.0 + 400.0 * (0.9 * x).sin() * (0.7 * y + 0.3).cos() + 3.0 * x) as f32
        });
        let img = Img::new(a.view(), "a").unwrap();
        let c = bspline5_coeffs(&img);
        let grid = crate::grid::Grid::for_windows(w, h, 16, 16, 0.5).unwrap();
        // a smooth field of a few px varying by up to 0.02 px/px
        let field = |x: f64, y: f64| (3.0 + 0.02 * y, -1.2 + 0.015 * x);
        let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            let (x, y) = grid.xy(j, i);
            field(x, y).0
        });
        let v = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            let (x, y) = grid.xy(j, i);
            field(x, y).1
        });
        let f = GridField { grid, u, v };
        let (da, db) = deform_pair(&c, &c, bspline5_weights, &f);
        let (mut worst, mut n) = (0.0f32, 0);
        let (x_in, y_in) = (
            grid.x0 + 3.0..=grid.x0 + (grid.nx - 1) as f64 * grid.dx - 3.0,
            grid.y0 + 3.0..=grid.y0 + (grid.ny - 1) as f64 * grid.dy - 3.0,
        );
        for y in 0..h {
            for x in 0..w {
                if !(x_in.contains(&(x as f64)) && y_in.contains(&(y as f64))) {
                    continue;
                }
                let (fu, fv) = f.at(x as f64, y as f64);
                let (xa, ya) = (x as f64 - fu / 2.0, y as f64 - fv / 2.0);
                let (xb, yb) = (x as f64 + fu / 2.0, y as f64 + fv / 2.0);
                let (ga, gb) = (da.slice()[y * w + x], db.slice()[y * w + x]);
                if inside(xa, ya, w, h) {
                    let e = c.interp(xa, ya, bspline5_weights);
                    worst = worst.max((ga - e).abs());
                    n += 1;
                } else {
                    assert!(ga.is_nan());
                }
                if inside(xb, yb, w, h) {
                    let e = c.interp(xb, yb, bspline5_weights);
                    worst = worst.max((gb - e).abs());
                } else {
                    assert!(gb.is_nan());
                }
            }
        }
        // the separable passes sample the N tap columns at y positions that vary by
        // d(f_y/2)/dx per px: an error of about d(f_y/2)/dx * var(beta5) * d2A/dxdy (0.0075 *
        // 0.5 * 252 = 0.95 counts here, a shear of 5e-4 of the pattern, the same and opposite in
        // both frames; the 2D interpolation's own error against the analytic image is larger)
        let bound = 0.0075 * 0.5 * 400.0 * 0.9 * 0.7;
        assert!(n > 1500 && (worst as f64) < 1.25 * bound, "{n} {worst}");
    }

    #[test]
    fn rejects_nan() {
        let mut a = Array2::<f32>::zeros((4, 4));
        a[[1, 2]] = f32::NAN;
        assert!(Img::new(a.view(), "frame_a").is_err());
    }
}
