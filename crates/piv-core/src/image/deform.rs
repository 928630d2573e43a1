//! The deformation of a whole frame pair by a displacement field ([`deform_pair`]).
//!
//! Each output row is built in phases over arrays (positions, integer bases and fractions,
//! the kernel's weights for every pixel of the row, then the taps), so that the weights, the
//! costliest part (a quintic B-spline weight set is ~20 flops), are computed by vector
//! instructions, and 8-pixel chunks whose taps start on the same source row (column pass) or
//! at the same offset (row pass) read contiguous values per tap; on x86-64 with AVX2 and FMA
//! the row is compiled for them (runtime detection; the same code and the same rounding as the
//! portable path: no fused multiply-adds are formed, tested bit for bit).

use super::field::*;
use super::sample::inside;
use super::{Img, Pixel, LANES};
use image_core::kernels::{int_of_whole, mirror};
use image_core::zeroed_frame;
use ndarray::CowArray;
use rayon::prelude::*;

/// `A'(p) = A(p - f(p)/2)` and `B'(p) = B(p + f(p)/2)`, sampled from `ia`, `ib` with kernel `wf`
/// (rows in parallel). Windows of a regular grid are then plain copies of the deformed images,
/// which costs one interpolation per pixel instead of one per pixel and overlapping window. A
/// pixel whose source position lies outside its frame (see [`inside`]) is set to NaN, as in
/// [`super::sample_pair`].
///
/// The separable kernel is applied in two 1D passes per output row (`2 N` taps per pixel
/// instead of `N^2`): first every column `i` of the source is interpolated along y at
/// `y -+ f_y(i +- f_x(i)/2)/2`, the vertical displacement of the output pixel whose source
/// column is `i`; then the row of these values is interpolated along x at `x -+ f_x(x)/2`.
/// This equals the 2D interpolation up to the change of the field across the `N` taps times
/// the displacement (second order: below 1e-4 px for a field varying by 0.01 px/px).
///
/// `reuse`: the buffers of an earlier deformed pair of the same size (see [`into_buffers`]),
/// written over instead of allocating (every pixel is written): a fresh 190 MB frame costs
/// its page faults and the kernel's zeroing, more than a tenth of a 47 MP pass.
pub fn deform_pair<U: Pixel, W: Fn(f32) -> [f32; N] + Copy + Sync, const N: usize>(
    ia: &Img<'_, U>,
    ib: &Img<'_, U>,
    wf: W,
    f: &GridField,
    reuse: Option<(Vec<f32>, Vec<f32>)>,
) -> (Img<'static, f32>, Img<'static, f32>) {
    deform_pair_with(ia, ib, wf, f, reuse, simd_available())
}

/// The pixel buffers of a deformed pair, for the `reuse` of the next [`deform_pair`] (the
/// images [`deform_pair`] returns own their pixels, which are handed over without a copy;
/// `None` if the data does not start at the buffer's beginning).
pub fn into_buffers(pair: (Img<'static, f32>, Img<'static, f32>)) -> Option<(Vec<f32>, Vec<f32>)> {
    let own = |img: Img<'static, f32>| {
        let (v, off) = img.data.into_owned().into_raw_vec_and_offset();
        (off == Some(0) || v.is_empty()).then_some(v)
    };
    Some((own(pair.0)?, own(pair.1)?))
}

/// [`deform_pair`] with the vector path on or off (`simd` is honoured only where available).
pub(crate) fn deform_pair_with<U: Pixel, W: Fn(f32) -> [f32; N] + Copy + Sync, const N: usize>(
    ia: &Img<'_, U>,
    ib: &Img<'_, U>,
    wf: W,
    f: &GridField,
    reuse: Option<(Vec<f32>, Vec<f32>)>,
    simd: bool,
) -> (Img<'static, f32>, Img<'static, f32>) {
    let (w, h) = (ia.width, ia.height);
    let (mut da, mut db) = match reuse {
        Some((a, b)) if a.len() == w * h && b.len() == w * h => (a, b),
        _ => (zeroed_frame(w * h), zeroed_frame(w * h)),
    };
    let g = &f.grid;
    // the x interpolation state of every column, shared by all rows
    let cols: Vec<(usize, usize, f64)> = (0..w)
        .map(|x| GridField::axis(x as f64, g.x0, g.dx, g.nx))
        .collect();
    let simd = simd && simd_available();
    da.par_chunks_mut(w)
        .zip(db.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || Row::new(g.nx, w, N),
            |row, (y, (ra, rb))| {
                let job = RowJob {
                    ia,
                    ib,
                    wf,
                    f,
                    cols: &cols,
                    y,
                };
                #[cfg(target_arch = "x86_64")]
                if simd {
                    // SAFETY: simd_available() checked AVX2 and FMA at run time.
                    unsafe { deform_row_avx2(&job, row, ra, rb) };
                    return;
                }
                let _ = simd;
                deform_row(&job, row, ra, rb);
            },
        );
    let wrap = |v: Vec<f32>| Img {
        data: CowArray::from(ndarray::Array2::from_shape_vec((h, w), v).expect("shape")),
        width: w,
        height: h,
    };
    (wrap(da), wrap(db))
}

