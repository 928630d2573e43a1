"""Conditional averages of the velocity fluctuations about ejections and sweeps, and about
events named by the caller (vortex cores).

What an ejection (a Q2 event: ``u' < 0``, ``v' > 0``) or a sweep (Q4: ``u' > 0``, ``v' < 0``)
at a reference height looks like around it, on average: the low- or high-speed region it sits
in, its streamwise extent and its inclination to the wall. The quadrant analysis
(:mod:`rspiv.quadrant`) says how much stress the events carry; this says what they carry it
with.

Definition. For a reference row ``r`` and each field, the events are the vectors ``(r, c)``
of that row, valid and usable, in the event's quadrant and outside the hole: ``|u' v'| >= H
u_rms v_rms`` with the vector's own standard deviations (the quadrant analysis's rule; ``H``
the ``hole``). The conditional average at the offset ``(row, d)`` is

    <u' | event>(row, d) = sum over fields and events (r, c) of u'(row, c + d) / N(row, d)

where ``N`` counts the terms whose vector ``(row, c + d)`` is valid and usable (an event near
the field's edge adds to the offsets inside it only), and ``<v' | event>`` alike. Each vector
is an event of its own (no extremum picked): for jointly Gaussian fluctuations this is exactly
the linear stochastic estimate ``C(u'(row, c + d), z) C_zz^-1 <z | event>`` of ``z = (u'(r,
c), v'(r, c))`` (``tests/test_conditional.py`` holds it to the sampling error).

Frame and units: ``u' = sign_x (u - U)`` positive downstream and ``v' = sign_y (v - V)``
positive away from the wall, each vector's fluctuation about its own mean, in the fields'
units (px per pair); offsets ``d`` in grid columns (``sign_x d`` columns downstream) and
``row`` in grid rows. Which rows and offsets: every ``row_step``-th row of ``rows`` and every
``col_step``-th offset from ``-half_width`` to ``half_width``, so that a 47 MP grid's map
stays at about 160 x 160 points (the structures are the boundary layer's, many vectors wide).

Other events: the kinds :data:`VORTEX_KINDS` (``prograde``, ``retrograde``) are events the
caller names field by field (``add(..., events=...)``: a vortex pass's cores, each at the grid
vector nearest its centroid on a reference row); the averages about them are the same sums.

Standard errors: from ``batches`` batch means of contiguous pairs (the caller names each
field's batch), which keeps the correlation of an event's neighbours and of consecutive pairs
inside a batch.

Cost: each field's rows of the map are Fourier-transformed along the row once (u', v', their
validity), and each reference row and kind costs three inverse transforms: the sums over the
events are correlations of the events' indicator with the rows: 9-15 ms per field of a 149 x
151 point map at 47 MP, whatever the number of events (``benches/bench_conditional.py``).
"""

from __future__ import annotations

import functools

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.grid_arrays import as_grid, entering

__all__ = ["KINDS", "VORTEX_KINDS", "ConditionalAccumulator"]

#: The quadrant events: Q2 ejections, Q4 sweeps (the default kinds, in this order).
KINDS: tuple[str, ...] = ("Q2", "Q4")
#: Events the caller names per field: vortex cores turning with the mean shear, and against it.
VORTEX_KINDS: tuple[str, ...] = ("prograde", "retrograde")

#: The most rows and offsets of a map along each axis (``row_step``, ``col_step`` chosen so).
MAX_MAP = 161


_grid = functools.partial(as_grid, "conditional")  # a 2-D array of the grid, checked


