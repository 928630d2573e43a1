//! The particle images' diameter, measured from the correlation peaks, and the peak-locking
//! check that it feeds.
//!
//! A correlation peak of two windows of the same Gaussian particle images (standard deviation
//! `s` px each, as recorded: the optics' image integrated over the pixel) is a Gaussian of
//! standard deviation `sqrt(2) s`; its width along x and y comes with every 3-point fit
//! ([`crate::Peak::width`]). The particle images' e^-2 diameter is `d = 4 s = 2 sqrt(2)` times
//! the peak's width. [`particle_diameter`] takes the median over the confident peaks
//! (`peak ratio >= `[`DIAMETER_MIN_PEAK_RATIO`]: a peak of camera noise is about one pixel wide
//! whatever the particles) of the *first* pass, whose windows are cut from the frames as
//! recorded: the later passes read interpolated (deformed or sub-pixel offset) frames, whose
//! interpolation widens particle images under 2 px by 10-25 %. A displacement that varies
//! across a window widens its peak too (along x for `du/dy`), so the diameter is an upper
//! bound in a strongly sheared field; the smaller of the two axes is the better estimate.
//!
//! Measured on synthetic particle images of known size (`render_particles`, pixel-integrated;
//! passes 64 -> 32 -> 32 x 8): the diameter comes back 1-4 % under the recorded one (e.g.
//! 1.51 px for particles of nominal diameter 1.0, whose pixel-integrated image has 1.53 px).
//!
//! Particle images under about 2 px are known to bias every sub-pixel fit towards whole pixels
//! (peak locking; Westerweel 1997, Raffel et al. 2018 ch. 5): the displacement's fractional
//! part is pulled towards 0, the bias a sine of it. It does not average out: the mean and the
//! fluctuations of a whole campaign carry it, and the per-vector uncertainty (the correlation
//! statistics) does not see it. [`peak_locking_warning`] names it in one line.

use crate::correlate::{Correlator, Peak, SubPixel};
use crate::error::{PivError, Result};
use crate::multipass::{check_mask, check_pair};
use image_core::Pixel;
use ndarray::ArrayView2;
use rayon::prelude::*;

/// The peaks that measure the particle images: peak ratio at least this (the median over the
/// windows of a real recording is about 3 or more; camera noise 1.1-1.2, its peaks a pixel
/// wide).
pub const DIAMETER_MIN_PEAK_RATIO: f64 = 2.0;

/// A peak at least this high (the normalised correlation coefficient) comes from the same
/// pixels in both windows: frame A given twice, or a static pattern that dominates the window.
/// Its width is that of the autocorrelation, narrowed by the noise it shares with itself (1 px
/// for camera noise, 2.5 px for OpenPIV's `test1` whose images read 2.5-3.2 px against their
/// partner): not the particle images', so such peaks are left out. Real pairs give 0.3-0.9.
pub const DIAMETER_MAX_COEF: f64 = 0.999;

/// Fewer confident peaks than this: the diameter is not measured (NaN).
pub const DIAMETER_MIN_WINDOWS: usize = 16;

/// Particle images whose diameter (e^-2, as recorded, [`particle_diameter`]) is under this
/// along either axis lock the sub-pixel displacements towards whole pixels by more than about
/// a hundredth of a pixel ([`peak_locking_warning`]). Measured on synthetic particle images
/// (`python benches/bench_accuracy.py --only particle-size`: 2048 x 1024 px, 0.03
/// particles/px, 5 % noise, passes 64 -> 32 -> 32 x 8, symmetric deformation or window
/// offset alike), the amplitude of the bias `-a sin(2 pi t)` in the true displacement `t`:
/// 0.050 px at a diameter of 1.39 px, 0.036 at 1.48, 0.027 at 1.61, 0.018 at 1.75, 0.011 at
/// 1.91, 0.003 at 2.24, 0.001 at 2.68 px.
pub const MIN_PARTICLE_DIAMETER: f64 = 2.0;

