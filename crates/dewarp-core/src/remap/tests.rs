//! Tests of the remap: exact references (Keys kernel in f64), identity, grids, borders, SIMD vs scalar.
use super::coords::*;
use super::scalar::*;
use super::*;
use ndarray::Array2;

/// A smooth analytic image: low-frequency sinusoids and a Gaussian.
fn analytic(x: f64, y: f64) -> f64 {
    1000.0
        + 300.0 * (2.0 * std::f64::consts::PI * x / 47.0 + 0.3).sin()
        + 200.0 * (2.0 * std::f64::consts::PI * y / 31.0 - 1.1).cos()
        + 150.0 * (2.0 * std::f64::consts::PI * (x + y) / 59.0).sin()
        + 400.0 * (-((x - 70.0).powi(2) + (y - 40.0).powi(2)) / (2.0 * 15.0f64.powi(2))).exp()
}

fn render(h: usize, w: usize, f: impl Fn(f64, f64) -> f64) -> Array2<f32> {
    Array2::from_shape_fn((h, w), |(y, x)| f(x as f64, y as f64) as f32)
}

/// A lens-like map: rotation, scale, pincushion and decentring (object -> image px).
fn lens(x: f64, y: f64) -> (f64, f64) {
    let (cx, cy) = (64.3, 48.7);
    let (dx, dy) = (x - cx, y - cy);
    let r2 = (dx * dx + dy * dy) / (80.0 * 80.0);
    let (c, s) = (0.03f64.cos(), 0.03f64.sin());
    let k = 1.0 + 0.004 * r2;
    let px = k * dx + 0.5e-3 * dx * dy / 80.0;
    let py = k * dy;
    (cx + 0.7 + c * px - s * py, cy - 0.4 + s * px + c * py)
}

#[test]
fn identity_map_returns_image_exactly() {
    let img = Array2::from_shape_fn((37, 53), |(y, x)| ((x * 7919 + y * 104729) % 65536) as u16);
    let id = |x: f64, y: f64| (x, y);
    for sampling in [
        MapSampling::Exact,
        MapSampling::Grid { step: 16 },
        MapSampling::Auto { tol: 1e-3 },
    ] {
        let opts = RemapOptions {
            sampling,
            ..Default::default()
        };
        let out: Array2<u16> = remap(img.view(), &id, &opts).unwrap();
        assert_eq!(out, img);
        let outf: Array2<f32> = remap(img.view(), &id, &opts).unwrap();
        assert!(outf.iter().zip(img.iter()).all(|(a, b)| *a == *b as f32));
    }
}

#[test]
fn integer_shift_is_exact_with_zero_fill() {
    let img = render(30, 40, analytic);
    let map = |x: f64, y: f64| (x + 3.0, y - 2.0);
    let out: Array2<f32> = remap(img.view(), &map, &RemapOptions::default()).unwrap();
    for ((y, x), &v) in out.indexed_iter() {
        let (sx, sy) = (x as i64 + 3, y as i64 - 2);
        if sx >= 40 || sy < 0 {
            assert_eq!(v, 0.0, "({x},{y}) outside");
        } else {
            assert_eq!(v, img[(sy as usize, sx as usize)]);
        }
    }
}

#[test]
fn zero_fill_outside_and_footprint_inside() {
    let img = Array2::<f32>::from_elem((10, 12), 500.0);
    // Points just inside the footprint [-0.5, w-0.5] get the (replicated) constant; beyond
    // it the fill value.
    let pts = [(-0.49, 3.0), (11.49, 3.0), (4.0, -0.5), (4.0, 9.5)];
    let outside = [
        (-0.51, 3.0),
        (11.51, 3.0),
        (4.0, -0.6),
        (4.0, 9.6),
        (f64::NAN, 1.0),
    ];
    let coords_x = Array2::from_shape_fn(
        (1, 9),
        |(_, i)| if i < 4 { pts[i].0 } else { outside[i - 4].0 },
    );
    let coords_y = Array2::from_shape_fn(
        (1, 9),
        |(_, i)| if i < 4 { pts[i].1 } else { outside[i - 4].1 },
    );
    let out: Array2<f32> =
        remap_with_coords(img.view(), coords_x.view(), coords_y.view(), 0.0).unwrap();
    for i in 0..4 {
        assert!(
            (out[(0, i)] - 500.0).abs() < 1e-3,
            "inside {i}: {}",
            out[(0, i)]
        );
    }
    for i in 4..9 {
        assert_eq!(out[(0, i)], 0.0, "outside {i}");
    }
    let out7: Array2<f32> =
        remap_with_coords(img.view(), coords_x.view(), coords_y.view(), 7.0).unwrap();
    assert_eq!(out7[(0, 8)], 7.0);
}

