//! The standard uncertainty of a correlation peak from the correlation statistics of its
//! window pair (Wieneke 2015).

use super::Correlator;

impl Correlator {
    /// The standard uncertainty `(sigma_dx, sigma_dy)` (px) of the sub-pixel peak at the plane
    /// position `(c, r)` (lag `(c - cw/2, r - ch/2)`) from the correlation statistics of the
    /// window pair (Wieneke 2015, Meas. Sci. Technol. 26 074002).
    ///
    /// Each pixel of the overlap of A (its mean removed, as B's: `ca`, `cb`) with B shifted by
    /// the integer lag `(tx, ty)` contributes `a(x, y) b(x + tx + 1, y + ty)` to the
    /// correlation at `tx + 1` and `a(x + 1, y) b(x + tx, y + ty)` to the one at `tx - 1`; their
    /// difference
    /// `dC_i` is zero for every pixel when B is A shifted by exactly the lag, and noise, loss of
    /// pairs, in-window gradients or interpolation errors make it scatter. The variance of
    /// the peak's asymmetry `C(+1) - C(-1)` is `sigma_C^2 = sum_i (dC_i - mean dC)^2`
    /// (contributions taken as independent); scaled as the plane (by `scale = 1 / sqrt(E_a
    /// E_b)` and the overlap factor of the sub-pixel fit, see [`find_peak`]) and carried through
    /// the 3-point Gaussian estimator to first order (`C(+1)` and `C(-1)` moved by `+-
    /// sigma_C / 2`), it gives `sigma_dx`; likewise along y. The estimate holds best after
    /// deformation, when the residual lag is small (the windows then match but for the
    /// errors); with residuals towards half a pixel (one pass, no deformation) the mismatch
    /// of the sub-pixel shift itself adds to the scatter and the estimate is conservative. For
    /// the 2D Gaussian estimator it is the 3-point one's. NaN where the 3-point fit has no
    /// maximum (a value not positive uses the parabolic fit's own derivative) and where the
    /// overlap is empty. It covers random errors only: a bias (the interpolation's on
    /// under-sampled particles, peak locking) is not in the correlation statistics.
    #[inline(always)]
    pub(super) fn sigma_at(&self, (c, r): (usize, usize), scale: f64) -> (f64, f64) {
        let (w, h) = (self.w, self.h);
        let (cw, ch) = (self.cw, self.ch);
        let tx = c as isize - (cw / 2) as isize;
        let ty = r as isize - (ch / 2) as isize;
        // the overlap of A and B shifted by (tx, ty): x in x0..x1, y in y0..y1 of A
        let (x0, x1) = (
            (-tx).max(0) as usize,
            (w as isize - tx).min(w as isize) as usize,
        );
        let (y0, y1) = (
            (-ty).max(0) as usize,
            (h as isize - ty).min(h as isize) as usize,
        );
        let (a, b) = (&self.ca, &self.cb);
        let bx = |x: usize| (x as isize + tx) as usize;
        let by = |y: usize| (y as isize + ty) as usize;
        let var = |(s, s2, n): (f64, f64, usize)| {
            if n == 0 {
                f64::NAN
            } else {
                (s2 - s * s / n as f64).max(0.0)
            }
        };
        // along x: a(x) b(x + tx + 1) - a(x + 1) b(x + tx), x and x + 1 in the overlap
        let mut acc = (0.0f64, 0.0f64, 0usize);
        if (tx, ty) == (0, 0) && w > 1 {
            // lag 0 (a deformed pair): the whole window as one run, less the pairs that
            // wrap from the end of a row to the start of the next
            let nn = w * h;
            let (mut s, mut s2) = asymmetry_sums(&a[..nn - 1], &a[1..], &b[..nn - 1], &b[1..]);
            for r in 0..h - 1 {
                let i = r * w + w - 1;
                let d = a[i] * b[i + 1] - a[i + 1] * b[i];
                s -= d;
                s2 -= d * d;
            }
            acc = (s as f64, s2 as f64, h * (w - 1));
        } else if x1 > x0 + 1 {
            let m = x1 - x0 - 1;
            for y in y0..y1 {
                let ra = &a[y * w..(y + 1) * w];
                let rb = &b[by(y) * w..(by(y) + 1) * w];
                let (s, s2) = asymmetry_sums(
                    &ra[x0..x0 + m],
                    &ra[x0 + 1..x0 + 1 + m],
                    &rb[bx(x0)..bx(x0) + m],
                    &rb[bx(x0) + 1..bx(x0) + 1 + m],
                );
                acc = (acc.0 + s as f64, acc.1 + s2 as f64, acc.2 + m);
            }
        }
        let vx = var(acc);
        // along y: a(y) b(y + ty + 1) - a(y + 1) b(y + ty)
        let mut acc = (0.0f64, 0.0f64, 0usize);
        if (tx, ty) == (0, 0) && h > 1 {
            let nn = w * h;
            let (s, s2) = asymmetry_sums(&a[..nn - w], &a[w..], &b[..nn - w], &b[w..]);
            acc = (s as f64, s2 as f64, nn - w);
        } else if x1 > x0 {
            let m = x1 - x0;
            for y in y0..y1.saturating_sub(1) {
                let (s, s2) = asymmetry_sums(
                    &a[y * w + x0..y * w + x0 + m],
                    &a[(y + 1) * w + x0..(y + 1) * w + x0 + m],
                    &b[by(y) * w + bx(x0)..by(y) * w + bx(x0) + m],
                    &b[(by(y) + 1) * w + bx(x0)..(by(y) + 1) * w + bx(x0) + m],
                );
                acc = (acc.0 + s as f64, acc.1 + s2 as f64, acc.2 + m);
            }
        }
        let vy = var(acc);
        let (fw, fh) = (w as f64, h as f64);
        let weighted = !self.ovx.is_empty();
        let ox = |c: usize| {
            if weighted {
                self.ovx[c]
            } else {
                1.0 - (c as f64 - (cw / 2) as f64).abs() / fw
            }
        };
        let oy = |r: usize| {
            if weighted {
                self.ovy[r]
            } else {
                1.0 - (r as f64 - (ch / 2) as f64).abs() / fh
            }
        };
        let overlap = ox(c) * oy(r);
        let at = |c: usize, r: usize| self.corr[r * cw + c] as f64 / (ox(c) * oy(r));
        let sx = vx.sqrt() * scale / overlap;
        let sy = vy.sqrt() * scale / overlap;
        (
            sx * gauss3_slope(at(c - 1, r), at(c, r), at(c + 1, r)),
            sy * gauss3_slope(at(c, r - 1), at(c, r), at(c, r + 1)),
        )
    }
}

