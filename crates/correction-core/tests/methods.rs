//! Methods I and II against an exact answer: a mapping that is a pure shift (object -> image
//! px, F(X) = X + (0.3, -0.2)), raw frames rendered with a uniform image displacement. The
//! object displacement then equals the image one, so both methods (and both displacement
//! mappings) must recover it; Method II's vectors sit on Method I's object grid.

use correction_core::{method_one, method_two, object_grid, DisplacementMapping, ZeroFill};
use dewarp_core::{fit_mapping, FitOptions, Model};
use ndarray::Array2;
use piv_core::{render_particles, Pass, PivSettings};
use rand::{Rng, SeedableRng};

fn shift_mapping() -> dewarp_core::Mapping {
    let mut obj = Vec::new();
    for j in 0..9 {
        for i in 0..9 {
            obj.push([20.0 + 27.0 * i as f64, 15.0 + 21.0 * j as f64]);
        }
    }
    let o = Array2::from_shape_fn((obj.len(), 2), |(k, c)| obj[k][c]);
    let img = Array2::from_shape_fn((obj.len(), 2), |(k, c)| obj[k][c] + [0.3, -0.2][c]);
    fit_mapping(o.view(), img.view(), Model::P3, &FitOptions::default()).unwrap()
}

fn pair(d: (f64, f64)) -> (Array2<u16>, Array2<u16>) {
    let (h, w) = (200, 256);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let n = (0.03 * (h * w) as f64) as usize;
    let x: Vec<f64> = (0..n)
        .map(|_| rng.random::<f64>() * (w + 20) as f64 - 10.0)
        .collect();
    let y: Vec<f64> = (0..n)
        .map(|_| rng.random::<f64>() * (h + 20) as f64 - 10.0)
        .collect();
    let i: Vec<f64> = (0..n)
        .map(|_| 800.0 + 400.0 * rng.random::<f64>())
        .collect();
    let dia = vec![2.5; n];
    let a = render_particles(h, w, &x, &y, &i, &dia, 0.0, 4095, 1).unwrap();
    let xb: Vec<f64> = x.iter().map(|v| v + d.0).collect();
    let yb: Vec<f64> = y.iter().map(|v| v + d.1).collect();
    let b = render_particles(h, w, &xb, &yb, &i, &dia, 0.0, 4095, 2).unwrap();
    (a, b)
}

#[test]
fn both_methods_recover_a_uniform_displacement_through_a_shift_mapping() {
    let m = shift_mapping();
    let (fx, fy) = m.forward(100.0, 80.0);
    assert!((fx - 100.3).abs() < 1e-9 && (fy - 79.8).abs() < 1e-9);
    let d = (2.3, 1.1);
    let (a, b) = pair(d);
    let s = PivSettings {
        passes: vec![Pass::new(64, 64), Pass::new(32, 32)],
        ..PivSettings::default()
    };
    let grid = object_grid(a.dim(), &s).unwrap();
    let one = method_one(a.view(), b.view(), &m, &s, None, None, ZeroFill::Mask).unwrap();
    for mode in [DisplacementMapping::Full, DisplacementMapping::Positions] {
        let two = method_two(a.view(), b.view(), &m, &s, mode, None, None).unwrap();
        assert_eq!(two.grid, Some(grid));
        assert_eq!(two.x, one.x);
        assert_eq!(two.y, one.y);
        let mut n = 0;
        for k in 0..two.u.len() {
            let (j, i) = (k / grid.nx, k % grid.nx);
            if !two.valid[[j, i]] {
                continue;
            }
            n += 1;
            assert!(
                (two.u[[j, i]] - d.0).abs() < 0.05,
                "{mode:?} u {}",
                two.u[[j, i]]
            );
            assert!(
                (two.v[[j, i]] - d.1).abs() < 0.05,
                "{mode:?} v {}",
                two.v[[j, i]]
            );
        }
        assert!(
            n >= grid.len() * 3 / 4,
            "{mode:?}: {n} of {} valid",
            grid.len()
        );
    }
    let mut n = 0;
    for ((&u, &v), &ok) in one.u.iter().zip(one.v.iter()).zip(one.valid.iter()) {
        if ok {
            n += 1;
            assert!(
                (u - d.0).abs() < 0.05 && (v - d.1).abs() < 0.05,
                "I: {u} {v}"
            );
        }
    }
    assert!(n >= grid.len() / 2, "I: {n} of {} valid", grid.len());
    // the zero fill of Method I (the 0.3 px shift leaves the last column's sources outside
    // the sensor only within its half pixel, so no object px is masked) and the mask rule
    let pair =
        correction_core::dewarp_pair(a.view(), b.view(), &m, None, None, ZeroFill::Mask).unwrap();
    let masked = pair.mask.unwrap();
    assert!(masked.iter().filter(|&&p| p).count() < a.ncols() + a.nrows());
}

#[test]
fn bad_input_is_an_error() {
    let m = shift_mapping();
    let (a, _) = pair((1.0, 0.0));
    let b = Array2::<u16>::zeros((10, 10));
    let s = PivSettings::default();
    let e = method_two(
        a.view(),
        b.view(),
        &m,
        &s,
        DisplacementMapping::Full,
        None,
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("differ in shape"), "{e}");
    let e = method_one(a.view(), b.view(), &m, &s, None, None, ZeroFill::Mask)
        .unwrap_err()
        .to_string();
    assert!(e.contains("differ in shape"), "{e}");
    let tiny = PivSettings {
        passes: vec![Pass::new(512, 512)],
        ..PivSettings::default()
    };
    let e = method_two(
        a.view(),
        a.view(),
        &m,
        &tiny,
        DisplacementMapping::Full,
        None,
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("larger than the image"), "{e}");
}
