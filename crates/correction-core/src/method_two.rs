//! Method II: PIV on the raw frames at the images of the object grid, vectors mapped back.

use crate::error::{CorrectionError, Result};
use crate::method::DisplacementMapping;
use dewarp_core::Mapping;
use image_core::Pixel;
use ndarray::{Array2, ArrayView2, Zip};
use piv_core::{Grid, PivField, PivSettings, RingGrid, Roi};

/// The regular object grid of the last pass of `settings` on an object frame of
/// `object_shape` (rows, columns): the grid [`piv_core::piv`] gives on the dewarped frames, so
/// Methods I and II share their vector positions (cut to [`PivSettings::roi`] when given).
pub fn object_grid(object_shape: (usize, usize), settings: &PivSettings) -> Result<Grid> {
    let last = settings
        .passes
        .last()
        .ok_or_else(|| CorrectionError::InvalidInput("passes is empty".into()))?;
    if let Some(roi) = settings.roi {
        roi.check(object_shape, settings)?;
        return Ok(roi.grid(last.w, last.h, last.overlap, object_shape, (0, 0))?);
    }
    Ok(Grid::for_windows(
        object_shape.1,
        object_shape.0,
        last.w,
        last.h,
        last.overlap,
    )?)
}

/// The grid the final pass runs on (`grid`) and [`object_grid`] in it (`inner`, at `at`): in
/// a region of interest [`piv_core::ROI_RINGS`] more rings of the object frame's grid points
/// around it where it has them (the median test's neighbours and the pooled uncertainty of the
/// region's outer vectors); without one both are [`object_grid`].
pub fn object_grid_ring(object_shape: (usize, usize), settings: &PivSettings) -> Result<RingGrid> {
    let (Some(roi), Some(last)) = (settings.roi, settings.passes.last()) else {
        let g = object_grid(object_shape, settings)?;
        return Ok(RingGrid {
            grid: g,
            at: (0, 0),
            inner: g,
        });
    };
    roi.check(object_shape, settings)?;
    let rings = piv_core::ROI_RINGS;
    Ok(roi.grid_ring(last.w, last.h, last.overlap, object_shape, (0, 0), rings)?)
}

/// Object-frame displacements of the image displacements `(u, v)` measured at the image points
/// `(x, y)` (all of one shape): [`DisplacementMapping::Full`] gives
/// `F^-1(p + d/2) - F^-1(p - d/2)` (NaN where `d` is not finite or the inverse does not
/// converge), [`DisplacementMapping::Positions`] the displacements as measured.
pub fn map_displacements(
    mapping: &Mapping,
    x: ArrayView2<'_, f64>,
    y: ArrayView2<'_, f64>,
    u: ArrayView2<'_, f64>,
    v: ArrayView2<'_, f64>,
    mode: DisplacementMapping,
) -> (Array2<f64>, Array2<f64>) {
    if mode == DisplacementMapping::Positions {
        return (u.to_owned(), v.to_owned());
    }
    let mut du = Array2::from_elem(u.dim(), f64::NAN);
    let mut dv = Array2::from_elem(u.dim(), f64::NAN);
    Zip::from(&mut du)
        .and(&mut dv)
        .and(x)
        .and(y)
        .and(u)
        .and(v)
        .par_for_each(|du, dv, &x, &y, &u, &v| {
            if !(u.is_finite() && v.is_finite()) {
                return;
            }
            let end = |s: f64| {
                let (p, ok, _) = mapping.inverse_checked(x + s * 0.5 * u, y + s * 0.5 * v);
                // a point that does not converge gives NaN, as `Mapping.inverse(on_fail="nan")`
                if ok && (x + s * 0.5 * u).is_finite() && (y + s * 0.5 * v).is_finite() {
                    p
                } else {
                    (f64::NAN, f64::NAN)
                }
            };
            let (a, b) = (end(-1.0), end(1.0));
            *du = b.0 - a.0;
            *dv = b.1 - a.1;
        });
    (du, dv)
}

/// The standard uncertainties `(sigma_u, sigma_v)` of image displacements carried to the
/// object frame as [`map_displacements`] carries the displacements: to first order the mapped
/// displacement is `J d` with `J` the Jacobian of the inverse mapping at the image point, the
/// inverse of the forward mapping's Jacobian at the object point `(gx, gy)` (central
/// differences over 1 object px); with independent errors of u and v, `sigma_U^2 = J11^2
/// sigma_u^2 + J12^2 sigma_v^2` and `sigma_V^2 = J21^2 sigma_u^2 + J22^2 sigma_v^2`. Unchanged
/// for [`DisplacementMapping::Positions`]; NaN where a sigma is NaN or `J` is singular.
pub fn map_sigmas(
    mapping: &Mapping,
    gx: ArrayView2<'_, f64>,
    gy: ArrayView2<'_, f64>,
    su: ArrayView2<'_, f64>,
    sv: ArrayView2<'_, f64>,
    mode: DisplacementMapping,
) -> (Array2<f64>, Array2<f64>) {
    if mode == DisplacementMapping::Positions {
        return (su.to_owned(), sv.to_owned());
    }
    let mut ou = Array2::from_elem(su.dim(), f64::NAN);
    let mut ov = Array2::from_elem(su.dim(), f64::NAN);
    Zip::from(&mut ou)
        .and(&mut ov)
        .and(gx)
        .and(gy)
        .and(su)
        .and(sv)
        .par_for_each(|ou, ov, &x, &y, &su, &sv| {
            if !(su.is_finite() && sv.is_finite()) {
                return;
            }
            let (xp, xm) = (mapping.forward(x + 0.5, y), mapping.forward(x - 0.5, y));
            let (yp, ym) = (mapping.forward(x, y + 0.5), mapping.forward(x, y - 0.5));
            // forward Jacobian [[a, b], [c, d]] (image per object px)
            let (a, c) = (xp.0 - xm.0, xp.1 - xm.1);
            let (b, d) = (yp.0 - ym.0, yp.1 - ym.1);
            let det = a * d - b * c;
            if !(det.is_finite() && det.abs() > 1e-12) {
                return;
            }
            let (j11, j12, j21, j22) = (d / det, -b / det, -c / det, a / det);
            *ou = ((j11 * su).powi(2) + (j12 * sv).powi(2)).sqrt();
            *ov = ((j21 * su).powi(2) + (j22 * sv).powi(2)).sqrt();
        });
    (ou, ov)
}

