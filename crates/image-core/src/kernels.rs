//! Separable interpolation kernels and their border helpers.
//!
//! A kernel of `N` taps gives the weights of the samples `floor - (N/2 - 1) ..= floor + N/2` of
//! a position whose fractional part is `t` in `[0, 1)`:
//!
//! - [`keys_weights`]: Keys (1981) cubic convolution, `a = -0.5`, on the pixels themselves
//!   (third-order accurate: quadratics are reproduced; exact `(0, 1, 0, 0)` at `t = 0`);
//! - [`bspline_weights`], [`bspline5_weights`]: cubic and quintic B-splines, applied to the
//!   prefiltered coefficients of [`crate::spline`] (interpolating: exact at the pixels).
//!
//! Weights are `f32` (relative rounding ~1e-7, far below any 12-16 bit intensity step).

/// A separable `N`-tap interpolation kernel (see the module docs). Samplers take any
/// `Fn(f32) -> [f32; N]`; pass the kernel functions themselves so that they are inlined.
pub type Weights<const N: usize> = fn(f32) -> [f32; N];

/// Keys cubic-convolution weights (a = -0.5) for the neighbours at offsets -1, 0, 1, 2 of a
/// sample at fractional position `t` in `[0, 1)`.
#[inline(always)]
pub fn keys_weights(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// The Keys kernel (a = -0.5) itself, `W(s)` for a signed distance `s` in px (`f64`, for
/// reference computations).
pub fn keys_kernel(s: f64) -> f64 {
    let s = s.abs();
    if s < 1.0 {
        (1.5 * s - 2.5) * s * s + 1.0
    } else if s < 2.0 {
        ((-0.5 * s + 2.5) * s - 4.0) * s + 2.0
    } else {
        0.0
    }
}

/// Cubic B-spline interpolation weights for the four neighbours floor-1 .. floor+2 of a
/// position with fractional part `t`; apply them to the cubic coefficients of
/// [`crate::spline`].
#[inline(always)]
pub fn bspline_weights(t: f32) -> [f32; 4] {
    const K: f32 = 1.0 / 6.0;
    let t2 = t * t;
    let t3 = t2 * t;
    let s = 1.0 - t;
    [
        s * s * s * K,
        (3.0 * t3 - 6.0 * t2 + 4.0) * K,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) * K,
        t3 * K,
    ]
}

/// Quintic B-spline interpolation weights for the six neighbours floor-2 .. floor+3 of a
/// position with fractional part `t`; apply them to the quintic coefficients of
/// [`crate::spline`]. (`120 beta5(t - k)` for k = -2 ..= 3 as polynomials in `t`, Horner form.)
#[inline(always)]
pub fn bspline5_weights(t: f32) -> [f32; 6] {
    const K: f32 = 1.0 / 120.0;
    let s = 1.0 - t;
    let (t2, s2) = (t * t, s * s);
    let w1 = ((((5.0 * t - 20.0) * t + 20.0) * t + 20.0) * t - 50.0) * t + 26.0;
    let w2 = t2 * (t2 * (30.0 - 10.0 * t) - 60.0) + 66.0;
    let w3 = ((((10.0 * t - 20.0) * t - 20.0) * t + 20.0) * t + 50.0) * t + 26.0;
    let w4 = ((((5.0 - 5.0 * t) * t + 10.0) * t + 10.0) * t + 5.0) * t + 1.0;
    [
        s2 * s2 * s * K,
        w1 * K,
        w2 * K,
        w3 * K,
        w4 * K,
        t2 * t2 * t * K,
    ]
}

/// `floor(x)` as an integer (without a libm call; saturating, 0 for NaN).
#[inline(always)]
pub fn floor_i(x: f64) -> isize {
    let i = x as isize;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// The whole number `f` (a floor, say) as `isize`, exactly for `|f| <= 2^50`; beyond, and for
/// NaN, clamped to +-2^50. By the bits of `f + 1.5 * 2^52`, whose mantissa then holds `f`: an
/// add and an integer subtract that vectorise, where AVX2 has no packed f64 -> i64 conversion
/// (a saturating `as`, and [`floor_i`], go lane by lane).
#[inline(always)]
pub fn int_of_whole(f: f64) -> isize {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52: ulp 1 over 2^52 +- 2^51
    const LIM: f64 = 1_125_899_906_842_624.0; // 2^50

    // not `clamp`: that keeps a NaN, whose bits would give an arbitrary integer
    #[allow(clippy::manual_clamp)]
    let c = f.max(-LIM).min(LIM);
    ((c + MAGIC).to_bits() as i64 - MAGIC.to_bits() as i64) as isize
}

/// Whole-sample symmetric index into `n` samples: ... 2 1 | 0 1 .. n-1 | n-2 n-3 ...
#[inline(always)]
pub fn mirror(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let k = i.rem_euclid(period);
    if k >= n as isize {
        (period - k) as usize
    } else {
        k as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn int_of_whole_is_the_integer_within_its_range_and_clamps_beyond() {
        let lim = (1i64 << 50) as f64;
        for f in [
            0.0,
            -0.0,
            1.0,
            -1.0,
            7.0,
            -8.0,
            123_456_789.0,
            -lim,
            lim,
            lim - 1.0,
        ] {
            assert_eq!(int_of_whole(f), f as isize, "{f}");
        }
        assert_eq!(int_of_whole(1e300), 1isize << 50);
        assert_eq!(int_of_whole(-1e300), -(1isize << 50));
        assert_eq!(int_of_whole(f64::NAN).abs(), 1isize << 50);
    }

    #[test]
    fn keys_weights_match_kernel_and_partition_unity() {
        for k in 0..=20 {
            let t = k as f64 / 20.0 * 0.999;
            let w = keys_weights(t as f32);
            let exact = [
                keys_kernel(t + 1.0),
                keys_kernel(t),
                keys_kernel(t - 1.0),
                keys_kernel(t - 2.0),
            ];
            for i in 0..4 {
                assert!((w[i] as f64 - exact[i]).abs() < 1e-6, "t={t} i={i}");
            }
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
        assert_eq!(keys_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn keys_weights_sum_to_one_and_interpolate() {
        for k in 0..10 {
            let t = k as f32 / 10.0;
            let w = keys_weights(t);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            // reproduces a linear function exactly
            let lin: f32 = -w[0] + w[2] + w[3] * 2.0;
            assert!((lin - t).abs() < 1e-6);
        }
        assert_eq!(keys_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn floor_and_mirror() {
        assert_eq!(floor_i(-0.5), -1);
        assert_eq!(floor_i(2.0), 2);
        assert_eq!(floor_i(f64::NAN), 0);
        let idx: Vec<usize> = (-3..8).map(|i| mirror(i, 4)).collect();
        assert_eq!(idx, vec![3, 2, 1, 0, 1, 2, 3, 2, 1, 0, 1]);
        assert_eq!(mirror(-5, 1), 0);
    }
}