/// The particle images' e^-2 diameter (px, as recorded) along x and y: `2 sqrt(2)` times the
/// median width of the confident correlation peaks among `peaks` (peak ratio at least
/// [`DIAMETER_MIN_PEAK_RATIO`], coefficient under [`DIAMETER_MAX_COEF`]; see the module
/// notes); NaN along an axis with fewer than [`DIAMETER_MIN_WINDOWS`] of them.
pub fn particle_diameter(peaks: &[Peak]) -> (f64, f64) {
    let confident = || {
        peaks
            .iter()
            .filter(|p| p.ok && p.ratio >= DIAMETER_MIN_PEAK_RATIO && p.coef < DIAMETER_MAX_COEF)
    };
    let axis = |w: fn(&Peak) -> f64| {
        let mut a: Vec<f64> = confident().map(w).filter(|x| x.is_finite()).collect();
        if a.len() < DIAMETER_MIN_WINDOWS {
            return f64::NAN;
        }
        let mid = a.len() / 2;
        let (_, m, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
        2.0 * std::f64::consts::SQRT_2 * *m
    };
    (axis(|p| p.width.0), axis(|p| p.width.1))
}

/// Most windows [`measure`] correlates.
pub const MEASURE_WINDOWS: usize = 4096;

/// The particle images' e^-2 diameter (px, along x and y) of a frame pair as recorded:
/// [`particle_diameter`] of up to [`MEASURE_WINDOWS`] window pairs of `w` x `h` px cut from the
/// frames at the same place (no offset: a displacement of up to half the window is found, as in
/// a first pass), on a regular grid of whole windows side by side, every `k`-th along x and y
/// when there are more; a window whose centre is masked is left out; `backgrounds` (of frames
/// A and B) are subtracted from the windows, clipped at 0, as the conditioning does. What
/// `rspiv.piv` reports for the frames as recorded when it conditions or dewarps them itself:
/// a high-pass narrows the correlation peaks without making the particle images smaller (2.7
/// px images read 2.0-2.2 px after a 2 px high-pass), the hot-pixel rule flattens images under
/// 2 px (1.6 px images read 1.9 px after it), and an interpolation widens images under 2 px.
///
/// # Errors
/// [`PivError::InvalidInput`] for frames of different shapes, a mask or a background of
/// another shape, or windows under 4 px or larger than the frames.
pub fn measure<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    (w, h): (usize, usize),
    mask: Option<ArrayView2<'_, bool>>,
    backgrounds: Option<(ArrayView2<'_, f32>, ArrayView2<'_, f32>)>,
) -> Result<(f64, f64)> {
    check_pair(&frame_a, &frame_b)?;
    let (rows, cols) = frame_a.dim();
    check_mask(&mask, (rows, cols))?;
    if let Some((ba, bb)) = &backgrounds {
        if ba.dim() != (rows, cols) || bb.dim() != (rows, cols) {
            return Err(PivError::InvalidInput(format!(
                "backgrounds {:?} and {:?} differ in shape from the frames {:?}",
                ba.dim(),
                bb.dim(),
                (rows, cols)
            )));
        }
    }
    if w < 4 || h < 4 || w > cols || h > rows {
        return Err(PivError::InvalidInput(format!(
            "window {w} x {h} px: at least 4 x 4 and at most the frames' {cols} x {rows}"
        )));
    }
    let (nx, ny) = (cols / w, rows / h);
    let k = ((nx * ny) as f64 / MEASURE_WINDOWS as f64)
        .sqrt()
        .ceil()
        .max(1.0) as usize;
    let (x0, y0) = ((cols - nx * w) / 2, (rows - ny * h) / 2);
    let peaks: Vec<Peak> = (0..ny)
        .step_by(k)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map_init(
            || Correlator::new(w, h),
            |c, j| {
                let mut row = Vec::new();
                for i in (0..nx).step_by(k) {
                    let (xa, ya) = (x0 + i * w, y0 + j * h);
                    if mask.is_some_and(|m| m[[ya + h / 2, xa + w / 2]]) {
                        continue;
                    }
                    for r in 0..h {
                        for q in 0..w {
                            let (y, x) = (ya + r, xa + q);
                            let (mut va, mut vb) =
                                (frame_a[[y, x]].to_f32(), frame_b[[y, x]].to_f32());
                            if let Some((ba, bb)) = &backgrounds {
                                va = (va - ba[[y, x]]).max(0.0);
                                vb = (vb - bb[[y, x]]).max(0.0);
                            }
                            c.wa[r * w + q] = va;
                            c.wb[r * w + q] = vb;
                        }
                    }
                    row.push(c.correlate(SubPixel::Gauss3));
                }
                row
            },
        )
        .flatten()
        .collect();
    Ok(particle_diameter(&peaks))
}

