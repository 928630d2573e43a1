"""A recording over its run: what drifts between pairs spread over it, and which way it flows.

:func:`check_drift` follows pairs spread over a run (one in memory at a time), measuring each
as :func:`rspiv.check_recording` does the first: its seeding (the particle images per px,
corrected for overlap), each frame's background and the particle images' brightness, and the
median displacement of its coarse pass (:func:`rspiv.recording.coarse_pass`). It says where the
seeding thins out, the laser's energy drifts, the background creeps, and where a pair's
displacement points the other way from the run's (:func:`flow_direction`).

**Frames in reverse order.** A pair whose frames A and B are swapped (a frame dropped by the
camera, files named in the wrong order, a pairing shifted by one frame in a double-frame
sequence) correlates as well as any other and passes every test within its field, but measures
the flow backwards. In a boundary layer such a pair is no small error: one pair of ``-U``
among ``N`` adds ``4 U^2 / N`` to the variance of ``u``, so one in a thousand pairs with ``U``
of 20 px adds 1.6 px^2 (the variance of a ``u_rms`` of 1.3 px), and the skewness and flatness
go wild. Nothing in a single
field tells it; only the run does. :func:`flow_direction` takes the sampled pairs' median
displacements: where they agree on one direction (along the axis they share, turned the way
most of them go, every pair's displacement is at least half of their median, or at most minus
half; at most a quarter of them the other way; their median length at least 1 px), it gives that
direction, which a campaign holds each pair's
mean displacement against (:mod:`rspiv.campaign.pair_quality`); where the flow's mean turns
(a wake, an oscillating flow, a flow at rest), it says why no direction is given rather than
guess.

Displacements in px per pair in the raw frame, intensities in the frames' counts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.multipass import mask_array
from rspiv.recording import (
    BLOCK,
    DEFAULT_DIAMETER,
    MAX_BACKGROUND_SPREAD,
    MIN_SEEDING_SHARE,
    _corrected,
    _frame_stats,
    _lit_blocks,
    coarse_pass,
    exclusion_area,
    median_displacement,
)

__all__ = [
    "MAX_SIGNAL_RATIO",
    "MAX_REVERSED_SHARE",
    "MIN_DIRECTION_PX",
    "STEADY_SHARE",
    "FlowDirection",
    "RecordingDrift",
    "check_drift",
    "flow_direction",
    "pair_brightness",
]

#: The particle images' brightness (signal) varying more than this factor over the run is said.
MAX_SIGNAL_RATIO = 1.5
#: A run's direction is given only where every sampled pair's median displacement along it is
#: at least this share of its length, or at most minus this share (the other way: reversed).
STEADY_SHARE = 0.5
#: ... and where the run's median displacement is at least this long (px), and at most this
#: share of the samples displace the other way.
MIN_DIRECTION_PX, MAX_REVERSED_SHARE = 1.0, 0.25
#: The bands of 64 px rows :func:`pair_brightness` measures.
STRIPES = 2


@dataclasses.dataclass(frozen=True)
class FlowDirection:
    """The run's direction from sampled pairs (module docstring).

    Attributes
    ----------
    displacement : (float, float) or None
        The median displacement ``(u, v)`` px of the sampled pairs that agree on it; None when
        the samples cannot tell one (``note`` says why).
    pairs : list of int
        The pairs that agree on it.
    reversed : list of int
        Sampled pairs whose displacement points the other way (frames in reverse order?).
    note : str
        Why no direction is given; empty when one is.
    """

    displacement: tuple[float, float] | None
    pairs: list[int]
    reversed: list[int]
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field."""
        d = dataclasses.asdict(self)
        d["displacement"] = None if self.displacement is None else list(self.displacement)
        return d


