"""Ensemble correlation (issue 13, first part) against exact synthetic answers.

- Near a wall (a mean profile ``u(y)`` curved over a few px), thin ensemble windows give the
  mean profile where the instantaneous 32 x 8 windows average it away.
- Accumulators of disjoint halves of the pairs merge to the accumulator of all of them.
- Bad input is a one-line InvalidInputError.
"""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.ensemble import EnsembleAccumulator, ensemble_grid
from rspiv.synth import particle_pair

SHAPE = (96, 256)  # rows, columns; the "wall" is the bottom row
DELTA = 6.0  # px: the near-wall profile's length scale


def profile(y):
    """u(y): 3 px far from the wall, 0 at the wall (y = 95.5), curved over a few px."""
    d = np.clip(SHAPE[0] - 0.5 - y, 0, None)
    return 3.0 * (1.0 - np.exp(-d / DELTA))


def field(x, y):
    return profile(y) + 0 * x, 0.0 * x


def box_mean(y, h):
    """The profile's mean over rows y - h/2 .. y + h/2 (fine quadrature)."""
    t = np.linspace(-0.5, 0.5, 401)
    return np.mean(profile(y[..., None] + h * t), axis=-1)


@pytest.fixture(scope="module")
def pairs():
    return [particle_pair(SHAPE, field, seed=100 + k) for k in range(60)]


def test_thin_windows_resolve_the_near_wall_profile(pairs):
    window = (64, 4)
    x, y = ensemble_grid(SHAPE, window, (32, 2))
    acc = EnsembleAccumulator(x, y, window, offset=(profile(y), 0.0))
    acc.add_all(pairs, auto_pairs=30)
    res = acc.result()
    # windows whose offset reaches past the image's sides are left out, the others all count
    used = res.count > 0
    assert used[:, 1:-1].all() and res.ok[used].all() and np.all(res.count[used] == len(pairs))
    near = y[:, 0] > SHAPE[0] - 1 - 20  # the 20 px next to the wall
    got = np.nanmean(res.u, axis=1)[near]
    want = box_mean(y[near, 0], window[1])
    # within 2 % of the velocity away from the wall (0.06 px) at every row
    assert np.max(np.abs(got - want)) < 0.02 * 3.0, np.c_[y[near, 0], got, want]
    # the instantaneous 32 x 8 mean over the same pairs cannot get that close to the wall
    inst = [rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)]) for a, b in pairs[:20]]
    yi = inst[0].y[:, 0]
    ui = np.nanmean([np.nanmean(np.where(f.valid, f.u, np.nan), axis=1) for f in inst], axis=0)
    last = np.argmax(yi)
    # the row nearest the wall: its centre is 4 px up and its value the 8 px window's mean
    assert yi[last] <= y[near, 0].max() - 2
    assert abs(ui[last] - profile(yi[last])) > np.max(np.abs(got - profile(y[near, 0])))


def test_windows_deformed_by_the_mean_field(pairs):
    """Deformed by the profile itself (a grid field, a row per px), the windows still give the
    profile's 4 px means: the deformation's window mean plus the residual."""
    window = (64, 4)
    x, y = ensemble_grid(SHAPE, window, (32, 2))
    gy = np.arange(0.0, SHAPE[0])
    gx = np.arange(0.0, SHAPE[1], 32.0)
    u = np.repeat(profile(gy)[:, None], gx.size, axis=1)
    acc = EnsembleAccumulator(x, y, window, deform=((0.0, 0.0, 32.0, 1.0), u, 0 * u))
    acc.add_all(pairs, auto_pairs=30)
    res = acc.result()
    near = y[:, 0] > SHAPE[0] - 1 - 20
    got = np.nanmean(res.u, axis=1)[near]
    assert np.max(np.abs(got - box_mean(y[near, 0], window[1]))) < 0.02 * 3.0
    with pytest.raises(rspiv.InvalidInputError, match="deform"):
        EnsembleAccumulator(x, y, window, deform=np.zeros((3, 3)))


