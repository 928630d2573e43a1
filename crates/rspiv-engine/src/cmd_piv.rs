//! `piv`: multipass PIV of an image pair; writes a CSV of x,y,u,v,valid,replaced,peak_ratio
//! (pixel frame: x right, y down, origin at the centre of the top-left pixel; px).

use crate::csv::write_atomic;
use crate::imageio::read_u16;
use piv_core::{piv, Mode, Pass, PivSettings, SubPixel};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Arguments of `piv`.
#[derive(clap::Args, Debug)]
pub struct PivArgs {
    /// First frame (TIFF, PNG or BMP).
    pub frame_a: PathBuf,
    /// Second frame.
    pub frame_b: PathBuf,
    /// Output CSV file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Window sizes per pass, WxH (W along x, H along y), comma separated.
    #[arg(long, default_value = "64x64,32x32,32x8")]
    pub passes: String,
    /// Fractional window overlap.
    #[arg(long, default_value_t = 0.5)]
    pub overlap: f64,
    /// How passes follow the predictor: symmetric (image deformation) or offset.
    #[arg(long, default_value = "symmetric")]
    pub deformation: String,
    /// Iterations per pass.
    #[arg(long, default_value_t = 1)]
    pub iterations: usize,
    /// Sub-pixel estimator: gauss3 or gauss2d.
    #[arg(long, default_value = "gauss3")]
    pub subpixel: String,
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

/// Run `piv`.
pub fn run_piv(args: &PivArgs) -> Result<(), String> {
    let windows = parse_passes(&args.passes)?;
    let mode = match args.deformation.as_str() {
        "symmetric" => Mode::Deform,
        "offset" => Mode::Offset,
        o => return Err(format!("--deformation {o:?}: use symmetric or offset")),
    };
    let subpixel = match args.subpixel.as_str() {
        "gauss3" => SubPixel::Gauss3,
        "gauss2d" => SubPixel::Gauss2d,
        o => return Err(format!("--subpixel {o:?}: use gauss3 or gauss2d")),
    };
    let a = read_u16(&args.frame_a)?;
    let b = read_u16(&args.frame_b)?;
    let s = PivSettings {
        passes: windows
            .iter()
            .map(|&(w, h)| Pass {
                w,
                h,
                overlap: args.overlap,
                iterations: args.iterations,
            })
            .collect(),
        mode,
        subpixel,
        ..PivSettings::default()
    };
    let f = piv(a.view(), b.view(), None, &s).map_err(|e| {
        format!(
            "{} / {}: {e}",
            args.frame_a.display(),
            args.frame_b.display()
        )
    })?;
    let mut out = String::with_capacity(f.u.len() * 48);
    out.push_str("x,y,u,v,valid,replaced,peak_ratio\n");
    for k in 0..f.u.len() {
        let (j, i) = (k / f.u.ncols(), k % f.u.ncols());
        let _ = writeln!(
            out,
            "{},{},{:.5},{:.5},{},{},{:.4}",
            f.x[[j, i]],
            f.y[[j, i]],
            f.u[[j, i]],
            f.v[[j, i]],
            u8::from(f.valid[[j, i]]),
            u8::from(f.replaced[[j, i]]),
            f.peak_ratio[[j, i]]
        );
    }
    write_atomic(&args.output, out.as_bytes())?;
    eprintln!(
        "rspiv-engine piv: {} vectors ({} x {}), {} replaced -> {}",
        f.u.len(),
        f.u.ncols(),
        f.u.nrows(),
        f.replaced.iter().filter(|&&r| r).count(),
        args.output.display()
    );
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
}
