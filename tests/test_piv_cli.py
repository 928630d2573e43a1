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


def test_cli_piv_writes_derived_quantities(pair_files, tmp_path, capsys):
    """``--derived SCHEME``: vorticity, divergence and swirling strength beside u and v (a
    uniform displacement: zero inside, NaN on the outermost vectors); Tecplot refused in one
    line before any work."""
    d, _, _ = pair_files
    frames = [str(d / "a.tif"), str(d / "b.tif")]
    out = tmp_path / "derived.nc"
    assert main(["piv", *frames, "-o", str(out), "--passes", "32x32", "--derived", "central"]) == 0
    ds = xr.load_dataset(out, engine="h5netcdf")
    for name in ("vorticity", "divergence", "swirling_strength"):
        assert ds[name].attrs["units"] == "1/pair" and "central" in ds[name].attrs["long_name"]
        inner = ds[name].values[1:-1, 1:-1]
        assert np.isfinite(inner).all() and np.abs(inner).max() < 0.01
        assert np.isnan(ds[name].values[0]).all()
    capsys.readouterr()
    bad = tmp_path / "derived.dat"
    assert main(["piv", *frames, "-o", str(bad), "--derived", "central"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--derived: derived.dat: the Tecplot file's columns are fixed" in err
    assert not bad.exists()


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


def test_weighting_flag_in_both_clis(pair_files, tmp_path, engine):
    """``--weighting`` of the engine binary and of ``rspiv piv`` give rspiv.piv's field with
    that weighting; an unknown name is one line naming the flag, exit 2."""
    d, a, b = pair_files
    py = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], weighting="gaussian")
    out = tmp_path / "f.csv"
    args = [engine, "piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out)]
    args += ["--passes", "64x64,32x32"]
    r = subprocess.run(args + ["--weighting", "Gaussian"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    data = np.genfromtxt(out, delimiter=",", names=True)
    np.testing.assert_allclose(data["u"], py.u.ravel(), atol=1e-3)
    r = subprocess.run(args + ["--weighting", "hann"], capture_output=True, text=True)
    assert r.returncode == 2 and "--weighting" in r.stderr and "hann" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    nc = tmp_path / "f.nc"
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(nc), "--passes",
                 "64x64,32x32", "--weighting", "gaussian"]) == 0  # fmt: skip
    ds = xr.load_dataset(nc, engine="h5netcdf")
    np.testing.assert_array_equal(ds.u.values, py.u)
    assert json.loads(ds.attrs["piv_settings"])["weighting"] == "gaussian"


def test_jpeg_frames_are_read_with_a_warning(pair_files, tmp_path, engine):
    """JPEG frames (OpenPIV's ``test3``, phone and webcam PIV) are read by the API, ``rspiv
    piv`` and the engine binary, each warning once that the compression adds error; the
    displacement measured on them is the exact one to within the compression's error. A
    campaign file may list them."""
    from PIL import Image

    d, a, b = pair_files
    a8, b8 = ((f >> 4).astype(np.uint8) for f in (a, b))
    for name, f in (("a.jpg", a8), ("b.jpeg", b8)):
        Image.fromarray(f).save(tmp_path / name, quality=95)
    Image.fromarray(np.stack([a8] * 3, axis=-1)).save(tmp_path / "rgb.jpg", quality=95)
    with pytest.warns(UserWarning, match="JPEG is lossy"):
        ja, jb = read_pair(tmp_path / "a.jpg", tmp_path / "b.jpeg")
    assert ja.dtype == np.uint8 and ja.shape == a.shape
    # quality 95: the decoded counts are the recorded ones up to the compression's error (1.7
    # counts RMS here against the particle images' 29; not rescaled)
    assert np.sqrt(np.mean((ja.astype(float) - a8) ** 2)) < 2.5
    with pytest.warns(UserWarning, match="JPEG is lossy") as rec:
        grey = read_image(tmp_path / "rgb.jpg")
    assert "(this file: quality about 95)" in str(rec[0].message)
    # the file's quality, estimated from its quantisation table, and under 90 what it costs
    Image.fromarray(a8).save(tmp_path / "q60.jpg", quality=60)
    with pytest.warns(UserWarning, match="quality about 60; .* 0.27 px at 75"):
        read_image(tmp_path / "q60.jpg")
    from rspiv.io import jpeg_quality

    for q in (30, 60, 97):
        Image.fromarray(a8).save(tmp_path / "q.jpg", quality=q)
        with Image.open(tmp_path / "q.jpg") as im:
            assert jpeg_quality(im) == q
    with Image.open(d / "a.png") as im:
        assert jpeg_quality(im) is None  # no quantisation table: not a JPEG
    assert grey.dtype == np.float32 and np.sqrt(np.mean((grey - a8) ** 2)) < 2.5
    f = rspiv.piv(ja, jb, passes=[(64, 64), (32, 32)])
    assert np.median(np.abs(f.u - 2.5)) < 0.05 and np.median(np.abs(f.v + 1.0)) < 0.05
    out = tmp_path / "j.nc"
    args = [str(tmp_path / "a.jpg"), str(tmp_path / "b.jpeg")]
    with pytest.warns(UserWarning, match="JPEG is lossy"):
        assert main(["piv", *args, "-o", str(out), "--passes", "64x64,32x32"]) == 0
    ds = xr.load_dataset(out, engine="h5netcdf")
    np.testing.assert_array_equal(ds.u.values, f.u)
    csv = tmp_path / "j.csv"
    r = subprocess.run([engine, "piv", *args, "-o", str(csv), "--passes", "64x64,32x32"],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "JPEG is lossy" in r.stderr and "a.jpg" in r.stderr, r.stderr
    # on the terminal the warning is one line of the command (not Python's two lines)
    import sys

    r2 = subprocess.run([sys.executable, "-m", "rspiv", "piv", *args, "-o", str(tmp_path / "k.nc"),
                         "--passes", "64x64,32x32"], capture_output=True, text=True)  # fmt: skip
    assert r2.returncode == 0, r2.stderr
    lines = r2.stderr.splitlines()
    assert lines[0].startswith("rspiv piv: warning: JPEG is lossy") and len(lines) == 1, lines
    data = np.genfromtxt(csv, delimiter=",", names=True)
    # another decoder (zune-jpeg, not libjpeg): the same field to within its rounding
    assert np.median(np.abs(data["u"] - 2.5)) < 0.05
    assert np.median(np.abs(data["u"] - f.u.ravel())) < 0.01
    from rspiv.campaign_config import load_campaign_config

    toml = tmp_path / "c.toml"
    toml.write_text('[images]\npairs = [["a.jpg", "b.jpeg"]]\n[correction]\nmethod = "none"\n')
    pairs = load_campaign_config(toml).images.pair_files()
    assert [(p.name, q.name) for p, q in pairs] == [("a.jpg", "b.jpeg")]
    (tmp_path / "bad.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(rspiv.InvalidInputError, match="bad.jpg"):
        read_image(tmp_path / "bad.jpg")


def test_frames_that_do_not_correlate_are_said_so(pair_files, tmp_path, engine, capsys):
    """Frames that do not correlate give random vectors of which the median test keeps about
    60 % as valid; the field's median peak ratio gives them away (1.1-1.2 against about 3
    for particle images): rspiv.piv warns (CorrelationWarning), ``rspiv piv`` says so in one
    line and in the file, the engine binary says so. A part of the frames without particle
    images is said so too (the field stays a measurement). Particle images, and frame A given
    twice, are not warned about."""
    import warnings

    d, a, b = pair_files
    rng = np.random.default_rng(7)
    other = particle_pair(a.shape, (2.5, -1.0), seed=22)[1]  # another recording's frame B
    cases = {
        "noise": (rng.integers(0, 4000, a.shape).astype(np.uint16),
                  rng.integers(0, 4000, a.shape).astype(np.uint16)),
        "wrong pairing": (a, other),
        "dark frame B": (a, rng.normal(30.0, 3.0, a.shape).clip(0).astype(np.uint16)),
        "frame B shuffled": (a, rng.permutation(b.ravel()).reshape(b.shape)),
    }  # fmt: skip
    for name, (fa, fb) in cases.items():
        with pytest.warns(rspiv.CorrelationWarning, match="the frames do not correlate") as rec:
            f = rspiv.piv(fa, fb, passes=[(64, 64), (32, 32)])
        median = float(str(rec[0].message).split(" is ")[1].split()[0])
        assert 1.0 <= median < 1.3, (name, median)
        assert f.warning() == str(rec[0].message) and f.uncorrelated()
        # what the warning is about: the median test kept random vectors
        assert f.valid.mean() > 0.3, (name, f.valid.mean())
    # a part of the frames without particle images: its random vectors are said so, the field
    # is still a measurement elsewhere
    fa, fb = particle_pair((256, 384), (2.5, -1.0), seed=21)[:2]
    for f in (fa, fb):
        f[:, 230:] = rng.normal(40.0, 8.0, f[:, 230:].shape).clip(0)
    with pytest.warns(rspiv.CorrelationWarning, match="lie where the frames hardly correlate"):
        f = rspiv.piv(fa, fb, passes=[(64, 64), (32, 32), (32, 8)])
    assert not f.uncorrelated()
    # a displacement beyond the first pass's search (32 px for 64 x 64 px windows) looks the same
    fa, fb = particle_pair((256, 256), (40.0, 0.0), seed=23)[:2]
    with pytest.warns(rspiv.CorrelationWarning, match="beyond the first pass's search"):
        rspiv.piv(fa, fb, passes=[(64, 64), (32, 32)])
    with pytest.raises(rspiv.InvalidInputError, match="differ in shape"):
        rspiv._rspiv.correlation_check(np.ones((2, 3)), np.ones((3, 2), bool), True)
    with pytest.warns(rspiv.CorrelationWarning, match="no window could be correlated"):
        rspiv.piv(np.zeros(a.shape), np.zeros(a.shape), passes=[(64, 64), (32, 32)])
    with pytest.warns(rspiv.CorrelationWarning, match="the frames do not correlate"):
        gx, gy = np.meshgrid(np.arange(32.0, 161.0, 16.0), np.arange(32.0, 97.0, 16.0))
        rspiv.piv_at(*cases["noise"], np.stack([gx, gy], axis=-1), (32, 32))
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.CorrelationWarning)
        for fa, fb in ((a, b), (a, a)):
            f = rspiv.piv(fa, fb, passes=[(64, 64), (32, 32)])
            assert f.warning() is None and not f.uncorrelated()
    # the command line: one line on stderr and the file's attribute; the engine binary
    import tifffile

    tifffile.imwrite(tmp_path / "n1.tif", cases["noise"][0])
    tifffile.imwrite(tmp_path / "n2.tif", cases["noise"][1])
    args = [str(tmp_path / "n1.tif"), str(tmp_path / "n2.tif")]
    out = tmp_path / "n.nc"
    capsys.readouterr()
    assert main(["piv", *args, "-o", str(out), "--passes", "64x64,32x32"]) == 0
    err = capsys.readouterr().err
    assert err.count("rspiv piv: warning: the frames do not correlate") == 1, err
    assert "CorrelationWarning" not in err
    assert "the frames do not correlate" in xr.load_dataset(out, engine="h5netcdf").attrs["warning"]
    assert "warning" not in xr.load_dataset(_good_nc(d, tmp_path), engine="h5netcdf").attrs
    r = subprocess.run([engine, "piv", *args, "-o", str(tmp_path / "n.csv"), "--passes",
                        "64x64,32x32"], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and "warning: " in r.stderr and "do not correlate" in r.stderr


def test_a_mask_takes_a_region_out(tmp_path, engine, capsys):
    """The partial-correlation warning says "mask it": ``rspiv piv --mask`` (an image or a JSON
    of polygons) and ``rspiv-engine piv --mask`` (an image) do. A pair whose right part (x >=
    230 px) is camera noise only: unmasked, one warning line; masked, no warning, exactly the
    vectors whose centre lies on the mask are masked (NaN), the same by both readers and in
    the engine's CSV. A mask of another size, or a JSON mask given to the engine: one line
    naming the file, exit status 2."""
    from PIL import Image

    rng = np.random.default_rng(7)
    fa, fb = particle_pair((256, 384), (2.5, -1.0), seed=21)[:2]
    for f in (fa, fb):
        f[:, 230:] = rng.normal(40.0, 8.0, f[:, 230:].shape).clip(0)
    tifffile.imwrite(tmp_path / "a.tif", fa)
    tifffile.imwrite(tmp_path / "b.tif", fb)
    img = np.zeros(fa.shape, np.uint8)
    img[:, 230:] = 255
    Image.fromarray(img).save(tmp_path / "mask.png")
    poly = {"polygons": [[[229.6, -5.0], [400.0, -5.0], [400.0, 300.0], [229.6, 300.0]]]}
    (tmp_path / "mask.json").write_text(json.dumps(poly))
    Image.fromarray(img[:, :200]).save(tmp_path / "small.png")
    frames = [str(tmp_path / "a.tif"), str(tmp_path / "b.tif")]
    capsys.readouterr()
    assert main(["piv", *frames, "-o", str(tmp_path / "open.nc")]) == 0
    assert "lie where the frames hardly correlate" in capsys.readouterr().err
    for name in ("mask.png", "mask.json"):
        out = tmp_path / f"{name}.nc"
        assert main(["piv", *frames, "-o", str(out), "--mask", str(tmp_path / name)]) == 0
        assert "warning" not in capsys.readouterr().err, name
        ds = xr.load_dataset(out, engine="h5netcdf")
        assert "warning" not in ds.attrs and ds.attrs["mask"] == str(tmp_path / name)
        x = np.broadcast_to(ds["x"].values[None, :], ds["u"].shape)
        masked = ds["chc"].values == -1
        np.testing.assert_array_equal(masked, x >= 230)
        assert np.all(np.isnan(ds["u"].values[masked])) and masked.sum() == 567
    r = subprocess.run([engine, "piv", *frames, "-o", str(tmp_path / "m.csv"), "--mask",
                        str(tmp_path / "mask.png")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    rows = np.genfromtxt(tmp_path / "m.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(rows["masked"] == 1, rows["x"] >= 230)
    for name, why in (("small.png", "mask is 200 x 256 px, the images are 384 x 256 px"),):
        assert main(["piv", *frames, "-o", str(tmp_path / "x.nc"), "--mask",
                     str(tmp_path / name)]) == 2  # fmt: skip
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, err
    for name, why in (("small.png", "mask is 200 x 256 px, the frames are 384 x 256 px"),
                      ("mask.json", "polygon masks (JSON) are read by `rspiv piv`")):  # fmt: skip
        r = subprocess.run([engine, "piv", *frames, "-o", str(tmp_path / "x.csv"), "--mask",
                            str(tmp_path / name)], capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 2 and why in r.stderr and str(tmp_path / name) in r.stderr, r
    assert not (tmp_path / "x.nc").exists() and not (tmp_path / "x.csv").exists()


def _warned_once_by_both_command_lines(tmp_path, engine, capsys, pair, phrase):
    """``rspiv piv`` and ``rspiv-engine piv`` on ``pair`` (written as TIFF files), passes 64 x 64
    -> 32 x 32 -> 32 x 8: both succeed and say ``phrase`` in one warning line."""
    tifffile.imwrite(tmp_path / "a.tif", pair[0])
    tifffile.imwrite(tmp_path / "b.tif", pair[1])
    frames = [str(tmp_path / "a.tif"), str(tmp_path / "b.tif")]
    capsys.readouterr()
    assert main(["piv", *frames, "-o", str(tmp_path / "z.nc"), "--passes", "64x64,32x32,32x8"]) == 0
    err = capsys.readouterr().err
    assert err.count("rspiv piv: warning: ") == 1 and phrase in err, err
    r = subprocess.run([engine, "piv", *frames, "-o", str(tmp_path / "z.csv"), "--passes",
                        "64x64,32x32,32x8"], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and phrase in r.stderr, r.stderr


def test_windows_too_blank_to_correlate_are_said_so(tmp_path, engine, capsys):
    """More than a fifth of the windows (not masked) too blank to be correlated: their vectors
    are only interpolated, and rspiv says so (CorrelationWarning, one line from ``rspiv piv``
    and from the engine). A pair whose right part (x >= 250 px) holds no signal (zero in both
    frames): warned unmasked (about a third of the windows), not once masked, the rest measured.
    OpenPIV's real recording ``test6`` (sparse seeding, about one particle image per 16 x 16 px
    window): warned at 16 x 16 px (about 31 % of the windows blank), not at 32 x 32 px. The
    windows at the frame's edge that fail because their displaced half reaches outside the
    frame (a small pair of the fixture: 35 % of its 77 windows at 32 x 32 px) are not counted."""
    import os
    import warnings

    import openpiv

    fa, fb = particle_pair((256, 384), (2.5, -1.0), seed=21)[:2]
    for f in (fa, fb):
        f[:, 250:] = 0
    passes = [(64, 64), (32, 32), (32, 8)]
    with pytest.warns(rspiv.CorrelationWarning, match="held too little signal") as rec:
        f = rspiv.piv(fa, fb, passes=passes)
    share = float(str(rec[0].message).split(" %")[0])
    assert 25 <= share <= 45 and not f.uncorrelated(), str(rec[0].message)
    mask = np.zeros(fa.shape, bool)
    mask[:, 250:] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.CorrelationWarning)
        f = rspiv.piv(fa, fb, passes=passes, mask=mask)
    assert f.warning() is None
    ok = f.valid & ~f.masked
    assert np.median(np.hypot(f.u[ok] - 2.5, f.v[ok] + 1.0)) < 0.1
    # the command lines: one warning line each
    _warned_once_by_both_command_lines(tmp_path, engine, capsys, (fa, fb), "too little signal")
    # particle images too sparse for the windows (one per 64 x 64 px window, gaps between them
    # too long to tell a clean background from fill: see
    # test_sparse_particles_on_a_clean_background_are_correlated) on a background without
    # noise: nothing correlated inside the grid's outer rings is no measurement, in one line
    a, b = particle_pair((256, 384), (1.5, -0.7), density=0.0005, noise=0.0, seed=31)[:2]
    with pytest.warns(rspiv.CorrelationWarning, match="too sparse on a background without noise"):
        f = rspiv.piv(a, b, passes=passes)
    assert f.uncorrelated()
    # the check's arrays must agree in shape, the mask too
    with pytest.raises(rspiv.InvalidInputError, match=r"and masked \(3, 2\) differ in shape"):
        rspiv._rspiv.correlation_check(
            np.ones((2, 3)), np.ones((2, 3), bool), True, np.ones((3, 2), bool)
        )
    # the windows failed at the frame's edge only: no warning
    a, b = particle_pair((128, 192), (2.5, -1.0), seed=21)
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.CorrelationWarning)
        f = rspiv.piv(a, b, passes=[(64, 64), (32, 32)])
    assert (f.peak_ratio == 0).mean() > 0.3 and (f.peak_ratio[2:-2, 2:-2] > 0).all()
    # a real recording seeded sparsely for 16 x 16 px windows
    d = os.path.join(os.path.dirname(openpiv.__file__), "data", "test6")
    a = read_image(os.path.join(d, "Pattern_0001_A.tif"))
    b = read_image(os.path.join(d, "Pattern_1001_B.tif"))
    with pytest.warns(rspiv.CorrelationWarning, match="held too little signal") as rec:
        rspiv.piv(a, b, passes=[(64, 64), (32, 32), (16, 16)])
    assert 25 <= float(str(rec[0].message).split(" %")[0]) <= 40
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.CorrelationWarning)
        rspiv.piv(a, b, passes=[(64, 64), (32, 32)])


def _good_nc(d, tmp_path):
    """The NetCDF of ``rspiv piv`` on the good pair."""
    out = tmp_path / "good.nc"
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(out), "--passes",
                 "64x64,32x32"]) == 0  # fmt: skip
    return out


def test_palette_images_read_as_intensities(tmp_path, engine):
    """An indexed-colour image holds palette indices, which are intensities only when the
    palette is the identity grey ramp (OpenPIV's test2 TIFFs: 16-bit levels k * 257): a
    reversed or shuffled grey palette, or a colour palette, must be read through the palette
    (the indices read as they are would be another image). Grey with alpha reads as its grey
    channel. The engine reads a palette PNG alike."""
    from PIL import Image

    rng = np.random.default_rng(3)
    idx = rng.integers(0, 256, (40, 60)).astype(np.uint8)
    ramp = np.arange(256)
    cases = {
        "identity": (np.repeat(ramp[:, None], 3, 1), idx),
        "reversed": (np.repeat(255 - ramp[:, None], 3, 1), 255 - idx),
        "shuffled": (np.repeat(rng.permutation(256)[:, None], 3, 1), None),
        "colour": (rng.integers(0, 256, (256, 3)), None),
    }
    for name, (pal, want) in cases.items():
        im = Image.fromarray(idx, mode="P")
        im.putpalette(pal.astype(np.uint8).ravel().tolist())
        im.save(tmp_path / f"{name}.png")
        got = read_image(tmp_path / f"{name}.png")
        if name == "colour":
            rgb = pal[idx].astype(np.float32)
            np.testing.assert_allclose(got, rgb @ np.float32([0.299, 0.587, 0.114]), rtol=1e-6)
            assert got.dtype == np.float32
        else:
            want = pal[idx, 0].astype(np.uint8) if want is None else want
            assert got.dtype == np.uint8 and np.array_equal(got, want), name
        # a TIFF colour map holds 16-bit levels: k * 257 for 8-bit ones
        cmap = (pal.T * 257).astype(np.uint16)
        tifffile.imwrite(tmp_path / f"{name}.tif", idx, photometric="palette", colormap=cmap)
        np.testing.assert_array_equal(read_image(tmp_path / f"{name}.tif"), got)
    # 16-bit levels that are not 8-bit ones stay uint16
    cmap = np.repeat((np.arange(256) * 100)[None, :], 3, 0).astype(np.uint16)
    tifffile.imwrite(tmp_path / "deep.tif", idx, photometric="palette", colormap=cmap)
    got = read_image(tmp_path / "deep.tif")
    assert got.dtype == np.uint16 and np.array_equal(got, idx.astype(np.uint16) * 100)
    # grey with alpha
    la = np.stack([idx, np.full_like(idx, 200)], axis=-1)
    Image.fromarray(la, mode="LA").save(tmp_path / "la.png")
    np.testing.assert_array_equal(read_image(tmp_path / "la.png"), idx)
    # the engine: the reversed palette PNG gives the field of the intensities (PIV of a pair
    # whose frames are the same palette image: zero displacement either way, so compare the
    # pair with a shift through the reversed palette against the grey files)
    a, b = particle_pair((128, 192), (2.5, -1.0), seed=21)[:2]
    a8, b8 = (np.clip(f >> 4, 0, 255).astype(np.uint8) for f in (a, b))
    rev = np.repeat(255 - ramp[:, None], 3, 1).astype(np.uint8).ravel().tolist()
    for f, nm in ((a8, "pa"), (b8, "pb")):
        im = Image.fromarray((255 - f).astype(np.uint8), mode="P")
        im.putpalette(rev)
        im.save(tmp_path / f"{nm}.png")
        Image.fromarray(f).save(tmp_path / f"{nm}_grey.png")
        np.testing.assert_array_equal(read_image(tmp_path / f"{nm}.png"), f)
    outs = []
    for suffix in ("", "_grey"):
        out = tmp_path / f"e{suffix}.csv"
        r = subprocess.run([engine, "piv", str(tmp_path / f"pa{suffix}.png"),
                            str(tmp_path / f"pb{suffix}.png"), "-o", str(out), "--passes",
                            "64x64,32x32"], capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 0, r.stderr
        outs.append(out.read_text())
    assert outs[0] == outs[1]


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


def test_tecplot_export_round_trips_and_flags_masked_vectors(pair_files, tmp_path):
    """``rspiv piv -o f.dat`` writes Tecplot ASCII (the DaVis/PIVlab exchange format): the
    values of the field to 9 digits, I = x fastest, masked vectors u = v = 0 with chc = -1."""
    d, a, b = pair_files
    mask = np.zeros(a.shape, bool)
    mask[:, :40] = True
    f = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], mask=mask)
    assert f.masked.any() and (~f.masked).any()
    out = tmp_path / "f.dat"
    rspiv.write_tecplot(f, out, aux={"note": 'say "hi"'})
    data, aux = rspiv.read_tecplot(out)
    assert aux["units"] == "px" and aux["note"] == "say 'hi'"
    assert data["u"].shape == f.shape
    np.testing.assert_allclose(data["x"], f.x, rtol=1e-9)
    np.testing.assert_allclose(data["y"], f.y, rtol=1e-9)
    ok = ~f.masked
    np.testing.assert_allclose(data["u"][ok], f.u[ok], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(data["v"][ok], f.v[ok], rtol=1e-8, atol=1e-9)
    assert np.all(data["u"][f.masked] == 0) and np.all(data["chc"][f.masked] == -1)
    np.testing.assert_array_equal(data["chc"][ok] == 1, f.valid[ok])
    header = out.read_text().splitlines()[:8]
    assert header[1] == (
        'VARIABLES = "x", "y", "u", "v", "chc", "peak_ratio", "coef", "sigma_u", "sigma_v"'
    )
    # each valid vector's uncertainty; 0 where it is not estimated
    good = f.valid
    np.testing.assert_array_equal(np.isfinite(f.sigma_u), good)
    np.testing.assert_allclose(data["sigma_u"][good], f.sigma_u[good], rtol=1e-8)
    np.testing.assert_allclose(data["sigma_v"][good], f.sigma_v[good], rtol=1e-8)
    assert np.all(data["sigma_u"][~f.valid] == 0)
    assert any(h.startswith("ZONE") and f"I={f.shape[1]}, J={f.shape[0]}" in h for h in header)
    # the CLI picks the format from the suffix
    cli_out = tmp_path / "cli.tec"
    assert main(["piv", str(d / "a.tif"), str(d / "b.tif"), "-o", str(cli_out),
                 "--passes", "64x64,32x32"]) == 0  # fmt: skip
    data2, aux2 = rspiv.read_tecplot(cli_out)
    assert "piv_settings" in aux2 and data2["u"].shape == f.shape
    with pytest.raises(rspiv.InvalidInputError, match="needs a PivField"):
        rspiv.write_tecplot({"u": f.u}, tmp_path / "no.dat")
    assert not (tmp_path / "no.dat").exists()
    bad = tmp_path / "bad.dat"
    bad.write_text("TITLE = x\nVARIABLES = a, b\nZONE I=2, J=2\n1 2\n3 4\n")
    with pytest.raises(rspiv.InvalidInputError, match="bad.dat"):
        rspiv.read_tecplot(bad)


def test_polygon_mask_json(tmp_path, pair_files):
    """A JSON of polygons (px) is a mask like an image: pixels whose centre is inside are
    excluded (or kept, with invert); rspiv.piv takes the path."""
    from rspiv.io import read_mask

    p = tmp_path / "mask.json"
    p.write_text(json.dumps({"polygons": [[[1.5, 0.5], [4.5, 0.5], [4.5, 2.5], [1.5, 2.5]]]}))
    m = read_mask(p, (4, 6))
    want = np.zeros((4, 6), bool)
    want[1:3, 2:5] = True
    np.testing.assert_array_equal(m, want)
    p2 = tmp_path / "keep.json"
    p2.write_text(json.dumps({"polygons": [[[1.5, 0.5], [4.5, 0.5], [4.5, 2.5], [1.5, 2.5]]],
                              "invert": True}))  # fmt: skip
    np.testing.assert_array_equal(read_mask(p2, (4, 6)), ~want)
    d, a, b = pair_files
    h, w = a.shape
    left = tmp_path / "left.json"
    left.write_text(json.dumps({"polygons": [[[-1, -1], [40, -1], [40, h], [-1, h]]]}))
    f = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], mask=str(left))
    assert f.masked[:, f.x[0] < 40].all() and not f.masked[:, f.x[0] > 72].any()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"polygons": [[[0, 0], [1, 1]]]}))
    with pytest.raises(rspiv.InvalidInputError, match="bad.json: polygon 0 needs >= 3"):
        read_mask(bad, (4, 6))
    with pytest.raises(rspiv.InvalidInputError, match="mask is 6 x 4 px"):
        read_mask(np.zeros((4, 6), bool), (5, 6))


