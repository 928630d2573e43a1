"""The figure of a run's spectral POD (:mod:`rspiv.campaign.spod`): the premultiplied
eigenvalue spectra ``f lambda_j`` of the leading modes with the leading one's 95 % interval,
and the real part of the leading mode's ``u`` at the kept frequency where ``f lambda_1`` is
largest (the structure at one phase), over the domain.

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_spod"]


def plot_spod(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.spod.write_outputs`) to
    ``path``."""
    from matplotlib.figure import Figure

    f = np.asarray(prof["f"])
    lam = np.asarray(prof["energy"])
    if f.size < 3 or not prof["mode_f"].size:
        raise InvalidInputError("SPOD figure: fewer than 3 frequencies or no mode to draw")
    fig = Figure(figsize=(12.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2)
    fs = f[1:]
    ax.fill_between(fs, fs * prof["energy_low"][1:], fs * prof["energy_high"][1:],
                    color="C0", alpha=0.25, lw=0, label="mode 1, 95 % interval")  # fmt: skip
    for j in range(min(3, lam.shape[1])):
        ax.plot(fs, fs * lam[1:, j], color=f"C{j}", label=f"mode {j + 1}")
    ax.plot(fs, fs * prof["total"][1:], color="k", lw=0.8, label="all modes")
    if np.isfinite(prof.get("noise_total", np.nan)):
        ax.plot(fs, fs * prof["noise_total"], "k:", lw=1.0, label="noise floor, all modes")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("f (Hz)" if prof["per_s"] else "f (cycles per pair interval)")
    ax.set_ylabel(r"$f \lambda_j$")
    ax.set_title(f"SPOD spectrum ({prof['blocks']} blocks of {prof['segment']} pairs)")
    ax.legend(fontsize=8)
    i = int(np.argmax(prof["mode_f"] * lam[np.searchsorted(f, prof["mode_f"]), 0]))
    phi = np.real(prof["phi_u"][i, 0])
    lim = float(np.nanmax(np.abs(phi))) or 1.0
    unit = "m" if prof["si"] else "px"
    im = bx.pcolormesh(prof["x"], prof["y"], phi, cmap="RdBu_r", vmin=-lim, vmax=lim,
                       shading="nearest")  # fmt: skip
    fig.colorbar(im, ax=bx, label=r"Re $\phi_u$")
    speed = prof["phase_speed"][i]
    bx.set_title(f"leading mode at f = {prof['mode_f'][i]:.3g}: phase speed {speed:.3g}")
    bx.set_xlabel(f"x ({unit})")
    bx.set_ylabel(f"distance from the wall ({unit})")
    return _save(fig, pathlib.Path(path), 110)
