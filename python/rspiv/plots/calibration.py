"""Calibration figures (matplotlib, Agg backend, written to PNG files).

- :func:`detection_overlay`: the target image with the indexed markers, the central marker,
  the rejected blobs and the lattice found.
- :func:`object_image_arrows`: normalised object points with arrows to the image points,
  magnified x20 (the paper's Fig. 5).
- :func:`monte_carlo_jpdfs`: per-marker joint PDFs of the Monte Carlo residuals with the 1 and
  2 px boxes (the paper's Fig. 9), laid out as the grid.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

__all__ = ["detection_overlay", "object_image_arrows", "monte_carlo_jpdfs", "write_all"]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def detection_overlay(
    image: np.ndarray, calibration: Any, path: str | os.PathLike[str], max_px: int = 1600
) -> pathlib.Path:
    """Draw the target image with what the calibration found.

    The image is strided to at most ``max_px`` pixels along its longer side and contrast
    stretched (1st to 99.5th percentile of the strided pixels); on it each indexed marker (a
    circle of 3 marker sigmas, with its (i, j) on the plate: relative to the fiducial when the
    plate has one, else to the central marker), the central marker, the fiducial (a magenta
    star; a second one that fixes +u, a magenta diamond with an arrow from the origin), the
    other level's markers of a two-level plate (cyan dots, not used) and the blobs that were
    detected but not indexed (:attr:`Calibration.lattice` ``rejected_px``) as red crosses, with
    a legend; the title summarises the lattice, level, polarity and origin
    (:meth:`Calibration.lattice_summary`).
    """
    plt = _plt()
    img = np.asarray(image)
    step = max(1, int(np.ceil(max(img.shape) / max_px)))
    small = img[::step, ::step]
    mk = calibration.markers
    fig, ax = plt.subplots(figsize=(12, 12 * small.shape[0] / small.shape[1] + 0.9))
    lo, hi = np.percentile(small, [1, 99.5])
    ax.imshow(small, cmap="gray", vmin=lo, vmax=hi, extent=(
        -0.5, img.shape[1] - 0.5, img.shape[0] - 0.5, -0.5))  # fmt: skip
    r = 3 * max(calibration.size_px, 1.0)
    xy, c = mk.image_px, mk.centre
    others = np.arange(len(mk)) != c
    ax.add_collection(
        _circles(plt, xy[others], r, "lime", f"indexed marker ({len(mk)}), with its (i, j)")
    )
    ax.add_collection(_circles(plt, xy[c : c + 1], 1.6 * r, "orange", "central marker"))
    pitch = float(calibration.pitch_mm)
    labels = (
        np.rint(mk.object_mm / pitch).astype(np.int64)
        if mk.object_mm is not None and pitch > 0
        else mk.index
    )
    for k, (x, y) in enumerate(xy):
        ax.text(x + r, y - r, f"{labels[k][0]},{labels[k][1]}", fontsize=6,
                color="orange" if k == c else "lime")  # fmt: skip
    lattice = calibration.lattice
    other = np.asarray((lattice or {}).get("other_level_px", np.zeros((0, 2)))).reshape(-1, 2)
    if len(other):
        ax.plot(other[:, 0], other[:, 1], ".", color="cyan", ms=4, ls="none",
                label=f"other level ({len(other)}), not used")  # fmt: skip
    fid = (lattice or {}).get("fiducial")
    if fid:
        ax.plot(*fid["image_px"], "*", color="magenta", ms=16, mfc="none", mew=1.5, ls="none",
                label=f"fiducial ({fid['kind']}): origin (0, 0)")  # fmt: skip
        axis = fid.get("axis")
        if axis:
            ax.annotate("", xy=axis["image_px"], xytext=fid["image_px"],
                        arrowprops={"arrowstyle": "->", "color": "magenta", "lw": 1.5})
            ax.plot(*axis["image_px"], "D", color="magenta", ms=10, mfc="none", mew=1.5,
                    ls="none", label=f"fiducial ({axis['kind']}): +u axis")  # fmt: skip
    if lattice is not None and len(lattice["rejected_px"]):
        rej = np.asarray(lattice["rejected_px"])
        ax.plot(rej[:, 0], rej[:, 1], "x", color="red", ms=9, mew=1.5, ls="none",
                label=f"rejected blob ({len(rej)}): detected, not on the grid")  # fmt: skip
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.07), ncol=3, fontsize=8, frameon=False)
    summary = calibration.lattice_summary()
    if summary is None:
        summary = f"{len(mk)} markers indexed of {calibration.n_detected} detected"
    ax.set_title(summary.replace("; ", "\n"), fontsize=8)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.set_xlim(-0.5, img.shape[1] - 0.5)
    ax.set_ylim(img.shape[0] - 0.5, -0.5)
    out = pathlib.Path(path)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


def _circles(plt: Any, xy: np.ndarray, radius: float, colour: str, label: str) -> Any:
    """Hollow circles of ``radius`` (data units) at ``xy``, as one collection with a label."""
    from matplotlib.collections import PatchCollection

    patches = [plt.Circle((float(x), float(y)), radius) for x, y in xy]
    return PatchCollection(patches, facecolor="none", edgecolor=colour, linewidth=0.8, label=label)


def object_image_arrows(
    calibration: Any, path: str | os.PathLike[str], magnify: float = 20.0
) -> pathlib.Path:
    """Normalised object points (red) with arrows to the image points, magnified ``magnify``."""
    plt = _plt()
    mk = calibration.markers
    s = calibration.mapping.scale
    oh = (mk.object_px - mk.object_px[mk.centre]) / s
    ih = (mk.image_px - mk.image_px[mk.centre]) / s
    d = (ih - oh) * magnify
    fig, ax = plt.subplots(figsize=(10, 5.6))
    ax.plot(oh[:, 0], oh[:, 1], "r.", ms=6)
    ax.quiver(oh[:, 0], oh[:, 1], d[:, 0], d[:, 1], angles="xy", scale_units="xy", scale=1,
              width=0.002)  # fmt: skip
    both = np.vstack([oh, oh + d])
    pad = 0.03 * float(np.ptp(both[:, 0]))
    ax.set_xlim(both[:, 0].min() - pad, both[:, 0].max() + pad)
    ax.set_ylim(both[:, 1].max() + pad, both[:, 1].min() - pad)  # y down
    ax.set_aspect("equal")
    ax.set_xlabel(r"$\hat{x}_o$")
    ax.set_ylabel(r"$\hat{y}_o$ (down)")
    ax.set_title(f"object points and arrows to the image points (x{magnify:g})")
    out = pathlib.Path(path)
    fig.savefig(out, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return out


def monte_carlo_jpdfs(result: Any, path: str | os.PathLike[str]) -> pathlib.Path:
    """Per-marker JPDF of the residuals on the marker grid, with 1 and 2 px boxes.

    Uses ``result.hist`` when present (``monte_carlo(..., hist_bins=...)``), else draws each
    marker's 1- and 2-sigma covariance ellipses.
    """
    plt = _plt()
    idx = result.index
    i0, j0 = idx.min(axis=0)
    ni, nj = idx.max(axis=0) - idx.min(axis=0) + 1
    fig, axes = plt.subplots(nj, ni, figsize=(1.3 * ni, 1.3 * nj), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    h = result.hist_half_range_px if result.hist is not None else 2.5
    t = np.linspace(0, 2 * np.pi, 64)
    for k, (i, j) in enumerate(idx):
        ax = axes[j - j0, i - i0]
        ax.set_axis_on()
        if result.hist is not None:
            hk = result.hist[k].astype(float)
            ax.imshow(np.log1p(hk), origin="lower", extent=(-h, h, -h, h), cmap="viridis")
        else:
            w, v = np.linalg.eigh(result.cov_px2[k])
            for ns in (1, 2):
                e = v @ (
                    ns * np.sqrt(np.maximum(w, 0))[:, None] * np.vstack([np.cos(t), np.sin(t)])
                )
                ax.plot(result.mean_px[k, 0] + e[0], result.mean_px[k, 1] + e[1], "b-", lw=0.6)
        for b in (1.0, 2.0):
            ax.plot([-b, b, b, -b, -b], [-b, -b, b, b, -b], color="0.5", lw=0.6)
        ax.set_xlim(-h, h)
        ax.set_ylim(h, -h)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(
        f"Monte Carlo {result.model}: residual JPDFs, N = {result.n}, boxes 1 and 2 px",
        fontsize=9,
    )
    out = pathlib.Path(path)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out


def write_all(
    directory: str | os.PathLike[str], calibration: Any, image: np.ndarray | None = None
) -> list[pathlib.Path]:
    """Write the calibration figures into ``directory`` (created); returns the paths."""
    d = pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [object_image_arrows(calibration, d / "calibration_arrows.png")]
    if image is not None:
        out.append(detection_overlay(image, calibration, d / "calibration_markers.png"))
    return out
