"""Calibration from given marker positions (``rspiv.calibrate_points``): the same path as
``calibrate`` after detection, the lattice ``calibrate`` reports, the refusal of poor fits, the
warnings and their file round trip, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rspiv
from rspiv.calibration import Calibration, calibrate, calibrate_points
from rspiv.errors import InvalidInputError
from rspiv.synth import calibration_target

PITCH = 19.51


@pytest.fixture(scope="module")
def target():
    """A quarter-scale target (2216 x 1322 px, 91 markers), rotated 2 degrees, 4 spurious
    blobs, and its calibration from the image."""
    tg = calibration_target(scale=0.25, seed=31, rotation_deg=2.0, spurious=4)
    return tg, calibrate(tg.image, PITCH, model="auto")


def _sensor_points(shape, n=(41, 23)):
    """A regular grid of object px over the sensor (for comparing mappings everywhere)."""
    h, w = shape
    xs, ys = np.meshgrid(np.linspace(0, w - 1, n[0]), np.linspace(0, h - 1, n[1]))
    return np.column_stack([xs.ravel(), ys.ravel()])


def _truth_points(tg, sigma_px, seed):
    """The target's true marker positions with Gaussian noise, and their target mm."""
    rng = np.random.default_rng(seed)
    img = tg.markers_px + rng.normal(0.0, sigma_px, tg.markers_px.shape)
    return img, PITCH * tg.index.astype(float)


def test_points_reproduce_calibrate(target):
    tg, cal = target
    mk = cal.markers
    assert cal.model in ("r2", "p3") and cal.warnings == []
    pts = calibrate_points(
        mk.image_px,
        PITCH * mk.index,
        cov_px2=mk.cov_px2,
        image_shape=cal.image_shape,
        model="auto",
        pitch_mm=PITCH,
    )
    assert pts.markers.centre == mk.centre  # the marker nearest the image centre
    np.testing.assert_array_equal(pts.markers.index, mk.index)
    np.testing.assert_allclose(pts.markers.object_px, mk.object_px, rtol=0, atol=1e-9)
    grid = _sensor_points(cal.image_shape)
    np.testing.assert_allclose(
        pts.mapping.forward(grid), cal.mapping.forward(grid), rtol=0, atol=1e-9
    )
    assert pts.model == cal.model and pts.model_reason == cal.model_reason
    assert pts.magnification == pytest.approx(cal.magnification, rel=1e-14)
    assert pts.magnification_sigma == pytest.approx(cal.magnification_sigma, rel=1e-9)
    assert pts.object_sigma_px == pytest.approx(cal.object_sigma_px, rel=1e-9, abs=1e-12)
    assert pts.image_sigma_px == cal.image_sigma_px
    for m in ("r1", "r2", "p3"):
        assert pts.models[m]["loo_rms_px"] == pytest.approx(cal.models[m]["loo_rms_px"], 1e-9)
    assert pts.marker == "points" and pts.lattice is None and pts.warnings == []
    assert pts.image_sigma_source == "given cov_px2"
    assert cal.image_sigma_source == "marker detector"
    # The pitch defaults to the central marker's nearest-neighbour distance on the target, and
    # the target-plane origin is free: the same calibration.
    moved = calibrate_points(
        mk.image_px,
        PITCH * mk.index + [250.0, -75.5],
        cov_px2=mk.cov_px2,
        image_shape=cal.image_shape,
        model=cal.model,
        compare=False,
    )
    assert moved.pitch_mm == pytest.approx(PITCH, rel=1e-12)
    np.testing.assert_array_equal(moved.markers.index, mk.index)
    np.testing.assert_allclose(
        moved.mapping.forward(grid), cal.mapping.forward(grid), rtol=0, atol=1e-9
    )


def test_points_from_another_tool_recover_the_true_mapping():
    # Exact marker positions plus 0.02 px noise, as another detector might report them.
    tg = calibration_target(scale=0.25, seed=5)
    img, obj = _truth_points(tg, 0.02, seed=1)
    cal = rspiv.calibrate_points(img, obj, image_shape=tg.image.shape, sigma_px=0.02)
    assert cal.model == "p3" and cal.warnings == []
    assert abs(cal.magnification / tg.optics.magnification - 1) < 1e-3
    assert cal.image_sigma_px == pytest.approx(0.02)
    # The calibrated map against the true one between the markers (half-integer grid sites).
    ij = np.array([(i + 0.5, j + 0.5) for i in range(-6, 6) for j in range(-3, 3)])
    c = cal.markers.object_px[cal.markers.centre]
    pred = cal.mapping.forward(c + cal.magnification * PITCH * ij)
    err = np.hypot(*(pred - tg.true_image_px(ij)).T)
    assert float(np.sqrt(np.mean(err**2))) < 0.03


