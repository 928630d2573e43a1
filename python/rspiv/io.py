"""Reading images: the one reader of rspiv (PIV frames, calibration targets, masks).

TIFF (single or multi-frame, via tifffile), PNG, BMP and JPEG (via Pillow) and LaVision DaVis
buffers (``.im7``, ``.imx``, ``.ims``, through LaVision's ``lvpyio``, the optional extra
``pip install 'rspiv[davis]'``; never bundled) and high-speed recordings (Photron ``.cihx`` or
``.cih`` with their ``.mraw``, :mod:`rspiv.photron`; Phantom ``.cine``, :mod:`rspiv.phantom`;
one frame read at a time) are read as C-contiguous 2D arrays ``image[y, x]``. A DaVis
buffer's images are numbered in file order over its frames and their planes: a double-frame
PIV recording holds frame A at 0 and frame B at 1 (the raw counts, bit depth as stored: the
buffer's intensity scale is reported by :func:`davis_info`, not applied).
uint8, uint16, float32 and float64 keep their dtype (not rescaled); other dtypes become float64;
colour images become grey (0.299 R + 0.587 G + 0.114 B, float32); palette (indexed-colour)
images are read through their palette (a grey one gives its levels), grey with alpha as its grey
channel. Arrays pass through the same
rules, so every entry point accepts a file or an array alike. Errors raise
:class:`rspiv.InvalidInputError` naming the file: missing, unreadable or truncated files, a frame
out of range, images that are not 2D, float images with NaN or inf. JPEG is read with a
:class:`UserWarning` (:data:`JPEG_LOSSY` with the file's estimated quality,
:func:`jpeg_quality`; once per calling line and quality): its compression adds error.
"""

from __future__ import annotations

import json
import os
import pathlib
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import tifffile
from PIL import Image

from rspiv.errors import InvalidInputError
from rspiv.phantom import PHANTOM_SUFFIXES, PhantomRecording, phantom_recording
from rspiv.photron import PHOTRON_SUFFIXES, PhotronRecording, photron_recording

__all__ = [
    "DAVIS_SUFFIXES",
    "JPEG_LOSSY",
    "RECORDING_SUFFIXES",
    "camera_recording",
    "recording_rate",
    "davis_info",
    "frame_count",
    "jpeg_quality",
    "read_image",
    "read_mask",
    "read_pair",
    "turn_frame",
]

_TIFF = {".tif", ".tiff"}
_JPEG = {".jpg", ".jpeg"}
_PIL = {".png", ".bmp"} | _JPEG
#: The warning for JPEG frames (also the Rust engine's): lossy compression on 8 x 8 px blocks.
JPEG_LOSSY = (
    "JPEG is lossy: its 8 x 8 px block artefacts add error to sub-pixel displacements and "
    "marker centres; record TIFF or PNG where you can"
)
#: DaVis buffer files (read through lvpyio).
DAVIS_SUFFIXES = (".im7", ".imx", ".ims")
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
                page = tf.pages[frame]
                img = page.asarray()
                if page.photometric == tifffile.PHOTOMETRIC.PALETTE and page.colormap is not None:
                    return _palette(img, page.colormap, name)
                return img
        if ext in DAVIS_SUFFIXES:
            images = _davis_images(p)
            if not 0 <= frame < len(images):
                raise InvalidInputError(
                    f"{name}: frame {frame} out of range ({len(images)} frames)"
                )
            return images[frame]
        if ext in RECORDING_SUFFIXES:
            return camera_recording(p).read(frame)
        if ext in _PIL:
            if frame != 0:
                raise InvalidInputError(f"{name}: {ext} files hold a single frame")
            with Image.open(p) as im:
                im.load()
                img = _pil_array(im, name)
                quality = jpeg_quality(im) if ext in _JPEG else None
            if ext in _JPEG:
                # one message per quality: shown once per calling line, not once per pair
                warnings.warn(_jpeg_warning(quality), UserWarning, stacklevel=3)
            return img
    except InvalidInputError:
        raise
    except Exception as exc:  # corrupt, truncated or foreign file
        raise InvalidInputError(f"{name}: cannot read image: {exc}") from exc
    raise InvalidInputError(
        f"{name}: unsupported image type {ext!r} (TIFF, PNG, BMP, JPEG, DaVis .im7/.imx/.ims, "
        "Photron .cihx/.cih/.mraw, Phantom .cine)"
    )


