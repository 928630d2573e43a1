"""Particle tracking assisted by PIV: each particle image followed from frame A to frame B.

A PIV vector is the mean displacement of the particle images in its window; at the wall, where
the velocity goes from zero to a good part of the free stream within one window, that mean is
not the velocity at the window's centre. Tracking the particle images one by one measures the
displacement where each particle is, and binning the tracks by their distance from the wall
(:mod:`rspiv.ptv_profile`) gives the mean profile and the Reynolds stresses in bins far finer
than a window, down to about a particle image's diameter from the wall (Keane, Adrian & Zhang
1995, "super-resolution" PIV; Kähler, Scharnowski & Cierpka 2012, Exp. Fluids 52:1641, for the
wall).

:func:`detect_particles` finds the particle images of a frame (``piv_core::ptv::detect``): the
local maxima above their block's background by ``max(4 sigma, 0.2 signal)``, exactly those the
recording check counts (:mod:`rspiv.recording`), each centre from a 3-point Gaussian along x
and y (a centroid where the profile is clipped or faint). :func:`track_particles` predicts where
each particle image of A lies in B from a predictor (a :class:`rspiv.PivField` of the same pair,
a uniform displacement or a function) and keeps the pairs that are unique both ways within
``radius`` (``piv_core::ptv::track``): one candidate in B, claimed by no other particle image
of A.

The predictor of a field is sampled at the midpoint of the predicted track (the field's
displacement belongs to the middle of the pulse pair, as :func:`rspiv.synth.particle_pair`
places its particles), its missing vectors filled from the nearest valid ones. Given a ``wall``
(:class:`rspiv.Wall`, or any object with ``line(x)`` and ``flow_side``), the field's rows
closer to the wall than half the final window (whose windows hold the wall or its reflection)
are not used: below the first row clear of it, the predictor is that row's displacement scaled
linearly to zero at the wall (no slip), which is exact in the viscous sublayer.

What a user must choose is ``radius``: it has to hold the fluctuation of each particle's
displacement about the predictor (the sub-window turbulence and the PIV's own error), and the
larger it is, the more pairs are dropped as ambiguous and the more lost partners are replaced by
a stray particle image. Every call states what it saw (:attr:`Tracks.warnings`): few pairs, a
seeding dense for the radius, residuals that crowd its edge (the radius clips the fluctuations).

Positions in px of the frames (pixel frame: x right, y down, origin at the top-left pixel's
centre); displacements in px per pair (B minus A); heights in the frames' counts above the
background.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.multipass import mask_array
from rspiv.recording import K_NOISE, REL_SIGNAL, full_scale

__all__ = [
    "CROWDED_EDGE",
    "DETECT_BLOCK",
    "MAX_DIAMETER",
    "WIDEST_KEPT",
    "STATUS",
    "Particles",
    "Tracks",
    "detect_particles",
    "predictor_of",
    "search_rows",
    "track_particles",
    "wall_sign",
]

#: Block size (px) of the background and noise under the particle images: smaller than the
#: recording check's 64 px, to follow a background that changes near a glaring wall.
DETECT_BLOCK = 32

#: The status codes of ``piv_core::ptv::track``, by name.
STATUS = {"matched": 0, "none": 1, "several": 2, "claimed": 3, "no_predictor": 4}

#: Share of the pairs whose residual from the predictor lies beyond 3/4 of the radius above
#: which the radius is said to clip the fluctuations. Residuals well inside the radius leave
#: only the stray pairs there (uniform over the disc: 44 % of them beyond 3/4 of the radius).
CROWDED_EDGE = 0.05

#: Pairs whose image is wider than this many times its frame's median diameter are dropped:
#: two particle images merged into one maximum. On the generator's particle images (2.5 px,
#: 0.02 per px^2, 5 % noise) the merged ones were 1 % of the pairs, their displacement 0.5-1.3
#: px wrong; 1.3 drops 83 % of them and 11 % of the sound pairs (whose widths scatter with the
#: noise), leaving 0.3 % wrong pairs against 1.5 % (``tests/test_ptv.py``).
MAX_DIAMETER = 1.3

#: ... or wider than this percentile of the frame's images' widest axes, whichever is larger:
#: real particle images vary in size (defocus, their place in the light sheet; OpenPIV's real
#: ``test1``: 1.85-3.75 px from the 10th to the 90th percentile), and a width within the
#: frame's own spread says nothing of a merger. There the shape test drops the widest tenth.
WIDEST_KEPT = 90.0

#: Fewer of A's particle images paired than this share: said.
MIN_MATCHED_SHARE = 0.25

#: More than this share of the pairs expected to be strays (:attr:`Tracks.stray_pairs`): said.
#: A stray's displacement is spread over the disc about the prediction: 2 % of them add about
#: ``0.02 r^2 / 4`` to each component's variance (0.02 px^2 at a radius of 2 px).
MAX_STRAY_PAIRS = 0.02


@dataclasses.dataclass(frozen=True)
class Particles:
    """The particle images of one frame (:func:`detect_particles`).

    Attributes
    ----------
    x, y : ndarray of float64
        Sub-pixel centres (px).
    height : ndarray of float32
        The peak pixel above its block's background (counts).
    diameter_x, diameter_y : ndarray of float32
        e^-2 diameter along x and y from the Gaussian fit (px; NaN where not measured: a
        neighbour not above the background, or saturated; ``piv_core::ptv::detect``).
    sigma_x, sigma_y : ndarray of float32
        Standard uncertainty of the centre along x and y, the block's noise carried through the
        3-point Gaussian (px; NaN where the centroid was used; ``piv_core::ptv::detect``).
    saturated : ndarray of bool
        The peak pixel is at the sensor's full scale (its centre from a clipped profile).
    """

    x: np.ndarray
    y: np.ndarray
    height: np.ndarray
    diameter_x: np.ndarray
    diameter_y: np.ndarray
    sigma_x: np.ndarray
    sigma_y: np.ndarray
    saturated: np.ndarray

    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def diameter(self) -> float:
        """The median e^-2 diameter over both axes where measured (px; NaN when none was)."""
        d = np.concatenate([self.diameter_x, self.diameter_y]).astype(np.float64)
        d = d[np.isfinite(d)]
        return float(np.median(d)) if d.size else float("nan")


@dataclasses.dataclass(frozen=True)
class Tracks:
    """Particle images followed from frame A to frame B (:func:`track_particles`).

    Attributes
    ----------
    x, y : ndarray
        The track's midpoint (px): where its displacement belongs.
    u, v : ndarray
        Displacement B - A (px per pair).
    du, dv : ndarray
        The predictor's displacement for the track (px per pair); ``u - du`` is the residual.
    sigma_u, sigma_v : ndarray
        The camera noise's share of the error of ``u`` and ``v`` (px; the two centres'
        first-order uncertainties, their variances added). It is not the whole error: on the
        generator's images (2.5 px, 0.02 per px^2, 5 % noise) the tracks' actual error was
        0.10 px rms whatever their ``sigma_u`` (the pixel-integrated images' shape and the
        neighbouring images' tails dominate), while ``sigma_u`` read 0.09-0.43 px from the
        brightest to the faintest images. Use it to rank tracks, not as their error.
    height_a, height_b : ndarray
        The particle image's height in A and in B (counts above the background).
    saturated : ndarray of bool
        Either image saturated.
    status : dict of str to int
        Of A's particle images: ``matched``, ``none`` (no candidate within the radius),
        ``several`` (two or more), ``claimed`` (its candidate was another's too),
        ``no_predictor`` (the predictor has no value there); and of the pairs, ``misshapen``:
        dropped because an image is wider than ``max_diameter`` times its frame's median
        diameter along a measured axis (two particle images merged into one maximum: their
        centre lies between them and moves with neither).
    detected : (int, int)
        Particle images found in A and in B.
    radius : float
        The search radius (px).
    diameter : float
        The particle images' median e^-2 diameter in A (px).
    stray_share : float
        The expected share of A's particle images whose partner is lost that are paired with a
        stray particle image within the radius instead (``1 - exp(-n pi r^2)``, ``n`` B's
        particle images per px^2 over the frame).
    stray_pairs : float
        The expected share of the pairs that are such strays: a lost partner leaves no
        candidate with the chance ``exp(-l)`` and one stray with ``l exp(-l)`` (``l = n pi
        r^2``, Poisson), so the strays number about ``l`` times the particle images left
        without a candidate (``status["none"]``; with a ``wall``, those in the flow), over the
        pairs matched. An upper bound on the strays (the shape test drops some); merged
        particle images that pass the shape test are wrong pairs too (on the generator's images
        0.5 % of the pairs 3 px or more from the wall against an estimate of 0.45 % strays).
    edge_share : float
        Share of the pairs whose residual lies beyond 3/4 of the radius.
    warnings : tuple of str
        What the tracking saw that weakens the tracks, one line each (module docstring).
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    sigma_u: np.ndarray
    sigma_v: np.ndarray
    height_a: np.ndarray
    height_b: np.ndarray
    saturated: np.ndarray
    status: dict[str, int]
    detected: tuple[int, int]
    radius: float
    diameter: float
    stray_share: float
    stray_pairs: float
    edge_share: float
    warnings: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.x.size)


def detect_particles(
    frame: np.ndarray,
    *,
    mask: Any = None,
    full: float | None = None,
    block: int = DETECT_BLOCK,
    k: float = K_NOISE,
    rel: float = REL_SIGNAL,
    rows: tuple[int, int] | None = None,
) -> Particles:
    """The particle images of ``frame`` with their sub-pixel centres.

    Parameters
    ----------
    frame : ndarray, 2D
        uint8, uint16, float32 or float64 (read in place, not copied).
    mask : array of bool, path or None
        True (or a mask file's excluded area) = not searched; a particle image whose 3 x 3
        neighbourhood touches the mask is not kept.
    full : float, optional
        The level at which a peak pixel counts as saturated; default the integer frame's full
        scale where it reaches it (:func:`rspiv.recording.full_scale`), else none.
    block : int
        Block size (px, >= 8) of the background and noise estimates.
    k, rel : float
        The threshold ``b + max(k sigma, rel signal)`` (``piv_core::seeding``).
    rows : (int, int), optional
        Search only rows ``first`` to ``stop - 1`` (a view of them, not a copy), as a frame of
        their own: the blocks start at ``first``, and the signal of the threshold is the
        median over those rows' blocks; the centres are still in the whole frame's px. A
        particle image on the first or last of those rows is not found (its neighbours are
        outside). Tracking at a wall needs only the rows near it (:func:`search_rows`).

    Returns
    -------
    Particles

    Raises
    ------
    InvalidInputError
        A frame that is not 2D or under 3 x 3 px, a mask of another shape, non-finite values,
        bad factors, rows outside the frame or fewer than 3 of them.
    """
    a = np.asarray(frame)
    if a.ndim != 2:
        raise InvalidInputError(f"frame must be 2D, got shape {a.shape}")
    m = mask_array(mask, a.shape)
    if full is None:
        full = full_scale(a)
    r0 = 0
    if rows is not None:
        r0, r1 = _rows(rows, a.shape[0])
        a = a[r0:r1]
        m = None if m is None else m[r0:r1]
    d = _rspiv.detect_particles(a, int(block), float(k), float(rel), full, m)
    if r0:
        d["y"] += r0
    return Particles(
        x=d["x"], y=d["y"], height=d["height"], diameter_x=d["diameter_x"],
        diameter_y=d["diameter_y"], sigma_x=d["sigma_x"], sigma_y=d["sigma_y"],
        saturated=d["saturated"],
    )  # fmt: skip


def _rows(rows: Any, height: int) -> tuple[int, int]:
    """``rows`` as ``(first, stop)`` within a frame of ``height`` rows, at least 3 of them."""
    try:
        r0, r1 = (int(r) for r in rows)
    except (TypeError, ValueError):
        raise InvalidInputError(f"rows must be (first, stop), got {rows!r}") from None
    if not (0 <= r0 and r1 <= height and r1 - r0 >= 3):
        raise InvalidInputError(
            f"rows ({r0}, {r1}): give first >= 0, stop <= the frame's {height} rows and at "
            "least 3 rows"
        )
    return r0, r1


def search_rows(
    wall: Any, shape: tuple[int, int], band_px: float, margin_px: float,
    context_px: float = 0.0, block: int = DETECT_BLOCK, to_frame: Callable | None = None,
) -> tuple[int, int]:  # fmt: skip
    """The rows a tracking at ``wall`` has to search, as ``rows`` of :func:`detect_particles`:
    from ``margin_px`` beyond the wall to ``band_px + margin_px + context_px`` into the flow
    (``wall.line(x)`` over the frame's width, ``flow_side`` as :func:`wall_sign`), widened to
    whole blocks of the detection. ``margin_px`` must hold a particle image's partner (the
    search radius and the largest displacement across the rows) and its neighbours; the
    ``context_px`` beyond the band make the frame's statistics (the threshold's signal, the
    shape test's diameters) those of the flow rather than of the wall's neighbourhood.
    ``to_frame``: the wall given in another frame (Method II: the object frame), this maps
    ``(n, 2)`` points of that frame to the frames' px (the mapping's ``forward``); the band's
    edges are mapped at 65 places across the width. InvalidInputError when the band lies
    outside the frame."""
    s = wall_sign(wall)
    h, w = int(shape[0]), int(shape[1])
    x = np.linspace(0.0, w - 1.0, 65)
    wy = np.asarray(wall.line(x), dtype=np.float64)
    far = band_px + margin_px + context_px
    lo = wy - far if s > 0 else wy - margin_px
    hi = wy + margin_px if s > 0 else wy + far
    if to_frame is not None:
        ends = np.asarray(to_frame(np.column_stack([np.r_[x, x], np.r_[lo, hi]])), np.float64)
        lo = hi = ends[:, 1]
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise InvalidInputError("the wall's line is not finite across the frame")
    r0 = max(0, int(np.floor(lo.min())))
    r1 = min(h, int(np.ceil(hi.max())) + 1)
    r0 = (r0 // block) * block
    r1 = min(h, -(-r1 // block) * block)
    if r1 - r0 < 3:
        raise InvalidInputError(
            f"the wall's band (rows {lo.min():.0f} to {hi.max():.0f}) lies outside the frame's "
            f"{h} rows"
        )
    return r0, r1


def wall_sign(wall: Any) -> float:
    """+1 for a flow above ``wall`` (at smaller y), -1 below it. InvalidInputError for an
    object without ``line(x)`` or whose ``flow_side`` is neither ``"above"`` nor ``"below"``
    (absent: above)."""
    if not callable(getattr(wall, "line", None)):
        raise InvalidInputError("wall must have line(x) (an rspiv.Wall)")
    side = getattr(wall, "flow_side", "above")
    if side not in ("above", "below"):
        raise InvalidInputError(f"wall.flow_side must be above or below, got {side!r}")
    return 1.0 if side == "above" else -1.0


def _filled(field: Any) -> tuple[np.ndarray, np.ndarray]:
    """``u``, ``v`` of a field with every missing vector taken from the nearest present one."""
    from scipy.ndimage import distance_transform_edt  # deferred: scipy loads on first use

    u, v = (np.asarray(c, dtype=np.float64) for c in (field.u, field.v))
    bad = ~(np.isfinite(u) & np.isfinite(v))
    if bad.all():
        raise InvalidInputError("the predictor field holds no finite vector")
    if bad.any():
        _, (iy, ix) = distance_transform_edt(bad, return_indices=True)
        u, v = u[iy, ix], v[iy, ix]
    return u, v


class _FieldPredictor:
    """A PIV field sampled at points (bilinear between nodes, the edge rows and columns
    continued outwards: the PIV's own predictor, in Rust), optionally continued linearly to
    zero at a wall (module docstring)."""

    def __init__(self, field: Any, wall: Any = None) -> None:
        x, y = np.asarray(field.x, dtype=np.float64), np.asarray(field.y, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 2:
            raise InvalidInputError("the predictor field must be a grid of at least 2 x 2 vectors")
        u, v = _filled(field)
        dx, dy = float(x[0, 1] - x[0, 0]), float(y[1, 0] - y[0, 0])
        if not (np.isfinite(dx) and np.isfinite(dy) and dx != 0 and dy != 0):
            raise InvalidInputError("the predictor field's grid is not regular")
        # the grid ascending along both axes, as the sampler takes it
        if dx < 0:
            x, u, v = x[:, ::-1], u[:, ::-1], v[:, ::-1]
        if dy < 0:
            y, u, v = y[::-1], u[::-1], v[::-1]
        self.node = (float(x[0, 0]), float(y[0, 0]), abs(dx), abs(dy))
        self.u, self.v = np.ascontiguousarray(u), np.ascontiguousarray(v)
        self.wall = wall
        if wall is not None:
            self.sign = wall_sign(wall)
            win = getattr(field, "window", None)
            self.half = 0.5 * float(win[1]) if win is not None else 0.0

    def _sample(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        qx, qy = (np.ascontiguousarray(p, dtype=np.float64) for p in (px, py))
        return _rspiv.field_at(self.node, self.u, self.v, qx, qy)

    def __call__(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.wall is None:
            return self._sample(px, py)
        s, wy = self.sign, np.asarray(self.wall.line(px), dtype=np.float64)
        h = s * (wy - py)
        # the first row clear of the wall by half a window, at each point's x (rows ascending)
        _, y0, _, dy = self.node
        t = (wy - s * self.half - y0) / dy
        row_y = y0 + (np.floor(t) if s > 0 else np.ceil(t)) * dy
        h1 = s * (wy - row_y)
        near = h < h1
        qy = np.where(near, row_y, py)
        u, v = self._sample(px, qy)
        f = np.where(near, np.clip(h / np.where(h1 > 0, h1, 1.0), 0.0, 1.0), 1.0)
        return u * f, v * f


def predictor_of(predictor: Any, wall: Any = None) -> Callable:
    """``predictor`` as a function ``(x, y) -> (u, v)`` of arrays (px): a field (anything with
    ``x``, ``y``, ``u``, ``v`` on a regular grid: :class:`rspiv.PivField`,
    :class:`rspiv.VectorFile`), a pair of floats, or a callable. ``wall`` applies to a field
    only (module docstring)."""
    if hasattr(predictor, "u") and hasattr(predictor, "x"):
        return _FieldPredictor(predictor, wall)
    if callable(predictor):
        return predictor
    if isinstance(predictor, tuple | list) and len(predictor) == 2:
        u, v = (float(c) for c in predictor)
        if not (np.isfinite(u) and np.isfinite(v)):
            raise InvalidInputError(f"the predicted displacement ({u}, {v}) is not finite")
        return lambda x, y: (np.full(np.shape(x), u), np.full(np.shape(x), v))
    raise InvalidInputError(
        "predictor must be a PIV field, a (u, v) pair of floats or a callable (x, y) -> (u, v)"
    )


def _predict(fn: Callable, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The displacement predicted for particle images at ``(x, y)`` in A: the predictor at the
    track's predicted midpoint (one fixed-point step from A's position)."""
    u0, v0 = (np.broadcast_to(np.asarray(c, dtype=np.float64), x.shape) for c in fn(x, y))
    u, v = (np.broadcast_to(np.asarray(c, dtype=np.float64), x.shape)
            for c in fn(x + 0.5 * u0, y + 0.5 * v0))  # fmt: skip
    return np.ascontiguousarray(u), np.ascontiguousarray(v)


def track_particles(
    frame_a: np.ndarray | Particles,
    frame_b: np.ndarray | Particles,
    predictor: Any,
    *,
    radius: float = 2.0,
    wall: Any = None,
    mask: Any = None,
    full: float | None = None,
    max_diameter: float | None = MAX_DIAMETER,
    rows: tuple[int, int] | None = None,
) -> Tracks:
    """Follow each particle image of frame A to frame B.

    Parameters
    ----------
    frame_a, frame_b : ndarray or Particles
        The pair (or their particle images from :func:`detect_particles`).
    predictor : PivField, (u, v) or callable
        The displacement expected at a point (px per pair): a PIV field of the same pair (the
        usual choice), a uniform displacement, or ``f(x, y) -> (u, v)`` on arrays.
    radius : float
        Search radius about each prediction (px; module docstring).
    wall : Wall, optional
        Continue a field's predictor linearly to zero at this wall.
    mask, full
        As :func:`detect_particles` (frames only).
    max_diameter : float or None
        Drop pairs whose image in A or B is wider (e^-2, along an axis where it was measured)
        than this many times its frame's median diameter (:data:`MAX_DIAMETER`) and than the
        :data:`WIDEST_KEPT` percentile of its frame's widths; saturated images are kept and
        flagged. None keeps every pair.
    rows : (int, int), optional
        Search only these rows of the frames (:func:`detect_particles`; frames only): the
        tracks, the counts and the stray estimate are then those of these rows (the frames'
        statistics too: a stray's chance from B's particle images per px^2 of these rows).

    Returns
    -------
    Tracks
        The pairs unique both ways, with what was seen (:attr:`Tracks.warnings`).

    Raises
    ------
    InvalidInputError
        Frames of different shapes, a bad radius, a predictor that is not one of the above or
        has no finite value.
    """
    if not (isinstance(radius, int | float) and np.isfinite(radius) and radius > 0):
        raise InvalidInputError(f"radius must be a finite number of px > 0, got {radius!r}")
    if wall is not None:
        wall_sign(wall)
    shape = None
    if not isinstance(frame_a, Particles) and not isinstance(frame_b, Particles):
        sa, sb = np.shape(frame_a), np.shape(frame_b)
        if sa != sb:
            raise InvalidInputError(f"frames of different shapes: A {sa}, B {sb}")
        shape = sa
    if rows is not None:
        if shape is None or len(shape) != 2:
            raise InvalidInputError("rows apply to 2D frames, not to particle images found")
        rows = _rows(rows, shape[0])
    pa, pb = (f if isinstance(f, Particles)
              else detect_particles(f, mask=mask, full=full, rows=rows)
              for f in (frame_a, frame_b))  # fmt: skip
    fn = predictor_of(predictor, wall)
    du, dv = _predict(fn, pa.x, pa.y)
    partner, status = _rspiv.track_particles(pa.x, pa.y, pb.x, pb.y, du, dv, float(radius))
    ok = status == STATUS["matched"]
    ia, ib = np.flatnonzero(ok), partner[ok]
    counts = {name: int(np.count_nonzero(status == code)) for name, code in STATUS.items()}
    if max_diameter is not None:
        shaped = _shaped(pa, ia, max_diameter) & _shaped(pb, ib, max_diameter)
        counts["misshapen"] = int(np.count_nonzero(~shaped))
        ia, ib = ia[shaped], ib[shaped]
    u, v = pb.x[ib] - pa.x[ia], pb.y[ib] - pa.y[ia]
    if shape is not None:
        area = float((shape[0] if rows is None else rows[1] - rows[0]) * shape[1])
    else:
        area = float((np.ptp(pb.x) + 1) * (np.ptp(pb.y) + 1)) if len(pb) > 1 else 1.0
    lam = len(pb) / area * np.pi * radius**2
    stray = 1.0 - float(np.exp(-lam))
    # the particle images without a candidate; with a wall, only those in the flow (the
    # reflections' strays never reach a profile)
    none = status == STATUS["none"]
    if wall is not None:
        none &= wall_sign(wall) * (np.asarray(wall.line(pa.x), dtype=np.float64) - pa.y) > 0
    matched = counts["matched"]
    stray_pairs = lam * np.count_nonzero(none) / matched if matched else float("nan")
    res = np.hypot(u - du[ia], v - dv[ia])
    edge = float(np.mean(res > 0.75 * radius)) if res.size else float("nan")
    tracks = Tracks(
        x=0.5 * (pa.x[ia] + pb.x[ib]), y=0.5 * (pa.y[ia] + pb.y[ib]), u=u, v=v,
        du=du[ia], dv=dv[ia],
        sigma_u=np.hypot(pa.sigma_x[ia], pb.sigma_x[ib]).astype(np.float64),
        sigma_v=np.hypot(pa.sigma_y[ia], pb.sigma_y[ib]).astype(np.float64),
        height_a=pa.height[ia], height_b=pb.height[ib],
        saturated=pa.saturated[ia] | pb.saturated[ib], status=counts,
        detected=(len(pa), len(pb)), radius=float(radius), diameter=pa.diameter,
        stray_share=stray, stray_pairs=float(stray_pairs), edge_share=edge,
    )  # fmt: skip
    return dataclasses.replace(tracks, warnings=_warnings(tracks))


def _shaped(p: Particles, idx: np.ndarray, factor: float) -> np.ndarray:
    """Which of ``p``'s particle images ``idx`` are no wider along either measured axis than
    ``factor`` times the frame's median diameter or the :data:`WIDEST_KEPT` percentile of its
    images' widest axes, whichever is larger (saturated ones, and those measured along neither
    axis, pass)."""
    if not (np.isfinite(factor) and factor > 0):
        raise InvalidInputError(f"max_diameter must be > 0, got {factor!r}")
    every = np.fmax(p.diameter_x, p.diameter_y).astype(np.float64)
    every = every[np.isfinite(every)]
    limit = factor * p.diameter
    if every.size:
        limit = max(limit, float(np.percentile(every, WIDEST_KEPT)))
    widest = np.fmax(p.diameter_x[idx], p.diameter_y[idx]).astype(np.float64)
    # an axis not measured (NaN: a faint or small image) is not held against the image
    return p.saturated[idx] | np.isnan(widest) | (widest <= limit)


def _warnings(t: Tracks) -> tuple[str, ...]:
    """What weakens the tracks (module docstring), one line each."""
    out = []
    na = t.detected[0]
    if na == 0 or t.detected[1] == 0:
        out.append(f"no particle images found in frame {'A' if na == 0 else 'B'}")
        return tuple(out)
    share = t.status["matched"] / na
    if share < MIN_MATCHED_SHARE:
        s = t.status
        out.append(
            f"only {100 * share:.0f} % of frame A's {na} particle images paired ({s['none']} "
            f"without a candidate within {t.radius:g} px, {s['several']} with several, "
            f"{s['claimed']} claimed twice): the predictor misses the flow, the seeding is "
            "dense for the radius, or the frames are not a pair"
        )
    if t.stray_pairs > MAX_STRAY_PAIRS:
        out.append(
            f"about {100 * t.stray_pairs:.0f} % of the pairs are particle images whose partner "
            f"was lost paired with a stray one (a stray within {t.radius:g} px of "
            f"{100 * t.stray_share:.0f} % of the predictions): a smaller radius, a better "
            "predictor or sparser seeding"
        )
    if len(t) and t.edge_share > CROWDED_EDGE:
        out.append(
            f"{100 * t.edge_share:.0f} % of the pairs lie beyond 3/4 of the {t.radius:g} px "
            "radius from the predictor: the radius clips the fluctuations about it (the "
            "stresses read low); a larger radius or a better predictor"
        )
    return tuple(out)
