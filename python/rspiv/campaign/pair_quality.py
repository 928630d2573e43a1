"""Each pair's quality over a campaign: pairs whose frames are in reverse order left out, and
the pairs unlike the rest of their run said.

Per pair and run (:func:`measure`, in the pair's work, 14 ms at 47 MP): the share of the
final grid's windows (not masked) whose vectors enter the statistics (``valid``), the median
peak ratio of those vectors (``peak_ratio``), their mean displacement (``u``, ``v``, px per
pair in the run's frame) and their lean towards whole pixels (``locking``, px:
:func:`rspiv.peak_locking.locking_amplitude`, 13 ms at 47 MP; the run's peak locking,
:func:`rspiv.peak_locking.campaign_locking`, is said at the end); and per pair its frames as
recorded
(:func:`rspiv.recording_drift.pair_brightness`, 20 ms at 47 MP: ``counted``, ``signal_a``,
``signal_b``, ``background_a``, ``background_b``). The figures go to the run log's ``pair``
event (``quality``, with the context's fingerprint), so that the series survives an
interruption, Dask chunks and shards; pairs logged by an older rspiv have none.

**Frames in reverse order** (:mod:`rspiv.recording_drift`): a campaign's preparation takes the
run's direction from the pairs its drift check samples (``[images] check_pairs``,
:func:`rspiv.recording_drift.flow_direction`). A pair whose mean displacement along that
direction is at most :data:`REVERSED_SHARE` of it measures the flow backwards: it is left out of
every statistic (a ``skipped`` event naming the figures). The first run's field decides (the
uncorrected run when there is one; a corrected run holds the direction mapped into its object
frame by the mapping's Jacobian at the frame's centre). Where the samples give no direction
(fewer than two correlate, a flow whose mean turns, a displacement under 1 px), nothing is left
out and the campaign says why.

**Pairs unlike the run** (:func:`screen`, at the end of the run, from the series of the main
run): a pair whose mean displacement is at most :data:`REVERSED_SHARE` of the run's median (the
median of the pairs that go its way) points the other way (frames in reverse order where no
direction was taken before the run, or the samples went both ways); then robust scores against
the run's median (a median absolute deviation times 1.4826 as the
spread, :data:`OUTLIER_SPREADS` of them, and never less than a fixed share): a mean
displacement along the run's median one (when that is :data:`MIN_SCREEN_PX` or longer) off by
more than :data:`ALONG_SHARE` of it (another pulse separation, an uneven frame rate, a pairing
unlike the others) or across it by more than :data:`ACROSS_PX` (the camera or one laser sheet
moved between the exposures), a share of valid vectors more than :data:`VALID_DROP` under the
median (a bubble, a misfire of part of the sheet), a median peak ratio under :data:`PEAK_SHARE`
of the median (fog, particle images out of focus), a frame's particle images under
:data:`SIGNAL_SHARE` of their median brightness (a weak or missed laser pulse, which may
correlate as well as any other), or fewer particle images counted than
:data:`rspiv.recording.MIN_SEEDING_SHARE` of the median. What drifts over the run is said too
(:func:`trends`: the mean displacement, a tunnel's speed; the valid share; each frame's
brightness and background; the seeding), from a straight line through the pairs (its slope's
standard error allowing for the residuals' lag-1 correlation: successive pairs of a
time-resolved recording share the flow's slow scales). The pairs
unlike the run stay in the statistics (a real flow has rare events; only the user can tell):
they are said in the log, ``summary.json`` (``pair_outliers``) and the report, and can be left
out by ``[images] exclude_pairs``. ``OUT/pairs_<run>.csv`` holds every pair's figures.
"""

from __future__ import annotations

import csv
import io
from typing import Any

import numpy as np

from rspiv.campaign.spec import PairContext, RunSpec
from rspiv.outputs import atomic_write_text
from rspiv.peak_locking import (
    LOCKING_SAID_PX,
    campaign_locking,
    locking_amplitude,
    locking_said,
)
from rspiv.recording import MIN_SEEDING_SHARE
from rspiv.report import ReportSection, ReportTable