def _lvpyio(name: str) -> Any:
    try:
        import lvpyio  # deferred: optional extra (LaVision's licence: not bundled)
    except ImportError:
        raise InvalidInputError(
            f"{name}: reading DaVis files needs LaVision's lvpyio: pip install 'rspiv[davis]'"
        ) from None
    return lvpyio


#: The most values a DaVis buffer's header may announce: 2**28 (a 47 MP double frame is 2**26.5),
#: and at most 1024 per byte of the file (DaVis' compression of images and vector fields stays
#: far below that). A damaged header announcing more is refused before lvpyio allocates it.
_DAVIS_MAX_VALUES = 1 << 28


def _davis_header_check(p: pathlib.Path) -> None:
    """Refuse a DaVis buffer whose header announces absurd sizes (little-endian int32 sizeX,
    sizeY, sizeZ, sizeF at bytes 8-23 of the IM7/VC7 header), which lvpyio would allocate."""
    try:
        with p.open("rb") as fh:
            head = fh.read(24)
        size = p.stat().st_size
    except OSError as exc:
        raise InvalidInputError(f"{p}: cannot read: {exc}") from None
    if len(head) < 24:
        raise InvalidInputError(f"{p}: cannot read the DaVis buffer: {len(head)} bytes only")
    dims = [int.from_bytes(head[k : k + 4], "little", signed=True) for k in (8, 12, 16, 20)]
    count = dims[0] * dims[1] * dims[2] * dims[3]
    if min(dims) < 1 or count > min(_DAVIS_MAX_VALUES, 1024 * max(size, 1)):
        raise InvalidInputError(
            f"{p}: cannot read the DaVis buffer: its header announces "
            f"{' x '.join(map(str, dims))} values in a file of {size} bytes (damaged or cut)"
        )


def davis_frames(p: pathlib.Path) -> int:
    """The frames of a DaVis 7+ buffer (``.im7``/``.vc7``) from its header alone (sizeF, bytes
    20-23), the header checked as before lvpyio reads it; InvalidInputError in one line."""
    _davis_header_check(p)
    with p.open("rb") as fh:
        head = fh.read(24)
    return int.from_bytes(head[20:24], "little", signed=True)


def _davis_buffer(p: pathlib.Path) -> Any:
    lv = _lvpyio(str(p))
    if p.suffix.lower() in (".im7", ".vc7"):  # DaVis 7+ headers; the older .imx has another
        _davis_header_check(p)
    try:
        return lv.read_buffer(str(p))
    except Exception as exc:  # truncated or foreign file: lvpyio raises various types
        raise InvalidInputError(f"{p}: cannot read the DaVis buffer: {exc}") from exc


#: The last DaVis buffer read, ``(path, mtime_ns, size), images``: frames A and B of a pair are
#: read from one file one after the other; decoding it once is enough (one buffer in memory).
_LAST_DAVIS: list[Any] = [None]


def last_file(slot: list[Any], p: pathlib.Path, load: Callable[[pathlib.Path], Any]) -> Any:
    """``load(p)``, kept in the one-entry cache ``slot`` (a list of one ``(key, value)`` or
    None) under the file's path, modification time and size: a file read again at once (a
    pair's two frames, a session's pairs) is loaded once, one file held. What ``load`` raises
    is not kept."""
    st = p.stat()
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    last = slot[0]  # one (key, value) tuple, replaced atomically
    if last is not None and last[0] == key:
        return last[1]
    value = load(p)
    slot[0] = (key, value)
    return value


def _davis_images(p: pathlib.Path) -> list[np.ndarray]:
    """The images of a DaVis buffer in file order (frames, then their planes)."""

    def load(path: pathlib.Path) -> list[np.ndarray]:
        out = [np.asarray(img) for frame in _davis_buffer(path) for img in frame.images]
        if not out:
            raise InvalidInputError(f"{path}: the DaVis buffer holds no image")
        return out

    return last_file(_LAST_DAVIS, p, load)


def davis_info(path: str | os.PathLike) -> dict[str, Any]:
    """What a DaVis buffer says about itself: the number of images, the camera/frame label of
    each (``"1A"``, ``"1B"``, ... from its CameraName; "" when absent), their shape and dtype, the
    x/y/intensity scales of its first frame (``(slope, offset, unit)``: e.g. mm per px) and its
    attributes (acquisition time series, camera, ...), as plain Python values."""
    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    buf = _davis_buffer(p)
    frames = list(buf)
    if not frames or not frames[0].images:
        raise InvalidInputError(f"{p}: the DaVis buffer holds no image")
    first = frames[0]
    img = np.asarray(first.images[0])

    def scale(s: Any) -> tuple[float, float, str]:
        return float(s.slope), float(s.offset), str(s.unit)

    attrs = {}
    for k, v in dict(first.attributes).items():
        attrs[str(k)] = v.tolist() if isinstance(v, np.ndarray) else v
    cameras = [
        str(dict(f.attributes).get("CameraName", "")).split(":")[0]
        for f in frames
        for _ in f.images
    ]
    return {
        "images": sum(len(f.images) for f in frames),
        "cameras": cameras,
        "shape": tuple(int(n) for n in img.shape),
        "dtype": str(img.dtype),
        "x_scale": scale(first.scales.x),
        "y_scale": scale(first.scales.y),
        "intensity_scale": scale(first.scales.i),
        "attributes": attrs,
    }


