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

Variables, dim ``replaced``
    ``replaced_index`` (int64: the flat row-major index in the ``(y, x)`` grid), ``replaced_u``,
    ``replaced_v`` (float32, px): the PIV's replacements of the vectors not valid (interpolated
    from their neighbours; the streamwise spectra take them in rows that are mostly valid), so
    that a campaign can re-reduce its statistics from the files (:func:`read_pair`).

Coordinates
    ``x``, ``y`` (px): the window centres of the final pass in that frame (the grid of the
    statistics files before they are scaled and turned to the wall).

Attributes
    ``pair_id``, ``frame_a``, ``frame_b`` (the files, with ``[index]`` for a page of a stack),
    ``run``, ``method``, ``campaign``, ``fields_fingerprint`` (the context's
    :meth:`~rspiv.campaign.spec.PairContext.fields_fingerprint`: a campaign re-reduces its
    statistics from files of its own, :mod:`rspiv.campaign.rereduce`); ``dt_s`` (``[flow]
    dt``, when given) and ``m_per_px`` (from the calibration, when there is one):
    ``u m_per_px / dt_s`` is in m/s.

Size and time: 17 bytes per vector and run (and 16 per replaced vector), 12 MB per pair and run
for a 47 MP frame with 32 x 8 px windows at 50 % overlap (730,000 vectors): a 35,000-pair
campaign with Method II and the uncorrected comparison writes about 0.9 TB. The two files of a
pair take about 0.1 s (2 cores, local disk); a local run writes them by a thread while the next
pair is processed (:class:`rspiv.campaign.executors.local.LocalExecutor`), a Dask task in its
chunk.

Reading them back as one dataset with a ``pair`` dimension (dask installed)::

    ds = xr.open_mfdataset("OUT/fields/method_II/pair_*.nc", combine="nested",
                           concat_dim="pair", engine="h5netcdf")

