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

#[cfg(target_arch = "x86_64")]
mod avx2;
mod coords;
mod scalar;
#[cfg(test)]
mod tests;

pub use coords::CoordGrid;
use coords::{ArrayCoords, ExactCoords, RowCoords};
use scalar::{contiguous, interp_row_best};

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
