"""Two tools over a whole recording: their statistics compared pair by pair and row by row.

One pair says how far two tools' vectors differ; a campaign is judged by its statistics.
:func:`compare_series` takes the reference tool's fields and the compared tool's fields of the
same pairs (in the same order: ``rspiv compare "davis/B*.vc7" "OUT/fields/uncorrected/*.nc"``),
compares each pair as :func:`rspiv.compare.compare_fields` does, and over the pairs keeps, at
each of the reference's vectors and over the pairs where both tools have it valid (one sample
set for both, so that differences are the tools', not the sampling's):

- both tools' means ``U``, ``V`` and their fluctuations' (co)variances ``uu``, ``vv``, ``uv``
  (px per pair, px^2), one pass of sums, a file at a time (never all fields in memory);
- per row of the reference's vectors (``rows``), the row's averages of these over its
  columns, and the mean difference ``dU``, ``dV`` with a standard error from the scatter of the
  pairs' own row means (pairs are taken as independent samples; the columns of one pair are
  not, so the error is not divided by their number); ``n_pairs`` counts the pairs that gave
  the row a vector.

Series of files (lists of paths or ``(path, frame)`` tuples) are read ahead by reader
processes (``readers``; :mod:`rspiv.vector_readahead`), half of them for each series: the
figures are those of the files read in turn, bit for bit.

A boundary-layer user reads the rows as profiles: where the two tools' mean velocity or
Reynolds stresses part towards the wall, and by how much against the error of the mean. Every
pair's one-line summary (``pairs``) and any pair whose comparison warned (a convention, a
coverage) are kept; a warning in most of the pairs is said once for the series.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from rspiv.compare import compare_with_differences, json_ready
from rspiv.errors import InvalidInputError
from rspiv.vector_files import VectorFile, as_vectors, read_vectors

__all__ = ["SeriesComparison", "compare_series"]

#: The per-vector sums kept over the pairs, in this order.
_SUMS = ("ru", "rv", "fu", "fv", "ruu", "rvv", "ruv", "fuu", "fvv", "fuv", "du", "dv")

#: The pooled |d| is counted in bins of this width (px) up to _BINS of them (20 px), so that
#: its median (to 1e-4 px) and the share apart need no vector kept.
_BIN = 1e-4
_BINS = 200_000

#: Columns of :attr:`SeriesComparison.rows`.
ROW_COLUMNS = (
    "y", "n_pairs", "dU", "dU_err", "dV", "dV_err", "U_ref", "U_field", "V_ref", "V_field",
    "uu_ref", "uu_field", "vv_ref", "vv_field", "uv_ref", "uv_field",
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SeriesComparison:
    """A field series against a reference series (module docstring); px per pair and px^2.

    ``pairs`` holds per pair ``(index, vectors compared, bias du, bias dv, median |d|, share
    apart, warning)``; ``rows`` one tuple per reference row with a vector compared in at least
    two pairs, columns :data:`ROW_COLUMNS`. The pooled figures are over every vector compared.
    """

    n_pairs: int
    n_compared: int
    bias_u: float
    bias_v: float
    std_u: float
    std_v: float
    median: float
    share_apart: float
    threshold: float
    pairs: tuple[tuple[Any, ...], ...]
    rows: tuple[tuple[float, ...], ...]
    warning: str

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (NaN as None); ``row_columns`` names the rows' columns."""
        out = json_ready(dataclasses.asdict(self))
        out["row_columns"] = list(ROW_COLUMNS)
        return out

    def to_json(self) -> str:
        """:meth:`to_dict` as JSON text."""
        return json.dumps(self.to_dict(), indent=1)

    def report(self, rows: bool = False) -> str:
        """The pooled agreement, the pairs that warned, and with ``rows`` the profiles."""
        warned = [p for p in self.pairs if p[6]]
        lines = [
            f"{self.n_pairs} pairs, {self.n_compared} vectors compared: bias du "
            f"{self.bias_u:+.4f}, dv {self.bias_v:+.4f} px; std {self.std_u:.4f}, "
            f"{self.std_v:.4f} px; |d| median {self.median:.4f} px; "
            f"{100 * self.share_apart:.2f} % more than {self.threshold:g} px apart",
            f"  {len(warned)} pairs warned" + (f" (first: pair {warned[0][0]}: {warned[0][6]})"
                                              if warned else ""),
        ]  # fmt: skip
        if rows and self.rows:
            lines.append(
                "  rows: y px, pairs, dU +/- err, dV +/- err, U ref/field, uu ref/field, "
                "vv ref/field, uv ref/field"
            )
            for r in self.rows:
                lines.append(
                    f"  {r[0]:9.2f} {r[1]:5d} {r[2]:+.4f} {r[3]:.4f} {r[4]:+.4f} {r[5]:.4f} "
                    f"{r[6]:8.4f} {r[7]:8.4f} {r[10]:.4f} {r[11]:.4f} {r[12]:.4f} {r[13]:.4f} "
                    f"{r[14]:+.4f} {r[15]:+.4f}"
                )
        if self.warning:
            lines.append(f"  WARNING: {self.warning}")
        return "\n".join(lines)


