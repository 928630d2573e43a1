"""Analysing a campaign: the wall, the profiles, the boundary layer, the output files and the
report of every run.

Per run the wall is found from the mean field's mirror symmetry (:func:`find_run_wall`, with
:func:`rspiv.find_wall`), the statistics are averaged along x into profiles from the wall and
converted to SI units (``M`` from the calibration, ``dt`` and ``nu`` from ``[flow]``), the
boundary layer is analysed (:func:`rspiv.analyse_profile`), and the outputs are written
atomically: ``statistics_<run>.nc`` (pivpy names, CF units), ``profile_<run>.nc``,
``profile_<run>.csv``, ``summary.json`` and ``report/report.{md,html}``. A shard writes its raw
accumulators instead (:func:`write_shard`).

The output folder describes the last analysis only: a run's file that an earlier analysis
wrote and this one did not (its pass refused or failed, turned off, or ``[output] netcdf`` /
``csv`` off) is removed and named in the log and in ``summary.json`` (``removed``), so that a
refused pass never leaves an older result beside the new ones (:func:`remove_stale`).
"""

from __future__ import annotations

import json
import pathlib
from typing import Any

import numpy as np

from rspiv._rspiv import __version__
from rspiv.boundary_layer import analyse_profile, u_tau_jackknife
from rspiv.campaign import conditional as conditional_work
from rspiv.campaign import convergence as convergence_work
from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign import pair_quality
from rspiv.campaign import pod as pod_work
from rspiv.campaign import ptv as ptv_work
from rspiv.campaign import quadrant as quadrant_work
from rspiv.campaign import reference as reference_work
from rspiv.campaign import screen as screen_work
from rspiv.campaign import spod as spod_work
from rspiv.campaign import temporal as temporal_work
from rspiv.campaign import two_point as two_point_work
from rspiv.campaign import vortices as vortices_work
from rspiv.campaign import vorticity as vorticity_work
from rspiv.campaign.spec import STAGES, RunSpec
from rspiv.campaign.state import CampaignResult, RunAnalysis, RunLog, json_default
from rspiv.campaign_config import CampaignConfig
from rspiv.convergence import profile_rows
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outputs import (
    atomic_path,
    atomic_write_text,
    profile_dataset,
    statistics_dataset,
    write_netcdf,
    write_profile_csv,
)
from rspiv.profiles import (
    pair_error_columns,
    pair_error_summary,
    pair_errors,
    pair_errors_in_wall_units,
    profile_from_accumulator,
    scaled_accumulator,
)
from rspiv.reference_comparison import viscous_window
from rspiv.report import ReportSection, ReportTable, campaign_report
from rspiv.stats import FieldAccumulator
from rspiv.wall import check_level, find_wall

__all__ = [
    "analyse_result",
    "analyse_run",
    "calibration_table",
    "find_run_wall",
    "partial_correlation_note",
    "remove_stale",
    "run_statistics_dataset",
    "wall_dict",
    "wall_figure",
    "write_report",
    "write_shard",
]


def find_run_wall(acc: FieldAccumulator, gx, gy, stations: int, side: str, min_count: int):
    """Find the wall in an accumulator's mean u field; returns ``(Wall, flow_side)``.

    Vectors with fewer than ``min_count`` valid samples are left out; :func:`rspiv.find_wall`
    finds the band itself (centred on the row of smallest mean |u|, as wide as the field
    allows). ``flow_side`` is ``"above"`` (flow at smaller y: the wall near the bottom of the
    image) or ``"below"``: the wall finder's judgement for ``side="auto"``, else the configured
    side (``"bottom"``: the wall at the bottom, the flow above it). A wall tilted more than
    :data:`rspiv.wall.MAX_TILT_DEG` off the rows is refused (:func:`rspiv.wall.check_level`).
    """
    u = np.where(acc.count >= max(min(min_count, acc.n_fields), 1), acc.mean_u, np.nan)
    st = min(int(stations), u.shape[1])
    wall = check_level(find_wall(u, y=gy[:, 0], x=gx[0], stations=st))
    if side == "auto":
        flow_side = wall.flow_side
    else:
        flow_side = "above" if side == "bottom" else "below"
    return wall, flow_side


