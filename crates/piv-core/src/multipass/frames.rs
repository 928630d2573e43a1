//! The prepared frame pair: interpolation coefficients, per-frame variance, deformation, and
//! sweeps over the (deformed) frames.

use super::settings::*;
use super::window::*;
use crate::correlate::{Peak, SubPixel, Uncertainty};
use crate::error::Result;
use crate::image::{
    bspline5_coeffs, bspline5_weights, bspline_coeffs, bspline_weights, deform_pair, into_buffers,
    keys_weights, sample_shift, GridField, Img, Pixel, Source,
};
use crate::weighting::Weighting;
use ndarray::ArrayView2;
use rayon::prelude::*;

/// Runs `$body` with `$src` bound to the [`Source`] of `$frames` for the interpolation images
/// `$coeffs` (one arm per kernel: the sweeps are generic over it).
macro_rules! with_source {
    ($frames:expr, $coeffs:expr, |$src:ident| $body:expr) => {
        match $coeffs {
            Coeffs::Quintic(ca, cb) => {
                let $src = Source {
                    a: &$frames.a,
                    b: &$frames.b,
                    ia: ca,
                    ib: cb,
                    wf: bspline5_weights,
                };
                $body
            }
            Coeffs::Cubic(ca, cb) => {
                let $src = Source {
                    a: &$frames.a,
                    b: &$frames.b,
                    ia: ca,
                    ib: cb,
                    wf: bspline_weights,
                };
                $body
            }
            Coeffs::Keys => {
                let $src = Source {
                    a: &$frames.a,
                    b: &$frames.b,
                    ia: &$frames.a,
                    ib: &$frames.b,
                    wf: keys_weights,
                };
                $body
            }
        }
    };
}

/// Do both windows of every point not skipped (centres `xs`, `ys`, symmetric offsets `du`,
/// `dv`) start on integer pixel positions (plain copies, no interpolation)?
fn on_integers(
    w: usize,
    h: usize,
    (xs, ys): (&[f64], &[f64]),
    (du, dv): (&[f64], &[f64]),
    skip: &[bool],
) -> bool {
    let int = |p: f64| p == p.round();
    let (hw, hh) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    (0..xs.len()).all(|k| {
        skip[k]
            || (int(xs[k] - hw - du[k] / 2.0)
                && int(ys[k] - hh - dv[k] / 2.0)
                && int(xs[k] - hw + du[k] / 2.0)
                && int(ys[k] - hh + dv[k] / 2.0))
    })
}

/// The interpolation images of a frame pair.
pub(crate) enum Coeffs {
    /// Quintic B-spline coefficients.
    Quintic(Img<'static, f32>, Img<'static, f32>),
    /// Cubic B-spline coefficients.
    Cubic(Img<'static, f32>, Img<'static, f32>),
    /// Keys on the frames themselves.
    Keys,
}

/// The frames and their interpolants; `sweep` over them.
pub(crate) struct Frames<'a, T: Pixel> {
    a: Img<'a, T>,
    b: Img<'a, T>,
    interp: Interpolation,
    /// The interpolation images, computed on first use (windows on integer positions need
    /// none).
    coeffs: std::sync::OnceLock<Coeffs>,
    /// How a window's blank blocks are told: the per-pixel variance below which a block is
    /// blank ([`BLANK_VARIANCE`] times the larger variance of the two frames), and the
    /// frames' clean background level, if both have the same one ([`clean_background`]).
    rule: BlankRule,
}

/// A window whose per-pixel variance is below this fraction of its frame's variance is blank
/// (zero fill of a dewarped frame, including the interpolation's ringing next to its edge;
/// regions without signal): it is not correlated. Camera noise alone is far above it.
pub const BLANK_VARIANCE: f64 = 1e-6;

