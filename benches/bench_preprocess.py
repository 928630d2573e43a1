"""Image conditioning of a full 47 MP pair (8864 x 5288 uint16): rspiv side by side with OpenCV
and numpy/scipy doing the same steps.

    python benches/bench_preprocess.py [--repeat 3]

Steps timed per pair (frames A and B), each the best of ``--repeat`` interleaved runs, every
library on the same 2 threads (``cv2.setNumThreads(2)``, rayon's default pool):

- ``background``: minimum background subtraction (the run's background precomputed, not
  timed), float32 out, clipped at 0;
- ``background + min-max (15 px)``: the same plus the local min-max normalisation (running
  min/max over 15 x 15, both envelopes smoothed by a 15 x 15 box);
- ``high-pass (2 px)``: subtract a Gaussian of sigma 2 px (truncated at 3 sigma);
- ``near-wall default``: ``rspiv.preprocess.NEAR_WALL`` (hot pixels, background, high-pass).

OpenCV: ``cv2.subtract``/``np.maximum``, ``cv2.erode``/``cv2.dilate`` (rectangular 15 x 15:
running min/max) + ``cv2.blur``, ``cv2.GaussianBlur``; numpy does the arithmetic. rspiv computes
the min-max envelopes on 5 px cells (extreme over 3 x 3 cells, mean over 3 x 3 cells, bilinear
to each pixel: ``piv-core/src/condition.rs`` step 5), the same window and smoothing lengths
without running filters. Both sides' times include the conversion of the uint16 frame to
float32 (rspiv fuses it with the first step).
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from bench_piv import best_of  # the one best-of-n timer of the benches


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scale", type=float, default=1.0, help="sensor scale (1.0: 8864 x 5288)")
    args = ap.parse_args()

    import cv2
    from rspiv.preprocess import NEAR_WALL, Preprocess, condition

    cv2.setNumThreads(2)
    h, w = int(5288 * args.scale), int(8864 * args.scale)
    rng = np.random.default_rng(0)
    frames = [rng.integers(50, 4000, (h, w), dtype=np.uint16) for _ in range(2)]
    bgs = [np.full((h, w), 60.0, np.float32), np.full((h, w), 70.0, np.float32)]
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (15, 15))

    def cv_background():
        return [np.maximum(f.astype(np.float32) - b, 0) for f, b in zip(frames, bgs, strict=True)]

    def cv_minmax():
        out = []
        for g in cv_background():
            lo = cv2.blur(cv2.erode(g, kernel), (15, 15))
            hi = cv2.blur(cv2.dilate(g, kernel), (15, 15))
            out.append(np.clip((g - lo) / np.maximum(hi - lo, 1e-6), 0, 1))
        return out

    def cv_highpass():
        out = []
        for f in frames:
            g = f.astype(np.float32)
            out.append(g - cv2.GaussianBlur(g, (0, 0), 2.0, borderType=cv2.BORDER_REFLECT_101))
        return out

    def ours(pre, with_bg=True):
        if with_bg:
            return lambda: [condition(f, pre, b) for f, b in zip(frames, bgs, strict=True)]
        return lambda: [condition(f, pre) for f in frames]

    rows = [
        ("background", ours(Preprocess()), cv_background),
        ("background + min-max (15 px)", ours(Preprocess(min_max=15)), cv_minmax),
        ("high-pass (2 px)", ours(Preprocess(high_pass=2.0), with_bg=False), cv_highpass),
        ("near-wall default", ours(NEAR_WALL), None),
    ]
    print(f"pair {w} x {h} uint16, {os.cpu_count()} cpus, best of {args.repeat}")
    print(f"{'step':32s} {'rspiv':>9s} {'OpenCV':>9s} {'OpenCV/rspiv':>13s}")
    for name, ours, peer in rows:
        t_ours = best_of(ours, args.repeat)[0]
        if peer is None:
            print(f"{name:32s} {t_ours:8.3f}s {'-':>9s} {'-':>13s}")
            continue
        t_peer = best_of(peer, args.repeat)[0]
        print(f"{name:32s} {t_ours:8.3f}s {t_peer:8.3f}s {t_peer / t_ours:12.2f}x")


if __name__ == "__main__":
    main()
