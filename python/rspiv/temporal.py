"""Frequency spectra, space-time correlations and convection velocities of a time-resolved
recording, streamed field by field.

A high-speed camera's recording (frames paired sequentially, ``[images] pairing =
"sequential"``) gives fields one pair interval apart: the time series of every vector, which
the statistics cannot hold. :class:`TemporalAccumulator` takes the fields in time order and
keeps, at reference rows, the sums that give:

- the one-sided frequency spectra ``phi_uu(f)``, ``phi_vv(f)`` and the co-spectrum ``phi_uv(f)``
  (Welch: segments of ``segment`` fields overlapping by half, each column's segment detrended
  by its mean and tapered by a Hann window, averaged over the row's columns and the segments);
- the space-time correlation ``R_uu(dx, tau) = <u'(x, t) u'(x + dx, t + tau)> / sigma_u^2`` (and
  ``R_vv``) for time lags ``tau`` of 0 to ``max_lag`` pair intervals and offsets ``dx`` along the
  row, summed in Fourier space along the row (each field's row transformed once; no
  wrap-around);
- the convection velocity ``U_c(tau)``: the offset of the correlation's ridge at each lag over
  the lag. The ridge is followed from ``dx = 0`` at lag 0, lag by lag, to the local maximum
  nearest to where its last step points (a parabola through it and its neighbours), while it
  stands at 0.2 or more inside the offsets (:func:`follow_ridge`): a pattern of a few scales
  correlates again a wavelength away, and the largest value at a lag can lie on such a lobe.

Conventions and units
---------------------
Fields are in the fields' units (px per pair in a campaign), each vector's fluctuation about
its own mean (``mean_u``, ``mean_v``: the run's statistics), ``u' = sign_x (u - U)`` downstream,
``v' = sign_y (v - V)`` away from the wall. Time in pair intervals (``f`` in cycles per pair
interval, so that ``sum phi(f_j) df`` over the one-sided frequencies is the variance the taper
passes), offsets in grid columns (``d`` columns: ``sign_x d`` columns downstream). A campaign
converts to Hz, m and m/s (:mod:`rspiv.campaign.temporal`).

Which samples: the vectors of the reference rows that are valid and usable. A column enters a
segment when at least ``min_valid`` of its samples in it are; the others are set to the
segment's mean (they add no power). The correlations count each product of two valid vectors
(``pairs``); a gap in the pair ids (a pair left out or not processed) restarts the segment and
the lags, so nothing is correlated across it. Fields added to parts in parallel lose the
segments and lags that straddle their boundaries, nothing else: the parts merge by addition.

What a PIV field does to them (not corrected): the measurement noise is white, a floor under
the spectra at high frequencies and a spike at ``tau = 0`` that lowers ``R`` at every other lag
by ``var / (var + noise)``; the window's width averages the small scales away.
"""

from __future__ import annotations

import functools

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.grid_arrays import as_grid

__all__ = [
    "TemporalAccumulator",
    "consecutive_runs",
    "follow_ridge",
    "hann_taper",
    "noise_reached",
    "one_sided_density",
    "peak_offset",
]

#: A lag's correlation peak below this is not a convection velocity (the structures are gone).
MIN_PEAK = 0.2


_grid = functools.partial(as_grid, "temporal")  # a 2-D array of the grid, checked


def _even_segment(m) -> int:
    if isinstance(m, bool) or int(m) != m or m < 2 or m % 2:
        raise InvalidInputError(f"temporal: a segment must be an even integer >= 2, got {m!r}")
    return int(m)


def hann_taper(m: int) -> np.ndarray:
    """The periodic Hann window of ``m`` samples (scipy.signal.welch's; ``m`` even, >= 2): a
    line on a bin fills 3 bins."""
    m = _even_segment(m)
    return 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(m) / m)


