"""Dask scale-out (rspiv.campaign.executors.dask) against the local run of the same tiny campaign.

The reference is :meth:`Campaign.run` (one sequential pass); the Dask runs use a LocalCluster of
2 worker processes of 1 thread (loopback, no dashboard). The statistics must agree to 1e-12
relative (rounding of Chan's merge against Welford's update), including the lag-1 moments behind
n_eff (adjacent chunks join their chains).
"""

from __future__ import annotations

import copy
import json
import os
import pathlib
import shutil
import signal
import threading
import time

import numpy as np
import pytest
from rspiv.campaign import Campaign
from rspiv.campaign.fields import read_field
from scaleout_cases import assert_same_statistics, make_campaign, prepared_copy

distributed = pytest.importorskip("distributed")

from rspiv.campaign.executors import dask as scaleout  # noqa: E402
from rspiv.campaign.executors.dask import run_dask  # noqa: E402

N_PAIRS = 6


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> pathlib.Path:
    d = tmp_path_factory.mktemp("scaleout")
    make_campaign(d, N_PAIRS)
    return d


@pytest.fixture(scope="module")
def local(synth):
    """The local (sequential) run: the reference."""
    return Campaign.load(synth / "campaign.toml", progress=False, checkpoint_every=2).run()


@pytest.fixture(scope="module")
def client():
    with scaleout.local_cluster(n_workers=2, rayon_threads=1) as cluster:
        with distributed.Client(cluster) as c:
            yield c


def _camp(synth, out, **kw):
    return Campaign.load(synth / "campaign.toml", progress=False, out_dir=out, **kw)


def _events(out: pathlib.Path) -> list[dict]:
    return [json.loads(x) for x in (out / "run_log.jsonl").read_text().splitlines()]


def _u_tau(res, run):
    return res.analyses[run].result.u_tau


def test_two_workers_give_the_local_statistics(synth, local, client, tmp_path):
    out = prepared_copy(local.out_dir, tmp_path / "out")
    res = run_dask(_camp(synth, out, checkpoint_every=2), client, chunk_size=2, progress_interval=0)
    assert res.n_done == N_PAIRS and not res.skipped
    assert set(res.accumulators) == set(local.accumulators) == {"method_II", "uncorrected"}
    for run, ref in local.accumulators.items():
        assert_same_statistics(ref, res.accumulators[run], rtol=1e-12)
        # the analysis downstream agrees too; the profile fit (wall position, fitted offset)
        # amplifies the 1e-14 differences of the statistics about 1e5-fold
        assert _u_tau(res, run) == pytest.approx(_u_tau(local, run), rel=1e-7)
    # the outputs of a local run are all there
    for run in local.accumulators:
        assert (out / f"statistics_{run}.nc").is_file() and (out / f"profile_{run}.csv").is_file()
        # each pair's figures came back from the workers: the local run's series
        got, ref = (
            np.loadtxt(d / f"pairs_{run}.csv", delimiter=",", skiprows=1, usecols=range(6))
            for d in (out, local.out_dir)
        )
        assert got.shape == (N_PAIRS, 6)
        np.testing.assert_allclose(got, ref, atol=1e-4)
    # work was really spread: both worker processes returned chunks
    info = res.info["dask"]
    assert info["workers"] == 2 and info["worker_processes_seen"] == 2 and info["chunks"] == 3
    # progress: pairs done, failed and throughput, in the run log
    ev = _events(out)
    assert [e["event"] for e in ev].count("pair") == N_PAIRS
    prog = [e for e in ev if e["event"] == "progress"]
    assert prog and prog[-1]["done"] == N_PAIRS and prog[-1]["failed"] == 0
    assert prog[-1]["pairs_per_min"] > 0
    summ = [e for e in ev if e["event"] == "dask_summary"][0]
    assert summ["pairs_done"] == N_PAIRS and summ["pairs_failed"] == 0
    assert summ["pairs_per_min"] > 0
    # the workers' rayon pools were sized before their first task: 2 cores / 2 workers
    envs = client.run(lambda: os.environ.get("RAYON_NUM_THREADS"))
    assert set(envs.values()) == {"1"}


