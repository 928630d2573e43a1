"""The figure of a run's quadrant analysis (:mod:`rspiv.campaign.quadrant`): each quadrant's
share of u'v' against y+ (hole sizes 0 and, when asked for, 2), with a jointly Gaussian (u', v')
of the row's correlation coefficient beside it, and the joint PDF of (u'/u_rms, v'/v_rms) at
three heights (the rows within 10 % of each height pooled).

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_quadrant"]

#: Heights (y / delta_99) of the joint PDFs.
HEIGHTS = (0.1, 0.3, 0.6)
_COLOURS = ("tab:grey", "tab:red", "tab:olive", "tab:blue")


def plot_quadrant(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.quadrant.write_outputs`, in wall
    units) to ``path``; rows flagged ``near_wall`` or ``uv_unresolved`` and rows beyond delta_99
    are left out."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    if "y_plus" not in prof:
        raise InvalidInputError("quadrant figure: the rows have no wall units")
    # beyond delta_99 u'v' tends to 0 and its fractions to noise over noise
    ok = ~np.asarray(prof["near_wall"], bool) & np.isfinite(prof["fraction"][:, 0, 0])
    ok &= np.asarray(prof["y"]) <= prof["delta_99"]
    ok &= ~np.asarray(prof.get("uv_unresolved", np.zeros(ok.shape, bool)), bool)
    if ok.sum() < 2:
        raise InvalidInputError("quadrant figure: fewer than 2 rows away from the wall")
    yp = prof["y_plus"][ok]
    frac = prof["fraction"][ok]
    holes = list(np.asarray(prof["holes"], float))
    fig = Figure(figsize=(14.0, 4.4), layout="constrained")
    ax, *jx = fig.subplots(1, 1 + len(HEIGHTS), width_ratios=[2.0] + [1.0] * len(HEIGHTS))
    names = ("Q1 outward", "Q2 ejection", "Q3 inward", "Q4 sweep")
    for q, (name, c) in enumerate(zip(names, _COLOURS, strict=True)):
        if 0.0 in holes:
            ax.plot(yp, frac[:, q, holes.index(0.0)], color=c, label=f"{name}, H = 0")
            ax.plot(yp, prof["fraction_gaussian"][ok][:, q], color=c, lw=0.6, ls=":")
        if 2.0 in holes:
            ax.plot(yp, frac[:, q, holes.index(2.0)], color=c, ls="--", label=f"{name}, H = 2")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(r"$y^+$")
    ax.set_ylabel(r"$\langle u'v' \rangle_{Q,H} / \langle u'v' \rangle$")
    ax.set_title("share of u'v' by quadrant (dotted: Gaussian, same rho)")
    ax.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.14))
    c = prof["centres"]
    delta = prof["delta_99"]
    y_ok = prof["y"][ok]
    jp = prof["jpdf"][ok]
    levels = [0.005, 0.02, 0.05, 0.1, 0.15]
    n_ok = np.asarray(prof["count"], np.float64)[ok]
    for bx, h in zip(jx, HEIGHTS, strict=True):
        i = int(np.argmin(np.abs(y_ok - h * delta)))
        # the rows within 10 % of the height pooled, weighted by their samples
        near = np.abs(y_ok - y_ok[i]) <= 0.1 * y_ok[i]
        pooled = np.tensordot(n_ok[near], jp[near], axes=1) / n_ok[near].sum()
        bx.contour(c, c, pooled, levels=levels, colors="k", linewidths=0.7)
        bx.axhline(0.0, color="0.6", lw=0.6)
        bx.axvline(0.0, color="0.6", lw=0.6)
        title = f"JPDF at $y/\\delta = {y_ok[i] / delta:.2f}$, $y^+ = {yp[i]:.0f}$"
        bx.set_title(title, fontsize=9)
        bx.set_xlabel(r"$u' / u_{rms}$")
        bx.set_aspect("equal")
        bx.set_xlim(-4, 4)
        bx.set_ylim(-4, 4)
    jx[0].set_ylabel(r"$v' / v_{rms}$")
    return _save(fig, pathlib.Path(path), 120)
