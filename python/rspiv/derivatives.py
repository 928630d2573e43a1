"""Velocity gradients of a vector field on a regular grid, and what follows from them:
vorticity, divergence and swirling strength.

Frame
    rspiv's fields are in the pixel frame (x right, y *down*; ``v`` positive downward). Every
    quantity here is given in the right-handed frame of the image as it is shown: x right, y
    *up*, z out of the image, so that a counter-clockwise rotation on the screen has positive
    vorticity. With ``y_up = -y`` and ``v_up = -v``:

    - ``du/dy_up = -du/dy``, ``dv_up/dx = -dv/dx``, ``dv_up/dy_up = dv/dy``;
    - vorticity ``omega_z = dv_up/dx - du/dy_up = du/dy - dv/dx`` (pixel-frame derivatives);
    - divergence ``du/dx + dv/dy`` (the same in both frames).

    :func:`gradients` returns the four derivatives in the y-up frame.

Units
    Displacements in px per pair over grid spacings in px give derivatives in 1/pair (per pulse
    separation): divide by ``dt`` (s) for 1/s. A corrected field's object px cancel alike.

Schemes (Raffel et al. 2018, *Particle Image Velocimetry*, 3rd ed., Sect. 10.1), along each
grid axis with spacing ``h``:

    ``"central"``        ``(f[i+1] - f[i-1]) / 2h``, second order; error of uncorrelated noise
                         ``sigma`` on f: ``0.707 sigma / h``
    ``"least_squares"``  ``(2 f[i+2] + f[i+1] - f[i-1] - 2 f[i-2]) / 10h``, second order,
                         smoothing: ``0.316 sigma / h``
    ``"richardson"``     ``(f[i-2] - 8 f[i-1] + 8 f[i+1] - f[i+2]) / 12h``, fourth order:
                         ``0.950 sigma / h``

Where the scheme's five points are not all available (the grid's second rows and columns, next
to a vector not computed) the central difference is used, and where its two points are not
either (the outermost rows and columns, a NaN neighbour) the derivative is NaN. Replaced
vectors enter with their interpolated values, as in any PIV tool. With 50 % overlap the noise
of neighbouring vectors is correlated, so the noise figures above are the uncorrelated case.

Swirling strength (Zhou et al. 1999; Adrian, Christensen & Liu 2000): the imaginary part of the
complex eigenvalues of the 2-D velocity gradient tensor, ``lambda_ci = sqrt(max(0, -((a - d)^2
/ 4 + b c)))`` with ``a = du/dx``, ``b = du/dy``, ``c = dv/dx``, ``d = dv/dy`` (the same in
either frame); signed by the vorticity it marks prograde and retrograde vortices (Wu &
Christensen 2006).
"""

from __future__ import annotations

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "SCHEMES",
    "derivative",
    "divergence",
    "gradients",
    "swirl_from_gradients",
    "swirling_strength",
    "vorticity",
]

#: The difference schemes: offsets and weights (times 1 / h).
SCHEMES: dict[str, tuple[tuple[int, ...], tuple[float, ...]]] = {
    "central": ((-1, 1), (-0.5, 0.5)),
    "least_squares": ((-2, -1, 1, 2), (-0.2, -0.1, 0.1, 0.2)),
    "richardson": ((-2, -1, 1, 2), (1 / 12, -8 / 12, 8 / 12, -1 / 12)),
}


def _stencil(f: np.ndarray, axis: int, scheme: str) -> np.ndarray:
    """The scheme's sum along ``axis`` (times h), NaN where a point is missing or beyond."""
    offsets, weights = SCHEMES[scheme]
    f = np.moveaxis(f, axis, 0)
    n = f.shape[0]
    out = np.zeros_like(f)
    for k, w in zip(offsets, weights, strict=True):
        shifted = np.full_like(f, np.nan)
        if k > 0:
            shifted[: n - k] = f[k:]
        else:
            shifted[-k:] = f[: n + k]
        out += w * shifted
    return np.moveaxis(out, 0, axis)


def derivative(f, h: float, axis: int, scheme: str = "least_squares") -> np.ndarray:
    """``df/dx_axis`` of the 2-D array ``f`` with grid spacing ``h`` along ``axis`` (0: rows,
    1: columns), in the array's own direction (module docstring: schemes, edges, NaN).

    Raises
    ------
    InvalidInputError
        ``f`` not 2-D, ``h`` not positive, or an unknown scheme.
    """
    if scheme not in SCHEMES:
        raise InvalidInputError(f"scheme: expected one of {', '.join(SCHEMES)}, got {scheme!r}")
    f = np.asarray(f, dtype=np.float64)
    if f.ndim != 2:
        raise InvalidInputError(f"derivative: expected a 2-D field, got shape {f.shape}")
    if not (np.isfinite(h) and h > 0):
        raise InvalidInputError(f"derivative: grid spacing must be positive, got {h}")
    with np.errstate(invalid="ignore"):
        d = _stencil(f, axis, scheme)
        if scheme != "central":
            d = np.where(np.isfinite(d), d, _stencil(f, axis, "central"))
    return d / h


def gradients(u, v, dx: float, dy: float, scheme: str = "least_squares") -> dict[str, np.ndarray]:
    """``dudx, dudy, dvdx, dvdy`` in the y-up frame (module docstring) of a field in the pixel
    frame (``u`` right, ``v`` down; rows down) on a grid of spacing ``dx``, ``dy`` px."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    if u.shape != v.shape:
        raise InvalidInputError(f"gradients: u {u.shape} and v {v.shape} differ in shape")
    return {
        "dudx": derivative(u, dx, 1, scheme),
        "dudy": -derivative(u, dy, 0, scheme),
        "dvdx": -derivative(v, dx, 1, scheme),
        "dvdy": derivative(v, dy, 0, scheme),
    }


def vorticity(u, v, dx: float, dy: float, scheme: str = "least_squares") -> np.ndarray:
    """The vorticity ``omega_z`` (positive counter-clockwise on the image), 1/pair."""
    g = gradients(u, v, dx, dy, scheme)
    return g["dvdx"] - g["dudy"]


def divergence(u, v, dx: float, dy: float, scheme: str = "least_squares") -> np.ndarray:
    """The in-plane divergence ``du/dx + dv/dy``, 1/pair (not zero in a plane of a 3-D flow:
    it is ``-dw/dz``)."""
    g = gradients(u, v, dx, dy, scheme)
    return g["dudx"] + g["dvdy"]


def swirling_strength(
    u, v, dx: float, dy: float, scheme: str = "least_squares", signed: bool = False
) -> np.ndarray:
    """The swirling strength ``lambda_ci`` (1/pair, 0 where the local motion does not swirl),
    with ``signed=True`` times the sign of the vorticity (module docstring)."""
    return swirl_from_gradients(gradients(u, v, dx, dy, scheme), signed)


def swirl_from_gradients(g: dict[str, np.ndarray], signed: bool = False) -> np.ndarray:
    """:func:`swirling_strength` from :func:`gradients`' dictionary (NaN where they are)."""
    a, b, c, d = g["dudx"], g["dudy"], g["dvdx"], g["dvdy"]
    disc = 0.25 * (a - d) ** 2 + b * c
    with np.errstate(invalid="ignore"):
        lam = np.sqrt(np.maximum(-disc, 0.0))
    lam = np.where(np.isfinite(disc), lam, np.nan)
    return lam * np.sign(c - b) if signed else lam
