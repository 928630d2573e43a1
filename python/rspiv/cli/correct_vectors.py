"""``rspiv correct-vectors FILES... --calibration cal.json -o DIR``: rspiv's Method II for vector
fields another tool measured on the raw frames (DaVis ``.vc7``, OpenPIV text, PIVlab MAT, TSI
Insight ``.vec``, an uncorrected rspiv run; :func:`rspiv.correction.correct_vectors`).

Each field (each frame of a multi-frame file: a PIVlab session's pairs) is read, corrected and
written as ``DIR/<name>.nc`` (``<name>_<frame>.nc`` for a file of several), one at a time and
atomically, in rspiv's NetCDF layout: ``rspiv compare`` and :func:`rspiv.read_vectors` read them
back as corrected fields (object px) of their tool. A file already written is kept with
``--skip-existing`` (a long batch resumed). The first file that cannot be read or corrected
stops the batch with one line naming it (exit 2); the files written before it stay whole.
From 64 fields on, one process per core reads the files ahead of the correction
(``--readers N``, 0: none; :mod:`rspiv.vector_readahead`); the fields written are the same.
"""

from __future__ import annotations

import argparse
import pathlib

from rspiv.calibration import Calibration
from rspiv.correction import correct_vectors
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf
from rspiv.vector_files import vector_frames
from rspiv.vector_readahead import ReadAhead, auto_readers


def run(args: argparse.Namespace) -> int:
    if args.readers is not None and args.readers < 0:
        raise InvalidInputError(f"--readers {args.readers}: a whole number >= 0")
    cal = Calibration.load(args.calibration)
    out = pathlib.Path(args.output)
    todo, kept = [], 0  # ((file, frame), target)
    for name in args.files:
        n = vector_frames(name)
        for k in range(n):
            stem = pathlib.Path(name).stem + (f"_{k:05d}" if n > 1 else "")
            target = out / f"{stem}.nc"
            if args.skip_existing and target.exists():
                kept += 1
            else:
                todo.append(((name, k), target))
    readers = auto_readers(len(todo)) if args.readers is None else args.readers
    with ReadAhead([e for e, _ in todo], {}, readers) as reads:
        for i, (_, target) in enumerate(todo):
            fixed = correct_vectors(reads.get(i), cal, mapping=args.mapping)
            write_netcdf(fixed.to_xarray(), target)
    written = len(todo)
    print(f"rspiv correct-vectors: {written} fields corrected to {out}"
          + (f", {kept} already there kept" if kept else ""))  # fmt: skip
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "correct-vectors",
        help="Method II for vector fields of another tool measured on the raw frames",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("files", nargs="+", help="vector files (.vc7, .txt/.vec, .mat, .nc, .dat)")
    p.add_argument("--calibration", required=True, help="calibration JSON (rspiv calibrate)")
    p.add_argument("--mapping", default="full", choices=("full", "positions"),
                   help="the displacement mapping (full: through the inverse)")  # fmt: skip
    p.add_argument("-o", "--output", required=True, help="folder of the corrected fields")
    p.add_argument("--skip-existing", action="store_true", help="keep fields already written")
    p.add_argument("--readers", type=int, default=None, metavar="N",
                   help="processes reading the files ahead (default: one per core from 64 "
                   "fields; 0: none)")
    p.set_defaults(func=run)
