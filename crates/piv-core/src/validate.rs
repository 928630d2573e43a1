//! Vector validation: normalised median test (Westerweel & Scarano 2005) and replacement of
//! rejected vectors from their valid neighbours.

use ndarray::parallel::prelude::*;
use ndarray::{Array2, Axis};

/// Fewest usable neighbours for the median test.
pub const MIN_NEIGHBOURS: usize = 6;

/// Normalised median test over the 3 x 3 neighbourhood. `usable[j, i]` says which vectors may
/// serve as neighbours (and be tested). A vector fails when, for u or v,
/// `|x0 - median(x_n)| / (median(|x_n - median(x_n)|) + eps) > threshold`.
/// Vectors with fewer than 6 usable neighbours (image edges and corners, holes) are not tested:
/// a one-sided neighbourhood in a strong gradient has a near-zero residual median and would
/// reject good vectors. Returns `true` = outlier.
pub fn median_test(
    u: &Array2<f64>,
    v: &Array2<f64>,
    usable: &Array2<bool>,
    eps: f64,
    threshold: f64,
) -> Array2<bool> {
    let mut out = Array2::from_elem(u.dim(), false);
    // rows in parallel: each vector's test reads only the inputs
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(j, mut row)| {
            for (i, o) in row.iter_mut().enumerate() {
                if usable[[j, i]] {
                    let at = (u[[j, i]], v[[j, i]]);
                    *o = residual(u, v, usable, (j, i), at, eps).is_some_and(|r| r > threshold);
                }
            }
        });
    out
}

/// The normalised median residual (the larger of u's and v's) of a candidate vector `(cu, cv)`
/// at `(j, i)` against the usable vectors of its 3 x 3 neighbourhood, as in [`median_test`];
/// `None` with fewer than [`MIN_NEIGHBOURS`] usable neighbours.
pub fn residual(
    u: &Array2<f64>,
    v: &Array2<f64>,
    usable: &Array2<bool>,
    (j, i): (usize, usize),
    (cu, cv): (f64, f64),
    eps: f64,
) -> Option<f64> {
    let (ny, nx) = u.dim();
    let mut nu = [0.0f64; 8];
    let mut nv = [0.0f64; 8];
    let mut res = [0.0f64; 8];
    let mut k = 0;
    for jj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
        for ii in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
            if (jj, ii) != (j, i) && usable[[jj, ii]] {
                nu[k] = u[[jj, ii]];
                nv[k] = v[[jj, ii]];
                k += 1;
            }
        }
    }
    if k < MIN_NEIGHBOURS {
        return None;
    }
    let ru = normalised_residual(cu, &mut nu[..k], &mut res[..k], eps);
    let rv = normalised_residual(cv, &mut nv[..k], &mut res[..k], eps);
    Some(ru.max(rv))
}

/// The median of the usable vectors of the 3 x 3 neighbourhood of `(j, i)` (itself excluded)
/// for `u` and for `v`; `None` with fewer than 3 of them.
pub fn neighbour_median(
    u: &Array2<f64>,
    v: &Array2<f64>,
    usable: &Array2<bool>,
    (j, i): (usize, usize),
) -> Option<(f64, f64)> {
    let (ny, nx) = u.dim();
    let mut nu = [0.0f64; 8];
    let mut nv = [0.0f64; 8];
    let mut k = 0;
    for jj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
        for ii in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
            if (jj, ii) != (j, i) && usable[[jj, ii]] {
                nu[k] = u[[jj, ii]];
                nv[k] = v[[jj, ii]];
                k += 1;
            }
        }
    }
    (k >= 3).then(|| (median(&mut nu[..k]), median(&mut nv[..k])))
}

