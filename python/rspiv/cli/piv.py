"""``rspiv piv A.tif B.tif -o field.nc``: multipass PIV of one image pair to NetCDF.

With ``--calibration cal.json`` the distortion is corrected (``--method II``, the default, maps
the vectors; ``--method I`` dewarps the images first): the field is then on the object grid, in
object px. The flags, and the keys of ``--settings FILE.json``, are the one vocabulary of
:class:`rspiv.PivSettings` (shared with the campaign file and ``rspiv-engine piv``).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import warnings
from typing import Any

import rspiv
from rspiv.calibration import Calibration
from rspiv.correction import correct
from rspiv.derivatives import SCHEMES
from rspiv.errors import CorrelationWarning, InvalidInputError, ParticleSizeWarning
from rspiv.export import TECPLOT_SUFFIXES, write_tecplot
from rspiv.io import (
    DAVIS_SUFFIXES,
    camera_recording,
    davis_info,
    read_mask,
    read_pair,
    recording_rate,
)
from rspiv.outputs import write_netcdf
from rspiv.particle_size import as_recorded, warnings_for
from rspiv.preprocess import Preprocess, condition_pair
from rspiv.settings import (
    DEFORMATIONS,
    INTERPOLATIONS,
    MAPPING_MODES,
    SUBPIXELS,
    WEIGHTINGS,
    PivSettings,
    parse_method,
)

_SCALAR_KEYS = (
    "deformation",
    "interpolation",
    "subpixel",
    "weighting",
    "validate",
    "median_eps",
    "median_threshold",
    "min_peak_ratio",
    "peak_candidates",
    "uncertainty",
)


def _numbers(text: str, cast: Any, flag: str) -> Any:
    try:
        vals = [cast(v) for v in text.split(",")]
    except ValueError as exc:
        raise InvalidInputError(f"{flag}: {text!r} is not a number or a list of them") from exc
    return vals[0] if len(vals) == 1 else tuple(vals)


def _passes(text: str) -> list[tuple[int, int]]:
    out = []
    for item in text.split(","):
        try:
            w, h = item.lower().split("x")
            out.append((int(w), int(h)))
        except ValueError as exc:
            raise InvalidInputError(f"--passes: {item!r} is not WxH") from exc
    return out


def _frames(text: str | None) -> tuple[int, int] | None:
    """``--frames I,J``: two frame indices (>= 0) of one multi-frame file, or None."""
    if text is None:
        return None
    try:
        i, j = (int(v) for v in text.split(","))
    except ValueError:
        raise InvalidInputError(f"--frames: {text!r} is not two frame numbers I,J") from None
    if i < 0 or j < 0 or i == j:
        raise InvalidInputError(f"--frames: {text!r}: two different frames, counted from 0")
    return i, j


def recording_line(path: str | pathlib.Path, frames: tuple[int, int] | None) -> str | None:
    """One line on a high-speed recording read as a pair (its camera, frames and frame rate,
    and the time between the two frames), or None for any other file."""
    rec = camera_recording(path)
    if rec is None:
        return None
    i, j = frames or (0, 1)
    apart = f": frames {i} and {j} are {abs(j - i) * rec.dt:g} s apart" if rec.fps > 0 else ""
    return (
        f"{rec.KIND} recording {rec.source.name}: {rec.frames} frames of {rec.width} x "
        f"{rec.height} px, {recording_rate(rec)}{apart}"
    )


def settings_from_args(args: argparse.Namespace) -> PivSettings:
    """The PIV settings of the command line: ``--settings FILE.json`` (or the defaults), with
    every flag given explicitly overriding its key."""
    base = PivSettings.load(args.settings) if args.settings else PivSettings()
    changes: dict[str, Any] = {}
    if args.passes is not None:
        changes["passes"] = _passes(args.passes)
    for key in _SCALAR_KEYS:
        value = getattr(args, key)
        if value is not None:
            changes[key] = value
    if args.overlap is not None:
        changes["overlap"] = _numbers(args.overlap, float, "--overlap")
    if args.iterations is not None:
        changes["iterations"] = _numbers(args.iterations, int, "--iterations")
    if args.roi is not None:
        try:
            changes["roi"] = tuple(int(v) for v in args.roi.split(","))
        except ValueError as exc:
            raise InvalidInputError(f"--roi: {args.roi!r} is not X0,Y0,X1,Y1 in px") from exc
    return base.replace(**changes) if changes else base


#: The run's attributes also written into a Tecplot file.
_TECPLOT_AUX = (
    "warning",
    "peak_locking",
    "hot_pixels",
    "particle_diameter_px",
    "frame_a",
    "frame_b",
    "piv_settings",
    "preprocess",
    "mask",
    "calibration",
    "method",
    "davis_x_scale",
    "davis_y_scale",
)


def run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    out = pathlib.Path(args.output)
    if args.derived is not None and out.suffix.lower() in TECPLOT_SUFFIXES:
        raise InvalidInputError(
            f"--derived: {out.name}: the Tecplot file's columns are fixed; write NetCDF (.nc)"
        )
    frames = _frames(args.frames)
    a, b = read_pair(args.frame_a, args.frame_b, frames)
    said = recording_line(args.frame_a, frames) if args.frame_b is None else None
    if said:
        print(f"rspiv piv: {said}")
    davis = None
    if pathlib.Path(args.frame_a).suffix.lower() in DAVIS_SUFFIXES:
        davis = davis_info(args.frame_a)
        (sx, _, ux), (sy, _, uy) = davis["x_scale"], davis["y_scale"]
        print(
            f"rspiv piv: DaVis buffer {args.frame_a}: {davis['images']} image(s) "
            f"{davis['shape'][1]} x {davis['shape'][0]} {davis['dtype']}, "
            f"scale x {sx:g} {ux}/px, y {sy:g} {uy}/px (vectors stay in px)"
        )
        cams = davis["cameras"]
        if args.frame_b is None and len(cams) > 2:
            print(
                f"rspiv piv: using images 0 and 1 ({cams[0] or '?'}, {cams[1] or '?'}) of "
                f"{len(cams)} ({', '.join(c or '?' for c in cams)})"
            )
    mask = read_mask(args.mask, a.shape) if args.mask is not None else None
    pre = Preprocess(
        hot_pixels=args.hot_pixels,
        high_pass=args.high_pass,
        smooth=args.smooth,
        cap=args.cap,
        min_max=args.min_max,
    )
    recorded = a, b
    if pre.enabled:
        a, b = condition_pair(a, b, pre)
    method = "none"
    with warnings.catch_warnings():
        # said once below, as one line of this command, and written to the file
        warnings.simplefilter("ignore", CorrelationWarning)
        warnings.simplefilter("ignore", ParticleSizeWarning)
        if args.calibration is not None:
            method = parse_method(args.method or "II")
            if method == "none":
                field = rspiv.piv(a, b, settings=settings, mask=mask)
            else:
                cal = Calibration.load(args.calibration)
                field = correct(a, b, cal, method, settings, mapping=args.mapping, mask=mask)
        elif args.method is not None and parse_method(args.method) != "none":
            raise InvalidInputError(f"--method {args.method} needs --calibration")
        else:
            field = rspiv.piv(a, b, settings=settings, mask=mask)
    # the particle images as recorded (not as conditioned or dewarped), and what they say
    field = as_recorded(
        field, *recorded, settings.passes[0], mask=mask, preprocess=pre, dewarped=method == "I"
    )
    small = warnings_for(field.particle_diameter, pre)
    ds = field.to_xarray(derived=args.derived)
    ds.attrs.update(small)  # "peak_locking" (as to_xarray has it), "hot_pixels"
    i, j = frames or (0, 1)
    ds.attrs["frame_a"] = str(args.frame_a) + (f"[{i}]" if frames else "")
    ds.attrs["frame_b"] = str(args.frame_b) if args.frame_b else f"{args.frame_a}[{j}]"
    ds.attrs["piv_settings"] = settings.to_json()
    if pre.enabled:
        ds.attrs["preprocess"] = json.dumps(pre.to_dict())
    if args.mask is not None:
        ds.attrs["mask"] = str(args.mask)
    if davis is not None:
        for axis in ("x", "y"):
            slope, offset, unit = davis[f"{axis}_scale"]
            ds.attrs[f"davis_{axis}_scale"] = f"{slope:.9g} {offset:.9g} {unit}"
    if args.calibration is not None:
        ds.attrs["calibration"] = str(args.calibration)
        ds.attrs["method"] = parse_method(args.method or "II")
    if out.suffix.lower() in TECPLOT_SUFFIXES:
        aux = {k: str(v) for k, v in ds.attrs.items() if k in _TECPLOT_AUX}
        write_tecplot(field, out, zone=f"{args.frame_a}", aux=aux)
    else:
        write_netcdf(ds, out)
    n = field.u.size
    c = field.peak_counts()
    dx, dy = field.particle_diameter
    print(
        f"rspiv piv: {n} vectors {field.shape[1]} x {field.shape[0]}, "
        f"{c['second']} from the second correlation peak, {c['third']} from the third, "
        f"{c['interpolated']} interpolated, {int(field.masked.sum())} masked, "
        f"particle images {dx:.1f} x {dy:.1f} px -> {out}"
    )
    if "warning" in ds.attrs:
        print(f"rspiv piv: warning: {ds.attrs['warning']}", file=sys.stderr)
    for line in small.values():
        print(f"rspiv piv: warning: {line}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "piv",
        help="multipass PIV of an image pair -> NetCDF or Tecplot",
        description="Multipass FFT PIV of an image pair (pixel frame, px). Windows WxH are W px "
        "along x (columns) by H px along y (rows). The settings are rspiv.PivSettings: the same "
        "keys in --settings JSON, the campaign file's [piv] and rspiv-engine piv.",
    )
    p.add_argument(
        "frame_a",
        help="first frame (TIFF/PNG/BMP/JPEG/DaVis .im7), or a multi-frame file: a TIFF stack, "
        "a DaVis buffer, a Photron (.cihx/.cih/.mraw) or Phantom (.cine) recording",
    )
    p.add_argument("frame_b", nargs="?", default=None, help="second frame")
    p.add_argument(
        "--frames",
        default=None,
        help="I,J: the two frames of a multi-frame file that form the pair (0,1)",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="output file: NetCDF (.nc, pivpy-compatible) or Tecplot ASCII (.dat, .tec, .plt)",
    )
    p.add_argument("--settings", default=None, help="PIV settings JSON (PivSettings.to_dict)")
    p.add_argument("--passes", default=None, help="window sizes WxH per pass (64x64,32x32,32x8)")
    p.add_argument("--overlap", default=None, help="fractional overlap, one or one per pass (0.5)")
    p.add_argument("--iterations", default=None, help="iterations, one or one per pass (1)")
    p.add_argument("--deformation", default=None, type=str.lower, choices=DEFORMATIONS)
    p.add_argument("--interpolation", default=None, type=str.lower, choices=INTERPOLATIONS)
    p.add_argument("--subpixel", default=None, type=str.lower, choices=SUBPIXELS)
    p.add_argument("--weighting", default=None, type=str.lower, choices=WEIGHTINGS)
    g = p.add_argument_group("image conditioning (rspiv.preprocess; 0: off)")
    g.add_argument("--hot-pixels", type=float, default=0.0, help="factor over the neighbours (3)")
    g.add_argument("--high-pass", type=float, default=0.0, help="Gaussian sigma, px (2)")
    g.add_argument(
        "--smooth",
        type=float,
        default=0.0,
        help="Gaussian smoothing sigma, px, <= 2 (0.7: about halves the peak locking of particle "
        "images under 2 px)",
    )
    g.add_argument("--cap", type=float, default=0.0, help="cap at mean + CAP * std")
    g.add_argument("--min-max", type=int, default=0, help="min-max normalisation window, px")
    p.add_argument(
        "--validate", default=None, action=argparse.BooleanOptionalAction,
        help="normalised median test with replacement (default on)",
    )  # fmt: skip
    p.add_argument(
        "--uncertainty", default=None, action=argparse.BooleanOptionalAction,
        help="per-vector uncertainty sigma_u, sigma_v (default on)",
    )  # fmt: skip
    p.add_argument("--median-eps", dest="median_eps", type=float, default=None, help="px (0.1)")
    p.add_argument("--median-threshold", dest="median_threshold", type=float, default=None)
    p.add_argument("--min-peak-ratio", dest="min_peak_ratio", type=float, default=None)
    p.add_argument(
        "--peak-candidates",
        dest="peak_candidates",
        type=int,
        default=None,
        help="correlation peaks tried before interpolating a rejected vector: 1, 2, 3 [3]",
    )
    p.add_argument(
        "--mask",
        default=None,
        help="mask of the frames: an image (non-zero = excluded) or a JSON of polygons "
        "(rspiv.io.read_mask); vectors whose centre falls on it are masked (NaN)",
    )
    p.add_argument(
        "--roi",
        default=None,
        help="region of interest X0,Y0,X1,Y1 in px (x0 <= x < x1; object px with --calibration):"
        " the whole frame's grid cut to it, only it and a margin read",
    )
    p.add_argument("--calibration", default=None, help="calibration JSON: correct the distortion")
    p.add_argument(
        "--method", default=None,
        help='correction with --calibration: "I" (dewarp the images), "II" (map the vectors, '
        'default) or "none"',
    )  # fmt: skip
    p.add_argument("--mapping", default="full", type=str.lower, choices=MAPPING_MODES,
                   help="Method II displacement mapping (full)")  # fmt: skip
    p.add_argument(
        "--derived", default=None, type=str.lower, choices=tuple(SCHEMES),
        help="also write vorticity, divergence and signed swirling strength (1/pair; x right, "
        "y up) by this difference scheme (rspiv.derivatives; NetCDF only)",
    )  # fmt: skip
    p.set_defaults(func=run)
