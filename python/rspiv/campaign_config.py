"""The campaign file: a TOML description of one PIV campaign, its schema, loader and writer.

A complete file (every key optional except where noted; defaults shown)::

    [campaign]
    name = "campaign"
    description = ""

    [calibration]
    target = "target.tif"        # calibration target image (omit: no calibration)
    pitch_mm = 19.51             # marker pitch, and its one-sigma uncertainty
    pitch_sigma_mm = 0.02
    model = "P3"                 # "R1" | "R2" | "P3" (any case)
    marker = "dot"               # "dot" | "cross"
    marker_size_px = 0.0         # 0: estimated from the image
    monte_carlo_samples = 10000  # 0: no Monte Carlo
    level = 0                    # two-level plate: 1 (nearer) | 2; 0: the fiducial's, else 1

    [images]                     # exactly one of glob / pairs / multiframe / double_frame
    glob = "raw/*.tif"           # sorted; consecutive files form the pairs (1-2, 3-4, ...)
    # pairs = [["a0.tif", "b0.tif"], ["a1.tif", "b1.tif"]]
    # multiframe = "run.tif"     # frames (0, 1), (2, 3), ... of one TIFF or Photron .cihx
    # double_frame = "run/*.im7" # one pair per file, frames 0 and 1: DaVis double-frame
                                 # buffers (.im7/.imx/.ims, needs rspiv[davis]) or 2-page TIFFs;
                                 # a DaVis "Run.set" means the files Run/*.im7
    max_pairs = 0                # 0: all
    pairing = "pairs"            # glob / multiframe: "pairs" (frames 1-2, 3-4, ...: a
                                 # double-frame camera) | "sequential" (frames k and
                                 # k + frame_gap for k = 0, pair_step, 2 pair_step, ...: a
                                 # time-resolved recording; each frame is read once)
    frame_gap = 1                # sequential: frame B is frame_gap frames after frame A
                                 # ([flow] dt is then the time across those frame_gap frames)
    pair_step = 1                # sequential: frames between the first frames of two pairs
    rotate = 0                   # 0 | 90 | 180 | 270: degrees counter-clockwise every frame,
                                 # the target and the mask are turned as read (flow along +x)
    mirror = false               # mirror them left-right before the turn (a camera looking
                                 # through a mirror)
    check_pairs = 5              # pairs spread over the run whose seeding, background,
                                 # brightness and displacement are checked before the PIV
                                 # (0: off; under 2: reversed pairs are not looked for)
    exclude_pairs = []           # pair ids (0-based positions in the pair list) left out,
                                 # e.g. the pairs summary.json's pair_outliers names
                                 # (a finished campaign with [output] fields re-reduces
                                 # its statistics from the field files, without the PIV)

    [correction]
    method = "II"                # "I" (dewarp images, then PIV) | "II" (PIV, then map) | "none"
                                 # (any case; "images" = "I", "vectors" = "II")
    mapping = "full"             # Method II: "full" (through the exact inverse) | "positions"
                                 # (old key: map_displacement = true | false)
    compare_uncorrected = true   # also process without correction (for the report)

    [piv]                        # the keys of rspiv.PivSettings (one vocabulary with the API
                                 # and rspiv-engine piv --settings), campaign defaults:
    passes = [[64, 64], [32, 32], [32, 8]]   # interrogation windows [w, h] in px, coarse first
    overlap = 0.5
    iterations = 1               # correlation iterations per pass
    deformation = "offset"       # "offset" | "symmetric" (old key: deform = false | true)
    interpolation = "bspline"    # "bspline" (quintic) | "bspline3" | "keys"
    subpixel = "gauss3"          # "gauss3" | "gauss2d"
    weighting = "tophat"         # "tophat" | "gaussian" | "blackman" (window weighting)
    validate = true              # normalised median test (Westerweel & Scarano 2005)
    median_threshold = 2.0
    median_eps = 0.1             # px (old key: median_epsilon)
    min_peak_ratio = 0.0         # 0: off
    peak_candidates = 3          # correlation peaks tried before interpolating (1: off)
    uncertainty = true           # per-vector uncertainty (Wieneke 2015), sigma_u / sigma_v
    mask = ""                    # optional mask: an image (non-zero = excluded) or a JSON of
                                 # polygons in px (rspiv.io.read_mask); "" : none

    [preprocess]                 # rspiv.preprocess.Preprocess, applied to the raw frames
                                 # before every PIV; the defaults are rspiv.preprocess.NEAR_WALL
                                 # (all three below "none"/0: the raw intensities)
    background = "min"           # "none" | "min" | "mean": over the run, per frame A and B
    hot_pixels = 3.0             # factor over the brightest neighbour (0: off)
    high_pass = 2.0              # Gaussian sigma, px (0: off)
    smooth = 0.0                 # Gaussian smoothing sigma, px, <= 2 (0: off; 0.4-0.7 px
                                 # against peak locking: particle images under 2 px)
    cap = 0.0                    # cap at mean + cap * std (0: off)
    min_max = 0                  # min-max normalisation window, px (0: off)

    [wall]
    enabled = true
    side = "auto"                # "auto" | "top" | "bottom"
    rotate = true                # remove the target's rotation found from the wall
    stations = 16                # streamwise stations for the wall fit

    [flow]
    nu = 1.5e-5                  # kinematic viscosity, m^2/s
    dt = 0.0                     # pulse separation, s (0: outputs stay in px per pair)
    u_inf = 0.0                  # free stream, m/s (0: from the profile)

    [statistics]
    min_count = 10               # vectors with fewer valid samples are left out of profiles
    use_n_eff = true             # uncertainties from the lag-1 effective sample count
    fit_offset = true            # fit the wall offset in the composite fit
    reference_re_theta = 0.0     # DNS station for plots (0: the closest in Re_tau)
    noise_correction = false     # subtract each vector's mean sigma^2 from uu and vv
                                 # (rspiv.stats "Measurement noise"; needs [piv] uncertainty)
    two_point = false            # streamwise spectra and two-point correlations per row
                                 # (rspiv.two_point; two_point_<run>.nc, a report section)
    two_point_min_valid = 0.9    # fraction of valid vectors a row of a pair needs to enter
    two_point_heights = [0.1, 0.3, 0.6]  # reference heights of the two-point maps ([]: none)
    two_point_height_units = "delta"     # "delta" (the pilot's delta_99) | "px" from the wall
    quadrant = false             # quadrant analysis of u'v' and joint PDFs per row, a second
                                 # pass over the fields (rspiv.quadrant; needs [output] fields;
                                 # quadrant_<run>.nc, a report section)
    quadrant_holes = [0, 1, 2, 4]  # hole sizes H: |u'v'| >= H u_rms v_rms
    pod = false                  # snapshot POD of the fluctuations, a second pass over the
                                 # fields (rspiv.pod; needs [output] fields; pod_<run>.nc, a
                                 # report section)
    pod_modes = 10               # modes kept (1-200)
    pod_snapshots = 1000         # at most this many pairs, spread evenly over the run
    pod_height = 0.0             # domain up to this many delta_99 from the wall (0: all)
    vorticity = false            # per-vector statistics of the vorticity and swirling strength
                                 # (rspiv.vorticity; vorticity_<run>.nc, a report figure)
    vorticity_scheme = "least_squares"  # "central" | "least_squares" | "richardson"
    vortices = false             # vortex cores per pair and their population by height, a
                                 # second pass over the fields (rspiv.vortices; needs [output]
                                 # fields and vorticity; vortices_<run>.nc, a report figure)
    vortex_threshold = 1.5       # |Lambda_ci| >= this times its rms at the core's height
    vortex_min_diameter = 1.0    # cores smaller than a disc this many final windows wide
                                 # are dropped (not resolved; mostly noise)
    vortex_fits = true           # a Lamb-Oseen vortex fitted to each core: core radius,
                                 # circulation, convection (rspiv.fit_oseen; ~0.2 ms a core)
    vortex_fit_shear = false     # ... in a uniform background shear (Stanislas et al. 2008)
    conditional = false          # conditional averages of u', v' about ejections (Q2) and
                                 # sweeps (Q4) at reference heights, a second pass over the
                                 # fields (rspiv.conditional; needs [output] fields;
                                 # conditional_<run>.nc, a report figure)
    conditional_heights = [0.15, 0.4]    # the events' heights (1 to 8, increasing)
    conditional_height_units = "delta"   # "delta" (the run's delta_99) | "px" from the wall
    conditional_hole = 1.0       # events with |u'v'| >= this times u_rms v_rms
    temporal = false             # frequency spectra, space-time correlations and convection
                                 # velocities of a time-resolved recording at reference
                                 # heights, a second pass over the fields (rspiv.temporal;
                                 # needs [output] fields and [images] pairing = "sequential";
                                 # temporal_<run>.nc, a report figure)
    temporal_heights = [0.15, 0.4]       # the reference heights (1 to 8, increasing)
    temporal_height_units = "delta"      # "delta" (the run's delta_99) | "px" from the wall
    temporal_segment = 256       # pairs per Welch segment (even, 8-65536)
    temporal_max_lag = 32        # the correlations' largest time lag, pair intervals
    spod = false                 # spectral POD of a time-resolved recording, a second pass
                                 # over the fields (rspiv.spod; needs [output] fields and
                                 # pairing = "sequential"; spod_<run>.nc, a report figure)
    spod_segment = 256           # pairs per block (even, 8-65536), blocks overlap by half
    spod_modes = 3               # leading modes kept at each chosen frequency (1-50)
    spod_frequencies = 6         # frequencies whose modes are kept: largest f lambda_1 (1-64)
    spod_height = 0.0            # domain up to this many delta_99 from the wall (0: all)
    screen = 7.0                 # leave out of the statistics a vector farther than this
                                 # many local spreads from its pilot pairs' centre (a random
                                 # vector the median test passed: rspiv.outlier_screen; 0: off)

    [ensemble]                   # ensemble correlation in a band at the wall (rspiv.ensemble):
                                 # correlation planes summed over every pair, then the peak
    enabled = false
    window = [64, 4]             # [w, h] px of the ensemble windows (h along the wall normal)
    step = [64, 2]               # [sx, sy] px between window centres (along, away from the wall);
                                 # the profile sums each row's windows, so overlap along the wall
                                 # adds memory (the planes of every window), not accuracy
    band = 60.0                  # height of the band from the wall (see band_units)
    band_units = "px"            # "px" | "plus" (wall units of the pilot's profile fit)
    auto_pairs = 200             # pairs whose auto planes (the particle images) are summed
    single_pixel = false         # also single-pixel ensemble correlation in rows at the wall
                                 # (rspiv.ensemble_pixel): one px wall-normal resolution; rows
                                 # the wall biases (within two particle-image widths) are
                                 # flagged near_wall in the outputs
    pixel_band = 10.0            # height of the single-pixel rows from the wall (band_units)
    pixel_step = 0.5             # px between the rows (the first one step from the wall)
    pixel_segment = 64           # px along the wall per summed segment (>= 8)
    pixel_lags = [8, 3]          # lag half-ranges [x, y] px around the pilot's profile

    [ptv]                        # particle tracking at the wall after the analysis, over the
                                 # campaign's first run (rspiv.campaign.ptv; needs [output]
                                 # fields): OUT/ptv_<run>.csv/.json/.png and a report section;
                                 # `rspiv ptv` takes its settings from here
    enabled = false
    runs = []                    # the runs to track ("method_II", "method_I", "uncorrected");
                                 # none given: the first
    radius = 2.0                 # search radius about each predicted position, px
    bin_px = 0.5                 # bin height, px
    band_px = 32.0               # band from the wall, px
    whole_frame = false          # search the whole frames, not only the rows near the wall

    [output]
    dir = "rspiv-out"
    netcdf = true
    csv = true
    report = true
    fields = false               # every pair's vector fields: OUT/fields/<run>/pair_<id>.nc
                                 # (rspiv.campaign.fields; 12 MB per 47 MP pair and run)

Paths are relative to the campaign file's folder; the loader makes them absolute. Any error
(malformed TOML, a wrong type, an unknown key) raises :class:`~rspiv.errors.InvalidInputError`
with a one-line message naming the file and the key, e.g.
``campaign.toml: [piv].passes: expected a list of [w, h] pairs, got 'abc'``.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import Any

try:  # Python >= 3.11
    import tomllib as _toml
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as _toml  # type: ignore[no-redef]

from rspiv.campaign_schema import (
    ALIASES,
    PARSERS,
    Ctx,
    dump_toml,
    locate_toml_error,
    parse_pairs,
    toml_plain,
)
from rspiv.errors import InvalidInputError
from rspiv.outlier_screen import SIGMAS as SCREEN_SIGMAS
from rspiv.outputs import atomic_write_text
from rspiv.preprocess import Preprocess
from rspiv.settings import (
    OPTION_KEYS,
    PivSettings,
)


# ---------------------------------------------------------------------------- sections
@dataclasses.dataclass
class CalibrationConfig:
    target: pathlib.Path | None = None
    pitch_mm: float = 19.51
    pitch_sigma_mm: float = 0.02
    model: str = "P3"
    marker: str = "dot"
    marker_size_px: float = 0.0
    monte_carlo_samples: int = 10000
    level: int = 0


@dataclasses.dataclass
class ImagesConfig:
    glob: str | None = None
    pairs: list[tuple[pathlib.Path, pathlib.Path]] | None = None
    multiframe: pathlib.Path | None = None
    double_frame: str | None = None
    max_pairs: int = 0
    pairing: str = "pairs"
    frame_gap: int = 1
    pair_step: int = 1
    #: degrees counter-clockwise (0, 90, 180, 270) every frame, the target and the mask
    #: image are turned as they are read (:func:`rspiv.io.turn_frame`)
    rotate: int = 0
    #: mirror them left-right before the turn
    mirror: bool = False
    #: pairs spread over the run checked for drift before the PIV
    #: (:func:`rspiv.recording_drift.check_drift`; 0: off)
    check_pairs: int = 5
    #: pair ids (positions in the full pair list) left out of the campaign
    exclude_pairs: list[int] = dataclasses.field(default_factory=list)

    def frame_pairs(self, n: int, source: str, *, odd_ok: bool = False) -> list[tuple[int, int]]:
        """The (frame A, frame B) indices of ``n`` frames in order (files of ``glob``, pages
        of ``multiframe``, named by ``source`` in errors), as ``pairing`` forms them.

        ``odd_ok``: with ``pairs``, an odd last frame is left out (the pages of one stack: a
        recording stopped after frame A) rather than refused (files: one may be missing
        anywhere, and every pair after it would be formed wrongly).

        Raises
        ------
        InvalidInputError
            ``pairs`` with an odd number of frames (unless ``odd_ok``); ``sequential`` with
            ``frame_gap`` frames or fewer.
        """
        if self.pairing == "sequential":
            if n <= self.frame_gap:
                raise InvalidInputError(
                    f"{source}: {n} frame(s); sequential pairing with frame_gap = "
                    f"{self.frame_gap} needs at least {self.frame_gap + 1}"
                )
            out = [(k, k + self.frame_gap) for k in range(0, n - self.frame_gap, self.pair_step)]
        else:
            if n % 2 and odd_ok:
                n -= 1
            if n % 2:
                raise InvalidInputError(
                    f"{source}: {n} frames; pairs (1-2, 3-4, ...) need an even count "
                    '(a time-resolved recording: [images] pairing = "sequential")'
                )
            out = [(k, k + 1) for k in range(0, n, 2)]
        return out[: self.max_pairs] if self.max_pairs else out

    def orientation(self) -> int:
        """The frames' orientation code of :func:`rspiv.io.turn_frame`: ``rotate`` in quarter
        turns, plus 4 when ``mirror``."""
        return self.rotate // 90 + (4 if self.mirror else 0)

    def pairing_info(self) -> dict[str, Any] | None:
        """``summary.json``'s ``pairing`` entry: the keys and :meth:`describe_pairing` for
        sequential pairing, None for pairs."""
        if self.pairing != "sequential":
            return None
        return {
            "pairing": self.pairing,
            "frame_gap": self.frame_gap,
            "pair_step": self.pair_step,
            "description": self.describe_pairing(),
        }

    def describe_pairing(self) -> str:
        """One line: how the frames form pairs."""
        if self.pairing != "sequential":
            return "frames 1-2, 3-4, ... (pairs)"
        step = "every frame" if self.pair_step == 1 else f"every {self.pair_step} frames"
        return f"frames k and k + {self.frame_gap}, {step} (sequential, time-resolved)"

    def double_frame_files(self) -> list[pathlib.Path]:
        """The files of ``double_frame`` (a glob, or a DaVis ``.set`` standing for the
        ``*.im7`` files of its folder), sorted. InvalidInputError when nothing matches."""
        assert self.double_frame is not None
        pattern = pathlib.Path(self.double_frame)
        if pattern.suffix.lower() == ".set":
            pattern = pattern.with_suffix("") / "*.im7"
        files = sorted(pattern.parent.glob(pattern.name))
        if not files:
            raise InvalidInputError(f"[images].double_frame: no file matches {str(pattern)!r}")
        return files[: self.max_pairs] if self.max_pairs else files

    def pair_files(self) -> list[tuple[pathlib.Path, pathlib.Path]]:
        """The (frame A, frame B) files for ``glob`` or ``pairs`` (not for ``multiframe``).

        Raises
        ------
        InvalidInputError
            If the glob matches nothing, or too few or an odd number of files for the
            pairing (:meth:`frame_pairs`).
        """
        if self.pairs is not None:
            out = list(self.pairs)
        elif self.glob is not None:
            pattern = pathlib.Path(self.glob)
            files = sorted(pattern.parent.glob(pattern.name))
            if not files:
                raise InvalidInputError(f"[images].glob: no file matches {self.glob!r}")
            idx = self.frame_pairs(len(files), f"[images].glob {self.glob!r}")
            return [(files[i], files[j]) for i, j in idx]
        else:
            raise InvalidInputError("[images]: multiframe input has frames, not pair files")
        return out[: self.max_pairs] if self.max_pairs else out


@dataclasses.dataclass
class CorrectionConfig:
    method: str = "II"
    map_displacement: bool = True
    compare_uncorrected: bool = True

    @property
    def mapping(self) -> str:
        """Method II's displacement mapping in the one vocabulary: "full" or "positions"."""
        return "full" if self.map_displacement else "positions"


