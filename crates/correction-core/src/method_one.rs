//! Method I: dewarp both frames (and the mask) into the object frame, then the regular
//! multipass PIV of the dewarped pair.

use crate::error::Result;
use crate::method::ZeroFill;
use dewarp_core::remap::{remap, RemapOptions};
use dewarp_core::Mapping;
use image_core::Pixel;
use ndarray::{Array2, ArrayView2};
use piv_core::{PivField, PivSettings, Roi};

/// A frame pair dewarped into the object frame.
#[derive(Debug, Clone)]
pub struct DewarpedPair {
    /// Frame A, object frame (f32, zero outside the sensor).
    pub a: Array2<f32>,
    /// Frame B, object frame.
    pub b: Array2<f32>,
    /// `true` = excluded, object frame; `None` when nothing is excluded by request.
    pub mask: Option<Array2<bool>>,
}

/// Both frames and the mask dewarped into an object frame of `object_shape` (rows, columns;
/// default: the frames' shape): Keys bicubic, the mapping on the coarsest grid within 1e-3 px
/// (the remap's default), zero outside the sensor. The object mask covers the zero fill
/// (object px whose image lies outside the sensor: the dewarped ones-image `< 0.5`) with
/// [`ZeroFill::Mask`], and the raw `mask` dewarped with fill 1 (`> 0.5`).
pub fn dewarp_pair<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mapping: &Mapping,
    object_shape: Option<(usize, usize)>,
    mask: Option<ArrayView2<'_, bool>>,
    zero_fill: ZeroFill,
) -> Result<DewarpedPair> {
    let shape = object_shape.unwrap_or(frame_a.dim());
    let whole = Roi::from([0, 0, shape.1, shape.0]);
    dewarp_region(frame_a, frame_b, mapping, whole, mask, zero_fill)
}

/// [`dewarp_pair`] of the object px `region` only (a rectangle of the object frame): the
/// returned frames' pixel `(0, 0)` is the object frame's `(region.x0, region.y0)`.
pub fn dewarp_region<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mapping: &Mapping,
    region: Roi,
    mask: Option<ArrayView2<'_, bool>>,
    zero_fill: ZeroFill,
) -> Result<DewarpedPair> {
    if frame_a.dim() != frame_b.dim() {
        return Err(piv_core::PivError::InvalidInput(format!(
            "frame_a {:?} and frame_b {:?} differ in shape (rows, columns)",
            frame_a.dim(),
            frame_b.dim()
        ))
        .into());
    }
    if let Some(m) = &mask {
        if m.dim() != frame_a.dim() {
            return Err(piv_core::PivError::InvalidInput(format!(
                "mask {:?} differs in shape from the frames {:?}",
                m.dim(),
                frame_a.dim()
            ))
            .into());
        }
    }
    let (ox, oy) = (region.x0 as f64, region.y0 as f64);
    let map = |x: f64, y: f64| mapping.forward(x + ox, y + oy);
    let opts = RemapOptions {
        out_shape: Some((region.height(), region.width())),
        ..RemapOptions::default()
    };
    let (a, b) = rayon::join(
        || remap::<T, f32, _>(frame_a, &map, &opts),
        || remap::<T, f32, _>(frame_b, &map, &opts),
    );
    let (a, b) = (a?, b?);
    let mut object_mask: Option<Array2<bool>> = None;
    if zero_fill == ZeroFill::Mask {
        let ones = Array2::<f32>::ones(frame_a.dim());
        let d: Array2<f32> = remap(ones.view(), &map, &opts)?;
        object_mask = Some(d.mapv(|v| v < 0.5));
    }
    if let Some(m) = mask {
        let mf = m.mapv(|v| if v { 1.0f32 } else { 0.0 });
        let opts1 = RemapOptions { fill: 1.0, ..opts };
        let d: Array2<f32> = remap(mf.view(), &map, &opts1)?;
        let dm = d.mapv(|v| v > 0.5);
        object_mask = Some(match object_mask {
            Some(z) => ndarray::Zip::from(&z).and(&dm).map_collect(|&p, &q| p || q),
            None => dm,
        });
    }
    Ok(DewarpedPair {
        a,
        b,
        mask: object_mask,
    })
}

/// Method I: [`dewarp_pair`], then [`piv_core::piv`] of the dewarped frames with `settings`;
/// vectors centred on the object mask are masked. Vectors and displacements in object px.
///
/// With [`PivSettings::roi`] (object px, inside `object_shape`) only the region and the margin
/// [`piv_core::roi_margin`] around it are dewarped and correlated.
pub fn method_one<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mapping: &Mapping,
    settings: &PivSettings,
    object_shape: Option<(usize, usize)>,
    mask: Option<ArrayView2<'_, bool>>,
    zero_fill: ZeroFill,
) -> Result<PivField> {
    let Some(roi) = settings.roi else {
        let d = dewarp_pair(frame_a, frame_b, mapping, object_shape, mask, zero_fill)?;
        return Ok(piv_core::piv(
            d.a.view(),
            d.b.view(),
            d.mask.as_ref().map(|m| m.view()),
            settings,
        )?);
    };
    let shape = object_shape.unwrap_or(frame_a.dim());
    roi.check(shape, settings)?;
    let crop = roi.grown(piv_core::roi_margin(settings), shape);
    let d = dewarp_region(frame_a, frame_b, mapping, crop, mask, zero_fill)?;
    Ok(piv_core::piv_cropped(
        d.a.view(),
        d.b.view(),
        d.mask.as_ref().map(|m| m.view()),
        settings,
        shape,
        crop,
        None,
    )?)
}
