"""Calibration from a target image or from given marker positions (paper section 3.1;
DESIGN.md "Calibration from a target image"): sub-pixel markers with their uncertainty, grid
indexing, magnification, object points, the choice of mapping model by held-out error, and a
refusal of fits that do not follow the markers.

Frames
------
Image px: the raw camera image (README pixel frame: x = column, y = row, origin at the centre of
the top-left pixel, y down). Object px: the dewarped frame, whose origin is the central marker:
``P_o = P_ic + M * (X_mm - X_c)``, with ``X_mm`` a marker's position on the target plane (mm),
``X_c`` and ``P_ic`` the target-plane and image positions of the central marker (the marker
nearest the image centre) and ``M`` the magnification (px/mm) measured from the central marker
and its nearest neighbours. For a target image ``X_mm = pitch_mm * (i, j)`` with ``(i, j)`` the
grid index (i along +x, j along +y), so ``P_o = P_ic + M * pitch_mm * (i, j)``: an axis-aligned
square grid. A target rotation on the sensor is thus part of the mapping (see
:meth:`Calibration.with_rotation` for the wall-alignment correction).

:func:`calibrate` (detection and indexing) and :func:`calibrate_points` (positions found by
another tool or by hand) share one path from the points on: magnification, object points, model
comparison, fit, fit-quality check and uncertainties.
"""

from __future__ import annotations

import json
import os
import pathlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv import calibration_input as check
from rspiv.calibration_fit import (
    MIN_POINTS,
    N_PARAMS,
    check_fit,
    choose_model,
    compare_models,
    fit_stats,
    lattice_outliers,
    magnification,
    touching_dots,
)
from rspiv.errors import InvalidInputError
from rspiv.io import read_image
from rspiv.mapping import Mapping, fit_mapping
from rspiv.outputs import atomic_write_text
from rspiv.plate import (
    analyse_plate,
    lattice_from_json,
    lattice_line,
    lattice_problems,
    lattice_record,
    lattice_to_json,
    other_lattices,
    union_of_levels,
)

__all__ = [
    "Markers",
    "Calibration",
    "CalibrationReport",
    "calibrate",
    "calibrate_points",
    "compare_models",
]

#: How a refused calibration is kept anyway (its problems then recorded as warnings).
KEEP_IT = "pass accept_poor_fit=True (rspiv calibrate --accept-poor-fit) to keep it"

FORMAT = "rspiv-calibration"
VERSION = 1  # later additions (warnings, lattice, image_sigma_source) are optional keys
POINTS = "points"  # the ``marker`` of a calibration from given points
DETECTOR = "marker detector"  # the image sigma's source for a target image
# Detected markers whose median sub-pixel sigma exceeds this (px) place nothing: refused.
MAX_MARKER_SIGMA_PX = 0.3


@dataclass
class Markers:
    """The indexed markers of a calibration (one row per marker).

    Attributes
    ----------
    image_px : ndarray (n, 2)
        Measured image positions (x, y), px.
    object_px : ndarray (n, 2)
        Object positions, object px.
    cov_px2 : ndarray (n, 2, 2)
        Covariance of each image position (px^2), from the sub-pixel fit.
    index : ndarray of int (n, 2)
        Grid index (i, j); (0, 0) is the central marker.
    centre : int
        Row of the central marker.
    object_mm : ndarray (n, 2) or None
        Target-plane coordinates (mm) relative to the plate's origin: its fiducial when it has
        one (:mod:`rspiv.plate`), else the central marker; for given points, as given. Two
        calibrations of the same plate agree in this frame. None in files written before it.
    """

    image_px: np.ndarray
    object_px: np.ndarray
    cov_px2: np.ndarray
    index: np.ndarray
    centre: int
    object_mm: np.ndarray | None = None

    @property
    def sigma_px(self) -> np.ndarray:
        """Per-axis standard uncertainty (n, 2) of the image positions, px."""
        return np.sqrt(np.stack([self.cov_px2[:, 0, 0], self.cov_px2[:, 1, 1]], axis=1))

    def __len__(self) -> int:
        return len(self.image_px)


