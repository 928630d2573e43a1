"""A campaign's vorticity statistics (``[statistics] vorticity``).

Every run's :class:`~rspiv.stats.FieldAccumulator` carries a
:class:`~rspiv.vorticity.VorticityAccumulator` (:func:`attach`, with the scheme the context
names) that each pair's field is added to beside the statistics
(:func:`rspiv.campaign.reduce.add_fields`); checkpoints, shards, ``rspiv merge`` and Dask carry
it with the accumulator.

At the end (:func:`write_outputs`) the rows on the flow side become ``vorticity_<run>.nc``: per
row (``y`` from the wall, ``y_plus``) the mean vorticity ``Omega_z`` and its rms
``omega_rms`` in the flow's frame (a boundary layer's ``Omega_z = -dU/dy < 0``), the signed
swirling strength's mean and rms, in 1/s with ``[flow] dt`` (else 1/pair) and in wall units
(``omega_rms_plus = omega_rms nu / u_tau^2``), the vectors averaged per row and the
``near_wall`` flag, which here also takes the rows whose differences reach into the rows the
wall shapes (the scheme's reach, 2 rows for least squares and Richardson: on the demo's layer
the first row beyond 2.5 window heights read the rms 20 % high against the exact field's, the
next ones 5-7 %). The measured rms holds the measurement noise, amplified by the difference
(about ``0.3-1 sigma / h`` per component, :mod:`rspiv.derivatives`), and lacks what the windows
average away: the DNS's ``omega_z,rms+`` is drawn beside it in the report, not matched.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.campaign.spec import PairContext, RunSpec
from rspiv.derivatives import SCHEMES
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf
from rspiv.reference import dns_profile_for_re_tau
from rspiv.report import ReportSection
from rspiv.vorticity import VorticityAccumulator

__all__ = [
    "attach", "report_section", "vorticity_dataset", "vorticity_profile", "write_outputs",
]  # fmt: skip


def attach(ctx: PairContext, accs: dict[str, Any]) -> dict[str, Any]:
    """Give every run's empty FieldAccumulator in ``accs`` a VorticityAccumulator when the
    context asks for one; returns ``accs``."""
    if not ctx.vorticity:
        return accs
    gx, gy = ctx.grid()
    for run in ctx.runs:
        a = accs.get(run.name)
        if a is None or a.n_fields != 0 or getattr(a, "vorticity", None) is not None:
            continue
        a.vorticity = VorticityAccumulator(
            a.shape, float(gx[0, 1] - gx[0, 0]), float(gy[1, 0] - gy[0, 0]), ctx.vorticity
        )
    return accs


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The vorticity profile of ``run`` (module docstring) written as
    ``OUT/vorticity_<run>.nc`` (with ``[output] netcdf``); None when the run has none."""
    acc = res.accumulators[run.name]
    if getattr(acc, "vorticity", None) is None or not res.context.vorticity:
        return None
    prof = vorticity_profile(
        acc, an, camp.config.statistics.min_count, camp.config.flow.dt,
        res.context.piv.final_window[1],
    )  # fmt: skip
    if camp.config.output.netcdf:
        res.files[f"vorticity_{run.name}"] = write_netcdf(
            vorticity_dataset(prof, run), camp.out_dir / f"vorticity_{run.name}.nc"
        )
    return prof


