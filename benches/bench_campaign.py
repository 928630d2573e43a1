"""Campaign throughput: pairs per minute, peak memory and the time per stage (read, condition,
dewarp, PIV, statistics) of ``rspiv process`` on synthetic campaigns (rspiv.demo's scene), for
Method II, Method I and the uncorrected processing, at the demo scale and on full 47 MP pairs.

Pairs per minute are the pair loop's wall time (the run without its analysis and outputs), and
after the first pair: from the first pair's end to the last's, the loop's steady state that a
long campaign runs at (the first pair also pays the process's first touch of its whole-frame
buffers, about 0.5 s at 47 MP on the development machine);
before 2026-11-26 (eighth session) they were the sum of the read, dewarp, PIV and statistics
stages, which left the frames' conditioning (about 0.4 s per 47 MP pair) out.

Each configuration runs in its own subprocess; its peak memory (VmHWM) is reported for the
preparation (calibration of the target, wall pilot) and, reset in between, for the pair loop.
Side by side, the same pair through OpenPIV (``openpiv.pyprocess.extended_search_area_piv``,
one pass of 32 x 32 px windows, 50 % overlap, plus its sig2noise validation), the peer's
per-pair cost for a *single* pass without any distortion correction.

Usage::

    python benches/bench_campaign.py [--scales 0.4 1.0] [--pairs 4] [--workdir /tmp/rspiv-bench]
    python benches/bench_campaign.py --scales 1.0 --no-peer --methods II --roi-rows 0.25
    python benches/bench_campaign.py --scales 1.0 --no-peer --methods II --two-point
    python benches/bench_campaign.py --scales 1.0 --no-peer --methods II --extras
    python benches/bench_campaign.py --scales 1.0 --no-peer --methods II --rereduce
    python benches/bench_campaign.py --scales 0.146 0.505 1.0 --methods II --threads 1 2 --no-peer

Prints a Markdown table (for benches/RESULTS.md), and the run's CPU time (loop and analysis,
user and system: the system share is mostly the kernel zeroing fresh pages). With ``--threads``,
each configuration runs once per thread count (``RAYON_NUM_THREADS``, the pool every rspiv
kernel runs on) and a scaling table follows: the loop's seconds per pair and per megapixel, and
the speed-up over one thread (scales 0.146 / 0.505 / 1.0 are 1 / 12 / 47 MP sensors). With
``--rereduce`` each pair's fields are written and the campaign runs again with pair 1 left out:
its statistics summed again from the field files (:mod:`rspiv.campaign.rereduce`), in seconds
per pair against the PIV's.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

CHILD = r"""
import json, os, sys, time, pathlib
from rspiv.campaign import STAGES, Campaign
from rspiv.campaign_config import load_campaign_config
toml, method, out = sys.argv[1], sys.argv[2], sys.argv[3]
cfg = load_campaign_config(toml)
if len(sys.argv) > 4:  # the region of interest: the lower fraction of the rows (the wall's side)
    h, w = json.loads((pathlib.Path(toml).parent / "truth.json").read_text())["image_shape"]
    cfg.piv.roi = [0, int(round(h * (1.0 - float(sys.argv[4])))), w, h]
cfg.correction.method = method
cfg.correction.compare_uncorrected = False
# the synthetic campaign's [statistics] two_point (spectra, maps and their pilot) only if asked
cfg.statistics.two_point = os.environ.get("RSPIV_BENCH_TWO_POINT") == "1"
# its vorticity statistics, each pair's fields and the passes over them (quadrant, POD, vortices)
# alike
extras = os.environ.get("RSPIV_BENCH_EXTRAS") == "1"
cfg.statistics.vorticity = cfg.statistics.quadrant = extras
cfg.statistics.pod = cfg.statistics.vortices = extras
# the other passes over the fields (the synthetic campaign turns conditional averages on): only
# with the extras, which write the fields they read
for key in ("conditional", "temporal", "spod"):
    setattr(cfg.statistics, key, extras and getattr(cfg.statistics, key))
# each pair's fields, and a second run with pair 1 left out, summed again from them
rereduce = os.environ.get("RSPIV_BENCH_REREDUCE") == "1"
cfg.output.fields = extras or rereduce

cfg.calibration.monte_carlo_samples = 0
cfg.output.report = False
def hwm_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")
def huge_mb():  # anonymous transparent huge pages resident now
    try:
        for line in open("/proc/self/smaps_rollup"):
            if line.startswith("AnonHugePages:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")
t0 = time.perf_counter()
# one pilot pair for the wall's angle; two for the two-point maps' delta_99 (a profile)
camp = Campaign(cfg, progress=False, out_dir=out, pilot_pairs=2 if cfg.statistics.two_point else 1)
t1 = time.perf_counter()
camp.prepare()
prepare_s = time.perf_counter() - t1
prepare_peak = hwm_mb()
with open("/proc/self/clear_refs", "w") as f:  # reset the peak RSS (VmHWM) for the loop
    f.write("5")
