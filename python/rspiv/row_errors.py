"""Standard errors of a profile's rows from the scatter between pairs (:class:`RowErrors`).

A campaign's profile averages each row of vectors along the wall over every pair
(:func:`rspiv.profiles.average_along_x`). Its standard errors there take the vectors of one
field as fully correlated (``eps_U = sqrt(uu / n_eff)``, :mod:`rspiv.boundary_layer`): a
conservative bound, since the fluctuations decorrelate along the wall over a few structures
and a wide frame averages several independent ones. On the synthetic campaign at 47 MP the
bound was a median 7.6 times the actual error of a row's mean (``python
benches/profile_errors.py``).

:class:`RowErrors` sums, per pair and row, the valid vectors' count and their sums of ``u``,
``v``, ``u^2``, ``v^2`` and ``u v``, and over the pairs those six sums and their products (a
6 x 6 matrix per row). Each pair is one cluster: the standard errors of the row's pooled mean
``U = sum u / n``, of its variance about that mean ``uu = sum u^2 / n - U^2`` (``vv``, ``uv``
alike) follow from the clusters' scatter by the delta method (the cluster-robust variance of a
ratio estimator, ``P / (P - 1)`` for ``P`` clusters), exactly as
:class:`rspiv.ptv_profile.TrackProfile` does for the tracks' bins. The campaign's ``uu`` is the
mean along the row of each vector's own variance over the pairs; where the mean changes little
along the row the two variances and their errors agree to first order.

Assumptions: the pairs are independent (a double-frame campaign). For a time-resolved
recording the caller scales the variances by the serial correlation (``n / n_eff`` of the
per-vector statistics). Rows with fewer than :data:`MIN_PAIRS` pairs get NaN.

Units: those of the fields added (px per pair in a campaign); errors of the stresses in their
square.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["MIN_PAIRS", "RowErrors"]

#: Fewer pairs in a row than this: no error (a scatter of fewer pairs says little).
MIN_PAIRS = 3

# the six per-pair row sums: count, u, v, uu, vv, uv
_N, _U, _V, _UU, _VV, _UV = range(6)


class RowErrors:
    """Per-row cluster sums over a run's pairs (module docstring).

    Parameters
    ----------
    rows : int
        The fields' rows (axis 0; the profile runs along it, averaged along axis 1).

    Attributes
    ----------
    total : ndarray, shape (rows, 6)
        The six sums over every pair.
    outer : ndarray, shape (rows, 6, 6)
        The sums over the pairs of each pair's products of its six sums.
    pairs_in : ndarray of int64, shape (rows,)
        Pairs with a valid vector in the row.
    pair_ids : set of int
    n_fields : int
    """

    def __init__(self, rows: int) -> None:
        if int(rows) < 1:
            raise InvalidInputError(f"rows must be >= 1, got {rows}")
        self.rows = int(rows)
        self.total = np.zeros((self.rows, 6))
        self.outer = np.zeros((self.rows, 6, 6))
        self.pairs_in = np.zeros(self.rows, np.int64)
        self.pair_ids: set[int] = set()
        self.n_fields = 0

    def add(self, u: Any, v: Any, valid: Any = None, pair_id: int | None = None) -> None:
        """Add one pair's field (``u``, ``v`` of shape (rows, columns); ``valid`` the vectors
        to count, NaN never counted).

        Raises
        ------
        InvalidInputError
            Fields of another number of rows or of different shapes, or a pair added before.
        """
        if pair_id is not None and int(pair_id) in self.pair_ids:
            raise InvalidInputError(f"row errors: pair {pair_id} was added before")
        u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
        if u.ndim != 2 or u.shape != v.shape or u.shape[0] != self.rows:
            raise InvalidInputError(
                f"row errors: fields of {self.rows} rows expected, got u {u.shape}, v {v.shape}"
            )
        ok = np.isfinite(u) & np.isfinite(v)
        if valid is not None:
            ok &= np.asarray(valid, dtype=bool)
        uz, vz = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
        m = np.stack(
            [ok.sum(axis=1), uz.sum(1), vz.sum(1), (uz * uz).sum(1), (vz * vz).sum(1),
             (uz * vz).sum(1)], axis=-1,
        ).astype(np.float64)  # fmt: skip
        self.total += m
        self.outer += m[:, :, None] * m[:, None, :]
        self.pairs_in += m[:, _N] > 0
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: RowErrors) -> RowErrors:
        """Add ``other``'s sums (the same rows, no pair in both); returns self."""
        if other.rows != self.rows:
            raise InvalidInputError(f"row errors: {other.rows} rows, not {self.rows}")
        common = self.pair_ids & other.pair_ids
        if common:
            raise InvalidInputError(f"row errors: pair {min(common)} in both parts")
        self.total += other.total
        self.outer += other.outer
        self.pairs_in += other.pairs_in
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    def result(self) -> dict[str, np.ndarray]:
        """Per row: the pooled ``U``, ``V``, ``uu``, ``vv``, ``uv`` and their standard errors
        ``se_U`` ... ``se_uv`` from the pairs' scatter (module docstring), ``pairs`` (NaN
        errors below :data:`MIN_PAIRS`)."""
        t, q = self.total, self.outer
        n = t[:, _N]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = t / n[:, None]
            U, V = mean[:, _U], mean[:, _V]
            out = {
                "U": U,
                "V": V,
                "uu": mean[:, _UU] - U * U,
                "vv": mean[:, _VV] - V * V,
                "uv": mean[:, _UV] - U * V,
                "pairs": self.pairs_in.copy(),
            }
            # each statistic's derivative by the six sums, over n (the delta method)
            zero = np.zeros_like(U)
            grads = {
                "U": (-U, np.ones_like(U), zero, zero, zero, zero),
                "V": (-V, zero, np.ones_like(U), zero, zero, zero),
                "uu": (2 * U * U - mean[:, _UU], -2 * U, zero, np.ones_like(U), zero, zero),
                "vv": (2 * V * V - mean[:, _VV], zero, -2 * V, zero, np.ones_like(U), zero),
                "uv": (2 * U * V - mean[:, _UV], -V, -U, zero, zero, np.ones_like(U)),
            }
            p = self.pairs_in.astype(np.float64)
            scale = np.where(p >= MIN_PAIRS, p / np.maximum(p - 1, 1), np.nan)
            for key, g in grads.items():
                w = np.stack(g, axis=-1) / n[:, None]
                var = np.einsum("ri,rij,rj->r", w, q, w) * scale
                out[f"se_{key}"] = np.sqrt(np.maximum(var, 0.0))
        return out

    def to_dataset_vars(self) -> tuple[dict, dict]:
        """``(variables, attrs)`` to write beside a FieldAccumulator's (``row_errors_*``)."""
        return (
            {
                "row_errors_total": (("y", "row_errors_sum"), self.total),
                "row_errors_outer": (("y", "row_errors_sum", "row_errors_sum2"), self.outer),
                "row_errors_pairs": (("y",), self.pairs_in),
            },
            {"row_errors_fields": int(self.n_fields)},
        )

    @classmethod
    def from_dataset_vars(cls, ds: Any, pair_ids: Any) -> RowErrors:
        """Read back :meth:`to_dataset_vars` (the pairs are the statistics')."""
        total = np.asarray(ds["row_errors_total"].values, np.float64)
        acc = cls(total.shape[0])
        acc.total = total.copy()
        acc.outer = np.asarray(ds["row_errors_outer"].values, np.float64).copy()
        acc.pairs_in = np.asarray(ds["row_errors_pairs"].values, np.int64).copy()
        acc.n_fields = int(ds.attrs.get("row_errors_fields", 0))
        acc.pair_ids = {int(i) for i in pair_ids}
        return acc