def test_halves_merge_to_the_whole(pairs):
    window = (32, 8)
    x, y = ensemble_grid(SHAPE, window, (16, 4))
    whole = EnsembleAccumulator(x, y, window, offset=(2.0, 0.0))
    a = EnsembleAccumulator(x, y, window, offset=(2.0, 0.0))
    b = EnsembleAccumulator(x, y, window, offset=(2.0, 0.0))
    for k, (fa, fb) in enumerate(pairs[:10]):
        whole.add(fa, fb)
        (a if k % 2 else b).add(fa, fb)
    a.merge(b)
    np.testing.assert_allclose(a.acc, whole.acc, rtol=1e-12, atol=1e-12)
    assert a.pairs == whole.pairs == 10
    ra, rw = a.result(), whole.result()
    np.testing.assert_allclose(ra.u, rw.u, rtol=1e-9)


def test_noise_gives_no_window(pairs):
    """Frames of noise alone: the Gaussian fits succeed on the noise, but no summed peak
    stands out of it (peak ratio under 3), so no window and no row is ok; the particle
    pairs' windows all stand far above (23 or more)."""
    rng = np.random.default_rng(5)
    window = (64, 4)
    x, y = ensemble_grid(SHAPE, window, (32, 2))
    acc = EnsembleAccumulator(x, y, window, offset=(1.0, 0.0))
    for _ in range(20):
        acc.add(*(rng.normal(100.0, 5.0, SHAPE).astype(np.float32) for _ in range(2)))
    for res in (acc.result(), acc.result(rows=True)):
        assert not res.ok.any() and np.isnan(res.u).all()
        assert np.nanmax(res.peak_ratio[np.isfinite(res.peak_ratio)]) < 3.0
    real = EnsembleAccumulator(x, y, window, offset=(profile(y), 0.0))
    real.add_all(pairs, auto_pairs=30)
    got = real.result()
    assert np.all(got.peak_ratio[got.count > 0] > 20.0)


def test_bad_input_is_one_line(pairs):
    fa, fb = pairs[0]
    with pytest.raises(rspiv.InvalidInputError, match="thinner than 2 px"):
        ensemble_grid(SHAPE, (32, 1), (16, 1))
    x, y = ensemble_grid(SHAPE, (32, 8), (16, 4))
    acc = EnsembleAccumulator(x, y, (32, 1))
    with pytest.raises(rspiv.InvalidInputError, match="too small"):
        acc.add(fa, fb)
    acc = EnsembleAccumulator(x, y, (32, 8))
    with pytest.raises(rspiv.InvalidInputError, match="differ in shape"):
        acc.add(fa, fb[:, :100])
    other = EnsembleAccumulator(x + 1, y, (32, 8))
    with pytest.raises(rspiv.InvalidInputError, match="different windows"):
        acc.merge(other)


# ---------------------------------------------------------------------------- single pixel
@pytest.fixture(scope="module")
def tbl_pairs():
    """40 pairs of rspiv.demo's boundary layer at scale 0.1 (viscous length 1.49 px), an ideal
    camera and a level wall, with the exact displacement of each."""
    return [_tbl_pair(k) for k in range(40)]


def _tbl_pair(k: int, wall_y0_px: float | None = None):
    """Pair ``k`` of the layer of :func:`tbl_pairs`: ``(a, b, truth)`` (the wall moved to
    ``wall_y0_px`` px when given)."""
    import dataclasses

    from rspiv.demo import DEFAULT_SCENE, PAPER_M
    from rspiv.synth import tbl_pair

    scene = dataclasses.replace(DEFAULT_SCENE, scale=0.1)
    return tbl_pair(
        scale=0.1, seed=scene.seed + 1 + k, flow=scene.flow(), u_inf_px=scene.u_inf_px,
        wall_angle_deg=0.0, correlation_px=scene.correlation_px,
        magnification=PAPER_M / 0.1, lens=None, wall_y0_px=wall_y0_px,
    )  # fmt: skip


