//! A displacement field on a regular grid (the predictor of a pass), its bilinear interpolation
//! and its window average.

/// A displacement field on a regular grid, interpolated bilinearly (constant beyond the outer
/// grid points). Used as the predictor of a pass and for image deformation.
#[derive(Debug, Clone)]
pub struct GridField {
    /// The grid of the field.
    pub grid: crate::grid::Grid,
    /// x displacement (px) per grid point, shape (ny, nx).
    pub u: ndarray::Array2<f64>,
    /// y displacement (px) per grid point, shape (ny, nx).
    pub v: ndarray::Array2<f64>,
}

impl GridField {
    /// Interpolation index and weight along one axis.
    #[inline(always)]
    pub(crate) fn axis(p: f64, p0: f64, step: f64, n: usize) -> (usize, usize, f64) {
        if n == 1 {
            return (0, 0, 0.0);
        }
        let t = (p - p0) / step;
        if t <= 0.0 {
            (0, 0, 0.0)
        } else if t >= (n - 1) as f64 {
            (n - 1, n - 1, 0.0)
        } else {
            let i = t as usize; // t > 0: the cast is the floor
            (i, i + 1, t - i as f64)
        }
    }

    /// The y-interpolation state of row `y` for [`Self::at_row`].
    #[inline]
    pub fn row(&self, y: f64) -> (usize, usize, f64) {
        let g = &self.grid;
        Self::axis(y, g.y0, g.dy, g.ny)
    }

    /// Displacement at (x, y) with the row state of `y` from [`Self::row`].
    #[inline(always)]
    pub fn at_row(&self, row: &(usize, usize, f64), x: f64) -> (f64, f64) {
        let g = &self.grid;
        let (i0, i1, tx) = Self::axis(x, g.x0, g.dx, g.nx);
        let (j0, j1, ty) = *row;
        let nx = g.nx;
        let (us, vs) = (
            self.u.as_slice().expect("standard layout"),
            self.v.as_slice().expect("standard layout"),
        );
        let bl = |a: &[f64]| {
            let top = a[j0 * nx + i0] * (1.0 - tx) + a[j0 * nx + i1] * tx;
            let bot = a[j1 * nx + i0] * (1.0 - tx) + a[j1 * nx + i1] * tx;
            top * (1.0 - ty) + bot * ty
        };
        (bl(us), bl(vs))
    }

    /// The field averaged over a `w` x `h` px window (top-hat, the pixel areas
    /// `[x - w/2, x + w/2] x [y - h/2, y + h/2]`) of its bilinear interpolant, at every grid
    /// point: the displacement a window centred there measures when the frames move by this
    /// field. Used to filter a pass's predictor with the window of the pass (see
    /// [`crate::multipass`]). Beyond the outer grid points the field is constant, as in
    /// [`Self::at`].
    pub fn window_average(&self, w: usize, h: usize) -> GridField {
        let g = &self.grid;
        let wx = tophat_weights(w as f64, g.dx, g.nx);
        let wy = tophat_weights(h as f64, g.dy, g.ny);
        let filt = |a: &ndarray::Array2<f64>| {
            let (ny, nx) = (g.ny as isize, g.nx as isize);
            let rows = ndarray::Array2::from_shape_fn((g.ny, g.nx), |(j, i)| {
                wx.iter()
                    .map(|&(o, wt)| wt * a[[j, (i as isize + o).clamp(0, nx - 1) as usize]])
                    .sum::<f64>()
            });
            ndarray::Array2::from_shape_fn((g.ny, g.nx), |(j, i)| {
                wy.iter()
                    .map(|&(o, wt)| wt * rows[[(j as isize + o).clamp(0, ny - 1) as usize, i]])
                    .sum::<f64>()
            })
        };
        GridField {
            grid: self.grid,
            u: filt(&self.u),
            v: filt(&self.v),
        }
    }

