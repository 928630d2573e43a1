"""A time-resolved campaign's frequency spectra and convection velocities (``[statistics]
temporal``).

A second pass over the fields the pair loop wrote (``[output] fields = true``), at the end of a
run whose frames are paired sequentially (``[images] pairing = "sequential"``; both required by
the configuration): every pair's field file is read back in time order and added to a
:class:`~rspiv.temporal.TemporalAccumulator` about the run's own statistics (the definitions,
the frame and what the PIV's noise does are there).

Time: pair k starts at frame ``k pair_step``, so pairs lie ``pair_step`` frame intervals apart
and ``[flow] dt`` (the time across ``frame_gap`` frames) makes the pair interval ``dt pair_step /
frame_gap`` seconds. Where: the rows nearest to ``temporal_heights`` from the run's wall (the
run's own delta_99 with ``temporal_height_units = "delta"``, which needs its boundary-layer fit;
or px), each at least 2.5 final window heights off the wall. The correlations reach
``temporal_max_lag`` pair intervals and, along the row, 1.25 times the distance the mean flow
at the references covers in that time (at most the row).

Output ``temporal_<run>.nc``: per reference (``ref``, ``y_ref``): ``phi_uu``, ``phi_vv``,
``phi_uv`` against ``f`` (Hz and (m/s)^2/Hz with a calibration and ``[flow] dt``; else cycles
and px^2 per pair interval), the premultiplied ``f phi_uu / u_tau^2`` with a boundary-layer fit,
``segments``; ``R_uu``, ``R_vv`` against ``lag`` (s) and ``dx`` (downstream positive), ``peak``
and ``shift`` per lag, and the convection velocity ``U_c`` (the shifts over the lags, a line
through the origin fitted to the lags whose peak stands at 0.2 or more) beside the row's mean
``U`` and their ratio. The PIV's noise floor per reference, ``noise_uu``, ``noise_vv``: ``2
<sigma^2>`` (the run's mean per-vector uncertainty over the row, taken as white, in the spectra's
units; NaN without ``[piv] uncertainty``), and ``f_noise_u``, ``f_noise_v``: the frequency from
which the spectrum stays under twice it (NaN: never). Sequential pairs share a frame, so their
errors are partly anti-correlated: the real floor is lower at low frequencies and higher near the
Nyquist frequency (0.14 to 1.5 times the white one on uniform motion, whose fluctuations are all
noise). A report figure.

Said in one line (log, file attribute, report): a pair whose field file is missing, and gaps in
the pairs (a gap restarts the segments and the lags); fewer consecutive pairs than a segment (no
spectrum); a reference whose correlation has no peak to follow (no convection velocity); a
spectrum within twice its noise floor at every frequency (it measures the noise).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from rspiv.campaign.fields import each_field, finish_pass, pass_section, run_field_files
from rspiv.campaign.spec import RunSpec
from rspiv.campaign.two_point import reference_rows
from rspiv.errors import InvalidInputError
from rspiv.temporal import TemporalAccumulator, consecutive_runs, noise_reached

__all__ = ["report_section", "write_outputs"]


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The frequency spectra and convection velocities of ``run`` (module docstring), written
    as ``OUT/temporal_<run>.nc`` (with ``[output] netcdf``); None when ``[statistics]
    temporal`` is off."""
    cfg = camp.config
    st = cfg.statistics
    if not st.temporal:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    p = an.profile
    dist = np.asarray(p["dist_px"], np.float64)
    _, refs, _ = reference_rows(
        an, st.temporal_heights, st.temporal_height_units, "temporal_heights",
        res.context.piv.final_window[1],
    )
    ids, paths, x = run_field_files(camp, run.name, acc.pair_ids)
    dx_px = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    images = cfg.images
    per_interval = images.pair_step / images.frame_gap  # px per pair -> px per pair interval
    usable = an.flow_vectors(acc, st.min_count)
    sign_x = float(p.get("sign_x", 1.0))
    ok_ref = usable[refs] & np.isfinite(acc.mean_u[refs])
    with np.errstate(invalid="ignore", divide="ignore"):
        u_ref = np.where(ok_ref, acc.mean_u[refs], 0.0).sum(1) / ok_ref.sum(1)  # NaN: none
    u_ref = sign_x * u_ref * per_interval  # px per pair interval, downstream
    reach = st.temporal_max_lag * float(np.nanmax(np.abs(u_ref), initial=0.0)) / dx_px
    half = min(int(np.ceil(1.25 * reach)) + 8, acc.shape[1] - 1)
    q = TemporalAccumulator(
        acc.mean_u,
        acc.mean_v,
        refs,
        usable=usable,
        sign_x=sign_x,
        sign_y=float(p.get("sign_y", 1.0)),
        segment=st.temporal_segment,
        max_lag=st.temporal_max_lag,
        half_width=half,
    )

    def add(part: TemporalAccumulator, i: int, pid: int, u, v, valid) -> None:
        part.add(u, v, valid, pair_id=pid)

    # parts in parallel lose the segments across their boundaries: only for long runs
    workers = None if len(ids) >= 32 * st.temporal_segment else 1
    parts, missing = each_field(
        paths, acc.shape, run.name, lambda w: q if w == 0 else q.empty_copy(), add, workers,
        screen=res.context.screens().get(run.name),
    )  # fmt: skip
    for other in parts[1:]:
        q.merge(other)
    r = q.results()
    si = bool(p.get("si"))
    m = p["m_per_px"] if si else 1.0
    dt = cfg.flow.dt
    interval = dt * per_interval if dt > 0 else 1.0  # s (or 1: pair intervals)
    k = float(p.get("k", 1.0))  # m/s per px per pair
    vel2 = k**2 if si else 1.0  # (m/s)^2 per (px per pair)^2
    order = np.argsort(sign_x * r["offsets"])
    shift = sign_x * r["shift"] * dx_px  # px downstream
    lags = r["lag"].astype(np.float64)
    ok = np.isfinite(shift) & (lags > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        u_c = np.where(ok, shift * lags, 0.0).sum(1) / np.where(ok, lags**2, 0.0).sum(1)
        u_c = np.where(ok.sum(1) >= 2, u_c, np.nan)  # px per pair interval
    prof: dict[str, Any] = {
        "y_ref": dist[refs] * m,
        "dist_px": dist[refs],
        "ref_rows": refs,
        "f": r["f"] / interval,
        "phi_uu": r["phi_uu"] * vel2 * interval,
        "phi_vv": r["phi_vv"] * vel2 * interval,
        "phi_uv": r["phi_uv"] * vel2 * interval,
        "segments": r["segments"],
        "lag": lags * interval,
        "dx": sign_x * r["offsets"][order] * dx_px * m,
        "R_uu": r["R_uu"][..., order],
        "R_vv": r["R_vv"][..., order],
        "peak": r["peak"],
        "shift": shift * m,
        "U_c": u_c * m / interval,
        "U": u_ref * m / interval,
        "si": si,
        "per_s": dt > 0,
        "interval": interval,
        "pairs": int(q.n_fields),
        "missing": missing,
    }
    with np.errstate(invalid="ignore", divide="ignore"):
        prof["U_c_ratio"] = prof["U_c"] / prof["U"]
    # the PIV's noise: white, 2 <sigma^2> per cycle per pair interval (one-sided)
    for c, noise in (("u", acc.noise_uu()), ("v", acc.noise_vv())):
        has = ok_ref & np.isfinite(noise[refs])
        with np.errstate(invalid="ignore", divide="ignore"):
            s2 = np.where(has, noise[refs], 0.0).sum(1) / has.sum(1)  # NaN: no uncertainties
        floor = 2.0 * s2 * vel2 * interval
        reach = noise_reached(prof[f"phi_{c}{c}"], floor)
        prof[f"noise_{c}{c}"] = floor
        prof[f"f_noise_{c}"] = np.where(reach >= 0, prof["f"][np.maximum(reach, 0)], np.nan)
    bl = an.result
    if bl is not None and si and dt > 0:
        lv = bl.nu / bl.u_tau
        prof["y_ref_plus"] = prof["y_ref"] / lv
        prof["f_phi_uu_plus"] = prof["f"] * prof["phi_uu"] / bl.u_tau**2
        prof["f_phi_vv_plus"] = prof["f"] * prof["phi_vv"] / bl.u_tau**2
        prof["noise_uu_plus"] = prof["noise_uu"] / bl.u_tau**2  # times f: wall units
        prof["delta_99"] = float(bl.delta99)
    prof["seconds"] = time.perf_counter() - t0
    camp.say(
        f"{run.label}: frequency spectra and convection velocities at {len(refs)} heights from "
        f"{q.n_fields} consecutive pairs' fields ({prof['seconds']:.1f} s)"
    )
    said = []
    if missing:
        said.append(
            f"{len(missing)} of {len(paths)} pairs have no field file (first: pair "
            f"{missing[0]}): the series break there"
        )
    lengths = consecutive_runs(sorted(set(ids) - set(missing)))
    if len(lengths) > 1:
        said.append(
            f"the pairs form {len(lengths)} unbroken series (the longest {max(lengths)} pairs): "
            "a gap restarts the segments and the lags"
        )
    if not int(r["segments"].sum()):
        said.append(
            f"no {st.temporal_segment} consecutive pairs (temporal_segment) with enough valid "
            f"vectors: no frequency spectrum (the longest series holds {max(lengths, default=0)})"
        )
    lost = [f"{prof['y_ref'][i]:.4g}" for i in range(len(refs)) if not np.isfinite(u_c[i])]
    if lost:
        said.append(
            f"no convection velocity at {', '.join(lost)} {'m' if si else 'px'}: the "
            f"space-time correlation has no peak of {0.2:g} or more inside the offsets at two "
            "lags or more (the structures decorrelate within a pair interval, or noise)"
        )
    drowned = [
        f"{c} at {prof['y_ref'][i]:.4g} {'m' if si else 'px'}"
        for c in ("u", "v")
        for i in range(len(refs))
        if prof[f"f_noise_{c}"][i] <= prof["f"][1] and r["segments"][i] > 0
    ]
    if drowned:
        said.append(
            f"the spectra of {', '.join(drowned)} lie within twice the PIV's noise floor (each "
            "vector's uncertainty, white) at every frequency: they measure the noise, not the "
            "flow"
        )
    return finish_pass(camp, res, run, prof, said, "temporal", "temporal", _dataset)


def _dataset(prof: dict, run: RunSpec) -> Any:
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    per_s = prof["per_s"]
    freq = "Hz" if per_s else "1"
    vel = "m s-1" if prof["si"] and per_s else "pix"
    psd = "m2 s-1" if prof["si"] and per_s else "pix2"
    ds = xr.Dataset(
        coords={
            "ref": ("ref", np.arange(len(prof["y_ref"]))),
            "f": ("f", prof["f"], {"units": freq, "long_name": "frequency (per pair interval "
                  "without [flow] dt)"}),  # fmt: skip
            "lag": ("lag", prof["lag"], {"units": "s" if per_s else "1",
                    "long_name": "time lag (pair intervals without [flow] dt)"}),  # fmt: skip
            "dx": ("dx", prof["dx"], {"units": length, "long_name": "streamwise offset, "
                   "downstream positive"}),  # fmt: skip
        }
    )
    ds["y_ref"] = ("ref", prof["y_ref"], {"units": length, "long_name": "distance from the wall"})
    for q in ("uu", "vv", "uv"):
        ds[f"phi_{q}"] = (("ref", "f"), prof[f"phi_{q}"], {"units": psd,
                          "long_name": "one-sided frequency spectrum (Welch, Hann)"})  # fmt: skip
    ds["segments"] = ("ref", prof["segments"], {"long_name": "column-segments averaged"})
    for q in ("u", "v"):
        ds[f"noise_{q}{q}"] = ("ref", prof[f"noise_{q}{q}"], {"units": psd, "long_name":
                               "the PIV's white noise floor, 2 <sigma^2> (one-sided)"})  # fmt: skip
        ds[f"f_noise_{q}"] = ("ref", prof[f"f_noise_{q}"], {"units": freq, "long_name":
                              "from here up the spectrum stays under twice the floor"})  # fmt: skip
    for q in ("uu", "vv"):
        ds[f"R_{q}"] = (("ref", "lag", "dx"), prof[f"R_{q}"].astype(np.float32),
                        {"units": "1", "long_name": "space-time correlation coefficient"})
    ds["peak"] = (("ref", "lag"), prof["peak"], {"units": "1", "long_name": "largest R_uu"})
    ds["shift"] = (("ref", "lag"), prof["shift"], {"units": length,
                   "long_name": "offset of the largest R_uu"})  # fmt: skip
    ds["U_c"] = ("ref", prof["U_c"], {"units": vel, "long_name": "convection velocity"})
    ds["U"] = ("ref", prof["U"], {"units": vel, "long_name": "the row's mean velocity"})
    ds["U_c_ratio"] = ("ref", prof["U_c_ratio"], {"units": "1"})
    if "y_ref_plus" in prof:
        ds["y_ref_plus"] = ("ref", prof["y_ref_plus"], {"units": "1"})
        for q in ("uu", "vv"):
            ds[f"f_phi_{q}_plus"] = (("ref", "f"), prof[f"f_phi_{q}_plus"], {"units": "1"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "pair_interval": prof["interval"],
            "description": "rspiv frequency spectra and space-time correlations "
            "(rspiv.temporal): u' downstream, v' away from the wall, each vector's fluctuation "
            "about its own mean",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's spectra and convection velocities, or None."""
    main = res.context.runs[0]
    prof = res.temporal.get(main.name)
    if prof is None:
        return None
    unit = "m/s" if prof["si"] and prof["per_s"] else "px per pair interval"
    conv = ", ".join(
        f"{uc:.3g} {unit} ({ratio:.2f} U)"
        for uc, ratio in zip(prof["U_c"], prof["U_c_ratio"], strict=True)
    )
    text = (
        f"Frequency spectra and space-time correlations of {prof['pairs']} consecutive pairs "
        f"at {len(prof['y_ref'])} heights (each vector's fluctuation about its own mean). "
        f"Convection velocities: {conv}. The measurement noise is a floor under the spectra "
        "at high frequencies and lowers the correlation at every lag but zero."
    )
    freq = "Hz" if prof["per_s"] else "cycles per pair interval"
    reach = [
        f"{'beyond the Nyquist frequency' if np.isnan(f) else f'{f:.3g} {freq}'} at "
        f"{y:.3g} {'m' if prof['si'] else 'px'}"
        for f, y in zip(prof["f_noise_u"], prof["y_ref"], strict=True)
    ]
    if np.isfinite(prof["noise_uu"]).any():
        text += (
            " The PIV's noise floor (dotted; 2 <sigma_u^2> from each vector's uncertainty, "
            "taken as white: the estimate is good to about 30 %) is reached by the u spectra "
            f"from {', '.join(reach)}: above it they hold mostly noise."
        )
    return pass_section(
        camp, prof, "Frequency spectra and convection", text,
        "rspiv.plots.temporal:plot_temporal", "temporal",
        f"{main.label}: frequency spectra and space-time correlation",
    )
