//! Tests of the image view, the B-spline coefficients, the field and the samplers.
use super::field::*;
use super::sample::*;
use super::*;
use ndarray::Array2;

/// Largest difference between the separable sampler of field-deformed windows
/// ([`sample_pair`]) and the per-pixel 2D interpolation, over windows inside and past every
/// edge, quintic and cubic B-spline; the outside pixels (NaN) must be the same. The field
/// is `(6.3 + gx x - 0.008 y, -2.2 + gy x + 0.01 y)`.
fn separable_vs_2d(gx: f64, gy: f64) -> f32 {
    use crate::grid::Grid;
    let (iw, ih) = (120usize, 90usize);
    let a = Array2::from_shape_fn((ih, iw), |(y, x)| {
        let (x, y) = (x as f64, y as f64);
        (1000.0 + 400.0 * (0.9 * x).sin() * (0.7 * y + 0.3).cos() + 3.0 * x) as f32
    });
    let b = a.mapv(|p| 0.5 * p + 100.0);
    let (ia, ib) = (
        Img::new(a.view(), "a").unwrap(),
        Img::new(b.view(), "b").unwrap(),
    );
    let grid = Grid::for_windows(iw, ih, 16, 16, 0.5).unwrap();
    let field = GridField {
        grid,
        u: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            let (x, y) = grid.xy(j, i);
            6.3 + gx * x - 0.008 * y
        }),
        v: Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            let (x, y) = grid.xy(j, i);
            -2.2 + gy * x + 0.01 * y
        }),
    };
    let (c5a, c5b) = (bspline5_coeffs(&ia), bspline5_coeffs(&ib));
    let (c3a, c3b) = (bspline_coeffs(&ia), bspline_coeffs(&ib));
    let src5 = Source {
        a: &ia,
        b: &ib,
        ia: &c5a,
        ib: &c5b,
        wf: bspline5_weights,
    };
    let src3 = Source {
        a: &ia,
        b: &ib,
        ia: &c3a,
        ib: &c3b,
        wf: bspline_weights,
    };
    let (w, h) = (32usize, 8usize);
    let (mut worst, mut n_nan) = (0.0f32, 0);
    let mut compare = |p: &[f32], q: &[f32]| {
        for (p, q) in p.iter().zip(q) {
            assert_eq!(p.is_nan(), q.is_nan());
            if p.is_nan() {
                n_nan += 1;
            } else {
                worst = worst.max((p - q).abs());
            }
        }
    };
    for &(left, top) in &[
        (40.3, 30.7),
        (-2.6, 20.2),
        (95.1, 84.9),
        (50.5, -1.4),
        (0.0, 0.0),
    ] {
        let spec = WindowSpec {
            left,
            top,
            du: 0.35,
            dv: -0.2,
            field: Some(&field),
        };
        let mut s = [vec![0.0f32; w * h], vec![0.0f32; w * h]];
        let mut r = [vec![0.0f32; w * h], vec![0.0f32; w * h]];
        let [sa, sb] = &mut s;
        let [ra, rb] = &mut r;
        let ok_s = sample_pair(&src5, w, h, &spec, sa, sb);
        let ok_r = sample_field_2d(&src5, w, h, &spec, &field, ra, rb);
        assert_eq!(ok_s, ok_r);
        compare(sa, ra);
        compare(sb, rb);
        let ok_s = sample_pair(&src3, w, h, &spec, sa, sb);
        let ok_r = sample_field_2d(&src3, w, h, &spec, &field, ra, rb);
        assert_eq!(ok_s, ok_r);
        compare(sa, ra);
        compare(sb, rb);
    }
    assert!(n_nan > 0);
    worst
}

/// The separable sampler equals the 2D interpolation when the vertical displacement does
/// not change along x (every tap column then has the exact vertical position: f32
/// rounding only, the image is ~1000 counts), and otherwise differs by an amount
/// proportional to that change (the second-order term of [`sample_field_sep`]).
#[test]
fn separable_field_windows_match_2d_interpolation() {
    let exact = separable_vs_2d(0.01, 0.0);
    assert!(exact < 2e-3, "{exact}");
    let e1 = separable_vs_2d(0.01, -0.006);
    let e2 = separable_vs_2d(0.01, -0.003);
    let ratio = e1 / e2;
    assert!((1.7..2.3).contains(&ratio), "{e1} {e2}");
    // 0.006 px/px: below a 2e-3 px shift of the 360 counts/px steepest slope
    assert!(e1 < 0.72, "{e1}");
}

