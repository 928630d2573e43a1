//! The region of interest of a PIV evaluation ([`PivSettings::roi`]): its checks, the part of
//! the frames read around it, and its grids.
//!
//! A region of interest is the rectangle `x0 <= x < x1`, `y0 <= y < y1` of pixels (x along the
//! columns, y along the rows, px of the frame the field lies in: the frames' own for
//! [`super::piv`], the object frame for the corrections of `correction-core`). Every pass's
//! grid is the whole frame's ([`Grid::for_windows`]) cut to the points whose windows lie
//! inside the region; the field's `x`, `y` and `grid` are in the frame's px, as without a
//! region.
//!
//! Only the region and a margin around it ([`margin`]) are read: windows displaced by the
//! search, the deformation and the interpolation's support read real pixels next to the region
//! as they would in the whole frame, and the time taken scales with the region's area. So the
//! vectors a few grid steps inside the region are the whole frame's (up to the frame-wide
//! statistics of the blank-window rule; the validation's neighbours and the predictor stop at
//! the region's edge), and a campaign run over a region measures what it measures over the
//! whole frame there.

use super::settings::PivSettings;
use crate::error::{PivError, Result};
use crate::grid::Grid;
use ndarray::{s, ArrayView2, SliceInfo, SliceInfoElem};
use serde::{Deserialize, Serialize};
use std::fmt;

/// A pass's grid in a region with rings of points around it ([`Roi::grid_ring`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RingGrid {
    /// The region's points and the rings around them (where the frames' grid has them).
    pub grid: Grid,
    /// The place `(column, row)` of `inner`'s first point in `grid`.
    pub at: (usize, usize),
    /// The region's own points ([`Roi::grid`]).
    pub inner: Grid,
}

/// A rectangle of pixels `x0 <= x < x1`, `y0 <= y < y1` (module docs). The vocabulary's JSON
/// form is `[x0, y0, x1, y1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(from = "[usize; 4]", into = "[usize; 4]")]
pub struct Roi {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

impl From<[usize; 4]> for Roi {
    fn from([x0, y0, x1, y1]: [usize; 4]) -> Roi {
        Roi { x0, y0, x1, y1 }
    }
}

impl From<Roi> for [usize; 4] {
    fn from(r: Roi) -> [usize; 4] {
        [r.x0, r.y0, r.x1, r.y1]
    }
}

impl fmt::Display for Roi {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "roi [{}, {}, {}, {}]",
            self.x0, self.y0, self.x1, self.y1
        )
    }
}

/// The rings of the frames' grid points beyond a region that every pass runs on as well
/// (where the frames have them; cut off at the end): the region's outer vectors get the
/// median test's neighbours and their pooled uncertainty, and the next pass's predictor (and
/// its window average for the deformation) is interpolated there rather than held at its edge
/// value. With window offset two rings make every vector of the region the whole frame's, bit
/// for bit; with one, the outer ring differed by up to 0.03 px (`tests/test_roi.py`).
pub const RINGS: usize = 2;

/// The margin (px) read around a region for settings `s`: the largest window dimension of any
/// pass, at least 64 px. It holds the first pass's search (half a window), the deformation's
/// half displacements within it, the interpolation's support and the memory of the B-spline
/// prefilter (its poles are at most 0.43 in magnitude: 0.43^64 ~ 1e-23).
pub fn margin(s: &PivSettings) -> usize {
    s.passes
        .iter()
        .map(|p| p.w.max(p.h))
        .max()
        .unwrap_or(0)
        .max(64)
}

impl Roi {
    /// Width (px along x).
    pub fn width(&self) -> usize {
        self.x1 - self.x0
    }

    /// Height (px along y).
    pub fn height(&self) -> usize {
        self.y1 - self.y0
    }

    /// Not empty (`x0 < x1`, `y0 < y1`); [`PivSettings::validate`] runs this.
    pub fn validate(&self) -> Result<()> {
        if self.x0 >= self.x1 || self.y0 >= self.y1 {
            return Err(PivError::InvalidInput(format!(
                "{self} is empty: give [x0, y0, x1, y1] with x0 < x1 and y0 < y1 (px)"
            )));
        }
        Ok(())
    }

