//! Tests of marker detection.

use super::*;
use crate::target::{render_target, TargetScene};
use coarse::{correlate, correlate_marker, template};
use ndarray::{Array1, Array2};

fn scene_img(pts: &[(f64, f64)], s: f64, h: usize, w: usize, seed: u64) -> Array2<u16> {
    let c = Array2::from_shape_fn(
        (pts.len(), 2),
        |(k, j)| if j == 0 { pts[k].0 } else { pts[k].1 },
    );
    let sig = Array1::from_elem(pts.len(), s);
    let amp = Array1::from_elem(pts.len(), 2500.0);
    // No illumination gradient: it shifts a blob's apparent centre by g s^2 (a real effect,
    // exaggerated on this tiny image), and this test checks the fit against the noise.
    let scene = TargetScene {
        seed,
        gradient: (0.0, 0.0),
        vignetting: 0.0,
        ..Default::default()
    };
    render_target(h, w, c.view(), sig.view(), amp.view(), None, &scene).unwrap()
}

#[test]
fn finds_dots_with_subpixel_accuracy_and_honest_sigma() {
    let mut pts = Vec::new();
    for j in 0..4 {
        for i in 0..5 {
            pts.push((
                30.0 + 45.0 * i as f64 + 0.37 * j as f64,
                25.0 + 40.0 * j as f64 + 0.21 * i as f64,
            ));
        }
    }
    let mut err2 = 0.0;
    let mut sig2 = 0.0;
    let mut n = 0.0;
    for seed in 0..3 {
        let img = scene_img(&pts, 4.0, 180, 250, seed);
        let det = detect_markers(img.view(), &DetectOptions::default()).unwrap();
        assert_eq!(det.markers.len(), pts.len());
        assert!((det.size_px - 4.0).abs() < 1.0, "size {}", det.size_px);
        for p in &pts {
            let m = det.markers.iter().min_by(|a, b| {
                (a.x - p.0)
                    .hypot(a.y - p.1)
                    .total_cmp(&(b.x - p.0).hypot(b.y - p.1))
            });
            let m = m.unwrap();
            err2 += (m.x - p.0).powi(2) + (m.y - p.1).powi(2);
            sig2 += m.sigma_x.powi(2) + m.sigma_y.powi(2);
            n += 1.0;
        }
    }
    let (rms, sig) = ((err2 / n).sqrt(), (sig2 / n).sqrt());
    assert!(rms < 0.05, "rms {rms}");
    assert!(
        sig / rms < 1.5 && rms / sig < 1.5,
        "sigma {sig} vs error {rms}"
    );
}

#[test]
fn finds_crosses() {
    // Crosses: two perpendicular bars of Gaussian profile (sigma 2 px), arms 12 px long.
    let pts = [(30.3, 28.6), (80.7, 29.1), (31.2, 78.4), (81.5, 79.8)];
    let img = Array2::from_shape_fn((110, 115), |(y, x)| {
        let mut v = 100.0;
        for &(cx, cy) in &pts {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let bar = |a: f64, b: f64| {
                (-(a * a) / 8.0).exp() * (1.0 / (1.0 + (-(12.0 - b.abs()) * 2.0).exp()))
            };
            v += 1500.0 * bar(dx, dy).max(bar(dy, dx));
        }
        v
    });
    let o = DetectOptions {
        kind: MarkerKind::Cross,
        size_px: Some(2.0),
        // Four crosses are no lattice for the polarity survey: the polarity is given.
        dark: Some(false),
        ..Default::default()
    };
    let det = detect_markers(img.view(), &o).unwrap();
    assert_eq!(det.markers.len(), 4);
    for (m, p) in det.markers.iter().zip(pts.iter()) {
        assert!(
            (m.x - p.0).abs() < 0.05 && (m.y - p.1).abs() < 0.05,
            "{m:?} vs {p:?}"
        );
    }
}

#[test]
fn blank_and_bad_inputs_are_errors() {
    let img = scene_img(&[], 3.0, 64, 64, 0);
    assert!(detect_markers(img.view(), &DetectOptions::default()).is_err());
    let o = DetectOptions {
        size_px: Some(-1.0),
        ..Default::default()
    };
    let img = scene_img(&[(30.0, 30.0)], 3.0, 64, 64, 0);
    assert!(detect_markers(img.view(), &o).is_err());
    let tiny = Array2::<f64>::zeros((4, 4));
    assert!(detect_markers(tiny.view(), &DetectOptions::default()).is_err());
}

