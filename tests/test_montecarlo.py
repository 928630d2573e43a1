"""Monte Carlo study: exact linear theory for P3, determinism across thread counts, defaults,
histograms and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.errors import InvalidInputError
from rspiv.synth import calibration_target


@pytest.fixture(scope="module")
def cal():
    tg = calibration_target(scale=0.25, seed=21)
    return rspiv.calibrate(tg.image, 19.51, model="p3", compare=False)


def test_p3_matches_exact_linear_theory(cal):
    # P3 is linear in its coefficients: with fixed object points the residual is
    # eps = (H - I)(b + z), z ~ N(0, s^2) except at the fixed central marker, so
    # mean = nominal residual and cov = s^2 [(H - I) D (H - I)^T]_jj exactly.
    s = 0.05
    res = rspiv.monte_carlo(cal, n=20_000, sigma_image_px=s, sigma_object_px=0.0, seed=3)
    mk = cal.markers
    oh = (mk.object_px - mk.object_px[mk.centre]) / cal.mapping.scale
    x, y = oh.T
    phi = np.column_stack([x**a * y**b for a in range(4) for b in range(4 - a)])
    h = phi @ np.linalg.pinv(phi)
    d = np.ones(len(x))
    d[mk.centre] = 0.0
    a = h - np.eye(len(x))
    var = s**2 * np.einsum("jk,k,jk->j", a, d, a)
    assert res.n_failed == 0
    np.testing.assert_allclose(res.cov_px2[:, 0, 0], var, rtol=0.05, atol=1e-6)
    np.testing.assert_allclose(res.cov_px2[:, 1, 1], var, rtol=0.05, atol=1e-6)
    nominal = cal.mapping.residuals
    np.testing.assert_allclose(res.nominal_px, nominal, atol=1e-6)
    np.testing.assert_allclose(res.mean_px, nominal, atol=5 * s / np.sqrt(20_000) + 1e-9)
    # Gaussian residuals: the 99 % radius of a (nearly) isotropic 2D normal is 3.035 sigma.
    j = int(np.argmax(var))
    assert res.radius99_px[j] == pytest.approx(3.035 * np.sqrt(var[j]), rel=0.05)


def test_same_seed_same_result_on_1_and_2_threads(cal):
    kw = dict(n=5000, seed=9, sigma_image_px=0.057, sigma_object_px=0.38, hist_bins=16)
    a = rspiv.monte_carlo(cal, threads=1, **kw)
    b = rspiv.monte_carlo(cal, threads=2, **kw)
    for f in ("mean_px", "cov_px2", "radius99_px", "within1", "within2", "hist"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    c = rspiv.monte_carlo(cal, threads=2, **{**kw, "seed": 10})
    assert not np.array_equal(a.cov_px2, c.cov_px2)
    r2a = rspiv.monte_carlo(cal, model="r2", threads=1, **{**kw, "n": 600})
    r2b = rspiv.monte_carlo(cal, model="r2", threads=2, **{**kw, "n": 600})
    np.testing.assert_array_equal(r2a.cov_px2, r2b.cov_px2)
    assert r2a.model == "r2" and r2a.n_failed == 0


def test_defaults_histogram_samples_and_paper_numbers(cal):
    res = rspiv.monte_carlo(cal, n=3000, hist_bins=32, keep_samples=True, seed=1)
    assert res.sigma_image_px == pytest.approx(cal.image_sigma_px)
    assert res.sigma_object_px == pytest.approx(cal.object_sigma_px)
    m = len(cal.markers)
    assert res.hist.shape == (m, 32, 32) and res.samples.shape == (3000, m, 2)
    assert np.all(res.hist.sum(axis=(1, 2)) <= 3000)
    r = np.hypot(res.samples[..., 0], res.samples[..., 1])
    np.testing.assert_allclose(res.within1, np.mean(r <= 1.0, axis=0), atol=1e-12)
    # The paper's uncertainties (0.057 px image, 0.380 px object): P3 keeps 99 % within 2 px.
    p = rspiv.monte_carlo(cal, n=4000, sigma_image_px=0.057, sigma_object_px=0.38, seed=2)
    assert np.all(p.radius99_px < 2.0) and np.all(p.within2 > 0.99)
    assert "99 % radius" in p.summary()


def test_bad_input(cal):
    for kw in ({"n": 0}, {"n": -5}, {"threads": 0}, {"sigma_image_px": -1.0}, {"model": "q9"}):
        with pytest.raises(InvalidInputError):
            rspiv.monte_carlo(cal, **{"n": 10, **kw})
    with pytest.raises(InvalidInputError):
        rspiv.monte_carlo("not a calibration", n=10)
