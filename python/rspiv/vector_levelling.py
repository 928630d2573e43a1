"""The wall levelled and each field corrected, for a series of another tool's vector fields
(:mod:`rspiv.vector_statistics`, steps 2 and 3).

- :func:`field_transform`: the per-field resampling, Method II through a calibration's mapping
  (possibly rotated) or a rotated identity (:func:`identity_mapping`), or nothing.
- :func:`levelling`: the rotation that levels the wall, found on the first pilot fields.
- :func:`wall_rise` and :func:`wall_bow`: how far the wall found rises across the field and
  how much it bows (px), for what the statistics say.

Units and frames: px of the fields' frame, x right, y down; angles in degrees.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from rspiv.campaign.analysis import find_run_wall
from rspiv.correction import correct_vectors
from rspiv.errors import RspivError
from rspiv.mapping import fit_mapping
from rspiv.stats import FieldAccumulator
from rspiv.vector_files import VectorFile

__all__ = ["field_transform", "identity_mapping", "levelling", "wall_bow", "wall_rise"]


def identity_mapping(x: np.ndarray, y: np.ndarray) -> Any:
    """The identity mapping over the grid's extent (a P3 fitted to points mapped onto
    themselves): rotated, it levels a field without a calibration."""
    gx, gy = np.meshgrid(np.linspace(x[0], x[-1], 7), np.linspace(y[0], y[-1], 7))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    return fit_mapping(pts, pts, "p3")


def field_transform(mapping_obj: Any, on: bool, mode: str) -> Callable[[VectorFile], VectorFile]:
    """The per-field resampling: Method II through ``mapping_obj`` (a calibration's mapping,
    possibly rotated, or a rotated identity), or nothing."""
    if not on or mapping_obj is None:
        return lambda vf: vf

    def apply(vf: VectorFile) -> VectorFile:
        if vf.frame == "object":  # an already corrected field, levelled only (identity)
            vf = dataclasses.replace(vf, frame="image")
        return correct_vectors(vf, mapping_obj, mapping=mode)

    return apply


def levelling(
    reads,
    start,
    first,
    red,
    base,
    calibration,
    mode,
    level,
    pilot,
    grid,
    wall_opts,
    warnings,
) -> tuple[float, Any]:
    """The rotation (degrees) that levels the wall, from the first ``pilot`` fields of the
    series ``reads`` reads (a :class:`rspiv.vector_readahead.ReadAhead`; step 3 of
    :mod:`rspiv.vector_statistics`), and the mapping to resample every field through (None:
    none)."""
    if level is False or (level == "auto" and calibration is None):
        return 0.0, base
    gx, gy = grid
    side, stations, min_count = wall_opts
    pre = field_transform(base, calibration is not None, mode)
    acc = FieldAccumulator(first.u.shape)
    ks = range(start, min(len(reads.entries), start + max(int(pilot), 1)))
    reads.along(ks[1:])
    for k in ks:
        try:
            vf = first if k == start else reads.get(k)
            if not red.check(vf):
                red.add(acc, pre(vf), k)
        except RspivError:
            continue  # the main pass names it
    w, _ = find_run_wall(acc, gx, gy, stations, side, min(min_count, acc.n_fields))
    theta = float(w.rotation_deg)
    if calibration is not None:
        return theta, base.rotated(theta)
    warnings.append(
        f"the fields were rotated by {theta:.4f} deg to level the wall, interpolated between "
        "their nodes: it lowers the stresses a little (level=False keeps the nodes)"
    )
    return theta, identity_mapping(gx[0], gy[:, 0]).rotated(theta)


def wall_rise(w: Any, gx: np.ndarray, gy: np.ndarray) -> tuple[float, float]:
    """How far (px) the wall ``w`` rises across the field, and the rows' spacing (px)."""
    rise = abs(np.tan(np.deg2rad(w.angle_deg))) * float(np.ptp(gx))
    return rise, abs(float(gy[1, 0] - gy[0, 0]))


def wall_bow(w: Any) -> float:
    """The wall's bow, px: the quadratic term of a parabola through its stations, from the
    middle of the field to its ends (0 with fewer than 4 stations)."""
    ok = np.isfinite(w.position_px)
    x = np.asarray(w.x_px, dtype=np.float64)[ok]
    if x.size < 4 or np.ptp(x) <= 0:
        return 0.0
    xc = (x - 0.5 * (x.min() + x.max())) / (0.5 * np.ptp(x))
    return float(np.polyfit(xc, np.asarray(w.position_px)[ok], 2)[0])
