"""Distortion correction of PIV: Method I, Method II and the position-only variant.

This module is the one home of the correction; :func:`rspiv.piv`, the campaign and the wall
table all call it. The calibration maps object px (the dewarped frame) to image px (the raw
sensor): ``x = F(X)``, its rotation included.

Method I (``"I"``, alias ``"images"``): both frames (and the mask) are dewarped
(:func:`rspiv.dewarp`, the object frame sampled through ``F``), then the regular multigrid PIV
runs on them (:func:`dewarp_pair`, :func:`correct`). Object pixels imaged outside the sensor are
zero fill; vectors centred in it are not computed (masked) unless the caller asks to keep the
fill unmasked (``zero_fill="keep"``, then its windows are blank and not correlated).

Method II (``"II"``, alias ``"vectors"``): for every point ``X`` of the regular object grid (the
grid :func:`rspiv.piv` would give on the dewarped frames, so Methods I and II share their vector
positions) the windows are placed at its image position ``x = F(X)`` on the raw frames, offset or
deformed by a coarse predictor measured on the raw frames, and the measured image displacement
``d`` is mapped back to the object frame:

- ``mapping="full"`` (rspiv's default): through the exact inverse, symmetric about the window
  centre as the central-difference PIV measures it::

      D = F^-1(x + d/2) - F^-1(x - d/2)

  so the local magnification, shear and rotation of the distortion act on the displacement too;
- ``mapping="positions"`` (the paper's correction): the position is mapped (``X``) and the
  displacement is kept as measured, ``D = d``. This leaves a bias of order
  ``|d| * |J(F^-1) - I|`` (about 0.08 px at 32 px displacement in the paper); see
  :func:`position_only_bias`.

Without a given predictor each method is one native call (``correction_core::method_one`` /
``method_two``, the path ``rspiv-engine piv --calibration cal.json --method I|II`` runs, so the
engine's vectors equal the API's).

Cost of Method II. Without a given predictor the raw-frame PIV runs on one prepared frame pair
(``piv_core::piv_with_final_points``): the predictor passes (all but the
last window size, a plain PIV of the raw frames, the same work as Method I's first passes on the
dewarped frames) and the final pass at the image points share the frames' B-spline
coefficients. The final pass runs once per point (``iterations=1``, as every pass of
:func:`rspiv.piv` by default). With ``deformation="offset"`` (the campaign's default) the final
windows are shifted by the predictor as in Method I's offset pass; with ``"symmetric"`` the raw
pair is deformed once by the predictor (as Method I deforms the dewarped pair) and each window is
read at its fractional position with a common sub-pixel shift of both frames. Method II saves the
three dewarps (both frames and the fill mask). Measured on one 47 MP pair (2 cores, loaded
machine, ``python benches/bench_method2.py --scale 1.0``): offset 8.5 s against 9.6 s for Method I
(II/I 0.89), symmetric 10.3 s against 9.9 s (II/I 1.03), at the same accuracy (RMS vs truth
0.095 / 0.095 px offset, 0.050 / 0.053 px symmetric, Method I / II). When the uncorrected field of
the same pair is computed anyway (the campaign's comparison run), pass it as ``predictor``: the
final pass (:func:`rspiv.multipass.run_points`, which builds the coefficients again) is then all
Method II adds.

All maps are vectorised (one call of ``Mapping.forward``/``inverse`` per field, no Python loop
over windows). Coordinates: README pixel frame (x = column, y = row down); ``u``, ``v`` along x
and y in object px.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.ndimage import map_coordinates

from rspiv import _rspiv
from rspiv.dewarp import check_calibration_shape, dewarp, native_mapping
from rspiv.errors import InvalidInputError
from rspiv.field import PivField
from rspiv.multipass import frames, mask_array, run_final_points, run_grid, run_points
from rspiv.settings import (
    OPTION_KEYS,
    PivSettings,
    parse_choice,
    parse_mapping_mode,
    parse_method,
    per_pass,
)
from rspiv.vector_files import VectorFile, as_vectors
from rspiv.vector_sampling import sample_at

__all__ = [
    "correct",
    "correct_vectors",
    "dewarp_pair",
    "grid_for_windows",
    "final_grid",
    "map_displacements",
    "mapping_of",
    "method_one",
    "method_two",
    "piv_vectors",
    "position_only_bias",
]

#: How Method I treats the dewarped frames' zero fill (object px imaged outside the sensor):
#: ``"mask"`` (vectors centred in it are not computed) or ``"keep"`` (no mask; its blank windows
#: are not correlated and the caller filters the windows that reach past the sensor).
ZERO_FILL = ("mask", "keep")


def mapping_of(calibration: Any) -> Any:
    """The object px -> image px mapping of a :class:`rspiv.Calibration` or a
    :class:`rspiv.Mapping` (InvalidInputError for anything else)."""
    m = getattr(calibration, "mapping", calibration)
    if not (hasattr(m, "forward") and hasattr(m, "inverse")):
        raise InvalidInputError(
            "calibration must be an rspiv Calibration or Mapping (forward and inverse maps), "
            f"got {type(calibration).__name__}"
        )
    return m


def grid_for_windows(
    shape: tuple[int, int], window: tuple[int, int], overlap: float
) -> tuple[np.ndarray, np.ndarray]:
    """Window centres of :func:`rspiv.piv`'s grid for one window size (the same formula as the
    Rust ``Grid::for_windows``): the grid is centred in an image of ``shape = (h, w)`` with every
    window inside it and its top-left pixel on an integer position.

    Returns
    -------
    x, y : ndarray, shape (ny, nx)
        Window centres in px.
    """
    height, width = (int(s) for s in shape)
    w, h = (int(s) for s in window)
    if w < 4 or h < 4 or w > width or h > height:
        raise InvalidInputError(
            f"window {w} x {h} px does not fit the image ({width} x {height} px) or is < 4 px"
        )
    if not (0.0 <= overlap < 1.0):
        raise InvalidInputError(f"overlap {overlap} is outside [0, 1)")
    sx = max(int(round(w * (1.0 - overlap))), 1)
    sy = max(int(round(h * (1.0 - overlap))), 1)
    nx = (width - w) // sx + 1
    ny = (height - h) // sy + 1
    mx = (width - w - (nx - 1) * sx) // 2
    my = (height - h - (ny - 1) * sy) // 2
    xs = mx + (w - 1) / 2.0 + sx * np.arange(nx, dtype=np.float64)
    ys = my + (h - 1) / 2.0 + sy * np.arange(ny, dtype=np.float64)
    return np.meshgrid(xs, ys)


def final_grid(shape: tuple[int, int], settings: PivSettings) -> tuple[np.ndarray, np.ndarray]:
    """Window centres of the last pass of ``settings`` on a frame of ``shape = (h, w)``: the
    grid :func:`rspiv.piv` gives, cut to the points whose windows lie inside ``settings.roi``
    when given (``correction_core::object_grid``: the region checked against ``shape`` and the
    windows).

    Returns
    -------
    x, y : ndarray, shape (ny, nx)
        Window centres in px of the frame.
    """
    (gx, gy), cut = _object_grid(shape, settings)
    return gx[cut], gy[cut]


def _object_grid(
    shape: tuple[int, int], settings: PivSettings
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[slice, slice]]:
    """The grid the final pass runs on (in a region of interest with two more rings of points
    around it, ``correction_core::object_grid_ring``) and the slices (rows, columns) of
    :func:`final_grid`'s points in it."""
    (x0, y0, dx, dy, nx, ny), (i0, j0), (nx0, ny0) = _rspiv.object_grid(
        (int(shape[0]), int(shape[1])), settings.to_json()
    )
    grid = np.meshgrid(x0 + dx * np.arange(nx), y0 + dy * np.arange(ny))
    return grid, (slice(j0, j0 + ny0), slice(i0, i0 + nx0))


