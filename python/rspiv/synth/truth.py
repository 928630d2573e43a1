"""A processed synthetic campaign against its exact answers (the files
:func:`rspiv.demo.synth_campaign` writes beside the frames): the helpers of
:func:`rspiv.demo.verdicts`, one per statistic, each giving the largest deviation over the rows
or heights its claim names.
"""

from __future__ import annotations

import json
import pathlib
from typing import Any

import numpy as np

from rspiv.conditional import ConditionalAccumulator
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf
from rspiv.pod import pod
from rspiv.profiles import profile_from_accumulator
from rspiv.stats import FieldAccumulator
from rspiv.synth.target import PAPER_OPTICS
from rspiv.two_point import TwoPointAccumulator, integral_length
from rspiv.vortices import VortexAccumulator, find_vortices, min_core_vectors
from rspiv.vorticity import VorticityAccumulator

__all__ = [
    "MOMENT_KEYS",
    "PAPER_M",
    "conditional_errors",
    "filtered_profile",
    "moment_errors",
    "pod_errors",
    "quadrant_errors",
    "read_truth",
    "stress_errors",
    "two_point_errors",
    "vortex_errors",
    "vorticity_errors",
    "write_conditional_truth",
    "write_pod_truth",
    "write_vortex_truth",
]

#: The demo's POD domain: up to this many delta_99 from the wall (``[statistics] pod_height``).
POD_HEIGHT = 1.0
#: The modes the demo's POD claim compares.
POD_MODES = 5

#: The paper's magnification, px/mm (the synthetic scenes keep it at every scale).
PAPER_M = PAPER_OPTICS.magnification


def read_truth(directory: pathlib.Path) -> dict[str, Any]:
    p = pathlib.Path(directory) / "truth.json"
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"{p}: cannot read the synthetic truth ({exc})") from None


def filtered_profile(directory: pathlib.Path, info: dict[str, Any]):
    import xarray as xr


    with xr.open_dataset(pathlib.Path(directory) / "truth_filtered.nc", engine="h5netcdf") as ds:
        acc = FieldAccumulator.from_xarray(ds.load())
    prof = profile_from_accumulator(acc)
    d = np.asarray(info["filtered_wall_distance_px"])
    ut_px = info["u_inf_px"] / info["u_inf_plus"]
    return {
        "y_plus": d / info["viscous_length_px"],
        "u_plus": prof["U"] / ut_px,
        "uu_plus": prof["uu"] / ut_px**2,
        "vv_plus": prof["vv"] / ut_px**2,
        "uv_plus": prof["uv"] / ut_px**2,
        **{k: prof[k] for k in MOMENT_KEYS},
    }


#: The skewness and flatness compared with the exact field (:func:`moment_errors`).
MOMENT_KEYS = ("S_u", "F_u", "S_v", "F_v")


def moment_errors(r, filt: dict[str, Any], ut: float, nu: float, re_tau: float) -> dict:
    """Largest deviation of the measured skewness and flatness of u and v from the
    window-averaged exact field ``filt``, from 2.5 window heights off the wall (the rows not
    flagged ``near_wall``) to 0.5 delta+."""
    yp = r.y * ut / nu
    mom = r.extra
    if not all(k in mom for k in (*MOMENT_KEYS, "near_wall")):
        return {k: float("nan") for k in MOMENT_KEYS}
    out = {}
    for k in MOMENT_KEYS:
        meas = np.asarray(mom[k])
        m = (mom["near_wall"] == 0) & (yp <= 0.5 * re_tau) & np.isfinite(meas)
        ref = np.interp(yp[m], filt["y_plus"], filt[k])
        out[k] = float(np.max(np.abs(meas[m] - ref))) if m.any() else float("nan")
    return out


def stress_errors(r, filt: dict[str, Any], ut: float, nu: float, re_tau: float) -> dict:
    """Largest relative deviation of the measured uu+, vv+ and -uv+ (true wall units) from the
    window-averaged exact field ``filt`` over 30 <= y+ <= 0.5 delta+."""
    yp = r.y * ut / nu
    scale = (r.u_tau / ut) ** 2
    out = {}
    for comp in ("uu", "vv", "uv"):
        meas = getattr(r, f"{comp}_plus") * scale
        m = (yp >= 30) & (yp <= 0.5 * re_tau) & np.isfinite(meas)
        if not m.any():
            out[comp] = float("nan")
            continue
        ref = np.interp(yp[m], filt["y_plus"], filt[f"{comp}_plus"])
        out[comp] = float(np.max(np.abs(meas[m] / ref - 1.0)))
    return out


