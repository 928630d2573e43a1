"""`rspiv calibrate` / `rspiv montecarlo` and `rspiv-engine calibrate`: files, figures, exit
codes, and nothing written on error."""

from __future__ import annotations

import re
import subprocess

import numpy as np
import pytest
import tifffile
from lens_cases import Oblique
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
    assert "WARNING" not in text  # the synthetic target fits to the markers' noise
    # One line describing the lattice found: 91 dots, no spurious blob, 19.51 mm at M px/mm.
    (line,) = [t for t in text.splitlines() if t.startswith("lattice: ")]
    assert "91 markers indexed of 91 detected (0 rejected)" in line
    px = [float(v) for v in re.search(r"pitch ([\d.]+) x ([\d.]+) px", line).groups()]
    assert px == pytest.approx([tg.optics.magnification * 19.51] * 2, rel=5e-3)
    assert re.search(r"i axis at [+-]0\.0\d deg", line) and "axes 90.0" in line
    cal = Calibration.load(out)
    assert cal.lattice["n_indexed"] == 91 and cal.warnings == []
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


def _write_points(path, cal, image_px=None, sigma="cov"):
    """The calibration's markers as a --points CSV (full precision)."""
    mk = cal.markers
    img = mk.image_px if image_px is None else image_px
    mm = 19.51 * mk.index
    cols = ["x_px", "y_px", "x_mm", "y_mm"]
    data = [img[:, 0], img[:, 1], mm[:, 0], mm[:, 1]]
    if sigma == "cov":
        cols += ["sxx", "syy", "sxy"]
        data += [mk.cov_px2[:, 0, 0], mk.cov_px2[:, 1, 1], mk.cov_px2[:, 0, 1]]
    elif sigma is not None:
        cols += ["sigma_px"]
        data += [np.full(len(img), sigma)]
    rows = [",".join(repr(float(v)) for v in r) for r in zip(*data, strict=True)]
    path.write_text("\n".join([",".join(cols), *rows]) + "\n")
    return path


def test_calibrate_points_command(target_tif, tmp_path, capsys):
    tif, tg = target_tif
    from rspiv.calibration import calibrate

    ref = calibrate(tif, 19.51, model="p3")
    csv = _write_points(tmp_path / "markers.csv", ref)
    out = tmp_path / "points.json"
    h, w = tg.image.shape
    args = ["calibrate", "--points", str(csv), "--image-shape", str(h), str(w), "-o", str(out)]
    assert main([*args, "--pitch-mm", "19.51", "--plots", str(tmp_path / "plots")]) == 0
    text = capsys.readouterr().out
    assert f"calibration from {csv}: 91 points, {w} x {h} px sensor" in text
    assert "91 given" in text and "WARNING" not in text
    cal = Calibration.load(out)
    assert cal.marker == "points" and cal.image_sigma_source == "given cov_px2"
    # The CSV holds calibrate's indexed markers: the same mapping.
    pts = ref.markers.object_px
    np.testing.assert_allclose(cal.mapping.forward(pts), ref.mapping.forward(pts), atol=1e-9)
    assert (tmp_path / "plots" / "calibration_arrows.png").stat().st_size > 1000
    # Random 5 px errors on markers that claim 0.01 px: refused, kept with --accept-poor-fit.
    rng = np.random.default_rng(0)
    noisy = ref.markers.image_px + rng.normal(0.0, 5.0, ref.markers.image_px.shape)
    poor = _write_points(tmp_path / "poor.csv", ref, noisy, sigma=0.01)
    bad_out = tmp_path / "poor.json"
    poor_args = ["calibrate", "--points", str(poor), "--image-shape", str(h), str(w)]
    assert main([*poor_args, "-o", str(bad_out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(poor) in err
    assert "calibration refused: p3 leaves" in err and "--accept-poor-fit" in err
    assert not bad_out.exists()
    assert main([*poor_args, "-o", str(bad_out), "--accept-poor-fit"]) == 0
    warned = [t for t in capsys.readouterr().out.splitlines() if t.startswith("WARNING:")]
    assert len(warned) == 1 and "poor fit kept" in warned[0]
    assert Calibration.load(bad_out).warnings == [warned[0].removeprefix("WARNING: ")]


def test_calibrate_points_bad_csv_writes_nothing(target_tif, tmp_path, capsys):
    tif, tg = target_tif
    from rspiv.calibration import calibrate

    ref = calibrate(tif, 19.51, compare=False)
    good = _write_points(tmp_path / "good.csv", ref, sigma=0.02).read_text().splitlines()
    out = tmp_path / "o.json"
    shape = [str(v) for v in tg.image.shape]

    def write(name, lines):
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        return str(tmp_path / name)

    nan = [*good[:5], ",".join(["nan", *good[5].split(",")[1:]]), *good[6:]]
    word = [*good[:3], good[3].replace(good[3].split(",")[2], "abc", 1), *good[4:]]
    cases = [
        (write("cols.csv", ["x,y,x_mm,y_mm", *good[1:]]), "missing column 'x_px'"),
        (write("nan.csv", nan), "line 6: column x_px: 'nan' is not a finite number"),
        (write("word.csv", word), "line 4: column x_mm: cannot parse 'abc'"),
        (write("few.csv", good[:8]), "model p3 needs at least 11 points, 7 were given"),
        (write("nohead.csv", good[1:]), "expected a header row"),
        (write("half.csv", [good[0] + ",sxx", *(r + ",0.1" for r in good[1:])]),
         "give sigma_px or sxx,syy,sxy, not both"),
    ]  # fmt: skip
    for path, msg in cases:
        assert main(["calibrate", "--points", path, "--image-shape", *shape, "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert path in err and msg in err, err
    # The points without --image-shape, and a TARGET together with --points.
    pts = write("ok.csv", good)
    for args in (["--points", pts], [str(tif), "--points", pts, "--pitch-mm", "19.51"]):
        assert main(["calibrate", *args, "-o", str(out)]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.suffix != ".csv"]


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


def test_engine_refuses_two_level_plates_and_poor_fits(tmp_path, engine):
    # The engine calibrates axis-aligned single-level plates; a 45-degree union lattice (two
    # levels) and a fit far above the markers' noise are refused in one line, nothing written.
    two = calibration_target(scale=0.25, seed=1, levels=2, fiducial="missing")
    oblique = calibration_target(
        scale=0.25, seed=3, lens=None, mapping=Oblique((2216, 1322))
    )  # fmt: skip
    for name, img, expect in (
        ("two_level", two.image, "two-level plate"),
        ("oblique", oblique.image, "calibration refused"),
    ):
        tif, out = tmp_path / f"{name}.tif", tmp_path / f"{name}.json"
        tifffile.imwrite(tif, img)
        r = subprocess.run(
            [engine, "calibrate", str(tif), "--pitch-mm", "19.51", "-o", str(out)],
            capture_output=True,
            text=True,
        )
        assert r.returncode == 2 and expect in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and not out.exists()
    r = subprocess.run(
        [engine, "calibrate", str(tmp_path / "oblique.tif"), "--pitch-mm", "19.51", "-o",
         str(tmp_path / "kept.json"), "--accept-poor-fit"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0 and (tmp_path / "kept.json").exists()

