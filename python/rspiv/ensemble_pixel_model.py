"""The single-pixel rows' two wall-normal biases, measured and removed (used by
:meth:`rspiv.ensemble.PixelAccumulator.result`).

A single-pixel row sees the particles whose images overlap it: those within about one image
width ``s`` (the image's standard deviation across the row, ``s^2 = auto_yy / 2``) of the row.
Its summed cross peak is the mixture of their displacements, each weighted by its image's
intensity at the row. Three things follow.

1. **Where the row measures** (its effective height). Away from the wall the particles lie
   evenly on both sides of the row and it measures at its own distance ``d``. Within about two
   image widths of the wall the particles beyond the wall are missing (and their reflection is
   masked), so the row sees particles farther out on average: +22 % at 0.5 px on the synthetic
   layer. The same particles make the row's *auto*-correlation peak: its
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
   corrected each time).
3. **The rows next to the wall** (within three image widths): there the masked pixels beyond
   the wall, the mirror images' tails and the interpolation across the cut shape the planes,
   and how depends on where the wall falls within its pixel. :func:`model_planes_wall` builds
   their expected planes on the pixel grid itself: pixel-integrated Gaussian images of the
   particles (uniform in ``t > 0``) and of their mirror images, the pixels beyond the wall
   constant, the rows interpolated by the accumulator's own interpolant (:func:`cardinal`),
   the images' correlation along the row that of pixel-integrated Gaussians (:func:`along_row`),
   at the columns' wall phases (:class:`WallGeometry`; a tilted wall's are sampled). Its two
   parameters come from the data: the image's standard deviation from the far rows' auto
   peak width (the same fit on model and data), the reflection from the near rows' auto
   planes (least squares; 0.50-0.54 on the synthetic layer with 160 pairs, whose truth is
   0.5). This needs the accumulator's planes to be linear in the particles, which is why
   ``piv_core::ensemble_pixel`` normalises each pair's planes over the whole row. The row's
   bias is the model's fit less the model's mean where the model's auto peak puts it, as
   beyond.

Measured (``tests/test_ensemble.py``, the synthetic layer at scale 0.1: viscous length 1.49 px,
2.5 px images, reflection 0.5): against the realisations' exact mean at ``d_eff``, 160 pairs
read within 1.62 % for 0.5 <= y+ <= 5 (mean |error| 0.58 %), three other sets of 160 within
1.26-1.58 %; with the wall 0.08 px into a pixel (masked) instead of 0.32 px past the centre of
one (kept), five sets of 160-320 pairs within 1.7-2.1 % (before the wall model: -6.8 % at y+
0.7 with 40 pairs); with 40 pairs the rows next to the wall carry 2-5 % of random error (eight
sets: 1.1-4.9 %). See :class:`rspiv.ensemble.PixelAccumulator`.

Units: px (distances and displacements per pair), px^2 (stresses). Distance coordinates: ``d``
into the flow from the wall; a positive pixel lag ``sy`` is toward the wall when the flow is
"above" it (pixel y smaller), away from it when "below".
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import ndtr

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.settings import INTERPOLATIONS, parse_choice

__all__ = [
    "WallGeometry",
    "along_row",
    "cardinal",
    "effective_distance",
    "fit_bias",
    "model_planes_wall",
    "smooth",
    "wall_response",
]

#: Gauss-Hermite nodes for the streamwise and the independent wall-normal fluctuation.
_NODES_U, _NODES_V = 9, 5
#: Quadrature step over particle heights (px) and reach (image widths) on each side of a row.
_DT, _REACH = 0.05, 4.0
#: The model's regime: a modelled row's mean displacement of at least 0.1 px, and a bias of at
#: most 10 % of it (the synthetic layer's is 0.5-4 %); other rows are left as fitted.
_MIN_U, _MAX_REL = 0.1, 0.10
#: Rows closer to the wall than this many image widths are modelled with the wall
#: (:func:`model_planes_wall`); the wall no longer reaches the planes of the rows beyond.
_WALL_REACH = 3.0
#: Pixels on each side of a row that the interpolant's response reaches (its weights fall as
#: 0.43^k for the quintic B-spline, 0.27^k for the cubic).
_PIX_REACH = 10
#: The interpolations the wall model is validated for. Keys' sub-pixel shift bias (a few 0.01
#: px, periodic in the shift: 5-15 % of the displacement next to the wall) is not modelled:
#: with it the wall model read +14 % at y+ 0.5 (60 pairs), the fallback -6 to +7 %.
_MODELLED = ("bspline", "bspline3")


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


def _particles(
    t: np.ndarray, wt: np.ndarray, profile: dict[str, np.ndarray], du: float
) -> tuple[np.ndarray, ...]:
    """The particles at heights ``t`` (weights ``wt``) over the Gauss-Hermite nodes of their
    fluctuations (``u' = su g1``, ``v' = l21 g1 + l22 g2``, the Cholesky factor of the
    ``profile``'s stresses): flat arrays of their x lag from the predictor ``du``, height,
    wall-normal motion and weight."""
    g1, w1 = _gauss_hermite(_NODES_U)
    g2, w2 = _gauss_hermite(_NODES_V)
    yp = profile["y"]
    mean = np.interp(t, yp, profile["u"])
    su = np.sqrt(np.maximum(np.interp(t, yp, profile["uu"]), 0.0))
    l21 = np.interp(t, yp, profile["uv"]) / np.where(su > 0, su, 1.0) * (su > 0)
    l22 = np.sqrt(np.maximum(np.interp(t, yp, profile["vv"]) - l21**2, 0.0))
    shape = (t.size, g1.size, g2.size)
    cx = mean[:, None, None] + su[:, None, None] * g1[None, :, None] - du
    v = l21[:, None, None] * g1[None, :, None] + l22[:, None, None] * g2[None, None, :]
    w = wt[:, None, None] * w1[None, :, None] * w2[None, None, :]
    return tuple(np.broadcast_to(q, shape).ravel() for q in (cx, t[:, None, None], v, w))


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
    sx2, sy2 = s2
    sy = np.sqrt(sy2)
    out = np.zeros((d.size, 2 * npl + 2))
    exa = np.exp(-(lx**2) / (4 * sx2))
    for k in range(d.size):  # rows of a profile (tens to hundreds), each vectorised
        t = np.arange(max(_DT / 2, d[k] - _REACH * sy), d[k] + _REACH * sy, _DT)
        wt = np.exp(-((d[k] - t) ** 2) / (2 * sy2))  # the A row's share of each height
        cx, tt, v, w = _particles(t, wt, profile, du[k])
        cy = d[k] - tt - v  # the B image's lag: its distance is d - sy
        ex = np.exp(-((lx[None, :] - cx[:, None]) ** 2) / (4 * sx2))
        ey = np.exp(-((ly[None, :] - cy[:, None]) ** 2) / (2 * sy2))
        cross = np.einsum("n,nr,nc->rc", w, ey, ex)
        eya = np.exp(-((ly[None, :] - (d[k] - t)[:, None]) ** 2) / (2 * sy2))
        auto = np.outer(wt @ eya, exa)
        out[k, :npl] = (cross / cross.max()).ravel()
        out[k, npl : 2 * npl] = (auto / auto.max()).ravel()
        out[k, 2 * npl :] = 1.0
    return out


def _bspline(x: np.ndarray, n: int) -> np.ndarray:
    """The centred B-spline of degree ``n`` at ``x`` (truncated-power form)."""
    from math import comb, factorial

    x = np.abs(np.asarray(x, dtype=np.float64))
    out = np.zeros_like(x)
    for k in range(n + 2):
        out += (-1) ** k * comb(n + 1, k) * np.maximum(x + (n + 1) / 2 - k, 0.0) ** n
    return out / factorial(n)


@functools.lru_cache(maxsize=4)
def cardinal(interpolation: str) -> Callable[[np.ndarray], np.ndarray]:
    """The interpolant's response to one unit pixel, ``eta(x)`` (x in px from its centre): the
    frame's value between pixels is ``sum_k eta(x - k) p_k``. The cardinal quintic or cubic
    B-spline (``"bspline"``, ``"bspline3"``: the B-spline weights of the prefilter's impulse
    response, which falls as 0.43^k / 0.27^k) or the Keys kernel (``"keys"``, a = -0.5)."""
    interpolation = parse_choice(interpolation, INTERPOLATIONS, "interpolation")
    if interpolation == "keys":

        def keys(x: np.ndarray) -> np.ndarray:
            a, x = -0.5, np.abs(np.asarray(x, dtype=np.float64))
            near = (a + 2) * x**3 - (a + 3) * x**2 + 1
            far = a * x**3 - 5 * a * x**2 + 8 * a * x - 4 * a
            return np.where(x <= 1, near, np.where(x < 2, far, 0.0))

        return keys
    n = 5 if interpolation == "bspline" else 3
    j = np.arange(-2 * _PIX_REACH, 2 * _PIX_REACH + 1)
    coef = np.linalg.solve(_bspline(j[:, None] - j[None, :], n), (j == 0).astype(np.float64))
    keep = np.abs(coef) > 1e-9 * np.abs(coef).max()
    j, coef = j[keep], coef[keep]

    def spline(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return _bspline(x[..., None] - j, n) @ coef

    return spline


@dataclasses.dataclass(frozen=True)
class WallGeometry:
    """Where a single-pixel band's rows lie on the pixel grid, for :func:`model_planes_wall`.

    ``dist``, ``phase``: arrays ``(rows, k)``, ``k`` columns sampled along each row: the row's
    distance from the wall at that column and the distance of the first pixel centre kept on
    the flow's side (0 <= phase < 1: the pixels at ``phase + m``, m >= 0, keep their values,
    those beyond the wall are the background). ``interpolation``: the accumulator's.
    ``auto``: the rows' mean auto planes ``(rows, 2 ry + 1, 2 rx + 1)`` (the data)."""

    dist: np.ndarray
    phase: np.ndarray
    interpolation: str
    auto: np.ndarray


