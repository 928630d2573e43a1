"""The target plate behind an indexed lattice: one level or two, and the fiducial.

Commercial calibration plates often carry two interleaved square lattices of the same pitch at
two depths, staggered by half a pitch along both axes. Seen together they form one square
lattice of pitch ``pitch / sqrt(2)`` at 45 degrees to the plate's axes: calibrating on it mixes
two depths and reports a magnification off by ``sqrt(2)``. This module reads, from the grid
indexing of all detected markers (the *union* lattice, indices ``(i, j)`` from
:func:`rspiv._rspiv.index_grid`), whether the plate has one level or two, splits the levels,
indexes each on its own square lattice and finds the fiducial.

Seen obliquely, the second level shifts against the first's half-sites by a parallax ``t``. Up to
15 % of the union's step the union is still indexed as one lattice (the grid allows the
class-signed error, ``rspiv._rspiv.index_grid``); beyond, the grid takes one level and
:func:`union_of_levels` finds the other among the markers left out and rebuilds the union's
indices. Lattices of the same pitch beside the plate's (a stepped or 3-D target's other
sections) are counted by :func:`other_lattices` and reported, never mixed in.

Levels
------
The union lattice's two parity classes (``i + j`` even or odd) are the candidate levels. They
are told apart by

- **geometry**: a level farther from the camera is imaged smaller about the principal point
  (taken at the image centre). A cubic polynomial in ``(i, j)`` is fitted to all positions, and
  again with a parity-dependent similarity (shift, scale ``eps``, rotation); ``F`` is the
  extra-sum-of-squares statistic of those 4 parameters (``F >> 1``: two depths);
- **appearance**: each marker's log size and log amplitude minus the mean of its union
  neighbours (which are of the other class): smooth illumination and blur cancel, a level
  difference (contrast, focus, dot size) alternates. ``z`` is the class difference of its mean
  over its standard error.

Two levels when ``F > F_LEVELS`` or either ``|z| > Z_LEVELS``. If neither and the union
lattice's axes lie within 10 degrees of 45 degrees from the image axes, the plate is ambiguous
(a single-level plate turned 45 degrees, or two levels that look and scale alike) and is
refused unless the caller says ``levels=1`` or ``levels=2``. Level 1 is the nearer one (the
larger magnification) when the scale difference is significant, else the one of brighter dots.

Fiducials
---------
Each level's fiducials (a larger, smaller, brighter or dimmer dot, a missing dot, a hollow
ring, a printed square or triangle) are found and read by :mod:`rspiv.fiducial`, which chooses
the origin ``(0, 0)`` and, from a second shape fiducial on a lattice line through it, the +u
axis; the marker at the origin (if any) is left out of the fit. Without a fiducial the origin is
the level's marker nearest the image centre (the paper's central marker).

Indices
-------
A level's ``(u, v)`` index its own square lattice (``u`` along the axis nearest +x, ``v`` nearest
+y, both integers), relative to the origin; object coordinates are ``pitch_mm * (u, v)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from rspiv import _rspiv
from rspiv import fiducial as fid
from rspiv.errors import InvalidInputError

__all__ = [
    "PlateLayout",
    "analyse_plate",
    "union_of_levels",
    "other_lattices",
    "lattice_record",
    "lattice_line",
    "lattice_to_json",
    "lattice_problems",
    "lattice_from_json",
    "F_LEVELS",
    "Z_LEVELS",
]

#: Geometric test: F of the parity-dependent similarity above which the classes are two depths.
F_LEVELS = 50.0
#: Appearance test: |z| of the alternating log size or log amplitude above which they differ.
Z_LEVELS = 8.0
#: A plate's lattice: axes within this many degrees of square (an oblique view skews them a
#: little; a 3-D target or clutter lined up, much more), and at least this many markers along
#: each axis (a mapping of degree 2-3 in x and y needs them).
MAX_SKEW_DEG = 15.0
MIN_SPAN = 4
_NB4 = ((1, 0), (-1, 0), (0, 1), (0, -1))


@dataclass
class PlateLayout:
    """What :func:`analyse_plate` found.

    Attributes
    ----------
    levels : int
        1 or 2.
    level : int
        The level calibrated (1 or 2; 1 for a single-level plate).
    use : ndarray of bool (n,)
        Detections used for the calibration (the chosen level, the fiducial left out).
    indexed : ndarray of bool (n,)
        Detections on a lattice site of either level (the rest are rejected blobs).
    index : ndarray of float (n, 2)
        ``(u, v)`` on the chosen level's lattice relative to the origin (rows not in ``use``: 0):
        integers, or half-integers when the origin is a fiducial between sites.
    central : int
        Row (into the detections) of the chosen level's marker nearest the image centre.
    fiducial : dict or None
        ``kind`` ("square", "ring", "triangle", "larger", "smaller", "brighter", "dimmer" or
        "missing"), ``level``, ``site`` (its ``(u, v)`` before re-centring and turning; half-
        integers between sites), ``image_px``, and ``axis``: None, or the ``kind`` and
        ``image_px`` of the fiducial that fixed +u (:mod:`rspiv.fiducial`).
    summary : dict
        Per level: counts, pitch (px), and the tests' statistics, the scale ratio.
    other_px : ndarray (k, 2)
        The other level's markers (two-level plates).
    """

    levels: int
    level: int
    use: np.ndarray
    indexed: np.ndarray
    index: np.ndarray
    central: int
    fiducial: dict[str, Any] | None
    summary: dict[str, Any] = field(default_factory=dict)
    other_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def _class_z(contrast: np.ndarray, parity: np.ndarray) -> float:
    """The difference of the classes' mean contrast over its standard error."""
    ok = np.isfinite(contrast)
    a, b = contrast[(parity == 0) & ok], contrast[(parity == 1) & ok]
    if len(a) < 3 or len(b) < 3:
        return 0.0
    se = np.sqrt(np.var(a, ddof=1) / len(a) + np.var(b, ddof=1) / len(b))
    d = float(np.mean(a) - np.mean(b))
    return d / se if se > 0 else (np.inf if d != 0 else 0.0)