#[test]
fn bicubic_reproduces_quadratic_inside() {
    let a = Array2::from_shape_fn((20, 20), |(y, x)| {
        (0.1 * (x as f64) * (x as f64) + 2.0 * y as f64) as f32
    });
    let img = Img::new(a.view(), "a").unwrap();
    let v = img.bicubic(7.3, 9.6);
    let exact = 0.1 * 7.3f64 * 7.3 + 2.0 * 9.6;
    // Keys a=-0.5 is third-order accurate: exact for quadratics
    assert!((v as f64 - exact).abs() < 1e-3, "{v} {exact}");
}

#[test]
fn bspline_coefficients_interpolate_the_pixels() {
    let a = Array2::from_shape_fn((13, 17), |(y, x)| {
        ((x * 7 + y * 3) % 11) as f32 + 0.5 * y as f32
    });
    let img = Img::new(a.view(), "a").unwrap();
    let c = bspline_coeffs(&img);
    for y in 2..11 {
        for x in 2..15 {
            let v = c.interp(x as f64, y as f64, bspline_weights);
            assert!((v - a[[y, x]]).abs() < 1e-3, "{x} {y} {v} {}", a[[y, x]]);
        }
    }
    let w = bspline_weights(0.37);
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
}

#[test]
fn quintic_bspline_interpolates_and_reproduces_polynomials() {
    let poly = |x: f64, y: f64| 0.02 * x * x * x - 0.3 * x * y + 0.5 * y * y + 2.0 * x + 7.0;
    let a = Array2::from_shape_fn((40, 48), |(y, x)| poly(x as f64, y as f64) as f32);
    let img = Img::new(a.view(), "a").unwrap();
    let c = bspline5_coeffs(&img);
    // exact at the pixels (also at the border: mirror boundaries)
    for y in 0..40 {
        for x in 0..48 {
            let v = c.interp(x as f64, y as f64, bspline5_weights);
            let e = a[[y, x]];
            assert!((v - e).abs() < 2e-3 * e.abs().max(1.0), "{x} {y} {v} {e}");
        }
    }
    // between the pixels, away from the border: cubic polynomials are reproduced (the
    // mirror boundary's influence decays as 0.43^k)
    for &(x, y) in &[(20.3, 17.6), (24.5, 20.5), (30.9, 15.05), (17.25, 25.75)] {
        let v = c.interp(x, y, bspline5_weights) as f64;
        let e = poly(x, y);
        assert!((v - e).abs() < 1e-3 * e.abs(), "{x} {y} {v} {e}");
    }
    let w = bspline5_weights(0.37);
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    assert_eq!(bspline5_weights(0.0)[5], 0.0);
    // first moment: the weights reproduce the position
    let m: f32 = w
        .iter()
        .enumerate()
        .map(|(k, wk)| (k as f32 - 2.0) * wk)
        .sum();
    assert!((m - 0.37).abs() < 1e-6, "{m}");
}

#[test]
fn interpolation_near_the_border_is_mirrored_not_zero() {
    let a = Array2::from_elem((12, 12), 100.0f32);
    let img = Img::new(a.view(), "a").unwrap();
    for c in [bspline5_coeffs(&img), bspline_coeffs(&img)] {
        for &(x, y) in &[(-0.5, 3.0), (0.2, -0.4), (11.5, 11.3), (5.5, 11.49)] {
            let v5 = c.interp(x, y, bspline5_weights);
            let v3 = c.interp(x, y, bspline_weights);
            assert!((v5 - 100.0).abs() < 1e-3 || (v3 - 100.0).abs() < 1e-3);
        }
    }
    let c5 = bspline5_coeffs(&img);
    assert!((c5.interp(-0.5, -0.5, bspline5_weights) - 100.0).abs() < 1e-3);
    assert!((img.bicubic(-0.5, 11.5) - 100.0).abs() < 1e-3);
    assert_eq!(mirror(-1, 5), 1);
    assert_eq!(mirror(5, 5), 3);
    assert_eq!(mirror(-9, 5), 1);
    assert_eq!(mirror(3, 1), 0);
}