def one_sided_density(m: int) -> np.ndarray:
    """The factor per bin of ``rfft`` of a Hann-tapered segment of ``m`` samples (``m`` even)
    that makes ``|X|^2`` a one-sided spectral density per cycle per sample: 2 (1 at 0 and the
    Nyquist bin) over the taper's sum of squares, so ``sum phi(f_j) / m`` is the variance the
    taper passes."""
    m = _even_segment(m)
    scale = np.full(m // 2 + 1, 2.0)
    scale[0] = 1.0
    scale[-1] = 1.0  # m even: the Nyquist bin is its own
    return scale / np.sum(hann_taper(m) ** 2)


def noise_reached(phi, floor, factor: float = 2.0) -> np.ndarray:
    """The index of the lowest frequency from which a spectrum ``phi`` (``(..., nf)``) stays
    under ``factor`` times its noise floor ``floor`` (``(...)``, a white floor's density) at
    every higher frequency: -1 where it never does (resolved to the Nyquist frequency), 0 where
    it does at every frequency (noise throughout; the mean's bin 0 aside, 1). NaN floors give
    -1."""
    phi = np.asarray(phi, np.float64)
    floor = np.asarray(floor, np.float64)
    if phi.ndim < 1 or phi.shape[-1] < 1 or floor.shape != phi.shape[:-1]:
        raise InvalidInputError(
            f"temporal: a floor of shape {phi.shape[:-1]} per spectrum of {phi.shape} needed, "
            f"got {floor.shape}"
        )
    floor = np.broadcast_to(floor[..., None], phi.shape)
    with np.errstate(invalid="ignore"):
        under = phi < factor * floor
    # under from index j to the end: the reversed cumulative product
    tail = np.cumprod(under[..., ::-1], axis=-1)[..., ::-1].astype(bool)
    first = np.argmax(tail, axis=-1)
    return np.where(tail.any(axis=-1), first, -1)


def consecutive_runs(ids) -> list[int]:
    """The lengths of the runs of consecutive integers in sorted ``ids`` (a gap in a time
    series' pair ids ends a run)."""
    ids = np.asarray(ids)
    if ids.size and (ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer)):
        raise InvalidInputError(f"temporal: ids must be 1-D integers, got {ids.dtype} {ids.shape}")
    if ids.size > 1 and np.any(np.diff(ids) <= 0):
        raise InvalidInputError("temporal: ids must increase")
    ids = ids.astype(np.int64)
    if ids.size == 0:
        return []
    cut = np.flatnonzero(np.diff(ids) != 1) + 1
    return [len(r) for r in np.split(ids, cut)]


def peak_offset(r: np.ndarray, near: float | None = None) -> float:
    """The sub-sample position (index) of a peak of ``r``: the largest value, or with ``near``
    the local maximum nearest to that index (a parabola through it and its neighbours); NaN
    when it lies at an end or ``r`` holds no finite value there."""
    r = np.asarray(r, np.float64)
    if not np.isfinite(r).any():
        return float("nan")
    if near is None:
        i = int(np.nanargmax(r))
    else:
        inner = r[1:-1]
        with np.errstate(invalid="ignore"):
            top = np.flatnonzero((inner >= r[:-2]) & (inner >= r[2:]) & np.isfinite(inner)) + 1
        if top.size == 0:
            return float("nan")
        i = int(top[np.argmin(np.abs(top - near))])
    if i == 0 or i == r.size - 1 or not np.all(np.isfinite(r[i - 1 : i + 2])):
        return float("nan")
    a, b, c = r[i - 1], r[i], r[i + 1]
    den = a - 2 * b + c
    return float(i + (0.5 * (a - c) / den if den < 0 else 0.0))


