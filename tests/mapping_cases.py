"""Known mappings of each model over the full 47 MP sensor, and an independent NumPy
implementation of the models (the ground truth of tests/test_mapping*.py).

Sensor 8864 x 5288 px, 13 x 7 markers at 19.51 mm pitch and M = 34.538 px/mm (paper section
3.1), centred on the sensor. Each case maps object px -> image px through a model with known
coefficients in its own normalised frame (centre and scale differ from rspiv's on purpose; the
model classes are closed under those changes of frame). Run as a script to print the cases'
distortion at the sensor corner.
"""

from __future__ import annotations

import numpy as np

SENSOR = (8864, 5288)
PITCH_PX = 19.51 * 34.538
CENTRE = ((SENSOR[0] - 1) / 2.0, (SENSOR[1] - 1) / 2.0)

# The truth's own normalisation (the paper's Table 2 values), deliberately not rspiv's.
TRUTH_CO = (4380.906, 2559.182)
TRUTH_CI = (4380.356, 2555.753)
TRUTH_S = 8423.924


def grid_13x7() -> np.ndarray:
    """The 91 object points (object px), row-major from the top-left marker."""
    i, j = np.meshgrid(np.arange(13) - 6.0, np.arange(7) - 3.0)
    return np.column_stack([CENTRE[0] + i.ravel() * PITCH_PX, CENTRE[1] + j.ravel() * PITCH_PX])


def sensor_grid(nx: int = 45, ny: int = 28) -> np.ndarray:
    """Points covering the whole sensor, edges included (px)."""
    x, y = np.meshgrid(np.linspace(0, SENSOR[0] - 1, nx), np.linspace(0, SENSOR[1] - 1, ny))
    return np.column_stack([x.ravel(), y.ravel()])


def eval_model(model: str, c: np.ndarray, x: np.ndarray, y: np.ndarray):
    """The model F in normalised coordinates (coefficient layout of rspiv/DESIGN.md)."""
    c = np.asarray(c, dtype=np.float64)
    if model == "r1":
        d = c[6] * x + c[7] * y + 1.0
        return (c[0] * x + c[1] * y + c[2]) / d, (c[3] * x + c[4] * y + c[5]) / d
    if model == "r2":
        phi = np.stack([x, y, np.ones_like(x), x * x, x * y, y * y])
        psi = np.stack([x, y, x * x, x * y, y * y])
        d = 1.0 + c[12:17] @ psi
        return (c[0:6] @ phi) / d, (c[6:12] @ phi) / d
    if model == "p3":
        b = p3_basis(x, y)
        return c[:10] @ b, c[10:] @ b
    raise ValueError(model)


def p3_basis(x, y):
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3])


def coeff_jacobian(model: str, c: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """d(fx, fy)/dc stacked as (2N, P): rows of fx first, then rows of fy."""
    n = x.size
    if model == "p3":
        b = p3_basis(x, y).T
        j = np.zeros((2 * n, 20))
        j[:n, :10] = b
        j[n:, 10:] = b
        return j
    fx, fy = eval_model(model, c, x, y)
    if model == "r1":
        d = c[6] * x + c[7] * y + 1.0
        phi = np.stack([x, y, np.ones_like(x)]).T / d[:, None]
        psi = np.stack([x, y]).T / d[:, None]
        j = np.zeros((2 * n, 8))
        j[:n, 0:3] = phi
        j[n:, 3:6] = phi
        j[:n, 6:8] = -fx[:, None] * psi
        j[n:, 6:8] = -fy[:, None] * psi
        return j
    d = 1.0 + c[12:17] @ np.stack([x, y, x * x, x * y, y * y])
    phi = np.stack([x, y, np.ones_like(x), x * x, x * y, y * y]).T / d[:, None]
    psi = np.stack([x, y, x * x, x * y, y * y]).T / d[:, None]
    j = np.zeros((2 * n, 17))
    j[:n, 0:6] = phi
    j[n:, 6:12] = phi
    j[:n, 12:17] = -fx[:, None] * psi
    j[n:, 12:17] = -fy[:, None] * psi
    return j


def truth_coefficients(model: str, strength: float = 1.0) -> np.ndarray:
    """Known coefficients; ``strength = 1`` gives 0.33 % of the radius at the sensor corner
    (the paper's pincushion, ~17 px) plus small decentring and perspective terms; 3 gives ~1 %."""
    k = 0.0088 * strength  # radial term: k r^2 at the corner (r^2 ~ 0.375) ~ 0.33 %
    if model == "r1":
        p = 0.0025 * strength
        return np.array([1.0004, 0.0003, 2e-4, -0.0002, 0.9997, -3e-4, p, -0.6 * p])
    if model == "r2":
        return np.array(
            [
                *(1.0004, 0.0003, 2e-4, 1.5e-4, -1e-4, 0.5e-4),
                *(-0.0002, 0.9997, -3e-4, -0.5e-4, 1.2e-4, 2e-4),
                *(0.0004, -0.0003, -k, 0.0, -k),
            ]
        )
    if model == "p3":
        return np.array(
            [
                *(2e-4, 1.0004, 0.0003, 1.5e-4, -1e-4, 0.5e-4, k, 0.0, k, 0.0),
                *(-3e-4, -0.0002, 0.9997, -0.5e-4, 1.2e-4, 2e-4, 0.0, k, 0.0, k),
            ]
        )
    raise ValueError(model)


def apply_truth(model: str, coeffs: np.ndarray, object_px: np.ndarray) -> np.ndarray:
    """Object px -> image px through the known mapping."""
    x = (object_px[:, 0] - TRUTH_CO[0]) / TRUTH_S
    y = (object_px[:, 1] - TRUTH_CO[1]) / TRUTH_S
    fx, fy = eval_model(model, coeffs, x, y)
    return np.column_stack([TRUTH_CI[0] + TRUTH_S * fx, TRUTH_CI[1] + TRUTH_S * fy])


def linear_start(model: str, oh: np.ndarray, ih: np.ndarray) -> np.ndarray:
    """Linearised (DLT-style) least-squares start for scipy, independent of rspiv."""
    x, y = oh[:, 0], oh[:, 1]
    if model == "p3":
        b = p3_basis(x, y).T
        cx = np.linalg.lstsq(b, ih[:, 0], rcond=None)[0]
        cy = np.linalg.lstsq(b, ih[:, 1], rcond=None)[0]
        return np.concatenate([cx, cy])
    if model == "r1":
        phi = np.column_stack([x, y, np.ones_like(x)])
        psi = np.column_stack([x, y])
    else:
        phi = np.column_stack([x, y, np.ones_like(x), x * x, x * y, y * y])
        psi = np.column_stack([x, y, x * x, x * y, y * y])
    q, r = phi.shape[1], psi.shape[1]
    n = x.size
    a = np.zeros((2 * n, 2 * q + r))
    a[:n, :q] = phi
    a[n:, q : 2 * q] = phi
    a[:n, 2 * q :] = -ih[:, [0]] * psi
    a[n:, 2 * q :] = -ih[:, [1]] * psi
    return np.linalg.lstsq(a, np.concatenate([ih[:, 0], ih[:, 1]]), rcond=None)[0]


if __name__ == "__main__":
    corner = np.array([[0.0, 0.0], [SENSOR[0] - 1.0, SENSOR[1] - 1.0]])
    for m in ("r1", "r2", "p3"):
        for s in (1.0, 3.0):
            img = apply_truth(m, truth_coefficients(m, s), corner)
            d = np.hypot(*(img - corner).T)
            print(f"{m} strength {s}: corner displacement {d.round(2)} px")
