"""Vortex cores in PIV fields and their population statistics (Wu & Christensen 2006).

A vortex core is a connected region (8-neighbour) of vectors whose signed swirling strength
``Lambda_ci = lambda_ci sign(omega_z)`` (:func:`rspiv.derivatives.swirling_strength`) is beyond a
threshold, of one sign, holding at least ``min_vectors`` vectors. For each core:

``x``, ``y``
    The centroid weighted by ``|Lambda_ci|`` (px, the grid's coordinates).
``sign``
    +1 counter-clockwise, -1 clockwise, in the frame of the ``omega`` given (the image's y-up
    frame of :mod:`rspiv.derivatives`, or the flow's after the caller's orientation).
``vectors``, ``radius``
    The vectors in the core, and the radius of a disc of their area (``sqrt(n dx dy / pi)``, px).
``circulation``
    The sum of ``omega_z dx dy`` over the core (px^2 per pair): the part of the vortex's
    circulation inside the threshold (a Lamb-Oseen vortex at a threshold of a quarter of its
    peak swirl keeps about 60 % of it).
``peak``
    The largest ``|Lambda_ci|`` of the core (1/pair).

The threshold is usually a multiple (1.5 in Wu & Christensen) of the root mean square of
``Lambda_ci`` at the core's height: the wall-normal variation of the swirl's level would
otherwise fill the buffer layer with cores and leave the outer layer empty.
:class:`VortexAccumulator` counts the cores of many fields by their centroid's row, prograde
(rotating with the mean shear) and retrograde apart. Noise makes cores as well: the
``min_vectors`` rule (:func:`min_core_vectors`: a campaign keeps cores at least as wide as
its final window) and the rms threshold keep most of them out, not all.
"""

from __future__ import annotations

import warnings

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "CORE_FIELDS",
    "OSEEN_FIELDS",
    "VortexAccumulator",
    "find_vortices",
    "fit_oseen",
    "min_core_vectors",
    "oseen_velocity",
]

#: The per-core arrays :func:`find_vortices` returns.
CORE_FIELDS = ("x", "y", "sign", "vectors", "radius", "circulation", "peak")

_EIGHT = np.ones((3, 3), bool)


def min_core_vectors(diameter: float, dx: float, dy: float) -> int:
    """The vectors of a grid of spacing ``dx`` x ``dy`` px that cover a disc of ``diameter``
    px (at least 1): the smallest core a campaign keeps, a disc as wide as the final window.
    A core smaller than the window is not resolved (the window averages it), and most cores
    smaller than that are the noise's: on the demo's layer, cores of 3 vectors or more read
    44-60 % too many against the exact field's, 13 (a 32 px disc on 16 x 4 px) 2-3 %."""
    if not (diameter > 0 and dx > 0 and dy > 0):
        raise InvalidInputError(f"vortices: diameter and spacing must be > 0, got {diameter}")
    return max(1, int(np.ceil(np.pi * diameter**2 / 4.0 / (dx * dy) - 1e-9)))


