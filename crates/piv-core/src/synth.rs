//! Rendering of synthetic particle images: Gaussian particles integrated over the pixel area.
//!
//! A particle at (xp, yp) (pixel frame) with peak intensity `I0` (counts) and e^-2 diameter `d`
//! (px; standard deviation `d / 4`) contributes to pixel (i, j)
//! `I0 * pi d^2 / 32 * [erf((i + 1/2 - xp) sqrt(8)/d) - erf((i - 1/2 - xp) sqrt(8)/d)]
//!  * [erf((j + 1/2 - yp) sqrt(8)/d) - erf((j - 1/2 - yp) sqrt(8)/d)]`,
//! the exact integral of `I0 exp(-8 r^2 / d^2)` over the pixel's square. Gaussian noise of
//! standard deviation `noise_sigma` counts is added, and the result is rounded and clipped to
//! `[0, max_count]`.

use crate::error::{PivError, Result};
use ndarray::Array2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;

pub use image_core::erf;

const BAND: usize = 16;

/// Render particles into a `height` x `width` image of counts.
///
/// `x`, `y`: particle centres (px, pixel frame; particles outside the image still contribute
/// their tails); `intensity`: peak intensity of each particle (counts); `diameter`: e^-2
/// diameter in px, one value for all (`len() == 1`) or one per particle; `noise_sigma`:
/// standard deviation of additive Gaussian noise (counts); `max_count`: saturation level
/// (4095 for 12-bit). Deterministic for a given `seed` whatever the number of threads (the
/// noise of row `j` comes from stream `j` of a ChaCha8 generator seeded with `seed`).
pub fn render_particles(
    height: usize,
    width: usize,
    x: &[f64],
    y: &[f64],
    intensity: &[f64],
    diameter: &[f64],
    noise_sigma: f64,
    max_count: u16,
    seed: u64,
) -> Result<Array2<u16>> {
    let n = x.len();
    if height == 0 || width == 0 {
        return Err(PivError::InvalidInput(format!(
            "image shape {height} x {width} is empty"
        )));
    }
    if y.len() != n || intensity.len() != n {
        return Err(PivError::InvalidInput(format!(
            "x ({n}), y ({}) and intensity ({}) differ in length",
            y.len(),
            intensity.len()
        )));
    }
    if !(diameter.len() == 1 || diameter.len() == n) {
        return Err(PivError::InvalidInput(format!(
            "diameter has {} values; give 1 or one per particle ({n})",
            diameter.len()
        )));
    }
    if x.iter().chain(y).chain(intensity).any(|v| !v.is_finite()) {
        return Err(PivError::InvalidInput(
            "particle positions or intensities contain NaN or inf".into(),
        ));
    }
    if diameter.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(PivError::InvalidInput(
            "particle diameters must be finite and > 0".into(),
        ));
    }
    if !(noise_sigma.is_finite() && noise_sigma >= 0.0) {
        return Err(PivError::InvalidInput(format!(
            "noise_sigma {noise_sigma} must be finite and >= 0"
        )));
    }
    let diam = |k: usize| {
        if diameter.len() == 1 {
            diameter[0]
        } else {
            diameter[k]
        }
    };
    let radius = |k: usize| diam(k) + 1.0; // > 4 sigma + half a pixel
                                           // bucket the particles by row bands (CSR), in particle order
    let nb = height.div_ceil(BAND);
    let band_range = |k: usize| -> Option<(usize, usize)> {
        let r = radius(k);
        let lo = (y[k] - r).floor();
        let hi = (y[k] + r).ceil();
        let xlo = x[k] + r;
        let xhi = x[k] - r;
        if hi < 0.0 || lo > (height - 1) as f64 || xlo < 0.0 || xhi > (width - 1) as f64 {
            return None;
        }
        let lo = lo.max(0.0) as usize / BAND;
        let hi = (hi.min((height - 1) as f64) as usize) / BAND;
        Some((lo, hi))
    };
    let mut counts = vec![0usize; nb + 1];
    for k in 0..n {
        if let Some((lo, hi)) = band_range(k) {
            for b in lo..=hi {
                counts[b + 1] += 1;
            }
        }
    }
    for b in 0..nb {
        counts[b + 1] += counts[b];
    }
    let mut fill = counts.clone();
    let mut members = vec![0u32; counts[nb]];
    for k in 0..n {
        if let Some((lo, hi)) = band_range(k) {
            for b in lo..=hi {
                members[fill[b]] = k as u32;
                fill[b] += 1;
            }
        }
    }
    let mut out = Array2::<u16>::zeros((height, width));
    let maxc = max_count as f64;
    out.as_slice_mut()
        .expect("standard layout")
        .par_chunks_mut(BAND * width)
        .enumerate()
        .for_each(|(band, chunk)| {
            let rows = chunk.len() / width;
            let r0 = band * BAND;
            let mut acc = vec![0.0f64; rows * width];
            let mut ex = Vec::new();
            let mut ey = Vec::new();
            for &k in &members[counts[band]..counts[band + 1]] {
                let k = k as usize;
                let d = diam(k);
                let r = radius(k);
                let s = 8f64.sqrt() / d;
                let amp = intensity[k] * std::f64::consts::PI * d * d / 32.0;
                let c0 = ((x[k] - r).floor().max(0.0)) as usize;
                let c1 = ((x[k] + r).ceil().min((width - 1) as f64)) as usize;
                let j0 = ((y[k] - r).floor().max(r0 as f64)) as usize;
                let j1 = ((y[k] + r).ceil().min((r0 + rows - 1) as f64)) as usize;
                if c1 < c0 || j1 < j0 {
                    continue;
                }
                ex.clear();
                let mut prev = erf((c0 as f64 - 0.5 - x[k]) * s);
                for c in c0..=c1 {
                    let next = erf((c as f64 + 0.5 - x[k]) * s);
                    ex.push(next - prev);
                    prev = next;
                }
                ey.clear();
                let mut prev = erf((j0 as f64 - 0.5 - y[k]) * s);
                for j in j0..=j1 {
                    let next = erf((j as f64 + 0.5 - y[k]) * s);
                    ey.push(amp * (next - prev));
                    prev = next;
                }
                for (jj, wy) in ey.iter().enumerate() {
                    let row =
                        &mut acc[(j0 + jj - r0) * width + c0..(j0 + jj - r0) * width + c1 + 1];
                    for (a, wx) in row.iter_mut().zip(&ex) {
                        *a += wy * wx;
                    }
                }
            }
            for rr in 0..rows {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream((r0 + rr) as u64);
                for c in 0..width {
                    let mut val = acc[rr * width + c];
                    if noise_sigma > 0.0 {
                        let z: f64 = rng.sample(StandardNormal);
                        val += noise_sigma * z;
                    }
                    chunk[rr * width + c] = val.round().clamp(0.0, maxc) as u16;
                }
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn particle_integral_and_centroid() {
        let img =
            render_particles(32, 40, &[17.3], &[12.6], &[1000.0], &[3.0], 0.0, 60000, 1).unwrap();
        let total: f64 = img.iter().map(|&v| v as f64).sum();
        let exact = 1000.0 * std::f64::consts::PI * 9.0 / 8.0;
        assert!((total - exact).abs() / exact < 0.01, "{total} {exact}");
        let mut cx = 0.0;
        let mut cy = 0.0;
        for ((j, i), &v) in img.indexed_iter() {
            cx += i as f64 * v as f64;
            cy += j as f64 * v as f64;
        }
        assert!((cx / total - 17.3).abs() < 0.02 && (cy / total - 12.6).abs() < 0.02);
    }

    #[test]
    fn deterministic_whatever_the_threads() {
        let n = 400;
        let xs: Vec<f64> = (0..n).map(|k| (k * 37 % 97) as f64 + 0.3).collect();
        let ys: Vec<f64> = (0..n).map(|k| (k * 53 % 61) as f64 - 1.7).collect();
        let it = vec![2000.0; n];
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let a = one
            .install(|| render_particles(60, 100, &xs, &ys, &it, &[2.5], 50.0, 4095, 9).unwrap());
        let b = render_particles(60, 100, &xs, &ys, &it, &[2.5], 50.0, 4095, 9).unwrap();
        assert_eq!(a, b);
        let c = render_particles(60, 100, &xs, &ys, &it, &[2.5], 50.0, 4095, 10).unwrap();
        assert_ne!(a, c);
        assert!(render_particles(60, 100, &xs, &ys[..3], &it, &[2.5], 50.0, 4095, 9).is_err());
    }
}
