"""Conditional averages about ejections and sweeps (rspiv.conditional): the sums equal the
definition's direct sums (signs, holes, masks, the field's edges, batches), parts merge to one
pass, and on jointly Gaussian fields of known covariance the averages are the linear stochastic
estimate from that covariance, to their own standard errors."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.conditional import KINDS, VORTEX_KINDS, ConditionalAccumulator
from rspiv.errors import InvalidInputError


def _direct(fields, mean, rms_u, rms_v, ref, rows, offsets, hole, sx, sy, usable):
    """The definition, term by term (module docstring of rspiv.conditional)."""
    ny, nx = mean.shape
    out = {}
    for k, (a, b) in enumerate(((-1, 1), (1, -1))):
        su = np.zeros((len(rows), len(offsets)))
        sv = np.zeros_like(su)
        n = np.zeros(su.shape, np.int64)
        events = 0
        for u, v, valid in fields:
            ok = valid & usable
            uf, vf = sx * (u - mean), sy * (v - mean)
            for c in range(nx):
                x, y = uf[ref, c], vf[ref, c]
                if not ok[ref, c] or abs(x * y) < hole * rms_u[ref, c] * rms_v[ref, c]:
                    continue
                if not (np.sign(x) == a and np.sign(y) == b):
                    continue
                events += 1
                for j, d in enumerate(offsets):
                    if 0 <= c + d < nx:
                        m = ok[rows, c + d]
                        su[:, j] += np.where(m, uf[rows, c + d], 0.0)
                        sv[:, j] += np.where(m, vf[rows, c + d], 0.0)
                        n[:, j] += m
        with np.errstate(invalid="ignore", divide="ignore"):
            out[k] = (su / n, sv / n, n, events)
    return out


def test_sums_equal_the_direct_sums():
    rng = np.random.default_rng(3)
    ny, nx = 30, 90
    mean = rng.normal(0, 0.2, (ny, nx))
    rms_u = rng.uniform(0.8, 1.2, (ny, nx))
    rms_v = rng.uniform(0.5, 0.9, (ny, nx))
    usable = np.ones((ny, nx), bool)
    usable[:, :3] = False  # a column the statistics did not keep
    usable[17, 40:50] = False
    fields = []
    for _ in range(7):
        u = mean + rng.normal(size=(ny, nx))
        v = mean + rng.normal(size=(ny, nx)) * 0.7 - 0.3 * (u - mean)
        fields.append((u, v, rng.random((ny, nx)) > 0.08))
    for sx, sy, hole in ((1.0, 1.0, 0.0), (-1.0, -1.0, 1.0), (-1.0, 1.0, 2.0)):
        acc = ConditionalAccumulator(mean, mean, rms_u, rms_v, [8, 21], rows=(4, 26),
                                     half_width=12, usable=usable, sign_x=sx, sign_y=sy,
                                     hole=hole, batches=3)  # fmt: skip
        for p, (u, v, valid) in enumerate(fields):
            acc.add(u, v, valid, pair_id=p, batch=p * 3 // len(fields))
        r = acc.results()
        np.testing.assert_array_equal(r["rows"], np.arange(4, 26))
        np.testing.assert_array_equal(r["offsets"], np.arange(-12, 13))
        for i, ref in enumerate((8, 21)):
            want = _direct(fields, mean, rms_u, rms_v, ref, r["rows"], r["offsets"], hole, sx,
                           sy, usable)  # fmt: skip
            for k in range(2):
                wu, wv, wn, we = want[k]
                assert r["events"][i, k] == we > 0
                np.testing.assert_array_equal(r["count"][i, k], wn)
                np.testing.assert_allclose(r["u"][i, k], wu, rtol=1e-12, atol=1e-12)
                np.testing.assert_allclose(r["v"][i, k], wv, rtol=1e-12, atol=1e-12)
                # at the event itself: the events' own mean
                at = (r["rows"] == ref, r["offsets"] == 0)
                assert r["u"][i, k][at[0]][:, at[1]][0, 0] == pytest.approx(r["event_u"][i, k])
                assert r["v"][i, k][at[0]][:, at[1]][0, 0] == pytest.approx(r["event_v"][i, k])
                sign = (-1, 1) if k == 0 else (1, -1)
                assert np.sign(r["event_u"][i, k]) == sign[0]
                assert np.sign(r["event_v"][i, k]) == sign[1]
        assert acc.n_fields == 7 and acc.pair_ids == set(range(7))


def test_parts_merge_to_one_pass_and_errors_are_batch_means():
    rng = np.random.default_rng(5)
    ny, nx = 20, 64
    zero, one = np.zeros((ny, nx)), np.ones((ny, nx))
    fields = [(rng.normal(size=(ny, nx)), rng.normal(size=(ny, nx))) for _ in range(12)]
    whole = ConditionalAccumulator(zero, zero, one, one, [10], half_width=9, batches=4)
    parts = [whole.empty_copy(), whole.empty_copy()]
    for p, (u, v) in enumerate(fields):
        whole.add(u, v, one.astype(bool), pair_id=p, batch=p // 3)
        parts[p // 6].add(u, v, one.astype(bool), pair_id=p, batch=p // 3)
    parts[0].merge(parts[1])
    a, b = whole.results(), parts[0].results()
    for key in ("u", "v", "u_se", "v_se", "count", "events"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12)
    # the standard error: the scatter of the 4 batch means
    means = [ConditionalAccumulator(zero, zero, one, one, [10], half_width=9) for _ in range(4)]
    for p, (u, v) in enumerate(fields):
        means[p // 3].add(u, v, one.astype(bool))
    bm = np.array([m.results()["u"] for m in means])
    np.testing.assert_allclose(a["u_se"], bm.std(axis=0, ddof=1) / 2.0, rtol=1e-10)
    assert np.all(a["batches_used"][np.isfinite(a["u"])] == 4)
    other = ConditionalAccumulator(zero, zero, one, one, [11], half_width=9, batches=4)
    with pytest.raises(InvalidInputError, match="other plans"):
        whole.merge(other)


def _gaussian_case(ny: int, nx: int):
    """Transfer functions of two jointly Gaussian fields on a periodic grid: u from one white
    noise, v from it (shifted: an inclined link) and a second; their exact covariances."""
    ky, kx = np.fft.fftfreq(ny)[:, None], np.fft.fftfreq(nx)[None, :]

    def gauss(sy: float, sx: float) -> np.ndarray:
        return np.exp(-2 * np.pi**2 * ((ky * sy) ** 2 + (kx * sx) ** 2))

    h1 = gauss(3.0, 8.0)
    h2 = -0.8 * gauss(2.0, 4.0) * np.exp(-2j * np.pi * (ky * 3 + kx * 6))
    h3 = gauss(2.0, 3.0)

    def cov(f, g):  # cov(f(x + r), g(x)) at every lag r
        return np.fft.ifft2(f * np.conj(g)).real

    c = {"uu": cov(h1, h1), "uv": cov(h1, h2), "vu": cov(h2, h1),
         "vv": cov(h2, h2) + cov(h3, h3)}  # fmt: skip
    return h1, h2, h3, c


def test_gaussian_fields_give_the_linear_stochastic_estimate():
    """For jointly Gaussian fluctuations E[u(x + r) | z] = C(u(x + r), z) C_zz^-1 z exactly (z
    the event's (u', v')), so the average over events is that estimate at the events' mean z:
    the difference is sampling noise, of the size of the reported standard errors."""
    rng = np.random.default_rng(7)
    ny, nx = 96, 512
    h1, h2, h3, c = _gaussian_case(ny, nx)
    su, sv = np.sqrt(c["uu"][0, 0]), np.sqrt(c["vv"][0, 0])
    zero = np.zeros((ny, nx))
    refs = [30, 60]
    acc = ConditionalAccumulator(zero, zero, np.full((ny, nx), su), np.full((ny, nx), sv), refs,
                                 rows=(10, 90), half_width=40, hole=1.0)  # fmt: skip
    for k in range(48):
        w1 = np.fft.fft2(rng.normal(size=(ny, nx)))
        w2 = np.fft.fft2(rng.normal(size=(ny, nx)))
        u = np.fft.ifft2(w1 * h1).real
        v = np.fft.ifft2(w1 * h2 + w2 * h3).real
        acc.add(u, v, np.ones((ny, nx), bool), batch=k % 8)
    r = acc.results()
    czz = np.array([[c["uu"][0, 0], c["uv"][0, 0]], [c["vu"][0, 0], c["vv"][0, 0]]])
    for i, r0 in enumerate(refs):
        dy, d = (r["rows"] - r0)[:, None] % ny, r["offsets"][None, :] % nx
        for k in range(2):
            assert r["events"][i, k] > 1500
            w = np.linalg.solve(czz, [r["event_u"][i, k], r["event_v"][i, k]])
            for q, (a, b) in (("u", ("uu", "uv")), ("v", ("vu", "vv"))):
                want = c[a][dy, d] * w[0] + c[b][dy, d] * w[1]
                err = np.sqrt(np.mean((r[q][i, k] - want) ** 2))
                se = np.sqrt(np.mean(r[f"{q}_se"][i, k] ** 2))
                assert 0.7 < err / se < 1.4, (i, k, q, err, se)
                assert np.abs(want).max() > 8 * se  # a structure well above the noise


def test_events_named_by_the_caller_are_averaged_about():
    """Vortex kinds: the caller's events (each a vector of a reference row) give the direct
    sums of the fluctuations about them; an event on a vector that does not enter is not one;
    the quadrant kinds beside them are unchanged."""
    rng = np.random.default_rng(5)
    ny, nx = 24, 60
    mean = rng.normal(0, 0.2, (ny, nx))
    rms = np.ones((ny, nx))
    refs = [7, 15]
    fields, named = [], []
    for _ in range(6):
        u = mean + rng.normal(size=(ny, nx))
        v = mean + rng.normal(size=(ny, nx))
        valid = rng.random((ny, nx)) > 0.1
        ev = {k: rng.random((len(refs), nx)) < 0.1 for k in VORTEX_KINDS}
        fields.append((u, v, valid))
        named.append(ev)
    kinds = ("prograde", "Q2", "retrograde", "Q4")
    acc = ConditionalAccumulator(mean, mean, rms, rms, refs, rows=(2, 22), half_width=9,
                                 kinds=kinds)  # fmt: skip
    plain = ConditionalAccumulator(mean, mean, rms, rms, refs, rows=(2, 22), half_width=9)
    for p, ((u, v, valid), ev) in enumerate(zip(fields, named, strict=True)):
        acc.add(u, v, valid, pair_id=p, events=ev)
        plain.add(u, v, valid, pair_id=p)
    r, q = acc.results(), plain.results()
    assert list(r["kinds"]) == list(kinds)
    for k, kind in enumerate(kinds):
        if kind in KINDS:  # the quadrant kinds as without the others
            j = KINDS.index(kind)
            np.testing.assert_array_equal(r["u"][:, k], q["u"][:, j])
            continue
        for i, ref in enumerate(refs):
            su = np.zeros((20, 19))
            n = np.zeros_like(su)
            events = 0
            for (u, _, valid), ev in zip(fields, named, strict=True):
                uf = np.where(valid, u - mean, 0.0)
                for c in np.flatnonzero(ev[kind][i] & valid[ref]):
                    events += 1
                    for j, d in enumerate(range(-9, 10)):
                        if 0 <= c + d < nx:
                            su[:, j] += uf[2:22, c + d]
                            n[:, j] += valid[2:22, c + d]
            assert r["events"][i, k] == events > 0
            np.testing.assert_array_equal(r["count"][i, k], n)
            with np.errstate(invalid="ignore", divide="ignore"):
                np.testing.assert_allclose(r["u"][i, k], su / n, rtol=1e-12, atol=1e-12)
    with pytest.raises(InvalidInputError, match="prograde events of this field are missing"):
        acc.add(*fields[0])
    with pytest.raises(InvalidInputError, match="must be boolean"):
        acc.add(*fields[0], events={"prograde": np.zeros((2, nx)), "retrograde": ev["retrograde"]})
    with pytest.raises(InvalidInputError, match="kinds must be distinct"):
        ConditionalAccumulator(mean, mean, rms, rms, refs, kinds=("Q2", "Q2"))
    with pytest.raises(InvalidInputError, match="kinds must be distinct"):
        ConditionalAccumulator(mean, mean, rms, rms, refs, kinds=("Q3",))
    with pytest.raises(InvalidInputError, match="other plans"):
        acc.merge(plain)


def test_bad_input_is_refused():
    z, o = np.zeros((10, 20)), np.ones((10, 20))
    for kwargs, match in (
        ({"ref_rows": [10]}, "reference rows"),
        ({"ref_rows": []}, "reference rows"),
        ({"ref_rows": [2], "rows": (5, 3)}, "map rows"),
        ({"ref_rows": [2], "half_width": -1}, "half_width"),
        ({"ref_rows": [2], "sign_x": 0.5}, "signs"),
        ({"ref_rows": [2], "hole": -1.0}, "hole"),
        ({"ref_rows": [2], "hole": float("nan")}, "hole"),
    ):
        with pytest.raises(InvalidInputError, match=match):
            ConditionalAccumulator(z, z, o, o, **kwargs)
    with pytest.raises(InvalidInputError, match="shape"):
        ConditionalAccumulator(z, z[:5], o, o, [2])
    acc = ConditionalAccumulator(z, z, o, o, [2], batches=2)
    with pytest.raises(InvalidInputError, match="batch"):
        acc.add(z, z, o.astype(bool), batch=2)
    with pytest.raises(InvalidInputError, match="shape"):
        acc.add(z[:, :5], z, o.astype(bool))
