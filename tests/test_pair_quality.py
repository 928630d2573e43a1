"""Each pair's quality over a campaign (rspiv.campaign.pair_quality, rspiv.recording_drift).

Ground truth: a synthetic campaign (scale 0.15, 10 pairs) in which pair 6's frames are swapped
(frames A and B in reverse order: it measures the flow backwards and passes every test within its
field), pair 3 is rendered with half the displacement (half the pulse separation) and pair 8's
frame B is moved down by a row (the camera shaken between the exposures), and pair 1's frame B
is dimmed to 35 % above its background (a weak laser pulse). The swapped pair must be left out of
every statistic, exactly as if it had been excluded; the mistimed, shaken and dim pairs must be
said and kept; no other pair may be said. The run's direction and the
screen are checked on constructed inputs with known answers.
"""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest
import tifffile
from campaign_cases import lean
from rspiv.campaign import Campaign
from rspiv.campaign import pair_quality as pq
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.recording_drift import flow_direction
from rspiv.synth.particles import particle_pair
from rspiv.synth.tbl import tbl_pair
from rspiv.synth.truth import PAPER_M

SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=10, monte_carlo_samples=300)
SWAPPED, MISTIMED, FACTOR, SHAKEN, DIM = 6, 3, 0.5, 8, 1


def _toml(text: str, out: str, *, report: bool = False, uncorrected: bool = False, **images) -> str:
    """The campaign without the statistics these tests do not check (``campaign_cases.lean``)
    and without a background: the background over the pairs would differ by the pair excluded.
    """
    text = lean(text, report=report, uncorrected=uncorrected)
    text = text.replace('background = "min"', 'background = "none"')
    text = text.replace('dir = "out"', f'dir = "{out}"')
    for key, value in images.items():
        text = text.replace(f"{key} = []", f"{key} = {value}")
    return text


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("pairs")
    toml = synth_campaign(d, scene=SCENE)
    raw = d / "raw"
    # pair 6: frames in reverse order
    a, b = raw / f"pair_{SWAPPED:05d}_a.tif", raw / f"pair_{SWAPPED:05d}_b.tif"
    tmp = raw / "swap.tmp"
    a.rename(tmp)
    b.rename(a)
    tmp.rename(b)
    # pair 3: the same flow with half the pulse separation
    s = SCENE
    fa, fb, _ = tbl_pair(
        scale=s.scale, seed=s.seed + 1 + MISTIMED, flow=s.flow(), u_inf_px=FACTOR * s.u_inf_px,
        wall_angle_deg=s.wall_angle_deg, density=s.density, diameter=s.diameter, noise=s.noise,
        reflection=s.reflection, correlation_px=s.correlation_px, magnification=PAPER_M / s.scale,
        lens=s.lens(),
    )  # fmt: skip
    tifffile.imwrite(raw / f"pair_{MISTIMED:05d}_a.tif", fa)
    tifffile.imwrite(raw / f"pair_{MISTIMED:05d}_b.tif", fb)
    # pair 8: frame B one row lower (its last row wraps to the top)
    path = raw / f"pair_{SHAKEN:05d}_b.tif"
    tifffile.imwrite(path, np.roll(tifffile.imread(path), 1, axis=0))
    # pair 1: frame B's particle images at 35 % (the background, its median, kept)
    path = raw / f"pair_{DIM:05d}_b.tif"
    f = tifffile.imread(path).astype(np.float64)
    bg = np.median(f)
    tifffile.imwrite(path, (bg + 0.35 * (f - bg)).clip(0, 4095).round().astype(np.uint16))
    # a run whose frames go both ways: pairs 2, 5, 6 and 7 (pair 6 swapped above) reversed
    both = d / "raw_both"
    both.mkdir()
    for k in range(SCENE.pairs):
        ab = ("b", "a") if k in (2, 5, 7) else ("a", "b")
        for dst, src in zip(("a", "b"), ab, strict=True):
            (both / f"pair_{k:05d}_{dst}.tif").symlink_to(raw / f"pair_{k:05d}_{src}.tif")
    text = toml.read_text()
    files = {
        # the report is checked in the first; every run's statistics against those excluding
        "said": _toml(text, "out", report=True, uncorrected=True),
        "both": _toml(text, "out_both").replace("check_pairs = 5", "check_pairs = 10")
        .replace('glob = "raw/*.tif"', 'glob = "raw_both/*.tif"'),
        "excluded": _toml(text, "out_excluded", uncorrected=True, exclude_pairs=f"[{SWAPPED}]"),
        "unsampled": _toml(text, "out_unsampled").replace("check_pairs = 5", "check_pairs = 1"),
    }
    out = {}
    for name, body in files.items():
        path = d / f"{name}.toml"
        path.write_text(body)
        camp = Campaign.load(path, progress=False)
        out[name] = (camp, camp.run())
    return d, out


