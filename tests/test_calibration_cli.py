"""`rspiv calibrate` / `rspiv montecarlo` and `rspiv-engine calibrate`: files, figures, exit
codes, and nothing written on error."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import tifffile
from rspiv.calibration import Calibration
from rspiv.cli import main
from rspiv.synth import calibration_target


@pytest.fixture(scope="module")
def target_tif(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    tg = calibration_target(scale=0.25, seed=31)
    p = d / "target.tif"
    tifffile.imwrite(p, tg.image)
    return p, tg


def test_calibrate_and_montecarlo_commands(target_tif, tmp_path, capsys):
    tif, tg = target_tif
    out = tmp_path / "calib.json"
    plots = tmp_path / "plots"
    args = ["calibrate", str(tif), "--pitch-mm", "19.51", "--model", "auto", "-o", str(out)]
    assert main([*args, "--plots", str(plots)]) == 0
    text = capsys.readouterr().out
    assert "held-out" in text and "magnification" in text
    cal = Calibration.load(out)
    assert len(cal.markers) == 91 and cal.image_shape == tg.image.shape
    assert (plots / "calibration_arrows.png").stat().st_size > 1000
    assert (plots / "calibration_markers.png").stat().st_size > 1000
    assert main(["montecarlo", str(out), "-n", "3000", "--plots", str(plots)]) == 0
    assert "99 % radius" in capsys.readouterr().out
    assert (plots / f"montecarlo_{cal.model}.png").stat().st_size > 1000


def test_cli_errors_write_nothing(target_tif, tmp_path, capsys):
    tif, _ = target_tif
    out = tmp_path / "calib.json"
    blank = tmp_path / "blank.tif"
    tifffile.imwrite(blank, np.full((300, 400), 100, np.uint16))
    trunc = tmp_path / "trunc.tif"
    trunc.write_bytes(tif.read_bytes()[:5000])
    for args in (
        [str(blank), "--pitch-mm", "19.51"],
        [str(tif), "--pitch-mm", "-1"],
        [str(trunc), "--pitch-mm", "19.51"],
        [str(tmp_path / "nope.tif"), "--pitch-mm", "19.51"],
    ):
        assert main(["calibrate", *args, "-o", str(out)]) == 2
        assert "error" in capsys.readouterr().err
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blank.tif", "trunc.tif"]
    assert main(["montecarlo", str(tmp_path / "missing.json")]) == 2


def test_engine_calibrate_matches_python(target_tif, tmp_path, engine):
    tif, tg = target_tif
    out = tmp_path / "engine.json"
    r = subprocess.run(
        [engine, "calibrate", str(tif), "--pitch-mm", "19.51", "-o", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    cal = Calibration.load(out)  # the engine writes Python's format
    from rspiv.calibration import calibrate

    py = calibrate(tif, 19.51, compare=False)
    np.testing.assert_allclose(cal.markers.image_px, py.markers.image_px, atol=1e-9)
    np.testing.assert_array_equal(cal.markers.index, py.markers.index)
    assert cal.magnification == pytest.approx(py.magnification, rel=1e-12)
    pts = py.markers.object_px
    np.testing.assert_allclose(cal.mapping.forward(pts), py.mapping.forward(pts), atol=1e-8)
    bad = subprocess.run(
        [engine, "calibrate", str(tif), "--pitch-mm", "0", "-o", str(tmp_path / "x.json")],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "pitch" in bad.stderr
    assert not (tmp_path / "x.json").exists()