def two_point_errors(prof: dict | None, directory: pathlib.Path, info: dict[str, Any]) -> dict:
    """Largest deviation of a run's streamwise correlation coefficients ``R_uu, R_vv`` (lags
    within two correlation lengths) and largest relative deviation of their integral lengths
    from the same pairs' exact field (``truth_two_point.nc``), over the rows from 2.5 window
    heights off the wall (not ``near_wall``) to 0.5 delta, at the rows' measured distances;
    and the largest deviation of the maps about each reference row up to 0.8 delta (beyond, the
    layer's fluctuations fade into the free stream and the coefficients into noise), at the
    same separation from the reference row."""
    import xarray as xr

    keys = ("R_uu", "R_vv", "L_uu", "L_vv", "map_uu", "map_vv")
    if prof is None or "R_uu_map" not in prof:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_two_point.nc", engine="h5netcdf") as ds:
        acc = TwoPointAccumulator.from_dataset_vars(ds.load(), set())
    exact, exact_maps = acc.correlation(), acc.maps()
    d = np.asarray(info["filtered_wall_distance_px"])
    delta_px = info["delta99_mm"] * PAPER_M
    rows = ~prof["near_wall"] & (prof["dist_px"] <= 0.5 * delta_px)
    m = (prof["R_uu"].shape[1] - 1) // 2
    step = float(prof["dx"][m + 1] - prof["dx"][m])  # one grid step, in the run's length unit
    grid_px = info["grid_step_px"]
    # lags (grid steps) held by both, within two correlation lengths
    lags = np.arange(-m, m + 1)
    reach = np.abs(lags) * grid_px <= 2 * info["scene"]["correlation_px"]
    use = np.flatnonzero(np.isin(lags, exact["lag"]) & reach)
    col = np.searchsorted(exact["lag"], lags[use])
    out = {}
    for q in ("uu", "vv"):
        ref = np.array([np.interp(prof["dist_px"][rows], d, exact[f"R_{q}"][:, c]) for c in col]).T
        out[f"R_{q}"] = float(np.nanmax(np.abs(prof[f"R_{q}"][rows][:, use] - ref)))
        length = integral_length(exact["lag"], exact[f"R_{q}"]) * grid_px
        ref_l = np.interp(prof["dist_px"][rows], d, length)
        out[f"L_{q}"] = float(np.nanmax(np.abs(prof[f"L_{q}"][rows] / step * grid_px / ref_l - 1)))
    # the maps, in the separation from each reference row (the exact rows about their own)
    d_map = d[exact_maps["rows"]]
    for q in ("uu", "vv"):
        worst = 0.0
        for i, ref in enumerate(exact_maps["refs"]):
            sep = prof["map_dist_px"] - prof["ref_dist_px"][i] + d[ref]
            inside = (sep >= d_map[0]) & (sep <= d_map[-1])
            inside &= prof["map_dist_px"] <= 0.8 * delta_px  # beyond, the free stream's noise
            ref_m = np.array(
                [np.interp(sep[inside], d_map, exact_maps[f"R_{q}"][i][:, c]) for c in col]
            ).T
            diff = prof[f"R_{q}_map"][i][inside][:, use] - ref_m
            worst = max(worst, float(np.nanmax(np.abs(diff))))
        out[f"map_{q}"] = worst
    return out


def quadrant_errors(prof: dict | None, directory: pathlib.Path, info: dict[str, Any]) -> dict:
    """Largest deviation of a run's shares of u'v' carried by ejections (Q2) and sweeps (Q4)
    at hole sizes 0 and 2 from those of the same pairs' exact field (``truth_quadrant.nc``),
    over the rows from 2.5 window heights off the wall (not ``near_wall``) to 0.5 delta, at the
    rows' measured distances."""
    import xarray as xr

    keys = {"Q2 H0": (1, 0.0), "Q4 H0": (3, 0.0), "Q2 H2": (1, 2.0), "Q4 H2": (3, 2.0)}
    if prof is None:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_quadrant.nc", engine="h5netcdf") as ds:
        d, holes, frac = ds["y"].values, list(ds["hole"].values), ds["fraction"].values
    rows = ~prof["near_wall"] & (prof["dist_px"] <= 0.5 * info["delta99_mm"] * PAPER_M)
    mine = list(prof["holes"])
    out = {}
    for k, (q, h) in keys.items():
        ref = np.interp(prof["dist_px"][rows], d, frac[:, q, holes.index(h)])
        out[k] = float(np.nanmax(np.abs(prof["fraction"][rows, q, mine.index(h)] - ref)))
    return out


