"""A region of interest (``PivSettings.roi``): every pass's grid laid out in it, the frame's px
kept, only the region and a margin read; the whole frame's vectors inside it for the plain PIV
and Methods I and II, from the API, the command line and a campaign, and bad regions refused in
one line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import rspiv
import tifffile
from campaign_cases import lean_file
from lens_cases import frames_through, p3_mapping, strong_lens
from rspiv.campaign import Campaign
from rspiv.cli import main
from rspiv.correction import final_grid, method_two
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.synth import particle_pair


def flow(x, y):
    return 2.0 + 1.5 * np.sin(2 * np.pi * y / 300), 0.6 * np.cos(2 * np.pi * x / 400)


@pytest.fixture(scope="module")
def pair():
    return particle_pair((512, 768), flow, seed=3)


def test_a_single_pass_in_a_region_is_the_whole_frames_pass_there(pair):
    """Where the region's grid coincides with the whole frame's (32 px windows every 16 px from
    15.5 px), the windows hold the same pixels: the same vectors, bit for bit, away from the
    region's edge (the median test and the pooled uncertainty reach one neighbour out)."""
    a, b = pair
    s = rspiv.PivSettings(passes=((32, 32),), deformation="offset")
    whole = rspiv.piv(a, b, settings=s)
    f = rspiv.piv(a, b, settings=s.replace(roi=(96, 64, 288, 224)))
    assert f.u.shape == (9, 11) and f.grid == (111.5, 79.5, 16.0, 16.0)
    inner = np.s_[1:-1, 1:-1]
    there = np.s_[5:12, 7:16]  # the whole frame's rows 4 + 1 .. and columns 6 + 1 ..
    for name in ("x", "y", "u", "v", "valid", "sigma_u", "sigma_v", "peak_ratio"):
        np.testing.assert_array_equal(getattr(f, name)[inner], getattr(whole, name)[there], name)


@pytest.mark.parametrize("deformation", ["offset", "symmetric"])
def test_the_papers_passes_in_a_region_are_the_whole_frames(pair, deformation):
    """Every pass on the whole frame's grid cut to the region and two rings: with window offset
    every vector of the region is the whole frame's, bit for bit; with symmetric deformation
    (whose predictor's window average reaches past the rings) within 0.005 px on the outer
    vectors (measured 0.0050) and 0.002 px from 20 px inside the edge (measured 0.0012)."""
    a, b = pair
    roi = (100, 150, 600, 450)
    whole = rspiv.piv(a, b, deformation=deformation)
    f = rspiv.piv(a, b, roi=roi, deformation=deformation)
    j0 = int(np.flatnonzero(whole.y[:, 0] == f.y[0, 0])[0])
    i0 = int(np.flatnonzero(whole.x[0] == f.x[0, 0])[0])
    there = np.s_[j0 : j0 + f.u.shape[0], i0 : i0 + f.u.shape[1]]
    np.testing.assert_array_equal(f.x, whole.x[there])
    np.testing.assert_array_equal(f.y, whole.y[there])
    if deformation == "offset":
        for name in ("u", "v", "valid", "replaced", "sigma_u", "sigma_v", "peak_ratio"):
            np.testing.assert_array_equal(getattr(f, name), getattr(whole, name)[there], name)
        return
    d = np.hypot(f.u - whole.u[there], f.v - whole.v[there])
    edge = np.minimum.reduce([f.x - roi[0], roi[2] - f.x, f.y - roi[1], roi[3] - f.y])
    assert d.max() < 0.01 and d[edge >= 20].max() < 0.002, (d.max(), d[edge >= 20].max())


