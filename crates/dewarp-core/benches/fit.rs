//! One fit of the 91 markers (13 x 7 over the 47 MP sensor) per model.
//!
//! - `refit/*`: the allocation-free `FitWorkspace::fit_normalized` used by the Monte Carlo study,
//!   cycling over 64 perturbed data sets (image sigma 0.057 px, object sigma 0.380 px, central
//!   marker fixed); R1/R2 warm-started from the unperturbed solution (`warm`) or from the
//!   linearised solution (`cold`).
//! - `fit_mapping/*`: the validating, reference-quality fit (pixel input, statistics,
//!   covariance, tight LM tolerances).
//!
//! Run: `cargo bench -p dewarp-core --bench fit`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use dewarp_core::{eval_normalized, fit_mapping, FitOptions, FitWorkspace, Model};
use ndarray::Array2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

const S: f64 = 8423.924;

fn truth(model: Model) -> Vec<f64> {
    let k = 0.0088;
    match model {
        Model::R1 => vec![
            1.0004, 0.0003, 2e-4, -0.0002, 0.9997, -3e-4, 0.0025, -0.0015,
        ],
        Model::R2 => vec![
            1.0004, 0.0003, 2e-4, 1.5e-4, -1e-4, 0.5e-4, -0.0002, 0.9997, -3e-4, -0.5e-4, 1.2e-4,
            2e-4, 0.0004, -0.0003, -k, 0.0, -k,
        ],
        Model::P3 => vec![
            2e-4, 1.0004, 0.0003, 1.5e-4, -1e-4, 0.5e-4, k, 0.0, k, 0.0, -3e-4, -0.0002, 0.9997,
            -0.5e-4, 1.2e-4, 2e-4, 0.0, k, 0.0, k,
        ],
    }
}

/// Normalised object grid (central marker at the origin) and its exact images.
fn grid(model: Model) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let pitch = 19.51 * 34.538 / S;
    let c = truth(model);
    let mut o = Vec::new();
    let mut i = Vec::new();
    for r in 0..7 {
        for q in 0..13 {
            let (x, y) = ((q as f64 - 6.0) * pitch, (r as f64 - 3.0) * pitch);
            let (fx, fy) = eval_normalized(model, &c, x, y);
            let (gx, gy) = eval_normalized(model, &c, 0.0, 0.0);
            o.push([x, y]);
            i.push([fx - gx, fy - gy]);
        }
    }
    (o, i)
}

fn perturbed(model: Model, sets: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let (o, i) = grid(model);
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let ni = Normal::new(0.0, 0.057 / S).unwrap();
    let no = Normal::new(0.0, 0.380 / S).unwrap();
    let mut os = Vec::new();
    let mut is = Vec::new();
    for _ in 0..sets {
        for k in 0..o.len() {
            if k == 45 {
                os.push(o[k]);
                is.push(i[k]);
            } else {
                os.push([o[k][0] + no.sample(&mut rng), o[k][1] + no.sample(&mut rng)]);
                is.push([i[k][0] + ni.sample(&mut rng), i[k][1] + ni.sample(&mut rng)]);
            }
        }
    }
    (os, is)
}

fn bench_refit(c: &mut Criterion) {
    let mut g = c.benchmark_group("refit");
    g.throughput(Throughput::Elements(1));
    const SETS: usize = 64;
    for model in Model::ALL {
        let (o0, i0) = grid(model);
        let mut ws = FitWorkspace::new();
        let start = ws.fit_normalized(model, &o0, &i0, None).unwrap().to_vec();
        let (os, is) = perturbed(model, SETS);
        let n = o0.len();
        let warm_modes: &[bool] = if model == Model::P3 {
            &[false]
        } else {
            &[true, false]
        };
        for &warm in warm_modes {
            let label = match (model, warm) {
                (Model::P3, _) => "p3".to_string(),
                (_, true) => format!("{model}_warm"),
                (_, false) => format!("{model}_cold"),
            };
            let mut k = 0;
            g.bench_function(label, |b| {
                b.iter(|| {
                    let s = (k % SETS) * n;
                    k += 1;
                    let w = warm.then_some(start.as_slice());
                    black_box(
                        ws.fit_normalized(model, &os[s..s + n], &is[s..s + n], w)
                            .unwrap()[0],
                    )
                })
            });
        }
    }
    g.finish();
}

fn bench_fit_mapping(c: &mut Criterion) {
    let mut g = c.benchmark_group("fit_mapping");
    g.throughput(Throughput::Elements(1));
    for model in Model::ALL {
        let (os, is) = perturbed(model, 1);
        let mut obj = Array2::zeros((os.len(), 2));
        let mut img = Array2::zeros((os.len(), 2));
        for k in 0..os.len() {
            obj[[k, 0]] = 4431.5 + S * os[k][0];
            obj[[k, 1]] = 2643.5 + S * os[k][1];
            img[[k, 0]] = 4380.0 + S * is[k][0];
            img[[k, 1]] = 2555.0 + S * is[k][1];
        }
        let opts = FitOptions::default();
        g.bench_function(model.name(), |b| {
            b.iter(|| {
                black_box(
                    fit_mapping(obj.view(), img.view(), model, &opts)
                        .unwrap()
                        .coefficients[0],
                )
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_refit, bench_fit_mapping);
criterion_main!(benches);
