"""The serial correlation of a run's pairs, taken from the rows' own means
(rspiv.row_errors.RowErrors.serial, rspiv.profiles.pair_errors, rspiv.convergence).

Ground truth: rows whose mean follows a first-order autoregressive process from pair to pair
(a time-resolved recording's slow scales) under independent noise per vector (the small scales
and the measurement noise), whose mean's variance over the run is known exactly:
``Var = (1/N^2) sum_{p,q} C(|p - q|)``; independent pairs beside them.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from rspiv import row_errors
from rspiv.convergence import run_convergence
from rspiv.errors import InvalidInputError
from rspiv.profiles import pair_errors
from rspiv.row_errors import RowErrors, serial_factor
from rspiv.stats import FieldAccumulator

ROWS, COLS = 200, 8
#: the rows' slow part: variance and correlation from one pair to the next
SLOW_VAR, PHI = 0.09, 0.8
#: the per-vector noise's variance
NOISE_VAR = 0.25


def _fields(seed: int, pairs: int, phi: float = PHI):
    """``pairs`` fields of ROWS x COLS: u = 5 + the row's slow part (AR(1) in the pair, its
    own per row) + noise per vector; v = noise only (independent pairs)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, np.sqrt(SLOW_VAR), ROWS)
    for _ in range(pairs):
        u = 5.0 + a[:, None] + rng.normal(0.0, np.sqrt(NOISE_VAR), (ROWS, COLS))
        v = 0.5 + rng.normal(0.0, np.sqrt(NOISE_VAR), (ROWS, COLS))
        yield u, v
        a = phi * a + np.sqrt(1 - phi * phi) * rng.normal(0.0, np.sqrt(SLOW_VAR), ROWS)


def _exact_var_of_mean(pairs: int, phi: float = PHI) -> float:
    """The variance of a row's mean of u over ``pairs`` pairs of :func:`_fields`."""
    lag = np.arange(pairs)
    c = SLOW_VAR * phi**lag
    c[0] += NOISE_VAR / COLS
    return float((pairs * c[0] + 2 * np.sum((pairs - lag[1:]) * c[1:])) / pairs**2)


def _accumulated(seed: int, pairs: int, phi: float = PHI, order=None):
    """A FieldAccumulator of :func:`_fields` carrying its RowErrors (pairs added in
    ``order``, default by id)."""
    fields = list(_fields(seed, pairs, phi))
    acc = FieldAccumulator((ROWS, COLS))
    acc.rows = RowErrors(ROWS)
    for k in range(pairs) if order is None else order:
        acc.add(*fields[k], pair_id=k)
        acc.rows.add(*fields[k], pair_id=k)
    return acc


def test_the_errors_of_correlated_pairs_are_the_exact_ones():
    """1000 pairs, the rows' slow part correlated at 0.8 from pair to pair: the error of a
    row's U is 2.6 times that of independent pairs. The rows' own factor finds it (median
    within 10 % of the exact variance), and the rows' z scores against the true mean spread by
    1 with it, by 2.6 without it; the per-vector lag-1 n_eff (noise-dominated vectors) alone
    would leave them at 2. v, independent from pair to pair, keeps a factor near 1."""
    acc = _accumulated(31, 1000)
    res = acc.rows.result()
    exact = _exact_var_of_mean(1000)
    factor = exact / np.median(res["se_U"]) ** 2
    assert 6.5 < factor < 7.5  # the model's own factor on the variance: 6.94
    assert abs(np.median(res["serial_U"]) / factor - 1) < 0.1
    assert np.median(res["serial_V"]) < 1.1 and np.mean(res["open_U"]) < 0.05
    pe = pair_errors(acc)
    z_serial = (res["U"] - 5.0) / pe["U"]
    z_indep = (res["U"] - 5.0) / res["se_U"]
    z_vector = (res["U"] - 5.0) / (res["se_U"] / np.sqrt(acc.n_eff("u").sum(1) / acc.count.sum(1)))
    assert 0.85 < np.std(z_serial) < 1.15, np.std(z_serial)
    assert np.std(z_indep) > 2.2 and np.std(z_vector) > 1.8
    np.testing.assert_allclose(pe["serial_U"], 1 / res["serial_U"], rtol=1e-12)
    assert not pe["open_U"].any() or np.mean(pe["open_U"]) < 0.05
    # the stresses' factors: u's slow part also moves uu about (its square), v's nothing
    assert np.median(res["serial_uu"]) > 1.5 and np.median(res["serial_vv"]) < 1.1
    # the run's first 500 pairs against the rest, with the correlation within the parts: of
    # one flow (the median |z| of a normal deviate, 0.674), nothing said
    cv = run_convergence(acc.rows, pe, np.ones(ROWS, bool))
    assert cv.drifting == [] and cv.warning is None and cv.serial_warning is None
    assert 0.55 < cv.summary()["median_z_U"] < 0.8 and cv.serial_open < 0.05


