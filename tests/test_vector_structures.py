"""Spectra, two-point correlations and quadrant analysis of another tool's vector series
(:mod:`rspiv.vector_structures`, ``rspiv statistics --two-point --quadrant``).

Ground truth from the generator (:mod:`rspiv.synth.tbl`): the synthetic layer's fluctuations are
white noise Gaussian-filtered to a standard deviation of ``correlation_px / 2`` = 16 px, so
along a row ``R(dx) = exp(-dx^2 / (4 16^2))``, the integral length is ``sqrt(pi) 16`` px and
the one-sided spectrum of unit variance is ``(2 16 / sqrt(pi)) exp(-(16 k)^2)`` (k in rad/px);
``u'`` and ``v'`` are jointly Gaussian with the flow's correlation coefficient, so the quadrant
shares at H = 0 are a Gaussian pair's (:func:`rspiv.quadrant.gaussian_quadrant`). Exact: the
same sums computed here in numpy from the arrays written to the files.
"""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pytest
import xarray as xr
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.quadrant import gaussian_quadrant
from rspiv.synth.tbl import TBLFlow
from rspiv.vector_statistics import vector_statistics
from vector_series_cases import exact_field, write_series

pytest.importorskip("lvpyio", reason="the series are DaVis files (rspiv[davis])")
FLOW = TBLFlow()
NU = FLOW.nu
SIGMA = 16.0  # px: the fluctuations' Gaussian filter (correlation_px 32 at the cases' scale)
N = 60


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    folder = tmp_path_factory.mktemp("structures")
    files, truth = write_series(folder, N)
    r = vector_statistics(files, nu=NU, two_point=True, quadrant=True, screen=0)
    return folder, files, truth, r


def _px(r, values):
    """Lengths of the result in px (its outputs are in m)."""
    return np.asarray(values) / (r.mm_per_px * 1e-3)


def test_two_point_statistics_are_the_generators(series):
    _, _, _, r = series
    tp = r.two_point
    assert r.warnings == [] and tp["pairs"] == N and tuple(tp["columns"]) == (0, 138)
    far = ~tp["near_wall"] & (tp["y"] < 0.1)  # inside the layer (delta_99 ~ 0.1 m)
    assert far.sum() > 40
    dx = _px(r, tp["dx"])
    i0 = int(np.argmin(np.abs(dx)))
    assert np.allclose(dx[i0 : i0 + 4], [0, 16, 32, 48], atol=1e-6)
    want = np.exp(-(dx[i0 : i0 + 4] ** 2) / (4 * SIGMA**2))
    for q in ("R_uu", "R_vv"):
        got = np.median(tp[q][far][:, i0 : i0 + 4], axis=0)
        # measured: within 0.0041 of the generator's at every lag
        np.testing.assert_allclose(got, want, atol=0.015, err_msg=q)
    length = np.median(_px(r, tp["L_uu"][far]))
    assert length == pytest.approx(np.sqrt(np.pi) * SIGMA, rel=0.03)  # measured: +0.8 %
    # the spectrum, normalised by its row's integral, against the generator's shape, where it
    # holds a tenth of its peak
    k = tp["k_x"] * r.mm_per_px * 1e-3  # rad/px
    shape = 2 * SIGMA / np.sqrt(np.pi) * np.exp(-((SIGMA * k) ** 2))
    var = np.trapezoid(tp["phi_uu"][far], tp["k_x"], axis=1)
    got = np.median(tp["phi_uu"][far] / var[:, None], axis=0) / (r.mm_per_px * 1e-3)
    band = shape > 0.1 * shape[0]
    rel = got[band] / shape[band] - 1
    # measured: 2.8 % median, 7.8 % at most over the 34 wavenumbers (60 fields' scatter)
    assert np.median(np.abs(rel)) < 0.05 and np.max(np.abs(rel)) < 0.15, rel
    # wall units: lambda+ and the premultiplied spectrum
    assert np.allclose(tp["lambda_plus"][1:], 2 * np.pi / tp["k_x"][1:] / (NU / r.result.u_tau))


