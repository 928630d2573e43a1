"""``rspiv piv A.tif B.tif -o field.nc``: multipass PIV of one image pair to NetCDF."""

from __future__ import annotations

import argparse
import os
import pathlib

import rspiv
from rspiv.errors import InvalidInputError
from rspiv.io import read_pair


def _passes(text: str) -> list[tuple[int, int]]:
    out = []
    for item in text.split(","):
        try:
            w, h = item.lower().split("x")
            out.append((int(w), int(h)))
        except ValueError as exc:
            raise InvalidInputError(f"--passes: {item!r} is not WxH") from exc
    return out


def run(args: argparse.Namespace) -> int:

    a, b = read_pair(args.frame_a, args.frame_b)
    field = rspiv.piv(
        a,
        b,
        passes=_passes(args.passes),
        overlap=args.overlap,
        deformation=args.deformation,
        iterations=args.iterations,
    )
    ds = field.to_xarray()
    ds.attrs["frame_a"] = str(args.frame_a)
    ds.attrs["frame_b"] = str(args.frame_b) if args.frame_b else str(args.frame_a) + "[1]"
    out = pathlib.Path(args.output)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        ds.to_netcdf(tmp, engine="h5netcdf")
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    n = field.u.size
    print(
        f"rspiv piv: {n} vectors {field.shape[1]} x {field.shape[0]}, "
        f"{int(field.replaced.sum())} replaced -> {out}"
    )
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "piv",
        help="multipass PIV of an image pair -> NetCDF",
        description="Multipass FFT PIV of an image pair (pixel frame, px). Windows WxH are W px "
        "along x (columns) by H px along y (rows).",
    )
    p.add_argument("frame_a", help="first frame (TIFF/PNG/BMP), or a two-frame TIFF")
    p.add_argument("frame_b", nargs="?", default=None, help="second frame")
    p.add_argument("-o", "--output", required=True, help="output NetCDF file (.nc)")
    p.add_argument("--passes", default="64x64,32x32,32x8", help="window sizes WxH per pass")
    p.add_argument("--overlap", type=float, default=0.5, help="fractional overlap (0.5)")
    p.add_argument("--deformation", default="symmetric", choices=["symmetric", "offset"])
    p.add_argument("--iterations", type=int, default=1, help="iterations per pass")
    p.set_defaults(func=run)