def analyse_run(
    run: RunSpec,
    acc: FieldAccumulator,
    gx,
    gy,
    cfg: CampaignConfig,
    mag,
    dt,
    window,
    y_wall_px: float | None = None,
) -> RunAnalysis:
    """Wall, profile (SI when ``mag`` and ``dt`` are known) and boundary-layer analysis of one
    run's accumulator. ``y_wall_px``: the wall's row (px, level), given rather than found
    (``cfg.wall.side`` then says where the flow is: not ``"auto"``)."""
    st = cfg.statistics
    xs, ys = gx[0], gy[:, 0]
    wall, side = None, "above"
    if y_wall_px is not None:
        side = "above" if cfg.wall.side != "top" else "below"
        y_wall = float(y_wall_px)
    elif cfg.wall.enabled:
        wall, side = find_run_wall(acc, gx, gy, cfg.wall.stations, cfg.wall.side, st.min_count)
        y_wall = float(wall.line(np.mean(xs)))
    else:
        side = "above" if cfg.wall.side != "top" else "below"
        y_wall = float(ys[-1] + 0.5 * (ys[1] - ys[0])) if side == "above" else float(ys[0])
    sign_y = -1.0 if side == "above" else 1.0  # physical y (into the flow) vs pixel y
    dist_px = sign_y * (ys - y_wall)
    mean_u = np.nanmean(np.where(acc.count > 0, acc.mean_u, np.nan))
    sign_x = -1.0 if mean_u < 0 else 1.0
    si = mag is not None and dt > 0
    m_per_px = 1e-3 / mag if mag is not None else None
    k = (m_per_px / dt) if si else 1.0
    prof_acc = scaled_accumulator(acc, k, sign_x, sign_y)
    prof = profile_from_accumulator(prof_acc, min_count=max(st.min_count, 2))
    profile: dict[str, Any] = {
        "si": si,
        "k": k,
        "sign_x": sign_x,
        "sign_y": sign_y,
        "y_wall_px": y_wall,
        "dist_px": dist_px,
        "U": prof["U"],
        "V": prof["V"],
        "uu": prof["uu"],
        "vv": prof["vv"],
        "uv": prof["uv"],
        "noise_uu": prof["noise_uu"],
        "noise_vv": prof["noise_vv"],
        "noise_corrected": bool(st.noise_correction),
        "count": prof["count"],
        "m_per_px": m_per_px,
        "x_coord": (xs - xs[0]) * m_per_px if m_per_px else xs,
        "y_coord": dist_px * m_per_px if m_per_px else dist_px,
    }
    if not si:
        return RunAnalysis(
            run,
            wall,
            side,
            profile,
            None,
            "no SI units: a calibration and [flow].dt > 0 are needed",
        )
    n_eff = prof["n_eff"] if st.use_n_eff else prof["count"]
    if isinstance(n_eff, dict):
        n_eff = {kk: vv for kk, vv in n_eff.items() if kk != "V"}
    ok = profile_rows(profile)  # the rows the profile holds (rspiv.convergence's too)
    if ok.sum() < 8:
        raise InvalidInputError(f"{run.label}: fewer than 8 profile points above the wall")
    y_m = dist_px[ok] * m_per_px
    sel = (lambda a: a[ok]) if not isinstance(n_eff, dict) else None
    ne = {kk: vv[ok] for kk, vv in n_eff.items()} if isinstance(n_eff, dict) else sel(n_eff)
    # Leave out of the composite fit the windows that reach the wall and its reflection.
    y_min_fit = (0.5 * window[1] + 1.0) * m_per_px
    # the measurement noise's variance out of the normal stresses (rspiv.boundary_layer)
    keys = ("noise_uu", "noise_vv", "eps_noise_uu", "eps_noise_vv")
    noise = tuple(prof[k][ok] for k in keys) if st.noise_correction else None
    extra = profile_extra(
        prof, ok, st.noise_correction, dist_px[ok] < NEAR_WALL_HEIGHTS * window[1]
    )
    if (pe := pair_errors(acc, k)) is not None:  # the rows' errors from pair to pair
        extra.update(pair_error_columns(pe, ok, noise))
    result = analyse_profile(
        y_m,
        prof["U"][ok],
        prof["uu"][ok],
        prof["vv"][ok],
        prof["uv"][ok],
        cfg.flow.nu,
        ne,
        u_e=cfg.flow.u_inf if cfg.flow.u_inf > 0 else None,
        fit_offset=st.fit_offset,
        y_min_fit=y_min_fit,
        noise=noise,
        extra=extra,
    )
    pair_errors_in_wall_units(result.extra, result.u_tau)
    if pe is not None and "replicates" in pe:  # u_tau's error from the pairs (jackknife)
        result.u_tau_std_pairs = u_tau_jackknife(
            y_m, pe["replicates"][:, ok] * sign_x, cfg.flow.nu, fit_offset=st.fit_offset,
            y_min_fit=y_min_fit, serial=float(np.nanmedian(pe["serial_U"][ok])),
        )  # fmt: skip
    return RunAnalysis(run, wall, side, profile, result)


