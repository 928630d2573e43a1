"""A campaign's screen of its statistics (:mod:`rspiv.outlier_screen`): planned before the run,
applied where the fields meet the statistics, said at the end.

:func:`plan` runs the PIV of pilot pairs spread over the run (``camp.pilot_pairs``, at least
:data:`MIN_PILOT`, evenly in pair id; a pair that fails or is left out is replaced by the next
one) for every run, and freezes
each run's :class:`~rspiv.outlier_screen.ScreenBounds` in ``OUT/screen_<run>.npz`` and the
context (``PairContext.screen``: the bounds' digests, so that other bounds are other
statistics; not in ``fields_fingerprint``: the field files keep the PIV's own validation, and a
screen switched on, off or changed after a run sums the statistics again from them,
:mod:`rspiv.campaign.rereduce`). Pairs spread over the run rather than the first ones: the
first pairs of a time-resolved recording are one state of the flow, and a drift over the run
belongs in the spread.

:func:`apply` leaves the screened vectors out of a field as the PIV's rejected ones are (the
statistics, the two-point sums with the centre as their replacement, the vorticity, the peak
locking's histogram, the second passes over the field files: quadrants, POD, vortices,
conditional averages, frequency spectra) and counts them
(:class:`~rspiv.outlier_screen.ScreenTally`, carried with the statistics through checkpoints,
shards, ``rspiv merge`` and Dask).

:func:`run_summary` gives ``summary.json``'s ``screen`` per run, says rows where more than 1 %
of the vectors were screened (a part of the recording that often does not correlate: a scratch,
a glare spot, a bubble's path), and :func:`report_text` the report's paragraph.
"""

from __future__ import annotations

import dataclasses
import pathlib
import time
from typing import Any

import numpy as np

from rspiv.campaign import pair as pair_work
from rspiv.campaign.spec import PairContext, PairSpec
from rspiv.outlier_screen import (
    HALF_BLOCK,
    HALF_WIDTH,
    SAY_SHARE,
    ScreenBounds,
    ScreenTally,
    screen_bounds,
)

__all__ = [
    "MIN_PILOT",
    "TRIES",
    "apply",
    "attach",
    "missing",
    "plan",
    "report_text",
    "run_summary",
]

#: A screen needs at least this many usable pilot pairs (fewer: no screen, said).
MIN_PILOT = 3
#: Pairs tried for each pilot pair (the target and the ones after it).
TRIES = 3


def _targets(ids: list[int], k: int) -> list[int]:
    """``k`` pair ids spread evenly from the first of ``ids`` to the last (in id space, so
    that a pair left out does not move the others' choice)."""
    return sorted({int(round(t)) for t in np.linspace(ids[0], ids[-1], min(k, len(ids)))})


def plan(camp: Any, ctx: PairContext, pairs: list[PairSpec], info: dict) -> PairContext:
    """The bounds of every run of ``ctx`` from pilot pairs spread over ``pairs``; ``ctx`` with
    them (unchanged with ``[statistics] screen = 0`` or too few usable pairs, which the log and
    ``info["screen"]`` say)."""
    sigmas = float(camp.config.statistics.screen)
    if sigmas <= 0 or not pairs:
        return ctx
    t0 = time.perf_counter()
    want = max(camp.pilot_pairs, MIN_PILOT)
    got: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    used: list[int] = []
    by_id = {p.pair_id: p for p in pairs}
    ids = sorted(by_id)
    tried: set[int] = set()
    for target in _targets(ids, want):
        # the target pair, else the next ones after it (missing, unreadable, left out)
        for pid in [i for i in ids if i >= target and i not in tried][:TRIES]:
            tried.add(pid)
            r = pair_work.process_pair(ctx, by_id[pid])
            if r.ok:
                for name, (u, v, valid, *_) in r.fields.items():
                    got.setdefault(name, []).append((u, v, valid))
                used.append(pid)
                break
    if len(used) < MIN_PILOT:
        why = f"{len(used)} usable pilot pair(s), {MIN_PILOT} needed"
        info["screen"] = {"sigmas": sigmas, "off": why}
        camp.say(f"screen of the statistics: off ({why})")
        return ctx
    # a wall's layer changes across the rows only: each vector's row; else a square block
    hw, hh = (HALF_WIDTH, 0) if camp.config.wall.enabled else (HALF_BLOCK, HALF_BLOCK)
    runs = {}
    for name, fields in got.items():
        us, vs, oks = zip(*fields, strict=True)
        bounds = screen_bounds(
            us, vs, oks, sigmas=sigmas, half_width=hw, half_height=hh, pairs=used
        )
        path = camp.out_dir / f"screen_{name}.npz"
        bounds.save(path)
        runs[name] = {"path": str(path), "digest": bounds.digest()}
    seconds = time.perf_counter() - t0
    info["screen"] = {
        "sigmas": sigmas,
        "pilot_pairs": used,
        "neighbourhood": {"columns": 2 * hw + 1, "rows": 2 * hh + 1},
        "seconds": round(seconds, 2),
    }
    camp.say(
        f"screen of the statistics: bounds at {sigmas:g} local spreads from {len(used)} pilot "
        f"pairs spread over the run ({seconds:.1f} s)"
    )
    screen = {"sigmas": sigmas, "pairs": used, "runs": runs}
    return dataclasses.replace(ctx, screen=screen, _cache={})


