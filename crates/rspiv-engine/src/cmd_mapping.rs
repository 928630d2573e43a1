//! `fit-mapping` and `map`: fit a mapping model to point pairs from a CSV file, and apply a
//! saved mapping (forward or inverse) to points from a CSV file.

use crate::csv::{read_columns, write_atomic, write_rows};
use dewarp_core::{fit_mapping, FitOptions, Mapping, Model};
use ndarray::Array2;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `fit-mapping`.
#[derive(clap::Args, Debug)]
pub struct FitMappingArgs {
    /// CSV with columns x_obj,y_obj,x_img,y_img (object px and image px).
    pub points: PathBuf,
    /// Mapping model: r1, r2 or p3.
    #[arg(long, default_value = "p3")]
    pub model: String,
    /// Output JSON file of the mapping.
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Index (data row, from 0) of the central marker; default: nearest the centroid.
    #[arg(long)]
    pub center_index: Option<usize>,
    /// Normalising scale in px; default: max |x_obj|.
    #[arg(long)]
    pub scale: Option<f64>,
}

/// Arguments of `map`.
#[derive(clap::Args, Debug)]
pub struct MapArgs {
    /// Mapping JSON written by fit-mapping (or rspiv's Mapping.save).
    pub mapping: PathBuf,
    /// CSV with columns x,y.
    pub points: PathBuf,
    /// Map image px -> object px instead of object px -> image px.
    #[arg(long)]
    pub inverse: bool,
    /// Output CSV (x,y); default: standard output.
    #[arg(short = 'o', long)]
    pub output: Option<PathBuf>,
}

fn to_array(rows: &[Vec<f64>], c0: usize) -> Array2<f64> {
    let mut a = Array2::zeros((rows.len(), 2));
    for (k, r) in rows.iter().enumerate() {
        a[[k, 0]] = r[c0];
        a[[k, 1]] = r[c0 + 1];
    }
    a
}

/// Run `fit-mapping`.
pub fn run_fit_mapping(args: &FitMappingArgs) -> Result<(), String> {
    let model: Model = args.model.parse().map_err(|e| format!("--model: {e}"))?;
    let rows = read_columns(&args.points, &["x_obj", "y_obj", "x_img", "y_img"])?;
    let (obj, img) = (to_array(&rows, 0), to_array(&rows, 2));
    let opts = FitOptions {
        center_index: args.center_index,
        scale: args.scale,
        ..FitOptions::default()
    };
    let m = fit_mapping(obj.view(), img.view(), model, &opts)
        .map_err(|e| format!("{}: {e}", args.points.display()))?;
    let mut json = m.to_json();
    json.push('\n');
    write_atomic(&args.output, json.as_bytes())?;
    let s = &m.stats;
    println!(
        "{}: {} points, rms ({:.4}, {:.4}) px, max |res| ({:.4}, {:.4}) px -> {}",
        m.model,
        s.n_points,
        s.rms_px[0],
        s.rms_px[1],
        s.max_abs_px[0],
        s.max_abs_px[1],
        args.output.display()
    );
    Ok(())
}

/// Run `map`.
pub fn run_map(args: &MapArgs) -> Result<(), String> {
    let name = args.mapping.display();
    let bytes = std::fs::read(&args.mapping).map_err(|e| format!("{name}: cannot read ({e})"))?;
    let text = String::from_utf8(bytes).map_err(|_| format!("{name}: not a UTF-8 text file"))?;
    let m = Mapping::from_json(&text).map_err(|e| format!("{name}: {e}"))?;
    let rows = read_columns(&args.points, &["x", "y"])?;
    let pts = to_array(&rows, 0);
    let out = if args.inverse {
        let (out, ok) = m.inverse_many(pts.view());
        let bad: Vec<usize> = ok
            .iter()
            .enumerate()
            .filter(|(_, &b)| !b)
            .map(|(i, _)| i)
            .collect();
        if let Some(&first) = bad.first() {
            return Err(format!(
                "{}: inverse map did not converge for {} of {} points (first: data row {first}, ({}, {}))",
                args.points.display(),
                bad.len(),
                ok.len(),
                pts[[first, 0]],
                pts[[first, 1]]
            ));
        }
        out
    } else {
        m.forward_many(pts.view())
    };
    let rows: Vec<[f64; 2]> = out.rows().into_iter().map(|r| [r[0], r[1]]).collect();
    match &args.output {
        Some(path) => {
            let mut buf = Vec::new();
            write_rows(&mut buf, &["x", "y"], &rows).map_err(|e| e.to_string())?;
            write_atomic(path, &buf)
        }
        None => {
            let stdout = std::io::stdout();
            let mut lock = std::io::BufWriter::new(stdout.lock());
            write_rows(&mut lock, &["x", "y"], &rows)
                .and_then(|_| lock.flush())
                .map_err(|e| format!("standard output: {e}"))
        }
    }
}
