"""Preparing a campaign: calibration (figures, Monte Carlo), the wall pilot, the frozen context.

:func:`prepare_context` calibrates from the target image, runs a *pilot* over the first few
pairs to find the wall in the corrected field and its angle, rotates the calibration to level it
(paper section 3.2), and freezes everything the per-pair work needs into a :class:`PairContext`
written to ``OUT/context.json`` (reused by shards and restarts of the same configuration).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import pathlib
import time
import warnings
from typing import Any

import numpy as np

from rspiv.calibration import Calibration, calibrate
from rspiv.campaign import pair as pair_work
from rspiv.campaign import screen as screen_work
from rspiv.campaign import two_point as two_point_work
from rspiv.campaign.analysis import analyse_run, calibration_table, find_run_wall, wall_dict
from rspiv.campaign.ensemble import plan_bands
from rspiv.campaign.spec import PairContext, PairSpec
from rspiv.campaign.state import check_writable, json_default
from rspiv.errors import InvalidInputError, RspivError
from rspiv.io import read_image, read_mask, turn_frame
from rspiv.montecarlo import monte_carlo
from rspiv.outputs import atomic_path, atomic_write_text
from rspiv.particle_size import particle_diameter, warnings_for
from rspiv.piv import piv
from rspiv.preprocess import Background
from rspiv.recording import check_recording, mean_diameter, roi_mask, spread, unlike_pairs
from rspiv.recording_drift import check_drift
from rspiv.stats import FieldAccumulator

__all__ = ["prepare_context"]


def prepare_context(camp: Any, pairs: list[PairSpec] | None = None) -> PairContext:
    """Calibrate, find the wall angle on the pilot pairs, and freeze the context of ``camp``
    (a :class:`rspiv.Campaign`: its ``calibration`` and ``info`` are set).

    Reuses ``OUT/context.json`` when it was written for the same configuration.
    """
    out = camp.out_dir
    check_writable(out)
    ctx_path = out / "context.json"
    h = camp.config_hash()
    if ctx_path.is_file():
        try:
            saved = json.loads(ctx_path.read_text(encoding="utf-8"))
            gone = screen_work.missing(saved["context"].get("screen"))
            if gone:  # the screen's bounds removed since: the context is prepared again
                camp.say(f"{ctx_path}: {gone[0]} is gone; preparing the context again")
            elif saved.get("config_hash") == h:
                camp.info = saved.get("info", {})
                cal_path = out / "calibration.json"
                if cal_path.is_file():
                    camp.calibration = Calibration.load(cal_path)
                camp.say(f"reusing {ctx_path}")
                return PairContext.from_dict(saved["context"])
        except (OSError, ValueError, KeyError, TypeError):
            pass  # rebuilt below
    pairs = camp.pairs() if pairs is None else pairs
    cfg = camp.config
    runs = camp.runs()
    figdir = out / "report" / "figures"
    info: dict[str, Any] = {"figures": {}, "wall_deviation": {}}
    mapping_json = None
    cal = None
    # Everything that can refuse the inputs runs before anything is written: the frames' shape
    # (the target's, else the first readable frame's), the mask against it, the background
    # pass over every pair, the check of a sequential pairing; then the calibration and its
    # figures.
    turn = cfg.images.orientation()  # [images] rotate, mirror: the target as the frames
    image = None
    if cfg.calibration.target is not None:
        image = turn_frame(read_image(cfg.calibration.target), turn)
    image_shape = _first_shape(pairs) if image is None else tuple(image.shape)
    if turn:
        how = "mirrored left-right, then " if cfg.images.mirror else ""
        camp.say(
            f"[images] rotate = {cfg.images.rotate}, mirror = {str(cfg.images.mirror).lower()}: "
            f"every frame, the target and the mask are {how}turned {cfg.images.rotate} deg "
            f"counter-clockwise as read; the campaign's frames are {image_shape[1]} x "
            f"{image_shape[0]} px"
        )
    if cfg.piv.mask is not None:
        read_mask(cfg.piv.mask, image_shape, turn)
    pre = cfg.preprocess.settings()
    background = _backgrounds(camp, pairs, pre, image_shape) if pre.background != "none" else None
    if cfg.images.pairing == "sequential":
        _check_sequence(camp, pairs, image_shape, cfg.piv.passes[0])
    if image is not None:
        t0 = time.perf_counter()
        cc = cfg.calibration
        cal = calibrate(
            image,
            cc.pitch_mm,
            model=cc.model.lower(),
            marker=cc.marker,
            pitch_sigma_mm=cc.pitch_sigma_mm if cc.pitch_sigma_mm > 0 else None,
            marker_size_px=cc.marker_size_px if cc.marker_size_px > 0 else None,
            level=cc.level or None,
        )
        camp.say(f"calibration: {cal!r} ({time.perf_counter() - t0:.1f} s)")
        for warning in cal.warnings:
            camp.say(f"WARNING: calibration: {warning}")
        info["calibration_table"] = calibration_table(cal)
        try:
            from rspiv.plots.calibration import write_all  # deferred: matplotlib

            figs = write_all(figdir, cal, image)
            info["figures"]["calibration"] = [str(p) for p in figs]
        except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
            camp.say(f"calibration figures failed: {exc}")
        if cc.monte_carlo_samples > 0:
            t0 = time.perf_counter()
            info.update(_monte_carlo(camp, cal, cc.monte_carlo_samples, figdir))
            camp.say(
                f"Monte Carlo: {cc.monte_carlo_samples} samples "
                f"({time.perf_counter() - t0:.1f} s)"
            )
    background_paths = None if background is None else _save_backgrounds(background, out)
    base = PairContext(
        runs=runs,
        image_shape=image_shape,
        object_shape=image_shape,
        mapping_json=None if cal is None else cal.mapping.to_json(),
        piv=cfg.piv.settings(),
        mask_path=None if cfg.piv.mask is None else str(cfg.piv.mask),
        preprocess=pre,
        background_paths=background_paths,
        turn=turn,
    )
    main = runs[0]
    if cal is not None and main.method != "none" and cfg.wall.enabled and cfg.wall.rotate:
        t0 = time.perf_counter()
        pilot_ctx = dataclasses.replace(base, runs=(main,), _cache={})
        accs, used = _pilot(camp, pilot_ctx, pairs, "the wall alignment pilot")
        acc = accs[main.name]
        gx, gy = base.grid()
        wall, side = find_run_wall(
            acc, gx, gy, cfg.wall.stations, cfg.wall.side, cfg.statistics.min_count
        )
        theta = wall.rotation_deg
        cal = cal.with_rotation(theta)
        mapping_json = cal.mapping.to_json()
        model = cfg.calibration.model
        info["wall_deviation"][f"Dewarped by {model}"] = wall.max_deviation_px
        info["pilot"] = {
            "pairs": used,
            "wall_angle_deg": wall.angle_deg,
            "rotation_deg": theta,
            "max_deviation_px": wall.max_deviation_px,
            "flow_side": side,
        }
        info["pilot_wall"] = wall_dict(wall)
        camp.say(
            f"wall alignment on {len(used)} pilot pair(s): angle {wall.angle_deg:.4f} deg, "
            f"max deviation {wall.max_deviation_px:.2f} px; rotating the mapping by "
            f"{theta:.4f} deg ({time.perf_counter() - t0:.1f} s)"
        )
    elif cal is not None:
        mapping_json = cal.mapping.to_json()
    ctx = dataclasses.replace(base, mapping_json=mapping_json, _cache={})
    _particle_images(camp, ctx, pairs, info)
    ctx = _direction(camp, ctx, info)
    if cfg.ensemble.enabled:
        ctx = _plan_ensemble(camp, ctx, pairs, cal, info)
    if cfg.statistics.two_point:
        ctx = _plan_two_point(camp, ctx, pairs, cal, info)
    if cfg.statistics.vorticity:
        ctx = dataclasses.replace(ctx, vorticity=cfg.statistics.vorticity_scheme, _cache={})
    ctx = screen_work.plan(camp, ctx, pairs, info)
    camp.calibration = cal
    if cal is not None:
        cal.save(out / "calibration.json")
    camp.info = info
    atomic_write_text(
        ctx_path,
        json.dumps(
            {"config_hash": h, "context": ctx.to_dict(), "info": info},
            indent=1,
            default=json_default,
        ),
    )
    return ctx


def _particle_images(camp, ctx: PairContext, pairs: list[PairSpec], info: dict) -> None:
    """The particle images' e^-2 diameter (px, along x and y) on the first readable pair of
    the first ``camp.pilot_pairs``, as recorded (:func:`rspiv.particle_diameter`: the raw
    frames less the run's backgrounds, the first pass's window, the mask), in
    ``info["particle_diameter_px"]``. Particle images too small for a sub-pixel fit or for the
    hot-pixel rule (:func:`rspiv.particle_size.warnings_for`) are said once and kept in
    ``info["particle_size_warnings"]`` for ``summary.json`` and the report: the optics do not
    change within a campaign, and every pair's displacements carry the same bias. The same
    pair's recording check (:func:`_recording`) follows."""
    for p in pairs[: max(camp.pilot_pairs, 1)]:
        frames = pair_work.read_ahead(p, ctx.image_shape)
        if isinstance(frames, str):
            continue
        try:
            dx, dy = particle_diameter(*frames, ctx.piv.passes[0], ctx.mask(), ctx.backgrounds())
        except (RspivError, ValueError):
            continue  # bad data: the pair loop says what (and leaves the pair out)
        info["particle_diameter_px"] = [dx, dy]
        camp.say(f"particle images {dx:.2f} x {dy:.2f} px (pair {p.pair_id}, e^-2 diameter)")
        said = warnings_for((dx, dy), ctx.preprocess)
        if said:
            info["particle_size_warnings"] = said
        for line in said.values():
            camp.say(f"WARNING: {line}")
        _recording(camp, ctx, p, frames, pairs, info)
        return


