"""Streamwise spectra and two-point correlations of a sequence of 2D vector fields, streamed.

A large sensor's field of view holds the boundary layer's large scales along the wall; these
are their statistics. :class:`TwoPointAccumulator` takes one field at a time (rows along the
wall, the streamwise direction along a row) and keeps per row the sums from which it gives,
exactly, for the fluctuations about each vector's own mean over the pairs:

- the one-sided streamwise wavenumber spectra ``phi_uu, phi_vv`` and the co-spectrum
  ``phi_uv`` (:meth:`TwoPointAccumulator.spectra`), and
- the streamwise two-point correlation coefficients ``R_uu(dx), R_vv(dx), R_uv(dx)`` at every
  row (:meth:`TwoPointAccumulator.correlation`) and their integral lengths
  (:func:`integral_length`), and
- optionally the two-point maps ``R_uu(dx, y; y_ref)``, ``R_vv`` about reference rows
  (:meth:`TwoPointAccumulator.maps`): the correlation of each reference row with every row of
  a band, over the fields in which every row of the band entered (one sample set for the whole
  map, so its means are exact as well).

Conventions and units
---------------------
Rows are the first axis of a field, the streamwise direction the second; ``dx`` is the grid
step along a row. Velocities are in the fields' unit (px per pair in a campaign), lengths in
grid steps unless a spacing is given, wavenumbers ``k = 2 pi / lambda`` in rad per unit length.
``integral phi(k) dk`` from 0 to the Nyquist wavenumber ``pi / dx`` is the variance (one-sided
spectrum). ``R_uv(dx) = <u'(x) v'(x + dx)> / (sigma_u sigma_v)``.

How
---
Only the columns ``columns = (c0, c1)`` enter (a campaign leaves out those whose windows reach
past the sensor). A row of a field enters when all its values there are finite and at least
``min_valid`` of its vectors are valid (the others hold the PIV's replacements); rows are
counted separately (``count``). Per row the accumulator keeps ``n``, the sums of the rows'
discrete Fourier transforms and of their products:

- zero-padded to at least twice the length (no wrap-around: the next even length whose FFT
  is fast, :func:`pad_length`; a row of 554 vectors is padded to 1152, not 1108 = 4 x 277,
  whose transform takes 5 times longer) and without a taper for the correlations: ``sum A`` and
  ``sum conj(A_a) A_b``;
- tapered by a Hann window for the spectra: ``sum B`` and ``sum conj(B_a) B_b``.

The transform is linear, so the fluctuations' sums are ``sum conj(A_a') A_b' = sum conj(A_a)
A_b - conj(sum A_a) sum A_b / n``: the mean of every vector over the row's ``n`` fields is
removed exactly, though it is only known at the end; sums over parts of a campaign merge by
addition (:meth:`TwoPointAccumulator.merge`).

The correlation at lag ``d`` (grid steps) divides by ``(n - 1) (N - |d|)`` (the ``N - |d|``
products of each field's row, unbiased; N columns), the variances by ``(n - 1) N``; lags beyond
``N / 2`` are not given.
The spectrum is the Hann-windowed periodogram as a one-sided density, ``phi(k_j) = 2 dx / (2
pi) <|B_j'|^2> / sum(w^2)`` at ``k_j = 2 pi j / (N dx)``, averaged over the fields with ``n -
1``; its trapezoidal integral over ``k_j`` is the variance the taper passes (Parseval).

What a PIV field does to them (not corrected here): the measurement noise adds to the variance
at zero lag and lowers every ``R`` by about ``var / (var + noise)``; the interrogation window
averages over its width, so wavelengths shorter than a few window widths are attenuated and
the spectrum's tail holds the noise. A campaign marks both (:mod:`rspiv.campaign.two_point`).
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

import numpy as np
import scipy.fft as sfft

from rspiv.errors import InvalidInputError

__all__ = ["TwoPointAccumulator", "integral_length", "pad_length"]

_COMPONENTS = ("uu", "vv", "uv")
#: The state's sums besides ``count`` (module docstring): transforms, powers, cross products.
_SUMS = ("sum_a", "pow_a", "cross_a", "sum_b", "pow_b", "cross_b")
_MAP_SUMS = ("map_sum", "map_pow", "map_cross")


def pad_length(n: int) -> int:
    """The padded transform's length for rows of ``n`` columns: the smallest even length of at
    least ``2 n`` whose FFT is fast (:func:`scipy.fft.next_fast_len`). Any length from ``2 n
    - 1`` on gives the same linear correlation; even, so that the length follows from the
    one-sided transform's ``L // 2 + 1`` bins (states of earlier versions, padded to ``2 n``
    exactly, are read and added to as they are)."""
    m = 2 * int(n)
    while True:
        length = sfft.next_fast_len(m, real=True)
        if length % 2 == 0:
            return int(length)
        m = length + 1


class TwoPointAccumulator:
    """Streamed streamwise spectra and two-point correlations per row (module docstring).

    Parameters
    ----------
    shape : (int, int)
        The fields' shape ``(rows, columns)``.
    columns : (int, int), optional
        Columns ``c0 <= c < c1`` that enter (default: all). At least 8.
    min_valid : float
        Fraction of valid vectors (within ``columns``) a row needs to enter, in (0, 1].
    band : (int, int), optional
        Rows ``r0 <= r < r1`` of the two-point maps (:meth:`maps`): a field enters them when
        every row of the band enters.
    refs : sequence of int, optional
        The maps' reference rows, inside ``band``.

    Raises
    ------
    InvalidInputError
        A shape that is not 2D, fewer than 8 columns, ``min_valid`` outside (0, 1], a band
        outside the rows or a reference row outside the band.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        columns: tuple[int, int] | None = None,
        min_valid=0.9,
        band: tuple[int, int] | None = None,
        refs=(),
    ) -> None:
        shape = tuple(int(s) for s in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise InvalidInputError(f"shape: expected (rows, columns), got {shape}")
        c0, c1 = (0, shape[1]) if columns is None else (int(columns[0]), int(columns[1]))
        if not (0 <= c0 < c1 <= shape[1]) or c1 - c0 < 8:
            raise InvalidInputError(
                f"columns: ({c0}, {c1}) must hold at least 8 of the {shape[1]} columns"
            )
        if not (0.0 < float(min_valid) <= 1.0):
            raise InvalidInputError(f"min_valid: expected a fraction in (0, 1], got {min_valid}")
        self.shape = shape
        self.columns = (c0, c1)
        self.min_valid = float(min_valid)
        ny, n = shape[0], c1 - c0
        nk_pad = pad_length(n) // 2 + 1  # rfft of pad_length(n) points
        nk = n // 2 + 1
        self.count = np.zeros(ny, np.int64)
        self.sum_a = np.zeros((2, ny, nk_pad), np.complex128)  # u, v
        self.pow_a = np.zeros((2, ny, nk_pad))  # |u|^2, |v|^2
        self.cross_a = np.zeros((ny, nk_pad), np.complex128)  # conj(u) v
        self.sum_b = np.zeros((2, ny, nk), np.complex128)
        self.pow_b = np.zeros((2, ny, nk))
        self.cross_b = np.zeros((ny, nk), np.complex128)
        self.pair_ids: set[Hashable] = set()
        self.n_fields = 0
        refs = tuple(int(r) for r in refs)
        self.band = None if band is None else (int(band[0]), int(band[1]))
        self.refs = refs
        if self.band is None:
            if refs:
                raise InvalidInputError("refs: the maps' reference rows need a band")
            nb = 0
        else:
            r0, r1 = self.band
            if not (0 <= r0 < r1 <= ny) or not refs:
                raise InvalidInputError(
                    f"band: rows ({r0}, {r1}) must lie in the {ny} rows, with reference rows"
                )
            if any(not (r0 <= r < r1) for r in refs):
                raise InvalidInputError(f"refs: {list(refs)} must lie in the band ({r0}, {r1})")
            nb = r1 - r0
        #: fields in the maps, and their band's sums: transforms, powers, and per reference
        #: row conj(A_ref) A_row (u with u, v with v)
        self.map_count = 0
        self.map_sum = np.zeros((2, nb, nk_pad), np.complex128)
        self.map_pow = np.zeros((2, nb, nk_pad))
        self.map_cross = np.zeros((len(refs), 2, nb, nk_pad), np.complex128)

    @property
    def n_columns(self) -> int:
        return self.columns[1] - self.columns[0]

    @property
    def n_pad(self) -> int:
        """The padded transform's length (:func:`pad_length`; ``2 n`` in states of earlier
        versions), from the sums themselves."""
        return 2 * (self.sum_a.shape[-1] - 1)

    def _taper(self) -> np.ndarray:
        return np.hanning(self.n_columns + 2)[1:-1]  # nowhere zero

    # ------------------------------------------------------------------ input
    def add(self, u, v, valid=None, pair_id: Hashable | None = None) -> int:
        """Add one field; returns the number of rows that entered.

        Parameters
        ----------
        u, v : array_like, shape ``self.shape``
        valid : array_like of bool, optional
            The PIV's accepted vectors (default: where u and v are finite).
        pair_id : hashable, optional
            A repeated id is refused.

        Raises
        ------
        InvalidInputError
            Wrong shape or a repeated pair id.
        """
        u = np.asarray(u, np.float64)
        v = np.asarray(v, np.float64)
        for name, a in (("u", u), ("v", v)):
            if a.shape != self.shape:
                raise InvalidInputError(f"{name}: expected shape {self.shape}, got {a.shape}")
        if valid is not None:
            valid = np.asarray(valid)
            if valid.shape != self.shape:
                raise InvalidInputError(
                    f"valid: expected shape {self.shape}, got {valid.shape}"
                )
        if pair_id is not None and pair_id in self.pair_ids:
            raise InvalidInputError(f"pair_id: {pair_id!r} was already added")
        c0, c1 = self.columns
        u, v = u[:, c0:c1], v[:, c0:c1]
        finite = np.isfinite(u) & np.isfinite(v)
        ok = finite if valid is None else (valid[:, c0:c1].astype(bool) & finite)
        rows = finite.all(axis=1) & (ok.mean(axis=1) >= self.min_valid)
        if pair_id is not None:
            self.pair_ids.add(pair_id)
        self.n_fields += 1
        if not rows.any():
            return 0
        every = bool(rows.all())
        uv = np.stack([u, v] if every else [u[rows], v[rows]])  # (2, rows, N)
        a = sfft.rfft(uv, n=self.n_pad, axis=-1)
        b = sfft.rfft(uv * self._taper(), axis=-1)
        at = slice(None) if every else rows
        for part, f in (("a", a), ("b", b)):
            getattr(self, f"sum_{part}")[:, at] += f
            power = f.real**2
            power += f.imag**2
            getattr(self, f"pow_{part}")[:, at] += power
            getattr(self, f"cross_{part}")[at] += np.conj(f[0]) * f[1]
        self.count += rows
        if self.band is not None and rows[self.band[0] : self.band[1]].all():
            pos = np.cumsum(rows) - 1  # a row's place among the rows that entered
            fb = a[:, pos[self.band[0] : self.band[1]]]
            self.map_sum += fb
            power = fb.real**2
            power += fb.imag**2
            self.map_pow += power
            for i, r in enumerate(self.refs):
                self.map_cross[i] += np.conj(fb[:, r - self.band[0], None]) * fb
            self.map_count += 1
        return int(rows.sum())

    # ------------------------------------------------------------------ merge
    def merge(self, other: TwoPointAccumulator) -> TwoPointAccumulator:
        """Add ``other``'s sums to these (in place; exact); returns ``self``.

        Raises
        ------
        InvalidInputError
            Another shape, columns or ``min_valid``, or a pair in both.
        """
        if not isinstance(other, TwoPointAccumulator):
            raise InvalidInputError(f"other: expected a TwoPointAccumulator, got {type(other)!r}")
        mine = (self.shape, self.columns, self.min_valid, self.band, self.refs, self.n_pad)
        theirs = (other.shape, other.columns, other.min_valid, other.band, other.refs, other.n_pad)
        if mine != theirs:
            raise InvalidInputError(
                f"other: (shape, columns, min_valid, band, refs, padded length) {theirs} differ "
                f"from this accumulator's {mine}"
            )
        common = self.pair_ids & other.pair_ids
        if common:
            raise InvalidInputError(f"merge: {len(common)} pair id(s) in both accumulators")
        for k in ("count", *_SUMS, "map_count", *_MAP_SUMS):
            setattr(self, k, getattr(self, k) + getattr(other, k))
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    # ------------------------------------------------------------------ results
    def _fluct(self, part: str) -> np.ndarray:
        """``sum conj(F_a') F_b'`` of the fluctuations (uu, vv, uv) per row for the padded
        (``part = "a"``) or tapered (``"b"``) transforms; NaN below 2 fields."""
        sums = getattr(self, f"sum_{part}")
        power = getattr(self, f"pow_{part}")
        n = self.count.astype(np.float64)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.stack(
                [
                    power[0] - (sums[0].real ** 2 + sums[0].imag ** 2) / n,
                    power[1] - (sums[1].real ** 2 + sums[1].imag ** 2) / n,
                    getattr(self, f"cross_{part}") - np.conj(sums[0]) * sums[1] / n,
                ]
            )
        out[:, self.count < 2] = np.nan
        return out

    def spectra(self, dx: float = 1.0) -> dict[str, np.ndarray]:
        """One-sided streamwise spectra per row.

        Parameters
        ----------
        dx : float
            Grid step along a row, in the unit of length wanted.

        Returns
        -------
        dict
            ``k`` (rad per unit length, from 0 to Nyquist), ``phi_uu``, ``phi_vv`` and the
            co-spectrum ``phi_uv`` (rows x k; velocity^2 x length), ``count`` (fields per
            row). ``trapezoid(phi_uu, k)`` is about the rows' variance.
        """
        n = self.n_columns
        k = 2.0 * np.pi * np.arange(n // 2 + 1) / (n * dx)
        f = self._fluct("b")
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = 2.0 * dx / (2.0 * np.pi * np.sum(self._taper() ** 2))
            nm1 = (self.count - 1.0)[:, None]
            out = {f"phi_{q}": f[i].real * scale / nm1 for i, q in enumerate(_COMPONENTS)}
        return {"k": k, **out, "count": self.count.copy()}

    def correlation(self, max_lag: int | None = None) -> dict[str, np.ndarray]:
        """Streamwise two-point correlation coefficients per row.

        Parameters
        ----------
        max_lag : int, optional
            Largest lag (grid steps) returned; at most (and by default) ``N // 2``.

        Returns
        -------
        dict
            ``lag`` (grid steps, ``-max_lag .. max_lag``), ``R_uu``, ``R_vv``, ``R_uv`` (rows x
            lag), ``var_u``, ``var_v``, ``cov_uv`` (per row, unbiased, averaged along the row)
            and ``count``.
        """
        n = self.n_columns
        m = n // 2 if max_lag is None else min(int(max_lag), n // 2)
        if m < 0:
            raise InvalidInputError(f"max_lag: expected >= 0, got {max_lag}")
        f = self._fluct("a")
        size = self.n_pad
        c = sfft.irfft(f, n=size, axis=-1)  # lag d at d, -d at size - d
        lag = np.arange(-m, m + 1)
        c = c[..., lag % size]
        nm1 = (self.count - 1.0)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            cov = c / ((n - np.abs(lag)) * nm1)
            var = cov[:, :, m]  # lag 0: (uu, vv, uv) per row
            su, sv = np.sqrt(var[0]), np.sqrt(var[1])
            out = {
                "R_uu": cov[0] / var[0][:, None],
                "R_vv": cov[1] / var[1][:, None],
                "R_uv": cov[2] / (su * sv)[:, None],
            }
        return {
            "lag": lag,
            **out,
            "var_u": var[0],
            "var_v": var[1],
            "cov_uv": var[2],
            "count": self.count.copy(),
        }

    def maps(self, max_lag: int | None = None) -> dict[str, np.ndarray]:
        """Two-point correlation maps about the reference rows.

        ``R_uu[i, j, l] = <u'(x, ref_i) u'(x + lag_l, band_j)> / (sigma_u(ref_i)
        sigma_u(band_j))`` over the fields in which every row of the band entered
        (``map_count``), each vector's fluctuation about its mean over those fields; R_vv alike.

        Parameters
        ----------
        max_lag : int, optional
            Largest lag (grid steps); at most (and by default) ``N // 2``.

        Returns
        -------
        dict
            ``lag`` (grid steps), ``rows`` (the band's row indices), ``refs``, ``R_uu``,
            ``R_vv`` (refs x band rows x lags), ``count`` (fields; NaN maps below 2).

        Raises
        ------
        InvalidInputError
            The accumulator has no band.
        """
        if self.band is None:
            raise InvalidInputError("maps: this accumulator was made without a band")
        n = self.n_columns
        m = n // 2 if max_lag is None else min(int(max_lag), n // 2)
        lag = np.arange(-m, m + 1)
        cnt = float(self.map_count)
        r0, r1 = self.band
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = self.map_sum / cnt
            auto = self.map_pow - cnt * (mean.real**2 + mean.imag**2)  # (2, nb, k)
            size = self.n_pad
            var = sfft.irfft(auto, n=size, axis=-1)[..., 0] / (n * (cnt - 1.0))
            idx = [r - r0 for r in self.refs]
            cross = self.map_cross - cnt * np.conj(mean[:, idx]).transpose(1, 0, 2)[
                :, :, None, :
            ] * mean[None]
            c = sfft.irfft(cross, n=size, axis=-1)[..., lag % size]
            cov = c / ((n - np.abs(lag)) * (cnt - 1.0))
            norm = np.sqrt(var[:, idx].T[:, :, None] * var[None])  # (refs, 2, nb)
            r = cov / norm[..., None]
        if self.map_count < 2:
            r[:] = np.nan
        return {
            "lag": lag,
            "rows": np.arange(r0, r1),
            "refs": np.array(self.refs, int),
            "R_uu": r[:, 0],
            "R_vv": r[:, 1],
            "count": self.map_count,
        }

    # ------------------------------------------------------------------ I/O
    def to_dataset_vars(self, prefix: str = "two_point_") -> tuple[dict[str, Any], dict]:
        """The state as (variables, attributes) for an xarray Dataset (complex sums split in
        real and imaginary parts); :meth:`from_dataset_vars` reads them back exactly."""
        out: dict[str, Any] = {f"{prefix}count": (("tp_row",), self.count)}
        for k in _SUMS:
            a = getattr(self, k)
            d = ("tp_comp", "tp_row", f"tp_k_{k[-1]}")[3 - a.ndim :]
            out[f"{prefix}{k}_re"] = (d, a.real)
            if np.iscomplexobj(a):
                out[f"{prefix}{k}_im"] = (d, a.imag)
        if self.band is not None:
            for k in _MAP_SUMS:
                a = getattr(self, k)
                d = ("tp_ref", "tp_comp", "tp_band", "tp_k_a")[4 - a.ndim :]
                out[f"{prefix}{k}_re"] = (d, a.real)
                if np.iscomplexobj(a):
                    out[f"{prefix}{k}_im"] = (d, a.imag)
        attrs = {
            f"{prefix}shape": list(self.shape),
            f"{prefix}columns": list(self.columns),
            f"{prefix}min_valid": self.min_valid,
            f"{prefix}n_fields": self.n_fields,
            **(
                {}
                if self.band is None
                else {
                    f"{prefix}band": list(self.band),
                    f"{prefix}refs": list(self.refs),
                    f"{prefix}map_count": self.map_count,
                }
            ),
        }
        return out, attrs

    @classmethod
    def from_dataset_vars(cls, ds, pair_ids, prefix: str = "two_point_") -> TwoPointAccumulator:
        """The accumulator :meth:`to_dataset_vars` wrote into ``ds`` (its pairs ``pair_ids``)."""
        try:
            band = ds.attrs.get(f"{prefix}band")
            acc = cls(
                tuple(np.ravel(ds.attrs[f"{prefix}shape"])),
                tuple(np.ravel(ds.attrs[f"{prefix}columns"])),
                float(ds.attrs[f"{prefix}min_valid"]),
                None if band is None else tuple(np.ravel(band)),
                () if band is None else tuple(np.ravel(ds.attrs[f"{prefix}refs"])),
            )
            acc.count = np.array(ds[f"{prefix}count"].values, np.int64)
            nk = int(np.shape(ds[f"{prefix}sum_a_re"].values)[-1])  # padded as when written
            if nk != acc.sum_a.shape[-1]:
                if 2 * (nk - 1) < 2 * acc.n_columns:
                    raise ValueError(f"sum_a has {nk} wavenumbers, fewer than {acc.n_columns + 1}")
                for k in ("sum_a", "pow_a", "cross_a", *_MAP_SUMS):
                    old = getattr(acc, k)
                    setattr(acc, k, np.zeros((*old.shape[:-1], nk), old.dtype))
            if band is not None:
                acc.map_count = int(ds.attrs[f"{prefix}map_count"])
            for k in _SUMS + (_MAP_SUMS if band is not None else ()):
                a = np.asarray(ds[f"{prefix}{k}_re"].values, np.float64)
                if np.iscomplexobj(getattr(acc, k)):
                    a = a + 1j * np.asarray(ds[f"{prefix}{k}_im"].values, np.float64)
                if a.shape != getattr(acc, k).shape:
                    raise ValueError(f"{k} has shape {a.shape}")
                setattr(acc, k, a)
            acc.n_fields = int(ds.attrs[f"{prefix}n_fields"])
        except (KeyError, ValueError, TypeError) as exc:
            raise InvalidInputError(f"two-point state: incomplete or malformed ({exc})") from None
        acc.pair_ids = set(pair_ids)
        return acc

    def __repr__(self) -> str:
        return (
            f"TwoPointAccumulator(shape={self.shape}, columns={self.columns}, "
            f"fields={self.n_fields}, max rows' count={int(self.count.max(initial=0))})"
        )


def integral_length(lag, r) -> np.ndarray:
    """Integral length of correlation coefficients ``r`` (rows x lag, lags ``lag`` symmetric
    about 0): the trapezoidal integral of ``r`` over ``0 <= lag`` up to its first zero crossing
    (linearly interpolated), in the unit of ``lag``; NaN for a row whose ``r`` does not cross
    zero within the lags given (the length is then not resolved by the field of view)."""
    lag = np.asarray(lag, np.float64)
    r = np.atleast_2d(np.asarray(r, np.float64))
    pos = lag >= 0
    x, y = lag[pos], r[:, pos]
    out = np.full(y.shape[0], np.nan)
    for i, row in enumerate(y):  # one small integral per row (not per pixel)
        if not np.isfinite(row[0]):
            continue
        neg = np.flatnonzero(~(row > 0))
        if neg.size == 0:
            continue
        j = int(neg[0])
        if j == 0:
            out[i] = 0.0
            continue
        if not np.all(np.isfinite(row[: j + 1])):
            continue
        x0 = x[j - 1] + (x[j] - x[j - 1]) * row[j - 1] / (row[j - 1] - row[j])
        xs = np.append(x[:j], x0)
        ys = np.append(row[:j], 0.0)
        out[i] = float(np.trapezoid(ys, xs))
    return out
