"""A campaign run's convergence with its pairs and the agreement of its first pairs and its
last (:mod:`rspiv.convergence`): its files, its entry in ``summary.json``, its line in the log
and its report section.

Outputs (atomic), per run whose statistics carry the rows' history (runs processed since it
exists; a state resumed from before gives none, said in ``summary.json``):

- ``OUT/convergence_<run>.csv``: per prefix (the pairs numbered below 10, 20, 50 ... and the
  whole run) and profile row on the flow's side of the wall: ``pairs``, ``y_px`` (from the
  wall), with the campaign's units ``y_m`` and ``y_plus`` (the run's composite fit), ``U``,
  ``uu``, ``vv``, ``uv`` of the prefix in the profile's units (m/s, m^2/s^2; px per pair
  without them) and ``band_U`` ... (one standard deviation of the prefix's departure from the
  whole run for pairs of one flow), ``judged`` (1 where the stationarity test judges the row);
- ``OUT/convergence_<run>.png``: the departures at up to four heights
  (:func:`rspiv.plots.convergence.plot_convergence`): ``y+`` near 15, 50, 150 and 500 where
  the run has wall units, else heights spread over the rows judged;
- ``summary.json``: ``runs.<run>.convergence`` (:meth:`rspiv.convergence.Convergence.summary`
  and the files); its ``warning`` also in the log and the report.
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from rspiv.convergence import STATISTICS, Convergence, run_convergence
from rspiv.errors import RspivError
from rspiv.outputs import write_profile_csv
from rspiv.profiles import pair_errors

__all__ = ["INFO_KEY", "PLUS_HEIGHTS", "report_section", "write_outputs"]

#: ``camp.info`` key holding this analysis's convergence per run label: ``(summary, figure)``.
INFO_KEY = "convergence"
#: The heights of the figure in wall units (the nearest row judged within a factor 1.6 each).
PLUS_HEIGHTS = (15.0, 50.0, 150.0, 500.0)


def _heights(an: Any, cv: Convergence, y_plus: np.ndarray | None) -> list[tuple[int, str]]:
    """The figure's rows: near :data:`PLUS_HEIGHTS` in wall units, else four spread in log
    distance over the rows judged."""
    dist = np.asarray(an.profile["dist_px"], np.float64)
    rows = np.flatnonzero(cv.judged & np.isfinite(cv.values["U"][-1]))
    if rows.size == 0:
        return []
    if y_plus is not None:
        got: list[tuple[int, str]] = []
        for target in PLUS_HEIGHTS:
            r = rows[np.argmin(np.abs(np.log(np.maximum(y_plus[rows], 1e-9) / target)))]
            if abs(np.log(max(y_plus[r], 1e-9) / target)) < np.log(1.6) and r not in dict(got):
                got.append((int(r), f"y+ = {y_plus[r]:.0f}"))
        if got:
            return got
    order = rows[np.argsort(dist[rows])]
    picks = np.unique(np.round(np.geomspace(1, order.size, 4)).astype(int) - 1)
    return [(int(order[i]), f"{dist[order[i]]:.0f} px from the wall") for i in picks]


def write_outputs(
    camp: Any, res: Any, run: Any, an: Any, near_wall_px: float
) -> dict[str, Any] | None:
    """Write run ``run``'s convergence files (module docstring) from its accumulator and its
    analysis ``an``; returns its ``summary.json`` entry, or None when the run has no profile.
    Rows within ``near_wall_px`` of the wall are not judged."""
    prof = an.profile
    if not prof:
        return None
    acc = res.accumulators[run.name]
    rows = getattr(acc, "rows", None)
    pe = pair_errors(acc, prof["k"]) if rows is not None else None
    if rows is None or pe is None or rows.history is None:
        return {"missing": "the statistics were summed before the rows' history was kept"}
    dist = np.asarray(prof["dist_px"], np.float64)
    ok = (dist > 0) & np.isfinite(prof["U"]) & (np.asarray(prof["count"]) > 0)
    try:
        cv = run_convergence(rows, pe, ok & (dist >= near_wall_px), prof["k"],
                             prof["sign_x"], prof["sign_y"])  # fmt: skip
    except (RspivError, ValueError) as exc:
        camp.say(f"{run.label}: no convergence: {exc}")
        return None
    if cv is None:  # fewer than two prefixes of MIN_PREFIX_PAIRS pairs: nothing to show
        return None
    y_plus = y_m = None
    if an.result is not None and prof.get("m_per_px"):
        y_m = dist * prof["m_per_px"] - an.result.y0
        y_plus = y_m * an.result.u_tau / an.result.nu
    out = pathlib.Path(camp.out_dir)
    sel = np.flatnonzero(ok)
    P = cv.pairs.size
    cols: dict[str, np.ndarray] = {
        "pairs": np.repeat(cv.pairs, sel.size).astype(np.float64),
        "y_px": np.tile(dist[sel], P),
    }
    if y_m is not None and y_plus is not None:
        cols["y_m"], cols["y_plus"] = np.tile(y_m[sel], P), np.tile(y_plus[sel], P)
    for key in STATISTICS:
        cols[key] = cv.values[key][:, sel].ravel()
    for key in STATISTICS:
        cols[f"band_{key}"] = cv.band[key][:, sel].ravel()
    cols["judged"] = np.tile(cv.judged[sel], P).astype(np.float64)
    units = "SI (m, m/s, m^2/s^2)" if prof.get("si") else "px per pair"
    csv = write_profile_csv(
        out / f"convergence_{run.name}.csv", cols,
        metadata={"run": run.name, "label": run.label, "units": units,
                  "split_pairs": "" if cv.split is None else f"{cv.split[0]} {cv.split[1]}"},
    )  # fmt: skip
    res.files[f"convergence_{run.name}_csv"] = csv
    entry = {**cv.summary(), "csv": str(csv)}
    fig = None
    heights = _heights(an, cv, y_plus)
    if heights:
        from rspiv.plots.convergence import plot_convergence  # deferred: matplotlib

        try:
            fig = plot_convergence(out / f"convergence_{run.name}.png", cv, heights,
                                   title=f"{run.label}: convergence over {int(cv.pairs[-1])} "
                                   "pairs (shaded: two standard deviations)")  # fmt: skip
            res.files[f"convergence_{run.name}_png"] = fig
            entry["figure"] = str(fig)
        except Exception as exc:  # noqa: BLE001 - a figure never fails the analysis
            camp.say(f"{run.label}: convergence figure failed: {exc}")
    if cv.warning:
        camp.say(f"warning: {run.label}: {cv.warning}")
    camp.info.setdefault(INFO_KEY, {})[run.label] = (entry, fig)
    return entry


#: The report's words on the figure and the test.
REPORT_TEXT = (
    "Each run's mean velocity and stresses over the pairs numbered below 10, 20, 50 ... "
    "against the whole run's, at a few heights, with the band (two standard deviations) "
    "within which the first n pairs of one flow stray from it (the pairs' scatter, "
    "sigma_1 sqrt(1/n - 1/N)). The run's pairs split in two near half way: where more than a "
    "quarter of the rows judged differ between the parts by more than four standard errors, "
    "the flow or the recording changed over the run and the statistics average over it."
)


def report_section(camp: Any) -> Any:
    """The report's section: every run's convergence figure, its split and what it found;
    None when no run has one."""
    from rspiv.report import ReportSection, ReportTable  # deferred: the report's writer

    got = camp.info.get(INFO_KEY) or {}
    if not got:
        return None
    rows, figures, said = [], [], []
    for label, (entry, fig) in got.items():
        row: dict[str, Any] = {"run": label, "pairs": entry["prefix_pairs"][-1]}
        if "split_pairs" in entry:
            row["first part, rest (pairs)"] = "{}, {}".format(*entry["split_pairs"])
            for key in STATISTICS:
                share = entry.get(f"beyond_{key}")
                row[f"rows beyond 4 SE, {key} (%)"] = None if share is None else 100 * share
        rows.append(row)
        if fig is not None:
            figures.append((fig, f"{label}: convergence with the pairs"))
        if entry.get("warning"):
            said.append(f"Warning: {label}: {entry['warning']}.")
    text = "\n\n".join([REPORT_TEXT, *said])
    return ReportSection(
        "Convergence with the pairs", text=text, figures=figures,
        tables=[ReportTable("The first pairs against the rest", rows)],
    )  # fmt: skip