def follow_ridge(r: np.ndarray, start: int) -> tuple[np.ndarray, np.ndarray]:
    """The ridge of a space-time correlation ``r`` (lag, offset), followed from the index
    ``start`` at lag 0: at each lag the local maximum nearest to where the ridge's last step
    points (so a far lobe of a quasi-periodic pattern is not taken for it), while it stands at
    :data:`MIN_PEAK` or more. Returns the sub-sample indices and the values (NaN from the
    first lag it is lost on).

    Raises
    ------
    InvalidInputError
        ``r`` not 2-D, or ``start`` outside its offsets.
    """
    r = np.asarray(r, np.float64)
    if r.ndim != 2 or not 0 <= int(start) < r.shape[1]:
        raise InvalidInputError(
            f"temporal: the ridge needs a (lag, offset) array and a start inside its "
            f"{r.shape[-1] if r.ndim else 0} offsets, got shape {r.shape} and {start}"
        )
    pos = np.full(r.shape[0], np.nan)
    val = np.full(r.shape[0], np.nan)
    at, step = float(start), 0.0
    for lag in range(r.shape[0]):
        x = peak_offset(r[lag], near=at + step)
        j = int(round(x)) if np.isfinite(x) else -1
        if j < 0 or not r[lag, j] >= MIN_PEAK:
            break
        if lag:
            step = x - at
        at, pos[lag], val[lag] = x, x, r[lag, j]
    return pos, val