#[test]
fn window_average_keeps_linear_fields_and_averages_noise() {
    let grid = crate::grid::Grid::for_windows(200, 120, 32, 32, 0.5).unwrap();
    let lin = |x: f64, y: f64| 0.01 * x - 0.02 * y + 1.0;
    let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
        let (x, y) = grid.xy(j, i);
        lin(x, y)
    });
    let f = GridField {
        grid,
        u: u.clone(),
        v: -u.clone(),
    };
    let g = f.window_average(32, 32);
    // interior nodes: the top-hat mean of a linear function is its centre value
    for j in 1..grid.ny - 1 {
        for i in 1..grid.nx - 1 {
            assert!((g.u[[j, i]] - u[[j, i]]).abs() < 1e-12);
            assert!((g.v[[j, i]] + u[[j, i]]).abs() < 1e-12);
        }
    }
    // 32 px windows on a 16 px grid: weights 1/4, 1/2, 1/4 per axis
    let w = tophat_weights(32.0, 16.0, 5);
    assert_eq!(w, vec![(-1, 0.25), (0, 0.5), (1, 0.25)]);
    let w = tophat_weights(32.0, 24.0, 5);
    assert!((w.iter().map(|p| p.1).sum::<f64>() - 1.0).abs() < 1e-12);
    assert_eq!(tophat_weights(32.0, 16.0, 1), vec![(0, 1.0)]);
}

#[test]
fn separable_deformation_matches_the_2d_interpolation() {
    let (h, w) = (64, 80);
    let a = Array2::from_shape_fn((h, w), |(y, x)| {
        let (x, y) = (x as f64, y as f64);
        (1000.0 + 400.0 * (0.9 * x).sin() * (0.7 * y + 0.3).cos() + 3.0 * x) as f32
    });
    let img = Img::new(a.view(), "a").unwrap();
    let c = bspline5_coeffs(&img);
    let grid = crate::grid::Grid::for_windows(w, h, 16, 16, 0.5).unwrap();
    // a smooth field of a few px varying by up to 0.02 px/px
    let field = |x: f64, y: f64| (3.0 + 0.02 * y, -1.2 + 0.015 * x);
    let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
        let (x, y) = grid.xy(j, i);
        field(x, y).0
    });
    let v = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
        let (x, y) = grid.xy(j, i);
        field(x, y).1
    });
    let f = GridField { grid, u, v };
    let (da, db) = deform_pair(&c, &c, bspline5_weights, &f, None);
    let (mut worst, mut n) = (0.0f32, 0);
    let (x_in, y_in) = (
        grid.x0 + 3.0..=grid.x0 + (grid.nx - 1) as f64 * grid.dx - 3.0,
        grid.y0 + 3.0..=grid.y0 + (grid.ny - 1) as f64 * grid.dy - 3.0,
    );
    for y in 0..h {
        for x in 0..w {
            if !(x_in.contains(&(x as f64)) && y_in.contains(&(y as f64))) {
                continue;
            }
            let (fu, fv) = f.at(x as f64, y as f64);
            let (xa, ya) = (x as f64 - fu / 2.0, y as f64 - fv / 2.0);
            let (xb, yb) = (x as f64 + fu / 2.0, y as f64 + fv / 2.0);
            let (ga, gb) = (da.slice()[y * w + x], db.slice()[y * w + x]);
            if inside(xa, ya, w, h) {
                let e = c.interp(xa, ya, bspline5_weights);
                worst = worst.max((ga - e).abs());
                n += 1;
            } else {
                assert!(ga.is_nan());
            }
            if inside(xb, yb, w, h) {
                let e = c.interp(xb, yb, bspline5_weights);
                worst = worst.max((gb - e).abs());
            } else {
                assert!(gb.is_nan());
            }
        }
    }
    // the separable passes sample the N tap columns at y positions that vary by
    // d(f_y/2)/dx per px: an error of about d(f_y/2)/dx * var(beta5) * d2A/dxdy (0.0075 *
    // 0.5 * 252 = 0.95 counts here, a shear of 5e-4 of the pattern, the same and opposite in
    // both frames; the 2D interpolation's own error against the analytic image is larger)
    let bound = 0.0075 * 0.5 * 400.0 * 0.9 * 0.7;
    assert!(n > 1500 && (worst as f64) < 1.25 * bound, "{n} {worst}");
}

#[test]
fn rejects_nan() {
    let mut a = Array2::<f32>::zeros((4, 4));
    a[[1, 2]] = f32::NAN;
    assert!(Img::new(a.view(), "frame_a").is_err());
}

