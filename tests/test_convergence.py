"""How a run's profile converges with its pairs, and whether its first pairs and its last agree
(rspiv.convergence, the history of rspiv.row_errors.RowErrors).

Ground truth: fields drawn from known distributions (independent rows, so that the rows' z
scores are independent standard normal deviates), the prefixes' statistics against those
computed directly from the first pairs, and runs whose turbulence or mean speed changes half
way through.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from rspiv import row_errors
from rspiv.convergence import DRIFT_SIGMAS, STATISTICS, pooled, run_convergence
from rspiv.errors import InvalidInputError
from rspiv.row_errors import RowErrors
from rspiv.stats import FieldAccumulator

ROWS, COLS = 300, 24


def _fields(rng, pairs, gain=1.0, shift=0.0, from_pair=None):
    """``pairs`` fields of ROWS x COLS: u = 5 + row / 100 + a fluctuation of rms 1, v of rms
    0.5 correlated with u at -0.5; from pair ``from_pair`` on, u's fluctuation times ``gain``
    and its mean plus ``shift``."""
    for k in range(pairs):
        a = rng.normal(size=(ROWS, COLS))
        b = rng.normal(size=(ROWS, COLS))
        later = from_pair is not None and k >= from_pair
        u = 5.0 + np.arange(ROWS)[:, None] / 100 + (gain if later else 1.0) * a
        v = 0.5 * (-0.5 * a + np.sqrt(0.75) * b)
        yield u + (shift if later else 0.0), v


def _errors(rows: RowErrors, k: float = 1.0) -> dict:
    """The rows' errors from pair to pair as rspiv.profiles.pair_errors gives them (independent
    pairs, unit ``k``)."""
    res = rows.result()
    out = {key: res[f"se_{key}"] * abs(k) ** (1 if key == "U" else 2) for key in STATISTICS}
    return {**out, "pairs": res["pairs"]}


def _direct(fields, n) -> dict:
    """The rows' pooled statistics of the first ``n`` fields, computed directly."""
    u = np.concatenate([f[0] for f in fields[:n]], axis=1)
    v = np.concatenate([f[1] for f in fields[:n]], axis=1)
    U, V = u.mean(1), v.mean(1)
    return {"U": U, "uu": (u * u).mean(1) - U * U, "vv": (v * v).mean(1) - V * V,
            "uv": (u * v).mean(1) - U * V}  # fmt: skip


def test_prefixes_are_the_statistics_of_the_first_pairs():
    """Pairs added out of order into two shards and merged: each prefix holds the pairs
    numbered below its edge, its statistics those of these pairs; through pickles and the
    NetCDF state alike. Sums written before the history give none and merge to none."""
    fields = list(_fields(np.random.default_rng(4), 60))
    order = np.random.default_rng(5).permutation(60)
    a, b = RowErrors(ROWS), RowErrors(ROWS)
    for k in order:
        (a if k % 3 else b).add(*fields[k], pair_id=int(k))
    whole = copy.deepcopy(a).merge(b)
    got = whole.prefixes()
    assert [n for n, _ in got] == [10, 20, 50, 60]
    for n, sums in got:
        p, d = pooled(sums), _direct(fields, n)
        for key in STATISTICS:
            np.testing.assert_allclose(p[key], d[key], rtol=1e-9, atol=1e-12)
    acc = FieldAccumulator((ROWS, COLS))
    acc.rows = whole
    for k, (u, v) in enumerate(fields):
        acc.add(u, v, pair_id=k)
    back = FieldAccumulator.from_xarray(acc.to_xarray())
    np.testing.assert_array_equal(back.rows.history, whole.history)
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(whole)).history, whole.history)
    old = copy.deepcopy(b)
    del old.__dict__["history"]  # pickled before the history
    old = pickle.loads(pickle.dumps(old))
    assert old.history is None and old.prefixes() == []
    assert run_convergence(old, _errors(old), np.ones(ROWS, bool)) is None
    assert copy.deepcopy(a).merge(old).history is None
    with pytest.raises(InvalidInputError, match="rows judged"):
        run_convergence(whole, _errors(whole), np.ones(ROWS - 1, bool))