def vorticity_errors(prof: dict | None, directory: pathlib.Path, info: dict[str, Any]) -> dict:
    """Largest relative deviation of a run's vorticity rms and of its mean vorticity from the
    same pairs' exact field by the same scheme on the same grid (``truth_vorticity.nc``), over
    the rows from 2.5 window heights off the wall (not ``near_wall``) to 0.5 delta, at the
    rows' measured distances; and the median ratio of the rms to the exact one (the
    measurement noise, which the differences amplify, raises it)."""
    import xarray as xr

    keys = ("omega_rms", "omega_mean", "median rms ratio")
    if prof is None or "omega_rms" not in prof:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_vorticity.nc", engine="h5netcdf") as ds:
        d, rms, mean = ds["y"].values, ds["omega_rms"].values, ds["omega_mean"].values
    rows = ~prof["near_wall"] & (prof["dist_px"] <= 0.5 * info["delta99_mm"] * PAPER_M)
    per_pair = info["dt"] if prof.get("per_s") else 1.0  # the run's 1/s back to 1/pair
    y = prof["dist_px"][rows]
    ratio = prof["omega_rms"][rows] * per_pair / np.interp(y, d, rms)
    dev = prof["omega_mean"][rows] * per_pair / np.interp(y, d, mean) - 1.0
    return {
        "omega_rms": float(np.nanmax(np.abs(ratio - 1.0))),
        "omega_mean": float(np.nanmax(np.abs(dev))),
        "median rms ratio": float(np.nanmedian(ratio)),
    }


def write_pod_truth(
    path: pathlib.Path, exact: list, d: np.ndarray, delta_px: float, window_h: float
) -> pathlib.Path:
    """The snapshot POD (:func:`rspiv.pod.pod`) of the pairs' exact fields ``exact`` (``(u, v)``
    per pair on rows ``d`` px from the wall) over the campaign's domain (from 2.5 window heights
    off the wall to ``POD_HEIGHT`` delta_99), written to ``path``: ``energy`` (px^2 per pair^2,
    summed over the domain), ``coefficient`` (pair, mode), attributes ``total_energy`` and
    ``vectors``."""
    import xarray as xr

    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: the campaign's rule

    u = np.array([e[0] for e in exact])
    v = np.array([e[1] for e in exact])
    rows = (d >= NEAR_WALL_HEIGHTS * window_h) & (d <= POD_HEIGHT * delta_px)
    r = pod(u, v, n_modes=2 * POD_MODES, domain=np.broadcast_to(rows[:, None], u.shape[1:]))
    return write_netcdf(
        xr.Dataset(
            {"energy": ("mode", r.energy), "coefficient": (("pair", "mode"), r.coefficients)},
            coords={"mode": np.arange(1, r.n_modes + 1)},
            attrs={
                "total_energy": r.total,
                "vectors": int(r.domain.sum()),
                "description": "snapshot POD of the exact field (rspiv.pod), px per pair",
            },
        ),
        path,
    )


def pod_errors(prof: dict | None, directory: pathlib.Path) -> dict:
    """A run's POD against that of the same pairs' exact field (``truth_pod.nc``), both per
    vector of their domains (the grids differ by a fraction of a row): the relative deviation
    of the total fluctuation energy and the largest of the first ``POD_MODES`` eigenvalues; and
    the smallest cosine of the principal angles between the spans of the first ``POD_MODES``
    coefficient vectors (the modes' subspace seen in the snapshots, grid-free: 1 when the
    measurement orders the pairs' structures as the truth does, even where modes mix)."""
    import xarray as xr

    keys = ("total", "eigenvalues", "subspace")
    if prof is None:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_pod.nc", engine="h5netcdf") as ds:
        lam, coef = ds["energy"].values, ds["coefficient"].values
        total, vectors = float(ds.attrs["total_energy"]), int(ds.attrs["vectors"])
    k2 = prof["k"] ** 2
    k = min(POD_MODES, lam.size, prof["energy"].size)
    mine = prof["energy"][:k] / k2 / prof["vectors"]
    ref = lam[:k] / vectors
    qa, _ = np.linalg.qr(coef[:, :k])
    qb, _ = np.linalg.qr(prof["coefficient"][:, :k])
    return {
        "total": float(prof["total"] / k2 / prof["vectors"] / (total / vectors) - 1.0),
        "eigenvalues": float(np.max(np.abs(mine / ref - 1.0))),
        "subspace": float(np.linalg.svd(qa.T @ qb, compute_uv=False).min()),
    }


