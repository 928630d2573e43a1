"""Spectral POD (rspiv.spod) against exact answers: the eigenvalues and modes of scipy's
cross-spectral density matrix, planted travelling waves, and the sampling error of white
noise."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss
from rspiv.errors import InvalidInputError
from rspiv.spod import SpodBuilder, spod


def _csd_matrix(x: np.ndarray, segment: int) -> np.ndarray:
    """scipy's one-sided cross-spectral density matrix of the columns of ``x`` (Hann, half
    overlap, no detrend), as ``S[f, i, j] = <X_i conj(X_j)>``."""
    d = x.shape[1]
    s = np.zeros((segment // 2 + 1, d, d), complex)
    for i in range(d):
        for j in range(d):
            _, s[:, j, i] = ss.csd(x[:, i], x[:, j], window="hann", nperseg=segment,
                                   noverlap=segment // 2, detrend=False)  # fmt: skip
    return s


def _fields(n=400, ny=3, nx=4, seed=1):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, ny, nx))
    v = 0.5 * rng.standard_normal((n, ny, nx))
    t = np.arange(n)[:, None, None]
    xs = np.arange(nx)[None, None, :]
    u += 2.0 * np.cos(2 * np.pi * (0.125 * t - 0.2 * xs))  # a wave on bin 4 of 32
    return u, v


def _values(u, v):
    n = u.shape[0]
    return np.concatenate([(u - u.mean(0)).reshape(n, -1), (v - v.mean(0)).reshape(n, -1)], 1)


def test_the_eigenvalues_and_modes_are_those_of_scipys_cross_spectral_matrix():
    u, v = _fields()
    r = spod(u, v, segment=32, n_modes=3, frequencies=[0, 4, 9, 16])
    s = _csd_matrix(_values(u, v), 32)
    lam, vec = np.linalg.eigh(s)
    lam, vec = lam[:, ::-1], vec[:, :, ::-1]
    assert r.blocks == 24 and r.energy.shape == (17, 24)
    np.testing.assert_allclose(r.energy, lam[:, :24], rtol=0, atol=1e-12 * lam.max())
    np.testing.assert_allclose(r.total, np.trace(s, axis1=1, axis2=2).real, rtol=1e-12)
    d = u[0].size
    for i, fi in enumerate(r.mode_f):
        for j in range(3):
            phi = np.concatenate([r.modes_u[i, j].ravel(), r.modes_v[i, j].ravel()])
            ref = vec[fi, :, j]
            assert abs(np.vdot(ref, phi)) == pytest.approx(1.0, abs=1e-9)  # same up to phase
            big = np.argmax(np.abs(phi))
            assert phi[big].real > 0 and abs(phi[big].imag) < 1e-12
            assert np.sum(np.abs(phi[:d]) ** 2 + np.abs(phi[d:]) ** 2) == pytest.approx(1.0)


def test_a_planted_wave_is_the_leading_mode_with_its_phase_speed():
    u, v = _fields(n=800)
    r = spod(u, v, segment=32, n_modes=2, n_frequencies=1)
    assert list(r.mode_f) == [4]  # where f lambda_1 is largest: the wave
    phi = r.modes_u[0, 0, 0]
    # the wave cos(2 pi (f t - 0.2 x)): its phase falls 0.4 pi per column downstream
    step = np.angle(np.sum(phi[1:] * np.conj(phi[:-1])))
    assert step == pytest.approx(-0.4 * np.pi, abs=0.03)  # the noise's share of the mode
    assert r.fraction[4, 0] > 0.9
    # the wave (amplitude 2 on the 12 u values, a line on bin 4 of 32): one-sided density
    # A^2 N / 3 per value under the periodic Hann; a quarter of it in each neighbouring bin;
    # the white noise's density along the wave's direction, 2, on top
    line = 12 * 2.0**2 * 32 / 3
    assert r.energy[4, 0] == pytest.approx(line + 2.0, rel=0.04)
    np.testing.assert_allclose(r.energy[[3, 5], 0], line / 4 + 2.0, rtol=0.06)
    assert np.all(r.energy[3:6, 1] < 6.0)  # the rest is noise


def test_gaps_restart_the_blocks_and_slices_add_up():
    u, v = _fields(n=300, seed=4)
    ids = np.r_[np.arange(0, 140), np.arange(150, 310)]  # a gap of ten pairs
    r = spod(u, v, segment=32, pair_ids=ids, frequencies=[4])
    x = _values(u, v)
    a, b = x[:140], x[140:]
    # every series' blocks averaged: scipy per series, weighted by its blocks
    ka, kb = (140 - 32) // 16 + 1, (160 - 32) // 16 + 1
    s = (ka * _csd_matrix(a, 32) + kb * _csd_matrix(b, 32)) / (ka + kb)
    assert r.blocks == ka + kb and r.series == [140, 160]
    lam = np.linalg.eigvalsh(s)[:, ::-1]
    np.testing.assert_allclose(r.energy, lam[:, : r.blocks], atol=1e-12 * lam.max())
    # the builder fed in slices of the values, in any order, is the same decomposition
    b_ = SpodBuilder(u.mean(0), v.mean(0), np.ones(u.shape[1:], bool), ids, 32)
    xs = b_.fluctuations(u, v)
    for sl in (slice(10, 24), slice(0, 3), slice(3, 10)):
        b_.add_columns(sl, xs[:, sl])
    b_.solve(1, frequencies=[4])
    for sl in (slice(0, 5), slice(5, 24)):
        b_.add_mode_columns(sl, xs[:, sl])
    r2 = b_.result()
    np.testing.assert_allclose(r2.energy, r.energy, atol=1e-12 * lam.max())
    np.testing.assert_allclose(r2.modes_u[0, 0], r.modes_u[0, 0], atol=1e-12)


def test_rejected_vectors_are_filled_with_their_mean_and_counted():
    u, v = _fields(n=200, seed=5)
    valid = np.ones(u.shape, bool)
    valid[::7, 1, 2] = False
    u2 = u.copy()
    u2[~valid] = 1e6  # a wild rejected value must not enter
    mu, mv = u.mean(0), v.mean(0)
    r = spod(u2, v, valid, segment=32, mean_u=mu, mean_v=mv, frequencies=[4])
    # a rejected vector is both components at their means
    uf, vf = np.where(valid, u, mu), np.where(valid, v, mv)
    ref = spod(uf, vf, segment=32, mean_u=mu, mean_v=mv, frequencies=[4])
    np.testing.assert_allclose(r.energy, ref.energy, rtol=1e-12, atol=1e-12)
    assert r.gaps == pytest.approx((~valid).sum() / valid.size)  # vectors filled


def test_the_interval_holds_white_noises_spread():
    # one value: the eigenvalue is the Welch estimate; across frequencies and realisations its
    # relative variance is 2 / nu, and the 95 % interval holds the true density 2 sigma^2
    rng = np.random.default_rng(7)
    rel, inside = [], []
    for _ in range(100):
        u = rng.standard_normal((32 * 13, 1, 1))
        r = spod(u, np.zeros_like(u), segment=64, frequencies=[1])
        lam = r.energy[1:-1, 0]  # interior bins: nu = r.nu[1]
        rel.append(lam / 2.0 - 1.0)
        lo, hi = r.interval(0.95)
        inside.append((lo[1:-1, 0] <= 2.0) & (2.0 <= hi[1:-1, 0]))
    rel = np.concatenate(rel)
    nu = r.nu[1]
    assert r.blocks == 12 and nu == pytest.approx(2 * 144 / (12 + 2 * 11 / 36))
    assert np.var(rel) == pytest.approx(2 / nu, rel=0.1)  # 3100 estimates, correlated bins
    assert np.mean(np.concatenate(inside)) == pytest.approx(0.95, abs=0.025)


def test_bad_input_is_refused_in_one_line():
    u, v = _fields(n=100)
    mean = np.zeros(u.shape[1:])
    dom = np.ones(u.shape[1:], bool)
    with pytest.raises(InvalidInputError, match="segment must be an even integer"):
        spod(u, v, segment=33)
    with pytest.raises(InvalidInputError, match="at least 2 are needed"):
        spod(u, v, segment=96)
    with pytest.raises(InvalidInputError, match="pair_ids must increase"):
        SpodBuilder(mean, mean, dom, [3, 2, 5], 4)
    with pytest.raises(InvalidInputError, match="one shape"):
        spod(u, v[:, :2])
    with pytest.raises(InvalidInputError, match="frequencies must be indices"):
        spod(u, v, segment=16, frequencies=[9])
    with pytest.raises(InvalidInputError, match="level must lie"):
        spod(u, v, segment=16).interval(1.5)
    b = SpodBuilder(mean, mean, dom, np.arange(100), 16)
    x = b.fluctuations(u, v)
    with pytest.raises(InvalidInputError, match="not added"):
        b.solve()
    with pytest.raises(InvalidInputError, match="must be"):
        b.add_columns(slice(0, 5), x[:, :4])
    b.add_columns(slice(0, 24), x)
    with pytest.raises(InvalidInputError, match="already added"):
        b.add_columns(slice(0, 2), x[:, :2])
    with pytest.raises(InvalidInputError, match="add_mode_columns"):
        b.add_mode_columns(slice(0, 24), x)
    b.solve()
    with pytest.raises(InvalidInputError, match="every value added twice"):
        b.result()
