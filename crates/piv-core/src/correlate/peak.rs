//! The peak search of a correlation plane: the highest peak, its two alternatives and the peak
//! ratio, and the sub-pixel estimators (3-point Gaussian, 9-point 2D Gaussian).

use super::{AltPeak, Peak, SubPixel};

/// Locate the peak in a plane of `ch` rows of `cw` lags (lag 0 at the centre, a one-lag border
/// around the search region), with sub-pixel refinement and peak ratio. The sub-pixel fit uses
/// the plane divided by the overlap fraction `(1 - |tx|/w)(1 - |ty|/h)` of the two windows at
/// each lag, which removes the bias of linear correlation towards zero displacement
/// (Westerweel 1997); the integer peak, its height and the peak ratio use the plane itself.
/// Allocates a scratch plane: [`super::Correlator::correlate`] uses its own instead.
pub fn find_peak(corr: &[f32], cw: usize, ch: usize, w: usize, h: usize, sub: SubPixel) -> Peak {
    let mut hm = vec![0.0f32; cw * (ch + 1)];
    find_peak_with(corr, &mut hm, cw, ch, w, h, None, sub).0
}

/// `a` if it is greater than `b`, else `b` (one `maxps`; a NaN `a` is skipped).
#[inline(always)]
pub(super) fn gt_max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// The maximum of `x` (NaN skipped; -inf if empty), with 8 independent lanes; from 8 values
/// on, the last chunk overlaps the one before it (no scalar remainder).
#[inline(always)]
pub(super) fn max8(x: &[f32]) -> f32 {
    if x.len() < 8 {
        return x.iter().fold(f32::NEG_INFINITY, |m, &a| gt_max(a, m));
    }
    let mut acc = [f32::NEG_INFINITY; 8];
    for s in chunks8(x.len()) {
        let c: &[f32; 8] = x[s..s + 8].try_into().unwrap();
        for k in 0..8 {
            acc[k] = gt_max(c[k], acc[k]);
        }
    }
    lanes_max(acc)
}

/// The maximum of 8 lanes holding no NaN, by halves (three steps instead of a chain of
/// eight).
#[inline(always)]
fn lanes_max(mut a: [f32; 8]) -> f32 {
    for k in 0..4 {
        a[k] = gt_max(a[k + 4], a[k]);
    }
    for k in 0..2 {
        a[k] = gt_max(a[k + 2], a[k]);
    }
    gt_max(a[1], a[0])
}

/// The starts `s` of the 8-value chunks `s .. s + 8` covering `0 .. n` (`n >= 8`): `0, 8,
/// ...` and, where `n` is not a multiple of 8, a last chunk `n - 8 ..` overlapping the one
/// before (for work that gives the same result when done twice).
#[inline(always)]
fn chunks8(n: usize) -> impl Iterator<Item = usize> {
    (0..n).step_by(8).map(move |s| s.min(n - 8))
}

/// `o[i] = max(row[i], row[i + 1], row[i + 2])` for `i < o.len()` (the horizontal maxima of
/// the 3 x 3 neighbourhoods, centred on `i + 1`); returns 8 lanes whose maximum is that of
/// `row[1 ..= o.len()]` (the row's search region).
#[inline(always)]
fn row_max3(row: &[f32], o: &mut [f32]) -> [f32; 8] {
    let n = o.len();
    let row = &row[..n + 2];
    if n < 8 {
        for (i, o) in o.iter_mut().enumerate() {
            *o = gt_max(gt_max(row[i], row[i + 1]), row[i + 2]);
        }
        let mut acc = [f32::NEG_INFINITY; 8];
        acc[0] = max8(&row[1..n + 1]);
        return acc;
    }
    let mut acc = [f32::NEG_INFINITY; 8];
    for s in chunks8(n) {
        let a: &[f32; 8] = row[s..s + 8].try_into().unwrap();
        let b: &[f32; 8] = row[s + 1..s + 9].try_into().unwrap();
        let c: &[f32; 8] = row[s + 2..s + 10].try_into().unwrap();
        let o: &mut [f32; 8] = (&mut o[s..s + 8]).try_into().unwrap();
        for k in 0..8 {
            o[k] = gt_max(gt_max(a[k], b[k]), c[k]);
            acc[k] = gt_max(b[k], acc[k]);
        }
    }
    acc
}

