"""``rspiv check A.tif B.tif`` or ``rspiv check campaign.toml``: is a recording fit for PIV, and
which passes does it need?

For a pair, prints what :func:`rspiv.check_recording` measured (particle images per px and per
window, their diameter, the sensor's saturation, noise and background, the displacement of a
coarse pass) and the passes it recommends, then one ``warning:`` line per concern; ``--passes``
checks the passes a campaign will use as well. For a campaign file, the same for its first pair
with the campaign's passes, mask and region of interest, and what the campaign will cost on
this machine (:mod:`rspiv.campaign.estimate`: time per pair and in all, field files on disk),
then :func:`rspiv.recording_drift.check_drift` over ``--samples`` pairs spread evenly over the
run (seeding, background, brightness, displacement and the run's direction). ``--json FILE``
writes every figure. The exit status is 0 when the check ran (warnings included), 2 for input it
cannot read.
"""

from __future__ import annotations

import json
import pathlib

from rspiv.cli.piv import _frames, _passes, recording_line
from rspiv.errors import InvalidInputError
from rspiv.io import read_mask, read_pair
from rspiv.outputs import atomic_write_text
from rspiv.recording import check_recording, mean_diameter, roi_mask, spread
from rspiv.recording_drift import check_drift


def _campaign(args) -> dict:
    """A campaign file's first pair and the drift over its run; the JSON-ready figures."""
    from rspiv.campaign import Campaign  # deferred: the campaign stack only for a campaign file
    from rspiv.campaign.estimate import estimate_campaign, estimate_lines  # deferred: as above
    from rspiv.campaign.pair import read_checked_pair, read_frame  # deferred: as above

    if args.samples < 1:
        raise InvalidInputError(f"--samples must be at least 1, got {args.samples}")
    camp = Campaign.load(args.frame_a, progress=False)
    cfg = camp.config
    pairs = camp.pairs()
    if not pairs:
        raise InvalidInputError(f"{args.frame_a}: the campaign lists no image pair")
    shape = read_frame(pairs[0].a, pairs[0].frame_a, pairs[0].turn).shape
    turn = pairs[0].turn
    mask = read_mask(cfg.piv.mask, shape, turn) if cfg.piv.mask else None
    mask = roi_mask(mask, cfg.piv.roi, shape)
    passes = [tuple(p) for p in cfg.piv.passes]
    a, b = read_checked_pair(pairs[0], shape)
    try:
        first = check_recording(a, b, mask=mask, passes=passes)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{pairs[0].describe()}: {exc}") from exc
    print(f"first pair ({pairs[0].describe()}):")
    for line in first.lines():
        print(f"  {line}")
    cost = estimate_campaign(camp, a, b, mask)  # time and disk on this machine
    del a, b
    print("the campaign (an estimate):")
    for line in estimate_lines(cost):
        print(f"  {line}")
    chosen = spread(pairs, args.samples)
    print("pairs spread over the run: " + ", ".join(str(p.pair_id) for p in chosen))
    drift = check_drift(
        ((p.pair_id, *read_checked_pair(p, shape)) for p in chosen),
        mask=mask,
        diameter=mean_diameter(first.diameter),
        passes=passes,
    )
    for line in drift.lines():
        print(f"  {line}")
    return {"first": first.to_dict(), "drift": drift.to_dict(), "estimate": cost}


def _run(args) -> int:
    if args.frame_b is None and str(args.frame_a).lower().endswith(".toml"):
        figures = _campaign(args)
    else:
        frames = _frames(args.frames)
        a, b = read_pair(args.frame_a, args.frame_b, frames)
        names = args.frame_a if args.frame_b is None else f"{args.frame_a}, {args.frame_b}"
        said = recording_line(args.frame_a, frames) if args.frame_b is None else None
        if said:
            print(said)
        mask = read_mask(args.mask, a.shape) if args.mask is not None else None
        passes = _passes(args.passes) if args.passes else None
        try:
            check = check_recording(a, b, mask=mask, passes=passes)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{names}: {exc}") from exc
        for line in check.lines():
            print(line)
        figures = check.to_dict()
    if args.json:
        path = atomic_write_text(
            pathlib.Path(args.json), json.dumps(figures, indent=1, default=float)
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
        help="first frame (TIFF/PNG/BMP/JPEG/DaVis .im7), a multi-frame file (TIFF stack, DaVis "
        "buffer, Photron or Phantom recording), or a campaign file (.toml: its first pair with "
        "its passes and mask, then the drift over its run)",
    )
    p.add_argument("frame_b", nargs="?", default=None, help="second frame")
    p.add_argument(
        "--frames", default=None, help="I,J: the two frames of a multi-frame file (0,1)"
    )
    p.add_argument("--mask", default=None, help="mask image or polygon JSON (True = excluded)")
    p.add_argument(
        "--passes", default=None, help="the passes a campaign will use, WxH,... (64x64,32x32,32x8)"
    )
    p.add_argument(
        "--samples", type=int, default=20, help="a campaign's pairs checked for drift (20)"
    )
    p.add_argument("--json", default=None, help="write every figure to this JSON file")
    p.set_defaults(func=_run)
