"""FieldAccumulator: exact streaming/merged statistics against one-pass numpy over all samples."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.stats import FieldAccumulator

SHAPE = (6, 5)


def _campaign(rng, n=40, reject=0.2):
    """n fields of correlated (u, v) with a large mean, some vectors rejected (NaN at rejects)."""
    mean = np.array([9.6, 0.3])
    cov = np.array([[0.8, -0.25], [-0.25, 0.3]])
    L = np.linalg.cholesky(cov)
    z = rng.standard_normal((n, 2) + SHAPE)
    u = mean[0] + L[0, 0] * z[:, 0]
    v = mean[1] + L[1, 0] * z[:, 0] + L[1, 1] * z[:, 1]
    u *= 1.0 + 0.1 * np.arange(SHAPE[1])  # vary per vector
    valid = rng.random((n,) + SHAPE) > reject
    return u, v, valid


def _numpy_stats(u, v, valid):
    """Reference: masked two-pass numpy over all samples (ddof=1)."""
    n = valid.sum(axis=0)
    um = np.where(valid, u, 0).sum(0) / n
    vm = np.where(valid, v, 0).sum(0) / n
    du = np.where(valid, u - um, 0)
    dv = np.where(valid, v - vm, 0)
    return (
        n,
        um,
        vm,
        (du * du).sum(0) / (n - 1),
        (dv * dv).sum(0) / (n - 1),
        (du * dv).sum(0) / (n - 1),
    )


def _assert_matches(acc, ref):
    n, um, vm, uu, vv, uv = ref
    np.testing.assert_array_equal(acc.count, n)
    for got, want in ((acc.mean_u, um), (acc.mean_v, vm), (acc.uu, uu), (acc.vv, vv), (acc.uv, uv)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13)


def test_streaming_equals_numpy(rng):
    u, v, valid = _campaign(rng)
    acc = FieldAccumulator(SHAPE)
    for k in range(u.shape[0]):
        acc.add(u[k], v[k], valid[k], pair_id=k)
    _assert_matches(acc, _numpy_stats(u, v, valid))
    assert acc.pair_ids == set(range(u.shape[0])) and acc.n_fields == u.shape[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_merge_any_split_and_order_is_exact(seed):
    rng = np.random.default_rng(seed)
    u, v, valid = _campaign(rng, n=60)
    ref = _numpy_stats(u, v, valid)
    order = rng.permutation(u.shape[0])
    cuts = np.sort(rng.choice(np.arange(1, 60), size=4, replace=False))
    parts = []
    for chunk in np.split(order, cuts):
        a = FieldAccumulator(SHAPE)
        for k in chunk:
            a.add(u[k], v[k], valid[k], pair_id=int(k))
        parts.append(a)
    rng.shuffle(parts)
    # tree merge in a shuffled order, including an empty accumulator
    parts.append(FieldAccumulator(SHAPE))
    while len(parts) > 1:
        b = parts.pop()
        parts[rng.integers(len(parts))].merge(b)
    _assert_matches(parts[0], ref)
    assert parts[0].pair_ids == set(range(60))


def test_vector_with_no_or_one_sample():
    acc = FieldAccumulator((2,))
    acc.add([1.0, 2.0], [0.0, 0.0], [True, False])
    assert acc.count.tolist() == [1, 0]
    assert np.isnan(acc.uu).all()  # ddof=1 needs two samples
    acc.add([3.0, 5.0], [1.0, 1.0], [True, True])
    assert acc.count.tolist() == [2, 1]
    assert acc.uu[0] == pytest.approx(2.0) and acc.uv[0] == pytest.approx(1.0)
    assert acc.mean_u.tolist() == [2.0, 5.0]


def test_pickle_round_trip_and_merge_after(rng):
    u, v, valid = _campaign(rng, n=20)
    a = FieldAccumulator(SHAPE)
    for k in range(10):
        a.add(u[k], v[k], valid[k], pair_id=f"p{k}")
    b = pickle.loads(pickle.dumps(a))
    for name in ("count", "mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv", "lag_c_u"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert b.pair_ids == a.pair_ids
    for k in range(10, 20):
        b.add(u[k], v[k], valid[k], pair_id=f"p{k}")
    _assert_matches(b, _numpy_stats(u, v, valid))


def test_pair_id_overlap_refused(rng):
    u, v, valid = _campaign(rng, n=3)
    a, b = FieldAccumulator(SHAPE), FieldAccumulator(SHAPE)
    a.add(u[0], v[0], valid[0], pair_id=7)
    b.add(u[1], v[1], valid[1], pair_id=7)
    with pytest.raises(InvalidInputError, match="pair id"):
        a.merge(b)
    with pytest.raises(InvalidInputError, match="already added"):
        a.add(u[2], v[2], valid[2], pair_id=7)
    assert a.count.max() == 1  # the refused add changed nothing


def test_bad_input():
    acc = FieldAccumulator((3, 4))
    z = np.zeros((3, 4))
    with pytest.raises(InvalidInputError, match=r"u: expected shape \(3, 4\)"):
        acc.add(np.zeros((4, 3)), z)
    with pytest.raises(InvalidInputError, match="valid: expected shape"):
        acc.add(z, z, np.ones((3,), bool))
    with pytest.raises(InvalidInputError, match="shape"):
        acc.merge(FieldAccumulator((3, 5)))
    with pytest.raises(InvalidInputError):
        FieldAccumulator((0, 4))
    with pytest.raises(InvalidInputError, match="boolean"):
        acc.add(z, z, np.full((3, 4), 0.5))
    # NaN at a vector marked valid is an error; NaN at a rejected vector is ignored
    un = z.copy()
    un[1, 2] = np.nan
    with pytest.raises(InvalidInputError, match="1 vector"):
        acc.add(un, z, np.ones((3, 4), bool))
    assert acc.n_fields == 0 and acc.count.sum() == 0
    mask = np.ones((3, 4), bool)
    mask[1, 2] = False
    acc.add(un, z, mask)
    # valid=None: non-finite vectors are rejected
    acc.add(un + 1.0, z)
    assert acc.count[1, 2] == 0 and acc.count[0, 0] == 2
    assert np.all(np.isfinite(acc.mean_u))


def test_lag1_correlation_and_n_eff(rng):
    n, rho = 4000, 0.6
    shape = (2, 3)
    e = rng.standard_normal((n,) + shape)
    x = np.empty_like(e)
    x[0] = e[0]
    for k in range(1, n):  # AR(1) series per vector
        x[k] = rho * x[k - 1] + np.sqrt(1 - rho**2) * e[k]
    acc = FieldAccumulator(shape)
    for k in range(n):
        acc.add(x[k] + 5.0, e[k])
    np.testing.assert_allclose(acc.lag1_correlation("u"), rho, atol=0.05)
    np.testing.assert_allclose(acc.lag1_correlation("v"), 0.0, atol=0.06)
    np.testing.assert_allclose(acc.n_eff("u"), n * (1 - rho) / (1 + rho), rtol=0.15)
    np.testing.assert_allclose(acc.n_eff("uu"), n * (1 - rho**2) / (1 + rho**2), rtol=0.15)
    np.testing.assert_allclose(acc.n_eff("v"), n, rtol=0.15)
    assert set(acc.n_eff_all()) == {"U", "V", "uu", "vv", "uv"}
    with pytest.raises(InvalidInputError, match="quantity"):
        acc.n_eff("w")
    # merged lag statistics equal those of the union of within-shard pairs
    a, b = FieldAccumulator(shape), FieldAccumulator(shape)
    for k in range(n // 2):
        a.add(x[k], e[k])
    for k in range(n // 2, n):
        b.add(x[k], e[k])
    a.merge(b)
    pa = np.concatenate([x[: n // 2 - 1], x[n // 2 : n - 1]])
    pb = np.concatenate([x[1 : n // 2], x[n // 2 + 1 :]])
    cab = ((pa - pa.mean(0)) * (pb - pb.mean(0))).sum(0)
    np.testing.assert_allclose(a.lag_c_u, cab, rtol=1e-11)
    assert (a.lag_count_u == n - 2).all()


def test_xarray_round_trip(rng, tmp_path):
    u, v, valid = _campaign(rng, n=12)
    acc = FieldAccumulator(SHAPE)
    for k in range(12):
        acc.add(u[k], v[k], valid[k], pair_id=k)
    ds = acc.to_xarray(x=np.arange(SHAPE[1]) * 1e-3, y=np.arange(SHAPE[0]) * 1e-3)
    assert ds["u"].attrs["units"] == "m s-1" and ds["uu"].attrs["units"] == "m2 s-2"
    assert ds["u"].dims == ("y", "x")
    path = tmp_path / "acc.nc"
    ds.to_netcdf(path, engine="h5netcdf")
    import xarray as xr

    with xr.open_dataset(path, engine="h5netcdf") as back:
        acc2 = FieldAccumulator.from_xarray(back.load())
    _assert_matches(acc2, _numpy_stats(u, v, valid))
    assert acc2.pair_ids == set(range(12)) and acc2.n_fields == 12


def test_string_pair_ids_and_no_ids_survive_netcdf(rng, tmp_path):
    import xarray as xr
    from rspiv.outputs import write_netcdf

    for ids in (["run1/0001", "run1/0002"], [None, None]):
        acc = FieldAccumulator((2, 3))
        for i in ids:
            acc.add(rng.random((2, 3)), rng.random((2, 3)), pair_id=i)
        write_netcdf(acc.to_xarray(), tmp_path / "a.nc")
        with xr.open_dataset(tmp_path / "a.nc", engine="h5netcdf") as ds:
            back = FieldAccumulator.from_xarray(ds.load())
        assert back.pair_ids == {i for i in ids if i is not None} and back.n_fields == 2
        np.testing.assert_array_equal(back.c_uv, acc.c_uv)