def test_chunks_merged_out_of_order_join_exactly(synth, local):
    """The ordered merge itself, without Dask: chunks arriving in any order give one pass."""
    from rspiv.campaign import PairContext
    from rspiv.campaign.executors.dask import _OrderedMerge, _Segment, process_chunk
    from rspiv.stats import FieldAccumulator

    camp = _camp(synth, local.out_dir)
    ctx = PairContext.from_dict(json.loads((local.out_dir / "context.json").read_text())["context"])
    pairs = camp.pairs()
    gx, _ = ctx.grid()
    results = {lo: process_chunk(ctx, pairs[lo:hi]) for lo, hi in ((0, 1), (1, 3), (3, 6))}
    for order in ((3, 0, 1), (1, 3, 0), (0, 1, 3)):
        m = _OrderedMerge(
            _Segment(0, 0, {r.name: FieldAccumulator(gx.shape) for r in ctx.runs}, None, [])
        )
        his = {0: 1, 1: 3, 3: 6}
        for lo in order:
            r = results[lo]
            # fresh copies: merging works in place
            m.add(_Segment(lo, his[lo], copy.deepcopy(r.accumulators), r.first, list(r.done)))
        assert m.pending() == 0
        for run, ref in local.accumulators.items():
            assert_same_statistics(ref, m.prefix.accs[run], rtol=1e-12)


