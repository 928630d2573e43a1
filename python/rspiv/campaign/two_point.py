"""A campaign's streamwise spectra and two-point correlations (``[statistics] two_point``).

Every run's :class:`~rspiv.stats.FieldAccumulator` carries a
:class:`~rspiv.two_point.TwoPointAccumulator` (:func:`attach`) that each pair's field is added
to beside the statistics (:func:`rspiv.campaign.reduce.add_fields`); checkpoints, shards and
Dask carry it with the accumulator. The columns that enter are fixed before the first pair
(:func:`plan`): those whose final windows, widened by half a window on each side for the
displacement (up to a window width), lie inside the recorded frames at every row (a corrected
run's windows mapped to the raw frame), so the vectors the campaign rejects at the sensor's
edges never enter.

At the end (:func:`write_outputs`) the rows on the flow side become ``two_point_<run>.nc``: per
row (``y`` from the wall, ``y_plus``) the one-sided spectra ``phi_uu, phi_vv, phi_uv`` against
``k_x`` (rad/m) with ``lambda_x`` and ``lambda_plus``, the premultiplied ``kphi_uu_plus``
(``k_x phi_uu / u_tau^2``), the correlation coefficients ``R_uu, R_vv, R_uv`` against the lag
``dx`` (m, ``dx_plus``), the integral lengths ``L_uu, L_vv`` (m), the fields per row and the
``near_wall`` flag (:data:`rspiv.campaign.analysis.NEAR_WALL_HEIGHTS`). SI units when the run's
profile has them (a calibration and ``[flow] dt``), else px and px per pair.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.campaign.pair import _window_positions
from rspiv.campaign.spec import PairContext, RunSpec
from rspiv.errors import InvalidInputError
from rspiv.outputs import write_netcdf
from rspiv.report import ReportSection
from rspiv.two_point import TwoPointAccumulator, integral_length

__all__ = [
    "attach",
    "map_rows",
    "plan",
    "report_section",
    "two_point_dataset",
    "two_point_profile",
    "write_outputs",
    "FILTER_WIDTHS",
]

#: Wavelengths shorter than this many final-window widths lose more than 20 % of their energy
#: to the window's average along x (the top hat's transfer ``sinc^2(pi w / lambda)`` is 0.81
#: at ``lambda = 4 w``); they are marked in the figure and the file (``filtered``).
FILTER_WIDTHS = 4.0


def plan(
    ctx: PairContext,
    min_valid: float,
    walls: dict[str, tuple[Any, str]] | None = None,
    heights_px=(),
) -> dict[str, Any]:
    """The context's ``two_point``: ``min_valid``, the columns ``[c0, c1)`` of every run
    (module docstring) and, with ``walls`` and ``heights_px``, every run's maps: their
    reference rows (the rows nearest to each height from the run's wall) and their band (the
    rows from :data:`~rspiv.campaign.analysis.NEAR_WALL_HEIGHTS` window heights off the wall
    to twice the highest reference, within the grid).

    Parameters
    ----------
    walls : dict, optional
        Run name -> ``(Wall, flow_side)`` of a pilot.
    heights_px : sequence of float
        Reference heights from the wall, px, increasing.

    Raises
    ------
    InvalidInputError
        No 8 columns of a run lie inside the frames, or a height lies beyond the grid or
        within the rows the wall shapes.
    """
    cols: dict[str, list[int]] = {}
    for run in ctx.runs:
        idx = np.flatnonzero(np.all(_inside_frames(ctx, run, axis=0), axis=0))
        if idx.size < 8 or idx[-1] - idx[0] + 1 != idx.size:
            raise InvalidInputError(
                f"[statistics] two_point: {run.label}: only {idx.size} columns of final windows "
                "lie inside the frames with half a window's margin on each side (8 are needed)"
            )
        cols[run.name] = [int(idx[0]), int(idx[-1]) + 1]
    out: dict[str, Any] = {"columns": cols, "min_valid": float(min_valid)}
    if not walls or not len(heights_px):
        return out
    gx, gy = ctx.grid()
    maps = {}
    for run in ctx.runs:
        wall, side = walls[run.name]
        y_wall = float(wall.line(np.mean(gx[0])))
        dist = (y_wall - gy[:, 0]) * (1.0 if side == "above" else -1.0)
        try:
            band, refs = map_rows(dist, heights_px, ctx.piv.final_window[1])
        except InvalidInputError as exc:
            raise InvalidInputError(
                f"[statistics] two_point_heights: {run.label}: {exc}"
            ) from None
        maps[run.name] = {
            "band": list(band),
            "refs": list(refs),
            "heights_px": [float(y) for y in heights_px],
        }
    out["maps"] = maps
    return out


def map_rows(dist, heights_px, window_height: float) -> tuple[tuple[int, int], tuple[int, ...]]:
    """The two-point maps' rows of a grid whose rows lie ``dist`` px from the wall (monotonic):
    the band ``(r0, r1)`` of the rows from :data:`~rspiv.campaign.analysis.NEAR_WALL_HEIGHTS`
    window heights off the wall to twice the highest reference, and the reference rows, the
    rows nearest to ``heights_px``.

    Raises
    ------
    InvalidInputError
        A height within the rows the wall shapes, beyond the last row, or more than a row's
        spacing from the nearest row.
    """
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    dist = np.asarray(dist, np.float64)
    lo, hi = NEAR_WALL_HEIGHTS * window_height, 2.0 * max(heights_px)
    band = np.flatnonzero((dist >= lo) & (dist <= hi))
    spacing = float(np.min(np.abs(np.diff(dist))))
    refs = []
    for y in heights_px:
        i = int(np.argmin(np.abs(dist - y)))
        if not (lo <= y <= dist.max()) or abs(dist[i] - y) > spacing:
            raise InvalidInputError(
                f"{y:.1f} px from the wall lies outside the rows from {lo:g} px "
                f"({NEAR_WALL_HEIGHTS:g} window heights) to {dist.max():.1f} px (the field's edge)"
            )
        refs.append(i)
    return (int(band.min()), int(band.max()) + 1), tuple(refs)


def reference_heights_px(an: Any, heights, units: str, key: str) -> list[float]:
    """Reference heights in px from the wall of the run analysed in ``an``: ``heights`` as
    given with ``units = "px"``, else fractions of the run's own delta_99 (``"delta"``), which
    needs its boundary-layer fit. ``key``: the campaign file's key, for the refusal.

    Raises
    ------
    InvalidInputError
        Heights in delta_99 without the run's boundary-layer fit.
    """
    if units == "px":
        return [float(h) for h in heights]
    p, bl = an.profile, an.result
    if bl is None or not p.get("si") or not np.isfinite(bl.delta99):
        raise InvalidInputError(
            f"{key} in delta_99 need the run's boundary-layer fit (a calibration and [flow] "
            f'dt); give them in px ({key.replace("heights", "height_units")} = "px")'
        )
    return [float(h) * bl.delta99 / p["m_per_px"] for h in heights]


def reference_rows(
    an: Any, heights, units: str, key: str, window_height: float
) -> tuple[tuple[int, int], np.ndarray, list[float]]:
    """The band and the reference rows (:func:`map_rows`) of the heights ``heights`` in
    ``units`` of the run analysed in ``an``, and the heights in px
    (:func:`reference_heights_px`).

    Raises
    ------
    InvalidInputError
        ``[statistics] <key>: ...``: heights in delta_99 without the run's boundary-layer fit,
        or a height the rows cannot hold.
    """
    px = reference_heights_px(an, heights, units, key)
    try:
        band, refs = map_rows(np.asarray(an.profile["dist_px"], np.float64), px, window_height)
    except InvalidInputError as exc:
        raise InvalidInputError(f"[statistics] {key}: {exc}") from None
    return band, np.asarray(refs, np.int64), px


def _inside_frames(ctx: PairContext, run: RunSpec, axis: int) -> np.ndarray:
    """Per grid point: do the run's final windows, widened by half a window on each side for
    the displacement (up to a window width), lie inside the recorded frames along ``axis``
    (0: x, 1: y)? A corrected run's windows are mapped to the raw frame."""
    pos = _window_positions(ctx, run.method != "none")[..., axis]
    size = ctx.piv.final_window[axis]
    extent = ctx.image_shape[1 - axis]
    return (pos - size >= -0.5) & (pos + size <= extent - 0.5)


