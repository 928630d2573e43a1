"""The campaign report: one Markdown file and its HTML rendering, with PNG figures and tables.

:func:`write_report` takes report sections (:class:`ReportSection`), and, as plain dicts so that
the pipeline can pass whatever it has, figures grouped by topic (calibration, Monte Carlo, wall,
boundary layer ...) and tables. Figures are referenced by relative path; a figure outside the
report folder is copied into ``figures/`` first. Both files are written atomically.

The helpers :func:`calibration_table`, :func:`wall_deviation_table`,
:func:`tbl_characteristics_table` and :func:`piv_parameters_table` build the run's versions of
the paper's tables (Sun et al.: the calibration characteristics, the wall's maximum deviation,
the boundary-layer characteristics against EuHIT, and the acquisition parameters with the
statistical uncertainties) next to the paper's values.

Table data (plain dicts) may be

- ``{name: value}`` — a two-column table (quantity, value);
- ``{row: {column: value}}`` — rows labelled by ``row``;
- ``[{column: value}, ...]`` — plain rows.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import html
import os
import pathlib
import shutil
from collections.abc import Mapping, Sequence
from typing import Any

from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_write_text

#: Values reported by Sun et al. (the paper), for the comparison columns.
PAPER_WALL_DEVIATION_PX = {
    "Distorted": 9.00,
    "Dewarped by R2": 5.42,
    "Dewarped by R2 and rotated": 1.90,
    "Dewarped by P3": 3.98,
    "Dewarped by P3 and rotated": 0.62,
}
PAPER_TBL = {
    "Sun et al. (paper)": {
        "U_inf (m/s)": 9.64,
        "delta_99 (mm)": 103,
        "u_tau (m/s)": 0.348,
        "Re_tau": 2386,
    },
    "EuHIT (Cuvier et al. 2017)": {
        "U_inf (m/s)": 9.64,
        "delta_99 (mm)": 104,
        "u_tau (m/s)": 0.346,
        "Re_tau": 2360,
    },
}
PAPER_CALIBRATION = {
    "pitch (mm)": "19.510 +/- 0.020",
    "magnification M (px/mm)": "34.538 +/- 0.5",
    "max |residual| R2 (px)": "(1.577, 1.517)",
    "max |residual| P3 (px)": "(1.742, 1.290)",
    "RMS residual R2 (px)": "(0.836, 0.681)",
    "RMS residual P3 (px)": "(0.868, 0.508)",
    "marker sigma, image (px)": 0.057,
    "marker sigma, object (px)": 0.380,
    "max distortion (%)": 0.33,
}
PAPER_PIV = {
    "U_inf (m/s)": 9.64,
    "Re_tau": 2386,
    "samples N": 34535,
    "final window x (px)": 32,
    "final window y (px)": 8,
    "final window x+": 21.7,
    "final window y+": 5.42,
    "uncertainty of U (%)": 0.825,
    "uncertainty of uu, vv (%)": 0.381,
    "uncertainty of uv (%)": 0.695,
}


@dataclasses.dataclass
class ReportTable:
    """A table: ``data`` in one of the plain-dict forms of the module docstring."""

    title: str
    data: Any
    note: str = ""


@dataclasses.dataclass
class ReportSection:
    """A report section: text paragraphs (blank-line separated), figures, tables.

    ``figures`` holds paths or ``(path, caption)`` pairs.
    """

    title: str
    text: str = ""
    figures: list[Any] = dataclasses.field(default_factory=list)
    tables: list[ReportTable] = dataclasses.field(default_factory=list)


# ---------------------------------------------------------------------------- table helpers
def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if v != v:
            return "-"
        a = abs(v)
        if a != 0 and (a >= 1e5 or a < 1e-3):
            return f"{v:.4g}"
        return f"{v:.4g}" if a < 1 else f"{v:.5g}"
    if isinstance(v, (tuple, list)):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    try:  # numpy scalars
        import numpy as np

        if isinstance(v, np.generic):
            return _fmt(v.item())
    except ImportError:  # pragma: no cover
        pass
    return str(v)


def normalise_table(data: Any) -> tuple[list[str], list[list[str]]]:
    """(header, rows of strings) of a plain-dict table (module docstring forms)."""
    if isinstance(data, Mapping):
        if data and all(isinstance(v, Mapping) for v in data.values()):
            cols: list[str] = []
            for row in data.values():
                cols += [c for c in row if c not in cols]
            header = ["", *cols]
            rows = [[str(k)] + [_fmt(r.get(c)) for c in cols] for k, r in data.items()]
            return header, rows
        return ["quantity", "value"], [[str(k), _fmt(v)] for k, v in data.items()]
    if isinstance(data, Sequence) and not isinstance(data, str):
        if not all(isinstance(r, Mapping) for r in data):
            raise InvalidInputError("table: a list table must hold dicts (one per row)")
        cols = []
        for row in data:
            cols += [c for c in row if c not in cols]
        return cols, [[_fmt(r.get(c)) for c in cols] for r in data]
    raise InvalidInputError(f"table: expected a dict or a list of dicts, got {type(data).__name__}")


def wall_deviation_table(run: Mapping[str, float]) -> dict[str, dict[str, Any]]:
    """The wall's maximum deviation from straight and level (px), this run beside the paper.

    ``run`` maps condition -> deviation; the paper's conditions are "Distorted", "Dewarped by
    R2", "Dewarped by R2 and rotated", "Dewarped by P3", "Dewarped by P3 and rotated".
    """
    rows: dict[str, dict[str, Any]] = {}
    for cond in list(PAPER_WALL_DEVIATION_PX) + [
        c for c in run if c not in PAPER_WALL_DEVIATION_PX
    ]:
        rows[cond] = {
            "this run (px)": run.get(cond),
            "paper (px)": PAPER_WALL_DEVIATION_PX.get(cond),
        }
    return rows


def tbl_characteristics_table(result, label: str = "this run") -> dict[str, dict[str, Any]]:
    """Boundary-layer characteristics (U_inf, delta_99, u_tau, Re_tau) against the paper.

    ``result`` is a :class:`~rspiv.boundary_layer.BoundaryLayerResult` or its ``summary()``.
    """
    s = result.summary() if hasattr(result, "summary") else dict(result)
    row = {
        "U_inf (m/s)": s.get("u_e"),
        "delta_99 (mm)": None if s.get("delta99") is None else 1e3 * s["delta99"],
        "u_tau (m/s)": s.get("u_tau"),
        "Re_tau": s.get("re_tau"),
        "u_tau Clauser (m/s)": s.get("u_tau_clauser"),
        "Re_theta": s.get("re_theta"),
        "H": s.get("H"),
    }
    return {label: row, **PAPER_TBL}


def calibration_table(run: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Calibration characteristics, this run beside the paper (keys as in PAPER_CALIBRATION)."""
    keys = list(PAPER_CALIBRATION) + [k for k in run if k not in PAPER_CALIBRATION]
    return {k: {"this run": run.get(k), "paper": PAPER_CALIBRATION.get(k)} for k in keys}


