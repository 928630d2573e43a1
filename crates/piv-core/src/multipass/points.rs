//! PIV at arbitrary image points with a predictor ([`piv_at`]) and Method II's one-call
//! predictor + final points driver ([`piv_with_final_points`]).

use super::field::*;
use super::frames::*;
use super::regular::*;
use super::roi::{margin as roi_margin, Roi, RINGS};
use super::settings::*;
use super::window::*;
use crate::correlate::Uncertainty;
use crate::error::{PivError, Result};
use crate::image::{GridField, Pixel};
use crate::particle_size::particle_diameter;
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

/// The predictor of [`piv_at`].
#[derive(Debug, Clone, Copy)]
pub enum Predictor<'a> {
    /// No predictor (zero displacement).
    Zero,
    /// One displacement per point (same shape as the points), px: the windows are offset
    /// symmetrically (sub-pixel) by it.
    PerPoint {
        u: ArrayView2<'a, f64>,
        v: ArrayView2<'a, f64>,
    },
    /// A regular-grid field (e.g. a previous [`piv`] on the same frames): the windows are
    /// deformed by it (symmetric, see [`Interpolation`]). The first correlation deforms the
    /// whole pair once on the pixel lattice (as [`piv`] does) and reads each window at its
    /// fractional position from the deformed pair with Keys: both windows of a pair are
    /// shifted by the same fraction, a linear shift-invariant filter applied to both, which
    /// widens the correlation peak but does not move it (the interpolation bias that the
    /// quintic B-spline keeps small is a bias of the relative shift of the two frames). It
    /// costs one interpolation per pixel plus a constant-shift copy per window, instead of a
    /// deformed interpolation per pixel and overlapping window. Later iterations (a per-point
    /// residual offset on top of the field) sample each window on its own.
    Field(&'a GridField),
}

/// Multipass PIV at arbitrary image positions `(x, y)` (pixel frame, arrays of one shape
/// (ny, nx)) with a given predictor: for each window of `windows` (`(w, h)`, w along x) in turn,
/// and `iterations` times each, every point's window pair is displaced by the current
/// displacement (the predictor's deformation plus a per-point symmetric offset) and the residual
/// is added. Between iterations the points are validated as a (ny, nx) grid of neighbours when
/// `s.validate` (give nx = 1 or ny = 1 only if neighbours along the line are meaningful).
/// `s.passes` and `s.mode` are ignored: `windows` gives the passes, and a `Field` predictor
/// means deformation. Points whose centre lies outside the image or in the mask are not computed.
/// Used by Method II (PIV on the raw frames at the images of an object grid).
pub fn piv_at<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    predictor: Predictor<'_>,
    mask: Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    s: &PivSettings,
) -> Result<PivField> {
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    let settings = check_at(dim, &x, &y, &predictor, &mask, windows, iterations, s)?;
    let frames = Frames::new(frame_a, frame_b, settings.interpolation)?;
    at_points(
        &frames, dim, x, y, predictor, &mask, windows, iterations, &settings,
    )
}

/// Check the inputs of [`piv_at`] other than the frames; returns its settings.
pub(crate) fn check_at(
    dim: (usize, usize),
    x: &ArrayView2<'_, f64>,
    y: &ArrayView2<'_, f64>,
    predictor: &Predictor<'_>,
    mask: &Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    s: &PivSettings,
) -> Result<PivSettings> {
    check_mask(mask, dim)?;
    if let Some(r) = &s.roi {
        return Err(PivError::InvalidInput(format!(
            "{r}: a region of interest cuts the regular grid of piv and of Methods I and II; \
             the points given here are where they are (leave roi out)"
        )));
    }
    if x.dim() != y.dim() {
        return Err(PivError::InvalidInput(format!(
            "points: x {:?} and y {:?} differ in shape",
            x.dim(),
            y.dim()
        )));
    }
    if windows.is_empty() || iterations == 0 {
        return Err(PivError::InvalidInput(
            "piv_at needs at least one window and one iteration".into(),
        ));
    }
    let mut settings = s.clone();
    settings.passes = windows.iter().map(|&(w, h)| Pass::new(w, h)).collect();
    settings.validate()?;
    for &(w, h) in windows {
        if w > dim.1 || h > dim.0 {
            return Err(PivError::InvalidInput(format!(
                "window {w} x {h} px (w x h) is larger than the image ({} x {} px)",
                dim.1, dim.0
            )));
        }
    }
    if let Predictor::PerPoint { u, v } = predictor {
        if u.dim() != x.dim() || v.dim() != x.dim() {
            return Err(PivError::InvalidInput(format!(
                "predictor shape {:?} differs from the points' {:?}",
                u.dim(),
                x.dim()
            )));
        }
        if u.iter().chain(v.iter()).any(|p| !p.is_finite()) {
            return Err(PivError::InvalidInput(
                "predictor contains NaN or inf".into(),
            ));
        }
    }
    Ok(settings)
}

