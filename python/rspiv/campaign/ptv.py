"""Particle tracking at the wall over a processed campaign (``rspiv ptv campaign.toml``).

A campaign's profiles come from windows: the 32 x 8 px windows of the paper's last pass span
several wall units, and the rows nearest the wall hold the wall itself or its reflection. This
pass follows each particle image of every pair from frame A to frame B
(:func:`rspiv.ptv.track_particles`), with that pair's own field as the predictor, and bins the
tracks by their distance from the run's wall (:class:`rspiv.ptv_profile.TrackProfile`): the
mean profile and the Reynolds stresses in bins of half a pixel, down to about a particle
image's diameter from the wall, and the wall shear from the viscous sublayer
(:func:`rspiv.ptv_profile.sublayer_fit`) beside the campaign's own ``u_tau``.

Needs
    A campaign processed with ``[output] fields = true``: ``OUT/summary.json`` (the run's wall,
    ``u_tau``, ``nu``), ``OUT/context.json`` written for the campaign file as it is now, and
    the run's field files (``OUT/fields/<run>/pair_<id>.nc``, which carry the context's fields
    fingerprint). Each pair's frames are read again and conditioned as the ensemble bands are
    (the campaign's conditioning without the high-pass filter and the smoothing, which reshape
    the particle images).

Frames per run
    ``none``: the raw frames, the field and the wall in raw px. Method I: the frames dewarped
    to the object frame, as the campaign correlated them. Method II: the raw frames; the
    predictor at a raw point ``p`` is the object field at ``X = F^-1(p)`` mapped as
    ``F(X + D/2) - F(X - D/2)``, and each track's two centres are mapped to the object frame
    by ``F^-1`` (its displacement the difference, its position the midpoint): the tracks are
    corrected exactly, point by point.

Rows searched
    Only the tracks within ``band_px`` of the wall reach the profile, so only the rows that
    can hold them and their partners are searched for particle images
    (:func:`rspiv.ptv.search_rows`): from a margin beyond the wall (the radius, the field's
    largest wall-normal displacement and 8 px) to the band, the margin and
    :data:`CONTEXT_PX` more rows of flow, whose particle images make the detection's frame
    statistics (the threshold's signal, the shape test's diameters) the flow's, as over the
    whole frame, rather than those of the wall's neighbourhood (its reflections, its glare).
    For Method II the band's edges are mapped to the raw frames. The tracks' counts and
    warnings are then those of these rows. At 47 MP a few hundred of 5288 rows; the whole
    frames with ``whole_frame=True`` (``rspiv ptv --whole-frame``).

Outputs (atomic)
    ``OUT/ptv_<run>.csv``: per bin ``h_px`` (object px for the corrected runs), ``n``,
    ``pairs``, ``U``, ``V``, ``uu``, ``vv``, ``uv`` (px per pair; :mod:`rspiv.ptv_profile`'s
    wall frame, ``U`` towards the flow) with ``se_*``, the two-track stresses ``uu_two``,
    ``vv_two``, ``uv_two`` (without the tracks' own error) with ``n_two``, ``near_wall``; with
    the campaign's units
    ``y_m``, ``U_si`` ... (m, m/s, m^2/s^2) and wall units ``y_plus``, ``U_plus``,
    ``uu_plus`` ... from the run's ``u_tau``. ``OUT/ptv_<run>.json``: the settings, the pairs,
    the tracks' counts, the warnings the pairs gave (each once, with how many pairs and the
    figures of the first pair that gave it), the tracks' own error at most
    (``track_error_px2``: the single-track stresses less the two-track ones), the sublayer fit
    (``u_tau`` from it with its standard error against the campaign's), the pairs' serial
    correlation (``serial_factor_U``, ``serial_open`` and, where the errors are lower bounds,
    ``serial_warning``, also in ``profile_warning``, said in the log) and the fields'
    fingerprint. ``OUT/ptv_<run>.png``:
    the profile's figure (:func:`rspiv.plots.ptv.plot_track_profile`, beside the campaign's
    windowed profile and the DNS).

Shards
    A long pass splits over processes or cluster jobs: ``campaign_ptv(..., shard=(i, n))``
    (``rspiv ptv campaign.toml --shard i/n``) tracks every n-th pair from the i-th into its own
    resumable state ``OUT/ptv/<run>.shard-<i>-of-<n>.pkl``; once all n are complete,
    :func:`merge_ptv` (``rspiv ptv campaign.toml --merge``) sums them (the profile's sums add
    up: the same profile as one pass, to rounding) and writes the outputs.

From the campaign file
    ``[ptv] enabled = true`` (with ``[output] fields = true``) runs the pass over the
    section's ``runs`` (none given: the campaign's first run; a run the campaign does not have
    is said and left) at the end of ``rspiv process``, once the analysis has written
    ``summary.json`` and before the report (:func:`configured_ptv`), with the section's
    ``radius``, ``bin_px``, ``band_px`` and ``whole_frame``; ``rspiv ptv`` takes its defaults
    from the same section. A campaign processed again resumes the pass (no pair tracked twice
    while the fields stay the same). A sharded campaign's shards do not track; the merge's
    analysis does, in one process (``rspiv ptv --shard`` spreads it instead).

Report
    The campaign report (``OUT/report``, written by ``rspiv process``; a processed campaign's
    report is written again by ``rspiv process`` in seconds, no pair processed again) has a
    section "Particle tracking at the wall" for every run tracked over the fields as they are
    (:func:`report_section`); a pass over other fields is named there, not shown.

Resuming
    Every :data:`CHECKPOINT_EVERY` pairs the profile's sums and the pairs done are written to
    ``OUT/ptv/<run>.pkl`` (atomically); a pass started again with the same settings and fields
    goes on from there; with other settings it starts afresh (said).
"""

