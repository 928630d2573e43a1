"""A campaign's statistics re-reduced from each pair's field files, without its PIV.

A 35,000-pair campaign at 14 pairs/min holds 40 hours of PIV on 2 cores. When it is done, the
pairs said unlike the run (:mod:`rspiv.campaign.pair_quality`: a weak laser pulse, a camera
shaken between the exposures) or found otherwise are to be left out (``[images]
exclude_pairs``), or a statistic that rides on the pairs is wanted after all (``[statistics]
two_point`` or ``vorticity``, an ensemble band). Its checkpoint holds sums over the pairs
that cannot be taken apart (the lag-1 chains, the central moments to order 8): the
statistics must be summed again. With ``[output] fields = true`` every pair's fields are on
disk, and :func:`resume` sums them again from the files, in pair order, in place of the PIV;
the run then goes on with the pairs still to do.

When
    The checkpoint (``OUT/checkpoint/``) holds finished pairs that are no longer among the
    campaign's (``exclude_pairs``, ``max_pairs``, files removed at the end of the list), or it
    was written for another context whose
    :meth:`~rspiv.campaign.spec.PairContext.fields_fingerprint` is this one's (only the
    statistics planned beside the fields changed).

Needs
    ``[output] fields = true``, and for every finished pair kept, every run's file
    (:func:`rspiv.campaign.fields.read_pair`) carrying this context's fields fingerprint. With
    an ensemble band also the pair's frames: a band correlates the images, not the fields, so
    they are read, conditioned, dewarped for Method I and correlated in the band
    (:func:`rspiv.campaign.pair.band_pair`), without the PIV. Otherwise the checkpoint is
    refused as before, in one line that also says why its statistics could not be re-reduced
    (:func:`rspiv.campaign.checkpoint.stale_error`); nothing is written until every pair is
    summed again.

What equals what
    The statistics equal those of a campaign run afresh without those pairs, to the float32
    rounding of the stored fields (about 6e-8 of each displacement: 1e-6 px at 20 px); the
    lag-1 chains join across a pair left out as they do in the fresh run. A pair's figures and
    warning (the run log's ``pair`` and ``warning`` events) are carried over to a new context
    fingerprint, so that the pairs' series, screen and warnings see it. The run log and that
    run's ``summary.json`` have a ``rereduced`` entry (the pairs, those left out, whether the
    context changed, the seconds); ``summary.json`` lists ``excluded_pairs`` in every run.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rspiv.campaign import checkpoint
from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign.fields import read_pair
from rspiv.campaign.pair import band_pair, read_checked_pair
from rspiv.campaign.reduce import add_fields, new_accumulators
from rspiv.campaign.spec import PairContext, PairResult
from rspiv.campaign.state import RunState
from rspiv.errors import InvalidInputError

__all__ = ["resume"]


def resume(camp: Any, state: RunState, ctx: PairContext) -> dict[str, Any] | None:
    """The campaign's checkpoint for ``ctx`` (:func:`rspiv.campaign.checkpoint.load_checkpoint`),
    its statistics re-reduced from the field files when it is stale (module docs).

    Returns
    -------
    dict or None
        The checkpoint's state (``accumulators``, ``finished``, ``timings``), None without one.

    Raises
    ------
    InvalidInputError
        One line: the checkpoint is corrupt, of another version or of other frames, or stale
        and its statistics cannot be re-reduced (why, and what to do).
    """
    path = camp.checkpoint_path()
    pairs = camp.pair_index()
    ck = checkpoint.load_checkpoint(path, ctx, pairs, stale_ok=True)
    if ck is None:
        return None
    stale = ck.pop("stale")
    if not (stale["config"] or stale["gone"]):
        return ck
    ids = sorted(i for i in ck["finished"] if i in pairs)
    writer = camp.field_writer()
    why_not = ""
    if writer is None:
        why_not = "[output] fields is off"
    elif ck.get("fields_fingerprint") != ctx.fields_fingerprint():
        why_not = (
            "the pairs' fields themselves change (calibration, PIV, mask, conditioning, runs or "
            "the run's direction)"
            if "fields_fingerprint" in ck
            else "the checkpoint was written by an rspiv without field fingerprints"
        )
    else:
        missing = [i for i in ids for r in ctx.runs if not writer.path(r.name, i).is_file()]
        if missing:
            why_not = (
                f"{len(missing)} field file(s) missing, e.g. "
                f"{writer.path(ctx.runs[0].name, missing[0]).parent.parent}/*/pair_"
                f"{missing[0]:06d}.nc"
            )
    if why_not:
        raise checkpoint.stale_error(path, stale, len(pairs), why_not)
    try:
        return _rebuild(camp, state, ctx, ck, ids, stale)
    except InvalidInputError as exc:
        raise checkpoint.stale_error(path, stale, len(pairs), str(exc)) from None


def _rebuild(
    camp: Any,
    state: RunState,
    ctx: PairContext,
    ck: dict[str, Any],
    ids: list[int],
    stale: dict[str, Any],
) -> dict[str, Any]:
    """``ck`` with its accumulators summed again from the field files of the pairs ``ids`` (and
    their frames, for an ensemble band), its finished pairs ``ids``."""
    t0 = time.perf_counter()
    writer = camp.field_writer()
    pairs = camp.pair_index()
    shape = tuple(ctx.grid()[0].shape)
    fp = ctx.fields_fingerprint()
    accs = new_accumulators(ctx)
    screens = ctx.screens()
    bands = ensemble_work.band_accumulators(accs)
    gone = stale["gone"]
    what = (
        f"pair(s) {', '.join(map(str, gone[:8]))}{' ...' if len(gone) > 8 else ''} left out"
        if gone
        else "the statistics planned beside the fields changed"
    )
    camp.say(
        f"checkpoint: {what}: re-reducing the statistics of {len(ids)} finished pair(s) from "
        f"their field files{' and the bands from their frames' if bands else ''}, without the PIV"
    )

    def load(pid: int) -> tuple[dict[str, Any], Any]:
        fields = {
            r.name: read_pair(writer.path(r.name, pid), shape, r.name, fp) for r in ctx.runs
        }
        frames = read_checked_pair(pairs[pid], ctx.image_shape) if bands else None
        return fields, frames

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="rspiv-reread") as reader:
        ahead = reader.submit(load, ids[0]) if ids else None
        for k, pid in enumerate(ids):
            fields, frames = ahead.result()
            ahead = reader.submit(load, ids[k + 1]) if k + 1 < len(ids) else None
            add_fields(accs, PairResult(pid, True, fields=fields), screens)
            if bands:
                band_pair(ctx, frames, bands)
    seconds = time.perf_counter() - t0
    if stale["config"]:
        _carry_events(state, ck.get("fingerprint"), ctx.fingerprint(), ids)
    timings = dict(ck.get("timings", {}))
    timings["statistics"] = timings.get("statistics", 0.0) + seconds
    state.log.write(
        "rereduced", pairs=len(ids), left_out=gone, config=stale["config"],
        seconds=round(seconds, 3), fingerprint=ctx.fingerprint(),
    )  # fmt: skip
    camp.say(f"checkpoint: {len(ids)} pair(s) re-reduced in {seconds:.1f} s")
    # for this run's summary.json (prepare wrote context.json's info before)
    camp.info["rereduced"] = {
        "pairs": len(ids), "left_out": gone, "config": stale["config"],
        "seconds": round(seconds, 3),
    }  # fmt: skip
    camp.save_checkpoint(ctx, accs, set(ids), timings)
    return {**ck, "accumulators": accs, "finished": ids, "timings": timings}


def _carry_events(state: RunState, old: str | None, new: str, ids: list[int]) -> None:
    """Write each re-reduced pair's last ``pair`` event with figures, and its ``warning``
    event, logged under the checkpoint's context fingerprint ``old``, again under ``new``
    (their figures are the fields', which did not change), so that the run's series and
    warnings see them."""
    keep = set(ids)
    for event, key in (("pair", "quality"), ("warning", "reason")):
        last: dict[int, dict[str, Any]] = {}
        for rec in state.log.events(event):
            pid = rec.get("pair_id")
            if pid in keep and key in rec and rec.get("fingerprint") == old:
                last[int(pid)] = rec
        for pid in sorted(last):
            rec = {k: v for k, v in last[pid].items() if k not in ("time", "event")}
            state.log.write(event, **{**rec, "fingerprint": new, "rereduced": True})
