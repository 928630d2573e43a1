"""Calibration from a synthetic target: marker accuracy and sigma, the mapping against the true
distortion, model choice, grid indexing, files, and bad input."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import rspiv
from rspiv.calibration import Calibration, calibrate
from rspiv.errors import InvalidInputError
from rspiv.synth import PAPER_OPTICS, calibration_target, paper_lens

PITCH = 19.51


def _match(cal_px, true_px):
    d = np.hypot(*(cal_px[:, None, :] - true_px[None, :, :]).transpose(2, 0, 1))
    return d.argmin(axis=1)


def _truth_rms_full_sensor(tg, cal):
    """RMS (px) of calibrated mapping minus true mapping over the whole sensor."""
    o = tg.optics
    xs, ys = np.meshgrid(np.linspace(0, o.width - 1, 61), np.linspace(0, o.height - 1, 37))
    ideal = np.column_stack([xs.ravel(), ys.ravel()])
    c0 = tg.ideal_px([[0, 0]])[0]
    basis = np.column_stack([tg.ideal_px([[1, 0]])[0] - c0, tg.ideal_px([[0, 1]])[0] - c0])
    ij = np.linalg.solve(basis, (ideal - c0).T).T  # continuous grid coordinates
    true = tg.true_image_px(ij)
    mk = cal.markers
    obj = mk.object_px[mk.centre] + cal.magnification * cal.pitch_mm * ij
    pred = cal.mapping.forward(obj)
    return float(np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1))))


@pytest.fixture(scope="module")
def half_scale():
    """The paper's optics at half scale (4432 x 2644 px, M = 17.27 px/mm), 12-bit noise."""
    tg = calibration_target(scale=0.5, seed=11)
    return tg, calibrate(tg.image, PITCH, model="p3")


def test_markers_within_003px_and_sigma_honest(half_scale):
    # Claim checked at scale 0.5 (same relative distortion, dots and 12-bit noise as the full
    # sensor; the blob centre precision does not depend on the scale) over 2 noise seeds.
    errs, sigs = [], []
    for tg, cal in (
        half_scale,
        _second := (lambda t: (t, calibrate(t.image, PITCH, compare=False)))(
            calibration_target(scale=0.5, seed=12)
        ),
    ):
        assert len(cal.markers) == 91
        k = _match(cal.markers.image_px, tg.markers_px)
        assert len(set(k.tolist())) == 91
        errs.append(cal.markers.image_px - tg.markers_px[k])
        sigs.append(cal.markers.sigma_px)
    err = np.concatenate(errs)
    sig = np.concatenate(sigs)
    rms_err = float(np.sqrt(np.mean(err**2)))
    rms_sig = float(np.sqrt(np.mean(sig**2)))
    assert rms_err < 0.03
    assert 1 / 1.5 < rms_sig / rms_err < 1.5, (rms_sig, rms_err)
    # Per axis, normalised errors are O(1): the sigma is honest marker by marker too.
    z = err / sig
    assert 0.6 < float(np.std(z)) < 1.5


def test_p3_matches_true_mapping_over_full_sensor(half_scale):
    tg, cal = half_scale
    assert not tg.lens.is_radial  # the paper lens has a decentring term
    assert _truth_rms_full_sensor(tg, cal) <= 0.05
    # Magnification and geometry as configured.
    assert abs(cal.magnification - tg.optics.magnification) / tg.optics.magnification < 2e-3
    assert cal.image_shape == tg.image.shape
    r = cal.report()
    assert r["n_markers"] == 91 and set(r["models"]) == {"r1", "r2", "p3"}
    assert "p3" in str(r) and "held-out" in str(r)


def test_p3_beats_r2_when_distortion_not_radially_symmetric():
    o = PAPER_OPTICS.scaled(0.5)
    base = paper_lens(o)
    lens = dataclasses.replace(base, ka=0.3 * base.k1)  # anisotropic radial term
    tg = calibration_target(scale=0.5, seed=4, lens=lens)
    cal = calibrate(tg.image, PITCH, model="auto")
    m = cal.models
    assert m["p3"]["loo_rms_px"] < 0.5 * m["r2"]["loo_rms_px"]
    assert m["r2"]["loo_rms_px"] < m["r1"]["loo_rms_px"]
    assert cal.model == "p3" and "held-out" in cal.model_reason
    assert _truth_rms_full_sensor(tg, cal) <= 0.05


