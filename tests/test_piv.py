"""PIV engine: accuracy against synthetic ground truth, OpenPIV agreement, API and errors."""

from __future__ import annotations

import os

import numpy as np
import openpiv
import pytest
import rspiv
from rspiv.synth import particle_pair


def _uniform_ramp_pair(h=384, w=1024, seed=11):
    """True displacement uniform over [0, 1) px in both components across the image."""

    def disp(x, y):
        return x / w, y / h

    a, b = particle_pair((h, w), disp, density=0.03, diameter=2.5, noise=0.05, seed=seed)
    return a, b, disp


def test_subpixel_bias_rms_and_no_peak_locking():
    a, b, disp = _uniform_ramp_pair()
    f = rspiv.piv(a, b, passes=[(64, 64), (32, 32)])
    tu, tv = disp(f.x, f.y)
    true = np.concatenate([tu.ravel(), tv.ravel()])
    meas = np.concatenate([f.u.ravel(), f.v.ravel()])
    err = meas - true
    # RMS error at 32 x 32 windows, per component
    rms_u = np.sqrt(np.mean((f.u - tu) ** 2))
    rms_v = np.sqrt(np.mean((f.v - tv) ** 2))
    assert rms_u <= 0.03 and rms_v <= 0.03, (rms_u, rms_v)
    # bias curve: mean error per 0.1 px bin of the true displacement; peak locking would show
    # as a systematic S-shaped bias pulling towards 0 and 1
    bins = np.clip((true * 10).astype(int), 0, 9)
    bias = np.array([err[bins == k].mean() for k in range(10)])
    assert np.all(np.abs(bias) <= 0.02), bias
    # histogram of the fractional part of the measurement: flat within 25 % per bin
    # (about 190 samples per bin; a peak-locked estimator empties the middle bins)
    frac = np.mod(meas, 1.0)
    hist, _ = np.histogram(frac, bins=10, range=(0, 1))
    expected = len(frac) / 10
    assert np.all(np.abs(hist - expected) <= 0.25 * expected), hist
    # peak-locking degree (Christensen 2004): 1 - (min bin / max bin) of the central histogram
    assert 1 - hist.min() / hist.max() < 0.4, hist


def test_single_pass_32x32_unbiased():
    a, b = particle_pair((256, 256), (0.3, -0.7), seed=2)
    f = rspiv.piv(a, b, passes=[(32, 32)])
    assert abs(f.u.mean() - 0.3) < 0.01 and abs(f.v.mean() + 0.7) < 0.01
    assert np.sqrt(np.mean((f.u - 0.3) ** 2 + (f.v + 0.7) ** 2)) < 0.05


def test_sinusoidal_shear_multipass_deformation():
    # L = 8 window heights of the final 32 x 32 windows
    h = w = 512
    amp, length = 1.0, 8 * 32

    def disp(x, y):
        return amp * np.sin(2 * np.pi * y / length), 0 * x

    a, b = particle_pair((h, w), disp, seed=3)
    f = rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 32)], deformation="symmetric")
    tu, tv = disp(f.x, f.y)
    rms = np.sqrt(np.mean((f.u - tu) ** 2 + (f.v - tv) ** 2))
    assert rms <= 0.05, rms
    # a single pass without deformation is much worse: the window averages the shear
    g = rspiv.piv(a, b, passes=[(32, 32)])
    rms1 = np.sqrt(np.mean((g.u - tu) ** 2 + (g.v - tv) ** 2))
    assert rms1 > rms


def test_boundary_layer_rectangular_windows_resolve_the_wall():
    delta, u_inf = 10.0, 8.0

    def disp(x, y):
        return u_inf * (1 - np.exp(-np.maximum(y, 0) / delta)), 0 * x

    a, b = particle_pair((256, 768), disp, seed=4)
    errs = {}
    for name, passes in {
        "32x32": [(64, 64), (32, 32)],
        "32x8": [(64, 64), (32, 32), (32, 8)],
    }.items():
        f = rspiv.piv(a, b, passes=passes)
        tu, _ = disp(f.x, f.y)
        near = f.y < 40
        errs[name] = float(np.sqrt(np.mean((f.u - tu)[near] ** 2)))
    print("near-wall RMS error (px):", errs)
    assert errs["32x8"] < 0.8 * errs["32x32"], errs


