"""The lighting of a real near-wall recording, added to rendered particle frames: a background
that the laser sheet lights unevenly (a gradient that differs between frames A and B), a static
glare line along the wall, and a slow drift of both over the run.

Intensities are in counts of the frames' bit depth (12-bit by default); lengths in image px. The
glare is a Gaussian across the wall's image line (the wall mapped through the camera, so it
follows the lens distortion), the same in every frame up to the drift. The drift scales the
background and the glare linearly over the run: by ``1`` at the first pair and ``1 + drift`` at
the last. Sums above the full scale saturate, as on a camera.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["Lighting", "NEAR_WALL_LIGHTING"]


@dataclasses.dataclass(frozen=True)
class Lighting:
    """Background, gradient, glare and drift of a recording (module docstring).

    Attributes
    ----------
    background : float
        Mean background level, counts.
    gradient : float
        Peak-to-peak of the background's linear gradient across the image, counts; frame A's
        rises along x, frame B's along y (the two laser cavities light the sheet differently).
    glare : float
        Peak of the glare line at the wall, counts.
    glare_sigma_px : float
        Standard deviation of the glare across the wall, px.
    drift : float
        Relative growth of background and glare from the first pair to the last.
    full_scale : int
        Saturation level (4095 for 12-bit frames).
    """

    background: float = 300.0
    gradient: float = 600.0
    glare: float = 2500.0
    glare_sigma_px: float = 6.0
    drift: float = 0.3
    full_scale: int = 4095

    def __post_init__(self) -> None:
        for key in ("background", "gradient", "glare", "drift"):
            v = getattr(self, key)
            if not (np.isfinite(v) and v >= 0):
                raise InvalidInputError(f"Lighting.{key} must be a finite number >= 0, got {v!r}")
        if not (np.isfinite(self.glare_sigma_px) and self.glare_sigma_px > 0):
            raise InvalidInputError("Lighting.glare_sigma_px must be > 0")

    def field(self, shape: tuple[int, int], wall_row: np.ndarray, frame: int, k: int, n: int):
        """The light added to frame ``frame`` (0 = A, 1 = B) of pair ``k`` of ``n``: float64
        array of ``shape``; ``wall_row[i]`` is the wall's image row at column ``i``."""
        h, w = shape
        scale = 1.0 + self.drift * (k / (n - 1) if n > 1 else 0.0)
        y = np.arange(h, dtype=np.float64)[:, None]
        x = np.arange(w, dtype=np.float64)[None, :]
        ramp = x / max(w - 1, 1) if frame == 0 else y / max(h - 1, 1)
        light = self.background + self.gradient * (ramp - 0.5)
        d = (y - np.asarray(wall_row, np.float64)[None, :]) / self.glare_sigma_px
        light = light + self.glare * np.exp(-0.5 * d * d)
        return scale * light

    def apply(self, img: np.ndarray, wall_row: np.ndarray, frame: int, k: int, n: int):
        """``img`` (integer counts) with :meth:`field` added, saturated at ``full_scale``."""
        out = img.astype(np.float64) + self.field(img.shape, wall_row, frame, k, n)
        return np.minimum(np.rint(out), self.full_scale).astype(img.dtype)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as a plain dictionary."""
        return dataclasses.asdict(self)


#: The impairments of the near-wall test campaigns: a glare line brighter than most particles,
#: a gradient of twice the background level and a 30 % drift over the run.
NEAR_WALL_LIGHTING = Lighting()


def wall_rows(truth: Any) -> np.ndarray:
    """The wall's image row at every column of ``truth``'s sensor (the object-frame wall line
    mapped through the camera, interpolated along x)."""
    h, w = truth.shape
    xo = np.linspace(-16.0, w + 15.0, 256)
    img = np.asarray(truth.to_image(np.column_stack([xo, truth.wall_y(xo)])), np.float64)
    order = np.argsort(img[:, 0])
    return np.interp(np.arange(w, dtype=np.float64), img[order, 0], img[order, 1])
