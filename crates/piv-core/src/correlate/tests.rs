use super::peak::{gauss3_2, gauss9, peak_ratio};
use super::uncertainty::gauss3_slope;
use super::*;
use crate::weighting::Weighting;

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
fn particle_windows(w: usize, h: usize, (sx, sy): (f64, f64), seed: u64) -> (Vec<f32>, Vec<f32>) {
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
        let got = plane[((ty + (ch / 2) as i32) as usize) * cw + (tx + (cw / 2) as i32) as usize];
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
            s +=
                (wa[(r * wi + c) as usize] as f64 - ma) * (wb[(r2 * wi + c2) as usize] as f64 - mb);
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
    let ratio = peak_ratio(best, second);
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
    // the peak's width from its three values along each axis, written out
    let width_of = |m: f32, c: f32, p: f32| {
        let (m, c, p) = (m as f64, c as f64, p as f64);
        let k = m.ln() - 2.0 * c.ln() + p.ln();
        if m > 0.0 && c > 0.0 && p > 0.0 && k < 0.0 {
            (-1.0 / k).sqrt()
        } else {
            f64::NAN
        }
    };
    let u = |c: usize, r: usize| unbiased(c, r);
    let width = (
        width_of(u(pc - 1, pr), u(pc, pr), u(pc + 1, pr)),
        width_of(u(pc, pr - 1), u(pc, pr), u(pc, pr + 1)),
    );
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
        width,
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
        println!("{w}x{h} noise {noise}: {n} peaks, rms(err/sigma) {rms:.3}, coverage {cov:.3}");
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
                let ok = |x: isize, y: isize| x >= 0 && y >= 0 && x < w as isize && y < h as isize;
                ok(x, y) && ok(x + dx, y + dy) && ok(x + tx, y + ty) && ok(x + tx + dx, y + ty + dy)
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
            let overlap = (1.0 - tx.abs() as f64 / w as f64) * (1.0 - ty.abs() as f64 / h as f64);
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
