"""The standard errors of a profile's rows from the scatter between pairs (rspiv.row_errors,
rspiv.profiles.pair_errors).

Ground truth: fields drawn from known distributions, many rows at once: the errors are right
when the rows' estimates scatter about the true values by them (z-scores of spread 1).
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from rspiv import row_errors
from rspiv.errors import InvalidInputError
from rspiv.profiles import pair_errors
from rspiv.row_errors import RowErrors
from rspiv.stats import FieldAccumulator

ROWS, COLS = 300, 24


def _fields(rng, pairs, along=0.0):
    """``pairs`` fields of ROWS x COLS: u = 2 + row / 100 + a fluctuation of rms 1, v of rms
    0.5 correlated with u at -0.5; ``along``: the share of u's variance that is one offset per
    row and pair (fully correlated along the row)."""
    for _ in range(pairs):
        a = rng.normal(size=(ROWS, COLS))
        if along:
            a = np.sqrt(1 - along) * a + np.sqrt(along) * rng.normal(size=(ROWS, 1))
        b = rng.normal(size=(ROWS, COLS))
        u = 2.0 + np.arange(ROWS)[:, None] / 100 + a
        v = 0.5 * (-0.5 * a + np.sqrt(0.75) * b)
        yield u, v


TRUE = {"uu": 1.0, "vv": 0.25, "uv": -0.25}


def _whole_and_parts(seed: int, pairs: int, first: int):
    """``pairs`` fields (:func:`_fields`) summed whole, and in two parts: the first ``first``
    pairs and the rest."""
    fields = list(_fields(np.random.default_rng(seed), pairs))
    whole, a, b = RowErrors(ROWS), RowErrors(ROWS), RowErrors(ROWS)
    for k, (u, v) in enumerate(fields):
        whole.add(u, v, pair_id=k)
        (a if k < first else b).add(u, v, pair_id=k)
    return fields, whole, a, b


@pytest.mark.parametrize("along", [0.0, 0.8])
def test_the_errors_are_the_scatter_of_the_rows(along):
    """Independent vectors (the error of a row's mean sqrt(COLS) times smaller than a
    vector's) and vectors mostly correlated along the row: the z-scores of U, uu, vv, uv
    against the truth spread by 1 over the rows."""
    rng = np.random.default_rng(3)
    rows = RowErrors(ROWS)
    for k, (u, v) in enumerate(_fields(rng, 60, along)):
        rows.add(u, v, pair_id=k)
    r = rows.result()
    assert (r["pairs"] == 60).all()
    truth = {"U": 2.0 + np.arange(ROWS) / 100, "V": 0.0, **TRUE}
    for key, want in truth.items():
        # the rows' scatter about the truth against their typical error (not the mean of
        # each row's ratio: a variance's error grows with its estimate, which skews that)
        d, se = r[key] - want, np.median(r[f"se_{key}"])
        assert abs(np.mean(d)) < 0.25 * se and 0.85 < np.std(d) / se < 1.15, (key, np.std(d) / se)
    # the error of U: a vector's rms over sqrt(pairs x the independent vectors of a row)
    independent = COLS if not along else 1 / (along + (1 - along) / COLS)
    assert np.median(r["se_U"]) == pytest.approx(1 / np.sqrt(60 * independent), rel=0.1)


def test_the_skewness_and_flatness_errors_are_the_scatter_of_the_rows():
    """u skewed (a gamma fluctuation of shape 4: S 1, F 4.5) and v Gaussian (S 0, F 3), both
    far from zero against their spread (20 and -15 px per pair against rms 0.1: the sums are
    taken about each row's first mean, else the fourth powers lose the digits), and the parts
    of other shifts merged: the rows' S and F scatter about the truth by their errors."""
    rng = np.random.default_rng(11)
    parts = [RowErrors(ROWS) for _ in range(3)]
    for k in range(90):
        a = (rng.gamma(4.0, size=(ROWS, COLS)) - 4.0) / 2.0  # mean 0, rms 1, S 1, F 4.5
        u = 20.0 + 0.1 * a
        v = -15.0 + 0.1 * rng.normal(size=(ROWS, COLS))
        parts[k % 3].add(u, v, pair_id=k)
    assert not np.allclose(parts[0].shift, parts[1].shift)
    r = parts[0].merge(parts[1]).merge(parts[2]).result()
    truth = {"S_u": 1.0, "F_u": 4.5, "S_v": 0.0, "F_v": 3.0, "uu": 0.01, "vv": 0.01}
    for key, want in truth.items():
        # against the rows' rms error: the error of a higher moment follows each row's own
        # tail, which varies from row to row (u's heavy tail: 1.04-1.16 over three seeds, and
        # 0.99-1.10 with four times the pairs; v's 0.94-1.02)
        d, se = r[key] - want, np.sqrt(np.mean(r[f"se_{key}"] ** 2))
        top = 1.2 if key.endswith("_u") else 1.15
        assert abs(np.mean(d)) < 0.3 * se and 0.85 < np.std(d) / se < top, (key, np.std(d) / se)
    # S's error of Gaussian values: sqrt(6 / n) for n independent values
    assert np.median(r["se_S_v"]) == pytest.approx(np.sqrt(6 / (90 * COLS)), rel=0.1)


def test_sums_of_six_give_no_skewness_and_merge_as_six():
    """A state written before the third and fourth powers (six sums per pair and row, taken
    about zero): its U and stresses as before, no S or F; merged with a state of ten sums,
    the six."""
    _, whole, old, new = _whole_and_parts(12, 8, 4)
    # the old state as it was written: about zero, six sums
    zero = copy.deepcopy(old)
    t = row_errors._shift_transform(-zero.shift)
    zero.total = np.einsum("rij,rj->ri", t, zero.total)[:, :6]
    zero.outer = np.einsum("rij,rjk,rlk->ril", t, zero.outer, t)[:, :6, :6]
    zero.shift = np.zeros_like(zero.shift)
    zero.lags, zero.recent = None, []  # written before the lags too
    for key, val in old.result().items():
        if key.startswith(("serial_", "open_", "gamma_")) or key == "lag_max":
            continue
        if key[-2:] not in ("_u", "_v"):
            np.testing.assert_allclose(zero.result()[key], val, rtol=1e-8, atol=1e-12)
    assert "S_u" not in zero.result() and "se_F_v" not in zero.result()
    # pickled before the shifts (a checkpoint or a Dask chunk of that version): about zero
    del zero.__dict__["shift"]
    zero = pickle.loads(pickle.dumps(zero))
    assert np.all(zero.shift == 0) and zero.shift.shape == (ROWS, 2)
    merged = zero.merge(new)
    assert merged.total.shape == (ROWS, 6) and "S_u" not in merged.result()
    for key in ("U", "uu", "se_U", "se_uu", "se_uv"):
        np.testing.assert_allclose(merged.result()[key], whole.result()[key], rtol=1e-8)


def test_parts_merge_to_the_whole_and_round_trip():
    rng = np.random.default_rng(5)
    fields = list(_fields(rng, 12))
    whole, a, b = RowErrors(ROWS), RowErrors(ROWS), RowErrors(ROWS)
    for k, (u, v) in enumerate(fields):
        whole.add(u, v, pair_id=k)
        (a if k % 2 else b).add(u, v, pair_id=k)
    merged = copy.deepcopy(a).merge(b)
    for key, val in whole.result().items():
        if key.startswith(("serial_", "open_", "gamma_")):
            continue  # the parts' chains are not joined (tests/test_row_serial.py)
        np.testing.assert_allclose(merged.result()[key], val, rtol=1e-10)
    again = pickle.loads(pickle.dumps(whole))
    np.testing.assert_array_equal(again.result()["se_uu"], whole.result()["se_uu"])
    with pytest.raises(InvalidInputError, match="in both parts"):
        a.merge(whole)
    with pytest.raises(InvalidInputError, match="added before"):
        a.add(*fields[1], pair_id=1)
    with pytest.raises(InvalidInputError, match="rows"):
        a.add(fields[0][0][:5], fields[0][1][:5], pair_id=99)
    with pytest.raises(InvalidInputError, match="rows"):
        a.merge(RowErrors(ROWS - 1))


def test_a_field_accumulator_carries_them():
    """Attached to a FieldAccumulator: merged with it, through its NetCDF state, masked
    vectors left out; pair_errors scales them and gives none for sums of other pairs."""
    rng = np.random.default_rng(8)
    accs = [FieldAccumulator((ROWS, COLS)) for _ in range(2)]
    for acc in accs:
        acc.rows = RowErrors(ROWS)
    for k, (u, v) in enumerate(_fields(rng, 10)):
        valid = rng.uniform(size=u.shape) > 0.1
        u = np.where(valid, u, 1e6)  # invalid vectors never count, whatever they hold
        acc = accs[k % 2]
        acc.add(u, v, valid, pair_id=k)
        acc.rows.add(u, v, valid, pair_id=k)
    whole = FieldAccumulator.merged(accs)
    assert whole.rows.pair_ids == set(range(10)) and whole.rows.n_fields == 10
    back = FieldAccumulator.from_xarray(whole.to_xarray())
    np.testing.assert_array_equal(back.rows.outer, whole.rows.outer)
    pe = pair_errors(back, k=2.0)
    res = whole.rows.result()
    assert np.all(res["U"] < 10)  # the 1e6 of the invalid vectors left out
    # independent pairs (n_eff <= n): at least the clusters' errors, scaled by k and k^2
    assert np.all(pe["U"] >= 2.0 * res["se_U"] * (1 - 1e-12))
    assert np.all(pe["uu"] >= 4.0 * res["se_uu"] * (1 - 1e-12))
    assert np.median(pe["U"] / (2.0 * res["se_U"])) < 1.3
    # sums of other pairs than the statistics' (a state from before they existed): none
    back.rows = RowErrors(ROWS)
    assert pair_errors(back) is None


def test_the_batches_give_the_delete_one_batch_means():
    """Each pair's row sums go to batch ``pair_id % BATCHES``: the replicates are the rows'
    means without one batch, exactly; they merge, round-trip and are none for sums written
    before the batches or with fewer than MIN_BATCHES batches of pairs."""
    fields, whole, a, b = _whole_and_parts(21, 40, 17)
    reps = whole.replicates()
    assert reps.shape == (row_errors.BATCHES, ROWS)
    for bt in (0, 7, 15):
        keep = [u for k, (u, _) in enumerate(fields) if k % row_errors.BATCHES != bt]
        np.testing.assert_allclose(reps[bt], np.mean(keep, axis=(0, 2)), rtol=1e-12)
    np.testing.assert_allclose(copy.deepcopy(a).merge(b).replicates(), reps, rtol=1e-12)
    acc = FieldAccumulator((ROWS, COLS))
    acc.rows = whole
    for k, (u, v) in enumerate(fields):
        acc.add(u, v, pair_id=k)
    back = FieldAccumulator.from_xarray(acc.to_xarray())
    np.testing.assert_array_equal(back.rows.replicates(), reps)
    few = RowErrors(ROWS)
    for k, (u, v) in enumerate(fields[: row_errors.MIN_BATCHES - 1]):
        few.add(u, v, pair_id=k)
    assert few.replicates() is None
    old = copy.deepcopy(b)
    del old.__dict__["batch"]  # pickled before the batches
    old = pickle.loads(pickle.dumps(old))
    assert old.batch is None and old.replicates() is None
    assert copy.deepcopy(a).merge(old).replicates() is None


def test_u_tau_error_from_the_pairs_is_the_spread_of_campaigns():
    """Ground truth for u_tau's error (rspiv.boundary_layer.u_tau_jackknife): 30 independent
    'campaigns' of 48 pairs of a composite profile (u_tau 0.4 m/s), each pair's rows moved
    together (a 1 % scale and a smooth bump over the log layer: the flow's large structures)
    and each vector by its own noise. The spread of the 30 campaigns' u_tau is their
    jackknife error (within 25 %: 0.89 of it); the fit's own error, the rows taken as
    independent, is several times smaller (5.3 times)."""
    from rspiv.boundary_layer import composite_fit, composite_u_plus, u_tau_jackknife

    nu, ut = 1.5e-5, 0.4
    y = np.geomspace(2e-4, 0.05, 120)  # m: y+ 5 to 1300
    base = ut * composite_u_plus(y * ut / nu, 0.04 * ut / nu, 0.5)
    rng = np.random.default_rng(31)
    fits, jack, own = [], [], []
    for _ in range(30):
        rows = RowErrors(y.size)
        for k in range(48):
            bump = np.exp(-0.5 * (np.log(y / rng.uniform(2e-3, 2e-2)) / 0.6) ** 2)
            u = base * (1 + 0.01 * rng.normal()) + 0.05 * rng.normal() * bump
            field = u[:, None] + 0.3 * rng.normal(size=(y.size, 16))
            rows.add(field, np.zeros_like(field), pair_id=k)
        mean = rows.result()["U"]
        fit = composite_fit(y, mean, nu)
        fits.append(fit.u_tau)
        own.append(fit.u_tau_std)
        jack.append(u_tau_jackknife(y, rows.replicates(), nu))
    spread = np.std(fits, ddof=1)
    assert abs(np.mean(fits) - ut) < 2 * spread / np.sqrt(30)
    with pytest.raises(InvalidInputError, match=r"replicates: expected \(batches, 120\)"):
        u_tau_jackknife(y, rows.replicates()[:, :-1], nu)
    assert np.isnan(u_tau_jackknife(y, rows.replicates()[:7], nu))  # too few to say
    assert 0.75 < spread / np.median(jack) < 1.25, (spread, np.median(jack))
    assert spread / np.median(own) > 3, (spread, np.median(own))
