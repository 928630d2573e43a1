"""A campaign's statistics re-reduced from its field files (rspiv.campaign.rereduce).

Ground truth: the same campaign processed afresh without the pairs left out, from the same
prepared context (its ``context.json``: the background, the calibration and the wall's angle
come from the pairs the campaign was prepared with). The re-reduced statistics must equal it to
the float32 rounding of the stored fields, the ensemble band's sums bit for bit (the band is
correlated from the frames again), and no pair finished before may go through the PIV again.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings

import h5py
import numpy as np
import pytest
from campaign_cases import lean
from rspiv.campaign import Campaign
from rspiv.campaign import pair as pair_work
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.outputs import read_profile_csv

SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=8, monte_carlo_samples=300)
LEFT_OUT = 3
FIRST = 5  # the first run stops after pairs 0-4 (an interrupted campaign)
# float32 rounding of the stored fields: 6e-8 of each value, summed over a few pairs
REL = 1e-5


def _toml(text: str, out: str, **changes: str) -> str:
    # the statistics re-reduced here (besides the profile's), the field files; no report
    text = lean(text, keep=("two_point", "vorticity"), fields=True, report=False)
    for a, b in changes.items():
        text = text.replace(a, b)
    return text.replace('dir = "out"', f'dir = "{out}"')


def _run(d, name, body, **kw):
    path = d / f"{name}.toml"
    path.write_text(body)
    return Campaign.load(path, progress=False, **kw).run()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("rereduce")
    toml = synth_campaign(d, scene=SCENE)
    text = toml.read_text().replace("[ensemble]\nenabled = false", "[ensemble]\nenabled = true")
    assert "[ensemble]\nenabled = true" in text and "fields = true" in text
    return d, text


@pytest.fixture(scope="module")
def runs(campaign):
    """The first five pairs; then all eight with pair 3 left out (re-reduced from the files,
    then the last three processed); then the same afresh from the same context."""
    d, text = campaign
    first = _run(d, "first", _toml(text, "out", **{"max_pairs = 0": f"max_pairs = {FIRST}"}))
    calls: list[int] = []
    real = pair_work.process_pair

    def counted(context, pair, *args, **kwargs):
        calls.append(pair.pair_id)
        return real(context, pair, *args, **kwargs)

    pair_work.process_pair = counted
    try:
        body = _toml(text, "out", **{"exclude_pairs = []": "exclude_pairs = [3]"})
        again = _run(d, "again", body)
    finally:
        pair_work.process_pair = real
    fresh_dir = d / "out_fresh"
    fresh_dir.mkdir()
    for name in ("context.json", "calibration.json"):  # the same prepared context
        shutil.copy(d / "out" / name, fresh_dir / name)
    fresh = _run(
        d, "fresh", _toml(text, "out_fresh", **{"exclude_pairs = []": "exclude_pairs = [3]"})
    )
    return d, first, again, fresh, calls


def _close(a, b, what):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isfinite(a), np.isfinite(b)), what
    ok = np.isfinite(a)
    scale = max(float(np.max(np.abs(b[ok]))), 1e-12) if ok.any() else 1.0
    assert float(np.max(np.abs(a[ok] - b[ok]), initial=0.0)) <= REL * scale, what


def test_field_files_give_the_campaigns_quadrant_and_two_point(runs):
    """The campaign's field files through ``rspiv statistics --two-point --quadrant``
    (:mod:`rspiv.vector_structures`): the campaign's own quadrant analysis and two-point
    correlations (the same fields, about the same means)."""
    import xarray as xr
    from rspiv.campaign.quadrant import accumulate, quadrant_accumulator, quadrant_profile
    from rspiv.vector_statistics import vector_statistics

    d, _, _, fresh, _ = runs
    out = d / "out_fresh"
    cfg = json.loads((out / "summary.json").read_text())
    for run in ("method_II", "uncorrected"):
        files = sorted((out / "fields" / run).glob("pair_*.nc"))
        r = vector_statistics(
            files, nu=cfg["runs"][run]["nu"], min_count=2, screen=0, two_point=True, quadrant=True
        )
        qd, tp = r.quadrant, r.two_point
        # the campaign's own second pass (rspiv.campaign.quadrant.write_outputs' sums), over
        # its files with its screen, about its statistics
        acc, an = fresh.accumulators[run], fresh.analyses[run]
        q = quadrant_accumulator(acc, an, 2, (0.0, 1.0, 2.0, 4.0))
        paths = {pid: out / "fields" / run / f"pair_{pid:06d}.nc" for pid in acc.pair_ids}
        n, missing = accumulate(q, paths, run, screen=fresh.context.screens().get(run))
        assert n == len(files) and not missing
        ref, _ = quadrant_profile(q, acc, an, 2, 8.0)
        # the same rows; the wall found apart (without the screen's vectors) within 0.1 px
        np.testing.assert_array_equal(qd["rows"], ref["rows"])
        np.testing.assert_allclose(qd["dist_px"], ref["dist_px"], atol=0.1)
        # the campaign's screen left out a few vectors the files hold: 1.1e-5 measured
        a, b = qd["fraction"][..., 0], ref["fraction"][..., 0]
        ok = np.isfinite(b) & ~ref["near_wall"][:, None]
        assert ok.sum() > 100 and np.array_equal(np.isfinite(a)[ok], np.isfinite(b)[ok])
        assert np.abs(a - b)[ok & np.isfinite(a)].max() < 1e-3, run
        with xr.open_dataset(out / f"two_point_{run}.nc", engine="h5netcdf") as t:
            assert tp["y"].size == t.sizes["y"]
            # the campaign leaves out the columns whose windows reach past the frames, rspiv
            # statistics those whose vectors its pilot fields found not valid: within a column
            c0, c1 = t.attrs["columns"]
            assert abs(tp["columns"][0] - c0) <= 1 and abs(tp["columns"][1] - c1) <= 1
            far = ~t["near_wall"].values
            ia, ib = int(np.argmin(np.abs(tp["dx"]))), int(np.argmin(np.abs(t["dx"].values)))
            ra = np.nanmedian(tp["R_uu"][far][:, ia + 1 : ia + 4], axis=0)
            rb = np.nanmedian(t["R_uu"].values[far][:, ib + 1 : ib + 4], axis=0)
            # measured: 1e-8 where the columns agree (uncorrected), 0.0009 a column apart
            same = tuple(tp["columns"]) == (c0, c1)
            np.testing.assert_allclose(ra, rb, atol=1e-6 if same else 0.003)


def test_pairs_left_out_are_re_reduced_from_the_fields_without_the_piv(runs):
    d, first, again, fresh, calls = runs
    assert first.n_done == FIRST
    # pairs 0-4 came from their field files: only the pairs not finished went through the PIV
    assert calls == [5, 6, 7]
    kept = set(range(SCENE.pairs)) - {LEFT_OUT}
    for run, acc in again.accumulators.items():
        ref = fresh.accumulators[run]
        assert acc.pair_ids == ref.pair_ids == kept
        np.testing.assert_array_equal(acc.count, ref.count)
        for name in ("mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv", "hm_u", "hm_v",
                     "lag_c_u", "lag_c_v", "lag_count_u", "noise_s_uu", "noise_s_vv"):  # fmt: skip
            _close(getattr(acc, name), getattr(ref, name), f"{run} {name}")
        # the two-point sums (with the PIV's replacements of rejected vectors, kept in the
        # files) and the vorticity statistics
        tp, tp_ref = acc.two_point, ref.two_point
        assert tp.pair_ids == tp_ref.pair_ids == kept
        for name, val in vars(tp_ref).items():
            if isinstance(val, np.ndarray) and val.dtype.kind in "fc":
                _close(np.abs(getattr(tp, name)), np.abs(val), f"{run} two_point {name}")
        vo, vo_ref = acc.vorticity, ref.vorticity
        for name, val in vars(vo_ref).items():
            if isinstance(val, np.ndarray) and val.dtype.kind == "f":
                _close(getattr(vo, name), val, f"{run} vorticity {name}")
        # the profile rows' sums for their errors from pair to pair
        ro, ro_ref = acc.rows, ref.rows
        assert ro.pair_ids == ro_ref.pair_ids == kept
        np.testing.assert_array_equal(ro.pairs_in, ro_ref.pairs_in)
        for name in ("total", "outer"):
            _close(getattr(ro, name), getattr(ro_ref, name), f"{run} rows {name}")
        # the ensemble band, correlated from the frames again: to the last bit
        assert acc.ensemble.pairs == ref.ensemble.pairs == len(kept)
        np.testing.assert_array_equal(acc.ensemble.acc, ref.ensemble.acc)
    # the files written from them
    for stem in ("statistics", "two_point", "vorticity"):
        for run in again.accumulators:
            name = f"{stem}_{run}.nc"
            assert (d / "out" / name).is_file() and (d / "out_fresh" / name).is_file()
    events = [json.loads(line) for line in (d / "out" / "run_log.jsonl").open()]
    rer = [e for e in events if e["event"] == "rereduced"]
    assert len(rer) == 1 and rer[0]["left_out"] == [LEFT_OUT] and rer[0]["pairs"] == FIRST - 1
    summary = json.loads((d / "out" / "summary.json").read_text())
    assert summary["excluded_pairs"] == [LEFT_OUT]
    assert summary["rereduced"]["left_out"] == [LEFT_OUT]
    rows = (d / "out" / "pairs_method_II.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == sorted(kept)
    # the checkpoint now holds the kept pairs: the next run resumes them all
    calls_again = []
    real = pair_work.process_pair
    pair_work.process_pair = lambda *a, **k: calls_again.append(a[1].pair_id) or real(*a, **k)
    try:
        body = (d / "again.toml").read_text()
        res = Campaign.load(d / "again.toml", progress=False).run()
    finally:
        pair_work.process_pair = real
    assert "exclude_pairs = [3]" in body and not calls_again and res.n_resumed == len(kept)


def test_statistics_switched_on_later_are_re_reduced(campaign):
    """The vorticity statistics and the two-point sums off in the first run, on in the second:
    the checkpoint of the other context is re-reduced, each pair's figures carried over."""
    d, text = campaign
    off = {"two_point = true": "two_point = false", "vorticity = true": "vorticity = false",
           "[ensemble]\nenabled = true": "[ensemble]\nenabled = false"}  # fmt: skip
    first = _run(d, "off", _toml(text, "out_on", **off))
    assert first.accumulators["method_II"].vorticity is None
    on = _run(d, "on", _toml(text, "out_on"))
    assert on.n_done == on.n_resumed == SCENE.pairs
    # no pair went through the loop's PIV again (the new context's preparation runs its pilot
    # pairs for the ensemble band and the two-point maps); their figures were carried over
    events = [json.loads(line) for line in (d / "out_on" / "run_log.jsonl").open()]
    last = max(i for i, e in enumerate(events) if e["event"] == "start")
    done = [e for e in events[last:] if e["event"] == "pair"]
    assert done == []
    carried = [e for e in events if e["event"] == "pair" and e.get("rereduced")]
    assert sorted(e["pair_id"] for e in carried) == list(range(SCENE.pairs))
    assert {e["fingerprint"] for e in carried} == {on.context.fingerprint()}
    acc = on.accumulators["method_II"]
    assert acc.vorticity.pair_ids == acc.two_point.pair_ids == set(range(SCENE.pairs))
    assert acc.ensemble.pairs == SCENE.pairs
    assert set(on.vorticity) == set(on.two_point) == {"method_II", "uncorrected"}
    for run, a in on.accumulators.items():  # the statistics themselves unchanged
        np.testing.assert_array_equal(a.count, first.accumulators[run].count)
        _close(a.mean_u, first.accumulators[run].mean_u, run)
    series = on.pair_quality["series"]["method_II"]
    assert list(series["pair"]) == list(range(SCENE.pairs))


