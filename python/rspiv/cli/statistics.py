"""``rspiv statistics FILES... --nu NU -o OUT``: a series of vector fields another tool measured
(DaVis ``.vc7``, OpenPIV text, PIVlab MAT, TSI Insight ``.vec``, rspiv's own NetCDF)
reduced to a campaign's statistics and boundary layer in wall units
(:mod:`rspiv.vector_statistics`).

FILES are files, folders or quoted globs, in time order (a PIVlab session or a DaVis buffer of
several frames gives each of its fields). The pulse separation and the scale come from DaVis'
files, else from ``--dt`` and ``--mm-per-px``; with ``--calibration cal.json`` the raw-frame
fields are corrected by Method II and the calibration gives the scale. The wall is found from
the mean profile's mirror symmetry (the particles' reflection) and levelled with a calibration
(``--level yes`` rotates the fields without one; ``--wall-y`` gives a wall not seen). Written to OUT
atomically: ``statistics.nc`` (per vector, SI, y from the wall), ``profile.nc`` and
``profile.csv`` (wall units with their uncertainties), ``summary.json``, with ``--vorticity``
``vorticity.nc`` (the mean vorticity, its rms and the swirling strength per row) and, with
``--two-point`` ``two_point.nc`` (streamwise spectra and two-point correlations per row;
``--two-point-maps 0.1,0.3,0.6`` adds the maps about rows at those heights in delta_99), with
``--quadrant`` ``quadrant.nc`` (the quadrant analysis of u'v', a second pass over the files;
:mod:`rspiv.vector_structures`), with ``--conditional 0.15,0.4`` ``conditional.nc`` (the
conditional averages of u', v' about ejections and sweeps at those heights in delta_99, in the
second pass), with ``--pod [N]`` ``pod.nc`` (the snapshot POD of at most N fields, 1000, spread
over the series; ``--pod-modes``, ``--pod-height``), with ``--vortices [THRESHOLD]``
``vortices.nc`` (every field's vortex cores beyond THRESHOLD (1.5) times the swirl's rms at
their height, with a Lamb-Oseen fit each, and their population by height, in the second pass,
where ``--conditional`` averages about them too;
``--vortex-min-diameter``, ``--no-vortex-fits``, ``--vortex-fit-shear``) and, with
``--figures``, the profiles against the DNS, the spectra, the quadrant shares, the conditional
averages, the POD's energies and modes and the vortex population; ``--report`` adds
``OUT/report/report.md`` and ``report.html`` with all of them. A stopped run started
again with the same files and options resumes from ``OUT/checkpoint.pkl``. Warnings go to
stderr as well; a series without a usable field or a wall rspiv cannot see is refused in one
line (exit 2).
"""

from __future__ import annotations

import argparse
import sys

from rspiv.calibration import Calibration
from rspiv.outlier_screen import SIGMAS
from rspiv.progress import Progress
from rspiv.vector_statistics import vector_statistics


def _window(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    w, _, h = text.lower().partition("x")
    try:
        return (int(w), int(h or w))
    except ValueError:
        raise ValueError(f"--window {text!r}: W or WxH in px") from None


_HEIGHTS = "heights in delta_99, e.g. 0.15,0.4"


def _two_point(text: str | None) -> bool | float:
    if text is None:
        return False
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--two-point {text!r}: a share of valid vectors, e.g. 0.9") from None


def _numbers(text: str | None, option: str, what: str) -> tuple[float, ...] | None:
    """A comma-separated list of numbers given to ``option`` (None when not given)."""
    if text is None:
        return None
    try:
        return tuple(float(h) for h in text.split(","))
    except ValueError:
        raise ValueError(f"{option} {text!r}: {what}") from None


class _Bar:
    """The reduction's progress (:class:`rspiv.progress.Progress` on stderr), opened at the
    first field it reports (a resumed run counts the fields still to do); a larger total
    (the POD's reads, known once its domain is) extends it."""

    def __init__(self) -> None:
        self.bar: Progress | None = None
        self.total = 0

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = Progress(total - done + 1, "fields").__enter__()
        elif total > self.total:
            self.bar.extend(total - self.total)
        self.total = max(self.total, total)
        self.bar.advance()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)