from __future__ import annotations

import collections
import dataclasses
import json
import pathlib
import pickle
import re
import time
from typing import Any

import numpy as np

from rspiv.campaign.pair import read_checked_pair
from rspiv.campaign.ptv_pair import CONTEXT_PX, pair_field, pair_tracks
from rspiv.campaign.spec import PairContext
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outputs import (
    atomic_write_bytes,
    atomic_write_text,
    read_profile_csv,
    write_profile_csv,
)
from rspiv.profiles import VERDICT_PAIRS
from rspiv.ptv_profile import TrackProfile, WallLine, sublayer_fit
from rspiv.reference import dns_profile_for_re_tau

__all__ = [
    "CHECKPOINT_EVERY",
    "CONTEXT_PX",
    "campaign_ptv",
    "configured_ptv",
    "merge_ptv",
    "report_section",
]

#: The report section's opening paragraph.
REPORT_TEXT = (
    "Each particle image followed from frame A to frame B through the pair's own field "
    "(`rspiv ptv`), the tracks binned by their distance from the wall: the mean velocity and "
    "the Reynolds stresses down to about a particle image's diameter from the wall, and the "
    "wall shear from the viscous sublayer's gradient (with the DNS's curvature taken out) "
    "beside the campaign's. Error bars and errors: the scatter between pairs. The stresses "
    "include the tracks' own error (about 0.01 px^2 per component on clean images), which "
    "dominates vv within a few wall units of the wall; the two-track stresses (the products "
    "of two tracks' fluctuations a few px apart along the wall, extrapolated to none) leave it "
    "out, at the price of larger errors (the figure's third panel)."
)

#: Pairs between two checkpoints of the pass.
CHECKPOINT_EVERY = 20

#: The state file's format (a pass resumes only a state of its own format).
_STATE_VERSION = 3  # 2: the two-track stresses' sums; 3: the rows searched




