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
``region``
    The thresholded region the core is part of (numbered from 1 in each field). Two vortices
    of one sense closer than about three core radii make one region, and a core of both would
    read as one vortex of twice the circulation. With ``split``, a region whose swirl has two
    or more maxima, each over a saddle that falls to ``split`` (:data:`SPLIT_SADDLE`) of the
    lower maximum or below and each part holding ``min_vectors``, is split into one core per
    maximum, the cores sharing its number (the swirl taken against its row's threshold, which
    follows the swirl's level with height). Each vector goes to the maximum it climbs to
    (steepest ascent through its eight neighbours in the region), and parts whose maxima do
    not stand clear of their saddle are joined again, the highest saddles first (a watershed
    merged by persistence). A PIV field's noise splits regions too: :func:`confirm_splits`
    keeps a split only where the parts fit as vortices.

The threshold is usually a multiple (1.5 in Wu & Christensen) of the root mean square of
``Lambda_ci`` at the core's height: the wall-normal variation of the swirl's level would
otherwise fill the buffer layer with cores and leave the outer layer empty.
:class:`VortexAccumulator` counts the cores of many fields by their centroid's row, prograde
(rotating with the mean shear) and retrograde apart. Noise makes cores as well: the
``min_vectors`` rule (:func:`min_core_vectors`: a campaign keeps cores at least as wide as
its final window) and the rms threshold keep most of them out, not all. The Lamb-Oseen fits
of the cores are :mod:`rspiv.vortex_fits`' (their names are kept here too).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.vortex_fits import (
    OSEEN_CROWDED,
    OSEEN_FIELDS,
    OSEEN_JOINT_MAX,
    OSEEN_MIN_FIT,
    fit_neighbours,
    fit_oseen,
    oseen_velocity,
)

# the Lamb-Oseen fits live in rspiv.vortex_fits; their names are kept here too
__all__ = [
    "CORE_FIELDS",
    "OSEEN_CROWDED",
    "OSEEN_FIELDS",
    "OSEEN_JOINT_MAX",
    "OSEEN_MIN_FIT",
    "SPLIT_SADDLE",
    "VortexAccumulator",
    "batch_density_se",
    "confirm_splits",
    "find_vortices",
    "fit_neighbours",
    "fit_oseen",
    "min_core_vectors",
    "oseen_velocity",
]

#: The per-core arrays :func:`find_vortices` returns.
CORE_FIELDS = ("x", "y", "sign", "vectors", "radius", "circulation", "peak", "region")

#: A thresholded region is split into one core per swirl maximum where the swirl between two
#: maxima falls to this share of the lower one or below (:func:`find_vortices`' ``split``).
#: Two exact Lamb-Oseen vortices of one sense and one r_c make one region up to about 2.9 r_c
#: apart (at the tests' threshold), with two swirl maxima from 1.8 r_c apart; the swirl between
#: them falls to 0.85 of the maxima at 1.8 r_c, 0.66-0.71 at 2.0 and 0.46 at 2.2. A single fit
#: of such a region takes both for one vortex of twice the circulation that explains 91-97 %
#: of its patch (``tests/test_vortices.py``).
SPLIT_SADDLE = 0.75

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
    split: float | None = None,
    regions=None,
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
    split : float or None
        A region is split at saddles of its swirl at most this share of the lower maximum
        (module docstring: ``region``; 0 < split < 1, usually :data:`SPLIT_SADDLE`); None
        keeps each region one core. The noise of a PIV field splits regions too: a split is
        confirmed by fitting the parts (:func:`confirm_splits`).
    regions : array_like of int, optional
        With ``split``, split only the regions of these numbers (``region``); the others stay
        whole, after the split ones of their sign. Default: every region.

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
    if split is not None and not 0.0 < split < 1.0:
        raise InvalidInputError(f"vortices: split must lie between 0 and 1, got {split}")
    xs = dx * np.arange(s.shape[1]) if x is None else np.asarray(x, np.float64)
    ys = dy * np.arange(s.shape[0]) if y is None else np.asarray(y, np.float64)
    if xs.shape != (s.shape[1],) or ys.shape != (s.shape[0],):
        raise InvalidInputError("vortices: x and y must give the columns' and rows' coordinates")
    mag = np.abs(s)
    with np.errstate(invalid="ignore"):
        strong = np.isfinite(s) & (mag >= thr)
    out: dict[str, list[np.ndarray]] = {k: [] for k in CORE_FIELDS}
    wz = np.where(np.isfinite(w), w, 0.0)
    numbered = 0  # the regions numbered before this sign's
    # the swirl against its row's threshold: where the threshold follows the swirl's rms with
    # height, a maximum of |swirl| alone sits at the edge of a region nearest the wall
    with np.errstate(invalid="ignore", divide="ignore"):
        level = np.where(strong, mag / thr, 0.0)
    for sign in (1.0, -1.0):
        labels, n = ndimage.label(strong & (np.sign(s) == sign), structure=_EIGHT)
        if n == 0:
            continue
        region = np.arange(n + 1) + numbered  # each label's region (label 0: none)
        numbered += n
        if split is not None and regions is None:
            labels, region = _split_regions(labels, region, level, split, min_vectors)
            n = region.size - 1
        elif split is not None:  # these regions alone split, after the others
            chosen = np.isin(region, np.asarray(regions, np.float64).ravel())
            chosen[0] = False
            if chosen.any():  # their labels left empty, their parts numbered after n
                alone = np.where(chosen[labels], labels, 0)
                cut, cut_region = _split_regions(alone, region, level, split, min_vectors)
                labels = np.where(alone > 0, cut + n, labels)
                region = np.concatenate([region, cut_region[1:]])
                n = region.size - 1
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
        out["region"].append(region[keep])
    return {
        k: (np.concatenate(v) if v else np.zeros(0)).astype(np.float64) for k, v in out.items()
    }


