"""Statistics in wall units from another tool's vector files (:mod:`rspiv.vector_statistics`).

Ground truth: series of the synthetic layer's exact fields written as DaVis and OpenPIV files
(``vector_series_cases``), whose mean profile, Reynolds stresses and friction velocity are the
flow's (:class:`rspiv.synth.tbl.TBLFlow`); through a strong known lens, the raw-frame fields a
tool measures, to be corrected by Method II.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import rspiv
from lens_cases import strong_lens
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.synth.tbl import TBLFlow
from rspiv.vector_statistics import vector_statistics
from vector_series_cases import exact_field, write_insight, write_series, write_vc7

pytest.importorskip("lvpyio", reason="the series are DaVis files (rspiv[davis])")
REAL = pathlib.Path(__file__).parent / "data" / "real"
FLOW = TBLFlow()
NU = FLOW.nu


def _errors(r):
    """Median and largest error of U+, uu+, vv+, uv+ against the flow, away from the wall."""
    res = r.result
    yp = res.y_plus
    far = res.extra["near_wall"] == 0
    uu, vv, uv = FLOW.stresses_plus(yp)
    out = {}
    for name, got, want in (("U", res.u_plus, FLOW.u_plus(yp)), ("uu", res.uu_plus, uu),
                            ("vv", res.vv_plus, vv), ("uv", res.uv_plus, uv)):  # fmt: skip
        d = (got - want)[far]
        out[name] = (float(np.nanmedian(d)), float(np.nanmax(np.abs(d))))
    return out


@pytest.fixture(scope="module")
def level(tmp_path_factory):
    folder = tmp_path_factory.mktemp("level")
    files, truth = write_series(folder, 80)
    return folder, files, truth


def test_a_davis_series_gives_the_flows_wall_units(level, tmp_path):
    folder, files, truth = level
    r = vector_statistics(str(folder / "*.vc7"), nu=NU)
    assert r.used == 80 and not r.skipped and r.tool == "DaVis" and r.window == (32, 32)
    # the scale and pulse separation come from the files' scales
    assert r.mm_per_px == pytest.approx(1 / truth.magnification, rel=1e-5)  # 6 digits
    assert r.dt == pytest.approx(truth.dt, rel=1e-5)
    assert r.warnings == []
    res = r.result
    assert res.u_tau == pytest.approx(truth.u_tau, rel=0.003)  # measured: +0.04 %
    assert res.delta99 * 1e3 == pytest.approx(FLOW.delta99_mm, rel=0.02)  # measured: -0.9 %
    err = _errors(r)
    assert abs(err["U"][0]) < 0.03 and err["U"][1] < 0.1
    for k in ("uu", "vv", "uv"):  # 80 independent fields: the stresses' own scatter
        assert abs(err[k][0]) < 0.03, (k, err[k])
    assert abs(r.analysis.wall.line(1000.0) - truth.wall_y(1000.0)) < 2.0
    # a dt given against the files' own: the files' is used, and said
    other = vector_statistics(files[:20], nu=NU, dt=2 * truth.dt)
    assert other.dt == r.dt and any("dt = " in w and "files'" in w for w in other.warnings)
    files_out = r.write(tmp_path / "out")
    assert {"statistics", "profile_nc", "profile_csv", "summary", "convergence_csv"} <= set(
        files_out
    )
    # 80 fields of one flow: the first 50 and the last 30 agree (rspiv.convergence)
    cv = r.convergence
    assert list(cv.pairs) == [10, 20, 50, 80] and cv.split == (50, 30) and cv.warning is None
    assert max(cv.summary()[f"beyond_{k}"] for k in ("U", "uu", "vv", "uv")) < 0.05
    ds = r.to_xarray()
    assert ds.attrs["tool"] == "DaVis" and ds["u"].attrs["units"] == "m s-1"
    # the command gives the same figures
    # the vorticity statistics: the mean is the flow's -dU+/dy+ away from the wall
    vort = vector_statistics(files, nu=NU, vorticity=True).vorticity
    far = ~vort["near_wall"] & (vort["y_plus"] < 2000)
    yp = vort["y_plus"][far]
    slope = (FLOW.u_plus(yp * 1.001) - FLOW.u_plus(yp * 0.999)) / (0.002 * yp)
    rel = vort["omega_mean_plus"][far] / -slope - 1
    # measured: median error -0.04 %, median |error| 4.2 % (2.3 % over 200 fields: noise)
    assert abs(np.median(rel)) < 0.01 and np.median(np.abs(rel)) < 0.06, rel
    out = tmp_path / "cli"
    cmd = ["statistics", str(folder), "--nu", repr(NU), "-o", str(out), "--figures"]
    assert main([*cmd, "--vorticity"]) == 0 and (out / "vorticity.nc").is_file()
    assert (out / "mean_velocity.png").stat().st_size > 10_000
    import json

    summ = json.loads((out / "summary.json").read_text())
    assert summ["u_tau"] == pytest.approx(res.u_tau, rel=1e-12) and summ["fields"] == 80
    assert summ["convergence"]["split_pairs"] == [50, 30] and (out / "convergence.png").is_file()
    # against the DNS the layer is built from (its inner layer, its outer layer in outer
    # scaling): every band agrees (measured: within 1.6 %)
    ref = summ["reference"]
    assert ref["reference"].startswith("DNS Re_theta=4061") and ref["differing"] == []
    assert {b["band"] for b in ref["bands"]} >= {"log layer", "outer layer"}
    assert max(abs(b["relative"]) for b in ref["bands"]) < 0.03
    # judged by the rows' scatter from field to field (80 fields), under the bound
    assert ref["errors"] == "pairs"
    over = res.eps_u_plus / res.extra["eps_U_plus_pairs"]
    assert np.nanmedian(over) > 1.5, np.nanmedian(over)
    lv_px = res.nu / res.u_tau / (r.mm_per_px * 1e-3)
    assert ref["window_plus"] == pytest.approx([32 / lv_px, 32 / lv_px], rel=1e-9)


def test_a_series_whose_flow_speeds_up_is_said(tmp_path):
    """60 exact fields of the layer, every displacement of the last 30 10 % larger (the tunnel
    faster, the files' scales the same): the first 20 fields against the other 40 (10 as
    before, 30 faster: U +7.5 %, +7.1 % of the whole series' U) say that U changed, with the
    change."""
    folder = tmp_path / "faster"
    folder.mkdir()
    files = []
    for k in range(60):
        tr, _, _, u, v = exact_field(k)
        g = 1.1 if k >= 30 else 1.0
        files.append(write_vc7(folder / f"B{k:05d}.vc7", g * u, g * v, 1 / tr.magnification, tr.dt))
    r = vector_statistics(files, nu=NU)
    cv = r.convergence
    assert cv.split == (20, 40) and "U" in cv.drifting and cv.warning in r.warnings
    judged = cv.judged & (cv.z["U"] > 4)
    assert abs(np.median(cv.change["U"][judged]) - 0.075 / 1.05) < 0.01
    assert "first 20 pairs and of the last 40 differ" in cv.warning


def test_openpiv_text_of_the_same_fields_sums_the_same(level, tmp_path):
    folder, files, truth = level
    for s in range(30):
        _, x, y, u, v = exact_field(s)
        flags = np.zeros(x.size)
        rows = np.column_stack([x.ravel() + 0.5, y.ravel() + 0.5, u.astype(np.float32).ravel(),
                                v.astype(np.float32).ravel(), flags, flags])  # fmt: skip
        np.savetxt(tmp_path / f"B{s:05d}.txt", rows, header="x y u v flags mask")
    davis = vector_statistics(files[:30], nu=NU)
    text = vector_statistics(
        str(tmp_path / "*.txt"), nu=NU, dt=truth.dt, mm_per_px=1 / truth.magnification,
        window=(32, 32),
    )  # fmt: skip
    a, b = davis.accumulator, text.accumulator
    np.testing.assert_allclose(b.mean_u, a.mean_u, rtol=0, atol=1e-5)
    np.testing.assert_allclose(b.m2_uu, a.m2_uu, rtol=1e-5, atol=1e-5)
    assert text.result.u_tau == pytest.approx(davis.result.u_tau, rel=1e-5)
    assert text.frame == "image" and any("lens distortion" in w for w in text.warnings)


def test_openpiv_files_in_mm_as_openpiv_saves_them(level, tmp_path):
    """OpenPIV's ``tools.save`` (``%.4e``) of fields scaled to mm and mm/s: 5 digits leave the
    nodes up to 0.02 px off their grid, which made the rows unequal (refused) before the reader
    put them back on it."""
    tools = pytest.importorskip("openpiv.tools", reason="OpenPIV is in the test extra")
    folder, files, truth = level
    mm = 1 / truth.magnification
    for s in range(20):
        _, x, y, u, v = exact_field(s)
        z = np.zeros(u.shape)
        tools.save(tmp_path / f"B{s:05d}.txt", (x + 0.5) * mm, (y + 0.5) * mm, u * mm / truth.dt,
                   v * mm / truth.dt, z, z)  # fmt: skip
    davis = vector_statistics(files[:20], nu=NU)
    text = vector_statistics(
        str(tmp_path / "*.txt"), nu=NU, dt=truth.dt, mm_per_px=mm, window=(32, 32),
        read_options={"scale": mm, "dt": truth.dt},
    )  # fmt: skip
    assert text.used == 20
    assert any(w.startswith("as read (") and "the file's rounding" in w for w in text.warnings)
    np.testing.assert_allclose(text.accumulator.mean_u, davis.accumulator.mean_u, atol=1e-3)
    assert text.result.u_tau == pytest.approx(davis.result.u_tau, rel=1e-4)


def test_insight_files_of_the_same_fields_give_the_same_wall_units(level, tmp_path):
    """TSI Insight's ``.vec`` (mm, m/s, y up, dt and the scale in the header): the same
    statistics as the DaVis files, the units taken from the files."""
    folder, files, truth = level
    mm = 1 / truth.magnification
    for s in range(30):
        _, x, y, u, v = exact_field(s)
        write_insight(tmp_path / f"Run{s:06d}.T000.D000.P000.H001.L.vec", x, y,
                      u.astype(np.float32), v.astype(np.float32), mm_per_px=mm, dt=truth.dt)
    davis = vector_statistics(files[:30], nu=NU)
    tsi = vector_statistics(tmp_path, nu=NU, window=(32, 32))
    assert tsi.tool == "Insight" and tsi.used == 30 and tsi.frame == "image"
    assert tsi.dt == pytest.approx(truth.dt, rel=1e-9)
    assert tsi.mm_per_px == pytest.approx(mm, rel=1e-6)  # the header's 6 decimals of a um
    a, b = davis.accumulator, tsi.accumulator
    np.testing.assert_allclose(b.mean_u, a.mean_u, rtol=0, atol=1e-5)
    np.testing.assert_allclose(b.m2_uu, a.m2_uu, rtol=1e-5, atol=1e-5)
    assert tsi.result.u_tau == pytest.approx(davis.result.u_tau, rel=1e-5)


def test_a_calibrated_pivlab_series_gives_the_same_wall_units(level, tmp_path):
    """PIVlab's calibrated MAT exports (m and m/s, y up, offsets set, as PIVlab's
    ``compute_calibration`` and ``apply_xy`` make them): read back in px with the files'
    scale and dt, the same statistics as the DaVis files of the same fields, the positions'
    unknown offset changing nothing measured from the wall."""
    import scipy.io

    folder, files, truth = level
    mm = 1 / truth.magnification
    calxy = mm * 1e-3
    calu, calv = calxy / truth.dt, -calxy / truth.dt
    for s in range(30):
        _, x, y, u, v = exact_field(s)
        cells = {}
        for k, a in (("x", (x + 1.5) * calxy - 0.031), ("y", (4000 - (y + 1.5)) * calxy + 0.002),
                     ("u_original", u * calu), ("v_original", v * calv),
                     ("typevector_original", np.ones(u.shape))):  # fmt: skip
            cells[k] = np.empty((1, 1), dtype=object)
            cells[k][0, 0] = a
        scipy.io.savemat(tmp_path / f"PIVlab_{s:04d}.mat", {
            **cells, "calxy": calxy, "calu": calu, "calv": calv,
            "units": "[m] respectively [m/s]"})  # fmt: skip
    davis = vector_statistics(files[:30], nu=NU)
    lab = vector_statistics(tmp_path, nu=NU, window=(32, 32))
    assert lab.tool == "PIVlab" and lab.used == 30
    assert lab.dt == pytest.approx(truth.dt, rel=1e-9)
    assert lab.mm_per_px == pytest.approx(mm, rel=1e-12)
    assert any("offset" in w for w in lab.warnings)  # the positions' caveat said
    a, b = davis.accumulator, lab.accumulator
    np.testing.assert_allclose(b.mean_u, a.mean_u, rtol=0, atol=1e-5)
    np.testing.assert_allclose(b.m2_uu, a.m2_uu, rtol=1e-5, atol=1e-5)
    assert lab.result.u_tau == pytest.approx(davis.result.u_tau, rel=1e-5)
    # the DaVis files hold float32, the MAT files float64: measured 4e-6
    assert lab.result.delta99 == pytest.approx(davis.result.delta99, rel=1e-5)
    # a wall given where the calibration puts it (m, the files' y) is the DaVis files' row
    w = float(davis.analysis.wall.line(np.mean(davis.x)))
    w_file = (4000 - (w + 1.5)) * calxy + 0.002
    davis = vector_statistics(files[:30], nu=NU, wall="bottom", wall_y=w)
    lab = vector_statistics(tmp_path, nu=NU, window=(32, 32), wall="bottom", wall_y=w_file,
                            wall_y_units="file")  # fmt: skip
    assert lab.result.u_tau == pytest.approx(davis.result.u_tau, rel=1e-5)
    with pytest.raises(InvalidInputError, match="gives its positions in px"):
        vector_statistics(files[:3], nu=NU, wall="bottom", wall_y=0.01, wall_y_units="file")
    with pytest.raises(InvalidInputError, match="wall_y_units 'mm': px or file"):
        vector_statistics(files[:3], nu=NU, wall="bottom", wall_y=0.01, wall_y_units="mm")


@pytest.fixture(scope="module")
def lens_series(tmp_path_factory):
    shape = (1322, 2216)
    m = 8.6345  # the scene's magnification at SCALE
    lens = strong_lens(shape)
    gx, gy = np.meshgrid(np.linspace(40, shape[1] - 41, 23), np.linspace(40, shape[0] - 41, 14))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    cal = rspiv.calibrate_points(lens.distort(obj), obj / m, image_shape=shape, sigma_px=0.02)
    folder = tmp_path_factory.mktemp("lens")
    write_series(folder, 60, wall_y0=1150.0, camera=cal.mapping)
    return folder, cal


def test_method_two_corrects_a_series_seen_through_a_lens(lens_series):
    folder, cal = lens_series
    r = vector_statistics(folder, nu=NU, calibration=cal)
    assert r.frame == "object" and r.warnings == []
    assert r.result.u_tau == pytest.approx(FLOW.u_tau, rel=0.005)  # measured: -0.17 %
    err = _errors(r)
    # the resampling between nodes (rspiv.vector_sampling, Keys' cubic) smooths the
    # fluctuations a little: the stresses' median errors -0.004 (uu+), -0.0001 (vv+), 0.0000
    # (uv+), the largest 0.11 (uu+); bilinear sampling gave -0.083, -0.032, +0.017 and 0.47
    for k in ("uu", "vv", "uv"):
        assert abs(err[k][0]) < 0.03, (k, err[k])
    assert err["uu"][1] < 0.25 and abs(err["U"][0]) < 0.05
    # uncorrected, the wall bows and the friction velocity is off: said
    raw = vector_statistics(folder, nu=NU)
    assert abs(raw.result.u_tau / FLOW.u_tau - 1) > 0.01  # measured: +1.9 %
    said = [w for w in raw.warnings if "bows by" in w and "calibration" in w]
    assert said, raw.warnings
    # the lens bows the object's straight wall (y 1150 px) by +10.5 px over the stations (the
    # quadratic term of a parabola through them); read +9.8 (+8.4 before the joint fit)
    xo = np.linspace(-100.0, 2316.0, 500)
    img = cal.mapping.forward(np.column_stack([xo, np.full_like(xo, 1150.0)]))
    xs = raw.analysis.wall.x_px[raw.analysis.wall.valid]
    xc = (xs - 0.5 * (xs.min() + xs.max())) / (0.5 * np.ptp(xs))
    bow = np.polyfit(xc, np.interp(xs, img[:, 0], img[:, 1]), 2)[0]
    assert float(said[0].split("bows by ")[1].split()[0]) == pytest.approx(bow, abs=1.0)


def test_a_tilted_wall_is_said_or_levelled(tmp_path):
    write_series(tmp_path, 30, angle=0.3)
    r = vector_statistics(tmp_path, nu=NU)
    assert r.rotation_deg == 0.0
    assert any("rises" in w and "not levelled" in w for w in r.warnings), r.warnings
    lv = vector_statistics(tmp_path, nu=NU, level=True)
    # rows 16 px apart: find_wall's joint fit reads 0.337 deg on the pilot fields' mean, whose
    # band holds 2 rows of reflection (the resampled estimate alone read 0.415; 0.2975 from
    # 10 fields whose band holds 4: module docs of rspiv.wall)
    assert lv.rotation_deg == pytest.approx(0.3, abs=0.05)
    assert any("rotated" in w for w in lv.warnings)
    assert not any("not levelled" in w for w in lv.warnings)


def test_a_stopped_run_resumes_to_the_same_sums(level, tmp_path):
    folder, files, _ = level
    whole = vector_statistics(files[:25], nu=NU)

    def stop(done, total):
        if done == 17:
            raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        vector_statistics(files[:25], nu=NU, out_dir=out, checkpoint_every=5, progress=stop)
    seen = []
    again = vector_statistics(
        files[:25], nu=NU, out_dir=out, checkpoint_every=5, progress=lambda d, t: seen.append(d)
    )
    assert seen[0] == 16  # resumed after the 15 fields of the last checkpoint
    for name in ("mean_u", "m2_uu", "c_uv", "count", "lag_c_u"):
        np.testing.assert_array_equal(getattr(again.accumulator, name),
                                      getattr(whole.accumulator, name))  # fmt: skip
    with pytest.raises(InvalidInputError, match="other options"):
        vector_statistics(files[:25], nu=NU, out_dir=out, level=True)
    # the analysis' options do not enter the sums: analysed again from the checkpoint
    seen.clear()
    other = vector_statistics(
        files[:25], nu=2 * NU, out_dir=out, progress=lambda d, t: seen.append(d)
    )
    assert seen == [] and other.used == 25
    assert other.result.u_tau != pytest.approx(again.result.u_tau, rel=1e-3)
    with pytest.raises(InvalidInputError, match="not this run's first"):
        vector_statistics(files[1:26], nu=NU, out_dir=out)
    (out / "checkpoint.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(InvalidInputError, match="cannot resume"):
        vector_statistics(files[:25], nu=NU, out_dir=out)


def test_bad_fields_skipped_and_bad_series_refused(level, tmp_path, capsys):
    folder, files, truth = level
    other = write_vc7(tmp_path / "other.vc7", np.ones((5, 7)), np.ones((5, 7)), 0.1, 1e-3)
    broken = tmp_path / "broken.vc7"
    broken.write_bytes(files[0].read_bytes()[:300])
    r = vector_statistics([*files[:10], other, broken, *files[10:20]], nu=NU)
    assert r.used == 20 and set(r.skipped) == {str(other), str(broken)}
    assert "another grid" in r.skipped[str(other)]
    assert any("2 field(s) skipped" in w for w in r.warnings)
    with pytest.raises(InvalidInputError, match="no field could be read"):
        vector_statistics([broken], nu=NU)
    # every vector filled by the tool (PIVMat's DaVis jet is so): no measurement to sum
    _, x, _, u, v = exact_field(0)
    filled = write_vc7(tmp_path / "filled.vc7", u, v, 0.1, 1e-3, choice=4)
    with pytest.raises(InvalidInputError, match=r"validation accepted \(\d+ filled"):
        vector_statistics([filled], nu=NU)
    # a uniform flow has no wall to mirror: refused, not given one
    flat = [write_vc7(tmp_path / f"flat{k}.vc7", np.full(x.shape, 5.0 + 0.01 * k),
                      np.zeros(x.shape), 0.1, 1e-3) for k in range(12)]  # fmt: skip
    with pytest.raises(InvalidInputError):
        vector_statistics(flat, nu=NU)
    for bad in ({"nu": 0.0}, {"nu": NU, "dt": -1.0}, {"nu": NU, "wall": "left"},
                {"nu": NU, "vorticity": "spline"}):  # fmt: skip
        with pytest.raises(InvalidInputError):
            vector_statistics(files[:3], **bad)
    assert main(["statistics", str(broken), "--nu", "1e-6", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "broken.vc7" in err[0]


def test_a_davis_set_file_stands_for_its_folder(level, tmp_path, capsys):
    _, files, _ = level
    folder = tmp_path / "PIV_MP(2x32x32_50%ov)"  # as DaVis names a vector set
    folder.mkdir()
    for f in files[:12]:
        (folder / f.name).symlink_to(f)
    (tmp_path / "PIV_MP(2x32x32_50%ov).set").write_text("SetType=Vector\n")
    r = vector_statistics(tmp_path / "PIV_MP(2x32x32_50%ov).set", nu=NU, screen=0)
    direct = vector_statistics(files[:12], nu=NU, screen=0)
    assert r.used == 12
    np.testing.assert_array_equal(r.to_xarray()["uu"].values, direct.to_xarray()["uu"].values)
    (tmp_path / "alone.set").write_text("SetType=Vector\n")
    with pytest.raises(InvalidInputError, match=r"alone.set: a DaVis set whose folder alone/"):
        vector_statistics(tmp_path / "alone.set", nu=NU)
    assert main(["statistics", str(tmp_path / "alone.set"), "--nu", "1e-6", "-o",
                 str(tmp_path / "o")]) == 2  # fmt: skip
    assert "is not beside it" in capsys.readouterr().err


def test_random_vectors_the_tool_kept_are_screened(level, tmp_path):
    folder, files, truth = level
    rng = np.random.default_rng(3)
    planted = 0
    series = []
    for s in range(30):
        tr, x, _, u, v = exact_field(s)
        if s in (4, 11, 23):  # 40 random vectors the tool's validation passed
            j = rng.integers(5, 50, 40)
            i = rng.integers(2, x.shape[1] - 2, 40)
            u[j, i] += rng.choice([-1, 1], 40) * rng.uniform(15, 25, 40)
            planted += len(set(zip(j, i, strict=True)))
        series.append(write_vc7(tmp_path / f"B{s:05d}.vc7", u, v, 1 / tr.magnification, tr.dt))
    clean = vector_statistics(files[:30], nu=NU, min_count=5)
    kept = vector_statistics(series, nu=NU, min_count=5, screen=0)
    screened = vector_statistics(series, nu=NU, min_count=5)
    sc = screened.screened()
    assert kept.screened() is None and planted - 5 <= sc["vectors"] <= planted + 20, sc
    bad = np.nanmax(np.abs(kept.result.uu_plus - clean.result.uu_plus))
    good = np.nanmax(np.abs(screened.result.uu_plus - clean.result.uu_plus))
    assert bad > 0.5 and good < 0.1 * bad, (bad, good)  # measured: 1.06 and 0.004 (120 of 120)


def test_peak_locking_in_the_fields_is_measured_and_said(level, tmp_path):
    folder, files, truth = level
    a = 0.04  # px, towards whole pixels (rspiv.peak_locking's model)
    series = []
    for s in range(30):
        tr, _, _, u, v = exact_field(s)
        locked = [d - a * np.sin(2 * np.pi * d) for d in (u, v)]
        series.append(write_vc7(tmp_path / f"B{s:05d}.vc7", *locked, 1 / tr.magnification, tr.dt))
    r = vector_statistics(series, nu=NU)
    assert r.locking["amplitude_px"] == pytest.approx(a, abs=0.01) and r.locking["said"]
    assert any(w.startswith("peak locking") for w in r.warnings)
    clean = vector_statistics(files[:30], nu=NU)
    assert abs(clean.locking["amplitude_px"]) < 0.005 and not clean.locking["said"]
    assert not any("peak locking" in w for w in clean.warnings)


def test_real_fields_without_a_wall_are_refused_not_given_one():
    """pivpy's samples (BSD 3-clause, tests/data/real): OpenPIV's exp1_001 and a PIVlab session
    of two pairs (read as its two fields) hold no wall: refused in one line."""
    for name in ("pivpy_openpiv_exp1_001_b.txt", "pivpy_pivlab_session.mat"):
        with pytest.raises(InvalidInputError, match="no wall reflection seen"):
            vector_statistics(REAL / name, nu=1e-6, min_count=1)
