"""Validation of calibration inputs: every function returns the checked value or raises
:class:`~rspiv.errors.InvalidInputError` with one line naming the input (and the row) and the
problem (used by :mod:`rspiv.calibration`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.mapping import MODELS, as_points

__all__ = [
    "covariance",
    "distinct",
    "image_shape",
    "inside_image",
    "model_name",
    "nonneg",
    "positive",
    "rows",
]


def model_name(model: Any) -> str:
    """``model`` in lower case: "auto", "r1", "r2" or "p3"."""
    if not isinstance(model, str) or model.lower() not in (*MODELS, "auto"):
        raise InvalidInputError(f"unknown model {model!r} (expected auto, r1, r2 or p3)")
    return model.lower()


def image_shape(v: Any) -> tuple[int, int]:
    """``v`` as (height, width): two positive integers."""
    ok = isinstance(v, (tuple, list, np.ndarray)) and len(v) == 2
    ok = ok and all(isinstance(d, (int, np.integer)) and not isinstance(d, bool) for d in v)
    if not ok or min(v) <= 0:
        raise InvalidInputError(
            f"image_shape must be (height, width) as two positive integers, got {v!r}"
        )
    return int(v[0]), int(v[1])


def rows(name: str, a: Any) -> np.ndarray:
    """``a`` as a C-contiguous float64 (n, 2) array of finite numbers, or InvalidInputError
    naming the first bad row."""
    arr = as_points(name, a)
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if len(bad):
        k = int(bad[0])
        raise InvalidInputError(
            f"{name}[{k}] = ({float(arr[k, 0])}, {float(arr[k, 1])}) is not finite "
            f"({len(bad)} such rows of {len(arr)})"
        )
    return np.ascontiguousarray(arr)


def inside_image(img: np.ndarray, shape: tuple[int, int]) -> None:
    """Every point (x, y) of ``img`` within the ``shape`` (height, width) image, pixel edges
    included; else the first one outside is named."""
    h, w = shape
    out = np.flatnonzero(
        (img[:, 0] < -0.5) | (img[:, 0] > w - 0.5) | (img[:, 1] < -0.5) | (img[:, 1] > h - 0.5)
    )
    if len(out):
        k = int(out[0])
        raise InvalidInputError(
            f"image_px[{k}] = ({img[k, 0]:g}, {img[k, 1]:g}) lies outside the {w} x {h} px "
            f"image (image_shape is (height, width) = {shape})"
        )


def distinct(name: str, pts: np.ndarray) -> None:
    """No point of ``pts`` twice; else the first repeated pair of rows is named."""
    _, first, counts = np.unique(pts, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        k = int(first[np.argmax(counts > 1)])
        dup = np.flatnonzero((pts == pts[k]).all(axis=1))
        raise InvalidInputError(
            f"{name} rows {int(dup[0])} and {int(dup[1])} are the same point "
            f"({pts[k, 0]:g}, {pts[k, 1]:g})"
        )


def covariance(cov_px2: Any, sigma_px: Any, n: int) -> np.ndarray | None:
    """The (n, 2, 2) covariances (px^2) from ``cov_px2`` (symmetric positive definite) or
    ``sigma_px`` (isotropic, one number or one per point, > 0); None when neither is given."""
    if cov_px2 is not None and sigma_px is not None:
        raise InvalidInputError("give cov_px2 or sigma_px, not both")
    if sigma_px is not None:
        try:
            sig = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (n,))
        except (TypeError, ValueError):
            raise InvalidInputError(
                f"sigma_px must be a number or {n} numbers (one per point), got "
                f"{np.shape(sigma_px) or sigma_px!r}"
            ) from None
        bad = np.flatnonzero(~(np.isfinite(sig) & (sig > 0)))
        if len(bad):
            raise InvalidInputError(f"sigma_px[{int(bad[0])}] = {float(sig[bad[0]])} must be > 0")
        return sig[:, None, None] ** 2 * np.eye(2)
    if cov_px2 is None:
        return None
    try:
        cov = np.array(cov_px2, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"cov_px2: not an array of numbers ({exc})") from None
    if cov.shape != (n, 2, 2):
        raise InvalidInputError(f"cov_px2 must have shape ({n}, 2, 2), got {cov.shape}")
    sxx, syy, sxy, syx = cov[:, 0, 0], cov[:, 1, 1], cov[:, 0, 1], cov[:, 1, 0]
    ok = np.isfinite(cov).all(axis=(1, 2)) & (sxx > 0) & (syy > 0)
    ok &= np.isclose(sxy, syx, rtol=1e-9, atol=0.0)
    bad = np.flatnonzero(~(ok & (sxx * syy > sxy * syx)))
    if len(bad):
        k = int(bad[0])
        raise InvalidInputError(
            f"cov_px2[{k}] = {cov[k].tolist()} is not a symmetric positive definite covariance"
        )
    return np.ascontiguousarray(cov)


def positive(name: str, v: Any) -> float:
    """``v`` as a finite float > 0."""
    return _number(name, v, strict=True)


def nonneg(name: str, v: Any) -> float:
    """``v`` as a finite float >= 0."""
    return _number(name, v, strict=False)


def _number(name: str, v: Any, *, strict: bool) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {v!r}") from None
    if not (np.isfinite(f) and (f > 0 if strict else f >= 0)):
        raise InvalidInputError(f"{name} must be {'>' if strict else '>='} 0, got {v!r}")
    return f
