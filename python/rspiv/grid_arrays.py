"""Per-vector arrays on a field's grid (rows, columns), checked where a module takes them.

The accumulators of the second passes (:mod:`rspiv.quadrant`, :mod:`rspiv.conditional`,
:mod:`rspiv.temporal`) take each vector's mean, spread and every field as 2-D arrays of one
shape; a wrong one is refused in one line naming the module and the array.
"""

from __future__ import annotations

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["as_grid", "entering"]


def as_grid(who: str, name: str, a, shape: tuple[int, int] | None = None) -> np.ndarray:
    """``a`` as a float64 2-D array (of ``shape`` when given).

    Raises
    ------
    InvalidInputError
        ``"<who>: <name> must be ..."``: not 2-D, or not ``shape``.
    """
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or (shape is not None and arr.shape != shape):
        want = "a 2-D array" if shape is None else f"shape {shape}"
        raise InvalidInputError(f"{who}: {name} must be {want}, got shape {arr.shape}")
    return arr


def entering(mean_u, mean_v, rms_u, rms_v, usable=None) -> np.ndarray:
    """The vectors that may enter a pass about each vector's mean and spread: mean finite,
    spreads positive and finite, and ``usable`` (a bool array of the grid's shape) where
    given."""
    ok = (
        np.isfinite(mean_u)
        & np.isfinite(mean_v)
        & (rms_u > 0)
        & (rms_v > 0)
        & np.isfinite(rms_u * rms_v)
    )
    if usable is not None:
        ok &= np.asarray(usable, bool).reshape(np.shape(mean_u))
    return ok