def test_grid_survives_missing_spurious_and_rotation():
    tg = calibration_target(
        scale=0.25, seed=8, rotation_deg=2.0, missing=[(1, 0), (-4, 2), (6, -3)], spurious=5
    )
    cal = calibrate(tg.image, PITCH, model="p3", compare=False)
    assert cal.n_detected >= 88
    assert len(cal.markers) == 88
    k = _match(cal.markers.image_px, tg.markers_px)
    assert np.max(np.hypot(*(cal.markers.image_px - tg.markers_px[k]).T)) < 0.1
    # Indices agree with the truth (both have (0, 0) at the centre marker).
    np.testing.assert_array_equal(cal.markers.index, tg.index[k])
    assert _truth_rms_full_sensor(tg, cal) <= 0.05


def test_save_load_roundtrip_and_rotation(half_scale, tmp_path):
    _, cal = half_scale
    p = tmp_path / "calib.json"
    cal.save(p)
    back = Calibration.load(p)
    np.testing.assert_array_equal(back.markers.image_px, cal.markers.image_px)
    np.testing.assert_array_equal(back.markers.index, cal.markers.index)
    assert back.image_shape == cal.image_shape and back.model == cal.model
    pts = cal.markers.object_px[:5]
    np.testing.assert_allclose(back.mapping.forward(pts), cal.mapping.forward(pts), atol=1e-9)
    rot = cal.with_rotation(0.04)
    assert rot.mapping.rotation == pytest.approx(np.deg2rad(0.04))
    assert cal.mapping.rotation == 0.0
    assert [f.name for f in tmp_path.iterdir()] == ["calib.json"]  # no temp files left


def test_bad_input(tmp_path, half_scale):
    tg, _ = half_scale
    blank = np.full((400, 600), 200, np.uint16)
    with pytest.raises(InvalidInputError):
        calibrate(blank, PITCH)
    # Blobs without a grid.
    rng = np.random.default_rng(1)
    pts = rng.uniform([20, 20], [580, 380], size=(25, 2))
    noise_img = rspiv._rspiv.render_target(400, 600, pts, np.full(25, 3.0), np.full(25, 2000.0))
    with pytest.raises(InvalidInputError):
        calibrate(noise_img, PITCH)
    small = calibration_target(scale=0.25, seed=1)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInputError):
            calibrate(small.image, bad)
    # Too few markers for the model: a crop holding 3 x 3 markers (P3 needs 11).
    c = small.markers_px[45]
    step = small.optics.magnification * PITCH
    y0, y1 = int(c[1] - 1.5 * step), int(c[1] + 1.5 * step)
    x0, x1 = int(c[0] - 1.5 * step), int(c[0] + 1.5 * step)
    crop = np.ascontiguousarray(small.image[y0:y1, x0:x1])
    with pytest.raises(InvalidInputError, match="needs at least"):
        calibrate(crop, PITCH, model="p3")
    with pytest.raises(InvalidInputError):
        calibrate(small.image, PITCH, model="p7")
    # Unreadable and truncated files.
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"not an image at all")
    with pytest.raises(InvalidInputError, match="junk.tif"):
        calibrate(junk, PITCH)
    import tifffile

    good = tmp_path / "t.tif"
    tifffile.imwrite(good, small.image)
    data = good.read_bytes()
    trunc = tmp_path / "trunc.tif"
    trunc.write_bytes(data[: len(data) // 3])
    with pytest.raises(InvalidInputError, match="trunc.tif"):
        calibrate(trunc, PITCH)
    with pytest.raises(InvalidInputError):
        calibrate(tmp_path / "missing.tif", PITCH)
    cal = calibrate(good, PITCH, compare=False)  # a path works
    assert len(cal.markers) == 91
    bad_json = tmp_path / "bad.json"
    bad_json.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(InvalidInputError):
        Calibration.load(bad_json)
    bad_json.write_text("{ truncated")
    with pytest.raises(InvalidInputError):
        Calibration.load(bad_json)