/// The deformation's AVX2 row (vector weights and gathers) equals the portable one bit for bit,
/// over a field strong enough that tap rows and offsets change inside the 8-pixel chunks, with
/// samples outside the frame (NaN) and mirrored taps at the edges; for each kernel. Reused
/// buffers give the same pair as fresh ones.
#[test]
fn deformation_vector_and_portable_paths_agree_exactly() {
    let (h, w) = (61, 203);
    let a = Array2::from_shape_fn((h, w), |(y, x)| {
        let (x, y) = (x as f64, y as f64);
        (900.0 + 300.0 * (0.8 * x).sin() * (0.6 * y + 0.2).cos() + 2.0 * y) as f32
    });
    let img = Img::new(a.view(), "a").unwrap();
    let grid = crate::grid::Grid::for_windows(w, h, 16, 16, 0.5).unwrap();
    let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
        let (x, y) = grid.xy(j, i);
        5.0 * (x / 40.0).sin() + 0.3 * y / 10.0
    });
    let v = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
        let (x, y) = grid.xy(j, i);
        -4.0 + 6.0 * (x / 25.0).cos() + 0.1 * y
    });
    let f = GridField { grid, u, v };
    let c5 = bspline5_coeffs(&img);
    let c3 = bspline_coeffs(&img);
    // buffers handed back for reuse (here full of garbage) give the same pair as fresh ones
    let fresh = deform_pair(&c5, &c5, bspline5_weights, &f, None);
    let garbage = (vec![7.5f32; w * h], vec![f32::NAN; w * h]);
    let reused = deform_pair(&c5, &c5, bspline5_weights, &f, Some(garbage));
    for (p, q) in fresh.0.slice().iter().zip(reused.0.slice()) {
        assert!(p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()));
    }
    for (p, q) in fresh.1.slice().iter().zip(reused.1.slice()) {
        assert!(p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()));
    }
    let (ba, bb) = into_buffers(reused).expect("owned buffers");
    assert_eq!((ba.len(), bb.len()), (w * h, w * h));
    let runs = [
        (
            super::deform::deform_pair_with(&c5, &c5, bspline5_weights, &f, None, true),
            super::deform::deform_pair_with(&c5, &c5, bspline5_weights, &f, None, false),
        ),
        (
            super::deform::deform_pair_with(&c3, &c3, bspline_weights, &f, None, true),
            super::deform::deform_pair_with(&c3, &c3, bspline_weights, &f, None, false),
        ),
        (
            super::deform::deform_pair_with(&img, &img, keys_weights, &f, None, true),
            super::deform::deform_pair_with(&img, &img, keys_weights, &f, None, false),
        ),
    ];
    for ((va, vb), (pa, pb)) in &runs {
        let (mut nan, mut n) = (0, 0);
        for (p, q) in va
            .slice()
            .iter()
            .zip(pa.slice())
            .chain(vb.slice().iter().zip(pb.slice()))
        {
            assert!(
                p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()),
                "{p} {q}"
            );
            nan += p.is_nan() as usize;
            n += 1;
        }
        assert!(nan > 100 && nan < n / 4, "{nan} of {n}");
    }
}

/// The separable constant-shift window equals the per-pixel one bit for bit, for the three
/// kernels, square and rectangular windows, any fraction; it declines windows whose taps
/// leave the image or rows wider than SHIFT_LINE (the caller then goes pixel by pixel).
#[test]
fn separable_shift_equals_the_per_pixel_taps() {
    let (h, w) = (90, 300);
    let a = Array2::from_shape_fn((h, w), |(y, x)| {
        let (x, y) = (x as f64, y as f64);
        (700.0 + 250.0 * (0.77 * x).sin() * (0.61 * y + 0.4).cos() + 1.5 * x - y) as f32
    });
    let img = Img::new(a.view(), "a").unwrap();
    let c5 = bspline5_coeffs(&img);
    let c3 = bspline_coeffs(&img);
    let mut n = 0;
    // (20, 12): rows of 8-column chunks and a remainder
    for (k, &(ww, wh)) in [
        (32usize, 32usize),
        (32, 8),
        (64, 16),
        (8, 32),
        (128, 4),
        (20, 12),
    ]
    .iter()
    .enumerate()
    {
        for (ix, iy) in [
            (0isize, 0isize),
            (17, 5),
            (w as isize - ww as isize - 5, 40),
        ] {
            let t = 0.137 + 0.19 * k as f32;
            let (mut sep, mut per) = (vec![0.0f32; ww * wh], vec![0.0f32; ww * wh]);
            let w5 = bspline5_weights(t);
            let w5y = bspline5_weights(1.0 - t);
            assert!(shift_separable(&c5, &w5, &w5y, ww, wh, ix, iy, &mut sep));
            shift_per_pixel(&c5, &w5, &w5y, ww, wh, ix, iy, &mut per);
            assert!(sep
                .iter()
                .zip(&per)
                .all(|(p, q)| p.to_bits() == q.to_bits()));
            let w3 = bspline_weights(t);
            assert!(shift_separable(&c3, &w3, &w3, ww, wh, ix, iy, &mut sep));
            shift_per_pixel(&c3, &w3, &w3, ww, wh, ix, iy, &mut per);
            assert!(sep
                .iter()
                .zip(&per)
                .all(|(p, q)| p.to_bits() == q.to_bits()));
            let wk = keys_weights(t);
            assert!(shift_separable(&img, &wk, &wk, ww, wh, ix, iy, &mut sep));
            shift_per_pixel(&img, &wk, &wk, ww, wh, ix, iy, &mut per);
            assert!(sep
                .iter()
                .zip(&per)
                .all(|(p, q)| p.to_bits() == q.to_bits()));
            n += 3;
        }
    }
    assert_eq!(n, 54);
    let w5 = bspline5_weights(0.3);
    let mut out = vec![0.0f32; 256 * 4];
    assert!(!shift_separable(&c5, &w5, &w5, 32, 8, -1, 3, &mut out)); // taps left of the image
    assert!(!shift_separable(&c5, &w5, &w5, 32, 8, 270, 3, &mut out)); // right of it
    assert!(!shift_separable(&c5, &w5, &w5, 32, 8, 3, 83, &mut out)); // below it
    assert!(!shift_separable(
        &c5,
        &w5,
        &w5,
        SHIFT_LINE + 1,
        2,
        0,
        0,
        &mut out
    )); // too wide
}

