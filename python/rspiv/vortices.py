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

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

__all__ = [
    "CORE_FIELDS",
    "OSEEN_CROWDED",
    "OSEEN_FIELDS",
    "OSEEN_JOINT_MAX",
    "VortexAccumulator",
    "batch_density_se",
    "find_vortices",
    "fit_neighbours",
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
    wz = np.where(np.isfinite(w), w, 0.0)
    for sign in (1.0, -1.0):
        labels, n = ndimage.label(strong & (np.sign(s) == sign), structure=_EIGHT)
        if n == 0:
            continue
        # the labelled vectors only, summed per label by bincount (in the grid's order)
        at = np.flatnonzero(labels)
        lab = labels.ravel()[at]
        count = np.bincount(lab, minlength=n + 1)[1:].astype(np.float64)
        keep = np.flatnonzero(count >= min_vectors) + 1
        if keep.size == 0:
            continue
        m_at = mag.ravel()[at]
        i_at, j_at = np.divmod(at, s.shape[1])
        wsum = np.bincount(lab, m_at, n + 1)[keep]
        ci = np.bincount(lab, m_at * i_at, n + 1)[keep] / wsum
        cj = np.bincount(lab, m_at * j_at, n + 1)[keep] / wsum
        peak = np.zeros(n + 1)
        np.maximum.at(peak, lab, m_at)
        nvec = count[keep - 1]
        out["x"].append(np.interp(cj, np.arange(xs.size), xs))
        out["y"].append(np.interp(ci, np.arange(ys.size), ys))
        out["sign"].append(np.full(keep.size, sign))
        out["vectors"].append(nvec)
        out["radius"].append(np.sqrt(nvec * abs(dx * dy) / np.pi))
        out["circulation"].append(np.bincount(lab, wz.ravel()[at], n + 1)[keep] * abs(dx * dy))
        out["peak"].append(peak[keep])
    return {
        k: (np.concatenate(v) if v else np.zeros(0)).astype(np.float64) for k, v in out.items()
    }


#: The per-core arrays :func:`fit_oseen` returns.
OSEEN_FIELDS = (
    "x", "y", "radius", "circulation", "u", "v", "shear", "fit", "ok", "neighbour", "joint",
)  # fmt: skip

#: The kernel's per-core arrays, in the order of ``_rspiv.oseen_fit_joint``'s ``fits``.
_KERNEL_FIELDS = ("x", "y", "radius", "circulation", "u", "v", "shear", "fit")

#: Groups of more kept fits than this, each within :data:`OSEEN_CROWDED` of another, are left
#: to their single fits (defined by the kernel, ``piv_core::vortex_joint``).
OSEEN_JOINT_MAX = _rspiv.OSEEN_JOINT_MAX

#: A kept single fit closer than this to another kept fit of its field (centre to centre, in
#: their mean core radius: :func:`fit_oseen`'s ``neighbour``) is biased by it: a single-vortex
#: fit takes the neighbour's uniform part into its convection, not its gradient. Measured on
#: pairs of exact Lamb-Oseen vortices of one r_c (``tests/test_vortices.py``, six directions):
#: from 4 core radii apart r_c and the circulation within 0.8 % of the truth, at 3 up to 16 %
#: off (like sense) and 9 % (opposite sense); two of like sense 2.5 r_c apart are one core.
#: Such fits are fitted again together (:func:`fit_oseen`'s ``joint``).
OSEEN_CROWDED = 4.0

#: A fit is kept (``ok``) when it explains at least this share of the patch's velocity
#: variance about its own convection (a vortex through the PIV: 0.997; OpenPIV's ``test10``
#: vortex: 0.87-0.92; vortices planted on turbulence: 0.7-0.9; cores of noise: median 0.2).
#: Defined by the kernel (``piv_core::vortex_fit``).
OSEEN_MIN_FIT = _rspiv.OSEEN_MIN_FIT


def oseen_velocity(x, y, xc, yc, circulation, radius, uc=0.0, vc=0.0, shear=0.0):
    """The Lamb-Oseen vortex's velocity at ``(x, y)`` in a right-handed frame (y up).

    ``u_theta(r) = Gamma / (2 pi r) (1 - exp(-r^2 / r_c^2))`` about ``(xc, yc)``, counter-
    clockwise for ``circulation`` (Gamma) > 0, plus the uniform ``(uc, vc)`` and a background
    shear ``shear (y - yc)`` in ``u`` (``dU/dy``, y up; :func:`fit_oseen`): its vorticity is
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
    return uc + (shear - g) * ddy, vc + g * ddx


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
    iterations: int = 100,
    shear: bool = False,
    joint: bool = True,
) -> dict[str, np.ndarray]:
    """A Lamb-Oseen vortex fitted to the vectors about each core of :func:`find_vortices`.

    The thresholded core's radius and circulation depend on the threshold (a Lamb-Oseen vortex
    at a quarter of its peak swirl keeps about 60 % of its circulation); the fit gives the
    vortex's own core radius ``r_c``, its whole circulation, its centre and its convection
    (Carlier & Stanislas 2005, J. Fluid Mech. 535). The model is :func:`oseen_velocity` with
    six parameters per core, fitted by Levenberg-Marquardt (``dewarp_core::lm``) to the valid
    vectors within ``reach`` times the core's radius of its centroid (at least two grid steps),
    cores in parallel in Rust (``piv_core::vortex_fit``). A fit drifting to a core wider than
    twice its patch, or centred twice as far as a kept fit may be, is abandoned early.

    With ``shear``, a seventh parameter adds a uniform background shear ``dU/dy`` about the
    centre, as Stanislas, Perret & Foucaut (2008, J. Fluid Mech. 602) fit the vortices of a
    boundary layer: without it, a vortex in a shear is fitted with a core too small and too
    weak yet looks right (a vortex in a shear of 5 % of its peak vorticity: ``r_c`` 9 % and
    ``Gamma`` 18 % low at a fit of 0.98, `piv_core::vortex_fit`'s tests), and a shear alone is
    not taken for a vortex (``fit`` is then measured about the fitted background). Where there
    is no uniform shear the seventh parameter costs accuracy (600 random vortices with noise:
    median error of ``r_c`` 5.8 % against 3.2 % without it, ``benches/bench_oseen.py``).

    Frame: ``u``, ``v`` in rspiv's pixel frame (v positive downward, rows down, px per pair);
    the fit is made in the image's y-up frame (:mod:`rspiv.derivatives`), and ``orient``
    (+1 or -1) turns its circulation into the frame of the ``omega`` the cores were found in
    (a campaign's flow frame), as for the vorticity.

    Parameters
    ----------
    u, v : array_like, (ny, nx)
        The field (or its fluctuations; a shear across the patch is in the model only with
        ``shear``).
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
        Levenberg-Marquardt steps tried (model evaluations) per core at most (>= 1).
    shear : bool
        Fit the background shear with the vortex (above).
    joint : bool
        Fit neighbouring vortices together (below).

    Returns
    -------
    dict
        Per core (:data:`OSEEN_FIELDS`): ``x``, ``y`` the fitted centre (the coordinates of
        ``x``, ``y``), ``radius`` the core radius ``r_c`` (px), ``circulation`` (px^2 per
        pair, in ``orient``'s frame), ``u``, ``v`` the convection (px per pair, pixel frame),
        ``shear`` the background's ``du/dy`` (pixel frame, rows down: 1/pair; NaN without
        ``shear``), ``fit`` the share of the patch's velocity variance about the convection
        (and the fitted shear) it explains
        (NaN for a core not fitted: fewer than 7 valid vectors in its patch, or a patch that
        does not determine a vortex), and ``ok``: a fit of the core's sense of rotation,
        centred within two core radii of the centroid, with ``r_c`` between a third of a grid
        step and the patch's radius and ``fit >= OSEEN_MIN_FIT``. Values of a core that is not
        ``ok`` are NaN. Two fits of one sense closer than their mean core radius are one
        vortex split into two cores by the threshold: only the one with the higher ``fit`` is
        kept. ``neighbour``: the distance (px) from a kept fit's centre to the
        nearest other kept fit's, in their mean core radius ``(r_c + r_c') / 2`` (NaN without
        another); below :data:`OSEEN_CROWDED` the neighbour biases a single-vortex fit.
        ``joint``: the fit was made with its neighbours (with ``joint``): the kept fits
        closer than :data:`OSEEN_CROWDED` to another are grouped (chained, at most
        :data:`OSEEN_JOINT_MAX` a group) and each group's vortices fitted at once to the
        union of their patches, with one convection (and shear), from their single fits
        (``piv_core::vortex_joint``). Where the joint fit is kept (every vortex turning with
        its core, within two core radii of its centroid, no two of one sense closer than
        their mean core radius, the group's ``fit >= OSEEN_MIN_FIT``) it replaces the single
        ones, ``fit`` being the group's and ``u``, ``v`` the convection at each centre;
        otherwise the single fits stand, ``joint`` False.

    Raises
    ------
    InvalidInputError
        Fields or ``valid`` of other shapes, a spacing or reach not > 0, ``orient`` not +-1,
        ``iterations`` under 1, or cores without their ``x``, ``y``, ``sign`` and ``radius`` of
        one length.
    """
    uu = np.asarray(u, np.float64)
    vv = np.asarray(v, np.float64)
    if uu.ndim != 2 or vv.shape != uu.shape:
        raise InvalidInputError(f"oseen: u {uu.shape} and v {vv.shape} must be 2-D alike")
    if not (dx > 0 and dy > 0 and reach > 0):
        raise InvalidInputError(f"oseen: dx, dy and reach must be > 0, got {dx}, {dy}, {reach}")
    if orient not in (1.0, -1.0):
        raise InvalidInputError(f"oseen: orient must be +1 or -1, got {orient}")
    if int(iterations) < 1:
        raise InvalidInputError(f"oseen: iterations must be >= 1, got {iterations}")
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
    out["joint"] = np.zeros(n, bool)
    if n == 0:
        return out
    # centroids in grid steps; the fit itself is the kernel's (piv_core::vortex_fit)
    fits_at = np.column_stack([np.interp(cols[0], xs, np.arange(nx)),
                               np.interp(cols[1], ys, np.arange(ny))])  # fmt: skip
    fits = _rspiv.oseen_fit(
        uu, vv, ok_vec, fits_at[:, 0].copy(), fits_at[:, 1].copy(), cols[3], cols[2],
        float(dx), float(dy), float(reach), float(orient), int(iterations), bool(shear),
    )  # fmt: skip
    for k in (*_KERNEL_FIELDS, "ok"):
        out[k] = fits[{"x": "col", "y": "row"}.get(k, k)]
    _one_per_vortex(out, out["x"] * dx, out["y"] * dy)
    group = _crowds(out["x"] * dx, out["y"] * dy, out["radius"], out["ok"]) if joint else None
    if group is not None and np.any(group >= 0):
        centroids = np.column_stack([fits_at, cols[3], cols[2]])
        got = _rspiv.oseen_fit_joint(
            uu, vv, ok_vec, centroids, np.column_stack([out[k] for k in _KERNEL_FIELDS]),
            group, float(dx), float(dy), float(reach), float(orient), int(iterations),
            bool(shear),
        )  # fmt: skip
        for k in (*_KERNEL_FIELDS, "joint"):
            out[k] = got[{"x": "col", "y": "row"}.get(k, k)]
    out["neighbour"] = fit_neighbours(out["x"] * dx, out["y"] * dy, out["radius"], out["ok"])
    out["x"] = np.interp(out["x"], np.arange(nx), xs)  # NaN stays NaN
    out["y"] = np.interp(out["y"], np.arange(ny), ys)
    return out


def fit_neighbours(x: np.ndarray, y: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Each kept fit's distance to the nearest other kept fit in their mean core radius
    (:func:`fit_oseen`'s ``neighbour``: centres ``x``, ``y`` and core radii ``r`` px, ``ok``
    the fits kept; NaN where not kept or alone), by blocks of 512 fits."""
    out = np.full(ok.size, np.nan)
    k = np.flatnonzero(ok)
    if k.size < 2:
        return out
    near = np.empty(k.size)
    for a, d in _apart(x[k], y[k], r[k]):
        near[a : a + len(d)] = d.min(axis=1)
    out[k] = near
    return out


def _apart(x: np.ndarray, y: np.ndarray, r: np.ndarray):
    """``(a, d)`` by blocks of 512 points from ``a``: their distances to every point in their
    mean core radius (inf to themselves)."""
    for a in range(0, x.size, 512):
        b = min(a + 512, x.size)
        d = np.hypot(x[a:b, None] - x[None], y[a:b, None] - y[None])
        d /= 0.5 * (r[a:b, None] + r[None])
        d[np.arange(b - a), np.arange(a, b)] = np.inf  # not itself
        yield a, d


def _crowds(x: np.ndarray, y: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Each kept fit's group (-1: none): the kept fits chained by distances under
    :data:`OSEEN_CROWDED` mean core radii (centres ``x``, ``y`` and ``r`` px), groups of two
    or more labelled from 0."""
    k = np.flatnonzero(ok)
    label = np.full(ok.size, -1, np.int64)
    if k.size < 2:
        return label
    root = np.arange(k.size)

    def find(a: int) -> int:
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        return a

    for a, d in _apart(x[k], y[k], r[k]):
        i, j = np.nonzero(d < OSEEN_CROWDED)
        for i0, j0 in zip(i + a, j, strict=True):  # a few per field
            if i0 < j0:
                root[find(i0)] = find(j0)
    top = np.array([find(a) for a in range(k.size)])
    _, which, size = np.unique(top, return_inverse=True, return_counts=True)
    label[k] = np.where(size[which] > 1, which, -1)
    return label


def _one_per_vortex(out: dict[str, np.ndarray], x: np.ndarray, y: np.ndarray) -> None:
    """Two kept fits of one sense closer than their mean core radius are one vortex whose swirl
    the threshold split into two cores (two resolved vortices of like sense merge into one
    core from about 2.5 r_c apart): the one explaining less of its patch is no longer kept,
    its values NaN, as for any fit not kept (``x``, ``y`` px, in place in ``out``)."""
    k = np.flatnonzero(out["ok"])
    if k.size < 2:
        return
    sense = np.sign(out["circulation"][k])
    pairs = []
    for a, d in _apart(x[k], y[k], out["radius"][k]):
        i, j = np.nonzero((d < 1.0) & (sense[a : a + len(d), None] == sense[None]))
        pairs += [(k[i0 + a], k[j0]) for i0, j0 in zip(i, j, strict=True) if i0 + a < j0]
    for i, j in pairs:  # rare: a few per field
        if out["ok"][i] and out["ok"][j]:
            worse = i if out["fit"][i] < out["fit"][j] else j
            out["ok"][worse] = False
            for name in ("x", "y", "radius", "circulation", "u", "v", "shear"):
                out[name][worse] = np.nan


class VortexAccumulator:
    """Cores of many fields counted by their centroid's row (module docstring).

    Parameters
    ----------
    rows : int
        The grid's rows.
    prograde : float
        +1 or -1: the sign of a core rotating with the mean shear (a boundary layer's mean
        vorticity is negative in the flow's frame, so -1 there).
    batches : int
        Batches of contiguous fields whose counts are kept apart (the densities' standard
        errors, :func:`batch_density_se`).

    Attributes
    ----------
    count, radius_sum, circulation_sum : ndarray, (2, rows)
        Per row (index 0 prograde, 1 retrograde): the cores, and the sums of their radii and
        circulations; ``radius_sq``, ``circulation_sq`` the sums of their squares.
    oseen_count, oseen_radius_sum, oseen_circulation_sum, oseen_u_sum : ndarray, (2, rows)
        The same over the cores whose Lamb-Oseen fit is ``ok`` (:func:`fit_oseen`), and the
        sum of their convection velocities; ``oseen_*_sq`` the sums of their squares.
    count_batches : ndarray, (batches, 2, rows)
        ``count`` per batch; ``fields_batches`` (batches,) the fields of each.
    n_fields : int
    """

    #: The per-row sums of :meth:`add` (the Lamb-Oseen ones over the fits that are ``ok``).
    SUMS = ("count", "radius_sum", "circulation_sum", "oseen_count", "oseen_radius_sum",
            "oseen_circulation_sum", "oseen_u_sum", "radius_sq", "circulation_sq",
            "oseen_radius_sq", "oseen_circulation_sq", "oseen_u_sq")  # fmt: skip

    def __init__(self, rows: int, prograde: float, batches: int = 8):
        if prograde not in (1.0, -1.0):
            raise InvalidInputError(f"vortices: prograde must be +1 or -1, got {prograde}")
        self.rows = int(rows)
        self.prograde = float(prograde)
        self.batches = int(batches)
        for name in self.SUMS:
            setattr(self, name, np.zeros((2, self.rows), np.int64 if "count" in name else float))
        self.count_batches = np.zeros((self.batches, 2, self.rows), np.int64)
        self.fields_batches = np.zeros(self.batches, np.int64)
        self.n_fields = 0

    def add(self, cores: dict[str, np.ndarray], row: np.ndarray, oseen=None, batch: int = 0):
        """Add one field's ``cores`` (:func:`find_vortices`), ``row`` the grid row of each
        centroid (an int per core; outside ``0 .. rows-1`` not counted), and their Lamb-Oseen
        fits (:func:`fit_oseen`; ``u`` the convection to sum, in the caller's units), if
        given; ``batch`` the field's batch of contiguous fields (``0 .. batches-1``)."""
        b = int(batch)
        if not 0 <= b < self.batches:
            raise InvalidInputError(f"vortices: batch {batch} outside 0..{self.batches - 1}")
        row = np.asarray(row, np.int64)
        inside = (row >= 0) & (row < self.rows)
        kind = np.where(cores["sign"] == self.prograde, 0, 1)
        sums = [("count", None), ("radius_sum", cores["radius"]),
                ("circulation_sum", cores["circulation"]), ("radius_sq", cores["radius"] ** 2),
                ("circulation_sq", cores["circulation"] ** 2)]  # fmt: skip
        if oseen is not None:
            for k in ("radius", "circulation", "u"):
                sums += [(f"oseen_{k}_sum", oseen[k]), (f"oseen_{k}_sq", oseen[k] ** 2)]
            sums.append(("oseen_count", None))
        for name, values in sums:
            at = inside & (oseen["ok"] if name.startswith("oseen") else True)
            np.add.at(getattr(self, name), (kind[at], row[at]), 1 if values is None else values[at])
        np.add.at(self.count_batches[b], (kind[inside], row[inside]), 1)
        self.fields_batches[b] += 1
        self.n_fields += 1

    def merge(self, other: VortexAccumulator) -> VortexAccumulator:
        """Add ``other``'s counts (the same rows, orientation and batches); returns self."""
        if (self.rows, self.prograde, self.batches) != (other.rows, other.prograde,
                                                         other.batches):  # fmt: skip
            raise InvalidInputError("vortices: cannot merge counts of other grids")
        for name in (*self.SUMS, "count_batches", "fields_batches"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.n_fields += other.n_fields
        return self

    def empty_copy(self) -> VortexAccumulator:
        return VortexAccumulator(self.rows, self.prograde, self.batches)


def batch_density_se(count_batches: np.ndarray, fields_batches: np.ndarray,
                     area: np.ndarray) -> np.ndarray:  # fmt: skip
    """The standard error of a density ``count / (fields area)`` from the batches' own
    densities: ``count_batches`` ``(batches, ...)`` cores per batch, ``fields_batches``
    ``(batches,)`` its fields, ``area`` broadcast against one batch's counts. Batches of
    contiguous fields keep the correlation of successive fields inside a batch, so the error
    holds it (a time-resolved recording's cores seen again in the next field). NaN with fewer
    than 2 batches of fields."""
    used = np.asarray(fields_batches) > 0
    n_b = int(used.sum())
    if n_b < 2:
        return np.full(np.shape(count_batches)[1:], np.nan)
    shape = (-1,) + (1,) * (np.ndim(count_batches) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        dens = count_batches[used] / (np.asarray(fields_batches)[used].reshape(shape) * area)
        # the batches weighted by their fields, as the overall density is
        w = (np.asarray(fields_batches)[used] / np.sum(np.asarray(fields_batches)[used]))
        w = w.reshape(shape)
        mean = np.sum(w * dens, axis=0)
        var = np.sum(w * (dens - mean) ** 2, axis=0) * n_b / (n_b - 1)
        return np.sqrt(var / n_b)
