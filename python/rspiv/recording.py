"""Is a recording fit for PIV, and which windows does it need? The check a user runs on the first
pair before a campaign of thousands.

:func:`check_recording` measures one frame pair as recorded and says what it holds:

- **particle images**: counted block by block (``piv_core::seeding``: each 64 px block's
  background and camera noise from two quantiles of its values, robust to a background
  clipped at zero; a particle image is a local maximum standing above ``b + max(4 s, 0.2
  signal)``, the signal being the median over the blocks of their 99.5th percentile above
  the background). Two particle images closer than about their diameter merge into one
  maximum, so the count falls short of the particles present as they get denser; it is
  corrected by an exclusion area ``A = 5 + 0.35 d^2`` px^2 (``d`` the e^-2 diameter):
  ``counted = n exp(-n A)``. Measured on the generator's particle images
  (:func:`rspiv.synth.particle_pair`: Gaussian particle images, peak intensities uniform over
  0.6-1.0, 5 % noise, 1024 x 1024 px), the corrected density is within 10 % of the true one
  from 0.005 to 0.04 particles/px at 1.5-3.5 px (``tests/test_recording.py``); where
  ``counted A > 0.25``, or where the noise threshold ``4 s`` exceeds half the signal (the tails
  of overlapping images raise the background's quantiles; or the camera noise is high), most
  particle images are hidden and the density is given as a lower bound (on the generator's
  images: flagged from source densities of about 0.2 at 2 px and 0.4 at 3.5 px; 0.69 of the
  particles at 0.58 with 3.5 px images). Faint particle images (under a fifth of the
  signal) are not counted: they weigh little in a correlation, which goes with the square of
  the intensity (4 % at a fifth), and the bound keeps the noise's own maxima out where the
  quantiles read the noise low (a background clipped at zero and then noised again counted
  18 % too many particle images with a tenth). The **particles per window** ``N_I = n w h``
  come from the median density of the lit blocks (those holding at least a fifth of the 90th
  percentile's density);
- **particle image diameter** (:func:`rspiv.particle_diameter`, from the coarse pass's peaks);
- **the sensor**: the share of the particle images whose brightest pixel is saturated (integer
  frames at their full scale, 255 or ``2^n - 1``), the particle images' signal over the camera
  noise, the background's spread over the frame;
- **the displacement**: one coarse pass of square windows (64 px; doubled up to 256 px while
  the 99th percentile of the displacement exceeds a quarter of the window or the frames do not
  correlate), its median and 99th percentile along x and y, and the displacement difference
  across a window per px of window (the 95th percentile over the vectors of the larger of
  ``|du/dx| + |du/dy|`` and ``|dv/dx| + |dv/dy|``, least-squares gradients of the coarse
  field: a uniform shear of 0.03 / 0.06 px/px reads 0.033 / 0.069, the coarse windows'
  noise adding to it).

From these it recommends passes by the usual rules (Keane & Adrian 1992; Raffel et al. 2018,
ch. 5): the first window at least four times the largest displacement (the one-quarter rule,
99th percentile), the final window the smallest that holds at least
:data:`MIN_PARTICLES_PER_WINDOW` particle images, halving in between; window deformation where
the displacement varies by more than 5 % of the final window across it. The passes a campaign
will use are held to what makes a pass fail rather than to the rules of thumb: a window with
fewer than 7 particle images (:data:`MIN_PARTICLES_WARN`), a first window that keeps fewer than
10 particle image pairs at the largest displacement or whose displacement passes a third of it.
Every concern is one line in :attr:`RecordingCheck.warnings`, keyed by what it is about
(``correlation``, ``same_frames``, ``density``, ``peak_locking``, ``diameter``,
``saturated_A``/``_B``, ``noise_A``/``_B``, ``background_A``/``_B``, ``lit``,
``seeding_rows``/``_columns``: the widest band of 64 px block rows or columns whose lit blocks
hold under :data:`MIN_SEEDING_SHARE` of the frame's density, said where the smallest given
window holds under 7 particle images there but not over the frame (under half the frame's
density without given passes), ``displacement``, ``deformation``, ``windows_WxH``,
``quarter_rule``). A campaign runs the check on its first pair (``summary.json``'s
``recording``).

:func:`rspiv.recording_drift.check_drift` follows pairs spread over a run (one in memory at a
time): each pair's seeding (the same count), background, brightness and displacement, and says
where the seeding thins out, the laser's energy drifts, the background creeps or a pair's frames
are in reverse order (``rspiv check campaign.toml``).

Lengths in px, intensities in the frames' counts, displacements in px per pair.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.multipass import mask_array
from rspiv.piv import piv

__all__ = [
    "MIN_PARTICLES_PER_WINDOW",
    "RecordingCheck",
    "check_recording",
    "coarse_pass",
    "exclusion_area",
    "full_scale",
    "mean_diameter",
    "median_displacement",
    "roi_mask",
    "spread",
    "unlike_pairs",
]

#: Particle images a window needs: Keane & Adrian (1992) give a valid detection probability
#: over 95 % for ``N_I F_I F_O > 7`` with a window offset; 10 leaves room for the out-of-plane
#: loss ``F_O`` of a thin light sheet, which one plane cannot measure.
MIN_PARTICLES_PER_WINDOW = 10.0
#: The one-quarter rule: the first window at least this many times the largest displacement.
QUARTER_RULE = 4.0
#: Given passes are warned about below these: a window's particle images (Keane & Adrian's
#: ``N_I F_I F_O > 7`` with no loss of pairs, as in a pass that follows a predictor); the first
#: window's pairs left at the largest displacement, ``N_I (1 - |u|/w) (1 - |v|/h)``; and the
#: largest displacement's share of the first window (its peak search ends at half the window).
MIN_PARTICLES_WARN, MIN_FIRST_PAIRS, MAX_FIRST_SHARE = 7.0, 10.0, 1.0 / 3.0
#: The displacement difference across a window over its size above which the window offset
#: loses the correlation (Keane & Adrian 1992): deform the windows.
GRADIENT_SHARE = 0.05
#: The square window sizes the recommendation picks from (px).
SIZES = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)
#: The block side of the particle count (px), the noise factor ``k`` and the signal share.
BLOCK, K_NOISE, REL_SIGNAL = 64, 4.0, 0.2
#: Above this ``counted x A`` the particle images overlap too much to be counted.
MAX_COUNTED_OVERLAP = 0.25
#: A lit block holds at least this share of the 90th percentile's density.
LIT_SHARE = 0.2
#: A band of blocks (or a sampled pair, :func:`rspiv.recording_drift.check_drift`) whose
#: seeding falls under this share of the frame's (the run's median) is said.
MIN_SEEDING_SHARE = 0.7
#: A coarse pass whose median correlation coefficient reaches this correlates the same pixels
#: (``piv_core::particle_size::DIAMETER_MAX_COEF``'s reasoning: real pairs give 0.3-0.9).
SAME_FRAMES_COEF = 0.999
#: Thresholds of the warnings (module docstring and :func:`check_recording`).
MIN_SNR, MAX_DIAMETER, MAX_SATURATED, MIN_LIT, MAX_BACKGROUND_SPREAD = 5.0, 6.0, 0.05, 0.8, 0.5


#: The e^-2 diameter (px) the overlap correction takes where the diameter was not measured.
DEFAULT_DIAMETER = 2.5
#: Two successive pairs of frames paired sequentially (1-2, 2-3) whose median displacements
#: differ by more than this factor (the larger over 1 px) are not a time-resolved recording's.
SEQUENCE_MAX_RATIO = 3.0


def unlike_pairs(ok0: bool, m0: float, ok1: bool, m1: float) -> bool:
    """Whether frames paired 1-2 and 2-3 cannot be two pairs of a time-resolved recording: one
    correlates and the other does not (``ok``), or both do and their median displacements
    ``m`` (px) differ by more than :data:`SEQUENCE_MAX_RATIO`, the larger over 1 px. Frames A,
    B, A, B ... of a double-frame camera so paired give a short interval and a long one
    (PIVlab's ``Jet_0001A``, ``B``, ``Jet_0002A``: 0.47 and 11.9 px). Used to refuse sequential
    pairing (``rspiv.campaign.prepare``) and to choose the pairing (:mod:`rspiv.campaign_init`)."""
    lo, hi = sorted((m0, m1))
    return ok0 != ok1 or (ok0 and hi > 1.0 and hi > SEQUENCE_MAX_RATIO * lo)


def mean_diameter(diameter: Sequence[float]) -> float:
    """The mean of the measured diameters ``(x, y)`` px, :data:`DEFAULT_DIAMETER` when neither
    was measured (NaN)."""
    d = [float(v) for v in diameter if np.isfinite(v)]
    return float(np.mean(d)) if d else DEFAULT_DIAMETER


def spread(items: Sequence[Any], n: int) -> list[Any]:
    """Up to ``n`` of ``items`` spread evenly from the first to the last (the pairs
    :func:`rspiv.recording_drift.check_drift` follows)."""
    if not items or n < 1:
        return []
    picks = np.unique(np.linspace(0, len(items) - 1, min(n, len(items))).round())
    return [items[int(i)] for i in picks]


def exclusion_area(diameter: float) -> float:
    """The area (px^2) around a particle image within which another merges into its maximum,
    ``5 + 0.35 d^2`` for an e^-2 diameter ``d`` px (module docstring)."""
    return 5.0 + 0.35 * float(diameter) ** 2


def _corrected(counted: float, area: float) -> tuple[float, bool]:
    """The density ``n`` with ``counted = n exp(-n A)`` (principal branch, by Newton), and
    whether it is only a lower bound (``counted A > MAX_COUNTED_OVERLAP``)."""
    if not np.isfinite(counted) or counted <= 0:
        return float(counted), False
    if counted * area > MAX_COUNTED_OVERLAP:
        return float(counted), True
    n = counted
    for _ in range(50):
        f = n * np.exp(-n * area) - counted
        n -= f / (np.exp(-n * area) * (1.0 - n * area))
    return float(n), False


@dataclasses.dataclass(frozen=True)
class RecordingCheck:
    """What :func:`check_recording` measured (module docstring); ``(a, b)`` pairs are per
    frame, NaN where not measured."""

    shape: tuple[int, int]
    dtype: str
    #: Particle images per px as counted, and corrected for overlap (``density_bound``: the
    #: corrected value is only a lower bound); source density ``n pi d^2 / 4``.
    counted_density: float
    density: float
    density_bound: bool
    source_density: float
    #: The share of 64 px blocks holding particle images, and the lit part's bounding box
    #: ``(x0, y0, x1, y1)`` px (x1, y1 exclusive).
    lit_fraction: float
    lit_box: tuple[int, int, int, int] | None
    #: e^-2 diameter (x, y), px.
    diameter: tuple[float, float]
    #: Per frame: the background (median of the lit blocks' medians), its spread (5th to 95th
    #: percentile of the blocks' backgrounds), the camera noise sigma and the particle images'
    #: signal (counts), and the share of the particle images counted whose brightest pixel is
    #: at the sensor's full scale.
    background: tuple[float, float]
    background_spread: tuple[float, float]
    noise: tuple[float, float]
    signal: tuple[float, float]
    saturated: tuple[float, float]
    #: The coarse pass's window (px), its median displacement ``(u, v)``, the 99th percentile
    #: of ``|u|`` and ``|v|``, its median peak ratio and the share of its vectors valid.
    coarse_window: int
    median_displacement: tuple[float, float]
    p99_displacement: tuple[float, float]
    peak_ratio: float
    valid_share: float
    correlates: bool
    #: The 95th percentile of the displacement difference across one window per px of
    #: window (px/px, from the coarse field's gradients).
    gradient: float
    #: The recommendation: passes ``[(w, h), ...]`` and the deformation; None when the frames
    #: do not correlate.
    passes: list[tuple[int, int]] | None
    deformation: str | None
    #: Particle images per window ``{"WxH": N}`` for the recommended and the given passes.
    per_window: dict[str, float]
    warnings: dict[str, str]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field."""
        d = dataclasses.asdict(self)
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}

    def lines(self) -> list[str]:
        """The check as lines of text: the measurements, the recommendation, the warnings."""

        def two(v: tuple[float, float], f: str = ".0f") -> str:
            return f"{v[0]:{f}} / {v[1]:{f}}"

        dens = f"{self.density:.4f}" + (" or more" if self.density_bound else "")
        out = [
            f"frames: {self.shape[1]} x {self.shape[0]} px, {self.dtype}",
            f"particle images: {dens} per px ({self.counted_density:.4f} counted), source "
            f"density {self.source_density:.3f}, e^-2 diameter {self.diameter[0]:.1f} x "
            f"{self.diameter[1]:.1f} px",
            f"lit part: {100 * self.lit_fraction:.0f} % of the frame"
            + (f", x {self.lit_box[0]}-{self.lit_box[2]}, y {self.lit_box[1]}-{self.lit_box[3]} px"
               if self.lit_box else ""),
            f"frames A / B: background {two(self.background)}, spread {two(self.background_spread)}"
            f", noise {two(self.noise, '.1f')}, signal {two(self.signal)} counts, saturated "
            f"{two(tuple(100 * s for s in self.saturated), '.1f')} % of the particle images",
            f"displacement ({self.coarse_window} px windows): median u "
            f"{self.median_displacement[0]:.2f}, v {self.median_displacement[1]:.2f} px; 99th "
            f"percentile |u| "
            f"{self.p99_displacement[0]:.2f}, |v| {self.p99_displacement[1]:.2f} px; peak ratio "
            f"{self.peak_ratio:.2f}, {100 * self.valid_share:.0f} % valid; difference across a "
            f"window {100 * self.gradient:.1f} % of it",
        ]  # fmt: skip
        if self.passes:
            out.append(
                "recommended passes: "
                + " -> ".join(f"{w}x{h}" for w, h in self.passes)
                + f", deformation {self.deformation}"
            )
        out.append(
            "particle images per window: "
            + ", ".join(f"{k} {v:.1f}" for k, v in self.per_window.items())
        )
        out += [f"warning: {w}" for w in self.warnings.values()]
        return out


