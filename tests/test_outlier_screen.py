"""The screen of a campaign's statistics (rspiv.outlier_screen, rspiv.campaign.screen).

Ground truth: (1) constructed fields of known distributions, with planted outliers, drifts and
gaps, against the rule's exact answer; (2) a synthetic campaign (scale 0.15, 10 pairs) whose
pairs 1, 4 and 7 hold "bubbles" (discs of camera noise in both frames, where random vectors
pass the median test), against the same campaign without them: the same frames, so its
statistics are what the bubbled pairs' should be. The screen must bring the bubbled campaign's
Reynolds stresses back to the clean ones and screen nothing of the clean campaign's flow off the
wall; switching it off after the run sums the statistics again from the field files, equal to
a fresh run without it.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import pickle

import numpy as np
import pytest
import rspiv
import tifffile
import xarray as xr
from campaign_cases import lean
from rspiv.campaign import Campaign
from rspiv.campaign_config import load_campaign_config
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.outlier_screen import (
    FLOOR_PX,
    FLOOR_SHARE,
    ScreenBounds,
    ScreenTally,
    screen_bounds,
)
from rspiv.stats import FieldAccumulator

SHAPE = (60, 200)


def _fields(rng, n, draw, mean=(10.0, 0.0)):
    us = [mean[0] + draw(rng, SHAPE) for _ in range(n)]
    vs = [mean[1] + draw(rng, SHAPE) / 3 for _ in range(n)]
    return us, vs, [np.ones(SHAPE, bool)] * n


def test_scale_is_the_standard_deviation_and_gaussian_fields_pass():
    """The 5-95 % span gives the standard deviation of Gaussian and Laplace samples (the MAD
    would give 0.73 of a Laplace's); 40 fields of Gaussian vectors: none screened."""
    rng = np.random.default_rng(1)
    gauss = lambda r, s: r.normal(0, 1.5, s)  # noqa: E731
    b = screen_bounds(*_fields(rng, 6, gauss))
    assert np.nanmedian(b.limit_u) / b.sigmas == pytest.approx(1.5, rel=0.04)
    assert np.nanmedian(b.limit_v) / b.sigmas == pytest.approx(0.5, rel=0.04)
    assert np.nanmedian(b.center_u) == pytest.approx(10.0, abs=0.03)
    us, vs, oks = _fields(rng, 40, gauss)
    assert sum(int(b.outliers(u, v, ok).sum()) for u, v, ok in zip(us, vs, oks, strict=True)) == 0
    lap = lambda r, s: r.laplace(0, 1.5 / np.sqrt(2), s)  # noqa: E731  std 1.5
    bl = screen_bounds(*_fields(rng, 6, lap))
    assert np.nanmedian(bl.limit_u) / bl.sigmas == pytest.approx(1.5, rel=0.06)


def test_planted_outliers_are_found_and_nothing_else():
    """Vectors put 1.3 limits from their centre (either way, u or v) are exactly the ones
    screened; rejected vectors never are."""
    rng = np.random.default_rng(2)
    gauss = lambda r, s: r.normal(0, 1.0, s)  # noqa: E731
    b = rspiv.screen_bounds(*_fields(rng, 4, gauss), pairs=[0, 3, 6, 9])
    assert isinstance(b, rspiv.ScreenBounds) and b.pairs == [0, 3, 6, 9]
    u, v, ok = (a[0] for a in _fields(rng, 1, gauss))
    u, v = u.copy(), v.copy()
    planted = np.zeros(SHAPE, bool)
    planted.flat[rng.choice(u.size, 80, replace=False)] = True
    idx = np.flatnonzero(planted)
    side = rng.choice([-1.0, 1.0], idx.size)
    on_u = rng.random(idx.size) < 0.5
    for k, s, cu in zip(idx, side, on_u, strict=True):
        if cu:
            u.flat[k] = b.center_u.flat[k] + 1.3 * s * b.limit_u.flat[k]
        else:
            v.flat[k] = b.center_v.flat[k] + 1.3 * s * b.limit_v.flat[k]
    np.testing.assert_array_equal(b.outliers(u, v, ok), planted)
    rejected = ok.copy()
    rejected.flat[idx[:10]] = False
    assert b.outliers(u, v, rejected).sum() == planted.sum() - 10


def test_floors_keep_a_drift_and_gaps_are_not_screened():
    """A quiet free stream (spread 0.01 px at 20 px): the limit is a fifth of the centre, so a
    10 % drift stays in and a wrong peak 5 px off goes; a part of the grid that the pilot
    hardly saw valid is not screened at all."""
    rng = np.random.default_rng(3)
    quiet = lambda r, s: r.normal(0, 0.01, s)  # noqa: E731
    us, vs, oks = _fields(rng, 4, quiet, mean=(20.0, 0.0))
    oks = [ok.copy() for ok in oks]
    for ok in oks:
        ok[:, :40] = False
        ok[:, 40:44] = rng.random((SHAPE[0], 4)) < 0.05
    b = screen_bounds(us, vs, oks)
    lim = max(FLOOR_PX, FLOOR_SHARE * 20.0)
    assert np.nanmin(b.limit_u[:, 60:]) == pytest.approx(lim, rel=1e-3)
    assert np.isnan(b.limit_u[:, :20]).all()
    u = np.full(SHAPE, 22.0)  # 10 % faster
    v = np.zeros(SHAPE)
    ok = np.ones(SHAPE, bool)
    assert not b.outliers(u, v, ok).any()
    u[:, 100] = 25.0
    u[:, 5] = 50.0  # no bounds there
    got = b.outliers(u, v, ok)
    assert got[:, 100].all() and got.sum() == SHAPE[0]


def test_a_coherent_event_is_kept_and_a_lone_spike_is_not():
    """A smooth burst of 8 px that the quiet pilot pairs never saw moves with its neighbours:
    kept; the same 8 px in a lone vector (or among random neighbours) is screened."""
    rng = np.random.default_rng(6)
    quiet = lambda r, s: r.normal(0, 0.3, s)  # noqa: E731
    b = screen_bounds(*_fields(rng, 4, quiet))
    noise = lambda r, s: r.normal(0, 0.1, s)  # noqa: E731  the measurement's, vector to vector
    u, v, ok = (a[0].copy() for a in _fields(rng, 1, noise))
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    u += 8.0 * np.exp(-((xx - 50) ** 2 + (yy - 30) ** 2) / (2 * 4.0**2))
    assert not b.outliers(u, v, ok).any()
    u[10, 150] += 8.0
    u[40:43, 120:123] += rng.uniform(-12, 12, (3, 3))  # a patch of random vectors
    out = b.outliers(u, v, ok)
    assert out[10, 150] and out[40:43, 120:123].sum() >= 5
    assert out.sum() == 1 + out[40:43, 120:123].sum()


def test_a_vortex_core_needs_a_block_not_a_row():
    """A vortex (10 px at its 1.5-vector core) whose centre moves by a row between pairs: a
    row through the core sees it in a few columns only, so row bounds would screen it; the
    block a flow without a wall uses holds it."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]].astype(float)

    def vortex(yc):
        dx, dy = xx - 100.0, yy - yc
        r = np.hypot(dx, dy) + 1e-9
        speed = 10.0 * np.where(r < 1.5, r / 1.5, 1.5 / r)
        noise = rng.normal(0, 0.05, (2, *SHAPE))
        return -speed * dy / r + noise[0], speed * dx / r + noise[1], np.ones(SHAPE, bool)

    pilot = [vortex(30.0 + d) for d in (-1, 0, 1, 0)]
    us, vs, oks = zip(*pilot, strict=True)
    rows = screen_bounds(us, vs, oks)
    block = screen_bounds(us, vs, oks, half_width=4, half_height=4)
    fields = [vortex(30.0 + d) for d in (-1.4, -0.6, 0.6, 1.4)]
    assert sum(int(rows.outliers(*f).sum()) for f in fields) > 0
    assert sum(int(block.outliers(*f).sum()) for f in fields) == 0


def test_bad_input_is_refused():
    f = np.zeros(SHAPE)
    ok = np.ones(SHAPE, bool)
    with pytest.raises(InvalidInputError, match="at least 2"):
        screen_bounds([f], [f], [ok])
    with pytest.raises(InvalidInputError, match="one shape"):
        screen_bounds([f, f[:, :10]], [f, f], [ok, ok])
    with pytest.raises(InvalidInputError, match="sigmas"):
        screen_bounds([f, f], [f, f], [ok, ok], sigmas=0)
    with pytest.raises(InvalidInputError, match="half_height"):
        screen_bounds([f, f], [f, f], [ok, ok], half_height=-1)
    b = screen_bounds([f, f], [f, f], [ok, ok])
    with pytest.raises(InvalidInputError, match="shape"):
        b.outliers(f[:, :10], f[:, :10], ok[:, :10])
    with pytest.raises(InvalidInputError, match="four 2-D arrays of one shape"):
        ScreenBounds(f, f, f, f[:, :10], 7.0)
    tally = ScreenTally(SHAPE)
    with pytest.raises(InvalidInputError, match="shape"):
        tally.add(b, f, f, ok[:, :10], 0)
    with pytest.raises(InvalidInputError, match="merging shape"):
        tally.merge(ScreenTally((3, 3)))


def test_bad_files_and_settings_are_refused(tmp_path):
    """A bounds file that is not one, and a negative ``[statistics] screen``, in one line
    naming them."""
    bad = tmp_path / "screen_method_II.npz"
    bad.write_bytes(b"not an npz")
    with pytest.raises(InvalidInputError, match="screen_method_II.npz: not a readable screen"):
        ScreenBounds.load(bad)
    toml = tmp_path / "c.toml"
    toml.write_text('[images]\nglob = "raw/*.tif"\n[statistics]\nscreen = -1\n')
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.screen") as err:
        load_campaign_config(toml)
    assert "\n" not in str(err.value)


def test_tally_streams_merges_and_round_trips(tmp_path):
    """Two parts of a run's pairs merge into the whole's tally; it rides on a FieldAccumulator
    through pickles, merges and its statistics file; a pair is not counted twice."""
    rng = np.random.default_rng(4)
    gauss = lambda r, s: r.normal(0, 1.0, s)  # noqa: E731
    b = screen_bounds(*_fields(rng, 4, gauss))
    b.save(tmp_path / "b.npz")
    b2 = ScreenBounds.load(tmp_path / "b.npz")
    assert b2.digest() == b.digest()
    whole, parts = ScreenTally(SHAPE), [ScreenTally(SHAPE), ScreenTally(SHAPE)]
    accs = [FieldAccumulator(SHAPE), FieldAccumulator(SHAPE)]
    for acc, part in zip(accs, parts, strict=True):
        acc.screen = part
    for pid in range(6):
        u, v, ok = (a[0].copy() for a in _fields(rng, 1, gauss))
        u[pid, 3 * pid] += 40.0
        out = b.outliers(u, v, ok)
        assert out.sum() == 1
        whole.add(b, u, v, out, pid)
        parts[pid // 3].add(b, u, v, out, pid)
        accs[pid // 3].add(u, v, ok & ~out, pair_id=pid)
    with pytest.raises(InvalidInputError, match="added before"):
        whole.add(b, u, v, out, 5)
    merged = pickle.loads(pickle.dumps(accs[0])).merge(copy.deepcopy(accs[1]))
    for got in (merged.screen, FieldAccumulator.from_xarray(merged.to_xarray()).screen):
        np.testing.assert_array_equal(got.count, whole.count)
        np.testing.assert_allclose(got.row_sq_u, whole.row_sq_u, rtol=1e-12)
        assert got.per_pair == whole.per_pair == {p: 1 for p in range(6)}
        assert got.pair_ids == set(range(6))
    res = whole.result(merged.count)
    assert res["vectors"] == 6 and res["pairs_with_any"] == 6
    assert res["row_added_uu"][0] == pytest.approx(whole.row_sq_u[0] / (6 * SHAPE[1]))
    with pytest.raises(InvalidInputError, match="in both parts"):
        copy.deepcopy(parts[0]).merge(parts[0])


# ---------------------------------------------------------------------------- a campaign
SCENE = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=10, monte_carlo_samples=300)
BUBBLED = (1, 4, 7)


def _bubbles(raw, rng):
    """Four discs of camera noise (r = 12-25 px) in both frames of each bubbled pair."""
    h, w = tifffile.imread(raw / "pair_00000_a.tif").shape
    yy, xx = np.mgrid[:h, :w]
    for pid in BUBBLED:
        frames = [raw / f"pair_{pid:05d}_{ab}.tif" for ab in "ab"]
        fa, fb = (tifffile.imread(p).astype(np.float64) for p in frames)
        med = np.median(fa)
        for _ in range(4):
            cx, cy = rng.uniform(50, w - 50), rng.uniform(0.35 * h, 0.9 * h)
            r = rng.uniform(12, 25)
            m = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
            fa[m] = med + rng.normal(0, 20, m.sum())
            fb[m] = med + rng.normal(0, 20, m.sum())
        for p, f in zip(frames, (fa, fb), strict=True):
            tifffile.imwrite(p, np.clip(f, 0, 4095).astype(np.uint16))


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    d = tmp_path_factory.mktemp("screen")
    toml = synth_campaign(d / "clean", scene=SCENE)
    text = lean(toml.read_text(), fields=True)  # the screen's statistics; re-reduced
    assert "screen = 7.0" in text and "fields = true" in text
    bub = d / "bubbled"
    bub.mkdir()
    (bub / "raw").mkdir()
    for p in (d / "clean").iterdir():
        if p.is_file():
            (bub / p.name).write_bytes(p.read_bytes())
    for p in (d / "clean" / "raw").iterdir():
        (bub / "raw" / p.name).write_bytes(p.read_bytes())
    _bubbles(bub / "raw", np.random.default_rng(5))
    runs = {
        "clean": (d / "clean", text.replace('dir = "out"', 'dir = "out_clean"')),
        "screened": (bub, text.replace('dir = "out"', 'dir = "out_s"')),
        "unscreened": (
            bub,
            text.replace('dir = "out"', 'dir = "out_u"').replace("screen = 7.0", "screen = 0"),
        ),
        # the screened run's folder, the screen switched off after it: summed again
        "switched_off": (bub, text.replace('dir = "out"', 'dir = "out_s"').replace(
            "screen = 7.0", "screen = 0"
        )),
    }  # fmt: skip
    out = {}
    for name, (folder, body) in runs.items():
        path = folder / f"{name}.toml"
        path.write_text(body)
        camp = Campaign.load(path, progress=False)
        res = camp.run()
        summary = json.loads((res.out_dir / "summary.json").read_text())
        summary["report"] = (res.out_dir / "report" / "report.md").read_text()
        out[name] = (res, summary)
    return out


def _row_stress(acc, ref, name):
    """The stress averaged along each row over the vectors the clean run saw 6 times or more
    (NaN for a row without any)."""
    ok = ref.count > 5
    n = ok.sum(axis=1)
    with np.errstate(all="ignore"):
        total = np.where(ok, getattr(acc, name), 0.0).sum(axis=1)
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def test_bubbles_screened_give_the_clean_stresses(campaigns):
    """The bubbles' random vectors that pass the median test raise u'u' and v'v' by tens of
    percent in rows of the layer; screened, every row is within 10 % of the clean frames'
    (u'u') and 5 % (v'v'); rows away from the bubbles are untouched."""
    clean, _ = campaigns["clean"]
    scr, s_sum = campaigns["screened"]
    uns, u_sum = campaigns["unscreened"]
    for run in ("method_II", "uncorrected"):
        ref = clean.accumulators[run]
        for name, ok_rel, bad_rel in (("uu", 0.10, 0.3), ("vv", 0.05, 0.5)):
            want = _row_stress(ref, ref, name)
            got = _row_stress(scr.accumulators[run], ref, name)
            raw = _row_stress(uns.accumulators[run], ref, name)
            with np.errstate(all="ignore"):
                e_got, e_raw = (np.nanmax(np.abs(x / want - 1)) for x in (got, raw))
            print(f"{run} {name}: rows off the clean frames' by {e_got:.3f} screened, "
                  f"{e_raw:.3f} not")  # fmt: skip
            assert e_got < ok_rel and e_raw > bad_rel, (run, name)
        screened = s_sum["runs"][run]["screen"]
        print(run, screened)
        assert screened["vectors"] > 0 and "warning" not in screened
        assert screened["most_screened_pairs"][0][0] in BUBBLED
        assert "screen" not in u_sum["runs"][run]
    assert s_sum["screen"]["pilot_pairs"] == [0, 3, 6, 9]
    assert "## Vectors screened out of the statistics" in s_sum["report"]
    assert "screened" not in u_sum["report"]


def test_the_clean_flow_is_not_screened_off_the_wall(campaigns):
    """In the clean campaign, whose fluctuations are Gaussian, the screen takes only vectors
    whose windows reach the wall (within 2.5 window heights of it or behind it)."""
    clean, summary = campaigns["clean"]
    h = SCENE.passes[-1][1]
    for run in ("method_II", "uncorrected"):
        ds = xr.open_dataset(clean.out_dir / f"statistics_{run}.nc", engine="h5netcdf")
        rows = np.flatnonzero(ds["screened_count"].values.sum(axis=1))
        dist = clean.analyses[run].profile["dist_px"]
        assert np.all(dist[rows] < 2.5 * h), (run, dist[rows])
        assert summary["runs"][run]["screen"]["share"] < 2e-4


def test_switching_the_screen_off_sums_again_from_the_fields(campaigns):
    """The screen is not in the fields' fingerprint: turned off after the run, the statistics
    are summed again from the field files (no PIV) and equal a fresh run without it."""
    sw, summary = campaigns["switched_off"]
    fresh, _ = campaigns["unscreened"]
    assert summary["rereduced"]["pairs"] == SCENE.pairs
    for run, acc in sw.accumulators.items():
        ref = fresh.accumulators[run]
        assert acc.screen is None
        np.testing.assert_array_equal(acc.count, ref.count)
        for name in ("mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv"):
            a, b = getattr(acc, name), getattr(ref, name)
            scale = np.nanmax(np.abs(b))
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * scale, err_msg=name)


def test_a_removed_bounds_file_is_prepared_again_to_the_same_bounds(campaigns):
    """A bounds file deleted from the output folder: the context is prepared again (the pilot's
    PIV deterministic, the same digests), and the run resumes from its checkpoint."""
    clean, _ = campaigns["clean"]
    path = clean.out_dir / "screen_method_II.npz"
    digest = ScreenBounds.load(path).digest()
    path.unlink()
    toml = clean.out_dir.parent / "clean.toml"
    res = Campaign.load(toml, progress=False).run()
    assert path.is_file() and ScreenBounds.load(path).digest() == digest
    assert res.n_resumed == SCENE.pairs and res.context.fingerprint() == clean.context.fingerprint()
