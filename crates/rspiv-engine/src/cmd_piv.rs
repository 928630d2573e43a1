//! `piv`: multipass PIV of an image pair, plain or distortion-corrected (Method I or II through
//! a calibration); writes a CSV of x,y,u,v,valid,replaced,masked,peak_ratio,coef,peak_choice,sigma_u,sigma_v
//! (sigma: the per-vector standard uncertainty in px, NaN where not valid).
//!
//! Settings: `--settings FILE.json` holds the keys of the one vocabulary (`rspiv.PivSettings`,
//! `piv_core::PivSettings::from_json`: passes, overlap, iterations, deformation, interpolation,
//! subpixel, weighting, validate, median_eps, median_threshold, min_peak_ratio, peak_candidates, uncertainty); the flags given on the
//! command line override the file. Pixel frame: x right, y down, origin at the centre of the
//! top-left pixel; px (object px with a calibration). Values are written to full precision
//! (shortest round-trip decimal), NaN where a vector is masked.

use crate::cmd_dewarp::load_mapping;
use crate::csv::write_atomic;
use crate::imageio::read_u16;
use correction_core::{method_one, method_two, DisplacementMapping, Method, ZeroFill};
use ndarray::Array2;
use piv_core::{piv, Interpolation, Mode, Pass, PivField, PivSettings, Roi, SubPixel, Weighting};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `piv`.
#[derive(clap::Args, Debug)]
pub struct PivArgs {
    /// First frame (TIFF, PNG, BMP or JPEG).
    pub frame_a: PathBuf,
    /// Second frame.
    pub frame_b: PathBuf,
    /// Output CSV file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// PIV settings JSON (the keys of rspiv.PivSettings); flags override its values.
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Window sizes per pass, WxH (W along x, H along y), comma separated [default 64x64,32x32,32x8].
    #[arg(long)]
    pub passes: Option<String>,
    /// Fractional window overlap (every pass) [default 0.5].
    #[arg(long)]
    pub overlap: Option<f64>,
    /// How passes follow the predictor: symmetric (image deformation) or offset [default symmetric].
    #[arg(long)]
    pub deformation: Option<String>,
    /// Iterations per pass [default 1].
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Interpolation of deformed windows: bspline (quintic), bspline3 or keys [default bspline].
    #[arg(long)]
    pub interpolation: Option<String>,
    /// Sub-pixel estimator: gauss3 or gauss2d [default gauss3].
    #[arg(long)]
    pub subpixel: Option<String>,
    /// Weighting window of the interrogation windows: tophat, gaussian or blackman [default
    /// tophat].
    #[arg(long)]
    pub weighting: Option<String>,
    /// Correlation peaks tried per vector before interpolating a rejected one: 1, 2 or 3
    /// [default 3].
    #[arg(long)]
    pub peak_candidates: Option<usize>,
    /// Calibration JSON (rspiv calibrate) or mapping JSON: correct the distortion.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Correction method with --calibration: I (dewarp the frames, then PIV) or II (PIV on the
    /// raw frames, vectors mapped back) [default II].
    #[arg(long)]
    pub method: Option<String>,
    /// Method II's displacement mapping: full (exact inverse) or positions [default full].
    #[arg(long)]
    pub mapping: Option<String>,
    /// Mask image of the frames' size (TIFF, PNG, BMP), non-zero = excluded: vectors whose
    /// centre falls on it are masked (NaN). Polygon masks (JSON) are read by `rspiv piv`.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Region of interest X0,Y0,X1,Y1 (px, x0 <= x < x1, y0 <= y < y1; object px with
    /// --calibration): the whole frame's grid cut to it, only it and a margin read.
    #[arg(long)]
    pub roi: Option<String>,
}

