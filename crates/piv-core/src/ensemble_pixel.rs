//! Single-pixel ensemble correlation along rows (Westerweel, Geelhoed & Lindken 2004; Kähler,
//! Scholz & Ortmanns 2006): the correlation of one pixel row of frame A with the rows of frame B
//! around it, summed over many pairs and along the row (a flow homogeneous along it, e.g. a
//! boundary layer along the wall), so that the wall-normal resolution is one pixel (the
//! particle image's size) instead of a window's height.
//!
//! # The accumulator
//!
//! A band of `n` rows, each cut into `nseg` segments of `seg` px along x (segment `j` of a row
//! covers the pixel centres `x0 + j seg ..= x0 + j seg + seg - 1`) at its own y (`y[k nseg + j]`,
//! a pixel centre or between two: the rows can follow a tilted wall) and its own predictor
//! `(du, dv)` (frame A sampled at `p - d/2`, frame B at `p + d/2`, interpolated as
//! [`Interpolation`] says). For one pair, [`accumulate`] adds to each row of the accumulator
//! ([`stride`] f64 values):
//! - the cross plane `C(sx, sy) = sum a'(x) b'(x + sx, y + sy) / sqrt(sum a'^2 sum b'^2)` for
//!   lags `-rx ..= rx` by `-ry ..= ry` (`a'`: the A row less its mean; `b'`: each B row of the
//!   strip less its own mean; each segment its own), the sums over all the row's segments of
//!   the pair, times the number of segments (so that every pair counts alike whatever its
//!   brightness, and each segment once);
//! - the auto planes of the A row against the A strip and of the B row against the B strip
//!   (each normalised by its row's energy over the segments), summed;
//! - the segments added to each.
//!
//! The products are summed over the row before they are normalised, not normalised segment by
//! segment: a 64 px segment holds a few particle images, and the mean of per-segment ratios
//! weights each particle by its segment's other particles (a segment with one faint image
//! counts as much as one with five bright ones), which makes the expected plane a non-linear
//! function of the particles. Summed over the row (13 segments on the tests' 886 px frames,
//! 138 on a 47 MP sensor), the expected plane is the sum of each particle's, which
//! `rspiv.ensemble_pixel_model` models exactly next to the wall (its masked pixels, mirror
//! images and interpolation).
//!
//! No lag loses pixels (the strips are `2 rx` wider than the segment), so unlike a window's
//! plane none needs an overlap correction. Segments whose centre is masked, whose strips reach
//! outside the image, or whose rows are blank are not added. Accumulators of the same band merge
//! by adding them.
//!
//! # The result
//!
//! [`peaks`] fits each row's mean planes as [`crate::ensemble::peaks`] does a window's (a
//! Gaussian on a constant baseline, the zero lag of the auto plane and the maximum of the cross
//! plane left out): the centre is the mean displacement relative to the predictor, `C_cross -
//! C_auto` the displacement covariance at that row (px^2), with no window to spread the mean
//! gradient over (the particle image's own height does, and is in both peaks).

use crate::ensemble::{baseline_fit, peak_ratio, split_fit, EnsemblePeak, MIN_PEAK_RATIO};
use crate::error::{PivError, Result};
use crate::image::{inside, Pixel};
use crate::multipass::{check_mask, check_pair, excluded_point, Frames, Interpolation};
use ndarray::ArrayView2;
use rayon::prelude::*;

/// The band of a single-pixel ensemble (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct PixelBand<'a> {
    /// Segment length along x, px (>= 8).
    pub seg: usize,
    /// Segments per row.
    pub nseg: usize,
    /// x of the first segment's first pixel centre.
    pub x0: f64,
    /// Lag half-ranges along x and y (>= 1).
    pub rx: usize,
    pub ry: usize,
    /// Per segment (`rows * nseg`, row-major): its row's y and its predictor, px.
    pub y: &'a [f64],
    pub du: &'a [f64],
    pub dv: &'a [f64],
}

/// Values per row of the accumulator: `cross[(2rx+1)(2ry+1)]`, `auto[..]`, `n_cross`, `n_auto`.
pub fn stride(rx: usize, ry: usize) -> usize {
    2 * (2 * rx + 1) * (2 * ry + 1) + 2
}