def find_vortices(
    swirl,
    omega,
    threshold,
    dx: float,
    dy: float,
    *,
    x=None,
    y=None,
    min_vectors: int = 3,
) -> dict[str, np.ndarray]:
    """The vortex cores of one field (module docstring).

    Parameters
    ----------
    swirl : array_like, (ny, nx)
        Signed swirling strength (1/pair); NaN where unknown (never part of a core).
    omega : array_like, (ny, nx)
        Vorticity in the same frame (1/pair), for the circulation.
    threshold : float or array_like
        ``|swirl| >= threshold`` (> 0) makes a core's vector; broadcast against the grid (a
        column ``(ny, 1)`` per row).
    dx, dy : float
        Grid spacing, px.
    x, y : array_like, optional
        The columns' and rows' coordinates (px); default ``dx * j`` and ``dy * i``.
    min_vectors : int
        Cores of fewer vectors are dropped.

    Returns
    -------
    dict
        ``CORE_FIELDS`` arrays, one entry per core, positive cores first.
    """
    from scipy import ndimage  # deferred: scipy is heavy to import

    s = np.asarray(swirl, np.float64)
    w = np.asarray(omega, np.float64)
    if s.ndim != 2 or w.shape != s.shape:
        raise InvalidInputError(f"vortices: swirl {s.shape} and omega {w.shape} must be 2-D alike")
    try:
        thr = np.broadcast_to(np.asarray(threshold, np.float64), s.shape)
    except ValueError:
        raise InvalidInputError(
            f"vortices: a threshold of shape {np.shape(threshold)} for a grid of {s.shape}"
        ) from None
    if not np.all(thr[np.isfinite(thr)] > 0):
        raise InvalidInputError("vortices: the threshold must be > 0")
    if min_vectors < 1:
        raise InvalidInputError(f"vortices: min_vectors must be >= 1, got {min_vectors}")
    xs = dx * np.arange(s.shape[1]) if x is None else np.asarray(x, np.float64)
    ys = dy * np.arange(s.shape[0]) if y is None else np.asarray(y, np.float64)
    if xs.shape != (s.shape[1],) or ys.shape != (s.shape[0],):
        raise InvalidInputError("vortices: x and y must give the columns' and rows' coordinates")
    mag = np.abs(s)
    with np.errstate(invalid="ignore"):
        strong = np.isfinite(s) & (mag >= thr)
    out: dict[str, list[np.ndarray]] = {k: [] for k in CORE_FIELDS}
    rows, cols = np.indices(s.shape)
    for sign in (1.0, -1.0):
        labels, n = ndimage.label(strong & (np.sign(s) == sign), structure=_EIGHT)
        if n == 0:
            continue
        idx = np.arange(1, n + 1)
        count = ndimage.sum_labels(np.ones(s.shape), labels, idx)
        keep = idx[count >= min_vectors]
        if keep.size == 0:
            continue
        weight = np.where(labels > 0, mag, 0.0)
        wsum = ndimage.sum_labels(weight, labels, keep)
        ci = ndimage.sum_labels(weight * rows, labels, keep) / wsum
        cj = ndimage.sum_labels(weight * cols, labels, keep) / wsum
        nvec = count[keep - 1]
        out["x"].append(np.interp(cj, np.arange(xs.size), xs))
        out["y"].append(np.interp(ci, np.arange(ys.size), ys))
        out["sign"].append(np.full(keep.size, sign))
        out["vectors"].append(nvec)
        out["radius"].append(np.sqrt(nvec * abs(dx * dy) / np.pi))
        wz = np.where(np.isfinite(w), w, 0.0)
        out["circulation"].append(ndimage.sum_labels(wz, labels, keep) * abs(dx * dy))
        out["peak"].append(ndimage.maximum(mag, labels, keep))
    return {
        k: (np.concatenate(v) if v else np.zeros(0)).astype(np.float64) for k, v in out.items()
    }


#: The per-core arrays :func:`fit_oseen` returns.
OSEEN_FIELDS = ("x", "y", "radius", "circulation", "u", "v", "fit", "ok")

#: A fit is kept (``ok``) when it explains at least this share of the patch's velocity
#: variance about its own convection (a vortex through the PIV: 0.997; OpenPIV's ``test10``
#: vortex: 0.87-0.92; vortices planted on turbulence: 0.7-0.9; cores of noise: median 0.2).
OSEEN_MIN_FIT = 0.7


def oseen_velocity(x, y, xc, yc, circulation, radius, uc=0.0, vc=0.0):
    """The Lamb-Oseen vortex's velocity at ``(x, y)`` in a right-handed frame (y up).

    ``u_theta(r) = Gamma / (2 pi r) (1 - exp(-r^2 / r_c^2))`` about ``(xc, yc)``, counter-
    clockwise for ``circulation`` (Gamma) > 0, plus the uniform ``(uc, vc)``: its vorticity is
    ``Gamma / (pi r_c^2) exp(-r^2 / r_c^2)`` (a Gaussian of standard deviation ``r_c / sqrt(2)``
    per axis) and its azimuthal velocity peaks at ``r = 1.121 r_c``. Arguments broadcast; a
    core radius that is not a number > 0 is refused (:class:`~rspiv.errors.InvalidInputError`).
    """
    rc = np.asarray(radius, np.float64)
    if not np.all(rc > 0):
        raise InvalidInputError(f"oseen: the core radius must be > 0, got {radius!r}")
    ddx = np.asarray(x, np.float64) - xc
    ddy = np.asarray(y, np.float64) - yc
    rc2 = rc**2
    g = np.asarray(circulation, np.float64) * _decay((ddx * ddx + ddy * ddy) / rc2)[0]
    g = g / (2.0 * np.pi * rc2)
    return uc - g * ddy, vc + g * ddx


