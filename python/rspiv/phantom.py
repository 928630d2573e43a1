"""Phantom high-speed recordings: Vision Research ``.cine`` files.

A ``.cine`` holds a file header, a bitmap header, the camera's setup, tagged blocks (among
them each frame's time stamp) and the frames, each at an offset listed in the file, behind its
own annotation. :func:`phantom_recording` reads the headers and the offsets;
:func:`read_phantom_frame` reads one frame, and only its bytes (a recording of thousands of
frames is never held in memory).

Layout read here (little-endian): the file header (44 bytes: ``"CI"``, compression at byte 4,
the image count at 20, the offsets of the bitmap header, setup and frame offsets at 24, 28 and
32); the bitmap header (``biWidth``, ``biHeight``, ``biBitCount``, ``biClrImportant`` = 2 to the
sensor's bit depth); the setup's ``Mark`` (``"ST"``) and ``Length`` at bytes 140 and 142 of it,
and its 16-bit frame rate at byte 0; the tagged blocks that follow the setup (block size,
type, more-follow flag; type 1002 holds each frame's time as seconds and 2^-32 s fractions);
and one 64-bit offset per frame. Rows are stored bottom-up (a bitmap's positive height) and
are returned top-down, ``image[y, x]`` (a negative height: stored top-down).

The time between frames is taken from the frames' own time stamps (the median interval) when
the file has them: a recording saved with decimation (every 10th frame of a 90 kHz recording)
is then 9 kHz, as its frames are, where the setup's rate would say 90 kHz. Without them the
setup's 16-bit rate is used. A campaign checks its ``[flow] dt`` against it.

Only monochrome, uncompressed 8 or 16 bit frames are read. Refused in one line naming the
file: a file that is not a cine, colour frames (interpolated 24/48 bit, or a colour sensor's
uninterpolated raw), JPEG-compressed cines, 10 or 12 bit packed frames (save as 16 bit), a
frame whose stored size is not its width times its height, a frame out of range.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import pathlib
import struct
import typing

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["PHANTOM_SUFFIXES", "PhantomRecording", "phantom_recording", "read_phantom_frame"]

#: A Phantom recording is one ``.cine`` file.
PHANTOM_SUFFIXES = (".cine",)

_TIME_ONLY = 1002  # tagged block: one TIME64 per frame
_RANGE_DATA = 1004  # tagged block after which nothing is read


@dataclasses.dataclass(frozen=True)
class PhantomRecording:
    """A ``.cine`` file's headers and frame offsets.

    Attributes
    ----------
    path : pathlib.Path
        The file.
    width, height, frames : int
        Frame size (px) and the number of frames.
    bits : int
        Bits per pixel as stored: 8 or 16.
    depth : int
        The sensor's bit depth (from ``biClrImportant``; ``bits`` if it does not say).
    fps : float
        Frames per second of the frames saved (their time stamps; the setup's rate without
        them; NaN if neither says).
    fps_source : str
        ``"time stamps"``, ``"setup"`` or ``""``.
    first_image : int
        The first saved frame's number relative to the trigger.
    offsets : tuple of int
        Each frame's offset in the file (its annotation's start).
    camera : str
        Empty: the cine's model is not read here.
    shutter_s : float
        NaN: the exposure is not read here.
    bottom_up : bool
        Rows stored bottom-up (a positive ``biHeight``, the usual case).
    """

    KIND: typing.ClassVar[str] = "Phantom"
    path: pathlib.Path
    width: int
    height: int
    frames: int
    bits: int
    depth: int
    fps: float
    fps_source: str
    first_image: int
    offsets: tuple[int, ...]
    camera: str = ""
    bottom_up: bool = True
    shutter_s: float = math.nan

    @property
    def source(self) -> pathlib.Path:
        """The file the recording is named by."""
        return self.path

    @property
    def dt(self) -> float:
        """Time between consecutive frames, s (NaN without a frame rate)."""
        return 1.0 / self.fps if self.fps > 0 else math.nan

    def read(self, index: int) -> np.ndarray:
        """Frame ``index``: :func:`read_phantom_frame`."""
        return read_phantom_frame(self, index)


def _unpack(fmt: str, raw: bytes, at: int, p: pathlib.Path, what: str) -> tuple:
    try:
        return struct.unpack_from(fmt, raw, at)
    except struct.error:
        raise InvalidInputError(f"{p}: the file ends inside its {what}") from None


def _frame_rate(raw: bytes, p: pathlib.Path, off_setup: int, n: int, end: int) -> tuple:
    """``(fps, source)``: from the frames' time stamps (tagged block 1002) if the file holds
    them, else from the setup's 16-bit rate (65535 there means "see the 32-bit field")."""
    mark, length = _unpack("<2sH", raw, off_setup + 140, p, "setup")
    if mark == b"ST":
        at = off_setup + length
        while at + 8 <= end:
            size, kind, more = _unpack("<IHH", raw, at, p, "tagged blocks")
            if size < 8 or kind == _RANGE_DATA:
                break
            if kind == _TIME_ONLY and (size - 8) // 8 >= n >= 2:
                # a time stamp is seconds . 2^-32 s in 32.32 fixed point: its differences are
                # intervals in 2^-32 s, exact (as float seconds they would lose 0.2 us)
                stamps = np.frombuffer(raw, "<u8", count=n, offset=at + 8).astype(np.int64)
                step = float(np.median(np.diff(stamps))) / 2.0**32
                if step > 0:
                    return 1.0 / step, "time stamps"
            if not more:
                break
            at += size
    rate = _unpack("<H", raw, off_setup, p, "setup")[0]
    return (float(rate), "setup") if 0 < rate < 65535 else (math.nan, "")