impl PixelBand<'_> {
    /// Rows of the band.
    pub fn rows(&self) -> usize {
        self.y.len().checked_div(self.nseg).unwrap_or(0)
    }

    /// Segments of at least 8 px, lags of at least 1, per-segment arrays of one length
    /// (whole rows), finite.
    pub fn check(&self) -> Result<()> {
        if self.seg < 8 || self.nseg == 0 || self.rx == 0 || self.ry == 0 {
            return Err(PivError::InvalidInput(format!(
                "single-pixel band: segments of {} px (at least 8), {} per row, lags +-{} x +-{} \
                 (at least 1)",
                self.seg, self.nseg, self.rx, self.ry
            )));
        }
        let n = self.y.len();
        if n == 0 || n % self.nseg != 0 || self.du.len() != n || self.dv.len() != n {
            return Err(PivError::InvalidInput(format!(
                "single-pixel band: y ({}), du ({}) and dv ({}) must hold whole rows of {} segments",
                n,
                self.du.len(),
                self.dv.len(),
                self.nseg
            )));
        }
        let all = self.y.iter().chain(self.du).chain(self.dv);
        if !self.x0.is_finite() || all.into_iter().any(|v| !v.is_finite()) {
            return Err(PivError::InvalidInput(
                "single-pixel band: a position or predictor is NaN or infinite".into(),
            ));
        }
        Ok(())
    }
}

/// Add one frame pair to `acc` (`rows` x [`stride`]); the auto planes too when `auto`. Returns
/// the segments added. Errors: frames of different shapes or with NaN/inf, a mask of another
/// shape, a bad band ([`PixelBand::check`]), an accumulator of the wrong length.
pub fn accumulate<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    band: &PixelBand<'_>,
    interpolation: Interpolation,
    auto: bool,
    acc: &mut [f64],
) -> Result<usize> {
    band.check()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    check_mask(&mask, dim)?;
    let st = stride(band.rx, band.ry);
    let rows = band.rows();
    if acc.len() != rows * st {
        return Err(PivError::InvalidInput(format!(
            "single-pixel accumulator holds {} values, {} rows of lags +-{} x +-{} need {}",
            acc.len(),
            rows,
            band.rx,
            band.ry,
            rows * st
        )));
    }
    let frames = Frames::new(frame_a, frame_b, interpolation)?;
    let (sw, sh) = (band.seg + 2 * band.rx, 2 * band.ry + 1);
    let np = (2 * band.rx + 1) * sh;
    let used = acc
        .par_chunks_mut(st)
        .enumerate()
        .map(|(k, row)| {
            let mut sa = vec![0.0f32; sw * sh];
            let mut sb = vec![0.0f32; sw * sh];
            // this pair's raw sums over the row's segments, normalised once at the end
            let mut sums = vec![0.0f64; 3 * np];
            let (mut ea, mut eb) = (0.0f64, 0.0f64);
            let mut added = 0usize;
            for j in 0..band.nseg {
                let i = k * band.nseg + j;
                let (y, du, dv) = (band.y[i], band.du[i], band.dv[i]);
                let left = band.x0 + (j * band.seg) as f64;
                let xc = left + (band.seg as f64 - 1.0) / 2.0;
                if excluded_point(&mask, dim, xc, y) {
                    continue;
                }
                let a0 = (
                    left - band.rx as f64 - du / 2.0,
                    y - band.ry as f64 - dv / 2.0,
                );
                let b0 = (
                    left - band.rx as f64 + du / 2.0,
                    y - band.ry as f64 + dv / 2.0,
                );
                let (ew, eh) = ((sw - 1) as f64, (sh - 1) as f64);
                let fits = |p: (f64, f64)| {
                    inside(p.0, p.1, dim.1, dim.0) && inside(p.0 + ew, p.1 + eh, dim.1, dim.0)
                };
                if !(fits(a0) && fits(b0)) {
                    continue;
                }
                frames.shift_pair((sw, sh), a0, b0, &mut sa, &mut sb);
                remove_row_means(&mut sa, sw);
                remove_row_means(&mut sb, sw);
                let (e1, e2) = (centre_energy(&sa, band), centre_energy(&sb, band));
                let norm = (e1 * e2).sqrt();
                if norm.is_nan() || norm <= 1e-12 {
                    continue; // a blank row
                }
                let (cross, autos) = sums.split_at_mut(np);
                products(&sa, &sb, band, cross);
                if auto {
                    let (aa, ab) = autos.split_at_mut(np);
                    products(&sa, &sa, band, aa);
                    products(&sb, &sb, band, ab);
                }
                ea += e1;
                eb += e2;
                added += 1;
            }
            if added > 0 {
                // the mean normalised plane of this pair's row, counted once per segment
                let n = added as f64;
                let (cross, autos) = sums.split_at(np);
                let norm = (ea * eb).sqrt();
                let (out, rest) = row.split_at_mut(np);
                for (o, &c) in out.iter_mut().zip(cross) {
                    *o += n * c / norm;
                }
                rest[np] += n;
                if auto {
                    let (aa, ab) = autos.split_at(np);
                    for ((o, &p), &q) in rest[..np].iter_mut().zip(aa).zip(ab) {
                        *o += n * (p / ea + q / eb);
                    }
                    rest[np + 1] += 2.0 * n;
                }
            }
            added
        })
        .sum();
    Ok(used)
}