class CalibrationReport(dict):
    """The paper's Table 3 quantities (a dict); ``str()`` gives a printable table."""

    def __str__(self) -> str:
        r = self
        if r.get("marker") == POINTS:
            count = f"{r['n_markers']} given"
        else:
            count = f"{r['n_markers']} indexed of {r['n_detected']} detected"
        lines = [
            f"markers                      {count}",
            f"pitch (mm)                   {r['pitch_mm']:.3f} +/- {r['pitch_sigma_mm']:.3f}",
            "magnification M (px/mm)      {:.3f} +/- {:.3f}".format(
                r["magnification"], r["magnification_sigma"]
            ),
            "image sigma (px)             {:.4f} ({})".format(
                r["image_sigma_px"], r.get("image_sigma_source", DETECTOR)
            ),
            "object sigma (px)            {:.4f} ({})".format(
                r["object_sigma_px"], r["object_sigma_source"]
            ),
            "centre, image space (px)     ({:.3f}, {:.3f})".format(*r["centre_image_px"]),
            "centre, object space (px)    ({:.3f}, {:.3f})".format(*r["centre_object_px"]),
            f"x_o_max (px)                 {r['x_o_max']:.3f}",
            "image hat min / max          ({:.6f}, {:.6f}) / ({:.6f}, {:.6f})".format(
                *r["image_hat_min"], *r["image_hat_max"]
            ),
            "object hat min / max         ({:.6f}, {:.6f}) / ({:.6f}, {:.6f})".format(
                *r["object_hat_min"], *r["object_hat_max"]
            ),
            "model      max|err| x, y (px)   mean x, y (px)     RMS x, y (px)   held-out RMS (px)",
        ]
        for m, s in r["models"].items():
            mark = "*" if m == r["model"] else " "
            lines.append(
                f"{m}{mark}        {s['max_abs_px'][0]:7.3f} {s['max_abs_px'][1]:7.3f}"
                f"   {s['mean_px'][0]:7.3f} {s['mean_px'][1]:7.3f}"
                f"   {s['rms_px'][0]:7.3f} {s['rms_px'][1]:7.3f}   {_fmt_loo(s['loo_rms_px'])}"
            )
        lines.append(f"model: {r['model']} ({r['model_reason']})")
        lines += [f"WARNING: {w}" for w in r.get("warnings", [])]
        return "\n".join(lines)


def _fmt_loo(v: Any) -> str:
    return "        -" if v is None else f"{v:9.4f}"


