"""The per-pair work of a campaign: read the frames, correct, run the PIV of every run.

:func:`process_pair` is pure (no files written, no state kept beyond the context's cache of the
parsed mapping and window positions), so any executor (local, Dask) can run it anywhere. The
correction is :mod:`rspiv.correction` (Method I: :func:`~rspiv.correction.dewarp_pair` then the
multipass PIV; Method II: :func:`~rspiv.correction.method_two` with the uncorrected field as its
predictor), the PIV :mod:`rspiv.multipass`, with the context's one :class:`rspiv.PivSettings`.

Units: fields in px per pair; corrected runs in object px, the uncorrected run in image px.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign import pair_quality
from rspiv.campaign.ensemble_pixel import saturation_level
from rspiv.campaign.spec import STAGES, PairContext, PairResult, PairSpec
from rspiv.correction import dewarp_pair, method_two
from rspiv.errors import InvalidInputError, RspivError
from rspiv.io import read_image, turn_frame
from rspiv.multipass import run_grid
from rspiv.preprocess import condition_pair
from rspiv.recording_drift import pair_brightness

__all__ = [
    "FrameCache",
    "band_pair",
    "process_pair",
    "read_ahead",
    "read_checked_pair",
    "read_frame",
]


def read_frame(path: str, index: int | None, turn: int = 0) -> np.ndarray:
    """One 2D frame: a file, or frame ``index`` of a multi-frame TIFF (:func:`rspiv.io.read_image`;
    InvalidInputError naming the file when it is missing, unreadable or not 2D), turned by
    orientation ``turn`` (:func:`rspiv.io.turn_frame`)."""
    return turn_frame(read_image(path, 0 if index is None else int(index)), turn)


class FrameCache:
    """The frames read last, kept for the pairs still to come that share them.

    With sequential pairing (a time-resolved recording, ``[images] pairing = "sequential"``)
    frame k is frame B of pair k - frame_gap and frame A of pair k: kept here, each frame is read
    and decoded once. The cache holds at most ``frames`` frames and ``max_bytes`` of pixels,
    evicting the least recently used; its frames are read-only (the same array serves two
    pairs). Not thread-safe: one reader uses it.

    Build it with :meth:`for_pairs`, which sizes it from the pairs' own reuse distance.
    """

    def __init__(self, frames: int, max_bytes: int = 512 << 20) -> None:
        self.frames = max(int(frames), 1)
        self.max_bytes = int(max_bytes)
        self._held: collections.OrderedDict[tuple[str, int, int], np.ndarray] = (
            collections.OrderedDict()
        )
        self.hits = 0
        self.reads = 0

    @classmethod
    def for_pairs(cls, pairs: Sequence[PairSpec], limit: int = 8) -> FrameCache | None:
        """A cache large enough for ``pairs`` processed in order: one frame more than the
        longest run of pairs between two uses of a frame (at most ``limit``); None when no
        frame is used twice (pairs 1-2, 3-4, ...: nothing to keep)."""
        last: dict[tuple[str, int], int] = {}
        gap = 0
        for k, p in enumerate(pairs):
            for key in (_frame_key(p.a, p.frame_a), _frame_key(p.b, p.frame_b)):
                if key in last and k > last[key]:
                    gap = max(gap, k - last[key])
                last[key] = k
        return cls(min(gap + 1, limit)) if gap else None

    def read(self, path: str, index: int | None, turn: int = 0) -> np.ndarray:
        """Frame ``index`` of ``path`` (:func:`read_frame`), from the cache when held."""
        key = (*_frame_key(path, index), turn)
        f = self._held.get(key)
        if f is not None:
            self._held.move_to_end(key)
            self.hits += 1
            return f
        f = read_frame(path, index, turn)
        self.reads += 1
        f.flags.writeable = False
        self._held[key] = f
        while len(self._held) > self.frames or (
            len(self._held) > 1 and sum(a.nbytes for a in self._held.values()) > self.max_bytes
        ):
            self._held.popitem(last=False)
        return f


def _frame_key(path: str, index: int | None) -> tuple[str, int]:
    """A frame's key in :class:`FrameCache`: its file and its page (0 for a single image)."""
    return (path, 0 if index is None else int(index))


