"""Wall-normal profiles from per-vector statistics: the count-weighted average along the
streamwise direction of a statistics grid (:func:`average_along_x`), and of a
:class:`~rspiv.stats.FieldAccumulator` with its effective sample counts and noise
(:func:`profile_from_accumulator`), the input of :func:`rspiv.boundary_layer.analyse_profile`.
Units are those of the statistics (px or SI); the profile runs along the remaining axis.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import numpy as np

from rspiv import moments
from rspiv.errors import InvalidInputError
from rspiv.stats import FieldAccumulator

__all__ = [
    "MOMENT_KEYS",
    "PAIR_ERROR_KEYS",
    "VERDICT_PAIRS",
    "average_along_x",
    "judged_error",
    "judged_errors",
    "pair_error_columns",
    "pair_error_summary",
    "pair_errors",
    "pair_errors_in_wall_units",
    "pair_rows",
    "profile_from_accumulator",
    "scaled_accumulator",
]


def average_along_x(
    mean_u, mean_v, uu, vv, uv, count, n_eff=None, axis: int = -1, min_count: int = 2
):
    """Average per-vector statistics along the streamwise axis into wall-normal profiles.

    Means and stresses are count-weighted averages of the per-vector values (the stresses are
    not pooled with the spread of the means, which would add the streamwise growth of the
    layer). The profile's sample count is the sum of counts; its n_eff is the count-weighted
    mean of the per-vector n_eff (vectors in one field are taken as fully correlated, a
    conservative choice). Vectors with count < ``min_count`` (at least 2) are skipped.

    Parameters
    ----------
    n_eff : array_like or mapping, optional
        Per-vector n_eff, or a mapping of them (e.g.
        :meth:`~rspiv.stats.FieldAccumulator.n_eff_all`); the output's ``n_eff`` has the
        same form.

    Returns
    -------
    dict
        ``U, V, uu, vv, uv, count, n_eff`` as 1D arrays along the remaining axis.
    """
    arrs = [np.asarray(a, dtype=np.float64) for a in (mean_u, mean_v, uu, vv, uv)]
    cnt = np.asarray(count, dtype=np.float64)
    for name, a in zip(("mean_v", "uu", "vv", "uv"), arrs[1:], strict=True):
        if a.shape != arrs[0].shape:
            raise InvalidInputError(f"{name}: shape {a.shape} differs from mean_u {arrs[0].shape}")
    if cnt.shape != arrs[0].shape or arrs[0].ndim != 2:
        raise InvalidInputError(f"count: expected 2D shape {arrs[0].shape}, got {cnt.shape}")
    w = np.where(
        (cnt >= max(int(min_count), 2)) & np.all([np.isfinite(a) for a in arrs], axis=0), cnt, 0.0
    )
    wsum = w.sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = {
            k: np.where(wsum > 0, (w * np.nan_to_num(a)).sum(axis=axis) / wsum, np.nan)
            for k, a in zip(("U", "V", "uu", "vv", "uv"), arrs, strict=True)
        }
        out["count"] = w.sum(axis=axis)

        def avg(a):
            a = np.asarray(a, dtype=np.float64)
            if a.shape != w.shape:
                raise InvalidInputError(f"n_eff: expected shape {w.shape}, got {a.shape}")
            return np.where(wsum > 0, (w * np.nan_to_num(a)).sum(axis=axis) / wsum, np.nan)

        if n_eff is None:
            out["n_eff"] = np.full(wsum.shape, np.nan)
        elif isinstance(n_eff, Mapping):
            out["n_eff"] = {k: avg(v) for k, v in n_eff.items()}
        else:
            out["n_eff"] = avg(n_eff)
    return out


def profile_from_accumulator(acc, *, min_count: int = 2, axis: int = -1) -> dict:
    """:func:`average_along_x` of a 2D :class:`~rspiv.stats.FieldAccumulator` with its
    per-quantity n_eff (:meth:`~rspiv.stats.FieldAccumulator.n_eff_all`).

    The result's ``U, uu, vv, uv`` and ``n_eff`` go straight into :func:`analyse_profile`.
    It also holds ``noise_uu``, ``noise_vv``: the count-weighted averages along x of the
    per-vector mean squared uncertainties (:meth:`~rspiv.stats.FieldAccumulator.noise_uu`; NaN
    where no uncertainties were accumulated), the variance the measurement noise adds to
    ``uu`` and ``vv``, and ``eps_noise_uu``, ``eps_noise_vv``, their standard errors (the
    ``noise`` of :func:`analyse_profile`).

    The skewness and flatness of u and v: ``S_u, F_u, eps_S_u, eps_F_u`` (and ``_v``) from the
    count-weighted averages along x of the per-vector central moments ``mu_2 .. mu_8``
    (:meth:`~rspiv.stats.FieldAccumulator.central_moments`; like the stresses, not pooled with
    the spread of the means), their errors with the profile's n_eff of the mean
    (:func:`rspiv.moments.skewness_flatness`), and ``S_u_c, F_u_c`` (``_v``) without the
    measurement noise (:func:`rspiv.moments.noise_corrected`; NaN without uncertainties).
    """
    if len(acc.shape) != 2:
        raise InvalidInputError(f"acc: expected a 2D accumulator, got shape {acc.shape}")
    out = average_along_x(
        acc.mean_u,
        acc.mean_v,
        acc.uu,
        acc.vv,
        acc.uv,
        acc.count,
        n_eff=acc.n_eff_all(),
        axis=axis,
        min_count=min_count,
    )
    keep = np.asarray(acc.count) >= max(int(min_count), 2)
    cnt = np.asarray(acc.count, dtype=np.float64)

    def along_x(a, ok):
        """Count-weighted average along x of ``a`` (leading axes kept) where ``ok``."""
        w = np.where(keep & ok, cnt, 0.0)
        wsum = w.sum(axis=axis)
        ax = axis if axis < 0 else axis + a.ndim - w.ndim
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(wsum > 0, (w * np.nan_to_num(a)).sum(axis=ax) / wsum, np.nan)

    for key, noise in (
        ("noise_uu", acc.noise_uu()),
        ("noise_vv", acc.noise_vv()),
        # per-vector standard errors averaged alike (taken as fully correlated: conservative)
        ("eps_noise_uu", acc.noise_uncertainty("u")),
        ("eps_noise_vv", acc.noise_uncertainty("v")),
    ):
        out[key] = along_x(noise, np.isfinite(noise))
    for comp in ("u", "v"):
        mu = acc.central_moments(comp)  # orders 2-8 lead
        avg = along_x(mu, np.all(np.isfinite(mu), axis=0))
        noise4 = acc.noise_sigma4(comp)
        s4 = along_x(noise4, np.isfinite(noise4))
        sf = moments.skewness_flatness(avg, out["n_eff"][comp.upper()])
        for key in ("S", "F", "eps_S", "eps_F"):
            out[f"{key}_{comp}"] = sf[key]
        s_c, f_c = moments.noise_corrected(avg[0], avg[1], avg[2], out[f"noise_{comp * 2}"], s4)
        out[f"S_{comp}_c"], out[f"F_{comp}_c"] = s_c, f_c
    return out


def pair_errors(acc, k: float = 1.0) -> dict[str, np.ndarray] | None:
    """The standard errors of the profile's rows from the scatter between pairs
    (:class:`rspiv.row_errors.RowErrors` attached to ``acc`` as ``acc.rows``): ``U``, ``V``,
    ``uu``, ``vv``, ``uv`` (each row's), in the units of ``acc`` times ``k`` (``k^2`` for the
    stresses), the skewness and flatness's ``S_u``, ``F_u``, ``S_v``, ``F_v`` (none from sums
    written before them), and ``pairs``; ``replicates``, the rows' mean u times ``k`` with one
    batch of pairs left out in each (:meth:`rspiv.row_errors.RowErrors.replicates`; none
    before 8 batches hold pairs), ``serial_U``, each row's ``n_eff / n`` of u, and
    ``open_U`` (True where that is an upper bound: the pairs' correlation not yet seen to end);
    ``serial`` and ``serial_lag1``, per statistic the ``n_eff / n`` applied and the per-vector
    one alone; ``lag_max``, the lags the rows' factor followed (states written since the lags).
    Pairs that follow each other in time (a time-resolved recording) are not independent: each
    variance is divided by the smaller of two ``n_eff / n``: the row's mean of the per-vector
    statistics' (:meth:`rspiv.stats.FieldAccumulator.n_eff`, lag 1 only) and the inverse of
    the rows' own serial factor over up to 32 lags (:meth:`rspiv.row_errors.RowErrors.serial`;
    U's for S and F of u, V's for those of v); 1 for independent pairs. None when ``acc``
    carries no such sums, or sums of other pairs than its own (a state resumed from before they
    existed).
    """
    rows = getattr(acc, "rows", None)
    if rows is None or rows.pair_ids != acc.pair_ids or rows.n_fields != acc.n_fields:
        return None
    res = rows.result()
    cnt = np.asarray(acc.count, dtype=np.float64)
    csum = cnt.sum(axis=-1)
    out: dict[str, np.ndarray] = {"pairs": res["pairs"]}
    with np.errstate(invalid="ignore", divide="ignore"):
        for key, q, power in (("U", "u", 1), ("V", "v", 1), ("uu", "uu", 2), ("vv", "vv", 2),
                              ("uv", "uv", 2), ("S_u", "u", 0), ("F_u", "u", 0),
                              ("S_v", "v", 0), ("F_v", "v", 0)):  # fmt: skip
            if f"se_{key}" not in res:
                continue
            serial = np.nansum(np.asarray(acc.n_eff(q), dtype=np.float64), axis=-1) / csum
            serial = np.where(serial > 0, np.minimum(serial, 1.0), 1.0)
            out.setdefault("serial_lag1", {})[key] = serial
            own = f"serial_{'UV'[q == 'v'] if power == 0 else key}"
            if own in res:  # the rows' own serial factor (states written since the lags)
                serial = np.minimum(serial, 1.0 / np.where(res[own] >= 1, res[own], 1.0))
            out.setdefault("serial", {})[key] = serial
            out[key] = res[f"se_{key}"] / np.sqrt(serial) * abs(k) ** power
            if key == "U":
                out["serial_U"] = serial
                out["open_U"] = res.get("open_U", np.zeros(serial.shape, dtype=bool))
                if "lag_max" in res:
                    out["lag_max"] = res["lag_max"]
    reps = rows.replicates()
    if reps is not None:  # the rows' mean u, one batch of pairs left out in each (times k)
        out["replicates"] = reps * k
    return out


#: The fewest pairs in a row for its scatter between pairs (``eps_U_plus_pairs`` ...) to give
#: its error, in the verdicts against a reference (:mod:`rspiv.reference_comparison`), the
#: profile figures' error bars and the report's uncertainties; with fewer the bound
#: (``eps_U_plus`` ...) serves: the scatter of fewer pairs is uncertain by more than a sixth.
VERDICT_PAIRS = 20


def pair_rows(own, pairs) -> np.ndarray:
    """The rows whose scatter between pairs ``own`` gives their error: those of
    :data:`VERDICT_PAIRS` pairs or more where ``own`` is finite (all False without them)."""
    if own is None or pairs is None:
        return np.zeros(np.shape(own if pairs is None else pairs), dtype=bool)
    own = np.asarray(own, dtype=np.float64)
    return (np.asarray(pairs, dtype=np.float64) >= VERDICT_PAIRS) & np.isfinite(own)


def judged_error(bound, own, pairs) -> np.ndarray:
    """A profile's error per row: ``own`` (its scatter between pairs) in the rows of
    :func:`pair_rows`, else ``bound`` (the vectors of a field taken as fully correlated along
    the wall). Arrays of one length, any units."""
    bound = np.asarray(bound, dtype=np.float64)
    if own is None or pairs is None:
        return bound
    return np.where(pair_rows(own, pairs), np.asarray(own, dtype=np.float64), bound)


def judged_errors(result) -> tuple[dict[str, np.ndarray], str]:
    """The errors a :class:`rspiv.boundary_layer.BoundaryLayerResult` is judged and drawn by:
    ``{"eps_u_plus", "eps_uu_plus", "eps_vv_plus", "eps_uv_plus"}`` (wall units) from
    :func:`judged_error`, and ``"pairs"`` when any row took its scatter between pairs, else
    ``"bound"``. A result without its rows' errors gives the bound."""
    extra = getattr(result, "extra", None) or {}
    pairs = extra.get("pairs")
    out, used = {}, False
    for key in PAIR_ERROR_KEYS:
        bound = np.asarray(getattr(result, f"eps_{key.lower()}_plus"), dtype=np.float64)
        own = extra.get(f"eps_{key}_plus_pairs")
        out[f"eps_{key.lower()}_plus"] = judged_error(bound, own, pairs)
        used |= bool(pair_rows(own, pairs).any())
    return out, "pairs" if used else "bound"


