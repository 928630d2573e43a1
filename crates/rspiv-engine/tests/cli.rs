//! The `rspiv-engine` binary as a user runs it: a synthetic pair of known uniform displacement
//! through `piv` (the vectors are the planted shift), and bad input refused in one line with
//! exit status 2 and no output file.
//!
//! Building this test also builds the binary with the workspace's test features, which is the
//! build pytest's `engine` fixture asks for (`tests/conftest.py`): CI builds it once.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const ENGINE: &str = env!("CARGO_BIN_EXE_rspiv-engine");

/// A fresh scratch directory for one test.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rspiv-engine-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(args: &[&str]) -> Output {
    Command::new(ENGINE).args(args).output().unwrap()
}

/// Gaussian particle images (e^-2 diameter 2.8 px) at pseudo-random places, shifted by
/// `(dx, dy)`, as a 16-bit grey PNG of `w x h` px.
fn particle_frame(path: &Path, w: u32, h: u32, dx: f64, dy: f64) {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let n = (w * h) as usize / 40; // 0.025 particles per px
    let parts: Vec<(f64, f64, f64)> = (0..n)
        .map(|_| {
            let x = next() * f64::from(w + 20) - 10.0 + dx;
            let y = next() * f64::from(h + 20) - 10.0 + dy;
            (x, y, 0.5 + 0.5 * next())
        })
        .collect();
    let r2 = (2.8f64 / 4.0).powi(2) * 2.0; // 2 sigma^2, sigma = d / 4
    let mut img = vec![0f64; (w * h) as usize];
    for &(px, py, a) in &parts {
        let (x0, x1) = ((px - 4.0).floor().max(0.0), (px + 4.0).ceil());
        let (y0, y1) = ((py - 4.0).floor().max(0.0), (py + 4.0).ceil());
        for y in (y0 as u32)..(y1.min(f64::from(h)) as u32) {
            for x in (x0 as u32)..(x1.min(f64::from(w)) as u32) {
                let d2 = (f64::from(x) - px).powi(2) + (f64::from(y) - py).powi(2);
                img[(y * w + x) as usize] += a * (-d2 / r2).exp();
            }
        }
    }
    let raw: Vec<u16> = img
        .iter()
        .map(|v| (200.0 + 3000.0 * v).min(65535.0).round() as u16)
        .collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, raw)
        .unwrap()
        .save(path)
        .unwrap();
}

/// The CSV's columns `x`, `y`, `u`, `v` and whether `valid` is 1.
fn vectors(csv: &str) -> Vec<(f64, f64, f64, f64, bool)> {
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |k: &str| head.iter().position(|h| *h == k).unwrap();
    let (ix, iy, iu, iv, ok) = (col("x"), col("y"), col("u"), col("v"), col("valid"));
    let num = |f: &[&str], i: usize| f[i].parse::<f64>().unwrap();
    lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .map(|f| {
            (
                num(&f, ix),
                num(&f, iy),
                num(&f, iu),
                num(&f, iv),
                f[ok] == "1",
            )
        })
        .collect()
}

#[test]
fn piv_of_a_uniform_shift_gives_the_shift() {
    let d = scratch("shift");
    let (a, b, out) = (d.join("a.png"), d.join("b.png"), d.join("v.csv"));
    let (dx, dy) = (3.3, -1.6);
    particle_frame(&a, 256, 192, 0.0, 0.0);
    particle_frame(&b, 256, 192, dx, dy);
    let o = run(&[
        "piv",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--passes",
        "64x64,32x32",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let vecs = vectors(&std::fs::read_to_string(&out).unwrap());
    // 32 px windows every 16 px from 15.5 px: 11 x 15 vectors; the outer ring's windows, moved
    // by half the shift each way, reach past the frame and are replaced from their neighbours
    assert_eq!(vecs.len(), 11 * 15);
    for &(x, y, u, v, ok) in &vecs {
        let inner = x > 16.0 && x < 239.0 && y > 16.0 && y < 175.0;
        assert_eq!(ok, inner, "valid at ({x}, {y})");
        assert!(
            (u - dx).abs() < 0.05 && (v - dy).abs() < 0.05,
            "({x}, {y}): ({u}, {v})"
        );
    }
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_missing_frame_is_one_line_and_exit_two_with_no_output() {
    let d = scratch("missing");
    let out = d.join("v.csv");
    let missing = d.join("nowhere_a.tif");
    let o = run(&[
        "piv",
        missing.to_str().unwrap(),
        missing.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.starts_with("rspiv-engine: error: ") && err.contains("nowhere_a.tif"),
        "{err}"
    );
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(&d).unwrap().count(),
        0,
        "no temporary file left"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn bad_passes_are_refused_before_any_frame_is_read() {
    let d = scratch("passes");
    let out = d.join("v.csv");
    let o = run(&[
        "piv",
        "a.tif",
        "b.tif",
        "-o",
        out.to_str().unwrap(),
        "--passes",
        "64y64",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--passes") && err.contains("64y64"), "{err}");
    assert!(!out.exists());
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn info_names_the_version() {
    let o = run(&["info"]);
    assert!(o.status.success());
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.starts_with(&format!("rspiv-engine {}", env!("CARGO_PKG_VERSION"))),
        "{s}"
    );
}
