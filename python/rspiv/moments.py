"""Higher-order moments of velocity samples: skewness and flatness, their standard errors and
their correction for the measurement noise.

Per vector, :class:`rspiv.stats.FieldAccumulator` keeps the central sums ``M_p = sum (x -
mean)^p`` of orders 2 to 8 (``M_2`` is its ``m2_uu``; this module's arrays hold ``M_3 .. M_8``,
shape ``(6, *grid)``), updated one field at a time and merged exactly (Pébay 2008, "Formulas
for robust, one-pass parallel computation of covariances and arbitrary-order statistical
moments", Sandia report SAND2008-6212). The central moments are ``mu_p = M_p / n`` (population
moments, as for scipy's ``skew`` and ``kurtosis(fisher=False)`` with ``bias=True``).

Skewness and flatness
    ``S = mu_3 / mu_2^(3/2)`` and ``F = mu_4 / mu_2^2`` (flatness, the kurtosis; 3 for a
    Gaussian). Dimensionless, so the same in px and in wall units.

Standard errors
    The asymptotic variances of the sample skewness and flatness for any distribution (the delta
    method on the moments' influence functions; ``d = x - mean``):

    - ``n var(S) = E[I3^2] / mu2^3 - 3 mu3 E[I3 I2] / mu2^4 + 9/4 mu3^2 E[I2^2] / mu2^5``,
    - ``n var(F) = E[I4^2] / mu2^4 - 4 mu4 E[I4 I2] / mu2^5 + 4 mu4^2 E[I2^2] / mu2^6``,

    with ``E[I2^2] = mu4 - mu2^2``, ``E[I3^2] = mu6 - mu3^2 - 6 mu2 mu4 + 9 mu2^3``, ``E[I3 I2]
    = mu5 - 4 mu2 mu3``, ``E[I4^2] = mu8 - mu4^2 - 8 mu3 mu5 + 16 mu3^2 mu2`` and ``E[I4 I2] =
    mu6 - mu2 mu4 - 4 mu3^2``. For a Gaussian they are 6 / n and 24 / n; near a wall, where the
    streamwise fluctuations are skewed and heavy-tailed, several times more. That is why orders
    5 to 8 are kept. ``n`` is the effective number of independent samples (the caller's: the
    campaign takes that of the mean, :meth:`rspiv.stats.FieldAccumulator.n_eff`, which is the
    smallest of any moment's for correlated samples).

Measurement noise
    A vector's error ``e`` (zero mean, symmetric, independent of the flow, standard uncertainty
    ``sigma`` varying from vector to vector) adds ``<sigma^2>`` to ``mu_2``, nothing to ``mu_3``
    and ``6 <sigma^2> mu_2 + 3 <sigma^4>`` to ``mu_4`` (Gaussian errors: ``E[e^4] = 3
    sigma^4``). :func:`noise_corrected` removes them: ``mu2_c = mu2 - <sigma^2>``, ``mu4_c = mu4 -
    6 <sigma^2> mu2_c - 3 <sigma^4>``; NaN where ``mu2_c <= 0`` (the noise holds all the variance).
    The noise lowers ``|S|`` and draws ``F`` towards 3; spurious vectors that pass the validation
    raise ``F`` far above, which no correction removes.
"""

from __future__ import annotations

from math import comb

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

#: Orders of the central sums kept beside ``M_2`` (``M_3 .. M_8``).
ORDERS = tuple(range(3, 9))

__all__ = [
    "ORDERS",
    "add_sample",
    "merge",
    "scale",
    "skewness_flatness",
    "noise_corrected",
]


def _sums(m2, hm) -> list:
    """``[None, None, M_2, M_3, ..., M_8]``, indexed by order."""
    return [None, None, m2, *hm]


def add_sample(hm: np.ndarray, m2, n_old, delta) -> None:
    """Update ``hm`` (``M_3 .. M_8``, shape ``(6, *grid)``, C-contiguous float64) in place for
    one more sample per position (in Rust: ``piv_core::moments``).

    ``m2`` and ``n_old`` are ``M_2`` and the count before this sample, ``delta`` the sample
    minus the mean before it (0 where no sample is added: nothing changes there). Every order's
    increment is taken from the sums before the update:
    ``M_p += sum_{k=1}^{p-2} C(p, k) M_{p-k} (-r)^k + r^p (na^p + (-1)^p na)``, ``r = delta / n``,
    ``na = n_old``, ``n = na + 1`` (Pébay's merge with a one-sample set).
    """
    _rspiv.moments_add(
        hm.reshape(len(ORDERS), -1),
        np.ascontiguousarray(m2, dtype=np.float64).reshape(-1),
        np.ascontiguousarray(n_old, dtype=np.int64).reshape(-1),
        np.ascontiguousarray(delta, dtype=np.float64).reshape(-1),
    )