@functools.lru_cache(maxsize=16)
def _open(path: str, stamp: tuple) -> PhantomRecording:
    p = pathlib.Path(path)
    with open(p, "rb") as f:
        head = f.read(44)
        if len(head) < 44 or head[:2] != b"CI":
            raise InvalidInputError(f"{p}: not a Phantom cine file (no 'CI' header)")
        _, _, compression, _, _, _, first, n, off_bi, off_setup, off_offsets, _ = struct.unpack(
            "<2sHHHiIiIIIIQ", head
        )
        f.seek(0)
        # the headers, the setup and the tagged blocks end where the frame offsets begin
        raw = f.read(off_offsets + 8 * n)
    bi = _unpack("<IiiHHIIiiII", raw, off_bi, p, "bitmap header")
    w, h, bits, clr_important = bi[1], bi[2], bi[4], bi[10]
    if compression == 1:
        raise InvalidInputError(f"{p}: a JPEG-compressed cine: rspiv reads uncompressed frames")
    if compression == 2 or bits in (24, 48):
        raise InvalidInputError(
            f"{p}: a colour camera's frames ({bits} bit, "
            f"{'uninterpolated raw' if compression == 2 else 'interpolated colour'}): rspiv "
            "reads monochrome recordings; the colour filter's pattern would be in every "
            "particle image"
        )
    if bits not in (8, 16) or w <= 0 or h == 0 or n <= 0:
        raise InvalidInputError(
            f"{p}: {n} frames of {w} x {h} px at {bits} bit (monochrome 8 or 16 bit are read)"
        )
    offsets = _unpack(f"<{n}q", raw, off_offsets, p, "frame offsets")
    fps, how = _frame_rate(raw, p, off_setup, n, off_offsets)
    depth = bits
    if clr_important > 1 and clr_important & (clr_important - 1) == 0:
        depth = min(bits, clr_important.bit_length() - 1)
    return PhantomRecording(
        path=p, width=w, height=abs(h), frames=n, bits=bits, depth=depth, fps=fps,
        fps_source=how, first_image=first, offsets=tuple(offsets), bottom_up=h > 0,
    )  # fmt: skip


def phantom_recording(path: str | os.PathLike) -> PhantomRecording:
    """The recording of a Phantom ``.cine`` file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    PhantomRecording
        Monochrome, uncompressed, 8 or 16 bit (module docs).

    Raises
    ------
    InvalidInputError
        A missing file, not a cine, colour, compressed or packed frames (module docs).
    """
    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    st = p.stat()
    return _open(str(p.resolve()), (st.st_mtime_ns, st.st_size))


def read_phantom_frame(rec: PhantomRecording, index: int) -> np.ndarray:
    """Frame ``index`` (0-based, in file order) of a cine: ``uint8`` or ``uint16``
    ``image[y, x]``, rows top-down. Only its bytes are read.

    Raises
    ------
    InvalidInputError
        ``index`` outside ``0 .. rec.frames - 1``; a frame packed at 10 or 12 bit, or whose
        stored size is not ``width * height`` pixels; a file cut short.
    """
    if not 0 <= index < rec.frames:
        raise InvalidInputError(f"{rec.path}: frame {index} out of range ({rec.frames} frames)")
    px = rec.width * rec.height
    with open(rec.path, "rb") as f:
        f.seek(rec.offsets[index])
        ann = f.read(4)
        if len(ann) < 4:
            raise InvalidInputError(f"{rec.path}: frame {index} lies beyond the file's end")
        (ann_size,) = struct.unpack("<I", ann)
        f.seek(rec.offsets[index] + ann_size - 4)
        (size,) = struct.unpack("<I", f.read(4) or b"\0\0\0\0")
        if size * 8 in (10 * px, 12 * px):
            raise InvalidInputError(
                f"{rec.path}: frames packed at {size * 8 // px} bit: save the cine unpacked "
                "(16 bit) to read it"
            )
        if size != px * rec.bits // 8:
            raise InvalidInputError(
                f"{rec.path}: frame {index} holds {size} bytes, not {rec.width} x {rec.height} "
                f"px at {rec.bits} bit"
            )
        data = f.read(size)
    if len(data) != size:
        raise InvalidInputError(f"{rec.path}: frame {index} is cut short ({len(data)} bytes)")
    img = np.frombuffer(data, np.uint8 if rec.bits == 8 else "<u2").reshape(rec.height, rec.width)
    img = img[::-1] if rec.bottom_up else img
    return np.ascontiguousarray(img, dtype=np.uint8 if rec.bits == 8 else np.uint16)
