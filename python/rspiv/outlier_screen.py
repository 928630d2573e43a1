"""Screening a campaign's statistics for vectors that stand apart from their own ensemble.

The PIV's validation (the normalised median test, Westerweel & Scarano 2005) holds each vector
against its neighbours in the same field. Where a part of a pair does not correlate (a bubble in
the light sheet, a shadow, a glare spot, a drop on the window: windows of noise), the
neighbours are as random as the vector, the neighbours' residuals are large, and the
normalised residual is small: the random vectors pass. A noise patch of 20-50 px radius in a
synthetic boundary-layer pair left 83 valid vectors off the truth by 1-14 px (the peak ratio
1.0-1.8, where the pair's median is 4.5). A vector off by 8 px in one pair of 200 adds 0.3 px^2
to u'u' there: about a third of the variance of a boundary layer's u at 47 MP. No single field
tells, and the campaign's warnings say such a part only when it holds a tenth of the field.

Each vector's own ensemble does tell: a wrong peak lies anywhere in the search range, mostly
far outside the flow's fluctuations at that place. :class:`ScreenBounds` holds, per vector of
the final grid, a centre and a limit for u and v from pilot pairs spread over the run: the
samples of every pilot pair in the vector's neighbourhood, its row ``half_width`` columns
either side where the statistics change across the rows only (a wall's layer: 33 columns), a
square block of ``2 half_height + 1`` rows otherwise (9 x 9 vectors: a vortex's core, which a row
through it sees in a few columns only, would be screened by a row's bounds):

- the centre: the median of the samples;
- the scale ``s``: the samples' 5-95 % span over 3.29, the standard deviation for a Gaussian
  and within 1 % of it for a Laplace distribution (0.95 of it for a uniform one): nearly
  independent of the tails, unlike the median absolute deviation (0.73 of a Laplace's standard
  deviation), and moved little by up to 5 % of outliers among the samples;
- the limit: ``max(k s, FLOOR_PX, FLOOR_SHARE |c|)`` px (``|c|`` the centre's magnitude). The
  floors keep the flow's own slow changes in: a wrong peak lies at least a particle image away
  from the right one, and a tunnel's speed or a pulse separation drifting by up to a fifth over
  the run must not screen a vector (the campaign's ``pair_trends`` says drifts from 1 %).

A vector of a pair is screened when u or v lies beyond its limit from the centre, unless it
moves with its neighbours: within :data:`COHERENCE` of its limits from the median of its valid
neighbours (at least :data:`MIN_NEIGHBOURS` of the 8). A wrong peak in a part that does not
correlate has neighbours as random as itself; a real event the pilot pairs did not see (a
burst, a vortex passing) is smooth over the grid (the windows overlap). A screened vector is left
out of every statistic as a rejected vector is (:func:`rspiv.campaign.reduce.add_fields`), and
counted (:class:`ScreenTally`: per vector, per pair, and per row the squared deviations it
would have added). At the default ``k = 7`` a Gaussian variable passes the limit with
probability 3e-12, a Laplace one (flatness 6, heavier-tailed than a boundary layer's u and v
off the wall) with 5e-5, carrying 0.3 % of its variance (0.6 % measured with the bounds from
6 pilot fields of 132 samples each; 1.5 % at ``k = 6``); a neighbourhood with fewer than
:data:`MIN_SAMPLES` valid pilot samples is not screened. On the synthetic pair above, with
per-row scales, ``k = 7`` screened 73 % of the wrong vectors, holding 92 % of the variance they
added, and none of the 63,103 right ones (``k = 6``: 77 % and 95 %).

What it cannot do: a wrong vector within the flow's own fluctuations stays (it adds little); a
cluster of wrong vectors that agree with each other (a glare spot correlating at its own
standstill) stays; a rare real event beyond the flow's spread there that is not smooth over the
grid (a core a vector or two wide) is screened. Each screened vector is counted, and a row
where more than :data:`SAY_SHARE` of the vectors were screened is said. On OpenPIV's sample
recordings: none of ``test8``, ``test14`` and the ``test10`` vortex (13 of its core's vectors
with the bounds of rows), 9 of about 17,600 of ``test12``, and 5.5 % of ``test18`` (0.2
particle images per 32 x 32 px window, a median peak ratio of 1.6: vectors up to 10 px where
the flow moves 0.5 px), said.

Units: px per pair, like the fields. Rows are the final grid's rows (parallel to the wall in a
corrected, aligned run).
"""

