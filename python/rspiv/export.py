"""Vector fields for the tools people already use: Tecplot ASCII (DaVis, PIVlab, Tecplot 360).

The NetCDF form (pivpy-compatible xarray, :meth:`rspiv.PivField.to_xarray`) is rspiv's own; this
module writes the same field as a Tecplot ASCII point file, the format DaVis and PIVlab export:

.. code-block:: text

    TITLE = "rspiv"
    VARIABLES = "x", "y", "u", "v", "chc", "peak_ratio", "coef", "sigma_u", "sigma_v"
    DATASETAUXDATA units = "px"
    DATASETAUXDATA frame = "pixel frame: x right, y down, origin at the top-left pixel centre"
    ZONE T="frame", I=nx, J=ny, F=POINT
    x y u v chc peak_ratio coef sigma_u sigma_v      (I, i.e. x, varies fastest)

Columns: window centres ``x``, ``y`` and displacements ``u``, ``v`` in px (object px for a
corrected field; y and v positive downward, as everywhere in rspiv), ``chc`` 1 valid, 0 replaced,
-1 not computed (pivpy's and DaVis' flag), the peak ratio and correlation coefficient, and the
per-vector standard uncertainties ``sigma_u``, ``sigma_v`` in px (:class:`rspiv.PivField`).
Tecplot has no NaN: a vector not computed is written as ``u = v = 0`` with ``chc = -1`` (DaVis
writes disabled vectors the same way), and an uncertainty that is not estimated (a replaced or
masked vector, or ``uncertainty=False``) as 0, so readers must use ``chc``. Values are written
with 9 significant digits (below 1e-8 px for any displacement under 10 px). Files are written
atomically (:func:`rspiv.outputs.atomic_write_text`).
"""

from __future__ import annotations

import io
import os
import pathlib

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.field import PivField
from rspiv.outputs import atomic_write_text

__all__ = ["TECPLOT_SUFFIXES", "read_tecplot", "write_tecplot"]

#: File suffixes the CLI writes as Tecplot ASCII.
TECPLOT_SUFFIXES = (".dat", ".tec", ".plt")

_VARIABLES = ("x", "y", "u", "v", "chc", "peak_ratio", "coef", "sigma_u", "sigma_v")


def _quote(text: str) -> str:
    return str(text).replace('"', "'").replace("\n", " ")


def write_tecplot(
    field: PivField,
    path: str | os.PathLike,
    *,
    title: str = "rspiv",
    zone: str = "frame",
    aux: dict[str, str] | None = None,
) -> pathlib.Path:
    """Write ``field`` as a Tecplot ASCII point file (module docstring); returns the path.

    Parameters
    ----------
    field : PivField
        A grid field (from :func:`rspiv.piv` or a correction); a field at arbitrary points is
        written as an ordered zone of its own shape.
    path : path-like
        Destination (written atomically).
    title, zone : str
        The dataset title and the zone name (e.g. the frame pair).
    aux : dict of str, optional
        Extra ``DATASETAUXDATA`` entries (e.g. the PIV settings, the calibration).
    """
    if not isinstance(field, PivField):
        raise InvalidInputError(f"write_tecplot needs a PivField, got {type(field).__name__}")
    if field.u.ndim != 2:
        raise InvalidInputError(f"field arrays must be 2D (ny, nx), got shape {field.u.shape}")
    ny, nx = field.u.shape
    chc = np.where(field.masked, -1, np.where(field.valid, 1, 0))
    u = np.where(field.masked, 0.0, field.u)
    v = np.where(field.masked, 0.0, field.v)
    su, sv = (np.where(np.isfinite(a), a, 0.0) for a in (field.sigma_u, field.sigma_v))
    cols = [field.x, field.y, u, v, chc, field.peak_ratio, field.coef, su, sv]
    table = np.column_stack([np.asarray(c, dtype=np.float64).ravel() for c in cols])
    if not np.all(np.isfinite(table)):
        raise InvalidInputError("field holds NaN or inf outside its masked vectors")
    out = io.StringIO()
    out.write(f'TITLE = "{_quote(title)}"\n')
    out.write("VARIABLES = " + ", ".join(f'"{k}"' for k in _VARIABLES) + "\n")
    meta = {
        "units": "px",
        "frame": "pixel frame: x right, y down, origin at the top-left pixel centre",
        "chc": "1 valid, 0 replaced, -1 not computed (u = v = 0)",
        "window_w_h_px": f"{field.window[0]} {field.window[1]}",
    }
    meta.update(aux or {})
    for k, val in meta.items():
        out.write(f'DATASETAUXDATA {k} = "{_quote(val)}"\n')
    out.write(f'ZONE T="{_quote(zone)}", I={nx}, J={ny}, F=POINT\n')
    np.savetxt(out, table, fmt=["%.9g"] * 4 + ["%d"] + ["%.9g"] * 4, delimiter=" ")
    return atomic_write_text(path, out.getvalue())


def read_tecplot(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Read a Tecplot ASCII point file of one ordered zone (as :func:`write_tecplot` writes, or
    DaVis/PIVlab exports): ``({variable: array (J, I)}, {aux key: value})``. InvalidInputError
    naming the file for anything else."""
    p = pathlib.Path(path)
    try:
        lines = p.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"{p}: cannot read as text: {exc}") from None
    names: list[str] = []
    aux: dict[str, str] = {}
    shape = None
    start = None
    for k, line in enumerate(lines):
        s = line.strip()
        up = s.upper()
        if up.startswith("VARIABLES"):
            names = [t.strip().strip('"') for t in s.split("=", 1)[1].split(",")]
        elif up.startswith("DATASETAUXDATA"):
            key, _, val = s[len("DATASETAUXDATA") :].partition("=")
            aux[key.strip()] = val.strip().strip('"')
        elif up.startswith("ZONE"):
            fields = dict(
                (a.strip().upper(), b.strip())
                for a, _, b in (t.partition("=") for t in s[4:].split(","))
            )
            try:
                shape = (int(fields["J"]), int(fields["I"]))
            except (KeyError, ValueError):
                raise InvalidInputError(f"{p}: ZONE without I and J sizes: {s}") from None
            start = k + 1
            break
    if not names or shape is None or start is None:
        raise InvalidInputError(f"{p}: not a Tecplot ASCII point file (VARIABLES, ZONE)")
    try:
        data = np.loadtxt(lines[start:], ndmin=2)
    except ValueError as exc:
        raise InvalidInputError(f"{p}: bad data line: {exc}") from exc
    if data.shape != (shape[0] * shape[1], len(names)):
        raise InvalidInputError(
            f"{p}: {data.shape[0]} rows of {data.shape[1]} values, the header says "
            f"{shape[0] * shape[1]} rows of {len(names)}"
        )
    return {n: data[:, i].reshape(shape) for i, n in enumerate(names)}, aux