def run(args: argparse.Namespace) -> int:
    cal = None if args.calibration is None else Calibration.load(args.calibration)
    read = {"y_up": args.y_up, "scale": args.openpiv_scale, "dt": args.openpiv_dt}
    level = {"auto": "auto", "yes": True, "no": False}[args.level]
    bar = _Bar()
    try:
        r = vector_statistics(
            args.files, nu=args.nu, dt=args.dt, mm_per_px=args.mm_per_px, calibration=cal,
            mapping=args.mapping, level=level, pilot=args.pilot, wall=args.wall,
            wall_y=args.wall_y, wall_y_units=args.wall_y_units, stations=args.stations,
            min_count=args.min_count,
            u_inf=args.u_inf, noise_correction=args.noise_correction, screen=args.screen,
            vorticity=args.vorticity or False, two_point=_two_point(args.two_point),
            two_point_maps=_numbers(args.two_point_maps, "--two-point-maps", _HEIGHTS),
            quadrant=_numbers(args.quadrant, "--quadrant", "hole sizes, e.g. 0,1,2,4") or False,
            conditional=_numbers(args.conditional, "--conditional", _HEIGHTS) or False,
            conditional_hole=args.conditional_hole,
            pod=False if args.pod is None else args.pod, pod_modes=args.pod_modes,
            pod_height=args.pod_height,
            vortices=False if args.vortices is None else args.vortices,
            vortex_min_diameter=args.vortex_min_diameter, vortex_fits=not args.no_vortex_fits,
            vortex_fit_shear=args.vortex_fit_shear, window=_window(args.window),
            read_options={k: v for k, v in read.items() if v not in (False, None)},
            out_dir=args.output, progress=bar, readers=args.readers,
        )  # fmt: skip
    finally:
        bar.close()
    print(r.report())
    files = r.write(args.output, figures=args.figures, report=args.report)
    print(f"written: {', '.join(str(p) for p in files.values())}")
    for w in r.warnings:
        print(f"rspiv statistics: warning: {w}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "statistics",
        help="another tool's vector fields (DaVis, OpenPIV, PIVlab, Insight) to wall-unit "
        "statistics",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("files", nargs="+", help="vector files, folders or quoted globs, in order")
    p.add_argument("--nu", type=float, required=True, help="kinematic viscosity, m^2/s")
    p.add_argument("--dt", type=float, default=None, help="pulse separation, s (not in file)")
    p.add_argument("--mm-per-px", type=float, default=None, help="scale, mm/px (not in file)")
    p.add_argument("--calibration", default=None, help="calibration JSON: Method II first")
    p.add_argument("--mapping", default="full", choices=("full", "positions"),
                   help="with --calibration: the displacement mapping (full)")  # fmt: skip
    p.add_argument("--level", default="auto", choices=("auto", "yes", "no"),
                   help="rotate the fields to level the wall (auto)")  # fmt: skip
    p.add_argument("--pilot", type=int, default=50, help="fields that find the wall's angle")
    p.add_argument("--wall", default="auto", choices=("auto", "bottom", "top"),
                   help="where the wall is: bottom (flow above it), top, auto")  # fmt: skip
    p.add_argument("--wall-y", type=float, default=None,
                   help="the wall's row, px, its reflection unseen (with --wall)")  # fmt: skip
    p.add_argument("--wall-y-units", default="px", choices=("px", "file"),
                   help="--wall-y in px, or in the files' own units (a calibrated PIVlab "
                        "export's m)")  # fmt: skip
    p.add_argument("--stations", type=int, default=16, help="wall stations along x (16)")
    p.add_argument("--min-count", type=int, default=10, help="fields a vector needs (10)")
    p.add_argument("--u-inf", type=float, default=None, help="free-stream velocity, m/s")
    p.add_argument("--noise-correction", action="store_true",
                   help="remove the tool's uncertainties' variance from the stresses")  # fmt: skip
    p.add_argument("--screen", type=float, default=SIGMAS,
                   help=f"screen beyond this many local spreads ({SIGMAS:g}; 0: off)")  # fmt: skip
    p.add_argument("--vorticity", nargs="?", const="least_squares", default=None,
                   help="vorticity statistics per row (scheme: least_squares)")  # fmt: skip
    p.add_argument("--two-point", nargs="?", const="0.9", default=None, metavar="MIN_VALID",
                   help="spectra and two-point correlations per row (a row of a field enters "
                   "with this share of valid vectors: 0.9)")  # fmt: skip
    p.add_argument("--two-point-maps", default=None, metavar="HEIGHTS",
                   help="with --two-point: maps about rows at these heights in delta_99 "
                   "(e.g. 0.1,0.3,0.6), summed in a second pass")  # fmt: skip
    p.add_argument("--quadrant", nargs="?", const="0,1,2,4", default=None, metavar="HOLES",
                   help="quadrant analysis of u'v' (hole sizes: 0,1,2,4), a second pass")
    p.add_argument("--conditional", nargs="?", const="0.15,0.4", default=None,
                   metavar="HEIGHTS", help="conditional averages about ejections and sweeps "
                   "at these heights in delta_99 (0.15,0.4), a second pass")  # fmt: skip
    p.add_argument("--conditional-hole", type=float, default=1.0,
                   help="events with |u'v'| >= this times u_rms v_rms (1.0)")  # fmt: skip
    p.add_argument("--pod", nargs="?", const=1000, default=None, type=int, metavar="N",
                   help="snapshot POD of at most N fields spread over the series (1000)")
    p.add_argument("--pod-modes", type=int, default=10, help="with --pod: modes kept (10)")
    p.add_argument("--pod-height", type=float, default=0.0,
                   help="with --pod: the domain's top in delta_99 (0: the flow side)")
    p.add_argument("--vortices", nargs="?", const=1.5, default=None, type=float,
                   metavar="THRESHOLD", help="vortex cores beyond THRESHOLD times the swirl's "
                   "rms at their height (1.5) and their population, a second pass")  # fmt: skip
    p.add_argument("--vortex-min-diameter", type=float, default=1.0,
                   help="with --vortices: cores smaller than a disc this many final windows "
                   "wide dropped (1.0)")  # fmt: skip
    p.add_argument("--no-vortex-fits", action="store_true",
                   help="with --vortices: no Lamb-Oseen fit of each core")  # fmt: skip
    p.add_argument("--vortex-fit-shear", action="store_true",
                   help="with --vortices: each Lamb-Oseen vortex in a uniform shear")  # fmt: skip
    p.add_argument("--window", default=None, help="final window WxH px (not in the files)")
    p.add_argument("--y-up", action="store_true", help="OpenPIV text: y and v point up")
    p.add_argument("--openpiv-scale", type=float, default=None, help="OpenPIV: units per px")
    p.add_argument("--openpiv-dt", type=float, default=None, help="OpenPIV: s its u, v are per")
    p.add_argument("--readers", type=int, default=None, metavar="N",
                   help="processes reading the files ahead (default: one per core from 64 "
                   "fields; 0: none)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--figures", action="store_true", help="the profiles against the DNS (PNG)")
    p.add_argument("--report", action="store_true",
                   help="OUT/report/report.md and .html: what was read, the warnings, the "
                   "boundary layer and each analysis with its figure (draws the figures)")
    p.set_defaults(func=run)
