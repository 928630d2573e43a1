"""Skewness and flatness per vector (rspiv.moments, FieldAccumulator): streaming against the
direct sums, merging, state round trips, the standard errors against the scatter of replicates,
the noise correction, and through PIV against the exact displacements drawn."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import rspiv
import scipy.stats as ss
from rspiv import _rspiv, moments
from rspiv.profiles import profile_from_accumulator, scaled_accumulator
from rspiv.stats import FieldAccumulator
from rspiv.synth import particle_pair


def _skewed(rng, size):
    """A skewed, heavy-tailed sample (gamma, shape 2: S = 1.41, F = 6)."""
    return rng.gamma(2.0, size=size) * 0.7 + 3.0


def _direct_central(x, p):
    m = np.nanmean(x, axis=0)
    n = np.sum(np.isfinite(x), axis=0)
    return np.nansum((x - m) ** p, axis=0) / n


def test_streaming_equals_the_direct_moments():
    rng = np.random.default_rng(1)
    x = _skewed(rng, (300, 4, 5))
    x[rng.random(x.shape) < 0.1] = np.nan  # rejected vectors
    y = -0.5 * x**2 + 1.0
    acc = FieldAccumulator((4, 5))
    for k in range(len(x)):
        acc.add(x[k], y[k])
    for comp, data in (("u", x), ("v", y)):
        mu = acc.central_moments(comp)
        for p in range(2, 9):
            ref = _direct_central(data, p)
            assert np.allclose(mu[p - 2], ref, rtol=1e-10, atol=0), p
        sf = acc.skewness_flatness(comp)
        assert np.allclose(sf["S"], ss.skew(data, axis=0, nan_policy="omit"), rtol=1e-10)
        assert np.allclose(
            sf["F"], ss.kurtosis(data, axis=0, fisher=False, nan_policy="omit"), rtol=1e-10
        )


def test_any_split_merges_to_one_pass():
    rng = np.random.default_rng(2)
    x = _skewed(rng, (240, 3, 3))
    x[rng.random(x.shape) < 0.2] = np.nan
    x[:, 0, 0] = np.nan  # a vector that never has a sample
    x[:50, 1, 1] = np.nan  # one that has none in the first part
    whole = FieldAccumulator((3, 3))
    parts = [FieldAccumulator((3, 3)) for _ in range(4)]  # the last stays empty
    for k in range(len(x)):
        whole.add(x[k], 2 * x[k])
        parts[0 if k < 50 else (1 if k < 200 else 2)].add(x[k], 2 * x[k], pair_id=k)
    merged = FieldAccumulator.merged(parts)
    for comp in ("u", "v"):
        a, b = whole.central_moments(comp), merged.central_moments(comp)
        assert np.array_equal(np.isnan(a), np.isnan(b))
        ok = np.isfinite(a)
        assert np.allclose(a[ok], b[ok], rtol=1e-9, atol=1e-12)


def test_states_round_trip_and_old_states_have_no_higher_moments():
    rng = np.random.default_rng(3)
    acc = FieldAccumulator((2, 3))
    for k in range(20):
        acc.add(_skewed(rng, (2, 3)), rng.normal(size=(2, 3)), pair_id=k)
    ds = acc.to_xarray()
    assert {"skewness_u", "flatness_u", "skewness_v", "flatness_v", "hm_u"} <= set(ds)
    back = FieldAccumulator.from_xarray(ds)
    assert np.array_equal(back.hm_u, acc.hm_u) and np.array_equal(back.hm_v, acc.hm_v)
    assert np.array_equal(pickle.loads(pickle.dumps(acc)).hm_v, acc.hm_v)
    # a state written before the higher moments: NaN, also after merging into a new one
    old = FieldAccumulator.from_xarray(ds.drop_vars(["hm_u", "hm_v"]))
    assert np.isnan(old.skewness_flatness("u")["S"]).all()
    state = acc.__getstate__()
    del state["hm_u"], state["hm_v"]
    unpickled = FieldAccumulator.__new__(FieldAccumulator)
    unpickled.__setstate__(state)
    assert np.isnan(unpickled.skewness_flatness("v")["F"]).all()
    fresh = FieldAccumulator((2, 3))
    fresh.add(np.ones((2, 3)), np.ones((2, 3)), pair_id="new")
    assert np.isnan(fresh.merge(old).skewness_flatness("u")["S"]).all()
    # the second moments are untouched by all this
    assert np.allclose(old.uu, acc.uu)


@pytest.mark.parametrize("kind", ["gaussian", "gamma"])
def test_standard_errors_match_the_scatter_of_replicates(kind):
    """Each of 3000 vectors is an independent replicate of 1000 samples: the standard
    deviation of their skewness and flatness is what eps_S, eps_F must state."""
    rng = np.random.default_rng(4)
    nvec, n = 3000, 1000
    acc = FieldAccumulator((nvec,))
    for _ in range(n):
        u = rng.normal(size=nvec) if kind == "gaussian" else _skewed(rng, nvec)
        acc.add(u, u)
    sf = acc.skewness_flatness("u")
    for key in ("S", "F"):
        scatter = np.std(sf[key])
        stated = np.sqrt(np.mean(sf[f"eps_{key}"] ** 2))
        assert abs(stated / scatter - 1) < 0.1, (kind, key, stated, scatter)
    if kind == "gaussian":
        assert abs(np.mean(sf["eps_S"]) / np.sqrt(6 / n) - 1) < 0.03
        assert abs(np.mean(sf["eps_F"]) / np.sqrt(24 / n) - 1) < 0.05
    else:  # skewed and heavy-tailed: several times the Gaussian values
        assert np.mean(sf["eps_F"]) > 3 * np.sqrt(24 / n)


def test_the_noise_correction_recovers_the_flow_moments():
    """Gaussian errors of a sigma that varies from sample to sample, sigma given per vector:
    the corrected S and F are the error-free samples', the raw ones are drawn towards 0 and 3."""
    rng = np.random.default_rng(5)
    nvec, n = 200, 5000
    clean, noisy = FieldAccumulator((nvec,)), FieldAccumulator((nvec,))
    for _ in range(n):
        u = _skewed(rng, nvec)  # std 0.99
        sig = rng.uniform(0.4, 0.8, nvec)
        e = rng.normal(size=nvec) * sig
        clean.add(u, u)
        noisy.add(u + e, u, sigma_u=sig, sigma_v=np.zeros(nvec))
    ref = clean.skewness_flatness("u")
    raw = noisy.skewness_flatness("u")
    cor = noisy.skewness_flatness("u", corrected=True)
    for key in ("S", "F"):
        err_raw = np.mean(raw[key] - ref[key])
        err_cor = np.mean(cor[key] - ref[key])
        # the average over 200 vectors: its own scatter is eps / sqrt(200)
        tol = 3 * np.sqrt(np.mean(raw[f"eps_{key}"] ** 2) / nvec)
        assert abs(err_cor) < tol, (key, err_cor, tol)
        assert abs(err_raw) > 5 * tol, (key, err_raw, tol)
    assert np.mean(raw["S"]) < np.mean(ref["S"]) and np.mean(raw["F"]) < np.mean(ref["F"])


