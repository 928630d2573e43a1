"""Quadrant analysis of the Reynolds shear stress and the joint PDF of (u', v'), per row of a
vector grid, summed over the fields of a campaign.

Definitions
    Each vector's fluctuation is taken about its own mean over the campaign and oriented by the
    flow: ``u' = s_x (u - U)``, ``v' = s_y (v - V)`` with ``s_x, s_y = +-1`` chosen so that u'
    is positive downstream and v' positive away from the wall (the pixel frame's y runs down;
    :func:`rspiv.campaign.analysis.analyse_run` gives both signs). ``U, V`` and the standard
    deviations ``u_rms, v_rms`` are the vector's statistics over the same fields (a first pass:
    :class:`rspiv.stats.FieldAccumulator`), so the sums here are exact sums over the fields, not
    estimates about a provisional mean.

    Quadrants (Wallace, Eckelmann & Brodkey 1972; Lu & Willmarth 1973, J. Fluid Mech. 60, 481):
    Q1 ``u' > 0, v' > 0`` (outward interaction), Q2 ``u' < 0, v' > 0`` (ejection), Q3 ``u' < 0,
    v' < 0`` (inward interaction), Q4 ``u' > 0, v' < 0`` (sweep). A zero fluctuation counts as
    positive (a set of measure zero for real data).

    Hole size H (Lu & Willmarth): an event of quadrant Q lies outside the hole when ``|u'v'| >=
    H u_rms v_rms`` with the vector's own standard deviations; H = 0 takes every event.

Per row, over the N samples (vectors of the row times the fields in which they were valid)
    ``stress[Q, H] = (1/N) sum u'v' [event in Q, outside H]`` (px^2 per pair^2, or the caller's
    units), ``fraction[Q, H] = stress[Q, H] / <u'v'>`` with ``<u'v'> = sum_Q stress[Q, 0]``
    (Q2 and Q4 positive in a boundary layer, summing to more than 1 with Q1 and Q3 negative),
    ``time_fraction[Q, H] = N[Q, H] / N``; the joint PDF of ``(u'/u_rms, v'/v_rms)`` on a
    ``bins`` x ``bins`` grid over ``[-extent, extent]^2`` (its integral is the share of samples
    inside that square).

The fluctuations are those of the measured vectors: the measurement noise (each vector's
``sigma_u``, ``sigma_v``) moves events across the quadrants' edges and raises u_rms v_rms, so
near the edges and for small H the fractions move towards those of uncorrelated noise. Parts
merge by addition (:meth:`QuadrantAccumulator.merge`); :func:`gaussian_quadrant` gives the exact
values of a jointly Gaussian (u', v') with correlation coefficient rho.
"""

from __future__ import annotations

import functools

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.grid_arrays import as_grid, entering

__all__ = ["QUADRANTS", "QuadrantAccumulator", "gaussian_quadrant"]

#: The quadrants' names, Q1..Q4 in order.
QUADRANTS = ("outward interaction", "ejection", "inward interaction", "sweep")


_grid = functools.partial(as_grid, "quadrant")  # a 2-D array of the grid, checked


