//! The correlation plane summed directly (in space) at a few lags: the restricted search of
//! [`Correlator::restricted`], for passes whose windows already follow a predictor.
//!
//! `R(tx, ty) = sum a(x, y) b(x + tx, y + ty) / sqrt(E_a E_b)` (means removed; weighted windows
//! as the FFT's) over the windows' overlap, for `|tx| <= sx + 1`, `|ty| <= sy + 1`: the values
//! the zero-padded FFT of [`Correlator::new`] gives at those lags, summed in another order (they
//! agree to f32 rounding). A's window is held in rows padded with zeros to a multiple of 8
//! values, B's inside a zero border of `sx + 1` columns and `sy + 1` rows, so that every lag
//! is a sum of whole 8-value products with no bounds inside the window (the zeros stand for
//! the pixels outside the overlap). The sum over a lag row runs in 8 lanes per lag, `cw`
//! lags at once (their accumulators in registers for the common plane widths), lanes added
//! pairwise at the end: a fixed order, the same with or without AVX2 (no fused multiply-add).
//!
//! Cost: `cw ch h ceil(w / 8)` 8-lane products, against the FFT's plane of the whole range;
//! for 32 x 8 windows at radius 2 (`7 x 7` lags) a quarter of the work.

use super::Correlator;

/// The shape `(width, rows)` of B's bordered window for `w` x `h` windows and half-ranges
/// `sx`, `sy`.
pub(super) fn direct_shape(w: usize, h: usize, sx: usize, sy: usize) -> (usize, usize) {
    (w.next_multiple_of(8) + 2 * (sx + 1), h + 2 * (sy + 1))
}

impl Correlator {
    /// The normalised plane at lags `|tx| <= sx + 1`, `|ty| <= sy + 1` into `corr`, from the
    /// windows' means `ma`, `mb` and energies `ea`, `eb` (unweighted; those of the weighted
    /// windows are computed here as in the FFT's path); returns the means and the energies
    /// the plane was normalised by.
    #[inline(always)]
    pub(super) fn plane_direct(
        &mut self,
        ma: f32,
        mb: f32,
        ea: f64,
        eb: f64,
    ) -> (f32, f32, f64, f64) {
        let (w, h, sx, sy) = (self.w, self.h, self.sx, self.sy);
        let wp = w.next_multiple_of(8);
        let (dw, _) = direct_shape(w, h, sx, sy);
        let inner = |y: usize| (y + sy + 1) * dw + sx + 1;
        let (ea, eb) = if self.wgt.is_empty() {
            for (row, ra) in self.pa.chunks_exact_mut(wp).zip(self.wa.chunks_exact(w)) {
                for (o, &a) in row.iter_mut().zip(ra) {
                    *o = a - ma;
                }
            }
            for (y, rb) in self.wb.chunks_exact(w).enumerate() {
                for (o, &b) in self.pb[inner(y)..][..w].iter_mut().zip(rb) {
                    *o = b - mb;
                }
            }
            (ea, eb)
        } else {
            let (mut sa, mut sb) = (0.0f64, 0.0f64);
            let rows = self
                .pa
                .chunks_exact_mut(wp)
                .zip(self.wa.chunks_exact(w))
                .zip(self.wb.chunks_exact(w))
                .zip(self.wgt.chunks_exact(w));
            for (y, (((row, ra), rb), rg)) in rows.enumerate() {
                let brow = &mut self.pb[inner(y)..][..w];
                for ((((o, ob), &a), &b), &g) in row.iter_mut().zip(brow).zip(ra).zip(rb).zip(rg) {
                    let (x, z) = ((a - ma) * g, (b - mb) * g);
                    sa += (x * x) as f64;
                    sb += (z * z) as f64;
                    *o = x;
                    *ob = z;
                }
            }
            (sa, sb)
        };
        let norm = (1.0 / (ea * eb).sqrt()) as f32;
        let (pa, pb, ch) = (&self.pa[..wp * h], &self.pb[..], self.ch);
        let corr = &mut self.corr[..self.cw * ch];
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe {
                match self.cw {
                    5 => lag_rows_avx2::<5>(pa, pb, wp, dw, ch, corr, norm),
                    7 => lag_rows_avx2::<7>(pa, pb, wp, dw, ch, corr, norm),
                    9 => lag_rows_avx2::<9>(pa, pb, wp, dw, ch, corr, norm),
                    11 => lag_rows_avx2::<11>(pa, pb, wp, dw, ch, corr, norm),
                    cw => lag_rows(pa, pb, wp, dw, ch, cw, corr, norm),
                }
            }
            return (ma, mb, ea, eb);
        }
        lag_rows(pa, pb, wp, dw, ch, self.cw, corr, norm);
        (ma, mb, ea, eb)
    }
}

