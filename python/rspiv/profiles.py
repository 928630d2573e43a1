"""Wall-normal profiles from per-vector statistics: the count-weighted average along the
streamwise direction of a statistics grid (:func:`average_along_x`), and of a
:class:`~rspiv.stats.FieldAccumulator` with its effective sample counts and noise
(:func:`profile_from_accumulator`), the input of :func:`rspiv.boundary_layer.analyse_profile`.
Units are those of the statistics (px or SI); the profile runs along the remaining axis.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from rspiv import moments
from rspiv.errors import InvalidInputError

__all__ = ["average_along_x", "profile_from_accumulator"]


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
