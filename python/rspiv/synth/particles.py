"""Synthetic particle image pairs with a known displacement field.

Particles are drawn with numpy (positions, intensities) and rendered in Rust
(:func:`rspiv._rspiv.render_particles`): Gaussian particles integrated exactly over each pixel's
area (erf), additive Gaussian noise, rounded and clipped to the sensor's bit depth.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rspiv import _rspiv
from rspiv.errors import InvalidInputError

__all__ = ["convected_sequence", "particle_pair", "particle_sequence"]


def _displacement_at(displacement, x: np.ndarray, y: np.ndarray, shape) -> tuple:
    if callable(displacement):
        u, v = displacement(x, y)
        return (
            np.broadcast_to(np.asarray(u, float), x.shape),
            np.broadcast_to(np.asarray(v, float), x.shape),
        )
    if isinstance(displacement, tuple | list) and len(displacement) == 2:
        u, v = (np.asarray(c, dtype=float) for c in displacement)
        if u.ndim == 0 and v.ndim == 0:
            return np.full(x.shape, float(u)), np.full(x.shape, float(v))
        if u.shape == tuple(shape) and v.shape == tuple(shape):
            from scipy.ndimage import map_coordinates

            coords = np.vstack([y, x])
            return (
                map_coordinates(u, coords, order=1, mode="nearest"),
                map_coordinates(v, coords, order=1, mode="nearest"),
            )
    raise InvalidInputError(
        "displacement must be a callable (x, y) -> (u, v), a pair of floats, or a pair of "
        f"arrays of the image shape {tuple(shape)}"
    )


def particle_pair(
    shape: tuple[int, int],
    displacement: Callable | tuple,
    density: float = 0.03,
    diameter: float = 2.5,
    noise: float = 0.05,
    seed: int = 0,
    *,
    bits: int = 12,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a PIV image pair whose particles move by a known displacement field.

    Parameters
    ----------
    shape : (height, width)
        Image shape in px.
    displacement : callable, (u, v) floats or (u, v) arrays
        Displacement in px along x (right) and y (down). A callable receives particle positions
        ``(x, y)`` (arrays, pixel frame) and returns ``(u, v)``; arrays have the image shape and
        are interpolated bilinearly. The displacement is evaluated at each particle's midpoint
        ``p``; the particle sits at ``p - d/2`` in frame A and ``p + d/2`` in frame B, so the
        field is exact at the centre of the exposure pair (as symmetric PIV measures it).
    density : float
        Particles per pixel (e.g. 0.03).
    diameter : float
        Particle image diameter in px (e^-2 intensity, i.e. 4 standard deviations).
    noise : float
        Standard deviation of additive Gaussian noise as a fraction of the mean particle peak
        intensity (the peak intensities are uniform in [0.6, 1.0] x 80 % of full scale).
    seed : int
        Seed of the particle positions, intensities and noise.
    bits : int
        Sensor bit depth; counts are clipped to ``[0, 2**bits - 1]``.

    Returns
    -------
    frame_a, frame_b : ndarray of uint16, shape ``shape``
    """
    frame_a, frame_b = _render(
        shape, displacement, (-0.5, 0.5), density, diameter, noise, seed, bits
    )
    return frame_a, frame_b


def particle_sequence(
    shape: tuple[int, int],
    displacement: Callable | tuple,
    frames: int,
    density: float = 0.03,
    diameter: float = 2.5,
    noise: float = 0.05,
    seed: int = 0,
    *,
    bits: int = 12,
) -> list[np.ndarray]:
    """Render a time-resolved recording: ``frames`` frames whose particles move by a known
    displacement per frame interval.

    Each particle moves on a straight line at its own constant displacement per frame,
    ``displacement`` evaluated at its position ``p`` at the middle of the recording: in frame k
    it sits at ``p + (k - (frames - 1) / 2) d(p)``. Frames k and k + g are then a pair whose
    displacement is ``g d``, exactly where ``d`` is uniform or points along x and varies with
    y only (a parallel shear flow, a boundary layer's mean profile); elsewhere ``d`` is taken
    at the particle's mid-recording position.

    Parameters
    ----------
    shape, density, diameter, noise, seed, bits
        As :func:`particle_pair`.
    displacement : callable, (u, v) floats or (u, v) arrays
        Displacement per frame interval in px, as :func:`particle_pair` takes it.
    frames : int
        Number of frames, >= 2.

    Returns
    -------
    list of ndarray of uint16, shape ``shape``
        The frames in time order.
    """
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise InvalidInputError(f"frames must be an integer >= 2, got {frames!r}")
    c = (int(frames) - 1) / 2.0
    offsets = tuple(k - c for k in range(int(frames)))
    return _render(shape, displacement, offsets, density, diameter, noise, seed, bits)


def _checked(shape, density, diameter, noise, bits) -> tuple[int, int]:
    """``(h, w)`` of a scene whose particles' parameters are checked (one line each)."""
    h, w = (int(s) for s in shape)
    if h < 1 or w < 1:
        raise InvalidInputError(f"shape {shape} must be positive")
    if not (density > 0 and diameter > 0 and noise >= 0 and 1 <= bits <= 16):
        raise InvalidInputError("density and diameter must be > 0, noise >= 0, 1 <= bits <= 16")
    return h, w


def _brightness(rng, n: int, diameter: float, noise: float, bits: int) -> tuple:
    """Each particle's peak (uniform in [0.6, 1.0] x 80 % of full scale), the noise's standard
    deviation, the diameter as the renderer takes it and the full scale."""
    full = float(2**bits - 1)
    peak = 0.8 * full * rng.uniform(0.6, 1.0, n)
    return peak, noise * 0.8 * full * 0.8, np.array([float(diameter)]), int(full)


