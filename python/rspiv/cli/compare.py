"""``rspiv compare REFERENCE FIELD``: how far two vector fields of one pair agree.

The reference is the lab's result of another tool (DaVis ``.vc7``, OpenPIV ``.txt``, PIVlab
``.mat``, TSI Insight ``.vec``) and the field rspiv's (``rspiv piv A.tif B.tif -o field.nc``),
or any two of them (:mod:`rspiv.vector_files` gives each format's conventions,
:mod:`rspiv.compare` the figures).
With ``--calibration cal.json`` the reference, measured on the raw frames, is first corrected
by rspiv's Method II (:func:`rspiv.correction.correct_vectors`), to be compared with an rspiv
run corrected by the same calibration. The report goes to stdout; a suspected convention error
(y upward, positions shifted, another dt), a corrected field against an uncorrected one or a
poor coverage is said on stderr as well. ``--json`` writes the figures and the rows,
``--figure`` a PNG of the rows (:mod:`rspiv.plots.compare`).

Two series of the same pairs (a glob, quoted, a folder, or a file of several pairs such as a
PIVlab session: ``rspiv compare "davis/*.vc7" OUT/fields/uncorrected``) are compared pair by
pair, in sorted order, and their statistics row by row (:mod:`rspiv.compare_series`: mean
velocity and Reynolds stresses of both tools over the pairs both measured, the mean difference
with its error). Their files are read ahead by reader processes (``--readers N``, 0: none; one
per core from 64 pairs by default; :mod:`rspiv.vector_readahead`); the figures are the same.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from rspiv.calibration import Calibration
from rspiv.compare import compare_fields
from rspiv.compare_series import compare_series
from rspiv.correction import correct_vectors
from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_write_text
from rspiv.vector_files import read_vectors, vector_series


def _name(item: Any) -> str:
    return f"{item[0]}[{item[1]}]" if isinstance(item, tuple) else str(item)


def _run_series(args: argparse.Namespace, refs: list[str], flds: list[str]) -> int:
    if len(refs) != len(flds):
        raise InvalidInputError(
            f"{len(refs)} reference files and {len(flds)} fields: give the same pairs"
        )
    opts = {"frame": args.frame, "y_up": args.y_up, "scale": args.scale, "dt": args.dt}
    c = compare_series(refs, flds, threshold=args.threshold, reference_options=opts,
                       readers=args.readers)  # fmt: skip
    print(f"{_name(refs[0])} ... against {_name(flds[0])} ...")
    print(c.report(rows=args.rows))
    return _written(args, c)


def _written(args: argparse.Namespace, c) -> int:
    """The JSON file and the figure when asked, the warning on stderr; the exit code."""
    if args.json:
        atomic_write_text(args.json, c.to_json() + "\n")
    if args.figure:
        from rspiv.plots.compare import plot_comparison  # deferred: matplotlib on request

        print(f"figure: {plot_comparison(args.figure, c)}")
    if c.warning:
        print(f"rspiv compare: warning: {c.warning}", file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    refs, flds = vector_series(args.reference), vector_series(args.field)
    if (refs is None) != (flds is None):
        raise InvalidInputError("a series against one file: give two files or two series")
    if refs is not None and flds is not None:
        if args.calibration is not None:
            raise InvalidInputError("--calibration corrects one reference field, not a series")
        return _run_series(args, refs, flds)
    ref = read_vectors(
        args.reference, frame=args.frame, y_up=args.y_up, scale=args.scale, dt=args.dt
    )
    fld = read_vectors(args.field, frame=args.field_frame)
    if args.calibration is not None:
        ref = correct_vectors(ref, Calibration.load(args.calibration), mapping=args.mapping)
    for f in (ref, fld):
        print(f.describe())
        for note in f.notes:
            print(f"  ({note})")
    c = compare_fields(ref, fld, threshold=args.threshold)
    print(c.report())
    if args.rows:
        print("  rows: y px, vectors, mean du, mean dv, rms px")
        for y, n, du, dv, rms in c.rows:
            print(f"  {y:9.2f} {n:6d} {du:+9.4f} {dv:+9.4f} {rms:9.4f}")
    return _written(args, c)


def register(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="how far two vector fields of one pair agree (rspiv against DaVis, OpenPIV, PIVlab, "
        "Insight)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("reference", help="the reference field (.vc7, .txt/.vec, .mat, .nc, .dat)")
    p.add_argument("field", help="the field to compare (e.g. rspiv piv's .nc)")
    p.add_argument("--frame", type=int, default=0, help="the reference's frame or PIVlab pair")
    p.add_argument("--field-frame", type=int, default=0, help="the field's frame or pair")
    p.add_argument(
        "--y-up", action="store_true",
        help="the reference (OpenPIV text) has y and v upward (transform_coordinates)",
    )  # fmt: skip
    p.add_argument("--scale", type=float, default=1.0, help="OpenPIV reference: units per px")
    p.add_argument("--dt", type=float, default=1.0, help="OpenPIV reference: s its u, v are per")
    p.add_argument(
        "--threshold", type=float, default=0.5, help="px: vectors farther apart disagree (0.5)"
    )
    p.add_argument(
        "--calibration", default=None,
        help="calibration JSON: correct the reference (raw-frame vectors) by Method II first",
    )  # fmt: skip
    p.add_argument("--mapping", default="full", choices=("full", "positions"),
                   help="with --calibration: the displacement mapping (full)")  # fmt: skip
    p.add_argument("--rows", action="store_true", help="print the differences row by row")
    p.add_argument("--readers", type=int, default=None, metavar="N",
                   help="two series: processes reading the files ahead (default: one per core "
                   "from 64 pairs; 0: none)")
    p.add_argument("--json", default=None, help="write the figures as JSON")
    p.add_argument(
        "--figure", default=None,
        help="PNG of the rows: the differences (one field), both tools' profiles (a series)",
    )  # fmt: skip
    p.set_defaults(func=run)