def _recording(camp, ctx: PairContext, p: PairSpec, frames, pairs, info: dict) -> None:
    """:func:`rspiv.check_recording` of pair ``p`` as recorded with the campaign's passes and
    its mask and region of interest (:func:`rspiv.recording.roi_mask`):
    ``info["recording"]`` (every figure) and one line in the log; its warnings that the
    campaign does not answer already are said and kept in ``info["recording_warnings"]`` (the
    particle size is said above, the correlation by the pair loop, the background where the
    conditioning subtracts it or high-passes, the deformation where the passes deform); then
    the drift over the run (:func:`_drift`)."""
    mask = roi_mask(ctx.mask(), ctx.piv.roi, tuple(ctx.image_shape))
    try:
        check = check_recording(*frames, mask=mask, passes=ctx.piv.passes)
    except (RspivError, ValueError) as exc:
        camp.say(f"recording check of pair {p.pair_id} failed: {exc}")
        return
    info["recording"] = check.to_dict()
    own = ", ".join(f"{w}x{h} {check.per_window[f'{w}x{h}']:.1f}" for w, h in ctx.piv.passes)
    rec = " -> ".join(f"{w}x{h}" for w, h in check.passes) if check.passes else "none"
    camp.say(
        f"recording (pair {p.pair_id}): {check.density:.4f}"
        f"{' or more' if check.density_bound else ''} particle images per px; per window {own}; "
        f"recommended passes {rec}"
    )
    pre = ctx.preprocess
    answered = {"peak_locking", "correlation"}
    if pre.background != "none" or pre.high_pass > 0:
        answered |= {"background_A", "background_B"}
    if ctx.piv.deformation == "symmetric":
        answered.add("deformation")
    said = {k: v for k, v in check.warnings.items() if k not in answered}
    said.update(_drift(camp, ctx, pairs, check, mask, info))
    if said:
        info["recording_warnings"] = said
    for line in said.values():
        camp.say(f"WARNING: recording: {line}")


