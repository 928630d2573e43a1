"""Multigrid / multipass FFT cross-correlation PIV: the user-facing :func:`piv` and
:func:`piv_at`.

Coordinates follow the pixel frame of the README: x = column (right), y = row (down), origin at
the centre of the top-left pixel; displacements ``u`` (along x) and ``v`` (along y, positive
downward) are in pixels.

Windows are given as ``(w, h)``: ``w`` px wide along x and ``h`` px tall along y, so ``(32, 8)``
is 32 px streamwise by 8 px wall-normal when the flow runs along x (the paper's final window).

The keyword arguments are a thin shim over :class:`rspiv.PivSettings`; the native driver is
:mod:`rspiv.multipass` and the distortion correction (``calibration`` and ``method``)
:mod:`rspiv.correction`. :class:`PivField` (:mod:`rspiv.field`) is re-exported here.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv import _rspiv
from rspiv.correction import correct
from rspiv.errors import CorrelationWarning, InvalidInputError, ParticleSizeWarning
from rspiv.field import PivField
from rspiv.multipass import run_grid, run_points
from rspiv.particle_size import as_recorded, warnings_for
from rspiv.preprocess import Preprocess, condition_pair
from rspiv.settings import OPTION_KEYS, PivSettings, parse_mapping_mode, parse_method

__all__ = ["PivField", "piv", "piv_at", "window_response"]


def window_response(weighting: str, n: int, wavelength: float) -> float:
    """The spatial response of an interrogation window: the amplitude ratio with which an
    ``n`` px window weighted by ``weighting`` returns a displacement ``A sin(2 pi y / L)``
    varying along its ``n`` px axis, ``L = wavelength`` px.

    ``H(L) = sum_j p(j) cos(2 pi (j - (n - 1) / 2) / L)`` with the pixel weights ``p = w**2 /
    sum(w**2)`` of the weighting window ``w`` (both windows of a pair are weighted, so a
    particle pair counts with ``w**2``; ``piv_core::weighting``). The top-hat gives the
    discrete ``sinc(n / L)`` (0.900 at ``L = 4 n``, 0 at ``L = n``, negative between ``n / 2``
    and ``n``); "gaussian" and "blackman" stay positive down to ``L = n / 2``. This is the
    response of :func:`piv` for any number of passes and iterations (deformation), within a
    few percent where the particle images resolve the wavelength.

    Parameters
    ----------
    weighting : {"tophat", "gaussian", "blackman"}
    n : int
        Window size along the axis, px.
    wavelength : float
        Wavelength of the displacement, px.

    Returns
    -------
    float

    Raises
    ------
    InvalidInputError
        An unknown weighting, ``n`` or ``wavelength`` not positive.
    """
    return float(_rspiv.window_response(str(weighting), int(n), float(wavelength)))


def piv(
    frame_a,
    frame_b,
    passes: Sequence[tuple[int, int]] = ((64, 64), (32, 32), (32, 8)),
    overlap: float | Sequence[float] = 0.5,
    deformation: str = "symmetric",
    mask=None,
    calibration: Any = None,
    method: str | None = None,
    mapping: str = "full",
    *,
    iterations: int | Sequence[int] = 1,
    subpixel: str = "gauss3",
    interpolation: str = "bspline",
    weighting: str = "tophat",
    validate: bool = True,
    median_eps: float = 0.1,
    median_threshold: float = 2.0,
    min_peak_ratio: float = 0.0,
    peak_candidates: int = 3,
    uncertainty: bool = True,
    roi: tuple[int, int, int, int] | None = None,
    settings: PivSettings | None = None,
    preprocess: Preprocess | None = None,
    backgrounds: tuple[Any, Any] | None = None,
) -> PivField:
    """Multipass PIV of a frame pair on a regular grid.

    Without ``calibration`` the field is in the image frame (px). With a ``calibration`` and a
    ``method`` the lens distortion is corrected and the field lies on the regular object grid
    (the grid of the last pass on object-frame images of the frames' shape), ``x``, ``y``, ``u``,
    ``v`` in object px:

    - ``method="images"`` (Method I): both frames (and the mask) are dewarped with the
      calibration (:func:`rspiv.dewarp`), then the regular PIV runs on them; vectors centred in
      the zero fill (object points imaged outside the sensor) are not computed (masked).
    - ``method="vectors"`` (Method II): PIV on the raw frames at the images of the object grid,
      displacements mapped to the object frame (:func:`rspiv.correction.piv_vectors`, with
      ``mapping``).

    The keywords are a shim over :class:`rspiv.PivSettings` (the one vocabulary shared with the
    campaign file and the Rust CLI); pass ``settings=`` to give them as one object instead
    (the window/validation keywords must then be left at their defaults). The correction itself
    is :func:`rspiv.correction.correct`.

    Windows that reach past the image edge (after offset and deformation) or whose content is
    blank (zero variance, e.g. zero fill) are not correlated: ``valid`` is False and ``replaced``
    True (their value is interpolated from the valid neighbours).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D, same shape
        The two exposures, ``image[y, x]``. uint8, uint16, float32 and float64 are read in place
        (no copy for C-contiguous arrays); other dtypes are converted to float32.
    passes : sequence of (w, h)
        Window sizes in px from coarse to fine; ``w`` along x, ``h`` along y. The grid of the
        last pass is the output grid (centred in the image, every window inside it).
    overlap : float or sequence of float
        Fractional window overlap in [0, 1), one value or one per pass.
    deformation : {"symmetric", "offset"}
        How later passes follow the previous field: symmetric image deformation (interpolated
        with ``interpolation``) or a symmetric sub-pixel window offset.
    mask : ndarray of bool, optional
        Same shape as the frames, True = excluded; vectors centred on it are not computed.
    calibration : Calibration or Mapping, optional
        Object px -> image px; requires ``method``.
    method : {"images", "vectors"} or {"I", "II"}, optional
        Distortion correction with ``calibration``: Method I (dewarp the images) or Method II
        (map the vectors); see above (any case). Requires ``calibration``.
    mapping : {"full", "positions"}
        Method II's displacement mapping (:mod:`rspiv.correction`); ignored by Method I.
    iterations : int or sequence of int
        Correlation iterations per pass (each re-deforms with the latest field). The extra
        iterations of a pass are under-relaxed (each moves the field 0.4 of the way to the
        new estimate, ``piv_core::multipass::RELAXATION``) so that each is at least as
        accurate as the one before.
    subpixel : {"gauss3", "gauss2d"}
        3-point Gaussian per axis, or a 9-point 2D Gaussian least-squares fit.
    interpolation : {"bspline", "bspline3", "keys"}
        Interpolation of the frames at the fractional positions of deformed or offset windows:
        quintic B-spline (default; exact mirror-boundary prefilter, 6 x 6 taps applied as two
        1D passes; its bias on 2.5 px particles is below 0.006 px), cubic B-spline (as
        scipy's ``order=3`` and openpiv.windef; up to 0.018 px bias at half-pixel shifts) or
        Keys bicubic (a = -0.5), which biases sub-pixel shifts of 2-3 px particles by a few
        0.01 px.
    weighting : {"tophat", "gaussian", "blackman"}
        Weighting window of the interrogation windows (:class:`rspiv.PivSettings`): the
        top-hat (default, the most accurate on smooth flows) or a taper whose spatial response
        has no sign reversal at wavelengths shorter than the window, for more random error.
    validate : bool
        Normalised median test with replacement after every iteration.
    median_eps, median_threshold : float
        Noise level (px) and threshold of the normalised median test.
    min_peak_ratio : float
        Reject vectors whose peak ratio is below this (0 disables).
    peak_candidates : int
        Correlation peaks tried per vector (1 to 3): a vector that fails the median test takes
        its second or third peak when that passes the test, before it is interpolated
        (``PivField.peak_choice``, :meth:`PivField.peak_counts`).
    uncertainty : bool
        Estimate every valid vector's standard uncertainty (``PivField.sigma_u``,
        ``sigma_v``, px) from its last correlation (Wieneke 2015); True.
    roi : (x0, y0, x1, y1), optional
        Region of interest, px (``x0 <= x < x1``, ``y0 <= y < y1``; object px with a
        ``method``): every pass runs on the whole frame's grid cut to it, and only it and a
        margin of the largest window (at least 64 px) are read, dewarped and correlated, so
        the time scales with its area (:class:`rspiv.PivSettings`); ``x``, ``y`` stay in the
        frame's px.
        ``preprocess`` still conditions the whole frames.
    settings : PivSettings, optional
        All of the above PIV settings as one object (overrides the keywords).
    preprocess : rspiv.preprocess.Preprocess, optional
        Image conditioning of the raw frames before anything else (e.g.
        ``rspiv.preprocess.NEAR_WALL``), the same steps the campaign's ``[preprocess]`` runs.
    backgrounds : (ndarray, ndarray), optional
        The run's backgrounds of frames A and B (``rspiv.preprocess.Background``), subtracted
        when ``preprocess`` is given.

    Returns
    -------
    PivField

    Raises
    ------
    InvalidInputError
        Frames not 2D, of different shapes, with NaN/inf, windows larger than the image, bad
        settings; ``method`` without ``calibration`` (or the reverse), an unknown ``method`` or
        ``mapping``; frames whose shape differs from a Calibration's ``image_shape``.

    Warns
    -----
    CorrelationWarning
        The frames do not correlate, or no window could be correlated
        (:meth:`PivField.warning`): the field is returned, but its vectors are no measurement.
    ParticleSizeWarning
        The particle images are under 2 px across (:meth:`PivField.peak_locking`): the
        displacements lean towards whole pixels; and ``preprocess``'s hot-pixel rule flattens
        them (:func:`rspiv.particle_size.warnings_for`).
    """
    options = {k: v for k, v in locals().items() if k in OPTION_KEYS}
    mapping = parse_mapping_mode(mapping)
    if settings is None:
        settings = PivSettings(
            passes=tuple(passes), overlap=overlap, iterations=iterations, **options
        )
    elif not isinstance(settings, PivSettings):
        raise InvalidInputError(f"settings must be an rspiv.PivSettings, got {type(settings)}")
    recorded = frame_a, frame_b
    if preprocess is not None:
        frame_a, frame_b = condition_pair(frame_a, frame_b, preprocess, backgrounds)
    elif backgrounds is not None:
        raise InvalidInputError("backgrounds are subtracted by a preprocess step: give preprocess")
    which = None
    if method is not None or calibration is not None:
        which = parse_method(method) if method is not None else None
        if which not in ("I", "II"):
            raise InvalidInputError(f'method must be "images" or "vectors", got {method!r}')
        if calibration is None:
            raise InvalidInputError(f"method={method!r} needs a calibration")
        field = correct(frame_a, frame_b, calibration, which, settings, mapping=mapping, mask=mask)
    else:
        field = run_grid(frame_a, frame_b, settings, mask)
    # the particle images as recorded, not as high-passed, smoothed or dewarped
    field = as_recorded(
        field, *recorded, settings.passes[0], mask=mask, preprocess=preprocess,
        backgrounds=backgrounds, dewarped=which == "I",
    )  # fmt: skip
    return _warned(field, preprocess)


def _warned(field: PivField, preprocess: Preprocess | None = None) -> PivField:
    """``field``, raising its :meth:`PivField.warning` (frames that do not correlate) as a
    :class:`rspiv.CorrelationWarning` and what its particle images' size says
    (:func:`rspiv.particle_size.warnings_for`: peak locking, the hot-pixel rule of
    ``preprocess``) as :class:`rspiv.ParticleSizeWarning` at the caller's line."""
    w = field.warning()
    if w is not None:
        warnings.warn(w, CorrelationWarning, stacklevel=3)
    for w in warnings_for(field.particle_diameter, preprocess).values():
        warnings.warn(w, ParticleSizeWarning, stacklevel=3)
    return field


def piv_at(
    frame_a,
    frame_b,
    points,
    window: tuple[int, int] | Sequence[tuple[int, int]] = (32, 8),
    predictor=None,
    *,
    iterations: int = 2,
    mask=None,
    validate: bool | None = None,
    subpixel: str = "gauss3",
    interpolation: str = "bspline",
    weighting: str = "tophat",
    median_eps: float = 0.1,
    median_threshold: float = 2.0,
    min_peak_ratio: float = 0.0,
    peak_candidates: int = 3,
    uncertainty: bool = True,
) -> PivField:
    """PIV at arbitrary image positions with given predictor displacements (Method II).

    Parameters
    ----------
    frame_a, frame_b : ndarray, 2D
        As for :func:`piv`.
    points : array_like, shape (..., 2)
        Window centres ``(x, y)`` in px (pixel frame). ``(N, 2)`` for a list of points or
        ``(ny, nx, 2)`` for a structured (possibly distorted) grid, whose neighbours then serve
        the median test.
    window : (w, h) or sequence of (w, h)
        Window size(s) in px (w along x); several sizes run as successive passes at the same
        points, each starting from the previous pass's result.
    predictor : None, array_like (..., 2) or PivField
        None: zero. An array of ``(u, v)`` per point: the windows are offset symmetrically by it
        (sub-pixel). A grid :class:`PivField` (e.g. from :func:`piv` on the same frames): the
        windows are deformed by it (symmetric, interpolated with ``interpolation``): the first
        iteration deforms the whole pair once and reads each window at its fractional position
        with a common sub-pixel shift of both frames (Keys; a filter applied to both windows
        alike does not move the correlation peak); later iterations interpolate each window.
    iterations : int
        Iterations per window size; each re-offsets the windows by the latest result, the
        extra ones under-relaxed as in :func:`piv`.
    mask : ndarray of bool, optional
        Points centred on a True pixel are not computed.
    validate : bool, optional
        Normalised median test among grid neighbours; defaults to True for ``(ny, nx, 2)``
        points and False for a ``(N, 2)`` list.
    subpixel, interpolation, weighting, median_eps, median_threshold, min_peak_ratio,
    peak_candidates, uncertainty
        As for :func:`piv`.

    Returns
    -------
    PivField
        Arrays of shape ``points.shape[:-1]``; ``grid`` is None. Points centred outside the
        image are masked; points whose window (either frame, after offset or deformation)
        reaches past the image edge (``[-0.5, w - 0.5] x [-0.5, h - 0.5]``), or whose window is
        blank (zero variance, e.g. zero fill), are not correlated: ``valid`` False, ``coef``
        and ``peak_ratio`` 0, their value interpolated from the valid neighbours and
        ``replaced`` True.

    Warns
    -----
    CorrelationWarning, ParticleSizeWarning
        As for :func:`piv`.
    """
    windows = [window] if np.ndim(window) == 1 else list(window)
    settings = PivSettings(
        passes=tuple(windows),
        interpolation=interpolation,
        subpixel=subpixel,
        weighting=weighting,
        median_eps=median_eps,
        median_threshold=median_threshold,
        min_peak_ratio=min_peak_ratio,
        peak_candidates=peak_candidates,
        uncertainty=uncertainty,
    )
    field = run_points(
        frame_a,
        frame_b,
        points,
        list(settings.passes),
        settings,
        predictor=predictor,
        iterations=iterations,
        validate=validate,
        mask=mask,
    )
    return _warned(field)
