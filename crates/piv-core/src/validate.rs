//! Vector validation: normalised median test (Westerweel & Scarano 2005) and replacement of
//! rejected vectors from their valid neighbours.

use ndarray::parallel::prelude::*;
use ndarray::{Array2, ArrayView2, Axis};

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

/// The median of `x` (finite values, at least one), which it reorders. A full 3 x 3
/// neighbourhood (8 values,
/// the common case) goes through a sorting network (the 19 compare-exchanges of Knuth, TAOCP
/// 3, 5.3.4, optimal for 8) in registers, each a min and a max without a branch, where a
/// comparison sort mispredicts about every other comparison; the values only change places
/// (and end sorted). Other lengths (a field's peak ratios, [`correlation_check`]) go through a
/// selection, linear in `n`.
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
    let n = x.len();
    let (low, &mut mid, _) = x.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        mid
    } else {
        0.5 * (low.iter().copied().fold(f64::NEG_INFINITY, f64::max) + mid)
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
/// measurement ([`correlation_check`]); a window under it counts as uncorrelated in the local
/// test.
pub const MIN_MEDIAN_PEAK_RATIO: f64 = 1.3;

/// Half-width of the neighbourhood of [`correlation_check`]'s local test (5 x 5 vectors).
pub const LOCAL_HALF_WIDTH: usize = 2;

/// Above this fraction of its valid vectors in uncorrelated neighbourhoods a field is partly
/// uncorrelated ([`correlation_check`]).
pub const MAX_UNCORRELATED_FRACTION: f64 = 0.1;

/// Above this fraction of its windows not masked held too little signal to be correlated (blank
/// by the multipass's rule: no particle images, or too few in the window) a field is partly
/// uncorrelated ([`correlation_check`]): their vectors are only interpolated from their
/// neighbours. Measured with OpenPIV's recordings (`test1`, `test2`, `test4`-`test6`, passes
/// 64 -> 32 -> 32 x 32, 32 x 8 or 16 x 16, inside the [`BLANK_EDGE`] outer rings): 0-0.4 %
/// where the windows hold enough particle images, 29.2 % for `test5` and `test6` at 16 x 16
/// px (31.2 % for `test5`'s pattern 10; about one particle image per window), `python
/// benches/real_data_checks.py`; 0.4-0.5 % for the 47 MP boundary layer of `rspiv.demo`'s
/// scene (uncorrected, Method I and II).
pub const MAX_BLANK_FRACTION: f64 = 0.2;

/// Above this fraction of its vectors (not masked, inside the [`BLANK_EDGE`] outer rings) only
/// interpolated from their neighbours, rejected by the validation or from windows too blank to
/// correlate, a field is partly uncorrelated ([`correlation_check`]): where the median test
/// rejects that many, the vectors it keeps are wrong as well, more often than their neighbours
/// tell. Measured (passes 64 -> 32 -> 32 x 32, 32 x 8 or 16 x 16 px, `python
/// benches/real_data_checks.py`): 0.5-4.4 % for OpenPIV's recordings where their windows hold
/// enough particle images (`test1`, `test2` pairs 0 and 1, `test4`, `test5` patterns 1 and 10,
/// `test6`), 0.4-0.5 % for the 47 MP boundary layer of `rspiv.demo`'s scene (uncorrected,
/// symmetric, Method II); for synthetic particle images with too few per window (`python
/// benches/bench_accuracy.py --only seeding`) 13.5-51 % where the RMS error of the vectors
/// kept is 0.3-3.5 px (0.001-0.004 particles/px, against 0.01-0.05 px with enough particle
/// images). A field a tenth to a fifth of whose windows are too blank (under
/// [`MAX_BLANK_FRACTION`]) is said so by this count.
pub const MAX_REPLACED_FRACTION: f64 = 0.1;

/// The outer rings of a grid that [`correlation_check`] leaves out of its count of windows too
/// blank to correlate: a window there fails as well when its displaced half reaches outside
/// the frame (measured on 256 x 320 px pairs: the outer ring for displacements up to a grid
/// step, the two outer rings for 20 px with 16 x 16 px windows at a step of 8 px).
pub const BLANK_EDGE: usize = 2;

/// What the peak ratios of a field say about its frames' correlation ([`correlation_check`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Correlation {
    /// The frames correlate.
    Fine,
    /// The frames do not correlate, or no window could be correlated: the field is no
    /// measurement. The one-line message says what was seen.
    Uncorrelated(String),
    /// The frames correlate, but too many valid vectors lie where they hardly do (a part
    /// without particle images, or with too few per window), too many windows were too blank
    /// to be correlated, or too many vectors are only interpolated. The one-line message
    /// says what was seen.
    Partly(String),
}

