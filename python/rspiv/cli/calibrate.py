"""``rspiv calibrate``, ``rspiv montecarlo`` and ``rspiv repeatability``.

- ``rspiv calibrate TARGET --pitch-mm 19.51 [--model auto] -o calib.json [--plots DIR]``:
  detect and index the markers of a target image, fit the mapping, print the lattice found and
  a Table-3-like summary and write one JSON file (nothing is written on error).
- ``rspiv calibrate --points MARKERS.csv --image-shape H W -o calib.json``: the same from marker
  positions found by another tool or by hand (CSV columns ``x_px,y_px,x_mm,y_mm``, optionally
  ``sigma_px`` or ``sxx,syy,sxy`` (the covariance, px^2); a header row is required).
- ``--accept-poor-fit`` keeps a fit that does not follow the markers (refused by default); any
  warning is printed on a line starting ``WARNING:``.
- ``rspiv montecarlo calib.json [-n 500000] [--seed 0] [--plots DIR]``: the Monte Carlo study of
  the calibration's mapping (paper section 4); prints per-marker confidence.
- ``rspiv repeatability shot1.json shot2.json``: two calibrations of one plate compared: the
  markers' scatter between the shots against their reported sigma, the shared field apart
  (:mod:`rspiv.repeatability`); one line.
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

from rspiv.calibration import Calibration, calibrate, calibrate_points
from rspiv.cli.mapping import read_csv_columns
from rspiv.errors import InvalidInputError
from rspiv.io import read_image
from rspiv.montecarlo import monte_carlo
from rspiv.repeatability import repeatability

POINT_COLUMNS = ["x_px", "y_px", "x_mm", "y_mm"]
SIGMA_COLUMNS = ("sigma_px", "sxx", "syy", "sxy")


def _calibrate(args: argparse.Namespace) -> int:

    out = pathlib.Path(args.output)
    if not out.parent.is_dir():
        raise InvalidInputError(f"{out}: directory {out.parent} does not exist")
    if (args.target is None) == (args.points is None):
        raise InvalidInputError("give a TARGET image or --points FILE.csv (exactly one of them)")
    image = None
    if args.points is not None:
        cal = _calibrate_points(args)
        print(
            f"calibration from {args.points}: {len(cal.markers)} points, "
            f"{cal.image_shape[1]} x {cal.image_shape[0]} px sensor"
        )
    else:
        if args.pitch_mm is None:
            raise InvalidInputError("--pitch-mm is required with a TARGET image")
        if args.image_shape is not None:
            raise InvalidInputError("--image-shape is for --points (a TARGET image has its own)")
        image = read_image(args.target)
        cal = calibrate(
            image,
            args.pitch_mm,
            model=args.model,
            marker=args.marker,
            pitch_sigma_mm=args.pitch_sigma_mm,
            marker_size_px=args.marker_size_px,
            dark=args.dark,
            profile=args.profile,
            levels=args.levels,
            level=args.level,
            accept_poor_fit=args.accept_poor_fit,
        )
        print(f"calibration of {args.target}: {image.shape[1]} x {image.shape[0]} px")
        print(cal.lattice_summary())
    print(cal.report())
    cal.save(out)
    print(f"wrote {out}")
    if args.plots:
        from rspiv.plots.calibration import write_all  # deferred: matplotlib

        for p in write_all(args.plots, cal, image):
            print(f"wrote {p}")
    return 0


def _calibrate_points(args: argparse.Namespace) -> Calibration:
    """The calibration from ``--points``; errors about the points name the file."""
    if args.image_shape is None:
        raise InvalidInputError(
            "--points needs --image-shape H W (the sensor's height and width, px)"
        )
    if min(args.image_shape) <= 0:
        raise InvalidInputError(f"--image-shape H W must be positive, got {args.image_shape}")
    d = read_csv_columns(args.points, POINT_COLUMNS, SIGMA_COLUMNS, finite=True)
    cov = sigma = None
    cov_cols = [c for c in SIGMA_COLUMNS[1:] if c in d]
    if "sigma_px" in d and cov_cols:
        raise InvalidInputError(f"{args.points}: give sigma_px or sxx,syy,sxy, not both")
    if cov_cols and len(cov_cols) < 3:
        raise InvalidInputError(
            f"{args.points}: the covariance needs the three columns sxx,syy,sxy "
            f"(the header has {','.join(cov_cols)})"
        )
    if cov_cols:
        cov = np.stack([d["sxx"], d["sxy"], d["sxy"], d["syy"]], axis=1).reshape(-1, 2, 2)
    elif "sigma_px" in d:
        sigma = d["sigma_px"]
    if args.sigma_px is not None:
        if cov is not None or sigma is not None:
            raise InvalidInputError(
                f"{args.points}: --sigma-px given and the file has its own sigma columns"
            )
        sigma = args.sigma_px
    try:
        return calibrate_points(
            np.column_stack([d["x_px"], d["y_px"]]),
            np.column_stack([d["x_mm"], d["y_mm"]]),
            image_shape=tuple(args.image_shape),
            pitch_mm=args.pitch_mm,
            model=args.model,
            cov_px2=cov,
            sigma_px=sigma,
            pitch_sigma_mm=args.pitch_sigma_mm,
            accept_poor_fit=args.accept_poor_fit,
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"{args.points}: {exc}") from None


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


def _repeatability(args: argparse.Namespace) -> int:

    rep = repeatability(
        Calibration.load(args.calibration_a),
        Calibration.load(args.calibration_b),
        neighbours=args.neighbours,
    )
    print(rep)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the camera from a target image or from marker positions",
        description="Detect the target's markers, index the grid, fit the mapping model and "
        "write the calibration (JSON); or fit marker positions given in a CSV file (--points).",
    )
    p.add_argument("target", nargs="?", default=None, help="target image (TIFF, PNG, BMP or JPEG)")
    p.add_argument(
        "--points",
        default=None,
        metavar="FILE.csv",
        help="marker positions instead of a TARGET image: CSV with a header and columns "
        "x_px,y_px,x_mm,y_mm (image px, target mm), optionally sigma_px or sxx,syy,sxy (px^2)",
    )
    p.add_argument(
        "--image-shape",
        type=int,
        nargs=2,
        default=None,
        metavar=("H", "W"),
        help="sensor height and width (px); required with --points",
    )
    p.add_argument(
        "--pitch-mm",
        type=float,
        default=None,
        help="marker pitch (mm); required with a TARGET image (with --points default: the "
        "central point's nearest-neighbour distance)",
    )
    p.add_argument("--pitch-sigma-mm", type=float, default=None, help="pitch uncertainty (mm)")
    p.add_argument(
        "--sigma-px",
        type=float,
        default=None,
        help="with --points: image uncertainty of every point (px) when the file has no sigma "
        "columns (default: estimated from the fit residuals)",
    )
    p.add_argument("--model", default="p3", choices=["auto", "r1", "r2", "p3"])
    p.add_argument("--marker", default="dot", choices=["dot", "cross"])
    p.add_argument("--marker-size-px", type=float, default=None, help="marker sigma (px)")
    pol = p.add_mutually_exclusive_group()
    pol.add_argument(
        "--dark", dest="dark", action="store_const", const=True, default=None,
        help="markers darker than the background (default: found from the image)",
    )  # fmt: skip
    pol.add_argument(
        "--bright", dest="dark", action="store_const", const=False,
        help="markers brighter than the background (default: found from the image)",
    )  # fmt: skip
    p.add_argument(
        "--levels", type=int, choices=[1, 2], default=None,
        help="levels of the plate (default: read from the image; an ambiguous plate is refused)",
    )  # fmt: skip
    p.add_argument(
        "--level", type=int, choices=[1, 2], default=None,
        help="the level of a two-level plate to calibrate on (1: the nearer; default: the level "
        "holding the fiducial, else 1)",
    )  # fmt: skip
    p.add_argument(
        "--profile", default="auto", choices=["auto", "gaussian", "disc"],
        help="dot profile of the sub-pixel fit (default: a disc when the dots are flat-topped)",
    )  # fmt: skip
    p.add_argument(
        "--accept-poor-fit",
        action="store_true",
        help="keep a fit whose residuals exceed max(10 x the marker sigma, 0.5 px) (refused "
        "by default), with a warning",
    )
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

    r = sub.add_parser(
        "repeatability",
        help="how well two shots of one plate repeat, against the markers' reported sigma",
        description="Pair the markers of two calibrations of the same plate, remove the "
        "shots' motion and the field their neighbours share (shimmer, vibration), and compare "
        "the markers' own scatter with their reported sigma (rspiv.repeatability).",
    )
    r.add_argument("calibration_a", help="calibration file of one shot (from rspiv calibrate)")
    r.add_argument("calibration_b", help="calibration file of another shot of the same plate")
    r.add_argument("--neighbours", type=int, default=4, help="markers whose mean is the field")
    r.set_defaults(func=_repeatability)
