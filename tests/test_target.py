"""Synthetic calibration target: lens model and renderer (ground truth of the calibration)."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.synth import PAPER_OPTICS, LensDistortion, calibration_target, paper_lens


def test_lens_formula_and_identity():
    lens = LensDistortion(k1=0.01, k2=0.002, p1=1e-3, p2=-2e-3, centre=(100.0, 50.0), radius=200.0)
    p = np.array([[300.0, -30.0], [100.0, 50.0]])
    u, v = 1.0, -0.4
    r2 = u * u + v * v
    rad = 0.01 * r2 + 0.002 * r2 * r2
    du = u * rad + 2e-3 * u * v - 2e-3 * (r2 + 2 * u * u)
    dv = v * rad + 1e-3 * (r2 + 2 * v * v) - 4e-3 * u * v
    np.testing.assert_allclose(lens.distort(p)[0], [300 + 200 * du, -30 + 200 * dv], rtol=1e-12)
    np.testing.assert_allclose(lens.distort(p)[1], [100.0, 50.0])  # the centre does not move
    ident = LensDistortion(centre=(3.0, 4.0), radius=10.0)
    np.testing.assert_array_equal(ident.distort(p), p)
    assert ident.is_radial and not lens.is_radial
    with pytest.raises(InvalidInputError):
        lens.distort(np.zeros((3, 3)))
    with pytest.raises(InvalidInputError):
        LensDistortion(radius=0.0)


def test_paper_lens_reaches_about_9px_at_the_corner_and_scales():
    lens = paper_lens()
    corners = np.array([[0.0, 0.0], [8863.0, 0.0], [0.0, 5287.0], [8863.0, 5287.0]])
    shift = np.hypot(*(lens.distort(corners) - corners).T)
    assert 7.5 < shift.max() < 10.5
    small = paper_lens(PAPER_OPTICS.scaled(0.25))
    sc = corners * 0.25
    np.testing.assert_allclose(np.hypot(*(small.distort(sc) - sc).T), 0.25 * shift, rtol=0.02)


def test_render_truth_is_the_distorted_dot_centre():
    t = calibration_target(scale=0.25, noise=False, seed=3)
    o = t.optics
    assert t.image.shape == (1322, 2216) and t.image.dtype == np.uint16
    assert t.image.max() <= 4095
    assert len(t.markers_px) == 91
    np.testing.assert_allclose(t.markers_px, t.lens.distort(t.ideal_px(t.index)))
    # Intensity-weighted centroid of the noise-free blob (background removed) hits the truth.
    s = t.extra["dot_sigma_px"]
    for k in (0, 45, 90):
        x0, y0 = t.markers_px[k]
        xs = np.arange(int(x0 - 5 * s), int(x0 + 5 * s) + 1)
        ys = np.arange(int(y0 - 5 * s), int(y0 + 5 * s) + 1)
        w = t.image[np.ix_(ys, xs)].astype(float)
        w -= np.median(np.concatenate([w[0], w[-1], w[:, 0], w[:, -1]]))
        w = np.clip(w, 0, None)
        cx = (w.sum(0) * xs).sum() / w.sum()
        cy = (w.sum(1) * ys).sum() / w.sum()
        assert abs(cx - x0) < 0.1 and abs(cy - y0) < 0.1
    step = o.magnification * o.pitch_mm
    assert abs(np.hypot(*(t.markers_px[46] - t.markers_px[45])) - step) < 0.01 * step


def test_missing_spurious_rotation_and_determinism():
    a = calibration_target(scale=0.25, seed=5, missing=[(1, 0), (2, 2)], spurious=4, rotation_deg=2)
    b = calibration_target(scale=0.25, seed=5, missing=[(1, 0), (2, 2)], spurious=4, rotation_deg=2)
    np.testing.assert_array_equal(a.image, b.image)
    assert len(a.markers_px) == 89 and len(a.spurious_px) == 4
    assert not np.any((a.index[:, 0] == 1) & (a.index[:, 1] == 0))
    c = calibration_target(scale=0.25, seed=6)
    assert not np.array_equal(a.image, c.image)
    with pytest.raises(InvalidInputError):
        calibration_target(scale=0.0)
    with pytest.raises(InvalidInputError):
        calibration_target(scale=0.25, lens="bogus")


def test_mapping_as_distortion_and_unpacking():
    import rspiv

    base = calibration_target(scale=0.25, noise=False)
    ideal = base.ideal_px(base.index)
    m = rspiv.fit_mapping(ideal, base.markers_px, "p3")
    t = calibration_target(mapping=m, scale=0.25, noise=False)
    np.testing.assert_allclose(t.markers_px, m.forward(ideal))
    image, truth = t
    assert image is t.image and truth is t.markers_px
