"""``rspiv process campaign.toml [--shard i/n] [-o DIR] [--checkpoint-every K]``.

Runs a whole campaign (:class:`rspiv.Campaign`): calibration, wall alignment, PIV of every
pair, streaming statistics, boundary-layer analysis, NetCDF/CSV outputs and the report. A rich
progress bar on a terminal, plain log lines otherwise. Restarting the same command resumes from
``OUT/checkpoint/``; ``--shard i/n`` processes the i-th of n slices and writes partial
statistics for a later merge.
"""

from __future__ import annotations

import argparse
import sys

from rspiv.campaign import Campaign, pair_quality
from rspiv.campaign import reference as reference_work
from rspiv.campaign.analysis import partial_correlation_note
from rspiv.campaign.executors.dask import run_dask
from rspiv.settings import parse_method


def _add_dask_arguments(parser: argparse.ArgumentParser) -> None:
    """``--dask ADDRESS``, ``--dask-workers N``, ``--rayon-threads N``, ``--chunk-size N``:
    run the pairs on dask.distributed (:func:`rspiv.campaign.executors.dask.run_dask`)."""
    g = parser.add_argument_group("Dask scale-out (pip install 'rspiv[dask]')")
    g.add_argument(
        "--dask",
        default=None,
        metavar="ADDRESS",
        help="run the pairs on dask.distributed: 'local' (a LocalCluster sized to this "
        "machine), a scheduler address tcp://host:8786 or a scheduler file (.json)",
    )
    g.add_argument(
        "--dask-workers",
        type=int,
        default=None,
        metavar="N",
        help="--dask local: worker processes (default: the cores, memory permitting)",
    )
    g.add_argument(
        "--rayon-threads",
        type=int,
        default=None,
        metavar="N",
        help="--dask: rayon threads per worker (default: cores / workers per host)",
    )
    g.add_argument(
        "--chunk-size",
        type=int,
        default=None,
        metavar="N",
        help="--dask: pairs per task (default: ~4 tasks per worker)",
    )


def _process(args: argparse.Namespace) -> int:
    camp = Campaign.load(
        args.campaign,
        shard=args.shard,
        checkpoint_every=args.checkpoint_every,
        pilot_pairs=args.pilot_pairs,
        extra_methods=tuple(args.also_method or ()),
        out_dir=args.output,
        progress=not args.quiet,
    )
    if args.dask:
        res = run_dask(
            camp,
            args.dask,
            n_workers=args.dask_workers,
            rayon_threads=args.rayon_threads,
            chunk_size=args.chunk_size,
        )
    else:
        res = camp.run()
    print(
        f"{res.n_done} of {res.n_pairs} pair(s) processed"
        + (f" ({res.n_resumed} from the checkpoint)" if res.n_resumed else "")
        + (
            f", {len(res.skipped)} skipped (see {res.out_dir / 'run_log.jsonl'})"
            if res.skipped
            else ""
        )
    )
    note = partial_correlation_note(res)
    if note:
        print(f"warning: {note}", file=sys.stderr)
    for line in camp.info.get("particle_size_warnings", {}).values():
        print(f"warning: {line}", file=sys.stderr)
    for line in camp.info.get("recording_warnings", {}).values():
        print(f"warning: recording: {line}", file=sys.stderr)
    for line in pair_quality.warning_lines(res):
        print(f"warning: {line}", file=sys.stderr)
    for line in camp.info.get("screen_warnings", {}).values():
        print(f"warning: {line}", file=sys.stderr)
    for key in ("recording_file", "davis_timing"):  # a [flow] dt against the files' own
        if "warning" in (camp.info.get(key) or {}):
            print(f"warning: {camp.info[key]['warning']}", file=sys.stderr)
    against = camp.info.get(reference_work.INFO_KEY) or {}
    for a in res.analyses.values():
        if a.result is not None:
            s = a.result.summary()
            print(
                f"  {a.run.label}: u_tau = {s['u_tau']:.4g} m/s, Re_tau = {s['re_tau']:.4g}, "
                f"delta99 = {1e3 * s['delta99']:.4g} mm"
            )
            if a.run.label in against:
                print(f"    {against[a.run.label].verdict()}")
        elif a.error:
            print(f"  {a.run.label}: {a.error}")
    for name, path in res.files.items():
        if not name.startswith("report"):
            print(f"wrote {path}")
    if res.report is not None:
        print(f"report: {res.report}")
    return 0 if res.n_done else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "process",
        help="run a PIV campaign described by a TOML file",
        description="Calibrate, align the wall, run PIV on every pair, accumulate statistics, "
        "analyse the boundary layer and write NetCDF, CSV and the report. Re-running resumes "
        "from the checkpoint.",
    )
    p.add_argument("campaign", help="campaign file (TOML)")
    p.add_argument("-o", "--output", default=None, help="output folder (default: [output].dir)")
    p.add_argument(
        "--shard",
        default=None,
        metavar="I/N",
        help="process the I-th of N slices of the pairs (1-based) and write partial statistics",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int,
        default=25,
        metavar="K",
        help="pairs between checkpoints (default 25)",
    )
    p.add_argument(
        "--pilot-pairs", type=int, default=4, help="pairs used to find the wall angle (default 4)"
    )
    p.add_argument(
        "--also-method",
        action="append",
        type=parse_method,
        help="also process with this correction method, I or II (comparison)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    _add_dask_arguments(p)
    p.set_defaults(func=_process)


if __name__ == "__main__":  # pragma: no cover
    from rspiv.cli import main  # deferred: the package's entry point runs this module

    sys.exit(main(["process", *sys.argv[1:]]))
