"""Writers for campaign outputs: NetCDF (xarray + h5netcdf), profile CSV, atomic file writes.

Every writer is atomic: it writes a temporary file in the destination folder and renames it
over the destination with :func:`os.replace`, so a crash never leaves a half-written output and
readers never see one.

NetCDF variables follow pivpy's names (coordinates ``x``, ``y``; velocities ``u``, ``v``; the
``units`` attribute on each variable and pivpy's dataset attributes ``variables``/``units``/
``dt``) plus CF-1.8 attributes (``long_name``, ``units``, ``axis``).
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import pathlib
import tempfile
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError


def creation_mode(path: pathlib.Path) -> int:
    """The permission bits a file written at ``path`` gets: those of the file it replaces, else
    those of any new file the user creates (``0o666`` less the process umask)."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        pass
    try:  # Linux: the umask without changing it
        for line in pathlib.Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, make_parents: bool = True) -> Iterator[pathlib.Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The temporary file keeps the destination's suffix (some writers infer the format from it)
    and is removed if the block raises. The result has the permissions of any file the user
    creates (:func:`creation_mode`; ``mkstemp``'s private 0600 is not kept), or those of the file
    it replaces. ``make_parents=False``: a missing folder is an error (FileNotFoundError).
    """
    path = pathlib.Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    mode = creation_mode(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(fd)
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, mode)
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)


def atomic_write_bytes(
    path: str | os.PathLike, data: bytes, *, make_parents: bool = True
) -> pathlib.Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path, make_parents=make_parents) as tmp:
        tmp.write_bytes(data)
    return pathlib.Path(path)


def atomic_write_text(
    path: str | os.PathLike, text: str, *, make_parents: bool = True
) -> pathlib.Path:
    """Write UTF-8 ``text`` to ``path`` atomically (:func:`atomic_path`)."""
    return atomic_write_bytes(path, text.encode("utf-8"), make_parents=make_parents)


def write_netcdf(ds, path: str | os.PathLike) -> pathlib.Path:
    """Write an :class:`xarray.Dataset` to NetCDF-4 (engine h5netcdf), atomically."""
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return pathlib.Path(path)


def statistics_dataset(acc, x=None, y=None, *, velocity_units: str = "m s-1", dt=None, attrs=None):
    """Per-vector statistics of a :class:`~rspiv.stats.FieldAccumulator` as a pivpy-style,
    CF-annotated Dataset.

    Parameters
    ----------
    acc : FieldAccumulator
        Two-dimensional accumulator (``(ny, nx)``).
    x, y : array_like, optional
        Streamwise and wall-normal coordinates of the grid (m, y from the wall).
    velocity_units : str
        Units of the accumulated velocities ("m s-1", or "pix" for px per pair).
    dt : float, optional
        Pulse separation (s), recorded as pivpy's ``dt`` attribute.
    """
    if len(acc.shape) != 2:
        raise InvalidInputError(f"acc: expected a 2D accumulator, got shape {acc.shape}")
    ds = acc.to_xarray(x=x, y=y, velocity_units=velocity_units, attrs=attrs)
    length = "m" if velocity_units in ("m s-1", "m/s") else "pix"
    if "x" in ds.coords:
        ds["x"].attrs.update({"long_name": "streamwise position", "units": length, "axis": "X"})
    if "y" in ds.coords:
        ds["y"].attrs.update(
            {"long_name": "wall-normal distance from the wall", "units": length, "axis": "Y"}
        )
    ds.attrs.update(
        {
            "variables": ["x", "y", "u", "v"],
            "units": [length, length, velocity_units, velocity_units],
            "dt": float(dt) if dt is not None else 1.0,
        }
    )
    return ds


def profile_dataset(result, *, attrs: Mapping[str, Any] | None = None):
    """A :class:`~rspiv.boundary_layer.BoundaryLayerResult` as a Dataset along ``y``.

    The profiles (wall units, with uncertainties) become variables, the scalar results
    (u_tau, delta_99, ...) dataset attributes.
    """
    import xarray as xr

    cols = result.profile_columns()
    units = {
        "y_m": "m",
        "y_plus": "1",
        "n_eff": "1",
    }
    long = {
        "y_plus": "wall-normal distance in wall units",
        "U_plus": "mean streamwise velocity in wall units",
        "uu_plus": "streamwise Reynolds normal stress in wall units",
        "vv_plus": "wall-normal Reynolds normal stress in wall units",
        "uv_plus": "Reynolds shear stress in wall units",
        "n_eff": "effective number of independent samples",
        "S_u": "skewness of u",
        "F_u": "flatness (kurtosis) of u",
        "S_v": "skewness of v",
        "F_v": "flatness (kurtosis) of v",
    }
    ds = xr.Dataset(coords={"y": ("y", cols["y_m"], {"units": "m", "axis": "Y"})})
    ds["y"].attrs["long_name"] = "wall-normal distance from the fitted wall"
    for k, v in cols.items():
        if k == "y_m":
            continue
        name = long.get(k, f"standard uncertainty of {k[4:]}" if k.startswith("eps_") else k)
        ds[k] = (
            "y",
            np.asarray(v, dtype=np.float64),
            {"units": units.get(k, "1"), "long_name": name},
        )
    ds.attrs.update({"Conventions": "CF-1.8", "title": "rspiv boundary-layer profile"})
    ds.attrs.update({k: float(v) for k, v in result.summary().items()})
    if attrs:
        ds.attrs.update(attrs)
    return ds


def write_profile_csv(
    path: str | os.PathLike,
    columns: Mapping[str, Any],
    metadata: Mapping[str, Any] | None = None,
) -> pathlib.Path:
    """Write profile columns to CSV, atomically.

    Parameters
    ----------
    path : path-like
        Destination file.
    columns : mapping or BoundaryLayerResult
        Column name -> 1D array (all the same length); a BoundaryLayerResult writes its
        :meth:`profile_columns` and its :meth:`summary` as metadata.
    metadata : mapping, optional
        Scalars written first as ``# key = value`` comment lines.

    Notes
    -----
    Values are written with ``repr`` precision (round-trip exact); NaN is written as ``nan``.
    """
    if hasattr(columns, "profile_columns"):
        meta = dict(columns.summary())
        meta.update(metadata or {})
        metadata, columns = meta, columns.profile_columns()
    names = list(columns)
    arrays = [np.asarray(columns[k], dtype=np.float64).ravel() for k in names]
    if not arrays:
        raise InvalidInputError("columns: nothing to write")
    n = arrays[0].size
    for k, a in zip(names, arrays, strict=True):
        if a.size != n:
            raise InvalidInputError(f"columns: {k!r} has {a.size} values, expected {n}")
    buf = io.StringIO()
    for k, v in (metadata or {}).items():
        buf.write(f"# {k} = {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in zip(*arrays, strict=True):
        w.writerow([repr(float(x)) for x in row])
    return atomic_write_text(path, buf.getvalue())


def read_profile_csv(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Read a file written by :func:`write_profile_csv`: (columns, metadata strings)."""
    meta: dict[str, str] = {}
    lines = pathlib.Path(path).read_text(encoding="utf-8").splitlines()
    body = []
    for line in lines:
        if line.startswith("#"):
            k, _, v = line[1:].partition("=")
            meta[k.strip()] = v.strip()
        elif line.strip():
            body.append(line)
    rows = list(csv.reader(body))
    if not rows:
        raise InvalidInputError(f"{path}: no header row")
    names = rows[0]
    data = np.array([[float(x) for x in r] for r in rows[1:]], dtype=np.float64).reshape(
        -1, len(names)
    )
    return {k: data[:, i] for i, k in enumerate(names)}, meta


__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "profile_dataset",
    "read_profile_csv",
    "statistics_dataset",
    "write_netcdf",
    "write_profile_csv",
]