def _step(n: int) -> int:
    return max(1, -(-n // MAX_MAP))


class ConditionalAccumulator:
    """Conditional averages of ``u'``, ``v'`` about Q2 and Q4 events, summed field by field
    (module docstring).

    Parameters
    ----------
    mean_u, mean_v : array, shape (ny, nx)
        Each vector's mean displacement over the campaign, in the fields' frame and units.
    rms_u, rms_v : array, shape (ny, nx)
        Each vector's standard deviation, same units.
    ref_rows : sequence of int
        The reference rows (grid rows) whose vectors are the events.
    rows : (int, int), optional
        The map's rows ``[r0, r1)`` (default: every row).
    half_width : int, optional
        The map's offsets run from ``-half_width`` to ``half_width`` columns (default: the
        whole row, ``nx - 1``).
    usable : bool array, shape (ny, nx), optional
        Vectors that may enter (e.g. those with enough valid samples for their statistics);
        vectors whose mean or standard deviation is not finite and positive never enter.
    sign_x, sign_y : {1.0, -1.0}
        Orientation: ``u' = sign_x (u - U)`` positive downstream, ``v' = sign_y (v - V)``
        positive away from the wall.
    hole : float
        The hole size H >= 0: an event's ``|u'v'|`` is at least ``H u_rms v_rms``.
    batches : int
        Batches of fields for the standard errors.
    kinds : sequence of str
        The events, in the order of the results' ``kind`` axis: any of :data:`KINDS` and
        :data:`VORTEX_KINDS`, each once (default ``KINDS``); the latter are given to
        :meth:`add`.

    Raises
    ------
    InvalidInputError
        Arrays of different shapes, a reference row or the map's rows outside the grid, a
        negative hole or half width, a sign other than +-1, or an unknown or repeated kind.
    """

    def __init__(
        self,
        mean_u,
        mean_v,
        rms_u,
        rms_v,
        ref_rows,
        *,
        rows: tuple[int, int] | None = None,
        half_width: int | None = None,
        usable=None,
        sign_x: float = 1.0,
        sign_y: float = 1.0,
        hole: float = 1.0,
        batches: int = 8,
        kinds=KINDS,
    ):
        self.mean_u = _grid("mean_u", mean_u)
        self.shape: tuple[int, int] = self.mean_u.shape  # type: ignore[assignment]
        ny, nx = self.shape
        self.mean_v = _grid("mean_v", mean_v, self.shape)
        self.rms_u = _grid("rms_u", rms_u, self.shape)
        self.rms_v = _grid("rms_v", rms_v, self.shape)
        refs = np.asarray(ref_rows, dtype=np.int64).ravel()
        if refs.size == 0 or refs.min() < 0 or refs.max() >= ny:
            raise InvalidInputError(
                f"conditional: reference rows must lie in 0..{ny - 1}, got {refs.tolist()}"
            )
        r0, r1 = (0, ny) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= r0 < r1 <= ny:
            raise InvalidInputError(f"conditional: map rows [{r0}, {r1}) outside 0..{ny}")
        hw = nx - 1 if half_width is None else int(half_width)
        if hw < 0:
            raise InvalidInputError(f"conditional: half_width must be >= 0, got {half_width}")
        if sign_x not in (1.0, -1.0) or sign_y not in (1.0, -1.0):
            raise InvalidInputError(f"conditional: signs must be +1 or -1, got {sign_x}, {sign_y}")
        if not (np.isfinite(hole) and hole >= 0):
            raise InvalidInputError(f"conditional: the hole must be a number >= 0, got {hole}")
        self.kinds = tuple(str(k) for k in kinds)
        if (
            not self.kinds
            or len(set(self.kinds)) != len(self.kinds)
            or not set(self.kinds) <= set(KINDS + VORTEX_KINDS)
        ):
            raise InvalidInputError(
                f"conditional: kinds must be distinct ones of {KINDS + VORTEX_KINDS}, got "
                f"{list(self.kinds)}"
            )
        self.usable = entering(self.mean_u, self.mean_v, self.rms_u, self.rms_v, usable)
        self.sign_x, self.sign_y = float(sign_x), float(sign_y)
        self.hole = float(hole)
        self.ref_rows = refs
        self.map_rows = np.arange(r0, r1, _step(r1 - r0), dtype=np.int64)
        self.half_width = hw
        cstep = _step(2 * hw + 1)
        self.offsets = np.concatenate([-np.arange(0, hw + 1, cstep)[:0:-1],
                                       np.arange(0, hw + 1, cstep)])  # fmt: skip
        self.batches = max(int(batches), 1)
        from scipy.fft import next_fast_len  # deferred: scipy is heavy to import

        # an FFT length without wrap-around for |d| <= hw: nx + hw, rounded up to a fast one
        self._nfft = next_fast_len(nx + hw, real=True)
        # the events' hole at the reference rows: |u'v'| at least this
        self._thr = (self.hole * self.rms_u * self.rms_v)[refs]
        shape = (self.batches, refs.size, len(self.kinds), self.map_rows.size, self.offsets.size)
        self.sum_u = np.zeros(shape)
        self.sum_v = np.zeros(shape)
        self.n = np.zeros(shape, np.int64)
        self.events = np.zeros(shape[:3], np.int64)  # (batch, ref, kind)
        self.event_u = np.zeros(shape[:3])  # sum of the events' own u', v'
        self.event_v = np.zeros(shape[:3])
        self.n_fields = 0
        self.pair_ids: set[int] = set()

    def empty_copy(self) -> ConditionalAccumulator:
        """An accumulator of the same plan holding no field (for parts summed in parallel)."""
        new = object.__new__(ConditionalAccumulator)
        new.__dict__.update(self.__dict__)
        for k in ("sum_u", "sum_v", "n", "events", "event_u", "event_v"):
            setattr(new, k, np.zeros_like(getattr(self, k)))
        new.n_fields = 0
        new.pair_ids = set()
        return new

    def fluctuations(self, u, v, valid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``u'``, ``v'`` of one field in the flow's signs (0 where not entering) and the
        mask of the vectors that enter (valid, finite and usable)."""
        u = _grid("u", u, self.shape)
        v = _grid("v", v, self.shape)
        ok = np.asarray(valid, bool).reshape(self.shape) & self.usable
        ok &= np.isfinite(u) & np.isfinite(v)
        uf = np.where(ok, self.sign_x * (u - self.mean_u), 0.0)
        vf = np.where(ok, self.sign_y * (v - self.mean_v), 0.0)
        return uf, vf, ok

    def _events(self, i: int, ur, vr, okr, given: dict) -> list[np.ndarray]:
        """The events of reference ``i`` (its row's ``u'``, ``v'``, mask) per kind."""
        big = okr & (np.abs(ur * vr) >= self._thr[i])
        out = []
        for kind in self.kinds:
            if kind == "Q2":
                out.append(big & (ur < 0) & (vr > 0))
            elif kind == "Q4":
                out.append(big & (ur > 0) & (vr < 0))
            else:  # named by the caller: valid vectors only
                out.append(given[kind][i] & okr)
        return out

    def add(self, u, v, valid, *, pair_id: int | None = None, batch: int = 0,
            events=None) -> None:  # fmt: skip
        """Add one field (``valid``: the vectors that are measurements; module docstring).
        ``pair_id`` is remembered (a pair is not added twice by a caller that checks it);
        ``batch`` in ``[0, batches)``; ``events``: for each kind of :data:`VORTEX_KINDS` among
        the accumulator's, a boolean array ``(references, nx)``, True at the vectors of each
        reference row that are events (a vector that does not enter is not one)."""
        b = int(batch)
        if not 0 <= b < self.batches:
            raise InvalidInputError(f"conditional: batch {batch} outside 0..{self.batches - 1}")
        given = {}
        for kind in self.kinds:
            if kind in KINDS:
                continue
            arr = None if events is None else events.get(kind)
            if arr is None:
                raise InvalidInputError(f"conditional: the {kind} events of this field are missing")
            arr = np.asarray(arr)
            if arr.dtype != bool or arr.shape != (self.ref_rows.size, self.shape[1]):
                raise InvalidInputError(
                    f"conditional: {kind} events must be boolean ({self.ref_rows.size}, "
                    f"{self.shape[1]}), got {arr.dtype} {arr.shape}"
                )
            given[kind] = arr
        uf, vf, ok = self.fluctuations(u, v, valid)
        n = self._nfft
        rows = self.map_rows
        fu = np.fft.rfft(uf[rows], n, axis=1)
        fv = np.fft.rfft(vf[rows], n, axis=1)
        fk = np.fft.rfft(ok[rows].astype(np.float64), n, axis=1)
        cols = self.offsets % n
        for i, r in enumerate(self.ref_rows):
            ur, vr, okr = uf[r], vf[r], ok[r]
            for k, ev in enumerate(self._events(i, ur, vr, okr, given)):
                m = int(np.count_nonzero(ev))
                if m == 0:
                    continue
                self.events[b, i, k] += m
                self.event_u[b, i, k] += float(ur[ev].sum())
                self.event_v[b, i, k] += float(vr[ev].sum())
                # sum over the events c of f(row, c + d): the correlation of the indicator
                g = np.conj(np.fft.rfft(ev.astype(np.float64), n))
                self.sum_u[b, i, k] += np.fft.irfft(fu * g, n, axis=1)[:, cols]
                self.sum_v[b, i, k] += np.fft.irfft(fv * g, n, axis=1)[:, cols]
                self.n[b, i, k] += np.rint(np.fft.irfft(fk * g, n, axis=1)[:, cols]).astype(
                    np.int64
                )
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: ConditionalAccumulator) -> None:
        """Add another accumulator of the same plan (a part summed in parallel)."""
        if (
            other.shape != self.shape
            or other.sum_u.shape != self.sum_u.shape
            or not np.array_equal(other.ref_rows, self.ref_rows)
            or not np.array_equal(other.map_rows, self.map_rows)
            or not np.array_equal(other.offsets, self.offsets)
            or other.hole != self.hole
            or other.kinds != self.kinds
        ):
            raise InvalidInputError("conditional: cannot merge accumulators of other plans")
        for k in ("sum_u", "sum_v", "n", "events", "event_u", "event_v"):
            getattr(self, k).__iadd__(getattr(other, k))
        self.n_fields += other.n_fields
        self.pair_ids |= other.pair_ids

    def results(self) -> dict[str, np.ndarray]:
        """The conditional averages and their standard errors.

        Returns
        -------
        dict
            ``u``, ``v`` (ref, kind, row, offset): the conditional averages (NaN where no
            term); ``u_se``, ``v_se``: their standard errors from the batch means (NaN with
            fewer than 2 batches holding terms); ``batches_used`` (ref, kind, row, offset);
            ``count`` (ref, kind, row, offset): the terms; ``events`` (ref, kind);
            ``event_u``, ``event_v`` (ref, kind): the events' own mean ``u'``, ``v'``;
            ``rows``, ``offsets``, ``ref_rows``: the grid rows and column offsets; ``kinds``.
        """
        n = self.n.sum(0)
        ev = self.events.sum(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out: dict[str, np.ndarray] = {
                "u": np.where(n > 0, self.sum_u.sum(0) / n, np.nan),
                "v": np.where(n > 0, self.sum_v.sum(0) / n, np.nan),
                "count": n,
                "events": ev,
                "event_u": np.where(ev > 0, self.event_u.sum(0) / ev, np.nan),
                "event_v": np.where(ev > 0, self.event_v.sum(0) / ev, np.nan),
            }
            has = self.n > 0
            used = has.sum(0)
            out["batches_used"] = used
            for q in ("u", "v"):
                means = np.where(has, getattr(self, f"sum_{q}") / np.maximum(self.n, 1), 0.0)
                mu = means.sum(0) / np.maximum(used, 1)
                var = np.where(has, (means - mu) ** 2, 0.0).sum(0) / np.maximum(used - 1, 1)
                out[f"{q}_se"] = np.where(used > 1, np.sqrt(var / np.maximum(used, 1)), np.nan)
        out["rows"] = self.map_rows.copy()
        out["offsets"] = self.offsets.copy()
        out["ref_rows"] = self.ref_rows.copy()
        out["kinds"] = np.array(self.kinds)
        return out