def test_the_papers_passes_in_a_region_are_as_accurate_and_faster(pair):
    a, b = pair
    roi = (0, 300, 400, 512)
    whole = rspiv.piv(a, b)
    f = rspiv.piv(a, b, roi=roi)
    assert f.x.min() > 0 and f.x.max() < 400 and f.y.min() > 300 and f.y.max() < 512
    np.testing.assert_array_equal((f.x, f.y), final_grid(a.shape, rspiv.PivSettings(roi=roi)))

    def err(g):
        tu, tv = flow(g.x, g.y)
        inside = (g.x > 16) & (g.x < 384) & (g.y > 316) & (g.y < 496) & g.valid
        return np.sqrt(np.mean(((g.u - tu) ** 2 + (g.v - tv) ** 2)[inside])), inside.sum()

    (e_roi, n_roi), (e_whole, n_whole) = err(f), err(whole)
    assert n_roi > 1000 and n_whole > 1000
    assert e_roi < 1.15 * e_whole + 0.005, (e_roi, e_whole)


@pytest.mark.parametrize(
    "roi, match",
    [
        ((0, 0, 800, 100), r"roi \[0, 0, 800, 100\] reaches beyond the frames \(768 x 512 px\)"),
        ((0, 0, 40, 100), r"roi \[0, 0, 40, 100\] \(40 x 100 px\) holds no 64 x 64 px window"),
        ((10, 0, 10, 100), r"roi \[10, 0, 10, 100\] is empty"),
        ((0, 0, 100), r"roi must be \(x0, y0, x1, y1\)"),
        ((0, -1, 100, 100), r"four whole px >= 0"),
    ],
)
def test_bad_regions_are_refused_in_one_line(pair, roi, match):
    a, b = pair
    with pytest.raises(rspiv.InvalidInputError, match=match):
        rspiv.piv(a, b, roi=roi)


def test_points_refuse_a_region(pair):
    a, b = pair
    s = rspiv.PivSettings(roi=(0, 0, 200, 200))
    from rspiv.multipass import run_points

    with pytest.raises(rspiv.InvalidInputError, match="leave roi out"):
        run_points(a, b, np.array([[100.0, 100.0]]), [(32, 32)], s, iterations=1)


SHAPE = (400, 640)
U_OBJ, V_OBJ = 9.0, 1.5


@pytest.fixture(scope="module")
def lens_case():
    lens = strong_lens(SHAPE)
    return p3_mapping(lens, SHAPE), frames_through(lens, SHAPE, (U_OBJ, V_OBJ), 7, 11)


@pytest.mark.parametrize(
    "method, deformation", [("I", "symmetric"), ("II", "symmetric"), ("II", "offset")]
)
def test_methods_in_a_region_of_the_object_frame(lens_case, method, deformation):
    """The object grid cut to the region (object px); its vectors those of the whole object
    frame at the same points: Method II with window offset bit for bit (its raw region's
    predictor passes on the whole raw grid), with deformation within 1e-4 px (measured 3e-5),
    Method I within 0.001 px (measured 0.0002: the dewarped region's coarse map differs from
    the whole frame's within its 1e-3 px)."""
    mapping, (a, b) = lens_case
    roi = (160, 100, 480, 300)
    kw = {"calibration": mapping, "method": method, "deformation": deformation}
    whole = rspiv.piv(a, b, **kw)
    f = rspiv.piv(a, b, roi=roi, **kw)
    assert f.u.shape == (49, 19) and f.grid[:2] == (175.5, 103.5)
    there = np.s_[25:74, 10:29]
    np.testing.assert_array_equal(f.x, whole.x[there])
    np.testing.assert_array_equal(f.y, whole.y[there])
    ok = f.valid & whole.valid[there]
    assert ok.mean() > 0.9
    d = np.hypot(f.u - whole.u[there], f.v - whole.v[there])[ok]
    if (method, deformation) == ("II", "offset"):
        np.testing.assert_array_equal(f.u, whole.u[there])
        # the final pass ran with two more rings: the outer vectors pooled their uncertainty
        # with the same neighbours
        np.testing.assert_array_equal(f.sigma_v, whole.sigma_v[there])
        np.testing.assert_array_equal(f.valid, whole.valid[there])
    assert d.max() < (0.001 if method == "I" else 1e-4), d.max()
    assert np.sqrt(np.mean((f.u[ok] - U_OBJ) ** 2 + (f.v[ok] - V_OBJ) ** 2)) < 0.05