def _region_around(
    points: np.ndarray, settings: PivSettings, shape: tuple[int, int]
) -> tuple[tuple[slice, slice], tuple[int, int]]:
    """The slices (rows, columns) of the frames holding ``points`` (..., 2) and the margin a
    region of interest reads around them (``piv_core::Roi::around``, ``roi_margin``), and their
    origin ``(x0, y0)``."""
    xy = np.ascontiguousarray(points.reshape(-1, 2).T)
    r = _rspiv.region_around(xy[0], xy[1], settings.to_json(), (int(shape[0]), int(shape[1])))
    x0, y0, x1, y1 = r if r is not None else (0, 0, int(shape[1]), int(shape[0]))
    return (slice(y0, y1), slice(x0, x1)), (x0, y0)


def map_displacements(
    mapping: Any, image_xy: np.ndarray, d: np.ndarray, mode: str = "full"
) -> np.ndarray:
    """Object-frame displacements of image displacements ``d`` measured at image points.

    Parameters
    ----------
    mapping : Mapping
        Object px -> image px.
    image_xy, d : ndarray, shape (N, 2)
        Window centres (image px) and their displacements (image px); non-finite rows give NaN.
    mode : {"full", "positions"}
        See the module docstring.

    Returns
    -------
    ndarray, shape (N, 2)
        Displacements in object px (NaN where ``d`` is not finite or the inverse fails).
    """
    if parse_mapping_mode(mode) == "positions":
        return np.array(d, dtype=np.float64, copy=True)
    d = np.asarray(d, dtype=np.float64)
    ok = np.all(np.isfinite(d), axis=1)
    out = np.full(d.shape, np.nan)
    if not ok.any():
        return out
    p = np.asarray(image_xy, dtype=np.float64)[ok]
    half = 0.5 * d[ok]
    ends = mapping.inverse(np.concatenate([p - half, p + half]), on_fail="nan")
    n = int(ok.sum())
    out[ok] = ends[n:] - ends[:n]
    return out