/// `X0,Y0,X1,Y1` as a region of interest.
pub fn parse_roi(s: &str) -> Result<Roi, String> {
    let v: Vec<usize> = s
        .split(',')
        .map(|t| t.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--roi {s:?}: give X0,Y0,X1,Y1 in px (integers >= 0)"))?;
    let a: [usize; 4] = v
        .try_into()
        .map_err(|_| format!("--roi {s:?}: give X0,Y0,X1,Y1 in px (four integers)"))?;
    Ok(Roi::from(a))
}

/// The mask image `path` (non-zero = excluded) of frames of `shape` (rows, columns), as
/// `rspiv.io.read_mask` reads an image; a JSON polygon mask or an image of another size is
/// refused in one line naming the file.
fn read_mask(path: &Path, shape: (usize, usize)) -> Result<Array2<bool>, String> {
    let json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if json {
        return Err(format!(
            "{}: polygon masks (JSON) are read by `rspiv piv`; give rspiv-engine an image \
             (non-zero = excluded)",
            path.display()
        ));
    }
    let m = read_u16(path)?;
    if m.dim() != shape {
        return Err(format!(
            "{}: mask is {} x {} px, the frames are {} x {} px",
            path.display(),
            m.ncols(),
            m.nrows(),
            shape.1,
            shape.0
        ));
    }
    Ok(m.mapv(|v| v > 0))
}

/// Parse "64x64,32x32,32x8" into (w, h) pairs.
pub fn parse_passes(s: &str) -> Result<Vec<(usize, usize)>, String> {
    s.split(',')
        .map(|p| {
            let (w, h) = p
                .trim()
                .split_once(['x', 'X'])
                .ok_or_else(|| format!("--passes: {p:?} is not WxH"))?;
            let w = w
                .trim()
                .parse()
                .map_err(|_| format!("--passes: bad width in {p:?}"))?;
            let h = h
                .trim()
                .parse()
                .map_err(|_| format!("--passes: bad height in {p:?}"))?;
            Ok((w, h))
        })
        .collect()
}

/// The settings of the run: the file's (or the defaults), then the flags given.
pub fn settings_of(args: &PivArgs) -> Result<PivSettings, String> {
    let mut s = match &args.settings {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
            PivSettings::from_json(&text).map_err(|e| format!("{}: {e}", path.display()))?
        }
        None => PivSettings::default(),
    };
    if let Some(p) = &args.passes {
        let (overlap, iterations) = s
            .passes
            .first()
            .map_or((0.5, 1), |p| (p.overlap, p.iterations));
        s.passes = parse_passes(p)?
            .into_iter()
            .map(|(w, h)| Pass {
                w,
                h,
                overlap,
                iterations,
            })
            .collect();
    }
    for p in &mut s.passes {
        if let Some(o) = args.overlap {
            p.overlap = o;
        }
        if let Some(i) = args.iterations {
            p.iterations = i;
        }
    }
    // the vocabulary's message ("deformation \"warp\": use ...") with the flag's dashes
    let flag = |e: piv_core::PivError| match e {
        piv_core::PivError::InvalidInput(m) => format!("--{m}"),
    };
    if let Some(d) = &args.deformation {
        s.mode = d.parse::<Mode>().map_err(flag)?;
    }
    if let Some(i) = &args.interpolation {
        s.interpolation = i.parse::<Interpolation>().map_err(flag)?;
    }
    if let Some(p) = &args.subpixel {
        s.subpixel = p.parse::<SubPixel>().map_err(flag)?;
    }
    if let Some(p) = &args.weighting {
        s.weighting = p.parse::<Weighting>().map_err(flag)?;
    }
    if let Some(n) = args.peak_candidates {
        s.peak_candidates = n;
    }
    if let Some(r) = &args.roi {
        s.roi = Some(parse_roi(r)?);
    }
    s.validate().map_err(|e| format!("settings: {e}"))?;
    Ok(s)
}

/// The calibration's image shape (rows, columns), when the JSON holds one.
fn image_shape(path: &Path) -> Option<(usize, usize)> {
    let text = std::fs::read_to_string(path).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    let s = v.get("image_shape")?.as_array()?;
    Some((s.first()?.as_u64()? as usize, s.get(1)?.as_u64()? as usize))
}

