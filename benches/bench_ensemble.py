"""Ensemble band cost and memory on the full 8864 x 5288 sensor (issue 13).

Run: ``python benches/bench_ensemble.py [--pairs N] [--band PX]``. Renders one synthetic
boundary-layer pair at the paper's scale (``rspiv.synth.tbl_pair``, no lens: the timing does not
depend on it), then, in one run, times per pair

- the instantaneous PIV of the pair (``rspiv.piv``, 64x64 -> 32x32 -> 32x8, 50 % overlap,
  symmetric deformation as in the campaign defaults), and
- adding the pair to an ensemble band at the wall (``rspiv.EnsembleAccumulator`` with the
  campaign's defaults: 64 x 4 px windows every 64 x 2 px, ``band`` px from the wall, deformed
  by the wall-parallel profile; the auto planes as in the first ``auto_pairs`` pairs and without
  them as in the rest),

- adding the pair to single-pixel rows at the wall (``rspiv.ensemble.PixelAccumulator`` with
  the campaign's defaults: rows every 0.5 px up to ``--pixel-band`` px, 64 px segments, lags
  +-8 x +-3, the reflection beyond the wall masked),

and prints the ratios (the issue's limit: the band <= 25 % of the PIV), the accumulator's size
and the process's peak RSS (limit: <= 1 GB for a 600 px band).
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import rspiv
from rspiv.ensemble import (
    EnsembleAccumulator,
    PixelAccumulator,
    band_grid,
    pixel_band,
    profile_field,
)
from rspiv.synth import tbl_pair


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3, help="timed repetitions")
    ap.add_argument("--band", type=float, default=600.0, help="band height, px")
    ap.add_argument("--no-piv", action="store_true", help="time the band alone (its memory)")
    ap.add_argument("--pixel-band", type=float, default=10.0, help="single-pixel rows, px")
    args = ap.parse_args()
    t = time.perf_counter()
    a, b, truth = tbl_pair(scale=1.0, seed=1, lens=None, wall_angle_deg=0.0)
    print(f"render {a.shape[1]} x {a.shape[0]}: {time.perf_counter() - t:.1f} s")
    window = (64, 4)
    x, y, dist = band_grid(a.shape, window, (64, 2), args.band, truth.wall_y0_px, "above")
    dd = np.arange(0.5, args.band + 32, 1.0)
    prof = truth.mean_displacement_px(dd)
    field = profile_field(a.shape, truth.wall_y0_px, "above", dd, prof, 0 * prof, dx=64)
    acc = EnsembleAccumulator(x, y, window, deform=field)
    print(
        f"band {args.band:g} px: {x.size} windows ({x.shape[0]} rows x {x.shape[1]}), "
        f"accumulator {acc.acc.nbytes / 1e6:.0f} MB"
    )
    rows = np.arange(0.5, args.pixel_band + 1e-9, 0.5)
    py, px0, pd = pixel_band(a.shape, 64, rows, truth.wall_y0_px, "above", margin_x=32)
    pdu = truth.mean_displacement_px(pd)
    pix = PixelAccumulator(py, 64, px0, (pdu[:, None], 0.0), wall=(truth.wall_y0_px, "above"))
    print(f"single-pixel: {py.shape[0]} rows x {py.shape[1]} segments of 64 px")
    t_piv, t_auto, t_cross, t_pix = [], [], [], []
    for _ in range(args.pairs):
        t = time.perf_counter()
        if not args.no_piv:
            rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5,
                      deformation="symmetric")  # fmt: skip
        t_piv.append(time.perf_counter() - t)
        t = time.perf_counter()
        acc.add(a, b, auto=True)
        t_auto.append(time.perf_counter() - t)
        t = time.perf_counter()
        acc.add(a, b, auto=False)
        t_cross.append(time.perf_counter() - t)
        t = time.perf_counter()
        pix.add(a, b, auto=True)
        t_pix.append(time.perf_counter() - t)
    piv, auto, cross, pixel = (float(np.median(v)) for v in (t_piv, t_auto, t_cross, t_pix))
    if not args.no_piv:
        print(f"instantaneous PIV per pair: {piv:.2f} s")
    for name, v in (("with auto planes", auto), ("cross only", cross)):
        share = "" if args.no_piv else f" ({100 * v / piv:.0f} % of the PIV)"
        print(f"ensemble band per pair, {name}: {v:.2f} s{share}")
    share = "" if args.no_piv else f" ({100 * pixel / piv:.1f} % of the PIV)"
    print(f"single-pixel rows per pair, with auto planes: {pixel:.3f} s{share}")
    t = time.perf_counter()
    res = acc.result(rows=True)
    print(f"fit of {x.shape[0]} rows: {time.perf_counter() - t:.2f} s, ok {int(res.ok.sum())}")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
