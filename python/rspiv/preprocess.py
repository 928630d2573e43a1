"""Image conditioning of real recordings before PIV: background removal, hot pixels, high-pass,
smoothing, intensity capping and min-max normalisation.

:class:`Preprocess` is the settings object (one vocabulary, as :class:`rspiv.PivSettings`);
:class:`Background` estimates the background of a run streaming over its frames (one frame in
memory at a time for ``"min"``/``"mean"`` over the run; ``window`` frames for a sliding window);
:func:`condition` and :func:`condition_pair` apply the steps in Rust (``piv_core::condition``,
whose docs give the exact definitions) to a float32 copy of each frame, with the GIL released.
Frame A and frame B keep separate backgrounds: their lighting differs (two laser cavities).

Order of the steps: hot pixels, background subtraction (clipped at 0), high-pass (subtract a
Gaussian of ``high_pass`` px sigma; signed, not clipped, see ``piv_core::condition``), smoothing
(a Gaussian of ``smooth`` px sigma, at most 2), intensity cap at ``mean + cap * std``, min-max
normalisation over ``min_max`` px windows (output in [0, 1]). Intensities are in the frame's
counts until the normalisation, dimensionless after it; lengths in px.

=================  ==============  =====================================================
key                value           meaning (0 or "none": off)
=================  ==============  =====================================================
background         str             "none", "min", "mean" or "percentile"
background_window  int             frames of the sliding window (0: the whole run)
percentile         float           the percentile for ``background="percentile"``
hot_pixels         float           factor over the brightest neighbour (e.g. 3)
high_pass          float           Gaussian sigma, px (e.g. 4)
smooth             float           Gaussian sigma, px, at most 2 (e.g. 0.5)
cap                float           cap at mean + cap * std (e.g. 2)
min_max            int             min-max normalisation window, px (e.g. 15)
=================  ==============  =====================================================

:data:`NEAR_WALL` holds what an experienced user switches on for near-wall data: the minimum
background over the run (per frame A and B), hot pixels (factor 3) and a high-pass of 2 px sigma
(glare lines and light gradients are far wider than 2-3 px particle images). Measured on a pair
with a static glare line (6 px sigma), light gradients that differ between the frames, hot pixels
and particles of 10x different brightness (tests/test_preprocess.py): RMS error of the valid
vectors 0.44 px raw (the glare line locks its vectors near zero; 0.93 px without the second
correlation peak, ``PivSettings.peak_candidates``), 0.027 px with a 2 px high-pass,
0.031 px with 3 px, 0.049 px with 4 px; capping at 2 standard deviations on top raises it to
0.12 px (it flattens the particle images of a sparse, high-passed frame), so it is not a default.

``smooth`` eases the peak locking of particle images too small for a sub-pixel fit (under 2 px,
:meth:`rspiv.PivField.peak_locking`): their squared e^-2 diameter grows by about ``16
smooth^2``, but what the sensor did not sample is not restored. Measured on synthetic particle
images (2048 x 1024 px, passes 64 -> 32 -> 32 x 8, ``python benches/bench_accuracy.py --only
particle-size``), the locking bias's amplitude without / with ``smooth = 0.7``: 0.036 / 0.022 px
for 1.48 px images, 0.018 / 0.0065 px for 1.75 px, 0.011 / 0.004 px for 1.91 px, at the same
RMS error; 0.5 px gains a fifth of that, under 0.4 px the sampled kernel hardly smooths, and
0.9 px raises the random error. A slight defocus at the recording does better.
"""

from __future__ import annotations

import collections
import dataclasses
import os
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.io import read_image
from rspiv.settings import from_keys

__all__ = ["Background", "NEAR_WALL", "Preprocess", "condition", "condition_pair"]

BACKGROUNDS = ("none", "min", "mean", "percentile")
#: The widest smoothing, px (``piv_core::condition::MAX_SMOOTH_SIGMA``).
MAX_SMOOTH = 2.0


@dataclasses.dataclass(frozen=True)
class Preprocess:
    """Which conditioning steps run (module docstring); checked on construction."""

    background: str = "none"
    background_window: int = 0
    percentile: float = 5.0
    hot_pixels: float = 0.0
    high_pass: float = 0.0
    cap: float = 0.0
    min_max: int = 0
    smooth: float = 0.0

    def __post_init__(self) -> None:
        s = object.__setattr__
        b = str(self.background).lower()
        if b not in BACKGROUNDS:
            raise InvalidInputError(
                f"background {self.background!r}: use one of {', '.join(BACKGROUNDS)}"
            )
        s(self, "background", b)
        for key, lo in (("background_window", 0), ("min_max", 0)):
            v = int(getattr(self, key))
            if v < lo:
                raise InvalidInputError(f"{key} must be >= {lo}, got {v}")
            s(self, key, v)
        if 0 < self.min_max < 3:
            raise InvalidInputError(f"min_max window {self.min_max} px must be 0 or >= 3")
        for key in ("percentile", "hot_pixels", "high_pass", "cap", "smooth"):
            v = float(getattr(self, key))
            if not np.isfinite(v) or v < 0:
                raise InvalidInputError(f"{key} must be a finite number >= 0, got {v}")
            s(self, key, v)
        if self.smooth > MAX_SMOOTH:
            raise InvalidInputError(
                f"smooth sigma {self.smooth} px must be 0 or at most {MAX_SMOOTH} (it widens the "
                "particle images: 0.4-0.7 px against peak locking)"
            )
        if 0 < self.hot_pixels <= 1:
            raise InvalidInputError(f"hot_pixels factor {self.hot_pixels} must be 0 or > 1")
        if not 0 <= self.percentile <= 100:
            raise InvalidInputError(f"percentile {self.percentile} is outside [0, 100]")
        if b == "percentile" and self.background_window == 0:
            raise InvalidInputError(
                "background 'percentile' needs a background_window (frames held in memory)"
            )

    @property
    def enabled(self) -> bool:
        """Does any step run?"""
        return self.background != "none" or any(
            (self.hot_pixels, self.high_pass, self.smooth, self.cap, self.min_max)
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "preprocess") -> Preprocess:
        """Settings from vocabulary keys (unknown keys are an error naming ``where``)."""
        return from_keys(cls, d, where, "preprocessing key(s)")


