"""Synthetic turbulent-boundary-layer image pairs with the wall reflection (paper sections 2, 3.2).

The ground truth of the wall alignment, Method I/II and the campaign statistics. Python describes
the scene (numpy); Rust renders the particles (:func:`rspiv._rspiv.render_particles`).

Flow (:class:`TBLFlow`)
-----------------------
The paper's flow: Re_tau = 2386, U_inf = 9.64 m/s, delta99 = 103 mm, imaged at
M = 34.538 px/mm, so the viscous length is ``delta99 / Re_tau = 43.2 um = 1.49 px``. No DNS exists
at that Re_tau in ``ref/``; the mean profile and the Reynolds stresses are an inner/outer
composite of the Re_theta = 4060 station (Schlatter & Örlü 2010, Re_tau = 1271.5):

- below ``y = 0.07 delta99`` the inner scaling holds: U+, uu+, vv+, uv+ are the DNS values at the
  same y+ (U+ continued by the log law ``U+ = ln(y+) / 0.41 + B``, B matched to the DNS at
  y+ = 0.15 Re_tau_DNS, where y+ exceeds it);
- above ``y = 0.2 delta99`` the outer scaling holds: the velocity defect ``U_inf+ - U+`` and the
  stresses are the DNS values at the same ``y / delta99``;
- in between the two are blended with a smooth step in ``y / delta99``. ``U_inf+`` is fixed by
  matching inner and outer U+ at ``y = 0.1 delta99`` (Re_tau = 2386 gives U_inf+ = 27.5 against
  the paper's 9.64 / 0.348 = 27.7).

Displacements are in object px: ``d = vel+ * (u_inf_px / U_inf+)`` with ``u_inf_px`` the
free-stream displacement (default 25 px); ``dt = u_inf_px / (U_inf * M)``.

Fluctuations: two independent Gaussian random fields ``g1, g2`` (white noise on a grid, Gaussian
filtered to a correlation length ``correlation_px``, normalised to unit variance, interpolated by
cubic splines) combined by the Cholesky factor of the local Reynolds-stress tensor::

    u' = sqrt(uu) g1,   v' = uv / sqrt(uu) g1 + sqrt(vv - uv^2 / uu) g2

so ``<u'u'> = uu``, ``<v'v'> = vv``, ``<u'v'> = uv`` at every distance from the wall (in the
ensemble over seeds). The field is frozen over the pair.

Geometry
--------
Object px (the dewarped frame): the wall is the line ``y_wall(x) = wall_y0 + x tan(wall_angle)``;
the flow lies on the side ``flow_side`` ("above": y < y_wall, the wall near the bottom of the
image). ``u`` runs along the wall, ``v`` is normal to it, positive into the flow. Each particle's
displacement is evaluated at its midpoint ``p`` and it sits at ``p - d/2`` (frame A) and
``p + d/2`` (frame B). Particles on the far side of the wall are removed; every particle's mirror
image about the wall line is added with intensity ``reflection`` times its own. Object px then
go to image px through the camera: ``lens.distort`` (object px = ideal image px, the convention
of :func:`rspiv.synth.calibration_target` with ``rotation_deg = 0``) or ``mapping.forward``.
The default wall angle, 0.04 degree, is the paper's misalignment of the target with the wall.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv.errors import InvalidInputError
from rspiv.reference import load_dns
from rspiv.synth.target import PAPER_OPTICS, LensDistortion, paper_lens
from rspiv.vortices import oseen_velocity

__all__ = ["TBLFlow", "TBLTruth", "tbl_pair", "tbl_scene", "load_profile"]

KAPPA = 0.41
_BLEND = (0.07, 0.2)  # y / delta99 range of the inner -> outer blend
_MATCH = 0.1  # y / delta99 where U_inf+ is matched


def load_profile(re_theta: float = 4060) -> Any:
    """The DNS station used for the composite (``rspiv.reference.load_dns``)."""

    return load_dns(re_theta)


def _smoothstep(eta: np.ndarray) -> np.ndarray:
    t = np.clip((eta - _BLEND[0]) / (_BLEND[1] - _BLEND[0]), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclasses.dataclass(frozen=True)
class TBLFlow:
    """Mean profile and Reynolds stresses of a zero-pressure-gradient TBL at ``re_tau``.

    Attributes
    ----------
    re_tau : float
        Friction Reynolds number ``delta99 / l_v`` (paper: 2386).
    u_inf : float
        Free-stream velocity (m/s).
    delta99_mm : float
        Boundary-layer thickness (mm).
    profile : DNSProfile
        The DNS station of the composite (default Re_theta = 4060).
    """

    re_tau: float = 2386.0
    u_inf: float = 9.64
    delta99_mm: float = 103.0
    profile: Any = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.re_tau) and self.re_tau > 100):
            raise InvalidInputError(f"re_tau must be > 100, got {self.re_tau!r}")
        if not (self.u_inf > 0 and self.delta99_mm > 0):
            raise InvalidInputError("u_inf and delta99_mm must be positive")
        if self.profile is None:
            object.__setattr__(self, "profile", load_profile(4060))

    # -- the composite ---------------------------------------------------------------------
    def _inner_u(self, yp: np.ndarray) -> np.ndarray:
        p = self.profile
        y_fit = 0.15 * p.re_tau
        u_fit = np.interp(y_fit, p.y_plus, p.u_plus)
        b = u_fit - np.log(y_fit) / KAPPA
        with np.errstate(divide="ignore"):
            log_law = np.log(np.maximum(yp, 1e-300)) / KAPPA + b
        return np.where(yp <= y_fit, np.interp(yp, p.y_plus, p.u_plus), log_law)

    def _defect(self, eta: np.ndarray) -> np.ndarray:
        p = self.profile
        return p.u_inf_plus - np.interp(eta, p.y_delta99, p.u_plus, right=p.u_inf_plus)

    @property
    def u_inf_plus(self) -> float:
        """Free-stream velocity in wall units, from matching at ``y = 0.1 delta99``."""
        return float(self._inner_u(np.array(_MATCH * self.re_tau)) + self._defect(np.array(_MATCH)))

    @property
    def u_tau(self) -> float:
        """Friction velocity (m/s)."""
        return self.u_inf / self.u_inf_plus

    @property
    def viscous_length_mm(self) -> float:
        """``l_v = nu / u_tau = delta99 / Re_tau`` (mm)."""
        return self.delta99_mm / self.re_tau

    @property
    def nu(self) -> float:
        """Kinematic viscosity (m^2/s) implied by ``u_tau`` and ``l_v``."""
        return self.u_tau * self.viscous_length_mm * 1e-3

    def u_plus(self, y_plus: npt.ArrayLike) -> np.ndarray:
        """Mean streamwise velocity U+ at wall distance(s) ``y_plus`` (0 at and below the wall)."""
        yp = np.maximum(np.asarray(y_plus, dtype=np.float64), 0.0)
        eta = yp / self.re_tau
        w = _smoothstep(eta)
        outer = self.u_inf_plus - self._defect(eta)
        return (1.0 - w) * self._inner_u(yp) + w * outer

    def stresses_plus(self, y_plus: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reynolds stresses ``(uu+, vv+, uv+)`` at ``y_plus`` (uv+ < 0)."""
        p = self.profile
        yp = np.maximum(np.asarray(y_plus, dtype=np.float64), 0.0)
        eta = yp / self.re_tau
        w = _smoothstep(eta)
        out = []
        for col, right in ((p.uu_plus, p.uu_plus[-1]), (p.vv_plus, p.vv_plus[-1]),
                           (p.uv_plus, p.uv_plus[-1])):  # fmt: skip
            inner = np.interp(yp, p.y_plus, col, right=right)
            outer = np.interp(eta, p.y_delta99, col, right=right)
            out.append((1.0 - w) * inner + w * outer)
        uu, vv, uv = out
        # Keep the tensor positive semi-definite under interpolation.
        uv = np.clip(uv, -0.999 * np.sqrt(uu * vv), 0.999 * np.sqrt(uu * vv))
        return uu, vv, uv


