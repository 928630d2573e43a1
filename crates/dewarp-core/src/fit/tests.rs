//! Tests of the validating fit and the workspace refit against exact mappings.
use super::*;
use ndarray::Array2;

/// 13 x 7 object grid over the 8864 x 5288 sensor (pitch 673.84 px) and a known mapping.
pub(crate) fn grid() -> Array2<f64> {
    let pitch = 19.51 * 34.538;
    let (cx, cy) = (4431.5, 2643.5);
    let mut a = Array2::zeros((91, 2));
    for j in 0..7 {
        for i in 0..13 {
            a[[j * 13 + i, 0]] = cx + (i as f64 - 6.0) * pitch;
            a[[j * 13 + i, 1]] = cy + (j as f64 - 3.0) * pitch;
        }
    }
    a
}

fn truth(model: Model) -> Vec<f64> {
    match model {
        Model::R1 => vec![1.001, 0.002, 0.0003, -0.0015, 0.999, -0.0002, 0.003, -0.002],
        Model::R2 => vec![
            1.001, 0.002, 0.0003, 0.001, -0.002, 0.0015, -0.0015, 0.999, -0.0002, 0.002, 0.001,
            -0.003, 0.003, -0.002, 0.005, -0.004, 0.006,
        ],
        Model::P3 => vec![
            0.0001, 1.0002, 0.0003, 0.001, -0.002, 0.0005, 0.013, 0.001, 0.012, -0.0004, -0.0002,
            0.0004, 0.9998, -0.001, 0.0006, 0.002, 0.0002, 0.013, -0.0001, 0.0125,
        ],
    }
}

const S: f64 = 8000.0;
const CI: [f64; 2] = [4400.0, 2600.0];

fn apply(model: Model, c: &[f64], obj: &Array2<f64>) -> Array2<f64> {
    let mut img = obj.clone();
    for mut r in img.rows_mut() {
        let (x, y) = ((r[0] - 4431.5) / S, (r[1] - 2643.5) / S);
        let (fx, fy) = eval_normalized(model, c, x, y);
        r[0] = CI[0] + S * fx;
        r[1] = CI[1] + S * fy;
    }
    img
}

#[test]
fn noise_free_fits_reproduce_the_mapping_on_the_sensor() {
    let obj = grid();
    for model in Model::ALL {
        let c = truth(model);
        let img = apply(model, &c, &obj);
        let m = fit_mapping(obj.view(), img.view(), model, &FitOptions::default()).unwrap();
        assert_eq!(m.stats.n_points, 91);
        let mut worst: f64 = 0.0;
        for yy in (0..=5288).step_by(176) {
            for xx in (0..=8864).step_by(277) {
                let (x, y) = (xx as f64, yy as f64);
                let (fx, fy) = eval_normalized(model, &c, (x - 4431.5) / S, (y - 2643.5) / S);
                let (gx, gy) = m.forward(x, y);
                worst = worst
                    .max((gx - CI[0] - S * fx).abs())
                    .max((gy - CI[1] - S * fy).abs());
            }
        }
        assert!(worst < 0.01, "{model}: worst {worst} px");
        assert!(m.stats.rms_px[0] < 1e-6 && m.stats.rms_px[1] < 1e-6);
    }
}