    /// Check the region against frames of shape `dim` (rows, columns) and the windows of `s`:
    /// inside the frames, and every pass's grid has a window inside it.
    pub fn check(&self, dim: (usize, usize), s: &PivSettings) -> Result<()> {
        self.validate()?;
        let (h, w) = dim;
        if self.x1 > w || self.y1 > h {
            return Err(PivError::InvalidInput(format!(
                "{self} reaches beyond the frames ({w} x {h} px)"
            )));
        }
        for p in &s.passes {
            self.grid(p.w, p.h, p.overlap, dim, (0, 0))?;
        }
        Ok(())
    }

    /// The region grown by `m` px on every side, clipped to frames of shape `dim`.
    pub fn grown(&self, m: usize, dim: (usize, usize)) -> Roi {
        Roi {
            x0: self.x0.saturating_sub(m),
            y0: self.y0.saturating_sub(m),
            x1: (self.x1 + m).min(dim.1),
            y1: (self.y1 + m).min(dim.0),
        }
    }

    /// The smallest region holding the points `(xs, ys)` (px; non-finite ones left out)
    /// grown by `m` px and clipped to frames of shape `dim`; `None` if no point lies in them.
    pub fn around(xs: &[f64], ys: &[f64], m: usize, dim: (usize, usize)) -> Option<Roi> {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for (&x, &y) in xs.iter().zip(ys) {
            if x.is_finite() && y.is_finite() {
                lo = [lo[0].min(x), lo[1].min(y)];
                hi = [hi[0].max(x), hi[1].max(y)];
            }
        }
        let (h, w) = (dim.0 as f64, dim.1 as f64);
        let m = m as f64;
        let x0 = (lo[0] - m).floor().max(0.0);
        let y0 = (lo[1] - m).floor().max(0.0);
        let x1 = (hi[0] + m).ceil().min(w - 1.0) + 1.0;
        let y1 = (hi[1] + m).ceil().min(h - 1.0) + 1.0;
        (x0 < x1 && y0 < y1).then_some(Roi {
            x0: x0 as usize,
            y0: y0 as usize,
            x1: x1 as usize,
            y1: y1 as usize,
        })
    }

    /// The ndarray slice (rows, columns) of the region.
    pub fn slice(&self) -> SliceInfo<[SliceInfoElem; 2], ndarray::Ix2, ndarray::Ix2> {
        s![self.y0..self.y1, self.x0..self.x1]
    }

