"""Vector files' nodes on their regular grid: the shared checks of :mod:`rspiv.vector_files`'
readers (and :mod:`rspiv.insight`'s).

Text files give each vector's position; :func:`grid_from_columns` places them on the ``(ny,
nx)`` grid they describe (y increasing), refusing, in one line naming the file, positions that
are not one vector per node of an evenly spaced grid. Positions a file printed to few digits
(OpenPIV's ``%.4e`` of mm) are put back on the grid they round (:func:`on_grid`), and said.
"""

from __future__ import annotations

import pathlib

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["file_error", "grid_from_columns", "on_grid", "check_regular"]


def file_error(p: pathlib.Path, what: str) -> InvalidInputError:
    """The one-line error about file ``p``: ``"<p>: <what>"``."""
    return InvalidInputError(f"{p}: {what}")


def grid_from_columns(
    p: pathlib.Path, xs: np.ndarray, ys: np.ndarray, cols: list[np.ndarray], notes: list[str]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Scattered rows (x, y, values...) of a regular grid -> (ny, nx) arrays, y increasing; the
    nodes placed on the grid their printed positions round (:func:`on_grid`, said in
    ``notes``)."""
    if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))):
        raise file_error(p, "a position that is not a number")
    ux = np.unique(xs)
    uy = np.unique(ys)
    if ux.size * uy.size != xs.size:
        raise file_error(
            p,
            f"{xs.size} vectors at {ux.size} x positions and {uy.size} y positions: "
            "not one vector per node of a regular grid",
        )
    ix = np.searchsorted(ux, xs)
    iy = np.searchsorted(uy, ys)
    taken = np.zeros((uy.size, ux.size), dtype=bool)
    taken[iy, ix] = True
    if not taken.all():
        raise file_error(p, "two vectors at one position: not a regular grid")
    out = []
    for c in cols:
        a = np.full((uy.size, ux.size), np.nan)
        a[iy, ix] = c
        out.append(a)
    gx, gy = np.meshgrid(on_grid(p, ux, "x", notes), on_grid(p, uy, "y", notes))
    check_regular(p, gx, gy)
    return gx, gy, out


def on_grid(p: pathlib.Path, values: np.ndarray, name: str, notes: list[str]) -> np.ndarray:
    """A text file's sorted node positions placed on the regular grid they round: OpenPIV's
    ``tools.save`` writes 5 significant digits (``%.4e``), which at a scale of mm leaves the
    nodes up to 0.04 px off their grid; the rows would then not be equally spaced for the wall
    finder (8.7321e+01 mm is 3015.50 +- 0.09 px at 1/34.5 mm per px; Insight's 6 decimals of a
    mm leave 1e-5 px, enough for the wall finder's 1e-6 of the step). Off by more than 5 % of
    the step: not a regular grid, refused."""
    n = values.size
    if n < 3:
        return values
    k = np.arange(n)
    step, first = np.polyfit(k, values, 1)
    off = float(np.max(np.abs(values - (first + step * k))))
    if off <= 1e-7 * abs(step):
        return values
    if step <= 0 or off > 0.05 * step:
        raise file_error(p, f"the {name} positions are not evenly spaced and increasing")
    if off > 1e-3:  # Insight's 6 decimals of a mm (1e-5 px) are not worth a word
        notes.append(
            f"{name} positions up to {off:.2g} px off a regular grid (the file's rounding)"
        )
    return first + step * k


def check_regular(p: pathlib.Path, x: np.ndarray, y: np.ndarray) -> None:
    for arr, axis, name in ((x, 1, "x"), (y, 0, "y")):
        if arr.shape[axis] < 2:
            continue
        d = np.diff(arr, axis=axis)
        step = float(np.median(d))
        if step <= 0 or np.max(np.abs(d - step)) > 1e-3 * step + 1e-6:
            raise file_error(p, f"the {name} positions are not evenly spaced and increasing")
