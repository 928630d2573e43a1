"""A campaign's POD at 47 MP: ``rspiv.campaign.pod.decompose`` streaming field files (blocks of
rows for the inner products, one more read for the modes) beside the obvious peer, numpy's thin
SVD of the whole snapshot matrix held in memory (``np.linalg.svd(X, full_matrices=False)``, the
modes ``X = U S V^T``), in one run on the same files.

The files are written first: ``--snapshots`` field files of the 47 MP campaign's grid (``--rows``
x ``--cols`` vectors, 32 x 8 px windows at 50 % overlap on 8864 x 5288 px) in the layout of
:mod:`rspiv.campaign.fields` (float32 ``u``, ``v``, uint8 ``valid``; 3 % rejected), holding a
mean flow, ``--modes`` planted structures and noise. Each side runs in its own subprocess, so
each peak memory (VmHWM) is its own; the two spectra are compared (relative 1e-8).

Usage::

    python benches/bench_pod.py [--snapshots 200] [--rows 1322] [--cols 554] [--no-peer]
        [--workdir /tmp/rspiv-bench-pod]

Prints a Markdown table (for benches/RESULTS.md).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

CHILD = r"""
import json, pathlib, sys, time
import numpy as np
import h5py

side, work, n, k = sys.argv[1], pathlib.Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
paths = [work / f"pair_{i:06d}.nc" for i in range(n)]
with h5py.File(work / "mean.h5", "r") as f:
    mean_u, mean_v = f["u"][...], f["v"][...]
domain = np.ones(mean_u.shape, bool)
if side == "rspiv":
    from rspiv.campaign.pod import decompose
    from rspiv.pod import PodBuilder
t0 = time.perf_counter()
if side == "rspiv":
    b = PodBuilder(mean_u, mean_v, domain, n)
    decompose(b, paths, "bench", k)
    energy = b.result().energy
else:
    d = mean_u.size
    x = np.empty((n, 2 * d))
    for i, p in enumerate(paths):
        with h5py.File(p, "r") as f:
            ok = f["valid"][...].astype(bool).ravel()
            x[i, :d] = np.where(ok, f["u"][...].ravel() - mean_u.ravel(), 0.0)
            x[i, d:] = np.where(ok, f["v"][...].ravel() - mean_v.ravel(), 0.0)
    u_, s, vt = np.linalg.svd(x, full_matrices=False)
    energy = s[:k] ** 2 / n
seconds = time.perf_counter() - t0
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM"))
print(json.dumps({"seconds": seconds, "hwm_mb": hwm / 1024, "energy": energy.tolist()}))
"""


def write_files(work: pathlib.Path, n: int, rows: int, cols: int, modes: int) -> None:
    """``n`` field files (module docstring) and ``mean.h5``, unless already there."""
    import h5py

    work.mkdir(parents=True, exist_ok=True)
    stamp = work / "done.json"
    want = {"n": n, "rows": rows, "cols": cols, "modes": modes}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:rows, 0:cols] / np.array([rows, cols])[:, None, None]
    mean_u = (10 * np.sqrt(1 - y)).astype(np.float32)
    mean_v = np.zeros_like(mean_u)
    shapes = [np.sin(np.pi * (j + 1) * y) * np.cos(2 * np.pi * (j + 1) * x) for j in range(modes)]
    amp = 2.0 / (1 + np.arange(modes))
    for i in range(n):
        c = rng.standard_normal(modes) * amp
        fu = mean_u + np.tensordot(c, shapes, 1) + 0.1 * rng.standard_normal(mean_u.shape)
        fv = mean_v + 0.5 * np.tensordot(c[::-1], shapes, 1)
        valid = (rng.random(mean_u.shape) > 0.03).astype(np.uint8)
        with h5py.File(work / f"pair_{i:06d}.nc", "w") as f:
            f.attrs["run"] = "bench"
            f["u"] = np.where(valid, fu, np.nan).astype(np.float32)
            f["v"] = np.where(valid, fv, np.nan).astype(np.float32)
            f["valid"] = valid
            f["x"] = np.arange(cols, dtype=np.float64) * 16 + 16
    with h5py.File(work / "mean.h5", "w") as f:  # the run's means, as a campaign has them
        f["u"], f["v"] = mean_u, mean_v
    stamp.write_text(json.dumps(want))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--snapshots", type=int, default=200)
    ap.add_argument("--rows", type=int, default=1322)
    ap.add_argument("--cols", type=int, default=554)
    ap.add_argument("--modes", type=int, default=10)
    ap.add_argument("--workdir", default="/tmp/rspiv-bench-pod")
    ap.add_argument("--no-peer", action="store_true")
    args = ap.parse_args()
    work = pathlib.Path(args.workdir)
    t0 = time.perf_counter()
    write_files(work, args.snapshots, args.rows, args.cols, args.modes)
    print(f"files ready ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    out = {}
    for side in ("rspiv",) + (() if args.no_peer else ("numpy",)):
        run = subprocess.run(
            [sys.executable, "-c", CHILD, side, str(work), str(args.snapshots), str(args.modes)],
            capture_output=True,
            text=True,
            env=os.environ.copy(),
        )
        if run.returncode != 0:
            print(run.stderr, file=sys.stderr)
            return 1
        out[side] = json.loads(run.stdout.strip().splitlines()[-1])
    vectors = args.rows * args.cols
    print(f"\n{args.snapshots} snapshots of {args.cols} x {args.rows} vectors ({vectors:,}), "
          f"{args.modes} modes; {os.cpu_count()} cores\n")  # fmt: skip
    print("| side | seconds | peak RSS MB |")
    print("|---|---|---|")
    for side, r in out.items():
        print(f"| {side} | {r['seconds']:.1f} | {r['hwm_mb']:.0f} |")
    if "numpy" in out:
        a, b = np.array(out["rspiv"]["energy"]), np.array(out["numpy"]["energy"])
        dev = float(np.max(np.abs(a / b - 1)))
        ratio = out["numpy"]["seconds"] / out["rspiv"]["seconds"]
        print(f"\nnumpy / rspiv time: {ratio:.2f}x; memory {out['numpy']['hwm_mb'] / out['rspiv']['hwm_mb']:.1f}x; "  # noqa: E501
              f"largest eigenvalue deviation {dev:.1e}")  # fmt: skip
        if dev > 1e-8:
            print("the two spectra differ", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
