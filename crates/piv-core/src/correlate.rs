//! FFT cross-correlation of one window pair, zero-padded (linear, no wrap-around inside the
//! search range), normalised by the window energies, with peak finding, sub-pixel estimation,
//! peak ratio and correlation coefficient.
//!
//! A window is `w` px wide (along x, columns) and `h` px tall (along y, rows). Both real windows
//! travel through one complex 2D FFT (`a + i b`); the cross-spectrum `conj(A) B` is separated
//! from it by Hermitian symmetry, and one inverse FFT gives the correlation
//! `R(tx, ty) = sum a(x, y) b(x + tx, y + ty) / sqrt(E_a E_b)` (means removed), whose peak is
//! the displacement of B relative to A. `R` is real, so its spectrum is Hermitian: only the
//! columns `kx = 0 ..= pw/2` are formed and inverted along y, and the lag rows the peak search
//! needs are inverted along x two at a time (`r1 + i r2` from the Hermitian extensions of their
//! half spectra), about half the inverse work of a full complex transform. On x86-64 with AVX2
//! the loops around the FFTs run in 8 lanes (same arithmetic, same results). The padded size is the smallest 2^a 3^b 5^c length
//! `>= w + w/2` (and likewise for `h`), which keeps every lag `|t| <= w/2` free of wrap-around.
//! The peak is searched in `|tx| <= w/2 - 1`, `|ty| <= h/2 - 1`.
//!
//! FFT plans are cached per padded shape and shared between threads ([`plans`]); each thread
//! owns a [`Correlator`] (its scratch buffers), so correlating a window allocates nothing.

use crate::weighting::Weighting;
use image_core::fast_len;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Sub-pixel peak estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SubPixel {
    /// Independent 3-point Gaussian fits along x and y (parabolic where a value is <= 0).
    #[default]
    Gauss3,
    /// Least-squares 2D Gaussian over the 3 x 3 neighbourhood (9 points, Nobach & Honkanen
    /// 2005), which also handles elliptic peaks tilted by a shear; falls back to `Gauss3`
    /// where a value is <= 0.
    Gauss2d,
}

/// The outcome of correlating one window pair. Equality is field by field, with the
/// uncertainties compared as values where both are numbers and as equal where both are NaN
/// (not estimated).
#[derive(Debug, Clone, Copy)]
pub struct Peak {
    /// Displacement of B relative to A along x, px (sub-pixel).
    pub dx: f64,
    /// Displacement along y, px.
    pub dy: f64,
    /// Normalised correlation at the integer peak (correlation coefficient, <= 1).
    pub coef: f64,
    /// Highest peak over the second-highest local maximum (>= 1; capped at 1000).
    pub ratio: f64,
    /// `false` when a window was blank (zero variance) or the highest value of the search
    /// region is not a local maximum (the peak lies beyond the search range).
    pub ok: bool,
    /// The second and third highest local maxima of the plane (outside the primary peak's
    /// 3 x 3 neighbourhood and each other's), sub-pixel as the primary: the candidates that
    /// the validation tries when the primary peak fails the median test
    /// ([`crate::multipass`]). [`AltPeak::NONE`] where the plane has fewer maxima.
    pub alt: [AltPeak; 2],
    /// Standard uncertainty (one sigma) of `dx` and `dy`, px, from the correlation statistics
    /// ([`Correlator::sigma_at`]); NaN unless asked for ([`Correlator::uncertainty`]) and the
    /// peak is `ok`.
    pub sigma: (f64, f64),
}

/// A secondary correlation peak (see [`Peak::alt`]); equality as [`Peak`]'s.
#[derive(Debug, Clone, Copy)]
pub struct AltPeak {
    /// Displacement along x and y, px (sub-pixel), as [`Peak::dx`], [`Peak::dy`].
    pub dx: f64,
    pub dy: f64,
    /// Normalised correlation at the peak; `-inf` for [`AltPeak::NONE`].
    pub coef: f64,
    /// Standard uncertainty of `dx`, `dy` as [`Peak::sigma`].
    pub sigma: (f64, f64),
}

/// Equal uncertainties: equal numbers, or both NaN (not estimated).
fn same_sigma(a: (f64, f64), b: (f64, f64)) -> bool {
    let eq = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
    eq(a.0, b.0) && eq(a.1, b.1)
}

impl PartialEq for AltPeak {
    fn eq(&self, o: &Self) -> bool {
        self.dx == o.dx && self.dy == o.dy && self.coef == o.coef && same_sigma(self.sigma, o.sigma)
    }
}

impl PartialEq for Peak {
    fn eq(&self, o: &Self) -> bool {
        self.dx == o.dx
            && self.dy == o.dy
            && self.coef == o.coef
            && self.ratio == o.ratio
            && self.ok == o.ok
            && self.alt == o.alt
            && same_sigma(self.sigma, o.sigma)
    }
}

impl AltPeak {
    /// No such peak.
    pub const NONE: AltPeak = AltPeak {
        dx: 0.0,
        dy: 0.0,
        coef: f64::NEG_INFINITY,
        sigma: (f64::NAN, f64::NAN),
    };

    /// Is there such a peak?
    pub fn exists(&self) -> bool {
        self.coef.is_finite()
    }
}

impl Peak {
    /// A failed correlation.
    pub const FAILED: Peak = Peak {
        dx: 0.0,
        dy: 0.0,
        coef: 0.0,
        ratio: 0.0,
        ok: false,
        alt: [AltPeak::NONE; 2],
        sigma: (f64::NAN, f64::NAN),
    };
}