def _direction(camp, ctx: PairContext, info: dict) -> PairContext:
    """``ctx`` with the run's direction from the drift check's sampled pairs
    (``info["recording_drift"]["direction"]``, :func:`rspiv.recording_drift.flow_direction`),
    which the pair loop holds each pair against (:mod:`rspiv.campaign.pair_quality`); said
    either way, and why not (``info["reversed_check"]``)."""
    fd = (info.get("recording_drift") or {}).get("direction") or {}
    ref = fd.get("displacement")
    if ref is None:
        n = camp.config.images.check_pairs
        why = fd.get("note") or (
            f"[images] check_pairs = {n} (at least 2 are needed)"
            if n < 2
            else "the recording's drift check did not run"
        )
        info["reversed_check"] = {"direction": None, "note": why}
        camp.say(f"pairs with frames in reverse order are not looked for: {why}")
        return ctx
    ref = (float(ref[0]), float(ref[1]))
    info["reversed_check"] = {"direction": list(ref), "pairs": fd.get("pairs", [])}
    camp.say(
        f"the run's direction ({ref[0]:.2f}, {ref[1]:.2f}) px from {len(fd.get('pairs', []))} "
        "sampled pairs: a pair displacing the other way (frames in reverse order) is left out"
    )
    return dataclasses.replace(ctx, reference=ref, _cache={})


