"""The figure of a run's pairs over the run (:mod:`rspiv.campaign.pair_quality`): per pair its
mean displacement along the run's median one (in units of it), its share of valid vectors and
its median peak ratio, the pairs unlike the run marked.

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping

import numpy as np

from rspiv.plots.boundary_layer import _save

__all__ = ["plot_pairs"]


def plot_pairs(
    path: str | os.PathLike,
    series: Mapping[str, np.ndarray],
    along: np.ndarray,
    median: tuple[float, float],
    outliers: Mapping[int, str],
    dpi: int = 110,
) -> pathlib.Path:
    """Write the figure of one run's ``series`` (:func:`rspiv.campaign.pair_quality.series`),
    each pair's displacement ``along`` the run's ``median`` one
    (:func:`rspiv.campaign.pair_quality.along_run`), with the pairs of ``outliers`` marked, to
    ``path``."""
    from matplotlib.figure import Figure

    ids = np.asarray(series["pair"])
    du, dv = median
    marked = np.isin(ids, np.fromiter(outliers, np.int64, len(outliers)))
    panels = (
        (along, f"displacement along the median ({du:.2f}, {dv:.2f}) px"),
        (100 * np.asarray(series["valid"]), "valid vectors (%)"),
        (np.asarray(series["peak_ratio"]), "median peak ratio"),
    )
    fig = Figure(figsize=(10.0, 7.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for ax, (y, label) in zip(axes, panels, strict=True):
        ax.plot(ids, y, ".", ms=3, color="C0")
        if np.any(marked):
            ax.plot(ids[marked], y[marked], "o", mfc="none", color="C3", label="unlike the run")
            ax.legend(loc="best")
        ax.set_ylabel(label)
    axes[-1].set_xlabel("pair")
    axes[0].set_title(f"{ids.size} pairs over the run")
    return _save(fig, pathlib.Path(path), dpi)
