"""Per-vector statistics of the vorticity and the swirling strength over many fields, streamed
(a campaign's ``[statistics] vorticity``).

Each field's vorticity ``omega_z`` and signed swirling strength ``lambda_ci`` are computed on
its grid (:mod:`rspiv.derivatives`: the image's right-handed frame, x right, y up; 1/pair) from
its *valid* vectors only: a rejected vector is NaN, so the stencils about it fall back to the
central difference or give NaN (a replaced vector's interpolated value is not differentiated).
Per vector the accumulator keeps the count, mean and sum of squared deviations of both
(Welford's update; parts merge exactly by Chan's formula).

Orientation: reflecting one axis flips the sign of both quantities, so in the flow's frame (u'
downstream, y away from the wall) ``omega_flow = s omega`` with ``s = sign_x * flip_y``
(:meth:`VorticityAccumulator.profile`); the standard deviations do not change. A boundary layer
has ``Omega_z = -dU/dy < 0`` in that frame.
"""

from __future__ import annotations

import numpy as np

from rspiv.derivatives import gradients, swirl_from_gradients
from rspiv.errors import InvalidInputError

__all__ = ["VorticityAccumulator"]

_NAMES = ("omega", "swirl")
_ARRAYS = ("count", "mean", "m2")


class VorticityAccumulator:
    """Streamed per-vector statistics of ``omega_z`` and signed ``lambda_ci`` (module
    docstring).

    Parameters
    ----------
    shape : (ny, nx)
        The vector grid.
    dx, dy : float
        Grid spacing along x and y, px.
    scheme : str
        Difference scheme (:data:`rspiv.derivatives.SCHEMES`).
    """

    def __init__(self, shape, dx: float, dy: float, scheme: str = "least_squares"):
        self.shape = tuple(int(s) for s in shape)
        if len(self.shape) != 2 or min(self.shape) < 3:
            raise InvalidInputError(f"vorticity: a grid of at least 3 x 3, got {self.shape}")
        self.dx, self.dy, self.scheme = float(dx), float(dy), str(scheme)
        gradients(np.zeros((3, 3)), np.zeros((3, 3)), self.dx, self.dy, self.scheme)  # checks
        for n in _NAMES:
            setattr(self, f"{n}_count", np.zeros(self.shape, np.int64))
            setattr(self, f"{n}_mean", np.zeros(self.shape))
            setattr(self, f"{n}_m2", np.zeros(self.shape))
        self.n_fields = 0
        self.pair_ids: set[int] = set()

    @staticmethod
    def fields(u, v, valid, dx: float, dy: float, scheme: str) -> tuple[np.ndarray, np.ndarray]:
        """``omega_z`` and signed ``lambda_ci`` (1/pair) of one field's valid vectors."""
        ok = np.asarray(valid, bool) & np.isfinite(u) & np.isfinite(v)
        g = gradients(np.where(ok, u, np.nan), np.where(ok, v, np.nan), dx, dy, scheme)
        return g["dvdx"] - g["dudy"], swirl_from_gradients(g, signed=True)

    def add(self, u, v, valid=None, *, pair_id: int | None = None) -> None:
        """Add one field (pixel frame, px): ``u``, ``v`` of the grid's shape.

        Raises
        ------
        InvalidInputError
            Another shape, or a pair added before.
        """
        u = np.asarray(u, np.float64)
        v = np.asarray(v, np.float64)
        if u.shape != self.shape or v.shape != self.shape:
            raise InvalidInputError(f"vorticity: expected shape {self.shape}, got {u.shape}")
        if pair_id is not None and int(pair_id) in self.pair_ids:
            raise InvalidInputError(f"vorticity: pair {pair_id} was added before")
        valid = np.ones(self.shape, bool) if valid is None else valid
        for name, x in zip(_NAMES, self.fields(u, v, valid, self.dx, self.dy, self.scheme),
                           strict=True):  # fmt: skip
            ok = np.isfinite(x)
            n = getattr(self, f"{name}_count")
            mean = getattr(self, f"{name}_mean")
            n += ok
            with np.errstate(invalid="ignore", divide="ignore"):
                delta = np.where(ok, x - mean, 0.0)
                mean += np.where(ok, delta / np.maximum(n, 1), 0.0)
            getattr(self, f"{name}_m2")[...] += np.where(ok, delta * (x - mean), 0.0)
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: VorticityAccumulator) -> VorticityAccumulator:
        """Add ``other`` (the same grid, spacing and scheme) exactly; returns self."""
        if (self.shape, self.dx, self.dy, self.scheme) != (
            other.shape, other.dx, other.dy, other.scheme):  # fmt: skip
            raise InvalidInputError("vorticity: cannot merge parts of other grids or schemes")
        if self.pair_ids & other.pair_ids:
            raise InvalidInputError("vorticity: parts share pairs")
        for name in _NAMES:
            na, nb = getattr(self, f"{name}_count"), getattr(other, f"{name}_count")
            ma, mb = getattr(self, f"{name}_mean"), getattr(other, f"{name}_mean")
            n = na + nb
            with np.errstate(invalid="ignore", divide="ignore"):
                d = mb - ma
                f = np.where(n > 0, nb / np.maximum(n, 1), 0.0)
                setattr(self, f"{name}_mean", ma + d * f)
                m2 = getattr(self, f"{name}_m2") + getattr(other, f"{name}_m2")
                setattr(self, f"{name}_m2", m2 + np.where(n > 0, d * d * na * f, 0.0))
            setattr(self, f"{name}_count", n)
        self.n_fields += other.n_fields
        self.pair_ids |= other.pair_ids
        return self

    def mean(self, name: str = "omega") -> np.ndarray:
        """Per-vector mean (1/pair, image frame), NaN without samples."""
        return np.where(getattr(self, f"{name}_count") > 0, getattr(self, f"{name}_mean"), np.nan)

    def var(self, name: str = "omega") -> np.ndarray:
        """Per-vector sample variance (ddof 1; 1/pair^2), NaN below 2 samples."""
        n = getattr(self, f"{name}_count")
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 1, getattr(self, f"{name}_m2") / (n - 1), np.nan)

    def profile(self, usable, orient: float) -> dict[str, np.ndarray]:
        """Per row, over the ``usable`` vectors with two samples or more: the mean of the
        per-vector means (times ``orient``: the flow frame) and the square root of the mean of
        the per-vector variances, for ``omega`` and ``swirl``; ``count`` the vectors averaged."""
        out = {}
        for name in _NAMES:
            ok = np.asarray(usable, bool) & (getattr(self, f"{name}_count") > 1)
            k = ok.sum(axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                out[f"{name}_mean"] = orient * np.where(ok, self.mean(name), 0).sum(1) / k
                out[f"{name}_rms"] = np.sqrt(np.where(ok, self.var(name), 0).sum(1) / k)
            out[f"{name}_vectors"] = k
        return out

    # ------------------------------------------------------------------ I/O
    def to_dataset_vars(self) -> tuple[dict, dict]:
        """``(variables, attrs)`` to write beside a FieldAccumulator's (``vorticity_*``)."""
        dims = ("y", "x")
        variables = {
            f"vorticity_{n}_{a}": (dims, getattr(self, f"{n}_{a}"))
            for n in _NAMES
            for a in _ARRAYS
        }
        attrs = {"vorticity_grid": [self.dx, self.dy], "vorticity_scheme": self.scheme,
                 "vorticity_fields": int(self.n_fields)}  # fmt: skip
        return variables, attrs

    @classmethod
    def from_dataset_vars(cls, ds, pair_ids) -> VorticityAccumulator:
        """Read back :meth:`to_dataset_vars` (the pairs are the statistics')."""
        dx, dy = (float(t) for t in np.ravel(ds.attrs["vorticity_grid"]))
        acc = cls(ds["vorticity_omega_count"].shape, dx, dy, str(ds.attrs["vorticity_scheme"]))
        for n in _NAMES:
            for a in _ARRAYS:
                dtype = np.int64 if a == "count" else np.float64
                setattr(acc, f"{n}_{a}", np.array(ds[f"vorticity_{n}_{a}"].values, dtype=dtype))
        acc.n_fields = int(ds.attrs.get("vorticity_fields", 0))
        acc.pair_ids = set(pair_ids)
        return acc
