"""``rspiv compare-profile PROFILE.csv [REFERENCE.csv]``: a boundary-layer profile in wall units
against the DNS or another profile, band by band (:mod:`rspiv.reference_comparison`).

Prints the reference, each band's mean difference with its error and verdict, and the uu+
peak of both; ``--json FILE`` writes every figure. Exit status 0 when compared (differences
included), 2 for a file it cannot read.
"""

from __future__ import annotations

import json
import pathlib

from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_write_text
from rspiv.reference_comparison import compare_reference


def _run(args) -> int:
    window = None
    if args.window_plus:
        try:
            w, h = (float(v) for v in args.window_plus.split(","))
        except ValueError:
            raise InvalidInputError(
                f"--window-plus: expected W,H in wall units, got {args.window_plus!r}"
            ) from None
        window = (w, h)
    cmp = compare_reference(args.profile, args.reference, window_plus=window)
    for line in cmp.lines():
        print(line)
    print(cmp.verdict())
    if args.json:
        path = atomic_write_text(pathlib.Path(args.json), json.dumps(cmp.to_dict(), indent=1))
        print(f"-> {path}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "compare-profile",
        help="a boundary-layer profile against the DNS or another profile, band by band",
        description="Hold a profile in wall units (a campaign's or rspiv statistics' "
        "profile_*.csv, or any CSV with y_plus and U_plus, uu_plus, vv_plus, uv_plus columns) "
        "against the Schlatter & Orlu DNS station nearest its Re_tau, or against another "
        "profile: in the viscous sublayer, buffer, log and outer layers, the mean difference "
        "with its error and whether it agrees within three errors, and the uu+ peak.",
    )
    p.add_argument("profile", help="the measured profile (CSV)")
    p.add_argument(
        "reference", nargs="?", default=None, help="a reference profile (CSV); default the DNS"
    )
    p.add_argument(
        "--window-plus",
        default=None,
        help="W,H: the final window in wall units (the DNS mean velocity averaged over H)",
    )
    p.add_argument("--json", default=None, help="write every figure to this JSON file")
    p.set_defaults(func=_run)
