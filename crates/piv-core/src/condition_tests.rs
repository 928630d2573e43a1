//! Tests of the image conditioning against exact answers and brute-force evaluations.
use super::*;
use ndarray::Array2;

fn run(img: &Array2<f32>, c: &Conditioning, bg: Option<&Array2<f32>>) -> Array2<f32> {
    let mut out = img.clone();
    condition(out.view_mut(), c, bg.map(|b| b.view())).unwrap();
    out
}

#[test]
fn nothing_switched_on_changes_nothing() {
    let img = Array2::from_shape_fn((9, 13), |(y, x)| (x * 7 + y * 3) as f32);
    assert_eq!(run(&img, &Conditioning::default(), None), img);
}

#[test]
fn background_is_subtracted_and_clipped_at_zero() {
    let img = Array2::from_shape_fn((5, 6), |(y, x)| (10 * y + x) as f32);
    let bg = Array2::from_elem((5, 6), 12.0f32);
    let out = run(&img, &Conditioning::default(), Some(&bg));
    for ((y, x), &v) in out.indexed_iter() {
        assert_eq!(v, ((10 * y + x) as f32 - 12.0).max(0.0));
    }
}

#[test]
fn hot_pixels_are_replaced_and_particles_kept() {
    let mut img = Array2::from_elem((12, 12), 10.0f32);
    img[[3, 4]] = 4000.0; // a hot pixel: isolated
                          // a particle of ~2 px: its neighbours are lit
    for (y, x, v) in [
        (8, 8, 900.0),
        (8, 9, 600.0),
        (9, 8, 600.0),
        (7, 8, 500.0),
        (8, 7, 450.0),
    ] {
        img[[y, x]] = v;
    }
    let c = Conditioning {
        hot_pixels: Some(3.0),
        ..Default::default()
    };
    let out = run(&img, &c, None);
    assert_eq!(out[[3, 4]], 10.0);
    assert_eq!(out[[8, 8]], 900.0);
    assert_eq!(out.iter().filter(|&&v| v != 10.0).count(), 5);
}

#[test]
fn high_pass_removes_smooth_light_and_keeps_particles() {
    // a linear gradient plus a glare line (a wide Gaussian ridge) plus particles
    let particle = |x: f64, y: f64| {
        let mut s = 0.0;
        for (px, py) in [(20.0, 30.0), (45.5, 12.25), (60.0, 50.0)] {
            s += 1000.0 * (-((x - px) * (x - px) + (y - py) * (y - py)) / 2.0).exp();
        }
        s
    };
    let smooth = |x: f64, y: f64| 200.0 + 2.0 * x + 400.0 * (-(y - 40.0).powi(2) / 800.0).exp();
    let img = Array2::from_shape_fn((80, 96), |(y, x)| {
        (smooth(x as f64, y as f64) + particle(x as f64, y as f64)) as f32
    });
    let c = Conditioning {
        high_pass_sigma: Some(4.0),
        ..Default::default()
    };
    let out = run(&img, &c, None);
    // away from particles (and the mirrored border) what is left of the smooth light is
    // a few counts out of ~600; a particle keeps most of its peak
    let far = out[[70, 80]];
    assert!(far.abs() < 5.0, "{far}");
    assert!(out[[30, 20]] > 700.0, "{}", out[[30, 20]]);
    assert!(out[[50, 60]] > 700.0, "{}", out[[50, 60]]);
}

#[test]
fn smoothing_widens_particle_images_and_keeps_their_sum() {
    // one Gaussian particle image of standard deviation 0.4 px (e^-2 diameter 1.6 px)
    let s0 = 0.4f64;
    let img = Array2::from_shape_fn((32, 40), |(y, x)| {
        let (dx, dy) = (x as f64 - 20.3, y as f64 - 15.6);
        (1000.0 * (-(dx * dx + dy * dy) / (2.0 * s0 * s0)).exp()) as f32
    });
    let c = Conditioning {
        smooth_sigma: Some(0.6),
        ..Default::default()
    };
    let out = run(&img, &c, None);
    let moments = |a: &Array2<f32>| {
        let (mut m0, mut mx, mut mxx) = (0.0f64, 0.0f64, 0.0f64);
        for ((_, x), &v) in a.indexed_iter() {
            let (v, x) = (v as f64, x as f64);
            m0 += v;
            mx += v * x;
            mxx += v * x * x;
        }
        let mean = mx / m0;
        (m0, mean, mxx / m0 - mean * mean)
    };
    let (a0, ax, avar) = moments(&img);
    let (b0, bx, bvar) = moments(&out);
    // the sum and the centre stay; the variance grows by about the kernel's (the sampled
    // Gaussian of 0.6 px has a variance of 0.35 px^2, not 0.36)
    assert!(
        (b0 / a0 - 1.0).abs() < 1e-5 && (bx - ax).abs() < 1e-4,
        "{a0} {b0} {ax} {bx}"
    );
    assert!((bvar - avar - 0.355).abs() < 0.01, "{avar} -> {bvar}");
    // out of range: refused with the parameter named
    for bad in [0.0f32, -1.0, 2.5, f32::NAN] {
        let c = Conditioning {
            smooth_sigma: Some(bad),
            ..Default::default()
        };
        let mut f = img.clone();
        let e = condition(f.view_mut(), &c, None).unwrap_err().to_string();
        assert!(e.contains("smooth sigma"), "{e}");
    }
}