#: The time units of a DaVis frame's acquisition time (``AcqTimeSeries``, e.g. ``"1050 µs"``).
_DAVIS_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "\u00b5s": 1e-6, "\u03bcs": 1e-6, "ns": 1e-9}


def davis_frame_dt(path: str | os.PathLike) -> float | None:
    """The time (s) from frame 0 to frame 1 of a DaVis buffer, from its frames' acquisition
    times (the ``AcqTimeSeries`` attribute of each frame, a number and a unit: ``"1050 µs"``;
    PIVMat's ``getframedt`` reads the same attribute): the pulse separation of a double-frame
    recording. None when the buffer has one frame or a time is absent, unreadable or not
    later in frame 1. InvalidInputError in one line for a file lvpyio cannot read."""
    p = pathlib.Path(path)
    frames = list(_davis_buffer(p))
    times = []
    for f in frames[:2]:
        text = str(dict(f.attributes).get("AcqTimeSeries", "")).strip().split()
        if len(text) != 2 or text[1] not in _DAVIS_TIME_UNITS:
            return None
        try:
            times.append(float(text[0]) * _DAVIS_TIME_UNITS[text[1]])
        except ValueError:
            return None
    if len(times) < 2 or not times[1] > times[0]:
        return None
    return times[1] - times[0]


def frame_count(path: str | os.PathLike) -> int:
    """Number of frames (images) a file holds: TIFF pages, DaVis images, a Photron or Phantom
    recording's frames, 1 for PNG/BMP/JPEG."""
    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    ext = p.suffix.lower()
    if ext in DAVIS_SUFFIXES:
        return len(_davis_images(p))
    if ext in _TIFF:
        try:
            with tifffile.TiffFile(p) as tf:
                return len(tf.pages)
        except Exception as exc:  # noqa: BLE001 - corrupt or foreign file
            raise InvalidInputError(f"{p}: cannot read image: {exc}") from exc
    rec = camera_recording(p)
    if rec is not None:
        return rec.frames
    if ext in _PIL:
        return 1
    raise InvalidInputError(f"{p}: unsupported image type {ext!r}")


#: High-speed camera recordings: many frames in the camera's own file(s).
RECORDING_SUFFIXES = PHOTRON_SUFFIXES + PHANTOM_SUFFIXES


def camera_recording(path: str | os.PathLike) -> PhotronRecording | PhantomRecording | None:
    """The high-speed recording a file names (Photron ``.cihx``/``.cih``/``.mraw``, Phantom
    ``.cine``; checked, see :mod:`rspiv.photron` and :mod:`rspiv.phantom`), or None for any
    other file. Both kinds give ``KIND``, ``source``, ``camera``, ``width``, ``height``,
    ``frames``, ``bits``, ``depth``, ``fps``, ``shutter_s``, ``dt`` and ``read(index)``."""
    ext = pathlib.Path(path).suffix.lower()
    if ext in PHOTRON_SUFFIXES:
        return photron_recording(path)
    if ext in PHANTOM_SUFFIXES:
        return phantom_recording(path)
    return None


def recording_rate(rec: PhotronRecording | PhantomRecording) -> str:
    """The frame rate of a recording's frames in words: ``"10000 fps"``, with the camera's
    own rate when only every ``step``-th frame was saved, or why it is not known."""
    step = getattr(rec, "step", 1)
    note = getattr(rec, "rate_note", "")
    if rec.fps > 0:
        if step > 1:
            return f"{rec.fps:g} fps ({rec.record_fps:g} fps recorded, every {step}th frame saved)"
        return f"{rec.fps:g} fps"
    return note or "no frame rate in the file"


#: The IJG (libjpeg) luminance quantisation table at quality 50, natural order.
_IJG_LUMA = np.array(
    [16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57,
     69, 56, 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64,
     81, 104, 113, 92, 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99]
)  # fmt: skip