Reading them back, a second pass at the end of a run (the quadrant analysis, the POD, the
vortex population, the conditional averages, a time-resolved run's spectra):
:func:`read_field` (a whole field or a block of rows, the run and the grid checked),
:func:`each_field` (every pair's file, contiguous runs of the pairs on each core) and
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
from rspiv.hdf5_check import global_heap_damage
from rspiv.outputs import write_netcdf

__all__ = [
    "FieldWriter",
    "each_field",
    "finish_pass",
    "frame_name",
    "grid_x",
    "read_field",
    "read_pair",
]


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
        fp = context._cache.get("fields_fingerprint")
        if fp is None:  # once per process
            fp = context._cache["fields_fingerprint"] = context.fields_fingerprint()
        dims = ("y", "x")
        for run, (u, v, valid, su, sv) in result.fields.items():
            ok = np.asarray(valid, bool)
            data: dict[str, Any] = {
                "u": (dims, np.where(ok, u, np.nan).astype(np.float32), _px("x")),
                "v": (dims, np.where(ok, v, np.nan).astype(np.float32), _px("y (down)")),
                "valid": (dims, ok.astype(np.uint8), {"long_name": "1 valid, 0 rejected"}),
            }
            # the PIV's replacements of the vectors not valid (the two-point sums take them in
            # rows that are mostly valid): kept apart, so that u and v stay NaN there
            idx = np.flatnonzero(~ok & np.isfinite(u) & np.isfinite(v))
            data["replaced_index"] = ("replaced", idx.astype(np.int64), _REPLACED)
            for name, x in (("replaced_u", u), ("replaced_v", v)):
                data[name] = ("replaced", np.ravel(x)[idx].astype(np.float32), _px(name[-1]))
            for name, s, axis in (("sigma_u", su, "u"), ("sigma_v", sv, "v")):
                if s is not None:
                    data[name] = (
                        dims,
                        np.where(ok, s, np.nan).astype(np.float32),
                        {"units": "pix", "long_name": f"standard uncertainty of {axis}"},
                    )
            attrs: dict[str, Any] = {
                "pair_id": int(pair.pair_id),
                "frame_a": frame_name(pair.a, pair.frame_a),
                "frame_b": frame_name(pair.b, pair.frame_b),
                "run": run,
                "method": methods.get(run, ""),
                "frame": "raw image" if methods.get(run) == "none" else "object",
                "campaign": self.campaign,
                "fields_fingerprint": fp,
                # the final window (read back by rspiv.read_vectors)
                "window": " ".join(str(int(w)) for w in context.piv.final_window),
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


_REPLACED = {"long_name": "flat (row-major) index of a vector not valid that the PIV replaced"}


def frame_name(path: str, index: int | None) -> str:
    """A frame's file, with ``[index]`` for a page of a stack."""
    return path if index is None else f"{path}[{index}]"


def _px(axis: str) -> dict[str, str]:
    return {"units": "pix", "long_name": f"displacement along {axis}, frame A to frame B"}


def read_field(
    path: pathlib.Path,
    shape: tuple[int, int],
    run: str,
    rows: slice | None = None,
    sigmas: bool = False,
    fingerprint: str | None = None,
    screen: Any = None,
) -> tuple[np.ndarray | None, ...]:
    """``u, v, valid`` of a field file of ``run`` (rows ``rows`` only, when given), as stored
    (float32, float32, uint8; u and v NaN where not valid).

    Parameters
    ----------
    sigmas : bool
        Also return ``sigma_u, sigma_v`` (float32, NaN where not valid; None when the file has
        none).
    fingerprint : str, optional
        The file must carry this ``fields_fingerprint`` (a file written by another
        configuration, or by an rspiv before the attribute, is refused).
    screen : rspiv.outlier_screen.ScreenBounds, optional
        The run's screen (the whole grid's): its screened vectors come back not valid (u and
        v NaN), as the statistics took them.

    Raises
    ------
    InvalidInputError
        The file cannot be read, is another run's or of another fingerprint, or its grid is not
        ``shape``.
    """
    import h5py  # deferred: only a second pass reads fields

    damage = global_heap_damage(path)  # HDF5 would loop on it (rspiv.hdf5_check)
    if damage:
        raise InvalidInputError(f"{path}: not a readable field file ({damage})")
    try:
        with h5py.File(path, "r") as f:
            got = _text(f.attrs.get("run"))
            if got is not None and got != run:
                raise InvalidInputError(f"{path}: a field of run {got!r}, not {run!r}")
            if fingerprint is not None and _text(f.attrs.get("fields_fingerprint")) != fingerprint:
                raise InvalidInputError(
                    f"{path}: a field of another configuration (fields_fingerprint "
                    f"{_text(f.attrs.get('fields_fingerprint'))}, the campaign's is {fingerprint})"
                )
            ds = [f[k] for k in ("u", "v", "valid")]
            if any(d.shape != shape for d in ds):
                s = ds[0].shape
                raise InvalidInputError(
                    f"{path}: a grid of {s[-1]} x {s[0]} vectors, the campaign's is "
                    f"{shape[1]} x {shape[0]}"
                )
            sel = slice(None) if rows is None else rows
            out = [np.asarray(d[sel]) for d in ds]
            if screen is not None:
                b = screen if rows is None else screen.rows(rows)
                gone = b.outliers(out[0], out[1], out[2].astype(bool))
                if gone.any():
                    for k in range(2):
                        out[k] = np.where(gone, np.nan, out[k]).astype(out[k].dtype)
                    out[2] = np.where(gone, 0, out[2]).astype(out[2].dtype)
            if sigmas:
                has = "sigma_u" in f and "sigma_v" in f
                out += [np.asarray(f[k][sel]) if has else None for k in ("sigma_u", "sigma_v")]
            return tuple(out)
    except (OSError, KeyError) as exc:
        raise InvalidInputError(f"{path}: not a readable field file ({exc})") from None


def read_pair(
    path: pathlib.Path, shape: tuple[int, int], run: str, fingerprint: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A field file of ``run`` as the pair loop gave it to the statistics (``(u, v, valid,
    sigma_u, sigma_v)``, :attr:`rspiv.campaign.spec.PairResult.fields`): float64, the PIV's
    replacements back in ``u`` and ``v``; equal to the loop's to the float32 rounding of the
    file (about 6e-8 of each value).

    Raises
    ------
    InvalidInputError
        :func:`read_field`'s, and a file without its replacements (written by an rspiv before
        them).
    """
    import h5py  # deferred: only a re-reduction reads them

    u, v, valid, su, sv = read_field(path, shape, run, sigmas=True, fingerprint=fingerprint)
    u, v = u.astype(np.float64), v.astype(np.float64)
    try:
        with h5py.File(path, "r") as f:
            idx = np.asarray(f["replaced_index"], np.int64)
            u.flat[idx] = np.asarray(f["replaced_u"], np.float64)
            v.flat[idx] = np.asarray(f["replaced_v"], np.float64)
    except (OSError, KeyError, IndexError) as exc:
        raise InvalidInputError(f"{path}: no readable replaced vectors ({exc})") from None
    if su is not None:
        su, sv = su.astype(np.float64), sv.astype(np.float64)
    return u, v, valid.astype(bool), su, sv


def _text(value: Any) -> str | None:
    """An HDF5 attribute as text (None when absent)."""
    if value is None:
        return None
    return value.decode() if isinstance(value, bytes) else str(value)


def grid_x(path: pathlib.Path) -> np.ndarray:
    """The ``x`` coordinate (px) of a field file."""
    import h5py  # deferred: only a second pass reads fields

    damage = global_heap_damage(path)  # HDF5 would loop on it (rspiv.hdf5_check)
    if damage:
        raise InvalidInputError(f"{path}: not a readable field file ({damage})")
    try:
        with h5py.File(path, "r") as f:
            return np.asarray(f["x"], np.float64)
    except (OSError, KeyError) as exc:
        raise InvalidInputError(f"{path}: not a readable field file ({exc})") from None


def run_field_files(
    camp: Any, run: str, pair_ids
) -> tuple[list[int], dict[int, pathlib.Path], np.ndarray]:
    """The field files of ``run``'s pairs ``pair_ids``: the ids in order, pair id -> file, and
    the grid's ``x`` (px) from the first file there.

    Raises
    ------
    InvalidInputError
        None of the pairs has a field file (named: the folder).
    """
    writer = camp.field_writer()
    ids = sorted(pair_ids)
    paths = {pid: writer.path(run, pid) for pid in ids}
    first = next((paths[i] for i in ids if paths[i].exists()), None)
    if first is None:
        where = paths[ids[0]].parent if ids else writer.path(run, 0).parent
        raise InvalidInputError(f"none of the {len(paths)} pairs has a field file in {where}")
    return ids, paths, grid_x(first)


def each_field(
    paths: dict[int, pathlib.Path],
    shape: tuple[int, int],
    run: str,
    new_part: Callable[[int], Any],
    add: Callable[..., None],
    workers: int | None = None,
    screen: Any = None,
) -> tuple[list[Any], list[int]]:
    """Read every field file of ``paths`` (pair id -> file) of ``run`` and hand it to
    ``add(part, i, pair_id, u, v, valid)`` (``i`` the pair's position in id order); returns the
    parts and the pair ids whose file is missing. ``screen``: the run's
    :class:`~rspiv.outlier_screen.ScreenBounds` (:func:`read_field`).

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
            add(part, i, ids[i], *read_field(path, shape, run, screen=screen))
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


def pass_section(
    camp: Any,
    prof: dict[str, Any],
    title: str,
    text: str,
    plot: str,
    name: str,
    caption: str,
) -> Any:
    """The report's section of a second pass over ``prof``: ``text``, the pass's warning after
    it, and the figure ``plot`` (``"module:function"``, imported only to draw: matplotlib)
    draws into ``OUT/report/figures/<name>.png`` with ``caption``. A figure that fails is said
    in the log and left out: a figure must not stop a campaign."""
    import importlib

    from rspiv.report import ReportSection  # deferred: only a report needs it

    figures = []
    try:
        module, function = plot.split(":")
        draw = getattr(importlib.import_module(module), function)
        figures.append((draw(camp.out_dir / "report" / "figures" / f"{name}.png", prof), caption))
    except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
        camp.say(f"{name} figure failed: {exc}")
    if "warning" in prof:
        text += f"\n\nWarning: {prof['warning']}."
    return ReportSection(title, text=text, figures=figures)