/// The median of `x` (finite values), which it sorts. A full 3 x 3 neighbourhood (8 values,
/// the common case) goes through a sorting network (the 19 compare-exchanges of Knuth, TAOCP
/// 3, 5.3.4, optimal for 8) in registers, each a min and a max without a branch, where a
/// comparison sort mispredicts about every other comparison; the values only change places.
fn median(x: &mut [f64]) -> f64 {
    if let Ok(v) = <&mut [f64; 8]>::try_from(&mut *x) {
        let [mut a0, mut a1, mut a2, mut a3, mut a4, mut a5, mut a6, mut a7] = *v;
        macro_rules! cx {
            ($p:ident, $q:ident) => {
                let (p, q) = ($p, $q);
                $p = if q < p { q } else { p };
                $q = if q < p { p } else { q };
            };
        }
        cx!(a0, a1);
        cx!(a2, a3);
        cx!(a4, a5);
        cx!(a6, a7);
        cx!(a0, a2);
        cx!(a1, a3);
        cx!(a4, a6);
        cx!(a5, a7);
        cx!(a1, a2);
        cx!(a5, a6);
        cx!(a0, a4);
        cx!(a3, a7);
        cx!(a1, a5);
        cx!(a2, a6);
        cx!(a1, a4);
        cx!(a3, a6);
        cx!(a2, a4);
        cx!(a3, a5);
        cx!(a3, a4);
        *v = [a0, a1, a2, a3, a4, a5, a6, a7];
        return 0.5 * (a3 + a4);
    }
    x.sort_unstable_by(|a, b| a.total_cmp(b));
    let n = x.len();
    if n % 2 == 1 {
        x[n / 2]
    } else {
        0.5 * (x[n / 2 - 1] + x[n / 2])
    }
}

fn normalised_residual(x0: f64, nb: &mut [f64], res: &mut [f64], eps: f64) -> f64 {
    let m = median(nb);
    for (r, x) in res.iter_mut().zip(nb.iter()) {
        *r = (x - m).abs();
    }
    let rm = median(res);
    (x0 - m).abs() / (rm + eps)
}

/// Replace every vector with `good[j, i] == false` by the mean of its good 3 x 3 neighbours,
/// sweeping until all are filled (newly filled vectors count as good in the next sweep). With no
/// good vector at all the field is set to zero.
pub fn replace(u: &mut Array2<f64>, v: &mut Array2<f64>, good: &Array2<bool>) {
    let (ny, nx) = u.dim();
    let mut g = good.clone();
    if !g.iter().any(|&b| b) {
        u.fill(0.0);
        v.fill(0.0);
        return;
    }
    loop {
        let mut filled = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                if g[[j, i]] {
                    continue;
                }
                let (mut su, mut sv, mut n) = (0.0, 0.0, 0usize);
                for jj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
                    for ii in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
                        if g[[jj, ii]] {
                            su += u[[jj, ii]];
                            sv += v[[jj, ii]];
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    filled.push((j, i, su / n as f64, sv / n as f64));
                }
            }
        }
        if filled.is_empty() {
            break;
        }
        for (j, i, a, b) in filled {
            u[[j, i]] = a;
            v[[j, i]] = b;
            g[[j, i]] = true;
        }
    }
}

/// A field whose correlated windows have a median peak ratio below this is not taken for a
/// measurement ([`correlation_warning`]).
pub const MIN_MEDIAN_PEAK_RATIO: f64 = 1.3;

