"""Streamwise spectra and two-point correlations (rspiv.two_point) against direct sums and
against random fields of known correlation and spectrum."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.two_point import TwoPointAccumulator, integral_length


def _fields(rng, pairs, shape, gap=0.03):
    for p in range(pairs):
        u = rng.standard_normal(shape) + np.linspace(0.0, 3.0, shape[1]) + 5.0
        v = 0.5 * u + rng.standard_normal(shape)
        valid = rng.random(shape) > gap
        yield p, u, v, valid


def _lagged(a, b, d):
    """sum over fields and x of a'(x) b'(x + d), each about its vectors' means over the fields
    (fields along the first axis)."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    n = a.shape[1]
    return (a[:, : n - d] * b[:, d:]).sum() if d >= 0 else (a[:, -d:] * b[:, : n + d]).sum()


def _direct(us, vs, d):
    """The lagged sums uu and uv of one row's fields."""
    return _lagged(us, us, d), _lagged(us, vs, d)


def test_sums_equal_the_direct_estimates_with_rows_left_out():
    rng = np.random.default_rng(1)
    shape, cols = (5, 40), (3, 37)
    acc = TwoPointAccumulator(shape, columns=cols, min_valid=0.95)
    kept, us, vs = [], [], []
    for p, u, v, valid in _fields(rng, 40, shape):
        if p == 7:
            u[2, 10] = np.nan  # a NaN leaves its row out of this field
        n_rows = acc.add(u, v, valid, pair_id=p)
        c = slice(*cols)
        rows = np.isfinite(u[:, c]).all(axis=1) & (valid[:, c].mean(axis=1) >= 0.95)
        assert n_rows == rows.sum()
        kept.append(rows)
        us.append(u[:, c])
        vs.append(v[:, c])
    kept, us, vs = np.array(kept), np.array(us), np.array(vs)
    assert 0 < kept.sum() < kept.size  # some rows of some fields were left out
    cr = acc.correlation()
    sp = acc.spectra(dx=2.0)
    n = cols[1] - cols[0]
    w = np.hanning(n + 2)[1:-1]
    for y in range(shape[0]):
        ru, rv = us[kept[:, y], y], vs[kept[:, y], y]
        m = len(ru)
        assert acc.count[y] == m
        var_u = ((ru - ru.mean(0)) ** 2).sum() / (n * (m - 1))
        var_v = ((rv - rv.mean(0)) ** 2).sum() / (n * (m - 1))
        for i, d in enumerate(cr["lag"]):
            cu, cuv = _direct(ru, rv, int(d))
            norm = (n - abs(d)) * (m - 1)
            assert cr["R_uu"][y, i] == pytest.approx(cu / norm / var_u, abs=1e-10)
            assert cr["R_uv"][y, i] == pytest.approx(cuv / norm / np.sqrt(var_u * var_v), abs=1e-10)
        assert cr["var_u"][y] == pytest.approx(var_u, rel=1e-10)
        # the Hann-windowed periodogram of the fluctuations, one-sided
        b = np.fft.rfft((ru - ru.mean(0)) * w, axis=-1)
        phi = (np.abs(b) ** 2).sum(0) / (m - 1) * 2 * 2.0 / (2 * np.pi * (w**2).sum())
        np.testing.assert_allclose(sp["phi_uu"][y], phi, rtol=1e-9, atol=1e-12)


