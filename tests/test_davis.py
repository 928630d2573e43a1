"""DaVis buffers (.im7) through LaVision's lvpyio (the optional extra rspiv[davis]): rspiv reads
the same arrays lvpyio does, double-frame buffers give the pair, a campaign runs on a folder (or
a ``.set``) of double-frame files with the same results as on TIFFs, and bad input is one line.
The buffers are written here with lvpyio itself (nothing of lvpyio's is bundled)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import rspiv
import tifffile
from rspiv.io import davis_info, frame_count, read_image, read_pair

lv = pytest.importorskip("lvpyio", reason="the DaVis tests need lvpyio (pip install rspiv[davis])")


def _write_im7(path, frames, planes=False):
    """A DaVis buffer of ``frames``: one frame per array, or one frame of several planes."""
    buf = lv.arrays_to_buffer(np.stack(frames) if planes else list(frames))
    lv.write_buffer(buf, str(path))
    return path


@pytest.mark.parametrize("planes", [False, True])
def test_double_frame_buffer_reads_as_lvpyio_does(tmp_path, planes):
    rng = np.random.default_rng(1)
    a = rng.integers(0, 4096, (48, 64), dtype=np.uint16)  # 12-bit counts in 16-bit words
    b = rng.integers(0, 4096, (48, 64), dtype=np.uint16)
    p = _write_im7(tmp_path / "pair.im7", [a, b], planes)
    ref = [np.asarray(img) for frame in lv.read_buffer(str(p)) for img in frame.images]
    assert frame_count(p) == 2
    for k, want in enumerate((a, b)):
        got = read_image(p, k)
        assert got.dtype == np.uint16 and got.flags.c_contiguous
        np.testing.assert_array_equal(got, ref[k])
        np.testing.assert_array_equal(got, want)
    pa, pb = read_pair(p)
    np.testing.assert_array_equal(pa, a)
    np.testing.assert_array_equal(pb, b)
    info = davis_info(p)
    assert info["images"] == 2 and info["shape"] == (48, 64) and info["dtype"] == "uint16"
    assert info["x_scale"][2] and len(info["intensity_scale"]) == 3
    assert len(info["cameras"]) == 2 and all(isinstance(c, str) for c in info["cameras"])


def test_bad_davis_input_is_one_line(tmp_path, monkeypatch):
    a = np.zeros((16, 20), np.uint16)
    p = _write_im7(tmp_path / "one.im7", [a])
    with pytest.raises(rspiv.InvalidInputError, match=r"one.im7: frame 1 out of range \(1"):
        read_image(p, 1)
    good = _write_im7(tmp_path / "good.im7", [a + 7, a + 9])
    cut = tmp_path / "cut.im7"
    cut.write_bytes(good.read_bytes()[:200])
    with pytest.raises(rspiv.InvalidInputError, match="cut.im7: cannot read the DaVis buffer"):
        read_image(cut)
    # a campaign's double_frame glob (or .set) that matches nothing
    from rspiv.campaign_config import ImagesConfig

    for pattern in ("nothing/*.im7", "Nothing.set"):
        with pytest.raises(rspiv.InvalidInputError, match=r"\[images\].double_frame: no file"):
            ImagesConfig(double_frame=str(tmp_path / pattern)).double_frame_files()
    # without lvpyio: the error says how to install it
    monkeypatch.setitem(sys.modules, "lvpyio", None)
    other = tmp_path / "other.im7"
    other.write_bytes(good.read_bytes())
    with pytest.raises(rspiv.InvalidInputError, match=r"pip install 'rspiv\[davis\]'"):
        read_image(other)


def test_campaign_on_double_frame_davis_files_equals_the_tiff_run(tmp_path, capsys):
    from rspiv.campaign_config import load_campaign_config
    from rspiv.cli import main

    d = tmp_path / "c"
    synth = ["synth", "campaign", str(d), "--pairs", "3", "--scale", "0.1", "--monte-carlo", "0"]
    assert main([*synth, "-q"]) == 0
    cfg = load_campaign_config(d / "campaign.toml")
    cfg.correction.compare_uncorrected = False
    cfg.output.report = False
    cfg.save(d / "tiff.toml")
    tifs = sorted((d / "raw").glob("*.tif"))
    run = d / "Run"
    run.mkdir()
    for k in range(0, len(tifs), 2):
        a, b = tifffile.imread(tifs[k]), tifffile.imread(tifs[k + 1])
        _write_im7(run / f"B{k // 2 + 1:05d}.im7", [a, b])
    (d / "Run.set").write_text("DaVis set stand-in: the frames are in Run/\n")
    cfg.images.glob = None
    cfg.images.double_frame = str(d / "Run.set")
    cfg.save(d / "davis.toml")
    assert load_campaign_config(d / "davis.toml").images.double_frame.endswith("Run.set")
    assert main(["process", str(d / "tiff.toml"), "-q", "-o", str(tmp_path / "t")]) == 0
    assert main(["process", str(d / "davis.toml"), "-q", "-o", str(tmp_path / "v")]) == 0
    import xarray as xr

    t = xr.load_dataset(tmp_path / "t" / "statistics_method_II.nc", engine="h5netcdf")
    v = xr.load_dataset(tmp_path / "v" / "statistics_method_II.nc", engine="h5netcdf")
    np.testing.assert_array_equal(t["u"].values, v["u"].values)
    np.testing.assert_array_equal(t["count"].values, v["count"].values)
    # a truncated buffer in the run: that pair is skipped with one line naming the file
    first = sorted(run.glob("*.im7"))[0]
    first.write_bytes(first.read_bytes()[:300])
    assert main(["process", str(d / "davis.toml"), "-q", "-o", str(tmp_path / "cut")]) == 0
    log = (tmp_path / "cut" / "run_log.jsonl").read_text().splitlines()
    skipped = [r["reason"] for r in map(json.loads, log) if r["event"] == "skipped"]
    assert len(skipped) == 1 and f"{first.name}: cannot read the DaVis buffer" in skipped[0]
    # every buffer truncated: refused in one line, nothing written
    for f in run.glob("*.im7"):
        f.write_bytes(f.read_bytes()[:300])
    capsys.readouterr()
    assert main(["process", str(d / "davis.toml"), "-q", "-o", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot read the DaVis buffer" in err, err
    assert not any((tmp_path / "none").iterdir())


def test_cli_piv_reads_a_double_frame_buffer_and_reports_its_scale(tmp_path, capsys):
    from rspiv.cli import main
    from rspiv.synth import particle_pair

    a, b = particle_pair((128, 160), (2.5, -1.0), seed=3)
    p = _write_im7(tmp_path / "B00001.im7", [a, b])
    out = tmp_path / "f.dat"
    assert main(["piv", str(p), "-o", str(out), "--passes", "64x64,32x32"]) == 0
    said = capsys.readouterr().out
    assert "DaVis buffer" in said and "2 image(s) 160 x 128 uint16" in said
    data, aux = rspiv.read_tecplot(out)
    assert "davis_x_scale" in aux
    assert abs(np.median(data["u"][data["chc"] == 1]) - 2.5) < 0.05


def test_a_davis_buffer_is_checked_before_a_campaign(tmp_path, capsys):
    """``rspiv check run.im7``: a double-frame DaVis buffer (12-bit counts in 16-bit words) is
    read as the pair and checked like TIFFs: the same figures."""
    from rspiv.cli import main
    from rspiv.synth.particles import particle_pair

    a, b = particle_pair((256, 384), (5.0, 1.0), 0.02, 2.5, 0.05, seed=3)
    p = _write_im7(tmp_path / "run.im7", [a, b])
    out = tmp_path / "check.json"
    assert main(["check", str(p), "--json", str(out)]) == 0
    assert "recommended passes" in capsys.readouterr().out
    got = json.loads(out.read_text())
    want = rspiv.check_recording(a, b)
    assert got["density"] == pytest.approx(want.density)
    assert got["passes"] == [list(s) for s in want.passes]
    assert abs(got["density"] / 0.02 - 1.0) < 0.1


def _timed_im7(path, frames, times):
    """A DaVis buffer whose frames carry acquisition times (``AcqTimeSeries``, as DaVis writes
    them: a number and a unit)."""
    buf = lv.arrays_to_buffer(list(frames))
    for f, t in zip(buf, times, strict=True):
        f.attributes["AcqTimeSeries"] = t
    lv.write_buffer(buf, str(path))
    return path


def test_the_files_pulse_separation(tmp_path):
    """The time between a double-frame buffer's frames (rspiv.io.davis_frame_dt) and a
    campaign's [flow] dt held against it."""
    from rspiv.campaign.runner import davis_timing
    from rspiv.campaign_config import CampaignConfig
    from rspiv.io import davis_frame_dt

    a = np.zeros((16, 20), np.uint16)
    p = _timed_im7(tmp_path / "t.im7", [a, a + 1], ["1000 \u00b5s", "1060 \u00b5s"])
    assert davis_frame_dt(p) == pytest.approx(60e-6, rel=1e-12)
    assert davis_frame_dt(_timed_im7(tmp_path / "ms.im7", [a, a], ["2 ms", "2.5 ms"])) == (
        pytest.approx(0.5e-3, rel=1e-12)
    )
    # no times (lvpyio writes "no acquisition time series value"), one frame, the same time
    assert davis_frame_dt(_write_im7(tmp_path / "plain.im7", [a, a + 1])) is None
    assert davis_frame_dt(_write_im7(tmp_path / "one.im7", [a])) is None
    assert davis_frame_dt(_timed_im7(tmp_path / "eq.im7", [a, a], ["5 us", "5 us"])) is None
    cut = tmp_path / "cut.im7"
    cut.write_bytes(p.read_bytes()[:200])
    with pytest.raises(rspiv.InvalidInputError, match="cut.im7: cannot read the DaVis buffer"):
        davis_frame_dt(cut)

    class Camp:
        def __init__(self, dt):
            self.config = CampaignConfig()
            self.config.flow.dt = dt
            self.said = []

        def say(self, text):
            self.said.append(text)

    right, wrong, none = Camp(60e-6), Camp(120e-6), Camp(0.0)
    assert davis_timing(right, p) == {"file": str(p), "dt_s": pytest.approx(60e-6)}
    assert not right.said
    info = davis_timing(wrong, p)
    assert "every velocity reads 0.5x its true value" in info["warning"]
    assert wrong.said[0].startswith("WARNING: [flow] dt = 0.00012 s, but t.im7's frames")
    assert "warning" not in davis_timing(none, p) and "[flow] dt = 6e-05 gives" in none.said[0]
    assert davis_timing(right, tmp_path / "plain.im7") is None