__all__ = [
    "ACROSS_PX",
    "ALONG_SHARE",
    "MIN_PAIRS",
    "MIN_SCREEN_PX",
    "OUTLIER_SPREADS",
    "PEAK_SHARE",
    "REVERSED_SHARE",
    "TREND_SHARE",
    "TREND_SIGMAS",
    "TREND_VALID",
    "VALID_DROP",
    "along_run",
    "measure",
    "report_section",
    "reversed_ids",
    "reversed_reason",
    "run_direction",
    "screen",
    "series",
    "summary_entries",
    "trends",
    "warning_lines",
    "write_outputs",
]

#: A pair whose mean displacement along the run's direction is at most this share of the
#: direction's length points the other way: its frames are in reverse order.
REVERSED_SHARE = -0.5
#: How a pair left out as reversed is said (its ``skipped`` reason holds it).
REVERSED_SAID = "frames A and B in reverse order?"
#: The screen's robust spreads (1.4826 median absolute deviations) from the run's median.
OUTLIER_SPREADS = 5.0
#: ... and its floors: the mean displacement along the run's off by this share of it, the
#: valid share this far under the median, the median peak ratio under this share of the run's.
ALONG_SHARE, VALID_DROP, PEAK_SHARE = 0.25, 0.1, 0.5
#: ... and the mean displacement across the run's median one off by this much (px).
ACROSS_PX = 0.2
#: A drift over the run is said where the line fitted to the pairs (the pairs unlike the run
#: left out) changes from the first pair to the last by more than this share of the mean
#: displacement along the run's median, or these points of valid share, at
#: :data:`TREND_SIGMAS` standard errors of its slope or more.
TREND_SHARE, TREND_VALID, TREND_SIGMAS = 0.01, 0.05, 5.0
#: Runs of fewer pairs are not screened (a median and its spread need a few).
MIN_PAIRS = 8
#: The run's median displacement must be this long (px) for the screen to hold pairs against
#: it (the mean over a field's vectors is good to a few hundredths of a px).
MIN_SCREEN_PX = 0.5
#: ... the particle images' brightness of a frame under this share of the run's, the count
#: under :data:`rspiv.recording.MIN_SEEDING_SHARE` of it.
SIGNAL_SHARE = 0.5
#: A drift of a frame's brightness by this share of the run's median, of the count by this
#: share, of a background by this share of the particle images' signal is said (the drift
#: check's bars, :mod:`rspiv.recording_drift`, a little lower over every pair).
TREND_SIGNAL, TREND_COUNT, TREND_BACKGROUND = 0.25, 0.3, 0.5
#: Each pair's frames as recorded (:func:`rspiv.recording_drift.pair_brightness`).
FRAME_FIGURES = ("counted", "signal_a", "signal_b", "background_a", "background_b")
#: The figures per pair and run, in the log and ``pairs_<run>.csv``.
FIGURES = ("valid", "peak_ratio", "u", "v", "locking", *FRAME_FIGURES)


def measure(field: Any, arrays: tuple) -> dict[str, float]:
    """One run's figures of a pair (module docstring): ``field`` its PIV field (the peak ratio,
    the mask), ``arrays`` its ``(u, v, valid, ...)`` as they enter the statistics."""
    u, v, valid = arrays[0], arrays[1], np.asarray(arrays[2], bool)
    live = max(int(np.count_nonzero(~np.asarray(field.masked, bool))), 1)
    n = int(np.count_nonzero(valid))
    if n == 0:
        nan = float("nan")
        return {"valid": 0.0, "peak_ratio": nan, "u": nan, "v": nan, "locking": nan}
    pr = np.asarray(field.peak_ratio)[valid]
    pr = pr[pr > 0]
    return {
        "valid": round(n / live, 5),
        "peak_ratio": round(float(np.median(pr)), 4) if pr.size else float("nan"),
        "u": round(float(np.mean(u, where=valid)), 5),
        "v": round(float(np.mean(v, where=valid)), 5),
        "locking": round(locking_amplitude(u, v, valid), 5),
    }


