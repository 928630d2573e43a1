"""``rspiv dewarp`` (Method I).

- ``rspiv dewarp calib.json IMAGES... -o DIR [--rotation DEG] [--dtype float32|uint16]
  [--sampling auto|exact]``: dewarp each image through the calibration's mapping (Keys bicubic,
  zero outside the image) and write ``DIR/<stem>.tif`` (float32 or uint16 TIFF). Nothing is
  written for an image that fails; the command stops at the first error.
"""

from __future__ import annotations

import argparse
import pathlib

from rspiv.calibration import Calibration
from rspiv.dewarp import dewarp
from rspiv.errors import InvalidInputError
from rspiv.io import read_image


def _dewarp(args: argparse.Namespace) -> int:
    import tifffile


    out_dir = pathlib.Path(args.output)
    if not out_dir.is_dir():
        raise InvalidInputError(f"{out_dir}: output directory does not exist")
    cal = Calibration.load(args.calibration)
    if args.rotation:
        cal = cal.with_rotation(args.rotation)
    for name in args.images:
        img = read_image(name)
        out = dewarp(img, cal.mapping, output_shape=img.shape, out_dtype=args.dtype,
                     sampling=args.sampling)  # fmt: skip
        dest = out_dir / (pathlib.Path(name).stem + ".tif")
        if dest.resolve() == pathlib.Path(name).resolve():
            raise InvalidInputError(f"{dest}: would overwrite its input")
        tifffile.imwrite(dest, out)
        print(f"{name} -> {dest}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dewarp", help="dewarp images through a calibration (Method I)")
    p.add_argument("calibration", help="calibration JSON written by `rspiv calibrate`")
    p.add_argument("images", nargs="+", help="images to dewarp (TIFF, PNG, BMP, JPEG)")
    p.add_argument("-o", "--output", required=True, help="output directory (must exist)")
    p.add_argument("--rotation", type=float, default=0.0,
                   help="extra rotation (degrees), e.g. the angle from `rspiv wall`")  # fmt: skip
    p.add_argument("--dtype", choices=("float32", "uint16"), default="float32")
    p.add_argument("--sampling", choices=("auto", "exact"), default="auto",
                   help="mapping on a coarse grid within 1e-3 px (auto) or per pixel")  # fmt: skip
    p.set_defaults(func=_dewarp)
