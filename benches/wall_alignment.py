"""Wall alignment end to end on synthetic reflection images (paper section 3.2, Table 4).

    python benches/wall_alignment.py [--scale 1.0] [--pairs 4] [--stations 16] [--png wall.png]
                                     [--table]

Ground truth: boundary-layer pairs (:func:`rspiv.synth.tbl_pair`) rendered through the paper-like
lens (:func:`rspiv.synth.paper_lens`) with the wall at 0.04 degree to the target's frame, and a
synthetic target through the same lens. Steps, as in the paper:

1. calibrate (P3) from the target image;
2. PIV (64 -> 32 -> 32 x 8 px windows, 50 % overlap, 75 % for the last pass: a vector row
   every 2 px, see :mod:`rspiv.wall`) of the raw frames in a band around the wall; the wall
   from the reflection symmetry: its deviation is compared with the rendered one (the wall
   line pushed through the lens);
3. dewarp the frames with the calibration (Method I), PIV, find the wall: the angle is the
   target misalignment (0.04 degree);
4. rotate the calibration by the measured angle, dewarp, PIV, find the wall again: straight and
   level.

Prints the paper's Table 4 quantities. The full scale takes ~2 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--stations", type=int, default=16)
    ap.add_argument("--angle", type=float, default=0.04, help="wall angle in the target frame")
    ap.add_argument("--png", default=None, help="write the wall-shape figure (paper Fig. 8)")
    ap.add_argument(
        "--table", action="store_true", help="also print rspiv.wall_table's five rows (Table 4)"
    )
    args = ap.parse_args()

    import rspiv
    from rspiv.dewarp import dewarp
    from rspiv.synth import PAPER_OPTICS, calibration_target, paper_lens, tbl_pair
    from rspiv.wall import find_wall

    t0 = time.perf_counter()
    s = args.scale
    optics = PAPER_OPTICS.scaled(s) if s != 1.0 else PAPER_OPTICS
    lens = paper_lens(optics)
    cal = rspiv.calibrate(calibration_target(scale=s, seed=0).image, pitch_mm=optics.pitch_mm)
    pairs = [
        tbl_pair(scale=s, seed=k, lens=lens, wall_angle_deg=args.angle) for k in range(args.pairs)
    ]
    truth = pairs[0][2]
    h, w = truth.shape
    yw = truth.wall_y0_px
    r0, r1 = int(yw - 160 * s - 40), min(h, int(yw + 100 * s + 40))
    band = (yw - 120 * s - 20, yw + 80 * s + 20)
    print(f"sensor {w} x {h}, {args.pairs} pairs, calibration {cal.model}: "
          f"{time.perf_counter() - t0:.1f} s")  # fmt: skip

    def fields(mapping=None):
        out = []
        for a, b, _ in pairs:
            if mapping is not None:
                a, b = dewarp(a, mapping), dewarp(b, mapping)
            a, b = np.ascontiguousarray(a[r0:r1]), np.ascontiguousarray(b[r0:r1])
            f = rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=[0.5, 0.5, 0.75])
            out.append(dataclasses.replace(f, y=f.y + r0))
        return out

    def wall(mapping=None):
        return find_wall(fields(mapping), band=band, stations=args.stations)

    w_raw = wall()
    xs = np.linspace(0, w - 1, 1000)
    rendered = truth.to_image(np.column_stack([xs, truth.wall_y(xs)]))
    ry = np.interp(w_raw.x_px, rendered[:, 0], rendered[:, 1])
    ok = w_raw.valid
    w_dw = wall(cal.mapping)
    cal_rot = cal.with_rotation(w_dw.rotation_deg)
    w_rot = wall(cal_rot.mapping)
    print(f"{'condition':26s} {'max dev [px]':>12s} {'angle [deg]':>12s} {'straight [px]':>13s}")
    for name, wl in (("distorted", w_raw), ("dewarped P3", w_dw), ("P3 + rotation", w_rot)):
        print(f"{name:26s} {wl.max_deviation_px:12.3f} {wl.angle_deg:12.5f} "
              f"{wl.straightness_px:13.3f}")  # fmt: skip
    print(f"rendered raw wall deviation at the stations: {np.ptp(ry[ok]):.3f} px; "
          f"largest station error {np.nanmax(np.abs(w_raw.position_px - ry)):.3f} px")  # fmt: skip
    print(f"angle after dewarping {w_dw.angle_deg:.5f} deg (rendered {args.angle} deg): "
          f"error {abs(w_dw.angle_deg - args.angle):.5f} deg")  # fmt: skip
    if args.table:
        t1 = time.perf_counter()
        table = rspiv.wall_table([p[:2] for p in pairs], cal, band=band, stations=args.stations)
        print("rspiv.wall_table (the paper's Table 4; Method I, R2 and P3 from the same markers):")
        print(table.format())
        print(f"wall_table {time.perf_counter() - t1:.1f} s")
    print(f"total {time.perf_counter() - t0:.1f} s")
    if args.png:
        from rspiv.plots.wall import wall_shape

        wall_shape({"distorted": w_raw, "dewarped P3": w_dw, "P3 + rotation": w_rot}, args.png)


if __name__ == "__main__":
    main()
