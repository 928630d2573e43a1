"""``rspiv wall``: the run's version of the paper's Table 4 and Fig. 8.

- ``rspiv wall FRAME_A FRAME_B [FRAME_A FRAME_B ...] [--calibration calib.json]
  [--models r2 p3] [--band Y0 Y1] [--stations N] [--figure wall_shape.png]
  [--write-rotated calib2.json]``: PIV of each pair on the raw frames and on the frames
  dewarped (Method I, as the paper) by each model fitted to the calibration's markers, without
  and with the levelling rotation; the wall from the reflection symmetry of the mean profile;
  prints the maximum deviation (px) and angle (deg) per condition
  (:func:`rspiv.wall_table.wall_table`) and writes the wall-shape figure. ``--write-rotated``
  writes the calibration (its own model) with the rotation measured for that model.
"""

from __future__ import annotations

import argparse

from rspiv.calibration import Calibration
from rspiv.errors import InvalidInputError
from rspiv.wall_table import refit, wall_table


def _wall(args: argparse.Namespace) -> int:

    if len(args.frames) % 2:
        raise InvalidInputError("wall: give frames in pairs (A B [A B ...])")
    if args.write_rotated and not args.calibration:
        raise InvalidInputError("wall: --write-rotated needs --calibration")
    cal = Calibration.load(args.calibration) if args.calibration else None
    models = [m.lower() for m in args.models]
    if cal is not None and args.write_rotated and cal.model not in models:
        models.append(cal.model)
    pairs = list(zip(args.frames[::2], args.frames[1::2], strict=True))
    table = wall_table(
        pairs,
        cal,
        models=models,
        band=tuple(args.band) if args.band else None,
        stations=args.stations,
        progress=(lambda msg: print(f"  {msg} ...", flush=True)) if args.verbose else None,
    )
    print(f"{len(pairs)} pair(s); Method I (frames dewarped before the PIV) as the paper's Table 4")
    print(table.format())
    if args.figure:
        from rspiv.plots.wall import wall_shape  # deferred: matplotlib

        out = wall_shape(table.walls, args.figure)
        print(f"wall shape (paper Fig. 8) -> {out}")
    if args.write_rotated:
        assert cal is not None
        row = table[f"{cal.model.upper()} + rotation"]
        refit(cal, cal.model).with_rotation(row.rotation_deg).save(args.write_rotated)
        print(f"{cal.model} calibration rotated by {row.rotation_deg:+.5f} deg -> "
              f"{args.write_rotated}")  # fmt: skip
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    q = sub.add_parser("wall", help="wall alignment: the paper's Table 4 and Fig. 8")
    q.add_argument("frames", nargs="+", help="image pairs: A1 B1 [A2 B2 ...]")
    q.add_argument("--calibration", help="calibration JSON (its markers are fitted by each model)")
    q.add_argument("--models", nargs="+", default=["r2", "p3"], choices=["r1", "r2", "p3"],
                   help="mapping models of the corrected rows (r2 p3)")  # fmt: skip
    q.add_argument("--band", nargs=2, type=float, metavar=("Y0", "Y1"),
                   help="rows (px) around the wall to use")  # fmt: skip
    q.add_argument("--stations", type=int, default=16, help="streamwise stations (16)")
    q.add_argument("--figure", default="wall_shape.png",
                   help="wall-shape figure PNG (wall_shape.png; '' to skip)")  # fmt: skip
    q.add_argument("--write-rotated", metavar="JSON",
                   help="write the calibration with the levelling rotation")  # fmt: skip
    q.add_argument("-v", "--verbose", action="store_true", help="print each condition")
    q.set_defaults(func=_wall)
