"""A vector field sampled between its nodes (:func:`rspiv.vector_sampling.sample_at`): Keys'
cubic where the 4 x 4 nodes about a point are valid, bilinear from four valid nodes elsewhere,
the node itself on a node, NaN without four valid neighbours."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from rspiv.vector_sampling import sample_at


def _field(fun, valid=None):
    x, y = np.meshgrid(np.arange(12) * 16.0 + 7.5, np.arange(9) * 8.0 + 3.5)
    u = fun(x, y)
    ok = np.ones(u.shape, bool) if valid is None else valid
    return SimpleNamespace(x=x, y=y, u=u, v=np.zeros_like(u), valid=ok)


def _points(rng, n=400):
    # inside the nodes' span, two steps from the edges (where the cubic has its 16 nodes)
    return rng.uniform(7.5 + 32, 7.5 + 16 * 9, n), rng.uniform(3.5 + 16, 3.5 + 8 * 6, n)


def test_cubic_reproduces_quadratics_and_bilinear_does_not():
    f = _field(lambda x, y: 0.002 * x * x - 0.01 * x * y + 0.03 * y * y + x - 2 * y + 3)
    xs, ys = _points(np.random.default_rng(0))
    want = 0.002 * xs * xs - 0.01 * xs * ys + 0.03 * ys * ys + xs - 2 * ys + 3
    (cub,) = sample_at(f, xs, ys, [f.u])
    (bil,) = sample_at(f, xs, ys, [f.u], method="bilinear")
    np.testing.assert_allclose(cub, want, atol=1e-9)  # Keys' kernel is exact to order 2
    assert np.max(np.abs(bil - want)) > 0.1  # bilinear misses the curvature (0.13 + 0.48)
    # on a node: the node's value, by either method
    (on,) = sample_at(f, f.x[3:5, 4], f.y[3:5, 4], [f.u])
    np.testing.assert_array_equal(on, f.u[3:5, 4])


def test_waves_half_way_between_nodes_keep_their_amplitude():
    """A wave sampled half-way between nodes: bilinear keeps ``cos(w / 2)`` of its amplitude,
    Keys' cubic ``1.125 cos(w / 2) - 0.125 cos(3 w / 2)`` (w radians per grid step): 71 % and
    88 % for a wave four steps long, 92 % and 99 % for eight steps."""
    for steps, b_want, c_want in ((4, 0.7071, 0.8839), (8, 0.9239, 0.9915)):
        w = 2 * np.pi / steps
        f = _field(lambda x, y, w=w: np.cos(w * (x - 7.5) / 16.0))
        xs = f.x[4, 2:-3] + 8.0
        ys = np.full(xs.shape, f.y[4, 0])
        wave = np.cos(w * (xs - 7.5) / 16.0)
        (cub,) = sample_at(f, xs, ys, [f.u])
        (bil,) = sample_at(f, xs, ys, [f.u], method="bilinear")
        gain_b, gain_c = np.cos(w / 2), 1.125 * np.cos(w / 2) - 0.125 * np.cos(1.5 * w)
        np.testing.assert_allclose(bil, gain_b * wave, atol=1e-12)
        np.testing.assert_allclose(cub, gain_c * wave, atol=1e-12)
        assert (gain_b, gain_c) == pytest.approx((b_want, c_want), abs=1e-4)


def test_invalid_nodes_fall_back_to_bilinear_then_nan():
    valid = np.ones((9, 12), bool)
    valid[4, 6] = False
    f = _field(lambda x, y: 0.002 * x * x + y, valid)
    f.u[4, 6] = 1e6  # what a tool leaves in a rejected vector must never leak
    # next to the invalid node (its 4 x 4 holds it) but with four valid neighbours: bilinear
    x0, y0 = f.x[2, 4] + 4.0, f.y[2, 4] + 2.0
    (got,) = sample_at(f, np.array([x0]), np.array([y0]), [f.u])
    (bil,) = sample_at(f, np.array([x0]), np.array([y0]), [f.u], method="bilinear")
    assert got[0] == bil[0] and abs(got[0]) < 1e3
    # a point among the invalid node's four neighbours: NaN
    (gone,) = sample_at(f, np.array([f.x[4, 6] - 4.0]), np.array([f.y[4, 6] + 2.0]), [f.u])
    assert np.isnan(gone[0])
    # beyond the grid: NaN; at its last cells (no 4 x 4): bilinear
    (out,) = sample_at(f, np.array([f.x[0, -1] + 1.0, f.x[0, -1] - 4.0]),
                       np.array([f.y[3, 0], f.y[3, 0]]), [f.u])  # fmt: skip
    assert np.isnan(out[0]) and np.isfinite(out[1])
    with pytest.raises(ValueError, match="cubic or bilinear"):
        sample_at(f, np.array([x0]), np.array([y0]), [f.u], method="nearest")