/// Max error of a sub-pixel shift of sinusoids with wavelength `lam` (px).
fn shift_error(lam: f64) -> f64 {
    let k = 2.0 * std::f64::consts::PI / lam;
    let f = |x: f64, y: f64| 100.0 * (k * x + 0.2).sin() * (0.5 * k * y).cos();
    let img = render(64, 64, f);
    let (ddx, ddy) = (0.37, -0.81);
    let map = move |x: f64, y: f64| (x + ddx, y + ddy);
    let out: Array2<f32> = remap(img.view(), &map, &RemapOptions::default()).unwrap();
    let mut worst = 0.0f64;
    for y in 4..60 {
        for x in 4..60 {
            let e = (out[(y, x)] as f64 - f(x as f64 + ddx, y as f64 + ddy)).abs();
            worst = worst.max(e);
        }
    }
    worst / 100.0
}

#[test]
fn subpixel_shift_converges_at_third_order() {
    // Keys (a = -0.5) is third-order accurate: the error of a band-limited signal falls
    // as (1/lambda)^3. Doubling the wavelength divides it by ~8.
    let e16 = shift_error(16.0);
    let e32 = shift_error(32.0);
    let e64 = shift_error(64.0);
    assert!(e16 < 2e-3, "e16 {e16}");
    let (r1, r2) = (e16 / e32, e32 / e64);
    assert!(r1 > 6.0 && r1 < 10.0, "ratio {r1}");
    assert!(r2 > 6.0 && r2 < 10.0, "ratio {r2}");
}

#[test]
fn analytic_warp_matches_analytic_image() {
    let (h, w) = (96, 128);
    let img = render(h, w, analytic);
    for sampling in [MapSampling::Exact, MapSampling::Auto { tol: 1e-3 }] {
        let opts = RemapOptions {
            sampling,
            ..Default::default()
        };
        let out: Array2<f32> = remap(img.view(), &lens, &opts).unwrap();
        let mut worst = 0.0f64;
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let (sx, sy) = lens(x as f64, y as f64);
                if sx < 2.0 || sy < 2.0 || sx > w as f64 - 3.0 || sy > h as f64 - 3.0 {
                    continue;
                }
                worst = worst.max((out[(y, x)] as f64 - analytic(sx, sy)).abs());
            }
        }
        // Shortest wavelength 31 px, amplitudes <= 400: Keys' third-order error is ~1e-4 of
        // the amplitude per term (see the convergence test), ~0.04 in all (measured 0.042);
        // the grid adds <= 1e-3 px of map error times |grad| (<= ~60 per px).
        let bound = if sampling == MapSampling::Exact {
            0.06
        } else {
            0.06 + 0.06
        };
        assert!(worst < bound, "{sampling:?}: worst {worst}");
    }
}

#[test]
fn auto_grid_is_within_tolerance_everywhere() {
    let (h, w) = (400, 600);
    // Stronger curvature than `lens`, on a larger output.
    let map = |x: f64, y: f64| {
        let (dx, dy) = (x - 300.0, y - 200.0);
        let r2 = (dx * dx + dy * dy) / 1e5;
        (
            x + 0.5 * r2 * dx / 300.0,
            y + 0.5 * r2 * dy / 300.0 + 1e-6 * dx * dx * dy / 10.0,
        )
    };
    let grid = CoordGrid::auto(&map, h, w, 1e-3).unwrap().unwrap();
    assert!(grid.step() >= 2 && grid.step() < 128);
    let mut worst = 0.0f64;
    for y in (0..h).step_by(3) {
        for x in (0..w).step_by(5) {
            let (ex, ey) = map(x as f64, y as f64);
            let (ax, ay) = grid.eval(x as f64, y as f64);
            worst = worst.max((ex - ax).hypot(ey - ay));
        }
    }
    assert!(worst <= 1e-3, "worst {worst} at step {}", grid.step());
    // The row filler agrees with eval.
    let mut sx = vec![0.0; w];
    let mut sy = vec![0.0; w];
    for y in [0, 1, 63, 199, h - 1] {
        grid.fill_row(y, &mut sx, &mut sy);
        for x in 0..w {
            let (ax, ay) = grid.eval(x as f64, y as f64);
            assert!((sx[x] - ax).abs() < 1e-9 && (sy[x] - ay).abs() < 1e-9);
        }
    }
}

