"""Ensemble correlation: correlation planes summed over many pairs before the peak is found.

Near a wall the windows an instantaneous PIV needs (enough particles per window) are far taller
than the flow's smallest scale. Summing each window's correlation plane over the whole campaign
(Delnoij et al. 1999; Meinhart, Wereley & Santiago 2000) gives the mean displacement from
windows of a few px, and the summed peak's shape gives the displacement's covariance, i.e. the
Reynolds stresses (Scharnowski, Hain & Kähler 2012). The work per pixel runs in Rust
(``piv_core::ensemble``); the accumulator is a NumPy array that this module owns, so shards and
workers merge by adding it.

:class:`EnsembleAccumulator` holds ``n`` windows (``w`` x ``h`` px, w along x) at points
``(x, y)`` (pixel frame) offset symmetrically by ``(du, dv)`` per window (the mean displacement
predictor, e.g. a coarser ensemble or the instantaneous mean field);
:meth:`~EnsembleAccumulator.add` adds a pair, :meth:`~EnsembleAccumulator.result` fits the peaks:

- ``u, v``: offset + the peak's centre, px;
- ``uu, vv, uv``: the displacement covariance within the window, px^2: the cross peak's
  covariance minus the particle images' own (the auto peaks of both frames), minus the spread of
  the mean displacement over the window, ``J diag(w^2, h^2) J^T / 12`` with ``J`` the gradient of
  the mean field (finite differences on the grid; only for grid-shaped points).

With ``rows=True`` :meth:`~EnsembleAccumulator.result` sums the planes of each grid row before
fitting (a flow homogeneous along the rows): one peak from all the row's windows, which is what a
boundary-layer profile wants; :func:`band_grid` lays such rows along a wall and
:func:`profile_field` turns a wall-parallel profile into the ``deform=`` predictor (no slip at
the wall). :mod:`rspiv.campaign.ensemble` runs this in a campaign. :class:`PixelAccumulator`
(with :func:`pixel_band`, both in :mod:`rspiv.ensemble_pixel` and exported here) is the
single-pixel ensemble: one pixel row of frame A against the rows of frame B around it, summed
over the pairs and along the row (its limits in its Notes).

Accuracy: on pairs moved by Gaussian random displacements (Rust tests) the mean within
0.012 px and the covariances within 13 % at 16 x 4 px windows (9 % at 32 x 16). On the synthetic
boundary layer (``tests/test_ensemble_campaign.py``: viscous length 1.49 px, 80 pairs, 64 x 4 px
rows every 2 px, deformed by a 4-pair pilot's profile), against the exact statistics of the
same 80 realisations: the mean within 1.3 % from y+ = 1.5 and within 0.9 % above y+ = 2.8, uu
and vv at the uu+ peak within 10 %, uv within 15 %. Limits: a Gaussian is fitted to the summed
peak, so with tens of pairs per *window* (``rows=False``) its variance reads 5-15 % low (the
window's few displacement samples make a lumpy peak), and in the first row off the wall, where
the fluctuations grow across the window's height, the peak is a peaked mixture and uu reads
10-15 % low; a high-pass-filtered frame (negative side lobes) breaks the cross = auto * PDF
model, so the campaign correlates its bands on frames without the high-pass.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.ensemble_pixel import PixelAccumulator, SaturationTally, _wall_y, pixel_band
from rspiv.errors import InvalidInputError
from rspiv.settings import INTERPOLATIONS, parse_choice

__all__ = [
    "EnsembleAccumulator",
    "EnsembleField",
    "PixelAccumulator",
    "band_grid",
    "ensemble_grid",
    "pixel_band",
    "profile_field",
]


def _checked_layout(
    shape: tuple[int, int], window: tuple[int, int], step: tuple[float, float]
) -> tuple[tuple[int, int], tuple[int, int], tuple[float, float]]:
    """``shape``, ``window`` and ``step`` as ints/floats; InvalidInputError for a window thinner
    than 2 px or larger than the image, or a step that is not positive."""
    rows, cols = (int(s) for s in shape)
    w, h = (int(s) for s in window)
    sx, sy = (float(s) for s in step)
    if w < 2 or h < 2 or w > cols or h > rows:
        raise InvalidInputError(
            f"ensemble window {w} x {h} px does not fit the image ({cols} x {rows} px) or is "
            "thinner than 2 px"
        )
    if not (sx > 0 and sy > 0):
        raise InvalidInputError(f"ensemble grid step {step} must be positive")
    return (rows, cols), (w, h), (sx, sy)


def ensemble_grid(
    shape: tuple[int, int], window: tuple[int, int], step: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Window centres ``(x, y)`` (each ``(ny, nx)``) of ``window`` = ``(w, h)`` px windows every
    ``step = (sx, sy)`` px, every window inside an image of ``shape = (rows, columns)``."""
    (rows, cols), (w, h), (sx, sy) = _checked_layout(shape, window, step)
    xs = np.arange((w - 1) / 2, cols - (w - 1) / 2 - 0.5 + 1e-9, sx)
    ys = np.arange((h - 1) / 2, rows - (h - 1) / 2 - 0.5 + 1e-9, sy)
    return np.meshgrid(xs, ys)


