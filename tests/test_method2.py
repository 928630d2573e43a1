"""Method II (PIV on the raw frames, vectors mapped to the object frame): geometry against exact
answers, and end to end on particle images rendered through a known distortion."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from lens_cases import frames_through, p3_mapping, strong_lens
from rspiv.correction import (
    grid_for_windows,
    map_displacements,
    piv_vectors,
    position_only_bias,
)

SHAPE = (400, 640)  # (h, w), small sensor
U_OBJ, V_OBJ = 9.0, 1.5  # uniform object displacement, px
# RMS vs truth of the piv(method=...) contract; measured 0.021 (images), 0.016 (vectors), 0.023
# between them, 0.255 for mapping="positions"
TOL_RMS = 0.05


@pytest.fixture(scope="module")
def lens():
    return strong_lens(SHAPE)


@pytest.fixture(scope="module")
def mapping(lens):
    return p3_mapping(lens, SHAPE)


@pytest.fixture(scope="module")
def frames(lens):
    """Particles moving by a uniform object displacement, imaged through the lens."""
    return frames_through(lens, SHAPE, (U_OBJ, V_OBJ), seed=7, render_seed=11)


@pytest.mark.parametrize(
    "shape, window, overlap",
    [((400, 640), (32, 8), 0.5), ((257, 301), (32, 32), 0.5), ((100, 130), (16, 8), 0.25)],
)
def test_grid_matches_piv(shape, window, overlap):
    rng = np.random.default_rng(0)
    a = rng.random(shape).astype(np.float32)
    f = rspiv.piv(a, a, [window], overlap=overlap)
    gx, gy = grid_for_windows(shape, window, overlap)
    np.testing.assert_array_equal(gx, f.x)
    np.testing.assert_array_equal(gy, f.y)


def test_full_mapping_inverts_exact_displacements(mapping):
    """d = F(X + D/2) - F(X - D/2) mapped back through F^-1 gives D (to the inverse's 1e-6 px)."""
    rng = np.random.default_rng(3)
    X = rng.uniform([50, 50], [590, 350], (500, 2))
    D = rng.uniform(-20, 20, (500, 2))
    ends = mapping.forward(np.concatenate([X - D / 2, X + D / 2]))
    d = ends[500:] - ends[:500]
    centre = mapping.forward(X)
    # the window centre is F(X); the exact midpoint differs at O(D^2 F''): use it here
    mid = 0.5 * (ends[500:] + ends[:500])
    got = map_displacements(mapping, mid, d, "full")
    np.testing.assert_allclose(got, D, atol=1e-5)
    # positions-only keeps d: its error is exactly position_only_bias
    pos = map_displacements(mapping, centre, d, "positions")
    np.testing.assert_allclose(pos - D, position_only_bias(mapping, X, D), atol=1e-9)
    assert np.abs(pos - D).max() > 0.05  # the distortion is strong enough to matter


def test_nonfinite_rows_stay_nan(mapping):
    d = np.array([[1.0, 2.0], [np.nan, 0.0]])
    p = np.array([[300.0, 200.0], [310.0, 200.0]])
    out = map_displacements(mapping, p, d, "full")
    assert np.all(np.isfinite(out[0])) and np.all(np.isnan(out[1]))


@pytest.mark.parametrize("deformation, noise", [("symmetric", 0.1), ("offset", 0.3)])
def test_piv_vectors_recovers_object_displacement(frames, mapping, deformation, noise):
    a, b = frames
    f = piv_vectors(a, b, mapping, passes=[(64, 64), (32, 32), (32, 8)], deformation=deformation)
    gx, gy = grid_for_windows(SHAPE, (32, 8), 0.5)
    np.testing.assert_array_equal(f.x, gx)
    assert f.grid is not None and f.window == (32, 8)
    ok = f.valid
    assert ok.mean() > 0.9
    # PIV outliers that pass validation are rare (the edge windows); the rest is accurate
    out = np.abs(f.u - U_OBJ) > 1.0
    assert np.mean(out[ok]) < 0.002
    ok &= ~out
    assert abs(np.mean(f.u[ok]) - U_OBJ) < 0.02
    assert abs(np.mean(f.v[ok]) - V_OBJ) < 0.02
    # random error: window offset (whole-pixel shifts) vs symmetric image deformation
    assert np.std(f.u[ok] - U_OBJ) < noise


def test_positions_only_leaves_the_predicted_bias(frames, mapping):
    a, b = frames
    full = piv_vectors(a, b, mapping, mapping="full", deformation="symmetric")
    pos = piv_vectors(a, b, mapping, mapping="positions", deformation="symmetric")
    ok = full.valid & pos.valid
    ok &= (np.abs(full.u - U_OBJ) < 1.0) & (np.abs(pos.u - U_OBJ) < 1.0)  # rare outliers
    X = np.column_stack([pos.x[ok], pos.y[ok]])
    bias = position_only_bias(mapping, X, np.tile([U_OBJ, V_OBJ], (len(X), 1)))
    err_pos = pos.u[ok] - U_OBJ
    err_full = full.u[ok] - U_OBJ
    # the measured error of the position-only correction follows the predicted bias
    assert abs(np.mean(err_pos - bias[:, 0])) < 0.02
    assert np.corrcoef(err_pos, bias[:, 0])[0, 1] > 0.8
    assert np.abs(np.mean(err_full)) < 0.2 * np.abs(np.mean(bias[:, 0]))


def test_methods_agree_on_the_object_grid(frames, mapping):
    """Method I (dewarp, then PIV) and Method II give the same field at the same points."""
    from rspiv.dewarp import dewarp

    a, b = frames
    da = dewarp(a, mapping)
    db = dewarp(b, mapping)
    f1 = rspiv.piv(da, db, [(64, 64), (32, 32), (32, 8)], deformation="offset")
    f2 = piv_vectors(a, b, mapping)
    np.testing.assert_array_equal(f1.x, f2.x)
    ok = f1.valid & f2.valid & (np.abs(f1.u - U_OBJ) < 1.0) & (np.abs(f2.u - U_OBJ) < 1.0)
    assert abs(np.mean(f1.u[ok]) - np.mean(f2.u[ok])) < 0.02
    assert abs(np.mean(f1.v[ok]) - np.mean(f2.v[ok])) < 0.02


def test_bad_input(frames, mapping):
    a, b = frames
    with pytest.raises(rspiv.InvalidInputError, match="full"):
        piv_vectors(a, b, mapping, mapping="vectors")
    with pytest.raises(rspiv.InvalidInputError, match="Calibration or Mapping"):
        piv_vectors(a, b, object())
    with pytest.raises(rspiv.InvalidInputError):
        piv_vectors(a, b[:, :-1], mapping)
    with pytest.raises(rspiv.InvalidInputError, match="passes"):
        piv_vectors(a, b, mapping, passes=[])
    with pytest.raises(rspiv.InvalidInputError, match="deformation"):
        piv_vectors(a, b, mapping, deformation="warp")
    with pytest.raises(rspiv.InvalidInputError, match="predictor_overlap"):
        piv_vectors(a, b, mapping, predictor_overlap=[0.5, 0.5, 0.5])


def _err(f, valid_only=True):
    ok = f.valid & ~f.masked if valid_only else ~f.masked
    return f.u[ok] - U_OBJ, f.v[ok] - V_OBJ


def test_piv_contract_methods_agree_with_truth(frames, mapping):
    a, b = frames
    passes = [(64, 64), (32, 32)]
    fi = rspiv.piv(a, b, passes, calibration=mapping, method="images")
    fv = rspiv.piv(a, b, passes, calibration=mapping, method="vectors")
    fp = rspiv.piv(a, b, passes, calibration=mapping, method="vectors", mapping="positions")
    # both on the regular object grid
    np.testing.assert_array_equal(fi.x, fv.x)
    np.testing.assert_array_equal(fi.y, fv.y)
    rms = {}
    for name, f in (("images", fi), ("vectors", fv), ("positions", fp)):
        eu, ev = _err(f)
        assert eu.size > 0.7 * f.u.size, name
        rms[name] = float(np.sqrt(np.mean(eu**2 + ev**2)))
        print(name, rms[name], float(np.mean(eu)), float(np.mean(ev)))
    both = fi.valid & fv.valid
    diff = np.hypot(fi.u - fv.u, fi.v - fv.v)[both]
    print("images vs vectors rms", float(np.sqrt(np.mean(diff**2))))
    assert rms["images"] < TOL_RMS and rms["vectors"] < TOL_RMS, rms
    assert np.sqrt(np.mean(diff**2)) < TOL_RMS
    # mapping the positions only leaves the local magnification in the displacement
    assert rms["positions"] > 0.15 and rms["positions"] > 5 * rms["vectors"], rms


def test_piv_contract_errors(frames, mapping):
    a, b = frames
    with pytest.raises(rspiv.InvalidInputError):
        rspiv.piv(a, b, [(32, 32)], method="vectors")
    with pytest.raises(rspiv.InvalidInputError):
        rspiv.piv(a, b, [(32, 32)], calibration=mapping, method="bogus")
    with pytest.raises(rspiv.InvalidInputError):
        rspiv.piv(a, b, [(32, 32)], calibration=mapping)
    with pytest.raises(rspiv.InvalidInputError):
        rspiv.piv(a, b, [(32, 32)], calibration=mapping, method="vectors", mapping="nope")


@pytest.mark.parametrize("deformation", ["offset", "symmetric"])
def test_final_pass_does_method_I_work_at_method_I_accuracy(frames, mapping, deformation):
    """Method II's final pass runs once per point (as each pass of rspiv.piv, Method I) with
    the same deformation; a second iteration (the former default, twice the final pass's work)
    gains ~2 % RMS here, and Method II stays as accurate as Method I against the truth
    (benches/bench_method2.py times both)."""
    from rspiv.dewarp import dewarp

    a, b = frames
    passes = [(64, 64), (32, 32), (32, 8)]
    f1 = rspiv.piv(dewarp(a, mapping), dewarp(b, mapping), passes, deformation=deformation)
    one = piv_vectors(a, b, mapping, passes, deformation=deformation)
    same = piv_vectors(a, b, mapping, passes, deformation=deformation, iterations=1)
    two = piv_vectors(a, b, mapping, passes, deformation=deformation, iterations=2)
    np.testing.assert_array_equal(one.u, same.u)  # the default is one iteration
    ok = f1.valid & one.valid & two.valid
    ok &= (np.abs(f1.u - U_OBJ) < 1) & (np.abs(one.u - U_OBJ) < 1) & (np.abs(two.u - U_OBJ) < 1)
    assert ok.mean() > 0.85

    def rms(f):
        return float(np.sqrt(np.mean((f.u[ok] - U_OBJ) ** 2 + (f.v[ok] - V_OBJ) ** 2)))

    r1, r_one, r_two = rms(f1), rms(one), rms(two)
    print(deformation, "I", r1, "II 1 it", r_one, "II 2 it", r_two)
    assert r_one < 1.15 * r1 + 0.005
    assert r_one < 1.15 * r_two + 0.005


@pytest.mark.parametrize("deformation", ["offset", "symmetric"])
@pytest.mark.parametrize("with_mask", [False, True])
def test_one_native_call_equals_predictor_then_piv_at(frames, mapping, deformation, with_mask):
    """piv_vectors without a predictor (one native call: predictor passes and final pass on one
    prepared pair) gives the vectors of the two-call path (rspiv.piv of passes[:-1], then
    rspiv.piv_at with that field), masked predictor vectors included."""
    a, b = frames
    passes = [(64, 64), (32, 32), (32, 8)]
    mask = None
    if with_mask:
        mask = np.zeros(SHAPE, bool)
        mask[150:230, 250:330] = True
    kw = dict(deformation=deformation, mask=mask, predictor_overlap=[0.5, 0.25])
    one = piv_vectors(a, b, mapping, passes, **kw)
    pred = rspiv.piv(a, b, passes[:-1], overlap=[0.5, 0.25], deformation=deformation, mask=mask)
    assert not with_mask or pred.masked.any()
    two = piv_vectors(a, b, mapping, passes, deformation=deformation, mask=mask, predictor=pred)
    for k in ("valid", "replaced", "masked"):
        np.testing.assert_array_equal(getattr(one, k), getattr(two, k))
    assert one.valid.mean() > 0.85
    np.testing.assert_allclose(one.u, two.u, rtol=0, atol=1e-9)
    np.testing.assert_allclose(one.v, two.v, rtol=0, atol=1e-9)
    np.testing.assert_allclose(one.peak_ratio, two.peak_ratio, rtol=1e-9, atol=1e-12)
    # another predictor overlap is really forwarded (a different predictor)
    other = piv_vectors(a, b, mapping, passes, deformation=deformation, mask=mask)
    assert not np.array_equal(other.u, one.u, equal_nan=True)


def test_piv_contract_forwards_settings_to_method_II(frames, mapping):
    """rspiv.piv(method="vectors") passes per-pass overlaps, iterations, interpolation,
    validate and min_peak_ratio on to piv_vectors."""
    a, b = frames
    passes = [(64, 64), (32, 32), (32, 8)]
    kw = dict(interpolation="bspline3", validate=False, min_peak_ratio=1.2)
    f = rspiv.piv(a, b, passes, [0.25, 0.5, 0.5], "symmetric", calibration=mapping,
                  method="vectors", iterations=[1, 2, 2], **kw)  # fmt: skip
    g = piv_vectors(a, b, mapping, passes, 0.5, deformation="symmetric", iterations=2,
                    predictor_overlap=[0.25, 0.5], predictor_iterations=[1, 2], **kw)  # fmt: skip
    np.testing.assert_array_equal(f.u, g.u)
    np.testing.assert_array_equal(f.valid, g.valid)
    base = piv_vectors(a, b, mapping, passes, 0.5, deformation="symmetric")
    assert not np.array_equal(f.u, base.u, equal_nan=True)
