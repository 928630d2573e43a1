"""``rspiv merge PARTS... -o stats.nc``: combine partial statistics of a sharded campaign;
``rspiv merge --campaign campaign.toml``: merge all its shards and run the analysis.

Each part is a ``statistics_<run>.shard-<i>-of-<n>.nc`` written by ``rspiv process --shard i/n``
(or an earlier merge). Parts sharing a pair, the same shard twice or the same file twice are
refused; the order of the parts does not change the result (see :mod:`rspiv.merge`).
"""

from __future__ import annotations

import argparse
import sys

from rspiv.campaign import Campaign
from rspiv.errors import InvalidInputError
from rspiv.merge import merge_campaign, merge_files, missing_shards, read_part


def _merge(args: argparse.Namespace) -> int:

    if args.campaign is not None:
        if args.parts:
            raise InvalidInputError("give either PARTS or --campaign, not both")

        camp = Campaign.load(args.campaign, out_dir=args.output, progress=not args.quiet)
        res = merge_campaign(camp)
        print(f"merged {res.n_done} pair(s) of {len(res.accumulators)} run(s)")
        for a in res.analyses.values():
            if a.result is not None:
                s = a.result.summary()
                print(f"  {a.run.label}: u_tau = {s['u_tau']:.4g} m/s, Re_tau = {s['re_tau']:.4g}")
        for path in res.files.values():
            print(f"wrote {path}")
        return 0
    if not args.parts or args.output is None:
        raise InvalidInputError("give the parts and -o FILE (or --campaign campaign.toml)")
    written = merge_files(args.parts, args.output)
    for run, path in written.items():
        print(f"wrote {path}" + (f" (run {run})" if run else ""))
    missing = missing_shards(read_part(p) for p in written.values())
    if missing:
        print(
            f"note: shard(s) {', '.join(missing)} not merged yet (partial statistics)",
            file=sys.stderr,
        )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "merge",
        help="merge partial statistics of a sharded campaign",
        description="Combine the shard files of `rspiv process --shard i/n` (or earlier "
        "merges) into one statistics file. A pair is never counted twice: overlapping parts "
        "are refused.",
    )
    p.add_argument("parts", nargs="*", help="shard files (statistics_<run>.shard-*.nc)")
    p.add_argument(
        "-o",
        "--output",
        default=None,
        help="merged file (.nc); a folder when the parts are of several runs; with "
        "--campaign: the campaign's output folder (default [output].dir)",
    )
    p.add_argument(
        "--campaign",
        default=None,
        metavar="TOML",
        help="merge every run's complete set of shard files in the campaign's output folder "
        "and analyse the result like an unsharded run (profiles, NetCDF, CSV, report)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=_merge)


if __name__ == "__main__":  # pragma: no cover
    from rspiv.cli import main

    sys.exit(main(["merge", *sys.argv[1:]]))