def test_agrees_with_openpiv_windef_on_its_test_images():
    from openpiv import tools, windef

    data = os.path.join(os.path.dirname(openpiv.__file__), "data", "test1")
    fa = tools.imread(os.path.join(data, "exp1_001_a.bmp"))
    fb = tools.imread(os.path.join(data, "exp1_001_b.bmp"))
    s = windef.PIVSettings()
    s.windowsizes = (64, 32)
    s.overlap = (32, 16)
    s.num_iterations = 2
    s.show_plot = False
    s.save_plot = False
    x, y, u, v, flags = windef.simple_multipass(fa, fb, s)
    # back to image coordinates: simple_multipass returns y up and v up
    xo, yo, uo, vo = tools.transform_coordinates(x, y, u, v)
    ours = rspiv.piv(fa, fb, passes=[(64, 64), (32, 32)])
    from scipy.interpolate import RegularGridInterpolator

    pts = np.stack([yo.ravel(), xo.ravel()], axis=-1)
    inside = (
        (pts[:, 0] >= ours.y[0, 0])
        & (pts[:, 0] <= ours.y[-1, 0])
        & (pts[:, 1] >= ours.x[0, 0])
        & (pts[:, 1] <= ours.x[0, -1])
    )
    pts = pts[inside]
    iu = RegularGridInterpolator((ours.y[:, 0], ours.x[0, :]), ours.u)(pts)
    iv = RegularGridInterpolator((ours.y[:, 0], ours.x[0, :]), ours.v)(pts)
    du = np.abs(iu - uo.ravel()[inside])
    dv = np.abs(iv - vo.ravel()[inside])
    print("median |du|, |dv| vs openpiv.windef:", np.median(du), np.median(dv))
    assert np.median(du) <= 0.1 and np.median(dv) <= 0.1


def test_offset_mode_and_gauss2d_and_dtypes():
    a, b = particle_pair((192, 192), (2.4, 1.1), seed=5)
    ref = rspiv.piv(a, b, passes=[(64, 64), (32, 32)])
    for kw in ({"deformation": "offset"}, {"subpixel": "gauss2d"}):
        f = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], **kw)
        assert np.sqrt(np.mean((f.u - 2.4) ** 2 + (f.v - 1.1) ** 2)) < 0.05
    # Keys bicubic deformation works but leaves the interpolation bias the B-spline avoids
    keys = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], interpolation="keys")
    e_keys = np.sqrt(np.mean((keys.u - 2.4) ** 2 + (keys.v - 1.1) ** 2))
    e_ref = np.sqrt(np.mean((ref.u - 2.4) ** 2 + (ref.v - 1.1) ** 2))
    assert e_ref < e_keys < 0.1, (e_ref, e_keys)
    for dt in (np.float32, np.float64, np.int32):
        f = rspiv.piv(a.astype(dt), b.astype(dt), passes=[(64, 64), (32, 32)])
        np.testing.assert_allclose(f.u, ref.u, atol=1e-3)


def test_mask_flags_vectors_without_computing_them():
    a, b = particle_pair((160, 160), (1.0, 0.5), seed=6)
    mask = np.zeros(a.shape, bool)
    mask[:, :60] = True
    f = rspiv.piv(a, b, passes=[(32, 32)], mask=mask)
    inside = np.round(f.x) < 60
    assert np.array_equal(f.masked, inside)
    assert np.all(np.isnan(f.u[inside])) and not np.any(f.valid[inside])
    assert np.all(np.abs(f.u[~inside] - 1.0) < 0.1)