def roi_mask(
    mask: np.ndarray | None, roi: Sequence[int] | None, shape: tuple[int, int]
) -> np.ndarray | None:
    """``mask`` (True = excluded, or None) with everything outside ``roi = (x0, y0, x1, y1)``
    px (``x0 <= x < x1``) excluded too, for frames of ``shape``; ``mask`` itself without a
    region. A campaign's region of interest is in object px with a correction: the distortion
    shifts it by at most its displacement, a few 64 px blocks' worth at most."""
    if roi is None:
        return mask
    out = np.ones(tuple(shape), bool)
    x0, y0, x1, y1 = (int(v) for v in roi)
    out[y0:y1, x0:x1] = False
    return out if mask is None else out | mask


def full_scale(frame: np.ndarray) -> float | None:
    """The sensor's full scale where an integer frame reaches it (255, or ``2^n - 1`` for n of
    8-16 reached by the frame's maximum), else None: the level at which a particle image counts
    as saturated."""
    if frame.dtype.kind == "u" and frame.size:
        top = int(frame.max())
        if top in ({255} if frame.dtype == np.uint8 else {2**n - 1 for n in range(8, 17)}):
            return float(top)
    return None


def _frame_stats(frame: np.ndarray, mask: np.ndarray | None) -> dict[str, Any]:
    """The Rust block count of one frame; its particle images at the full scale of an integer
    frame (:func:`full_scale`) count as saturated."""
    return _rspiv.seeding(frame, BLOCK, K_NOISE, REL_SIGNAL, full_scale(frame), mask)