def test_image_sigma_estimated_from_residuals_when_not_given():
    tg = calibration_target(scale=0.25, seed=5)
    img, obj = _truth_points(tg, 0.05, seed=2)
    cal = calibrate_points(img, obj, image_shape=tg.image.shape, model="p3", compare=False)
    # 91 markers, 20 coefficients: the residual estimate of a 0.05 px noise.
    assert cal.image_sigma_px == pytest.approx(0.05, rel=0.2)
    assert "residuals" in cal.image_sigma_source and cal.object_sigma_px == 0.0
    assert len(cal.warnings) == 1 and "could not be checked" in cal.warnings[0]
    assert "WARNING: the image sigma was estimated" in str(cal.report())


def test_lattice_of_a_target_image(target, tmp_path):
    tg, cal = target
    la = cal.lattice
    step = tg.optics.magnification * PITCH
    assert la["pitch_px"] == pytest.approx([step, step], rel=5e-3)
    assert la["angle_deg"] == pytest.approx(2.0, abs=0.05)
    assert la["axes_angle_deg"] == pytest.approx(90.0, abs=0.1)
    assert (la["n_indexed"], la["n_detected"], la["n_rejected"]) == (91, 95, 4)
    assert la["size_px"] == cal.size_px > 0
    # The rejected blobs are the spurious ones.
    rej = la["rejected_px"]
    d = np.hypot(*(rej[:, None, :] - tg.spurious_px[None, :, :]).transpose(2, 0, 1))
    assert sorted(d.argmin(axis=1).tolist()) == [0, 1, 2, 3] and d.min(axis=1).max() < 1.0
    line = cal.lattice_summary()
    assert "91 markers indexed of 95 detected (4 rejected)" in line
    assert f"{la['pitch_px'][0]:.2f} x {la['pitch_px'][1]:.2f} px" in line
    # Saved and loaded with the calibration.
    cal.save(tmp_path / "c.json")
    back = Calibration.load(tmp_path / "c.json")
    np.testing.assert_array_equal(back.lattice["rejected_px"], rej)
    assert back.lattice_summary() == line and back.warnings == []


def test_files_without_the_new_keys_still_load(target, tmp_path):
    # Version-1 files written before warnings/lattice/image_sigma_source (and rspiv-engine's).
    _, cal = target
    d = cal.to_dict()
    for k in ("warnings", "lattice", "image_sigma_source"):
        del d[k]
    p = tmp_path / "old.json"
    p.write_text(json.dumps(d))
    old = Calibration.load(p)
    assert old.warnings == [] and old.lattice is None
    assert old.image_sigma_source == "marker detector" and old.lattice_summary() is None
    np.testing.assert_array_equal(old.mapping.coefficients, cal.mapping.coefficients)
    d["warnings"] = "not a list"
    p.write_text(json.dumps(d))
    with pytest.raises(InvalidInputError, match="corrupt"):
        Calibration.load(p)


def test_poor_fit_refused_unless_accepted(tmp_path):
    tg = calibration_target(scale=0.25, seed=5)
    img, obj = _truth_points(tg, 0.02, seed=3)
    shape = tg.image.shape
    # Random 5 px errors on markers that claim 0.02 px: refused, saying what was seen.
    rng = np.random.default_rng(4)
    bad = img + rng.normal(0.0, 5.0, img.shape)
    with pytest.raises(InvalidInputError) as exc:
        calibrate_points(bad, obj, image_shape=shape, sigma_px=0.02, compare=False)
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1
    assert msg.startswith("calibration refused: p3 leaves ")
    assert "against a marker sigma of 0.02 px over 91 given points" in msg
    assert "accept_poor_fit=True" in msg
    kept = calibrate_points(
        bad, obj, image_shape=shape, sigma_px=0.02, compare=False, accept_poor_fit=True
    )
    rms = float(np.sqrt(np.mean(np.asarray(kept.mapping.residuals) ** 2)))
    assert 3.5 < rms < 5.0  # 5 px noise less what 20 coefficients absorb
    assert f"p3 leaves {rms:.3g} px RMS residuals" in msg
    assert len(kept.warnings) == 1 and kept.warnings[0].startswith("poor fit kept")
    assert "WARNING: poor fit kept" in str(kept.report())
    kept.save(tmp_path / "kept.json")
    assert Calibration.load(tmp_path / "kept.json").warnings == kept.warnings
    # A smooth field no cubic follows (a 3 px wave of 1.5 pitches): refused too.
    step = tg.optics.magnification * PITCH
    wave = img + 3.0 * np.sin(2 * np.pi * img[:, ::-1] / (1.5 * step))
    with pytest.raises(InvalidInputError, match="calibration refused: p3"):
        calibrate_points(wave, obj, image_shape=shape, sigma_px=0.02, compare=False)
    # Noise 5x the stated sigma (0.1 px against 0.02 px): kept, with a warning.
    loose = calibrate_points(
        img + rng.normal(0.0, 0.1, img.shape), obj, image_shape=shape, sigma_px=0.02
    )
    assert len(loose.warnings) == 1 and "x the sigma" in loose.warnings[0]
    ratio = float(loose.warnings[0].split(" x the sigma")[0].rsplit(" ", 1)[1])
    assert 3.0 < ratio < 6.0


