"""Wall-alignment figures (matplotlib, Agg backend, written to PNG files).

- :func:`wall_shape`: the apparent shape of the wall measured from the particle reflection, one
  curve per condition (raw, dewarped, dewarped and rotated), with each fitted line and the
  maximum deviation in the legend (the paper's Fig. 8 and Table 4).
- :func:`wall_profile`: one station's mean profile, its mirror image about the found wall and the
  wall position (the paper's Fig. 7).
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["wall_shape", "wall_profile"]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def wall_shape(
    walls: Mapping[str, Any],
    path: str | os.PathLike[str],
    *,
    relative: bool = True,
    title: str | None = None,
) -> pathlib.Path:
    """Plot the measured wall position against x for each condition.

    Parameters
    ----------
    walls : mapping of label -> Wall
        E.g. ``{"distorted": w_raw, "dewarped P3": w_p3, "P3 + rotation": w_rot}``.
    path : path-like
        PNG file to write.
    relative : bool
        Plot ``position - mean(position)`` so conditions share one axis (the paper's figure
        shows the shape, not the absolute row).
    title : str, optional

    Returns
    -------
    pathlib.Path
        The written file.
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for label, w in walls.items():
        ok = np.isfinite(w.position_px)
        ref = np.nanmean(w.position_px) if relative else 0.0
        (line,) = ax.plot(
            w.x_px[ok],
            w.position_px[ok] - ref,
            "o",
            ms=3,
            label=f"{label}: max deviation {w.max_deviation_px:.2f} px, "
            f"angle {w.angle_deg:+.4f} deg",
        )
        xs = np.array([w.x_px[ok].min(), w.x_px[ok].max()])
        ax.plot(xs, w.line(xs) - ref, "-", lw=1, color=line.get_color())
    ax.set_xlabel("x (px)")
    ax.set_ylabel("wall position - mean (px)" if relative else "wall position y (px)")
    ax.invert_yaxis()  # the pixel frame's y grows downward
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "Apparent shape of the wall from the particle reflection")
    fig.tight_layout()
    out = pathlib.Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def wall_profile(
    u: np.ndarray,
    y: np.ndarray,
    wall_px: float,
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
) -> pathlib.Path:
    """One station's mean streamwise profile ``u(y)`` with its mirror image about ``wall_px``.

    Parameters
    ----------
    u, y : ndarray, shape (n,)
        Mean streamwise displacement (px) and wall-normal positions (px).
    wall_px : float
        The wall found for this station (e.g. ``Wall.position_px[k]``).
    path : path-like
        PNG file to write.
    """
    plt = _plt()
    u = np.asarray(u, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    fig, ax = plt.subplots(figsize=(4.5, 6))
    ax.plot(u, y, "o-", ms=3, lw=1, label="measured")
    ax.plot(u, 2.0 * wall_px - y, "--", lw=1, label="mirrored about the wall")
    ax.axhline(wall_px, color="k", lw=1, label=f"wall y = {wall_px:.2f} px")
    ax.set_xlabel("mean u (px)")
    ax.set_ylabel("y (px)")
    ax.invert_yaxis()
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "Mirror symmetry of the profile at the wall")
    fig.tight_layout()
    out = pathlib.Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
