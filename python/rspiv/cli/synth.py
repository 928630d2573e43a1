"""``rspiv synth campaign DIR --pairs N [--scale S] [--seed K]``: a synthetic campaign.

Writes a calibration target, N boundary-layer image pairs through the paper's lens distortion
(with the wall reflection), the exact truth and a ``campaign.toml`` ready for
``rspiv process`` (see :mod:`rspiv.demo` for the scene).
"""

from __future__ import annotations

import argparse
import dataclasses

from rspiv.demo import DEFAULT_SCENE, synth_campaign


def _campaign(args: argparse.Namespace) -> int:

    scene = DEFAULT_SCENE
    if args.seed is not None:
        scene = dataclasses.replace(scene, seed=args.seed)
    if args.monte_carlo is not None:
        scene = dataclasses.replace(scene, monte_carlo_samples=args.monte_carlo)
    path = synth_campaign(
        args.dir,
        pairs=args.pairs,
        scale=args.scale,
        scene=scene,
        log=None if args.quiet else (lambda m: print(m, flush=True)),
    )
    print(f"wrote {path}")
    print(f"next: rspiv process {path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth",
        help="write synthetic data with an exact answer",
        description="Synthetic data whose ground truth rspiv controls.",
    )
    s = p.add_subparsers(dest="what", metavar="WHAT")
    s.required = True
    c = s.add_parser(
        "campaign",
        help="a boundary-layer campaign: target, image pairs, truth and campaign.toml",
        description="Render the calibration target and N boundary-layer pairs through the "
        "paper's lens distortion, and write the truth and a campaign file.",
    )
    c.add_argument("dir", help="folder to write (created)")
    c.add_argument("--pairs", type=int, default=None, help="number of pairs (default 12)")
    c.add_argument(
        "--scale",
        type=float,
        default=None,
        help="sensor and boundary-layer scale against the paper's 8864 x 5288 px, "
        "magnification kept (default 0.4)",
    )
    c.add_argument("--seed", type=int, default=None)
    c.add_argument(
        "--monte-carlo",
        type=int,
        default=None,
        metavar="N",
        help="Monte Carlo samples written to the campaign file",
    )
    c.add_argument("-q", "--quiet", action="store_true")
    c.set_defaults(func=_campaign)