from __future__ import annotations

import hashlib
import os
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "FLOOR_PX",
    "FLOOR_SHARE",
    "HALF_BLOCK",
    "HALF_WIDTH",
    "MIN_SAMPLES",
    "SAY_SHARE",
    "SIGMAS",
    "ScreenBounds",
    "ScreenTally",
    "screen_bounds",
]

#: Default limit in scales of the local spread.
SIGMAS = 7.0
#: Columns either side of a vector whose pilot samples give its centre and scale (its row).
HALF_WIDTH = 16
#: Rows and columns either side of a vector, the block of a flow without a wall.
HALF_BLOCK = 4
#: The limit is never under this many px (a wrong peak lies a particle image away or more).
FLOOR_PX = 2.0
#: Nor under this share of the centre's magnitude (slow drifts of the flow stay in).
FLOOR_SHARE = 0.2
#: A neighbourhood with fewer valid pilot samples is not screened.
MIN_SAMPLES = 24
#: A vector beyond its limit that lies within this share of its limit from the median of its
#: valid neighbours (at least :data:`MIN_NEIGHBOURS` of the 8) moves with them: kept.
COHERENCE = 0.5
#: Valid neighbours a vector needs for the coherence test (fewer: screened when beyond).
MIN_NEIGHBOURS = 3
#: A row with more than this share of its vectors screened is said.
SAY_SHARE = 0.01
#: The 5-95 % span of a unit Gaussian.
_SPAN = 3.2897072539029435
_ROWS = 64  # rows per chunk of the quantiles (a few tens of MB at 47 MP)


class ScreenBounds:
    """Per-vector centres and limits of u and v (px; NaN: not screened there).

    Parameters
    ----------
    center_u, center_v, limit_u, limit_v : ndarray, shape (ny, nx)
    sigmas : float
        The ``k`` the limits were made with.
    pairs : sequence of int
        The pilot pairs they come from.
    """

    def __init__(
        self,
        center_u: np.ndarray,
        center_v: np.ndarray,
        limit_u: np.ndarray,
        limit_v: np.ndarray,
        sigmas: float,
        pairs: Sequence[int] = (),
    ) -> None:
        arrays = [np.asarray(a, np.float32) for a in (center_u, center_v, limit_u, limit_v)]
        if len({a.shape for a in arrays}) != 1 or arrays[0].ndim != 2:
            raise InvalidInputError("screen bounds: four 2-D arrays of one shape expected")
        self.center_u, self.center_v, self.limit_u, self.limit_v = arrays
        self.sigmas = float(sigmas)
        self.pairs = [int(p) for p in pairs]

    @property
    def shape(self) -> tuple[int, int]:
        return self.center_u.shape  # type: ignore[return-value]

    def rows(self, sel: slice) -> ScreenBounds:
        """The bounds of the rows ``sel`` (views)."""
        arrays = (self.center_u, self.center_v, self.limit_u, self.limit_v)
        return ScreenBounds(*(a[sel] for a in arrays), self.sigmas, self.pairs)

    def outliers(self, u: Any, v: Any, valid: Any) -> np.ndarray:
        """The valid vectors of a field beyond their limits (bool, the field's shape)."""
        u = np.asarray(u, np.float64)
        v = np.asarray(v, np.float64)
        ok = np.asarray(valid, bool)
        if u.shape != self.shape or v.shape != self.shape or ok.shape != self.shape:
            raise InvalidInputError(
                f"screen: a field of shape {u.shape}, the bounds are {self.shape}"
            )
        with np.errstate(invalid="ignore"):
            out = (np.abs(u - self.center_u) > self.limit_u) | (
                np.abs(v - self.center_v) > self.limit_v
            )
        out &= ok
        if out.any():
            out[_coherent(out, u, v, ok, self.limit_u, self.limit_v)] = False
        return out

    def digest(self) -> str:
        """A hash of the bounds (the campaign's context carries it: other bounds, other
        statistics)."""
        h = hashlib.sha256()
        for a in (self.center_u, self.center_v, self.limit_u, self.limit_v):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((self.sigmas, self.pairs)).encode())
        return h.hexdigest()[:16]

    def save(self, path: str | os.PathLike) -> None:
        """Write the bounds to ``path`` (``.npz``), atomically."""
        path = os.fspath(path)
        tmp = f"{path}.tmp{os.getpid()}.npz"
        np.savez(
            tmp,
            center_u=self.center_u,
            center_v=self.center_v,
            limit_u=self.limit_u,
            limit_v=self.limit_v,
            sigmas=np.float64(self.sigmas),
            pairs=np.asarray(self.pairs, np.int64),
        )
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> ScreenBounds:
        """Read :meth:`save`'s file.

        Raises
        ------
        InvalidInputError
            Not a readable bounds file.
        """
        try:
            with np.load(os.fspath(path)) as z:
                return cls(
                    z["center_u"],
                    z["center_v"],
                    z["limit_u"],
                    z["limit_v"],
                    float(z["sigmas"]),
                    [int(p) for p in z["pairs"]],
                )
        except (OSError, ValueError, KeyError) as exc:
            raise InvalidInputError(f"{path}: not a readable screen bounds file ({exc})") from None


