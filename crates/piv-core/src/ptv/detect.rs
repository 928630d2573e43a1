//! Individual particle images found in a frame, each with its sub-pixel centre.
//!
//! A particle image is a pixel that stands above its block's threshold `b + max(k s, rel
//! signal)` and is the maximum of its 3 x 3 neighbourhood, exactly as [`crate::seeding`]
//! counts them (the same blocks, backgrounds `b`, noises `s` and signal; the frame's outermost
//! ring and masked pixels never count). Each one's centre is then fitted:
//!
//! - along x and along y separately, a Gaussian through the peak pixel and its two neighbours,
//!   heights taken above the block's background (the 3-point Gaussian estimator; Raffel et al.
//!   2018 sec. 5.4, Cierpka et al. 2013 for particle tracking); the Gaussian's width gives the
//!   particle image's e^-2 diameter `4 sigma` along that axis, and the block's noise `s`
//!   carried through the estimator gives the centre's standard uncertainty along it: with
//!   `L, C, R` the logarithms of the three heights `l, c, r` and `D = L - 2C + R`,
//!   `var = s^2 ((R - C)^2 / l^2 + (C - L)^2 / r^2 + (L - R)^2 / c^2) / D^4` (first order in the
//!   noise; white noise of the block's sigma on every pixel);
//! - where a neighbour is not above the background (a faint or small particle image on a noisy
//!   background) or the peak is saturated, the 3-point centroid of the heights (clamped at 0)
//!   instead, and the diameter and the uncertainty along that axis are NaN (not measured). A
//!   peak pixel is above its earlier neighbours and not below its later ones, so its three
//!   heights always curve down where all are above the background;
//! - a particle image whose 3 x 3 neighbourhood touches a masked pixel is not kept (its fit
//!   would read the mask).
//!
//! The fit is exact (to rounding) for a sampled Gaussian and within about 0.02 px for
//! pixel-integrated Gaussian images of 2-4 px without noise; peak locking (the pull towards
//! whole pixels of images under 2 px) is the correlation's ([`crate::particle_size`]).
//! Two particle images closer than about their diameter merge into one maximum: the merged
//! centre lies between them. [`crate::ptv::track`] leaves such a centre to the ambiguity tests.
//!
//! Units: px of the frame (pixel frame: x = column, y = row, origin at the centre of the
//! top-left pixel); heights in the frame's counts above the block's background.

use crate::error::{PivError, Result};
use crate::seeding::{self, is_peak, threshold};
use image_core::Pixel;
use ndarray::ArrayView2;
use rayon::prelude::*;

/// The particle images of one frame (the module docs), in raster order of their peak pixel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Particles {
    /// Sub-pixel centre along x (px).
    pub x: Vec<f64>,
    /// Sub-pixel centre along y (px).
    pub y: Vec<f64>,
    /// The peak pixel's height above its block's background (counts).
    pub height: Vec<f32>,
    /// e^-2 diameter along x and y (px; NaN where not measured: the module docs).
    pub diameter_x: Vec<f32>,
    pub diameter_y: Vec<f32>,
    /// Standard uncertainty of the centre along x and y from the noise (px; NaN where the
    /// centroid was used).
    pub sigma_x: Vec<f32>,
    pub sigma_y: Vec<f32>,
    /// The peak pixel is at or above `full` (its centre from a clipped profile).
    pub saturated: Vec<bool>,
}

impl Particles {
    /// How many particle images.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// No particle image.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    fn push(&mut self, p: Found) {
        self.x.push(p.x);
        self.y.push(p.y);
        self.height.push(p.height);
        self.diameter_x.push(p.dx);
        self.diameter_y.push(p.dy);
        self.sigma_x.push(p.sx);
        self.sigma_y.push(p.sy);
        self.saturated.push(p.saturated);
    }
}

/// One particle image's fit.
#[derive(Debug, Clone, Copy)]
struct Found {
    x: f64,
    y: f64,
    height: f32,
    dx: f32,
    dy: f32,
    sx: f32,
    sy: f32,
    saturated: bool,
}

