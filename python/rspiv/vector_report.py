"""The report of another tool's vector series (``rspiv statistics --report``;
:meth:`rspiv.vector_statistics.VectorStatistics.write` with ``report=True``).

One Markdown file and its HTML rendering (:func:`rspiv.report.write_report`), in
``OUT/report/``: what was read (the tool, the fields used and skipped, the frame, the scale, the
pulse separation, the final window, the wall and its levelling, the peak locking, the vectors
screened), every warning of the reduction word for word, the boundary layer in wall units
(its characteristics, the statistical uncertainties of the profiles and the figures against
the DNS) and one section per structure analysis asked for (two-point, quadrant, conditional
averages, POD, vortices: what it holds, its own warning and its figure). Figures are those
:meth:`~rspiv.vector_statistics.VectorStatistics.write` draws with ``figures``, copied into
``OUT/report/figures/``.

A series without wall units (no scale or no pulse separation) gets the report without the
boundary layer's section, and says why there; the figures need wall units too.
"""

from __future__ import annotations

import math
import os
import pathlib
from typing import Any

from rspiv._rspiv import __version__
from rspiv.convergence import REPORT_TEXT as CONVERGENCE_TEXT
from rspiv.errors import InvalidInputError
from rspiv.reference_comparison import REPORT_TEXT
from rspiv.report import (
    ERROR_BARS,
    MOMENTS_CAPTION,
    ReportSection,
    ReportTable,
    pairs_for_paper,
    u_tau_text,
    uncertainty_summary,
    write_report,
)
from rspiv.vector_structures import STRUCTURES, report_lines

__all__ = ["CAPTIONS", "write_series_report"]

#: Each figure's caption (the files' ``figure_<name>`` of ``VectorStatistics.write``).
CAPTIONS = {
    "mean_velocity": "Mean streamwise velocity U+(y+) against the DNS",
    "reynolds_stresses": (
        "Reynolds stresses uu+, vv+, -uv+ against the DNS (rows within 2.5 window heights of the "
        "wall, flagged near_wall, left out: there the wall, its reflection and the gradient "
        "across the window raise the stresses)"
    ),
    "higher_moments": MOMENTS_CAPTION,
    "vorticity": (
        "The vorticity's rms and the mean shear against the DNS (the rms holds the measurement "
        "noise, which the differences amplify, and lacks the scales the windows average away)"
    ),
    "two_point": "Streamwise spectra and two-point correlations per row (wall units)",
    "two_point_maps": "Two-point correlation maps about the reference rows",
    "quadrant": "Quadrant analysis of u'v': the shares per quadrant and hole, the joint PDFs",
    "conditional": "Conditional averages of u', v' about the events at the reference heights",
    "pod": "POD: the modes' energies and the first modes",
    "vortices": "Vortex population by height: densities, radii and circulations",
}

#: The sections of the structure analyses: title and the figures each draws.
_STRUCTURE_SECTIONS = {
    "two_point": ("Spectra and two-point correlations", ("two_point", "two_point_maps")),
    "quadrant": ("Quadrant analysis", ("quadrant",)),
    "conditional": ("Conditional averages", ("conditional",)),
    "pod": ("Proper orthogonal decomposition", ("pod",)),
    "vortices": ("Vortex population", ("vortices",)),
}


def _number(v: float, fmt: str) -> str | None:
    return None if v is None or not math.isfinite(v) else format(v, fmt)