#[test]
fn linear_map_grid_is_exact_and_matches_exact_sampling() {
    let img = render(50, 70, analytic);
    let map = |x: f64, y: f64| (0.98 * x + 0.01 * y + 0.3, -0.01 * x + 1.01 * y - 0.2);
    let a: Array2<f32> = remap(
        img.view(),
        &map,
        &RemapOptions {
            sampling: MapSampling::Exact,
            ..Default::default()
        },
    )
    .unwrap();
    let b: Array2<f32> = remap(
        img.view(),
        &map,
        &RemapOptions {
            sampling: MapSampling::Grid { step: 16 },
            ..Default::default()
        },
    )
    .unwrap();
    let d = a
        .iter()
        .zip(b.iter())
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f32::max);
    assert!(d < 1e-2, "{d}");
}

#[test]
fn u16_output_rounds_and_clamps() {
    assert_eq!(<u16 as OutSample>::from_f32(2.5), 3);
    assert_eq!(<u16 as OutSample>::from_f32(2.49), 2);
    assert_eq!(<u16 as OutSample>::from_f32(-3.0), 0);
    assert_eq!(<u16 as OutSample>::from_f32(70000.0), 65535);
    assert_eq!(<u16 as OutSample>::from_f32(f32::NAN), 0);
}

#[test]
fn non_contiguous_input_and_output_shape() {
    let big = render(40, 60, analytic);
    let view = big.slice(ndarray::s![..;2, ..;2]);
    let map = |x: f64, y: f64| (x + 0.5, y + 0.25);
    let opts = RemapOptions {
        out_shape: Some((7, 9)),
        ..Default::default()
    };
    let out: Array2<f32> = remap(view, &map, &opts).unwrap();
    let owned = view.to_owned();
    let ref_out: Array2<f32> = remap(owned.view(), &map, &opts).unwrap();
    assert_eq!(out.dim(), (7, 9));
    assert_eq!(out, ref_out);
}

