"""Single-pixel ensemble correlation along rows at a wall (Westerweel, Geelhoed & Lindken 2004;
Kähler, Scholz & Ortmanns 2006): :class:`PixelAccumulator` and :func:`pixel_band`, exported by
:mod:`rspiv.ensemble` too. The work per pixel runs in Rust (``piv_core::ensemble_pixel``); the
accumulator is a NumPy array this module owns, so shards and workers merge by adding it.
Coordinates: the pixel frame of the README (x = column, y = row, y down); displacements px per
pair, stresses px^2.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.ensemble_pixel_model import WallGeometry, effective_distance, fit_bias
from rspiv.errors import InvalidInputError
from rspiv.settings import INTERPOLATIONS, parse_choice

#: A row's summed cross peak must stand this many times above its plane's next local maximum
#: (3, ``piv_core::ensemble::MIN_PEAK_RATIO``, which the fit applies): on the synthetic layer
#: 21 or more with 40 pairs (2 with a single pair), for frames of noise 1.9 at most.
MIN_PEAK_RATIO: float = _rspiv.ENSEMBLE_MIN_PEAK_RATIO

__all__ = ["PixelAccumulator", "SaturationTally", "pixel_band", "segment_centres"]


def segment_centres(x0: float, seg: int, nseg: int) -> np.ndarray:
    """The centre x (px) of ``nseg`` segments of ``seg`` px, the first pixel centre at ``x0``."""
    return x0 + (np.arange(nseg) + 0.5) * seg - 0.5


class SaturationTally:
    """Per row (or window) of a band: the summed fraction of its pixels saturated in the raw
    frames over the pairs reported (:meth:`add`), so that the rows whose particle images are
    clipped (a glare line, overexposure) can be flagged; merges by adding."""

    def __init__(self, n: int) -> None:
        self.sum = np.zeros(int(n))
        self.pairs = 0

    def add(self, fraction: Any) -> None:
        """One pair's fraction (0-1) per row."""
        f = np.asarray(fraction, dtype=np.float64).ravel()
        if f.size != self.sum.size or not np.all((f >= 0) & (f <= 1)):
            raise InvalidInputError(
                f"saturation: {f.size} fractions for {self.sum.size} rows, each in 0..1"
            )
        self.sum += f
        self.pairs += 1

    def merge(self, other: SaturationTally) -> None:
        self.sum += other.sum
        self.pairs += other.pairs

    def mean(self) -> np.ndarray:
        """The mean fraction per row (0 before any pair)."""
        return self.sum / max(self.pairs, 1)

    def to_arrays(self) -> dict[str, Any]:
        return {"saturated": self.sum, "saturation_pairs": int(self.pairs)}

    @classmethod
    def from_arrays(cls, d: dict[str, Any], n: int) -> SaturationTally:
        """From :meth:`to_arrays`' keys in ``d`` (empty when absent: older states)."""
        out = cls(n)
        if d.get("saturated") is not None:
            out.sum = np.array(d["saturated"], dtype=np.float64).reshape(n)
            out.pairs = int(d["saturation_pairs"])
        return out


def _wall_y(wall: Any, x: np.ndarray) -> np.ndarray:
    """The wall's pixel y at ``x``: ``wall`` is a float (a level wall), a callable, or an
    object with ``line(x)`` (:class:`rspiv.Wall`)."""
    if hasattr(wall, "line"):
        return np.asarray(wall.line(x), dtype=np.float64)
    if callable(wall):
        return np.asarray(wall(x), dtype=np.float64) + 0.0 * x
    return np.full(np.shape(x), float(wall))