def _split_regions(
    labels: np.ndarray, region: np.ndarray, mag: np.ndarray, split: float, min_vectors: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each region of ``labels`` (8-neighbour, 1..n; ``region`` each label's region number)
    split at its swirl's saddles (:func:`find_vortices`' ``region``): the new labels and each
    new label's region number. Vectorised but for the merging of the parts, in a loop over
    the pairs of touching parts (a few per region)."""
    ny, nx = labels.shape
    at = np.flatnonzero(labels)
    lab = labels.ravel()[at]
    m = mag.ravel()[at]
    # each labelled vector's place in `at` on the grid with a border (-1: none); the labels are
    # one sign's 8-neighbour regions, so a labelled neighbour is in the same region
    i, j = np.divmod(at, nx)
    wb = nx + 2
    here = (i + 1) * wb + j + 1
    pos = np.full((ny + 2) * wb, -1, np.int64)
    pos[here] = np.arange(at.size)
    # steepest ascent: each vector's highest neighbour (itself at a maximum)
    up = np.arange(at.size)
    best = m.copy()
    for di, dj in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
        q = pos[here + di * wb + dj]
        val = np.where(q >= 0, m[q], -np.inf)
        higher = val > best
        up[higher] = q[higher]
        best[higher] = val[higher]
    while True:  # each vector's maximum, by pointer doubling
        nxt = up[up]
        if np.array_equal(nxt, up):
            break
        up = nxt
    tops, part = np.unique(up, return_inverse=True)
    if tops.size == region.size - 1:  # one maximum per region: nothing to split
        return labels, region
    peak = m[tops]
    size = np.bincount(part, minlength=tops.size)
    # the saddle of each pair of touching parts: the highest min(|swirl|) across their border
    keys, sad = [], []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        q = pos[here + di * wb + dj]
        a = np.flatnonzero(q >= 0)
        b = q[a]
        cross = part[a] != part[b]
        a, b = a[cross], b[cross]
        keys.append(np.minimum(part[a], part[b]) * tops.size + np.maximum(part[a], part[b]))
        sad.append(np.minimum(m[a], m[b]))
    key, saddle = np.concatenate(keys), np.concatenate(sad)
    root = np.arange(tops.size)
    if key.size:
        order = np.lexsort((-saddle, key))
        key, saddle = key[order], saddle[order]
        first = np.r_[True, key[1:] != key[:-1]]
        key, saddle = key[first], saddle[first]
        pa, pb = np.divmod(key, tops.size)

        def find(x: int) -> int:
            while root[x] != x:
                root[x] = root[root[x]]
                x = root[x]
            return x

        # the highest saddles first: a part joins its neighbour unless both maxima stand
        # clear of the saddle and both parts are cores on their own
        for k in np.argsort(-saddle, kind="stable"):
            ra, rb = find(int(pa[k])), find(int(pb[k]))
            if ra == rb:
                continue
            apart = saddle[k] <= split * min(peak[ra], peak[rb])
            if apart and size[ra] >= min_vectors and size[rb] >= min_vectors:
                continue
            hi, lo = (ra, rb) if peak[ra] >= peak[rb] else (rb, ra)
            root[lo] = hi
            size[hi] += size[lo]
        while not np.array_equal(root[root], root):  # every part to its root
            root = root[root]
    kept, new = np.unique(root, return_inverse=True)
    out = np.zeros(ny * nx, np.int64)
    out[at] = new[part] + 1
    # each new label's region: that of any of its vectors
    reg = np.zeros(kept.size + 1, np.int64)
    reg[new[part] + 1] = region[lab]
    return out.reshape(ny, nx), reg


def confirm_splits(
    u, v, cores: dict[str, np.ndarray], parts: Any, dx: float, dy: float, **fit: Any
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The cores of a field with the regions that hold two vortices or more split, and their
    Lamb-Oseen fits.

    A region of swirl can hold two vortices of one sense (closer than about three core
    radii: one core, whose single fit takes both for one vortex of twice the circulation),
    but the noise of a PIV field also makes maxima over saddles: split by the swirl alone, the
    demo's PIV fields counted 25-30 % more cores than their exact fields. So a region is split
    only where its one fit is kept and its parts' joint fit, started from the parts
    (:func:`fit_oseen`), is kept too: each
    part a vortex of its own sense within two core radii of its centroid, holding at least
    half its part's circulation inside the threshold (one vortex given as two parts fits as
    itself and a vortex of the noise of a few per cent of its circulation), no two of one
    sense closer than their mean core radius, and the group explaining ``OSEEN_MIN_FIT`` of
    its patch.

    Parameters
    ----------
    u, v : array_like, (ny, nx)
        The field, as for :func:`fit_oseen`.
    cores : dict
        :func:`find_vortices` of the field without ``split``.
    parts : dict or callable
        :func:`find_vortices` of it with ``split`` (the same swirl, threshold and grid), or a
        function of the regions worth splitting (those whose one fit is kept) that gives it
        (``find_vortices(..., split=SPLIT_SADDLE, regions=...)``: no other region is split).
    dx, dy : float
        Grid spacing, px.
    **fit
        :func:`fit_oseen`'s keywords (``valid``, ``x``, ``y``, ``orient``, ...).

    Returns
    -------
    cores, fits : dict
        The cores (``cores``' but for the regions whose split is confirmed, which are
        ``parts``', each part a core; positive cores first, then by region) and
        :func:`fit_oseen` of them.
    """
    region = np.asarray(cores.get("region", ()), np.float64)
    if region.size != np.asarray(cores["x"]).size:
        raise InvalidInputError("oseen: cores and parts must be find_vortices' of one field")
    fits = fit_oseen(u, v, cores, dx, dy, **fit)
    # only a region whose one fit is kept can be two vortices fitted as one (two vortices of
    # one sense 2-2.5 r_c apart: the one fit explains 91-97 % of its patch); most regions of
    # noise are not kept, and trying them would cost as much as the fits themselves
    kept = np.unique(region[fits["ok"]])
    if kept.size == 0:
        return cores, fits
    if callable(parts):
        parts = parts(kept)
    preg = np.asarray(parts.get("region", ()), np.float64)
    if preg.size != np.asarray(parts["x"]).size:
        raise InvalidInputError("oseen: cores and parts must be find_vortices' of one field")
    got, count = np.unique(preg, return_counts=True)
    many = got[(count >= 2) & (count <= OSEEN_JOINT_MAX)]
    many = many[np.isin(many, kept)]
    if many.size == 0:
        return cores, fits
    # the parts of these regions fitted on their own (their joint fits from the parts)
    trial_at = np.flatnonzero(np.isin(preg, many))
    trial = {k: np.asarray(val)[trial_at] for k, val in parts.items()}
    tf = fit_oseen(u, v, trial, dx, dy, **fit)
    held = tf["ok"] & tf["joint"]
    confirmed = [r for r in many if held[trial["region"] == r].all()]
    if not confirmed:
        return cores, fits
    whole = np.flatnonzero(~np.isin(region, confirmed))
    split = np.flatnonzero(np.isin(preg, confirmed))
    out = {k: np.concatenate([np.asarray(cores[k])[whole], np.asarray(parts[k])[split]])
           for k in CORE_FIELDS}  # fmt: skip
    order = np.lexsort((out["region"], -out["sign"]))
    out = {k: val[order] for k, val in out.items()}
    return out, fit_oseen(u, v, out, dx, dy, **fit)


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