def merge(hm_a, m2_a, n_a, hm_b, m2_b, n_b, delta) -> np.ndarray:
    """``M_3 .. M_8`` of two sample sets together (Pébay 2008, eq. 3.1).

    ``delta`` is mean_b - mean_a; ``m2_*`` the sets' ``M_2`` before the merge. Exact (to
    rounding) in any split: the result equals one pass over all the samples.
    """
    na = np.asarray(n_a, dtype=np.float64)
    nb = np.asarray(n_b, dtype=np.float64)
    n = na + nb
    with np.errstate(invalid="ignore", divide="ignore"):
        fa = np.where(n > 0, na / np.where(n > 0, n, 1.0), 0.0)
        fb = np.where(n > 0, nb / np.where(n > 0, n, 1.0), 0.0)
    d = np.where(n > 0, delta, 0.0)
    sa, sb = _sums(m2_a, hm_a), _sums(m2_b, hm_b)
    out = np.empty_like(np.asarray(hm_a, dtype=np.float64))
    for i, p in enumerate(ORDERS):
        acc = sa[p] + sb[p]
        for k in range(1, p - 1):
            acc = acc + comb(p, k) * ((-fb) ** k * sa[p - k] + fa**k * sb[p - k]) * d**k
        # (na nb d / n)^p (1 / nb^(p-1) - (-1 / na)^(p-1)) = d^p (fa^p nb + (-1)^p fb^p na),
        # safe where either set is empty
        acc = acc + d**p * (fa**p * nb + (-1) ** p * fb**p * na)
        out[i] = acc
    return out


def scale(hm: np.ndarray, k: float) -> np.ndarray:
    """``M_3 .. M_8`` of the samples times ``k`` (a unit change or a sign flip): ``M_p k^p``."""
    return np.stack([hm[i] * k**p for i, p in enumerate(ORDERS)])


def skewness_flatness(mu, n_eff=None) -> dict[str, np.ndarray]:
    """Skewness, flatness and their standard errors from central moments.

    Parameters
    ----------
    mu : sequence of arrays
        ``mu_2, mu_3, ..., mu_8`` (7 arrays of one shape; population central moments).
    n_eff : array_like, optional
        Effective number of independent samples; without it the errors are NaN.

    Returns
    -------
    dict
        ``S``, ``F``, ``eps_S``, ``eps_F`` (NaN where ``mu_2 <= 0`` or not finite).
    """
    if len(mu) != 7:
        raise InvalidInputError(f"mu: expected the central moments of orders 2-8, got {len(mu)}")
    m2, m3, m4, m5, m6, _, m8 = (np.asarray(a, dtype=np.float64) for a in mu)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ok = np.isfinite(m2) & (m2 > 0)
        v = np.where(ok, m2, np.nan)
        S = m3 / v**1.5
        F = m4 / v**2
        i22 = m4 - v**2
        i33 = m6 - m3**2 - 6 * v * m4 + 9 * v**3
        i32 = m5 - 4 * v * m3
        i44 = m8 - m4**2 - 8 * m3 * m5 + 16 * m3**2 * v
        i42 = m6 - v * m4 - 4 * m3**2
        var_s = i33 / v**3 - 3 * m3 * i32 / v**4 + 2.25 * m3**2 * i22 / v**5
        var_f = i44 / v**4 - 4 * m4 * i42 / v**5 + 4 * m4**2 * i22 / v**6
        if n_eff is None:
            eps_s = eps_f = np.full(np.shape(S), np.nan)
        else:
            ne = np.asarray(n_eff, dtype=np.float64)
            ne = np.where(ne > 0, ne, np.nan)
            eps_s = np.sqrt(np.maximum(var_s, 0.0) / ne)
            eps_f = np.sqrt(np.maximum(var_f, 0.0) / ne)
    return {"S": S, "F": F, "eps_S": eps_s, "eps_F": eps_f}


def noise_corrected(mu2, mu3, mu4, noise2, noise4) -> tuple[np.ndarray, np.ndarray]:
    """Skewness and flatness without the measurement noise (module docstring).

    ``noise2`` and ``noise4`` are the mean ``<sigma^2>`` and ``<sigma^4>`` of the vectors'
    standard uncertainties (NaN: no uncertainty known, the result is NaN). Returns ``(S_c,
    F_c)``, NaN where the noise holds all the variance.
    """
    mu2, mu3, mu4, s2, s4 = (
        np.asarray(a, dtype=np.float64) for a in (mu2, mu3, mu4, noise2, noise4)
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        v = mu2 - s2
        v = np.where(v > 0, v, np.nan)
        m4c = mu4 - 6 * s2 * v - 3 * s4
        return mu3 / v**1.5, m4c / v**2