/// The particle images of `img` (module docs): blocks of `block` px, threshold factors `k`
/// and `rel`, saturation at `full` (counts). Errors as [`seeding::measure`] does: a block
/// under 8 px, a frame under 3 x 3 px, a mask of another shape, negative or non-finite
/// factors, a value that is not finite.
pub fn detect<T: Pixel>(
    img: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    block: usize,
    k: f32,
    rel: f32,
    full: f32,
) -> Result<Particles> {
    let s = seeding::blocks(img, mask, block, k, rel)?;
    if full.is_nan() {
        return Err(PivError::InvalidInput(
            "the saturation level must not be NaN".into(),
        ));
    }
    let (h, w) = img.dim();
    let excluded = |y: usize, x: usize| mask.as_ref().is_some_and(|m| m[[y, x]]);
    let touches_mask = |y: usize, x: usize| {
        mask.is_some() && (y - 1..=y + 1).any(|yy| (x - 1..=x + 1).any(|xx| excluded(yy, xx)))
    };
    // each block row's particle images, in raster order within the row of blocks
    let rows: Vec<Vec<Found>> = (0..s.rows)
        .into_par_iter()
        .map(|r| {
            let (y0, y1) = ((r * block).max(1), ((r + 1) * block).min(h - 1));
            let mut found = Vec::new();
            for y in y0..y1 {
                let row = img.row(y);
                let out = mask.as_ref().map(|m| m.row(y));
                for c in 0..s.cols {
                    let i = r * s.cols + c;
                    let b = s.background[i];
                    if !b.is_finite() {
                        continue;
                    }
                    let thr = threshold(b, s.noise[i], s.signal, k, rel);
                    let (x0, x1) = ((c * block).max(1), ((c + 1) * block).min(w - 1));
                    for x in x0..x1 {
                        if out.as_ref().is_some_and(|m| m[x]) {
                            continue;
                        }
                        let v = row[x].to_f32();
                        if v > thr && is_peak(&img, y, x, v) && !touches_mask(y, x) {
                            found.push(fit(&img, y, x, b, s.noise[i], v >= full));
                        }
                    }
                }
            }
            found
        })
        .collect();
    let mut out = Particles::default();
    for p in rows.into_iter().flatten() {
        out.push(p);
    }
    Ok(out)
}

/// The sub-pixel centre, diameters and uncertainties of the particle image peaking at
/// `(y, x)`, heights above the background `b`, noise `s` (module docs).
fn fit<T: Pixel>(
    img: &ArrayView2<'_, T>,
    y: usize,
    x: usize,
    b: f32,
    s: f32,
    saturated: bool,
) -> Found {
    let at = |yy: usize, xx: usize| (img[[yy, xx]].to_f32() - b) as f64;
    let c = at(y, x);
    let ax = axis(at(y, x - 1), c, at(y, x + 1), s as f64, saturated);
    let ay = axis(at(y - 1, x), c, at(y + 1, x), s as f64, saturated);
    Found {
        x: x as f64 + ax.offset,
        y: y as f64 + ay.offset,
        height: c as f32,
        dx: ax.diameter,
        dy: ay.diameter,
        sx: ax.sigma,
        sy: ay.sigma,
        saturated,
    }
}

/// One axis of a particle image's fit.
struct Axis {
    /// From the centre pixel (|offset| <= 0.5 px).
    offset: f64,
    /// e^-2 diameter (px; NaN for the centroid).
    diameter: f32,
    /// Standard uncertainty of the offset (px; NaN for the centroid).
    sigma: f32,
}

