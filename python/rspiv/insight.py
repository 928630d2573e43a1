"""TSI Insight vector files (``.vec``), read into rspiv's pixel frame.

Insight (3G, 4G) writes each field as a Tecplot-style text file: a header of ``TITLE=``,
``VARIABLES=`` with each column's name and unit (``"X mm", "Y mm", "U m/s", "V m/s", "CHC"``,
or ``"X pixel", ..., "U pixel"``), ``DATASETAUXDATA`` entries and ``ZONE I=nx, J=ny, F=POINT``,
then one line per vector, x fastest, the top row first.

The conventions, from the entries the file carries:

- **Positions.** Insight measures x right and y *up*, in ``LengthUnit`` (``pixel``, ``mm``, ``m``)
  from ``OriginInImageX``/``OriginInImageY`` (image px). A pixel coordinate is
  ``X / s + OriginInImageX`` and ``OriginInImageY - Y / s`` (``s`` the length per px:
  ``MicrometersPerPixelX``/``Y``, 1 for pixel units). Insight labels a window of w px from pixel
  i by ``i + w/2`` (its real samples: 32 px windows of a 1024 px image at 16, 32, ... 1008),
  half a pixel past the window's centre ``i + (w - 1)/2`` in rspiv's frame (origin at the
  top-left pixel's centre): ``x - 1/2``, ``y - 1/2``; the nodes 6 decimals of a mm leave off
  their grid are put back on it (:mod:`rspiv.vector_grid`).
- **Displacements.** ``U``, ``V`` in a velocity unit (``m/s``, ``mm/s``, ``pixel/s``...) are
  multiplied by the pulse separation ``MicrosecondsPerDeltaT``; a unit without a time
  (``"U pixel"``, ``TimeUnit="deltaT"``) is already per pair. ``v`` is turned downward.
- **Choice code** ``CHC`` (TSI's validity flag): 1-3 a vector from the first to third
  correlation peak that Insight's validation accepted (``valid``); 4 and
  above a vector Insight filled after the validation (``postprocessed``); 0 and below rejected or
  not computed (NaN; TSI's samples hold -1 and -3, some with the rejected value written: it is
  not counted). A file without ``CHC`` counts every vector, and says so. The real files rspiv
  was tried on hold only the codes 1, -1 and -3; the reading of 2-4 follows TSI's description of
  the code (the peak chosen, then the vectors filled), not a sample.
- **Frame.** ``DewarpedImageSource="0"``: the raw recording (``"image"``); ``"1"``: images
  Insight dewarped (``"object"``); absent: not said.
- ``MicrosecondsPerDeltaT`` gives ``dt``; ``MicrometersPerPixelX`` the scale.
  ``SourceImageWidth``/``Height`` bound the positions (a vector outside the image is refused).

A third component (``W``) is left out and said; ``F=BLOCK`` and several zones are refused.
"""

from __future__ import annotations

import dataclasses
import pathlib
import re

import numpy as np

from rspiv.vector_grid import file_error as _fail

__all__ = ["InsightColumns", "is_insight", "read_insight"]

#: Lengths in mm, by the unit names Insight writes.
_LENGTH_MM = {"m": 1e3, "cm": 10.0, "mm": 1.0, "um": 1e-3, "µm": 1e-3, "micron": 1e-3}
_PIXEL = ("pixel", "pixels", "px", "pix")
#: Times in s.
_TIME_S = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


@dataclasses.dataclass(frozen=True)
class InsightColumns:
    """One Insight field as columns in rspiv's pixel frame (module docstring), one entry per
    vector in the file's order.

    Attributes
    ----------
    x, y : ndarray
        Positions, px (x right, y down, origin at the top-left pixel's centre).
    u, v : ndarray
        Displacements over the pair, px (v down).
    chc : ndarray of int
        TSI's choice code as written (all 1 when the file has none).
    dt, mm_per_px : float
        Pulse separation (s) and scale (mm per px), NaN when the file does not give them.
    frame : str
        ``"image"``, ``"object"`` or ``""`` (not said).
    notes : tuple of str
        What was assumed or left out.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    chc: np.ndarray
    dt: float
    mm_per_px: float
    frame: str
    notes: tuple[str, ...]


def is_insight(p: pathlib.Path) -> bool:
    """The file starts as Insight's header does (``TITLE=`` or ``VARIABLES=``)."""
    try:
        with open(p, "rb") as fh:
            head = fh.read(64).lstrip(b"\xef\xbb\xbf \t\r\n").upper()
    except OSError:
        return False
    return head.startswith((b"TITLE", b"VARIABLES"))


