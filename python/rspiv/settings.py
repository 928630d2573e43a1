"""The one vocabulary of rspiv's PIV settings, correction methods and mapping models.

:class:`PivSettings` is the single settings object of a PIV job. The same keys, with the same
values, are used by the Python API (:func:`rspiv.piv` keywords are a thin shim over it), the
campaign file's ``[piv]`` section, the native binding and the Rust CLI (``rspiv-engine piv
--settings FILE.json`` reads the JSON of :meth:`PivSettings.to_dict`):

================  ==========================  ===============================================
key               type                        values / unit
================  ==========================  ===============================================
passes            list of (w, h)              window px, coarse to fine; w along x, h along y
overlap           float or one per pass       fraction in [0, 1)
iterations        int or one per pass         >= 1 correlation iterations per pass
deformation       str                         "symmetric" (image deformation) or "offset"
interpolation     str                         "bspline" (quintic), "bspline3", "keys"
subpixel          str                         "gauss3" or "gauss2d"
weighting         str                         "tophat", "gaussian" or "blackman" windows
validate          bool                        normalised median test + replacement
median_eps        float                       px, noise level of the median test
median_threshold  float                       threshold of the normalised median test
min_peak_ratio    float                       reject vectors below this peak ratio (0: off)
peak_candidates   int 1-3                     correlation peaks tried before interpolating
uncertainty       bool                        per-vector uncertainty (``PivField.sigma_u``)
roi               (x0, y0, x1, y1) or None    region of interest, px: ``x0 <= x < x1``, ...
================  ==========================  ===============================================

String values are case-insensitive on input and stored lowercase. The correction methods are
``"I"`` (dewarp the images, then PIV), ``"II"`` (PIV on the raw frames, vectors mapped back) and
``"none"``, accepted case-insensitively with the aliases ``"images"`` (I) and ``"vectors"`` (II)
(:func:`parse_method`). Method II's displacement mapping is ``"full"`` or ``"positions"``
(:func:`parse_mapping_mode`). Mapping model names are ``"r1"``, ``"r2"``, ``"p3"``, accepted in
any case (:func:`normalise_model`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "PivSettings",
    "OPTION_KEYS",
    "DEFORMATIONS",
    "INTERPOLATIONS",
    "SUBPIXELS",
    "WEIGHTINGS",
    "METHODS",
    "MAPPING_MODES",
    "MODELS",
    "parse_choice",
    "parse_method",
    "parse_mapping_mode",
    "parse_roi",
    "normalise_model",
]

DEFORMATIONS = ("symmetric", "offset")
INTERPOLATIONS = ("bspline", "bspline3", "keys")
SUBPIXELS = ("gauss3", "gauss2d")
WEIGHTINGS = ("tophat", "gaussian", "blackman")
METHODS = ("I", "II", "none")
MAPPING_MODES = ("full", "positions")
MODELS = ("r1", "r2", "p3")

#: The settings besides the per-pass ones (passes, overlap, iterations): what the keyword shims
#: (:func:`rspiv.piv`, :func:`rspiv.correction.piv_vectors`) pass through unchanged.
OPTION_KEYS = (
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
    "roi",
)

_METHOD_ALIASES = {"i": "I", "images": "I", "ii": "II", "vectors": "II", "none": "none"}


def from_keys(cls: Any, d: Mapping[str, Any], where: str, what: str) -> Any:
    """A frozen settings dataclass ``cls`` from a dictionary of its field names; unknown keys
    are an InvalidInputError naming ``where`` and listing the known ones ("``what``")."""
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InvalidInputError(
            f"{where}: unknown {what} {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
    return cls(**dict(d))


def parse_choice(value: Any, choices: Sequence[str], what: str) -> str:
    """``value`` lower-cased if it is one of ``choices`` (lowercase), else InvalidInputError
    naming ``what``, the value and the choices."""
    if isinstance(value, str) and value.lower() in choices:
        return value.lower()
    listed = ", ".join(repr(c) for c in choices)
    raise InvalidInputError(f"{what} must be one of {listed}, got {value!r}")


def parse_method(value: Any) -> str:
    """Canonical correction method: ``"I"``, ``"II"`` or ``"none"`` (``"images"`` and
    ``"vectors"`` are aliases of I and II; any case)."""
    if isinstance(value, str) and value.lower() in _METHOD_ALIASES:
        return _METHOD_ALIASES[value.lower()]
    raise InvalidInputError(
        f'method must be "I" (or "images"), "II" (or "vectors") or "none", got {value!r}'
    )


def parse_mapping_mode(value: Any) -> str:
    """Method II's displacement mapping: ``"full"`` or ``"positions"`` (any case)."""
    return parse_choice(value, MAPPING_MODES, "mapping")