def test_existing_cluster_gets_rayon_threads_from_the_plugin(synth, local, tmp_path, monkeypatch):
    """On a cluster rspiv did not start, a worker plugin sets RAYON_NUM_THREADS to the host's
    cores divided by the workers on that host before the first task."""
    monkeypatch.delenv("RAYON_NUM_THREADS", raising=False)
    out = prepared_copy(local.out_dir, tmp_path / "out")
    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        ) as cluster,
        distributed.Client(cluster) as c,
    ):
        assert set(c.run(lambda: os.environ.get("RAYON_NUM_THREADS")).values()) == {None}
        res = run_dask(_camp(synth, out), c.scheduler.address, chunk_size=3)
        envs = c.run(lambda: os.environ.get("RAYON_NUM_THREADS"))
    cores = len(os.sched_getaffinity(0))
    assert set(envs.values()) == {str(max(1, cores // 2))}
    for run, ref in local.accumulators.items():
        assert_same_statistics(ref, res.accumulators[run], rtol=1e-12)


def test_worker_killed_mid_campaign(synth, local, tmp_path):
    """SIGKILL of a busy worker: Dask restarts it, its chunk is recomputed elsewhere and the
    campaign completes with the local statistics, every pair counted once."""
    out = prepared_copy(local.out_dir, tmp_path / "out")
    killed: dict = {}

    def killer(client):
        deadline = time.monotonic() + 60
        log = out / "run_log.jsonl"
        while time.monotonic() < deadline:
            if log.is_file() and '"event": "pair"' in log.read_text():
                busy = [w for w, ts in client.processing().items() if ts]
                if busy:
                    pids = client.run(os.getpid, workers=busy[:1])
                    ((addr, pid),) = pids.items()
                    killed["n_pairs_before"] = log.read_text().count('"event": "pair"')
                    os.kill(pid, signal.SIGKILL)
                    killed["pid"] = pid
                    return
            time.sleep(0.02)

    with scaleout.local_cluster(n_workers=2, rayon_threads=1) as cluster:
        with distributed.Client(cluster) as c:
            t = threading.Thread(target=killer, args=(c,), daemon=True)
            t.start()
            res = run_dask(_camp(synth, out, checkpoint_every=1), c, chunk_size=1)
            t.join(5)
            pids_after = set(c.run(os.getpid).values())
    assert "pid" in killed, "the worker was not killed during the campaign"
    assert killed["n_pairs_before"] < N_PAIRS
    assert killed["pid"] not in pids_after
    assert res.n_done == N_PAIRS and not res.skipped
    assert [e["event"] for e in _events(out)].count("pair") == N_PAIRS
    for run, ref in local.accumulators.items():
        assert_same_statistics(ref, res.accumulators[run], rtol=1e-12)


def test_bad_pair_is_skipped_and_logged_under_dask(synth, local, client, tmp_path):
    """A truncated frame: skipped, logged with its reason, absent from the statistics, which
    equal the local run of the same broken campaign. A pair whose frames hold camera noise
    only in their right 40 % stays in and is reported as correlating in part, by the Dask run
    as by the local one."""
    import tifffile

    d = tmp_path / "broken"
    shutil.copytree(synth, d, ignore=shutil.ignore_patterns("out"))
    bad = d / "raw" / "pair_00002_b.tif"
    bad.write_bytes(bad.read_bytes()[:300])
    rng = np.random.default_rng(0)
    for f in (d / "raw" / "pair_00004_a.tif", d / "raw" / "pair_00004_b.tif"):
        img = tifffile.imread(f)
        c, med = int(0.6 * img.shape[1]), float(np.median(img))
        img[:, c:] = np.clip(rng.normal(med, 0.05 * med + 10, img[:, c:].shape), 0, None)
        tifffile.imwrite(f, img)
    ref = Campaign.load(
        d / "campaign.toml", progress=False, out_dir=prepared_copy(local.out_dir, d / "ref")
    ).run()
    out = prepared_copy(local.out_dir, d / "dask")
    res = run_dask(_camp(d, out), client, chunk_size=2)
    assert set(res.skipped) == set(ref.skipped) == {2}
    ev = [e for e in _events(out) if e["event"] == "skipped"]
    assert len(ev) == 1 and ev[0]["pair_id"] == 2 and "pair_00002_b.tif" in ev[0]["reason"]
    assert list(ref.warned) == list(res.warned) == [4] and ref.warned == res.warned
    ev = [e for e in _events(out) if e["event"] == "warning"]
    assert [e["pair_id"] for e in ev] == [4] and "pair_00004_a.tif" in ev[0]["files"]
    for run, acc in ref.accumulators.items():
        assert 2 not in res.accumulators[run].pair_ids
        assert_same_statistics(acc, res.accumulators[run], rtol=1e-12)


def test_dask_workers_write_each_pairs_fields(synth, local, client, tmp_path):
    """[output] fields under Dask: each worker writes its pairs' files; per run, their valid
    vectors average to the local run's statistics, in object px with the calibration's
    scale."""
    import xarray as xr

    out = prepared_copy(local.out_dir, tmp_path / "out")
    camp = _camp(synth, out)
    camp.config.output.fields = True
    res = run_dask(camp, client, chunk_size=2, progress_interval=0)
    assert res.n_done == N_PAIRS and res.timings["fields"] > 0
    for run, ref in local.accumulators.items():
        files = sorted((out / "fields" / run).glob("pair_*.nc"))
        assert [f.name for f in files] == [f"pair_{k:06d}.nc" for k in range(N_PAIRS)]
        dss = [xr.load_dataset(f, engine="h5netcdf") for f in files]
        assert dss[0].attrs["frame"] == ("raw image" if run == "uncorrected" else "object")
        assert dss[0].attrs["m_per_px"] == pytest.approx(1e-3 / camp.calibration.magnification)
        # the files keep the PIV's own validation; read with the run's screen, they give the
        # vectors the statistics took
        valid = np.stack([ds["valid"].values for ds in dss]).astype(bool)
        np.testing.assert_array_equal(valid.sum(axis=0) - ref.screen.count, ref.count)
        screen = res.context.screens()[run]
        got = [read_field(f, ref.shape, run, screen=screen) for f in files]
        np.testing.assert_array_equal(np.stack([g[2] for g in got]).sum(axis=0), ref.count)
        u = np.nansum(np.stack([g[0].astype(np.float64) for g in got]), axis=0)
        seen = ref.count > 0
        np.testing.assert_allclose(u[seen] / ref.count[seen], ref.mean_u[seen], atol=1e-5)
    # the POD's second pass reads the workers' files about the merged statistics: the local
    # run's decomposition
    assert set(local.pod) == set(res.pod) == set(local.accumulators)
    for run, prof in local.pod.items():
        np.testing.assert_allclose(res.pod[run]["energy"], prof["energy"], rtol=1e-9)
        np.testing.assert_allclose(np.abs(res.pod[run]["coefficient"]),
                                   np.abs(prof["coefficient"]), rtol=1e-6, atol=1e-12)  # fmt: skip


def test_dask_resumes_an_interrupted_local_run(synth, local, client, tmp_path, monkeypatch):
    """A local run interrupted after 3 pairs, resumed on Dask: the checkpoint's pairs are not
    recomputed and the statistics (lag-1 chains included) are those of one uninterrupted pass."""
    from rspiv.campaign import pair as campaign_mod

    out = prepared_copy(local.out_dir, tmp_path / "out")
    real = campaign_mod.process_pair
    calls = []

    def interrupting(ctx, pair, frames=None, ensembles=None):
        if len(calls) == 3:
            raise KeyboardInterrupt
        calls.append(pair.pair_id)
        return real(ctx, pair, frames, ensembles)

    monkeypatch.setattr(campaign_mod, "process_pair", interrupting)
    with pytest.raises(KeyboardInterrupt):
        _camp(synth, out, checkpoint_every=1).run()
    monkeypatch.setattr(campaign_mod, "process_pair", real)
    res = run_dask(_camp(synth, out, checkpoint_every=1), client, chunk_size=2)
    assert res.n_resumed == 3
    ev = _events(out)
    starts = [i for i, e in enumerate(ev) if e["event"] == "start"]
    redone = {e["pair_id"] for e in ev[starts[-1] :] if e["event"] == "pair"}
    assert redone == set(range(3, N_PAIRS))
    for run, ref in local.accumulators.items():
        assert_same_statistics(ref, res.accumulators[run], rtol=1e-12)


def test_cli_process_dask_local(synth, local, tmp_path, capsys):
    from rspiv.cli import main

    out = prepared_copy(local.out_dir, tmp_path / "out")
    rc = main(
        [
            "process",
            str(synth / "campaign.toml"),
            "-o",
            str(out),
            "-q",
            "--dask",
            "local",
            "--dask-workers",
            "2",
            "--rayon-threads",
            "1",
        ]
    )
    assert rc == 0
    assert f"{N_PAIRS} of {N_PAIRS} pair(s) processed" in capsys.readouterr().out
    import xarray as xr

    for run in local.accumulators:
        with (
            xr.open_dataset(out / f"statistics_{run}.nc", engine="h5netcdf") as a,
            xr.open_dataset(local.out_dir / f"statistics_{run}.nc", engine="h5netcdf") as b,
        ):
            for k in ("u", "uu", "uv"):
                x = b[k].values
                np.testing.assert_allclose(
                    a[k].values, x, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(x))
                )


def _run_killing_workers(synth, local, tmp_path):
    """The campaign on a fresh 2-worker cluster in chunks of 2 pairs, a task failed at the first
    death of its worker (``allowed-failures`` 0): ``(out_dir, result)``."""
    import dask

    out = prepared_copy(local.out_dir, tmp_path / "out")
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with scaleout.local_cluster(n_workers=2, rayon_threads=1) as cluster:
            with distributed.Client(cluster) as c:
                return out, run_dask(_camp(synth, out), c, chunk_size=2)


def test_pair_that_kills_its_worker_is_recorded_failed(synth, local, tmp_path, monkeypatch):
    """A pair whose processing kills the worker process every time: its chunk is split into
    single pairs, the deadly pair is recorded as failed and left out, the others are merged."""
    from rspiv.campaign import PairContext

    def deadly(ctx, pairs, **kw):  # a local function: pickled by value to the workers
        import os

        from rspiv.campaign.executors.dask import process_chunk as real

        if any(p.pair_id == 3 for p in pairs):
            os._exit(1)
        return real(ctx, pairs, **kw)

    monkeypatch.setattr(scaleout, "process_chunk", deadly)
    out, res = _run_killing_workers(synth, local, tmp_path)
    assert set(res.skipped) == {3} and "worker died" in res.skipped[3]
    assert res.info["dask"]["pairs_failed"] == 1 and res.n_done == N_PAIRS - 1
    ev = _events(out)
    assert [e["pair_id"] for e in ev if e["event"] == "failed"] == [3]
    # the deadly pair's chunk is split; a bystander chunk queued on a dying worker may be too
    # (which one is the scheduler's choice): its pairs are then merged like the others
    splits = [e["pairs"] for e in ev if e["event"] == "chunk_split"]
    assert [c for c in splits if 3 in c] == [[2, 3]], splits
    # retried once apart from the other suspects before being recorded
    assert 3 in [e["pair_id"] for e in ev if e["event"] == "pair_retry"]
    # the statistics are one pass over the other pairs
    monkeypatch.undo()
    ctx = PairContext.from_dict(json.loads((local.out_dir / "context.json").read_text())["context"])
    pairs = [p for p in _camp(synth, out).pairs() if p.pair_id != 3]
    ref = scaleout.process_chunk(ctx, pairs)
    for run, acc in ref.accumulators.items():
        assert_same_statistics(acc, res.accumulators[run], rtol=1e-12)


def test_pair_killed_beside_another_is_retried_not_failed(synth, local, tmp_path, monkeypatch):
    """A single pair whose worker died once while it was only a bystander (Dask counts every
    task on a dying worker as suspect) is retried on its own and merged, not recorded failed:
    here pair 2's worker dies on its first two runs (its chunk's and its own) only."""

    count = tmp_path / "deaths"
    count.write_text("0")

    def dies_twice(ctx, pairs, **kw):  # a local function: pickled by value to the workers
        import os
        import pathlib

        from rspiv.campaign.executors.dask import process_chunk as real

        f = pathlib.Path(str(count))
        if any(p.pair_id == 2 for p in pairs):
            n = int(f.read_text())
            if n < 2:
                f.write_text(str(n + 1))
                os._exit(1)
        return real(ctx, pairs, **kw)

    monkeypatch.setattr(scaleout, "process_chunk", dies_twice)
    out, res = _run_killing_workers(synth, local, tmp_path)
    assert count.read_text() == "2"
    assert not res.skipped and res.n_done == N_PAIRS
    ev = _events(out)
    assert not [e for e in ev if e["event"] == "failed"]
    # pair 2's chunk is split (and a bystander chunk queued on a dying worker may be: the
    # scheduler's choice; the CI saw [4, 5] split beside it, its pairs merged)
    splits = [e["pairs"] for e in ev if e["event"] == "chunk_split"]
    assert [c for c in splits if 2 in c] == [[2, 3]], splits
    assert 2 in [e["pair_id"] for e in ev if e["event"] == "pair_retry"]
    for run, acc in local.accumulators.items():
        assert_same_statistics(acc, res.accumulators[run], rtol=1e-12)


def test_dask_shards_merge_to_the_local_statistics(synth, local, client, tmp_path):
    """--shard with --dask: each shard's partial file, merged, gives the local statistics."""
    from rspiv.merge import merge_files, read_part

    out = prepared_copy(local.out_dir, tmp_path / "out")
    for shard in ("2/2", "1/2"):
        res = run_dask(_camp(synth, out, shard=shard), client, chunk_size=1)
        assert not res.analyses and res.n_pairs == N_PAIRS // 2
    parts = sorted((out / "shards").glob("statistics_method_II.shard-*-of-2.nc"))
    merged = read_part(merge_files(parts, tmp_path / "m.nc")["method_II"]).accumulator
    assert_same_statistics(local.accumulators["method_II"], merged, rtol=1e-12, lag=False)


def test_interrupted_client_keeps_chunks_merged_out_of_order(
    synth, local, client, tmp_path, monkeypatch
):
    """Pair 0 is slow, so pairs 1.. finish first and wait beside the empty prefix; the client is
    interrupted. The restarted run recomputes pair 0 and the pairs never merged, not the
    out-of-order ones saved beside the checkpoint, and gives the local statistics."""

    def slow_first(ctx, pairs, **kw):  # a local function: pickled by value to the workers
        import time

        from rspiv.campaign.executors.dask import process_chunk as real

        if pairs[0].pair_id == 0:
            time.sleep(8.0)
        return real(ctx, pairs, **kw)

    real_save = scaleout._save_segments

    def save_then_interrupt(path, ctx, shard, todo, merger):
        real_save(path, ctx, shard, todo, merger)
        if sum(sg.hi - sg.lo for lo, sg in merger.by_lo.items() if lo) >= 2:
            raise KeyboardInterrupt

    out = prepared_copy(local.out_dir, tmp_path / "out")
    monkeypatch.setattr(scaleout, "process_chunk", slow_first)
    monkeypatch.setattr(scaleout, "_save_segments", save_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_dask(_camp(synth, out, checkpoint_every=1), client, chunk_size=1)
    monkeypatch.undo()
    seg_file = out / "checkpoint" / "dask_segments.pkl"
    assert seg_file.is_file()
    n_before = len(_events(out))
    res = run_dask(_camp(synth, out, checkpoint_every=1), client, chunk_size=1)
    ev = _events(out)[n_before:]
    resumed = [e for e in ev if e["event"] == "resumed_segments"]
    assert resumed and resumed[0]["pairs"] >= 2
    redone = {e["pair_id"] for e in ev if e["event"] == "pair"}
    assert 0 in redone and len(redone) == N_PAIRS - resumed[0]["pairs"]
    assert res.info["dask"]["pairs_from_segments"] == resumed[0]["pairs"]
    assert not seg_file.exists()  # removed once everything joined the checkpoint
    for run, ref in local.accumulators.items():
        assert_same_statistics(ref, res.accumulators[run], rtol=1e-12)


def test_sequential_pairing_under_dask(client, tmp_path, monkeypatch):
    """A time-resolved recording paired sequentially: each chunk reads its frames once
    (FrameCache) and the statistics are the local run's."""
    import tifffile
    from rspiv.campaign_config import CampaignConfig, ImagesConfig
    from rspiv.synth import particle_sequence

    frames = particle_sequence((192, 256), lambda x, y: (1.5 + y / 192.0, 0.0 * y), 7, seed=4)
    for k, f in enumerate(frames):
        tifffile.imwrite(tmp_path / f"f_{k:02d}.tif", f)
    cfg = CampaignConfig()
    cfg.images = ImagesConfig(glob=str(tmp_path / "f_*.tif"), pairing="sequential")
    cfg.correction.method = "none"
    cfg.correction.compare_uncorrected = False
    cfg.wall.enabled = False
    cfg.output.report = False
    ref = Campaign(cfg, progress=False, out_dir=tmp_path / "local").run()
    out = prepared_copy(tmp_path / "local", tmp_path / "dask")
    res = run_dask(
        Campaign(cfg, progress=False, out_dir=out), client, chunk_size=3, progress_interval=0
    )
    assert res.n_done == ref.n_done == 6 and not res.skipped
    assert_same_statistics(
        ref.accumulators["uncorrected"], res.accumulators["uncorrected"], rtol=1e-12
    )
    # a chunk of three pairs reads its four frames once each
    from rspiv.campaign import pair as pair_work

    reads = []
    read = pair_work.read_frame
    monkeypatch.setattr(pair_work, "read_frame", lambda f, i, t=0: reads.append(f) or read(f, i, t))
    chunk = scaleout.process_chunk(res.context, Campaign(cfg, progress=False).pairs()[:3])
    assert len(chunk.done) == 3 and len(reads) == 4