def test_piv_at_points_and_predictors():
    def disp(x, y):
        return 6.0 + 0.01 * y, -1.5 + 0 * x

    a, b = particle_pair((256, 256), disp, seed=7)
    grid = rspiv.piv(a, b, passes=[(64, 64), (32, 32)])
    pts = np.array([[100.3, 80.7], [150.0, 120.25], [60.5, 200.0]])
    tu, tv = disp(pts[:, 0], pts[:, 1])
    # with a per-point predictor (offset) and with the grid field (deformation)
    for pred in (np.stack([tu + 0.4, tv - 0.3], -1), grid):
        f = rspiv.piv_at(a, b, pts, window=(32, 32), predictor=pred, iterations=2)
        assert f.shape == (3,)
        assert np.all(np.abs(f.u - tu) < 0.1) and np.all(np.abs(f.v - tv) < 0.1), (f.u, f.v)
    # structured points with multipass windows and no predictor
    ys, xs = np.mgrid[60:200:20, 60:200:20].astype(float)
    f = rspiv.piv_at(a, b, np.stack([xs, ys], -1), window=[(64, 64), (32, 8)], iterations=2)
    assert f.shape == xs.shape and f.grid is None
    assert np.sqrt(np.mean((f.u - disp(xs, ys)[0]) ** 2)) < 0.1


def test_to_xarray_is_pivpy_like():
    a, b = particle_pair((128, 160), (1.0, 0.0), seed=8)
    f = rspiv.piv(a, b, passes=[(32, 32), (32, 8)])
    ds = f.to_xarray()
    assert set(("u", "v", "chc")) <= set(ds.data_vars)
    assert ds.u.dims == ("y", "x") and ds.sizes["x"] == f.shape[1]
    np.testing.assert_array_equal(ds.x.values, f.x[0])
    assert f.window == (32, 8) and f.x.shape == f.peak_ratio.shape


def test_rectangular_window_orientation():
    # (w, h) = (32, 8): 32 px along x, 8 px along y -> vectors every 16 px in x, 4 px in y
    a, b = particle_pair((64, 128), (0.5, 0.0), seed=9)
    f = rspiv.piv(a, b, passes=[(32, 8)], overlap=0.5)
    assert f.x[0, 1] - f.x[0, 0] == 16 and f.y[1, 0] - f.y[0, 0] == 4
    assert f.x[0, 0] == pytest.approx(15.5) and f.y[0, 0] == pytest.approx(3.5)


def test_render_particles_contract():
    img = rspiv._rspiv.render_particles(
        20, 30, np.array([10.2]), np.array([7.6]), np.array([1000.0]), np.array([3.0]), 0.0, 4095, 1
    )
    assert img.dtype == np.uint16 and img.shape == (20, 30)
    total = img.astype(float).sum()
    assert abs(total - 1000 * np.pi * 9 / 8) / total < 0.01
    yy, xx = np.mgrid[:20, :30]
    assert abs((img * xx).sum() / total - 10.2) < 0.02
    a1, _ = particle_pair((64, 64), (1, 1), seed=3)
    a2, _ = particle_pair((64, 64), (1, 1), seed=3)
    assert np.array_equal(a1, a2) and a1.max() <= 4095


@pytest.mark.parametrize(
    "fa, fb, kw, msg",
    [
        (np.zeros((64, 64)), np.zeros((64, 65)), {}, "differ in shape"),
        (np.zeros((64, 64)), np.zeros((64, 64)), {"passes": [(128, 32)]}, "larger than the image"),
        (np.zeros((2, 64, 64)), np.zeros((2, 64, 64)), {}, "2D"),
        (np.full((64, 64), np.nan), np.zeros((64, 64)), {"passes": [(32, 32)]}, "NaN"),
        (np.zeros((64, 64)), np.zeros((64, 64)), {"passes": [(32, 32)], "overlap": 1.5}, "overlap"),
        (np.zeros((64, 64)), np.zeros((64, 64)), {"deformation": "warp"}, "deformation"),
    ],
)
def test_bad_input_raises_invalid_input(fa, fb, kw, msg):
    with pytest.raises(rspiv.InvalidInputError, match=msg):
        rspiv.piv(fa, fb, **kw)