/// Each strip row less its mean.
fn remove_row_means(strip: &mut [f32], w: usize) {
    for r in strip.chunks_mut(w) {
        let m = r.iter().map(|&v| v as f64).sum::<f64>() / w as f64;
        for v in r.iter_mut() {
            *v -= m as f32;
        }
    }
}

/// The energy (sum of squares) of the centre row of a strip `s` over its segment (columns
/// `rx .. rx + seg`).
fn centre_energy(s: &[f32], band: &PixelBand<'_>) -> f64 {
    let sw = band.seg + 2 * band.rx;
    let a = &s[band.ry * sw + band.rx..band.ry * sw + band.rx + band.seg];
    a.iter().map(|&v| (v as f64) * (v as f64)).sum()
}

/// Add the products of the centre row of `s` (its segment: columns `rx .. rx + seg`) with
/// every row of `t` at each lag to `out` (not normalised).
fn products(s: &[f32], t: &[f32], band: &PixelBand<'_>, out: &mut [f64]) {
    let (seg, rx, ry) = (band.seg, band.rx, band.ry);
    let sw = seg + 2 * rx;
    let a = &s[ry * sw + rx..ry * sw + rx + seg];
    let cw = 2 * rx + 1;
    for r in 0..2 * ry + 1 {
        let trow = &t[r * sw..(r + 1) * sw];
        for c in 0..cw {
            let sum: f32 = a.iter().zip(&trow[c..c + seg]).map(|(p, q)| p * q).sum();
            out[r * cw + c] += sum as f64;
        }
    }
}

/// Fit every row's mean planes in `acc` (see the module docs).
pub fn peaks(acc: &[f64], rx: usize, ry: usize) -> Result<Vec<EnsemblePeak>> {
    let st = stride(rx, ry);
    if rx == 0 || ry == 0 || acc.len() % st != 0 {
        return Err(PivError::InvalidInput(format!(
            "single-pixel accumulator of {} values is not whole rows of {} (lags +-{} x +-{})",
            acc.len(),
            st,
            rx,
            ry
        )));
    }
    let (cw, ch) = (2 * rx + 1, 2 * ry + 1);
    Ok(acc.par_chunks(st).map(|row| fit_row(row, cw, ch)).collect())
}

