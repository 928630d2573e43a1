"""Fiducials of a target plate: the marks that fix its origin and axes.

A plate's lattice has no origin and, seen by a rotated camera, no preferred axis. Plates mark
them with *fiducials*: a dot larger, smaller, brighter or dimmer than the others, a missing dot,
a hollow ring, or a printed square or triangle on a lattice site. This module finds them on one
level's lattice (indices ``(u, v)`` from :mod:`rspiv.plate`), reads their shape from the image,
and chooses the origin and the +u axis.

Candidates
----------
A marker whose fitted size or amplitude departs from the median of its (at least three) level
neighbours' by more than :data:`FIDUCIAL_SIZE` / :data:`FIDUCIAL_AMPLITUDE` (log ratio), or an
interior site whose four neighbours are all present while it is empty (the detector may leave a
printed shape unfitted, or the plate may have no dot there), is a candidate; so is an empty site
at the lattice's edge (three neighbours) when a shape is read there, and a blob off every
lattice half-way between sites (:func:`off_site`: where two-level plates print their marks, at
the centre of a cell of the union of the levels) when a shape is read there. Such a fiducial's
site is a half-integer ``(u, v)``, and object coordinates relative to it are half-integer
multiples of the pitch. A shape mark of the dots' size and contrast on a site is not searched
for: a plate's fiducials are larger than its dots.

Shape
-----
Each candidate's mark is read from the image within half the distance to its nearest other
marker: the pixels above half its height over the median level there (bright or dark marks
alike), the connected part at the site, its holes filled. With ``z = (x - xc) + i (y - yc)``
about the filled region's centroid, the normalised complex moments
``c_n = |sum z^n| / sum |z|^n`` are 0 for a disc, about 0.6 (``n = 3``) for a triangle and 0.4
(``n = 4``) for a square, blurred or not. Measured on rendered marks of circumradius 4-40 px
with 1 px blur and 12-bit noise, a disc's stay below 0.09, a square's ``c_3`` below 0.22, a
triangle's ``c_4`` below 0.25, and every regular mark's ``c_2`` (elongation) below 0.21.

- Regions smaller than a disc of radius :data:`MIN_SHAPE_RADIUS_PX` (a triangle of
  circumradius 4 px blurred by 1 px covers 2.4 px) or elongated (``c_2 > C2_MAX``; OpenPTV's
  plate: its isosceles triangle 0.13, a glint on its edge 0.57, the "0" of its label beyond)
  have no shape: they keep the kind their size or contrast gave.
- A region whose holes fill more than :data:`RING_HOLE` of it is a ``"ring"``;
- a ``"triangle"`` when ``c_3 > C3_TRIANGLE`` and ``c_3 / 0.6 > c_4 / 0.4``;
- a ``"square"`` when ``c_4 > C4_SQUARE`` and ``c_4 / 0.4 > c_3 / 0.6``.

Origin and axes
---------------
- Shape fiducials (square, ring, triangle: printed on purpose) come first: the origin is the one
  of the highest rank in :data:`ORIGIN_RANK` when that kind appears once on the level.
- Otherwise a level with exactly one candidate holds the origin (several size or contrast
  outliers of no shape are no fiducial: the origin is then the level's marker nearest the image
  centre, the paper's central marker).
- Another shape fiducial on a lattice line through the origin fixes the axes: the indices are
  turned by a multiple of 90 degrees so that it lies on +u. Without one, +u is the lattice axis
  nearest the image's +x (:func:`rspiv.plate.analyse_plate`). The turn keeps the handedness of
  the image, so a plate seen from behind reads mirrored.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = [
    "FIDUCIAL_SIZE",
    "FIDUCIAL_AMPLITUDE",
    "ORIGIN_RANK",
    "SHAPES",
    "candidates",
    "edge_sites",
    "off_site",
    "lattice_coordinates",
    "shape_at",
    "local_contrast",
    "classify_shape",
    "choose",
    "turn_to_axis",
]

#: Candidates: |log(size / neighbours' size)| and |log(amplitude / neighbours')| above.
FIDUCIAL_SIZE = 0.15
FIDUCIAL_AMPLITUDE = 0.3
#: Shape: the holes' share of a ring's filled region, and the moment thresholds.
RING_HOLE = 0.2
C3_TRIANGLE = 0.25
C4_SQUARE = 0.15
C2_MAX = 0.3
MIN_SHAPE_RADIUS_PX = 2.2
#: The kinds that mark a plate on purpose, in the order they take the origin.
SHAPES = ("square", "ring", "triangle")
ORIGIN_RANK = SHAPES

_NB4 = ((1, 0), (-1, 0), (0, 1), (0, -1))


def local_contrast(
    ij: np.ndarray, values: np.ndarray, steps: tuple = _NB4, min_neighbours: int = 1
) -> np.ndarray:
    """log(value) minus the median log of the neighbours at ``steps`` (NaN with fewer than
    ``min_neighbours``; the median keeps one odd neighbour, a fiducial, from marking the
    others)."""
    at = {(int(a), int(b)): k for k, (a, b) in enumerate(ij)}
    lv = np.log(np.maximum(np.abs(values), 1e-300))
    out = np.full(len(ij), np.nan)
    for k, (a, b) in enumerate(ij):
        nb = [at.get((int(a) + da, int(b) + db)) for da, db in steps]
        nb = [q for q in nb if q is not None]
        if nb and len(nb) >= min_neighbours:
            out[k] = lv[k] - float(np.median(lv[nb]))
    return out


def candidates(uv: np.ndarray, size: np.ndarray, amp: np.ndarray) -> list[dict[str, Any]]:
    """Fiducial candidates on one level's lattice: dicts of ``kind``, ``row`` (into ``uv``, or
    None for an empty site) and ``site`` ``(u, v)``."""
    cands: list[dict[str, Any]] = []
    cs = local_contrast(uv, size, min_neighbours=3)
    ca = local_contrast(uv, amp, min_neighbours=3)
    for k in range(len(uv)):
        kind = None
        if np.isfinite(cs[k]) and abs(cs[k]) > FIDUCIAL_SIZE:
            kind = "larger" if cs[k] > 0 else "smaller"
        elif np.isfinite(ca[k]) and abs(ca[k]) > FIDUCIAL_AMPLITUDE:
            kind = "brighter" if ca[k] > 0 else "dimmer"
        if kind:
            cands.append({"kind": kind, "row": k, "site": (int(uv[k, 0]), int(uv[k, 1]))})
    at = {(int(a), int(b)) for a, b in uv}
    for a, b in at:
        for da, db in _NB4:
            s = (a + da, b + db)
            if s in at:
                continue
            if all((s[0] + ea, s[1] + eb) in at for ea, eb in _NB4):
                cand = {"kind": "missing", "row": None, "site": s}
                if cand not in cands:
                    cands.append(cand)
    return cands


def edge_sites(uv: np.ndarray) -> list[tuple[int, int]]:
    """Empty sites with three of their four neighbours present (the lattice's edge): a shape
    fiducial the detector left unfitted may sit there (they are candidates only when a shape is
    read at them: a dot lost at the plate's edge is no fiducial)."""
    at = {(int(a), int(b)) for a, b in uv}
    out = set()
    for a, b in at:
        for da, db in _NB4:
            s = (a + da, b + db)
            if s not in at and sum((s[0] + ea, s[1] + eb) in at for ea, eb in _NB4) == 3:
                out.add(s)
    return sorted(out)


def lattice_coordinates(
    uv: np.ndarray, px: np.ndarray, points: np.ndarray, k: int = 12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fractional ``(u, v)`` of image ``points`` on a lattice of sites ``uv`` at ``px``: an
    affine fit of the ``k`` sites nearest each point (image px from ``(u, v)``), inverted at
    it. Returns the coordinates (NaN where the fit is singular), each fit's mean step (px) and
    the distances to the ``k`` nearest sites (px), one row per point."""
    uvf, pxf = np.asarray(uv, dtype=np.float64), np.asarray(px, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    k = min(k, len(pxf))
    dist, near = cKDTree(pxf).query(pts, k=k)
    dist, near = dist.reshape(len(pts), k), near.reshape(len(pts), k)
    frac = np.full((len(pts), 2), np.nan)
    step = np.zeros(len(pts))
    for n, (b, q) in enumerate(zip(pts, near, strict=True)):
        design = np.column_stack([np.ones(k), uvf[q]])
        coef, *_ = np.linalg.lstsq(design, pxf[q], rcond=None)
        steps = coef[1:]  # rows: image step of +u, of +v
        step[n] = float(np.mean(np.hypot(steps[:, 0], steps[:, 1])))
        try:
            frac[n] = np.linalg.solve(steps.T, b - coef[0])
        except np.linalg.LinAlgError:
            pass
    return frac, step, dist


def off_site(
    uv: np.ndarray, px: np.ndarray, blobs: np.ndarray, tol: float = 0.12
) -> list[tuple[tuple[float, float], np.ndarray]]:
    """Blobs (off every lattice) that sit half-way between sites of a level: at ``(u + 1/2, v)``,
    ``(u, v + 1/2)`` or ``(u + 1/2, v + 1/2)`` within ``tol`` of the level's pitch, inside the
    lattice (three of its markers within 1.6 pitches). Where commercial two-level plates print
    their fiducials (the centre of a cell of the union of the levels).

    Each blob's fractional ``(u, v)`` is :func:`lattice_coordinates`'; returns
    ``(site, blob_px)``.
    """
    out: list[tuple[tuple[float, float], np.ndarray]] = []
    blobs = np.asarray(blobs, dtype=np.float64).reshape(-1, 2)
    if len(px) < 6 or len(blobs) == 0:
        return out
    frac, step, dist = lattice_coordinates(uv, px, blobs)
    for f, pitch, d, b in zip(frac, step, dist, blobs, strict=True):
        if np.count_nonzero(d < 1.6 * pitch) < 3 or not np.all(np.isfinite(f)):
            continue
        half = np.round(2.0 * f)
        if np.max(np.abs(2.0 * f - half)) > 2.0 * tol or np.all(half % 2 == 0):
            continue  # not half-way, or on a site (the empty-site probes cover those)
        out.append(((float(half[0]) / 2.0 + 0.0, float(half[1]) / 2.0 + 0.0), b))  # no -0.0
    return out


def shape_at(
    image: np.ndarray, at: np.ndarray, others_px: np.ndarray, dark: bool
) -> tuple[str | None, np.ndarray]:
    """:func:`classify_shape` of the mark at ``at`` within half the distance to the nearest of
    ``others_px`` (itself, at distance 0, excluded): the kind and the centroid."""
    d = np.hypot(*(np.asarray(others_px, dtype=np.float64).reshape(-1, 2) - at).T)
    d = d[d > 1e-6]
    if len(d) == 0:
        return None, np.asarray(at, dtype=np.float64)
    kind, centroid, _ = classify_shape(image, at, 0.5 * float(np.min(d)), dark)
    return kind, centroid


def classify_shape(
    image: np.ndarray, centre_px: np.ndarray, radius_px: float, dark: bool
) -> tuple[str | None, np.ndarray, dict[str, float]]:
    """The shape of the mark at ``centre_px`` within ``radius_px`` (see the module notes).

    Returns
    -------
    kind : {"ring", "square", "triangle", None}
        None: round, too small to tell, or no mark there.
    centroid : ndarray (2,)
        The filled region's centroid (px; ``centre_px`` when there is no mark).
    measures : dict
        ``c3``, ``c4``, ``hole`` (share of the filled region), ``radius`` (equivalent, px).
    """
    c = np.asarray(centre_px, dtype=np.float64)
    h, w = image.shape
    r = max(2.0, float(radius_px))
    x0, x1 = max(0, int(np.floor(c[0] - r))), min(w, int(np.ceil(c[0] + r)) + 1)
    y0, y1 = max(0, int(np.floor(c[1] - r))), min(h, int(np.ceil(c[1] + r)) + 1)
    none: dict[str, float] = {"c3": 0.0, "c4": 0.0, "hole": 0.0, "radius": 0.0}
    if x1 - x0 < 5 or y1 - y0 < 5:
        return None, c, none
    patch = image[y0:y1, x0:x1].astype(np.float64)
    if dark:
        patch = -patch
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    inside = np.hypot(xx - c[0], yy - c[1]) <= r
    level = float(np.median(patch[inside]))
    height = float(np.max(ndimage.uniform_filter(patch, 3)[inside])) - level
    if not height > 0:
        return None, c, none
    mask = (patch - level > 0.5 * height) & inside
    labels, n = ndimage.label(mask)
    if n == 0:
        return None, c, none
    # The part at the site: the one holding the pixel nearest the centre among its pixels.
    d = np.where(mask, np.hypot(xx - c[0], yy - c[1]), np.inf)
    part = labels == labels.flat[int(np.argmin(d))]
    filled = ndimage.binary_fill_holes(part)
    area = float(np.count_nonzero(filled))
    hole = 1.0 - np.count_nonzero(part) / area
    xs, ys = xx[filled], yy[filled]
    centroid = np.array([xs.mean(), ys.mean()])
    z = (xs - centroid[0]) + 1j * (ys - centroid[1])
    a = np.abs(z)
    c2 = float(abs(np.sum(z**2)) / max(np.sum(a**2), 1e-300))
    c3 = float(abs(np.sum(z**3)) / max(np.sum(a**3), 1e-300))
    c4 = float(abs(np.sum(z**4)) / max(np.sum(a**4), 1e-300))
    radius = float(np.sqrt(area / np.pi))
    measures = {"c2": c2, "c3": c3, "c4": c4, "hole": float(hole), "radius": radius}
    if radius < MIN_SHAPE_RADIUS_PX or c2 > C2_MAX:
        return None, centroid, measures
    if hole > RING_HOLE:
        return "ring", centroid, measures
    if c3 > C3_TRIANGLE and c3 / 0.6 > c4 / 0.4:
        return "triangle", centroid, measures
    if c4 > C4_SQUARE and c4 / 0.4 > c3 / 0.6:
        return "square", centroid, measures
    return None, centroid, measures


def choose(cands: list[dict[str, Any]]) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The origin fiducial and the axis fiducial (or None) among a level's candidates (each with
    its final ``kind``; see the module notes)."""
    shapes = [f for f in cands if f["kind"] in SHAPES]
    origin = None
    for kind in ORIGIN_RANK:
        of_kind = [f for f in shapes if f["kind"] == kind]
        if len(of_kind) == 1:
            origin = of_kind[0]
            break
        if of_kind:  # two of the top kind: no origin can be told
            return None, None
    if origin is None:
        return (cands[0] if len(cands) == 1 else None), None
    o = np.array(origin["site"])
    on_axis = [
        f for f in shapes
        if f is not origin and np.count_nonzero(np.array(f["site"]) - o) == 1
    ]  # fmt: skip
    if not on_axis:
        return origin, None
    return origin, min(on_axis, key=lambda f: float(np.abs(np.array(f["site"]) - o).sum()))


def turn_to_axis(uv: np.ndarray, origin: tuple[int, int], axis: tuple[int, int]) -> np.ndarray:
    """``uv`` turned by the multiple of 90 degrees that puts ``axis`` on +u from ``origin``."""
    d = np.array(axis) - np.array(origin)
    out = np.asarray(uv).copy()
    for _ in range(4):
        if d[0] > 0 and d[1] == 0:
            return out
        d = np.array([-d[1], d[0]])
        out = np.column_stack([-out[:, 1], out[:, 0]])
    raise ValueError(f"axis fiducial {axis} is not on a lattice line through {origin}")