def test_too_few_points_for_the_model():
    tg = calibration_target(scale=0.25, seed=5)
    img, obj = _truth_points(tg, 0.02, seed=6)
    block = (np.abs(tg.index[:, 0]) <= 2) & np.isin(tg.index[:, 1], [0, 1])  # 5 x 2 markers
    assert block.sum() == 10
    with pytest.raises(InvalidInputError) as exc:
        calibrate_points(img[block], obj[block], image_shape=tg.image.shape, sigma_px=0.02)
    assert str(exc.value) == "calibration: model p3 needs at least 11 points, 10 were given"
    r1 = calibrate_points(
        img[block], obj[block], image_shape=tg.image.shape, sigma_px=0.02, model="r1"
    )
    assert len(r1.markers) == 10 and r1.model == "r1"
    with pytest.raises(InvalidInputError, match="no model can be fitted to 4 given points"):
        calibrate_points(img[:4], obj[:4], image_shape=tg.image.shape, model="auto")


def test_bad_points_named():
    tg = calibration_target(scale=0.25, seed=5)
    img, obj = _truth_points(tg, 0.02, seed=7)
    shape = tg.image.shape

    def refused(match, im=img, ob=obj, **kw):
        kw.setdefault("image_shape", shape)
        with pytest.raises(InvalidInputError, match=match) as exc:
            calibrate_points(im, ob, **kw)
        assert len(str(exc.value).splitlines()) == 1

    nan = img.copy()
    nan[7, 1] = np.nan
    refused(r"image_px\[7\] = \(.*, nan\) is not finite \(1 such rows of 91\)", im=nan)
    inf = obj.copy()
    inf[3, 0] = np.inf
    refused(r"object_mm\[3\] = \(inf, .*\) is not finite", ob=inf)
    refused(r"image_px must have shape \(n, 2\), got \(91, 3\)", im=np.zeros((91, 3)))
    refused("image_px has 91 rows and object_mm 90", ob=obj[:90])
    refused(r"image_px\[.*\] = .* lies outside the 1322 x 2216 px image", image_shape=shape[::-1])
    for bad_shape in ((0, 100), (1322.0, 2216), (1322,), "1322x2216", (True, 5)):
        refused("image_shape must be", image_shape=bad_shape)
    dup = obj.copy()
    dup[10] = dup[11]
    refused(r"object_mm rows 10 and 11 are the same point", ob=dup)
    refused("give cov_px2 or sigma_px, not both", cov_px2=np.tile(np.eye(2), (91, 1, 1)),
            sigma_px=0.1)  # fmt: skip
    refused(r"sigma_px\[0\] = 0.0 must be > 0", sigma_px=0.0)
    refused("sigma_px must be a number or 91 numbers", sigma_px=np.ones(5))
    cov = np.tile(np.eye(2) * 1e-4, (91, 1, 1))
    cov[12] = [[1e-4, 2e-4], [2e-4, 1e-4]]  # not positive definite
    refused(r"cov_px2\[12\] = .* is not a symmetric positive definite", cov_px2=cov)
    refused(r"cov_px2 must have shape \(91, 2, 2\)", cov_px2=np.ones((91, 2)))
    refused("centre 91 is out of range for 91 points", centre=91)
    refused("pitch_mm must be > 0", pitch_mm=-1.0)
    refused("unknown model 'p4'", model="p4")
