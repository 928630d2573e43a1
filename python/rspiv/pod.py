"""Proper orthogonal decomposition of PIV fields: the snapshot method (Sirovich 1987).

The fluctuating fields of ``n`` pairs, ``x_i = (u'_i, v'_i)`` over the ``D`` vectors of a
domain, are decomposed into orthonormal spatial modes ``phi_k`` and their coefficients ``c_ik``,
``x_i = sum_k c_ik phi_k``, ordered by energy. The snapshot method builds the ``n x n`` matrix of
inner products ``K_ij = x_i . x_j`` (the work is ``n^2 D``; its memory ``n^2``, not ``D^2``),
solves ``(K / n) a_k = lambda_k a_k`` and forms ``phi_k = sum_i a_ik x_i / sqrt(n lambda_k)``,
``c_ik = sqrt(n lambda_k) a_ik``.

Conventions
    ``lambda_k`` (``energy``) is the mean over the snapshots of ``c_ik^2``: the mode's share of
    ``<|x|^2>``, the fluctuation energy summed over the domain's vectors (twice the turbulent
    kinetic energy of the in-plane components, summed), in the fields' velocity units squared
    (px^2 per pair^2, or m^2/s^2). ``total`` is ``<|x|^2>`` itself, the sum of every eigenvalue,
    so ``fraction = lambda_k / total``. The modes are unit vectors over the domain
    (``sum phi_u^2 + phi_v^2 = 1``), NaN outside it; a mode's sign is chosen so that its largest
    value is positive (the coefficients carry the other sign).
    The fluctuation of each vector is about the mean given (a campaign's: its statistics over
    every pair, so the decomposition is exact, not about a pilot's mean), or the mean of the
    snapshots' valid samples.

Gaps
    A vector rejected in a snapshot is filled with zero fluctuation (its mean). That removes
    its energy: the eigenvalues read low by about the filled share (``gaps``); modes whose
    structures sit where the gaps are also change shape. Gappy POD (Everson & Sirovich 1995)
    iterates the fill from the leading modes; rspiv does not.

Sampling error
    ``north`` is North et al.'s (1982) rule of thumb for an eigenvalue's standard error,
    ``lambda_k sqrt(2 / n_eff)`` with ``n_eff`` independent snapshots. Two modes whose
    eigenvalues differ by less than it are not separated (``separated`` False): any rotation
    of the pair fits the sample as well, so their shapes and coefficients are one sample's
    mixture and must be read together. Consecutive pairs of a time-resolved recording are not
    independent; pass ``n_eff`` from the statistics' lag-1 correlation
    (:meth:`rspiv.stats.FieldAccumulator.n_eff`).

The decomposition is built by :class:`PodBuilder` from blocks of rows, so a campaign streams
it over its field files (:mod:`rspiv.campaign.pod`); :func:`pod` is the in-memory call.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["PodBuilder", "PodResult", "domain_fluctuations", "fields_in_memory", "pod"]


@dataclasses.dataclass
class PodResult:
    """A snapshot POD (module docstring for the conventions).

    Attributes
    ----------
    energy : ndarray, (k,)
        Eigenvalues ``lambda_k``, decreasing (velocity units squared, summed over the domain).
    total : float
        ``<|x|^2>``, the sum of all ``n`` eigenvalues.
    modes_u, modes_v : ndarray, (k, ny, nx)
        The modes' components, unit norm over the domain, NaN outside it.
    coefficients : ndarray, (n, k)
        ``c_ik``; their mean square over the snapshots is ``energy``.
    pair_ids : ndarray, (n,)
        The snapshots' pair ids, in the order of the coefficients' rows.
    domain : ndarray of bool, (ny, nx)
        The vectors decomposed.
    gaps : float
        The share of the domain's samples (vectors x snapshots) filled with zero fluctuation.
    n_eff : float
        The independent snapshots the sampling error assumes.
    next_energy : float
        The eigenvalue of the first mode not kept (0 when every mode is kept), against which
        the last mode kept is judged separated.
    """

    energy: np.ndarray
    total: float
    modes_u: np.ndarray
    modes_v: np.ndarray
    coefficients: np.ndarray
    pair_ids: np.ndarray
    domain: np.ndarray
    gaps: float
    n_eff: float
    next_energy: float = 0.0

    @property
    def n_modes(self) -> int:
        return int(self.energy.size)

    @property
    def fraction(self) -> np.ndarray:
        """Each mode's share of the fluctuation energy."""
        return self.energy / self.total if self.total > 0 else np.full_like(self.energy, np.nan)

    @property
    def cumulative(self) -> np.ndarray:
        """The share of the first ``k`` modes together."""
        return np.cumsum(self.fraction)

    @property
    def north(self) -> np.ndarray:
        """North's standard error of each eigenvalue, ``lambda sqrt(2 / n_eff)``."""
        return self.energy * np.sqrt(2.0 / max(self.n_eff, 1.0))

    @property
    def separated(self) -> np.ndarray:
        """Modes whose eigenvalue is farther than its standard error from both neighbours'
        (the last mode kept is judged against the first mode not kept too)."""
        lam, err = self.energy, self.north
        d = -np.diff(np.append(lam, self.next_energy))  # gap to the next one down
        gap = d.copy()
        gap[1:] = np.minimum(gap[1:], d[:-1])
        if self.next_energy == 0 and lam.size:  # every mode kept: the last has no lower one
            gap[-1] = d[-2] if lam.size > 1 else np.inf
        return gap > err

    def reconstruct(self, index: int, modes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Snapshot ``index``'s fluctuation ``(u', v')`` from its first ``modes`` modes (all
        kept by default); NaN outside the domain."""
        k = self.n_modes if modes is None else int(modes)
        if not 0 < k <= self.n_modes:
            raise InvalidInputError(f"modes must be 1 to {self.n_modes}, got {modes}")
        c = self.coefficients[index, :k]
        return (
            np.tensordot(c, self.modes_u[:k], axes=1),
            np.tensordot(c, self.modes_v[:k], axes=1),
        )


def fields_in_memory(who: str, u, v, valid, mean_u, mean_v) -> tuple[np.ndarray, ...]:
    """Fields held in memory, checked: ``u``, ``v`` (float64, ``(n, ny, nx)``), the mask of
    their valid samples (finite, and ``valid`` where given), and the means about which the
    fluctuations are taken (the valid samples' where ``mean_u`` or ``mean_v`` is None).
    ``who`` names the caller in the refusals."""
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    if u.ndim != 3 or v.shape != u.shape:
        raise InvalidInputError(
            f"{who}: u and v must be (n, ny, nx) of one shape, got {u.shape}, {v.shape}"
        )
    ok = np.isfinite(u) & np.isfinite(v)
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != u.shape:
            raise InvalidInputError(f"{who}: valid must be {u.shape}, got {valid.shape}")
        ok &= valid
    if mean_u is None or mean_v is None:
        cnt = ok.sum(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_u = np.where(ok, u, 0.0).sum(0) / cnt
            mean_v = np.where(ok, v, 0.0).sum(0) / cnt
    return u, v, ok, mean_u, mean_v


def domain_fluctuations(
    domain: np.ndarray, mean_u: np.ndarray, mean_v: np.ndarray, rows: slice, u, v, valid
) -> tuple[np.ndarray, int, int]:
    """``(m, 2 d)`` fluctuations of ``m`` snapshots at the ``d`` vectors of ``domain`` in
    ``rows`` (``u'`` of every vector, then ``v'``; a rejected or non-finite vector is 0, its
    mean), the samples so filled and the samples counted. ``u``, ``v``, ``valid``: ``(m,
    rows, nx)``; ``domain``, ``mean_u``, ``mean_v``: the whole grid's."""
    u, v = np.asarray(u), np.asarray(v)
    dom = domain[rows]
    if u.shape[1:] != dom.shape or v.shape != u.shape:
        raise InvalidInputError(
            f"a block of rows {rows.start}:{rows.stop} must be (snapshots, {dom.shape[0]}, "
            f"{dom.shape[1]}), got {u.shape} and {v.shape}"
        )
    m = u.shape[0]
    idx: np.ndarray | slice = np.flatnonzero(dom)
    d = idx.size
    if d and idx[-1] - idx[0] == d - 1:  # one run of vectors (whole rows): no gather
        idx = slice(int(idx[0]), int(idx[-1]) + 1)
    x = np.empty((m, 2 * d))
    xu, xv = x[:, :d], x[:, d:]
    xu[...] = u.reshape(m, -1)[:, idx]
    xv[...] = v.reshape(m, -1)[:, idx]
    xu -= mean_u[rows].ravel()[idx]
    xv -= mean_v[rows].ravel()[idx]
    bad = ~(np.isfinite(xu) & np.isfinite(xv))
    if valid is not None:
        bad |= ~np.asarray(valid, bool).reshape(m, -1)[:, idx]
    np.copyto(xu, 0.0, where=bad)
    np.copyto(xv, 0.0, where=bad)
    return x, int(np.count_nonzero(bad)), bad.size


class PodBuilder:
    """A snapshot POD built from blocks of rows, then the modes from whole snapshots.

    1. :meth:`add_rows` for every block of rows (each block holding every snapshot's rows
       there, in the snapshots' order): the inner products ``K`` are summed block by block.
    2. :meth:`solve`: the eigenvalues and the coefficients.
    3. :meth:`add_snapshot` for every snapshot: its share of each mode.
    4. :meth:`result`.

    Parameters
    ----------
    mean_u, mean_v : array_like, (ny, nx)
        Each vector's mean, about which the fluctuations are taken.
    domain : array_like of bool, (ny, nx)
        The vectors decomposed (finite means required there).
    n_snapshots : int
        The snapshots that will be added (>= 2).
    sign_x, sign_y : float
        +-1: the components' signs in the result (a campaign's flow frame).
    """

    def __init__(self, mean_u, mean_v, domain, n_snapshots: int, sign_x=1.0, sign_y=1.0):
        self.mean_u = np.asarray(mean_u, np.float64)
        self.mean_v = np.asarray(mean_v, np.float64)
        self.shape = self.mean_u.shape
        dom = np.asarray(domain, bool)
        if self.mean_v.shape != self.shape or dom.shape != self.shape or len(self.shape) != 2:
            raise InvalidInputError(
                f"mean_u, mean_v and domain must be 2-D of one shape, got {self.mean_u.shape}, "
                f"{self.mean_v.shape}, {dom.shape}"
            )
        self.n = int(n_snapshots)
        if self.n < 2:
            raise InvalidInputError(f"a POD needs at least 2 snapshots, got {self.n}")
        self.domain = dom & np.isfinite(self.mean_u) & np.isfinite(self.mean_v)
        if not self.domain.any():
            raise InvalidInputError("the POD domain holds no vector with a finite mean")
        self.signs = (float(sign_x), float(sign_y))
        self.gram = np.zeros((self.n, self.n))
        self.filled = 0
        self.samples = 0
        self._rows_done = np.zeros(self.shape[0], bool)
        self._a: np.ndarray | None = None
        self._lam: np.ndarray | None = None
        self._modes: np.ndarray | None = None
        self._added: np.ndarray | None = None

    def _fluct(self, rows: slice, u, v, valid) -> tuple[np.ndarray, int, int]:
        return domain_fluctuations(self.domain, self.mean_u, self.mean_v, rows, u, v, valid)

    def add_rows(self, rows: slice, u, v, valid=None) -> None:
        """Add every snapshot's rows ``rows`` (``u``, ``v``, ``valid``: ``(n, rows, nx)``,
        the snapshots in their final order; rejected vectors invalid or non-finite)."""
        if self._a is not None:
            raise InvalidInputError("rows added after solve()")
        rows = slice(*rows.indices(self.shape[0])[:2])
        if np.shape(u)[0] != self.n:
            raise InvalidInputError(f"a block must hold all {self.n} snapshots, got {len(u)}")
        if self._rows_done[rows].any():
            raise InvalidInputError(f"rows {rows.start}:{rows.stop} were already added")
        self._rows_done[rows] = True
        x, gaps, total = self._fluct(rows, u, v, valid)
        self.filled += gaps
        self.samples += total
        if x.shape[1]:
            self.gram += x @ x.T

    def solve(self, n_modes: int, n_eff: float | None = None) -> None:
        """The eigenvalues and coefficients of the first ``n_modes`` modes (fewer when the
        snapshots span fewer: eigenvalues under 1e-12 of the total are dropped). ``n_eff``:
        the independent snapshots the sampling error assumes (default all)."""
        missing = self.domain.any(axis=1) & ~self._rows_done
        if missing.any():
            raise InvalidInputError(
                f"{int(missing.sum())} rows of the domain were not added (first: row "
                f"{int(np.flatnonzero(missing)[0])})"
            )
        if n_modes < 1:
            raise InvalidInputError(f"n_modes must be >= 1, got {n_modes}")
        lam, a = np.linalg.eigh(self.gram / self.n)
        order = np.argsort(lam)[::-1]
        lam, a = lam[order], a[:, order]
        self.total = float(np.trace(self.gram) / self.n)
        keep = min(int(n_modes), int(np.count_nonzero(lam > 1e-12 * max(self.total, 1e-300))))
        if keep == 0:
            raise InvalidInputError("the snapshots hold no fluctuation about the mean")
        self._lam, self._a = lam[:keep], a[:, :keep]
        rest = lam[keep:]
        self._next = float(rest[0]) if rest.size and rest[0] > 1e-12 * self.total else 0.0
        self.n_eff = float(self.n if n_eff is None else min(max(n_eff, 1.0), self.n))
        d = int(self.domain.sum())
        self._modes = np.zeros((keep, 2 * d))
        self._added = np.zeros(self.n, bool)
        # snapshots wait in a buffer of about 64 MB, added to the modes by one product
        self._buf = np.empty((max(1, min(self.n, (64 << 20) // (16 * d + 1))), 2 * d))
        self._buf_ids: list[int] = []

    def add_snapshot(self, index: int, u, v, valid=None) -> None:
        """Add snapshot ``index`` (its whole ``(ny, nx)`` field) to the modes."""
        if self._a is None:
            raise InvalidInputError("add_snapshot() before solve()")
        if self._added[index]:
            raise InvalidInputError(f"snapshot {index} was already added to the modes")
        self._added[index] = True
        x, _, _ = self._fluct(slice(0, self.shape[0]), np.asarray(u)[None], np.asarray(v)[None],
                              None if valid is None else np.asarray(valid)[None])  # fmt: skip
        self._buf[len(self._buf_ids)] = x[0]
        self._buf_ids.append(index)
        if len(self._buf_ids) == len(self._buf):
            self._flush()

    def _flush(self) -> None:
        """Add the buffered snapshots to the modes."""
        if self._buf_ids:
            w = self._a[self._buf_ids] / np.sqrt(self.n * self._lam)
            self._modes += w.T @ self._buf[: len(self._buf_ids)]
            self._buf_ids = []

    def result(self, pair_ids=None) -> PodResult:
        """The decomposition, after every snapshot was added to the modes."""
        if self._a is None or not self._added.all():
            raise InvalidInputError(
                "result() needs solve() and every snapshot added to the modes "
                f"({0 if self._added is None else int(self._added.sum())} of {self.n})"
            )
        self._flush()
        coef = self._a * np.sqrt(self.n * self._lam)
        modes = self._modes
        # each mode's largest value positive; the coefficients carry the sign
        big = modes[np.arange(modes.shape[0]), np.argmax(np.abs(modes), axis=1)]
        flip = np.where(big < 0, -1.0, 1.0)
        modes = modes * flip[:, None]
        coef = coef * flip[None, :]
        d = int(self.domain.sum())
        mu = np.full((modes.shape[0], *self.shape), np.nan)
        mv = np.full_like(mu, np.nan)
        mu[:, self.domain] = modes[:, :d] * self.signs[0]
        mv[:, self.domain] = modes[:, d:] * self.signs[1]
        ids = np.arange(self.n) if pair_ids is None else np.asarray(pair_ids)
        if ids.shape != (self.n,):
            raise InvalidInputError(f"pair_ids must hold {self.n} ids, got {ids.shape}")
        return PodResult(
            energy=self._lam.copy(),
            total=self.total,
            modes_u=mu,
            modes_v=mv,
            coefficients=coef,
            pair_ids=ids,
            domain=self.domain.copy(),
            gaps=self.filled / max(self.samples, 1),
            n_eff=self.n_eff,
            next_energy=self._next,
        )


def pod(
    u,
    v,
    valid=None,
    n_modes: int = 10,
    *,
    mean_u=None,
    mean_v=None,
    domain=None,
    n_eff: float | None = None,
    pair_ids=None,
) -> PodResult:
    """The snapshot POD of ``n`` fields held in memory (module docstring).

    Parameters
    ----------
    u, v : array_like, (n, ny, nx)
        The snapshots' velocity components; NaN where rejected.
    valid : array_like of bool, (n, ny, nx), optional
        False where a vector was rejected (besides NaN).
    n_modes : int
        The modes kept (fewer when the snapshots span fewer).
    mean_u, mean_v : array_like, (ny, nx), optional
        The mean about which the fluctuations are taken; default the snapshots' valid samples'.
    domain : array_like of bool, (ny, nx), optional
        The vectors decomposed; default those valid in at least 2 snapshots.
    n_eff : float, optional
        Independent snapshots, for the sampling error (default ``n``).
    pair_ids : array_like, optional
        The snapshots' ids (default ``0 .. n-1``).

    Returns
    -------
    PodResult

    Raises
    ------
    InvalidInputError
        Shapes that do not agree, fewer than 2 snapshots, an empty domain, or snapshots
        without fluctuation.
    """
    u, v, ok, mean_u, mean_v = fields_in_memory("pod", u, v, valid, mean_u, mean_v)
    if u.shape[0] < 2:
        raise InvalidInputError(f"a POD needs at least 2 snapshots, got {u.shape[0]}")
    if domain is None:
        domain = ok.sum(0) >= 2
    b = PodBuilder(mean_u, mean_v, domain, u.shape[0])
    b.add_rows(slice(0, u.shape[1]), u, v, ok)
    b.solve(n_modes, n_eff)
    for i in range(u.shape[0]):
        b.add_snapshot(i, u[i], v[i], ok[i])
    return b.result(pair_ids)