def test_two_point_sums_are_the_fields(series):
    """R_uu at one step, row by row, as numpy gives it from the arrays written (float32)."""
    _, _, _, r = series
    u = np.stack([exact_field(s)[3].astype(np.float32) for s in range(N)]).astype(np.float64)
    tp = r.two_point
    uf = u - u.mean(axis=0)
    n, _, nx = u.shape
    var = (uf**2).sum(axis=(0, 2)) / ((n - 1) * nx)
    r1 = (uf[:, :, :-1] * uf[:, :, 1:]).sum(axis=(0, 2)) / ((n - 1) * (nx - 1)) / var
    dx = _px(r, tp["dx"])
    i1 = int(np.argmin(np.abs(dx - 16 * np.sign(dx[-1]))))
    np.testing.assert_allclose(tp["R_uu"][:, i1], r1[tp["rows"]], atol=1e-5)


def test_quadrant_shares_are_a_gaussian_pairs_and_the_fields(series):
    _, _, _, r = series
    qd = r.quadrant
    assert qd["pairs"] == N and list(qd["holes"]) == [0, 1, 2, 4]
    far = ~qd["near_wall"] & (qd["y"] < qd["delta_99"])
    uu, vv, uv = FLOW.stresses_plus(qd["y_plus"][far])
    rho = uv / np.sqrt(uu * vv)
    np.testing.assert_allclose(qd["rho"][far], rho, atol=0.06)  # measured: 0.040 at most
    gauss = np.array([gaussian_quadrant(c, (0.0,))["fraction"][:, 0] for c in rho])
    dev = qd["fraction"][far][:, :, 0] - gauss
    # sweeps and ejections carry the stress (Q2, Q4 ~ 0.66), Q1 and Q3 subtract (~ -0.16)
    # measured: 0.0115 on average, 0.040 at most over 50 rows
    assert np.abs(dev).mean() < 0.02 and np.abs(dev).max() < 0.06, dev
    assert np.all(qd["stress_plus"][far][:, :, 0].sum(axis=1) < 0)
    # exact: the shares at H = 0 from the arrays, about each vector's own mean
    us, vs = zip(*[exact_field(s)[3:] for s in range(N)], strict=True)
    u = np.stack(us).astype(np.float32).astype(np.float64)
    v = np.stack(vs).astype(np.float32).astype(np.float64)
    p = r.analysis.profile
    du = p["sign_x"] * (u - u.mean(axis=0))
    dv = p["sign_y"] * (v - v.mean(axis=0))
    prod = du * dv
    rows = qd["rows"]
    total = prod.sum(axis=(0, 2))[rows]
    q2 = np.where((du < 0) & (dv >= 0), prod, 0).sum(axis=(0, 2))[rows]
    np.testing.assert_allclose(qd["fraction"][:, 1, 0], q2 / total, atol=1e-5)
    k = r.result.u_tau / (r.mm_per_px * 1e-3 / r.dt)  # px per pair -> wall units: u / u_tau
    np.testing.assert_allclose(qd["uv"] / r.result.u_tau**2, total / (prod[:, 0].size) / k**2,
                               rtol=1e-4)  # fmt: skip


def test_two_point_maps_are_the_generators_isotropic_correlation(series):
    """The maps about rows at 0.1, 0.3 and 0.6 delta_99, summed in the second pass: the
    generator's fluctuations are filtered alike along both axes, so about every reference row
    ``R_uu(dx, dy) = exp(-(dx^2 + dy^2) / (4 16^2))``; the rows' own statistics are those
    summed in the first pass."""
    _, files, _, r = series
    m = vector_statistics(files, nu=NU, two_point=True, two_point_maps=(0.1, 0.3, 0.6), screen=0)
    tp = m.two_point
    assert m.warnings == [] and tp["map_pairs"] == N and tp["R_uu_map"].shape[0] == 3
    for k in ("R_uu", "R_vv", "phi_uu"):
        np.testing.assert_allclose(tp[k], r.two_point[k], rtol=1e-9, atol=1e-12)
    dx = _px(m, tp["dx"])
    i0 = int(np.argmin(np.abs(dx)))
    dev = []
    for i, ref in enumerate(_px(m, tp["y_ref"])):
        assert ref / _px(m, [tp["delta_99"]])[0] == pytest.approx([0.1, 0.3, 0.6][i], abs=0.01)
        j = int(np.argmin(np.abs(_px(m, tp["map_y"]) - ref)))
        for dj in (-2, -1, 0, 1, 2):
            if not 0 <= j + dj < tp["map_y"].size:
                continue
            dy = _px(m, [tp["map_y"][j + dj]])[0] - ref
            want = np.exp(-(dy**2 + dx[i0 : i0 + 3] ** 2) / (4 * SIGMA**2))
            dev.append(tp["R_uu_map"][i, j + dj, i0 : i0 + 3] - want)
    dev = np.abs(np.array(dev))
    # measured: 0.031 at most, 0.009 on average (60 fields' scatter)
    assert dev.max() < 0.05 and dev.mean() < 0.015, dev


