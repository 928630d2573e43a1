"""Tracks binned by their distance from the wall: a mean profile and Reynolds stresses at the
wall with their standard errors, and the wall shear from the viscous sublayer.

:class:`TrackProfile` adds the tracks of each pair (:func:`rspiv.ptv.track_particles`) into
bins of ``bin_px`` px of wall distance, from the wall out to ``band_px``. A track belongs to
the bin of its midpoint's distance from the wall line, measured along the wall's normal; its
displacement is turned into the wall's frame: ``U`` along the wall (towards +x), ``V`` normal to
it, positive away from the wall (into the flow), so that ``uv`` has the sign of the physical
``u'v'`` (negative in a boundary layer). Units: px of the frames, px per pair.

Per bin: the number of tracks, the mean track distance ``h_px`` (where the bin measures), ``U``
and ``V`` there, and the stresses ``uu``, ``vv``, ``uv``, each with its standard error. The
stresses are the tracks' scatter about a straight line in ``h`` fitted within the bin (the
means' variation across the bin is not a fluctuation: in the viscous sublayer of a layer
whose viscous length is 0.5 px, ``U`` changes by 1 px across a bin of 0.5 px, which would add
0.08 px^2 to ``uu``), with ``n - 2`` degrees of freedom. They include the tracks' own error:
the variance of the two centres' errors, 0.0106 px^2 per component (0.073 px per centre) on
the generator's 2.5 px particle images at 0.02 per px^2 and 5 % noise
(``tests/test_ptv.py``), from the camera noise, the pixel-integrated images' shape and the
neighbouring images' tails. :attr:`rspiv.ptv.Tracks.sigma_u` is the camera noise's share
alone, to first order.

The standard errors treat each pair as one independent draw (cluster sampling): the tracks of
one pair in one bin are correlated along the wall by the turbulence, so ``sigma / sqrt(n)``
would be too small; instead the spread of each pair's sums about the bins' means is carried
through the ratio (the delta method on the sums of the pairs; Cochran 1977 ch. 6). This needs
the pairs to be independent of each other (a double-frame recording, or a time-resolved one
sampled further apart than the flow's integral time); a bin with tracks from fewer than two
pairs has no standard error (NaN). Estimated from a few tens of pairs, that spread is itself
uncertain, most for the stresses whose tracks' errors have long tails (one bin of 20 pairs
read its ``vv``'s error at half the independent tracks' ``vv sqrt(2 / n)``): the error given is
the larger of the two.

Pairs that follow each other in time (a time-resolved recording) are not independent draws: as
the PIV profile's rows do (:mod:`rspiv.row_errors`), each bin keeps the products of its pairs'
ten single-track sums with those of the pairs up to :data:`rspiv.row_errors.LAGS` ids before it
(the ids :meth:`TrackProfile.add` is given, else the order of the calls), and the variances of
``U``, ``V``, ``uu``, ``vv``, ``uv`` take the factor of their residuals' autocovariances
(:func:`rspiv.row_errors.lag_factor`: Geyer's initial monotone sequence, neighbouring bins
averaged; the two-track stresses take their single-track stress's); ``serial_U`` ... per bin,
and ``open_U`` where the lags followed span fewer than five correlation times (the errors are
then lower bounds). Profiles pickled before the lags: no factor.

**Two-track stresses** (``uu_two``, ``vv_two``, ``uv_two``): from the products of the residuals
of two different tracks of one pair in one bin, ``s`` apart along the wall. Their errors are
independent (the lowest separation, 4 px by default, keeps the two particle images apart), so
the tracks' own error drops out of the products' mean, which is the two-point correlation
``C(s) = <u'(x) u'(x + s)>``. Its mean in each class of separations (``separation_px``: 4-10,
10-17 and 17-24 px by default) is fitted by a straight line in ``s^2`` (a smooth field's
correlation is ``C(0) - C''(0) s^2 / 2 + ...``), weighted by each class's pairs of tracks, and
the line's value at ``s = 0`` is the stress without the tracks' error. On fields correlated over
30 px along the wall with 0.1 px errors per component it is the error-free tracks' stress within
its errors and ``uu - uu_two``, ``vv - vv_two`` are the errors' variance to 0.0002 px^2
(``tests/test_ptv.py``); a field correlated over less than about the largest separation bends
the line (a Gaussian correlation of 25 px: 1-3 % low). Near the wall the turbulence stays
correlated along it over tens of wall units (``v``) to hundreds (``u``, the streaks), at the
paper's 0.67 wall units per px well beyond 24 px. Where the difference matters most is ``vv``
within a few wall units of the wall, whose true value (``v+`` ~ ``y+^2``) is below the tracks'
error. Each track pairs with only the few others of its bin that near (about 0.4 at 0.02
particle images per px^2 in bins of 0.5 px), so the two-track stresses need many pairs; their
standard errors come the same way, over the pairs, floored by independent products'
(``sqrt((s_a^2 s_b^2 + C^2) / n2)`` through the fit).

Bins within one particle-image diameter of the wall (``near_wall``) hold particle images that
merge with their own reflection in the wall: their centres are pulled towards the wall line and
their displacements mix with the reflection's.

:func:`sublayer_fit` fits ``U = g (h - h0)`` to the bins of the viscous sublayer, weighted by
their standard errors: the wall-normal gradient ``g`` (px per pair per px) and the wall's
offset ``h0`` from the line the tracks were binned against (px). The wall shear follows with
no magnification: ``u_tau = sqrt(nu g / dt)`` (``nu`` in m^2/s, ``dt`` the pulse separation
in s), the classic way to measure it from tracks at the wall. The sublayer is linear to about
2 % at ``y+ = 5`` (Schlatter & Örlü's profile: ``U+ = 4.90`` there).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.ptv import wall_sign
from rspiv.row_errors import LAGS, chain_lags, lag_factor

__all__ = ["SublayerFit", "TrackProfile", "WallLine", "sublayer_fit"]

#: The moments summed per bin and pair: n, U, V, UU, VV, UV, c, cc, cU, cV (``c`` the track's
#: distance from the bin's centre), then for each class of separations the sums over the pairs
#: of tracks ``(i, j)`` in it (:class:`TrackProfile`): N2, Pu, Pv, Qu, Qv, H1, H2, Xuu, Xvv,
#: Xuv, S2 with ``P_a = a_i + a_j``, ``Q_a = a_i c_j + a_j c_i``, ``H1 = c_i + c_j``, ``H2 = c_i
#: c_j``, ``X_ab = (a_i b_j + a_j b_i) / 2`` and ``S2`` the separation squared.
_SINGLE = 10
_PER_CLASS = 11

#: The edges (px) of the classes of separation along the wall of the two tracks whose products
#: give the two-track stresses.
SEPARATION_PX = (4.0, 10.0, 17.0, 24.0)


@dataclasses.dataclass(frozen=True)
class WallLine:
    """A straight wall ``y = intercept_px + slope x`` (px of the frames) with the flow on
    ``flow_side`` (``"above"``: at smaller y), for a wall known otherwise than by
    :func:`rspiv.find_wall` (whose :class:`rspiv.Wall` serves as well)."""

    intercept_px: float
    slope: float = 0.0
    flow_side: str = "above"

    def line(self, x: Any) -> np.ndarray:
        """The wall's y at ``x`` (px)."""
        return self.intercept_px + self.slope * np.asarray(x, dtype=np.float64)


