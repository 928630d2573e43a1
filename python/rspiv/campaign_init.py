"""``rspiv init``: a campaign file written from a recording, every value the recording decides
written with what decided it, and what it cannot decide said.

A lab's first campaign on its own recording starts from a folder of frames and a target image.
:func:`init_campaign` looks at them as a user would before writing the campaign file by hand:

- **the source** (:func:`images_source`): a folder (its most common image type), a glob, a
  DaVis ``Run.set``, a multi-frame TIFF or a camera recording (Photron ``.cihx``/``.cih``,
  Phantom ``.cine``). Files of two images each (DaVis double-frame buffers, two-page TIFFs)
  give ``[images] double_frame``, files of one image ``glob``, one file of more
  ``multiframe``. A single frame, a folder without images and files of more than two images
  each are refused in one line.
- **the pairing** of single frames (:func:`choose_pairing`): frames 1-2 and 2-3 through one
  coarse pass each (:func:`rspiv.recording.coarse_pass`). Both correlating and moving alike
  (:func:`rspiv.recording.unlike_pairs` false) is a time-resolved recording (``pairing =
  "sequential"``); one correlating and not the other, or moving several times as far, is a
  double-frame camera's A, B, A, B (``"pairs"``). Neither correlating cannot be told apart and
  is said (``"pairs"`` written). Two frames are one pair either way.
- **the orientation** (:func:`quarter_turn`): ``[images] rotate`` turns the first pair's median
  displacement to +x, as a campaign expects. A flow more than :data:`MAX_OBLIQUE_DEG` from the
  nearest axis, or a median under :data:`MIN_ORIENT_PX`, is said (rspiv turns frames by quarter
  turns; the wall alignment removes a small rotation only).
- **the passes** and the deformation from :func:`rspiv.check_recording` on the first pair:
  its first window (the one-quarter rule) halving down to a last pass four times finer across
  the wall than along it, the paper's 32 x 32 -> 32 x 8, that holds ten particle images
  (:func:`wall_passes`). The check's own square windows resolve the wall-normal direction
  four times more coarsely: on a synthetic layer cut 49 px below its wall, its 24 x 24 px last
  pass left the campaign no complete profile about the wall. Its warnings are said. Particle
  images under 2 px (peak locking) get ``[preprocess] smooth = 0.7`` (README: about half the
  locking at the same random error).
- **frames that hardly move** between successive frames of a time-resolved recording: a
  ``frame_gap`` that moves them :data:`GAP_TARGET_PX` is said, not written.
- **the statistics' minimum count**: a recording of fewer than 20 pairs gets ``min_count`` of
  half its pairs (at least 2), so that its profile is not left empty.
- **the pulse separation** of a camera recording paired sequentially: ``frame_gap`` frames at
  the rate of its frames (:func:`rspiv.io.camera_recording`); of DaVis double-frame files:
  their frames' acquisition times (:func:`rspiv.io.davis_frame_dt`). Otherwise ``dt`` is taken
  as given (``dt=``) or said: 0 leaves the outputs in px per pair.
- **the calibration** with a target: :func:`rspiv.calibrate` with ``model="auto"`` on the target
  turned as the frames are, refused as it refuses; the model it picks and its lattice are
  written. Without a target no correction is run (``[correction] method = "none"``).

Also said, never guessed: the kinematic viscosity when not given (1.5e-5 m^2/s, air near 20 C,
is written; water is about 1.0e-6), a frame size other than the target's, an odd number of
single frames paired 1-2, 3-4. The file is parsed back before it is written (atomically, never
over an existing one unless ``force``), and its paths are relative to its folder.

Lengths in px, times in s, the viscosity in m^2/s.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import pathlib

try:  # Python >= 3.11
    import tomllib as _toml
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as _toml  # type: ignore[no-redef]

import numpy as np

from rspiv.campaign_config import (
    CalibrationConfig,
    CampaignConfig,
    ImagesConfig,
    parse_campaign_config,
)
from rspiv.campaign_schema import dump_toml
from rspiv.errors import InvalidInputError
from rspiv.io import (
    DAVIS_SUFFIXES,
    camera_recording,
    davis_frame_dt,
    frame_count,
    read_image,
    recording_rate,
    turn_frame,
)
from rspiv.outputs import atomic_write_text
from rspiv.recording import (
    MIN_PARTICLES_PER_WINDOW,
    SIZES,
    _correlation_state,
    check_recording,
    coarse_pass,
    unlike_pairs,
)
from rspiv.settings import parse_method

__all__ = [
    "IMAGE_SUFFIXES",
    "MAX_OBLIQUE_DEG",
    "MIN_ORIENT_PX",
    "CampaignInit",
    "choose_pairing",
    "frame_marks",
    "images_source",
    "init_campaign",
    "quarter_turn",
    "wall_passes",
]

#: The files a folder is searched for (any case): images, DaVis buffers, camera recordings.
IMAGE_SUFFIXES = (
    ".tif", ".tiff", ".png", ".bmp", ".jpg", ".jpeg", ".im7", ".imx", ".ims", ".cine", ".cihx",
    ".cih",
)  # fmt: skip
#: A flow farther than this from the nearest image axis (degrees) is said: frames turn by
#: quarter turns only.
MAX_OBLIQUE_DEG = 10.0
#: A median displacement under this (px) does not orient the frames.
MIN_ORIENT_PX = 0.5
#: The smoothing written for particle images under 2 px (``[preprocess] smooth``, px).
SMOOTH_SMALL_PARTICLES = 0.7
#: A time-resolved recording moving less gets a ``frame_gap`` said that moves it this far
#: (px, the 99th percentile), at most a quarter of the first window.
GAP_TARGET_PX = 8.0
#: The viscosity written when none is given (m^2/s: air near 20 C).
DEFAULT_NU = 1.5e-5


@dataclasses.dataclass
class CampaignInit:
    """What :func:`init_campaign` found.

    ``config`` holds absolute paths; ``notes`` maps ``(section, key)`` to what decided the
    value (a comment beside it in the file); ``said`` lists what the user must check or
    decide (the file's first lines, and the command's output)."""

    config: CampaignConfig
    notes: dict[tuple[str, str], str]
    said: list[str]

    def text(self, folder: str | os.PathLike) -> str:
        """The campaign file's text, paths relative to ``folder`` (the file's own)."""
        cfg = self.config
        if not pathlib.Path(cfg.output.dir).is_absolute():  # relative to the file's folder
            out = dataclasses.replace(cfg.output, dir=pathlib.Path(folder) / cfg.output.dir)
            cfg = dataclasses.replace(cfg, output=out)
        data = cfg.to_dict(relative_to=folder)
        lines = ["# written by rspiv init: every value with a comment was decided by the recording"]
        lines += [f"# CHECK: {s}" for s in self.said]
        lines.append("")
        section = ""
        for line in dump_toml(data).splitlines():
            if line.startswith("["):
                section = line.strip("[]")
            key = line.split(" = ", 1)[0]
            note = self.notes.get((section, key))
            lines.append(f"{line}  # {note}" if note and " = " in line else line)
        return "\n".join(lines) + "\n"

    def write(self, path: str | os.PathLike, *, force: bool = False) -> pathlib.Path:
        """Write the campaign file atomically (parsed back first). InvalidInputError when the
        file exists and ``force`` is false."""
        path = pathlib.Path(path)
        if path.exists() and not force:
            raise InvalidInputError(f"{path}: exists; give another name or --force")
        text = self.text(path.parent.resolve())
        parse_campaign_config(_toml.loads(text), fname=str(path), base=path.parent)
        return atomic_write_text(path, text)


def _has_glob(text: str) -> bool:
    return any(ch in text for ch in "*?[")


def images_source(spec: str | os.PathLike) -> ImagesConfig:
    """The ``[images]`` source of a folder, glob or file (module docstring), absolute paths,
    ``pairing`` still the default. InvalidInputError in one line for what holds no pairs."""
    text = str(spec)
    p = pathlib.Path(text).expanduser()
    if not _has_glob(text) and p.is_dir():
        found = [
            f.suffix for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES
        ]
        if not found:
            raise InvalidInputError(
                f"{p}: no image file ({', '.join(IMAGE_SUFFIXES)}) in the folder"
            )
        suffix, _ = collections.Counter(found).most_common(1)[0]
        if suffix.lower() in (".cine", ".cihx", ".cih"):
            raise InvalidInputError(f"{p}: holds camera recordings: give the one to process")
        p, text = p / f"*{suffix}", str(p / f"*{suffix}")
    if _has_glob(text):
        p = p.parent.resolve() / p.name
        files = sorted(p.parent.glob(p.name))
        if not files:
            raise InvalidInputError(f"{text}: no file matches")
        n = frame_count(files[0])
        if n == 2:
            return ImagesConfig(double_frame=str(p))
        if n == 1:
            return ImagesConfig(glob=str(p))
        if len(files) == 1:
            return ImagesConfig(multiframe=files[0])
        raise InvalidInputError(
            f"{files[0]}: holds {n} frames and {len(files) - 1} more files match {text!r}: "
            "give one multi-frame file at a time"
        )
    if not p.exists():
        raise InvalidInputError(f"{p}: no such file or folder")
    p = p.resolve()
    if p.suffix.lower() == ".set":
        cfg = ImagesConfig(double_frame=str(p))
        cfg.double_frame_files()  # its folder's .im7 files, or refused
        return cfg
    n = frame_count(p)
    if camera_recording(p) is not None or n > 2:
        return ImagesConfig(multiframe=p)
    if n == 2:
        return ImagesConfig(double_frame=str(p))
    raise InvalidInputError(
        f"{p}: one frame; give the recording's folder, a glob of its files or a multi-frame file"
    )


def _frames(images: ImagesConfig, count: int) -> list[tuple[str, int]]:
    """The first ``count`` frames in recording order as ``(file, index)``: the glob's files, the
    multi-frame file's pages or frames, or the double-frame files' images 0 and 1."""
    if images.multiframe is not None:
        n = frame_count(images.multiframe)
        return [(str(images.multiframe), k) for k in range(min(n, count))]
    if images.double_frame is not None:
        files = images.double_frame_files()[: (count + 1) // 2]
        return [(str(f), k) for f in files for k in (0, 1)][:count]
    assert images.glob is not None
    pattern = pathlib.Path(images.glob)
    return [(str(f), 0) for f in sorted(pattern.parent.glob(pattern.name))[:count]]


def _pair_count(images: ImagesConfig) -> int:
    """The pairs ``images`` forms with its pairing."""
    if images.multiframe is not None:
        n = frame_count(images.multiframe)
        return len(images.frame_pairs(n, str(images.multiframe), odd_ok=True))
    if images.double_frame is not None:
        return len(images.double_frame_files())
    return len(images.pair_files())


def _read(frame: tuple[str, int], shape: tuple[int, int] | None) -> np.ndarray:
    a = read_image(frame[0], frame[1])
    if shape is not None and a.shape != shape:
        raise InvalidInputError(
            f"{frame[0]}: frame {frame[1]} is {a.shape[1]} x {a.shape[0]} px, the first "
            f"{shape[1]} x {shape[0]}"
        )
    return a


def _motion(a: np.ndarray, b: np.ndarray) -> tuple[bool, float]:
    """``(correlates, median |displacement| px)`` of one coarse pass."""
    field, _ = coarse_pass(a, b, None, a.shape)
    good, _, correlates = _correlation_state(field)
    if not correlates:
        return False, math.nan
    return True, float(np.median(np.hypot(field.u[good], field.v[good])))


def frame_marks(names: list[str]) -> str | None:
    """How the files' names mark frames A and B: "alternate" when every stem ends in A or B
    (any case, after separators) and, sorted, they run A, B, A, B ...; "out of order" when they
    all carry a mark but do not alternate so (a glob would pair A with A: OpenPIV's
    ``Pattern_0001_A`` ... ``Pattern_0005_A``, ``Pattern_1001_B`` ...); None without marks."""
    marks = [pathlib.Path(n).stem.rstrip("_-. ")[-1:].upper() for n in names]
    if len(names) < 2 or any(m not in ("A", "B") for m in marks):
        return None
    alternate = len(marks) % 2 == 0 and all(
        m == ("A" if k % 2 == 0 else "B") for k, m in enumerate(marks)
    )
    return "alternate" if alternate else "out of order"


def choose_pairing(
    frames: list[np.ndarray], *, camera: bool = False
) -> tuple[str, str | None, str]:
    """The pairing of a run of single frames (module docstring): ``(pairing, said, note)``:
    "sequential" or "pairs", one line to say when the frames cannot tell (else None), and
    what decided it. ``camera``: a high-speed camera's recording, whose two frames are taken
    as one sequential pair."""
    if len(frames) < 3:
        if camera:
            return "sequential", None, f"a camera recording of {len(frames)} frames: one pair"
        return "pairs", None, f"{len(frames)} frames: one pair either way"
    ok0, m0 = _motion(frames[0], frames[1])
    ok1, m1 = _motion(frames[1], frames[2])

    def moved(ok: bool, m: float) -> str:
        return f"{m:.2f} px" if ok else "do not correlate"

    seen = f"frames 1-2 {moved(ok0, m0)}, 2-3 {moved(ok1, m1)}"
    if unlike_pairs(ok0, m0, ok1, m1):
        return "pairs", None, f"{seen}: a double-frame camera's A, B, A, B"
    if ok0 and ok1 and max(m0, m1) > 1.0:
        return "sequential", None, f"{seen}: a time-resolved recording"
    why = "neither correlates" if not ok0 else "they hardly move"
    return (
        "pairs",
        f"[images] pairing: {seen}: {why}, so a time-resolved recording cannot be told from "
        "a double-frame camera; 'pairs' (1-2, 3-4, ...) written",
        seen,
    )


def quarter_turn(u: float, v: float) -> int:
    """The quarter turns counter-clockwise (0-3, :func:`rspiv.io.turn_frame`) that bring the
    displacement ``(u, v)`` (px, y down) nearest to +x: one turn takes ``(u, v)`` to ``(v,
    -u)``."""
    best, turns = -math.inf, 0
    for k in range(4):
        if u > best:
            best, turns = u, k
        u, v = v, -u
    return turns


def wall_passes(first: int, density: float) -> list[tuple[int, int]]:
    """The passes of a wall-bounded campaign: square windows from ``first`` px (the
    one-quarter rule's) halving down to ``W``, then ``W x W/4`` px, the paper's shape (32 x 32
    -> 32 x 8) that resolves the wall-normal direction four times finer. ``W`` is the
    smallest of :data:`rspiv.recording.SIZES` (16 px or more) whose ``W x W/4`` window holds
    :data:`rspiv.recording.MIN_PARTICLES_PER_WINDOW` particle images at ``density`` (per px),
    and at most ``first``."""
    need = [s for s in SIZES if s >= 16 and s * s / 4 * density >= MIN_PARTICLES_PER_WINDOW]
    last = min(need[0] if need else first, first)
    passes = [(first, first)]
    while passes[-1][0] // 2 >= last:
        half = passes[-1][0] // 2
        passes.append((half, half))
    return passes + [(passes[-1][0], passes[-1][0] // 4)]


def _oblique_deg(u: float, v: float) -> float:
    """Degrees between ``(u, v)`` and the nearest image axis (0-45)."""
    ang = math.degrees(math.atan2(abs(v), abs(u)))
    return min(ang, 90.0 - ang)


def init_campaign(
    images: str | os.PathLike,
    *,
    target: str | os.PathLike | None = None,
    pitch_mm: float | None = None,
    pitch_sigma_mm: float | None = None,
    marker: str = "dot",
    level: int | None = None,
    dt: float | None = None,
    nu: float | None = None,
    method: str | None = None,
    output_dir: str | os.PathLike = "rspiv-out",
    name: str | None = None,
) -> CampaignInit:
    """A campaign for the recording ``images``, decided from the recording (module docstring).

    Parameters
    ----------
    images : str or path
        A folder, a glob (wildcards in the file name only), a DaVis ``.set``, a multi-frame
        TIFF or a camera recording.
    target, pitch_mm, pitch_sigma_mm, marker : optional
        The calibration target's image (turned as the frames are), its marker pitch (mm,
        required with a target), the pitch's one-sigma uncertainty (mm; default 0: estimated
        from the fit's residuals beyond the image noise, as :func:`rspiv.calibrate` does) and
        the marker shape ("dot" | "cross").
    level : {None, 1, 2}, optional
        The level of a two-level plate to calibrate on (1 = the nearer); default the level
        holding the fiducial, else 1, written and said: it must be the light sheet's plane.
    dt : float, optional
        The pulse separation (s); a camera recording paired sequentially gives its own.
    nu : float, optional
        The kinematic viscosity (m^2/s); :data:`DEFAULT_NU` written and said otherwise.
    method : {"II", "I", "none"}, optional
        The correction; default "II" with a target, "none" without.
    output_dir : str or path
        The campaign's output folder (relative to the campaign file's folder when relative).
    name : str, optional
        The campaign's name; default the recording's folder name.

    Returns
    -------
    CampaignInit
        The configuration, the notes behind its values and what must be checked.

    Raises
    ------
    InvalidInputError
        One line: no frames, frames of different sizes, a target without a pitch or that does
        not calibrate, a target of another size than the frames, pairs of an odd number of
        frames.
    """
    if target is not None and (pitch_mm is None or not pitch_mm > 0):
        raise InvalidInputError(f"{target}: a target needs its marker pitch (--pitch-mm)")
    if pitch_sigma_mm is not None and not pitch_sigma_mm >= 0:
        raise InvalidInputError(f"pitch_sigma_mm must be >= 0 mm, got {pitch_sigma_mm}")
    if dt is not None and not dt > 0:
        raise InvalidInputError(f"dt must be > 0 s, got {dt}")
    if nu is not None and not nu > 0:
        raise InvalidInputError(f"nu must be > 0 m^2/s, got {nu}")
    method = parse_method(method or ("II" if target is not None else "none"))
    if method != "none" and target is None:
        raise InvalidInputError(f"method {method} needs a calibration target (--target)")
    src = images_source(images)
    notes: dict[tuple[str, str], str] = {}
    said: list[str] = []
    cfg = CampaignConfig(images=src)
    where = src.multiframe or src.double_frame or src.glob
    cfg.name = name or pathlib.Path(str(where)).parent.name or "campaign"
    cfg.description = f"written by rspiv init from {where}"

    # the pairing: single frames only; a double-frame file is one pair
    frames_at = _frames(src, 2 if src.double_frame is not None else 3)
    if len(frames_at) < 2:
        raise InvalidInputError(f"{where}: {len(frames_at)} frame(s); a pair needs two")
    first = _read(frames_at[0], None)
    frames = [first] + [_read(f, first.shape) for f in frames_at[1:]]
    if src.double_frame is None:
        marks = None
        if src.glob is not None:
            pattern = pathlib.Path(src.glob)
            marks = frame_marks([f.name for f in sorted(pattern.parent.glob(pattern.name))])
        if marks == "out of order":
            raise InvalidInputError(
                f"{src.glob}: the files' names mark frames A and B, but in sorted order they do "
                "not run A, B, A, B: a glob would pair them wrongly; list the pairs in "
                "[images] pairs, or give a glob that sorts them in pairs"
            )
        camera = src.multiframe is not None and camera_recording(src.multiframe) is not None
        src.pairing, unclear, why = choose_pairing(frames, camera=camera)
        if marks == "alternate":
            if src.pairing == "sequential":
                why += " (as paired 1-2, 3-4 too)"
            src.pairing, unclear, why = "pairs", None, f"file names alternate A, B; {why}"
        notes[("images", "pairing")] = why
        if unclear:
            said.append(unclear)
    else:
        notes[("images", "double_frame")] = "two images per file: frames A and B"
    a, b = frames[0], frames[1]
    del frames
    n_pairs = _pair_count(src)
    if n_pairs < 2 * cfg.statistics.min_count:
        cfg.statistics.min_count = max(2, min(cfg.statistics.min_count, n_pairs // 2))
        notes[("statistics", "min_count")] = (
            f"{n_pairs} pair(s): a profile point needs this many valid samples"
        )

    # the first pair as recorded: passes, deformation, particle size, orientation
    check = check_recording(a, b)
    said += [f"recording: {w}" for w in check.warnings.values()]
    u, v = check.median_displacement
    turn = 0
    if check.correlates and math.hypot(u, v) >= MIN_ORIENT_PX:
        turn = quarter_turn(u, v)
        src.rotate = 90 * turn
        notes[("images", "rotate")] = (
            f"the first pair's median displacement ({u:.2f}, {v:.2f}) px turned to +x"
        )
        oblique = _oblique_deg(u, v)
        if oblique > MAX_OBLIQUE_DEG:
            said.append(
                f"[images] rotate: the flow runs {oblique:.0f} degrees from the nearest image "
                "axis; frames turn by quarter turns only and the wall alignment removes a small "
                "rotation: align the camera with the flow"
            )
    else:
        said.append(
            "[images] rotate: the first pair's displacement does not orient the frames "
            f"(median ({u:.2f}, {v:.2f}) px); 0 written: the flow must run along +x"
        )
    if check.passes:
        cfg.piv.passes = wall_passes(check.passes[0][0], check.density)
        cfg.piv.deformation = str(check.deformation)
        w, h = cfg.piv.passes[-1]
        held = check.density * w * h
        notes[("piv", "passes")] = (
            f"rspiv check on the first pair: 99th percentile |u| {check.p99_displacement[0]:.1f}"
            f", |v| {check.p99_displacement[1]:.1f} px, {check.density:.4f} particle images per "
            f"px; the last pass 4:1 along the wall, {held:.1f} particle images per window"
        )
        if held < MIN_PARTICLES_PER_WINDOW:
            said.append(
                f"[piv] passes: the last window ({w} x {h} px) holds {held:.1f} particle images, "
                f"under {MIN_PARTICLES_PER_WINDOW:g}: more seeding, or larger windows"
            )
        notes[("piv", "deformation")] = (
            f"displacement difference across a window {100 * check.gradient:.1f} % of it"
        )
    else:
        said.append(
            "[piv] passes: the first pair does not correlate, so no passes could be "
            "recommended; the campaign defaults are written"
        )
    d = float(np.nanmean(check.diameter))
    if d < 2.0:
        cfg.preprocess.smooth = SMOOTH_SMALL_PARTICLES
        notes[("preprocess", "smooth")] = (
            f"particle images {d:.1f} px: smoothing about halves the peak locking"
        )

    # the pulse separation and the viscosity
    rec = camera_recording(src.multiframe) if src.multiframe is not None else None
    first_file = pathlib.Path(frames_at[0][0])
    davis_dt = (
        davis_frame_dt(first_file)
        if src.double_frame is not None and first_file.suffix.lower() in DAVIS_SUFFIXES
        else None
    )
    if dt is not None:
        cfg.flow.dt = float(dt)
        notes[("flow", "dt")] = "given"
    elif rec is not None and rec.fps > 0 and src.pairing == "sequential":
        cfg.flow.dt = src.frame_gap / rec.fps
        notes[("flow", "dt")] = f"frame_gap {src.frame_gap} at {recording_rate(rec)}"
    elif davis_dt is not None:
        cfg.flow.dt = davis_dt
        notes[("flow", "dt")] = f"{first_file.name}: its frames' acquisition times (AcqTimeSeries)"
    else:
        said.append(
            "[flow] dt: the pulse separation is not in the files; 0 leaves every output in px "
            "per pair"
        )
    if nu is not None:
        cfg.flow.nu = float(nu)
        notes[("flow", "nu")] = "given"
    else:
        cfg.flow.nu = DEFAULT_NU
        said.append(
            f"[flow] nu: not given; {DEFAULT_NU:g} m^2/s (air near 20 C) written, water near "
            "20 C is 1.0e-6: wall units scale with it"
        )

    # the calibration, on the target turned as the frames are
    cfg.correction.method = method
    if target is not None:
        cfg.calibration = _calibration(
            target, float(pitch_mm), marker, level, turn, a.shape, notes, said
        )
        cfg.calibration.pitch_sigma_mm = float(pitch_sigma_mm or 0.0)
        notes[("calibration", "pitch_sigma_mm")] = (
            "given" if pitch_sigma_mm else "0: estimated from the fit's residuals beyond the "
            "image noise"
        )
    else:
        cfg.correction.compare_uncorrected = False
        said.append(
            "[calibration]: no target given: the frames are not corrected for the lens, and "
            "the outputs stay in px (rspiv init --target TARGET --pitch-mm P)"
        )
    if src.pairing == "sequential" and check.passes:
        p99 = max(check.p99_displacement)
        gap = _frame_gap(p99, cfg.piv.passes[0][0])
        if gap > 1:
            said.append(
                f"[images] frame_gap: successive frames move {p99:.2f} px at most (99th "
                f"percentile), where the random error is 0.05-0.1 px; frame_gap = {gap} moves "
                f"them {gap * p99:.1f} px (the flow changes more between a pair's frames)"
            )
    cfg.output.dir = pathlib.Path(output_dir)
    return CampaignInit(cfg, notes, said)


def _frame_gap(p99: float, first: int) -> int:
    """The frames between a pair's frames that bring the 99th percentile displacement ``p99``
    (px per frame) to :data:`GAP_TARGET_PX`, or a quarter of the first window if smaller."""
    if not p99 > 0:
        return 1
    return max(1, int(min(GAP_TARGET_PX, 0.25 * first) / p99))


def _calibration(
    target: str | os.PathLike,
    pitch_mm: float,
    marker: str,
    level: int | None,
    turn: int,
    shape: tuple[int, int],
    notes: dict[tuple[str, str], str],
    said: list[str],
) -> CalibrationConfig:
    """The ``[calibration]`` section: the target calibrated as the campaign will (turned), the
    model held-out error picks, and a two-level plate's level (written, and said unless
    given)."""
    from rspiv.calibration import calibrate  # deferred: the calibration stack only with a target

    path = pathlib.Path(target).expanduser().resolve()
    image = turn_frame(read_image(path), turn)
    want = turn_frame(np.empty(shape, dtype=np.uint8), turn).shape
    if image.shape != want:
        raise InvalidInputError(
            f"{path}: the target is {image.shape[1]} x {image.shape[0]} px as turned, the "
            f"frames {want[1]} x {want[0]}"
        )
    try:
        cal = calibrate(image, pitch_mm, model="auto", marker=marker, level=level)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{path}: {exc}") from None
    notes[("calibration", "model")] = f"{cal.model_reason}; {cal.lattice_summary().split(';')[0]}"
    notes[("calibration", "pitch_mm")] = "given"
    out = CalibrationConfig(target=path, pitch_mm=pitch_mm, model=cal.model.upper(), marker=marker)
    la = cal.lattice or {}
    if la.get("levels") == 2:
        out.level = int(la["level"])
        notes[("calibration", "level")] = "given" if level else "a two-level plate"
        if not level:
            said.append(
                f"[calibration] level: a two-level plate; level {out.level} (1 = the nearer) "
                "written, the one holding the fiducial or else the nearer: it must be the "
                "light sheet's plane (rspiv init --level 1|2)"
            )
    return out

