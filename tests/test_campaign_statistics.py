"""A campaign's statistics beyond the moments, on one small synthetic campaign (quadrant and
vorticity on, as the demo has them): the quadrant analysis (``[statistics] quadrant``,
rspiv.campaign.quadrant), a second pass over the fields the pair loop wrote, equals direct sums
over those files about the run's own statistics, and missing and foreign field files are said;
the vorticity statistics (``[statistics] vorticity``, rspiv.campaign.vorticity) equal the
vorticity of those files, row by row; the POD (``[statistics] pod``, rspiv.campaign.pod) equals
an SVD of those files' fluctuations, streamed by blocks of rows or read at once."""

from __future__ import annotations

import dataclasses
import json
import pathlib
import shutil

import numpy as np
import pytest
from campaign_cases import switch
from rspiv.campaign import Campaign
from rspiv.campaign_config import load_campaign_config
from rspiv.demo import DEFAULT_SCENE, synth_campaign

SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=3, monte_carlo_samples=500)


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    d = tmp_path_factory.mktemp("quadrant")
    synth_campaign(d, scene=SCENE)  # quadrant and fields on, as the demo has them
    toml = d / "campaign.toml"
    toml.write_text(switch(toml.read_text(), "vortex_fits", True))  # and the vortices' fits
    cfg = load_campaign_config(d / "campaign.toml")
    assert cfg.statistics.quadrant and cfg.output.fields and cfg.statistics.vorticity
    assert cfg.statistics.pod
    camp = Campaign.load(d / "campaign.toml", progress=False)
    return d, camp, camp.run()


