"""Merging partial statistics: ``rspiv merge PARTS... -o stats.nc``.

A sharded campaign (``rspiv process campaign.toml --shard i/N``, e.g. one SLURM array task per
shard) writes, per run, ``OUT/shards/statistics_<run>.shard-<i>-of-<N>.nc``: the exact state of
a :class:`~rspiv.stats.FieldAccumulator` (px per pair, pixel axes) with the ids of the pairs it
holds. :func:`merge_files` combines such parts (or earlier merges) with Chan's parallel
formulas into one file of the same format, so merges can be nested.

Guarantees
    * **No pair is counted twice**: parts that share a pair id, the same shard label (``2/8``)
      given twice, or the same file given twice are refused
      (:class:`~rspiv.errors.InvalidInputError` naming the files).
    * **Order does not matter**: the parts are merged in a canonical order (by their smallest
      pair id, then shard label), so any order on the command line gives the same bits.
    * **Consistency**: parts of different runs, campaigns (context fingerprint) or grids are
      refused.

The lag-1 chains behind ``n_eff`` are not joined across parts (each part's chains end at its
boundary; see :mod:`rspiv.stats`): the first and second moments equal those of one pass over
all pairs to rounding, the lag-1 moments miss one sample pair per vector and part boundary.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import pickle
import re
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from rspiv.campaign import Campaign
from rspiv.errors import InvalidInputError
from rspiv.hdf5_check import global_heap_damage
from rspiv.outputs import write_netcdf
from rspiv.stats import FieldAccumulator

__all__ = [
    "Part",
    "read_part",
    "merge_parts",
    "merge_files",
    "merge_campaign",
    "missing_shards",
]


@dataclasses.dataclass
class Part:
    """One partial statistics file.

    Attributes
    ----------
    path : pathlib.Path
    accumulator : FieldAccumulator
    attrs : dict
        The file's global attributes (``run``, ``shard``, ``campaign``, ``fingerprint`` ...).
    x, y : ndarray or None
        Grid coordinates (px) when the file has them.
    """

    path: pathlib.Path
    accumulator: FieldAccumulator
    attrs: dict[str, Any]
    x: np.ndarray | None
    y: np.ndarray | None

    @property
    def run(self) -> str:
        return str(self.attrs.get("run", ""))

    @property
    def shards(self) -> list[str]:
        """Shard labels (``"i/n"``) this part holds (several for a merged file)."""
        if "shards" in self.attrs:
            return [s for s in str(self.attrs["shards"]).split(",") if s]
        s = self.attrs.get("shard")
        return [str(s)] if s not in (None, "", "merged") else []

    def sort_key(self) -> tuple:
        ids = self.accumulator.pair_ids
        lo = min(ids, key=lambda t: (type(t).__name__, t)) if ids else None
        return (lo is None, (type(lo).__name__, lo) if lo is not None else ("", 0), self.shards)


def read_part(path: str | os.PathLike) -> Part:
    """Read a partial statistics file written by a shard or by :func:`merge_files`."""
    import xarray as xr

    p = pathlib.Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    damage = global_heap_damage(p)  # HDF5 could loop on it (rspiv.hdf5_check)
    if damage:
        raise InvalidInputError(f"{p}: cannot read as NetCDF ({damage})")
    try:
        with xr.open_dataset(p, engine="h5netcdf") as ds:
            ds = ds.load()
    except Exception as exc:  # noqa: BLE001 - any decoder failure is a bad file
        raise InvalidInputError(f"{p}: cannot read as NetCDF ({exc})") from None
    try:
        acc = FieldAccumulator.from_xarray(ds)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{p}: {exc}") from None
    x = np.asarray(ds["x"].values, np.float64) if "x" in ds.coords else None
    y = np.asarray(ds["y"].values, np.float64) if "y" in ds.coords else None
    return Part(p, acc, dict(ds.attrs), x, y)


def _check_compatible(parts: Sequence[Part]) -> None:
    ref = parts[0]
    for q in parts[1:]:
        for key, what in (("run", "run"), ("fingerprint", "campaign context")):
            a, b = ref.attrs.get(key), q.attrs.get(key)
            if a is not None and b is not None and str(a) != str(b):
                raise InvalidInputError(
                    f"{q.path}: {what} {b!r} differs from {ref.path}'s {a!r}; "
                    "only parts of the same run of the same campaign can be merged"
                )
        if q.accumulator.shape != ref.accumulator.shape:
            raise InvalidInputError(
                f"{q.path}: grid {q.accumulator.shape} differs from {ref.path}'s "
                f"{ref.accumulator.shape}"
            )
        for name, a, b in (("x", ref.x, q.x), ("y", ref.y, q.y)):
            if a is not None and b is not None and not np.array_equal(a, b):
                raise InvalidInputError(f"{q.path}: {name} coordinates differ from {ref.path}'s")
        if ref.attrs.get("velocity_units") != q.attrs.get("velocity_units"):
            raise InvalidInputError(
                f"{q.path}: velocity units {q.attrs.get('velocity_units')!r} differ from "
                f"{ref.path}'s {ref.attrs.get('velocity_units')!r}"
            )


def _check_disjoint(parts: Sequence[Part]) -> None:
    seen_path: dict[pathlib.Path, pathlib.Path] = {}
    seen_shard: dict[str, pathlib.Path] = {}
    seen_ids: dict[Any, pathlib.Path] = {}
    for q in parts:
        rp = q.path.resolve()
        if rp in seen_path:
            raise InvalidInputError(f"{q.path}: given twice (a part may be merged only once)")
        seen_path[rp] = q.path
        for s in q.shards:
            if s in seen_shard:
                raise InvalidInputError(
                    f"{q.path}: shard {s} is already in {seen_shard[s]} "
                    "(the same shard would be counted twice)"
                )
            seen_shard[s] = q.path
        common = [i for i in q.accumulator.pair_ids if i in seen_ids]
        if common:
            first = sorted(common, key=lambda t: (type(t).__name__, t))[:5]
            raise InvalidInputError(
                f"{q.path}: {len(common)} pair(s) already in {seen_ids[common[0]]} "
                f"(e.g. {', '.join(map(str, first))}); a pair must not be counted twice"
            )
        for i in q.accumulator.pair_ids:
            seen_ids[i] = q.path


def missing_shards(parts: Iterable[Part]) -> list[str]:
    """Shard labels ``i/n`` absent from ``parts`` (for every ``n`` seen)."""
    have: dict[int, set[int]] = {}
    for q in parts:
        for s in q.shards:
            try:
                i, n = (int(t) for t in s.split("/"))
            except ValueError:
                continue
            have.setdefault(n, set()).add(i)
    return [f"{i}/{n}" for n, got in sorted(have.items()) for i in range(1, n + 1) if i not in got]


def merge_parts(parts: Sequence[Part]) -> tuple[FieldAccumulator, dict[str, Any]]:
    """Merge ``parts`` (one run) into a new accumulator; returns it and the merged attributes.

    Raises
    ------
    InvalidInputError
        Nothing to merge, incompatible parts, or a pair / shard / file counted twice.
    """
    parts = list(parts)
    if not parts:
        raise InvalidInputError("merge: no part given")
    _check_compatible(parts)
    _check_disjoint(parts)
    ordered = sorted(parts, key=Part.sort_key)
    acc = FieldAccumulator.merged(q.accumulator for q in ordered)
    shards = [s for q in ordered for s in q.shards]
    ref = ordered[0]
    attrs = {
        k: ref.attrs[k]
        for k in ("run", "campaign", "fingerprint", "frame", "velocity_units")
        if k in ref.attrs
    }
    attrs.update(
        {
            "shard": "merged",
            "shards": ",".join(shards),
            "merged_parts": len(parts),
            "merged_from": ", ".join(q.path.name for q in ordered),
        }
    )
    return acc, attrs


def merge_files(
    paths: Sequence[str | os.PathLike], output: str | os.PathLike
) -> dict[str, pathlib.Path]:
    """Merge partial statistics files and write the result(s) atomically.

    Parameters
    ----------
    paths : sequence of path
        Shard files or earlier merges.
    output : path
        The merged file when all parts are of one run; a folder (created) receiving
        ``statistics_<run>.nc`` per run when they are of several runs.

    Returns
    -------
    dict
        Run name -> written path.
    """

    parts = [read_part(p) for p in paths]
    if not parts:
        raise InvalidInputError("merge: no part given")
    by_run: dict[str, list[Part]] = {}
    for q in parts:
        by_run.setdefault(q.run, []).append(q)
    out = pathlib.Path(output)
    if len(by_run) > 1 and out.suffix == ".nc":
        raise InvalidInputError(
            f"{out}: the parts are of {len(by_run)} runs ({', '.join(sorted(by_run))}); give a "
            "folder for -o (one statistics_<run>.nc per run)"
        )
    written: dict[str, pathlib.Path] = {}
    for run, group in sorted(by_run.items()):
        acc, attrs = merge_parts(group)
        ref = group[0]
        ds = acc.to_xarray(
            x=ref.x,
            y=ref.y,
            velocity_units=str(ref.attrs.get("velocity_units", "pix")),
            attrs=attrs,
        )
        path = out if len(by_run) == 1 else out / f"statistics_{run or 'merged'}.nc"
        written[run] = write_netcdf(ds, path)
    return written


def merge_campaign(campaign, *, progress: bool = False):
    """Merge a sharded campaign's shard files and analyse them like an unsharded run.

    For every run of ``campaign`` (a :class:`rspiv.Campaign` or a campaign file), the files
    ``OUT/shards/statistics_<run>.shard-<i>-of-<n>.nc`` of one complete set ``i = 1..n`` are
    merged (:func:`merge_parts`), written as the campaign's checkpoint (``OUT/checkpoint/``)
    and :meth:`Campaign.run` then finds every merged pair finished and goes straight to the
    analysis (wall, profiles, NetCDF/CSV outputs, report). Pairs the shards skipped are retried
    there.

    Raises
    ------
    InvalidInputError
        No shard files, an incomplete or mixed set of shards, parts of another configuration,
        or an existing unsharded checkpoint holding other pairs.
    """

    camp = (
        campaign if isinstance(campaign, Campaign) else Campaign.load(campaign, progress=progress)
    )
    if camp.shard != (1, 1):
        raise InvalidInputError("merge: give the campaign without --shard")
    out = camp.out_dir
    ctx = camp.prepare()
    accs: dict[str, FieldAccumulator] = {}
    ids = None
    pat = re.compile(r"\.shard-(\d+)-of-(\d+)\.nc$")
    for run in ctx.runs:
        files = sorted((out / "shards").glob(f"statistics_{run.name}.shard-*-of-*.nc"))
        if not files:
            raise InvalidInputError(f"{out / 'shards'}: no shard file of run {run.name}")
        ns = {int(m.group(2)) for f in files if (m := pat.search(f.name))}
        if len(ns) != 1:
            raise InvalidInputError(
                f"{out / 'shards'}: shard files of several splittings ({sorted(ns)} shards) for "
                f"run {run.name}; merge the parts explicitly with `rspiv merge PARTS -o FILE`"
            )
        parts = [read_part(f) for f in files]
        missing = missing_shards(parts)
        if missing:
            raise InvalidInputError(
                f"run {run.name}: shard(s) {', '.join(missing)} missing in {out / 'shards'}"
            )
        for q in parts:
            fp = q.attrs.get("fingerprint")
            if fp is not None and str(fp) != ctx.fingerprint():
                raise InvalidInputError(
                    f"{q.path}: written for another configuration (fingerprint {fp}, the "
                    f"campaign's is {ctx.fingerprint()})"
                )
        acc, _ = merge_parts(parts)
        if ids is not None and acc.pair_ids != ids:
            raise InvalidInputError(
                f"run {run.name}: the shards hold other pairs than the main run"
            )
        ids = acc.pair_ids
        accs[run.name] = acc
    ckpt = camp.checkpoint_path()
    if ckpt.is_file():
        try:
            old = set(pickle.loads(ckpt.read_bytes()).get("finished", []))
        except Exception:  # noqa: BLE001 - unreadable: refuse below
            old = None
        if old != set(ids):
            raise InvalidInputError(
                f"{ckpt}: an unsharded checkpoint with other pairs exists; delete it to analyse "
                "the merged shards"
            )
    camp.save_checkpoint(ctx, accs, set(ids), {})
    return camp.run()
