"""Spectral proper orthogonal decomposition (SPOD) of a time-resolved recording.

A snapshot POD (:mod:`rspiv.pod`) orders structures by energy alone; a structure that convects
past the camera is spread over many of its modes, each a mixture of time scales. SPOD (Lumley
1970; Towne, Schmidt & Colonius 2018, J. Fluid Mech. 847) decomposes the cross-spectral density
of the fields at each frequency instead: its modes are coherent in space *and* time, each
oscillating at one frequency, ordered by energy at that frequency.

Definition (Welch's estimate)
    The time series of the fluctuations ``x(t)`` (``u'`` then ``v'`` of every vector of a
    domain: ``D = 2 d`` values) is cut into ``K`` blocks of ``segment`` consecutive fields
    overlapping by half, each tapered by the periodic Hann window ``w`` and transformed,
    ``X_k(f) = sum_t w_t x_k(t) exp(-2 pi i f t)``. The one-sided cross-spectral density is
    ``S(f) = c(f) / K sum_k X_k(f) X_k(f)^H`` with ``c(f)`` the density factor of
    :func:`rspiv.temporal.one_sided_density` (the frequency spectra's scaling, so that ``sum_f
    trace S(f) / segment`` is the fluctuation energy the taper passes). Its eigenvalues
    ``lambda_j(f)`` (``energy``, decreasing) and unit eigenvectors ``phi_j(f)`` (``modes``,
    complex) are found from the ``K x K`` matrix ``X^H X`` (the snapshot method: memory ``K^2``
    per frequency, not ``D^2``). ``total(f) = trace S(f)`` is every eigenvalue summed.

Conventions and units
    Fields in their own units (px per pair in a campaign); time in pair intervals, so ``f`` is
    in cycles per pair interval (0 to 0.5) and ``energy`` in (field units)^2 per cycle per pair
    interval, summed over the domain's vectors. A campaign converts to Hz and (m/s)^2/Hz
    (:mod:`rspiv.campaign.spod`). The fluctuations are about each vector's mean (a campaign's:
    its statistics over every pair), ``u' = sign_x (u - U)``, ``v' = sign_y (v - V)``. A mode
    is a unit vector over the domain (``sum |phi_u|^2 + |phi_v|^2 = 1``), NaN outside it; its
    phase is arbitrary, and chosen so that its largest value is real and positive. The real
    part of ``phi exp(2 pi i f t)`` is the structure at time ``t``; a structure convecting at
    ``c`` has a phase that falls by ``2 pi f dx / c`` over ``dx`` downstream.

Series and gaps
    Blocks never straddle a gap in the pair ids (a pair left out or not processed): each unbroken
    series gives its own blocks. A vector rejected in a field is filled with zero fluctuation,
    its mean (``gaps``: the share so filled); the eigenvalues read low by about that share.

Sampling error
    For Gaussian data an eigenvalue's estimate is ``lambda chi^2_nu / nu``; ``nu`` is ``2 K``
    for independent blocks (``K`` at 0 and at the Nyquist frequency, whose transforms are
    real). Half-overlapping Hann blocks are not independent: ``nu = 2 K^2 / (K + 2 n r)``, with
    ``n`` the adjacent overlapping blocks and ``r = 1/36`` the correlation of their
    periodograms (Welch 1967: the square of the taper's overlap correlation, 1/6 for Hann at
    half overlap; exact for white noise). :meth:`SpodResult.interval` gives the two-sided
    interval (Schmidt & Colonius 2020, AIAA J. 58). It holds for the leading eigenvalue and the
    trace; the lower eigenvalues of a few blocks are biased apart (the sample's own spread).

The decomposition is built by :class:`SpodBuilder` from slices of the domain's values over the
whole series, so a campaign streams it (:mod:`rspiv.campaign.spod`); :func:`spod` is the
in-memory call.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.pod import domain_fluctuations, fields_in_memory
from rspiv.temporal import consecutive_runs, hann_taper, one_sided_density

__all__ = ["SpodBuilder", "SpodResult", "spod"]

#: Correlation of the periodograms of two half-overlapping periodic-Hann blocks (white noise):
#: ``(sum_{t < m/2} w_t w_{t + m/2} / sum w_t^2)^2 = (1/6)^2``.
OVERLAP_CORRELATION = 1.0 / 36.0


@dataclasses.dataclass
class SpodResult:
    """An SPOD (module docstring for the conventions).

    Attributes
    ----------
    f : ndarray, (nf,)
        Frequencies, cycles per pair interval (0 to 0.5).
    energy : ndarray, (nf, K)
        The eigenvalues ``lambda_j(f)``, decreasing along the second axis (field units squared
        per cycle per pair interval, summed over the domain).
    mode_f : ndarray of int, (nm,)
        The indices into ``f`` of the frequencies whose modes are kept.
    modes_u, modes_v : ndarray of complex, (nm, n_modes, ny, nx)
        The leading modes at those frequencies; unit norm over the domain, NaN outside it.
    blocks : int
        ``K``, the blocks averaged.
    nu : ndarray, (nf,)
        The eigenvalues' degrees of freedom (module docstring).
    segment : int
        Fields per block.
    series : list of int
        The lengths of the unbroken series of pairs.
    domain : ndarray of bool, (ny, nx)
        The vectors decomposed.
    gaps : float
        The share of the domain's samples filled with zero fluctuation.
    """

    f: np.ndarray
    energy: np.ndarray
    mode_f: np.ndarray
    modes_u: np.ndarray
    modes_v: np.ndarray
    blocks: int
    nu: np.ndarray
    segment: int
    series: list
    domain: np.ndarray
    gaps: float

    @property
    def total(self) -> np.ndarray:
        """``trace S(f)``: every eigenvalue at each frequency summed, (nf,)."""
        return self.energy.sum(axis=1)

    @property
    def fraction(self) -> np.ndarray:
        """Each eigenvalue's share of its frequency's total, (nf, K); the leading mode's share
        is the spectrum's low rank (1: one structure; ``1 / K``: none stands out)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.energy / self.total[:, None]

    def interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """The two-sided ``level`` interval of every eigenvalue, ``(low, high)``, each (nf, K)
        (chi-squared with ``nu`` degrees of freedom, module docstring)."""
        from scipy.stats import chi2  # deferred: scipy's stats import is slow

        if not 0 < level < 1:
            raise InvalidInputError(f"level must lie in (0, 1), got {level}")
        nu = self.nu[:, None]
        a = (1 - level) / 2
        return self.energy * nu / chi2.ppf(1 - a, nu), self.energy * nu / chi2.ppf(a, nu)


