"""Time-resolved recordings: a campaign's frames paired sequentially (``[images] pairing``).

A high-speed camera records single frames at a fixed rate; frames k and k + frame_gap form a
pair. The ground truth is :func:`rspiv.synth.particle_sequence`: particles moving at a known
displacement per frame interval along x that varies with y (exact for every gap).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import tifffile
from rspiv.campaign import Campaign, PairSpec
from rspiv.campaign import pair as pair_work
from rspiv.campaign_config import CampaignConfig, ImagesConfig, load_campaign_config
from rspiv.errors import InvalidInputError
from rspiv.synth import particle_sequence

SHAPE = (256, 384)
FRAMES = 6


def per_frame(x, y):
    """Displacement per frame interval (px): along x, 2 px at the top to 3 px at the bottom."""
    return 2.0 + y / 256.0, 0.0 * y


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("tr")
    for k, f in enumerate(particle_sequence(SHAPE, per_frame, FRAMES, seed=5)):
        tifffile.imwrite(d / f"frame_{k:03d}.tif", f)
    return d


def _config(d, out, **images) -> CampaignConfig:
    cfg = CampaignConfig()
    cfg.images = ImagesConfig(glob=str(d / "frame_*.tif"), **images)
    cfg.correction.method = "none"
    cfg.correction.compare_uncorrected = False
    cfg.calibration.monte_carlo_samples = 0
    cfg.wall.enabled = False
    cfg.output.dir = out
    cfg.output.report = False
    return cfg


def _run(cfg, out):
    camp = Campaign(cfg, progress=False, out_dir=out)
    return camp, camp.run()


def test_frame_pairs():
    seq = ImagesConfig(pairing="sequential")
    assert seq.frame_pairs(5, "x") == [(0, 1), (1, 2), (2, 3), (3, 4)]
    seq = ImagesConfig(pairing="sequential", frame_gap=2, pair_step=2)
    assert seq.frame_pairs(7, "x") == [(0, 2), (2, 4), (4, 6)]
    seq = ImagesConfig(pairing="sequential", frame_gap=3, max_pairs=2)
    assert seq.frame_pairs(10, "x") == [(0, 3), (1, 4)]
    with pytest.raises(InvalidInputError, match="x: 3 frame.*frame_gap = 3 needs at least 4"):
        ImagesConfig(pairing="sequential", frame_gap=3).frame_pairs(3, "x")
    assert ImagesConfig().frame_pairs(4, "x") == [(0, 1), (2, 3)]
    with pytest.raises(InvalidInputError, match='x: 5 frames; pairs .*pairing = "sequential"'):
        ImagesConfig().frame_pairs(5, "x")
    # the pages of one stack: an odd last page is left out
    assert ImagesConfig().frame_pairs(5, "x", odd_ok=True) == [(0, 1), (2, 3)]


def test_config_keys(tmp_path):
    (tmp_path / "a.tif").write_bytes(b"")
    head = '[images]\nglob = "*.tif"\n'
    tail = '[correction]\nmethod = "none"\n'

    def load(images):
        p = tmp_path / "c.toml"
        p.write_text(head + images + tail, encoding="utf-8")
        return load_campaign_config(p)

    im = load('pairing = "Sequential"\nframe_gap = 2\npair_step = 3\n').images
    assert (im.pairing, im.frame_gap, im.pair_step) == ("sequential", 2, 3)
    # written and read back
    cfg = load('pairing = "sequential"\nframe_gap = 2\n')
    cfg.save(tmp_path / "back.toml")
    back = load_campaign_config(tmp_path / "back.toml").images
    assert (back.pairing, back.frame_gap, back.pair_step) == ("sequential", 2, 1)
    assert load("").images.pairing == "pairs"
    refused = {
        'pairing = "odd"\n': "[images].pairing: expected one of 'pairs', 'sequential'",
        "frame_gap = 2\n": '[images].frame_gap: needs [images] pairing = "sequential"',
        'pairing = "pairs"\npair_step = 2\n': "[images].pair_step: needs [images] pairing",
        'pairing = "sequential"\nframe_gap = 0\n': "[images].frame_gap: expected a value >= 1",
        'pairing = "sequential"\npair_step = 1.5\n': "[images].pair_step: expected an integer",
    }
    for text, message in refused.items():
        with pytest.raises(InvalidInputError) as e:
            load(text)
        assert message in str(e.value), str(e.value)
    p = tmp_path / "pairs.toml"
    p.write_text(
        '[images]\npairs = [["a.tif", "a.tif"]]\npairing = "sequential"\n' + tail,
        encoding="utf-8",
    )
    with pytest.raises(InvalidInputError, match=r"\[images\].pairing: .sequential. pairs the"):
        load_campaign_config(p)


def test_frame_cache_reads_each_frame_once(recording):
    files = sorted(str(f) for f in recording.glob("frame_*.tif"))
    seq = [PairSpec(k, files[k], files[k + 1]) for k in range(FRAMES - 1)]
    cache = pair_work.FrameCache.for_pairs(seq)
    assert cache is not None and cache.frames == 2
    for p in seq:
        a, b = pair_work.read_checked_pair(p, SHAPE, cache)
        np.testing.assert_array_equal(a, tifffile.imread(p.a))
        np.testing.assert_array_equal(b, tifffile.imread(p.b))
        assert not a.flags.writeable and not b.flags.writeable  # one array serves two pairs
    assert (cache.reads, cache.hits) == (FRAMES, FRAMES - 2)
    # a gap of 3 frames: a frame is used again three pairs later
    gap3 = [PairSpec(k, f"f{k}", f"f{k + 3}") for k in range(7)]
    assert pair_work.FrameCache.for_pairs(gap3).frames == 4
    # pairs 1-2, 3-4: nothing is read twice, no cache
    assert pair_work.FrameCache.for_pairs([PairSpec(0, files[0], files[1])]) is None
    # over the byte limit only the frame read last is kept: pair 0's frame A is gone when
    # pair 0's frame B is read, and frame B serves pair 1
    small = pair_work.FrameCache(4, max_bytes=1)
    for p in seq[:2]:
        pair_work.read_checked_pair(p, SHAPE, small)
    assert (small.reads, small.hits) == (3, 1)
    pair_work.read_checked_pair(seq[0], SHAPE, small)
    assert (small.reads, small.hits) == (5, 1)


@pytest.mark.parametrize("gap", [1, 2])
def test_sequential_campaign_measures_the_frame_gap(recording, tmp_path, gap, monkeypatch):
    """Frames k and k + gap: every frame used, each pair's displacement gap times the
    displacement per frame, every frame read once by the background pass and once by the pair
    loop; summary.json says how the pairs were formed."""
    reads = []
    read = pair_work.read_frame
    monkeypatch.setattr(pair_work, "read_frame", lambda p, i, t=0: reads.append(p) or read(p, i, t))
    out = tmp_path / "out"
    cfg = _config(recording, out, pairing="sequential", frame_gap=gap)
    camp, res = _run(cfg, out)
    assert res.n_done == FRAMES - gap and not res.skipped
    # the frames' shape (frame 0), the background pass, the check of the first two pairs'
    # displacements (gap 1: frames 0, 1, 2; gap 2: 0, 2, 1, 3), the particle images' size on
    # pair 0, the recording's drift on [images] check_pairs = 5 pairs spread over the run, the
    # screen's pilot pairs, the pair loop (without the cache: 1 + 10 + 4 + 2 + 10 + 8 + 10 for
    # gap 1)
    drift = 2 * min(cfg.images.check_pairs, FRAMES - gap)
    pilot = 2 * len(camp.info["screen"]["pilot_pairs"])
    assert pilot == 8
    assert len(reads) == 1 + FRAMES + (2 + gap) + 2 + drift + pilot + FRAMES, sorted(reads)
    assert [(p.a[-7:-4], p.b[-7:-4]) for p in camp.pairs()] == [
        (f"{k:03d}", f"{k + gap:03d}") for k in range(FRAMES - gap)
    ]
    acc = res.accumulators["uncorrected"]
    _, y = res.context.grid()
    truth = gap * per_frame(0.0, y)[0]
    err = acc.mean_u - truth
    inner = np.zeros(err.shape, bool)
    inner[2:-2, 2:-2] = True  # away from the frame's edges
    # the mean of 5 or 4 pairs of 32 x 8 px windows (measured: median 0.007 / 0.010 px, 99th
    # percentile 0.026 / 0.046 px; a wrong gap would be off by 2 px or more)
    assert np.nanmedian(np.abs(err[inner])) < 0.02, np.nanmedian(np.abs(err[inner]))
    assert np.nanpercentile(np.abs(err[inner]), 99) < 0.08
    assert np.nanmax(np.abs(acc.mean_v[inner])) < 0.1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pairing"]["frame_gap"] == gap
    assert summary["pairing"]["description"] == (
        f"frames k and k + {gap}, every frame (sequential, time-resolved)"
    )


def test_pairs_of_the_same_frames_measure_one_interval(recording, tmp_path):
    """The default pairing of the same six frames: 1-2, 3-4, 5-6, one frame interval each,
    and nothing said about the pairing."""
    out = tmp_path / "out"
    _, res = _run(_config(recording, out), out)
    assert res.n_done == FRAMES // 2
    _, y = res.context.grid()
    err = res.accumulators["uncorrected"].mean_u - per_frame(0.0, y)[0]
    assert np.nanmedian(np.abs(err[2:-2, 2:-2])) < 0.02
    assert "pairing" not in json.loads((out / "summary.json").read_text())


def test_sequential_pages_of_one_stack(recording, tmp_path):
    """The pages of a multi-frame TIFF pair as the files do: the same pairs, the same field."""
    files = sorted(recording.glob("frame_*.tif"))
    stack = tmp_path / "run.tif"
    tifffile.imwrite(stack, np.stack([tifffile.imread(f) for f in files]))
    cfg = _config(recording, tmp_path / "a", pairing="sequential", frame_gap=2)
    cfg.images.glob = None
    cfg.images.multiframe = stack
    camp, res = _run(cfg, tmp_path / "a")
    assert [(p.frame_a, p.frame_b) for p in camp.pairs()] == [(0, 2), (1, 3), (2, 4), (3, 5)]
    assert pair_work.FrameCache.for_pairs(camp.pairs()).frames == 3
    ref_cfg = _config(recording, tmp_path / "b", pairing="sequential", frame_gap=2)
    _, ref = _run(ref_cfg, tmp_path / "b")
    np.testing.assert_array_equal(
        res.accumulators["uncorrected"].mean_u, ref.accumulators["uncorrected"].mean_u
    )


def _field_files(out, run):
    import xarray as xr

    files = sorted((out / "fields" / run).glob("pair_*.nc"))
    return [xr.load_dataset(f, engine="h5netcdf") for f in files], files


def test_fields_of_every_pair(recording, tmp_path):
    """[output] fields: one file per pair and run, whose valid vectors average to the
    campaign's statistics; turned on for a finished campaign, the pairs without a file are
    said."""
    out = tmp_path / "out"
    cfg = _config(recording, out, pairing="sequential")
    cfg.flow.dt = 1e-3
    _, plain = _run(cfg, out)
    assert not (out / "fields").exists()
    cfg.output.fields = True
    said = []
    camp = Campaign(cfg, progress=False, out_dir=out, log=said.append)
    res = camp.run()  # resumed: every pair finished, none has its file
    assert res.n_resumed == FRAMES - 1
    assert any(f"{FRAMES - 1} pair(s) finished before have no field file" in s for s in said)
    out2 = tmp_path / "out2"
    _, res = _run(cfg, out2)
    dss, files = _field_files(out2, "uncorrected")
    assert [f.name for f in files] == [f"pair_{k:06d}.nc" for k in range(FRAMES - 1)]
    gx, gy = res.context.grid()
    acc = res.accumulators["uncorrected"]
    for k, ds in enumerate(dss):
        assert ds["u"].dtype == np.float32 and ds["u"].attrs["units"] == "pix"
        assert ds.attrs["pair_id"] == k and ds.attrs["frame_b"].endswith(f"frame_{k + 1:03d}.tif")
        assert ds.attrs["dt_s"] == 1e-3 and "m_per_px" not in ds.attrs
        assert ds.attrs["frame"] == "raw image" and ds.attrs["run"] == "uncorrected"
        np.testing.assert_array_equal(ds["x"], gx[0])
        np.testing.assert_array_equal(ds["y"], gy[:, 0])
        assert {"sigma_u", "sigma_v", "valid"} <= set(ds)
        assert np.all(np.isnan(ds["u"].values[ds["valid"].values == 0]))
    valid = np.stack([ds["valid"].values for ds in dss]).astype(bool)
    np.testing.assert_array_equal(valid.sum(axis=0), acc.count)
    for comp, mean in (("u", acc.mean_u), ("v", acc.mean_v)):
        stack = np.stack([ds[comp].values.astype(np.float64) for ds in dss])
        seen = acc.count > 0
        got = np.nansum(stack, axis=0)[seen] / acc.count[seen]
        # float32 files: a relative rounding of 6e-8 per value
        np.testing.assert_allclose(got, mean[seen], rtol=1e-6, atol=1e-6)
    # the statistics do not depend on the fields being written
    np.testing.assert_array_equal(acc.mean_u, plain.accumulators["uncorrected"].mean_u)
    summary = json.loads((out2 / "summary.json").read_text())
    assert summary["timings_s"]["fields"] > 0
    assert summary["fields"]["files"] == {"uncorrected": FRAMES - 1}
    assert res.files["fields"] == out2 / "fields"


def test_a_pair_list_changed_under_the_checkpoint_is_refused(recording, tmp_path):
    """Pairs are resumed by id: the checkpoint keeps each finished pair's frames, so switching
    the pairing (pair 1: frames 2-3, then 1-2) is refused in one line, while pairs added after
    the finished ones (a recording that grew) resume."""
    out = tmp_path / "out"
    _run(_config(recording, out), out)
    with pytest.raises(InvalidInputError) as e:
        _run(_config(recording, out, pairing="sequential"), out)
    msg = str(e.value)
    assert "\n" not in msg and "the pair list changed under the checkpoint" in msg, msg
    assert "finished pair 1 is now " in msg and "frame_001.tif, " in msg and "frame_002.tif" in msg
    # a recording that grew: the first three sequential pairs, then all five
    out2 = tmp_path / "out2"
    _run(_config(recording, out2, pairing="sequential", max_pairs=3), out2)
    _, res = _run(_config(recording, out2, pairing="sequential"), out2)
    assert (res.n_resumed, res.n_done) == (3, FRAMES - 1)
    # fewer pairs than were finished: refused as well
    gone = "finished pair 2 is not among the campaign's 2 pairs"
    with pytest.raises(InvalidInputError, match=gone):
        _run(_config(recording, out2, pairing="sequential", max_pairs=2), out2)


def test_particle_sequence_is_the_pair_renderer_in_time():
    """Two frames of a recording are particle_pair's pair (the same draws, the particles at
    p -+ d/2); bad input is refused in one line."""
    from rspiv.synth import particle_pair

    seq = particle_sequence((64, 96), per_frame, 2, seed=7)
    pair = particle_pair((64, 96), per_frame, seed=7)
    for s, p in zip(seq, pair, strict=True):
        np.testing.assert_array_equal(s, p)
    for bad in (1, 2.5, "3"):
        with pytest.raises(InvalidInputError, match=f"frames must be an integer >= 2, got {bad!r}"):
            particle_sequence((64, 96), (1.0, 0.0), bad)
    with pytest.raises(InvalidInputError, match="displacement must be a callable"):
        particle_sequence((64, 96), "fast", 3)
    with pytest.raises(InvalidInputError, match="density and diameter must be > 0"):
        particle_sequence((64, 96), (1.0, 0.0), 3, diameter=0.0)


def test_shared_read_only_frames_go_through_unconditioned(recording, tmp_path):
    """With no conditioning the cached frames themselves (read-only, shared by two pairs)
    reach the PIV, here with symmetric deformation: nothing writes into them."""
    out = tmp_path / "out"
    cfg = _config(recording, out, pairing="sequential")
    cfg.preprocess.background = "none"
    cfg.preprocess.hot_pixels = 0.0
    cfg.preprocess.high_pass = 0.0
    cfg.piv.deformation = "symmetric"
    _, res = _run(cfg, out)
    assert res.n_done == FRAMES - 1 and not res.skipped
    _, y = res.context.grid()
    err = res.accumulators["uncorrected"].mean_u - per_frame(0.0, y)[0]
    assert np.nanmedian(np.abs(err[2:-2, 2:-2])) < 0.02


def test_fields_that_cannot_be_written_stop_the_run_in_one_line(recording, tmp_path, capsys):
    from rspiv.cli import main

    out = tmp_path / "out"
    cfg = _config(recording, out, pairing="sequential")
    cfg.output.fields = True
    (out / "fields").mkdir(parents=True)
    (out / "fields" / "uncorrected").write_text("a file where the run's folder goes")
    toml = cfg.save(tmp_path / "c.toml")
    assert main(["process", str(toml), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "[output] fields: cannot write " in err and "pair_000000.nc" in err, err


def test_fields_written_behind_the_pairs_keep_the_checkpoint_whole(recording, tmp_path,
                                                                    monkeypatch):
    """The local loop writes each pair's fields while the next pair is processed: a write that
    fails (pair 2's) stops the run with its error, and the checkpoint (every pair) holds only
    pairs whose files were written; every file written equals a run that waits for its disk."""
    import xarray as xr
    from rspiv.campaign.fields import FieldWriter

    out = tmp_path / "out"
    cfg = _config(recording, out, pairing="sequential")
    cfg.output.fields = True
    real = FieldWriter.write

    def failing(self, context, pair, result):
        if pair.pair_id == 2:
            raise OSError(f"[output] fields: cannot write {self.path('uncorrected', 2)}: full")
        return real(self, context, pair, result)

    monkeypatch.setattr(FieldWriter, "write", failing)
    camp = Campaign(cfg, progress=False, out_dir=out, checkpoint_every=1)
    with pytest.raises(OSError, match="pair_000002.nc: full"):
        camp.run()
    ckpt = camp.load_checkpoint(camp.prepare())
    written = {int(f.stem[5:]) for f in (out / "fields" / "uncorrected").glob("pair_*.nc")}
    assert set(ckpt["finished"]) == written == {0, 1}
    # resumed without the failure: every pair, files equal to a run that never failed
    monkeypatch.setattr(FieldWriter, "write", real)
    res = Campaign(cfg, progress=False, out_dir=out).run()
    assert res.n_done == FRAMES - 1
    ref_out = tmp_path / "ref"
    ref_cfg = _config(recording, ref_out, pairing="sequential")
    ref_cfg.output.fields = True
    _run(ref_cfg, ref_out)
    for k in range(FRAMES - 1):
        name = f"uncorrected/pair_{k:06d}.nc"
        with xr.open_dataset(out / "fields" / name, engine="h5netcdf") as a, xr.open_dataset(
            ref_out / "fields" / name, engine="h5netcdf"
        ) as b:
            np.testing.assert_array_equal(a["u"].values, b["u"].values)


def test_a_dask_chunk_records_a_pair_whose_fields_cannot_be_written(recording, tmp_path):
    from rspiv.campaign.executors.dask import process_chunk
    from rspiv.campaign.fields import FieldWriter

    out = tmp_path / "out"
    camp, res = _run(_config(recording, out, pairing="sequential"), out)
    blocked = tmp_path / "blocked"
    (blocked / "fields").mkdir(parents=True)
    (blocked / "fields" / "uncorrected").write_text("not a folder")
    chunk = process_chunk(res.context, camp.pairs()[:2], FieldWriter(str(blocked), "c"))
    assert chunk.done == [] and sorted(chunk.failed) == [0, 1]
    assert chunk.failed[0][1].startswith("[output] fields: cannot write "), chunk.failed[0]


def test_a_double_frame_recording_paired_sequentially_is_refused(tmp_path):
    """Frames A, B, A, B ... paired 1-2, 2-3: pairs of a short and a long interval, refused
    before anything is written, whether the long pairs still correlate (a slow flow: 1 px
    from A to B, 4 px from B to the next A) or not (independent pairs)."""
    seq = particle_sequence(SHAPE, (1.0, 0.0), 12, seed=2)
    slow = [seq[k] for k in (0, 1, 5, 6, 10, 11)]
    independent = [f for s in (1, 2, 3) for f in particle_sequence(SHAPE, (2.0, 0.0), 2, seed=s)]
    for name, frames, moves in (
        ("slow", slow, r"moves 1\.0\d px .* 4\.0\d px"),
        ("independent", independent, r"moves 2\.0\d px"),
    ):
        d = tmp_path / name
        d.mkdir()
        for k, f in enumerate(frames):
            tifffile.imwrite(d / f"frame_{k:03d}.tif", f)
        out = tmp_path / f"out_{name}"
        with pytest.raises(InvalidInputError) as e:
            _run(_config(d, out, pairing="sequential"), out)
        msg = str(e.value)
        assert "\n" not in msg and 'pairing = "sequential": pair 0 (' in msg, msg
        assert "double-frame camera" in msg and re.search(moves, msg), msg
        assert not any(p.is_file() for p in out.rglob("*")), sorted(out.rglob("*"))
        # the same frames paired 1-2, 3-4 are processed
        _, res = _run(_config(d, tmp_path / f"pairs_{name}"), tmp_path / f"pairs_{name}")
        assert res.n_done == 3 and not res.skipped