@dataclasses.dataclass
class PIVConfig:
    """The ``[piv]`` section: the keys of :class:`rspiv.PivSettings` (campaign default
    deformation "offset") and the mask. ``roi = [x0, y0, x1, y1]`` (px, raw frames for the
    uncorrected run, object px for Methods I and II) lays every run's grid out in that region
    and reads only it and a margin: the alignment's PIV too, so the region must hold the wall."""

    passes: list[tuple[int, int]] = dataclasses.field(
        default_factory=lambda: [(64, 64), (32, 32), (32, 8)]
    )
    overlap: float = 0.5
    iterations: int = 1
    deformation: str = "offset"
    interpolation: str = "bspline"
    subpixel: str = "gauss3"
    weighting: str = "tophat"
    validate: bool = True
    median_threshold: float = 2.0
    median_eps: float = 0.1
    min_peak_ratio: float = 0.0
    peak_candidates: int = 3
    uncertainty: bool = True
    roi: list[int] | None = None
    mask: pathlib.Path | None = None

    def settings(self) -> PivSettings:
        """The section as the one PIV settings object."""
        return PivSettings(
            passes=tuple(tuple(p) for p in self.passes),
            overlap=self.overlap,
            iterations=self.iterations,
            **{k: getattr(self, k) for k in OPTION_KEYS},
        )


