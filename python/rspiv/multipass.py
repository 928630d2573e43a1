"""The native multipass PIV driver, called with one :class:`~rspiv.settings.PivSettings`.

Plain PIV, no distortion correction: :func:`run_grid` (the regular multigrid PIV of
:func:`rspiv.piv`), :func:`run_points` (windows at arbitrary image points, :func:`rspiv.piv_at`)
and :func:`run_final_points` (the predictor passes on the regular grid and a final pass at given
points, in one native call on one prepared frame pair: Method II's raw-frame PIV). The work runs
in Rust (``rspiv._rspiv``) with the GIL released: FFT cross-correlation of the zero-padded windows
normalised by their energies, 3-point Gaussian sub-pixel peak (or a 9-point 2D Gaussian fit),
symmetric image deformation (quintic B-spline) or window offset from pass to pass, normalised
median test (Westerweel & Scarano 2005) with replacement after every pass.

Coordinates: pixel frame of the README (x = column, y = row down, origin at the centre of the
top-left pixel); windows ``(w, h)`` with ``w`` along x; displacements in px.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.field import PivField
from rspiv.io import read_mask
from rspiv.settings import PivSettings

__all__ = ["frames", "mask_array", "run_grid", "run_points", "run_final_points"]

_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)


def frames(frame_a: Any, frame_b: Any) -> tuple[np.ndarray, np.ndarray]:
    """The two exposures as 2D arrays of one dtype the native code reads in place (uint8,
    uint16, float32, float64; anything else is converted to float32). InvalidInputError for
    frames that are not 2D, of an unsupported dtype or of different shapes."""
    a = np.asarray(frame_a)
    b = np.asarray(frame_b)
    for name, f in (("frame_a", a), ("frame_b", b)):
        if f.ndim != 2:
            raise InvalidInputError(f"{name} must be a 2D array, got {f.ndim} dimension(s)")
        if f.dtype.kind not in "uif":
            raise InvalidInputError(f"{name} has unsupported dtype {f.dtype}")
    if a.shape != b.shape:
        raise InvalidInputError(
            f"frame_a {a.shape} and frame_b {b.shape} differ in shape (rows, columns)"
        )
    if a.dtype != b.dtype or a.dtype.type not in _DTYPES:
        a = a.astype(np.float32)
        b = b.astype(np.float32)
    return a, b


def mask_array(mask: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """A mask (True = excluded) as a bool array of the frames' ``shape``, or None; a path is
    read by :func:`rspiv.io.read_mask` (an image, or a JSON of polygons)."""
    if mask is None:
        return None
    if isinstance(mask, (str, os.PathLike)):
        return read_mask(mask, (int(shape[0]), int(shape[1])))
    m = np.asarray(mask, dtype=bool)
    if m.shape != shape:
        raise InvalidInputError(f"mask {m.shape} differs in shape from the frames {shape}")
    return m


def run_grid(frame_a: Any, frame_b: Any, settings: PivSettings, mask: Any = None) -> PivField:
    """Multipass PIV of a frame pair on the regular grid of the last pass (see
    :func:`rspiv.piv` for the conventions of the result)."""
    a, b = frames(frame_a, frame_b)
    d = _rspiv.piv(a, b, settings.to_json(), mask=mask_array(mask, a.shape))
    return PivField._from_native(d, settings.final_window)


def _predictor_field(predictor: PivField) -> dict[str, Any]:
    """A grid field as the native ``field_*`` keywords; its masked (NaN) vectors filled with
    the field's mean."""
    if predictor.grid is None:
        raise InvalidInputError("a PivField predictor must be a grid field (from piv)")
    out: dict[str, Any] = {"field_grid": predictor.grid}
    for key, comp in (("field_u", predictor.u), ("field_v", predictor.v)):
        arr = np.ascontiguousarray(comp, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            fill = np.nanmean(arr) if np.any(np.isfinite(arr)) else 0.0
            arr = np.where(np.isfinite(arr), arr, fill)
        out[key] = arr
    return out


def run_points(
    frame_a: Any,
    frame_b: Any,
    points: Any,
    windows: list[tuple[int, int]],
    settings: PivSettings,
    *,
    predictor: Any = None,
    iterations: int = 2,
    validate: bool | None = None,
    mask: Any = None,
) -> PivField:
    """PIV at arbitrary image points (see :func:`rspiv.piv_at`). ``settings`` gives the
    subpixel fit, interpolation and validation parameters; ``windows`` and ``iterations`` the
    passes at the points; ``validate`` None means: for a ``(ny, nx, 2)`` grid of points."""
    a, b = frames(frame_a, frame_b)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim not in (2, 3) or pts.shape[-1] != 2:
        raise InvalidInputError(f"points must have shape (N, 2) or (ny, nx, 2), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidInputError("points contain NaN or inf")
    out_shape = pts.shape[:-1]
    grid_pts = pts if pts.ndim == 3 else pts[np.newaxis, :, :]
    if validate is None:
        validate = pts.ndim == 3
    kwargs: dict[str, Any] = {}
    if isinstance(predictor, PivField):
        kwargs.update(_predictor_field(predictor))
    elif predictor is not None:
        p = np.asarray(predictor, dtype=np.float64)
        if p.shape != pts.shape:
            raise InvalidInputError(
                f"predictor shape {p.shape} differs from the points' shape {pts.shape}"
            )
        p = p.reshape(grid_pts.shape)
        kwargs.update(
            predictor_u=np.ascontiguousarray(p[..., 0]),
            predictor_v=np.ascontiguousarray(p[..., 1]),
        )
    d = _rspiv.piv_at(
        a,
        b,
        np.ascontiguousarray(grid_pts[..., 0]),
        np.ascontiguousarray(grid_pts[..., 1]),
        list(windows),
        settings.replace(validate=bool(validate)).to_json(),
        iterations=int(iterations),
        mask=mask_array(mask, a.shape),
        **kwargs,
    )
    return PivField._from_native(d, windows[-1], shape=out_shape)


def run_final_points(
    frame_a: Any,
    frame_b: Any,
    points: np.ndarray,
    settings: PivSettings,
    mask: Any = None,
) -> PivField:
    """The predictor passes (``settings.passes[:-1]`` on the regular grid) and the final pass
    (``settings.passes[-1]`` with its iterations) at ``points`` (ny, nx, 2) in one native call
    on one prepared frame pair (Method II's raw-frame PIV, :mod:`rspiv.correction`)."""
    a, b = frames(frame_a, frame_b)
    # the final pass runs at the given points (its overlap is not used)
    d = _rspiv.piv_final_points(
        a,
        b,
        np.ascontiguousarray(points[..., 0], dtype=np.float64),
        np.ascontiguousarray(points[..., 1], dtype=np.float64),
        settings.to_json(),
        mask=mask_array(mask, a.shape),
    )
    return PivField._from_native(d, settings.final_window)
