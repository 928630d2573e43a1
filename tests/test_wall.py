"""Wall alignment from the mirror symmetry of the mean profile (rspiv.wall)."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.wall import Wall, find_wall, mirror_shift_positions


def _profile(d: np.ndarray) -> np.ndarray:
    """A TBL-like mean displacement (px) at |distance| d from the wall: linear sublayer, steep
    buffer, slow outer growth; mirrored about the wall by construction."""
    d = np.abs(d)
    return 18.0 * np.tanh(d / 5.0) + 6.0 * np.tanh(d / 40.0)


def _mirrored(y: np.ndarray, x: np.ndarray, wall: np.ndarray) -> np.ndarray:
    return _profile(y[:, None] - wall[None, :])


@pytest.mark.parametrize("dy", [1.0, 4.0])
def test_straight_tilted_wall_positions_and_angle(dy):
    x = np.arange(40) * 220.0 + 16.0
    y = np.arange(0.0, 240.0, dy) + 3.0
    angle = 0.04
    wall = 121.37 + x * np.tan(np.deg2rad(angle))
    w = find_wall(_mirrored(y, x, wall), y=y, x=x)
    assert isinstance(w, Wall)
    assert np.max(np.abs(w.position_px - wall)) < 0.05
    assert abs(w.angle_deg - angle) < 0.001
    assert w.rotation_deg == w.angle_deg  # see Wall.rotation_deg
    assert w.max_deviation_px == pytest.approx(np.ptp(wall), abs=0.05)
    assert w.straightness_px < 0.05
    assert np.all(w.peak_correlation > 0.99)
    np.testing.assert_allclose(w.line(x), wall, atol=0.05)


def test_parabolic_distortion_deviation_is_recovered():
    # The raw image: wall bent by the lens (parabola, ~9 px) plus the 0.04 degree tilt.
    x = np.linspace(16.0, 8848.0, 60)
    y = np.arange(4800.0, 5200.0, 4.0)
    xc = 4432.0
    bend = 9.0 * ((x - xc) / xc) ** 2
    wall = 5000.3 + x * np.tan(np.deg2rad(0.04)) + bend
    w = find_wall(_mirrored(y, x, wall), y=y, x=x)
    assert np.max(np.abs(w.position_px - wall)) < 0.05
    assert w.max_deviation_px == pytest.approx(np.ptp(wall), abs=0.05)
    # The line through a symmetric parabola keeps the tilt.
    slope = np.polyfit(x, wall, 1)[0]
    assert abs(w.angle_deg - np.degrees(np.arctan(slope))) < 0.001
    resid = wall - np.polyval(np.polyfit(x, wall, 1), x)
    assert w.straightness_px == pytest.approx(np.max(np.abs(resid)), abs=0.05)


def test_band_restricts_rows_and_noise_is_tolerated(rng):
    x = np.arange(30) * 100.0
    y = np.arange(0.0, 400.0, 2.0)
    wall = 300.6 - x * np.tan(np.deg2rad(0.5))
    u = _mirrored(y, x, wall)
    # Unrelated structure far from the wall (outside the band) must not matter.
    u[:40] += 50.0 * np.sin(y[:40, None] / 3.0)
    stack = u[None] + 0.05 * rng.standard_normal((50, *u.shape))
    w = find_wall(stack, y=y, x=x, band=(220.0, 380.0))
    assert np.max(np.abs(w.position_px - wall)) < 0.05
    assert abs(w.angle_deg + 0.5) < 0.002


def test_field_input_with_invalid_vectors_and_stations():
    class Field:
        pass

    x = np.arange(64) * 16.0 + 16
    y = np.arange(0.0, 300.0, 4.0) + 2
    wall = 150.25 + 0.001 * x
    f = Field()
    f.x, f.y = np.meshgrid(x, y)
    f.u = _mirrored(y, x, wall)
    f.valid = np.ones(f.u.shape, bool)
    f.valid[10, 5] = False
    f.u[10, 5] = 1e6  # an outlier flagged invalid must be ignored
    w = find_wall(f, stations=8)
    assert w.x_px.shape == (8,)
    true = 150.25 + 0.001 * w.x_px
    assert np.max(np.abs(w.position_px - true)) < 0.05
    # A sequence of fields averages them.
    w2 = find_wall([f, f])
    assert np.max(np.abs(w2.position_px - (150.25 + 0.001 * x))) < 0.05


def test_outlier_station_is_rejected():
    x = np.arange(20) * 50.0
    y = np.arange(0.0, 200.0)
    wall = 100.0 + 0.002 * x
    u = _mirrored(y, x, wall)
    u[:, 7] = _profile(y - 130.0)  # one station sees a different "wall"
    w = find_wall(u, y=y, x=x)
    assert np.isnan(w.position_px[7])
    assert abs(w.slope - 0.002) < 1e-5
    w_all = find_wall(u, y=y, x=x, reject=None)
    assert w_all.position_px[7] == pytest.approx(130.0, abs=0.05)


def test_no_wall_is_refused_and_stations_without_one_left_out(rng):
    """Profiles that do not mirror (a boundary layer without its reflection, a linear shear,
    noise) are no wall: find_wall refuses in one line. Stations whose profile does not match
    its mirror image are left out (NaN) when at least half the stations see the wall."""
    x = np.arange(20) * 50.0
    y = np.arange(0.0, 200.0, 2.0)
    one_sided = np.repeat((18.0 * np.tanh(y / 5.0) + 6.0 * np.tanh(y / 40.0))[:, None], 20, 1)
    shear = np.repeat((3.0 + 0.05 * y)[:, None], 20, 1)
    noise = rng.standard_normal((len(y), 20))
    for u in (one_sided, shear, noise):
        with pytest.raises(InvalidInputError, match="no wall reflection seen") as e:
            find_wall(u, y=y, x=x, band=None)
        assert "\n" not in str(e.value)
    # the automatic band, centred on the slowest row, already finds too few rows beside it
    with pytest.raises(InvalidInputError, match="rows in the band"):
        find_wall(one_sided, y=y, x=x)
    wall = 100.3 + 0.002 * x
    u = _mirrored(y, x, wall)
    u[:, 3:9] = noise[:, 3:9]  # six stations of noise beside fourteen that see the wall
    w = find_wall(u, y=y, x=x, reject=None)
    assert np.all(np.isnan(w.position_px[3:9]))
    ok = np.r_[0:3, 9:20]
    assert np.max(np.abs(w.position_px[ok] - wall[ok])) < 0.05
    assert abs(w.slope - 0.002) < 1e-5
    u[:, 9:14] = noise[:, 9:14]  # eleven of twenty: fewer than half see it
    with pytest.raises(InvalidInputError, match=r"at [0-9]+ of 20 stations"):
        find_wall(u, y=y, x=x)


def test_mirror_shift_positions_index_units():
    n = 101
    idx = np.arange(n, dtype=float)
    centres = np.array([30.0, 50.5, 61.23, 70.77])
    prof = _profile(idx[:, None] - centres[None, :])
    pos, rho = mirror_shift_positions(prof)
    np.testing.assert_allclose(pos, centres, atol=0.02)
    assert np.all(rho > 0.99)


def test_invalid_inputs():
    with pytest.raises(InvalidInputError):
        find_wall(np.zeros((3, 4)))
    with pytest.raises(InvalidInputError):
        find_wall(np.zeros((10, 4)), y=np.r_[0:9, 20.0])
    with pytest.raises(InvalidInputError):
        find_wall(np.zeros(10))
    with pytest.raises(InvalidInputError):
        mirror_shift_positions(np.full((10, 2), np.nan))


def test_wall_figures_are_written(tmp_path):
    from rspiv.plots.wall import wall_profile, wall_shape

    x = np.arange(30) * 100.0
    y = np.arange(0.0, 200.0, 2.0)
    bent = 100.0 + 2e-6 * (x - 1500.0) ** 2
    w_raw = find_wall(_mirrored(y, x, bent), y=y, x=x)
    w_flat = find_wall(_mirrored(y, x, np.full_like(x, 100.0)), y=y, x=x)
    p = wall_shape({"distorted": w_raw, "corrected": w_flat}, tmp_path / "wall.png")
    assert p.stat().st_size > 10_000
    u = _mirrored(y, x, bent)[:, 3]
    q = wall_profile(u, y, w_raw.position_px[3], tmp_path / "profile.png")
    assert q.stat().st_size > 5_000


def test_find_wall_on_a_whole_47_mp_field():
    """``find_wall(field)`` with no band or stations on a whole full-sensor field: the boundary
    layer along the bottom edge, ~5,000 px of free stream above it (issue 16). The wall finder
    picks its band around the row of smallest mean |u| and averages the 553 columns into 32
    stations by itself."""
    import rspiv
    from rspiv.synth import tbl_pair

    a, b, t = tbl_pair(scale=1.0, seed=11, lens=None, wall_angle_deg=0.04)
    assert a.shape == (5288, 8864) and t.wall_y0_px > 4900  # ~5,000 px of free stream above
    f = rspiv.piv(a, b)
    w = rspiv.find_wall(f)
    assert w.flow_side == "above"
    assert len(w.x_px) == 32 and w.valid.sum() >= 28
    err = w.position_px - t.wall_y(w.x_px)
    ok = w.valid
    print(f"47 MP field: wall error max {np.max(np.abs(err[ok])):.3f} px, mean "
          f"{np.mean(err[ok]):+.3f} px, angle {w.angle_deg:+.5f} deg (true +0.04)")  # fmt: skip
    # One pair, 4 px vector rows: the station errors are the row-locking and reflection effects
    # of the module docstring (tenths of a pixel), far below the 3.5 px of the lens distortion.
    assert np.max(np.abs(err[ok])) < 0.6
    assert abs(np.mean(err[ok])) < 0.3
    assert abs(w.angle_deg - 0.04) < 0.01


@pytest.mark.parametrize("window", [0.0, 32.0])
def test_the_joint_fit_on_rows_16_px_apart(window):
    """Rows 16 px apart (another tool's 32 px windows at 50 % overlap): the synthetic layer's
    mirrored mean profile, at points or averaged over 32 px windows. The symmetric resampling
    alone errs by up to 1.2 px with the wall's place between rows (``fit="resample"``); the
    joint fit of one one-sided profile to both sides (the default) by 0.03 / 0.15 px."""
    from rspiv.synth.tbl import tbl_scene

    truth = tbl_scene(0.25, seed=0, lens=None)
    s = np.linspace(-window / 2, window / 2, 65 if window else 1)
    h = 16.0
    wall = (40 + np.arange(16) / 16) * h
    d = (np.arange(80) * h)[:, None] - wall[None, :]
    prof = truth.mean_displacement_px(np.abs(d[..., None] + s)).mean(-1)
    joint = mirror_shift_positions(prof)[0] * h - wall
    resampled = mirror_shift_positions(prof, fit="resample")[0] * h - wall
    assert np.max(np.abs(resampled)) > 0.9  # measured 1.2 (points), 1.0 (windows)
    assert np.max(np.abs(joint)) < (0.04 if window == 0 else 0.2)  # measured 0.026, 0.15
    # a wall near the field's edge: find_wall's band then holds 4 rows each side of it; the
    # resampling has 3 lags left and errs by 2.4 px, the joint fit by 0.04 / 0.17 px
    band = prof[36:45]
    near = mirror_shift_positions(band)[0] * h - (wall - 36 * h)
    near_resampled = mirror_shift_positions(band, fit="resample")[0] * h - (wall - 36 * h)
    assert np.max(np.abs(near_resampled)) > 2.0
    assert np.max(np.abs(near)) < (0.06 if window == 0 else 0.25)
    with pytest.raises(InvalidInputError, match="fit must be"):
        mirror_shift_positions(prof, fit="spline")


def test_the_joint_fits_basis_is_scipys_and_rspiv_leaves_scipy_interpolate_alone():
    """``rspiv.wall.bspline_basis`` is scipy's ``BSpline.design_matrix`` (to rounding), written
    in rspiv so that ``import rspiv`` stays without ``scipy.interpolate`` (first blamed for a
    47 MP campaign loop's higher peak, which later came without it: ``benches/RESULTS.md``)."""
    import subprocess
    import sys

    from rspiv.wall import _distance_knots, bspline_basis
    from scipy.interpolate import BSpline

    rng = np.random.default_rng(0)
    for reach in (5.3, 40.7, 700.2):
        t = _distance_knots(reach)
        x = np.r_[0.0, rng.uniform(0, reach, 300), reach, t[5], t[9]]
        got = bspline_basis(x, t)
        np.testing.assert_allclose(got, BSpline.design_matrix(x, t, 3).toarray(), atol=1e-14)
        np.testing.assert_allclose(got.sum(axis=1), 1.0, atol=1e-14)
    code = "import sys, rspiv; sys.exit('scipy.interpolate' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0



def test_the_wall_moves_with_the_positions_and_nothing_else():
    """Positions known up to a constant (a calibrated PIVlab export read back in px, ``-((H -
    y) c - offset) / c``: equally spaced to rounding): the wall found is the same plus that
    constant. The band's far edge, ``y[j] - half``, rounded past its row for about a third of
    such calibrations and the row was lost: pivpy's urban-canopy series read "3 of 11
    stations" as "2 of 18"."""
    x = np.arange(12) * 160.0 + 7.5
    y = np.arange(0.0, 640.0, 16.0) + 7.5
    wall = 420.3 + 0.02 * x
    u = _mirrored(y, x, wall) + np.random.default_rng(1).normal(0.0, 0.3, (y.size, x.size))
    ref = find_wall(u, y=y, x=x).position_px
    rng = np.random.default_rng(0)
    for calxy, offset in rng.uniform((1e-6, -0.05), (1e-4, 0.05), (30, 2)):
        yc = -(((4000 - (y + 1.5)) * calxy - offset) / calxy) - 1.5
        shift = float(np.mean(yc - y))
        got = find_wall(u, y=yc, x=x).position_px - shift
        np.testing.assert_allclose(got, ref, atol=1e-6)


@pytest.mark.parametrize("angle", [4.0, -6.0, 10.0])
def test_a_wall_far_from_level_is_refused_where_a_campaign_finds_it(angle):
    """check_level: a wall found more than MAX_TILT_DEG off the rows is a flow's extremum or a
    camera far from level, refused in one line; within it the wall is kept as found."""
    from rspiv.wall import MAX_TILT_DEG, check_level

    x = np.arange(16) * 60.0 + 30.0
    y = np.arange(0.0, 1200.0, 4.0)
    wall = 600.0 + (x - x.mean()) * np.tan(np.deg2rad(angle))
    w = find_wall(_mirrored(y, x, wall), y=y, x=x)
    assert w.angle_deg == pytest.approx(angle, abs=0.01)
    if abs(angle) <= MAX_TILT_DEG:
        assert check_level(w) is w
    else:
        with pytest.raises(InvalidInputError, match=rf"tilted {angle:.1f} degrees .*at most 5"):
            check_level(w)
