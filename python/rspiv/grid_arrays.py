"""Per-vector arrays on a field's grid (rows, columns), checked where a module takes them.

The accumulators of the second passes (:mod:`rspiv.quadrant`, :mod:`rspiv.conditional`,
:mod:`rspiv.temporal`) take each vector's mean, spread and every field as 2-D arrays of one
shape; a wrong one is refused in one line naming the module and the array.
"""

from __future__ import annotations

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["as_grid"]


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