class PixelAccumulator:
    """Single-pixel ensemble correlation along rows (``piv_core::ensemble_pixel``): each row's
    pixels of frame A correlated with the rows of frame B around it, summed over the pairs and
    along the row, so that the wall-normal resolution is one pixel (the particle image's own
    size), not a window's height (Westerweel, Geelhoed & Lindken 2004; Kähler, Scholz &
    Ortmanns 2006).

    Parameters
    ----------
    y : array_like, shape (rows, nseg)
        The y (px, pixel frame; fractional allowed) of each row's segments: a row may follow a
        tilted wall, one y per segment.
    seg : int
        Segment length along x, px (>= 8); segment ``j`` covers the pixel centres
        ``x0 + j seg .. x0 + j seg + seg - 1``.
    x0 : float
        The first segment's first pixel centre, px.
    offset : (array_like, array_like)
        ``(du, dv)`` per segment (the shape of ``y``), px: the predictor (frame A sampled at
        ``p - d/2``, B at ``p + d/2``).
    lags : (int, int)
        Lag half-ranges ``(rx, ry)`` around the predictor (>= 1); the residual displacement
        and the fluctuations must lie well inside them.
    interpolation : {"bspline", "bspline3", "keys"}
    wall : (wall, str), optional
        ``(wall, flow_side)``: the wall line as :func:`pixel_band` takes it (a float, a
        callable of x or an object with ``line(x)``) and the side holding the flow
        ("above"/"below"). The pixels beyond the wall, where the reflection's mirror images
        are, are then set to the frames' background (the median of the rest of the band's rows)
        before the pair is added: see Notes.

    Notes
    -----
    :meth:`result` gives per row ``u, v`` (the segments' mean predictor plus the summed peak's
    centre, px) and ``uu, vv, uv`` (the cross peak's covariance less the auto peaks', px^2).
    With a ``wall``, each row is reported where it measures (``dist_eff``: its distance moved by
    the auto peak's wall-normal centre, the mean offset of the particles it sees) and ``u`` has
    the Gaussian fit's bias removed, modelled from the measured profile
    (:mod:`rspiv.ensemble_pixel_model`). Measured on the synthetic boundary layer
    (``tests/test_ensemble.py``: 2.5 px particles, reflection 0.5, viscous length 1.49 px, the
    exact wall and profile as predictor) against the realisations' exact mean at ``dist_eff``:

    - 160 pairs: within 1.62 % from y+ 0.5 to 5 (mean |error| 0.58 %; three other sets
      1.26-1.58 %); 40 pairs: 1.1-4.9 % over eight sets (the random error of the rows next to
      the wall).
    - Next to the wall (within three image widths) the planes depend on where the wall falls
      within its pixel; those rows are modelled on the pixel grid (masked pixels, mirror
      images, the interpolation across the cut; the image width and the reflection
      calibrated from the data, ``wall_image``), alike with the wall 0.32 px past the centre
      of the pixel it crosses (the figures above) or 0.08 px into a masked one (five sets of
      160-320 pairs: within 1.7-2.1 %; before that model -6.8 % at y+ 0.7). The model
      assumes the wall where ``wall`` says: a wall found 0.24 px off left the row 0.25 px
      out, measuring at y+ 0.39, 8.9 % high in the campaign's test (the rows from y+ 0.5
      within 3 %). ``near_wall`` flags the rows within two image widths. The model is
      validated for the B-spline interpolations; with ``"keys"`` (its sub-pixel shift bias of
      a few 0.01 px, 5-15 % of the displacement next to the wall, is not modelled) the near
      rows take the nearest modelled row's relative bias instead and read to within about 7 %
      (60 pairs); making such a band warns, and the campaign uses ``"bspline"`` for its rows
      when its PIV uses Keys.
    - Before the correction, at each row's own distance: +22 % at 0.5 px (the particle images
      cut by the wall: the slow particles next to it are missing), -1 to -3.5 % from 1 to 8 px
      (the fit's bias: the summed peak is the mixture of the particles over the image's height,
      whose mean and spread both grow with their distance; the Gaussian fit sits on its mode,
      below its mean). ``u_fit`` and ``fit_bias`` keep both.
    - Without ``wall`` the rows 1-3 px out read -14 to -1 %: each particle's mirror image in
      frame B makes a ghost peak ``2 d`` toward the wall, tilted the other way by the shear,
      that pulls the fit toward the slow particles (or, where it rivals the true peak, leaves
      the row ``weak``); masking the pixels beyond the wall removes all but the mirror
      images' tails. Nothing is moved or corrected then.
    - A row whose summed cross peak does not stand :data:`MIN_PEAK_RATIO` times above the
      plane's next local maximum (``piv_core::ensemble::peak_ratio``) is ``weak`` and not
      ``ok``: frames of noise alone give no
      row (their ratio 1.9 at most), the synthetic layer 21 or more with 40 pairs.

    The wall-normal variance next to the wall (within about 2 px) comes out negative or too
    small: the auto peak there holds the mirror images' tails too.
    """

    def __init__(
        self,
        y: Any,
        seg: int,
        x0: float,
        offset: tuple[Any, Any],
        lags: tuple[int, int] = (8, 3),
        interpolation: str = "bspline",
        wall: tuple[Any, str] | None = None,
    ) -> None:
        self.y = np.ascontiguousarray(np.atleast_2d(np.asarray(y, dtype=np.float64)))
        self.seg, self.x0 = int(seg), float(x0)
        self.lags = (int(lags[0]), int(lags[1]))
        du, dv = (np.broadcast_to(np.asarray(o, dtype=np.float64), self.y.shape) for o in offset)
        self.du, self.dv = np.ascontiguousarray(du), np.ascontiguousarray(dv)
        self.interpolation = parse_choice(interpolation, INTERPOLATIONS, "interpolation")
        if wall is not None and self.interpolation == "keys":
            warnings.warn(
                "single-pixel rows with Keys interpolation: its sub-pixel shift bias is not "
                "modelled, the rows next to the wall read only to within about 7 % (synthetic "
                "layer, 60 pairs); 'bspline' is modelled to within about 2 %",
                UserWarning,
                stacklevel=2,
            )
        stride = _rspiv.pixel_stride(*self.lags)
        self.acc = np.zeros((self.y.shape[0], stride), dtype=np.float64)
        self.pairs = 0
        #: per row, the fraction of its pixels saturated in the raw frames (a campaign adds it
        #: per pair)
        self.saturation = SaturationTally(self.y.shape[0])
        #: the wall as ``(flow_side, x, y)``: its pixel y sampled at every column the strips
        #: can reach (linear in between, constant beyond), or None
        self.wall: tuple[str, np.ndarray, np.ndarray] | None = None
        if wall is not None:
            side = parse_choice(wall[1], ("above", "below"), "flow_side")
            reach = self.x0 + self.y.shape[1] * self.seg + self.lags[0] + np.abs(self.du).max()
            xs = np.arange(0.0, np.ceil(reach) + 3.0)
            self._set_wall(side, xs, _wall_y(wall[0], xs))

    def _set_wall(self, side: str, xs: np.ndarray, ys: np.ndarray) -> None:
        xs, ys = (np.ascontiguousarray(t, dtype=np.float64).ravel() for t in (xs, ys))
        at = np.interp(self.segment_x(), xs, ys) if xs.size == ys.size and xs.size else None
        if at is None or not np.all(np.isfinite(ys)):
            raise InvalidInputError("single-pixel band: the wall line is not finite")
        beyond = (self.y >= at) if side == "above" else (self.y <= at)
        if np.any(beyond):
            raise InvalidInputError(
                f"single-pixel band: a row lies on or beyond the wall (flow {side} it)"
            )
        self.wall = (side, xs, ys)

    def _wall_geometry(self, samples: int = 8) -> WallGeometry:
        """The rows on the pixel grid next to the wall (:class:`WallGeometry`): at up to
        ``samples`` columns per row (one for a wall level with the pixel rows and rows at one
        height), chosen at the quantiles of the wall's position within its pixel."""
        assert self.wall is not None
        side, xs, ys = self.wall
        rows, nseg = self.y.shape
        cols = self.x0 + np.arange(nseg * self.seg, dtype=np.float64)
        wy = np.interp(cols, xs, ys)
        yr = self.y[:, np.arange(cols.size) // self.seg]
        dist = wy[None, :] - yr if side == "above" else yr - wy[None, :]
        # the first pixel kept on the flow's side (``_without_reflection``): floor / ceil
        phase = wy - np.floor(wy) if side == "above" else np.ceil(wy) - wy
        if np.ptp(phase) < 0.01 and np.ptp(dist, axis=1).max() < 0.01:
            pick = np.array([cols.size // 2])
        else:
            ranks = np.argsort(phase, kind="stable")
            pick = ranks[((np.arange(samples) + 0.5) * cols.size / samples).astype(int)]
        rx, ry = self.lags
        npl = (2 * rx + 1) * (2 * ry + 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            auto = self.acc[:, npl : 2 * npl] / self.acc[:, 2 * npl + 1 : 2 * npl + 2]
        auto = auto.reshape(rows, 2 * ry + 1, 2 * rx + 1)
        return WallGeometry(
            dist=np.ascontiguousarray(dist[:, pick]),
            phase=np.broadcast_to(phase[pick], (rows, pick.size)).copy(),
            interpolation=self.interpolation,
            # the model's lags as for a flow "above" the wall: positive toward it
            auto=np.ascontiguousarray(auto if side == "above" else auto[:, ::-1, :]),
        )

    def segment_x(self) -> np.ndarray:
        """The centre x of each segment (px), shape ``(nseg,)``."""
        return segment_centres(self.x0, self.seg, self.y.shape[1])

    def _without_reflection(self, frames: list[np.ndarray], mask: Any) -> tuple[Any, ...]:
        """The band's rows of the frames (with ``ry + 6`` px of margin) with the pixels beyond
        the wall set to the median of the others, the mask cut alike, and the rows' offset."""
        assert self.wall is not None
        side, xs, ys = self.wall
        rows, cols = frames[0].shape
        ry = self.lags[1]
        r0 = max(0, int(np.floor(self.y.min())) - ry - 6)
        r1 = min(rows, int(np.ceil(self.y.max())) + ry + 7)
        wy = np.interp(np.arange(cols, dtype=np.float64), xs, ys)
        off = np.arange(r0, r1, dtype=np.float64)[:, None] - wy[None, :]
        beyond = off > 0 if side == "above" else off < 0
        out = []
        for f in frames:
            crop = np.array(f[r0:r1], copy=True)
            if beyond.any() and not beyond.all():
                crop[beyond] = np.median(crop[~beyond])
            out.append(crop)
        m = None if mask is None else mask[r0:r1]
        return out[0], out[1], m, r0

    def to_arrays(self) -> dict[str, Any]:
        """The whole state as named arrays and scalars (:meth:`from_arrays` restores it
        exactly; e.g. into a shard's NetCDF file)."""
        out: dict[str, Any] = {
            "sum": self.acc,
            "y": self.y,
            "du": self.du,
            "dv": self.dv,
            "seg": int(self.seg),
            "x0": float(self.x0),
            "lags": np.asarray(self.lags, dtype=np.int64),
            "pairs": int(self.pairs),
            "interpolation": self.interpolation,
            **self.saturation.to_arrays(),
        }
        if self.wall is not None:
            out.update(wall_side=self.wall[0], wall_x=self.wall[1], wall_y=self.wall[2])
        return out

    @classmethod
    def from_arrays(cls, d: dict[str, Any]) -> PixelAccumulator:
        """An accumulator restored from :meth:`to_arrays` (InvalidInputError if the sums do
        not fit the rows)."""
        rx, ry = (int(t) for t in np.asarray(d["lags"]).ravel())
        out = cls(
            d["y"],
            int(d["seg"]),
            float(d["x0"]),
            (d["du"], d["dv"]),
            lags=(rx, ry),
            interpolation=str(d["interpolation"]),
        )
        if d.get("wall_side") is not None:
            out._set_wall(str(d["wall_side"]), d["wall_x"], d["wall_y"])
        s = np.asarray(d["sum"], dtype=np.float64)
        if s.shape != out.acc.shape:
            raise InvalidInputError(
                f"single-pixel sums of shape {s.shape} do not fit {out.acc.shape[0]} rows of "
                f"lags +-{rx} x +-{ry}"
            )
        out.acc = np.array(s)
        out.pairs = int(d["pairs"])
        out.saturation = SaturationTally.from_arrays(d, out.y.shape[0])
        return out

    def add(self, frame_a: Any, frame_b: Any, mask: Any = None, auto: bool = True) -> int:
        """Add one pair (2D arrays of one dtype); the auto planes too when ``auto``. Returns the
        segments added (masked, outside the image or blank ones are left out)."""
        m = None if mask is None else np.ascontiguousarray(mask, dtype=bool)
        fa, fb, y = np.asarray(frame_a), np.asarray(frame_b), self.y
        if self.wall is not None and fa.ndim == 2 and fa.shape == fb.shape:
            if m is not None and m.shape != fa.shape:
                raise InvalidInputError(
                    f"the mask is {m.shape[1]} x {m.shape[0]} px, the frames "
                    f"{fa.shape[1]} x {fa.shape[0]} px"
                )
            fa, fb, m, r0 = self._without_reflection([fa, fb], m)
            y = self.y - r0
        n = _rspiv.pixel_add(
            np.ascontiguousarray(fa),
            np.ascontiguousarray(fb),
            self.seg,
            self.y.shape[1],
            self.x0,
            self.lags,
            np.ascontiguousarray(y).ravel(),
            self.du.ravel(),
            self.dv.ravel(),
            self.acc,
            auto=auto,
            mask=m,
            interpolation=self.interpolation,
        )
        self.pairs += 1
        return int(n)

    def merge(self, other: PixelAccumulator) -> PixelAccumulator:
        """Add another accumulator of the same band into this one."""
        same = (
            self.seg == other.seg
            and self.x0 == other.x0
            and self.lags == other.lags
            and np.array_equal(self.y, other.y)
            and np.array_equal(self.du, other.du)
            and np.array_equal(self.dv, other.dv)
            and (self.wall is None) == (other.wall is None)
            and (
                self.wall is None
                or (
                    other.wall is not None
                    and self.wall[0] == other.wall[0]
                    and np.array_equal(self.wall[1], other.wall[1])
                    and np.array_equal(self.wall[2], other.wall[2])
                )
            )
        )
        if not same:
            raise InvalidInputError("single-pixel accumulators of different bands cannot merge")
        self.acc += other.acc
        self.pairs += other.pairs
        self.saturation.merge(other.saturation)
        return self

    def result(self) -> dict[str, np.ndarray]:
        """Per row: ``u, v`` (px), ``uu, vv, uv`` (px^2), ``cross``, ``auto`` (the peaks'
        fitted covariances ``(xx, yy, xy)``), ``auto_centre`` (the auto peak's centre, px lags),
        ``count`` (segments summed), ``coef`` (the mean normalised cross plane's maximum:
        0.75-0.86 on the synthetic layer, 0.03 for frames of noise alone), ``peak_ratio``
        (of the summed cross plane, ``piv_core::ensemble::peak_ratio``), ``weak`` (a peak
        under :data:`MIN_PEAK_RATIO`: no clear peak, not ``ok``, its values NaN), ``ok``;
        with a ``wall``, ``dist`` (the row's mean distance
        from it, px), ``dist_eff`` (where the row measures, px; see Notes), ``u`` less
        ``fit_bias`` (``u_fit``: before; ``corrected``: the rows the model reached; the rows
        within three image widths by the wall model, ``wall_image``: its image standard
        deviation, px, and reflection, NaN when not used) and ``near_wall``: the rows within
        two particle-image row widths of the wall (the width ``sqrt(auto_yy / 2)``, the median
        over the rows), which measure farther out than they lie; without one, ``dist`` and
        ``dist_eff`` are NaN, ``near_wall`` and ``corrected`` False, ``u`` the fit.
        ``saturated``: the mean fraction of each row's pixels
        reported saturated (``saturation``; 0 when nothing was reported).

        ``uu`` and ``uv`` have the mean gradient across the particle image removed: a row sees
        the particles over the image's height ``s`` (``s^2 = auto_yy / 2``), each moving with
        the mean displacement at its own y, which adds ``(du/dy)^2 s^2`` to the peak's x
        variance and ``(du/dy) s^2`` to its covariance (``du/dy`` from the rows' own ``u``;
        none with a single row). ``uu_raw``, ``uv_raw``: before. ``vv`` keeps its term
        ``((1 + dv/dy)^2 - 1) s^2``: ``dv/dy`` is about 0 along a wall, and the rows next to it
        do not measure it. Measured on the synthetic layer, rows 2.25-7 px from the wall
        against the pairs' sample variance: ``uu`` within +-12 % (60 pairs) and +-22 % (40
        pairs, ``tests/test_ensemble.py``) where the raw value reads up to 60-70 % high next to
        the wall; the correction undershoots from about 4 px out (-9 to -22 % where the raw
        value is within +-16 %): the fitted peak's width does not grow by the whole second
        moment there. ``uv`` from -0.3 to -0.4 px^2 (truth 0.00 to +0.08) to -0.09 to +0.03."""
        d = _rspiv.pixel_peaks(self.acc, self.lags)
        ok = np.asarray(d["ok"], dtype=bool)
        ratio = np.asarray(d["peak_ratio"])
        weak = ratio < MIN_PEAK_RATIO  # NaN (no segment summed) is not weak
        cross = np.stack([d["cxx"], d["cyy"], d["cxy"]], axis=-1)
        auto = np.stack([d["axx"], d["ayy"], d["axy"]], axis=-1)
        cov = cross - auto
        u = np.where(ok, self.du.mean(axis=1) + d["dx"], np.nan)
        rows = ok & np.isfinite(u) & np.isfinite(auto[:, 1])
        grad = np.zeros(self.y.shape[0])
        if rows.sum() >= 2:
            ym = self.y.mean(axis=1)
            grad[rows] = np.gradient(u[rows], ym[rows])
        s2 = float(np.median(auto[rows, 1])) / 2.0 if rows.any() else 0.0
        dist = np.full(self.y.shape[0], np.nan)
        near = np.zeros(self.y.shape[0], dtype=bool)
        uu, uv = cov[:, 0] - grad**2 * s2, cov[:, 2] - grad * s2
        u_fit, bias = u, np.full(u.shape, np.nan)
        image: tuple[float, float] | None = None
        ady = np.asarray(d["ady"])
        d_eff = np.full(u.shape, np.nan)
        if self.wall is not None:
            side, xs, ys = self.wall
            at = np.interp(self.segment_x(), xs, ys)
            dist = np.mean(at[None, :] - self.y if side == "above" else self.y - at, axis=1)
            near = dist < 2.0 * (np.sqrt(s2) if rows.any() else np.inf)
            d_eff = effective_distance(dist, ady, side)
            into_flow = -1.0 if side == "above" else 1.0  # v into the flow, from pixel v
            bias, image = fit_bias(
                dist, d_eff, self.du.mean(axis=1), u_fit, (uu, cov[:, 1], into_flow * uv),
                auto, rows, self.lags, wall=self._wall_geometry(),
            )  # fmt: skip
        corrected = np.isfinite(bias)
        return {
            "dist": dist,
            "dist_eff": d_eff,
            "near_wall": near,
            "saturated": self.saturation.mean(),
            "u": np.where(corrected, u_fit - bias, u_fit),
            "u_fit": u_fit,
            "fit_bias": bias,
            "corrected": corrected,
            "wall_image": np.array(image if image is not None else (np.nan, np.nan)),
            "v": np.where(ok, self.dv.mean(axis=1) + d["dy"], np.nan),
            "uu": uu,
            "vv": cov[:, 1],
            "uv": uv,
            "uu_raw": cov[:, 0],
            "uv_raw": cov[:, 2],
            "gradient": grad,
            "cross": cross,
            "auto": auto,
            "auto_centre": np.stack([np.asarray(d["adx"]), ady], axis=-1),
            "count": np.asarray(d["count"]),
            "coef": np.asarray(d["coef"]),
            "peak_ratio": ratio,
            "weak": weak,
            "ok": ok,
        }


def pixel_band(
    shape: tuple[int, int],
    seg: int,
    dist: Any,
    wall: Any,
    flow_side: str = "above",
    lags: tuple[int, int] = (8, 3),
    margin_x: int = 8,
) -> tuple[np.ndarray, float, np.ndarray]:
    """The rows of a single-pixel band along a wall: row ``k`` at wall distance ``dist[k]`` (px,
    into the flow), following the wall line segment by segment, segments of ``seg`` px from
    ``margin_x`` px in from the image's sides.

    Returns ``(y, x0, d)``: ``y`` of shape (rows, nseg) for :class:`PixelAccumulator`, the first
    pixel centre ``x0``, and ``d`` the rows' distances. ``margin_x`` must also hold half the
    predictor's displacement, else the end segments reach outside and are left out.
    InvalidInputError when a row's strips (its lags around it) leave the image.
    """
    rows, cols = (int(s) for s in shape)
    d = np.asarray(dist, dtype=np.float64).ravel()
    rx, ry = (int(t) for t in lags)
    x0 = float(max(int(margin_x), rx + 2))
    nseg = int((cols - 2 * x0) // int(seg))
    if nseg < 1 or d.size < 1 or not np.all(np.isfinite(d)):
        raise InvalidInputError(
            f"single-pixel band: no {seg} px segment fits the {cols} px wide image, or no finite "
            "row distance"
        )
    if flow_side not in ("above", "below"):
        raise InvalidInputError(f"flow_side must be 'above' or 'below', got {flow_side!r}")
    xc = segment_centres(x0, int(seg), nseg)
    sign = -1.0 if flow_side == "above" else 1.0
    y = _wall_y(wall, xc)[None, :] + sign * d[:, None]
    margin = ry + 3.0
    if np.min(y) < margin or np.max(y) > rows - 1 - margin:
        raise InvalidInputError(
            f"single-pixel band: rows {d.min():g}..{d.max():g} px from the wall leave the "
            f"{cols} x {rows} px image"
        )
    return np.ascontiguousarray(y), x0, d