@dataclasses.dataclass
class PreprocessConfig:
    """The ``[preprocess]`` section: the keys of :class:`rspiv.preprocess.Preprocess`. The
    defaults are ``rspiv.preprocess.NEAR_WALL`` (background = "min", hot_pixels = 3,
    high_pass = 2: what a boundary-layer recording needs, tests/test_campaign_lighting.py);
    ``background = "none"``, ``hot_pixels = 0``, ``high_pass = 0`` turn it off. The background
    is estimated over the whole run, per frame A and B."""

    background: str = "min"
    percentile: float = 5.0
    hot_pixels: float = 3.0
    high_pass: float = 2.0
    cap: float = 0.0
    min_max: int = 0
    smooth: float = 0.0

    def settings(self) -> Preprocess:
        """The section as the preprocessing settings object."""
        return Preprocess(**dataclasses.asdict(self))


@dataclasses.dataclass
class WallConfig:
    enabled: bool = True
    side: str = "auto"
    rotate: bool = True
    stations: int = 16


@dataclasses.dataclass
class FlowConfig:
    nu: float = 1.5e-5
    dt: float = 0.0
    u_inf: float = 0.0


@dataclasses.dataclass
class StatisticsConfig:
    min_count: int = 10
    use_n_eff: bool = True
    fit_offset: bool = True
    reference_re_theta: float = 0.0
    noise_correction: bool = False
    two_point: bool = False
    two_point_min_valid: float = 0.9
    two_point_heights: tuple[float, ...] = (0.1, 0.3, 0.6)
    two_point_height_units: str = "delta"
    quadrant: bool = False
    quadrant_holes: tuple[float, ...] = (0.0, 1.0, 2.0, 4.0)
    pod: bool = False
    pod_modes: int = 10
    pod_snapshots: int = 1000
    pod_height: float = 0.0
    vorticity: bool = False
    vorticity_scheme: str = "least_squares"
    vortices: bool = False
    vortex_threshold: float = 1.5
    vortex_min_diameter: float = 1.0
    vortex_fits: bool = True
    vortex_fit_shear: bool = False
    conditional: bool = False
    conditional_heights: tuple[float, ...] = (0.15, 0.4)
    conditional_height_units: str = "delta"
    conditional_hole: float = 1.0
    temporal: bool = False
    temporal_heights: tuple[float, ...] = (0.15, 0.4)
    temporal_height_units: str = "delta"
    temporal_segment: int = 256
    temporal_max_lag: int = 32
    spod: bool = False
    spod_segment: int = 256
    spod_modes: int = 3
    spod_frequencies: int = 6
    spod_height: float = 0.0
    screen: float = SCREEN_SIGMAS