def test_a_pair_in_reverse_order_is_left_out_as_if_excluded(runs):
    """The swapped pair is skipped with its figures named; the statistics are those of the run
    that excludes it, to the last bit."""
    _, out = runs
    camp, res = out["said"]
    assert set(res.skipped) == {SWAPPED}
    why = res.skipped[SWAPPED]
    assert pq.REVERSED_SAID in why and "points the other way" in why
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["reversed_pairs"]["left_out"] == [SWAPPED]
    dx, dy = summary["reversed_pairs"]["direction"]
    assert dx == pytest.approx(SCENE.u_inf_px * 0.72, rel=0.3) and abs(dy) < 0.5
    _, ex = out["excluded"]
    assert not ex.skipped and ex.n_pairs == SCENE.pairs - 1
    for run, acc in res.accumulators.items():
        ref = ex.accumulators[run]
        assert acc.pair_ids == ref.pair_ids == set(range(SCENE.pairs)) - {SWAPPED}
        for name in ("mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv", "count"):
            np.testing.assert_array_equal(getattr(acc, name), getattr(ref, name), err_msg=name)
    # said once in the report
    md = (res.out_dir / "report" / "report.md").read_text()
    assert "## The pairs over the run" in md and "reverse order" in md


def test_mistimed_and_shaken_pairs_are_said_and_kept(runs):
    """The pair of half the displacement and the pair whose frame B moved by a row are the only
    ones said unlike the run, each for what it is; they stay in the statistics; every pair's
    figures are in pairs_<run>.csv."""
    _, out = runs
    _, res = out["said"]
    outliers = res.pair_quality["outliers"]
    assert list(outliers) == [DIM, MISTIMED, SHAKEN]
    assert "frame B's particle images at 35 %" in outliers[DIM]
    assert "frame A" not in outliers[DIM]
    assert res.pair_quality["trends"] == {}  # nothing drifts over these pairs
    assert "times the run's median" in outliers[MISTIMED] and "across" not in outliers[MISTIMED]
    assert "across the run's median +0.9" in outliers[SHAKEN] and "camera" in outliers[SHAKEN]
    assert "times the run's median" not in outliers[SHAKEN]
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert list(summary["pair_outliers"]) == [str(DIM), str(MISTIMED), str(SHAKEN)]
    assert {DIM, MISTIMED, SHAKEN} <= res.accumulators["method_II"].pair_ids
    for run in res.accumulators:
        with open(res.out_dir / f"pairs_{run}.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert [int(r["pair"]) for r in rows] == [k for k in range(SCENE.pairs) if k != SWAPPED]
        along = {int(r["pair"]): float(r["along"]) for r in rows}
        assert along[MISTIMED] == pytest.approx(FACTOR, rel=0.1)
        assert all(abs(v - 1) < 0.05 for k, v in along.items() if k != MISTIMED)
        assert all(0.9 < float(r["valid"]) <= 1 and float(r["peak_ratio"]) > 3 for r in rows)
        across = {int(r["pair"]): float(r["across_px"]) for r in rows}
        assert across[SHAKEN] == pytest.approx(1.0, abs=0.15)  # its own flow: about 0.1 px
        assert all(abs(v) < 0.25 for k, v in across.items() if k != SHAKEN)
        flagged = [int(r["pair"]) for r in rows if r["unlike_run"]]
        assert flagged == ([DIM, MISTIMED, SHAKEN] if run == "method_II" else [])
        ratio = {int(r["pair"]): float(r["signal_b"]) / float(r["signal_a"]) for r in rows}
        assert ratio[DIM] == pytest.approx(0.35, abs=0.03)
        assert all(abs(v - 1) < 0.05 for k, v in ratio.items() if k != DIM)


def test_without_sampled_pairs_reversed_frames_are_not_looked_for(runs):
    """With ``check_pairs = 1`` no direction is known: nothing is left out, and the summary
    says why."""
    _, out = runs
    _, res = out["unsampled"]
    assert not res.skipped and res.n_done == SCENE.pairs
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["reversed_pairs"]["direction"] is None
    assert "check_pairs = 1" in summary["reversed_pairs"]["note"]
    # the screen still finds the mistimed pair; the swapped one is unlike the run too
    assert set(res.pair_quality["outliers"]) == {DIM, MISTIMED, SWAPPED, SHAKEN}


def test_frames_going_both_ways_leave_nothing_out(runs):
    """Four of ten sampled pairs reversed: either way may be the right one, so no direction is
    taken and nothing is left out; the preparation says so, and the screen names the four."""
    _, out = runs
    camp, res = out["both"]
    assert not res.skipped and res.n_done == SCENE.pairs
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["reversed_pairs"]["direction"] is None
    assert "both ways (6 one way, 4 the other: pairs 2, 5, 6, 7)" in (
        summary["reversed_pairs"]["note"]
    )
    assert "leaves no pair out" in summary["recording_warnings"]["drift_reversed"]
    unlike = res.pair_quality["outliers"]
    assert {2, 5, 6, 7} <= set(unlike)
    assert all("-0.9" in unlike[k] or "-1.0" in unlike[k] for k in (2, 5, 6, 7))


def test_excluding_a_pair_the_checkpoint_holds_is_refused(runs, tmp_path):
    """A pair excluded after it entered the checkpoint: one line naming exclude_pairs."""
    d, out = runs
    camp, res = out["said"]
    text = (d / "said.toml").read_text().replace("exclude_pairs = []", "exclude_pairs = [2]")
    path = d / "said_excluding.toml"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match="exclude_pairs"):
        Campaign.load(path, progress=False).run()
    bad = text.replace("exclude_pairs = [2]", "exclude_pairs = [40]")
    path.write_text(bad)
    with pytest.raises(InvalidInputError, match="pair 40 is not among the campaign's 10 pairs"):
        Campaign.load(path, progress=False).pairs()
    path.write_text(text.replace("exclude_pairs = [2]", "exclude_pairs = [2.5]"))
    with pytest.raises(InvalidInputError, match="exclude_pairs"):
        Campaign.load(path, progress=False)


