//! Particle tracking's kernels on a 2048 x 2048 synthetic pair of 0.03 particles/px: the
//! particle images of one frame with their sub-pixel centres (`piv_core::ptv::detect`, in
//! pixels per second) and the pairing of A's with B's through a uniform predictor
//! (`piv_core::ptv::track`, radius 2 px, in particle images of A per second). Run: `cargo bench
//! -p piv-core --bench ptv`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use piv_core::ptv::{detect, track};
use piv_core::render_particles;
use rand::{Rng, SeedableRng};
use std::hint::black_box;

fn ptv(c: &mut Criterion) {
    let (h, w) = (2048usize, 2048usize);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let n = (0.03 * (h * w) as f64) as usize;
    let xs: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * w as f64).collect();
    let ys: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * h as f64).collect();
    let it: Vec<f64> = (0..n)
        .map(|_| 1500.0 + 1000.0 * rng.random::<f64>())
        .collect();
    let shifted: Vec<f64> = xs.iter().map(|x| x + 4.3).collect();
    let a = render_particles(h, w, &xs, &ys, &it, &[2.5], 100.0, 4095, 1).unwrap();
    let b = render_particles(h, w, &shifted, &ys, &it, &[2.5], 100.0, 4095, 2).unwrap();
    let mut g = c.benchmark_group("ptv");
    g.throughput(Throughput::Elements((h * w) as u64));
    g.bench_function("detect_2048x2048_u16", |bch| {
        bch.iter(|| detect(black_box(a.view()), None, 32, 4.0, 0.2, 4095.0).unwrap())
    });
    let pa = detect(a.view(), None, 32, 4.0, 0.2, 4095.0).unwrap();
    let pb = detect(b.view(), None, 32, 4.0, 0.2, 4095.0).unwrap();
    let (du, dv) = (vec![4.3; pa.len()], vec![0.0; pa.len()]);
    g.throughput(Throughput::Elements(pa.len() as u64));
    g.bench_function("track_radius2", |bch| {
        bch.iter(|| track(&pa.x, &pa.y, &pb.x, &pb.y, black_box(&du), &dv, 2.0).unwrap())
    });
    g.finish();
}

criterion_group!(benches, ptv);
criterion_main!(benches);
