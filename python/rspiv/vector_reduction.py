"""A series of another tool's vector fields, read one field at a time (for
:mod:`rspiv.vector_statistics`).

- :func:`series_entries`: the fields to read, in order (files, folders, globs, multi-field
  files expanded), each a path or a ``(path, frame)`` tuple; :func:`read_entry` reads one
  (:func:`rspiv.vector_files.read_vectors`), :func:`entry_name` names it in messages.
- :class:`SeriesReducer`: whether a field joins the series the first field fixed (its grid,
  pulse separation and scale), and its valid vectors added to a
  :class:`rspiv.stats.FieldAccumulator` and to what the accumulator carries.
- :func:`pilot_fields`: up to 20 fields spread evenly over the series, as the statistics will
  see them (the screen's bounds and the two-point columns are fixed from them).
- The checkpoint (``OUT/checkpoint.pkl``): :func:`save_checkpoint`, :func:`load_checkpoint`;
  a run is resumed only with the same settings (:func:`fingerprint`) and the same first fields.

Units and frames are those of :class:`rspiv.vector_files.VectorFile`: px of the fields' frame,
x right, y down, displacements px per pair.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import pickle
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from rspiv.campaign import screen as screen_work
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outputs import atomic_write_bytes
from rspiv.stats import FieldAccumulator
from rspiv.vector_files import VectorFile, read_vectors, vector_frames, vector_series

__all__ = [
    "SeriesReducer",
    "entry_name",
    "fingerprint",
    "load_checkpoint",
    "pilot_fields",
    "read_entry",
    "save_checkpoint",
    "series_entries",
]

#: The checkpoint's format tag and version (``OUT/checkpoint.pkl``).
_CHECKPOINT = ("rspiv-vector-statistics", 1)


def series_entries(files: Any) -> list[Any]:
    """The fields to read, in order: paths, (path, frame) tuples; a folder, a glob or a file of
    several fields expanded (:func:`rspiv.vector_files.vector_series`, each file of a folder
    or glob by its own fields). A DaVis set's ``.set`` file stands for the folder of its name
    beside it, where DaVis keeps the set's buffers. A file that cannot be opened stays one
    entry, named when the reduction skips it."""
    if isinstance(files, (str, os.PathLike)):
        files = [files]
    out: list[Any] = []
    for item in files:
        if isinstance(item, tuple):
            out.append((str(item[0]), int(item[1])))
            continue
        item = _davis_set(item)
        try:
            series = vector_series(str(item))
        except InvalidInputError:
            if any(c in str(item) for c in "*?[") or pathlib.Path(item).is_dir():
                raise
            series = None
        for f in [str(item)] if series is None else series:
            out.extend(_frames(f) if isinstance(f, str) and series is not None else [f])
    if not out:
        raise InvalidInputError("statistics: no vector file given")
    return out


def _davis_set(item: Any) -> Any:
    """The folder a DaVis ``X.set`` stands for (``X/`` beside it), else ``item``.

    Raises
    ------
    InvalidInputError
        A ``.set`` file without its folder (copied alone from the project).
    """
    p = pathlib.Path(item)
    if p.suffix.lower() != ".set":
        return item
    folder = p.with_suffix("")
    if not folder.is_dir():
        raise InvalidInputError(
            f"{item}: a DaVis set whose folder {folder.name}/ (its buffers) is not beside it"
        )
    return str(folder)


def _frames(path: str) -> list[Any]:
    """One file of a folder or glob: itself, or its fields when it holds several."""
    try:
        n = vector_frames(path)
    except InvalidInputError:
        return [path]
    return [(path, k) for k in range(n)] if n > 1 else [path]


def entry_name(entry: Any) -> str:
    return f"{entry[0]}[{entry[1]}]" if isinstance(entry, tuple) else str(entry)


def read_entry(entry: Any, options: dict[str, Any]) -> VectorFile:
    if isinstance(entry, tuple):
        return read_vectors(entry[0], **{**options, "frame": entry[1]})
    return read_vectors(entry, **options)


class SeriesReducer:
    """The fields of one series summed into an accumulator, with the checks of step 1."""

    def __init__(self, first: VectorFile, mm_per_px: float, dt: float) -> None:
        self.first = first
        self.mm_per_px = mm_per_px
        self.dt = dt

    def check(self, vf: VectorFile) -> str:
        """Why ``vf`` cannot join the first field's series ("" when it can)."""
        f = self.first
        if vf.u.shape != f.u.shape or not (np.allclose(vf.x, f.x) and np.allclose(vf.y, f.y)):
            return f"on another grid ({vf.u.shape[1]} x {vf.u.shape[0]}) than the first field"
        if not vf.valid.any():
            post = int(np.count_nonzero(vf.postprocessed))
            return f"no vector its tool's validation accepted ({post} filled or smoothed)"
        for what, a, b in (("pulse separation", vf.dt, f.dt), ("scale", vf.mm_per_px,
                                                                f.mm_per_px)):  # fmt: skip
            if np.isfinite(a) and np.isfinite(b) and abs(a - b) > 1e-6 * abs(b):
                return f"its {what} {a:.6g} is not the first field's {b:.6g}"
        return ""

    @staticmethod
    def vectors(
        vf: VectorFile, bounds: Any = None, tally: Any = None, pair_id: int | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, v, valid)`` of a field as the statistics take it: valid the tool's accepted,
        finite vectors, less those the screen ``bounds`` leaves out (counted in ``tally``; u
        and v there the screen's centres, :func:`rspiv.campaign.screen.apply`)."""
        valid = vf.valid & np.isfinite(vf.u) & np.isfinite(vf.v)
        if bounds is None:
            return vf.u, vf.v, valid
        return screen_work.apply(bounds, vf.u, vf.v, valid, tally, pair_id)

    def again(
        self,
        reads: Any,
        pair_id: int,
        transform: Callable[[VectorFile], VectorFile],
        bounds: Any,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, v, valid)`` of entry ``pair_id`` read again after the first pass (the second
        pass, the POD) by ``reads`` (a :class:`rspiv.vector_readahead.ReadAhead`), checked,
        corrected by ``transform`` and screened by ``bounds`` as the statistics took it
        (:meth:`vectors`, nothing counted).

        Raises
        ------
        RspivError
            The file no longer reads, or the field no longer joins the series (:meth:`check`).
        """
        vf = reads.get(pair_id)
        why = self.check(vf)
        if why:
            raise InvalidInputError(why)
        return self.vectors(transform(vf), bounds, None, pair_id)

    @classmethod
    def add(cls, acc: FieldAccumulator, vf: VectorFile, pair_id: int, bounds: Any = None) -> None:
        """Add a field's valid vectors, those the screen ``bounds`` leaves out excepted (counted
        in ``acc.screen``), to ``acc`` and to the peak-locking histogram, vorticity and
        two-point sums it carries."""
        u, v, valid = cls.vectors(vf, bounds, acc.screen, pair_id)
        ok = vf.valid & np.isfinite(vf.u) & np.isfinite(vf.v)  # the tool's, before the screen
        su, sv = vf.sigma_u, vf.sigma_v
        if su is None or sv is None or not np.isfinite(su[ok]).any():
            su = sv = None
        acc.add(u, v, valid, pair_id=pair_id, sigma_u=su, sigma_v=sv)
        for extra in (acc.locking, acc.vorticity, acc.two_point, acc.rows):  # not the pilot's
            if extra is not None:
                extra.add(u, v, valid, pair_id=pair_id)


def pilot_fields(
    reads: Any,
    reducer: SeriesReducer,
    transform: Callable[[VectorFile], VectorFile],
    pilot: int,
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], list[int]]:
    """``(u, v, valid)`` of up to ``pilot`` (at most 20, at least 3) fields spread evenly over
    the series, as the statistics will see them (``transform`` applied; ``valid`` the tool's
    accepted and finite vectors), and their indices; fields that cannot join are passed over.
    ``reads`` (a :class:`rspiv.vector_readahead.ReadAhead`) reads the series' entries."""
    n = len(reads.entries)
    picks = sorted({int(round(t)) for t in np.linspace(0, n - 1, min(n, max(min(pilot, 20), 3)))})
    got, used = [], []
    reads.along(picks)
    for k in picks:
        try:
            vf = reads.get(k)
            if not reducer.check(vf):
                vf = transform(vf)
                got.append((vf.u, vf.v, vf.valid & np.isfinite(vf.u) & np.isfinite(vf.v)))
                used.append(k)
        except RspivError:
            continue
    return got, used