/// Method II: the passes of `settings` but the last as the raw-frame predictor, the last pass
/// (its window and iterations) at the images `F(X)` of the points `X` of [`object_grid`], on
/// one prepared frame pair ([`piv_core::piv_with_final_points`]); the measured displacements
/// mapped back by `mode` ([`map_displacements`]).
///
/// The result lives on the object grid (`grid`, `x`, `y` in object px, displacements in object
/// px). A vector whose displacement cannot be mapped back (the inverse fails) is masked;
/// `valid`, `replaced` and `peak_choice` are cleared where masked; peak ratio and correlation coefficient
/// are those of the final correlation at the image point; the uncertainties are mapped by
/// [`map_sigmas`].
pub fn method_two<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mapping: &Mapping,
    settings: &PivSettings,
    mode: DisplacementMapping,
    object_shape: Option<(usize, usize)>,
    mask: Option<ArrayView2<'_, bool>>,
) -> Result<PivField> {
    let shape = object_shape.unwrap_or(frame_a.dim());
    // in a region, with its rings (cut off at the end)
    let RingGrid { grid, at, inner } = object_grid_ring(shape, settings)?;
    let (gx, gy) = (
        Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| grid.xy(j, i).0),
        Array2::from_shape_fn((grid.ny, grid.nx), |(j, i)| grid.xy(j, i).1),
    );
    let mut ix = Array2::zeros(gx.dim());
    let mut iy = Array2::zeros(gx.dim());
    Zip::from(&mut ix)
        .and(&mut iy)
        .and(&gx)
        .and(&gy)
        .par_for_each(|ix, iy, &x, &y| {
            (*ix, *iy) = mapping.forward(x, y);
        });
    if ix.iter().chain(iy.iter()).any(|p| !p.is_finite()) {
        return Err(CorrectionError::InvalidInput(
            "the mapping sends object grid points to NaN or infinity".into(),
        ));
    }
    let (_, f) = match settings.roi {
        None => {
            piv_core::piv_with_final_points(frame_a, frame_b, ix.view(), iy.view(), mask, settings)?
        }
        // a region of interest (object px): the raw frames' region holding the object grid's
        // images and their windows (the predictor passes cut to it, a margin read around it)
        Some(_) => {
            let (xs, ys) = (ix.as_slice().expect("owned"), iy.as_slice().expect("owned"));
            let dim = frame_a.dim();
            let last = settings.passes[settings.passes.len() - 1];
            let raw = Roi::around(xs, ys, last.w.max(last.h), dim)
                .unwrap_or(Roi::from([0, 0, dim.1, dim.0]));
            let inner = PivSettings {
                roi: Some(raw),
                ..settings.clone()
            };
            piv_core::piv_with_final_points(frame_a, frame_b, ix.view(), iy.view(), mask, &inner)?
        }
    };
    let (du, dv) = map_displacements(mapping, ix.view(), iy.view(), f.u.view(), f.v.view(), mode);
    let masked = Zip::from(&f.masked)
        .and(&du)
        .and(&dv)
        .map_collect(|&m, &u, &v| m || !(u.is_finite() && v.is_finite()));
    let nan_where = |d: Array2<f64>| {
        Zip::from(&d)
            .and(&masked)
            .map_collect(|&d, &m| if m { f64::NAN } else { d })
    };
    let valid = Zip::from(&f.valid)
        .and(&masked)
        .map_collect(|&ok, &m| ok && !m);
    let replaced = Zip::from(&f.replaced)
        .and(&masked)
        .map_collect(|&r, &m| r && !m);
    let (su, sv) = map_sigmas(
        mapping,
        gx.view(),
        gy.view(),
        f.sigma_u.view(),
        f.sigma_v.view(),
        mode,
    );
    let peak_choice = Zip::from(&f.peak_choice)
        .and(&masked)
        .map_collect(|&c, &m| if m { 0 } else { c });
    let field = PivField {
        grid: Some(grid),
        x: gx,
        y: gy,
        u: nan_where(du),
        v: nan_where(dv),
        peak_ratio: f.peak_ratio,
        coef: f.coef,
        sigma_u: nan_where(su),
        sigma_v: nan_where(sv),
        valid,
        replaced,
        peak_choice,
        masked,
        particle_diameter: f.particle_diameter,
    };
    Ok(if grid == inner {
        field
    } else {
        field.cut(at, inner)
    })
}
