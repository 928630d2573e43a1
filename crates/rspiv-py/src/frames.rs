//! The two frames of a call as views of one pixel type, and the object-safe entry points that
//! run the cores on them with the GIL released (no copy of C-contiguous arrays).

use crate::errors::{invalid, PyRspivErr};
use correction_core::CorrectionError;
use correction_core::{DisplacementMapping, ZeroFill};
use dewarp_core::Mapping;
use ndarray::ArrayView2;
use numpy::{Element, PyReadonlyArray2};
use piv_core::{PivError, PivField, PivSettings, Pixel, Predictor};
use pyo3::prelude::*;

/// Evaluate `$body` (a `PyResult`) with `$view` the `ArrayView2` of one frame read in place as
/// its own pixel type (uint16, uint8, float32, float64: the same types as [`frames`]), or fail
/// in one line for any other array.
macro_rules! with_frame {
    ($frame:expr, |$view:ident| $body:expr) => {{
        use numpy::PyReadonlyArray2;
        if let Ok(a) = $frame.extract::<PyReadonlyArray2<'_, u16>>() {
            let $view = a.as_array();
            $body
        } else if let Ok(a) = $frame.extract::<PyReadonlyArray2<'_, u8>>() {
            let $view = a.as_array();
            $body
        } else if let Ok(a) = $frame.extract::<PyReadonlyArray2<'_, f32>>() {
            let $view = a.as_array();
            $body
        } else if let Ok(a) = $frame.extract::<PyReadonlyArray2<'_, f64>>() {
            let $view = a.as_array();
            $body
        } else {
            Err($crate::errors::invalid(
                "frame must be a 2D uint8, uint16, float32 or float64 array",
            ))
        }
    }};
}
pub(crate) use with_frame;

/// The frames as views of one pixel type.
pub(crate) enum Frames<'py> {
    U8(PyReadonlyArray2<'py, u8>, PyReadonlyArray2<'py, u8>),
    U16(PyReadonlyArray2<'py, u16>, PyReadonlyArray2<'py, u16>),
    F32(PyReadonlyArray2<'py, f32>, PyReadonlyArray2<'py, f32>),
    F64(PyReadonlyArray2<'py, f64>, PyReadonlyArray2<'py, f64>),
}

pub(crate) fn frames<'py>(a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>) -> PyResult<Frames<'py>> {
    fn both<'py, T: Element>(
        a: &Bound<'py, PyAny>,
        b: &Bound<'py, PyAny>,
    ) -> Option<(PyReadonlyArray2<'py, T>, PyReadonlyArray2<'py, T>)> {
        Some((a.extract().ok()?, b.extract().ok()?))
    }
    if let Some((x, y)) = both::<u16>(a, b) {
        return Ok(Frames::U16(x, y));
    }
    if let Some((x, y)) = both::<f32>(a, b) {
        return Ok(Frames::F32(x, y));
    }
    if let Some((x, y)) = both::<f64>(a, b) {
        return Ok(Frames::F64(x, y));
    }
    if let Some((x, y)) = both::<u8>(a, b) {
        return Ok(Frames::U8(x, y));
    }
    Err(invalid(
        "frame_a and frame_b must be 2D arrays of one dtype among uint8, uint16, float32, float64",
    ))
}