impl Correlation {
    /// The one-line warning, `None` for [`Correlation::Fine`].
    pub fn message(&self) -> Option<&str> {
        match self {
            Correlation::Fine => None,
            Correlation::Uncorrelated(m) | Correlation::Partly(m) => Some(m),
        }
    }
}

/// Whether a field's frames correlate, from the peak ratios of its windows (`0` or NaN: a
/// window not correlated, being blank, masked or reaching outside the frame), its `valid`
/// flags and its `masked` flags (same shape; rows of the grid along axis 0; `None`: nothing
/// masked).
///
/// Frames that do not correlate (a wrong pairing, a missing laser pulse, frames of noise)
/// still give a highest peak in every window, and their random vectors, among neighbours as
/// random, pass the normalised median test about 60 % of the time. Their peak ratios are low
/// all over. Measured with the paper's passes (`python benches/real_data_checks.py`, table in
/// `benches/RESULTS.md`), the median over the correlated windows: 1.12-1.20 for camera noise,
/// a dark frame B, frame B shuffled and OpenPIV's `test2` paired wrongly; 2.97-6.53 for
/// OpenPIV's real recordings `test1`, `test2`, `test4`, `test5`, 1.37 for its `test3` (lit on
/// a third of the frame, the rest dark), 2.99-4.80 for synthetic particle images from one
/// particle per 32 x 8 px window to a noise of 0.3 of the particles' peak. Under
/// [`MIN_MEDIAN_PEAK_RATIO`] the field is [`Correlation::Uncorrelated`]; so is it where the
/// noise swamps the particles (1.14-1.20 at a noise of 0.45-0.6 of the peak, where the median
/// error of the 32 x 8 px vectors kept as valid is 0.6-1.6 px), with a displacement beyond the
/// first pass's search range (half its window: 1.24 for 40 px with 64 x 64 px windows), and
/// with no correlated window at all (blank or constant frames).
///
/// `local`: on a grid, also the local test: a valid vector whose 5 x 5 neighbourhood
/// ([`LOCAL_HALF_WIDTH`]) has more than half of its correlated windows under
/// [`MIN_MEDIAN_PEAK_RATIO`] lies where the frames hardly correlate (an unlit part, outside
/// the light sheet, a shadow, or too few particle images per window); above
/// [`MAX_UNCORRELATED_FRACTION`] of the valid vectors so the field is [`Correlation::Partly`]
/// (measured: 0-2.6 % for the real recordings and the synthetic particle images above, 25.7 %
/// for a particle pair whose right 40 % is camera noise only, 32.6 % for `test3`, whose lit
/// part hardly correlates either: its windows' median peak ratio is 1.24-1.56 region by region
/// with 32 x 8 px windows, 1.5 with 32 x 32 px). Box counts over summed-area tables: linear in the vectors.
///
/// Last, with or without `local`: more than [`MAX_BLANK_FRACTION`] of the windows not masked
/// not correlated (too little signal) is [`Correlation::Partly`] too (the local test's message
/// first when both hold); the grid's [`BLANK_EDGE`] outer rings are left out of that count
/// (a grid without an inside is not judged). No window correlated inside them is
/// [`Correlation::Uncorrelated`], whatever a stray window at the edge gave. Then, inside the
/// same rings, more than [`MAX_REPLACED_FRACTION`] of the vectors not masked only interpolated
/// (the correlated ones the validation rejected, not `valid`, and those too blank to
/// correlate) is [`Correlation::Partly`]: too few particle images per window, or a
/// displacement that varies too much across one.
pub fn correlation_check(
    peak_ratio: ArrayView2<'_, f64>,
    valid: ArrayView2<'_, bool>,
    masked: Option<ArrayView2<'_, bool>>,
    local: bool,
) -> Correlation {
    let correlated = |p: f64| p.is_finite() && p > 0.0;
    let check = uncorrelated_or_weak(peak_ratio, valid, local, correlated);
    if check != Correlation::Fine {
        return check;
    }
    // the windows not masked that could not be correlated (masks of another shape: none),
    // inside the grid's BLANK_EDGE outer rings
    let masked = masked.filter(|m| m.dim() == peak_ratio.dim());
    let at = |k: (usize, usize)| masked.as_ref().is_some_and(|m| m[k]);
    let (ny, nx) = peak_ratio.dim();
    let e = BLANK_EDGE;
    // valid flags of another shape: none rejected
    let rejected_at = |k: (usize, usize)| valid.dim() == peak_ratio.dim() && !valid[k];
    let (mut open, mut blank, mut rejected) = (0usize, 0usize, 0usize);
    for j in e..ny.saturating_sub(e) {
        for i in e..nx.saturating_sub(e) {
            if !at((j, i)) {
                open += 1;
                if correlated(peak_ratio[[j, i]]) {
                    rejected += rejected_at((j, i)) as usize;
                } else {
                    blank += 1;
                }
            }
        }
    }
    if open > 0 && blank == open {
        // a stray window at the edge may correlate: still no measurement
        return Correlation::Uncorrelated(NO_WINDOW.into());
    }
    let fraction = blank as f64 / open.max(1) as f64;
    if fraction > MAX_BLANK_FRACTION {
        return Correlation::Partly(format!(
            "{:.0} % of the {open} windows (not masked) held too little signal to be correlated \
             (no particle images, or too few per window) and their vectors are only \
             interpolated from their neighbours: use larger windows, or mask where there is no \
             signal",
            100.0 * fraction
        ));
    }
    let fraction = (rejected + blank) as f64 / open.max(1) as f64;
    if fraction > MAX_REPLACED_FRACTION {
        return Correlation::Partly(format!(
            "{:.0} % of the {open} vectors (not masked) are only interpolated from their \
             neighbours ({rejected} rejected by the validation, {blank} from windows too blank \
             to correlate; real recordings that correlate: under 5 %): too few particle images \
             per window, a part without signal, or a displacement that varies too much across \
             a window, and the vectors kept are as suspect: use larger windows, or mask where \
             there is no signal",
            100.0 * fraction
        ));
    }
    Correlation::Fine
}