def normalise_model(value: Any) -> str:
    """Mapping model name in its canonical lowercase form (``"R2"`` -> ``"r2"``)."""
    return parse_choice(value, MODELS, "model")


def _window(w: Any) -> tuple[int, int]:
    try:
        ww, hh = (int(v) for v in w)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"window {w!r} is not a (w, h) pair of integers") from exc
    return ww, hh


def per_pass(value: Any, n: int, name: str, cast: Any) -> list:
    """One value per pass: a scalar repeated ``n`` times, or a sequence of length ``n``."""
    if np.ndim(value) == 0:
        return [cast(value)] * n
    vals = [cast(v) for v in value]
    if len(vals) != n:
        raise InvalidInputError(f"{name} has {len(vals)} entries for {n} passes")
    return vals


def parse_roi(value: Any) -> tuple[int, int, int, int] | None:
    """A region of interest ``(x0, y0, x1, y1)`` of whole px with ``0 <= x0 < x1`` and
    ``0 <= y0 < y1``, or None (InvalidInputError naming what was given)."""
    if value is None:
        return None
    vals = list(value) if isinstance(value, (list, tuple, np.ndarray)) else []
    ok = len(vals) == 4 and all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0 for v in vals
    )
    if not ok:
        raise InvalidInputError(f"roi must be (x0, y0, x1, y1): four whole px >= 0, got {value!r}")
    x0, y0, x1, y1 = (int(v) for v in vals)
    if x0 >= x1 or y0 >= y1:
        raise InvalidInputError(
            f"roi [{x0}, {y0}, {x1}, {y1}] is empty: give x0 < x1 and y0 < y1 (px)"
        )
    return x0, y0, x1, y1


def _scalar_or_tuple(value: Any, cast: Any) -> Any:
    if np.ndim(value) == 0:
        return cast(value)
    return tuple(cast(v) for v in value)