def _header(p: pathlib.Path) -> tuple[str, int]:
    """The header (every line before the first line of numbers) and its number of lines."""
    try:
        with open(p, "rb") as fh:
            for k, raw in enumerate(fh):
                s = raw.lstrip()
                if s[:1].isdigit() or s[:1] in (b"+", b"-", b"."):
                    fh.seek(0)
                    head = b" ".join(fh.readline().rstrip(b"\r\n") for _ in range(k))
                    return head.decode("latin-1"), k
    except OSError as exc:
        raise _fail(p, f"cannot read: {exc}") from None
    raise _fail(p, "an Insight header without vectors")


def _unit(p: pathlib.Path, unit: str, per_pixel_mm: float, what: str) -> float:
    """mm (or px when ``per_pixel_mm`` is 1 and the unit is a pixel) per px of ``unit``."""
    u = unit.strip().lower()
    if u in _PIXEL:
        return 1.0
    if u in _LENGTH_MM:
        if not np.isfinite(per_pixel_mm):
            raise _fail(p, f"{what} in {unit} without MicrometersPerPixel: cannot place them in px")
        return _LENGTH_MM[u] / per_pixel_mm
    raise _fail(p, f"{what} in {unit!r}: a length unit rspiv does not know")


def _velocity(p: pathlib.Path, unit: str, per_pixel_mm: float, dt: float) -> float:
    """The factor from a velocity column's unit to px per pair."""
    length, _, time = unit.strip().partition("/")
    factor = _unit(p, length or "pixel", per_pixel_mm, "displacements")
    if not time.strip():
        return factor  # "U pixel" with TimeUnit deltaT: per pair
    t = time.strip().lower()
    if t not in _TIME_S:
        raise _fail(p, f"displacements in {unit!r}: a time unit rspiv does not know")
    if not np.isfinite(dt):
        raise _fail(p, f"displacements in {unit} without MicrosecondsPerDeltaT")
    return factor * dt / _TIME_S[t]


def _aux_float(aux: dict[str, str], key: str) -> float:
    try:
        value = float(aux[key])
    except (KeyError, ValueError):
        return float("nan")
    return value if np.isfinite(value) else float("nan")