/// Which peaks of a correlation get their uncertainty ([`Correlator::uncertainty`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Uncertainty {
    /// None (the sigmas stay NaN).
    #[default]
    Off,
    /// The highest peak.
    Peak,
    /// The highest peak and the alternatives ([`Peak::alt`]).
    AllPeaks,
}

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

/// Per-thread correlation engine for one window shape; reuse it for every window.
pub struct Correlator {
    /// Window width (px along x).
    pub w: usize,
    /// Window height (px along y).
    pub h: usize,
    /// Peak search half-ranges.
    sx: usize,
    sy: usize,
    plans: Arc<Plans>,
    buf: Vec<Complex32>,
    buf2: Vec<Complex32>,
    scratch: Vec<Complex32>,
    /// Window of frame A, row-major `h` x `w`; fill it before [`Correlator::correlate`].
    pub wa: Vec<f32>,
    /// Window of frame B.
    pub wb: Vec<f32>,
    corr: Vec<f32>,
    /// Scratch plane of the peak search.
    hm: Vec<f32>,
    cw: usize,
    ch: usize,
    /// Per-pixel variance at or below which a window is blank and not correlated (besides the
    /// relative floor of [`Correlator::correlate`]); 0 by default.
    pub min_var: f32,
    /// Which peaks get their uncertainty (see [`Uncertainty`]); off by default.
    pub uncertainty: Uncertainty,
    /// The windows with their means removed (for the uncertainty); scratch of `w * h` values
    /// otherwise (the ensemble keeps frame B's window in `cb`).
    pub(crate) ca: Vec<f32>,
    pub(crate) cb: Vec<f32>,
    /// The weighting window ([`Correlator::set_weighting`]): for anything but the top-hat its
    /// `w * h` pixel weights and the overlap of the weighted windows at the plane's lags (f64
    /// for the uncertainty, f32 for the sub-pixel fit); empty for the top-hat.
    wgt: Vec<f32>,
    ovx: Vec<f64>,
    ovy: Vec<f64>,
    ovx32: Vec<f32>,
    ovy32: Vec<f32>,
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
            hm: vec![0.0; cw * ch],
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
    fn correlate_impl(&mut self, sub: SubPixel) -> Peak {
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
    fn sigma_at(&self, (c, r): (usize, usize), scale: f64) -> (f64, f64) {
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
    let (mut t, mut t2) = (s.iter().sum::<f32>(), s2.iter().sum::<f32>());
    for i in n / 8 * 8..n {
        let d = a0[i] * b1[i] - a1[i] * b0[i];
        t += d;
        t2 += d * d;
    }
    (t, t2)
}

/// `|d off / d delta|` of the 3-point estimator [`gauss3`] when `p` moves by `+delta/2` and `m`
/// by `-delta/2` (the asymmetry of the peak changes by `delta`); Gaussian when all values are
/// positive, else parabolic; NaN where the estimator has no maximum.
fn gauss3_slope(m: f64, c: f64, p: f64) -> f64 {
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

/// Locate the peak in a plane of `ch` rows of `cw` lags (lag 0 at the centre, a one-lag border
/// around the search region), with sub-pixel refinement and peak ratio. The sub-pixel fit uses
/// the plane divided by the overlap fraction `(1 - |tx|/w)(1 - |ty|/h)` of the two windows at
/// each lag, which removes the bias of linear correlation towards zero displacement
/// (Westerweel 1997); the integer peak, its height and the peak ratio use the plane itself.
/// Allocates a scratch plane: [`Correlator::correlate`] uses its own instead.
pub fn find_peak(corr: &[f32], cw: usize, ch: usize, w: usize, h: usize, sub: SubPixel) -> Peak {
    let mut hm = vec![0.0f32; cw * ch];
    find_peak_with(corr, &mut hm, cw, ch, w, h, None, sub).0
}

/// `a` if it is greater than `b`, else `b` (one `maxps`; a NaN `a` is skipped).
#[inline(always)]
fn gt_max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// The maximum of `x` (NaN skipped; -inf if empty), with 8 independent lanes.
#[inline(always)]
fn max8(x: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            acc[k] = gt_max(c[k], acc[k]);
        }
    }
    let m = acc.iter().fold(f32::NEG_INFINITY, |m, &a| gt_max(a, m));
    it.remainder().iter().fold(m, |m, &a| gt_max(a, m))
}

/// [`find_peak`] with a scratch plane `hm` of `cw * ch` values; also returns the plane
/// positions `(column, row)` of the peak and of its two alternatives.
#[inline(always)]
fn find_peak_with(
    corr: &[f32],
    hm: &mut [f32],
    cw: usize,
    ch: usize,
    w: usize,
    h: usize,
    overlap: Option<(&[f32], &[f32])>,
    sub: SubPixel,
) -> (Peak, [(usize, usize); 3]) {
    let corr = &corr[..cw * ch];
    let hm = &mut hm[..cw * ch];
    let at = |c: usize, r: usize| corr[r * cw + c];
    let (hx, hy) = ((cw / 2) as f32, (ch / 2) as f32);
    let (fw, fh) = (w as f32, h as f32);
    // the windows' overlap at each lag: given (weighted windows) or the top-hat's
    let unbiased = |c: usize, r: usize| match overlap {
        Some((ox, oy)) => corr[r * cw + c] / (ox[c] * oy[r]),
        None => {
            let ox = 1.0 - (c as f32 - hx).abs() / fw;
            let oy = 1.0 - (r as f32 - hy).abs() / fh;
            corr[r * cw + c] / (ox * oy)
        }
    };
    let n = cw - 2;
    // primary peak inside the border (the first of equal values in row-major order)
    let (mut pc, mut pr, mut best) = (1usize, 1usize, f32::NEG_INFINITY);
    for (r, row) in corr.chunks_exact(cw).enumerate().take(ch - 1).skip(1) {
        let inner = &row[1..cw - 1];
        let m = max8(inner);
        if m > best {
            best = m;
            pr = r;
            pc = 1 + inner.iter().position(|&v| v == m).unwrap_or(0);
        }
    }
    if !best.is_finite() {
        return (Peak::FAILED, [(0, 0); 3]);
    }
    // second-highest local maximum outside the peak's 3 x 3 neighbourhood: maximum of the
    // 3 x 3 neighbourhoods, separably (rows first: hm[r cw + i] for column i + 1)
    for (o, row) in hm.chunks_exact_mut(cw).zip(corr.chunks_exact(cw)) {
        for (((o, &a), &b), &c) in o[..n]
            .iter_mut()
            .zip(&row[..n])
            .zip(&row[1..n + 1])
            .zip(&row[2..])
        {
            *o = gt_max(gt_max(a, b), c);
        }
    }
    // then along y, in place into the first n values of row r - 1 (rows r - 1, r, r + 1 are
    // still the horizontal maxima when row r is reached), keeping the value where it is a
    // local maximum (at least its neighbourhood's maximum) and -inf elsewhere; the two highest
    // local maxima (not adjacent to each other: a plateau counts once) are kept with their lags
    let mut top = [(f32::NEG_INFINITY, 0usize, 0usize); 2];
    for r in 1..ch - 1 {
        let (up, rest) = hm[(r - 1) * cw..].split_at_mut(cw);
        let (mid, dn) = rest.split_at(cw);
        let v = &corr[r * cw + 1..r * cw + 1 + n];
        let up = &mut up[..n];
        for (((u, &m), &d), &x) in up.iter_mut().zip(&mid[..n]).zip(&dn[..n]).zip(v) {
            let mx = gt_max(gt_max(*u, m), d);
            *u = if x >= mx { x } else { f32::NEG_INFINITY };
        }
        if r.abs_diff(pr) <= 1 {
            // not the peak's own neighbourhood: columns pc-1 ..= pc+1 (indices pc-2 ..= pc)
            up[pc.saturating_sub(2)..(pc + 1).min(n)].fill(f32::NEG_INFINITY);
        }
        if max8(up) > top[1].0 {
            for (i, &x) in up.iter().enumerate() {
                if x > top[1].0 {
                    keep_top2(&mut top, (x, i + 1, r));
                }
            }
        }
    }
    let second = top[0].0;
    let ratio = if best <= 0.0 {
        1.0
    } else if second <= best * 1e-3 {
        1000.0
    } else {
        (best / second) as f64
    };
    // a peak on the search border is kept only if it is a true local maximum (the plane has
    // one exact lag beyond the search range on every side)
    let on_border = (pr - 1..=pr + 1)
        .any(|rr| (pc - 1..=pc + 1).any(|cc| (rr, cc) != (pr, pc) && at(cc, rr) > best));
    let (ox, oy) = match sub {
        SubPixel::Gauss3 => gauss3_2(&unbiased, pc, pr),
        SubPixel::Gauss2d => {
            gauss9(&unbiased, pc, pr).unwrap_or_else(|| gauss3_2(&unbiased, pc, pr))
        }
    };
    let cx = (cw / 2) as f64;
    let cy = (ch / 2) as f64;
    let alt = top.map(|(x, c, r)| {
        if x.is_finite() {
            let (ox, oy) = gauss3_2(&unbiased, c, r);
            AltPeak {
                dx: c as f64 - cx + ox,
                dy: r as f64 - cy + oy,
                coef: x as f64,
                sigma: (f64::NAN, f64::NAN),
            }
        } else {
            AltPeak::NONE
        }
    });
    let lags = [(pc, pr), (top[0].1, top[0].2), (top[1].1, top[1].2)];
    let peak = Peak {
        dx: pc as f64 - cx + ox,
        dy: pr as f64 - cy + oy,
        coef: best as f64,
        ratio,
        ok: !on_border,
        alt,
        sigma: (f64::NAN, f64::NAN),
    };
    (peak, lags)
}

/// Insert the local maximum `cand` = (value, column, row) into the two highest `top` (highest
/// first), where a maximum next to a held one (a plateau) replaces it only when higher.
#[inline]
fn keep_top2(top: &mut [(f32, usize, usize); 2], cand: (f32, usize, usize)) {
    let near = |a: &(f32, usize, usize)| a.1.abs_diff(cand.1) <= 1 && a.2.abs_diff(cand.2) <= 1;
    if near(&top[0]) {
        if cand.0 > top[0].0 {
            top[0] = cand;
        }
        return;
    }
    if near(&top[1]) {
        if cand.0 > top[1].0 {
            top[1] = cand;
            if top[1].0 > top[0].0 {
                top.swap(0, 1);
            }
        }
        return;
    }
    if cand.0 > top[0].0 {
        top[1] = top[0];
        top[0] = cand;
    } else if cand.0 > top[1].0 {
        top[1] = cand;
    }
}

/// 3-point estimator along one axis; Gaussian when all values are positive, else parabolic.
#[inline]
pub fn gauss3(m: f32, c: f32, p: f32) -> f64 {
    let (m, c, p) = (m as f64, c as f64, p as f64);
    let off = if m > 0.0 && c > 0.0 && p > 0.0 {
        let (lm, lc, lp) = (m.ln(), c.ln(), p.ln());
        let den = 2.0 * (lm - 2.0 * lc + lp);
        if den < 0.0 {
            (lm - lp) / den
        } else {
            0.0
        }
    } else {
        let den = 2.0 * (m - 2.0 * c + p);
        if den < 0.0 {
            (m - p) / den
        } else {
            0.0
        }
    };
    off.clamp(-0.5, 0.5)
}

fn gauss3_2(at: &impl Fn(usize, usize) -> f32, c: usize, r: usize) -> (f64, f64) {
    (
        gauss3(at(c - 1, r), at(c, r), at(c + 1, r)),
        gauss3(at(c, r - 1), at(c, r), at(c, r + 1)),
    )
}

/// Least-squares fit of `ln R = a + b x + c y + d x^2 + e x y + f y^2` to the 3 x 3
/// neighbourhood; the vertex of the fitted paraboloid. `None` if a value is <= 0 or the fit is
/// not a maximum.
fn gauss9(at: &impl Fn(usize, usize) -> f32, c: usize, r: usize) -> Option<(f64, f64)> {
    let mut c10 = 0.0;
    let mut c01 = 0.0;
    let mut c11 = 0.0;
    let mut c20 = 0.0;
    let mut c02 = 0.0;
    for j in -1i32..=1 {
        for i in -1i32..=1 {
            let v = at((c as i32 + i) as usize, (r as i32 + j) as usize) as f64;
            if v <= 0.0 {
                return None;
            }
            let l = v.ln();
            let (x, y) = (i as f64, j as f64);
            c10 += x * l / 6.0;
            c01 += y * l / 6.0;
            c11 += x * y * l / 4.0;
            c20 += (3.0 * x * x - 2.0) * l / 6.0;
            c02 += (3.0 * y * y - 2.0) * l / 6.0;
        }
    }
    // ln R ~ const + c10 x + c01 y + c20 x^2 + c11 x y + c02 y^2
    let det = 4.0 * c20 * c02 - c11 * c11;
    if !(c20 < 0.0 && det > 0.0) {
        return None;
    }
    let x0 = (c11 * c01 - 2.0 * c10 * c02) / det;
    let y0 = (c11 * c10 - 2.0 * c01 * c20) / det;
    if x0.abs() > 1.0 || y0.abs() > 1.0 {
        return None;
    }
    Some((x0, y0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian_blob(w: usize, h: usize, cx: f64, cy: f64) -> Vec<f32> {
        let mut v = vec![0.0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                let dx = c as f64 - cx;
                let dy = r as f64 - cy;
                v[r * w + c] = (-(dx * dx + dy * dy) / 2.0).exp() as f32;
            }
        }
        v
    }

    #[test]
    fn gauss3_exact_on_gaussian() {
        let d: f64 = 0.3;
        let g = |x: f64| (-(x - d) * (x - d) / 1.7).exp() as f32;
        assert!((gauss3(g(-1.0), g(0.0), g(1.0)) - d).abs() < 1e-5);
    }

    #[test]
    fn gauss9_exact_on_tilted_gaussian() {
        let (x0, y0) = (0.27, -0.41);
        let f = |i: usize, j: usize| {
            let x = i as f64 - 1.0 - x0;
            let y = j as f64 - 1.0 - y0;
            (-(0.8 * x * x + 0.5 * x * y + 0.6 * y * y)).exp() as f32
        };
        let (ex, ey) = gauss9(&f, 1, 1).unwrap();
        assert!(
            (ex - x0).abs() < 1e-5 && (ey - y0).abs() < 1e-5,
            "{ex} {ey}"
        );
    }

    /// Particle images (Gaussian, 2.5 px diameter) at random places in a `w` x `h` window,
    /// the second window's moved by `(sx, sy)`.
    fn particle_windows(
        w: usize,
        h: usize,
        (sx, sy): (f64, f64),
        seed: u64,
    ) -> (Vec<f32>, Vec<f32>) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = (0.05 * ((w + 8) * (h + 8)) as f64) as usize;
        let pts: Vec<(f64, f64)> = (0..n)
            .map(|_| {
                (
                    rng.random::<f64>() * (w + 8) as f64 - 4.0,
                    rng.random::<f64>() * (h + 8) as f64 - 4.0,
                )
            })
            .collect();
        let render = |dx: f64, dy: f64| -> Vec<f32> {
            (0..w * h)
                .map(|k| {
                    let (c, r) = ((k % w) as f64, (k / w) as f64);
                    pts.iter()
                        .map(|&(x, y)| {
                            let (ex, ey) = (c - x - dx, r - y - dy);
                            (-(ex * ex + ey * ey) / (2.0 * 0.625 * 0.625)).exp()
                        })
                        .sum::<f64>() as f32
                })
                .collect()
        };
        (render(0.0, 0.0), render(sx, sy))
    }

    #[test]
    fn weighted_windows_find_a_subpixel_shift() {
        let (w, h) = (32usize, 32usize);
        let shift = (0.3, -0.2);
        for wt in [Weighting::TopHat, Weighting::Gaussian, Weighting::Blackman] {
            let mut err = (0.0f64, 0.0f64);
            for seed in 0..20 {
                let (a, b) = particle_windows(w, h, shift, seed);
                let mut c = Correlator::new(w, h);
                c.set_weighting(wt);
                c.uncertainty = Uncertainty::Peak;
                c.wa.copy_from_slice(&a);
                c.wb.copy_from_slice(&b);
                let p = c.correlate(SubPixel::Gauss3);
                assert!(
                    p.ok && p.sigma.0.is_finite() && p.sigma.1.is_finite(),
                    "{wt:?} {p:?}"
                );
                err.0 += p.dx - shift.0;
                err.1 += p.dy - shift.1;
            }
            // no bias from the taper: the overlap correction of the weighted windows
            let (bx, by) = (err.0 / 20.0, err.1 / 20.0);
            assert!(bx.abs() < 0.02 && by.abs() < 0.02, "{wt:?} {bx} {by}");
        }
        // the top-hat set explicitly is the default, bit for bit
        let (a, b) = particle_windows(32, 8, (1.3, 0.4), 7);
        let mut c0 = Correlator::new(32, 8);
        let mut c1 = Correlator::new(32, 8);
        c1.set_weighting(Weighting::Gaussian);
        c1.set_weighting(Weighting::TopHat);
        for c in [&mut c0, &mut c1] {
            c.wa.copy_from_slice(&a);
            c.wb.copy_from_slice(&b);
        }
        assert_eq!(
            c0.correlate(SubPixel::Gauss3),
            c1.correlate(SubPixel::Gauss3)
        );
    }

    #[test]
    fn integer_shift_of_random_pattern_is_found_exactly() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (w, h) = (32usize, 8usize);
        let big_w = w + 40;
        let big_h = h + 40;
        let img: Vec<f32> = (0..big_w * big_h).map(|_| rng.random::<f32>()).collect();
        for (sx, sy) in [(0i32, 0i32), (3, 1), (-5, -2), (7, 3), (-14, 0), (-15, -3)] {
            let mut c = Correlator::new(w, h);
            for r in 0..h {
                for col in 0..w {
                    let (ra, ca) = (r + 20, col + 20);
                    c.wa[r * w + col] = img[ra * big_w + ca];
                    // B(x) = A(x - s): pattern moved by +s
                    let (rb, cb) = ((ra as i32 - sy) as usize, (ca as i32 - sx) as usize);
                    c.wb[r * w + col] = img[rb * big_w + cb];
                }
            }
            let p = c.correlate(SubPixel::Gauss3);
            assert!(p.ok, "{sx} {sy} {p:?}");
            assert!(
                (p.dx - sx as f64).abs() < 0.2 && (p.dy - sy as f64).abs() < 0.2,
                "{sx} {sy} {p:?}"
            );
            if sx == 0 && sy == 0 {
                assert!((p.coef - 1.0).abs() < 1e-4, "{p:?}");
            }
        }
    }