@dataclasses.dataclass
class EnsembleConfig:
    enabled: bool = False
    window: tuple[int, int] = (64, 4)
    step: tuple[float, float] = (64.0, 2.0)
    band: float = 60.0
    band_units: str = "px"
    auto_pairs: int = 200
    single_pixel: bool = False
    pixel_band: float = 10.0
    pixel_step: float = 0.5
    pixel_segment: int = 64
    pixel_lags: tuple[int, int] = (8, 3)


@dataclasses.dataclass
class PtvConfig:
    enabled: bool = False
    runs: tuple[str, ...] = ()
    radius: float = 2.0
    bin_px: float = 0.5
    band_px: float = 32.0
    whole_frame: bool = False


@dataclasses.dataclass
class OutputConfig:
    dir: pathlib.Path = dataclasses.field(default_factory=lambda: pathlib.Path("rspiv-out"))
    netcdf: bool = True
    csv: bool = True
    report: bool = True
    fields: bool = False


_SECTIONS: dict[str, type] = {
    "calibration": CalibrationConfig,
    "images": ImagesConfig,
    "correction": CorrectionConfig,
    "piv": PIVConfig,
    "preprocess": PreprocessConfig,
    "wall": WallConfig,
    "flow": FlowConfig,
    "statistics": StatisticsConfig,
    "ensemble": EnsembleConfig,
    "ptv": PtvConfig,
    "output": OutputConfig,
}


