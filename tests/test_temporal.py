"""Frequency spectra, space-time correlations and convection velocities of a time-resolved
recording (rspiv.temporal), against exact answers: a travelling wave's line (its power, its
co-spectrum), a frozen random pattern convected at a known speed (the speed, and the frequency
spectrum as Taylor's hypothesis maps the pattern's own), gaps that restart the series, parts
that merge, segments with too few valid samples."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.errors import InvalidInputError
from rspiv.temporal import TemporalAccumulator, follow_ridge, peak_offset

NY, NX = 6, 256


def _ones():
    return np.ones((NY, NX), bool)


def test_a_travelling_wave_gives_its_line_and_its_speed():
    m, amp, f0, kx = 64, 1.3, 8 / 64, 1 / 32.0  # f0 on a bin; a wavelength of 32 columns
    zero = np.zeros((NY, NX))
    acc = TemporalAccumulator(zero, zero, [2, 4], segment=m, max_lag=3, half_width=16)
    x = np.arange(NX)
    for t in range(5 * m):
        u = np.broadcast_to(amp * np.cos(2 * np.pi * (kx * x - f0 * t)), (NY, NX))
        acc.add(u, -0.5 * u, _ones(), pair_id=t)
    r = acc.results()
    df = 1.0 / m
    assert r["segments"].tolist() == [9 * NX, 9 * NX]  # 5 segments' worth at half overlap
    np.testing.assert_allclose(r["phi_uu"].sum(1) * df, amp**2 / 2, rtol=1e-12)
    np.testing.assert_allclose(r["phi_vv"].sum(1) * df, amp**2 / 8, rtol=1e-12)
    np.testing.assert_allclose(r["phi_uv"].sum(1) * df, -(amp**2) / 4, rtol=1e-12)
    # the line: the Hann window spreads it over its bin and the two beside it
    assert r["phi_uu"][0, 7:10].sum() * df == pytest.approx(amp**2 / 2, rel=1e-12)
    np.testing.assert_allclose(r["var_u"], amp**2 / 2, rtol=1e-12)
    np.testing.assert_allclose(r["R_uu"][:, 0, 16], 1.0, rtol=1e-12)
    # the crest moves f0 / kx = 4 columns per pair interval
    np.testing.assert_allclose(r["shift"][:, 1:], [[4.0, 8.0, 12.0]] * 2, atol=0.05)
    # R is the cosine of the wave at every lag and offset
    d = r["offsets"]
    for lag in range(4):
        want = np.cos(2 * np.pi * (kx * d - f0 * lag))
        np.testing.assert_allclose(r["R_uu"][0, lag], want, atol=1e-3)  # 256 columns: edges


def _frozen(rng, c: float, frames: int, length: int = 4096):
    """Rows of a random pattern g(x - c t), exact at any c by the Fourier shift, and the
    pattern's one-sided spatial spectrum (per cycle per column)."""
    k = np.fft.rfftfreq(length)
    amp = np.exp(-((k / 0.03) ** 2))
    g = amp * (rng.normal(size=(NY, k.size)) + 1j * rng.normal(size=(NY, k.size)))
    g[:, 0] = 0.0
    spec = 2.0 * np.abs(g) ** 2 / length  # each row's, per cycle per column
    for t in range(frames):
        yield np.fft.irfft(g * np.exp(-2j * np.pi * k * c * t), length)[:, :NX]
    yield k, spec


def test_a_convected_pattern_gives_its_speed_and_taylors_spectrum():
    rng = np.random.default_rng(2)
    c, frames, m = 2.37, 1536, 128
    zero = np.zeros((NY, NX))
    acc = TemporalAccumulator(zero, zero, [1, 3], segment=m, max_lag=16, half_width=60)
    gen = _frozen(rng, c, frames)
    for t in range(frames):
        u = next(gen)
        acc.add(u, -0.3 * u, _ones(), pair_id=t)
    k, spec = next(gen)
    r = acc.results()
    lags = r["lag"][1:]
    for i in range(2):
        speed = np.sum(r["shift"][i, 1:] * lags) / np.sum(lags**2)
        assert speed == pytest.approx(c, rel=0.003)
        assert np.all(np.abs(r["shift"][i, 1:] / lags - c) < 0.02 * c)
        assert r["peak"][i, 16] > 0.98  # frozen: the pattern keeps its shape
    # Taylor: a structure of wavenumber k passes at f = c k; phi_t(f) = phi_x(f / c) / c
    f = r["f"]
    # where the pattern holds its power; f = 0 left out (each segment loses its mean)
    band = (f > 0) & (f <= 2 * c * 0.03)
    for i, row in enumerate((1, 3)):
        # the row's spectrum smoothed over the bins of a segment's frequency
        want = np.array([spec[row][np.abs(k * c - fj) <= 0.5 / m].mean() for fj in f]) / c
        got = r["phi_uu"][i]
        assert np.sum(got[1:]) / m == pytest.approx(np.sum(want[1:]) / m, rel=0.08)
        assert np.corrcoef(np.log(got[band]), np.log(want[band]))[0, 1] > 0.99