/// The local maxima of one row: `o[i] = v[i]` where `v[i]` is at least the maximum of the
/// three horizontal maxima `up[i]`, `mid[i]`, `dn[i]` (its 3 x 3 neighbourhood), else -inf.
#[inline(always)]
fn local_max_row(up: &[f32], mid: &[f32], dn: &[f32], v: &[f32], o: &mut [f32]) {
    let n = o.len();
    let pick = |u: f32, m: f32, d: f32, x: f32| {
        let mx = gt_max(gt_max(u, m), d);
        if x >= mx {
            x
        } else {
            f32::NEG_INFINITY
        }
    };
    if n < 8 {
        for i in 0..n {
            o[i] = pick(up[i], mid[i], dn[i], v[i]);
        }
        return;
    }
    for s in chunks8(n) {
        let u: &[f32; 8] = up[s..s + 8].try_into().unwrap();
        let m: &[f32; 8] = mid[s..s + 8].try_into().unwrap();
        let d: &[f32; 8] = dn[s..s + 8].try_into().unwrap();
        let x: &[f32; 8] = v[s..s + 8].try_into().unwrap();
        let o: &mut [f32; 8] = (&mut o[s..s + 8]).try_into().unwrap();
        for k in 0..8 {
            o[k] = pick(u[k], m[k], d[k], x[k]);
        }
    }
}

/// [`find_peak`] with a scratch plane `hm` of `cw * (ch + 1)` values; also returns the plane
/// positions `(column, row)` of the peak and of its two alternatives.
#[inline(always)]
pub(super) fn find_peak_with(
    corr: &[f32],
    hm: &mut [f32],
    cw: usize,
    ch: usize,
    w: usize,
    h: usize,
    overlap: Option<(&[f32], &[f32])>,
    sub: SubPixel,
) -> (Peak, [(usize, usize); 3]) {
    let corr = &corr[..cw * ch];
    let (hm, lm) = hm[..cw * (ch + 1)].split_at_mut(cw * ch);
    let at = |c: usize, r: usize| corr[r * cw + c];
    let ub = Unbiased {
        corr,
        cw,
        hx: (cw / 2) as f32,
        hy: (ch / 2) as f32,
        fw: w as f32,
        fh: h as f32,
        overlap,
    };
    let unbiased = |c: usize, r: usize| ub.at(c, r);
    let n = cw - 2;
    let lm = &mut lm[..n];
    // one pass over the rows: the maxima of the 3 x 3 neighbourhoods along x (hm[r cw + i]
    // for column i + 1), and the primary peak inside the border (the first of equal values in
    // row-major order)
    let (mut pc, mut pr, mut best) = (1usize, 1usize, f32::NEG_INFINITY);
    for (r, (o, row)) in hm
        .chunks_exact_mut(cw)
        .zip(corr.chunks_exact(cw))
        .enumerate()
    {
        let m = lanes_max(row_max3(row, &mut o[..n]));
        if r >= 1 && r < ch - 1 && m > best {
            best = m;
            pr = r;
            pc = 1 + row[1..cw - 1].iter().position(|&v| v == m).unwrap_or(0);
        }
    }
    if !best.is_finite() {
        return (Peak::FAILED, [(0, 0); 3]);
    }
    // second-highest local maximum outside the peak's 3 x 3 neighbourhood: each row's local
    // maxima (its values at least their neighbourhood's maximum, -inf elsewhere) into lm; the
    // two highest (not adjacent to each other: a plateau counts once) are kept with their lags
    let mut top = [(f32::NEG_INFINITY, 0usize, 0usize); 2];
    for r in 1..ch - 1 {
        let up = &hm[(r - 1) * cw..][..n];
        let mid = &hm[r * cw..][..n];
        let dn = &hm[(r + 1) * cw..][..n];
        local_max_row(up, mid, dn, &corr[r * cw + 1..][..n], lm);
        if r.abs_diff(pr) <= 1 {
            // not the peak's own neighbourhood: columns pc-1 ..= pc+1 (indices pc-2 ..= pc)
            lm[pc.saturating_sub(2)..(pc + 1).min(n)].fill(f32::NEG_INFINITY);
        }
        if max8(lm) > top[1].0 {
            for (i, &x) in lm.iter().enumerate() {
                if x > top[1].0 {
                    keep_top2(&mut top, (x, i + 1, r));
                }
            }
        }
    }
    let second = top[0].0;
    let ratio = peak_ratio(best, second);
    // a peak on the search border is kept only if it is a true local maximum (the plane has
    // one exact lag beyond the search range on every side)
    let mut on_border = false;
    for rr in pr - 1..=pr + 1 {
        for cc in pc - 1..=pc + 1 {
            on_border |= (rr, cc) != (pr, pc) && at(cc, rr) > best;
        }
    }
    let (g3, width) = gauss3_2_width(&unbiased, pc, pr);
    let (ox, oy) = match sub {
        SubPixel::Gauss3 => g3,
        SubPixel::Gauss2d => gauss9(&unbiased, pc, pr).unwrap_or(g3),
    };
    let cx = (cw / 2) as f64;
    let cy = (ch / 2) as f64;
    let alt = top.map(|(x, c, r)| {
        if x.is_finite() {
            let (ox, oy) = gauss3_2(&unbiased, c, r);
            AltPeak {
                dx: c as f64 - cx + ox,
                dy: r as f64 - cy + oy,
                coef: x as f64,
                sigma: (f64::NAN, f64::NAN),
            }
        } else {
            AltPeak::NONE
        }
    });
    let lags = [(pc, pr), (top[0].1, top[0].2), (top[1].1, top[1].2)];
    let peak = Peak {
        dx: pc as f64 - cx + ox,
        dy: pr as f64 - cy + oy,
        coef: best as f64,
        ratio,
        ok: !on_border,
        alt,
        sigma: (f64::NAN, f64::NAN),
        width,
    };
    (peak, lags)
}