def _load(item: Any, name: str, read: dict[str, Any]) -> VectorFile:
    if isinstance(item, (str, os.PathLike)):
        return read_vectors(item, **read)
    if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], (str, os.PathLike)):
        return read_vectors(item[0], **{**read, "frame": int(item[1])})
    return as_vectors(item, name)


def _is_entry(item: Any) -> bool:
    """A path, or a ``(path, frame)`` tuple: what a reader process can read."""
    return isinstance(item, (str, os.PathLike)) or (
        isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], (str, os.PathLike))
    )


def _pairs(
    references: Iterable[Any], fields: Iterable[Any], opts: dict[str, Any],
    readers: int | None, stack: contextlib.ExitStack,
) -> Iterator[tuple[Any, Any]]:  # fmt: skip
    """The pairs' ``(reference, field)`` items in turn, or ``(ReadAhead, k)`` twins when both
    series are lists of files of equal length and reader processes are to read them."""
    if isinstance(references, (list, tuple)) and isinstance(fields, (list, tuple)):
        if len(references) == len(fields) and all(map(_is_entry, [*references, *fields])):
            from rspiv.vector_readahead import ReadAhead, auto_readers  # deferred: processes

            n = auto_readers(len(references)) if readers is None else readers
            if n > 0:
                per = max(n // 2, 1)
                ref_reads = stack.enter_context(ReadAhead(list(references), opts, per))
                fld_reads = stack.enter_context(ReadAhead(list(fields), {}, per))
                for k in range(len(references)):
                    yield (ref_reads, k), (fld_reads, k)
                return
    refs, flds = iter(references), iter(fields)
    k = 0
    while True:
        r_item, f_item = next(refs, None), next(flds, None)
        if r_item is None and f_item is None:
            return
        if r_item is None or f_item is None:
            raise InvalidInputError(
                f"compare: {k} pairs of one series and more of the other: give the same pairs"
            )
        yield r_item, f_item
        k += 1


def _read(item: Any, name: str, read: dict[str, Any]) -> VectorFile:
    """One field: read ahead (``(ReadAhead, k)``) or as :func:`_load` reads it."""
    if isinstance(item, tuple) and len(item) == 2 and hasattr(item[0], "get"):
        return item[0].get(item[1])
    return _load(item, name, read)


def compare_series(
    references: Iterable[Any],
    fields: Iterable[Any],
    *,
    threshold: float = 0.5,
    reference_options: dict[str, Any] | None = None,
    readers: int | None = None,
) -> SeriesComparison:
    """Compare a series of fields with a reference series, pair by pair (module docstring).

    Parameters
    ----------
    references, fields : iterables of paths, (path, frame) tuples, VectorFile or PivField
        The two tools' fields of the same pairs, in the same order and of equal number; paths
        are read one at a time (:func:`rspiv.vector_files.read_vectors`), a tuple names a
        frame of a multi-frame file (a PIVlab session's pair, a DaVis buffer's frame).
    threshold : float
        px: vectors farther apart count as disagreeing.
    reference_options : dict, optional
        Keywords for reading the references (``y_up``, ``scale``, ``dt``, ``frame``).
    readers : int, optional
        Reader processes reading two lists of files ahead, half for each series (module
        docstring; 0: none). Default: :func:`rspiv.vector_readahead.auto_readers`' choice (one
        per core from 64 pairs).

    Returns
    -------
    SeriesComparison

    Raises
    ------
    InvalidInputError
        Series of unequal length or empty, references on different grids, a file that cannot
        be read, a pair without a vector in common.
    """
    if not (np.isfinite(threshold) and threshold > 0):
        raise InvalidInputError(f"compare: threshold {threshold} px must be positive")
    if readers is not None and (isinstance(readers, bool) or not isinstance(readers, int)
                                or readers < 0):  # fmt: skip
        raise InvalidInputError(f"compare: readers {readers!r} must be a whole number >= 0")
    opts = dict(reference_options or {})
    with contextlib.ExitStack() as stack:
        return _compare(_pairs(references, fields, opts, readers, stack), opts, threshold)


def _compare(pairs_in: Iterator[tuple[Any, Any]], opts: dict[str, Any],
             threshold: float) -> SeriesComparison:  # fmt: skip
    """:func:`compare_series`' sums over the pairs ``pairs_in`` gives."""
    grid = None
    sums: dict[str, np.ndarray] = {}
    count = None
    rows_acc = None  # per row: pairs giving it a vector; mean and M2 of their row du, dv
    pairs = []
    pooled = np.zeros(5)  # n, sum du, sum dv, sum du^2, sum dv^2
    hist = np.zeros(_BINS + 1, dtype=np.int64)  # |d| in bins of _BIN px, the last beyond
    k = 0
    for r_item, f_item in pairs_in:
        ref = _read(r_item, f"reference {k}", opts)
        fld = _read(f_item, f"field {k}", {})
        if grid is None:
            grid = (ref.x, ref.y)
            sums = {s: np.zeros(ref.u.shape) for s in _SUMS}
            count = np.zeros(ref.u.shape, dtype=np.int64)
            rows_acc = np.zeros((5, ref.u.shape[0]))
        elif ref.x.shape != grid[0].shape or not (
            np.allclose(ref.x, grid[0]) and np.allclose(ref.y, grid[1])
        ):
            raise InvalidInputError(
                f"compare: {ref.path} is on another grid than the first reference"
            )
        c, d = compare_with_differences(ref, fld, threshold)
        pairs.append(
            (k, c.n_compared, c.bias_u, c.bias_v, c.median, c.share_apart, c.warning)
        )
        idx = d.index
        vals = {
            "ru": d.ru, "rv": d.rv, "fu": d.fu, "fv": d.fv, "ruu": d.ru**2, "rvv": d.rv**2,
            "ruv": d.ru * d.rv, "fuu": d.fu**2, "fvv": d.fv**2, "fuv": d.fu * d.fv,
            "du": d.du, "dv": d.dv,
        }  # fmt: skip
        for s in _SUMS:  # each reference vector at most once per pair: a plain add
            sums[s].reshape(-1)[idx] += vals[s]
        count.reshape(-1)[idx] += 1
        rows_of = idx // ref.u.shape[1]
        nrow = ref.u.shape[0]
        n_row = np.bincount(rows_of, minlength=nrow)
        given = n_row > 0
        mu = np.bincount(rows_of, d.du, minlength=nrow)[given] / n_row[given]
        mv = np.bincount(rows_of, d.dv, minlength=nrow)[given] / n_row[given]
        rows_acc[0, given] += 1  # Welford's update of each row's mean and M2, du then dv
        for at, x in ((1, mu), (3, mv)):  # not k: the pairs' count
            delta = x - rows_acc[at, given]
            rows_acc[at, given] += delta / rows_acc[0, given]
            rows_acc[at + 1, given] += delta * (x - rows_acc[at, given])
        pooled += [d.du.size, d.du.sum(), d.dv.sum(), (d.du**2).sum(), (d.dv**2).sum()]
        hist += np.bincount(
            np.minimum((np.hypot(d.du, d.dv) / _BIN).astype(np.int64), _BINS), minlength=_BINS + 1
        )
        k += 1
    if k == 0 or grid is None or count is None:
        raise InvalidInputError("compare: no pairs given")
    return _finish(grid, sums, count, rows_acc, pairs, pooled, hist, threshold)


def _finish(grid, sums, count, rows_acc, pairs, pooled, hist, threshold) -> SeriesComparison:
    n, su, sv, suu, svv = pooled
    bias_u, bias_v = su / n, sv / n
    std_u = float(np.sqrt(max(suu / n - bias_u**2, 0.0)))
    std_v = float(np.sqrt(max(svv / n - bias_v**2, 0.0)))
    cum = np.cumsum(hist)
    median = (int(np.searchsorted(cum, cum[-1] / 2.0)) + 0.5) * _BIN
    apart = hist[int(np.ceil(threshold / _BIN)) :].sum() / cum[-1]
    rows = []
    with np.errstate(invalid="ignore", divide="ignore"):
        m = {s: sums[s] / count for s in _SUMS}
        cov = {
            "uu_ref": m["ruu"] - m["ru"] ** 2, "vv_ref": m["rvv"] - m["rv"] ** 2,
            "uv_ref": m["ruv"] - m["ru"] * m["rv"], "uu_field": m["fuu"] - m["fu"] ** 2,
            "vv_field": m["fvv"] - m["fv"] ** 2, "uv_field": m["fuv"] - m["fu"] * m["fv"],
        }  # fmt: skip
    for j in range(count.shape[0]):
        cols = count[j] >= 2
        npairs = int(rows_acc[0, j])
        if not cols.any() or npairs < 2:
            continue

        def avg(a: np.ndarray, j: int = j, cols: np.ndarray = cols) -> float:
            return float(np.mean(a[j][cols]))

        def mean_err(k: int, j: int = j, n: int = npairs) -> tuple[float, float]:
            """Mean of the pairs' row means and its standard error (their scatter)."""
            return float(rows_acc[k, j]), float(np.sqrt(rows_acc[k + 1, j] / (n - 1) / n))

        rows.append((
            float(grid[1][j, 0]), npairs, *mean_err(1), *mean_err(3),
            avg(m["ru"]), avg(m["fu"]), avg(m["rv"]), avg(m["fv"]),
            avg(cov["uu_ref"]), avg(cov["uu_field"]), avg(cov["vv_ref"]), avg(cov["vv_field"]),
            avg(cov["uv_ref"]), avg(cov["uv_field"]),
        ))  # fmt: skip
    warned = [p for p in pairs if p[6]]
    warning = ""
    if len(warned) * 2 > len(pairs):
        warning = (
            f"{len(warned)} of {len(pairs)} pairs warned; the first: pair {warned[0][0]}: "
            f"{warned[0][6]}"
        )
    return SeriesComparison(
        n_pairs=len(pairs), n_compared=int(n), bias_u=float(bias_u), bias_v=float(bias_v),
        std_u=std_u, std_v=std_v, median=float(median),
        share_apart=float(apart), threshold=float(threshold),
        pairs=tuple(pairs), rows=tuple(rows), warning=warning,
    )  # fmt: skip
