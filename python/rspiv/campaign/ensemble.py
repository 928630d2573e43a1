"""The campaign's ensemble correlation in a band at the wall (``[ensemble]``, issue 13).

Besides the instantaneous PIV, every pair's correlation planes are summed in thin windows
(:class:`rspiv.EnsembleAccumulator`) in a band that follows the wall, for every run: the raw
frames (no correction), the dewarped frames (Method I), or the raw frames at the mapped positions
of object-plane windows (Method II). The peaks are fitted once, after the last pair.

Plan (:func:`plan_bands`, in :func:`rspiv.campaign.prepare.prepare_context`)
    The pilot pairs are processed for every run (the instantaneous PIV); the wall is found in
    each run's pilot mean field, and the mean displacement averaged along the wall, continued
    to 0 at the wall (no slip, linear below the first row whose window clears the wall), is the
    *predictor*: every ensemble window is deformed by it pixel by pixel
    (:func:`rspiv.ensemble.profile_field`), so the summed peak holds the residual displacement
    and the fluctuations, not the mean gradient across the window. What the per-pair work needs
    (wall line, flow side, predictor profile, windows) is frozen into the context
    (``PairContext.ensemble``) and so into its fingerprint and the checkpoints.

Per pair (:func:`accumulate`, in :func:`rspiv.campaign.pair.process_pair`)
    Each run's accumulator rides on that run's :class:`rspiv.stats.FieldAccumulator`
    (``.ensemble``): merged with it (shards, Dask chunks), pickled with it (checkpoints),
    written with it (shard NetCDF files). The auto planes are summed over the first
    ``auto_pairs`` pairs.

Result (:func:`ensemble_profile`)
    The fitted windows averaged along the wall, row by row: the mean displacement, the
    Reynolds stresses from the peak's covariance less the particle images' own
    (:mod:`rspiv.ensemble`), at each row's distance from the wall that the final analysis found.
    Method II's windows sit at mapped positions in the raw frames: their displacements and
    covariances go to the object plane through the mapping's Jacobian (``J^-1 d``,
    ``J^-1 C J^-T``). Units: px per pair in the run's frame (object px for Methods I/II, image
    px without correction), pixel axes; :func:`ensemble_profile` converts like the run's own
    profile (SI, wall units) when the analysis has them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.campaign.ensemble_pixel import (
    SATURATED_MAX,
    Line,
    new_pixel_accumulator,
    pixel_layout,
    pixel_profile,
    pixel_spec,
    raw_pixels,
    saturation,
    to_object,
)
from rspiv.campaign.spec import PairContext, RunSpec
from rspiv.ensemble import EnsembleAccumulator, band_grid, profile_field
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf, write_profile_csv
from rspiv.report import ReportSection, ReportTable

#: Gap (px) between the found wall and the first row's windows: the pilot's wall is uncertain by
#: a few tenths of a px, and a window reaching past the true wall sums the reflections (moving
#: with the particles they mirror, slower than the window's flow) into its peak.
WALL_MARGIN_PX = 0.5
#: Fewest pairs whose summed rows are fitted: below it a row's peak is a few particle images'
#: correlations, not the displacement PDF (with 80 pairs of 64 x 4 px windows at 0.03 ppp the
#: stresses hold to 10 %), and the profile is refused rather than written.
MIN_PAIRS = 20

__all__ = [
    "MIN_PAIRS",
    "WALL_MARGIN_PX",
    "accumulate",
    "attach",
    "band_accumulators",
    "band_layout",
    "ensemble_profile",
    "new_accumulator",
    "plan_bands",
]


def _row_profile(acc, gx, gy, wall, flow_side: str, min_dist: float):
    """The pilot's mean field averaged along the wall: ``(dist, u, v)`` of the rows whose
    windows clear the wall (``dist >= min_dist``), px."""
    sign = 1.0 if flow_side == "above" else -1.0
    d = sign * (wall.line(gx) - gy)
    ok = acc.count > 0
    n = np.maximum(ok.sum(axis=1), 1)
    rows = ok.any(axis=1)
    dist = np.where(rows, np.where(ok, d, 0.0).sum(axis=1) / n, np.nan)
    u = np.where(rows, np.where(ok, acc.mean_u, 0.0).sum(axis=1) / n, np.nan)
    v = np.where(rows, np.where(ok, acc.mean_v, 0.0).sum(axis=1) / n, np.nan)
    keep = np.isfinite(dist) & np.isfinite(u) & np.isfinite(v) & (dist >= min_dist)
    return dist[keep], u[keep], v[keep]


def plan_bands(
    ctx: PairContext,
    pilot: dict[str, Any],
    walls: dict[str, tuple[Any, str]],
    cfg: Any,
    band_px: float,
    pixel_band_px: float | None = None,
) -> dict[str, Any]:
    """The ensemble band of every run, as plain data for ``PairContext.ensemble``; with
    ``pixel_band_px``, the single-pixel rows too (``spec["pixel"]``,
    :mod:`rspiv.campaign.ensemble_pixel`).

    Parameters
    ----------
    ctx : PairContext
        The frozen context (final mapping) without the ensemble.
    pilot : dict
        Run name -> the pilot's FieldAccumulator.
    walls : dict
        Run name -> ``(Wall, flow_side)`` found in the pilot (``Wall`` with ``line(x)``).
    cfg : CampaignConfig
        ``cfg.ensemble``: window, step, auto_pairs.
    band_px : float
        The band's height from the wall, px (``[ensemble] band`` converted by the caller).

    Raises
    ------
    InvalidInputError
        One line: a band outside the image, a window larger than the frame, a pilot without a
        profile.
    """
    ec = cfg.ensemble
    gx, gy = ctx.grid()
    h_piv = float(ctx.piv.final_window[1])
    out: dict[str, Any] = {}
    for run in ctx.runs:
        wall, side = walls[run.name]
        dist, u, v = _row_profile(pilot[run.name], gx, gy, wall, side, 0.5 * h_piv)
        if dist.size < 1:
            raise InvalidInputError(
                f"{run.label}: [ensemble]: the pilot's mean field has no row off the wall to "
                "predict the band from"
            )
        spec = {
            "window": [int(t) for t in ec.window],
            "step": [float(t) for t in ec.step],
            "band_px": float(band_px),
            "wall": [float(wall.intercept_px), float(wall.slope)],
            "flow_side": side,
            "dist": [float(t) for t in dist],
            "u": [float(t) for t in u],
            "v": [float(t) for t in v],
            "auto_pairs": int(ec.auto_pairs),
        }
        if pixel_band_px is not None:
            spec["pixel"] = pixel_spec(cfg, pixel_band_px)
        out[run.name] = spec
        # refuse a band that does not fit now, not at the first pair
        band_layout(ctx, run, spec)
        if pixel_band_px is not None:
            pixel_layout(ctx, run, spec)
    return out


def band_layout(ctx: PairContext, run: RunSpec, spec: dict[str, Any] | None = None) -> dict:
    """The windows and predictor of ``run``'s band (cached per process).

    Returns a dict: ``x, y`` (window centres in the frames the run correlates: object px for
    Method I, raw image px otherwise), ``X, Y`` (the same in the run's own frame: object px
    for Methods I/II), ``dist`` (each row's distance from the pilot's wall, px), ``axes`` (the
    1D column and row coordinates for the gradient correction), ``field`` (the predictor as a
    grid field in the correlated frames), ``window``, ``auto_pairs``.
    """
    key = f"ensemble_layout:{run.name}"
    if spec is None:
        if key in ctx._cache:
            return ctx._cache[key]
        if not ctx.ensemble or run.name not in ctx.ensemble:
            raise InvalidInputError(f"{run.label}: the context has no ensemble band")
        spec = ctx.ensemble[run.name]
    wall = Line(*spec["wall"])
    side = spec["flow_side"]
    window = (int(spec["window"][0]), int(spec["window"][1]))
    step = (float(spec["step"][0]), float(spec["step"][1]))
    frame_shape = tuple(ctx.object_shape if run.method != "none" else ctx.image_shape)
    where = f"{run.label}: [ensemble]"
    try:
        X, Y, dist = band_grid(
            frame_shape, window, step, spec["band_px"], wall, side, margin=WALL_MARGIN_PX
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc}") from None
    dx = max(float(step[0]), 8.0)
    field = profile_field(frame_shape, wall, side, spec["dist"], spec["u"], spec["v"], dx=dx)
    x, y = X, Y
    if run.method == "II":
        m = ctx.mapping
        pts = m.forward(np.column_stack([X.ravel(), Y.ravel()]))
        x, y = pts[:, 0].reshape(X.shape), pts[:, 1].reshape(X.shape)
        # the columns whose every window, mapped to the raw image, lies inside it
        h, w = ctx.image_shape
        mx, my = (window[0] - 1) / 2, (window[1] - 1) / 2
        inside = (x >= mx) & (x <= w - 1 - mx) & (y >= my) & (y <= h - 1 - my)
        cols = np.all(inside, axis=0)
        if not cols.any():
            raise InvalidInputError(
                f"{where}: the band's windows, mapped to the raw image, leave its {w} x {h} px"
            )
        X, Y, x, y = (np.ascontiguousarray(t[:, cols]) for t in (X, Y, x, y))
        field = _raw_field(ctx, field, (x, y), window)
    # each window's pixels on a 4 x 2 px lattice, for their saturation in the raw frames
    ox = np.arange(-(window[0] - 1) / 2, window[0] / 2, 4.0)
    oy = np.arange(-(window[1] - 1) / 2, window[1] / 2, 2.0)
    OX, OY = (t.ravel() for t in np.meshgrid(ox, oy))
    out = {
        "raw_pixels": raw_pixels(ctx, run, x.ravel()[:, None] + OX, y.ravel()[:, None] + OY),
        "x": x,
        "y": y,
        "X": X,
        "Y": Y,
        "dist": dist,
        "axes": (X[0, :], Y[:, 0]),
        "field": field,
        "window": window,
        "auto_pairs": int(spec["auto_pairs"]),
    }
    ctx._cache[key] = out
    return out


def _raw_field(ctx: PairContext, obj_field, raw_xy, window) -> tuple:
    """The object-plane predictor as a grid field over the raw image rows the band's windows
    reach: at raw point ``q``, ``F(X + D/2) - F(X - D/2)`` with ``X = F^-1(q)`` and ``D`` the
    object predictor at ``X`` (bilinear in the object grid field)."""
    from scipy.ndimage import map_coordinates

    m = ctx.mapping
    (gx0, gy0, gdx, gdy), fu, fv = obj_field
    x, y = raw_xy
    margin = 0.5 * window[1] + 8.0
    h, w = ctx.image_shape
    r0 = max(int(np.floor(np.min(y) - margin)), 0)
    r1 = min(int(np.ceil(np.max(y) + margin)), h - 1)
    dx = gdx
    nx = max(int(np.ceil((w - 1) / dx)) + 1, 2)
    qx = np.arange(nx) * dx
    qy = np.arange(r0, r1 + 1, dtype=np.float64)
    QX, QY = np.meshgrid(qx, qy)
    q = np.column_stack([QX.ravel(), QY.ravel()])
    X = m.inverse(q, on_fail="nan")
    c = np.vstack([(X[:, 1] - gy0) / gdy, (X[:, 0] - gx0) / gdx])
    du = map_coordinates(fu, c, order=1, mode="nearest")
    dv = map_coordinates(fv, c, order=1, mode="nearest")
    d = np.column_stack([du, dv])
    ok = np.all(np.isfinite(X), axis=1)
    d[~ok] = 0.0
    X[~ok] = q[~ok]
    raw = m.forward(X + 0.5 * d) - m.forward(X - 0.5 * d)
    raw[~ok] = 0.0
    u = raw[:, 0].reshape(QX.shape)
    v = raw[:, 1].reshape(QX.shape)
    return (0.0, float(r0), float(dx), 1.0), np.ascontiguousarray(u), np.ascontiguousarray(v)


def new_accumulator(ctx: PairContext, run: RunSpec) -> EnsembleAccumulator:
    """An empty accumulator of ``run``'s band."""
    lay = band_layout(ctx, run)
    return EnsembleAccumulator(
        lay["x"],
        lay["y"],
        lay["window"],
        interpolation=ctx.piv.interpolation,
        deform=lay["field"],
    )