def test_conditional_averages_are_the_generators_regression(series):
    """About an event at a reference row the generator's u' (``sqrt(uu(y)) g1``, g1 a Gaussian
    field of correlation ``rho``) averages to ``sqrt(uu(y) / uu(y_ref)) rho(dx, dy)`` times
    the events' own u'; v' at the reference row to ``rho(dx, 0)`` times the events' own v'."""
    _, files, _, _ = series
    r = vector_statistics(files, nu=NU, conditional=True, screen=0)
    c = r.conditional
    assert r.warnings == [] and c["kinds"] == ["Q2", "Q4"] and c["pairs"] == N
    assert c["events"].min() > 500  # per height and kind
    assert np.all(c["event_u"][:, 0] < 0) and np.all(c["event_v"][:, 0] > 0)  # ejections
    assert np.all(c["event_u"][:, 1] > 0) and np.all(c["event_v"][:, 1] < 0)  # sweeps
    i0 = int(np.argmin(np.abs(c["dx_px"])))
    dxs = c["dx_px"][i0 : i0 + 3]
    dev = []
    for i, yr in enumerate(c["y_ref"]):
        assert yr / c["delta_99"] == pytest.approx([0.15, 0.4][i], abs=0.01)
        j = int(np.argmin(np.abs(c["y"] - yr)))
        for kind in range(2):
            for dj in (-1, 0, 1):
                dy = _px(r, [c["y"][j + dj] - yr])[0]
                uu = FLOW.stresses_plus(c["y_plus"][[j + dj, j]])[0]
                rho = np.exp(-(dxs**2 + dy**2) / (4 * SIGMA**2))
                got = c["u"][i, kind, j + dj, i0 : i0 + 3] / c["event_u"][i, kind]
                dev.append(got - np.sqrt(uu[0] / uu[1]) * rho)
            got = c["v"][i, kind, j, i0 : i0 + 3] / c["event_v"][i, kind]
            dev.append(got - np.exp(-(dxs**2) / (4 * SIGMA**2)))
    dev = np.abs(np.array(dev))
    # measured: 0.066 at most, 0.014 on average (about 1000 events per height and kind)
    assert dev.max() < 0.12 and dev.mean() < 0.03, dev
    # local structures: the far part of the maps holds nothing of the events
    assert np.all(np.abs(c["far_ratio"]) < 0.1)


def test_maps_without_wall_units_are_left_out_and_said(tmp_path):
    for s in range(12):
        _, x, y, u, v = exact_field(s)
        rows = np.column_stack([x.ravel() + 0.5, y.ravel() + 0.5, u.ravel(), v.ravel(),
                                0 * u.ravel(), 0 * u.ravel()])  # fmt: skip
        np.savetxt(tmp_path / f"B{s:05d}.txt", rows, header="x y u v flags mask")
    r = vector_statistics(str(tmp_path / "*.txt"), nu=NU, two_point=True, window=(32, 32),
                          two_point_maps=(0.1, 0.3))  # fmt: skip
    assert r.result is None and r.two_point is not None and "R_uu_map" not in r.two_point
    assert any("no two-point maps" in w and "wall units" in w for w in r.warnings), r.warnings