def test_maps_equal_the_direct_estimates_over_the_fields_holding_the_band():
    rng = np.random.default_rng(4)
    shape, band, refs = (7, 30), (1, 6), (2, 4)
    acc = TwoPointAccumulator(shape, min_valid=0.95, band=band, refs=refs)
    us, vs = [], []
    for p, u, v, valid in _fields(rng, 30, shape, gap=0.0):
        if p % 4 == 1:
            valid[3, :5] = False  # a band row left out: the field stays out of the maps
        if p % 4 == 2:
            valid[0, :5] = False  # a row outside the band: the field enters the maps
        acc.add(u, v, valid, pair_id=p)
        if p % 4 != 1:
            us.append(u)
            vs.append(v)
    us, vs = np.array(us), np.array(vs)
    mp = acc.maps(max_lag=9)
    assert mp["count"] == len(us) == acc.map_count
    n = shape[1]
    m = len(us)
    for comp, arr in (("R_uu", us), ("R_vv", vs)):
        var = ((arr - arr.mean(0)) ** 2).sum(axis=(0, 2)) / (n * (m - 1))
        for i, r in enumerate(refs):
            for j, y in enumerate(range(*band)):
                for li, d in enumerate(mp["lag"]):
                    c = _lagged(arr[:, r], arr[:, y], int(d))
                    want = c / ((n - abs(d)) * (m - 1)) / np.sqrt(var[r] * var[y])
                    assert mp[comp][i, j, li] == pytest.approx(want, abs=1e-10)
    # a map's reference row against itself is the row's own correlation
    np.testing.assert_allclose(mp["R_uu"][0, refs[0] - band[0], mp["lag"].size // 2], 1.0)
    with pytest.raises(InvalidInputError, match="in the band"):
        TwoPointAccumulator(shape, band=band, refs=(6,))
    with pytest.raises(InvalidInputError, match="without a band"):
        TwoPointAccumulator(shape).maps()


def test_merged_parts_and_a_saved_state_equal_one_pass():
    import xarray as xr

    rng = np.random.default_rng(2)
    fields = list(_fields(rng, 12, (4, 24)))
    kw = {"min_valid": 0.9, "band": (1, 4), "refs": (2,)}
    one = TwoPointAccumulator((4, 24), **kw)
    parts = [TwoPointAccumulator((4, 24), **kw) for _ in range(3)]
    for p, u, v, valid in fields:
        one.add(u, v, valid, pair_id=p)
        parts[p % 3].add(u, v, valid, pair_id=p)
    variables, attrs = parts[2].to_dataset_vars()
    parts[2] = TwoPointAccumulator.from_dataset_vars(
        xr.Dataset(variables, attrs=attrs), parts[2].pair_ids
    )
    merged = parts[0].merge(parts[1]).merge(parts[2])
    assert merged.pair_ids == one.pair_ids and merged.n_fields == 12
    a, b = merged.correlation(), one.correlation()
    for k in ("R_uu", "R_vv", "R_uv", "var_u"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(merged.spectra()["phi_uv"], one.spectra()["phi_uv"], atol=1e-12)
    np.testing.assert_allclose(merged.maps()["R_vv"], one.maps()["R_vv"], rtol=1e-10, atol=1e-12)
    with pytest.raises(InvalidInputError, match="pair id"):
        merged.merge(one)
    with pytest.raises(InvalidInputError, match="differ"):
        merged.merge(TwoPointAccumulator((4, 24), columns=(1, 20)))


def test_known_correlation_and_spectrum():
    """A Gaussian random field with rho(dx, dy) = exp(-(dx^2 + dy^2) / L^2) (white noise
    filtered by a Gaussian of standard deviation L / 2 on a periodic plane four times the
    field): R along the rows, the maps about a reference row and the one-sided spectrum sigma^2
    L / sqrt(pi) exp(-k^2 L^2 / 4) within the sampling error."""
    rng = np.random.default_rng(3)
    big, n, rows, pairs, length = 1024, 256, 16, 200, 6.0
    x = np.arange(big)
    x = np.minimum(x, big - x)
    y = np.arange(4 * rows)
    y = np.minimum(y, 4 * rows - y)
    r2 = x[None, :] ** 2 + y[:, None] ** 2
    kernel_ft = np.fft.rfft2(np.exp(-r2 / (2 * (length / 2) ** 2)))
    acc = TwoPointAccumulator((rows, n), band=(0, rows), refs=(8,))
    sigma = 0.7
    for p in range(pairs):
        white = rng.standard_normal((2, 4 * rows, big))
        g = np.fft.irfft2(np.fft.rfft2(white) * kernel_ft, s=(4 * rows, big))
        g *= sigma / np.sqrt(np.sum(np.exp(-r2 / (length / 2) ** 2)))
        u = 3.0 + g[0, :rows, :n]
        v = -1.0 + g[1, :rows, :n]
        acc.add(u, v, pair_id=p)
    cr = acc.correlation(max_lag=24)
    exact = np.exp(-(cr["lag"] ** 2) / length**2)
    # Bartlett: the standard error of a lag's estimate is sqrt(sum rho^2 / samples), 0.012
    # per row (0.006 over the 4 rows) here
    for q in ("R_uu", "R_vv"):
        assert np.max(np.abs(cr[q] - exact)) < 0.06
        assert np.max(np.abs(cr[q].mean(axis=0) - exact)) < 0.03
    assert np.max(np.abs(cr["R_uv"].mean(axis=0))) < 0.03  # u and v independent
    np.testing.assert_allclose(cr["var_u"], sigma**2, rtol=0.04)
    sp = acc.spectra(dx=1.0)
    k = sp["k"]
    phi = sigma**2 * length / np.sqrt(np.pi) * np.exp(-(k**2) * length**2 / 4)
    big_enough = phi > 0.05 * phi.max()
    ratio = sp["phi_uu"].mean(axis=0)[big_enough] / phi[big_enough]
    assert np.all(np.abs(ratio - 1) < 0.12), ratio
    # the spectrum integrates to the variance (one-sided, up to Nyquist)
    assert np.trapezoid(sp["phi_uu"], k, axis=1) == pytest.approx(cr["var_u"], rel=0.05)
    lengths = integral_length(cr["lag"], cr["R_uu"])
    assert np.all(np.abs(lengths / (length * np.sqrt(np.pi) / 2) - 1) < 0.08), lengths
    mp = acc.maps(max_lag=24)
    dy = mp["rows"] - 8
    exact2 = np.exp(-(mp["lag"][None, :] ** 2 + dy[:, None] ** 2) / length**2)
    for q in ("R_uu", "R_vv"):
        assert np.max(np.abs(mp[q][0] - exact2)) < 0.06


def test_integral_length_of_a_triangle_and_unresolved_rows():
    lag = np.arange(-10, 11)
    tri = np.clip(1 - np.abs(lag) / 4.0, -0.2, None)
    wide = np.exp(-(lag**2) / 1e4)  # never crosses zero within the lags
    out = integral_length(lag * 2.0, np.array([tri, wide, np.full(lag.size, np.nan)]))
    assert out[0] == pytest.approx(4.0)  # a / 2 with a = 4 steps of 2
    assert np.isnan(out[1]) and np.isnan(out[2])


def test_bad_input_is_refused():
    with pytest.raises(InvalidInputError, match="8 of the"):
        TwoPointAccumulator((3, 6))
    with pytest.raises(InvalidInputError, match="min_valid"):
        TwoPointAccumulator((3, 16), min_valid=0)
    with pytest.raises(InvalidInputError, match="rows, columns"):
        TwoPointAccumulator((16,))
    acc = TwoPointAccumulator((3, 16))
    with pytest.raises(InvalidInputError, match="u: expected shape"):
        acc.add(np.zeros((3, 15)), np.zeros((3, 16)))
    with pytest.raises(InvalidInputError, match="valid: expected shape"):
        acc.add(np.zeros((3, 16)), np.zeros((3, 16)), np.ones((2, 16), bool))
    acc.add(np.zeros((3, 16)), np.zeros((3, 16)), pair_id=1)
    with pytest.raises(InvalidInputError, match="already added"):
        acc.add(np.zeros((3, 16)), np.zeros((3, 16)), pair_id=1)
    # one field: no fluctuation is defined yet
    assert np.all(np.isnan(acc.correlation()["R_uu"]))


def _old_state(acc):
    """``acc`` as an rspiv before :func:`pad_length` made it: the correlations' transforms
    padded to exactly twice the row."""
    n = acc.n_columns + 1
    for k in ("sum_a", "pow_a", "cross_a", "map_sum", "map_pow", "map_cross"):
        old = getattr(acc, k)
        setattr(acc, k, np.zeros((*old.shape[:-1], n), old.dtype))
    return acc


def test_padding_to_a_fast_length_gives_the_same_correlations():
    """A row of 277 vectors is padded to 576 (5-smooth), not 554 = 2 x 277: the same linear
    correlations and maps as the exact doubling of earlier versions, whose states still read,
    add and save as they were (and do not merge with the new)."""
    import xarray as xr
    from rspiv.two_point import pad_length

    assert pad_length(277) == 576 and pad_length(554) == 1152 and pad_length(24) == 48
    for n in range(8, 700):
        p = pad_length(n)
        assert p >= 2 * n and p % 2 == 0 and p <= 2 * n * 1.25
    rng = np.random.default_rng(5)
    shape = (5, 277)
    kw = {"min_valid": 0.9, "band": (1, 5), "refs": (2, 3)}
    new = TwoPointAccumulator(shape, **kw)
    old = _old_state(TwoPointAccumulator(shape, **kw))
    assert new.n_pad == 576 and old.n_pad == 554
    fields = list(_fields(rng, 10, shape, gap=0.01))
    for p, u, v, valid in fields[:6]:
        new.add(u, v, valid, pair_id=p)
        old.add(u, v, valid, pair_id=p)
    # the old state saved and read back stays padded as it was, and takes more fields
    variables, attrs = old.to_dataset_vars()
    old = TwoPointAccumulator.from_dataset_vars(xr.Dataset(variables, attrs=attrs), old.pair_ids)
    assert old.n_pad == 554
    for p, u, v, valid in fields[6:]:
        new.add(u, v, valid, pair_id=p)
        old.add(u, v, valid, pair_id=p)
    a, b = new.correlation(), old.correlation()
    assert new.count.min() >= 2
    for k in ("R_uu", "R_vv", "R_uv", "var_u", "cov_uv"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(new.maps()["R_uu"], old.maps()["R_uu"], rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(new.spectra()["phi_uu"], old.spectra()["phi_uu"])
    # against the direct sums, row 1, lags 0 and 5
    us = np.stack([u[1] for _, u, _, _ in fields])
    vs = np.stack([v[1] for _, _, v, _ in fields])
    for d in (0, 5, -7):
        uu, _ = _direct(us, vs, d)
        m = int(np.flatnonzero(a["lag"] == d)[0])
        got = a["R_uu"][1, m] * a["var_u"][1] * (len(fields) - 1) * (277 - abs(d))
        assert got == pytest.approx(uu, rel=1e-9)
    with pytest.raises(InvalidInputError, match="padded length"):
        new.merge(old)