class Calibration:
    """A camera calibration from a target image (:func:`calibrate`) or from given marker
    positions (:func:`calibrate_points`).

    Attributes
    ----------
    markers : Markers
    mapping : Mapping
        Object px -> image px.
    model : str
    model_reason : str
        Why the model was chosen.
    models : dict
        Per-model residual statistics and held-out error (see :func:`compare_models`).
    pitch_mm, pitch_sigma_mm : float
    magnification, magnification_sigma : float
        M (px/mm) from the central marker and its nearest neighbours (on a grid: its four
        neighbours), and the standard deviation of those estimates.
    object_sigma_px : float
        Uncertainty of the object points, px: ``pitch_sigma_mm * M`` when the pitch uncertainty
        is given, else estimated from the chosen fit's residuals beyond the image noise.
    object_sigma_source : str
    image_sigma_source : str
        Where the markers' image covariances come from: ``"marker detector"`` (a target image),
        the caller (``cov_px2`` / ``sigma_px`` of :func:`calibrate_points`), or the fit residuals.
    image_shape : tuple of int
        (height, width) of the calibrated sensor.
    marker : str
        Marker shape (``"dot"``, ``"cross"``), or ``"points"`` for given positions.
    size_px : float
        Marker size used by the detector (Gaussian sigma, px); 0 for given positions.
    n_detected : int
        Blobs detected (markers + rejected spurious blobs); the number of given points.
    lattice : dict or None
        The lattice the grid indexing found (target images): ``pitch_px`` (its two steps at the
        central marker, px, along i and j), ``angle_deg`` (direction of the i step from +x
        towards +y), ``axes_angle_deg`` (angle between the two steps), ``n_indexed``,
        ``n_detected``, ``n_rejected`` (detected but not indexed), ``size_px`` and
        ``rejected_px`` (the rejected blobs' positions, ndarray (k, 2)). None for given points.
    warnings : list of str
        What the caller should know about this calibration (a fit looser than the markers'
        noise, an estimated image sigma); empty when nothing is to be said.
    """

    def __init__(self, **kw: Any) -> None:
        self.markers: Markers = kw["markers"]
        self.mapping: Mapping = kw["mapping"]
        self.model: str = kw["model"]
        self.model_reason: str = kw["model_reason"]
        self.models: dict[str, dict[str, Any]] = kw["models"]
        self.pitch_mm: float = float(kw["pitch_mm"])
        self.pitch_sigma_mm: float = float(kw["pitch_sigma_mm"])
        self.magnification: float = float(kw["magnification"])
        self.magnification_sigma: float = float(kw["magnification_sigma"])
        self.object_sigma_px: float = float(kw["object_sigma_px"])
        self.object_sigma_source: str = kw["object_sigma_source"]
        self.image_sigma_source: str = str(kw.get("image_sigma_source", DETECTOR))
        self.image_shape: tuple[int, int] = (int(kw["image_shape"][0]), int(kw["image_shape"][1]))
        self.marker: str = kw["marker"]
        self.size_px: float = float(kw["size_px"])
        self.n_detected: int = int(kw["n_detected"])
        self.lattice: dict[str, Any] | None = kw.get("lattice")
        self.warnings: list[str] = [str(w) for w in kw.get("warnings", [])]

    @property
    def image_sigma_px(self) -> float:
        """RMS per-axis uncertainty of the image points (px), the Monte Carlo default."""
        return float(np.sqrt(np.mean(self.markers.sigma_px**2)))

    def with_rotation(self, theta_deg: float) -> Calibration:
        """A new Calibration whose mapping includes an extra rotation ``theta_deg`` (degrees;
        see :meth:`rspiv.Mapping.rotated`)."""
        new = Calibration(**self._fields())
        new.mapping = self.mapping.rotated(theta_deg)
        return new

    def _fields(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in (
            "markers", "mapping", "model", "model_reason", "models", "pitch_mm",
            "pitch_sigma_mm", "magnification", "magnification_sigma", "object_sigma_px",
            "object_sigma_source", "image_sigma_source", "image_shape", "marker", "size_px",
            "n_detected", "lattice", "warnings",
        )}  # fmt: skip

    def lattice_summary(self) -> str | None:
        """One line describing the lattice the grid indexing found (None for given points)."""
        la = self.lattice
        if la is None:
            return None
        return lattice_line(la)

    def report(self) -> CalibrationReport:
        """The quantities of the paper's Table 3 (and the model comparison)."""
        mk = self.markers
        ci = mk.image_px[mk.centre]
        co = mk.object_px[mk.centre]
        s = self.mapping.scale
        ih = (mk.image_px - ci) / s
        oh = (mk.object_px - co) / s
        return CalibrationReport(
            n_markers=len(mk),
            n_detected=self.n_detected,
            pitch_mm=self.pitch_mm,
            pitch_sigma_mm=self.pitch_sigma_mm,
            magnification=self.magnification,
            magnification_sigma=self.magnification_sigma,
            image_sigma_px=self.image_sigma_px,
            object_sigma_px=self.object_sigma_px,
            object_sigma_source=self.object_sigma_source,
            image_sigma_source=self.image_sigma_source,
            marker=self.marker,
            centre_image_px=[float(v) for v in ci],
            centre_object_px=[float(v) for v in co],
            x_o_max=float(s),
            image_hat_min=[float(v) for v in ih.min(axis=0)],
            image_hat_max=[float(v) for v in ih.max(axis=0)],
            object_hat_min=[float(v) for v in oh.min(axis=0)],
            object_hat_max=[float(v) for v in oh.max(axis=0)],
            models=self.models,
            model=self.model,
            model_reason=self.model_reason,
            image_shape=list(self.image_shape),
            lattice=lattice_to_json(self.lattice),
            warnings=list(self.warnings),
        )

    # -- files ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        mk = self.markers
        return {
            "format": FORMAT,
            "version": VERSION,
            "image_shape": list(self.image_shape),
            "pitch_mm": self.pitch_mm,
            "pitch_sigma_mm": self.pitch_sigma_mm,
            "magnification": self.magnification,
            "magnification_sigma": self.magnification_sigma,
            "object_sigma_px": self.object_sigma_px,
            "object_sigma_source": self.object_sigma_source,
            "image_sigma_source": self.image_sigma_source,
            "marker": self.marker,
            "size_px": self.size_px,
            "n_detected": self.n_detected,
            "model": self.model,
            "model_reason": self.model_reason,
            "models": self.models,
            "warnings": list(self.warnings),
            "lattice": lattice_to_json(self.lattice),
            "markers": {
                "image_px": mk.image_px.tolist(),
                "object_px": mk.object_px.tolist(),
                "cov_px2": mk.cov_px2.tolist(),
                "index": mk.index.tolist(),
                "centre": int(mk.centre),
                **({} if mk.object_mm is None else {"object_mm": mk.object_mm.tolist()}),
            },
            "mapping": json.loads(self.mapping.to_json()),
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the calibration as one JSON file (atomically: temp file + rename)."""
        path = pathlib.Path(path)
        text = json.dumps(self.to_dict(), indent=1)
        directory = path.parent if str(path.parent) else pathlib.Path(".")
        if not directory.is_dir():
            raise InvalidInputError(f"{path}: directory {directory} does not exist")
        atomic_write_text(path, text, make_parents=False)

    @classmethod
    def from_dict(cls, d: Any, name: str = "calibration") -> Calibration:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise InvalidInputError(f"{name}: not an rspiv calibration file")
        if d.get("version") != VERSION:
            raise InvalidInputError(f"{name}: unsupported version {d.get('version')!r}")
        try:
            m = d["markers"]
            markers = Markers(
                image_px=np.asarray(m["image_px"], dtype=np.float64).reshape(-1, 2),
                object_px=np.asarray(m["object_px"], dtype=np.float64).reshape(-1, 2),
                cov_px2=np.asarray(m["cov_px2"], dtype=np.float64).reshape(-1, 2, 2),
                index=np.asarray(m["index"], dtype=np.int64).reshape(-1, 2),
                centre=int(m["centre"]),
                object_mm=(
                    np.asarray(m["object_mm"], dtype=np.float64).reshape(-1, 2)
                    if "object_mm" in m
                    else None
                ),
            )
            om = markers.object_mm
            if not (len(markers.object_px) == len(markers.image_px) == len(markers.index)) or (
                om is not None and len(om) != len(markers.index)
            ):
                raise ValueError("marker arrays differ in length")
            mapping = Mapping.from_json(json.dumps(d["mapping"]))
            fields = {k: d[k] for k in (
                "model", "model_reason", "models", "pitch_mm", "pitch_sigma_mm",
                "magnification", "magnification_sigma", "object_sigma_px",
                "object_sigma_source", "image_shape", "marker", "size_px", "n_detected",
            )}  # fmt: skip
            # Optional keys (absent from older files and from rspiv-engine's).
            fields["image_sigma_source"] = str(d.get("image_sigma_source", DETECTOR))
            fields["warnings"] = _string_list(d.get("warnings", []))
            fields["lattice"] = lattice_from_json(d.get("lattice"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"{name}: corrupt calibration ({exc})") from None
        return cls(markers=markers, mapping=mapping, **fields)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a file written by :meth:`save`; InvalidInputError for unreadable/corrupt files."""
        path = pathlib.Path(path)
        try:
            d = json.loads(path.read_text())
        except OSError as exc:
            raise InvalidInputError(f"{path}: cannot read ({exc.strerror or exc})") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InvalidInputError(f"{path}: not valid JSON ({exc})") from None
        return cls.from_dict(d, str(path))

    def __repr__(self) -> str:
        return (
            f"Calibration({len(self.markers)} markers, model={self.model}, "
            f"M={self.magnification:.3f} px/mm, image {self.image_shape[1]}x{self.image_shape[0]})"
        )


def calibrate(
    image: Any,
    pitch_mm: float,
    model: str = "p3",
    marker: str = "dot",
    pitch_sigma_mm: float | None = None,
    *,
    marker_size_px: float | None = None,
    threshold: float = 0.25,
    min_snr: float = 8.0,
    dark: bool | None = None,
    profile: str = "auto",
    levels: int | None = None,
    level: int | None = None,
    grid_tolerance: float = 0.3,
    compare: bool = True,
    accept_poor_fit: bool = False,
) -> Calibration:
    """Calibrate from a target image.

    Parameters
    ----------
    image : array_like or path
        The target image (2D; uint8/uint16/float), or a TIFF/PNG/BMP/JPEG file.
    pitch_mm : float
        Marker pitch (mm), > 0.
    model : {"auto", "r1", "r2", "p3"}
        Mapping model; ``"auto"`` picks the smallest held-out (leave-one-out) error.
    marker : {"dot", "cross"}
        Marker shape.
    pitch_sigma_mm : float, optional
        Uncertainty of the pitch (mm); gives ``object_sigma_px = pitch_sigma_mm * M``. Default:
        estimated from the chosen fit's residuals beyond the image noise.
    marker_size_px : float, optional
        Marker size (Gaussian sigma, px); default read from the image (the size at which the
        detections form the strongest lattice, refined from the strongest markers' fits).
    threshold, min_snr : float
        Detection thresholds (fraction of the lattice's median correlation level, or of the
        strongest peak when size and polarity are both given; multiple of the correlation
        noise).
    dark : bool, optional
        Markers darker than the background; default found from the image (the polarity whose
        detections form the stronger lattice).
    profile : {"auto", "gaussian", "disc"}
        Dot profile of the sub-pixel fit: a Gaussian blob or a printed disc blurred by the lens;
        ``"auto"`` takes the disc when the strongest dots' Gaussian fits show a flat top.
    levels : {None, 1, 2}
        Levels of the plate; default read from the image (:mod:`rspiv.plate`: two interleaved
        lattices told apart by their scale or their dots; an ambiguous plate is refused).
    level : {None, 1, 2}
        The level to calibrate on (1 = the nearer); default the level holding the fiducial,
        else level 1. The grid origin ``(0, 0)`` is the fiducial when the level has one, else
        its marker nearest the image centre.
    grid_tolerance : float
        Grid acceptance radius as a fraction of the pitch.
    compare : bool
        Compare all models (residuals and held-out error). Forced on for ``model="auto"``.
    accept_poor_fit : bool
        Keep a fit whose residual RMS exceeds ``max(10 x`` the markers' image sigma, 0.5 px)
        (recorded in :attr:`Calibration.warnings`) instead of refusing it.

    Returns
    -------
    Calibration
        With :attr:`Calibration.lattice` (the lattice found) and :attr:`Calibration.warnings`
        (a residual RMS above 3 x the markers' image sigma).

    Raises
    ------
    InvalidInputError
        Unreadable file, blank image, no grid, pitch <= 0, too few markers for the model, a fit
        that does not follow the markers (see ``accept_poor_fit``).
    """
    pitch = check.positive("pitch_mm", pitch_mm)
    psig = None if pitch_sigma_mm is None else check.nonneg("pitch_sigma_mm", pitch_sigma_mm)
    model = check.model_name(model)
    img = read_image(image)
    h, w = img.shape
    if profile not in ("auto", "gaussian", "disc"):
        raise InvalidInputError(f"profile must be auto, gaussian or disc, got {profile!r}")
    det = _rspiv.detect_markers(
        img, marker, size_px=marker_size_px, threshold=threshold, min_snr=min_snr,
        dark=None if dark is None else bool(dark), profile=profile,
    )  # fmt: skip
    pts = det["image_px"]
    idx, found, _, a1, a2 = _rspiv.index_grid(
        pts, (0.5 * (w - 1), 0.5 * (h - 1)), grid_tolerance
    )
    centre_px = (0.5 * (w - 1), 0.5 * (h - 1))
    union = None
    if levels != 1:  # a two-level plate seen so obliquely that its union is no lattice
        union = union_of_levels(pts, idx, found, a1, a2, centre_px)
        if union is not None:
            idx, found, a1, a2 = union
    # a checkerboard's squares, indexed along their diagonals: refused before the levels
    f = np.asarray(found, dtype=bool)
    touch = (
        touching_dots(img, np.asarray(idx)[f], pts[f], det["amplitude"][f], bool(det["dark"]))
        if marker == "dot"
        else None
    )
    if touch is not None and not accept_poor_fit:
        raise InvalidInputError(f"calibration refused: {touch}; {KEEP_IT}")
    # A stepped target's other sections (the grid took the one at the centre: a lattice grown
    # from another could cross into its neighbours at another depth).
    others = [] if union is not None else other_lattices(pts, found, a1, a2, centre_px)
    size = np.where(det["radius_px"] > 0, det["radius_px"], det["width_px"])
    plate = analyse_plate(
        pts, idx, found, a1, a2, size, det["amplitude"], (h, w), levels=levels, level=level,
        image=img, dark=bool(det["dark"]), unfitted_px=det["rejected_px"],
    )  # fmt: skip
    size_px = float(det["size_px"])
    keep = np.flatnonzero(plate.use)
    lattice = lattice_record(pts, a1, a2, det, plate)
    # Isolated markers off their lattice (a dot half hidden, a glint) are left out and said so
    # (calibration_fit.lattice_outliers).
    out_rows, out_scale = lattice_outliers(plate.index[keep], pts[keep])
    outlier_note = []
    if len(out_rows):
        dropped = keep[out_rows]
        keep = np.delete(keep, out_rows)
        lattice["n_indexed"] -= len(dropped)
        lattice["n_rejected"] += len(dropped)
        lattice["rejected_px"] = np.vstack([lattice["rejected_px"], pts[dropped]])
        outlier_note.append(
            f"{len(dropped)} indexed marker(s) left out at "
            + ", ".join(f"({x:.0f}, {y:.0f})" for x, y in pts[dropped])
            + f" px: off the place their lattice neighbours predict by more than "
            f"{8 * out_scale:.3f} px (8 x the markers' scatter about it): a dot half hidden, "
            "a glint, or cut by the image's border?"
        )
    central = plate.central
    if central not in keep and len(keep):
        central = int(keep[np.argmin(np.hypot(*(pts[keep] - np.array(centre_px)).T))])
    # Other sections: the lattices beside the plate's that no level took.
    lattice["other_lattices"] = [
        n for n in (int(np.count_nonzero(g[1] & ~plate.indexed)) for g in others) if n >= 12
    ]
    # Too few markers for the model is its own (more specific) error, raised by the fit.
    needed = min(MIN_POINTS.values()) if model == "auto" else MIN_POINTS[model]
    problems = lattice_problems(lattice, plate.index[keep]) if len(keep) >= needed else []
    if touch is not None:
        problems.insert(0, touch)
    # Markers a sub-pixel fit cannot place (a wrong polarity or size, or no markers at all).
    cov = det["cov_px2"][keep]
    typical = float(np.sqrt(np.median(0.5 * (cov[:, 0, 0] + cov[:, 1, 1])))) if len(keep) else 0.0
    if typical > MAX_MARKER_SIGMA_PX:
        problems.append(
            f"the {len(keep)} indexed markers are poorly defined (median sigma {typical:.2f} px, "
            f"a target's is below {MAX_MARKER_SIGMA_PX} px): wrong polarity or size? (dark=, "
            "marker_size_px=)"
        )
    if problems and not accept_poor_fit:
        raise InvalidInputError(f"calibration refused: {problems[0]}; {KEEP_IT}")
    origin_of_points = _Origin(
        unit="markers", verb="indexed", marker=marker, size_px=size_px,
        n_detected=lattice["n_detected"], image_sigma_source=DETECTOR, lattice=lattice,
        warnings=tuple(f"kept (accept_poor_fit=True): {p}" for p in problems) + tuple(
            outlier_note
        ) + tuple(
            f"{len(lattice['other_lattices'])} other lattice(s) of the same pitch "
            f"({', '.join(map(str, lattice['other_lattices']))} markers) were left out: a "
            "stepped or 3-D target? the calibration holds for its one flat section"
            for _ in lattice["other_lattices"][:1]
        ),
    )  # fmt: skip
    return _calibrate_points(
        np.ascontiguousarray(pts[keep]),
        pitch * plate.index[keep].astype(np.float64),
        det["cov_px2"][keep],
        centre=int(np.flatnonzero(keep == central)[0]),
        pitch_mm=pitch,
        pitch_sigma_mm=psig,
        model=model,
        compare=compare,
        image_shape=(h, w),
        accept_poor_fit=accept_poor_fit,
        origin=origin_of_points,
    )


def calibrate_points(
    image_px: npt.ArrayLike,
    object_mm: npt.ArrayLike,
    *,
    image_shape: tuple[int, int],
    pitch_mm: float | None = None,
    model: str = "p3",
    cov_px2: npt.ArrayLike | None = None,
    sigma_px: float | npt.ArrayLike | None = None,
    pitch_sigma_mm: float | None = None,
    centre: int | None = None,
    compare: bool = True,
    accept_poor_fit: bool = False,
) -> Calibration:
    """Calibrate from marker positions found by another tool or by hand.

    The points go through the same path as :func:`calibrate` after its detection and indexing
    (magnification, object points, model comparison, fit, fit-quality check, uncertainties):
    given :func:`calibrate`'s own indexed markers it returns the same calibration.

    Parameters
    ----------
    image_px : array_like, shape (n, 2)
        Marker positions (x, y) on the image, px (README pixel frame).
    object_mm : array_like, shape (n, 2)
        The same markers' positions on the target plane, mm, row by row (any origin; x and y
        along the target's axes, e.g. ``pitch_mm * (i, j)``).
    image_shape : (int, int)
        (height, width) of the sensor, px.
    pitch_mm : float, optional
        Marker pitch (mm), > 0: the unit of :attr:`Markers.index` (``(object_mm -
        object_mm[centre]) / pitch_mm``, rounded) and of ``pitch_sigma_mm``. Default: the
        distance on the target from the central point to its nearest neighbour.
    model : {"auto", "r1", "r2", "p3"}
        Mapping model; ``"auto"`` picks the smallest held-out (leave-one-out) error.
    cov_px2 : array_like, shape (n, 2, 2), optional
        Covariance of each image position (px^2), symmetric positive definite.
    sigma_px : float or array_like (n,), optional
        Isotropic standard uncertainty of the image positions (px), > 0; instead of
        ``cov_px2``. When neither is given the image sigma is estimated from the chosen fit's
        residuals (:attr:`Calibration.image_sigma_source` says so, and a warning notes that the
        fit could not be checked against the markers' noise).
    pitch_sigma_mm : float, optional
        Uncertainty of the pitch (mm); gives ``object_sigma_px = pitch_sigma_mm * M``. Default:
        estimated from the chosen fit's residuals beyond the image noise.
    centre : int, optional
        Row of the central point (the origin of the object frame). Default: the point nearest
        the image centre.
    compare : bool
        Compare all models (residuals and held-out error). Forced on for ``model="auto"``.
    accept_poor_fit : bool
        Keep a fit whose residual RMS exceeds ``max(10 x`` the image sigma, 0.5 px) (recorded in
        :attr:`Calibration.warnings`) instead of refusing it.

    Returns
    -------
    Calibration
        ``marker == "points"``, ``size_px == 0``, ``lattice is None``.

    Raises
    ------
    InvalidInputError
        Shapes other than (n, 2) / (n, 2, 2), different row counts, NaN or inf (naming the
        row), points outside the image, repeated target positions, a bad image_shape, pitch or
        covariance, fewer points than the model needs, a central point without two neighbours,
        a fit that does not follow the points (see ``accept_poor_fit``).
    """
    model = check.model_name(model)
    shape = check.image_shape(image_shape)
    img = check.rows("image_px", image_px)
    obj = check.rows("object_mm", object_mm)
    if len(img) != len(obj):
        raise InvalidInputError(
            f"image_px has {len(img)} rows and object_mm {len(obj)}: they must pair up row by row"
        )
    check.inside_image(img, shape)
    check.distinct("object_mm", obj)
    cov = check.covariance(cov_px2, sigma_px, len(img))
    pitch = None if pitch_mm is None else check.positive("pitch_mm", pitch_mm)
    psig = None if pitch_sigma_mm is None else check.nonneg("pitch_sigma_mm", pitch_sigma_mm)
    if centre is None:
        mid = np.array([0.5 * (shape[1] - 1), 0.5 * (shape[0] - 1)])
        c = int(np.argmin(np.hypot(*(img - mid).T))) if len(img) else 0
    elif isinstance(centre, bool) or not isinstance(centre, (int, np.integer)):
        raise InvalidInputError(f"centre must be a row number, got {centre!r}")
    elif not 0 <= int(centre) < len(img):
        raise InvalidInputError(f"centre {centre} is out of range for {len(img)} points")
    else:
        c = int(centre)
    origin = _Origin(
        unit="points", verb="given", marker=POINTS, size_px=0.0, n_detected=len(img),
        image_sigma_source="given cov_px2" if cov_px2 is not None else "given sigma_px",
    )  # fmt: skip
    return _calibrate_points(
        img, obj, cov, centre=c, pitch_mm=pitch, pitch_sigma_mm=psig, model=model,
        compare=compare, image_shape=shape, accept_poor_fit=accept_poor_fit, origin=origin,
    )  # fmt: skip


@dataclass(frozen=True)
class _Origin:
    """Where the points of a calibration come from: the wording of messages (``unit``,
    ``verb``: "markers"/"indexed", "points"/"given") and the detector's fields."""

    unit: str
    verb: str
    marker: str
    size_px: float
    n_detected: int
    image_sigma_source: str
    lattice: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()

    @property
    def one(self) -> str:
        """The singular of ``unit``."""
        return self.unit[:-1]

    def what(self, n: int) -> str:
        """``"91 indexed markers"``, ``"40 given points"``."""
        return f"{n} {self.verb} {self.unit}"


def _calibrate_points(
    image_px: np.ndarray,
    object_mm: np.ndarray,
    cov_px2: np.ndarray | None,
    *,
    centre: int,
    pitch_mm: float | None,
    pitch_sigma_mm: float | None,
    model: str,
    compare: bool,
    image_shape: tuple[int, int],
    accept_poor_fit: bool,
    origin: _Origin,
) -> Calibration:
    """The one path from paired points to a Calibration (validated inputs; ``cov_px2`` None:
    estimated from the fit residuals)."""
    n = len(image_px)
    if model == "auto" and n < min(MIN_POINTS.values()):
        raise InvalidInputError(
            f"calibration: no model can be fitted to {origin.what(n)} "
            f"(r1 needs at least {MIN_POINTS['r1']})"
        )
    if model != "auto" and n < MIN_POINTS[model]:
        raise InvalidInputError(
            f"calibration: model {model} needs at least {MIN_POINTS[model]} {origin.unit}, "
            f"{n} were {origin.verb}"
        )
    mag, mag_sigma, nearest_mm = magnification(image_px, object_mm, centre, origin.one)
    pitch = nearest_mm if pitch_mm is None else pitch_mm
    rel = object_mm - object_mm[centre]
    object_px = np.ascontiguousarray(image_px[centre] + mag * rel)
    index = np.rint(rel / pitch).astype(np.int64)
    models = compare_models(object_px, image_px, centre) if (compare or model == "auto") else {}
    model, reason = choose_model(model, models, origin.what(n))
    scale = float(np.max(np.abs(object_px[:, 0])))
    mapping = fit_mapping(object_px, image_px, model, center_index=centre, scale=scale)
    if model not in models:
        models[model] = fit_stats(mapping, None)  # held-out error not computed (compare=False)
    res = np.asarray(mapping.residuals)
    mean_sq = float(np.mean(res**2))  # per axis, px^2
    dof = max(1e-9, 1.0 - N_PARAMS[model] / (2.0 * n))
    estimated = cov_px2 is None
    warnings: list[str] = list(origin.warnings)
    sigma_source = origin.image_sigma_source
    if estimated:
        cov_px2 = np.tile(np.eye(2) * (mean_sq / dof), (n, 1, 1))
        sigma_source = f"{model} fit residuals (no cov_px2 or sigma_px given)"
        warnings.append(
            f"the image sigma was estimated from the {model} fit residuals (no cov_px2 or "
            "sigma_px given): the fit could not be checked against the markers' noise"
        )
    markers = Markers(
        image_px=image_px, object_px=object_px, cov_px2=cov_px2, index=index, centre=centre,
        object_mm=np.array(object_mm, dtype=np.float64),
    )  # fmt: skip
    image_var = float(np.mean(markers.sigma_px**2))
    if not estimated:
        # The typical marker (median: one bad blob must not raise the bar), and the target's
        # own errors when the user states them.
        typical = float(np.median(np.mean(markers.sigma_px**2, axis=1)))
        target = 0.0 if pitch_sigma_mm is None else (pitch_sigma_mm * mag) ** 2
        warnings += check_fit(
            model, float(np.sqrt(mean_sq)), float(np.sqrt(typical + target)), origin.what(n),
            mag * pitch, accept_poor_fit,
        )  # fmt: skip
    if pitch_sigma_mm is not None:
        osig, source, pitch_sigma = pitch_sigma_mm * mag, "pitch_sigma_mm * M", pitch_sigma_mm
    else:
        # Nothing is left beyond an image sigma estimated from these very residuals.
        excess = 0.0 if estimated else mean_sq / dof - image_var
        osig = float(np.sqrt(max(0.0, excess)))
        source = f"{model} residuals beyond the image noise" + (
            " (none: the image sigma comes from the same residuals)" if estimated else ""
        )
        pitch_sigma = osig / mag
    return Calibration(
        markers=markers,
        mapping=mapping,
        model=model,
        model_reason=reason,
        models=models,
        pitch_mm=pitch,
        pitch_sigma_mm=pitch_sigma,
        magnification=mag,
        magnification_sigma=mag_sigma,
        object_sigma_px=osig,
        object_sigma_source=source,
        image_sigma_source=sigma_source,
        image_shape=image_shape,
        marker=origin.marker,
        size_px=origin.size_px,
        n_detected=origin.n_detected,
        lattice=origin.lattice,
        warnings=warnings,
    )


def _string_list(v: Any) -> list[str]:
    if not isinstance(v, list) or not all(isinstance(w, str) for w in v):
        raise ValueError("warnings is not a list of strings")
    return list(v)
