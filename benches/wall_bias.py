"""The wall finder's error with the wall's place between vector rows (``rspiv.wall``).

    python benches/wall_bias.py [--scales 0.25 1.0] [--places 16] [--noise-trials 100]
                                [--piv 1.0 0.5 0.25] [--pairs 4]

Ground truth: the synthetic layer's mean displacement profile (``rspiv.synth.tbl``: the scene's
``mean_displacement_px`` of the distance from the wall), mirrored about the wall as the particle
reflections make it, sampled at rows ``h`` px apart as a PIV tool's vectors are: at points, or
averaged over windows (top-hat, ``window`` px tall, centred on the row). The wall is placed at
``places`` positions across one row spacing; for each, the wall finder's mirror position
(:func:`rspiv.wall.mirror_shift_positions`) with ``fit="resample"`` (the symmetric resampling
alone) and ``fit="joint"`` (the default: one smooth one-sided profile fitted to both sides).

Printed, per case: the error's peak to peak and largest magnitude over the wall's place (px),
and the time per station. Then the scatter with noise on each sample (Gaussian, a fraction of
the free stream's displacement), the wall 0.3 of a row past a row, and a tilted wall (0.3 deg)
read by :func:`rspiv.find_wall` from the mean of exact DaVis-grid fields
(``tests/vector_series_cases.py``: rows 16 px apart).

With ``--piv``: rendered pairs of the layer through the paper's lens (``rspiv.synth.tbl_pair``,
the wall at 0.04 deg, ``benches/wall_alignment.py``'s band), ``pairs`` of them through
``rspiv.piv`` on three grids (32 x 8 px windows at 75 % overlap: rows 2 px apart, as
:func:`rspiv.wall_table`; at 50 %: 4 px; 32 x 32 at 50 %: 16 px, another tool's usual grid),
``find_wall`` with 16 stations and each fit; the stations' error against the rendered wall (the
wall line pushed through the lens).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
import warnings

import numpy as np

CASES = (  # (rows apart px, window px (0: points), rows in the profile)
    (16, 0, 80),
    (16, 32, 80),
    (4, 8, 300),
    (2, 8, 600),
)


def profile(truth, d: np.ndarray, window: float) -> np.ndarray:
    """The mirrored mean displacement (px) at signed distances ``d`` (px) from the wall, at
    points (``window`` 0) or averaged over a ``window`` px tall top-hat."""
    if window == 0:
        return truth.mean_displacement_px(np.abs(d))
    s = np.linspace(-window / 2, window / 2, 129)
    return truth.mean_displacement_px(np.abs(d[..., None] + s)).mean(-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", type=float, nargs="+", default=[0.25, 1.0])
    ap.add_argument("--places", type=int, default=16)
    ap.add_argument("--noise-trials", type=int, default=100)
    ap.add_argument("--piv", type=float, nargs="*", default=[], help="scales of rendered pairs")
    ap.add_argument("--pairs", type=int, default=4)
    args = ap.parse_args()

    from rspiv.synth.tbl import tbl_scene
    from rspiv.wall import find_wall, mirror_shift_positions

    print("| scale | rows apart | samples | resampled: p-p / max (px) | joint fit: p-p / max (px) "
          "| ms per station (resampled / joint) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for scale in args.scales:
        truth = tbl_scene(scale, seed=0, lens=None)
        for h, window, nrows in CASES:
            place = np.arange(args.places) / args.places
            wall = (nrows // 2 + place) * h
            prof = profile(truth, (np.arange(nrows) * h)[:, None] - wall[None, :], window)
            cells = []
            for fit in ("resample", "joint"):
                t0 = time.perf_counter()
                pos, _ = mirror_shift_positions(prof, fit=fit)
                ms = (time.perf_counter() - t0) / len(wall) * 1e3
                err = pos * h - wall
                cells.append((np.ptp(err), np.max(np.abs(err)), ms))
            what = "points" if window == 0 else f"{window} px windows"
            print(f"| {scale:g} | {h} px | {what} | {cells[0][0]:.3f} / {cells[0][1]:.3f} | "
                  f"{cells[1][0]:.3f} / {cells[1][1]:.3f} | {cells[0][2]:.1f} / "
                  f"{cells[1][2]:.1f} |")  # fmt: skip

    rng = np.random.default_rng(1)
    truth = tbl_scene(args.scales[0], seed=0, lens=None)
    u_inf = float(truth.mean_displacement_px(np.array([1e5]))[0])
    print(f"\nNoise (scale {args.scales[0]:g}, free stream {u_inf:.1f} px, the wall 0.3 of a row "
          f"past a row, {args.noise_trials} trials): error mean / sd (px)\n")  # fmt: skip
    print("| rows apart | samples | noise / free stream | resampled | joint fit |")
    print("|---|---|---|---|---|")
    for h, window, nrows, sigma in ((16, 32, 80, 0.02), (16, 32, 80, 0.1), (2, 8, 600, 0.02)):
        wall = (nrows // 2 + 0.3) * h
        clean = profile(truth, np.arange(nrows) * h - wall, window)
        noisy = clean[:, None] + sigma * rng.standard_normal((nrows, args.noise_trials))
        cells = []
        for fit in ("resample", "joint"):
            err = mirror_shift_positions(noisy, fit=fit)[0] * h - wall
            cells.append(f"{np.mean(err):+.3f} / {np.std(err):.3f}")
        print(f"| {h} px | {window} px windows | {sigma / u_inf:.2%} | {cells[0]} | {cells[1]} |")

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
    from vector_series_cases import exact_field

    fields = [exact_field(s, angle=0.3) for s in range(10)]
    tr, x, y = fields[0][:3]
    u = np.mean([f[3] for f in fields], axis=0)
    print("\nA wall tilted by 0.3 deg, 10 exact fields (DaVis grid, rows 16 px apart, scale "
          "0.25), find_wall with 32 stations:\n")  # fmt: skip
    print("| fit | angle (deg) | station errors: max / rms (px) |")
    print("|---|---|---|")
    for fit in ("resample", "joint"):
        w = find_wall(u, y=y[:, 0], x=x[0], stations=32, fit=fit)
        err = (w.position_px - tr.wall_y(w.x_px))[w.valid]
        rms = np.sqrt(np.mean(err**2))
        print(f"| {fit} | {w.angle_deg:.4f} | {np.max(np.abs(err)):.2f} / {rms:.2f} |")
    if args.piv:
        rendered(args.piv, args.pairs)


GRIDS = (  # (name, passes, overlap)
    ("32 x 8, 75 % (2 px rows)", [(64, 64), (32, 32), (32, 8)], [0.5, 0.5, 0.75]),
    ("32 x 8, 50 % (4 px rows)", [(64, 64), (32, 32), (32, 8)], 0.5),
    ("32 x 32, 50 % (16 px rows)", [(64, 64), (32, 32)], 0.5),
)


def rendered(scales: list[float], n_pairs: int) -> None:
    """The stations' error against the rendered wall, per scale, grid and fit (module docs)."""
    import dataclasses

    import rspiv
    from rspiv.errors import InvalidInputError
    from rspiv.synth import PAPER_OPTICS, paper_lens, tbl_pair
    from rspiv.wall import find_wall

    print(f"\nRendered pairs through the paper's lens ({n_pairs} pairs, 16 stations): the "
          "stations' error against the rendered wall, mean / rms / max (px)\n")  # fmt: skip
    print("| scale | grid | resampled | joint fit |")
    print("|---|---|---|---|")
    for s in scales:
        optics = PAPER_OPTICS.scaled(s) if s != 1.0 else PAPER_OPTICS
        lens = paper_lens(optics)
        pairs = [tbl_pair(scale=s, seed=k, lens=lens, wall_angle_deg=0.04) for k in range(n_pairs)]
        truth = pairs[0][2]
        h, w = truth.shape
        yw = truth.wall_y0_px
        r0, r1 = int(yw - 160 * s - 40), min(h, int(yw + 100 * s + 40))
        band = (yw - 120 * s - 20, yw + 80 * s + 20)
        xs = np.linspace(0, w - 1, 1000)
        line = truth.to_image(np.column_stack([xs, truth.wall_y(xs)]))
        for name, passes, overlap in GRIDS:
            fields = []
            for a, b, _ in pairs:
                a, b = np.ascontiguousarray(a[r0:r1]), np.ascontiguousarray(b[r0:r1])
                with warnings.catch_warnings():  # 10-15 % replaced at 0.25-0.5 scale: known
                    warnings.simplefilter("ignore", rspiv.CorrelationWarning)
                    f = rspiv.piv(a, b, passes=passes, overlap=overlap)
                fields.append(dataclasses.replace(f, y=f.y + r0))
            cells = []
            for fit in ("resample", "joint"):
                try:
                    wl = find_wall(fields, band=band, stations=16, fit=fit)
                except InvalidInputError as exc:  # a band of a few rows: no reflection seen
                    cells.append(f"refused ({str(exc).split(': ')[1]})")
                    continue
                e = (wl.position_px - np.interp(wl.x_px, line[:, 0], line[:, 1]))[wl.valid]
                cells.append(f"{e.mean():+.3f} / {np.sqrt(np.mean(e**2)):.3f} / "
                             f"{np.abs(e).max():.3f}")  # fmt: skip
            print(f"| {s:g} | {name} | {cells[0]} | {cells[1]} |", flush=True)


if __name__ == "__main__":
    main()
