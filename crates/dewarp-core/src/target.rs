//! Synthetic calibration-target renderer: the ground truth of marker detection.
//!
//! Each marker is rendered as an isotropic 2D Gaussian blob of intensity
//! `A_k exp(-|p - c_k|^2 / (2 s_k^2))`, or, when it has a radius `R_k > 0`, as a printed disc
//! seen through the lens: a uniform disc of radius `R_k` blurred by a Gaussian of standard
//! deviation `s_k`, `A_k P(|p - c_k|; R_k, s_k)` (the profile of [`crate::markers`]' disc
//! model, tabulated to 1e-7 and checked there against a brute-force convolution), or, with
//! [`render_target_shapes`], as a printed regular polygon (a fiducial: triangle, square, ...) of
//! circumradius `R_k` blurred by `s_k`, `A_k prod_e Phi(d_e / s_k)` over its edges `e` (`d_e`
//! the signed distance inside edge `e`: exact along the edges, the corners rounded slightly
//! more than a true convolution would), centred
//! *exactly* at its image position `c_k` (the image
//! of the dot's centre under the lens distortion, computed by the caller), so the true marker
//! position is known exactly. The local change of magnification across one dot (< 0.5 % for the
//! paper's lens) is neglected: the blob stays circular. The blob value is evaluated at the
//! pixel centre (the pixel frame of the README: x = column, y = row, origin at the centre of
//! the top-left pixel).
//!
//! The scene is `I = B + G(x, y) * (L + sum_k blob_k)`, with a background `B` (the dark level),
//! an illuminated plate level `L` (0 for bright dots on a black plate; a bright plate with
//! negative amplitudes gives dark dots on a bright plate, vignetted like a real one), an illumination field
//! `G = (1 + gx xn + gy yn) (1 - v r_n^2)` (xn, yn in [-1, 1] across the sensor, r_n the
//! distance from the sensor centre over the half-diagonal), then camera noise: shot noise of
//! variance `gain * signal` (counts) and Gaussian read noise, quantised and clipped to
//! `[0, full_scale]` (4095 for 12 bit). Noise comes from a ChaCha8 stream per row seeded by
//! `seed`, so a render is identical whatever the thread count.

use crate::error::{DewarpError, Result};
use crate::markers::disc::DiscTable;
use image_core::normal_cdf;
use ndarray::{Array2, ArrayView1, ArrayView2, Axis};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Illumination and camera model of a rendered target.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetScene {
    /// Background level (counts).
    pub background: f64,
    /// Linear illumination gradient across the sensor in x and y (fraction per half width).
    pub gradient: (f64, f64),
    /// Vignetting: illumination falls by this fraction at the corners.
    pub vignetting: f64,
    /// Shot-noise gain: variance added = gain * signal (counts); 0 disables.
    pub gain: f64,
    /// Read noise standard deviation (counts); 0 disables.
    pub read_noise: f64,
    /// Illuminated plate level (counts, under the illumination field `G`).
    pub plate: f64,
    /// Largest representable count (4095 for a 12-bit camera).
    pub full_scale: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for TargetScene {
    fn default() -> Self {
        Self {
            background: 200.0,
            gradient: (0.08, -0.05),
            vignetting: 0.15,
            gain: 0.5,
            read_noise: 4.0,
            plate: 0.0,
            full_scale: 4095.0,
            seed: 0,
        }
    }
}

/// Render a target image of `height` x `width` pixels (uint16 counts).
///
/// `centres` is `(n, 2)` image px (x, y); `sigma_px` and `amplitude` have one entry per marker
/// (blob standard deviation in px, or a disc's blur; peak counts before illumination, negative
/// for a dark dot); `radius_px`, if given, one disc radius (px) per marker, 0 for a Gaussian.
pub fn render_target(
    height: usize,
    width: usize,
    centres: ArrayView2<f64>,
    sigma_px: ArrayView1<f64>,
    amplitude: ArrayView1<f64>,
    radius_px: Option<ArrayView1<f64>>,
    scene: &TargetScene,
) -> Result<Array2<u16>> {
    render_target_shapes(
        height, width, centres, sigma_px, amplitude, radius_px, None, scene,
    )
}

/// A marker's printed shape: a regular polygon of `sides` (3 or more) whose first vertex lies
/// at `angle` (radians, from +x towards +y) from its centre, its circumradius the marker's
/// radius. Round markers (discs, Gaussian blobs) have no shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Polygon {
    pub sides: u32,
    pub angle: f64,
}

