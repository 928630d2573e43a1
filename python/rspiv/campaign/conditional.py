"""A campaign's conditional averages about ejections and sweeps (``[statistics] conditional``).

Like the quadrant analysis, a second pass over the fields the pair loop wrote (``[output]
fields = true``, which the configuration requires), at the end of a run, about the run's own
statistics: every pair's field file is read back and added to a
:class:`~rspiv.conditional.ConditionalAccumulator` (the definition, the frame and the standard
errors are there).

Where: the reference rows are the rows nearest to ``conditional_heights`` from the run's wall
(in the run's own delta_99 with ``conditional_height_units = "delta"``, which needs its
boundary-layer fit: a calibration and ``[flow] dt``; or px), each at least 2.5 final window
heights off the wall (:func:`rspiv.campaign.two_point.map_rows`, the two-point maps' rule,
refuses a height there or beyond the field). The map covers the rows from 2.5 window heights off
the wall to twice the highest reference, and streamwise offsets as far either way (at most the
field's width); the events are those with ``|u'v'| >= conditional_hole u_rms v_rms`` (1.0) of
vectors whose statistics rest on ``[statistics] min_count`` samples or more.

About vortex cores: with ``[statistics] vortices`` on as well, the averages are also taken about
the vortex pass's cores (:mod:`rspiv.campaign.vortices`, which runs first) whose centroid lies
nearest a reference row, each at the vector nearest its centroid: ``kind`` ``prograde`` (turning
with the mean shear) and ``retrograde`` beside Q2 and Q4 (two cores on one vector are one
event). Around a prograde core of the outer layer an inclined shear layer with an ejection below
and behind it and a sweep above and ahead is the hairpin-head signature (Christensen & Adrian
2001, J. Fluid Mech. 431).

Output ``conditional_<run>.nc``: ``u``, ``v`` (``ref``, ``kind`` = Q2, Q4, ``y``, ``dx``) in
m/s with a calibration and ``[flow] dt`` (px per pair without), ``u_plus``, ``v_plus`` in wall
units, their standard errors ``u_se``, ``v_se`` (8 batch means of contiguous pairs),
``resolved`` (both ``|u|`` and ``|v|`` or either beyond Student's 95 % factor times its error),
``count`` (terms per point), ``events`` and the events' own mean ``event_u``, ``event_v`` per
reference and kind; ``y`` the distance from the wall and ``dx`` the streamwise offset
(downstream positive), ``y_ref`` the reference heights. A report figure.

Said in one line (log, file attribute, report): a pair whose field file is missing (left out); a
reference height and kind without events (none outside the hole) or with fewer than
:data:`MIN_EVENTS` (their noise), a hole a short campaign cannot reach (the quadrant analysis's
bound), and averages that do not decay away from their events: where the mean ``u'`` at
:data:`FAR` of the map's half width or farther exceeds :data:`FAR_SHARE` of the events' own
(``far_ratio``), the fluctuations are of the whole field (OpenPIV's ``test14``, whose speed
drifts by 35 % over its 33 pairs: 1.00-1.01), not local structures (the demo's layer: -0.04 to
-0.01).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from rspiv.campaign.fields import each_field, finish_pass, pass_section, run_field_files
from rspiv.campaign.quadrant import _t95
from rspiv.campaign.spec import RunSpec
from rspiv.campaign.two_point import reference_rows
from rspiv.conditional import KINDS, VORTEX_KINDS, ConditionalAccumulator
from rspiv.errors import InvalidInputError

__all__ = [
    "FAR",
    "FAR_SHARE",
    "MIN_EVENTS",
    "conditional_accumulator",
    "conditional_dataset",
    "conditional_profile",
    "core_events",
    "report_section",
    "write_outputs",
]

#: The map's far part: offsets at this share of its half width or more.
FAR = 0.75
#: Said when the far part's mean u' exceeds this share of the events' own (no decay).
FAR_SHARE = 0.5
#: Said when a reference height and kind has fewer events (but some): where the structure has
#: decayed an average of n events keeps about ``u_rms / sqrt(n)`` of noise (more where events
#: share a field), a tenth of u_rms or more below 100 events: field-sized patches in the map.
MIN_EVENTS = 100


def conditional_accumulator(
    acc: Any,
    an: Any,
    band: tuple[int, int],
    refs: Any,
    heights_px: Any,
    dx_px: float,
    min_count: int,
    hole: float,
    kinds=KINDS,
) -> ConditionalAccumulator:
    """An empty ConditionalAccumulator about the run's statistics ``acc`` and analysis ``an``:
    the map's rows ``band`` about the reference rows ``refs`` (at ``heights_px`` from the
    wall, :func:`rspiv.campaign.two_point.map_rows`), offsets up to twice the highest height
    either way (at most the field's width; ``dx_px`` the grid's step), the vectors with
    ``min_count`` samples or more on the flow side, events outside ``hole``."""
    p = an.profile
    half_width = min(int(np.ceil(2.0 * max(heights_px) / dx_px)), acc.shape[1] - 1)
    usable = an.flow_vectors(acc, min_count)
    with np.errstate(invalid="ignore"):
        return ConditionalAccumulator(
            acc.mean_u,
            acc.mean_v,
            np.sqrt(acc.uu),
            np.sqrt(acc.vv),
            refs,
            rows=band,
            half_width=half_width,
            usable=usable,
            sign_x=float(p.get("sign_x", 1.0)),
            sign_y=float(p.get("sign_y", 1.0)),
            hole=hole,
            kinds=kinds,
        )


def core_events(found: tuple | None, refs: Any, nx: int) -> dict[str, np.ndarray]:
    """A field's vortex cores as :class:`~rspiv.conditional.ConditionalAccumulator` events:
    ``found`` its cores' ``(rows, columns, prograde)`` (a vortex search's ``core_events``;
    None: no core), for each of :data:`~rspiv.conditional.VORTEX_KINDS` a boolean array
    ``(len(refs), nx)`` True at the columns of the cores centred on each reference row."""
    events = {k: np.zeros((len(refs), nx), bool) for k in VORTEX_KINDS}
    if found is None:
        return events
    rows, cols, pro = found
    for j, ref in enumerate(refs):
        at = rows == ref
        events["prograde"][j, cols[at & pro]] = True
        events["retrograde"][j, cols[at & ~pro]] = True
    return events


def conditional_profile(
    q: ConditionalAccumulator, acc: Any, an: Any, dx_px: float, window_height: float,
    min_count: int,
) -> tuple[dict[str, Any], list[str]]:  # fmt: skip
    """The filled accumulator ``q`` (:func:`conditional_accumulator`) in the run's units
    (module docstring's variables: rows by distance from the wall, offsets downstream) and
    what must be said of it (kinds without events, averages that do not decay, a hole the
    pairs cannot reach). ``window_height`` (px) sets the ``near_wall`` rows."""
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    kinds = list(q.kinds)
    sign_x = float(p.get("sign_x", 1.0))
    r = q.results()
    si = bool(p.get("si"))
    m = p["m_per_px"] if si else 1.0
    k = float(p.get("k", 1.0))
    # rows by distance from the wall, offsets downstream
    ry = np.argsort(dist[r["rows"]])
    dxs = sign_x * r["offsets"] * dx_px
    rx = np.argsort(dxs)

    def grid(a: np.ndarray) -> np.ndarray:
        return a[:, :, ry][:, :, :, rx]

    with np.errstate(invalid="ignore"):
        u, v = grid(r["u"]) * k, grid(r["v"]) * k
        u_se, v_se = grid(r["u_se"]) * k, grid(r["v_se"]) * k
        t = _t95(grid(r["batches_used"]))
        resolved = (np.abs(u) > t * u_se) | (np.abs(v) > t * v_se)
    prof: dict[str, Any] = {
        "y": dist[r["rows"]][ry] * m,
        "dist_px": dist[r["rows"]][ry],
        "dx": dxs[rx] * m,
        "dx_px": dxs[rx],
        "k": k,  # the velocity unit's factor from px per pair (1 without SI units)
        "y_ref": dist[r["ref_rows"]] * m,
        "ref_rows": r["ref_rows"],
        "kinds": kinds,
        "u": u,
        "v": v,
        "u_se": u_se,
        "v_se": v_se,
        "resolved": resolved,
        "count": grid(r["count"]),
        "events": r["events"],
        "event_u": r["event_u"] * k,
        "event_v": r["event_v"] * k,
        "hole": float(q.hole),
        "near_wall": dist[r["rows"]][ry] < NEAR_WALL_HEIGHTS * window_height,
        "si": si,
        "per_s": si,
        "pairs": int(q.n_fields),
    }
    bl = an.result
    if bl is not None and si:
        lv = bl.nu / bl.u_tau
        prof["y_plus"] = prof["y"] / lv
        prof["dx_plus"] = prof["dx"] / lv
        prof["y_ref_plus"] = prof["y_ref"] / lv
        for key in ("u", "v", "u_se", "v_se"):
            prof[f"{key}_plus"] = prof[key] / bl.u_tau
        prof["delta_99"] = float(bl.delta99)
    ev = r["events"]
    said = []
    empty = [
        f"{kinds[j]} at {prof['y_ref'][i]:.4g} {'m' if si else 'px'}"
        for i in range(ev.shape[0])
        for j in range(ev.shape[1])
        if ev[i, j] == 0
    ]
    if empty:
        said.append(
            f"no events (outside the hole H = {q.hole:g}, or vortex cores centred "
            f"there): {', '.join(empty)}"
        )
    few = [
        f"{kinds[j]} at {prof['y_ref'][i]:.4g} {'m' if si else 'px'} {ev[i, j]}"
        for i in range(ev.shape[0])
        for j in range(ev.shape[1])
        if 0 < ev[i, j] < MIN_EVENTS
    ]
    if few:
        said.append(
            f"few events to average ({', '.join(few)}; fewer than {MIN_EVENTS}): away from "
            "the events their noise, about u_rms / sqrt(events), shows as patches; the "
            "resolved flags say where the averages stand out of it"
        )
    # a local structure decays away from its event; fluctuations of the whole field do not
    far = np.abs(prof["dx_px"]) >= FAR * np.abs(prof["dx_px"]).max()
    far_u = u[:, :, ~prof["near_wall"]][..., far]
    fin = np.isfinite(far_u)
    with np.errstate(invalid="ignore", divide="ignore"):
        far_mean = np.where(fin, far_u, 0.0).sum(axis=(2, 3)) / fin.sum(axis=(2, 3))
        # over the events' own u' (quadrant kinds), or the map's largest |u'| (about a
        # vortex core the event's own u' is about zero)
        peak = np.nanmax(np.abs(np.where(np.isfinite(u), u, 0.0)[:, :, ~prof["near_wall"]]),
                         axis=(2, 3))  # fmt: skip
        own = np.where([kd in KINDS for kd in kinds], prof["event_u"], peak)
        ratio = np.where(ev > 0, far_mean / own, np.nan)  # NaN for a kind without events
    prof["far_ratio"] = ratio
    coherent = [
        f"{kinds[j]} at {prof['y_ref'][i]:.4g} {'m' if si else 'px'} {ratio[i, j]:.2f}"
        for i in range(ratio.shape[0])
        for j in range(ratio.shape[1])
        if ratio[i, j] > FAR_SHARE
    ]
    if coherent:
        said.append(
            f"they do not decay away from their events (u' at {FAR:g} of "
            f"the map's half width or farther, over the event's own: {', '.join(coherent)}): "
            "the fluctuations are of the whole field (a speed drifting over the run, pairs of "
            "another pulse separation), not local structures"
        )
    usable = an.flow_vectors(acc, min_count)
    n_typ = int(np.median(acc.count[usable])) if usable.any() else 0
    reach = (n_typ - 1) ** 2 / max(n_typ, 1)
    if q.hole > reach:
        said.append(
            f"with {n_typ} pairs per vector |u'v'| / (u_rms v_rms) cannot exceed {reach:.2f}, "
            f"below the hole {q.hole:g}"
        )
    return prof, said


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The conditional averages of ``run`` (module docstring), written as
    ``OUT/conditional_<run>.nc`` (with ``[output] netcdf``); None when ``[statistics]
    conditional`` is off."""
    st = camp.config.statistics
    if not st.conditional:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    window_h = res.context.piv.final_window[1]
    band, refs, heights = reference_rows(
        an, st.conditional_heights, st.conditional_height_units, "conditional_heights", window_h
    )
    ids, paths, x = run_field_files(camp, run.name, acc.pair_ids)
    dx_px = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    vort = res.vortices.get(run.name) if st.vortices else None
    kinds = KINDS + VORTEX_KINDS if vort is not None else KINDS
    q = conditional_accumulator(
        acc, an, band, refs, heights, dx_px, st.min_count, st.conditional_hole, kinds
    )
    n_pairs = len(ids)

    def add(part: ConditionalAccumulator, i: int, pid: int, u, v, valid) -> None:
        events = None
        if vort is not None:  # the pair's cores centred on a reference row
            events = core_events(vort["core_events"].get(pid), refs, acc.shape[1])
        part.add(u, v, valid, pair_id=pid, batch=i * q.batches // n_pairs, events=events)

    parts, missing = each_field(
        paths, acc.shape, run.name, lambda w: q if w == 0 else q.empty_copy(), add,
        screen=res.context.screens().get(run.name),
    )  # fmt: skip
    for other in parts[1:]:
        q.merge(other)
    prof, profile_said = conditional_profile(q, acc, an, dx_px, window_h, st.min_count)
    prof["missing"] = missing
    prof["seconds"] = time.perf_counter() - t0
    ev = prof["events"]
    cores = (
        f", {int(ev[:, 2].sum())} prograde and {int(ev[:, 3].sum())} retrograde vortex cores"
        if vort is not None
        else ""
    )
    camp.say(
        f"{run.label}: conditional averages about {int(ev[:, 0].sum())} ejections and "
        f"{int(ev[:, 1].sum())} sweeps{cores} at {len(refs)} heights in {q.n_fields} pairs' "
        f"fields ({prof['seconds']:.1f} s)"
    )
    said = []
    if missing:
        said.append(
            f"{len(missing)} of {len(paths)} pairs have no field file (first: pair "
            f"{missing[0]}): the conditional averages hold {q.n_fields} pairs"
        )
    if st.vortices and vort is None:
        said.append(
            "no averages about vortex cores: the run's vortex pass did not run to its end "
            "(its error is in summary.json)"
        )
    said += profile_said
    return finish_pass(
        camp, res, run, prof, said, "conditional", "conditional averages", conditional_dataset
    )


def conditional_dataset(prof: dict, run: RunSpec) -> Any:
    """The averages ``prof`` (:func:`conditional_profile`) of ``run`` as a dataset
    (``conditional_<run>.nc``: the module docstring's variables)."""
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    vel = "m s-1" if prof["per_s"] else "pix"
    dims = ("ref", "kind", "y", "dx")
    ds = xr.Dataset(
        coords={
            "ref": ("ref", np.arange(len(prof["y_ref"]))),
            "kind": ("kind", prof["kinds"], {"long_name": "Q2 ejection (u' < 0, v' > 0); "
                     "Q4 sweep (u' > 0, v' < 0); prograde, retrograde: a vortex core centred "
                     "there (rotating with the mean shear, against it)"}),  # fmt: skip
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "dx": ("dx", prof["dx"], {"units": length, "long_name": "streamwise offset from "
                   "the event, downstream positive"}),  # fmt: skip
        }
    )
    ds["y_ref"] = ("ref", prof["y_ref"], {"units": length, "long_name": "the events' height"})
    for q in ("u", "v"):
        ds[q] = (dims, prof[q].astype(np.float32), {"units": vel, "long_name": f"<{q}' | "
                 "event>, each vector's fluctuation about its mean"})  # fmt: skip
        ds[f"{q}_se"] = (dims, prof[f"{q}_se"].astype(np.float32), {"units": vel, "long_name":
                         "standard error (8 batch means of contiguous pairs)"})  # fmt: skip
        ds[f"event_{q}"] = (("ref", "kind"), prof[f"event_{q}"],
                            {"units": vel, "long_name": f"the events' own mean {q}'"})
    ds["resolved"] = (dims, prof["resolved"], {"long_name": "u or v beyond 95 % of its error"})
    ds["count"] = (dims, prof["count"], {"long_name": "terms (event x valid vector) per point"})
    ds["events"] = (("ref", "kind"), prof["events"], {"long_name": "events over all pairs"})
    ds["far_ratio"] = (("ref", "kind"), prof["far_ratio"], {"long_name": "mean u' at 0.75 of "
                       "the half width or farther over the events' own"})  # fmt: skip
    ds["near_wall"] = ("y", prof["near_wall"], {"long_name": "row shaped by the wall"})
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        ds["dx_plus"] = ("dx", prof["dx_plus"], {"units": "1"})
        ds["y_ref_plus"] = ("ref", prof["y_ref_plus"], {"units": "1"})
        for q in ("u", "v"):
            ds[f"{q}_plus"] = (dims, prof[f"{q}_plus"].astype(np.float32), {"units": "1"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "hole": prof["hole"],
            "description": "rspiv conditional averages (rspiv.conditional): u' downstream, v' "
            "away from the wall, about every vector of the reference row in Q2 or Q4 with "
            "|u'v'| >= hole u_rms v_rms",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's conditional averages, or None."""
    main = res.context.runs[0]
    prof = res.conditional.get(main.name)
    if prof is None:
        return None
    ev = prof["events"]
    text = (
        f"Conditional averages of u' and v' about ejections (Q2) and sweeps (Q4) at "
        f"{len(prof['y_ref'])} heights over {prof['pairs']} pairs ({int(ev[:, 0].sum())} and "
        f"{int(ev[:, 1].sum())} events with |u'v'| at least {prof['hole']:g} u_rms v_rms): "
        "the region each event sits in, its streamwise extent and inclination. Each vector's "
        "fluctuation about its own mean; colour u', arrows (u', v') where resolved at 95 %."
    )
    if ev.shape[1] > 2:
        text += (
            f" Also about {int(ev[:, 2].sum())} prograde and {int(ev[:, 3].sum())} retrograde "
            "vortex cores centred at those heights (the vortex pass's cores, each at the vector "
            "nearest its centroid)."
        )
    return pass_section(
        camp, prof, "Conditional averages", text,
        "rspiv.plots.conditional:plot_conditional", "conditional",
        f"{main.label}: conditional averages about ejections and sweeps",
    )
