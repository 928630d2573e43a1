"""Vector fields written by other PIV tools, read into rspiv's pixel frame.

A lab that takes up rspiv first asks whether it agrees with the tool it has, on its own
recordings. :func:`read_vectors` reads that tool's vector field as a :class:`VectorFile` in
rspiv's conventions, so that :func:`rspiv.compare.compare_fields` can answer (``rspiv compare``).

The conventions everything is brought to (those of :class:`rspiv.PivField`): positions in px of
the recording, x right and y down, the origin at the centre of the top-left pixel; displacements
in px over the pair, u right and v down. Each reader states how it gets there:

- **DaVis** vector buffers (``.vc7``, read by ``lvpyio``): the stored components are
  displacements in px along the image's axes (DaVis' scales turn them into m/s). Vector ``(i, j)``
  stands at ``(i + 1/2) * grid`` px from the image's top-left edge (lvpyio's placement), i.e.
  ``x = (i + 1/2) * grid - 1/2`` in rspiv's frame. The pulse separation and the scale come from
  the scales (``dt = |x slope| / velocity slope``). Of DaVis' choices, 0 is the highest peak and
  1-3 the second to fourth (valid, ``peak_choice`` 1-4); 4 and 5 are vectors DaVis filled or
  smoothed after the validation (``postprocessed``). Disabled and masked vectors are not computed.
  DaVis' ``TS:Uncertainty Vx/Vy`` (when written) give ``sigma_u``/``sigma_v`` (px; 0 read as none),
  ``TS:Peak ratio`` the peak ratio. A 3C buffer's ``w`` is left out (said in ``notes``).
- **OpenPIV** text files (``openpiv.tools.save``: ``x y u v flags mask``; older files ``x y u v
  s2n``): positions in px and displacements in px per pair, as OpenPIV writes them without a
  scaling factor; ``scale`` (units per px) and ``dt`` (s) undo one. OpenPIV measures positions
  from the image's top-left corner (its ``get_coordinates``: a window of w px from pixel i is at
  ``i + w/2``), half a pixel from rspiv's origin at that pixel's centre: ``x - 1/2``. OpenPIV's
  ``transform_coordinates`` (which its ``windef`` pipeline applies before saving) turns y and v
  upward by reversing the rows: with ``y_up=True`` they are turned back (``y -> y_min + y_max -
  y``, ``v -> -v``). A file does not say which it is: :func:`rspiv.compare.compare_fields` checks
  the other reading and says when it fits far better. Flags 0 valid, 1 invalid, 2 interpolated
  (``postprocessed``); a mask of 1 or a NaN is not computed. A fifth column (older files) is
  read as its header names it: ``mask`` or ``flags`` (1 invalid, as OpenPIV's validation
  wrote it), else the signal-to-noise ratio (``peak_ratio``); without a header, values of 0, 1
  and 2 only are flags.
- **PIVlab** MAT files (the GUI's "save all frames", or ``PIVlab_commandline``): cell arrays
  ``x``, ``y``, ``u_original``/``v_original`` (or ``u``/``v``) and ``typevector_original`` (or
  ``typevector``) of one cell per pair; ``frame`` picks the cell. PIVlab labels a window of w
  px from (1-based) pixel i by ``i + w/2``, half a pixel past its centre ``i + (w - 1)/2``, and
  counts pixels from 1: ``x - 3/2`` in rspiv's frame (``piv_FFTmulti``'s ``xtable``). u and v
  are px per pair along the image's axes. Typevector 1 valid, 0 masked, 2 interpolated by the
  post-processing (``typevector_filtered`` of the GUI's export, ``typevector_filt`` of
  ``PIVlab_commandline``: when present it decides validity). A calibrated export (``calxy``
  m/px, ``calu``/``calv`` m/s or m per px per pair, their signs the axes' directions) is read
  back in px: ``u / calu``, ``v / calv``, the scale ``calxy`` and ``dt = calxy / |calu|``
  (none when ``units`` says m/frame). Its positions are PIVlab's ``(x or width - x) * calxy -
  offset``, and the file holds neither the offset nor the width: they are read as ``+-x /
  calxy``, the recording's px up to a constant (``origin_known`` False), so that what needs
  the recording's px (a camera calibration, ``wall_y``, a comparison) is refused.
  Exports of PIVlab before ``calu``/``calv`` (``caluv`` not 1) are refused. A session file
  (``resultslist``) holds px whatever its calibration, which then gives the scale and dt.
- **TSI Insight** ``.vec`` files (a Tecplot-style header: ``TITLE=``, ``VARIABLES=``, ``CHC``;
  told from OpenPIV's ``.vec`` by that header): y up from the header's origin, positions half a
  pixel past the windows' centres, the header's units, dt and scale; choice codes 1-3 valid, 4
  and above filled, 0 and below not counted (:mod:`rspiv.insight`).
- **rspiv**'s own NetCDF (``rspiv piv -o field.nc``, a campaign's ``OUT/fields/<run>/pair_*.nc``)
  and Tecplot files (``.dat``, ``.tec``, ``.plt`` with ``units = "px"``).

Every reader refuses, in one line naming the file, a file it cannot read this way, positions
that are not a regular grid, and values that are not numbers.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import pathlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.hdf5_check import global_heap_damage
from rspiv.insight import is_insight, read_insight
from rspiv.vector_grid import check_regular as _check_regular
from rspiv.vector_grid import file_error as _fail
from rspiv.vector_grid import grid_from_columns as _grid_from_columns

__all__ = [
    "VECTOR_SUFFIXES", "VectorFile", "read_vectors", "vector_frames", "from_piv_field",
    "as_vectors", "vector_series",
]  # fmt: skip


#: Suffixes :func:`read_vectors` reads, by tool.
VECTOR_SUFFIXES = {
    ".vc7": "DaVis",
    ".txt": "OpenPIV",
    ".vec": "OpenPIV",
    ".mat": "PIVlab",
    ".nc": "rspiv",
    ".dat": "rspiv",
    ".tec": "rspiv",
    ".plt": "rspiv",
}


@dataclasses.dataclass(frozen=True)
class VectorFile:
    """A vector field in rspiv's pixel frame (module docstring); arrays of shape ``(ny, nx)``.

    Attributes
    ----------
    x, y : ndarray of float64
        Vector positions, px (x right, y down, origin at the top-left pixel's centre); a regular
        grid: ``x`` constant along columns' rows, ``y`` increasing downward.
    u, v : ndarray of float64
        Displacement over the pair, px (v down); NaN where not computed.
    valid : ndarray of bool
        Measured and accepted by the tool's validation (not filled, smoothed or masked).
    postprocessed : ndarray of bool
        Computed but filled or smoothed by the tool after its validation.
    peak_ratio, sigma_u, sigma_v : ndarray of float64 or None
        The tool's peak ratio (or signal-to-noise ratio) and standard uncertainties (px), when it
        wrote them; NaN where it did not.
    tool : str
        ``"DaVis"``, ``"OpenPIV"``, ``"PIVlab"``, ``"Insight"`` or ``"rspiv"``.
    path : str
        The file read.
    dt : float
        Pulse separation, s, when the file gives it (DaVis, Insight, rspiv), else NaN.
    mm_per_px : float
        Scale of the recording, mm per px, when the file gives it (DaVis, Insight, rspiv), else
        NaN.
    window : tuple of int or None
        The final interrogation window ``(w, h)``, px, when the file gives it.
    notes : tuple of str
        What the reader assumed or left out, one line each.
    frame : str
        ``"image"`` (the raw recording's px: OpenPIV, PIVlab, an uncorrected rspiv run),
        ``"object"`` (px of a distortion-corrected frame: rspiv's Method I or II), or ``""``
        when the file does not say (DaVis, which may have dewarped the images itself).
    origin_known : bool
        False when the positions are the recording's px only up to a constant per axis (a
        calibrated PIVlab export: its offset is not in the file); spacing and displacements
        are exact. ``y_from_file`` ``(a, b)``: then ``y = a y_file + b`` of the file's own y.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    postprocessed: np.ndarray
    peak_ratio: np.ndarray | None
    sigma_u: np.ndarray | None
    sigma_v: np.ndarray | None
    tool: str
    path: str
    dt: float = float("nan")
    mm_per_px: float = float("nan")
    window: tuple[int, int] | None = None
    notes: tuple[str, ...] = ()
    frame: str = ""
    origin_known: bool = True
    y_from_file: tuple[float, float] | None = None

    @property
    def spacing(self) -> tuple[float, float]:
        """Grid spacing ``(dx, dy)``, px (NaN along an axis of one vector)."""
        dx = float(self.x[0, 1] - self.x[0, 0]) if self.x.shape[1] > 1 else float("nan")
        dy = float(self.y[1, 0] - self.y[0, 0]) if self.y.shape[0] > 1 else float("nan")
        return dx, dy

    def to_xarray(self):
        """The field as an :class:`xarray.Dataset` in the layout ``rspiv piv`` writes (``u``,
        ``v`` px, ``chc`` 1 valid, 0 filled or smoothed, -1 not computed, the peak ratio and
        uncertainties when given; coordinates ``x``, ``y`` px), with the tool, the source file
        and the frame as attributes, so that :func:`read_vectors` reads it back as it is."""
        import xarray as xr

        dims = ("y", "x")
        chc = np.where(self.valid, 1, np.where(self.postprocessed, 0, -1)).astype(np.int8)
        pix = {"units": "pix"}
        data = {"u": (dims, self.u, pix), "v": (dims, self.v, pix), "chc": (dims, chc)}
        for name in ("peak_ratio", "sigma_u", "sigma_v"):
            arr = getattr(self, name)
            if arr is not None:
                data[name] = (dims, arr, {} if name == "peak_ratio" else pix)
        attrs = {"tool": self.tool, "source": self.path, "frame": self.frame}
        if not self.origin_known:
            attrs["origin"] = "unknown"
        if self.window is not None:
            attrs["window"] = f"{self.window[0]} {self.window[1]}"
        for key, val in (("dt_s", self.dt), ("mm_per_px", self.mm_per_px)):
            if np.isfinite(val):
                attrs[key] = float(val)
        if self.notes:
            attrs["notes"] = "; ".join(self.notes)
        coords = {"x": ("x", self.x[0], pix), "y": ("y", self.y[:, 0], pix)}
        return xr.Dataset(data, coords=coords, attrs=attrs)

    def describe(self) -> str:
        """One line: the tool, the grid, the vectors valid and post-processed."""
        ny, nx = self.u.shape
        dx, dy = self.spacing
        computed = int(np.isfinite(self.u).sum())
        extra = ""
        if self.window is not None:
            extra += f", window {self.window[0]} x {self.window[1]} px"
        if np.isfinite(self.dt):
            extra += f", dt {self.dt * 1e6:.6g} us"
        if np.isfinite(self.mm_per_px):
            extra += f", {self.mm_per_px * 1e3:.6g} um/px"
        return (
            f"{self.tool} field {pathlib.Path(self.path).name}: {nx} x {ny} vectors every "
            f"{dx:g} x {dy:g} px{extra}; {int(self.valid.sum())} valid, "
            f"{int(self.postprocessed.sum())} filled or smoothed, "
            f"{nx * ny - computed} not computed"
        )


def _davis(p: pathlib.Path, frame: int) -> VectorFile:
    from rspiv.io import _davis_buffer  # deferred: lvpyio is imported only for DaVis files

    buf = _davis_buffer(p)
    if not 0 <= frame < len(buf):
        raise _fail(p, f"frame {frame} out of range: the buffer holds {len(buf)}")
    f = buf[frame]
    if type(f).__name__ != "VectorFrame":
        raise _fail(p, "a DaVis image, not a vector field")
    notes = []
    try:
        comps = f.components
        gx, gy = int(f.grid.x), int(f.grid.y)
        choice = np.asarray(f.active_choice[0])
        on = np.asarray(f.enabled[0]) != 0
        if "MASK" in comps:
            on &= np.asarray(comps["MASK"][0]) != 0
        ny, nx = choice.shape
        u = np.full((ny, nx), np.nan)
        v = np.full((ny, nx), np.nan)
        last = int(f.choices) - 1
        for k in range(6):
            sel = on & (choice == k)
            if not sel.any():
                continue
            src = k if k <= last else last
            u[sel] = np.asarray(comps[f"U{src}"][0], dtype=np.float64)[sel]
            v[sel] = np.asarray(comps[f"V{src}"][0], dtype=np.float64)[sel]
        if len(comps["U0"]) > 1:
            notes.append(f"plane 0 of {len(comps['U0'])} read")
        if "W0" in comps:
            notes.append("a 3C field: w left out")
        sx, sy, si = f.scales.x, f.scales.y, f.scales.i

        def scalar(name: str) -> np.ndarray | None:
            if name not in comps:
                return None
            a = np.asarray(comps[name][0], dtype=np.float64).copy()
            a[~on] = np.nan
            return a

        peak = scalar("TS:Peak ratio")
        su = scalar("TS:Uncertainty Vx")
        sv = scalar("TS:Uncertainty Vy")
        attrs = dict(f.attributes)
    except (KeyError, AttributeError, IndexError, TypeError, ValueError) as exc:
        raise _fail(p, f"a DaVis vector buffer without the expected parts ({exc})") from None
    if gx < 1 or gy < 1:
        raise _fail(p, f"a DaVis vector grid of {gx} x {gy} px")
    known = on & (choice >= 0) & (choice <= 5)
    u[~known] = np.nan
    v[~known] = np.nan
    for a in (su, sv):
        if a is not None:
            a[a <= 0] = np.nan  # DaVis writes 0 where it has no estimate
    xs = (np.arange(nx) + 0.5) * gx - 0.5
    ys = (np.arange(ny) + 0.5) * gy - 0.5
    x, y = np.meshgrid(xs, ys)
    mm_per_px = dt = float("nan")
    if str(sx.unit).strip().lower() == "mm" and sx.slope != 0:
        mm_per_px = abs(float(sx.slope))
        if str(si.unit).strip().lower() == "m/s" and si.slope > 0:
            dt = mm_per_px * 1e-3 / float(si.slope)
    if float(sy.slope) * float(sx.slope) > 0:
        notes.append("scales with y and x the same sign: DaVis' y axis points down")
    window = None
    size = str(attrs.get("InterrogationWindowSize", "")).strip()
    if size.isdigit():
        window = (int(size), int(size))
    valid = known & (choice <= 3)
    post = known & (choice >= 4)
    if not valid.any() and post.any():
        notes.append("every vector filled or smoothed by DaVis: no raw vector to compare")
    return VectorFile(
        x=x, y=y, u=u, v=v, valid=valid, postprocessed=post, peak_ratio=peak,
        sigma_u=su, sigma_v=sv, tool="DaVis", path=str(p), dt=dt, mm_per_px=mm_per_px,
        window=window, notes=tuple(notes),
    )  # fmt: skip


def _openpiv(p: pathlib.Path, y_up: bool, scale: float, dt: float) -> VectorFile:
    try:
        text = p.read_text(errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(p, f"cannot read as text: {exc}") from None
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise _fail(p, "no vectors")
    try:
        data = np.loadtxt(rows, ndmin=2)
    except ValueError as exc:
        raise _fail(p, f"not an OpenPIV text file of numbers: {exc}") from None
    if data.shape[1] not in (4, 5, 6):
        raise _fail(p, f"{data.shape[1]} columns: an OpenPIV file has x y u v [flags [mask]]")
    if not (np.isfinite(scale) and scale > 0 and np.isfinite(dt) and dt > 0):
        raise _fail(p, f"scale {scale} and dt {dt} must be positive")
    notes = []
    xs, ys = data[:, 0] / scale - 0.5, data[:, 1] / scale - 0.5  # corner -> pixel centre
    u, v = data[:, 2] * dt / scale, data[:, 3] * dt / scale
    flags = np.zeros(len(data))
    mask = np.zeros(len(data))
    snr = np.full(len(data), np.nan)
    if data.shape[1] == 6:
        flags, mask = data[:, 4], data[:, 5]
    elif data.shape[1] == 5:
        col = data[:, 4]
        heads = [ln.lstrip("# \t").split() for ln in text.splitlines() if ln.startswith("#")]
        fifth = heads[-1][4].lower() if heads and len(heads[-1]) == 5 else ""
        if fifth in ("flags", "mask") or (not fifth and np.all(np.isin(col, (0.0, 1.0, 2.0)))):
            flags = col
            notes.append(f"fifth column ({fifth or 'values 0, 1, 2'}) read as flags: 1 invalid")
        else:
            snr = col
            notes.append("fifth column read as the signal-to-noise ratio")
    x, y, (u, v, flags, mask, snr) = _grid_from_columns(
        p, xs, ys, [u, v, flags, mask, snr], notes
    )
    if y_up:
        # OpenPIV's transform_coordinates reverses the rows and negates v
        u, v, flags, mask, snr = (a[::-1] for a in (u, v, flags, mask, snr))
        v = -v
        notes.append("read with y and v upward (OpenPIV's transform_coordinates) and turned")
    computed = (mask == 0) & np.isfinite(u) & np.isfinite(v)
    u = np.where(computed, u, np.nan)
    v = np.where(computed, v, np.nan)
    valid = computed & (flags == 0)
    post = computed & (flags == 2)
    peak = snr if np.isfinite(snr).any() else None
    return VectorFile(
        x=x, y=y, u=u, v=v, valid=valid, postprocessed=post, peak_ratio=peak, sigma_u=None,
        sigma_v=None, tool="OpenPIV", path=str(p), notes=tuple(notes), frame="image",
    )  # fmt: skip


#: The last MAT file parsed, ``((path, mtime_ns, size), variables)``: a PIVlab session holds
#: every pair of a series, read a pair at a time; parsing it once is enough (one file held).
_LAST_MAT: list[Any] = [None]


def _mat_variables(p: pathlib.Path) -> dict[str, Any]:
    """MATLAB variables of a v5-v7 (:mod:`rspiv.matfile`) or v7.3 (HDF5, h5py) file, in MATLAB's
    shapes; a cell is an object array of arrays. The last file's are kept (:data:`_LAST_MAT`)."""
    from rspiv.io import last_file  # deferred: io imports the image readers

    return last_file(_LAST_MAT, p, _parse_mat)


def _parse_mat(p: pathlib.Path) -> dict[str, Any]:
    with p.open("rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x89HDF"):
        import h5py

        damage = global_heap_damage(p)  # HDF5 could loop on it (rspiv.hdf5_check)
        if damage:
            raise _fail(p, f"not a readable MAT file ({damage})")
        out: dict[str, Any] = {}
        try:
            with h5py.File(p, "r") as h:
                for name, ds in h.items():
                    if not isinstance(ds, h5py.Dataset) or name.startswith("#"):
                        continue
                    if ds.dtype == object:  # a cell: references, stored transposed
                        refs = np.asarray(ds).T
                        cell = np.empty(refs.shape, dtype=object)
                        for k in np.ndindex(refs.shape):
                            item = h[refs[k]]
                            empty = bool(item.attrs.get("MATLAB_empty", 0))
                            cell[k] = np.zeros((0, 0)) if empty else np.asarray(item).T
                        out[name] = cell
                    else:
                        out[name] = np.asarray(ds).T
        except Exception as exc:  # h5py raises RuntimeError, OSError, KeyError... on damage
            raise _fail(p, f"not a MATLAB v7.3 file h5py reads: {exc}") from None
        return out
    from rspiv.matfile import read_mat  # deferred: only PIVlab files need it

    return read_mat(p)  # not scipy's reader: a damaged file crashed it (rspiv.matfile)


def _pivlab_units(p: pathlib.Path, var: dict[str, Any]) -> dict[str, float]:
    """PIVlab's units: ``su``, ``sv`` (``calu``/``calv``: +-1 in px, else the calibration's
    factors, their signs the axes' directions), ``calxy`` (m/px, 1 in px), ``dt`` (s, NaN in
    px or displacements only); refuses a calibration it cannot undo."""

    def scalar(key: str) -> float | None:
        if key not in var:
            return None
        try:
            c = np.asarray(var[key], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise _fail(p, f"{key} is not a number") from None
        return float(c[0]) if c.size else None

    calxy, caluv = scalar("calxy"), scalar("caluv")
    calu, calv = scalar("calu"), scalar("calv")
    if caluv is not None and caluv != 1.0 and (calu is None or calv is None):
        raise _fail(p, f"a calibrated export of an older PIVlab (calxy {calxy}, caluv {caluv}, "
                       "no calu/calv): export it in px")  # fmt: skip
    calxy = 1.0 if calxy is None else calxy
    su, sv = (1.0 if c is None else c for c in (calu, calv))
    if calxy == 1.0 and abs(su) == 1.0 and abs(sv) == 1.0:
        return {"su": su, "sv": sv, "calxy": 1.0, "dt": float("nan")}
    if not (np.isfinite(calxy) and calxy > 0 and np.isfinite(su) and np.isfinite(sv)
            and su != 0 and abs(abs(su) / abs(sv) - 1.0) < 1e-9):  # fmt: skip
        raise _fail(p, f"a PIVlab calibration rspiv cannot undo (calxy {calxy:g}, calu {su:g}, "
                       f"calv {sv:g})")  # fmt: skip
    units = var.get("units", "")
    if isinstance(units, np.ndarray) and units.dtype.kind in "ui":  # v7.3: UTF-16 codes
        units = "".join(chr(int(c)) for c in units.ravel(order="F"))
    units = _text(units)
    # PIVlab writes "[m] respectively [m/s]" or "[m/frame]"; without it, |calu| = calxy is a
    # displacement (a pulse separation of 1 s is not PIV's)
    per_frame = "m/frame" in units or ("m/s" not in units and abs(abs(su) / calxy - 1) < 1e-9)
    dt = float("nan") if per_frame else calxy / abs(su)
    return {"su": su, "sv": sv, "calxy": calxy, "dt": dt}


def _pivlab(p: pathlib.Path, frame: int) -> VectorFile:
    try:
        var = _mat_variables(p)
    except OSError as exc:
        raise _fail(p, f"cannot read: {exc}") from None
    session = var.get("resultslist")
    # a session's results are px whatever its calibration (which PIVlab applies on export):
    # the calibration gives the scale and dt only
    in_px = session is not None and not any(k in var for k in ("x", "u_original", "u"))
    try:
        cal = _pivlab_units(p, var)
    except InvalidInputError:
        if not in_px:
            raise
        cal = {"su": 1.0, "sv": 1.0, "calxy": 1.0, "dt": float("nan")}
    calxy = cal["calxy"]
    su, sv = (1.0, 1.0) if in_px else (cal["su"], cal["sv"])
    scaled = calxy != 1.0 and not in_px  # positions in m: px up to PIVlab's offset

    def cell(*names: str) -> np.ndarray | None:
        for name in names:
            if name in var:
                val = var[name]
                items = val.ravel(order="F") if val.dtype == object else [val]
                if not 0 <= frame < len(items):
                    raise _fail(p, f"frame {frame} out of range: {name} holds {len(items)}")
                a = np.asarray(items[frame], dtype=np.float64)
                return a if a.size else None
        if session is not None and session.dtype == object and len(names) and names[-1]:
            row = {"x": 0, "y": 1, "u": 2, "v": 3, "typevector": 4, "u_filt": 6,
                   "typevector_filt": 8}.get(names[-1])  # fmt: skip
            if row is not None and row < session.shape[0]:
                if not 0 <= frame < session.shape[1]:
                    raise _fail(p, f"frame {frame} out of range: {session.shape[1]} results")
                a = np.asarray(session[row, frame], dtype=np.float64)
                return a if a.ndim == 2 and a.size else None  # [] (or its dims) when empty
        return None

    try:
        x, y = cell("x"), cell("y")
        u, v = cell("u_original", "u"), cell("v_original", "v")
        tv = cell("typevector_original", "typevector")
        tf = cell("typevector_filtered", "typevector_filt")
        uf = cell("u_filtered", "u_filt")
    except (TypeError, ValueError, AttributeError, IndexError) as exc:
        raise _fail(p, f"a PIVlab variable that is not an array of numbers ({exc})") from None
    if x is None or y is None or u is None or v is None:
        raise _fail(p, "not a PIVlab result: no x, y, u_original/u and v_original/v")
    shapes = {a.shape for a in (x, y, u, v) + tuple(b for b in (tv, tf) if b is not None)}
    if len(shapes) != 1 or x.ndim != 2:
        raise _fail(p, f"x, y, u, v and the typevectors differ in shape: {sorted(shapes)}")
    u, v = u / su, v / sv  # calu/calv: the calibration, its sign the axis' direction
    if scaled:  # PIVlab's px up to its offset (and the width where an axis turned)
        x, y = np.sign(su) * x / calxy, np.sign(sv) * y / calxy
    x, y = x - 1.5, y - 1.5  # 1-based, and half a pixel past the window's centre
    if y.shape[0] > 1 and y[1, 0] < y[0, 0]:
        raise _fail(p, "y decreases down the rows: not PIVlab's pixel coordinates")
    _check_regular(p, x, y)
    tv = np.ones_like(u) if tv is None else tv
    computed = (tv != 0) & np.isfinite(u) & np.isfinite(v)
    notes = ["positions read as PIVlab's: 1-based, half a pixel past the window's centre"]
    if sv < 0 or su < 0:
        notes.append("calu/calv negative: the axis turned back")
    if scaled:
        notes.append(
            f"a calibrated export read back in px ({calxy * 1e6:.6g} um/px): positions up to "
            "PIVlab's offset, not the recording's px"
        )
    elif calxy != 1.0:
        notes.append(f"a session in px; its calibration gives {calxy * 1e6:.6g} um/px")
    valid = computed & np.isin(tv, (1, 3))  # 3: PIVlab's valid vector from the second peak
    post = np.zeros_like(valid)
    if tf is not None:
        valid &= np.isin(tf, (1, 3))
        post = computed & (tf == 2)
        notes.append("validity from the filtered typevector (2: interpolated by PIVlab)")
    elif uf is not None:
        notes.append("filtered velocities without their typevector: PIVlab's filtering not read")
    return VectorFile(
        x=x, y=y, u=np.where(computed, u, np.nan), v=np.where(computed, v, np.nan),
        valid=valid, postprocessed=post, peak_ratio=None, sigma_u=None, sigma_v=None,
        tool="PIVlab", path=str(p), notes=tuple(notes), frame="image",
        dt=cal["dt"], mm_per_px=float("nan") if calxy == 1.0 else calxy * 1e3,
        origin_known=not scaled, y_from_file=(float(np.sign(sv)) / calxy, -1.5) if scaled else None,
    )  # fmt: skip


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return _text(value.ravel()[0])
    return str(value)


def _rspiv_netcdf(p: pathlib.Path) -> VectorFile:
    """rspiv's NetCDF-4 fields, read with h5py (its layout is rspiv's own: no xarray needed,
    and h5netcdf's failure on a damaged file left a noisy destructor behind)."""
    import h5py

    names = ("x", "y", "u", "v", "chc", "valid", "peak_ratio", "sigma_u", "sigma_v",
             "replaced_index", "replaced_u", "replaced_v")  # fmt: skip
    damage = global_heap_damage(p)  # HDF5 would loop on it (rspiv.hdf5_check)
    if damage:
        raise _fail(p, f"not a NetCDF-4 file rspiv reads ({damage})")
    try:
        with h5py.File(p, "r") as h:
            arr = {k: np.asarray(h[k][()]) for k in names if isinstance(h.get(k), h5py.Dataset)}
            units = {k: _text(h[k].attrs.get("units", "pix")) for k in ("u", "v") if k in arr}
            attrs = {
                k: _text(h.attrs.get(k, ""))
                for k in ("method", "run", "piv_settings", "frame", "tool", "window", "origin")
            }
            # the pulse separation and scale: a campaign's field files (dt_s, m_per_px) and a
            # VectorFile written by to_xarray (dt_s, mm_per_px)
            scales = {k: h.attrs.get(k) for k in ("dt_s", "m_per_px", "mm_per_px")}
    except Exception as exc:  # h5py raises OSError, KeyError, RuntimeError... on damage
        first = (str(exc).splitlines() or [""])[0]
        raise _fail(p, f"not a NetCDF-4 file rspiv reads ({type(exc).__name__}: {first})") from None
    if not {"u", "v", "x", "y"} <= set(arr):
        raise _fail(p, "not an rspiv vector field on a grid (u, v on coordinates x, y)")
    for name, unit in units.items():
        if unit not in ("pix", "px"):
            raise _fail(p, f"{name} in {unit!r}: only fields in px are read")
    try:
        x, y = np.meshgrid(arr["x"].astype(float), arr["y"].astype(float))
        u = arr["u"].astype(float)
        v = arr["v"].astype(float)
        if u.shape != x.shape or v.shape != x.shape:
            raise ValueError(f"u {u.shape}, v {v.shape} on a grid of {x.shape}")
    except (TypeError, ValueError) as exc:
        raise _fail(p, f"not an rspiv vector field on a grid ({exc})") from None
    _check_regular(p, x, y)
    if "chc" in arr:  # rspiv piv's field: 1 valid, 0 replaced, -1 not computed
        chc = arr["chc"]
    elif "valid" in arr:  # a campaign's field file: rejected vectors NaN, valid 1, and the
        chc = np.where(arr["valid"].astype(bool) & np.isfinite(u), 1, -1)  # replacements apart
        rep = [arr.get(k) for k in ("replaced_index", "replaced_u", "replaced_v")]
        if all(r is not None and r.ndim == 1 and r.size == rep[0].size for r in rep):
            idx = rep[0].astype(np.int64)
            if idx.size and (idx.min() < 0 or idx.max() >= u.size):
                raise _fail(p, "replaced vectors outside the grid")
            u, v = u.copy(), v.copy()
            u.flat[idx], v.flat[idx] = rep[1], rep[2]
            chc.flat[idx] = 0
    else:
        chc = np.where(np.isfinite(u), 1, -1)
    if chc.shape != x.shape:
        raise _fail(p, f"flags of shape {chc.shape} on a grid of {x.shape}")

    def opt(name: str) -> np.ndarray | None:
        a = arr.get(name)
        return a.astype(float) if a is not None and a.shape == x.shape else None

    # rspiv piv's attrs name the method of a corrected field, a campaign's files the run, and a
    # VectorFile written by to_xarray its tool and frame (empty where the tool did not say)
    method, run = attrs["method"].strip(), attrs["run"].strip()
    tool, frame = attrs["tool"].strip(), attrs["frame"].strip()
    if method in ("I", "II") or run.startswith("method_") or frame == "object":
        frame = "object"
    elif not (tool and frame == ""):
        frame = "image"
    window = None
    try:
        window = tuple(int(w) for w in json.loads(attrs["piv_settings"])["passes"][-1])[:2]
    except (KeyError, ValueError, TypeError, IndexError):
        try:
            window = tuple(int(w) for w in attrs["window"].split())[:2]
        except ValueError:
            pass
    dt, mm = (_positive(scales[k]) for k in ("dt_s", "mm_per_px"))
    if not np.isfinite(mm):
        mm = _positive(scales["m_per_px"]) * 1e3
    return VectorFile(
        x=x, y=y, u=np.where(chc >= 0, u, np.nan), v=np.where(chc >= 0, v, np.nan),
        valid=chc == 1, postprocessed=chc == 0, peak_ratio=opt("peak_ratio"),
        sigma_u=opt("sigma_u"), sigma_v=opt("sigma_v"), tool=tool or "rspiv", path=str(p),
        window=window if window and len(window) == 2 else None, frame=frame, dt=dt,
        mm_per_px=mm, origin_known=attrs["origin"].strip() != "unknown",
    )  # fmt: skip


def _positive(value: Any) -> float:
    """A file's scalar attribute as a positive float, NaN when absent or not one."""
    try:
        x = float(np.asarray(value, dtype=np.float64).ravel()[0])
    except (TypeError, ValueError, IndexError):
        return float("nan")
    return x if np.isfinite(x) and x > 0 else float("nan")


def _insight(p: pathlib.Path) -> VectorFile:
    c = read_insight(p)
    notes = list(c.notes)
    x, y, (u, v, chc) = _grid_from_columns(
        p, c.x, c.y, [c.u, c.v, c.chc.astype(float)], notes
    )
    computed = chc >= 1  # 0 and below: rejected or not computed (rspiv.insight)
    return VectorFile(
        x=x, y=y, u=np.where(computed, u, np.nan), v=np.where(computed, v, np.nan),
        valid=computed & (chc <= 3), postprocessed=chc >= 4, peak_ratio=None, sigma_u=None,
        sigma_v=None, tool="Insight", path=str(p), dt=c.dt, mm_per_px=c.mm_per_px,
        notes=tuple(notes), frame=c.frame,
    )  # fmt: skip


def _rspiv_tecplot(p: pathlib.Path) -> VectorFile:
    from rspiv.export import read_tecplot  # deferred: export imports the field classes

    cols, aux = read_tecplot(p)
    units = aux.get("units", "")
    if units not in ("px", "pix"):
        raise _fail(p, f"a Tecplot file in {units or 'unstated units'}: only px is read")
    for key in ("x", "y", "u", "v"):
        if key not in cols:
            raise _fail(p, f"a Tecplot file without variable {key!r}")
    x, y = cols["x"], cols["y"]
    _check_regular(p, x, y)
    chc = cols.get("chc", np.ones_like(x))
    computed = chc >= 0

    def opt(name: str) -> np.ndarray | None:
        if name not in cols:
            return None
        a = cols[name].astype(float).copy()
        a[~computed] = np.nan
        if name.startswith("sigma"):
            a[a <= 0] = np.nan  # written as 0 where not estimated
        return a

    return VectorFile(
        x=x, y=y, u=np.where(computed, cols["u"], np.nan),
        v=np.where(computed, cols["v"], np.nan), valid=chc == 1, postprocessed=chc == 0,
        peak_ratio=opt("peak_ratio"), sigma_u=opt("sigma_u"), sigma_v=opt("sigma_v"),
        tool="rspiv", path=str(p),
    )  # fmt: skip


def read_vectors(
    path: str | os.PathLike,
    *,
    frame: int = 0,
    y_up: bool = False,
    scale: float = 1.0,
    dt: float = 1.0,
) -> VectorFile:
    """Read a vector field of DaVis, OpenPIV, PIVlab, Insight or rspiv into rspiv's pixel frame.

    Parameters
    ----------
    path : str or PathLike
        ``.vc7`` (DaVis), ``.txt``/``.vec`` (OpenPIV; a ``.vec`` with Insight's header: TSI
        Insight), ``.mat`` (PIVlab), ``.nc`` or ``.dat``/``.tec``/``.plt`` (rspiv); the module
        docstring gives each one's conventions.
    frame : int
        The frame of a multi-frame DaVis buffer or the pair (cell) of a PIVlab file.
    y_up : bool
        OpenPIV only: the file's y and v point up (OpenPIV's ``transform_coordinates``).
    scale, dt : float
        OpenPIV only: the file's units per px and the time its u, v are per (s); positions are
        divided by ``scale``, displacements multiplied by ``dt / scale``.

    Returns
    -------
    VectorFile

    Raises
    ------
    InvalidInputError
        A missing file, a suffix of no tool above, or a file its reader cannot use (one line
        naming the file).
    """
    p = pathlib.Path(path)
    if p.is_dir():
        raise InvalidInputError(f"{p}: a folder, not a vector file (rspiv compare takes folders)")
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    tool = VECTOR_SUFFIXES.get(p.suffix.lower())
    if tool is None:
        raise InvalidInputError(
            f"{p}: not a vector file rspiv reads ({', '.join(sorted(VECTOR_SUFFIXES))})"
        )
    insight = p.suffix.lower() == ".vec" and is_insight(p)
    if (tool != "OpenPIV" or insight) and (y_up or scale != 1.0 or dt != 1.0):
        raise InvalidInputError(f"{p}: y_up, scale and dt are for OpenPIV text files only")
    if frame < 0:
        raise InvalidInputError(f"{p}: frame {frame} is negative")
    if tool == "DaVis":
        return _davis(p, frame)
    if insight:
        return _insight(p)
    if tool == "OpenPIV":
        return _openpiv(p, y_up, scale, dt)
    if tool == "PIVlab":
        return _pivlab(p, frame)
    if p.suffix.lower() == ".nc":
        return _rspiv_netcdf(p)
    return _rspiv_tecplot(p)


def vector_frames(path: str | os.PathLike) -> int:
    """How many fields a vector file holds: the frames of a DaVis buffer, the pairs (cells) of a
    PIVlab file, 1 for the others. InvalidInputError naming the file if it cannot be read."""
    p = pathlib.Path(path)
    tool = VECTOR_SUFFIXES.get(p.suffix.lower())
    if not p.is_file() or tool is None:
        read_vectors(p)  # the one-line refusal of a missing or foreign file
    if tool == "DaVis" and p.suffix.lower() == ".vc7":
        from rspiv.io import davis_frames  # deferred: io imports the image readers

        return davis_frames(p)  # the header's frame count: the buffer is not decoded twice
    if tool == "PIVlab":
        var = _mat_variables(p)
        for name in ("x", "u_original", "u"):
            val = var.get(name)
            if isinstance(val, np.ndarray) and val.dtype == object:
                return int(val.size)
        session = var.get("resultslist")
        if isinstance(session, np.ndarray) and session.dtype == object and session.ndim == 2:
            return int(session.shape[1])
    return 1


def from_piv_field(field: Any, name: str = "rspiv") -> VectorFile:
    """An rspiv :class:`~rspiv.PivField` on a grid as a :class:`VectorFile` (no copy of its
    arrays beyond the NaN of masked vectors)."""
    if getattr(field, "grid", None) is None:
        raise InvalidInputError(f"{name}: a field at scattered points; compare needs a grid")
    masked = np.asarray(field.masked)
    return VectorFile(
        x=np.asarray(field.x, dtype=np.float64), y=np.asarray(field.y, dtype=np.float64),
        u=np.where(masked, np.nan, field.u), v=np.where(masked, np.nan, field.v),
        valid=np.asarray(field.valid, dtype=bool),
        postprocessed=np.asarray(field.replaced, dtype=bool),
        peak_ratio=np.asarray(field.peak_ratio, dtype=np.float64),
        sigma_u=np.asarray(field.sigma_u, dtype=np.float64),
        sigma_v=np.asarray(field.sigma_v, dtype=np.float64), tool="rspiv", path=name,
        window=tuple(int(w) for w in field.window),
    )  # fmt: skip


def as_vectors(obj: Any, name: str) -> VectorFile:
    """``obj`` as a :class:`VectorFile`: itself, or an rspiv :class:`~rspiv.PivField`."""
    if isinstance(obj, VectorFile):
        return obj
    if hasattr(obj, "peak_choice") and hasattr(obj, "masked"):
        return from_piv_field(obj, name)
    raise InvalidInputError(f"{name}: a VectorFile or an rspiv PivField, not {type(obj).__name__}")


def vector_series(arg: str) -> list[Any] | None:
    """The files of a folder or a glob, sorted, or the fields of one multi-frame file (a
    PIVlab file of several pairs, a DaVis buffer of several frames) as ``(file, frame)``; None
    for a file of one field. InvalidInputError (one line) for a folder or glob of no vector
    file."""
    p = pathlib.Path(arg)
    if p.is_dir():
        files = sorted(str(f) for f in p.iterdir() if f.suffix.lower() in VECTOR_SUFFIXES)
    elif any(c in arg for c in "*?["):
        files = sorted(glob.glob(arg))
    else:
        n = vector_frames(p)
        return [(arg, k) for k in range(n)] if n > 1 else None
    if not files:
        raise InvalidInputError(f"{arg}: no vector file")
    return files
