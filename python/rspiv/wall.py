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
it corrects ``w``. Because both samples of a pair share the same fractional grid position, an
exactly mirrored profile gives an exactly symmetric pair at the true wall: the iteration's fixed
point is unbiased.

Sampling. The profile must be sampled finely enough for the near-wall shape: with 32 x 8 px
windows at 50 % overlap (a vector row every 4 px) the mirror position locks to the rows, an error
periodic in the wall's position relative to them (peak to peak 0.06 px at full scale, 0.14 px
at half scale, 0.6-0.8 px at 0.25-0.3 scale for a window-averaged DNS profile; the viscous length
is 1.4 px x scale); every 2 px (75 % overlap) it is below 0.05 px at all these scales.
:func:`wall_table` uses 75 % overlap for the final pass.

Table 4. :func:`wall_table` measures the wall on the raw frames and on the frames dewarped
(Method I, as the paper) by each mapping model fitted to the same calibration markers, without
and with the levelling rotation: :class:`WallTable`, printed by ``rspiv wall``.

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
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["Wall", "WallRow", "WallTable", "find_wall", "mirror_shift_positions", "wall_table"]


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
    """

    x_px: np.ndarray
    position_px: np.ndarray
    intercept_px: float
    slope: float
    angle_deg: float
    max_deviation_px: float
    straightness_px: float
    peak_correlation: np.ndarray

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
    profiles: np.ndarray, *, iterations: int = 8, half_width: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mirror position of each column of ``profiles`` in row-index units.

    Parameters
    ----------
    profiles : ndarray, shape (n, m)
        ``m`` profiles sampled at ``n`` equally spaced wall-normal positions (no NaN).
    iterations : int
        Symmetric-resampling refinement steps after the integer-lag search.
    half_width : int, optional
        Half-width (samples) of the symmetric refinement window; default: as wide as the
        profile allows around each estimate.

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
    w = np.where(rho > 0, w, np.nan)
    return w, rho


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


def find_wall(
    data: Any,
    *,
    y: np.ndarray | None = None,
    x: np.ndarray | None = None,
    band: tuple[float, float] | None = None,
    stations: int | None = None,
    iterations: int = 8,
    reject: float | None = 3.5,
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
    band : (float, float), optional
        Restrict to rows with ``band[0] <= y <= band[1]`` (px): a band around the wall holding
        the flow profile and its reflection.
    stations : int, optional
        Average the columns into this many streamwise stations (default: one station per
        column).
    iterations : int
        Symmetric-resampling refinement steps (see the module docstring).
    reject : float or None
        Stations farther than ``reject`` robust standard deviations (1.4826 x the median
        absolute deviation) from the fitted line are set to NaN and excluded from the line, the
        angle and the deviations (iterated); None keeps every station.

    Returns
    -------
    Wall
        Per-station wall positions, the fitted line, its angle and the deviations.

    Raises
    ------
    InvalidInputError
        Unequally spaced ``y``, too few rows, or no station with a usable profile.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices give NaN: handled
        return _find_wall(data, y, x, band, stations, iterations, reject)


def _find_wall(
    data: Any,
    y: np.ndarray | None,
    x: np.ndarray | None,
    band: tuple[float, float] | None,
    stations: int | None,
    iterations: int,
    reject: float | None,
) -> Wall:
    u, yy, xx = _profiles_from_input(data, y, x)
    if u.shape != (len(yy), len(xx)):
        raise InvalidInputError(
            f"find_wall: u has shape {u.shape} but y, x have {len(yy)}, {len(xx)} entries"
        )
    order = np.argsort(yy)
    u, yy = u[order], yy[order]
    if band is not None:
        keep = (yy >= min(band)) & (yy <= max(band))
        u, yy = u[keep], yy[keep]
    if len(yy) < 5:
        raise InvalidInputError(f"find_wall: {len(yy)} rows in the band; need at least 5")
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
    w_idx, r = mirror_shift_positions(ug, iterations=iterations)
    pos[good] = yy[0] + w_idx * dy[0]
    rho[good] = r
    ok = np.isfinite(pos)
    if ok.sum() < 2:
        raise InvalidInputError("find_wall: fewer than 2 stations with a mirrored profile")
    ok = _robust_inliers(xx, pos, ok, reject)
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
    )


# -- the paper's Table 4 --------------------------------------------------------------------------

DEFAULT_PASSES: tuple[tuple[int, int], ...] = ((64, 64), (32, 32), (32, 8))
#: Overlap per pass for the wall: the final 32 x 8 px windows at 75 % overlap put a vector row
#: every 2 px. At 4 px (50 %) the near-wall profile (viscous length ~1.4 px x scale) is
#: under-sampled and the mirror position locks to the vector rows: a periodic error of the
#: wall's phase relative to the rows, +-0.03 px at full scale but +-0.3 px at 0.3 scale, which
#: biases the angle low when the wall crosses less than one row spacing over the frame.
DEFAULT_OVERLAP: tuple[float, ...] = (0.5, 0.5, 0.75)


@dataclasses.dataclass(frozen=True)
class WallRow:
    """One condition of :class:`WallTable`.

    Attributes
    ----------
    condition : str
        ``"distorted"``, ``"R2"``, ``"R2 + rotation"``, ``"P3"``, ``"P3 + rotation"`` (the
        model name upper-cased).
    model : str or None
        Mapping model of the dewarping (None: the raw frames).
    rotation_deg : float
        Rotation added to the calibration for this row (0 for the unrotated rows), degrees,
        :attr:`Wall.rotation_deg` of the model's unrotated row.
    wall : Wall
        The wall found on the (dewarped) frames.
    """

    condition: str
    model: str | None
    rotation_deg: float
    wall: Wall

    @property
    def max_deviation_px(self) -> float:
        """Maximum deviation from the straight and horizontal position (px; Table 4)."""
        return self.wall.max_deviation_px

    @property
    def angle_deg(self) -> float:
        """Angle of the fitted wall line (degrees, pixel frame)."""
        return self.wall.angle_deg


@dataclasses.dataclass(frozen=True)
class WallTable:
    """The run's version of the paper's Table 4 (:func:`wall_table`).

    Attributes
    ----------
    rows : tuple of WallRow
        ``distorted`` first, then for each model its dewarped row and its rotated row.
    mappings : dict of str -> Mapping
        The mapping of every corrected row, by condition (the rotated rows' mappings include
        the levelling rotation: ``mappings["P3 + rotation"]`` is the calibration to use).
    method : str
        How the corrected rows were measured: ``"images"`` (Method I, the frames dewarped
        before the PIV, as the paper's Table 4).
    """

    rows: tuple[WallRow, ...]
    mappings: dict[str, Any]
    method: str = "images"

    def __getitem__(self, condition: str) -> WallRow:
        for r in self.rows:
            if r.condition.lower() == condition.lower():
                return r
        raise KeyError(f"no row {condition!r}; rows: {[r.condition for r in self.rows]}")

    @property
    def walls(self) -> dict[str, Wall]:
        """``{condition: Wall}`` in row order (for :func:`rspiv.plots.wall.wall_shape`)."""
        return {r.condition: r.wall for r in self.rows}

    @property
    def best(self) -> WallRow:
        """The row with the smallest maximum deviation."""
        return min(self.rows, key=lambda r: r.max_deviation_px)

    def format(self) -> str:
        """The table as text: condition, max deviation (px), angle (deg), straightness (px),
        valid stations."""
        lines = [
            f"{'condition':16s} {'max deviation [px]':>18s} {'angle [deg]':>12s} "
            f"{'straightness [px]':>17s} {'stations':>9s}"
        ]
        for r in self.rows:
            w = r.wall
            lines.append(
                f"{r.condition:16s} {w.max_deviation_px:18.3f} {w.angle_deg:+12.5f} "
                f"{w.straightness_px:17.3f} {int(w.valid.sum()):4d} / {len(w.valid):<4d}"
            )
        return "\n".join(lines)


def refit(calibration: Any, model: str) -> Any:
    """The calibration's markers fitted with another mapping ``model`` (same object points,
    central marker and normalising scale): a new :class:`rspiv.Calibration` whose ``model``
    and ``mapping`` are the refit (its rotation is not carried over)."""
    from rspiv.calibration import Calibration
    from rspiv.mapping import fit_mapping

    if not isinstance(calibration, Calibration):
        raise InvalidInputError(
            f"refitting model {model!r} needs a Calibration (with its markers), "
            f"got {type(calibration).__name__}"
        )
    mk = calibration.markers
    m = fit_mapping(
        mk.object_px, mk.image_px, model, center_index=mk.centre, scale=calibration.mapping.scale
    )
    new = Calibration(**calibration._fields())
    new.mapping = m
    new.model = m.model
    new.model_reason = f"refitted from the markers of a {calibration.model} calibration"
    return new


def _pair_frames(pair: Any) -> tuple[np.ndarray, np.ndarray]:
    from rspiv.calibration import read_image

    if len(pair) < 2:
        raise InvalidInputError("wall_table: every pair must hold two frames (A, B)")
    a, b = read_image(pair[0]), read_image(pair[1])
    if a.shape != b.shape:
        raise InvalidInputError(
            f"wall_table: frames of a pair differ in shape: {a.shape}, {b.shape}"
        )
    return a, b


def wall_table(
    pairs: Sequence[Any],
    calibration: Any = None,
    *,
    models: Sequence[str] | None = ("r2", "p3"),
    band: tuple[float, float] | None = None,
    stations: int | None = 16,
    passes: Sequence[tuple[int, int]] = DEFAULT_PASSES,
    overlap: float | Sequence[float] | None = None,
    iterations: int = 8,
    reject: float | None = 3.5,
    progress: Callable[[str], None] | None = None,
) -> WallTable:
    """The paper's Table 4 for a run: the wall on the raw frames and on the frames dewarped by
    each model, without and with the levelling rotation.

    As in the paper (section 3.2, Table 4, Fig. 8) the corrected rows come from Method I: each
    pair is dewarped with the model's mapping, PIV runs on the dewarped frames (object px), and
    :func:`find_wall` finds the wall from the reflection symmetry. The rotated row of a model
    dewarps with its mapping rotated by :attr:`Wall.rotation_deg` of that model's unrotated row.

    Parameters
    ----------
    pairs : sequence of (frame_a, frame_b)
        Frame pairs (arrays or image files) holding the wall and the particles' reflection.
    calibration : Calibration or Mapping, optional
        None: the distorted row only. A :class:`rspiv.Calibration`: every model of ``models``
        is fitted to its markers (R2 and P3 from the same markers, :func:`refit`); its own
        rotation is not used (the table measures it). A :class:`rspiv.Mapping` (or a
        Calibration with ``models=None``): that mapping only, as it is.
    models : sequence of {"r1", "r2", "p3"} or None
        Models of the corrected rows, in row order.
    band : (float, float), optional
        Rows (px) holding the flow profile and its reflection, passed to :func:`find_wall`;
        the PIV then runs only on these rows plus the largest window height on either side.
        Default: the whole frame.
    stations, iterations, reject
        As for :func:`find_wall`.
    passes, overlap
        PIV windows (coarse to fine, ``(w, h)`` px) and overlap (one value, or one per pass) of
        :func:`rspiv.piv`. Default overlap: 0.5, and 0.75 for the last pass, which samples the
        profile every 2 px with 8 px high windows: coarser rows lock the wall position to them
        (see ``DEFAULT_OVERLAP``).
    progress : callable, optional
        Called with a short message before each condition.

    Returns
    -------
    WallTable
        For a Mapping input the unrotated row uses the mapping as it is (its own rotation
        included) and the rotated row adds the measured rotation to it.

    Raises
    ------
    InvalidInputError
        No pairs, unreadable frames, frames of different shapes, a band outside the frames,
        a model that cannot be refitted.
    """
    from rspiv.dewarp import check_calibration_shape, dewarp
    from rspiv.method2 import _mapping_of
    from rspiv.piv import piv

    if len(pairs) == 0:
        raise InvalidInputError("wall_table: no frame pairs")
    frames = [_pair_frames(p) for p in pairs]
    shape = frames[0][0].shape
    for a, _ in frames:
        if a.shape != shape:
            raise InvalidInputError(f"wall_table: frames of shape {a.shape} and {shape} mixed")
    passes = [tuple(int(t) for t in p) for p in passes]
    if not passes:
        raise InvalidInputError("wall_table: passes is empty")
    if overlap is None:
        overlap = [0.5] * (len(passes) - 1) + [0.75]
    if np.ndim(overlap) == 0:
        overlap = [float(overlap)] * len(passes)  # type: ignore[arg-type]
    overlaps = [float(v) for v in overlap]  # type: ignore[union-attr]
    if len(overlaps) != len(passes):
        raise InvalidInputError(f"wall_table: {len(overlaps)} overlaps for {len(passes)} passes")
    h = shape[0]
    if band is not None:
        y0, y1 = sorted(float(v) for v in band)
        pad = max(p[1] for p in passes)
        r0 = max(0, int(np.floor(y0)) - pad)
        r1 = min(h, int(np.ceil(y1)) + pad + 1)
        if r1 - r0 < max(p[1] for p in passes) or y1 < 0 or y0 > h - 1:
            raise InvalidInputError(f"wall_table: band {band} lies outside the {h}-row frames")
        band_t: tuple[float, float] | None = (y0, y1)
    else:
        r0, r1, band_t = 0, h, None

    # The mappings, by model.
    conditions: list[tuple[str, str, Any]] = []  # (condition, model, mapping) unrotated
    if calibration is not None:
        if models is None or not hasattr(calibration, "markers"):
            m = _mapping_of(calibration)
            conditions.append((m.model.upper(), m.model, m))
        else:
            for model in models:
                c = refit(calibration, str(model).lower())
                conditions.append((c.model.upper(), c.model, c.mapping))
        if hasattr(calibration, "image_shape"):
            check_calibration_shape(calibration, shape, "frames")

    def find(mapping: Any) -> Wall:
        fields = []
        for a, b in frames:
            if mapping is not None:
                a, b = dewarp(a, mapping), dewarp(b, mapping)
            a = np.ascontiguousarray(a[r0:r1])
            b = np.ascontiguousarray(b[r0:r1])
            f = piv(a, b, passes, overlap=overlaps)
            fields.append(dataclasses.replace(f, y=f.y + r0))
        return find_wall(fields, band=band_t, stations=stations, iterations=iterations,
                         reject=reject)  # fmt: skip

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    say("distorted")
    rows = [WallRow("distorted", None, 0.0, find(None))]
    mappings: dict[str, Any] = {}
    for name, model, m in conditions:
        say(name)
        w = find(m)
        rows.append(WallRow(name, model, 0.0, w))
        mappings[name] = m
        rot = w.rotation_deg
        mr = m.rotated(rot)
        say(f"{name} + rotation ({rot:+.5f} deg)")
        rows.append(WallRow(f"{name} + rotation", model, rot, find(mr)))
        mappings[f"{name} + rotation"] = mr
    return WallTable(rows=tuple(rows), mappings=mappings)