#[test]
fn simd_kernel_agrees_with_scalar_kernel() {
    // Random positions inside, on the border and outside the image, some NaN; row lengths
    // that are not multiples of 8.
    let (h, w) = (23usize, 37usize);
    let img16 = Array2::from_shape_fn((h, w), |(y, x)| ((x * 7919 + y * 104_729) % 4096) as u16);
    let img32 = img16.mapv(|v| v as f32 * 0.37 - 100.0);
    let mut state = 12345u64;
    let mut rnd = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for n in [1usize, 7, 8, 9, 61, 64] {
        let mut sx: Vec<f64> = (0..n).map(|_| -3.0 + (w as f64 + 6.0) * rnd()).collect();
        let sy: Vec<f64> = (0..n).map(|_| -3.0 + (h as f64 + 6.0) * rnd()).collect();
        if n > 5 {
            sx[3] = f64::NAN;
        }
        let d16 = img16.as_slice().unwrap();
        let d32 = img32.as_slice().unwrap();
        let mut a = vec![0.0f32; n];
        let mut b = vec![0.0f32; n];
        interp_row(d16, h, w, &sx, &sy, -1.0f32, &mut a);
        interp_row_best(d16, h, w, &sx, &sy, -1.0f32, &mut b);
        for k in 0..n {
            assert!(
                (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
                "u16 {k}: {} {}",
                a[k],
                b[k]
            );
        }
        interp_row(d32, h, w, &sx, &sy, -1.0f32, &mut a);
        interp_row_best(d32, h, w, &sx, &sy, -1.0f32, &mut b);
        for k in 0..n {
            assert!(
                (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
                "f32 {k}: {} {}",
                a[k],
                b[k]
            );
        }
        let mut c = vec![0u16; n];
        let mut e = vec![0u16; n];
        interp_row(d16, h, w, &sx, &sy, 0u16, &mut c);
        interp_row_best(d16, h, w, &sx, &sy, 0u16, &mut e);
        for k in 0..n {
            assert!((c[k] as i32 - e[k] as i32).abs() <= 1, "u16 out {k}");
        }
    }
    // Fully inside: the SIMD lanes are exercised (every position in the fast region).
    let n = 64;
    let sx: Vec<f64> = (0..n).map(|_| 1.0 + (w as f64 - 3.1) * rnd()).collect();
    let sy: Vec<f64> = (0..n).map(|_| 1.0 + (h as f64 - 3.1) * rnd()).collect();
    let mut a = vec![0.0f32; n];
    let mut b = vec![0.0f32; n];
    interp_row(img16.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, &mut a);
    interp_row_best(img16.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, &mut b);
    for k in 0..n {
        assert!(
            (a[k] - b[k]).abs() <= 1e-3 * (1.0 + a[k].abs()),
            "inside {k}"
        );
    }
}

/// Keys interpolation in f64 straight from the kernel definition: zero outside the
/// footprint `[-0.5, w - 0.5] x [-0.5, h - 0.5]`, edge pixels replicated inside it.
fn reference_keys(img: &Array2<u16>, x: f64, y: f64) -> f64 {
    let (h, w) = img.dim();
    if !(x >= -0.5 && x <= w as f64 - 0.5 && y >= -0.5 && y <= h as f64 - 0.5) {
        return 0.0;
    }
    let (fx, fy) = (x.floor(), y.floor());
    let mut v = 0.0;
    for r in -1..=2 {
        let yy = ((fy as i64 + r).clamp(0, h as i64 - 1)) as usize;
        let wy = keys_kernel(y - (fy + r as f64));
        for c in -1..=2 {
            let xx = ((fx as i64 + c).clamp(0, w as i64 - 1)) as usize;
            v += wy * keys_kernel(x - (fx + c as f64)) * img[(yy, xx)] as f64;
        }
    }
    v
}

/// Runs `interp_row_best` over every row of `map` (output `oh x ow`); returns the output and
/// the number of contiguous-load blocks.
fn run_best(
    img: &Array2<u16>,
    oh: usize,
    ow: usize,
    map: impl Fn(f64, f64) -> (f64, f64),
) -> (Array2<f32>, usize) {
    let (h, w) = img.dim();
    let mut out = Array2::<f32>::zeros((oh, ow));
    let mut blocks = 0;
    for y in 0..oh {
        let (sx, sy): (Vec<f64>, Vec<f64>) = (0..ow).map(|x| map(x as f64, y as f64)).unzip();
        let o = out.row_mut(y).into_slice().unwrap();
        blocks += interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0.0f32, o);
    }
    (out, blocks)
}

fn random_image(h: usize, w: usize, seed: u64) -> Array2<u16> {
    let mut state = seed;
    Array2::from_shape_fn((h, w), |_| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) % 4096) as u16
    })
}

/// Largest |fast - reference| over the output.
fn max_dev(img: &Array2<u16>, out: &Array2<f32>, map: impl Fn(f64, f64) -> (f64, f64)) -> f64 {
    out.indexed_iter()
        .map(|((y, x), &v)| {
            let (sx, sy) = map(x as f64, y as f64);
            (v as f64 - reference_keys(img, sx, sy)).abs()
        })
        .fold(0.0, f64::max)
}