def test_the_runs_direction_from_sampled_pairs():
    """flow_direction: the agreeing pairs' median; a reversed sample named; no direction where
    the samples disagree, turn, stand still or are too few."""
    ids = [0, 10, 20, 30, 40]
    steady = [(12.0, 0.5), (11.5, 0.4), (12.5, 0.6), (12.2, 0.3), (11.8, 0.5)]
    fd = flow_direction(ids, steady)
    assert fd.displacement == pytest.approx((12.0, 0.5)) and not fd.reversed and not fd.note
    one_back = steady[:3] + [(-12.1, -0.4)] + steady[4:]
    fd = flow_direction(ids, one_back)
    assert fd.reversed == [30] and fd.pairs == [0, 10, 20, 40]
    assert fd.displacement == pytest.approx((11.9, 0.5))
    turning = steady[:2] + [(2.0, 0.1)] + steady[3:]
    fd = flow_direction(ids, turning)
    assert fd.displacement is None and "pair 20" in fd.note and "changes" in fd.note
    tied = flow_direction(ids[:4], steady[:2] + [(-12, 0), (-12, 0)])
    assert tied.displacement is None and "both ways (2 one way, 2 the other" in tied.note
    # two of five the other way: either may be right; no direction, both sides named
    fd = flow_direction(ids, steady[:3] + [(-12.1, -0.4), (-11.9, -0.5)])
    assert fd.displacement is None and fd.reversed == [30, 40] and fd.pairs == [0, 10, 20]
    assert "both ways (3 one way, 2 the other: pairs 30, 40)" in fd.note
    assert "under 1 px" in flow_direction(ids[:2], [(0.3, 0.1), (0.2, 0.1)]).note
    assert "fewer than two" in flow_direction(ids[:2], [(5.0, 0), (np.nan, np.nan)]).note


