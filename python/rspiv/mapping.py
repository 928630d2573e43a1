"""Mapping models object px -> image px: fit, forward and inverse maps, rotation, files.

Conventions
-----------
Points are ``(N, 2)`` float arrays of ``(x, y)`` in the pixel frame of the README (x = column,
y = row, origin at the centre of the top-left pixel, y down). *Object px* is the dewarped
image's pixel frame, *image px* the raw camera image's. A mapping goes from object to image:

    P_i = c_i + s R(theta) F((P_o - c_o) / s)

with ``c_o``/``c_i`` the object/image points of the central marker, ``s`` the normalising scale
(the paper's ``x_o_max``), ``F`` the model in normalised coordinates and ``R(theta)`` a rotation
(radians, counter-clockwise in the (x, y) axes). Models (DESIGN.md "Mapping models"):

- ``"r1"``: first-order rational (projective), 8 coefficients;
- ``"r2"``: second-order rational with a shared denominator, 17 free coefficients (the paper's
  18 includes the fixed ``a33 = 1``);
- ``"p3"``: bicubic polynomial, 20 coefficients, solved directly by QR.

R1/R2 are fitted by rspiv's own Levenberg-Marquardt solver, started from the linearised
(DLT-style) solution, at tolerances near double precision.
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv.errors import ConvergenceError, InvalidInputError
from rspiv.outputs import atomic_write_text
from rspiv.settings import MODELS as SETTINGS_MODELS

MODELS = SETTINGS_MODELS  # the one vocabulary (rspiv.settings)

__all__ = ["MODELS", "Mapping", "fit_mapping"]


def as_points(name: str, a: Any) -> np.ndarray:
    """``a`` as a C-contiguous float64 ``(N, 2)`` array, or InvalidInputError (shared with the
    calibration's input checks)."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name}: not an array of numbers ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InvalidInputError(f"{name} must have shape (n, 2), got {arr.shape}")
    return np.ascontiguousarray(arr)


class Mapping:
    """A fitted mapping object px -> image px.

    Create one with :func:`fit_mapping` or :meth:`Mapping.load`; a mapping is immutable
    (:meth:`rotated` returns a new one).

    Attributes
    ----------
    model : str
        ``"r1"``, ``"r2"`` or ``"p3"``.
    coefficients : ndarray, shape (P,)
        Model coefficients in normalised coordinates.
    centre_object, centre_image : tuple of float
        Object px / image px of the central marker (the normalised origins).
    scale : float
        Normalising scale ``s`` in px.
    rotation : float
        Rotation ``theta`` in radians applied after the model.
    residuals : ndarray, shape (N, 2)
        Fit residuals in image px, fitted minus measured (without rotation).
    stats : dict
        ``max_abs_px``, ``mean_px``, ``rms_px`` (each a pair x, y, in image px), ``n_points``,
        ``model``, and the solver's ``cost``, ``termination``, ``n_evals``.
    covariance : ndarray, shape (P, P)
        Coefficient covariance ``s^2 (J^T J)^-1`` (normalised units).
    """

    __slots__ = ("_native",)

    def __init__(self, native: _rspiv.NativeMapping) -> None:
        if not isinstance(native, _rspiv.NativeMapping):
            raise TypeError("Mapping wraps a native mapping; use rspiv.fit_mapping or Mapping.load")
        self._native = native

    # -- maps ---------------------------------------------------------------------------------
    def forward(self, object_px: npt.ArrayLike) -> np.ndarray:
        """Map object px to image px.

        Parameters
        ----------
        object_px : array_like, shape (N, 2)
            Object points (x, y) in object px.

        Returns
        -------
        ndarray, shape (N, 2)
            Image points in image px (rotation included). Vectorised in Rust, GIL released.
        """
        return self._native.forward(as_points("object_px", object_px))

    def forward_jacobian(self, object_px: npt.ArrayLike) -> np.ndarray:
        """``d(image px) / d(object px)`` at each object point, shape (N, 2, 2):
        ``J[k] = [[dxi/dxo, dxi/dyo], [dyi/dxo, dyi/dyo]]``."""
        return self._native.forward_jacobian(as_points("object_px", object_px))

    def inverse(self, image_px: npt.ArrayLike, *, on_fail: str = "raise") -> np.ndarray:
        """Map image px to object px by Newton's method on the analytic Jacobian.

        Parameters
        ----------
        image_px : array_like, shape (N, 2)
            Image points (x, y) in image px.
        on_fail : {"raise", "nan"}
            What to do with points where Newton does not converge to 1e-6 px (e.g. outside the
            region where the mapping is invertible): raise :class:`rspiv.ConvergenceError`
            naming them, or return NaN for those rows. Rows with NaN/inf input come back as NaN
            either way.

        Returns
        -------
        ndarray, shape (N, 2)
            Object points in object px; ``forward(inverse(p))`` equals ``p`` to 1e-6 px.
        """
        if on_fail not in ("raise", "nan"):
            raise InvalidInputError(f'on_fail must be "raise" or "nan", got {on_fail!r}')
        pts = as_points("image_px", image_px)
        out, ok = self._native.inverse(pts)
        finite = np.isfinite(pts).all(axis=1)
        out[~finite] = np.nan  # NaN in, NaN out (e.g. masked vectors): not a failure
        if not ok[finite].all():
            bad = np.flatnonzero(~ok & finite)
            if on_fail == "raise":
                shown = ", ".join(f"{i} ({pts[i, 0]:g}, {pts[i, 1]:g})" for i in bad[:5])
                more = f" and {bad.size - 5} more" if bad.size > 5 else ""
                raise ConvergenceError(
                    f"inverse map did not converge for {bad.size} of {len(pts)} image points: "
                    f"{shown}{more}"
                )
            out[bad] = np.nan
        return out

    def rotated(self, theta_deg: float) -> Mapping:
        """A new mapping with an extra rotation ``R(theta)`` after this one.

        ``theta_deg`` (degrees, counter-clockwise in the (x, y) axes) is added to the current
        rotation, so ``m.rotated(a).rotated(b) == m.rotated(a + b)``. For the wall alignment
        use the negative of the wall angle measured after dewarping (paper section 3.2).
        """
        theta = float(theta_deg)
        if not np.isfinite(theta):
            raise InvalidInputError(f"rotation angle must be finite, got {theta_deg!r}")
        return Mapping(self._native.with_rotation(self._native.rotation + np.deg2rad(theta)))

    # -- attributes ---------------------------------------------------------------------------
    @property
    def model(self) -> str:
        return self._native.model

    @property
    def coefficients(self) -> np.ndarray:
        return self._native.coefficients

    @property
    def centre_object(self) -> tuple[float, float]:
        return self._native.centre_object

    @property
    def centre_image(self) -> tuple[float, float]:
        return self._native.centre_image

    @property
    def scale(self) -> float:
        return self._native.scale

    @property
    def rotation(self) -> float:
        return self._native.rotation

    @property
    def residuals(self) -> np.ndarray:
        return self._native.residuals

    @property
    def stats(self) -> dict[str, Any]:
        return self._native.stats

    @property
    def covariance(self) -> np.ndarray:
        return self._native.covariance

    # -- files --------------------------------------------------------------------------------
    def to_json(self) -> str:
        """The mapping as JSON text (format tag ``rspiv-mapping``, version 1)."""
        return self._native.to_json()

    @classmethod
    def from_json(cls, text: str) -> Mapping:
        """Parse JSON written by :meth:`to_json`; InvalidInputError for corrupt/foreign text."""
        if not isinstance(text, str):
            raise InvalidInputError(f"mapping JSON must be text, got {type(text).__name__}")
        return cls(_rspiv.NativeMapping.from_json(text))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the mapping as JSON to ``path`` atomically (temporary file + rename)."""
        atomic_write_text(path, self.to_json() + "\n", make_parents=False)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Mapping:
        """Read a mapping written by :meth:`save`.

        Raises
        ------
        InvalidInputError
            If the file is not UTF-8 JSON of an rspiv mapping (the message names the file).
        OSError
            If the file cannot be read.
        """
        try:
            text = pathlib.Path(path).read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise InvalidInputError(f"{path}: not a text (JSON) file ({exc.reason})") from None
        try:
            return cls.from_json(text)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{path}: {exc}") from None

    def __repr__(self) -> str:
        rms = self.stats["rms_px"]
        return (
            f"Mapping(model={self.model!r}, n_points={self.stats['n_points']}, "
            f"rms_px=({rms[0]:.4g}, {rms[1]:.4g}), rotation_deg={np.rad2deg(self.rotation):.6g})"
        )


def fit_mapping(
    object_px: npt.ArrayLike,
    image_px: npt.ArrayLike,
    model: str = "p3",
    *,
    center_index: int | None = None,
    scale: float | None = None,
) -> Mapping:
    """Fit a mapping model to point pairs.

    Parameters
    ----------
    object_px : array_like, shape (N, 2)
        Object points (x, y) in object px (e.g. the target's marker grid).
    image_px : array_like, shape (N, 2)
        The measured image points (x, y) in image px, in the same order.
    model : {"r1", "r2", "p3"}
        Mapping model (case-insensitive).
    center_index : int, optional
        Index of the central marker (origin of the normalised frames). Default: the object point
        nearest the centroid of the object points.
    scale : float, optional
        Normalising scale in px. Default: ``max |x_o|`` (the paper's ``x_o_max``).

    Returns
    -------
    Mapping

    Raises
    ------
    InvalidInputError
        Shapes, NaN/inf, fewer points than the model needs, duplicate or collinear points,
        degenerate geometry, unknown model.
    ConvergenceError
        If Levenberg-Marquardt exhausts its evaluations (R1/R2).
    """
    if not isinstance(model, str) or model.strip().lower() not in MODELS:
        raise InvalidInputError(
            f"unknown mapping model {model!r} (expected one of {', '.join(MODELS)})"
        )
    obj = as_points("object_px", object_px)
    img = as_points("image_px", image_px)
    if obj.shape != img.shape:
        raise InvalidInputError(
            f"object_px {obj.shape} and image_px {img.shape} must have the same shape"
        )
    if center_index is not None:
        if isinstance(center_index, bool) or not isinstance(center_index, (int, np.integer)):
            raise InvalidInputError(f"center_index must be an integer, got {center_index!r}")
        if not 0 <= int(center_index) < len(obj):
            raise InvalidInputError(
                f"center_index {center_index} is out of range for {len(obj)} points"
            )
        center_index = int(center_index)
    if scale is not None:
        scale = float(scale)
    return Mapping(_rspiv.fit_mapping(obj, img, model.strip().lower(), center_index, scale))