def _check_image(sigma: float, rho: float) -> None:
    """InvalidInputError unless the image's standard deviation is positive and finite and the
    reflection within 0-1."""
    if not (np.isfinite(sigma) and sigma > 0 and 0.0 <= rho <= 1.0):
        raise InvalidInputError(
            f"wall model: image standard deviation {sigma!r} px (must be > 0) or reflection "
            f"{rho!r} (must be within 0-1)"
        )


def wall_response(
    z: np.ndarray, t: np.ndarray, sigma: float, rho: float, phase: float, eta: Callable
) -> np.ndarray:
    """``a[i, j]``: the value of a frame row interpolated ``z[i]`` px from the wall (into the
    flow) for one particle ``t[j]`` px from it and its mirror image at ``-t[j]`` (intensity
    ``rho``): Gaussian images of standard deviation ``sigma`` integrated over the pixels, the
    pixels at ``phase + m`` (m >= 0) kept, those beyond the wall constant (they add nothing to
    a row less its mean), interpolated by ``eta`` (:func:`cardinal`)."""
    _check_image(sigma, rho)
    z = np.atleast_1d(np.asarray(z, dtype=np.float64))
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    m0 = max(0, int(np.floor(z.min() - phase)) - _PIX_REACH)
    zk = phase + np.arange(m0, int(np.ceil(z.max() - phase)) + _PIX_REACH + 1)

    def pixel(off: np.ndarray) -> np.ndarray:
        return ndtr((off + 0.5) / sigma) - ndtr((off - 0.5) / sigma)

    pk = pixel(zk[:, None] - t[None, :]) + rho * pixel(zk[:, None] + t[None, :])
    return eta(z[:, None] - zk[None, :]) @ pk