def _edge_pair(shape=(128, 160), d=(3.0, 2.0), seed=5):
    a, b = particle_pair(
        shape,
        lambda x, y: (np.full_like(x, d[0]), np.full_like(y, d[1])),
        density=0.03,
        diameter=2.5,
        noise=0.05,
        seed=seed,
    )
    return a, b


def test_piv_at_windows_past_the_edge_are_invalid_not_garbage():
    # the pipeline's failure: points near and beyond the border on uniform flow came back
    # valid with outliers (-13.8 px)
    a, b = _edge_pair()
    h, w = a.shape
    xs = np.array([40.0, 100.0, 140.0, 145.0, 147.0, 148.0, 150.0, 159.4, 170.0])
    pts = np.column_stack([xs, np.full_like(xs, 60.0)])
    for pred, off in ((None, 0.0), (np.tile([3.0, 2.0], (len(xs), 1)), 1.5)):
        f = rspiv.piv_at(a, b, pts, window=(24, 24), predictor=pred, iterations=1)
        left = xs - 11.5
        fits = (left - off >= -0.5) & (left + 23 + off <= w - 0.5)
        np.testing.assert_array_equal(f.valid, fits)
        assert f.valid.sum() >= 3
        np.testing.assert_allclose(f.u[f.valid], 3.0, atol=0.1)
        np.testing.assert_allclose(f.v[f.valid], 2.0, atol=0.1)
        assert f.masked[-1] and np.isnan(f.u[-1])  # centre outside the image
        assert np.all(f.coef[~f.valid] == 0.0)


def test_grid_windows_deformed_past_the_edge_are_invalid():
    a, b = _edge_pair(d=(6.0, -5.0))
    f = rspiv.piv(a, b, passes=[(32, 32), (32, 32)])
    h, w = a.shape
    left, top = f.x - 15.5, f.y - 15.5
    out = (left < 2.5) | (top < 2.0) | (left + 31 > w - 1 - 2.5) | (top + 31 > h - 1 - 2.0)
    assert out.any() and not f.valid[out].any()
    assert np.all(f.replaced[out])
    assert f.valid[1:-1, 1:-1].all()
    np.testing.assert_allclose(f.u[f.valid], 6.0, atol=0.1)
    np.testing.assert_allclose(f.v[f.valid], -5.0, atol=0.1)


def test_clean_background_is_correlated_not_blank():
    """A noise-free render (0.03 ppp, 1.5 px particles: 72 % of the pixels exactly zero and a
    third of the 4 x 4 px blocks empty) is particle images on a clean background, not fill:
    every window is correlated and the field is as good as with camera noise. Before, the
    blank-window rule refused all 49 first-pass windows and the final 32 x 8 pass, left with
    a zero predictor, returned 105 valid vectors off by more than 3 px."""
    n = 256

    def field(x, y):
        return 3.3 + 0.05 * (y - n / 2), -1.7 + 0.025 * (x - n / 2)

    rms = {}
    for noise in (0.0, 0.05):
        a, b = particle_pair((n, n), field, density=0.03, diameter=1.5, noise=noise, seed=20)
        first = rspiv.piv(a, b, passes=[(64, 64)], overlap=0.5)
        assert first.valid.all(), noise
        f = rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5)
        tu, tv = field(f.x, f.y)
        err = np.hypot(f.u - tu, f.v - tv)[f.valid]
        inside = (f.x > 32) & (f.x < n - 33) & (f.y > 32) & (f.y < n - 33)
        assert f.valid[inside].mean() > 0.95 and err.max() < 0.5, (noise, err.max())
        rms[noise] = np.sqrt(np.mean(err**2))
    # measured: 0.065 px noise-free, 0.108 px with 5 % noise
    assert rms[0.0] <= rms[0.05], rms