#[test]
fn cap_limits_bright_pixels_at_mean_plus_k_std() {
    let img = Array2::from_shape_fn(
        (10, 10),
        |(y, x)| if x == 5 && y == 5 { 1000.0 } else { 1.0 },
    );
    let c = Conditioning {
        cap_sigma: Some(2.0),
        ..Default::default()
    };
    let out = run(&img, &c, None);
    let (mean, std) = mean_std(img.as_slice().unwrap());
    let top = (mean + 2.0 * std) as f32;
    assert!((out[[5, 5]] - top).abs() < 1e-3 && out[[0, 0]] == 1.0);
}

#[test]
fn min_max_gives_equal_contrast_to_dim_and_bright_regions() {
    // the same particle pattern at two brightness levels (left dim, right 10x)
    let pattern = |x: usize, y: usize| if (x * 7 + y * 13) % 11 == 0 { 1.0 } else { 0.0 };
    let img = Array2::from_shape_fn((40, 80), |(y, x)| {
        let gain = if x < 40 { 50.0 } else { 500.0 };
        20.0 + gain * pattern(x, y)
    });
    let c = Conditioning {
        min_max_window: Some(9),
        ..Default::default()
    };
    let out = run(&img, &c, None);
    let mean_lit = |x0: usize, x1: usize| {
        let (mut s, mut n) = (0.0, 0);
        for y in 10..30 {
            for x in x0..x1 {
                if pattern(x, y) > 0.0 {
                    s += out[[y, x]];
                    n += 1;
                }
            }
        }
        s / n as f32
    };
    let (dim, bright) = (mean_lit(8, 30), mean_lit(50, 72));
    assert!((dim - bright).abs() < 0.02, "{dim} {bright}");
    assert!(out.iter().all(|v| (0.0..=1.0).contains(v)));
}

#[test]
fn cell_envelopes_match_brute_force() {
    let (w, h) = (37usize, 23usize);
    let img: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 101) as f32).collect();
    for n in [3usize, 4, 9, 15, 40] {
        let c = cell_size(n);
        let (lo, hi, cw, ch) = cell_extremes(&img, w, h, c);
        assert_eq!((cw, ch), (w.div_ceil(c), h.div_ceil(c)));
        // the extremes of each cell
        let cell = |j: usize, i: usize, max: bool| {
            let mut e = if max {
                f32::NEG_INFINITY
            } else {
                f32::INFINITY
            };
            for y in j * c..((j + 1) * c).min(h) {
                for x in i * c..((i + 1) * c).min(w) {
                    let v = img[y * w + x];
                    e = if max { e.max(v) } else { e.min(v) };
                }
            }
            e
        };
        for j in 0..ch {
            for i in 0..cw {
                assert_eq!(lo[j * cw + i], cell(j, i, false));
                assert_eq!(hi[j * cw + i], cell(j, i, true));
            }
        }
        // the smoothed envelope: 3 x 3 extreme then 3 x 3 mean, both clipped
        let env = smooth_envelope(&hi, cw, ch, true);
        let ext = |j: usize, i: usize| {
            let mut e = f32::NEG_INFINITY;
            for jj in j.saturating_sub(1)..=(j + 1).min(ch - 1) {
                for ii in i.saturating_sub(1)..=(i + 1).min(cw - 1) {
                    e = e.max(hi[jj * cw + ii]);
                }
            }
            e
        };
        for j in 0..ch {
            for i in 0..cw {
                let (mut s, mut k) = (0.0f64, 0);
                for jj in j.saturating_sub(1)..=(j + 1).min(ch - 1) {
                    for ii in i.saturating_sub(1)..=(i + 1).min(cw - 1) {
                        s += ext(jj, ii) as f64;
                        k += 1;
                    }
                }
                assert!((env[j * cw + i] as f64 - s / k as f64).abs() < 1e-3);
            }
        }
        // interpolation weights: exact at the cell centres, clamped at the ends
        let xs = cell_lerp(w, cw, c);
        for (p, &(i, f)) in xs.iter().enumerate() {
            let t = ((p as f32 + 0.5) / c as f32 - 0.5).clamp(0.0, (cw - 1) as f32);
            assert!((i as f32 + f - t).abs() < 1e-5 && (0.0..=1.0).contains(&f));
        }
    }
}