#[test]
fn workspace_matches_the_accurate_fit() {
    let obj = grid();
    for model in Model::ALL {
        let c = truth(model);
        let mut img = apply(model, &c, &obj);
        // deterministic pseudo-noise of ~0.05 px
        for (k, v) in img.iter_mut().enumerate() {
            *v += 0.05 * ((k as f64 * 12.9898).sin() * 43758.5453).fract();
        }
        let m = fit_mapping(obj.view(), img.view(), model, &FitOptions::default()).unwrap();
        let s = m.scale;
        let oh: Vec<[f64; 2]> = obj
            .rows()
            .into_iter()
            .map(|r| {
                [
                    (r[0] - m.centre_object[0]) / s,
                    (r[1] - m.centre_object[1]) / s,
                ]
            })
            .collect();
        let ih: Vec<[f64; 2]> = img
            .rows()
            .into_iter()
            .map(|r| {
                [
                    (r[0] - m.centre_image[0]) / s,
                    (r[1] - m.centre_image[1]) / s,
                ]
            })
            .collect();
        let mut ws = FitWorkspace::new();
        for warm in [None, Some(m.coefficients.as_slice())] {
            let c2 = ws.fit_normalized(model, &oh, &ih, warm).unwrap().to_vec();
            for o in &oh {
                let a = eval_normalized(model, &m.coefficients, o[0], o[1]);
                let b = eval_normalized(model, &c2, o[0], o[1]);
                assert!(
                    (a.0 - b.0).abs() * s < 1e-4 && (a.1 - b.1).abs() * s < 1e-4,
                    "{model}"
                );
            }
        }
    }
}

#[test]
fn bad_input_is_rejected_with_clear_messages() {
    let obj = grid();
    let img = apply(Model::P3, &truth(Model::P3), &obj);
    let fo = FitOptions::default();
    let few = obj.slice(ndarray::s![..8, ..]);
    let e = fit_mapping(few, img.slice(ndarray::s![..8, ..]), Model::P3, &fo).unwrap_err();
    assert!(e.to_string().contains("needs at least 11 points"), "{e}");
    let mut nan = img.clone();
    nan[[5, 1]] = f64::NAN;
    let e = fit_mapping(obj.view(), nan.view(), Model::R2, &fo).unwrap_err();
    assert!(e.to_string().contains("image points point 5"), "{e}");
    let mut dup = obj.clone();
    dup[[7, 0]] = dup[[3, 0]];
    dup[[7, 1]] = dup[[3, 1]];
    let e = fit_mapping(dup.view(), img.view(), Model::R1, &fo).unwrap_err();
    assert!(e.to_string().contains("coincide"), "{e}");
    let mut line = obj.clone();
    for (k, mut r) in line.rows_mut().into_iter().enumerate() {
        r[0] = k as f64;
        r[1] = 2.0 * k as f64 + 1.0;
    }
    let e = fit_mapping(line.view(), img.view(), Model::P3, &fo).unwrap_err();
    assert!(e.to_string().contains("collinear"), "{e}");
    let e = fit_mapping(obj.view(), img.slice(ndarray::s![..90, ..]), Model::P3, &fo).unwrap_err();
    assert!(e.to_string().contains("differ in number"), "{e}");
    // three rows of points: every cubic in y is not determined
    let three = obj.slice(ndarray::s![..39, ..]);
    let e = fit_mapping(three, img.slice(ndarray::s![..39, ..]), Model::P3, &fo).unwrap_err();
    assert!(e.to_string().contains("degenerate"), "{e}");
}

/// Pixel markers (object, image) and their normalised copies.
type Markers = (Array2<f64>, Array2<f64>, Vec<[f64; 2]>, Vec<[f64; 2]>);

/// Noisy markers (~0.05 px) of the known R1/R2 mappings, normalised as `fit_mapping` does with
/// the given centre (grid point 45, the centre) and scale `S`.
fn noisy_normalised(model: Model) -> Markers {
    let obj = grid();
    let mut img = apply(model, &truth(model), &obj);
    for (k, v) in img.iter_mut().enumerate() {
        *v += 0.05 * ((k as f64 * 12.9898).sin() * 43758.5453).fract();
    }
    let norm = |a: &Array2<f64>| -> Vec<[f64; 2]> {
        let c = [a[[45, 0]], a[[45, 1]]];
        a.rows()
            .into_iter()
            .map(|r| [(r[0] - c[0]) / S, (r[1] - c[1]) / S])
            .collect()
    };
    let (oh, ih) = (norm(&obj), norm(&img));
    (obj, img, oh, ih)
}

