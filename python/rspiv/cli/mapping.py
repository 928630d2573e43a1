"""``rspiv fit-mapping`` and ``rspiv map``: the Python twins of the engine's commands.

- ``rspiv fit-mapping POINTS.csv --model p3 -o mapping.json``: fit a mapping model to point
  pairs (CSV columns ``x_obj,y_obj,x_img,y_img``; object px and image px).
- ``rspiv map mapping.json POINTS.csv [--inverse] [-o OUT.csv]``: apply a saved mapping to points
  (CSV columns ``x,y``), object px -> image px, or image px -> object px with ``--inverse``.
"""

from __future__ import annotations

import argparse
import io
import pathlib
import sys

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.mapping import Mapping, fit_mapping
from rspiv.outputs import atomic_write_text


def _read_csv(path: str, cols: list[str]) -> np.ndarray:
    """The named columns of a numeric CSV file with a header row, as an (N, len(cols)) array."""
    data = read_csv_columns(path, cols)
    return np.column_stack([data[c] for c in cols])


def read_csv_columns(
    path: str, cols: list[str], optional: tuple[str, ...] = (), *, finite: bool = False
) -> dict[str, np.ndarray]:
    """The columns of a numeric CSV file with a header row (``#`` lines and blank lines are
    skipped), by name: every one of ``cols`` and those of ``optional`` the header holds.

    Raises
    ------
    InvalidInputError
        One line naming the file (and the line): not UTF-8, no header (or a header of
        numbers), a missing column, a row of the wrong length, a field that is not a number
        (or, with ``finite``, is NaN or inf), no data rows.
    """
    try:
        text = pathlib.Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InvalidInputError(f"{path}: not a UTF-8 text file") from None
    lines = [
        (i + 1, line.strip())
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.strip().startswith("#")
    ]
    if not lines:
        raise InvalidInputError(f"{path}: empty file (expected a header row)")
    names = [n.strip().strip('"') for n in lines[0][1].split(",")]
    if all(_is_number(n) for n in names):
        raise InvalidInputError(
            f"{path}: line {lines[0][0]}: expected a header row naming the columns "
            f"({','.join(cols)}), got numbers"
        )
    for c in cols:
        if c not in names:
            raise InvalidInputError(
                f"{path}: missing column {c!r} (header has {','.join(names)}; "
                f"expected {','.join(cols)})"
            )
    wanted = [*cols, *(c for c in optional if c in names)]
    idx = [names.index(c) for c in wanted]
    rows = []
    for lineno, line in lines[1:]:
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != len(names):
            raise InvalidInputError(
                f"{path}: line {lineno}: {len(fields)} fields, the header has {len(names)}"
            )
        row = []
        for k, c in zip(idx, wanted, strict=True):
            try:
                v = float(fields[k])
            except ValueError:
                raise InvalidInputError(
                    f"{path}: line {lineno}: column {c}: cannot parse {fields[k]!r} as a number"
                ) from None
            if finite and not np.isfinite(v):
                raise InvalidInputError(
                    f"{path}: line {lineno}: column {c}: {fields[k]!r} is not a finite number"
                )
            row.append(v)
        rows.append(row)
    if not rows:
        raise InvalidInputError(f"{path}: no data rows")
    data = np.asarray(rows, dtype=np.float64)
    return {c: data[:, k] for k, c in enumerate(wanted)}


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _write_csv(path: str | None, pts: np.ndarray) -> None:
    buf = io.StringIO()
    buf.write("x,y\n")
    for x, y in pts:
        buf.write(f"{float(x)!r},{float(y)!r}\n")
    if path is None:
        sys.stdout.write(buf.getvalue())
        return
    atomic_write_text(path, buf.getvalue(), make_parents=False)


def _fit(args: argparse.Namespace) -> int:

    data = _read_csv(args.points, ["x_obj", "y_obj", "x_img", "y_img"])
    try:
        m = fit_mapping(
            data[:, :2], data[:, 2:], args.model, center_index=args.center_index, scale=args.scale
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"{args.points}: {exc}") from None
    m.save(args.output)
    s = m.stats
    print(
        f"{m.model}: {s['n_points']} points, rms ({s['rms_px'][0]:.4f}, {s['rms_px'][1]:.4f}) px, "
        f"max |res| ({s['max_abs_px'][0]:.4f}, {s['max_abs_px'][1]:.4f}) px -> {args.output}"
    )
    return 0


def _map(args: argparse.Namespace) -> int:

    m = Mapping.load(args.mapping)
    pts = _read_csv(args.points, ["x", "y"])
    out = m.inverse(pts) if args.inverse else m.forward(pts)
    _write_csv(args.output, out)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``fit-mapping`` and ``map`` to the ``rspiv`` command."""
    p = subparsers.add_parser(
        "fit-mapping",
        help="fit a mapping model (r1, r2, p3) to point pairs from a CSV file",
        description="Fit a mapping model to point pairs: CSV columns x_obj,y_obj,x_img,y_img "
        "(object px, image px). Writes the mapping as JSON.",
    )
    p.add_argument("points", help="CSV with columns x_obj,y_obj,x_img,y_img")
    p.add_argument("--model", default="p3", help="r1, r2 or p3 (default p3)")
    p.add_argument("-o", "--output", required=True, help="output mapping JSON")
    p.add_argument("--center-index", type=int, default=None, help="row of the central marker")
    p.add_argument("--scale", type=float, default=None, help="normalising scale in px")
    p.set_defaults(func=_fit)

    q = subparsers.add_parser(
        "map",
        help="apply a saved mapping to points x,y from a CSV file",
        description="Map points (CSV columns x,y) object px -> image px, or image px -> object "
        "px with --inverse. Writes CSV x,y to standard output or -o.",
    )
    q.add_argument("mapping", help="mapping JSON (from fit-mapping or Mapping.save)")
    q.add_argument("points", help="CSV with columns x,y")
    q.add_argument("--inverse", action="store_true", help="image px -> object px")
    q.add_argument("-o", "--output", default=None, help="output CSV (default: standard output)")
    q.set_defaults(func=_map)
