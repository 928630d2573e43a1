//! Correlator throughput (window pairs per second) per window shape, its plane and its peak
//! search apart, and the multipass engine on a 1024 x 1024 synthetic pair. Run: `cargo bench -p piv-core --bench correlator`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use ndarray::Array2;
use piv_core::correlate::find_peak;
use piv_core::{piv, render_particles, Correlator, Mode, Pass, PivSettings, SubPixel};
use rand::{Rng, SeedableRng};
use std::hint::black_box;

fn pair(h: usize, w: usize, u: f64, v: f64) -> (Array2<u16>, Array2<u16>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let n = (0.03 * (h * w) as f64) as usize;
    let xs: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * w as f64).collect();
    let ys: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * h as f64).collect();
    let it = vec![2500.0; n];
    let xa: Vec<f64> = xs.iter().map(|x| x - u / 2.0).collect();
    let ya: Vec<f64> = ys.iter().map(|y| y - v / 2.0).collect();
    let xb: Vec<f64> = xs.iter().map(|x| x + u / 2.0).collect();
    let yb: Vec<f64> = ys.iter().map(|y| y + v / 2.0).collect();
    (
        render_particles(h, w, &xa, &ya, &it, &[2.5], 100.0, 4095, 1).unwrap(),
        render_particles(h, w, &xb, &yb, &it, &[2.5], 100.0, 4095, 2).unwrap(),
    )
}

/// A correlator for `w` x `h` windows holding the windows of `a` and `b` at (10, 10).
fn window_pair(a: &Array2<u16>, b: &Array2<u16>, w: usize, h: usize) -> Correlator {
    let mut cor = Correlator::new(w, h);
    for r in 0..h {
        for c in 0..w {
            cor.wa[r * w + c] = a[[r + 10, c + 10]] as f32;
            cor.wb[r * w + c] = b[[r + 10, c + 10]] as f32;
        }
    }
    cor
}

fn correlator(c: &mut Criterion) {
    let (a, b) = pair(256, 256, 1.3, -0.6);
    // a residual under half a pixel: the peak at lag 0, as after a deformation or a window
    // offset (the uncertainty's own path for lag 0)
    let (a0, b0) = pair(256, 256, 0.3, -0.2);
    let mut g = c.benchmark_group("correlate_window_pair");
    // "+sigma": with the per-vector uncertainty (Correlator::uncertainty), as on the last
    // iteration of a PIV
    let cases = [(128, 32), (64, 64), (32, 32), (32, 8), (16, 16)]
        .into_iter()
        .map(|s| (s, false))
        .chain([((32, 32), true), ((32, 8), true), ((16, 16), true)])
        .map(|c| (c, false))
        .chain([(((32, 32), true), true), (((32, 8), true), true)]);
    for (((w, h), sigma), lag0) in cases {
        g.throughput(Throughput::Elements(1));
        let name = format!(
            "{w}x{h}{}{}",
            if sigma { "+sigma" } else { "" },
            if lag0 { "@lag0" } else { "" }
        );
        let (a, b) = if lag0 { (&a0, &b0) } else { (&a, &b) };
        g.bench_with_input(
            BenchmarkId::from_parameter(name),
            &(w, h),
            |bch, &(w, h)| {
                let mut cor = window_pair(a, b, w, h);
                if sigma {
                    cor.uncertainty = piv_core::Uncertainty::Peak;
                }
                bch.iter(|| black_box(cor.correlate(SubPixel::Gauss3)));
            },
        );
    }
    // the two halves of a correlation: the normalised plane (FFTs, spectrum) and the peak
    // search on it (highest peak, second and third, sub-pixel fits)
    for (w, h) in [(32usize, 8usize), (32, 32), (64, 64)] {
        g.bench_function(format!("{w}x{h}plane"), |bch| {
            let mut cor = window_pair(&a, &b, w, h);
            bch.iter(|| black_box(cor.correlate_plane()));
        });
        g.bench_function(format!("{w}x{h}peak"), |bch| {
            let mut cor = window_pair(&a, &b, w, h);
            cor.correlate_plane();
            let (pl, cw, ch) = cor.plane();
            let pl = pl.to_vec();
            bch.iter(|| black_box(find_peak(&pl, cw, ch, w, h, SubPixel::Gauss3)));
        });
    }
    g.finish();
}

fn multipass(c: &mut Criterion) {
    let (a, b) = pair(1024, 1024, 3.3, -0.6);
    let mut g = c.benchmark_group("piv_1024x1024");
    g.sample_size(10);
    let cases = [
        ("single_32x32", vec![Pass::new(32, 32)], Mode::Deform),
        (
            "multipass_64_32_32x8_deform",
            vec![Pass::new(64, 64), Pass::new(32, 32), Pass::new(32, 8)],
            Mode::Deform,
        ),
        (
            "multipass_64_32_32x8_offset",
            vec![Pass::new(64, 64), Pass::new(32, 32), Pass::new(32, 8)],
            Mode::Offset,
        ),
    ];
    for (name, passes, mode) in cases {
        let s = PivSettings {
            passes,
            mode,
            ..PivSettings::default()
        };
        let n = piv(a.view(), b.view(), None, &s).unwrap().u.len();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function(name, |bch| {
            bch.iter(|| black_box(piv(a.view(), b.view(), None, &s).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, correlator, multipass);
criterion_main!(benches);