def test_single_pixel_rows_resolve_the_buffer_layer(tbl_pairs):
    """Rows a quarter px apart, each its own displacement, against the 40 realisations' exact
    mean where each row measures (``dist_eff``): within 3 % (the issue's single-pixel limit)
    for 0.5 <= y+ <= 5 (measured 2.6 %), down to the row 0.75 px from the wall (measuring at
    0.79 px, y+ 0.53). Without the correction the row 0.5 px out reads 22 % high at its own
    distance (the particle images cut by the wall) and the others 1-3 % low (the
    Gaussian fit of the skewed mixture); without the mask the reflection's ghost peak takes
    the rows 1-3.5 px out 9-14 % low or leaves them without a clear peak (refused: weak).
    Frames of noise alone give no row. See rspiv.ensemble_pixel_model."""
    from rspiv.ensemble import PixelAccumulator, pixel_band

    a0, _, t0 = tbl_pairs[0]
    wall, H = t0.wall_y0_px, a0.shape[0]
    lv = t0.viscous_length_px
    dist = np.arange(0.5, 10.01, 0.25)
    y, x0, d = pixel_band(a0.shape, 64, dist, wall, "above", margin_x=16)
    du = t0.mean_displacement_px(wall - y)
    acc = PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3), wall=(wall, "above"))
    bare = PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3))
    halves = [
        PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3), wall=(wall, "above"))
        for _ in range(2)
    ]
    xs = np.arange(x0, x0 + 64 * y.shape[1])
    # the exact displacement on a fine grid of distances, to read the truth where rows measure
    fine = np.arange(0.0, 12.001, 0.05)
    sample, fine_sample = [], []
    for k, (a, b, t) in enumerate(tbl_pairs):
        assert acc.add(a, b) == y.size
        bare.add(a, b)
        halves[k % 2].add(a, b)
        u, _ = t.displacement(np.tile(xs, (d.size, 1)).ravel(), np.repeat(wall - d, xs.size))
        sample.append(u.reshape(d.size, -1))
        u, _ = t.displacement(np.tile(xs, (fine.size, 1)).ravel(), np.repeat(wall - fine, xs.size))
        fine_sample.append(u.reshape(fine.size, -1).mean(axis=1))
    res, raw = acc.result(), bare.result()
    sample = np.array(sample)  # (pairs, rows, points)
    truth = sample.mean(axis=(0, 2))
    d_eff = res["dist_eff"]
    at_eff = np.interp(d_eff, fine, np.mean(fine_sample, axis=0))
    # the streamwise stress, the mean gradient across the particle image removed: 40 pairs
    # leave it scattered by +-23 % about the sample truth (2.25-7 px) where the raw value
    # reads up to 35 % high next to the wall
    tuu = np.mean((sample - truth[None, :, None]) ** 2, axis=(0, 2))
    mid = (d >= 2.25) & (d <= 7.0)
    e_uu, e_raw = res["uu"][mid] / tuu[mid] - 1, res["uu_raw"][mid] / tuu[mid] - 1
    assert np.max(np.abs(e_uu)) < 0.25, np.c_[d[mid], e_uu, e_raw]
    # next to the wall (2.25-3 px) the gradient's term is most of the raw value's error
    wall_side = d[mid] <= 3.0
    assert np.all(np.abs(e_uu[wall_side]) < 0.1) and np.all(e_raw[wall_side] > 0.2)
    assert res["ok"].all() and np.all(res["count"] == 40 * y.shape[1])
    np.testing.assert_allclose(res["dist"], d, atol=1e-9)
    err = res["u"] / at_eff - 1
    sel = (d_eff / lv >= 0.5) & (d_eff / lv <= 5.0)
    assert res["corrected"].all() and sel.sum() >= 27 and d_eff[sel].min() / lv < 0.6
    assert np.max(np.abs(err[sel])) < 0.03, np.c_[d, d_eff / lv, 100 * err][sel]
    assert np.max(np.abs(err)) < 0.03  # out to 10 px (y+ 6.7), the band's edge too
    # what the correction removed: at its own distance the row 0.5 px out reads 22 % high
    # (the particle images cut by the wall); the fit's bias, modelled from the data, is -11 %
    # and -6 % of u for the two rows within an image width (the wall model: the mask, the
    # mirror images, the interpolation across the cut), -1 to -3 % in the viscous sublayer
    # beyond (its skew) shrinking to -0.3 % at y+ 5 (measured)
    fit_err = res["u_fit"] / truth - 1
    assert fit_err[0] > 0.15, fit_err[:3]
    rel_bias = res["fit_bias"] / res["u"]
    assert np.all(np.abs(rel_bias) < 0.15) and np.all(np.abs(rel_bias[d >= 1.0]) < 0.05)
    inner = d / lv <= 5.0
    assert np.all((rel_bias[inner] > -0.15) & (rel_bias[inner] < -0.0015)), rel_bias
    assert rel_bias[0] < 3 * rel_bias[inner][-1], rel_bias
    assert d_eff[0] > 0.65 and np.all(np.abs(d_eff[d > 2.5] - d[d > 2.5]) < 0.06)
    # the rows this far out do not see the wall: the mask changes their fits by the spline's
    # reach across the band's cut edge only (measured 1.3e-5)
    np.testing.assert_allclose(res["u_fit"][d >= 5], raw["u"][d >= 5], rtol=1e-4)
    near = (d >= 1.0) & (d < 3.5)
    err_bare = raw["u"] / truth - 1
    assert np.nanmax(np.abs(err_bare[near])) > 0.09 > np.max(np.abs(err[near]))
    # ... and the ghost peak, a second peak in the plane, leaves some of them without a clear
    # one: refused (weak) rather than read
    assert raw["weak"][near].any() and not res["weak"].any()
    # flagged: the rows within two image widths (about 0.7 px each) of the wall, and only those;
    # without a wall nothing is moved or corrected
    assert res["near_wall"][d < 1.3].all() and not res["near_wall"][d > 1.5].any()
    assert not raw["near_wall"].any() and np.isnan(raw["dist"]).all()
    assert not raw["corrected"].any() and np.isnan(raw["dist_eff"]).all()
    # each quarter-pixel row its own value: the profile rises row by row
    assert np.all(np.diff(res["u"][d >= 1.0]) > 0)
    # a band of rows all within three image widths of the wall: moved to where they measure, but
    # no row out there to model the fit's bias from: left uncorrected, and said so
    inner = PixelAccumulator(y[:4], 64, x0, (du[:4], 0.0), lags=(8, 3), wall=(wall, "above"))
    for a, b, _ in tbl_pairs[:10]:
        inner.add(a, b)
    got = inner.result()
    assert not got["corrected"].any() and np.isnan(got["fit_bias"]).all()
    np.testing.assert_array_equal(got["u"], got["u_fit"])
    moved = got["dist_eff"][:2] - got["dist"][:2]
    assert moved[0] > 0.15 and moved[1] > 0.03 and got["near_wall"][:3].all(), moved
    # no flow (frame A twice): nothing to model, so nothing corrected and no row moved off 0
    still = PixelAccumulator(y, 64, x0, (0.0, 0.0), lags=(8, 3), wall=(wall, "above"))
    for a, _, _ in tbl_pairs[:10]:
        still.add(a, a)
    got = still.result()
    assert not got["corrected"].any() and np.max(np.abs(got["u"])) < 0.02
    # frames of noise alone: fits succeed on the noise, but no row's peak stands out of it
    rng = np.random.default_rng(3)
    noise = PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3), wall=(wall, "above"))
    for _ in range(10):
        noise.add(*(rng.normal(100.0, 5.0, a0.shape).astype(np.float32) for _ in range(2)))
    got = noise.result()
    assert got["weak"].any() and not got["ok"].any() and np.isnan(got["u"]).all()
    assert np.all(got["peak_ratio"] < 2.0) and np.all(res["peak_ratio"] > 15.0)
    # the same pairs upside down, the flow below the wall: the same rows, moved and corrected
    # alike (the covariance's sign follows the wall-normal axis)
    flip = H - 1.0 - wall
    yf, _, _ = pixel_band(a0.shape, 64, dist, flip, "below", margin_x=16)
    below = PixelAccumulator(yf, 64, x0, (du, 0.0), lags=(8, 3), wall=(flip, "below"))
    above = PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3), wall=(wall, "above"))
    for a, b, _ in tbl_pairs[:10]:
        above.add(a, b)
        below.add(np.ascontiguousarray(a[::-1]), np.ascontiguousarray(b[::-1]))
    ra, rb = above.result(), below.result()
    for key in ("dist", "dist_eff", "u", "fit_bias"):
        np.testing.assert_allclose(rb[key], ra[key], rtol=0, atol=1e-6, err_msg=key)
    merged = halves[0].merge(halves[1])
    np.testing.assert_allclose(merged.acc, acc.acc, rtol=1e-12, atol=1e-12)
    with pytest.raises(rspiv.InvalidInputError, match="different bands"):
        merged.merge(PixelAccumulator(y + 1, 64, x0, (du, 0.0), lags=(8, 3)))
    with pytest.raises(rspiv.InvalidInputError, match="different bands"):
        merged.merge(bare)
    with pytest.raises(rspiv.InvalidInputError, match="leave the"):
        pixel_band(a0.shape, 64, np.array([0.5, 600.0]), wall, "above")
    with pytest.raises(rspiv.InvalidInputError, match="segments of 4 px"):
        PixelAccumulator(y, 4, x0, (du, 0.0)).add(a0, a0)
    with pytest.raises(rspiv.InvalidInputError, match="on or beyond the wall"):
        PixelAccumulator(y, 64, x0, (du, 0.0), wall=(wall, "below"))
    with pytest.raises(rspiv.InvalidInputError, match="flow_side"):
        PixelAccumulator(y, 64, x0, (du, 0.0), wall=(wall, "left"))