def test_through_piv_the_drawn_displacements_moments_come_back():
    """Pairs of one uniform displacement each, drawn from a skewed distribution: every vector
    of the accumulated fields has the skewness and flatness of the draws, up to what the PIV's
    own error allows (it depends on the displacement, peak-locking-like, so it reshapes the
    distribution by about its size relative to the spread: S by ~3 r, F by ~1.5 F r with r =
    the vectors' RMS error over the draws' standard deviation)."""
    rng = np.random.default_rng(6)
    n = 120
    draws = {
        "u": rng.gamma(2.0, size=n) * 0.8 + 1.0,  # S = 1.74, F = 9.6 for these draws
        "v": -(rng.gamma(3.0, size=n) * 0.3) + 0.5,  # S = -1.57, F = 7.1
    }
    acc = None
    inner = (slice(1, -1), slice(1, -1))
    sq = {"u": 0.0, "v": 0.0}
    for k in range(n):
        a, b = particle_pair((128, 128), (draws["u"][k], draws["v"][k]), seed=100 + k)
        f = rspiv.piv(a, b, passes=[(32, 32), (32, 32)])
        if acc is None:
            acc = FieldAccumulator(f.u.shape)
        acc.add(f.u, f.v, valid=f.valid, sigma_u=f.sigma_u, sigma_v=f.sigma_v)
        for comp, got in (("u", f.u), ("v", f.v)):
            sq[comp] += np.mean((got[inner] - draws[comp][k]) ** 2)
    for comp, d in draws.items():
        r = np.sqrt(sq[comp] / n) / np.std(d)
        assert r < 0.03  # 0.012 (u) and 0.025 (v) px over 1.1 and 0.5 px
        sf = acc.skewness_flatness(comp)
        s_ref, f_ref = ss.skew(d), ss.kurtosis(d, fisher=False)
        assert np.max(np.abs(sf["S"][inner] - s_ref)) < 3 * r, comp
        assert np.max(np.abs(sf["F"][inner] - f_ref)) < 1.5 * f_ref * r, comp


