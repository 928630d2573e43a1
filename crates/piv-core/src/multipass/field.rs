//! The vector field of a PIV evaluation, its validation and replacement after every iteration,
//! and its assembly.

use super::settings::*;
use crate::correlate::Peak;
use crate::grid::Grid;
use crate::image::GridField;
use crate::validate::{median_test, replace};
use ndarray::Array2;

/// A vector field. All arrays have the same shape (ny, nx).
#[derive(Debug, Clone)]
pub struct PivField {
    /// The regular grid of the vectors (`None` for [`piv_at`]).
    pub grid: Option<Grid>,
    /// Window centres, px (pixel frame).
    pub x: Array2<f64>,
    pub y: Array2<f64>,
    /// Displacement along x (right) and y (down), px; NaN where `masked`.
    pub u: Array2<f64>,
    pub v: Array2<f64>,
    /// Peak ratio of the last correlation (0 where not computed).
    pub peak_ratio: Array2<f64>,
    /// Correlation coefficient (normalised peak height) of the last correlation.
    pub coef: Array2<f64>,
    /// Passed the final validation.
    pub valid: Array2<bool>,
    /// Rejected and replaced by interpolation from neighbours.
    pub replaced: Array2<bool>,
    /// Not computed: inside the mask, or the centre outside the image.
    pub masked: Array2<bool>,
}

impl PivField {
    /// The field as a predictor (only for grid fields).
    pub fn to_grid_field(&self) -> Option<GridField> {
        let grid = self.grid?;
        let fill = |a: &Array2<f64>| a.mapv(|x| if x.is_finite() { x } else { 0.0 });
        let mut u = fill(&self.u);
        let mut v = fill(&self.v);
        let good = self.masked.mapv(|m| !m);
        replace(&mut u, &mut v, &good);
        Some(GridField { grid, u, v })
    }
}

/// Validate (optionally) and replace; returns (valid, replaced).
pub(crate) fn validate_replace(
    u: &mut Array2<f64>,
    v: &mut Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    s: &PivSettings,
) -> (Array2<bool>, Array2<bool>) {
    let dim = u.dim();
    let usable = Array2::from_shape_fn(dim, |(j, i)| {
        let k = j * dim.1 + i;
        let p = &peaks[k];
        !skip[k]
            && p.ok
            && p.ratio >= s.min_peak_ratio
            && u[[j, i]].is_finite()
            && v[[j, i]].is_finite()
    });
    let good = if s.validate {
        let out = median_test(u, v, &usable, s.median_eps, s.median_threshold);
        Array2::from_shape_fn(dim, |ji| usable[ji] && !out[ji])
    } else {
        usable
    };
    replace(u, v, &good);
    let replaced = Array2::from_shape_fn(dim, |(j, i)| !good[[j, i]] && !skip[j * dim.1 + i]);
    (good, replaced)
}

pub(crate) fn finish(
    grid: Option<Grid>,
    x: Array2<f64>,
    y: Array2<f64>,
    mut u: Array2<f64>,
    mut v: Array2<f64>,
    peaks: &[Peak],
    skip: &[bool],
    valid: Array2<bool>,
    replaced: Array2<bool>,
) -> PivField {
    let dim = u.dim();
    let masked = Array2::from_shape_fn(dim, |(j, i)| skip[j * dim.1 + i]);
    for ((uu, vv), &m) in u.iter_mut().zip(v.iter_mut()).zip(masked.iter()) {
        if m {
            *uu = f64::NAN;
            *vv = f64::NAN;
        }
    }
    let peak_ratio = Array2::from_shape_fn(dim, |(j, i)| peaks[j * dim.1 + i].ratio);
    let coef = Array2::from_shape_fn(dim, |(j, i)| peaks[j * dim.1 + i].coef);
    PivField {
        grid,
        x,
        y,
        u,
        v,
        peak_ratio,
        coef,
        valid,
        replaced,
        masked,
    }
}