class TrackProfile:
    """Tracks of many pairs binned by their distance from a wall (module docstring).

    Parameters
    ----------
    wall : Wall
        The wall line (:class:`rspiv.Wall`, or any object with ``line(x)``, ``slope`` and
        ``flow_side``), in the frames' px.
    bin_px : float
        Bin height (px, > 0).
    band_px : float
        The band's height from the wall (px, > ``bin_px``).
    x_range : (float, float), optional
        Only tracks whose midpoint x lies within this range (px).
    saturated : bool
        Keep tracks whose particle image is saturated in either frame (their centres come
        from clipped profiles); default False.
    separation_px : sequence of float
        The edges (px, at least three, increasing) of the classes of separation along the wall
        of two tracks of one pair and one bin whose fluctuations' products give the two-track
        stresses (module docstring); the lowest keeps the two particle images apart (their
        errors independent).
    """

    def __init__(
        self,
        wall: Any,
        *,
        bin_px: float = 0.5,
        band_px: float = 32.0,
        x_range: tuple[float, float] | None = None,
        saturated: bool = False,
        separation_px: tuple[float, ...] = SEPARATION_PX,
    ) -> None:
        sign = wall_sign(wall)
        edges = np.asarray(separation_px, dtype=np.float64)
        if not (
            edges.ndim == 1 and edges.size >= 3 and np.all(np.isfinite(edges))
            and edges[0] >= 0 and np.all(np.diff(edges) > 0)
        ):  # fmt: skip
            raise InvalidInputError(
                f"separation_px {tuple(separation_px)}: give at least three increasing edges "
                "(px, >= 0)"
            )
        self.separation_px = tuple(float(e) for e in edges)
        self.moments = _SINGLE + _PER_CLASS * (edges.size - 1)
        if not (np.isfinite(bin_px) and bin_px > 0 and np.isfinite(band_px) and band_px > bin_px):
            raise InvalidInputError(
                f"bin_px ({bin_px}) must be > 0 and band_px ({band_px}) larger than it"
            )
        self.wall, self.sign = wall, sign
        self.bin_px, self.band_px = float(bin_px), float(band_px)
        self.nbins = int(np.ceil(self.band_px / self.bin_px))
        self.x_range = x_range
        self.keep_saturated = bool(saturated)
        slope = float(getattr(wall, "slope", 0.0))
        self._cos = 1.0 / np.hypot(1.0, slope)
        # the wall's tangent (towards +x) and normal (into the flow), pixel frame
        self._t = np.array([1.0, slope]) * self._cos
        self._n = -self.sign * np.array([-slope, 1.0]) * self._cos
        self.pairs = 0
        self.total = np.zeros((self.nbins, self.moments))
        self.outer = np.zeros((self.nbins, self.moments, self.moments))
        self.pairs_in = np.zeros(self.nbins, dtype=np.int64)
        self.diameters: list[float] = []
        #: per lag 1 .. LAGS and bin: the sums of the products of a pair's single-track sums
        #: with those of the pair that many ids later (module docstring); None when pickled
        #: before them
        self.lags: np.ndarray | None = np.zeros((LAGS, self.nbins, _SINGLE, _SINGLE))
        #: the last pairs' ``(id, single-track sums)`` (the chain; cleared by a merge)
        self.recent: list[tuple[int, np.ndarray]] = []

    def __setstate__(self, state: dict) -> None:
        state.setdefault("lags", None)  # pickled before the lags
        state.setdefault("recent", [])
        self.__dict__.update(state)

    def add(self, tracks: Any, pair_id: int | None = None) -> int:
        """Add one pair's tracks (:class:`rspiv.ptv.Tracks`); returns how many fell in the
        band. ``pair_id``: the pair's place in time (its id in the campaign), for the pairs'
        serial correlation (module docstring); default the number of pairs added before.
        Raises InvalidInputError, before anything is added, for an id that is not an integer."""
        if pair_id is not None and not isinstance(pair_id, (int, np.integer)):
            raise InvalidInputError(f"pair_id: expected an integer id, got {pair_id!r}")
        x, y = np.asarray(tracks.x, dtype=np.float64), np.asarray(tracks.y, dtype=np.float64)
        keep = np.isfinite(tracks.u) & np.isfinite(tracks.v)
        if not self.keep_saturated:
            keep &= ~np.asarray(tracks.saturated, dtype=bool)
        if self.x_range is not None:
            keep &= (x >= self.x_range[0]) & (x <= self.x_range[1])
        h = self.sign * (np.asarray(self.wall.line(x), dtype=np.float64) - y) * self._cos
        h = np.where(keep & np.isfinite(h), h, -1.0)  # a track mapped nowhere (NaN) is left out
        b = np.floor(h / self.bin_px).astype(np.int64)
        keep &= (h >= 0) & (b < self.nbins)
        b, h = b[keep], h[keep]
        d = np.stack([np.asarray(tracks.u)[keep], np.asarray(tracks.v)[keep]], axis=-1)
        U, V = d @ self._t, d @ self._n
        # h about the bin's centre: the sums of h^2 stay well conditioned
        c = h - (b + 0.5) * self.bin_px
        m = np.stack([np.ones_like(U), U, V, U * U, V * V, U * V, c, c * c, c * U, c * V], -1)
        t = np.zeros((self.nbins, self.moments))
        np.add.at(t[:, :_SINGLE], b, m)
        along = np.stack([x[keep], y[keep]], axis=-1) @ self._t
        self._two_track_sums(t, b, along, U, V, c)
        self.total += t
        self.outer += t[:, :, None] * t[:, None, :]
        self.pairs_in += t[:, 0] > 0
        if self.lags is not None:
            pid = self.pairs if pair_id is None else int(pair_id)
            chain_lags(self.lags, self.recent, pid, t[:, :_SINGLE].copy())
        self.pairs += 1
        if np.isfinite(getattr(tracks, "diameter", np.nan)):
            self.diameters.append(float(tracks.diameter))
        return int(b.size)

    def _two_track_sums(self, t, b, along, U, V, c) -> None:
        """Add to ``t[:, 10:]`` the sums over this pair's pairs of tracks in one bin, by the
        class of their separation along the wall (:attr:`separation_px`, ``_PER_CLASS``): the
        tracks sorted by bin and place along the wall, each compared with its k-th successor
        for k = 1, 2 ... while any successor in the bin is near enough."""
        edges = np.asarray(self.separation_px)
        s_lo, s_hi = edges[0], edges[-1]
        o = np.lexsort((along, b))
        b, along, U, V, c = b[o], along[o], U[o], V[o], c[o]
        for k in range(1, b.size):
            same = b[k:] == b[:-k]
            ds = along[k:] - along[:-k]
            near = same & (ds <= s_hi)
            if not near.any():
                break
            i = np.flatnonzero(near & (ds >= s_lo))
            j = i + k
            cls = np.minimum(np.searchsorted(edges, ds[i], side="right") - 1, edges.size - 2)
            m = np.stack([
                np.ones(i.size), U[i] + U[j], V[i] + V[j],
                U[i] * c[j] + U[j] * c[i], V[i] * c[j] + V[j] * c[i],
                c[i] + c[j], c[i] * c[j],
                U[i] * U[j], V[i] * V[j], 0.5 * (U[i] * V[j] + U[j] * V[i]), ds[i] ** 2,
            ], -1)  # fmt: skip
            cols = _SINGLE + _PER_CLASS * cls[:, None] + np.arange(_PER_CLASS)
            np.add.at(t, (b[i][:, None], cols), m)

    def merge(self, other: TrackProfile) -> None:
        """Add the sums of ``other`` (a profile of other pairs: a shard of the same pass) to
        this one. Refused (InvalidInputError) unless both have the same wall, bins, band,
        range, separations and saturation choice."""
        def shape(p: TrackProfile) -> tuple:
            return (
                p.sign, p.bin_px, p.band_px, p.x_range, p.keep_saturated, p.separation_px,
                float(getattr(p.wall, "slope", 0.0)), float(np.asarray(p.wall.line(0.0))),
            )  # fmt: skip

        if shape(self) != shape(other):
            raise InvalidInputError(
                f"the profiles differ in wall, bins or separations: {shape(self)} against "
                f"{shape(other)}"
            )
        self.total += other.total
        self.outer += other.outer
        theirs = getattr(other, "lags", None)
        self.lags = None if self.lags is None or theirs is None else self.lags + theirs
        self.recent = []  # the chains of two parts are not joined
        self.pairs_in += other.pairs_in
        self.pairs += other.pairs
        self.diameters.extend(other.diameters)

    def result(self, min_tracks: int = 10) -> dict[str, np.ndarray]:
        """The profile (module docstring): per bin ``h_px``, ``edge_px`` (the bin's lower edge),
        ``n``, ``pairs`` (the pairs with a track in it), ``U``, ``V``, ``uu``, ``vv``, ``uv``,
        the two-track stresses ``uu_two``, ``vv_two``, ``uv_two`` with ``n_two`` (the pairs
        of tracks), ``se_U``, ... ``se_uv_two`` and ``near_wall``; bins with fewer than
        ``min_tracks`` (at least 3) tracks, or pairs of tracks for the two-track stresses, are
        NaN; ``serial_U`` ... ``serial_uv`` and ``open_U`` ... (the pairs' serial factor on
        each variance, already in its ``se_``, and where it is a lower bound; none for
        profiles pickled before the lags). Also ``diameter_px`` (the particle images' median
        e^-2 diameter) and ``total_pairs`` as 0-d arrays."""
        T, M, P = self.total, self.outer, self.pairs
        n = T[:, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            stats = _statistics(T)
            # each statistic's gradient in the sums, by central differences
            grads = {k: np.zeros((self.nbins, self.moments)) for k in stats}
            for j in range(self.moments):
                step = 1e-6 * np.maximum(np.abs(T[:, j]), 1.0)
                hi, lo = T.copy(), T.copy()
                hi[:, j] += step
                lo[:, j] -= step
                up, down = _statistics(hi), _statistics(lo)
                for k in stats:
                    grads[k][:, j] = (up[k] - down[k]) / (2 * step)
            # covariance of the sums over pairs drawn independently: P/(P-1) (M - T T^T / P)
            cov = (M - T[:, :, None] * T[:, None, :] / max(P, 1)) * (P / max(P - 1, 1))
            out: dict[str, np.ndarray] = {}
            iid = _independent_errors(stats, n, T)
            serial = self._serial(grads)
            for k, g in grads.items():
                out[k] = stats[k]
                se = np.sqrt(np.maximum(np.einsum("bi,bij,bj->b", g, cov, g), 0.0))
                f = serial.get(k.removesuffix("_two"), (1.0, None))[0]
                out[f"se_{k}"] = np.fmax(se, iid[k]) * np.sqrt(f)
            for k, (f, still) in serial.items():
                out[f"serial_{k}"], out[f"open_{k}"] = f, still
            centre = (np.arange(self.nbins) + 0.5) * self.bin_px
            h = centre + T[:, 6] / n
        few = n < max(int(min_tracks), 3)
        n_two = _extrapolation(T)[1].sum(axis=1)
        few_two = n_two < max(int(min_tracks), 3)
        for k in list(out):
            if k.startswith(("serial_", "open_")):
                continue
            out[k] = np.where(few | (few_two if k.endswith("_two") else False), np.nan, out[k])
            if k.startswith("se_"):
                out[k] = np.where(self.pairs_in < 2, np.nan, out[k])
        diameter = float(np.median(self.diameters)) if self.diameters else float("nan")
        out.update(
            h_px=np.where(n > 0, h, centre),
            edge_px=centre - 0.5 * self.bin_px,
            n=n.astype(np.int64),
            n_two=n_two.astype(np.int64),
            pairs=self.pairs_in.copy(),
            near_wall=centre < (diameter if np.isfinite(diameter) else 0.0),
            diameter_px=np.asarray(diameter),
            total_pairs=np.asarray(P),
        )
        return out

    def _serial(self, grads: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per single-track statistic, the serial factor on its variance per bin and whether
        it is a lower bound (module docstring); empty for profiles pickled before the lags."""
        if self.lags is None:
            return {}
        M = self.outer[:, :_SINGLE, :_SINGLE]
        out = {}
        for k in ("U", "V", "uu", "vv", "uv"):
            g = np.nan_to_num(grads[k][:, :_SINGLE])
            gam0 = np.einsum("bi,bij,bj->b", g, M, g)
            gam = np.einsum("bi,kbij,bj->kb", g, self.lags, g)
            out[k] = lag_factor(gam0, gam, self.pairs_in)
        return out


def _independent_errors(
    stats: dict[str, np.ndarray], n: np.ndarray, T: np.ndarray
) -> dict[str, np.ndarray]:
    """The standard errors of ``n`` independent tracks (Gaussian fluctuations for the
    stresses): the floor of the pairs' estimate (module docstring)."""
    uu, vv, uv = (np.maximum(stats[k], 0.0) if k != "uv" else stats[k] for k in ("uu", "vv", "uv"))
    m = np.maximum(n - 1, 1)
    lam, n2 = _extrapolation(T)
    n2 = (np.where(n2 > 0, lam**2 / np.where(n2 > 0, n2, 1.0), 0.0)).sum(axis=1)
    n2 = 1.0 / n2  # the pairs of tracks the extrapolated products are worth
    return {
        "U": np.sqrt(uu / n),
        "V": np.sqrt(vv / n),
        "uu": uu * np.sqrt(2.0 / m),
        "vv": vv * np.sqrt(2.0 / m),
        "uv": np.sqrt((uu * vv + uv**2) / m),
        # a product of two tracks' fluctuations: variance s_a^2 s_b^2 + C_ab^2
        "uu_two": np.sqrt((uu * uu + stats["uu_two"] ** 2) / n2),
        "vv_two": np.sqrt((vv * vv + stats["vv_two"] ** 2) / n2),
        "uv_two": np.sqrt((uu * vv + stats["uv_two"] ** 2) / n2),
    }


def _statistics(T: np.ndarray) -> dict[str, np.ndarray]:
    """``U``, ``V`` (at the tracks' mean distance) and the stresses about the bin's straight
    lines in ``h`` (module docstring), and the two-track stresses ``uu_two``, ``vv_two``,
    ``uv_two``: the mean product of two tracks' residuals from those lines at no separation,
    from the sums ``T`` (bins, moments: ``_SINGLE`` and ``_PER_CLASS`` per class)."""
    n = T[:, 0]
    mu, mv, mc = T[:, 1] / n, T[:, 2] / n, T[:, 6] / n
    vc = T[:, 7] / n - mc**2
    cu, cv = T[:, 8] / n - mu * mc, T[:, 9] / n - mv * mc
    dof = n / (n - 2)
    out = {
        "U": mu,
        "V": mv,
        "uu": (T[:, 3] / n - mu**2 - cu * cu / vc) * dof,
        "vv": (T[:, 4] / n - mv**2 - cv * cv / vc) * dof,
        "uv": (T[:, 5] / n - mu * mv - cu * cv / vc) * dof,
    }
    # the bin's lines a + b c (c from the bin's centre), the pairs of tracks' mean products of
    # their residuals from them in each class of separation, and those extrapolated to no
    # separation (module docstring; _PER_CLASS for the sums)
    bu, bv = cu / vc, cv / vc
    line = {"U": (mu - bu * mc, bu, 1, 3), "V": (mv - bv * mc, bv, 2, 4)}
    lam, _ = _extrapolation(T)
    for key, (p, q), x in (("uu_two", ("U", "U"), 7), ("vv_two", ("V", "V"), 8),
                           ("uv_two", ("U", "V"), 9)):  # fmt: skip
        (aa, ba, ia, ja), (ab, bb, ib, jb) = line[p], line[q]
        r0 = np.zeros_like(n)
        for k in range(lam.shape[1]):
            o = _SINGLE + _PER_CLASS * k
            n2, h1, h2 = T[:, o], T[:, o + 5], T[:, o + 6]
            pa, qa, pb, qb = T[:, o + ia], T[:, o + ja], T[:, o + ib], T[:, o + jb]
            c = (
                T[:, o + x] - 0.5 * (ab * pa + aa * pb) - 0.5 * (bb * qa + ba * qb)
                + aa * ab * n2 + 0.5 * (aa * bb + ba * ab) * h1 + ba * bb * h2
            ) / n2  # fmt: skip
            r0 = r0 + np.where(n2 > 0, lam[:, k] * c, 0.0)
        out[key] = r0
    return out


def _extrapolation(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weights ``lam`` (bins, classes) that take the classes' mean products ``C_k`` to
    their straight line in the squared separation at no separation, ``R0 = sum lam_k C_k``
    (least squares weighted by each class's pairs of tracks; module docstring), and those
    pairs ``n2`` (bins, classes). NaN where fewer than two classes hold pairs."""
    k = (T.shape[1] - _SINGLE) // _PER_CLASS
    o = _SINGLE + _PER_CLASS * np.arange(k)
    n2 = T[:, o]
    m = np.where(n2 > 0, T[:, o + 10] / np.where(n2 > 0, n2, 1.0), 0.0)
    w_sum = n2.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        m_bar = (n2 * m).sum(axis=1, keepdims=True) / w_sum
        sxx = (n2 * (m - m_bar) ** 2).sum(axis=1, keepdims=True)
        return n2 / w_sum - m_bar * n2 * (m - m_bar) / sxx, n2


@dataclasses.dataclass(frozen=True)
class SublayerFit:
    """The viscous sublayer's gradient fitted to a track profile's bins (:func:`sublayer_fit`).

    Attributes
    ----------
    gradient, se_gradient : float
        ``dU/dh`` at the wall (px per pair per px) and its standard error.
    wall_offset_px, se_wall_offset_px : float
        Where the fitted profile reaches zero, from the wall line the tracks were binned
        against (px; positive: the wall lies into the flow from that line).
    bins : int
        Bins fitted.
    chi2_dof : float
        The residuals' chi-square per degree of freedom against the bins' standard errors
        (about 1 for a profile of the fitted shape; well above: the range leaves the sublayer,
        the wall is not where the profile says, or the errors are too small).
    h_range_px : (float, float)
        The distances fitted (px).
    curvature : bool
        The bins were corrected for the sublayer's departure from a straight line (the DNS's
        ``U+(y+)``; :func:`sublayer_fit` with ``nu``, ``dt`` and ``scale_m_per_px``).
    y_plus_range : (float, float)
        The fitted range in wall units (NaN without ``nu``, ``dt`` and ``scale_m_per_px``).
    """

    gradient: float
    se_gradient: float
    wall_offset_px: float
    se_wall_offset_px: float
    bins: int
    chi2_dof: float
    h_range_px: tuple[float, float]
    curvature: bool = False
    y_plus_range: tuple[float, float] = (float("nan"), float("nan"))

    def u_tau(self, nu: float, dt: float) -> tuple[float, float]:
        """The friction velocity ``sqrt(nu g / dt)`` and its standard error (m/s), ``nu`` the
        kinematic viscosity (m^2/s), ``dt`` the pulse separation (s)."""
        return _u_tau(self.gradient, self.se_gradient, nu, dt)


def _u_tau(g: float, se: float, nu: float, dt: float) -> tuple[float, float]:
    if not (nu > 0 and dt > 0):
        raise InvalidInputError(f"nu ({nu}) and dt ({dt}) must be > 0")
    if not g > 0:
        raise InvalidInputError(
            f"the sublayer's gradient {g:.4g} px/px is not positive: no wall shear from it"
        )
    ut = float(np.sqrt(nu * g / dt))
    return ut, 0.5 * ut * se / g


def _line(h: np.ndarray, U: np.ndarray, se: np.ndarray) -> tuple:
    """``U = g (h - h0)`` weighted by ``1 / se^2``: ``g``, ``h0``, their covariance (on
    ``(g, c)`` with ``c = -g h0``) and the chi-square."""
    w = 1.0 / se**2
    A = np.column_stack([h, np.ones(h.size)])
    cov = np.linalg.inv(A.T @ (A * w[:, None]))
    g, c = cov @ (A.T @ (w * U))
    return float(g), float(c), cov, float(np.sum(w * (U - g * h - c) ** 2))


def sublayer_fit(
    profile: dict[str, np.ndarray],
    h_max_px: float,
    *,
    h_min_px: float | None = None,
    nu: float | None = None,
    dt: float | None = None,
    scale_m_per_px: float | None = None,
) -> SublayerFit:
    """Fit the viscous sublayer to the bins of ``profile`` (:meth:`TrackProfile.result`)
    between ``h_min_px`` (default: the first bin clear of ``near_wall``) and ``h_max_px``.

    Without ``nu``, ``dt`` and ``scale_m_per_px``: a straight line ``U = g (h - h0)``. The
    sublayer is not quite straight: fitted over ``y+`` 2-5, a line reads the DNS profile's
    gradient 5.3 % low (0.9 % over 0.5-3; ``u_tau`` half as much), the offset ``h0`` by
    ``-0.13`` viscous lengths. With all three (m^2/s, s, m per px of the frames), each bin is
    first brought onto the straight line by the DNS's ``y+ / U+(y+)`` at its ``y+`` (from the
    previous fit's ``u_tau`` and ``h0``), and the line refitted until ``u_tau`` settles
    (:attr:`SublayerFit.curvature`); the DNS profile fitted this way gives its own gradient
    back (``tests/test_ptv.py``).

    Raises InvalidInputError with fewer than three bins with a standard error in the range,
    or a fit that does not settle in 50 rounds."""
    h, U, se = (np.asarray(profile[k], dtype=np.float64) for k in ("h_px", "U", "se_U"))
    near = np.asarray(profile.get("near_wall", np.zeros(h.size, bool)), dtype=bool)
    lo = float(h_min_px) if h_min_px is not None else (
        float(np.max(h[near], initial=0.0)) + 1e-9 if near.any() else 0.0
    )  # fmt: skip
    use = (h >= lo) & (h <= h_max_px) & np.isfinite(U) & np.isfinite(se) & (se > 0)
    if np.count_nonzero(use) < 3:
        raise InvalidInputError(
            f"sublayer fit: {np.count_nonzero(use)} bins with a standard error between "
            f"{lo:.3g} and {h_max_px:.3g} px from the wall; at least 3 needed"
        )
    h, U, se = h[use], U[use], se[use]
    g, c, cov, chi2 = _line(h, U, se)
    given = [v is not None for v in (nu, dt, scale_m_per_px)]
    yp = (float("nan"), float("nan"))
    if any(given):
        if not all(given) or not (nu > 0 and dt > 0 and scale_m_per_px > 0):  # type: ignore
            raise InvalidInputError(
                "sublayer fit: nu, dt and scale_m_per_px go together, each > 0"
            )
        from rspiv.reference import load_dns  # deferred: the DNS table loads on first use

        dns = load_dns()
        for _ in range(50):
            ut, _se = _u_tau(g, 0.0, nu, dt)  # type: ignore[arg-type]
            y_plus = (h + c / g) * scale_m_per_px * ut / nu  # type: ignore[operator]
            fy = np.interp(np.maximum(y_plus, 1e-6), dns.y_plus, dns.u_plus)
            k = np.where(y_plus > 1e-6, np.maximum(y_plus, 1e-6) / fy, 1.0)
            g2, c, cov, chi2 = _line(h, U * k, se * k)
            if abs(g2 - g) <= 1e-9 * abs(g):
                g = g2
                break
            g = g2
        else:
            raise InvalidInputError("sublayer fit: the curvature correction did not settle")
        yp = (float(np.min(y_plus)), float(np.max(y_plus)))
    h0 = -c / g
    j = np.array([c / g**2, -1.0 / g])
    return SublayerFit(
        gradient=float(g),
        se_gradient=float(np.sqrt(cov[0, 0])),
        wall_offset_px=float(h0),
        se_wall_offset_px=float(np.sqrt(j @ cov @ j)),
        bins=int(h.size),
        chi2_dof=float(chi2 / max(h.size - 2, 1)),
        h_range_px=(float(np.min(h)), float(np.max(h))),
        curvature=bool(all(given)),
        y_plus_range=yp,
    )
