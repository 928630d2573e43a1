//! `calibrate`: detect and index the markers of a target image, fit the mapping and write a
//! calibration JSON file in the format of Python's `rspiv.Calibration.save` (so that either
//! side reads the other's file). The object sigma is taken from `--pitch-sigma-mm` or, as in
//! Python, estimated from the fit residuals beyond the image noise.

use crate::csv::write_atomic;
use dewarp_core::grid::index_grid;
use dewarp_core::markers::{
    detect_markers, touching_share, DetectOptions, MarkerKind, TOUCH_SHARE,
};
use dewarp_core::{fit_mapping, FitOptions, Mapping, Model};
use ndarray::{Array2, ArrayView2};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// Arguments of `calibrate`.
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Target image (TIFF, PNG, BMP or JPEG; grey).
    pub target: PathBuf,
    /// Marker pitch (mm).
    #[arg(long)]
    pub pitch_mm: f64,
    /// Pitch uncertainty (mm); default: estimated from the fit residuals.
    #[arg(long)]
    pub pitch_sigma_mm: Option<f64>,
    /// Mapping model: auto, r1, r2 or p3 (auto: smallest held-out error).
    #[arg(long, default_value = "p3")]
    pub model: String,
    /// Marker shape: dot or cross.
    #[arg(long, default_value = "dot")]
    pub marker: String,
    /// Marker size (Gaussian sigma, px); default: estimated.
    #[arg(long)]
    pub marker_size_px: Option<f64>,
    /// Output calibration JSON.
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Keep a fit whose residual RMS exceeds max(10 x the markers' image sigma, 0.5 px).
    #[arg(long)]
    pub accept_poor_fit: bool,
}

fn read_grey(path: &Path) -> Result<Array2<u16>, String> {
    let name = path.display();
    let img = image::ImageReader::open(path)
        .map_err(|e| format!("{name}: cannot open ({e})"))?
        .with_guessed_format()
        .map_err(|e| format!("{name}: cannot read ({e})"))?
        .decode()
        .map_err(|e| format!("{name}: cannot decode the image ({e})"))?;
    let g = img.into_luma16();
    let (w, h) = (g.width() as usize, g.height() as usize);
    Array2::from_shape_vec((h, w), g.into_raw()).map_err(|e| format!("{name}: {e}"))
}

fn stats_json(m: &Mapping, loo: f64) -> Value {
    json!({
        "max_abs_px": m.stats.max_abs_px,
        "mean_px": m.stats.mean_px,
        "rms_px": m.stats.rms_px,
        "loo_rms_px": if loo.is_finite() { json!(loo) } else { Value::Null },
    })
}

fn fit(
    obj: &Array2<f64>,
    img: &Array2<f64>,
    model: Model,
    c: usize,
    s: f64,
) -> Result<Mapping, String> {
    let opts = FitOptions {
        center_index: Some(c),
        scale: Some(s),
        ..FitOptions::default()
    };
    fit_mapping(obj.view(), img.view(), model, &opts).map_err(|e| e.to_string())
}

fn loo_rms(
    obj: &Array2<f64>,
    img: &Array2<f64>,
    model: Model,
    c: usize,
    s: f64,
) -> Result<f64, String> {
    let n = obj.nrows();
    let mut acc = 0.0;
    for k in (0..n).filter(|&k| k != c) {
        let keep: Vec<usize> = (0..n).filter(|&q| q != k).collect();
        let o = obj.select(ndarray::Axis(0), &keep);
        let i = img.select(ndarray::Axis(0), &keep);
        let m = fit(&o, &i, model, if k < c { c - 1 } else { c }, s)?;
        let (fx, fy) = m.forward(obj[[k, 0]], obj[[k, 1]]);
        acc += (fx - img[[k, 0]]).powi(2) + (fy - img[[k, 1]]).powi(2);
    }
    Ok((acc / (n - 1) as f64).sqrt())
}

