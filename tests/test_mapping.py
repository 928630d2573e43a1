"""Mapping models R1/R2/P3: fits against known mappings and against scipy's MINPACK,
Jacobians against central differences, inverse round trips, files, and bad input.

Ground truth: tests/mapping_cases.py (known mappings over the full 8864 x 5288 sensor, 13 x 7
markers, and an independent NumPy implementation of the models).
"""

from __future__ import annotations

import json

import mapping_cases as mc
import numpy as np
import pytest
import rspiv
from rspiv import ConvergenceError, InvalidInputError
from scipy.optimize import least_squares

MODELS = ["r1", "r2", "p3"]
N_PARAMS = {"r1": 8, "r2": 17, "p3": 20}


def _data(model, strength=1.0, noise=0.0, seed=7):
    obj = mc.grid_13x7()
    c = mc.truth_coefficients(model, strength)
    img = mc.apply_truth(model, c, obj)
    if noise:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return obj, img, c


@pytest.mark.parametrize("model", MODELS)
def test_noise_free_fit_reproduces_the_mapping_over_the_sensor(model):
    obj, img, c = _data(model)
    m = rspiv.fit_mapping(obj, img, model=model)
    assert m.model == model and m.coefficients.shape == (N_PARAMS[model],)
    pts = mc.sensor_grid()
    err = np.abs(m.forward(pts) - mc.apply_truth(model, c, pts)).max()
    assert err < 0.01, err
    assert max(m.stats["rms_px"]) < 1e-6


def _scipy_reference(model, m, obj, img):
    """scipy least_squares(method="lm") on the same normalised problem (rspiv's frame)."""
    s = m.scale
    oh = (obj - np.asarray(m.centre_object)) / s
    ih = (img - np.asarray(m.centre_image)) / s
    x, y = oh[:, 0], oh[:, 1]

    def fun(c):
        fx, fy = mc.eval_model(model, c, x, y)
        return np.concatenate([fx - ih[:, 0], fy - ih[:, 1]])

    def jac(c):
        return mc.coeff_jacobian(model, c, x, y)

    x0 = mc.linear_start(model, oh, ih)
    res = least_squares(
        fun, x0, jac=jac, method="lm", ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=100000
    )
    assert res.success, res.message
    return res, oh


