"""``rspiv ptv campaign.toml``: particle tracking at the wall over a processed campaign
(:mod:`rspiv.campaign.ptv`).

Tracks every pair's particle images with the pair's field as the predictor, bins them by their
distance from the run's wall and writes ``OUT/ptv_<run>.csv``, ``.json`` and ``.png``;
prints the tracks' counts, what the pairs said and the wall shear from the viscous sublayer
against the campaign's ``u_tau``. Exit status 0 when written, 2 for a campaign it cannot use
(not processed, no field files, no wall). The settings not given default to the campaign
file's ``[ptv]`` section (the same names: ``radius``, ``bin_px``, ``band_px``,
``whole_frame``).
"""

from __future__ import annotations

import numpy as np

from rspiv.campaign.ptv import campaign_ptv, merge_ptv
from rspiv.campaign.runner import Campaign
from rspiv.campaign.spec import parse_shard
from rspiv.errors import InvalidInputError


def _run(args) -> int:
    camp = Campaign.load(args.campaign, progress=False, log=None if args.quiet else print)
    if args.merge and args.shard:
        raise InvalidInputError("--merge and --shard: a shard tracks, the merge writes; one")
    if args.merge:
        given = [f"--{k.replace('_', '-')}" for k in ("radius", "bin", "band", "max_pairs",
                 "whole_frame", "afresh") if getattr(args, k) not in (None, 0, False)]  # fmt: skip
        if given:
            raise InvalidInputError(
                f"--merge sums the shards as they were tracked: {', '.join(given)} would not "
                "apply (give them to the shards)"
            )
        info = merge_ptv(camp, args.run)
    else:
        shard = parse_shard(args.shard) if args.shard else None
        pc = camp.config.ptv  # the campaign file's [ptv] settings, unless given here
        info = campaign_ptv(
            camp, args.run, radius=pc.radius if args.radius is None else args.radius,
            bin_px=pc.bin_px if args.bin is None else args.bin,
            band_px=pc.band_px if args.band is None else args.band,
            max_pairs=args.max_pairs, resume=not args.afresh, shard=shard,
            whole_frame=args.whole_frame or pc.whole_frame,
        )  # fmt: skip
        if shard is not None:
            print(
                f"ptv {info['run']} shard {info['shard']}: {info['pairs']} pair(s) tracked "
                f"({info['skipped']} skipped) in {info['seconds']:.1f} s -> {info['state']}; "
                f"`rspiv ptv {args.campaign} --merge` writes the profile once every shard is done"
            )
            return 0
    c = info["counts"]
    print(
        f"ptv {info['run']}: {info['pairs']} pair(s), {c.get('tracks', 0)} tracks of "
        f"{c.get('detected_a', 0)} particle images in A (particle images "
        f"{info['diameter_px']:.2f} px) in {info['seconds']:.1f} s"
    )
    for w, n in info["warnings"].items():
        print(f"  {n} pair(s): {w}" + (" (the figures of the first)" if n > 1 else ""))
    e = info.get("track_error_px2") or {}
    if np.isfinite(e.get("uu", np.nan)):
        print(
            f"  the tracks' own error (at most, from the two-track stresses): uu {e['uu']:.4f} "
            f"+- {e['se_uu']:.4f}, vv {e['vv']:.4f} +- {e['se_vv']:.4f} px^2"
        )
    if info.get("profile_warning"):
        print(f"  warning: {info['profile_warning']}")
    s = info["sublayer"]
    if not s["fitted"]:
        print(f"  no sublayer fit: {s['reason']}")
    elif "u_tau" in s:
        ref = s.get("campaign_u_tau")
        z = s.get("difference_errors")  # in both errors combined, when the campaign has its
        zs = f", {z:+.1f} errors" if z is not None else ""
        vs = (
            f" against the campaign's {ref:.4g} m/s ({100 * s['difference']:+.1f} %{zs})"
            if ref else ""
        )  # fmt: skip
        print(
            f"  u_tau from the viscous sublayer ({s['bins']} bins, y+ "
            f"{s['y_plus_range'][0]:.2g}-{s['y_plus_range'][1]:.2g}): {s['u_tau']:.4g} "
            f"+- {s['se_u_tau']:.2g} m/s{vs}; the wall {s['wall_offset_px']:+.2f} "
            f"+- {s['se_wall_offset_px']:.2f} px from the campaign's"
        )
    else:
        print(f"  sublayer gradient {s['gradient']:.4g} +- {s['se_gradient']:.2g} px/px per pair")
    print(f"-> {info['csv']}\n-> {info['json']}")
    if "figure" in info:
        print(f"-> {info['figure']}")
    if camp.config.output.report:
        print(
            f"the campaign report shows the tracks after `rspiv process {args.campaign}` again "
            "(it resumes: no pair is processed again)"
        )
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "ptv",
        help="particle tracking at the wall over a processed campaign",
        description="Follow each particle image of every pair of a processed campaign "
        "([output] fields = true) from frame A to frame B, with the pair's field as the "
        "predictor, and bin the tracks by their distance from the run's wall: the mean profile "
        "and Reynolds stresses in half-pixel bins down to about a particle image's diameter "
        "from the wall, and u_tau from the viscous sublayer. Resumes after an interruption.",
    )
    p.add_argument("campaign", help="the campaign file (TOML)")
    p.add_argument("--run", default=None, help="the run (default the campaign's first)")
    p.add_argument(
        "--radius", type=float, default=None,
        help="search radius about each predicted position, px (default: [ptv] radius, 2)",
    )  # fmt: skip
    p.add_argument(
        "--bin", type=float, default=None, help="bin height, px (default: [ptv] bin_px, 0.5)"
    )
    p.add_argument(
        "--band", type=float, default=None,
        help="band from the wall, px (default: [ptv] band_px, 32)",
    )  # fmt: skip
    p.add_argument("--max-pairs", type=int, default=0, help="only the first N pairs (0: all)")
    p.add_argument("--afresh", action="store_true", help="ignore the pass's checkpoint")
    p.add_argument(
        "--whole-frame", action="store_true",
        help="search the whole frames for particle images, not only the rows near the wall",
    )  # fmt: skip
    p.add_argument(
        "--shard", default=None, metavar="I/N",
        help="track every N-th pair from the I-th into the shard's own state (for cluster jobs)",
    )  # fmt: skip
    p.add_argument(
        "--merge", action="store_true",
        help="write the profile of a pass run in shards, once every shard is done",
    )  # fmt: skip
    p.add_argument("-q", "--quiet", action="store_true", help="say less")
    p.set_defaults(func=_run)
