//! The particle count of one frame (`piv_core::seeding::measure`: each 64 px block's quantiles,
//! then its local maxima above the threshold), in pixels per second, on a 2048 x 2048 synthetic
//! frame of 0.03 particles/px. Run: `cargo bench -p piv-core --bench seeding`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use piv_core::render_particles;
use piv_core::seeding::measure;
use rand::{Rng, SeedableRng};
use std::hint::black_box;

fn seeding(c: &mut Criterion) {
    let (h, w) = (2048usize, 2048usize);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let n = (0.03 * (h * w) as f64) as usize;
    let xs: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * w as f64).collect();
    let ys: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * h as f64).collect();
    let it: Vec<f64> = (0..n)
        .map(|_| 1500.0 + 1000.0 * rng.random::<f64>())
        .collect();
    let img = render_particles(h, w, &xs, &ys, &it, &[2.5], 100.0, 4095, 1).unwrap();
    let mut g = c.benchmark_group("seeding");
    g.throughput(Throughput::Elements((h * w) as u64));
    g.bench_function("measure_2048x2048_u16", |bch| {
        bch.iter(|| measure(black_box(img.view()), None, 64, 4.0, 0.1, 4095.0).unwrap())
    });
    g.finish();
}

criterion_group!(benches, seeding);
criterion_main!(benches);