#: The statistics whose pair-to-pair errors a profile carries in wall units
#: (``eps_U_plus_pairs``, ``eps_uu_plus_pairs`` ...: :func:`pair_errors_in_wall_units`).
PAIR_ERROR_KEYS = ("U", "uu", "vv", "uv")
#: The skewness and flatness whose pair-to-pair errors a profile carries (``eps_S_u_pairs``
#: ..., beside the bound ``eps_S_u`` ... of :func:`profile_from_accumulator`).
MOMENT_KEYS = ("S_u", "F_u", "S_v", "F_v")


def pair_error_columns(pe: dict, ok: np.ndarray, noise=None) -> dict[str, np.ndarray]:
    """:func:`pair_errors` at the profile's points ``ok`` as columns for
    :func:`rspiv.boundary_layer.analyse_profile`'s ``extra`` (in the profile's units until
    :func:`pair_errors_in_wall_units`), ``pairs``, and ``eps_S_u_pairs`` ... (no units).
    ``noise``: the ``noise`` given to ``analyse_profile`` (the normal stresses noise-corrected):
    its standard errors of the mean squared uncertainty are added in quadrature, as to the
    profile's own ``eps_uu``."""
    out = {f"_pair_se_{k}": np.asarray(pe[k], dtype=np.float64)[ok] for k in PAIR_ERROR_KEYS}
    if noise is not None:
        out["_pair_se_uu"] = np.hypot(out["_pair_se_uu"], noise[2])
        out["_pair_se_vv"] = np.hypot(out["_pair_se_vv"], noise[3])
    out["pairs"] = np.asarray(pe["pairs"], dtype=np.float64)[ok]
    for key in MOMENT_KEYS:  # no units: the columns as they stay
        if key in pe:
            out[f"eps_{key}_pairs"] = np.asarray(pe[key], dtype=np.float64)[ok]
    return out