def write_vortex_truth(
    path: pathlib.Path,
    exact: list,
    d: np.ndarray,
    dx: float,
    window: tuple[int, int],
    scheme: str,
    threshold: float,
    min_diameter: float,
) -> pathlib.Path:
    """The vortex population of the pairs' exact fields ``exact`` (``(u, v)`` per pair on rows
    ``d`` px from the wall, spacing ``dx``), found as a campaign finds it
    (:mod:`rspiv.campaign.vortices`: the same scheme, ``threshold`` times each row's rms of
    the signed swirling strength, rows from 2.5 heights of the final ``window`` plus the
    stencil's reach, cores smaller than a disc ``min_diameter`` windows wide dropped), written
    to ``path``: ``count`` per row and kind (prograde, retrograde), ``radius_sum``, ``area`` (the
    row's strip, px^2), attribute ``pairs``."""
    import xarray as xr

    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: the campaign's rule
    from rspiv.derivatives import SCHEMES  # deferred: beside the rule

    dy = float(d[1] - d[0])
    # rows turned to the image's (down, towards the wall): its y-up frame is the flow's
    fields = [VorticityAccumulator.fields(u[::-1], -v[::-1], np.ones(u.shape, bool), dx, dy,
                                          scheme) for u, v in exact]  # fmt: skip
    omega = np.array([w[::-1] for w, _ in fields])
    swirl = np.array([s[::-1] for _, s in fields])
    reach = max(abs(k) for k in SCHEMES[scheme][0]) * dy
    rows = d >= NEAR_WALL_HEIGHTS * window[1] + reach
    min_vectors = min_core_vectors(min_diameter * max(window), dx, dy)
    fin = np.isfinite(swirl)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt((np.where(fin, swirl, 0.0) ** 2).sum(axis=(0, 2)) / fin.sum(axis=(0, 2)))
        mean = np.where(fin, omega, 0.0).sum(axis=(0, 2)) / fin.sum(axis=(0, 2))
    thr = np.where(rows & (rms > 0), threshold * rms, np.inf)[:, None]
    prograde = -1.0 if np.nanmedian(mean[rows]) <= 0 else 1.0
    acc = VortexAccumulator(d.size, prograde)
    for w, s in zip(omega, swirl, strict=True):
        cores = find_vortices(s, w, thr, dx, dy, y=np.arange(d.size, dtype=np.float64),
                              min_vectors=min_vectors)  # fmt: skip
        acc.add(cores, np.rint(cores["y"]).astype(np.int64))
    area = np.isfinite(swirl).any(axis=0).sum(axis=1) * dx * dy
    return write_netcdf(
        xr.Dataset(
            {
                "count": (("y", "kind"), acc.count.T),
                "radius_sum": (("y", "kind"), acc.radius_sum.T),
                "area": ("y", area),
            },
            coords={"y": d, "kind": ["prograde", "retrograde"]},
            attrs={"pairs": len(exact), "description": "vortex cores of the exact field "
                   "(rspiv.vortices); y = wall distance, px"},  # fmt: skip
        ),
        path,
    )


def vortex_errors(prof: dict | None, directory: pathlib.Path, info: dict[str, Any]) -> dict:
    """A run's vortex population against that of the same pairs' exact field
    (``truth_vortices.nc``), over the rows of both from the first searched row to 0.5 delta:
    the relative deviation of the prograde and retrograde cores per area and pair, and of
    their mean radius."""
    import xarray as xr

    keys = ("prograde", "retrograde", "radius")
    if prof is None:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_vortices.nc", engine="h5netcdf") as ds:
        d, count, rsum = ds["y"].values, ds["count"].values, ds["radius_sum"].values
        area, pairs = ds["area"].values, int(ds.attrs["pairs"])
    top = 0.5 * info["delta99_mm"] * PAPER_M
    lo = max(float(prof["dist_px"][0]), float(d[np.flatnonzero(count.sum(1) > 0)[0]]))
    mine = (prof["dist_px"] >= lo) & (prof["dist_px"] <= top)
    ref = (d >= lo) & (d <= top)
    m = prof["y"][0] / prof["dist_px"][0] if prof["dist_px"][0] > 0 else 1.0  # m per px
    dens = prof["count"][mine].sum(0) / (prof["pairs"] * prof["area"][mine].sum() / m**2)
    dens_ref = count[ref].sum(0) / (pairs * area[ref].sum())
    rad = np.nansum(prof["radius"][mine] * prof["count"][mine]) / prof["count"][mine].sum() / m
    rad_ref = rsum[ref].sum() / count[ref].sum()
    return {
        "prograde": float(dens[0] / dens_ref[0] - 1.0),
        "retrograde": float(dens[1] / dens_ref[1] - 1.0),
        "radius": float(rad / rad_ref - 1.0),
    }