    /// The region of a frame or mask.
    pub fn view<'a, T>(&self, a: &ArrayView2<'a, T>) -> ArrayView2<'a, T> {
        (*a).slice_move(self.slice())
    }

    /// The grid of a pass of `w` x `h` windows at `overlap` on frames of shape `dim` (rows,
    /// columns; [`Grid::for_windows`]) cut to the points whose windows lie inside the region,
    /// in px of a crop of those frames whose pixel `(0, 0)` is the frames' `origin`.
    pub fn grid(
        &self,
        w: usize,
        h: usize,
        overlap: f64,
        dim: (usize, usize),
        origin: (usize, usize),
    ) -> Result<Grid> {
        Ok(self.grid_ring(w, h, overlap, dim, origin, 0)?.inner)
    }

    /// [`Self::grid`] with `ring` more points of the frames' grid on every side where it has
    /// them ([`RingGrid`]).
    pub fn grid_ring(
        &self,
        w: usize,
        h: usize,
        overlap: f64,
        dim: (usize, usize),
        origin: (usize, usize),
        ring: usize,
    ) -> Result<RingGrid> {
        let g = Grid::for_windows(dim.1, dim.0, w, h, overlap)?;
        // the points whose windows [c - (n - 1)/2, c + (n - 1)/2] lie in [lo, hi - 1]
        let cut = |c0: f64, d: f64, n: usize, count: usize, lo: usize, hi: usize| {
            let half = (n as f64 - 1.0) / 2.0;
            let first = ((lo as f64 + half - c0) / d).ceil().max(0.0) as usize;
            let last = ((hi as f64 - 1.0 - half - c0) / d).floor();
            if last < 0.0 {
                return None;
            }
            let last = (last as usize).min(count - 1);
            (last >= first).then_some((first, last - first + 1))
        };
        let (Some((i0, nx)), Some((j0, ny))) = (
            cut(g.x0, g.dx, w, g.nx, self.x0, self.x1),
            cut(g.y0, g.dy, h, g.ny, self.y0, self.y1),
        ) else {
            return Err(PivError::InvalidInput(format!(
                "{self} ({} x {} px) holds no {w} x {h} px window (w x h) of the frames' grid \
                 (every {} x {} px)",
                self.width(),
                self.height(),
                g.dx,
                g.dy
            )));
        };
        // the points i0 .. i0 + n of the frames' grid, in the crop's px
        let part = |i0: usize, j0: usize, nx: usize, ny: usize| Grid {
            x0: g.x0 + i0 as f64 * g.dx - origin.0 as f64,
            y0: g.y0 + j0 as f64 * g.dy - origin.1 as f64,
            nx,
            ny,
            ..g
        };
        let (ia, ja) = (i0.saturating_sub(ring), j0.saturating_sub(ring));
        let mx = (i0 + nx + ring).min(g.nx) - ia;
        let my = (j0 + ny + ring).min(g.ny) - ja;
        Ok(RingGrid {
            grid: part(ia, ja, mx, my),
            at: (i0 - ia, j0 - ja),
            inner: part(i0, j0, nx, ny),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multipass::Pass;

    #[test]
    fn checks_name_the_region() {
        let s = PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 8)],
            ..PivSettings::default()
        };
        let r = Roi::from([10, 20, 300, 120]);
        assert!(r.check((200, 400), &s).is_ok());
        let e = r.check((100, 400), &s).unwrap_err().to_string();
        assert!(
            e.contains("roi [10, 20, 300, 120] reaches beyond the frames (400 x 100 px)"),
            "{e}"
        );
        let e = Roi::from([10, 20, 60, 120])
            .check((200, 400), &s)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("roi [10, 20, 60, 120] (50 x 100 px) holds no 64 x 64 px window"),
            "{e}"
        );
        let e = Roi::from([10, 20, 10, 120])
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("is empty"), "{e}");
        assert_eq!(margin(&s), 64);
    }

    #[test]
    fn grown_around_and_grids() {
        let r = Roi::from([10, 20, 300, 120]);
        let g = r.grown(64, (150, 320));
        assert_eq!(g, Roi::from([0, 0, 320, 150]));
        let g = r.grown(5, (150, 320));
        assert_eq!(g, Roi::from([5, 15, 305, 125]));
        let a = Roi::around(&[10.5, 40.2, f64::NAN], &[3.0, 7.9, 1.0], 2, (100, 30)).unwrap();
        assert_eq!(a, Roi::from([8, 1, 30, 11]));
        assert!(Roi::around(&[f64::NAN], &[1.0], 2, (10, 10)).is_none());
        // the region's grid in a crop: the whole frame's points whose windows lie in it, moved
        let whole = Grid::for_windows(320, 150, 32, 8, 0.5).unwrap();
        assert_eq!(
            (whole.x0, whole.y0, whole.nx, whole.ny),
            (15.5, 4.5, 19, 36)
        );
        let grid = r.grid(32, 8, 0.5, (150, 320), (5, 15)).unwrap();
        // x: windows [x - 15.5, x + 15.5] inside [10, 299]: 31.5 ..= 271.5 (i = 1 ..= 16)
        // y: windows [y - 3.5, y + 3.5] inside [20, 119]: 24.5 ..= 112.5 (j = 5 ..= 27)
        assert_eq!((grid.x0, grid.y0), (31.5 - 5.0, 24.5 - 15.0));
        assert_eq!((grid.nx, grid.ny, grid.dx, grid.dy), (16, 23, 16.0, 4.0));
        // one point more on every side (the frames' grid has them)
        let ring = r.grid_ring(32, 8, 0.5, (150, 320), (5, 15), 1).unwrap();
        let ext = ring.grid;
        assert_eq!((ring.at, ring.inner), ((1, 1), grid));
        assert_eq!(
            (ext.x0, ext.y0, ext.nx, ext.ny),
            (grid.x0 - 16.0, grid.y0 - 4.0, 18, 25)
        );
        // at the frames' edge there is none
        let ring = Roi::from([0, 0, 320, 150])
            .grid_ring(32, 8, 0.5, (150, 320), (0, 0), 1)
            .unwrap();
        assert_eq!((ring.at, ring.grid, ring.inner), ((0, 0), whole, whole));
    }
}
