"""Dewarping images through a fitted mapping (rspiv.dewarp, Method I)."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.dewarp import dewarp, remap
from rspiv.errors import InvalidInputError
from rspiv.synth import paper_lens
from rspiv.synth.target import PAPER_OPTICS

H, W = 120, 200


def _lens_poly(p):
    """An exact cubic map (object px -> image px): pincushion ~2 px at the corners, a shear and
    a shift; P3 reproduces it exactly."""
    x, y = p[:, 0], p[:, 1]
    u, v = (x - 100.0) / 100.0, (y - 60.0) / 100.0
    r2 = u * u + v * v
    return np.column_stack(
        [x + 0.4 + 1.5 * u * r2 + 0.2 * u * v, y - 0.3 + 1.5 * v * r2 + 0.1 * u * u]
    )


@pytest.fixture(scope="module")
def mapping():
    gx, gy = np.meshgrid(np.linspace(4, W - 5, 13), np.linspace(4, H - 5, 7))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    return rspiv.fit_mapping(obj, _lens_poly(obj), "p3")


def _scene(x, y):
    return (
        800.0
        + 250.0 * np.sin(2 * np.pi * x / 37.0)
        + 150.0 * np.cos(2 * np.pi * (x - 2 * y) / 53.0)
        + 300.0 * np.exp(-((x - 90.0) ** 2 + (y - 50.0) ** 2) / (2 * 14.0**2))
    )


def _pixels(h, w):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.column_stack([xx.ravel(), yy.ravel()])


def test_fitted_mapping_is_the_exact_polynomial(mapping):
    pts = _pixels(H, W)
    np.testing.assert_allclose(mapping.forward(pts), _lens_poly(pts), atol=1e-8)


def test_dewarp_equals_remap_through_the_mapping(mapping, rng):
    img = rng.uniform(0, 4000, (H, W)).astype(np.float32)
    src = mapping.forward(_pixels(H, W))
    ref = remap(img, src[:, 0].reshape(H, W), src[:, 1].reshape(H, W))
    exact = dewarp(img, mapping, sampling="exact")
    np.testing.assert_allclose(exact, ref, atol=1e-2)
    # The coarse grid moves source positions by <= 1e-3 px; a random image has gradients up
    # to ~1e4 counts/px through the kernel: differences stay within 1e-3 * 1.5e4.
    auto = dewarp(img, mapping)
    assert np.max(np.abs(auto - ref)) < 15.0
    assert np.median(np.abs(auto - ref)) < 1.0
    # JSON text and a Calibration-like object give the same.
    np.testing.assert_array_equal(dewarp(img, mapping.to_json(), sampling="exact"), exact)

    class Cal:
        pass

    cal = Cal()
    cal.mapping = mapping
    cal.image_shape = (H - 10, W - 20)
    out = dewarp(img, cal, sampling="exact")
    assert out.shape == (H - 10, W - 20)
    # Same values up to float32 rounding (pixels may fall in a SIMD lane or the scalar tail).
    np.testing.assert_allclose(out, exact[: H - 10, : W - 20], rtol=1e-6, atol=1e-3)


def test_dewarp_recovers_the_undistorted_scene(mapping):
    # The recorded image of the scene g: I(q) = g(F^-1(q)); dewarping gives g back.
    obj = mapping.inverse(_pixels(H, W))
    recorded = _scene(obj[:, 0], obj[:, 1]).reshape(H, W).astype(np.float32)
    out = dewarp(recorded, mapping)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    inner = (slice(6, H - 6), slice(6, W - 6))
    err = np.abs(out - _scene(xx, yy))[inner]
    # Keys' third-order error for wavelengths >= 37 px and the scene's gradients: < 0.2 counts.
    assert err.max() < 0.2
    # Without the correction the scene is off by the distortion (up to ~2 px of ~50 counts/px).
    assert np.abs(recorded - _scene(xx, yy))[inner].max() > 20


def test_rotated_mapping_and_callable_mapping(mapping, rng):
    img = rng.uniform(0, 4000, (H, W)).astype(np.float32)
    rot = mapping.rotated(0.5)
    src = rot.forward(_pixels(H, W))
    ref = remap(img, src[:, 0].reshape(H, W), src[:, 1].reshape(H, W))
    np.testing.assert_allclose(dewarp(img, rot, sampling="exact"), ref, atol=1e-2)
    # A callable on (N, 2) arrays, e.g. a lens model's distort.
    lens = paper_lens(PAPER_OPTICS.scaled(0.05))
    out = dewarp(img, lens.distort)
    src = lens.distort(_pixels(H, W))
    np.testing.assert_array_equal(out, remap(img, src[:, 0].reshape(H, W), src[:, 1].reshape(H, W)))
    assert np.array_equal(dewarp(img, lens), out)


def test_uint16_output_and_zero_fill(mapping):
    img = np.full((H, W), 1234, np.uint16)
    out = dewarp(img, mapping, out_dtype="uint16", output_shape=(H + 20, W + 20))
    assert out.dtype == np.uint16 and out.shape == (H + 20, W + 20)
    src = mapping.forward(_pixels(H + 20, W + 20))
    inside = (
        (src[:, 0] >= -0.5) & (src[:, 0] <= W - 0.5) & (src[:, 1] >= -0.5) & (src[:, 1] <= H - 0.5)
    ).reshape(H + 20, W + 20)
    # A constant image stays constant inside (partition of unity), zero outside. Pixels within
    # 1e-3 px of the footprint's edge may fall either way under the coarse map grid.
    src = src.reshape(H + 20, W + 20, 2)
    sx, sy = src[..., 0], src[..., 1]
    edges = [np.abs(sx + 0.5), np.abs(sx - W + 0.5), np.abs(sy + 0.5), np.abs(sy - H + 0.5)]
    margin = np.minimum.reduce(edges)
    sure = margin > 2e-3
    assert np.all(out[inside & sure] == 1234)
    assert np.all(out[~inside & sure] == 0)


def test_invalid_arguments(mapping):
    img = np.zeros((10, 10), np.uint16)
    with pytest.raises(InvalidInputError):
        dewarp(img, mapping, kernel="lanczos")
    with pytest.raises(InvalidInputError):
        dewarp(img, 42)
    with pytest.raises(InvalidInputError):
        dewarp(img, mapping, output_shape=(0, 3))
    with pytest.raises(InvalidInputError):
        dewarp(img, mapping, sampling="nearest")
    with pytest.raises(InvalidInputError):
        dewarp(img, "{not json")


def test_cli_dewarp_and_wall(tmp_path, capsys):
    import tifffile
    from rspiv.calibration import calibrate
    from rspiv.cli import main
    from rspiv.synth import calibration_target, tbl_pair

    scale = 0.15
    tgt = calibration_target(scale=scale, seed=0)
    cal = calibrate(tgt.image, pitch_mm=19.51)
    cal_path = tmp_path / "calib.json"
    cal.save(cal_path)
    a, b, t = tbl_pair(scale=scale, seed=0, lens=tgt.lens)
    tifffile.imwrite(tmp_path / "a.tif", a)
    tifffile.imwrite(tmp_path / "b.tif", b)
    out = tmp_path / "out"
    out.mkdir()
    rc = main(["dewarp", str(cal_path), str(tmp_path / "a.tif"), str(tmp_path / "b.tif"),
               "-o", str(out), "--dtype", "uint16"])  # fmt: skip
    assert rc == 0
    got = tifffile.imread(out / "a.tif")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, dewarp(a, cal.mapping, out_dtype="uint16"))
    # The raw frames, dewarped by the command itself.
    rot = str(tmp_path / "rot.json")
    rc = main(["wall", str(tmp_path / "a.tif"), str(tmp_path / "b.tif"), "--band",
               str(t.wall_y0_px - 40), str(t.wall_y0_px + 30), "--stations", "6",
               "--calibration", str(cal_path), "--write-rotated", rot,
               "--figure", str(tmp_path / "wall.png")])  # fmt: skip
    assert rc == 0
    assert (tmp_path / "wall.png").stat().st_size > 0
    text = capsys.readouterr().out
    assert "angle" in text and "max deviation" in text
    assert rspiv.Calibration.load(rot).mapping.rotation != 0.0
    # Errors exit with status 2 and one line.
    assert main(["dewarp", str(cal_path), str(tmp_path / "missing.tif"), "-o", str(out)]) == 2


def test_engine_dewarp_matches_python(engine, mapping, tmp_path, rng):
    import subprocess

    import tifffile

    img = rng.integers(0, 4096, (H, W), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "frame.tif", img)
    mpath = tmp_path / "m.json"
    mapping.save(mpath)
    out = tmp_path / "out"
    out.mkdir()
    r = subprocess.run([engine, "dewarp", str(mpath), str(tmp_path / "frame.tif"), "-o",
                        str(out), "--rotation", "0.3"], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    got = tifffile.imread(out / "frame.tif")
    want = dewarp(img, mapping.rotated(0.3), out_dtype="uint16")
    assert got.dtype == np.uint16 and got.shape == (H, W)
    # Same kernel and map; uint16 rounding may differ by one count where the float value sits
    # at a half (SIMD lane vs scalar tail).
    assert np.max(np.abs(got.astype(int) - want.astype(int))) <= 1
    r = subprocess.run([engine, "dewarp", str(mpath), str(tmp_path / "nope.tif"), "-o", str(out)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and "nope.tif" in r.stderr