def _drift(
    camp, ctx: PairContext, pairs: list[PairSpec], check, mask, info: dict
) -> dict[str, str]:
    """:func:`rspiv.recording_drift.check_drift` over ``[images] check_pairs`` pairs spread evenly
    over the run (unreadable ones left to the pair loop): ``info["recording_drift"]`` and one
    line in the log; its warnings keyed ``drift_<key>``."""
    chosen = spread(pairs, camp.config.images.check_pairs)
    if len(chosen) < 2:
        return {}

    def frames():
        for p in chosen:
            got = pair_work.read_ahead(p, ctx.image_shape)
            if not isinstance(got, str):
                yield (p.pair_id, *got)

    d = mean_diameter(check.diameter)
    try:
        drift = check_drift(frames(), mask=mask, diameter=d, passes=ctx.piv.passes)
    except (RspivError, ValueError) as exc:
        camp.say(f"recording drift check failed: {exc}")
        return {}
    info["recording_drift"] = drift.to_dict()
    camp.say(
        f"recording over the run: {len(drift.pairs)} pairs, "
        f"{min(drift.density):.4f}-{max(drift.density):.4f} particle images per px"
    )
    return {f"drift_{k}": v for k, v in drift.warnings.items()}


def _pilot(
    camp, ctx: PairContext, pairs: list[PairSpec], what: str
) -> tuple[dict[str, FieldAccumulator], list[int]]:
    """The instantaneous statistics of every run of ``ctx`` over the first ``camp.pilot_pairs``
    usable pairs, and the ids of those pairs (unreadable ones are passed over). No usable pair
    at all is an InvalidInputError for ``what`` that quotes the first pair's reason (a
    setting every pair fails on is not an unreadable file)."""
    accs: dict[str, FieldAccumulator] = {}
    used: list[int] = []
    first_reason = ""
    for p in pairs:
        if len(used) >= camp.pilot_pairs:
            break
        r = pair_work.process_pair(ctx, p)
        if not r.ok:
            first_reason = first_reason or f"pair {p.pair_id}: {r.reason}"
            continue
        for name, (u, v, valid, *_) in r.fields.items():
            accs.setdefault(name, FieldAccumulator(u.shape)).add(u, v, valid)
        used.append(p.pair_id)
    if not used:
        why = f" ({first_reason})" if first_reason else ""
        raise InvalidInputError(f"no usable image pair for {what}{why}")
    return accs, used


