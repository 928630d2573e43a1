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
  and the files); its ``warning`` and ``serial_warning`` (pairs too close in time for their
  correlation to be known) also in the log and the report, whose table gives each run's
  ``serial factor on var(U)`` (the median over the rows judged; 1 for independent pairs).
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from rspiv.convergence import (
    REPORT_TEXT,
    STATISTICS,
    Convergence,
    profile_convergence,
    profile_rows,
)
from rspiv.errors import RspivError
from rspiv.outputs import write_profile_csv

__all__ = ["INFO_KEY", "PLUS_HEIGHTS", "report_section", "write_files", "write_outputs"]

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
    if an.wall is not None:
        return [(int(order[i]), f"{dist[order[i]]:.0f} px from the wall") for i in picks]
    # no wall found (none looked for): the rows by their place in the frame
    y = an.profile["y_wall_px"] + an.profile["sign_y"] * dist
    return [(int(order[i]), f"row y = {y[order[i]]:.0f} px") for i in picks]


def write_files(
    out_dir: pathlib.Path,
    name: str,
    cv: Convergence,
    an: Any,
    label: str,
    say=None,
    figure: bool = True,
) -> tuple[dict[str, Any], dict[str, pathlib.Path]]:
    """Write ``<name>.csv`` and (with ``figure``) ``<name>.png`` of ``cv`` (module docstring)
    to ``out_dir`` for the run analysis ``an`` (its profile's rows, wall units from its result
    when it has one); returns the ``summary.json`` entry and the files written (``csv``,
    ``png``). A figure that fails is said through ``say`` and left out."""
    prof = an.profile
    dist = np.asarray(prof["dist_px"], np.float64)
    y_plus = y_m = None
    if an.result is not None and prof.get("m_per_px"):
        y_m = dist * prof["m_per_px"] - an.result.y0
        y_plus = y_m * an.result.u_tau / an.result.nu
    sel = np.flatnonzero(profile_rows(prof))
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
    files = {"csv": write_profile_csv(
        out_dir / f"{name}.csv", cols,
        metadata={"label": label, "units": units,
                  "split_pairs": "" if cv.split is None else f"{cv.split[0]} {cv.split[1]}"},
    )}  # fmt: skip
    entry = {**cv.summary(), "csv": str(files["csv"])}
    heights = _heights(an, cv, y_plus) if figure else []
    if heights:
        from rspiv.plots.convergence import plot_convergence  # deferred: matplotlib

        try:
            files["png"] = plot_convergence(out_dir / f"{name}.png", cv, heights,
                                            title=f"{label}: convergence over "
                                            f"{int(cv.pairs[-1])} pairs (shaded: two standard "
                                            "deviations)")  # fmt: skip
            entry["figure"] = str(files["png"])
        except Exception as exc:  # noqa: BLE001 - a figure never fails the analysis
            if say is not None:
                say(f"{label}: convergence figure failed: {exc}")
    return entry, files


def write_outputs(
    camp: Any, res: Any, run: Any, an: Any, near_wall_px: float
) -> dict[str, Any] | None:
    """Write run ``run``'s convergence files (module docstring) from its accumulator and its
    analysis ``an``; returns its ``summary.json`` entry, or None when the run has no profile
    or too few pairs. Rows within ``near_wall_px`` of the wall are not judged."""
    if not an.profile:
        return None
    acc = res.accumulators[run.name]
    if getattr(getattr(acc, "rows", None), "history", None) is None:
        return {"missing": "the statistics were summed before the rows' history was kept"}
    try:
        cv = profile_convergence(acc, an.profile, near_wall_px)
    except (RspivError, ValueError) as exc:
        camp.say(f"{run.label}: no convergence: {exc}")
        return None
    if cv is None:  # fewer than two prefixes of MIN_PREFIX_PAIRS pairs: nothing to show
        return None
    entry, files = write_files(
        pathlib.Path(camp.out_dir), f"convergence_{run.name}", cv, an, run.label, camp.say
    )
    for kind, path in files.items():
        res.files[f"convergence_{run.name}_{kind}"] = path
    for said in (cv.warning, cv.serial_warning):
        if said:
            camp.say(f"warning: {run.label}: {said}")
    camp.info.setdefault(INFO_KEY, {})[run.label] = (entry, files.get("png"))
    return entry


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
        if entry.get("serial_factor_U") is not None:
            row["serial factor on var(U)"] = entry["serial_factor_U"]
        rows.append(row)
        if fig is not None:
            figures.append((fig, f"{label}: convergence with the pairs"))
        for key in ("warning", "serial_warning"):
            if entry.get(key):
                said.append(f"Warning: {label}: {entry[key]}.")
    text = "\n\n".join([REPORT_TEXT, *said])
    return ReportSection(
        "Convergence with the pairs", text=text, figures=figures,
        tables=[ReportTable("The first pairs against the rest", rows)],
    )  # fmt: skip
