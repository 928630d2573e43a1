//! The normalised correlation plane of a window pair: FFT plans cached per padded shape and
//! the correlator's forward transform, cross-spectrum and partial inverse (module docs of
//! [`super`]).

use super::peak::find_peak_with;
use super::{Correlator, Peak, SubPixel, Uncertainty};
use crate::weighting::Weighting;
use image_core::fast_len;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// FFT plans of one padded shape.
pub struct Plans {
    pub pw: usize,
    pub ph: usize,
    fwd_w: Arc<dyn Fft<f32>>,
    fwd_h: Arc<dyn Fft<f32>>,
    inv_w: Arc<dyn Fft<f32>>,
    inv_h: Arc<dyn Fft<f32>>,
    scratch_len: usize,
}

/// The shared, cached plans for a `pw` x `ph` padded transform.
pub fn plans(pw: usize, ph: usize) -> Arc<Plans> {
    type Cache = Mutex<HashMap<(usize, usize), Arc<Plans>>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
    let mut map = cache.lock().unwrap_or_else(|e| e.into_inner());
    map.entry((pw, ph))
        .or_insert_with(|| {
            let mut planner = FftPlanner::<f32>::new();
            let fwd_w = planner.plan_fft_forward(pw);
            let fwd_h = planner.plan_fft_forward(ph);
            let inv_w = planner.plan_fft_inverse(pw);
            let inv_h = planner.plan_fft_inverse(ph);
            let scratch_len = [&fwd_w, &fwd_h, &inv_w, &inv_h]
                .iter()
                .map(|f| f.get_inplace_scratch_len())
                .max()
                .unwrap_or(0);
            Arc::new(Plans {
                pw,
                ph,
                fwd_w,
                fwd_h,
                inv_w,
                inv_h,
                scratch_len,
            })
        })
        .clone()
}

impl Correlator {
    /// A correlator for `w` x `h` windows (w along x). Requires `w, h >= 4`.
    pub fn new(w: usize, h: usize) -> Correlator {
        let sx = (w / 2).saturating_sub(1).max(1);
        let sy = (h / 2).saturating_sub(1).max(1);
        let pw = fast_len(w + sx + 1);
        let ph = fast_len(h + sy + 1);
        let plans = plans(pw, ph);
        let cw = 2 * sx + 3;
        let ch = 2 * sy + 3;
        Correlator {
            w,
            h,
            sx,
            sy,
            scratch: vec![Complex32::default(); plans.scratch_len],
            plans,
            buf: vec![Complex32::default(); pw * ph],
            buf2: vec![Complex32::default(); pw * ph],
            wa: vec![0.0; w * h],
            wb: vec![0.0; w * h],
            corr: vec![0.0; cw * ch],
            hm: vec![0.0; cw * (ch + 1)],
            cw,
            ch,
            min_var: 0.0,
            uncertainty: Uncertainty::Off,
            ca: vec![0.0; w * h],
            cb: vec![0.0; w * h],
            wgt: Vec::new(),
            ovx: Vec::new(),
            ovy: Vec::new(),
            ovx32: Vec::new(),
            ovy32: Vec::new(),
        }
    }

    /// Weight both windows' pixels by `weighting` before correlating them (see
    /// [`crate::weighting`]); the top-hat by default. The correlation is normalised by the
    /// weighted windows' energies and the sub-pixel fit (and the uncertainty) divides by the
    /// weighted windows' overlap at each lag ([`Weighting::overlap`]).
    pub fn set_weighting(&mut self, weighting: Weighting) {
        if weighting == Weighting::TopHat {
            self.wgt.clear();
            self.ovx.clear();
            self.ovy.clear();
            self.ovx32.clear();
            self.ovy32.clear();
            return;
        }
        let (gx, gy) = (weighting.weights(self.w), weighting.weights(self.h));
        self.wgt = gy
            .iter()
            .flat_map(|&b| gx.iter().map(move |&a| (a * b) as f32))
            .collect();
        let lags = |n: usize, c: usize| -> Vec<f64> {
            (0..n)
                .map(|k| weighting.overlap(c, k as isize - (n / 2) as isize))
                .collect()
        };
        self.ovx = lags(self.cw, self.w);
        self.ovy = lags(self.ch, self.h);
        self.ovx32 = self.ovx.iter().map(|&o| o as f32).collect();
        self.ovy32 = self.ovy.iter().map(|&o| o as f32).collect();
    }

    /// Peak search half-ranges (sx, sy) in px.
    pub fn search(&self) -> (usize, usize) {
        (self.sx, self.sy)
    }

