"""Monte Carlo sensitivity study of a calibration's mapping (paper section 4).

Each sample perturbs every image point by ``N(0, sigma_image_px^2)`` per axis and every object
point by ``N(0, sigma_object_px^2)``, keeps the central marker fixed, refits the model (same
centre and scale), and records each marker's residual ``eps_j = F_n(P_O,j,n) - P_I,j,n`` (fitted
minus measured, image px). Per marker it reports the mean residual, the 2 x 2 covariance, the
99 % radius and the fractions of samples within 1 and 2 px (the paper's Fig. 9 boxes), and
optionally a 2D histogram (the JPDF) or all samples.

The work runs in Rust (``dewarp_core::montecarlo``), rayon-parallel, with one ChaCha8 stream per
chunk of 2048 samples: a given ``seed`` gives identical results on any number of threads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rspiv import _rspiv
from rspiv.calibration import Calibration
from rspiv.errors import InvalidInputError
from rspiv.mapping import MODELS

__all__ = ["MonteCarloResult", "monte_carlo"]


@dataclass
class MonteCarloResult:
    """Per-marker results of :func:`monte_carlo` (rows in the calibration's marker order).

    Attributes
    ----------
    model : str
    n, n_failed : int
        Samples requested; refits that failed (excluded from the statistics).
    sigma_image_px, sigma_object_px : float
        Per-axis perturbations used.
    object_px, image_px : ndarray (m, 2)
        The nominal markers.
    index : ndarray of int (m, 2)
        Grid index of each marker.
    mean_px : ndarray (m, 2)
        Mean residual.
    cov_px2 : ndarray (m, 2, 2)
        Residual covariance.
    radius99_px : ndarray (m,)
        Radius about zero holding 99 % of the residuals.
    within1, within2 : ndarray (m,)
        Fractions of residuals within 1 px and 2 px.
    nominal_px : ndarray (m, 2)
        Residual of the unperturbed fit.
    hist : ndarray (m, bins, bins) or None
        Residual counts on ``[-h, h]^2`` (rows: y, columns: x), ``h = hist_half_range_px``.
    hist_half_range_px : float
    samples : ndarray (n_ok, m, 2) of float32 or None
    """

    model: str
    n: int
    n_failed: int
    sigma_image_px: float
    sigma_object_px: float
    object_px: np.ndarray
    image_px: np.ndarray
    index: np.ndarray
    mean_px: np.ndarray
    cov_px2: np.ndarray
    radius99_px: np.ndarray
    within1: np.ndarray
    within2: np.ndarray
    nominal_px: np.ndarray
    hist: np.ndarray | None
    hist_half_range_px: float
    samples: np.ndarray | None

    def summary(self) -> str:
        """A short text summary (worst markers and the confidence over all markers)."""
        lines = [
            f"Monte Carlo {self.model}: N = {self.n} ({self.n_failed} failed refits), "
            f"sigma_image = {self.sigma_image_px:.4f} px, "
            f"sigma_object = {self.sigma_object_px:.4f} px",
            f"99 % radius: median {np.median(self.radius99_px):.3f} px, "
            f"max {np.max(self.radius99_px):.3f} px "
            f"(marker {tuple(int(v) for v in self.index[np.argmax(self.radius99_px)])})",
            f"fraction within 1 px: min {np.min(self.within1):.4f}; within 2 px: min "
            f"{np.min(self.within2):.4f}",
            f"markers with 99 % of residuals within 2 px: {int(np.sum(self.radius99_px <= 2.0))}"
            f" of {len(self.radius99_px)}",
        ]
        return "\n".join(lines)


def monte_carlo(
    calibration: Calibration,
    n: int = 500_000,
    sigma_image_px: float | None = None,
    sigma_object_px: float | None = None,
    seed: int = 0,
    *,
    model: str | None = None,
    threads: int | None = None,
    hist_bins: int = 0,
    hist_half_range_px: float = 2.0,
    keep_samples: bool = False,
) -> MonteCarloResult:
    """Run the Monte Carlo study of a calibration.

    Parameters
    ----------
    calibration : Calibration
    n : int
        Number of samples (> 0).
    sigma_image_px, sigma_object_px : float, optional
        Per-axis perturbations (px). Defaults: the calibration's RMS marker uncertainty
        (:attr:`Calibration.image_sigma_px`) and :attr:`Calibration.object_sigma_px`.
    seed : int
        Seed; identical results for any thread count.
    model : str, optional
        Model to study (default: the calibration's).
    threads : int, optional
        Worker threads (a local rayon pool); default: all cores.
    hist_bins, hist_half_range_px : int, float
        Per-marker 2D histogram of the residuals (0 bins: none).
    keep_samples : bool
        Return every residual (n x m x 2 float32; mind the memory).

    Returns
    -------
    MonteCarloResult
    """
    if not isinstance(calibration, Calibration):
        raise InvalidInputError("monte_carlo needs a rspiv.Calibration")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n <= 0:
        raise InvalidInputError(f"n must be a positive integer, got {n!r}")
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1
    ):
        raise InvalidInputError(f"threads must be a positive integer, got {threads!r}")
    if isinstance(hist_bins, bool) or not isinstance(hist_bins, (int, np.integer)) or hist_bins < 0:
        raise InvalidInputError(f"hist_bins must be a non-negative integer, got {hist_bins!r}")
    if seed < 0:
        raise InvalidInputError(f"seed must be >= 0, got {seed!r}")
    model = (model or calibration.model).lower()
    if model not in MODELS:
        raise InvalidInputError(f"unknown model {model!r}")
    si = calibration.image_sigma_px if sigma_image_px is None else float(sigma_image_px)
    so = calibration.object_sigma_px if sigma_object_px is None else float(sigma_object_px)
    mk = calibration.markers
    r = _rspiv.monte_carlo(
        np.ascontiguousarray(mk.object_px),
        np.ascontiguousarray(mk.image_px),
        model,
        int(n),
        si,
        so,
        int(mk.centre),
        scale=float(calibration.mapping.scale),
        seed=int(seed),
        hist_bins=int(hist_bins),
        hist_half_range_px=float(hist_half_range_px),
        keep_samples=bool(keep_samples),
        threads=None if threads is None else int(threads),
    )
    return MonteCarloResult(
        model=model,
        n=int(n),
        n_failed=int(r["n_failed"]),
        sigma_image_px=si,
        sigma_object_px=so,
        object_px=mk.object_px,
        image_px=mk.image_px,
        index=mk.index,
        mean_px=r["mean_px"],
        cov_px2=r["cov_px2"],
        radius99_px=r["radius99_px"],
        within1=r["within1"],
        within2=r["within2"],
        nominal_px=r["nominal_px"],
        hist=r.get("hist"),
        hist_half_range_px=float(hist_half_range_px),
        samples=r.get("samples"),
    )