#[test]
fn contiguous_fast_path_matches_reference_keys() {
    // A near-identity lens-like map (scale, rotation, pincushion) shifted so that parts of
    // the output fall on the image border and outside it (zero fill); a random 12-bit image,
    // where neighbouring taps are uncorrelated (worst case for rounding).
    let (h, w) = (70usize, 203usize);
    let img = random_image(h, w, 7);
    let map = |x: f64, y: f64| {
        let (dx, dy) = (x - 100.0, y - 35.0);
        let k = 1.0 + 2e-6 * (dx * dx + dy * dy);
        let (s, c) = (0.004f64.sin(), 0.004f64.cos());
        let (px, py) = (1.003 * k * dx, k * dy);
        (100.0 + 2.3 + c * px - s * py, 35.0 - 2.3 + s * px + c * py)
    };
    let (out, blocks) = run_best(&img, h, w, map);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // Most 8-pixel blocks (25 per row) take the contiguous path.
        assert!(blocks > h * 25 * 2 / 3, "contiguous blocks {blocks}");
    }
    let _ = blocks;
    // f32 weights and sums on values up to 4095: rounding ~1e-7 relative, a few 1e-4 counts.
    let dev = max_dev(&img, &out, map);
    assert!(dev < 2e-3, "max deviation {dev} counts");
    // The shift puts the last 2-3 columns and the first row outside the footprint: fill.
    assert!(out.row(0).iter().all(|&v| v == 0.0));
    assert!(out.column(w - 1).iter().all(|&v| v == 0.0));
    assert!(out.row(h / 2).iter().filter(|&&v| v != 0.0).count() > w - 5);
}

#[test]
fn strong_distortion_falls_back_to_gathers_correctly() {
    // Source columns 1.7 px apart and rows changing along the output row: no block of 8
    // has consecutive columns in one row band, every block takes the gather path.
    let (h, w) = (40usize, 90usize);
    let img = random_image(h, w, 11);
    let map = |x: f64, y: f64| (1.7 * x - 0.2 * y + 3.1, 0.35 * x + 0.5 * y + 1.2);
    let (out, blocks) = run_best(&img, 30, 48, map);
    assert_eq!(blocks, 0);
    let dev = max_dev(&img, &out, map);
    assert!(dev < 2e-3, "max deviation {dev} counts");
    assert!(out.iter().filter(|&&v| v != 0.0).count() > 30 * 48 / 2);
    // Mixed: a map that is contiguous on the left and stretched on the right of each row.
    let mixed = |x: f64, y: f64| {
        let sx = if x < 40.0 {
            x + 0.3
        } else {
            40.3 + 1.4 * (x - 40.0)
        };
        (sx, y + 0.01 * x + 0.6)
    };
    let (out, blocks) = run_best(&img, 30, 64, mixed);
    assert!(blocks > 0 && blocks < 30 * 8, "contiguous blocks {blocks}");
    let dev = max_dev(&img, &out, mixed);
    assert!(dev < 2e-3, "max deviation {dev} counts");
    // Mirrored and strongly stretched maps through `remap` on a grid of step 16 (the fused
    // grid path with f32 offsets, or the f64 path where offsets get long): against the
    // reference at the grid's positions.
    for map in [
        (|x: f64, y: f64| (80.0 - 0.9 * x, 2.0 + 0.8 * y + 0.01 * x)) as fn(f64, f64) -> (f64, f64),
        |x: f64, y: f64| (3.0 + 40.0 * x, 5.0 + 0.5 * y),
        |x: f64, y: f64| (2.5 + 0.02 * x, 1.5 + 0.3 * y + 0.001 * x * x),
    ] {
        let opts = RemapOptions {
            out_shape: Some((30, 96)),
            sampling: MapSampling::Grid { step: 16 },
            ..Default::default()
        };
        let out: Array2<f32> = remap(img.view(), &map, &opts).unwrap();
        let grid = CoordGrid::build(&map, 30, 96, 16).unwrap();
        let dev = max_dev(&img, &out, |x, y| grid.eval(x, y));
        assert!(dev < 0.03, "max deviation {dev} counts");
        assert!(out.iter().any(|&v| v != 0.0));
    }
}