def _coherent(
    cand: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    ok: np.ndarray,
    lu: np.ndarray,
    lv: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates ``cand`` (row and column indices) that move with their valid neighbours:
    within :data:`COHERENCE` of their limits from the neighbours' median in u and v, with at
    least :data:`MIN_NEIGHBOURS` of them. A wrong peak's neighbours in a part that does not
    correlate are as random as it is; a real event (a burst, a vortex the pilot pairs did not
    see) is smooth over the grid."""
    ny, nx = cand.shape
    j, i = np.nonzero(cand)
    nu = np.full((j.size, 8), np.nan)
    nv = np.full((j.size, 8), np.nan)
    k = 0
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            if dj == di == 0:
                continue
            jj, ii = j + dj, i + di
            sel = (jj >= 0) & (jj < ny) & (ii >= 0) & (ii < nx)
            sel[sel] &= ok[jj[sel], ii[sel]]
            nu[sel, k] = u[jj[sel], ii[sel]]
            nv[sel, k] = v[jj[sel], ii[sel]]
            k += 1
    enough = np.isfinite(nu).sum(axis=1) >= MIN_NEIGHBOURS
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a candidate without neighbours
        mu, mv = np.nanmedian(nu, axis=1), np.nanmedian(nv, axis=1)
        keep = (
            enough
            & (np.abs(u[j, i] - mu) <= COHERENCE * lu[j, i])
            & (np.abs(v[j, i] - mv) <= COHERENCE * lv[j, i])
        )
    return j[keep], i[keep]


def _quantiles(
    stack: np.ndarray, half_width: int, half_height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per position of ``stack`` (P, ny, nx; NaN not valid): the 5, 50 and 95 % quantiles of
    the samples within ``half_width`` columns and ``half_height`` rows of it over every field,
    and their count."""
    p, ny, nx = stack.shape
    hw, hh = half_width, half_height
    qs = np.full((3, ny, nx), np.nan, np.float32)
    n = np.zeros((ny, nx), np.int64)
    rows = max(1, min(_ROWS, (8 << 20) // max(nx * p * (2 * hw + 1) * (2 * hh + 1), 1)))
    pad = np.full((p, ny + 2 * hh, nx + 2 * hw), np.nan, np.float32)
    pad[:, hh : hh + ny, hw : hw + nx] = stack
    for j0 in range(0, ny, rows):
        j1 = min(j0 + rows, ny)
        r = j1 - j0
        part = pad[:, j0 : j1 + 2 * hh]
        win = np.lib.stride_tricks.sliding_window_view(part, (2 * hh + 1, 2 * hw + 1), (1, 2))
        # (P, r, nx, H, W) -> (r, nx, P H W), sorted: NaN last
        s = np.sort(np.moveaxis(win, 0, 2).reshape(r, nx, -1), axis=-1)
        cnt = np.isfinite(s).sum(axis=-1)
        n[j0:j1] = cnt
        last = np.maximum(cnt - 1, 0)
        for k, q in enumerate((0.05, 0.5, 0.95)):
            pos = q * last
            lo = np.floor(pos).astype(np.int64)
            hi = np.minimum(lo + 1, last)
            a = np.take_along_axis(s, lo[..., None], -1)[..., 0]
            b = np.take_along_axis(s, hi[..., None], -1)[..., 0]
            qs[k, j0:j1] = a + (pos - lo) * (b - a)
    return qs[0], qs[1], qs[2], n


def screen_bounds(
    us: Sequence[Any],
    vs: Sequence[Any],
    valids: Sequence[Any],
    *,
    sigmas: float = SIGMAS,
    half_width: int = HALF_WIDTH,
    half_height: int = 0,
    pairs: Sequence[int] = (),
) -> ScreenBounds:
    """The bounds of :class:`ScreenBounds` from pilot fields (px; their valid vectors only).

    Parameters
    ----------
    us, vs, valids : sequences of array_like, each (ny, nx)
        The pilot pairs' fields (at least 2 of them; spread over the run, so that their
        samples hold its slow changes).
    sigmas : float
        ``k``, the limit in scales of the local spread (> 0).
    half_width, half_height : int
        Columns and rows either side of a vector that share its samples (>= 0): its row
        (``half_height = 0``) where the statistics change across the rows only (a wall's
        layer), a square block in a flow without such a direction (a vortex, whose core a row
        through it sees in a few columns only).
    pairs : sequence of int
        The pilot pairs' ids (recorded with the bounds).

    Raises
    ------
    InvalidInputError
        Fewer than 2 fields, fields of different shapes, ``sigmas <= 0`` or a negative half
        width or height.
    """
    if len(us) < 2 or not len(us) == len(vs) == len(valids):
        raise InvalidInputError("screen: at least 2 pilot fields of u, v and valid are needed")
    if not sigmas > 0 or half_width < 0 or half_height < 0:
        raise InvalidInputError(
            f"screen: sigmas {sigmas} (> 0), half_width {half_width} and half_height "
            f"{half_height} (>= 0)"
        )
    shape = np.shape(us[0])
    if len(shape) != 2 or any(
        np.shape(a) != shape for group in (us, vs, valids) for a in group
    ):
        raise InvalidInputError("screen: the pilot fields must be 2-D arrays of one shape")
    ok = np.stack([np.asarray(m, bool) for m in valids])
    out = []
    n = None
    for comp in (us, vs):
        stack = np.where(ok, np.stack([np.asarray(a, np.float32) for a in comp]), np.nan)
        lo, mid, hi, n = _quantiles(stack.astype(np.float32), int(half_width), int(half_height))
        out.append((mid, (hi - lo) / _SPAN))
    (cu, su), (cv, sv) = out
    floor = np.maximum(FLOOR_PX, FLOOR_SHARE * np.hypot(cu, cv))
    lu = np.maximum(sigmas * su, floor)
    lv = np.maximum(sigmas * sv, floor)
    few = n < MIN_SAMPLES
    for a in (cu, cv, lu, lv):
        a[few] = np.nan
    return ScreenBounds(cu, cv, lu, lv, sigmas, pairs)


class ScreenTally:
    """What a campaign's screen left out of a run's statistics, streamed and merged like them.

    Attributes
    ----------
    count : ndarray of int64, (ny, nx)
        Vectors screened at each position.
    row_sq_u, row_sq_v : ndarray of float64, (ny,)
        Per row, the sum of the screened vectors' squared deviations from their centres
        (px^2): divided by the row's samples, what they would have added to u'u' and v'v'.
    per_pair : dict of int to int
        Pair id -> vectors screened, for the pairs that had any.
    pair_ids : set of int
        The pairs added.
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = tuple(int(s) for s in shape)
        self.count = np.zeros(self.shape, np.int64)
        self.row_sq_u = np.zeros(self.shape[0])
        self.row_sq_v = np.zeros(self.shape[0])
        self.per_pair: dict[int, int] = {}
        self.pair_ids: set[int] = set()
        self.n_fields = 0

    def add(
        self, bounds: ScreenBounds, u: Any, v: Any, out: np.ndarray, pair_id: int | None = None
    ) -> None:
        """Count a field's screened vectors ``out`` (from :meth:`ScreenBounds.outliers`).

        Raises
        ------
        InvalidInputError
            Another shape, or a pair added before.
        """
        if pair_id is not None and int(pair_id) in self.pair_ids:
            raise InvalidInputError(f"screen: pair {pair_id} was added before")
        out = np.asarray(out, bool)
        if out.shape != self.shape or bounds.shape != self.shape:
            raise InvalidInputError(f"screen: shape {out.shape}, the tally's {self.shape}")
        n = int(out.sum())
        if n:
            self.count += out
            du = np.where(out, np.asarray(u, np.float64) - bounds.center_u, 0.0)
            dv = np.where(out, np.asarray(v, np.float64) - bounds.center_v, 0.0)
            self.row_sq_u += (du * du).sum(axis=1)
            self.row_sq_v += (dv * dv).sum(axis=1)
            if pair_id is not None:
                self.per_pair[int(pair_id)] = n
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: ScreenTally) -> ScreenTally:
        """Add another part's tally (other pairs of the same run)."""
        if other.shape != self.shape:
            raise InvalidInputError(f"screen: merging shape {other.shape} into {self.shape}")
        common = self.pair_ids & other.pair_ids
        if common:
            raise InvalidInputError(f"screen: pairs {sorted(common)[:5]} are in both parts")
        self.count += other.count
        self.row_sq_u += other.row_sq_u
        self.row_sq_v += other.row_sq_v
        self.per_pair.update(other.per_pair)
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    def result(self, valid_count: np.ndarray, top: int = 5) -> dict[str, Any]:
        """Figures of the tally against the statistics' valid count per vector (after the
        screen): ``vectors`` screened, their ``share`` of the vectors the PIV passed, the rows
        (indices) whose share exceeds :data:`SAY_SHARE` with their shares, the ``row_share``
        per row, the added variance per row (``row_added_uu``, ``row_added_vv``, px^2), and
        the ``pairs`` with the most screened vectors (``top`` of them)."""
        kept = np.asarray(valid_count, np.int64)
        row_n = (kept + self.count).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            row_share = np.where(row_n > 0, self.count.sum(axis=1) / row_n, 0.0)
            add_uu = np.where(row_n > 0, self.row_sq_u / row_n, 0.0)
            add_vv = np.where(row_n > 0, self.row_sq_v / row_n, 0.0)
        total = int(self.count.sum())
        passed = int(row_n.sum())
        rows = np.flatnonzero(row_share > SAY_SHARE)
        worst = sorted(self.per_pair.items(), key=lambda kv: (-kv[1], kv[0]))[:top]
        return {
            "vectors": total,
            "share": total / passed if passed else 0.0,
            "rows_said": [int(j) for j in rows],
            "rows_said_share": [round(float(row_share[j]), 4) for j in rows],
            "row_share": row_share,
            "row_added_uu": add_uu,
            "row_added_vv": add_vv,
            "pairs_with_any": len(self.per_pair),
            "pairs": [[int(p), int(c)] for p, c in worst],
        }

    def to_dataset_vars(self) -> tuple[dict, dict]:
        """``(variables, attrs)`` to write beside a FieldAccumulator's (``screened_*``)."""
        pairs = np.asarray(sorted(self.per_pair.items()), np.int64).reshape(-1, 2)
        variables = {
            "screened_count": (("y", "x"), self.count),
            "screened_row_sq_u": (("y",), self.row_sq_u),
            "screened_row_sq_v": (("y",), self.row_sq_v),
            "screened_pairs": (("screened_pair", "screened_column"), pairs),
        }
        return variables, {"screened_fields": int(self.n_fields)}

    @classmethod
    def from_dataset_vars(cls, ds: Any, pair_ids: Any) -> ScreenTally:
        """Read back :meth:`to_dataset_vars` (the pairs are the statistics')."""
        count = np.asarray(ds["screened_count"].values, np.int64)
        acc = cls(count.shape)
        acc.count = count.copy()
        acc.row_sq_u = np.array(ds["screened_row_sq_u"].values, np.float64)
        acc.row_sq_v = np.array(ds["screened_row_sq_v"].values, np.float64)
        acc.per_pair = {int(p): int(c) for p, c in np.asarray(ds["screened_pairs"].values)}
        acc.n_fields = int(ds.attrs.get("screened_fields", 0))
        acc.pair_ids = {int(i) for i in pair_ids}
        return acc
