"""Synthetic calibration targets with a known lens distortion: the ground truth of calibration.

Python describes the scene (optics, lens, marker grid); Rust renders the pixels
(:func:`rspiv._rspiv.render_target`). Coordinates follow the README's pixel frame (x = column,
y = row, origin at the centre of the top-left pixel, y down).

Scene
-----
The target is a square grid of ``n_markers = (13, 7)`` dots at ``pitch_mm``; marker ``(i, j)``
(``i`` along +x, ``j`` along +y, ``(0, 0)`` the centre marker) lies at ``pitch_mm * (i, j)`` mm in
the target plane. Its *ideal* image (a perfect lens) is ``c + M R(rotation) pitch (i, j)`` with
``c`` the sensor centre plus ``grid_offset_px`` and ``M`` the magnification (px/mm); the lens then
moves it to its *true image position* :meth:`LensDistortion.distort` (or ``mapping.forward``).
Dots are rendered as isotropic Gaussian blobs of standard deviation ``dot_sigma_mm * M``, or
(``dot="disc"``) as printed discs of diameter ``dot_diameter_px`` blurred by a Gaussian PSF of
``blur_px``, centred exactly at that position (the true marker position); bright on a dark plate
or (``dark=True``) dark on a bright, vignetted plate. See ``dewarp_core::target`` for the
illumination (gradient, vignetting) and camera noise (shot + read noise, clipping to the bit
depth). ``clutter`` adds blobs off the plate (random sizes, the markers' polarity) and glare
spots: what a real photograph holds besides the target.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

__all__ = [
    "Optics",
    "PAPER_OPTICS",
    "LensDistortion",
    "paper_lens",
    "CalibrationTarget",
    "calibration_target",
]


@dataclass(frozen=True)
class Optics:
    """Camera and target of a synthetic calibration (defaults: the paper's, section 3.1).

    Attributes
    ----------
    width, height : int
        Sensor size (px).
    magnification : float
        M, px/mm at the sensor centre.
    pitch_mm : float
        Marker pitch (mm).
    n_markers : tuple of int
        Markers along x and y (odd numbers: a centre marker exists).
    dot_sigma_mm : float
        Dot size as the standard deviation of its Gaussian profile (mm).
    amplitude : float
        Dot peak above background (counts, before illumination).
    bit_depth : int
        Camera bit depth (12: counts in [0, 4095]).
    """

    width: int = 8864
    height: int = 5288
    magnification: float = 34.538
    pitch_mm: float = 19.51
    n_markers: tuple[int, int] = (13, 7)
    dot_sigma_mm: float = 0.5
    amplitude: float = 2500.0
    bit_depth: int = 12

    def scaled(self, scale: float) -> Optics:
        """The same optics on a sensor ``scale`` times smaller in each direction (M scales)."""
        return dataclasses.replace(
            self,
            width=int(round(self.width * scale)),
            height=int(round(self.height * scale)),
            magnification=self.magnification * scale,
        )


PAPER_OPTICS = Optics()
"""The paper's optics: 8864 x 5288 px, M = 34.538 px/mm, 13 x 7 markers at 19.51 mm."""


@dataclass(frozen=True)
class LensDistortion:
    """Brown-Conrady radial + decentring lens distortion (ideal image px -> distorted image px).

    With ``u = (x - cx) / R``, ``v = (y - cy) / R``, ``r^2 = u^2 + v^2``::

        du = u ((k1 + ka) r^2 + k2 r^4) + 2 p1 u v + p2 (r^2 + 2 u^2)
        dv = v ((k1 - ka) r^2 + k2 r^4) + p1 (r^2 + 2 v^2) + 2 p2 u v
        x_d = x + R du,  y_d = y + R dv

    ``k1 > 0`` is pincushion. ``ka`` (default 0, not part of Brown-Conrady) makes the radial term
    anisotropic (stronger along x than y): a distortion that is not radially symmetric and that
    a rational R2 model cannot follow, while a bicubic P3 can. Coefficients are dimensionless
    (relative to ``R``), so :meth:`scaled` keeps the relative distortion on a smaller sensor.

    Attributes
    ----------
    k1, k2 : float
        Radial coefficients.
    p1, p2 : float
        Decentring (tangential) coefficients.
    ka : float
        Anisotropic radial coefficient.
    centre : tuple of float
        Distortion centre (px).
    radius : float
        Normalising radius R (px), e.g. the sensor's half diagonal.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 1.0
    ka: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.k1, self.k2, self.p1, self.p2, self.ka, *self.centre, self.radius)
        if not all(np.isfinite(v) for v in vals) or self.radius <= 0:
            raise InvalidInputError("LensDistortion: coefficients must be finite and radius > 0")

    def distort(self, points_px: npt.ArrayLike) -> np.ndarray:
        """Ideal (undistorted) image px -> distorted image px; ``(N, 2)`` in and out."""
        p = np.asarray(points_px, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise InvalidInputError(f"points must have shape (N, 2), got {p.shape}")
        u = (p[:, 0] - self.centre[0]) / self.radius
        v = (p[:, 1] - self.centre[1]) / self.radius
        r2 = u * u + v * v
        rad = self.k2 * r2 * r2
        radx = rad + (self.k1 + self.ka) * r2
        rady = rad + (self.k1 - self.ka) * r2
        du = u * radx + 2 * self.p1 * u * v + self.p2 * (r2 + 2 * u * u)
        dv = v * rady + self.p1 * (r2 + 2 * v * v) + 2 * self.p2 * u * v
        return np.column_stack([p[:, 0] + self.radius * du, p[:, 1] + self.radius * dv])

    def scaled(self, scale: float) -> LensDistortion:
        """The same lens on a sensor ``scale`` times smaller (centre and radius scale)."""
        return dataclasses.replace(
            self,
            centre=(self.centre[0] * scale, self.centre[1] * scale),
            radius=self.radius * scale,
        )

    @property
    def is_radial(self) -> bool:
        """True when the distortion is radially symmetric (no decentring)."""
        return self.p1 == 0.0 and self.p2 == 0.0 and self.ka == 0.0


def paper_lens(optics: Optics = PAPER_OPTICS, *, decentring: bool = True) -> LensDistortion:
    """The default lens: pincushion reaching 8-10 px at the sensor corners (paper: 9 px) plus a
    small decentring term (up to about 1.7 px at a corner), centre 20 px right and 12 px above the
    sensor centre (scaled with the sensor: ``optics.width / 8864``).
    """
    s = optics.width / PAPER_OPTICS.width
    cx = 0.5 * (optics.width - 1) + 20.0 * s
    cy = 0.5 * (optics.height - 1) - 12.0 * s
    radius = 0.5 * float(np.hypot(optics.width, optics.height))
    k1 = 8.0 * s / radius  # radial part 8 px at the half-diagonal
    p1, p2 = (1.0e-4, -0.6e-4) if decentring else (0.0, 0.0)
    return LensDistortion(k1=k1, k2=0.0, p1=p1, p2=p2, centre=(cx, cy), radius=radius)


@dataclass
class CalibrationTarget:
    """A rendered target and its ground truth.

    Attributes
    ----------
    image : ndarray of uint16, shape (height, width)
    markers_px : ndarray, shape (n, 2)
        True image positions (x, y) of the rendered grid markers (px).
    index : ndarray of int, shape (n, 2)
        Grid index (i, j) of each marker, (0, 0) the centre marker.
    spurious_px : ndarray, shape (k, 2)
        Centres of the spurious blobs (not markers).
    optics : Optics
    lens : LensDistortion or None
    mapping : object or None
        The Mapping used as the distortion instead of ``lens``.
    rotation_deg : float
    grid_offset_px : tuple of float
    """

    image: np.ndarray
    markers_px: np.ndarray
    index: np.ndarray
    spurious_px: np.ndarray
    optics: Optics
    lens: LensDistortion | None
    mapping: Any
    rotation_deg: float
    grid_offset_px: tuple[float, float]
    extra: dict[str, Any] = field(default_factory=dict)

    def __iter__(self) -> Any:
        """``image, markers_px = calibration_target(...)`` unpacks the image and the truth."""
        return iter((self.image, self.markers_px))

    def ideal_px(self, grid_ij: npt.ArrayLike) -> np.ndarray:
        """Ideal (undistorted) image px of continuous grid coordinates ``(i, j)``."""
        ij = np.asarray(grid_ij, dtype=np.float64).reshape(-1, 2)
        o = self.optics
        th = np.deg2rad(self.rotation_deg)
        c, s = np.cos(th), np.sin(th)
        step = o.magnification * o.pitch_mm
        cx = 0.5 * (o.width - 1) + self.grid_offset_px[0]
        cy = 0.5 * (o.height - 1) + self.grid_offset_px[1]
        x = cx + step * (c * ij[:, 0] - s * ij[:, 1])
        y = cy + step * (s * ij[:, 0] + c * ij[:, 1])
        return np.column_stack([x, y])

    def true_image_px(self, grid_ij: npt.ArrayLike) -> np.ndarray:
        """True image px of continuous grid coordinates ``(i, j)`` (the exact mapping)."""
        ideal = self.ideal_px(grid_ij)
        if self.mapping is not None:
            return np.asarray(self.mapping.forward(ideal))
        if self.lens is not None:
            return self.lens.distort(ideal)
        return ideal


def calibration_target(
    mapping: Any = None,
    rotation_deg: float = 0.0,
    scale: float = 1.0,
    noise: bool = True,
    seed: int = 0,
    *,
    lens: LensDistortion | None | str = "paper",
    optics: Optics = PAPER_OPTICS,
    missing: list[tuple[int, int]] | tuple[()] = (),
    spurious: int = 0,
    grid_offset_px: tuple[float, float] = (0.37, -0.21),
    read_noise: float = 4.0,
    gain: float = 0.5,
    dot: str = "gaussian",
    dot_diameter_px: float | None = None,
    blur_px: float = 1.0,
    dark: bool = False,
    vignetting: float = 0.15,
    bit_depth: int | None = None,
    clutter: int = 0,
    levels: int = 1,
    level_scale: float = 0.995,
    level_contrast: float = 0.8,
    level_shift_px: tuple[float, float] = (0.0, 0.0),
    fiducial: str | Sequence[str] | None = None,
    fiducial_site: tuple[int, int] | Sequence[tuple[int, int]] = (1, 0),
) -> CalibrationTarget:
    """Render a synthetic calibration target (uint16, 12-bit range) with its true markers.

    Parameters
    ----------
    mapping : Mapping, optional
        A distortion given as a mapping (object px = ideal image px -> image px); overrides
        ``lens``.
    rotation_deg : float
        Rotation of the target on the sensor (degrees, counter-clockwise in (x, y)).
    scale : float
        Sensor scale in (0, 1]: ``scale = 0.25`` renders a 2216 x 1322 sensor with M / 4 and the
        same relative distortion (fast tests).
    noise : bool
        Camera noise (shot noise of gain ``gain`` and read noise ``read_noise`` counts).
    seed : int
        Seed of the noise and of the spurious blobs.
    lens : LensDistortion, "paper" or None
        The distortion; ``"paper"`` is :func:`paper_lens` (scaled), ``None`` an ideal lens.
        A LensDistortion is used as given (give it in the scaled sensor's px).
    optics : Optics
        Full-size optics (scaled by ``scale``).
    missing : list of (i, j)
        Grid markers left out.
    spurious : int
        Number of spurious blobs (random size and brightness, away from every grid site).
    grid_offset_px : tuple of float
        Grid centre relative to the sensor centre (px at full scale).
    read_noise, gain : float
        Read noise (counts) and shot-noise gain (variance per count of signal), for 12 bit;
        scaled with the full scale for other bit depths.
    dot : {"gaussian", "disc"}
        Marker profile: a Gaussian blob, or a printed disc blurred by the lens.
    dot_diameter_px : float, optional
        Disc diameter (px, at the rendered scale); default ``4 * dot_sigma_mm * M``.
    blur_px : float
        Standard deviation of the disc's Gaussian blur (px).
    dark : bool
        Dark dots on a bright plate (the plate vignetted with the illumination).
    vignetting : float
        Fraction by which the illumination falls at the corners (0.8: a 5x fall).
    bit_depth : int, optional
        8, 12 or 16; default the optics' (12).
    clutter : int
        Number of blobs off the plate (random Gaussian or disc blobs of 0.5-3x the marker size
        and the markers' polarity, every fifth a large bright glare spot), at least one pitch
        beyond the outermost markers.
    levels : {1, 2}
        A two-level plate: a second lattice of the same pitch, staggered by half a pitch along
        both axes (sites ``(i + 1/2, j + 1/2)``), on a level farther from the camera: its image
        is scaled by ``level_scale`` about the sensor centre (the principal point) before the
        lens, and its dots have ``level_contrast`` times the amplitude. Its true positions and
        indices are ``extra["level2_px"]``, ``extra["level2_index"]`` (half-integer sites).
    level_shift_px : (float, float)
        The second level's parallax in an oblique view: its ideal image shifted by this many px
        (at the rendered scale) before the lens.
    fiducial : str or sequence of str, optional
        Fiducials on the first level, one per site of ``fiducial_site`` (a site, or one site per
        fiducial): ``"large"`` (a dot 1.6 times larger), ``"ring"`` (a hollow ring, outer radius
        1.6, inner 1.0 times the dot's), ``"missing"`` (no dot), ``"square"`` (a printed square
        of half side 1.3 dot radii, its edges along the lattice) or ``"triangle"`` (an
        equilateral triangle of circumradius 2 dot radii, a vertex towards the lattice's +i);
        a dot's radius is the disc's, or 2 sigma. A site may be half-way between two: a shape
        printed there (``(i + 1/2, j)``, ``(i, j + 1/2)``; on a one-level plate also
        ``(i + 1/2, j + 1/2)``) leaves every dot in place, as commercial two-level plates do.
        Fiducials on sites are left out of ``markers_px``/``index``; their true positions are
        ``extra["fiducial_px"]`` (k, 2), their sites ``extra["fiducial_sites"]`` (k, 2), the
        first's ``extra["fiducial_index"]``.

    Returns
    -------
    CalibrationTarget
    """
    if not (np.isfinite(scale) and 0.05 <= scale <= 1.0):
        raise InvalidInputError(f"scale must lie in [0.05, 1], got {scale!r}")
    if not np.isfinite(rotation_deg):
        raise InvalidInputError(f"rotation_deg must be finite, got {rotation_deg!r}")
    for name, v in (("spurious", spurious), ("clutter", clutter)):
        if not isinstance(v, (int, np.integer)) or v < 0:
            raise InvalidInputError(f"{name} must be a non-negative integer, got {v!r}")
    if dot not in ("gaussian", "disc"):
        raise InvalidInputError(f"dot must be 'gaussian' or 'disc', got {dot!r}")
    if not (np.isfinite(blur_px) and blur_px > 0):
        raise InvalidInputError(f"blur_px must be > 0, got {blur_px!r}")
    if not (np.isfinite(vignetting) and 0.0 <= vignetting < 1.0):
        raise InvalidInputError(f"vignetting must lie in [0, 1), got {vignetting!r}")
    if levels not in (1, 2):
        raise InvalidInputError(f"levels must be 1 or 2, got {levels!r}")
    fid_kinds, fid_sites = _fiducials(fiducial, fiducial_site)
    o = optics.scaled(scale) if scale != 1.0 else optics
    if isinstance(lens, str):
        if lens != "paper":
            raise InvalidInputError(f"lens must be a LensDistortion, 'paper' or None, got {lens!r}")
        lens = paper_lens(o)
    nx, ny = o.n_markers
    miss = {(int(a), int(b)) for a, b in missing} | {f for f in fid_sites if isinstance(f[0], int)}
    if levels == 2 and any(not float(a).is_integer() and not float(b).is_integer()
                           for a, b in fid_sites):  # fmt: skip
        raise InvalidInputError(
            f"fiducial_site: a site (i + 1/2, j + 1/2) holds a level-2 dot: {fid_sites}"
        )
    ij = np.array(
        [
            (i, j)
            for j in range(-(ny // 2), ny // 2 + 1)
            for i in range(-(nx // 2), nx // 2 + 1)
            if (i, j) not in miss
        ],
        dtype=np.int64,
    )
    tgt = CalibrationTarget(
        image=np.zeros((0, 0), np.uint16),
        markers_px=np.zeros((0, 2)),
        index=ij,
        spurious_px=np.zeros((0, 2)),
        optics=o,
        lens=lens,
        mapping=mapping,
        rotation_deg=float(rotation_deg),
        grid_offset_px=(grid_offset_px[0] * scale, grid_offset_px[1] * scale),
    )
    pts = tgt.true_image_px(ij)
    # The second level: half-pitch staggered sites, scaled about the sensor centre.
    ij2 = np.array(
        [(i + 0.5, j + 0.5) for j in range(-(ny // 2), ny // 2) for i in range(-(nx // 2), nx // 2)]
    ).reshape(-1, 2)
    if levels == 2:
        c0 = np.array([0.5 * (o.width - 1), 0.5 * (o.height - 1)])
        ideal2 = c0 + float(level_scale) * (tgt.ideal_px(ij2) - c0) + np.asarray(level_shift_px)
        if mapping is not None:
            pts2 = np.asarray(mapping.forward(ideal2))
        elif lens is not None:
            pts2 = lens.distort(ideal2)
        else:
            pts2 = ideal2
    else:
        ij2, pts2 = np.zeros((0, 2)), np.zeros((0, 2))
    fid_px = tgt.true_image_px(fid_sites) if fid_sites else np.zeros((0, 2))
    # Spurious blobs keep away from every grid site, missing ones and a ring beyond the edge
    # included (a blob there would be indistinguishable from a marker).
    sites = tgt.true_image_px(
        [
            (i, j)
            for j in range(-(ny // 2) - 1, ny // 2 + 2)
            for i in range(-(nx // 2) - 1, nx // 2 + 2)
        ]
    )
    sites = np.vstack([sites, pts2])
    dot_sigma = o.dot_sigma_mm * o.magnification
    bits = o.bit_depth if bit_depth is None else int(bit_depth)
    if bits not in (8, 12, 16):
        raise InvalidInputError(f"bit_depth must be 8, 12 or 16, got {bit_depth!r}")
    full = float(2**bits - 1)
    counts = full / 4095.0  # levels, noise and gain are given for 12 bit
    if dot == "disc":
        diameter = 4.0 * dot_sigma if dot_diameter_px is None else float(dot_diameter_px)
        if not (np.isfinite(diameter) and diameter > 0):
            raise InvalidInputError(f"dot_diameter_px must be > 0, got {dot_diameter_px!r}")
        radius, size, dot_size = 0.5 * diameter, float(blur_px), 0.5 * diameter
    else:
        radius, size, dot_size = 0.0, dot_sigma, 2.0 * dot_sigma
    rng = np.random.default_rng(seed)
    spur = []
    step = o.magnification * o.pitch_mm
    while len(spur) < spurious:
        m = 2 * dot_size
        p = rng.uniform([m, m], [o.width - m, o.height - m])
        if np.min(np.hypot(*(sites - p).T)) > 0.35 * step and all(
            np.hypot(*(p - q)) > 3 * dot_size for q in spur
        ):
            spur.append(p)
    spur_arr = np.array(spur, dtype=np.float64).reshape(-1, 2)
    # Clutter: off the plate, at least one pitch beyond the outermost markers.
    lo, hi = sites.min(axis=0), sites.max(axis=0)
    clut: list[np.ndarray] = []
    tries = 0
    while len(clut) < clutter:
        tries += 1
        if tries > 200 * (clutter + 1):
            raise InvalidInputError(
                f"clutter: no room for {clutter} blobs off a plate spanning {hi - lo} px"
            )
        m = 3 * dot_size
        p = rng.uniform([m, m], [o.width - m, o.height - m])
        off_plate = bool(np.any(p < lo - 0.2 * step) or np.any(p > hi + 0.2 * step))
        if off_plate and all(np.hypot(*(p - q)) > 6 * dot_size for q in clut):
            clut.append(p)
    clut_arr = np.array(clut, dtype=np.float64).reshape(-1, 2)
    contrast = o.amplitude * counts * (-1.0 if dark else 1.0)
    # Level 2 and the fiducials ride with the markers: (centre, sigma, amplitude, radius,
    # polygon sides, first vertex's angle).
    extra_rows = [(p, size, contrast * level_contrast, radius, 0, 0.0) for p in pts2]
    big = 1.6 * (radius if radius > 0 else size)
    r_dot = radius if radius > 0 else 2.0 * size
    blur = size if radius > 0 else 0.5 * size
    axis = np.radians(rotation_deg)  # the lattice's +i in the image (before the lens)
    for kind, p in zip(fid_kinds, fid_px, strict=True):
        if kind == "large":
            fid_sigma, fid_radius = (size, big) if radius > 0 else (big, 0.0)
            extra_rows.append((p, fid_sigma, contrast, fid_radius, 0, 0.0))
        elif kind == "ring":
            extra_rows += [(p, blur, contrast, 1.6 * r_dot, 0, 0.0)]
            extra_rows += [(p, blur, -contrast, r_dot, 0, 0.0)]
        elif kind == "square":
            extra_rows.append((p, blur, contrast, 1.3 * np.sqrt(2.0) * r_dot, 4, axis + np.pi / 4))
        elif kind == "triangle":
            extra_rows.append((p, blur, contrast, 2.0 * r_dot, 3, axis))
    pts_all = np.vstack([pts, np.array([r[0] for r in extra_rows]).reshape(-1, 2)])
    n_s, n_c = len(spur_arr), len(clut_arr)
    centres = np.vstack([pts_all, spur_arr, clut_arr])
    glare = np.arange(n_c) % 5 == 4
    c_scale = np.where(glare, rng.uniform(6.0, 12.0, n_c), rng.uniform(0.5, 3.0, n_c))
    sig = np.concatenate(
        [
            np.full(len(pts), size),
            [r[1] for r in extra_rows],
            size * rng.uniform(0.6, 1.4, size=n_s),
            np.where(glare | (radius == 0.0), dot_sigma * c_scale, size),
        ]
    )
    amp = np.concatenate(
        [
            np.full(len(pts), contrast),
            [r[2] for r in extra_rows],
            contrast * rng.uniform(0.5, 1.0, n_s),
            np.where(glare, abs(contrast) * 0.8, contrast * rng.uniform(0.5, 1.5, n_c)),
        ]
    )
    rad = np.concatenate(
        [
            np.full(len(pts), radius),
            [r[3] for r in extra_rows],
            radius * rng.uniform(0.6, 1.4, size=n_s),
            np.where(glare | (radius == 0.0), 0.0, radius * c_scale),
        ]
    )
    n_rest = n_s + n_c
    sides = np.concatenate([np.zeros(len(pts)), [r[4] for r in extra_rows], np.zeros(n_rest)])
    angles = np.concatenate([np.zeros(len(pts)), [r[5] for r in extra_rows], np.zeros(n_rest)])
    polygons = bool(np.any(sides > 0))
    background = 200.0 * counts
    plate = 0.7 * full - background if dark else 0.0
    tgt.image = _rspiv.render_target(
        o.height,
        o.width,
        np.ascontiguousarray(centres),
        np.ascontiguousarray(sig),
        np.ascontiguousarray(amp),
        background=background,
        vignetting=float(vignetting),
        gain=gain * counts if noise else 0.0,
        read_noise=read_noise * counts if noise else 0.0,
        full_scale=full,
        seed=int(seed),
        radius_px=np.ascontiguousarray(rad),
        plate=plate,
        sides=sides.astype(np.uint32) if polygons else None,
        orientation_rad=np.ascontiguousarray(angles) if polygons else None,
    )
    if bits == 8:
        tgt.image = tgt.image.astype(np.uint8)
    tgt.markers_px = pts
    tgt.spurious_px = spur_arr
    tgt.extra.update(
        dot_sigma_px=dot_sigma, dot=dot, disc_radius_px=radius, blur_px=float(blur_px),
        dark=bool(dark), bit_depth=bits, clutter_px=clut_arr, level2_px=pts2,
        level2_index=ij2, fiducial=fiducial, fiducial_px=fid_px,
        fiducial_index=np.array(fid_sites[0]) if fid_sites else None,
        fiducial_sites=np.array(fid_sites, dtype=np.float64).reshape(-1, 2),
    )
    return tgt


FIDUCIAL_KINDS = ("large", "ring", "missing", "square", "triangle")


def _fiducials(
    fiducial: str | Sequence[str] | None, site: Any
) -> tuple[list[str], list[tuple[int, int]]]:
    """The renderer's fiducials as (kinds, sites), checked."""
    if fiducial is None:
        return [], []
    kinds = [fiducial] if isinstance(fiducial, str) else list(fiducial)
    for k in kinds:
        if k not in FIDUCIAL_KINDS:
            raise InvalidInputError(
                f"fiducial must be None or one or more of {', '.join(FIDUCIAL_KINDS)}, got {k!r}"
            )
    arr = np.asarray(site, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape != (len(kinds), 2) or not np.all(2 * arr == np.round(2 * arr)):
        raise InvalidInputError(
            f"fiducial_site must give one (i, j) site per fiducial ({len(kinds)}), integers or "
            f"half-integers, got {site!r}"
        )
    sites = [
        (int(a), int(b)) if a == round(a) and b == round(b) else (float(a), float(b))
        for a, b in arr
    ]
    if len(set(sites)) != len(sites):
        raise InvalidInputError(f"fiducial_site: two fiducials on one site: {sites}")
    return kinds, sites