def attach(ctx: PairContext, accs: dict[str, Any]) -> dict[str, Any]:
    """Give every run's FieldAccumulator in ``accs`` an empty ensemble accumulator when the
    context has a band and it has none; returns ``accs``."""
    if not ctx.ensemble:
        return accs
    for run in ctx.runs:
        a = accs.get(run.name)
        if a is None or a.n_fields != 0:
            continue
        if getattr(a, "ensemble", None) is None:
            a.ensemble = new_accumulator(ctx, run)
        if getattr(a, "pixel", None) is None and "pixel" in ctx.ensemble.get(run.name, {}):
            a.pixel = new_pixel_accumulator(ctx, run)
    return accs


def band_accumulators(accs: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """Run name -> ``(windows, single-pixel)`` accumulators of the runs' FieldAccumulators
    that carry either (what :func:`rspiv.campaign.pair.process_pair` adds each pair to)."""
    out = {}
    for name, a in accs.items():
        band = (getattr(a, "ensemble", None), getattr(a, "pixel", None))
        if band != (None, None):
            out[name] = band
    return out


def accumulate(
    ctx: PairContext, run: RunSpec, band: tuple[Any, Any], a, b, mask=None, raw=None
) -> int:
    """Add one pair's frames (those ``run`` correlates: dewarped for Method I) to the run's
    band accumulators ``(windows, single-pixel)`` (either may be None); the auto planes for the
    first ``auto_pairs`` pairs. ``raw``: ``(frame_a, frame_b, levels)``, the pair as recorded
    and its :func:`~rspiv.campaign.ensemble_pixel.saturation_level`, whose saturated pixels
    on the single-pixel rows are counted. Returns the windows and segments added."""
    windows, pixel = band
    n = 0
    for acc, layout in ((windows, band_layout), (pixel, pixel_layout)):
        if acc is not None:
            lay = layout(ctx, run)
            n += acc.add(a, b, mask=mask, auto=acc.pairs < lay["auto_pairs"])
            if raw is not None:
                acc.saturation.add(saturation(lay, raw))
    return n


def ensemble_profile(ctx: PairContext, run: RunSpec, acc: EnsembleAccumulator, an: Any) -> dict:
    """The band's profile: one peak per row of windows, fitted to the planes summed along the
    row (:meth:`rspiv.EnsembleAccumulator.result` with ``rows=True``: the boundary layer is
    homogeneous along the wall), at the row's distance from the wall (module docstring).

    Parameters
    ----------
    an : RunAnalysis
        The run's analysis: its wall (distances are measured from it; else the pilot's),
        ``profile`` (``k``, ``sign_x``, ``sign_y``, ``si``, ``m_per_px``) and ``result`` (wall
        units).

    Returns
    -------
    dict of ndarray
        ``dist_px``, ``U``, ``V``, ``uu``, ``vv``, ``uv`` (px per pair, pixel axes; a row whose
        windows reach behind the wall sits at the centroid of their part in the flow),
        ``windows`` (windows summed per row), ``pairs``; with SI units also ``y_m``,
        ``U_si`` ... (m, m/s, m^2/s^2, along the wall and into the flow); with a
        boundary-layer result also ``y_plus``, ``U_plus``, ``uu_plus``, ``vv_plus``,
        ``uv_plus``.
    """
    lay = band_layout(ctx, run)
    res = acc.result(axes=lay["axes"], rows=True)
    u, v, uu, vv, uv = (a[:, 0] for a in (res.u, res.v, res.uu, res.vv, res.uv))
    if run.method == "II":
        u, v, uu, vv, uv = to_object(ctx, lay, u, v, uu, vv, uv)
    counts = acc.window_counts
    X, Y = lay["X"], lay["Y"]
    if an is not None and an.wall is not None:
        sign = 1.0 if an.flow_side == "above" else -1.0
        d = sign * (an.wall.line(X) - Y)
    else:
        d = np.broadcast_to(lay["dist"][:, None], X.shape)
    # a window reaching behind the wall holds particles only on the flow's side: its value is
    # the mean over that part, at that part's centroid
    half = 0.5 * lay["window"][1]
    d = np.where(d - half < 0, 0.5 * np.maximum(d + half, 0.0), d)
    used = counts > 0
    n = used.sum(axis=1)
    dist = np.where(used, d, 0.0).sum(axis=1) / np.maximum(n, 1)
    keep = (n > 0) & res.ok[:, 0] & np.isfinite(u) & np.isfinite(v)
    sat = acc.saturation.mean().reshape(X.shape)
    sat = np.where(used, sat, 0.0).sum(axis=1) / np.maximum(n, 1)
    out: dict[str, Any] = {
        "dist_px": dist[keep],
        "U": u[keep],
        "V": v[keep],
        "uu": uu[keep],
        "vv": vv[keep],
        "uv": uv[keep],
        "windows": n[keep],
        "saturated": sat[keep],
        "clipped": sat[keep] > SATURATED_MAX,
        "pairs": int(acc.pairs),
    }
    return with_units(out, an)


def with_units(out: dict[str, Any], an: Any) -> dict[str, Any]:
    """Add to a band's profile (``dist_px``, ``U``, ``V``, ``uu``, ``vv``, ``uv`` in px per pair)
    the SI columns and the wall units of the run's analysis ``an``, converted as the run's own
    profile (its ``k``, axis signs, ``m_per_px``, the fit's ``u_tau``, ``nu``, ``y0``), when it
    has them; returns ``out``."""
    pr = getattr(an, "profile", None) or {}
    if pr.get("si"):
        k, sx, sy = pr["k"], pr["sign_x"], pr["sign_y"]
        m_per_px = float(pr["m_per_px"])
        out["y_m"] = out["dist_px"] * m_per_px
        out["U_si"] = out["U"] * k * sx
        out["V_si"] = out["V"] * k * sy
        out["uu_si"] = out["uu"] * k * k
        out["vv_si"] = out["vv"] * k * k
        out["uv_si"] = out["uv"] * k * k * sx * sy
        r = getattr(an, "result", None)
        if r is not None:
            ut = r.u_tau
            lv = r.nu / ut
            out["y_plus"] = (out["y_m"] - r.y0) / lv
            out["U_plus"] = out["U_si"] / ut
            out["uu_plus"] = out["uu_si"] / ut**2
            out["vv_plus"] = out["vv_si"] / ut**2
            out["uv_plus"] = out["uv_si"] / ut**2
    return out


def ensemble_dataset(prof: dict[str, Any], attrs: dict[str, Any] | None = None):
    """The ensemble profile as an :class:`xarray.Dataset` (dimension ``row``, CF units)."""
    import xarray as xr

    units = {
        "dist_px": ("wall distance of the row (from the found wall)", "pix"),
        "dist_row_px": (
            "wall distance of the single-pixel row itself (dist_px: where it measures)",
            "pix",
        ),
        "U": ("mean displacement along x", "pix"),
        "V": ("mean displacement along y", "pix"),
        "uu": ("displacement variance along x", "pix2"),
        "vv": ("displacement variance along y", "pix2"),
        "uv": ("displacement covariance (pixel axes)", "pix2"),
        "windows": ("windows fitted in the row", "1"),
        "segments": ("single-pixel segments summed in the row", "1"),
        "near_wall": (
            "1: the row lies within two particle-image widths of the wall (reported where it "
            "measures, dist_px)",
            "1",
        ),
        "saturated": ("mean fraction of the row's pixels saturated in the raw frames", "1"),
        "corrected": ("1: the single-pixel row's peak-fit bias was modelled and removed", "1"),
        "clipped": ("1: more of the row's pixels saturated than SATURATED_MAX", "1"),
        "y_m": ("wall distance", "m"),
        "U_si": ("mean streamwise velocity", "m s-1"),
        "V_si": ("mean wall-normal velocity (into the flow)", "m s-1"),
        "uu_si": ("streamwise Reynolds normal stress", "m2 s-2"),
        "vv_si": ("wall-normal Reynolds normal stress", "m2 s-2"),
        "uv_si": ("Reynolds shear stress", "m2 s-2"),
        "y_plus": ("wall distance in wall units (the run's fit)", "1"),
        "U_plus": ("U+", "1"),
        "uu_plus": ("uu+", "1"),
        "vv_plus": ("vv+", "1"),
        "uv_plus": ("uv+", "1"),
    }
    ds = xr.Dataset()
    for k, (name, unit) in units.items():
        if k in prof:
            val = np.asarray(prof[k])
            val = val.astype(np.int8) if val.dtype == bool else val  # flags as 0/1
            ds[k] = (("row",), val, {"long_name": name, "units": unit})
    ds.attrs.update(
        {
            "title": "rspiv ensemble-correlation profile",
            "Conventions": "CF-1.8",
            "pairs": int(prof["pairs"]),
        }
    )
    if attrs:
        ds.attrs.update(attrs)
    return ds


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The ensemble profile of ``run`` (:func:`ensemble_profile`) written as
    ``OUT/profile_ensemble_<run>.csv`` and ``.nc`` (as ``[output]`` says); the profile, or None
    when the run has no ensemble."""
    acc = res.accumulators[run.name].ensemble
    if acc is None or not res.context.ensemble:
        return None
    _enough_pairs(acc, "the ensemble band", "ensemble")
    prof = ensemble_profile(res.context, run, acc, an)
    spec = res.context.ensemble[run.name]
    meta = {
        "run": run.name,
        "label": run.label,
        "pairs": prof["pairs"],
        "window_px": "x".join(str(t) for t in spec["window"]),
        "band_px": spec["band_px"],
        **_flags(camp, run, prof, "ensemble rows"),
    }
    _write(camp, res, run, prof, meta, "ensemble", "rspiv ensemble-correlation profile")
    return prof


def write_pixel_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The single-pixel profile of ``run`` (:func:`rspiv.campaign.ensemble_pixel.pixel_profile`
    with units) written as ``OUT/profile_pixel_<run>.csv`` and ``.nc``; the profile, or None
    when the run has no single-pixel rows. The rows the wall biases are said and flagged."""
    acc = getattr(res.accumulators[run.name], "pixel", None)
    if acc is None or not res.context.ensemble:
        return None
    _enough_pairs(acc, "the single-pixel rows", "single-pixel")
    prof = with_units(pixel_profile(res.context, run, acc, an), an)
    spec = res.context.ensemble[run.name]["pixel"]
    meta = {
        "run": run.name,
        "label": run.label,
        "pairs": prof["pairs"],
        "segment_px": spec["segment"],
        "row_step_px": spec["step"],
        "band_px": spec["band_px"],
        "row_bend_px": round(pixel_layout(res.context, run)["bend_px"], 4),
        **_flags(camp, run, prof, "single-pixel rows"),
    }
    _write(camp, res, run, prof, meta, "pixel", "rspiv single-pixel ensemble profile")
    return prof


def _flags(camp: Any, run: RunSpec, prof: dict, what: str) -> dict[str, Any]:
    """The profile's flagged rows for its metadata (``near_wall_rows``, ``clipped_rows``,
    ``warning``), said when there are any."""
    near = int(np.count_nonzero(prof.get("near_wall", ())))
    clipped = int(np.count_nonzero(prof["clipped"]))
    said = []
    if near:
        said.append(
            f"{near} row(s) lie within two particle-image widths of the wall: they measure "
            "farther out than they lie and are reported there, modelled on the pixel grid at "
            "the found wall (with a wall found 0.24 px off, the row measuring at y+ 0.4 read "
            "9 % high) (near_wall = 1)"
        )
    if clipped:
        said.append(
            f"{clipped} row(s) have more than {100 * SATURATED_MAX:g} % of their pixels "
            "saturated in the raw frames (glare?) and read wrong (clipped = 1)"
        )
    if prof.get("weak_rows"):
        said.append(
            f"{prof['weak_rows']} row(s) left out: their summed peak does not stand out of the "
            "correlation noise (too few pairs, or no particles there)"
        )
    if "corrected" in prof and not np.all(prof["corrected"]):
        said.append(
            f"{int(np.count_nonzero(~np.asarray(prof['corrected'], dtype=bool)))} row(s) keep "
            "the peak fit's bias (1-3.5 % low on the synthetic layer): no row three image widths "
            "out to model it from, or its model failed (corrected = 0)"
        )
    out: dict[str, Any] = {"clipped_rows": clipped, "warning": "; ".join(said)}
    if "near_wall" in prof:
        out["near_wall_rows"] = near
    if "weak_rows" in prof:
        out["weak_rows"] = int(prof["weak_rows"])
    if said:
        camp.say(f"{run.label}: {what}: {out['warning']}")
    return out


def _enough_pairs(acc: Any, what: str, name: str) -> None:
    if acc.pairs < MIN_PAIRS:
        raise InvalidInputError(
            f"{what} summed {acc.pairs} pair(s); its peaks need at least {MIN_PAIRS}, no "
            f"{name} profile written"
        )


def _write(camp, res, run, prof: dict, meta: dict, kind: str, title: str) -> None:
    """``OUT/profile_<kind>_<run>.csv`` and ``.nc`` of a band's profile, as ``[output]``
    says (flags as 0/1)."""
    if np.size(prof["dist_px"]) == 0:
        raise InvalidInputError(f"no row of the {kind} band gave a peak, nothing written")
    flags = ("near_wall", "clipped", "corrected")
    cols = {k: (np.asarray(v).astype(int) if k in flags else v) for k, v in prof.items()}
    cols.pop("pairs")
    cols.pop("weak_rows", None)
    out = camp.out_dir / f"profile_{kind}_{run.name}"
    cfg = camp.config
    if cfg.output.csv:
        res.files[f"profile_{kind}_{run.name}_csv"] = write_profile_csv(
            out.with_suffix(".csv"), cols, metadata=meta
        )
    if cfg.output.netcdf:
        ds = ensemble_dataset(prof, attrs={k: str(v) for k, v in meta.items()})
        ds.attrs["title"] = title
        res.files[f"profile_{kind}_{run.name}_nc"] = write_netcdf(ds, out.with_suffix(".nc"))


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the ensemble: U+ and the stresses of every run's instantaneous
    and ensemble profiles against the DNS, and the first rows of the main run's profile."""
    runs: dict[str, Any] = {}
    pixel_rows: list[dict[str, Any]] = []
    for run in res.context.runs:
        an = res.analyses.get(run.name)
        prof = res.ensembles.get(run.name)
        if an is None or an.result is None or prof is None or "y_plus" not in prof:
            continue
        if not runs:
            runs[f"{run.label} (instantaneous)"] = an.result
            first = prof
        runs[f"{run.label} (ensemble)"] = _series(prof, an.result.re_tau, ~prof["clipped"])
        pix = getattr(res, "pixel_profiles", {}).get(run.name)
        if pix is not None and "y_plus" in pix:
            bad = np.asarray(pix["near_wall"], dtype=bool) | np.asarray(pix["clipped"], bool)
            if not pixel_rows:
                pixel_rows = _table(pix, "segments", flagged=bad)
            if not bad.all():
                runs[f"{run.label} (single-pixel)"] = _series(pix, an.result.re_tau, ~bad)
    if not runs:
        return None
    figures = []
    try:
        from rspiv.plots.boundary_layer import plot_boundary_layer  # deferred: matplotlib

        paths = plot_boundary_layer(
            camp.out_dir / "report" / "figures", runs, prefix="ensemble_", dns=None, moments=False
        )
        figures = [
            (paths["mean_velocity"], "Mean velocity: instantaneous and ensemble, against DNS"),
            (paths["reynolds_stresses"], "Reynolds stresses: instantaneous and ensemble"),
        ]
    except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
        camp.say(f"ensemble figures failed: {exc}")
    rows = _table(first, "windows", flagged=first["clipped"])
    info = camp.info.get("ensemble", {})
    text = (
        "Correlation planes summed over every pair in thin windows "
        f"({info.get('window', ['?', '?'])[0]} x {info.get('window', ['?', '?'])[1]} px) in a "
        f"band of {info.get('band_px', float('nan')):.1f} px at the wall, each window deformed "
        "by the pilot's mean profile (no slip at the wall); the Reynolds stresses from the "
        "summed peak's covariance less the particle images' own. Rows with more than "
        f"{100 * SATURATED_MAX:g} % of their pixels saturated in the recorded frames (clipped "
        "particle images, e.g. a glare line) are flagged and left out of the figures."
    )
    tables = [ReportTable("Ensemble profile near the wall (main run)", rows)]
    if pixel_rows:
        text += (
            " Single-pixel rows: one pixel row of frame A against the rows of frame B, summed "
            "along the wall, the reflection beyond the wall masked, each row reported at the "
            "distance where it measures (next to the wall, farther out than it lies: the mean "
            "offset of the particle images it sees) and the peak fit's bias removed (next to the "
            "wall modelled on the pixel grid); the rows within two particle-image widths of the "
            "wall, moved the most, are flagged and left out of the figures."
        )
        tables.append(ReportTable("Single-pixel profile at the wall (main run)", pixel_rows))
    return ReportSection(
        "Ensemble correlation near the wall", text=text, figures=figures, tables=tables
    )


def _series(prof: dict[str, Any], re_tau: float, keep: Any = None) -> dict[str, Any]:
    """A band profile as a series of :func:`rspiv.plots.boundary_layer.plot_boundary_layer`."""
    sel = slice(None) if keep is None else keep
    out = {name: prof[k][sel] for name, k in _PLUS.items()}
    return {**out, "re_tau": re_tau}


#: plot series name -> band profile column
_PLUS = {k.lower(): k for k in ("y_plus", "U_plus", "uu_plus", "vv_plus", "uv_plus")}


def _table(prof: dict[str, Any], count: str, flagged: Any = None) -> list[dict[str, Any]]:
    """The first 12 rows of a band profile for the report."""
    rows = []
    for i in range(min(12, prof["y_plus"].size)):
        row = {
            "y+": float(prof["y_plus"][i]),
            "U+": float(prof["U_plus"][i]),
            "uu+": float(prof["uu_plus"][i]),
            "vv+": float(prof["vv_plus"][i]),
            "-uv+": float(-prof["uv_plus"][i]),
            count: int(prof[count][i]),
        }
        if flagged is not None:
            row["flagged"] = "yes" if flagged[i] else "no"
        rows.append(row)
    return rows