def test_profile_columns():
    """Along x, the per-vector central moments are averaged (count-weighted), then S and F."""
    rng = np.random.default_rng(7)
    acc = FieldAccumulator((3, 4))
    for k in range(400):
        u = _skewed(rng, (3, 4)) * np.array([1.0, 2.0, 3.0])[:, None]
        u[0, 0] = np.nan if k % 2 else u[0, 0]
        acc.add(u, -u, sigma_u=np.full((3, 4), 0.1), sigma_v=np.full((3, 4), 0.1))
    prof = profile_from_accumulator(acc, axis=1)
    mu = acc.central_moments("u")
    w = acc.count.astype(float)
    avg = (mu * w).sum(axis=2) / w.sum(axis=1)
    assert np.allclose(prof["S_u"], avg[1] / avg[0] ** 1.5)
    assert np.allclose(prof["F_u"], avg[2] / avg[0] ** 2)
    assert np.allclose(prof["S_v"], -prof["S_u"]) and np.allclose(prof["F_v"], prof["F_u"])
    s_c, f_c = moments.noise_corrected(avg[0], avg[1], avg[2], 0.01, 1e-4)
    assert np.allclose(prof["S_u_c"], s_c) and np.allclose(prof["F_u_c"], f_c)
    assert np.all(prof["eps_S_u"] > 0) and np.all(prof["eps_F_u"] > prof["eps_S_u"])


def test_units_and_axis_flips_keep_the_shape_of_the_distribution():
    """The campaign's SI scaling with the axes flipped (``scaled_accumulator``): S changes
    sign with its axis, F does not, the errors stay."""
    rng = np.random.default_rng(8)
    acc = FieldAccumulator((2, 2))
    for _ in range(50):
        acc.add(_skewed(rng, (2, 2)), _skewed(rng, (2, 2)))
    si = scaled_accumulator(acc, 2.5e-3, -1.0, 1.0)
    for comp, sign in (("u", -1.0), ("v", 1.0)):
        a, b = acc.skewness_flatness(comp), si.skewness_flatness(comp)
        assert np.allclose(b["S"], sign * a["S"]) and np.allclose(b["F"], a["F"])
        assert np.allclose(b["eps_S"], a["eps_S"]) and np.allclose(b["eps_F"], a["eps_F"])


def test_bad_input_is_refused_in_one_line():
    acc = FieldAccumulator((2, 2))
    for call in (
        lambda: acc.skewness_flatness("w"),
        lambda: acc.central_moments("uv"),
        lambda: acc.noise_sigma4("x"),
        lambda: moments.skewness_flatness([np.ones(3)] * 3),
        lambda: _rspiv.moments_add(
            np.zeros((6, 4)), np.zeros(3), np.zeros(4, np.int64), np.zeros(4)
        ),
    ):
        with pytest.raises(rspiv.InvalidInputError) as e:
            call()
        assert "\n" not in str(e.value)
