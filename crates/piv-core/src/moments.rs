//! Central sums of orders 3 to 8 of per-vector samples, one sample per position added in place:
//! the streaming skewness and flatness (and their standard errors) of
//! `rspiv.stats.FieldAccumulator`, whose formulas and conventions are documented in
//! `python/rspiv/moments.py` (Pébay 2008, SAND2008-6212: a one-sample merge).
//!
//! With `n_a` samples before, `r = delta / (n_a + 1)` (`delta` = the sample minus the mean
//! before it), every order `p` gains `sum_{k=1}^{p-2} C(p, k) M_{p-k} (-r)^k + r^p (n_a^p +
//! (-1)^p n_a)`, taken from the sums before the update (`M_2` included, which the caller updates
//! after). A position with `delta = 0` (no sample added there) is left as it was.

use crate::error::{PivError, Result};
use rayon::prelude::*;

/// Orders kept, `M_3 ..= M_8`.
pub const ORDERS: usize = 6;

/// Binomial coefficients `C(p, k)`, `p <= 8`.
const fn binomials() -> [[f64; 9]; 9] {
    let mut c = [[0.0; 9]; 9];
    let mut p = 0;
    while p < 9 {
        c[p][0] = 1.0;
        let mut k = 1;
        while k <= p {
            c[p][k] = c[p - 1][k - 1] + if k < p { c[p - 1][k] } else { 0.0 };
            k += 1;
        }
        p += 1;
    }
    c
}

const C: [[f64; 9]; 9] = binomials();

/// Add one sample per position: `hm` holds `M_3 .. M_8` as [`ORDERS`] planes of `n` values
/// (`hm[(p - 3) * n + i]`), `m2` the positions' `M_2` and `n_old` their counts before the
/// sample, `delta` the sample minus the mean before it (0: no sample). Errors: lengths that
/// do not match.
pub fn add_sample(hm: &mut [f64], m2: &[f64], n_old: &[i64], delta: &[f64]) -> Result<()> {
    let n = m2.len();
    if n_old.len() != n || delta.len() != n || hm.len() != ORDERS * n {
        return Err(PivError::InvalidInput(format!(
            "moments: {} sums for {} positions of M2, {} counts and {} deltas (expected {} sums)",
            hm.len(),
            n,
            n_old.len(),
            delta.len(),
            ORDERS * n
        )));
    }
    if n == 0 {
        return Ok(());
    }
    // blocks of positions, each task holding its block of every order's plane
    const BLOCK: usize = 4096;
    let mut blocks: Vec<Vec<&mut [f64]>> = (0..n.div_ceil(BLOCK)).map(|_| Vec::new()).collect();
    for plane in hm.chunks_mut(n) {
        for (b, part) in plane.chunks_mut(BLOCK).enumerate() {
            blocks[b].push(part);
        }
    }
    blocks
        .into_par_iter()
        .enumerate()
        .for_each(|(b, mut parts)| {
            let start = b * BLOCK;
            for j in 0..parts[0].len() {
                let i = start + j;
                let d = delta[i];
                if d == 0.0 {
                    continue;
                }
                let na = n_old[i] as f64;
                let r = d / (na + 1.0);
                // old sums by order, M_2 ..= M_8
                let mut s = [0.0f64; 9];
                s[2] = m2[i];
                for (q, part) in parts.iter().enumerate() {
                    s[q + 3] = part[j];
                }
                // (-r)^k and (-na)^k
                let (mut nr, mut nn) = ([1.0f64; 9], [1.0f64; 9]);
                for k in 1..9 {
                    nr[k] = nr[k - 1] * -r;
                    nn[k] = nn[k - 1] * -na;
                }
                for (q, part) in parts.iter_mut().enumerate() {
                    let p = q + 3;
                    let mut inc = 0.0;
                    for k in 1..p - 1 {
                        inc += C[p][k] * s[p - k] * nr[k];
                    }
                    // r^p (na^p + (-1)^p na) = (-r)^p ((-na)^p + na)
                    inc += nr[p] * (nn[p] + na);
                    part[j] = s[p] + inc;
                }
            }
        });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central sums of `x` about its mean, orders 2 ..= 8.
    fn direct(x: &[f64]) -> [f64; 9] {
        let m = x.iter().sum::<f64>() / x.len() as f64;
        let mut s = [0.0; 9];
        for p in 2..9 {
            s[p] = x.iter().map(|v| (v - m).powi(p as i32)).sum();
        }
        s
    }

    #[test]
    fn one_sample_at_a_time_equals_the_direct_sums() {
        // a skewed sample at two positions, the second one skipping every third sample
        let xs: Vec<f64> = (0..200)
            .map(|k| {
                let t = (k as f64 * 0.7131).sin();
                3.0 + t * t * t + 0.2 * t
            })
            .collect();
        let n = 2;
        let mut hm = vec![0.0; ORDERS * n];
        let (mut m2, mut mean, mut cnt) = (vec![0.0; n], vec![0.0; n], vec![0i64; n]);
        let mut kept = [Vec::new(), Vec::new()];
        for (k, &x) in xs.iter().enumerate() {
            let take = [true, k % 3 != 0];
            let delta: Vec<f64> = (0..n)
                .map(|i| if take[i] { x - mean[i] } else { 0.0 })
                .collect();
            add_sample(&mut hm, &m2, &cnt, &delta).unwrap();
            for i in 0..n {
                if take[i] {
                    cnt[i] += 1;
                    mean[i] += delta[i] / cnt[i] as f64;
                    m2[i] += delta[i] * (x - mean[i]);
                    kept[i].push(x);
                }
            }
        }
        for i in 0..n {
            let s = direct(&kept[i]);
            assert!((m2[i] - s[2]).abs() <= 1e-10 * s[2]);
            for p in 3..9 {
                let got = hm[(p - 3) * n + i];
                let scale =
                    kept[i].len() as f64 * (s[2] / kept[i].len() as f64).powf(p as f64 / 2.0);
                assert!(
                    (got - s[p]).abs() <= 1e-10 * scale,
                    "order {p} position {i}: {got} vs {}",
                    s[p]
                );
            }
        }
    }

    #[test]
    fn mismatched_lengths_are_refused() {
        let mut hm = vec![0.0; ORDERS * 3];
        let e = add_sample(&mut hm, &[0.0; 3], &[0; 2], &[0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("moments"));
    }
}