def _render(shape, displacement, offsets, density, diameter, noise, seed, bits) -> list:
    """Frames of particles drawn around midpoints ``p`` and placed at ``p + o d(p)`` for each
    offset ``o`` of ``offsets`` (:func:`particle_pair`: -1/2 and 1/2)."""
    h, w = _checked(shape, density, diameter, noise, bits)
    rng = np.random.default_rng(seed)
    margin = 2.0 * diameter + 4.0
    while True:
        area = (w + 2 * margin) * (h + 2 * margin)
        n = rng.poisson(density * area)
        xm = rng.uniform(-margin, w - 1 + margin, n)
        ym = rng.uniform(-margin, h - 1 + margin, n)
        u, v = _displacement_at(displacement, xm, ym, (h, w))
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v))):
            raise InvalidInputError("displacement contains NaN or inf")
        reach = max(abs(o) for o in offsets) * float(
            max(np.max(np.abs(u), initial=0), np.max(np.abs(v), initial=0))
        )
        if reach + 2.0 * diameter + 2.0 <= margin:
            break
        margin = reach + 2.0 * diameter + 4.0
    peak, sigma, diam, full = _brightness(rng, n, diameter, noise, bits)
    seeds = rng.integers(0, 2**63 - 1, len(offsets))
    frames = []
    for sign, s in zip(offsets, seeds, strict=True):
        frames.append(
            _rspiv.render_particles(
                h, w, xm + sign * u, ym + sign * v, peak, diam, sigma, full, int(s)
            )
        )
    return frames


def convected_sequence(
    shape: tuple[int, int],
    speed: float,
    amplitude: float,
    frames: int,
    *,
    wavelengths: tuple[float, ...] = (64.0, 96.0, 160.0),
    density: float = 0.03,
    diameter: float = 2.5,
    noise: float = 0.05,
    seed: int = 0,
    bits: int = 12,
    substeps: int = 2,
) -> list[np.ndarray]:
    """Render a time-resolved recording of a frozen pattern convected along x at ``speed`` px
    per frame interval: the exact answer for a convection velocity and, through Taylor's
    hypothesis, a frequency spectrum.

    The particles move with the velocity ``(speed + u'(x - speed t, y), v'(x - speed t, y))``
    (px per frame interval, t in frames), where ``(u', v')`` derive from the stream function
    ``psi = sum_j amplitude / k_j sin(k_j xi + a_j) sin(m_j y + b_j)`` (``k_j = 2 pi /
    wavelengths[j]``, ``m_j = 2 pi / (1.5 wavelengths[j])``, phases drawn from ``seed``):
    divergence-free, ``|v'| <= amplitude`` per mode. Positions are integrated by the midpoint
    rule in ``substeps`` steps per frame; the particles fill the region the pattern sweeps into
    the frame.

    Parameters
    ----------
    shape, density, diameter, noise, seed, bits
        As :func:`particle_pair`.
    speed, amplitude : float
        The pattern's speed and the modes' amplitude, px per frame interval.
    frames : int
        Number of frames, >= 2.

    Returns
    -------
    list of ndarray of uint16, shape ``shape``
        The frames in time order.
    """
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise InvalidInputError(f"frames must be an integer >= 2, got {frames!r}")
    if not (np.isfinite(speed) and np.isfinite(amplitude) and len(wavelengths) > 0):
        raise InvalidInputError("speed and amplitude must be finite, with one wavelength or more")
    h, w = _checked(shape, density, diameter, noise, bits)
    rng = np.random.default_rng(seed)
    k = 2 * np.pi / np.asarray(wavelengths, np.float64)
    mw = k / 1.5
    a, b = rng.uniform(0, 2 * np.pi, (2, k.size))

    def velocity(x, y, t):
        xi = x[:, None] - speed * t
        sx, cx = np.sin(k * xi + a), np.cos(k * xi + a)
        sy, cy = np.sin(mw * y[:, None] + b), np.cos(mw * y[:, None] + b)
        return (speed + amplitude * (mw / k * sx * cy).sum(1),
                -amplitude * (cx * sy).sum(1))  # fmt: skip

    # in the pattern's frame the particles circle in its cells (a closed stream function): an
    # incompressible flow keeps them uniform, except within a cell of the seeded region's edge
    margin = 2.0 * diameter + 4.0 + 0.75 * float(np.max(wavelengths))
    travel = abs(speed) * (frames - 1)
    x0 = -margin - (travel if speed > 0 else 0.0)
    x1 = w - 1 + margin + (travel if speed < 0 else 0.0)
    n = rng.poisson(density * (x1 - x0) * (h + 2 * margin))
    x = rng.uniform(x0, x1, n)
    y = rng.uniform(-margin, h - 1 + margin, n)
    peak, sigma, diam, full = _brightness(rng, n, diameter, noise, bits)
    seeds = rng.integers(0, 2**63 - 1, int(frames))
    out = []
    dt = 1.0 / int(substeps)
    edge = 2.0 * diameter + 4.0  # the particles that reach the frame's pixels
    for f in range(int(frames)):
        inside = (x > -edge) & (x < w - 1 + edge) & (y > -edge) & (y < h - 1 + edge)
        out.append(_rspiv.render_particles(h, w, x[inside], y[inside], peak[inside], diam,
                                           sigma, full, int(seeds[f])))  # fmt: skip
        for s in range(int(substeps)):
            t = f + s * dt
            u1, v1 = velocity(x, y, t)
            u2, v2 = velocity(x + 0.5 * dt * u1, y + 0.5 * dt * v1, t + 0.5 * dt)
            x, y = x + dt * u2, y + dt * v2
    return out
