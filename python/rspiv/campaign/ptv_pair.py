"""One pair's tracks at the wall for ``rspiv ptv`` (:mod:`rspiv.campaign.ptv`): the pair's
field file as the predictor (:func:`pair_field`), and its frames conditioned as the ensemble
bands see them, dewarped for Method I, searched for particle images in the rows near the wall
and tracked (:func:`pair_tracks`; Method II in the raw frames through the mapped predictor,
each track's centres mapped to the object frame). The module docstring of
:mod:`rspiv.campaign.ptv` gives the frames per run and the rows searched.

Units: px of the run's frame (object px for the corrected runs), displacements in px per pair.
"""

from __future__ import annotations

import dataclasses
import pathlib
from types import SimpleNamespace
from typing import Any

import numpy as np

from rspiv.campaign.fields import frame_name, read_pair
from rspiv.campaign.spec import PairContext
from rspiv.correction import dewarp_pair
from rspiv.errors import InvalidInputError
from rspiv.preprocess import condition_pair
from rspiv.ptv import (
    Particles,
    Tracks,
    detect_particles,
    predictor_of,
    search_rows,
    track_particles,
)
from rspiv.recording import full_scale

__all__ = ["CONTEXT_PX", "pair_field", "pair_tracks"]

#: Rows of flow searched beyond the band (px of the run's frame; :mod:`rspiv.campaign.ptv`,
#: "Rows searched").
CONTEXT_PX = 256.0


def pair_field(
    path: pathlib.Path, pair: Any, shape: tuple[int, int], run: str, fp: str,
    window: tuple[int, int],
) -> SimpleNamespace:  # fmt: skip
    """A pair's field file as a predictor: its window centres, ``u``, ``v`` (replacements in),
    the final ``window`` (w, h). InvalidInputError when the file was written for other frames
    than ``pair``'s (the campaign's image list changed since)."""
    import h5py  # deferred: only the pass reads the coordinates

    u, v, _valid, _su, _sv = read_pair(path, shape, run, fp)
    try:
        with h5py.File(path, "r") as f:
            x, y = np.asarray(f["x"], np.float64), np.asarray(f["y"], np.float64)
            names = [_text(f.attrs.get(k)) for k in ("frame_a", "frame_b")]
    except (OSError, KeyError) as exc:
        raise InvalidInputError(f"{path}: no readable window centres ({exc})") from None
    want = [frame_name(pair.a, pair.frame_a), frame_name(pair.b, pair.frame_b)]
    if [pathlib.Path(n or "").name for n in names] != [pathlib.Path(n).name for n in want]:
        raise InvalidInputError(
            f"{path}: written for frames {names[0]}, {names[1]}, not the pair's {want[0]}, "
            f"{want[1]} (the campaign's images changed since it was processed)"
        )
    X, Y = np.meshgrid(x, y)
    return SimpleNamespace(x=X, y=Y, u=u, v=v, window=window)


def _text(v: Any) -> str | None:
    return v.decode() if isinstance(v, bytes) else (None if v is None else str(v))


def _frames(ctx: PairContext, frames: tuple[np.ndarray, np.ndarray], rows=None) -> tuple:
    """The pair conditioned as the ensemble bands see it (module docstring); with ``rows``,
    those rows of it. A conditioning of pixels and their neighbours only (hot pixels, the
    background) runs on those rows and two more each side: the same values as the whole
    frames' rows; one that looks further or over the frame (the cap, the min-max
    normalisation) runs on the whole frames."""
    pre = ctx.ensemble_preprocess() or ctx.preprocess
    a, b = frames
    if rows is None:
        return (a, b) if not pre.enabled else condition_pair(a, b, pre, ctx.backgrounds())
    r0, r1 = rows
    if not pre.enabled:
        return a[r0:r1], b[r0:r1]
    bg = ctx.backgrounds()
    if pre.cap or pre.min_max or pre.high_pass or pre.smooth:
        ca, cb = condition_pair(a, b, pre, bg)
        return ca[r0:r1], cb[r0:r1]
    lo, hi = max(r0 - 2, 0), min(r1 + 2, a.shape[0])
    ca, cb = condition_pair(
        a[lo:hi], b[lo:hi], pre, None if bg is None else (bg[0][lo:hi], bg[1][lo:hi])
    )
    return ca[r0 - lo : r1 - lo], cb[r0 - lo : r1 - lo]