def test_fields_mostly_interpolated_are_said_so(tmp_path, engine, capsys):
    """Too few particle images per window (about one per 32 x 8 px window: 0.004 particles/px
    with 5 % noise): the median test rejects a quarter of the vectors, and the ones it keeps
    are off by about 1 px RMS (0.05 px with enough particle images). rspiv says so in one line
    (``rspiv.piv``, ``rspiv piv``, the engine); with 32 x 32 px windows over the same frames
    (1.5 % rejected, 0.065 px RMS) and with enough particle images it says nothing. Noise-free,
    1.0 particle per 32 x 32 px window: 18 % of the windows too blank and 4 % rejected, 0.63
    px RMS: said too. Real recordings that correlate: 0.5-4.4 % only interpolated
    (``benches/real_data_checks.py``)."""
    import warnings

    truth = (1.5, -0.7)
    a, b = particle_pair((512, 1024), truth, density=0.004, noise=0.05, seed=31)[:2]
    passes = [(64, 64), (32, 32), (32, 8)]
    with pytest.warns(rspiv.CorrelationWarning, match="only interpolated from their") as rec:
        f = rspiv.piv(a, b, passes=passes)
    msg = str(rec[0].message)
    share = float(msg.split(" %")[0])
    assert "rejected by the validation, 0 from windows too blank" in msg, msg
    inner = np.zeros(f.u.shape, bool)
    inner[2:-2, 2:-2] = True
    ok = f.valid & inner
    rms = np.sqrt(np.mean((f.u[ok] - truth[0]) ** 2 + (f.v[ok] - truth[1]) ** 2))
    # measured: 24 % rejected, 0.98 px RMS of the vectors kept
    assert 15 <= share <= 40 and rms > 0.5 and not f.uncorrelated(), (share, rms)
    c, d = particle_pair((512, 1024), truth, density=0.001, noise=0.0, seed=31)[:2]
    with pytest.warns(rspiv.CorrelationWarning, match="only interpolated from their") as rec:
        rspiv.piv(c, d, passes=passes[:2])
    msg = str(rec[0].message)
    assert 15 <= float(msg.split(" %")[0]) <= 30 and "from windows too blank" in msg, msg
    for p, dens in ((passes[:2], 0.004), (passes, 0.03)):
        c, d = particle_pair((512, 1024), truth, density=dens, noise=0.05, seed=31)[:2]
        with warnings.catch_warnings():
            warnings.simplefilter("error", rspiv.CorrelationWarning)
            g = rspiv.piv(c, d, passes=p)
        assert g.warning() is None
    # the command lines: one warning line each
    _warned_once_by_both_command_lines(
        tmp_path, engine, capsys, (a, b), "only interpolated from their"
    )