def pair_errors_in_wall_units(extra: dict, u_tau: float) -> None:
    """Turn :func:`pair_error_columns` in ``extra`` (a profile's, sorted with it) into wall
    units of ``u_tau`` in place: ``eps_U_plus_pairs`` (``/ u_tau``), ``eps_uu_plus_pairs``,
    ``eps_vv_plus_pairs``, ``eps_uv_plus_pairs`` (``/ u_tau^2``)."""
    for key in PAIR_ERROR_KEYS:
        a = extra.pop(f"_pair_se_{key}", None)
        if a is not None:
            extra[f"eps_{key}_plus_pairs"] = a / u_tau ** (1 if key == "U" else 2)


def pair_error_summary(result) -> dict[str, float] | None:
    """``summary.json``'s ``profile_errors`` of a run's
    :class:`rspiv.boundary_layer.BoundaryLayerResult`: per statistic the median over the
    profile's points of its conservative error (``eps_U_plus`` ...) over its error from pair
    to pair (``eps_U_plus_pairs`` ...): how many times the profile's error bars overstate the
    scatter of its rows (``overstated_U`` ..., and ``overstated_S_u`` ... of the skewness and
    flatness where their sums were kept); and the fewest pairs in a row. None without them."""
    extra = result.extra
    if "eps_U_plus_pairs" not in extra:
        return None
    out = {}
    for key in PAIR_ERROR_KEYS:
        conservative = np.asarray(getattr(result, f"eps_{key.lower()}_plus"), dtype=np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = conservative / extra[f"eps_{key}_plus_pairs"]
        r = r[np.isfinite(r)]
        out[f"overstated_{key}"] = float(np.median(r)) if r.size else float("nan")
    for key in MOMENT_KEYS:  # the skewness and flatness, where the sums had their powers
        if f"eps_{key}_pairs" in extra and f"eps_{key}" in extra:
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.asarray(extra[f"eps_{key}"]) / np.asarray(extra[f"eps_{key}_pairs"])
            r = r[np.isfinite(r)]
            out[f"overstated_{key}"] = float(np.median(r)) if r.size else float("nan")
    pairs = np.asarray(extra["pairs"], dtype=np.float64)
    out["pairs_min"] = float(np.nanmin(pairs)) if np.isfinite(pairs).any() else 0.0
    return out


def scaled_accumulator(
    acc: FieldAccumulator, k: float, sign_u: float = 1.0, sign_v: float = 1.0
) -> FieldAccumulator:
    """A copy of ``acc`` with u scaled by ``k * sign_u`` and v by ``k * sign_v`` (unit change
    and axis flips; every moment of the state transforms exactly)."""
    # not the ensemble's sums, nor the rows' pair sums (their errors come from the unscaled
    # accumulator: :func:`pair_errors`, scaled there)
    attached = (acc.ensemble, acc.pixel, acc.two_point, acc.vorticity, getattr(acc, "rows", None))
    out = copy.deepcopy(acc, memo={id(a): None for a in attached})
    ku, kv = k * sign_u, k * sign_v
    out.mean_u = acc.mean_u * ku
    out.mean_v = acc.mean_v * kv
    out.m2_uu = acc.m2_uu * ku * ku
    out.m2_vv = acc.m2_vv * kv * kv
    out.c_uv = acc.c_uv * ku * kv
    for comp, kk in (("u", ku), ("v", kv)):
        for part in ("a", "b"):
            name = f"lag_mean_{part}_{comp}"
            setattr(out, name, getattr(acc, name) * kk)
        setattr(out, f"lag_c_{comp}", getattr(acc, f"lag_c_{comp}") * kk * kk)
    # the noise sums: sigma^2 scales by k^2, sigma^4 by k^4 (the signs do not enter)
    out.noise_s_uu = acc.noise_s_uu * k**2
    out.noise_s_vv = acc.noise_s_vv * k**2
    out.noise_s2_uu = acc.noise_s2_uu * k**4
    out.noise_s2_vv = acc.noise_s2_vv * k**4
    # the central sums of orders 3-8: M_p by k^p (with the sign)
    out.hm_u = moments.scale(acc.hm_u, ku)
    out.hm_v = moments.scale(acc.hm_v, kv)
    return out