def vorticity_profile(acc: Any, an: Any, min_count: int, dt: float, window_h: float) -> dict:
    """The rows of an accumulator's :class:`~rspiv.vorticity.VorticityAccumulator` on the flow
    side of the analysis ``an``'s wall (module docstring): a dict of per-row arrays (``y``,
    ``dist_px``, ``omega_mean``, ``omega_rms``, ``swirl_mean``, ``swirl_rms``, their
    ``_plus`` with SI units, ``vectors``, ``near_wall``) and the run's figures. ``dt``: the
    pulse separation (s; 0: per pair); ``window_h``: the final window's height (px).

    Raises
    ------
    InvalidInputError
        No row on the flow side holds the vorticity of two pairs.
    """
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    va = acc.vorticity
    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    usable = an.flow_vectors(acc, min_count)
    # a reflection of one axis flips the vorticity: the flow frame against the image's y-up
    orient = float(p.get("sign_x", 1.0)) * -float(p.get("sign_y", 1.0))
    rows = va.profile(usable, orient)
    keep = np.flatnonzero((dist > 0) & (rows["omega_vectors"] > 0))
    if keep.size == 0:
        raise InvalidInputError("no row on the flow side holds vorticity of two pairs")
    keep = keep[np.argsort(dist[keep])]
    # a row's differences reach this far towards the wall: into the rows the wall shapes
    reach = max(abs(k) for k in SCHEMES[va.scheme][0]) * va.dy
    per_s = 1.0 / dt if dt > 0 else 1.0
    m = p["m_per_px"] if p.get("si") else 1.0
    prof: dict[str, Any] = {
        "y": dist[keep] * m,
        "dist_px": dist[keep],
        "rows": keep,
        "vectors": rows["omega_vectors"][keep],
        "near_wall": dist[keep] < NEAR_WALL_HEIGHTS * window_h + reach,
        "si": bool(p.get("si")),
        "per_s": dt > 0,
        "scheme": va.scheme,
        "pairs": int(va.n_fields),
    }
    for name in ("omega", "swirl"):
        for stat in ("mean", "rms"):
            prof[f"{name}_{stat}"] = rows[f"{name}_{stat}"][keep] * per_s
    r = an.result
    if r is not None and p.get("si") and dt > 0:
        scale = r.nu / r.u_tau**2
        prof["y_plus"] = prof["y"] * r.u_tau / r.nu
        for name in ("omega", "swirl"):
            for stat in ("mean", "rms"):
                prof[f"{name}_{stat}_plus"] = prof[f"{name}_{stat}"] * scale
        prof["re_tau"] = float(r.delta99 * r.u_tau / r.nu)
    return prof


def vorticity_dataset(prof: dict, run: RunSpec) -> Any:
    """The profile of :func:`vorticity_profile` as ``vorticity_<run>.nc``'s Dataset."""
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    rate = "s-1" if prof["per_s"] else "1/pair"
    ds = xr.Dataset(
        coords={"y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"})}
    )
    what = {
        "omega_mean": "mean vorticity Omega_z (flow frame: x downstream, y from the wall)",
        "omega_rms": "rms of the vorticity fluctuation omega_z'",
        "swirl_mean": "mean swirling strength signed by the vorticity",
        "swirl_rms": "rms of the signed swirling strength",
    }
    for k, long in what.items():
        ds[k] = ("y", prof[k], {"units": rate, "long_name": long})
        if f"{k}_plus" in prof:
            ds[f"{k}_plus"] = ("y", prof[f"{k}_plus"], {"units": "1", "long_name": f"{k} nu / "
                                                         "u_tau^2"})  # fmt: skip
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
    ds["vectors"] = ("y", prof["vectors"], {"long_name": "vectors averaged per row"})
    ds["near_wall"] = ("y", prof["near_wall"], {"long_name": "row shaped by the wall"})
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "scheme": prof["scheme"],
            "description": "rspiv vorticity statistics (rspiv.vorticity): differences of each "
            "pair's valid vectors; the rms holds the measurement noise and lacks what the "
            "windows average away",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's vorticity, or None."""
    main = res.context.runs[0]
    prof = res.vorticity.get(main.name)
    if prof is None or "y_plus" not in prof:
        return None
    figures = []
    try:
        from rspiv.plots.vorticity import plot_vorticity  # deferred: matplotlib

        dns = dns_profile_for_re_tau(prof["re_tau"])
        path = plot_vorticity(camp.out_dir / "report" / "figures" / "vorticity.png", prof, dns)
        figures.append((path, f"{main.label}: vorticity against the DNS ({dns.label()})"))
    except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
        camp.say(f"vorticity figure failed: {exc}")
    text = (
        f"Vorticity of {prof['pairs']} pairs by {prof['scheme'].replace('_', ' ')} differences "
        "of each pair's valid vectors, in the flow's frame. Its rms holds the measurement "
        "noise, which the differences amplify, and lacks the scales the windows average away: "
        "the DNS is drawn for comparison, not as a target. Rows within 2.5 window heights of "
        "the wall are left out (near_wall)."
    )
    return ReportSection("Vorticity", text=text, figures=figures)