def _geometry_test(
    ij: np.ndarray, px: np.ndarray, parity: np.ndarray, centre: np.ndarray
) -> tuple[float, float, float]:
    """F of a parity-dependent similarity on top of a cubic in (i, j); the scale eps of class 1
    relative to class 0 and its standard error."""
    i, j = ij[:, 0].astype(np.float64), ij[:, 1].astype(np.float64)
    span = max(1.0, float(np.max(np.abs(ij))))
    i, j = i / span, j / span
    poly = np.column_stack([i**a * j**b for a in range(4) for b in range(4 - a)])  # 10 terms
    n, m = len(ij), poly.shape[1]
    z = np.zeros((n, m))
    base = np.block([[poly, z], [z, poly]])
    y = np.concatenate([px[:, 0], px[:, 1]])
    c1 = (parity == 1).astype(np.float64)
    dx, dy = (px[:, 0] - centre[0]) * c1, (px[:, 1] - centre[1]) * c1
    extra = np.column_stack(
        [
            np.concatenate([c1, np.zeros(n)]),
            np.concatenate([np.zeros(n), c1]),
            np.concatenate([dx, dy]),  # scale
            np.concatenate([-dy, dx]),  # rotation
        ]
    )
    full = np.hstack([base, extra])
    dof = 2 * n - full.shape[1]
    if dof < 4:
        return 0.0, 0.0, np.inf
    r0 = y - base @ np.linalg.lstsq(base, y, rcond=None)[0]
    coef, *_ = np.linalg.lstsq(full, y, rcond=None)
    r1 = y - full @ coef
    rss0, rss1 = float(r0 @ r0), float(r1 @ r1)
    s2 = rss1 / dof
    f = ((rss0 - rss1) / 4.0) / s2 if s2 > 0 else np.inf
    try:
        cov = np.linalg.inv(full.T @ full) * s2
        se = float(np.sqrt(cov[-2, -2]))
    except np.linalg.LinAlgError:
        se = np.inf
    return f, float(coef[-2]), se


