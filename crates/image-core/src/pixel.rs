//! The one pixel trait of rspiv: the numeric types an image may hold, read without converting
//! the whole image.

/// Memory layout of a pixel type (lets SIMD kernels pick their loads; `#[doc(hidden)]` users
/// only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelKind {
    U8,
    U16,
    F32,
    F64,
}

/// A pixel type: `u8`, `u16` (camera counts), `f32` or `f64` (conditioned or dewarped images).
pub trait Pixel: Copy + Send + Sync + 'static {
    /// The type's layout.
    const KIND: PixelKind;
    /// The value as `f32` (interpolation and correlation work in `f32`).
    fn to_f32(self) -> f32;
    /// The value as `f64` (marker fits work in `f64`).
    fn to_f64(self) -> f64;
    /// `false` for NaN or infinite values (always `true` for integers).
    #[inline(always)]
    fn is_finite_px(self) -> bool {
        true
    }
}

/// `Pixel` for a numeric type; `$finite` decides `is_finite_px` (integers: always true).
macro_rules! pixel {
    ($t:ty, $kind:ident, $finite:expr) => {
        impl Pixel for $t {
            const KIND: PixelKind = PixelKind::$kind;
            #[inline(always)]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn is_finite_px(self) -> bool {
                let finite: fn($t) -> bool = $finite;
                finite(self)
            }
        }
    };
}

pixel!(u8, U8, |_| true);
pixel!(u16, U16, |_| true);
pixel!(f32, F32, f32::is_finite);
pixel!(f64, F64, f64::is_finite);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_and_finiteness() {
        assert_eq!(200u8.to_f32(), 200.0);
        assert_eq!(65535u16.to_f64(), 65535.0);
        assert_eq!(0.25f32.to_f64(), 0.25);
        assert_eq!(1.5f64.to_f32(), 1.5);
        assert!(3u16.is_finite_px());
        assert!(!f32::NAN.is_finite_px());
        assert!(!f64::INFINITY.is_finite_px());
        assert_eq!(<u16 as Pixel>::KIND, PixelKind::U16);
    }
}
