"""Reducing another tool's vector files to statistics: ``rspiv.vector_statistics`` on a series of
DaVis ``.vc7`` files of a 47 MP camera's size, side by side with the floor any tool pays: the
same files read by lvpyio and summed by numpy into the mean and the covariance (Welford), in one
run.

The fields are the synthetic layer's exact fields (``tests/vector_series_cases.py``) on the
grid DaVis gives an 8864 x 5288 px frame with 32 px windows at 50 % overlap (16 px: 553 x 330
vectors), written once; each is a copy of its own (DaVis' buffer is cached per file, so copies
of one file would not be read again). rspiv's figure covers everything its reduction does: the
reading, the screen's bounds from 20 fields and the screen, the accumulator (moments to order
8, the lag-1 chains, the uncertainties' sums), the wall and the boundary-layer analysis; a
second run with the screen off shows the screen's cost (its pilot reads 20 fields more).

Usage::

    python benches/bench_vector_statistics.py [--fields 200] [--workdir /tmp/rspiv-vstat]

Prints a Markdown table (fields per second, the ratio to the floor, peak memory) for
``benches/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import pathlib
import resource
import shutil
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))


def _write(workdir: pathlib.Path, n: int) -> list[pathlib.Path]:
    from vector_series_cases import exact_field, write_vc7

    workdir.mkdir(parents=True, exist_ok=True)
    files = sorted(workdir.glob("B*.vc7"))
    if len(files) >= n:
        return files[:n]
    seeds = 4  # four distinct fields at full size, copied: the reading is what is timed
    first = []
    for s in range(seeds):
        tr, _, _, u, v = exact_field(s, scale=1.0)
        first.append(write_vc7(workdir / f"B{s:05d}.vc7", u, v, 1 / tr.magnification, tr.dt))
    for k in range(seeds, n):
        shutil.copyfile(first[k % seeds], workdir / f"B{k:05d}.vc7")
    return sorted(workdir.glob("B*.vc7"))[:n]


def _floor(files: list[pathlib.Path]) -> float:
    """lvpyio + numpy: the mean and covariance of u, v over the valid vectors (Welford)."""
    import lvpyio as lv

    t0 = time.perf_counter()
    n = mu = mv = suu = svv = suv = None
    for f in files:
        frame = lv.read_buffer(str(f))[0]
        u = np.asarray(frame.components["U0"][0], np.float64)
        v = np.asarray(frame.components["V0"][0], np.float64)
        ok = np.asarray(frame.enabled[0]) != 0
        if n is None:
            n = np.zeros(u.shape)
            mu, mv, suu, svv, suv = (np.zeros(u.shape) for _ in range(5))
        n += ok
        du = np.where(ok, u - mu, 0.0)
        dv = np.where(ok, v - mv, 0.0)
        mu += du / np.maximum(n, 1)
        mv += dv / np.maximum(n, 1)
        suu += du * np.where(ok, u - mu, 0.0)
        svv += dv * np.where(ok, v - mv, 0.0)
        suv += du * np.where(ok, v - mv, 0.0)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", type=int, default=200)
    ap.add_argument("--workdir", default="/tmp/rspiv-vstat")
    args = ap.parse_args()
    from rspiv.synth.tbl import TBLFlow
    from rspiv.vector_statistics import vector_statistics

    files = _write(pathlib.Path(args.workdir), args.fields)
    floor = _floor(files)
    t0 = time.perf_counter()
    r = vector_statistics(files, nu=TBLFlow().nu)
    rs = time.perf_counter() - t0
    t0 = time.perf_counter()
    vector_statistics(files, nu=TBLFlow().nu, screen=0)
    bare = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ny, nx = r.accumulator.shape
    print(f"{len(files)} DaVis fields of {nx} x {ny} vectors; u_tau {r.result.u_tau:.4f} m/s")
    print("| | s | fields/s | ratio |")
    print("|---|---|---|---|")
    print(f"| lvpyio + numpy mean/cov (floor) | {floor:.2f} | {len(files) / floor:.1f} | 1 |")
    print(f"| rspiv.vector_statistics | {rs:.2f} | {len(files) / rs:.1f} | {rs / floor:.2f} |")
    print(
        f"| rspiv, screen off (no pilot) | {bare:.2f} | {len(files) / bare:.1f} "
        f"| {bare / floor:.2f} |"
    )
    print(f"peak RSS {peak:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
