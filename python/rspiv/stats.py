"""Streaming, mergeable velocity statistics per vector.

:class:`FieldAccumulator` holds, for every vector position of a PIV grid, the running count,
means and second central moments of ``(u, v)`` (Welford's update for one field, the parallel
formulas of Chan, Golub & LeVeque 1979 for merging), all in float64. Rejected vectors
(``valid == False``) are excluded per vector, so the count differs from vector to vector.

Lag-1 statistics
    To estimate how correlated successive samples are (time-resolved or over-sampled
    campaigns), the accumulator also keeps, per vector, the bivariate moments of the pairs
    ``(x_k, x_{k+1})`` of successive *valid* samples of u and of v, in the order the fields were
    added. A rejected vector breaks the chain at that position; merging never joins two chains
    (pairs never span shards). :meth:`FieldAccumulator.lag1_correlation` gives
    ``rho_1 = C_{k,k+1} / M2``, and :meth:`FieldAccumulator.n_eff` the effective number of
    independent samples ``n (1 - r) / (1 + r)`` (first-order autoregressive model, r clipped to
    [0, 0.99]) with ``r = rho_1`` for the means and, for the second moments of a Gaussian
    process, ``r = rho_u^2`` (uu), ``rho_v^2`` (vv), ``rho_u rho_v`` (uv). Independent samples
    give n_eff ~ n.

Measurement noise
    :meth:`FieldAccumulator.add` may be given each vector's standard uncertainty ``sigma_u``,
    ``sigma_v`` (:attr:`rspiv.PivField.sigma_u`, same units as u, v). Per vector the accumulator
    keeps the count of valid samples with a finite sigma and the sums of ``sigma^2`` and
    ``sigma^4`` (plain sums: merging adds them). :meth:`FieldAccumulator.noise_uu` is the mean
    ``<sigma_u^2>``, the variance the measurement noise adds to ``uu``; the noise-corrected
    stresses (:meth:`FieldAccumulator.uu_corrected`, ``vv_corrected``) subtract it:
    ``uu_c = uu - <sigma_u^2>``. ``uv`` is not corrected: the errors of u and v of one vector
    come from the asymmetry of one peak along two axes and are taken as uncorrelated (Wieneke
    2015; Sciacchitano & Wieneke 2016). Where the correction would make the stress negative the
    corrected value is NaN (the noise estimate exceeds the measured variance: the vector holds
    no resolved fluctuation). Standard uncertainty of ``<sigma^2>``: ``sqrt(var(sigma^2) / n)``
    from the sums (:meth:`FieldAccumulator.noise_uncertainty`). States written before this
    (no ``noise_*`` variables) load with no noise information.

Higher-order moments
    Per vector the accumulator also keeps the central sums of orders 3 to 8 of u and of v
    (``hm_u``, ``hm_v``, shape ``(6, *shape)``), updated and merged exactly like the second
    moments (:mod:`rspiv.moments`): :meth:`FieldAccumulator.skewness_flatness` gives the
    skewness, the flatness and their standard errors, raw or without the measurement noise.
    States written before them load with NaN sums (no higher moments).

Pair ids
    :meth:`FieldAccumulator.add` may be given the id of the image pair the field came from; the
    ids are kept in a set. Adding the same id twice, or merging two accumulators that share an
    id, raises :class:`~rspiv.errors.InvalidInputError` (a campaign must not count a pair twice).

NaN policy
    With ``valid=None`` a vector counts where both u and v are finite (NaN marks rejection).
    With an explicit ``valid`` mask, a non-finite u or v at a valid position is an error
    (:class:`~rspiv.errors.InvalidInputError` with the number of such vectors); non-finite values
    at rejected positions are ignored.

Covariances use ``ddof=1`` (sample covariances); they are NaN where fewer than two samples.
Units are those of the inputs; :meth:`FieldAccumulator.to_xarray` records them.
"""

from __future__ import annotations

import copy
from collections.abc import Hashable, Iterable
from typing import Any

import numpy as np

from rspiv import moments
from rspiv.errors import InvalidInputError
from rspiv.outlier_screen import ScreenTally
from rspiv.peak_locking import LockingHistogram
from rspiv.row_errors import RowErrors
from rspiv.two_point import TwoPointAccumulator
from rspiv.vorticity import VorticityAccumulator

_STATE = (
    "count",
    "mean_u",
    "mean_v",
    "m2_uu",
    "m2_vv",
    "c_uv",
    "lag_count_u",
    "lag_mean_a_u",
    "lag_mean_b_u",
    "lag_c_u",
    "lag_count_v",
    "lag_mean_a_v",
    "lag_mean_b_v",
    "lag_c_v",
)


#: The noise sums (module docstring "Measurement noise"), kept apart from ``_STATE`` so that
#: states written before them still load.
_NOISE = ("noise_count", "noise_s_uu", "noise_s_vv", "noise_s2_uu", "noise_s2_vv")