def _context(camp: Any) -> tuple[PairContext, dict[str, Any]]:
    """The frozen context and the summary of the campaign's last processing (the fields, the
    wall and ``u_tau`` all come from it, whatever the campaign file says since)."""
    out = pathlib.Path(camp.out_dir)
    summary_path, ctx_path = out / "summary.json", out / "context.json"
    if not summary_path.is_file() or not ctx_path.is_file():
        raise InvalidInputError(
            f"{out}: no summary.json or context.json: process the campaign first (rspiv process)"
        )
    try:
        saved = json.loads(ctx_path.read_text(encoding="utf-8"))
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        ctx = PairContext.from_dict(saved["context"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInputError(f"{out}: cannot read the campaign's outputs: {exc}") from None
    return ctx, summary


def _wall(summary: dict[str, Any], run: str) -> WallLine:
    """The run's wall as its analysis found it (``summary.json``)."""
    r = summary.get("runs", {}).get(run, {})
    w = r.get("wall")
    if not w or not np.isfinite(w.get("intercept_px", np.nan)):
        raise InvalidInputError(f"run {run}: summary.json holds no wall: nothing to track against")
    return WallLine(float(w["intercept_px"]), float(w["slope"]), r.get("flow_side", "above"))


def campaign_ptv(
    camp: Any,
    run: str | None = None,
    *,
    radius: float = 2.0,
    bin_px: float = 0.5,
    band_px: float = 32.0,
    max_pairs: int = 0,
    resume: bool = True,
    shard: tuple[int, int] | None = None,
    whole_frame: bool = False,
) -> dict[str, Any]:
    """Track the particle images of a processed campaign's pairs at the wall (module docstring).

    Parameters
    ----------
    camp : rspiv.Campaign
        The campaign (``rspiv.Campaign.load(path)``).
    run : str, optional
        The run (``method_II``, ``method_I``, ``uncorrected``); default the campaign's first.
    radius, bin_px, band_px
        :func:`rspiv.ptv.track_particles`'s search radius and
        :class:`rspiv.ptv_profile.TrackProfile`'s bins (px of the run's frame).
    max_pairs : int
        Track only the first this many pairs with fields (0: all).
    resume : bool
        Go on from the pass's checkpoint when its settings match.
    shard : (int, int), optional
        ``(i, n)``: track only the i-th of every n pairs (1-based) into the shard's own state
        ``OUT/ptv/<run>.shard-<i>-of-<n>.pkl``, writing no profile; :func:`merge_ptv` writes
        it once every shard is done (module docstring, "Shards").
    whole_frame : bool
        Search the whole frames for particle images, not only the rows of the band and its
        margins (module docstring, "Rows searched"); the same profile, at 47 MP several times
        slower.

    Returns
    -------
    dict
        What ``OUT/ptv_<run>.json`` holds, with ``csv`` and ``json`` the files written; for a
        shard, ``run``, ``shard``, ``pairs``, ``skipped``, ``seconds`` and ``state``.

    Raises
    ------
    InvalidInputError
        A campaign not processed, without field files for the run, an unknown run, a run
        without a wall, bad settings, no pair tracked (a pair whose frames cannot be read or
        whose field file was written for other frames is skipped with its reason).
    """
    if not (isinstance(radius, int | float) and np.isfinite(radius) and radius > 0):
        raise InvalidInputError(f"radius must be a finite number of px > 0, got {radius!r}")
    if shard is not None:
        i, n = shard
        if not (isinstance(i, int) and isinstance(n, int) and 1 <= i <= n):
            raise InvalidInputError(f"shard {shard!r}: give (i, n) with 1 <= i <= n")
    ctx, summary = _context(camp)
    runs = {r.name: r for r in ctx.runs}
    name = run or ctx.runs[0].name
    if name not in runs:
        raise InvalidInputError(f"run {name!r}: the campaign's runs are {', '.join(runs)}")
    spec = runs[name]
    wall = _wall(summary, name)
    out = pathlib.Path(camp.out_dir)
    fdir = out / "fields" / name
    files = {
        int(m.group(1)): p
        for p in sorted(fdir.glob("pair_*.nc"))
        if (m := re.fullmatch(r"pair_(\d{6})\.nc", p.name))
    }
    pairs = camp.pair_index()
    ids = [pid for pid in sorted(files) if pid in pairs]
    if not ids:
        raise InvalidInputError(
            f"{fdir}: no field files of the campaign's pairs: process it with [output] fields = "
            "true first (the pass takes each pair's field as its predictor)"
        )
    if max_pairs:
        ids = ids[: int(max_pairs)]
    if shard is not None:
        ids = ids[shard[0] - 1 :: shard[1]]
    shape = tuple(ctx.grid()[0].shape)
    fp = ctx.fields_fingerprint()
    window = tuple(int(c) for c in ctx.piv.passes[-1])
    settings = {"radius": float(radius), "bin_px": float(bin_px), "band_px": float(band_px),
                "whole_frame": bool(whole_frame)}  # fmt: skip
    search_band = None if whole_frame else float(band_px)
    prof = TrackProfile(wall, bin_px=bin_px, band_px=band_px)
    state_path = out / "ptv" / (
        f"{name}.pkl" if shard is None else f"{name}.shard-{shard[0]}-of-{shard[1]}.pkl"
    )
    done: list[int] = []
    counts: collections.Counter = collections.Counter()
    said: collections.Counter = collections.Counter()
    first: dict[str, str] = {}  # each warning as its first pair said it, figures and all
    skipped: dict[int, str] = {}
    key = {"version": _STATE_VERSION, "fingerprint": fp, "settings": settings}
    if resume and state_path.is_file():
        try:
            st = pickle.loads(state_path.read_bytes())
            if {k: st.get(k) for k in key} == key and set(st["done"]) <= set(ids):
                prof, done, counts, said = st["profile"], st["done"], st["counts"], st["said"]
                first = st.get("first", {})
                skipped = st["skipped"]
                camp.say(f"ptv {name}: resuming after {len(done)} pair(s) ({state_path})")
            else:
                camp.say(
                    f"ptv {name}: {state_path} was written with other settings or pairs; afresh"
                )
        except (OSError, pickle.UnpicklingError, KeyError, EOFError, AttributeError):
            camp.say(f"ptv {name}: {state_path} cannot be read; starting afresh")

    def save(complete: bool = False) -> None:
        st = {**key, "profile": prof, "done": done, "counts": counts, "said": said, "first": first,
              "skipped": skipped, "ids": ids, "complete": complete,
              "seconds": seconds + time.perf_counter() - t0}  # fmt: skip
        atomic_write_bytes(state_path, pickle.dumps(st, protocol=pickle.HIGHEST_PROTOCOL))

    seconds = 0.0  # of the earlier passes this state resumes (a shard's time, all told)
    if done or skipped:
        seconds = float(st.get("seconds", 0.0))
    t0 = time.perf_counter()
    seen = set(done) | set(skipped)
    todo = [pid for pid in ids if pid not in seen]
    for k, pid in enumerate(todo):
        try:
            frames = read_checked_pair(pairs[pid], ctx.image_shape)
            field = pair_field(files[pid], pairs[pid], shape, name, fp, window)
            tracks = pair_tracks(ctx, spec, frames, field, wall, radius, search_band)
        except (RspivError, ValueError, OSError) as exc:
            skipped[pid] = str(exc)
            camp.say(f"ptv {name}: pair {pid} skipped: {exc}")
            continue
        prof.add(tracks, pair_id=pid)
        counts.update(tracks.status)
        counts["tracks"] += len(tracks)
        counts["detected_a"] += tracks.detected[0]
        for w in tracks.warnings:
            said[_general(w)] += 1
            first.setdefault(_general(w), w)
        done.append(pid)
        if (k + 1) % CHECKPOINT_EVERY == 0:
            save()
            camp.say(f"ptv {name}: {len(done)} of {len(ids)} pair(s)")
    save(complete=True)
    if shard is not None:  # the merge writes the profile
        return {"run": name, "shard": f"{shard[0]}/{shard[1]}", "pairs": len(done),
                "skipped": len(skipped), "seconds": seconds + time.perf_counter() - t0,
                "state": str(state_path)}  # fmt: skip
    if not done:
        reason = next(iter(skipped.values()), "no pair")
        raise InvalidInputError(f"ptv {name}: no pair tracked ({len(skipped)} skipped: {reason})")
    # each warning once, with the figures of the first pair that gave it
    warned = {first.get(w, w): n for w, n in said.most_common()}
    return _write(camp, summary, ctx, name, prof, settings, done, counts, warned, skipped,
                  time.perf_counter() - t0)  # fmt: skip


def configured_ptv(camp: Any) -> list[dict[str, Any]]:
    """The passes a campaign file asks for (``[ptv] enabled``), over its ``runs`` (none given:
    the first) with the file's settings, run by the analysis once ``summary.json`` holds the
    walls (module docstring, "From the campaign file"): what :func:`campaign_ptv` returned for
    each run tracked; none when not asked for. A run that cannot be tracked (not among the
    campaign's, no wall ...) is said in the log and left: the campaign's own outputs stand."""
    pc = getattr(camp.config, "ptv", None)
    if pc is None or not pc.enabled:
        return []
    done = []
    for run in pc.runs or (None,):
        try:
            info = campaign_ptv(
                camp, run, radius=pc.radius, bin_px=pc.bin_px, band_px=pc.band_px,
                whole_frame=pc.whole_frame,
            )  # fmt: skip
        except InvalidInputError as exc:
            camp.say(f"warning: [ptv]: no tracks at the wall: {exc}")
            continue
        s = info["sublayer"]
        fit = (
            f"u_tau from the viscous sublayer {s['u_tau']:.4g} +- {s['se_u_tau']:.2g} m/s"
            if "u_tau" in s
            else f"no sublayer u_tau ({s.get('reason', 'no units')})"
        )
        camp.say(
            f"ptv {info['run']}: {info['pairs']} pair(s), {info['counts'].get('tracks', 0)} "
            f"tracks at the wall; {fit} -> {info['csv']}"
        )
        for w in ([info["profile_warning"]] if info.get("profile_warning") else []) + list(
            info["warnings"]
        ):
            camp.say(f"warning: ptv {info['run']}: {w}")
        done.append(info)
    return done


def merge_ptv(camp: Any, run: str | None = None) -> dict[str, Any]:
    """Write the profile of a pass run in shards (:func:`campaign_ptv` with ``shard``): the
    states ``OUT/ptv/<run>.shard-<i>-of-<n>.pkl`` of every ``i`` of one ``n``, each complete,
    of one set of settings and of the campaign's fields as they are, summed into one profile
    (:meth:`rspiv.ptv_profile.TrackProfile.merge`) and written as :func:`campaign_ptv`
    writes it.

    Returns
    -------
    dict
        What ``OUT/ptv_<run>.json`` holds (``seconds``: the shards' time, summed).

    Raises
    ------
    InvalidInputError
        No shard, shards of more than one count, a shard missing or not complete, shards of
        other settings, of other pairs (another ``max_pairs``) or of other fields than the
        campaign's, no pair tracked.
    """
    ctx, summary = _context(camp)
    names = [r.name for r in ctx.runs]
    name = run or names[0]
    if name not in names:
        raise InvalidInputError(f"run {name!r}: the campaign's runs are {', '.join(names)}")
    sdir = pathlib.Path(camp.out_dir) / "ptv"
    found: dict[int, dict[int, pathlib.Path]] = collections.defaultdict(dict)
    for path in sdir.glob(f"{name}.shard-*-of-*.pkl"):
        if m := re.fullmatch(rf"{re.escape(name)}\.shard-(\d+)-of-(\d+)\.pkl", path.name):
            found[int(m.group(2))][int(m.group(1))] = path
    if not found:
        raise InvalidInputError(f"{sdir}: no shard of run {name} (rspiv ptv --shard I/N first)")
    if len(found) > 1:
        raise InvalidInputError(
            f"{sdir}: shards of {' and of '.join(str(n) for n in sorted(found))} for run {name}: "
            "remove the states of the count not wanted"
        )
    ((n, paths),) = found.items()
    missing = [i for i in range(1, n + 1) if i not in paths]
    if missing:
        raise InvalidInputError(
            f"{sdir}: shard {missing[0]} of {n} of run {name} is missing: run `rspiv ptv "
            f"--shard {missing[0]}/{n}` first"
        )
    fp = ctx.fields_fingerprint()
    states = []
    for i in range(1, n + 1):
        try:
            st = pickle.loads(paths[i].read_bytes())
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError) as exc:
            raise InvalidInputError(f"{paths[i]}: cannot be read ({exc})") from exc
        if st.get("version") != _STATE_VERSION or st.get("fingerprint") != fp:
            raise InvalidInputError(
                f"{paths[i]}: written for other fields than the campaign's (processed again "
                "since?) or by another version: run the shard again"
            )
        if not st.get("complete"):
            raise InvalidInputError(
                f"{paths[i]}: shard {i} of {n} stopped after {len(st['done'])} of "
                f"{len(st['ids'])} pair(s): run it again to finish"
            )
        if states and st["settings"] != states[0]["settings"]:
            raise InvalidInputError(
                f"{paths[i]}: settings {st['settings']} differ from shard 1's "
                f"{states[0]['settings']}"
            )
        states.append(st)
    # every shard took every n-th of one list of pairs (shards of other --max-pairs do not)
    union = sorted({pid for st in states for pid in st["ids"]})
    for i, st in enumerate(states, 1):
        if list(st["ids"]) != union[i - 1 :: n]:
            took, want = list(st["ids"]), union[i - 1 :: n]
            raise InvalidInputError(
                f"{paths[i]}: shard {i} of {n} took pairs {_ids(took)}, not {_ids(want)} (every "
                f"{n}-th of the shards' {len(union)} from the {i}-th): shards run with other "
                "--max-pairs? run them again alike"
            )
    prof = states[0]["profile"]
    counts: collections.Counter = collections.Counter()
    said: collections.Counter = collections.Counter()
    first: dict[str, str] = {}
    done: list[int] = []
    skipped: dict[int, str] = {}
    for k, st in enumerate(states):
        if k:
            prof.merge(st["profile"])
        counts.update(st["counts"])
        said.update(st["said"])
        for g, w in st["first"].items():
            first.setdefault(g, w)
        done += st["done"]
        skipped.update(st["skipped"])
    if not done:
        reason = next(iter(skipped.values()), "no pair")
        raise InvalidInputError(f"ptv {name}: no pair tracked ({len(skipped)} skipped: {reason})")
    warned = {first.get(w, w): c for w, c in said.most_common()}
    seconds = sum(float(st.get("seconds", 0.0)) for st in states)
    camp.say(f"ptv {name}: {n} shard(s) merged, {len(done)} pair(s)")
    return _write(camp, summary, ctx, name, prof, states[0]["settings"], sorted(done), counts,
                  warned, skipped, seconds)  # fmt: skip


def _ids(ids: list) -> str:
    """Pair ids for a message: all of a few, else the first five and how many."""
    head = ", ".join(str(i) for i in ids[:5])
    return head if len(ids) <= 5 else f"{head} ... ({len(ids)})"


def _general(warning: str) -> str:
    """A pair's warning without its figures (the same warning of many pairs, said once)."""
    return re.sub(r"\d+(\.\d+)?", "#", warning)


def _write(camp, summary, ctx, name, prof, settings, done, counts, said, skipped, seconds):
    """The pass's profile and summary files (module docstring)."""
    res = prof.result()
    out = pathlib.Path(camp.out_dir)
    r = summary["runs"][name]
    ut, nu = r.get("u_tau"), r.get("nu")
    cfg = camp.config
    dt = getattr(cfg.flow, "dt", None)
    m_per_px = _m_per_px(ctx, camp)
    U = res["U"][np.isfinite(res["U"])]
    sign_x = -1.0 if U.size and np.median(U) < 0 else 1.0
    cols: dict[str, Any] = {
        "h_px": res["h_px"], "n": res["n"], "pairs": res["pairs"],
        "U": sign_x * res["U"], "se_U": res["se_U"], "V": res["V"], "se_V": res["se_V"],
        "uu": res["uu"], "se_uu": res["se_uu"], "vv": res["vv"], "se_vv": res["se_vv"],
        "uv": sign_x * res["uv"], "se_uv": res["se_uv"],
        "n_two": res["n_two"], "uu_two": res["uu_two"], "se_uu_two": res["se_uu_two"],
        "vv_two": res["vv_two"], "se_vv_two": res["se_vv_two"],
        "uv_two": sign_x * res["uv_two"], "se_uv_two": res["se_uv_two"],
        "near_wall": res["near_wall"].astype(float),
    }  # fmt: skip
    info: dict[str, Any] = {
        "run": name, "method": next(x.method for x in ctx.runs if x.name == name),
        "fingerprint": ctx.fields_fingerprint(),
        "settings": settings, "pairs": len(done), "skipped": skipped,
        "seconds": round(seconds, 3), "counts": dict(counts),
        "diameter_px": float(res["diameter_px"]),
        "track_error_px2": (err := _track_error(cols)),
        "warnings": said,
    }  # fmt: skip
    serial = _serial(res, len(done))
    info.update(serial)
    info["profile_warning"] = "; ".join(
        w for w in (_error_warning(cols, err), serial.get("serial_warning", "")) if w
    )
    si = bool(dt and m_per_px and dt > 0)
    if si:
        v = m_per_px / dt
        cols.update(y_m=res["h_px"] * m_per_px, U_si=cols["U"] * v)
        stresses = [f"{c}{t}" for t in ("", "_two") for c in ("uu", "vv", "uv")]
        cols.update({f"{k}_si": cols[k] * v * v for k in stresses})
        if ut and nu and np.isfinite(ut) and ut > 0:
            cols.update(y_plus=cols["y_m"] * ut / nu, U_plus=cols["U_si"] / ut)
            cols.update({f"{k}_plus": cols[f"{k}_si"] / ut**2 for k in stresses})
    info["sublayer"] = _sublayer(cols, res, ut, nu, dt, m_per_px, sign_x)
    ut_se = r.get("u_tau_std_pairs")  # the campaign's u_tau error from its pairs, if any
    s = info["sublayer"]
    if s.get("difference") is not None and ut_se is not None and np.isfinite(ut_se):
        s["campaign_se_u_tau"] = float(ut_se)
        s["difference_errors"] = float((s["u_tau"] - ut) / np.hypot(s["se_u_tau"], ut_se))
    try:
        info["figure"] = str(_figure(out, name, cols, info["sublayer"], r))
    except Exception as exc:  # noqa: BLE001 -- a figure never costs the profile
        camp.say(f"ptv {name}: figure not drawn: {exc}")
    csv_path = out / f"ptv_{name}.csv"
    meta = {"run": name, "pairs": len(done), "radius_px": settings["radius"]}
    write_profile_csv(csv_path, cols, meta)
    json_path = out / f"ptv_{name}.json"
    info.update(csv=str(csv_path), json=str(json_path))
    atomic_write_text(json_path, json.dumps(info, indent=2, default=float) + "\n")
    return info


def _figure(out: pathlib.Path, name: str, cols, sublayer, run_summary) -> pathlib.Path:
    """``OUT/ptv_<run>.png`` (:func:`rspiv.plots.ptv.plot_track_profile`) with the campaign's
    windowed profile of the run and the DNS station nearest its ``Re_tau``."""
    from rspiv.plots.ptv import plot_track_profile  # deferred: matplotlib only to draw

    piv = None
    if (p := out / f"profile_{name}.csv").is_file():
        piv = read_profile_csv(p)[0]
    re_tau = run_summary.get("re_tau")
    dns = dns_profile_for_re_tau(float(re_tau)) if re_tau and np.isfinite(re_tau) else None
    title = f"Particle tracks at the wall: {run_summary.get('label', name)}"
    return plot_track_profile(
        out / f"ptv_{name}.png", cols, sublayer=sublayer, piv=piv, dns=dns, title=title
    )


def _track_error(cols: dict[str, Any]) -> dict[str, float]:
    """The tracks' own error per component (px^2), at most: the median over the bins off the
    wall of the single-track stress less the two-track one (:mod:`rspiv.ptv_profile`), with
    the median's standard error from the bins' spread; NaN without two-track stresses."""
    out: dict[str, float] = {}
    for c in ("uu", "vv"):
        d = (cols[c] - cols[f"{c}_two"])[cols["near_wall"] == 0]
        d = d[np.isfinite(d)]
        out[c] = float(np.median(d)) if d.size else float("nan")
        out[f"se_{c}"] = float(1.2533 * np.std(d) / np.sqrt(d.size)) if d.size > 1 else float("nan")
    return out


def _serial(res: dict[str, Any], pairs: int) -> dict[str, Any]:
    """The pairs' serial correlation over the bins off the wall with
    :data:`rspiv.profiles.VERDICT_PAIRS` pairs or more (:mod:`rspiv.ptv_profile`): the median
    factor on the variance of U (``serial_factor_U``), the share of those bins where it is a
    lower bound (``serial_open``) and, where that is over a quarter, ``serial_warning``; empty
    for profiles pickled before the lags or without such bins."""
    if "serial_U" not in res:
        return {}
    judged = (res["pairs"] >= VERDICT_PAIRS) & ~res["near_wall"] & np.isfinite(res["U"])
    if not judged.any():
        return {}
    factor, still = res["serial_U"][judged], res["open_U"][judged]
    out: dict[str, Any] = {"serial_factor_U": float(np.median(factor)),
                           "serial_open": float(np.mean(still))}  # fmt: skip
    if out["serial_open"] > 0.25:
        out["serial_warning"] = (
            f"the pairs follow each other too closely for {pairs} of them to say how far the "
            f"tracks' statistics are from the flow's: in {100 * out['serial_open']:.0f} % of "
            "the bins the pairs' correlation lasts longer than a fifth of the lags followed "
            f"(the variance of U {np.median(factor[still]):.1f} times that of independent "
            "pairs and more), so the errors are lower bounds"
        )
    return out


def _error_warning(cols: dict[str, Any], err: dict[str, float]) -> str:
    """What to say when the tracks' own error is more than half the single-track ``vv`` (the
    median over the bins off the wall), beyond two of its standard errors: those stresses
    are then mostly tracking error (a dense or noisy recording, strays). Empty otherwise."""
    vv = np.asarray(cols["vv"], dtype=float)[np.asarray(cols["near_wall"]) == 0]
    vv = vv[np.isfinite(vv)]
    e, se = err.get("vv", np.nan), err.get("se_vv", np.nan)
    if not (vv.size and np.isfinite(e) and np.isfinite(se) and e - 2 * se > 0.5 * np.median(vv)):
        return ""
    return (
        f"the tracks' own error ({e:.3g} +- {se:.2g} px^2 per component) is more than half the "
        f"single-track vv ({np.median(vv):.3g} px^2, the bins' median): those stresses are "
        "mostly tracking error; use the two-track ones (uu_two, vv_two, uv_two)"
    )


def _m_per_px(ctx: PairContext, camp: Any) -> float | None:
    """Metres per px of the run's frame, as the campaign's analysis scales every run: 1e-3
    over the calibration's magnification (px/mm); None without a calibration."""
    cal = getattr(camp, "calibration", None)
    if cal is None:
        path = pathlib.Path(camp.out_dir) / "calibration.json"
        if path.is_file():
            from rspiv.calibration import Calibration  # deferred: only with a calibration

            cal = Calibration.load(path)
    mag = getattr(cal, "magnification", None)
    return 1e-3 / float(mag) if mag else None


def _sublayer(cols, res, ut, nu, dt, m_per_px, sign_x) -> dict[str, Any]:
    """The sublayer fit up to ``y+ = 5`` (by the campaign's ``u_tau``; 8 bins without it),
    its ``u_tau`` against the campaign's, or why there is none."""
    prof = {"h_px": res["h_px"], "U": sign_x * res["U"], "se_U": res["se_U"],
            "near_wall": res["near_wall"]}  # fmt: skip
    units = bool(ut and nu and dt and m_per_px and ut > 0)
    h_max = 5.0 * nu / (ut * m_per_px) if units else 8 * float(np.diff(res["edge_px"][:2])[0])
    try:
        if units:
            fit = sublayer_fit(prof, h_max, nu=nu, dt=dt, scale_m_per_px=m_per_px)
        else:
            fit = sublayer_fit(prof, h_max)
    except InvalidInputError as exc:
        return {"fitted": False, "reason": str(exc), "h_max_px": h_max}
    d = {"fitted": True, **dataclasses.asdict(fit), "h_max_px": h_max}
    if nu and dt:
        try:
            u, se = fit.u_tau(nu, dt)
            d.update(u_tau=u, se_u_tau=se, campaign_u_tau=ut)
            if ut:
                d["difference"] = (u - ut) / ut
        except InvalidInputError as exc:
            d["reason"] = str(exc)
    return d


def report_section(camp: Any, ctx: PairContext) -> Any:
    """The report's section of the runs tracked by ``rspiv ptv`` (``OUT/ptv_<run>.json`` of
    the campaign's fields as they are; a pass over other fields is named, not shown), or
    None when no run was tracked."""
    from rspiv.report import ReportSection, ReportTable  # deferred: the report's writer

    out = pathlib.Path(camp.out_dir)
    fp = ctx.fields_fingerprint()
    rows, figures, said, stale, warned = [], [], [], [], []
    for spec in ctx.runs:
        path = out / f"ptv_{spec.name}.json"
        if not path.is_file():
            continue
        try:
            info = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            stale.append(f"{path.name} (unreadable)")
            continue
        if info.get("fingerprint") != fp:
            stale.append(path.name)
            continue
        s, c = info.get("sublayer") or {}, info.get("counts") or {}
        row = {"run": spec.label, "pairs": info.get("pairs"), "tracks": c.get("tracks")}
        if c.get("detected_a"):
            row["images of A paired (%)"] = 100.0 * c["tracks"] / c["detected_a"]
        row["u_tau, sublayer (m/s)"] = s.get("u_tau")
        row["its SE (m/s)"] = s.get("se_u_tau")
        row["u_tau, campaign (m/s)"] = s.get("campaign_u_tau")
        if s.get("difference") is not None:
            row["difference (%)"] = 100.0 * s["difference"]
        if s.get("difference_errors") is not None:  # in both u_tau's errors combined
            row["difference (errors)"] = s["difference_errors"]
        row["chi2/dof"] = s.get("chi2_dof")
        e = info.get("track_error_px2") or {}
        if e:
            row["tracks' own error uu, vv (px^2, at most)"] = (e.get("uu"), e.get("vv"))
        if s.get("fitted") and np.all(np.isfinite(s.get("y_plus_range", [np.nan]))):
            row["y+ fitted"] = "{:.2f}-{:.2f}".format(*s["y_plus_range"])
        elif not s.get("fitted"):
            row["sublayer"] = s.get("reason", "not fitted")
        rows.append(row)
        warned.append(info.get("profile_warning", ""))
        if info.get("figure") and pathlib.Path(info["figure"]).is_file():
            figures.append((info["figure"], f"{spec.label}: tracks at the wall"))
        said += [
            f"Warning ({spec.label}, {n} pair(s); the figures of the first): {w}."
            for w, n in info["warnings"].items()
        ]
    if not rows and not stale:
        return None
    text = REPORT_TEXT
    said = [f"Warning ({r['run']}): {w}." for r, w in zip(rows, warned, strict=True) if w] + said
    if said:
        text += "\n\n" + "\n\n".join(said)
    if stale:
        text += "\n\n" + (
            f"Not shown: {', '.join(stale)} tracked fields other than this analysis's; run "
            "`rspiv ptv` again."
        )
    tables = [ReportTable("Wall shear from the tracks", rows)] if rows else []
    return ReportSection("Particle tracking at the wall", text=text, figures=figures,
                         tables=tables)  # fmt: skip
