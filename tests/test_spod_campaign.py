"""A time-resolved campaign's spectral POD (``[statistics] spod``, rspiv.campaign.spod) through
the PIV: two travelling waves of a frozen pattern convected at a known speed
(rspiv.synth.convected_sequence) are the leading modes at their frequencies, with that speed as
their phase speed; the pass equals rspiv.spod of the written fields, in memory or on disk."""

from __future__ import annotations

import dataclasses as dc
import json

import numpy as np
import pytest
import tifffile
from rspiv.campaign import Campaign
from rspiv.campaign import spod as spod_pass
from rspiv.campaign.fields import read_field
from rspiv.campaign_config import CampaignConfig, load_campaign_config
from rspiv.errors import InvalidInputError
from rspiv.spod import spod
from rspiv.synth import convected_sequence

SPEED = 8.0  # px per frame interval
SEGMENT = 32
# wavelengths 128 and 64 px pass at 8/128 and 8/64 cycles per frame: bins 2 and 4 of 32
WAVES = {2: 128.0, 4: 64.0}


def _config(d) -> CampaignConfig:
    cfg = CampaignConfig(name="two waves")
    cfg.images.glob = str(d / "raw" / "frame_*.tif")
    cfg.images.pairing = "sequential"
    cfg.correction.method = "none"
    cfg.piv.passes = [(32, 32), (32, 32)]
    cfg.wall.enabled = False
    cfg.statistics.min_count = 2
    cfg.statistics.spod = True
    cfg.statistics.spod_segment = SEGMENT
    cfg.statistics.spod_modes = 2
    cfg.output.fields = True
    cfg.output.dir = d / "out"
    return cfg


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    d = tmp_path_factory.mktemp("waves")
    (d / "raw").mkdir()
    frames = convected_sequence((256, 384), SPEED, 0.5, 161, wavelengths=tuple(WAVES.values()),
                                seed=3)  # fmt: skip
    for k, f in enumerate(frames):
        tifffile.imwrite(d / "raw" / f"frame_{k:04d}.tif", f)
    camp = Campaign.load(_config(d).save(d / "campaign.toml"), progress=False)
    return camp, camp.run()


def test_the_waves_are_the_leading_modes_at_their_speed(processed):
    import xarray as xr

    camp, res = processed
    prof = res.spod["uncorrected"]
    assert prof["pairs"] == 160 and prof["blocks"] == 9 and "warning" not in prof
    f = prof["f"]
    for b in WAVES:
        i = int(np.flatnonzero(np.isclose(prof["mode_f"], f[b]))[0])
        # one structure at the wave's frequency, passing at the pattern's speed
        assert prof["leading_fraction"][b] > 0.95
        assert prof["phase_speed"][i] == pytest.approx(SPEED, rel=0.003)
        assert prof["energy_low"][b] > prof["second_high"][b]
    # the pattern's harmonics stand above the floor up to the Nyquist frequency, if not there
    assert not prof["f_noise"] < 0.5
    with xr.open_dataset(res.out_dir / "spod_uncorrected.nc", engine="h5netcdf") as ds:
        assert ds["energy"].dims == ("f", "mode") and ds.attrs["blocks"] == 9
        assert ds["phi_u_re"].dims == ("mode_f", "kept", "y", "x")
        norm = sum(
            np.nansum(ds[f"phi_{c}_{p}"].values.astype(np.float64) ** 2, axis=(2, 3))
            for c in "uv"
            for p in ("re", "im")
        )
        np.testing.assert_allclose(norm, 1.0, rtol=1e-5)  # float32 in the file
        np.testing.assert_allclose(ds["phase_speed"].values, prof["phase_speed"])
    summary = json.loads((res.out_dir / "summary.json").read_text())
    assert summary["runs"]["uncorrected"]["spod"]["pairs"] == 160
    # the report's section and figure (the report itself needs a calibration and [flow] dt)
    sec = spod_pass.report_section(camp, res)
    assert "Spectral POD of 160 consecutive pairs" in sec.text and "Warning" not in sec.text
    png, _ = sec.figures[0]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _from_the_files(res, ids=None):
    """rspiv.spod of the written field files, about the run's statistics."""
    acc = res.accumulators["uncorrected"]
    prof = res.spod["uncorrected"]
    ids = sorted(acc.pair_ids) if ids is None else ids
    files = [res.out_dir / "fields" / "uncorrected" / f"pair_{i:06d}.nc" for i in ids]
    read = [read_field(f, acc.shape, "uncorrected") for f in files]
    u, v, ok = (np.array([r[j] for r in read]) for j in range(3))
    domain = np.zeros(acc.shape, bool)
    domain[prof["rows"]] = acc.count[prof["rows"]] >= 2
    p = res.analyses["uncorrected"].profile
    assert p["sign_x"] == 1 and p["sign_y"] == -1  # no wall: y up from the lower edge
    freqs = np.searchsorted(prof["f"], prof["mode_f"])
    r = spod(u, v, ok.astype(bool), segment=SEGMENT, n_modes=2, frequencies=freqs,
             mean_u=acc.mean_u, mean_v=acc.mean_v, domain=domain, pair_ids=ids)  # fmt: skip
    return r, domain


def test_the_pass_is_rspiv_spod_of_the_written_fields(processed):
    _, res = processed
    prof = res.spod["uncorrected"]
    r, domain = _from_the_files(res)
    assert prof["vectors"] == domain.sum()
    np.testing.assert_allclose(prof["energy"], r.energy, rtol=1e-10, atol=1e-12)
    keep = prof["rows"]
    np.testing.assert_allclose(prof["phi_u"], r.modes_u[:, :, keep], atol=1e-10)
    np.testing.assert_allclose(prof["phi_v"], -r.modes_v[:, :, keep], atol=1e-10)  # v up


