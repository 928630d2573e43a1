"""A campaign's proper orthogonal decomposition (``[statistics] pod``).

Like the quadrant analysis, the POD needs each vector's mean before the first snapshot, so it is
a second pass over the fields the pair loop wrote (``[output] fields = true``, which the
configuration requires), at the end of a run (also after ``rspiv merge`` or a Dask run, which
share the output folder). It decomposes the fluctuations about the run's own statistics (each
vector's mean over every pair) with :class:`rspiv.pod.PodBuilder`:

Snapshots
    At most ``[statistics] pod_snapshots`` pairs, spread evenly over the run's pairs (all of
    them when fewer). A pair whose field file is missing is left out, and said.
Domain
    The vectors of the rows on the flow side whose statistics rest on at least ``[statistics]
    min_count`` valid samples (the profiles' rule), less the rows the wall shapes (within 2.5
    final window heights, ``near_wall`` in the other outputs: their fluctuations are mostly the
    wall's bias and noise), up to ``pod_height`` delta_99 from the wall when it is set (0: the
    whole flow side). A vector rejected in a snapshot is filled with its mean (``gaps``).
Streaming
    The inner products are summed over blocks of rows (every snapshot's rows of a block read
    from its file, at most about 256 MB per block), then every file is read once more for the
    modes; a grid whose domain fits one block is read once. The work is ``n^2 D`` (a 47 MP grid
    of 730,000 vectors and 1000 snapshots: about 1.5e12 multiply-adds).
Sampling error
    North's rule with ``n_eff`` the fewer of the snapshots and the statistics' effective count
    (the median over the domain of :meth:`~rspiv.stats.FieldAccumulator.n_eff` of ``uu``): a
    time-resolved recording's consecutive pairs are not independent.

Output: ``pod_<run>.nc``: ``energy`` (lambda_k, m^2/s^2 summed over the domain's vectors with a
calibration and ``[flow] dt``, else px^2 per pair^2), ``fraction``, ``cumulative``, ``north``,
``separated``; the modes ``phi_u``, ``phi_v`` (dims ``mode, y, x``; unit norm over the domain, NaN
outside; the flow's frame: u downstream, v away from the wall, rows by distance from the wall);
``coefficient`` (dims ``pair, mode``, velocity units), attributes ``total_energy``, ``gaps``,
``n_eff``; and a report section with the energy spectrum and the leading modes.

Said in one line (log, file, report): missing field files; more than 5 % of the domain's samples
filled; no mode kept separated from its neighbours (the spectrum flat within its sampling error:
no shape is determined). A pair of modes not separated from each other is common and not said
(a convected structure appears as a sine and cosine pair of equal energy): ``separated`` flags
it, the figure draws it open.
A file whose grid or run is not the campaign's stops the analysis of that run, naming it.
"""

from __future__ import annotations

import pathlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rspiv.campaign.fields import finish_pass, grid_x, pass_section, read_field
from rspiv.campaign.spec import RunSpec
from rspiv.errors import InvalidInputError
from rspiv.pod import PodBuilder

__all__ = [
    "BLOCK_BYTES",
    "decompose",
    "decompose_with",
    "domain_of",
    "flow_domain",
    "pod_dataset",
    "pod_profile",
    "report_section",
    "select_snapshots",
    "write_outputs",
]

#: Memory of one block of rows while the inner products are summed (float64 u and v).
BLOCK_BYTES = 256 << 20


def select_snapshots(ids, limit: int) -> list:
    """At most ``limit`` of ``ids`` (sorted), spread evenly from the first to the last."""
    ids = sorted(ids)
    if len(ids) <= limit:
        return ids
    take = np.unique(np.round(np.linspace(0, len(ids) - 1, limit)).astype(int))
    return [ids[i] for i in take]


