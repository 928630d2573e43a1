"""Each pair's vector fields, written as a campaign goes (``[output] fields = true``).

Statistics answer most questions of a boundary-layer campaign, but not all: conditional
averages, spectra and two-point correlations of a time-resolved recording, POD, quadrant
analysis, or a look at the pair that went wrong need the instantaneous fields.

Files
    ``OUT/fields/<run>/pair_<id>.nc`` (``id`` the pair's position in the campaign's pair list,
    six digits) for every pair processed and every run (``method_II``, ``method_I``,
    ``uncorrected``): NetCDF-4 (h5netcdf), written atomically with the permissions of any file
    the user creates. A pair processed again (a resumed campaign, a retried Dask task) writes
    the same values again.

Variables, dims ``(y, x)``
    ``u``, ``v`` (float32): the displacement from frame A to frame B in px per pair, along x
    (right) and y (down) of the frame the run measures in: object px for the corrected runs
    (Method I's dewarped frame, Method II's mapped vectors), raw image px for ``uncorrected``;
    rejected vectors are NaN. ``valid`` (uint8: 1 valid, 0 rejected or not computed);
    ``sigma_u``, ``sigma_v`` (float32, px): each vector's standard uncertainty, when the
    campaign estimates it (``[piv] uncertainty``).

Coordinates
    ``x``, ``y`` (px): the window centres of the final pass in that frame (the grid of the
    statistics files before they are scaled and turned to the wall).

Attributes
    ``pair_id``, ``frame_a``, ``frame_b`` (the files, with ``[index]`` for a page of a stack),
    ``run``, ``method``, ``campaign``; ``dt_s`` (``[flow] dt``, when given) and ``m_per_px``
    (from the calibration, when there is one): ``u m_per_px / dt_s`` is in m/s.

Size and time: 17 bytes per vector and run, 12 MB per pair and run for a 47 MP frame with
32 x 8 px windows at 50 % overlap (730,000 vectors): a 35,000-pair campaign with Method II and
the uncorrected comparison writes about 0.9 TB. The two files of a pair take about 0.1 s (2
cores, local disk); a local run writes them by a thread while the next pair is processed
(:class:`rspiv.campaign.executors.local.LocalExecutor`), a Dask task in its chunk.

Reading them back as one dataset with a ``pair`` dimension (dask installed)::

    ds = xr.open_mfdataset("OUT/fields/method_II/pair_*.nc", combine="nested",
                           concat_dim="pair", engine="h5netcdf")

Reading them back, a second pass at the end of a run (the quadrant analysis, the POD, the
vortex population): :func:`read_field` (a whole field or a block of rows, the run and the grid
checked), :func:`each_field` (every pair's file, contiguous runs of the pairs on each core) and
:func:`finish_pass` (its warnings said in one line, its file written).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from rspiv.campaign.spec import PairContext, PairResult, PairSpec
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf

__all__ = ["FieldWriter", "each_field", "finish_pass", "grid_x", "read_field"]


@dataclasses.dataclass(frozen=True)
class FieldWriter:
    """Writes each processed pair's fields (module docs); picklable, so a Dask task can write
    its own pairs' files.

    Attributes
    ----------
    out_dir : str
        The campaign's output folder; the files go to ``out_dir/fields/<run>/``.
    campaign : str
        The campaign's name (an attribute of every file).
    dt : float or None
        ``[flow] dt`` in s, None when not given.
    m_per_px : float or None
        Metres per object px from the calibration, None without one.
    """

    out_dir: str
    campaign: str
    dt: float | None = None
    m_per_px: float | None = None

    def path(self, run: str, pair_id: int) -> pathlib.Path:
        """The file of ``run``'s field of pair ``pair_id``."""
        return pathlib.Path(self.out_dir) / "fields" / run / f"pair_{pair_id:06d}.nc"

    def write(self, context: PairContext, pair: PairSpec, result: PairResult) -> float:
        """Write every run's field of ``result`` (a pair processed, ``result.ok``); returns the
        seconds it took. OSError naming the file when one cannot be written (the local run
        stops there, a Dask chunk records the pair as failed)."""
        import xarray as xr

        t0 = time.perf_counter()
        gx, gy = context.grid()
        methods = {r.name: r.method for r in context.runs}
        dims = ("y", "x")
        for run, (u, v, valid, su, sv) in result.fields.items():
            ok = np.asarray(valid, bool)
            data: dict[str, Any] = {
                "u": (dims, np.where(ok, u, np.nan).astype(np.float32), _px("x")),
                "v": (dims, np.where(ok, v, np.nan).astype(np.float32), _px("y (down)")),
                "valid": (dims, ok.astype(np.uint8), {"long_name": "1 valid, 0 rejected"}),
            }
            for name, s, axis in (("sigma_u", su, "u"), ("sigma_v", sv, "v")):
                if s is not None:
                    data[name] = (
                        dims,
                        np.where(ok, s, np.nan).astype(np.float32),
                        {"units": "pix", "long_name": f"standard uncertainty of {axis}"},
                    )
            attrs: dict[str, Any] = {
                "pair_id": int(pair.pair_id),
                "frame_a": _frame(pair.a, pair.frame_a),
                "frame_b": _frame(pair.b, pair.frame_b),
                "run": run,
                "method": methods.get(run, ""),
                "frame": "raw image" if methods.get(run) == "none" else "object",
                "campaign": self.campaign,
            }
            if self.dt:
                attrs["dt_s"] = float(self.dt)
            if self.m_per_px:
                attrs["m_per_px"] = float(self.m_per_px)
            ds = xr.Dataset(
                data,
                coords={
                    "x": ("x", gx[0], {"units": "pix", "long_name": "window centre"}),
                    "y": ("y", gy[:, 0], {"units": "pix", "long_name": "window centre (down)"}),
                },
                attrs=attrs,
            )
            path = self.path(run, pair.pair_id)
            try:
                write_netcdf(ds, path)
            except OSError as exc:
                raise OSError(f"[output] fields: cannot write {path}: {exc}") from exc
        return time.perf_counter() - t0