@dataclasses.dataclass
class CampaignConfig:
    """A whole campaign (see the module docstring for the file format).

    ``source`` is the file it was read from (None when built in code); paths are absolute
    after :func:`load_campaign_config`.
    """

    name: str = "campaign"
    description: str = ""
    calibration: CalibrationConfig = dataclasses.field(default_factory=CalibrationConfig)
    images: ImagesConfig = dataclasses.field(default_factory=ImagesConfig)
    correction: CorrectionConfig = dataclasses.field(default_factory=CorrectionConfig)
    piv: PIVConfig = dataclasses.field(default_factory=PIVConfig)
    preprocess: PreprocessConfig = dataclasses.field(default_factory=PreprocessConfig)
    wall: WallConfig = dataclasses.field(default_factory=WallConfig)
    flow: FlowConfig = dataclasses.field(default_factory=FlowConfig)
    statistics: StatisticsConfig = dataclasses.field(default_factory=StatisticsConfig)
    ensemble: EnsembleConfig = dataclasses.field(default_factory=EnsembleConfig)
    ptv: PtvConfig = dataclasses.field(default_factory=PtvConfig)
    output: OutputConfig = dataclasses.field(default_factory=OutputConfig)
    source: pathlib.Path | None = None

    # ------------------------------------------------------------------ writing
    def to_dict(self, relative_to: str | os.PathLike | None = None) -> dict[str, Any]:
        """Plain TOML-ready dict; paths relative to ``relative_to`` where possible."""
        base = pathlib.Path(relative_to).resolve() if relative_to is not None else None

        def p(v):
            if v is None:
                return ""
            v = pathlib.Path(v)
            if base is not None:
                try:
                    return os.path.relpath(v.resolve(), base)
                except ValueError:  # other drive on Windows
                    return str(v)
            return str(v)

        out: dict[str, Any] = {"campaign": {"name": self.name, "description": self.description}}
        c = self.calibration
        cal = {
            "pitch_mm": c.pitch_mm,
            "pitch_sigma_mm": c.pitch_sigma_mm,
            "model": c.model,
            "marker": c.marker,
            "marker_size_px": c.marker_size_px,
            "monte_carlo_samples": c.monte_carlo_samples,
            "level": c.level,
        }
        if c.target is not None:
            cal = {"target": p(c.target), **cal}
        out["calibration"] = cal
        im = self.images
        imd: dict[str, Any] = {}
        if im.glob is not None:
            imd["glob"] = p(im.glob)
        if im.pairs is not None:
            imd["pairs"] = [[p(a), p(b)] for a, b in im.pairs]
        if im.multiframe is not None:
            imd["multiframe"] = p(im.multiframe)
        if im.double_frame is not None:
            imd["double_frame"] = p(im.double_frame)
        imd["max_pairs"] = im.max_pairs
        imd["pairing"] = im.pairing
        imd["frame_gap"] = im.frame_gap
        imd["pair_step"] = im.pair_step
        imd["rotate"] = im.rotate
        imd["mirror"] = im.mirror
        imd["check_pairs"] = im.check_pairs
        imd["exclude_pairs"] = list(im.exclude_pairs)
        out["images"] = imd
        out["correction"] = dataclasses.asdict(self.correction)
        pv = dataclasses.asdict(self.piv)
        pv["passes"] = [[int(w), int(h)] for w, h in self.piv.passes]
        pv["mask"] = p(self.piv.mask)
        if self.piv.roi is None:  # TOML has no null: no key is the whole frame
            del pv["roi"]
        else:
            pv["roi"] = [int(v) for v in self.piv.roi]
        out["piv"] = pv
        for name in ("preprocess", "wall", "flow", "statistics", "ensemble", "ptv"):
            out[name] = dataclasses.asdict(getattr(self, name))
        out["ensemble"]["window"] = [int(v) for v in self.ensemble.window]
        out["ensemble"]["step"] = [float(v) for v in self.ensemble.step]
        out["ensemble"]["pixel_lags"] = [int(v) for v in self.ensemble.pixel_lags]
        o = dataclasses.asdict(self.output)
        o["dir"] = p(self.output.dir)
        out["output"] = o
        return toml_plain(out)

    def to_toml(self, relative_to: str | os.PathLike | None = None) -> str:
        """The campaign as TOML text (tomli_w when installed, else a small built-in writer)."""
        data = self.to_dict(relative_to)
        try:
            import tomli_w
        except ModuleNotFoundError:
            return dump_toml(data)
        return tomli_w.dumps(data)

    def save(self, path: str | os.PathLike) -> pathlib.Path:
        """Write the campaign to ``path`` atomically, paths relative to its folder."""
        path = pathlib.Path(path)
        text = self.to_toml(relative_to=path.parent)
        return atomic_write_text(path, text)


