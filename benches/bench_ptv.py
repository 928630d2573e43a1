"""Particle tracking side by side: rspiv against trackpy (and a scipy baseline), one run.

A 2048 x 2048 synthetic pair whose particle positions and displacements are known (Gaussian
particle images of 2.5 px integrated over the pixels, 0.02 per px^2, 5 % noise, 12-bit; a shear
flow u = 3 + 4 y / 2048 px with per-particle fluctuations of 0.2 px rms). For each tool:

- **detection**: the time to find one frame's particle images and their centres, the share of
  the isolated particles found (no other within 6 px) and the rms error of their centres;
- **tracking**: the time to pair A's images with B's given the mean flow as the predictor
  (rspiv: ``track_particles`` with the flow's mean as a function; trackpy: ``link`` on B's
  positions moved back by the same prediction, search range = rspiv's radius; scipy: the
  nearest neighbour of the prediction within the radius, ``cKDTree``), the pairs, the share
  wrong (more than 0.5 px from the truth) and the rms error of the rest.

Run: ``python benches/bench_ptv.py`` (trackpy from PyPI; skipped when it is missing).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rspiv import _rspiv
from rspiv.ptv import detect_particles, track_particles
from scipy import ndimage
from scipy.spatial import cKDTree

SIZE, DENSITY, DIAMETER, NOISE, RADIUS = 2048, 0.02, 2.5, 0.05, 2.0


def _mean(x, y):
    return 3.0 + 4.0 * y / SIZE, 0.0 * y


def scene(seed: int = 0):
    rng = np.random.default_rng(seed)
    n = rng.poisson(DENSITY * (SIZE + 20) ** 2)
    xm, ym = rng.uniform(-10, SIZE + 10, n), rng.uniform(-10, SIZE + 10, n)
    u0, v0 = _mean(xm, ym)
    u, v = u0 + 0.2 * rng.normal(size=n), v0 + 0.2 * rng.normal(size=n)
    peak = 0.8 * 4095 * rng.uniform(0.6, 1.0, n)
    sigma = NOISE * 0.8 * 4095 * 0.8
    frames = [
        _rspiv.render_particles(SIZE, SIZE, xm + s * u, ym + s * v, peak,
                                np.array([DIAMETER]), sigma, 4095, seed + k)
        for k, s in ((1, -0.5), (2, 0.5))
    ]  # fmt: skip
    return frames, np.c_[xm - 0.5 * u, ym - 0.5 * v], np.c_[u, v]


def _isolated(truth: np.ndarray) -> np.ndarray:
    d, _ = cKDTree(truth).query(truth, k=2)
    inside = np.all((truth > 4) & (truth < SIZE - 5), axis=1)
    return (d[:, 1] > 6.0) & inside


def _detection(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    iso = _isolated(truth)
    d, _ = cKDTree(found).query(truth[iso])
    hit = d < 1.0
    return float(hit.mean()), float(np.sqrt(np.mean(d[hit] ** 2)))


def _tracking(xa, ua, truth_a, truth_u) -> tuple[float, float]:
    _, i = cKDTree(truth_a).query(xa)
    err = np.hypot(*(ua - truth_u[i]).T)
    wrong = err > 0.5
    return float(wrong.mean()), float(np.sqrt(np.mean(err[~wrong] ** 2)))


def _best(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def scipy_detect(frame: np.ndarray) -> np.ndarray:
    """Local maxima of 3 x 3 above 4 sigma of a global background, 3-point Gaussian centres."""
    f = frame.astype(np.float64)
    b = np.median(f)
    s = 1.4826 * np.median(np.abs(f - b))
    peak = (f == ndimage.maximum_filter(f, size=3)) & (f > b + 4 * s)
    peak[[0, -1], :] = peak[:, [0, -1]] = False
    y, x = np.nonzero(peak)
    g = np.log(np.maximum(f - b, 1e-3))
    c = g[y, x]
    dx = (g[y, x - 1] - g[y, x + 1]) / (2 * (g[y, x - 1] - 2 * c + g[y, x + 1]))
    dy = (g[y - 1, x] - g[y + 1, x]) / (2 * (g[y - 1, x] - 2 * c + g[y + 1, x]))
    ok = np.isfinite(dx) & np.isfinite(dy) & (np.abs(dx) <= 0.5) & (np.abs(dy) <= 0.5)
    return np.c_[x[ok] + dx[ok], y[ok] + dy[ok]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    (a, b), truth_a, truth_u = scene()
    rows = []

    t_det, pa = _best(lambda: detect_particles(a), args.repeat)
    pb = detect_particles(b)
    rec, rms = _detection(np.c_[pa.x, pa.y], truth_a)
    t_trk, tr = _best(lambda: track_particles(pa, pb, _mean, radius=RADIUS), args.repeat)
    xa = np.c_[tr.x - 0.5 * tr.u, tr.y - 0.5 * tr.v]
    wrong, err = _tracking(xa, np.c_[tr.u, tr.v], truth_a, truth_u)
    rows.append(("rspiv", t_det, rec, rms, t_trk, len(tr), wrong, err))

    t_sd, fa = _best(lambda: scipy_detect(a), args.repeat)
    fb = scipy_detect(b)
    rec_s, rms_s = _detection(fa, truth_a)

    def nn():
        du, dv = _mean(fa[:, 0], fa[:, 1])
        pred = fa + np.c_[du, dv]
        d, j = cKDTree(fb).query(pred, distance_upper_bound=RADIUS)
        ok = np.isfinite(d)
        return fa[ok], fb[j[ok]] - fa[ok]

    t_sn, (sa, su) = _best(nn, args.repeat)
    wrong_s, err_s = _tracking(sa, su, truth_a, truth_u)
    rows.append(("scipy (maximum_filter, nearest neighbour)", t_sd, rec_s, rms_s, t_sn, len(sa),
                 wrong_s, err_s))  # fmt: skip

    try:
        import pandas as pd
        import trackpy as tp
    except ImportError:
        print("trackpy is not installed: its rows are left out")
    else:
        tp.quiet()
        t_td, la = _best(lambda: tp.locate(a, 5, preprocess=False), args.repeat)
        lb = tp.locate(b, 5, preprocess=False)
        rec_t, rms_t = _detection(la[["x", "y"]].to_numpy(), truth_a)

        def link():
            fa_ = la[["x", "y"]].assign(frame=0)
            du, dv = _mean(lb["x"].to_numpy(), lb["y"].to_numpy())
            # B moved back by the prediction: the link's search range is the residual's
            fb_ = lb[["x", "y"]].assign(frame=1, x=lb["x"] - du, y=lb["y"] - dv)
            linked = tp.link(pd.concat([fa_, fb_], ignore_index=True), RADIUS, memory=0)
            g = linked.groupby("particle")
            both = g.filter(lambda s: len(s) == 2).sort_values(["particle", "frame"])
            p0 = both[both.frame == 0][["x", "y"]].to_numpy()
            p1 = both[both.frame == 1][["x", "y"]].to_numpy()
            du1, dv1 = _mean(p1[:, 0], p1[:, 1])
            return p0, p1 + np.c_[du1, dv1] - p0

        t_tl, (ta, tu) = _best(link, 1)
        wrong_t, err_t = _tracking(ta, tu, truth_a, truth_u)
        rows.append(("trackpy (locate, link)", t_td, rec_t, rms_t, t_tl, len(ta), wrong_t, err_t))

    print(f"{SIZE} x {SIZE} px, {DENSITY} particles/px^2, {DIAMETER} px, {NOISE:.0%} noise; "
          f"{len(truth_a)} particles, radius {RADIUS} px")  # fmt: skip
    print("| tool | detect one frame (s) | isolated found | centre rms (px) | track (s) | "
          "pairs | wrong | displacement rms (px) |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]:.3f} | {100 * r[2]:.1f} % | {r[3]:.4f} | {r[4]:.3f} | {r[5]} | "
              f"{100 * r[6]:.2f} % | {r[7]:.4f} |")  # fmt: skip
    base = rows[0]
    for r in rows[1:]:
        print(f"rspiv against {r[0]}: detection {r[1] / base[1]:.1f}x, tracking "
              f"{r[4] / base[4]:.1f}x")  # fmt: skip


if __name__ == "__main__":
    main()
