//! Marker detection on the full 47 MP target (8864 x 5288, 13 x 7 dots, paper optics) and the
//! Monte Carlo study (P3 and R2, 91 markers). Run: `cargo bench -p dewarp-core --bench markers`.

use criterion::{criterion_group, criterion_main, Criterion};
use dewarp_core::markers::{detect_markers, DetectOptions};
use dewarp_core::montecarlo::{monte_carlo, MonteCarloConfig};
use dewarp_core::target::{render_target, TargetScene};
use dewarp_core::Model;
use ndarray::{Array1, Array2};
use std::hint::black_box;

/// The paper's grid through an 8 px pincushion at the half diagonal (the Python default lens
/// without its decentring term).
fn paper_grid() -> (Vec<[f64; 2]>, Vec<[f64; 2]>, usize) {
    let (w, h) = (8864.0f64, 5288.0f64);
    let (cx, cy) = (0.5 * (w - 1.0), 0.5 * (h - 1.0));
    let r = 0.5 * w.hypot(h);
    let k1 = 8.0 / r;
    let step = 34.538 * 19.51;
    let (mut obj, mut img, mut centre) = (Vec::new(), Vec::new(), 0);
    for j in -3..=3 {
        for i in -6..=6 {
            if i == 0 && j == 0 {
                centre = obj.len();
            }
            let (x, y) = (cx + step * i as f64, cy + step * j as f64);
            let (u, v) = ((x - cx) / r, (y - cy) / r);
            let f = k1 * (u * u + v * v) * r;
            obj.push([x, y]);
            img.push([x + u * f, y + v * f]);
        }
    }
    (obj, img, centre)
}

fn bench(c: &mut Criterion) {
    let (obj, img, centre) = paper_grid();
    let n = img.len();
    let centres = Array2::from_shape_fn((n, 2), |(k, a)| img[k][a]);
    let sigma = Array1::from_elem(n, 0.5 * 34.538);
    let amp = Array1::from_elem(n, 2500.0);
    let image = render_target(
        5288,
        8864,
        centres.view(),
        sigma.view(),
        amp.view(),
        None,
        &TargetScene::default(),
    )
    .expect("render");
    let mut g = c.benchmark_group("calibration");
    g.sample_size(10);
    g.bench_function("detect_markers_47MP", |b| {
        b.iter(|| {
            black_box(detect_markers(image.view(), &DetectOptions::default()).expect("detect"))
        })
    });
    for (model, nsamp) in [(Model::P3, 20_000usize), (Model::R2, 2_000)] {
        let cfg = MonteCarloConfig {
            model,
            n: nsamp,
            sigma_image_px: 0.057,
            sigma_object_px: 0.38,
            centre_index: centre,
            scale: None,
            seed: 0,
            hist_bins: 0,
            hist_half_range_px: 2.0,
            keep_samples: false,
            threads: None,
        };
        g.bench_function(format!("monte_carlo_{}_{nsamp}", model.name()), |b| {
            b.iter(|| black_box(monte_carlo(&obj, &img, &cfg).expect("mc")))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
