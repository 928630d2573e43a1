"""Synthetic boundary-layer pairs with the wall reflection (rspiv.synth.tbl)."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.reference import load_dns
from rspiv.synth import TBLFlow, tbl_pair, tbl_scene


@pytest.fixture(scope="module")
def flow():
    return TBLFlow()


def test_composite_profile_follows_the_dns_in_inner_and_outer_scaling(flow):
    p = load_dns(4060)
    # Inner layer (y < 0.07 delta99): the DNS at the same y+.
    yp = np.array([0.5, 2.0, 5.0, 15.0, 40.0, 100.0, 160.0])
    np.testing.assert_allclose(flow.u_plus(yp), np.interp(yp, p.y_plus, p.u_plus), rtol=1e-12)
    uu, vv, uv = flow.stresses_plus(yp)
    np.testing.assert_allclose(uu, np.interp(yp, p.y_plus, p.uu_plus), rtol=1e-12)
    np.testing.assert_allclose(uv, np.interp(yp, p.y_plus, p.uv_plus), rtol=1e-12)
    # Outer layer (y > 0.2 delta99): the DNS defect at the same y / delta99.
    eta = np.array([0.25, 0.5, 0.8, 1.0, 1.3])
    defect = flow.u_inf_plus - flow.u_plus(eta * flow.re_tau)
    np.testing.assert_allclose(defect, p.u_inf_plus - np.interp(eta, p.y_delta99, p.u_plus),
                               atol=1e-12)  # fmt: skip
    uu, vv, uv = flow.stresses_plus(eta * flow.re_tau)
    np.testing.assert_allclose(vv, np.interp(eta, p.y_delta99, p.vv_plus), rtol=1e-12)
    # The free stream grows by the log law between the Reynolds numbers (kappa = 0.41).
    expected = p.u_inf_plus + np.log(flow.re_tau / p.re_tau) / 0.41
    assert flow.u_inf_plus == pytest.approx(expected, abs=0.3)
    # The paper's flow: u_tau = 0.348 m/s, l_v ~ 43 um.
    assert flow.u_tau == pytest.approx(0.348, rel=0.02)
    assert flow.viscous_length_mm * 1e3 == pytest.approx(43.2, abs=0.1)
    # Monotone mean profile, positive semi-definite stress tensor.
    y = np.geomspace(0.1, 3 * flow.re_tau, 500)
    assert np.all(np.diff(flow.u_plus(y)) >= -1e-9)
    uu, vv, uv = flow.stresses_plus(y)
    assert np.all(uv * uv <= uu * vv + 1e-15)


def test_scene_geometry_and_mean_flow():
    t = tbl_scene(scale=0.1, seed=0, turbulence=False, wall_angle_deg=0.5)
    x = np.array([0.0, 200.0, 700.0])
    yw = t.wall_y(x)
    np.testing.assert_allclose(t.wall_distance(x, yw), 0.0, atol=1e-9)
    # Above the wall (smaller y) is the flow.
    assert np.all(t.wall_distance(x, yw - 3.0) > 0)
    mx, my = t.mirror(x, yw - 3.0)
    np.testing.assert_allclose(t.wall_distance(mx, my), -t.wall_distance(x, yw - 3.0))
    bx, by = t.mirror(mx, my)
    np.testing.assert_allclose(np.c_[bx, by], np.c_[x, yw - 3.0], atol=1e-9)
    # Mean flow along the wall; free stream = u_inf_px; zero below the wall.
    d = 250.0 * t.viscous_length_px
    u, v = t.displacement(x, yw - d / np.cos(np.deg2rad(0.5)))
    speed = np.hypot(u, v)
    np.testing.assert_allclose(speed, t.mean_displacement_px(d), rtol=1e-9)
    np.testing.assert_allclose(v / u, np.tan(np.deg2rad(0.5)), rtol=1e-9)
    far = 3.0 * t.flow.re_tau * t.viscous_length_px
    assert t.mean_displacement_px(far) == pytest.approx(t.u_inf_px, rel=1e-3)
    u, v = t.displacement(x, yw + 2.0)
    assert np.all(u == 0) and np.all(v == 0)
    assert t.viscous_length_px == pytest.approx(43.17e-3 * 34.538 * 0.1, rel=1e-3)
    assert t.dt == pytest.approx(25.0 / (9.64e3 * 34.538 * 0.1))


def test_fluctuations_have_the_dns_reynolds_stresses():
    # Sample the frozen fields of several scenes along rows at fixed wall distances.
    dists_plus = np.array([30.0, 150.0, 800.0])
    acc = []
    for seed in range(12):
        t = tbl_scene(scale=1.0, seed=seed, wall_angle_deg=0.0)
        x = np.arange(0.0, t.shape[1], 8.0)
        k = t.u_inf_px / t.flow.u_inf_plus
        rows = []
        for dp in dists_plus:
            y = np.full_like(x, t.wall_y0_px - dp * t.viscous_length_px)
            u, v = t.displacement(x, y)
            um = t.mean_displacement_px(dp * t.viscous_length_px)
            # v is positive downward in px; into the flow (up) is -v.
            rows.append(np.stack([(u - um) / k, -v / k]))
        acc.append(np.stack(rows))
    a = np.concatenate(acc, axis=-1)  # (ndist, 2, nsamples)
    uu, vv, uv = TBLFlow().stresses_plus(dists_plus)
    # ~12 x 92 correlation lengths per row: ~1000 independent samples, 4.5 % standard error.
    np.testing.assert_allclose(np.var(a[:, 0], axis=1), uu, rtol=0.15)
    np.testing.assert_allclose(np.var(a[:, 1], axis=1), vv, rtol=0.15)
    cov = np.mean(a[:, 0] * a[:, 1], axis=1) - a[:, 0].mean(1) * a[:, 1].mean(1)
    np.testing.assert_allclose(cov, uv, rtol=0.2)


def test_rendered_pair_density_and_reflection():
    a, b, t = tbl_pair(scale=0.1, seed=2, lens=None, noise=0.0)
    h, w = t.shape
    assert a.shape == b.shape == (h, w) and a.dtype == np.uint16
    yw = int(t.wall_y0_px)
    area = (t.extent[1] - t.extent[0]) * (t.wall_y0_px - t.extent[2])
    assert t.n_particles / area == pytest.approx(0.03, rel=0.05)
    # The strip below the wall holds the reflection: fainter, but not empty.
    above = a[yw - 30 : yw - 5].mean()
    below = a[yw + 5 : yw + 30].mean()
    assert 0.3 * above < below < 0.7 * above
    assert t.n_mirrors > 0
    # No reflection: the strip below the wall is black.
    a0, _, _ = tbl_pair(scale=0.1, seed=2, lens=None, noise=0.0, reflection=0.0)
    assert a0[yw + 5 :].max() == 0


def test_flow_below_the_wall():
    a, b, t = tbl_pair(scale=0.1, seed=4, lens=None, noise=0.0, flow_side="below",
                       reflection=0.0)  # fmt: skip
    yw = int(np.ceil(t.wall_y0_px))
    assert a[: yw - 4].max() == 0 and a[yw + 5 :].max() > 0
    u, v = t.displacement(np.array([100.0]), np.array([t.wall_y0_px + 50.0]))
    assert u[0] > 0


def test_piv_of_the_pair_recovers_the_flow_and_the_wall():
    from rspiv.piv import piv
    from rspiv.wall import find_wall

    fields, truths = [], []
    for seed in (1, 2, 3):
        # Half scale (viscous length 0.7 px) and 75 % final overlap (a vector row every 2 px):
        # at scale 0.2 (0.3 px) three pairs leave station errors up to 0.6-0.8 px, the
        # row-locking and reflection-brightness effects of the rspiv.wall docstring
        a, b, t = tbl_pair(scale=0.5, seed=seed, lens=None, wall_angle_deg=0.3)
        fields.append(piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=[0.5, 0.5, 0.75]))
        truths.append(t)
    f, t = fields[0], truths[0]
    # Away from the wall the measured field is the exact one.
    d = t.wall_distance(f.x, f.y)
    sel = f.valid & (d > 40) & (f.x > 40) & (f.x < t.shape[1] - 40) & (f.y > 40)
    ue, ve = t.displacement(f.x[sel], f.y[sel])
    assert np.sqrt(np.mean((f.u[sel] - ue) ** 2)) < 0.3
    assert np.sqrt(np.mean((f.v[sel] - ve) ** 2)) < 0.3
    # The wall from the reflection symmetry of the mean of three pairs. The 32 x 8 windows that
    # straddle the wall see the real particles brighter than their reflections (intensity 0.5),
    # which pulls the symmetry centre ~0.2 px into the reflection; single stations scatter by a
    # few tenths of a pixel on so few pairs.
    w = find_wall(fields, band=(t.wall_y0_px - 150, t.wall_y0_px + 100), stations=8)
    err = w.position_px - t.wall_y(w.x_px)
    assert np.all(np.isfinite(err))
    assert np.max(np.abs(err)) < 0.6
    assert abs(np.mean(err)) < 0.3
    assert abs(w.angle_deg - 0.3) < 0.02


def test_invalid_arguments():
    with pytest.raises(InvalidInputError):
        tbl_pair(scale=0.001)
    with pytest.raises(InvalidInputError):
        tbl_pair(scale=0.1, flow_side="left")
    with pytest.raises(InvalidInputError):
        tbl_pair(scale=0.1, density=-1)
    with pytest.raises(InvalidInputError):
        TBLFlow(re_tau=10)


def test_planted_vortices_are_lamb_oseen_and_prograde():
    """``vortices=n``: n Lamb-Oseen vortices on the fluctuations, 0.15-0.6 delta_99 from the
    wall, turning with the mean shear (clockwise on the screen above the wall, the other way
    below), each adding exactly its closed form to the displacement; none by default, which
    leaves the scene as it was (the same draws)."""
    from rspiv.vortices import oseen_velocity

    plain = tbl_scene(scale=0.1, seed=7)
    assert plain.vortices.shape == (0, 4)
    for side, sense in (("above", -1.0), ("below", 1.0)):
        sc = tbl_scene(scale=0.1, seed=7, flow_side=side, vortices=4, vortex_radius_px=10.0,
                       vortex_swirl_px=2.0)  # fmt: skip
        assert sc.vortices.shape == (4, 4) and np.all(sc.vortices[:, 3] == 10.0)
        assert np.all(np.sign(sc.vortices[:, 2]) == sense)
        delta = sc.flow.delta99_mm * sc.magnification
        d = sc.wall_distance(sc.vortices[:, 0], sc.vortices[:, 1])
        assert np.all((d >= 0.15 * delta) & (d <= 0.6 * delta))
        # peak azimuthal displacement 2 px at 1.121 r_c
        u, v = oseen_velocity(1.12091 * 10.0, 0.0, 0.0, 0.0, sc.vortices[0, 2], 10.0)
        assert abs(v) == pytest.approx(2.0, rel=1e-4) and abs(u) < 1e-12
        # the displacement is the plain scene's plus the vortices' (pixel frame: v down)
        ref = tbl_scene(scale=0.1, seed=7, flow_side=side)
        x = sc.vortices[:, 0][:, None] + np.linspace(-30, 30, 7)[None, :]
        y = sc.vortices[:, 1][:, None] + np.linspace(-20, 20, 7)[None, :]
        du, dv = np.subtract(sc.displacement(x, y), ref.displacement(x, y))
        eu, ev = np.zeros_like(x), np.zeros_like(x)
        for xc, yc, g, rc in sc.vortices:
            a, b = oseen_velocity(x, -y, xc, -yc, g, rc)
            eu, ev = eu + a, ev - b
        np.testing.assert_allclose(du, eu, atol=1e-12)
        np.testing.assert_allclose(dv, ev, atol=1e-12)
    with pytest.raises(InvalidInputError, match="vortices"):
        tbl_scene(scale=0.1, vortices=-1)
    with pytest.raises(InvalidInputError, match="vortices"):
        tbl_pair(scale=0.1, vortices=2, vortex_radius_px=0.0)
