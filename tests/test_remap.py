"""Keys-bicubic remap with coordinate arrays (rspiv.dewarp.remap), against analytic images and
OpenCV."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.dewarp import remap
from rspiv.errors import InvalidInputError


def _analytic(x, y):
    """Smooth test image: low-frequency sinusoids and a Gaussian (wavelengths >= 23 px)."""
    return (
        1000.0
        + 300.0 * np.sin(2 * np.pi * x / 41.0 + 0.3)
        + 200.0 * np.cos(2 * np.pi * y / 23.0 - 1.1)
        + 400.0 * np.exp(-((x - 60.0) ** 2 + (y - 35.0) ** 2) / (2 * 12.0**2))
    )


def _grid(h, w):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return xx, yy


def _keys_1d(t):
    """Keys weights (a = -0.5) of the neighbours -1, 0, 1, 2 at fractional position t."""
    t2, t3 = t * t, t * t * t
    return np.stack([-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1,
                     -1.5 * t3 + 2 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2])  # fmt: skip


def test_matches_a_direct_keys_evaluation():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 4000, (20, 30)).astype(np.float32)
    sx = rng.uniform(1.0, 26.99, (5, 7))
    sy = rng.uniform(1.0, 16.99, (5, 7))
    out = remap(img, sx, sy)
    ix, iy = np.floor(sx).astype(int), np.floor(sy).astype(int)
    wx, wy = _keys_1d(sx - ix), _keys_1d(sy - iy)
    ref = np.zeros_like(sx)
    for j in range(4):
        for i in range(4):
            ref += wy[j] * wx[i] * img[iy + j - 1, ix + i - 1]
    np.testing.assert_allclose(out, ref, rtol=2e-6, atol=2e-3)


def test_identity_is_exact_for_uint16_and_float32():
    rng = np.random.default_rng(2)
    img = rng.integers(0, 65536, (33, 47), dtype=np.uint16)
    xx, yy = _grid(33, 47)
    assert np.array_equal(remap(img, xx, yy, out_dtype="uint16"), img)
    assert np.array_equal(remap(img, xx, yy), img.astype(np.float32))
    f = rng.standard_normal((33, 47)).astype(np.float32)
    assert np.array_equal(remap(f, xx.astype(np.float32), yy.astype(np.float32)), f)


def test_subpixel_shift_of_band_limited_image_and_zero_fill():
    h, w = 80, 120
    xx, yy = _grid(h, w)
    img = _analytic(xx, yy).astype(np.float32)
    dx, dy = 0.3712, -0.8149
    out = remap(img, xx + dx, yy + dy)
    exact = _analytic(xx + dx, yy + dy)
    inner = (slice(4, h - 4), slice(4, w - 4))
    err = np.abs(out[inner] - exact[inner])
    # Third-order kernel: shortest wavelength 23 px, amplitudes <= 400 -> ~1e-4 relative
    # (measured 0.078 counts of ~1000).
    assert err.max() < 0.15
    # Outside the footprint [-0.5, w - 0.5] the fill value, inside the image values.
    out = remap(img, xx + 0.6 * w, yy, fill=-7.0)
    assert np.all(out[:, xx[0] + 0.6 * w > w - 0.5] == -7.0)
    assert np.all(out[:, xx[0] + 0.6 * w <= w - 0.5] > 0)


def test_full_precision_beats_opencv_quantisation():
    cv2 = pytest.importorskip("cv2")
    h, w = 64, 96
    xx, yy = _grid(h, w)
    img = _analytic(xx, yy).astype(np.float32)
    # A shift between OpenCV's 1/32 px steps.
    dx, dy = 0.4843, 0.2231
    mx, my = (xx + dx).astype(np.float32), (yy + dy).astype(np.float32)
    ours = remap(img, mx, my)
    theirs = cv2.remap(img, mx, my, interpolation=cv2.INTER_CUBIC,
                       borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    exact = _analytic(xx + dx, yy + dy)
    inner = (slice(4, h - 4), slice(4, w - 4))
    e_ours = np.abs(ours - exact)[inner].max()
    e_cv = np.abs(theirs - exact)[inner].max()
    # Measured: 0.073 against OpenCV's 3.7 (its a = -0.75 kernel and 1/32 px quantisation).
    assert e_ours < 0.15
    assert e_ours < 0.1 * e_cv
    # Both are cubic convolutions of the same image: close, not equal.
    assert np.abs(ours - theirs)[inner].max() < 6.0


def test_uint16_output_rounds_and_clips():
    img = np.array([[0, 65535, 65535, 0]] * 4, dtype=np.uint16)
    xx, yy = _grid(4, 4)
    out = remap(img, xx + 0.5, yy, out_dtype=np.uint16)
    assert out.dtype == np.uint16
    # Overshoot of the cubic kernel is clipped at 65535, undershoot at 0.
    assert out.max() <= 65535 and out.min() >= 0
    f = remap(img, xx + 0.5, yy)
    np.testing.assert_array_equal(out, np.clip(np.round(f), 0, 65535).astype(np.uint16))


def test_invalid_inputs():
    img = np.zeros((4, 4), np.uint16)
    xx, yy = _grid(4, 4)
    with pytest.raises(InvalidInputError):
        remap(img, xx, yy[:3])
    with pytest.raises(InvalidInputError):
        remap(np.zeros((2, 2, 2)), xx, yy)
    with pytest.raises(InvalidInputError):
        remap(img, xx, yy, out_dtype="int8")
    with pytest.raises(InvalidInputError):
        remap(np.zeros((0, 4), np.float32), xx, yy)
