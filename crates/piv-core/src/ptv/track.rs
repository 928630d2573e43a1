//! Particle images of frame A paired with those of frame B through a predictor (particle
//! tracking assisted by PIV: Keane, Adrian & Zhang 1995; Kähler, Scharnowski & Cierpka 2012).
//!
//! Each particle image `i` of A is predicted in B at `p_i = a_i + d_i`, `d_i` the caller's
//! predicted displacement (a PIV field interpolated there). Its candidates are the particle
//! images of B within `radius` of `p_i`. The pair `(i, j)` is kept only when it is unique both
//! ways:
//!
//! - `i` has exactly one candidate `j` (none: [`NONE`]; two or more: [`SEVERAL`]);
//! - no other particle image of A has `j` among its candidates ([`CLAIMED`]).
//!
//! A particle image whose partner was lost (out of the light sheet, merged with another, under
//! the threshold in B) can still have one candidate: another particle image that happens to lie
//! within `radius`. Such a wrong pair is uniform over the disc about the prediction, so it adds
//! about `radius^2 / 4` to each displacement component's variance, times the share of lost
//! partners times the chance `1 - exp(-n pi radius^2)` of a stray candidate (`n` particle
//! images per px^2 of B). The caller sizes `radius` from the predictor's error and the flow's
//! fluctuation about it, and states that share ([`stray_share`]).
//!
//! Units: px; positions in the pixel frame (x = column, y = row).

use crate::error::{PivError, Result};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Paired, unique both ways.
pub const MATCHED: u8 = 0;
/// No particle image of B within the radius of the prediction.
pub const NONE: u8 = 1;
/// Two or more particle images of B within the radius.
pub const SEVERAL: u8 = 2;
/// Its one candidate is also another particle image's candidate.
pub const CLAIMED: u8 = 3;
/// The predicted displacement is not finite (the predictor has no value there).
pub const NO_PREDICTOR: u8 = 4;

/// Cells per axis at most in the search grid of B (a radius much finer than the frame is
/// searched over coarser cells, never more than this many).
const MAX_CELLS: f64 = 2048.0;

/// Each particle image of A's partner in B (an index into B, or -1) and why ([`MATCHED`],
/// [`NONE`], [`SEVERAL`], [`CLAIMED`], [`NO_PREDICTOR`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Matches {
    pub partner: Vec<i64>,
    pub status: Vec<u8>,
}

/// A set of points binned into square cells (counting sort).
struct CellGrid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    start: Vec<usize>,
    index: Vec<usize>,
}

impl CellGrid {
    fn new(x: &[f64], y: &[f64], radius: f64) -> Self {
        let lo = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let (x0, y0) = (lo(x), lo(y));
        let span = (hi(x) - x0).max(hi(y) - y0).max(0.0);
        let cell = radius.max(span / MAX_CELLS);
        let nx = ((hi(x) - x0) / cell) as usize + 1;
        let ny = ((hi(y) - y0) / cell) as usize + 1;
        let at = |i: usize| {
            let cx = ((x[i] - x0) / cell) as usize;
            let cy = ((y[i] - y0) / cell) as usize;
            cy.min(ny - 1) * nx + cx.min(nx - 1)
        };
        let mut start = vec![0usize; nx * ny + 1];
        for i in 0..x.len() {
            start[at(i) + 1] += 1;
        }
        for c in 0..nx * ny {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut index = vec![0usize; x.len()];
        for i in 0..x.len() {
            let c = at(i);
            index[fill[c]] = i;
            fill[c] += 1;
        }
        CellGrid {
            x0,
            y0,
            cell,
            nx,
            ny,
            start,
            index,
        }
    }

    /// Calls `f(j)` for every point within `r` of `(px, py)`.
    fn within(&self, x: &[f64], y: &[f64], px: f64, py: f64, r: f64, mut f: impl FnMut(usize)) {
        let span = |p: f64, o: f64, n: usize| -> Option<(usize, usize)> {
            let a = ((p - r - o) / self.cell).floor();
            let b = ((p + r - o) / self.cell).floor();
            if b < 0.0 || a > (n - 1) as f64 {
                return None;
            }
            Some((a.max(0.0) as usize, (b as usize).min(n - 1)))
        };
        let (Some((cx0, cx1)), Some((cy0, cy1))) =
            (span(px, self.x0, self.nx), span(py, self.y0, self.ny))
        else {
            return;
        };
        let r2 = r * r;
        for cy in cy0..=cy1 {
            for cx in cx0..=cx1 {
                let c = cy * self.nx + cx;
                for &j in &self.index[self.start[c]..self.start[c + 1]] {
                    let (ex, ey) = (x[j] - px, y[j] - py);
                    if ex * ex + ey * ey <= r2 {
                        f(j);
                    }
                }
            }
        }
    }
}

/// Pairs the particle images `(ax, ay)` of frame A with `(bx, by)` of frame B through the
/// predicted displacements `(du, dv)` of A's (module docs). Errors on arrays of unequal
/// lengths, a radius that is not finite and positive, or a position that is not finite.
pub fn track(
    ax: &[f64],
    ay: &[f64],
    bx: &[f64],
    by: &[f64],
    du: &[f64],
    dv: &[f64],
    radius: f64,
) -> Result<Matches> {
    let n = ax.len();
    if ay.len() != n || du.len() != n || dv.len() != n || bx.len() != by.len() {
        return Err(PivError::InvalidInput(format!(
            "particle arrays of unequal lengths: A x {n}, y {}, predictor {} / {}; B x {}, y {}",
            ay.len(),
            du.len(),
            dv.len(),
            bx.len(),
            by.len()
        )));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(PivError::InvalidInput(format!(
            "the search radius must be finite and > 0 px, got {radius}"
        )));
    }
    if ax
        .iter()
        .chain(ay)
        .chain(bx)
        .chain(by)
        .any(|v| !v.is_finite())
    {
        return Err(PivError::InvalidInput(
            "a particle position is not finite".into(),
        ));
    }
    let mut out = Matches {
        partner: vec![-1; n],
        status: vec![NONE; n],
    };
    if n == 0 {
        return Ok(out);
    }
    if bx.is_empty() {
        for (s, (u, v)) in out.status.iter_mut().zip(du.iter().zip(dv)) {
            if !(u.is_finite() && v.is_finite()) {
                *s = NO_PREDICTOR;
            }
        }
        return Ok(out);
    }
    let grid = CellGrid::new(bx, by, radius);
    let claims: Vec<AtomicU32> = (0..bx.len()).map(|_| AtomicU32::new(0)).collect();
    // each A's candidates: (how many, the first)
    let found: Vec<(u32, usize)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (px, py) = (ax[i] + du[i], ay[i] + dv[i]);
            if !(px.is_finite() && py.is_finite()) {
                return (u32::MAX, 0);
            }
            let (mut count, mut first) = (0u32, 0usize);
            grid.within(bx, by, px, py, radius, |j| {
                if count == 0 {
                    first = j;
                }
                count += 1;
                claims[j].fetch_add(1, Ordering::Relaxed);
            });
            (count, first)
        })
        .collect();
    for (i, &(count, j)) in found.iter().enumerate() {
        out.status[i] = match count {
            u32::MAX => NO_PREDICTOR,
            0 => NONE,
            1 if claims[j].load(Ordering::Relaxed) == 1 => {
                out.partner[i] = j as i64;
                MATCHED
            }
            1 => CLAIMED,
            _ => SEVERAL,
        };
    }
    Ok(out)
}