#[test]
fn min_max_output_is_the_bilinear_envelope_normalisation() {
    for (w, h, n) in [
        (53usize, 31usize, 15usize),
        (20, 7, 9),
        (8, 40, 3),
        (5, 5, 40),
    ] {
        let img = Array2::from_shape_fn((h, w), |(y, x)| {
            (((x * 7919 + y * 104729) % 97) as f32) * (1.0 + 0.05 * x as f32)
        });
        let c = cell_size(n);
        let src = img.as_slice().unwrap();
        let (lo, hi, cw, ch) = cell_extremes(src, w, h, c);
        let (gmin, gmax) = (
            src.iter().cloned().fold(f32::INFINITY, f32::min),
            src.iter().cloned().fold(f32::NEG_INFINITY, f32::max),
        );
        let (lo, hi) = (
            smooth_envelope(&lo, cw, ch, false),
            smooth_envelope(&hi, cw, ch, true),
        );
        let (xs, ys) = (cell_lerp(w, cw, c), cell_lerp(h, ch, c));
        let bilinear = |e: &[f32], y: usize, x: usize| {
            let ((j, fy), (i, fx)) = (ys[y], xs[x]);
            let (j1, i1) = ((j + 1).min(ch - 1), (i + 1).min(cw - 1));
            let at = |jj: usize, ii: usize| e[jj * cw + ii] as f64;
            let (fx, fy) = (fx as f64, fy as f64);
            (1.0 - fy) * ((1.0 - fx) * at(j, i) + fx * at(j, i1))
                + fy * ((1.0 - fx) * at(j1, i) + fx * at(j1, i1))
        };
        let cond = Conditioning {
            min_max_window: Some(n),
            ..Default::default()
        };
        let out = run(&img, &cond, None);
        let floor = 1e-6 * (gmax - gmin) as f64;
        for ((y, x), &o) in out.indexed_iter() {
            let (l, u) = (bilinear(&lo, y, x), bilinear(&hi, y, x));
            let want = ((img[[y, x]] as f64 - l) / (u - l).max(floor)).clamp(0.0, 1.0);
            assert!(
                (o as f64 - want).abs() < 1e-4,
                "{w}x{h} n {n} at ({y}, {x}): {o} vs {want}"
            );
        }
    }
}

#[test]
fn hot_pixels_match_the_plain_rule() {
    // spikes, zeros and negatives (a high-passed frame), edges and corners
    for (w, h) in [
        (17usize, 11usize),
        (1, 5),
        (6, 1),
        (2, 2),
        (9, 150),
        (3, 129),
        (5, 64),
    ] {
        let img = Array2::from_shape_fn((h, w), |(y, x)| {
            let v = ((x * 7919 + y * 104729) % 53) as f32 - 10.0;
            if (x + 3 * y) % 7 == 0 {
                v * 40.0
            } else {
                v
            }
        });
        let c = Conditioning {
            hot_pixels: Some(3.0),
            ..Default::default()
        };
        let out = run(&img, &c, None);
        for ((y, x), &o) in out.indexed_iter() {
            let v = img[[y, x]];
            let mut m = f32::NEG_INFINITY;
            for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                    if (yy, xx) != (y, x) {
                        m = m.max(img[[yy, xx]]);
                    }
                }
            }
            let want = if v > 0.0 && m > f32::NEG_INFINITY && v > 3.0 * m.max(0.0) {
                m
            } else {
                v
            };
            assert_eq!(o, want, "{w}x{h} at ({y}, {x})");
        }
    }
}