#: The near-wall defaults (module docstring).
NEAR_WALL = Preprocess(background="min", hot_pixels=3.0, high_pass=2.0)


class Background:
    """A run's background, estimated streaming over its frames.

    ``kind="min"`` or ``"mean"`` with ``window=0``: over the whole run, one frame in memory
    (float64 running sum for the mean); with ``window=N``: over the last N frames added (N
    frames in memory), ``kind="percentile"`` included. :meth:`add` takes arrays or image
    paths; :attr:`value` is the current estimate (float32).
    """

    def __init__(self, kind: str = "min", window: int = 0, percentile: float = 5.0) -> None:
        kind = str(kind).lower()
        if kind not in BACKGROUNDS[1:]:
            raise InvalidInputError(f"background {kind!r}: use min, mean or percentile")
        if window < 0 or (kind == "percentile" and window == 0):
            raise InvalidInputError(f"background window {window} frames is not usable for {kind}")
        self.kind, self.window, self.percentile = kind, int(window), float(percentile)
        self.n = 0
        self._acc: np.ndarray | None = None
        self._frames: collections.deque[np.ndarray] = collections.deque(maxlen=window or None)

    def add(self, frame: Any, index: int = 0) -> None:
        """Add one frame (an array, or an image path read with :func:`rspiv.io.read_image`
        taking frame ``index`` of a multi-frame file)."""
        name = os.fspath(frame) if isinstance(frame, (str, os.PathLike)) else "frame"
        a = read_image(frame, frame=index)
        if self._acc is not None and a.shape != self._acc.shape:
            raise InvalidInputError(
                f"{name}: shape {a.shape} differs from the run's {self._acc.shape}"
            )
        if self._frames and a.shape != self._frames[0].shape:
            raise InvalidInputError(
                f"{name}: shape {a.shape} differs from the run's {self._frames[0].shape}"
            )
        self.n += 1
        if self.window:
            self._frames.append(np.asarray(a, dtype=np.float32))
            return
        if self._acc is None:
            self._acc = np.array(a, dtype=np.float64)
        elif self.kind == "min":
            np.minimum(self._acc, a, out=self._acc)
        else:
            self._acc += a

    @property
    def value(self) -> np.ndarray:
        """The background (float32, C-contiguous). InvalidInputError before any frame."""
        if self.n == 0:
            raise InvalidInputError("background: no frame added")
        if self.window:
            stack = np.stack(self._frames)
            if self.kind == "min":
                return np.ascontiguousarray(stack.min(axis=0), dtype=np.float32)
            if self.kind == "mean":
                return np.ascontiguousarray(stack.mean(axis=0, dtype=np.float64), np.float32)
            return np.ascontiguousarray(np.percentile(stack, self.percentile, axis=0), np.float32)
        assert self._acc is not None
        if self.kind == "mean":
            return (self._acc / self.n).astype(np.float32)
        return self._acc.astype(np.float32)

    @classmethod
    def of(cls, frames: Iterable[Any], kind: str = "min", **kw: Any) -> np.ndarray:
        """The background of ``frames`` (arrays or paths), read one at a time."""
        bg = cls(kind, **kw)
        for f in frames:
            bg.add(f)
        return bg.value


def condition(frame: Any, settings: Preprocess, background: Any = None) -> np.ndarray:
    """One frame conditioned by ``settings`` (module docstring) as a new float32 array.

    ``background`` (same shape) is subtracted when given; ``settings.background`` only says how
    the caller estimates it (:class:`Background`). InvalidInputError for bad shapes, NaN/inf.
    """
    if not isinstance(settings, Preprocess):
        raise InvalidInputError(f"settings must be a Preprocess, got {type(settings).__name__}")
    a = read_image(frame)
    bg = None
    if background is not None:
        bg = np.ascontiguousarray(background, dtype=np.float32)
        if bg.shape != a.shape:
            raise InvalidInputError(
                f"background {bg.shape} differs in shape from the frame {a.shape}"
            )
    # the float32 copy is made in Rust, fused with the first steps
    return _rspiv.conditioned(
        a,
        hot_pixels=settings.hot_pixels or None,
        high_pass=settings.high_pass or None,
        cap=settings.cap or None,
        min_max=settings.min_max or None,
        background=bg,
        smooth=settings.smooth or None,
    )


def condition_pair(
    frame_a: Any,
    frame_b: Any,
    settings: Preprocess,
    backgrounds: tuple[Any, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Both frames of a pair conditioned, each with its own background (frame A's and frame
    B's lighting differ)."""
    bga, bgb = backgrounds if backgrounds is not None else (None, None)
    return condition(frame_a, settings, bga), condition(frame_b, settings, bgb)