def flow_direction(
    ids: Sequence[int], displacement: Sequence[tuple[float, float]]
) -> FlowDirection:
    """The run's direction from its sampled pairs' median displacements (module docstring).

    Parameters
    ----------
    ids : sequence of int
        The pairs' ids.
    displacement : sequence of (u, v)
        Each pair's median displacement (px); NaN for a pair that does not correlate (left out).

    Returns
    -------
    FlowDirection

    Raises
    ------
    InvalidInputError
        Displacements that are not ``(u, v)`` pairs, or not one per id.
    """
    d = np.asarray(displacement, float)
    ids = [int(k) for k in ids]
    if d.ndim != 2 or d.shape[1:] != (2,) or d.shape[0] != len(ids):
        raise InvalidInputError(
            f"flow_direction: expected one (u, v) displacement per pair id ({len(ids)}), got an "
            f"array of shape {d.shape}"
        )
    ok = np.all(np.isfinite(d), axis=1)
    if np.count_nonzero(ok) < 2:
        return FlowDirection(None, [], [], "fewer than two of the sampled pairs correlate")
    keep = [k for k, o in zip(ids, ok, strict=True) if o]
    d = d[ok]
    length = float(np.median(np.hypot(d[:, 0], d[:, 1])))
    if length < MIN_DIRECTION_PX:
        return FlowDirection(
            None, [], [],
            f"the sampled pairs' median displacement is {length:.2f} px, under "
            f"{MIN_DIRECTION_PX:g} px",
        )  # fmt: skip
    # the axis the displacements share (the principal one), turned the way most of them go
    axis = np.linalg.eigh(d.T @ d)[1][:, -1]
    proj = d @ axis
    if np.count_nonzero(proj > 0) < np.count_nonzero(proj < 0):
        axis, proj = -axis, -proj
    ref = axis * float(np.median(np.abs(proj)))
    along = proj / float(np.median(np.abs(proj)))
    forward = along >= STEADY_SHARE
    back = along <= -STEADY_SHARE
    unsteady = ~(forward | back)
    if np.any(unsteady):
        j = int(np.flatnonzero(unsteady)[0])
        return FlowDirection(
            None, [], [],
            f"pair {keep[j]}'s median displacement ({d[j, 0]:.2f}, {d[j, 1]:.2f}) px is "
            f"{along[j]:.2f} of the sampled pairs' ({ref[0]:.2f}, {ref[1]:.2f}) px along it: the "
            "flow's direction changes over the run",
        )  # fmt: skip
    fwd = [k for k, f in zip(keep, forward, strict=True) if f]
    rev = [k for k, b in zip(keep, back, strict=True) if b]
    if len(rev) > MAX_REVERSED_SHARE * len(keep):
        # a minority that large may as well be the right way: refuse to choose
        return FlowDirection(
            None, fwd, rev,
            f"the sampled pairs displace both ways ({len(fwd)} one way, {len(rev)} the other: "
            f"pairs {', '.join(map(str, rev))}): frames in reverse order in a large part of the "
            "run? Which way the flow goes cannot be told from the samples",
        )  # fmt: skip
    ref = np.median(d[forward], axis=0)
    return FlowDirection((float(ref[0]), float(ref[1])), fwd, rev)


@dataclasses.dataclass(frozen=True)
class RecordingDrift:
    """What :func:`check_drift` measured on pairs spread over a run: per pair (``pairs``, in
    the order given) the particle images per px (corrected for overlap, the two frames'
    mean), each frame's background (median of its blocks' medians) and signal (counts), and
    the median displacement of its coarse pass (px, NaN where it does not correlate); the run's
    direction (:func:`flow_direction`); and one line per concern (``seeding``,
    ``signal_A``/``_B``, ``background_A``/``_B``, ``reversed``)."""

    pairs: list[int]
    density: list[float]
    background: list[tuple[float, float]]
    signal: list[tuple[float, float]]
    displacement: list[tuple[float, float]]
    direction: FlowDirection
    warnings: dict[str, str]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field."""
        d = dataclasses.asdict(self)
        d["direction"] = self.direction.to_dict()
        return d

    def lines(self) -> list[str]:
        """A table of the pairs, the run's direction, then the warnings."""
        out = ["pair  particles/px  background A / B  signal A / B (counts)  displacement (px)"]
        for k, d, b, s, uv in zip(
            self.pairs, self.density, self.background, self.signal, self.displacement,
            strict=True,
        ):  # fmt: skip
            out.append(
                f"{k:>5}  {d:12.4f}  {b[0]:8.0f} / {b[1]:<6.0f}  {s[0]:6.0f} / {s[1]:<13.0f}"
                f"  ({uv[0]:.2f}, {uv[1]:.2f})"
            )
        fd = self.direction
        if fd.displacement is not None:
            out.append(
                f"the run's direction: ({fd.displacement[0]:.2f}, {fd.displacement[1]:.2f}) px "
                f"from {len(fd.pairs)} pairs"
            )
        else:
            out.append(f"the run's direction: not given ({fd.note})")
        return out + [f"warning: {w}" for w in self.warnings.values()]


