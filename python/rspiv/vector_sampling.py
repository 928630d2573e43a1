"""A vector field sampled at other points: the node itself where one lies there, else bilinear
between four valid nodes (:func:`sample_at`), as the comparison of two tools' fields
(:mod:`rspiv.compare`) and Method II for another tool's vectors
(:func:`rspiv.correction.correct_vectors`) need it.

Positions are px of the field's frame (:mod:`rspiv.vector_files`: x right, y down, the origin at
the top-left pixel's centre); the field's grid is regular (its reader checked it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["axis_of", "sample_at"]

#: Positions closer than this (px) are the same vector's (:func:`sample_at`).
_SAME_POSITION = 0.01


def axis_of(coords: np.ndarray) -> tuple[float, float, int]:
    """(origin, step, n) of a regular axis."""
    n = coords.size
    step = float(coords[1] - coords[0]) if n > 1 else 1.0
    return float(coords[0]), step, n


def sample_at(
    f: Any, xs: np.ndarray, ys: np.ndarray, arrays: list[np.ndarray | None]
) -> list[np.ndarray]:
    """``arrays`` of the field ``f`` (u, v, ...) at positions (xs, ys): the node itself where one
    lies within 0.01 px, else bilinear from four valid nodes; NaN where neither (or None given).

    ``f`` is a :class:`rspiv.vector_files.VectorFile` (or any field with ``x``, ``y``, ``u``,
    ``v`` and ``valid`` on a regular grid); ``arrays`` are of its grid's shape."""
    x0, dx, nx = axis_of(f.x[0])
    y0, dy, ny = axis_of(f.y[:, 0])
    fx = (xs - x0) / dx
    fy = (ys - y0) / dy
    out = []
    good = f.valid & np.isfinite(f.u) & np.isfinite(f.v)
    ix = np.rint(fx).astype(np.int64)
    iy = np.rint(fy).astype(np.int64)
    on_node = (
        (np.abs(fx - ix) * abs(dx) < _SAME_POSITION)
        & (np.abs(fy - iy) * abs(dy) < _SAME_POSITION)
        & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    )  # fmt: skip
    i0 = np.clip(np.floor(fx).astype(np.int64), 0, max(nx - 2, 0))
    j0 = np.clip(np.floor(fy).astype(np.int64), 0, max(ny - 2, 0))
    tx = fx - i0
    ty = fy - j0
    inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1) & (nx > 1) & (ny > 1)
    i1 = np.minimum(i0 + 1, nx - 1)
    j1 = np.minimum(j0 + 1, ny - 1)
    four = inside & good[j0, i0] & good[j0, i1] & good[j1, i0] & good[j1, i1]
    ixc = np.clip(ix, 0, nx - 1)
    iyc = np.clip(iy, 0, ny - 1)
    node_ok = on_node & good[iyc, ixc]
    for a in arrays:
        if a is None:
            out.append(np.full(xs.shape, np.nan))
            continue
        bil = (
            (1 - tx) * (1 - ty) * a[j0, i0] + tx * (1 - ty) * a[j0, i1]
            + (1 - tx) * ty * a[j1, i0] + tx * ty * a[j1, i1]
        )  # fmt: skip
        val = np.where(node_ok, a[iyc, ixc], np.where(four & ~on_node, bil, np.nan))
        out.append(val)
    return out