/// Sum and sum of squares of `a0 b1 - a1 b0` over four slices of one length (8 lanes).
#[inline(always)]
fn asymmetry_sums(a0: &[f32], a1: &[f32], b0: &[f32], b1: &[f32]) -> (f32, f32) {
    let n = a0.len();
    let (a1, b0, b1) = (&a1[..n], &b0[..n], &b1[..n]);
    let (s, s2) = asymmetry_lanes(a0, a1, b0, b1);
    let (mut t, mut t2) = (s.iter().sum::<f32>(), s2.iter().sum::<f32>());
    for i in n / 8 * 8..n {
        let d = a0[i] * b1[i] - a1[i] * b0[i];
        t += d;
        t2 += d * d;
    }
    (t, t2)
}

/// The 8 lanes of [`asymmetry_sums`] over the whole chunks of 8: lane `k` sums the values
/// `8 j + k` (four slices of one length). With AVX the lanes are one register each (the
/// compiler keeps this loop scalar otherwise); the same products, differences and sums in the
/// same order as the portable loop, so bit for bit its result.
#[inline(always)]
fn asymmetry_lanes(a0: &[f32], a1: &[f32], b0: &[f32], b1: &[f32]) -> ([f32; 8], [f32; 8]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU supports AVX (checked just above).
            return unsafe { asymmetry_lanes_avx(a0, a1, b0, b1) };
        }
    }
    asymmetry_lanes_portable(a0, a1, b0, b1)
}

/// [`asymmetry_lanes`] without vector instructions named (the reference of the AVX path).
#[inline(always)]
fn asymmetry_lanes_portable(
    a0: &[f32],
    a1: &[f32],
    b0: &[f32],
    b1: &[f32],
) -> ([f32; 8], [f32; 8]) {
    let mut s = [0.0f32; 8];
    let mut s2 = [0.0f32; 8];
    let chunks = a0
        .chunks_exact(8)
        .zip(a1.chunks_exact(8))
        .zip(b0.chunks_exact(8).zip(b1.chunks_exact(8)));
    for ((p0, p1), (q0, q1)) in chunks {
        for k in 0..8 {
            let d = p0[k] * q1[k] - p1[k] * q0[k];
            s[k] += d;
            s2[k] += d * d;
        }
    }
    (s, s2)
}