/// [`lag_rows`] in AVX2 registers for a plane `CW` lags wide (its accumulators held in
/// registers; the same products and sums in the same order).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn lag_rows_avx2<const CW: usize>(
    pa: &[f32],
    pb: &[f32],
    wp: usize,
    dw: usize,
    ch: usize,
    corr: &mut [f32],
    norm: f32,
) {
    use std::arch::x86_64::*;
    let h = pa.len() / wp;
    // every read below lies inside the slices: A's rows `wp` values, B's rows from column
    // `8 c + t` for 8 values, `t < CW`, in rows up to `h + ch - 2`
    assert!(wp % 8 == 0 && wp + CW - 1 <= dw && pb.len() >= (h + ch - 1) * dw);
    assert!(corr.len() >= ch * CW);
    for r in 0..ch {
        let mut acc = [_mm256_setzero_ps(); CW];
        for y in 0..h {
            // SAFETY: in bounds (asserted above)
            let (ap, bp) = unsafe { (pa.as_ptr().add(y * wp), pb.as_ptr().add((y + r) * dw)) };
            for c in (0..wp).step_by(8) {
                // SAFETY: in bounds (asserted above); unaligned loads
                let a = unsafe { _mm256_loadu_ps(ap.add(c)) };
                for (t, acc) in acc.iter_mut().enumerate() {
                    let b = unsafe { _mm256_loadu_ps(bp.add(c + t)) };
                    *acc = _mm256_add_ps(*acc, _mm256_mul_ps(a, b));
                }
            }
        }
        for (t, acc) in acc.iter().enumerate() {
            let mut l = [0.0f32; 8];
            // SAFETY: `l` holds 8 values
            unsafe { _mm256_storeu_ps(l.as_mut_ptr(), *acc) };
            corr[r * CW + t] = lanes_sum(&l) * norm;
        }
    }
}

/// The `ch` lag rows of `cw` lags each (see the module docs): lag row `r` pairs A's row `y`
/// with B's bordered row `y + r`, lag `t` reads B's row from column `t`; each lag's sum in 8
/// lanes, added pairwise at the end.
#[allow(clippy::too_many_arguments)]
pub(super) fn lag_rows(
    pa: &[f32],
    pb: &[f32],
    wp: usize,
    dw: usize,
    ch: usize,
    cw: usize,
    corr: &mut [f32],
    norm: f32,
) {
    let h = pa.len() / wp;
    let mut acc = vec![[0.0f32; 8]; cw];
    for (r, out) in corr.chunks_exact_mut(cw).take(ch).enumerate() {
        acc.fill([0.0; 8]);
        for (arow, brow) in pa
            .chunks_exact(wp)
            .zip(pb[r * dw..].chunks_exact(dw))
            .take(h)
        {
            for (c, a) in arow.chunks_exact(8).enumerate() {
                for (t, acc) in acc.iter_mut().enumerate() {
                    let b = &brow[8 * c + t..8 * c + t + 8];
                    for l in 0..8 {
                        acc[l] += a[l] * b[l];
                    }
                }
            }
        }
        for (o, acc) in out.iter_mut().zip(&acc) {
            *o = lanes_sum(acc) * norm;
        }
    }
}

/// The 8 lanes added pairwise (a fixed order).
#[inline(always)]
fn lanes_sum(a: &[f32; 8]) -> f32 {
    ((a[0] + a[4]) + (a[2] + a[6])) + ((a[1] + a[5]) + (a[3] + a[7]))
}