    /// The normalised correlation around zero lag from the last call of [`Self::correlate`]:
    /// `(2 sy + 3)` rows of `(2 sx + 3)` lags, lag 0 at the centre.
    pub fn plane(&self) -> (&[f32], usize, usize) {
        (&self.corr, self.cw, self.ch)
    }

    /// Correlate `wa` with `wb` and locate the peak.
    ///
    /// Fails ([`Peak::FAILED`]) when a window holds a non-finite value (a sample outside the
    /// image, see [`crate::image::deform_pair`]) or has (near) zero variance: per-pixel variance
    /// `<= 1e-8 mean^2 + 1e-12 + min_var` (a constant window up to f32 rounding: zero fill,
    /// blank or saturated regions; PIV sets `min_var` relative to the frames' variance). Windows
    /// only partly blank (e.g. part-way into the zero fill of a dewarped frame) are handled
    /// before this call by the multipass's signal-fraction rule (`crate::multipass`).
    pub fn correlate(&mut self, sub: SubPixel) -> Peak {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.correlate_avx2(sub) };
            }
        }
        self.correlate_impl(sub)
    }

    /// [`Self::correlate_impl`] compiled for AVX2 (8-lane loops around the FFTs; rustfft picks
    /// its own kernels at run time). No FMA: the results are the same as without AVX2.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn correlate_avx2(&mut self, sub: SubPixel) -> Peak {
        self.correlate_impl(sub)
    }

    /// The plane shape `(cw, ch)` (lags `-sx-1 ..= sx+1` by `-sy-1 ..= sy+1`) of a correlator for
    /// `w` x `h` windows, as [`Self::plane`] returns it.
    pub fn plane_shape(w: usize, h: usize) -> (usize, usize) {
        let sx = (w / 2).saturating_sub(1).max(1);
        let sy = (h / 2).saturating_sub(1).max(1);
        (2 * sx + 3, 2 * sy + 3)
    }

    /// The normalised correlation plane of `wa` with `wb` only (no peak search), in
    /// [`Self::plane`]; `false` (plane untouched) where a window is blank or not finite, as
    /// [`Self::correlate`] fails. Used by the ensemble correlation.
    pub fn correlate_plane(&mut self) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.plane_avx2() }.is_some();
            }
        }
        self.plane_impl().is_some()
    }

    /// [`Self::plane_impl`] compiled for AVX2.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn plane_avx2(&mut self) -> Option<(f32, f32, f64, f64)> {
        self.plane_impl()
    }

    #[inline(always)]
    pub(super) fn correlate_impl(&mut self, sub: SubPixel) -> Peak {
        let Some((ma, mb, ea, eb)) = self.plane_impl() else {
            return Peak::FAILED;
        };
        let (w, h, cw, ch) = (self.w, self.h, self.cw, self.ch);
        let ov = (!self.wgt.is_empty()).then_some((&self.ovx32[..], &self.ovy32[..]));
        let (mut peak, lags) = find_peak_with(&self.corr, &mut self.hm, cw, ch, w, h, ov, sub);
        if self.uncertainty != Uncertainty::Off && peak.ok {
            let scale = 1.0 / (ea * eb).sqrt();
            if self.wgt.is_empty() {
                for (o, &a) in self.ca.iter_mut().zip(&self.wa) {
                    *o = a - ma;
                }
                for (o, &b) in self.cb.iter_mut().zip(&self.wb) {
                    *o = b - mb;
                }
            } else {
                for ((o, &a), &g) in self.ca.iter_mut().zip(&self.wa).zip(&self.wgt) {
                    *o = (a - ma) * g;
                }
                for ((o, &b), &g) in self.cb.iter_mut().zip(&self.wb).zip(&self.wgt) {
                    *o = (b - mb) * g;
                }
            }
            peak.sigma = self.sigma_at(lags[0], scale);
            if self.uncertainty == Uncertainty::AllPeaks {
                for (k, &l) in lags[1..].iter().enumerate() {
                    if peak.alt[k].exists() {
                        peak.alt[k].sigma = self.sigma_at(l, scale);
                    }
                }
            }
        }
        peak
    }

    /// The normalised plane into `corr`; the windows' means and energies (of the weighted
    /// windows when weighted), `None` when blank.
    #[inline(always)]
    fn plane_impl(&mut self) -> Option<(f32, f32, f64, f64)> {
        let (w, h) = (self.w, self.h);
        let n = (w * h) as f32;
        let ma = sum8(&self.wa) / n;
        let mb = sum8(&self.wb) / n;
        let ea = sq_dev8(&self.wa, ma) as f64;
        let eb = sq_dev8(&self.wb, mb) as f64;
        let floor = self.min_var as f64;
        let blank = |e: f64, m: f32| {
            let m = m as f64;
            !(e.is_finite() && m.is_finite()) || e / n as f64 <= 1e-8 * m * m + 1e-12 + floor
        };
        if blank(ea, ma) || blank(eb, mb) {
            return None;
        }
        let pl = &*self.plans;
        let (pw, ph) = (pl.pw, pl.ph);
        // 1. a + i b into the first h rows, zero padding to pw columns (weighted windows: their
        // energies are the plane's normalisation)
        let zero = Complex32::default();
        let (ea, eb) = if self.wgt.is_empty() {
            for ((row, ra), rb) in self
                .buf
                .chunks_exact_mut(pw)
                .zip(self.wa.chunks_exact(w))
                .zip(self.wb.chunks_exact(w))
            {
                for ((o, &a), &b) in row.iter_mut().zip(ra).zip(rb) {
                    *o = Complex32::new(a - ma, b - mb);
                }
                row[w..].fill(zero);
            }
            (ea, eb)
        } else {
            let (mut sa, mut sb) = (0.0f64, 0.0f64);
            for (((row, ra), rb), rg) in self
                .buf
                .chunks_exact_mut(pw)
                .zip(self.wa.chunks_exact(w))
                .zip(self.wb.chunks_exact(w))
                .zip(self.wgt.chunks_exact(w))
            {
                for (((o, &a), &b), &g) in row.iter_mut().zip(ra).zip(rb).zip(rg) {
                    let (x, y) = ((a - ma) * g, (b - mb) * g);
                    sa += (x * x) as f64;
                    sb += (y * y) as f64;
                    *o = Complex32::new(x, y);
                }
                row[w..].fill(zero);
            }
            (sa, sb)
        };
        // 2. row FFTs of the non-zero rows
        pl.fwd_w
            .process_with_scratch(&mut self.buf[..h * pw], &mut self.scratch);
        // 3. transpose into buf2 (pw rows of ph), padding rows h.. with zeros
        transpose_into(&self.buf[..h * pw], h, pw, &mut self.buf2, ph);
        // 4. column FFTs
        pl.fwd_h
            .process_with_scratch(&mut self.buf2, &mut self.scratch);
        // 5. cross-spectrum conj(A) B from Z = A + i B, into buf (same transposed layout), for
        // kx = 0 ..= pw/2 only: the correlation is real, so its spectrum is Hermitian and the
        // other half is never needed
        let nk = pw / 2 + 1;
        // with A = (Z + conj(Zm)) / 2 and B = (Z - conj(Zm)) / 2i (Zm = Z at -k):
        // 2 conj(A) B = Im(Z Zm) + i (|Zm|^2 - |Z|^2) / 2 (the 2 is undone in `norm`)
        let spec = |z: Complex32, zm: Complex32| {
            Complex32::new(
                z.re * zm.im + z.im * zm.re,
                0.5 * ((zm.re * zm.re + zm.im * zm.im) - (z.re * z.re + z.im * z.im)),
            )
        };
        for (kx, orow) in self.buf[..nk * ph].chunks_exact_mut(ph).enumerate() {
            let mkx = if kx == 0 { 0 } else { pw - kx };
            let zrow = &self.buf2[kx * ph..(kx + 1) * ph];
            let mrow = &self.buf2[mkx * ph..(mkx + 1) * ph];
            // ky = 0 pairs with 0, ky pairs with ph - ky
            orow[0] = spec(zrow[0], mrow[0]);
            for ((o, &z), &zm) in orow[1..]
                .iter_mut()
                .zip(&zrow[1..])
                .zip(mrow[1..].iter().rev())
            {
                *o = spec(z, zm);
            }
        }
        // 6. inverse along y of those columns: c(kx, ty), Hermitian in kx for every ty
        pl.inv_h
            .process_with_scratch(&mut self.buf[..nk * ph], &mut self.scratch);
        // 7. lag rows ty = -sy-1 ..= sy+1 (ty < 0 at the end of each column), two at a time:
        // X = H1 + i H2 with H the Hermitian extension of a row's half spectrum, whose inverse
        // along x is r1 + i r2 (the real correlation rows)
        let (sx, sy) = (self.sx, self.sy);
        let ch = self.ch;
        let lag_at = |t: usize| {
            if t <= sy {
                ph - (sy + 1) + t
            } else {
                t - (sy + 1)
            }
        };
        let npairs = ch.div_ceil(2);
        let half = &self.buf[..nk * ph];
        // kx = 1 ..= np pair with pw - kx; kx = 0 (and pw/2 for even pw) pair with themselves
        let np = (pw - 1) / 2;
        for (p, x) in self.buf2[..npairs * pw].chunks_exact_mut(pw).enumerate() {
            let i1 = lag_at(2 * p);
            // an odd last row has no partner: read row i1 again, weighted 0
            let (i2, s2) = if 2 * p + 1 < ch {
                (lag_at(2 * p + 1), 1.0)
            } else {
                (i1, 0.0)
            };
            let (x0, rest) = x.split_at_mut(1);
            let (mid, tail) = rest.split_at_mut(np);
            // self-paired frequencies of a Hermitian row are real
            x0[0] = Complex32::new(half[i1].re, half[i2].re * s2);
            if pw % 2 == 0 {
                let col = &half[(pw / 2) * ph..];
                tail[0] = Complex32::new(col[i1].re, col[i2].re * s2);
            }
            let t = tail.len();
            for ((o, m), col) in mid
                .iter_mut()
                .zip(tail[t - np..].iter_mut().rev())
                .zip(half[ph..].chunks_exact(ph))
            {
                let (c1, c2) = (col[i1], col[i2] * s2);
                *o = Complex32::new(c1.re - c2.im, c1.im + c2.re);
                // X[pw - kx] = conj(c1) + i conj(c2)
                *m = Complex32::new(c1.re + c2.im, c2.re - c1.im);
            }
        }
        pl.inv_w
            .process_with_scratch(&mut self.buf2[..npairs * pw], &mut self.scratch);
        // 8. normalised plane: lags tx = -sx-1 ..= sx+1 (negative ones at the end of a row)
        let norm = (0.5 / ((pw * ph) as f64 * (ea * eb).sqrt())) as f32;
        let cw = self.cw;
        for (rows, y) in self.corr.chunks_mut(2 * cw).zip(self.buf2.chunks_exact(pw)) {
            let (r1, r2) = rows.split_at_mut(cw);
            let (neg, pos) = (&y[pw - sx - 1..], &y[..sx + 2]);
            let (n1, p1) = r1.split_at_mut(sx + 1);
            for (o, v) in n1.iter_mut().zip(neg) {
                *o = v.re * norm;
            }
            for (o, v) in p1.iter_mut().zip(pos) {
                *o = v.re * norm;
            }
            if !r2.is_empty() {
                let (n2, p2) = r2.split_at_mut(sx + 1);
                for (o, v) in n2.iter_mut().zip(neg) {
                    *o = v.im * norm;
                }
                for (o, v) in p2.iter_mut().zip(pos) {
                    *o = v.im * norm;
                }
            }
        }
        Some((ma, mb, ea, eb))
    }
}

