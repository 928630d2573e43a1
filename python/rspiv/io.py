"""Reading PIV images.

TIFF (single or multi-frame, via tifffile), PNG and BMP (via matplotlib's Pillow reader) are
read as 2D arrays ``image[y, x]`` of their native dtype (uint8/uint16 kept, not rescaled).
Errors raise :class:`rspiv.InvalidInputError` naming the file.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["read_image", "read_pair"]

_TIFF = {".tif", ".tiff"}
_PIL = {".png", ".bmp"}


def _grey(arr: np.ndarray, name: str) -> np.ndarray:
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        rgb = arr[..., :3].astype(np.float32)
        arr = rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    if arr.ndim != 2:
        raise InvalidInputError(f"{name}: expected a grey 2D image, got shape {arr.shape}")
    return arr


def read_image(path: str | os.PathLike, frame: int = 0) -> np.ndarray:
    """Read one grey image.

    Parameters
    ----------
    path : str or path-like
        A ``.tif``/``.tiff``, ``.png`` or ``.bmp`` file.
    frame : int
        Page of a multi-frame TIFF (0-based); must be 0 for other formats.

    Returns
    -------
    ndarray, 2D, ``image[y, x]``
    """
    p = pathlib.Path(path)
    name = str(p)
    if not p.is_file():
        raise InvalidInputError(f"{name}: no such file")
    ext = p.suffix.lower()
    try:
        if ext in _TIFF:
            import tifffile

            with tifffile.TiffFile(p) as tf:
                n = len(tf.pages)
                if not 0 <= frame < n:
                    raise InvalidInputError(f"{name}: frame {frame} out of range ({n} frames)")
                arr = tf.pages[frame].asarray()
        elif ext in _PIL:
            if frame != 0:
                raise InvalidInputError(f"{name}: {ext} files hold a single frame")
            from PIL import Image

            with Image.open(p) as im:
                arr = np.asarray(im)
        else:
            raise InvalidInputError(f"{name}: unsupported image type {ext!r} (TIFF, PNG, BMP)")
    except InvalidInputError:
        raise
    except Exception as exc:  # corrupt or foreign file
        raise InvalidInputError(f"{name}: cannot read image: {exc}") from exc
    return _grey(np.asarray(arr), name)


def read_pair(path_a, path_b=None) -> tuple[np.ndarray, np.ndarray]:
    """Read a PIV image pair: two files, or one two-frame TIFF (``path_b`` None)."""
    if path_b is None:
        return read_image(path_a, 0), read_image(path_a, 1)
    return read_image(path_a), read_image(path_b)