def test_method_two_with_a_predictor_in_a_region(lens_case):
    """The campaign's path: the uncorrected field of the region (raw px) is Method II's
    predictor; the raw frames are cropped around the object grid's images."""
    mapping, (a, b) = lens_case
    s = rspiv.PivSettings(roi=(160, 100, 480, 300), deformation="offset")
    raw = rspiv.piv(a, b, settings=s)
    f = method_two(a, b, mapping, s, predictor=raw)
    s0 = s.replace(roi=None)
    whole = method_two(a, b, mapping, s0, predictor=rspiv.piv(a, b, settings=s0))
    np.testing.assert_array_equal(f.x, whole.x[25:74, 10:29])
    ok = f.valid & whole.valid[25:74, 10:29]
    assert ok.mean() > 0.9
    d = np.hypot(f.u - whole.u[25:74, 10:29], f.v - whole.v[25:74, 10:29])[ok]
    # measured 0.0011 px at most, 86 % bit for bit: the raw region's predictor is held at its
    # edge where the object grid's outer images lie beyond it
    assert d.max() < 0.002 and np.mean(d == 0) > 0.7, (d.max(), np.mean(d == 0))
    assert np.sqrt(np.mean((f.u[ok] - U_OBJ) ** 2 + (f.v[ok] - V_OBJ) ** 2)) < 0.05