def test_a_checkpoint_that_cannot_be_re_reduced_is_refused_saying_why(runs, tmp_path):
    d, *_ = runs
    out = tmp_path / "out"
    shutil.copytree(d / "out", out)
    body = (d / "again.toml").read_text().replace('dir = "out"', f'dir = "{out}"')
    assert str(out) in body
    more = body.replace("exclude_pairs = [3]", "exclude_pairs = [3, 4]")
    # a field file missing
    gone = out / "fields" / "uncorrected" / "pair_000002.nc"
    gone.rename(tmp_path / "kept.nc")
    with pytest.raises(InvalidInputError) as err:
        _run(d, "missing", more)
    msg = str(err.value)
    assert "\n" not in msg and "finished pair 4 is not among" in msg and "exclude_pairs" in msg
    assert "1 field file(s) missing" in msg and "pair_000002.nc" in msg
    (tmp_path / "kept.nc").rename(gone)
    # a field file of another configuration
    with h5py.File(gone, "a") as f:
        f.attrs["fields_fingerprint"] = "0123456789abcdef"
    with pytest.raises(InvalidInputError, match="pair_000002.nc: a field of another config"):
        _run(d, "other", more)
    # the fields off
    with pytest.raises(InvalidInputError, match=r"field files: \[output\] fields is off"):
        _run(d, "off", more.replace("fields = true", "fields = false"))


