//! Lamb-Oseen fits of vortex cores (`piv_core::vortex_fit`): one core, and 64 cores of one field
//! in parallel. The field: 64 vortices (r_c 12-30 px, |Gamma| 150-400 px^2 per pair, both
//! senses) on 200 x 300 vectors of 8 px with 0.05 px of noise; each core's centroid and radius
//! off the vortex's by a few px, as a thresholded core's are.
//! Run: `cargo bench -p piv-core --bench vortex_fit`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use ndarray::Array2;
use piv_core::vortex_fit::{fit_cores, OseenCore, OseenSettings};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;
use std::hint::black_box;

const H: f64 = 8.0;

fn field() -> (Array2<f64>, Array2<f64>, Vec<OseenCore>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (ny, nx) = (200, 300);
    let mut u = Array2::<f64>::zeros((ny, nx));
    let mut v = Array2::<f64>::zeros((ny, nx));
    let mut cores = Vec::new();
    for k in 0..64 {
        // one vortex per cell of an 8 x 8 layout, so that patches do not overlap much
        let xc = H * nx as f64 * ((k % 8) as f64 + 0.5 + rng.random_range(-0.2..0.2)) / 8.0;
        let yc = H * ny as f64 * ((k / 8) as f64 + 0.5 + rng.random_range(-0.2..0.2)) / 8.0;
        let rc: f64 = rng.random_range(12.0..30.0);
        let sense = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let gam = sense * rng.random_range(150.0..400.0);
        for ((i, j), uu) in u.indexed_iter_mut() {
            // y up: Y = -dy i
            let (dx, dy) = (H * j as f64 - xc, -H * i as f64 + yc);
            let s = (dx * dx + dy * dy) / (rc * rc);
            let f = if s < 1e-8 { 1.0 } else { -(-s).exp_m1() / s };
            let g = gam * f / (2.0 * PI * rc * rc);
            *uu -= g * dy;
            v[[i, j]] -= g * dx;
        }
        cores.push(OseenCore {
            col: xc / H + rng.random_range(-0.5..0.5),
            row: yc / H + rng.random_range(-0.5..0.5),
            radius: 0.8 * rc,
            sign: sense,
        });
    }
    let noise = Normal::new(0.0, 0.05).unwrap();
    u.mapv_inplace(|x| x + noise.sample(&mut rng));
    v.mapv_inplace(|x| x + noise.sample(&mut rng));
    (u, v, cores)
}

fn vortex_fit(c: &mut Criterion) {
    let (u, v, cores) = field();
    let valid = Array2::from_elem(u.dim(), true);
    let s = OseenSettings {
        dx: H,
        dy: H,
        reach: 2.5,
        orient: 1.0,
        max_evals: 100,
        shear: false,
    };
    let kept = fit_cores(u.view(), v.view(), valid.view(), &cores, &s)
        .unwrap()
        .iter()
        .filter(|f| f.ok)
        .count();
    assert!(kept >= 56, "{kept} of 64 fits kept");
    let mut g = c.benchmark_group("vortex_fit");
    g.throughput(Throughput::Elements(1));
    g.bench_function("one core", |b| {
        b.iter(|| fit_cores(u.view(), v.view(), valid.view(), black_box(&cores[..1]), &s))
    });
    g.throughput(Throughput::Elements(cores.len() as u64));
    g.bench_function("64 cores, parallel", |b| {
        b.iter(|| fit_cores(u.view(), v.view(), valid.view(), black_box(&cores), &s))
    });
    // the seventh parameter, a background shear (Stanislas, Perret & Foucaut 2008)
    let sheared = OseenSettings { shear: true, ..s };
    g.throughput(Throughput::Elements(cores.len() as u64));
    g.bench_function("64 cores, parallel, with the background shear", |b| {
        b.iter(|| {
            fit_cores(
                u.view(),
                v.view(),
                valid.view(),
                black_box(&cores),
                &sheared,
            )
        })
    });
    g.finish();
}

criterion_group!(benches, vortex_fit);
criterion_main!(benches);
