"""The figure of a run's vortex population (:mod:`rspiv.campaign.vortices`): the prograde and
retrograde cores per delta_99^2 and pair against y / delta_99 (error bars: one standard error
from the batches of contiguous pairs), and their mean radius in wall units against y+ (and,
dashed, the mean Lamb-Oseen core radius of the fits kept, if any), in ``BANDS`` bands of rows
(a row holds a few cores).

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save
from rspiv.vortices import batch_density_se

__all__ = ["plot_vortices"]

#: Bands of rows the figure counts together.
BANDS = 24


def plot_vortices(path: str | os.PathLike, prof: dict[str, Any]) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.vortices.write_outputs`, in wall
    units) to ``path``."""
    from matplotlib.figure import Figure

    if "y_plus" not in prof:
        raise InvalidInputError("vortex figure: the rows have no wall units")
    # a row holds a few cores: bands of rows, their cores over their area
    y = np.asarray(prof["y"], np.float64)
    edges = np.linspace(y.min(), y.max() + 1e-12 * max(y.max(), 1), BANDS + 1)
    band = np.clip(np.searchsorted(edges, y, side="right") - 1, 0, BANDS - 1)
    count = np.asarray(prof["count"], np.float64)
    area = np.bincount(band, prof["area"], BANDS) * prof["pairs"]
    dens_se = np.full((BANDS, 2), np.nan)
    if "count_batches" in prof:  # each band's cores per batch: the densities' errors
        cb = np.asarray(prof["count_batches"])  # (batch, y, kind)
        per_band = np.zeros((cb.shape[0], BANDS, 2))
        np.add.at(per_band, (slice(None), band), cb)
        strip = np.bincount(band, prof["area"], BANDS)[:, None]
        dens_se = batch_density_se(per_band, prof["fields_batches"], strip) * prof["delta_99"] ** 2
    mid = 0.5 * (edges[1:] + edges[:-1])
    lv = prof["y"][0] / prof["y_plus"][0] if prof["y_plus"][0] > 0 else np.nan
    fig = Figure(figsize=(11.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2)
    for k, (name, marker) in enumerate((("prograde", "o-"), ("retrograde", "s-"))):
        n = np.bincount(band, count[:, k], BANDS)
        rad = np.bincount(band, np.nan_to_num(prof["radius"][:, k]) * count[:, k], BANDS)
        with np.errstate(invalid="ignore", divide="ignore"):
            dens = n / area * prof["delta_99"] ** 2
            rad = rad / n / lv
        ax.errorbar(mid / prof["delta_99"], dens, yerr=dens_se[:, k], fmt=marker, ms=3,
                    capsize=2, label=name)  # fmt: skip
        line = bx.plot(mid / lv, rad, marker, ms=3, label=name)[0]
        fitted = np.asarray(prof.get("oseen_count", np.zeros_like(count))[:, k], np.float64)
        if fitted.sum() > 0:  # the Lamb-Oseen core radius of the fits kept, dashed
            nf = np.bincount(band, fitted, BANDS)
            rc = np.bincount(band, np.nan_to_num(prof["oseen_radius"][:, k]) * fitted, BANDS)
            with np.errstate(invalid="ignore", divide="ignore"):
                rc = rc / nf / lv
            bx.plot(mid / lv, rc, "--", color=line.get_color(), label=f"{name}: Lamb-Oseen r_c")
    ax.set_xlabel(r"$y / \delta_{99}$")
    ax.set_ylabel(r"cores per $\delta_{99}^2$ and pair")
    ax.set_title(f"vortex population, {prof['pairs']} pairs")
    ax.legend()
    bx.set_xscale("log")
    bx.set_xlabel(r"$y^+$")
    bx.set_ylabel(r"mean core radius $r^+$")
    bx.legend()
    return _save(fig, pathlib.Path(path), 120)
