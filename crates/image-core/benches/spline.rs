//! The B-spline prefilter of a 4096 x 2048 frame (a sixth of a 47 MP sensor), cubic and
//! quintic, in place on `f32` and converting from `u16` camera counts, on all threads. Run:
//! `cargo bench -p image-core --bench spline`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use image_core::spline::{prefilter, prefilter_from, SplineOrder};
use std::hint::black_box;

fn spline(c: &mut Criterion) {
    let (w, h) = (4096usize, 2048usize);
    let img: Vec<u16> = (0..w * h)
        .map(|i| ((i.wrapping_mul(2_654_435_761) >> 7) % 4096) as u16)
        .collect();
    let f: Vec<f32> = img.iter().map(|&v| v as f32).collect();
    let mut g = c.benchmark_group("prefilter_4096x2048");
    g.throughput(Throughput::Elements((w * h) as u64));
    g.sample_size(10);
    for (name, order) in [
        ("cubic", SplineOrder::Cubic),
        ("quintic", SplineOrder::Quintic),
    ] {
        let mut buf = f.clone();
        g.bench_function(format!("{name}_in_place"), |b| {
            b.iter(|| {
                buf.copy_from_slice(&f);
                prefilter(black_box(&mut buf), w, h, order);
            })
        });
        g.bench_function(format!("{name}_from_u16"), |b| {
            b.iter(|| black_box(prefilter_from(black_box(&img), w, h, order)))
        });
    }
    g.finish();
}

criterion_group!(benches, spline);
criterion_main!(benches);
