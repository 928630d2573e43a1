"""Conditional averages at 47 MP: :class:`rspiv.ConditionalAccumulator` (each field's map rows
Fourier-transformed along the row once, the sums over the events as correlations of their
indicator with the rows) beside the obvious peer in numpy, a gather of every event's patch
(``np.take`` of the map's rows at ``c + offsets`` for all events at once, then sums over the
events), in one run on the same fields; the two maps are compared (relative 1e-9).

The fields are generated on the 47 MP campaign's grid (``--rows`` x ``--cols`` vectors: 32 x 8
px windows at 50 % overlap on 8864 x 5288 px), Gaussian fluctuations about zero with 3 %
rejected, with the campaign's default plan for a layer whose delta_99 is ``--delta`` px: the
references at 0.15 and 0.4 delta_99, the map's rows from 20 px to 0.8 delta_99, offsets as far
either way (at most 161 x 161 points).

Usage::

    python benches/bench_conditional.py [--fields 20] [--rows 1321] [--cols 553]
        [--delta 3000]

Prints a Markdown table (for benches/RESULTS.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rspiv.conditional import ConditionalAccumulator


def peer(acc: ConditionalAccumulator, fields) -> tuple[np.ndarray, np.ndarray]:
    """The conditional average of u' by gathering each event's patch (numpy)."""
    ny, nx = acc.shape
    shape = (acc.ref_rows.size, 2, acc.map_rows.size, acc.offsets.size)
    su, n = np.zeros(shape), np.zeros(shape)
    pad = acc.half_width
    for u, v, valid in fields:
        uf, vf, ok = acc.fluctuations(u, v, valid)
        up = np.pad(uf[acc.map_rows], ((0, 0), (pad, pad)))
        kp = np.pad(ok[acc.map_rows].astype(np.float64), ((0, 0), (pad, pad)))
        thr = acc.hole * acc.rms_u * acc.rms_v
        for i, r in enumerate(acc.ref_rows):
            big = ok[r] & (np.abs(uf[r] * vf[r]) >= thr[r])
            for k, ev in enumerate((big & (uf[r] < 0) & (vf[r] > 0),
                                    big & (uf[r] > 0) & (vf[r] < 0))):  # fmt: skip
                cols = np.flatnonzero(ev)[:, None] + pad + acc.offsets[None, :]
                su[i, k] += np.take(up, cols, axis=1).sum(axis=1)
                n[i, k] += np.take(kp, cols, axis=1).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return su / n, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fields", type=int, default=20)
    ap.add_argument("--rows", type=int, default=1321)
    ap.add_argument("--cols", type=int, default=553)
    ap.add_argument("--delta", type=float, default=3000.0, help="delta_99 in px")
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    ny, nx = args.rows, args.cols
    dy, dx = 4.0, 16.0  # the grid's spacing, px
    zero, one = np.zeros((ny, nx)), np.ones((ny, nx))
    refs = [int(round(0.15 * args.delta / dy)), int(round(0.4 * args.delta / dy))]
    band = (int(20 / dy), min(int(0.8 * args.delta / dy) + 1, ny))
    half = min(int(np.ceil(0.8 * args.delta / dx)), nx - 1)
    rho = -0.45  # u'v' / (u_rms v_rms) of a boundary layer's log region
    fields = []
    for _ in range(args.fields):
        u = rng.normal(size=(ny, nx))
        v = rho * u + np.sqrt(1 - rho**2) * rng.normal(size=(ny, nx))
        fields.append((u, v, rng.random((ny, nx)) > 0.03))
    print(f"grid {ny} x {nx} vectors, 2 heights x 2 kinds, rho {rho}; the maps agree\n")
    print("| hole H | events per field | map points | rspiv (FFT) ms | numpy gather ms | ratio |")
    print("|---|---:|---|---:|---:|---:|")
    for hole in (0.0, 1.0, 2.0):
        acc = ConditionalAccumulator(zero, zero, one, one, refs, rows=band, half_width=half,
                                     hole=hole)  # fmt: skip
        t0 = time.perf_counter()
        for u, v, valid in fields:
            acc.add(u, v, valid)
        t_rspiv = (time.perf_counter() - t0) / args.fields
        r = acc.results()
        t0 = time.perf_counter()
        cu, cn = peer(acc, fields)
        t_peer = (time.perf_counter() - t0) / args.fields
        np.testing.assert_array_equal(r["count"], cn)
        np.testing.assert_allclose(r["u"], cu, rtol=1e-9, atol=1e-12)
        events = int(r["events"].sum()) / args.fields
        print(f"| {hole:g} | {events:.0f} | {acc.map_rows.size} x {acc.offsets.size} | "
              f"{1e3 * t_rspiv:.1f} | {1e3 * t_peer:.1f} | {t_peer / t_rspiv:.1f}x |")  # fmt: skip


if __name__ == "__main__":
    main()