/// A correlation plane divided by the windows' overlap at each lag: the values the sub-pixel
/// fits use ([`find_peak`]).
struct Unbiased<'a> {
    corr: &'a [f32],
    cw: usize,
    /// The plane's centre (lag 0).
    hx: f32,
    hy: f32,
    /// The window size.
    fw: f32,
    fh: f32,
    /// The weighted windows' overlap per lag along x and y; the top-hat's where `None`.
    overlap: Option<(&'a [f32], &'a [f32])>,
}

impl Unbiased<'_> {
    #[inline(always)]
    fn at(&self, c: usize, r: usize) -> f32 {
        let v = self.corr[r * self.cw + c];
        match self.overlap {
            Some((ox, oy)) => v / (ox[c] * oy[r]),
            None => {
                let ox = 1.0 - (c as f32 - self.hx).abs() / self.fw;
                let oy = 1.0 - (r as f32 - self.hy).abs() / self.fh;
                v / (ox * oy)
            }
        }
    }
}

/// The peak ratio of a plane whose highest value is `best` and second-highest local maximum
/// `second`: 1 when the peak is not positive, capped at 1000 (no second peak above a
/// thousandth of the first), else `best / second`.
pub(super) fn peak_ratio(best: f32, second: f32) -> f64 {
    if best <= 0.0 {
        1.0
    } else if second <= best * 1e-3 {
        1000.0
    } else {
        (best / second) as f64
    }
}

/// Insert the local maximum `cand` = (value, column, row) into the two highest `top` (highest
/// first), where a maximum next to a held one (a plateau) replaces it only when higher.
#[inline]
pub(super) fn keep_top2(top: &mut [(f32, usize, usize); 2], cand: (f32, usize, usize)) {
    let near = |a: &(f32, usize, usize)| a.1.abs_diff(cand.1) <= 1 && a.2.abs_diff(cand.2) <= 1;
    if near(&top[0]) {
        if cand.0 > top[0].0 {
            top[0] = cand;
        }
        return;
    }
    if near(&top[1]) {
        if cand.0 > top[1].0 {
            top[1] = cand;
            if top[1].0 > top[0].0 {
                top.swap(0, 1);
            }
        }
        return;
    }
    if cand.0 > top[0].0 {
        top[1] = top[0];
        top[0] = cand;
    } else if cand.0 > top[1].0 {
        top[1] = cand;
    }
}

