"""The figure of a run's pairs over the run (:mod:`rspiv.campaign.pair_quality`): per pair its
mean displacement along the run's median one (in units of it), its share of valid vectors, its
median peak ratio and its frames' brightness, the pairs unlike the run marked.

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
    across: np.ndarray,
    median: tuple[float, float],
    outliers: Mapping[int, str],
    dpi: int = 110,
) -> pathlib.Path:
    """Write the figure of one run's ``series`` (:func:`rspiv.campaign.pair_quality.series`),
    each pair's displacement ``along`` the run's ``median`` one (a share of it) and
    ``across`` it (px, :func:`rspiv.campaign.pair_quality.along_run`), with the pairs of
    ``outliers`` marked, to ``path``."""
    from matplotlib.figure import Figure

    ids = np.asarray(series["pair"])
    du, dv = median
    marked = np.isin(ids, np.fromiter(outliers, np.int64, len(outliers)))
    def share(name: str) -> np.ndarray:
        x = np.asarray(series.get(name, np.full(ids.shape, np.nan)), float)
        m = np.nanmedian(x) if np.any(np.isfinite(x)) else np.nan
        return 100 * x / m if np.isfinite(m) and m > 0 else np.full(ids.shape, np.nan)

    panels = (
        ((along,), "along the median (share)"),
        ((across,), "across the median (px)"),
        ((100 * np.asarray(series["valid"]),), "valid vectors (%)"),
        ((np.asarray(series["peak_ratio"]),), "median peak ratio"),
        ((share("signal_a"), share("signal_b")), "brightness A, B (% of the median)"),
    )
    fig = Figure(figsize=(10.0, 10.5), layout="constrained")
    axes = fig.subplots(len(panels), 1, sharex=True)
    for ax, (ys, label) in zip(axes, panels, strict=True):
        for k, y in enumerate(ys):
            ax.plot(ids, y, ".", ms=3, color=f"C{k}", label="AB"[k] if len(ys) > 1 else None)
            if np.any(marked):
                ax.plot(ids[marked], y[marked], "o", mfc="none", color="C3",
                        label="unlike the run" if k == 0 else None)  # fmt: skip
        if np.any(marked) or len(ys) > 1:
            ax.legend(loc="best")
        ax.set_ylabel(label)
    axes[-1].set_xlabel("pair")
    axes[0].set_title(f"{ids.size} pairs over the run, median displacement ({du:.2f}, {dv:.2f}) px")
    return _save(fig, pathlib.Path(path), dpi)
