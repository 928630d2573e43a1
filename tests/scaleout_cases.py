"""Tiny synthetic campaigns shared by the scale-out, merge and resume tests.

``rspiv.demo``'s scene at the smallest scale (0.1: an 886 x 528 px sensor at the paper's
magnification), no Monte Carlo and no report, so that a pair takes about half a second and the
preparation (calibration, wall pilot) a few seconds.
"""

from __future__ import annotations

import dataclasses
import pathlib
import shutil

import numpy as np

SCALE = 0.1


def make_campaign(directory: pathlib.Path, pairs: int, seed: int = 2386) -> pathlib.Path:
    """Write a synthetic campaign (``campaign.toml`` with output folder ``out``)."""
    from rspiv.campaign_config import load_campaign_config
    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    scene = dataclasses.replace(
        DEFAULT_SCENE, scale=SCALE, pairs=pairs, monte_carlo_samples=0, seed=seed
    )
    path = synth_campaign(directory, scene=scene)
    cfg = load_campaign_config(path)
    cfg.output.report = False
    cfg.calibration.monte_carlo_samples = 0
    # an ensemble band at the wall: its sums ride on the statistics through every executor
    cfg.ensemble.enabled = True
    cfg.ensemble.band = 16.0
    return cfg.save(path)


def prepared_copy(src_out: pathlib.Path, dst_out: pathlib.Path) -> pathlib.Path:
    """A fresh output folder sharing ``src_out``'s prepared context (calibration and wall
    angle computed once), without its checkpoints, log or outputs."""
    dst_out.mkdir(parents=True, exist_ok=True)
    for name in ("context.json", "calibration.json"):
        if (src_out / name).is_file():
            shutil.copy2(src_out / name, dst_out / name)
    return dst_out


STAT_FIELDS = ("mean_u", "mean_v", "uu", "vv", "uv")


def assert_same_statistics(a, b, rtol: float = 1e-12, lag: bool = True) -> None:
    """Two FieldAccumulators hold the same statistics: identical pair ids and counts, every
    statistic equal to ``rtol`` relative to the largest magnitude of that field (so that values
    crossing zero, e.g. uv, are compared on the field's scale), NaN at the same places."""
    assert a.pair_ids == b.pair_ids
    np.testing.assert_array_equal(a.count, b.count)
    names = list(STAT_FIELDS)
    if lag:
        np.testing.assert_array_equal(a.lag_count_u, b.lag_count_u)
        np.testing.assert_array_equal(a.lag_count_v, b.lag_count_v)
        names += ["lag_c_u", "lag_c_v", "lag_mean_a_u", "lag_mean_b_v"]
    for name in names:
        x = np.asarray(getattr(a, name), float)
        y = np.asarray(getattr(b, name), float)
        np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=name)
        scale = np.nanmax(np.abs(x)) if np.isfinite(x).any() else 0.0
        np.testing.assert_allclose(y, x, rtol=rtol, atol=rtol * scale, err_msg=name)
    if lag:
        for q in ("u", "uu", "uv"):
            x = a.n_eff(q)
            np.testing.assert_allclose(b.n_eff(q), x, rtol=rtol, atol=rtol * np.max(x))
    # the ensemble band's summed planes (issue 13): the same sums to rtol
    assert (a.ensemble is None) == (b.ensemble is None)
    if a.ensemble is not None:
        assert a.ensemble.pairs == b.ensemble.pairs
        x = a.ensemble.acc
        np.testing.assert_allclose(b.ensemble.acc, x, rtol=rtol, atol=rtol * np.max(np.abs(x)))
    # the two-point sums (the synthetic campaign's [statistics] two_point): the same sums
    assert (a.two_point is None) == (b.two_point is None)
    if a.two_point is not None:
        assert a.two_point.pair_ids == b.two_point.pair_ids
        np.testing.assert_array_equal(a.two_point.count, b.two_point.count)
        # the raw sums (sums of transforms: plain additions); the coefficients derived from
        # them subtract the means' products and lose about 1e-10 to the cancellation
        for name in ("sum_a", "pow_a", "cross_a", "sum_b", "pow_b", "cross_b"):
            x, y = getattr(a.two_point, name), getattr(b.two_point, name)
            np.testing.assert_allclose(y, x, rtol=rtol, atol=rtol * np.max(np.abs(x)), err_msg=name)
    # the vorticity statistics (the synthetic campaign's [statistics] vorticity) alike
    assert (a.vorticity is None) == (b.vorticity is None)
    if a.vorticity is not None:
        np.testing.assert_array_equal(a.vorticity.omega_count, b.vorticity.omega_count)
        for name in ("omega", "swirl"):
            x, y = a.vorticity.var(name), b.vorticity.var(name)
            np.testing.assert_allclose(y, x, rtol=rtol, atol=rtol * np.nanmax(x))