def band_grid(
    shape: tuple[int, int],
    window: tuple[int, int],
    step: tuple[float, float],
    band_px: float,
    wall: Any,
    flow_side: str = "above",
    margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window centres in a band along a wall, the whole windows on the flow's side.

    Row ``k`` lies at wall distance ``d_k = h/2 + margin + k sy`` (px, positive into the flow)
    for every ``d_k + h/2 <= band_px``; the columns every ``sx`` px along x, every window inside
    the image. The rows follow the wall line: ``y = wall(x) - d_k`` when the flow is
    ``"above"`` the wall (at smaller y: the wall near the bottom of the image),
    ``wall(x) + d_k`` when ``"below"``.

    Parameters
    ----------
    shape : (int, int)
        Image (rows, columns).
    window : (int, int)
        ``(w, h)`` px, at least 2 x 2.
    step : (float, float)
        ``(sx, sy)`` px between centres along and away from the wall.
    band_px : float
        Height of the band from the wall, px.
    wall : float, callable or rspiv.Wall
        The wall's pixel y (a level wall), a function of x, or a found wall (its ``line``).
    flow_side : {"above", "below"}
    margin : float
        Gap (px) between the wall and the first row's windows: the wall's own uncertainty,
        so that no window reaches past the true wall into the reflections.

    Returns
    -------
    x, y : ndarray, shape (ny, nx)
        Window centres, px.
    dist : ndarray, shape (ny,)
        Each row's distance from the wall, px.

    Raises
    ------
    InvalidInputError
        A window thinner than 2 px or wider than the image, a band thinner than one window,
        a band that leaves the image (each row's windows must lie inside it at every column).
    """
    (rows, cols), (w, h), (sx, sy) = _checked_layout(shape, window, step)
    if flow_side not in ("above", "below"):
        raise InvalidInputError(f"flow_side must be 'above' or 'below', got {flow_side!r}")
    if not (band_px >= h):
        raise InvalidInputError(
            f"ensemble band of {band_px} px is thinner than its {w} x {h} px windows"
        )
    xs = np.arange((w - 1) / 2, cols - (w - 1) / 2 - 0.5 + 1e-9, sx)
    if not (margin >= 0 and band_px >= h + margin):
        raise InvalidInputError(
            f"ensemble band of {band_px} px cannot hold {w} x {h} px windows {margin} px off "
            "the wall"
        )
    dist = np.arange(h / 2 + margin, band_px - h / 2 + 1e-9, sy)
    sign = -1.0 if flow_side == "above" else 1.0
    wy = _wall_y(wall, xs)
    y = wy[None, :] + sign * dist[:, None]
    lo, hi = (h - 1) / 2, rows - 1 - (h - 1) / 2
    inside = np.all((y >= lo - 1e-9) & (y <= hi + 1e-9), axis=1)
    if not inside.all():
        first = float(np.min(wy))
        raise InvalidInputError(
            f"ensemble band of {band_px:g} px from the wall (at y = {first:.1f} px, flow "
            f"{flow_side}) leaves the {cols} x {rows} px image at {np.sum(~inside)} of "
            f"{dist.size} rows"
        )
    x = np.broadcast_to(xs[None, :], y.shape).copy()
    return x, y, dist


def profile_field(
    shape: tuple[int, int],
    wall: Any,
    flow_side: str,
    dist: Any,
    u: Any,
    v: Any,
    dx: float = 32.0,
) -> tuple[tuple[float, float, float, float], np.ndarray, np.ndarray]:
    """A wall-parallel displacement field as a grid field (the ``deform=`` of
    :class:`EnsembleAccumulator`): the profile ``u(d), v(d)`` (px per pair along the pixel axes,
    ``d`` the wall distance in px) at every row of the image and every ``dx`` px along x,
    following the wall line. Between the wall and the first profile point the no-slip
    condition (0 at ``d = 0``) and linear interpolation; beyond the last point its value; 0
    behind the wall (the reflection).

    Returns ``((x0, y0, dx, dy), U, V)`` with ``U, V`` of shape (rows, nx).
    """
    rows, cols = (int(s) for s in shape)
    d = np.asarray(dist, dtype=np.float64)
    pu = np.asarray(u, dtype=np.float64)
    pv = np.asarray(v, dtype=np.float64)
    ok = np.isfinite(d) & np.isfinite(pu) & np.isfinite(pv) & (d > 0)
    if ok.sum() < 1:
        raise InvalidInputError("profile_field: no finite profile point off the wall")
    order = np.argsort(d[ok])
    d, pu, pv = d[ok][order], pu[ok][order], pv[ok][order]
    d, pu, pv = np.r_[0.0, d], np.r_[0.0, pu], np.r_[0.0, pv]
    nx = max(int(np.ceil((cols - 1) / dx)) + 1, 2)
    gx = np.arange(nx) * float(dx)
    gy = np.arange(rows, dtype=np.float64)
    sign = 1.0 if flow_side == "above" else -1.0
    dd = sign * (_wall_y(wall, gx)[None, :] - gy[:, None])
    fu = np.where(dd > 0, np.interp(dd, d, pu), 0.0)
    fv = np.where(dd > 0, np.interp(dd, d, pv), 0.0)
    return (0.0, 0.0, float(dx), 1.0), fu, fv


def _grid_field(deform: Any) -> tuple[tuple[float, ...], np.ndarray, np.ndarray] | None:
    """``deform`` (None, a grid PivField, or ``((x0, y0, dx, dy), u, v)``) as the grid and
    float64 arrays; InvalidInputError for anything else."""
    if deform is None:
        return None
    grid = getattr(deform, "grid", None)
    if grid is not None and hasattr(deform, "u"):
        parts = (grid, deform.u, deform.v)
    elif isinstance(deform, tuple) and len(deform) == 3:
        parts = deform
    else:
        raise InvalidInputError(
            "deform: expected a grid PivField or ((x0, y0, dx, dy), u, v), "
            f"got {type(deform).__name__}"
        )
    g = tuple(float(t) for t in parts[0])
    u = np.ascontiguousarray(parts[1], dtype=np.float64)
    v = np.ascontiguousarray(parts[2], dtype=np.float64)
    if len(g) != 4 or u.ndim != 2 or u.shape != v.shape or not np.all(np.isfinite(u + v)):
        raise InvalidInputError(
            "deform: the grid must be (x0, y0, dx, dy) and u, v finite 2D arrays of one shape"
        )
    return g, u, v


@dataclass(frozen=True)
class EnsembleField:
    """The ensemble result; every array has the accumulator's points' shape.

    Attributes
    ----------
    x, y : ndarray
        Window centres, px.
    u, v : ndarray
        Mean displacement, px (NaN where the fit failed).
    uu, vv, uv : ndarray
        Displacement covariance within the window, px^2 (module docstring).
    cross, auto : ndarray, shape (..., 3)
        The fitted covariances ``(xx, yy, xy)`` of the cross and auto peaks, px^2.
    count : ndarray
        Pairs summed per window.
    coef : ndarray
        Height of the mean normalised cross plane.
    ok : ndarray of bool
        The fit succeeded and the summed peak is clear (``peak_ratio`` at least 3,
        ``piv_core::ensemble::MIN_PEAK_RATIO``).
    peak_ratio : ndarray
        The summed cross plane's highest local maximum over its next highest, both less the
        plane's median (``piv_core::ensemble::peak_ratio``; NaN where nothing was summed): 23
        or more for 64 x 4 px windows of 60 synthetic pairs (3.1 or more for 32 x 8 px of 2
        pairs), at most 2.3 for frames of noise.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    uu: np.ndarray
    vv: np.ndarray
    uv: np.ndarray
    cross: np.ndarray
    auto: np.ndarray
    count: np.ndarray
    coef: np.ndarray
    ok: np.ndarray
    peak_ratio: np.ndarray


class EnsembleAccumulator:
    """Correlation planes of many pairs summed per window (module docstring).

    Parameters
    ----------
    x, y : array_like
        Window centres, px (one shape; a 2D grid ``(ny, nx)`` enables the gradient correction).
    window : (int, int)
        ``(w, h)`` px, w along x, at least 2 x 2.
    offset : (array_like, array_like), optional
        ``(du, dv)`` per window (the shape of ``x``), px: the windows of frame A and B are
        shifted by ``-d/2`` and ``+d/2``. Default 0.
    deform : PivField or ((x0, y0, dx, dy), u, v), optional
        A regular-grid displacement field (e.g. the instantaneous mean field) by which every
        window is also deformed, pixel by pixel, so that the mean field's variation inside a
        window does not widen the summed peak (the stresses in a mean gradient); the reported
        ``u, v`` add its mean over each window.
    interpolation : {"bspline", "bspline3", "keys"}
        Interpolation of the frames at fractional offsets.
    """

    def __init__(
        self,
        x: Any,
        y: Any,
        window: tuple[int, int],
        offset: tuple[Any, Any] | None = None,
        interpolation: str = "bspline",
        deform: Any = None,
    ) -> None:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if x.shape != y.shape or x.size == 0:
            raise InvalidInputError(f"x {x.shape} and y {y.shape} must be non-empty, one shape")
        self.shape = x.shape
        self.x, self.y = x, y
        self.window = (int(window[0]), int(window[1]))
        if offset is None:
            du = dv = np.zeros(x.shape)
        else:
            du, dv = (np.broadcast_to(np.asarray(o, dtype=np.float64), x.shape) for o in offset)
        self.du, self.dv = np.array(du), np.array(dv)
        self.interpolation = parse_choice(interpolation, INTERPOLATIONS, "interpolation")
        self.deform = _grid_field(deform)
        stride = _rspiv.ensemble_stride(*self.window)
        self.acc = np.zeros((x.size, stride), dtype=np.float64)
        self.pairs = 0
        #: per window, the fraction of its pixels saturated in the raw frames (a campaign adds
        #: it per pair)
        self.saturation = SaturationTally(self.x.size)

    def _field_kwargs(self) -> dict[str, Any]:
        if self.deform is None:
            return {}
        g, u, v = self.deform
        return {"field_grid": g, "field_u": u, "field_v": v}

    def add(self, frame_a: Any, frame_b: Any, mask: Any = None, auto: bool = True) -> int:
        """Add one pair (2D arrays of one dtype: uint8, uint16, float32, float64); the auto
        planes too when ``auto`` (they only need a few hundred pairs). Returns the windows
        added (windows masked, reaching outside the image or blank are left out)."""
        m = None if mask is None else np.ascontiguousarray(mask, dtype=bool)
        n = _rspiv.ensemble_add(
            np.ascontiguousarray(frame_a),
            np.ascontiguousarray(frame_b),
            self.x.ravel(),
            self.y.ravel(),
            self.du.ravel(),
            self.dv.ravel(),
            self.window,
            self.acc,
            auto=auto,
            mask=m,
            interpolation=self.interpolation,
            **self._field_kwargs(),
        )
        self.pairs += 1
        return int(n)

    def add_all(self, pairs: Iterable[tuple[Any, Any]], auto_pairs: int = 200) -> None:
        """Add every pair of an iterable (streamed: one pair in memory at a time); the auto
        planes from the first ``auto_pairs``."""
        for a, b in pairs:
            self.add(a, b, auto=self.pairs < auto_pairs)

    @property
    def window_counts(self) -> np.ndarray:
        """Cross planes summed per window (the accumulator's ``n_cross`` column), the shape of
        the points."""
        return self.acc[:, -2].reshape(self.shape)

    def to_arrays(self) -> dict[str, Any]:
        """The whole state as named arrays and scalars (:meth:`from_arrays` restores it
        exactly; e.g. into a shard's NetCDF file)."""
        out: dict[str, Any] = {
            "sum": self.acc,
            "x": self.x,
            "y": self.y,
            "du": self.du,
            "dv": self.dv,
            "window": np.asarray(self.window, dtype=np.int64),
            "pairs": int(self.pairs),
            **self.saturation.to_arrays(),
            "interpolation": self.interpolation,
        }
        if self.deform is not None:
            g, u, v = self.deform
            out.update(field_grid=np.asarray(g, dtype=np.float64), field_u=u, field_v=v)
        return out

    @classmethod
    def from_arrays(cls, d: dict[str, Any]) -> EnsembleAccumulator:
        """An accumulator restored from :meth:`to_arrays` (InvalidInputError if the sums do
        not fit the windows)."""
        deform = None
        if d.get("field_grid") is not None:
            deform = (tuple(np.asarray(d["field_grid"]).tolist()), d["field_u"], d["field_v"])
        w, h = (int(t) for t in np.asarray(d["window"]).ravel())
        out = cls(
            d["x"],
            d["y"],
            (w, h),
            offset=(d["du"], d["dv"]),
            interpolation=str(d["interpolation"]),
            deform=deform,
        )
        s = np.asarray(d["sum"], dtype=np.float64)
        if s.shape != out.acc.shape:
            raise InvalidInputError(
                f"ensemble sums of shape {s.shape} do not fit {out.acc.shape[0]} windows of "
                f"{w} x {h} px"
            )
        out.acc = np.array(s)
        out.pairs = int(d["pairs"])
        out.saturation = SaturationTally.from_arrays(d, out.x.size)
        return out

    def merge(self, other: EnsembleAccumulator) -> EnsembleAccumulator:
        """Add another accumulator of the same windows (shards, workers) into this one."""
        same = (
            self.window == other.window
            and self.shape == other.shape
            and np.array_equal(self.x, other.x)
            and np.array_equal(self.y, other.y)
            and np.array_equal(self.du, other.du)
            and np.array_equal(self.dv, other.dv)
            and self._field_kwargs().keys() == other._field_kwargs().keys()
            and all(
                np.array_equal(a, b)
                for a, b in zip(
                    self._field_kwargs().values(), other._field_kwargs().values(), strict=True
                )
            )
        )
        if not same:
            raise InvalidInputError("ensemble accumulators of different windows cannot merge")
        self.acc += other.acc
        self.pairs += other.pairs
        self.saturation.merge(other.saturation)
        return self

    def result(self, axes: tuple[Any, Any] | None = None, rows: bool = False) -> EnsembleField:
        """Fit every window's summed peak (module docstring).

        Parameters
        ----------
        axes : (array_like, array_like), optional
            The 1D coordinates (px) of the grid's columns and rows for the gradient
            correction; default ``x[0, :]`` and ``y[:, 0]`` (e.g. object px when the windows sit
            at mapped positions, Method II).
        rows : bool
            Sum the planes of each grid row before fitting (a flow homogeneous along the rows,
            e.g. a boundary layer along x): one peak per row from all its windows' pairs, so
            the fit sees the row's whole displacement PDF rather than each window's few
            samples of it (with tens of pairs a window's summed peak is lumpy and its Gaussian
            fit reads the variance low). The result has shape ``(ny, 1)``: the rows' mean
            centres, the count-weighted mean of the windows' offsets plus the row peak's
            centre, the stresses from the row peak (less the spread of the mean across the
            window's height only).
        """
        x, y, du, dv = self.x, self.y, self.du, self.dv
        mu, mv = np.zeros(self.shape), np.zeros(self.shape)
        if self.deform is not None:
            fu, fv = _rspiv.grid_field_window_mean(
                *self.deform, self.x.ravel(), self.y.ravel(), self.window
            )
            mu, mv = np.reshape(fu, self.shape), np.reshape(fv, self.shape)
        acc = self.acc
        shape = self.shape
        if rows:
            if len(self.shape) != 2:
                raise InvalidInputError("result(rows=True) needs a 2D grid of windows")
            ny, nx = self.shape
            acc = acc.reshape(ny, nx, -1).sum(axis=1)
            w = self.window_counts
            n = np.maximum(w.sum(axis=1, keepdims=True), 1e-300)

            def avg(a):
                return (np.where(w > 0, a, 0.0) * w).sum(axis=1, keepdims=True) / n

            x, y, du, dv, mu, mv = (avg(a) for a in (x, y, du, dv, mu, mv))
            shape = (ny, 1)
            if axes is not None:
                axes = (np.zeros(1), np.asarray(axes[1], np.float64))
        d = _rspiv.ensemble_peaks(np.ascontiguousarray(acc), self.window)

        def shaped(k: str) -> np.ndarray:
            return np.asarray(d[k]).reshape(shape)

        ok = shaped("ok")
        u = np.where(ok, du + mu + shaped("dx"), np.nan)
        v = np.where(ok, dv + mv + shaped("dy"), np.nan)
        cross = np.stack([shaped("cxx"), shaped("cyy"), shaped("cxy")], axis=-1)
        auto = np.stack([shaped("axx"), shaped("ayy"), shaped("axy")], axis=-1)
        cov = cross - auto
        if len(shape) == 2 and shape[0] >= 2:
            # the spread of the mean displacement over the window: J diag(w^2, h^2) J^T / 12
            # (of the mean less the deformation's part: what the windows still hold)
            gx, gy = (x[0, :], y[:, 0]) if axes is None else axes
            gx, gy = np.asarray(gx, np.float64), np.asarray(gy, np.float64)
            if shape[1] >= 2:
                dudy, dudx = np.gradient(u - mu, gy, gx)
                dvdy, dvdx = np.gradient(v - mv, gy, gx)
            else:
                dudy, dvdy = (np.gradient(a[:, 0], gy)[:, None] for a in (u - mu, v - mv))
                dudx = dvdx = np.zeros(shape)
            w2, h2 = self.window[0] ** 2 / 12.0, self.window[1] ** 2 / 12.0
            cov = cov - np.stack(
                [
                    dudx**2 * w2 + dudy**2 * h2,
                    dvdx**2 * w2 + dvdy**2 * h2,
                    dudx * dvdx * w2 + dudy * dvdy * h2,
                ],
                axis=-1,
            )
        return EnsembleField(
            x=x,
            y=y,
            u=u,
            v=v,
            uu=cov[..., 0],
            vv=cov[..., 1],
            uv=cov[..., 2],
            cross=cross,
            auto=auto,
            count=shaped("count"),
            coef=shaped("coef"),
            ok=ok,
            peak_ratio=shaped("peak_ratio"),
        )