def piv_parameters_table(run: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Acquisition/processing parameters and statistical uncertainties beside the paper's."""
    keys = list(PAPER_PIV) + [k for k in run if k not in PAPER_PIV]
    return {k: {"this run": run.get(k), "paper": PAPER_PIV.get(k)} for k in keys}


# ---------------------------------------------------------------------------- rendering
def _md_table(t: ReportTable) -> str:
    header, rows = normalise_table(t.data)

    def cell(s: str) -> str:
        return s.replace("|", "\\|").replace("\n", " ")

    out = [f"**{t.title}**", "", "| " + " | ".join(cell(h) for h in header) + " |"]
    out.append("|" + "|".join("---" for _ in header) + "|")
    out += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    if t.note:
        out += ["", f"*{t.note}*"]
    return "\n".join(out)


def _html_table(t: ReportTable) -> str:
    header, rows = normalise_table(t.data)
    e = html.escape
    parts = [f"<table>\n<caption>{e(t.title)}</caption>"]
    parts.append("<tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
    for r in rows:
        parts.append("<tr>" + "".join(f"<td>{e(c)}</td>" for c in r) + "</tr>")
    parts.append("</table>")
    if t.note:
        parts.append(f"<p class='note'>{e(t.note)}</p>")
    return "\n".join(parts)


_CSS = """
body { font-family: sans-serif; max-width: 60em; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
caption { font-weight: bold; text-align: left; padding-bottom: 0.3em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
figure { margin: 1em 0; } figure img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #555; } .note { font-size: 0.9em; color: #555; }
"""


def _figure_entries(figs: Any) -> list[tuple[Any, str]]:
    if figs is None:
        return []
    if isinstance(figs, (str, os.PathLike)):
        return [(figs, pathlib.Path(figs).stem.replace("_", " "))]
    if isinstance(figs, Mapping):  # caption -> path
        return [(p, str(c)) for c, p in figs.items()]
    out = []
    for f in figs:
        if isinstance(f, (tuple, list)) and len(f) == 2:
            out.append((f[0], str(f[1])))
        else:
            out.append((f, pathlib.Path(f).stem.replace("_", " ")))
    return out


def _place_figure(out_dir: pathlib.Path, path: Any) -> str:
    """Relative path (posix) of the figure from out_dir, copying it under figures/ if needed."""
    p = pathlib.Path(path)
    if not p.is_absolute():
        p = (out_dir / p) if (out_dir / p).exists() else p.resolve()
    if not p.exists():
        raise InvalidInputError(f"figures: {str(path)!r} does not exist")
    p = p.resolve()
    try:
        return p.relative_to(out_dir.resolve()).as_posix()
    except ValueError:
        dest = out_dir / "figures" / p.name
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(p, dest)
        return dest.relative_to(out_dir).as_posix()


def write_report(
    out_dir: str | os.PathLike,
    *sections: ReportSection,
    title: str = "rspiv campaign report",
    figures: Mapping[str, Any] | None = None,
    tables: Mapping[str, Any] | None = None,
    metadata: Mapping[str, Any] | None = None,
    name: str = "report",
) -> dict[str, pathlib.Path]:
    """Write ``<name>.md`` and ``<name>.html`` into ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Report folder (created if missing).
    *sections : ReportSection
        Sections in order.
    figures : mapping, optional
        Topic -> figures (a path, a list of paths or ``(path, caption)`` pairs, or a
        ``{caption: path}`` dict), e.g. ``{"Calibration": [...], "Monte Carlo": [...],
        "Wall alignment": [...]}``. A topic that matches a section's title is appended to that
        section, otherwise it becomes a new section.
    tables : mapping, optional
        Table title -> plain-dict table data; they form a "Tables" section.
    metadata : mapping, optional
        Shown under the title (e.g. campaign name, rspiv version, number of pairs).

    Returns
    -------
    dict
        ``{"markdown": path, "html": path}``.
    """
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    secs = [
        dataclasses.replace(s, figures=list(s.figures), tables=list(s.tables)) for s in sections
    ]
    by_title = {s.title: s for s in secs}
    for topic, figs in (figures or {}).items():
        entries = _figure_entries(figs)
        if topic in by_title:
            by_title[topic].figures.extend(entries)
        else:
            s = ReportSection(title=str(topic), figures=entries)
            secs.append(s)
            by_title[s.title] = s
    if tables:
        secs.append(
            ReportSection(
                title="Tables", tables=[ReportTable(str(k), v) for k, v in tables.items()]
            )
        )
    meta = {"generated": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
    meta.update(metadata or {})

    md = [f"# {title}", ""]
    md += [f"- **{k}**: {_fmt(v)}" for k, v in meta.items()] + [""]
    e = html.escape
    hb = [
        "<!DOCTYPE html>",
        "<html><head><meta charset='utf-8'>",
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        "<ul>"
        + "".join(f"<li><b>{e(str(k))}</b>: {e(_fmt(v))}</li>" for k, v in meta.items())
        + "</ul>",
    ]
    for s in secs:
        md += [f"## {s.title}", ""]
        hb.append(f"<h2>{e(s.title)}</h2>")
        for para in [p.strip() for p in s.text.split("\n\n") if p.strip()]:
            md += [para, ""]
            hb.append(f"<p>{e(para)}</p>")
        for path, caption in _figure_entries(s.figures):
            rel = _place_figure(out_dir, path)
            md += [f"![{caption}]({rel})", "", f"*{caption}*", ""]
            hb.append(
                f"<figure><img src='{e(rel, quote=True)}' alt='{e(caption, quote=True)}'>"
                f"<figcaption>{e(caption)}</figcaption></figure>"
            )
        for t in s.tables:
            t = t if isinstance(t, ReportTable) else ReportTable(*t)
            md += [_md_table(t), ""]
            hb.append(_html_table(t))
    hb.append("</body></html>")
    md_path = atomic_write_text(out_dir / f"{name}.md", "\n".join(md).rstrip() + "\n")
    html_path = atomic_write_text(out_dir / f"{name}.html", "\n".join(hb) + "\n")
    return {"markdown": md_path, "html": html_path}


def uncertainty_summary(result, y_plus_min: float = 30.0) -> dict[str, float]:
    """Relative standard uncertainties (%) of U, uu, vv, uv: medians over the points with
    ``y_plus_min < y+ < Re_tau`` (one sigma; compare with the paper's Table 1). Each point's
    error is the one the run is judged by (:func:`rspiv.profiles.judged_errors`): its row's
    scatter between pairs where the row has 20 pairs or more, else the bound from n_eff."""
    import numpy as np

    from rspiv.profiles import judged_errors  # deferred: numpy-only helpers, loaded on use

    m = (result.y_plus > y_plus_min) & (result.y_plus < result.re_tau)
    if not np.any(m):
        raise InvalidInputError(f"result: no profile point with {y_plus_min} < y+ < Re_tau")

    def rel(eps, val):
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.abs(eps[m] / val[m])
        r = r[np.isfinite(r)]
        return float(100.0 * np.median(r)) if r.size else float("nan")

    eps, _ = judged_errors(result)
    return {
        "uncertainty of U (%)": rel(eps["eps_u_plus"], result.u_plus),
        "uncertainty of uu (%)": rel(eps["eps_uu_plus"], result.uu_plus),
        "uncertainty of vv (%)": rel(eps["eps_vv_plus"], result.vv_plus),
        "uncertainty of uv (%)": rel(eps["eps_uv_plus"], result.uv_plus),
    }


def pairs_for_paper(result, y_plus_min: float = 30.0) -> dict[str, int] | None:
    """The pairs a run would need for sampling errors as large as the paper's uncertainties
    (its Table 1: U 0.825 %, uu and vv 0.381 %, uv 0.695 %; the paper does not say what they
    include): per quantity, the run's pairs (the median over the rows of
    :func:`uncertainty_summary`) times the square of its relative uncertainty there over the
    paper's. Only from errors of the rows' scatter between pairs, which fall as one over the
    root of the pairs (:func:`rspiv.profiles.judged_errors`); None when the run's errors are
    the bound, or it has no such rows."""
    import numpy as np

    from rspiv.profiles import judged_errors  # deferred: numpy-only helpers, loaded on use

    _, which = judged_errors(result)
    pairs = (getattr(result, "extra", None) or {}).get("pairs")
    if which != "pairs" or pairs is None:
        return None
    try:
        unc = uncertainty_summary(result, y_plus_min)
    except InvalidInputError:
        return None
    m = (result.y_plus > y_plus_min) & (result.y_plus < result.re_tau)
    n = float(np.nanmedian(np.asarray(pairs, dtype=np.float64)[m]))
    out = {}
    papers = {"U": "uncertainty of U (%)", "uu": "uncertainty of uu, vv (%)",
              "vv": "uncertainty of uu, vv (%)", "uv": "uncertainty of uv (%)"}  # fmt: skip
    for key, paper in papers.items():
        rel = unc[f"uncertainty of {key} (%)"]
        if np.isfinite(rel) and np.isfinite(n):
            out[key] = int(np.ceil(n * (rel / PAPER_PIV[paper]) ** 2))
    return out or None


def u_tau_text(s: Mapping[str, float]) -> str:
    """``u_tau`` of a result's :meth:`~rspiv.boundary_layer.BoundaryLayerResult.summary` with
    its error: from the pairs' scatter (its jackknife, ``u_tau_std_pairs``) where there is one,
    else the fit's own said to be a lower bound (its rows taken as independent)."""
    import math

    e = s.get("u_tau_std_pairs", math.nan)
    if math.isfinite(e):
        return f"{s['u_tau']:.4g} +/- {e:.2g} m/s (one standard error from the pairs' scatter)"
    e = s.get("u_tau_std", math.nan)
    if math.isfinite(e):
        return (f"{s['u_tau']:.4g} +/- {e:.2g} m/s (the fit's own, its rows taken as "
                "independent: too small)")  # fmt: skip
    return f"{s['u_tau']:.4g} m/s"


#: What a profile's error bars are (the figures of :func:`rspiv.plots.plot_boundary_layer`).
ERROR_BARS = (
    "Error bars are one standard uncertainty: the scatter of each row between the pairs where "
    "it has 20 pairs or more, else the bound from the effective sample count (the vectors of a "
    "field taken as fully correlated along the wall)."
)


#: The caption of the skewness and flatness figure: what moves them besides the flow.
MOMENTS_CAPTION = (
    "Skewness S and flatness F of u and v (error bars: one standard error, the scatter of each "
    "row between the pairs where it has 20 pairs or more, else from the moments up to order 8, "
    "any distribution). Rows within 2.5 window heights of the wall are left out "
    "(flagged near_wall in the profile files): there the wall, its reflection and the gradient "
    "across the window skew the measured distribution, much as the DNS's S(u) at the wall. "
    "The measurement noise draws S towards 0 and F towards 3 (removed with [statistics] "
    "noise_correction); spurious vectors that pass the validation raise F"
)


def campaign_report(
    out_dir: str | os.PathLike,
    results: Mapping[str, Any],
    *,
    calibration: Mapping[str, Any] | None = None,
    wall_deviation: Mapping[str, float] | None = None,
    piv_parameters: Mapping[str, Any] | None = None,
    calibration_figures: Any = None,
    monte_carlo_figures: Any = None,
    wall_figures: Any = None,
    extra_sections: Sequence[ReportSection] = (),
    metadata: Mapping[str, Any] | None = None,
    title: str = "rspiv campaign report",
) -> dict[str, pathlib.Path]:
    """The standard campaign report: boundary-layer figures and the paper's tables.

    Parameters
    ----------
    out_dir : path-like
        Report folder; the boundary-layer figures go to ``out_dir/figures``.
    results : mapping
        Run name -> :class:`~rspiv.boundary_layer.BoundaryLayerResult`; the first is the main
        run (e.g. ``{"P3, Method II": r, "uncorrected": r0}``).
    calibration, wall_deviation, piv_parameters : mapping, optional
        This run's values for the calibration table, the wall-deviation table (condition ->
        px) and the acquisition-parameter table (the main run's uncertainties are added).
    calibration_figures, monte_carlo_figures, wall_figures : optional
        Figures in any form :func:`write_report` accepts for a topic.
    extra_sections : sequence of ReportSection
        Appended after the standard sections.
    """
    from rspiv.plots.boundary_layer import plot_boundary_layer  # deferred: matplotlib

    if not results:
        raise InvalidInputError("results: at least one boundary-layer result is needed")
    out_dir = pathlib.Path(out_dir)
    main_name, main = next(iter(results.items()))
    figs = plot_boundary_layer(out_dir / "figures", results)
    s = main.summary()
    text = (
        f"Main run: {main_name}. u_tau = {u_tau_text(s)}, composite fit (Clauser "
        f"{s['u_tau_clauser']:.4g} m/s), wall offset y0+ = {s['y0_plus']:.3g}, "
        f"delta_99 = {1e3 * s['delta99']:.4g} mm, Re_tau = {s['re_tau']:.4g}, "
        f"Re_theta = {s['re_theta']:.4g}, H = {s['H']:.4g}. Profiles in wall units of each "
        f"run's own u_tau. {ERROR_BARS}"
    )
    bl = ReportSection(
        "Boundary layer",
        text=text,
        figures=[
            (figs["mean_velocity"], "Mean streamwise velocity U+(y+)"),
            (
                figs["reynolds_stresses"],
                "Reynolds stresses uu+, vv+, -uv+ (rows within 2.5 window heights of the wall, "
                "flagged near_wall, left out: there the wall, its reflection and the gradient "
                "across the window raise the stresses)",
            ),
            *(
                [(figs["higher_moments"], MOMENTS_CAPTION)]
                if "higher_moments" in figs
                else []
            ),
        ],
        tables=[
            ReportTable(
                "Turbulent boundary-layer characteristics (as in the paper)",
                {
                    **{
                        name: tbl_characteristics_table(r, name)[name]
                        for name, r in results.items()
                    },
                    **PAPER_TBL,
                },
            )
        ],
    )
    sections: list[ReportSection] = []
    if calibration is not None or calibration_figures is not None:
        sections.append(
            ReportSection(
                "Calibration",
                figures=list(_figure_entries(calibration_figures)),
                tables=[
                    ReportTable(
                        "Calibration characteristics (as in the paper)",
                        calibration_table(calibration or {}),
                    )
                ],
            )
        )
    if monte_carlo_figures is not None:
        sections.append(
            ReportSection("Monte Carlo", figures=list(_figure_entries(monte_carlo_figures)))
        )
    if wall_deviation is not None or wall_figures is not None:
        sections.append(
            ReportSection(
                "Wall alignment",
                figures=list(_figure_entries(wall_figures)),
                tables=[
                    ReportTable(
                        "Maximum deviation of the wall from straight and level (as in the paper)",
                        wall_deviation_table(wall_deviation or {}),
                    )
                ],
            )
        )
    sections.append(bl)
    piv = dict(piv_parameters or {})
    try:
        unc = uncertainty_summary(main)
    except InvalidInputError:
        unc = {}
    piv.setdefault("uncertainty of U (%)", unc.get("uncertainty of U (%)"))
    if unc:
        piv.setdefault(
            "uncertainty of uu, vv (%)",
            (unc["uncertainty of uu (%)"], unc["uncertainty of vv (%)"]),
        )
        piv.setdefault("uncertainty of uv (%)", unc["uncertainty of uv (%)"])
    need = pairs_for_paper(main)
    if need:
        piv.setdefault("pairs for sampling errors as the paper's (" + ", ".join(need) + ")",
                       tuple(need.values()))  # fmt: skip
    piv.setdefault("Re_tau", s["re_tau"])
    piv.setdefault("U_inf (m/s)", s["u_e"])
    sections.append(
        ReportSection(
            "Acquisition and statistics",
            text=(
                "Uncertainties: median over 30 < y+ < Re_tau of the one-sigma relative "
                "uncertainty of the main run (as its error bars). Pairs for sampling errors "
                "as the paper's uncertainties: the run's pairs times the square of its "
                "uncertainty over the paper's (where its errors are the rows' scatter between "
                "pairs; the paper does not say what its uncertainties include)."
            ),
            tables=[ReportTable("PIV parameters (as in the paper)", piv_parameters_table(piv))],
        )
    )
    sections.extend(extra_sections)
    return write_report(out_dir, *sections, title=title, metadata=metadata)


__all__ = [
    "ERROR_BARS",
    "campaign_report",
    "pairs_for_paper",
    "u_tau_text",
    "uncertainty_summary",
    "PAPER_CALIBRATION",
    "PAPER_PIV",
    "PAPER_TBL",
    "PAPER_WALL_DEVIATION_PX",
    "ReportSection",
    "ReportTable",
    "calibration_table",
    "normalise_table",
    "piv_parameters_table",
    "tbl_characteristics_table",
    "wall_deviation_table",
    "write_report",
]