# when each pair's processing ends: the loop's steady state is the time from the first pair's
# end to the last's (the first pair also pays the process's first touch of its frame buffers,
# the FFT plans and the thread pool)
import rspiv.campaign.pair as _pair
ends = []
_process = _pair.process_pair
def _timed(*a, **k):
    r = _process(*a, **k)
    ends.append(time.perf_counter())
    return r
_pair.process_pair = _timed
cpu0 = os.times()
t2 = time.perf_counter()
res = camp.run()  # reuses the prepared context
run_s = time.perf_counter() - t2
cpu1 = os.times()
huge_after = huge_mb()
wall = time.perf_counter() - t0
t = res.timings
n = res.n_done
rer = {}
if rereduce:
    _pair.process_pair = _process
    cfg.images.exclude_pairs = [1]
    again = Campaign(cfg, progress=False, out_dir=out, pilot_pairs=camp.pilot_pairs)
    t3 = time.perf_counter()
    again.run()
    done = again.info["rereduced"]
    rer = {"rereduce_s": done["seconds"] / done["pairs"], "rerun_s": time.perf_counter() - t3}
print(json.dumps({**rer,
    "pairs": n, "total_s": wall,
    # the pair loop's wall time: the run without its analysis and outputs
    "loop_s": run_s - t.get("analysis", 0.0),
    "steady_s": (ends[-1] - ends[0]) / (len(ends) - 1) if len(ends) > 1 else float("nan"),
    "stages_s": sum(t.get(k, 0.0) for k in STAGES),
    **{k: t.get(k, 0.0) / n for k in STAGES},
    "prepare_s": prepare_s, "analysis_s": t.get("analysis", 0.0),
    "peak_rss_mb": hwm_mb(), "prepare_peak_mb": prepare_peak, "huge_mb": huge_after,
    # the run's CPU time (loop and analysis): the kernel's share is mostly first-touch page
    # zeroing of fresh buffers
    "user_s": cpu1.user - cpu0.user, "sys_s": cpu1.system - cpu0.system,
}))
"""

PEER = r"""
import json, sys, time, tifffile, numpy as np
from openpiv import pyprocess, validation
a = tifffile.imread(sys.argv[1]).astype(np.int32)
b = tifffile.imread(sys.argv[2]).astype(np.int32)
t0 = time.perf_counter()
u, v, s2n = pyprocess.extended_search_area_piv(a, b, window_size=32, overlap=16,
                                                search_area_size=32, sig2noise_method="peak2peak")