def _pilot_walls(camp, ctx: PairContext, pairs: list[PairSpec], what: str):
    """:func:`_pilot` of every run of ``ctx`` and the wall each run's pilot statistics show:
    ``(accumulators, pair ids, {run: (Wall, flow_side)})`` (with ``[wall] enabled = false``
    the convention of :func:`analyse_run`: a level wall at the grid's edge)."""
    cfg = camp.config
    accs, used = _pilot(camp, ctx, pairs, what)
    gx, gy = ctx.grid()
    walls = {}
    for run in ctx.runs:
        if cfg.wall.enabled:
            walls[run.name] = find_run_wall(
                accs[run.name], gx, gy, cfg.wall.stations, cfg.wall.side, 1
            )
        else:
            ys = gy[:, 0]
            side = "above" if cfg.wall.side != "top" else "below"
            y = ys[-1] + 0.5 * (ys[1] - ys[0]) if side == "above" else ys[0]
            walls[run.name] = (_LevelWall(float(y)), side)
    return accs, used, walls


def _pilot_profile(camp, ctx: PairContext, accs: dict[str, FieldAccumulator], cal):
    """:func:`analyse_run` of the main run's pilot statistics ``accs``: the profile from the
    vectors valid in two of the pilot's pairs (the campaign's ``[statistics] min_count`` is for
    the whole run, more than a pilot's few pairs)."""
    cfg = copy.deepcopy(camp.config)
    cfg.statistics.min_count = 2
    main = ctx.runs[0]
    gx, gy = ctx.grid()
    mag = None if cal is None else cal.magnification
    return analyse_run(
        main, accs[main.name], gx, gy, cfg, mag, cfg.flow.dt, ctx.piv.final_window
    )


def _plan_two_point(camp, ctx: PairContext, pairs: list[PairSpec], cal, info: dict) -> PairContext:
    """The columns of the streamwise spectra and, with ``two_point_heights``, the rows of the
    two-point maps (:func:`rspiv.campaign.two_point.plan`) from a pilot over the first
    ``camp.pilot_pairs`` usable pairs; ``ctx`` with them."""
    st = camp.config.statistics
    walls, delta_px = None, None
    if st.two_point_heights:
        t0 = time.perf_counter()
        accs, used, walls = _pilot_walls(camp, ctx, pairs, "the two-point maps' pilot")
        if st.two_point_height_units == "delta":
            try:
                an = _pilot_profile(camp, ctx, accs, cal)
            except (RspivError, ValueError) as exc:
                raise InvalidInputError(
                    f"[statistics] two_point_height_units = 'delta': the profile fit of the "
                    f"pilot's {len(used)} pair(s) failed ({exc})"
                ) from None
            if an.result is None:
                raise InvalidInputError(
                    "[statistics] two_point_height_units = 'delta' needs the pilot's delta_99: a "
                    "calibration and [flow].dt > 0 (or give the heights in px)"
                )
            delta_px = an.result.delta99 / an.profile["m_per_px"]
        info["two_point"] = {"pilot_pairs": used, "delta99_px": delta_px}
        camp.say(
            f"two-point maps: the wall from {len(used)} pilot pair(s)"
            + (f", delta_99 {delta_px:.0f} px" if delta_px else "")
            + f" ({time.perf_counter() - t0:.1f} s)"
        )
    heights = [h * delta_px if delta_px else float(h) for h in st.two_point_heights]
    spec = two_point_work.plan(ctx, st.two_point_min_valid, walls, heights)
    n = ctx.grid()[0].shape[1]
    for run in ctx.runs:
        c0, c1 = spec["columns"][run.name]
        if c1 - c0 < n:
            camp.say(
                f"two-point: {run.label}: {c1 - c0} of {n} columns enter (the others' windows, "
                "with half a window's margin, reach past the frames)"
            )
    return dataclasses.replace(ctx, two_point=spec, _cache={})