/// Run `f` on the frames' views with the GIL released.
pub(crate) fn with_frames<R: Send>(
    py: Python<'_>,
    fr: &Frames<'_>,
    f: impl Fn(&dyn Runner) -> Result<R, PyRspivErr> + Send + Sync,
) -> PyResult<R> {
    let res = match fr {
        Frames::U8(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::U16(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::F32(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
        Frames::F64(a, b) => {
            let (a, b) = (a.as_array(), b.as_array());
            py.detach(|| f(&(a, b)))
        }
    };
    Ok(res?)
}

/// Object-safe entry points over one frame pair of any pixel type.
pub(crate) trait Runner: Sync {
    fn particle_diameter(
        &self,
        window: (usize, usize),
        mask: Option<ArrayView2<'_, bool>>,
        backgrounds: Option<(ArrayView2<'_, f32>, ArrayView2<'_, f32>)>,
    ) -> Result<(f64, f64), PivError>;
    fn piv(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<PivField, PivError>;
    fn piv_at(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        pred: Predictor<'_>,
        mask: Option<ArrayView2<'_, bool>>,
        windows: &[(usize, usize)],
        iterations: usize,
        s: &PivSettings,
    ) -> Result<PivField, PivError>;
    fn piv_final_points(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<(Option<PivField>, PivField), PivError>;
    fn method_one(
        &self,
        mapping: &Mapping,
        s: &PivSettings,
        object_shape: Option<(usize, usize)>,
        mask: Option<ArrayView2<'_, bool>>,
        zero_fill: ZeroFill,
    ) -> Result<PivField, CorrectionError>;
    fn method_two(
        &self,
        mapping: &Mapping,
        s: &PivSettings,
        mode: DisplacementMapping,
        object_shape: Option<(usize, usize)>,
        mask: Option<ArrayView2<'_, bool>>,
    ) -> Result<PivField, CorrectionError>;
    fn ensemble_add(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        win: &piv_core::ensemble::Windows<'_>,
        field: Option<&piv_core::GridField>,
        interp: piv_core::Interpolation,
        auto: bool,
        acc: &mut [f64],
    ) -> Result<usize, PivError>;
    fn pixel_add(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        band: &piv_core::ensemble_pixel::PixelBand<'_>,
        interp: piv_core::Interpolation,
        auto: bool,
        acc: &mut [f64],
    ) -> Result<usize, PivError>;
}

impl<T: Pixel> Runner for (ArrayView2<'_, T>, ArrayView2<'_, T>) {
    fn particle_diameter(
        &self,
        window: (usize, usize),
        mask: Option<ArrayView2<'_, bool>>,
        backgrounds: Option<(ArrayView2<'_, f32>, ArrayView2<'_, f32>)>,
    ) -> Result<(f64, f64), PivError> {
        piv_core::particle_size::measure(self.0, self.1, window, mask, backgrounds)
    }
    fn piv(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<PivField, PivError> {
        piv_core::piv(self.0, self.1, mask, s)
    }
    fn piv_at(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        pred: Predictor<'_>,
        mask: Option<ArrayView2<'_, bool>>,
        windows: &[(usize, usize)],
        iterations: usize,
        s: &PivSettings,
    ) -> Result<PivField, PivError> {
        piv_core::piv_at(self.0, self.1, x, y, pred, mask, windows, iterations, s)
    }
    fn piv_final_points(
        &self,
        x: ArrayView2<'_, f64>,
        y: ArrayView2<'_, f64>,
        mask: Option<ArrayView2<'_, bool>>,
        s: &PivSettings,
    ) -> Result<(Option<PivField>, PivField), PivError> {
        piv_core::piv_with_final_points(self.0, self.1, x, y, mask, s)
    }
    fn method_one(
        &self,
        mapping: &Mapping,
        s: &PivSettings,
        object_shape: Option<(usize, usize)>,
        mask: Option<ArrayView2<'_, bool>>,
        zero_fill: ZeroFill,
    ) -> Result<PivField, CorrectionError> {
        correction_core::method_one(self.0, self.1, mapping, s, object_shape, mask, zero_fill)
    }
    fn method_two(
        &self,
        mapping: &Mapping,
        s: &PivSettings,
        mode: DisplacementMapping,
        object_shape: Option<(usize, usize)>,
        mask: Option<ArrayView2<'_, bool>>,
    ) -> Result<PivField, CorrectionError> {
        correction_core::method_two(self.0, self.1, mapping, s, mode, object_shape, mask)
    }
    fn ensemble_add(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        win: &piv_core::ensemble::Windows<'_>,
        field: Option<&piv_core::GridField>,
        interp: piv_core::Interpolation,
        auto: bool,
        acc: &mut [f64],
    ) -> Result<usize, PivError> {
        piv_core::ensemble::accumulate(self.0, self.1, mask, win, field, interp, auto, acc)
    }
    fn pixel_add(
        &self,
        mask: Option<ArrayView2<'_, bool>>,
        band: &piv_core::ensemble_pixel::PixelBand<'_>,
        interp: piv_core::Interpolation,
        auto: bool,
        acc: &mut [f64],
    ) -> Result<usize, PivError> {
        piv_core::ensemble_pixel::accumulate(self.0, self.1, mask, band, interp, auto, acc)
    }
}