fn fit_row(row: &[f64], cw: usize, ch: usize) -> EnsemblePeak {
    let np = cw * ch;
    let (nc, na) = (row[2 * np], row[2 * np + 1]);
    let failed = EnsemblePeak {
        dx: f64::NAN,
        dy: f64::NAN,
        cross: (f64::NAN, f64::NAN, f64::NAN),
        auto: (f64::NAN, f64::NAN, f64::NAN),
        auto_centre: (f64::NAN, f64::NAN),
        coef: 0.0,
        peak_ratio: f64::NAN,
        count: (nc, na),
        ok: false,
    };
    if nc <= 0.0 {
        return failed;
    }
    let cross = &row[..np];
    let (mut pc, mut pr, mut best) = (0, 0, f64::NEG_INFINITY);
    for r in 1..ch - 1 {
        for c in 1..cw - 1 {
            if cross[r * cw + c] > best {
                (pc, pr, best) = (c, r, cross[r * cw + c]);
            }
        }
    }
    let coef = best / nc;
    let ratio = peak_ratio(cross, cw);
    let failed = EnsemblePeak {
        coef,
        peak_ratio: ratio,
        ..failed
    };
    if ratio.is_nan() || ratio < MIN_PEAK_RATIO {
        return failed;
    }
    let Some((mx, my, cov)) = baseline_fit(|c, r| cross[r * cw + c] / nc, cw, ch, (pc, pr), true)
    else {
        return failed;
    };
    let (auto_centre, auto) = split_fit(if na > 0.0 {
        let plane = &row[np..2 * np];
        baseline_fit(
            |c, r| plane[r * cw + c] / na,
            cw,
            ch,
            (cw / 2, ch / 2),
            true,
        )
    } else {
        None
    });
    EnsemblePeak {
        dx: pc as f64 - (cw / 2) as f64 + mx,
        dy: pr as f64 - (ch / 2) as f64 + my,
        cross: cov,
        auto,
        auto_centre,
        coef,
        peak_ratio: ratio,
        count: (nc, na),
        ok: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render_particles;
    use rand::{Rng, SeedableRng};

    /// Rows moved by a profile u(y) that changes every pixel row: each row's peak gives its own
    /// displacement, where a window would average several rows.
    #[test]
    fn each_row_gets_its_own_displacement() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let (h, w) = (48usize, 512usize);
        let prof = |y: f64| 0.5 + 0.12 * (y - 8.0);
        let (rx, ry, seg) = (4usize, 2usize, 64usize);
        let rows: Vec<f64> = (12..36).map(|r| r as f64).collect();
        let nseg = (w - 2 * 8) / seg;
        let ys: Vec<f64> = rows.iter().flat_map(|&y| vec![y; nseg]).collect();
        let du: Vec<f64> = ys.iter().map(|&y| prof(y).round()).collect();
        let dv = vec![0.0; ys.len()];
        let band = PixelBand {
            seg,
            nseg,
            x0: 8.0,
            rx,
            ry,
            y: &ys,
            du: &du,
            dv: &dv,
        };
        let mut acc = vec![0.0; rows.len() * stride(rx, ry)];
        for _ in 0..60 {
            let n = (0.04 * (h * w) as f64) as usize;
            let (mut xa, mut ya, mut xb, mut yb) = (vec![], vec![], vec![], vec![]);
            for _ in 0..n {
                let (x, y) = (
                    rng.random_range(-4.0..w as f64 + 4.0),
                    rng.random_range(-4.0..h as f64 + 4.0),
                );
                let u = prof(y);
                xa.push(x - u / 2.0);
                ya.push(y);
                xb.push(x + u / 2.0);
                yb.push(y);
            }
            let inten = vec![1000.0; n];
            let fa =
                render_particles(h, w, &xa, &ya, &inten, &[2.5], 10.0, 4095, rng.random()).unwrap();
            let fb =
                render_particles(h, w, &xb, &yb, &inten, &[2.5], 10.0, 4095, rng.random()).unwrap();
            let added = accumulate(
                fa.view(),
                fb.view(),
                None,
                &band,
                Interpolation::BSpline,
                true,
                &mut acc,
            )
            .unwrap();
            assert_eq!(added, rows.len() * nseg);
        }
        let res = peaks(&acc, rx, ry).unwrap();
        for (k, p) in res.iter().enumerate() {
            assert!(p.ok);
            let u = du[k * nseg] + p.dx;
            assert!(
                (u - prof(rows[k])).abs() < 0.03,
                "row {} got {u} want {}",
                rows[k],
                prof(rows[k])
            );
            // the wall-normal centre from +-2 lags of a 2.5 px particle image: noisier
            assert!(p.dy.abs() < 0.1, "row {} dy {}", rows[k], p.dy);
        }
    }

    #[test]
    fn bad_input_is_one_line() {
        let ys = vec![10.0; 3];
        let z = vec![0.0; 3];
        let band = PixelBand {
            seg: 4,
            nseg: 3,
            x0: 0.0,
            rx: 2,
            ry: 1,
            y: &ys,
            du: &z,
            dv: &z,
        };
        let f = ndarray::Array2::<f32>::zeros((32, 64));
        let mut acc = vec![0.0; stride(2, 1)];
        let e = accumulate(
            f.view(),
            f.view(),
            None,
            &band,
            Interpolation::Keys,
            true,
            &mut acc,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("segments of 4 px") && !e.contains('\n'), "{e}");
        let band = PixelBand { seg: 8, ..band };
        let mut short = vec![0.0; 3];
        let e = accumulate(
            f.view(),
            f.view(),
            None,
            &band,
            Interpolation::Keys,
            true,
            &mut short,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("accumulator holds 3 values"), "{e}");
        assert!(peaks(&[0.0; 5], 2, 1)
            .unwrap_err()
            .to_string()
            .contains("not whole rows"));
    }
}
