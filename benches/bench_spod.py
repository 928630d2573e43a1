"""Spectral POD of a time-resolved recording: :func:`rspiv.spod` (the snapshot method: each
block's transform once, a ``K x K`` matrix per frequency) beside the direct route with scipy,
the full ``D x D`` cross-spectral density matrix (``scipy.signal.csd`` of every value against
every other, broadcast in one call) and its eigenvalues (``numpy.linalg.eigvalsh``), in one run
on the same fields; the eigenvalues are compared (relative 1e-9 of the largest).

The fields are ``--pairs`` random fields of ``--rows`` x ``--cols`` vectors (Gaussian, a
travelling wave on top, 3 % rejected and filled with the mean), blocks of ``--segment`` pairs at
half overlap. The direct route's memory grows as ``D^2`` per frequency (``D = 2`` values per
vector), its work as ``D^3``: it runs only while ``D <= --peer-max``; rspiv is timed at every
size, up to a time-resolved camera's grid.

Usage::

    python benches/bench_spod.py [--pairs 1024] [--segment 128] [--peer-max 1200]

Prints a Markdown table (for benches/RESULTS.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rspiv.spod import spod


def fields(n: int, ny: int, nx: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, ny, nx))
    v = 0.5 * rng.standard_normal((n, ny, nx))
    t = np.arange(n)[:, None, None]
    u += np.cos(2 * np.pi * (0.05 * t - np.arange(nx)[None, None, :] / 12.0))
    valid = rng.random((n, ny, nx)) > 0.03
    return u, v, valid


def peer(u, v, valid, segment: int) -> np.ndarray:
    """The eigenvalues of scipy's full cross-spectral density matrix, (nf, D) decreasing."""
    from scipy.signal import csd

    n = u.shape[0]
    mu = np.where(valid, u, 0).sum(0) / valid.sum(0)
    mv = np.where(valid, v, 0).sum(0) / valid.sum(0)
    x = np.concatenate([np.where(valid, u - mu, 0).reshape(n, -1),
                        np.where(valid, v - mv, 0).reshape(n, -1)], axis=1)  # fmt: skip
    _, s = csd(x[:, None, :], x[:, :, None], window="hann", nperseg=segment,
               noverlap=segment // 2, detrend=False, axis=0)  # fmt: skip
    return np.linalg.eigvalsh(s)[:, ::-1]  # (nf, D, D): the frequency stays first


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=1024)
    ap.add_argument("--segment", type=int, default=128)
    ap.add_argument("--peer-max", type=int, default=1200, help="largest D for scipy's route")
    args = ap.parse_args()
    print(f"{args.pairs} pairs, blocks of {args.segment} at half overlap\n")
    print("| vectors (D = 2 x) | rspiv.spod s | scipy csd + eigvalsh s | ratio | max rel diff |")
    print("|---|---:|---:|---:|---:|")
    for ny, nx in ((10, 20), (20, 30), (64, 64), (127, 127)):
        u, v, valid = fields(args.pairs, ny, nx)
        mu = np.where(valid, u, 0).sum(0) / valid.sum(0)
        mv = np.where(valid, v, 0).sum(0) / valid.sum(0)
        t0 = time.perf_counter()
        r = spod(u, v, valid, segment=args.segment, mean_u=mu, mean_v=mv,
                 domain=np.ones((ny, nx), bool))  # fmt: skip
        t_r = time.perf_counter() - t0
        d = 2 * ny * nx
        if d <= args.peer_max:
            t0 = time.perf_counter()
            lam = peer(u, v, valid, args.segment)
            t_p = time.perf_counter() - t0
            k = r.blocks
            diff = np.abs(lam[:, :k] - r.energy).max() / lam.max()
            print(f"| {ny} x {nx} ({d}) | {t_r:.3f} | {t_p:.2f} | {t_p / t_r:.0f}x | "
                  f"{diff:.1e} |")  # fmt: skip
            assert diff < 1e-9
        else:
            print(f"| {ny} x {nx} ({d}) | {t_r:.3f} | (D^2 x {args.segment // 2 + 1} complex: "
                  f"{16 * d * d * (args.segment // 2 + 1) / 1e9:.0f} GB) | | |")  # fmt: skip


if __name__ == "__main__":
    main()