/// The fit along one axis from the heights `l`, `c`, `r` above the background, noise `s`
/// (module docs).
fn axis(l: f64, c: f64, r: f64, s: f64, saturated: bool) -> Axis {
    if !saturated && l > 0.0 && c > 0.0 && r > 0.0 {
        let (ll, lc, lr) = (l.ln(), c.ln(), r.ln());
        let den = ll - 2.0 * lc + lr;
        if den < 0.0 {
            let off = (ll - lr) / (2.0 * den);
            if off.is_finite() && off.abs() <= 0.5 {
                let var = s
                    * s
                    * ((lr - lc).powi(2) / (l * l)
                        + (lc - ll).powi(2) / (r * r)
                        + (ll - lr).powi(2) / (c * c))
                    / den.powi(4);
                return Axis {
                    offset: off,
                    diameter: (4.0 * (-1.0 / den).sqrt()) as f32,
                    sigma: var.sqrt() as f32,
                };
            }
        }
    }
    let (l, c, r) = (l.max(0.0), c.max(0.0), r.max(0.0));
    let sum = l + c + r;
    let off = if sum > 0.0 { (r - l) / sum } else { 0.0 };
    Axis {
        offset: off.clamp(-0.5, 0.5),
        diameter: f32::NAN,
        sigma: f32::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render_particles;
    use ndarray::Array2;
    use rand::{Rng, SeedableRng};

    /// A sampled Gaussian (not integrated over the pixel) of standard deviation `sd` at
    /// `(x0, y0)` on a flat background.
    fn sampled(x0: f64, y0: f64, sd: f64) -> Array2<f32> {
        Array2::from_shape_fn((32, 32), |(y, x)| {
            let r2 = (x as f64 - x0).powi(2) + (y as f64 - y0).powi(2);
            (100.0 + 1000.0 * (-r2 / (2.0 * sd * sd)).exp()) as f32
        })
    }

    #[test]
    fn a_sampled_gaussian_is_fitted_exactly() {
        for (x0, y0) in [(15.0, 16.0), (15.3, 16.45), (14.62, 15.51)] {
            let img = sampled(x0, y0, 0.8);
            let p = detect(img.view(), None, 16, 4.0, 0.2, f32::INFINITY).unwrap();
            assert_eq!(p.len(), 1, "one particle image at ({x0}, {y0})");
            // the background is the block's quantile estimate (100 to a rounding of counts)
            assert!((p.x[0] - x0).abs() < 2e-3, "x {} vs {x0}", p.x[0]);
            assert!((p.y[0] - y0).abs() < 2e-3, "y {} vs {y0}", p.y[0]);
            assert!(
                (p.diameter_x[0] - 3.2).abs() < 0.02,
                "d {}",
                p.diameter_x[0]
            );
        }
    }

    #[test]
    fn rendered_particles_are_found_where_they_were_placed() {
        // isolated particle images (no two within 8 px) of 2.5 px, 2 % noise
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        for gy in 0..15 {
            for gx in 0..15 {
                xs.push(12.0 + 12.0 * gx as f64 + rng.random_range(-2.0..2.0));
                ys.push(12.0 + 12.0 * gy as f64 + rng.random_range(-2.0..2.0));
            }
        }
        let peak = vec![3000.0; xs.len()];
        let img = render_particles(192, 192, &xs, &ys, &peak, &[2.5], 50.0, 4095, 7).unwrap();
        let p = detect(img.view(), None, 32, 4.0, 0.2, 4095.0).unwrap();
        assert_eq!(p.len(), xs.len());
        let mut se = 0.0;
        for (&x, &y) in p.x.iter().zip(&p.y) {
            let d2 = xs
                .iter()
                .zip(&ys)
                .map(|(a, b)| (a - x).powi(2) + (b - y).powi(2))
                .fold(f64::INFINITY, f64::min);
            se += d2;
        }
        let rms = (se / p.len() as f64).sqrt();
        assert!(rms < 0.05, "centre rms {rms} px");
        // the stated uncertainty is the scatter's: sqrt(mean(sx^2 + sy^2)) against the rms
        let stated = (p
            .sigma_x
            .iter()
            .zip(&p.sigma_y)
            .map(|(a, b)| (a * a + b * b) as f64)
            .sum::<f64>()
            / p.len() as f64)
            .sqrt();
        assert!(
            stated > 0.75 * rms && stated < 1.33 * rms,
            "stated {stated} vs rms {rms}"
        );
    }

    #[test]
    fn masked_neighbourhoods_and_saturation() {
        let img = sampled(15.3, 16.45, 0.8);
        let mut mask = Array2::from_elem((32, 32), false);
        mask[[17, 16]] = true;
        let p = detect(img.view(), Some(mask.view()), 16, 4.0, 0.2, f32::INFINITY).unwrap();
        assert!(
            p.is_empty(),
            "a neighbourhood touching the mask is not fitted"
        );
        // clipped at 700 counts: a plateau of a few pixels, its centre from the centroid
        let clipped = img.mapv(|v| v.min(700.0));
        let p = detect(clipped.view(), None, 16, 4.0, 0.2, 700.0).unwrap();
        assert_eq!(p.len(), 1);
        assert!(p.saturated[0] && p.diameter_x[0].is_nan());
        assert!((p.x[0] - 15.3).abs() < 0.5);
        assert!(detect(img.view(), None, 16, 4.0, 0.2, f32::NAN).is_err());
    }
}