class QuadrantAccumulator:
    """Quadrant sums and joint PDF per row, summed field by field (module docstring).

    Parameters
    ----------
    mean_u, mean_v : array, shape (ny, nx)
        Each vector's mean displacement over the campaign, in the fields' frame and units.
    rms_u, rms_v : array, shape (ny, nx)
        Each vector's standard deviation, same units.
    usable : bool array, shape (ny, nx), optional
        Vectors that may enter (e.g. those with enough valid samples for their statistics);
        vectors whose mean or standard deviation is not finite and positive never enter.
    sign_x, sign_y : {1.0, -1.0}
        Orientation: ``u' = sign_x (u - U)`` positive downstream, ``v' = sign_y (v - V)``
        positive away from the wall.
    holes : sequence of float
        Hole sizes H, increasing, >= 0 (default 0, 1, 2, 4).
    bins, extent : int, float
        The joint PDF's grid: ``bins`` x ``bins`` cells over ``[-extent, extent]^2`` in
        standard deviations.
    batches : int
        Batches of fields for the standard error of ``<u'v'>`` (batch means: each field is
        added to the batch the caller names, contiguous runs of pairs, so that the correlation
        of neighbouring vectors and of consecutive pairs stays inside a batch).

    Raises
    ------
    InvalidInputError
        Arrays of different shapes, holes not increasing or negative, a sign other than +-1,
        fewer than 4 bins or a non-positive extent.
    """

    def __init__(
        self,
        mean_u,
        mean_v,
        rms_u,
        rms_v,
        *,
        usable=None,
        sign_x: float = 1.0,
        sign_y: float = 1.0,
        holes=(0.0, 1.0, 2.0, 4.0),
        bins: int = 64,
        extent: float = 4.0,
        batches: int = 8,
    ):
        self.mean_u = _grid("mean_u", mean_u)
        self.shape: tuple[int, int] = self.mean_u.shape  # type: ignore[assignment]
        self.mean_v = _grid("mean_v", mean_v, self.shape)
        self.rms_u = _grid("rms_u", rms_u, self.shape)
        self.rms_v = _grid("rms_v", rms_v, self.shape)
        holes = np.asarray(holes, dtype=np.float64).ravel()
        if holes.size == 0 or not np.all(np.isfinite(holes)) or holes[0] < 0 or np.any(
            np.diff(holes) <= 0
        ):
            raise InvalidInputError(
                f"quadrant: holes must be increasing numbers >= 0, got {holes.tolist()}"
            )
        if sign_x not in (1.0, -1.0) or sign_y not in (1.0, -1.0):
            raise InvalidInputError(f"quadrant: signs must be +1 or -1, got {sign_x}, {sign_y}")
        if int(bins) < 4 or not (extent > 0):
            raise InvalidInputError(f"quadrant: bins >= 4 and extent > 0, got {bins}, {extent}")
        self.usable = entering(self.mean_u, self.mean_v, self.rms_u, self.rms_v, usable)
        self.sign_x, self.sign_y = float(sign_x), float(sign_y)
        self.holes = holes
        # level edges: 0 first (every event), then the holes above 0
        self._edges = np.unique(np.concatenate([[0.0], holes]))
        self.bins, self.extent = int(bins), float(extent)
        ny = self.shape[0]
        nl = self._edges.size
        self.n_level = np.zeros((ny, 4, nl), np.int64)  # events per row, quadrant and level
        self.s_level = np.zeros((ny, 4, nl), np.float64)  # their sum of u'v'
        self.jpdf_count = np.zeros((ny, self.bins, self.bins), np.int64)  # [row, v bin, u bin]
        self.count = np.zeros(ny, np.int64)  # samples per row
        self.batches = max(int(batches), 1)
        self.batch_n = np.zeros((self.batches, ny), np.int64)  # samples per batch and row
        self.batch_s = np.zeros((self.batches, ny))  # their sum of u'v'
        self.n_fields = 0
        self.pair_ids: set[int] = set()

    def empty_copy(self) -> QuadrantAccumulator:
        """A new, empty accumulator about the same means, signs, holes, grid and batches (a
        part to :meth:`merge` back)."""
        return QuadrantAccumulator(
            self.mean_u, self.mean_v, self.rms_u, self.rms_v, usable=self.usable,
            sign_x=self.sign_x, sign_y=self.sign_y, holes=self.holes, bins=self.bins,
            extent=self.extent, batches=self.batches,
        )  # fmt: skip

    def add(
        self, u, v, valid=None, *, pair_id: int | None = None, batch: int = 0
    ) -> None:
        """Add one field: ``u``, ``v`` of shape (ny, nx) in the means' frame and units; NaN or
        ``valid == 0`` vectors are left out; ``batch`` (``0 <= batch < batches``) for the
        standard error.

        Raises
        ------
        InvalidInputError
            A shape other than the means', or a ``pair_id`` added before.
        """
        u = _grid("u", u, self.shape)
        v = _grid("v", v, self.shape)
        if pair_id is not None and int(pair_id) in self.pair_ids:
            raise InvalidInputError(f"quadrant: pair {pair_id} was added before")
        ok = self.usable & np.isfinite(u) & np.isfinite(v)
        if valid is not None:
            ok &= np.asarray(valid, bool).reshape(self.shape)
        rows = np.nonzero(ok)[0]
        du = self.sign_x * (u[ok] - self.mean_u[ok])
        dv = self.sign_y * (v[ok] - self.mean_v[ok])
        su, sv = self.rms_u[ok], self.rms_v[ok]
        uv = du * dv
        q = np.where(du >= 0, np.where(dv >= 0, 0, 3), np.where(dv >= 0, 1, 2))
        level = np.searchsorted(self._edges, np.abs(uv) / (su * sv), side="right") - 1
        ny, nl = self.shape[0], self._edges.size
        idx = (rows * 4 + q) * nl + level
        size = ny * 4 * nl
        self.n_level += np.bincount(idx, minlength=size).reshape(ny, 4, nl)
        self.s_level += np.bincount(idx, weights=uv, minlength=size).reshape(ny, 4, nl)
        w = 2.0 * self.extent / self.bins
        bu = np.floor((du / su + self.extent) / w)
        bv = np.floor((dv / sv + self.extent) / w)
        inside = (bu >= 0) & (bu < self.bins) & (bv >= 0) & (bv < self.bins)
        jidx = (rows[inside] * self.bins + bv[inside].astype(np.int64)) * self.bins + bu[
            inside
        ].astype(np.int64)
        self.jpdf_count += np.bincount(jidx, minlength=ny * self.bins**2).reshape(
            ny, self.bins, self.bins
        )
        per_row = np.bincount(rows, minlength=ny)
        self.count += per_row
        b = min(max(int(batch), 0), self.batches - 1)
        self.batch_n[b] += per_row
        self.batch_s[b] += np.bincount(rows, weights=uv, minlength=ny)
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def merge(self, other: QuadrantAccumulator) -> QuadrantAccumulator:
        """Add ``other``'s sums (the same means, signs, holes and grid) to this one; returns
        self.

        Raises
        ------
        InvalidInputError
            Parts about other means, signs, holes or grids, or sharing a pair.
        """
        same = (
            self.shape == other.shape
            and np.array_equal(self.holes, other.holes)
            and (self.sign_x, self.sign_y, self.bins, self.extent, self.batches)
            == (other.sign_x, other.sign_y, other.bins, other.extent, other.batches)
            and all(
                np.array_equal(getattr(self, k), getattr(other, k), equal_nan=True)
                for k in ("mean_u", "mean_v", "rms_u", "rms_v", "usable")
            )
        )
        if not same:
            raise InvalidInputError("quadrant: cannot merge parts about other means or grids")
        if self.pair_ids & other.pair_ids:
            raise InvalidInputError(
                f"quadrant: parts share pair(s) {sorted(self.pair_ids & other.pair_ids)[:5]}"
            )
        self.n_level += other.n_level
        self.s_level += other.s_level
        self.jpdf_count += other.jpdf_count
        self.count += other.count
        self.batch_n += other.batch_n
        self.batch_s += other.batch_s
        self.n_fields += other.n_fields
        self.pair_ids |= other.pair_ids
        return self

    def _batch_se(self) -> tuple[np.ndarray, np.ndarray]:
        """Standard error of each row's ``<u'v'>`` from the spread of its batch means, and the
        number of batches it rests on."""
        with np.errstate(invalid="ignore", divide="ignore"):
            means = np.where(self.batch_n > 0, self.batch_s / self.batch_n, np.nan)
            k = np.isfinite(means).sum(axis=0)
            mu = np.where(np.isfinite(means), means, 0).sum(axis=0) / k
            var = np.where(np.isfinite(means), (means - mu) ** 2, 0).sum(axis=0) / (k - 1)
            return np.where(k > 1, np.sqrt(var / k), np.nan), k

    def _at_holes(self, a: np.ndarray) -> np.ndarray:
        """Per-level sums -> sums over the events outside each hole, shape (4, nH, ny)."""
        above = np.cumsum(a[..., ::-1], axis=-1)[..., ::-1]  # level l and above
        pick = np.searchsorted(self._edges, self.holes)
        return np.moveaxis(above[..., pick], 0, -1)

    def results(self) -> dict[str, np.ndarray]:
        """Per row: ``count`` (N), ``uv`` (``<u'v'>``), ``uv_se`` (its standard error from the
        batch means, NaN with fewer than two batches) and ``uv_batches`` (the batches it rests
        on), ``stress``, ``fraction`` and
        ``time_fraction`` of shape (4, n_holes, ny) (Q1..Q4, ``holes``), ``jpdf`` (ny, bins,
        bins; [row, v', u']) with its cell centres ``centres`` (standard deviations); rows
        without samples are NaN."""
        n = self.count.astype(np.float64)
        se, k = self._batch_se()
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(n > 0, 1.0 / n, np.nan)
            stress = self._at_holes(self.s_level) * inv
            uv = self.s_level.sum(axis=(1, 2)) * inv
            w = 2.0 * self.extent / self.bins
            jpdf = self.jpdf_count * (inv / (w * w))[:, None, None]
            return {
                "count": self.count.copy(),
                "uv_se": se,
                "uv_batches": k,
                "holes": self.holes.copy(),
                "uv": uv,
                "stress": stress,
                "fraction": stress / uv,
                "time_fraction": self._at_holes(self.n_level.astype(np.float64)) * inv,
                "jpdf": jpdf,
                "centres": -self.extent + w * (np.arange(self.bins) + 0.5),
            }


