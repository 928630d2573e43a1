"""`rspiv piv` command, image reading and the engine binary's `piv`."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import rspiv
import tifffile
import xarray as xr
from rspiv.cli import main
from rspiv.io import read_image, read_pair
from rspiv.synth import particle_pair


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("piv")
    a, b = particle_pair((128, 192), (2.5, -1.0), seed=21)
    tifffile.imwrite(d / "a.tif", a)
    tifffile.imwrite(d / "b.tif", b)
    tifffile.imwrite(d / "ab.tif", np.stack([a, b]))
    from PIL import Image

    Image.fromarray((a >> 4).astype(np.uint8)).save(d / "a.png")
    return d, a, b


def test_read_image_formats(pair_files):
    d, a, b = pair_files
    np.testing.assert_array_equal(read_image(d / "a.tif"), a)
    ra, rb = read_pair(d / "ab.tif")
    np.testing.assert_array_equal(ra, a)
    np.testing.assert_array_equal(rb, b)
    png = read_image(d / "a.png")
    assert png.dtype == np.uint8 and png.shape == a.shape
    with pytest.raises(rspiv.InvalidInputError, match="no such file"):
        read_image(d / "missing.tif")
    (d / "bad.tif").write_bytes(b"not a tiff")
    with pytest.raises(rspiv.InvalidInputError, match="bad.tif"):
        read_image(d / "bad.tif")
    with pytest.raises(rspiv.InvalidInputError, match="frame 2"):
        read_image(d / "ab.tif", frame=2)


def test_cli_piv_writes_netcdf(pair_files, tmp_path):
    d, a, b = pair_files
    out = tmp_path / "field.nc"
    rc = main(
        ["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--passes", "64x64,32x32"]
    )
    assert rc == 0 and out.exists()
    ds = xr.load_dataset(out, engine="h5netcdf")
    assert float(np.abs(ds.u - 2.5).median()) < 0.05
    assert float(np.abs(ds.v + 1.0).median()) < 0.05
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--passes", "6"]) == 2


def test_engine_binary_piv(pair_files, tmp_path, engine):
    exe = engine
    d, a, b = pair_files
    out = tmp_path / "f.csv"
    r = subprocess.run(
        [exe, "piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--passes", "64x64,32x32"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert set(data.dtype.names) >= {"x", "y", "u", "v", "valid", "peak_ratio"}
    py = rspiv.piv(a, b, passes=[(64, 64), (32, 32)])
    np.testing.assert_allclose(data["u"], py.u.ravel(), atol=1e-3)
    np.testing.assert_allclose(data["x"], py.x.ravel())
    r = subprocess.run(
        [exe, "piv", str(d / "nope.tif"), str(d / "b.tif"), "-o", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "nope.tif" in r.stderr


def test_read_image_checks_arrays_by_the_file_rules():
    """One reader: arrays pass through the same rules as files."""
    img = read_image(np.arange(12, dtype=np.int32).reshape(3, 4))
    assert img.dtype == np.float64 and img.flags.c_contiguous
    u16 = np.zeros((3, 4), np.uint16)
    assert read_image(u16).dtype == np.uint16
    with pytest.raises(rspiv.InvalidInputError, match="NaN"):
        read_image(np.full((3, 4), np.nan, np.float32))
    with pytest.raises(rspiv.InvalidInputError, match="2D"):
        read_image(np.zeros((2, 3, 5)))


def test_cli_piv_settings_file_and_flags_share_the_vocabulary(pair_files, tmp_path):
    """``--settings FILE.json`` holds rspiv.PivSettings keys; flags given override them."""
    d, a, b = pair_files
    s = rspiv.PivSettings(passes=((64, 64), (32, 32)), overlap=(0.5, 0.75), subpixel="GAUSS2D")
    assert s.subpixel == "gauss2d" and rspiv.PivSettings.from_dict(s.to_dict()) == s
    path = tmp_path / "piv.json"
    path.write_text(s.to_json())
    out = tmp_path / "f.nc"
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--settings",
                 str(path)]) == 0  # fmt: skip
    ds = xr.load_dataset(out, engine="h5netcdf")
    ref = rspiv.piv(a, b, settings=s)
    np.testing.assert_array_equal(ds.u.values, ref.u)
    assert rspiv.PivSettings.from_dict(json.loads(ds.attrs["piv_settings"])) == s
    # a flag overrides its key of the file
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--settings",
                 str(path), "--subpixel", "gauss3"]) == 0  # fmt: skip
    ds = xr.load_dataset(out, engine="h5netcdf")
    ref = rspiv.piv(a, b, settings=s.replace(subpixel="gauss3"))
    np.testing.assert_array_equal(ds.u.values, ref.u)
    # an unknown key, a correction method without a calibration: one-line errors, exit 2
    path.write_text('{"passes": [[32, 32]], "median_epsilon": 0.1}')
    assert main(["piv", str(d / "a.tif"), "-o", str(out), "--settings", str(path)]) == 2
    assert main(["piv", str(d / "a.tif"), "-o", str(out), "--method", "I"]) == 2