def along_row(r: np.ndarray, sigma: float) -> np.ndarray:
    """The correlation along a row of two pixel-integrated Gaussian images (standard deviation
    ``sigma``, px) whose centres are ``r`` px apart, averaged over their position within the
    pixel: the Gaussian of standard deviation ``sqrt(2) sigma`` convolved with the triangle of
    half-width 1 px (the pixel's box correlated with itself); closed form (peak ~1 at 0)."""
    _check_image(sigma, 0.0)
    tau = np.sqrt(2.0) * sigma
    r = np.asarray(r, dtype=np.float64)

    def cdf(x: np.ndarray) -> np.ndarray:
        return ndtr(x / tau)

    def pdf(x: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * (x / tau) ** 2) / (tau * np.sqrt(2.0 * np.pi))

    right = (1.0 - r) * (cdf(r) - cdf(r - 1.0)) - tau**2 * (pdf(r) - pdf(r - 1.0))
    left = (1.0 + r) * (cdf(r + 1.0) - cdf(r)) + tau**2 * (pdf(r + 1.0) - pdf(r))
    return right + left


def model_planes_wall(
    geom: tuple[np.ndarray, np.ndarray],
    du: np.ndarray,
    profile: dict[str, np.ndarray] | None,
    image: tuple[float, float],
    lags: tuple[int, int],
    eta: Callable,
) -> np.ndarray:
    """Expected single-pixel accumulator rows next to a wall, as :func:`model_planes` but on
    the pixel grid: particles uniform in ``t > 0``, each with its mirror image, images of
    standard deviation ``image[0]`` (px, before the pixel's integration) and reflection
    ``image[1]``, the pixels beyond the wall set to the background, the rows interpolated
    (``eta``) as the accumulator interpolates them, the planes normalised over the row as the
    accumulator's (linear in the particles: their expectation is the sum of each particle's).
    ``geom = (dist, phase)`` of shape ``(rows, k)``: the planes are averaged over the ``k``
    columns. Along the row the images are the same pixel-integrated Gaussians (their
    correlation :func:`along_row`). Without a ``profile`` only the auto planes (also in the
    cross planes' place: for calibration)."""
    rx, ry = lags
    lx, ly = np.arange(-rx, rx + 1.0), np.arange(-ry, ry + 1.0)
    npl = lx.size * ly.size
    sigma, rho = image
    reach = _REACH * np.sqrt(sigma**2 + 1.0 / 12.0) + ry
    exa = along_row(lx, sigma)
    dist, phase = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in geom)
    out = np.zeros((dist.shape[0], 2 * npl + 2))
    for k in range(dist.shape[0]):  # rows near the wall (ten or so), each vectorised
        cross, auto = np.zeros((ly.size, lx.size)), np.zeros((ly.size, lx.size))
        for d, ph in zip(dist[k], phase[k], strict=True):
            t = np.arange(_DT / 2, d + reach, _DT)
            a = wall_response(d, t, sigma, rho, ph, eta)[0]  # the A row's share of each height
            auto += np.outer(wall_response(d - ly, t, sigma, rho, ph, eta) @ a, exa)
            if profile is None:
                continue
            cx, tt, v, w = _particles(t, a, profile, du[k])
            tb = np.maximum(tt + v, 0.0)  # frame B's particle (a crossing: at the wall)
            b = wall_response(d - ly, tb, sigma, rho, ph, eta)  # the B strip's rows
            ex = along_row(lx[None, :] - cx[:, None], sigma)
            cross += np.einsum("n,rn,nc->rc", w, b, ex)
        cross = auto if profile is None else cross
        out[k, :npl] = (cross / cross.max()).ravel()
        out[k, npl : 2 * npl] = (auto / auto.max()).ravel()
        out[k, 2 * npl :] = 1.0
    return out


