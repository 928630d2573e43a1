"""``rspiv init``: a campaign file written from a recording (:mod:`rspiv.campaign_init`).

Ground truth: recordings rendered here with a known pairing and flow direction
(:func:`rspiv.synth.particle_sequence`: a time-resolved recording; independent pairs of it: a
double-frame camera), and a synthetic campaign (``rspiv synth campaign``) whose friction
velocity is known: the file ``init`` writes from its frames and target processes to it.
"""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pytest
import rspiv
import tifffile
from rspiv.campaign import Campaign
from rspiv.campaign_config import load_campaign_config
from rspiv.campaign_init import (
    choose_pairing,
    frame_marks,
    images_source,
    init_campaign,
    quarter_turn,
    wall_passes,
)
from rspiv.cli import main
from rspiv.io import turn_frame
from rspiv.recording import coarse_pass, median_displacement
from rspiv.synth import particle_sequence

REAL_DATA = pathlib.Path(__file__).parent / "data" / "real"
SHAPE = (192, 256)


def _write(d, frames, names=None):
    d.mkdir(parents=True, exist_ok=True)
    for k, f in enumerate(frames):
        tifffile.imwrite(d / (names[k] if names else f"f_{k:03d}.tif"), f)
    return d


def _sequence(d, u, v, frames=4, seed=5):
    return _write(d, particle_sequence(SHAPE, (u, v), frames, seed=seed))


def _double_frame(d, u=4.0, v=0.0, pairs=3, names=None):
    frames = []
    for s in range(pairs):  # each pair its own particles: the next pair's frame A is unrelated
        frames += particle_sequence(SHAPE, (u, v), 2, seed=10 + s)
    return _write(d, frames, names)


def test_quarter_turn_matches_turn_frame():
    """The turn brings the displacement to +x on frames turned by rspiv.io.turn_frame."""
    img = np.zeros((9, 11))
    for u, v in [(3, 0.5), (0.2, 3), (-3, -1), (1, -3), (2, 2.1), (-2, 1.9)]:
        k = quarter_turn(u, v)
        a, b = img.copy(), img.copy()
        a[4, 5] = 1
        b[4 + round(v), 5 + round(u)] = 1  # (x, y) = column, row
        ya, xa = np.argwhere(turn_frame(a, k))[0]
        yb, xb = np.argwhere(turn_frame(b, k))[0]
        du, dv = xb - xa, yb - ya
        assert du > 0 and du >= abs(dv), (u, v, k, du, dv)


