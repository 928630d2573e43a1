"""Quadrant analysis and joint PDFs (rspiv.quadrant) against direct sums and the exact values of
a jointly Gaussian (u', v')."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.errors import InvalidInputError
from rspiv.quadrant import QuadrantAccumulator, gaussian_quadrant

HOLES = (0.0, 0.5, 1.0, 2.0, 4.0)


def _fields(rng, n, ny, nx, rho, nan_share=0.05):
    """Fields of a jointly Gaussian (u', v') about varying means and standard deviations, in
    the pixel frame (v down: the flow's v' = -(v - V))."""
    mu, mv = rng.normal(size=(ny, nx)), rng.normal(size=(ny, nx))
    su, sv = 0.5 + rng.random((ny, nx)), 0.2 + rng.random((ny, nx))
    g1, g2 = rng.normal(size=(2, n, ny, nx))
    u = mu + su * g1
    v = mv - sv * (rho * g1 + np.sqrt(1 - rho**2) * g2)
    u[rng.random(u.shape) < nan_share] = np.nan
    valid = rng.random(u.shape) > nan_share
    return mu, mv, su, sv, u, v, valid


def test_sums_equal_the_direct_sums():
    rng = np.random.default_rng(3)
    n, ny, nx = 12, 5, 40
    mu, mv, su, sv, u, v, valid = _fields(rng, n, ny, nx, -0.4)
    usable = rng.random((ny, nx)) > 0.1
    acc = QuadrantAccumulator(mu, mv, su, sv, usable=usable, sign_y=-1.0, holes=HOLES,
                              bins=20, extent=3.0)  # fmt: skip
    for k in range(n):
        acc.add(u[k], v[k], valid[k], pair_id=k)
    r = acc.results()
    ok = usable & np.isfinite(u) & valid
    du, dv = u - mu, -(v - mv)
    uv = np.where(ok, du * dv, 0.0)
    level = np.abs(du * dv) / (su * sv)
    quads = [(du >= 0) & (dv >= 0), (du < 0) & (dv >= 0), (du < 0) & (dv < 0), (du >= 0) & (dv < 0)]
    count = ok.sum(axis=(0, 2))
    np.testing.assert_array_equal(r["count"], count)
    np.testing.assert_allclose(r["uv"], uv.sum(axis=(0, 2)) / count, rtol=1e-12)
    for q, inq in enumerate(quads):
        for h, hole in enumerate(HOLES):
            sel = ok & inq & (level >= hole)
            want = np.where(sel, uv, 0.0).sum(axis=(0, 2)) / count
            np.testing.assert_allclose(r["stress"][q, h], want, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(r["time_fraction"][q, h], sel.sum(axis=(0, 2)) / count)
    # each event in exactly one quadrant: the shares at H = 0 add up to 1
    np.testing.assert_allclose(r["fraction"][:, 0].sum(axis=0), 1.0, rtol=1e-12)
    np.testing.assert_allclose(r["time_fraction"][:, 0].sum(axis=0), 1.0, rtol=1e-12)
    # the joint PDF: the direct histogram, integrating to the share inside the square
    w = 6.0 / 20
    for row in range(ny):
        s = ok[:, row]
        hist, _, _ = np.histogram2d((dv / sv)[:, row][s], (du / su)[:, row][s], bins=20,
                                    range=[[-3, 3], [-3, 3]])  # fmt: skip
        np.testing.assert_allclose(r["jpdf"][row] * count[row] * w * w, hist, atol=1e-9)
    inside = np.abs(du / su) < 3
    inside &= np.abs(dv / sv) < 3
    np.testing.assert_allclose(r["jpdf"].sum(axis=(1, 2)) * w * w,
                               (inside & ok).sum(axis=(0, 2)) / count, rtol=1e-12)  # fmt: skip


def test_parts_merge_to_one_pass():
    rng = np.random.default_rng(4)
    mu, mv, su, sv, u, v, valid = _fields(rng, 9, 4, 30, 0.3)
    one = QuadrantAccumulator(mu, mv, su, sv)
    parts = [QuadrantAccumulator(mu, mv, su, sv) for _ in range(3)]
    for k in range(9):
        one.add(u[k], v[k], valid[k], pair_id=k)
        parts[k % 3].add(u[k], v[k], valid[k], pair_id=k)
    merged = parts[0].merge(parts[1]).merge(parts[2])
    a, b = one.results(), merged.results()
    for key in ("count", "stress", "time_fraction", "jpdf"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12)
    assert merged.pair_ids == set(range(9)) and merged.n_fields == 9
    with pytest.raises(InvalidInputError, match="share pair"):
        merged.merge(parts[1])
    with pytest.raises(InvalidInputError, match="other means"):
        one.merge(QuadrantAccumulator(mu + 1, mv, su, sv))


def test_gaussian_field_gives_the_exact_shares():
    """200 fields of 8 x 500 vectors, rho = -0.45: every quadrant's share of u'v' and of the
    time at H = 0.5, 1, 2, 4 within 0.012 (about 4 standard errors of these 800,000 samples)
    of the exact bivariate normal values."""
    rng = np.random.default_rng(5)
    rho = -0.45
    mu, mv, su, sv, u, v, _ = _fields(rng, 200, 8, 500, rho, nan_share=0.0)
    acc = QuadrantAccumulator(mu, mv, su, sv, sign_y=-1.0, holes=HOLES)
    for k in range(u.shape[0]):
        acc.add(u[k], v[k], batch=k * 8 // u.shape[0])
    r = acc.results()
    g = gaussian_quadrant(rho, HOLES)
    got = r["fraction"].mean(axis=-1)
    np.testing.assert_allclose(got, g["fraction"], atol=0.012)
    np.testing.assert_allclose(r["time_fraction"].mean(axis=-1), g["time_fraction"], atol=0.004)
    # Q2 and Q4 carry the stress of a layer (rho < 0); the shares fall with the hole
    assert np.all(np.diff(g["fraction"][1]) < 0) and g["fraction"][1, 0] > 0.6
    # mean about the exact means (not the sample means): uv = rho u_rms v_rms
    np.testing.assert_allclose(r["uv"].mean(), rho * np.mean(su * sv), rtol=0.01)
    # the batch means' standard error of uv against the exact one of independent samples,
    # sqrt((1 + rho^2) <(su sv)^2> / N) per row (8 batches: each estimate within about 27 %)
    exact = np.sqrt((1 + rho**2) * np.mean((su * sv) ** 2, axis=1) / r["count"])
    assert np.all(r["uv_batches"] == 8)
    assert np.mean(r["uv_se"] / exact) == pytest.approx(1.0, abs=0.2)


def test_gaussian_reference_values():
    """The closed form at H = 0 and the integral for H > 0 against a Monte Carlo of 4 million
    samples; rho = 0 is symmetric; the shares of H = 0 add up to 1."""
    for rho in (-0.6, 0.0001, 0.3):
        g = gaussian_quadrant(rho, (0.0,))
        assert g["fraction"][:, 0].sum() == pytest.approx(1.0, abs=1e-12)
        assert g["time_fraction"][:, 0].sum() == pytest.approx(1.0, abs=1e-12)
    g = gaussian_quadrant(0.0001, (0.0, 1.0))
    np.testing.assert_allclose(g["time_fraction"][:, 0], 0.25, atol=1e-4)
    rng = np.random.default_rng(6)
    rho = -0.5
    x = rng.normal(size=4_000_000)
    y = rho * x + np.sqrt(1 - rho**2) * rng.normal(size=x.size)
    g = gaussian_quadrant(rho, (0.0, 1.0, 3.0))
    for q, (a, b) in enumerate(((1, 1), (-1, 1), (-1, -1), (1, -1))):
        inq = (a * x >= 0) & (b * y >= 0)
        for h, hole in enumerate((0.0, 1.0, 3.0)):
            sel = inq & (np.abs(x * y) >= hole)
            assert np.mean(np.where(sel, x * y, 0)) == pytest.approx(g["stress"][q, h], abs=2e-3)
            assert np.mean(sel) == pytest.approx(g["time_fraction"][q, h], abs=1e-3)
    with pytest.raises(InvalidInputError, match="rho"):
        gaussian_quadrant(1.0)


def test_bad_input_is_refused():
    z = np.zeros((3, 4))
    one = np.ones((3, 4))
    with pytest.raises(InvalidInputError, match="shape"):
        QuadrantAccumulator(z, z, one, np.ones((3, 5)))
    with pytest.raises(InvalidInputError, match="holes"):
        QuadrantAccumulator(z, z, one, one, holes=(1.0, 0.5))
    with pytest.raises(InvalidInputError, match="holes"):
        QuadrantAccumulator(z, z, one, one, holes=(-1.0,))
    with pytest.raises(InvalidInputError, match="signs"):
        QuadrantAccumulator(z, z, one, one, sign_x=0.5)
    acc = rspiv.QuadrantAccumulator(z, z, one, one)
    with pytest.raises(InvalidInputError, match="shape"):
        acc.add(np.zeros((4, 3)), np.zeros((4, 3)))
    acc.add(one, one, pair_id=7)
    with pytest.raises(InvalidInputError, match="pair 7"):
        acc.add(one, one, pair_id=7)
    # vectors without a spread never enter; rows without samples give NaN
    acc = QuadrantAccumulator(z, z, np.where(np.arange(3)[:, None] == 1, 0.0, one), one)
    acc.add(one, -one)
    r = acc.results()
    assert r["count"].tolist() == [4, 0, 4] and np.isnan(r["stress"][:, :, 1]).all()
