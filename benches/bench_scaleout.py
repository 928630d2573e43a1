"""Dask scale-out throughput against the local run, on the same machine in one run.

The demo campaign (rspiv.demo's scene, ``--scale`` of the paper's sensor, ``--pairs`` pairs;
Method II plus the uncorrected comparison, no Monte Carlo, no report) is prepared once
(calibration, wall pilot); then the same pairs are processed

* locally (:meth:`rspiv.Campaign.run`, rayon on all cores),
* on a Dask LocalCluster of 1 worker (rayon on all cores),
* on a Dask LocalCluster of 2 workers (1 thread each, rayon threads = cores / 2),

each from an empty checkpoint. Reported: the time of the pair loop (map + merge; the local
run's total minus preparation and analysis, Dask's ``info["dask"]["map_seconds"]``), pairs per
minute, the ratio to the local run, the cluster start-up time and the end-to-end time of
``run_dask`` (start-up and analysis included). The statistics of every Dask run are checked
against the local run (max relative difference of the mean u).

Usage::

    python benches/bench_scaleout.py [--scale 0.4] [--pairs 8] [--workdir /tmp/rspiv-bench-scaleout]

Prints a Markdown table (for benches/RESULTS.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import shutil
import time


def _fresh(prep: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for name in ("context.json", "calibration.json"):
        if (prep / name).is_file():
            shutil.copy2(prep / name, out / name)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scale", type=float, default=0.4)
    ap.add_argument("--pairs", type=int, default=8)
    ap.add_argument("--workdir", default="/tmp/rspiv-bench-scaleout")
    args = ap.parse_args()

    import distributed
    import numpy as np
    from rspiv.campaign import Campaign
    from rspiv.campaign.executors.dask import local_cluster, run_dask
    from rspiv.campaign_config import load_campaign_config
    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    work = pathlib.Path(args.workdir)
    tag = f"s{args.scale:g}-p{args.pairs}"
    root = work / tag
    toml = root / "campaign.toml"
    if not toml.is_file():
        scene = dataclasses.replace(
            DEFAULT_SCENE, scale=args.scale, pairs=args.pairs, monte_carlo_samples=0
        )
        t0 = time.perf_counter()
        synth_campaign(root, scene=scene)
        print(
            f"synthesised {args.pairs} pairs at scale {args.scale} in "
            f"{time.perf_counter() - t0:.1f} s"
        )
    cfg = load_campaign_config(toml)
    cfg.output.report = False
    cfg.calibration.monte_carlo_samples = 0
    cfg.save(toml)
    prep = root / "prep"
    if not (prep / "context.json").is_file():
        t0 = time.perf_counter()
        Campaign.load(toml, progress=False, out_dir=prep).prepare()
        print(f"prepared (calibration, pilot) in {time.perf_counter() - t0:.1f} s")
    cores = len(os.sched_getaffinity(0))

    rows = []
    t0 = time.perf_counter()
    ref = Campaign.load(toml, progress=False, out_dir=_fresh(prep, root / "local")).run()
    wall = time.perf_counter() - t0
    t = ref.timings
    loop = t["total"] - t["prepare"] - t.get("analysis", 0.0)
    rows.append((f"local (rayon {cores} threads)", ref.n_done, loop, 0.0, wall, 0.0))

    for n_workers in (1, 2):
        rayon = max(1, cores // n_workers)
        t0 = time.perf_counter()
        cluster = local_cluster(n_workers=n_workers, rayon_threads=rayon)
        client = distributed.Client(cluster)
        startup = time.perf_counter() - t0
        try:
            out = _fresh(prep, root / f"dask{n_workers}")
            t0 = time.perf_counter()
            res = run_dask(Campaign.load(toml, progress=False, out_dir=out), client)
            wall = time.perf_counter() - t0
        finally:
            client.close()
            cluster.close()
        a, b = ref.accumulators["method_II"].mean_u, res.accumulators["method_II"].mean_u
        diff = float(np.nanmax(np.abs(a - b)) / np.nanmax(np.abs(a)))
        rows.append(
            (
                f"Dask {n_workers} worker(s) x 1 thread, rayon {rayon}",
                res.n_done,
                res.info["dask"]["map_seconds"],
                startup,
                wall,
                diff,
            )
        )

    base = rows[0][2] / rows[0][1]
    print()
    print(f"Demo campaign, scale {args.scale:g}, {args.pairs} pairs, {cores} cores")
    print()
    print(
        "| configuration | pairs | pair loop (s) | pairs/min | vs local | cluster start (s) "
        "| end to end (s) | max rel. diff mean u |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, n, loop, start, wall, diff in rows:
        ppm = 60.0 * n / loop
        print(
            f"| {name} | {n} | {loop:.1f} | {ppm:.2f} | {base / (loop / n):.2f}x | "
            f"{start:.1f} | {wall:.1f} | {diff:.1e} |"
        )


if __name__ == "__main__":
    main()