def _pixel_rows_160(wall_y0_px: float | None = None):
    """Single-pixel rows every 0.25 px from 0.5 px over 160 pairs of the layer (the wall at
    ``wall_y0_px`` when given): ``(result, error against the pairs' exact mean where each row
    measures, rows measuring at 0.5 <= y+ <= 5, dist_eff, viscous length)``."""
    from rspiv.ensemble import PixelAccumulator, pixel_band

    fine = np.arange(0.0, 12.001, 0.05)
    acc, truth = None, []
    for k in range(160):
        a, b, t = _tbl_pair(k, wall_y0_px=wall_y0_px)
        if acc is None:
            wall, lv = t.wall_y0_px, t.viscous_length_px
            y, x0, d = pixel_band(a.shape, 64, np.arange(0.5, 10.01, 0.25), wall, margin_x=16)
            du = t.mean_displacement_px(wall - y)
            acc = PixelAccumulator(y, 64, x0, (du, 0.0), lags=(8, 3), wall=(wall, "above"))
            xs = np.tile(np.arange(x0, x0 + 64 * y.shape[1]), (fine.size, 1))
        acc.add(a, b)
        u, _ = t.displacement(xs.ravel(), np.repeat(wall - fine, xs.shape[1]))
        truth.append(u.reshape(fine.size, -1).mean(axis=1))
    res = acc.result()
    d_eff = res["dist_eff"]
    err = res["u"] / np.interp(d_eff, fine, np.mean(truth, axis=0)) - 1
    return res, err, (d_eff / lv >= 0.5) & (d_eff / lv <= 5.0), d_eff, lv


