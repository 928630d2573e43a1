"""The figure of a comparison of two tools (:mod:`rspiv.compare`, :mod:`rspiv.compare_series`),
as a validation report shows it: per row of the reference's vectors (y down the frame, px),

- one field: the mean difference du and dv of the row, and its RMS;
- a series: both tools' mean U and their u'u', v'v' and u'v' (px per pair, px^2), and the
  mean difference dU, dV with its standard error (the pairs' row means' scatter).

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.plots.boundary_layer import _save

__all__ = ["plot_comparison"]


def plot_comparison(path: str | os.PathLike, comparison: Any, dpi: int = 110) -> pathlib.Path:
    """Write the figure of a :class:`~rspiv.compare.FieldComparison` or a
    :class:`~rspiv.compare_series.SeriesComparison` to ``path`` (PNG); returns the path."""
    from matplotlib.figure import Figure

    from rspiv.compare_series import ROW_COLUMNS  # deferred: the series imports compare

    rows = np.asarray(comparison.rows, dtype=np.float64)
    series = rows.ndim == 2 and rows.shape[1] == len(ROW_COLUMNS)
    fig = Figure(figsize=(11, 4.2) if series else (6, 4.2))
    if rows.size == 0:
        ax = fig.add_subplot(1, 1, 1)
        ax.text(0.5, 0.5, "no row compared", ha="center", va="center")
        return _save(fig, pathlib.Path(path), dpi)
    y = rows[:, 0]
    if not series:
        ax = fig.add_subplot(1, 1, 1)
        ax.plot(rows[:, 2], y, "o-", ms=3, label="mean du")
        ax.plot(rows[:, 3], y, "s-", ms=3, label="mean dv")
        ax.plot(rows[:, 4], y, "k:", label="rms |d|")
        ax.axvline(0.0, color="0.6", lw=0.8)
        ax.set_xlabel("field - reference (px)")
        ax.set_ylabel("y (px, down the frame)")
        ax.invert_yaxis()
        ax.legend(fontsize=8)
        ax.set_title(f"{pathlib.Path(comparison.field).name} against "
                     f"{pathlib.Path(comparison.reference).name}", fontsize=9)  # fmt: skip
        return _save(fig, pathlib.Path(path), dpi)
    col = {name: i for i, name in enumerate(ROW_COLUMNS)}
    panels = (
        ("mean U (px)", ("U_ref", "U_field")),
        ("stresses (px^2)", ("uu_ref", "uu_field", "vv_ref", "vv_field", "uv_ref", "uv_field")),
    )
    for k, (label, names) in enumerate(panels):
        ax = fig.add_subplot(1, 3, k + 1)
        for name in names:
            style = "o-" if name.endswith("_ref") else "s--"
            ax.plot(rows[:, col[name]], y, style, ms=3, label=name.replace("_", " "))
        ax.set_xlabel(label)
        ax.invert_yaxis()
        ax.legend(fontsize=7)
    ax = fig.add_subplot(1, 3, 3)
    for name, style in (("dU", "o-"), ("dV", "s-")):
        ax.errorbar(rows[:, col[name]], y, xerr=rows[:, col[name + "_err"]], fmt=style, ms=3,
                    capsize=2, label=f"{name} +/- its error")  # fmt: skip
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.set_xlabel("field - reference (px)")
    ax.invert_yaxis()
    ax.legend(fontsize=7)
    fig.axes[0].set_ylabel("y (px, down the frame)")
    fig.suptitle(f"{comparison.n_pairs} pairs, {comparison.n_compared} vectors compared",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    return _save(fig, pathlib.Path(path), dpi)