/// The block-eliminated linearised start is the least-squares solution of the whole DLT system
/// `N(x) - t D'(x) = t`: its residual is orthogonal to every column (normal equations hold to
/// rounding).
#[test]
fn dlt_start_solves_the_whole_linearised_system() {
    for model in [Model::R1, Model::R2] {
        let (_, _, oh, ih) = noisy_normalised(model);
        let c = dlt_start(model, &oh, &ih).unwrap();
        let n = model.n_params();
        let (q, r) = if model == Model::R1 { (3, 2) } else { (6, 5) };
        let mut grad = vec![0.0; n];
        let mut scale = vec![0.0; n];
        for (o, i) in oh.iter().zip(&ih) {
            let (phi, psi) = varpro::rational_bases(model, o[0], o[1]);
            for axis in 0..2 {
                let t = i[axis];
                let mut row = vec![0.0; n];
                row[axis * q..(axis + 1) * q].copy_from_slice(&phi[..q]);
                for k in 0..r {
                    row[2 * q + k] = -t * psi[k];
                }
                let res = row.iter().zip(&c).map(|(a, b)| a * b).sum::<f64>() - t;
                for k in 0..n {
                    grad[k] += row[k] * res;
                    scale[k] += row[k].abs() * t.abs();
                }
            }
        }
        for k in 0..n {
            assert!(
                grad[k].abs() <= 1e-12 * scale[k],
                "{model} column {k}: {grad:?}"
            );
        }
    }
}

/// The validating fit (variable projection, stopped at the cost's rounding error) lands on the
/// optimum of the generic Levenberg-Marquardt over all coefficients at tight tolerances.
#[test]
fn fit_mapping_reaches_the_full_lm_optimum() {
    for model in [Model::R1, Model::R2] {
        let (obj, img, oh, ih) = noisy_normalised(model);
        let opts = FitOptions {
            center_index: Some(45),
            scale: Some(S),
            ..FitOptions::default()
        };
        let m = fit_mapping(obj.view(), img.view(), model, &opts).unwrap();
        assert!(
            m.stats.n_evals <= 4,
            "{model}: {} evaluations",
            m.stats.n_evals
        );
        let prob = MappingProblem {
            model,
            obj: &oh,
            img: &ih,
        };
        // the gradient J^T r on every coefficient at rounding of its scale |J_k| |r| (measured
        // <= 8e-12; variable projection alone leaves R2's denominators at 1e-9 here and 7e-7 on
        // test_mapping.py's data: the Gauss-Newton polish's job)
        let n = model.n_params();
        let (mut g, mut jn, mut rn) = (vec![0.0; n], vec![0.0; n], 0.0);
        let (mut jx, mut jy) = ([0.0; 20], [0.0; 20]);
        for (o, i) in oh.iter().zip(&ih) {
            eval_coeff_jacobian(model, &m.coefficients, o[0], o[1], &mut jx, &mut jy);
            let (fx, fy) = eval_normalized(model, &m.coefficients, o[0], o[1]);
            let (rx, ry) = (fx - i[0], fy - i[1]);
            rn += rx * rx + ry * ry;
            for k in 0..n {
                g[k] += jx[k] * rx + jy[k] * ry;
                jn[k] += jx[k] * jx[k] + jy[k] * jy[k];
            }
        }
        for k in 0..n {
            let rel = g[k].abs() / (jn[k] * rn).sqrt();
            assert!(
                rel < 1e-10,
                "{model} coefficient {k}: gradient {rel:e} of its scale"
            );
        }
        let reference = lm::minimize(&prob, &truth(model), &LmConfig::tight()).unwrap();
        assert!(m.stats.cost <= reference.cost * (1.0 + 1e-9), "{model}");
        for o in &oh {
            let a = eval_normalized(model, &m.coefficients, o[0], o[1]);
            let b = eval_normalized(model, &reference.params, o[0], o[1]);
            assert!(
                (a.0 - b.0).abs() * S < 1e-6 && (a.1 - b.1).abs() * S < 1e-6,
                "{model}"
            );
        }
    }
}
