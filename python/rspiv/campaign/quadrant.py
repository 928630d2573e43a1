"""A campaign's quadrant analysis and joint PDFs (``[statistics] quadrant``).

Quadrant analysis needs each vector's mean before any event can be classified, so it is a
second pass, over the fields the pair loop wrote (``[output] fields = true``, which the
configuration requires): at the end of a run (:func:`write_outputs`, also after ``rspiv merge``
or a Dask run, which share the output folder) every pair's field file of the run is read back
and added to a :class:`~rspiv.quadrant.QuadrantAccumulator` about the run's own statistics (the
mean and standard deviation of every vector over the same pairs, from its
:class:`~rspiv.stats.FieldAccumulator`). The sums are therefore exact, not about a pilot's
mean. The fields are stored as float32: the fluctuations carry its rounding (about 1e-7 of the
displacement).

Which vectors enter: those of the rows on the flow side whose statistics rest on at least
``[statistics] min_count`` valid samples (the profiles' rule), in every pair in which they are
valid (the statistics' rule). Units: the stresses in m^2/s^2 with a calibration and ``[flow]
dt``, else px^2 per pair^2; the signs are the flow's (u' downstream, v' away from the wall).

Output: ``quadrant_<run>.nc`` per row (``y`` from the wall, ``y_plus``): ``count``, ``uv``,
``stress``, ``fraction`` and ``time_fraction`` by ``quadrant`` (1-4) and ``hole`` (``[statistics]
quadrant_holes``), ``fraction_gaussian`` (H = 0: a jointly Gaussian (u', v') with the row's
correlation coefficient, for comparison), the joint PDF ``jpdf`` of ``(u'/u_rms, v'/v_rms)``,
``uv_se`` (the standard error of ``uv`` from 8 batches of contiguous pairs, which keeps the
correlation of neighbouring vectors and consecutive pairs inside a batch), ``uv_unresolved``
(``|uv|`` not beyond Student's 95 % factor times ``uv_se``, 2.36 with 8 batches: the shares
there divide noise by noise; left out of the figure) and the
``near_wall`` flag; a report section with the figure.

Said in one line (log, file attribute, report): a pair whose field file is missing (left out);
more than half of the rows off the wall and inside delta_99 unresolved (PIVlab's three
consecutive ``Karman`` pairs: every row, shares from -15 to 15); hole sizes a short campaign
cannot reach (over n samples ``|u'| / u_rms <= (n - 1) / sqrt(n)``, so ``|u'v'| / (u_rms
v_rms) <= (n - 1)^2 / n``: 1.33 for 3 pairs). A file whose grid or run is not the campaign's
stops the analysis of that run with one line naming it.
"""

from __future__ import annotations

import pathlib
import time
from typing import Any

import numpy as np

from rspiv.campaign.fields import each_field, finish_pass, pass_section
from rspiv.campaign.spec import RunSpec
from rspiv.errors import InvalidInputError
from rspiv.quadrant import QUADRANTS, QuadrantAccumulator, gaussian_quadrant

__all__ = [
    "accumulate",
    "quadrant_accumulator",
    "quadrant_dataset",
    "quadrant_profile",
    "report_section",
    "write_outputs",
]


def _t95(batches: np.ndarray) -> np.ndarray:
    """Student's two-sided 95 % factor for the mean of ``batches`` batch means (inf below 2)."""
    from scipy.stats import t  # deferred: scipy is heavy to import

    k = np.asarray(batches, np.float64)
    return np.where(k > 1, t.ppf(0.975, np.maximum(k - 1, 1)), np.inf)