def run_direction(context: PairContext, run: RunSpec) -> tuple[float, float] | None:
    """The run's direction (``context.reference``, px per pair in the raw frame) in ``run``'s
    frame: as it is for the uncorrected run; for a corrected run mapped into its object frame
    by the inverse of the mapping's Jacobian at the object frame's centre (cached); None
    without a reference."""
    ref = context.reference
    if ref is None or run.method == "none" or context.mapping is None:
        return None if ref is None else (float(ref[0]), float(ref[1]))
    key = "direction_object"
    got = context._cache.get(key)
    if got is None:
        h, w = context.object_shape
        jac = context.mapping.forward_jacobian(np.array([[0.5 * (w - 1), 0.5 * (h - 1)]]))[0]
        d = np.linalg.solve(jac, np.asarray(ref, float))
        got = (float(d[0]), float(d[1]))
        context._cache[key] = got
    return got


def reversed_reason(quality: dict[str, float], direction: tuple[float, float] | None) -> str:
    """Why a pair of these figures points the other way from ``direction``, or ``""`` (also
    without a direction or a measured displacement)."""
    if direction is None or not np.isfinite(quality.get("u", np.nan)):
        return ""
    dx, dy = direction
    along = (quality["u"] * dx + quality["v"] * dy) / (dx * dx + dy * dy)
    if along > REVERSED_SHARE:
        return ""
    return (
        f"its mean displacement ({quality['u']:.2f}, {quality['v']:.2f}) px points the other way "
        f"from the run's ({dx:.2f}, {dy:.2f}) px ({along:.2f} of it): {REVERSED_SAID} Left out "
        "of the statistics"
    )


def series(log: Any, fingerprint: str, ids: set) -> dict[str, dict[str, np.ndarray]]:
    """Run name -> ``{"pair": ids, "valid": ..., "peak_ratio": ..., "u": ..., "v": ...}`` of the
    pairs of ``ids`` from the run log's ``pair`` events under the context ``fingerprint``
    (the last event of a pair counts; pairs without figures, e.g. logged by an older rspiv,
    are missing)."""
    latest: dict[int, dict] = {}
    for rec in log.events("pair"):
        pid, q = rec.get("pair_id"), rec.get("quality")
        if rec.get("fingerprint") == fingerprint and pid in ids and isinstance(q, dict):
            latest[int(pid)] = q
    out: dict[str, dict[str, list]] = {}
    for pid in sorted(latest):
        for run, figs in latest[pid].items():
            col = out.setdefault(run, {"pair": [], **{k: [] for k in FIGURES}})
            col["pair"].append(pid)
            for k in FIGURES:
                val = figs.get(k)
                col[k].append(np.nan if val is None else float(val))
    return {
        run: {k: np.asarray(v, np.int64 if k == "pair" else float) for k, v in cols.items()}
        for run, cols in out.items()
    }


def _robust(x: np.ndarray) -> tuple[float, float]:
    """The median and the spread (1.4826 median absolute deviations) of the finite ``x``."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return np.nan, np.nan
    m = float(np.median(x))
    return m, 1.4826 * float(np.median(np.abs(x - m)))


def along_run(
    s: dict[str, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Each pair's mean displacement along the run's median one (in units of its length) and
    across it (px, positive to its left in the image: counter-clockwise from it with y down),
    and that median ``(u, v)`` px; both NaN when the median is under :data:`MIN_SCREEN_PX`."""
    u, v = np.asarray(s["u"], float), np.asarray(s["v"], float)
    nan = np.full(u.shape, np.nan)
    du, dv = np.nan, np.nan
    if np.any(np.isfinite(u)):
        du, dv = float(np.nanmedian(u)), float(np.nanmedian(v))
        # the median of the pairs that go its way: a run whose frames go both ways in part has
        # a median between the two
        with np.errstate(invalid="ignore"):
            ahead = u * du + v * dv > 0
        if np.any(ahead):
            du, dv = float(np.median(u[ahead])), float(np.median(v[ahead]))
    n2 = du * du + dv * dv
    if not np.isfinite(n2) or n2 < MIN_SCREEN_PX**2:
        return nan, nan.copy(), (du, dv)
    return (u * du + v * dv) / n2, (v * du - u * dv) / np.sqrt(n2), (du, dv)


