"""Calibration from a target image (paper section 3.1; DESIGN.md "Calibration from a target
image"): sub-pixel markers with their uncertainty, grid indexing, magnification, object points,
and the choice of mapping model by held-out error.

Frames
------
Image px: the raw camera image (README pixel frame: x = column, y = row, origin at the centre of
the top-left pixel, y down). Object px: the dewarped frame, an axis-aligned square grid whose
origin is the central marker: ``P_o = P_ic + M * pitch_mm * (i, j)``, with ``P_ic`` the image
position of the central marker (the marker nearest the image centre), ``(i, j)`` the grid index
(i along +x, j along +y) and ``M`` the magnification measured from the central marker and its four
neighbours. A target rotation on the sensor is thus part of the mapping (see
:meth:`Calibration.with_rotation` for the wall-alignment correction).
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
from rspiv.errors import InvalidInputError, RspivError
from rspiv.io import read_image
from rspiv.mapping import MODELS, Mapping, fit_mapping
from rspiv.outputs import atomic_write_text

__all__ = [
    "Markers",
    "Calibration",
    "CalibrationReport",
    "calibrate",
    "compare_models",
]

FORMAT = "rspiv-calibration"
VERSION = 1


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
    """

    image_px: np.ndarray
    object_px: np.ndarray
    cov_px2: np.ndarray
    index: np.ndarray
    centre: int

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
        lines = [
            f"markers                      {r['n_markers']} indexed of {r['n_detected']} detected",
            f"pitch (mm)                   {r['pitch_mm']:.3f} +/- {r['pitch_sigma_mm']:.3f}",
            "magnification M (px/mm)      {:.3f} +/- {:.3f}".format(
                r["magnification"], r["magnification_sigma"]
            ),
            "image sigma (px)             {:.4f}".format(r["image_sigma_px"]),
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
        return "\n".join(lines)


def _fmt_loo(v: Any) -> str:
    return "        -" if v is None else f"{v:9.4f}"


def _loo_rms(obj: np.ndarray, img: np.ndarray, centre: int, model: str, scale: float) -> float:
    """RMS held-out error (px): each non-central marker predicted by a fit without it."""
    errs = []
    n = len(obj)
    for k in range(n):
        if k == centre:
            continue
        keep = np.arange(n) != k
        c = centre - (1 if k < centre else 0)
        m = fit_mapping(obj[keep], img[keep], model, center_index=c, scale=scale)
        errs.append(np.sum((m.forward(obj[k : k + 1])[0] - img[k]) ** 2))
    return float(np.sqrt(np.mean(errs)))


def compare_models(
    object_px: npt.ArrayLike,
    image_px: npt.ArrayLike,
    centre: int,
    models: tuple[str, ...] = MODELS,
) -> dict[str, dict[str, Any]]:
    """Fit each model and measure its residuals and its leave-one-out (held-out) error.

    Returns ``{model: {"max_abs_px", "mean_px", "rms_px", "loo_rms_px"}}`` for the models that
    have enough markers; models that cannot be fitted are left out.
    """
    obj = np.asarray(object_px, dtype=np.float64)
    img = np.asarray(image_px, dtype=np.float64)
    scale = float(np.max(np.abs(obj[:, 0])))
    out: dict[str, dict[str, Any]] = {}
    for model in models:
        try:
            m = fit_mapping(obj, img, model, center_index=centre, scale=scale)
            loo = _loo_rms(obj, img, centre, model, scale)
        except RspivError:
            continue
        st = m.stats
        out[model] = {
            "max_abs_px": [float(v) for v in st["max_abs_px"]],
            "mean_px": [float(v) for v in st["mean_px"]],
            "rms_px": [float(v) for v in st["rms_px"]],
            "loo_rms_px": loo,
        }
    return out


class Calibration:
    """A camera calibration from a target image.

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
        M (px/mm) from the central marker and its four neighbours, and the standard deviation
        of those four estimates.
    object_sigma_px : float
        Uncertainty of the object points, px: ``pitch_sigma_mm * M`` when the pitch uncertainty
        is given, else estimated from the chosen fit's residuals beyond the image noise.
    object_sigma_source : str
    image_shape : tuple of int
        (height, width) of the calibrated sensor.
    marker : str
    size_px : float
        Marker size used by the detector (Gaussian sigma, px).
    n_detected : int
        Blobs detected (markers + rejected spurious blobs).
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
        self.image_shape: tuple[int, int] = (int(kw["image_shape"][0]), int(kw["image_shape"][1]))
        self.marker: str = kw["marker"]
        self.size_px: float = float(kw["size_px"])
        self.n_detected: int = int(kw["n_detected"])

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
            "object_sigma_source", "image_shape", "marker", "size_px", "n_detected",
        )}  # fmt: skip

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
            "marker": self.marker,
            "size_px": self.size_px,
            "n_detected": self.n_detected,
            "model": self.model,
            "model_reason": self.model_reason,
            "models": self.models,
            "markers": {
                "image_px": mk.image_px.tolist(),
                "object_px": mk.object_px.tolist(),
                "cov_px2": mk.cov_px2.tolist(),
                "index": mk.index.tolist(),
                "centre": int(mk.centre),
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
            )
            if not (len(markers.object_px) == len(markers.image_px) == len(markers.index)):
                raise ValueError("marker arrays differ in length")
            mapping = Mapping.from_json(json.dumps(d["mapping"]))
            fields = {k: d[k] for k in (
                "model", "model_reason", "models", "pitch_mm", "pitch_sigma_mm",
                "magnification", "magnification_sigma", "object_sigma_px",
                "object_sigma_source", "image_shape", "marker", "size_px", "n_detected",
            )}  # fmt: skip
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
    dark: bool = False,
    grid_tolerance: float = 0.3,
    compare: bool = True,
) -> Calibration:
    """Calibrate from a target image.

    Parameters
    ----------
    image : array_like or path
        The target image (2D; uint8/uint16/float), or a TIFF/PNG/BMP file.
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
        Marker size (Gaussian sigma, px); default estimated from the image.
    threshold, min_snr : float
        Detection thresholds (fraction of the strongest correlation peak; multiple of the
        correlation noise).
    dark : bool
        Markers darker than the background.
    grid_tolerance : float
        Grid acceptance radius as a fraction of the pitch.
    compare : bool
        Compare all models (residuals and held-out error). Forced on for ``model="auto"``.

    Returns
    -------
    Calibration

    Raises
    ------
    InvalidInputError
        Unreadable file, blank image, no grid, pitch <= 0, too few markers for the model.
    """
    pitch = _positive("pitch_mm", pitch_mm)
    psig = None if pitch_sigma_mm is None else _nonneg("pitch_sigma_mm", pitch_sigma_mm)
    if not isinstance(model, str) or model.lower() not in (*MODELS, "auto"):
        raise InvalidInputError(f"unknown model {model!r} (expected auto, r1, r2 or p3)")
    model = model.lower()
    img = read_image(image)
    h, w = img.shape
    det = _rspiv.detect_markers(
        img, marker, size_px=marker_size_px, threshold=threshold, min_snr=min_snr, dark=dark
    )
    pts = det["image_px"]
    idx, found, origin, _, _ = _rspiv.index_grid(
        pts, (0.5 * (w - 1), 0.5 * (h - 1)), grid_tolerance
    )
    keep = np.flatnonzero(found)
    image_px = np.ascontiguousarray(pts[keep])
    index = idx[keep].astype(np.int64)
    cov = det["cov_px2"][keep]
    centre = int(np.flatnonzero(keep == origin)[0])
    # Magnification from the central marker and its (up to) four neighbours.
    pc = image_px[centre]
    dists = []
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        hit = np.flatnonzero((index[:, 0] == di) & (index[:, 1] == dj))
        if len(hit):
            dists.append(float(np.hypot(*(image_px[hit[0]] - pc))))
    if len(dists) < 2:
        raise InvalidInputError("calibration: the central marker has fewer than 2 neighbours")
    mag = float(np.mean(dists)) / pitch
    mag_sigma = float(np.std(dists, ddof=1)) / pitch
    object_px = np.ascontiguousarray(pc + mag * pitch * index.astype(np.float64))
    needed = {"r1": 5, "r2": 9, "p3": 11}
    if model != "auto" and len(image_px) < needed[model]:
        raise InvalidInputError(
            f"calibration: model {model} needs at least {needed[model]} markers, "
            f"{len(image_px)} were indexed"
        )
    models = compare_models(object_px, image_px, centre) if (compare or model == "auto") else {}
    if model == "auto":
        if not models:
            raise InvalidInputError(
                f"calibration: no model can be fitted to {len(image_px)} indexed markers"
            )
        ranked = sorted(models, key=lambda m: models[m]["loo_rms_px"])
        model = ranked[0]
        reason = "smallest held-out error: " + " < ".join(
            f"{m} {models[m]['loo_rms_px']:.4f} px" for m in ranked
        )
    else:
        reason = "chosen by the user"
        if model in models and len(models) > 1:
            best = min(models, key=lambda m: models[m]["loo_rms_px"])
            if best != model:
                reason += f" (note: {best} has a smaller held-out error)"
    scale = float(np.max(np.abs(object_px[:, 0])))
    mapping = fit_mapping(object_px, image_px, model, center_index=centre, scale=scale)
    if model not in models:
        st = mapping.stats
        models[model] = {
            "max_abs_px": [float(v) for v in st["max_abs_px"]],
            "mean_px": [float(v) for v in st["mean_px"]],
            "rms_px": [float(v) for v in st["rms_px"]],
            "loo_rms_px": None,  # not computed (compare=False)
        }
    markers = Markers(
        image_px=image_px, object_px=object_px, cov_px2=cov, index=index, centre=centre
    )
    if psig is not None:
        osig, source = psig * mag, "pitch_sigma_mm * M"
        pitch_sigma = psig
    else:
        res = np.asarray(mapping.residuals)
        dof = max(1.0, 1.0 - mapping.coefficients.size / (2.0 * len(res)))
        excess = float(np.mean(res**2)) / dof - float(np.mean(markers.sigma_px**2))
        osig = float(np.sqrt(max(0.0, excess)))
        source = f"{model} residuals beyond the image noise"
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
        image_shape=(h, w),
        marker=marker,
        size_px=float(det["size_px"]),
        n_detected=len(pts),
    )


def _positive(name: str, v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {v!r}") from None
    if not (np.isfinite(f) and f > 0):
        raise InvalidInputError(f"{name} must be > 0, got {v!r}")
    return f


def _nonneg(name: str, v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {v!r}") from None
    if not (np.isfinite(f) and f >= 0):
        raise InvalidInputError(f"{name} must be >= 0, got {v!r}")
    return f
