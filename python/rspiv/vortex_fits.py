"""Lamb-Oseen vortices fitted to the vectors about vortex cores (:func:`fit_oseen`).

The cores are :func:`rspiv.vortices.find_vortices`'; each is fitted on its own by the kernel
(``piv_core::vortex_fit``), and the fits that lie close together, or the cores whose single fits
take two vortices for one, are fitted together (``piv_core::vortex_joint``). The model
(:func:`oseen_velocity`), its frame and its units are in :func:`fit_oseen`'s docstring.
"""

from __future__ import annotations

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

__all__ = [
    "OSEEN_CROWDED",
    "OSEEN_FIELDS",
    "OSEEN_JOINT_MAX",
    "OSEEN_MIN_FIT",
    "fit_neighbours",
    "fit_oseen",
    "oseen_velocity",
]

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
    collapsed = _one_per_vortex(out, out["x"] * dx, out["y"] * dy)
    centroids = np.column_stack([fits_at, cols[3], cols[2]])

    def fit_together(start: dict[str, np.ndarray], group: np.ndarray, least=None) -> np.ndarray:
        """The groups' joint fits from ``start``, taken into ``out`` where kept (and where
        each vortex's circulation is at least ``least`` in size): which."""
        got = _rspiv.oseen_fit_joint(
            uu, vv, ok_vec, centroids, np.column_stack([start[k] for k in _KERNEL_FIELDS]),
            group, float(dx), float(dy), float(reach), float(orient), int(iterations),
            bool(shear),
        )  # fmt: skip
        took = got["joint"].astype(bool)
        if least is not None:
            weak = took & ~(np.abs(got["circulation"]) >= least)
            took &= ~np.isin(group, group[weak])
        for k in _KERNEL_FIELDS:
            out[k][took] = got[{"x": "col", "y": "row"}.get(k, k)][took]
        out["ok"][took] = True
        out["joint"] |= took
        return took

    if joint:
        # the cores of one region split at its swirl's saddles (find_vortices' region), and
        # cores whose single fits became one vortex, fitted together from the cores themselves:
        # two vortices of one sense within about 2.5 r_c are each fitted as one of both
        start = _split_starts(uu, vv, ok_vec, cores, collapsed, fits_at, cols, reach, dx, dy)
        if start is not None:
            # one vortex given as two cores fits as itself and a vortex of the noise: each
            # must hold half its core's circulation inside the threshold (a Lamb-Oseen
            # vortex holds about 60 % of its own there at a quarter of its peak swirl)
            least = 0.5 * np.abs(np.asarray(cores["circulation"], np.float64).ravel())
            fit_together(*start, least=least)
        group = _crowds(out["x"] * dx, out["y"] * dy, out["radius"], out["ok"])
        if np.any(group >= 0):
            fit_together(out, group)
    out["neighbour"] = fit_neighbours(out["x"] * dx, out["y"] * dy, out["radius"], out["ok"])
    out["x"] = np.interp(out["x"], np.arange(nx), xs)  # NaN stays NaN
    out["y"] = np.interp(out["y"], np.arange(ny), ys)
    return out


def _split_starts(uu, vv, ok_vec, cores, collapsed, fits_at, cols, reach, dx, dy):
    """The start of the joint fits of the cores split from one region (:func:`fit_oseen`) or
    whose single fits became one vortex (``collapsed``, pairs of cores), groups of 2 to
    :data:`OSEEN_JOINT_MAX` (chained), or None without any: each vortex at its core's
    centroid, ``r_c`` its core's radius, its circulation the core's over the share of a
    Lamb-Oseen vortex's inside ``r_c`` (1 - 1/e), the convection the median of the valid
    vectors about the group; with the group of each core (-1: none). Cores without their
    ``circulation`` have no start."""
    n = cols[0].size
    try:
        circ = np.asarray(cores["circulation"], np.float64).ravel()
        region = np.asarray(cores.get("region", np.zeros(n)), np.float64).ravel()
    except (KeyError, TypeError, ValueError):
        return None
    if region.size != n or circ.size != n:
        return None
    root = np.arange(n)  # each core's group: its region's first core
    in_region = np.flatnonzero(region > 0)
    if in_region.size:
        _, first, inv = np.unique(region[in_region], return_index=True, return_inverse=True)
        root[in_region] = in_region[first][inv]
    for i, j in collapsed:  # a few per field
        ri, rj = root[i], root[j]
        root[root == rj] = ri
    _, which, size = np.unique(root, return_inverse=True, return_counts=True)
    many = (size[which] >= 2) & (size[which] <= OSEEN_JOINT_MAX) & np.isfinite(circ)
    if not many.any():
        return None
    group = np.where(many, which, -1).astype(np.int64)
    start = {k: np.full(n, np.nan) for k in _KERNEL_FIELDS}
    start["x"][many], start["y"][many] = fits_at[many, 0], fits_at[many, 1]
    start["radius"][many] = cols[3][many]
    start["circulation"][many] = circ[many] / (1.0 - np.exp(-1.0))
    start["shear"][many] = 0.0
    ny, nx = uu.shape
    for g in np.unique(group[many]):  # a few per field
        k = group == g
        span = reach * cols[3][k].max()
        j0 = max(int(np.floor(fits_at[k, 0].min() - span / dx)), 0)
        j1 = min(int(np.ceil(fits_at[k, 0].max() + span / dx)) + 1, nx)
        i0 = max(int(np.floor(fits_at[k, 1].min() - span / dy)), 0)
        i1 = min(int(np.ceil(fits_at[k, 1].max() + span / dy)) + 1, ny)
        use = ok_vec[i0:i1, j0:j1]
        if not use.any():
            group[k] = -1
            continue
        start["u"][k] = np.median(uu[i0:i1, j0:j1][use])
        start["v"][k] = np.median(vv[i0:i1, j0:j1][use])
    return start, group


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


def _one_per_vortex(
    out: dict[str, np.ndarray], x: np.ndarray, y: np.ndarray
) -> list[tuple[int, int]]:
    """Two kept fits of one sense closer than their mean core radius are one vortex: one whose
    swirl the threshold split into two cores, or two vortices of like sense within about 2.5
    r_c, each core's fit taking both for one: the one explaining less of its patch is no
    longer kept, its values NaN, as for any fit not kept (``x``, ``y`` px, in place in
    ``out``). Returns the pairs of cores so found (:func:`fit_oseen` fits them together)."""
    k = np.flatnonzero(out["ok"])
    if k.size < 2:
        return []
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
    return [(int(i), int(j)) for i, j in pairs]
