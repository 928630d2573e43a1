"""The convergence figure of a run (:mod:`rspiv.convergence`): per statistic (``U``, ``uu``,
``vv``, ``uv``) the relative departure of the first ``n`` pairs' value from the whole run's at
a few heights, against ``n``, with the band of two standard deviations pairs of one flow
would stray by.

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Sequence

import numpy as np

from rspiv.convergence import STATISTICS, Convergence
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_convergence"]


def plot_convergence(
    path: str | os.PathLike,
    cv: Convergence,
    heights: Sequence[tuple[int, str]],
    title: str = "",
    dpi: int = 110,
) -> pathlib.Path:
    """Write the convergence figure of ``cv`` at ``heights`` (``(row, label)`` each: the
    profile's row and how the legend names its height) to ``path``: per statistic, ``100
    (X_n - X_N) / |X_N|`` against the pairs ``n`` (log scale) and the band ``+/- 2`` of
    :attr:`Convergence.band` about zero, shaded in the height's colour."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    fig = Figure(figsize=(10.0, 7.0), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True).ravel()
    n = np.asarray(cv.pairs, dtype=np.float64)
    for ax, key in zip(axes, STATISTICS, strict=True):
        vals = cv.values[key]
        for c, (row, label) in enumerate(heights):
            with np.errstate(invalid="ignore", divide="ignore"):
                ref = abs(vals[-1, row])
                dep = 100 * (vals[:, row] - vals[-1, row]) / ref
                band = 200 * cv.band[key][:, row] / ref
            ax.fill_between(n, -band, band, color=f"C{c}", alpha=0.12, lw=0)
            ax.plot(n, dep, "o-", ms=3, color=f"C{c}", label=label)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())  # 10, 100, not 10^1, 10^2
        ax.xaxis.set_minor_formatter(NullFormatter())
        ticks = [int(v) for v in n]  # the prefixes' pairs; many: the powers of ten and the run's
        if len(ticks) > 8:
            ticks = [t for t in ticks[:-1] if str(t).rstrip("0") == "1"] + ticks[-1:]
        ax.set_xticks(ticks)
        ax.set_ylabel(f"{key} of the first n pairs less the run's (%)")
    for ax in axes[2:]:
        ax.set_xlabel("pairs n")
    axes[0].legend(loc="best", fontsize="small")
    fig.suptitle(title or f"Convergence over {int(n[-1])} pairs (shaded: two standard deviations)")
    return _save(fig, pathlib.Path(path), dpi)
