"""The recording check (``rspiv.check_recording``, ``rspiv check``) against synthetic particle
images whose density, diameter, displacement, noise and lighting the generator sets."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.recording import MIN_PARTICLES_PER_WINDOW, SIZES, check_recording
from rspiv.synth.particles import particle_pair

SHAPE = (512, 768)


def _pair(displacement=(6.0, 1.0), density=0.02, diameter=2.5, noise=0.05, seed=3, **kw):
    return particle_pair(SHAPE, displacement, density, diameter, noise, seed, **kw)


@pytest.mark.parametrize("diameter", [1.5, 2.5, 3.5])
@pytest.mark.parametrize("density", [0.005, 0.01, 0.02, 0.04])
def test_the_density_is_the_generators_or_a_lower_bound(diameter, density):
    """Within 10 % of the particles drawn per px; where the images overlap or hide in the
    noise the check says it is a lower bound, and then it is not above the truth."""
    a, b = particle_pair((768, 768), (4.0, 1.0), density, diameter, 0.05, seed=5)
    r = check_recording(a, b)
    if r.density_bound:
        assert r.density <= 1.1 * density
        assert any("lower bound" in w for w in r.warnings.values())
    else:
        assert abs(r.density / density - 1.0) < 0.1, r.density
    assert r.source_density == pytest.approx(r.density * np.pi * np.mean(r.diameter) ** 2 / 4)


def test_sparse_images_are_measured_not_bounded():
    """The usual seeding of a large-sensor recording (0.01-0.02 particles/px of 2.5 px) is
    counted, not only bounded."""
    for density in (0.01, 0.02):
        r = check_recording(*_pair(density=density))
        assert not r.density_bound
        assert r.lit_fraction == 1.0


def test_the_recommendation_follows_the_rules():
    """The first window is the smallest size at least four times the largest displacement, the
    final window the smallest holding ten particle images of the true density, halving in
    between; the displacement and diameter are the generator's."""
    density = 0.02
    r = check_recording(*_pair(displacement=(9.0, -2.0), density=density))
    assert r.correlates and r.median_displacement == pytest.approx((9.0, -2.0), abs=0.02)
    assert r.p99_displacement[0] == pytest.approx(9.0, abs=0.1)
    assert np.all(np.abs(np.array(r.diameter) - 2.7) < 0.3)  # 2.5 px, pixel-integrated
    first, final = r.passes[0][0], r.passes[-1][0]
    assert first == min(s for s in SIZES if s >= 4 * 9.0)  # 48
    true_n = {s: density * s * s for s in SIZES}
    assert true_n[final] >= 0.9 * MIN_PARTICLES_PER_WINDOW
    smaller = max(s for s in SIZES if s < final)
    assert true_n[smaller] < 1.1 * MIN_PARTICLES_PER_WINDOW
    assert r.passes == [(48, 48), (24, 24)]
    assert r.deformation == "offset" and r.gradient < 0.01
    assert r.per_window["24x24"] == pytest.approx(r.density * 576)
    assert not r.warnings


def test_a_shear_asks_for_deformation_and_small_displacements_for_a_longer_dt():
    """du/dy of 0.06 px/px moves the window's rows 6 % of it apart: deform the windows (Keane &
    Adrian's 5 %); displacements under a tenth of the final window are said, with the factor
    of a pulse separation that puts them at a quarter of it."""
    r = check_recording(*_pair(displacement=lambda x, y: (0.06 * (y - 256.0), 0.0 * y)))
    assert r.gradient == pytest.approx(0.06, rel=0.2)  # the coarse pass's noise adds
    assert r.deformation == "symmetric"
    assert any("deform the windows" in w for w in r.warnings.values())
    r = check_recording(*_pair(displacement=(1.0, 0.2)))
    assert r.deformation == "offset"
    final = r.passes[-1][0]
    said = r.warnings["displacement"]
    assert "pulse separation" in said
    assert f"up to {final / 4 / r.p99_displacement[0]:.0f} times" in said


