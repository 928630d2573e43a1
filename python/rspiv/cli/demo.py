"""``rspiv demo [-o DIR]``: synthesise the embedded default campaign, process it, print the
accuracy verdicts against the exact truth and where the report is."""

from __future__ import annotations

import argparse
import dataclasses
import time

from rspiv.demo import DEFAULT_SCENE, format_verdicts, run_demo


def _demo(args: argparse.Namespace) -> int:

    scene = DEFAULT_SCENE
    if args.pairs is not None:
        scene = dataclasses.replace(scene, pairs=args.pairs)
    if args.scale is not None:
        scene = dataclasses.replace(scene, scale=args.scale)
    t0 = time.perf_counter()
    print(
        f"rspiv demo: {scene.pairs} synthetic boundary-layer pairs at scale {scene.scale:g} "
        f"of the paper's 47 MP sensor, into {args.output}",
        flush=True,
    )
    res, rows = run_demo(
        args.output,
        scene=scene,
        progress=not args.quiet,
        log=(lambda m: None) if args.quiet else (lambda m: print(m, flush=True)),
    )
    print()
    print(format_verdicts(rows))
    failed = [r for r in rows if r["pass"] is False]
    print()
    print(
        f"{'all claims hold' if not failed else f'{len(failed)} claim(s) FAILED'}; "
        f"{time.perf_counter() - t0:.0f} s in total"
    )
    print(f"report: {res.report}")
    return 1 if failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the embedded synthetic campaign end to end and print the verdicts",
        description="Synthesise the default boundary-layer campaign (target + pairs through the "
        "paper's lens), process it with Methods I and II and without correction, compare with "
        "the exact truth and write the report.",
    )
    p.add_argument("-o", "--output", default="rspiv-demo", help="folder (default rspiv-demo)")
    p.add_argument("--pairs", type=int, default=None, help="number of pairs (default 24)")
    p.add_argument("--scale", type=float, default=None, help="scene scale (default 0.4)")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=_demo)