@pytest.mark.parametrize(
    ("u", "v", "rotate"), [(3, 0, 0), (0, 3, 90), (-3, 0, 180), (0.4, -3, 270)]
)
def test_time_resolved_recording_any_direction(tmp_path, u, v, rotate):
    d = _sequence(tmp_path / "rec", u, v)
    found = init_campaign(d)
    im = found.config.images
    assert im.glob.endswith("*.tif") and im.pairing == "sequential" and im.rotate == rotate
    assert "a time-resolved recording" in found.notes[("images", "pairing")]
    a, b = (turn_frame(tifffile.imread(d / f"f_00{k}.tif"), rotate // 90) for k in (0, 1))
    mu, mv = median_displacement(coarse_pass(a, b, None, a.shape)[0])
    assert mu == pytest.approx(np.hypot(u, v), abs=0.05) and abs(mv) < 0.5
    # no target: no correction, the outputs in px, said
    assert found.config.correction.method == "none"
    assert any("no target given" in s for s in found.said)
    assert any("[flow] dt" in s for s in found.said) and any("[flow] nu" in s for s in found.said)


def test_double_frame_camera_and_what_cannot_be_told(tmp_path):
    found = init_campaign(_double_frame(tmp_path / "dbl"))
    assert found.config.images.pairing == "pairs"
    assert "2-3 do not correlate: a double-frame camera" in found.notes[("images", "pairing")]
    assert not any("pairing" in s for s in found.said)
    # frames that hardly move cannot tell the two apart: said, pairs written
    still = _sequence(tmp_path / "still", 0.05, 0.0)
    found = init_campaign(still)
    assert found.config.images.pairing == "pairs"
    assert any("they hardly move" in s and "cannot be told" in s for s in found.said)
    assert any("does not orient the frames" in s for s in found.said)
    assert found.config.images.rotate == 0
    # an oblique flow is said
    found = init_campaign(_sequence(tmp_path / "oblique", 3.0, 1.5))
    said = [s for s in found.said if "degrees from the nearest image axis" in s]
    assert len(said) == 1 and said[0].startswith("[images] rotate: the flow runs 27 degrees")


def test_file_names_marking_frames(tmp_path):
    assert frame_marks(["x_01_A.tif", "x_01_B.tif", "x_02a.tif", "x_02b.tif"]) == "alternate"
    assert frame_marks(["f_000.tif", "f_001.tif"]) is None
    assert frame_marks(["P_0001_A.tif", "P_0002_A.tif", "P_1001_B.tif", "P_1002_B.tif"]) == (
        "out of order"
    )
    # names that alternate A, B win over frames that could also be sequential
    names = ["run_001_A.tif", "run_001_B.tif", "run_002_A.tif", "run_002_B.tif"]
    d = _write(tmp_path / "ab", particle_sequence(SHAPE, (3.0, 0.0), 4, seed=2), names)
    found = init_campaign(d)
    assert found.config.images.pairing == "pairs"
    assert found.notes[("images", "pairing")].startswith("file names alternate A, B")
    # marked but sorted A, A, B, B (OpenPIV's test6): a glob would pair them wrongly
    names = ["P_0001_A.tif", "P_0002_A.tif", "P_1001_B.tif", "P_1002_B.tif"]
    d = _double_frame(tmp_path / "bad", pairs=2, names=names)
    with pytest.raises(rspiv.InvalidInputError, match=r"mark frames A and B.*pair them wrongly"):
        init_campaign(d)


def test_pairing_of_few_frames():
    frames = particle_sequence(SHAPE, (3.0, 0.0), 2, seed=1)
    assert choose_pairing(frames)[0] == "pairs"
    assert choose_pairing(frames, camera=True)[0] == "sequential"


def test_wall_passes():
    # the paper's passes where a 32 x 8 window holds 10 particle images
    assert wall_passes(64, 0.04) == [(64, 64), (32, 32), (32, 8)]
    assert wall_passes(96, 0.0312) == [(96, 96), (48, 48), (48, 12)]
    assert wall_passes(32, 0.005) == [(32, 32), (32, 8)]  # sparse: as large as the first allows
    for first, density in [(64, 0.04), (128, 0.01), (256, 0.1), (16, 0.5)]:
        passes = wall_passes(first, density)
        w, h = passes[-1]
        assert passes[0] == (first, first) and w == 4 * h and h >= 4
        assert all(p[0] >= q[0] for p, q in zip(passes, passes[1:], strict=False))


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    d = tmp_path_factory.mktemp("init") / "sc"
    assert main(["synth", "campaign", str(d), "--pairs", "4", "--scale", "0.15", "-q"]) == 0
    return d, json.loads((d / "truth.json").read_text())


def test_synthetic_campaign_from_its_frames(synthetic, capsys):
    """The file written from the frames and the target alone (dt and nu given) processes to the
    campaign's friction velocity."""
    d, truth = synthetic
    pitch = load_campaign_config(d / "campaign.toml").calibration.pitch_mm
    toml = d / "init.toml"
    args = ["init", str(d / "raw"), "-o", str(toml), "--target", str(d / "target.tif")]
    args += ["--pitch-mm", str(pitch), "--dt", str(truth["dt"]), "--nu", str(truth["nu"])]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"wrote {toml}" in out and "[calibration] model: smallest held-out error" in out
    text = toml.read_text()
    assert text.startswith("# written by rspiv init")
    cfg = load_campaign_config(toml)
    im = cfg.images
    assert im.glob == str(d / "raw" / "*.tif") and im.pairing == "pairs" and im.rotate == 0
    assert cfg.calibration.model == "P3" and cfg.correction.method == "II"
    assert cfg.calibration.pitch_sigma_mm == 0.0  # estimated from the fit, as calibrate does
    assert cfg.piv.passes[-1][0] == 4 * cfg.piv.passes[-1][1]
    assert cfg.flow.dt == truth["dt"] and cfg.flow.nu == truth["nu"]
    assert cfg.statistics.min_count == 2  # 4 pairs
    # the pairs are the original campaign's
    orig = Campaign.load(d / "campaign.toml", progress=False).pairs()
    assert [(p.a, p.b) for p in Campaign(cfg, progress=False).pairs()] == [
        (p.a, p.b) for p in orig
    ]
    # a second time: refused without --force, one line, exit 2
    assert main(args) == 2
    assert "exists; give another name (-o) or --force" in capsys.readouterr().err
    # processed: the friction velocity of the flow
    camp = Campaign(cfg, progress=False, out_dir=d / "out_init")
    camp.run()
    summary = json.loads((d / "out_init" / "summary.json").read_text())
    got = summary["runs"]["method_II"]["u_tau"]
    assert got == pytest.approx(truth["u_tau"], rel=0.005)  # measured: -0.06 %
    # held against the DNS with its final window in wall units (rspiv.reference_comparison)
    ref = summary["runs"]["method_II"]["reference"]
    w, h = cfg.piv.passes[-1]
    lv_px = truth["viscous_length_px"]
    assert ref["window_plus"] == pytest.approx([w / lv_px, h / lv_px], rel=0.01)
    assert ref["bands"] and "Against the DNS" in (d / "out_init/report/report.md").read_text()


def test_turned_camera(synthetic, tmp_path):
    """Frames and target recorded by a camera on its side: the turn that undoes it."""
    d, _ = synthetic
    raw = tmp_path / "raw"
    raw.mkdir()
    for f in sorted((d / "raw").glob("*.tif")):
        tifffile.imwrite(raw / f.name, np.rot90(tifffile.imread(f)))  # flow now along -y
    target = tmp_path / "target.tif"
    tifffile.imwrite(target, np.rot90(tifffile.imread(d / "target.tif")))
    found = init_campaign(raw, target=target, pitch_mm=2.9265)
    turn = found.config.images.rotate // 90
    assert turn == 3
    np.testing.assert_array_equal(
        turn_frame(tifffile.imread(target), turn), tifffile.imread(d / "target.tif")
    )
    assert found.config.calibration.model == "P3"
    # the target of another size than the frames is refused
    tifffile.imwrite(target, tifffile.imread(d / "target.tif"))  # not turned
    with pytest.raises(rspiv.InvalidInputError, match="target.tif: the target is .* the frames"):
        init_campaign(raw, target=target, pitch_mm=2.9265)


def test_camera_recording_gives_dt():
    """PIMS' real Phantom cine: a camera recording, paired sequentially, dt from its frames."""
    cine = REAL_DATA / "pims_cine_781_2frames.cine"
    found = init_campaign(cine)
    im = found.config.images
    assert im.multiframe == cine.resolve() and im.pairing == "sequential"
    assert found.config.flow.dt == pytest.approx(111.07e-6, rel=1e-3)
    assert "at 9003" in found.notes[("flow", "dt")]
    assert not any("[flow] dt" in s for s in found.said)
    # one frame only: refused
    with pytest.raises(rspiv.InvalidInputError, match="1 frame.*a pair needs two"):
        init_campaign(REAL_DATA / "pymraw_beam_1frame.cihx")


def test_davis_double_frames(tmp_path):
    lv = pytest.importorskip("lvpyio", reason="DaVis buffers need lvpyio")
    run = tmp_path / "Run"
    run.mkdir()
    frames = particle_sequence(SHAPE, (-4.0, 0.0), 2, seed=3)
    for k in range(2):
        buf = lv.arrays_to_buffer([f.copy() for f in frames])
        for f, t in zip(buf, ("0 \u00b5s", "45 \u00b5s"), strict=True):
            f.attributes["AcqTimeSeries"] = t  # as DaVis writes each frame's time
        lv.write_buffer(buf, str(run / f"B{k:05d}.im7"))
    (tmp_path / "Run.set").write_text("DaVis set stand-in\n")
    for given in (run, tmp_path / "Run.set"):
        found = init_campaign(given)
        im = found.config.images
        assert im.double_frame is not None and im.pairing == "pairs" and im.rotate == 180
        assert found.notes[("images", "double_frame")] == "two images per file: frames A and B"
        assert found.config.flow.dt == pytest.approx(45e-6, rel=1e-12)
        assert "AcqTimeSeries" in found.notes[("flow", "dt")]
        assert not any("[flow] dt" in s for s in found.said)


def test_refusals(tmp_path):
    d = _sequence(tmp_path / "rec", 3.0, 0.0)
    with pytest.raises(rspiv.InvalidInputError, match="needs its marker pitch"):
        init_campaign(d, target=d / "f_000.tif")
    with pytest.raises(rspiv.InvalidInputError, match="method II needs a calibration target"):
        init_campaign(d, method="II")
    with pytest.raises(rspiv.InvalidInputError, match="method must be"):
        init_campaign(d, method="III")
    (tmp_path / "empty").mkdir()
    with pytest.raises(rspiv.InvalidInputError, match="empty: no image file"):
        images_source(tmp_path / "empty")
    with pytest.raises(rspiv.InvalidInputError, match="nothing_\\*.tif: no file matches"):
        images_source(tmp_path / "nothing_*.tif")
    with pytest.raises(rspiv.InvalidInputError, match="f_000.tif: one frame"):
        images_source(d / "f_000.tif")
    # frames of another size
    odd = tmp_path / "odd"
    shutil.copytree(d, odd)
    tifffile.imwrite(odd / "f_002.tif", np.zeros((64, 64), np.uint16))
    with pytest.raises(rspiv.InvalidInputError, match="f_002.tif: frame 0 is 64 x 64 px"):
        init_campaign(odd)
    # an odd number of files paired 1-2, 3-4
    dbl = _double_frame(tmp_path / "dbl")
    (dbl / "f_005.tif").unlink()
    with pytest.raises(rspiv.InvalidInputError, match="5 frames; pairs"):
        init_campaign(dbl)


def test_written_file(tmp_path):
    d = _sequence(tmp_path / "rec", 3.0, 0.0, frames=6)
    found = init_campaign(d, dt=1e-3, nu=1e-6, output_dir="results")
    path = found.write(tmp_path / "c.toml")
    text = path.read_text()
    assert "# CHECK: [calibration]" in text and 'dir = "results"' in text
    assert 'pairing = "sequential"  # frames 1-2 3.00 px, 2-3 3.00 px' in text
    cfg = load_campaign_config(path)
    assert cfg.flow.dt == 1e-3 and cfg.flow.nu == 1e-6
    assert cfg.output.dir == (tmp_path / "results").resolve()
    assert len(Campaign(cfg, progress=False).pairs()) == 5
    with pytest.raises(rspiv.InvalidInputError, match="c.toml: exists"):
        found.write(path)
    assert found.write(path, force=True) == path


def test_openpiv_recordings_as_a_user(tmp_path):
    """OpenPIV's real recordings (in the openpiv package, not vendored): test2 is a double-frame
    camera's six pairs whose flow runs along -x; processed, its mean profile's smooth minimum
    mirrors itself along a line tilted 10 degrees, which is refused as a wall. test6's names
    mark frames A and B that sort A, A, ..., B, B."""
    openpiv = pytest.importorskip("openpiv")
    data = pathlib.Path(openpiv.__file__).parent / "data"
    found = init_campaign(data / "test2")
    cfg = found.config
    assert cfg.images.pairing == "pairs" and cfg.images.rotate == 180
    assert cfg.piv.deformation == "symmetric" and cfg.piv.passes == [(48, 48), (48, 12)]
    toml = found.write(tmp_path / "c.toml")
    camp = Campaign.load(toml, progress=False)
    camp.run()
    summary = json.loads((tmp_path / "rspiv-out" / "summary.json").read_text())
    err = summary["runs"]["uncorrected"]["error"]
    assert "is tilted 10.0 degrees from the rows (at most 5)" in err and "extremum" in err
    with pytest.raises(rspiv.InvalidInputError, match="test6.*mark frames A and B"):
        init_campaign(data / "test6")


def test_slow_time_resolved_recording_gets_a_frame_gap_said(tmp_path):
    found = init_campaign(_sequence(tmp_path / "slow", 1.5, 0.0))
    assert found.config.images.pairing == "sequential" and found.config.images.frame_gap == 1
    (line,) = [s for s in found.said if s.startswith("[images] frame_gap")]
    first = found.config.piv.passes[0][0]
    gap = int(line.split("frame_gap = ")[1].split()[0])
    assert gap >= 2 and gap * 1.5 <= min(8.0, first / 4) + 0.1
    # a recording that moves enough gets none
    assert not any("frame_gap" in s for s in init_campaign(_sequence(tmp_path / "f", 9, 0)).said)


def test_two_level_plate(synthetic, tmp_path, monkeypatch):
    """A two-level plate: the level calibrated is written ([calibration] level, which the
    campaign passes to rspiv.calibrate) and said unless given."""
    from rspiv.synth import calibration_target

    d, _ = synthetic
    target = tmp_path / "two.tif"
    plate = calibration_target(scale=0.15, seed=1, levels=2, fiducial="missing")
    tifffile.imwrite(target, plate.image)
    found = init_campaign(d / "raw", target=target, pitch_mm=2.9265)
    assert found.config.calibration.level == 1
    assert any(s.startswith("[calibration] level: a two-level plate; level 1") for s in found.said)
    found = init_campaign(d / "raw", target=target, pitch_mm=2.9265, level=2)
    assert found.config.calibration.level == 2
    assert found.notes[("calibration", "level")] == "given"
    assert not any("level" in s for s in found.said)
    cfg = load_campaign_config(found.write(tmp_path / "c.toml"))
    assert cfg.calibration.level == 2
    # the campaign calibrates on that level
    import rspiv.campaign.prepare as prepare

    seen = {}

    class Stop(Exception):
        pass

    def calibrate(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(prepare, "calibrate", calibrate)
    with pytest.raises(Stop):
        Campaign(cfg, progress=False, out_dir=tmp_path / "out").prepare()
    assert seen["level"] == 2
    # a single-level target: level 0 (the default) written
    one = init_campaign(d / "raw", target=d / "target.tif", pitch_mm=2.9265)
    assert one.config.calibration.level == 0
    bad = (tmp_path / "c.toml").read_text().replace("level = 2", "level = 3")
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(rspiv.InvalidInputError, match=r"level: expected a value <= 2"):
        load_campaign_config(tmp_path / "bad.toml")