def test_sparse_particles_on_a_clean_background_are_correlated():
    """Sparse particle images on a background without noise (a noise-free render, a background
    subtracted and clipped hard at zero) leave gaps of 80-170 px between them along a row:
    before, the clean background went unrecognised (runs of 4-48 px only), every window was
    blank and nothing was correlated at 0.002-0.004 particles/px. Now they are measured, as
    well as or better than the same particles with camera noise."""
    n = (512, 1024)
    passes = [(64, 64), (32, 32)]
    rms = {}
    for density in (0.002, 0.004):
        for noise in (0.0, 0.05):
            a, b = particle_pair(n, (1.5, -0.7), density=density, noise=noise, seed=31)
            f = rspiv.piv(a, b, passes=passes)
            inner = np.zeros(f.u.shape, bool)
            inner[2:-2, 2:-2] = True
            ok = f.valid & inner
            rms[density, noise] = np.sqrt(np.mean((f.u[ok] - 1.5) ** 2 + (f.v[ok] + 0.7) ** 2))
            # measured: 96 % (0.002) and 99.9 % (0.004) of the windows correlated noise-free
            assert (f.peak_ratio[inner] > 0).mean() > (0.9 if density < 0.003 else 0.99)
        # measured: 0.024 vs 0.22 px (0.002), 0.015 vs 0.065 px (0.004)
        assert rms[density, 0.0] < min(0.05, rms[density, 0.05]), rms


def test_zero_filled_half_frame_is_blank():
    a, b = _edge_pair(d=(1.5, 0.5))
    a = a.copy()
    b = b.copy()
    a[:, 80:] = 0
    b[:, 80:] = 0
    f = rspiv.piv(a, b, passes=[(32, 32), (16, 16)])
    hw = 7.5
    blank = f.x - hw - 0.75 - 2.0 >= 79.5
    assert blank.any() and not f.valid[blank].any()
    assert np.all(f.coef[blank] == 0.0)
    # windows straddling the fill edge are still correlated (a partial fill is not detected, see
    # the docs of piv) and bias their neighbours' predictor: check those a first-pass window
    # (32 px) away from the edge
    clear = f.valid & (f.x + hw + 32 < 80.0)
    assert clear.sum() >= 6
    err = np.hypot(f.u[clear] - 1.5, f.v[clear] - 0.5)
    # measured: rms 0.05, max 0.15 (16 x 16 windows, the worst on the image's bottom edge)
    assert np.sqrt(np.mean(err**2)) < 0.08 and err.max() < 0.25, (
        np.sqrt(np.mean(err**2)),
        err.max(),
    )


def test_windows_reaching_into_zero_fill_are_flagged_interior_unchanged():
    # a dewarped pair's zero fill (object points imaged outside the sensor): columns from 200
    # on are 0 in both frames; the particles move by (1.5, 0.5) px everywhere else
    a, b = particle_pair((192, 320), (1.5, 0.5), seed=21)
    af, bf = a.copy(), b.copy()
    af[:, 200:] = 0
    bf[:, 200:] = 0
    ref = rspiv.piv(a, b, passes=[(32, 32)])
    f = rspiv.piv(af, bf, passes=[(32, 32)])
    left = f.x - 15.5
    fill = np.clip(left + 32 - 200, 0, 32) / 32  # fraction of the window in the fill
    assert ((fill > 0) & (fill < 1)).sum() >= 6
    # the rule (multipass.rs, signal_fraction): blocks of 4 x 4 px entirely in the fill are
    # blank; more than a quarter of the window blank -> not correlated, flagged
    blank = sum((left + 4 * k >= 200).astype(float) for k in range(8)) / 8
    np.testing.assert_array_equal(f.valid, blank <= 0.25)
    assert not f.valid[fill > 0.45].any() and np.all(f.coef[blank > 0.25] == 0.0)
    assert np.all(f.replaced[blank > 0.25])
    # the valid ones, windows part-way into the fill included (correlated over their image
    # part), are not pulled towards zero: before, windows half in the fill came back valid
    part = f.valid & (fill > 0)
    assert part.sum() >= 6 and abs(f.u[part].mean() - 1.5) < 0.05, f.u[part]
    assert np.hypot(f.u - 1.5, f.v - 0.5)[f.valid].max() < 0.2
    # windows clear of the fill are unchanged
    clear = fill == 0
    np.testing.assert_array_equal(f.u[clear], ref.u[clear])
    np.testing.assert_array_equal(f.v[clear], ref.v[clear])
    np.testing.assert_array_equal(f.valid[clear], ref.valid[clear])
    # piv_at at the same points (one iteration: no offset) follows the same rule
    g = rspiv.piv_at(af, bf, np.stack([f.x, f.y], -1), window=(32, 32), iterations=1)
    np.testing.assert_array_equal(g.valid, f.valid)
    np.testing.assert_array_equal(g.u[g.valid], f.u[f.valid])
    # multipass with deformation: windows mostly in the fill flagged, the ones clear of it
    # right (the deformed fill edge is not stationary: see signal_fraction's docs)
    m = rspiv.piv(af, bf, passes=[(64, 64), (32, 32)])
    inside = np.zeros_like(clear)
    inside[1:-1, 1:-1] = True  # the border windows are deformed past the image edge
    assert not m.valid[fill > 0.45].any() and m.valid[clear & inside].all()
    assert np.hypot(m.u - 1.5, m.v - 0.5)[clear & inside].max() < 0.1