def read_insight(p: pathlib.Path) -> InsightColumns:
    """Read one Insight ``.vec`` file (module docstring); InvalidInputError naming the file for
    a file that is not one, a header it cannot place in px or values that are not numbers."""
    head, skip = _header(p)
    upper = head.upper()
    start = upper.find("VARIABLES")
    if start < 0:
        raise _fail(p, "an Insight header without VARIABLES")
    # the names run to the next keyword of the header (no nested regular expression: a damaged
    # header must not make the search backtrack)
    ends = [upper.find(k, start) for k in ("DATASETAUXDATA", "ZONE", "AUXDATA")]
    end = min([e for e in ends if e > start] or [len(head)])
    names = re.findall(r'"([^"]*)"', head[start:end])
    cols: dict[str, tuple[int, str]] = {}
    for k, name in enumerate(names):
        key, _, unit = name.strip().partition(" ")
        cols.setdefault(key.upper(), (k, unit.strip()))
    for key in ("X", "Y", "U", "V"):
        if key not in cols:
            raise _fail(p, f"an Insight file without the column {key} (columns {names})")
    aux = dict(re.findall(r'DATASETAUXDATA\s+(\w+)\s*=\s*"([^"]*)"', head, re.IGNORECASE))
    zones = re.split(r"\bZONE\b", head, flags=re.IGNORECASE)[1:]
    if len(zones) > 1:
        raise _fail(p, f"{len(zones)} zones: rspiv reads Insight files of one field")
    shape = None
    if zones:
        fmt = re.search(r"\bF\s*=\s*(\w+)", zones[0], re.IGNORECASE)
        if fmt and fmt.group(1).upper() != "POINT":
            raise _fail(p, f"F={fmt.group(1)}: only Insight's F=POINT layout is read")
        i = re.search(r"\bI\s*=\s*(\d+)", zones[0], re.IGNORECASE)
        j = re.search(r"\bJ\s*=\s*(\d+)", zones[0], re.IGNORECASE)
        if i and j:
            shape = (int(j.group(1)), int(i.group(1)))
    try:
        data = np.loadtxt(p, delimiter=",", skiprows=skip, ndmin=2, encoding="latin-1")
    except ValueError as exc:
        raise _fail(p, f"Insight vectors that are not numbers: {exc}") from None
    if data.shape[1] != len(names):
        raise _fail(p, f"{data.shape[1]} columns of numbers under {len(names)} VARIABLES")
    if shape is not None and shape[0] * shape[1] != len(data):
        raise _fail(p, f"{len(data)} vectors in a zone of I={shape[1]} x J={shape[0]}")
    if not np.all(np.isfinite(data[:, [cols[k][0] for k in ("X", "Y", "U", "V")]])):
        raise _fail(p, "a position or displacement that is not a number")
    notes = []
    mm_x = _aux_float(aux, "MicrometersPerPixelX") * 1e-3
    mm_y = _aux_float(aux, "MicrometersPerPixelY") * 1e-3
    if not np.isfinite(mm_y):
        mm_y = mm_x
    if np.isfinite(mm_x) and abs(mm_y - mm_x) > 1e-6 * mm_x:
        notes.append(f"pixels {mm_x * 1e3:g} x {mm_y * 1e3:g} um: the x scale given")
    dt = _aux_float(aux, "MicrosecondsPerDeltaT") * 1e-6
    dt = dt if dt > 0 else float("nan")
    ox, oy = _aux_float(aux, "OriginInImageX"), _aux_float(aux, "OriginInImageY")
    if not (np.isfinite(ox) and np.isfinite(oy)):
        ox = oy = 0.0
        notes.append("no OriginInImageX/Y: positions taken from the image's top-left corner")
    fx = _unit(p, cols["X"][1] or aux.get("LengthUnit", "pixel"), mm_x, "positions")
    fy = _unit(p, cols["Y"][1] or aux.get("LengthUnit", "pixel"), mm_y, "positions")
    # 6 decimals of a mm leave the nodes 1e-5 px off their grid: rspiv.vector_grid puts them back
    x = ox + data[:, cols["X"][0]] * fx - 0.5
    y = oy - data[:, cols["Y"][0]] * fy - 0.5
    u = data[:, cols["U"][0]] * _velocity(p, cols["U"][1] or "pixel", mm_x, dt)
    v = -data[:, cols["V"][0]] * _velocity(p, cols["V"][1] or "pixel", mm_y, dt)
    w_img, h_img = _aux_float(aux, "SourceImageWidth"), _aux_float(aux, "SourceImageHeight")
    if np.isfinite(w_img) and np.isfinite(h_img):
        out = (x < -1) | (y < -1) | (x > w_img) | (y > h_img)
        if out.any():
            raise _fail(
                p, f"{int(out.sum())} vectors outside the {w_img:g} x {h_img:g} px image: "
                "the header's origin or scale does not place them",
            )  # fmt: skip
    if "CHC" in cols:
        chc = data[:, cols["CHC"][0]]
        if not np.all(chc == np.round(chc)):
            raise _fail(p, "a CHC (choice code) that is not an integer")
        chc = chc.astype(np.int64)
    else:
        chc = np.ones(len(data), np.int64)
        notes.append("no CHC column: every vector counted as valid")
    if "W" in cols:
        notes.append("a 3C field: w left out")
    dewarped = aux.get("DewarpedImageSource", "").strip()
    frame = {"0": "image", "1": "object"}.get(dewarped, "")
    return InsightColumns(
        x=x, y=y, u=u, v=v, chc=chc, dt=dt, mm_per_px=mm_x if np.isfinite(mm_x) else np.nan,
        frame=frame, notes=tuple(notes),
    )  # fmt: skip
