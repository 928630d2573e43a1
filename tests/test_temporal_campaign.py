"""A time-resolved campaign's frequency spectra and convection velocities (``[statistics]
temporal``, rspiv.campaign.temporal) through the PIV: a frozen pattern convected at a known
speed (rspiv.synth.convected_sequence) gives that speed as its convection velocity, and the
spectra equal scipy's Welch estimate of the written fields' time series."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from rspiv.campaign import Campaign
from rspiv.campaign_config import CampaignConfig, load_campaign_config
from rspiv.errors import InvalidInputError
from rspiv.synth import convected_sequence

SPEED = 3.0  # px per frame interval
SEGMENT = 32


def _config(d) -> CampaignConfig:
    cfg = CampaignConfig(name="convected pattern")
    cfg.images.glob = str(d / "raw" / "frame_*.tif")
    cfg.images.pairing = "sequential"
    cfg.correction.method = "none"
    cfg.piv.passes = [(32, 32), (32, 32)]
    cfg.wall.enabled = False  # no wall: heights in px from the frame's lower edge
    cfg.statistics.min_count = 2
    cfg.statistics.temporal = True
    cfg.statistics.temporal_heights = (80.0, 160.0)
    cfg.statistics.temporal_height_units = "px"
    cfg.statistics.temporal_segment = SEGMENT
    cfg.statistics.temporal_max_lag = 8
    cfg.output.fields = True
    cfg.output.dir = d / "out"
    return cfg


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    d = tmp_path_factory.mktemp("convected")
    (d / "raw").mkdir()
    for k, f in enumerate(convected_sequence((256, 384), SPEED, 0.25, 129, seed=3)):
        tifffile.imwrite(d / "raw" / f"frame_{k:04d}.tif", f)
    toml = _config(d).save(d / "campaign.toml")
    camp = Campaign.load(toml, progress=False)
    return camp, camp.run()


def test_the_convection_velocity_is_the_patterns_speed(processed):
    import xarray as xr

    _, res = processed
    prof = res.temporal["uncorrected"]
    assert prof["pairs"] == 128 and "warning" not in prof
    # px per pair interval: the pattern moves SPEED px per frame, pairs are a frame apart
    np.testing.assert_allclose(prof["U"], SPEED, rtol=0.005)
    np.testing.assert_allclose(prof["U_c"], SPEED, rtol=0.02)
    assert np.all(prof["peak"][:, 1:] > 0.7)
    # the pattern's modes pass at SPEED / wavelength: 0.019, 0.031 and 0.047 cycles per frame;
    # the spectrum's largest bin above 0 is the one of 0.031
    f = prof["f"]
    assert np.all(f[1 + np.argmax(prof["phi_uu"][:, 1:], axis=1)] == pytest.approx(1 / SEGMENT))
    with xr.open_dataset(res.out_dir / "temporal_uncorrected.nc", engine="h5netcdf") as ds:
        assert ds["R_uu"].dims == ("ref", "lag", "dx")
        assert ds["phi_uu"].dims == ("ref", "f")
        np.testing.assert_allclose(ds["U_c"].values, prof["U_c"])
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["runs"]["uncorrected"]["temporal"]["pairs"] == 128
    # the report's figure (the report itself needs SI units: a calibration and [flow] dt)
    from rspiv.plots.temporal import plot_temporal

    png = plot_temporal(res.out_dir / "temporal.png", prof)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_spectra_are_welchs_of_the_written_fields(processed):
    import xarray as xr
    from scipy.signal import welch

    _, res = processed
    prof = res.temporal["uncorrected"]
    acc = res.accumulators["uncorrected"]
    p = res.analyses["uncorrected"].profile
    files = sorted((res.out_dir / "fields" / "uncorrected").glob("pair_*.nc"))
    u, ok = [], []
    for f in files:
        with xr.open_dataset(f, engine="h5netcdf") as ds:
            u.append(ds["u"].values[prof["ref_rows"]].astype(np.float64))
            ok.append(ds["valid"].values[prof["ref_rows"]].astype(bool))
    u, ok = np.array(u), np.array(ok)  # (time, ref, column)
    usable = (acc.count >= 2)[prof["ref_rows"]]
    du = p["sign_x"] * (u - acc.mean_u[prof["ref_rows"]])
    for i in range(len(prof["ref_rows"])):
        # 7 segments of 32 in 128 pairs at half overlap; a column's segment enters with 90 %
        # of its samples valid, the others at the mean of the valid ones (no power)
        spectra = []
        for start in range(0, 128 - SEGMENT + 1, SEGMENT // 2):
            seg, good = du[start : start + SEGMENT, i], ok[start : start + SEGMENT, i]
            enter = usable[i] & (good.mean(axis=0) >= 0.9)
            mean = np.where(good, seg, 0.0).sum(axis=0) / np.maximum(good.sum(axis=0), 1)
            seg = np.where(good, seg, mean)[:, enter]
            f, pxx = welch(seg, fs=1.0, window="hann", nperseg=SEGMENT, detrend="constant",
                           axis=0)  # fmt: skip
            spectra.append(pxx)
        pxx = np.concatenate(spectra, axis=1)
        assert pxx.shape[1] == prof["segments"][i] >= 7 * 18
        np.testing.assert_allclose(prof["f"], f)
        np.testing.assert_allclose(prof["phi_uu"][i], pxx.mean(axis=1), rtol=1e-9, atol=1e-12)


def test_the_noise_floor_is_each_vectors_uncertainty(processed):
    """The floor is 2 <sigma^2> of the reference rows' vectors (white, one-sided); above the
    pattern's three lines (0.019-0.047 cycles per pair interval) the spectra are the PIV's
    noise, and they lie on it."""
    _, res = processed
    prof = res.temporal["uncorrected"]
    acc = res.accumulators["uncorrected"]
    refs = prof["ref_rows"]
    usable = (acc.count >= 2)[refs]
    for c, noise in (("u", acc.noise_uu()), ("v", acc.noise_vv())):
        s2 = np.array([noise[r][usable[i]].mean() for i, r in enumerate(refs)])
        np.testing.assert_allclose(prof[f"noise_{c}{c}"], 2 * s2, rtol=1e-12)
        plateau = prof[f"phi_{c}{c}"][:, prof["f"] >= 0.15].mean(axis=1)
        ratio = plateau / prof[f"noise_{c}{c}"]
        assert np.all((ratio > 0.75) & (ratio < 1.25)), ratio  # 0.91-0.98 measured
        assert np.all((prof[f"f_noise_{c}"] > 0.047) & (prof[f"f_noise_{c}"] <= 0.2))
    assert "noise" not in prof.get("warning", "")


def test_temporal_keys_are_checked(tmp_path):
    """``[statistics] temporal``: needs the fields and a time-resolved recording; the segment
    even and at least 8; anything else named in one line."""
    base = _config(tmp_path)
    base.output.dir = tmp_path / "out"
    text = base.save(tmp_path / "c.toml").read_text()
    cfg = load_campaign_config(tmp_path / "c.toml")
    assert cfg.statistics.temporal and cfg.statistics.temporal_segment == SEGMENT
    for old, new, match in (
        ('pairing = "sequential"', 'pairing = "pairs"', "time-resolved recording"),
        ("fields = true", "fields = false", "needs each pair's fields"),
        ("temporal_segment = 32", "temporal_segment = 33", "even"),
        ("temporal_segment = 32", "temporal_segment = 4", ">= 8"),
        ("temporal_max_lag = 8", "temporal_max_lag = 0", ">= 1"),
    ):
        assert old in text
        (tmp_path / "bad.toml").write_text(text.replace(old, new))
        with pytest.raises(InvalidInputError, match=match) as exc:
            load_campaign_config(tmp_path / "bad.toml")
        assert "\n" not in str(exc.value)


def test_pairs_across_two_frames_two_frames_apart(processed, tmp_path):
    """``frame_gap = 2`` doubles each pair's displacement and ``pair_step = 2`` the time between
    pairs: the velocities per pair interval follow both (the same frames, 64 pairs of 6 px,
    two frames apart: the pattern moves 6 px per pair interval)."""
    camp, _ = processed
    cfg = _config(tmp_path)
    cfg.images.glob = camp.config.images.glob
    cfg.images.frame_gap = cfg.images.pair_step = 2
    cfg.statistics.temporal_segment = 16
    res = Campaign.load(cfg.save(tmp_path / "c.toml"), progress=False).run()
    prof = res.temporal["uncorrected"]
    assert prof["pairs"] == 64 and prof["segments"].min() > 0
    np.testing.assert_allclose(prof["U"], 2 * SPEED, rtol=0.005)
    np.testing.assert_allclose(prof["U_c"], 2 * SPEED, rtol=0.02)


def test_si_units_follow_the_pair_interval(processed):
    """With a calibration and ``[flow] dt`` (the time across ``frame_gap`` frames) the pass
    gives Hz, (m/s)^2/Hz, s, m and m/s: the same numbers as in px and pair intervals, scaled."""
    import dataclasses as dc

    from rspiv.campaign.temporal import write_outputs

    camp, res = processed
    run = res.context.runs[0]
    an = res.analyses[run.name]
    px = write_outputs(camp, res, run, an)
    m_per_px, dt = 2e-5, 1e-3  # 50 px/mm; 1 ms across a frame
    profile = {**an.profile, "si": True, "m_per_px": m_per_px, "k": m_per_px / dt}
    camp.config.flow.dt, camp.config.output.netcdf = dt, False  # the fixture's files stay
    try:
        si = write_outputs(camp, res, run, dc.replace(an, profile=profile))
    finally:
        camp.config.flow.dt, camp.config.output.netcdf = 0.0, True
    np.testing.assert_allclose(si["f"], px["f"] / dt)  # Hz: a pair interval is a frame
    np.testing.assert_allclose(si["lag"], px["lag"] * dt)
    np.testing.assert_allclose(si["U_c"], px["U_c"] * m_per_px / dt)
    np.testing.assert_allclose(si["U"], px["U"] * m_per_px / dt)
    np.testing.assert_allclose(si["dx"], px["dx"] * m_per_px)
    # the variance in (m/s)^2 whichever the units: sum phi df
    var_px = px["phi_uu"].sum(1) * (px["f"][1] - px["f"][0]) * (m_per_px / dt) ** 2
    var_si = si["phi_uu"].sum(1) * (si["f"][1] - si["f"][0])
    np.testing.assert_allclose(var_si, var_px, rtol=1e-12)


def test_a_convected_sequence_refuses_bad_input():
    for kwargs, match in (
        ({"frames": 1}, "frames"),
        ({"frames": 2.5}, "frames"),
        ({"speed": float("nan")}, "finite"),
        ({"wavelengths": ()}, "wavelength"),
        ({"noise": -0.1}, "noise >= 0"),
        ({"density": 0.0}, "density and diameter must be > 0"),
        ({"shape": (0, 32)}, "must be positive"),
    ):
        args = {"shape": (32, 32), "speed": 1.0, "amplitude": 0.1, "frames": 3, **kwargs}
        with pytest.raises(InvalidInputError, match=match):
            convected_sequence(**args)
