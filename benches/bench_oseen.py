"""Lamb-Oseen fits of a field's vortex cores: :func:`rspiv.fit_oseen` (Levenberg-Marquardt with
an analytic Jacobian, core by core in Rust, cores in parallel: ``piv_core::vortex_fit``) beside
``scipy.optimize.least_squares`` (its trust-region reflective solver, the same model and
Jacobian by its own finite differences) core by core on the same patches, in one run; the fitted
core radii and circulations are compared.

The field: ``--vortices`` Lamb-Oseen vortices (r_c 12-30 px, |Gamma| 150-400 px^2 per pair, both
signs) at random places on a ``--rows`` x ``--cols`` grid of 8 px (660 x 1100: a 47 MP frame's
8 px grid), 0.05 px of noise; the cores are :func:`rspiv.find_vortices` of its swirling strength
at 1.5 times its rms.

Usage::

    python benches/bench_oseen.py [--vortices 600] [--rows 660] [--cols 1100] [--peer 200]

``--peer``: the cores scipy fits (the first ones; its time is scaled to all of them).
Prints a Markdown table (for benches/RESULTS.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rspiv.derivatives import swirling_strength, vorticity
from rspiv.vortices import find_vortices, fit_oseen, oseen_velocity

H = 8.0  # grid step, px


def field(n: int, ny: int, nx: int, seed: int = 3):
    """u, v (pixel frame) of ``n`` random Lamb-Oseen vortices with noise, and the vortices
    (rows ``x, y, r_c, Gamma``: px, Gamma counter-clockwise on the screen)."""
    rng = np.random.default_rng(seed)
    x = H * np.arange(nx)[None, :]
    y = H * np.arange(ny)[:, None]
    u, v = np.zeros((ny, nx)), np.zeros((ny, nx))
    planted = []
    for _ in range(n):
        xc, yc = rng.uniform(0, nx * H), rng.uniform(0, ny * H)
        rc = rng.uniform(12, 30)
        gamma = rng.choice([-1.0, 1.0]) * rng.uniform(150, 400)
        planted.append((xc, yc, rc, gamma))
        i0, i1 = max(0, int((yc - 8 * rc) / H)), int((yc + 8 * rc) / H) + 1
        j0, j1 = max(0, int((xc - 8 * rc) / H)), int((xc + 8 * rc) / H) + 1
        uu, vu = oseen_velocity(x[:, j0:j1], -y[i0:i1], xc, -yc, gamma, rc)
        u[i0:i1, j0:j1] += uu
        v[i0:i1, j0:j1] -= vu
    noise = 0.05 * rng.standard_normal((2, *u.shape))
    return u + noise[0], v + noise[1], np.array(planted)


def against_planted(f: dict, planted: np.ndarray) -> str:
    """The kept fits against the planted vortex nearest each (within its r_c): median errors
    of r_c and Gamma."""
    ok = f["ok"]
    d = np.hypot(f["x"][ok, None] - planted[None, :, 0], f["y"][ok, None] - planted[None, :, 1])
    j = np.argmin(d, axis=1)
    on = d[np.arange(j.size), j] <= planted[j, 2]
    e_rc = np.abs(f["radius"][ok][on] / planted[j[on], 2] - 1)
    e_g = np.abs(f["circulation"][ok][on] / planted[j[on], 3] - 1)
    return (f"{int(on.sum())} on a planted vortex, {int((~on).sum())} elsewhere; median error "
            f"of r_c {np.median(e_rc):.3f}, of Gamma {np.median(e_g):.3f}")  # fmt: skip


def scipy_fits(u, v, cores, n: int):
    """The same fits with scipy, core by core (the first ``n``): r_c and Gamma."""
    from scipy.optimize import least_squares

    ny, nx = u.shape
    out = []
    for k in range(n):
        j0, i0 = cores["x"][k] / H, cores["y"][k] / H
        big = max(2.5 * cores["radius"][k], 2 * H)
        h = int(np.ceil(big / H))
        jj, ii = np.meshgrid(np.arange(round(j0) - h, round(j0) + h + 1),
                             np.arange(round(i0) - h, round(i0) + h + 1))  # fmt: skip
        px, py = H * jj, -H * ii
        sel = ((jj >= 0) & (jj < nx) & (ii >= 0) & (ii < ny)
               & ((px - H * j0) ** 2 + (py + H * i0) ** 2 <= big**2))  # fmt: skip
        px, py = px[sel], py[sel]
        pu, pv = u[ii[sel], jj[sel]], -v[ii[sel], jj[sel]]

        def res(t, px=px, py=py, pu=pu, pv=pv):
            mu, mv = oseen_velocity(px, py, t[0], t[1], t[2], np.exp(t[3]), t[4], t[5])
            return np.concatenate([mu - pu, mv - pv])

        g0 = cores["sign"][k] * 2.5 * abs(cores["circulation"][k])
        t0 = [H * j0, -H * i0, g0, np.log(cores["radius"][k]), np.median(pu), np.median(pv)]
        t = least_squares(res, t0).x
        out.append((np.exp(t[3]), t[2]))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vortices", type=int, default=600)
    ap.add_argument("--rows", type=int, default=660)
    ap.add_argument("--cols", type=int, default=1100)
    ap.add_argument("--peer", type=int, default=200)
    args = ap.parse_args()
    u, v, planted = field(args.vortices, args.rows, args.cols)
    s = swirling_strength(u, v, H, H, signed=True)
    w = vorticity(u, v, H, H)
    cores = find_vortices(s, w, 1.5 * np.sqrt(np.nanmean(s**2)), H, H, min_vectors=7)
    n = cores["x"].size
    fit_oseen(u, v, {k: a[:8] for k, a in cores.items()}, H, H)  # warm up
    t = time.perf_counter()
    f = fit_oseen(u, v, cores, H, H)
    t_rspiv = time.perf_counter() - t
    t = time.perf_counter()
    fs = fit_oseen(u, v, cores, H, H, shear=True)
    t_shear = time.perf_counter() - t
    m = min(args.peer, n)
    t = time.perf_counter()
    peer = scipy_fits(u, v, cores, m)
    t_peer = (time.perf_counter() - t) * n / m
    ok = f["ok"][:m]
    d_rc = np.abs(f["radius"][:m][ok] / peer[ok, 0] - 1)
    d_g = np.abs(f["circulation"][:m][ok] / peer[ok, 1] - 1)
    print(f"{n} cores on {args.rows} x {args.cols} vectors; {int(f['ok'].sum())} fits kept")
    print("\n| fits of every core | time (s) | per core (ms) |")
    print("|---|---:|---:|")
    print(f"| rspiv.fit_oseen (Rust, cores in parallel) | {t_rspiv:.3f} | "
          f"{1e3 * t_rspiv / n:.3f} |")  # fmt: skip
    print(f"| rspiv.fit_oseen with the background shear (7 parameters) | {t_shear:.3f} | "
          f"{1e3 * t_shear / n:.3f} |")  # fmt: skip
    print(f"| scipy least_squares per core ({m} timed, scaled) | {t_peer:.2f} | "
          f"{1e3 * t_peer / n:.2f} |")  # fmt: skip
    print(f"\nratio {t_peer / t_rspiv:.1f}x; over the {int(ok.sum())} kept of the first {m}: "
          f"r_c agrees to {np.median(d_rc):.1e} (median), {d_rc.max():.1e} (max); Gamma to "
          f"{np.median(d_g):.1e}, {d_g.max():.1e}")  # fmt: skip
    print(f"against the planted vortices: {against_planted(f, planted)}; with the background "
          f"shear: {against_planted(fs, planted)}")  # fmt: skip
    both = f["ok"] & fs["ok"]
    moved = np.median(np.abs(fs["radius"][both] / f["radius"][both] - 1))
    print(f"with the background shear: {int(fs['ok'].sum())} kept; on the {int(both.sum())} "
          f"kept by both, r_c moves by {moved:.1e} (median), |shear| "
          f"{np.median(np.abs(fs['shear'][both])):.1e} 1/pair (median)")  # fmt: skip


if __name__ == "__main__":
    main()
