//! Image access for the correlator: a borrowed, row-contiguous view of `u8`, `u16`, `f32` or
//! `f64` pixels (no copy when the caller's array is in standard layout), and the window
//! samplers (integer copy, constant sub-pixel shift, per-pixel deformation) with separable
//! interpolation kernels: quintic B-spline (6 x 6 coefficients, the default of the PIV
//! engine), cubic B-spline or Keys bicubic (a = -0.5, 4 x 4 pixels); taps beyond the image
//! are mirrored (whole-sample symmetric).
//!
//! Files: this one (the view and the spline coefficients), `field` ([`GridField`]), `sample`
//! (window samplers), `deform` (the deformation of a whole frame pair).
//!
//! Pixel frame: x = column, y = row, origin at the centre of the top-left pixel, y down.

use crate::error::{PivError, Result};
pub use image_core::kernels::{bspline5_weights, bspline_weights, keys_weights, Weights};
use image_core::kernels::{floor_i, mirror};
use image_core::spline::{prefilter_from, SplineOrder};
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
    let c = prefilter_from(img.slice(), w, h, order);
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

/// Pixels handled together by the vector loops of the deformation and of the window offset's
/// sampler (8 f32 lanes of AVX2).
const LANES: usize = 8;

mod deform;
mod field;
mod sample;
#[cfg(test)]
mod tests;

pub use deform::{deform_pair, into_buffers};
pub use field::GridField;
pub(crate) use sample::sample_shift;
pub use sample::{inside, sample_pair, Source, WindowSpec};
