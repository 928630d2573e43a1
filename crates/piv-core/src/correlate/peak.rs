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
    let mut hm = vec![0.0f32; cw * ch];
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

/// The maximum of `x` (NaN skipped; -inf if empty), with 8 independent lanes.
#[inline(always)]
pub(super) fn max8(x: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            acc[k] = gt_max(c[k], acc[k]);
        }
    }
    let m = acc.iter().fold(f32::NEG_INFINITY, |m, &a| gt_max(a, m));
    it.remainder().iter().fold(m, |m, &a| gt_max(a, m))
}

/// [`find_peak`] with a scratch plane `hm` of `cw * ch` values; also returns the plane
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
    let hm = &mut hm[..cw * ch];
    let at = |c: usize, r: usize| corr[r * cw + c];
    let (hx, hy) = ((cw / 2) as f32, (ch / 2) as f32);
    let (fw, fh) = (w as f32, h as f32);
    // the windows' overlap at each lag: given (weighted windows) or the top-hat's
    let unbiased = |c: usize, r: usize| match overlap {
        Some((ox, oy)) => corr[r * cw + c] / (ox[c] * oy[r]),
        None => {
            let ox = 1.0 - (c as f32 - hx).abs() / fw;
            let oy = 1.0 - (r as f32 - hy).abs() / fh;
            corr[r * cw + c] / (ox * oy)
        }
    };
    let n = cw - 2;
    // primary peak inside the border (the first of equal values in row-major order)
    let (mut pc, mut pr, mut best) = (1usize, 1usize, f32::NEG_INFINITY);
    for (r, row) in corr.chunks_exact(cw).enumerate().take(ch - 1).skip(1) {
        let inner = &row[1..cw - 1];
        let m = max8(inner);
        if m > best {
            best = m;
            pr = r;
            pc = 1 + inner.iter().position(|&v| v == m).unwrap_or(0);
        }
    }
    if !best.is_finite() {
        return (Peak::FAILED, [(0, 0); 3]);
    }
    // second-highest local maximum outside the peak's 3 x 3 neighbourhood: maximum of the
    // 3 x 3 neighbourhoods, separably (rows first: hm[r cw + i] for column i + 1)
    for (o, row) in hm.chunks_exact_mut(cw).zip(corr.chunks_exact(cw)) {
        for (((o, &a), &b), &c) in o[..n]
            .iter_mut()
            .zip(&row[..n])
            .zip(&row[1..n + 1])
            .zip(&row[2..])
        {
            *o = gt_max(gt_max(a, b), c);
        }
    }
    // then along y, in place into the first n values of row r - 1 (rows r - 1, r, r + 1 are
    // still the horizontal maxima when row r is reached), keeping the value where it is a
    // local maximum (at least its neighbourhood's maximum) and -inf elsewhere; the two highest
    // local maxima (not adjacent to each other: a plateau counts once) are kept with their lags
    let mut top = [(f32::NEG_INFINITY, 0usize, 0usize); 2];
    for r in 1..ch - 1 {
        let (up, rest) = hm[(r - 1) * cw..].split_at_mut(cw);
        let (mid, dn) = rest.split_at(cw);
        let v = &corr[r * cw + 1..r * cw + 1 + n];
        let up = &mut up[..n];
        for (((u, &m), &d), &x) in up.iter_mut().zip(&mid[..n]).zip(&dn[..n]).zip(v) {
            let mx = gt_max(gt_max(*u, m), d);
            *u = if x >= mx { x } else { f32::NEG_INFINITY };
        }
        if r.abs_diff(pr) <= 1 {
            // not the peak's own neighbourhood: columns pc-1 ..= pc+1 (indices pc-2 ..= pc)
            up[pc.saturating_sub(2)..(pc + 1).min(n)].fill(f32::NEG_INFINITY);
        }
        if max8(up) > top[1].0 {
            for (i, &x) in up.iter().enumerate() {
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
    let on_border = (pr - 1..=pr + 1)
        .any(|rr| (pc - 1..=pc + 1).any(|cc| (rr, cc) != (pr, pc) && at(cc, rr) > best));
    let (ox, oy) = match sub {
        SubPixel::Gauss3 => gauss3_2(&unbiased, pc, pr),
        SubPixel::Gauss2d => {
            gauss9(&unbiased, pc, pr).unwrap_or_else(|| gauss3_2(&unbiased, pc, pr))
        }
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
    };
    (peak, lags)
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
    let (m, c, p) = (m as f64, c as f64, p as f64);
    let off = if m > 0.0 && c > 0.0 && p > 0.0 {
        let (lm, lc, lp) = (m.ln(), c.ln(), p.ln());
        let den = 2.0 * (lm - 2.0 * lc + lp);
        if den < 0.0 {
            (lm - lp) / den
        } else {
            0.0
        }
    } else {
        let den = 2.0 * (m - 2.0 * c + p);
        if den < 0.0 {
            (m - p) / den
        } else {
            0.0
        }
    };
    off.clamp(-0.5, 0.5)
}

pub(super) fn gauss3_2(at: &impl Fn(usize, usize) -> f32, c: usize, r: usize) -> (f64, f64) {
    (
        gauss3(at(c - 1, r), at(c, r), at(c + 1, r)),
        gauss3(at(c, r - 1), at(c, r), at(c, r + 1)),
    )
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