def _series(rng, n: int, step: int, *, valid: float, u: float) -> dict[str, np.ndarray]:
    """A run's series of ``n`` pairs (ids ``step`` apart) scattered as a turbulent run's: the
    valid share about 0.97 and the mean displacement about (15, 0) px, with the given relative
    scatters, the peak ratio about 5."""
    return {
        "pair": np.arange(n) * step,
        "valid": 0.97 + valid * rng.standard_normal(n),
        "peak_ratio": 5.0 + 0.2 * rng.standard_normal(n),
        "u": 15.0 * (1 + u * rng.standard_normal(n)),
        "v": 0.02 * rng.standard_normal(n),
    }


def test_the_screen_names_each_kind_of_outlier():
    """A constructed series: one pair of twice the displacement, one displaced sideways, one
    with a third of its vectors lost, one correlating weakly; the others scattered as a
    turbulent run's are."""
    s = _series(np.random.default_rng(7), 40, 3, valid=0.005, u=0.03)
    assert pq.screen(s) == {}
    s["u"][5] *= 2.0
    s["valid"][11] = 0.64
    s["peak_ratio"][20] = 2.1
    s["v"][30] += 0.5
    got = pq.screen(s)
    assert list(got) == [15, 33, 60, 90]
    assert "times the run's median" in got[15]
    assert "64 % of its vectors valid" in got[33]
    assert "median peak ratio 2.10" in got[60]
    assert "across the run's median +0.49" in got[90] and len(got[90].split("; ")) == 1
    assert pq.screen({k: v[: pq.MIN_PAIRS - 1] for k, v in s.items()}) == {}


def test_the_direction_in_a_corrected_frame(runs):
    """A corrected run holds the direction mapped into its object frame: the displacement
    between the inverse images of its two ends about the frame's centre."""
    _, out = runs
    _, res = out["said"]
    ctx = res.context
    run = ctx.runs[0]
    assert run.method == "II" and ctx.reference is not None
    h, w = ctx.object_shape
    centre = ctx.mapping.forward(np.array([[0.5 * (w - 1), 0.5 * (h - 1)]]))[0]
    ref = np.asarray(ctx.reference)
    ends = ctx.mapping.inverse(np.array([centre - ref / 2, centre + ref / 2]))
    assert pq.run_direction(ctx, run) == pytest.approx(ends[1] - ends[0], abs=2e-3)
    assert pq.run_direction(ctx, ctx.runs[-1]) == pytest.approx(tuple(ref))


def test_reversed_reason():
    """A pair is reversed at or below minus half the direction; nothing is said without a
    direction or a displacement."""
    d = (10.0, 0.0)
    assert pq.reversed_reason({"u": -6.0, "v": 0.0}, d)
    assert not pq.reversed_reason({"u": -4.0, "v": 0.0}, d)
    assert not pq.reversed_reason({"u": -9.0, "v": 0.0}, None)
    assert not pq.reversed_reason({"u": np.nan, "v": np.nan}, d)


