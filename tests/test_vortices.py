"""Vortex cores (rspiv.vortices) against exact answers: Lamb-Oseen vortices planted in a field
are found one by one, with their sign, centre, the area inside the threshold and the
circulation there from the closed form; cores smaller than ``min_vectors`` are dropped; the
counts by row and kind add up and merge."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv import InvalidInputError
from rspiv.derivatives import gradients, swirl_from_gradients
from rspiv.vortices import VortexAccumulator, find_vortices, min_core_vectors
from scipy.optimize import brentq

H = 2.0  # grid step, px
NY, NX = 90, 140


def _lamb_oseen(centres):
    """u, v (pixel frame: v down) of Lamb-Oseen vortices ``(x0, y0, gamma, rc)`` (px, gamma > 0
    counter-clockwise on the image) on a uniform flow of 3 px to the right."""
    yy, xx = np.mgrid[0:NY, 0:NX] * H
    u = np.full((NY, NX), 3.0)
    v = np.zeros((NY, NX))
    for x0, y0, gamma, rc in centres:
        dx, dy_up = xx - x0, -(yy - y0)
        r = np.hypot(dx, dy_up) + 1e-300
        ut = gamma / (2 * np.pi * r) * (1 - np.exp(-(r**2) / rc**2))
        u += -ut * dy_up / r
        v -= ut * dx / r
    return u, v


def _swirl(r, gamma, rc):
    """lambda_ci of a Lamb-Oseen vortex at radius r: sqrt(u_theta / r * du_theta / dr)."""
    e = np.exp(-(r**2) / rc**2)
    omega = gamma / (2 * np.pi * r**2) * (1 - e)
    dut = gamma / (2 * np.pi * r**2) * (-(1 - e) + 2 * r**2 / rc**2 * e)
    return np.sqrt(max(omega * dut, 0.0))


def _edge(gamma, rc, thr):
    """The radius where the swirl falls to ``thr``: inside 1.1209 rc, where du_theta/dr = 0
    (e^x = 1 + 2x at x = r^2 / rc^2 = 1.2564) and the swirl ends."""
    return brentq(lambda r: _swirl(r, gamma, rc) - thr, 1e-3 * rc, 1.1209 * rc)


def test_planted_lamb_oseen_vortices_are_found_with_their_closed_form():
    centres = [(60.0, 50.0, 300.0, 12.0), (180.0, 120.0, -250.0, 14.0), (220.0, 40.0, 200.0, 10)]
    u, v = _lamb_oseen(centres)
    g = gradients(u, v, H, H, "richardson")
    swirl, omega = swirl_from_gradients(g, signed=True), g["dvdx"] - g["dudy"]
    thr = 0.01
    cores = find_vortices(swirl, omega, thr, H, H, min_vectors=3)
    assert cores["x"].size == 3
    order = np.lexsort((cores["x"], -cores["sign"]))  # positive first, then by x
    expect = sorted(centres, key=lambda c: (-np.sign(c[2]), c[0]))
    for k, (x0, y0, gamma, rc) in zip(order, expect, strict=True):
        assert cores["sign"][k] == np.sign(gamma)
        assert abs(cores["x"][k] - x0) < 0.02 * H and abs(cores["y"][k] - y0) < 0.02 * H
        peak = abs(gamma) / (2 * np.pi * rc**2)
        assert cores["peak"][k] == pytest.approx(peak, rel=0.02)
        # the radius where the swirl falls to the threshold, and the circulation inside it
        radius = _edge(abs(gamma), rc, thr)
        assert cores["radius"][k] == pytest.approx(radius, rel=0.05)
        inside = gamma * (1 - np.exp(-(radius**2) / rc**2))
        assert cores["circulation"][k] == pytest.approx(inside, rel=0.06)
        assert cores["vectors"][k] == pytest.approx(np.pi * radius**2 / H**2, rel=0.1)


def test_small_cores_and_weak_swirl_are_left_out():
    # a vortex of about one grid step's core: 5 vectors (the stencil's reach), dropped
    u, v = _lamb_oseen([(60.0, 50.0, 300.0, 12.0), (200.0, 100.0, 40.0, 1.2)])
    g = gradients(u, v, H, H, "central")
    swirl, omega = swirl_from_gradients(g, signed=True), g["dvdx"] - g["dudy"]
    assert find_vortices(swirl, omega, 0.01, H, H, min_vectors=1)["x"].size == 2
    assert find_vortices(swirl, omega, 0.01, H, H, min_vectors=6)["x"].size == 1
    # a threshold per row: rows above 80 px cannot hold a core
    thr = np.where(np.arange(NY) * H < 80, 0.01, np.inf)[:, None]
    got = find_vortices(swirl, omega, thr, H, H, min_vectors=1)
    assert got["x"].size == 1 and got["y"][0] == pytest.approx(50.0, abs=0.05)
    # NaN vectors are never part of a core; shear alone does not swirl
    swirl2 = swirl.copy()
    swirl2[:, :] = np.nan
    assert find_vortices(swirl2, omega, 0.01, H, H)["x"].size == 0
    s = gradients(np.tile(0.1 * np.arange(NY)[:, None], (1, NX)), np.zeros((NY, NX)), H, H)
    lam = swirl_from_gradients(s)
    assert np.all(lam[np.isfinite(lam)] == 0) and np.isfinite(lam).sum() > 0.9 * lam.size


def test_counts_by_row_and_kind_add_and_merge():
    cores = {
        "sign": np.array([-1.0, -1.0, 1.0, -1.0]),
        "radius": np.array([2.0, 4.0, 3.0, 5.0]),
        "circulation": np.array([-1.0, -2.0, 0.5, -3.0]),
    }
    a = VortexAccumulator(5, prograde=-1.0)
    a.add(cores, np.array([1, 1, 3, 7]))  # the last row is outside the grid: not counted
    np.testing.assert_array_equal(a.count, [[0, 2, 0, 0, 0], [0, 0, 0, 1, 0]])
    np.testing.assert_allclose(a.radius_sum[0, 1], 6.0)
    np.testing.assert_allclose(a.circulation_sum[1, 3], 0.5)
    b = a.empty_copy()
    b.add({k: x[:1] for k, x in cores.items()}, np.array([4]))
    a.merge(b)
    assert a.count[0, 4] == 1 and a.n_fields == 2
    with pytest.raises(InvalidInputError, match="other grids"):
        a.merge(VortexAccumulator(6, -1.0))
    with pytest.raises(InvalidInputError, match="prograde must be"):
        VortexAccumulator(5, 0.0)


def test_bad_input_is_refused_in_one_line():
    z = np.zeros((4, 5))
    for call, msg in (
        (lambda: find_vortices(z, z[:3], 1.0, 1, 1), "must be 2-D alike"),
        (lambda: find_vortices(z, z, np.ones(3), 1, 1), "a threshold of shape"),
        (lambda: find_vortices(z, z, 0.0, 1, 1), "must be > 0"),
        (lambda: find_vortices(z, z, 1.0, 1, 1, min_vectors=0), "min_vectors"),
        (lambda: find_vortices(z, z, 1.0, 1, 1, x=np.arange(3)), "x and y"),
    ):
        with pytest.raises(InvalidInputError, match=msg) as exc:
            call()
        assert "\n" not in str(exc.value)


def test_the_smallest_core_is_a_disc_as_wide_as_the_window():
    assert min_core_vectors(32, 16, 4) == 13  # pi 16^2 / 64 = 12.6
    assert min_core_vectors(16, 8, 8) == 4  # pi 8^2 / 64 = 3.14
    assert min_core_vectors(1, 16, 4) == 1
    with pytest.raises(InvalidInputError, match="must be > 0"):
        min_core_vectors(0, 16, 4)