#: The central sums of orders 3-8 (module docstring "Higher-order moments"), kept apart alike.
_MOMENTS = ("hm_u", "hm_v")


def _chan_merge_moments(na, ma, nb, mb, n):
    """Return (delta, weight) for Chan's formulas, safe where n == 0."""
    delta = mb - ma
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(n > 0, nb / np.where(n > 0, n, 1), 0.0)
    return delta, frac


class FieldAccumulator:
    """Per-vector running statistics of u and v over many PIV fields.

    Parameters
    ----------
    shape : tuple of int
        Shape of the vector grid (``(ny, nx)`` for a PIV field; any shape is accepted).

    Attributes
    ----------
    count : ndarray of int64
        Number of valid samples per vector.
    mean_u, mean_v : ndarray of float64
        Means per vector (0 where count == 0).
    pair_ids : set
        Ids of the image pairs added (those given to :meth:`add`).
    n_fields : int
        Number of fields added (with or without an id).
    """

    def __init__(self, shape: tuple[int, ...] | int):
        shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
        if not shape or any(int(s) <= 0 for s in shape):
            raise InvalidInputError(f"shape: expected positive dimensions, got {shape!r}")
        self.shape: tuple[int, ...] = tuple(int(s) for s in shape)
        self.count = np.zeros(self.shape, dtype=np.int64)
        for name in _STATE[1:]:
            dtype = np.int64 if name.startswith("lag_count") else np.float64
            setattr(self, name, np.zeros(self.shape, dtype=dtype))
        self._last_u = np.zeros(self.shape, dtype=np.float64)
        self._last_v = np.zeros(self.shape, dtype=np.float64)
        self._has_last = np.zeros(self.shape, dtype=bool)
        self.pair_ids: set[Hashable] = set()
        self.n_fields = 0
        for name in _NOISE:
            dtype = np.int64 if name == "noise_count" else np.float64
            setattr(self, name, np.zeros(self.shape, dtype=dtype))
        for name in _MOMENTS:
            setattr(self, name, np.zeros((len(moments.ORDERS), *self.shape)))
        #: optional :class:`rspiv.EnsembleAccumulator` of the same pairs (a campaign's ensemble
        #: band): carried through :meth:`merge`, pickles and :meth:`to_xarray`
        self.ensemble: Any = None
        #: optional :class:`rspiv.ensemble.PixelAccumulator` of the same pairs (the campaign's
        #: single-pixel rows at the wall), carried alike
        self.pixel: Any = None
        #: optional :class:`rspiv.two_point.TwoPointAccumulator` of the same fields (a
        #: campaign's streamwise spectra and correlations), carried alike
        self.two_point: Any = None
        #: optional :class:`rspiv.vorticity.VorticityAccumulator` of the same fields, alike
        self.vorticity: Any = None
        #: optional :class:`rspiv.peak_locking.LockingHistogram` of the same fields, alike
        self.locking: Any = None
        #: optional :class:`rspiv.row_errors.RowErrors` of the same fields, alike
        self.rows: Any = None
        #: optional :class:`rspiv.outlier_screen.ScreenTally` of what a screen left out, alike
        self.screen: Any = None

    # ------------------------------------------------------------------ input
    def _check(self, name: str, a) -> np.ndarray:
        arr = np.asarray(a)
        if arr.shape != self.shape:
            raise InvalidInputError(f"{name}: expected shape {self.shape}, got {arr.shape}")
        return arr

    def add(
        self,
        u,
        v,
        valid=None,
        pair_id: Hashable | None = None,
        sigma_u=None,
        sigma_v=None,
    ) -> None:
        """Add one velocity field.

        Parameters
        ----------
        u, v : array_like, shape ``self.shape``
            Velocity components (any unit, the same for every call).
        valid : array_like of bool, optional
            True where the vector is accepted. Default: where u and v are finite.
        pair_id : hashable, optional
            Id of the image pair (int or str); a repeated id is refused.
        sigma_u, sigma_v : array_like, optional
            Standard uncertainty of every vector (the units of u, v; NaN where not estimated):
            accumulated at the valid vectors where both are finite (module docstring).

        Raises
        ------
        InvalidInputError
            Wrong shape, a non-boolean mask, NaN/inf at a valid vector, a negative sigma, only
            one of the sigmas, or a repeated pair id.
        """
        u = self._check("u", u).astype(np.float64, copy=False)
        v = self._check("v", v).astype(np.float64, copy=False)
        finite = np.isfinite(u) & np.isfinite(v)
        if valid is None:
            ok = finite
        else:
            valid = self._check("valid", valid)
            if valid.dtype != np.bool_:
                if not np.issubdtype(valid.dtype, np.integer) or np.any(
                    (valid != 0) & (valid != 1)
                ):
                    raise InvalidInputError(
                        f"valid: expected a boolean mask, got dtype {valid.dtype}"
                    )
                valid = valid.astype(bool)
            bad = valid & ~finite
            if bad.any():
                raise InvalidInputError(
                    f"u, v: {int(bad.sum())} vector(s) marked valid are NaN or inf; "
                    "mark them invalid (valid=False) or pass valid=None"
                )
            ok = valid
        if pair_id is not None:
            if pair_id in self.pair_ids:
                raise InvalidInputError(f"pair_id: {pair_id!r} was already added")
        if (sigma_u is None) != (sigma_v is None):
            raise InvalidInputError("sigma_u, sigma_v: give both or neither")
        if sigma_u is not None:
            su = self._check("sigma_u", sigma_u).astype(np.float64, copy=False)
            sv = self._check("sigma_v", sigma_v).astype(np.float64, copy=False)
            with np.errstate(invalid="ignore"):
                if np.any(su < 0) or np.any(sv < 0):
                    raise InvalidInputError("sigma_u, sigma_v: an uncertainty is negative")
            has = ok & np.isfinite(su) & np.isfinite(sv)
            su2 = np.where(has, su * su, 0.0)
            sv2 = np.where(has, sv * sv, 0.0)
            self.noise_count += has
            self.noise_s_uu += su2
            self.noise_s_vv += sv2
            self.noise_s2_uu += su2 * su2
            self.noise_s2_vv += sv2 * sv2
        u0 = np.where(ok, u, 0.0)
        v0 = np.where(ok, v, 0.0)

        # lag-1 pairs (previous valid sample, this sample) where the chain is unbroken
        lag = ok & self._has_last
        self._lag_update("u", lag, self._last_u, u0)
        self._lag_update("v", lag, self._last_v, v0)
        np.copyto(self._last_u, u0, where=ok)
        np.copyto(self._last_v, v0, where=ok)
        self._has_last = ok.copy()

        # Welford update of the means and co-moments, in place; w = 0 leaves a rejected
        # vector unchanged (u0, v0 are finite there, so 0 * finite = 0)
        w = ok.astype(np.float64)
        n_new = self.count + ok
        inv = w / np.maximum(n_new, 1)
        du = u0 - self.mean_u
        du *= w
        dv = v0 - self.mean_v
        dv *= w
        # orders 3-8 from the sums before this sample (M_2 included)
        moments.add_sample(self.hm_u, self.m2_uu, self.count, du)
        moments.add_sample(self.hm_v, self.m2_vv, self.count, dv)
        self.mean_u += du * inv
        self.mean_v += dv * inv
        du2 = u0 - self.mean_u
        dv2 = v0 - self.mean_v
        self.m2_uu += du * du2
        self.m2_vv += dv * dv2
        self.c_uv += du * dv2
        self.count = n_new
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(pair_id)

    def _lag_update(self, comp: str, mask, a, b) -> None:
        n = getattr(self, f"lag_count_{comp}")
        ma = getattr(self, f"lag_mean_a_{comp}")
        mb = getattr(self, f"lag_mean_b_{comp}")
        c = getattr(self, f"lag_c_{comp}")
        w = mask.astype(np.float64)
        n_new = n + mask
        inv = w / np.maximum(n_new, 1)
        da = a - ma
        da *= w
        db = b - mb
        db *= w
        ma = ma + da * inv
        mb = mb + db * inv
        c = c + da * (b - mb)
        setattr(self, f"lag_count_{comp}", n_new)
        setattr(self, f"lag_mean_a_{comp}", ma)
        setattr(self, f"lag_mean_b_{comp}", mb)
        setattr(self, f"lag_c_{comp}", c)

    # ------------------------------------------------------------------ merge
    def merge(self, other: FieldAccumulator) -> FieldAccumulator:
        """Merge ``other`` into ``self`` (in place) and return ``self``.

        Exact (to rounding) in any split and order: the result equals one pass over all the
        samples. The lag-1 chains are not joined across the two parts, and after a merge the
        next :meth:`add` starts a new chain.

        Raises
        ------
        InvalidInputError
            If the shapes differ or the two share a pair id.
        """
        if not isinstance(other, FieldAccumulator):
            raise InvalidInputError(f"other: expected a FieldAccumulator, got {type(other)!r}")
        if other.shape != self.shape:
            raise InvalidInputError(
                f"other: shape {other.shape} differs from this accumulator's {self.shape}"
            )
        common = self.pair_ids & other.pair_ids
        if common:
            shown = sorted(map(repr, common))[:5]
            raise InvalidInputError(
                f"merge: {len(common)} pair id(s) in both accumulators (e.g. {', '.join(shown)})"
            )
        na, nb = self.count, other.count
        n = na + nb
        du, fu = _chan_merge_moments(na, self.mean_u, nb, other.mean_u, n)
        dv, _ = _chan_merge_moments(na, self.mean_v, nb, other.mean_v, n)
        w = na * fu  # na * nb / n
        # orders 3-8 from both parts' sums before the merge (M_2 included)
        self.hm_u = moments.merge(self.hm_u, self.m2_uu, na, other.hm_u, other.m2_uu, nb, du)
        self.hm_v = moments.merge(self.hm_v, self.m2_vv, na, other.hm_v, other.m2_vv, nb, dv)
        self.m2_uu = self.m2_uu + other.m2_uu + du * du * w
        self.m2_vv = self.m2_vv + other.m2_vv + dv * dv * w
        self.c_uv = self.c_uv + other.c_uv + du * dv * w
        self.mean_u = self.mean_u + du * fu
        self.mean_v = self.mean_v + dv * fu
        self.count = n
        for comp in ("u", "v"):
            la, lb = getattr(self, f"lag_count_{comp}"), getattr(other, f"lag_count_{comp}")
            ln = la + lb
            da, fa = _chan_merge_moments(
                la,
                getattr(self, f"lag_mean_a_{comp}"),
                lb,
                getattr(other, f"lag_mean_a_{comp}"),
                ln,
            )
            db, _ = _chan_merge_moments(
                la,
                getattr(self, f"lag_mean_b_{comp}"),
                lb,
                getattr(other, f"lag_mean_b_{comp}"),
                ln,
            )
            c = getattr(self, f"lag_c_{comp}") + getattr(other, f"lag_c_{comp}") + da * db * la * fa
            setattr(self, f"lag_c_{comp}", c)
            setattr(self, f"lag_mean_a_{comp}", getattr(self, f"lag_mean_a_{comp}") + da * fa)
            setattr(self, f"lag_mean_b_{comp}", getattr(self, f"lag_mean_b_{comp}") + db * fa)
            setattr(self, f"lag_count_{comp}", ln)
        self._has_last = np.zeros(self.shape, dtype=bool)
        for name in _NOISE:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        for name in ("ensemble", "pixel", "two_point", "vorticity", "locking", "screen", "rows"):
            theirs = getattr(other, name)
            if theirs is not None:
                mine = getattr(self, name)
                if mine is None:
                    setattr(self, name, copy.deepcopy(theirs))
                else:
                    mine.merge(theirs)
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    @classmethod
    def merged(cls, parts: Iterable[FieldAccumulator]) -> FieldAccumulator:
        """A new accumulator holding the merge of ``parts`` (none of them is modified)."""
        parts = list(parts)
        if not parts:
            raise InvalidInputError("parts: nothing to merge")
        out = cls(parts[0].shape)
        for p in parts:
            out.merge(p)
        return out

    # ------------------------------------------------------------------ results
    def _cov(self, m2) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 1, m2 / (self.count - 1), np.nan)

    @property
    def uu(self) -> np.ndarray:
        """Sample variance of u per vector (ddof=1; NaN where count < 2)."""
        return self._cov(self.m2_uu)

    @property
    def vv(self) -> np.ndarray:
        """Sample variance of v per vector (ddof=1; NaN where count < 2)."""
        return self._cov(self.m2_vv)

    @property
    def uv(self) -> np.ndarray:
        """Sample covariance of u and v per vector (ddof=1; NaN where count < 2)."""
        return self._cov(self.c_uv)

    def _noise_mean(self, s) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.noise_count > 0, s / self.noise_count, np.nan)

    def noise_uu(self) -> np.ndarray:
        """Mean ``<sigma_u^2>`` per vector (NaN without uncertainties)."""
        return self._noise_mean(self.noise_s_uu)

    def noise_vv(self) -> np.ndarray:
        """Mean ``<sigma_v^2>`` per vector (NaN without uncertainties)."""
        return self._noise_mean(self.noise_s_vv)

    def noise_sigma4(self, component: str = "u") -> np.ndarray:
        """Mean ``<sigma^4>`` of ``component`` ("u" or "v") per vector (NaN without
        uncertainties): with ``<sigma^2>``, the noise in the flatness (:mod:`rspiv.moments`)."""
        if component not in ("u", "v"):
            raise InvalidInputError(f"component: expected 'u' or 'v', got {component!r}")
        return self._noise_mean(getattr(self, f"noise_s2_{component * 2}"))

    def noise_uncertainty(self, component: str = "u") -> np.ndarray:
        """Standard uncertainty of ``<sigma^2>`` of ``component`` ("u" or "v"): the sample
        standard deviation of ``sigma^2`` over ``sqrt(n)`` (NaN where n < 2)."""
        if component not in ("u", "v"):
            raise InvalidInputError(f"component: expected 'u' or 'v', got {component!r}")
        s = getattr(self, f"noise_s_{component * 2}")
        s2 = getattr(self, f"noise_s2_{component * 2}")
        n = self.noise_count
        with np.errstate(invalid="ignore", divide="ignore"):
            var = np.maximum(s2 - s * s / np.maximum(n, 1), 0.0) / np.maximum(n - 1, 1)
            return np.where(n > 1, np.sqrt(var / np.maximum(n, 1)), np.nan)

    def _corrected(self, raw, noise) -> np.ndarray:
        c = raw - noise
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(noise) & (c >= 0), c, np.nan)

    def uu_corrected(self) -> np.ndarray:
        """``uu - <sigma_u^2>``: the streamwise stress without the measurement noise (NaN
        where no uncertainties were given or the noise exceeds the measured variance)."""
        return self._corrected(self.uu, self.noise_uu())

    def vv_corrected(self) -> np.ndarray:
        """``vv - <sigma_v^2>`` (see :meth:`uu_corrected`)."""
        return self._corrected(self.vv, self.noise_vv())

    def central_moments(self, component: str = "u") -> np.ndarray:
        """Central moments ``mu_2 .. mu_8`` of ``component`` ("u" or "v") per vector: shape
        ``(7, *shape)``, ``mu_p = M_p / n`` (population moments; NaN where count < 2, and
        orders 3-8 NaN in states written before they were kept)."""
        if component not in ("u", "v"):
            raise InvalidInputError(f"component: expected 'u' or 'v', got {component!r}")
        m2 = self.m2_uu if component == "u" else self.m2_vv
        sums = np.concatenate([m2[None], getattr(self, f"hm_{component}")])
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 1, sums / np.maximum(self.count, 1), np.nan)

    def skewness_flatness(self, component: str = "u", corrected: bool = False) -> dict:
        """Skewness ``S``, flatness ``F`` of ``component`` per vector and their standard errors
        ``eps_S``, ``eps_F`` (:func:`rspiv.moments.skewness_flatness`; n_eff of the mean,
        :meth:`n_eff`).

        ``corrected``: S and F without the measurement noise (:func:`rspiv.moments.
        noise_corrected`, from the accumulated ``<sigma^2>``, ``<sigma^4>``; NaN where no
        uncertainties were given). The errors are those of the measured moments either way.
        """
        mu = self.central_moments(component)
        out = moments.skewness_flatness(mu, self.n_eff(component))
        if corrected:
            s2 = self.noise_uu() if component == "u" else self.noise_vv()
            out["S"], out["F"] = moments.noise_corrected(
                mu[0], mu[1], mu[2], s2, self.noise_sigma4(component)
            )
        return out

    def lag1_correlation(self, component: str = "u") -> np.ndarray:
        """Lag-1 autocorrelation ``rho_1`` of successive valid samples (NaN without pairs)."""
        if component not in ("u", "v"):
            raise InvalidInputError(f"component: expected 'u' or 'v', got {component!r}")
        m2 = self.m2_uu if component == "u" else self.m2_vv
        nl = getattr(self, f"lag_count_{component}")
        c = getattr(self, f"lag_c_{component}")
        with np.errstate(invalid="ignore", divide="ignore"):
            # both normalised per sample: lag co-moment / (n-1) over variance M2 / (n-1)
            rho = (c / np.maximum(nl, 1)) / (m2 / np.maximum(self.count, 1))
        return np.where((nl > 1) & (m2 > 0), rho, np.nan)

    def n_eff(self, quantity: str = "u") -> np.ndarray:
        """Effective number of independent samples, ``n (1 - r) / (1 + r)``.

        Parameters
        ----------
        quantity : {"u", "v", "uu", "vv", "uv"}
            ``"u"``/``"v"`` for the means (``r = rho_1``); ``"uu"``, ``"vv"``, ``"uv"`` for the
            second moments (``r = rho_u^2``, ``rho_v^2``, ``rho_u rho_v``: the lag-1
            correlation of the products of a Gaussian process).

        Notes
        -----
        Each rho_1 is clipped to [0, 0.99]; where it is unknown (fewer than two lag pairs) it
        is taken as 0, so n_eff = n.
        """
        if quantity not in ("u", "v", "uu", "vv", "uv"):
            raise InvalidInputError(
                f"quantity: expected 'u', 'v', 'uu', 'vv' or 'uv', got {quantity!r}"
            )

        def rho(comp):
            r = self.lag1_correlation(comp)
            return np.clip(np.nan_to_num(r, nan=0.0), 0.0, 0.99)

        if quantity in ("u", "v"):
            r = rho(quantity)
        elif quantity == "uv":
            r = rho("u") * rho("v")
        else:
            r = rho(quantity[0]) ** 2
        return self.count * (1.0 - r) / (1.0 + r)

    def n_eff_all(self) -> dict[str, np.ndarray]:
        """n_eff of every statistic: keys ``"U", "V", "uu", "vv", "uv"`` (the form
        :func:`rspiv.profiles.average_along_x` and ``analyse_profile`` accept)."""
        return {
            "U": self.n_eff("u"),
            "V": self.n_eff("v"),
            "uu": self.n_eff("uu"),
            "vv": self.n_eff("vv"),
            "uv": self.n_eff("uv"),
        }

    # ------------------------------------------------------------------ I/O
    def __getstate__(self):
        return self.__dict__.copy()

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.__dict__.setdefault("ensemble", None)
        self.__dict__.setdefault("pixel", None)
        self.__dict__.setdefault("two_point", None)
        self.__dict__.setdefault("vorticity", None)
        self.__dict__.setdefault("locking", None)
        self.__dict__.setdefault("rows", None)
        self.__dict__.setdefault("screen", None)
        # pickles from before the noise sums: no noise information
        for name in _NOISE:
            if name not in self.__dict__:
                dtype = np.int64 if name == "noise_count" else np.float64
                setattr(self, name, np.zeros(self.shape, dtype=dtype))
        # pickles from before the higher moments: NaN sums (none known)
        for name in _MOMENTS:
            if name not in self.__dict__:
                setattr(self, name, np.full((len(moments.ORDERS), *self.shape), np.nan))

    def to_xarray(self, x=None, y=None, velocity_units: str = "m s-1", attrs=None):
        """The statistics as an :class:`xarray.Dataset` (pivpy-compatible names).

        Variables: ``u``, ``v`` (means), ``uu``, ``vv``, ``uv`` (sample covariances),
        ``count``, ``n_eff_*`` and the raw accumulator state (``m2_uu`` ...,
        ``lag_*``, ``pair_id``) so that :meth:`from_xarray` restores it exactly. For a 2D grid the
        dimensions are ``("y", "x")`` and ``x``, ``y`` (1D, metres or px) become coordinates.
        """
        import xarray as xr

        if len(self.shape) == 2:
            dims = ("y", "x")
        else:
            dims = tuple(f"dim_{i}" for i in range(len(self.shape)))
        su = velocity_units
        stress_units = {"m s-1": "m2 s-2", "m/s": "m2 s-2", "pix": "pix2", "px": "px2"}.get(
            su, f"({su})2"
        )
        data = {
            "u": (self.mean_u, "mean streamwise velocity", su),
            "v": (self.mean_v, "mean wall-normal velocity", su),
            "uu": (self.uu, "streamwise Reynolds normal stress <u'u'> (ddof=1)", stress_units),
            "vv": (self.vv, "wall-normal Reynolds normal stress <v'v'> (ddof=1)", stress_units),
            "uv": (self.uv, "Reynolds shear stress <u'v'> (ddof=1)", stress_units),
            "count": (self.count, "number of valid samples", "1"),
            "n_eff_u": (self.n_eff("u"), "effective independent samples of u", "1"),
            "n_eff_v": (self.n_eff("v"), "effective independent samples of v", "1"),
            "n_eff_uu": (self.n_eff("uu"), "effective independent samples of uu", "1"),
            "n_eff_vv": (self.n_eff("vv"), "effective independent samples of vv", "1"),
            "n_eff_uv": (self.n_eff("uv"), "effective independent samples of uv", "1"),
        }
        ds = xr.Dataset()
        for k, (arr, long_name, units) in data.items():
            ds[k] = (dims, np.asarray(arr), {"long_name": long_name, "units": units})
        for k in _STATE[3:]:
            ds[k] = (dims, getattr(self, k), {"long_name": "accumulator state", "units": "1"})
        ids = sorted(self.pair_ids, key=lambda t: (type(t).__name__, t))
        if ids and all(isinstance(i, (int, np.integer)) for i in ids):
            id_arr = np.asarray(ids, dtype=np.int64)
        else:
            id_arr = np.asarray([str(i) for i in ids], dtype=str)
        ds["pair_id"] = (("pair",), id_arr, {"long_name": "image pair ids accumulated"})
        for k in _NOISE:
            ds[k] = (dims, getattr(self, k), {"long_name": "accumulator state (noise)"})
        for k, arr, long_name in (
            ("noise_uu", self.noise_uu(), "mean squared uncertainty of u <sigma_u^2>"),
            ("noise_vv", self.noise_vv(), "mean squared uncertainty of v <sigma_v^2>"),
            ("uu_corrected", self.uu_corrected(), "uu - <sigma_u^2> (noise-corrected)"),
            ("vv_corrected", self.vv_corrected(), "vv - <sigma_v^2> (noise-corrected)"),
        ):
            ds[k] = (dims, arr, {"long_name": long_name, "units": stress_units})
        for comp in ("u", "v"):
            sf = self.skewness_flatness(comp)
            ds[f"skewness_{comp}"] = (
                dims,
                sf["S"],
                {"long_name": f"skewness of {comp}", "units": "1"},
            )
            ds[f"flatness_{comp}"] = (
                dims,
                sf["F"],
                {"long_name": f"flatness (kurtosis) of {comp}", "units": "1"},
            )
        for k in _MOMENTS:
            ds[k] = (
                ("order", *dims),
                getattr(self, k),
                {"long_name": "accumulator state (central sums of orders 3-8)"},
            )
        if self.ensemble is not None:
            _ensemble_to_dataset(ds, self.ensemble)
        if self.pixel is not None:
            _pixel_to_dataset(ds, self.pixel)
        if self.two_point is not None:
            variables, tp_attrs = self.two_point.to_dataset_vars()
            for k, val in variables.items():
                ds[k] = val
            ds.attrs.update(tp_attrs)
        for extra in (self.vorticity, self.locking, self.screen, self.rows):
            if extra is not None:
                variables, v_attrs = extra.to_dataset_vars()
                ds = ds.assign(variables)
                ds.attrs.update(v_attrs)
        if x is not None and len(self.shape) == 2:
            ds = ds.assign_coords(x=("x", np.asarray(x, dtype=np.float64)))
        if y is not None and len(self.shape) == 2:
            ds = ds.assign_coords(y=("y", np.asarray(y, dtype=np.float64)))
        ds.attrs.update(
            {
                "title": "rspiv per-vector velocity statistics",
                "Conventions": "CF-1.8",
                "rspiv_accumulator": "FieldAccumulator v1",
                "n_fields": int(self.n_fields),
                "velocity_units": su,
            }
        )
        if attrs:
            ds.attrs.update(attrs)
        return ds

    @classmethod
    def from_xarray(cls, ds) -> FieldAccumulator:
        """Restore an accumulator written by :meth:`to_xarray` (exact round trip)."""
        missing = [k for k in ("count", "u", "v", *_STATE[3:]) if k not in ds]
        if missing:
            raise InvalidInputError(f"dataset: not an rspiv accumulator, missing {missing}")
        acc = cls(ds["count"].shape)
        # copies: the accumulator updates its arrays in place
        acc.count = np.array(ds["count"].values, dtype=np.int64)
        acc.mean_u = np.array(ds["u"].values, dtype=np.float64)
        acc.mean_v = np.array(ds["v"].values, dtype=np.float64)
        for k in _STATE[3:]:
            dtype = np.int64 if k.startswith("lag_count") else np.float64
            setattr(acc, k, np.array(ds[k].values, dtype=dtype))
        if "pair_id" in ds:
            vals = ds["pair_id"].values
            if np.issubdtype(vals.dtype, np.integer):
                acc.pair_ids = {int(i) for i in vals}
            else:
                acc.pair_ids = {str(i) for i in vals}
        acc.n_fields = int(ds.attrs.get("n_fields", 0))
        # states written before the noise sums existed load without noise information
        for k in _NOISE:
            if k in ds:
                dtype = np.int64 if k == "noise_count" else np.float64
                setattr(acc, k, np.array(ds[k].values, dtype=dtype))
        # states written before the higher moments: NaN sums (none known)
        for k in _MOMENTS:
            if k in ds:
                setattr(acc, k, np.array(ds[k].values, dtype=np.float64))
            else:
                setattr(acc, k, np.full((len(moments.ORDERS), *acc.shape), np.nan))
        if "ensemble_sum" in ds:
            acc.ensemble = _ensemble_from_dataset(ds)
        if "pixel_sum" in ds:
            acc.pixel = _pixel_from_dataset(ds)
        if "two_point_count" in ds:
            acc.two_point = TwoPointAccumulator.from_dataset_vars(ds, acc.pair_ids)
        if "vorticity_omega_count" in ds:
            acc.vorticity = VorticityAccumulator.from_dataset_vars(ds, acc.pair_ids)
        if "locking_counts" in ds:
            acc.locking = LockingHistogram.from_dataset_vars(ds, acc.pair_ids)
        if "screened_count" in ds:
            acc.screen = ScreenTally.from_dataset_vars(ds, acc.pair_ids)
        if "row_errors_total" in ds:
            acc.rows = RowErrors.from_dataset_vars(ds, acc.pair_ids)
        return acc

    def __repr__(self) -> str:
        return (
            f"FieldAccumulator(shape={self.shape}, fields={self.n_fields}, "
            f"pairs={len(self.pair_ids)}, max count={int(self.count.max())})"
        )