def attach(ctx: PairContext, accs: dict[str, Any]) -> dict[str, Any]:
    """Give every run's empty FieldAccumulator in ``accs`` a TwoPointAccumulator when the
    context asks for one; returns ``accs``."""
    spec = ctx.two_point
    if not spec:
        return accs
    for run in ctx.runs:
        a = accs.get(run.name)
        if a is None or a.n_fields != 0 or getattr(a, "two_point", None) is not None:
            continue
        m = spec.get("maps", {}).get(run.name)
        a.two_point = TwoPointAccumulator(
            a.shape,
            tuple(spec["columns"][run.name]),
            spec["min_valid"],
            None if m is None else tuple(m["band"]),
            () if m is None else tuple(m["refs"]),
        )
    return accs


def two_point_profile(
    tp: TwoPointAccumulator, an: Any, window: tuple[int, int], dx_px: float
) -> dict[str, Any]:
    """The spectra and correlations of the rows on the flow side, nearest the wall first, in
    the run's units (module docstring's variables): ``an`` the run's analysis, ``window``
    the final window ``(w, h)`` px, ``dx_px`` the grid's step along a row, px."""
    from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

    p = an.profile
    si = bool(p.get("si"))
    m = p["m_per_px"] if p.get("m_per_px") else None
    k = float(p.get("k", 1.0))
    sx, sy = float(p.get("sign_x", 1.0)), float(p.get("sign_y", 1.0))
    dist = np.asarray(p["dist_px"], np.float64)
    keep = np.flatnonzero(dist > 0)
    if not np.any(tp.count[keep] >= 2):
        raise InvalidInputError("no row on the flow side holds two fields")
    keep = keep[np.argsort(dist[keep])]
    dx = dx_px * (m if si else 1.0)
    sp = tp.spectra(dx=dx)
    cr = tp.correlation()
    lag = cr["lag"] * dx
    flip = (lambda a: a[:, ::-1]) if sx < 0 else (lambda a: a)  # lags along the flow
    out = {
        "y": dist[keep] * (m if si else 1.0),
        "dist_px": dist[keep],
        "rows": keep,
        "count": tp.count[keep],
        "near_wall": dist[keep] < NEAR_WALL_HEIGHTS * window[1],
        "k_x": sp["k"],
        "dx": lag,
        "phi_uu": sp["phi_uu"][keep] * k * k,
        "phi_vv": sp["phi_vv"][keep] * k * k,
        "phi_uv": sp["phi_uv"][keep] * k * k * sx * sy,
        "R_uu": flip(cr["R_uu"][keep]),
        "R_vv": flip(cr["R_vv"][keep]),
        "R_uv": flip(cr["R_uv"][keep]) * sx * sy,
        "si": si,
        "window_px": tuple(window),
        "columns": tp.columns,
        "pairs": int(tp.n_fields),
    }
    if tp.band is not None:
        mp = tp.maps()
        order = np.argsort(dist[mp["rows"]])  # the map's rows from the wall out
        out["map_dist_px"], out["ref_dist_px"] = dist[mp["rows"]][order], dist[mp["refs"]]
        out["map_y"] = out["map_dist_px"] * (m if si else 1.0)
        out["y_ref"] = out["ref_dist_px"] * (m if si else 1.0)
        for q in ("uu", "vv"):
            r = mp[f"R_{q}"][:, order]
            out[f"R_{q}_map"] = r[..., ::-1] if sx < 0 else r
        out["map_pairs"] = int(mp["count"])
    out["L_uu"] = integral_length(lag, out["R_uu"])
    out["L_vv"] = integral_length(lag, out["R_vv"])
    with np.errstate(divide="ignore"):
        out["lambda_x"] = np.where(sp["k"] > 0, 2.0 * np.pi / sp["k"], np.inf)
    out["filtered"] = out["lambda_x"] < FILTER_WIDTHS * window[0] * (m if si else 1.0)
    res = an.result
    if res is not None and si:
        lv = res.nu / res.u_tau
        out["y_plus"] = out["y"] / lv
        out["dx_plus"] = lag / lv
        out["lambda_plus"] = out["lambda_x"] / lv
        out["kphi_uu_plus"] = sp["k"] * out["phi_uu"] / res.u_tau**2
        out["kphi_vv_plus"] = sp["k"] * out["phi_vv"] / res.u_tau**2
        out["delta_99"] = float(res.delta99)
    return out