def write_series_report(
    out_dir: str | os.PathLike, stats: Any, files: dict[str, pathlib.Path]
) -> dict[str, pathlib.Path]:
    """Write ``report.md`` and ``report.html`` of the reduction ``stats`` (a
    :class:`~rspiv.vector_statistics.VectorStatistics`) into ``out_dir`` (module docstring),
    with the figures among ``files`` (name -> path, as ``VectorStatistics.write`` returns
    them); returns ``{"markdown": path, "html": path}``."""
    figs = {k[len("figure_") :]: p for k, p in files.items() if k.startswith("figure_")}
    an = stats.analysis
    wall = an.wall
    read = {
        "tool": stats.tool,
        "frame": stats.frame or "unknown (the files do not say)",
        "fields used": stats.used,
        "fields skipped": len(stats.skipped),
        "scale (mm/px)": _number(stats.mm_per_px, ".6g"),
        "pulse separation (s)": _number(stats.dt, ".6g"),
        "final window (px)": f"{stats.window[0]} x {stats.window[1]}",
        "flow side": an.flow_side,
        "wall angle (deg)": None if wall is None else f"{wall.angle_deg:.4f}",
        "levelled by (deg)": f"{stats.rotation_deg:.4f}",
    }
    lk = stats.locking
    if lk.get("amplitude_px") is not None:
        err = lk.get("standard_error_px")
        read["peak locking (px)"] = f"{lk['amplitude_px']:.4f}" + (
            f" +- {err:.4f}" if err is not None else ""
        )
    sc = stats.screened()
    if sc is not None:
        read["vectors screened"] = f"{sc['vectors']} ({100 * sc['share']:.3f} %)"
    skipped = ""
    if stats.skipped:
        name, why = next(iter(stats.skipped.items()))
        skipped = f"\n\n{len(stats.skipped)} field(s) skipped; the first, {name}: {why}."
    sections = [
        ReportSection(
            "Series",
            text=(
                f"{stats.used} {stats.tool} fields reduced to a campaign's statistics "
                f"(rspiv.vector_statistics) in {stats.seconds:.1f} s: only the vectors the "
                "tool's validation accepted enter them." + skipped
            ),
            tables=[ReportTable("What was read", read)],
        )
    ]
    if stats.warnings:
        sections.append(
            ReportSection(
                "Warnings",
                text="\n\n".join(f"Warning: {w}" for w in stats.warnings),
            )
        )
    sections.append(_boundary_layer(stats, figs))
    if "convergence" in figs:  # the first fields against the series (rspiv.convergence)
        sections.append(ReportSection("Convergence with the fields", text=CONVERGENCE_TEXT,
                                      figures=[(figs["convergence"], "Convergence")]))  # fmt: skip
    vort = stats.vorticity
    if vort is not None:
        text = (f"Vorticity statistics in {vort['y'].size} rows by "
                f"{vort['scheme'].replace('_', ' ')} differences of each field's valid vectors, "
                "in the flow's frame.")  # fmt: skip
        drawn = [(figs["vorticity"], CAPTIONS["vorticity"])] if "vorticity" in figs else []
        sections.append(ReportSection("Vorticity", text=text, figures=drawn))
    found = {k: getattr(stats, k) for k in STRUCTURES}
    for name, (title, drawn) in _STRUCTURE_SECTIONS.items():
        prof = found.get(name)
        if prof is None:
            continue
        text = "\n\n".join(report_lines({name: prof}))
        if "warning" in prof:
            text += f"\n\nWarning: {prof['warning']}."
        entries = [(figs[d], CAPTIONS[d]) for d in drawn if d in figs]
        if not entries:
            text += "\n\nNo figure: it needs wall units and `--figures`."
        sections.append(ReportSection(title, text=text, figures=entries))
    meta = {"rspiv": __version__, "tool": stats.tool, "fields": stats.used}
    return write_report(
        out_dir, *sections, title=f"rspiv statistics of {stats.used} {stats.tool} fields",
        metadata=meta,
    )  # fmt: skip


def _boundary_layer(stats: Any, figs: dict[str, pathlib.Path]) -> ReportSection:
    """The boundary layer's section: its characteristics, the profiles' uncertainties and
    figures; or why there is none."""
    r = stats.result
    if r is None:
        why = stats.analysis.error or "no scale or no pulse separation"
        return ReportSection("Boundary layer", text=f"No wall units: {why}.")
    s = r.summary()
    text = (
        f"u_tau = {u_tau_text(s)}, composite fit (Clauser "
        f"{_number(s['u_tau_clauser'], '.4g') or 'not found'}"
        f"{' m/s' if math.isfinite(s['u_tau_clauser']) else ''}), "
        f"wall offset y0+ = {s['y0_plus']:.3g}, "
        f"delta_99 = {1e3 * s['delta99']:.4g} mm, Re_tau = {s['re_tau']:.4g}, "
        f"Re_theta = {s['re_theta']:.4g}, H = {s['H']:.4g}. {ERROR_BARS}"
    )
    row = {
        "U_e (m/s)": s.get("u_e"),
        "delta_99 (mm)": 1e3 * s["delta99"],
        "u_tau (m/s)": s["u_tau"],
        "u_tau Clauser (m/s)": s["u_tau_clauser"],
        "Re_tau": s["re_tau"],
        "Re_theta": s["re_theta"],
        "H": s["H"],
    }
    tables = [ReportTable("Boundary-layer characteristics", row)]
    try:
        unc: dict[str, Any] = dict(uncertainty_summary(r))
        need = pairs_for_paper(r)  # none from the bound
        if need:
            key = "fields for sampling errors as the paper's (" + ", ".join(need) + ")"
            unc[key] = tuple(need.values())
        tables.append(
            ReportTable("Statistical uncertainties (median over 30 < y+ < Re_tau, one sigma)", unc)
        )
    except InvalidInputError as exc:
        text += f"\n\nNo uncertainty summary: {exc}."
    ref = stats.reference()
    if ref is not None:
        text += "\n\n" + REPORT_TEXT + " " + "; ".join(ref.lines()[-2:]) + "."
        tables.append(ReportTable(f"Against {ref.reference}", ref.table_rows()))
    drawn = [(figs[k], CAPTIONS[k]) for k in ("mean_velocity", "reynolds_stresses",
                                              "higher_moments") if k in figs]  # fmt: skip
    return ReportSection("Boundary layer", text=text, figures=drawn, tables=tables)
