"""Multigrid / multipass FFT cross-correlation PIV.

Coordinates follow the pixel frame of the README: x = column (right), y = row (down), origin at
the centre of the top-left pixel; displacements ``u`` (along x) and ``v`` (along y, positive
downward) are in pixels.

Windows are given as ``(w, h)``: ``w`` px wide along x and ``h`` px tall along y, so ``(32, 8)``
is 32 px streamwise by 8 px wall-normal when the flow runs along x (the paper's final window).

The work runs in Rust (``rspiv._rspiv``) with the GIL released: FFT cross-correlation of the
zero-padded windows normalised by their energies, 3-point Gaussian sub-pixel peak (or a 9-point
2D Gaussian fit), symmetric image deformation (quintic B-spline) or window offset from pass to pass,
normalised median test (Westerweel & Scarano 2005) with replacement after every pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

__all__ = ["PivField", "piv", "piv_at"]

_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)


@dataclass(frozen=True)
class PivField:
    """A PIV vector field; every array has the same 2D shape ``(ny, nx)``.

    Attributes
    ----------
    x, y : ndarray of float64
        Window centres, px (pixel frame).
    u, v : ndarray of float64
        Displacement along x (right) and y (down), px. Replaced vectors hold the interpolated
        value; vectors not computed (``masked``) are NaN.
    valid : ndarray of bool
        Passed the final validation (correlation found, median test, peak ratio).
    replaced : ndarray of bool
        Rejected by the final validation and replaced from the neighbours.
    masked : ndarray of bool
        Not computed: centre inside the mask or outside the image.
    peak_ratio : ndarray of float64
        Highest correlation peak over the second-highest (capped at 1000).
    coef : ndarray of float64
        Correlation coefficient: height of the normalised correlation peak.
    window : tuple of int
        Final window ``(w, h)`` in px (w along x).
    grid : tuple of float or None
        ``(x0, y0, dx, dy)`` of the regular grid (``x = x0 + i dx``), None for :func:`piv_at`.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    replaced: np.ndarray
    masked: np.ndarray
    peak_ratio: np.ndarray
    coef: np.ndarray
    window: tuple[int, int]
    grid: tuple[float, float, float, float] | None

    @classmethod
    def _from_native(cls, d: dict, window: tuple[int, int], shape=None) -> PivField:
        keys = ("x", "y", "u", "v", "valid", "replaced", "masked", "peak_ratio", "coef")
        arrays = {k: d[k] if shape is None else d[k].reshape(shape) for k in keys}
        grid = None if d["grid"] is None else tuple(float(g) for g in d["grid"])
        return cls(**arrays, window=tuple(window), grid=grid)

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the vector arrays."""
        return self.u.shape

    def to_xarray(self):
        """The field as an :class:`xarray.Dataset` compatible with pivpy.

        Variables ``u``, ``v`` (px) and ``chc`` (1 valid, 0 replaced, -1 not computed), plus
        ``peak_ratio``, ``coef``, ``valid``, ``replaced``, ``masked``; dims ``(y, x)``. For a
        grid field the coordinates ``x``, ``y`` are the window centres in px; for a field at
        arbitrary points (:func:`piv_at`) the dims are indexed 0..n-1 and the positions are the
        2D coordinates ``x_px``, ``y_px``.
        """
        import xarray as xr

        chc = np.where(self.masked, -1, np.where(self.valid, 1, 0)).astype(np.int8)
        dims = ("y", "x")
        data = {
            "u": (dims, self.u, {"units": "pix", "long_name": "displacement along x"}),
            "v": (dims, self.v, {"units": "pix", "long_name": "displacement along y (down)"}),
            "chc": (dims, chc, {"long_name": "1 valid, 0 replaced, -1 not computed"}),
            "peak_ratio": (dims, self.peak_ratio),
            "coef": (dims, self.coef),
            "valid": (dims, self.valid),
            "replaced": (dims, self.replaced),
            "masked": (dims, self.masked),
        }
        if self.grid is not None:
            coords = {
                "x": ("x", self.x[0, :], {"units": "pix"}),
                "y": ("y", self.y[:, 0], {"units": "pix"}),
            }
        else:
            coords = {
                "x_px": (dims, self.x, {"units": "pix"}),
                "y_px": (dims, self.y, {"units": "pix"}),
            }
        ds = xr.Dataset(data, coords=coords)
        ds.attrs.update(
            {
                "variables": "['x', 'y', 'u', 'v']",
                "units": "['pix', 'pix', 'pix/dt', 'pix/dt']",
                "window_w_h_px": list(self.window),
                "conventions": "pixel frame: x right, y down, origin at the top-left pixel centre",
            }
        )
        return ds


def _frames(frame_a, frame_b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(frame_a)
    b = np.asarray(frame_b)
    for name, f in (("frame_a", a), ("frame_b", b)):
        if f.ndim != 2:
            raise InvalidInputError(f"{name} must be a 2D array, got {f.ndim} dimension(s)")
        if f.dtype.kind not in "uif" or f.dtype.kind == "c":
            raise InvalidInputError(f"{name} has unsupported dtype {f.dtype}")
    if a.shape != b.shape:
        raise InvalidInputError(
            f"frame_a {a.shape} and frame_b {b.shape} differ in shape (rows, columns)"
        )
    if a.dtype != b.dtype or a.dtype.type not in _DTYPES:
        a = a.astype(np.float32)
        b = b.astype(np.float32)
    return a, b


def _mask(mask, shape) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask, dtype=bool)
    if m.shape != shape:
        raise InvalidInputError(f"mask {m.shape} differs in shape from the frames {shape}")
    return m


def _window(w) -> tuple[int, int]:
    try:
        ww, hh = (int(v) for v in w)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"window {w!r} is not a (w, h) pair of integers") from exc
    return ww, hh


def _per_pass(value, n: int, name: str, cast) -> list:
    if np.ndim(value) == 0:
        return [cast(value)] * n
    vals = [cast(v) for v in value]
    if len(vals) != n:
        raise InvalidInputError(f"{name} has {len(vals)} entries for {n} passes")
    return vals


def piv(
    frame_a,
    frame_b,
    passes: Sequence[tuple[int, int]] = ((64, 64), (32, 32), (32, 8)),
    overlap: float | Sequence[float] = 0.5,
    deformation: str = "symmetric",
    mask=None,
    calibration: Any = None,
    method: str | None = None,
    mapping: str = "full",
    *,
    iterations: int | Sequence[int] = 1,
    subpixel: str = "gauss3",
    interpolation: str = "bspline",
    validate: bool = True,
    median_eps: float = 0.1,
    median_threshold: float = 2.0,
    min_peak_ratio: float = 0.0,
) -> PivField:
    """Multipass PIV of a frame pair on a regular grid.

    Without ``calibration`` the field is in the image frame (px). With a ``calibration`` and a
    ``method`` the lens distortion is corrected and the field lies on the regular object grid
    (the grid of the last pass on object-frame images of the frames' shape), ``x``, ``y``, ``u``,
    ``v`` in object px:

    - ``method="images"`` (Method I): both frames (and the mask) are dewarped with the
      calibration (:func:`rspiv.dewarp`), then the regular PIV runs on them; vectors centred in
      the zero fill (object points imaged outside the sensor) are not computed (masked).
    - ``method="vectors"`` (Method II): PIV on the raw frames at the images of the object grid,
      displacements mapped to the object frame (:func:`rspiv.method2.piv_vectors`, with
      ``mapping``).

    Windows that reach past the image edge (after offset and deformation) or whose content is
    blank (zero variance, e.g. zero fill) are not correlated: ``valid`` is False and ``replaced``
    True (their value is interpolated from the valid neighbours).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D, same shape
        The two exposures, ``image[y, x]``. uint8, uint16, float32 and float64 are read in place
        (no copy for C-contiguous arrays); other dtypes are converted to float32.
    passes : sequence of (w, h)
        Window sizes in px from coarse to fine; ``w`` along x, ``h`` along y. The grid of the
        last pass is the output grid (centred in the image, every window inside it).
    overlap : float or sequence of float
        Fractional window overlap in [0, 1), one value or one per pass.
    deformation : {"symmetric", "offset"}
        How later passes follow the previous field: symmetric image deformation (interpolated
        with ``interpolation``) or a symmetric sub-pixel window offset.
    mask : ndarray of bool, optional
        Same shape as the frames, True = excluded; vectors centred on it are not computed.
    calibration : Calibration or Mapping, optional
        Object px -> image px; requires ``method``.
    method : {"images", "vectors"}, optional
        Distortion correction with ``calibration``: Method I (dewarp the images) or Method II
        (map the vectors); see above. Requires ``calibration``.
    mapping : {"full", "positions"}
        Method II's displacement mapping (:mod:`rspiv.method2`); ignored by Method I.
    iterations : int or sequence of int
        Correlation iterations per pass (each re-deforms with the latest field).
    subpixel : {"gauss3", "gauss2d"}
        3-point Gaussian per axis, or a 9-point 2D Gaussian least-squares fit.
    interpolation : {"bspline", "bspline3", "keys"}
        Interpolation of the frames at the fractional positions of deformed or offset windows:
        quintic B-spline (default; exact mirror-boundary prefilter, 6 x 6 taps applied as two
        1D passes; its bias on 2.5 px particles is below 0.006 px), cubic B-spline (as
        scipy's ``order=3`` and openpiv.windef; up to 0.018 px bias at half-pixel shifts) or
        Keys bicubic (a = -0.5), which biases sub-pixel shifts of 2-3 px particles by a few
        0.01 px.
    validate : bool
        Normalised median test with replacement after every iteration.
    median_eps, median_threshold : float
        Noise level (px) and threshold of the normalised median test.
    min_peak_ratio : float
        Reject vectors whose peak ratio is below this (0 disables).

    Returns
    -------
    PivField

    Raises
    ------
    InvalidInputError
        Frames not 2D, of different shapes, with NaN/inf, windows larger than the image, bad
        settings; ``method`` without ``calibration`` (or the reverse), an unknown ``method`` or
        ``mapping``; frames whose shape differs from a Calibration's ``image_shape``.
    """
    if mapping not in ("full", "positions"):
        raise InvalidInputError(f'mapping must be "full" or "positions", got {mapping!r}')
    if method is not None or calibration is not None:
        if method not in ("images", "vectors"):
            raise InvalidInputError(f'method must be "images" or "vectors", got {method!r}')
        if calibration is None:
            raise InvalidInputError(f"method={method!r} needs a calibration")
        from rspiv.dewarp import check_calibration_shape

        check_calibration_shape(calibration, np.shape(frame_a), "frame_a")
        check_calibration_shape(calibration, np.shape(frame_b), "frame_b")
        kw = dict(
            iterations=iterations,
            subpixel=subpixel,
            interpolation=interpolation,
            validate=validate,
            median_eps=median_eps,
            median_threshold=median_threshold,
            min_peak_ratio=min_peak_ratio,
        )
        if method == "vectors":
            from rspiv.method2 import piv_vectors

            n = len(list(passes))
            ov = _per_pass(overlap, n, "overlap", float)
            it = _per_pass(iterations, n, "iterations", int)
            return piv_vectors(
                frame_a,
                frame_b,
                calibration,
                passes,
                ov[-1],
                mapping=mapping,
                deformation="offset" if deformation == "offset" else "symmetric",
                iterations=it[-1],
                predictor_overlap=ov[:-1],
                predictor_iterations=it[:-1],
                subpixel=subpixel,
                interpolation=interpolation,
                validate=validate,
                median_threshold=median_threshold,
                median_eps=median_eps,
                min_peak_ratio=min_peak_ratio,
                mask=mask,
            )
        from rspiv.dewarp import dewarp

        a0, b0 = _frames(frame_a, frame_b)
        from rspiv.method2 import _mapping_of

        m = _mapping_of(calibration)
        da = dewarp(a0, m)
        db = dewarp(b0, m)
        # object pixels imaged outside the sensor (zero fill): True
        fill = dewarp(np.ones(a0.shape, np.float32), m) < 0.5
        if mask is not None:
            fill |= dewarp(_mask(mask, a0.shape).astype(np.float32), m, fill=1.0) > 0.5
        return piv(da, db, passes, overlap, deformation, fill, **kw)
    a, b = _frames(frame_a, frame_b)
    windows = [_window(p) for p in passes]
    if not windows:
        raise InvalidInputError("passes is empty")
    n = len(windows)
    overlaps = _per_pass(overlap, n, "overlap", float)
    iters = _per_pass(iterations, n, "iterations", int)
    d = _rspiv.piv(
        a,
        b,
        windows,
        overlaps,
        iters,
        deformation=deformation,
        subpixel=subpixel,
        interpolation=interpolation,
        validate=validate,
        median_eps=median_eps,
        median_threshold=median_threshold,
        min_peak_ratio=min_peak_ratio,
        mask=_mask(mask, a.shape),
    )
    return PivField._from_native(d, windows[-1])


def piv_at(
    frame_a,
    frame_b,
    points,
    window: tuple[int, int] | Sequence[tuple[int, int]] = (32, 8),
    predictor=None,
    *,
    iterations: int = 2,
    mask=None,
    validate: bool | None = None,
    subpixel: str = "gauss3",
    interpolation: str = "bspline",
    median_eps: float = 0.1,
    median_threshold: float = 2.0,
    min_peak_ratio: float = 0.0,
) -> PivField:
    """PIV at arbitrary image positions with given predictor displacements (Method II).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D
        As for :func:`piv`.
    points : array_like, shape (..., 2)
        Window centres ``(x, y)`` in px (pixel frame). ``(N, 2)`` for a list of points or
        ``(ny, nx, 2)`` for a structured (possibly distorted) grid, whose neighbours then serve
        the median test.
    window : (w, h) or sequence of (w, h)
        Window size(s) in px (w along x); several sizes run as successive passes at the same
        points, each starting from the previous pass's result.
    predictor : None, array_like (..., 2) or PivField
        None: zero. An array of ``(u, v)`` per point: the windows are offset symmetrically by it
        (sub-pixel). A grid :class:`PivField` (e.g. from :func:`piv` on the same frames): the
        windows are deformed by it (symmetric, interpolated with ``interpolation``): the first
        iteration deforms the whole pair once and reads each window at its fractional position
        with a common sub-pixel shift of both frames (Keys; a filter applied to both windows
        alike does not move the correlation peak); later iterations interpolate each window.
    iterations : int
        Iterations per window size; each re-offsets the windows by the latest result.
    mask : ndarray of bool, optional
        Points centred on a True pixel are not computed.
    validate : bool, optional
        Normalised median test among grid neighbours; defaults to True for ``(ny, nx, 2)``
        points and False for a ``(N, 2)`` list.
    subpixel, interpolation, median_eps, median_threshold, min_peak_ratio
        As for :func:`piv`.

    Returns
    -------
    PivField
        Arrays of shape ``points.shape[:-1]``; ``grid`` is None. Points centred outside the
        image are masked; points whose window (either frame, after offset or deformation)
        reaches past the image edge (``[-0.5, w - 0.5] x [-0.5, h - 0.5]``), or whose window is
        blank (zero variance, e.g. zero fill), are not correlated: ``valid`` False, ``coef``
        and ``peak_ratio`` 0, their value interpolated from the valid neighbours and
        ``replaced`` True.
    """
    a, b = _frames(frame_a, frame_b)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim not in (2, 3) or pts.shape[-1] != 2:
        raise InvalidInputError(f"points must have shape (N, 2) or (ny, nx, 2), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidInputError("points contain NaN or inf")
    out_shape = pts.shape[:-1]
    grid_pts = pts if pts.ndim == 3 else pts[np.newaxis, :, :]
    x = np.ascontiguousarray(grid_pts[..., 0])
    y = np.ascontiguousarray(grid_pts[..., 1])
    if validate is None:
        validate = pts.ndim == 3
    if np.ndim(window) == 1:
        windows = [_window(window)]
    else:
        windows = [_window(w) for w in window]
    kwargs = {}
    if isinstance(predictor, PivField):
        if predictor.grid is None:
            raise InvalidInputError("a PivField predictor must be a grid field (from piv)")
        kwargs.update(
            field_grid=predictor.grid,
            field_u=np.ascontiguousarray(predictor.u, dtype=np.float64),
            field_v=np.ascontiguousarray(predictor.v, dtype=np.float64),
        )
        # masked vectors of the predictor are NaN: fill them with the mean of the field
        for key in ("field_u", "field_v"):
            arr = kwargs[key]
            if not np.all(np.isfinite(arr)):
                fill = np.nanmean(arr) if np.any(np.isfinite(arr)) else 0.0
                kwargs[key] = np.where(np.isfinite(arr), arr, fill)
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
        x,
        y,
        windows,
        iterations=int(iterations),
        subpixel=subpixel,
        interpolation=interpolation,
        validate=bool(validate),
        median_eps=median_eps,
        median_threshold=median_threshold,
        min_peak_ratio=min_peak_ratio,
        mask=_mask(mask, a.shape),
        **kwargs,
    )
    return PivField._from_native(d, windows[-1], shape=out_shape)