# ---------------------------------------------------------------------------- loading
def parse_campaign_config(
    data: dict[str, Any], *, fname: str = "<campaign>", base: str | os.PathLike = "."
) -> CampaignConfig:
    """Validate a parsed TOML dict into a :class:`CampaignConfig` (see the module docstring).

    ``fname`` is used in error messages, ``base`` resolves relative paths.
    """
    ctx = Ctx(fname, pathlib.Path(base).resolve())
    cfg = CampaignConfig()
    for section, table in data.items():
        if section not in PARSERS:
            raise ctx.err(f"[{section}]", f"unknown section; expected one of {', '.join(PARSERS)}")
        if not isinstance(table, dict):
            raise ctx.err(f"[{section}]", f"expected a table, got {table!r}")
        parsers = PARSERS[section]
        values: dict[str, Any] = {}
        for key, val in table.items():
            where = f"[{section}].{key}"
            if key not in parsers:
                raise ctx.err(where, f"unknown key; expected one of {', '.join(parsers)}")
            parse = parse_pairs if (section, key) == ("images", "pairs") else parsers[key]
            name = ALIASES.get((section, key), key)
            if name in values:
                raise ctx.err(where, f"given twice (as {name} and an alias of it)")
            values[name] = parse(ctx, where, val)
        if section == "campaign":
            for k, v in values.items():
                setattr(cfg, k, v)
        else:
            setattr(cfg, section, _SECTIONS[section](**values))
            if section == "preprocess":
                try:
                    cfg.preprocess.settings()
                except InvalidInputError as exc:
                    raise ctx.err("[preprocess]", str(exc)) from None
    given = [
        k for k in ("glob", "pairs", "multiframe", "double_frame") if k in data.get("images", {})
    ]
    if len(given) != 1:
        raise ctx.err(
            "[images]",
            "expected exactly one of glob, pairs, multiframe, double_frame"
            + (f", got {', '.join(given)}" if given else ", got none"),
        )
    im = cfg.images
    if im.pairing != "sequential":
        for key in ("frame_gap", "pair_step"):
            if getattr(im, key) != 1:
                raise ctx.err(f"[images].{key}", 'needs [images] pairing = "sequential"')
    elif im.pairs is not None or im.double_frame is not None:
        raise ctx.err(
            "[images].pairing",
            '"sequential" pairs the frames of glob or multiframe; pairs and double_frame '
            "name their pairs",
        )
    if cfg.correction.method in ("I", "II") and cfg.calibration.target is None:
        raise ctx.err(
            "[calibration].target",
            f"method {cfg.correction.method!r} needs a calibration target (or method = 'none')",
        )
    if cfg.statistics.noise_correction and not cfg.piv.uncertainty:
        raise ctx.err(
            "[statistics].noise_correction",
            "needs the per-vector uncertainty ([piv] uncertainty = true)",
        )
    for key in ("quadrant", "pod", "vortices", "conditional", "temporal", "spod"):
        if getattr(cfg.statistics, key) and not cfg.output.fields:
            raise ctx.err(
                f"[statistics].{key}",
                "needs each pair's fields ([output] fields = true): the second pass reads them",
            )
    for key in ("temporal", "spod"):
        if getattr(cfg.statistics, key) and cfg.images.pairing != "sequential":
            raise ctx.err(
                f"[statistics].{key}",
                'needs a time-resolved recording ([images] pairing = "sequential"): the pairs '
                "of a double-frame camera are not a time series",
            )
    if cfg.statistics.vortices and not cfg.statistics.vorticity:
        raise ctx.err(
            "[statistics].vortices",
            "needs the vorticity statistics ([statistics] vorticity = true): the threshold is "
            "a multiple of the swirling strength's rms",
        )
    if cfg.ptv.enabled and not cfg.output.fields:
        raise ctx.err(
            "[ptv].enabled",
            "needs each pair's fields ([output] fields = true): they predict the tracks",
        )
    if cfg.ptv.bin_px >= cfg.ptv.band_px:
        raise ctx.err("[ptv].bin_px", f"must be under band_px ({cfg.ptv.band_px:g} px)")
    if cfg.ensemble.single_pixel and not cfg.ensemble.enabled:
        raise ctx.err(
            "[ensemble].single_pixel", "needs the ensemble band ([ensemble] enabled = true)"
        )
    if "dir" not in data.get("output", {}):
        cfg.output.dir = ctx.base / cfg.output.dir
    return cfg


