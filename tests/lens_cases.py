"""Particle pairs imaged through a known, strong lens (shared by the Method II and engine tests),
and an oblique view of a target (the calibration tests)."""

from __future__ import annotations

import dataclasses

import numpy as np
import rspiv
from rspiv import _rspiv
from rspiv.synth import PAPER_OPTICS, paper_lens


def strong_lens(shape: tuple[int, int]):
    """The paper's lens on a ``shape = (h, w)`` sensor with 20x its radial and 5x its decentring
    distortion (so that the position-only bias is clearly measurable)."""
    o = dataclasses.replace(PAPER_OPTICS, width=shape[1], height=shape[0])
    base = paper_lens(o)
    return dataclasses.replace(base, k1=20 * base.k1, p1=5 * base.p1)


def p3_mapping(lens, shape: tuple[int, int]):
    """The P3 mapping fitted to the lens on a 13 x 9 lattice over the sensor."""
    h, w = shape
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 13), np.linspace(0, h - 1, 9))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    return rspiv.fit_mapping(obj, lens.distort(obj), "p3", center_index=len(obj) // 2)


def frames_through(lens, shape, d_obj, seed: int, render_seed: int) -> list[np.ndarray]:
    """Two uint16 frames of particles (0.03 ppp, 2.5 px, noise 40 counts) moving by the
    uniform object displacement ``d_obj``, imaged through ``lens``."""
    h, w = shape
    rng = np.random.default_rng(seed)
    n = int(0.03 * (h + 60) * (w + 60))
    xm = rng.uniform(-30, w + 30, n)
    ym = rng.uniform(-30, h + 30, n)
    out = []
    for k, s in enumerate((-0.5, 0.5)):
        p = lens.distort(np.column_stack([xm + s * d_obj[0], ym + s * d_obj[1]]))
        out.append(
            _rspiv.render_particles(
                h,
                w,
                np.ascontiguousarray(p[:, 0]),
                np.ascontiguousarray(p[:, 1]),
                np.full(n, 2500.0),
                np.array([2.5]),
                40.0,
                4095,
                render_seed + k,
            )
        )
    return out


class Oblique:
    """An oblique view of a target on a ``(width, height)`` sensor: a homography about its
    centre (the image scale changes by ~40 % across a 2216 px sensor), which no polynomial
    mapping of degree 3 follows to the markers' precision."""

    def __init__(self, shape_wh: tuple[int, int]) -> None:
        self.c = 0.5 * (np.asarray(shape_wh, dtype=np.float64) - 1.0)

    def forward(self, p: np.ndarray) -> np.ndarray:
        q = (np.asarray(p) - self.c) / 1000.0
        den = 1.0 + 0.2 * q[:, 0] + 0.12 * q[:, 1]
        return self.c + 1000.0 * q / den[:, None]
