"""``rspiv calibrate`` and ``rspiv montecarlo``.

- ``rspiv calibrate TARGET --pitch-mm 19.51 [--model auto] -o calib.json [--plots DIR]``:
  detect and index the markers of a target image, fit the mapping, print a Table-3-like summary
  and write one JSON file (nothing is written on error).
- ``rspiv montecarlo calib.json [-n 500000] [--seed 0] [--plots DIR]``: the Monte Carlo study of
  the calibration's mapping (paper section 4); prints per-marker confidence.
"""

from __future__ import annotations

import argparse
import pathlib

from rspiv.calibration import Calibration, calibrate
from rspiv.errors import InvalidInputError
from rspiv.io import read_image
from rspiv.montecarlo import monte_carlo


def _calibrate(args: argparse.Namespace) -> int:

    out = pathlib.Path(args.output)
    if not out.parent.is_dir():
        raise InvalidInputError(f"{out}: directory {out.parent} does not exist")
    image = read_image(args.target)
    cal = calibrate(
        image,
        args.pitch_mm,
        model=args.model,
        marker=args.marker,
        pitch_sigma_mm=args.pitch_sigma_mm,
        marker_size_px=args.marker_size_px,
        dark=args.dark,
    )
    print(f"calibration of {args.target}: {image.shape[1]} x {image.shape[0]} px")
    print(cal.report())
    cal.save(out)
    print(f"wrote {out}")
    if args.plots:
        from rspiv.plots.calibration import write_all  # deferred: matplotlib

        for p in write_all(args.plots, cal, image):
            print(f"wrote {p}")
    return 0


def _montecarlo(args: argparse.Namespace) -> int:

    cal = Calibration.load(args.calibration)
    res = monte_carlo(
        cal,
        n=args.n,
        sigma_image_px=args.sigma_image_px,
        sigma_object_px=args.sigma_object_px,
        seed=args.seed,
        model=args.model,
        threads=args.threads,
        hist_bins=64 if args.plots else 0,
        hist_half_range_px=args.half_range_px,
    )
    print(res.summary())
    if args.plots:
        from rspiv.plots.calibration import monte_carlo_jpdfs  # deferred: matplotlib

        d = pathlib.Path(args.plots)
        d.mkdir(parents=True, exist_ok=True)
        print(f"wrote {monte_carlo_jpdfs(res, d / f'montecarlo_{res.model}.png')}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the camera from a target image",
        description="Detect the target's markers, index the grid, fit the mapping model and "
        "write the calibration (JSON).",
    )
    p.add_argument("target", help="target image (TIFF, PNG or BMP)")
    p.add_argument("--pitch-mm", type=float, required=True, help="marker pitch (mm)")
    p.add_argument("--pitch-sigma-mm", type=float, default=None, help="pitch uncertainty (mm)")
    p.add_argument("--model", default="p3", choices=["auto", "r1", "r2", "p3"])
    p.add_argument("--marker", default="dot", choices=["dot", "cross"])
    p.add_argument("--marker-size-px", type=float, default=None, help="marker sigma (px)")
    p.add_argument("--dark", action="store_true", help="markers darker than the background")
    p.add_argument("-o", "--output", required=True, help="calibration file to write (JSON)")
    p.add_argument("--plots", default=None, help="directory for the figures")
    p.set_defaults(func=_calibrate)

    q = sub.add_parser(
        "montecarlo",
        help="Monte Carlo study of a calibration's mapping",
        description="Perturb the markers within their uncertainties, refit, and report each "
        "marker's residual distribution (paper section 4).",
    )
    q.add_argument("calibration", help="calibration file (from rspiv calibrate)")
    q.add_argument("-n", type=int, default=500_000, help="number of samples")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--model", default=None, choices=["r1", "r2", "p3"])
    q.add_argument("--sigma-image-px", type=float, default=None)
    q.add_argument("--sigma-object-px", type=float, default=None)
    q.add_argument("--threads", type=int, default=None)
    q.add_argument("--half-range-px", type=float, default=2.5, help="JPDF half range (px)")
    q.add_argument("--plots", default=None, help="directory for the JPDF figure")
    q.set_defaults(func=_montecarlo)