def test_the_files_and_figures_the_command_writes(series, tmp_path):
    folder, _, _, r = series
    out = tmp_path / "out"
    assert main(["statistics", str(folder), "--nu", repr(NU), "-o", str(out), "--two-point",
                 "--two-point-maps", "0.1,0.3", "--quadrant", "--screen", "0",
                 "--conditional", "--figures"]) == 0  # fmt: skip
    with xr.open_dataset(out / "two_point.nc", engine="h5netcdf") as ds:
        assert ds["phi_uu"].attrs["units"] == "m2 s-2 m" and ds.attrs["pairs"] == N
        np.testing.assert_allclose(ds["R_uu"].values, r.two_point["R_uu"], atol=1e-12)
    with xr.open_dataset(out / "quadrant.nc", engine="h5netcdf") as ds:
        np.testing.assert_allclose(ds["fraction"].values, r.quadrant["fraction"], atol=1e-12)
        assert "y_plus" in ds and list(ds["hole"].values) == [0, 1, 2, 4]
    for png in ("two_point.png", "two_point_maps.png", "quadrant.png", "conditional.png"):
        assert (out / png).stat().st_size > 10_000
    summ = json.loads((out / "summary.json").read_text())
    assert summ["two_point_rows"] == r.two_point["y"].size
    assert summ["quadrant_rows"] == r.quadrant["y"].size
    assert np.array(summ["conditional_events"]).shape == (2, 2)
    with xr.open_dataset(out / "conditional.nc", engine="h5netcdf") as ds:
        assert "u_plus" in ds and ds.attrs["pairs"] == N
    # hole sizes and shares refused in one line
    for bad in (["--quadrant", "2,1"], ["--quadrant", "a"], ["--two-point", "1.5"],
                ["--two-point-maps", "0.1"], ["--two-point", "--two-point-maps", "x"],
                ["--conditional", "0"], ["--conditional-hole", "-1"]):
        assert main(["statistics", str(folder), "--nu", repr(NU), "-o", str(tmp_path / "x"),
                     *bad]) == 2  # fmt: skip


def test_a_stopped_second_pass_resumes_and_lost_fields_are_said(series, tmp_path):
    _, files, _, _ = series
    mine = tmp_path / "files"
    mine.mkdir()
    ours = [pathlib.Path(shutil.copy(f, mine / f.name)) for f in files[:25]]
    opts = {"nu": NU, "two_point": True, "quadrant": True, "screen": 0}
    whole = vector_statistics(ours, **opts)

    def stop(done, total):
        assert total == 50
        if done == 37:  # the twelfth field of the quadrant's second pass
            raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        vector_statistics(ours, **opts, out_dir=out, checkpoint_every=5, progress=stop)
    seen = []
    again = vector_statistics(
        ours, **opts, out_dir=out, checkpoint_every=5, progress=lambda d, t: seen.append(d)
    )
    assert seen[0] == 36  # resumed after the 10 second-pass fields of the last checkpoint
    for name in ("fraction", "stress", "count", "jpdf", "uv_se"):
        np.testing.assert_array_equal(again.quadrant[name], whole.quadrant[name])
    np.testing.assert_array_equal(again.two_point["phi_uu"], whole.two_point["phi_uu"])

    # a file read in the first pass and damaged before the second: left out and said
    def damage(done, total):
        if done == 25:
            ours[3].write_bytes(b"not a DaVis file")

    try:
        lost = vector_statistics(ours, **opts, progress=damage)
    finally:
        shutil.copy(files[3], ours[3])
    assert lost.used == 25 and lost.quadrant["pairs"] == 24
    said = [w for w in lost.warnings if "failed in the second" in w]
    assert len(said) == 1 and ours[3].name in said[0], lost.warnings


def test_too_few_columns_and_bad_options_are_refused(tmp_path):
    x, y = np.meshgrid(np.arange(40) * 16.0 + 7.5, np.arange(30) * 16.0 + 7.5)
    rng = np.random.default_rng(1)
    for s in range(6):
        u = rng.normal(5, 1, x.shape)
        flags = np.ones(x.size)
        flags[(np.arange(x.size) % 40 >= 10) & (np.arange(x.size) % 40 < 16)] = 0
        rows = np.column_stack([x.ravel() + 0.5, y.ravel() + 0.5, u.ravel(), 0 * u.ravel(),
                                flags, 0 * flags])  # fmt: skip
        np.savetxt(tmp_path / f"B{s:05d}.txt", rows, header="x y u v flags mask")
    with pytest.raises(InvalidInputError, match="two-point: only 6 contiguous columns of 40"):
        vector_statistics(str(tmp_path / "*.txt"), nu=NU, two_point=True, window=(32, 32))
    for bad in ({"two_point": 0.0}, {"quadrant": (1.0, 0.5)}, {"quadrant": ()},
                {"two_point_maps": (0.1,)}, {"two_point": True, "two_point_maps": (-0.1,)},
                {"conditional": ()}, {"conditional_hole": float("nan")}):
        with pytest.raises(InvalidInputError, match="statistics: "):
            vector_statistics(str(tmp_path / "*.txt"), nu=NU, **bad)