def test_the_sensor_is_checked():
    """Saturated particle images, particle images in the noise and a background that varies
    more than their signal are said, frame by frame."""
    a, b = _pair()
    sat = check_recording(*(np.minimum(f, 1500).astype(np.uint16) for f in (a, b)))
    assert sat.saturated[0] == 0.0  # 1500 is not a full scale
    bright = [np.minimum(f.astype(np.int64) * 2, 4095).astype(np.uint16) for f in (a, b)]
    r = check_recording(*bright)
    assert r.saturated[0] > 0.3 and any("full scale" in w for w in r.warnings.values())
    clean = check_recording(a, b)
    # 12-bit frames: where particle images overlap a few reach 4095
    assert max(clean.saturated) < 0.01 and not clean.warnings
    noisy = check_recording(*_pair(noise=0.4))
    assert any("above the camera noise" in w for w in noisy.warnings.values())
    ramp = np.linspace(0, 3000, SHAPE[1])[None, :]
    glare = [(f + ramp).clip(0, 65535).astype(np.uint16) for f in (a, b)]
    r = check_recording(*glare)
    assert r.background_spread[0] > 2000
    assert any("background varies" in w for w in r.warnings.values())


def test_an_unlit_part_is_found_and_a_region_proposed():
    a, b = _pair()
    a[:, 384:] = 0
    b[:, 384:] = 0
    r = check_recording(a, b)
    assert r.lit_fraction == pytest.approx(0.5, abs=0.05)
    assert r.lit_box[0] == 0 and r.lit_box[2] == 384
    assert any("region of interest" in w for w in r.warnings.values())
    assert abs(r.density / 0.02 - 1.0) < 0.1  # the lit part's density


def test_frames_that_do_not_correlate_get_no_recommendation():
    a, _ = _pair(seed=1)
    _, b = _pair(seed=2)
    r = check_recording(a, b)
    assert not r.correlates and r.passes is None and r.deformation is None
    assert any("do not correlate" in w for w in r.warnings.values())
    assert abs(r.density / 0.02 - 1.0) < 0.1  # the particle images are still counted


def test_the_campaigns_passes_are_checked():
    """Windows under 7 particle images, and a first window that keeps under 10 pairs at the
    largest displacement or whose displacement passes a third of it, are said; the paper's
    passes at the demo's seeding and displacement (20 px in 64 px windows) are not."""
    r = check_recording(*_pair(displacement=(24.0, 0.0)), passes=[(64, 64), (32, 32), (32, 8)])
    assert "32 x 8 px windows hold 5." in r.warnings["windows_32x8"]  # 0.02 x 256
    assert "one-quarter rule" in r.warnings["quarter_rule"]
    assert r.per_window["32x8"] == pytest.approx(r.density * 256)
    assert r.passes[0][0] == min(s for s in SIZES if s >= 4 * r.p99_displacement[0])
    sparse = check_recording(*_pair(displacement=(12.0, 0.0), density=0.004), passes=[(48, 48)])
    assert "pairs stay in a window" in sparse.warnings["quarter_rule"]  # 9.2 * 0.75 = 6.9
    ok = check_recording(
        *_pair(displacement=(20.0, 1.5), density=0.03), passes=[(64, 64), (32, 32), (32, 8)]
    )
    assert "quarter_rule" not in ok.warnings and "windows_32x8" not in ok.warnings
    assert ok.passes[0] == (96, 96)  # the recommendation keeps to the one-quarter rule


