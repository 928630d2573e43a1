"""The particle images' diameter from the correlation peaks, the peak-locking warning it feeds,
the hot-pixel rule's harm to small particle images, and the smoothing that eases the locking."""

from __future__ import annotations

import subprocess
import warnings

import numpy as np
import pytest
import rspiv
import tifffile
from rspiv.cli import main
from rspiv.preprocess import NEAR_WALL, Preprocess, condition
from rspiv.synth import particle_pair

SHAPE = (512, 1024)


def _ramp(x, y):
    """Every fractional part equally often: 0.3-4.3 px along x, 0.2-2.2 px along y."""
    return 4 * x / SHAPE[1] + 0.3, 2 * y / SHAPE[0] + 0.2


def _pair(d, seed=3):
    return particle_pair(SHAPE, _ramp, density=0.03, diameter=d, noise=0.05, seed=seed)


def _recorded(d):
    """The e^-2 diameter of a Gaussian image of nominal ``d`` integrated over a pixel."""
    return 4 * np.sqrt(d * d / 16 + 1 / 12)


def _locking(f):
    """The amplitude ``a`` of the locking bias ``-a sin(2 pi t)`` of the valid vectors (u and v
    pooled) and their RMS error."""
    tu, tv = _ramp(f.x, f.y)
    ok = f.valid & ~f.replaced
    t = np.concatenate([tu[ok], tv[ok]])
    e = np.concatenate([f.u[ok], f.v[ok]]) - t
    x = np.stack([np.ones_like(t), np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)], 1)
    return -np.linalg.lstsq(x, e, rcond=None)[0][1], float(np.sqrt(np.mean(e**2)))


def _quiet_correlation(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rspiv.CorrelationWarning)
        return fn(*args, **kw)


def _quiet(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args, **kw)


def test_small_particle_images_are_measured_and_their_peak_locking_said():
    """The diameter comes back within 5 % of the pixel-integrated one (the first pass's
    peaks); particle images under 2 px lock the displacements towards whole pixels (the
    bias's amplitude measured against the exact ramp), and rspiv says so in one line;
    images of 2.7 px neither lock nor are warned."""
    small, large = _pair(1.0), _pair(2.5)
    with pytest.warns(rspiv.ParticleSizeWarning, match="peak locking") as rec:
        fs = rspiv.piv(*small)
    assert len(rec) == 1 and "\n" not in str(rec[0].message)
    assert "1.5 x 1.5 px across" in str(rec[0].message), rec[0].message
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.ParticleSizeWarning)
        fl = rspiv.piv(*large)
    for f, d in ((fs, 1.0), (fl, 2.5)):
        for m in f.particle_diameter:
            assert abs(m / _recorded(d) - 1) < 0.05, (d, f.particle_diameter)
    a_small, _ = _locking(fs)
    a_large, _ = _locking(fl)
    assert a_small > 0.025 and abs(a_large) < 0.005, (a_small, a_large)
    assert fs.peak_locking() is not None and fl.peak_locking() is None
    # the pair measured directly (windows side by side): the same diameter
    direct = rspiv.particle_diameter(*small)
    assert np.allclose(direct, fs.particle_diameter, rtol=0.03), (direct, fs.particle_diameter)
    # in the dataset
    ds = fs.to_xarray()
    assert np.allclose(ds.attrs["particle_diameter_px"], fs.particle_diameter)
    assert "peak locking" in ds.attrs["peak_locking"]
    assert "peak_locking" not in fl.to_xarray().attrs


