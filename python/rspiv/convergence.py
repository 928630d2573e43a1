"""How a run's profile converges with its pairs, and whether its first pairs and its last agree.

A campaign's statistics are means over its pairs; a reader of its profile asks two things of
them that the error bars do not answer.

**Convergence.** The rows' pooled mean ``U`` and stresses ``uu``, ``vv``, ``uv`` of the pairs
numbered below 10, 20, 50, 100, 200, 500 ... (:data:`rspiv.row_errors.HISTORY_EDGES`, the
bands :class:`rspiv.row_errors.RowErrors` keeps), beside the whole run's, and the distance by
which each prefix of ``n`` of the run's ``N`` pairs should stray from the whole run's value if
the pairs were independent draws of one flow: ``sigma_1 sqrt(1/n - 1/N)``, ``sigma_1`` one
pair's scatter in the row (the rows' errors from pair to pair, :func:`rspiv.profiles.
pair_errors`, times ``sqrt(pairs)``; divided there by the serial correlation of a time-resolved
recording). A figure of the prefixes' relative departures at a few heights against that band
is the convergence plot a paper shows.

**Stationarity.** Pairs recorded over hours see the tunnel warm up, the seeding thin out, the
laser's energy drift; a camera's frames can shift. A drift of the mean speed is seen pair by
pair (:mod:`rspiv.campaign.pair_quality`), one of the turbulence is not: the stresses are
averages over the change and look as converged as any. The run's pairs are split at the edge
that parts them most evenly (the pairs numbered below it, "the first", and the rest), and per
row each statistic's difference between the two is held against its standard error, ``sigma_1
sqrt(1/n_1 + 1/n_2)``: ``z`` (``sigma_1`` here the scatter within the parts: the whole run's
sum of squares less the parts' difference's share, ``n_1 n_2 / N d^2``, over ``N - 2``; a
change would otherwise widen the scatter it is held against). For pairs of one flow ``z`` is a
standard normal deviate per row (the rows correlated with each other: they share their pairs
and the flow's structures); where more than :data:`DRIFT_SHARE` of the rows judged have ``|z|``
above :data:`DRIFT_SIGMAS` (a chance of 6e-5 per row), the run is said to change between its
first pairs and its last. Rows judged: on the flow's side of the wall, not flagged
``near_wall`` (:func:`rspiv.campaign.analysis.profile_extra`), with
:data:`rspiv.profiles.VERDICT_PAIRS` pairs or more.

**Pairs too close in time.** The errors of a time-resolved run take the pairs' serial
correlation from the rows' own means over up to 32 lags (:meth:`rspiv.row_errors.RowErrors.
serial`); where the lags a run's length allows (a quarter of its pairs) fall short of five of
the rows' correlation times, the errors and the bands are lower bounds. Where more than
:data:`DRIFT_SHARE` of the rows judged are so, the run says it (``serial_warning``), with the
median factor on the variance of U and the cure: a longer recording where the run's length
limits the lags, pairs spaced further apart in time where the 32 lags kept do. The split's test
takes the correlation within its two parts (a change between them is, to the whole run's
autocovariances, a correlation that lasts the run, and would hide itself): each lag's
autocovariance less the parts' difference's share; where it says the run changes, that is said
instead of the serial warning.

Units: the profile's (m/s and m^2/s^2 in SI, px per pair otherwise), relative departures as
fractions of the whole run's value.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.profiles import VERDICT_PAIRS, pair_errors
from rspiv.row_errors import LAGS, RowErrors, lag_factor

__all__ = [
    "DRIFT_SHARE",
    "DRIFT_SIGMAS",
    "MIN_HALF_PAIRS",
    "MIN_PREFIX_PAIRS",
    "REPORT_TEXT",
    "STATISTICS",
    "Convergence",
    "pooled",
    "profile_convergence",
    "profile_rows",
    "run_convergence",
]

#: The statistics followed (the profile's names).
STATISTICS = ("U", "uu", "vv", "uv")
#: Prefixes of fewer pairs are not shown (a mean of a few pairs says little of convergence).
MIN_PREFIX_PAIRS = 5
#: Each part of the stationarity test holds at least this many pairs, else no test.
MIN_HALF_PAIRS = 10
#: A row's statistic differs between the two parts where ``|z|`` exceeds this ...
DRIFT_SIGMAS = 4.0
#: ... and the run is said to change where more than this share of the rows judged do.
DRIFT_SHARE = 0.25
#: Fewer rows judged than this: no stationarity verdict.
MIN_ROWS = 3

#: The report's words on the figure and the test.
REPORT_TEXT = (
    "Each run's mean velocity and stresses over the pairs numbered below 10, 20, 50 ... "
    "against the whole run's, at a few heights, with the band (two standard deviations) "
    "within which the first n pairs of one flow stray from it (the pairs' scatter, "
    "sigma_1 sqrt(1/n - 1/N)). The run's pairs split in two near half way: where more than a "
    "quarter of the rows judged differ between the parts by more than four standard errors, "
    "the flow or the recording changed over the run, or its pairs span too few of the flow's "
    "largest scales, and the statistics average over it."
)


def pooled(sums: np.ndarray) -> dict[str, np.ndarray]:
    """The rows' pooled count, means ``U``, ``V`` and (co)variances ``uu``, ``vv``, ``uv``
    about them from the history's six sums (rows x 6: count, u, v, u^2, v^2, u v about zero;
    NaN in a row without vectors)."""
    s = np.asarray(sums, dtype=np.float64)
    n = s[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        m = s / np.where(n > 0, n, np.nan)[:, None]
    U, V = m[:, 1], m[:, 2]
    return {"count": n, "U": U, "V": V, "uu": m[:, 3] - U * U, "vv": m[:, 4] - V * V,
            "uv": m[:, 5] - U * V}  # fmt: skip


@dataclasses.dataclass
class Convergence:
    """A run's prefixes and its stationarity test (module docstring).

    Attributes
    ----------
    pairs : ndarray of int, shape (P,)
        Pairs in each prefix, the whole run's last.
    values : dict of str to ndarray, shape (P, rows)
        ``U``, ``uu``, ``vv``, ``uv`` of each prefix per row, in the profile's units.
    band : dict of str to ndarray, shape (P, rows)
        One standard deviation of a prefix's departure from the whole run for pairs of one
        flow, ``sigma_1 sqrt(1/n - 1/N)`` (0 for the whole run).
    judged : ndarray of bool, shape (rows,)
        The rows the stationarity test judges.
    split : tuple of int or None
        The pairs of the first part and of the rest; None when no split leaves both
        :data:`MIN_HALF_PAIRS` pairs.
    z, change : dict of str to ndarray (rows,) or None
        Per row, the rest's value less the first part's over its standard error, and over
        the whole run's value's magnitude.
    drifting : list of str
        The statistics whose ``|z|`` exceeds :data:`DRIFT_SIGMAS` in more than
        :data:`DRIFT_SHARE` of the rows judged.
    warning : str or None
        One line saying which, with the median relative change over those rows.
    serial : float or None
        The median over the rows judged of the factor by which the pairs' serial correlation
        multiplies the variance of U (1 for independent pairs; None for sums written before
        the lags).
    serial_open : float or None
        The share of the rows judged whose factor is a lower bound (the run too short for its
        pairs' correlation to be known).
    serial_warning : str or None
        One line when that share exceeds :data:`DRIFT_SHARE`.
    """

    pairs: np.ndarray
    values: dict[str, np.ndarray]
    band: dict[str, np.ndarray]
    judged: np.ndarray
    split: tuple[int, int] | None = None
    z: dict[str, np.ndarray] | None = None
    change: dict[str, np.ndarray] | None = None
    drifting: list[str] = dataclasses.field(default_factory=list)
    warning: str | None = None
    serial: float | None = None
    serial_open: float | None = None
    serial_warning: str | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready: the prefixes' pairs, the split, per statistic the share of rows judged
        beyond :data:`DRIFT_SIGMAS` (``beyond_U`` ...) and the median ``|z|`` over them
        (``median_z_U`` ...: 0.67 for one flow), the warning."""
        out: dict[str, Any] = {"prefix_pairs": [int(n) for n in self.pairs],
                               "rows_judged": int(np.count_nonzero(self.judged))}  # fmt: skip
        if self.split is not None and self.z is not None and self.change is not None:
            out["split_pairs"] = list(self.split)
            for key in STATISTICS:
                z = np.abs(self.z[key][self.judged])
                z = z[np.isfinite(z)]
                out[f"beyond_{key}"] = float(np.mean(z > DRIFT_SIGMAS)) if z.size else None
                out[f"median_z_{key}"] = float(np.median(z)) if z.size else None
        if self.serial is not None:
            out["serial_factor_U"] = self.serial
            out["serial_open"] = self.serial_open
        if self.warning:
            out["warning"] = self.warning
        if self.serial_warning:
            out["serial_warning"] = self.serial_warning
        return out


def _within_parts(
    errors: dict[str, Any],
    res: dict[str, np.ndarray],
    key: str,
    sigma_1: np.ndarray,
    d_px: np.ndarray,
    parts: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray | float]:
    """One pair's scatter of ``key`` as for independent pairs (``sigma_1`` without the serial
    factor :func:`rspiv.profiles.pair_errors` applied) and the serial factor within the two
    parts: the rows' autocovariances (``res``, :meth:`RowErrors.result`'s ``gamma_``, px
    units) less the share of the parts' difference ``d_px`` at each lag ``k``, ``d^2 (n1 n2 N
    - k (N^2 - n1 n2)) / N^4`` for ``parts`` = (n1, n2, N) pairs of the row, and at least the
    per-vector lag-1 factor; that factor alone where the correlation within the parts outlasts
    the lags followed (a change inside a part looks so). Sums written before the lags, or
    errors without their factors: ``sigma_1`` as it is and 1."""
    if "serial" not in errors or key not in errors["serial"]:
        return sigma_1, 1.0
    applied = np.asarray(errors["serial"][key], np.float64)  # n_eff / n
    lag1 = 1.0 / np.asarray(errors["serial_lag1"][key], np.float64)
    plain = sigma_1 * np.sqrt(applied)
    if f"gamma_{key}" not in res:
        return plain, lag1
    n1, n2, n = parts
    k = np.arange(res[f"gamma_{key}"].shape[0])[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        step = np.nan_to_num(d_px * d_px * (n1 * n2 * n - k * (n * n - n1 * n2)) / n**4)
    g = res[f"gamma_{key}"] - step
    factor, still = lag_factor(g[0], g[1:], res["pairs"])
    # a correlation within the parts that outlasts the lags (a change inside a part, or scales
    # longer than the lags): not known, and the test takes the per-vector lag-1 factor
    return plain, np.where(still, lag1, np.maximum(factor, lag1))


def _serial_verdict(out: Convergence, errors: dict[str, np.ndarray], N: int) -> None:
    """The pairs' serial correlation over the rows judged (``out.serial``, ``serial_open``,
    ``serial_warning``; module docstring), from :func:`rspiv.profiles.pair_errors`' ``serial_U``
    (n_eff / n) and ``open_U``."""
    if "open_U" not in errors or np.count_nonzero(out.judged) < MIN_ROWS:
        return
    with np.errstate(divide="ignore"):
        factor = 1.0 / np.asarray(errors["serial_U"], np.float64)[out.judged]
    still = np.asarray(errors["open_U"], bool)[out.judged]
    out.serial = float(np.median(factor))
    out.serial_open = float(np.mean(still))
    if out.serial_open > DRIFT_SHARE:
        lags = np.asarray(errors.get("lag_max", np.zeros(out.judged.size)))[out.judged][still]
        if lags.size and np.median(lags) >= LAGS:  # a long run, its lags too few
            cure = (
                f"{LAGS} lags are kept: pairs spaced further apart in time ([images] "
                "pair_step) make the correlation short enough in pairs to be followed"
            )
        else:
            cure = "a longer recording (more of the flow's slowest scales) makes them known"
        out.serial_warning = (
            f"the pairs follow each other too closely for {N} of them to say how far their "
            f"statistics are from the flow's: in {100 * out.serial_open:.0f} % of the rows the "
            f"pairs' correlation lasts longer than a fifth of the lags followed (the variance "
            f"of U {np.median(factor[still]):.1f} times that of independent pairs and more), so "
            f"the errors and the convergence bands are lower bounds; {cure}"
        )


def run_convergence(
    rows: RowErrors,
    errors: dict[str, np.ndarray],
    judged: np.ndarray,
    k: float = 1.0,
    sign_u: float = 1.0,
    sign_v: float = 1.0,
) -> Convergence | None:
    """The prefixes and the stationarity test of a run (module docstring).

    Parameters
    ----------
    rows : RowErrors
        The run's row sums (``acc.rows``), in px per pair.
    errors : dict
        :func:`rspiv.profiles.pair_errors` of the same run with the same ``k``: the rows'
        errors from pair to pair (``U``, ``uu``, ``vv``, ``uv``, ``pairs``).
    judged : ndarray of bool, shape (rows,)
        The rows the stationarity test may judge (module docstring; those of too few pairs
        are left out here).
    k, sign_u, sign_v : float
        The profile's unit change and axis flips (:func:`rspiv.profiles.scaled_accumulator`).

    Returns
    -------
    Convergence or None
        None for sums written before the history, or a run of fewer than two prefixes of
        :data:`MIN_PREFIX_PAIRS` pairs.
    """
    judged = np.asarray(judged, dtype=bool)
    if judged.shape != (rows.rows,):
        raise InvalidInputError(f"convergence: {judged.shape} rows judged, not ({rows.rows},)")
    got = [(n, s) for n, s in rows.prefixes() if n >= MIN_PREFIX_PAIRS]
    if len(got) < 2:
        return None
    scale = {"U": k * sign_u, "uu": k * k, "vv": k * k, "uv": k * k * sign_u * sign_v}
    N = got[-1][0]
    pairs = np.array([n for n, _ in got], dtype=np.int64)
    stats = [pooled(s) for _, s in got]
    values = {key: np.stack([p[key] for p in stats]) * scale[key] for key in STATISTICS}
    # a row's share of the run's pairs: its pairs in a prefix taken as that share of the prefix's
    share = np.asarray(errors["pairs"], np.float64) / N
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma_1 = {key: np.asarray(errors[key], np.float64) * np.sqrt(share * N)
                   for key in STATISTICS}  # fmt: skip
        band = {
            key: sigma_1[key][None]
            * np.sqrt(np.maximum(1 / (pairs[:, None] * share) - 1 / (N * share), 0))
            for key in STATISTICS
        }
    judged = judged & (np.asarray(errors["pairs"]) >= VERDICT_PAIRS)
    out = Convergence(pairs, values, band, judged)
    _serial_verdict(out, errors, N)
    # the split: the edge whose first part is nearest half the run, both parts large enough
    firsts = [
        i for i, (n, _) in enumerate(got[:-1]) if n >= MIN_HALF_PAIRS and N - n >= MIN_HALF_PAIRS
    ]
    if not firsts:
        return out
    i = min(firsts, key=lambda j: abs(got[j][0] - 0.5 * N))
    n1 = got[i][0]
    first, rest = pooled(got[i][1]), pooled(got[-1][1] - got[i][1])
    out.split = (n1, N - n1)
    out.z, out.change = {}, {}
    n1r, n2r, nr = n1 * share, (N - n1) * share, N * share  # the row's pairs in each part
    res = rows.result() if "serial" in errors else {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for key in STATISTICS:
            d = (rest[key] - first[key]) * scale[key]
            # one pair's scatter within the parts: the whole run's less the parts' difference,
            # and the pairs' serial correlation within the parts (a change between them would
            # otherwise widen the scatter, and lengthen the correlation, it is held against)
            s1, factor = _within_parts(errors, res, key, sigma_1[key], rest[key] - first[key],
                                       (n1r, n2r, nr))  # fmt: skip
            within = s1**2 * (nr - 1) - n1r * n2r / nr * d * d
            sig = np.sqrt(np.maximum(within, 0.0) / np.maximum(nr - 2, 1.0) * factor)
            out.z[key] = d / (sig * np.sqrt(1 / n1r + 1 / n2r))
            out.change[key] = d / np.abs(values[key][-1])
    if np.count_nonzero(judged) < MIN_ROWS:
        return out
    said = []
    for key in STATISTICS:
        z = out.z[key][judged]
        ok = np.isfinite(z)
        if ok.sum() < MIN_ROWS:
            continue
        beyond = np.abs(z[ok]) > DRIFT_SIGMAS
        if beyond.mean() > DRIFT_SHARE:
            out.drifting.append(key)
            med = float(np.median(out.change[key][judged][ok][beyond]))
            said.append(f"{key} by a median {100 * med:+.1f} % ({100 * beyond.mean():.0f} % of "
                        f"the rows beyond {DRIFT_SIGMAS:.0f} standard errors)")  # fmt: skip
    if said:
        # a change is a correlation that outlasts the lags: said as the change, with it
        longer = (
            "; the rows' means also stay correlated beyond the lags followed, so the errors "
            "are lower bounds"
            if out.serial_warning
            else ""
        )
        out.serial_warning = None
        out.warning = (
            f"the statistics of the first {n1} pairs and of the last {N - n1} differ beyond "
            f"their errors: {'; '.join(said)}; the flow or the recording changed over the run "
            "(the tunnel's speed or temperature, the seeding, the laser's energy, the camera), "
            "or its pairs span too few of the flow's largest scales; the statistics average "
            f"over the change{longer}"
        )
    return out


def profile_rows(profile: dict) -> np.ndarray:
    """The rows of a run's ``profile`` (:func:`rspiv.campaign.analysis.analyse_run`'s) on the
    flow's side of the wall with a mean: those its profile holds."""
    dist = np.asarray(profile["dist_px"], np.float64)
    return (dist > 0) & np.isfinite(profile["U"]) & (np.asarray(profile["count"]) > 0)


def profile_convergence(acc: Any, profile: dict, near_wall_px: float) -> Convergence | None:
    """:func:`run_convergence` of a run's accumulator ``acc`` (its ``acc.rows``) in the units
    and axes of its ``profile`` (:func:`rspiv.campaign.analysis.analyse_run`'s: ``k``,
    ``sign_x``, ``sign_y``, ``dist_px``, ``U``, ``count``), judging the rows on the flow's side
    at least ``near_wall_px`` from the wall. None when ``acc`` carries no history (sums
    written before it, or of other pairs than its own) or too few pairs."""
    rows = getattr(acc, "rows", None)
    if rows is None or getattr(rows, "history", None) is None:
        return None
    pe = pair_errors(acc, profile["k"])
    if pe is None:
        return None
    judged = profile_rows(profile) & (np.asarray(profile["dist_px"]) >= near_wall_px)
    return run_convergence(rows, pe, judged, profile["k"], profile["sign_x"], profile["sign_y"])
