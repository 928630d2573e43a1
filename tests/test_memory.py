"""numpy's huge pages off while a campaign runs (:mod:`rspiv.memory`): the setting inside a
campaign's pair loop and in a Dask task, restored after, and a user's environment variable
kept; and nothing of a campaign's preparation left in reference cycles for the pair loop."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import tifffile
from rspiv.campaign import pair as pair_work
from rspiv.campaign.runner import Campaign
from rspiv.campaign_config import CampaignConfig, ImagesConfig
from rspiv.memory import _multiarray, numpy_huge_pages
from rspiv.synth import particle_sequence

get = getattr(_multiarray, "_get_madvise_hugepage", None)
pytestmark = pytest.mark.skipif(get is None, reason="this numpy has no huge-page setting")


def _small_campaign(tmp_path) -> CampaignConfig:
    """Two sequential 128 x 192 pairs of a uniform 2 px shift, one 32 px pass, no wall."""
    for k, f in enumerate(particle_sequence((128, 192), lambda x, y: (2.0 + 0 * y, 0 * y), 3,
                                            seed=3)):  # fmt: skip
        tifffile.imwrite(tmp_path / f"frame_{k:03d}.tif", f)
    cfg = CampaignConfig()
    cfg.images = ImagesConfig(glob=str(tmp_path / "frame_*.tif"), pairing="sequential")
    cfg.correction.method = "none"
    cfg.correction.compare_uncorrected = False
    cfg.calibration.monte_carlo_samples = 0
    cfg.wall.enabled = False
    cfg.piv.passes = [(32, 32)]
    cfg.output.dir = tmp_path / "out"
    cfg.output.report = False
    return cfg


def test_the_setting_is_turned_and_restored(monkeypatch):
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    before = get()
    for wanted in (False, True):
        with numpy_huge_pages(wanted):
            assert get() is wanted
        assert get() is before
    with pytest.raises(RuntimeError), numpy_huge_pages(not before):
        assert get() is (not before)
        raise RuntimeError("a failing run")
    assert get() is before  # restored on the way out of a failure too
    # a user who set numpy's own variable keeps what it says
    monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")
    with numpy_huge_pages(not before):
        assert get() is before


def test_a_campaigns_pairs_run_without_huge_pages(tmp_path, monkeypatch):
    """Every frame a campaign reads (preparation and pair loop) is read with numpy's huge
    pages off; the caller's setting is back after the run."""
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    cfg = _small_campaign(tmp_path)
    seen = []
    read = pair_work.read_frame
    monkeypatch.setattr(pair_work, "read_frame",
                        lambda p, i, t=0: seen.append(get()) or read(p, i, t))  # fmt: skip
    before = get()
    with numpy_huge_pages(True):
        res = Campaign(cfg, progress=False, out_dir=tmp_path / "out").run()
        assert get() is True  # the caller's setting, back
    assert get() is before
    assert res.n_done == 2 and seen and not any(seen)
    assert np.isfinite(res.accumulators["uncorrected"].mean_u).any()


def test_a_dask_task_runs_without_huge_pages(monkeypatch):
    from rspiv.campaign.executors import dask as dask_exec

    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    seen = []
    monkeypatch.setattr(dask_exec, "_process_chunk", lambda *a: seen.append(get()) or "done")
    with numpy_huge_pages(True):
        assert dask_exec.process_chunk(None, []) == "done"
        assert get() is True
    assert seen == [False]


def test_the_preparation_leaves_no_frames_in_reference_cycles(tmp_path):
    """The preparation's frames, backgrounds and pilot fields were held in reference cycles
    until Python's collector ran, at 47 MP about 1 GB more through the pair loop (tracemalloc:
    the backgrounds, the target image and the pilot's accumulators): ``Campaign.prepare``
    collects them, so no array is found in garbage right after it (a collection then frees
    no numpy memory)."""
    import tracemalloc

    cfg = _small_campaign(tmp_path)
    cfg.preprocess.background = "min"
    camp = Campaign(cfg, progress=False, out_dir=tmp_path / "out")
    gc.collect()
    gc.disable()  # no automatic collection in between, as a long preparation may have none
    tracemalloc.start()
    try:
        camp.prepare()
        before = tracemalloc.get_traced_memory()[0]
        gc.collect()
        freed = before - tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
        gc.enable()
    frame = 128 * 192 * 4  # one float32 frame
    assert freed < frame, freed
