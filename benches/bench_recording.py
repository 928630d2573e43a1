"""The recording check at 47 MP: ``rspiv.check_recording`` (the particle count of both frames in
Rust, the coarse pass, the recommendation) and its particle count alone, beside the count a user
writes with scipy (``scipy.ndimage.maximum_filter`` 3 x 3 local maxima above the frame's median
plus four robust sigmas, the sigma from the median absolute deviation), in one run on the same
synthetic pair of known density (:func:`rspiv.synth.particle_pair`: 0.03 particles/px of 2.5 px,
5 % noise, a uniform 12 x 1 px displacement).

Usage::

    python benches/bench_recording.py [--scale 1.0] [--density 0.03] [--repeat 2]

Prints a Markdown table (for benches/RESULTS.md): seconds (best of ``--repeat``), the density
found against the generator's and, for the whole check, the peak memory of the process.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np


def _best(f, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return best, out


def _scipy_count(frame: np.ndarray) -> float:
    from scipy import ndimage

    x = frame.astype(np.float32)
    med = float(np.median(x))
    sigma = 1.4826 * float(np.median(np.abs(x - med)))
    peaks = (x == ndimage.maximum_filter(x, size=3)) & (x > med + 4.0 * sigma)
    return float(np.count_nonzero(peaks[1:-1, 1:-1]) / ((x.shape[0] - 2) * (x.shape[1] - 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0, help="of the 8864 x 5288 px sensor")
    ap.add_argument("--density", type=float, default=0.03)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    from rspiv import _rspiv
    from rspiv.recording import BLOCK, K_NOISE, REL_SIGNAL, check_recording
    from rspiv.synth.particles import particle_pair

    h, w = int(round(5288 * args.scale)), int(round(8864 * args.scale))
    t = time.perf_counter()
    a, b = particle_pair((h, w), (12.0, 1.0), args.density, 2.5, 0.05, seed=7)
    print(f"# synthesised {w} x {h} px in {time.perf_counter() - t:.1f} s")
    rows = []
    t_check, check = _best(lambda: check_recording(a, b), args.repeat)
    rows.append(("rspiv.check_recording (both frames, coarse pass)", t_check, check.density))

    def count():
        s = _rspiv.seeding(a, BLOCK, K_NOISE, REL_SIGNAL, 4095.0)
        return float(s["peaks"].sum() / s["searched"].sum())

    t_count, counted = _best(count, args.repeat)
    rows.append(("rspiv particle count, one frame (uncorrected)", t_count, counted))
    t_sp, sp = _best(lambda: _scipy_count(a), args.repeat)
    rows.append(("scipy maximum_filter count, one frame (uncorrected)", t_sp, sp))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"| {w} x {h} px, {args.density} particles/px | s | density found / generator's |")
    print("|---|---:|---:|")
    for name, sec, dens in rows:
        print(f"| {name} | {sec:.2f} | {dens / args.density:.3f} |")
    print(
        f"\nrspiv's count {t_sp / t_count:.1f}x scipy's; the whole check {t_check:.2f} s; "
        f"recommended {check.passes}; peak RSS of the process {rss:.0f} MB (the pair "
        f"{2 * a.nbytes / 2**20:.0f} MB)"
    )


if __name__ == "__main__":
    main()