def _ensemble_to_dataset(ds, ens) -> None:
    """Write an EnsembleAccumulator's state into ``ds`` (variables and attributes
    ``ensemble_*``; :func:`_ensemble_from_dataset` reads them back exactly)."""
    d = ens.to_arrays()
    ds["ensemble_sum"] = (("ensemble_window", "ensemble_value"), d["sum"])
    for k in ("x", "y", "du", "dv"):
        ds[f"ensemble_{k}"] = (("ensemble_window",), np.ravel(d[k]))
    if "field_grid" in d:
        ds["ensemble_field_u"] = (("ensemble_field_y", "ensemble_field_x"), d["field_u"])
        ds["ensemble_field_v"] = (("ensemble_field_y", "ensemble_field_x"), d["field_v"])
        ds.attrs["ensemble_field_grid"] = [float(t) for t in d["field_grid"]]
    ds.attrs["ensemble_shape"] = [int(t) for t in np.shape(d["x"])]
    ds.attrs["ensemble_window_px"] = [int(t) for t in d["window"]]
    ds.attrs["ensemble_pairs"] = int(d["pairs"])
    ds.attrs["ensemble_interpolation"] = str(d["interpolation"])
    ds["ensemble_saturated"] = (("ensemble_window",), np.ravel(d["saturated"]))
    ds.attrs["ensemble_saturation_pairs"] = int(d["saturation_pairs"])