def test_single_pixel_down_to_y_plus_half_with_160_pairs():
    """160 pairs streamed (the fixture's 40 and 120 more): every row from y+ 0.5 to 5 lies
    within 2 % of the truth where it measures (measured: max 1.62 %, mean |error| 0.58 %).
    The bound on the mean |error| was 0.5 % when the planes were normalised segment by
    segment (0.37 % on these pairs). Four sets of 160 pairs (seeds +0, +2000, +4000, +6000),
    before -> now: max 1.78 / 1.63 / 1.88 / 1.10 % -> 1.62 / 1.58 / 1.42 / 1.26 %, mean
    0.37 / 0.73 / 0.65 / 0.43 % -> 0.58 / 0.46 / 0.43 / 0.49 %: better on average, but these
    pairs were the old estimator's luckiest set, and a row's random error at 160 pairs is
    about 0.4-0.5 %, so the bound on the mean is 0.6 %."""
    res, err, sel, d_eff, lv = _pixel_rows_160()
    assert sel.sum() >= 27 and d_eff[sel].min() / lv < 0.55
    assert np.max(np.abs(err[sel])) < 0.02, np.c_[d_eff / lv, 100 * err][sel]
    assert np.mean(np.abs(err[sel])) < 0.006


def test_single_pixel_rows_wherever_the_wall_falls_in_its_pixel():
    """The same layer with the wall 0.08 px into a pixel (496.58: that pixel masked, the first
    kept pixel's centre 0.58 px out) instead of 0.32 px past a pixel centre: the rows next to
    the wall are modelled on the pixel grid (``rspiv.ensemble_pixel_model.model_planes_wall``),
    so they read as well here. 160 pairs, rows from y+ 0.5 to 5 (measured: within 1.74 %, the
    row 0.5 px out, measuring at y+ 0.64, +1.74 %; over five sets of 160-320 pairs in this
    geometry that row reads +1.7 to +2.1 %, the residual of the model and of its reflection,
    calibrated 0.51-0.57 for a truth of 0.5). Before the wall model, with the
    planes normalised segment by segment: -6.8 % at y+ 0.7 with 40 pairs, -5.9 % with 80."""
    res, err, sel, d_eff, lv = _pixel_rows_160(wall_y0_px=496.58)
    assert res["corrected"].all()
    assert sel.sum() >= 27 and d_eff[sel].min() / lv < 0.65
    assert np.max(np.abs(err[sel])) < 0.025, np.c_[d_eff / lv, 100 * err][sel]
    assert np.max(np.abs(err[sel][2:])) < 0.02 and np.mean(np.abs(err[sel])) < 0.01
    # the wall model's image: its width from the far rows, its reflection from the near ones
    sigma, rho = res["wall_image"]
    assert 0.55 < sigma < 0.65 and 0.4 < rho < 0.65, res["wall_image"]