def _bar(x: np.ndarray, floor: float, relative: bool, low: bool):
    """``(flags, median)``: the finite ``x`` off the median (under it only with ``low``) by
    more than :data:`OUTLIER_SPREADS` robust spreads and ``floor`` (a share of the median
    with ``relative``); None when nothing is finite."""
    m, sd = _robust(x)
    if not np.isfinite(m):
        return None
    bar = max(OUTLIER_SPREADS * sd, floor * abs(m) if relative else floor)
    with np.errstate(invalid="ignore"):
        return ((x - m < -bar) if low else (np.abs(x - m) > bar)), m


def screen(s: dict[str, np.ndarray]) -> dict[int, str]:
    """Pair id -> why the pair is unlike its run (module docstring); empty for a run of fewer
    than :data:`MIN_PAIRS` pairs."""
    ids = s["pair"]
    if ids.size < MIN_PAIRS:
        return {}
    along, across, (du, dv) = along_run(s)
    nan = np.full(ids.shape, np.nan)
    with np.errstate(invalid="ignore"):
        back = along <= REVERSED_SHARE
    ahead = np.where(back, np.nan, along)  # the spread of the pairs that go the run's way

    def col(name: str) -> np.ndarray:
        return s.get(name, nan)

    def pc(x: float, m: float) -> str:
        return f"{100 * x / m:.0f} %"

    # (values, floor, relative, low only, what it says for pair j against the median m)
    checks = (
        (ahead, ALONG_SHARE, True, False, lambda j, m: (
            f"mean displacement ({s['u'][j]:.2f}, {s['v'][j]:.2f}) px, {along[j]:.2f} times the "
            f"run's median ({du:.2f}, {dv:.2f}) px along it (another pulse separation or frame "
            "interval, another pairing?)")),
        (across, ACROSS_PX, False, False, lambda j, m: (
            f"mean displacement across the run's median {across[j]:+.2f} px against its "
            f"{m:+.2f} px (the camera or a laser sheet moved between the exposures?)")),
        (col("valid"), VALID_DROP, False, True, lambda j, m: (
            f"{100 * s['valid'][j]:.0f} % of its vectors valid against the run's median "
            f"{100 * m:.0f} % (a bubble, part of the sheet missing?)")),
        (col("peak_ratio"), 1 - PEAK_SHARE, True, True, lambda j, m: (
            f"median peak ratio {s['peak_ratio'][j]:.2f} against the run's {m:.2f} (a weak "
            "pulse, fog, particle images out of focus?)")),
        (col("signal_a"), 1 - SIGNAL_SHARE, True, True, lambda j, m: (
            f"frame A's particle images at {pc(s['signal_a'][j], m)} of the run's brightness "
            f"({s['signal_a'][j]:.0f} against {m:.0f} counts: a weak or missed laser pulse?)")),
        (col("signal_b"), 1 - SIGNAL_SHARE, True, True, lambda j, m: (
            f"frame B's particle images at {pc(s['signal_b'][j], m)} of the run's brightness "
            f"({s['signal_b'][j]:.0f} against {m:.0f} counts: a weak or missed laser pulse?)")),
        (col("counted"), 1 - MIN_SEEDING_SHARE, True, True, lambda j, m: (
            f"{s['counted'][j]:.4f} particle images counted per px against the run's {m:.4f} "
            "(the seeding thins, a bubble?)")),
    )  # fmt: skip
    out: dict[int, list[str]] = {}
    for j in np.flatnonzero(back):
        out[int(ids[j])] = [
            f"mean displacement ({s['u'][j]:.2f}, {s['v'][j]:.2f}) px, {along[j]:.2f} times the "
            f"run's median ({du:.2f}, {dv:.2f}) px: the other way (frames A and B in reverse "
            "order?)"
        ]
    for values, floor, relative, low, said in checks:
        got = _bar(values, floor, relative, low)
        if got is None:
            continue
        flags, m = got
        for j in np.flatnonzero(flags):
            out.setdefault(int(ids[j]), []).append(said(int(j), m))
    return {k: "; ".join(v) for k, v in sorted(out.items())}