/// The expected share of A's particle images whose partner was lost that are paired with a
/// stray particle image instead (module docs): `1 - exp(-n pi radius^2)`, `n` the particle
/// images of B per px^2.
pub fn stray_share(density_b: f64, radius: f64) -> f64 {
    1.0 - (-density_b * std::f64::consts::PI * radius * radius).exp()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn unique_pairs_are_kept_and_ambiguous_ones_said() {
        // A at (10, 10), (30, 10), (50, 10), (70, 10); predictor +2 px along x
        let ax = [10.0, 30.0, 50.0, 70.0, 90.0];
        let ay = [10.0; 5];
        let du = [2.0, 2.0, 2.0, 2.0, f64::NAN];
        let dv = [0.0; 5];
        // B: one partner near (12, 10); none near (32, 10); two near (52, 10); one near
        // (72, 10) that a sixth A particle image also reaches
        let bx = [12.3, 51.5, 52.6, 72.2];
        let by = [10.1, 10.0, 9.8, 10.4];
        let ax6 = [&ax[..], &[71.0]].concat();
        let ay6 = [&ay[..], &[11.5]].concat();
        let du6 = [&du[..], &[2.0]].concat();
        let dv6 = [&dv[..], &[0.0]].concat();
        let m = track(&ax6, &ay6, &bx, &by, &du6, &dv6, 1.5).unwrap();
        assert_eq!(
            m.status,
            vec![MATCHED, NONE, SEVERAL, CLAIMED, NO_PREDICTOR, CLAIMED]
        );
        assert_eq!(m.partner, vec![0, -1, -1, -1, -1, -1]);
    }

    #[test]
    fn every_pair_of_a_sparse_random_set_is_found() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let n = 4000;
        let ax: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..2000.0)).collect();
        let ay: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1000.0)).collect();
        let (du, dv) = (vec![5.0; n], vec![-1.0; n]);
        // B: each A moved by (5, -1) plus up to 0.5 px, in reverse order
        let (mut bx, mut by) = (Vec::new(), Vec::new());
        for i in (0..n).rev() {
            bx.push(ax[i] + 5.0 + rng.random_range(-0.35..0.35));
            by.push(ay[i] - 1.0 + rng.random_range(-0.35..0.35));
        }
        let m = track(&ax, &ay, &bx, &by, &du, &dv, 0.5).unwrap();
        // 0.002 images per px^2: two within 1 px of each other are rare, but happen
        let matched = m.status.iter().filter(|&&s| s == MATCHED).count();
        assert!(matched > n * 99 / 100, "{matched} of {n}");
        for i in 0..n {
            if m.status[i] == MATCHED {
                assert_eq!(m.partner[i] as usize, n - 1 - i, "a wrong partner");
            }
        }
    }

    #[test]
    fn bad_input_is_refused() {
        assert!(track(&[1.0], &[1.0], &[1.0], &[1.0], &[0.0], &[0.0], 0.0).is_err());
        assert!(track(&[1.0], &[1.0, 2.0], &[1.0], &[1.0], &[0.0], &[0.0], 1.0).is_err());
        assert!(track(&[f64::NAN], &[1.0], &[1.0], &[1.0], &[0.0], &[0.0], 1.0).is_err());
        let m = track(&[], &[], &[1.0], &[1.0], &[], &[], 1.0).unwrap();
        assert!(m.status.is_empty());
        let m = track(&[1.0], &[1.0], &[], &[], &[0.0], &[0.0], 1.0).unwrap();
        assert_eq!(m.status, vec![NONE]);
    }

    #[test]
    fn stray_share_is_the_poisson_chance() {
        assert!(
            (stray_share(0.01, 2.0) - (1.0 - (-0.04 * std::f64::consts::PI).exp())).abs() < 1e-15
        );
    }
}