def _q_pos(r: float, h: float) -> tuple[float, float]:
    """E[XY; X > 0, Y > 0, XY >= h] and P(X > 0, Y > 0, XY >= h) of a standard bivariate
    normal with correlation r (|r| < 1)."""
    from scipy.integrate import quad  # deferred: scipy is heavy to import
    from scipy.special import ndtr

    s = np.sqrt(1.0 - r * r)
    if h == 0.0:
        return (r / 4 + r * np.arcsin(r) / (2 * np.pi) + s / (2 * np.pi),
                0.25 + np.arcsin(r) / (2 * np.pi))  # fmt: skip
    phi = lambda z: np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi)  # noqa: E731

    def z(x):
        return (h / max(x, 1e-300) - r * x) / s

    # E[Y 1{Y > a} | X = x] = m (1 - Phi(z)) + s phi(z), m = r x, z = (a - m) / s
    e, _ = quad(lambda x: x * phi(x) * (r * x * ndtr(-z(x)) + s * phi(z(x))), 0, np.inf,
                epsabs=1e-13, epsrel=1e-11, limit=200)  # fmt: skip
    p, _ = quad(lambda x: phi(x) * ndtr(-z(x)), 0, np.inf, epsabs=1e-13, epsrel=1e-11, limit=200)
    return float(e), float(p)


