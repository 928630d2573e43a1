"""The campaign's single-pixel ensemble in rows at the wall (``[ensemble] single_pixel``, issue 13).

Next to the ensemble windows of :mod:`rspiv.campaign.ensemble`, every pair is also added to a
:class:`rspiv.ensemble.PixelAccumulator`: rows ``pixel_step`` px apart from ``pixel_step`` to
``pixel_band`` from the wall, each row cut into ``pixel_segment`` px segments along it, one pixel
row of frame A against the rows of frame B around it. The pixels beyond the wall (its
reflection) are masked first. The plan is the window band's: the pilot's wall and mean profile
(continued linearly to 0 at the wall) are the predictor, frozen into ``PairContext.ensemble``
(``spec["pixel"]``), so into the fingerprint and the checkpoints.

Frames per run
    ``none``: the raw frames, the rows along the wall found in the raw field. Method I: the
    dewarped frames, rows in object px. Method II: the raw frames; each object-plane row (a line
    at a fixed distance from the object wall) is mapped to the raw image segment by segment
    (one raw y per segment, at the segment's centre column), the predictor mapped as
    ``F(X + D/2) - F(X - D/2)``, the wall masked along its mapped line; the result goes back to
    the object plane through the mapping's Jacobian averaged over the row (``J^-1 d``,
    ``J^-1 C J^-T``). A row bent by the distortion across a segment blurs it by the bend
    (``spec["pixel"]["bend_px"]``, reported in the profile's metadata).

Result (:func:`pixel_profile`)
    Per row: the mean displacement (the Gaussian fit's bias removed) and the stresses (px per
    pair, pixel axes of the run's frame), the distance from the wall the final analysis found at
    which the row measures (``dist_px``: the row's own distance ``dist_row_px`` moved by the mean
    offset of the particles it sees; next to the wall they lie farther out, see
    :mod:`rspiv.ensemble_pixel_model`), the segments summed and ``near_wall``: the rows within
    two particle-image widths of the wall, whose effective distance differs from their own and
    whose fit bias is the nearest modelled row's. Units as the window profile (SI, wall units)
    when the analysis has them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.campaign.spec import PairContext, RunSpec
from rspiv.ensemble_pixel import PixelAccumulator, pixel_band, segment_centres
from rspiv.errors import InvalidInputError

#: Largest mean fraction of a row's pixels saturated in the raw frames before the row is
#: flagged ``clipped``: a particle image clipped by a glare line is flattened on the glare's
#: side, and the row then weights the particles away from the wall (read high: +6 to +85 % on
#: the synthetic layer under a saturating glare line, 5-99 % of their pixels saturated; 0.01-
#: 0.05 % without the glare).
SATURATED_MAX = 0.01

__all__ = [
    "SATURATED_MAX",
    "Line",
    "new_pixel_accumulator",
    "pixel_layout",
    "pixel_profile",
    "pixel_spec",
    "raw_pixels",
    "saturation",
    "saturation_level",
    "to_object",
]


def pixel_spec(cfg: Any, band_px: float) -> dict[str, Any]:
    """The plain-data plan of the single-pixel rows (``spec["pixel"]`` of a run's band)."""
    ec = cfg.ensemble
    return {
        "band_px": float(band_px),
        "step": float(ec.pixel_step),
        "segment": int(ec.pixel_segment),
        "lags": [int(t) for t in ec.pixel_lags],
    }


class Line:
    """A straight wall line ``y = intercept + slope x`` (px) with ``line(x)``."""

    def __init__(self, intercept: float, slope: float) -> None:
        self.intercept_px, self.slope = intercept, slope

    def line(self, x):
        return self.intercept_px + self.slope * np.asarray(x, dtype=np.float64)


def _profile_fn(spec: dict[str, Any]):
    """The pilot's profile as functions of the wall distance, 0 at the wall (no slip)."""
    d = np.r_[0.0, np.asarray(spec["dist"], dtype=np.float64)]
    u = np.r_[0.0, np.asarray(spec["u"], dtype=np.float64)]
    v = np.r_[0.0, np.asarray(spec["v"], dtype=np.float64)]
    return lambda t: np.interp(t, d, u), lambda t: np.interp(t, d, v)


def pixel_layout(ctx: PairContext, run: RunSpec, spec: dict[str, Any] | None = None) -> dict:
    """The rows of ``run``'s single-pixel band (cached per process).

    Returns a dict: ``y`` (rows, segments: each segment's row y in the frames the run
    correlates), ``x0``, ``seg``, ``du``, ``dv`` (the predictor per segment, px of those frames),
    ``X``, ``Y`` (the segments' centres in the run's own frame), ``dist`` (each row's distance
    from the pilot's wall, px of the run's frame), ``wall`` (the wall line in the correlated
    frames: an object with ``line(x)``), ``side``, ``lags``, ``auto_pairs``, ``bend_px`` (the
    largest change of a mapped row's y across one segment; 0 unless Method II).
    """
    key = f"pixel_layout:{run.name}"
    if spec is None:
        if key in ctx._cache:
            return ctx._cache[key]
        if not ctx.ensemble or "pixel" not in ctx.ensemble.get(run.name, {}):
            raise InvalidInputError(f"{run.label}: the context has no single-pixel band")
        spec = ctx.ensemble[run.name]
    p = spec["pixel"]
    wall = Line(*spec["wall"])
    side = spec["flow_side"]
    sign = 1.0 if side == "above" else -1.0
    lags = (int(p["lags"][0]), int(p["lags"][1]))
    seg = int(p["segment"])
    dist = np.arange(p["step"], p["band_px"] + 1e-9, p["step"])
    fu, fv = _profile_fn(spec)
    where = f"{run.label}: [ensemble] single_pixel"
    if dist.size < 1:
        raise InvalidInputError(f"{where}: pixel_band {p['band_px']:g} px holds no row")
    umax = float(np.max(np.abs(fu(dist))))
    margin = lags[0] + int(np.ceil(umax / 2)) + 4
    bend = 0.0
    if run.method != "II":
        shape = tuple(ctx.object_shape if run.method == "I" else ctx.image_shape)
        try:
            y, x0, d = pixel_band(shape, seg, dist, wall, side, lags, margin_x=margin)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{where}: {exc}") from None
        xc = segment_centres(x0, seg, y.shape[1])
        X = np.broadcast_to(xc[None, :], y.shape).copy()
        du = np.broadcast_to(fu(d)[:, None], y.shape).copy()
        dv = np.broadcast_to(fv(d)[:, None], y.shape).copy()
        Y, line = y, wall
    else:
        y, x0, X, Y, du, dv, line, bend = _mapped_rows(ctx, wall, sign, dist, fu, fv, seg, margin)
        h = ctx.image_shape[0]
        if np.min(y) < lags[1] + 3 or np.max(y) > h - 1 - lags[1] - 3:
            raise InvalidInputError(
                f"{where}: rows {dist[0]:g}..{dist[-1]:g} px from the wall, mapped to the raw "
                f"image, leave its {ctx.image_shape[1]} x {h} px"
            )
    # the rows' pixels (every 2nd px of each segment), for their saturation in the raw frames
    sx = x0 + np.arange(y.shape[1])[:, None] * seg + np.arange(0, seg, 2)[None, :]
    px = np.broadcast_to(sx.ravel()[None, :], (y.shape[0], sx.size))
    py = np.repeat(y, sx.shape[1], axis=1)
    out = {
        "raw_pixels": raw_pixels(ctx, run, px, py),
        "y": np.ascontiguousarray(y),
        "x0": float(x0),
        "seg": seg,
        "du": du,
        "dv": dv,
        "X": X,
        "Y": Y,
        "dist": dist,
        "wall": line,
        "side": side,
        "lags": lags,
        "auto_pairs": int(spec["auto_pairs"]),
        "bend_px": float(bend),
    }
    ctx._cache[key] = out
    return out


class _MappedLine:
    """The object wall mapped to the raw image, as a line of raw x (tabulated)."""

    def __init__(self, xr: np.ndarray, yr: np.ndarray) -> None:
        order = np.argsort(xr)
        self.xr, self.yr = xr[order], yr[order]

    def line(self, x):
        return np.interp(np.asarray(x, dtype=np.float64), self.xr, self.yr)


def _mapped_rows(ctx, wall, sign, dist, fu, fv, seg, margin):
    """Method II: the object rows at ``dist`` from the wall, mapped to the raw image at the
    raw segments' centre columns (see the module docstring)."""
    m = ctx.mapping
    h, w = ctx.image_shape
    x0 = float(margin)
    nseg = int((w - 2 * x0) // seg)
    if nseg < 1:
        raise InvalidInputError(
            f"[ensemble] single_pixel: no {seg} px segment fits the {w} px wide image"
        )
    xc = segment_centres(x0, seg, nseg)
    ow = ctx.object_shape[1]
    xo = np.linspace(-0.1 * ow, 1.1 * ow, max(int(1.2 * ow / 4), 64))

    def raw_row(d):
        obj = np.column_stack([xo, wall.line(xo) - sign * d])
        r = m.forward(obj)
        return r[:, 0], r[:, 1]

    wx, wy = raw_row(0.0)
    rows = dist.size
    y = np.empty((rows, nseg))
    X = np.empty((rows, nseg))
    bend = 0.0
    for k, d in enumerate(dist):
        rx, ry = raw_row(d)
        order = np.argsort(rx)
        rx, ry, ox = rx[order], ry[order], xo[order]
        y[k] = np.interp(xc, rx, ry)
        X[k] = np.interp(xc, rx, ox)
        ends = np.interp(np.c_[xc - seg / 2, xc + seg / 2], rx, ry)
        bend = max(bend, float(np.max(np.abs(ends[:, 1] - ends[:, 0]))))
    Y = wall.line(X) - sign * dist[:, None]
    D = np.stack([fu(dist), fv(dist)], axis=-1)[:, None, :]
    P = np.stack([X, Y], axis=-1)
    flat = (rows * nseg, 2)
    raw = m.forward((P + 0.5 * D).reshape(flat)) - m.forward((P - 0.5 * D).reshape(flat))
    du = raw[:, 0].reshape(rows, nseg)
    dv = raw[:, 1].reshape(rows, nseg)
    return y, x0, X, Y, du, dv, _MappedLine(wx, wy), bend


def raw_pixels(ctx: PairContext, run: RunSpec, px: np.ndarray, py: np.ndarray) -> tuple:
    """Points ``(px, py)`` (shape (n, m): m points of each of n rows or windows) of the frames
    ``run`` correlates, as the nearest pixels ``(rows, cols)`` of the raw frames (through the
    mapping for Method I's dewarped frames)."""
    if run.method == "I":
        raw = ctx.mapping.forward(np.column_stack([np.ravel(px), np.ravel(py)]))
        px, py = raw[:, 0].reshape(np.shape(py)), raw[:, 1].reshape(np.shape(py))
    h, w = ctx.image_shape
    return (
        np.clip(np.rint(py), 0, h - 1).astype(np.intp),
        np.clip(np.rint(px), 0, w - 1).astype(np.intp),
    )


def saturation_level(frame: np.ndarray) -> float:
    """The code at which ``frame`` saturates: its maximum when at least 50 pixels (and 1 in
    100,000) share it (a plateau: clipped particle images or glare), else inf (no pixel is
    taken as saturated; one or a few brightest pixels are particle peaks)."""
    top = frame.max()
    n = int(np.count_nonzero(frame == top))
    return float(top) if n >= max(50, frame.size // 100_000) else float("inf")


def saturation(lay: dict, raw: tuple) -> np.ndarray:
    """Per row (or window) of a band: the fraction of its pixels (``lay["raw_pixels"]``)
    saturated in either raw frame; ``raw``: ``(frame_a, frame_b, levels)``, the levels from
    :func:`saturation_level`."""
    ri, ci = lay["raw_pixels"]
    levels = raw[2]
    sat = (raw[0][ri, ci] >= levels[0]) | (raw[1][ri, ci] >= levels[1])
    return sat.mean(axis=1)


def new_pixel_accumulator(ctx: PairContext, run: RunSpec) -> PixelAccumulator:
    """An empty single-pixel accumulator of ``run``'s rows, the wall masked."""
    lay = pixel_layout(ctx, run)
    return PixelAccumulator(
        lay["y"],
        lay["seg"],
        lay["x0"],
        (lay["du"], lay["dv"]),
        lags=lay["lags"],
        # the rows next to the wall are modelled for the B-spline interpolants only (Keys'
        # sub-pixel shift bias is not: rspiv.ensemble_pixel_model): Keys PIV gets quintic rows
        interpolation="bspline" if ctx.piv.interpolation == "keys" else ctx.piv.interpolation,
        wall=(lay["wall"], lay["side"]),
    )


def to_object(ctx: PairContext, lay: dict, u, v, uu, vv, uv) -> tuple:
    """Method II, per row of a band (windows or single-pixel rows): displacements ``J^-1 d``
    and covariances ``J^-1 C J^-T`` in object px, with ``J`` the mapping's Jacobian averaged
    over the row's positions ``lay["X"], lay["Y"]`` (object px, shape (rows, columns))."""
    X = np.column_stack([lay["X"].ravel(), lay["Y"].ravel()])
    J = ctx.mapping.forward_jacobian(X).reshape(lay["X"].shape + (2, 2)).mean(axis=1)
    Ji = np.linalg.inv(J)  # (rows, 2, 2)
    d = np.stack([u, v], axis=-1)
    do = np.einsum("nij,nj->ni", Ji, d)
    C = np.empty((u.size, 2, 2))
    C[:, 0, 0], C[:, 1, 1] = uu, vv
    C[:, 0, 1] = C[:, 1, 0] = uv
    Co = np.einsum("nij,njk,nlk->nil", Ji, C, Ji)
    return do[:, 0], do[:, 1], Co[:, 0, 0], Co[:, 1, 1], Co[:, 0, 1]


def pixel_profile(ctx: PairContext, run: RunSpec, acc: PixelAccumulator, an: Any) -> dict:
    """The single-pixel profile of ``run`` (module docstring): ``dist_px`` (where the row
    measures), ``dist_row_px``, ``U``, ``V``,
    ``uu``, ``vv``, ``uv``, ``segments``, ``saturated`` (mean fraction of the row's pixels
    saturated in the raw frames), the flags ``near_wall``, ``corrected`` (the fit's bias
    removed) and ``clipped`` (more than
    :data:`SATURATED_MAX` saturated) per row, ``pairs``."""
    lay = pixel_layout(ctx, run)
    res = acc.result()
    u, v, uu, vv, uv = (res[k] for k in ("u", "v", "uu", "vv", "uv"))
    if run.method == "II":
        u, v, uu, vv, uv = to_object(ctx, lay, u, v, uu, vv, uv)
    X, Y = lay["X"], lay["Y"]
    if an is not None and an.wall is not None:
        sign = 1.0 if an.flow_side == "above" else -1.0
        dist = np.mean(sign * (an.wall.line(X) - Y), axis=1)
    else:
        dist = lay["dist"]
    # where the row measures (rspiv.ensemble_pixel_model): its offset from the row, in the
    # accumulator's px, to the run's frame (Method II: object px, by the mapping's local scale)
    shift = np.nan_to_num(res["dist_eff"] - res["dist"])
    if run.method == "II":
        pts = np.column_stack([X.ravel(), Y.ravel()])
        J = ctx.mapping.forward_jacobian(pts).reshape(X.shape + (2, 2)).mean(axis=1)
        shift = shift / np.sqrt(np.abs(np.linalg.det(J)))
    keep = res["ok"] & np.isfinite(u) & np.isfinite(v)
    return {
        "dist_px": (dist + shift)[keep],
        "dist_row_px": dist[keep],
        "U": u[keep],
        "V": v[keep],
        "uu": uu[keep],
        "vv": vv[keep],
        "uv": uv[keep],
        "segments": np.asarray(res["count"])[keep],
        "saturated": np.asarray(res["saturated"])[keep],
        "near_wall": np.asarray(res["near_wall"])[keep],
        "corrected": np.asarray(res["corrected"])[keep],
        "clipped": np.asarray(res["saturated"])[keep] > SATURATED_MAX,
        "pairs": int(acc.pairs),
        # rows left out: a summed peak under MIN_PEAK_RATIO times the plane's next local maximum
        "weak_rows": int(np.count_nonzero(res["weak"])),
    }
