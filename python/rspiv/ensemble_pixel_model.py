"""The single-pixel rows' two wall-normal biases, measured and removed (used by
:meth:`rspiv.ensemble.PixelAccumulator.result`).

A single-pixel row sees the particles whose images overlap it: those within about one image
width ``s`` (the image's standard deviation across the row, ``s^2 = auto_yy / 2``) of the row.
Its summed cross peak is the mixture of their displacements, each weighted by its image's
intensity at the row. Two things follow.

1. **Where the row measures** (its effective height). Away from the wall the particles lie
   evenly on both sides of the row and it measures at its own distance ``d``. Within about two
   image widths of the wall the particles beyond the wall are missing (and their reflection is
   masked), so the row sees particles farther out on average: +15 % at 0.75 px and +60 % at 0.5
   px on the synthetic layer. The same particles make the row's *auto*-correlation peak: its
   wall-normal centre is their mean offset from the row (the mirror of the cross peak's
   weighting), so ``d_eff = d + (the auto peak's centre, toward the flow)`` is measured from the
   data, with no model. The row's value is reported at ``d_eff``.
2. **How the peak fit reads the mixture** (the fit bias). The particles of a row move with
   ``U(t) + u'`` at their own height ``t``; next to a wall both the mean and the fluctuations
   grow with ``t`` (``U ~ t``, ``u_rms ~ t``), so the mixture is the product of two spreads,
   skewed toward the fast side, and the Gaussian fit sits on its mode, below its mean: -2.5 to
   -4 % of ``U`` for y+ < 5 on the synthetic layer at every distance (the expected planes of
   ideal Gaussian images reproduce it, -3.6 % at 3 px, while their first moment is exact to
   0.1 %). :func:`fit_bias` builds each row's expected planes from the measured profile (the
   rows' ``u`` at ``d_eff``, the stresses ``uu, vv, uv``, smoothed, and the image widths from
   the auto peaks), fits them with the same fit as the data, and returns the fit's offset from
   the model's own mean at the model's own ``d_eff``; three fixed-point passes (the profile
   corrected each time). The rows within two image widths of the wall, where the masked pixels
   beyond it are not modelled, take the relative bias of the first row outside: in the viscous
   sublayer ``U`` and ``u_rms`` both scale with ``t``, so the relative skew does not depend on
   the distance (the ideal planes: -3.6 to -4.1 % from 0.5 to 2 px).

Measured (``tests/test_ensemble.py``, the synthetic layer at scale 0.1: viscous length 1.49 px,
2.5 px images, reflection 0.5): against the realisations' exact mean at ``d_eff``, 400 pairs
read within 1.35 % for 0.5 <= y+ <= 5 (before: -4.5 % to +17 % at ``d``), four sets of 160
pairs within 1.2-2.6 %; with 40 pairs the random error of a row is itself 2-4 %. Not robust
within two image widths of the wall: with the wall 0.08 px into a pixel (masked) instead of
0.32 px past the centre of one (kept), the rows 0.5-1.25 px out read -2 to -6.8 % (the auto
peak of a row whose strip reaches the masked rows is cut by them and puts the row up to 0.08 px
too far out); from y+ 1 on the rows stay within 1 %. See
:class:`rspiv.ensemble.PixelAccumulator`.

Units: px (distances and displacements per pair), px^2 (stresses). Distance coordinates: ``d``
into the flow from the wall; a positive pixel lag ``sy`` is toward the wall when the flow is
"above" it (pixel y smaller), away from it when "below".
"""

from __future__ import annotations

import numpy as np

from rspiv import _rspiv

__all__ = ["effective_distance", "fit_bias", "smooth"]

#: Gauss-Hermite nodes for the streamwise and the independent wall-normal fluctuation.
_NODES_U, _NODES_V = 9, 5
#: Quadrature step over particle heights (px) and reach (image widths) on each side of a row.
_DT, _REACH = 0.05, 4.0
#: The model's regime: a modelled row's mean displacement of at least 0.1 px, and a bias of at
#: most 10 % of it (the synthetic layer's is 0.5-4 %); other rows are left as fitted.
_MIN_U, _MAX_REL = 0.1, 0.10


def effective_distance(dist: np.ndarray, auto_dy: np.ndarray, flow_side: str) -> np.ndarray:
    """The rows' effective wall distances (px): ``dist`` moved by the auto peak's wall-normal
    centre ``auto_dy`` (pixel lag; toward the flow is ``-y`` for a flow "above" the wall)."""
    sign = -1.0 if flow_side == "above" else 1.0
    return np.asarray(dist, dtype=np.float64) + sign * np.asarray(auto_dy, dtype=np.float64)


