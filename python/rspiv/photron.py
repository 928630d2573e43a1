"""Photron high-speed recordings: a ``.cihx`` or ``.cih`` header and its ``.mraw`` frames.

A Photron FASTCAM saves a recording as one raw file of every frame (``name.mraw``, frames one
after another, rows top-down, no padding) and a header beside it: ``name.cihx`` (a binary
preamble, then XML) or, from older software, ``name.cih`` (text, ``Key : Value`` per line).
:func:`photron_recording` reads the header, given either file, and checks that the raw file
holds exactly the frames it describes; :func:`read_photron_frame` reads one frame, and only
its bytes (a recording of thousands of frames is never held in memory).

Pixels, as the camera stores them:

- 8 bit: one byte per pixel.
- 12 bit: two pixels in three bytes, most significant bits first (``p0 = b0 << 4 | b1 >> 4``,
  ``p1 = (b1 & 15) << 8 | b2``).
- 16 bit: little-endian. The header's effective bit depth says how many bits hold the signal
  and on which side; an upper-side signal is shifted down, so frames read as counts from 0 to
  ``2**depth - 1``.

Frames are returned as ``uint8`` (8 bit) or ``uint16``, ``image[y, x]``. Only monochrome
recordings are read: a colour camera's frames (``Color``, or ``Raw``: the Bayer mosaic before
demosaicing) are refused, since every particle image would carry the colour filter's 2 x 2
pattern into the correlation peak. The header's frame rate and save step (frames saved every
``step`` recorded ones) give the time between the file's frames (:attr:`PhotronRecording.dt`);
a campaign checks its ``[flow] dt`` against it.

Errors raise :class:`rspiv.InvalidInputError` in one line naming the file: a header without
its raw file (or the other way round), a field missing from the header, a raw file whose size
is not the header's frames, a colour recording, a frame out of range.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import pathlib
import typing
import xml.etree.ElementTree as ET

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "PHOTRON_SUFFIXES",
    "PhotronRecording",
    "photron_header",
    "photron_recording",
    "read_photron_frame",
]

#: A Photron recording is named by its header (``.cihx``, ``.cih``) or its frames (``.mraw``).
PHOTRON_SUFFIXES = (".cihx", ".cih", ".mraw")


@dataclasses.dataclass(frozen=True)
class PhotronRecording:
    """A Photron recording's header, checked against its raw file.

    Attributes
    ----------
    header, data : pathlib.Path
        The header (``.cihx`` / ``.cih``) and the raw frames (``.mraw``; None for a header whose
        frames were exported as image files, :func:`photron_header`).
    width, height, frames : int
        Frame size (px) and the number of frames in the raw file.
    bits : int
        Bits per pixel as stored: 8, 12 (packed) or 16.
    depth : int
        Effective bit depth (the signal's bits; at most ``bits``: a 12 bit sensor saved in
        8 bit pixels is 8).
    fps : float
        Frames per second of the frames in the file (NaN if the header does not say): the
        camera's ``record_fps`` over ``step``.
    record_fps : float
        The camera's frame rate (``Record Rate(fps)``, ``recordRate``).
    step : int
        Frames saved every ``step`` recorded ones (``Save Step`` of a ``.cih``; 1: every
        frame). A real ``.cih`` (pyMRAW's ``sample_60k_16bit.cih``) says 12 frames saved with a
        step of 36 of 677 recorded at 60,000 fps: 1,666.7 fps in the file.
    rate_note : str
        Why ``fps`` is NaN though the camera's rate is known, or "": a ``.cihx`` whose
        ``skipFrame`` is over 1 (pyMRAW's ``beam.cihx``: 2500, with 4 frames of 400 recorded,
        which no step of 2500 gives) leaves the time between the file's frames unknown.
    file_format : str
        How the frames were saved (``MRaw``, or an image format they were exported in).
    shutter_s : float
        Exposure time, s (NaN if the header does not say).
    camera : str
        The camera's model as the header names it.
    start_frame : int
        The first saved frame's number relative to the trigger.
    upper : bool
        The signal's bits are the upper ones of a 16 bit pixel (shifted down as read).
    """

    KIND: typing.ClassVar[str] = "Photron"
    header: pathlib.Path
    data: pathlib.Path | None
    width: int
    height: int
    frames: int
    bits: int
    depth: int
    fps: float
    shutter_s: float
    camera: str
    start_frame: int
    upper: bool = False
    record_fps: float = math.nan
    step: int = 1
    rate_note: str = ""
    file_format: str = "MRaw"

    @property
    def source(self) -> pathlib.Path:
        """The file the recording is named by (its header)."""
        return self.header

    @property
    def frame_bytes(self) -> int:
        """Bytes of one frame in the raw file."""
        return self.width * self.height * self.bits // 8

    @property
    def dt(self) -> float:
        """Time between consecutive frames, s (NaN without a frame rate)."""
        return 1.0 / self.fps if self.fps > 0 else math.nan

    def read(self, index: int) -> np.ndarray:
        """Frame ``index``: :func:`read_photron_frame`."""
        return read_photron_frame(self, index)


def _sibling(p: pathlib.Path, suffixes: tuple[str, ...]) -> pathlib.Path | None:
    for s in suffixes:
        for cand in (p.with_suffix(s), p.with_suffix(s.upper())):
            if cand.is_file():
                return cand
    return None


def _cih_fields(p: pathlib.Path) -> dict[str, str]:
    """The ``Key : Value`` lines of a text ``.cih`` header."""
    out = {}
    for line in p.read_bytes().decode("latin-1").splitlines():
        key, sep, value = line.partition(":")
        if sep and not line.startswith("#"):
            out[key.strip()] = value.strip()
    return out


def _cihx_fields(p: pathlib.Path) -> dict[str, str]:
    """The fields of a ``.cihx`` header's XML, under the ``.cih`` names used here."""
    raw = p.read_bytes()
    start, end = raw.find(b"<?xml"), raw.find(b"</cih>")
    if start < 0 or end < 0:
        raise InvalidInputError(f"{p}: not a Photron .cihx header (no <cih> XML in it)")
    try:
        root = ET.fromstring(raw[start : end + len(b"</cih>")])
    except ET.ParseError as exc:
        raise InvalidInputError(f"{p}: the header's XML cannot be read ({exc})") from None
    where = {
        "Image Width": "imageDataInfo/resolution/width",
        "Image Height": "imageDataInfo/resolution/height",
        "Color Type": "imageDataInfo/colorInfo/type",
        "Color Bit": "imageDataInfo/colorInfo/bit",
        "EffectiveBit Depth": "imageDataInfo/effectiveBit/depth",
        "EffectiveBit Side": "imageDataInfo/effectiveBit/side",
        "Total Frame": "frameInfo/totalFrame",
        "Start Frame": "frameInfo/startFrame",
        "Skip Frame": "frameInfo/skipFrame",
        "Record Rate(fps)": "recordInfo/recordRate",
        "Shutter Speed(ns)": "recordInfo/shutterSpeedNsec",
        "Camera Type": "deviceInfo/deviceName",
        "File Format": "imageFileInfo/fileFormat",
    }
    out = {}
    for key, path in where.items():
        node = root.find(path)
        if node is not None and node.text is not None:
            out[key] = node.text.strip()
    return out


def _shutter(fields: dict[str, str]) -> float:
    """The exposure, s: ``Shutter Speed(ns)`` (``.cihx``) or ``Shutter Speed(s)``, which a
    ``.cih`` writes as a fraction (``1/800000``)."""
    try:
        if "Shutter Speed(ns)" in fields:
            return float(fields["Shutter Speed(ns)"]) * 1e-9
        num, _, den = fields.get("Shutter Speed(s)", "").partition("/")
        return float(num) / float(den) if den else float(num)
    except (ValueError, ZeroDivisionError):
        return math.nan


def _integer(fields: dict[str, str], key: str, header: pathlib.Path, default=None) -> int:
    if key not in fields and default is not None:
        return default
    try:
        return int(fields[key])
    except KeyError:
        raise InvalidInputError(f"{header}: the header has no '{key}'") from None
    except ValueError:
        raise InvalidInputError(
            f"{header}: the header's '{key}' is not an integer ({fields[key]!r})"
        ) from None


@functools.lru_cache(maxsize=16)
def _parse(header: pathlib.Path, stamp: tuple) -> PhotronRecording:
    """The recording a header describes, its frames not looked at (``data`` None)."""
    fields = _cihx_fields(header) if header.suffix.lower() == ".cihx" else _cih_fields(header)
    colour = fields.get("Color Type", "Mono")
    if colour.lower() != "mono":
        raise InvalidInputError(
            f"{header}: a colour camera's frames (colour type {colour!r}): rspiv reads "
            "monochrome recordings; the colour filter's pattern would be in every particle image"
        )
    w, h = _integer(fields, "Image Width", header), _integer(fields, "Image Height", header)
    n, bits = _integer(fields, "Total Frame", header), _integer(fields, "Color Bit", header)
    # a sensor deeper than the pixels saved (a 12 bit camera's 8 bit file): every bit is signal
    depth = min(_integer(fields, "EffectiveBit Depth", header, bits), bits)
    if bits not in (8, 12, 16) or depth <= 0:
        raise InvalidInputError(
            f"{header}: {bits} bit pixels of effective depth {depth} (8, 12 or 16 bit are read)"
        )
    if w <= 0 or h <= 0 or n <= 0 or (w * h * bits) % 8:
        raise InvalidInputError(f"{header}: frames of {w} x {h} px, {n} of them: not a recording")
    try:
        fps = float(fields.get("Record Rate(fps)", "nan"))
    except ValueError:
        fps = math.nan
    fps = fps if fps > 0 else math.nan
    step = max(_integer(fields, "Save Step", header, 1), 1)
    skip = _integer(fields, "Skip Frame", header, 1)
    note = ""
    if skip > 1:
        note = (
            f"its header's skipFrame is {skip}: the time between its frames is not known from "
            f"the camera's {fps:g} fps"
        )
    return PhotronRecording(
        header=header, data=None, width=w, height=h, frames=n, bits=bits, depth=depth,
        fps=math.nan if note else fps / step, record_fps=fps, step=step, rate_note=note,
        shutter_s=_shutter(fields), camera=fields.get("Camera Type", ""),
        start_frame=_integer(fields, "Start Frame", header, 0),
        upper=fields.get("EffectiveBit Side", "Lower").lower().startswith("h"),
        file_format=fields.get("File Format", "MRaw"),
    )  # fmt: skip


@functools.lru_cache(maxsize=16)
def _open(path: str, stamp: tuple) -> PhotronRecording:
    p = pathlib.Path(path)
    if p.suffix.lower() == ".mraw":
        data, header = p, _sibling(p, (".cihx", ".cih"))
        if header is None:
            raise InvalidInputError(f"{p}: no Photron header beside it ({p.stem}.cihx or .cih)")
    else:
        header, data = p, _sibling(p, (".mraw",))
    rec = _parse(header, stamp)
    if rec.file_format.lower() != "mraw":
        raise InvalidInputError(
            f"{header}: the recording was saved as {rec.file_format!r}, not MRaw: read the "
            "exported image files"
        )
    if data is None:
        raise InvalidInputError(f"{p}: no raw frames beside it ({p.stem}.mraw)")
    size = data.stat().st_size
    if size != rec.frames * rec.frame_bytes:
        raise InvalidInputError(
            f"{data}: {size} bytes, where {header.name} says {rec.frames} frames of {rec.width} x "
            f"{rec.height} px at {rec.bits} bit ({rec.frames * rec.frame_bytes} bytes)"
        )
    return dataclasses.replace(rec, data=data)


def photron_recording(path: str | os.PathLike) -> PhotronRecording:
    """The recording of a Photron header (``.cihx``, ``.cih``) or raw file (``.mraw``).

    Parameters
    ----------
    path : str or path-like
        Either file; the other is found beside it (same name).

    Returns
    -------
    PhotronRecording
        Checked: monochrome, 8, 12 or 16 bit, and a raw file of exactly the header's frames.

    Raises
    ------
    InvalidInputError
        A missing file or field, a colour recording, a raw file of another size (module docs).
    """
    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    other = _sibling(p, (".mraw",) if p.suffix.lower() != ".mraw" else (".cihx", ".cih"))
    stamps = tuple((f.stat().st_mtime_ns, f.stat().st_size) for f in (p, other) if f is not None)
    return _open(str(p.resolve()), stamps)


def photron_header(path: str | os.PathLike) -> PhotronRecording:
    """The recording a Photron header (``.cihx``, ``.cih``) describes, whatever its frames'
    format: for frames exported as image files (``File Format`` Bmp, Tiff, ...) beside it, its
    camera and frame rate. ``data`` is None; its frames are not read through it.

    Raises
    ------
    InvalidInputError
        A missing file or field, a colour recording (module docs).
    """
    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    if p.suffix.lower() not in (".cihx", ".cih"):
        raise InvalidInputError(f"{p}: not a Photron header (.cihx, .cih)")
    st = p.stat()
    return _parse(p.resolve(), (st.st_mtime_ns, st.st_size))


def read_photron_frame(rec: PhotronRecording, index: int) -> np.ndarray:
    """Frame ``index`` (0-based, in file order) of a recording: ``uint8`` or ``uint16``
    ``image[y, x]``, counts from 0 to ``2**rec.depth - 1`` (module docs). Only its bytes are
    read.

    Raises
    ------
    InvalidInputError
        ``index`` outside ``0 .. rec.frames - 1``, or a raw file cut short since it was opened.
    """
    if rec.data is None:
        raise InvalidInputError(
            f"{rec.header}: frames exported as {rec.file_format} files: read those files"
        )
    if not 0 <= index < rec.frames:
        raise InvalidInputError(f"{rec.data}: frame {index} out of range ({rec.frames} frames)")
    nb = rec.frame_bytes
    raw = np.fromfile(rec.data, dtype=np.uint8, count=nb, offset=index * nb)
    if raw.size != nb:
        raise InvalidInputError(
            f"{rec.data}: frame {index} is cut short ({raw.size} of {nb} bytes)"
        )
    if rec.bits == 8:
        img = raw
    elif rec.bits == 16:
        img = raw.view("<u2").astype(np.uint16)
    else:  # 12 bit: two pixels in three bytes, most significant bits first
        b = raw.reshape(-1, 3).astype(np.uint16)
        img = np.empty(2 * b.shape[0], np.uint16)
        img[0::2] = (b[:, 0] << 4) | (b[:, 1] >> 4)
        img[1::2] = ((b[:, 1] & 15) << 8) | b[:, 2]
    if rec.upper and rec.depth < rec.bits:
        img = img >> (rec.bits - rec.depth)
    return np.ascontiguousarray(img.reshape(rec.height, rec.width))
