"""Outputs (NetCDF, CSV, atomic writes), boundary-layer figures, and the Markdown/HTML report."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from rspiv.boundary_layer import analyse_profile
from rspiv.errors import InvalidInputError
from rspiv.outputs import (
    atomic_path,
    profile_dataset,
    read_profile_csv,
    statistics_dataset,
    write_netcdf,
    write_profile_csv,
)
from rspiv.reference import load_dns
from rspiv.report import (
    ReportSection,
    ReportTable,
    campaign_report,
    normalise_table,
    pairs_for_paper,
    tbl_characteristics_table,
    u_tau_text,
    uncertainty_summary,
    wall_deviation_table,
    write_report,
)
from rspiv.stats import FieldAccumulator

NU = 1.5e-5
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def result():
    d = load_dns(4060)
    u_tau = 0.35
    yp = np.arange(3.0, 0.95 * d.y_plus[-1], 10.0)
    y = (yp + 1.0) * NU / u_tau
    cols = [np.interp(yp, d.y_plus, c) for c in (d.u_plus, d.uu_plus, d.vv_plus, d.uv_plus)]
    return analyse_profile(
        y,
        cols[0] * u_tau,
        cols[1] * u_tau**2,
        cols[2] * u_tau**2,
        cols[3] * u_tau**2,
        NU,
        n_eff=500.0,
    )


def test_import_rspiv_stays_light():
    code = (
        "import sys, rspiv, rspiv.stats, rspiv.boundary_layer, rspiv.report, rspiv.outputs;"
        "print('matplotlib' in sys.modules, 'xarray' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_profile_csv_round_trip(tmp_path, result):
    path = write_profile_csv(tmp_path / "profile.csv", result)
    cols, meta = read_profile_csv(path)
    np.testing.assert_array_equal(cols["U_plus"], result.u_plus)  # repr precision: exact
    np.testing.assert_array_equal(cols["eps_uv_plus"], result.eps_uv_plus)
    assert float(meta["u_tau"]) == result.u_tau
    with pytest.raises(InvalidInputError, match="'b' has 2 values"):
        write_profile_csv(tmp_path / "bad.csv", {"a": [1, 2, 3], "b": [1, 2]})


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    dest = tmp_path / "x.nc"
    dest.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(dest) as tmp:
        tmp.write_text("partial")
        raise RuntimeError("crash")
    assert dest.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["x.nc"]


def test_netcdf_statistics_and_profile(tmp_path, result, rng):
    import xarray as xr

    acc = FieldAccumulator((4, 3))
    for k in range(5):
        acc.add(rng.normal(10, 1, (4, 3)), rng.normal(0, 1, (4, 3)), pair_id=k)
    ds = statistics_dataset(acc, x=np.arange(3) * 1e-3, y=np.arange(4) * 1e-3, dt=5e-5)
    p = write_netcdf(ds, tmp_path / "stats.nc")
    with xr.open_dataset(p, engine="h5netcdf") as back:
        assert back["u"].attrs["units"] == "m s-1" and back["x"].attrs["axis"] == "X"
        assert list(back.attrs["variables"]) == ["x", "y", "u", "v"] and back.attrs["dt"] == 5e-5
        np.testing.assert_array_equal(back["u"].values, acc.mean_u)
        assert FieldAccumulator.from_xarray(back.load()).pair_ids == set(range(5))
    q = write_netcdf(profile_dataset(result), tmp_path / "profile.nc")
    with xr.open_dataset(q, engine="h5netcdf") as back:
        np.testing.assert_array_equal(back["U_plus"].values, result.u_plus)
        assert back.attrs["u_tau"] == result.u_tau and back["y"].attrs["units"] == "m"


def test_boundary_layer_figures(tmp_path, result):
    from rspiv.plots.boundary_layer import plot_boundary_layer

    other = {
        "y_plus": result.y_plus,
        "u_plus": result.u_plus * 0.9,
        "uu_plus": result.uu_plus * 0.88,
        "vv_plus": result.vv_plus,
        "uv_plus": result.uv_plus,
    }
    paths = plot_boundary_layer(tmp_path / "fig", {"P3, Method II": result, "uncorrected": other})
    assert set(paths) == {"mean_velocity", "reynolds_stresses"}
    for p in paths.values():
        assert p.read_bytes()[:8] == PNG and p.stat().st_size > 10_000
    with pytest.raises(InvalidInputError, match="missing 'uu_plus'"):
        plot_boundary_layer(tmp_path, {"bad": {"y_plus": [1.0], "u_plus": [1.0]}})


def test_write_report_md_and_html(tmp_path, result):
    from rspiv.plots.boundary_layer import plot_boundary_layer

    figs = plot_boundary_layer(tmp_path / "out" / "figures", {"run": result})
    outside = tmp_path / "elsewhere" / "wall_profile.png"
    outside.parent.mkdir()
    outside.write_bytes(figs["mean_velocity"].read_bytes())
    paths = write_report(
        tmp_path / "out",
        ReportSection(
            "Boundary layer",
            text="Profiles in wall units.\n\nSecond <paragraph> & more.",
            figures=[(figs["mean_velocity"], "U+ against y+"), figs["reynolds_stresses"]],
            tables=[
                ReportTable("Boundary-layer characteristics", tbl_characteristics_table(result))
            ],
        ),
        figures={"Wall alignment": [(outside, "wall profile")], "Boundary layer": []},
        tables={
            "Maximum wall deviation": wall_deviation_table({"Distorted": 8.7, "custom": 0.1}),
            "Calibration": {"model": "P3", "RMS (px)": (0.5, 0.4)},
        },
        metadata={"campaign": "synthetic", "pairs": 12},
    )
    md = paths["markdown"].read_text()
    page = paths["html"].read_text()
    assert "![U+ against y+](figures/mean_velocity.png)" in md
    assert "figures/wall_profile.png" in md  # copied in from outside the report folder
    assert (tmp_path / "out" / "figures" / "wall_profile.png").exists()
    assert "<img src='figures/reynolds_stresses.png'" in page
    assert "Second &lt;paragraph&gt; &amp; more." in page
    assert "| Distorted | 8.7 | 9 |" in md and "| custom | 0.1 | - |" in md
    assert "| Sun et al. (paper) | 9.64 | 103 | 0.348 | 2386 |" in md
    assert f"| this run | {result.u_e:.5g} |" in md
    assert "| RMS (px) | (0.5, 0.4) |" in md
    assert page.count("<table>") == 3 and "<h2>Wall alignment</h2>" in page
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "figures",
        "report.html",
        "report.md",
    ]
    with pytest.raises(InvalidInputError, match="does not exist"):
        write_report(tmp_path / "o2", figures={"x": [tmp_path / "missing.png"]})


def test_normalise_table_forms():
    assert normalise_table([{"a": 1, "b": 2.5}, {"a": 3}]) == (
        ["a", "b"],
        [["1", "2.5"], ["3", "-"]],
    )
    assert normalise_table({"r": {"c": None}}) == (["", "c"], [["r", "-"]])
    with pytest.raises(InvalidInputError):
        normalise_table(42)


def test_campaign_report_assembles_everything(tmp_path, result):
    other = {
        "y_plus": result.y_plus,
        "u_plus": result.u_plus * 0.9,
        "uu_plus": result.uu_plus,
        "vv_plus": result.vv_plus,
        "uv_plus": result.uv_plus,
    }

    class Uncorrected:  # a result-like object with the attributes the report reads
        def __init__(self):
            for k, v in other.items():
                setattr(self, k, v)

        def summary(self):
            return {**result.summary(), "u_tau": 0.9 * result.u_tau}

    cal_png = tmp_path / "cal.png"
    cal_png.write_bytes(PNG + b"\0" * 64)
    paths = campaign_report(
        tmp_path / "rep",
        {"P3, Method II": result, "uncorrected": Uncorrected()},
        calibration={"magnification M (px/mm)": 34.5, "model": "P3"},
        wall_deviation={"Distorted": 9.1, "Dewarped by P3 and rotated": 0.6},
        calibration_figures=[(cal_png, "markers")],
        metadata={"pairs": 3},
    )
    md = paths["markdown"].read_text()
    for heading in (
        "## Calibration",
        "## Wall alignment",
        "## Boundary layer",
        "## Acquisition and statistics",
    ):
        assert heading in md
    assert "![markers](figures/cal.png)" in md
    assert "![Mean streamwise velocity U+(y+)](figures/mean_velocity.png)" in md
    assert "| Dewarped by P3 and rotated | 0.6 | 0.62 |" in md
    assert "| magnification M (px/mm) | 34.5 | 34.538 +/- 0.5 |" in md
    assert f"| uncorrected | {result.u_e:.5g} |" in md
    unc = uncertainty_summary(result)
    # n_eff = 500: eps_U/U ~ sqrt(uu/500)/U, a fraction of a percent
    assert 0.05 < unc["uncertainty of U (%)"] < 2
    assert unc["uncertainty of uu (%)"] == pytest.approx(100 * np.sqrt(2 / 500), rel=1e-9)
    assert f"| uncertainty of U (%) | {unc['uncertainty of U (%)']:.4g} | 0.825 |" in md


def test_rows_the_wall_shapes_are_left_out_of_the_stress_and_moment_figures(
    tmp_path, monkeypatch
):
    """A run whose ``extra`` flags rows ``near_wall``: the mean velocity figure draws every row,
    the stress and the skewness/flatness figures only the others."""
    from rspiv.plots import boundary_layer as bl

    drawn = []
    draw = bl._draw

    def spy(ax, i, name, x, y, err):
        drawn.append(np.asarray(x))
        draw(ax, i, name, x, y, err)

    monkeypatch.setattr(bl, "_draw", spy)
    yp = np.geomspace(1.0, 500.0, 30)
    one = np.ones_like(yp)
    run = {
        "y_plus": yp,
        "u_plus": np.log1p(yp) * 5,
        "uu_plus": 2 * one,
        "vv_plus": one,
        "uv_plus": -one,
        "extra": {
            "near_wall": (yp < 10).astype(float),
            **{k: 0.1 * one for k in ("S_u", "S_v", "eps_S_u", "eps_S_v", "eps_F_u", "eps_F_v")},
            "F_u": 3 * one,
            "F_v": 3 * one,
        },
    }
    paths = bl.plot_boundary_layer(tmp_path, {"run": run}, dns=False)
    assert set(paths) == {"mean_velocity", "reynolds_stresses", "higher_moments"}
    assert len(drawn) == 1 + 3 + 4
    assert drawn[0].size == yp.size
    for x in drawn[1:]:
        assert x.size == np.count_nonzero(yp >= 10) and x.min() >= 10


def test_error_bars_and_uncertainties_take_the_rows_scatter_between_pairs(
    tmp_path, monkeypatch, result
):
    """A run whose rows carry their scatter between pairs (``eps_U_plus_pairs`` ... and
    ``pairs``): the figures' error bars and the report's uncertainties take it in the rows of
    VERDICT_PAIRS pairs or more and the bound in the others, as the verdicts do."""
    import dataclasses

    from rspiv.plots import boundary_layer as bl
    from rspiv.profiles import VERDICT_PAIRS, judged_errors

    n = result.y_plus.size
    pairs = np.where(np.arange(n) < n // 2, VERDICT_PAIRS, VERDICT_PAIRS - 1).astype(float)
    own = {k: getattr(result, f"eps_{k.lower()}_plus") / 4 for k in ("U", "uu", "vv", "uv")}
    own["uu"][0] = np.nan  # no scatter in that row: the bound
    extra = {f"eps_{k}_plus_pairs": v for k, v in own.items()} | {"pairs": pairs}
    run = dataclasses.replace(result, extra=extra)

    eps, which = judged_errors(run)
    assert which == "pairs" and judged_errors(result)[1] == "bound"
    many = pairs >= VERDICT_PAIRS
    for k in ("U", "uu", "vv", "uv"):
        bound = getattr(result, f"eps_{k.lower()}_plus")
        want = np.where(many & np.isfinite(own[k]), own[k], bound)
        np.testing.assert_array_equal(eps[f"eps_{k.lower()}_plus"], want)
    assert eps["eps_uu_plus"][0] == result.eps_uu_plus[0]

    # the uncertainties: the judged errors' medians over 30 < y+ < Re_tau
    m = (result.y_plus > 30) & (result.y_plus < result.re_tau)
    unc = uncertainty_summary(run)
    want = 100 * np.median(np.abs(eps["eps_u_plus"][m] / result.u_plus[m]))
    assert unc["uncertainty of U (%)"] == pytest.approx(want, rel=1e-12)
    assert unc["uncertainty of U (%)"] < uncertainty_summary(result)["uncertainty of U (%)"]
    # the pairs for the paper's uncertainties: the run's pairs (the median over those rows)
    # times (its uncertainty / the paper's)^2; none from the bound
    need = pairs_for_paper(run)
    n = np.median(pairs[m])
    for k, paper in (("U", 0.825), ("uu", 0.381), ("vv", 0.381), ("uv", 0.695)):
        rel = unc[f"uncertainty of {k} (%)"]
        assert need[k] == int(np.ceil(n * (rel / paper) ** 2))
    assert pairs_for_paper(result) is None
    # u_tau's error: the pairs' where there is one, else the fit's said to be too small
    assert "(the fit's own, its rows taken as independent: too small)" in u_tau_text(
        result.summary())
    run.u_tau_std_pairs = 0.0123
    assert u_tau_text(run.summary()) == (
        f"{run.u_tau:.4g} +/- 0.012 m/s (one standard error from the pairs' scatter)")

    # the figures' error bars: the first run's judged errors at its drawn rows
    drawn = []
    draw = bl._draw

    def spy(ax, i, name, x, y, err):
        drawn.append((i, None if err is None else np.asarray(err)))
        draw(ax, i, name, x, y, err)

    monkeypatch.setattr(bl, "_draw", spy)
    bl.plot_boundary_layer(tmp_path, {"run": run, "bound": result}, dns=False, moments=False)
    first = [e for i, e in drawn if i == 0]
    pos = result.y_plus > 0
    for err, k in zip(first, ("u", "uu", "vv", "uv"), strict=True):
        np.testing.assert_array_equal(err, eps[f"eps_{k}_plus"][pos])


def test_the_texts_name_the_pairs_the_error_bars_take():
    """The reports' and figures' words say the rows' scatter is taken from
    :data:`rspiv.profiles.VERDICT_PAIRS` pairs on (written out where the texts are, so that the
    report stays free of the statistics' imports): they move together."""
    from rspiv.plots import boundary_layer as bl_plots
    from rspiv.profiles import VERDICT_PAIRS
    from rspiv.report import ERROR_BARS, MOMENTS_CAPTION, uncertainty_summary

    said = f"{VERDICT_PAIRS} pairs or more"
    texts = (ERROR_BARS, MOMENTS_CAPTION, uncertainty_summary.__doc__,
             bl_plots.plot_boundary_layer.__doc__, bl_plots._plot_moments.__doc__)  # fmt: skip
    for text in texts:
        assert said in " ".join(text.split()), text
