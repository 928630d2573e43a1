"""The PIV vector field: :class:`PivField`, what every PIV function of rspiv returns.

Coordinates follow the pixel frame of the README: x = column (right), y = row (down), origin at
the centre of the top-left pixel; displacements ``u`` (along x) and ``v`` (along y, positive
downward) are in pixels (object px for a corrected field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rspiv import _rspiv, derivatives
from rspiv.errors import InvalidInputError

__all__ = ["PivField"]


@dataclass(frozen=True)
class PivField:
    """A PIV vector field; every array has the same 2D shape ``(ny, nx)``.

    Attributes
    ----------
    x, y : ndarray of float64
        Window centres, px (pixel frame).
    u, v : ndarray of float64
        Displacement along x (right) and y (down), px. Replaced vectors hold the interpolated
        value; vectors not computed (``masked``) are NaN.
    valid : ndarray of bool
        Passed the final validation (correlation found, median test, peak ratio).
    replaced : ndarray of bool
        Rejected by the final validation and replaced from the neighbours.
    peak_choice : ndarray of uint8
        The correlation peak a valid vector comes from: 1 the highest, 2 or 3 the second or
        third (its highest peak failed the median test; ``PivSettings.peak_candidates``); 0
        where replaced or masked.
    masked : ndarray of bool
        Not computed: centre inside the mask or outside the image.
    peak_ratio : ndarray of float64
        Highest correlation peak over the second-highest (capped at 1000).
    coef : ndarray of float64
        Correlation coefficient: height of the normalised correlation peak.
    sigma_u, sigma_v : ndarray of float64
        Standard uncertainty (one sigma) of ``u`` and ``v``, px (object px for a corrected
        field), of every valid vector, from the statistics of its last correlation (Wieneke
        2015: the scatter of the per-pixel contributions to the peak's asymmetry carried
        through the 3-point Gaussian estimator; DESIGN.md "Per-vector uncertainty"), its
        variance pooled with the valid 3 x 3 neighbours' (the estimate of one window of a few
        particle images scatters by tens of percent), widened by the chance that the peak is a
        noise peak: ``p(peak_ratio) d**2`` is added to the
        variance, ``p = 0.8 exp(-3 (peak_ratio - 1))`` and ``d`` the distance to the median of
        the valid neighbours or, weighted by ``p`` once more, to the second peak
        (``piv_core::multipass::ambiguity_variance``); NaN where the vector is not valid
        (replaced, masked), and for the few valid ones whose correlation peak leaves the
        estimate undefined (a 3-point fit without a maximum: of the 59,380 valid vectors of
        OpenPIV's ``test4``, 81 for ``sigma_u`` and 246 for ``sigma_v``).
    window : tuple of int
        Final window ``(w, h)`` in px (w along x).
    grid : tuple of float or None
        ``(x0, y0, dx, dy)`` of the regular grid (``x = x0 + i dx``), None for :func:`piv_at`.
    particle_diameter : tuple of float
        The particle images' e^-2 diameter along x and y, px, as recorded (the optics' image
        integrated over the pixel), from the widths of the first pass's confident correlation
        peaks (``piv_core::particle_size``; 1-4 % under the pixel-integrated diameter on
        synthetic images); :func:`rspiv.piv` measures the frames as given when it conditions
        (only their backgrounds subtracted) or dewarps them (:mod:`rspiv.particle_size`). NaN
        where not measured (fewer than 16 windows with a peak ratio of 2 or more). A
        displacement varying across the windows widens the peaks, so the smaller axis is the
        better estimate. Under 2 px the sub-pixel displacements lean towards whole pixels
        (peak locking): :meth:`peak_locking` says so.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    replaced: np.ndarray
    masked: np.ndarray
    peak_ratio: np.ndarray
    coef: np.ndarray
    peak_choice: np.ndarray
    sigma_u: np.ndarray
    sigma_v: np.ndarray
    window: tuple[int, int]
    grid: tuple[float, float, float, float] | None
    particle_diameter: tuple[float, float] = (float("nan"), float("nan"))

    @classmethod
    def _from_native(cls, d: dict, window: tuple[int, int], shape=None) -> PivField:
        keys = ("x", "y", "u", "v", "valid", "replaced", "masked", "peak_ratio", "coef")
        keys += ("peak_choice", "sigma_u", "sigma_v")
        arrays = {k: d[k] if shape is None else d[k].reshape(shape) for k in keys}
        grid = None if d["grid"] is None else tuple(float(g) for g in d["grid"])
        diameter = tuple(float(x) for x in d.get("particle_diameter", (np.nan, np.nan)))
        return cls(**arrays, window=tuple(window), grid=grid, particle_diameter=diameter)

    def peak_counts(self) -> dict[str, int]:
        """How the vectors that are not masked came about: ``{"first", "second", "third",
        "interpolated"}`` = from the highest correlation peak, the second, the third, or
        replaced from their neighbours."""
        live = ~self.masked
        c = np.where(self.replaced, 0, self.peak_choice)[live]
        return {
            "first": int(np.count_nonzero(c == 1)),
            "second": int(np.count_nonzero(c == 2)),
            "third": int(np.count_nonzero(c == 3)),
            "interpolated": int(np.count_nonzero(self.replaced[live])),
        }

    def warning(self) -> str | None:
        """The one-line warning for a field whose frames do not correlate, in whole or in part;
        None when they correlate.

        Frames that do not correlate (a wrong pairing, a missing laser pulse, frames of noise,
        or a displacement beyond the first pass's search, half its window) still give a
        highest peak in every window, and about 60 % of their random vectors pass the median
        test among neighbours as random. What gives them away is the peak ratio: the median
        over the correlated windows (``peak_ratio > 0``) is 1.1-1.25 for them and about 3 or
        more for particle images (1.37 for a recording lit on a third of the frame). Under
        ``_rspiv.MIN_MEDIAN_PEAK_RATIO`` (1.3), or with no window correlated, the field is no
        measurement (:meth:`uncorrelated`). On a grid, a part of the frames without particle
        images (unlit, outside the light sheet, a shadow) or with too few per window is found
        the same way locally: more than 10 % of the valid vectors with most of their 5 x 5
        neighbourhood's windows under 1.3 (0-2.6 % for real recordings that correlate, 25.7 %
        for a pair 40 % unlit, 32.6 % for OpenPIV's ``test3``, whose lit part hardly
        correlates at 32 x 8 px either). A field whose windows (those not masked) were too
        blank to be correlated in more than ``_rspiv.MAX_BLANK_FRACTION`` (20 %) of the places
        is warned the same way: their vectors are only interpolated from their neighbours
        (0-0.4 % for OpenPIV's recordings with windows holding enough particle images, 29-31 %
        for its ``test5`` and ``test6`` at 16 x 16 px; the grid's two outer rings, whose
        windows also fail when they reach outside the frame, are not counted), and so is one
        more than ``_rspiv.MAX_REPLACED_FRACTION`` (10 %) of whose vectors there are only
        interpolated, rejected by the validation or too blank: where the median test rejects
        that many (too few particle images per window, a displacement that varies too much
        across one), the vectors it keeps are wrong as well (0.5-4.4 % for OpenPIV's recordings
        with enough particle images per window, 0.5 % for the demo's boundary layer; 13.5-51 %
        for synthetic particle images with too few per window, where the vectors kept are off
        by 0.3-3.5 px RMS). The
        measurements are ``benches/real_data_checks.py``'s, in ``benches/RESULTS.md``;
        ``piv_core::validate::correlation_check``. :func:`rspiv.piv` and :func:`rspiv.piv_at`
        raise it as a :class:`rspiv.CorrelationWarning`, ``rspiv piv`` prints it and writes it
        to the file; a campaign leaves out a pair whose frames do not correlate and reports
        those that correlate in part (:attr:`rspiv.campaign.CampaignResult.warned`).
        """
        return self.correlation()[1]

    def uncorrelated(self) -> bool:
        """True when the frames do not correlate as a whole, or no window could be correlated:
        the field is no measurement (:meth:`warning` says what was seen). The median test
        alone (3 ms for the 730,513 vectors of a 47 MP pair's last pass)."""
        return self.correlation(local=False)[0]

    def correlation(self, local: bool = True) -> tuple[bool, str | None]:
        """Both answers of the correlation check at once: ``(uncorrelated, warning)`` as
        :meth:`uncorrelated` and :meth:`warning` give them; ``local=False`` skips the local test
        (the warning is then only the whole field's; a field at points, :func:`rspiv.piv_at`,
        has no local test). 7 ms with the local test, 3 ms without, for a 47 MP pair's last pass
        (730,513 vectors)."""
        pr = np.asarray(self.peak_ratio, dtype=np.float64)
        valid = np.asarray(self.valid, dtype=bool)
        masked = np.atleast_2d(np.asarray(self.masked, dtype=bool))
        local = local and self.grid is not None and pr.ndim == 2
        return _rspiv.correlation_check(np.atleast_2d(pr), np.atleast_2d(valid), local, masked)

    def peak_locking(self) -> str | None:
        """The one-line warning for particle images too small for a sub-pixel fit, None
        otherwise or when not measured.

        Under ``_rspiv.MIN_PARTICLE_DIAMETER`` (2 px, e^-2, as recorded; along x or y of
        :attr:`particle_diameter`) every sub-pixel estimate leans towards whole pixels (peak
        locking): measured on synthetic particle images through the paper's passes, a bias
        ``-a sin(2 pi t)`` in the true displacement ``t`` of amplitude ``a`` = 0.050 px at a
        diameter of 1.39 px, 0.027 at 1.61, 0.011 at 1.91, 0.003 at 2.24 px
        (``piv_core::particle_size``). It does not average out: a campaign's mean profile and
        its fluctuations carry it, and the per-vector uncertainty does not include it. A slight
        defocus (particle images of 2-3 px) removes it; smoothing both frames after the
        recording (:class:`rspiv.preprocess.Preprocess` ``smooth = 0.7``) about halves it, at
        the same random error (the sub-pixel information the sensor did not sample is not
        restored). :func:`rspiv.piv` and :func:`rspiv.piv_at` raise it as a
        :class:`rspiv.ParticleSizeWarning`; ``rspiv piv`` prints it and writes it to the file.
        """
        dx, dy = self.particle_diameter
        return _rspiv.peak_locking_warning(float(dx), float(dy))

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the vector arrays."""
        return self.u.shape

    def _spacing(self, what: str) -> tuple[float, float]:
        if self.grid is None:
            raise InvalidInputError(
                f"{what}: needs a field on a regular grid (rspiv.piv), not rspiv.piv_at's points"
            )
        return float(self.grid[2]), float(self.grid[3])

    def gradients(self, scheme: str = "least_squares") -> dict[str, np.ndarray]:
        """``dudx, dudy, dvdx, dvdy`` in the image's right-handed frame (x right, y up), 1/pair
        (:mod:`rspiv.derivatives`: frame, schemes ``"central"``, ``"least_squares"``,
        ``"richardson"``, edges and NaN). Divide by the pulse separation for 1/s.

        Raises
        ------
        InvalidInputError
            A field at arbitrary points (:func:`rspiv.piv_at`), or an unknown scheme.
        """
        dx, dy = self._spacing("gradients")
        return derivatives.gradients(self.u, self.v, dx, dy, scheme)

    def vorticity(self, scheme: str = "least_squares") -> np.ndarray:
        """The vorticity ``omega_z``, positive counter-clockwise on the image, 1/pair
        (:func:`rspiv.derivatives.vorticity`)."""
        dx, dy = self._spacing("vorticity")
        return derivatives.vorticity(self.u, self.v, dx, dy, scheme)

    def divergence(self, scheme: str = "least_squares") -> np.ndarray:
        """The in-plane divergence, 1/pair (:func:`rspiv.derivatives.divergence`)."""
        dx, dy = self._spacing("divergence")
        return derivatives.divergence(self.u, self.v, dx, dy, scheme)

    def swirling_strength(self, scheme: str = "least_squares", signed: bool = False) -> np.ndarray:
        """The swirling strength ``lambda_ci``, 1/pair, signed by the vorticity with ``signed``
        (:func:`rspiv.derivatives.swirling_strength`)."""
        dx, dy = self._spacing("swirling_strength")
        return derivatives.swirling_strength(self.u, self.v, dx, dy, scheme, signed)

    def to_xarray(self, derived: str | None = None):
        """The field as an :class:`xarray.Dataset` compatible with pivpy.

        Variables ``u``, ``v`` (px) and ``chc`` (1 valid, 0 replaced, -1 not computed), plus
        ``peak_ratio``, ``coef``, ``sigma_u``, ``sigma_v`` (px), ``valid``, ``replaced``,
        ``masked``, ``peak_choice``; dims ``(y, x)``. For a grid field the coordinates ``x``,
        ``y`` are the window centres in px; for a field at arbitrary points (:func:`piv_at`) the
        dims are indexed 0..n-1 and the positions are the 2D coordinates ``x_px``, ``y_px``.
        The attribute ``warning`` holds :meth:`warning` when the frames do not correlate (in
        whole or in part), ``particle_diameter_px`` the :attr:`particle_diameter` (x, y) when
        measured, and ``peak_locking`` :meth:`peak_locking` when the particle images are too
        small.

        With ``derived`` (a scheme of :mod:`rspiv.derivatives`, e.g. ``"least_squares"``) it
        also holds ``vorticity``, ``divergence`` and the signed ``swirling_strength`` (1/pair;
        x right, y up).
        """
        import xarray as xr

        chc = np.where(self.masked, -1, np.where(self.valid, 1, 0)).astype(np.int8)
        dims = ("y", "x")
        data = {
            "u": (dims, self.u, {"units": "pix", "long_name": "displacement along x"}),
            "v": (dims, self.v, {"units": "pix", "long_name": "displacement along y (down)"}),
            "chc": (dims, chc, {"long_name": "1 valid, 0 replaced, -1 not computed"}),
            "peak_ratio": (dims, self.peak_ratio),
            "coef": (dims, self.coef),
            "sigma_u": (
                dims,
                self.sigma_u,
                {"units": "pix", "long_name": "standard uncertainty of u (correlation statistics)"},
            ),
            "sigma_v": (
                dims,
                self.sigma_v,
                {"units": "pix", "long_name": "standard uncertainty of v (correlation statistics)"},
            ),
            "valid": (dims, self.valid),
            "replaced": (dims, self.replaced),
            "masked": (dims, self.masked),
            "peak_choice": (
                dims,
                self.peak_choice,
                {"long_name": "correlation peak used: 1 highest, 2 second, 3 third, 0 none"},
            ),
        }
        if self.grid is not None:
            coords = {
                "x": ("x", self.x[0, :], {"units": "pix"}),
                "y": ("y", self.y[:, 0], {"units": "pix"}),
            }
        else:
            coords = {
                "x_px": (dims, self.x, {"units": "pix"}),
                "y_px": (dims, self.y, {"units": "pix"}),
            }
        if derived is not None:
            g = self.gradients(derived)
            long = f"(x right, y up; {derived} differences)"
            omega = g["dvdx"] - g["dudy"]
            for name, val, what in (
                ("vorticity", omega, "vorticity, counter-clockwise positive"),
                ("divergence", g["dudx"] + g["dvdy"], "in-plane divergence"),
                ("swirling_strength", derivatives.swirl_from_gradients(g, signed=True),
                 "swirling strength signed by the vorticity"),
            ):  # fmt: skip
                data[name] = (dims, val, {"units": "1/pair", "long_name": f"{what} {long}"})
        ds = xr.Dataset(data, coords=coords)
        ds.attrs.update(
            {
                "variables": "['x', 'y', 'u', 'v']",
                "units": "['pix', 'pix', 'pix/dt', 'pix/dt']",
                "window_w_h_px": list(self.window),
                "conventions": "pixel frame: x right, y down, origin at the top-left pixel centre",
            }
        )
        dx, dy = self.particle_diameter
        if np.isfinite(dx) or np.isfinite(dy):
            ds.attrs["particle_diameter_px"] = [float(dx), float(dy)]
        warning = self.warning()
        if warning is not None:
            ds.attrs["warning"] = warning
        locking = self.peak_locking()
        if locking is not None:
            ds.attrs["peak_locking"] = locking
        return ds