@pytest.mark.parametrize("model", MODELS)
def test_noisy_fit_matches_scipy_minpack(model):
    obj, img, _ = _data(model, noise=0.05)
    m = rspiv.fit_mapping(obj, img, model=model)
    res, oh = _scipy_reference(model, m, obj, img)
    rms_rspiv = np.sqrt(np.mean(m.residuals**2))
    rms_scipy = np.sqrt(np.mean(res.fun**2)) * m.scale
    assert rms_rspiv <= rms_scipy * (1 + 1e-9), (rms_rspiv, rms_scipy)
    # the same predictions at the markers and over the whole sensor
    fx, fy = mc.eval_model(model, res.x, oh[:, 0], oh[:, 1])
    pred_scipy = np.column_stack(
        [m.centre_image[0] + m.scale * fx, m.centre_image[1] + m.scale * fy]
    )
    assert np.abs(m.forward(obj) - pred_scipy).max() < 1e-6
    pts = mc.sensor_grid()
    ph = (pts - np.asarray(m.centre_object)) / m.scale
    gx, gy = mc.eval_model(model, res.x, ph[:, 0], ph[:, 1])
    ref = np.column_stack([m.centre_image[0] + m.scale * gx, m.centre_image[1] + m.scale * gy])
    assert np.abs(m.forward(pts) - ref).max() < 1e-6
    # residuals and statistics are those of the fit, in image px
    r = m.forward(obj) - img
    np.testing.assert_allclose(m.residuals, r, atol=1e-9)
    st = m.stats
    assert st["n_points"] == 91 and st["model"] == model
    np.testing.assert_allclose(st["rms_px"], np.sqrt(np.mean(r**2, axis=0)), rtol=1e-9)
    np.testing.assert_allclose(st["mean_px"], r.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(st["max_abs_px"], np.abs(r).max(axis=0), rtol=1e-9)
    # covariance s^2 (J^T J)^-1 from scipy's Jacobian at its solution
    dof = res.fun.size - res.x.size
    cov_ref = (res.fun @ res.fun / dof) * np.linalg.inv(res.jac.T @ res.jac)
    assert m.covariance.shape == (N_PARAMS[model],) * 2
    np.testing.assert_allclose(m.covariance, cov_ref, rtol=1e-6, atol=1e-9 * np.abs(cov_ref).max())


@pytest.mark.parametrize("model", MODELS)
def test_forward_jacobian_matches_central_differences(model):
    obj, img, _ = _data(model, noise=0.05)
    m = rspiv.fit_mapping(obj, img, model=model).rotated(0.7)
    pts = mc.sensor_grid(7, 5)
    j = m.forward_jacobian(pts)
    h = 1e-2
    ex, ey = np.array([h, 0.0]), np.array([0.0, h])
    num = np.stack(
        [
            (m.forward(pts + ex) - m.forward(pts - ex)) / (2 * h),
            (m.forward(pts + ey) - m.forward(pts - ey)) / (2 * h),
        ],
        axis=-1,
    )
    scale = np.maximum(np.abs(num), 1e-2)
    assert (np.abs(j - num) / scale).max() < 1e-6


@pytest.mark.parametrize(("model", "strength"), [("r1", 10.0), ("r2", 3.0), ("p3", 3.0)])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_inverse_round_trips_over_the_sensor_at_one_percent(model, strength, sign):
    obj, img, c = _data(model, strength=sign * strength)
    pts = mc.sensor_grid()
    disp = mc.apply_truth(model, c, pts) - pts
    r = np.hypot(*(pts - np.array(mc.CENTRE)).T)
    assert (np.hypot(*disp.T) / np.maximum(r, 1.0)).max() >= 0.009  # ~1 % distortion
    for m in (rspiv.fit_mapping(obj, img, model=model), None):
        if m is None:
            m = rspiv.fit_mapping(obj, img, model=model).rotated(-0.04)
        back = m.forward(m.inverse(pts))
        assert np.abs(back - pts).max() < 1e-6


def test_inverse_reports_points_without_a_preimage(tmp_path):
    obj, img, _ = _data("r1")
    m = rspiv.fit_mapping(obj, img, model="r1")
    doc = json.loads(m.to_json())
    doc["coefficients"] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0]  # x_i = x / (1 + x/2) < 2
    bad = rspiv.Mapping.from_json(json.dumps(doc))
    far = np.array([[bad.centre_image[0] + 2.5 * bad.scale, bad.centre_image[1]], [100.0, 50.0]])
    with pytest.raises(ConvergenceError, match="did not converge for 1 of 2"):
        bad.inverse(far)
    nan_row = np.array([[np.nan, 1.0], [100.0, 50.0]])
    masked = bad.inverse(nan_row)  # NaN in, NaN out, no error
    assert np.isnan(masked[0]).all() and np.isfinite(masked[1]).all()
    assert np.isnan(bad.forward(nan_row)[0]).all()
    out = bad.inverse(far, on_fail="nan")
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()
    np.testing.assert_allclose(bad.forward(out[1:]), far[1:], atol=1e-6)


def test_rotation_is_applied_after_the_model():
    obj, img, _ = _data("p3", noise=0.05)
    m = rspiv.fit_mapping(obj, img, model="p3")
    theta = 0.04
    r = m.rotated(theta)
    assert r.rotation == pytest.approx(np.deg2rad(theta))
    assert m.rotation == 0.0  # immutable
    pts = mc.sensor_grid(9, 6)
    ci = np.asarray(m.centre_image)
    t = np.deg2rad(theta)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    expect = ci + (m.forward(pts) - ci) @ rot.T
    np.testing.assert_allclose(r.forward(pts), expect, atol=1e-9)
    np.testing.assert_allclose(
        r.rotated(0.01).forward(pts), m.rotated(0.05).forward(pts), atol=1e-9
    )


@pytest.mark.parametrize("model", MODELS)
def test_save_load_round_trip(tmp_path, model):
    obj, img, _ = _data(model, noise=0.05)
    m = rspiv.fit_mapping(obj, img, model=model).rotated(-0.04)
    path = tmp_path / "mapping.json"
    m.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["mapping.json"]  # no temp files left
    doc = json.loads(path.read_text())
    assert doc["format"] == "rspiv-mapping" and doc["version"] == 1
    for key in ("model", "coefficients", "centre_object", "centre_image", "scale", "rotation"):
        assert key in doc
    assert {"stats", "covariance", "residuals"} <= doc.keys()
    back = rspiv.Mapping.load(path)
    np.testing.assert_array_equal(back.coefficients, m.coefficients)
    np.testing.assert_array_equal(back.covariance, m.covariance)
    np.testing.assert_array_equal(back.residuals, m.residuals)
    assert back.rotation == m.rotation and back.scale == m.scale and back.stats == m.stats
    pts = mc.sensor_grid(9, 6)
    np.testing.assert_array_equal(back.forward(pts), m.forward(pts))