def _frame(path: str, index: int | None) -> str:
    """A frame's file, with ``[index]`` for a page of a stack."""
    return path if index is None else f"{path}[{index}]"


def _px(axis: str) -> dict[str, str]:
    return {"units": "pix", "long_name": f"displacement along {axis}, frame A to frame B"}


def read_field(
    path: pathlib.Path, shape: tuple[int, int], run: str, rows: slice | None = None
) -> tuple[np.ndarray, ...]:
    """``u, v, valid`` of a field file of ``run`` (rows ``rows`` only, when given).

    Raises
    ------
    InvalidInputError
        The file cannot be read, is another run's, or its grid is not ``shape``.
    """
    import h5py  # deferred: only a second pass reads fields

    try:
        with h5py.File(path, "r") as f:
            got = f.attrs.get("run")
            got = got.decode() if isinstance(got, bytes) else got
            if got is not None and str(got) != run:
                raise InvalidInputError(f"{path}: a field of run {got!r}, not {run!r}")
            ds = [f[k] for k in ("u", "v", "valid")]
            if any(d.shape != shape for d in ds):
                s = ds[0].shape
                raise InvalidInputError(
                    f"{path}: a grid of {s[-1]} x {s[0]} vectors, the campaign's is "
                    f"{shape[1]} x {shape[0]}"
                )
            sel = slice(None) if rows is None else rows
            return tuple(np.asarray(d[sel]) for d in ds)
    except (OSError, KeyError) as exc:
        raise InvalidInputError(f"{path}: not a readable field file ({exc})") from None


def grid_x(path: pathlib.Path) -> np.ndarray:
    """The ``x`` coordinate (px) of a field file."""
    import h5py  # deferred: only a second pass reads fields

    try:
        with h5py.File(path, "r") as f:
            return np.asarray(f["x"], np.float64)
    except (OSError, KeyError) as exc:
        raise InvalidInputError(f"{path}: not a readable field file ({exc})") from None


def each_field(
    paths: dict[int, pathlib.Path],
    shape: tuple[int, int],
    run: str,
    new_part: Callable[[int], Any],
    add: Callable[..., None],
    workers: int | None = None,
) -> tuple[list[Any], list[int]]:
    """Read every field file of ``paths`` (pair id -> file) of ``run`` and hand it to
    ``add(part, i, pair_id, u, v, valid)`` (``i`` the pair's position in id order); returns the
    parts and the pair ids whose file is missing.

    ``workers`` threads (default: the cores, at most 4) each take a contiguous run of the
    pairs, in order, with a part of their own from ``new_part(w)`` (w = 0 first), so the parts
    in order hold the pairs in order (numpy and h5py release the GIL in the sums and reads).
    """
    ids = sorted(paths)
    n = len(ids)
    workers = max(1, min(workers or os.cpu_count() or 1, 4, n))

    def work(w: int) -> tuple[Any, list[int]]:
        part = new_part(w)
        missing = []
        for i in range(w * n // workers, (w + 1) * n // workers):
            path = paths[ids[i]]
            if not path.exists():
                missing.append(ids[i])
                continue
            add(part, i, ids[i], *read_field(path, shape, run))
        return part, missing

    with ThreadPoolExecutor(workers) as pool:
        done = list(pool.map(work, range(workers)))
    return [p for p, _ in done], sorted(pid for _, miss in done for pid in miss)


def finish_pass(
    camp: Any,
    res: Any,
    run: Any,
    prof: dict[str, Any],
    said: list[str],
    stem: str,
    what: str,
    dataset: Callable[[dict, Any], Any],
) -> dict[str, Any]:
    """The end of a second pass over ``run``'s fields: ``said`` joined into one line
    (``prof["warning"]``, the log's ``WARNING: <run>: <what>: ...``, the file's ``warning``
    attribute), and ``OUT/<stem>_<run>.nc`` written from ``dataset(prof, run)`` with ``[output]
    netcdf``; returns ``prof``."""
    if said:
        prof["warning"] = "; ".join(said)
        camp.say(f"WARNING: {run.label}: {what}: {prof['warning']}")
    if camp.config.output.netcdf:
        ds = dataset(prof, run)
        if said:
            ds.attrs["warning"] = prof["warning"]
        res.files[f"{stem}_{run.name}"] = write_netcdf(ds, camp.out_dir / f"{stem}_{run.name}.nc")
    return prof