def test_band_helpers_refuse_bad_input_in_one_line(pairs):
    """band_grid, profile_field, result(rows=True) and from_arrays: one-line errors."""
    from rspiv.ensemble import band_grid, profile_field

    wall = SHAPE[0] - 0.5
    with pytest.raises(rspiv.InvalidInputError, match="thinner than its 64 x 4 px windows"):
        band_grid(SHAPE, (64, 4), (64, 2), 3.0, wall)
    with pytest.raises(rspiv.InvalidInputError, match="flow_side"):
        band_grid(SHAPE, (64, 4), (64, 2), 20.0, wall, "left")
    with pytest.raises(rspiv.InvalidInputError, match="leaves the 256 x 96 px image"):
        band_grid(SHAPE, (64, 4), (64, 2), 200.0, wall)
    with pytest.raises(rspiv.InvalidInputError, match="no finite profile point"):
        profile_field(SHAPE, wall, "above", [np.nan, -1.0], [1.0, 1.0], [0.0, 0.0])
    x, y, d = band_grid(SHAPE, (64, 4), (64, 2), 20.0, wall)
    assert np.allclose(wall - y[:, 0], d) and d[0] == 2.0
    acc = EnsembleAccumulator(x.ravel(), y.ravel(), (64, 4))
    acc.add(*pairs[0])
    with pytest.raises(rspiv.InvalidInputError, match="needs a 2D grid"):
        acc.result(rows=True)
    state = acc.to_arrays()
    assert EnsembleAccumulator.from_arrays(state).pairs == 1
    state["sum"] = state["sum"][:, :-1]
    with pytest.raises(rspiv.InvalidInputError, match="do not fit"):
        EnsembleAccumulator.from_arrays(state)


def test_saturation_is_counted_only_on_a_plateau():
    """A frame saturates at its maximum only when many pixels share it (clipped images); the
    tally per row refuses fractions of the wrong size or outside 0..1 in one line."""
    from rspiv.campaign.ensemble_pixel import saturation, saturation_level
    from rspiv.ensemble_pixel import SaturationTally

    rng = np.random.default_rng(3)
    frame = rng.integers(0, 3000, (64, 256)).astype(np.uint16)
    assert saturation_level(frame) == np.inf  # one brightest pixel is a particle peak
    frame[10:12, :] = 4095
    assert saturation_level(frame) == 4095.0
    lay = {"raw_pixels": (np.array([[10, 10], [30, 30]]), np.array([[0, 5], [0, 5]]))}
    np.testing.assert_array_equal(saturation(lay, (frame, frame, [4095.0, np.inf])), [1.0, 0.0])
    tally = SaturationTally(2)
    tally.add([1.0, 0.0])
    tally.add([0.5, 0.0])
    np.testing.assert_allclose(tally.mean(), [0.75, 0.0])
    for bad in ([0.1], [0.1, 1.5], [np.nan, 0.0]):
        with pytest.raises(rspiv.InvalidInputError, match="2 rows, each in 0..1"):
            tally.add(bad)