class SpodBuilder:
    """An SPOD built from slices of the domain's values over the whole series.

    1. :meth:`fluctuations` turns fields into rows of ``x`` (``(n, D)``: each field's ``u'``
       then ``v'`` over the domain), in time order; the caller holds the ``(n_t, D)`` series
       (in memory or on disk).
    2. :meth:`add_columns` for every slice of ``D``: the blocks' transforms and their inner
       products are summed slice by slice.
    3. :meth:`solve`: the eigenvalues, and the frequencies whose modes are kept.
    4. :meth:`add_mode_columns` for every slice again: the modes' values there.
    5. :meth:`result`.

    Parameters
    ----------
    mean_u, mean_v : array_like, (ny, nx)
        Each vector's mean, about which the fluctuations are taken.
    domain : array_like of bool, (ny, nx)
        The vectors decomposed (finite means required there).
    pair_ids : array_like of int
        The fields' pair ids, increasing, in the order of ``x``'s rows; a gap ends a series.
    segment : int
        Fields per block (even, >= 4).
    sign_x, sign_y : float
        +-1: the components' signs in the modes (a campaign's flow frame).
    """

    def __init__(self, mean_u, mean_v, domain, pair_ids, segment: int = 256,
                 sign_x: float = 1.0, sign_y: float = 1.0):  # fmt: skip
        self.mean_u = np.asarray(mean_u, np.float64)
        self.mean_v = np.asarray(mean_v, np.float64)
        self.shape = self.mean_u.shape
        dom = np.asarray(domain, bool)
        if self.mean_v.shape != self.shape or dom.shape != self.shape or len(self.shape) != 2:
            raise InvalidInputError(
                f"spod: mean_u, mean_v and domain must be 2-D of one shape, got "
                f"{self.mean_u.shape}, {self.mean_v.shape}, {dom.shape}"
            )
        self.domain = dom & np.isfinite(self.mean_u) & np.isfinite(self.mean_v)
        if not self.domain.any():
            raise InvalidInputError("spod: the domain holds no vector with a finite mean")
        if abs(sign_x) != 1 or abs(sign_y) != 1:
            raise InvalidInputError(f"spod: signs must be +1 or -1, got {sign_x}, {sign_y}")
        self.signs = (float(sign_x), float(sign_y))
        if int(segment) != segment or segment < 4 or segment % 2:
            raise InvalidInputError(f"spod: segment must be an even integer >= 4, got {segment}")
        self.segment = m = int(segment)
        ids = np.asarray(pair_ids)
        if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
            raise InvalidInputError(f"spod: pair_ids must be 1-D integers, got {ids.dtype}")
        if ids.size > 1 and np.any(np.diff(ids) <= 0):
            raise InvalidInputError("spod: pair_ids must increase (the fields in time order)")
        self.n_t = int(ids.size)
        self.series = consecutive_runs(ids)
        starts, adjacent, pos = [], 0, 0
        for length in self.series:
            here = list(range(pos, pos + length - m + 1, m // 2))
            starts += here
            adjacent += max(len(here) - 1, 0)
            pos += length
        if len(starts) < 2:
            raise InvalidInputError(
                f"spod: {len(starts)} block(s) of {m} consecutive pairs (segment): at least 2 "
                f"are needed (the longest unbroken series holds {max(self.series, default=0)})"
            )
        self.starts = np.asarray(starts)
        k = len(starts)
        nf = m // 2 + 1
        nu = 2.0 * k * k / (k + 2 * adjacent * OVERLAP_CORRELATION)
        self.nu = np.full(nf, nu)
        self.nu[[0, -1]] = nu / 2  # real transforms: one degree of freedom per block
        self.d = int(self.domain.sum())
        self._taper = hann_taper(m)
        self._norm = one_sided_density(m) / k
        self.gram = np.zeros((nf, k, k), complex)
        self._done = np.zeros(2 * self.d, bool)
        self.filled = 0
        self.samples = 0
        self._count = threading.Lock()  # fields may be turned into rows from several threads
        self._lam: np.ndarray | None = None
        self._theta: np.ndarray | None = None
        self._mode_done: np.ndarray | None = None

    @property
    def n_values(self) -> int:
        """``D``: the domain's values per field (``u'`` and ``v'`` of every vector)."""
        return 2 * self.d

    @property
    def blocks(self) -> int:
        return int(self.starts.size)

    def fluctuations(self, u, v, valid=None) -> np.ndarray:
        """Rows of ``x`` for fields ``u``, ``v``, ``valid`` (``(n, ny, nx)`` or one ``(ny,
        nx)`` field: ``(n, D)`` or ``(D,)``); counts the samples filled (``gaps``)."""
        one = np.ndim(u) == 2
        if one:
            u, v = np.asarray(u)[None], np.asarray(v)[None]
            valid = None if valid is None else np.asarray(valid)[None]
        x, filled, total = domain_fluctuations(
            self.domain, self.mean_u, self.mean_v, slice(0, self.shape[0]), u, v, valid
        )
        with self._count:
            self.filled += filled
            self.samples += total
        return x[0] if one else x

    def _cols(self, cols: slice, x) -> tuple[slice, np.ndarray]:
        cols = slice(*cols.indices(self.n_values)[:2])
        x = np.asarray(x)
        if x.shape != (self.n_t, cols.stop - cols.start):
            raise InvalidInputError(
                f"spod: columns {cols.start}:{cols.stop} must be ({self.n_t}, "
                f"{cols.stop - cols.start}), got {x.shape}"
            )
        return cols, x

    def _transform(self, x: np.ndarray, freqs=None) -> np.ndarray:
        """The blocks' tapered transforms of ``x`` (``(n_t, c)``): ``(nf, K, c)``, or only the
        frequencies ``freqs``."""
        from scipy import fft  # deferred: only a decomposition needs it

        m = self.segment
        seg = np.empty((self.blocks, m, x.shape[1]))
        for b, s in enumerate(self.starts):
            np.multiply(x[s : s + m], self._taper[:, None], out=seg[b])
        q = fft.rfft(seg, axis=1, workers=-1)
        if freqs is not None:
            q = q[:, freqs]
        return np.ascontiguousarray(q.transpose(1, 0, 2))

    def add_columns(self, cols: slice, x) -> None:
        """Add the domain's values ``cols`` over the whole series (``x``: ``(n_t, c)``, rows in
        ``pair_ids`` order)."""
        if self._lam is not None:
            raise InvalidInputError("spod: columns added after solve()")
        cols, x = self._cols(cols, x)
        if self._done[cols].any():
            raise InvalidInputError(f"spod: columns {cols.start}:{cols.stop} were already added")
        self._done[cols] = True
        if x.shape[1]:
            q = self._transform(np.asarray(x, np.float64))
            self.gram += np.conj(q) @ q.transpose(0, 2, 1)

    def solve(self, n_modes: int = 3, frequencies=None, n_frequencies: int = 6) -> None:
        """The eigenvalues at every frequency; the modes to be built are the leading
        ``n_modes`` at ``frequencies`` (indices into ``f``), by default at the
        ``n_frequencies`` non-zero frequencies where the premultiplied leading eigenvalue
        ``f lambda_1`` is largest."""
        if not self._done.all():
            raise InvalidInputError(
                f"spod: {int((~self._done).sum())} of the domain's {self.n_values} values were "
                "not added"
            )
        if n_modes < 1 or n_frequencies < 1:
            raise InvalidInputError(
                f"spod: n_modes and n_frequencies must be >= 1, got {n_modes}, {n_frequencies}"
            )
        lam, theta = np.linalg.eigh(self.gram)
        lam, theta = lam[:, ::-1], theta[:, :, ::-1]
        self._raw = np.maximum(lam, 0.0)  # eigenvalues of X^H X
        self._lam = self._raw * self._norm[:, None]
        nf = lam.shape[0]
        if frequencies is None:
            f = np.arange(nf) / self.segment
            order = np.argsort(-(f * self._lam[:, 0])[1:], kind="stable") + 1
            freqs = np.sort(order[: int(n_frequencies)])
        else:
            freqs = np.unique(np.asarray(frequencies, np.int64))
            if freqs.size == 0 or freqs[0] < 0 or freqs[-1] >= nf:
                raise InvalidInputError(
                    f"spod: frequencies must be indices 0 to {nf - 1}, got {frequencies}"
                )
        self.mode_f = freqs
        k = min(int(n_modes), self.blocks)
        self._theta = theta[freqs, :, :k]
        with np.errstate(divide="ignore"):
            # unit norm: |X theta|^2 = the eigenvalue of X^H X; none (inf) where it is 0
            self._scale = 1.0 / np.sqrt(self._raw[freqs, :k])
        self._modes = np.zeros((freqs.size, k, self.n_values), complex)
        self._mode_done = np.zeros(self.n_values, bool)

    def add_mode_columns(self, cols: slice, x) -> None:
        """Add the domain's values ``cols`` (as in :meth:`add_columns`) to the modes."""
        if self._mode_done is None:
            raise InvalidInputError("spod: add_mode_columns() before solve()")
        cols, x = self._cols(cols, x)
        if self._mode_done[cols].any():
            raise InvalidInputError(f"spod: columns {cols.start}:{cols.stop} were already added")
        self._mode_done[cols] = True
        if x.shape[1]:
            q = self._transform(np.asarray(x, np.float64), self.mode_f)  # (nm, K, c)
            self._modes[:, :, cols] = np.einsum("fbc,fbk->fkc", q, self._theta)

    def result(self) -> SpodResult:
        """The decomposition, after every value was added to the modes."""
        if self._mode_done is None or not self._mode_done.all():
            raise InvalidInputError("spod: result() needs solve() and every value added twice")
        modes = self._modes * self._scale[:, :, None]
        modes[~np.isfinite(self._scale)] = np.nan  # a zero eigenvalue has no mode
        # the phase: the largest value real and positive
        big = np.take_along_axis(
            modes, np.argmax(np.abs(np.nan_to_num(modes)), axis=2)[:, :, None], axis=2
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            modes = modes * (np.abs(big) / big)
        nm, k = modes.shape[:2]
        mu = np.full((nm, k, *self.shape), np.nan, complex)
        mv = np.full_like(mu, np.nan)
        mu[:, :, self.domain] = modes[:, :, : self.d] * self.signs[0]
        mv[:, :, self.domain] = modes[:, :, self.d :] * self.signs[1]
        return SpodResult(
            f=np.arange(self.segment // 2 + 1) / self.segment,
            energy=self._lam.copy(),
            mode_f=self.mode_f.copy(),
            modes_u=mu,
            modes_v=mv,
            blocks=self.blocks,
            nu=self.nu.copy(),
            segment=self.segment,
            series=list(self.series),
            domain=self.domain.copy(),
            gaps=self.filled / max(self.samples, 1),
        )


def spod(
    u,
    v,
    valid=None,
    *,
    segment: int = 256,
    n_modes: int = 3,
    frequencies=None,
    n_frequencies: int = 6,
    mean_u=None,
    mean_v=None,
    domain=None,
    pair_ids=None,
) -> SpodResult:
    """The SPOD of a time series of fields held in memory (module docstring).

    Parameters
    ----------
    u, v : array_like, (n, ny, nx)
        The fields in time order, one pair interval apart; NaN where rejected.
    valid : array_like of bool, (n, ny, nx), optional
        False where a vector was rejected (besides NaN).
    segment : int
        Fields per block (even, >= 4); blocks overlap by half.
    n_modes : int
        The leading modes kept at each chosen frequency.
    frequencies : array_like of int, optional
        Indices into ``f`` whose modes are kept; default the ``n_frequencies`` non-zero
        frequencies with the largest ``f lambda_1``.
    n_frequencies : int
        See ``frequencies``.
    mean_u, mean_v : array_like, (ny, nx), optional
        The mean about which the fluctuations are taken; default the fields' valid samples'.
    domain : array_like of bool, (ny, nx), optional
        The vectors decomposed; default those valid in at least half the fields.
    pair_ids : array_like of int, optional
        The fields' pair ids, increasing (default ``0 .. n-1``); a gap ends a series.

    Returns
    -------
    SpodResult

    Raises
    ------
    InvalidInputError
        Shapes that do not agree, fewer than two blocks, an empty domain, bad indices.
    """
    u, v, ok, mean_u, mean_v = fields_in_memory("spod", u, v, valid, mean_u, mean_v)
    if domain is None:
        domain = ok.sum(0) >= max(u.shape[0] / 2, 1)
    ids = np.arange(u.shape[0]) if pair_ids is None else np.asarray(pair_ids)
    if ids.shape != (u.shape[0],):
        raise InvalidInputError(f"spod: pair_ids must hold {u.shape[0]} ids, got {ids.shape}")
    b = SpodBuilder(mean_u, mean_v, domain, ids, segment)
    x = b.fluctuations(u, v, ok)
    cols = slice(0, b.n_values)
    b.add_columns(cols, x)
    b.solve(n_modes, frequencies, n_frequencies)
    b.add_mode_columns(cols, x)
    return b.result()