/// Run `calibrate`.
pub fn run_calibrate(args: &CalibrateArgs) -> Result<(), String> {
    let name = args.target.display().to_string();
    if !(args.pitch_mm.is_finite() && args.pitch_mm > 0.0) {
        return Err(format!("--pitch-mm {} must be > 0", args.pitch_mm));
    }
    if let Some(p) = args.pitch_sigma_mm {
        if !(p.is_finite() && p >= 0.0) {
            return Err(format!("--pitch-sigma-mm {p} must be >= 0"));
        }
    }
    let auto = args.model.eq_ignore_ascii_case("auto");
    let model: Option<Model> = if auto {
        None
    } else {
        Some(args.model.parse().map_err(|e| format!("--model: {e}"))?)
    };
    let kind: MarkerKind = args.marker.parse().map_err(|e| format!("--marker: {e}"))?;
    if let Some(dir) = args.output.parent() {
        if !dir.as_os_str().is_empty() && !dir.is_dir() {
            return Err(format!(
                "{}: directory {} does not exist",
                args.output.display(),
                dir.display()
            ));
        }
    }
    let image = read_grey(&args.target)?;
    let (h, w) = image.dim();
    let view: ArrayView2<u16> = image.view();
    let opts = DetectOptions {
        kind,
        size_px: args.marker_size_px,
        ..DetectOptions::default()
    };
    let det = detect_markers(view, &opts).map_err(|e| format!("{name}: {e}"))?;
    let pts: Vec<[f64; 2]> = det.markers.iter().map(|m| [m.x, m.y]).collect();
    let centre_px = [0.5 * (w as f64 - 1.0), 0.5 * (h as f64 - 1.0)];
    let g = index_grid(&pts, centre_px, 0.3).map_err(|e| format!("{name}: {e}"))?;
    // A checkerboard's squares index as dots along their diagonals, where they touch: the
    // lattice's pitch is then not the side given (`dewarp_core::markers::touching_share`).
    if kind == MarkerKind::Dot {
        let amp: Vec<f64> = det.markers.iter().map(|m| m.amplitude).collect();
        if let Some((share, _)) = touching_share(view, &pts, &g.index, &amp, det.dark) {
            if share > TOUCH_SHARE {
                return Err(format!(
                    "{name}: calibration refused: the markers touch their lattice neighbours \
                     ({:.0} % of the segment between adjacent markers is as dark as the \
                     markers, where a dot target leaves a gap of background): the squares of a \
                     checkerboard, indexed along their diagonals, whose pitch is not the \
                     squares' side? rspiv calibrates dot and disc targets",
                    100.0 * share
                ));
            }
        }
    }
    // A lattice at 45 degrees may be the union of a two-level plate's levels: the engine
    // calibrates single-level plates only (the Python `rspiv calibrate` splits the levels).
    let angle = g.a1[1].atan2(g.a1[0]).to_degrees();
    if ((angle.abs() % 90.0) - 45.0).abs() < 10.0 {
        return Err(format!(
            "{name}: the marker lattice runs at {angle:+.1} deg: a two-level plate (two \
             staggered lattices) or a plate turned 45 degrees; rspiv-engine calibrates \
             axis-aligned single-level plates: use `rspiv calibrate` (levels, fiducials)"
        ));
    }
    let keep: Vec<usize> = (0..pts.len()).filter(|&k| g.index[k].is_some()).collect();
    let n = keep.len();
    let centre = keep
        .iter()
        .position(|&k| k == g.origin)
        .ok_or("grid origin lost")?;
    let idx: Vec<(i32, i32)> = keep.iter().map(|&k| g.index[k].unwrap_or((0, 0))).collect();
    let pc = pts[g.origin];
    let mut dists = Vec::new();
    for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
        if let Some(q) = idx.iter().position(|&v| v == (di, dj)) {
            let p = pts[keep[q]];
            dists.push((p[0] - pc[0]).hypot(p[1] - pc[1]));
        }
    }
    if dists.len() < 2 {
        return Err(format!(
            "{name}: the central marker has fewer than 2 neighbours"
        ));
    }
    let mean_d = dists.iter().sum::<f64>() / dists.len() as f64;
    let sd =
        (dists.iter().map(|d| (d - mean_d).powi(2)).sum::<f64>() / (dists.len() - 1) as f64).sqrt();
    let mag = mean_d / args.pitch_mm;
    let step = mag * args.pitch_mm;
    let img = Array2::from_shape_fn((n, 2), |(k, a)| pts[keep[k]][a]);
    let obj = Array2::from_shape_fn((n, 2), |(k, a)| {
        pc[a]
            + step
                * if a == 0 {
                    idx[k].0 as f64
                } else {
                    idx[k].1 as f64
                }
    });
    let scale = obj.column(0).iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mut models = serde_json::Map::new();
    let mut best: Option<(f64, Model)> = None;
    for m in [Model::R1, Model::R2, Model::P3] {
        if n < m.min_points() {
            continue;
        }
        let Ok(f) = fit(&obj, &img, m, centre, scale) else {
            continue;
        };
        let loo = loo_rms(&obj, &img, m, centre, scale).unwrap_or(f64::NAN);
        if loo.is_finite() && best.is_none_or(|(b, _)| loo < b) {
            best = Some((loo, m));
        }
        models.insert(m.name().to_string(), stats_json(&f, loo));
    }
    let (chosen, reason) = match model {
        Some(m) => {
            if n < m.min_points() {
                return Err(format!(
                    "{name}: model {} needs at least {} markers, {n} were indexed",
                    m.name(),
                    m.min_points()
                ));
            }
            (m, "chosen by the user".to_string())
        }
        None => {
            let (loo, m) = best.ok_or(format!("{name}: no model can be fitted to {n} markers"))?;
            (
                m,
                format!("smallest held-out error: {} {loo:.4} px", m.name()),
            )
        }
    };
    let mapping = fit(&obj, &img, chosen, centre, scale).map_err(|e| format!("{name}: {e}"))?;
    let cov: Vec<[[f64; 2]; 2]> = keep
        .iter()
        .map(|&k| {
            let m = &det.markers[k];
            [
                [m.sigma_x * m.sigma_x, m.cov_xy],
                [m.cov_xy, m.sigma_y * m.sigma_y],
            ]
        })
        .collect();
    let img_var = keep
        .iter()
        .map(|&k| 0.5 * (det.markers[k].sigma_x.powi(2) + det.markers[k].sigma_y.powi(2)))
        .sum::<f64>()
        / n as f64;
    let (osig, source, psig) = match args.pitch_sigma_mm {
        Some(p) => (p * mag, "pitch_sigma_mm * M".to_string(), p),
        None => {
            let r2 = mapping
                .residuals
                .iter()
                .map(|r| 0.5 * (r[0] * r[0] + r[1] * r[1]))
                .sum::<f64>()
                / n as f64;
            let dof = (1.0 - chosen.n_params() as f64 / (2.0 * n as f64)).max(1e-9);
            let o = (r2 / dof - img_var).max(0.0).sqrt();
            (
                o,
                format!("{} residuals beyond the image noise", chosen.name()),
                o / mag,
            )
        }
    };
    // Never write a fit far above the markers' noise (as `rspiv calibrate` does).
    let res_rms = (mapping
        .residuals
        .iter()
        .map(|r| 0.5 * (r[0] * r[0] + r[1] * r[1]))
        .sum::<f64>()
        / n as f64)
        .sqrt();
    let limit = (10.0 * img_var.sqrt()).max(0.5);
    if res_rms > limit && !args.accept_poor_fit {
        return Err(format!(
            "{name}: calibration refused: {} leaves {res_rms:.3} px RMS residuals against a \
             marker sigma of {:.4} px over {n} indexed markers (lattice pitch {step:.1} px): not \
             a flat target this model can follow; --accept-poor-fit keeps it",
            chosen.name(),
            img_var.sqrt()
        ));
    }
    let mapping_json: Value =
        serde_json::from_str(&mapping.to_json()).map_err(|e| e.to_string())?;
    let doc = json!({
        "format": "rspiv-calibration",
        "version": 1,
        "image_shape": [h, w],
        "pitch_mm": args.pitch_mm,
        "pitch_sigma_mm": psig,
        "magnification": mag,
        "magnification_sigma": sd / args.pitch_mm,
        "object_sigma_px": osig,
        "object_sigma_source": source,
        "marker": args.marker.to_ascii_lowercase(),
        "size_px": det.size_px,
        "n_detected": pts.len(),
        "model": chosen.name(),
        "model_reason": reason,
        "models": models,
        "markers": {
            "image_px": img.rows().into_iter().map(|r| [r[0], r[1]]).collect::<Vec<_>>(),
            "object_px": obj.rows().into_iter().map(|r| [r[0], r[1]]).collect::<Vec<_>>(),
            "cov_px2": cov,
            "index": idx.iter().map(|v| [v.0, v.1]).collect::<Vec<_>>(),
            "centre": centre,
        },
        "mapping": mapping_json,
    });
    let mut text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
    text.push('\n');
    write_atomic(&args.output, text.as_bytes())?;
    let s = &mapping.stats;
    println!(
        "{name}: {w} x {h} px, {n} markers indexed of {} detected, M = {mag:.4} px/mm, \
         image sigma {:.4} px, object sigma {osig:.4} px",
        pts.len(),
        img_var.sqrt()
    );
    for (k, v) in &models {
        println!(
            "  {k}: rms ({:.4}, {:.4}) px, held-out rms {} px",
            v["rms_px"][0], v["rms_px"][1], v["loo_rms_px"]
        );
    }
    println!(
        "model {} ({reason}): max |res| ({:.4}, {:.4}) px -> {}",
        chosen.name(),
        s.max_abs_px[0],
        s.max_abs_px[1],
        args.output.display()
    );
    Ok(())
}