@dataclasses.dataclass(frozen=True)
class PivSettings:
    """How a PIV job runs (frozen; the one vocabulary of the module docstring).

    Attributes
    ----------
    passes : tuple of (w, h)
        Window sizes in px from coarse to fine; ``w`` along x, ``h`` along y. The grid of the
        last pass is the output grid.
    overlap : float or tuple of float
        Fractional window overlap in [0, 1), one value or one per pass.
    iterations : int or tuple of int
        Correlation iterations per pass (each re-deforms with the latest field).
    deformation : {"symmetric", "offset"}
        How later passes follow the previous field: symmetric image deformation (interpolated
        with ``interpolation``) or a symmetric sub-pixel window offset.
    interpolation : {"bspline", "bspline3", "keys"}
        Interpolation of the frames at fractional positions: quintic B-spline, cubic B-spline
        or Keys bicubic (a = -0.5).
    subpixel : {"gauss3", "gauss2d"}
        3-point Gaussian per axis, or a 9-point 2D Gaussian least-squares fit.
    weighting : {"tophat", "gaussian", "blackman"}
        Weighting window of the interrogation windows (``piv_core::weighting``): every pixel
        alike (the most accurate on smooth flows; response ``sinc(h / L)`` to a sine of
        wavelength ``L``, sign-reversed between ``L = h / 2`` and ``h``), or tapered towards
        the edges, which returns every wavelength down to ``h / 2`` with a positive, higher
        amplitude (Gaussian 0.964, Blackman 0.983 at ``L = 4 h``; 0.55 and 0.75 at ``L = h``)
        from fewer particle images (more random error).
    validate : bool
        Normalised median test with replacement after every iteration.
    median_eps : float
        Noise level of the median test, px.
    median_threshold : float
        Threshold of the normalised median test.
    min_peak_ratio : float
        Reject vectors whose peak ratio is below this (0 disables).
    peak_candidates : int
        Correlation peaks tried per vector, 1 to 3 (3): a vector that fails the median test
        takes its second, then third correlation peak if that passes the test against the same
        neighbours, before it is interpolated (``PivField.peak_choice`` says which; 1 turns
        this off).
    uncertainty : bool
        Estimate every valid vector's standard uncertainty from its correlation statistics on
        the last iteration of the last pass (``PivField.sigma_u``, ``sigma_v``; Wieneke 2015),
        True. Off, they are NaN (saves 5-15 % of the last pass's correlation time).
    roi : (x0, y0, x1, y1) or None
        Region of interest in px of the frame the field lies in (the frames' own; object px
        with a correction): the pixels ``x0 <= x < x1``, ``y0 <= y < y1``. Every pass runs on
        the whole frame's grid cut to the points whose windows lie in it (and two rings of
        points beyond it, cut off at the end), and only it and a margin around it (the largest
        window, at least 64 px: what the search, the deformation and the interpolation read)
        are read, so the time scales with its area; ``x``, ``y`` stay in the frame's px, and
        its vectors are the whole frame's (bit for bit with window offset on synthetic pairs;
        where vectors are replaced in clusters next to its edge they can differ). None: the
        whole frame.

    Values are checked and normalised on construction (InvalidInputError naming the key).
    """

    passes: tuple[tuple[int, int], ...] = ((64, 64), (32, 32), (32, 8))
    overlap: float | tuple[float, ...] = 0.5
    iterations: int | tuple[int, ...] = 1
    deformation: str = "symmetric"
    interpolation: str = "bspline"
    subpixel: str = "gauss3"
    weighting: str = "tophat"
    validate: bool = True
    median_eps: float = 0.1
    median_threshold: float = 2.0
    min_peak_ratio: float = 0.0
    peak_candidates: int = 3
    uncertainty: bool = True
    roi: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        passes = tuple(_window(p) for p in self.passes)
        if not passes:
            raise InvalidInputError("passes is empty")
        s = object.__setattr__
        s(self, "passes", passes)
        s(self, "overlap", _scalar_or_tuple(self.overlap, float))
        s(self, "iterations", _scalar_or_tuple(self.iterations, int))
        for v in self.overlaps:
            if not (0.0 <= v < 1.0):
                raise InvalidInputError(f"overlap {v} is outside [0, 1)")
        for v in self.iteration_counts:
            if v < 1:
                raise InvalidInputError(f"iterations must be >= 1, got {v}")
        s(self, "deformation", parse_choice(self.deformation, DEFORMATIONS, "deformation"))
        s(self, "interpolation", parse_choice(self.interpolation, INTERPOLATIONS, "interpolation"))
        s(self, "subpixel", parse_choice(self.subpixel, SUBPIXELS, "subpixel"))
        s(self, "weighting", parse_choice(self.weighting, WEIGHTINGS, "weighting"))
        s(self, "validate", bool(self.validate))
        s(self, "uncertainty", bool(self.uncertainty))
        for key in ("median_eps", "median_threshold", "min_peak_ratio"):
            v = float(getattr(self, key))
            if not np.isfinite(v) or v < 0:
                raise InvalidInputError(f"{key} must be a finite number >= 0, got {v}")
            s(self, key, v)
        n = self.peak_candidates
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 3:
            raise InvalidInputError(f"peak_candidates must be 1, 2 or 3, got {n!r}")
        s(self, "peak_candidates", int(n))
        s(self, "roi", parse_roi(self.roi))

    # -- per-pass views ------------------------------------------------------------------------
    @property
    def overlaps(self) -> list[float]:
        """The overlap of every pass."""
        return per_pass(self.overlap, len(self.passes), "overlap", float)

    @property
    def iteration_counts(self) -> list[int]:
        """The iterations of every pass."""
        return per_pass(self.iterations, len(self.passes), "iterations", int)

    @property
    def final_window(self) -> tuple[int, int]:
        """The last pass's window ``(w, h)`` px."""
        return self.passes[-1]

    def replace(self, **changes: Any) -> PivSettings:
        """A copy with ``changes`` applied (checked like the constructor)."""
        return dataclasses.replace(self, **changes)

    # -- the one vocabulary's dictionary form --------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dictionary with the vocabulary's keys (lists for tuples)."""
        d = dataclasses.asdict(self)
        d["passes"] = [list(p) for p in self.passes]
        for key in ("overlap", "iterations", "roi"):
            if isinstance(d[key], tuple):
                d[key] = list(d[key])
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "settings") -> PivSettings:
        """Settings from a dictionary of vocabulary keys (unknown keys are an error naming
        ``where``); missing keys take the defaults."""
        return from_keys(cls, d, where, "PIV setting(s)")

    @classmethod
    def load(cls, path: str | os.PathLike) -> PivSettings:
        """Settings from a JSON file of vocabulary keys (what :meth:`to_dict` writes, and what
        ``rspiv-engine piv --settings`` reads). InvalidInputError naming the file for a
        missing or malformed file or an unknown key."""
        p = pathlib.Path(path)
        try:
            d = json.loads(p.read_text())
        except OSError as exc:
            raise InvalidInputError(f"{p}: cannot read the PIV settings: {exc}") from exc
        except ValueError as exc:
            raise InvalidInputError(f"{p}: not valid JSON: {exc}") from exc
        if not isinstance(d, dict):
            raise InvalidInputError(f"{p}: PIV settings must be a JSON object of keys")
        return cls.from_dict(d, where=str(p))

    def to_json(self) -> str:
        """The settings as JSON text (:meth:`to_dict`): what the native functions read
        (``piv_core::PivSettings::from_json``, the same vocabulary and checks)."""
        return json.dumps(self.to_dict(), indent=2)