def write_conditional_truth(
    path: pathlib.Path,
    exact: list,
    acc: FieldAccumulator,
    d: np.ndarray,
    dx: float,
    heights: tuple[float, ...],
    window_h: float,
    hole: float,
) -> pathlib.Path:
    """The conditional averages about ejections and sweeps (:class:`rspiv.conditional.
    ConditionalAccumulator`) of the pairs' exact fields ``exact`` (``(u, v)`` per pair on rows
    ``d`` px from the wall, spacing ``dx``; ``acc`` their statistics), planned as a campaign
    plans them (:mod:`rspiv.campaign.conditional`: reference rows nearest to ``heights`` px, the
    rows from 2.5 final window heights ``window_h`` to twice the highest, offsets as far either
    way), written to ``path``: ``u``, ``v`` (ref, kind, y, dx) in px per pair, ``y`` and ``dx``
    in px (downstream positive), ``events``."""
    import xarray as xr

    from rspiv.campaign.two_point import map_rows  # deferred: the campaign's plan

    band, refs = map_rows(d, heights, window_h)
    half = min(int(np.ceil(2.0 * max(heights) / dx)), acc.shape[1] - 1)
    sign_x = float(np.sign(np.nanmean(acc.mean_u))) or 1.0
    with np.errstate(invalid="ignore"):
        q = ConditionalAccumulator(acc.mean_u, acc.mean_v, np.sqrt(acc.uu), np.sqrt(acc.vv),
                                   refs, rows=band, half_width=half, sign_x=sign_x,
                                   hole=hole)  # fmt: skip
    for k, (u, v) in enumerate(exact):
        q.add(u, v, np.ones(u.shape, bool), pair_id=k, batch=k * q.batches // len(exact))
    r = q.results()
    dxs = sign_x * r["offsets"] * dx
    order = np.argsort(dxs)
    dims = ("ref", "kind", "y", "dx")
    return write_netcdf(
        xr.Dataset(
            {
                "u": (dims, r["u"][..., order]),
                "v": (dims, r["v"][..., order]),
                "events": (("ref", "kind"), r["events"]),
            },
            coords={"y": d[r["rows"]], "dx": dxs[order], "y_ref": ("ref", d[r["ref_rows"]])},
            attrs={"pairs": len(exact), "description": "conditional averages of the exact "
                   "field (rspiv.conditional); px per pair, y = wall distance, px"},  # fmt: skip
        ),
        path,
    )


def conditional_errors(prof: dict | None, directory: pathlib.Path) -> dict:
    """A run's conditional averages against those of the same pairs' exact field
    (``truth_conditional.nc``, interpolated to the run's rows and offsets): per kind (Q2, Q4),
    the largest deviation of ``u'`` or ``v'`` anywhere on the maps (rows not ``near_wall``,
    offsets within both maps) over the exact map's largest ``|u'|``, the largest over the
    reference heights."""
    import xarray as xr

    keys = ("Q2", "Q4")
    if prof is None:
        return {k: float("nan") for k in keys}
    with xr.open_dataset(directory / "truth_conditional.nc", engine="h5netcdf") as ds:
        d, dxs, tu, tv = ds["y"].values, ds["dx"].values, ds["u"].values, ds["v"].values
    x = prof["dx_px"]
    cols = (x >= dxs[0]) & (x <= dxs[-1])
    rows = ~np.asarray(prof["near_wall"], bool)
    rows &= (prof["dist_px"] >= d[0]) & (prof["dist_px"] <= d[-1])
    y = prof["dist_px"][rows]
    out = {}
    for j, key in enumerate(keys):
        worst = 0.0
        for i in range(tu.shape[0]):
            dev, peak = 0.0, 0.0
            for name, t in (("u", tu), ("v", tv)):
                ref = np.array([np.interp(x[cols], dxs, t[i, j, r]) for r in range(d.size)])
                ref = np.array([np.interp(y, d, ref[:, c]) for c in range(ref.shape[1])]).T
                mine = prof[name][i, j][rows][:, cols] / prof["k"]
                dev = max(dev, float(np.nanmax(np.abs(mine - ref))))
                if name == "u":
                    peak = float(np.nanmax(np.abs(ref)))
            worst = max(worst, dev / peak if peak > 0 else float("inf"))
        out[key] = worst
    return out