def _fields(out: pathlib.Path, run: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``u, v, valid`` of every field file the campaign wrote for ``run``, stacked in pair
    order (read with xarray, not the code under test)."""
    import xarray as xr

    u, v, ok = [], [], []
    for f in sorted((out / "fields" / run).glob("pair_*.nc")):
        with xr.open_dataset(f, engine="h5netcdf") as ds:
            u.append(ds["u"].values.astype(np.float64))
            v.append(ds["v"].values.astype(np.float64))
            ok.append(ds["valid"].values.astype(bool))
    return np.array(u), np.array(v), np.array(ok)


def _sums_about(events, du, dv, ok, rows, offsets):
    """The sums of ``du``, ``dv`` and the count of ``ok`` (pair, row, column) at ``rows`` and
    ``offsets`` from each event ``(pair, column)``, inside the field."""
    nx = du.shape[2]
    su = np.zeros((len(rows), len(offsets)))
    sv, n = np.zeros_like(su), np.zeros_like(su)
    for p, col in events:
        at = col + offsets
        inside = (at >= 0) & (at < nx)
        sel = np.ix_(rows, at[inside])
        su[:, inside] += du[p][sel]
        sv[:, inside] += dv[p][sel]
        n[:, inside] += ok[p][sel]
    return su, sv, n


def test_the_file_equals_direct_sums_over_the_fields(processed):
    import xarray as xr

    _, camp, res = processed
    out = res.out_dir
    holes = camp.config.statistics.quadrant_holes
    for run in ("method_II", "uncorrected"):
        acc = res.accumulators[run]
        prof = res.analyses[run].profile
        sx, sy, k = prof["sign_x"], prof["sign_y"], prof["k"]
        u, v, ok = _fields(out, run)
        assert len(u) == 3
        usable = (acc.count >= 2) & (prof["dist_px"] > 0)[:, None]
        ok &= usable & np.isfinite(u) & np.isfinite(v)
        du, dv = sx * (u - acc.mean_u), sy * (v - acc.mean_v)
        su, sv = np.sqrt(acc.uu), np.sqrt(acc.vv)
        with np.errstate(invalid="ignore"):
            level = np.abs(du * dv) / (su * sv)
        uv = np.where(ok, du * dv, 0.0)
        n = ok.sum(axis=(0, 2))
        with xr.open_dataset(out / f"quadrant_{run}.nc", engine="h5netcdf") as ds:
            assert ds.attrs["pairs"] == 3
            # 3 pairs: |u'v'| / (u_rms v_rms) <= (n - 1)^2 / n = 1.33, holes 2 and 4 say so
            assert "with 3 pairs per vector |u'v'| / (u_rms v_rms) cannot exceed 1.33" in (
                ds.attrs["warning"])  # fmt: skip
            assert np.all(ds["stress"].sel(hole=2.0).values[np.isfinite(ds["uv"].values)] == 0)
            assert ds["stress"].dims == ("y", "quadrant", "hole")
            assert ds["stress"].attrs["units"] == "m2 s-2"
            np.testing.assert_array_equal(ds["hole"].values, holes)
            rows = np.argsort(prof["dist_px"])
            rows = rows[(prof["dist_px"][rows] > 0) & (n[rows] > 0)]
            np.testing.assert_array_equal(ds["count"].values, n[rows])
            np.testing.assert_allclose(ds["uv"].values, uv.sum(axis=(0, 2))[rows] / n[rows] * k * k,
                                       rtol=1e-9)  # fmt: skip
            signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))
            for q, (a, b) in enumerate(signs):
                inq = ((du >= 0) if a > 0 else (du < 0)) & ((dv >= 0) if b > 0 else (dv < 0))
                for h, hole in enumerate(holes):
                    sel = ok & inq & (level >= hole)
                    want = np.where(sel, uv, 0).sum(axis=(0, 2))[rows] / n[rows] * k * k
                    np.testing.assert_allclose(ds["stress"].values[:, q, h], want, rtol=1e-9,
                                               atol=1e-15)  # fmt: skip
                    np.testing.assert_allclose(ds["time_fraction"].values[:, q, h],
                                               sel.sum(axis=(0, 2))[rows] / n[rows])  # fmt: skip
            # u'v' < 0 away from the wall: ejections and sweeps carry the stress
            away = ~ds["near_wall"].values & (ds["y"].values < 0.5 * ds.attrs["delta_99"])
            assert np.median(ds["uv"].values[away]) < 0
            frac = ds["fraction"].sel(hole=0.0).values[away]
            assert np.median(frac[:, 1] + frac[:, 3]) > 1.0
            np.testing.assert_allclose(frac.sum(axis=1), 1.0, rtol=1e-9)
    html = (out / "report" / "report.html").read_text()
    assert "Quadrant analysis" in html
    assert (out / "report" / "figures" / "quadrant.png").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"]["method_II"]["quadrant"]["pairs"] == 3


def _reanalyse(processed, tmp_path, broken):
    d, _, full = processed
    out = tmp_path / "out"
    shutil.copytree(full.out_dir, out, ignore=shutil.ignore_patterns("checkpoint"))
    broken(out)
    said = []
    camp = Campaign.load(d / "campaign.toml", progress=False, out_dir=out, log=said.append)
    return camp.analyse(full.accumulators), said, out


def test_a_missing_field_file_is_said(processed, tmp_path):
    def drop(out: pathlib.Path):
        (out / "fields" / "method_II" / "pair_000001.nc").unlink()

    res, said, out = _reanalyse(processed, tmp_path, drop)
    prof = res.quadrant["method_II"]
    assert prof["pairs"] == 2 and prof["missing"] == [1]
    assert "1 of 3 pairs have no field file (first: pair 1)" in prof["warning"]
    assert any("WARNING" in m and "quadrant" in m for m in said)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"]["method_II"]["quadrant"]["missing_fields"] == 1
    assert "no field file" in (out / "report" / "report.html").read_text()
    assert res.quadrant["uncorrected"]["pairs"] == 3  # the other run's files are all there
    pod = res.pod["method_II"]
    assert pod["pairs"] == 2 and pod["missing"] == [1] and pod["energy"].size == 2
    assert "1 of 3 pairs chosen have no field file (first: pair 1)" in pod["warning"]
    assert summary["runs"]["method_II"]["pod"]["missing_fields"] == 1


def test_a_refused_pass_leaves_no_older_file(processed, tmp_path):
    """A pass refused now removes the file an earlier analysis wrote for it (the folder held
    PIVlab's Karman campaign's older ``vortices_uncorrected.nc`` beside a refusal): named in the
    log and in ``summary.json``; other runs' files and files rspiv does not name stay."""

    def drop(out: pathlib.Path):
        for f in (out / "fields" / "method_II").glob("pair_*.nc"):
            f.unlink()
        (out / "notes_method_II.nc").write_text("mine")
        (out / "quadrant_other_run.nc").write_text("mine")

    d, _, full = processed
    before = {p.name for p in full.out_dir.glob("*_method_II.nc")}
    assert {"quadrant_method_II.nc", "pod_method_II.nc", "vortices_method_II.nc"} <= before
    res, said, out = _reanalyse(processed, tmp_path, drop)
    assert "method_II" not in res.quadrant and "method_II" not in res.pod
    gone = {"quadrant_method_II.nc", "pod_method_II.nc", "vortices_method_II.nc"}
    for name in gone:
        assert not (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    assert gone <= set(summary["removed"])
    assert "statistics_method_II.nc" not in summary["removed"]  # written again
    assert any(m.startswith("removed ") and "quadrant_method_II.nc" in m for m in said)
    for name in ("quadrant_uncorrected.nc", "statistics_method_II.nc", "notes_method_II.nc",
                 "quadrant_other_run.nc"):
        assert (out / name).is_file(), name


def test_a_foreign_field_file_stops_the_run_in_one_line(processed, tmp_path):
    import xarray as xr

    def foreign(out: pathlib.Path):
        path = out / "fields" / "method_II" / "pair_000002.nc"
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            small = ds.isel(x=slice(0, 10)).load()
        path.unlink()
        small.to_netcdf(path, engine="h5netcdf")

    res, said, out = _reanalyse(processed, tmp_path, foreign)
    assert "method_II" not in res.quadrant
    summary = json.loads((out / "summary.json").read_text())
    err = summary["runs"]["method_II"]["quadrant_error"]
    assert "pair_000002.nc: a grid of 10 x" in err and "\n" not in err
    assert any("quadrant profile failed" in m for m in said)
    assert "uncorrected" in res.quadrant
    err = summary["runs"]["method_II"]["pod_error"]
    assert "pair_000002.nc: a grid of 10 x" in err and "\n" not in err
    assert "method_II" not in res.pod and "uncorrected" in res.pod


def test_the_vorticity_profile_equals_that_of_the_fields(processed):
    """``vorticity_<run>.nc``: per row, the mean of the per-vector means and the root of the
    mean per-vector variance of omega_z over the usable vectors, in 1/s and the flow's frame,
    equal those of the written fields (float32: to 1e-5); the rows whose differences reach
    into the wall's rows are flagged; the figure is drawn."""
    import xarray as xr
    from rspiv.derivatives import vorticity

    _, camp, res = processed
    out = res.out_dir
    dt = camp.config.flow.dt
    for run in ("method_II", "uncorrected"):
        acc = res.accumulators[run]
        prof = res.analyses[run].profile
        gx, gy = res.context.grid()
        w = np.array([vorticity(u, v, gx[0, 1] - gx[0, 0], gy[1, 0] - gy[0, 0])
                      for u, v, _ in zip(*_fields(out, run), strict=True)])  # fmt: skip
        n = np.isfinite(w).sum(axis=0)
        usable = (acc.count >= 2) & (prof["dist_px"] > 0)[:, None] & (n > 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(np.isfinite(w), w, 0).sum(axis=0) / n
            var = np.where(np.isfinite(w), (w - mean) ** 2, 0).sum(axis=0) / (n - 1)
        orient = prof["sign_x"] * -prof["sign_y"]
        k = usable.sum(axis=1)
        rows = np.argsort(prof["dist_px"])
        rows = rows[(prof["dist_px"][rows] > 0) & (k[rows] > 0)]
        want_mean = orient * np.where(usable, mean, 0).sum(1)[rows] / k[rows] / dt
        want_rms = np.sqrt(np.where(usable, var, 0).sum(1)[rows] / k[rows]) / dt
        with xr.open_dataset(out / f"vorticity_{run}.nc", engine="h5netcdf") as ds:
            assert ds.attrs["pairs"] == 3 and ds.attrs["scheme"] == "least_squares"
            assert ds["omega_rms"].attrs["units"] == "s-1"
            # float32 fields: about 1e-7 px of each displacement, 1e-6 of the largest mean
            np.testing.assert_allclose(ds["omega_mean"].values, want_mean, rtol=1e-5,
                                       atol=1e-6 * np.abs(want_mean).max())  # fmt: skip
            np.testing.assert_allclose(ds["omega_rms"].values, want_rms, rtol=1e-5)
            # a boundary layer's mean vorticity is -dU/dy < 0 in the flow's frame
            away = ~ds["near_wall"].values & (ds["y"].values < 0.3 * res.analyses[run]
                                               .result.delta99)  # fmt: skip
            assert np.all(ds["omega_mean"].values[away] < 0)
            # flagged: 2.5 window heights (20 px) and the scheme's two rows (8 px)
            dist = ds["y"].values / prof["m_per_px"]
            np.testing.assert_array_equal(ds["near_wall"].values, dist < 28.0)
    assert (out / "report" / "figures" / "vorticity.png").is_file()
    assert "Vorticity" in (out / "report" / "report.html").read_text()


def test_statistics_carried_with_the_pairs_are_part_of_the_checkpoint(processed, tmp_path, capsys):
    """Switching vorticity off after the run (a statistic carried with every pair) rebuilds the
    context and refuses the old checkpoint in one line, rather than resuming without it; the
    quadrant analysis (a second pass at the end) does not touch the checkpoint."""
    from rspiv.cli import main

    d, _, full = processed
    out = tmp_path / "out"
    shutil.copytree(full.out_dir, out)
    cfg = load_campaign_config(d / "campaign.toml")
    cfg.output.dir = out
    cfg.statistics.quadrant_holes = (0.0, 3.0)
    same = cfg.save(tmp_path / "same.toml")
    assert main(["process", str(same), "-q"]) == 0
    assert "3 from the checkpoint" in capsys.readouterr().out
    cfg.statistics.vorticity = cfg.statistics.vortices = False  # the vortices need it
    other = cfg.save(tmp_path / "other.toml")
    assert main(["process", str(other), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "checkpoint of a different configuration" in err and len(err.splitlines()) == 1


def test_the_second_pass_in_threads_equals_one_thread(processed):
    """The field files added by 1 and by 3 threads (contiguous runs of pairs, parts merged)
    give the same sums, batches included; a missing file is named whichever thread meets it."""
    from rspiv.campaign.quadrant import accumulate
    from rspiv.quadrant import QuadrantAccumulator

    _, camp, res = processed
    acc = res.accumulators["method_II"]
    writer = camp.field_writer()
    paths = {pid: writer.path("method_II", pid) for pid in sorted(acc.pair_ids)}
    paths[99] = writer.path("method_II", 99)  # no such file
    out = []
    for workers in (1, 3):
        q = QuadrantAccumulator(acc.mean_u, acc.mean_v, np.sqrt(acc.uu), np.sqrt(acc.vv),
                                usable=acc.count >= 2, batches=4)  # fmt: skip
        n, missing = accumulate(q, paths, "method_II", workers=workers)
        assert n == 3 and missing == [99]
        out.append(q.results())
    for key in ("count", "uv", "stress", "time_fraction", "jpdf", "uv_se", "uv_batches"):
        np.testing.assert_allclose(out[1][key], out[0][key], rtol=1e-12, atol=1e-300)
    assert out[0]["uv_batches"].max() == 3  # 4 pairs over 4 batches: the missing one's empty


def _pod_domain(camp, res, run):
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS

    acc = res.accumulators[run]
    dist = res.analyses[run].profile["dist_px"]
    rows = (dist > 0) & (dist >= NEAR_WALL_HEIGHTS * res.context.piv.final_window[1])
    height = camp.config.statistics.pod_height  # delta_99, as the demo sets it
    assert height > 0
    an = res.analyses[run]
    rows &= dist * an.profile["m_per_px"] <= height * an.result.delta99
    return (acc.count >= 2) & rows[:, None]


def test_the_pod_file_equals_an_svd_of_the_fields(processed):
    """``pod_<run>.nc``: the eigenvalues, modes and coefficients of the fluctuations of the
    written fields about the run's means, over the vectors off the wall (rows within 2.5
    window heights left out), rejected vectors filled with the mean; in the flow's frame."""
    import xarray as xr

    _, camp, res = processed
    for run in ("method_II", "uncorrected"):
        acc = res.accumulators[run]
        prof = res.analyses[run].profile
        sx, sy, k = prof["sign_x"], prof["sign_y"], prof["k"]
        u, v, ok = _fields(res.out_dir, run)
        dom = _pod_domain(camp, res, run)
        ok &= np.isfinite(u) & np.isfinite(v)
        x = np.concatenate(
            [np.where(ok, u - acc.mean_u, 0)[:, dom], np.where(ok, v - acc.mean_v, 0)[:, dom]], 1
        )
        a, s, vt = np.linalg.svd(x, full_matrices=False)
        with xr.open_dataset(res.out_dir / f"pod_{run}.nc", engine="h5netcdf") as ds:
            assert ds.attrs["pairs"] == 3 and ds.attrs["vectors"] == dom.sum()
            # 3 snapshots: 2 modes of sampling errors sqrt(2/3) of themselves, said
            assert "no mode kept is separated from its neighbours" in ds.attrs["warning"]
            assert ds["energy"].attrs["units"] == "m2 s-2"
            n_modes = ds.sizes["mode"]
            assert n_modes == 2  # 3 snapshots about their own mean span 2 modes
            np.testing.assert_allclose(ds["energy"].values, s[:2] ** 2 / 3 * k * k, rtol=1e-9)
            assert ds.attrs["total_energy"] == pytest.approx((x**2).sum() / 3 * k * k, rel=1e-9)
            assert ds.attrs["gaps"] == pytest.approx(1 - ok[:, dom].mean(), rel=1e-9)
            rows = np.argsort(prof["dist_px"])
            rows = rows[dom[rows].any(axis=1)]
            np.testing.assert_allclose(ds["y"].values, prof["dist_px"][rows] * prof["m_per_px"])
            d = int(dom.sum())
            for i in range(n_modes):
                phi_u = np.full(dom.shape, np.nan)
                phi_v = np.full(dom.shape, np.nan)
                phi_u[dom], phi_v[dom] = sx * vt[i, :d], sy * vt[i, d:]
                sign = np.sign(np.nansum(ds["phi_u"].values[i] * phi_u[rows]))
                np.testing.assert_allclose(ds["phi_u"].values[i], sign * phi_u[rows], atol=1e-6)
                np.testing.assert_allclose(ds["phi_v"].values[i], sign * phi_v[rows], atol=1e-6)
                np.testing.assert_allclose(
                    ds["coefficient"].values[:, i], sign * a[:, i] * s[i] * k, rtol=1e-6
                )
    assert (res.out_dir / "report" / "figures" / "pod.png").is_file()
    assert "Proper orthogonal decomposition" in (res.out_dir / "report" / "report.html").read_text()


def test_the_pod_streamed_by_blocks_equals_one_read(processed):
    """Blocks of one row (every file read once per block, then once more for the modes) give
    the decomposition of one block read at once."""
    from rspiv.campaign.pod import decompose
    from rspiv.pod import PodBuilder

    _, camp, res = processed
    acc = res.accumulators["method_II"]
    dom = _pod_domain(camp, res, "method_II")
    writer = camp.field_writer()
    paths = [writer.path("method_II", pid) for pid in sorted(acc.pair_ids)]
    out = []
    for block in (1 << 40, 1):
        b = PodBuilder(acc.mean_u, acc.mean_v, dom, 3)
        decompose(b, paths, "method_II", 5, block_bytes=block)
        out.append(b.result())
    np.testing.assert_allclose(out[1].energy, out[0].energy, rtol=1e-12)
    np.testing.assert_allclose(out[1].modes_u, out[0].modes_u, atol=1e-12)
    np.testing.assert_allclose(out[1].coefficients, out[0].coefficients, rtol=1e-9)


def test_the_vortex_population_equals_the_cores_of_the_fields(processed):
    """``vortices_<run>.nc``: per row and kind, the cores found in the written fields' signed
    swirling strength (their valid vectors, the flow's frame) beyond 1.5 times its rms at the
    row (each vector's mean square over the pairs, averaged along the row), counted at their
    centroid's row, up to delta_99; prograde turns with the mean shear (clockwise in the flow's
    frame)."""
    import xarray as xr
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS
    from rspiv.derivatives import gradients, swirl_from_gradients
    from rspiv.vortices import find_vortices, min_core_vectors

    _, camp, res = processed
    st = camp.config.statistics
    for run in ("method_II", "uncorrected"):
        acc = res.accumulators[run]
        prof = res.analyses[run].profile
        orient = prof["sign_x"] * -prof["sign_y"]
        u, v, ok = _fields(res.out_dir, run)
        ok &= np.isfinite(u) & np.isfinite(v)
        dx, dy = acc.vorticity.dx, acc.vorticity.dy
        lam, om = [], []
        for k in range(len(u)):
            g = gradients(np.where(ok[k], u[k], np.nan), np.where(ok[k], v[k], np.nan), dx, dy)
            lam.append(swirl_from_gradients(g, signed=True) * orient)
            om.append((g["dvdx"] - g["dudy"]) * orient)
        lam, om = np.array(lam), np.array(om)
        dist = prof["dist_px"]
        rows = (dist > 0) & (dist >= NEAR_WALL_HEIGHTS * res.context.piv.final_window[1] + 2 * dy)
        fin = np.isfinite(lam)
        usable = (acc.count >= 2) & (fin.sum(0) >= 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            per_vector = np.where(fin, lam, 0.0) ** 2
            per_vector = per_vector.sum(0) / fin.sum(0)
            rms = np.sqrt(np.where(usable, per_vector, 0).sum(1) / usable.sum(1))
        rows &= usable.any(1) & (dist * prof["m_per_px"] <= res.analyses[run].result.delta99)
        thr = np.where(rows & (rms > 0), st.vortex_threshold * rms, np.inf)[:, None]
        # the smallest core: a disc as wide as the final window (32 px: 13 vectors of 16 x 4)
        least = min_core_vectors(max(res.context.piv.final_window), dx, dy)
        count = np.zeros((acc.shape[0], 2), int)
        for k in range(len(u)):
            c = find_vortices(lam[k], om[k], thr, dx, dy, y=np.arange(acc.shape[0], dtype=float),
                              min_vectors=least)  # fmt: skip
            np.add.at(count, (np.rint(c["y"]).astype(int), (c["sign"] > 0).astype(int)), 1)
        keep = np.flatnonzero(rows)
        keep = keep[np.argsort(dist[keep])]
        with xr.open_dataset(res.out_dir / f"vortices_{run}.nc", engine="h5netcdf") as ds:
            assert ds.attrs["pairs"] == 3 and ds.attrs["prograde_sign"] == -1
            assert ds.attrs["min_vectors"] == least
            np.testing.assert_array_equal(ds["count"].values, count[keep])
            assert ds["count"].values.sum() > 20
            np.testing.assert_allclose(ds["y"].values, dist[keep] * prof["m_per_px"])
            assert ds.sizes["core"] == count.sum()
            assert ds["density"].attrs["units"] == "m-2"
    assert (res.out_dir / "report" / "figures" / "vortices.png").is_file()



def test_the_lamb_oseen_fits_are_those_of_the_written_fields(processed):
    """Every listed core carries the Lamb-Oseen fit of the written field's fluctuations about
    the mean of the run's other pairs, n / (n - 1) times those about the run's means with n the
    vector's pairs (rspiv.vortices.fit_oseen on the cores the file lists, in the flow's
    frame): the same share explained, the same cores kept, the same radius and circulation in
    SI units; the per-row counts and means are those of the table's kept fits, and the report
    says what was kept. (The synthetic layer's swirling regions are not resolved Lamb-Oseen
    vortices: its fits are refused, so the kept values are checked in tests/test_vortices.py.)
    """
    import xarray as xr
    from rspiv.vortices import fit_oseen

    _, camp, res = processed
    run = "method_II"
    acc = res.accumulators[run]
    prof = res.analyses[run].profile
    orient = prof["sign_x"] * -prof["sign_y"]
    m, per_s = prof["m_per_px"], 1.0 / camp.config.flow.dt
    va = acc.vorticity
    u, v, ok = _fields(res.out_dir, run)
    dist = prof["dist_px"]
    usable = (acc.count >= max(camp.config.statistics.min_count, 2)) & (dist > 0)[:, None]
    usable &= va.swirl_count > 1
    mu, mv = np.where(usable, acc.mean_u, np.nan), np.where(usable, acc.mean_v, np.nan)
    n = acc.count.astype(np.float64)
    loo = np.where(usable, n / np.maximum(n - 1, 1), np.nan)  # about the other pairs' mean
    with xr.open_dataset(res.out_dir / f"vortices_{run}.nc", engine="h5netcdf") as ds:
        t = {k: ds[k].values for k in ds.data_vars if k.startswith("core_")}
        count, oseen_count = ds["count"].values, ds["oseen_count"].values
        kept_radius = ds["oseen_radius"].values
    with xr.open_dataset(next((res.out_dir / "fields" / run).glob("pair_*.nc")),
                         engine="h5netcdf") as ds:  # fmt: skip
        x = ds["x"].values.astype(np.float64)
    order = np.argsort(dist)  # the cores' rows back from their distances
    rows = np.interp(t["core_y"] / m, dist[order], np.arange(dist.size, dtype=float)[order])
    fit = np.full(t["core_x"].size, np.nan)
    okf = np.zeros(t["core_x"].size, bool)
    for k in range(len(u)):
        at = t["core_pair"] == sorted(acc.pair_ids)[k]
        cores = {"x": t["core_x"][at] / m, "y": rows[at], "sign": t["core_sign"][at],
                 "radius": t["core_radius"][at] / m}  # fmt: skip
        f = fit_oseen((u[k] - mu) * loo, (v[k] - mv) * loo, cores, va.dx, va.dy, valid=ok[k], x=x,
                      y=np.arange(acc.shape[0], dtype=float), orient=orient)  # fmt: skip
        fit[at], okf[at] = f["fit"], f["ok"]
        kept = f["ok"]
        np.testing.assert_allclose(t["core_oseen_radius"][at][kept], f["radius"][kept] * m)
        np.testing.assert_allclose(t["core_oseen_circulation"][at][kept],
                                   f["circulation"][kept] * m * m * per_s)  # fmt: skip
    assert t["core_x"].size > 20
    np.testing.assert_allclose(t["core_oseen_fit"], fit, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(t["core_oseen_ok"].astype(bool), okf)
    assert np.isnan(t["core_oseen_radius"][~okf]).all()
    assert oseen_count.sum() == okf.sum() and np.all(oseen_count <= count)
    assert np.isnan(kept_radius[oseen_count == 0]).all()
    md = (res.out_dir / "report" / "report.md").read_text()
    assert "Lamb-Oseen" in md
    if okf.sum() == 0:
        assert "No core's Lamb-Oseen fit was kept" in md

def test_pod_gaps_are_said(processed, tmp_path):
    """Rejected vectors in a tenth of the domain's samples (the field files' ``valid`` cleared
    in every other row of one pair): the POD says how many were filled with the mean."""
    import h5py

    def reject(out: pathlib.Path):
        with h5py.File(out / "fields" / "method_II" / "pair_000001.nc", "r+") as f:
            valid = f["valid"][...]
            valid[::2] = 0
            f["valid"][...] = valid

    res, said, _ = _reanalyse(processed, tmp_path, reject)
    prof = res.pod["method_II"]
    assert 0.05 < prof["gaps"] < 0.25
    assert f"{100 * prof['gaps']:.1f} % of the domain's samples were rejected" in prof["warning"]
    assert any("WARNING" in m and "POD" in m and "filled with their mean" in m for m in said)


def test_a_vortex_population_without_the_layer_is_refused(processed):
    """Without a boundary-layer fit (no delta_99: a wake, or no calibration or dt) the rows have
    no top, and above the layer a threshold relative to the row's swirl counts noise (PIVlab's
    real Karman pairs: 278 cores in 3 pairs where one pair shows 6): refused in one line."""
    import dataclasses as dc

    from rspiv.campaign.vortices import write_outputs
    from rspiv.errors import InvalidInputError

    _, camp, res = processed
    an = dc.replace(res.analyses["method_II"], result=None)
    with pytest.raises(InvalidInputError, match="needs the run's delta_99") as exc:
        write_outputs(camp, res, res.context.runs[0], an)
    assert "\n" not in str(exc.value)


def test_the_conditional_averages_equal_direct_sums_over_the_fields(processed):
    """``conditional_<run>.nc`` (``[statistics] conditional``, rspiv.campaign.conditional): per
    reference row and event kind, the average of the written fields' fluctuations about the
    run's own means at every row and offset of the map, the events read off the same files."""
    import xarray as xr

    _, camp, res = processed
    st = camp.config.statistics
    assert st.conditional and st.conditional_height_units == "px"
    for run in ("method_II", "uncorrected"):
        acc = res.accumulators[run]
        prof = res.analyses[run].profile
        c = res.conditional[run]
        sx, sy, k = prof["sign_x"], prof["sign_y"], prof["k"]
        dist = prof["dist_px"]
        u, v, ok = _fields(res.out_dir, run)
        ok &= (acc.count >= 2) & (dist > 0)[:, None] & np.isfinite(u) & np.isfinite(v)
        du = np.where(ok, sx * (u - acc.mean_u), 0.0)
        dv = np.where(ok, sy * (v - acc.mean_v), 0.0)
        thr = st.conditional_hole * np.sqrt(acc.uu * acc.vv)
        rows = np.array([np.flatnonzero(dist == y)[0] for y in c["dist_px"]])
        assert np.all(np.diff(c["dist_px"]) > 0) and np.all(np.diff(c["dx_px"]) > 0)
        dx_grid = float(np.median(np.diff(xr.open_dataset(
            next((res.out_dir / "fields" / run).glob("pair_*.nc")), engine="h5netcdf")["x"])))
        offsets = np.rint(sx * c["dx_px"] / dx_grid).astype(int)
        for i, ref in enumerate(c["ref_rows"]):
            assert abs(dist[ref] - st.conditional_heights[i]) <= 0.5 * abs(dist[1] - dist[0])
            a, b = du[:, ref], dv[:, ref]
            big = ok[:, ref] & (np.abs(a * b) >= thr[ref])
            for kind, ev in enumerate((big & (a < 0) & (b > 0), big & (a > 0) & (b < 0))):
                assert c["events"][i, kind] == ev.sum() > 0
                su, sv, n = _sums_about(zip(*np.nonzero(ev), strict=True), du, dv, ok, rows,
                                        offsets)  # fmt: skip
                np.testing.assert_array_equal(c["count"][i, kind], n)
                with np.errstate(invalid="ignore", divide="ignore"):
                    np.testing.assert_allclose(c["u"][i, kind] / k, su / n, rtol=1e-9, atol=1e-12)
                    np.testing.assert_allclose(c["v"][i, kind] / k, sv / n, rtol=1e-9, atol=1e-12)
        with xr.open_dataset(res.out_dir / f"conditional_{run}.nc", engine="h5netcdf") as ds:
            assert ds["u"].dims == ("ref", "kind", "y", "dx")
            # with the vortex pass on, the averages about its cores follow the quadrant kinds
            assert list(ds["kind"].values) == ["Q2", "Q4", "prograde", "retrograde"]
            assert ds["u"].attrs["units"] == "m s-1" and ds["dx"].attrs["units"] == "m"
            np.testing.assert_allclose(ds["u"].values, c["u"], rtol=1e-6)
            assert "u_plus" in ds and ds.attrs["pairs"] == 3
    html = (res.out_dir / "report" / "report.html").read_text()
    assert "Conditional averages" in html
    assert (res.out_dir / "report" / "figures" / "conditional.png").is_file()
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["runs"]["method_II"]["conditional"]["pairs"] == 3


def test_averages_about_vortex_cores_are_direct_sums_about_the_listed_cores(processed):
    """With ``vortices`` on, ``conditional`` also averages about the vortex pass's cores whose
    centroid lies nearest a reference row (each at the vector nearest its centroid): the direct
    sums of the written fields about the cores ``vortices_<run>.nc`` lists; and the average
    turns, at its centre, as its cores do (prograde: with the mean shear, clockwise here)."""
    import xarray as xr
    from rspiv.campaign.conditional import write_outputs

    _, camp, res = processed
    st = camp.config.statistics
    run = "method_II"
    acc = res.accumulators[run]
    prof = res.analyses[run].profile
    vort = res.vortices[run]
    t = vort["cores"]
    m = prof["m_per_px"]
    dist = prof["dist_px"]
    field = next((res.out_dir / "fields" / run).glob("pair_*.nc"))
    with xr.open_dataset(field, engine="h5netcdf") as ds:
        xg = ds["x"].values.astype(np.float64)
    rows = np.argmin(np.abs(dist[None, :] * m - t["y"][:, None]), axis=1)
    cols = np.rint(np.interp(t["x"] / m, xg, np.arange(xg.size))).astype(int)
    # the two rows holding the most cores that the conditional plan accepts, as references
    plan_ok = dist >= 2.5 * res.context.piv.final_window[1] + 1
    counts = np.bincount(rows, minlength=dist.size) * plan_ok
    refs = np.sort(np.argsort(counts)[-2:])
    assert counts[refs].min() >= 2
    keep = (st.conditional_heights, st.conditional_height_units)
    camp.config.output.netcdf = False  # the fixture's files stay the campaign's
    try:
        st.conditional_heights, st.conditional_height_units = tuple(dist[refs]), "px"
        c = write_outputs(camp, res, res.context.runs[0], res.analyses[run])
    finally:
        st.conditional_heights, st.conditional_height_units = keep
        camp.config.output.netcdf = True
    assert c["kinds"] == ["Q2", "Q4", "prograde", "retrograde"]
    np.testing.assert_array_equal(c["ref_rows"], refs)
    sx, sy, k = prof["sign_x"], prof["sign_y"], prof["k"]
    u, v, ok = _fields(res.out_dir, run)
    ok &= (acc.count >= 2) & (dist > 0)[:, None] & np.isfinite(u) & np.isfinite(v)
    du = np.where(ok, sx * (u - acc.mean_u), 0.0)
    dv = np.where(ok, sy * (v - acc.mean_v), 0.0)
    map_rows = np.array([np.flatnonzero(dist == y)[0] for y in c["dist_px"]])
    offsets = np.rint(sx * c["dx_px"] / float(np.median(np.diff(xg)))).astype(int)
    pro = t["sign"] == vort["prograde_sign"]
    pairs = sorted(acc.pair_ids)
    for i, ref in enumerate(refs):
        for kind, mine in ((2, pro), (3, ~pro)):
            at = set()  # two cores on one vector are one event
            for j in np.flatnonzero(mine & (rows == ref)):
                p = pairs.index(int(t["pair"][j]))
                if ok[p, ref, cols[j]]:
                    at.add((p, int(cols[j])))
            assert c["events"][i, kind] == len(at)
            if not at:
                continue
            su, sv, n = _sums_about(at, du, dv, ok, map_rows, offsets)
            np.testing.assert_array_equal(c["count"][i, kind], n)
            with np.errstate(invalid="ignore", divide="ignore"):
                np.testing.assert_allclose(c["u"][i, kind] / k, su / n, rtol=1e-9, atol=1e-12)
                np.testing.assert_allclose(c["v"][i, kind] / k, sv / n, rtol=1e-9, atol=1e-12)
    assert c["events"][:, 2:].sum() >= 4
    # the average's vorticity at its centre (flow frame: x downstream, y from the wall)
    ys, xs = c["dist_px"], c["dx_px"]
    for i, ref in enumerate(refs):
        r0 = int(np.argmin(np.abs(ys - dist[ref])))  # the map's rows may step over it
        c0 = int(np.flatnonzero(xs == 0)[0])
        for kind, sign in ((2, vort["prograde_sign"]), (3, -vort["prograde_sign"])):
            if c["events"][i, kind] == 0:
                continue
            uu, vv = c["u"][i, kind], c["v"][i, kind]
            dvdx = (vv[r0, c0 + 1] - vv[r0, c0 - 1]) / (xs[c0 + 1] - xs[c0 - 1])
            dudy = (uu[r0 + 1, c0] - uu[r0 - 1, c0]) / (ys[r0 + 1] - ys[r0 - 1])
            assert np.sign(dvdx - dudy) == sign


def test_conditional_heights_the_run_cannot_hold_are_refused(processed):
    """A reference height inside the rows the wall shapes, or heights in delta_99 without the
    run's boundary-layer fit: refused in one line (the run's other outputs stand)."""
    import dataclasses as dc

    from rspiv.campaign.conditional import write_outputs
    from rspiv.errors import InvalidInputError

    _, camp, res = processed
    st = camp.config.statistics
    keep = (st.conditional_heights, st.conditional_height_units)
    camp.config.output.netcdf = False  # the fixture's files stay the campaign's
    try:
        st.conditional_heights = (5.0,)
        with pytest.raises(InvalidInputError, match="conditional_heights: 5.0 px") as exc:
            write_outputs(camp, res, res.context.runs[0], res.analyses["method_II"])
        assert "\n" not in str(exc.value)
        st.conditional_heights, st.conditional_height_units = (0.2,), "delta"
        an = dc.replace(res.analyses["method_II"], result=None)
        with pytest.raises(InvalidInputError, match="boundary-layer fit") as exc:
            write_outputs(camp, res, res.context.runs[0], an)
        assert "\n" not in str(exc.value)
        # in delta_99 with the fit: the rows nearest to 0.2 delta_99
        prof = write_outputs(camp, res, res.context.runs[0], res.analyses["method_II"])
        bl = res.analyses["method_II"].result
        assert prof["y_ref"][0] == pytest.approx(0.2 * bl.delta99, rel=0.05)
    finally:
        st.conditional_heights, st.conditional_height_units = keep
        camp.config.output.netcdf = True


def test_conditional_averages_of_a_whole_field_drift_are_said(processed, tmp_path):
    """Fluctuations of the whole field (each pair's field moved as one, as a speed drifting over
    the run moves it) give conditional averages that do not decay away from their events: said
    in one line (log, file, summary), with the ratio per reference and kind."""
    import h5py
    from rspiv.campaign.conditional import FAR_SHARE, MIN_EVENTS

    prof = processed[2].analyses["method_II"].profile
    sx, sy = prof["sign_x"], prof["sign_y"]

    def drift(out: pathlib.Path):
        for p, f in enumerate(sorted((out / "fields" / "method_II").glob("pair_*.nc"))):
            # in the flow's frame: pair 0 an ejection, pair 1 a sweep, within the screen's
            # bounds (2 px at least)
            c = (-1.5, 1.5, 0.0)[p]
            with h5py.File(f, "r+") as h:
                h["u"][...] = h["u"][...] + sx * c
                h["v"][...] = h["v"][...] - sy * c

    res, said, out = _reanalyse(processed, tmp_path, drift)
    prof = res.conditional["method_II"]
    # the drift carries the far part: 0.3-0.8 of the events' own here (the pairs' own
    # fluctuations are of the drift's size), against -0.04 to -0.01 without it (the demo)
    ratio = prof["far_ratio"][:, :2]  # the quadrant kinds (no vortex core centred there)
    assert np.all(ratio > 0.25) and (ratio > FAR_SHARE).sum() >= 2
    assert "do not decay away from their events" in prof["warning"]
    decay = prof["warning"].split("do not decay")[1]
    for i, j in zip(*np.nonzero(ratio > FAR_SHARE), strict=True):
        assert f"{('Q2', 'Q4')[j]} at {prof['y_ref'][i]:.4g} m {ratio[i, j]:.2f}" in decay
    for i, j in zip(*np.nonzero(ratio <= FAR_SHARE), strict=True):
        assert f"{('Q2', 'Q4')[j]} at {prof['y_ref'][i]:.4g} m" not in decay
    # 3 pairs: 56-70 events per height and kind, said with their counts (MIN_EVENTS)
    ev = prof["events"]
    few = prof["warning"].split("few events to average")[1].split("fewer than")[0]
    for i, j in zip(*np.nonzero((ev[:, :2] > 0) & (ev[:, :2] < MIN_EVENTS)), strict=True):
        assert f"{('Q2', 'Q4')[j]} at {prof['y_ref'][i]:.4g} m {ev[i, j]}" in few
    assert any("WARNING" in m and "conditional averages" in m for m in said)
    assert "decay" not in res.conditional["uncorrected"].get("warning", "")
    assert np.all(np.abs(res.conditional["uncorrected"]["far_ratio"][:, :2]) < 0.5)
    summary = json.loads((out / "summary.json").read_text())
    assert "do not decay" in summary["runs"]["method_II"]["conditional"]["warning"]


def test_a_run_without_field_files_is_refused_in_one_line(processed, tmp_path):
    """Every field file of a run gone: its second passes that need the grid (vortices,
    conditional averages) are refused in one line naming the folder; the other run's stand."""

    def drop(out: pathlib.Path):
        for f in (out / "fields" / "method_II").glob("pair_*.nc"):
            f.unlink()

    res, said, out = _reanalyse(processed, tmp_path, drop)
    summary = json.loads((out / "summary.json").read_text())
    for key in ("conditional", "vortices"):
        err = summary["runs"]["method_II"][f"{key}_error"]
        assert err.startswith("none of the 3 pairs has a field file in ") and "\n" not in err
        assert err.endswith(str(out / "fields" / "method_II"))
        assert "method_II" not in getattr(res, key) and "uncorrected" in getattr(res, key)