def _method_two(ctx: PairContext, pa, pb, field, wall, radius: float) -> Tracks:
    """Method II: tracks in the raw frames through the mapped predictor, their centres mapped
    to the object frame (module docstring)."""
    m = ctx.mapping
    obj = predictor_of(field, wall)

    def raw(px: np.ndarray, py: np.ndarray):
        X = m.inverse(np.column_stack([px, py]), on_fail="nan")
        D = np.column_stack(obj(X[:, 0], X[:, 1]))
        d = m.forward(X + 0.5 * D) - m.forward(X - 0.5 * D)
        return d[:, 0], d[:, 1]

    # the wall in the raw frames (a cubic through it mapped), so that the stray estimate
    # counts the particle images without a partner in the flow only, as for the other runs
    xo = np.linspace(0.0, ctx.object_shape[1] - 1.0, 65)
    wr = m.forward(np.column_stack([xo, wall.line(xo)]))
    coef = np.polyfit(wr[:, 0], wr[:, 1], 3)
    raw_wall = SimpleNamespace(line=lambda x: np.polyval(coef, x), flow_side=wall.flow_side)
    t = track_particles(pa, pb, raw, radius=radius, wall=raw_wall)
    pa = np.column_stack([t.x - 0.5 * t.u, t.y - 0.5 * t.v])
    pb = np.column_stack([t.x + 0.5 * t.u, t.y + 0.5 * t.v])
    oa, ob = m.inverse(pa, on_fail="nan"), m.inverse(pb, on_fail="nan")
    mid, d = 0.5 * (oa + ob), ob - oa
    return dataclasses.replace(t, x=mid[:, 0], y=mid[:, 1], u=d[:, 0], v=d[:, 1])


def _rows(ctx: PairContext, run: Any, shape, field, wall, radius: float, band_px: float):
    """The rows of the run's frames searched for particle images (module docstring, "Rows
    searched"): :func:`rspiv.ptv.search_rows` with a margin of the radius, the field's largest
    wall-normal displacement (a quarter more for Method II's raw frames) and 8 px."""
    v = np.abs(np.asarray(field.v, dtype=np.float64))
    vmax = float(np.max(v[np.isfinite(v)])) if np.isfinite(v).any() else 0.0
    margin = radius + 1.25 * vmax + 8.0
    to = ctx.mapping.forward if run.method == "II" else None
    return search_rows(wall, shape, band_px, margin, CONTEXT_PX, to_frame=to)


def pair_tracks(
    ctx: PairContext, run: Any, frames, field, wall, radius: float, band_px: float | None
) -> Tracks:
    """One pair's tracks: the particle images of the rows searched (all with ``band_px``
    None) in each frame, in the frame's px, tracked through the pair's field."""
    mask = ctx.mask()
    shape = tuple(ctx.object_shape) if run.method == "I" else tuple(frames[0].shape)
    rows = (0, shape[0])
    if band_px is not None:
        rows = _rows(ctx, run, shape, field, wall, radius, band_px)
    if run.method == "I":
        a, b = _frames(ctx, frames)
        a, b, mask = dewarp_pair(
            a, b, ctx.mapping, object_shape=ctx.object_shape, mask=mask, zero_fill="keep"
        )
        a, b = a[rows[0] : rows[1]], b[rows[0] : rows[1]]
    else:
        a, b = _frames(ctx, frames, rows)
    m = None if mask is None else mask[rows[0] : rows[1]]
    # the sensor's full scale from the whole raw frame (none for conditioned frames)
    full = [full_scale(f) if a.dtype.kind == "u" else None for f in frames]
    pa, pb = (
        _shifted(detect_particles(f, mask=m, full=fs), rows[0])
        for f, fs in zip((a, b), full, strict=True)
    )
    if run.method == "II":
        return _method_two(ctx, pa, pb, field, wall, radius)
    return track_particles(pa, pb, field, radius=radius, wall=wall)


def _shifted(p: Particles, r0: int) -> Particles:
    """Particle images found in rows from ``r0`` on, in the whole frame's px."""
    return p if not r0 else dataclasses.replace(p, y=p.y + r0)