#[test]
fn simd_u16_store_rounds_like_from_f32() {
    let vals = [
        -3.0f32, -0.6, -0.5, -0.49, 0.0, 0.49, 0.5, 2.5, 1234.5001, 65534.5, 65535.49, 65535.6,
        70000.0, 3e9, -3e9,
    ];
    // Through the whole kernel: an f32 image holding the values, identity map (weights
    // exactly 0, 1, 0, 0) so the interpolated value is the pixel itself.
    let (h, w) = (8usize, vals.len() + 8);
    let img = Array2::from_shape_fn((h, w), |(_, x)| {
        if (4..4 + vals.len()).contains(&x) {
            vals[x - 4]
        } else {
            1.0
        }
    });
    let mut out = vec![0u16; w - 8];
    let sx: Vec<f64> = (0..w - 8).map(|x| (x + 4) as f64).collect();
    let sy = vec![3.0; w - 8];
    let blocks = interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0u16, &mut out);
    for (k, &v) in vals.iter().enumerate() {
        assert_eq!(out[k], <u16 as OutSample>::from_f32(v), "value {v}");
    }
    // Non-finite values straight through the SIMD store.
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        assert_eq!(blocks, vals.len() / 8);
        let v = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            0.5,
            1.49,
            9.5,
            -7.0,
        ];
        let mut o = [7u16; 8];
        // SAFETY: AVX2 and FMA are available (checked above); `o` holds 8 values.
        unsafe {
            use std::arch::x86_64::_mm256_loadu_ps;
            avx2::store8(_mm256_loadu_ps(v.as_ptr()), &mut o);
        }
        for k in 0..8 {
            assert_eq!(o[k], <u16 as OutSample>::from_f32(v[k]), "value {}", v[k]);
        }
    }
    let _ = blocks;
}

#[test]
fn spans_and_strided_output_agree_with_whole_rows() {
    let map = |x: f64, y: f64| {
        let (dx, dy) = (x - 300.0, y - 200.0);
        let r2 = (dx * dx + dy * dy) / 1e5;
        (x + 0.5 * r2 * dx / 300.0, y + 0.5 * r2 * dy / 300.0)
    };
    let (h, w) = (40, 1100);
    let grid = CoordGrid::build(&map, h, w, 16).unwrap();
    let (mut sx, mut sy) = (vec![0.0; w], vec![0.0; w]);
    for y in [0, 17, h - 1] {
        grid.fill_row(y, &mut sx, &mut sy);
        for x0 in [0usize, 5, 16, 511, 512, 1000] {
            let n = (w - x0).min(300);
            let (mut px, mut py) = (vec![0.0; n], vec![0.0; n]);
            grid.fill_span(y, x0, &mut px, &mut py);
            for k in 0..n {
                let (ax, ay) = grid.eval((x0 + k) as f64, y as f64);
                assert!((px[k] - sx[x0 + k]).abs() < 1e-9 && (px[k] - ax).abs() < 1e-9);
                assert!((py[k] - sy[x0 + k]).abs() < 1e-9 && (py[k] - ay).abs() < 1e-9);
            }
        }
    }
    // Output rows longer than a span, written through a strided view.
    let img = random_image(60, 1100, 3);
    let opts = RemapOptions {
        out_shape: Some((h, w)),
        ..Default::default()
    };
    let a: Array2<f32> = remap(img.view(), &map, &opts).unwrap();
    let mut big = Array2::<f32>::zeros((h, 2 * w));
    let view = big.slice_mut(ndarray::s![.., ..;2]);
    remap_into(img.view(), &map, opts.sampling, 0.0, view).unwrap();
    assert_eq!(big.slice(ndarray::s![.., ..;2]), a);
    // Against the reference at the auto grid's interpolated map (what `remap` samples).
    let auto = CoordGrid::auto(&map, h, w, 1e-3).unwrap().unwrap();
    let dev = max_dev(&img, &a, |x, y| auto.eval(x, y));
    // f32 position offsets on the fused grid path: see grid_cells_kernel_equals_coordinate_path.
    assert!(dev < 0.03, "max deviation {dev} counts");
}