def _ensemble_from_dataset(ds):
    from rspiv.ensemble import EnsembleAccumulator  # deferred: ensemble imports the extension

    shape = tuple(int(t) for t in np.ravel(ds.attrs["ensemble_shape"]))
    d: dict[str, Any] = {
        "sum": ds["ensemble_sum"].values,
        "window": np.ravel(ds.attrs["ensemble_window_px"]),
        "pairs": int(ds.attrs["ensemble_pairs"]),
        "interpolation": str(ds.attrs["ensemble_interpolation"]),
    }
    for k in ("x", "y", "du", "dv"):
        d[k] = np.asarray(ds[f"ensemble_{k}"].values, dtype=np.float64).reshape(shape)
    if "ensemble_saturated" in ds:
        d["saturated"] = np.asarray(ds["ensemble_saturated"].values, dtype=np.float64)
        d["saturation_pairs"] = int(ds.attrs["ensemble_saturation_pairs"])
    if "ensemble_field_u" in ds:
        d["field_grid"] = np.ravel(ds.attrs["ensemble_field_grid"])
        d["field_u"] = np.ascontiguousarray(ds["ensemble_field_u"].values, dtype=np.float64)
        d["field_v"] = np.ascontiguousarray(ds["ensemble_field_v"].values, dtype=np.float64)
    return EnsembleAccumulator.from_arrays(d)


