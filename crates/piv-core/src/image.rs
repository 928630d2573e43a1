//! Image access for the correlator: a borrowed, row-contiguous view of `u8`, `u16`, `f32` or
//! `f64` pixels (no copy when the caller's array is in standard layout), and the window
//! samplers (integer copy, constant sub-pixel shift, per-pixel deformation) with bicubic
//! interpolation (Keys, a = -0.5, 16 neighbours, zero outside the image).
//!
//! Pixel frame: x = column, y = row, origin at the centre of the top-left pixel, y down.

use crate::error::{PivError, Result};
use ndarray::{ArrayView2, CowArray, Ix2};
use rayon::prelude::*;

/// A pixel type the engine reads without conversion of the whole image.
pub trait Pixel: Copy + Send + Sync + 'static {
    /// The value as `f32`.
    fn to_f32(self) -> f32;
    /// `false` for NaN or infinite values (always `true` for integers).
    fn is_finite_px(self) -> bool {
        true
    }
}

impl Pixel for u8 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Pixel for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Pixel for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn is_finite_px(self) -> bool {
        self.is_finite()
    }
}
impl Pixel for f64 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn is_finite_px(self) -> bool {
        self.is_finite()
    }
}

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

    /// Keys bicubic value at a real position (zero outside the image).
    #[inline(always)]
    pub fn bicubic(&self, x: f64, y: f64) -> f32 {
        self.interp(x, y, keys_weights)
    }

    /// Value at a real position with the 4 x 4 kernel `wf` (zero outside the image).
    #[inline(always)]
    pub fn interp(&self, x: f64, y: f64, wf: Weights) -> f32 {
        let fx = x.floor();
        let fy = y.floor();
        let wx = wf((x - fx) as f32);
        let wy = wf((y - fy) as f32);
        let ix = fx as isize - 1;
        let iy = fy as isize - 1;
        self.taps(ix, iy, &wx, &wy)
    }

    /// Apply separable weights to the 4 x 4 neighbourhood whose top-left pixel is (ix, iy).
    #[inline(always)]
    fn taps(&self, ix: isize, iy: isize, wx: &[f32; 4], wy: &[f32; 4]) -> f32 {
        let w = self.width as isize;
        let h = self.height as isize;
        if ix >= 0 && iy >= 0 && ix + 3 < w && iy + 3 < h {
            let s = self.slice();
            let mut acc = 0.0f32;
            for (r, wyr) in wy.iter().enumerate() {
                let base = (iy as usize + r) * self.width + ix as usize;
                let row = &s[base..base + 4];
                let v = wx[0] * row[0].to_f32()
                    + wx[1] * row[1].to_f32()
                    + wx[2] * row[2].to_f32()
                    + wx[3] * row[3].to_f32();
                acc += wyr * v;
            }
            acc
        } else {
            let mut acc = 0.0f32;
            for (r, wyr) in wy.iter().enumerate() {
                let mut v = 0.0f32;
                for (c, wxc) in wx.iter().enumerate() {
                    v += wxc * self.get(ix + c as isize, iy + r as isize);
                }
                acc += wyr * v;
            }
            acc
        }
    }
}

/// A separable 4-tap interpolation kernel: weights of floor-1 .. floor+2 for fraction `t`.
pub type Weights = fn(f32) -> [f32; 4];

