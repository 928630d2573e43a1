"""Wall alignment from the particle reflection (paper section 3.2).

Particles reflect in the wall, so the mean streamwise displacement profile of each column is
mirror-symmetric about the wall. For every streamwise station the profile is cross-correlated
with its flipped copy; the correlation peak, located with a three-point Gaussian fit, is the
shift ``d`` and the wall lies at ``(h - d) / 2`` from the first sample (``h`` is the profile's
length). A line fitted to the stations gives the wall angle, i.e. the rotation that aligns the
calibration with the flow.

Refinement. A three-point Gaussian fit of a correlation peak that is not centred is biased (peak
locking). rspiv therefore iterates, as window deformation does in PIV: the profile is resampled
(linear interpolation) at positions ``w + k dy`` and ``w - k dy`` symmetric about the current
estimate ``w``, the residual shift of the flipped copy is measured at lags -1, 0, +1 and half of
it corrects ``w``. Both samples of a pair share the same fractional grid position, but seen from
the wall their nodes lie on opposite sides (at distances ``k - t`` and ``k + 1 - t`` above,
``k + t`` and ``k - 1 + t`` below): the interpolation errors of a curved profile cancel to second
order only, and the fixed point keeps an error periodic in the wall's place between rows (zero
at a row and half-way). On rows 16 px apart (another tool's 32 px windows at 50 % overlap) it
reaches +-1.2 px.

Joint fit (the default, ``fit="joint"``). The resampled estimate then starts a fit of the model
itself: one smooth profile ``f(|y - w|)`` of the distance from the wall (a cubic B-spline with
knots a row apart next to the wall and a tenth of the distance apart farther out; a kink is
allowed at the wall) fitted by least squares to both sides' samples at once, every row of the
profile as far from the start as the shorter side reaches, and a row beyond;
``w`` minimises the residual within half a row of the start (bounded Brent). Both sides'
samples fall on one curve only at the true wall, and no sample is interpolated. Where the
samples are few (a wall near the field's edge) the knots widen (1.5, 2, 3, 4 rows) until the
samples outnumber the curve's coefficients by :data:`JOINT_MIN_SPARE`; through every sample
any wall would fit. Fewer than 2 rows on a side keep the resampled estimate.
Measured on the synthetic layer's mirrored mean profile (``python benches/wall_bias.py``), the
wall's error peak to peak over its place between rows, resampled -> joint, at scale 0.25 (the
viscous length 0.37 px) / 1.0 (1.4 px):

- rows 16 px apart, sampled at points: 2.33 -> 0.052 px / 0.39 -> 0.055 px;
- rows 16 px apart, 32 px windows: 2.19 -> 0.30 px / 0.87 -> 0.17 px;
- rows 4 px apart, 8 px tall windows: 0.21 -> 0.041 px / 0.053 -> 0.004 px;
- rows 2 px apart, 8 px tall windows: 0.029 -> 0.025 px / 0.007 -> 0.004 px.

A wall tilted by 0.3 degree, read from 10 exact fields on rows 16 px apart: 0.404 degree
resampled, 0.2975 joint (stations within 0.10 px of the wall, 2.4 px before). Noise on the
samples scatters the joint fit a little more (sd 0.40 against 0.28 px with 0.4 % of the free
stream's displacement on every sample of rows 16 px apart) about a bias 7 times smaller. It
costs 2-17 ms per station.

Sampling. The profile must be sampled finely enough for the near-wall shape. With the resampling
alone and 32 x 8 px windows at 50 % overlap (a vector row every 4 px) the mirror position locked
to the rows (peak to peak 0.06 px at full scale, 0.14 px at half scale, 0.6-0.8 px at 0.25-0.3
scale for a window-averaged DNS profile; the viscous length is 1.4 px x scale); every 2 px (75 %
overlap) it was below 0.05 px at all these scales. :func:`rspiv.wall_table` uses 75 % overlap
for the final pass; the joint fit takes the locking on 4 px rows down 5-12 times (above).

Whole fields. By default :func:`find_wall` finds its own band and station count, so a whole PIV
field (a boundary layer along one edge, thousands of px of free stream beside it), a list of
fields or an array of mean profiles can be handed to it as it is: the band is centred on the row
of smallest mean |u| (the wall, where the particles and their reflections stand still) and as wide
as the rows with data allow on both sides; above 64 columns they are averaged into 32 stations.

Table 4 (the wall on the raw and the dewarped frames by each model) is :mod:`rspiv.wall_table`.

Coordinates: pixel frame of the README (x = column, y = row, y down). ``angle_deg`` is the wall's
slope angle in that frame, ``atan(d wall / d x)``; a positive angle means the wall descends (y
grows) to the right, which on screen is a clockwise rotation. The rotation that levels the wall
in ``p_i = R(theta) F(p_o)`` (rotation counter-clockwise in the (x, y) axes, as
:meth:`rspiv.Mapping.rotated`) is ``theta = +angle_deg``: a dewarped pixel ``P`` shows the image
at ``R(theta) P`` (about the centre), so a wall direction at angle ``a`` appears at ``a - theta``.
The paper's "negative of the angle" is the same rotation with the angle measured with y up
(its wall "rotated clockwise" is a positive ``angle_deg`` here). See :attr:`Wall.rotation_deg`.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from rspiv.errors import InvalidInputError

__all__ = [
    "MAX_TILT_DEG",
    "MIN_MIRROR_CORRELATION",
    "Wall",
    "auto_band",
    "check_level",
    "find_wall",
    "mirror_shift_positions",
]

#: Above this many columns ``stations="auto"`` averages them into ``AUTO_STATIONS`` stations.
AUTO_STATION_COLUMNS = 64
AUTO_STATIONS = 32
#: A station's profile must match its mirror image at least this well (``peak_correlation``):
#: a wall's reflection gives 0.998 or more (the synthetic layer, one pair or four); flows
#: without a wall gave medians of 0.36-0.81 (OpenPIV's recordings ``test2``, ``test4``,
#: ``test5``, whose mirror positions then scattered over 200 px; ``python
#: benches/real_data_checks.py``). Fewer than half the stations above it is no wall:
#: :func:`find_wall` refuses. A smooth extremum of the profile (a jet, a wake) mirrors itself
#: too and is not told from a wall, unless it tilts (:data:`MAX_TILT_DEG`).
MIN_MIRROR_CORRELATION = 0.9
#: A wall found tilted more than this from the image rows (degrees) is refused where a
#: campaign or a series finds its wall (:func:`check_level`). A real wall lies within a degree
#: or two of the rows (the paper's target: 0.04 degree off the wall). OpenPIV's real ``test2``,
#: whose mean profile over its six pairs has a smooth minimum and no wall, mirrored itself at
#: enough stations along a line tilted 10.5 degrees, bending 7.7 px off it.
MAX_TILT_DEG = 5.0


@dataclasses.dataclass(frozen=True)
class Wall:
    """The wall measured from the particle reflection.

    Attributes
    ----------
    x_px : ndarray, shape (n,)
        Streamwise position of each station (px).
    position_px : ndarray, shape (n,)
        Wall-normal position of the wall at each station (px, pixel frame; NaN where no
        symmetric profile was found).
    intercept_px, slope : float
        Least-squares line ``wall(x) = intercept_px + slope * x`` over the valid stations.
    angle_deg : float
        ``degrees(atan(slope))``: the wall's angle in the pixel frame (positive: y grows with x).
    max_deviation_px : float
        The paper's "maximum deviation of the measured wall profile from the straight and
        horizontal position" (Table 4): ``max(position) - min(position)`` over the valid
        stations, the width of the narrowest horizontal band holding the measured wall. Tilt and
        curvature both count.
    straightness_px : float
        Largest |position - fitted line|: the curvature alone, tilt removed.
    peak_correlation : ndarray, shape (n,)
        Normalised correlation of each station's profile with its flipped copy at the final
        shift (1 for a perfectly mirrored profile).
    flow_side : {"above", "below"}
        Where the flow is: ``"above"`` the wall (at smaller y: the wall is in the lower half of
        the rows with data, e.g. near the bottom edge) or ``"below"`` it; judged from the row of
        smallest mean |u|.
    """

    x_px: np.ndarray
    position_px: np.ndarray
    intercept_px: float
    slope: float
    angle_deg: float
    max_deviation_px: float
    straightness_px: float
    peak_correlation: np.ndarray
    flow_side: str = "above"

    @property
    def rotation_deg(self) -> float:
        """The rotation ``theta`` (degrees) that levels the wall, to pass to
        ``Mapping.rotated`` / ``Calibration.with_rotation``: ``+angle_deg`` in the pixel frame
        (see the module docstring)."""
        return self.angle_deg

    def line(self, x: np.ndarray | float) -> np.ndarray:
        """The fitted wall line at streamwise position(s) ``x`` (px)."""
        return self.intercept_px + self.slope * np.asarray(x, dtype=np.float64)

    @property
    def valid(self) -> np.ndarray:
        """Stations where a wall position was found."""
        return np.isfinite(self.position_px)


def _gauss3(cm: np.ndarray, c0: np.ndarray, cp: np.ndarray) -> np.ndarray:
    """Three-point Gaussian sub-sample peak offset (parabolic where a value is <= 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = (cm > 0) & (c0 > 0) & (cp > 0)
        lm, l0, lp = (np.log(np.where(pos, v, 1.0)) for v in (cm, c0, cp))
        den_g = 2.0 * (lm - 2.0 * l0 + lp)
        off_g = (lm - lp) / den_g
        den_p = 2.0 * (cm - 2.0 * c0 + cp)
        off_p = (cm - cp) / den_p
        off = np.where(pos & (den_g < 0), off_g, off_p)
    return np.where(np.isfinite(off), np.clip(off, -1.0, 1.0), 0.0)


def _interp_columns(prof: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``prof`` (n, m) at fractional row indices
    ``idx`` (k, m); NaN outside ``[0, n - 1]``."""
    n = prof.shape[0]
    inside = (idx >= 0) & (idx <= n - 1)
    i0 = np.clip(np.floor(idx).astype(np.int64), 0, max(n - 2, 0))
    t = idx - i0
    cols = np.broadcast_to(np.arange(prof.shape[1]), idx.shape)
    i1 = np.minimum(i0 + 1, n - 1)
    v = prof[i0, cols] * (1.0 - t) + prof[i1, cols] * t
    return np.where(inside, v, np.nan)


def _initial_shift(prof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integer-lag search: correlate each zero-mean column with its flipped copy (FFT, all lags);
    returns the wall estimate in row-index units and the peak's normalised value."""
    n, m = prof.shape
    a = prof - prof.mean(axis=0)
    b = a[::-1]
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    fa = np.fft.rfft(a, nfft, axis=0)
    fb = np.fft.rfft(b, nfft, axis=0)
    c = np.fft.irfft(np.conj(fa) * fb, nfft, axis=0)  # c[l] = sum_k a_k b_{k+l}
    lags = np.concatenate([np.arange(0, n), np.arange(-(n - 1), 0)])
    c = np.concatenate([c[:n], c[nfft - (n - 1) :]], axis=0)
    norm = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    # Require an overlap of at least a third of the profile: very short overlaps are noise.
    c = np.where(np.abs(lags)[:, None] <= (2 * n) // 3, c, -np.inf)
    k = np.argmax(c, axis=0)
    peak = c[k, np.arange(m)]
    cm = c[np.clip(k - 1, 0, len(lags) - 1), np.arange(m)]
    cp = c[np.clip(k + 1, 0, len(lags) - 1), np.arange(m)]
    cm = np.where(np.isfinite(cm), cm, 0.0)
    cp = np.where(np.isfinite(cp), cp, 0.0)
    # Lags are contiguous except at the wrap between n-1 and -(n-1); the +-1 neighbours of an
    # interior peak are the adjacent lags.
    m_peak = lags[k] + _gauss3(cm, peak, cp)
    wall_idx = ((n - 1) - m_peak) / 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(norm > 0, peak / norm, 0.0)
    return wall_idx, rho


def mirror_shift_positions(
    profiles: np.ndarray,
    *,
    iterations: int = 8,
    half_width: int | None = None,
    fit: str = "joint",
) -> tuple[np.ndarray, np.ndarray]:
    """Mirror position of each column of ``profiles`` in row-index units.

    Parameters
    ----------
    profiles : ndarray, shape (n, m)
        ``m`` profiles sampled at ``n`` equally spaced wall-normal positions (no NaN).
    iterations : int
        Symmetric-resampling refinement steps after the integer-lag search.
    half_width : int, optional
        Half-width (samples) of the symmetric refinement window and of the joint fit; default:
        as wide as the profile allows around each estimate.
    fit : {"joint", "resample"}
        ``"joint"`` (default): the resampled estimate refined by the joint fit of one smooth
        one-sided profile to both sides' samples; ``"resample"``: the resampled estimate alone
        (see the module docstring).

    Returns
    -------
    position : ndarray, shape (m,)
        Mirror (wall) position in fractional row indices; NaN where not found.
    rho : ndarray, shape (m,)
        Normalised correlation of the profile with its mirror at the final position.
    """
    prof = np.asarray(profiles, dtype=np.float64)
    if prof.ndim != 2 or prof.shape[0] < 5 or prof.shape[1] < 1:
        raise InvalidInputError(
            f"wall profiles must be (n >= 5 samples, m >= 1 stations), got shape {prof.shape}"
        )
    if not np.all(np.isfinite(prof)):
        raise InvalidInputError("wall profiles contain NaN or inf (fill or mask them first)")
    if fit not in ("joint", "resample"):
        raise InvalidInputError(f'mirror_shift_positions: fit must be "joint" or "resample", '
                                f"got {fit!r}")  # fmt: skip
    n, m = prof.shape
    w, rho = _initial_shift(prof)
    for _ in range(iterations):
        room = np.floor(np.minimum(w, (n - 1) - w)).astype(np.int64)
        kmax = int(np.max(room, initial=0))
        if half_width is not None:
            kmax = min(kmax, int(half_width))
        if kmax < 2:
            break
        k = np.arange(-kmax, kmax + 1)[:, None]
        up = _interp_columns(prof, w[None, :] + k)
        dn = _interp_columns(prof, w[None, :] - k)
        # Per column, only lags inside the column's room (and inside the refinement window).
        lim = np.minimum(room, kmax)[None, :]
        use = (np.abs(k) <= lim - 1) & np.isfinite(up) & np.isfinite(dn)
        mean = np.where(use, up, 0.0).sum(axis=0) / np.maximum(use.sum(axis=0), 1)
        a = np.where(use, up - mean, 0.0)
        b = np.where(use, dn - mean, 0.0)
        # c(l) = sum_k a_k b_{k+l}, l = -1, 0, +1.
        c0 = (a * b).sum(axis=0)
        cp = (a[:-1] * b[1:]).sum(axis=0)
        cm = (a[1:] * b[:-1]).sum(axis=0)
        norm = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
        with np.errstate(invalid="ignore", divide="ignore"):
            cn = [np.where(norm > 0, v / norm, 0.0) for v in (cm, c0, cp)]
        delta = _gauss3(*cn)
        # Flipped copy b(s) = p(w - s) = a(s + 2 (w_true - w)); its peak at lag l = -2 (w_true - w).
        w = np.clip(w - delta / 2.0, 0.0, n - 1.0)
        rho = cn[1]
        if np.all(np.abs(delta) < 1e-9):
            break
    if fit == "joint":
        w = np.array([_joint_fit(prof[:, j], w[j], half_width) for j in range(m)])
    w = np.where(rho > 0, w, np.nan)
    return w, rho


#: Joint fit: knots a row apart next to the wall, spaced by this fraction of the distance beyond.
JOINT_KNOT_GROWTH = 0.1
#: Joint fit: rows needed on each side of the resampled estimate (else it is kept).
MIN_JOINT_ROOM = 2.0
#: Joint fit: the knots' spacing next to the wall (rows), the finest the samples allow.
JOINT_KNOT_STEPS = (1.0, 1.5, 2.0, 3.0, 4.0)
#: Joint fit: samples beyond the curve's coefficients needed. With one to spare, 9 rows about
#: a wall on 16 px rows read it within 0.13 px rms (noise-free; 1.73 px resampled), and the
#: noise costs no more than the resampling's (1 % of the free stream on every sample: 1.4
#: against 1.6 px); with none any wall fits (``python benches/wall_bias.py``).
JOINT_MIN_SPARE = 1


def _distance_knots(reach: float, step: float = 1.0) -> np.ndarray:
    """Knot vector (cubic, clamped) over distances ``[0, reach]`` rows: ``step`` rows apart,
    then ``JOINT_KNOT_GROWTH`` times the distance apart."""
    inner = [0.0]
    while True:
        gap = max(step, JOINT_KNOT_GROWTH * inner[-1])
        if inner[-1] + gap >= reach - 0.5 * step:
            break
        inner.append(inner[-1] + gap)
    return np.r_[[0.0] * 3, inner, [reach] * 4]


def bspline_basis(x: np.ndarray, t: np.ndarray, k: int = 3) -> np.ndarray:
    """The B-spline basis of degree ``k`` on the knots ``t`` (non-decreasing; clamped: the end
    knots repeated ``k + 1`` times) at the points ``x`` (inside ``[t[0], t[-1]]``), by Cox-de
    Boor's recursion: an array ``(len(x), len(t) - k - 1)`` whose rows sum to 1.

    Written here rather than taken from ``scipy.interpolate``, which ``import rspiv`` does not
    load. That package was first blamed for a 47 MP campaign loop's peak of 3.1 GB instead of
    2.1 GB; the higher peak also came without it and varied with the machine's state
    (``benches/RESULTS.md``, thirty-third session)."""
    x = np.asarray(x, np.float64)[:, None]
    t = np.asarray(t, np.float64)
    # degree 0: the interval holding x; the right end belongs to the last non-empty interval
    b = ((t[:-1] <= x) & (x < t[1:])).astype(np.float64)
    last = int(np.flatnonzero(t[:-1] < t[1:])[-1])
    b[x[:, 0] >= t[last + 1], last] = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        for d in range(1, k + 1):
            left_den, right_den = t[d:-1] - t[: -d - 1], t[d + 1 :] - t[1:-d]
            left = np.where(left_den > 0, (x - t[: -d - 1]) / left_den, 0.0)
            right = np.where(right_den > 0, (t[d + 1 :] - x) / right_den, 0.0)
            b = left * b[:, :-1] + right * b[:, 1:]
    return b


def _joint_fit(p: np.ndarray, w0: float, half_width: int | None) -> float:
    """The wall (row-index units) within half a row of ``w0`` that lets one cubic B-spline of
    the distance ``|y - w|`` fit both sides' samples of ``p`` best (least squares); ``w0``
    itself where the sides share too few samples or ``w0`` is not finite (module docstring)."""
    n = len(p)
    if not np.isfinite(w0):
        return w0
    # Both sides sample the curve as far from the wall as the shorter side reaches: the samples
    # there (and a row beyond, which the search's half row may bring in) are one set for the
    # whole search. The long side's farther samples would only shape the curve beyond.
    short = min(w0, (n - 1) - w0)
    if half_width is not None:
        short = min(short, float(half_width))
    if short < MIN_JOINT_ROOM:
        return float(w0)
    reach = short + 1.0
    rows = np.arange(max(0, int(np.ceil(w0 - reach))), min(n - 1, int(np.floor(w0 + reach))) + 1)
    y = rows.astype(np.float64)
    vals = p[rows]
    # knots as close as a row apart, wider where the curve would pass through every sample
    # (then any wall fits and the search follows the rounding): JOINT_MIN_SPARE samples more
    # than coefficients, else no fit
    far = float(np.max(np.abs(y - w0))) + 0.5 + 1e-9
    for step in JOINT_KNOT_STEPS:
        t = _distance_knots(far, step)
        if len(rows) - (len(t) - 4) >= JOINT_MIN_SPARE:
            break
    else:
        return float(w0)

    def residual(w: float) -> float:
        basis = bspline_basis(np.abs(y - w), t)
        coef, *_ = np.linalg.lstsq(basis, vals, rcond=None)
        r = vals - basis @ coef
        return float(r @ r)

    best = minimize_scalar(
        residual, bounds=(w0 - 0.5, w0 + 0.5), method="bounded", options={"xatol": 1e-5}
    )
    return float(best.x) if np.isfinite(best.fun) else float(w0)


def _profiles_from_input(
    data: Any, y: np.ndarray | None, x: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean streamwise profile array (ny, nx) with its y and x coordinates (px)."""
    if hasattr(data, "u") and hasattr(data, "y") and hasattr(data, "x"):
        u = np.asarray(data.u, dtype=np.float64)
        valid = np.asarray(getattr(data, "valid", np.ones(u.shape, bool)), dtype=bool)
        fy = np.asarray(data.y, dtype=np.float64)
        fx = np.asarray(data.x, dtype=np.float64)
        yy = fy[:, 0] if fy.ndim == 2 else fy
        xx = fx[0, :] if fx.ndim == 2 else fx
        u = np.where(valid, u, np.nan)
        if u.ndim == 3:
            with np.errstate(invalid="ignore"):
                u = np.nanmean(u, axis=0)
        return u, yy, xx
    if isinstance(data, Sequence) and len(data) and hasattr(data[0], "u"):
        u, yy, xx = _profiles_from_input(data[0], None, None)
        stack = [u] + [_profiles_from_input(f, None, None)[0] for f in data[1:]]
        with np.errstate(invalid="ignore"):
            return np.nanmean(np.stack(stack), axis=0), yy, xx
    u = np.asarray(data, dtype=np.float64)
    if u.ndim == 3:
        with np.errstate(invalid="ignore"):
            u = np.nanmean(u, axis=0)
    if u.ndim != 2:
        raise InvalidInputError(f"find_wall: expected a (ny, nx) mean-u array, got {u.shape}")
    yy = np.arange(u.shape[0], dtype=np.float64) if y is None else np.asarray(y, np.float64)
    xx = np.arange(u.shape[1], dtype=np.float64) if x is None else np.asarray(x, np.float64)
    return u, yy, xx


def _robust_inliers(x: np.ndarray, pos: np.ndarray, ok: np.ndarray, k: float | None) -> np.ndarray:
    """Stations within ``k`` robust standard deviations (1.4826 MAD) of the line fitted to the
    inliers, iterated; all valid stations if ``k`` is None."""
    if k is None:
        return ok
    ok = ok.copy()
    for _ in range(5):
        if ok.sum() < 3:
            break
        slope, intercept = np.polyfit(x[ok], pos[ok], 1)
        r = pos - (intercept + slope * x)
        mad = 1.4826 * np.median(np.abs(r[ok] - np.median(r[ok])))
        new = np.isfinite(pos) & (np.abs(r) <= max(k * mad, 1e-9))
        if np.array_equal(new, ok) or new.sum() < 2:
            break
        ok = new
    return ok


def _wall_row(u: np.ndarray) -> tuple[int, np.ndarray]:
    """Index of the row of smallest mean |u| (-1 if none) and the indices of the rows with data."""
    have = np.isfinite(u).any(axis=1)
    rows = np.flatnonzero(have)
    if rows.size == 0:
        return -1, rows
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rows with some NaN are fine
        prof = np.nanmean(np.abs(u[rows]), axis=1)
    return int(rows[np.argmin(prof)]), rows


def auto_band(u: np.ndarray, y: np.ndarray) -> tuple[tuple[float, float], str]:
    """The band of rows around the wall, and the flow's side, of a mean-u array.

    The band is centred on the row of smallest mean |u| over the columns (the wall, where the
    particles and their reflections stand still) and as wide as the rows with data allow on
    both sides (at least 3 rows each way). The flow is ``"above"`` the wall (smaller y) when that
    row lies in the lower half of the rows, else ``"below"``.

    Parameters
    ----------
    u : ndarray, shape (ny, nx)
        Mean streamwise displacement, NaN where there is no data; rows sorted by ``y``.
    y : ndarray, shape (ny,)
        Row coordinates (px), increasing and equally spaced.

    Returns
    -------
    band : (float, float)
        ``(y0, y1)`` px.
    flow_side : {"above", "below"}
    """
    j, rows = _wall_row(u)
    if rows.size < 5:
        raise InvalidInputError(
            f"find_wall: {rows.size} rows of the field have data; need at least 5"
        )
    flow_side = "above" if j > (len(y) - 1) / 2 else "below"
    half = min(y[j] - y[rows[0]], y[rows[-1]] - y[j])
    dy = y[1] - y[0] if len(y) > 1 else 1.0
    half = max(half, 3 * dy)
    return (float(y[j] - half), float(y[j] + half)), flow_side


def find_wall(
    data: Any,
    *,
    y: np.ndarray | None = None,
    x: np.ndarray | None = None,
    band: tuple[float, float] | str | None = "auto",
    stations: int | str | None = "auto",
    iterations: int = 8,
    reject: float | None = 3.5,
    fit: str = "joint",
) -> Wall:
    """Find the wall from the mirror symmetry of the mean streamwise profile.

    Parameters
    ----------
    data : PIV field, sequence of fields, or ndarray
        A PIV field (attributes ``x``, ``y``, ``u`` and optionally ``valid``; ``u`` of shape
        (ny, nx) or a stack (nt, ny, nx)), a sequence of such fields, or a mean streamwise
        displacement array ``u[y, x]`` (2-D, or 3-D stacked along axis 0). Invalid vectors
        (``valid`` false or NaN) are excluded from the mean.
    y, x : ndarray, optional
        Coordinates (px) of the rows and columns of an array input (default: indices). ``y``
        must be equally spaced.
    band : "auto", (float, float) or None
        Restrict to rows with ``band[0] <= y <= band[1]`` (px): a band around the wall holding
        the flow profile and its reflection. ``"auto"`` (default): :func:`auto_band`, centred on
        the row of smallest mean |u| and as wide as the rows with data allow; None: every row.
    stations : "auto", int or None
        Average the columns into this many streamwise stations. ``"auto"`` (default): one
        station per column up to 64 columns, else 32 stations; None: one per column.
    iterations : int
        Symmetric-resampling refinement steps (see the module docstring).
    reject : float or None
        Stations farther than ``reject`` robust standard deviations (1.4826 x the median
        absolute deviation) from the fitted line are set to NaN and excluded from the line, the
        angle and the deviations (iterated); None keeps every station.
    fit : {"joint", "resample"}
        How each station's mirror position is refined (:func:`mirror_shift_positions`):
        ``"joint"`` (default), one smooth one-sided profile fitted to both sides' samples;
        ``"resample"``, the symmetric resampling alone (biased on coarse rows: module docs).

    Returns
    -------
    Wall
        Per-station wall positions, the fitted line, its angle and the deviations.

    Raises
    ------
    InvalidInputError
        Unequally spaced ``y``, too few rows (fewer than 5 with data), no station with a
        usable profile, or no wall seen: fewer than half the stations' profiles match their
        mirror image with a correlation of :data:`MIN_MIRROR_CORRELATION` (a station below it
        is left out, NaN, as an outlier is).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices give NaN: handled
        return _find_wall(data, y, x, band, stations, iterations, reject, fit)


def _find_wall(
    data: Any,
    y: np.ndarray | None,
    x: np.ndarray | None,
    band: tuple[float, float] | None,
    stations: int | None,
    iterations: int,
    reject: float | None,
    fit: str,
) -> Wall:
    u, yy, xx = _profiles_from_input(data, y, x)
    if u.shape != (len(yy), len(xx)):
        raise InvalidInputError(
            f"find_wall: u has shape {u.shape} but y, x have {len(yy)}, {len(xx)} entries"
        )
    order = np.argsort(yy)
    u, yy = u[order], yy[order]
    if isinstance(stations, str):
        if stations != "auto":
            raise InvalidInputError(
                f'find_wall: stations must be "auto", an int or None, got {stations!r}'
            )
        stations = AUTO_STATIONS if u.shape[1] > AUTO_STATION_COLUMNS else None
    auto = isinstance(band, str)
    if auto:
        if band != "auto":
            raise InvalidInputError(
                f'find_wall: band must be "auto", (y0, y1) or None, got {band!r}'
            )
        band, flow_side = auto_band(u, yy)
    else:
        j, _ = _wall_row(u)
        flow_side = "above" if j > (len(yy) - 1) / 2 else "below"
    if band is not None:
        # a row at the band's edge stays in whatever the positions' offset rounds it to
        tol = 1e-6 * (abs(float(yy[1] - yy[0])) if len(yy) > 1 else 1.0)
        keep = (yy >= min(band) - tol) & (yy <= max(band) + tol)
        u, yy = u[keep], yy[keep]
    if len(yy) < 5:
        msg = f"find_wall: {len(yy)} rows in the band; need at least 5"
        if auto:
            msg = (
                f"find_wall: {len(yy)} rows in the band around the row of smallest mean |u| "
                f"(y {np.mean(band):g} px, near the field's edge), need at least 5: no wall "
                "with its reflection inside the field"
            )
        raise InvalidInputError(msg)
    dy = np.diff(yy)
    if not np.allclose(dy, dy[0], rtol=1e-6, atol=1e-9) or dy[0] <= 0:
        raise InvalidInputError("find_wall: the profile's y must be equally spaced")
    if stations is not None:
        if stations < 1 or stations > u.shape[1]:
            raise InvalidInputError(
                f"find_wall: stations must be in 1..{u.shape[1]}, got {stations}"
            )
        edges = np.linspace(0, u.shape[1], stations + 1).round().astype(int)
        with np.errstate(invalid="ignore"):
            u = np.stack(
                [np.nanmean(u[:, a:b], axis=1) for a, b in zip(edges[:-1], edges[1:], strict=True)],
                axis=1,
            )
            xx = np.array([xx[a:b].mean() for a, b in zip(edges[:-1], edges[1:], strict=True)])
    # Stations with missing samples: fill interior gaps linearly, drop columns mostly empty.
    good = np.isfinite(u).mean(axis=0) >= 0.9
    pos = np.full(u.shape[1], np.nan)
    rho = np.zeros(u.shape[1])
    if not good.any():
        raise InvalidInputError("find_wall: no station has a complete profile")
    ug = u[:, good]
    if not np.all(np.isfinite(ug)):
        idx = np.arange(len(yy))
        for j in np.flatnonzero(~np.isfinite(ug).all(axis=0)):  # a few stations at most
            f = np.isfinite(ug[:, j])
            ug[:, j] = np.interp(idx, idx[f], ug[f, j])
    w_idx, r = mirror_shift_positions(ug, iterations=iterations, fit=fit)
    pos[good] = yy[0] + w_idx * dy[0]
    rho[good] = r
    seen = np.isfinite(pos) & (rho >= MIN_MIRROR_CORRELATION)
    n = int(good.sum())
    if seen.sum() < max(2, (n + 1) // 2):
        raise InvalidInputError(
            f"find_wall: no wall reflection seen: the mean profile matches its mirror image "
            f"(correlation >= {MIN_MIRROR_CORRELATION}) at {seen.sum()} of {n} stations "
            f"(median {np.median(rho[good]):.2f}; a wall's reflection gives 0.99 or more)"
        )
    ok = _robust_inliers(xx, pos, seen, reject)
    pos = np.where(ok, pos, np.nan)
    slope, intercept = np.polyfit(xx[ok], pos[ok], 1)
    resid = pos[ok] - (intercept + slope * xx[ok])
    return Wall(
        x_px=xx,
        position_px=pos,
        intercept_px=float(intercept),
        slope=float(slope),
        angle_deg=float(np.degrees(np.arctan(slope))),
        max_deviation_px=float(np.ptp(pos[ok])),
        straightness_px=float(np.max(np.abs(resid))),
        peak_correlation=rho,
        flow_side=flow_side,
    )


def check_level(wall: Wall) -> Wall:
    """``wall`` if it lies within :data:`MAX_TILT_DEG` of the image rows; else InvalidInputError
    in one line: a flow's smooth extremum (a wake, a shear layer) taken for a wall's reflection,
    or a camera far from level with the wall."""
    if abs(wall.angle_deg) > MAX_TILT_DEG:
        raise InvalidInputError(
            f"the wall found (where the mean profile mirrors itself) is tilted "
            f"{wall.angle_deg:.1f} degrees from the rows (at most {MAX_TILT_DEG:g}) and bends "
            f"{wall.straightness_px:.1f} px off its line: a flow's extremum (a wake, a shear "
            "layer) taken for a wall's reflection, or a camera far from level with the wall; "
            "level the camera, or give the wall's row, or turn the wall finding off "
            "([wall] enabled = false)"
        )
    return wall
