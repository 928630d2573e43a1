"""``rspiv wall``.

- ``rspiv wall FRAME_A FRAME_B [FRAME_A FRAME_B ...] [--calibration calib.json] [--band Y0 Y1]
  [--stations N] [--write-rotated calib2.json]``: PIV of each pair (dewarped first if a
  calibration is given), the wall from the reflection symmetry of the mean profile, its angle and
  deviation (paper Table 4); optionally write the calibration with the levelling rotation.
"""

from __future__ import annotations

import argparse


def _wall(args: argparse.Namespace) -> int:
    import numpy as np

    from rspiv.calibration import Calibration, read_image
    from rspiv.dewarp import dewarp
    from rspiv.errors import InvalidInputError
    from rspiv.piv import piv
    from rspiv.wall import find_wall

    if len(args.frames) % 2:
        raise InvalidInputError("wall: give frames in pairs (A B [A B ...])")
    cal = Calibration.load(args.calibration) if args.calibration else None
    fields = []
    for a_name, b_name in zip(args.frames[::2], args.frames[1::2], strict=True):
        a, b = read_image(a_name), read_image(b_name)
        if cal is not None:
            a, b = dewarp(a, cal.mapping), dewarp(b, cal.mapping)
        fields.append(piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5))
    w = find_wall(fields, band=tuple(args.band) if args.band else None, stations=args.stations)
    ok = np.isfinite(w.position_px)
    print(f"stations {ok.sum()} / {len(ok)}; wall at x = {w.x_px[0]:.0f} .. {w.x_px[-1]:.0f} px")
    print(f"angle {w.angle_deg:+.5f} deg (levelling rotation {w.rotation_deg:+.5f} deg)")
    print(f"max deviation from straight and level {w.max_deviation_px:.3f} px; "
          f"from the fitted line {w.straightness_px:.3f} px")  # fmt: skip
    if args.write_rotated:
        if cal is None:
            raise InvalidInputError("wall: --write-rotated needs --calibration")
        cal.with_rotation(w.rotation_deg).save(args.write_rotated)
        print(f"rotated calibration -> {args.write_rotated}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    q = sub.add_parser("wall", help="find the wall from the particle reflection")
    q.add_argument("frames", nargs="+", help="image pairs: A1 B1 [A2 B2 ...]")
    q.add_argument("--calibration", help="dewarp the frames with this calibration first")
    q.add_argument("--band", nargs=2, type=float, metavar=("Y0", "Y1"),
                   help="rows (px) around the wall to use")  # fmt: skip
    q.add_argument("--stations", type=int, default=16, help="streamwise stations (16)")
    q.add_argument("--write-rotated", metavar="JSON",
                   help="write the calibration with the levelling rotation")  # fmt: skip
    q.set_defaults(func=_wall)
