"""Repeatability of a target's markers between two shots: is the reported sigma honest?

A calibration reports each marker's image sigma from the detector's noise model
(:mod:`rspiv.calibration`). On a real photograph there is no truth to check it against, but a
second shot of the same plate is one: the plate's own manufacturing errors and the lens are the
same in both, so what differs between the shots' marker positions is their noise, plus whatever
moved. This module measures it.

Method
------
1. Markers are paired by image position (nearest within a quarter of the pitch after the
   shots' median shift is removed).
2. The shots' relative motion (camera or plate moved, refocused) is removed by a bivariate
   polynomial of degree :data:`MOTION_DEGREE` in image position fitted to the displacements
   ``p_b - p_a``; ``r`` are its residuals (px).
3. Shot-to-shot changes that vary over a few pitches (air shimmer, vibration of the plate) are
   no marker noise, but survive the polynomial. The *local* residual of a marker is its
   residual less the mean of its :data:`NEIGHBOURS` nearest markers', scaled by
   ``sqrt(k / (k + 1))`` so that white noise keeps its variance; what the neighbours share is
   the *field*, ``rms_field = sqrt(max(0, <r^2> - <local^2>))`` per axis.
4. The reported sigma of a pair is ``sqrt(sigma_a^2 + sigma_b^2)`` per axis (each marker's
   covariance, mean of its two axes); ``ratio = rms(local) / rms(reported)``: 1 for an honest
   detector, and the issue's band is [0.67, 1.5].

Units are image px throughout; ``ratio`` is dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from rspiv.errors import InvalidInputError

__all__ = ["Repeatability", "repeatability", "MOTION_DEGREE", "NEIGHBOURS"]

#: Degree of the polynomial that absorbs the shots' relative motion.
MOTION_DEGREE = 3
#: Neighbours whose mean residual is the local field.
NEIGHBOURS = 4


@dataclass(frozen=True)
class Repeatability:
    """What :func:`repeatability` measured (px per axis unless said otherwise).

    Attributes
    ----------
    n : int
        Markers paired.
    shift_px : tuple of float
        Median displacement of shot b against shot a.
    rms_motion_px : float
        RMS of the displacement the motion polynomial absorbed, about the median shift.
    rms_local_px : float
        RMS of the local residuals: the markers' own scatter between shots.
    rms_reported_px : float
        RMS of the reported ``sqrt(sigma_a^2 + sigma_b^2)``.
    ratio : float
        ``rms_local_px / rms_reported_px``.
    rms_field_px : float
        The part of the residuals that neighbouring markers share (shimmer, vibration).
    """

    n: int
    shift_px: tuple[float, float]
    rms_motion_px: float
    rms_local_px: float
    rms_reported_px: float
    ratio: float
    rms_field_px: float

    def __str__(self) -> str:
        return (
            f"{self.n} markers paired; shift ({self.shift_px[0]:+.3f}, {self.shift_px[1]:+.3f}) "
            f"px, motion {self.rms_motion_px:.4f} px RMS removed; markers repeat to "
            f"{self.rms_local_px:.4f} px against a reported {self.rms_reported_px:.4f} px "
            f"(actual/reported {self.ratio:.2f}); a field shared by neighbours of "
            f"{self.rms_field_px:.4f} px RMS moved between the shots"
        )


def _design(p: np.ndarray, centre: np.ndarray, half: float, degree: int) -> np.ndarray:
    x, y = (p[:, 0] - centre[0]) / half, (p[:, 1] - centre[1]) / half
    return np.column_stack([x**i * y**j for i in range(degree + 1) for j in range(degree + 1 - i)])


def _markers(c: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    mk = getattr(c, "markers", None)
    if mk is None or not hasattr(mk, "image_px") or not hasattr(mk, "cov_px2"):
        raise InvalidInputError(f"repeatability: {name} is not a Calibration with markers")
    px = np.asarray(mk.image_px, dtype=np.float64).reshape(-1, 2)
    cov = np.asarray(mk.cov_px2, dtype=np.float64).reshape(-1, 2, 2)
    return px, 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])


def repeatability(cal_a: Any, cal_b: Any, *, neighbours: int = NEIGHBOURS) -> Repeatability:
    """Measure the markers' repeatability between two calibrations of one plate.

    Parameters
    ----------
    cal_a, cal_b : Calibration
        Two shots of the same plate (:func:`rspiv.calibrate`), by the same camera.
    neighbours : int
        Nearest markers whose mean residual is the local field (>= 3).

    Returns
    -------
    Repeatability

    Raises
    ------
    InvalidInputError
        Not calibrations, marker pitches more than 10 % apart, too few markers paired (fewer
        than half of either shot's, or than 3 x the motion polynomial's terms), or
        ``neighbours`` below 3.
    """
    if not isinstance(neighbours, (int, np.integer)) or neighbours < 3:
        raise InvalidInputError(
            f"repeatability: neighbours must be an integer >= 3, got {neighbours!r}"
        )
    pa, va = _markers(cal_a, "cal_a")
    pb, vb = _markers(cal_b, "cal_b")
    terms = (MOTION_DEGREE + 1) * (MOTION_DEGREE + 2) // 2
    need = max(3 * terms, neighbours + 2)
    if min(len(pa), len(pb)) < need:
        raise InvalidInputError(
            f"repeatability: {len(pa)} and {len(pb)} markers, at least {need} are needed"
        )
    # Pair: nearest within a quarter pitch once the median shift is out (two rounds).
    pitch = float(np.median(cKDTree(pa).query(pa, k=2)[0][:, 1]))
    pitch_b = float(np.median(cKDTree(pb).query(pb, k=2)[0][:, 1]))
    if abs(pitch_b / pitch - 1.0) > 0.1:
        raise InvalidInputError(
            f"repeatability: the shots' markers are {pitch:.1f} and {pitch_b:.1f} px apart: "
            "not the same plate at the same magnification"
        )
    tree = cKDTree(pb)
    shift = np.zeros(2)
    for tol in (0.5, 0.25):
        d, k = tree.query(pa + shift)
        ok = d < tol * pitch
        if np.count_nonzero(ok) < max(need, 0.5 * max(len(pa), len(pb))):
            raise InvalidInputError(
                f"repeatability: only {np.count_nonzero(ok)} of {len(pa)} and {len(pb)} markers "
                f"pair within {tol} of the pitch ({pitch:.1f} px), at least {need} and half of "
                "them are needed: not the same plate, or not the same view?"
            )
        shift = np.median(pb[k[ok]] - pa[ok], axis=0)
    a, b = pa[ok], pb[k[ok]]
    var = va[ok] + vb[k[ok]]
    disp = b - a
    centre = 0.5 * (a.min(axis=0) + a.max(axis=0))
    half = max(1.0, 0.5 * float(np.max(a.max(axis=0) - a.min(axis=0))))
    design = _design(a, centre, half, MOTION_DEGREE)
    coef, *_ = np.linalg.lstsq(design, disp, rcond=None)
    motion = design @ coef
    r = disp - motion
    dof = max(1e-9, 1.0 - terms / len(a))
    _, nn = cKDTree(a).query(a, k=neighbours + 1)
    local = (r - r[nn[:, 1:]].mean(axis=1)) * np.sqrt(neighbours / (neighbours + 1.0))
    ms_r = float(np.mean(r**2)) / dof
    ms_local = float(np.mean(local**2)) / dof
    rms_rep = float(np.sqrt(np.mean(var)))
    return Repeatability(
        n=int(len(a)),
        shift_px=(float(shift[0]), float(shift[1])),
        rms_motion_px=float(np.sqrt(np.mean((motion - shift) ** 2))),
        rms_local_px=float(np.sqrt(ms_local)),
        rms_reported_px=rms_rep,
        ratio=float(np.sqrt(ms_local) / rms_rep) if rms_rep > 0 else float("inf"),
        rms_field_px=float(np.sqrt(max(0.0, ms_r - ms_local))),
    )
