"""Lamb-Oseen fits of vortices near another, single and joint (:func:`rspiv.fit_oseen` with
``joint`` False; :func:`rspiv.vortices.confirm_splits` of the cores found without and with
``split``, as a campaign fits them), against the planted vortices of the synthetic boundary
layer.

Each field is the synthetic layer's exact displacement at a DaVis grid (16 px,
``tests/vector_series_cases.exact_field``) with ``--per-field`` prograde Lamb-Oseen vortices
(r_c 40 px, peak swirl 8 px) planted at random 0.15-0.6 delta_99 from the wall. The fits are
made to the fluctuations about the exact mean of the same fields without vortices, so that only
the neighbours make a fit differ from a lone vortex's; the cores are
:func:`rspiv.find_vortices` of their swirling strength at 1.5 times the field's rms. For each
planted vortex, the kept fit nearest it (within its core radius) is compared with it, grouped
by the distance to its nearest planted neighbour.

Usage::

    python benches/oseen_neighbours.py [--fields 80] [--per-field 5]

Prints a Markdown table (for benches/RESULTS.md): the planted vortices, those found (a kept fit
within their core radius), and medians of the relative errors of r_c and Gamma, and in
brackets the 75th percentile of their absolute values.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
from rspiv.derivatives import gradients, swirl_from_gradients
from rspiv.vortices import SPLIT_SADDLE, confirm_splits, find_vortices, fit_oseen

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from vector_series_cases import exact_field  # noqa: E402

RC, SWIRL = 40.0, 8.0  # px: the planted core radius and peak azimuthal displacement
BANDS = ((4.0, np.inf), (3.25, 4.0), (2.5, 3.25), (2.0, 2.5), (0.0, 2.0))  # nearest neighbour, r_c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", type=int, default=80)
    ap.add_argument("--per-field", type=int, default=5)
    args = ap.parse_args()
    fields, mean = [], None
    for s in range(args.fields):
        _, x, y, u0, v0 = exact_field(s)
        tr, _, _, u, v = exact_field(s, vortices=args.per_field, vortex_radius_px=RC,
                                     vortex_swirl_px=SWIRL)  # fmt: skip
        mean = (u0, v0) if mean is None else (mean[0] + u0, mean[1] + v0)
        fields.append((u, v, tr.vortices))
    mu, mv = mean[0] / args.fields, mean[1] / args.fields
    xs, ys = x[0], y[:, 0]
    dx, dy = xs[1] - xs[0], ys[1] - ys[0]
    spacing: list[float] = []  # per planted vortex: its nearest neighbour in r_c
    rows = {False: [], True: []}  # per planted vortex: r_c error, Gamma error, neighbour, joint
    for u, v, planted in fields:
        du, dv = u - mu, v - mv
        g = gradients(du, dv, dx, dy)
        sw = swirl_from_gradients(g, signed=True)
        find = {"x": xs, "y": ys, "min_vectors": 4}
        thr = 1.5 * np.sqrt(np.nanmean(sw**2))
        cores = find_vortices(sw, g["dvdx"] - g["dudy"], thr, dx, dy, **find)
        parts = find_vortices(sw, g["dvdx"] - g["dudy"], thr, dx, dy, **find, split=SPLIT_SADDLE)
        centres = np.array([(p[0], p[1]) for p in planted])
        for i in range(len(planted)):  # every planted vortex's nearest planted neighbour
            d = np.hypot(*(centres - centres[i]).T)
            d[i] = np.inf
            spacing.append(d.min() / planted[i][3])
        for joint in (False, True):
            if joint:  # as a campaign fits: regions split where their parts fit as vortices
                _, f = confirm_splits(du, dv, cores, parts, dx, dy, x=xs, y=ys)
            else:
                f = fit_oseen(du, dv, cores, dx, dy, x=xs, y=ys, joint=False)
            k = np.flatnonzero(f["ok"])
            for i, (xc, yc, gamma, rc) in enumerate(planted):
                d = np.hypot(centres[:, 0] - xc, centres[:, 1] - yc)
                d[i] = np.inf
                near = np.hypot(f["x"][k] - xc, f["y"][k] - yc)
                if not near.size or near.min() > rc:
                    continue  # not kept
                a = k[np.argmin(near)]
                rows[joint].append((f["radius"][a] / rc - 1,
                                    abs(f["circulation"][a]) / abs(gamma) - 1,
                                    d.min() / rc, bool(f["joint"][a])))  # fmt: skip
    print(f"{args.fields} fields, {args.per_field} planted vortices each\n")
    print("| nearest planted neighbour | planted | found, single / joint | r_c, single | "
          "r_c, joint | Gamma, single | Gamma, joint | fitted jointly |")
    print("|---|---|---|---|---|---|---|---|")
    spacing_a = np.array(spacing)
    for lo, hi in BANDS:
        cells = []
        for joint in (False, True):
            r = np.array(rows[joint], float).reshape(-1, 4)
            cells.append(r[(r[:, 2] >= lo) & (r[:, 2] < hi)])
        if not cells[0].size:
            continue

        def fmt(e: np.ndarray) -> str:
            return f"{100 * np.median(e):+.1f} % ({100 * np.quantile(np.abs(e), 0.75):.1f})"

        band = f"beyond {lo:g} r_c" if np.isinf(hi) else f"{lo:g}-{hi:g} r_c"
        planted_n = int(np.count_nonzero((spacing_a >= lo) & (spacing_a < hi)))
        print(f"| {band} | {planted_n} | {len(cells[0])} / {len(cells[1])} | "
              f"{fmt(cells[0][:, 0])} | {fmt(cells[1][:, 0])} | "
              f"{fmt(cells[0][:, 1])} | {fmt(cells[1][:, 1])} | "
              f"{int(cells[1][:, 3].sum())} of {len(cells[1])} |")


if __name__ == "__main__":
    main()
