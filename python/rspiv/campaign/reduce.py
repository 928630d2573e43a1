"""The one reduce/log step of a campaign run, shared by every executor.

Whatever runs the per-pair work (:mod:`rspiv.campaign.executors`: a local loop, Dask workers),
its results come back to the client and go through a :class:`RunReducer`: timings summed, the
fields added to the run's accumulators (:func:`add_fields`), the pair recorded in the run log
(``pair``, ``skipped``, ``failed``, ``warning``), and a checkpoint written every
``checkpoint_every`` pairs.
"""

from __future__ import annotations

import time
from typing import Any

from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign import screen as screen_work
from rspiv.campaign import two_point as two_point_work
from rspiv.campaign import vorticity as vorticity_work
from rspiv.campaign.spec import PairContext, PairResult
from rspiv.campaign.state import RunLog, RunState
from rspiv.peak_locking import LockingHistogram
from rspiv.row_errors import RowErrors
from rspiv.stats import FieldAccumulator

__all__ = ["RunReducer", "add_fields", "logged_warnings", "new_accumulators"]


def new_accumulators(ctx: PairContext) -> dict[str, FieldAccumulator]:
    """One empty FieldAccumulator per run of ``ctx``, carrying what the context plans beside
    the statistics (the ensemble band, the two-point sums, the vorticity statistics, the
    screen's tally) and the displacements' histogram
    (:class:`rspiv.peak_locking.LockingHistogram`): the same for the local loop and every Dask
    chunk, so that their parts merge whole."""
    gx, _ = ctx.grid()
    accs = {r.name: FieldAccumulator(gx.shape) for r in ctx.runs}
    for work in (ensemble_work, two_point_work, vorticity_work):
        accs = work.attach(ctx, accs)
    for acc in accs.values():  # the displacements' histogram (peak locking), for every run
        acc.locking = LockingHistogram()
        acc.rows = RowErrors(gx.shape[0])  # the profile's errors from pair to pair
    return screen_work.attach(ctx, accs)


def add_fields(
    accs: dict[str, FieldAccumulator], result: PairResult, screens: dict[str, Any] | None = None
) -> float:
    """Add a processed pair's fields to the accumulators and the two-point sums and vorticity
    statistics they carry (keyed by its pair id, so a pair is never counted twice); returns the
    seconds it took. ``screens`` (run -> :class:`rspiv.outlier_screen.ScreenBounds`, the
    context's :meth:`~rspiv.campaign.spec.PairContext.screens`) first leaves out the vectors
    that stand apart from their ensemble (:func:`rspiv.campaign.screen.apply`)."""
    t0 = time.perf_counter()
    for name, (u, v, valid, su, sv) in result.fields.items():
        if screens and name in screens:
            tally = getattr(accs[name], "screen", None)
            u, v, valid = screen_work.apply(screens[name], u, v, valid, tally, result.pair_id)
        accs[name].add(u, v, valid, pair_id=result.pair_id, sigma_u=su, sigma_v=sv)
        acc = accs[name]
        for extra in (acc.two_point, acc.vorticity, acc.locking, acc.rows):
            if extra is not None:
                extra.add(u, v, valid, pair_id=result.pair_id)
    return time.perf_counter() - t0


def logged_warnings(log: RunLog, fingerprint: str, pair_ids: set[int]) -> dict[int, str]:
    """Pair id -> the ``warning`` event's text, for the pairs of ``pair_ids`` warned in the run
    log under the context ``fingerprint`` (any run of the output folder: a pair finished before
    an interruption, by a Dask chunk or by a shard keeps its warning; an unreadable line is
    passed over)."""
    out: dict[int, str] = {}
    for rec in log.events("warning"):
        pid = rec.get("pair_id")
        if rec.get("fingerprint") == fingerprint and isinstance(pid, int) and pid in pair_ids:
            out[pid] = str(rec.get("reason", ""))
    return dict(sorted(out.items()))


class RunReducer:
    """Bookkeeping of a run on the client: timings, skipped and failed pairs, the run log, the
    progress display and the checkpoint cadence.

    Parameters
    ----------
    campaign : rspiv.Campaign
        The campaign (its ``checkpoint_every`` and :meth:`~rspiv.Campaign.save_checkpoint`).
    state : RunState
        The run (after :meth:`~rspiv.Campaign.begin_run`); its ``timings`` are updated.
    progress : rspiv.progress.Progress
        The run's progress display.
    """

    def __init__(self, campaign: Any, state: RunState, progress: Any) -> None:
        self.campaign = campaign
        self.state = state
        self.progress = progress
        self.skipped: dict[int, str] = {}
        self.failed: dict[int, str] = {}
        self.n_ok = 0
        self.since = 0
        self._fingerprint: str | None = None

    def add_timings(self, timings: dict[str, float]) -> None:
        """Add seconds per stage to the run's timings."""
        t = self.state.timings
        for k, v in timings.items():
            t[k] = t.get(k, 0.0) + v

    def done(
        self,
        pair_id: int,
        timings: dict[str, float],
        quality: dict[str, dict[str, float]] | None = None,
        **extra: Any,
    ) -> None:
        """Record a pair added to the statistics (``pair`` event; with its figures per run,
        :mod:`rspiv.campaign.pair_quality`, under the context's fingerprint)."""
        if quality:
            if self._fingerprint is None:  # the context's, once per run
                self._fingerprint = self.state.ctx.fingerprint()
            extra.update(quality=quality, fingerprint=self._fingerprint)
        self.state.log.write("pair", pair_id=pair_id, timings=timings, **extra)
        self.n_ok += 1

    def warn(self, pair_id: int, files: str, warning: str) -> None:
        """Record a pair added to the statistics whose frames correlate only in part
        (``warning`` event, with the context's fingerprint: :func:`logged_warnings` reads it
        back for the end of the run, over resumed runs, Dask chunks and shards alike)."""
        self.state.log.write(
            "warning",
            pair_id=pair_id,
            files=files,
            reason=warning,
            fingerprint=self.state.ctx.fingerprint(),
        )
        self.progress.log(f"pair {pair_id}: {warning}")

    def skip(self, pair_id: int, files: str, reason: str) -> None:
        """Record a pair that could not be read (``skipped`` event, left out of the
        statistics)."""
        self.skipped[pair_id] = reason
        self.state.log.write("skipped", pair_id=pair_id, files=files, reason=reason)
        self.progress.log(f"pair {pair_id} skipped: {reason}")

    def fail(self, pair_id: int, files: str, reason: str) -> None:
        """Record a pair whose processing raised (``failed`` event, left out)."""
        self.failed[pair_id] = reason
        self.state.log.write("failed", pair_id=pair_id, files=files, reason=reason)
        self.progress.log(f"pair {pair_id} failed: {reason}")

    @property
    def n_handled(self) -> int:
        """Pairs done, skipped or failed in this run."""
        return self.n_ok + len(self.skipped) + len(self.failed)

    def count(self, n: int = 1) -> bool:
        """Count ``n`` pairs handled; True when a checkpoint is due."""
        self.since += n
        return self.since >= self.campaign.checkpoint_every

    def checkpointed(self, finished: int, **extra: Any) -> None:
        """Record a checkpoint of ``finished`` pairs (``checkpoint`` event); restart the
        count."""
        self.state.log.write("checkpoint", finished=finished, **extra)
        self.since = 0

    def checkpoint(self) -> None:
        """Write the run's checkpoint (the state's accumulators and finished pairs)."""
        st = self.state
        self.campaign.save_checkpoint(st.ctx, st.accs, st.finished, st.timings)
        self.checkpointed(len(st.finished))
