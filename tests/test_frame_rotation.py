"""Frames recorded with the camera on its side or through a mirror (``[images] rotate`` and
``mirror``): every frame, the target and the mask image are oriented as they are read, so that
a campaign of turned and mirrored files equals the campaign of the upright files (the flow along
+x), bit for bit."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
import tifffile
import xarray as xr
from campaign_cases import lean_file
from rspiv.campaign import Campaign
from rspiv.campaign_config import load_campaign_config
from rspiv.cli import main
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.io import read_mask, turn_frame

SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=3, monte_carlo_samples=200)


def test_a_turn_is_numpys_rot90_and_contiguous():
    a = np.arange(12, dtype=np.uint16).reshape(3, 4)
    assert turn_frame(a, 0) is a
    for k in range(1, 8):
        t = turn_frame(a, k)
        want = np.rot90(a[:, ::-1] if k >= 4 else a, k % 4)
        assert t.flags.c_contiguous and np.array_equal(t, want)
    for bad in (-1, 8):
        with pytest.raises(InvalidInputError, match="0-7"):
            turn_frame(a, bad)
    # one counter-clockwise turn: pixel (x, y) of a frame w px wide lands at (y, w - 1 - x)
    t = turn_frame(a, 1)
    for y in range(3):
        for x in range(4):
            assert t[4 - 1 - x, y] == a[y, x]


def test_a_mask_is_of_the_frames_as_recorded(tmp_path):
    # recorded frames 40 px tall and 60 wide; the campaign sees them turned once: 60 x 40
    poly = tmp_path / "mask.json"
    poly.write_text(json.dumps({"polygons": [[[-1, -1], [10, -1], [10, 5], [-1, 5]]]}))
    m = read_mask(poly, (60, 40), turn=1)
    assert m.shape == (60, 40)
    # the recorded top-left corner (x 0-10, y 0-5) is the turned frame's bottom-left
    assert m[-11:, :6].all() and m.sum() == 11 * 6
    img = tmp_path / "mask.tif"
    raw = np.zeros((40, 60), np.uint8)
    raw[:6, :11] = 1
    tifffile.imwrite(img, raw)
    assert np.array_equal(read_mask(img, (60, 40), turn=1), m)
    with pytest.raises(InvalidInputError, match="as recorded"):
        read_mask(img, (40, 60), turn=1)


def test_the_key_is_a_quarter_turn(tmp_path):
    base = "[images]\nglob = 'raw/*.tif'\n[correction]\nmethod = 'none'\n"
    (tmp_path / "raw").mkdir()
    toml = tmp_path / "c.toml"
    toml.write_text(base)
    im = load_campaign_config(toml).images
    assert (im.rotate, im.mirror, im.orientation()) == (0, False, 0)
    toml.write_text(base.replace("[correction]", "rotate = 270\nmirror = true\n[correction]"))
    im = load_campaign_config(toml).images
    assert (im.rotate, im.mirror, im.orientation()) == (270, True, 7)
    for key, bad in (("rotate", "45"), ("rotate", "true"), ("rotate", "'90'"),
                     ("rotate", "360"), ("mirror", "1"), ("mirror", "'yes'")):  # fmt: skip
        toml.write_text(base.replace("[correction]", f"{key} = {bad}\n[correction]"))
        with pytest.raises(InvalidInputError, match=key) as e:
            load_campaign_config(toml)
        assert "\n" not in str(e.value)


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    """The demo's layer (scale 0.15, 3 pairs) as recorded, and the same files turned a quarter
    turn clockwise and mirrored left-right (a camera on its side looking through a mirror: the
    flow runs up the frames, the wall along a column) with ``rotate = 90`` and ``mirror =
    true``; both with a mask image of a corner, each in its own files' orientation."""
    d = tmp_path_factory.mktemp("upright")
    toml = synth_campaign(d, scene=SCENE)
    lean_file(toml, uncorrected=False, report=False)
    shape = tifffile.imread(d / "target.tif").shape
    mask = np.zeros(shape, np.uint8)
    mask[: shape[0] // 4, -shape[1] // 5 :] = 255
    tifffile.imwrite(d / "mask.tif", mask)
    text = toml.read_text().replace('mask = ""', 'mask = "mask.tif"')
    assert 'mask = "mask.tif"' in text
    toml.write_text(text)
    t = tmp_path_factory.mktemp("turned")
    (t / "raw").mkdir()
    for f in [d / "target.tif", d / "mask.tif", *sorted((d / "raw").glob("*.tif"))]:
        tifffile.imwrite(t / f.relative_to(d), np.rot90(tifffile.imread(f), -1)[:, ::-1])
    shutil.copy(toml, t / "campaign.toml")
    text = (t / "campaign.toml").read_text()
    assert text.count("\nrotate = 0\n") == 1 and text.count("\nmirror = false\n") == 1
    text = text.replace("\nrotate = 0\n", "\nrotate = 90\n")
    (t / "campaign.toml").write_text(text.replace("\nmirror = false\n", "\nmirror = true\n"))
    out = {}
    for name, folder in (("upright", d), ("turned", t)):
        camp = Campaign.load(folder / "campaign.toml", progress=False)
        out[name] = (folder, camp.run())
    return out


def test_turned_files_give_the_upright_campaign_bit_for_bit(campaigns):
    (_, up), (_, turned) = campaigns["upright"], campaigns["turned"]
    assert up.n_done == turned.n_done == SCENE.pairs
    assert set(turned.accumulators) == set(up.accumulators)
    for run in up.accumulators:
        with (
            xr.open_dataset(up.out_dir / f"statistics_{run}.nc", engine="h5netcdf") as a,
            xr.open_dataset(turned.out_dir / f"statistics_{run}.nc", engine="h5netcdf") as b,
        ):
            assert set(a.data_vars) == set(b.data_vars)
            for name in a.data_vars:
                np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
            # the mask's corner: no vector there in either
            assert int(a["count"].values.min()) == 0
    # the calibration, the wall, u_tau and every figure of each run
    runs_up = json.loads((up.out_dir / "summary.json").read_text())["runs"]
    runs_turned = json.loads((turned.out_dir / "summary.json").read_text())["runs"]
    assert runs_up == runs_turned
    assert np.isfinite(runs_up["method_II"]["u_tau"])


def test_a_turned_campaign_is_checked_as_it_runs(campaigns, capsys):
    t, _ = campaigns["turned"]
    assert main(["check", str(t / "campaign.toml"), "--samples", "2"]) == 0
    assert "first pair" in capsys.readouterr().out