def _orient(uv: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Rotate integer lattice indices by a multiple of 90 degrees so that +u points nearest +x
    and +v nearest +y in the image."""
    best, out = -np.inf, uv
    for k in range(4):
        r = uv.copy()
        for _ in range(k):
            r = np.column_stack([-r[:, 1], r[:, 0]])
        design = np.column_stack([np.ones(len(r)), r.astype(np.float64)])
        coef, *_ = np.linalg.lstsq(design, px, rcond=None)
        su, sv = coef[1], coef[2]  # image step of +u and +v
        score = su[0] / np.hypot(*su) + sv[1] / np.hypot(*sv)
        if score > best:
            best, out = score, r
    return out


def analyse_plate(
    image_px: np.ndarray,
    union_index: np.ndarray,
    found: np.ndarray,
    a1: Any,
    a2: Any,
    size: np.ndarray,
    amplitude: np.ndarray,
    image_shape: tuple[int, int],
    *,
    levels: int | None = None,
    level: int | None = None,
    image: np.ndarray | None = None,
    dark: bool = False,
    unfitted_px: np.ndarray | None = None,
) -> PlateLayout:
    """Levels, indices and fiducial of a target plate from its union lattice.

    Parameters
    ----------
    image_px : ndarray (n, 2)
        All detections (px).
    union_index, found : ndarray (n, 2) int, ndarray (n,) bool
        The grid indexing of all detections (:func:`rspiv._rspiv.index_grid`).
    a1, a2 : pair of float
        The union lattice's steps (px).
    size, amplitude : ndarray (n,)
        Each detection's fitted size (disc radius or Gaussian width, px) and amplitude.
    image_shape : (int, int)
        Height and width (the image centre stands for the principal point).
    levels : {None, 1, 2}
        Force one or two levels; None decides from the image.
    level : {None, 1, 2}
        The level to calibrate on; default the one holding the fiducial, else level 1.
    image : ndarray, optional
        The target image: the fiducials' shapes are read from it (:mod:`rspiv.fiducial`);
        without it they are told by size, contrast or absence only.
    dark : bool
        The markers are darker than the plate.
    unfitted_px : ndarray (k, 2), optional
        Blobs the detector found off its coarse lattice and did not fit (with the detections
        that no level indexes, the places where a fiducial between sites is looked for).

    Returns
    -------
    PlateLayout

    Raises
    ------
    InvalidInputError
        An ambiguous plate (see the module documentation), a level that does not exist, or too
        few markers on the chosen level.
    """
    if levels not in (None, 1, 2):
        raise InvalidInputError(f"levels must be 1 or 2, got {levels!r}")
    if level not in (None, 1, 2):
        raise InvalidInputError(f"level must be 1 or 2, got {level!r}")
    rows = np.flatnonzero(found)
    ij = np.asarray(union_index)[rows].astype(np.int64)
    px = np.asarray(image_px, dtype=np.float64)[rows]
    sz, am = np.asarray(size)[rows], np.asarray(amplitude)[rows]
    h, w = image_shape
    centre = np.array([0.5 * (w - 1), 0.5 * (h - 1)])
    s1, s2 = np.asarray(a1, dtype=np.float64), np.asarray(a2, dtype=np.float64)
    angle = float(np.degrees(np.arctan2(s1[1], s1[0])))
    diagonal = abs(abs(angle) % 90.0 - 45.0) < 10.0
    parity = (ij.sum(axis=1) % 2).astype(np.int64)
    n0, n1 = int(np.sum(parity == 0)), int(np.sum(parity == 1))
    f_geo, eps, eps_se = _geometry_test(ij, px, parity, centre) if min(n0, n1) >= 12 else (0, 0, 0)
    z_size = _class_z(fid.local_contrast(ij, sz), parity)
    z_amp = _class_z(fid.local_contrast(ij, am), parity)
    summary: dict[str, Any] = {
        "union_pitch_px": float(0.5 * (np.hypot(*s1) + np.hypot(*s2))),
        "union_angle_deg": angle,
        "parity_counts": [n0, n1],
        "levels_f": float(f_geo),
        "levels_scale": float(1.0 + eps),
        "levels_scale_se": float(eps_se),
        "levels_z_size": float(z_size),
        "levels_z_amplitude": float(z_amp),
    }
    told_apart = f_geo > F_LEVELS or abs(z_size) > Z_LEVELS or abs(z_amp) > Z_LEVELS
    if levels is None:
        if told_apart:
            levels = 2
        elif diagonal and min(n0, n1) >= 5:
            raise InvalidInputError(
                f"ambiguous plate: a lattice of {len(rows)} markers at {angle:+.1f} deg "
                f"(pitch {summary['union_pitch_px']:.1f} px) whose two interleaved halves "
                f"({n0} and {n1} markers) look and scale alike (scale ratio {1 + eps:.4f} "
                f"+/- {eps_se:.5f}, size z {z_size:+.1f}, amplitude z {z_amp:+.1f}): a "
                "single-level plate turned 45 degrees, or two levels that cannot be told apart; "
                "say levels=1 or levels=2"
            )
        else:
            levels = 1
    if levels == 1:
        if level == 2:
            raise InvalidInputError(
                f"level 2 does not exist: the plate has one level ({len(rows)} markers)"
            )
        uv_all = {0: ij}
        members = {0: np.arange(len(rows))}
        names = {0: 1}
    else:
        # Level 1: the nearer (larger image) when the scale difference is significant, else
        # the class of brighter dots.
        if f_geo > F_LEVELS:
            first = 1 if eps > 0 else 0
        else:
            first = 0 if np.nanmedian(np.abs(am[parity == 0])) >= np.nanmedian(
                np.abs(am[parity == 1])
            ) else 1  # fmt: skip
        uv_all, members, names = {}, {}, {}
        for c in (0, 1):
            m = np.flatnonzero(parity == c)
            i, j = ij[m, 0] - c, ij[m, 1]
            uv_all[c] = np.column_stack([(i + j) // 2, (j - i) // 2])
            members[c] = m
            names[c] = 1 if c == first else 2
        # The union indexing prunes a level's corners (one union neighbour each): take back
        # detections that sit on a level's extrapolated sites.
        spare = np.flatnonzero(~np.asarray(found, dtype=bool))
        for c in (0, 1):
            for k, site in _extend(uv_all[c], px[members[c]], image_px[spare]):
                rows = np.append(rows, spare[k])
                px = np.vstack([px, image_px[spare[k]]])
                sz = np.append(sz, np.asarray(size)[spare[k]])
                am = np.append(am, np.asarray(amplitude)[spare[k]])
                members[c] = np.append(members[c], len(rows) - 1)
                uv_all[c] = np.vstack([uv_all[c], site])
        summary["level_counts"] = {names[c]: len(members[c]) for c in (0, 1)}
    # Orient each level, find and read its fiducials.
    fid_of: dict[int, list[dict[str, Any]]] = {}
    chosen_fid: dict[int, tuple[dict[str, Any] | None, dict[str, Any] | None]] = {}
    for c in uv_all:
        m = members[c]
        if len(m) >= 3:
            uv_all[c] = _orient(uv_all[c], px[m])
        fid_of[c] = fid.candidates(uv_all[c], sz[m], am[m]) if len(m) >= 5 else []
        _read_shapes(fid_of[c], uv_all[c], px[m], image, image_px, dark)
        if image is not None and len(m) >= 6:
            off = np.ones(len(image_px), dtype=bool)
            off[rows] = False
            loose = np.vstack([np.asarray(image_px)[off], np.zeros((0, 2)) if unfitted_px is
                               None else np.asarray(unfitted_px).reshape(-1, 2)])  # fmt: skip
            fid_of[c] += _between_sites(uv_all[c], px[m], loose, image, image_px, dark)
        chosen_fid[c] = fid.choose(fid_of[c])
    # The level holding the fiducial: on one of its sites (a mark between sites, at the centre
    # of a cell of the union, belongs to both levels alike).
    origin_of = {c: chosen_fid[c][0] for c in uv_all}
    on_site = [
        c for c, f in origin_of.items()
        if f is not None and all(float(v).is_integer() for v in f["site"])
    ]  # fmt: skip
    if level is None:
        chosen = on_site[0] if len(on_site) == 1 else next(c for c in uv_all if names[c] == 1)
    else:
        chosen = next(c for c in uv_all if names[c] == level)
    m = members[chosen]
    uv = uv_all[chosen]
    fiducial = None
    keep = np.ones(len(m), dtype=bool)
    f, axis = chosen_fid[chosen]
    if f is not None:
        origin = np.array(f["site"])
        if axis is not None:  # the plate's +u: towards the axis fiducial
            turned = fid.turn_to_axis(np.vstack([uv, origin]), f["site"], axis["site"])
            uv, origin = turned[:-1], turned[-1]
        fiducial = {"kind": f["kind"], "level": names[chosen], "site": f["site"],
                    "image_px": [float(v) for v in f["image_px"]],
                    "axis": None if axis is None else {
                        "kind": axis["kind"], "image_px": [float(v) for v in axis["image_px"]]
                    }}  # fmt: skip
        if f["row"] is not None:
            keep[f["row"]] = False
    # Printed shapes are no dots: their fitted centres stay out of the fit.
    for g in fid_of[chosen]:
        if g["kind"] in fid.SHAPES and g["row"] is not None:
            keep[g["row"]] = False
    if f is None:
        k0 = int(np.argmin(np.hypot(*(px[m] - centre).T)))
        origin = uv[k0]
    summary["fiducial_candidates"] = {names[c]: len(fid_of[c]) for c in uv_all}
    summary["fiducial_kinds"] = {names[c]: sorted({f["kind"] for f in fid_of[c]}) for c in uv_all}
    used = m[keep]
    if len(used) < 5:
        raise InvalidInputError(
            f"level {names[chosen]} holds only {len(used)} markers, at least 5 are needed"
        )
    use = np.zeros(len(image_px), dtype=bool)
    use[rows[used]] = True
    indexed = np.zeros(len(image_px), dtype=bool)
    indexed[rows] = True
    index = np.zeros((len(image_px), 2), dtype=np.float64)
    index[rows[m]] = uv - origin
    central = int(rows[used][np.argmin(np.hypot(*(px[used] - centre).T))])
    steps = [np.hypot(*d) for d in _level_steps(uv, px[m])]
    summary["level_pitch_px"] = [float(v) for v in steps]
    other = px[members[1 - chosen]] if levels == 2 else np.zeros((0, 2))
    if levels == 2:
        # The other level's image scale relative to the chosen one's (class 1 / class 0 is
        # 1 + eps): below 1, the other level is farther from the camera.
        r = 1.0 + eps if chosen == 0 else 1.0 / (1.0 + eps)
        summary["other_scale"] = float(r)
        summary["other_scale_se"] = float(eps_se)
    return PlateLayout(
        levels=int(levels),
        level=int(names[chosen]),
        use=use,
        indexed=indexed,
        index=index,
        central=central,
        fiducial=fiducial,
        summary=summary,
        other_px=np.ascontiguousarray(other),
    )


def _read_shapes(
    cands: list[dict[str, Any]],
    uv: np.ndarray,
    px: np.ndarray,
    image: np.ndarray | None,
    all_px: np.ndarray,
    dark: bool,
) -> None:
    """Give each candidate its ``image_px`` and, with the image, its shape's kind and centroid
    (read within half the distance to the nearest other detection)."""
    edge = [] if image is None else fid.edge_sites(uv)
    probes = cands + [{"kind": None, "row": None, "site": s} for s in edge]
    for f in probes:
        at = px[f["row"]] if f["row"] is not None else _predict(uv, px, np.array(f["site"]))
        f["image_px"] = at
        if image is None:
            continue
        kind, centroid = fid.shape_at(image, at, all_px, dark)
        if kind is not None:
            f["kind"], f["image_px"] = kind, centroid
    cands.extend(f for f in probes[len(cands):] if f["kind"] is not None)


def union_of_levels(
    image_px: np.ndarray,
    index: np.ndarray,
    found: np.ndarray,
    a1: Any,
    a2: Any,
    centre: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The union indexing of a two-level plate whose union is no lattice, or None.

    Seen obliquely enough (a parallax beyond 15 % of the union's step), a two-level plate's
    union is no lattice for :func:`rspiv._rspiv.index_grid`, which then indexes one level and
    leaves the other's markers out. When the markers left out form a second lattice of the same
    steps (lengths within 5 %, axes within 3 degrees), interleaved with the first (80 % of its
    points within 1.25 steps of one of the first's), whose points sit at one common offset from
    the first's half-sites ``(i + 1/2, j + 1/2)`` (the parallax: their fractional positions in
    the first's lattice, :func:`rspiv.fiducial.lattice_coordinates`, agree within 0.1
    of a step about their median), the two are one plate: returns its union indexing
    ``(index, found, a1, a2)`` (:func:`analyse_plate`'s input; the second level in the odd
    parity class). None otherwise.
    """
    pts = np.asarray(image_px, dtype=np.float64)
    found = np.asarray(found, dtype=bool)
    rest = np.flatnonzero(~found)
    if len(rest) < 12 or len(rest) < 0.3 * np.count_nonzero(found):
        return None
    try:
        idx_b, found_b, _, b1, b2 = _rspiv.index_grid(np.ascontiguousarray(pts[rest]), centre, 0.3)
    except InvalidInputError:
        return None
    s1, s2 = np.asarray(a1, dtype=np.float64), np.asarray(a2, dtype=np.float64)
    la, lb = sorted([np.hypot(*s1), np.hypot(*s2)]), sorted([np.hypot(*b1), np.hypot(*b2)])
    if not np.allclose(la, lb, rtol=0.05):
        return None
    angle_a, angle_b = (float(np.degrees(np.arctan2(v[1], v[0]))) % 90.0 for v in (s1, b1))
    da = abs((angle_a - angle_b + 45.0) % 90.0 - 45.0)
    if da > 3.0:
        return None
    rows_a, rows_b = np.flatnonzero(found), rest[np.asarray(found_b, dtype=bool)]
    ij_a = np.asarray(index)[rows_a].astype(np.float64)
    tree = cKDTree(pts[rows_a])
    # Interleaved: a half-site is 0.71 of a step from the nearest site (a parallax moves it by
    # at most half a step). A second lattice beside the first (another section of a stepped or
    # 3-D target) is no second level.
    near = tree.query(pts[rows_b])[0] / float(np.mean(la))
    if np.mean(near < 1.25) < 0.8:
        return None
    frac, _, _ = fid.lattice_coordinates(ij_a, pts[rows_a], pts[rows_b])
    if not np.all(np.isfinite(frac)):
        return None
    # The common offset from the half-sites, taken circularly (a parallax near half a step).
    phase = np.angle(np.mean(np.exp(2j * np.pi * (frac - 0.5)), axis=0)) / (2 * np.pi)
    cell = np.round(frac - 0.5 - phase)
    off = frac - 0.5 - cell - phase
    if np.median(np.hypot(*off.T)) > 0.1:
        return None
    # Union indices (p, q) = (i + j, j - i) of the doubled coordinates; level B odd.
    ia, ja = np.round(ij_a).astype(np.int64).T
    ib, jb = cell.astype(np.int64).T
    union = np.zeros((len(pts), 2), dtype=np.int64)
    union[rows_a] = np.column_stack([ia + ja, ja - ia])
    union[rows_b] = np.column_stack([ib + jb + 1, jb - ib])
    both = np.zeros(len(pts), dtype=bool)
    both[rows_a] = True
    both[rows_b] = True
    return union, both, 0.5 * (s1 + s2), 0.5 * (s2 - s1)


def other_lattices(
    image_px: np.ndarray, indexed: np.ndarray, a1: Any, a2: Any, centre: tuple[float, float]
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The further lattices among the detections not ``indexed``: at most 3, of 12 markers or
    more, steps within 20 % of ``a1``/``a2``'s (a stepped or 3-D target's other sections, which
    a planar calibration leaves out), each as ``(index, found, a1, a2)`` over all detections
    (:func:`rspiv._rspiv.index_grid`'s output), largest first."""
    pts = np.asarray(image_px, dtype=np.float64)
    left = np.flatnonzero(~np.asarray(indexed, dtype=bool))
    s1, s2 = np.asarray(a1, dtype=np.float64), np.asarray(a2, dtype=np.float64)
    step = 0.5 * (np.hypot(*s1) + np.hypot(*s2))
    out: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for _ in range(8):  # grids of junk (too small, another step) are set aside, not counted
        if len(left) < 12 or len(out) == 3:
            break
        try:
            idx, found, _, b1, b2 = _rspiv.index_grid(np.ascontiguousarray(pts[left]), centre, 0.3)
        except InvalidInputError:
            break
        found = np.asarray(found, dtype=bool)
        n = int(np.count_nonzero(found))
        if n < 12 or abs(0.5 * (np.hypot(*b1) + np.hypot(*b2)) / step - 1.0) > 0.2:
            left = left[~found]
            continue
        full_idx = np.zeros((len(pts), 2), dtype=np.int64)
        full_idx[left] = np.asarray(idx)
        full_found = np.zeros(len(pts), dtype=bool)
        full_found[left] = found
        out.append((full_idx, full_found, np.asarray(b1), np.asarray(b2)))
        left = left[~found]
    return sorted(out, key=lambda g: -int(np.count_nonzero(g[1])))


def _between_sites(
    uv: np.ndarray,
    px: np.ndarray,
    loose: np.ndarray,
    image: np.ndarray,
    all_px: np.ndarray,
    dark: bool,
) -> list[dict[str, Any]]:
    """Shape fiducials among the loose blobs half-way between a level's sites."""
    out: list[dict[str, Any]] = []
    near = np.vstack([np.asarray(all_px, dtype=np.float64).reshape(-1, 2), loose])
    for site, b in fid.off_site(uv, px, loose):
        kind, centroid = fid.shape_at(image, b, near, dark)
        if kind is not None and all(np.hypot(*(centroid - f["image_px"])) > 1.0 for f in out):
            out.append({"kind": kind, "row": None, "site": site, "image_px": centroid})
    return out


def _extend(
    uv: np.ndarray, px: np.ndarray, cand: np.ndarray, tol: float = 0.1
) -> list[tuple[int, tuple[int, int]]]:
    """Candidates (rows of ``cand``) within ``tol`` of the local step of an empty site next to
    the lattice, predicted by linear extrapolation from the two sites before it along u or v."""
    if len(cand) == 0 or len(uv) < 5:
        return []
    at = {(int(a), int(b)): k for k, (a, b) in enumerate(uv)}
    su, sv = _level_steps(uv, px)
    step = 0.5 * (np.hypot(*su) + np.hypot(*sv))
    free = np.ones(len(cand), dtype=bool)
    out: list[tuple[int, tuple[int, int]]] = []
    empty = {
        (a + da, b + db) for a, b in at for da, db in _NB4 if (a + da, b + db) not in at
    }
    for site in sorted(empty):
        preds = []
        for da, db in _NB4:
            k1 = at.get((site[0] - da, site[1] - db))
            k2 = at.get((site[0] - 2 * da, site[1] - 2 * db))
            if k1 is not None and k2 is not None:
                preds.append(2.0 * px[k1] - px[k2])
        if not preds:
            continue
        d = np.hypot(*(cand - np.mean(preds, axis=0)).T)
        d[~free] = np.inf
        k = int(np.argmin(d))
        if d[k] < tol * step:
            free[k] = False
            out.append((k, site))
    return out


def _level_steps(uv: np.ndarray, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean image steps of +u and +v over a level (affine fit)."""
    design = np.column_stack([np.ones(len(uv)), uv.astype(np.float64)])
    coef, *_ = np.linalg.lstsq(design, px, rcond=None)
    return coef[1], coef[2]


def _predict(uv: np.ndarray, px: np.ndarray, site: np.ndarray) -> np.ndarray:
    """Image position of an empty site: the mean of the midpoints of its neighbours on either
    side, along each axis where both are present (both axes inside the lattice, one at its
    edge)."""
    at = {(int(a), int(b)): k for k, (a, b) in enumerate(uv)}
    a, b = int(site[0]), int(site[1])
    mids = []
    for da, db in ((1, 0), (0, 1)):
        p, q = at.get((a + da, b + db)), at.get((a - da, b - db))
        if p is not None and q is not None:
            mids.append(0.5 * (px[p] + px[q]))
    return np.mean(mids, axis=0)


def lattice_record(
    pts: np.ndarray,
    a1: Any,
    a2: Any,
    det: dict[str, Any],
    plate: PlateLayout,
) -> dict[str, Any]:
    """The lattice summary of a detection, its grid indexing and plate analysis (see
    :attr:`Calibration.lattice`)."""
    steps = plate.summary["level_pitch_px"]
    s1, s2 = np.asarray(a1, dtype=np.float64), np.asarray(a2, dtype=np.float64)
    if plate.levels == 2:  # the level's own axes: the union's diagonals
        s1, s2 = s1 + s2, s2 - s1
    l1, l2 = float(np.hypot(*s1)), float(np.hypot(*s2))
    cos = float(np.dot(s1, s2)) / (l1 * l2) if l1 > 0 and l2 > 0 else 0.0
    n_used = int(np.count_nonzero(plate.use))
    indexed = plate.indexed
    # Rejected: detections off every level's lattice, and the blobs the detector left unfitted.
    unfitted = np.asarray(det.get("rejected_px", np.zeros((0, 2))), dtype=np.float64)
    rejected = np.vstack([pts[~indexed], unfitted.reshape(-1, 2)])
    angle = float(np.degrees(np.arctan2(s1[1], s1[0])))
    angle = (angle + 45.0) % 90.0 - 45.0  # the axis nearest +x
    return {
        "pitch_px": [float(v) for v in steps],
        "angle_deg": angle,
        "axes_angle_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        "n_indexed": n_used,
        "n_detected": int(len(pts)) + len(unfitted),
        "n_rejected": len(rejected),
        "size_px": float(det["size_px"]),
        "polarity": "dark" if det.get("dark") else "bright",
        "profile": str(det.get("profile", "gaussian")),
        "levels": plate.levels,
        "level": plate.level,
        "other_level_px": np.ascontiguousarray(plate.other_px).reshape(-1, 2),
        "fiducial": plate.fiducial,
        "plate": {k: v for k, v in plate.summary.items()},
        "rejected_px": np.ascontiguousarray(rejected),
    }


def lattice_to_json(lattice: dict[str, Any] | None) -> dict[str, Any] | None:
    if lattice is None:
        return None
    out = {**lattice, "rejected_px": np.asarray(lattice["rejected_px"]).tolist()}
    if "other_level_px" in lattice:
        out["other_level_px"] = np.asarray(lattice["other_level_px"]).tolist()
    return out


def lattice_from_json(d: Any) -> dict[str, Any] | None:
    if d is None:
        return None
    if not isinstance(d, dict):
        raise ValueError("lattice is not an object")
    out = {k: d[k] for k in ("pitch_px", "angle_deg", "axes_angle_deg", "size_px")}
    out["polarity"] = str(d.get("polarity", "bright"))
    out["profile"] = str(d.get("profile", "gaussian"))
    out["levels"] = int(d.get("levels", 1))
    out["level"] = int(d.get("level", 1))
    out["fiducial"] = d.get("fiducial")
    out["plate"] = d.get("plate", {})
    out["other_level_px"] = np.asarray(d.get("other_level_px", []), dtype=np.float64).reshape(-1, 2)
    out["other_lattices"] = [int(v) for v in d.get("other_lattices", [])]
    out.update({k: int(d[k]) for k in ("n_indexed", "n_detected", "n_rejected")})
    out["pitch_px"] = [float(v) for v in out["pitch_px"]]
    out["rejected_px"] = np.asarray(d["rejected_px"], dtype=np.float64).reshape(-1, 2)
    return out


def lattice_line(la: dict[str, Any]) -> str:
    """One line describing a lattice record (:func:`lattice_record`)."""
    line = (
        "lattice: pitch {:.2f} x {:.2f} px (i, j), i axis at {:+.2f} deg from +x (towards "
        "+y), axes {:.2f} deg apart; {} markers indexed of {} detected ({} rejected); "
        "{} {} dots, size {:.2f} px".format(
            *la["pitch_px"], la["angle_deg"], la["axes_angle_deg"], la["n_indexed"],
            la["n_detected"], la["n_rejected"], la.get("polarity", "bright"),
            la.get("profile", "gaussian"), la["size_px"],
        )
    )  # fmt: skip
    pl = la.get("plate") or {}
    if la.get("levels", 1) == 2:
        r = pl.get("other_scale", 1.0)
        line += (
            f"; two-level plate: level {la['level']} used, the other level's "
            f"{len(la['other_level_px'])} markers imaged at {r:.5f} x its scale "
            f"(+/- {pl.get('other_scale_se', 0.0):.5f}: {100 * (1 / r - 1):+.2f} % of the "
            "working distance farther)"
        )
    sections = la.get("other_lattices") or []
    if sections:
        line += (
            f"; {len(sections)} other lattice(s) of the same pitch ({', '.join(map(str, sections))}"
            " markers) not used: a stepped or 3-D target? (calibrated on one flat section)"
        )
    fid = la.get("fiducial")
    if fid:
        line += "; origin on the {} fiducial at ({:.1f}, {:.1f}) px".format(
            fid["kind"], *fid["image_px"]
        )
        axis = fid.get("axis")
        line += (
            ", +u towards the {} fiducial at ({:.1f}, {:.1f}) px".format(
                axis["kind"], *axis["image_px"]
            )
            if axis
            else ", +u the lattice axis nearest +x"
        )
    else:
        line += "; origin on the central marker (no fiducial found)"
    return line


def lattice_problems(la: dict[str, Any], index: np.ndarray) -> list[str]:
    """What makes a lattice record (:func:`lattice_record`) no plate to calibrate on, given the
    used markers' ``(u, v)``: axes more than :data:`MAX_SKEW_DEG` from square, or fewer than
    :data:`MIN_SPAN` markers along an axis. Empty when it is fine."""
    out = []
    skew = float(la["axes_angle_deg"]) - 90.0
    if abs(skew) > MAX_SKEW_DEG:
        out.append(
            f"the lattice's axes are {la['axes_angle_deg']:.1f} deg apart ({la['n_indexed']} "
            "markers): no square plate lattice (a 3-D target? clutter lined up?)"
        )
    idx = np.asarray(index).reshape(-1, 2)
    span = [len(np.unique(idx[:, a])) for a in (0, 1)]
    if min(span) < MIN_SPAN:
        out.append(
            f"the lattice spans only {span[0]} x {span[1]} markers ({len(idx)} indexed): too "
            f"narrow for a mapping in x and y (at least {MIN_SPAN} along each axis)"
        )
    return out