#: Rows whose windows' centres lie within this many window heights of the wall get the
#: ``near_wall`` flag (:func:`profile_extra`).
NEAR_WALL_HEIGHTS = 2.5


def profile_extra(
    prof: dict, ok: np.ndarray, corrected: bool, near_wall: np.ndarray
) -> dict[str, np.ndarray]:
    """The profile's columns beyond the mean and the stresses, at the points ``ok``: the
    skewness and flatness ``S_u, F_u, eps_S_u, eps_F_u`` and ``_v`` (of
    :func:`profile_from_accumulator`), without the measurement noise when ``corrected`` (as the
    normal stresses are; the errors are the measured moments'), and the ``near_wall`` flag.

    ``near_wall`` (1.0 / 0.0) flags the rows whose windows' centres lie within
    :data:`NEAR_WALL_HEIGHTS` window heights of the wall. There the wall, its reflection and the
    mean gradient across the window shape the measured distribution, not the flow. On the
    synthetic layer (Gaussian fluctuations, viscous length 1.49 px, 32 x 8 px windows, window
    offset), against the pairs' exact field averaged over the window:

    - S(u) read 1.06, 0.46, 0.14 at 3.7, 7.7, 11.8 px from the wall where the exact field has
      0.04 (1.23 / 2.29 / 0.34 at 1.9 / 5.9 / 10 px against 0.10 in a second scene, F(u) 30.6
      at 5.9 px), much like the DNS's S(u) at the wall; at two window heights F(v) was still
      0.12 off. From 2.5 window heights on, S was within 0.021 and F within 0.038 (Methods I
      and II; the demo's claim).
    - uu read 156 %, 51 %, 15 %, 5 % high at 3.7, 7.7, 11.7, 15.7 px (97 %, 24 %, 7 % at 5.9,
      9.9, 13.9 px in the second scene), vv 294 %, 68 %, 24 %, 13 % high; from 2.5 window
      heights on uu and uv within 4 %, vv within 10 % (within 2.3 % from four heights).
    - With symmetric deformation the bias is about a third (uu +50 / +12 / +4.8 % at 3.6 / 7.6
      / 11.6 px, S(u) 1.23 / 0.13 / 0.04); the one threshold serves both modes.

    The report's stress and moment figures leave the flagged rows out; the mean velocity's
    composite fit has its own lower limit (the windows that reach the wall).
    """
    out = {"near_wall": np.asarray(near_wall, dtype=np.float64)}
    for comp in ("u", "v"):
        tag = "_c" if corrected else ""
        out[f"S_{comp}"] = prof[f"S_{comp}{tag}"][ok]
        out[f"F_{comp}"] = prof[f"F_{comp}{tag}"][ok]
        out[f"eps_S_{comp}"] = prof[f"eps_S_{comp}"][ok]
        out[f"eps_F_{comp}"] = prof[f"eps_F_{comp}"][ok]
    return out


def run_statistics_dataset(
    acc: FieldAccumulator, an: RunAnalysis, gx, gy, dt: float, attrs: dict[str, Any]
):
    """The per-vector statistics of a run's accumulator as written (``statistics_<run>.nc``):
    in SI units where the analysis had them (else px per pair), x along the wall and y the
    distance from it, the vectors behind the wall masked (:func:`mask_behind_wall`)."""
    si = an.profile.get("si", False)
    k = an.profile.get("k", 1.0)
    ds = statistics_dataset(
        scaled_accumulator(acc, k, an.profile.get("sign_x", 1.0), an.profile.get("sign_y", 1.0)),
        x=an.profile["x_coord"],
        y=an.profile["y_coord"],
        velocity_units="m s-1" if si else "pix",
        dt=dt if dt > 0 else None,
        attrs=attrs,
    )
    if an.wall is not None:
        ds = mask_behind_wall(ds, an.wall, an.flow_side, gx, gy)
    return ds


