//! Grid indexing: give each detected marker its (i, j) place on the target's square grid.
//!
//! 1. **Origin.** Candidates are tried in order of distance to `centre` (the image centre): the
//!    first whose nearest neighbours contain two antipodal pairs (`p + e`, `p - e` both present
//!    within `tol |e|`) along two directions 60-120 degrees apart with lengths within 30 % of
//!    each other is the origin (0, 0). A spurious blob has no such neighbourhood. The pair closer
//!    to the x axis gives the step `a1` (pointing to +x), the other `a2` (pointing to +y, down).
//! 2. **Growth.** Breadth-first from the origin: the neighbour (i + di, j + dj) of an indexed
//!    marker p is predicted at `p + step`, where `step` is the last step along that direction
//!    (`p - p(i - di, j - dj)`) when that marker is indexed (this follows the distortion), else
//!    the origin's `a1` / `a2`. The unassigned detection nearest the prediction within
//!    `tol |step|` is taken. Missing markers are walked around through the other neighbours;
//!    spurious blobs are never near a prediction. Rotations of any angle below 45 degrees and
//!    distortions of a few percent per pitch are followed.
//! 3. **Regularity.** The median distance of the markers from their predictions, over the step,
//!    must stay below [`MAX_IRREGULARITY`] (a cloud of particles forms no lattice). A two-level
//!    plate seen obliquely is two interleaved lattices, the second shifted by a parallax `t`
//!    against the first's half-pitch sites: its union's steps alternate `a + t` and `a - t`,
//!    so each prediction errs by `+2t` into the even class (`i + j` even) and `-2t` into the
//!    odd one. The regularity is therefore the smaller of the plain median and the median after
//!    removing that class-signed mean (the median of the signed errors): for one lattice the two
//!    agree; for a random cloud the signed errors have no common direction and nothing changes.
//!    The growth follows a parallax up to 15 % of the union's step (`2t` within `tol = 0.3`).

use crate::error::{DewarpError, Result};
use std::collections::{HashMap, VecDeque};

/// Per point: its grid index or `None`.
type Indices = Vec<Option<(i32, i32)>>;

/// Largest median deviation of indexed markers from their predicted sites, as a fraction of the
/// local step, that is still a lattice.
pub const MAX_IRREGULARITY: f64 = 0.08;

/// At most this many points nearest the centre are tried as the origin.
pub const ORIGIN_CANDIDATES: usize = 256;

/// Result of [`index_grid`].
#[derive(Debug, Clone, PartialEq)]
pub struct GridIndex {
    /// Per input point: its (i, j) on the grid (i along +x, j along +y) or `None` (not a marker).
    pub index: Vec<Option<(i32, i32)>>,
    /// Input index of the origin marker (0, 0).
    pub origin: usize,
    /// Grid steps at the origin (image px): a1 along i, a2 along j.
    pub a1: [f64; 2],
    pub a2: [f64; 2],
    /// Median distance of the indexed markers from their predicted sites over the local step.
    pub irregularity: f64,
}