/// The one-line warning for particle images too small for a sub-pixel fit (under
/// [`MIN_PARTICLE_DIAMETER`] along x or y), `None` otherwise or when not measured (NaN).
pub fn peak_locking_warning(diameter: (f64, f64)) -> Option<String> {
    let (dx, dy) = diameter;
    let small = |d: f64| d < MIN_PARTICLE_DIAMETER;
    if !(small(dx) || small(dy)) {
        return None;
    }
    Some(format!(
        "the particle images are {dx:.1} x {dy:.1} px across (e^-2 diameter along x and y, from \
         the correlation peaks), under {MIN_PARTICLE_DIAMETER:.0} px: the sub-pixel \
         displacements lean towards whole pixels (peak locking: a bias of up to 0.01 px at 1.9 \
         px, 0.04 px at 1.5 px on synthetic images) that the uncertainties do not include and \
         that does not average out; a slight defocus (to 2-3 px) removes it, smoothing both \
         frames (preprocess smooth = 0.7 px) about halves it"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correlate::Correlator;
    use crate::synth::render_particles;
    use crate::SubPixel;
    use rand::{Rng, SeedableRng};

    fn peak(w: (f64, f64), ratio: f64) -> Peak {
        Peak {
            ratio,
            ok: true,
            width: w,
            coef: 0.6,
            ..Peak::FAILED
        }
    }

    #[test]
    fn the_median_of_the_confident_peaks() {
        // 20 confident peaks of width 0.6 / 0.8 px, 30 noise peaks of 0.3 px, NaN widths
        let mut peaks: Vec<Peak> = (0..20).map(|_| peak((0.6, 0.8), 3.0)).collect();
        peaks.extend((0..30).map(|_| peak((0.3, 0.3), 1.2)));
        peaks.extend((0..5).map(|_| peak((f64::NAN, f64::NAN), 5.0)));
        let (dx, dy) = particle_diameter(&peaks);
        let k = 2.0 * std::f64::consts::SQRT_2;
        assert!((dx - 0.6 * k).abs() < 1e-12 && (dy - 0.8 * k).abs() < 1e-12);
        // too few confident peaks: not measured
        let (dx, dy) = particle_diameter(&peaks[10..]);
        assert!(dx.is_nan() && dy.is_nan());
        // peaks of a window with itself (coefficient 1) are not the particle images'
        let same: Vec<Peak> = (0..40)
            .map(|_| Peak {
                coef: 1.0,
                ..peak((0.3, 0.3), 50.0)
            })
            .collect();
        let (dx, dy) = particle_diameter(&same);
        assert!(dx.is_nan() && dy.is_nan());
        assert!(peak_locking_warning((dx, dy)).is_none());
    }

    #[test]
    fn measure_refuses_what_it_cannot_use() {
        let a = ndarray::Array2::<f32>::zeros((64, 64));
        let b = ndarray::Array2::<f32>::zeros((64, 70));
        assert!(measure(a.view(), b.view(), (32, 32), None, None).is_err());
        assert!(measure(a.view(), a.view(), (128, 32), None, None).is_err());
        let m = ndarray::Array2::from_elem((10, 10), false);
        assert!(measure(a.view(), a.view(), (32, 32), Some(m.view()), None).is_err());
        let bg = Some((a.view(), b.view()));
        assert!(measure(a.view(), a.view(), (32, 32), None, bg).is_err());
        // blank frames: nothing measured
        let (dx, dy) = measure(a.view(), a.view(), (16, 16), None, None).unwrap();
        assert!(dx.is_nan() && dy.is_nan());
    }

    #[test]
    fn the_warning_names_the_small_axis() {
        assert!(peak_locking_warning((2.4, 2.1)).is_none());
        let w = peak_locking_warning((2.4, 1.6)).expect("warned");
        assert!(
            w.contains("2.4 x 1.6 px") && w.contains("peak locking"),
            "{w}"
        );
        assert!(!w.contains('\n'));
        assert!(peak_locking_warning((1.2, f64::NAN)).is_some());
    }

    /// The diameter of rendered particle images comes back from the correlation peaks of
    /// whole-pixel windows: `d^2 / 16 + 1 / 12` is the variance of a Gaussian image of e^-2
    /// diameter `d` integrated over a pixel (approximately).
    #[test]
    fn rendered_particle_images_measure_their_diameter() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (h, w) = (256usize, 256usize);
        for d in [1.0f64, 1.6, 2.5, 4.0] {
            let n = (0.02 * (h * w) as f64) as usize;
            let xs: Vec<f64> = (0..n)
                .map(|_| rng.random_range(-4.0..w as f64 + 4.0))
                .collect();
            let ys: Vec<f64> = (0..n)
                .map(|_| rng.random_range(-4.0..h as f64 + 4.0))
                .collect();
            let peak_i: Vec<f64> = (0..n).map(|_| rng.random_range(120.0..200.0)).collect();
            let (dx, dy) = (0.3, -0.6);
            let xb: Vec<f64> = xs.iter().map(|x| x + dx).collect();
            let yb: Vec<f64> = ys.iter().map(|y| y + dy).collect();
            let a = render_particles(h, w, &xs, &ys, &peak_i, &[d], 3.0, 255, 1).unwrap();
            let b = render_particles(h, w, &xb, &yb, &peak_i, &[d], 3.0, 255, 2).unwrap();
            let mut c = Correlator::new(32, 32);
            let mut peaks = Vec::new();
            for j in (0..h - 32).step_by(16) {
                for i in (0..w - 32).step_by(16) {
                    for r in 0..32 {
                        for q in 0..32 {
                            c.wa[r * 32 + q] = a[[j + r, i + q]] as f32;
                            c.wb[r * 32 + q] = b[[j + r, i + q]] as f32;
                        }
                    }
                    peaks.push(c.correlate(SubPixel::Gauss3));
                }
            }
            let (mx, my) = particle_diameter(&peaks);
            // the sampled measurement of the whole pair: the same windows, the same answer
            let fa = a.mapv(|v| v as f32);
            let fb = b.mapv(|v| v as f32);
            let sampled = measure(fa.view(), fb.view(), (32, 32), None, None).unwrap();
            let near = |p: f64, q: f64| (p / q - 1.0).abs() < 0.03;
            assert!(
                near(sampled.0, mx) && near(sampled.1, my),
                "{sampled:?} {mx} {my}"
            );
            let recorded = 4.0 * (d * d / 16.0 + 1.0 / 12.0).sqrt();
            for m in [mx, my] {
                assert!(
                    (m / recorded - 1.0).abs() < 0.06,
                    "d {d}: {m} vs {recorded}"
                );
            }
            assert_eq!(peak_locking_warning((mx, my)).is_some(), recorded < 2.0);
        }
    }
}