def _lit_blocks(sa: dict, sb: dict):
    """``(both, measured, lit, counted)`` of two frames' block counts: the particle images per
    px of each block (the frames' mean), the blocks measured, the lit ones (at least
    :data:`LIT_SHARE` of the 90th percentile's density) and the lit blocks' median density as
    counted."""
    both = 0.5 * sum(s["peaks"] / np.maximum(s["searched"], 1) for s in (sa, sb))
    measured = np.isfinite(sa["background"]) & (sa["searched"] > 0)
    ref = np.percentile(both[measured], 90) if np.any(measured) else 0.0
    lit = measured & (both >= LIT_SHARE * ref) & (ref > 0)
    counted = float(np.median(both[lit])) if np.any(lit) else 0.0
    return both, measured, lit, counted


def coarse_pass(frame_a, frame_b, mask, shape) -> Any:
    """The coarse pass (module docstring): the field and its window (px)."""
    limit = min(shape) // 2
    w = min(64, max(16, limit))
    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = piv(frame_a, frame_b, passes=[(w, w)], overlap=0.5, mask=mask, uncertainty=False)
        good = f.valid & ~f.replaced & ~f.masked
        p99 = (
            max(np.percentile(np.abs(f.u[good]), 99), np.percentile(np.abs(f.v[good]), 99))
            if np.any(good)
            else np.inf
        )
        if (f.uncorrelated() or p99 > w / QUARTER_RULE) and 2 * w <= min(limit, 256):
            w *= 2
            continue
        return f, w