def read_checked_pair(
    pair: PairSpec, shape: tuple[int, int], cache: FrameCache | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Frames A and B of ``pair``, each checked to be of the campaign's ``shape = (h, w)``;
    through ``cache`` (:class:`FrameCache`) when given.

    Raises
    ------
    InvalidInputError
        One line naming the file: a frame missing, unreadable (truncated, foreign) or not 2D,
        or of another size than ``shape`` (e.g. a page of a stack written at another size).
    """
    read = read_frame if cache is None else cache.read
    a = read(pair.a, pair.frame_a, pair.turn)
    b = read(pair.b, pair.frame_b, pair.turn)
    for name, f in (("frame A", a), ("frame B", b)):
        if f.shape != tuple(shape):
            raise InvalidInputError(
                f"{name} ({pair.describe()}) is {f.shape[1]} x {f.shape[0]} px, the campaign's "
                f"images are {shape[1]} x {shape[0]} px"
            )
    return a, b


def _window_positions(context: PairContext, corrected: bool) -> np.ndarray:
    """Raw-image positions (px) of the final windows, shape (ny, nx, 2): the grid itself for
    the uncorrected run, ``F(grid)`` for the corrected ones (cached per process)."""
    key = "image_xy" if corrected else "grid_xy"
    xy = context._cache.get(key)
    if xy is None:
        gx, gy = context.grid()
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        if corrected and context.mapping is not None:
            pts = context.mapping.forward(pts)
        xy = pts.reshape(gx.shape + (2,))
        context._cache[key] = xy
    return xy


def _field_arrays(
    f, context: PairContext, corrected: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(u, v, valid, sigma_u, sigma_v) of a field (the sigmas None when the PIV estimated
    none). Besides the PIV's own validation, a vector counts only if its
    two windows (the final window displaced by -d/2 and +d/2, d bounded by the field's 99th
    percentile displacement) lie inside the recorded image: windows reaching past the sensor or
    into the zero fill of a dewarped frame are no measurement."""
    u = np.asarray(f.u, np.float64)
    v = np.asarray(f.v, np.float64)
    valid = np.asarray(f.valid, bool) & ~np.asarray(f.masked, bool)
    valid &= np.isfinite(u) & np.isfinite(v)
    if valid.any():
        du = float(np.percentile(np.abs(u[valid]), 99))
        dv = float(np.percentile(np.abs(v[valid]), 99))
        w, h = context.piv.final_window
        xy = _window_positions(context, corrected)
        height, width = context.image_shape
        mx = 0.5 * w + 0.5 * du
        my = 0.5 * h + 0.5 * dv
        valid &= (xy[..., 0] - mx >= -0.5) & (xy[..., 0] + mx <= width - 0.5)
        valid &= (xy[..., 1] - my >= -0.5) & (xy[..., 1] + my <= height - 0.5)
    su, sv = getattr(f, "sigma_u", None), getattr(f, "sigma_v", None)
    if su is None or sv is None or not np.isfinite(su).any():
        return u, v, valid, None, None
    return u, v, valid, np.asarray(su, np.float64), np.asarray(sv, np.float64)


def read_ahead(
    pair: PairSpec, shape: tuple[int, int], cache: FrameCache | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """Frames A and B of ``pair`` (:func:`read_checked_pair`, through ``cache`` when given), or
    the one-line reason they cannot be used: what :func:`process_pair` takes as ``frames`` when
    the reading was done ahead, e.g. in a thread while the previous pair's PIV runs."""
    try:
        return read_checked_pair(pair, shape, cache)
    except (RspivError, ValueError, OSError) as exc:
        return str(exc)


def process_pair(
    context: PairContext,
    pair: PairSpec,
    frames: tuple[np.ndarray, np.ndarray] | str | None = None,
    ensembles: dict[str, Any] | None = None,
) -> PairResult:
    """Process one pair for every run of ``context`` (pure: no files written, no state kept
    beyond the context's cache of the parsed mapping).

    ``ensembles``: run name -> the run's band accumulators ``(windows, single-pixel)``
    (:func:`rspiv.campaign.ensemble.band_accumulators`; either may be None), added to in place
    once every run's PIV succeeded (the only state this function touches;
    ``timings["ensemble"]``).

    ``frames``: the pair's frames already read (:func:`read_ahead`: the arrays or the reason
    they cannot be used); None reads them here (``timings["read"]`` is then the read itself,
    else the caller's wait, see :class:`rspiv.campaign.executors.local.LocalExecutor`).

    Bad data (missing or unreadable frame, frames of different sizes or not of the campaign's
    size, frames that do not correlate: :meth:`rspiv.PivField.uncorrelated`) gives
    ``PairResult(ok=False, reason=...)``; frames that correlate only in part are processed
    and carry :meth:`rspiv.PivField.warning` in ``PairResult.warning``; programming errors
    propagate.
    """
    t = {k: 0.0 for k in STAGES if k != "statistics"}
    t0 = time.perf_counter()
    if frames is None:
        frames = read_ahead(pair, context.image_shape)
        t["read"] = time.perf_counter() - t0
    if isinstance(frames, str):
        return PairResult(pair.pair_id, False, frames, timings=t)
    ens_pre = context.ensemble_preprocess() if ensembles else None
    t0 = time.perf_counter()
    try:
        a, b = context.condition(*frames)
        # the frames the ensemble bands correlate (without the high-pass when it is on)
        ens_a, ens_b = (
            (a, b)
            if ens_pre is None
            else condition_pair(*frames, ens_pre, context.backgrounds())
        )
    except (RspivError, ValueError) as exc:
        return PairResult(pair.pair_id, False, f"{pair.describe()}: {exc}", timings=t)
    t["condition"] = time.perf_counter() - t0
    mask = context.mask()
    settings = context.piv
    fields: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    piv_fields: dict[str, Any] = {}
    ens_frames: dict[str, tuple[Any, Any, Any]] = {}
    ensembles = ensembles or {}
    raw = None
    try:
        # The uncorrected field first: it also serves as Method II's predictor.
        for run in sorted(context.runs, key=lambda r: r.method != "none"):
            t0 = time.perf_counter()
            if run.method == "none":
                raw = run_grid(a, b, settings, mask)
                t["piv"] += time.perf_counter() - t0
                piv_fields[run.name] = raw
                fields[run.name] = _field_arrays(raw, context, False)
                ens_frames[run.name] = (ens_a, ens_b, mask)
            elif run.method == "I":
                # Method I
                da, db, dmask = _dewarp(context, a, b, mask)
                t["dewarp"] += time.perf_counter() - t0
                t0 = time.perf_counter()
                f = run_grid(da, db, settings, dmask)
                t["piv"] += time.perf_counter() - t0
                piv_fields[run.name] = f
                fields[run.name] = _field_arrays(f, context, True)
                if ensembles.get(run.name) is not None and ens_pre is not None:
                    t0 = time.perf_counter()
                    da, db, dmask = _dewarp(context, ens_a, ens_b, mask)
                    t["dewarp"] += time.perf_counter() - t0
                ens_frames[run.name] = (da, db, dmask)
            elif run.method == "II":
                f = method_two(
                    a, b, context.mapping, settings, mapping=run.mapping,
                    object_shape=context.object_shape, predictor=raw, mask=mask,
                )  # fmt: skip
                t["piv"] += time.perf_counter() - t0
                piv_fields[run.name] = f
                fields[run.name] = _field_arrays(f, context, True)
                ens_frames[run.name] = (ens_a, ens_b, mask)
            else:
                raise InvalidInputError(f"run {run.name}: unknown method {run.method!r}")
    except InvalidInputError as exc:  # e.g. frames with NaN: bad data, not a bug
        return PairResult(pair.pair_id, False, f"{pair.describe()}: {exc}", timings=t)
    # frames that do not correlate (a missing laser pulse, a wrong pairing) give random vectors
    # that pass the median test: no measurement, the pair is left out; frames that correlate
    # in part only (a region unlit or too sparsely seeded) stay in, with the warning, for the
    # run to report (every run has the same frames: the first run's field tells)
    warning = ""
    t0 = time.perf_counter()
    for name, first in list(piv_fields.items())[:1]:
        uncorrelated, said = first.correlation()
        t["piv"] += time.perf_counter() - t0
        if uncorrelated:
            reason = f"{pair.describe()}: {name}: {said}"
            return PairResult(pair.pair_id, False, reason, timings=t)
        if said:
            warning = f"{name}: {said}"
    # each run's figures for the run's series (with the frames' seeding and brightness as
    # recorded); a pair whose displacement points the other way from the run's (frames in
    # reverse order) is left out, as the first run's field tells
    t0 = time.perf_counter()
    roi = settings.roi
    seen = pair_brightness(*frames, mask, None if roi is None else (roi[1], roi[3]))
    quality = {
        name: {**pair_quality.measure(f, fields[name]), **seen} for name, f in piv_fields.items()
    }
    name = next(iter(piv_fields))
    run0 = next(r for r in context.runs if r.name == name)
    backwards = pair_quality.reversed_reason(
        quality[name], pair_quality.run_direction(context, run0)
    )
    t["piv"] += time.perf_counter() - t0
    if backwards:
        reason = f"{pair.describe()}: {name}: {backwards}"
        return PairResult(pair.pair_id, False, reason, timings=t, quality=quality)
    # the ensemble bands last: a pair is either in every statistic or in none
    t0 = time.perf_counter()
    if ensembles:
        _add_to_bands(context, ensembles, ens_frames, frames)
    t["ensemble"] = time.perf_counter() - t0
    return PairResult(pair.pair_id, True, "", fields, t, warning, quality)


def _dewarp(context: PairContext, a: np.ndarray, b: np.ndarray, mask: Any) -> tuple[Any, ...]:
    """Method I's frames A and B and mask in the object frame; the zero fill stays unmasked
    (:func:`_field_arrays` keeps only the vectors whose windows lie inside the recorded
    image)."""
    return dewarp_pair(
        a, b, context.mapping, object_shape=context.object_shape, mask=mask, zero_fill="keep"
    )


def _add_to_bands(
    context: PairContext,
    ensembles: dict[str, Any],
    ens_frames: dict[str, tuple[Any, Any, Any]],
    frames: tuple[np.ndarray, np.ndarray],
) -> None:
    """Add a pair to every run's ensemble band: ``ens_frames`` run name -> the frames and mask
    the band correlates; ``frames`` the pair as recorded (the bands count its saturated
    pixels)."""
    raw = (*frames, [saturation_level(f) for f in frames])
    for run in context.runs:
        band = ensembles.get(run.name)
        if band is not None:
            fa, fb, fm = ens_frames[run.name]
            ensemble_work.accumulate(context, run, band, fa, fb, fm, raw=raw)


def band_pair(
    context: PairContext, frames: tuple[np.ndarray, np.ndarray], ensembles: dict[str, Any]
) -> None:
    """Add a pair already in the statistics to the runs' ensemble bands only, without its PIV
    (:mod:`rspiv.campaign.rereduce`): the frames conditioned and (Method I) dewarped as
    :func:`process_pair` does for the bands.

    ``ensembles``: run name -> ``(windows, single-pixel)`` band accumulators
    (:func:`rspiv.campaign.ensemble.band_accumulators`), added to in place.
    """
    pre = context.ensemble_preprocess()
    if pre is None:
        a, b = context.condition(*frames)
    else:
        a, b = condition_pair(*frames, pre, context.backgrounds())
    mask = context.mask()
    ens_frames = {
        run.name: _dewarp(context, a, b, mask) if run.method == "I" else (a, b, mask)
        for run in context.runs
        if ensembles.get(run.name) is not None
    }
    _add_to_bands(context, ensembles, ens_frames, frames)