/// Keys cubic convolution weights (a = -0.5) for the four neighbours floor-1 .. floor+2 of a
/// position whose fractional part is `t` in [0, 1).
#[inline(always)]
pub fn keys_weights(t: f32) -> [f32; 4] {
    // a = -0.5
    let t2 = t * t;
    let t3 = t2 * t;
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// Cubic B-spline interpolation weights for the four neighbours floor-1 .. floor+2 of a
/// position with fractional part `t`; apply them to the coefficients of [`bspline_coeffs`].
#[inline(always)]
pub fn bspline_weights(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    let s = 1.0 - t;
    [
        s * s * s / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
        t3 / 6.0,
    ]
}

const BSPLINE_Z: f32 = -0.267_949_2; // sqrt(3) - 2

fn prefilter_1d(c: &mut [f32]) {
    let n = c.len();
    if n < 2 {
        return;
    }
    let z = BSPLINE_Z;
    let horizon = n.min(12);
    let mut acc = 0.0f32;
    let mut zk = 1.0f32;
    for v in c.iter().take(horizon) {
        acc += zk * v;
        zk *= z;
    }
    c[0] = acc;
    for k in 1..n {
        c[k] += z * c[k - 1];
    }
    c[n - 1] = z / (z * z - 1.0) * (c[n - 1] + z * c[n - 2]);
    for k in (0..n - 1).rev() {
        c[k] = z * (c[k + 1] - c[k]);
    }
    for v in c.iter_mut() {
        *v *= 6.0;
    }
}

/// Cubic B-spline coefficients of an image (Unser's recursive prefilter, mirror boundaries):
/// sampling them with [`bspline_weights`] interpolates the image exactly at the pixels. The
/// B-spline's frequency response is far flatter than Keys' kernel, which keeps the sub-pixel
/// window shifts of deformation free of the position bias Keys leaves on 2-3 px particles.
pub fn bspline_coeffs<T: Pixel>(img: &Img<'_, T>) -> Img<'static, f32> {
    let (w, h) = (img.width, img.height);
    let mut c: Vec<f32> = img.slice().par_iter().map(|p| p.to_f32()).collect();
    c.par_chunks_mut(w).for_each(prefilter_1d);
    if h >= 2 {
        let z = BSPLINE_Z;
        const STRIP: usize = 2048;
        // causal initialisation: row 0 = sum_k z^k row k
        let horizon = h.min(12);
        let (first, rest) = c.split_at_mut(w);
        first.par_chunks_mut(STRIP).enumerate().for_each(|(s, f)| {
            let mut zk = z;
            for k in 1..horizon {
                let row = &rest[(k - 1) * w + s * STRIP..(k - 1) * w + s * STRIP + f.len()];
                for (a, b) in f.iter_mut().zip(row) {
                    *a += zk * b;
                }
                zk *= z;
            }
        });
        for y in 1..h {
            let (prev, cur) = c[(y - 1) * w..(y + 1) * w].split_at_mut(w);
            cur.par_chunks_mut(STRIP)
                .zip(prev.par_chunks(STRIP))
                .for_each(|(a, b)| {
                    for (x, p) in a.iter_mut().zip(b) {
                        *x += z * p;
                    }
                });
        }
        {
            let (prev, last) = c[(h - 2) * w..h * w].split_at_mut(w);
            let g = z / (z * z - 1.0);
            last.par_chunks_mut(STRIP)
                .zip(prev.par_chunks(STRIP))
                .for_each(|(a, b)| {
                    for (x, p) in a.iter_mut().zip(b) {
                        *x = g * (*x + z * p);
                    }
                });
        }
        for y in (0..h - 1).rev() {
            let (cur, next) = c[y * w..(y + 2) * w].split_at_mut(w);
            cur.par_chunks_mut(STRIP)
                .zip(next.par_chunks(STRIP))
                .for_each(|(a, b)| {
                    for (x, n) in a.iter_mut().zip(b) {
                        *x = z * (n - *x);
                    }
                });
        }
        c.par_chunks_mut(1 << 16)
            .for_each(|ch| ch.iter_mut().for_each(|x| *x *= 6.0));
    }
    let arr = ndarray::Array2::from_shape_vec((h, w), c).expect("shape");
    Img {
        data: CowArray::from(arr),
        width: w,
        height: h,
    }
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
            let i = t.floor() as usize;
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
pub struct Source<'s, 'a, 'c, T: Pixel, U: Pixel> {
    pub a: &'s Img<'a, T>,
    pub b: &'s Img<'a, T>,
    pub ia: &'s Img<'c, U>,
    pub ib: &'s Img<'c, U>,
    pub wf: Weights,
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

/// Sample the window pair into `wa`, `wb` (row-major, `h` rows of `w`). Returns `false` when
/// the sample position of any pixel of either window (after offset and deformation) lies
/// outside the image (see [`inside`]): such a window pair must not be correlated (its samples
/// outside are zeros).
pub fn sample_pair<T: Pixel, U: Pixel>(
    src: &Source<'_, '_, '_, T, U>,
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
            let ok = inside(ax, ay, iw, ih)
                && inside(ax + rw, ay + rh, iw, ih)
                && inside(bx, by, iw, ih)
                && inside(bx + rw, by + rh, iw, ih);
            if !ok {
                return false;
            }
            sample_shift(src.a, src.ia, src.wf, w, h, ax, ay, wa);
            sample_shift(src.b, src.ib, src.wf, w, h, bx, by, wb);
            true
        }
        Some(f) => {
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
                    ok &= inside(x - hu, y - hv, iw, ih) && inside(x + hu, y + hv, iw, ih);
                    *oa = src.ia.interp(x - hu, y - hv, src.wf);
                    *ob = src.ib.interp(x + hu, y + hv, src.wf);
                }
            }
            ok
        }
    }
}