def test_a_planted_mode_is_the_pods_first_and_its_sums_are_numpys(tmp_path, capsys):
    """The POD of a series (``pod=``, ``rspiv statistics --pod``). Ground truth: a mode planted
    in 30 exact fields, ``a_s phi`` with ``phi_u = cos(2 pi x / 1108 px) exp(-((y - 900 px) /
    150 px)^2)`` and ``a_s`` 10 px standard normal: the first mode is ``phi`` (normalised over
    the domain), its energy the coefficients' sample variance times ``|phi|^2``; and the
    decomposition is numpy's (:func:`rspiv.pod.pod` of the same fields in memory), its total the
    statistics' variance summed over the domain."""
    import rspiv
    from rspiv.campaign.pod import domain_of
    from rspiv.pod import pod
    from vector_series_cases import write_vc7

    rng = np.random.default_rng(5)
    amp = 10.0 * rng.standard_normal(30)
    amp -= amp.mean()  # about the series' mean: the planted part's own mean is zero
    for s in range(30):
        tr, x, y, u, v = exact_field(s)
        phi = np.cos(2 * np.pi * x / 1108.0) * np.exp(-(((y - 900.0) / 150.0) ** 2))
        write_vc7(tmp_path / f"B{s:05d}.vc7", u + amp[s] * phi, v, 1 / tr.magnification, tr.dt)
    calls = []
    r = vector_statistics(tmp_path, nu=NU, screen=0, pod=True, pod_modes=5,
                          progress=lambda d, t: calls.append((d, t)))  # fmt: skip
    # the progress: the 30 fields, then the POD's 30 reads (one block of rows) counted on
    assert calls == [(k, 30) for k in range(1, 31)] + [(k, 60) for k in range(31, 61)]
    p = r.pod
    assert p["pairs"] == 30 and p["gaps"] == 0 and p["fraction"].size == 5
    assert not any("POD" in w for w in r.warnings), r.warnings
    acc, an = r.accumulator, r.analysis
    domain = domain_of(an, acc, r.window[1], 10, 0.0, "pod_height")
    assert p["vectors"] == domain.sum()
    k = p["k"]
    # the first mode is the planted one (the modes' rows are by distance from the wall)
    rows = p["rows"]
    want = phi[rows] * domain[rows]
    got = p["phi_u"][0]
    fin = np.isfinite(got)
    corr = np.sum(got[fin] * want[fin]) / np.sqrt(np.sum(got[fin] ** 2) * np.sum(want[fin] ** 2))
    # measured: 0.9965 (3 px gave 0.963: with 30 snapshots the layer's fluctuations, 700 px^2
    # per mode against the planted 61,000, mix in)
    assert abs(corr) > 0.99
    planted = np.mean(amp**2) * np.sum(phi[domain] ** 2) * k * k
    assert p["energy"][0] == pytest.approx(planted, rel=0.03)  # measured: +0.7 %
    assert p["separated"][0]
    # numpy's decomposition of the same fields in memory, and the total the statistics' sum
    fields = [rspiv.read_vectors(f) for f in sorted(tmp_path.glob("*.vc7"))]
    ref = pod(np.stack([f.u for f in fields]), np.stack([f.v for f in fields]),
              np.stack([f.valid for f in fields]), 5, mean_u=acc.mean_u, mean_v=acc.mean_v,
              domain=domain)  # fmt: skip
    np.testing.assert_allclose(p["energy"], ref.energy * k * k, rtol=1e-5)
    total = np.sum((acc.m2_uu + acc.m2_vv)[domain]) / acc.n_fields * k * k
    assert p["total"] == pytest.approx(total, rel=1e-5)
    # the command: pod.nc and its figure; a POD of one field refused in one line
    out = tmp_path / "out"
    assert main(["statistics", str(tmp_path), "--nu", repr(NU), "-o", str(out), "--screen",
                 "0", "--pod", "20", "--pod-modes", "4", "--figures"]) == 0  # fmt: skip
    assert "[rspiv] fields: 50/50" in capsys.readouterr().err  # 30 fields, 20 POD reads
    with xr.open_dataset(out / "pod.nc", engine="h5netcdf") as ds:
        assert ds.attrs["pairs"] == 20 and ds["phi_u"].shape[0] == 4 and "y_plus" in ds
    assert (out / "pod.png").stat().st_size > 10_000
    summ = json.loads((out / "summary.json").read_text())
    assert len(summ["pod_fraction"]) == 4
    for bad in (["--pod", "1"], ["--pod", "5", "--pod-modes", "0"]):
        assert main(["statistics", str(tmp_path), "--nu", repr(NU), "-o", str(tmp_path / "x"),
                     *bad]) == 2  # fmt: skip