def jpeg_quality(im: Any) -> int | None:
    """The IJG quality (1-100) whose luminance quantisation table is closest to that of the
    JPEG image ``im`` (a Pillow image; least squares over the 64 entries: exact for files
    written by libjpeg, Pillow or OpenCV, which scale the IJG table; for a camera's own tables
    the nearest IJG quality), or None when the file carries no 8 x 8 luminance table."""
    tables = getattr(im, "quantization", None) or {}
    t = np.asarray(tables.get(0, ()), dtype=np.float64)
    if t.size != 64:
        return None
    q = np.arange(1, 101)
    scale = np.where(q < 50, 5000 // q, 200 - 2 * q)
    ref = np.clip((_IJG_LUMA[None, :] * scale[:, None] + 50) // 100, 1, 255)
    return int(q[np.argmin(((ref - t) ** 2).sum(axis=1))])


def _jpeg_warning(quality: int | None) -> str:
    """:data:`JPEG_LOSSY` with the file's estimated quality and, under 90, what that costs
    (benches/RESULTS.md: a target saved at 95 / 85 / 75 moved its marker centres by 0.02 /
    0.09 / 0.27 px)."""
    if quality is None:
        return JPEG_LOSSY
    cost = (
        "; the artefacts moved a calibration target's marker centres by 0.09 px at quality 85 "
        "and 0.27 px at 75"
        if quality < 90
        else ""
    )
    return f"{JPEG_LOSSY} (this file: quality about {quality}{cost})"


def _palette(idx: np.ndarray, cmap: Any, name: str) -> np.ndarray:
    """The intensities of an indexed-colour image: each index through its colour map
    (``cmap``: rows R, G, B). A grey map gives its levels (uint8, or uint16 beyond 255; a TIFF
    colour map's 16-bit levels k * 257 are the 8-bit levels k), so a map that is not the
    identity ramp (reversed, shuffled, a few levels) reads as the intensities, not the indices;
    a colour map gives R, G, B for :func:`_grey`'s luma."""
    cmap = np.asarray(cmap, dtype=np.int64)
    if cmap.ndim != 2 or cmap.shape[0] != 3:
        raise InvalidInputError(f"{name}: a colour map of shape {cmap.shape}, not (3, n)")
    n = cmap.shape[1]
    top = int(idx.max()) if idx.size else 0
    if top >= n:
        raise InvalidInputError(f"{name}: palette index {top} beyond its {n} colours")
    if cmap.max() > 255 and np.all(cmap % 257 == 0):
        cmap = cmap // 257
    r, g, b = cmap
    if np.array_equal(r, g) and np.array_equal(r, b):
        return r.astype(np.uint8 if r.max() <= 255 else np.uint16)[idx]
    return np.stack([r[idx], g[idx], b[idx]], axis=-1)


def _pil_array(im: Any, name: str) -> np.ndarray:
    """A Pillow image as an array: a palette image through its palette (:func:`_palette`:
    indices are no intensities), grey with alpha as its grey channel, others as they are."""
    if im.mode == "P":
        pal = np.asarray(im.getpalette() or [0, 0, 0], dtype=np.int64).reshape(-1, 3)
        return _palette(np.asarray(im), pal.T, name)
    if im.mode in ("LA", "La", "PA"):
        if im.mode == "PA":
            return _pil_array(im.convert("RGBA"), name)
        return np.asarray(im.getchannel(0))
    return np.asarray(im)


def read_image(source: str | os.PathLike | Any, frame: int = 0) -> np.ndarray:
    """Read one grey image from a file, or check an array by the same rules.

    Parameters
    ----------
    source : str, path-like or array_like
        A ``.tif``/``.tiff``, ``.png``, ``.bmp``, ``.jpg``/``.jpeg``, DaVis, Photron
        (``.cihx``, ``.cih``, ``.mraw``) or Phantom (``.cine``) file, or an image array.
    frame : int
        Page of a multi-frame TIFF, image of a DaVis buffer or frame of a high-speed
        recording (0-based); must be 0 for other formats and arrays.

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


def read_pair(path_a, path_b=None, frames: tuple[int, int] | None = None):
    """Read a PIV image pair: two files, or two frames of one multi-frame file (``path_b``
    None: a TIFF stack, a double-frame DaVis buffer or a high-speed recording; ``frames``, 0 and
    1 by default). ``frames`` with two files is refused (InvalidInputError)."""
    if path_b is None:
        i, j = (0, 1) if frames is None else frames
        return read_image(path_a, i), read_image(path_a, j)
    if frames is not None:
        raise InvalidInputError(
            f"{path_a}, {path_b}: frames pick two frames of one multi-frame file, and two files "
            "were given"
        )
    return read_image(path_a), read_image(path_b)


def turn_frame(a: np.ndarray, turn: int) -> np.ndarray:
    """``a`` in the orientation ``turn`` (0-7): mirrored left-right first when ``turn >= 4``,
    then turned by ``turn % 4`` quarter turns counter-clockwise as seen on screen (rows down,
    ``np.rot90``); C-contiguous (a copy unless ``turn`` is 0). A campaign's ``[images] rotate``
    (degrees) and ``mirror`` orient every frame, the target and the mask image so as they are
    read (:meth:`rspiv.campaign_config.ImagesConfig.orientation`), so that the flow runs along +x
    and the wall lies along a row. For one turn, pixel ``(x, y)`` of a frame ``w`` px wide lands
    at ``(y, w - 1 - x)``; mirrored, ``(x, y)`` lands at ``(w - 1 - x, y)``."""
    if not 0 <= turn <= 7:
        raise InvalidInputError(f"turn_frame: the orientation must be 0-7, got {turn}")
    if turn == 0:
        return a
    if turn >= 4:
        a = a[:, ::-1]
    return np.ascontiguousarray(np.rot90(a, turn % 4))


def read_mask(source: str | os.PathLike | Any, shape: tuple[int, int], turn: int = 0) -> np.ndarray:
    """A PIV mask (bool, True = excluded) of the frames' ``shape = (h, w)``.

    ``source`` is an image (non-zero = excluded; any format :func:`read_image` reads), a bool
    array, or a JSON file of polygons in px (README pixel frame)::

        {"polygons": [[[x0, y0], [x1, y1], [x2, y2], ...], ...], "invert": false}

    A pixel is excluded when its centre lies inside a polygon (``invert = true``: outside every
    polygon, i.e. the polygons outline the region to keep). InvalidInputError naming the file for
    a wrong shape, malformed JSON or a polygon of fewer than 3 finite vertices.

    ``turn``: the mask is of the frames as recorded (an image of their size, polygons in their
    px) and is turned as they are (:func:`turn_frame`); ``shape`` is that of the turned frames.
    """
    if turn % 2:
        shape = (shape[1], shape[0])
    h, w = (int(shape[0]), int(shape[1]))
    if isinstance(source, (str, os.PathLike)) and pathlib.Path(source).suffix.lower() == ".json":
        return turn_frame(_polygon_mask(pathlib.Path(source), h, w), turn)
    name = str(source) if isinstance(source, (str, os.PathLike)) else "mask"
    img = read_image(source)
    if img.shape != (h, w):
        raise InvalidInputError(
            f"{name}: mask is {img.shape[1]} x {img.shape[0]} px, the images are {w} x {h} px"
            + (" as recorded" if turn else "")
        )
    return turn_frame(np.asarray(img) > 0, turn)


def _polygon_mask(p: pathlib.Path, h: int, w: int) -> np.ndarray:
    from matplotlib.path import Path  # deferred: matplotlib (imported only for polygon masks)

    try:
        d = json.loads(p.read_text())
    except OSError as exc:
        raise InvalidInputError(f"{p}: cannot read the mask: {exc}") from exc
    except ValueError as exc:
        raise InvalidInputError(f"{p}: not valid JSON: {exc}") from exc
    polys = d.get("polygons") if isinstance(d, dict) else None
    if not isinstance(polys, list) or not polys:
        raise InvalidInputError(f'{p}: expected {{"polygons": [[[x, y], ...], ...]}}')
    out = np.zeros((h, w), bool)
    for k, poly in enumerate(polys):
        v = np.asarray(poly, dtype=np.float64) if isinstance(poly, list) else np.empty(0)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3 or not np.all(np.isfinite(v)):
            raise InvalidInputError(f"{p}: polygon {k} needs >= 3 finite [x, y] vertices")
        x0, y0 = (max(int(np.floor(v[:, i].min())), 0) for i in (0, 1))
        x1, y1 = (int(np.ceil(v[:, 0].max())), int(np.ceil(v[:, 1].max())))
        x1, y1 = min(x1, w - 1), min(y1, h - 1)
        if x1 < x0 or y1 < y0:
            continue  # entirely outside the frame
        yy, xx = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
        pts = np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float64)
        inside = Path(v).contains_points(pts).reshape(yy.shape)
        out[y0 : y1 + 1, x0 : x1 + 1] |= inside
    return ~out if bool(d.get("invert", False)) else out
