"""Fault tolerance of a local campaign: ``rspiv process`` killed with SIGKILL at random moments
(after a seeded-random number of finished pairs plus a seeded-random delay, so that the kill
lands mid-pair or mid-checkpoint whatever the machine's speed) and restarted gives
bit-identical statistics to an uninterrupted run, never recomputes a pair its checkpoint holds,
and keeps a corrupt pair out of the statistics.
"""

from __future__ import annotations

import json
import pickle
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rspiv.campaign import Campaign
from scaleout_cases import make_campaign, prepared_copy

N_PAIRS = 10
BAD = 5  # pair with a truncated frame
STATE = (
    "count",
    "mean_u",
    "mean_v",
    "m2_uu",
    "m2_vv",
    "c_uv",
    "lag_count_u",
    "lag_c_u",
    "lag_mean_a_u",
    "lag_mean_b_v",
    "lag_c_v",
)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("resume")
    toml = make_campaign(d, N_PAIRS)
    bad = d / "raw" / f"pair_{BAD:05d}_a.tif"
    bad.write_bytes(bad.read_bytes()[:500])
    ref = Campaign.load(toml, progress=False, checkpoint_every=1).run()
    return toml, ref


def _events(out):
    p = out / "run_log.jsonl"
    if not p.is_file():
        return []
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()]


def _kill_at_random_moment(
    proc, out, n_before: int, pairs: int, delay: float, held: set | None = None
) -> None:
    """SIGKILL ``proc`` once this attempt has logged ``pairs`` finished pairs (and, with
    ``held``, once its checkpoint holds more pairs than ``held``), ``delay`` seconds later (the
    log is polled every 5 ms; a half-written last line is ignored)."""
    deadline = time.monotonic() + 120.0
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            done = sum(1 for e in _events(out)[n_before:] if e["event"] == "pair")
        except json.JSONDecodeError:
            done = -1
        try:
            saved = held is None or len(_finished(out)) > len(held)
        except (EOFError, pickle.UnpicklingError):  # being replaced: look again
            saved = False
        if done >= pairs and saved:
            time.sleep(delay)
            break
        time.sleep(0.005)
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)


def _finished(out) -> set[int]:
    p = out / "checkpoint" / "state.pkl"
    return set(pickle.loads(p.read_bytes())["finished"]) if p.is_file() else set()


def test_sigkill_at_random_moments_then_resume(case, tmp_path):
    toml, ref = case
    out = prepared_copy(ref.out_dir, tmp_path / "out")
    cmd = [sys.executable, "-m", "rspiv", "process", str(toml), "-o", str(out), "-q"]
    cmd += ["--checkpoint-every", "1"]
    rng = np.random.default_rng(20261122)
    attempts = []  # (checkpoint's finished pairs at launch, log lines before, killed)
    for k in range(5):
        held = _finished(out)
        n_before = len(_events(out))
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        if k < 4:  # SIGKILL after 0 or 1 finished pairs plus a random delay of up to 50 ms
            pairs, delay = int(rng.integers(0, 2)), float(rng.uniform(0.0, 0.05))
            # the last kill waits for a checkpoint holding a pair, so that the last run has
            # something to resume however long a checkpoint takes to reach the disk (after
            # tests that wrote much, fsync can take longer than the random delays)
            _kill_at_random_moment(proc, out, n_before, pairs, delay, held if k == 3 else None)
        rc = proc.wait(timeout=120)
        attempts.append((held, n_before, rc == -signal.SIGKILL))
        if k == 4:
            assert rc == 0, proc.stderr.read().decode()
    kills = sum(a[2] for a in attempts)
    assert kills >= 3
    # -------- identical statistics: the checkpoint holds the exact accumulator state
    state = pickle.loads((out / "checkpoint" / "state.pkl").read_bytes())
    assert set(state["finished"]) == set(range(N_PAIRS)) - {BAD}
    for run, acc in ref.accumulators.items():
        got = state["accumulators"][run]
        assert got.pair_ids == acc.pair_ids and BAD not in got.pair_ids
        for name in STATE:
            np.testing.assert_array_equal(getattr(got, name), getattr(acc, name), err_msg=name)
    import xarray as xr

    for run in ref.accumulators:
        with xr.open_dataset(out / f"statistics_{run}.nc", engine="h5netcdf") as a:
            with xr.open_dataset(ref.out_dir / f"statistics_{run}.nc", engine="h5netcdf") as b:
                for k in ("u", "v", "uu", "vv", "uv", "count", "n_eff_uu"):
                    np.testing.assert_array_equal(a[k].values, b[k].values, err_msg=k)
    # -------- finished pairs never recomputed
    ev = _events(out)
    bounds = [a[1] for a in attempts] + [len(ev)]
    for (held, _, _), lo, hi in zip(attempts, bounds[:-1], bounds[1:], strict=True):
        span = ev[lo:hi]
        redone = {e["pair_id"] for e in span if e["event"] == "pair"}
        assert not (redone & held), f"pairs {sorted(redone & held)} recomputed"
        starts = [e for e in span if e["event"] == "start"]
        if starts:
            assert starts[0]["resumed"] == len(held)
    assert len(attempts[-1][0]) > 0  # the last run did resume something
    recomputed = sum(1 for e in ev if e["event"] == "pair") - (N_PAIRS - 1)
    # only a pair finished after the last checkpoint before a kill is recomputed: at most one
    # per kill with --checkpoint-every 1
    assert 0 <= recomputed <= kills
    # -------- the corrupt pair: skipped with its reason, never in the statistics
    sk = [e for e in ev if e["event"] == "skipped"]
    assert sk and all(e["pair_id"] == BAD and f"pair_{BAD:05d}_a.tif" in e["reason"] for e in sk)
    assert ev[-1]["event"] == "end" and ev[-1]["done"] == N_PAIRS - 1


