"""The standalone engine corrects as the Python API does: ``rspiv-engine piv --calibration
cal.json --method I|II`` against ``rspiv.correction.method_one/method_two`` on the same pair
(particles imaged through a known lens, 16-bit TIFF files), to 1e-9 px; and the native Method II
path against its composition from the native pieces (PIV at the image points, displacements
mapped back through the inverse)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import rspiv
import tifffile
from lens_cases import frames_through, p3_mapping, strong_lens
from rspiv.correction import grid_for_windows, map_displacements, method_one, method_two
from rspiv.multipass import run_final_points

SHAPE = (320, 480)  # (h, w)
D_OBJ = (7.0, 1.5)  # uniform object displacement, px
SETTINGS = rspiv.PivSettings(passes=((64, 64), (32, 32), (32, 16)), deformation="symmetric")


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The lens, its P3 mapping (saved as JSON) and a particle pair imaged through it (TIFF)."""
    lens = strong_lens(SHAPE)
    mapping = p3_mapping(lens, SHAPE)
    frames = frames_through(lens, SHAPE, D_OBJ, seed=3, render_seed=21)
    d = tmp_path_factory.mktemp("engine_m2")
    tifffile.imwrite(d / "a.tif", frames[0])
    tifffile.imwrite(d / "b.tif", frames[1])
    mapping.save(d / "cal.json")
    (d / "piv.json").write_text(SETTINGS.to_json())
    return d, mapping, frames[0], frames[1]


def _engine_field(engine, d, *extra):
    out = d / f"out{'_'.join(extra)}.csv"
    cmd = [engine, "piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out)]
    cmd += ["--settings", str(d / "piv.json"), "--calibration", str(d / "cal.json"), *extra]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return np.genfromtxt(out, delimiter=",", names=True)


def _same(data, f, tol=1e-9):
    np.testing.assert_array_equal(data["x"], f.x.ravel())
    np.testing.assert_array_equal(data["y"], f.y.ravel())
    np.testing.assert_array_equal(data["masked"].astype(bool), f.masked.ravel())
    np.testing.assert_array_equal(data["valid"].astype(bool), f.valid.ravel())
    for k in ("u", "v"):
        got, want = data[k], getattr(f, k).ravel()
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        ok = ~np.isnan(want)
        assert np.max(np.abs(got[ok] - want[ok])) <= tol


@pytest.mark.parametrize("mode", ["full", "positions"])
def test_engine_method_two_equals_the_api(case, engine, mode):
    d, mapping, a, b = case
    data = _engine_field(engine, d, "--method", "II", "--mapping", mode)
    f = method_two(a, b, mapping, SETTINGS, mapping=mode)
    _same(data, f)
    # and the API's field is right: the uniform object displacement, valid away from the edges
    # (where the distortion pushes windows past the sensor)
    assert f.valid[1:-1, 1:-1].mean() > 0.95
    if mode == "full":
        assert np.nanmax(np.abs(f.u[f.valid] - D_OBJ[0])) < 0.15
        assert np.nanmax(np.abs(f.v[f.valid] - D_OBJ[1])) < 0.15


def test_engine_method_one_equals_the_api(case, engine):
    d, mapping, a, b = case
    data = _engine_field(engine, d, "--method", "images")
    f = method_one(a, b, mapping, SETTINGS)
    _same(data, f)
    assert np.nanmedian(np.abs(f.u[f.valid] - D_OBJ[0])) < 0.05


def test_native_method_two_equals_its_composition(case):
    """correction_core::method_two against the pieces it is made of, composed in Python as
    before the move: the object grid, its image points, the raw-frame PIV at them and the
    displacements mapped back through the inverse (1e-12 px)."""
    _, mapping, a, b = case
    f = method_two(a, b, mapping, SETTINGS)
    gx, gy = grid_for_windows(SHAPE, SETTINGS.final_window, SETTINGS.overlaps[-1])
    np.testing.assert_array_equal(f.x, gx)
    np.testing.assert_array_equal(f.y, gy)
    img = mapping.forward(np.column_stack([gx.ravel(), gy.ravel()]))
    raw = run_final_points(a, b, img.reshape(gx.shape + (2,)), SETTINGS)
    dob = map_displacements(mapping, img, np.column_stack([raw.u.ravel(), raw.v.ravel()]))
    masked = raw.masked | ~np.all(np.isfinite(dob), axis=1).reshape(gx.shape)
    np.testing.assert_array_equal(f.masked, masked)
    np.testing.assert_array_equal(f.valid, raw.valid & ~masked)
    ok = ~masked.ravel()
    assert np.max(np.abs(f.u.ravel()[ok] - dob[ok, 0])) <= 1e-12
    assert np.max(np.abs(f.v.ravel()[ok] - dob[ok, 1])) <= 1e-12
    np.testing.assert_array_equal(f.peak_ratio, raw.peak_ratio)


def test_engine_bad_input_is_one_line(case, engine, tmp_path):
    d, _, _, _ = case
    out = tmp_path / "o.csv"
    base = [engine, "piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out)]
    for extra, says in [
        (["--method", "II"], "--method needs --calibration"),
        (["--calibration", str(d / "cal.json"), "--method", "III"], 'method "III"'),
        (["--calibration", str(d / "cal.json"), "--mapping", "half"], 'mapping "half"'),
        (["--calibration", str(d / "nope.json")], "nope.json"),
        (["--deformation", "warp"], '--deformation "warp"'),
        (["--overlap", "1.0"], "overlap 1 is outside [0, 1)"),
    ]:
        r = subprocess.run(base + extra, capture_output=True, text=True)
        assert r.returncode == 2, (extra, r.stderr)
        assert says in r.stderr and r.stderr.count("\n") == 1, (extra, r.stderr)
        assert not out.exists()


def test_a_duck_typed_mapping_takes_the_composed_path_with_the_same_result(case):
    """An object with forward/inverse that is not an rspiv Mapping (e.g. a user's lens model)
    still works: Method II composes the same native pieces in Python."""
    _, mapping, a, b = case

    class Duck:
        def forward(self, pts):
            return mapping.forward(pts)

        def inverse(self, pts, on_fail="raise"):
            return mapping.inverse(pts, on_fail=on_fail)

    f = method_two(a, b, mapping, SETTINGS)
    g = method_two(a, b, Duck(), SETTINGS)
    np.testing.assert_array_equal(f.masked, g.masked)
    ok = ~f.masked
    assert np.max(np.abs(f.u[ok] - g.u[ok])) <= 1e-12
    assert np.max(np.abs(f.v[ok] - g.v[ok])) <= 1e-12