__all__ = ["FieldAccumulator"]


def _pixel_to_dataset(ds, pix) -> None:
    """Write a PixelAccumulator's state into ``ds`` (variables and attributes ``pixel_*``;
    :func:`_pixel_from_dataset` reads them back exactly)."""
    d = pix.to_arrays()
    ds["pixel_sum"] = (("pixel_row", "pixel_value"), d["sum"])
    for k in ("y", "du", "dv"):
        ds[f"pixel_{k}"] = (("pixel_row", "pixel_segment"), d[k])
    if "wall_side" in d:
        ds["pixel_wall_x"] = (("pixel_wall_column",), d["wall_x"])
        ds["pixel_wall_y"] = (("pixel_wall_column",), d["wall_y"])
        ds.attrs["pixel_wall_side"] = str(d["wall_side"])
    ds.attrs["pixel_seg"] = int(d["seg"])
    ds.attrs["pixel_x0"] = float(d["x0"])
    ds.attrs["pixel_lags"] = [int(t) for t in d["lags"]]
    ds.attrs["pixel_pairs"] = int(d["pairs"])
    ds.attrs["pixel_interpolation"] = str(d["interpolation"])
    ds["pixel_saturated"] = (("pixel_row",), d["saturated"])
    ds.attrs["pixel_saturation_pairs"] = int(d["saturation_pairs"])