/// The passes of [`piv_at`] on prepared frames (inputs checked by [`check_at`]).
pub(crate) fn at_points<T: Pixel>(
    frames: &Frames<'_, T>,
    dim: (usize, usize),
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    predictor: Predictor<'_>,
    mask: &Option<ArrayView2<'_, bool>>,
    windows: &[(usize, usize)],
    iterations: usize,
    settings: &PivSettings,
) -> Result<PivField> {
    let shape = x.dim();
    let n = x.len();
    let xs: Vec<f64> = x.iter().copied().collect();
    let ys: Vec<f64> = y.iter().copied().collect();
    let skip: Vec<bool> = xs
        .iter()
        .zip(&ys)
        .map(|(&x, &y)| excluded(mask, dim, x, y))
        .collect();
    let (base, mut du, mut dv): (Option<&GridField>, Vec<f64>, Vec<f64>) = match predictor {
        Predictor::Zero => (None, vec![0.0; n], vec![0.0; n]),
        Predictor::PerPoint { u, v } => (
            None,
            u.iter().copied().collect(),
            v.iter().copied().collect(),
        ),
        Predictor::Field(f) => (Some(f), vec![0.0; n], vec![0.0; n]),
    };
    // the field predictor's part of a vector: its mean over the window (the residual of a
    // window deformed by it is the window mean of `true - predictor`, see `crate::multipass`)
    let (mut bu, mut bv) = (vec![0.0; n], vec![0.0; n]);
    let mut last = None;
    // measured on the first correlation (interpolated windows here unless the predictor is
    // zero: see `crate::particle_size`)
    let mut diameter = None;
    // the pair deformed once by the field predictor (see `Predictor::Field`)
    let mut deformed: Option<Frames<'static, f32>> = None;
    for (p, &(w, h)) in windows.iter().enumerate() {
        if let Some(f) = base {
            let mean = WindowMean::new(w, h, settings.weighting);
            // the window means at the points in parallel (each independent)
            let means: Vec<(f64, f64)> = xs
                .par_iter()
                .zip(ys.par_iter())
                .map(|(&x, &y)| mean.at(f, x, y))
                .collect();
            for (k, &(mu, mv)) in means.iter().enumerate() {
                if p > 0 {
                    // a new window: the windows keep their displacement, the offset stays
                    // relative to the predictor's part
                    du[k] += bu[k] - mu;
                    dv[k] += bv[k] - mv;
                }
                (bu[k], bv[k]) = (mu, mv);
            }
        }
        for it in 0..iterations {
            let unc = if settings.uncertainty && p + 1 == windows.len() && it + 1 == iterations {
                Uncertainty::Peak
            } else {
                Uncertainty::Off
            };
            let no_offset = du.iter().chain(&dv).all(|&d| d == 0.0);
            if no_offset && base.is_some() && deformed.is_none() {
                deformed = base.map(|f| frames.deformed(f, None));
            }
            let sub = (settings.subpixel, settings.weighting);
            let sweep = |xs: &[f64], ys: &[f64], du: &[f64], dv: &[f64], skip: &[bool], u| match (
                base, &deformed,
            ) {
                (Some(_), Some(d)) if no_offset => {
                    d.sweep(w, h, xs, ys, du, dv, skip, None, sub, u)
                }
                _ => frames.sweep(w, h, xs, ys, du, dv, skip, base, sub, u),
            };
            let mut peaks = sweep(&xs, &ys, &du, &dv, &skip, unc);
            diameter.get_or_insert_with(|| particle_diameter(&peaks));
            let mut u = par_grid(shape, |j, i| {
                let k = j * shape.1 + i;
                bu[k] + du[k] + peaks[k].dx
            });
            let mut v = par_grid(shape, |j, i| {
                let k = j * shape.1 + i;
                bv[k] + dv[k] + peaks[k].dy
            });
            let checked = validate_replace(&mut u, &mut v, &peaks, &skip, settings);
            if it > 0 {
                // an extra iteration of this window (see `RELAXATION`): the previous estimate
                // is the predictor's part plus the offset
                let prev = |b: &[f64], d: &[f64]| {
                    Array2::from_shape_fn(shape, |(j, i)| {
                        let k = j * shape.1 + i;
                        b[k] + d[k]
                    })
                };
                relax(&mut u, &prev(&bu, &du));
                relax(&mut v, &prev(&bv, &dv));
            }
            if unc != Uncertainty::Off {
                fill_alt_sigmas(
                    &mut peaks,
                    &checked,
                    (&xs, &ys, &du, &dv),
                    |x, y, u, v, skip| sweep(x, y, u, v, skip, Uncertainty::AllPeaks),
                );
            }
            for k in 0..n {
                let (j, i) = (k / shape.1, k % shape.1);
                du[k] = u[[j, i]] - bu[k];
                dv[k] = v[[j, i]] - bv[k];
            }
            last = Some((u, v, peaks, checked));
        }
    }
    let (u, v, peaks, checked) = last.expect("at least one iteration");
    Ok(finish(
        None,
        x.to_owned(),
        y.to_owned(),
        u,
        v,
        &peaks,
        &skip,
        diameter.unwrap_or((f64::NAN, f64::NAN)),
        checked,
    ))
}

