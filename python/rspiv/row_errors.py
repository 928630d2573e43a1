"""Standard errors of a profile's rows from the scatter between pairs (:class:`RowErrors`).

A campaign's profile averages each row of vectors along the wall over every pair
(:func:`rspiv.profiles.average_along_x`). Its standard errors there take the vectors of one
field as fully correlated (``eps_U = sqrt(uu / n_eff)``, :mod:`rspiv.boundary_layer`): a
conservative bound, since the fluctuations decorrelate along the wall over a few structures
and a wide frame averages several independent ones. On the synthetic campaign at 47 MP the
bound was a median 7.6 times the actual error of a row's mean (``python
benches/profile_errors.py``).

:class:`RowErrors` sums, per pair and row, the valid vectors' count and their sums of ``u``,
``v``, ``u^2``, ``v^2``, ``u v``, ``u^3``, ``v^3``, ``u^4`` and ``v^4``, and over the pairs
those ten sums and their products (a 10 x 10 matrix per row). Each pair is one cluster: the
standard errors of the row's pooled mean ``U = sum u / n``, of its variance about that mean
``uu = sum u^2 / n - U^2`` (``vv``, ``uv`` alike) and of its skewness and flatness
(``S_u = m3 / m2^1.5``, ``F_u = m4 / m2^2`` of the central moments about the pooled mean; ``v``
alike) follow from the clusters' scatter by the delta method (the cluster-robust variance of a
ratio estimator, ``P / (P - 1)`` for ``P`` clusters), exactly as
:class:`rspiv.ptv_profile.TrackProfile` does for the tracks' bins. The campaign's ``uu`` is the
mean along the row of each vector's own variance over the pairs (its S and F alike); where the
mean changes little along the row the two and their errors agree to first order. Sums written
before the third and fourth powers were (six per pair and row) give no S or F.

A fit over many rows (the friction velocity of the composite profile) needs the rows' errors
together, correlated as they are (rows share their pairs; the flow's structures move many rows
at once). For it each pair's row counts and sums of u also go to one of :data:`BATCHES`
batches (the pair's id modulo), and :meth:`RowErrors.replicates` gives the rows' means with
each batch left out: the fit done again on each gives its error by the jackknife
(:func:`rspiv.boundary_layer.u_tau_jackknife`).

How the statistics converge with the pairs, and whether the run's first pairs and its last
agree (:mod:`rspiv.convergence`), need the rows' sums over the first ``n`` pairs for a few
``n``. Each pair's row counts and sums of ``u``, ``v``, ``u^2``, ``v^2``, ``u v`` (about zero)
also go to the band of pair ids it falls in (:data:`HISTORY_EDGES`: 10, 20, 50, 100, 200, 500
...): the sums of the pairs numbered below an edge are the bands' below it summed, whichever
order the pairs came in and however the run was split into shards (the bands add up).

Pairs that follow each other in time (a time-resolved recording, or pairs recorded faster
than the flow forgets) are not independent, and the scatter between pairs then understates the
errors. The rows' means carry the flow's slow scales more than any one vector does (averaging
along the wall takes out the measurement noise and the small scales, which decorrelate from one
pair to the next), so the serial correlation is taken where the errors are: each pair's six
sums (count, u, v, u^2, v^2, u v about the row's shift) are multiplied with those of the pairs
up to :data:`LAGS` ids before it, ``L_k = sum_p m_p m_{p+k}^T`` per row (plain sums: merging
adds them, a chain never joined across two merged parts). For a statistic of gradient ``w``
(the delta method's, as for the errors) the residuals' autocovariance at lag ``k`` is
``gamma_k = w^T L_k w``, and the variance of the run's mean is ``-gamma_0 + 2 sum_m Gamma_m``,
``Gamma_m = gamma_2m + gamma_2m+1`` summed while positive and not increasing (Geyer's initial
monotone sequence, 1992), up to lag ``min(LAGS, pairs / 4)``, each ``gamma_k / gamma_0``
averaged first over :data:`SMOOTH_ROWS` neighbouring rows (one row's estimate is noisy), and
none taken where the averaged lag-1 correlation is within :data:`SEEN_SIGMAS` sampling errors
of none (independent pairs then keep a factor of 1, but in the few rows where chance
correlation passes that test: there the estimate is conservative). :meth:`RowErrors.serial`
gives the factor by which that exceeds ``gamma_0`` (the independent pairs' variance; at least
1) and whether those lags fall short of :data:`WINDOW_TAUS` times the integrated correlation
time (``factor / 2`` pairs; ``open``: the run is too short, or its pairs too close in time, for
their correlation to be known; its errors are then lower bounds). Rows with fewer than
:data:`MIN_PAIRS` pairs get NaN.

Units: those of the fields added (px per pair in a campaign); errors of the stresses in their
square.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "BATCHES",
    "HISTORY_EDGES",
    "LAGS",
    "LAG_SHARE",
    "MIN_BATCHES",
    "MIN_PAIRS",
    "SEEN_SIGMAS",
    "SMOOTH_ROWS",
    "WINDOW_TAUS",
    "RowErrors",
]
# chain_lags, lag_max, lag_factor and serial_factor are the serial correlation's kernels,
# shared with rspiv.ptv_profile and rspiv.convergence (arrays in, no checks): not the API

#: Fewer pairs in a row than this: no error (a scatter of fewer pairs says little).
MIN_PAIRS = 3
#: Batches of pairs (a pair's id modulo this) whose rows' counts and sums of u are kept apart:
#: the delete-one-batch replicates of the profile (:meth:`RowErrors.replicates`), from which a
#: fit over many rows (u_tau) gets its error by the jackknife, row-to-row correlation and all.
BATCHES = 16
#: Fewer batches holding pairs than this: no replicates.
MIN_BATCHES = 8
#: The pair ids at which the history's bands part (:meth:`RowErrors.prefixes`): a 1-2-5
#: sequence from 10 pairs, the statistics of the pairs numbered below each.
HISTORY_EDGES = tuple(m * 10**e for e in range(1, 9) for m in (1, 2, 5))
#: The history's sums per band and row: count, u, v, u^2, v^2, u v (about zero).
_HISTORY_SUMS = 6
#: The most lags (pair ids apart) whose products of the pairs' six row sums are kept: the
#: serial correlation of a time-resolved run (module docstring, :meth:`RowErrors.serial`).
LAGS = 32
#: The serial correlation is followed up to this share of a row's pairs (longer lags are
#: estimated from too few products to be trusted).
LAG_SHARE = 0.25
#: The lags followed must span this many integrated correlation times (``factor / 2`` pairs)
#: for the factor to be near its limit; fewer and it is a lower bound (Sokal 1997 takes 4-6).
WINDOW_TAUS = 5.0
#: The rows' lag correlations are averaged over this many neighbouring rows before the sum
#: (one row's estimate from its pairs alone is noisy: over 200 independent pairs its factor
#: strays to 1.4 in a tenth of the rows).
SMOOTH_ROWS = 9
#: A row's averaged lag-1 correlation is taken as seen beyond this many of its sampling errors
#: for independent pairs; below, the row's pairs count as independent (factor 1).
SEEN_SIGMAS = 2.0

# the ten per-pair row sums: count, u, v, uu, vv, uv, u^3, v^3, u^4, v^4 (the first six: the
# sums of states written before the higher powers were)
_N, _U, _V, _UU, _VV, _UV, _U3, _V3, _U4, _V4 = range(10)
_SUMS = 10


class RowErrors:
    """Per-row cluster sums over a run's pairs (module docstring).

    Parameters
    ----------
    rows : int
        The fields' rows (axis 0; the profile runs along it, averaged along axis 1).

    Attributes
    ----------
    total : ndarray, shape (rows, 10)
        The ten sums over every pair (6 in a state written before the higher powers).
    outer : ndarray, shape (rows, 10, 10)
        The sums over the pairs of each pair's products of its sums.
    pairs_in : ndarray of int64, shape (rows,)
        Pairs with a valid vector in the row.
    pair_ids : set of int
    n_fields : int
    """

    def __init__(self, rows: int) -> None:
        if int(rows) < 1:
            raise InvalidInputError(f"rows must be >= 1, got {rows}")
        self.rows = int(rows)
        self.total = np.zeros((self.rows, _SUMS))
        self.outer = np.zeros((self.rows, _SUMS, _SUMS))
        self.pairs_in = np.zeros(self.rows, np.int64)
        self.pair_ids: set[int] = set()
        self.n_fields = 0
        #: the (u, v) each row's sums are taken about (its first pair's row mean): powers of
        #: small numbers, so that the central moments and their errors keep their digits
        self.shift = np.zeros((self.rows, 2))
        #: per batch of pairs (:data:`BATCHES`) and row: the count and the sum of u (about
        #: zero); None in states written before the batches
        self.batch: np.ndarray | None = np.zeros((BATCHES, self.rows, 2))
        #: per band of pair ids (:data:`HISTORY_EDGES`) and row: the count and the sums of u,
        #: v, u^2, v^2, u v (about zero); None in states written before the history
        self.history: np.ndarray | None = np.zeros(
            (len(HISTORY_EDGES) + 1, self.rows, _HISTORY_SUMS)
        )
        #: per lag k = 1 .. LAGS and row: the sums over the pairs p of the products of pair p's
        #: six sums (about the shift) with those of pair p + k (``L_k``, module docstring);
        #: None in states written before them
        self.lags: np.ndarray | None = np.zeros((LAGS, self.rows, 6, 6))
        #: the last pairs added, ``(pair id, six sums per row)``, whose products with the next
        #: pairs are still to be taken (the chain; not written to NetCDF, cleared by a merge)
        self.recent: list[tuple[int, np.ndarray]] = []

    def __setstate__(self, state: dict) -> None:
        state.setdefault("shift", np.zeros((int(state["rows"]), 2)))  # pickled before shifts
        state.setdefault("batch", None)  # pickled before the batches
        state.setdefault("history", None)  # pickled before the history
        state.setdefault("lags", None)  # pickled before the lags
        state.setdefault("recent", [])
        self.__dict__.update(state)

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
        cnt = ok.sum(axis=1)
        fresh = (self.total[:, _N] == 0) & (cnt > 0)  # a row's first vectors: its shift
        if fresh.any():
            with np.errstate(invalid="ignore", divide="ignore"):
                first = np.stack([np.where(ok, u, 0.0).sum(1), np.where(ok, v, 0.0).sum(1)], -1)
            self.shift[fresh] = first[fresh] / cnt[fresh, None]
        uz = np.where(ok, u - self.shift[:, :1], 0.0)
        vz = np.where(ok, v - self.shift[:, 1:], 0.0)
        u2, v2 = uz * uz, vz * vz
        m = np.stack(
            [cnt, uz.sum(1), vz.sum(1), u2.sum(1), v2.sum(1), (uz * vz).sum(1),
             (u2 * uz).sum(1), (v2 * vz).sum(1), (u2 * u2).sum(1), (v2 * v2).sum(1)], axis=-1,
        ).astype(np.float64)[:, : self.total.shape[1]]  # fmt: skip
        self.total += m
        self.outer += m[:, :, None] * m[:, None, :]
        self.pairs_in += m[:, _N] > 0
        pid = int(pair_id) if pair_id is not None else self.n_fields
        # the sums about zero from those about the shift (a, b): x = x' + a expanded
        a, b = self.shift[:, 0], self.shift[:, 1]
        su, sv = m[:, _U] + cnt * a, m[:, _V] + cnt * b
        if self.batch is not None:
            self.batch[pid % BATCHES, :, 0] += cnt
            self.batch[pid % BATCHES, :, 1] += su
        if self.history is not None:
            self.history[int(np.searchsorted(HISTORY_EDGES, pid, side="right"))] += np.stack(
                [cnt, su, sv, m[:, _UU] + a * (m[:, _U] + su), m[:, _VV] + b * (m[:, _V] + sv),
                 m[:, _UV] + a * m[:, _V] + b * su], axis=-1,
            )  # fmt: skip
        if self.lags is not None:
            chain_lags(self.lags, self.recent, pid, m[:, :6].copy())
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: RowErrors) -> RowErrors:
        """Add ``other``'s sums (the same rows, no pair in both); returns self. The chains of
        the two parts are not joined (their lag products stay each part's own) and the next
        :meth:`add` starts a new one."""
        if other.rows != self.rows:
            raise InvalidInputError(f"row errors: {other.rows} rows, not {self.rows}")
        common = self.pair_ids & other.pair_ids
        if common:
            raise InvalidInputError(f"row errors: pair {min(common)} in both parts")
        k = min(self.total.shape[1], other.total.shape[1])  # a state of six sums: the six
        empty = self.total[:, _N] == 0  # rows of no vector yet take other's shift
        self.shift[empty] = other.shift[empty]
        t = _shift_transform(self.shift - other.shift)[:, :k, :k]
        self.total = self.total[:, :k] + np.einsum("rij,rj->ri", t, other.total[:, :k])
        self.outer = self.outer[:, :k, :k] + np.einsum(
            "rij,rjk,rlk->ril", t, other.outer[:, :k, :k], t
        )
        self.pairs_in += other.pairs_in
        theirs = getattr(other, "batch", None)
        self.batch = None if self.batch is None or theirs is None else self.batch + theirs
        theirs = getattr(other, "history", None)
        self.history = None if self.history is None or theirs is None else self.history + theirs
        theirs = getattr(other, "lags", None)
        if self.lags is None or theirs is None:
            self.lags = None
        else:
            t6 = t[:, :6, :6]
            self.lags = self.lags + np.einsum("rij,krjl,rml->krim", t6, theirs, t6)
        self.recent = []
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    def result(self) -> dict[str, np.ndarray]:
        """Per row: the pooled ``U``, ``V``, ``uu``, ``vv``, ``uv``, ``S_u``, ``F_u``, ``S_v``,
        ``F_v`` and their standard errors ``se_U`` ... ``se_F_v`` from the pairs' scatter
        (module docstring; no S or F from a state of six sums), ``pairs`` (NaN errors below
        :data:`MIN_PAIRS`); with the lags (states written since), ``serial_U`` ...
        ``serial_uv``, the factor by which the serial correlation of the pairs multiplies the
        variance of each (at least 1; NaN below :data:`MIN_PAIRS` pairs), ``open_U`` ...
        ``open_uv`` (True where the lags followed span fewer than :data:`WINDOW_TAUS`
        correlation times: the factor is a lower bound), ``gamma_U`` ... ``gamma_uv`` (lags 0 ..
        LAGS x rows: the autocovariances of each statistic's residuals, whose lag 0 is its
        variance for independent pairs) and ``lag_max`` (the lags followed per row). The
        ``se_`` values are those of independent pairs: the caller multiplies their variances by
        the factor (:func:`rspiv.profiles.pair_errors`)."""
        t, q = self.total, self.outer
        n = t[:, _N]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = t / n[:, None]
            U, V = mean[:, _U], mean[:, _V]  # about the shift
            out = {
                "U": U + self.shift[:, 0],
                "V": V + self.shift[:, 1],
                "uu": mean[:, _UU] - U * U,
                "vv": mean[:, _VV] - V * V,
                "uv": mean[:, _UV] - U * V,
                "pairs": self.pairs_in.copy(),
            }
            # each statistic's derivative by the sums, over n (the delta method)
            zero = np.zeros_like(U)
            grads = {
                "U": (-U, np.ones_like(U), zero, zero, zero, zero),
                "V": (-V, zero, np.ones_like(U), zero, zero, zero),
                "uu": (2 * U * U - mean[:, _UU], -2 * U, zero, np.ones_like(U), zero, zero),
                "vv": (2 * V * V - mean[:, _VV], zero, -2 * V, zero, np.ones_like(U), zero),
                "uv": (2 * U * V - mean[:, _UV], -V, -U, zero, zero, np.ones_like(U)),
            }
            if t.shape[1] >= _SUMS:
                for comp, i1, i2, i3, i4 in (("u", _U, _UU, _U3, _U4), ("v", _V, _VV, _V3, _V4)):
                    for key, val, g in _shape_gradients(mean[:, [i1, i2, i3, i4]]):
                        out[f"{key}_{comp}"] = val
                        grad = [zero] * _SUMS
                        for i, gi in zip((i1, i2, i3, i4), g, strict=True):
                            grad[i] = gi
                        # d/dn of f(t / n): -sum_j df/dm_j m_j
                        grad[_N] = -sum(gi * mean[:, i] for i, gi in zip((i1, i2, i3, i4), g,
                                                                         strict=True))  # fmt: skip
                        grads[f"{key}_{comp}"] = tuple(grad)
            p = self.pairs_in.astype(np.float64)
            scale = np.where(p >= MIN_PAIRS, p / np.maximum(p - 1, 1), np.nan)
            if self.lags is not None:
                out["lag_max"] = lag_max(p)
            for key, g in grads.items():
                g = tuple(g) + (zero,) * (t.shape[1] - len(g))
                w = np.stack(g, axis=-1) / n[:, None]
                var = np.einsum("ri,rij,rj->r", w, q, w) * scale
                out[f"se_{key}"] = np.sqrt(np.maximum(var, 0.0))
                if self.lags is not None and key in ("U", "V", "uu", "vv", "uv"):
                    w6 = np.nan_to_num(w[:, :6])
                    gam0 = np.einsum("ri,rij,rj->r", w6, q[:, :6, :6], w6)
                    gam = np.einsum("ri,krij,rj->kr", w6, self.lags, w6)
                    out[f"gamma_{key}"] = np.concatenate([gam0[None], gam])
                    factor, still = lag_factor(gam0, gam, p)
                    ok = p >= MIN_PAIRS
                    out[f"serial_{key}"] = np.where(ok, factor, np.nan)
                    out[f"open_{key}"] = ok & still
        return out

    def serial(self, statistic: str = "U") -> tuple[np.ndarray, np.ndarray] | None:
        """The serial correlation's factor on the variance of ``statistic`` ("U", "V", "uu",
        "vv" or "uv") per row and whether it is a lower bound (:meth:`result`'s ``serial_`` and
        ``open_``); None for sums written before the lags."""
        if statistic not in ("U", "V", "uu", "vv", "uv"):
            raise InvalidInputError(
                f"row errors: no serial factor of {statistic!r} (U, V, uu, vv or uv)"
            )
        if self.lags is None:
            return None
        res = self.result()
        return res[f"serial_{statistic}"], res[f"open_{statistic}"]

    def replicates(self) -> np.ndarray | None:
        """The rows' mean u with each batch of pairs left out in turn (batches x rows, the
        batches holding pairs only; NaN in a row no other batch reaches): a fit over the rows
        done again on each gives its jackknife error (:func:`rspiv.boundary_layer.
        u_tau_jackknife`). None before :data:`MIN_BATCHES` batches hold pairs, or for sums
        written before the batches."""
        if self.batch is None:
            return None
        used = np.flatnonzero(self.batch[:, :, 0].sum(axis=1) > 0)
        if used.size < MIN_BATCHES:
            return None
        whole = self.batch.sum(axis=0)
        rest = whole[None] - self.batch[used]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(rest[..., 0] > 0, rest[..., 1] / rest[..., 0], np.nan)

    def prefixes(self) -> list[tuple[int, np.ndarray]]:
        """The history's sums (rows x 6: count, u, v, u^2, v^2, u v) of the pairs numbered
        below each edge of :data:`HISTORY_EDGES` that parts the run's pairs, and of them all
        last, each as ``(pairs in it, sums)`` (one per number of pairs). Empty for sums
        written before the history."""
        if self.history is None or not self.pair_ids:
            return []
        ids = np.fromiter(self.pair_ids, np.int64, len(self.pair_ids))
        cum = np.cumsum(self.history, axis=0)
        out: list[tuple[int, np.ndarray]] = []
        for i, edge in enumerate(HISTORY_EDGES):
            n = int(np.count_nonzero(ids < edge))
            if 0 < n < ids.size and (not out or n > out[-1][0]):  # empty bands: one prefix
                out.append((n, cum[i]))
            if n == ids.size:
                break
        out.append((int(ids.size), cum[-1]))
        return out

    def to_dataset_vars(self) -> tuple[dict, dict]:
        """``(variables, attrs)`` to write beside a FieldAccumulator's (``row_errors_*``)."""
        return (
            {
                "row_errors_total": (("y", "row_errors_sum"), self.total),
                "row_errors_outer": (("y", "row_errors_sum", "row_errors_sum2"), self.outer),
                "row_errors_pairs": (("y",), self.pairs_in),
                "row_errors_shift": (("y", "component"), self.shift),
                **(
                    {}
                    if self.batch is None
                    else {
                        "row_errors_batch": (
                            ("row_errors_batch", "y", "row_errors_part"),
                            self.batch,
                        )
                    }
                ),
                **(
                    {}
                    if self.history is None
                    else {
                        "row_errors_history": (
                            ("row_errors_band", "y", "row_errors_hsum"),
                            self.history,
                        )
                    }
                ),
                **(
                    {}
                    if self.lags is None
                    else {
                        "row_errors_lags": (
                            ("row_errors_lag", "y", "row_errors_lsum", "row_errors_lsum2"),
                            self.lags,
                        )
                    }
                ),
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
        if "row_errors_shift" in ds:  # states written before the shifts: about zero
            acc.shift = np.asarray(ds["row_errors_shift"].values, np.float64).copy()
        acc.batch = (  # none in states written before the batches
            np.asarray(ds["row_errors_batch"].values, np.float64).copy()
            if "row_errors_batch" in ds
            else None
        )
        acc.history = (  # none in states written before the history
            np.asarray(ds["row_errors_history"].values, np.float64).copy()
            if "row_errors_history" in ds
            else None
        )
        acc.lags = (  # none in states written before the lags; the chain starts anew
            np.asarray(ds["row_errors_lags"].values, np.float64).copy()
            if "row_errors_lags" in ds
            else None
        )
        acc.pair_ids = {int(i) for i in pair_ids}
        return acc


def chain_lags(
    lags: np.ndarray, recent: list[tuple[int, np.ndarray]], pid: int, sums: np.ndarray
) -> None:
    """Add to ``lags`` (LAGS x rows x S x S) the products of pair ``pid``'s sums ``sums``
    (rows x S) with those of the ``recent`` pairs up to :data:`LAGS` ids away (the earlier
    pair's on the left, whichever came first), and keep it among the recent ones (the last
    ``2 LAGS``: pairs a little out of order still meet). The one chain of
    :class:`RowErrors` and :class:`rspiv.ptv_profile.TrackProfile`."""
    for q, sq in recent:
        k = abs(pid - q)
        if 1 <= k <= LAGS:
            early, late = (sq, sums) if q < pid else (sums, sq)
            lags[k - 1] += early[:, :, None] * late[:, None, :]
    recent.append((pid, sums))
    if len(recent) > 2 * LAGS:
        del recent[0]


def lag_max(pairs: np.ndarray) -> np.ndarray:
    """The lags followed per row of ``pairs`` pairs: :data:`LAG_SHARE` of them, at most
    :data:`LAGS`."""
    return np.minimum(LAGS, np.floor(LAG_SHARE * np.asarray(pairs, np.float64))).astype(np.int64)


def lag_factor(
    gamma0: np.ndarray, gamma: np.ndarray, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`serial_factor` of a statistic's autocovariances per row (``gamma0`` (rows,),
    ``gamma`` (lags x rows), as :meth:`RowErrors.result`'s ``gamma_`` holds them) over the
    lags :func:`lag_max` follows for ``pairs``, each row's
    correlations averaged over :data:`SMOOTH_ROWS` neighbours first; rows of fewer than
    :data:`MIN_PAIRS` ``pairs`` or no variance are left out of the average (factor 1), and so
    are rows whose averaged lag-1 correlation is within :data:`SEEN_SIGMAS` of its sampling
    error for independent pairs, ``1 / sqrt(pairs x rows averaged)`` (a correlation not seen:
    the sequence would otherwise add the noise of its first terms, a factor of 1.5-2 on one
    row of 40 independent pairs)."""
    pairs = np.asarray(pairs, np.float64)
    ok = (pairs >= MIN_PAIRS) & (gamma0 > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho, count = _along_rows(np.where(ok, gamma / np.where(ok, gamma0, 1.0), np.nan))
        seen = rho[0] > SEEN_SIGMAS / np.sqrt(pairs * count[0])
    return serial_factor((ok & seen).astype(np.float64), rho, lag_max(pairs))


def _along_rows(rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rho`` (lags x rows, NaN where unknown) averaged over :data:`SMOOTH_ROWS` neighbouring
    rows (those known; the correlation time changes slowly with height, its estimate from one
    row's pairs is noisy), and how many rows each average holds."""
    half = SMOOTH_ROWS // 2
    known = np.isfinite(rho)
    pad = ((0, 0), (half + 1, half))
    s = np.cumsum(np.pad(np.where(known, rho, 0.0), pad), axis=1)
    c = np.cumsum(np.pad(known.astype(np.float64), pad), axis=1)
    w = SMOOTH_ROWS
    total, count = s[:, w:] - s[:, :-w], c[:, w:] - c[:, :-w]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(known, total / count, np.nan), count


def serial_factor(
    gamma0: np.ndarray, gamma: np.ndarray, kmax: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The factor by which serial correlation multiplies a mean's variance, per row, from the
    residuals' autocovariances: ``gamma0`` (rows,) at lag 0, ``gamma`` (lags x rows) at lags
    1, 2 ...; ``kmax`` (rows,) the lags to follow at most. Geyer's initial monotone sequence:
    ``Gamma_m = gamma_2m + gamma_2m+1`` added while positive (and capped by the one before), the
    variance ``-gamma0 + 2 sum Gamma_m`` over ``gamma0`` (at least 1; 1 where ``gamma0`` is
    not positive). Returns ``(factor, open)``, ``open`` True where ``kmax`` is short of
    :data:`WINDOW_TAUS` integrated correlation times (``factor / 2`` pairs): the sum cut before
    the correlation has died out, the factor a lower bound."""
    g0 = np.asarray(gamma0, np.float64)
    g = np.asarray(gamma, np.float64)
    kmax = np.asarray(kmax, np.int64)
    total = np.zeros_like(g0)
    prev = np.full_like(g0, np.inf)
    alive = (g0 > 0) & (kmax >= 1)
    for m in range((g.shape[0] + 1) // 2):
        hi = 2 * m + 1  # Gamma_m: lags 2m and 2m + 1 (lag 0 is gamma0)
        within = alive & (hi <= kmax)
        if not within.any():
            break
        pair = (g0 if m == 0 else g[2 * m - 1]) + g[hi - 1]
        end = within & ~(pair > 0)
        add = within & ~end
        alive &= ~end
        pair = np.minimum(pair, prev)
        total = np.where(add, total + pair, total)
        prev = np.where(add, pair, prev)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(g0 > 0, (2 * total - g0) / g0, 1.0)
    factor = np.maximum(np.nan_to_num(factor, nan=1.0), 1.0)
    # the integrated correlation time in pairs is factor / 2: the lags followed must reach
    # WINDOW_TAUS of it for the sum to be near its limit (Sokal's window)
    return factor, kmax < WINDOW_TAUS * factor / 2


def _shape_gradients(raw: np.ndarray):
    """The skewness ``S = c3 / c2^1.5`` and flatness ``F = c4 / c2^2`` of the raw moments
    ``raw`` (rows x [E u, E u^2, E u^3, E u^4]), each as ``(name, value, gradient by the four
    raw moments)``."""
    m1, m2, m3, m4 = raw.T
    c2 = m2 - m1 * m1
    c3 = m3 - 3 * m1 * m2 + 2 * m1**3
    c4 = m4 - 4 * m1 * m3 + 6 * m1 * m1 * m2 - 3 * m1**4
    zero, one = np.zeros_like(m1), np.ones_like(m1)
    d2 = (-2 * m1, one, zero, zero)
    d3 = (-3 * m2 + 6 * m1 * m1, -3 * m1, one, zero)
    d4 = (-4 * m3 + 12 * m1 * m2 - 12 * m1**3, 6 * m1 * m1, -4 * m1, one)
    s_val, f_val = c3 / c2**1.5, c4 / c2**2
    ds = tuple(a / c2**1.5 - 1.5 * c3 / c2**2.5 * b for a, b in zip(d3, d2, strict=True))
    df = tuple(a / c2**2 - 2 * c4 / c2**3 * b for a, b in zip(d4, d2, strict=True))
    return (("S", s_val, ds), ("F", f_val, df))


def _shift_transform(delta: np.ndarray) -> np.ndarray:
    """Per row, the matrix that takes the ten sums about one (u, v) to the sums about it plus
    ``delta`` (rows x 2): ``x' = x - a``, ``y' = y - b`` expanded in powers of ``x`` and ``y``
    (the first six rows and columns for six sums)."""
    a, b = delta[:, 0], delta[:, 1]
    t = np.zeros((delta.shape[0], _SUMS, _SUMS))
    t[:, np.arange(_SUMS), np.arange(_SUMS)] = 1.0
    for (x, xx, x3, x4), d in (((_U, _UU, _U3, _U4), a), ((_V, _VV, _V3, _V4), b)):
        t[:, x, _N] = -d
        t[:, xx, x], t[:, xx, _N] = -2 * d, d * d
        t[:, x3, xx], t[:, x3, x], t[:, x3, _N] = -3 * d, 3 * d * d, -(d**3)
        t[:, x4, x3], t[:, x4, xx], t[:, x4, x], t[:, x4, _N] = (
            -4 * d, 6 * d * d, -4 * d**3, d**4)  # fmt: skip
    t[:, _UV, _U], t[:, _UV, _V], t[:, _UV, _N] = -b, -a, a * b
    return t
