"""Reading images: the one reader of rspiv (PIV frames, calibration targets, masks).

TIFF (single or multi-frame, via tifffile), PNG and BMP (via Pillow) are read as C-contiguous 2D
arrays ``image[y, x]``. uint8, uint16, float32 and float64 keep their dtype (not rescaled); other
dtypes become float64; colour images become grey (0.299 R + 0.587 G + 0.114 B, float32). Arrays
pass through the same rules, so every entry point accepts a file or an array alike. Errors raise
:class:`rspiv.InvalidInputError` naming the file: missing, unreadable or truncated files, a frame
out of range, images that are not 2D, float images with NaN or inf.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np
import tifffile
from PIL import Image

from rspiv.errors import InvalidInputError

__all__ = ["read_image", "read_pair"]

_TIFF = {".tif", ".tiff"}
_PIL = {".png", ".bmp"}
_NATIVE = (np.uint8, np.uint16, np.float32, np.float64)


def _grey(arr: np.ndarray, name: str) -> np.ndarray:
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        rgb = arr[..., :3].astype(np.float32)
        arr = rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    if arr.ndim != 2:
        raise InvalidInputError(f"{name}: expected a grey 2D image, got shape {arr.shape}")
    if arr.dtype.type not in _NATIVE:
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name}: contains NaN or inf")
    return arr


def _read_file(p: pathlib.Path, frame: int) -> np.ndarray:
    name = str(p)
    if not p.is_file():
        raise InvalidInputError(f"{name}: no such file")
    ext = p.suffix.lower()
    try:
        if ext in _TIFF:
            with tifffile.TiffFile(p) as tf:
                n = len(tf.pages)
                if not 0 <= frame < n:
                    raise InvalidInputError(f"{name}: frame {frame} out of range ({n} frames)")
                return tf.pages[frame].asarray()
        if ext in _PIL:
            if frame != 0:
                raise InvalidInputError(f"{name}: {ext} files hold a single frame")
            with Image.open(p) as im:
                im.load()
                return np.asarray(im)
    except InvalidInputError:
        raise
    except Exception as exc:  # corrupt, truncated or foreign file
        raise InvalidInputError(f"{name}: cannot read image: {exc}") from exc
    raise InvalidInputError(f"{name}: unsupported image type {ext!r} (TIFF, PNG, BMP)")


def read_image(source: str | os.PathLike | Any, frame: int = 0) -> np.ndarray:
    """Read one grey image from a file, or check an array by the same rules.

    Parameters
    ----------
    source : str, path-like or array_like
        A ``.tif``/``.tiff``, ``.png`` or ``.bmp`` file, or an image array.
    frame : int
        Page of a multi-frame TIFF (0-based); must be 0 for other formats and arrays.

    Returns
    -------
    ndarray, 2D, ``image[y, x]``, C-contiguous (module docstring for the dtypes)
    """
    if isinstance(source, (str, os.PathLike)):
        p = pathlib.Path(source)
        return _grey(np.asarray(_read_file(p, int(frame))), str(p))
    if frame != 0:
        raise InvalidInputError(f"image array: frame {frame} requested from a single image")
    return _grey(np.asarray(source), "image")


def read_pair(path_a, path_b=None) -> tuple[np.ndarray, np.ndarray]:
    """Read a PIV image pair: two files, or one two-frame TIFF (``path_b`` None)."""
    if path_b is None:
        return read_image(path_a, 0), read_image(path_a, 1)
    return read_image(path_a), read_image(path_b)