def test_a_series_on_disk_in_slices_is_the_same(processed, monkeypatch):
    camp, res = processed
    run = res.context.runs[0]
    before = res.spod[run.name]
    monkeypatch.setattr(spod_pass, "MEMORY_BYTES", 0)  # float32 on disk
    monkeypatch.setattr(spod_pass, "BLOCK_BYTES", 48 * 160 * 100)  # slices of 100 values
    camp.config.output.netcdf = False  # the fixture's files stay
    try:
        prof = spod_pass.write_outputs(camp, res, run, res.analyses[run.name])
    finally:
        camp.config.output.netcdf = True
    assert not list(res.out_dir.glob(".spod-*"))  # the temporary series is gone
    scale = before["energy"].max()
    np.testing.assert_allclose(prof["energy"], before["energy"], rtol=1e-4, atol=1e-6 * scale)
    np.testing.assert_allclose(prof["phi_u"][:, 0], before["phi_u"][:, 0], atol=1e-4)


def test_a_missing_field_file_splits_the_series_and_is_said(processed, tmp_path):
    camp, res = processed
    run = res.context.runs[0]
    path = camp.field_writer().path(run.name, 100)
    kept = path.read_bytes()
    path.unlink()
    camp.config.output.netcdf = False
    try:
        prof = spod_pass.write_outputs(camp, res, run, res.analyses[run.name])
        camp.config.statistics.spod_segment = 128  # no block of 128 in either series
        with pytest.raises(InvalidInputError, match="at least 2 are needed") as exc:
            spod_pass.write_outputs(camp, res, run, res.analyses[run.name])
        assert "\n" not in str(exc.value)
    finally:
        camp.config.output.netcdf = True
        camp.config.statistics.spod_segment = SEGMENT
        path.write_bytes(kept)
    assert "1 of 160 pairs have no field file (first: pair 100)" in prof["warning"]
    assert "2 unbroken series (the longest 100 pairs)" in prof["warning"]
    # blocks of 0-99 and 101-159: 5 + 2
    assert prof["blocks"] == 7 and "only 7 blocks" in prof["warning"]
    ids = [i for i in range(160) if i != 100]
    r, _ = _from_the_files(res, ids)
    np.testing.assert_allclose(prof["energy"], r.energy, rtol=1e-10, atol=1e-12)


def test_a_recording_without_structures_is_said(tmp_path):
    """Particles convected at a uniform speed: the fluctuations are the PIV's noise, and the
    pass says that nothing coherent stands out rather than offer modes."""
    (tmp_path / "raw").mkdir()
    for k, f in enumerate(convected_sequence((192, 256), SPEED, 0.0, 81, seed=5)):
        tifffile.imwrite(tmp_path / "raw" / f"frame_{k:04d}.tif", f)
    cfg = _config(tmp_path)
    cfg.statistics.spod_segment = 16
    res = Campaign.load(cfg.save(tmp_path / "c.toml"), progress=False).run()
    prof = res.spod["uncorrected"]
    assert prof["blocks"] == 9
    assert "nothing coherent stands out" in prof["warning"]
    # the PIV's noise is the whole of it: within twice its floor at every frequency
    assert prof["f_noise"] == 0.0 and "the decomposition is of the noise" in prof["warning"]
    assert prof["leading_fraction"][1:].max() < 0.5


def test_si_units_follow_the_pair_interval(processed):
    camp, res = processed
    run = res.context.runs[0]
    an = res.analyses[run.name]
    px = res.spod[run.name]
    m_per_px, dt = 2e-5, 1e-3
    profile = {**an.profile, "si": True, "m_per_px": m_per_px, "k": m_per_px / dt}
    camp.config.flow.dt, camp.config.output.netcdf = dt, False
    try:
        si = spod_pass.write_outputs(camp, res, run, dc.replace(an, profile=profile))
    finally:
        camp.config.flow.dt, camp.config.output.netcdf = 0.0, True
    np.testing.assert_allclose(si["f"], px["f"] / dt)
    np.testing.assert_allclose(si["phase_speed"], px["phase_speed"] * m_per_px / dt)
    # the energy in (m/s)^2 whichever the units: sum lambda df
    e_px = px["total"].sum() * px["f"][1] * (m_per_px / dt) ** 2
    np.testing.assert_allclose(si["total"].sum() * si["f"][1], e_px, rtol=1e-12)


def test_spod_keys_are_checked(tmp_path):
    base = _config(tmp_path)
    text = base.save(tmp_path / "c.toml").read_text()
    cfg = load_campaign_config(tmp_path / "c.toml")
    assert cfg.statistics.spod and cfg.statistics.spod_segment == SEGMENT
    for old, new, match in (
        ('pairing = "sequential"', 'pairing = "pairs"', "time-resolved recording"),
        ("fields = true", "fields = false", "needs each pair's fields"),
        ("spod_segment = 32", "spod_segment = 33", "even"),
        ("spod_modes = 2", "spod_modes = 0", ">= 1"),
        ("spod_frequencies = 6", "spod_frequencies = 65", "<= 64"),
        ("spod_height = 0.0", "spod_height = -1.0", ">= 0"),
    ):
        assert old in text
        (tmp_path / "bad.toml").write_text(text.replace(old, new))
        with pytest.raises(InvalidInputError, match=match) as exc:
            load_campaign_config(tmp_path / "bad.toml")
        assert "\n" not in str(exc.value)