def test_second_and_third_peaks_recover_outliers_interpolation_misses():
    """Injected outliers: in 10 windows (6 alone, a 2 x 2 cluster) frame B also holds frame
    A's particles, 1.5x brighter, at zero displacement: the highest correlation peak is at
    zero, the second is the particles' displacement. Recovered = within 0.25 px of the same
    window on the clean pair. Measured: 3 of 10 recovered by interpolation alone (the cluster
    is interpolated from the spoiled side too), 7 of 10 with the second/third peaks (5 from
    the second peak); the single-pass second peak of an isolated window is 0.1-0.3 px off
    where the field's gradient broadens it."""
    h, w = 256, 320

    def disp(x, y):
        return 3.0 + 1.5 * np.sin(2 * np.pi * y / 256), np.cos(2 * np.pi * x / 320)

    a, b = particle_pair((h, w), disp, seed=5)
    a, b = a.astype(np.float64), b.astype(np.float64)
    clean = rspiv.piv(a, b, passes=[(32, 32)], overlap=0.0, peak_candidates=1)
    sites = [(1, 2), (3, 7), (6, 3), (1, 8), (6, 8), (4, 1), (3, 4), (3, 5), (4, 4), (4, 5)]
    ghost = b.copy()
    for j, i in sites:
        win = np.s_[32 * j : 32 * j + 32, 32 * i : 32 * i + 32]
        ghost[win] += 1.5 * a[win]
    out = {}
    for n in (1, 3):
        f = rspiv.piv(a, ghost, passes=[(32, 32)], overlap=0.0, peak_candidates=n)
        err = np.hypot(f.u - clean.u, f.v - clean.v)
        out[n] = (sum(bool(err[s] < 0.25) for s in sites), f.peak_counts(), f)
    (one, one_c, _), (three, three_c, f) = out[1], out[3]
    print(f"recovered at the 10 sites: {one} by interpolation, {three} with the other peaks; "
          f"{one_c} -> {three_c}")  # fmt: skip
    assert one_c["second"] == one_c["third"] == 0 and one_c["interpolated"] >= 8
    assert three_c["second"] + three_c["third"] >= 4
    assert three >= one + 3, (one, three)
    # the cluster comes back from its second peaks: interpolation alone cannot
    err = np.hypot(f.u - clean.u, f.v - clean.v)
    assert all(err[s] < 0.25 for s in [(3, 4), (3, 5), (4, 4), (4, 5)])
    # the choice is reported everywhere the field goes
    ds = f.to_xarray()
    assert int((ds.peak_choice.values >= 2).sum()) == three_c["second"] + three_c["third"]
    assert not np.any(f.peak_choice[f.replaced])
    with pytest.raises(rspiv.InvalidInputError, match="peak_candidates"):
        rspiv.PivSettings(peak_candidates=4)