def accumulate(
    acc: QuadrantAccumulator,
    paths: dict[int, pathlib.Path],
    run: str,
    workers: int | None = None,
    screen: Any = None,
) -> tuple[int, list[int]]:
    """Add the field files ``paths`` (pair id -> file) of ``run`` to ``acc`` in the pairs'
    order, in ``acc.batches`` contiguous batches; returns the number added and the pair ids
    whose file is missing.

    ``workers`` threads (default: the cores, at most 4) each add a contiguous run of the pairs
    to a part of their own, merged into ``acc`` at the end (numpy releases the GIL in the
    sums: 1.8x on 2 cores at 47 MP). ``screen``: the run's screen of the statistics
    (:func:`rspiv.campaign.fields.read_field`).
    """
    n = len(paths)

    def add(part: QuadrantAccumulator, i: int, pid: int, u, v, valid) -> None:
        part.add(u, v, valid, pair_id=pid, batch=i * acc.batches // n)

    parts, missing = each_field(
        paths, acc.shape, run, lambda w: acc if w == 0 else acc.empty_copy(), add, workers, screen
    )
    for other in parts[1:]:
        acc.merge(other)
    return acc.n_fields, missing


def quadrant_accumulator(acc: Any, an: Any, min_count: int, holes) -> QuadrantAccumulator:
    """An empty QuadrantAccumulator about the run's statistics ``acc`` (FieldAccumulator) and
    analysis ``an``: each vector's mean and standard deviation, the flow's signs, and the
    vectors that may enter (rows on the flow side, at least ``min_count`` valid samples: the
    profiles' rule; ``min_count`` below 2 counts as 2)."""
    p = an.profile
    usable = an.flow_vectors(acc, min_count)
    with np.errstate(invalid="ignore"):
        return QuadrantAccumulator(
            acc.mean_u,
            acc.mean_v,
            np.sqrt(acc.uu),
            np.sqrt(acc.vv),
            usable=usable,
            sign_x=float(p.get("sign_x", 1.0)),
            sign_y=float(p.get("sign_y", 1.0)),
            holes=holes,
        )


def quadrant_profile(
    q: QuadrantAccumulator, acc: Any, an: Any, min_count: int, window_height: float
) -> tuple[dict[str, Any], list[str]]:
    """The rows of ``q`` (:func:`quadrant_accumulator` of ``acc`` and ``an``, the fields
    added) on the flow side, nearest the wall first, in the run's units (module docstring's
    variables), and what must be said of them (rows whose ``<u'v'>`` is unresolved, holes the
    pairs cannot reach). ``window_height`` (px) sets the ``near_wall`` rows."""
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    usable = an.flow_vectors(acc, min_count)
    r = q.results()
    keep = np.flatnonzero((dist > 0) & (r["count"] > 0))
    keep = keep[np.argsort(dist[keep])]
    si = bool(p.get("si"))
    m = p["m_per_px"] if si else 1.0
    k2 = float(p.get("k", 1.0)) ** 2
    orient = float(p.get("sign_x", 1.0)) * float(p.get("sign_y", 1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(usable, acc.uv / np.sqrt(acc.uu * acc.vv), np.nan)[keep]
        finite = np.isfinite(rho)
        rho_row = np.where(finite, rho, 0.0).sum(1) / finite.sum(1) * orient  # the flow's signs
    gauss = np.full((keep.size, 4), np.nan)
    for i, rr in enumerate(rho_row):
        if np.isfinite(rr) and abs(rr) < 1:
            gauss[i] = gaussian_quadrant(rr, (0.0,))["fraction"][:, 0]
    prof: dict[str, Any] = {
        "y": dist[keep] * m,
        "dist_px": dist[keep],
        "rows": keep,
        "count": r["count"][keep],
        "uv": r["uv"][keep] * k2,
        "uv_se": r["uv_se"][keep] * k2,
        # <u'v'> not distinguished from 0 at 95 % (Student's t over the batch means): its
        # shares divide noise by noise
        "uv_unresolved": ~(np.abs(r["uv"][keep]) > _t95(r["uv_batches"][keep]) * r["uv_se"][keep]),
        "stress": np.moveaxis(r["stress"][..., keep], -1, 0) * k2,  # (y, quadrant, hole)
        "fraction": np.moveaxis(r["fraction"][..., keep], -1, 0),
        "time_fraction": np.moveaxis(r["time_fraction"][..., keep], -1, 0),
        "fraction_gaussian": gauss,
        "rho": rho_row,
        "jpdf": r["jpdf"][keep],
        "centres": r["centres"],
        "holes": r["holes"],
        "near_wall": dist[keep] < NEAR_WALL_HEIGHTS * window_height,
        "si": si,
        "pairs": int(q.n_fields),
    }
    res_bl = an.result
    if res_bl is not None and si:
        lv = res_bl.nu / res_bl.u_tau
        prof["y_plus"] = prof["y"] / lv
        prof["stress_plus"] = prof["stress"] / res_bl.u_tau**2
        prof["delta_99"] = float(res_bl.delta99)
    said = []
    # the rows a user reads: off the wall, and inside the layer when it is known
    inner = ~prof["near_wall"] & (prof["y"] <= prof.get("delta_99", np.inf))
    bad = int(np.count_nonzero(prof["uv_unresolved"] & inner))
    if bad > 0.5 * max(int(inner.sum()), 1):
        said.append(
            f"u'v' is not distinguished from zero (95 %) in {bad} of {int(inner.sum())} rows "
            "(uv_unresolved): their quadrant shares divide noise by noise"
        )
    # a vector's |u'| / u_rms is at most (n - 1) / sqrt(n) over n samples
    n_typ = int(np.median(acc.count[usable])) if usable.any() else 0
    reach = (n_typ - 1) ** 2 / max(n_typ, 1)
    if any(h > reach for h in q.holes):
        said.append(
            f"with {n_typ} pairs per vector |u'v'| / (u_rms v_rms) cannot exceed {reach:.2f}: "
            "the shares of larger holes are 0 by construction"
        )
    return prof, said


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The quadrant analysis of ``run`` (module docstring), written as ``OUT/quadrant_<run>.nc``
    (with ``[output] netcdf``); None when ``[statistics] quadrant`` is off."""
    st = camp.config.statistics
    if not st.quadrant:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    q = quadrant_accumulator(acc, an, st.min_count, st.quadrant_holes)
    writer = camp.field_writer()
    paths = {pid: writer.path(run.name, pid) for pid in acc.pair_ids}
    n, missing = accumulate(q, paths, run.name, screen=res.context.screens().get(run.name))
    if n == 0:
        raise InvalidInputError(
            f"none of the {len(paths)} pairs has a field file in {writer.path(run.name, 0).parent}"
        )
    prof, rows_said = quadrant_profile(q, acc, an, st.min_count, res.context.piv.final_window[1])
    prof["pairs"] = int(n)
    prof["missing"] = missing
    prof["seconds"] = time.perf_counter() - t0
    camp.say(f"{run.label}: quadrant analysis of {n} pairs' fields ({prof['seconds']:.1f} s)")
    said = []
    if missing:
        said.append(
            f"{len(missing)} of {len(paths)} pairs have no field file (first: pair "
            f"{missing[0]}): the quadrant analysis holds {n} pairs, about the means of all "
            f"{len(paths)}"
        )
    said += rows_said
    return finish_pass(camp, res, run, prof, said, "quadrant", "quadrant", quadrant_dataset)


def quadrant_dataset(prof: dict, run: RunSpec) -> Any:
    """The rows ``prof`` (:func:`quadrant_profile`) of ``run`` as a dataset
    (``quadrant_<run>.nc``: the module docstring's variables)."""
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    vel2 = "m2 s-2" if prof["si"] else "pix2"
    dims = ("y", "quadrant", "hole")
    ds = xr.Dataset(
        coords={
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "quadrant": ("quadrant", np.arange(1, 5), {"long_name": "; ".join(
                f"Q{i + 1} {name}" for i, name in enumerate(QUADRANTS))}),  # fmt: skip
            "hole": ("hole", prof["holes"], {"units": "1",
                     "long_name": "hole size H: |u'v'| >= H u_rms v_rms"}),  # fmt: skip
            "u_n": ("u_n", prof["centres"], {"units": "1", "long_name": "u' / u_rms"}),
            "v_n": ("v_n", prof["centres"], {"units": "1", "long_name": "v' / v_rms"}),
        }
    )
    ds["count"] = ("y", prof["count"], {"long_name": "samples (vectors x pairs) per row"})
    ds["uv"] = ("y", prof["uv"], {"units": vel2, "long_name": "<u'v'> of the row's samples"})
    ds["stress"] = (dims, prof["stress"], {"units": vel2,
                                           "long_name": "<u'v'> of the events in Q outside H"})
    ds["fraction"] = (dims, prof["fraction"], {"units": "1", "long_name": "stress / uv"})
    ds["time_fraction"] = (dims, prof["time_fraction"],
                           {"units": "1", "long_name": "share of samples in Q outside H"})
    ds["fraction_gaussian"] = (("y", "quadrant"), prof["fraction_gaussian"], {
        "units": "1", "long_name": "fraction at H = 0 of a jointly Gaussian (u', v') with rho"})
    ds["rho"] = ("y", prof["rho"], {"units": "1", "long_name": "mean of uv / (u_rms v_rms)"})
    ds["uv_se"] = ("y", prof["uv_se"], {"units": vel2,
                   "long_name": "standard error of uv (batch means of contiguous pairs)"})
    ds["uv_unresolved"] = ("y", prof["uv_unresolved"],
                           {"long_name": "uv not distinguished from 0 at 95 %"})
    ds["jpdf"] = (("y", "v_n", "u_n"), prof["jpdf"].astype(np.float32),
                  {"units": "1", "long_name": "joint PDF of (u'/u_rms, v'/v_rms)"})
    ds["near_wall"] = ("y", prof["near_wall"], {"long_name": "row shaped by the wall"})
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        ds["stress_plus"] = (dims, prof["stress_plus"], {"units": "1",
                             "long_name": "stress / u_tau^2"})  # fmt: skip
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "description": "rspiv quadrant analysis (rspiv.quadrant): u' downstream, v' away "
            "from the wall, each vector's fluctuation about its own mean",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's quadrant analysis, or None."""
    main = res.context.runs[0]
    prof = res.quadrant.get(main.name)
    if prof is None or "y_plus" not in prof:
        return None
    text = (
        f"Quadrant analysis of u'v' over {prof['pairs']} pairs (each vector's fluctuation about "
        "its own mean; u' downstream, v' away from the wall): Q2 ejections and Q4 sweeps carry "
        "the stress, Q1 and Q3 subtract from it. Thin lines: a jointly Gaussian (u', v') with "
        "the row's correlation coefficient. The measurement noise moves events across the "
        "quadrants' edges, pulling the fractions at small hole sizes towards that Gaussian's. "
        "Rows within 2.5 window heights of the wall are left out (near_wall)."
    )
    return pass_section(
        camp, prof, "Quadrant analysis", text, "rspiv.plots.quadrant:plot_quadrant", "quadrant",
        f"{main.label}: quadrant analysis and joint PDFs",
    )