def test_center_and_scale_follow_the_paper_by_default():
    obj, img, _ = _data("p3")
    m = rspiv.fit_mapping(obj, img)
    k = 45  # the middle marker of the 13 x 7 grid
    assert m.centre_object == tuple(obj[k]) and m.centre_image == tuple(img[k])
    assert m.scale == np.abs(obj[:, 0]).max()
    m2 = rspiv.fit_mapping(obj, img, center_index=0, scale=1000.0)
    assert m2.centre_object == tuple(obj[0]) and m2.scale == 1000.0
    pts = mc.sensor_grid(9, 6)
    np.testing.assert_allclose(m2.forward(pts), m.forward(pts), atol=1e-6)


# -- bad input ----------------------------------------------------------------------------------


def _bad_cases():
    obj, img, _ = _data("p3")
    dup = obj.copy()
    dup[10] = dup[3]
    nan = img.copy()
    nan[4, 0] = np.nan
    inf = obj.copy()
    inf[2, 1] = np.inf
    line = np.column_stack([np.arange(91.0), 2 * np.arange(91.0) + 1])
    return [
        ("few points", (obj[:10], img[:10], "p3"), "needs at least 11 points"),
        ("few points r2", (obj[:8], img[:8], "r2"), "needs at least 9 points"),
        ("nan", (obj, nan, "r2"), "not finite"),
        ("inf", (inf, img, "r1"), "not finite"),
        ("duplicate", (dup, img, "p3"), "coincide"),
        ("collinear", (line, img, "p3"), "collinear"),
        ("shape mismatch", (obj, img[:90], "p3"), "same shape"),
        ("not (N, 2)", (obj[:, :1], img[:, :1], "p3"), "shape \\(n, 2\\)"),
        ("3 columns", (np.ones((20, 3)), np.ones((20, 3)), "p3"), "shape \\(n, 2\\)"),
        ("unknown model", (obj, img, "p4"), "unknown mapping model"),
        ("strings", ([["a", "b"]] * 12, img[:12], "p3"), "not an array of numbers"),
        ("three rows only", (obj[:39], img[:39], "p3"), "degenerate"),
    ]


@pytest.mark.parametrize(("name", "args", "msg"), _bad_cases(), ids=lambda v: str(v)[:20])
def test_bad_input_raises_invalid_input_error(name, args, msg):
    with pytest.raises(InvalidInputError, match=msg) as exc:
        rspiv.fit_mapping(args[0], args[1], model=args[2])
    assert isinstance(exc.value, ValueError)
    assert "\n" not in str(exc.value)


def test_bad_options_raise_invalid_input_error():
    obj, img, _ = _data("p3")
    with pytest.raises(InvalidInputError, match="out of range"):
        rspiv.fit_mapping(obj, img, center_index=91)
    with pytest.raises(InvalidInputError, match="scale"):
        rspiv.fit_mapping(obj, img, scale=-1.0)
    m = rspiv.fit_mapping(obj, img)
    with pytest.raises(InvalidInputError, match="shape"):
        m.forward(np.ones(4))
    with pytest.raises(InvalidInputError, match="on_fail"):
        m.inverse(obj, on_fail="ignore")


@pytest.mark.parametrize(
    ("content", "msg"),
    [
        ("{not json", "not valid JSON"),
        ('{"type": "FeatureCollection", "features": []}', "not an rspiv mapping"),
        ("[1, 2, 3]", "not an rspiv mapping"),
        ('{"format": "rspiv-mapping", "version": 7}', "unsupported format version 7"),
        ('{"format": "rspiv-mapping", "version": 1, "model": "p3"}', "missing field"),
    ],
)
def test_corrupt_or_foreign_json_is_rejected(tmp_path, content, msg):
    path = tmp_path / "m.json"
    path.write_text(content)
    with pytest.raises(InvalidInputError, match=msg) as exc:
        rspiv.Mapping.load(path)
    assert str(path) in str(exc.value)


def test_truncated_and_binary_files_are_rejected(tmp_path):
    obj, img, _ = _data("r2")
    text = rspiv.fit_mapping(obj, img, model="r2").to_json()
    (tmp_path / "t.json").write_text(text[: len(text) // 2])
    with pytest.raises(InvalidInputError, match="not valid JSON"):
        rspiv.Mapping.load(tmp_path / "t.json")
    (tmp_path / "b.json").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(InvalidInputError):
        rspiv.Mapping.load(tmp_path / "b.json")
    doc = json.loads(text)
    doc["coefficients"] = doc["coefficients"][:-1]
    with pytest.raises(InvalidInputError, match="needs 17 coefficients"):
        rspiv.Mapping.from_json(json.dumps(doc))