/// What [`correlation_check`] says when no window could be correlated (inside the grid's
/// [`BLANK_EDGE`] outer rings, or at all).
const NO_WINDOW: &str = "no window could be correlated: the frames are blank or constant \
     wherever the windows are, or their particle images too sparse on a background without \
     noise (under three quarters of each window carries signal)";

/// The whole field's test and the local one of [`correlation_check`].
fn uncorrelated_or_weak(
    peak_ratio: ArrayView2<'_, f64>,
    valid: ArrayView2<'_, bool>,
    local: bool,
    correlated: impl Fn(f64) -> bool,
) -> Correlation {
    let mut r: Vec<f64> = peak_ratio
        .iter()
        .copied()
        .filter(|&p| correlated(p))
        .collect();
    if r.is_empty() {
        return Correlation::Uncorrelated(NO_WINDOW.into());
    }
    let n = r.len();
    let median = median(&mut r);
    if median < MIN_MEDIAN_PEAK_RATIO {
        return Correlation::Uncorrelated(format!(
            "the frames do not correlate: the median peak ratio of the {n} correlated windows \
             is {median:.2} (frames that do not correlate give 1.1-1.25, particle images about \
             3 or more): a wrong pairing, a missing laser pulse, frames of noise, or a \
             displacement beyond the first pass's search (half its window)?"
        ));
    }
    if !local || peak_ratio.dim() != valid.dim() {
        return Correlation::Fine;
    }
    // summed-area tables of the correlated windows and of those under the limit
    let (ny, nx) = peak_ratio.dim();
    let mut all = vec![0u32; (ny + 1) * (nx + 1)];
    let mut weak = vec![0u32; (ny + 1) * (nx + 1)];
    for j in 0..ny {
        let (mut ra, mut rw) = (0u32, 0u32);
        for i in 0..nx {
            let p = peak_ratio[[j, i]];
            ra += correlated(p) as u32;
            rw += (correlated(p) && p < MIN_MEDIAN_PEAK_RATIO) as u32;
            let k = (j + 1) * (nx + 1) + i + 1;
            all[k] = all[k - nx - 1] + ra;
            weak[k] = weak[k - nx - 1] + rw;
        }
    }
    let boxed = |t: &[u32], (j0, j1, i0, i1): (usize, usize, usize, usize)| {
        t[j1 * (nx + 1) + i1] + t[j0 * (nx + 1) + i0]
            - t[j0 * (nx + 1) + i1]
            - t[j1 * (nx + 1) + i0]
    };
    let h = LOCAL_HALF_WIDTH;
    let (mut nv, mut inside) = (0usize, 0usize);
    for ((j, i), &ok) in valid.indexed_iter() {
        if !ok {
            continue;
        }
        nv += 1;
        let b = (
            j.saturating_sub(h),
            (j + h + 1).min(ny),
            i.saturating_sub(h),
            (i + h + 1).min(nx),
        );
        inside += (2 * boxed(&weak, b) > boxed(&all, b)) as usize;
    }
    let fraction = inside as f64 / nv.max(1) as f64;
    if fraction > MAX_UNCORRELATED_FRACTION {
        return Correlation::Partly(format!(
            "{:.0} % of the {nv} valid vectors lie where the frames hardly correlate (most \
             windows of their 5 x 5 neighbourhood have a peak ratio under \
             {MIN_MEDIAN_PEAK_RATIO}): a part without particle images (unlit, outside the light \
             sheet, a shadow?) or with too few per window gives random vectors that pass the \
             median test; mask it, or use larger windows",
            100.0 * fraction
        ));
    }
    Correlation::Fine
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
    fn correlation_check_reads_the_median_peak_ratio() {
        let whole = |pr: &[f64]| {
            let a = Array2::from_shape_vec((1, pr.len()), pr.to_vec()).unwrap();
            let v = Array2::from_elem(a.dim(), true);
            correlation_check(a.view(), v.view(), None, false)
        };
        // no window correlated (0: blank; NaN: masked)
        let c = whole(&[0.0, f64::NAN, 0.0]);
        assert!(matches!(c, Correlation::Uncorrelated(_)), "{c:?}");
        assert!(c
            .message()
            .unwrap()
            .starts_with("no window could be correlated"));
        // the median of the correlated windows only: 1.1, 1.2, 1.25 -> 1.2
        let c = whole(&[0.0, 1.25, 1.1, f64::NAN, 1.2]);
        let m = c.message().unwrap();
        assert!(m.contains("of the 3 correlated windows is 1.20"), "{m}");
        assert!(!m.contains('\n'));
        // an even count: the mean of the middle two, 1.28 and 1.34 -> 1.31, above the limit
        assert_eq!(whole(&[1.1, 1.28, 1.34, 4.0]), Correlation::Fine);
        // 1.1, 1.2, 1.3, 1.35 -> 1.25: warned
        assert!(matches!(
            whole(&[1.35, 1.3, 1.1, 1.2]),
            Correlation::Uncorrelated(_)
        ));
        // particle images, the capped ratio of identical frames
        assert_eq!(whole(&[3.0, 1000.0, 1.05, 2.5, 0.0]), Correlation::Fine);
        assert_eq!(whole(&[MIN_MEDIAN_PEAK_RATIO]), Correlation::Fine);
    }

    #[test]
    fn correlation_check_finds_a_region_that_does_not_correlate() {
        // a 10 x 20 grid: ratio 3 on the left, 1.1 on the right `c` columns, all valid
        let field = |c: usize| {
            let pr = Array2::from_shape_fn((10, 20), |(_, i)| if i >= 20 - c { 1.1 } else { 3.0 });
            (pr, Array2::from_elem((10, 20), true))
        };
        // 6 columns of 20 (14-19): the 5 x 5 neighbourhood of column 14 holds columns 12-16,
        // 3 of 5 under the limit: a majority; 13 holds 2 of 5: not. Columns 14-19: 30 %
        let (pr, v) = field(6);
        let c = correlation_check(pr.view(), v.view(), None, true);
        let m = c.message().unwrap_or_default().to_string();
        assert!(matches!(c, Correlation::Partly(_)), "{c:?}");
        assert!(m.starts_with("30 % of the 200 valid vectors"), "{m}");
        // the same without the local test; with the weak vectors flagged invalid the local
        // test has nothing to say, the count of rejected vectors does (columns 14-17 of the
        // inside's 2-17: 24 of 96)
        assert_eq!(
            correlation_check(pr.view(), v.view(), None, false),
            Correlation::Fine
        );
        let v2 = Array2::from_shape_fn((10, 20), |(_, i)| i < 14);
        let c = correlation_check(pr.view(), v2.view(), None, true);
        let m = c.message().unwrap_or_default().to_string();
        assert!(
            m.starts_with("25 % of the 96 vectors (not masked) are only interp"),
            "{m}"
        );
        // 2 columns of 20 (18, 19): column 19 holds 17-19, 2 of 3 under: a majority; 18 holds
        // 16-19, 2 of 4: not -> 5 %: fine
        let (pr, v) = field(2);
        assert_eq!(
            correlation_check(pr.view(), v.view(), None, true),
            Correlation::Fine
        );
    }

    #[test]
    fn correlation_check_counts_the_windows_too_blank_to_correlate() {
        // a 12 x 12 grid of well correlated windows (ratio 3), its inside (the 8 x 8 windows
        // past the two outer rings) with `n` blank ones (0) spread over it
        let inside = |(j, i): (usize, usize)| (2..10).contains(&j) && (2..10).contains(&i);
        let field = |n: usize| {
            Array2::from_shape_fn((12, 12), |(j, i)| {
                let k = (j.saturating_sub(2) * 8 + i.saturating_sub(2)) * 5 % 64;
                if inside((j, i)) && k < n {
                    0.0
                } else {
                    3.0
                }
            })
        };
        let check = |pr: &Array2<f64>, m: Option<&Array2<bool>>, local: bool| {
            let valid = pr.mapv(|p| p > 0.0);
            correlation_check(pr.view(), valid.view(), m.map(|m| m.view()), local)
        };
        let blank = |pr: &Array2<f64>| pr.iter().filter(|&&p| p == 0.0).count();
        assert_eq!(blank(&field(12)), 12);
        // 6 of 64 (9 %): fine; 12 (19 %): their vectors are only interpolated, said so (the
        // count of all interpolated vectors); 14 (22 %): said so as too blank, with or without
        // the local test
        assert_eq!(check(&field(6), None, true), Correlation::Fine);
        let m = check(&field(12), None, true).message().unwrap().to_string();
        assert!(
            m.starts_with("19 % of the 64 vectors (not masked) are only interp"),
            "{m}"
        );
        for local in [true, false] {
            let c = check(&field(14), None, local);
            assert!(matches!(c, Correlation::Partly(_)), "{c:?}");
            let m = c.message().unwrap();
            assert!(m.starts_with("22 % of the 64 windows (not masked)"), "{m}");
            assert!(!m.contains('\n'));
        }
        // the outer rings are not counted (their windows may reach outside the frame)
        let mut pr = field(6);
        pr.indexed_iter_mut()
            .filter(|(k, _)| !inside(*k))
            .for_each(|(_, p)| *p = 0.0);
        assert_eq!(blank(&pr), 6 + 144 - 64);
        assert_eq!(check(&pr, None, true), Correlation::Fine);
        // nor the masked windows: masking 8 inside windows that correlate leaves 12 of 56
        let pr = field(12);
        let mut n = 0;
        let mask = Array2::from_shape_fn((12, 12), |(j, i)| {
            let pick = inside((j, i)) && pr[[j, i]] > 0.0 && n < 8;
            n += pick as usize;
            pick
        });
        let c = check(&pr, Some(&mask), true);
        let m = c.message().unwrap_or_default().to_string();
        assert!(m.starts_with("21 % of the 56 windows (not masked)"), "{m}");
        // a mask of the blank windows themselves: fine
        let pr = field(30);
        assert_eq!(
            check(&pr, Some(&pr.mapv(|p| p == 0.0)), true),
            Correlation::Fine
        );
        // nothing correlated inside, a stray window at the edge: no measurement
        let mut pr = Array2::from_elem((12, 12), 0.0);
        pr[[0, 5]] = 2.3;
        let c = check(&pr, None, true);
        assert!(matches!(c, Correlation::Uncorrelated(_)), "{c:?}");
        assert!(c
            .message()
            .unwrap()
            .starts_with("no window could be correlated"));
        // a grid without an inside is not judged
        let small = Array2::from_shape_fn((4, 12), |(j, _)| if j == 1 { 0.0 } else { 3.0 });
        assert_eq!(check(&small, None, true), Correlation::Fine);
        // the frames' own failure comes first: low peak ratios and many blank windows
        let pr = field(30).mapv(|p| if p > 0.0 { 1.1 } else { 0.0 });
        assert!(matches!(
            check(&pr, None, true),
            Correlation::Uncorrelated(_)
        ));
    }

    #[test]
    fn correlation_check_counts_the_vectors_only_interpolated() {
        // a 12 x 12 grid of well correlated windows (ratio 3) whose inside (8 x 8 past the two
        // outer rings) has `n` vectors rejected by the validation, spread over it
        let inside = |(j, i): (usize, usize)| (2..10).contains(&j) && (2..10).contains(&i);
        let spread = |(j, i): (usize, usize), n: usize| {
            inside((j, i)) && (j.saturating_sub(2) * 8 + i.saturating_sub(2)) * 5 % 64 < n
        };
        let pr = Array2::from_elem((12, 12), 3.0);
        let valid = |n: usize| Array2::from_shape_fn((12, 12), |k| !spread(k, n));
        let check = |pr: &Array2<f64>, v: &Array2<bool>, m: Option<&Array2<bool>>| {
            correlation_check(pr.view(), v.view(), m.map(|m| m.view()), true)
        };
        // 6 of 64 (9 %): fine; 7 (11 %): said so, in one line
        assert_eq!(check(&pr, &valid(6), None), Correlation::Fine);
        let c = check(&pr, &valid(7), None);
        assert!(matches!(c, Correlation::Partly(_)), "{c:?}");
        let m = c.message().unwrap();
        assert!(
            m.starts_with("11 % of the 64 vectors (not masked) are only interpolated")
                && m.contains("(7 rejected by the validation, 0 from windows too blank"),
            "{m}"
        );
        assert!(!m.contains('\n'));
        // rejected vectors in the outer rings are not counted
        let mut v = valid(6);
        v.indexed_iter_mut()
            .filter(|(k, _)| !inside(*k))
            .for_each(|(_, ok)| *ok = false);
        assert_eq!(check(&pr, &v, None), Correlation::Fine);
        // nor masked ones: 7 rejected of which 2 masked is 5 of 62
        let mut n = 0;
        let mask = Array2::from_shape_fn((12, 12), |k| {
            let pick = spread(k, 7) && n < 2;
            n += pick as usize;
            pick
        });
        assert_eq!(check(&pr, &valid(7), Some(&mask)), Correlation::Fine);
        // windows too blank to correlate count too: 4 blank and 3 rejected of 64
        let blank = Array2::from_shape_fn((12, 12), |k| if spread(k, 4) { 0.0 } else { 3.0 });
        let c = check(&blank, &valid(7), None);
        let m = c.message().unwrap_or_default().to_string();
        assert!(
            m.contains("(3 rejected by the validation, 4 from windows too blank"),
            "{m}"
        );
        // valid flags of another shape reject nothing
        let other = Array2::from_elem((3, 3), false);
        assert_eq!(
            correlation_check(pr.view(), other.view(), None, false),
            Correlation::Fine
        );
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