    /// The mean of the field's bilinear interpolant (constant beyond the outer grid points, as
    /// [`Self::at`]) over the `w` x `h` px window centred at (x, y) (top-hat, the pixel areas
    /// `[x - w/2, x + w/2] x [y - h/2, y + h/2]`): the displacement a deformed window centred
    /// there measures when the frames move by this field. At grid points it equals
    /// [`Self::window_average`]; between them it is exact where the bilinear interpolation of
    /// the averaged nodes is not (a curved field's chord error).
    pub fn window_mean_at(&self, x: f64, y: f64, w: usize, h: usize) -> (f64, f64) {
        let g = &self.grid;
        let nx = g.nx;
        let (us, vs) = (
            self.u.as_slice().expect("standard layout"),
            self.v.as_slice().expect("standard layout"),
        );
        let (mut su, mut sv) = (0.0, 0.0);
        box_weights(y, g.y0, g.dy, g.ny, h as f64, |j, wy| {
            box_weights(x, g.x0, g.dx, nx, w as f64, |i, wx| {
                let k = j * nx + i;
                su += wy * wx * us[k];
                sv += wy * wx * vs[k];
            });
        });
        (su, sv)
    }

    /// The mean of the field's bilinear interpolant over the pixel centres of the window
    /// centred at (x, y) whose columns and rows weigh `px` and `py` (each summing to 1; the
    /// window is `px.len()` px wide, `py.len()` tall; pixel `i` at `x - (w - 1) / 2 + i`): the
    /// displacement a deformed window weighted so measures ([`crate::weighting`]).
    ///
    /// The interpolant is separable: the pixels' weights are gathered onto the grid nodes of
    /// each axis (at most `NODE_SPAN` nodes per axis on the stack; wider spans sum the
    /// pixels directly), then one small double sum over the nodes.
    pub fn weighted_mean_at(&self, x: f64, y: f64, px: &[f64], py: &[f64]) -> (f64, f64) {
        let g = &self.grid;
        let x0 = x - (px.len() as f64 - 1.0) / 2.0;
        let y0 = y - (py.len() as f64 - 1.0) / 2.0;
        let (mut cx, mut cy) = ([0.0f64; NODE_SPAN], [0.0f64; NODE_SPAN]);
        let bx = node_weights(px, x0, g.x0, g.dx, g.nx, &mut cx);
        let by = node_weights(py, y0, g.y0, g.dy, g.ny, &mut cy);
        let (Some((bx, nx)), Some((by, ny))) = (bx, by) else {
            return self.weighted_mean_direct(x0, y0, px, py);
        };
        let stride = g.nx;
        let (us, vs) = (
            self.u.as_slice().expect("standard layout"),
            self.v.as_slice().expect("standard layout"),
        );
        let (mut su, mut sv) = (0.0, 0.0);
        for (j, &wy) in cy[..ny].iter().enumerate() {
            let row = (by + j) * stride + bx;
            let (mut ru, mut rv) = (0.0, 0.0);
            for (i, &wx) in cx[..nx].iter().enumerate() {
                ru += wx * us[row + i];
                rv += wx * vs[row + i];
            }
            su += wy * ru;
            sv += wy * rv;
        }
        (su, sv)
    }

    /// [`Self::weighted_mean_at`] summed pixel by pixel (window corner `(x0, y0)`).
    fn weighted_mean_direct(&self, x0: f64, y0: f64, px: &[f64], py: &[f64]) -> (f64, f64) {
        let (mut su, mut sv) = (0.0, 0.0);
        for (j, &wy) in py.iter().enumerate() {
            let row = self.row(y0 + j as f64);
            let (mut ru, mut rv) = (0.0, 0.0);
            for (i, &wx) in px.iter().enumerate() {
                let (u, v) = self.at_row(&row, x0 + i as f64);
                ru += wx * u;
                rv += wx * v;
            }
            su += wy * ru;
            sv += wy * rv;
        }
        (su, sv)
    }

    /// Displacement (u, v) at (x, y).
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        let g = &self.grid;
        let (i0, i1, tx) = Self::axis(x, g.x0, g.dx, g.nx);
        let (j0, j1, ty) = Self::axis(y, g.y0, g.dy, g.ny);
        let bl = |a: &ndarray::Array2<f64>| {
            let top = a[[j0, i0]] * (1.0 - tx) + a[[j0, i1]] * tx;
            let bot = a[[j1, i0]] * (1.0 - tx) + a[[j1, i1]] * tx;
            top * (1.0 - ty) + bot * ty
        };
        (bl(&self.u), bl(&self.v))
    }
}

