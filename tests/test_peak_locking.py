"""Peak locking measured from the displacements' histogram (rspiv.peak_locking).

Ground truth: displacements drawn with a known bias ``-a sin(2 pi t)`` (the estimator's model);
synthetic PIV pairs of a known displacement ramp, whose locking amplitude is fitted against the
exact displacements (as ``benches/bench_accuracy.py --only particle-size`` does), including
saturated particle images whose diameter passes the 2 px rule; and a synthetic campaign of
1.3 px particle images against one of 2.5 px.
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import warnings

import numpy as np
import pytest
import rspiv
from campaign_cases import lean_file
from rspiv.campaign import Campaign
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.peak_locking import (
    LOCKING_SAID_PX,
    campaign_locking,
    exact_amplitude,
    locking_amplitude,
)
from rspiv.synth.particles import particle_pair


def _biased(t, a):
    return t - a * np.sin(2 * np.pi * t)


@pytest.mark.parametrize("a", [0.0, 0.01, 0.03])
def test_an_imposed_bias_is_read_back(a):
    rng = np.random.default_rng(7)
    uniform = rng.uniform(0.3, 6.3, 700_000)
    assert locking_amplitude(_biased(uniform, a)) == pytest.approx(a, abs=0.001)
    # a boundary layer's u over its height (a free stream within 0.05 px, where nothing can
    # be told) beside its narrow v (nothing to tell either)
    y = rng.uniform(0, 1, 700_000)
    u = 18.5 * np.clip(y / 0.6, 0, 1) ** (1 / 7) + rng.normal(0, 0.05, y.size)
    v = rng.normal(0, 0.4, y.size)
    got = locking_amplitude(_biased(u, a), _biased(v, a))
    assert got == pytest.approx(a, abs=0.0015)
    assert np.isnan(locking_amplitude(_biased(v, a)))


def test_what_is_counted():
    rng = np.random.default_rng(3)
    u = _biased(rng.uniform(0, 8, (600, 1000)), 0.02)
    valid = rng.random(u.shape) < 0.9
    wild = u.copy()
    bad = np.round(u[~valid])  # whole pixels (no sub-pixel fit), or NaN
    wild[~valid] = np.where(rng.random(bad.size) < 0.2, np.nan, bad)
    # the rejected vectors are not counted
    assert locking_amplitude(wild, valid=valid) == pytest.approx(0.02, abs=0.0015)
    # counted, vectors at whole pixels are locking at its worst, and read so
    assert locking_amplitude(wild) > 0.03
    assert np.isnan(locking_amplitude(np.full(100, 3.2)))
    assert np.isnan(locking_amplitude([]))
    with pytest.raises(InvalidInputError, match="one shape"):
        locking_amplitude(u, u[:10])
    with pytest.raises(InvalidInputError, match="one shape"):
        locking_amplitude(u, valid=valid[:10])
    with pytest.raises(InvalidInputError, match="arrays of numbers"):
        locking_amplitude(["a", "b"])
    # the reference fit against exact displacements
    t = rng.uniform(0, 5, 10_000)
    assert exact_amplitude(t, _biased(t, 0.02)) == pytest.approx(0.02, abs=1e-12)
    with pytest.raises(InvalidInputError, match="as many values"):
        exact_amplitude(t, t[:5])
    got = campaign_locking([0.01, 0.011, np.nan, 0.009, 0.0105])
    assert got["pairs"] == 4 and got["said"]
    assert got["amplitude_px"] == pytest.approx(0.010125, abs=1e-5)
    assert not campaign_locking([0.01, 0.011])["said"]  # no error under 3 pairs
    assert not campaign_locking([0.004, 0.0041, 0.0039])["said"]  # under the bar
    assert not campaign_locking([0.02, -0.01, 0.03, -0.02])["said"]  # within its scatter
    nothing = campaign_locking([np.nan])
    assert nothing["amplitude_px"] is None and "too few vectors" in nothing["note"]
    # a field too small to tell: NaN rather than a guess
    assert np.isnan(locking_amplitude(_biased(rng.uniform(-2.5, 2.5, 300), 0.03)))


def test_counts_pooled_over_pairs_tell_where_one_field_cannot():
    """48 fields of 500 displacements with a bias of 0.02 px: none tells alone; the counts
    summed over them (streamed in two parts, merged, through a statistics file) do, with an
    error from their batches; pair ids are not counted twice."""
    from rspiv.peak_locking import BATCHES, LockingHistogram
    from rspiv.stats import FieldAccumulator

    rng = np.random.default_rng(11)
    parts = [FieldAccumulator((20, 25)) for _ in range(2)]
    for p in parts:
        p.locking = LockingHistogram()
    alone = []
    for k in range(48):
        u = _biased(rng.uniform(0.3, 6.3, (20, 25)), 0.02)
        v = _biased(rng.normal(0.0, 0.3, (20, 25)), 0.02)
        alone.append(locking_amplitude(u, v))
        parts[k % 2].add(u, v, pair_id=k)
        parts[k % 2].locking.add(u, v, pair_id=k)
    assert np.all(np.isnan(alone))
    acc = FieldAccumulator.merged(parts)
    got = acc.locking.result()
    assert got["pairs"] == 48 and got["batches"] == BATCHES and got["said"]
    assert got["amplitude_px"] == pytest.approx(0.02, abs=3 * got["standard_error_px"])
    back = FieldAccumulator.from_xarray(acc.to_xarray(velocity_units="pix")).locking
    np.testing.assert_array_equal(back.counts, acc.locking.counts)
    assert back.result() == got
    kept = pickle.loads(pickle.dumps(acc)).locking  # a checkpoint: the bins held only
    np.testing.assert_array_equal(kept.counts, acc.locking.counts)
    assert kept.pair_ids == acc.locking.pair_ids and kept.n_fields == 48
    assert len(pickle.dumps(acc.locking)) < 60_000
    with pytest.raises(InvalidInputError, match="pair 3 was added before"):
        acc.locking.add(u, v, pair_id=3)
    with pytest.raises(InvalidInputError, match="in both parts"):
        acc.locking.merge(back)
    # a few pairs: an amplitude, no error, not said
    few = LockingHistogram()
    for k in range(2):
        few.add(_biased(rng.uniform(0.3, 6.3, 20_000), 0.02), pair_id=k)
    got = few.result()
    assert got["standard_error_px"] is None and not got["said"] and "3 are needed" in got["note"]


SHAPE = (1024, 2048)


def _ramp(x, y):
    return 6 * x / SHAPE[1] + 0.3, 3 * y / SHAPE[0] + 0.2


def _pair(diameter, clip=1.0):
    """(estimate, amplitude fitted against the exact displacements, particle diameter) of a
    synthetic ramp pair through the paper's passes; ``clip``: the frames saturated at that
    share of their brightest particle images."""
    a, b = particle_pair(SHAPE, _ramp, density=0.03, diameter=diameter, noise=0.05, seed=1)
    top = np.percentile(a, 99.9) * clip
    a, b = (np.minimum(f, top).astype(f.dtype) for f in (a, b))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)])
    tu, tv = _ramp(f.x, f.y)
    ok = f.valid & ~f.replaced
    exact = exact_amplitude(np.r_[tu[ok], tv[ok]], np.r_[f.u[ok], f.v[ok]])
    return locking_amplitude(f.u, f.v, f.valid), exact, min(f.particle_diameter)


def test_piv_pairs_against_their_exact_displacements():
    est, exact, _ = _pair(1.5)
    assert exact > 0.01 and exact <= est <= 1.45 * exact
    est, exact, _ = _pair(2.5)
    assert abs(exact) < 0.002 and abs(est) < 0.002
    # saturated particle images: their diameter passes the 2 px rule, their peaks lock
    est, exact, diameter = _pair(2.5, clip=0.15)
    assert diameter > 3.0
    assert exact > 0.009 and exact <= est <= 1.45 * exact and est > LOCKING_SAID_PX


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    d = tmp_path_factory.mktemp("locking")
    out = {}
    for name, diameter in (("small", 1.3), ("fine", 2.5)):
        scene = dataclasses.replace(
            DEFAULT_SCENE, scale=0.15, pairs=8, monte_carlo_samples=0, diameter=diameter
        )
        toml = synth_campaign(d / name, scene=scene)
        lean_file(toml)
        said: list[str] = []
        res = Campaign.load(toml, progress=False, log=said.append).run()
        summary = json.loads((d / name / "out" / "summary.json").read_text())
        out[name] = (res, summary, said)
    return out


def test_a_campaign_of_small_particle_images_says_its_locking(campaigns):
    res, summary, said = campaigns["small"]
    got = summary["peak_locking"]
    assert got["judged_on"] == "uncorrected"
    raw = got["runs"]["uncorrected"]
    assert raw["pairs"] >= 6 and raw["said"]
    assert raw["amplitude_px"] >= LOCKING_SAID_PX
    assert raw["amplitude_px"] >= 3 * raw["standard_error_px"]
    assert "peak locking measured" in got["warning"]
    assert any("peak locking measured" in line for line in said)
    # Method II's mapped displacements: a lower bound
    assert got["runs"]["method_II"]["amplitude_px"] < raw["amplitude_px"]
    rows = (res.out_dir / "pairs_uncorrected.csv").read_text().splitlines()
    assert rows[0].split(",")[5] == "locking"
    each = np.array([float(r.split(",")[5]) for r in rows[1:]])
    assert raw["pairs"] == 8 and raw["batches"] >= 6  # the pooled counts, batches of a pair
    assert np.count_nonzero(np.isfinite(each)) >= 6  # each pair's own figure
    assert np.all(each[np.isfinite(each)] > 0)
    md = (res.out_dir / "report" / "report.md").read_text()
    assert "peak locking measured" in md


def test_a_campaign_of_particle_images_that_resolve_says_nothing(campaigns):
    _, summary, said = campaigns["fine"]
    got = summary["peak_locking"]
    raw = got["runs"]["uncorrected"]
    assert raw["pairs"] >= 6 and not raw["said"] and "warning" not in got
    assert abs(raw["amplitude_px"]) <= 3 * raw["standard_error_px"]
    assert not any("peak locking measured" in line for line in said)
