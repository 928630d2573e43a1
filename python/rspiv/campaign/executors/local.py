"""The local executor: the pairs one after another in this process (each pair's PIV uses every
core through rayon)."""

from __future__ import annotations

from typing import Any

from rspiv.campaign import pair as pair_work
from rspiv.campaign.reduce import RunReducer, add_fields
from rspiv.campaign.state import RunState

__all__ = ["LocalExecutor"]


class LocalExecutor:
    """Run the pairs still to do in order, in this process.

    A checkpoint is written every ``checkpoint_every`` pairs and at the end; on an interrupt
    (KeyboardInterrupt) the pairs finished so far are checkpointed before it propagates, so a
    restart resumes from there.
    """

    name = "local"
    t_start: float | None = None

    def execute(
        self, campaign: Any, state: RunState, progress: Any
    ) -> tuple[dict[int, str], dict[int, str] | None]:
        """Process ``state.todo``; returns ``(skipped, failed)`` (failed: None, a local run
        lets a raising pair stop the run)."""
        campaign.announce_run(state, progress)
        red = RunReducer(campaign, state, progress)
        consistent = True  # the accumulators hold whole pairs only
        try:
            for p in state.todo:
                r = pair_work.process_pair(state.ctx, p)
                red.add_timings(r.timings)
                if not r.ok:
                    red.skip(p.pair_id, p.describe(), r.reason)
                    progress.advance(skipped=True)
                    continue
                consistent = False
                red.add_timings({"statistics": add_fields(state.accs, r)})
                state.finished.add(p.pair_id)
                consistent = True
                red.done(p.pair_id, {k: round(v, 4) for k, v in r.timings.items()})
                progress.advance()
                if red.count():
                    red.checkpoint()
        except KeyboardInterrupt:
            if consistent:  # keep what is done: a restart resumes from here
                campaign.save_checkpoint(state.ctx, state.accs, state.finished, state.timings)
                state.log.write("interrupted", finished=len(state.finished))
            raise
        red.checkpoint()
        return red.skipped, None
