//! Do the indexed dots touch their lattice neighbours? ([`touching_share`]).
//!
//! A checkerboard's squares are found as dots (dark squares fit a blurred disc as well as a
//! printed disc does), on the lattice of the squares' diagonals, where neighbours touch at a
//! corner. The pitch a user gives, the square's side, is then not the lattice's (the diagonal,
//! sqrt(2) x the side, or 2 x the side when the two sublattices are taken for two levels), and a
//! calibration would be wrong by that factor. Between two adjacent dots of a dot target lies
//! background; between two diagonal squares lies only their corner.

use super::Pixel;
use ndarray::ArrayView2;

/// Median share of the segments between lattice neighbours as dark as the dots, above which
/// the dots touch (a checkerboard). Dots with gaps leave the segment's middle at the background:
/// 0 % for a diameter of 0.3 pitch, 27 % for 0.5, 40 % for 0.6, 53 % for 0.7, about 71 % for
/// 0.8 (rendered targets); real dot targets 0-27 % (discorpy's patterns); checkerboards 93 %
/// (a rendered one and PIVlab's ChArUco example board).
pub const TOUCH_SHARE: f64 = 0.85;

/// Pairs of lattice neighbours needed for an answer.
const MIN_PAIRS: usize = 8;

/// Samples per segment, over its middle 70 % (t = 0.15 .. 0.85).
const SAMPLES: usize = 15;

/// The median over the pairs of lattice neighbours (`index` differing by one step along i or
/// j) of the share of their segment's samples nearer the dots' level than the background's:
/// the dots' level is the mean of the image at the two centres (bilinear), the background that
/// level plus the mean of the two `amplitude` magnitudes (counts), brighter for `dark` dots.
/// Returns `(share, pairs)`, or `None` with fewer than 8 pairs. `points[k]` is `(x, y)` px,
/// `index[k]` its lattice site or `None`.
pub fn touching_share<T: Pixel>(
    image: ArrayView2<'_, T>,
    points: &[[f64; 2]],
    index: &[Option<(i32, i32)>],
    amplitude: &[f64],
    dark: bool,
) -> Option<(f64, usize)> {
    let sites: std::collections::HashMap<(i32, i32), usize> = index
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.map(|s| (s, k)))
        .collect();
    let side = if dark { 1.0 } else { -1.0 };
    let mut shares = Vec::new();
    for (&(i, j), &a) in &sites {
        for step in [(1, 0), (0, 1)] {
            let Some(&b) = sites.get(&(i + step.0, j + step.1)) else {
                continue;
            };
            let (p, q) = (points[a], points[b]);
            let level = 0.5 * (bilinear(&image, p) + bilinear(&image, q));
            let contrast = 0.5 * (amplitude[a].abs() + amplitude[b].abs());
            let near = (0..SAMPLES)
                .filter(|&s| {
                    let t = 0.15 + 0.7 * s as f64 / (SAMPLES - 1) as f64;
                    let xy = [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])];
                    (bilinear(&image, xy) - level) * side < 0.5 * contrast
                })
                .count();
            shares.push(near as f64 / SAMPLES as f64);
        }
    }
    if shares.len() < MIN_PAIRS {
        return None;
    }
    shares.sort_by(|a, b| a.total_cmp(b));
    let n = shares.len();
    let median = if n % 2 == 1 {
        shares[n / 2]
    } else {
        0.5 * (shares[n / 2 - 1] + shares[n / 2])
    };
    Some((median, n))
}

/// `image` at `(x, y)` px, bilinear, clamped to the image.
fn bilinear<T: Pixel>(image: &ArrayView2<'_, T>, [x, y]: [f64; 2]) -> f64 {
    let (h, w) = image.dim();
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let v = |r: usize, c: usize| image[[r, c]].to_f32() as f64;
    let top = v(y0, x0) * (1.0 - fx) + v(y0, x1) * fx;
    let bot = v(y1, x0) * (1.0 - fx) + v(y1, x1) * fx;
    top * (1.0 - fy) + bot * fy
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    /// An image, its dots' centres and their lattice sites.
    type Lattice = (Array2<f32>, Vec<[f64; 2]>, Vec<Option<(i32, i32)>>);

    /// A lattice of `n x n` square dots of side `s` at pitch `pitch` (dark 30 on 200).
    fn squares(n: usize, pitch: f64, s: f64) -> Lattice {
        let size = (pitch * (n as f64 + 1.0)) as usize;
        let mut img = Array2::from_elem((size, size), 200.0f32);
        let mut pts = Vec::new();
        let mut idx = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (cx, cy) = (pitch * (i as f64 + 1.0), pitch * (j as f64 + 1.0));
                pts.push([cx, cy]);
                idx.push(Some((i as i32, j as i32)));
                for ((r, c), v) in img.indexed_iter_mut() {
                    if ((c as f64 - cx).abs() <= s / 2.0) && ((r as f64 - cy).abs() <= s / 2.0) {
                        *v = 30.0;
                    }
                }
            }
        }
        (img, pts, idx)
    }

    #[test]
    fn dots_with_gaps_leave_background_touching_squares_do_not() {
        // gaps of half the pitch: the middle third of every segment is background
        let (img, pts, idx) = squares(4, 20.0, 10.0);
        let amp = vec![170.0; pts.len()];
        let (share, pairs) = touching_share(img.view(), &pts, &idx, &amp, true).unwrap();
        assert_eq!(pairs, 24);
        // samples at t = 0.15 .. 0.85 in 14 steps of 0.05: dark while within 5 px of a centre
        // (t <= 0.25 or t >= 0.75): 3 + 3 of 15
        assert!((share - 6.0 / 15.0).abs() < 1e-12, "{share}");
        // squares as wide as the pitch: the segment is dark throughout
        let (img, pts, idx) = squares(4, 20.0, 20.0);
        let (share, _) = touching_share(img.view(), &pts, &idx, &amp, true).unwrap();
        assert_eq!(share, 1.0);
        assert!(share > TOUCH_SHARE);
        // bright dots on a dark background: the same, with the sides swapped
        let inv = img.mapv(|v| 230.0 - v);
        let (share, _) = touching_share(inv.view(), &pts, &idx, &amp, false).unwrap();
        assert_eq!(share, 1.0);
        // too few pairs: no answer
        assert!(touching_share(img.view(), &pts[..4], &idx[..4], &amp, true).is_none());
    }
}