def test_field_files_read_as_vector_files(runs):
    """``rspiv.read_vectors`` (``rspiv compare``) reads a campaign's field files as the campaign
    reads them back: the valid vectors, the PIV's replacements apart, the run's frame."""
    from rspiv.campaign.fields import read_pair
    from rspiv.vector_files import read_vectors

    d = runs[0]
    for run, frame in (("method_II", "object"), ("uncorrected", "image")):
        path = d / "out" / "fields" / run / "pair_000001.nc"
        vf = read_vectors(path)
        with h5py.File(path, "r") as h:
            fp = h.attrs["fields_fingerprint"]
            fp = fp.decode() if isinstance(fp, bytes) else str(fp)
        u, v, valid, su, _ = read_pair(path, vf.u.shape, run, fp)
        assert vf.frame == frame and vf.tool == "rspiv"
        np.testing.assert_array_equal(vf.valid, valid)
        np.testing.assert_array_equal(vf.postprocessed, ~valid & np.isfinite(u))
        np.testing.assert_allclose(vf.u[np.isfinite(u)], u[np.isfinite(u)], rtol=1e-7)
        if su is not None:
            np.testing.assert_allclose(vf.sigma_u[valid], su[valid], rtol=1e-7)


def test_rspiv_statistics_of_the_field_files_give_the_campaigns_statistics(runs):
    """The field files read as another tool's series (:func:`rspiv.vector_statistics`): the
    campaign's own sums and wall, to the float32 rounding of the stored fields."""
    d, _, _, fresh, _ = runs
    from rspiv.vector_statistics import vector_statistics

    cfg = json.loads((d / "out_fresh" / "summary.json").read_text())
    for run, ref in fresh.accumulators.items():
        files = sorted((d / "out_fresh" / "fields" / run).glob("pair_*.nc"))
        assert len(files) == SCENE.pairs - 1
        summ = cfg["runs"][run]
        r = vector_statistics(files, nu=summ["nu"], min_count=2, screen=0)
        acc = r.accumulator
        # the campaign's screen left out a few vectors (rspiv.outlier_screen); the files hold
        # them: the counts differ by the screen's, the sums agree where it left none out
        screened = ref.screen.count
        np.testing.assert_array_equal(acc.count, ref.count + screened)
        same = screened == 0
        assert same.mean() > 0.99
        for name in ("mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv"):
            _close(getattr(acc, name)[same], getattr(ref, name)[same], f"{run} {name}")
        # the files carry the final window, dt and the scale: the same analysis in wall units
        # (the few screened vectors apart: 1e-4 of u_tau measured)
        assert r.window == (32, 8) and r.frame == ("image" if run == "uncorrected" else "object")
        assert r.result.u_tau == pytest.approx(summ["u_tau"], rel=1e-3)
        assert r.analysis.wall.intercept_px == pytest.approx(summ["wall"]["intercept_px"], abs=0.1)
        # the uncorrected run's wall bows through the demo's lens (2.7 px here): said
        bowed = [w for w in r.warnings if "bows" in w]
        assert bool(bowed) == (run == "uncorrected"), r.warnings