/// Per-pixel variance of a frame (f64 accumulation, rows in parallel).
pub(crate) fn frame_variance<T: Pixel>(img: &Img<'_, T>) -> f64 {
    let n = (img.width * img.height) as f64;
    let (s, s2) = img
        .slice()
        .par_chunks(img.width.max(1))
        .map(|row| {
            row.iter().fold((0.0f64, 0.0f64), |(s, s2), p| {
                let v = p.to_f32() as f64;
                (s + v, s2 + v * v)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let m = s / n;
    (s2 / n - m * m).max(0.0)
}

impl Frames<'static, f32> {
    /// The pixel buffers of deformed frames, for the `reuse` of the next [`Frames::deformed`].
    pub(crate) fn into_buffers(self) -> Option<(Vec<f32>, Vec<f32>)> {
        into_buffers((self.a, self.b))
    }
}

/// The blank-window rule of a frame pair: [`BLANK_VARIANCE`] times the larger of the frames'
/// variances, and their clean background level if both have the same one.
fn blank_rule<T: Pixel>(a: &Img<'_, T>, b: &Img<'_, T>) -> BlankRule {
    let floor = (BLANK_VARIANCE * frame_variance(a).max(frame_variance(b))) as f32;
    let clean = |i: &Img<'_, T>| clean_background(i.slice(), i.width, i.height);
    let background = match (clean(a), clean(b)) {
        (Some(la), Some(lb)) if la == lb => Some(la),
        _ => None,
    };
    BlankRule { floor, background }
}

impl<'a, T: Pixel> Frames<'a, T> {
    pub(crate) fn new(
        a: ArrayView2<'a, T>,
        b: ArrayView2<'a, T>,
        interp: Interpolation,
    ) -> Result<Self> {
        Self::cut_from(a, b, interp, None)
    }

    /// [`Frames::new`] of frames cut from `whole` (a region of interest's crop): the
    /// blank-window rule is the whole frames' (their variance and clean background), so that
    /// the region's windows are told blank as in the whole frames. `None`: the frames' own.
    pub(crate) fn cut_from(
        a: ArrayView2<'a, T>,
        b: ArrayView2<'a, T>,
        interp: Interpolation,
        whole: Option<(ArrayView2<'_, T>, ArrayView2<'_, T>)>,
    ) -> Result<Self> {
        let a = Img::new(a, "frame_a")?;
        let b = Img::new(b, "frame_b")?;
        let rule = match whole {
            None => blank_rule(&a, &b),
            Some((wa, wb)) => blank_rule(&Img::new(wa, "frame_a")?, &Img::new(wb, "frame_b")?),
        };
        Ok(Frames {
            a,
            b,
            interp,
            coeffs: std::sync::OnceLock::new(),
            rule,
        })
    }

    pub(crate) fn coeffs(&self) -> &Coeffs {
        self.coeffs.get_or_init(|| match self.interp {
            Interpolation::BSpline => {
                let (ca, cb) =
                    rayon::join(|| bspline5_coeffs(&self.a), || bspline5_coeffs(&self.b));
                Coeffs::Quintic(ca, cb)
            }
            Interpolation::BSpline3 => {
                Coeffs::Cubic(bspline_coeffs(&self.a), bspline_coeffs(&self.b))
            }
            Interpolation::Keys => Coeffs::Keys,
        })
    }

    /// The frames deformed symmetrically by `f` (see [`deform_pair`]), written into `reuse`
    /// (the buffers of an earlier deformed pair, [`Frames::into_buffers`]) when given.
    /// Sample a `w` x `h` strip of frame A with its top-left at `a` and one of frame B at `b`
    /// (constant sub-pixel shifts, the frames' interpolation) into `wa`, `wb`; the caller
    /// keeps both inside the image.
    pub(crate) fn shift_pair(
        &self,
        (w, h): (usize, usize),
        a: (f64, f64),
        b: (f64, f64),
        wa: &mut [f32],
        wb: &mut [f32],
    ) {
        let coeffs = self.coeffs();
        with_source!(self, coeffs, |src| {
            sample_shift(src.a, src.ia, src.wf, w, h, a.0, a.1, wa);
            sample_shift(src.b, src.ib, src.wf, w, h, b.0, b.1, wb);
        })
    }

    pub(crate) fn deformed(
        &self,
        f: &GridField,
        reuse: Option<(Vec<f32>, Vec<f32>)>,
    ) -> Frames<'static, f32> {
        let (a, b) = match self.coeffs() {
            Coeffs::Quintic(ca, cb) => deform_pair(ca, cb, bspline5_weights, f, reuse),
            Coeffs::Cubic(ca, cb) => deform_pair(ca, cb, bspline_weights, f, reuse),
            Coeffs::Keys => deform_pair(&self.a, &self.b, keys_weights, f, reuse),
        };
        Frames {
            a,
            b,
            interp: Interpolation::Keys,
            coeffs: std::sync::OnceLock::from(Coeffs::Keys),
            rule: self.rule,
        }
    }

    pub(crate) fn sweep(
        &self,
        w: usize,
        h: usize,
        xs: &[f64],
        ys: &[f64],
        du: &[f64],
        dv: &[f64],
        skip: &[bool],
        base: Option<&GridField>,
        est: (SubPixel, Weighting),
        uncertainty: Uncertainty,
    ) -> Vec<Peak> {
        // windows on integer positions are plain copies: no interpolation images needed
        let integer = base.is_none() && on_integers(w, h, (xs, ys), (du, dv), skip);
        let coeffs = if integer {
            &Coeffs::Keys
        } else {
            self.coeffs()
        };
        with_source!(self, coeffs, |src| sweep(
            &src,
            w,
            h,
            xs,
            ys,
            du,
            dv,
            skip,
            base,
            est,
            uncertainty,
            self.rule
        ))
    }

    /// [`sweep_into`] over the frames: window pairs offset symmetrically by `(du, dv)` per point
    /// and deformed by `base` (interpolated unless the windows stay on integer positions);
    /// returns how many windows were used.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn sweep_into<F>(
        &self,
        w: usize,
        h: usize,
        points: (&[f64], &[f64]),
        offsets: (&[f64], &[f64]),
        base: Option<&GridField>,
        skip: &[bool],
        out: &mut [f64],
        stride: usize,
        f: F,
    ) -> usize
    where
        F: Fn(&mut crate::correlate::Correlator, &mut [f64]) + Sync,
    {
        let integer = base.is_none() && on_integers(w, h, points, offsets, skip);
        let coeffs = if integer {
            &Coeffs::Keys
        } else {
            self.coeffs()
        };
        with_source!(self, coeffs, |src| sweep_into(
            &src, w, h, points, offsets, base, skip, self.rule, out, stride, &f
        ))
    }
}