def _plan_ensemble(camp, ctx: PairContext, pairs: list[PairSpec], cal, info: dict) -> PairContext:
    """The ensemble bands (:func:`rspiv.campaign.ensemble.plan_bands`) from a pilot over the
    first ``camp.pilot_pairs`` usable pairs, every run; ``ctx`` with them."""
    t0 = time.perf_counter()
    cfg = camp.config
    accs, used, walls = _pilot_walls(camp, ctx, pairs, "the [ensemble] band's pilot")
    ec = cfg.ensemble
    band_px = float(ec.band)
    lv_px = None
    if ec.band_units == "plus" or cal is not None:
        try:
            an = _pilot_profile(camp, ctx, accs, cal)
            if an.result is not None:
                lv_px = an.result.nu / an.result.u_tau / an.profile["m_per_px"]
        except (RspivError, ValueError) as exc:
            if ec.band_units == "plus":
                raise InvalidInputError(
                    f"[ensemble].band_units = 'plus': the pilot's profile fit failed ({exc})"
                ) from None
        if ec.band_units == "plus":
            if lv_px is None:
                raise InvalidInputError(
                    "[ensemble].band_units = 'plus' needs wall units: a calibration and "
                    "[flow].dt > 0"
                )
            band_px = float(ec.band) * lv_px
    pixel_px = None
    if ec.single_pixel:
        pixel_px = float(ec.pixel_band) * (lv_px if ec.band_units == "plus" else 1.0)
    bands = plan_bands(ctx, accs, walls, cfg, band_px, pixel_px)
    info["ensemble"] = {
        "pilot_pairs": used,
        "band_px": band_px,
        "viscous_length_px": lv_px,
        "window": list(ec.window),
        "step": list(ec.step),
    }
    if pixel_px is not None:
        info["ensemble"]["single_pixel"] = {
            "band_px": pixel_px,
            "step_px": float(ec.pixel_step),
            "segment_px": int(ec.pixel_segment),
            "lags": list(ec.pixel_lags),
        }
    rows = (
        ""
        if pixel_px is None
        else f", single-pixel rows every {ec.pixel_step:g} px to {pixel_px:.1f} px"
    )
    camp.say(
        f"ensemble band: {band_px:.1f} px from the wall, {ec.window[0]} x {ec.window[1]} px "
        f"windows{rows}, predicted from {len(used)} pilot pair(s) "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return dataclasses.replace(ctx, ensemble=bands, _cache={})


class _LevelWall:
    """A level wall line ``y = intercept_px`` (``[wall] enabled = false``)."""

    def __init__(self, y: float) -> None:
        self.intercept_px, self.slope = y, 0.0

    def line(self, x):
        return self.intercept_px + 0.0 * np.asarray(x, dtype=np.float64)


def _backgrounds(camp, pairs: list[PairSpec], pre, shape: tuple[int, int]) -> tuple[Any, Any]:
    """The run's backgrounds of frames A and B (``pre.background``: min or mean over every
    pair, :class:`rspiv.preprocess.Background`), streaming over the files (one pair in memory;
    with sequential pairing, a time-resolved recording, the frames shared by successive pairs
    are read once). A pair that cannot be read or is not of the run's ``shape`` is left out
    here (the pair step reports it as skipped); InvalidInputError with the first such reason
    when fewer than two are left (over one pair the background is the frames themselves)."""
    t0 = time.perf_counter()
    est = (Background(pre.background), Background(pre.background))
    used = 0
    first_reason = ""
    cache = pair_work.FrameCache.for_pairs(pairs)  # sequential pairing: each frame read once
    for p in pairs:
        try:
            a, b = pair_work.read_checked_pair(p, shape, cache)
        except (RspivError, ValueError, OSError) as exc:
            first_reason = first_reason or str(exc)
            continue
        est[0].add(a)
        est[1].add(b)
        used += 1
    if not used:
        raise InvalidInputError(
            f"background: none of the {len(pairs)} image pair(s) can be used"
            + (f"; the first: {first_reason}" if first_reason else "")
        )
    if used < 2:
        raise InvalidInputError(
            f"background ({pre.background}) over 1 usable pair of {len(pairs)} would be the "
            "frames themselves and leave nothing to correlate: give more pairs or set "
            '[preprocess] background = "none"'
            + (f" (skipped: {first_reason})" if first_reason else "")
        )
    camp.say(
        f"background ({pre.background}) of frames A and B over {used} pair(s) "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return est[0].value, est[1].value


def _check_sequence(camp, pairs: list[PairSpec], shape: tuple[int, int], window) -> None:
    """Refuse sequential pairing of a double-frame recording. Paired 1-2, 2-3, ..., the frames
    A, B, A, B ... of a double-frame camera give pairs of two intervals, a short one (A to B)
    and a long one (B to the next A): PIVlab's ``Jet_0001A``, ``B``, ``Jet_0002A`` move 0.47
    px and 11.9 px, and through the campaign's passes the long pairs still correlate in part
    (median peak ratio 1.36), so they would enter the statistics. A time-resolved recording's
    successive pairs move alike and both correlate. The first two pairs, one pass of the first
    window on the raw frames; InvalidInputError in one line when one correlates and the other
    does not, or their median displacements differ by more than
    :data:`rspiv.recording.SEQUENCE_MAX_RATIO` (:func:`rspiv.recording.unlike_pairs`)."""
    seen = []
    cache = pair_work.FrameCache.for_pairs(pairs[:2])  # three frames read
    for p in pairs[:2]:
        frames = pair_work.read_ahead(p, shape, cache)
        if isinstance(frames, str):
            return  # the pair loop says what is wrong with it
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # said below, or by the pair loop
            f = piv(*frames, passes=[tuple(window)], overlap=0.5)
        speed = np.hypot(f.u, f.v)[f.valid]
        pr = f.peak_ratio[f.peak_ratio > 0]
        seen.append(
            (
                p,
                not f.uncorrelated(),
                float(np.median(speed)) if speed.size else float("nan"),
                float(np.median(pr)) if pr.size else float("nan"),
            )
        )
    if len(seen) < 2:
        return
    (p0, ok0, m0, r0), (p1, ok1, m1, r1) = seen
    if unlike_pairs(ok0, m0, ok1, m1):
        raise InvalidInputError(
            f'[images] pairing = "sequential": pair {p0.pair_id} ({p0.describe()}) moves '
            f"{m0:.2f} px (median peak ratio {r0:.2f}), pair {p1.pair_id} ({p1.describe()}) "
            f"{m1:.2f} px ({r1:.2f}): frames of a double-frame camera (A, B, A, B, ...) rather "
            'than a time-resolved recording? Pair them with pairing = "pairs"'
        )


def _save_backgrounds(background: tuple[Any, Any], out: pathlib.Path) -> tuple[str, str]:
    """Write the backgrounds of frames A and B as ``OUT/background_a.npy``/``background_b.npy``
    (atomically); their paths."""
    paths = []
    for name, value in zip(("a", "b"), background, strict=True):
        path = out / f"background_{name}.npy"
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, value)
        paths.append(str(path))
    return paths[0], paths[1]


def _first_shape(pairs: list[PairSpec]) -> tuple[int, int]:
    first_reason = ""
    for p in pairs:
        try:
            a = pair_work.read_frame(p.a, p.frame_a, p.turn)
        except (RspivError, ValueError, OSError) as exc:
            first_reason = first_reason or str(exc)
            continue
        return (int(a.shape[0]), int(a.shape[1]))
    raise InvalidInputError(
        f"no readable image among the campaign's {len(pairs)} pair(s)"
        + (f"; the first: {first_reason}" if first_reason else "")
    )


def _monte_carlo(camp: Any, cal: Any, n: int, figdir: pathlib.Path) -> dict[str, Any]:
    res = monte_carlo(cal, n=int(n), hist_bins=64)
    out: dict[str, Any] = {
        "monte_carlo": {
            "n": res.n,
            "n_failed": res.n_failed,
            "radius99_max_px": float(np.max(res.radius99_px)),
            "radius99_median_px": float(np.median(res.radius99_px)),
            "within1_min": float(np.min(res.within1)),
            "within2_min": float(np.min(res.within2)),
            "summary": res.summary(),
        }
    }
    try:
        from rspiv.plots.calibration import monte_carlo_jpdfs  # deferred: matplotlib

        figdir.mkdir(parents=True, exist_ok=True)
        p = monte_carlo_jpdfs(res, figdir / f"montecarlo_{res.model}.png")
        out["figures_mc"] = [str(p)]
    except Exception as exc:  # noqa: BLE001
        camp.say(f"Monte Carlo figure failed: {exc}")
    return out

# ------------------------------------------------------------------ checkpoints