def test_ids_far_apart_fall_in_their_bands():
    """Pair ids beyond the first edges (a long campaign's shard): each band by its id."""
    rows = RowErrors(ROWS)
    fields = list(_fields(np.random.default_rng(9), 4))
    for pid, f in zip((3, 150, 4999, 70000), fields, strict=True):
        rows.add(*f, pair_id=pid)
    assert [n for n, _ in rows.prefixes()] == [1, 2, 3, 4]
    assert row_errors.HISTORY_EDGES[:6] == (10, 20, 50, 100, 200, 500)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_run_of_one_flow_converges_within_its_band_and_is_not_said_to_drift(seed):
    """200 pairs of one flow: each prefix's departure from the whole run over its band, and
    the two parts' difference over its error (z), spread by 1 over the rows; no warning."""
    rows = RowErrors(ROWS)
    for k, f in enumerate(_fields(np.random.default_rng(seed), 200)):
        rows.add(*f, pair_id=k)
    cv = run_convergence(rows, _errors(rows, 2.0), np.ones(ROWS, bool), k=2.0, sign_u=-1.0)
    assert list(cv.pairs) == [10, 20, 50, 100, 200] and cv.split == (100, 100)
    assert cv.warning is None and cv.drifting == []
    for key in STATISTICS:
        dep = (cv.values[key][:-1] - cv.values[key][-1]) / cv.band[key][:-1]
        assert 0.8 < np.std(dep) < 1.2, (key, np.std(dep))
        assert 0.85 < np.std(cv.z[key]) < 1.15, (key, np.std(cv.z[key]))
        assert np.mean(np.abs(cv.z[key]) > DRIFT_SIGMAS) < 0.01
    # the unit and the flip: U of the profile is -2 times the px mean, uu 4 times
    np.testing.assert_allclose(cv.values["U"][-1], -2.0 * pooled(rows.prefixes()[-1][1])["U"])
    np.testing.assert_allclose(cv.values["uu"][-1], 4.0 * pooled(rows.prefixes()[-1][1])["uu"])
    s = cv.summary()
    assert s["split_pairs"] == [100, 100] and s["rows_judged"] == ROWS and "warning" not in s
    for key in STATISTICS:  # the median |z| of a standard normal deviate: 0.674
        assert 0.55 < s[f"median_z_{key}"] < 0.8 and s[f"beyond_{key}"] < 0.01


def test_turbulence_that_changes_half_way_is_said():
    """u's fluctuation 15 % stronger from pair 100 of 200 on (uu +32 %, about 7 standard
    errors of the parts' difference): said for uu, with the change; the mean speed, which did
    not change, is not."""
    rows = RowErrors(ROWS)
    for k, f in enumerate(_fields(np.random.default_rng(17), 200, gain=1.15, from_pair=100)):
        rows.add(*f, pair_id=k)
    cv = run_convergence(rows, _errors(rows), np.ones(ROWS, bool))
    assert "uu" in cv.drifting and "U" not in cv.drifting
    assert abs(np.median(cv.change["uu"]) - 0.3225 / 1.16125) < 0.03
    assert "first 100 pairs and of the last 100 differ" in cv.warning and "uu by" in cv.warning
    assert cv.summary()["warning"] == cv.warning


def test_a_mean_speed_that_changes_is_said_and_too_few_rows_are_not_judged():
    """The mean speed 0.3 px higher from pair 60 of 120 on (the parts split at pair 50: their
    means differ by 0.26 px, about 5.5 standard errors): said for U alone; with too few rows
    judged, nothing said."""
    rows = RowErrors(ROWS)
    for k, f in enumerate(_fields(np.random.default_rng(23), 120, shift=0.3, from_pair=60)):
        rows.add(*f, pair_id=k)
    cv = run_convergence(rows, _errors(rows), np.ones(ROWS, bool))
    assert cv.split == (50, 70) and cv.drifting == ["U"]
    few = np.zeros(ROWS, bool)
    few[:2] = True
    assert run_convergence(rows, _errors(rows), few).warning is None
