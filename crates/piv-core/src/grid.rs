//! Regular grids of interrogation-window centres.

use crate::error::{PivError, Result};

/// Window centres `x = x0 + i dx` (i < nx), `y = y0 + j dy` (j < ny), pixel frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub x0: f64,
    pub y0: f64,
    pub dx: f64,
    pub dy: f64,
    pub nx: usize,
    pub ny: usize,
}

impl Grid {
    /// The grid of one pass: windows `w` px wide (along x) and `h` px tall (along y) with the
    /// given fractional overlap, the whole grid centred in the image, every window inside it
    /// with its top-left pixel on an integer position.
    pub fn for_windows(
        width: usize,
        height: usize,
        w: usize,
        h: usize,
        overlap: f64,
    ) -> Result<Grid> {
        if w < 4 || h < 4 {
            return Err(PivError::InvalidInput(format!(
                "window {w} x {h} px is too small (at least 4 x 4)"
            )));
        }
        if w > width || h > height {
            return Err(PivError::InvalidInput(format!(
                "window {w} x {h} px (w x h) is larger than the image ({width} x {height} px)"
            )));
        }
        if !(0.0..1.0).contains(&overlap) || !overlap.is_finite() {
            return Err(PivError::InvalidInput(format!(
                "overlap {overlap} is outside [0, 1)"
            )));
        }
        let sx = ((w as f64 * (1.0 - overlap)).round() as usize).max(1);
        let sy = ((h as f64 * (1.0 - overlap)).round() as usize).max(1);
        let nx = (width - w) / sx + 1;
        let ny = (height - h) / sy + 1;
        let mx = (width - w - (nx - 1) * sx) / 2;
        let my = (height - h - (ny - 1) * sy) / 2;
        Ok(Grid {
            x0: mx as f64 + (w as f64 - 1.0) / 2.0,
            y0: my as f64 + (h as f64 - 1.0) / 2.0,
            dx: sx as f64,
            dy: sy as f64,
            nx,
            ny,
        })
    }

    /// Number of grid points.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// `true` if the grid has no point.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Centre of point `(j, i)` (row, column).
    #[inline]
    pub fn xy(&self, j: usize, i: usize) -> (f64, f64) {
        (self.x0 + i as f64 * self.dx, self.y0 + j as f64 * self.dy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_is_centred_and_inside() {
        let g = Grid::for_windows(100, 50, 32, 8, 0.5).unwrap();
        assert_eq!((g.dx, g.dy), (16.0, 4.0));
        assert_eq!(g.nx, (100 - 32) / 16 + 1);
        assert_eq!(g.ny, (50 - 8) / 4 + 1);
        let (x_last, y_last) = g.xy(g.ny - 1, g.nx - 1);
        let left = g.x0 - 15.5;
        let right = 99.0 - (x_last + 15.5);
        assert!(left >= 0.0 && right >= 0.0 && (left - right).abs() <= 1.0);
        assert!(y_last + 3.5 <= 49.0);
        assert!(Grid::for_windows(20, 50, 32, 8, 0.5).is_err());
    }
}