def _calibrate(
    wall: WallGeometry, rows: np.ndarray, far: np.ndarray, auto_yy: float,
    lags: tuple[int, int], eta: Callable,
) -> tuple[float, float] | None:  # fmt: skip
    """The particle image's standard deviation and the reflection for the wall model, from the
    data: ``sigma`` such that the model's auto peaks of the rows ``far`` from the wall fit the
    data's width ``auto_yy`` (the same Gaussian fit on both), then ``rho`` (0-1) that best
    matches the auto planes of the ``rows`` next to it (their lag columns +-1; each row's
    amplitude free). None when no row is far enough or the fits fail."""
    pick = far[np.linspace(0, far.size - 1, min(far.size, 4)).round().astype(int)]
    geom = (wall.dist[pick], wall.phase[pick])

    def width(sigma: float) -> float:
        planes = model_planes_wall(geom, np.zeros(pick.size), None, (sigma, 0.5), lags, eta)
        pk = _rspiv.pixel_peaks(np.ascontiguousarray(planes), lags)
        return float(np.nanmedian(np.asarray(pk["ayy"])))

    # the fitted width grows as sigma^2 plus a constant (pixel, interpolation): two secant steps
    s2 = [max(auto_yy / 2.0 - 1.0 / 12.0, 0.05), max(auto_yy / 2.0 - 0.25, 0.03)]
    w = [width(np.sqrt(v)) for v in s2]
    for _ in range(2):
        if not np.all(np.isfinite(w)) or w[1] == w[0]:
            return None
        nxt = s2[1] + (auto_yy - w[1]) * (s2[1] - s2[0]) / (w[1] - w[0])
        s2, w = [s2[1], float(np.clip(nxt, 0.01, 16.0))], [w[1], width(np.sqrt(max(nxt, 0.01)))]
    sigma = float(np.sqrt(s2[1]))
    rx, ry = lags
    data = 0.5 * (wall.auto[rows, :, rx - 1] + wall.auto[rows, :, rx + 1])
    near = (wall.dist[rows], wall.phase[rows])

    def misfit(rho: float) -> float:
        planes = model_planes_wall(near, np.zeros(rows.size), None, (sigma, rho), lags, eta)
        npl = (2 * rx + 1) * (2 * ry + 1)
        auto = planes[:, npl : 2 * npl].reshape(rows.size, 2 * ry + 1, 2 * rx + 1)
        m = auto[:, :, rx + 1]  # the model's columns +-1 are alike
        c = np.sum(m * data, axis=1) / np.sum(m * m, axis=1)  # each row's amplitude
        return float(np.sum(np.sum((data - c[:, None] * m) ** 2, axis=1) / np.sum(data**2, axis=1)))

    if rows.size == 0:
        return sigma, 0.0
    fit = minimize_scalar(misfit, bounds=(0.0, 1.0), method="bounded", options={"xatol": 0.01})
    return (sigma, float(fit.x)) if np.isfinite(fit.fun) else None


