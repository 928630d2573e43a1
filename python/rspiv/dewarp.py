"""Dewarp images through a mapping (paper section 3.3, Method I: dewarp, then PIV).

For every object pixel ``(x, y)`` of the output the mapping gives the image position
``F(x, y)`` (object px -> image px, the calibration's rotation included) and the output is the
input image interpolated there with the Keys cubic-convolution kernel (``a = -0.5``, 4 x 4
neighbours). The work runs in Rust (:func:`rspiv._rspiv.dewarp_image`), parallel over rows.

Conventions (see ``dewarp_core::remap``):

- Zero outside the image: a source position outside the sensor's footprint
  ``[-0.5, w - 0.5] x [-0.5, h - 0.5]`` gives ``fill`` (0); inside it the kernel's neighbours
  beyond the border replicate the edge pixel.
- Full precision: source coordinates are float64, the sub-pixel position is not quantised
  (OpenCV's ``remap`` quantises it to 1/32 px); weights and sums are float32.
- The identity map returns the image exactly.
- The mapping is evaluated on the coarsest grid (every 128, 64, ... px) whose bilinear
  interpolation error, checked against the exact map at every cell centre and edge midpoint, is
  at most ``tol`` (1e-3 px), or per pixel with ``sampling="exact"``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv.calibration import Calibration
from rspiv.errors import InvalidInputError

__all__ = ["check_calibration_shape", "dewarp", "remap"]


def _image(image: npt.ArrayLike) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 2:
        raise InvalidInputError(f"image must be 2-D, got shape {a.shape}")
    if a.dtype == np.uint16 or a.dtype == np.float32:
        return a
    if a.dtype in (np.uint8, np.int8, np.int16) or a.dtype == bool:
        return a.astype(np.float32) if a.dtype != np.uint8 else a.astype(np.uint16)
    if np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer):
        return a.astype(np.float32)
    raise InvalidInputError(f"image dtype {a.dtype} is not numeric")


def _out_dtype(out_dtype: Any) -> str:
    name = np.dtype(out_dtype).name
    if name not in ("float32", "uint16"):
        raise InvalidInputError(f"out_dtype must be float32 or uint16, got {out_dtype!r}")
    return name


def native_mapping(mapping: Any) -> Any:
    """The native mapping object (``_rspiv.NativeMapping``) of an rspiv Mapping, a Calibration
    or mapping JSON text (parsed once here); None for anything else (e.g. a callable)."""
    if isinstance(mapping, str):
        return _rspiv.NativeMapping.from_json(mapping)
    inner = getattr(mapping, "mapping", mapping)  # a Calibration holds its Mapping
    native = getattr(inner, "_native", None)
    return native if isinstance(native, _rspiv.NativeMapping) else None


def check_calibration_shape(calibration: Any, shape: tuple[int, ...], what: str = "image") -> None:
    """Raise if ``calibration`` is a :class:`rspiv.Calibration` made for another sensor size.

    A bare :class:`rspiv.Mapping` (or JSON text, callable) does not know its sensor: no check.
    """
    if not isinstance(calibration, Calibration):
        return
    want = tuple(int(v) for v in calibration.image_shape)
    got = tuple(int(v) for v in shape)
    if got != want:
        raise InvalidInputError(
            f"{what} shape (h, w) = {got} differs from the calibration's image_shape {want}: "
            "the calibration was made for another sensor size and does not cover this image"
        )


def _default_shape(mapping: Any, image: np.ndarray) -> tuple[int, int]:
    shape = getattr(mapping, "image_shape", None)
    if shape is not None:
        return int(shape[0]), int(shape[1])
    return int(image.shape[0]), int(image.shape[1])


def dewarp(
    image: npt.ArrayLike,
    mapping: Any,
    *,
    kernel: str = "keys",
    output_shape: tuple[int, int] | None = None,
    out_dtype: Any = "float32",
    sampling: str = "auto",
    tol: float = 1e-3,
    step: int = 16,
    fill: float = 0.0,
) -> np.ndarray:
    """Dewarp ``image`` into the object frame: ``out[y, x] = image(F(x, y))``.

    Parameters
    ----------
    image : ndarray, shape (h, w)
        The recorded (distorted) image. uint16 and float32 are used as they are; uint8 is
        widened to uint16, other numeric types are converted to float32.
    mapping : Mapping, Calibration, str or callable
        Object px -> image px: an :class:`rspiv.Mapping` (rotation included), an
        :class:`rspiv.Calibration` (its ``mapping``), a mapping's JSON text, or a vectorised
        callable ``f(points) -> points`` taking and returning ``(N, 2)`` arrays of (x, y) px
        (e.g. ``LensDistortion.distort``; evaluated per pixel in numpy, then remapped).
    kernel : {"keys"}
        Interpolation kernel: Keys cubic convolution, ``a = -0.5``.
    output_shape : (int, int), optional
        ``(height, width)`` of the output (object px); default the input's shape.
    out_dtype : {"float32", "uint16"}
        float32, or uint16 rounded half away from zero and clipped to ``[0, 65535]``.
    sampling : {"auto", "exact", "grid"}
        How the mapping is evaluated: ``"auto"`` the coarsest grid within ``tol`` px,
        ``"exact"`` per pixel, ``"grid"`` every ``step`` px with bilinear interpolation.
    tol : float
        Largest interpolation error of the mapping (px) for ``sampling="auto"``.
    step : int
        Grid step (px) for ``sampling="grid"``.
    fill : float
        Value of output pixels whose source lies outside the image.

    Returns
    -------
    ndarray, shape ``output_shape``, dtype ``out_dtype``

    Raises
    ------
    InvalidInputError
        Unknown kernel or dtype, bad shapes, an image whose shape differs from a Calibration's
        ``image_shape``, or a mapping that is none of the above.
    """
    if kernel != "keys":
        raise InvalidInputError(f"kernel must be 'keys', got {kernel!r}")
    img = _image(image)
    check_calibration_shape(mapping, img.shape)
    dt = _out_dtype(out_dtype)
    shape = tuple(output_shape) if output_shape is not None else _default_shape(mapping, img)
    if len(shape) != 2 or min(shape) < 1:
        raise InvalidInputError(f"output_shape must be (height, width) >= 1, got {shape}")
    shape = (int(shape[0]), int(shape[1]))
    native = native_mapping(mapping)
    if native is not None:
        return _rspiv.dewarp_image(
            img,
            native,
            out_shape=shape,
            sampling=sampling,
            tol=float(tol),
            step=int(step),
            fill=float(fill),
            out_dtype=dt,
        )
    fn: Callable[[np.ndarray], np.ndarray] | None = None
    if callable(mapping):
        fn = mapping
    elif hasattr(mapping, "distort"):
        fn = mapping.distort
    if fn is None:
        raise InvalidInputError(
            "mapping must be an rspiv Mapping, a Calibration, mapping JSON text or a callable "
            f"(N, 2) -> (N, 2); got {type(mapping).__name__}"
        )
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    pts = np.column_stack([xx.ravel().astype(np.float64), yy.ravel().astype(np.float64)])
    src = np.asarray(fn(pts), dtype=np.float64)
    if src.shape != pts.shape:
        raise InvalidInputError(f"mapping callable returned shape {src.shape}, not {pts.shape}")
    return remap(img, src[:, 0].reshape(shape), src[:, 1].reshape(shape), fill=fill,
                 out_dtype=dt)  # fmt: skip


def remap(
    image: npt.ArrayLike,
    map_x: npt.ArrayLike,
    map_y: npt.ArrayLike,
    *,
    fill: float = 0.0,
    out_dtype: Any = "float32",
) -> np.ndarray:
    """Keys-bicubic remap with precomputed source coordinates (like ``cv2.remap``).

    ``out[y, x] = image(map_x[y, x], map_y[y, x])``; the maps (image px, float32 or float64,
    same shape) give the output shape. Same conventions as :func:`dewarp`, without coordinate
    quantisation.
    """
    img = _image(image)
    mx = np.asarray(map_x)
    my = np.asarray(map_y)
    if mx.dtype != my.dtype or mx.dtype not in (np.float32, np.float64):
        mx = mx.astype(np.float64)
        my = my.astype(np.float64)
    if mx.ndim != 2 or mx.shape != my.shape:
        raise InvalidInputError(
            f"map_x and map_y must be 2-D of one shape, got {mx.shape} and {my.shape}"
        )
    return _rspiv.remap_coords(img, mx, my, fill=float(fill), out_dtype=_out_dtype(out_dtype))
