"""The figure of a run's conditional averages (:mod:`rspiv.campaign.conditional`): for each
reference height (rows) and event (Q2 ejection, Q4 sweep; columns), ``<u' | event>`` in colour
over the streamwise offset and the distance from the wall, arrows ``(<u'>, <v'>)`` where the
average is resolved at 95 %, and the event's point.

Axes in delta_99 when the run has a boundary-layer fit, else in the profile's units; velocities
in wall units when it has one. Uses matplotlib's object API with the Agg canvas; writes the PNG
atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_conditional"]

#: The most arrows along each axis of a panel.
ARROWS = 24


def plot_conditional(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.conditional.write_outputs`) to
    ``path``; rows flagged ``near_wall`` are left out."""
    from matplotlib.figure import Figure

    rows = ~np.asarray(prof["near_wall"], bool)
    if rows.sum() < 2 or np.asarray(prof["dx"]).size < 2:
        raise InvalidInputError("conditional figure: fewer than 2 rows or offsets to draw")
    plus = "u_plus" in prof
    scale = prof["delta_99"] if "delta_99" in prof else 1.0
    unit = r"/ \delta_{99}" if "delta_99" in prof else ("(m)" if prof["si"] else "(px)")
    x = np.asarray(prof["dx"]) / scale
    y = np.asarray(prof["y"])[rows] / scale
    u = np.asarray(prof["u_plus" if plus else "u"])[:, :, rows]
    v = np.asarray(prof["v_plus" if plus else "v"])[:, :, rows]
    ok = np.asarray(prof["resolved"], bool)[:, :, rows]
    n_ref, n_kind = u.shape[:2]
    fig = Figure(figsize=(5.2 * n_kind, 2.6 * n_ref + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(n_ref, n_kind, squeeze=False))
    lim = float(np.nanmax(np.abs(u))) if np.isfinite(u).any() else 1.0
    sy = max(1, y.size // ARROWS)
    sx = max(1, x.size // ARROWS)
    mesh = None
    for i in range(n_ref):
        for j in range(n_kind):
            ax = axes[i, j]
            mesh = ax.pcolormesh(x, y, u[i, j], cmap="RdBu_r", vmin=-lim, vmax=lim,
                                 shading="nearest")  # fmt: skip
            keep = ok[i, j][::sy, ::sx]
            xx, yy = np.meshgrid(x[::sx], y[::sy])
            if keep.any():
                ax.quiver(xx[keep], yy[keep], u[i, j][::sy, ::sx][keep],
                          v[i, j][::sy, ::sx][keep], color="k", width=0.003)  # fmt: skip
            ax.plot([0.0], [prof["y_ref"][i] / scale], "k+", ms=10, mew=1.5)
            ax.set_title(
                f"{prof['kinds'][j]} at $y = {prof['y_ref'][i] / scale:.3g}$ "
                f"({int(prof['events'][i, j])} events)",
                fontsize=9,
            )
            ax.set_aspect("equal")
            if i == n_ref - 1:
                ax.set_xlabel(f"$\\Delta x {unit}$" if "delta_99" in prof else f"dx {unit}")
            if j == 0:
                ax.set_ylabel(f"$y {unit}$" if "delta_99" in prof else f"y {unit}")
    label = r"$\langle u' \mid \mathrm{event} \rangle^+$" if plus else "<u' | event>"
    fig.colorbar(mesh, ax=axes, shrink=0.8, label=label)
    return _save(fig, pathlib.Path(path), 110)