def test_the_drift_check_says_a_reversed_pair():
    """check_drift over pairs spread over a run: a swapped pair is said (``reversed``) and the
    run's direction comes from the others."""
    from rspiv.recording_drift import check_drift

    def pairs():
        for k in range(5):
            a, b = particle_pair((512, 512), (6.0, 1.0), 0.02, 2.5, 0.05, 20 + k)
            yield 100 * k, *((b, a) if k == 3 else (a, b))

    r = check_drift(pairs())
    assert r.direction.reversed == [300] and set(r.warnings) == {"reversed"}
    assert r.direction.displacement == pytest.approx((6.0, 1.0), abs=0.1)
    assert r.displacement[3] == pytest.approx((-6.0, -1.0), abs=0.1)
    assert "pair(s) 300 displace the other way" in r.warnings["reversed"]
    assert any("the run's direction: (6.0" in line for line in r.lines())


def test_a_drift_over_the_run_is_said():
    """A constructed run: the mean displacement rising by 2 % from the first pair to the last
    and the valid share falling by 7 points, under a pair-to-pair scatter of 0.5 % and 0.3
    points, are said with their size; a steady run with one outlier says nothing."""
    rng = np.random.default_rng(11)
    n = 60
    t = np.linspace(0.0, 1.0, n)
    steady = _series(rng, n, 5, valid=0.003, u=0.005)
    lone = {k: v.copy() for k, v in steady.items()}
    lone["u"][-1] *= 2.0  # said as unlike the run, and left out of the line
    outliers = pq.screen(lone)
    assert list(outliers) == [5 * (n - 1)] and pq.trends(lone, outliers) == {}
    drifting = {k: v.copy() for k, v in steady.items()}
    drifting["u"] *= 1 + 0.02 * t
    drifting["valid"] -= 0.07 * t
    drifting["signal_b"] = 2000.0 * (1 - 0.4 * t) + 20 * rng.standard_normal(n)
    got = pq.trends(drifting, pq.screen(drifting))
    assert set(got) == {"displacement", "valid", "signal_B"}
    said = got["signal_B"]
    assert said.startswith("frame B's particle images change in brightness from 20")
    assert float(said.split("counts (")[1].split(" %")[0]) == pytest.approx(-40, abs=2)
    change = float(got["displacement"].split("changes by ")[1].split(" %")[0])
    assert change == pytest.approx(2.0, abs=0.3)
    assert "changes from 97 % to 90 %" in got["valid"]


def test_bad_input_is_refused_in_one_line():
    """The new public functions refuse what they cannot measure, naming it."""
    from rspiv.recording_drift import pair_brightness

    a = np.zeros((128, 128), np.uint16)
    with pytest.raises(InvalidInputError, match="2D arrays of one shape"):
        pair_brightness(a, a[:64], None)
    with pytest.raises(InvalidInputError, match="2D arrays of one shape"):
        pair_brightness(a[0], a[0], None)
    # frames of two dtypes are measured each as it is
    got = pair_brightness(a, a.astype(np.float32), None)
    assert got["background_a"] == got["background_b"] == 0
    with pytest.raises(InvalidInputError, match="the mask is"):
        pair_brightness(a, a, np.zeros((64, 64), bool))
    with pytest.raises(InvalidInputError, match="one \\(u, v\\) displacement per pair id"):
        flow_direction([0, 1, 2], [(1.0, 0.0), (1.0, 0.0)])
    with pytest.raises(InvalidInputError, match="one \\(u, v\\) displacement per pair id"):
        flow_direction([0], [1.0, 0.0, 3.0])


def test_correlated_pairs_do_not_make_a_drift():
    """Successive pairs of a time-resolved recording share the flow's slow scales: an AR(1)
    scatter of lag-1 correlation 0.95 and 3 % (about five independent samples in 200 pairs)
    has no drift, and none is said in 20 runs; without the correlation's allowance 9 of them
    read one (a fitted line at 5 naive standard errors and over 1 %)."""
    n, rho = 200, 0.95
    said = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        e = np.zeros(n)
        for i in range(1, n):  # an AR(1) series: 200 values, not pixels
            e[i] = rho * e[i - 1] + np.sqrt(1 - rho**2) * rng.standard_normal()
        s = _series(rng, n, 1, valid=0.003, u=0.0)
        s["u"] = 15.0 * (1 + 0.03 * e)
        said += "displacement" in pq.trends(s, {})
    assert said == 0