def decompose(
    builder: PodBuilder,
    paths: list[pathlib.Path],
    run: str,
    n_modes: int,
    n_eff: float | None = None,
    block_bytes: int = BLOCK_BYTES,
    screen: Any = None,
) -> None:
    """Stream the field files ``paths`` (the builder's snapshots, in order) through
    ``builder``: the inner products by blocks of rows, :meth:`~rspiv.pod.PodBuilder.solve`,
    then the modes (module docstring)."""
    shape = builder.shape

    def read(i: int, rows: slice | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return read_field(paths[i], shape, run, rows, screen=screen)

    decompose_with(builder, read, n_modes, n_eff, block_bytes)


def decompose_with(
    builder: PodBuilder,
    read: Callable[[int, slice | None], tuple[np.ndarray, np.ndarray, np.ndarray]],
    n_modes: int,
    n_eff: float | None = None,
    block_bytes: int = BLOCK_BYTES,
    progress: Callable[[int, int], None] | None = None,
) -> None:
    """:func:`decompose` of the builder's ``n`` snapshots read by ``read(i, rows)``: snapshot
    ``i``'s ``(u, v, valid)`` over the rows ``rows`` (a slice; None: every row), in the
    accumulator's units and axes. Each snapshot is read once per block of rows and once more
    for the modes, once in all when the domain fits one block. ``progress(done, total)``
    after each read of the rows (the total known once the blocks are)."""
    shape = builder.shape
    rows = np.flatnonzero(builder.domain.any(axis=1))
    r_lo, r_hi = int(rows[0]), int(rows[-1]) + 1
    n = builder.n
    per = max(1, int(block_bytes // max(n * shape[1] * 16, 1)))
    blocks = [slice(r, min(r + per, r_hi)) for r in range(r_lo, r_hi, per)]
    reads = n * len(blocks) + (n if len(blocks) > 1 else 0)
    done = 0

    def count() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, reads)

    held = None
    for blk in blocks:
        m = blk.stop - blk.start
        u = np.empty((n, m, shape[1]), np.float32)
        v = np.empty_like(u)
        ok = np.empty(u.shape, np.uint8)
        for i in range(n):
            u[i], v[i], ok[i] = read(i, blk)
            count()
        builder.add_rows(blk, u, v, ok)
        if len(blocks) == 1:
            held = (u, v, ok)
    builder.solve(n_modes, n_eff)
    if held is not None:  # the whole domain was one block: no second read
        u, v, ok = held
        full = np.full(shape, np.nan, np.float32)
        for i in range(n):
            fu, fv = full.copy(), full.copy()
            fok = np.zeros(shape, np.uint8)
            fu[r_lo:r_hi], fv[r_lo:r_hi], fok[r_lo:r_hi] = u[i], v[i], ok[i]
            builder.add_snapshot(i, fu, fv, fok)
        return
    for i in range(n):
        u, v, ok = read(i, None)
        count()
        builder.add_snapshot(i, u, v, ok)


def flow_domain(camp: Any, res: Any, an: Any, acc: Any, height: float, key: str) -> np.ndarray:
    """The vectors a decomposition of the run's fields takes (:func:`domain_of` with the run's
    final window and ``[statistics] min_count``)."""
    st = camp.config.statistics
    return domain_of(an, acc, res.context.piv.final_window[1], st.min_count, height, key)


def domain_of(
    an: Any, acc: Any, window_height: float, min_count: int, height: float, key: str
) -> np.ndarray:
    """The vectors a decomposition of a run's (or a series') fields takes (module docstring,
    Domain): on the flow side, outside the rows the wall shapes (``NEAR_WALL_HEIGHTS`` times
    ``window_height`` px), with at least ``min_count`` (and 2) valid samples, up to ``height``
    delta_99 from the wall when it is positive (``key`` names the setting in the refusal).

    Raises
    ------
    InvalidInputError
        ``height`` set without the boundary-layer fit; no vector left.
    """
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    near = dist < NEAR_WALL_HEIGHTS * window_height
    rows_in = (dist > 0) & ~near
    res_bl = an.result
    if height > 0:
        if res_bl is None or not p.get("si") or not np.isfinite(res_bl.delta99):
            raise InvalidInputError(
                f"{key} = {height:g} delta_99 needs the boundary-layer fit (a scale and a "
                "pulse separation: a campaign's calibration and [flow] dt), which it has not"
            )
        rows_in &= dist * p["m_per_px"] <= height * res_bl.delta99
    domain = (acc.count >= max(min_count, 2)) & rows_in[:, None]
    if not domain.any():
        raise InvalidInputError(f"no vector off the wall has enough valid samples ({key})")
    return domain


def pod_profile(
    r: Any, an: Any, domain: np.ndarray, x_px: np.ndarray, ids: list, seconds: float
) -> tuple[dict[str, Any], list[str]]:
    """The POD result ``r`` (:meth:`rspiv.pod.PodBuilder.result`) of the snapshots ``ids`` over
    ``domain`` in the analysis' units (module docstring's variables; rows by distance from the
    wall), and what must be said of it (samples filled, no mode separated)."""
    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    si = bool(p.get("si"))
    m = p["m_per_px"] if si else 1.0
    keep = np.flatnonzero(domain.any(axis=1))
    keep = keep[np.argsort(dist[keep])]
    k = float(p.get("k", 1.0))
    prof: dict[str, Any] = {
        "y": dist[keep] * m,
        "dist_px": dist[keep],
        "rows": keep,
        "x": np.asarray(x_px, np.float64) * m,
        "energy": r.energy * k * k,
        "total": r.total * k * k,
        "fraction": r.fraction,
        "cumulative": r.cumulative,
        "north": r.north * k * k,
        "separated": r.separated,
        "phi_u": r.modes_u[:, keep],
        "phi_v": r.modes_v[:, keep],
        "coefficient": r.coefficients * k,
        "pair_ids": np.asarray(ids),
        "gaps": r.gaps,
        "n_eff": r.n_eff,
        "vectors": int(domain.sum()),
        "k": k,  # the velocity unit's factor from px per pair (1 without SI units)
        "si": si,
        "pairs": len(ids),
        "seconds": seconds,
    }
    res_bl = an.result
    if res_bl is not None and si:
        prof["y_plus"] = prof["y"] / (res_bl.nu / res_bl.u_tau)
        prof["delta_99"] = float(res_bl.delta99)
    said = []
    if r.gaps > 0.05:
        said.append(
            f"{100 * r.gaps:.1f} % of the domain's samples were rejected vectors filled with "
            "their mean: the energies read low by about as much"
        )
    if not r.separated.any():
        said.append(
            f"no mode kept is separated from its neighbours (North's rule with {r.n_eff:.0f} "
            "independent snapshots): the spectrum is flat within its sampling error and no "
            "mode's shape is determined by these snapshots"
        )
    return prof, said


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The POD of ``run`` (module docstring), written as ``OUT/pod_<run>.nc`` (with ``[output]
    netcdf``); None when ``[statistics] pod`` is off."""
    st = camp.config.statistics
    if not st.pod:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    p = an.profile
    domain = flow_domain(camp, res, an, acc, st.pod_height, "pod_height")
    writer = camp.field_writer()
    chosen = select_snapshots(acc.pair_ids, st.pod_snapshots)
    paths = {pid: writer.path(run.name, pid) for pid in chosen}
    missing = [pid for pid in chosen if not paths[pid].exists()]
    ids = [pid for pid in chosen if paths[pid].exists()]
    if len(ids) < 2:
        raise InvalidInputError(
            f"{len(ids)} of the {len(chosen)} pairs chosen for the POD have a field file in "
            f"{writer.path(run.name, 0).parent}: at least 2 are needed"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        n_eff_all = float(np.median(acc.n_eff("uu")[domain]))
    n_eff = min(len(ids), n_eff_all)
    sign_x, sign_y = float(p.get("sign_x", 1.0)), float(p.get("sign_y", 1.0))
    builder = PodBuilder(acc.mean_u, acc.mean_v, domain, len(ids), sign_x, sign_y)
    screen = res.context.screens().get(run.name)
    decompose(builder, [paths[i] for i in ids], run.name, st.pod_modes, n_eff, screen=screen)
    r = builder.result(ids)
    prof, found = pod_profile(r, an, domain, grid_x(paths[ids[0]]), ids, 0.0)
    prof["missing"] = missing
    prof["seconds"] = time.perf_counter() - t0
    camp.say(
        f"{run.label}: POD of {len(ids)} pairs' fields over {prof['vectors']} vectors: the first "
        f"mode holds {100 * r.fraction[0]:.1f} %, the first {r.n_modes} "
        f"{100 * r.cumulative[-1]:.1f} % ({prof['seconds']:.1f} s)"
    )
    said = []
    if missing:
        said.append(
            f"{len(missing)} of {len(chosen)} pairs chosen have no field file (first: pair "
            f"{missing[0]}): the POD holds {len(ids)} snapshots"
        )
    said += found
    return finish_pass(camp, res, run, prof, said, "pod", "POD", pod_dataset)


def pod_dataset(prof: dict, run: RunSpec) -> Any:
    """``pod_<run>.nc`` of ``prof`` (:func:`pod_profile`; module docstring's variables)."""
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    vel = "m s-1" if prof["si"] else "pix"
    vel2 = "m2 s-2" if prof["si"] else "pix2"
    modes = np.arange(1, prof["energy"].size + 1)
    dims = ("mode", "y", "x")
    ds = xr.Dataset(
        coords={
            "mode": ("mode", modes),
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "x": ("x", prof["x"], {"units": length, "long_name": "x of the measured frame"}),
            "pair": ("pair", prof["pair_ids"], {"long_name": "the snapshots' pair ids"}),
        }
    )
    ds["energy"] = ("mode", prof["energy"], {
        "units": vel2, "long_name": "eigenvalue: mean square coefficient, summed over the domain"})
    ds["fraction"] = ("mode", prof["fraction"], {"units": "1", "long_name": "energy / total"})
    ds["cumulative"] = ("mode", prof["cumulative"], {"units": "1"})
    ds["north"] = ("mode", prof["north"], {"units": vel2,
                   "long_name": "standard error of energy, North et al. 1982"})  # fmt: skip
    ds["separated"] = ("mode", prof["separated"],
                       {"long_name": "eigenvalue beyond its standard error from its neighbours'"})
    for c, along in (("u", "u downstream"), ("v", "v away from the wall")):
        ds[f"phi_{c}"] = (dims, prof[f"phi_{c}"].astype(np.float32), {
            "units": "1", "long_name": f"mode, {along} (unit norm over the domain)"})
    ds["coefficient"] = (("pair", "mode"), prof["coefficient"], {"units": vel})
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "vectors": prof["vectors"],
            "total_energy": prof["total"],
            "gaps": prof["gaps"],
            "n_eff": prof["n_eff"],
            "description": "rspiv snapshot POD (rspiv.pod) of the fluctuations about each "
            "vector's mean; rejected vectors filled with the mean",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's POD, or None."""
    main = res.context.runs[0]
    prof = res.pod.get(main.name)
    if prof is None:
        return None
    n = prof["energy"].size
    text = (
        f"Snapshot POD of {prof['pairs']} pairs over {prof['vectors']} vectors (the fluctuations "
        "about each vector's mean; rows within 2.5 window heights of the wall left out): the "
        f"first mode holds {100 * prof['fraction'][0]:.1f} % of the fluctuation energy, the "
        f"first {n} together {100 * prof['cumulative'][-1]:.1f} %. Error bars: North's rule "
        f"with {prof['n_eff']:.0f} independent snapshots; modes not separated from a "
        "neighbour (open symbols) mix with it and are read together. The measurement noise "
        "adds to every eigenvalue."
    )
    return pass_section(
        camp, prof, "Proper orthogonal decomposition", text, "rspiv.plots.pod:plot_pod", "pod",
        f"{main.label}: POD energy spectrum and leading modes",
    )
