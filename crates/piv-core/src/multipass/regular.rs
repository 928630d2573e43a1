//! Multipass PIV on the regular grid ([`piv`]).

use super::field::*;
use super::frames::*;
use super::roi::{margin as roi_margin, Roi, RINGS};
use super::settings::*;
use super::window::*;
use crate::correlate::Uncertainty;
use crate::error::{PivError, Result};
use crate::grid::Grid;
use crate::image::{GridField, Pixel};
use crate::particle_size::particle_diameter;
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

/// Multipass PIV of a frame pair on the regular grid of the last pass.
///
/// `mask` (same shape as the frames, `true` = excluded) removes the vectors whose centre falls
/// on a masked pixel. With [`PivSettings::roi`] the grids are the whole frames' cut to the
/// region and only the region and a margin around it are read (`roi.rs`); `x`, `y` and `grid` stay in the
/// frames' px. Errors: frames of different shapes, NaN/inf pixels, windows larger than the
/// image (or the region), a region beyond the frames, bad settings.
pub fn piv<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
) -> Result<PivField> {
    s.validate()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    check_mask(&mask, dim)?;
    if let Some(roi) = s.roi {
        roi.check(dim, s)?;
        let crop = roi.grown(roi_margin(s), dim);
        let (ca, cb) = (crop.view(&frame_a), crop.view(&frame_b));
        let cmask = mask.as_ref().map(|m| crop.view(m));
        return piv_cropped(ca, cb, cmask, s, dim, crop, Some((frame_a, frame_b)));
    }
    let grids = grids_of(s, dim)?;
    let frames = Frames::new(frame_a, frame_b, s.interpolation)?;
    grid_passes(&frames, dim, &mask, s, grids)
}

/// [`piv`] in the region `s.roi` (px of frames of shape `dim`, checked) of the crop `crop` of
/// those frames (`frame_a`, `frame_b` and `mask` are the crop; it holds the region and a
/// margin): the grids are the whole frames' cut to the region (`roi.rs`); the field in the
/// frames' px. `whole`: the frames the crop was cut from, whose blank-window rule (their
/// variance and clean background) the crop then follows; `None`, the crop's own (Method I's
/// dewarped region). Every pass runs on [`RINGS`] more rings of the frames' grid points around the
/// region where the frames have them (windows reaching past the crop are not correlated and
/// only interpolated, as at a frame's edge); the field returned is cut to the region.
pub fn piv_cropped<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
    dim: (usize, usize),
    crop: Roi,
    whole: Option<(ArrayView2<'_, T>, ArrayView2<'_, T>)>,
) -> Result<PivField> {
    let roi = s
        .roi
        .ok_or_else(|| PivError::InvalidInput("piv_cropped needs a roi".into()))?;
    let rings = s
        .passes
        .iter()
        .map(|p| roi.grid_ring(p.w, p.h, p.overlap, dim, (crop.x0, crop.y0), RINGS))
        .collect::<Result<Vec<_>>>()?;
    let last = *rings.last().expect("checked: non-empty");
    let grids = rings.into_iter().map(|r| r.grid).collect();
    let frames = Frames::cut_from(frame_a, frame_b, s.interpolation, whole)?;
    let f = grid_passes(&frames, frame_a.dim(), &mask, s, grids)?;
    Ok(f.cut(last.at, last.inner)
        .moved(crop.x0 as f64, crop.y0 as f64))
}

/// The grids of the passes of `s` on frames of shape `dim` (rows, columns).
pub(crate) fn grids_of(s: &PivSettings, dim: (usize, usize)) -> Result<Vec<Grid>> {
    s.passes
        .iter()
        .map(|p| Grid::for_windows(dim.1, dim.0, p.w, p.h, p.overlap))
        .collect()
}