def map_sigmas(
    mapping: Any, object_xy: np.ndarray, sigma: np.ndarray, mode: str = "full"
) -> np.ndarray:
    """Object-frame standard uncertainties of image displacements, as :func:`map_displacements`
    carries the displacements (``correction_core::map_sigmas``, the same equations).

    To first order the object displacement is ``J d`` with ``J`` the Jacobian of the inverse
    mapping at the image point, the inverse of the forward mapping's Jacobian at the object
    point (central differences over 1 object px); with independent errors of u and v,
    ``sigma_U^2 = J11^2 sigma_u^2 + J12^2 sigma_v^2`` and ``sigma_V^2 = J21^2 sigma_u^2 +
    J22^2 sigma_v^2``.

    Parameters
    ----------
    mapping : Mapping
        Object px -> image px.
    object_xy, sigma : ndarray, shape (N, 2)
        Object points of the vectors and the (sigma_u, sigma_v) of their image displacements.
    mode : {"full", "positions"}
        ``"positions"`` returns ``sigma`` unchanged.

    Returns
    -------
    ndarray, shape (N, 2)
        Uncertainties in object px (NaN where a sigma is not finite or ``J`` is singular).
    """
    sigma = np.array(sigma, dtype=np.float64, copy=True)
    if parse_mapping_mode(mode) == "positions":
        return sigma
    p = np.asarray(object_xy, dtype=np.float64)
    ex, ey = np.array([0.5, 0.0]), np.array([0.0, 0.5])
    f = mapping.forward(np.concatenate([p + ex, p - ex, p + ey, p - ey]))
    n = len(p)
    jx, jy = f[:n] - f[n : 2 * n], f[2 * n : 3 * n] - f[3 * n :]
    a, c, b, d = jx[:, 0], jx[:, 1], jy[:, 0], jy[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        det = a * d - b * c
        det = np.where(np.abs(det) > 1e-12, det, np.nan)
        j11, j12, j21, j22 = d / det, -b / det, -c / det, a / det
    su, sv = sigma[:, 0], sigma[:, 1]
    return np.column_stack(
        [np.hypot(j11 * su, j12 * sv), np.hypot(j21 * su, j22 * sv)]
    )


def position_only_bias(calibration: Any, object_xy: np.ndarray, d_object: np.ndarray) -> np.ndarray:
    """Bias (object px) of the position-only correction for a true object displacement.

    For an object displacement ``D`` at object point ``X`` the image displacement is
    ``d = F(X + D/2) - F(X - D/2)``; the position-only correction reports ``d``, so its error is
    ``d - D``. Returns that error, shape (N, 2).
    """
    m = mapping_of(calibration)
    x = np.asarray(object_xy, dtype=np.float64)
    dd = np.asarray(d_object, dtype=np.float64)
    ends = m.forward(np.concatenate([x - 0.5 * dd, x + 0.5 * dd]))
    n = len(x)
    return (ends[n:] - ends[:n]) - dd


def _shape(object_shape: Any) -> tuple[int, int] | None:
    """An object shape ``(h, w)`` as ints (None: the frames' shape)."""
    if object_shape is None:
        return None
    h, w = (int(v) for v in object_shape)
    if h < 1 or w < 1:
        raise InvalidInputError(f"object_shape must be (height, width) >= 1, got {object_shape}")
    return h, w


# -- Method I --------------------------------------------------------------------------------------
def dewarp_pair(
    frame_a: Any,
    frame_b: Any,
    mapping: Any,
    *,
    object_shape: tuple[int, int] | None = None,
    mask: Any = None,
    zero_fill: str = "mask",
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Both frames and the mask dewarped into the object frame (Method I's first step).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D, same shape
        The raw exposures.
    mapping : Calibration or Mapping
        Object px -> image px.
    object_shape : (h, w), optional
        Shape of the object frame (default: the frames' shape).
    mask : ndarray of bool, optional
        Raw-frame mask (True = excluded), dewarped with fill 1 (outside the sensor: excluded).
    zero_fill : {"mask", "keep"}
        ``"mask"``: the object mask also covers the zero fill (object px imaged outside the
        sensor); ``"keep"``: only the dewarped ``mask``.

    Returns
    -------
    a, b : ndarray of float32
        The dewarped frames.
    object_mask : ndarray of bool or None
        True = excluded, in the object frame; None when nothing is excluded by request.
    """
    zero_fill = parse_choice(zero_fill, ZERO_FILL, "zero_fill")
    m = mapping_of(mapping)
    a0, b0 = frames(frame_a, frame_b)
    raw_mask = mask_array(mask, a0.shape)
    out = None if object_shape is None else tuple(int(v) for v in object_shape)
    da = dewarp(a0, m, output_shape=out)
    db = dewarp(b0, m, output_shape=out)
    object_mask = None
    if zero_fill == "mask":
        object_mask = dewarp(np.ones(a0.shape, np.float32), m, output_shape=out) < 0.5
    if raw_mask is not None:
        dm = dewarp(raw_mask.astype(np.float32), m, output_shape=out, fill=1.0) > 0.5
        object_mask = dm if object_mask is None else object_mask | dm
    return da, db, object_mask


def method_one(
    frame_a: Any,
    frame_b: Any,
    calibration: Any,
    settings: PivSettings,
    *,
    object_shape: tuple[int, int] | None = None,
    mask: Any = None,
    zero_fill: str = "mask",
) -> PivField:
    """Method I: :func:`dewarp_pair`, then the regular multipass PIV of the dewarped frames
    (object px; vectors centred on the object mask are masked), in one native call
    (``correction_core::method_one``, the path ``rspiv-engine piv --method I`` runs)."""
    zero_fill = parse_choice(zero_fill, ZERO_FILL, "zero_fill")
    native = native_mapping(mapping_of(calibration))
    if native is None:  # a duck-typed mapping (forward/inverse): the composition in Python
        da, db, dmask = dewarp_pair(
            frame_a, frame_b, calibration, object_shape=object_shape, mask=mask, zero_fill=zero_fill
        )
        return run_grid(da, db, settings, dmask)
    a, b = frames(frame_a, frame_b)
    check_calibration_shape(calibration, a.shape)
    d = _rspiv.method_one(
        a,
        b,
        native,
        settings.to_json(),
        object_shape=_shape(object_shape),
        mask=mask_array(mask, a.shape),
        zero_fill=zero_fill,
    )
    return PivField._from_native(d, settings.final_window)


# -- Method II -------------------------------------------------------------------------------------
def _sample_field(field: PivField, points: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a grid field's (u, v) at points (N, 2) (edge values outside;
    vectors not computed are filled with the field's mean)."""
    if field.grid is None:
        raise InvalidInputError("the predictor must be a grid field (from rspiv.piv)")
    x0, y0, dx, dy = field.grid
    c = np.vstack([(points[:, 1] - y0) / dy, (points[:, 0] - x0) / dx])
    out = []
    for comp in (field.u, field.v):
        arr = np.asarray(comp, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            fill = np.nanmean(arr) if np.any(np.isfinite(arr)) else 0.0
            arr = np.where(np.isfinite(arr), arr, fill)
        out.append(map_coordinates(arr, c, order=1, mode="nearest"))
    return np.column_stack(out)


def method_two(
    frame_a: Any,
    frame_b: Any,
    calibration: Any,
    settings: PivSettings,
    *,
    mapping: str = "full",
    object_shape: tuple[int, int] | None = None,
    predictor: PivField | None = None,
    mask: Any = None,
) -> PivField:
    """Method II with one :class:`PivSettings` (module docstring).

    ``settings.passes[:-1]`` (with their overlaps and iterations) are the raw-frame predictor
    passes, unused with a given ``predictor``; the last pass runs at the images of the regular
    object grid of ``settings.passes[-1]`` at ``settings.overlaps[-1]`` on ``object_shape``
    (default: the frames' shape), with ``settings.iteration_counts[-1]`` iterations. With
    ``settings.roi`` (object px) the object grid is cut to the region and only the raw frames
    around its images are read (:func:`final_grid`).
    """
    m = mapping_of(calibration)
    mode = parse_mapping_mode(mapping)
    native = native_mapping(m)
    if predictor is None and native is not None:
        # one native path (``correction_core::method_two``, as ``rspiv-engine piv --method II``)
        a, b = frames(frame_a, frame_b)
        d = _rspiv.method_two(
            a,
            b,
            native,
            settings.to_json(),
            mapping_mode=mode,
            object_shape=_shape(object_shape),
            mask=mask_array(mask, a.shape),
        )
        return PivField._from_native(d, settings.final_window)
    a = np.asarray(frame_a)
    shape = tuple(object_shape) if object_shape is not None else a.shape
    window = settings.final_window
    # in a region of interest the final pass runs on two more rings of points (the median test's
    # neighbours and the pooled uncertainty of the region's outer vectors), cut off at the end
    (gx, gy), cut = _object_grid(shape, settings)
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    img = m.forward(obj)
    points = img.reshape(gx.shape + (2,))
    # a region of interest: the raw frames around the points only (the points, the mask and
    # a predictor field moved into the crop)
    fa, fb, fmask, at, pred = frame_a, frame_b, mask, points, predictor
    if settings.roi is not None:
        (rows, cols), (cx, cy) = _region_around(points, settings, a.shape)
        fa, fb = a[rows, cols], np.asarray(frame_b)[rows, cols]
        raw_mask = mask_array(mask, a.shape)
        fmask = None if raw_mask is None else raw_mask[rows, cols]
        at = points - np.array([cx, cy], dtype=np.float64)
        if isinstance(predictor, PivField) and predictor.grid is not None:
            x0, y0, dx, dy = predictor.grid
            pred = dataclasses.replace(predictor, grid=(x0 - cx, y0 - cy, dx, dy))
        settings = settings.replace(roi=None)
    if predictor is None:  # a duck-typed mapping: the same steps composed in Python
        f = run_final_points(fa, fb, at, settings, fmask)
    else:
        if settings.deformation == "offset":
            pred = _sample_field(predictor, img).reshape(gx.shape + (2,))
        # deformation "symmetric": the windows are deformed by the predictor field
        f = run_points(
            fa,
            fb,
            at,
            [window],
            settings,
            predictor=pred,
            iterations=settings.iteration_counts[-1],
            validate=settings.validate,
            mask=fmask,
        )
    d = np.column_stack([f.u.ravel(), f.v.ravel()])
    dob = map_displacements(m, img, d, mode).reshape(gx.shape + (2,))
    sig = np.column_stack([f.sigma_u.ravel(), f.sigma_v.ravel()])
    sob = map_sigmas(m, obj, sig, mode).reshape(gx.shape + (2,))
    lost = ~np.all(np.isfinite(dob), axis=-1) & ~f.masked
    masked = (f.masked | lost)[cut]
    valid = f.valid[cut] & ~masked
    gx, gy, dob, sob = gx[cut], gy[cut], dob[cut], sob[cut]
    grid = (
        float(gx[0, 0]),
        float(gy[0, 0]),
        float(gx[0, 1] - gx[0, 0]) if gx.shape[1] > 1 else 1.0,
        float(gy[1, 0] - gy[0, 0]) if gy.shape[0] > 1 else 1.0,
    )
    return PivField(
        x=gx,
        y=gy,
        u=np.where(masked, np.nan, dob[..., 0]),
        v=np.where(masked, np.nan, dob[..., 1]),
        valid=valid,
        replaced=f.replaced[cut] & ~masked,
        peak_choice=np.where(masked, 0, f.peak_choice[cut]).astype(np.uint8),
        masked=masked,
        peak_ratio=f.peak_ratio[cut],
        coef=f.coef[cut],
        sigma_u=np.where(masked, np.nan, sob[..., 0]),
        sigma_v=np.where(masked, np.nan, sob[..., 1]),
        window=tuple(window),
        grid=grid,
    )


def piv_vectors(
    frame_a: Any,
    frame_b: Any,
    calibration: Any,
    passes: Sequence[tuple[int, int]] = ((64, 64), (32, 32), (32, 8)),
    overlap: float = 0.5,
    *,
    mapping: str = "full",
    object_shape: tuple[int, int] | None = None,
    predictor: PivField | None = None,
    deformation: str = "offset",
    iterations: int = 1,
    subpixel: str = "gauss3",
    interpolation: str = "bspline",
    weighting: str = "tophat",
    median_threshold: float = 2.0,
    median_eps: float = 0.1,
    mask: Any = None,
    predictor_overlap: float | Sequence[float] = 0.5,
    predictor_iterations: int | Sequence[int] = 1,
    validate: bool = True,
    min_peak_ratio: float = 0.0,
    peak_candidates: int = 3,
    uncertainty: bool = True,
) -> PivField:
    """Method II: PIV on the raw frames at ``F(object grid)``, vectors mapped to the object frame
    (keyword form of :func:`method_two`).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D
        The raw (distorted) exposures.
    calibration : Calibration or Mapping
        Object px -> image px (its rotation included).
    passes : sequence of (w, h)
        Window sizes, coarse to fine. All but the last run as a regular-grid :func:`rspiv.piv`
        on the raw frames (the predictor); the last one at the image positions of the object
        grid.
    overlap : float
        Overlap of the final object grid (the grid :func:`rspiv.piv` would give on the dewarped
        frames, so Methods I and II share their vector positions).
    mapping : {"full", "positions"}
        Displacement mapping (module docstring).
    object_shape : (h, w), optional
        Shape of the object frame (default: the frames' shape).
    predictor : PivField, optional
        A grid field on the raw frames to deform the final windows by (e.g. an uncorrected
        :func:`rspiv.piv` of the same pair); default: computed from ``passes[:-1]``.
    deformation : {"offset", "symmetric"}
        How the final windows follow the predictor: offset by it (interpolated bilinearly at
        each point) or deformed by it (:func:`rspiv.piv_at` with a grid field).
    iterations : int
        Correlation iterations of the final pass (1, as each pass of :func:`rspiv.piv`: a
        second iteration doubles the final pass's cost for an RMS gain of ~2 %).
    subpixel, interpolation, weighting, median_threshold, median_eps, mask, validate,
    min_peak_ratio, peak_candidates, uncertainty
        As for :func:`rspiv.piv` / :func:`rspiv.piv_at` (both the predictor and the final
        pass).
    predictor_overlap, predictor_iterations : float or sequence, int or sequence
        Overlap and iterations of the predictor passes (one value or one per pass of
        ``passes[:-1]``); unused with a given ``predictor``.

    Without a given ``predictor`` the predictor passes and the final pass run in one native
    call on one prepared frame pair (the frames' interpolation coefficients are built once);
    with one, the final pass is :func:`rspiv.piv_at`. Both give the same vectors.

    Returns
    -------
    PivField
        On the regular object grid (``grid`` set, ``x``, ``y`` in object px); ``u``, ``v`` in
        object px; ``valid``, ``replaced``, ``masked``, ``peak_ratio``, ``coef`` from the
        final raw-frame correlation (a vector whose displacement cannot be mapped is masked).
    """
    options = {k: v for k, v in locals().items() if k in OPTION_KEYS}
    mapping_of(calibration)
    mode = parse_mapping_mode(mapping)
    passes = [tuple(int(t) for t in p) for p in passes]
    if not passes:
        raise InvalidInputError("passes is empty")
    n = len(passes) - 1
    settings = PivSettings(
        passes=tuple(passes),
        overlap=(*per_pass(predictor_overlap, n, "predictor_overlap", float), float(overlap)),
        iterations=(*per_pass(predictor_iterations, n, "predictor_iterations", int), iterations),
        **options,
    )
    return method_two(
        frame_a,
        frame_b,
        calibration,
        settings,
        mapping=mode,
        object_shape=object_shape,
        predictor=predictor,
        mask=mask,
    )


# -- the one entry point ---------------------------------------------------------------------------
def correct(
    frame_a: Any,
    frame_b: Any,
    calibration: Any,
    method: str,
    settings: PivSettings,
    *,
    mapping: str = "full",
    mask: Any = None,
    object_shape: tuple[int, int] | None = None,
    predictor: PivField | None = None,
    zero_fill: str = "mask",
) -> PivField:
    """Distortion-corrected PIV of a raw frame pair: Method I or Method II.

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D
        The raw exposures (same shape; a :class:`rspiv.Calibration` checks it is its sensor's).
    calibration : Calibration or Mapping
        Object px -> image px.
    method : {"I", "II"} (aliases "images", "vectors"; any case)
        Dewarp the images, then PIV; or PIV on the raw frames, then map the vectors.
    settings : PivSettings
        The PIV job (for Method II, its last pass runs at the images of the object grid).
    mapping : {"full", "positions"}
        Method II's displacement mapping; ignored by Method I.
    mask : ndarray of bool, optional
        Raw-frame mask (True = excluded).
    object_shape : (h, w), optional
        Shape of the object frame (default: the frames' shape).
    predictor : PivField, optional
        Method II: a grid field on the raw frames to follow (e.g. the uncorrected field of the
        same pair); ignored by Method I.
    zero_fill : {"mask", "keep"}
        Method I: whether the dewarped frames' zero fill is masked (see :func:`dewarp_pair`).

    Returns
    -------
    PivField
        On the regular object grid of the last pass; ``x``, ``y``, ``u``, ``v`` in object px.
    """
    which = parse_method(method)
    if which == "none":
        raise InvalidInputError('correct: method "none" is no correction; call rspiv.piv')
    parse_mapping_mode(mapping)
    check_calibration_shape(calibration, np.shape(frame_a), "frame_a")
    check_calibration_shape(calibration, np.shape(frame_b), "frame_b")
    if which == "I":
        return method_one(
            frame_a,
            frame_b,
            calibration,
            settings,
            object_shape=object_shape,
            mask=mask,
            zero_fill=zero_fill,
        )
    return method_two(
        frame_a,
        frame_b,
        calibration,
        settings,
        mapping=mapping,
        object_shape=object_shape,
        predictor=predictor,
        mask=mask,
    )


# -- another tool's vectors ----------------------------------------------------------------------
def correct_vectors(vectors: Any, calibration: Any, *, mapping: str = "full") -> VectorFile:
    """Method II for a vector field measured on the raw frames by any tool (a DaVis, OpenPIV or
    PIVlab result read by :func:`rspiv.vector_files.read_vectors`, or an uncorrected rspiv run).

    At every point ``X`` of the field's own grid, now read as object px, the field is taken at
    the image point ``x = F(X)`` (:func:`rspiv.vector_sampling.sample_at`: Keys' cubic from the
    4 x 4 valid nodes about it, else bilinear from four: the vectors are not correlated again,
    so this adds the interpolation's smoothing between the field's nodes, which rspiv's own
    Method II, placing windows at ``F(X)``, does not; on the tests' lens series 0.040 px rms,
    0.097 px bilinear) and its displacement is
    mapped as :func:`map_displacements` does (``mapping="full"``: through the inverse,
    ``F^-1(x + d/2) - F^-1(x - d/2)``; ``"positions"``: kept). The tool's uncertainties are
    carried by :func:`map_sigmas`.

    Parameters
    ----------
    vectors : VectorFile or PivField
        The field on the raw frames (image px).
    calibration : Calibration or Mapping
        Object px -> image px, of the camera that recorded the frames.
    mapping : {"full", "positions"}

    Returns
    -------
    VectorFile
        On the input's grid in object px (``frame="object"``); valid where the image point has
        (at least) four valid neighbours and the inverse map converges, NaN elsewhere.

    Raises
    ------
    InvalidInputError
        A field already corrected, not a field, a calibration that is not one, or vectors
        outside the sensor a :class:`rspiv.Calibration` was made for (a bare Mapping does not
        know it: its polynomial would extrapolate without a word).
    """
    vf = as_vectors(vectors, "vectors")
    if vf.frame == "object":
        raise InvalidInputError(f"{vf.path}: already corrected for the distortion (object px)")
    mode = parse_mapping_mode(mapping)
    m = mapping_of(calibration)
    shape = getattr(calibration, "image_shape", None)
    if shape is not None:  # a Calibration knows its sensor; a bare Mapping does not
        h, w = (int(v) for v in shape)
        ok = np.isfinite(vf.u)
        if ok.any() and (
            vf.x[ok].min() < -0.5 or vf.x[ok].max() > w - 0.5
            or vf.y[ok].min() < -0.5 or vf.y[ok].max() > h - 0.5
        ):  # fmt: skip
            raise InvalidInputError(
                f"{vf.path}: vectors from ({vf.x[ok].min():.1f}, {vf.y[ok].min():.1f}) to "
                f"({vf.x[ok].max():.1f}, {vf.y[ok].max():.1f}) px reach past the calibration's "
                f"{w} x {h} px sensor: a calibration of another camera or binning?"
            )
    obj = np.column_stack([vf.x.ravel(), vf.y.ravel()])
    img = m.forward(obj)
    u, v, su, sv = sample_at(vf, img[:, 0], img[:, 1], [vf.u, vf.v, vf.sigma_u, vf.sigma_v])
    d_obj = map_displacements(m, img, np.column_stack([u, v]), mode)
    shape = vf.u.shape
    sig = None
    if vf.sigma_u is not None and vf.sigma_v is not None:
        sig = map_sigmas(m, obj, np.column_stack([su, sv]), mode)
    ok = np.all(np.isfinite(d_obj), axis=1).reshape(shape)
    return dataclasses.replace(
        vf,
        u=d_obj[:, 0].reshape(shape),
        v=d_obj[:, 1].reshape(shape),
        valid=ok,
        postprocessed=np.zeros(shape, dtype=bool),
        peak_ratio=None,
        sigma_u=None if sig is None else sig[:, 0].reshape(shape),
        sigma_v=None if sig is None else sig[:, 1].reshape(shape),
        frame="object",
        notes=vf.notes + (f"corrected by rspiv's Method II ({mode}): the field interpolated at "
                          "the image points of its grid read as object px",),
    )  # fmt: skip