def test_resumed_run_counts_the_checkpoint(case, tmp_path):
    """An in-process interruption after 3 pairs: the resumed run processes only the rest and
    reproduces the uninterrupted state bit for bit."""
    from rspiv.campaign import pair as campaign_mod

    toml, ref = case
    out = prepared_copy(ref.out_dir, tmp_path / "out")
    real = campaign_mod.process_pair
    seen: list[int] = []

    def interrupting(ctx, pair, frames=None, ensembles=None):
        if len(seen) == 3:
            raise KeyboardInterrupt
        seen.append(pair.pair_id)
        return real(ctx, pair, frames, ensembles)

    campaign_mod.process_pair = interrupting
    try:
        with pytest.raises(KeyboardInterrupt):
            Campaign.load(toml, progress=False, out_dir=out, checkpoint_every=1).run()
    finally:
        campaign_mod.process_pair = real
    res = Campaign.load(toml, progress=False, out_dir=out, checkpoint_every=1).run()
    assert res.n_resumed == 3 and res.n_done == N_PAIRS - 1
    for run, acc in ref.accumulators.items():
        for name in STATE:
            np.testing.assert_array_equal(
                getattr(res.accumulators[run], name), getattr(acc, name), err_msg=name
            )


def test_checkpoint_of_another_version_is_refused(tmp_path):
    """A checkpoint written by another checkpoint version (its accumulators' sums would not
    add to this version's: the single-pixel planes' normalisation changed in version 3) is
    refused in one line naming the file, before anything is added to it."""
    from rspiv.campaign.checkpoint import load_checkpoint
    from rspiv.campaign.spec import CHECKPOINT_FORMAT, CHECKPOINT_VERSION
    from rspiv.errors import InvalidInputError

    class Context:
        def fingerprint(self) -> str:
            return "same"

    path = tmp_path / "checkpoint.pkl"
    state = {"format": CHECKPOINT_FORMAT, "fingerprint": "same", "accumulators": {}}
    path.write_bytes(pickle.dumps({**state, "version": CHECKPOINT_VERSION - 1}))
    with pytest.raises(InvalidInputError, match=r"checkpoint\.pkl: checkpoint of version 2, "):
        load_checkpoint(path, Context())
    path.write_bytes(pickle.dumps({**state, "version": CHECKPOINT_VERSION}))
    assert load_checkpoint(path, Context())["accumulators"] == {}