/// The CSV of a field: one row per vector, row-major over the grid.
fn field_csv(f: &PivField) -> String {
    let mut out = String::with_capacity(f.u.len() * 96);
    out.push_str("x,y,u,v,valid,replaced,masked,peak_ratio,coef,peak_choice,sigma_u,sigma_v\n");
    for ((j, i), &u) in f.u.indexed_iter() {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            f.x[[j, i]],
            f.y[[j, i]],
            u,
            f.v[[j, i]],
            u8::from(f.valid[[j, i]]),
            u8::from(f.replaced[[j, i]]),
            u8::from(f.masked[[j, i]]),
            f.peak_ratio[[j, i]],
            f.coef[[j, i]],
            f.peak_choice[[j, i]],
            f.sigma_u[[j, i]],
            f.sigma_v[[j, i]]
        );
    }
    out
}

/// Run `piv`.
pub fn run_piv(args: &PivArgs) -> Result<(), String> {
    let s = settings_of(args)?;
    let method: Method = match (&args.calibration, &args.method) {
        (None, None) => Method::None,
        (None, Some(_)) => return Err("--method needs --calibration".into()),
        (Some(_), None) => Method::Two,
        (Some(_), Some(m)) => m.parse().map_err(|e| format!("--method: {e}"))?,
    };
    let mode: DisplacementMapping = match &args.mapping {
        Some(m) => m.parse().map_err(|e| format!("--mapping: {e}"))?,
        None => DisplacementMapping::Full,
    };
    let a = read_u16(&args.frame_a)?;
    let b = read_u16(&args.frame_b)?;
    let pair = format!("{} / {}", args.frame_a.display(), args.frame_b.display());
    let mask = args
        .mask
        .as_deref()
        .map(|m| read_mask(m, a.dim()))
        .transpose()?;
    let mask = mask.as_ref().map(|m| m.view());
    let f = match (&args.calibration, method) {
        (Some(cal), Method::One | Method::Two) => {
            let mapping = load_mapping(cal)?;
            if let Some(shape) = image_shape(cal) {
                if shape != a.dim() {
                    return Err(format!(
                        "{}: the calibration is for {} x {} px images, the frames are {} x {} \
                         (rows x columns)",
                        cal.display(),
                        shape.0,
                        shape.1,
                        a.nrows(),
                        a.ncols()
                    ));
                }
            }
            let r = if method == Method::One {
                method_one(a.view(), b.view(), &mapping, &s, None, mask, ZeroFill::Mask)
            } else {
                method_two(a.view(), b.view(), &mapping, &s, mode, None, mask)
            };
            r.map_err(|e| format!("{pair}: {e}"))?
        }
        _ => piv(a.view(), b.view(), mask, &s).map_err(|e| format!("{pair}: {e}"))?,
    };
    write_atomic(&args.output, field_csv(&f).as_bytes())?;
    let (_, second, third, interpolated) = f.peak_counts();
    eprintln!(
        "rspiv-engine piv: {} vectors ({} x {}), {second} from the second peak, {third} from \
         the third, {interpolated} interpolated, {} masked, particle images {:.1} x {:.1} px, \
         method {method} -> {}",
        f.u.len(),
        f.u.ncols(),
        f.u.nrows(),
        f.masked.iter().filter(|&&r| r).count(),
        f.particle_diameter.0,
        f.particle_diameter.1,
        args.output.display()
    );
    let check = piv_core::validate::correlation_check(
        f.peak_ratio.view(),
        f.valid.view(),
        Some(f.masked.view()),
        true,
    );
    if let Some(w) = check.message() {
        eprintln!("rspiv-engine piv: warning: {pair}: {w}");
    }
    if let Some(w) = piv_core::particle_size::peak_locking_warning(f.particle_diameter) {
        eprintln!("rspiv-engine piv: warning: {pair}: {w}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_parse() {
        assert_eq!(
            parse_passes("64x64, 32x8").unwrap(),
            vec![(64, 64), (32, 8)]
        );
        assert!(parse_passes("64").is_err());
        assert!(parse_passes("64xa").is_err());
    }

    #[test]
    fn roi_parses() {
        assert_eq!(
            parse_roi("0, 3000,8864,5288").unwrap(),
            Roi::from([0, 3000, 8864, 5288])
        );
        assert!(parse_roi("0,3000,8864")
            .unwrap_err()
            .contains("four integers"));
        assert!(parse_roi("0,-1,5,5").unwrap_err().contains("integers >= 0"));
    }
}