def behind_wall(wall, flow_side: str, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Grid points (window centres, px) on the far side of the found wall from the flow: the
    wall's reflection in the model surface, which is not flow (bool, shape of ``gx``)."""
    line = wall.line(gx)
    return gy > line if flow_side == "above" else gy < line


def mask_behind_wall(ds, wall, flow_side: str, gx: np.ndarray, gy: np.ndarray):
    """The statistics Dataset with every per-point float variable NaN behind the wall (the
    reflection region, :func:`behind_wall`) and the bool variable ``behind_wall`` saying where:
    the automatic mask of the region behind the wall, applied to the outputs."""
    behind = behind_wall(wall, flow_side, gx, gy)
    dims = ("y", "x")
    for name, var in ds.data_vars.items():
        if var.dims == dims and var.dtype.kind == "f" and var.shape == behind.shape:
            ds[name] = var.where(~behind)
    ds["behind_wall"] = (
        dims,
        behind,
        {"long_name": "behind the found wall (its reflection): masked, not flow"},
    )
    return ds


def wall_dict(wall) -> dict[str, Any]:
    return {
        "x_px": wall.x_px,
        "position_px": wall.position_px,
        "intercept_px": wall.intercept_px,
        "slope": wall.slope,
        "angle_deg": wall.angle_deg,
        "max_deviation_px": wall.max_deviation_px,
        "straightness_px": wall.straightness_px,
    }


def calibration_table(cal) -> dict[str, Any]:
    r = cal.report()
    mk = cal.markers
    d = np.hypot(*(mk.image_px - mk.object_px).T)
    rc = np.hypot(*(mk.object_px - mk.object_px[mk.centre]).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(rc > 0, d / rc, 0.0)
    out: dict[str, Any] = {
        "pitch (mm)": f"{r['pitch_mm']:.3f} +/- {r['pitch_sigma_mm']:.3f}",
        "magnification M (px/mm)": f"{r['magnification']:.3f} +/- {r['magnification_sigma']:.3f}",
    }
    for m, s in r["models"].items():
        out[f"max |residual| {m.upper()} (px)"] = tuple(round(v, 3) for v in s["max_abs_px"])
        out[f"RMS residual {m.upper()} (px)"] = tuple(round(v, 3) for v in s["rms_px"])
        out[f"held-out RMS {m.upper()} (px)"] = s["loo_rms_px"]
    out["marker sigma, image (px)"] = r["image_sigma_px"]
    out["marker sigma, object (px)"] = r["object_sigma_px"]
    out["max distortion (px)"] = float(d.max())
    out["max distortion (%)"] = float(100 * rel.max())
    out["markers"] = f"{r['n_markers']} of {r['n_detected']} detected"
    out["model"] = f"{r['model']} ({r['model_reason']})"
    return out


def wall_figure(path: pathlib.Path, res: CampaignResult, pilot: dict | None) -> pathlib.Path:
    """Wall position per station: pilot (before rotation) and each run, relative to its mean."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # deferred: matplotlib
    from matplotlib.figure import Figure  # deferred: matplotlib

    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    curves = []
    if pilot:
        curves.append(("before rotation (pilot)", pilot["x_px"], pilot["position_px"]))
    for a in res.analyses.values():
        if a.wall is not None:
            curves.append((a.run.label, a.wall.x_px, a.wall.position_px))
    for label, x, y in curves:
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        ax.plot(x, y - np.nanmean(y), "o-", ms=3, label=label)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("wall position - mean (px)")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path


def partial_correlation_note(res: CampaignResult) -> str:
    """One line on the pairs in the statistics whose frames correlate only in part
    (``res.warned``), for the run's outputs (the statistics files' ``warning`` attribute,
    ``summary.json``, the report, ``rspiv process``); empty when there are none."""
    if not res.warned:
        return ""
    ids = sorted(res.warned)
    shown = ", ".join(str(i) for i in ids[:8]) + (", ..." if len(ids) > 8 else "")
    return (
        f"{len(ids)} of the {res.n_done} pair(s) in the statistics correlate only in part "
        f"(pairs {shown}): a region unlit, outside the light sheet or too sparsely seeded gives "
        "random vectors that pass the median test, and theirs are in these statistics; mask "
        "the region or use larger windows (the pairs' warnings: run_log.jsonl, event "
        '"warning")'
    )


#: The stems of a run's analysis files, ``OUT/<stem>_<run>.nc`` and ``.csv``.
ANALYSIS_STEMS = (
    "statistics",
    "profile",
    "convergence",
    "profile_ensemble",
    "profile_pixel",
    "two_point",
    "quadrant",
    "pod",
    "vorticity",
    "vortices",
    "conditional",
    "temporal",
    "spod",
    "pairs",
)


def remove_stale(out: pathlib.Path, runs, written) -> list[str]:
    """Remove the analysis files of ``runs`` in ``out`` (``<stem>_<run>.nc`` / ``.csv`` of
    :data:`ANALYSIS_STEMS`) that are not among ``written`` (paths this analysis wrote): what
    an earlier analysis left. Returns the removed files' names. Files of runs this campaign
    does not have, and anything not named so, are left alone."""
    keep = {pathlib.Path(p).resolve() for p in written if isinstance(p, (str, pathlib.Path))}
    removed = []
    for run in runs:
        for stem in ANALYSIS_STEMS:
            for suffix in (".nc", ".csv"):
                path = out / f"{stem}_{run.name}{suffix}"
                if path.is_file() and path.resolve() not in keep:
                    path.unlink()
                    removed.append(path.name)
    return removed


def write_shard(camp: Any, res: CampaignResult) -> None:
    """Write the accumulators of a sharded run of ``camp``, one NetCDF file per run.

    Parameters
    ----------
    res : CampaignResult
        The result of this shard; the paths written are added to ``res.files``
        (``shard_<run>``: ``OUT/shards/statistics_<run>.shard-I-of-N.nc``).
    """
    i, n = camp.shard
    gx, gy = res.context.grid()
    for name, acc in res.accumulators.items():
        ds = acc.to_xarray(
            x=gx[0],
            y=gy[:, 0],
            velocity_units="pix",
            attrs={
                "run": name,
                "shard": f"{i}/{n}",
                "campaign": camp.config.name,
                "fingerprint": res.context.fingerprint(),
                "frame": "object px" if name != "uncorrected" else "image px",
            },
        )
        path = camp.out_dir / "shards" / f"statistics_{name}.shard-{i}-of-{n}.nc"
        res.files[f"shard_{name}"] = write_netcdf(ds, path)


def analyse_result(camp: Any, res: CampaignResult) -> None:
    """Analyse the accumulators of ``res`` and write the outputs of ``camp``.

    Finds the walls, fits the profiles, writes the NetCDF/CSV files, figures and report,
    and fills ``res.analyses`` and ``res.files`` in place.

    Parameters
    ----------
    res : CampaignResult
        A result whose ``accumulators`` hold every run of ``res.context``.
    """
    cfg = camp.config
    ctx = res.context
    out = camp.out_dir
    gx, gy = ctx.grid()
    cal = camp.calibration
    mag = cal.magnification if cal is not None else None  # px/mm
    dt = cfg.flow.dt
    model = cfg.calibration.model
    summary: dict[str, Any] = {
        "campaign": cfg.name,
        "runs": {},
        "pairs": res.n_pairs,
        "processed": res.n_done,
        "skipped": res.skipped,
    }
    note = partial_correlation_note(res)
    if note:
        summary["partly_correlated"] = res.warned
        summary["warning"] = note
        camp.say(f"warning: {note}")
    res.pair_quality = pair_quality.write_outputs(camp, res, RunLog(out / "run_log.jsonl"))
    camp.info.pop("screen_warnings", None)
    camp.info.pop(reference_work.INFO_KEY, None)
    camp.info.pop(convergence_work.INFO_KEY, None)
    summary.update(pair_quality.summary_entries(camp, res))
    for run in ctx.runs:
        acc = res.accumulators[run.name]
        try:
            an = analyse_run(run, acc, gx, gy, cfg, mag, dt, ctx.piv.final_window)
        except (RspivError, ValueError) as exc:
            camp.say(f"{run.label}: analysis failed: {exc}")
            res.analyses[run.name] = RunAnalysis(run, None, "", {}, None, str(exc))
            summary["runs"][run.name] = {"label": run.label, "error": str(exc)}
            continue
        res.analyses[run.name] = an
        if an.wall is not None:
            cond = {"none": "Distorted"}.get(
                run.method,
                f"Dewarped by {model}"
                + (" and rotated" if (cfg.wall.rotate and cal is not None) else ""),
            )
            if run.method != "none" and run.method != ctx.runs[0].method:
                cond += f" (Method {run.method})"
            res.wall_deviation[cond] = an.wall.max_deviation_px
        ds = run_statistics_dataset(
            acc,
            an,
            gx,
            gy,
            dt,
            {
                "run": run.name,
                "label": run.label,
                "method": run.method,
                "campaign": cfg.name,
                "n_pairs": int(acc.n_fields),
                "frame": "object" if run.method != "none" else "raw image",
                **({"warning": note} if note else {}),
            },
        )
        if cfg.output.netcdf:
            res.files[f"statistics_{run.name}"] = write_netcdf(
                ds, out / f"statistics_{run.name}.nc"
            )
        rs: dict[str, Any] = {
            "label": run.label,
            "method": run.method,
            "flow_side": an.flow_side,
        }
        if an.wall is not None:
            rs["wall"] = wall_dict(an.wall)
        screened = screen_work.run_summary(
            camp,
            run,
            acc,
            an.profile.get("dist_px") if an.wall is not None else None,
            NEAR_WALL_HEIGHTS * ctx.piv.final_window[1],
        )
        if screened is not None:  # what the screen left out (rspiv.outlier_screen)
            rs["screen"] = screened
            if "warning" in screened:
                camp.info.setdefault("screen_warnings", {})[run.name] = screened["warning"]
        if an.result is not None:
            rs.update(an.result.summary())
            if (ref := reference_work.run_entry(camp, an, ctx.piv.final_window)) is not None:
                rs["reference"] = ref
            if (pe := pair_error_summary(an.result)) is not None:
                rs["profile_errors"] = pe  # the conservative errors over the pairs' own
            if an.result.warning:
                rs["profile_warning"] = an.result.warning
                camp.say(f"warning: {run.label}: {an.result.warning}")
            if cfg.output.netcdf:
                res.files[f"profile_{run.name}_nc"] = write_netcdf(
                    profile_dataset(an.result, attrs={"run": run.name, "label": run.label}),
                    out / f"profile_{run.name}.nc",
                )
            if cfg.output.csv:
                res.files[f"profile_{run.name}_csv"] = write_profile_csv(
                    out / f"profile_{run.name}.csv",
                    an.result,
                    metadata={"run": run.name, "label": run.label},
                )
        elif an.error:
            rs["error"] = an.error
        near_px = NEAR_WALL_HEIGHTS * ctx.piv.final_window[1]
        if (conv := convergence_work.write_outputs(camp, res, run, an, near_px)) is not None:
            rs["convergence"] = conv  # the statistics over the first pairs (rspiv.convergence)
        bands = (
            ("ensemble", "ensemble", ensemble_work.write_outputs, res.ensembles),
            ("single_pixel", "single-pixel", ensemble_work.write_pixel_outputs, res.pixel_profiles),
            ("two_point", "two-point", two_point_work.write_outputs, res.two_point),
            ("quadrant", "quadrant", quadrant_work.write_outputs, res.quadrant),
            ("pod", "POD", pod_work.write_outputs, res.pod),
            ("vorticity", "vorticity", vorticity_work.write_outputs, res.vorticity),
            ("vortices", "vortex", vortices_work.write_outputs, res.vortices),
            ("conditional", "conditional", conditional_work.write_outputs, res.conditional),
            ("temporal", "temporal", temporal_work.write_outputs, res.temporal),
            ("spod", "SPOD", spod_work.write_outputs, res.spod),
        )
        for key, what, write, store in bands:
            try:
                prof = write(camp, res, run, an)
            except (RspivError, ValueError) as exc:
                camp.say(f"{run.label}: {what} profile failed: {exc}")
                rs[f"{key}_error"] = str(exc)
                continue
            if prof is not None:
                store[run.name] = prof
                rs[key] = {"pairs": prof["pairs"], "rows": int(prof["dist_px"].size)}
                if key == "two_point":
                    rs[key]["columns"] = list(prof["columns"])
                if prof.get("missing"):
                    rs[key]["missing_fields"] = len(prof["missing"])
                if "warning" in prof:
                    rs[key]["warning"] = prof["warning"]
                for flag in ("near_wall", "clipped"):
                    if flag in prof:
                        rs[key][f"{flag}_rows"] = int(np.count_nonzero(prof[flag]))
                if "weak_rows" in prof:
                    rs[key]["weak_rows"] = int(prof["weak_rows"])
        summary["runs"][run.name] = rs
    summary["wall_deviation_px"] = res.wall_deviation
    summary["timings_s"] = res.timings
    if camp.info.get("pilot"):
        summary["pilot"] = camp.info["pilot"]
    for key in (
        "davis_timing",
        "particle_diameter_px",
        "particle_size_warnings",
        "recording",
        "recording_drift",
        "recording_file",
        "recording_warnings",
        "screen",
    ):
        if key in camp.info:
            summary[key] = camp.info[key]
    if cfg.images.pairing_info() is not None:
        summary["pairing"] = cfg.images.pairing_info()
    if cfg.images.exclude_pairs:
        summary["excluded_pairs"] = sorted(cfg.images.exclude_pairs)
    if "rereduced" in camp.info:  # this run summed the checkpoint's pairs again from the fields
        summary["rereduced"] = camp.info["rereduced"]
    if cfg.output.fields:  # each pair's fields, written by the pair loop
        fields_dir = out / "fields"
        summary["fields"] = {
            "dir": str(fields_dir),
            "files": {r.name: len(list((fields_dir / r.name).glob("pair_*.nc"))) for r in ctx.runs},
        }
        res.files["fields"] = fields_dir
    removed = remove_stale(out, ctx.runs, res.files.values())
    if removed:
        summary["removed"] = removed
        camp.say(
            f"removed {len(removed)} file(s) an earlier analysis wrote and this one did not: "
            + ", ".join(removed)
        )
    res.files["summary"] = atomic_write_text(
        out / "summary.json", json.dumps(summary, indent=1, default=json_default)
    )
    ptv_work.configured_ptv(camp)  # [ptv]: the tracks at the wall, once the walls are written
    if cfg.output.report:
        write_report(camp, res)


def write_report(camp: Any, res: CampaignResult, extra_sections=()) -> None:
    """Write the campaign report of ``res`` (``OUT/report/report.{md,html}``), with
    ``extra_sections`` (:class:`rspiv.report.ReportSection`) appended."""
    ctx = res.context
    results = {a.run.label: a.result for a in res.analyses.values() if a.result is not None}
    repdir = camp.out_dir / "report"
    if not results:
        camp.say("no boundary-layer result to report (set [flow].dt and a calibration)")
        return
    wall_figs = []
    try:
        p = wall_figure(repdir / "figures" / "wall.png", res, camp.info.get("pilot_wall"))
        wall_figs.append((p, "Wall position per station (pilot before rotation, final runs)"))
    except Exception as exc:  # noqa: BLE001
        camp.say(f"wall figure failed: {exc}")
    main = ctx.runs[0]
    w, h = ctx.piv.final_window
    piv = {"samples N": res.n_done, "final window x (px)": w, "final window y (px)": h}
    if camp.config.images.pairing != "pairs":
        piv["image pairs"] = camp.config.images.describe_pairing()
    if "particle_diameter_px" in camp.info:
        piv["particle image diameter x, y (px)"] = tuple(camp.info["particle_diameter_px"])
    rec = camp.info.get("recording")
    if rec:  # the recording check of the first pair (rspiv.check_recording)
        bound = " or more" if rec["density_bound"] else ""
        piv["particle images per px (first pair)"] = f"{rec['density']:.4f}{bound}"
        piv["particle images per window (first pair)"] = ", ".join(
            f"{pw}x{ph} {rec['per_window'][f'{pw}x{ph}']:.1f}" for pw, ph in ctx.piv.passes
        )
        if rec["passes"]:
            piv["passes the recording check recommends"] = " -> ".join(
                f"{pw}x{ph}" for pw, ph in rec["passes"]
            )
    drift = camp.info.get("recording_drift")
    if drift:
        piv[f"particle images per px over the run ({len(drift['pairs'])} pairs)"] = (
            f"{min(drift['density']):.4f}-{max(drift['density']):.4f}"
        )
    r0 = res.analyses.get(main.name)
    if r0 is not None and r0.result is not None and camp.calibration is not None:
        m_per_px = 1e-3 / camp.calibration.magnification
        piv["final window x+"], piv["final window y+"] = viscous_window(r0.result, (w, h), m_per_px)
    if r0 is not None:
        # the measurement noise's share of the normal stresses (median over the profile)
        pr = r0.profile
        with np.errstate(invalid="ignore", divide="ignore"):
            share = [np.nanmedian(pr[f"noise_{c}"] / pr[c]) for c in ("uu", "vv")]
        if np.all(np.isfinite(share)):
            piv["measurement noise in uu, vv (%)"] = (100 * share[0], 100 * share[1])
            piv["stresses noise-corrected"] = "yes" if pr.get("noise_corrected") else "no"
    if r0 is not None and r0.result is not None and (pe := pair_error_summary(r0.result)):
        piv["the bound over the rows' scatter between pairs (U, uu)"] = (
            pe["overstated_U"], pe["overstated_uu"])  # fmt: skip
    extra = list(extra_sections)
    for sec in (
        reference_work.report_section(camp),
        convergence_work.report_section(camp),
        ptv_work.report_section(camp, ctx),
    ):
        extra += [sec] if sec is not None else []
    sec = pair_quality.report_section(camp, res, res.pair_quality)
    if sec is not None:
        extra.append(sec)
    text = screen_work.report_text(res)
    if text:
        extra.append(ReportSection("Vectors screened out of the statistics", text=text))
    if res.ensembles or res.pixel_profiles:
        sec = ensemble_work.report_section(camp, res)
        if sec is not None:
            extra.insert(0, sec)
    for store, work in (
        (res.two_point, two_point_work),
        (res.quadrant, quadrant_work),
        (res.pod, pod_work),
        (res.vorticity, vorticity_work),
        (res.vortices, vortices_work),
        (res.conditional, conditional_work),
        (res.temporal, temporal_work),
        (res.spod, spod_work),
    ):
        sec = work.report_section(camp, res) if store else None
        if sec is not None:
            extra.append(sec)
    if camp.info.get("particle_size_warnings"):
        said = "\n\n".join(f"Warning: {w}." for w in camp.info["particle_size_warnings"].values())
        extra.append(ReportSection("Particle images too small", text=said))
    if camp.info.get("recording_warnings"):
        said = "\n\n".join(f"Warning: {w}." for w in camp.info["recording_warnings"].values())
        extra.append(ReportSection("The recording (first pair)", text=said))
    no_free_stream = [
        f"{an.run.label}: {an.result.warning}."
        for an in res.analyses.values()
        if an.result is not None and an.result.warning
    ]
    if no_free_stream:
        extra.append(ReportSection("No free stream in the field", text="\n\n".join(no_free_stream)))
    note = partial_correlation_note(res)
    for title, text, column, pairs in (
        (
            "Skipped pairs",
            f"{len(res.skipped)} pair(s) were skipped and left out of the statistics.",
            "reason",
            res.skipped,
        ),
        ("Pairs whose frames correlate only in part", f"Warning: {note}.", "warning", res.warned),
    ):
        if pairs:
            rows = [{"pair": k, column: v} for k, v in sorted(pairs.items())]
            extra.append(ReportSection(title, text=text, tables=[ReportTable(title, rows)]))
    t = res.timings
    n = max(res.n_done - res.n_resumed, 1)
    extra.append(
        ReportSection(
            "Throughput",
            tables=[
                ReportTable(
                    "Time per stage (this run)",
                    {
                        k: {"total (s)": t.get(k, 0.0), "per pair (s)": t.get(k, 0.0) / n}
                        for k in (*STAGES, "prepare")
                    },
                )
            ],
        )
    )
    mc_figs = camp.info.get("figures_mc")
    paths = campaign_report(
        repdir,
        results,
        calibration=camp.info.get("calibration_table"),
        wall_deviation=res.wall_deviation,
        piv_parameters=piv,
        calibration_figures=camp.info.get("figures", {}).get("calibration"),
        monte_carlo_figures=mc_figs,
        wall_figures=wall_figs or None,
        extra_sections=extra,
        metadata={
            "campaign": camp.config.name,
            "rspiv": __version__,
            "pairs processed": res.n_done,
            "pairs skipped": len(res.skipped),
            "pairs correlating only in part": len(res.warned),
            "runs": ", ".join(r.label for r in ctx.runs),
        },
        title=f"rspiv campaign report: {camp.config.name}",
    )
    res.files["report_md"] = paths["markdown"]
    res.files["report_html"] = paths["html"]
