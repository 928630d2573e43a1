"""The paper's Table 4: the wall on the raw frames and on the frames dewarped by each model.

:func:`wall_table` measures the wall (:func:`rspiv.find_wall`, the particle reflection) on the
raw frames and on the frames dewarped (Method I, as the paper, :func:`rspiv.correction.dewarp_pair`)
by each mapping model fitted to the same calibration markers (:func:`refit`), without and with
the levelling rotation: a :class:`WallTable`, printed by ``rspiv wall``.

Coordinates, angles and rotations follow :mod:`rspiv.wall` (pixel frame, y down; the rotation
that levels the wall is ``+angle_deg``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rspiv.calibration import Calibration
from rspiv.correction import dewarp_pair, mapping_of
from rspiv.dewarp import check_calibration_shape
from rspiv.errors import InvalidInputError
from rspiv.io import read_image
from rspiv.mapping import fit_mapping
from rspiv.multipass import run_grid
from rspiv.settings import PivSettings
from rspiv.wall import Wall, find_wall

__all__ = ["WallRow", "WallTable", "refit", "wall_table", "DEFAULT_PASSES", "DEFAULT_OVERLAP"]

DEFAULT_PASSES: tuple[tuple[int, int], ...] = ((64, 64), (32, 32), (32, 8))
#: Overlap per pass for the wall: the final 32 x 8 px windows at 75 % overlap put a vector row
#: every 2 px. At 4 px (50 %) the near-wall profile (viscous length ~1.4 px x scale) is
#: under-sampled and the mirror position locks to the vector rows: a periodic error of the
#: wall's phase relative to the rows, +-0.03 px at full scale but +-0.3 px at 0.3 scale, which
#: biases the angle low when the wall crosses less than one row spacing over the frame.
DEFAULT_OVERLAP: tuple[float, ...] = (0.5, 0.5, 0.75)


@dataclasses.dataclass(frozen=True)
class WallRow:
    """One condition of :class:`WallTable`.

    Attributes
    ----------
    condition : str
        ``"distorted"``, ``"R2"``, ``"R2 + rotation"``, ``"P3"``, ``"P3 + rotation"`` (the
        model name upper-cased).
    model : str or None
        Mapping model of the dewarping (None: the raw frames).
    rotation_deg : float
        Rotation added to the calibration for this row (0 for the unrotated rows), degrees,
        :attr:`Wall.rotation_deg` of the model's unrotated row.
    wall : Wall
        The wall found on the (dewarped) frames.
    """

    condition: str
    model: str | None
    rotation_deg: float
    wall: Wall

    @property
    def max_deviation_px(self) -> float:
        """Maximum deviation from the straight and horizontal position (px; Table 4)."""
        return self.wall.max_deviation_px

    @property
    def angle_deg(self) -> float:
        """Angle of the fitted wall line (degrees, pixel frame)."""
        return self.wall.angle_deg


@dataclasses.dataclass(frozen=True)
class WallTable:
    """The run's version of the paper's Table 4 (:func:`wall_table`).

    Attributes
    ----------
    rows : tuple of WallRow
        ``distorted`` first, then for each model its dewarped row and its rotated row.
    mappings : dict of str -> Mapping
        The mapping of every corrected row, by condition (the rotated rows' mappings include
        the levelling rotation: ``mappings["P3 + rotation"]`` is the calibration to use).
    method : str
        How the corrected rows were measured: ``"images"`` (Method I, the frames dewarped
        before the PIV, as the paper's Table 4).
    """

    rows: tuple[WallRow, ...]
    mappings: dict[str, Any]
    method: str = "images"

    def __getitem__(self, condition: str) -> WallRow:
        for r in self.rows:
            if r.condition.lower() == condition.lower():
                return r
        raise KeyError(f"no row {condition!r}; rows: {[r.condition for r in self.rows]}")

    @property
    def walls(self) -> dict[str, Wall]:
        """``{condition: Wall}`` in row order (for :func:`rspiv.plots.wall.wall_shape`)."""
        return {r.condition: r.wall for r in self.rows}

    @property
    def best(self) -> WallRow:
        """The row with the smallest maximum deviation."""
        return min(self.rows, key=lambda r: r.max_deviation_px)

    def format(self) -> str:
        """The table as text: condition, max deviation (px), angle (deg), straightness (px),
        valid stations."""
        lines = [
            f"{'condition':16s} {'max deviation [px]':>18s} {'angle [deg]':>12s} "
            f"{'straightness [px]':>17s} {'stations':>9s}"
        ]
        for r in self.rows:
            w = r.wall
            lines.append(
                f"{r.condition:16s} {w.max_deviation_px:18.3f} {w.angle_deg:+12.5f} "
                f"{w.straightness_px:17.3f} {int(w.valid.sum()):4d} / {len(w.valid):<4d}"
            )
        return "\n".join(lines)


def refit(calibration: Any, model: str) -> Any:
    """The calibration's markers fitted with another mapping ``model`` (same object points,
    central marker and normalising scale): a new :class:`rspiv.Calibration` whose ``model``
    and ``mapping`` are the refit (its rotation is not carried over)."""
    if not isinstance(calibration, Calibration):
        raise InvalidInputError(
            f"refitting model {model!r} needs a Calibration (with its markers), "
            f"got {type(calibration).__name__}"
        )
    mk = calibration.markers
    m = fit_mapping(
        mk.object_px, mk.image_px, model, center_index=mk.centre, scale=calibration.mapping.scale
    )
    new = Calibration(**calibration._fields())
    new.mapping = m
    new.model = m.model
    new.model_reason = f"refitted from the markers of a {calibration.model} calibration"
    return new


def _pair_frames(pair: Any) -> tuple[np.ndarray, np.ndarray]:
    if len(pair) < 2:
        raise InvalidInputError("wall_table: every pair must hold two frames (A, B)")
    a, b = read_image(pair[0]), read_image(pair[1])
    if a.shape != b.shape:
        raise InvalidInputError(
            f"wall_table: frames of a pair differ in shape: {a.shape}, {b.shape}"
        )
    return a, b


def wall_table(
    pairs: Sequence[Any],
    calibration: Any = None,
    *,
    models: Sequence[str] | None = ("r2", "p3"),
    band: tuple[float, float] | None = None,
    stations: int | None = 16,
    passes: Sequence[tuple[int, int]] = DEFAULT_PASSES,
    overlap: float | Sequence[float] | None = None,
    iterations: int = 8,
    reject: float | None = 3.5,
    progress: Callable[[str], None] | None = None,
) -> WallTable:
    """The paper's Table 4 for a run: the wall on the raw frames and on the frames dewarped by
    each model, without and with the levelling rotation.

    As in the paper (section 3.2, Table 4, Fig. 8) the corrected rows come from Method I: each
    pair is dewarped with the model's mapping, PIV runs on the dewarped frames (object px), and
    :func:`find_wall` finds the wall from the reflection symmetry. The rotated row of a model
    dewarps with its mapping rotated by :attr:`Wall.rotation_deg` of that model's unrotated row.

    Parameters
    ----------
    pairs : sequence of (frame_a, frame_b)
        Frame pairs (arrays or image files) holding the wall and the particles' reflection.
    calibration : Calibration or Mapping, optional
        None: the distorted row only. A :class:`rspiv.Calibration`: every model of ``models``
        is fitted to its markers (R2 and P3 from the same markers, :func:`refit`); its own
        rotation is not used (the table measures it). A :class:`rspiv.Mapping` (or a
        Calibration with ``models=None``): that mapping only, as it is.
    models : sequence of {"r1", "r2", "p3"} or None
        Models of the corrected rows, in row order.
    band : (float, float), optional
        Rows (px) holding the flow profile and its reflection, passed to :func:`find_wall`;
        the PIV then runs only on these rows plus the largest window height on either side.
        Default: the whole frame.
    stations, iterations, reject
        As for :func:`find_wall`.
    passes, overlap
        PIV windows (coarse to fine, ``(w, h)`` px) and overlap (one value, or one per pass) of
        :func:`rspiv.piv`. Default overlap: 0.5, and 0.75 for the last pass, which samples the
        profile every 2 px with 8 px high windows: coarser rows lock the wall position to them
        (see ``DEFAULT_OVERLAP``).
    progress : callable, optional
        Called with a short message before each condition.

    Returns
    -------
    WallTable
        For a Mapping input the unrotated row uses the mapping as it is (its own rotation
        included) and the rotated row adds the measured rotation to it.

    Raises
    ------
    InvalidInputError
        No pairs, unreadable frames, frames of different shapes, a band outside the frames,
        a model that cannot be refitted.
    """
    if len(pairs) == 0:
        raise InvalidInputError("wall_table: no frame pairs")
    frames = [_pair_frames(p) for p in pairs]
    shape = frames[0][0].shape
    for a, _ in frames:
        if a.shape != shape:
            raise InvalidInputError(f"wall_table: frames of shape {a.shape} and {shape} mixed")
    passes = [tuple(int(t) for t in p) for p in passes]
    if not passes:
        raise InvalidInputError("wall_table: passes is empty")
    if overlap is None:
        overlap = [0.5] * (len(passes) - 1) + [0.75]
    if np.ndim(overlap) == 0:
        overlap = [float(overlap)] * len(passes)  # type: ignore[arg-type]
    overlaps = [float(v) for v in overlap]  # type: ignore[union-attr]
    if len(overlaps) != len(passes):
        raise InvalidInputError(f"wall_table: {len(overlaps)} overlaps for {len(passes)} passes")
    h = shape[0]
    if band is not None:
        y0, y1 = sorted(float(v) for v in band)
        pad = max(p[1] for p in passes)
        r0 = max(0, int(np.floor(y0)) - pad)
        r1 = min(h, int(np.ceil(y1)) + pad + 1)
        if r1 - r0 < max(p[1] for p in passes) or y1 < 0 or y0 > h - 1:
            raise InvalidInputError(f"wall_table: band {band} lies outside the {h}-row frames")
        band_t: tuple[float, float] | None = (y0, y1)
    else:
        r0, r1, band_t = 0, h, None

    # The mappings, by model.
    conditions: list[tuple[str, str, Any]] = []  # (condition, model, mapping) unrotated
    if calibration is not None:
        if models is None or not hasattr(calibration, "markers"):
            m = mapping_of(calibration)
            conditions.append((m.model.upper(), m.model, m))
        else:
            for model in models:
                c = refit(calibration, str(model).lower())
                conditions.append((c.model.upper(), c.model, c.mapping))
        if hasattr(calibration, "image_shape"):
            check_calibration_shape(calibration, shape, "frames")

    settings = PivSettings(passes=tuple(passes), overlap=tuple(overlaps))

    def find(mapping: Any) -> Wall:
        fields = []
        for a, b in frames:
            if mapping is not None:
                # Method I without a fill mask: the band's rows lie inside the sensor's image
                a, b, _ = dewarp_pair(a, b, mapping, zero_fill="keep")
            a = np.ascontiguousarray(a[r0:r1])
            b = np.ascontiguousarray(b[r0:r1])
            f = run_grid(a, b, settings)
            fields.append(dataclasses.replace(f, y=f.y + r0))
        return find_wall(fields, band=band_t, stations=stations, iterations=iterations,
                         reject=reject)  # fmt: skip

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    say("distorted")
    rows = [WallRow("distorted", None, 0.0, find(None))]
    mappings: dict[str, Any] = {}
    for name, model, m in conditions:
        say(name)
        w = find(m)
        rows.append(WallRow(name, model, 0.0, w))
        mappings[name] = m
        rot = w.rotation_deg
        mr = m.rotated(rot)
        say(f"{name} + rotation ({rot:+.5f} deg)")
        rows.append(WallRow(f"{name} + rotation", model, rot, find(mr)))
        mappings[f"{name} + rotation"] = mr
    return WallTable(rows=tuple(rows), mappings=mappings)