    #[test]
    fn no_wrap_around_and_subpixel_blob() {
        let (w, h) = (32usize, 32usize);
        let mut c = Correlator::new(w, h);
        c.wa.copy_from_slice(&gaussian_blob(w, h, 15.0, 15.0));
        c.wb.copy_from_slice(&gaussian_blob(w, h, 17.3, 14.4));
        let p = c.correlate(SubPixel::Gauss3);
        // the integer peak of an isolated blob moved by (2.3, -0.6); sub-pixel accuracy is
        // tested on particle patterns (the overlap correction assumes homogeneous seeding)
        assert!(
            p.ok && (p.dx - 2.3).abs() < 0.5 && (p.dy + 0.6).abs() < 0.5,
            "{p:?}"
        );
        // linear correlation: the plane equals the direct sum at a few lags
        let (plane, cw, ch) = c.plane();
        let (wa, wb) = (c.wa.clone(), c.wb.clone());
        let ma = wa.iter().sum::<f32>() as f64 / (w * h) as f64;
        let mb = wb.iter().sum::<f32>() as f64 / (w * h) as f64;
        let ea: f64 = wa.iter().map(|&a| (a as f64 - ma).powi(2)).sum();
        let eb: f64 = wb.iter().map(|&b| (b as f64 - mb).powi(2)).sum();
        for (tx, ty) in [(0i32, 0i32), (5, -3), (-16, 16), (16, -16), (-3, 9)] {
            let mut s = 0.0f64;
            for r in 0..h as i32 {
                for col in 0..w as i32 {
                    let (r2, c2) = (r + ty, col + tx);
                    if r2 < 0 || c2 < 0 || r2 >= h as i32 || c2 >= w as i32 {
                        continue;
                    }
                    s += (wa[(r * w as i32 + col) as usize] as f64 - ma)
                        * (wb[(r2 * w as i32 + c2) as usize] as f64 - mb);
                }
            }
            let expect = s / (ea * eb).sqrt();
            let got =
                plane[((ty + (ch / 2) as i32) as usize) * cw + (tx + (cw / 2) as i32) as usize];
            assert!(
                (got as f64 - expect).abs() < 1e-5,
                "{tx} {ty} {got} {expect}"
            );
        }
    }