/// Most grid nodes per axis that [`GridField::weighted_mean_at`] gathers on the stack.
pub const NODE_SPAN: usize = 64;

/// The weights `w[i]` of the pixels `p0 + i` of one axis gathered onto the grid nodes
/// `first + k` of the axis `g0 + n step` (`n < count`; linear interpolation, constant beyond
/// the outer nodes) into `out[k]`: `Some((first, nodes))`, or `None` when the pixels span more
/// than [`NODE_SPAN`] nodes.
#[inline]
fn node_weights(
    w: &[f64],
    p0: f64,
    g0: f64,
    step: f64,
    count: usize,
    out: &mut [f64; NODE_SPAN],
) -> Option<(usize, usize)> {
    let first = GridField::axis(p0, g0, step, count).0;
    let last = GridField::axis(p0 + (w.len() as f64 - 1.0), g0, step, count).1;
    let nodes = last.checked_sub(first)? + 1;
    if nodes > NODE_SPAN {
        return None;
    }
    for (i, &wi) in w.iter().enumerate() {
        let (i0, i1, t) = GridField::axis(p0 + i as f64, g0, step, count);
        out[i0 - first] += wi * (1.0 - t);
        out[i1 - first] += wi * t;
    }
    Some((first, nodes))
}

/// The integral of the unit hat (support `[-1, 1]`) from `-inf` to `x`.
#[inline]
fn hat_int(x: f64) -> f64 {
    if x <= -1.0 {
        0.0
    } else if x <= 0.0 {
        0.5 * (x + 1.0) * (x + 1.0)
    } else if x <= 1.0 {
        1.0 - 0.5 * (1.0 - x) * (1.0 - x)
    } else {
        1.0
    }
}

/// Calls `f(node, weight)` for the nodes (indices clamped to `0..n`: the interpolant is constant
/// beyond the outer nodes) of an axis `p0 + i step` in the mean of their linear interpolant over
/// `[p - win/2, p + win/2]`; the weights sum to one. A single node, a window <= 0 or a bad step
/// give the plain linear interpolation weights.
#[inline]
fn box_weights(p: f64, p0: f64, step: f64, n: usize, win: f64, mut f: impl FnMut(usize, f64)) {
    if n < 2 || step.is_nan() || step <= 0.0 || win.is_nan() || win <= 0.0 {
        let (i0, i1, t) = GridField::axis(p, p0, step, n);
        f(i0, 1.0 - t);
        if t > 0.0 {
            f(i1, t);
        }
        return;
    }
    let t = (p - p0) / step;
    let a = 0.5 * win / step;
    let lo = (t - a).floor() as isize - 1;
    let hi = (t + a).ceil() as isize + 1;
    for i in lo..=hi {
        let wt = (hat_int(t + a - i as f64) - hat_int(t - a - i as f64)) / (2.0 * a);
        if wt > 0.0 {
            f(i.clamp(0, n as isize - 1) as usize, wt);
        }
    }
}

/// Weights `(node offset, weight)` of the grid nodes (spacing `step`, `n` of them) in the mean
/// of their linear interpolant over `[-win/2, win/2]` around a node; `[(0, 1)]` for a single
/// node. They sum to one.
pub(crate) fn tophat_weights(win: f64, step: f64, n: usize) -> Vec<(isize, f64)> {
    if n < 2 || step.is_nan() || step <= 0.0 || win.is_nan() || win <= 0.0 {
        return vec![(0, 1.0)];
    }
    let a = 0.5 * win / step;
    let reach = a.ceil() as isize + 1;
    (-reach..=reach)
        .map(|j| {
            (
                j,
                (hat_int(a - j as f64) - hat_int(-a - j as f64)) / (2.0 * a),
            )
        })
        .filter(|&(_, wt)| wt > 0.0)
        .collect()
}