def test_independent_pairs_keep_a_factor_near_one():
    """200 independent pairs (the slow part drawn afresh each pair): the factors stay within
    the estimate's conservative bias (median under 1.1, never below 1), nothing is open, and
    the run's convergence says nothing of them."""
    acc = _accumulated(5, 200, phi=0.0)
    res = acc.rows.result()
    for key in ("U", "V", "uu", "vv", "uv"):
        f = res[f"serial_{key}"]
        assert np.all(f >= 1.0) and np.median(f) < 1.1 and np.quantile(f, 0.9) < 1.25, key
        assert np.mean(res[f"open_{key}"]) < 0.02, key
    pe = pair_errors(acc)
    cv = run_convergence(acc.rows, pe, np.ones(ROWS, bool))
    assert cv.serial_warning is None and cv.serial < 1.1 and cv.serial_open < 0.02
    assert "serial_warning" not in cv.summary() and cv.summary()["serial_factor_U"] < 1.1


def test_a_run_too_short_for_its_correlation_is_said():
    """40 pairs whose rows' slow part is correlated at 0.95 from pair to pair (a variance
    factor of 17 on U over 40 pairs): the ten lags a run of 40 allows cannot show where the
    correlation ends (the estimate, 4, is low: over 40 pairs the slow part hardly moves, and
    its mean is taken out with the run's); half the rows say their factor is a lower bound and
    the run says so,
    in its summary too. Independent pairs of the same length say nothing."""
    assert 16 < _exact_var_of_mean(40, 0.95) / (SLOW_VAR + NOISE_VAR / COLS) * 40 < 18
    acc = _accumulated(11, 40, phi=0.95)
    res = acc.rows.result()
    assert np.all(res["lag_max"] == 10)
    assert np.mean(res["open_U"]) > 0.45
    cv = run_convergence(acc.rows, pair_errors(acc), np.ones(ROWS, bool))
    assert cv.serial_open > 0.45 and "lower bounds" in cv.serial_warning
    assert "longer recording" in cv.serial_warning
    assert "40 of them" in cv.serial_warning
    assert cv.summary()["serial_warning"] == cv.serial_warning
    acc = _accumulated(11, 40, phi=0.0)
    cv = run_convergence(acc.rows, pair_errors(acc), np.ones(ROWS, bool))
    assert cv.serial_warning is None and cv.serial_open < 0.1


def test_a_long_run_whose_correlation_outlasts_the_lags_is_told_to_space_its_pairs():
    """2000 pairs correlated at 0.9 (a variance factor of 14, an integrated correlation time
    of 7 pairs: five of them are 35 lags, 32 are kept): most rows are open, and the run is told
    to space its pairs further apart (pair_step), not to record longer; its two halves agree.
    At 0.95 (five correlation times 70 lags) the correlation within the halves is not known
    either, the halves are held against the per-vector lag-1 errors, and the run is said to
    change, with its errors lower bounds."""
    acc = _accumulated(4, 2000, phi=0.9)
    res = acc.rows.result()
    assert np.all(res["lag_max"] == row_errors.LAGS) and np.mean(res["open_U"]) > 0.6
    cv = run_convergence(acc.rows, pair_errors(acc), np.ones(ROWS, bool))
    assert cv.drifting == [] and cv.serial_open > 0.6
    assert "pair_step" in cv.serial_warning and "longer recording" not in cv.serial_warning
    acc = _accumulated(3, 1000, phi=0.95)
    cv = run_convergence(acc.rows, pair_errors(acc), np.ones(ROWS, bool))
    assert cv.drifting == ["U"] and cv.serial_warning is None
    assert cv.warning.endswith("so the errors are lower bounds")