def test_the_profiles_errors_from_pair_to_pair_are_the_field_files_scatter(runs):
    """The profile's errors from the scatter between pairs (``eps_U_plus_pairs`` ...,
    :class:`rspiv.row_errors.RowErrors`) against the same read off the field files: each
    pair's row means' standard deviation over the square root of the pairs, relative to the
    vectors' own spread averaged along the row (the profile's conservative ``eps_U_plus``)."""
    d = runs[0]
    cols, _ = read_profile_csv(d / "out_fresh" / "profile_method_II.csv")
    assert np.nanmax(cols["pairs"]) == SCENE.pairs - 1  # pair 3 left out
    ratio = cols["eps_U_plus"] / cols["eps_U_plus_pairs"]
    stack = []
    for path in sorted((d / "out_fresh" / "fields" / "method_II").glob("pair_*.nc")):
        with h5py.File(path, "r") as f:
            u = np.asarray(f["u"], dtype=np.float64)
            stack.append(np.where(np.asarray(f["valid"]).astype(bool), u, np.nan))
    s = np.array(stack)
    with warnings.catch_warnings():  # rows without a valid vector
        warnings.simplefilter("ignore", RuntimeWarning)
        files = np.nanmean(np.nanstd(s, axis=0, ddof=1), axis=1) / np.nanstd(
            np.nanmean(s, axis=2), axis=0, ddof=1
        )
    files = files[np.isfinite(files)]
    # a wide frame: the pairs' scatter of a row mean is several times under the bound
    assert np.median(ratio) > 2.0
    assert np.median(ratio) == pytest.approx(np.median(files), rel=0.15)
    for k in ("uu", "vv", "uv"):
        assert np.nanmedian(cols[f"eps_{k}_plus"] / cols[f"eps_{k}_plus_pairs"]) > 1.5

