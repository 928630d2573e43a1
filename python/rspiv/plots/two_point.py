"""The figure of a run's streamwise spectra and two-point correlations
(:mod:`rspiv.campaign.two_point`): the premultiplied spectrogram ``k_x phi_uu / u_tau^2``
against ``lambda_x+`` and ``y+``, and ``R_uu`` against ``dx / delta_99`` at a few heights.

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_two_point", "plot_two_point_maps"]

#: Heights (y / delta_99) of the correlation curves, besides the buffer layer's y+ = 15.
HEIGHTS = (0.1, 0.3, 0.6)


def plot_two_point(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (the rows of :func:`rspiv.campaign.two_point.write_outputs`,
    in wall units) to ``path``; rows flagged ``near_wall`` are left out."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    if "y_plus" not in prof:
        raise InvalidInputError("two-point figure: the rows have no wall units")
    ok = ~np.asarray(prof["near_wall"], bool) & np.isfinite(prof["kphi_uu_plus"]).all(axis=1)
    if ok.sum() < 2:
        raise InvalidInputError("two-point figure: fewer than 2 rows away from the wall")
    yp = prof["y_plus"][ok]
    lam = prof["lambda_plus"][1:]  # k = 0 has no wavelength
    kphi = prof["kphi_uu_plus"][ok][:, 1:]
    fig = Figure(figsize=(11.0, 4.4), layout="constrained")
    ax, bx = fig.subplots(1, 2)
    cs = ax.contourf(lam, yp, kphi, levels=12, cmap="viridis")
    fig.colorbar(cs, ax=ax, label=r"$k_x \phi_{uu} / u_\tau^2$")
    short = lam[np.asarray(prof["filtered"])[1:]]
    if short.size:
        ax.axvspan(lam.min(), short.max(), fill=False, hatch="//", lw=0, ec="w")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(r"$\lambda_x^+$")
    ax.set_ylabel(r"$y^+$")
    ax.set_title("premultiplied streamwise spectrum of u")
    delta = prof["delta_99"]
    lv = prof["y"][0] / prof["y_plus"][0]
    targets = [("$y^+ = 15$", 15.0 * lv)] + [(f"$y/\\delta = {h:g}$", h * delta) for h in HEIGHTS]
    y_ok = prof["y"][ok]
    r_ok = prof["R_uu"][ok]
    for label, y in targets:
        i = int(np.argmin(np.abs(y_ok - y)))
        if abs(y_ok[i] - y) > 0.1 * y + 2 * np.min(np.diff(np.sort(y_ok))):
            continue  # no row there (the field or the flag)
        bx.plot(prof["dx"] / delta, r_ok[i], label=f"{label} ({y_ok[i] / delta:.3f} $\\delta$)")
    bx.axhline(0.0, color="0.6", lw=0.6)
    bx.set_xlabel(r"$\Delta x / \delta_{99}$")
    bx.set_ylabel(r"$R_{uu}$")
    bx.set_title("streamwise two-point correlation of u")
    bx.legend(fontsize=8)
    return _save(fig, pathlib.Path(path), 120)


def plot_two_point_maps(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the two-point maps of ``prof`` (``R_uu`` about each reference row against ``dx /
    delta_99`` and ``y / delta_99``; :func:`rspiv.campaign.two_point.write_outputs`) to
    ``path``."""
    from matplotlib.figure import Figure

    if "R_uu_map" not in prof or "delta_99" not in prof:
        raise InvalidInputError("two-point maps figure: no maps in wall units")
    delta = prof["delta_99"]
    n = len(prof["y_ref"])
    fig = Figure(figsize=(4.2 * n, 4.0), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, n, sharey=True))
    levels = np.arange(0.1, 1.01, 0.1)
    for ax, y_ref, r in zip(axes, prof["y_ref"], prof["R_uu_map"], strict=True):
        cs = ax.contourf(prof["dx"] / delta, prof["map_y"] / delta, r, levels=levels,
                         cmap="viridis", extend="neither")  # fmt: skip
        ax.contour(prof["dx"] / delta, prof["map_y"] / delta, r, levels=[0.05], colors="k",
                   linewidths=0.6)  # fmt: skip
        ax.plot([0.0], [y_ref / delta], "r+", ms=10)
        ax.set_title(f"$R_{{uu}}$ about $y/\\delta = {y_ref / delta:.2f}$")
        ax.set_xlabel(r"$\Delta x / \delta_{99}$")
        ax.set_aspect("equal", adjustable="box")
    axes[0].set_ylabel(r"$y / \delta_{99}$")
    fig.colorbar(cs, ax=axes.tolist(), label=r"$R_{uu}$", shrink=0.9)
    return _save(fig, pathlib.Path(path), 120)