def gaussian_quadrant(rho: float, holes=(0.0, 1.0, 2.0, 4.0)) -> dict[str, np.ndarray]:
    """The exact quadrant statistics of a jointly Gaussian ``(u', v')`` with correlation
    coefficient ``rho`` (|rho| < 1), in the module's definitions: ``stress`` (in units of
    ``u_rms v_rms``), ``fraction`` (NaN for rho = 0, where u'v' vanishes) and
    ``time_fraction``, each of shape (4, n_holes).

    H = 0 is closed form (``E[XY; X, Y > 0] = rho / 4 + rho asin(rho) / 2 pi + sqrt(1 - rho^2)
    / 2 pi``, ``P = 1/4 + asin(rho) / 2 pi``); H > 0 integrates the conditional normal over x
    (scipy's ``quad``, to about 1e-11).
    """
    rho = float(rho)
    if not abs(rho) < 1:
        raise InvalidInputError(f"gaussian_quadrant: |rho| must be < 1, got {rho}")
    holes = np.asarray(holes, np.float64).ravel()
    stress = np.empty((4, holes.size))
    tf = np.empty((4, holes.size))
    # quadrant sign patterns (a, b) of (u', v'): X' = a u', Y' = b v' are positive there
    for qi, (a, b) in enumerate(((1, 1), (-1, 1), (-1, -1), (1, -1))):
        for hi, h in enumerate(holes):
            e, p = _q_pos(a * b * rho, float(h))
            stress[qi, hi], tf[qi, hi] = a * b * e, p
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = stress / rho if rho != 0 else np.full_like(stress, np.nan)
    return {"stress": stress, "fraction": frac, "time_fraction": tf}