def _correlation_state(field) -> tuple[np.ndarray, bool, bool]:
    """``(good, same, correlates)`` of a coarse field: its vectors measured (valid, not
    replaced, not masked); the same pixels correlating (frame A given twice, or a static
    pattern over the particles: they correlate to 1 at zero lag, as particle images that moved
    never do, real pairs giving 0.3-0.9); and a field that correlates otherwise."""
    good = field.valid & ~field.replaced & ~field.masked
    same = bool(np.any(good)) and float(np.median(field.coef[good])) >= SAME_FRAMES_COEF
    return good, same, not field.uncorrelated() and bool(np.any(good)) and not same


def median_displacement(field) -> tuple[float, float]:
    """The median ``(u, v)`` px of a coarse field's measured vectors, NaN where the frames do
    not correlate or correlate the same pixels (:func:`coarse_pass`)."""
    good, _, correlates = _correlation_state(field)
    if not correlates:
        return (np.nan, np.nan)
    return (float(np.median(field.u[good])), float(np.median(field.v[good])))


def _thin_band(both: np.ndarray, lit: np.ndarray, counted: float, axis: int):
    """The widest run of block rows (``axis`` 0) or columns (1) whose lit blocks' median density
    is under :data:`MIN_SEEDING_SHARE` of ``counted``: ``(first, last + 1, share)`` in blocks,
    or None."""
    n = both.shape[axis]
    share = np.full(n, np.nan)
    for i in range(n):  # a few dozen block rows or columns, not pixels
        d = both[i] if axis == 0 else both[:, i]
        ok = lit[i] if axis == 0 else lit[:, i]
        if np.count_nonzero(ok) * 2 >= ok.size:
            share[i] = np.median(d[ok]) / counted
    thin = share < MIN_SEEDING_SHARE
    best, start = None, None
    for i in range(n + 1):
        if i < n and thin[i]:
            start = i if start is None else start
        elif start is not None:
            if best is None or i - start > best[1] - best[0]:
                best = (start, i, float(np.mean(share[start:i])))
            start = None
    return best