def load_campaign_config(path: str | os.PathLike) -> CampaignConfig:
    """Read and validate a campaign file.

    Parameters
    ----------
    path : path-like
        The TOML file; relative paths inside it are taken from its folder.

    Raises
    ------
    InvalidInputError
        Missing or unreadable file, malformed TOML, unknown section or key, wrong type or
        value; the message names the file and the key.
    """
    path = pathlib.Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot read the campaign file ({exc.strerror})") from exc
    try:
        data = _toml.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InvalidInputError(f"{path.name}: not UTF-8 text ({exc.reason})") from exc
    except _toml.TOMLDecodeError as exc:
        where = locate_toml_error(raw.decode("utf-8", "replace"), str(exc))
        raise InvalidInputError(f"{path.name}: {where}malformed TOML: {exc}") from exc
    cfg = parse_campaign_config(data, fname=path.name, base=path.resolve().parent)
    cfg.source = path.resolve()
    return cfg


__all__ = [
    "CalibrationConfig",
    "CampaignConfig",
    "CorrectionConfig",
    "FlowConfig",
    "ImagesConfig",
    "OutputConfig",
    "PIVConfig",
    "PtvConfig",
    "StatisticsConfig",
    "WallConfig",
    "load_campaign_config",
    "parse_campaign_config",
]
