"""Boundary-layer statistics in wall units from the vector fields another tool measured.

A lab comes to rspiv with years of DaVis, OpenPIV, PIVlab or Insight results whose images are
archived, not at hand, or were never kept. :func:`vector_statistics` reduces such a series of
vector files as a campaign reduces image pairs: the same statistics
(:class:`rspiv.stats.FieldAccumulator`: mean, Reynolds stresses, central moments to order 8, the
lag-1 chains of the effective sample count, the tool's uncertainties for the noise
correction), the same wall from the mean profile's mirror symmetry and the same boundary-layer
analysis in wall units
(:func:`rspiv.campaign.analysis.analyse_run`), to the same files (``rspiv statistics``).

The steps, for the fields in the order given (a file of several fields, a PIVlab session or a
DaVis buffer, in its own order):

1. Each field is read in rspiv's pixel frame (:func:`rspiv.vector_files.read_vectors`). Only the
   vectors the tool's validation accepted enter the statistics: vectors it filled or smoothed
   afterwards are no measurement (in a boundary layer they are many at the wall, and they
   carry the interpolation's smoothed stresses). The first field fixes the grid, the pulse
   separation and the scale; a later field on another grid, or whose file states another
   pulse separation or scale (a second recording mixed in), is skipped and named.
2. With a ``calibration`` the fields, measured on the raw frames, are corrected by Method II
   (:func:`rspiv.correction.correct_vectors`: each grid point read as object px takes the field
   at ``F(X)``, its displacement mapped through the inverse). The scale is then the
   calibration's magnification; a file's own scale more than 2 % from it is said (the files
   are of another camera or another calibration).
3. With a calibration the wall is levelled as the campaign levels it (paper section 3.2): its
   angle is found on the first ``pilot`` fields and the calibration rotated by it (Method II
   resamples the fields anyway). Without one the fields keep their nodes (``level="auto"``):
   rotating them means resampling between nodes (:func:`rspiv.vector_sampling.sample_at`),
   which smooths the fluctuations a little (on the synthetic series of
   ``tests/test_vector_statistics.py``, tilted 0.3 degree, the median error of uu+ went from
   0.000 to -0.001 levelled so, -0.094 with bilinear sampling: with rows 16 px apart a tilt
   that small mixes little). A wall that rises more than half a row across the field is said;
   ``level=True`` rotates the fields anyway. On rows 16 px apart :func:`rspiv.find_wall`'s
   joint fit places the wall within 0.10 px along the tilted wall above (10 fields, 4 rows of
   reflection in the band) and reads its tilt as 0.2975 degree; levelled from 30 pilot fields
   whose band holds 2 rows of reflection, 0.337 degree (resampling the profile about its
   mirror erred by -1.4 to +2.0 px with the wall's place between rows, -1.1 px on a level
   wall, and read 0.404 and 0.415 degree).
4. Units: the magnification from the calibration, else the files' scale (DaVis) or
   ``mm_per_px``; the pulse separation from the files (DaVis) or ``dt``. Without both the
   statistics are in px per pair and no wall units are derived (said).
5. With ``two_point``, ``quadrant`` and ``conditional``, the boundary layer's structure as a
   campaign gives it (:mod:`rspiv.vector_structures`): the streamwise spectra and two-point
   correlations per row, summed beside the statistics (with their maps, in the second pass),
   and the quadrant analysis, the conditional averages and the vortex population
   (``vortices``), a second pass over the files once each vector's mean and the wall are
   known; with ``pod``, the snapshot POD of the fluctuations, one more reading of the fields
   it takes.

Every pass reads its files ahead of the sums in reader processes (``readers``, one per core
from 64 fields; :mod:`rspiv.vector_readahead`): the figures are those of the files read in
turn, bit for bit, and a file that crashes its reading library is skipped and named.

Refused in one line (:class:`rspiv.errors.InvalidInputError`): no field could be used (with the
first file's reason), a wall the mean profile does not show (:func:`rspiv.find_wall`'s
refusal), fewer than 8 profile points beyond it, fewer than 8 contiguous columns for the
two-point sums. Warned (``warnings``, the CLI's stderr, ``summary.json``): fields skipped,
uncorrected raw-frame fields (the lens distortion is in the statistics), a final window
assumed, a wall tilted and not levelled, a scale that disagrees with the calibration, the
boundary-layer analysis' own warning, and the two-point, quadrant, conditional and vortex
analyses' (rows that entered few fields, ``u'v'`` unresolved, no events, maps or heights the
rows cannot hold, no wall units to bound the vortices' rows, no Lamb-Oseen fit kept, fields
lost between the passes).

Units and frames: positions px of the fields' frame (object px when corrected), x right, y
down; the accumulator holds px per pair, pixel axes; the outputs are SI (m, m/s) with y the
distance from the wall, as a campaign's.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time
from collections.abc import Callable, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from rspiv.campaign.analysis import (
    NEAR_WALL_HEIGHTS,
    analyse_run,
    run_statistics_dataset,
    wall_dict,
)
from rspiv.campaign.convergence import write_files as write_convergence
from rspiv.campaign.spec import RunSpec
from rspiv.campaign.state import RunAnalysis, json_default
from rspiv.campaign.vorticity import vorticity_dataset, vorticity_profile
from rspiv.campaign_config import FlowConfig, StatisticsConfig, WallConfig
from rspiv.convergence import Convergence, profile_convergence
from rspiv.derivatives import SCHEMES
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outlier_screen import HALF_WIDTH, ScreenTally, screen_bounds
from rspiv.outlier_screen import SIGMAS as SCREEN_SIGMAS
from rspiv.outputs import atomic_write_text, profile_dataset, write_netcdf, write_profile_csv
from rspiv.peak_locking import LockingHistogram
from rspiv.reference import dns_profile_for_re_tau
from rspiv.reference_comparison import ReferenceComparison, compare_reference, viscous_window
from rspiv.row_errors import RowErrors
from rspiv.stats import FieldAccumulator
from rspiv.two_point import TwoPointAccumulator
from rspiv.vector_levelling import field_transform, identity_mapping, levelling, wall_bow, wall_rise
from rspiv.vector_readahead import ReadAhead, auto_readers
from rspiv.vector_reduction import (
    SeriesReducer,
    entry_name,
    fingerprint,
    load_checkpoint,
    pilot_fields,
    read_entry,
    save_checkpoint,
    series_entries,
)
from rspiv.vector_report import write_series_report
from rspiv.vector_structures import (
    STRUCTURES,
    report_lines,
    structure_options,
    structures,
    summary_entries,
    two_point_columns,
    write_structures,
)
from rspiv.vorticity import VorticityAccumulator

__all__ = ["VectorStatistics", "vector_statistics"]

#: A file's scale may differ from the calibration's by this share before it is said.
_SCALE_TOLERANCE = 0.02


@dataclasses.dataclass
class VectorStatistics:
    """What :func:`vector_statistics` gives (module docstring).

    Attributes
    ----------
    accumulator : FieldAccumulator
        The fields' statistics, px per pair along the pixel axes, on the grid ``x, y``.
    x, y : ndarray
        The grid's columns and rows, px of the fields' frame (object px when corrected).
    analysis : RunAnalysis
        The wall, the profile (SI when the units are known) and the boundary-layer result
        (``analysis.result``, None without SI units).
    tool : str
        The tool that wrote the first field.
    frame : str
        ``"object"`` (corrected by the calibration, or fields already corrected), ``"image"``
        (raw frames, uncorrected) or ``""`` (the files do not say: DaVis).
    used, skipped : int, dict
        Fields in the statistics; file (with its frame) -> why it was left out.
    mm_per_px, dt : float
        The scale (mm per px of the fields' frame) and pulse separation (s) used; NaN unknown.
    window : tuple of int
        The final window ``(w, h)``, px (the files', or given, or assumed: ``warnings``).
    rotation_deg : float
        The rotation applied to level the wall (0: none).
    warnings : list of str
        What the result's reader must know, one line each.
    locking : dict
        The displacements' lean towards whole pixels over the series
        (:meth:`rspiv.peak_locking.LockingHistogram.result`: ``amplitude_px``,
        ``standard_error_px``, ``said``).
    vorticity : dict or None
        The vorticity statistics per row (with ``vorticity=``; their keys:
        :func:`rspiv.campaign.vorticity.vorticity_profile`).
    two_point, quadrant, conditional, pod, vortices : dict or None
        The spectra and two-point correlations per row, the quadrant analysis, the
        conditional averages, the POD and the vortex population (with ``two_point=``,
        ``quadrant=``, ``conditional=``, ``pod=``, ``vortices=``; their keys:
        :func:`rspiv.campaign.two_point.two_point_profile`, :func:`rspiv.campaign.quadrant.
        quadrant_profile`, :func:`rspiv.campaign.conditional.conditional_profile`,
        :func:`rspiv.campaign.pod.pod_profile`, :meth:`rspiv.campaign.vortices.VortexSearch.
        profile`; :mod:`rspiv.vector_structures`).
    seconds : float
        The reduction's wall time.
    convergence : Convergence or None
        The statistics of the first fields against the series' and the first fields against
        the rest (:mod:`rspiv.convergence`; the fields numbered in the series' order); None
        for fewer than two prefixes of 5 fields or a state resumed from before it existed.
    """

    accumulator: FieldAccumulator
    x: np.ndarray
    y: np.ndarray
    analysis: RunAnalysis
    tool: str
    frame: str
    used: int
    skipped: dict[str, str]
    mm_per_px: float
    dt: float
    window: tuple[int, int]
    rotation_deg: float
    warnings: list[str]
    locking: dict[str, Any] = dataclasses.field(default_factory=dict)
    vorticity: dict[str, Any] | None = None
    two_point: dict[str, Any] | None = None
    quadrant: dict[str, Any] | None = None
    conditional: dict[str, Any] | None = None
    pod: dict[str, Any] | None = None
    vortices: dict[str, Any] | None = None
    seconds: float = 0.0
    convergence: Convergence | None = None

    def screened(self) -> dict[str, Any] | None:
        """The vectors the screen left out of the statistics (their number and share of the
        valid ones), None without a screen."""
        tally = getattr(self.accumulator, "screen", None)
        if tally is None:
            return None
        n = int(tally.count.sum())
        total = n + int(self.accumulator.count.sum())
        return {"vectors": n, "share": n / total if total else 0.0}

    @property
    def result(self) -> Any:
        """The :class:`rspiv.boundary_layer.BoundaryLayerResult`, None without SI units."""
        return self.analysis.result

    def to_xarray(self) -> Any:
        """The statistics per vector as the campaign writes them (``statistics_<run>.nc``: SI
        when known, y the distance from the wall, the rows behind the wall masked)."""
        gx, gy = np.meshgrid(self.x, self.y)
        return run_statistics_dataset(
            self.accumulator, self.analysis, gx, gy, self.dt if self.dt > 0 else 0.0,
            {"tool": self.tool, "frame": self.frame or "unknown", "n_pairs": self.used},
        )  # fmt: skip

    def summary(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict (``summary.json``)."""
        an = self.analysis
        out: dict[str, Any] = {
            "tool": self.tool,
            "frame": self.frame or "unknown",
            "fields": self.used,
            "skipped": self.skipped,
            "mm_per_px": self.mm_per_px,
            "dt_s": self.dt,
            "window_px": list(self.window),
            "rotation_deg": self.rotation_deg,
            "screened": self.screened(),
            "peak_locking": self.locking,
            "vorticity_rows": None if self.vorticity is None else int(self.vorticity["y"].size),
            **summary_entries({k: getattr(self, k) for k in STRUCTURES}),
            "flow_side": an.flow_side,
            "seconds": self.seconds,
            "warnings": list(self.warnings),
        }
        if an.wall is not None:
            out["wall"] = wall_dict(an.wall)
        if self.convergence is not None:
            out["convergence"] = self.convergence.summary()
        if an.result is not None:
            out.update(an.result.summary())
            if (ref := self.reference()) is not None:
                out["reference"] = ref.to_dict()
        elif an.error:
            out["error"] = an.error
        return out

    def reference(self) -> ReferenceComparison | None:
        """The profile against the DNS station nearest its Re_tau, the window in wall units
        (:func:`rspiv.reference_comparison.compare_reference`); None without wall units."""
        r = self.result
        if r is None or not np.isfinite(self.mm_per_px) or self.mm_per_px <= 0:
            return None
        try:
            return compare_reference(
                r, window_plus=viscous_window(r, self.window, self.mm_per_px * 1e-3)
            )
        except InvalidInputError:
            return None

    def report(self) -> str:
        """A few lines for the terminal."""
        lines = [
            f"{self.used} {self.tool} fields ({self.frame or 'frame unknown'}), "
            f"{len(self.skipped)} skipped; grid {self.x.size} x {self.y.size}, "
            f"window {self.window[0]} x {self.window[1]} px",
        ]
        lk = self.locking
        if lk.get("amplitude_px") is not None:
            err = lk.get("standard_error_px")
            lines.append(
                f"peak locking: {lk['amplitude_px']:.4f}"
                + (f" +- {err:.4f}" if err is not None else "")
                + " px"
            )
        sc = self.screened()
        if sc is not None:
            lines.append(f"screened: {sc['vectors']} vectors ({100 * sc['share']:.3f} %)")
        w = self.analysis.wall
        if w is not None:
            lines.append(
                f"wall at y = {float(w.line(np.mean(self.x))):.2f} px, angle {w.angle_deg:.4f} "
                f"deg, flow {self.analysis.flow_side}; levelled by {self.rotation_deg:.4f} deg"
            )
        r = self.result
        if r is not None:
            lines.append(
                f"u_tau = {r.u_tau:.4g} +/- {r.u_tau_std:.2g} m/s (Clauser {r.u_tau_clauser:.4g}),"
                f" delta99 = {r.delta99 * 1e3:.2f} mm, Re_tau = {r.re_tau:.0f}, "
                f"Re_theta = {r.re_theta:.0f}, H = {r.H:.3f}"
            )
            if (ref := self.reference()) is not None:
                lines.append(ref.verdict())
        elif self.analysis.error:
            lines.append(f"no wall units: {self.analysis.error}")
        lines += report_lines({k: getattr(self, k) for k in STRUCTURES})
        lines += [f"WARNING: {w}" for w in self.warnings]
        return "\n".join(lines)

    def write(
        self, out_dir: str | os.PathLike, figures: bool = False, report: bool = False
    ) -> dict[str, pathlib.Path]:
        """Write ``statistics.nc``, ``profile.nc``, ``profile.csv``, ``summary.json``, with
        ``vorticity=`` ``vorticity.nc``, with ``two_point=``, ``quadrant=``, ``conditional=``,
        ``pod=`` and ``vortices=`` their ``<name>.nc`` (and with
        ``figures`` the profiles in wall units against the DNS and the figures of
        :func:`rspiv.vector_structures.write_structures`) atomically to ``out_dir``; with
        ``report`` (which draws the figures) ``report/report.md`` and ``report.html``
        (:mod:`rspiv.vector_report`); returns name -> path."""
        figures = figures or report
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        files = {"statistics": write_netcdf(self.to_xarray(), out / "statistics.nc")}
        r = self.result
        if r is not None:
            meta = {"tool": self.tool, "fields": self.used}
            files["profile_nc"] = write_netcdf(profile_dataset(r, attrs=meta), out / "profile.nc")
            files["profile_csv"] = write_profile_csv(out / "profile.csv", r, metadata=meta)
            if figures:
                from rspiv.plots.boundary_layer import plot_boundary_layer  # deferred: matplotlib

                for k, p in plot_boundary_layer(out, {f"{self.tool} fields": r}).items():
                    files[f"figure_{k}"] = pathlib.Path(p)
        if self.vorticity is not None:
            ds = vorticity_dataset(self.vorticity, self.analysis.run)
            files["vorticity"] = write_netcdf(ds, out / "vorticity.nc")
            if figures and "y_plus" in self.vorticity:
                from rspiv.plots.vorticity import plot_vorticity  # deferred: matplotlib

                dns = dns_profile_for_re_tau(self.vorticity["re_tau"])
                try:
                    files["figure_vorticity"] = plot_vorticity(
                        out / "vorticity.png", self.vorticity, dns
                    )
                except InvalidInputError:
                    pass  # too few rows in wall units to draw: the file holds them
        if self.convergence is not None:
            _, got = write_convergence(out, "convergence", self.convergence, self.analysis,
                                       f"{self.tool} fields", figure=figures)  # fmt: skip
            files["convergence_csv"] = got["csv"]
            if "png" in got:
                files["figure_convergence"] = got["png"]
        run = self.analysis.run
        files.update(write_structures(out, run, {k: getattr(self, k) for k in STRUCTURES}, figures))
        files["summary"] = atomic_write_text(
            out / "summary.json", json.dumps(self.summary(), indent=1, default=json_default)
        )
        if report:
            written = write_series_report(out / "report", self, files)
            files.update({f"report_{k}": v for k, v in written.items()})
        return files


def vector_statistics(
    files: Any,
    *,
    nu: float,
    dt: float | None = None,
    mm_per_px: float | None = None,
    calibration: Any = None,
    mapping: str = "full",
    level: str | bool = "auto",
    pilot: int = 50,
    wall: str = "auto",
    wall_y: float | None = None,
    wall_y_units: str = "px",
    stations: int = 16,
    min_count: int = 10,
    u_inf: float | None = None,
    noise_correction: bool = False,
    screen: float = SCREEN_SIGMAS,
    vorticity: str | bool = False,
    two_point: bool | float = False,
    two_point_maps: Sequence[float] | None = None,
    quadrant: bool | Sequence[float] = False,
    conditional: bool | Sequence[float] = False,
    conditional_hole: float = 1.0,
    pod: bool | int = False,
    pod_modes: int = 10,
    pod_height: float = 0.0,
    vortices: bool | float = False,
    vortex_min_diameter: float = 1.0,
    vortex_fits: bool = True,
    vortex_fit_shear: bool = False,
    window: tuple[int, int] | None = None,
    read_options: dict[str, Any] | None = None,
    out_dir: str | os.PathLike | None = None,
    checkpoint_every: int = 500,
    progress: Callable[[int, int], None] | None = None,
    readers: int | None = None,
) -> VectorStatistics:
    """Reduce a series of vector files to statistics and a boundary layer in wall units
    (module docstring).

    Parameters
    ----------
    files : path, glob, folder, or an iterable of paths and (path, frame) tuples
        The fields, one pair each, in time order (the effective sample count reads the lag-1
        correlation between successive fields).
    nu : float
        Kinematic viscosity, m^2/s (required: no fluid is assumed).
    dt, mm_per_px : float, optional
        Pulse separation (s) and scale (mm per px) where the files do not give them; a file's
        own figure wins for ``dt``, the calibration's for the scale.
    calibration : Calibration, optional
        Of the camera that recorded the raw frames: the fields are corrected by Method II.
    mapping : {"full", "positions"}
        Method II's displacement mapping.
    level : "auto", True or False
        Rotate the fields so that the wall is level (step 3).
    pilot : int
        Fields over which the wall's angle is found before the reduction.
    wall : {"auto", "bottom", "top"}
        Where the flow lies from the wall (``"bottom"``: the wall at the bottom of the image,
        the flow above it); ``"auto"`` reads it from the mean profile.
    wall_y : float, optional
        The wall's row, px of the fields' frame (object px when corrected), where the fields
        do not show its reflection (masked, out of view); ``wall`` must then be ``"bottom"``
        or ``"top"``. Nothing is levelled and no wall is checked: the row is the user's word.
    wall_y_units : {"px", "file"}
        ``"file"``: ``wall_y`` in the files' own position units, for files whose positions
        are the recording's px only up to a constant (a calibrated PIVlab export, in m: its
        ``VectorFile.y_from_file``).
    stations, min_count, u_inf, noise_correction
        As a campaign's ``[wall] stations``, ``[statistics] min_count``, ``[flow] u_inf``
        and ``[statistics] noise_correction`` (the tool's uncertainties, where it wrote them).
    screen : float
        Leave out of the statistics the vectors beyond this many local spreads of their row
        (:mod:`rspiv.outlier_screen`, a campaign's ``[statistics] screen``: random vectors the
        tool's validation kept), the bounds from ``pilot`` fields spread over the series (at
        most 20); 0 switches it off.
    vorticity : bool or str
        The vorticity statistics per row (a campaign's ``[statistics] vorticity``,
        :func:`rspiv.campaign.vorticity.vorticity_profile`: mean vorticity and its rms, the
        signed swirling strength, in 1/s and wall units): True for least-squares differences,
        or the scheme's name (:data:`rspiv.derivatives.SCHEMES`).
    two_point : bool or float
        Streamwise spectra and two-point correlations per row (a campaign's ``[statistics]
        two_point``, :mod:`rspiv.vector_structures`): True, or the share of valid vectors a
        row of a field needs to enter (default 0.9, a campaign's ``two_point_min_valid``).
    two_point_maps : sequence of float, optional
        With ``two_point``: the two-point maps about reference rows at these heights, in
        delta_99 from the wall (a campaign's ``two_point_heights``, e.g. ``(0.1, 0.3,
        0.6)``). Their rows are placed from the wall, so the two-point sums are then made in
        the second pass over the files (with the quadrant analysis when it is asked for).
    quadrant : bool or sequence of float
        The quadrant analysis of ``u'v'`` (a campaign's ``[statistics] quadrant``), a second
        pass over the files: True (hole sizes 0, 1, 2, 4), or the hole sizes.
    conditional : bool or sequence of float
        The conditional averages of u', v' about ejections and sweeps (a campaign's
        ``[statistics] conditional``), in the second pass: True (events at 0.15 and 0.4
        delta_99 from the wall), or the heights in delta_99; events with ``|u'v'| >=
        conditional_hole u_rms v_rms``.
    pod, pod_modes, pod_height : bool or int, int, float
        The snapshot POD (a campaign's ``[statistics] pod``, :func:`rspiv.vector_structures.
        pod_pass`): True (at most 1000 fields, spread evenly) or the fields at most; the modes
        kept; the domain up to ``pod_height`` delta_99 from the wall (0: the flow side).
    vortices, vortex_min_diameter, vortex_fits, vortex_fit_shear : bool or float, float, bool
        The vortex population (a campaign's ``[statistics] vortices``, ``vortex_threshold``
        (``vortices``: True for 1.5, or the threshold), ``vortex_min_diameter``,
        ``vortex_fits`` and ``vortex_fit_shear``; :mod:`rspiv.vector_structures`), in the
        second pass; it implies ``vorticity`` (least squares) for the thresholds, and needs
        wall units.
    window : (w, h), optional
        The final window where the files do not say (else twice the grid's spacing, said).
    read_options : dict, optional
        For :func:`rspiv.vector_files.read_vectors` (OpenPIV's ``y_up``, ``scale``, ``dt``).
    out_dir : path, optional
        Keep a checkpoint there (``checkpoint.pkl`` every ``checkpoint_every`` fields): a run
        stopped and started again with the same files and options resumes. Only what decides
        the sums must be the same (the reading, the calibration and mapping, the levelling):
        a finished run started again with other units, ``nu``, ``wall_y`` or ``u_inf`` is
        analysed again from its checkpoint without reading a file.
    progress : callable(done, total), optional
        Called after each field of each pass; ``total`` counts the second pass's fields when
        one is asked, and grows by the POD's reads once its domain is known.
    readers : int, optional
        Processes that read the files ahead of their use (:mod:`rspiv.vector_readahead`; the
        sums are the same, bit for bit); 0 reads in this process. None: one per core for a
        series of 64 fields or more, else 0.

    Returns
    -------
    VectorStatistics

    Raises
    ------
    InvalidInputError
        One line: no usable field, a bad option, no wall seen, too few points beyond it.
    """
    t_start = time.perf_counter()
    if not (np.isfinite(nu) and nu > 0):
        raise InvalidInputError(f"statistics: nu = {nu} m^2/s must be positive")
    for name, val in (("dt", dt), ("mm_per_px", mm_per_px), ("u_inf", u_inf)):
        if val is not None and not (np.isfinite(val) and val > 0):
            raise InvalidInputError(f"statistics: {name} = {val} must be positive")
    if wall not in ("auto", "bottom", "top"):
        raise InvalidInputError(f"statistics: wall {wall!r}: auto, bottom or top")
    if wall_y is not None and not (np.isfinite(wall_y) and wall in ("bottom", "top")):
        raise InvalidInputError(
            f"statistics: wall_y = {wall_y} needs wall='bottom' or 'top' (where the flow is)"
        )
    if wall_y_units not in ("px", "file"):
        raise InvalidInputError(f"statistics: wall_y_units {wall_y_units!r}: px or file")
    scheme = "least_squares" if vorticity is True else (vorticity or None)
    if vortices is not False and scheme is None:  # the thresholds are the swirl's rms
        scheme = "least_squares"
    if scheme is not None and scheme not in SCHEMES:
        raise InvalidInputError(
            f"statistics: vorticity {vorticity!r}: True or one of {sorted(SCHEMES)}"
        )
    if readers is not None and (isinstance(readers, bool) or not isinstance(readers, int)
                                or readers < 0):
        raise InvalidInputError(f"statistics: readers = {readers!r}: a whole number >= 0")
    if level not in ("auto", True, False):
        raise InvalidInputError(f"statistics: level {level!r}: auto, True or False")
    so = structure_options(two_point, two_point_maps, quadrant, conditional, conditional_hole,
                           pod, pod_modes, pod_height, vortices, vortex_min_diameter,
                           vortex_fits, vortex_fit_shear)  # fmt: skip
    entries = series_entries(files)
    opts = dict(read_options or {})
    # the first readable field fixes the series
    first, start, skipped = None, 0, {}
    for k, e in enumerate(entries):
        try:
            first, start = read_entry(e, opts), k
            break
        except RspivError as exc:
            skipped[entry_name(e)] = str(exc)
    if first is None:
        raise InvalidInputError(
            f"statistics: no field could be read ({next(iter(skipped.values()))})"
        )
    if wall_y is not None and wall_y_units == "file":  # to the positions as read
        if first.y_from_file is None:
            raise InvalidInputError(
                f"statistics: wall_y in the files' units: {entry_name(entries[start])} gives its "
                "positions in px (give wall_y in px)"
            )
        a, b = first.y_from_file
        wall_y = a * float(wall_y) + b
    if not first.origin_known:  # positions up to a constant: the recording's px unknown
        given = [k for k, v in (("a calibration", calibration),
                                ("wall_y in px", wall_y if wall_y_units == "px" else None))
                 if v is not None]  # fmt: skip
        if given:
            raise InvalidInputError(
                f"statistics: {entry_name(entries[start])}: its positions are the recording's px "
                f"only up to its calibration's offset (a calibrated export): {given[0]} needs "
                "them; export the fields in px"
                + (" (or give wall_y in the files' units)" if given[0] == "wall_y in px" else "")
            )
    # what the reader assumed or left out (a 3C field's w, a file without validity flags, the
    # file's rounded positions): said once, of the first file
    warnings: list[str] = [f"as read ({entry_name(entries[start])}): {n}" for n in first.notes]
    cal_scale = None
    if calibration is not None:
        mag = float(calibration.magnification)
        cal_scale = 1.0 / mag
        if np.isfinite(first.mm_per_px) and abs(first.mm_per_px / cal_scale - 1) > _SCALE_TOLERANCE:
            warnings.append(
                f"the files' scale {first.mm_per_px:.5g} mm/px is "
                f"{100 * (first.mm_per_px / cal_scale - 1):+.1f} % from the calibration's "
                f"{cal_scale:.5g}: are they of this camera and this calibration?"
            )
    scale = cal_scale or (first.mm_per_px if np.isfinite(first.mm_per_px) else mm_per_px)
    pulse = first.dt if np.isfinite(first.dt) else dt
    for what, given, used in (("dt", dt, pulse), ("mm_per_px", mm_per_px, scale)):
        if given is not None and used is not None and abs(given / used - 1) > 1e-6:
            src = "calibration's" if what == "mm_per_px" and cal_scale else "files'"
            warnings.append(f"{what} = {given:.6g} given, the {src} {used:.6g} used")
    if window is None:
        window = first.window
    if window is None:
        sx, sy = (
            abs(float(first.x[0, 1] - first.x[0, 0])),
            abs(float(first.y[1, 0] - first.y[0, 0])),
        )
        window = (int(round(2 * sx)), int(round(2 * sy)))
        warnings.append(
            f"the files do not give the final window: {window[0]} x {window[1]} px assumed "
            "(twice the grid's spacing; give window=)"
        )
    frame = "object" if (calibration is not None or first.frame == "object") else first.frame
    if frame == "image":
        warnings.append(
            "fields of the raw frames, not corrected: the lens distortion is in these statistics "
            + ("(give the camera's calibration)" if first.origin_known else
               "(export the fields in px to give the camera's calibration)")
        )  # fmt: skip
    xs, ys = first.x[0].copy(), first.y[:, 0].copy()
    gx, gy = np.meshgrid(xs, ys)
    red = SeriesReducer(first, scale, pulse)
    levelled = level if wall_y is None else False  # a wall given is not looked for
    # what decides the sums (the units, nu and the analysis' options do not: a finished run
    # started again with other ones is analysed again from its checkpoint)
    settings: dict[str, Any] = {
        "read": opts, "mapping": mapping, "level": levelled, "screen": float(screen),
        "vorticity": scheme,
        "calibration": None if calibration is None else calibration.mapping.to_json(),
    }  # fmt: skip
    if levelled is not False:
        settings.update(pilot=pilot, wall=wall, stations=stations, min_count=min_count)
    if so.two_point is not None:
        settings["two_point"] = so.two_point
    if so.maps is not None:  # the two-point sums move to the second pass
        settings["two_point_pass"] = 2
    ck_path = None if out_dir is None else pathlib.Path(out_dir) / "checkpoint.pkl"
    key = fingerprint(settings)
    state = load_checkpoint(ck_path, key, entries)
    base = calibration.mapping if calibration is not None else None
    pilot_said: list[str] = []  # what the pilots say, kept with the checkpoint
    n_readers = auto_readers(len(entries)) if readers is None else int(readers)
    reads = ReadAhead(entries, opts, n_readers)
    with reads:  # its processes end with the first pass (the second pass starts them again)
        if state is None:
            rotation, base = levelling(
                reads, start, first, red, base, calibration, mapping, levelled, pilot,
                (gx, gy), (wall, stations, min_count), pilot_said,
            )  # fmt: skip
            state = {"done": 0, "acc": FieldAccumulator(first.u.shape), "skipped": skipped,
                     "rotation": rotation, "warnings": pilot_said, "bounds": None}  # fmt: skip
            state["acc"].locking = LockingHistogram()
            state["acc"].rows = RowErrors(first.u.shape[0])  # the profile's errors by field
            if scheme is not None:
                dx, dy = float(xs[1] - xs[0]), float(ys[1] - ys[0])
                state["acc"].vorticity = VorticityAccumulator(first.u.shape, dx, dy, scheme)
        elif calibration is None and state["rotation"] != 0.0:
            base = identity_mapping(xs, ys).rotated(state["rotation"])
        elif calibration is not None:
            base = calibration.mapping.rotated(state["rotation"])
        on = calibration is not None or state["rotation"] != 0.0
        transform = field_transform(base, on, mapping)
        acc = state["acc"]
        if state["done"] == 0 and (screen > 0 or so.two_point is not None):
            pilots, used = pilot_fields(reads, red, transform, pilot)
            if screen > 0:
                state["bounds"] = _screen(pilots, used, float(screen), state["warnings"])
                if state["bounds"] is not None:
                    acc.screen = ScreenTally(acc.shape)
            if so.two_point is not None:
                state["columns"] = two_point_columns(pilots, so.two_point)
                if so.maps is None:
                    acc.two_point = TwoPointAccumulator(acc.shape, state["columns"], so.two_point)
        n_all = len(entries) * (2 if so.second else 1)  # the second pass counts (not the POD's)
        reads.along([k for k in range(state["done"], len(entries)) if k != start])
        for k in range(state["done"], len(entries)):
            e = entries[k]
            try:
                vf = first if k == start else reads.get(k)
                why = red.check(vf)
                if why:
                    raise InvalidInputError(why)
                red.add(acc, transform(vf), k, state["bounds"])
            except RspivError as exc:
                state["skipped"][entry_name(e)] = str(exc)
            state["done"] = k + 1
            if progress is not None:
                progress(k + 1, n_all)
            if ck_path is not None and (k + 1) % max(int(checkpoint_every), 1) == 0:
                save_checkpoint(ck_path, key, entries, state)
    if acc.n_fields == 0:
        raise InvalidInputError(
            f"statistics: no field could be used ({next(iter(state['skipped'].values()))})"
        )
    if ck_path is not None:
        save_checkpoint(ck_path, key, entries, state)
    warnings += state["warnings"]
    if state["skipped"]:
        name, why = next(iter(state["skipped"].items()))
        warnings.append(f"{len(state['skipped'])} field(s) skipped, the first {name}: {why}")
    cfg = SimpleNamespace(
        statistics=StatisticsConfig(min_count=min_count, noise_correction=noise_correction),
        wall=WallConfig(side=wall, stations=stations),
        flow=FlowConfig(nu=nu, dt=pulse or 0.0, u_inf=u_inf or 0.0),
    )
    run = RunSpec("vectors", f"{first.tool} fields", "II" if calibration is not None else "none")
    mag = None if scale is None else 1.0 / scale
    an = analyse_run(run, acc, gx, gy, cfg, mag, pulse or 0.0, window, wall_y)
    rise, row = wall_rise(an.wall, gx, gy) if an.wall is not None else (0.0, 1.0)
    if state["rotation"] == 0.0 and rise > 0.5 * row:
        warnings.append(
            f"the wall rises {rise:.2f} px across the field (angle {an.wall.angle_deg:.4f} deg) "
            f"and was not levelled: each row's profile mixes wall distances over {rise:.2f} px "
            "(a calibration levels it; level=True rotates the fields)"
        )
    sag = wall_bow(an.wall) if an.wall is not None else 0.0
    if abs(sag) > max(0.25 * row, 1.0):
        hint = (
            "is the calibration this camera's?"
            if calibration is not None
            else "a straight wall seen through an uncorrected lens does this: give the "
            "camera's calibration"
        )
        warnings.append(
            f"the wall bows by {sag:+.1f} px across the field (a parabola through its "
            f"stations; more than a quarter of a row): {hint}"
        )
    locking = acc.locking.result() if acc.locking is not None else {}
    if locking.get("said"):
        bound = (
            " (a lower bound: Method II maps the raw frame's displacements)" if calibration else ""
        )
        warnings.append(
            f"peak locking: the fields' displacements lean towards whole pixels, amplitude "
            f"{locking['amplitude_px']:.3f} +- {locking['standard_error_px']:.3f} px over "
            f"{locking['pairs']} fields{bound}; it does not average out (the mean, v'v' and the "
            "PDFs carry it): particle images under 2 px or saturated, or the tool's sub-pixel fit"
        )
    vort = None
    if acc.vorticity is not None:
        vort = vorticity_profile(acc, an, min_count, pulse or 0.0, window[1])

    def save() -> None:
        if ck_path is not None:
            save_checkpoint(ck_path, key, entries, state)

    passes = {"entries": entries, "reads": reads, "reducer": red, "transform": transform,
              "bounds": state["bounds"], "state": state, "save": save,
              "every": checkpoint_every, "progress": progress}  # fmt: skip
    with reads:
        found, said = structures(so, acc, an, window, xs, min_count, passes, pulse or 0.0)
    warnings += said
    if an.result is not None and an.result.warning:
        warnings.append(an.result.warning)
    if an.result is None:
        warnings.append(f"no wall units: {an.error}")
    warnings += reads.notes
    conv = profile_convergence(acc, an.profile, NEAR_WALL_HEIGHTS * window[1])
    if conv is not None:
        warnings += [w for w in (conv.warning, conv.serial_warning) if w]
    return VectorStatistics(
        acc, xs, ys, an, first.tool, frame, int(acc.n_fields), state["skipped"],
        float("nan") if scale is None else float(scale), float("nan") if pulse is None else pulse,
        (int(window[0]), int(window[1])), float(state["rotation"]), warnings, locking, vort,
        *(found[k] for k in STRUCTURES), time.perf_counter() - t_start, conv,
    )  # fmt: skip


def _screen(pilots: list, used: list[int], sigmas: float, warnings: list[str]) -> Any:
    """The screen's bounds (:func:`rspiv.outlier_screen.screen_bounds`, row by row: a wall's
    layer) from the pilot fields (:func:`rspiv.vector_reduction.pilot_fields`: up to 20 spread
    evenly over the series, as the statistics will see them); None with fewer than 3 (said)."""
    if len(pilots) < 3:
        warnings.append(
            f"no screen of the statistics: {len(pilots)} usable pilot field(s), 3 needed"
        )
        return None
    us, vs, oks = zip(*pilots, strict=True)
    return screen_bounds(us, vs, oks, sigmas=sigmas, half_width=HALF_WIDTH, pairs=used)