def test_single_pixel_rows_with_keys_interpolation_say_so(tbl_pairs):
    """The wall model leaves out Keys' sub-pixel shift bias (with it the rows next to the wall
    read +14 % at y+ 0.5 on 60 pairs of the layer): a band along a wall with Keys
    interpolation warns when it is made, and its near rows take the nearest row's relative
    bias instead (-6 to +7 % there), the wall model unused (``wall_image`` NaN)."""
    from rspiv.ensemble import PixelAccumulator, pixel_band

    a0, _, t0 = tbl_pairs[0]
    wall = t0.wall_y0_px
    y, x0, _ = pixel_band(a0.shape, 64, np.arange(0.5, 10.01, 0.25), wall, margin_x=16)
    du = t0.mean_displacement_px(wall - y)
    with pytest.warns(UserWarning, match="Keys interpolation: its sub-pixel shift bias"):
        acc = PixelAccumulator(
            y, 64, x0, (du, 0.0), lags=(8, 3), interpolation="keys", wall=(wall, "above")
        )
    for a, b, _ in tbl_pairs[:10]:
        acc.add(a, b)
    res = acc.result()
    assert np.isnan(res["wall_image"]).all() and res["corrected"].all()
    # restored from its arrays (a shard, a checkpoint) it does not warn again
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PixelAccumulator.from_arrays(acc.to_arrays())


def test_wall_model_helpers_against_exact_answers():
    """The wall model's pieces (``rspiv.ensemble_pixel_model``): each interpolant's response to
    one pixel is 1 at it and 0 at the others (interpolating); the correlation along a row of
    two pixel-integrated Gaussian images in closed form matches a fine numerical integral;
    a row on a kept pixel's centre, far from the wall, reads that pixel's integrated image
    exactly; bad parameters give one-line errors."""
    from rspiv.ensemble_pixel_model import along_row, cardinal, wall_response
    from scipy.special import ndtr

    k = np.arange(-4.0, 5.0)
    for kind in ("bspline", "bspline3", "keys"):
        np.testing.assert_allclose(cardinal(kind)(k), (k == 0).astype(float), atol=1e-9)
    sig = 0.625
    x = np.linspace(-12.0, 12.0, 24001)
    f = ndtr((x + 0.5) / sig) - ndtr((x - 0.5) / sig)
    for r in (0.0, 0.5, 1.3, 2.7):
        n = int(round(r / (x[1] - x[0])))
        num = (f[: f.size - n] * f[n:]).sum() * (x[1] - x[0])
        np.testing.assert_allclose(along_row(np.array(r), sig), num, rtol=1e-6)
    t = np.linspace(14.0, 16.0, 9)
    z = 0.32 + 15.0  # a kept pixel's centre, 15 px from the wall
    want = ndtr((z - t + 0.5) / sig) - ndtr((z - t - 0.5) / sig)
    got = wall_response(z, t, sig, 0.5, 0.32, cardinal("bspline"))[0]
    np.testing.assert_allclose(got, want, atol=1e-9)  # mirror images 30 px away: nothing
    with pytest.raises(rspiv.InvalidInputError, match="interpolation must be one of"):
        cardinal("linear")
    with pytest.raises(rspiv.InvalidInputError, match="image standard deviation 0.0 px"):
        wall_response(1.0, t, 0.0, 0.5, 0.3, cardinal("keys"))
    with pytest.raises(rspiv.InvalidInputError, match="reflection 1.5"):
        wall_response(1.0, t, 0.6, 1.5, 0.3, cardinal("keys"))