def test_the_lags_do_not_depend_on_the_order_and_merge_with_their_shifts():
    """The lag products are the same whichever order the pairs came in (each product with the
    earlier pair's sums on the left); two parts merged (different shifts) hold each part's
    own products, as one accumulator whose chain was broken between them; NetCDF and pickle
    keep them; a state from before them gives no factor and the per-vector n_eff alone."""
    fwd = _accumulated(7, 60)
    rev = _accumulated(7, 60, order=range(59, -1, -1))  # other shifts: the results compare
    for key in ("serial_U", "serial_V", "serial_uu", "serial_vv", "serial_uv"):
        np.testing.assert_allclose(rev.rows.result()[key], fwd.rows.result()[key], rtol=1e-9)
    fields = list(_fields(7, 60))
    a, b, broken = RowErrors(ROWS), RowErrors(ROWS), RowErrors(ROWS)
    for k, f in enumerate(fields):
        (a if k < 25 else b).add(*[x + (3.0 if k >= 25 else 0.0) for x in f], pair_id=k)
        if k == 25:
            broken.recent = []
        broken.add(*[x + (3.0 if k >= 25 else 0.0) for x in f], pair_id=k)
    merged = copy.deepcopy(a).merge(b)
    np.testing.assert_allclose(merged.lags, broken.lags, rtol=1e-9, atol=1e-8)
    assert merged.recent == []
    for key in ("serial_U", "serial_uu", "open_U"):
        np.testing.assert_allclose(merged.result()[key], broken.result()[key], rtol=1e-9)
    back = FieldAccumulator.from_xarray(fwd.to_xarray())
    np.testing.assert_array_equal(back.rows.lags, fwd.rows.lags)
    assert back.rows.recent == []  # the chain is not written: it starts anew on resume
    again = pickle.loads(pickle.dumps(fwd.rows))
    assert len(again.recent) == len(fwd.rows.recent)
    np.testing.assert_array_equal(again.result()["serial_U"], fwd.rows.result()["serial_U"])
    old = copy.deepcopy(fwd)
    del old.rows.__dict__["lags"], old.rows.__dict__["recent"]  # pickled before the lags
    old.rows = pickle.loads(pickle.dumps(old.rows))
    assert old.rows.lags is None and old.rows.serial() is None
    with pytest.raises(InvalidInputError, match="no serial factor of 'S_u'"):
        fwd.rows.serial("S_u")
    factor, still = fwd.rows.serial("uu")
    np.testing.assert_array_equal(factor, fwd.rows.result()["serial_uu"])
    assert "serial_U" not in old.rows.result()
    pe = pair_errors(old)
    assert not pe["open_U"].any()
    np.testing.assert_allclose(
        pe["serial_U"], np.minimum(old.n_eff("u").sum(1) / old.count.sum(1), 1.0), rtol=1e-12
    )
    fresh = RowErrors(ROWS)
    fresh.lags = None  # a part summed before the lags
    assert copy.deepcopy(fwd.rows).merge(fresh).lags is None


def test_serial_factor_of_known_sequences():
    """Geyer's sequence by hand: an exponential autocovariance (its sum), one that turns
    negative at once (1), one cut short by the lags allowed (open)."""
    k = np.arange(1, row_errors.LAGS + 1)
    g = np.stack([0.5**k, -0.9 * np.ones_like(k, dtype=float), 0.99**k], axis=1)
    factor, still = serial_factor(np.ones(3), g, np.array([32, 32, 8]))
    assert abs(factor[0] - (1 + 2 * 1.0)) < 1e-6  # 1 + 2 sum 0.5^k
    assert factor[1] == 1.0 and not still[1]
    np.testing.assert_allclose(factor[2], -1 + 2 * np.sum(np.r_[1, 0.99 ** k[:7]]), rtol=1e-12)
    assert still[2] and not still[0]