/// [`asymmetry_lanes`] in AVX registers (no FMA: each product rounded, as the portable loop).
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn asymmetry_lanes_avx(a0: &[f32], a1: &[f32], b0: &[f32], b1: &[f32]) -> ([f32; 8], [f32; 8]) {
    use std::arch::x86_64::*;
    let n = a0.len() / 8 * 8;
    let (a0, a1, b0, b1) = (&a0[..n], &a1[..n], &b0[..n], &b1[..n]);
    let mut s = _mm256_setzero_ps();
    let mut s2 = _mm256_setzero_ps();
    for i in (0..n).step_by(8) {
        // SAFETY: i + 8 <= n, the length of all four slices (taken just above)
        let (p0, p1, q0, q1) = unsafe {
            (
                _mm256_loadu_ps(a0.as_ptr().add(i)),
                _mm256_loadu_ps(a1.as_ptr().add(i)),
                _mm256_loadu_ps(b0.as_ptr().add(i)),
                _mm256_loadu_ps(b1.as_ptr().add(i)),
            )
        };
        let d = _mm256_sub_ps(_mm256_mul_ps(p0, q1), _mm256_mul_ps(p1, q0));
        s = _mm256_add_ps(s, d);
        s2 = _mm256_add_ps(s2, _mm256_mul_ps(d, d));
    }
    let (mut os, mut os2) = ([0.0f32; 8], [0.0f32; 8]);
    // SAFETY: each array holds 8 f32 (unaligned stores)
    unsafe {
        _mm256_storeu_ps(os.as_mut_ptr(), s);
        _mm256_storeu_ps(os2.as_mut_ptr(), s2);
    }
    (os, os2)
}

/// `|d off / d delta|` of the 3-point estimator [`gauss3`] when `p` moves by `+delta/2` and `m`
/// by `-delta/2` (the asymmetry of the peak changes by `delta`); Gaussian when all values are
/// positive, else parabolic; NaN where the estimator has no maximum.
pub(super) fn gauss3_slope(m: f64, c: f64, p: f64) -> f64 {
    if m > 0.0 && c > 0.0 && p > 0.0 {
        let (lm, lc, lp) = (m.ln(), c.ln(), p.ln());
        let (num, den) = (lm - lp, lm - 2.0 * lc + lp);
        if den >= 0.0 {
            return f64::NAN;
        }
        // off = num / (2 den); d lm = -1 / (2m), d lp = 1 / (2p)
        let dnum = -0.5 / m - 0.5 / p;
        let dden = -0.5 / m + 0.5 / p;
        ((dnum * den - num * dden) / (2.0 * den * den)).abs()
    } else {
        let den = m - 2.0 * c + p;
        if den >= 0.0 {
            return f64::NAN;
        }
        // off = (m - p) / (2 den); d(m - p) = -delta, d den = 0
        (0.5 / den).abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asymmetry_lanes_are_the_portable_loop_bit_for_bit() {
        // slices of every length about the 8-lane chunks, values of mixed signs and scales
        let v = |n: usize, k: u32| -> Vec<f32> {
            (0..n)
                .map(|i| (i as f32 * 0.731 + k as f32).sin() * 1e3f32.powi(k as i32 % 3))
                .collect()
        };
        for n in 0..41 {
            let (a0, a1, b0, b1) = (v(n, 1), v(n, 2), v(n, 3), v(n, 4));
            let (s, s2) = asymmetry_lanes(&a0, &a1, &b0, &b1);
            let (r, r2) = asymmetry_lanes_portable(&a0, &a1, &b0, &b1);
            for k in 0..8 {
                assert_eq!(s[k].to_bits(), r[k].to_bits(), "n {n} lane {k}");
                assert_eq!(s2[k].to_bits(), r2[k].to_bits(), "n {n} lane {k}");
            }
            if n >= 8 {
                assert!(s2.iter().any(|&x| x > 0.0));
            }
        }
    }
}
