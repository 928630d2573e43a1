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

Accuracy: on pairs moved by Gaussian random displacements (Rust tests) the mean within
0.012 px and the covariances within 13 % at 16 x 4 px windows (9 % at 32 x 16); a near-wall
profile curved over 6 px is resolved by 64 x 4 windows to within 0.024 px of its 4 px mean
(``tests/test_ensemble.py``). Not yet good enough: the covariances near the wall. With 120
pairs of that profile the rows read -0.04 .. +0.01 px^2 without fluctuations (offset or
deformed windows alike) and, with 0.3 px random displacements (variances 0.096 / 0.081 px^2),
uu 0.043 .. 0.109 (27 % low on average) and vv 0.049 .. 0.11 px^2. Still to come (issue 13):
the campaign's ``[ensemble]`` section and outputs, single-pixel ensemble, the band that follows
the wall, Methods I/II, and the 10 % the near-wall stresses need.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.settings import INTERPOLATIONS, parse_choice

__all__ = ["EnsembleAccumulator", "EnsembleField", "ensemble_grid"]


def ensemble_grid(
    shape: tuple[int, int], window: tuple[int, int], step: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Window centres ``(x, y)`` (each ``(ny, nx)``) of ``window`` = ``(w, h)`` px windows every
    ``step = (sx, sy)`` px, every window inside an image of ``shape = (rows, columns)``."""
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
    xs = np.arange((w - 1) / 2, cols - (w - 1) / 2 - 0.5 + 1e-9, sx)
    ys = np.arange((h - 1) / 2, rows - (h - 1) / 2 - 0.5 + 1e-9, sy)
    return np.meshgrid(xs, ys)


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
        The fit succeeded.
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
        return self

    def result(self) -> EnsembleField:
        """Fit every window's summed peak (module docstring)."""
        d = _rspiv.ensemble_peaks(self.acc, self.window)

        def shaped(k: str) -> np.ndarray:
            return np.asarray(d[k]).reshape(self.shape)

        ok = shaped("ok")
        mu, mv = np.zeros(self.shape), np.zeros(self.shape)
        if self.deform is not None:
            fu, fv = _rspiv.grid_field_window_mean(
                *self.deform, self.x.ravel(), self.y.ravel(), self.window
            )
            mu, mv = np.reshape(fu, self.shape), np.reshape(fv, self.shape)
        u = np.where(ok, self.du + mu + shaped("dx"), np.nan)
        v = np.where(ok, self.dv + mv + shaped("dy"), np.nan)
        cross = np.stack([shaped("cxx"), shaped("cyy"), shaped("cxy")], axis=-1)
        auto = np.stack([shaped("axx"), shaped("ayy"), shaped("axy")], axis=-1)
        cov = cross - auto
        if len(self.shape) == 2 and min(self.shape) >= 2:
            # the spread of the mean displacement over the window: J diag(w^2, h^2) J^T / 12
            # (of the mean less the deformation's part: what the windows still hold)
            gx, gy = self.x[0, :], self.y[:, 0]
            dudy, dudx = np.gradient(u - mu, gy, gx)
            dvdy, dvdx = np.gradient(v - mv, gy, gx)
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
            x=self.x,
            y=self.y,
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
        )