/// Sum with 8 independent accumulators (vectorises).
#[inline(always)]
fn sum8(x: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            acc[k] += c[k];
        }
    }
    acc.iter().sum::<f32>() + it.remainder().iter().sum::<f32>()
}

/// Sum of squared deviations from `m` with 8 accumulators.
#[inline(always)]
fn sq_dev8(x: &[f32], m: f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            let d = c[k] - m;
            acc[k] += d * d;
        }
    }
    acc.iter().sum::<f32>()
        + it.remainder()
            .iter()
            .map(|v| (v - m) * (v - m))
            .sum::<f32>()
}

/// Write the transpose of `src` (`rows` x `cols`) into `dst` as `cols` rows of `stride`,
/// zero-filling each destination row beyond `rows`.
#[inline(always)]
fn transpose_into(
    src: &[Complex32],
    rows: usize,
    cols: usize,
    dst: &mut [Complex32],
    stride: usize,
) {
    let dst = &mut dst[..cols * stride];
    for dr in dst.chunks_exact_mut(stride) {
        dr[rows..].fill(Complex32::default());
    }
    // four source rows at a time: each destination row gets four contiguous values
    let mut blocks = src[..rows * cols].chunks_exact(4 * cols);
    let mut r0 = 0;
    for b in &mut blocks {
        let (s0, rest) = b.split_at(cols);
        let (s1, rest) = rest.split_at(cols);
        let (s2, s3) = rest.split_at(cols);
        for ((((d, &x0), &x1), &x2), &x3) in
            dst.chunks_exact_mut(stride).zip(s0).zip(s1).zip(s2).zip(s3)
        {
            let d = &mut d[r0..r0 + 4];
            d[0] = x0;
            d[1] = x1;
            d[2] = x2;
            d[3] = x3;
        }
        r0 += 4;
    }
    for s in blocks.remainder().chunks_exact(cols) {
        for (d, &x) in dst.chunks_exact_mut(stride).zip(s) {
            d[r0] = x;
        }
        r0 += 1;
    }
}