def _seeding_figures(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None):
    """``(counted, (background A, B), (signal A, B))`` of one pair: the particle images counted
    per px in the lit blocks (not corrected for overlap), each frame's background and signal
    (counts); ``(0, NaN, NaN)`` where no block is measured."""
    stats = [_frame_stats(f, mask) for f in (a, b)]
    _, measured, lit, counted = _lit_blocks(*stats)
    if not np.any(measured):
        return 0.0, (np.nan, np.nan), (np.nan, np.nan)
    sel = lit if np.any(lit) else measured
    bg = tuple(float(np.nanmedian(s["median"][sel])) for s in stats)
    return counted, bg, tuple(float(s["signal"]) for s in stats)


def _pair_figures(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None, diameter: float):
    """``(density, (background A, B), (signal A, B), (u, v))`` of one pair (module
    docstring)."""
    counted, bg, sig = _seeding_figures(a, b, mask)
    field, _ = coarse_pass(a, b, mask, a.shape)
    uv = median_displacement(field)
    density = _corrected(counted, exclusion_area(diameter))[0] if counted > 0 else 0.0
    return density, bg, sig, uv


def pair_brightness(
    a: np.ndarray,
    b: np.ndarray,
    mask: np.ndarray | None,
    rows: tuple[int, int] | None = None,
    stripes: int = STRIPES,
) -> dict[str, float]:
    """A pair's seeding and each frame's brightness from ``stripes`` bands of 64 px rows at
    ``(k + 1/2) / stripes`` of the rows ``rows = (y0, y1)`` (default all; a band of fewer
    rows is taken whole): ``counted`` particle images per px in the lit blocks (not
    corrected for overlap: a measure to follow over a run), ``signal_a``/``signal_b`` (the
    particle images' height above the background, counts) and ``background_a``/``_b``
    (counts); NaN where nothing is measured. Two bands are a twentieth of a 47 MP frame, 25 ms
    per pair.

    The pair loop of a campaign keeps them for every pair (:mod:`rspiv.campaign.pair_quality`):
    a weak laser pulse, the seeding running out or the background creeping, pair by pair.

    Raises
    ------
    InvalidInputError
        Frames that are not 2D arrays of one shape, or a mask of another shape.
    """
    a, b = np.asarray(a), np.asarray(b)
    if a.ndim != 2 or a.shape != b.shape:
        raise InvalidInputError(
            f"pair_brightness: frames must be 2D arrays of one shape, got {a.shape} and {b.shape}"
        )
    if mask is not None and np.shape(mask) != a.shape:
        raise InvalidInputError(
            f"pair_brightness: the mask is {np.shape(mask)}, the frames {a.shape}"
        )
    y0, y1 = (0, a.shape[0]) if rows is None else (max(int(rows[0]), 0), int(rows[1]))
    y1 = min(y1, a.shape[0])
    if y1 - y0 > stripes * BLOCK:
        mid = y0 + (np.arange(stripes) + 0.5) * (y1 - y0) / stripes
        starts = np.clip((mid - BLOCK / 2).round().astype(int), y0, y1 - BLOCK)
        take = np.concatenate([np.arange(y, y + BLOCK) for y in starts])
    else:
        take = np.arange(y0, y1)
    a, b = a[take], b[take]
    mask = None if mask is None else mask[take]
    counted, bg, sig = _seeding_figures(a, b, mask)
    return {
        "counted": round(float(counted), 6),
        "signal_a": round(sig[0], 2),
        "signal_b": round(sig[1], 2),
        "background_a": round(bg[0], 2),
        "background_b": round(bg[1], 2),
    }