class TemporalAccumulator:
    """Frequency spectra and space-time correlations at reference rows of fields added in time
    order (module docstring).

    Parameters
    ----------
    mean_u, mean_v : array, shape (ny, nx)
        Each vector's mean over the run, in the fields' frame and units.
    ref_rows : sequence of int
        The reference rows (grid rows).
    usable : bool array, shape (ny, nx), optional
        Vectors that may enter; vectors whose mean is not finite never do.
    sign_x, sign_y : {1.0, -1.0}
        Orientation of ``u'`` and ``v'`` (module docstring).
    segment : int
        Fields per Welch segment (even, >= 8).
    max_lag : int
        The largest time lag of the correlations, pair intervals (>= 1).
    half_width : int, optional
        Offsets of the correlations from ``-half_width`` to ``half_width`` columns (default:
        half the row).
    min_valid : float
        The share of a column's samples in a segment that must be valid for it to enter.

    Raises
    ------
    InvalidInputError
        Arrays of different shapes, reference rows outside the grid, an odd or short segment,
        a lag under 1, a negative half width, a share outside (0, 1] or a sign other than +-1.
    """

    def __init__(
        self,
        mean_u,
        mean_v,
        ref_rows,
        *,
        usable=None,
        sign_x: float = 1.0,
        sign_y: float = 1.0,
        segment: int = 256,
        max_lag: int = 32,
        half_width: int | None = None,
        min_valid: float = 0.9,
    ):
        self.mean_u = _grid("mean_u", mean_u)
        self.shape: tuple[int, int] = self.mean_u.shape  # type: ignore[assignment]
        ny, nx = self.shape
        self.mean_v = _grid("mean_v", mean_v, self.shape)
        refs = np.asarray(ref_rows, dtype=np.int64).ravel()
        if refs.size == 0 or refs.min() < 0 or refs.max() >= ny:
            raise InvalidInputError(
                f"temporal: reference rows must lie in 0..{ny - 1}, got {refs.tolist()}"
            )
        if int(segment) < 8 or int(segment) % 2:
            raise InvalidInputError(f"temporal: segment must be even and >= 8, got {segment}")
        if int(max_lag) < 1:
            raise InvalidInputError(f"temporal: max_lag must be >= 1, got {max_lag}")
        hw = nx // 2 if half_width is None else int(half_width)
        if hw < 0:
            raise InvalidInputError(f"temporal: half_width must be >= 0, got {half_width}")
        if not 0 < min_valid <= 1:
            raise InvalidInputError(f"temporal: min_valid must lie in (0, 1], got {min_valid}")
        if sign_x not in (1.0, -1.0) or sign_y not in (1.0, -1.0):
            raise InvalidInputError(f"temporal: signs must be +1 or -1, got {sign_x}, {sign_y}")
        ok = np.isfinite(self.mean_u) & np.isfinite(self.mean_v)
        if usable is not None:
            ok &= np.asarray(usable, bool).reshape(self.shape)
        self.usable = ok
        self.sign_x, self.sign_y = float(sign_x), float(sign_y)
        self.ref_rows = refs
        self.segment, self.max_lag, self.half_width = int(segment), int(max_lag), hw
        self.min_valid = float(min_valid)
        self._nfft = nx + hw
        nr, nf, nk = refs.size, self.segment // 2 + 1, self._nfft // 2 + 1
        self._taper = hann_taper(self.segment)
        # Welch sums per reference: |U|^2, |V|^2, Re(U conj V) and the column-segments
        self.p_uu = np.zeros((nr, nf))
        self.p_vv = np.zeros((nr, nf))
        self.p_uv = np.zeros((nr, nf))
        self.segments = np.zeros(nr, np.int64)
        # space-time sums in Fourier space along the row, per reference and lag
        self.s_uu = np.zeros((nr, self.max_lag + 1, nk), complex)
        self.s_vv = np.zeros((nr, self.max_lag + 1, nk), complex)
        self.s_kk = np.zeros((nr, self.max_lag + 1, nk), complex)
        self.n_fields = 0
        self.pair_ids: set[int] = set()
        self._reset()

    def _reset(self) -> None:
        self._last: int | None = None
        self._buf: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # rows per field
        self._hist: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # transforms, newest last

    def empty_copy(self) -> TemporalAccumulator:
        """An accumulator of the same plan holding no field (for parts summed in parallel)."""
        new = object.__new__(TemporalAccumulator)
        new.__dict__.update(self.__dict__)
        for k in ("p_uu", "p_vv", "p_uv", "segments", "s_uu", "s_vv", "s_kk"):
            setattr(new, k, np.zeros_like(getattr(self, k)))
        new.n_fields = 0
        new.pair_ids = set()
        new._reset()
        return new

    def add(self, u, v, valid, *, pair_id: int) -> None:
        """Add the next field in time (``pair_id``: its place in the sequence; a gap restarts
        the segment and the lags)."""
        r = self.ref_rows
        # only the reference rows are read (a 47 MP field is not copied whole)
        u, v = (np.asarray(a) for a in (u, v))
        if u.shape != self.shape or v.shape != self.shape:
            raise InvalidInputError(
                f"temporal: u and v must be of shape {self.shape}, got {u.shape}, {v.shape}"
            )
        u, v = u[r].astype(np.float64), v[r].astype(np.float64)
        pid = int(pair_id)
        if self._last is not None and pid != self._last + 1:
            self._reset()
        self._last = pid
        ok = np.asarray(valid, bool).reshape(self.shape)[r] & self.usable[r]
        ok &= np.isfinite(u) & np.isfinite(v)
        uf = np.where(ok, self.sign_x * (u - self.mean_u[r]), 0.0)
        vf = np.where(ok, self.sign_y * (v - self.mean_v[r]), 0.0)
        # the space-time sums against every earlier field within max_lag
        n = self._nfft
        now = (np.fft.rfft(uf, n, axis=1), np.fft.rfft(vf, n, axis=1),
               np.fft.rfft(ok.astype(np.float64), n, axis=1))  # fmt: skip
        self._hist.append(now)
        if len(self._hist) > self.max_lag + 1:
            self._hist.pop(0)
        for lag, old in enumerate(reversed(self._hist)):
            for acc, a, b in ((self.s_uu, now[0], old[0]), (self.s_vv, now[1], old[1]),
                              (self.s_kk, now[2], old[2])):  # fmt: skip
                acc[:, lag] += a * np.conj(b)
        # the Welch segments
        self._buf.append((uf, vf, ok))
        if len(self._buf) == self.segment:
            self._segment()
            del self._buf[: self.segment // 2]
        self.n_fields += 1
        self.pair_ids.add(pid)

    def _segment(self) -> None:
        us = np.stack([b[0] for b in self._buf], axis=-1)  # (ref, column, time)
        vs = np.stack([b[1] for b in self._buf], axis=-1)
        ks = np.stack([b[2] for b in self._buf], axis=-1)
        count = ks.sum(-1)
        enter = count >= self.min_valid * self.segment
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = np.where(enter, us.sum(-1) / count, 0.0)[..., None]
            mv = np.where(enter, vs.sum(-1) / count, 0.0)[..., None]
        # detrended by the segment's mean; missing samples at that mean (no power)
        a = np.fft.rfft(np.where(ks, us - mu, 0.0) * self._taper, axis=-1)
        b = np.fft.rfft(np.where(ks, vs - mv, 0.0) * self._taper, axis=-1)
        w = enter[..., None]
        self.p_uu += np.where(w, np.abs(a) ** 2, 0.0).sum(1)
        self.p_vv += np.where(w, np.abs(b) ** 2, 0.0).sum(1)
        self.p_uv += np.where(w, (a * np.conj(b)).real, 0.0).sum(1)
        self.segments += enter.sum(1)

    def merge(self, other: TemporalAccumulator) -> None:
        """Add another accumulator of the same plan (a part summed in parallel)."""
        if (
            other.shape != self.shape
            or not np.array_equal(other.ref_rows, self.ref_rows)
            or (other.segment, other.max_lag, other.half_width)
            != (self.segment, self.max_lag, self.half_width)
        ):
            raise InvalidInputError("temporal: cannot merge accumulators of other plans")
        for k in ("p_uu", "p_vv", "p_uv", "segments", "s_uu", "s_vv", "s_kk"):
            getattr(self, k).__iadd__(getattr(other, k))
        self.n_fields += other.n_fields
        self.pair_ids |= other.pair_ids

    def results(self) -> dict[str, np.ndarray]:
        """The spectra, correlations and convection velocities (module docstring).

        Returns
        -------
        dict
            ``f`` (cycles per pair interval); ``phi_uu``, ``phi_vv``, ``phi_uv`` (ref, f),
            per cycle per pair interval (NaN for a reference without segments);
            ``segments`` (ref): the column-segments averaged; ``lag`` (pair intervals),
            ``offsets`` (grid columns); ``R_uu``, ``R_vv`` (ref, lag, offset) and ``pairs``
            (ref, lag, offset): the products summed; ``var_u``, ``var_v`` (ref): the
            variances at lag 0; ``peak`` (ref, lag): ``R_uu`` on the ridge at each lag;
            ``shift`` (ref, lag): the ridge's offset (columns, sub-sample; NaN from the lag
            where it falls under :data:`MIN_PEAK` or reaches the offsets' ends); ``ref_rows``.
        """
        m = self.segment
        norm = one_sided_density(m)
        seg = np.maximum(self.segments, 1)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            out: dict[str, np.ndarray] = {
                "f": np.arange(m // 2 + 1) / m,
                "phi_uu": np.where(self.segments[:, None] > 0, self.p_uu * norm / seg, np.nan),
                "phi_vv": np.where(self.segments[:, None] > 0, self.p_vv * norm / seg, np.nan),
                "phi_uv": np.where(self.segments[:, None] > 0, self.p_uv * norm / seg, np.nan),
                "segments": self.segments.copy(),
            }
        n, hw = self._nfft, self.half_width
        cols = np.arange(-hw, hw + 1)
        idx = cols % n

        def spatial(s):
            return np.fft.irfft(s, n, axis=-1)[..., idx]

        pairs = np.rint(spatial(self.s_kk)).astype(np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            cuu = np.where(pairs > 0, spatial(self.s_uu) / pairs, np.nan)
            cvv = np.where(pairs > 0, spatial(self.s_vv) / pairs, np.nan)
            var_u, var_v = cuu[:, 0, hw], cvv[:, 0, hw]
            r_uu = cuu / var_u[:, None, None]
            r_vv = cvv / var_v[:, None, None]
        ridges = [follow_ridge(r_uu[i], hw) for i in range(r_uu.shape[0])]
        shift = np.array([pos for pos, _ in ridges]) - hw
        peak = np.array([val for _, val in ridges])
        out.update(
            lag=np.arange(self.max_lag + 1),
            offsets=cols,
            R_uu=r_uu,
            R_vv=r_vv,
            pairs=pairs,
            var_u=var_u,
            var_v=var_v,
            peak=peak,
            shift=shift,
            ref_rows=self.ref_rows.copy(),
        )
        return out