/// Method II's PIV in one call on one prepared frame pair: the passes of `s` but the last run
/// as [`piv`] on the regular grid (the predictor), then the last pass (its window and
/// iterations; its overlap is ignored) runs as [`piv_at`] at the image points `(x, y)` with that
/// field as predictor: deformed by it ([`Predictor::Field`]) for [`Mode::Deform`], offset by
/// it interpolated at each point ([`Predictor::PerPoint`]) for [`Mode::Offset`]. The frames'
/// interpolation coefficients and variance are computed once for both stages. Vectors of the
/// predictor that are not computed (mask) take the mean of the computed ones.
///
/// Gives the same vectors as [`piv`] with the first passes followed by [`piv_at`] with that
/// predictor. Returns `(predictor, final)`; `predictor` is `None` when `s` has one pass (the
/// final pass then has no predictor).
///
/// With [`PivSettings::roi`] (px of these frames; it should hold the points' windows) only the
/// region and a margin are read, and the predictor passes run on the whole frames' grids cut
/// to it and [`RINGS`] rings around it, as [`piv`] runs them in a region (`roi.rs`).
pub fn piv_with_final_points<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
) -> Result<(Option<PivField>, PivField)> {
    s.validate()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    let Some(roi) = s.roi else {
        return final_points(frame_a, frame_b, x, y, mask, s, None);
    };
    roi.check(dim, &predictor_settings(s))?;
    let crop = roi.grown(roi_margin(s), dim);
    let (cx, cy) = (crop.x0 as f64, crop.y0 as f64);
    let inner = PivSettings {
        roi: None,
        ..s.clone()
    };
    let (p, f) = final_points(
        crop.view(&frame_a),
        crop.view(&frame_b),
        x.mapv(|v| v - cx).view(),
        y.mapv(|v| v - cy).view(),
        mask.as_ref().map(|m| crop.view(m)),
        &inner,
        Some((roi, dim, crop, (frame_a, frame_b))),
    )?;
    Ok((p.map(|p| p.moved(cx, cy)), f.moved(cx, cy)))
}