/// The passes of [`piv`] on prepared frames (inputs checked, `grids` from [`grids_of`]).
pub(crate) fn grid_passes<T: Pixel>(
    frames: &Frames<'_, T>,
    dim: (usize, usize),
    mask: &Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
    grids: Vec<Grid>,
) -> Result<PivField> {
    let mut pred: Option<GridField> = None;
    let mut last = None;
    let mut spare = None;
    // measured on the first correlation: windows cut from the frames as recorded
    let mut diameter = None;
    for (pass, grid) in s.passes.iter().zip(grids) {
        let n = grid.len();
        let mut xs = Vec::with_capacity(n);
        let mut ys = Vec::with_capacity(n);
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = grid.xy(j, i);
                xs.push(x);
                ys.push(y);
            }
        }
        let skip: Vec<bool> = xs
            .iter()
            .zip(&ys)
            .map(|(&x, &y)| excluded(mask, dim, x, y))
            .collect();
        let last_pass = std::ptr::eq(pass, s.passes.last().expect("non-empty"));
        let mean = WindowMean::new(pass.w, pass.h, s.weighting);
        for it in 0..pass.iterations {
            // the uncertainty of the vectors returned
            let unc = if s.uncertainty && last_pass && it + 1 == pass.iterations {
                Uncertainty::Peak
            } else {
                Uncertainty::Off
            };
            // the deformation predictor: the latest field averaged over this pass's window
            // (see the module notes)
            let cur = match (&pred, s.mode) {
                (Some(f), Mode::Deform) => Some(f.window_average(pass.w, pass.h)),
                (p, _) => p.clone(),
            };
            // predictor at the centres: for deformation the window mean of the deformation
            // field (the residual a deformed window measures is the window mean of
            // `true - deformation`, see the module notes); the centres in parallel (each
            // independent; 730,513 window means for a 47 MP pair's last pass)
            let centres = || xs.par_iter().zip(ys.par_iter());
            let (pu, pv): (Vec<f64>, Vec<f64>) = match (&cur, s.mode) {
                (Some(f), Mode::Deform) => centres().map(|(&x, &y)| mean.at(f, x, y)).unzip(),
                (Some(f), _) => centres().map(|(&x, &y)| f.at(x, y)).unzip(),
                (None, _) => (vec![0.0; n], vec![0.0; n]),
            };
            let zeros = vec![0.0; n];
            let (du, dv, base) = match s.mode {
                Mode::Deform => (&zeros, &zeros, cur.as_ref()),
                Mode::Offset => (&pu, &pv, None),
            };
            // grid windows sit on integer positions: deform the whole pair once, then the
            // windows are plain copies (the deformed pair's buffers serve the next one)
            let deformed = base.map(|f| frames.deformed(f, spare.take()));
            let sweep = |xs: &[f64], ys: &[f64], du: &[f64], dv: &[f64], skip: &[bool], u| {
                let sub = (s.subpixel, s.weighting);
                match &deformed {
                    Some(d) => d.sweep(pass.w, pass.h, xs, ys, du, dv, skip, None, sub, u),
                    None => frames.sweep(pass.w, pass.h, xs, ys, du, dv, skip, None, sub, u),
                }
            };
            let mut peaks = sweep(&xs, &ys, du, dv, &skip, unc);
            let first = *diameter.get_or_insert_with(|| particle_diameter(&peaks));
            let mut u = par_grid((grid.ny, grid.nx), |j, i| {
                let k = j * grid.nx + i;
                pu[k] + peaks[k].dx
            });
            let mut v = par_grid((grid.ny, grid.nx), |j, i| {
                let k = j * grid.nx + i;
                pv[k] + peaks[k].dy
            });
            let checked = validate_replace(&mut u, &mut v, &peaks, &skip, s);
            if let (true, Some(prev)) = (it > 0, &pred) {
                // an extra iteration on this pass's grid (see `RELAXATION`)
                relax(&mut u, &prev.u);
                relax(&mut v, &prev.v);
            }
            if unc != Uncertainty::Off {
                fill_alt_sigmas(
                    &mut peaks,
                    &checked,
                    (&xs, &ys, du, dv),
                    |x, y, u, v, skip| sweep(x, y, u, v, skip, Uncertainty::AllPeaks),
                );
            }
            if let Some(d) = deformed {
                spare = d.into_buffers();
            }
            pred = Some(GridField {
                grid,
                u: u.clone(),
                v: v.clone(),
            });
            last = Some((u, v, peaks, checked, first));
        }
        if let Some((u, v, peaks, checked, first)) = last.take() {
            if last_pass {
                let x = Array2::from_shape_vec((grid.ny, grid.nx), xs).expect("shape");
                let y = Array2::from_shape_vec((grid.ny, grid.nx), ys).expect("shape");
                return Ok(finish(
                    Some(grid),
                    x,
                    y,
                    u,
                    v,
                    &peaks,
                    &skip,
                    first,
                    checked,
                ));
            }
        }
    }
    Err(PivError::InvalidInput("passes is empty".into()))
}