def _decay(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(1 - exp(-s)) / s`` and its derivative in ``s`` (series where ``s`` is small)."""
    small = s < 1e-4
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(small, 1.0 - s / 2.0 + s * s / 6.0, -np.expm1(-s) / s)
        df = np.where(small, -0.5 + s / 3.0 - s * s / 8.0, (np.exp(-s) * (s + 1.0) - 1.0) / (s * s))
    return f, df


def fit_oseen(
    u,
    v,
    cores: dict[str, np.ndarray],
    dx: float,
    dy: float,
    *,
    valid=None,
    x=None,
    y=None,
    reach: float = 2.5,
    orient: float = 1.0,
    iterations: int = 60,
) -> dict[str, np.ndarray]:
    """A Lamb-Oseen vortex fitted to the vectors about each core of :func:`find_vortices`.

    The thresholded core's radius and circulation depend on the threshold (a Lamb-Oseen vortex
    at a quarter of its peak swirl keeps about 60 % of its circulation); the fit gives the
    vortex's own core radius ``r_c``, its whole circulation, its centre and its convection
    (Carlier & Stanislas 2005, J. Fluid Mech. 535). The model is :func:`oseen_velocity` with
    six parameters per core, fitted by Levenberg-Marquardt to the valid vectors within ``reach``
    times the core's radius of its centroid (at least two grid steps), all cores at once.

    Frame: ``u``, ``v`` in rspiv's pixel frame (v positive downward, rows down, px per pair);
    the fit is made in the image's y-up frame (:mod:`rspiv.derivatives`), and ``orient``
    (+1 or -1) turns its circulation into the frame of the ``omega`` the cores were found in
    (a campaign's flow frame), as for the vorticity.

    Parameters
    ----------
    u, v : array_like, (ny, nx)
        The field (or its fluctuations: a mean shear across the patch is not in the model).
    cores : dict
        :func:`find_vortices`' result for this grid (``x``, ``y``, ``sign``, ``radius``).
    dx, dy : float
        Grid spacing, px.
    valid : array_like of bool, optional
        The vectors that enter (default: the finite ones).
    x, y : array_like, optional
        The coordinates given to :func:`find_vortices` (default ``dx * j``, ``dy * i``).
    reach : float
        The patch's radius in core radii.
    orient : float
        +1 or -1, as above.
    iterations : int
        Levenberg-Marquardt iterations at most.

    Returns
    -------
    dict
        Per core (:data:`OSEEN_FIELDS`): ``x``, ``y`` the fitted centre (the coordinates of
        ``x``, ``y``), ``radius`` the core radius ``r_c`` (px), ``circulation`` (px^2 per
        pair, in ``orient``'s frame), ``u``, ``v`` the convection (px per pair, pixel frame),
        ``fit`` the share of the patch's velocity variance about the convection it explains,
        and ``ok``: a fit of the core's sense of rotation, centred within two core radii of the
        centroid, with ``r_c`` between a third of a grid step and the patch's radius and ``fit
        >= OSEEN_MIN_FIT``. Values of a core that is not ``ok`` are NaN.

    Raises
    ------
    InvalidInputError
        Fields or ``valid`` of other shapes, a spacing or reach not > 0, ``orient`` not +-1, or
        cores without their ``x``, ``y``, ``sign`` and ``radius`` of one length.
    """
    uu = np.asarray(u, np.float64)
    vv = np.asarray(v, np.float64)
    if uu.ndim != 2 or vv.shape != uu.shape:
        raise InvalidInputError(f"oseen: u {uu.shape} and v {vv.shape} must be 2-D alike")
    if not (dx > 0 and dy > 0 and reach > 0):
        raise InvalidInputError(f"oseen: dx, dy and reach must be > 0, got {dx}, {dy}, {reach}")
    if orient not in (1.0, -1.0):
        raise InvalidInputError(f"oseen: orient must be +1 or -1, got {orient}")
    ny, nx = uu.shape
    ok_vec = np.isfinite(uu) & np.isfinite(vv)
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != uu.shape:
            raise InvalidInputError(
                f"oseen: valid {valid.shape} must have the field's shape {uu.shape}"
            )
        ok_vec &= valid
    xs = dx * np.arange(nx) if x is None else np.asarray(x, np.float64)
    ys = dy * np.arange(ny) if y is None else np.asarray(y, np.float64)
    if xs.shape != (nx,) or ys.shape != (ny,):
        raise InvalidInputError("oseen: x and y must give the columns' and rows' coordinates")
    need = ("x", "y", "sign", "radius")
    try:
        cols = [np.asarray(cores[k], np.float64).ravel() for k in need]
    except (KeyError, TypeError, ValueError):
        raise InvalidInputError(
            f"oseen: cores must be find_vortices' dict of numbers ({', '.join(need)})"
        ) from None
    n = cols[0].size
    if any(c.size != n for c in cols):
        raise InvalidInputError(f"oseen: the cores' {', '.join(need)} differ in length")
    out = {k: np.full(n, np.nan) for k in OSEEN_FIELDS}
    out["ok"] = np.zeros(n, bool)
    if n == 0:
        return out
    # centroids in grid steps; each core's patch radius in px
    cj = np.interp(cores["x"], xs, np.arange(nx))
    ci = np.interp(cores["y"], ys, np.arange(ny))
    rad = np.asarray(cores["radius"], np.float64)
    sign = np.asarray(cores["sign"], np.float64)
    big = np.maximum(reach * rad, 2.0 * max(dx, dy))
    half = np.maximum(np.ceil(big / dx), np.ceil(big / dy)).astype(np.int64)
    # cores of similar patches together (a patch is padded to its group's largest)
    groups = np.floor(np.log(half) / np.log(1.6)).astype(np.int64)
    for g in np.unique(groups):
        at = np.flatnonzero(groups == g)
        fitted = _fit_oseen_group(uu, vv, ok_vec, cj[at], ci[at], rad[at], big[at], sign[at],
                                  dx, dy, orient, int(iterations))  # fmt: skip
        for k, val in fitted.items():
            out[k][at] = val
    out["x"] = np.interp(out["x"], np.arange(nx), xs)  # NaN stays NaN
    out["y"] = np.interp(out["y"], np.arange(ny), ys)
    return out


def _oseen_jacobian(px, py, t):
    """:func:`oseen_velocity` of the parameters ``t`` (cores x (xc, yc, Gamma, log r_c, uc,
    vc)) at the points ``px``, ``py`` (cores x points), and its derivatives (cores x points x
    6) for the fit."""
    ddx, ddy = px - t[:, :1], py - t[:, 1:2]
    gam, rc2 = t[:, 2:3], np.exp(2.0 * t[:, 3:4])
    q = ddx * ddx + ddy * ddy
    s = q / rc2
    f, df = _decay(s)
    phi = f / (2.0 * np.pi * rc2)  # u_theta / (Gamma r)
    phq = df / (2.0 * np.pi * rc2 * rc2)  # d phi / d q
    phl = -np.exp(-s) / (np.pi * rc2)  # d phi / d log r_c
    mu = t[:, 4:5] - gam * phi * ddy
    mv = t[:, 5:6] + gam * phi * ddx
    one, zero = np.ones_like(q), np.zeros_like(q)
    ju = np.stack([2.0 * gam * ddx * ddy * phq, gam * (2.0 * ddy * ddy * phq + phi), -phi * ddy,
                   -gam * ddy * phl, one, zero], axis=-1)  # fmt: skip
    jv = np.stack([-gam * (2.0 * ddx * ddx * phq + phi), -2.0 * gam * ddx * ddy * phq,
                   phi * ddx, gam * ddx * phl, zero, one], axis=-1)  # fmt: skip
    return mu, mv, ju, jv


def _fit_oseen_group(uu, vv, ok_vec, cj, ci, rad, big, sign, dx, dy, orient, iterations):
    """:func:`fit_oseen` for cores of similar patches (centroids ``cj``, ``ci`` in grid
    steps): Levenberg-Marquardt on all of them at once, each core stopping on its own."""
    ny, nx = uu.shape
    n = cj.size
    hj = int(np.ceil(big.max() / dx))
    hi = int(np.ceil(big.max() / dy))
    jj = np.rint(cj).astype(np.int64)[:, None, None] + np.arange(-hj, hj + 1)[None, None, :]
    ii = np.rint(ci).astype(np.int64)[:, None, None] + np.arange(-hi, hi + 1)[None, :, None]
    jj, ii = np.broadcast_arrays(jj, ii)
    inside = (jj >= 0) & (jj < nx) & (ii >= 0) & (ii < ny)
    jc, ic = np.clip(jj, 0, nx - 1), np.clip(ii, 0, ny - 1)
    # px in the image's y-up frame (X = dx j, Y = -dy i; v_up = -v)
    px, py = (dx * jc).reshape(n, -1), (-dy * ic).reshape(n, -1)
    x0, y0 = dx * cj, -dy * ci
    near = (px - x0[:, None]) ** 2 + (py - y0[:, None]) ** 2 <= big[:, None] ** 2
    w = (inside.reshape(n, -1) & near & ok_vec[ic, jc].reshape(n, -1)).astype(np.float64)
    pu = np.where(w > 0, uu[ic, jc].reshape(n, -1), 0.0)
    pv = np.where(w > 0, -vv[ic, jc].reshape(n, -1), 0.0)
    cnt = w.sum(1)
    # first guesses: the centroid, the core's radius, the patch's median convection and its
    # largest r u_theta (the circulation the patch holds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a patch without a vector: NaN
        uc0 = np.nan_to_num(np.nanmedian(np.where(w > 0, pu, np.nan), axis=1))
        vc0 = np.nan_to_num(np.nanmedian(np.where(w > 0, pv, np.nan), axis=1))
    ru = (px - x0[:, None]) * (pv - vc0[:, None]) - (py - y0[:, None]) * (pu - uc0[:, None])
    g0 = 2.0 * np.pi * np.max(np.abs(ru) * w, axis=1) * sign * orient
    lo, hi_ = np.log(min(dx, dy) / 100.0), np.log(100.0 * float(big.max()))
    theta = np.stack([x0, y0, g0, np.log(np.maximum(rad, 0.5 * min(dx, dy))), uc0, vc0], 1)

    def misfit(t, at, normal: bool = True):
        """The weighted misfit of the cores ``at`` and, with ``normal``, its normal equations
        ``J^T J`` and ``J^T r``."""
        with np.errstate(all="ignore"):
            t = t.copy()
            t[:, 3] = np.clip(t[:, 3], lo, hi_)
            mu, mv, ju, jv = _oseen_jacobian(px[at], py[at], t)
            ww = w[at]
            r = np.concatenate([(mu - pu[at]) * ww, (mv - pv[at]) * ww], axis=1)
            if not normal:
                return r, None, None
            jac = np.concatenate([ju * ww[..., None], jv * ww[..., None]], axis=1)
            jt = jac.transpose(0, 2, 1)
            return r, jt @ jac, (jt @ r[..., None])[..., 0]

    scale = np.array([dx, dy, 1.0, 1.0, 1.0, 1.0])
    reach_px = np.maximum(rad, max(dx, dy))  # how far a kept fit's centre may move: twice it
    lam = np.full(n, 1e-3)
    r, a, g = misfit(theta, slice(None))
    cost = np.sum(r * r, 1)
    active = np.flatnonzero(cnt >= 7)  # the cores still iterating
    eye = np.eye(6)
    for _ in range(iterations):
        if active.size == 0:
            break
        aa = a[active]
        diag = np.diagonal(aa, axis1=1, axis2=2)
        # damped normal equations, positive definite (a parameter without effect is held)
        tiny = 1e-12 * np.maximum(diag.max(1), 1e-300)
        damp = aa + (lam[active, None] * diag + tiny[:, None])[:, :, None] * eye
        with np.errstate(all="ignore"):
            step = -np.linalg.solve(damp, g[active][..., None])[..., 0]
        trial = theta[active] + step
        r_new, _, _ = misfit(trial, active, normal=False)
        c_new = np.sum(r_new * r_new, 1)
        better = np.isfinite(c_new) & (c_new < cost[active])
        small = np.max(np.abs(step) / np.maximum(np.abs(theta[active]), scale), axis=1) < 1e-9
        settled = (better & (cost[active] - c_new <= 1e-7 * cost[active])) | (~better & small)
        take = active[better]
        if take.size:
            theta[take] = trial[better]
            r[take], a[take], g[take] = misfit(theta[take], take)
            cost[take] = c_new[better]
        lam[active] = np.where(better, lam[active] / 3.0, lam[active] * 4.0)
        # a fit drifting to a core wider than twice its patch, or centred twice as far as a
        # fit may be, will not be kept: it stops (a patch in solid-body rotation crawls there)
        t = theta[active]
        lost = (t[:, 3] > np.log(2.0 * big[active])) | (
            np.hypot(t[:, 0] - x0[active], t[:, 1] - y0[active]) > 4.0 * reach_px[active]
        )
        active = active[~settled & ~lost & (lam[active] < 1e10)]
    xc, yc, gam, lrc, uc, vc = theta.T
    rc = np.exp(np.clip(lrc, lo, hi_))
    with np.errstate(invalid="ignore", divide="ignore"):
        su = np.sum(w * ((pu - uc[:, None]) ** 2 + (pv - vc[:, None]) ** 2), 1)
        fit = 1.0 - cost / su
    moved = np.hypot(xc - x0, yc - y0)
    ok = (
        np.isfinite(cost)
        & np.isfinite(fit)
        & (cnt >= 7)
        & (np.sign(gam) * orient == sign)
        & (moved <= 2.0 * reach_px)
        & (rc >= min(dx, dy) / 3.0)
        & (rc <= big)
        & (fit >= OSEEN_MIN_FIT)
    )
    keep = np.where(ok, 1.0, np.nan)
    return {
        "ok": ok,
        "x": xc / dx * keep,  # grid steps (the caller maps them to its coordinates)
        "y": -yc / dy * keep,
        "radius": rc * keep,
        "circulation": gam * orient * keep,
        "u": uc * keep,
        "v": -vc * keep,
        "fit": fit,
    }


class VortexAccumulator:
    """Cores of many fields counted by their centroid's row (module docstring).

    Parameters
    ----------
    rows : int
        The grid's rows.
    prograde : float
        +1 or -1: the sign of a core rotating with the mean shear (a boundary layer's mean
        vorticity is negative in the flow's frame, so -1 there).

    Attributes
    ----------
    count, radius_sum, circulation_sum : ndarray, (2, rows)
        Per row (index 0 prograde, 1 retrograde): the cores, and the sums of their radii and
        circulations.
    oseen_count, oseen_radius_sum, oseen_circulation_sum, oseen_u_sum : ndarray, (2, rows)
        The same over the cores whose Lamb-Oseen fit is ``ok`` (:func:`fit_oseen`), and the
        sum of their convection velocities.
    n_fields : int
    """

    #: The per-row sums of :meth:`add` (the Lamb-Oseen ones over the fits that are ``ok``).
    SUMS = ("count", "radius_sum", "circulation_sum", "oseen_count", "oseen_radius_sum",
            "oseen_circulation_sum", "oseen_u_sum")  # fmt: skip

    def __init__(self, rows: int, prograde: float):
        if prograde not in (1.0, -1.0):
            raise InvalidInputError(f"vortices: prograde must be +1 or -1, got {prograde}")
        self.rows = int(rows)
        self.prograde = float(prograde)
        for name in self.SUMS:
            setattr(self, name, np.zeros((2, self.rows), np.int64 if "count" in name else float))
        self.n_fields = 0

    def add(self, cores: dict[str, np.ndarray], row: np.ndarray, oseen=None) -> None:
        """Add one field's ``cores`` (:func:`find_vortices`), ``row`` the grid row of each
        centroid (an int per core; outside ``0 .. rows-1`` not counted), and their Lamb-Oseen
        fits (:func:`fit_oseen`; ``u`` the convection to sum, in the caller's units), if
        given."""
        row = np.asarray(row, np.int64)
        inside = (row >= 0) & (row < self.rows)
        kind = np.where(cores["sign"] == self.prograde, 0, 1)
        sums = [("count", None), ("radius_sum", cores["radius"]),
                ("circulation_sum", cores["circulation"])]  # fmt: skip
        if oseen is not None:
            sums += [("oseen_count", None), ("oseen_radius_sum", oseen["radius"]),
                     ("oseen_circulation_sum", oseen["circulation"]),
                     ("oseen_u_sum", oseen["u"])]  # fmt: skip
        for name, values in sums:
            at = inside & (oseen["ok"] if name.startswith("oseen") else True)
            np.add.at(getattr(self, name), (kind[at], row[at]), 1 if values is None else values[at])
        self.n_fields += 1

    def merge(self, other: VortexAccumulator) -> VortexAccumulator:
        """Add ``other``'s counts (the same rows and orientation); returns self."""
        if (self.rows, self.prograde) != (other.rows, other.prograde):
            raise InvalidInputError("vortices: cannot merge counts of other grids")
        for name in self.SUMS:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.n_fields += other.n_fields
        return self

    def empty_copy(self) -> VortexAccumulator:
        return VortexAccumulator(self.rows, self.prograde)