def _first_fit(need: float) -> int:
    """The smallest of :data:`SIZES` at least ``need``, or the largest."""
    return next((s for s in SIZES if s >= need), SIZES[-1])


def check_recording(
    frame_a: Any,
    frame_b: Any,
    *,
    mask: Any = None,
    passes: Sequence[tuple[int, int]] | None = None,
) -> RecordingCheck:
    """Measure a frame pair as recorded and recommend its PIV passes (module docstring).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D, same shape and dtype
        The two exposures as recorded (uint8, uint16, float32 or float64), not conditioned.
    mask : array_like of bool or path, optional
        True where nothing is to be measured (as :func:`rspiv.piv`).
    passes : sequence of (w, h), optional
        The passes a campaign will use: each window's particle count and the first window's
        quarter rule are checked too.

    Returns
    -------
    RecordingCheck

    Raises
    ------
    InvalidInputError
        Frames of different shapes or dtypes, not 2D, smaller than 32 x 32 px, with values
        that are not finite; a mask of another shape; a pass that is not two sizes >= 4.
    """
    a, b = np.asarray(frame_a), np.asarray(frame_b)
    if a.ndim != 2 or a.shape != b.shape or a.dtype != b.dtype:
        raise InvalidInputError(
            f"frames must be 2D arrays of one shape and dtype, got {a.shape} {a.dtype} and "
            f"{b.shape} {b.dtype}"
        )
    if min(a.shape) < 32:
        raise InvalidInputError(f"frames of {a.shape[1]} x {a.shape[0]} px: too small to check")
    given = [(int(w), int(h)) for w, h in passes] if passes else []
    if any(w < 4 or h < 4 for w, h in given):
        raise InvalidInputError(f"passes must be window sizes (w, h) >= 4 px, got {given}")
    m = mask_array(mask, a.shape)
    sa, sb = _frame_stats(a, m), _frame_stats(b, m)
    field, cw = coarse_pass(a, b, m, a.shape)
    said: dict[str, str] = {}

    # particle images: the lit blocks' median density, both frames
    both, measured, lit, counted = _lit_blocks(sa, sb)
    diameter = tuple(float(d) for d in field.particle_diameter)
    d_eff = mean_diameter(diameter)
    density, bound = _corrected(counted, exclusion_area(d_eff))
    # a threshold over half the signal leaves most particle images uncounted: overlapping
    # images (their tails raise the background's quantiles) or camera noise
    dense = bool(
        np.any(measured)
        and np.median(np.concatenate([sa["noise"][measured], sb["noise"][measured]])) * K_NOISE
        > 0.5 * 0.5 * (float(sa["signal"]) + float(sb["signal"]))
    )
    bound = bound or dense
    lit_fraction = float(np.count_nonzero(lit) / max(np.count_nonzero(measured), 1))
    lit_box = None
    if np.any(lit):
        rows, cols = np.nonzero(lit)
        lit_box = (
            int(cols.min() * BLOCK),
            int(rows.min() * BLOCK),
            int(min((cols.max() + 1) * BLOCK, a.shape[1])),
            int(min((rows.max() + 1) * BLOCK, a.shape[0])),
        )

    def per_frame(s: dict, key: str, q: float | None = None) -> float:
        v = s[key][lit] if np.any(lit) else s[key][measured]
        v = v[np.isfinite(v)]
        return float(np.percentile(v, q) if q is not None else np.median(v)) if v.size else np.nan

    background = (per_frame(sa, "median"), per_frame(sb, "median"))
    spread = tuple(
        float(np.subtract(*np.percentile(s["background"][measured], [95, 5])))
        if np.any(measured)
        else np.nan
        for s in (sa, sb)
    )
    noise = (per_frame(sa, "noise"), per_frame(sb, "noise"))
    signal = (float(sa["signal"]), float(sb["signal"]))
    saturated = tuple(
        float(s["saturated"].sum() / max(int(s["peaks"].sum()), 1)) for s in (sa, sb)
    )

    # the displacement
    good, same, correlates = _correlation_state(field)
    if correlates:
        med = median_displacement(field)
        p99 = (
            float(np.percentile(np.abs(field.u[good]), 99)),
            float(np.percentile(np.abs(field.v[good]), 99)),
        )
        g = field.gradients("least_squares")
        across = np.maximum(
            np.abs(g["dudx"]) + np.abs(g["dudy"]), np.abs(g["dvdx"]) + np.abs(g["dvdy"])
        )[good]
        across = across[np.isfinite(across)]
        gradient = float(np.percentile(across, 95)) if across.size else np.nan
    else:  # no displacement measured: frame A given twice, or frames that do not correlate
        med = p99 = (np.nan, np.nan)
        gradient = np.nan
        if same:
            said["same_frames"] = (
                f"frames A and B are the same pixels (median correlation coefficient "
                f"{float(np.median(field.coef[good])):.4f}): frame A given twice, or a static "
                "pattern that hides the particle images; no displacement measured and no passes "
                "recommended"
            )
        else:
            said["correlation"] = (
                f"the frames do not correlate ({field.warning() or 'no window correlated'}; "
                f"windows up to {cw} px): no displacement measured and no passes recommended; "
                "check the pairing, both exposures and the laser timing"
            )
    pr = field.peak_ratio[~field.masked & (field.peak_ratio > 0)]
    peak_ratio = float(np.median(pr)) if pr.size else np.nan
    live = ~field.masked
    valid_share = float(np.count_nonzero(good) / max(np.count_nonzero(live), 1))

    # the recommendation
    def n_in(w: int, h: int) -> float:
        return density * w * h

    rec = None
    deformation = None
    if correlates and density > 0:
        final = next((s for s in SIZES if n_in(s, s) >= MIN_PARTICLES_PER_WINDOW), SIZES[-1])
        first = max(_first_fit(QUARTER_RULE * max(p99)), final)
        rec = [first]
        while rec[-1] > final:
            rec.append(max(final, rec[-1] // 2))
        rec = [(s, s) for s in rec]
        deformation = "offset" if gradient <= GRADIENT_SHARE else "symmetric"  # NaN: unknown
    per_window = {f"{w}x{h}": n_in(w, h) for w, h in (rec or []) + given}

    # what to say
    if density <= 0:
        said["density"] = (
            "no separate particle images stand out of the noise"
            + (" (the noise threshold is over half the signal: overlapping images or noise)"
               if dense else "")
            + ": nothing to count"
        )  # fmt: skip
    elif bound:
        said["density"] = (
            f"the particle images overlap (source density {density * np.pi * d_eff**2 / 4:.2f} "
            "or more) or stand little above the noise: too many are hidden to be counted one "
            "by one, the density is a lower bound"
        )
    locking = _rspiv.peak_locking_warning(*diameter)
    if locking:
        said["peak_locking"] = locking
    if max((d for d in diameter if np.isfinite(d)), default=0.0) > MAX_DIAMETER:
        said["diameter"] = (
            f"particle images of {np.nanmax(diameter):.1f} px: the random error grows with the "
            "diameter (2-4 px is best); focus the camera or close its aperture"
        )
    for name, sat in zip("AB", saturated, strict=True):
        if sat > MAX_SATURATED:
            said[f"saturated_{name}"] = (
                f"frame {name}: {100 * sat:.0f} % of the particle images reach the sensor's full "
                "scale: flattened particle images bias the sub-pixel fit; lower the laser energy "
                "or the camera's gain"
            )
    for name, sig, nz in zip("AB", signal, noise, strict=True):
        if np.isfinite(sig) and np.isfinite(nz) and sig < MIN_SNR * nz:
            said[f"noise_{name}"] = (
                f"frame {name}: the particle images stand {sig / nz:.1f} times above the camera "
                f"noise (under {MIN_SNR:g}): more laser energy, a wider aperture or more gain"
            )
    for name, sp, sig in zip("AB", spread, signal, strict=True):
        if np.isfinite(sp) and np.isfinite(sig) and sig > 0 and sp > MAX_BACKGROUND_SPREAD * sig:
            said[f"background_{name}"] = (
                f"frame {name}: the background varies by {sp:.0f} counts over the frame "
                f"({sp / sig:.1f} times the particle images' signal; glare, reflections or an "
                "uneven sheet): subtract the run's minimum background and high-pass (the "
                "campaign's near-wall conditioning)"
            )
    if lit_fraction < MIN_LIT and lit_box is not None:
        said["lit"] = (
            f"only {100 * lit_fraction:.0f} % of the frame holds particle images (lit part x "
            f"{lit_box[0]}-{lit_box[2]}, y {lit_box[1]}-{lit_box[3]} px): mask the rest or set "
            "a region of interest"
        )
    if counted > 0:
        for axis, name, size in ((0, "rows", a.shape[0]), (1, "columns", a.shape[1])):
            band = _thin_band(both, lit, counted, axis)
            if band is None:
                continue
            lo, hi = band[0] * BLOCK, min(band[1] * BLOCK, size)
            per = ""
            if given:  # said where it fails the smallest window, not the frame as a whole
                w, h = min(given, key=lambda p: p[0] * p[1])
                n = band[2] * n_in(w, h)
                if n >= MIN_PARTICLES_WARN or n_in(w, h) < MIN_PARTICLES_WARN:
                    continue
                per = f" ({w} x {h} px windows hold {n:.1f} particle images there)"
            elif band[2] >= 0.5:
                continue
            said[f"seeding_{name}"] = (
                f"the seeding thins to {100 * band[2]:.0f} % of the frame's in {name} "
                f"{'y' if axis == 0 else 'x'} {lo}-{hi} px{per}: near a wall the particles "
                "thin out or glare hides them; larger windows there, or more seeding"
            )
    if correlates and rec:
        final = rec[-1][0]
        top = max(p99)
        if top < 0.1 * final:
            said["displacement"] = (
                f"the largest displacements are {top:.2f} px, {100 * top / final:.0f} % of a "
                f"{final} px window: the random error (about 0.05-0.1 px) is a large share of "
                f"them; a pulse separation up to {final / QUARTER_RULE / max(top, 1e-3):.0f} "
                "times as long keeps them within a quarter of the window"
            )
        if deformation == "symmetric":
            said["deformation"] = (
                f"the displacement varies by {100 * gradient:.0f} % of a window across it (95th "
                f"percentile; over {100 * GRADIENT_SHARE:.0f} %): deform the windows "
                "(deformation = symmetric), a window offset loses the correlation there"
            )
    for w, h in given:
        n = n_in(w, h)
        if n < MIN_PARTICLES_WARN:
            said[f"windows_{w}x{h}"] = (
                f"{w} x {h} px windows hold {n:.1f} particle images (under "
                f"{MIN_PARTICLES_WARN:g}, Keane & Adrian's N_I F_I F_O > 7 even without a loss "
                "of pairs): expect outliers; larger windows or more seeding"
            )
    if given and correlates:
        w, h = given[0]
        pairs = n_in(w, h) * max(1.0 - p99[0] / w, 0.0) * max(1.0 - p99[1] / h, 0.0)
        if p99[0] > MAX_FIRST_SHARE * w or p99[1] > MAX_FIRST_SHARE * h or (
            pairs < MIN_FIRST_PAIRS
        ):
            said["quarter_rule"] = (
                f"the first pass's {w} x {h} px windows are too small for the largest "
                f"displacements (|u| {p99[0]:.1f}, |v| {p99[1]:.1f} px, 99th percentile): "
                f"{pairs:.1f} particle image pairs stay in a window (under "
                f"{MIN_FIRST_PAIRS:g}) or the displacement passes a third of it; the "
                "one-quarter rule asks for windows four times the displacement"
            )
    return RecordingCheck(
        shape=(int(a.shape[0]), int(a.shape[1])),
        dtype=str(a.dtype),
        counted_density=counted,
        density=density,
        density_bound=bound,
        source_density=float(density * np.pi * d_eff**2 / 4),
        lit_fraction=lit_fraction,
        lit_box=lit_box,
        diameter=diameter,
        background=background,
        background_spread=spread,
        noise=noise,
        signal=signal,
        saturated=saturated,
        coarse_window=int(cw),
        median_displacement=med,
        p99_displacement=p99,
        peak_ratio=peak_ratio,
        valid_share=valid_share,
        correlates=correlates,
        gradient=gradient,
        passes=rec,
        deformation=deformation,
        per_window=per_window,
        warnings=said,
    )