#[test]
fn fft_correlation_matches_direct_sum() {
    let img = Array2::from_shape_fn((9, 11), |(y, x)| ((y * 7 + x * 3) % 5) as f64);
    let tpl = template(MarkerKind::Dot, 1.0);
    let c = correlate(&img, &tpl);
    let mean = img.mean().unwrap();
    let (th, tw) = tpl.dim();
    for y in 0..9 {
        for x in 0..11 {
            let mut s = 0.0;
            for u in 0..th {
                for v in 0..tw {
                    let (yy, xx) = (
                        y as isize + u as isize - (th / 2) as isize,
                        x as isize + v as isize - (tw / 2) as isize,
                    );
                    if yy >= 0 && xx >= 0 && yy < 9 && xx < 11 {
                        s += (img[[yy as usize, xx as usize]] - mean) * tpl[[u, v]];
                    }
                }
            }
            assert!((s - c[[y, x]]).abs() < 1e-9);
        }
    }
}

#[test]
fn survey_finds_size_polarity_and_profile_of_a_dark_disc_lattice() {
    // Dark printed discs (radius 5 px, blur 1 px) on a bright vignetted plate, 9 x 6 at 60 px.
    let mut pts = Vec::new();
    for j in 0..6 {
        for i in 0..9 {
            pts.push((40.3 + 60.0 * i as f64, 35.8 + 60.0 * j as f64));
        }
    }
    let n = pts.len();
    let c = Array2::from_shape_fn((n, 2), |(k, a)| if a == 0 { pts[k].0 } else { pts[k].1 });
    let scene = TargetScene {
        plate: 2500.0,
        vignetting: 0.6,
        ..TargetScene::default()
    };
    let img = render_target(
        380,
        560,
        c.view(),
        Array1::from_elem(n, 1.0).view(),
        Array1::from_elem(n, -1800.0).view(),
        Some(Array1::from_elem(n, 5.0).view()),
        &scene,
    )
    .unwrap();
    let det = detect_markers(img.view(), &DetectOptions::default()).unwrap();
    assert!(det.dark, "polarity");
    assert_eq!(det.profile, "disc");
    let sv = det.survey.as_ref().unwrap();
    assert!(sv.n_lattice >= 40, "{sv:?}");
    assert_eq!(det.markers.len(), n);
    let mut worst: f64 = 0.0;
    for m in &det.markers {
        let d = pts
            .iter()
            .map(|p| (m.x - p.0).hypot(m.y - p.1))
            .fold(f64::INFINITY, f64::min);
        worst = worst.max(d);
        assert!((m.radius - 5.0).abs() < 0.2, "radius {}", m.radius);
    }
    assert!(worst < 0.05, "worst {worst}");
    // Given the wrong polarity, the bright "lattice" is the side lobes: no markers fit there.
    let o = DetectOptions {
        dark: Some(false),
        ..DetectOptions::default()
    };
    assert!(detect_markers(img.view(), &o).map_or(true, |d| d.markers.len() < n));
}

#[test]
fn separable_dot_correlation_equals_the_fft_one() {
    // A textured image with a bright corner (the zero padding matters at the edges).
    let img = Array2::from_shape_fn((37, 53), |(y, x)| {
        ((y * 13 + x * 7) % 17) as f64 + if x + y < 10 { 50.0 } else { 0.0 }
    });
    for sc in [1.0, 1.7, 2.6, 4.9] {
        let a = correlate(&img, &template(MarkerKind::Dot, sc));
        let b = correlate_marker(&img, MarkerKind::Dot, sc);
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (p, q) in a.iter().zip(b.iter()) {
            assert!((p - q).abs() <= 1e-9 * scale, "sc {sc}: {p} vs {q}");
        }
    }
}

#[test]
fn flat_top_score_separates_discs_from_gaussians() {
    // One noisy blob each: a Gaussian (sigma 2.5 px) and a printed disc (radius 5 px, blur 1 px)
    // of similar extent; the score test of the Gaussian fit flags only the disc.
    let c = Array2::from_shape_vec((1, 2), vec![32.3, 30.8]).unwrap();
    let scene = TargetScene::default();
    let score = |sigma: f64, radius: Option<f64>| {
        let r = radius.map(|r| Array1::from_elem(1, r));
        let img = render_target(
            64,
            64,
            c.view(),
            Array1::from_elem(1, sigma).view(),
            Array1::from_elem(1, 2000.0).view(),
            r.as_ref().map(|r| r.view()),
            &scene,
        )
        .unwrap();
        let mut scratch = blob::BlobScratch::default();
        blob::fit_blob(
            img.view(),
            32.0,
            31.0,
            2.5,
            1.0,
            blob::Profile::Gauss,
            &mut scratch,
        )
        .map(|f| f.flat_top)
    };
    let g = score(2.5, None).expect("gaussian fit");
    assert!(g < FLAT_TOP_THRESHOLD, "gaussian scored {g}");
    // The flat-topped disc defeats the Gaussian fit or scores far above the threshold.
    assert!(score(1.0, Some(5.0)).is_none_or(|d| d > FLAT_TOP_THRESHOLD));
}