/// AVX2 and FMA present (x86-64 only).
fn simd_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// What one output row needs (shared by the rows).
struct RowJob<'j, 'a, 'b, U: Pixel, W, const N: usize> {
    ia: &'j Img<'a, U>,
    ib: &'j Img<'b, U>,
    wf: W,
    f: &'j GridField,
    cols: &'j [(usize, usize, f64)],
    y: usize,
}

/// Per-thread scratch of one output row (no allocation per row).
struct Row {
    /// Half the field at this row, at every grid column.
    ur: Vec<f64>,
    vr: Vec<f64>,
    /// The column indices as `f64` (`0, 1, .. w - 1`: the loops over them vectorise).
    colx: Vec<f64>,
    /// Half the field at every pixel of the row.
    hu: Vec<f64>,
    hv: Vec<f64>,
    /// Sample positions, their first tap and the kernel's weights (`k * width + i`).
    pos: Vec<f64>,
    base: Vec<isize>,
    frac: Vec<f32>,
    weights: Vec<f32>,
    /// The source columns interpolated along y (frames A and B).
    ta: Vec<f32>,
    tb: Vec<f32>,
    /// Sample position inside the frame (the row pass).
    inside: Vec<bool>,
}

impl Row {
    fn new(nx: usize, w: usize, n: usize) -> Row {
        Row {
            ur: vec![0.0; nx],
            vr: vec![0.0; nx],
            colx: (0..w).map(|x| x as f64).collect(),
            hu: vec![0.0; w],
            hv: vec![0.0; w],
            pos: vec![0.0; w],
            base: vec![0; w],
            frac: vec![0.0; w],
            weights: vec![0.0; n * w],
            ta: vec![0.0; w],
            tb: vec![0.0; w],
            inside: vec![false; w],
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn deform_row_avx2<U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
    job: &RowJob<'_, '_, '_, U, W, N>,
    row: &mut Row,
    ra: &mut [f32],
    rb: &mut [f32],
) {
    deform_row(job, row, ra, rb)
}

/// One output row of both deformed frames (see [`deform_pair`]).
#[inline(always)]
fn deform_row<U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
    job: &RowJob<'_, '_, '_, U, W, N>,
    row: &mut Row,
    ra: &mut [f32],
    rb: &mut [f32],
) {
    let (f, g) = (job.f, &job.f.grid);
    let (w, h) = (job.ia.width, job.ia.height);
    let yf = job.y as f64;
    let (us, vs) = (
        f.u.as_slice().expect("standard layout"),
        f.v.as_slice().expect("standard layout"),
    );
    // half the field interpolated to this row at every grid column, then at every pixel
    let (j0, j1, ty) = f.row(yf);
    for i in 0..g.nx {
        let (k0, k1) = (j0 * g.nx + i, j1 * g.nx + i);
        row.ur[i] = 0.5 * (us[k0] * (1.0 - ty) + us[k1] * ty);
        row.vr[i] = 0.5 * (vs[k0] * (1.0 - ty) + vs[k1] * ty);
    }
    let (ur, vr) = (&row.ur, &row.vr);
    let half = |&(i0, i1, tx): &(usize, usize, f64)| {
        (
            ur[i0] * (1.0 - tx) + ur[i1] * tx,
            vr[i0] * (1.0 - tx) + vr[i1] * tx,
        )
    };
    for (x, c) in job.cols.iter().enumerate() {
        (row.hu[x], row.hv[x]) = half(c);
    }
    // GridField::axis without its branches: the grid coordinate clamped to [0, nx - 1] gives
    // the same indices and weight inside, and at or beyond the ends the end value with the
    // weight 0 on a neighbour (which can only change the sign of a zero, lost when added to
    // the row's y below)
    let last = (g.nx - 1) as f64;
    let (x0, dx) = (g.x0, g.dx);
    // 1. every source column along y: frame A at y - f_y(i + f_x/2)/2, B at y + f_y(i - f_x/2)/2
    let sources = [
        (job.ia.slice(), -1.0, &mut row.ta),
        (job.ib.slice(), 1.0, &mut row.tb),
    ];
    for (s, sign, out) in sources {
        // the grid coordinates first (a loop of divisions that vectorises), then the field
        for ((p, &xi), &hu) in row.pos.iter_mut().zip(&row.colx).zip(&row.hu) {
            *p = (xi - sign * hu - x0) / dx;
        }
        for p in row.pos.iter_mut() {
            let t = p.max(0.0).min(last);
            let f = t.floor();
            let i0 = int_of_whole(f) as usize; // 0 ..= nx - 1
            let i1 = (i0 + 1).min(g.nx - 1);
            let tx = t - f;
            *p = yf + sign * (vr[i0] * (1.0 - tx) + vr[i1] * tx);
        }
        split(&row.pos, &mut row.base, &mut row.frac, N);
        weights_of(job.wf, &row.frac, &mut row.weights);
        let (base, weights) = (&row.base, &row.weights);
        let column = |i: usize| {
            let j0 = base[i];
            let mut acc = 0.0f32;
            if j0 >= 0 && j0 as usize + N <= h {
                let b = j0 as usize * w + i;
                for k in 0..N {
                    acc += weights[k * w + i] * s[b + k * w].to_f32();
                }
            } else {
                for k in 0..N {
                    let r = mirror(j0 + k as isize, h);
                    acc += weights[k * w + i] * s[r * w + i].to_f32();
                }
            }
            acc
        };
        // LANES columns whose taps start on the same row read LANES contiguous values per tap
        for (c, chunk) in out.chunks_mut(LANES).enumerate() {
            let i = c * LANES;
            let j0 = base[i];
            let same = chunk.len() == LANES
                && j0 >= 0
                && j0 as usize + N <= h
                && base[i..i + LANES].iter().all(|&b| b == j0);
            if same {
                let mut acc = [0.0f32; LANES];
                for k in 0..N {
                    let src = &s[(j0 as usize + k) * w + i..][..LANES];
                    let wk = &weights[k * w + i..][..LANES];
                    for l in 0..LANES {
                        acc[l] += wk[l] * src[l].to_f32();
                    }
                }
                chunk.copy_from_slice(&acc);
            } else {
                for (l, o) in chunk.iter_mut().enumerate() {
                    *o = column(i + l);
                }
            }
        }
    }
    // 2. the row along x: frame A at x - f_x/2, B at x + f_x/2 (NaN outside the frame)
    for (t, sign, out) in [(&row.ta, -1.0, &mut *ra), (&row.tb, 1.0, &mut *rb)] {
        for ((p, &xi), &hu) in row.pos.iter_mut().zip(&row.colx).zip(&row.hu) {
            *p = xi + sign * hu;
        }
        split(&row.pos, &mut row.base, &mut row.frac, N);
        weights_of(job.wf, &row.frac, &mut row.weights);
        for ((ok, &p), &hv) in row.inside.iter_mut().zip(&row.pos).zip(&row.hv) {
            *ok = inside(p, yf + sign * hv, w, h);
        }
        let (base, weights, ok) = (&row.base, &row.weights, &row.inside);
        let pixel = |x: usize| {
            if !ok[x] {
                return f32::NAN;
            }
            let i0 = base[x];
            let mut acc = 0.0f32;
            if i0 >= 0 && i0 as usize + N <= w {
                let b = i0 as usize;
                for k in 0..N {
                    acc += weights[k * w + x] * t[b + k];
                }
            } else {
                for k in 0..N {
                    acc += weights[k * w + x] * t[mirror(i0 + k as isize, w)];
                }
            }
            acc
        };
        // LANES pixels inside the frame whose taps start at the same offset from them read
        // LANES contiguous values per tap
        for (c, chunk) in out.chunks_mut(LANES).enumerate() {
            let x = c * LANES;
            let i0 = base[x];
            let same = chunk.len() == LANES
                && i0 >= 0
                && i0 as usize + LANES - 1 + N <= w
                && (0..LANES).all(|l| ok[x + l] && base[x + l] == i0 + l as isize);
            if same {
                let mut acc = [0.0f32; LANES];
                for k in 0..N {
                    let src = &t[i0 as usize + k..][..LANES];
                    let wk = &weights[k * w + x..][..LANES];
                    for l in 0..LANES {
                        acc[l] += wk[l] * src[l];
                    }
                }
                chunk.copy_from_slice(&acc);
            } else {
                for (l, o) in chunk.iter_mut().enumerate() {
                    *o = pixel(x + l);
                }
            }
        }
    }
}

/// First tap `floor(p) - (N/2 - 1)` and fraction `p - floor(p)` of every position (the floor
/// through [`int_of_whole`], which vectorises; a NaN position gives a NaN fraction, hence NaN
/// weights and a NaN sample, whatever its tap).
#[inline(always)]
fn split(pos: &[f64], base: &mut [isize], frac: &mut [f32], n: usize) {
    let back = (n / 2 - 1) as isize;
    for ((p, b), t) in pos.iter().zip(base.iter_mut()).zip(frac.iter_mut()) {
        let f = p.floor();
        *b = int_of_whole(f) - back;
        *t = (*p - f) as f32;
    }
}

/// The kernel's `N` weights of every fraction, stored `weights[k * len + i]` (one array per
/// tap: the loop over the pixels vectorises).
#[inline(always)]
fn weights_of<W: Fn(f32) -> [f32; N], const N: usize>(wf: W, frac: &[f32], weights: &mut [f32]) {
    let len = frac.len();
    let weights = &mut weights[..N * len];
    for (i, &t) in frac.iter().enumerate() {
        let wv = wf(t);
        for k in 0..N {
            weights[k * len + i] = wv[k];
        }
    }
}