/// The settings of [`piv_with_final_points`]'s predictor passes: all but the last (a single
/// pass checks the region against its own window).
fn predictor_settings(s: &PivSettings) -> PivSettings {
    let mut first = s.clone();
    if first.passes.len() > 1 {
        first.passes.pop();
    }
    first
}

/// The whole frames a crop is cut from: the region, their shape, the crop and the frames.
type Whole<'a, T> = (
    Roi,
    (usize, usize),
    Roi,
    (ArrayView2<'a, T>, ArrayView2<'a, T>),
);

/// [`piv_with_final_points`] on frames that are the crop `crop` of the frames `whole` when
/// `region` is given (the predictor's grids those frames' cut to the region and its rings, the
/// blank-window rule theirs).
fn final_points<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
    region: Option<Whole<'_, T>>,
) -> Result<(Option<PivField>, PivField)> {
    let dim = frame_a.dim();
    let last = *s.passes.last().expect("checked: non-empty");
    let windows = [(last.w, last.h)];
    // the final pass's checks before any work (the predictor shape is checked below)
    let settings_at = check_at(
        dim,
        &x,
        &y,
        &Predictor::Zero,
        &mask,
        &windows,
        last.iterations,
        s,
    )?;
    let mut first = s.clone();
    first.passes.pop();
    let grids = match region {
        None => grids_of(&first, dim)?,
        Some((roi, whole, crop, _)) => first
            .passes
            .iter()
            .map(|p| {
                Ok(roi
                    .grid_ring(p.w, p.h, p.overlap, whole, (crop.x0, crop.y0), RINGS)?
                    .grid)
            })
            .collect::<Result<Vec<_>>>()?,
    };
    let frames = Frames::cut_from(frame_a, frame_b, s.interpolation, region.map(|r| r.3))?;
    if first.passes.is_empty() {
        let f = at_points(
            &frames,
            dim,
            x,
            y,
            Predictor::Zero,
            &mask,
            &windows,
            last.iterations,
            &settings_at,
        )?;
        return Ok((None, f));
    }
    let pred = grid_passes(&frames, dim, &mask, &first, grids)?;
    let grid = pred.grid.expect("grid passes give a grid field");
    let fill = |a: &Array2<f64>| {
        let (sum, n) = a
            .iter()
            .filter(|p| p.is_finite())
            .fold((0.0, 0usize), |(s, n), &p| (s + p, n + 1));
        let m = if n > 0 { sum / n as f64 } else { 0.0 };
        a.mapv(|p| if p.is_finite() { p } else { m })
    };
    let gf = GridField {
        grid,
        u: fill(&pred.u),
        v: fill(&pred.v),
    };
    let f = match s.mode {
        Mode::Deform => at_points(
            &frames,
            dim,
            x,
            y,
            Predictor::Field(&gf),
            &mask,
            &windows,
            last.iterations,
            &settings_at,
        )?,
        Mode::Offset => {
            let finite = |p: f64| if p.is_finite() { p } else { 0.0 };
            let (pu, pv): (Vec<f64>, Vec<f64>) = x
                .iter()
                .zip(y.iter())
                .map(|(&x, &y)| {
                    let (u, v) = gf.at(x, y);
                    (finite(u), finite(v))
                })
                .unzip();
            let pu = Array2::from_shape_vec(x.dim(), pu).expect("shape");
            let pv = Array2::from_shape_vec(x.dim(), pv).expect("shape");
            at_points(
                &frames,
                dim,
                x,
                y,
                Predictor::PerPoint {
                    u: pu.view(),
                    v: pv.view(),
                },
                &mask,
                &windows,
                last.iterations,
                &settings_at,
            )?
        }
    };
    // the particle images as recorded: the predictor's first pass read the frames themselves
    let f = PivField {
        particle_diameter: pred.particle_diameter,
        ..f
    };
    Ok((Some(pred), f))
}