/// [`render_target`] with printed polygons: `shapes[k]` (if given and `Some`) draws marker `k`
/// as that polygon, its radius the circumradius (> 0) and its sigma the blur.
#[allow(clippy::too_many_arguments)]
pub fn render_target_shapes(
    height: usize,
    width: usize,
    centres: ArrayView2<f64>,
    sigma_px: ArrayView1<f64>,
    amplitude: ArrayView1<f64>,
    radius_px: Option<ArrayView1<f64>>,
    shapes: Option<&[Option<Polygon>]>,
    scene: &TargetScene,
) -> Result<Array2<u16>> {
    if height == 0 || width == 0 || height.saturating_mul(width) > 400_000_000 {
        return Err(DewarpError::InvalidInput(format!(
            "render_target: image size {height} x {width} is empty or too large"
        )));
    }
    let n = centres.nrows();
    if centres.ncols() != 2 || sigma_px.len() != n || amplitude.len() != n {
        return Err(DewarpError::InvalidInput(format!(
            "render_target: centres must be (n, 2) with n sigmas and amplitudes, got {:?}, {}, {}",
            centres.shape(),
            sigma_px.len(),
            amplitude.len()
        )));
    }
    if radius_px.is_some_and(|r| r.len() != n) {
        return Err(DewarpError::InvalidInput(format!(
            "render_target: {n} markers but {} radii",
            radius_px.map_or(0, |r| r.len())
        )));
    }
    if shapes.is_some_and(|p| p.len() != n) {
        return Err(DewarpError::InvalidInput(format!(
            "render_target: {n} markers but {} shapes",
            shapes.map_or(0, |p| p.len())
        )));
    }
    let radius = |k: usize| radius_px.map_or(0.0, |r| r[k]);
    let shape = |k: usize| shapes.and_then(|p| p[k]);
    for k in 0..n {
        if let Some(p) = shape(k) {
            if p.sides < 3 || p.sides > 64 || !p.angle.is_finite() || radius(k) <= 0.0 {
                return Err(DewarpError::InvalidInput(format!(
                    "render_target: marker {k} is a polygon of {} sides at angle {} with radius \
                     {}: it needs 3-64 sides, a finite angle and a radius > 0",
                    p.sides,
                    p.angle,
                    radius(k)
                )));
            }
        }
    }
    for k in 0..n {
        let (cx, cy, s, a) = (centres[[k, 0]], centres[[k, 1]], sigma_px[k], amplitude[k]);
        let r = radius(k);
        let valid = cx.is_finite()
            && cy.is_finite()
            && a.is_finite()
            && s > 0.0
            && s.is_finite()
            && r >= 0.0
            && r.is_finite();
        if !valid {
            return Err(DewarpError::InvalidInput(format!(
                "render_target: marker {k} has a non-finite position/amplitude, sigma <= 0 or radius < 0"
            )));
        }
    }
    let fields = [
        scene.background,
        scene.gradient.0,
        scene.gradient.1,
        scene.vignetting,
        scene.gain,
        scene.read_noise,
        scene.plate,
        scene.full_scale,
    ];
    if fields.iter().any(|v| !v.is_finite()) || scene.gain < 0.0 || scene.read_noise < 0.0 {
        return Err(DewarpError::InvalidInput(
            "render_target: scene parameters must be finite, gain and read noise >= 0".into(),
        ));
    }
    if !(scene.full_scale >= 1.0 && scene.full_scale <= 65535.0) {
        return Err(DewarpError::InvalidInput(format!(
            "render_target: full_scale {} must lie in [1, 65535]",
            scene.full_scale
        )));
    }
    // Blobs as (cx, cy, inv2s2, a, half-extent) sorted by nothing: per row we test the y-extent.
    let blobs: Vec<[f64; 5]> = (0..n)
        .map(|k| {
            let s = sigma_px[k];
            [
                centres[[k, 0]],
                centres[[k, 1]],
                0.5 / (s * s),
                amplitude[k],
                (radius(k) + 5.0 * s).ceil(),
            ]
        })
        .collect();
    // Discs: their tabulated profile (None for Gaussian blobs).
    let discs: Vec<Option<DiscTable>> = (0..n)
        .map(|k| {
            (radius(k) > 0.0 && shape(k).is_none()).then(|| {
                let mut t = DiscTable::default();
                t.ensure(
                    radius(k),
                    sigma_px[k],
                    blobs[k][4] * std::f64::consts::SQRT_2 + 2.0,
                );
                t
            })
        })
        .collect();
    // Polygons: each edge's outward normal and the inradius, with the blur's 1 / sigma.
    type Edges = (Vec<[f64; 2]>, f64, f64);
    let polygons: Vec<Option<Edges>> = (0..n)
        .map(|k| {
            shape(k).map(|p| {
                let m = p.sides as f64;
                let normals = (0..p.sides)
                    .map(|e| {
                        let t = p.angle + std::f64::consts::TAU * (e as f64 + 0.5) / m;
                        [t.cos(), t.sin()]
                    })
                    .collect();
                let inradius = radius(k) * (std::f64::consts::PI / m).cos();
                (normals, inradius, 1.0 / sigma_px[k])
            })
        })
        .collect();
    let hx = 0.5 * (width as f64 - 1.0);
    let hy = 0.5 * (height as f64 - 1.0);
    let half_diag2 = (hx * hx + hy * hy).max(1.0);
    let mut img = Array2::<u16>::zeros((height, width));
    img.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each_init(
            || vec![0.0f64; width],
            |row_buf, (y, mut row)| {
                let yf = y as f64;
                row_buf.iter_mut().for_each(|v| *v = scene.plate);
                for ((b, disc), polygon) in blobs.iter().zip(&discs).zip(&polygons) {
                    let dy = yf - b[1];
                    if dy.abs() > b[4] {
                        continue;
                    }
                    let x0 = ((b[0] - b[4]).floor().max(0.0)) as usize;
                    let x1 = ((b[0] + b[4]).ceil().min(width as f64 - 1.0)).max(-1.0);
                    if x1 < 0.0 {
                        continue;
                    }
                    if let Some((normals, inradius, inv_s)) = polygon {
                        for x in x0..=(x1 as usize) {
                            let dx = x as f64 - b[0];
                            let v: f64 = normals
                                .iter()
                                .map(|u| normal_cdf((inradius - dx * u[0] - dy * u[1]) * inv_s))
                                .product();
                            row_buf[x] += b[3] * v;
                        }
                        continue;
                    }
                    if let Some(t) = disc {
                        for x in x0..=(x1 as usize) {
                            row_buf[x] += b[3] * t.value((x as f64 - b[0]).hypot(dy));
                        }
                        continue;
                    }
                    let ey = (-dy * dy * b[2]).exp() * b[3];
                    for x in x0..=(x1 as usize) {
                        let dx = x as f64 - b[0];
                        row_buf[x] += ey * (-dx * dx * b[2]).exp();
                    }
                }
                let mut rng = ChaCha8Rng::seed_from_u64(scene.seed);
                rng.set_stream(y as u64);
                let yn = (yf - hy) / hy.max(1.0);
                for x in 0..width {
                    let xn = (x as f64 - hx) / hx.max(1.0);
                    let r2 = ((x as f64 - hx).powi(2) + (yf - hy).powi(2)) / half_diag2;
                    let g = (1.0 + scene.gradient.0 * xn + scene.gradient.1 * yn)
                        * (1.0 - scene.vignetting * r2);
                    let signal = (scene.background + g * row_buf[x]).max(0.0);
                    let mut v = signal;
                    if scene.gain > 0.0 {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        v += z * (scene.gain * signal).sqrt();
                    }
                    if scene.read_noise > 0.0 {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        v += z * scene.read_noise;
                    }
                    row[x] = v.round().clamp(0.0, scene.full_scale) as u16;
                }
            },
        );
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{array, Array1};

    /// A scene without illumination field or noise over a `background`.
    fn flat(background: f64) -> TargetScene {
        TargetScene {
            background,
            gradient: (0.0, 0.0),
            vignetting: 0.0,
            gain: 0.0,
            read_noise: 0.0,
            plate: 0.0,
            full_scale: 65535.0,
            seed: 1,
        }
    }

    /// The image's zeroth moment and centroid over a `background`.
    fn moments(img: &Array2<u16>, background: f64) -> (f64, f64, f64) {
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        for ((y, x), v) in img.indexed_iter() {
            let w = *v as f64 - background;
            sx += w * x as f64;
            sy += w * y as f64;
            s += w;
        }
        (s, sx / s, sy / s)
    }

    #[test]
    fn polygons_have_their_area_and_centroid() {
        // A square and a triangle of circumradius 12 px, blur 1 px: the integral is the
        // polygon's area (the blur conserves it; the rounded corners lose < 1 %), the centroid
        // its centre, and bad polygons are refused.
        let scene = flat(0.0);
        for (sides, area) in [(4u32, 2.0 * 144.0), (3, 0.75 * 3f64.sqrt() * 144.0)] {
            let c = array![[30.4, 29.7]];
            let shapes = [Some(Polygon { sides, angle: 0.3 })];
            let img = render_target_shapes(
                60,
                62,
                c.view(),
                Array1::from(vec![1.0]).view(),
                Array1::from(vec![1000.0]).view(),
                Some(Array1::from(vec![12.0]).view()),
                Some(&shapes),
                &scene,
            )
            .unwrap();
            let (s, cx, cy) = moments(&img, 0.0);
            let rel = s / 1000.0 / area - 1.0;
            assert!(rel.abs() < 0.01, "{sides} sides: area off by {rel}");
            assert!((cx - 30.4).abs() < 0.02 && (cy - 29.7).abs() < 0.02);
            assert_eq!(img[[30, 30]], 1000);
        }
        let c = array![[30.0, 30.0]];
        let one = |sides: u32, r: f64| {
            render_target_shapes(
                60,
                60,
                c.view(),
                Array1::from(vec![1.0]).view(),
                Array1::from(vec![1000.0]).view(),
                Some(Array1::from(vec![r]).view()),
                Some(&[Some(Polygon { sides, angle: 0.0 })]),
                &scene,
            )
        };
        assert!(one(2, 10.0).is_err());
        assert!(one(4, 0.0).is_err());
    }

    #[test]
    fn blob_peak_and_centroid_at_centre() {
        let c = array![[20.3, 15.7]];
        let scene = flat(10.0);
        let img = render_target(
            32,
            40,
            c.view(),
            Array1::from(vec![2.5]).view(),
            Array1::from(vec![1000.0]).view(),
            None,
            &scene,
        )
        .unwrap();
        let (_, cx, cy) = moments(&img, 10.0);
        assert!((cx - 20.3).abs() < 0.01, "{cx}");
        assert!((cy - 15.7).abs() < 0.01, "{cy}");
        assert_eq!(
            img[[16, 20]],
            (10.0 + 1000.0 * (-(0.09 + 0.09) / 12.5f64).exp()).round() as u16
        );
    }

    #[test]
    fn noise_is_deterministic_and_clipped() {
        let c = array![[5.0, 5.0]];
        let scene = TargetScene {
            full_scale: 4095.0,
            ..Default::default()
        };
        let s = Array1::from(vec![2.0]);
        let a = Array1::from(vec![1e6]);
        let a1 = render_target(12, 12, c.view(), s.view(), a.view(), None, &scene).unwrap();
        let a2 = render_target(12, 12, c.view(), s.view(), a.view(), None, &scene).unwrap();
        assert_eq!(a1, a2);
        assert_eq!(a1[[5, 5]], 4095);
        assert!(render_target(0, 12, c.view(), s.view(), a.view(), None, &scene).is_err());
        let bad = Array1::from(vec![0.0]);
        assert!(render_target(12, 12, c.view(), bad.view(), a.view(), None, &scene).is_err());
    }
}
