"""The figure of a run's vorticity statistics (:mod:`rspiv.campaign.vorticity`): the rms of
the vorticity fluctuation and the mean shear ``-Omega_z+`` against y+, beside a DNS profile
(``omega_z,rms+`` and ``dU+/dy+``).

Uses matplotlib's object API with the Agg canvas; writes the PNG atomically.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save

__all__ = ["plot_vorticity"]


def plot_vorticity(path: str | os.PathLike, prof: dict[str, Any], dns: Any) -> pathlib.Path:
    """Write the figure of ``prof`` (:func:`rspiv.campaign.vorticity.write_outputs`, in wall
    units) beside ``dns`` (:class:`rspiv.reference.DNSProfile`) to ``path``; rows flagged
    ``near_wall`` are left out."""
    from matplotlib.figure import Figure

    if "y_plus" not in prof:
        raise InvalidInputError("vorticity figure: the rows have no wall units")
    ok = ~np.asarray(prof["near_wall"], bool) & np.isfinite(prof["omega_rms_plus"])
    if ok.sum() < 2:
        raise InvalidInputError("vorticity figure: fewer than 2 rows away from the wall")
    yp = prof["y_plus"][ok]
    fig = Figure(figsize=(11.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2)
    ax.plot(yp, prof["omega_rms_plus"][ok], "o", ms=3, label="rspiv")
    ax.plot(dns.y_plus[1:], dns.omzrms_plus[1:], "k-", lw=1, label=dns.label())
    ax.set_ylabel(r"$\omega_{z,rms}^+$")
    ax.set_title(f"vorticity fluctuation ({prof['scheme'].replace('_', ' ')} differences)")
    bx.plot(yp, -prof["omega_mean_plus"][ok], "o", ms=3, label="rspiv")
    bx.plot(dns.y_plus[1:], dns.dudy_plus[1:], "k-", lw=1, label=dns.label())
    bx.set_ylabel(r"$-\Omega_z^+ = dU^+/dy^+$")
    bx.set_title("mean shear")
    for a in (ax, bx):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel(r"$y^+$")
        a.set_xlim(max(1.0, 0.5 * yp.min()), 2 * yp.max())
        a.legend(fontsize=8)
    return _save(fig, pathlib.Path(path), 120)