fn local_lattice(points: &[[f64; 2]], c: usize, tol: f64) -> Option<([f64; 2], [f64; 2])> {
    let n = points.len();
    let k = 8.min(n - 1);
    let mut near: Vec<(f64, usize)> = Vec::with_capacity(n);
    {
        let pc = points[c];
        near.clear();
        near.extend(
            (0..n)
                .filter(|&q| q != c)
                .map(|q| ((points[q][0] - pc[0]).hypot(points[q][1] - pc[1]), q)),
        );
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        near.truncate(k);
        // Antipodal pairs: (length, e).
        let mut pairs: Vec<(f64, [f64; 2])> = Vec::new();
        for a in 0..near.len() {
            for b in (a + 1)..near.len() {
                let (ua, ub) = (points[near[a].1], points[near[b].1]);
                let ea = [ua[0] - pc[0], ua[1] - pc[1]];
                let eb = [ub[0] - pc[0], ub[1] - pc[1]];
                let la = ea[0].hypot(ea[1]);
                let lb = eb[0].hypot(eb[1]);
                if la < 1e-9 || lb < 1e-9 {
                    continue;
                }
                let miss = (ea[0] + eb[0]).hypot(ea[1] + eb[1]);
                if miss < tol * la.min(lb) {
                    let e = [0.5 * (ea[0] - eb[0]), 0.5 * (ea[1] - eb[1])];
                    pairs.push((e[0].hypot(e[1]), e));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        // The shortest antipodal pair must be a grid step (else diagonals could pass as steps).
        if let Some(&(la, ea)) = pairs.first() {
            for &(lb, eb) in pairs.iter().skip(1) {
                if lb > 1.3 * la {
                    break;
                }
                let cos = (ea[0] * eb[0] + ea[1] * eb[1]) / (la * lb);
                if cos.abs() < 0.5 {
                    let (mut a1, mut a2) = if ea[0].abs() >= eb[0].abs() {
                        (ea, eb)
                    } else {
                        (eb, ea)
                    };
                    if a1[0] < 0.0 {
                        a1 = [-a1[0], -a1[1]];
                    }
                    if a2[1] < 0.0 {
                        a2 = [-a2[0], -a2[1]];
                    }
                    return Some((a1, a2));
                }
            }
        }
    }
    None
}

/// Index detected marker positions (image px) on a square grid; see the module documentation.
/// `tol` is the acceptance radius as a fraction of the local grid step (0.3 is a good value).
pub fn index_grid(points: &[[f64; 2]], centre: [f64; 2], tol: f64) -> Result<GridIndex> {
    let n = points.len();
    if n < 5 {
        return Err(DewarpError::InvalidInput(format!(
            "grid indexing: {n} markers detected, at least 5 (a marker and its 4 neighbours) are needed"
        )));
    }
    if !(tol > 0.0 && tol < 0.5) {
        return Err(DewarpError::InvalidInput(format!(
            "grid indexing: tolerance {tol} must lie in (0, 0.5)"
        )));
    }
    if points
        .iter()
        .any(|p| !(p[0].is_finite() && p[1].is_finite()))
        || !(centre[0].is_finite() && centre[1].is_finite())
    {
        return Err(DewarpError::InvalidInput(
            "grid indexing: non-finite marker position".into(),
        ));
    }
    let mut order: Vec<usize> = (0..n).collect();
    let d2 = |p: [f64; 2]| (p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2);
    order.sort_by(|&a, &b| d2(points[a]).total_cmp(&d2(points[b])));
    // Try the first few grid-like candidates nearest the centre; keep the largest grid.
    // (count, indices, a1, a2, deviations) of the largest grid grown so far.
    type Grown = (usize, Indices, [f64; 2], [f64; 2], Vec<Deviation>);
    let mut best: Option<Grown> = None;
    let mut tried = 0;
    let buckets = Buckets::new(points);
    // Origin candidates: the points nearest the centre (a lattice has one among them; the
    // cap keeps a cloud without any lattice from costing O(n^2 log n)).
    for &c in order.iter().take(ORIGIN_CANDIDATES) {
        let Some((a1, a2)) = local_lattice(points, c, tol) else {
            continue;
        };
        let (idx, count, dev) = grow(points, &buckets, c, a1, a2, tol);
        if best.as_ref().is_none_or(|b| count > b.0) {
            best = Some((count, idx, a1, a2, dev));
        }
        tried += 1;
        if tried >= 6 || count * 2 > n {
            break;
        }
    }
    let Some((count, mut index, a1, a2, mut dev)) = best else {
        return Err(DewarpError::InvalidInput(
            "grid indexing: no marker has a grid-like neighbourhood (no grid in the image?)".into(),
        ));
    };
    if count < 5 {
        return Err(DewarpError::InvalidInput(format!(
            "grid indexing: only {count} markers form a grid, at least 5 are needed"
        )));
    }
    // Prune markers with fewer than two indexed 4-neighbours (repeatedly): a blob that extends
    // the grid beyond its edge touches only the marker that predicted it. (A real corner marker
    // whose neighbour is missing is lost too, which costs one point, never a wrong one.)
    loop {
        let at: HashMap<(i32, i32), usize> = index
            .iter()
            .enumerate()
            .filter_map(|(q, v)| v.map(|k| (k, q)))
            .collect();
        let mut changed = false;
        for (&(i, j), &q) in &at {
            let nb = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .filter(|(di, dj)| at.contains_key(&(i + di, j + dj)))
                .count();
            if nb < 2 {
                index[q] = None;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let count = index.iter().filter(|v| v.is_some()).count();
    if count < 5 {
        return Err(DewarpError::InvalidInput(format!(
            "grid indexing: only {count} markers form a grid, at least 5 are needed"
        )));
    }
    let irregularity = irregularity(&mut dev);
    if irregularity > MAX_IRREGULARITY {
        return Err(DewarpError::InvalidInput(format!(
            "grid indexing: the {count} points found form no regular lattice (median deviation \
             from the predicted site {:.0} % of the pitch, a target's is below {:.0} %): not a \
             target?",
            100.0 * irregularity,
            100.0 * MAX_IRREGULARITY
        )));
    }
    // Re-centre on the indexed marker nearest the centre.
    let origin = order
        .iter()
        .copied()
        .find(|&q| index[q].is_some())
        .unwrap_or(0);
    let o = index[origin].unwrap_or((0, 0));
    for v in index.iter_mut().flatten() {
        *v = (v.0 - o.0, v.1 - o.1);
    }
    Ok(GridIndex {
        index,
        origin,
        a1,
        a2,
        irregularity,
    })
}

/// A marker's miss of its prediction over the step, and the parity sign of its site (+1 for
/// `i + j` even).
#[derive(Debug, Clone, Copy)]
struct Deviation {
    e: [f64; 2],
    sign: f64,
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// The regularity of a grown grid (module documentation, step 3).
fn irregularity(dev: &mut [Deviation]) -> f64 {
    let mut plain: Vec<f64> = dev.iter().map(|d| d.e[0].hypot(d.e[1])).collect();
    let plain = median(&mut plain);
    // The class-signed common error (2t over the step): the median of the signed errors.
    let mut sx: Vec<f64> = dev.iter().map(|d| d.sign * d.e[0]).collect();
    let mut sy: Vec<f64> = dev.iter().map(|d| d.sign * d.e[1]).collect();
    let m = [median(&mut sx), median(&mut sy)];
    let mut two: Vec<f64> = dev
        .iter()
        .map(|d| (d.e[0] - d.sign * m[0]).hypot(d.e[1] - d.sign * m[1]))
        .collect();
    plain.min(median(&mut two))
}

/// Points bucketed on a square grid of cells (about 4 points per cell) for the growth's
/// nearest-to-prediction queries.
struct Buckets {
    cell: f64,
    x0: f64,
    y0: f64,
    cells: HashMap<(i64, i64), Vec<usize>>,
}

impl Buckets {
    fn new(points: &[[f64; 2]]) -> Self {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in points {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        let area = ((x1 - x0) * (y1 - y0)).max(1.0);
        let cell = (4.0 * area / points.len().max(1) as f64).sqrt().max(1.0);
        let mut cells: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
        for (q, p) in points.iter().enumerate() {
            let key = (((p[0] - x0) / cell) as i64, ((p[1] - y0) / cell) as i64);
            cells.entry(key).or_default().push(q);
        }
        Buckets {
            cell,
            x0,
            y0,
            cells,
        }
    }

    /// Calls `f(q)` for every point within the cells covering the disc `(c, rad)`.
    fn near(&self, c: [f64; 2], rad: f64, mut f: impl FnMut(usize)) {
        let ka = (((c[0] - rad - self.x0) / self.cell).floor() as i64).max(-1);
        let kb = ((c[0] + rad - self.x0) / self.cell).floor() as i64;
        let la = (((c[1] - rad - self.y0) / self.cell).floor() as i64).max(-1);
        let lb = ((c[1] + rad - self.y0) / self.cell).floor() as i64;
        if (kb - ka + 1).saturating_mul(lb - la + 1) > 4 * self.cells.len() as i64 {
            // A radius wider than the cloud: look at every cell.
            self.cells.values().flatten().for_each(|&q| f(q));
            return;
        }
        for k in ka..=kb {
            for l in la..=lb {
                if let Some(v) = self.cells.get(&(k, l)) {
                    v.iter().for_each(|&q| f(q));
                }
            }
        }
    }
}

/// Grow the grid from `origin`: the indices, their count and each added marker's distance from
/// its prediction over the step.
fn grow(
    points: &[[f64; 2]],
    buckets: &Buckets,
    origin: usize,
    a1: [f64; 2],
    a2: [f64; 2],
    tol: f64,
) -> (Indices, usize, Vec<Deviation>) {
    let n = points.len();
    let mut dev = Vec::new();
    let mut index: Indices = vec![None; n];
    let mut at: HashMap<(i32, i32), usize> = HashMap::new();
    index[origin] = Some((0, 0));
    at.insert((0, 0), origin);
    let mut queue = VecDeque::from([(0i32, 0i32)]);
    while let Some((i, j)) = queue.pop_front() {
        let p = points[at[&(i, j)]];
        for (di, dj) in [(1i32, 0i32), (-1, 0), (0, 1), (0, -1)] {
            let key = (i + di, j + dj);
            if at.contains_key(&key) {
                continue;
            }
            let step = match at.get(&(i - di, j - dj)) {
                Some(&b) => [p[0] - points[b][0], p[1] - points[b][1]],
                None => {
                    let e = if di != 0 { a1 } else { a2 };
                    let sgn = (di + dj) as f64;
                    [sgn * e[0], sgn * e[1]]
                }
            };
            let pred = [p[0] + step[0], p[1] + step[1]];
            let len = step[0].hypot(step[1]);
            let rad = tol * len;
            let mut best: Option<(f64, usize)> = None;
            buckets.near(pred, rad, |q| {
                if index[q].is_some() {
                    return;
                }
                let dd = (points[q][0] - pred[0]).hypot(points[q][1] - pred[1]);
                // Ties go to the lower index, as a scan in order would.
                if dd < rad && best.is_none_or(|(b, bq)| dd < b || (dd == b && q < bq)) {
                    best = Some((dd, q));
                }
            });
            if let Some((_, q)) = best {
                let sign = if (key.0 + key.1).rem_euclid(2) == 0 {
                    1.0
                } else {
                    -1.0
                };
                let inv = 1.0 / len.max(1e-300);
                dev.push(Deviation {
                    e: [
                        (points[q][0] - pred[0]) * inv,
                        (points[q][1] - pred[1]) * inv,
                    ],
                    sign,
                });
                index[q] = Some(key);
                at.insert(key, q);
                queue.push_back(key);
            }
        }
    }
    let count = at.len();
    (index, count, dev)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(
        rot_deg: f64,
        missing: &[(i32, i32)],
        spurious: &[[f64; 2]],
    ) -> (Vec<[f64; 2]>, Indices) {
        let (c, s) = (rot_deg.to_radians().cos(), rot_deg.to_radians().sin());
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for j in -3..=3 {
            for i in -6..=6 {
                if missing.contains(&(i, j)) {
                    continue;
                }
                let (x, y) = (100.0 * i as f64, 100.0 * j as f64);
                // 1.5 % pincushion at the corner.
                let r2 = (x * x + y * y) / (670.0f64 * 670.0);
                let k = 1.0 + 0.015 * r2;
                pts.push([700.0 + k * (c * x - s * y), 400.0 + k * (s * x + c * y)]);
                truth.push(Some((i, j)));
            }
        }
        for p in spurious {
            pts.push(*p);
            truth.push(None);
        }
        (pts, truth)
    }

    #[test]
    fn survives_missing_spurious_rotation_and_distortion() {
        let spurious = [
            [652.0, 447.0],
            [700.0, 350.0],
            [30.0, 40.0],
            [1200.0, 95.0],
            [960.0, 720.0],
            [-24.0, 681.0], // at the virtual site (-7, 3), beyond the edge: one neighbour
        ];
        let (pts, truth) = grid(2.0, &[(1, 0), (-3, 2), (6, -3)], &spurious);
        let g = index_grid(&pts, [705.0, 405.0], 0.3).unwrap();
        // Indices are relative to the origin marker: compare relative to it.
        let o = truth[g.origin].unwrap();
        let rel: Vec<_> = truth
            .iter()
            .map(|t| t.map(|(i, j)| (i - o.0, j - o.1)))
            .collect();
        assert_eq!(g.index, rel);
        let (pts, truth) = grid(-4.0, &[], &[]);
        assert_eq!(index_grid(&pts, [690.0, 390.0], 0.3).unwrap().index, truth);
    }

    #[test]
    fn random_points_are_no_lattice() {
        // A dense random cloud (particles): every prediction finds some point within the
        // tolerance, but never where a lattice would put it.
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts: Vec<[f64; 2]> = (0..3000).map(|_| [1152.0 * rnd(), 768.0 * rnd()]).collect();
        let e = index_grid(&pts, [576.0, 384.0], 0.3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no regular lattice"), "{e}");
        // A distorted lattice is regular: its deviations are far below the limit.
        let (pts, _) = grid(3.0, &[], &[]);
        let g = index_grid(&pts, [700.0, 400.0], 0.3).unwrap();
        assert!(g.irregularity < 0.01, "{}", g.irregularity);
    }

    #[test]
    fn two_interleaved_lattices_with_parallax_are_one_regular_union() {
        // A two-level staggered plate seen obliquely: level 2 at the half-pitch sites, shifted
        // by a parallax of 10 % of the union's pitch against level 1 (OpenPTV's 4-camera plate
        // shows 9-10 %). The union's axes here are the image's; each level's are at 45 degrees.
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for j in -6..=6i32 {
            for i in -9..=9i32 {
                let shift = if (i + j).rem_euclid(2) == 1 {
                    10.0
                } else {
                    0.0
                };
                pts.push([
                    800.0 + 100.0 * i as f64 + shift,
                    700.0 + 100.0 * j as f64 + 0.3 * shift,
                ]);
                truth.push((i, j));
            }
        }
        // The plain median miss is 2t / a = 20 %; with the class-signed mean removed only the
        // steps' lengths (a +- t) differ, 1.2 %.
        let g = index_grid(&pts, [800.0, 700.0], 0.3).unwrap();
        assert!(g.irregularity < 0.02, "{}", g.irregularity);
        assert_eq!(g.index.iter().filter(|v| v.is_some()).count(), pts.len());
        let o = truth[g.origin];
        for (t, v) in truth.iter().zip(&g.index) {
            assert_eq!(v.unwrap(), (t.0 - o.0, t.1 - o.1));
        }
    }

    #[test]
    fn no_grid_is_an_error() {
        let pts: Vec<[f64; 2]> = (0..30)
            .map(|k| [(k * 37 % 101) as f64 * 9.1, (k * k % 53) as f64 * 7.3])
            .collect();
        assert!(index_grid(&pts, [400.0, 200.0], 0.3).is_err());
        assert!(index_grid(&pts[..3], [400.0, 200.0], 0.3).is_err());
    }
}