def fit_bias(
    dist: np.ndarray,
    d_eff: np.ndarray,
    du: np.ndarray,
    u: np.ndarray,
    stresses: tuple[np.ndarray, np.ndarray, np.ndarray],
    auto: np.ndarray,
    ok: np.ndarray,
    lags: tuple[int, int],
    wall: WallGeometry | None = None,
    passes: int = 3,
) -> tuple[np.ndarray, tuple[float, float] | None]:
    """The Gaussian fit's bias on each row's ``u`` (px; subtract it), see the module docs, and
    the wall model's particle image ``(sigma, reflection)`` (None when not used).

    ``dist``/``d_eff``: the rows' distances and effective distances (px), ``du``: their mean
    predictors, ``u``: the fitted displacements, ``stresses``: ``(uu, vv, uv)`` (px^2, ``v``
    into the flow: the pixel frame's ``-uv`` for a flow "above" the wall),
    ``auto``: the auto peaks' ``(xx, yy, xy)`` covariances, ``ok``: the rows to use, ``wall``:
    the rows on the pixel grid (:class:`WallGeometry`) for the rows within three image widths
    of the wall; without it (or with Keys interpolation, whose sub-pixel shift bias the model
    leaves out) they take the relative bias of the nearest row beyond. NaN for
    the rows it cannot model (failed fits, no row beyond three image widths, a mean under 0.1
    px or a modelled bias over 10 % (30 % with the wall model) at the row or the nearest
    modelled one)."""
    bias = np.full(dist.shape, np.nan)
    ok = ok & np.isfinite(u) & np.isfinite(d_eff) & np.all(np.isfinite(auto[:, :2]), axis=1)
    if ok.sum() < 3:
        return bias, None
    sy_all = np.sqrt(np.median(auto[ok, 1]) / 2.0)
    clear = ok & (dist > _WALL_REACH * sy_all)  # rows whose planes the wall does not reach
    if not clear.any():
        return bias, None
    s2 = (float(np.median(auto[clear, 0])) / 2.0, float(np.median(auto[clear, 1])) / 2.0)
    h = np.sqrt(2.0 * s2[1])  # the auto peak's own width
    use = ok & (dist >= _WALL_REACH * np.sqrt(s2[1]))
    near = ok & ~use
    if not use.any():
        return bias, None
    image = None
    if wall is not None and near.any() and wall.interpolation in _MODELLED:
        eta = cardinal(wall.interpolation)
        image = _calibrate(
            wall, np.flatnonzero(near), np.flatnonzero(clear), float(np.median(auto[clear, 1])),
            lags, eta,
        )  # fmt: skip
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
    nearest = int(np.flatnonzero(use)[np.argmin(dist[use])])
    rel = np.zeros(dist.shape)

    def relative(planes: np.ndarray, rows: np.ndarray, limit: float) -> np.ndarray:
        """The models' fitted ``u`` relative to the model's own mean where the fit says it
        measures (NaN outside the model's regime: a shear flow along the wall, a resolved
        mean, a bias of a few per cent)."""
        pk = _rspiv.pixel_peaks(np.ascontiguousarray(planes), lags)
        model_u = du[rows] + np.asarray(pk["dx"])
        want = np.interp(dist[rows] - np.asarray(pk["ady"]), profile["y"], profile["u"])
        with np.errstate(invalid="ignore", divide="ignore"):
            r = model_u / want - 1.0
        fits = np.asarray(pk["ok"], dtype=bool) & (np.abs(want) >= _MIN_U) & (np.abs(r) <= limit)
        return np.where(fits, r, np.nan)

    for _ in range(passes):
        uc = (u / (1.0 + np.nan_to_num(rel)))[ok][order]
        slope = _outer_slope(y[1:-1], uc, h)
        # the mean profile smoothed over the auto peak's width (the wall's zero among the
        # points): the rows next to the wall share their particles, and their models follow
        # the profile's curvature, which 40 pairs leave scattered by a few per cent
        inner = smooth(y[:-1], np.r_[0.0, uc], h)
        profile["u"] = np.r_[0.0, inner[1:], inner[-1] + slope * (far_y - y[-2])]
        r = relative(model_planes(dist[use], du[use], profile, s2, lags), use, _MAX_REL)
        good = np.isfinite(r)
        if good.sum() >= 2:
            r[good] = smooth(dist[use][good], r[good], h)
        rel = np.full(dist.shape, np.nan)
        rel[use] = r
        if image is not None:
            assert wall is not None
            rows = np.flatnonzero(near)
            geom = (wall.dist[rows], wall.phase[rows])
            planes = model_planes_wall(geom, du[rows], profile, image, lags, eta)
            rel[rows] = relative(planes, rows, 3.0 * _MAX_REL)
        else:
            rel[near] = rel[nearest]
    out = u * rel / (1.0 + rel)
    bias[ok] = out[ok]
    return bias, image