def test_bad_input_is_refused_in_one_line():
    a, b = _pair(2.5)
    for args, kw, what in (
        ((a, b[:, :-1]), {}, "differ in shape"),
        ((a, b), {"window": (2048, 64)}, "window"),
        ((a, b), {"mask": np.zeros((10, 10), bool)}, "mask"),
        ((a, b), {"backgrounds": (np.zeros((8, 8)), np.zeros((8, 8)))}, "backgrounds"),
    ):
        with pytest.raises(rspiv.InvalidInputError, match=what) as e:
            rspiv.particle_diameter(*args, **kw)
        assert "\n" not in str(e.value)
    # blank frames, and a frame given twice (its autocorrelation, narrowed by its own noise):
    # not measured, and nothing said
    z = np.zeros((128, 128), np.uint16)
    assert all(np.isnan(rspiv.particle_diameter(z, z)))
    assert all(np.isnan(rspiv.particle_diameter(a, a)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.ParticleSizeWarning)
        f = _quiet_correlation(rspiv.piv, a, a)
    assert all(np.isnan(f.particle_diameter)) and f.peak_locking() is None
    assert rspiv.particle_size.warnings_for((float("nan"), float("nan"))) == {}


def test_the_diameter_is_that_of_the_frames_as_recorded():
    """A high-pass narrows the correlation peaks without making the particle images smaller
    (2.7 px images read about 2 px once high-passed): rspiv.piv measures the frames before its
    own preprocessing, so NEAR_WALL on 2.7 px images is not warned. The frames conditioned
    by the caller read smaller, as the docs say. The hot-pixel rule flattens 1.5 px images:
    said beside the peak locking."""
    a, b = _pair(2.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", rspiv.ParticleSizeWarning)
        f = rspiv.piv(a, b, preprocess=NEAR_WALL)
    raw = rspiv.particle_diameter(a, b)
    assert np.allclose(f.particle_diameter, raw) and min(raw) > 2.4, (f.particle_diameter, raw)
    high = Preprocess(high_pass=2.0)
    narrowed = _quiet(rspiv.piv, condition(a, high), condition(b, high)).particle_diameter
    assert max(narrowed) < min(raw) - 0.3, (narrowed, raw)
    # small images through the hot-pixel rule: two lines, and a worse field than without it
    a, b = _pair(1.0)
    with pytest.warns(rspiv.ParticleSizeWarning) as rec:
        hot = rspiv.piv(a, b, preprocess=Preprocess(hot_pixels=3.0))
    said = [str(w.message) for w in rec]
    assert len(said) == 2 and "peak locking" in said[0] and "hot-pixel rule" in said[1], said
    assert "hot_pixels = 3" in said[1]
    _, rms_hot = _locking(hot)
    _, rms_raw = _locking(_quiet(rspiv.piv, a, b))
    assert rms_hot > 1.2 * rms_raw, (rms_hot, rms_raw)


def test_smoothing_eases_the_locking():
    """Smoothing both frames by a Gaussian of 0.7 px at least a third less locking bias on 1.7
    px images, at about the same random error; the warning stays (the frames as recorded)."""
    a, b = _pair(1.2)
    a0, rms0 = _locking(_quiet(rspiv.piv, a, b))
    with pytest.warns(rspiv.ParticleSizeWarning, match="peak locking"):
        f = rspiv.piv(a, b, preprocess=Preprocess(smooth=0.7))
    a1, rms1 = _locking(f)
    assert a1 < 0.67 * a0 and rms1 < 1.1 * rms0, (a0, a1, rms0, rms1)
    assert f.particle_diameter[0] < 2.0
    # the smoothing keeps a frame's sum and widens its particle images
    s = condition(a, Preprocess(smooth=0.7))
    assert abs(s.sum() / a.sum() - 1) < 1e-3
    assert min(rspiv.particle_diameter(s, condition(b, Preprocess(smooth=0.7)))) > 2.5
    for bad in (2.5, -0.5, float("nan")):
        with pytest.raises(rspiv.InvalidInputError, match="smooth"):
            Preprocess(smooth=bad)


def test_both_command_lines_say_it(tmp_path, engine, capsys):
    """``rspiv piv`` and ``rspiv-engine piv`` give the particle images' size and one warning
    line for peak locking; the file carries it; ``--smooth`` reaches the preprocessing."""
    a, b = _pair(1.0)
    tifffile.imwrite(tmp_path / "a.tif", a)
    tifffile.imwrite(tmp_path / "b.tif", b)
    frames = [str(tmp_path / "a.tif"), str(tmp_path / "b.tif")]
    capsys.readouterr()
    assert main(["piv", *frames, "-o", str(tmp_path / "z.nc")]) == 0
    out = capsys.readouterr()
    assert "particle images 1.5 x 1.5 px" in out.out, out.out
    assert out.err.count("rspiv piv: warning: ") == 1 and "peak locking" in out.err, out.err
    import xarray as xr

    with xr.open_dataset(tmp_path / "z.nc") as ds:
        assert "peak locking" in ds.attrs["peak_locking"]
    assert main(["piv", *frames, "-o", str(tmp_path / "s.nc"), "--smooth", "0.7",
                 "--hot-pixels", "3"]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("rspiv piv: warning: ") == 2 and "hot-pixel rule" in err, err
    with xr.open_dataset(tmp_path / "s.nc") as ds:
        assert '"smooth": 0.7' in ds.attrs["preprocess"] and "hot_pixels" in ds.attrs
    assert main(["piv", *frames, "-o", str(tmp_path / "x.nc"), "--smooth", "3"]) == 2
    assert "smooth" in capsys.readouterr().err
    r = subprocess.run([engine, "piv", *frames, "-o", str(tmp_path / "z.csv")],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and "particle images 1.5 x 1.5 px" in r.stderr, r.stderr
    assert r.stderr.count("warning: ") == 1 and "peak locking" in r.stderr, r.stderr