def fingerprint(settings: dict[str, Any]) -> str:
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _keys(entries: Iterable[Any]) -> list[str]:
    """The fields' identities: their files' names (not folders) and frames."""
    return [
        f"{pathlib.Path(e[0]).name}[{e[1]}]" if isinstance(e, tuple) else pathlib.Path(e).name
        for e in entries
    ]


def save_checkpoint(path: pathlib.Path, key: str, entries: list[Any], state: dict) -> None:
    done = state["done"]
    blob = {"format": _CHECKPOINT, "key": key, "fields": _keys(entries[:done]), **state}
    atomic_write_bytes(path, pickle.dumps(blob, protocol=pickle.HIGHEST_PROTOCOL))


def load_checkpoint(path: pathlib.Path | None, key: str, entries: list[Any]) -> dict | None:
    """The state of an earlier run of the same settings whose fields are this run's first ones;
    None when there is none. A checkpoint of other settings or other fields is refused."""
    if path is None or not path.is_file():
        return None
    try:
        blob = pickle.loads(path.read_bytes())
        if blob.get("format") != _CHECKPOINT:
            raise ValueError("not a checkpoint of rspiv statistics")
    except Exception as exc:  # noqa: BLE001 - any damage is one line
        raise InvalidInputError(
            f"{path}: cannot resume ({exc}); remove it to start again"
        ) from None
    if blob["key"] != key:
        raise InvalidInputError(
            f"{path}: written for other options; remove it to start again with these"
        )
    done = int(blob["done"])
    if done > len(entries) or blob["fields"] != _keys(entries[:done]):
        raise InvalidInputError(
            f"{path}: its {done} fields are not this run's first ones; remove it to start again"
        )
    state = {k: blob[k] for k in ("done", "acc", "skipped", "rotation", "warnings", "bounds")}
    state["second"] = blob.get("second", {})  # the second pass's sums (rspiv.vector_structures)
    state["columns"] = blob.get("columns")  # the two-point sums' columns
    return state