def _line(ids: np.ndarray, y: np.ndarray, keep: np.ndarray) -> tuple[float, float, float] | None:
    """A straight line fitted to ``y`` by pair id: its values at the first and the last pair
    and its slope in standard errors; None for fewer than :data:`MIN_PAIRS` pairs."""
    ok = keep & np.isfinite(y)
    if np.count_nonzero(ok) < MIN_PAIRS:
        return None
    x, yy = ids[ok] - ids[ok].mean(), y[ok]
    sxx = float(x @ x)
    if sxx <= 0:
        return None
    slope = float(x @ (yy - yy.mean())) / sxx
    resid = yy - yy.mean() - slope * x
    se = float(np.sqrt(resid @ resid / (yy.size - 2) / sxx))
    # successive pairs that share the flow's slow scales (a time-resolved recording) leave
    # correlated residuals: the slope's error grows by sqrt((1 + r) / (1 - r)) for a lag-1
    # correlation r (an AR(1) model of the residuals)
    r2 = float(resid @ resid)
    r = float(resid[1:] @ resid[:-1]) / r2 if r2 > 0 else 0.0
    r = min(max(r, 0.0), 0.95)
    se *= np.sqrt((1 + r) / (1 - r))
    start, end = (float(yy.mean() + slope * v) for v in (x.min(), x.max()))
    return start, end, (abs(slope) / se if se > 0 else np.inf)


def trends(s: dict[str, np.ndarray], outliers: dict[int, str]) -> dict[str, str]:
    """What drifts over the run (module docstring): ``"displacement"``, ``"valid"``,
    ``"seeding"``, ``"signal_A"``/``"_B"``, ``"background_A"``/``"_B"`` -> one line each, from
    a straight line fitted to the pairs by id (those of ``outliers`` left out); a change is
    relative to the line's value at the first pair, the valid share's in points and a
    background's in counts against the particle images' signal. Empty for fewer than
    :data:`MIN_PAIRS` pairs or no drift."""
    ids = np.asarray(s["pair"], float)
    keep = ~np.isin(s["pair"], np.fromiter(outliers, np.int64, len(outliers)))
    along, _, (du, dv) = along_run(s)
    nan = np.full(ids.shape, np.nan)

    def col(name: str) -> np.ndarray:
        return np.asarray(s.get(name, nan), float)

    def pct(a: float, b: float) -> str:
        return f"{100 * (b - a) / a:+.1f} %"

    tail = "from the first pair to the last (a fitted line, {:.0f} standard errors)"
    # (key, values, the bar: a share of the first value, or counts/points, what it says)
    specs = [
        ("displacement", along, TREND_SHARE, True, lambda a, b, t: (
            f"the mean displacement along the run's median ({du:.2f}, {dv:.2f}) px changes by "
            f"{pct(a, b)} {t}: the flow's speed drifts over the run (the tunnel, its "
            "temperature?) or the pairs span too few of the flow's largest scales; the "
            "statistics average over it")),
        ("valid", col("valid"), TREND_VALID, False, lambda a, b, t: (
            f"the share of valid vectors changes from {100 * a:.0f} % to {100 * b:.0f} % {t}: "
            "the seeding, the optics or the laser's energy change over the run")),
        ("seeding", col("counted"), TREND_COUNT, True, lambda a, b, t: (
            f"the particle images counted per px change from {a:.4f} to {b:.4f} ({pct(a, b)}) "
            f"{t}: the seeder or the mixing changes over the run")),
    ]
    for f in "AB":
        sig = col(f"signal_{f.lower()}")
        m = float(np.nanmedian(sig)) if np.any(np.isfinite(sig)) else np.nan
        specs += [
            (f"signal_{f}", sig, TREND_SIGNAL, True, lambda a, b, t, f=f: (
                f"frame {f}'s particle images change in brightness from {a:.0f} to {b:.0f} "
                f"counts ({pct(a, b)}) {t}: the laser's energy or the sheet's position drifts")),
            (f"background_{f}", col(f"background_{f.lower()}"), TREND_BACKGROUND * m, False,
             lambda a, b, t, f=f, m=m: (
                f"frame {f}'s background changes from {a:.0f} to {b:.0f} counts "
                f"({abs(b - a) / m:.1f} times the particle images' signal) {t}: a background "
                "over the whole run leaves the rest in the frames; a sliding window of frames "
                "([preprocess] background_window) follows it")),
        ]  # fmt: skip
    out: dict[str, str] = {}
    for key, y, bar, relative, said in specs:
        got = _line(ids, y, keep) if np.isfinite(bar) else None
        if got is None:
            continue
        a, b, sigmas = got
        size = abs(b - a) / abs(a) if relative else abs(b - a)
        if relative and a == 0:
            continue
        if size > bar and sigmas >= TREND_SIGMAS:
            out[key] = said(a, b, tail.format(sigmas))
    return out