/// 3-point estimator along one axis; Gaussian when all values are positive, else parabolic.
#[inline]
pub fn gauss3(m: f32, c: f32, p: f32) -> f64 {
    gauss3_lc(m, c, p, (c as f64).ln()).0
}

/// [`gauss3`] given `lc = ln(c)` (used only where `c > 0`), and the standard deviation (px) of
/// the Gaussian through the three values (NaN where they are not all positive or not a
/// maximum).
#[inline(always)]
fn gauss3_lc(m: f32, c: f32, p: f32, lc: f64) -> (f64, f64) {
    let (m, c, p) = (m as f64, c as f64, p as f64);
    let (off, width) = if m > 0.0 && c > 0.0 && p > 0.0 {
        let (lm, lp) = (m.ln(), p.ln());
        let den = 2.0 * (lm - 2.0 * lc + lp);
        if den < 0.0 {
            // ln R = const - (k - k0)^2 / (2 s^2): lm - 2 lc + lp = -1 / s^2
            ((lm - lp) / den, (-2.0 / den).sqrt())
        } else {
            (0.0, f64::NAN)
        }
    } else {
        let den = 2.0 * (m - 2.0 * c + p);
        if den < 0.0 {
            ((m - p) / den, f64::NAN)
        } else {
            (0.0, f64::NAN)
        }
    };
    (off.clamp(-0.5, 0.5), width)
}

/// [`gauss3`] along x and y at plane position `(c, r)` of `at`, the centre's logarithm once.
#[inline(always)]
pub(super) fn gauss3_2(at: &impl Fn(usize, usize) -> f32, c: usize, r: usize) -> (f64, f64) {
    gauss3_2_width(at, c, r).0
}

/// [`gauss3_2`] and the peak's standard deviations along x and y ([`super::Peak::width`]).
#[inline(always)]
pub(super) fn gauss3_2_width(
    at: &impl Fn(usize, usize) -> f32,
    c: usize,
    r: usize,
) -> ((f64, f64), (f64, f64)) {
    let v = at(c, r);
    let lc = (v as f64).ln();
    let (ox, wx) = gauss3_lc(at(c - 1, r), v, at(c + 1, r), lc);
    let (oy, wy) = gauss3_lc(at(c, r - 1), v, at(c, r + 1), lc);
    ((ox, oy), (wx, wy))
}

/// Least-squares fit of `ln R = a + b x + c y + d x^2 + e x y + f y^2` to the 3 x 3
/// neighbourhood; the vertex of the fitted paraboloid. `None` if a value is <= 0 or the fit is
/// not a maximum.
pub(super) fn gauss9(at: &impl Fn(usize, usize) -> f32, c: usize, r: usize) -> Option<(f64, f64)> {
    let mut c10 = 0.0;
    let mut c01 = 0.0;
    let mut c11 = 0.0;
    let mut c20 = 0.0;
    let mut c02 = 0.0;
    for j in -1i32..=1 {
        for i in -1i32..=1 {
            let v = at((c as i32 + i) as usize, (r as i32 + j) as usize) as f64;
            if v <= 0.0 {
                return None;
            }
            let l = v.ln();
            let (x, y) = (i as f64, j as f64);
            c10 += x * l / 6.0;
            c01 += y * l / 6.0;
            c11 += x * y * l / 4.0;
            c20 += (3.0 * x * x - 2.0) * l / 6.0;
            c02 += (3.0 * y * y - 2.0) * l / 6.0;
        }
    }
    // ln R ~ const + c10 x + c01 y + c20 x^2 + c11 x y + c02 y^2
    let det = 4.0 * c20 * c02 - c11 * c11;
    if !(c20 < 0.0 && det > 0.0) {
        return None;
    }
    let x0 = (c11 * c01 - 2.0 * c10 * c02) / det;
    let y0 = (c11 * c10 - 2.0 * c01 * c20) / det;
    if x0.abs() > 1.0 || y0.abs() > 1.0 {
        return None;
    }
    Some((x0, y0))
}