def test_bad_input_is_refused_in_one_line():
    a, b = _pair()
    for args, match in [
        ((a, b[:, :-1]), "one shape and dtype"),
        ((a, b.astype(np.float32)), "one shape and dtype"),
        ((a[:20, :20], b[:20, :20]), "too small"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            check_recording(*args)
    with pytest.raises(InvalidInputError, match="differs in shape"):
        check_recording(a, b, mask=np.zeros((10, 10), bool))
    with pytest.raises(InvalidInputError, match=">= 4"):
        check_recording(a, b, passes=[(2, 2)])
    fa, fb = a.astype(np.float32), b.astype(np.float32)
    fa[100, 200] = np.nan
    with pytest.raises(InvalidInputError, match="not finite") as exc:
        check_recording(fa, fb)
    assert "\n" not in str(exc.value)
    blank = np.zeros(SHAPE, np.uint8)  # every block at its floor: nothing counted, no panic
    r = check_recording(blank, blank)
    assert r.density == 0.0 and any("nothing to count" in w for w in r.warnings.values())


def test_the_command(tmp_path, capsys):
    a, b = _pair()
    pa, pb = tmp_path / "a.tif", tmp_path / "b.tif"
    tifffile.imwrite(pa, a)
    tifffile.imwrite(pb, b)
    out = tmp_path / "check.json"
    assert main(["check", str(pa), str(pb), "--passes", "64x64,32x8", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "recommended passes: 48x48 -> 24x24" not in text  # 6 px: 32 px first windows
    assert "recommended passes: 32x32 -> 24x24, deformation offset" in text
    assert "warning: 32 x 8 px windows hold" in text
    d = json.loads(out.read_text())
    assert d["passes"] == [[32, 32], [24, 24]] and d["correlates"] is True
    tifffile.imwrite(pb, b[:, :-3])
    assert main(["check", str(pa), str(pb)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(pa) in err and "one shape" in err


def test_the_drift_over_a_run_is_said():
    """Pairs spread over a run: the seeding thinning at one pair, frame B's brightness and
    frame A's background drifting are each said once; steady pairs say nothing."""
    from rspiv.recording_drift import check_drift

    def pairs(drift: bool):
        for k in range(4):
            density = 0.008 if (drift and k == 2) else 0.02
            a, b = _pair(density=density, seed=10 + k)
            if drift:
                a = a + np.uint16(500 * k)  # the background creeping up
                b = (b.astype(np.float64) * (1.0 + 0.4 * k)).clip(0, 4095).astype(np.uint16)
            yield 100 * k, a, b

    steady = check_drift(pairs(False), passes=[(64, 64), (32, 8)])
    assert steady.pairs == [0, 100, 200, 300] and not steady.warnings
    assert all(abs(d / 0.02 - 1) < 0.1 for d in steady.density)
    r = check_drift(pairs(True), passes=[(64, 64), (32, 8)])
    assert "at pair 200" in r.warnings["seeding"] and "32 x 8 px windows" in r.warnings["seeding"]
    assert r.density[2] == pytest.approx(0.008, rel=0.1)
    assert "frame B's particle images vary in brightness" in r.warnings["signal_B"]
    assert "background_window" in r.warnings["background_A"]
    assert r.background[3][0] - r.background[0][0] == pytest.approx(1500, abs=40)
    assert set(r.warnings) == {"seeding", "signal_B", "background_A"}
    with pytest.raises(InvalidInputError, match="at least one pair"):
        check_drift(iter(()))


def test_the_command_on_a_campaign(tmp_path, capsys):
    """``rspiv check campaign.toml``: the first pair with the campaign's passes, then pairs
    spread over the run."""
    import dataclasses

    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    d = tmp_path / "camp"
    synth_campaign(d, scene=dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=4))
    out = tmp_path / "c.json"
    assert main(["check", str(d / "campaign.toml"), "--samples", "3", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "recommended passes" in text and "particle images per window: " in text
    assert "32x8" in text  # the campaign's own passes are checked
    assert "pairs spread over the run: 0, 2, 3" in text
    data = json.loads(out.read_text())
    assert data["drift"]["pairs"] == [0, 2, 3] and "first" in data
    assert not data["drift"]["warnings"]
    # what the campaign will cost (rspiv.campaign.estimate): one PIV per run and pair
    est = data["estimate"]
    assert est["pairs"] == 4 and est["runs"] == ["P3 + rotation, Method II", "uncorrected"]
    assert est["per_pair_s"] == pytest.approx(est["condition_s"] + 2 * est["piv_s"], rel=1e-9)
    assert est["hours"] == pytest.approx(4 * est["per_pair_s"] / 3600, rel=1e-9)
    a = tifffile.imread(sorted((d / "raw").glob("*.tif"))[0])
    cols = (a.shape[1] - 32) // 16 + 1  # the 32 x 8 px last pass at half overlap
    rows = (a.shape[0] - 8) // 4 + 1
    assert est["vectors"] == pytest.approx(rows * cols, rel=0.02)
    assert est["fields_gb"] == pytest.approx(4 * 2 * est["vectors"] * 17 / 1e9, rel=1e-9)
    assert "the campaign (an estimate):" in text and "h on this machine" in text


def test_a_band_of_thin_seeding_is_found():
    """The bottom rows with a third of the seeding (particles thinning at a wall): the band of
    block rows is said with its particle images per window; a uniform frame says nothing."""
    a, b = _pair(density=0.03, seed=21)
    sa, sb = _pair(density=0.01, seed=22)
    a[448:], b[448:] = sa[448:], sb[448:]
    r = check_recording(a, b, passes=[(64, 64), (32, 8)])
    said = r.warnings["seeding_rows"]
    assert "rows y 448-512 px" in said and "32 x 8 px windows hold" in said
    share = float(said.split("thins to ")[1].split(" %")[0])
    assert 25 <= share <= 45  # a third of the frame's
    assert "seeding_columns" not in r.warnings
    assert not any(k.startswith("seeding") for k in check_recording(*_pair()).warnings)
    # said only where it fails the smallest window: 64 x 32 px windows hold enough there
    assert "seeding_rows" not in check_recording(a, b, passes=[(64, 32)]).warnings
    assert "seeding_rows" in check_recording(a, b).warnings  # a third: under half


def test_a_campaign_checks_its_run_before_the_piv(tmp_path):
    """The campaign's preparation checks its first pair and ``[images] check_pairs`` pairs
    spread over the run: one pair's frame A recorded at 40 % of the laser energy is said, in
    the campaign's info (``summary.json``); ``check_pairs = 0`` checks the first pair only."""
    import dataclasses

    from rspiv.campaign import Campaign
    from rspiv.campaign_config import load_campaign_config
    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    d = tmp_path / "camp"
    synth_campaign(d, scene=dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=4))
    cfg = load_campaign_config(d / "campaign.toml")
    assert cfg.images.check_pairs == 5
    cfg.calibration.monte_carlo_samples = 0
    cfg.correction.compare_uncorrected = False
    last = sorted((d / "raw").glob("*.tif"))[-2]  # frame A of the last pair
    f = tifffile.imread(last)
    tifffile.imwrite(last, (f.astype(np.float64) * 0.4).astype(f.dtype))
    toml = tmp_path / "c.toml"
    cfg.save(toml)
    said = []
    camp = Campaign.load(toml, progress=False, out_dir=tmp_path / "out", log=said.append)
    camp.prepare()
    drift = camp.info["recording_drift"]
    assert drift["pairs"] == [0, 1, 2, 3]
    assert "frame A's particle images vary in brightness" in camp.info["recording_warnings"][
        "drift_signal_A"
    ]
    assert "drift_signal_B" not in camp.info["recording_warnings"]
    assert any(m.startswith("recording over the run: 4 pairs") for m in said)
    cfg.images.check_pairs = 0
    cfg.save(toml)
    camp = Campaign.load(toml, progress=False, out_dir=tmp_path / "out0", log=said.append)
    camp.prepare()
    assert "recording" in camp.info and "recording_drift" not in camp.info


def test_noise_on_a_clipped_background_is_not_counted():
    """A background clipped at zero and noised again (a camera's offset removed, then its
    read noise): the quantiles read the noise low, and the signal's share keeps the noise's
    maxima out of the count; a glare line adds its own row of blocks, not the frame's
    density."""
    a, b = particle_pair((768, 1024), (8.0, 0.5), 0.02, 2.5, 0.05, seed=4)
    rng = np.random.default_rng(0)
    glare = 1500 * np.exp(-0.5 * ((np.arange(768)[:, None] - 600) / 4.0) ** 2)
    frames = [(f + glare + rng.normal(0, 30, f.shape)).clip(0, 4095).astype(np.uint16)
              for f in (a, b)]  # fmt: skip
    r = check_recording(*frames)
    assert abs(r.density / 0.02 - 1.0) < 0.1, r.density


def test_a_region_of_interest_masks_the_rest():
    """``roi_mask``: outside ``(x0, y0, x1, y1)`` excluded, added to a mask; none: the mask."""
    from rspiv.recording import roi_mask

    m = roi_mask(None, (10, 5, 30, 20), (40, 50))
    assert m.shape == (40, 50) and not m[5:20, 10:30].any()
    assert m.sum() == 40 * 50 - 15 * 20
    own = np.zeros((40, 50), bool)
    own[10, 12] = True
    both = roi_mask(own, (10, 5, 30, 20), (40, 50))
    assert both[10, 12] and both.sum() == m.sum() + 1
    assert roi_mask(own, None, (40, 50)) is own


def test_frame_a_given_twice_is_said_not_measured():
    """The same frame twice correlates to 1 at zero lag: said in one line, no displacement, no
    passes and no advice on the pulse separation (a first version advised 6000 times as long)."""
    a, _ = _pair()
    r = check_recording(a, a.copy())
    assert not r.correlates and r.passes is None
    assert "the same pixels" in r.warnings["same_frames"] and "displacement" not in r.warnings
    assert abs(r.density / 0.02 - 1.0) < 0.1  # the particle images are still counted