def test_command_line_region(pair, tmp_path, capsys):
    import xarray as xr

    a, b = pair
    pa, pb = tmp_path / "a.tif", tmp_path / "b.tif"
    tifffile.imwrite(pa, a)
    tifffile.imwrite(pb, b)
    out = tmp_path / "f.nc"
    assert main(["piv", str(pa), str(pb), "--roi", "0,300,400,512", "-o", str(out)]) == 0
    with xr.open_dataset(out, engine="h5netcdf") as ds:
        assert float(ds["x"].min()) > 0 and float(ds["x"].max()) < 400
        assert float(ds["y"].min()) > 300
        assert json.loads(ds.attrs["piv_settings"])["roi"] == [0, 300, 400, 512]
    capsys.readouterr()
    assert main(["piv", str(pa), str(pb), "--roi", "0,300,900,512", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "reaches beyond the frames (768 x 512 px)" in err[0], err
    assert main(["piv", str(pa), str(pb), "--roi", "0,300,a,512", "-o", str(out)]) == 2
    assert "--roi: '0,300,a,512' is not X0,Y0,X1,Y1" in capsys.readouterr().err


SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=3, monte_carlo_samples=500)


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    d = tmp_path_factory.mktemp("synth_roi")
    synth_campaign(d, scene=SCENE)
    lean_file(d / "campaign.toml")  # the profile, the wall and the report
    return d


def _with_roi(synth, tmp_path, roi):
    text = (synth / "campaign.toml").read_text()
    text = text.replace("[piv]\n", f"[piv]\nroi = {list(roi)}\n", 1)
    text = text.replace('glob = "raw/', f'glob = "{synth}/raw/').replace(
        'target = "target.tif"', f'target = "{synth}/target.tif"'
    )
    toml = tmp_path / "campaign.toml"
    toml.write_text(text)
    return toml


def test_a_campaign_in_a_region_holding_the_wall(synth, tmp_path):
    """The scene's wall lies at y = 745 px of its 1330 x 793 px sensor, the flow above it, and
    its boundary layer is about 540 px thick: a region of its lower 693 px rows gives the whole
    campaign's wall, friction velocity and profile there."""
    whole = Campaign.load(synth / "campaign.toml", progress=False).run()
    part = Campaign.load(_with_roi(synth, tmp_path, (0, 100, 1330, 793)), progress=False).run()
    assert part.n_done == whole.n_done == 3
    # the recording checks look at the region only (its lit blocks within it)
    rec = json.loads((part.out_dir / "summary.json").read_text())["recording"]
    assert rec["lit_box"][1] >= 64 and rec["lit_fraction"] > 0.9
    assert json.loads((whole.out_dir / "summary.json").read_text())["recording"]["lit_box"][1] == 0
    sw = json.loads((whole.out_dir / "summary.json").read_text())["runs"]
    sp = json.loads((part.out_dir / "summary.json").read_text())["runs"]
    for run in ("method_II", "uncorrected"):
        ww, wp = sw[run]["wall"], sp[run]["wall"]
        assert abs(ww["intercept_px"] - wp["intercept_px"]) < 0.1, (run, ww, wp)
        assert abs(sp[run]["u_tau"] / sw[run]["u_tau"] - 1) < 0.01, run
    import xarray as xr

    with (
        xr.open_dataset(whole.out_dir / "statistics_method_II.nc", engine="h5netcdf") as dw,
        xr.open_dataset(part.out_dir / "statistics_method_II.nc", engine="h5netcdf") as dp,
    ):
        # y is the distance from the wall (m): the region's rows are the whole grid's nearest
        y = dp["y"].values
        assert dp.sizes["y"] < 0.9 * dw.sizes["y"] and y.max() < 0.9 * float(dw["y"].max())
        u_w = dw["u"].sel(y=y[5:-5], method="nearest").mean("x").values
        u_p = dp["u"].isel(y=slice(5, -5)).mean("x").values
        ok = np.isfinite(u_w) & np.isfinite(u_p)
        assert ok.sum() > 20
        np.testing.assert_allclose(u_p[ok], u_w[ok], rtol=0.01, atol=0.01)


def test_a_campaign_region_that_cuts_the_layer_says_so(synth, tmp_path, capsys):
    """A region of 345 px rows above the wall, less than the layer's 540 px: the profile has no
    free stream, and the friction velocity it gives is biased (2 % here); said in one line per
    run on stderr, in summary.json and in the report."""
    toml = _with_roi(synth, tmp_path, (0, 400, 1330, 793))
    assert main(["process", str(toml)]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "no free stream in the field" in line]
    assert len(lines) == 2, err  # Method II and the uncorrected run
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    for run in ("method_II", "uncorrected"):
        assert "no free stream" in summary["runs"][run]["profile_warning"]
    report = (tmp_path / "out" / "report" / "report.md").read_text()
    assert "No free stream in the field" in report


def test_a_campaign_region_without_the_wall_is_refused(synth, tmp_path, capsys):
    toml = _with_roi(synth, tmp_path, (0, 0, 1330, 400))
    rc = main(["process", str(toml)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "wall" in err.lower(), err


def test_a_campaign_region_is_checked_on_loading(synth, tmp_path, capsys):
    toml = _with_roi(synth, tmp_path, (0, 400, 1330))
    assert main(["process", str(toml)]) == 2
    err = capsys.readouterr().err
    assert "roi" in err and "four whole px" in err, err


def test_the_engine_region_is_the_apis(pair, tmp_path, engine):
    """``rspiv-engine piv --roi`` gives ``rspiv.piv(roi=...)``'s vectors; a bad region exits
    non-zero with one line."""
    import subprocess

    a, b = pair
    pa, pb = tmp_path / "a.tif", tmp_path / "b.tif"
    tifffile.imwrite(pa, a)
    tifffile.imwrite(pb, b)
    out = tmp_path / "f.csv"
    cmd = [engine, "piv", str(pa), str(pb), "-o", str(out)]
    r = subprocess.run([*cmd, "--roi", "0,300,400,512"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    data = np.genfromtxt(out, delimiter=",", names=True)
    f = rspiv.piv(a, b, roi=(0, 300, 400, 512))
    np.testing.assert_array_equal(data["x"], f.x.ravel())
    np.testing.assert_array_equal(data["y"], f.y.ravel())
    ok = ~np.isnan(f.u.ravel())
    assert np.max(np.abs(data["u"][ok] - f.u.ravel()[ok])) <= 1e-9
    r = subprocess.run([*cmd, "--roi", "0,300,900,512"], capture_output=True, text=True)
    assert r.returncode != 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "reaches beyond the frames (768 x 512 px)" in lines[0], r.stderr