/// Deform a whole frame pair symmetrically by the field `f`: `A'(p) = A(p - f(p)/2)`,
/// `B'(p) = B(p + f(p)/2)`, sampled from `ia`, `ib` with kernel `wf` (rows in parallel). Windows
/// of a regular grid are then plain copies of the deformed images, which costs one
/// interpolation per pixel instead of one per pixel and overlapping window. A pixel whose
/// source position lies outside its frame (see [`inside`]) is set to NaN, so that a window
/// containing it fails to correlate (its energy is not finite) instead of correlating zeros.
pub fn deform_pair<U: Pixel>(
    ia: &Img<'_, U>,
    ib: &Img<'_, U>,
    wf: Weights,
    f: &GridField,
) -> (Img<'static, f32>, Img<'static, f32>) {
    let (w, h) = (ia.width, ia.height);
    let mut da = vec![0.0f32; w * h];
    let mut db = vec![0.0f32; w * h];
    da.par_chunks_mut(w)
        .zip(db.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (ra, rb))| {
            let yf = y as f64;
            let row = f.row(yf);
            for (x, (oa, ob)) in ra.iter_mut().zip(rb.iter_mut()).enumerate() {
                let xf = x as f64;
                let (fu, fv) = f.at_row(&row, xf);
                let (hu, hv) = (0.5 * fu, 0.5 * fv);
                let (xa, ya, xb, yb) = (xf - hu, yf - hv, xf + hu, yf + hv);
                *oa = if inside(xa, ya, w, h) {
                    ia.interp(xa, ya, wf)
                } else {
                    f32::NAN
                };
                *ob = if inside(xb, yb, w, h) {
                    ib.interp(xb, yb, wf)
                } else {
                    f32::NAN
                };
            }
        });
    let wrap = |v: Vec<f32>| Img {
        data: CowArray::from(ndarray::Array2::from_shape_vec((h, w), v).expect("shape")),
        width: w,
        height: h,
    };
    (wrap(da), wrap(db))
}

/// Sample a `w` x `h` window whose top-left pixel sits at (x0, y0) (constant shift): straight
/// from `img` at integer positions, else from `interp` with kernel `wf`.
fn sample_shift<T: Pixel, U: Pixel>(
    img: &Img<'_, T>,
    interp: &Img<'_, U>,
    wf: Weights,
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
    let (ix, iy) = (fx as isize, fy as isize);
    for r in 0..h {
        for c in 0..w {
            out[r * w + c] = interp.taps(ix + c as isize - 1, iy + r as isize - 1, &wx, &wy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn keys_weights_sum_to_one_and_interpolate() {
        for k in 0..10 {
            let t = k as f32 / 10.0;
            let w = keys_weights(t);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            // reproduces a linear function exactly
            let lin: f32 = -w[0] + w[2] + w[3] * 2.0;
            assert!((lin - t).abs() < 1e-6);
        }
        assert_eq!(keys_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
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
    fn rejects_nan() {
        let mut a = Array2::<f32>::zeros((4, 4));
        a[[1, 2]] = f32::NAN;
        assert!(Img::new(a.view(), "frame_a").is_err());
    }
}
