"""The figure of a run's frequency spectra and space-time correlation
(:mod:`rspiv.campaign.temporal`): the premultiplied spectra ``f phi_uu`` and ``f phi_vv`` at
each reference height (in wall units with a boundary-layer fit), and the space-time correlation
``R_uu(dx, lag)`` of the lowest reference with the convection velocity's line.

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_temporal"]


def plot_temporal(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.temporal.write_outputs`) to
    ``path``."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    f = np.asarray(prof["f"])
    if f.size < 3 or np.asarray(prof["lag"]).size < 2:
        raise InvalidInputError("temporal figure: fewer than 3 frequencies or 2 lags to draw")
    plus = "f_phi_uu_plus" in prof
    fig = Figure(figsize=(12.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2)
    unit = "m" if prof["si"] else "px"
    for i, y in enumerate(prof["y_ref"]):
        label = f"y = {y:.3g} {unit}"
        if "y_ref_plus" in prof:
            label += f" ($y^+$ = {prof['y_ref_plus'][i]:.0f})"
        for q, ls in (("uu", "-"), ("vv", "--")):
            spec = prof[f"f_phi_{q}_plus"][i] if plus else f * prof[f"phi_{q}"][i]
            ax.plot(f[1:], spec[1:], ls=ls, color=f"C{i}", label=f"{q}, {label}")
        floor = prof["noise_uu_plus" if plus else "noise_uu"][i]
        if np.isfinite(floor):  # the PIV's white noise floor of u, premultiplied
            ax.plot(f[1:], f[1:] * floor, ls=":", color=f"C{i}", lw=1.0)
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("f (Hz)" if prof["per_s"] else "f (cycles per pair interval)")
    ax.set_ylabel(r"$f \phi / u_\tau^2$" if plus else r"$f \phi$")
    ax.set_title("premultiplied frequency spectra (dashed: v; dotted: u's noise floor)")
    ax.legend(fontsize=7)
    dx, lag = np.asarray(prof["dx"]), np.asarray(prof["lag"])
    r = np.asarray(prof["R_uu"][0], np.float64)
    levels = np.linspace(-0.2, 1.0, 13)
    cs = bx.contourf(dx, lag, r, levels=levels, cmap="RdBu_r", extend="both")
    fig.colorbar(cs, ax=bx, label=r"$R_{uu}(\Delta x, \tau)$")
    if np.isfinite(prof["U_c"][0]):
        bx.plot(prof["U_c"][0] * lag, lag, "k--", lw=1.0,
                label=f"U_c = {prof['U_c'][0]:.3g} ({prof['U_c_ratio'][0]:.2f} U)")  # fmt: skip
        bx.legend(fontsize=8, loc="upper left")
    bx.set_xlim(dx[0], dx[-1])
    bx.set_xlabel(f"dx ({unit}, downstream)")
    bx.set_ylabel("lag (s)" if prof["per_s"] else "lag (pair intervals)")
    bx.set_title(f"space-time correlation at y = {prof['y_ref'][0]:.3g} {unit}")
    return _save(fig, pathlib.Path(path), 110)
