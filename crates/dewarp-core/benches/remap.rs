//! Throughput of the Keys-bicubic remap (Method I dewarp) over a size sweep, with the map
//! evaluated per pixel ("exact") and on the auto-chosen coarse grid (<= 1e-3 px).
//!
//! The map is a paper-like lens: a cubic pincushion reaching ~9 px at the corner of the full
//! 8864 x 5288 sensor, a small decentring term and a 0.04 degree rotation. Output float32, plus
//! uint16 for the full sensor (the issue-5 case). Run with
//! `cargo bench -p dewarp-core --bench remap` (one case: append e.g. `-- u16_to_u16`).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use dewarp_core::remap::{remap, MapSampling, RemapOptions};
use ndarray::Array2;
use std::hint::black_box;

fn lens(h: usize, w: usize) -> impl Fn(f64, f64) -> (f64, f64) + Sync {
    let (cx, cy) = ((w - 1) as f64 / 2.0, (h - 1) as f64 / 2.0);
    let r_corner2 = cx * cx + cy * cy;
    let k = 9.0 / r_corner2.sqrt() / r_corner2; // 9 px at the corner
    let (s, c) = (-0.04f64).to_radians().sin_cos();
    move |x, y| {
        let (dx, dy) = (x - cx, y - cy);
        let r2 = dx * dx + dy * dy;
        let px = dx * (1.0 + k * r2) + 2e-7 * dx * dy;
        let py = dy * (1.0 + k * r2) + 1e-7 * dx * dx;
        (cx + c * px - s * py, cy + s * px + c * py)
    }
}

fn image(h: usize, w: usize) -> Array2<u16> {
    Array2::from_shape_fn((h, w), |(y, x)| ((x * 7919 + y * 104_729) % 4096) as u16)
}

fn bench_remap(c: &mut Criterion) {
    let mut g = c.benchmark_group("remap_keys_u16_to_f32");
    g.sample_size(10);
    for &(h, w) in &[(1024usize, 1024usize), (2048, 4096), (5288, 8864)] {
        let img = image(h, w);
        let map = lens(h, w);
        g.throughput(Throughput::Elements((h * w) as u64));
        for (name, sampling) in [
            ("exact", MapSampling::Exact),
            ("auto_grid", MapSampling::Auto { tol: 1e-3 }),
        ] {
            let opts = RemapOptions {
                sampling,
                ..Default::default()
            };
            g.bench_with_input(
                BenchmarkId::new(name, format!("{w}x{h}")),
                &img,
                |b, img| {
                    b.iter(|| {
                        let out: Array2<f32> = remap(img.view(), &map, &opts).unwrap();
                        black_box(out)
                    })
                },
            );
        }
    }
    g.finish();

    // The issue-5 case: full sensor, auto grid, u16 out (as `benches/bench_dewarp.py`).
    let mut g = c.benchmark_group("remap_keys_u16_to_u16");
    g.sample_size(10);
    let (h, w) = (5288usize, 8864usize);
    let img = image(h, w);
    let map = lens(h, w);
    g.throughput(Throughput::Elements((h * w) as u64));
    let opts = RemapOptions::default();
    g.bench_function(BenchmarkId::new("auto_grid", format!("{w}x{h}")), |b| {
        b.iter(|| {
            let out: Array2<u16> = remap(img.view(), &map, &opts).unwrap();
            black_box(out)
        })
    });
    g.finish();
}

criterion_group!(benches, bench_remap);
criterion_main!(benches);
