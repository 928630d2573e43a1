"""Snapshot POD (rspiv.pod) against exact answers: fields built from known orthonormal modes
and coefficients are decomposed back into them; gappy fields equal a direct SVD of the
zero-filled fluctuations; blocks of rows equal one block; North's rule and its flags."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv import InvalidInputError, pod
from rspiv.campaign.pod import select_snapshots
from rspiv.pod import PodBuilder

NY, NX = 12, 17


def _built(n=30, energies=(5.0, 2.0, 1.0, 0.3), seed=1):
    """``n`` snapshots of a mean plus ``len(energies)`` orthonormal modes whose coefficients
    are orthogonal, of zero mean and mean square ``energies`` exactly."""
    rng = np.random.default_rng(seed)
    lam = np.asarray(energies)
    q, _ = np.linalg.qr(rng.standard_normal((2 * NY * NX, lam.size)))
    c = rng.standard_normal((n, lam.size))
    c -= c.mean(0)
    c, _ = np.linalg.qr(c)
    c *= np.sqrt(n * lam)
    x = c @ q.T
    mu, mv = rng.standard_normal((2, NY, NX))
    u = x[:, : NY * NX].reshape(n, NY, NX) + mu
    v = x[:, NY * NX :].reshape(n, NY, NX) + mv
    return u, v, q, c, lam, (mu, mv)


def _flat(r):
    return np.concatenate([r.modes_u.reshape(r.n_modes, -1), r.modes_v.reshape(r.n_modes, -1)], 1)


def test_known_modes_and_coefficients_are_recovered():
    u, v, q, c, lam, (mu, mv) = _built()
    r = pod(u, v, n_modes=10)
    assert r.n_modes == 4  # the snapshots span 4 modes: the rest are dropped
    np.testing.assert_allclose(r.energy, lam, rtol=1e-12)
    assert r.total == pytest.approx(lam.sum(), rel=1e-12)
    np.testing.assert_allclose(r.cumulative[-1], 1.0, rtol=1e-12)
    phi = _flat(r)
    np.testing.assert_allclose(phi @ phi.T, np.eye(4), atol=1e-12)
    sign = np.sign(np.sum(phi * q.T, axis=1))
    np.testing.assert_allclose(phi, q.T * sign[:, None], atol=1e-12)
    np.testing.assert_allclose(r.coefficients, c * sign[None, :], atol=1e-10)
    np.testing.assert_allclose((r.coefficients**2).mean(0), lam, rtol=1e-12)
    # the sign convention: each mode's largest value is positive
    assert np.all(phi[np.arange(4), np.argmax(np.abs(phi), 1)] > 0)
    ru, rv = r.reconstruct(7)
    np.testing.assert_allclose(ru, u[7] - mu, atol=1e-12)
    np.testing.assert_allclose(rv, v[7] - mv, atol=1e-12)
    ru2, _ = r.reconstruct(7, modes=2)
    exact2 = (c[7, :2] @ q[: NY * NX, :2].T).reshape(NY, NX)
    np.testing.assert_allclose(ru2, exact2, atol=1e-12)
    with pytest.raises(InvalidInputError, match="modes must be 1 to 4"):
        r.reconstruct(0, modes=5)


@pytest.mark.parametrize("hole", [False, True])  # whole rows (read as a run) or gathered
def test_gappy_fields_equal_an_svd_of_the_filled_fluctuations(hole):
    rng = np.random.default_rng(3)
    n = 25
    u = rng.standard_normal((n, NY, NX)) + 3.0
    v = 0.5 * rng.standard_normal((n, NY, NX)) - 1.0
    valid = rng.random((n, NY, NX)) > 0.1
    u[~valid & (rng.random(u.shape) > 0.5)] = np.nan  # some rejected vectors are NaN as well
    domain = np.ones((NY, NX), bool)
    domain[:2] = False  # two rows left out
    domain[5, 3:6] = not hole
    mean_u, mean_v = rng.standard_normal((2, NY, NX))
    r = pod(u, v, valid, n_modes=6, mean_u=mean_u, mean_v=mean_v, domain=domain,
            pair_ids=np.arange(100, 100 + n))  # fmt: skip
    ok = valid & np.isfinite(u)
    du = np.where(ok, u - mean_u, 0.0)[:, domain]
    dv = np.where(ok, v - mean_v, 0.0)[:, domain]
    x = np.concatenate([du, dv], 1)
    s = np.linalg.svd(x, compute_uv=False)
    np.testing.assert_allclose(r.energy, s[:6] ** 2 / n, rtol=1e-10)
    assert r.total == pytest.approx((x**2).sum() / n, rel=1e-12)
    assert r.gaps == pytest.approx(1 - ok[:, domain].mean(), rel=1e-12)
    assert np.all(np.isnan(r.modes_u[:, ~domain])) and np.all(np.isfinite(r.modes_u[:, domain]))
    np.testing.assert_array_equal(r.pair_ids, np.arange(100, 125))
    # the projection of each snapshot on the modes is its coefficient
    proj = x @ _flat(r)[:, np.concatenate([domain.ravel(), domain.ravel()])].T
    np.testing.assert_allclose(proj, r.coefficients, atol=1e-10)


@pytest.mark.parametrize("rows_per_block", [1, 5, 12])
def test_blocks_of_rows_equal_one_block(rows_per_block):
    u, v, *_ = _built(n=12, energies=(3.0, 2.0, 1.5, 1.0, 0.5, 0.2))
    ref = pod(u, v, n_modes=5)
    mean_u, mean_v = u.mean(0), v.mean(0)
    b = PodBuilder(mean_u, mean_v, np.ones((NY, NX), bool), 12)
    for r0 in range(0, NY, rows_per_block):
        blk = slice(r0, min(r0 + rows_per_block, NY))
        b.add_rows(blk, u[:, blk], v[:, blk])
    b.solve(5)
    for i in range(12):
        b.add_snapshot(i, u[i], v[i])
    r = b.result()
    np.testing.assert_allclose(r.energy, ref.energy, rtol=1e-12)
    np.testing.assert_allclose(r.modes_u, ref.modes_u, atol=1e-12)
    np.testing.assert_allclose(r.coefficients, ref.coefficients, atol=1e-10)


def test_north_rule_flags_modes_that_are_not_separated():
    n = 30
    u, v, *_ = _built(n=n, energies=(5.0, 4.9, 1.0, 0.5))
    r = pod(u, v)
    np.testing.assert_allclose(r.north, r.energy * np.sqrt(2 / n), rtol=1e-12)
    np.testing.assert_array_equal(r.separated, [False, False, True, True])
    # fewer independent snapshots: wider errors, mode 3 joins
    r4 = pod(u, v, n_eff=4)
    np.testing.assert_allclose(r4.north, r4.energy * np.sqrt(0.5), rtol=1e-12)
    np.testing.assert_array_equal(r4.separated, [False, False, False, True])
    # the last mode kept is judged against the first one not kept
    u, v, *_ = _built(n=n, energies=(5.0, 2.0, 1.95, 0.5))
    r2 = pod(u, v, n_modes=2)
    assert r2.next_energy == pytest.approx(1.95, rel=1e-12)
    np.testing.assert_array_equal(r2.separated, [True, False])
    np.testing.assert_array_equal(pod(u, v).separated, [True, False, False, True])


def test_the_flow_frame_signs_turn_the_components():
    u, v, *_ = _built(n=10)
    ref = pod(u, v)
    b = PodBuilder(u.mean(0), v.mean(0), np.ones((NY, NX), bool), 10, sign_x=1.0, sign_y=-1.0)
    b.add_rows(slice(0, NY), u, v)
    b.solve(10)
    for i in range(10):
        b.add_snapshot(i, u[i], v[i])
    r = b.result()
    np.testing.assert_allclose(r.energy, ref.energy, rtol=1e-12)
    np.testing.assert_allclose(r.modes_u, ref.modes_u, atol=1e-12)
    np.testing.assert_allclose(r.modes_v, -ref.modes_v, atol=1e-12)


def test_bad_input_is_refused_in_one_line():
    u, v, *_ = _built(n=6)
    ones = np.ones((NY, NX), bool)
    cases = [
        (lambda: pod(u[0], v[0]), "must be \\(n, ny, nx\\)"),
        (lambda: pod(u, v[:, :3]), "must be \\(n, ny, nx\\)"),
        (lambda: pod(u[:1], v[:1]), "at least 2 snapshots"),
        (lambda: pod(u, v, np.ones((6, 2, 2), bool)), "valid must be"),
        (lambda: pod(np.ones_like(u), np.ones_like(v)), "no fluctuation"),
        (lambda: pod(u, v, domain=~ones), "no vector with a finite mean"),
        (lambda: pod(u, v, pair_ids=[1, 2]), "pair_ids must hold 6"),
        (lambda: pod(u, v, n_modes=0), "n_modes must be >= 1"),
    ]
    for call, msg in cases:
        with pytest.raises(InvalidInputError, match=msg) as exc:
            call()
        assert "\n" not in str(exc.value)
    b = PodBuilder(u.mean(0), v.mean(0), ones, 6)
    b.add_rows(slice(0, 4), u[:, :4], v[:, :4])
    with pytest.raises(InvalidInputError, match="already added"):
        b.add_rows(slice(2, 6), u[:, 2:6], v[:, 2:6])
    with pytest.raises(InvalidInputError, match="must hold all 6 snapshots"):
        b.add_rows(slice(4, 6), u[:3, 4:6], v[:3, 4:6])
    with pytest.raises(InvalidInputError, match="rows of the domain were not added"):
        b.solve(3)
    with pytest.raises(InvalidInputError, match="before solve"):
        b.add_snapshot(0, u[0], v[0])
    b.add_rows(slice(4, NY), u[:, 4:], v[:, 4:])
    b.solve(3)
    with pytest.raises(InvalidInputError, match="after solve"):
        b.add_rows(slice(0, 1), u[:, :1], v[:, :1])
    b.add_snapshot(0, u[0], v[0])
    with pytest.raises(InvalidInputError, match="already added to the modes"):
        b.add_snapshot(0, u[0], v[0])
    with pytest.raises(InvalidInputError, match="1 of 6"):
        b.result()


def test_snapshots_are_spread_evenly():
    assert select_snapshots([3, 1, 2], 5) == [1, 2, 3]
    ids = list(range(1000))
    got = select_snapshots(ids[::-1], 10)
    assert got[0] == 0 and got[-1] == 999 and len(got) == 10
    assert np.ptp(np.diff(got)) <= 1
