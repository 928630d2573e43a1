//! image-core: the image kernels that rspiv's cores share, kept once.
//!
//! - [`pixel`]: the one pixel trait ([`Pixel`]) every core reads images through (`u8`, `u16`,
//!   `f32`, `f64`);
//! - [`kernels`]: separable interpolation kernels (Keys cubic convolution, cubic and quintic
//!   B-splines) and the index helpers of their borders (floor, mirror);
//! - [`spline`]: Unser's recursive B-spline prefilter (mirror boundaries), whose coefficients the
//!   B-spline kernels interpolate;
//! - [`fft`]: FFT sizing (the next 5-smooth length);
//! - [`buffer`]: whole-frame scratch buffers that are cheap to first touch;
//! - [`special`]: the error function and the normal distribution function (renderers).
//!
//! Pixel frame (every crate of rspiv): x = column, y = row, origin at the centre of the top-left
//! pixel, y down; positions in px.
//!
//! Nothing here fails: the kernels are total functions of their inputs (callers check their
//! images), so the crate has no error type.

pub mod buffer;
pub mod fft;
pub mod kernels;
pub mod pixel;
pub mod special;
pub mod spline;

pub use buffer::zeroed_frame;
pub use fft::fast_len;
pub use kernels::{bspline5_weights, bspline_weights, keys_kernel, keys_weights, Weights};
pub use pixel::{Pixel, PixelKind};
pub use special::{erf, normal_cdf};