def write_outputs(camp: Any, res: Any, log: Any) -> dict[str, Any]:
    """The series of every run of ``res`` from ``log``, the main run's screen and trends, and
    ``OUT/pairs_<run>.csv`` per run (paths in ``res.files``). Returns ``{"series": ...,
    "outliers": {pair: reason}, "trends": {what: line}}`` (empty when the log holds no
    figures)."""
    ctx = res.context
    ids: set = set()
    for acc in res.accumulators.values():
        ids |= set(acc.pair_ids)
    got = series(log, ctx.fingerprint(), ids)
    if not got:
        return {}
    main = ctx.runs[0].name
    outliers = screen(got[main]) if main in got else {}
    drifts = trends(got[main], outliers) if main in got else {}
    for run in ctx.runs:
        s = got.get(run.name)
        if s is None:
            continue
        along, across, _ = along_run(s)
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["pair", *FIGURES, "along", "across_px", "unlike_run"])
        for j, pid in enumerate(s["pair"]):
            row = [int(pid), *(repr(float(s[k][j])) for k in FIGURES)]
            row += [repr(round(float(along[j]), 5)), repr(round(float(across[j]), 5))]
            w.writerow([*row, outliers.get(int(pid), "") if run.name == main else ""])
        path = camp.out_dir / f"pairs_{run.name}.csv"
        res.files[f"pairs_{run.name}"] = atomic_write_text(path, buf.getvalue())
    # the pooled histogram of each run's pairs (it tells where a field alone is too thin); the
    # mean of the pairs' own figures for a checkpoint written before it
    locking = {}
    for run, s in got.items():
        hist = getattr(res.accumulators.get(run), "locking", None)
        locking[run] = hist.result() if hist is not None else campaign_locking(s["locking"])
    return {"series": got, "outliers": outliers, "trends": drifts, "locking": locking}