def test_a_gap_restarts_the_series_and_parts_merge():
    rng = np.random.default_rng(4)
    zero = np.zeros((NY, NX))
    fields = [rng.normal(size=(NY, NX)) for _ in range(40)]
    plan = {"segment": 8, "max_lag": 3, "half_width": 5}
    gapped = TemporalAccumulator(zero, zero, [2], **plan)
    for t, u in enumerate(fields):
        gapped.add(u, u, _ones(), pair_id=t if t < 20 else t + 1)  # pair 20 missing
    a = TemporalAccumulator(zero, zero, [2], **plan)
    b = a.empty_copy()
    for t, u in enumerate(fields):
        (a if t < 20 else b).add(u, u, _ones(), pair_id=t)
    a.merge(b)
    ra, rg = a.results(), gapped.results()
    for key in ("phi_uu", "R_uu", "pairs", "segments"):
        np.testing.assert_allclose(ra[key], rg[key], rtol=1e-12)
    # nothing is correlated across the gap: lag 1 holds 19 + 19 field pairs, not 39
    assert rg["pairs"][0, 1, 5] == 38 * NX
    assert rg["segments"][0] == 2 * 4 * NX  # 4 segments of 8 at half overlap in each 20
    with pytest.raises(InvalidInputError, match="other plans"):
        a.merge(TemporalAccumulator(zero, zero, [3], **plan))


def test_a_column_with_too_few_valid_samples_leaves_its_segment():
    zero = np.zeros((NY, NX))
    rng = np.random.default_rng(6)
    acc = TemporalAccumulator(zero, zero, [0], segment=16, max_lag=1, min_valid=0.9)
    for t in range(16):
        valid = _ones()
        valid[0, :10] = t % 4 != 0  # 4 of 16 missing: 75 % valid
        acc.add(rng.normal(size=(NY, NX)), zero, valid, pair_id=t)
    assert acc.results()["segments"].tolist() == [NX - 10]


def test_peak_offset_and_bad_input():
    assert peak_offset(np.array([0.0, 1.0, 0.0])) == 1.0
    assert peak_offset(np.array([0.2, 0.9, 1.0, 0.9])) == pytest.approx(2.0)
    assert np.isnan(peak_offset(np.array([1.0, 0.5, 0.2])))  # at an end
    assert np.isnan(peak_offset(np.full(4, np.nan)))
    z = np.zeros((NY, NX))
    for kwargs, match in (
        ({"ref_rows": [NY]}, "reference rows"),
        ({"ref_rows": [1], "segment": 7}, "segment"),
        ({"ref_rows": [1], "segment": 4}, "segment"),
        ({"ref_rows": [1], "max_lag": 0}, "max_lag"),
        ({"ref_rows": [1], "half_width": -2}, "half_width"),
        ({"ref_rows": [1], "min_valid": 0.0}, "min_valid"),
        ({"ref_rows": [1], "sign_y": 2.0}, "signs"),
    ):
        with pytest.raises(InvalidInputError, match=match):
            TemporalAccumulator(z, z, **kwargs)
    acc = TemporalAccumulator(z, z, [1])
    with pytest.raises(InvalidInputError, match="shape"):
        acc.add(z[:2], z, _ones(), pair_id=0)


def test_the_ridge_is_followed_past_a_higher_far_lobe():
    """A pattern of few scales correlates again a wavelength away: at lag 3 a far lobe stands
    above the ridge (0.9 against 0.8); the ridge, moving 4 columns per lag, is followed, and
    lost where it falls under 0.2."""
    d = np.arange(61, dtype=np.float64)
    r = np.zeros((6, d.size))
    for lag, top in enumerate((1.0, 0.95, 0.9, 0.8, 0.5, 0.1)):
        r[lag] = top * np.exp(-0.5 * ((d - 30 - 4 * lag) / 3.0) ** 2)
    r[3] += 0.9 * np.exp(-0.5 * ((d - 5) / 3.0) ** 2)
    assert np.argmax(r[3]) == 5  # the largest value is on the lobe
    pos, val = follow_ridge(r, 30)
    np.testing.assert_allclose(pos[:5], 30 + 4 * np.arange(5), atol=0.05)
    np.testing.assert_allclose(val[:5], (1.0, 0.95, 0.9, 0.8, 0.5), atol=1e-6)
    assert np.isnan(pos[5]) and np.isnan(val[5])
    assert peak_offset(r[3], near=40.0) == pytest.approx(42.0, abs=0.05)
    for bad, start in ((r[0], 30), (r, 61), (r, -1)):
        with pytest.raises(InvalidInputError, match="ridge needs a"):
            follow_ridge(bad, start)


def test_the_shared_helpers_refuse_bad_input_in_one_line():
    """The Welch taper and density, the noise floor's reach and the series' runs (shared by the
    temporal pass and the SPOD): exact on good input, one line on bad."""
    from rspiv.temporal import consecutive_runs, hann_taper, noise_reached, one_sided_density
    from scipy.signal import get_window

    np.testing.assert_allclose(hann_taper(16), get_window("hann", 16), atol=1e-15)
    d = one_sided_density(16)
    assert d.shape == (9,) and d[0] == d[-1] == pytest.approx(d[1] / 2)
    phi = np.array([[10, 5, 1, 3, 1], [10, 5, 1, 1, 1], [1, 1, 1, 1, 1], [9, 9, 9, 9, 9.0]])
    np.testing.assert_array_equal(noise_reached(phi, np.ones(4)), [4, 2, 0, -1])
    assert consecutive_runs([3, 4, 5, 9, 10, 12]) == [3, 2, 1] and consecutive_runs([]) == []
    for call, match in (
        (lambda: hann_taper(7), "even integer >= 2"),
        (lambda: one_sided_density(0), "even integer >= 2"),
        (lambda: noise_reached(phi, np.ones(3)), "floor of shape"),
        (lambda: consecutive_runs([1, 3, 2]), "must increase"),
        (lambda: consecutive_runs([1.5, 2.5]), "1-D integers"),
    ):
        with pytest.raises(InvalidInputError, match=match) as exc:
            call()
        assert "\n" not in str(exc.value)
