"""A time-resolved campaign's spectral POD (``[statistics] spod``).

A second pass over the fields the pair loop wrote (``[output] fields = true``), at the end of a
run whose frames are paired sequentially (``[images] pairing = "sequential"``; both required by
the configuration), with :class:`rspiv.spod.SpodBuilder` (the definitions, the sampling error
and the frame are there):

Domain
    The POD's (:func:`rspiv.campaign.pod.flow_domain`): the flow side's vectors with enough
    valid samples, less the rows the wall shapes, up to ``spod_height`` delta_99 (0: all).
Series
    Every pair's field file is read once, in time order, and its fluctuations about the run's
    statistics (the screen applied; a rejected vector filled with its mean) become a row of the
    ``(pairs, 2 vectors)`` series: held in memory (float64) up to :data:`MEMORY_BYTES`, beyond
    it in a float32 file in a temporary folder inside the output folder (removed after). The
    blocks' transforms and their inner products are then summed over slices of the domain
    (about :data:`BLOCK_BYTES` each) and the modes built from a second sweep of the slices.
    Blocks are ``spod_segment`` pairs, overlapping by half; a gap in the pair ids (a pair left
    out, a missing field file) ends a series, and no block straddles it.
Time
    As the frequency spectra's (:mod:`rspiv.campaign.temporal`): the pair interval is ``dt
    pair_step / frame_gap`` seconds.

Output ``spod_<run>.nc``: ``energy`` (``f``, ``mode``: every eigenvalue, (m/s)^2/Hz summed over
the domain's vectors with a calibration and ``[flow] dt``; else px^2 per pair^2 per cycle per
pair interval), ``total``, ``leading_fraction``, the leading eigenvalue's 95 % interval
(``energy_low``, ``energy_high``); the leading ``spod_modes`` modes at ``spod_frequencies``
frequencies (those where ``f lambda_1`` is largest): ``phi_u_re``, ``phi_u_im``, ``phi_v_re``,
``phi_v_im`` (dims ``mode_f, mode, y, x``; unit norm over the domain, NaN outside; u downstream,
v away from the wall, rows by distance from the wall), and each kept frequency's ``phase_speed``:
the leading mode's phase speed downstream, ``2 pi f`` over the fall of its phase per unit
length (the mean phase step between neighbours along x, weighted by their amplitudes);
``noise_total``: the PIV's noise floor of ``total``, ``2 <sigma^2>`` summed over the domain's
values (each vector's uncertainty, taken as white; see :mod:`rspiv.campaign.temporal` for why it
is not quite), and ``f_noise``, the frequency from which ``total`` stays under twice it. A report
figure.

Said in one line (log, file, report): missing field files and gaps (the series they leave);
more than 5 % of the domain's samples filled; fewer than 8 blocks (the interval spans more than
a factor of 3); the energy within twice the noise floor at every frequency; and no frequency
where the leading eigenvalue's interval clears the second's (nothing coherent stands out of
these blocks' sampling error).
"""

from __future__ import annotations

import tempfile
import time
from typing import Any

import numpy as np

from rspiv.campaign.fields import each_field, finish_pass, pass_section, run_field_files
from rspiv.campaign.pod import flow_domain
from rspiv.campaign.spec import RunSpec
from rspiv.errors import InvalidInputError
from rspiv.spod import SpodBuilder, SpodResult
from rspiv.temporal import noise_reached

__all__ = ["BLOCK_BYTES", "MEMORY_BYTES", "phase_speed", "report_section", "write_outputs"]

#: The series is held in memory (float64) up to this size, beyond it on disk (float32).
MEMORY_BYTES = 1 << 30
#: Memory of one slice of the domain's values while the transforms are summed (about 64 bytes
#: per value and pair: the values, the tapered blocks and their transforms).
BLOCK_BYTES = 256 << 20