flags = validation.sig2noise_val(s2n, threshold=1.05)
dt = time.perf_counter() - t0
import rspiv
t0 = time.perf_counter()
f = rspiv.piv(a.astype(np.uint16), b.astype(np.uint16), [(32, 32)], overlap=0.5)
dr = time.perf_counter() - t0
print(json.dumps({"openpiv_s": dt, "rspiv_1pass_s": dr, "vectors": int(u.size)}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", type=float, nargs="+", default=[0.4, 1.0])
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--workdir", default="/tmp/rspiv-bench-campaign")
    ap.add_argument("--methods", nargs="+", default=["II", "I", "none"])
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument("--threads", type=int, nargs="+", default=[None])
    ap.add_argument(
        "--two-point",
        action="store_true",
        help="keep the synthetic campaign's [statistics] two_point (spectra and maps)",
    )
    ap.add_argument(
        "--extras",
        action="store_true",
        help="keep the synthetic campaign's vorticity statistics, fields, quadrant, POD, vortices",
    )
    ap.add_argument(
        "--rereduce",
        action="store_true",
        help="write each pair's fields, then run again with pair 1 left out: the statistics "
        "summed again from the field files (s per pair against the PIV's)",
    )
    ap.add_argument(
        "--roi-rows",
        type=float,
        default=None,
        help="a region of interest ([piv] roi): the lower FRACTION of the rows, wall included",
    )
    args = ap.parse_args()

    import dataclasses

    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    rows = []
    peers = []
    for scale in args.scales:
        d = pathlib.Path(args.workdir) / f"scale-{scale:g}"
        toml = d / "campaign.toml"
        if not toml.is_file() or len(list((d / "raw").glob("*.tif"))) != 2 * args.pairs:
            t0 = time.perf_counter()
            scene = dataclasses.replace(
                DEFAULT_SCENE, scale=scale, pairs=args.pairs, monte_carlo_samples=0
            )
            synth_campaign(d, scene=scene)
            print(
                f"# synthesised {args.pairs} pairs at scale {scale:g} in "
                f"{time.perf_counter() - t0:.0f} s",
                file=sys.stderr,
            )
        shape = json.loads((d / "truth.json").read_text())["image_shape"]
        mp = shape[0] * shape[1] / 1e6
        for method in args.methods:
            for threads in args.threads:
                out = d / f"out-{method}"
                if out.exists():
                    import shutil

                    shutil.rmtree(out)
                env = dict(os.environ)
                if threads is not None:
                    env["RAYON_NUM_THREADS"] = str(threads)
                env["RSPIV_BENCH_TWO_POINT"] = "1" if args.two_point else "0"
                env["RSPIV_BENCH_EXTRAS"] = "1" if args.extras else "0"
                env["RSPIV_BENCH_REREDUCE"] = "1" if args.rereduce else "0"
                roi = [] if args.roi_rows is None else [str(args.roi_rows)]
                r = subprocess.run(
                    [sys.executable, "-c", CHILD, str(toml), method, str(out), *roi],
                    capture_output=True,
                    text=True,
                    env=env,
                )
                if r.returncode != 0:
                    print(r.stderr, file=sys.stderr)
                    continue
                m = json.loads(r.stdout.strip().splitlines()[-1])
                m.update(scale=scale, mp=mp, method=method, threads=threads,
                         per_min=60.0 * m["pairs"] / m["loop_s"])  # fmt: skip
                rows.append(m)
                print(f"# {scale:g} {method} threads={threads}: {m}", file=sys.stderr)
        if not args.no_peer:
            raw = sorted((d / "raw").glob("*.tif"))
            r = subprocess.run(
                [sys.executable, "-c", PEER, str(raw[0]), str(raw[1])],
                capture_output=True,
                text=True,
            )
            if r.returncode == 0:
                p = json.loads(r.stdout.strip().splitlines()[-1])
                p.update(scale=scale, mp=mp)
                peers.append(p)
            else:
                print(r.stderr, file=sys.stderr)

    print(
        "| sensor | method | threads | pairs/min | pairs/min after the first | read s | "
        "condition s | dewarp s | PIV s | statistics s | prepare s | peak RSS MB, loop | "
        "peak RSS MB, prepare |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for m in rows:
        label = {"II": "Method II", "I": "Method I", "none": "uncorrected"}[m["method"]]
        threads = "all" if m["threads"] is None else m["threads"]
        print(
            f"| {m['mp']:.1f} MP (scale {m['scale']:g}) | {label} | {threads} | "
            f"{m['per_min']:.1f} | {60.0 / m['steady_s']:.1f} | "
            f"{m['read']:.2f} | {m['condition']:.2f} | {m['dewarp']:.2f} | {m['piv']:.2f} | "
            f"{m['statistics']:.3f} | "
            f"{m['prepare_s']:.1f} | {m['peak_rss_mb']:.0f} | {m['prepare_peak_mb']:.0f} |"
        )
    print()
    print("| sensor | method | threads | CPU user s, run | CPU system s, run | system share |")
    print("|---|---|---|---|---|---|")
    for m in rows:
        threads = "all" if m["threads"] is None else m["threads"]
        cpu = m["user_s"] + m["sys_s"]
        print(
            f"| {m['mp']:.1f} MP | {m['method']} | {threads} | {m['user_s']:.1f} | "
            f"{m['sys_s']:.1f} | {m['sys_s'] / cpu if cpu > 0 else float('nan'):.0%} |"
        )
    if any("rereduce_s" in m for m in rows):
        print()
        print(
            "| sensor | method | PIV s per pair | re-reduced s per pair | PIV / re-reduced | "
            "second run s |"
        )
        print("|---|---|---|---|---|---|")
        for m in rows:
            if "rereduce_s" in m:
                print(
                    f"| {m['mp']:.1f} MP | {m['method']} | {m['piv']:.2f} | "
                    f"{m['rereduce_s']:.2f} | {m['piv'] / m['rereduce_s']:.1f} | "
                    f"{m['rerun_s']:.1f} |"
                )
    if any(m["threads"] is not None for m in rows):
        print()
        print("| sensor | method | threads | s per pair | s per MP | speed-up over 1 thread |")
        print("|---|---|---|---|---|---|")
        one = {(m["scale"], m["method"]): m for m in rows if m["threads"] == 1}
        for m in rows:
            per_pair = m["loop_s"] / m["pairs"]
            base = one.get((m["scale"], m["method"]))
            up = base["loop_s"] / base["pairs"] / per_pair if base else float("nan")
            print(
                f"| {m['mp']:.1f} MP | {m['method']} | {m['threads']} | {per_pair:.2f} | "
                f"{per_pair / m['mp']:.3f} | {up:.2f} |"
            )
    if peers:
        print()
        print("| sensor | OpenPIV 1 pass 32x32 (s) | rspiv 1 pass 32x32 (s) | ratio |")
        print("|---|---|---|---|")
        for p in peers:
            print(
                f"| {p['mp']:.1f} MP | {p['openpiv_s']:.2f} | {p['rspiv_1pass_s']:.2f} | "
                f"{p['openpiv_s'] / p['rspiv_1pass_s']:.1f}x |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