def missing(screen: dict[str, Any] | None) -> list[str]:
    """The bounds files a context's ``screen`` names that are not there (a folder cleaned
    by hand): such a context is prepared again, to the same bounds."""
    runs = (screen or {}).get("runs", {})
    return [d["path"] for d in runs.values() if not pathlib.Path(d["path"]).is_file()]


def attach(ctx: PairContext, accs: dict[str, Any]) -> dict[str, Any]:
    """An empty :class:`~rspiv.outlier_screen.ScreenTally` on each run's accumulator that
    ``ctx`` screens."""
    for name in (ctx.screen or {}).get("runs", {}):
        if name in accs:
            accs[name].screen = ScreenTally(accs[name].shape)
    return accs


def apply(
    bounds: ScreenBounds | None,
    u: np.ndarray,
    v: np.ndarray,
    valid: np.ndarray,
    tally: ScreenTally | None = None,
    pair_id: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(u, v, valid)`` of a field with its screened vectors left out (``valid`` False, u and
    v their centres: what the two-point sums take for a vector not valid), counted in
    ``tally``; the arrays themselves (not copied) when nothing is screened or without
    bounds."""
    if bounds is None:
        return u, v, valid
    out = bounds.outliers(u, v, valid)
    if tally is not None:
        tally.add(bounds, u, v, out, pair_id)
    if not out.any():
        return u, v, valid
    u = np.where(out, bounds.center_u, u)
    v = np.where(out, bounds.center_v, v)
    return u, v, np.asarray(valid, bool) & ~out


def run_summary(
    camp: Any, run: Any, acc: Any, dist_px: np.ndarray | None = None, off_wall: float = 0.0
) -> Any:
    """``summary.json``'s ``screen`` of a run (None without a screen); rows over
    :data:`~rspiv.outlier_screen.SAY_SHARE` are said in the log. ``dist_px``: the rows'
    distances from a found wall (None without one); the rows closer than ``off_wall`` px, or
    behind it, are not said (their windows reach the wall and its reflection: the statistics
    flag them ``near_wall``)."""
    tally = getattr(acc, "screen", None)
    if tally is None:
        return None
    got = tally.result(acc.count)
    out: dict[str, Any] = {
        "sigmas": camp.config.statistics.screen,
        "vectors": got["vectors"],
        "share": round(got["share"], 6),
        "pairs_with_any": got["pairs_with_any"],
        "most_screened_pairs": got["pairs"],
    }
    added = np.maximum(got["row_added_uu"], got["row_added_vv"])
    if dist_px is not None:  # the rows in the flow, as for the rows said
        added = np.where(np.asarray(dist_px) >= off_wall, added, -1.0)
    if added.size and added.max() >= 0:
        j = int(np.argmax(added))
        out["largest_added_variance_px2"] = {
            "row": j,
            "uu": round(float(got["row_added_uu"][j]), 6),
            "vv": round(float(got["row_added_vv"][j]), 6),
        }
    said = list(zip(got["rows_said"], got["rows_said_share"], strict=True))
    if dist_px is not None:
        said = [(j, s) for j, s in said if dist_px[j] >= off_wall]
    if said:
        rows = [j for j, _ in said]
        if dist_px is None:
            where = f"rows {rows[0]} to {rows[-1]} of the grid"
        else:
            d = sorted((dist_px[rows[0]], dist_px[rows[-1]]))
            where = f"{_px(d[0])} to {_px(d[1])} px from the wall"
        line = (
            f"{run.label}: the screen left out more than {100 * SAY_SHARE:g} % of the vectors "
            f"in {len(rows)} row(s) ({where}; at most {100 * max(s for _, s in said):.1f} %): "
            "a part of the recording that often does not correlate (a glare spot, a scratch, "
            "bubbles, too few particle images), or events the pilot pairs did not see; those "
            "rows rest on fewer pairs (screened_count in the statistics file; [statistics] "
            "screen = 0 sums them again without it)"
        )
        out["rows_said"] = rows
        out["warning"] = line
        camp.say(f"warning: {line}")
    return out


def _px(d: float) -> str:
    return f"{d:.0f}" if np.isfinite(d) else "?"


def report_text(res: Any) -> str:
    """The report's sentences on the screen of each run ("" without one)."""
    info = (res.context.screen or {}) if res.context is not None else {}
    if not info:
        return ""
    parts = []
    for an in res.analyses.values():
        tally = getattr(res.accumulators.get(an.run.name), "screen", None)
        if tally is None:
            continue
        got = tally.result(res.accumulators[an.run.name].count)
        parts.append(
            f"{an.run.label}: {got['vectors']} vectors ({100 * got['share']:.3f} %) in "
            f"{got['pairs_with_any']} pairs"
        )
    if not parts:
        return ""
    return (
        f"Vectors farther than {info['sigmas']:g} local spreads from the centre of their pilot "
        f"pairs ({len(info['pairs'])} pairs spread over the run) are left out of the "
        "statistics (random vectors the median test passed): " + "; ".join(parts) + "."
    )