def report_section(camp: Any, res: Any, quality: dict[str, Any]) -> Any:
    """The report's section on the main run's pairs over the run (a figure of the series, the
    pairs unlike the run, the pairs left out as reversed), or None without figures."""
    main = res.context.runs[0]
    s = quality.get("series", {}).get(main.name)
    if s is None:
        return None
    outliers = quality.get("outliers", {})
    figures = []
    try:
        from rspiv.plots.pairs import plot_pairs  # deferred: matplotlib

        path = camp.out_dir / "report" / "figures" / "pairs.png"
        along, across, median = along_run(s)
        path = plot_pairs(path, s, along, across, median, outliers)
        figures.append((path, f"{main.label}: each pair over the run"))
    except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
        camp.say(f"pairs figure failed: {exc}")
    rev = reversed_ids(res)
    text = (
        f"Each of the {s['pair'].size} pairs' mean displacement along and across the run's "
        "median, share of valid vectors, median peak ratio and its frames' brightness "
        f"(`pairs_{main.name}.csv`, with the particle images counted and the backgrounds)."
    )
    if rev:
        text += (
            f"\n\nWarning: {len(rev)} pair(s) displace the other way from the run (frames A and "
            f"B in reverse order?) and are left out of the statistics: {_shown(rev, 20)}."
        )
    for line in (quality.get("trends") or {}).values():
        text += f"\n\nWarning: over the run, {line}."
    judged, locked = locking_said(res.context.runs, quality.get("locking") or {})
    if locked:
        text += f"\n\nWarning: {locked}."
    elif judged is not None:
        got = quality["locking"][judged]
        se = got["standard_error_px"]
        text += (
            f"\n\nPeak locking measured on the {judged} displacements' histogram: amplitude "
            f"{got['amplitude_px']:.4f}" + ("" if se is None else f" +- {se:.4f}") + " px over "
            f"{got['pairs']} pairs (said from {LOCKING_SAID_PX} px"
            + ("" if se is not None else f"; {got.get('note', 'no standard error')}")
            + ")."
        )
    tables = []
    if outliers:
        text += (
            f"\n\nWarning: {len(outliers)} pair(s) are unlike the rest of the run and are in the "
            "statistics; list them in `[images] exclude_pairs` to leave them out (with "
            "`[output] fields = true` the statistics are then summed again from the field "
            "files, without the PIV)."
        )
        rows = [{"pair": k, "unlike the run": v} for k, v in list(outliers.items())[:50]]
        tables.append(ReportTable("Pairs unlike the run", rows))
    return ReportSection("The pairs over the run", text=text, figures=figures, tables=tables)


def reversed_ids(res: Any) -> list[int]:
    """The pairs of ``res`` left out as displacing the other way (:func:`reversed_reason`)."""
    return sorted(k for k, why in res.skipped.items() if REVERSED_SAID in why)


def warning_lines(res: Any) -> list[str]:
    """Lines for the log and ``rspiv process``: the pairs left out as reversed, the pairs
    unlike the run; none when there are none."""
    out = []
    rev = reversed_ids(res)
    if rev:
        out.append(
            f"{len(rev)} pair(s) displace the other way from the run and are left out (frames A "
            f"and B in reverse order?): pairs {_shown(rev)}"
        )
    for line in ((res.pair_quality or {}).get("trends") or {}).values():
        out.append(f"over the run, {line}")
    _, locked = locking_said(res.context.runs, (res.pair_quality or {}).get("locking") or {})
    if locked:
        out.append(locked)
    unlike = (res.pair_quality or {}).get("outliers") or {}
    if unlike:
        out.append(
            f"{len(unlike)} pair(s) are unlike the rest of the run (pairs {_shown(list(unlike))}; "
            "summary.json pair_outliers, pairs_<run>.csv): they are in the statistics; "
            "[images] exclude_pairs leaves them out (re-reduced from the field files when "
            "[output] fields is on)"
        )
    return out


def summary_entries(camp: Any, res: Any) -> dict[str, Any]:
    """``summary.json``'s ``reversed_pairs`` (the direction held against, or why none, and the
    pairs left out) and ``pair_outliers``; the warnings said in the log."""
    ctx = res.context
    out: dict[str, Any] = {}
    if ctx.reference is not None:
        out["reversed_pairs"] = {"direction": list(ctx.reference), "left_out": reversed_ids(res)}
    else:
        note = (camp.info.get("reversed_check") or {}).get("note", "not looked for")
        out["reversed_pairs"] = {"direction": None, "note": note}
    outliers = (res.pair_quality or {}).get("outliers")
    if outliers:
        out["pair_outliers"] = outliers
    drifts = (res.pair_quality or {}).get("trends")
    if drifts:
        out["pair_trends"] = drifts
    locking = (res.pair_quality or {}).get("locking")
    if locking:
        judged, line = locking_said(res.context.runs, locking)
        out["peak_locking"] = {"runs": locking, "judged_on": judged}
        if line:
            out["peak_locking"]["warning"] = line
    for line in warning_lines(res):
        camp.say(f"warning: {line}")
    return out


def _shown(ids: list[int], n: int = 8) -> str:
    """The first ``n`` of ``ids``, comma-separated."""
    return ", ".join(str(k) for k in ids[:n]) + (", ..." if len(ids) > n else "")
