"""Per-vector vorticity statistics streamed over fields (rspiv.vorticity) against direct
statistics of the same fields, merged parts, and the state carried by a FieldAccumulator."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.derivatives import swirling_strength, vorticity
from rspiv.errors import InvalidInputError
from rspiv.vorticity import VorticityAccumulator


def _fields(rng, n, ny=12, nx=20):
    """Smooth random fields (a few Fourier modes) with some vectors rejected."""
    y, x = np.mgrid[0:ny, 0:nx] * 4.0
    out = []
    for _ in range(n):
        a = rng.normal(size=6)
        u = a[0] * np.sin(x / 9 + a[1]) + a[2] * np.cos(y / 7)
        v = a[3] * np.cos(x / 11 + a[4]) * np.sin(y / 5 + a[5])
        valid = rng.random((ny, nx)) > 0.03
        out.append((u, v, valid))
    return out


def test_streamed_statistics_equal_the_direct_ones():
    rng = np.random.default_rng(7)
    fields = _fields(rng, 15)
    acc = VorticityAccumulator((12, 20), 4.0, 4.0, "richardson")
    for k, (u, v, valid) in enumerate(fields):
        acc.add(u, v, valid, pair_id=k)
    # the direct statistics: rejected vectors NaN before the differences
    w = np.array([vorticity(np.where(ok, u, np.nan), np.where(ok, v, np.nan), 4, 4, "richardson")
                  for u, v, ok in fields])  # fmt: skip
    s = np.array([swirling_strength(np.where(ok, u, np.nan), np.where(ok, v, np.nan), 4, 4,
                                    "richardson", signed=True) for u, v, ok in fields])  # fmt: skip
    for name, x in (("omega", w), ("swirl", s)):
        n = np.isfinite(x).sum(axis=0)
        np.testing.assert_array_equal(getattr(acc, f"{name}_count"), n)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(n > 0, np.where(np.isfinite(x), x, 0).sum(0) / n, np.nan)
            var = np.where(np.isfinite(x), (x - mean) ** 2, 0).sum(0) / (n - 1)
        np.testing.assert_allclose(acc.mean(name), mean, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(acc.var(name)[n > 1], var[n > 1], rtol=1e-9, atol=1e-15)
    # rejected vectors leave holes the stencils go round: fewer samples next to them
    assert acc.omega_count.min() < 15 and acc.omega_count.max() == 15
    # the row profile: mean of the means and root of the mean variance, oriented
    usable = np.ones(acc.shape, bool)
    prof = acc.profile(usable, -1.0)
    ok = acc.omega_count > 1
    with np.errstate(invalid="ignore"):  # the edge rows: no vector with two samples
        want = -np.where(ok, acc.mean(), 0).sum(1) / ok.sum(1)
        rms = np.sqrt(np.where(ok, acc.var(), 0).sum(1) / ok.sum(1))
    np.testing.assert_allclose(prof["omega_mean"], want, rtol=1e-12)
    np.testing.assert_allclose(prof["omega_rms"], rms, rtol=1e-12)


def test_parts_merge_to_one_pass_and_travel_with_the_statistics(tmp_path):
    rng = np.random.default_rng(8)
    fields = _fields(rng, 10)
    one = VorticityAccumulator((12, 20), 4.0, 4.0)
    parts = [VorticityAccumulator((12, 20), 4.0, 4.0) for _ in range(3)]
    stats = [rspiv.FieldAccumulator((12, 20)) for _ in range(3)]
    for k, (u, v, ok) in enumerate(fields):
        one.add(u, v, ok, pair_id=k)
        parts[k % 3].add(u, v, ok, pair_id=k)
        stats[k % 3].add(u, v, ok, pair_id=k)
    for st, part in zip(stats, parts, strict=True):
        st.vorticity = part
    # through the FieldAccumulator: merged, written and read back
    merged = rspiv.FieldAccumulator.merged(stats)
    back = rspiv.FieldAccumulator.from_xarray(merged.to_xarray(velocity_units="pix"))
    for got in (merged.vorticity, back.vorticity):
        for name in ("omega", "swirl"):
            np.testing.assert_array_equal(getattr(got, f"{name}_count"),
                                          getattr(one, f"{name}_count"))  # fmt: skip
            np.testing.assert_allclose(got.mean(name), one.mean(name), rtol=1e-10, atol=1e-15)
            np.testing.assert_allclose(got.var(name), one.var(name), rtol=1e-9, atol=1e-15)
        assert got.n_fields == 10 and got.scheme == "least_squares"
    assert back.vorticity.pair_ids == set(range(10))
    with pytest.raises(InvalidInputError, match="share"):
        parts[0].merge(parts[0])
    with pytest.raises(InvalidInputError, match="other grids"):
        one.merge(VorticityAccumulator((12, 20), 4.0, 8.0))


def test_bad_input_is_refused():
    with pytest.raises(InvalidInputError, match="scheme"):
        VorticityAccumulator((5, 5), 1.0, 1.0, "spectral")
    with pytest.raises(InvalidInputError, match="3 x 3"):
        VorticityAccumulator((2, 5), 1.0, 1.0)
    acc = VorticityAccumulator((5, 5), 1.0, 1.0)
    with pytest.raises(InvalidInputError, match="shape"):
        acc.add(np.zeros((5, 4)), np.zeros((5, 4)))
    acc.add(np.zeros((5, 5)), np.zeros((5, 5)), pair_id=1)
    with pytest.raises(InvalidInputError, match="pair 1"):
        acc.add(np.zeros((5, 5)), np.zeros((5, 5)), pair_id=1)