/// The weighted window mean of a field: exact for a linear field (symmetric weights: its value
/// at the centre), and for the top-hat's pixel weights within the pixel discretisation of
/// [`GridField::window_mean_at`] on a curved one.
#[test]
fn weighted_window_mean_of_a_field() {
    use crate::grid::Grid;
    use crate::weighting::Weighting;
    let grid = Grid {
        x0: 3.5,
        y0: 2.0,
        dx: 8.0,
        dy: 4.0,
        nx: 20,
        ny: 30,
    };
    let make = |f: &dyn Fn(f64, f64) -> (f64, f64)| {
        let u = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            f(grid.xy(j, i).0, grid.xy(j, i).1).0
        });
        let v = Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| {
            f(grid.xy(j, i).0, grid.xy(j, i).1).1
        });
        GridField { grid, u, v }
    };
    let linear = make(&|x, y| (1.5 + 0.02 * x - 0.01 * y, -0.7 + 0.03 * y + 0.005 * x));
    for wt in [Weighting::Gaussian, Weighting::Blackman] {
        let (px, py) = (wt.pixel_weights(32), wt.pixel_weights(8));
        for (x, y) in [(60.3, 50.0), (77.0, 61.7)] {
            let (u, v) = linear.weighted_mean_at(x, y, &px, &py);
            let (eu, ev) = linear.at(x, y);
            assert!(
                (u - eu).abs() < 1e-12 && (v - ev).abs() < 1e-12,
                "{wt:?} {u} {eu}"
            );
        }
    }
    let curved = make(&|x, y| ((x / 40.0).sin(), (y / 20.0).cos()));
    // the node-gathered sum is the pixel-by-pixel one, inside and past the grid's ends
    let (px, py) = (
        Weighting::Gaussian.pixel_weights(32),
        Weighting::Gaussian.pixel_weights(8),
    );
    for (x, y) in [(60.3, 50.0), (-5.0, 1.0), (170.0, 130.0)] {
        let (u, v) = curved.weighted_mean_at(x, y, &px, &py);
        let mut d = (0.0, 0.0);
        for (j, wy) in py.iter().enumerate() {
            for (i, wx) in px.iter().enumerate() {
                let (a, b) = curved.at(x - 15.5 + i as f64, y - 3.5 + j as f64);
                d = (d.0 + wx * wy * a, d.1 + wx * wy * b);
            }
        }
        assert!(
            (u - d.0).abs() < 1e-12 && (v - d.1).abs() < 1e-12,
            "{x} {y}"
        );
    }
    let (px, py) = (
        Weighting::TopHat.pixel_weights(32),
        Weighting::TopHat.pixel_weights(8),
    );
    for (x, y) in [(60.3, 50.0), (77.0, 61.7)] {
        let (u, v) = curved.weighted_mean_at(x, y, &px, &py);
        let (eu, ev) = curved.window_mean_at(x, y, 32, 8);
        assert!(
            (u - eu).abs() < 2e-3 && (v - ev).abs() < 2e-3,
            "{u} {eu} {v} {ev}"
        );
    }
}