/// The one-line warning for a field whose frames do not correlate, from the peak ratios of
/// its windows (`0` or NaN: a window not correlated, being blank, masked or reaching outside
/// the frame); `None` when they correlate.
///
/// Frames that do not correlate (a wrong pairing, a missing laser pulse, frames of noise)
/// still give a highest peak in every window, and their random vectors, among neighbours as
/// random, pass the normalised median test about 60 % of the time. Their peak ratios are low
/// all over. Measured with the paper's passes (`python benches/real_data_checks.py`, table in
/// `benches/RESULTS.md`), the median over the correlated windows: 1.12-1.20 for camera noise,
/// a dark frame B, frame B shuffled and OpenPIV's `test2` paired wrongly; 2.97-6.53 for
/// OpenPIV's real recordings `test1`, `test2`, `test4`, `test5`, 1.37 for its `test3` (lit on
/// a third of the frame, the rest dark), 2.99-4.80 for synthetic particle images from one
/// particle per 32 x 8 px window to a noise of 0.3 of the particles' peak. The warning is
/// also given where the noise swamps the particles (1.14-1.20 at a noise of 0.45-0.6 of the
/// peak, where the median error of the 32 x 8 px vectors kept as valid is 0.6-1.6 px). With
/// no correlated window at all the frames are blank (or constant) wherever there are windows.
/// A displacement beyond the first pass's search range (half its window: 40 px with 64 x 64
/// px windows) looks the same to the correlation (median 1.24), and is warned about too.
pub fn correlation_warning(peak_ratio: impl IntoIterator<Item = f64>) -> Option<String> {
    let mut r: Vec<f64> = peak_ratio
        .into_iter()
        .filter(|p| p.is_finite() && *p > 0.0)
        .collect();
    if r.is_empty() {
        return Some(
            "no window could be correlated: the frames are blank or constant wherever the \
             windows are"
                .into(),
        );
    }
    let n = r.len();
    let (low, &mut hi, _) = r.select_nth_unstable_by(n / 2, f64::total_cmp);
    let median = if n % 2 == 1 {
        hi
    } else {
        0.5 * (hi + low.iter().copied().fold(f64::NEG_INFINITY, f64::max))
    };
    (median < MIN_MEDIAN_PEAK_RATIO).then(|| {
        format!(
            "the frames do not correlate: the median peak ratio of the {n} correlated windows \
             is {median:.2} (frames that do not correlate give 1.1-1.2, particle images about \
             3 or more): a wrong pairing, a missing laser pulse, frames of noise, or a \
             displacement beyond the first pass's search (half its window)?"
        )
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_sorting_network_sorts_eight_values() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for case in 0..20_000 {
            // ties and repeated values as well as distinct ones
            let mut x: [f64; 8] = std::array::from_fn(|_| {
                let r: f64 = rng.random();
                if case % 2 == 0 {
                    (r * 4.0).floor()
                } else {
                    r - 0.5
                }
            });
            let mut want = x;
            want.sort_unstable_by(|a, b| a.total_cmp(b));
            let m = super::median(&mut x);
            assert_eq!(x, want, "{case}");
            assert_eq!(m, 0.5 * (want[3] + want[4]));
        }
    }

    use super::*;

    #[test]
    fn single_outlier_is_found_and_replaced() {
        let mut u = Array2::from_shape_fn((5, 6), |(j, i)| 0.1 * i as f64 + 0.05 * j as f64);
        let mut v = Array2::from_elem((5, 6), 1.0);
        u[[2, 3]] = 5.0;
        let usable = Array2::from_elem((5, 6), true);
        let bad = median_test(&u, &v, &usable, 0.1, 2.0);
        assert_eq!(bad.iter().filter(|&&b| b).count(), 1);
        assert!(bad[[2, 3]]);
        let good = bad.mapv(|b| !b);
        replace(&mut u, &mut v, &good);
        assert!((u[[2, 3]] - (0.3 + 0.1)).abs() < 1e-12, "{}", u[[2, 3]]);
    }

    #[test]
    fn correlation_warning_reads_the_median_peak_ratio() {
        // no window correlated (0: blank; NaN: masked)
        let w = correlation_warning([0.0, f64::NAN, 0.0]).unwrap();
        assert!(w.starts_with("no window could be correlated"), "{w}");
        // the median of the correlated windows only: 1.1, 1.2, 1.25 -> 1.2
        let w = correlation_warning([0.0, 1.25, 1.1, f64::NAN, 1.2]).unwrap();
        assert!(w.contains("of the 3 correlated windows is 1.20"), "{w}");
        assert!(!w.contains('\n'));
        // an even count: the mean of the middle two, 1.28 and 1.34 -> 1.31, above the limit
        assert_eq!(correlation_warning([1.1, 1.28, 1.34, 4.0]), None);
        // 1.1, 1.2, 1.3, 1.35 -> 1.25: warned
        assert!(correlation_warning([1.35, 1.3, 1.1, 1.2]).is_some());
        // particle images, the capped ratio of identical frames
        assert_eq!(correlation_warning([3.0, 1000.0, 1.05, 2.5, 0.0]), None);
        assert_eq!(correlation_warning([MIN_MEDIAN_PEAK_RATIO]), None);
    }

    #[test]
    fn replace_fills_holes() {
        let mut u = Array2::from_elem((4, 4), 2.0);
        let mut v = Array2::from_elem((4, 4), -1.0);
        let mut good = Array2::from_elem((4, 4), false);
        good[[0, 0]] = true;
        u[[3, 3]] = f64::NAN;
        replace(&mut u, &mut v, &good);
        assert!(u.iter().all(|&x| x == 2.0) && v.iter().all(|&x| x == -1.0));
    }
}