#[test]
fn conditioned_copy_equals_in_place_on_a_copy() {
    let raw = Array2::from_shape_fn((37, 53), |(y, x)| ((x * 7919 + y * 104729) % 4096) as u16);
    let bg = Array2::from_shape_fn((37, 53), |(y, x)| (x + y) as f32);
    let f = raw.mapv(|v| v as f32);
    let configs = [
        Conditioning::default(),
        Conditioning {
            hot_pixels: Some(3.0),
            high_pass_sigma: Some(2.0),
            ..Default::default()
        },
        Conditioning {
            cap_sigma: Some(2.0),
            min_max_window: Some(9),
            ..Default::default()
        },
    ];
    for c in &configs {
        for b in [None, Some(&bg)] {
            let want = run(&f, c, b);
            let got = conditioned(raw.view(), c, b.map(|b| b.view())).unwrap();
            assert_eq!(got, want, "{c:?} background {}", b.is_some());
            let got = conditioned(f.view(), c, b.map(|b| b.view())).unwrap();
            assert_eq!(got, want);
        }
    }
    let mut bad = f.clone();
    bad[[3, 4]] = f32::INFINITY;
    let e = conditioned(bad.view(), &configs[0], Some(bg.view())).unwrap_err();
    assert!(e.to_string().contains("NaN or infinite"), "{e}");
    assert!(conditioned(
        raw.view(),
        &configs[0],
        Some(bg.slice(ndarray::s![1.., ..]))
    )
    .is_err());
}

#[test]
fn bad_input() {
    let mut img = Array2::from_elem((4, 4), 1.0f32);
    let c = Conditioning {
        min_max_window: Some(2),
        ..Default::default()
    };
    assert!(condition(img.view_mut(), &c, None)
        .unwrap_err()
        .to_string()
        .contains(">= 3"));
    let bg = Array2::from_elem((3, 4), 1.0f32);
    let e = condition(img.view_mut(), &Conditioning::default(), Some(bg.view())).unwrap_err();
    assert!(e.to_string().contains("differs in shape"));
    img[[1, 1]] = f32::NAN;
    assert!(condition(img.view_mut(), &Conditioning::default(), None).is_err());
    let bg = Array2::from_elem((4, 4), 1.0f32);
    let e = condition(img.view_mut(), &Conditioning::default(), Some(bg.view())).unwrap_err();
    assert!(e.to_string().contains("NaN"), "{e}");
}

#[test]
fn banded_high_pass_and_smoothing_equal_the_whole_frame_blur() {
    // the frame blurred horizontally as a whole, then vertically row by row (the sums of
    // `high_pass` and `smooth` in their order), on frames of one band, several, a short last
    // band, kernels wider than a band's share, and the smoothing's narrow ones
    for (w, h, sigma) in [
        (23usize, 300usize, 2.0f32),
        (19, 129, 4.0),
        (40, 7, 2.0),
        (11, 257, 50.0),
        (8, 1, 1.0),
        (70, 40, 12.0),
        (5, 300, 1.5),
        (33, 260, 0.5),
        (9, 131, 0.3),
    ] {
        let img = Array2::from_shape_fn((h, w), |(y, x)| {
            ((x * 7919 + y * 104729) % 4093) as f32 * 0.37 - 300.0
        });
        let (k, r) = gaussian_taps(sigma);
        let src = img.as_slice().unwrap();
        // the horizontal blur as passes of `dst += k_j * shifted src`, mirrored at the ends
        let mut tmp = vec![0.0f32; w * h];
        for (s, d) in src.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
            for (j, &kj) in k.iter().enumerate() {
                for (i, o) in d.iter_mut().enumerate() {
                    *o += kj * s[mirror(i as isize + j as isize - r as isize, w)];
                }
            }
        }
        let mut want = src.to_vec();
        let mut blurred = src.to_vec();
        for (y, (row, b)) in want
            .chunks_exact_mut(w)
            .zip(blurred.chunks_exact_mut(w))
            .enumerate()
        {
            let mut low = vec![0.0f32; w];
            for (j, &kj) in k.iter().enumerate() {
                let yy = mirror(y as isize + j as isize - r as isize, h);
                for (o, &s) in low.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                    *o += kj * s;
                }
            }
            for (v, &l) in row.iter_mut().zip(&low) {
                *v -= l;
            }
            b.copy_from_slice(&low);
        }
        let same = |got: &[f32], want: &[f32]| {
            got.iter()
                .zip(want)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        };
        let mut got = src.to_vec();
        high_pass(&mut got, w, h, sigma);
        assert!(same(&got, &want), "high-pass {w}x{h} sigma {sigma}");
        let mut got = src.to_vec();
        smooth(&mut got, w, h, sigma);
        assert!(same(&got, &blurred), "smoothing {w}x{h} sigma {sigma}");
    }
}