def check_drift(
    pairs,
    *,
    mask: Any = None,
    diameter: float = DEFAULT_DIAMETER,
    passes: Sequence[tuple[int, int]] | None = None,
) -> RecordingDrift:
    """The seeding, background, brightness and displacement of pairs spread over a run, and
    how they drift.

    Parameters
    ----------
    pairs : iterable of (int, ndarray, ndarray)
        ``(pair id, frame A, frame B)`` as recorded, one pair in memory at a time.
    mask : array_like of bool or path, optional
        True where nothing is measured.
    diameter : float
        The particle images' e^-2 diameter (px) for the overlap correction
        (:func:`rspiv.check_recording` measures it).
    passes : sequence of (w, h), optional
        The run's passes: the thinnest seeding is also given per window of the smallest.

    Returns
    -------
    RecordingDrift
        Said: a pair whose seeding is under :data:`rspiv.recording.MIN_SEEDING_SHARE` of the
        median (the seeding thins out as a run goes on, or a pulse of the seeder), particle
        images whose brightness varies by more than :data:`MAX_SIGNAL_RATIO` (the laser's
        energy), a background that drifts by more than half the signal (a background over the
        whole run leaves the rest in the frames: a sliding window of frames follows it), and
        pairs whose displacement points the other way from the run's (``reversed``).
    """
    ids, dens, bgs, sigs, uvs = [], [], [], [], []
    m = None
    for k, a, b in pairs:
        a, b = np.asarray(a), np.asarray(b)
        if m is None and mask is not None:
            m = mask_array(mask, a.shape)
        d, bg, sig, uv = _pair_figures(a, b, m, diameter)
        ids.append(int(k))
        dens.append(d)
        bgs.append(bg)
        sigs.append(sig)
        uvs.append(uv)
    if not ids:
        raise InvalidInputError("check_drift needs at least one pair")
    said: dict[str, str] = {}
    med = float(np.median(dens))
    low = int(np.argmin(dens))
    if med > 0 and dens[low] < MIN_SEEDING_SHARE * med:
        per = ""
        if passes:
            w, h = min(passes, key=lambda p: p[0] * p[1])
            per = f" ({w} x {h} px windows then hold {dens[low] * w * h:.1f} particle images)"
        said["seeding"] = (
            f"the seeding thins to {dens[low]:.4f} particle images per px at pair {ids[low]}, "
            f"{100 * dens[low] / med:.0f} % of the run's median {med:.4f}{per}: the seeder or "
            "the mixing changed during the run"
        )
    sig, bg = np.array(sigs, float), np.array(bgs, float)
    for j, name in enumerate("AB"):
        s = sig[:, j][np.isfinite(sig[:, j]) & (sig[:, j] > 0)]
        if s.size and s.max() > MAX_SIGNAL_RATIO * s.min():
            said[f"signal_{name}"] = (
                f"frame {name}'s particle images vary in brightness by {s.max() / s.min():.1f} "
                f"times over the pairs ({s.min():.0f}-{s.max():.0f} counts): the laser's energy "
                "or the sheet's position drifts"
            )
        b = bg[:, j][np.isfinite(bg[:, j])]
        typical = float(np.median(s)) if s.size else np.nan
        if b.size and np.isfinite(typical) and np.ptp(b) > MAX_BACKGROUND_SPREAD * typical:
            said[f"background_{name}"] = (
                f"frame {name}'s background drifts by {np.ptp(b):.0f} counts over the pairs "
                f"({np.ptp(b) / typical:.1f} times the particle images' signal): a background "
                "over the whole run leaves the rest in the frames; a sliding window of frames "
                "([preprocess] background_window) follows it"
            )
    direction = flow_direction(ids, uvs)
    if direction.reversed and direction.displacement is not None:
        dx, dy = direction.displacement
        which = ", ".join(str(k) for k in direction.reversed)
        said["reversed"] = (
            f"pair(s) {which} displace the other way from the run's ({dx:.2f}, {dy:.2f}) px: "
            "frames A and B in reverse order there (a dropped frame, a pairing shifted by one "
            "frame)? Such a pair measures the flow backwards and passes every test within its "
            "field; a campaign leaves pairs that point the other way out"
        )
    elif direction.reversed:
        said["reversed"] = (
            f"{direction.note}; a campaign then leaves no pair out: check the pairing and the "
            "frames' order before the run"
        )
    return RecordingDrift(
        ids,
        dens,
        [tuple(x) for x in bgs],
        [tuple(x) for x in sigs],
        [tuple(x) for x in uvs],
        direction,
        said,
    )