def two_point_dataset(prof: dict, run: RunSpec) -> Any:
    """The rows ``prof`` (:func:`two_point_profile`) of ``run`` as a dataset
    (``two_point_<run>.nc``: the module docstring's variables)."""
    import xarray as xr

    si = prof["si"]
    length = "m" if si else "pix"
    vel2 = "m2 s-2" if si else "pix2"
    ds = xr.Dataset(
        coords={
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "k_x": ("k_x", prof["k_x"], {"units": f"rad {length}-1", "long_name": "wavenumber"}),
            "dx": ("dx", prof["dx"], {"units": length, "long_name": "streamwise lag"}),
        }
    )
    ds["lambda_x"] = ("k_x", prof["lambda_x"], {"units": length, "long_name": "wavelength"})
    ds["filtered"] = ("k_x", prof["filtered"], {"long_name": "attenuated by the window average"})
    for q in ("uu", "vv", "uv"):
        long = "co-spectrum" if q == "uv" else "spectrum"
        ds[f"phi_{q}"] = (("y", "k_x"), prof[f"phi_{q}"], {"units": f"{vel2} {length}",
                                                          "long_name": f"one-sided {long} {q}"})
        ds[f"R_{q}"] = (("y", "dx"), prof[f"R_{q}"],
                        {"units": "1", "long_name": f"two-point correlation coefficient {q}"})
    for q in ("uu", "vv"):
        ds[f"L_{q}"] = ("y", prof[f"L_{q}"], {"units": length, "long_name": f"integral length {q}"})
    ds["count"] = ("y", prof["count"], {"long_name": "fields per row"})
    if "map_y" in prof:
        ds = ds.assign_coords(
            y_ref=("ref", prof["y_ref"], {"units": length, "long_name": "reference row"}),
            y_map=("y_map", prof["map_y"], {"units": length, "long_name": "distance from wall"}),
        )
        for q in ("uu", "vv"):
            ds[f"R_{q}_map"] = (("ref", "y_map", "dx"), prof[f"R_{q}_map"], {
                "units": "1",
                "long_name": f"two-point correlation coefficient {q} about the reference row",
            })  # fmt: skip
        ds.attrs["map_pairs"] = prof["map_pairs"]
    ds["near_wall"] = ("y", prof["near_wall"], {"long_name": "row shaped by the wall"})
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        ds["dx_plus"] = ("dx", prof["dx_plus"], {"units": "1"})
        ds["lambda_plus"] = ("k_x", prof["lambda_plus"], {"units": "1"})
        for q in ("uu", "vv"):
            ds[f"kphi_{q}_plus"] = (("y", "k_x"), prof[f"kphi_{q}_plus"],
                                   {"units": "1", "long_name": f"k_x phi_{q} / u_tau^2"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "columns": list(prof["columns"]),
            "window_px": list(prof["window_px"]),
            "description": "rspiv streamwise spectra and two-point correlations (rspiv.two_point)",
        }
    )
    return ds


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The spectra and correlations of ``run`` (module docstring) written as
    ``OUT/two_point_<run>.nc`` (with ``[output] netcdf``); None when the run has none."""
    tp = getattr(res.accumulators[run.name], "two_point", None)
    if tp is None or not res.context.two_point:
        return None
    gx, _ = res.context.grid()
    prof = two_point_profile(tp, an, res.context.piv.final_window, float(gx[0, 1] - gx[0, 0]))
    # rows whose windows reach past the frames (the field's edge) never enter: not said
    edge = ~np.all(_inside_frames(res.context, run, axis=1), axis=1)[prof["rows"]]
    away = ~prof["near_wall"] & ~edge
    few = int(np.count_nonzero(away & (prof["count"] < 0.5 * prof["pairs"])))
    if few:
        prof["warning"] = (
            f"{few} of {int(away.sum())} rows away from the wall entered fewer than half of the "
            f"{prof['pairs']} pairs (a row of a pair enters with at least "
            f"{100 * tp.min_valid:g} % valid vectors): their spectra and correlations rest on "
            "fewer fields (count)"
        )
        camp.say(f"WARNING: {run.label}: two-point: {prof['warning']}")
    if camp.config.output.netcdf:
        ds = two_point_dataset(prof, run)
        if few:
            ds.attrs["warning"] = prof["warning"]
        res.files[f"two_point_{run.name}"] = write_netcdf(
            ds, camp.out_dir / f"two_point_{run.name}.nc"
        )
    return prof


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's spectra and correlations, or None."""
    main = res.context.runs[0]
    prof = res.two_point.get(main.name)
    if prof is None or "y_plus" not in prof:
        return None
    figures = []
    figdir = camp.out_dir / "report" / "figures"
    try:
        from rspiv.plots.two_point import plot_two_point, plot_two_point_maps  # deferred: mpl

        path = plot_two_point(figdir / "two_point.png", prof)
        figures.append((path, f"{main.label}: premultiplied spectra and two-point correlations"))
        if "R_uu_map" in prof:
            path = plot_two_point_maps(figdir / "two_point_maps.png", prof)
            figures.append((path, f"{main.label}: two-point correlation maps of u (R_uu >= 0.1; "
                                  "the black line is R_uu = 0.05)"))  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
        camp.say(f"two-point figure failed: {exc}")
    w = prof["window_px"][0]
    n = prof["columns"][1] - prof["columns"][0]
    text = (
        f"Streamwise spectra and two-point correlations of {prof['pairs']} pairs, per row along "
        f"the wall over {n} vectors ({prof['dx'][-1] * 2 / max(prof['delta_99'], 1e-30):.2f} "
        "delta_99), each vector's fluctuation about its own mean. Wavelengths longer than the "
        "field are not measured; those shorter than "
        f"{FILTER_WIDTHS:g} window widths ({FILTER_WIDTHS * w:g} px) lose more than 20 % of "
        "their energy to the window average (hatched), and the spectrum's tail there holds the "
        "measurement noise, which also lowers every correlation coefficient by about the "
        "noise's share of the variance. Rows within "
        "2.5 window heights of the wall are left out (near_wall)."
    )
    if "R_uu_map" in prof:
        text += (
            f" The maps correlate each reference row with the rows around it over the "
            f"{prof['map_pairs']} pairs in which every row of the map entered."
        )
    if "warning" in prof:
        text += f"\n\nWarning: {prof['warning']}."
    return ReportSection("Spectra and two-point correlations", text=text, figures=figures)