#[test]
fn grid_cells_kernel_equals_coordinate_path() {
    // The fused grid path (cell-linear coordinates straight into the kernel) against
    // coordinates filled per span and the row kernel: the same positions, so the same bits.
    // Output wider than the image and shifted: border, outside and partial blocks included.
    let img = random_image(90, 300, 5);
    let (oh, ow) = (70usize, 331usize);
    let map = |x: f64, y: f64| {
        let (dx, dy) = (x - 150.0, y - 45.0);
        let k = 1.0 + 3e-6 * (dx * dx + dy * dy);
        (
            150.0 - 4.2 + k * dx + 0.002 * dy,
            45.0 + 6.1 + k * dy - 0.002 * dx,
        )
    };
    let (h, w) = img.dim();
    for step in [8usize, 16, 24, 64, 4] {
        let grid = CoordGrid::build(&map, oh, ow, step).unwrap();
        for y in [0usize, 1, 33, oh - 1] {
            for (x0, n) in [(0usize, ow), (5, 200), (64, 267)] {
                let mut a = vec![0.0f32; n];
                let fused = grid.interp_span(y, x0, img.as_slice().unwrap(), h, w, 0.0, &mut a);
                let (mut sx, mut sy) = (vec![0.0; n], vec![0.0; n]);
                grid.fill_span(y, x0, &mut sx, &mut sy);
                let mut b = vec![0.0f32; n];
                interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0.0, &mut b);
                if fused {
                    // Inside the image the fused path takes positions as f32 offsets from
                    // an integer base (<= ~4e-6 px from the f64 positions at 32 px from
                    // the cell start); the Keys interpolant of random 12-bit data changes
                    // by < 6000 counts/px, plus f32 sum rounding (~2e-3): < 0.03 counts.
                    for (p, q) in a.iter().zip(&b) {
                        assert!((p - q).abs() <= 0.03, "step {step} row {y}: {p} {q}");
                    }
                } else {
                    // Steps that are not a multiple of 8 (or no AVX2) take the other path.
                    assert!(step % 8 != 0 || !cfg!(target_arch = "x86_64") || a == b);
                }
                let mut c = vec![0u16; n];
                let fused16 = grid.interp_span(y, x0, img.as_slice().unwrap(), h, w, 0u16, &mut c);
                if fused16 {
                    let mut d = vec![0u16; n];
                    interp_row_best(img.as_slice().unwrap(), h, w, &sx, &sy, 0u16, &mut d);
                    // Rounded: equal but for values within 0.03 of a half-integer.
                    assert!(c.iter().zip(&d).all(|(p, q)| p.abs_diff(*q) <= 1));
                }
            }
        }
    }
}

#[test]
fn invalid_inputs_are_errors() {
    let img = Array2::<u16>::zeros((4, 4));
    let id = |x: f64, y: f64| (x, y);
    let e = remap::<u16, f32, _>(
        img.view(),
        &id,
        &RemapOptions {
            out_shape: Some((0, 3)),
            ..Default::default()
        },
    );
    assert!(e.is_err());
    let e = remap::<u16, f32, _>(
        img.view(),
        &id,
        &RemapOptions {
            sampling: MapSampling::Grid { step: 0 },
            ..Default::default()
        },
    );
    assert!(e.is_err());
    let e = remap::<u16, f32, _>(
        img.view(),
        &id,
        &RemapOptions {
            sampling: MapSampling::Auto { tol: -1.0 },
            ..Default::default()
        },
    );
    assert!(e.is_err());
    let empty = Array2::<u16>::zeros((0, 4));
    assert!(remap::<u16, f32, _>(empty.view(), &id, &RemapOptions::default()).is_err());
    let mx = Array2::<f64>::zeros((2, 3));
    let my = Array2::<f64>::zeros((3, 2));
    assert!(remap_with_coords::<u16, f32, f64>(img.view(), mx.view(), my.view(), 0.0).is_err());
}

#[test]
fn every_pixel_type_gives_the_f32_result() {
    // u8 and f64 inputs (image-core's Pixel) take the same paths as f32: the values of a u8
    // image are exact in f32 and f64, so all three remaps must agree to the bit (both on the
    // SIMD path and at the borders, through a lens map with contiguous and gathered blocks).
    let img8 = Array2::from_shape_fn((61, 83), |(y, x)| ((x * 37 + y * 11) % 256) as u8);
    let img32 = img8.mapv(|p| p as f32);
    let img64 = img8.mapv(|p| p as f64);
    for sampling in [MapSampling::Exact, MapSampling::Grid { step: 16 }] {
        let opts = RemapOptions {
            sampling,
            ..Default::default()
        };
        let a: Array2<f32> = remap(img32.view(), &lens, &opts).unwrap();
        let b: Array2<f32> = remap(img8.view(), &lens, &opts).unwrap();
        let c: Array2<f32> = remap(img64.view(), &lens, &opts).unwrap();
        assert_eq!(a, b, "{sampling:?}: u8");
        assert_eq!(a, c, "{sampling:?}: f64");
        assert!(a.iter().any(|&v| v > 0.0));
    }
}