    /// The normalised linear correlation by its definition (f64), at lag (tx, ty).
    fn direct(wa: &[f32], wb: &[f32], w: usize, h: usize, tx: i32, ty: i32) -> f64 {
        let n = (w * h) as f64;
        let ma = wa.iter().map(|&a| a as f64).sum::<f64>() / n;
        let mb = wb.iter().map(|&b| b as f64).sum::<f64>() / n;
        let ea: f64 = wa.iter().map(|&a| (a as f64 - ma).powi(2)).sum();
        let eb: f64 = wb.iter().map(|&b| (b as f64 - mb).powi(2)).sum();
        let (wi, hi) = (w as i32, h as i32);
        let mut s = 0.0f64;
        for r in 0..hi {
            for c in 0..wi {
                let (r2, c2) = (r + ty, c + tx);
                if r2 < 0 || c2 < 0 || r2 >= hi || c2 >= wi {
                    continue;
                }
                s += (wa[(r * wi + c) as usize] as f64 - ma)
                    * (wb[(r2 * wi + c2) as usize] as f64 - mb);
            }
        }
        s / (ea * eb).sqrt()
    }

    #[test]
    fn whole_plane_equals_direct_sum_for_even_and_odd_padding() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        // padded sizes: 48x48, 48x12 (h = 8), 192x48, 96x96, 15x9 (odd), 18x18, 25x12
        for (w, h) in [
            (32usize, 32usize),
            (32, 8),
            (128, 32),
            (64, 64),
            (10, 6),
            (12, 12),
            (16, 8),
            (17, 7),
        ] {
            let mut c = Correlator::new(w, h);
            let (pw, ph) = (c.plans.pw, c.plans.ph);
            // a correlated pair: B = A shifted by (2, 1) plus noise
            let big: Vec<f32> = (0..(w + 4) * (h + 4))
                .map(|_| rng.random::<f32>() * 100.0)
                .collect();
            for r in 0..h {
                for col in 0..w {
                    c.wa[r * w + col] = big[(r + 2) * (w + 4) + col + 2];
                    c.wb[r * w + col] = big[(r + 1) * (w + 4) + col] + 10.0 * rng.random::<f32>();
                }
            }
            let p = c.correlate(SubPixel::Gauss3);
            assert!(p.ok, "{w}x{h} (padded {pw}x{ph}) {p:?}");
            let (plane, cw, ch) = c.plane();
            let (sx, sy) = c.search();
            assert_eq!((cw, ch), (2 * sx + 3, 2 * sy + 3));
            let mut worst = 0.0f64;
            for j in 0..ch {
                for i in 0..cw {
                    let (tx, ty) = (i as i32 - (sx + 1) as i32, j as i32 - (sy + 1) as i32);
                    let e = direct(&c.wa, &c.wb, w, h, tx, ty);
                    worst = worst.max((plane[j * cw + i] as f64 - e).abs());
                }
            }
            assert!(
                worst < 2e-6,
                "{w}x{h} (padded {pw}x{ph}): max error {worst}"
            );
        }
    }

    /// The peak search written plainly (reference for the vectorised one).
    fn find_peak_plain(corr: &[f32], cw: usize, ch: usize, sub: SubPixel) -> Peak {
        let at = |c: usize, r: usize| corr[r * cw + c];
        let (mut pc, mut pr, mut best) = (1usize, 1usize, f32::NEG_INFINITY);
        for r in 1..ch - 1 {
            for c in 1..cw - 1 {
                if at(c, r) > best {
                    (best, pc, pr) = (at(c, r), c, r);
                }
            }
        }
        let mut maxima = Vec::new();
        for r in 1..ch - 1 {
            for c in 1..cw - 1 {
                if r.abs_diff(pr) <= 1 && c.abs_diff(pc) <= 1 {
                    continue;
                }
                let v = at(c, r);
                let is_max = (r - 1..=r + 1)
                    .all(|rr| (c - 1..=c + 1).all(|cc| (rr == r && cc == c) || at(cc, rr) <= v));
                if is_max {
                    maxima.push((v, c, r));
                }
            }
        }
        maxima.sort_by(|a, b| b.0.total_cmp(&a.0));
        let second = maxima.first().map_or(f32::NEG_INFINITY, |m| m.0);
        let third = maxima.iter().find(|m| {
            let t = maxima[0];
            m.1.abs_diff(t.1) > 1 || m.2.abs_diff(t.2) > 1
        });
        let on_border = (pr - 1..=pr + 1)
            .any(|rr| (pc - 1..=pc + 1).any(|cc| (rr, cc) != (pr, pc) && at(cc, rr) > best));
        let ratio = if best <= 0.0 {
            1.0
        } else if second <= best * 1e-3 {
            1000.0
        } else {
            (best / second) as f64
        };
        // the windows are as large as the plane here
        let (hx, hy) = ((cw / 2) as f32, (ch / 2) as f32);
        let unbiased = |c: usize, r: usize| {
            let ox = 1.0 - (c as f32 - hx).abs() / cw as f32;
            let oy = 1.0 - (r as f32 - hy).abs() / ch as f32;
            at(c, r) / (ox * oy)
        };
        let (ox, oy) = match sub {
            SubPixel::Gauss3 => gauss3_2(&unbiased, pc, pr),
            SubPixel::Gauss2d => {
                gauss9(&unbiased, pc, pr).unwrap_or_else(|| gauss3_2(&unbiased, pc, pr))
            }
        };
        let alt_of = |m: Option<&(f32, usize, usize)>| match m {
            Some(&(v, c, r)) => {
                let (ox, oy) = gauss3_2(&unbiased, c, r);
                AltPeak {
                    dx: c as f64 - hx as f64 + ox,
                    dy: r as f64 - hy as f64 + oy,
                    coef: v as f64,
                    sigma: (f64::NAN, f64::NAN),
                }
            }
            None => AltPeak::NONE,
        };
        Peak {
            dx: pc as f64 - hx as f64 + ox,
            dy: pr as f64 - hy as f64 + oy,
            coef: best as f64,
            ratio,
            ok: !on_border,
            alt: [alt_of(maxima.first()), alt_of(third)],
            sigma: (f64::NAN, f64::NAN),
        }
    }

    #[test]
    fn peak_search_matches_plain_scan() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        for case in 0..600 {
            let cw = 3 + rng.random_range(0..40usize);
            let ch = 3 + rng.random_range(0..20usize);
            // coarse levels make ties and plateaus common
            let levels = [4.0f32, 16.0, 1e6][case % 3];
            let mut corr: Vec<f32> = (0..cw * ch)
                .map(|_| (rng.random::<f32>() * levels).floor() / levels - 0.3)
                .collect();
            if case % 5 == 0 {
                // a dominant peak, sometimes on the search border
                let (c, r) = (rng.random_range(1..cw - 1), rng.random_range(1..ch - 1));
                corr[r * cw + c] = 2.0;
            }
            let sub = [SubPixel::Gauss3, SubPixel::Gauss2d][case % 2];
            let p = find_peak(&corr, cw, ch, cw, ch, sub);
            let mut q = find_peak_plain(&corr, cw, ch, sub);
            if levels < 1e6 {
                // with ties, which of equal maxima is the second or third is a matter of order
                assert_eq!(p.alt.map(|a| a.coef), q.alt.map(|a| a.coef), "case {case}");
                q.alt = p.alt;
            }
            assert_eq!(p, q, "case {case}");
        }
    }

    #[test]
    fn second_and_third_peaks_found_sub_pixel() {
        // three Gaussian peaks of heights 1, 0.7, 0.5 at fractional lags; a weak bump next to
        // the second one is not a separate maximum
        let (cw, ch) = (41usize, 21usize);
        let bumps = [
            (1.0f64, 25.3f64, 12.6f64),
            (0.7, 8.8, 5.25),
            (0.5, 31.4, 4.7),
        ];
        let corr: Vec<f32> = (0..cw * ch)
            .map(|k| {
                let (c, r) = ((k % cw) as f64, (k / cw) as f64);
                let v: f64 = bumps
                    .iter()
                    .map(|&(a, x, y)| a * (-((c - x).powi(2) + (r - y).powi(2)) / 3.0).exp())
                    .sum();
                (v + 1e-3) as f32
            })
            .collect();
        // windows far larger than the plane: no overlap weighting
        let big = 1 << 24;
        let p = find_peak(&corr, cw, ch, big, big, SubPixel::Gauss3);
        let (hx, hy) = ((cw / 2) as f64, (ch / 2) as f64);
        assert!((p.dx - (25.3 - hx)).abs() < 0.02 && (p.dy - (12.6 - hy)).abs() < 0.02);
        for (a, &(height, x, y)) in p.alt.iter().zip(&bumps[1..]) {
            assert!(a.exists());
            assert!((a.dx - (x - hx)).abs() < 0.02, "{a:?}");
            assert!((a.dy - (y - hy)).abs() < 0.02, "{a:?}");
            assert!((a.coef - height).abs() < 0.05, "{a:?}");
        }
        // the ratio of the integer peaks' heights (at lags (25, 13) and (9, 5))
        let ratio = corr[13 * cw + 25] as f64 / corr[5 * cw + 9] as f64;
        assert!((p.ratio - ratio).abs() < 1e-6, "{} {ratio}", p.ratio);
        assert_eq!(p.alt[0].coef, corr[5 * cw + 9] as f64);
        // a plane with a single peak has no alternatives... beyond the flat floor's maxima
        let single: Vec<f32> = (0..cw * ch)
            .map(|k| {
                let (c, r) = ((k % cw) as f64, (k / cw) as f64);
                (-((c - 20.0).powi(2) + (r - 10.0).powi(2)) / 3.0).exp() as f32
            })
            .collect();
        let p = find_peak(&single, cw, ch, big, big, SubPixel::Gauss3);
        assert!(
            p.alt.iter().all(|a| !a.exists() || a.coef < 1e-6),
            "{:?}",
            p.alt
        );
        assert!(!Peak::FAILED.alt[0].exists());
    }

    /// Particle images (Gaussian, 2.5 px diameter) of a pattern moved by `(dx, dy)` within
    /// +-0.1 px (the residual left after deformation), with Gaussian noise: the correlation's
    /// uncertainty against the scatter of its error (with residuals up to +-0.5 px, a pass
    /// without deformation, it is conservative: coverage 0.79, rms(err/sigma) 0.82 at 5 %
    /// noise).
    #[test]
    fn uncertainty_matches_the_error_of_noisy_windows() {
        use rand::{Rng, SeedableRng};
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (w, h, noise) in [(32usize, 32usize, 0.05f32), (32, 32, 0.15), (32, 8, 0.08)] {
            let mut c = Correlator::new(w, h);
            c.uncertainty = Uncertainty::AllPeaks;
            let nd = Normal::new(0.0f32, noise).unwrap();
            let (mut ratios, mut inside, mut n) = (Vec::new(), [0usize; 2], 0usize);
            for _ in 0..600 {
                let (dx, dy) = (
                    0.2 * (rng.random::<f64>() - 0.5),
                    0.2 * (rng.random::<f64>() - 0.5),
                );
                let np = (0.05 * ((w + 8) * (h + 8)) as f64) as usize;
                let parts: Vec<(f64, f64, f64)> = (0..np)
                    .map(|_| {
                        (
                            rng.random::<f64>() * (w + 8) as f64 - 4.0,
                            rng.random::<f64>() * (h + 8) as f64 - 4.0,
                            0.5 + rng.random::<f64>(),
                        )
                    })
                    .collect();
                let render = |out: &mut [f32], sx: f64, sy: f64| {
                    out.fill(0.0);
                    for &(px, py, a) in &parts {
                        for r in 0..h {
                            for q in 0..w {
                                let (ex, ey) = (q as f64 - px - sx, r as f64 - py - sy);
                                out[r * w + q] += (a * (-(ex * ex + ey * ey) / 0.78).exp()) as f32;
                            }
                        }
                    }
                };
                render(&mut c.wa, -dx / 2.0, -dy / 2.0);
                render(&mut c.wb, dx / 2.0, dy / 2.0);
                for v in c.wa.iter_mut().chain(c.wb.iter_mut()) {
                    *v += nd.sample(&mut rng);
                }
                let p = c.correlate(SubPixel::Gauss3);
                if !p.ok || p.ratio < 1.5 || !(p.sigma.0.is_finite() && p.sigma.1.is_finite()) {
                    continue;
                }
                let e = [p.dx - dx, p.dy - dy];
                let sg = [p.sigma.0, p.sigma.1];
                for k in 0..2 {
                    ratios.push(e[k] / sg[k]);
                    inside[k] += usize::from(e[k].abs() <= sg[k]);
                }
                n += 1;
            }
            let rms = (ratios.iter().map(|r| r * r).sum::<f64>() / ratios.len() as f64).sqrt();
            let cov = (inside[0] + inside[1]) as f64 / (2 * n) as f64;
            println!(
                "{w}x{h} noise {noise}: {n} peaks, rms(err/sigma) {rms:.3}, coverage {cov:.3}"
            );
            assert!(n > 500, "{n}");
            assert!(
                (0.8..=1.25).contains(&rms),
                "{w}x{h} noise {noise}: rms {rms}"
            );
            assert!(
                (0.6..=0.76).contains(&cov),
                "{w}x{h} noise {noise}: coverage {cov}"
            );
        }
    }

    /// `sigma_at` (the lag-0 run over the whole window and the row-wise sums at other lags)
    /// against the definition summed pixel by pixel.
    #[test]
    fn uncertainty_sums_match_the_definition() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut checked = 0;
        let shapes = [(32usize, 32usize), (32, 8), (10, 6)];
        for (w, h) in shapes.into_iter().cycle().take(15) {
            let mut c = Correlator::new(w, h);
            c.uncertainty = Uncertainty::Peak;
            for v in c.wa.iter_mut().chain(c.wb.iter_mut()) {
                *v = rng.random::<f32>() * 100.0;
            }
            c.correlate(SubPixel::Gauss3);
            let (cw, ch) = (c.cw, c.ch);
            for (tx, ty) in [(0isize, 0isize), (1, -1), (-2, 1)] {
                let (pc, pr) = ((cw / 2) as isize + tx, (ch / 2) as isize + ty);
                let got = c.sigma_at((pc as usize, pr as usize), 1.0);
                // the definition
                let a = |x: isize, y: isize| c.ca[(y * w as isize + x) as usize] as f64;
                let b = |x: isize, y: isize| c.cb[(y * w as isize + x) as usize] as f64;
                let inside = |x: isize, y: isize, dx: isize, dy: isize| {
                    let ok =
                        |x: isize, y: isize| x >= 0 && y >= 0 && x < w as isize && y < h as isize;
                    ok(x, y)
                        && ok(x + dx, y + dy)
                        && ok(x + tx, y + ty)
                        && ok(x + tx + dx, y + ty + dy)
                };
                let var = |dx: isize, dy: isize| {
                    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
                    for y in 0..h as isize {
                        for x in 0..w as isize {
                            if inside(x, y, dx, dy) {
                                let d = a(x, y) * b(x + tx + dx, y + ty + dy)
                                    - a(x + dx, y + dy) * b(x + tx, y + ty);
                                s += d;
                                s2 += d * d;
                                n += 1.0;
                            }
                        }
                    }
                    s2 - s * s / n
                };
                let overlap =
                    (1.0 - tx.abs() as f64 / w as f64) * (1.0 - ty.abs() as f64 / h as f64);
                let at = |cc: isize, rr: isize| {
                    let ox = 1.0 - (cc - (cw / 2) as isize).abs() as f64 / w as f64;
                    let oy = 1.0 - (rr - (ch / 2) as isize).abs() as f64 / h as f64;
                    c.corr[(rr * cw as isize + cc) as usize] as f64 / (ox * oy)
                };
                let want = (
                    var(1, 0).sqrt() / overlap
                        * gauss3_slope(at(pc - 1, pr), at(pc, pr), at(pc + 1, pr)),
                    var(0, 1).sqrt() / overlap
                        * gauss3_slope(at(pc, pr - 1), at(pc, pr), at(pc, pr + 1)),
                );
                for (g, e) in [(got.0, want.0), (got.1, want.1)] {
                    checked += usize::from(e.is_finite());
                    assert!(
                        (g.is_nan() && e.is_nan()) || (g - e).abs() <= 1e-4 * e.abs(),
                        "{w}x{h} lag ({tx}, {ty}): {got:?} vs {want:?}"
                    );
                }
            }
        }
        assert!(checked >= 20, "{checked} finite comparisons");
    }

    #[test]
    fn portable_and_avx2_paths_agree_exactly() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for (w, h) in [(32usize, 32usize), (32, 8), (10, 6), (128, 32)] {
            let mut c = Correlator::new(w, h);
            c.uncertainty = Uncertainty::AllPeaks;
            for v in c.wa.iter_mut().chain(c.wb.iter_mut()) {
                *v = rng.random::<f32>() * 4095.0;
            }
            for sub in [SubPixel::Gauss3, SubPixel::Gauss2d] {
                let p = c.correlate(sub);
                let plane = c.plane().0.to_vec();
                let q = c.correlate_impl(sub);
                assert_eq!(p, q, "{w}x{h}");
                assert_eq!(plane, c.plane().0, "{w}x{h}");
            }
        }
    }

    #[test]
    fn blank_window_fails_cleanly() {
        let mut c = Correlator::new(16, 16);
        c.wa.fill(3.0);
        c.wb.fill(1.0);
        assert!(!c.correlate(SubPixel::Gauss3).ok);
    }
}
