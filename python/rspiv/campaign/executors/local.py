"""The local executor: the pairs one after another in this process (each pair's PIV uses every
core through rayon), the next pair's frames read and the last pair's fields written by threads
meanwhile."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign import pair as pair_work
from rspiv.campaign.reduce import RunReducer, add_fields
from rspiv.campaign.state import RunState

__all__ = ["LocalExecutor"]


class LocalExecutor:
    """Run the pairs still to do in order, in this process.

    While a pair is processed, one reader thread reads and decodes the next pair's frames
    (:func:`rspiv.campaign.pair.read_ahead`; the file reads and the PIV release the GIL), so the
    PIV does not wait for the disk: the frames of two pairs are in memory at a time (190 MB per
    47 MP pair of uint16 frames, besides the current pair's working copies). With sequential
    pairing the frames shared by successive pairs are read once
    (:class:`rspiv.campaign.pair.FrameCache`, a few frames more). The run log's ``read``
    timing is the time the PIV waited for its frames.

    With ``[output] fields`` one writer thread writes each pair's field files while the next
    pair is processed (one write in flight: a pair's fields in memory, 12 MB at 47 MP). The
    ``fields`` timing is the time the loop waited for the previous write, and a pair is
    recorded done (its ``pair`` event, the progress) once its files are written. Every
    checkpoint, the end and an interrupt wait for the write in flight first, so a checkpoint
    never holds a pair whose files are not written; a write that fails stops the run (its
    OSError names the file) before the next checkpoint.

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
        todo = list(state.todo)
        shape = tuple(state.ctx.image_shape)
        screens = state.ctx.screens()
        reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rspiv-read")
        writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rspiv-write")
        in_flight: list = []  # the previous pair's field write and its record, at most one

        def written() -> None:
            """Wait for the write in flight (its OSError raised here), then record its pair."""
            if in_flight:
                write, record = in_flight.pop()
                t0 = time.perf_counter()
                write.result()
                red.add_timings({"fields": time.perf_counter() - t0})
                record()

        cache = pair_work.FrameCache.for_pairs(todo)  # sequential pairing: frames read once
        ahead = reader.submit(pair_work.read_ahead, todo[0], shape, cache) if todo else None
        try:
            for i, p in enumerate(todo):
                t0 = time.perf_counter()
                frames = ahead.result()
                waited = time.perf_counter() - t0
                nxt = todo[i + 1] if i + 1 < len(todo) else None
                ahead = reader.submit(pair_work.read_ahead, nxt, shape, cache) if nxt else None
                ens = ensemble_work.band_accumulators(state.accs)
                consistent = not ens  # the ensembles are added to inside process_pair
                r = pair_work.process_pair(state.ctx, p, frames=frames, ensembles=ens)
                del frames
                r.timings["read"] = waited
                red.add_timings(r.timings)
                if not r.ok:
                    consistent = True
                    red.skip(p.pair_id, p.describe(), r.reason)
                    progress.advance(skipped=True)
                    continue
                written()  # the previous pair's fields, before this pair enters the statistics
                consistent = False
                red.add_timings({"statistics": add_fields(state.accs, r, screens)})
                state.finished.add(p.pair_id)
                consistent = True

                def record(p=p, r=r) -> None:
                    red.done(
                        p.pair_id, {k: round(v, 4) for k, v in r.timings.items()}, r.quality
                    )
                    if r.warning:
                        red.warn(p.pair_id, p.describe(), r.warning)
                    progress.advance()

                if state.fields is not None:  # written while the next pair is processed
                    in_flight.append((writer.submit(state.fields.write, state.ctx, p, r), record))
                else:
                    record()
                if red.count():
                    written()
                    red.checkpoint()
            written()
        except KeyboardInterrupt:
            try:
                written()
            except Exception:  # noqa: BLE001 - the interrupt propagates, not the write's error
                consistent = False  # a pair finished without its fields: no checkpoint
            if consistent:  # keep what is done: a restart resumes from here
                campaign.save_checkpoint(state.ctx, state.accs, state.finished, state.timings)
                state.log.write("interrupted", finished=len(state.finished))
            raise
        finally:
            reader.shutdown(wait=True, cancel_futures=True)
            writer.shutdown(wait=True)
        red.checkpoint()
        return red.skipped, None