def smooth(x: np.ndarray, y: np.ndarray, h: float) -> np.ndarray:
    """Local linear regression of ``y`` on ``x`` at each ``x``, Gaussian kernel of width ``h``
    (a row's stresses from 40 pairs scatter by +-20 %; the fit bias follows their slope)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    dx = x[None, :] - x[:, None]
    w = np.exp(-0.5 * (dx / h) ** 2)
    s0, s1, s2 = w.sum(axis=1), (w * dx).sum(axis=1), (w * dx * dx).sum(axis=1)
    t0, t1 = w @ y, (w * dx) @ y
    det = s0 * s2 - s1 * s1
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (s2 * t0 - s1 * t1) / det
    return np.where(np.abs(det) > 1e-12 * s0 * s0, out, t0 / s0)


def _outer_slope(y: np.ndarray, v: np.ndarray, h: float) -> float:
    """The slope of ``v(y)`` over the outermost ``3 h`` of the rows (0 with a single row)."""
    sel = y >= y[-1] - 3.0 * h
    if sel.sum() < 2 or np.ptp(y[sel]) <= 0:
        return 0.0
    return float(np.polyfit(y[sel], v[sel], 1)[0])


def _gauss_hermite(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.hermite_e.hermegauss(n)
    return x, w / w.sum()


def model_planes(
    d: np.ndarray,
    du: np.ndarray,
    profile: dict[str, np.ndarray],
    s2: tuple[float, float],
    lags: tuple[int, int],
) -> np.ndarray:
    """Expected single-pixel accumulator rows (:func:`rspiv._rspiv.pixel_stride` values each)
    for rows at distances ``d`` with predictors ``du``: Gaussian particle images of variances
    ``s2 = (sx^2, sy^2)``, particles uniform in ``t > 0``, moving with the ``profile``
    (``y``, ``u``, ``uu``, ``vv``, ``uv`` sampled at increasing ``y``, linear in between; ``v``
    into the flow). The planes are laid out as for a flow "above" the wall (a positive lag
    toward it); only their fits are used, each against its own model."""
    rx, ry = lags
    lx, ly = np.arange(-rx, rx + 1.0), np.arange(-ry, ry + 1.0)
    npl = lx.size * ly.size
    g1, w1 = _gauss_hermite(_NODES_U)
    g2, w2 = _gauss_hermite(_NODES_V)
    sx2, sy2 = s2
    sy = np.sqrt(sy2)
    yp = profile["y"]
    out = np.zeros((d.size, 2 * npl + 2))
    exa = np.exp(-(lx**2) / (4 * sx2))
    for k in range(d.size):  # rows of a profile (tens to hundreds), each vectorised
        t = np.arange(max(_DT / 2, d[k] - _REACH * sy), d[k] + _REACH * sy, _DT)
        wt = np.exp(-((d[k] - t) ** 2) / (2 * sy2))  # the A row's share of each height
        mean = np.interp(t, yp, profile["u"])
        su = np.sqrt(np.maximum(np.interp(t, yp, profile["uu"]), 0.0))
        l21 = np.interp(t, yp, profile["uv"]) / np.where(su > 0, su, 1.0) * (su > 0)
        l22 = np.sqrt(np.maximum(np.interp(t, yp, profile["vv"]) - l21**2, 0.0))
        shape = (t.size, g1.size, g2.size)
        cx = mean[:, None, None] + su[:, None, None] * g1[None, :, None] - du[k]
        v = l21[:, None, None] * g1[None, :, None] + l22[:, None, None] * g2[None, None, :]
        cy = d[k] - t[:, None, None] - v  # the B image's lag: its distance is d - sy
        w = wt[:, None, None] * w1[None, :, None] * w2[None, None, :]
        cx, cy, w = (np.broadcast_to(a, shape).ravel() for a in (cx, cy, w))
        ex = np.exp(-((lx[None, :] - cx[:, None]) ** 2) / (4 * sx2))
        ey = np.exp(-((ly[None, :] - cy[:, None]) ** 2) / (2 * sy2))
        cross = np.einsum("n,nr,nc->rc", w, ey, ex)
        eya = np.exp(-((ly[None, :] - (d[k] - t)[:, None]) ** 2) / (2 * sy2))
        auto = np.outer(wt @ eya, exa)
        out[k, :npl] = (cross / cross.max()).ravel()
        out[k, npl : 2 * npl] = (auto / auto.max()).ravel()
        out[k, 2 * npl :] = 1.0
    return out


def fit_bias(
    dist: np.ndarray,
    d_eff: np.ndarray,
    du: np.ndarray,
    u: np.ndarray,
    stresses: tuple[np.ndarray, np.ndarray, np.ndarray],
    auto: np.ndarray,
    ok: np.ndarray,
    lags: tuple[int, int],
    passes: int = 3,
) -> np.ndarray:
    """The Gaussian fit's bias on each row's ``u`` (px; subtract it), see the module docs.

    ``dist``/``d_eff``: the rows' distances and effective distances (px), ``du``: their mean
    predictors, ``u``: the fitted displacements, ``stresses``: ``(uu, vv, uv)`` (px^2, ``v``
    into the flow: the pixel frame's ``-uv`` for a flow "above" the wall),
    ``auto``: the auto peaks' ``(xx, yy, xy)`` covariances, ``ok``: the rows to use. NaN for
    the rows it cannot model (failed fits, no row beyond two image widths, a mean under 0.1 px
    or a modelled bias over 10 % at the row or the nearest modelled one)."""
    bias = np.full(dist.shape, np.nan)
    ok = ok & np.isfinite(u) & np.isfinite(d_eff) & np.all(np.isfinite(auto[:, :2]), axis=1)
    if ok.sum() < 3:
        return bias
    sy_all = np.sqrt(np.median(auto[ok, 1]) / 2.0)
    clear = ok & (dist > 3.0 * sy_all)  # rows whose auto peaks the wall does not cut
    if not clear.any():
        return bias
    s2 = (float(np.median(auto[clear, 0])) / 2.0, float(np.median(auto[clear, 1])) / 2.0)
    h = np.sqrt(2.0 * s2[1])  # the auto peak's own width
    use = ok & (dist >= 2.0 * np.sqrt(s2[1]))
    if not use.any():
        return bias
    order = np.argsort(d_eff[ok])
    y = d_eff[ok][order]
    # the wall (all zero) first; past the outermost row, the profile continued linearly over
    # the model's reach
    far_y = y[-1] + (_REACH + 1.0) * np.sqrt(s2[1])

    def extend(v: np.ndarray) -> np.ndarray:
        v = smooth(y, v, h)
        return np.r_[0.0, v, v[-1] + _outer_slope(y, v, h) * (far_y - y[-1])]

    st = [extend(s[ok][order]) for s in stresses]
    y = np.r_[0.0, y, far_y]
    profile = {"y": y, "uu": np.maximum(st[0], 0.0), "vv": np.maximum(st[1], 0.0), "uv": st[2]}
    near = ok & ~use  # inside two image widths: the nearest modelled row's (module docs)
    nearest = int(np.flatnonzero(use)[np.argmin(dist[use])])
    rel = np.zeros(dist.shape)
    for _ in range(passes):
        uc = (u / (1.0 + np.nan_to_num(rel)))[ok][order]
        slope = _outer_slope(y[1:-1], uc, h)
        profile["u"] = np.r_[0.0, uc, uc[-1] + slope * (far_y - y[-2])]
        planes = model_planes(dist[use], du[use], profile, s2, lags)
        pk = _rspiv.pixel_peaks(np.ascontiguousarray(planes), lags)
        model_u = du[use] + np.asarray(pk["dx"])
        want = np.interp(dist[use] - np.asarray(pk["ady"]), profile["y"], profile["u"])
        with np.errstate(invalid="ignore", divide="ignore"):
            r = model_u / want - 1.0
        # outside the model's regime (a shear flow along the wall: a resolved mean, a bias of
        # a few per cent) the row is left as fitted
        fits = np.asarray(pk["ok"], dtype=bool) & (np.abs(want) >= _MIN_U) & (np.abs(r) <= _MAX_REL)
        r = np.where(fits, r, np.nan)
        good = np.isfinite(r)
        if good.sum() >= 2:
            r[good] = smooth(dist[use][good], r[good], h)
        rel = np.full(dist.shape, np.nan)
        rel[use] = r
        rel[near] = rel[nearest]
    out = u * rel / (1.0 + rel)
    bias[ok] = out[ok]
    return bias
