"""``rspiv init RECORDING``: write a campaign file from a recording (:mod:`rspiv.campaign_init`).

Prints what decided each value and one ``check:`` line per thing the recording cannot decide
(also the file's first lines), then the path written. Exit status 0 when the file was written,
2 for input it refuses (no frames, frames A and B out of order, a target that does not
calibrate, an existing file without ``--force``).
"""

from __future__ import annotations

import pathlib

from rspiv.campaign_init import init_campaign
from rspiv.errors import InvalidInputError


def _run(args) -> int:
    out = pathlib.Path(args.output)
    if out.exists() and not args.force:  # said before the recording is read
        raise InvalidInputError(f"{out}: exists; give another name (-o) or --force")
    found = init_campaign(
        args.recording,
        target=args.target,
        pitch_mm=args.pitch_mm,
        pitch_sigma_mm=args.pitch_sigma_mm,
        marker=args.marker,
        level=args.level,
        dt=args.dt,
        nu=args.nu,
        method=args.method,
        output_dir=args.output_dir,
    )
    for (section, key), note in found.notes.items():
        print(f"[{section}] {key}: {note}")
    for line in found.said:
        print(f"check: {line}")
    path = found.write(out, force=args.force)
    print(f"wrote {path}")
    print(f"next: rspiv check {path}, then rspiv process {path}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "init",
        help="write a campaign file from a recording: pairing, orientation, passes, dt, "
        "calibration model",
        description="Look at a recording (a folder, a glob, a DaVis .set, a multi-frame TIFF or "
        "a Photron/Phantom recording) and write a campaign file: the pairing (time-resolved or "
        "double-frame, from frames 1-2 and 2-3), the turn that makes the flow run along +x, the "
        "passes rspiv check recommends, the pulse separation of a camera recording and, with a "
        "target, the mapping model. What the recording cannot decide is said and written at "
        "the top of the file. Lengths in px, times in s.",
    )
    p.add_argument("recording", help="folder, glob (quoted), .set, multi-frame TIFF, .cine, .cihx")
    p.add_argument("-o", "--output", default="campaign.toml", help="campaign file to write")
    p.add_argument("--target", default=None, help="calibration target image")
    p.add_argument("--pitch-mm", type=float, default=None, help="the target's marker pitch, mm")
    p.add_argument(
        "--pitch-sigma-mm",
        type=float,
        default=None,
        help="the pitch's one-sigma uncertainty, mm (default: estimated from the fit)",
    )
    p.add_argument("--marker", default="dot", choices=("dot", "cross"), help="marker shape")
    p.add_argument(
        "--level",
        type=int,
        choices=(1, 2),
        default=None,
        help="a two-level plate's level in the light sheet (1 = the nearer)",
    )
    p.add_argument("--dt", type=float, default=None, help="pulse separation, s")
    p.add_argument("--nu", type=float, default=None, help="kinematic viscosity, m^2/s")
    p.add_argument(
        "--method", default=None, help="correction: II, I or none (II with a target, else none)"
    )
    p.add_argument(
        "--output-dir", default="rspiv-out", help="the campaign's output folder (rspiv-out)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing campaign file")
    p.set_defaults(func=_run)