@dataclasses.dataclass
class TBLTruth:
    """The exact scene of a :func:`tbl_pair`: everything a test compares against.

    Attributes
    ----------
    flow : TBLFlow
    shape : (int, int)
        Sensor (height, width) in px.
    magnification : float
        M of this (possibly scaled) sensor, px/mm.
    viscous_length_px : float
        ``l_v * M`` (object px per wall unit).
    u_inf_px : float
        Free-stream displacement (object px).
    dt : float
        Time between the exposures (s).
    wall_y0_px, wall_angle_deg : float
        Wall line ``y = wall_y0_px + x tan(wall_angle)`` in object px.
    flow_side : str
        "above" (flow at y < y_wall) or "below".
    to_image : callable
        Object px (N, 2) -> image px (N, 2): the camera used for rendering.
    reflection : float
        Intensity ratio of the mirror images.
    n_particles, n_mirrors : int
        Flow particles (midpoints) and mirror images rendered (frame A).
    extent : (x0, x1, y0, y1)
        Object region (px) holding particles and the fluctuation field.
    vortices : ndarray, (n, 4)
        Lamb-Oseen vortices planted on the fluctuations (``x``, ``y`` object px, circulation
        px^2 per pair in the image's y-up frame, core radius px; :func:`rspiv.vortices.
        oseen_velocity`), prograde (turning with the mean shear); none by default.
    """

    flow: TBLFlow
    shape: tuple[int, int]
    magnification: float
    viscous_length_px: float
    u_inf_px: float
    dt: float
    wall_y0_px: float
    wall_angle_deg: float
    flow_side: str
    to_image: Callable[[np.ndarray], np.ndarray]
    reflection: float
    n_particles: int = 0
    n_mirrors: int = 0
    extent: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    vortices: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    _g: np.ndarray | None = dataclasses.field(default=None, repr=False)
    _grid: tuple[float, float, float] = (0.0, 0.0, 1.0)  # x0, y0, spacing of the noise grid

    # -- geometry ---------------------------------------------------------------------------
    @property
    def u_tau(self) -> float:
        return self.flow.u_tau

    @property
    def nu(self) -> float:
        return self.flow.nu

    @property
    def _sign(self) -> float:
        return 1.0 if self.flow_side == "above" else -1.0

    def _frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors along the wall (+x) and normal to it into the flow."""
        a = np.deg2rad(self.wall_angle_deg)
        t = np.array([np.cos(a), np.sin(a)])
        n = self._sign * np.array([np.sin(a), -np.cos(a)])
        return t, n

    def wall_y(self, x: npt.ArrayLike) -> np.ndarray:
        """Wall line in object px."""
        return self.wall_y0_px + np.asarray(x, np.float64) * np.tan(np.deg2rad(self.wall_angle_deg))

    def wall_distance(self, x: npt.ArrayLike, y: npt.ArrayLike) -> np.ndarray:
        """Signed distance (object px) from the wall, positive in the flow."""
        _, n = self._frame()
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        return (x - 0.0) * n[0] + (y - self.wall_y0_px) * n[1]

    def mirror(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Mirror images of object points about the wall line."""
        _, n = self._frame()
        d = self.wall_distance(x, y)
        return np.asarray(x) - 2.0 * d * n[0], np.asarray(y) - 2.0 * d * n[1]

    # -- velocity ---------------------------------------------------------------------------
    def _noise(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._g is None:
            z = np.zeros_like(np.asarray(x, np.float64))
            return z, z
        from scipy.ndimage import map_coordinates

        x0, y0, h = self._grid
        c = np.vstack([(np.ravel(y) - y0) / h, (np.ravel(x) - x0) / h])
        g1 = map_coordinates(self._g[0], c, order=3, mode="nearest").reshape(np.shape(x))
        g2 = map_coordinates(self._g[1], c, order=3, mode="nearest").reshape(np.shape(x))
        return g1, g2

    def mean_displacement_px(self, y_wall_px: npt.ArrayLike) -> np.ndarray:
        """Mean displacement along the wall (object px) at wall distance(s) ``y_wall_px``."""
        yp = np.asarray(y_wall_px, np.float64) / self.viscous_length_px
        return self.flow.u_plus(yp) * (self.u_inf_px / self.flow.u_inf_plus)

    def displacement(
        self, x: npt.ArrayLike, y: npt.ArrayLike, *, fluctuations: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact displacement (object px, pixel axes) at object points ``(x, y)`` (the pair's
        mid time); zero on the far side of the wall."""
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        d = self.wall_distance(x, y)
        inside = d > 0
        yp = np.maximum(d, 0.0) / self.viscous_length_px
        k = self.u_inf_px / self.flow.u_inf_plus
        us = self.flow.u_plus(yp)
        vs = np.zeros_like(us)
        if fluctuations and self._g is not None:
            uu, vv, uv = self.flow.stresses_plus(yp)
            g1, g2 = self._noise(x, y)
            l11 = np.sqrt(uu)
            with np.errstate(divide="ignore", invalid="ignore"):
                l21 = np.where(l11 > 0, uv / l11, 0.0)
            l22 = np.sqrt(np.maximum(vv - l21 * l21, 0.0))
            us = us + l11 * g1
            vs = l21 * g1 + l22 * g2
        t, n = self._frame()
        u = k * (us * t[0] + vs * n[0])
        v = k * (us * t[1] + vs * n[1])
        if fluctuations:
            for xc, yc, gamma, rc in self.vortices:  # pixel frame: y and v down
                du, dv = oseen_velocity(x, -y, xc, -yc, gamma, rc)
                u, v = u + du, v - dv
        return np.where(inside, u, 0.0), np.where(inside, v, 0.0)


def _noise_fields(
    rng: np.random.Generator, extent: tuple[float, float, float, float], corr: float
) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Two unit-variance Gaussian random fields with correlation length ``corr`` px."""
    from scipy.ndimage import gaussian_filter

    x0, x1, y0, y1 = extent
    h = corr / 4.0
    nx = int(np.ceil((x1 - x0) / h)) + 4
    ny = int(np.ceil((y1 - y0) / h)) + 4
    g = rng.standard_normal((2, ny, nx))
    # Gaussian kernel of standard deviation corr / 2 (in nodes: 2), 'wrap' keeps the variance
    # uniform up to the edges.
    g = gaussian_filter(g, sigma=(0, 2.0, 2.0), mode="wrap")
    g /= g.std(axis=(1, 2), keepdims=True)
    return g, (x0 - 2 * h, y0 - 2 * h, h)


def tbl_scene(
    scale: float = 1.0,
    seed: int = 0,
    *,
    flow: TBLFlow | None = None,
    u_inf_px: float = 25.0,
    wall_angle_deg: float = 0.04,
    wall_y0_px: float | None = None,
    flow_side: str = "above",
    lens: LensDistortion | str | None = "paper",
    mapping: Any = None,
    turbulence: bool = True,
    correlation_px: float | None = None,
    magnification: float = PAPER_OPTICS.magnification,
    reflection: float = 0.5,
    vortices: int = 0,
    vortex_radius_px: float = 12.0,
    vortex_swirl_px: float = 1.5,
) -> TBLTruth:
    """The scene of :func:`tbl_pair` without particles: flow, wall, fluctuation field, camera.

    Parameters are those of :func:`tbl_pair`. The fluctuation field (and the planted vortices)
    are the first draws of ``np.random.default_rng(seed)``, so :func:`tbl_pair` with the same
    seed renders this very scene.
    """
    rng = np.random.default_rng(seed)
    return _scene(rng, scale, flow, u_inf_px, wall_angle_deg, wall_y0_px, flow_side, lens,
                  mapping, turbulence, correlation_px, magnification, reflection,
                  (vortices, vortex_radius_px, vortex_swirl_px))  # fmt: skip


def _scene(
    rng: np.random.Generator,
    scale: float,
    flow: TBLFlow | None,
    u_inf_px: float,
    wall_angle_deg: float,
    wall_y0_px: float | None,
    flow_side: str,
    lens: LensDistortion | str | None,
    mapping: Any,
    turbulence: bool,
    correlation_px: float | None,
    magnification: float,
    reflection: float,
    planted: tuple[int, float, float] = (0, 12.0, 1.5),
) -> TBLTruth:
    if not (np.isfinite(scale) and 0.02 <= scale <= 1.0):
        raise InvalidInputError(f"scale must lie in [0.02, 1], got {scale!r}")
    if flow_side not in ("above", "below"):
        raise InvalidInputError(f"flow_side must be 'above' or 'below', got {flow_side!r}")
    if not (np.isfinite(u_inf_px) and u_inf_px > 0 and np.isfinite(wall_angle_deg)):
        raise InvalidInputError("u_inf_px must be > 0 and wall_angle_deg finite")
    flow = flow if flow is not None else TBLFlow()
    optics = PAPER_OPTICS.scaled(scale) if scale != 1.0 else PAPER_OPTICS
    h, w = optics.height, optics.width
    m = magnification * scale
    if wall_y0_px is None:
        wall_y0_px = 0.94 * (h - 1) if flow_side == "above" else 0.06 * (h - 1)

    if mapping is not None:
        fwd = mapping.forward if hasattr(mapping, "forward") else mapping
        to_image: Callable[[np.ndarray], np.ndarray] = lambda p: np.asarray(fwd(p), np.float64)  # noqa: E731
    elif lens is None:
        to_image = lambda p: np.asarray(p, np.float64)  # noqa: E731
    else:
        if isinstance(lens, str):
            if lens != "paper":
                raise InvalidInputError(f"lens must be a LensDistortion, 'paper' or None: {lens!r}")
            lens = paper_lens(optics)
        to_image = lens.distort

    corr = float(correlation_px) if correlation_px is not None else max(96.0 * scale, 32.0)
    # Object region holding particles: the sensor plus the distortion (~10 px at full scale),
    # half the displacement and the particle size.
    margin = 0.5 * u_inf_px + 32.0 * scale + 16.0
    extent = (-margin, w - 1 + margin, -margin, h - 1 + margin)
    truth = TBLTruth(
        flow=flow,
        shape=(h, w),
        magnification=m,
        viscous_length_px=flow.viscous_length_mm * m,
        u_inf_px=float(u_inf_px),
        dt=float(u_inf_px) / (flow.u_inf * 1e3 * m),
        wall_y0_px=float(wall_y0_px),
        wall_angle_deg=float(wall_angle_deg),
        flow_side=flow_side,
        to_image=to_image,
        reflection=float(reflection),
        extent=extent,
    )
    if turbulence:
        truth._g, truth._grid = _noise_fields(rng, extent, corr)
    truth.vortices = _planted_vortices(rng, truth, *planted)
    return truth


def _planted_vortices(rng: np.random.Generator, truth: TBLTruth, n: int, radius: float,
                      swirl: float) -> np.ndarray:  # fmt: skip
    """``n`` prograde Lamb-Oseen vortices of core radius ``radius`` px and peak azimuthal
    displacement ``swirl`` px, centred at random between 0.15 and 0.6 delta_99 from the wall
    and 10-90 % along it (rows of ``TBLTruth.vortices``)."""
    if n == 0:
        return np.zeros((0, 4))
    if not (n > 0 and radius > 0 and swirl > 0):
        raise InvalidInputError(
            f"vortices: a count >= 0, a radius and a swirl > 0, got {n}, {radius}, {swirl}"
        )
    w = truth.shape[1]
    delta = truth.flow.delta99_mm * truth.magnification
    x = rng.uniform(0.1 * w, 0.9 * w, n)
    d = rng.uniform(0.15 * delta, 0.6 * delta, n)
    _, normal = truth._frame()
    y = truth.wall_y(x) + d * normal[1]
    x = x + d * normal[0]
    # u_theta peaks at 1.12091 r_c with 0.71533 Gamma / (2 pi 1.12091 r_c); prograde turns
    # with the mean shear: clockwise on the screen for a flow above the wall
    gamma = -truth._sign * swirl * 2.0 * np.pi * 1.12091 * radius / 0.71533
    return np.column_stack([x, y, np.full(n, gamma), np.full(n, float(radius))])


def tbl_pair(
    scale: float = 1.0,
    seed: int = 0,
    *,
    flow: TBLFlow | None = None,
    u_inf_px: float = 25.0,
    wall_angle_deg: float = 0.04,
    wall_y0_px: float | None = None,
    flow_side: str = "above",
    lens: LensDistortion | str | None = "paper",
    mapping: Any = None,
    density: float = 0.03,
    diameter: float = 2.5,
    noise: float = 0.05,
    reflection: float = 0.5,
    turbulence: bool = True,
    correlation_px: float | None = None,
    bits: int = 12,
    magnification: float = PAPER_OPTICS.magnification,
    vortices: int = 0,
    vortex_radius_px: float = 12.0,
    vortex_swirl_px: float = 1.5,
) -> tuple[np.ndarray, np.ndarray, TBLTruth]:
    """Render a boundary-layer image pair with the wall reflection through a known camera.

    Parameters
    ----------
    scale : float
        Sensor scale in (0, 1]: the paper's 8864 x 5288 px times ``scale`` (M scales too, so
        ``scale = 0.1`` is the same flow on a 886 x 529 px sensor).
    seed : int
        Seed of particles, fluctuations and noise.
    flow : TBLFlow, optional
        The flow (default: the paper's, Re_tau = 2386).
    u_inf_px : float
        Free-stream displacement in object px (sets ``dt``).
    wall_angle_deg : float
        Angle of the wall in the object frame (degrees, pixel frame: positive means y grows
        with x); the paper's target misalignment is 0.04 degree.
    wall_y0_px : float, optional
        Wall ``y`` at ``x = 0`` (object px); default 94 % of the sensor height.
    flow_side : {"above", "below"}
        Side of the wall holding the flow (in the pixel frame, "above" is y < y_wall).
    lens : LensDistortion, "paper" or None
        Camera distortion (object px = ideal image px -> image px); "paper" is
        :func:`rspiv.synth.paper_lens` on the scaled sensor, None an ideal camera.
    mapping : Mapping or callable, optional
        Object px -> image px instead of ``lens``: an object with ``forward((N, 2))`` or a
        callable on ``(N, 2)`` arrays.
    density : float
        Particles per object px^2 in the flow (0.03).
    diameter : float
        Particle image diameter (px, e^-2).
    noise : float
        Additive Gaussian noise, fraction of the mean peak intensity.
    reflection : float
        Intensity of the mirror images relative to their particles (0 disables them).
    turbulence : bool
        Add the fluctuations (else the mean flow only).
    correlation_px : float, optional
        Correlation length of the fluctuations (px); default ``max(96 * scale, 32)``, a few
        interrogation windows.
    bits : int
        Sensor bit depth.
    magnification : float
        M of the full-size sensor (px/mm).
    vortices, vortex_radius_px, vortex_swirl_px
        Lamb-Oseen vortices planted on the fluctuations (0 by default): their number, core
        radius (px) and peak azimuthal displacement (px), prograde, 0.15-0.6 delta_99 from the
        wall (``TBLTruth.vortices``): the exact answer for :func:`rspiv.vortices.fit_oseen`.

    Returns
    -------
    frame_a, frame_b : ndarray of uint16
    truth : TBLTruth
    """
    if not (density > 0 and diameter > 0 and noise >= 0 and 0 <= reflection <= 1):
        raise InvalidInputError("density, diameter must be > 0; noise >= 0; reflection in [0, 1]")
    if diameter > 12.0:
        raise InvalidInputError(f"diameter must be <= 12 px, got {diameter!r}")
    rng = np.random.default_rng(seed)
    truth = _scene(rng, scale, flow, u_inf_px, wall_angle_deg, wall_y0_px, flow_side, lens,
                   mapping, turbulence, correlation_px, magnification, reflection,
                   (vortices, vortex_radius_px, vortex_swirl_px))  # fmt: skip
    h, w = truth.shape
    to_image = truth.to_image
    extent = truth.extent
    # Midpoints in the flow region of the object domain.
    area = (extent[1] - extent[0]) * (extent[3] - extent[2])
    n = rng.poisson(density * area)
    xm = rng.uniform(extent[0], extent[1], n)
    ym = rng.uniform(extent[2], extent[3], n)
    keep = truth.wall_distance(xm, ym) > 0
    xm, ym = xm[keep], ym[keep]
    u, v = truth.displacement(xm, ym, fluctuations=turbulence)
    xa, ya = xm - 0.5 * u, ym - 0.5 * v
    xb, yb = xm + 0.5 * u, ym + 0.5 * v
    # A particle crossing the wall (possible only through the tiny near-wall v') is dropped.
    ok = (truth.wall_distance(xa, ya) > 0) & (truth.wall_distance(xb, yb) > 0)
    xa, ya, xb, yb = xa[ok], ya[ok], xb[ok], yb[ok]
    full = float(2**bits - 1)
    peak = 0.8 * full * rng.uniform(0.6, 1.0, xa.size)
    sigma = noise * 0.8 * full * 0.8
    truth.n_particles = int(xa.size)

    frames = []
    seeds = rng.integers(0, 2**63 - 1, 2)
    # Mirror images: keep those that can reach the sensor (within the object extent).
    mxa, mya = truth.mirror(xa, ya)
    mxb, myb = truth.mirror(xb, yb)
    vis = ((mya >= extent[2]) & (mya <= extent[3])) | ((myb >= extent[2]) & (myb <= extent[3]))
    vis &= reflection > 0
    truth.n_mirrors = int(vis.sum())
    for (px, py, qx, qy), s in (((xa, ya, mxa, mya), seeds[0]), ((xb, yb, mxb, myb), seeds[1])):
        obj = np.column_stack([np.concatenate([px, qx[vis]]), np.concatenate([py, qy[vis]])])
        img = to_image(obj)
        inten = np.concatenate([peak, reflection * peak[vis]])
        frames.append(
            _rspiv.render_particles(
                h,
                w,
                np.ascontiguousarray(img[:, 0]),
                np.ascontiguousarray(img[:, 1]),
                inten,
                np.array([float(diameter)]),
                sigma,
                int(full),
                int(s),
            )
        )
    return frames[0], frames[1], truth
