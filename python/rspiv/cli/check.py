"""``rspiv check A.tif B.tif``: is a recording fit for PIV, and which passes does it need?

Prints what :func:`rspiv.check_recording` measured on the pair (particle images per px and per
window, their diameter, the sensor's saturation, noise and background, the displacement of a
coarse pass) and the passes it recommends, then one ``warning:`` line per concern. ``--passes``
checks the passes a campaign will use as well; ``--json FILE`` writes every figure. The exit
status is 0 when the check ran (warnings included), 2 for input it cannot read.
"""

from __future__ import annotations

import json
import pathlib

from rspiv.cli.piv import _passes
from rspiv.errors import InvalidInputError
from rspiv.io import read_mask, read_pair
from rspiv.outputs import atomic_write_text
from rspiv.recording import check_recording


def _run(args) -> int:
    a, b = read_pair(args.frame_a, args.frame_b)
    names = args.frame_a if args.frame_b is None else f"{args.frame_a}, {args.frame_b}"
    mask = read_mask(args.mask, a.shape) if args.mask is not None else None
    passes = _passes(args.passes) if args.passes else None
    try:
        check = check_recording(a, b, mask=mask, passes=passes)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{names}: {exc}") from exc
    for line in check.lines():
        print(line)
    if args.json:
        path = atomic_write_text(
            pathlib.Path(args.json), json.dumps(check.to_dict(), indent=1, default=float)
        )
        print(f"-> {path}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "check",
        help="check a recording before PIV: seeding, particle size, sensor, displacement, passes",
        description="Measure an image pair as recorded (particle images per px and per window, "
        "their diameter, saturation, noise, background, the displacement of a coarse pass) and "
        "recommend the PIV passes (one-quarter rule, >= 10 particle images per window). Lengths "
        "in px, intensities in counts.",
    )
    p.add_argument(
        "frame_a",
        help="first frame (TIFF/PNG/BMP/JPEG/DaVis .im7), or a two-frame TIFF or DaVis buffer",
    )
    p.add_argument("frame_b", nargs="?", default=None, help="second frame")
    p.add_argument("--mask", default=None, help="mask image or polygon JSON (True = excluded)")
    p.add_argument(
        "--passes", default=None, help="the passes a campaign will use, WxH,... (64x64,32x32,32x8)"
    )
    p.add_argument("--json", default=None, help="write every figure to this JSON file")
    p.set_defaults(func=_run)