def _pixel_from_dataset(ds):
    from rspiv.ensemble import PixelAccumulator  # deferred: ensemble imports the extension

    d: dict[str, Any] = {
        "sum": ds["pixel_sum"].values,
        "seg": int(ds.attrs["pixel_seg"]),
        "x0": float(ds.attrs["pixel_x0"]),
        "lags": np.ravel(ds.attrs["pixel_lags"]),
        "pairs": int(ds.attrs["pixel_pairs"]),
        "interpolation": str(ds.attrs["pixel_interpolation"]),
    }
    for k in ("y", "du", "dv"):
        d[k] = np.ascontiguousarray(ds[f"pixel_{k}"].values, dtype=np.float64)
    if "pixel_saturated" in ds:
        d["saturated"] = np.asarray(ds["pixel_saturated"].values, dtype=np.float64)
        d["saturation_pairs"] = int(ds.attrs["pixel_saturation_pairs"])
    if "pixel_wall_x" in ds:
        d["wall_side"] = str(ds.attrs["pixel_wall_side"])
        d["wall_x"] = np.asarray(ds["pixel_wall_x"].values, dtype=np.float64)
        d["wall_y"] = np.asarray(ds["pixel_wall_y"].values, dtype=np.float64)
    return PixelAccumulator.from_arrays(d)
