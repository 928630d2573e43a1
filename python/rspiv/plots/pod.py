"""The figure of a run's POD (:mod:`rspiv.campaign.pod`): the energy spectrum (each mode's share
with North's error bar, open where a mode is not separated from a neighbour, and the cumulative
share) and the streamwise component of the four leading modes in the flow's frame (x
downstream, y up from the wall).

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_pod"]


def plot_pod(path: str | os.PathLike, prof: dict[str, Any], dpi: int = 120) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.pod.write_outputs`) to ``path``
    (the modes drawn on at most 400 x 400 of their vectors)."""
    from matplotlib.figure import Figure

    energy = np.asarray(prof["energy"])
    if energy.size == 0:
        raise InvalidInputError("POD figure: no mode")
    k = np.arange(1, energy.size + 1)
    frac = np.asarray(prof["fraction"])
    err = np.asarray(prof["north"]) / prof["total"]
    sep = np.asarray(prof["separated"], bool)
    shown = min(4, energy.size)
    fig = Figure(figsize=(12.0, 3.2 * (1 + (shown + 1) // 2)), layout="constrained")
    grid = fig.add_gridspec(1 + (shown + 1) // 2, 2)
    ax = fig.add_subplot(grid[0, :])
    ax.errorbar(k, 100 * frac, yerr=100 * err, fmt="none", ecolor="C0", lw=1)
    ax.plot(k[sep], 100 * frac[sep], "o", color="C0", label="separated")
    ax.plot(k[~sep], 100 * frac[~sep], "o", mfc="none", color="C0", label="not separated")
    ax.set_xlabel("mode")
    ax.set_ylabel("share of the fluctuation energy (%)")
    ax.set_title(f"POD of {prof['pairs']} pairs, {prof['vectors']} vectors")
    bx = ax.twinx()
    bx.plot(k, 100 * np.asarray(prof["cumulative"]), "k-", lw=1, label="cumulative")
    bx.set_ylabel("cumulative (%)")
    bx.set_ylim(0, 100)
    ax.legend(loc="upper center")
    unit = "m" if prof.get("si") else "px"
    sy = max(1, len(prof["y"]) // 400)
    sx = max(1, len(prof["x"]) // 400)
    x = np.asarray(prof["x"], np.float64)[::sx]
    y = np.asarray(prof["y"], np.float64)[::sy]
    for i in range(shown):
        cx = fig.add_subplot(grid[1 + i // 2, i % 2])
        phi = np.asarray(prof["phi_u"][i], np.float64)[::sy, ::sx]
        lim = np.nanmax(np.abs(phi)) or 1.0
        im = cx.pcolormesh(x, y, phi, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="nearest")
        cx.set_title(f"mode {i + 1}: u ({100 * frac[i]:.1f} %)")
        cx.set_xlabel(f"x ({unit})")
        cx.set_ylabel(f"y from the wall ({unit})")
        fig.colorbar(im, ax=cx, shrink=0.8)
    return _save(fig, pathlib.Path(path), dpi)