def phase_speed(r: SpodResult) -> np.ndarray:
    """The leading mode's phase speed at each kept frequency (``r.mode_f``), in grid columns
    per pair interval towards +x: ``2 pi f / -dphi``, with ``dphi`` the phase of ``sum
    phi(x + 1) conj(phi(x))`` over both components and every row (the amplitude-weighted mean
    phase step; a structure's phase falls downstream). NaN where the step is 0 or undefined."""
    out = np.full(r.mode_f.size, np.nan)
    for i, fi in enumerate(r.mode_f):
        s = 0j
        for phi in (r.modes_u[i, 0], r.modes_v[i, 0]):
            s += np.nansum(phi[:, 1:] * np.conj(phi[:, :-1]))
        step = np.angle(s)
        if s != 0 and step != 0:
            out[i] = 2 * np.pi * r.f[fi] / -step
    return out


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The SPOD of ``run`` (module docstring), written as ``OUT/spod_<run>.nc`` (with
    ``[output] netcdf``); None when ``[statistics] spod`` is off."""
    cfg = camp.config
    st = cfg.statistics
    if not st.spod:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    p = an.profile
    domain = flow_domain(camp, res, an, acc, st.spod_height, "spod_height")
    ids, paths, x_px = run_field_files(camp, run.name, acc.pair_ids)
    missing = [pid for pid in ids if not paths[pid].exists()]
    present = [pid for pid in ids if paths[pid].exists()]
    sign_x, sign_y = float(p.get("sign_x", 1.0)), float(p.get("sign_y", 1.0))
    builder = SpodBuilder(
        acc.mean_u, acc.mean_v, domain, present, st.spod_segment, sign_x, sign_y
    )
    row = {pid: i for i, pid in enumerate(present)}
    n_t, n_val = builder.n_t, builder.n_values
    with tempfile.TemporaryDirectory(prefix=".spod-", dir=camp.out_dir) as tmp:
        if n_t * n_val * 8 <= MEMORY_BYTES:
            series = np.empty((n_t, n_val))
        else:
            series = np.lib.format.open_memmap(
                f"{tmp}/series.npy", mode="w+", dtype=np.float32, shape=(n_t, n_val)
            )

        def add(part: None, i: int, pid: int, u, v, valid) -> None:
            series[row[pid]] = builder.fluctuations(u, v, valid)

        each_field(
            {pid: paths[pid] for pid in present}, acc.shape, run.name, lambda w: None, add,
            screen=res.context.screens().get(run.name),
        )  # fmt: skip
        per = max(1, BLOCK_BYTES // (64 * n_t))
        slices = [slice(c, min(c + per, n_val)) for c in range(0, n_val, per)]
        for sl in slices:
            builder.add_columns(sl, series[:, sl])
        builder.solve(st.spod_modes, n_frequencies=st.spod_frequencies)
        for sl in slices:
            builder.add_mode_columns(sl, series[:, sl])
    r = builder.result()
    dist = np.asarray(p["dist_px"], np.float64)
    keep = np.flatnonzero(domain.any(axis=1))
    keep = keep[np.argsort(dist[keep])]
    si = bool(p.get("si"))
    m = p["m_per_px"] if si else 1.0
    images = cfg.images
    per_interval = images.pair_step / images.frame_gap
    dt = cfg.flow.dt
    interval = dt * per_interval if dt > 0 else 1.0  # s (or 1: pair intervals)
    k = float(p.get("k", 1.0)) if si else 1.0  # m/s per px per pair
    dx_px = float(np.median(np.diff(x_px))) if x_px.size > 1 else 1.0
    e_scale = k * k * interval  # (px per pair)^2 per cycle per interval -> the output's
    low, high = r.interval(0.95)
    c = phase_speed(r)  # columns per pair interval towards +x
    prof: dict[str, Any] = {
        "y": dist[keep] * m,
        "dist_px": dist[keep],
        "rows": keep,
        "x": x_px * m,
        "f": r.f / interval,
        "energy": r.energy * e_scale,
        "energy_low": low[:, 0] * e_scale,
        "energy_high": high[:, 0] * e_scale,
        "second_high": high[:, 1] * e_scale if r.blocks > 1 else np.full(r.f.size, np.nan),
        "total": r.total * e_scale,
        "leading_fraction": r.fraction[:, 0],
        "mode_f": r.f[r.mode_f] / interval,
        "phi_u": r.modes_u[:, :, keep],
        "phi_v": r.modes_v[:, :, keep],
        "phase_speed": sign_x * c * dx_px * m / interval,
        "blocks": r.blocks,
        "segment": r.segment,
        "nu": float(r.nu[1]),
        "series": len(r.series),
        "gaps": r.gaps,
        "vectors": int(domain.sum()),
        "si": si,
        "per_s": dt > 0,
        "interval": interval,
        "pairs": n_t,
        "missing": missing,
    }
    # the PIV's noise, white: 2 <sigma^2> per value (one-sided), summed over the domain
    with np.errstate(invalid="ignore"):
        s2 = float(np.nansum(acc.noise_uu()[domain] + acc.noise_vv()[domain]))
    has_noise = bool(np.isfinite(acc.noise_uu()[domain]).any())
    prof["noise_total"] = 2.0 * s2 * e_scale if has_noise else float("nan")
    reach = int(noise_reached(prof["total"], prof["noise_total"]))
    prof["f_noise"] = float(prof["f"][reach]) if reach >= 0 else float("nan")
    bl = an.result
    if bl is not None and si:
        prof["y_plus"] = prof["y"] / (bl.nu / bl.u_tau)
        prof["delta_99"] = float(bl.delta99)
    prof["seconds"] = time.perf_counter() - t0
    camp.say(
        f"{run.label}: SPOD of {n_t} consecutive pairs' fields over {prof['vectors']} vectors, "
        f"{r.blocks} blocks of {r.segment} ({prof['seconds']:.1f} s)"
    )
    said = []
    if missing:
        said.append(
            f"{len(missing)} of {len(ids)} pairs have no field file (first: pair {missing[0]})"
        )
    if len(r.series) > 1:
        said.append(
            f"the pairs form {len(r.series)} unbroken series (the longest {max(r.series)} "
            "pairs): no block straddles a gap"
        )
    if r.gaps > 0.05:
        said.append(
            f"{100 * r.gaps:.1f} % of the domain's samples were rejected vectors filled with "
            "their mean: the eigenvalues read low by about as much"
        )
    if r.blocks < 8:
        spread = float(np.nanmedian(high[1:, 0] / low[1:, 0]))
        said.append(
            f"only {r.blocks} blocks of {r.segment} pairs: an eigenvalue's 95 % interval spans "
            f"a factor of {spread:.1f}"
        )
    if 0 <= reach <= 1:
        said.append(
            "the fluctuation energy lies within twice the PIV's noise floor (each vector's "
            "uncertainty, white) at every frequency: the decomposition is of the noise"
        )
    clears = prof["energy_low"][1:] > prof["second_high"][1:]
    if not clears.any():
        said.append(
            "at no frequency does the leading eigenvalue's 95 % interval clear the second's: "
            "nothing coherent stands out of these blocks' sampling error, and no mode's shape "
            "is determined"
        )
    return finish_pass(camp, res, run, prof, said, "spod", "SPOD", _dataset)


def _dataset(prof: dict, run: RunSpec) -> Any:
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    per_s = prof["per_s"]
    vel = "m s-1" if prof["si"] and per_s else "pix"
    psd = "m2 s-1" if prof["si"] and per_s else "pix2"
    n_modes = prof["phi_u"].shape[1]
    ds = xr.Dataset(
        coords={
            "f": ("f", prof["f"], {"units": "Hz" if per_s else "1",
                  "long_name": "frequency (per pair interval without [flow] dt)"}),  # fmt: skip
            "mode": ("mode", np.arange(1, prof["energy"].shape[1] + 1)),
            "mode_f": ("mode_f", prof["mode_f"], {"units": "Hz" if per_s else "1",
                       "long_name": "the frequencies whose modes are kept"}),  # fmt: skip
            "kept": ("kept", np.arange(1, n_modes + 1)),
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "x": ("x", prof["x"], {"units": length, "long_name": "x of the measured frame"}),
        }
    )
    ds["energy"] = (("f", "mode"), prof["energy"], {"units": psd, "long_name": "SPOD "
                    "eigenvalue, summed over the domain's vectors (one-sided)"})  # fmt: skip
    ds["total"] = ("f", prof["total"], {"units": psd, "long_name": "every eigenvalue summed"})
    ds["leading_fraction"] = ("f", prof["leading_fraction"], {"units": "1"})
    ds["noise_total"] = ((), prof["noise_total"], {"units": psd, "long_name": "the PIV's white "
                         "noise floor of total: 2 <sigma^2> summed over the domain"})  # fmt: skip
    ds["f_noise"] = ((), prof["f_noise"], {"units": "Hz" if per_s else "1", "long_name":
                     "from here up total stays under twice the noise floor"})  # fmt: skip
    for key, what in (("energy_low", "lower"), ("energy_high", "upper")):
        name = f"{what} end of the leading eigenvalue's 95 % interval"
        ds[key] = ("f", prof[key], {"units": psd, "long_name": name})
    dims = ("mode_f", "kept", "y", "x")
    for comp, along in (("u", "u downstream"), ("v", "v away from the wall")):
        phi = prof[f"phi_{comp}"]
        for part, val in (("re", phi.real), ("im", phi.imag)):
            name = f"SPOD mode, {along}, {part} part (unit norm over the domain)"
            ds[f"phi_{comp}_{part}"] = (dims, val.astype(np.float32),
                                        {"units": "1", "long_name": name})  # fmt: skip
    ds["phase_speed"] = ("mode_f", prof["phase_speed"], {"units": vel,
                         "long_name": "the leading mode's phase speed downstream"})  # fmt: skip
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "blocks": prof["blocks"],
            "segment": prof["segment"],
            "degrees_of_freedom": prof["nu"],
            "vectors": prof["vectors"],
            "gaps": prof["gaps"],
            "pair_interval": prof["interval"],
            "description": "rspiv spectral POD (rspiv.spod) of the fluctuations about each "
            "vector's mean: Welch blocks with a Hann taper, half overlap; rejected vectors "
            "filled with the mean",
        }
    )
    return ds


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's SPOD, or None."""
    main = res.context.runs[0]
    prof = res.spod.get(main.name)
    if prof is None:
        return None
    unit = "Hz" if prof["per_s"] else "cycles per pair interval"
    text = (
        f"Spectral POD of {prof['pairs']} consecutive pairs over {prof['vectors']} vectors "
        f"({prof['blocks']} blocks of {prof['segment']} pairs, half overlapping; the "
        "fluctuations about each vector's mean; rows within 2.5 window heights of the wall "
        "left out). The leading mode holds "
        f"{100 * np.nanmax(prof['leading_fraction'][1:]):.0f} % of its frequency's energy at "
        f"most; its modes are kept at {', '.join(f'{f:.3g}' for f in prof['mode_f'])} {unit}. "
        "The band is the leading eigenvalue's 95 % interval; the measurement noise adds to "
        "every eigenvalue"
    )
    if np.isfinite(prof["noise_total"]):
        where = (
            "at no frequency" if np.isnan(prof["f_noise"]) else f"from {prof['f_noise']:.3g} {unit}"
        )
        text += (
            f" (the dotted line, from each vector's uncertainty, taken as white: the energy "
            f"summed over the modes reaches twice it {where})."
        )
    else:
        text += "."
    return pass_section(
        camp, prof, "Spectral proper orthogonal decomposition", text,
        "rspiv.plots.spod:plot_spod", "spod", f"{main.label}: SPOD spectrum and leading mode",
    )
