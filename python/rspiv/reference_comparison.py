"""A measured boundary-layer profile held against a reference, band by band, with its errors.

The paper judges its corrections by holding the profiles in wall units against a DNS and an
earlier experiment in similar flow conditions (its mean-velocity and Reynolds-stress figures:
``uu+`` from the distorted images "up to 12 % lower", its peak "slightly shifted").
:func:`compare_reference` says the same in figures:

- **the reference**: by default the Schlatter & Örlü (2010) DNS station nearest in Re_tau
  (:func:`rspiv.reference.dns_profile_for_re_tau`, taken as exact), or another campaign's
  profile (rspiv's ``profile_<run>.csv``, or any CSV with a ``y_plus`` column and some of
  ``U_plus``, ``uu_plus``, ``vv_plus``, ``uv_plus``, optionally their ``eps_`` errors and the
  header lines ``# re_tau = ...``, ``# u_e = ...``, ``# u_tau = ...``: an experiment's table
  converted to wall units);
- **the bands**: the viscous sublayer (``y+ < 5``), the buffer layer (5-30) and the log layer
  (30 to ``0.15 Re_tau`` of the lower of the two Reynolds numbers) in inner scaling, the
  reference interpolated linearly in ``log y+`` to the measured rows; the outer layer (0.15-1
  ``delta99``) in outer scaling, the velocity defect ``U_e+ - U+`` and the stresses at the same
  ``y / delta99`` (where both give their free stream and Re_tau);
- **per band and quantity**: the mean difference (measured minus reference), its error (the
  mean over the band's rows of the two profiles' standard errors combined: rows share pairs
  and windows overlap, so their errors are taken as fully correlated, an upper bound; each
  row's own error is its scatter between pairs, ``eps_U_plus_pairs`` ..., where the row has
  :data:`VERDICT_PAIRS` pairs or more, else the bound ``eps_U_plus`` ...: on the demo's 24
  pairs the bound is 4.7 times the scatter for U+, and three errors reach 17 % of the DNS's
  U+ or uu+ instead of 94 %), the
  difference relative to the reference's mean magnitude there, and a verdict: within three
  errors it agrees; beyond, it differs;
- **the resolution**: given the final window in wall units (``window_plus = (w+, h+)``), the
  reference's mean velocity is averaged over the window's height as a window sees it (a mean
  profile averaged over ``y +- h/2``: exact for the mean of a flow homogeneous along the wall;
  rows closer to the wall than half a window are not compared for ``U+``). The stresses are not
  filtered: a window of ``w+ x h+`` averages away the small scales, so a lower ``uu+`` near its
  peak is what a window of that size measures, not an error (the result names the window);
- **u_tau's error**: where a profile's u_tau has its error from the pairs (``u_tau_std_pairs``,
  :func:`rspiv.boundary_layer.u_tau_jackknife`), it enters each row's error in quadrature
  (``|U+| r`` for U+ and the defect, ``2 |q| r`` for a stress, ``r`` its relative error): a
  difference in wall units may be the friction velocity's;
- **rows beside the wall**: rows flagged ``near_wall`` (within 2.5 window heights, where the
  wall and its reflection shape the measured distribution) are left out of the stresses;
- **the peak of uu+** below ``y+ = 50`` in both, with its height.

Two runs of one campaign (Method II against the uncorrected run) share their pairs, so their
sampling errors are correlated and the combined error is then an upper bound.

Differences are in wall units of each profile's own friction velocity: a ``U+`` that differs
in the log layer may be a friction velocity in error as much as a velocity.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.profiles import VERDICT_PAIRS, judged_error, pair_rows
from rspiv.reference import DNSProfile, dns_profile_for_re_tau

__all__ = [
    "AGREE_SIGMAS",
    "VERDICT_PAIRS",
    "LOG_LAYER_TOP",
    "QUANTITIES",
    "ReferenceComparison",
    "REPORT_TEXT",
    "compare_reference",
    "profile_table",
    "viscous_window",
]

#: What a report says of the comparison's table.
REPORT_TEXT = (
    "The profile in wall units against the DNS station nearest its Re_tau, band by band: the "
    "mean difference (measured minus DNS) and its error (the rows' standard errors taken as "
    "fully correlated, an upper bound); within three errors it agrees. The DNS mean velocity "
    "is averaged over the final window's height as the window sees it; its stresses are not "
    "filtered, so stresses under the DNS's where the final window spans many wall units (near "
    "the uu+ peak) are the window's averaging, not an error. Rows beside the wall are left out "
    "of the stresses."
)

#: The compared quantities, in wall units.
QUANTITIES = ("U_plus", "uu_plus", "vv_plus", "uv_plus")
#: The top of the log layer in ``y / delta99`` (the outer layer above it).
LOG_LAYER_TOP = 0.15
#: A band's mean difference within this many errors agrees with the reference.
AGREE_SIGMAS = 3.0
#: The quantities whose largest relative error the verdict names (the stresses vv+ and uv+
#: are near zero at the wall, where any error is a large share of them).
HEADLINE = ("U_plus", "U_e+ - U+", "uu_plus")

#: The uu+ peak is looked for below this y+.
PEAK_BELOW = 50.0
_INNER = (("viscous sublayer", 0.0, 5.0), ("buffer layer", 5.0, 30.0))


@dataclasses.dataclass
class ReferenceComparison:
    """What :func:`compare_reference` found (module docstring).

    ``bands``: one dict per band and quantity compared: ``band``, ``quantity``, ``y_plus``
    (its range), ``rows``, ``difference`` (mean, measured minus reference), ``error``,
    ``relative`` and ``relative_error`` (the difference and the error over the reference's
    mean magnitude), ``agrees``. ``peak``:
    ``uu_plus`` and ``y_plus`` of the uu+ peak of each (``measured``, ``reference``), with
    ``near_wall`` when the measured one lies in a row beside the wall."""

    reference: str
    re_tau: float
    reference_re_tau: float
    window_plus: tuple[float, float] | None
    bands: list[dict[str, Any]]
    peak: dict[str, Any]
    left_out_near_wall: int
    #: Which errors judged the measurement: ``"pairs"`` (its rows' scatter between pairs,
    #: where they have :data:`VERDICT_PAIRS` pairs) or ``"bound"`` (the vectors of a field
    #: taken as fully correlated along the wall).
    errors: str = "bound"

    def differing(self) -> list[dict[str, Any]]:
        """The bands and quantities beyond :data:`AGREE_SIGMAS` errors of the reference."""
        return [b for b in self.bands if not b["agrees"]]

    def verdict(self) -> str:
        """One line: whether every band agrees, else which differ and by how much."""
        d = self.differing()
        if d:
            what = "differs in " + ", ".join(
                f"{b['band']} {b['quantity']} ({100 * b['relative']:+.1f} %)" for b in d
            )
        else:
            rel = [
                b["relative_error"]
                for b in self.bands
                if b["quantity"] in HEADLINE and math.isfinite(b["relative_error"])
            ]
            what = "every band agrees within three errors" + (
                f" (three errors reach {300 * max(rel):.0f} % of the reference's U+ or uu+: a "
                "smaller difference is not seen)"
                if rel
                else ""
            )
        return f"against {self.reference}: {what}"

    def lines(self) -> list[str]:
        """The comparison as text: the reference, each band and quantity, the peak."""
        out = [f"against {self.reference} (Re_tau {self.reference_re_tau:.0f}; measured "
               f"{self.re_tau:.0f})"
               + (f", final window {self.window_plus[0]:.1f} x {self.window_plus[1]:.1f} "
                  "wall units" if self.window_plus else "")]  # fmt: skip
        for b in self.bands:
            verdict = "agrees" if b["agrees"] else "differs"
            out.append(
                f"{b['band']} (y+ {b['y_plus'][0]:.3g}-{b['y_plus'][1]:.3g}, {b['rows']} rows) "
                f"{b['quantity']}: {b['difference']:+.3g} +- {b['error']:.2g} "
                f"({100 * b['relative']:+.1f} %): {verdict}"
            )
        m, r = self.peak.get("measured"), self.peak.get("reference")
        if m and r:
            out.append(
                f"uu+ peak: {m['uu_plus']:.2f} at y+ {m['y_plus']:.1f}"
                + (" (a row beside the wall)" if m.get("near_wall") else "")
                + f", reference {r['uu_plus']:.2f} at y+ {r['y_plus']:.1f}"
            )
        if self.left_out_near_wall:
            out.append(
                f"{self.left_out_near_wall} row(s) beside the wall left out of the stresses"
            )
        return out

    def table_rows(self) -> list[dict[str, Any]]:
        """One row per band and quantity, for a report's table."""
        return [
            {
                "band": b["band"],
                "y+": f"{b['y_plus'][0]:.3g}-{b['y_plus'][1]:.3g}",
                "rows": b["rows"],
                "quantity": b["quantity"],
                "difference": b["difference"],
                "error": b["error"],
                "relative (%)": 100 * b["relative"],
                "verdict": "agrees" if b["agrees"] else "differs",
            }
            for b in self.bands
        ]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        d = dataclasses.asdict(self)
        d["differing"] = [f"{b['band']} {b['quantity']}" for b in self.differing()]
        return d


def profile_table(source: Any) -> tuple[dict[str, np.ndarray], dict[str, float], str]:
    """``(columns, scalars, label)`` of a profile: a :class:`rspiv.BoundaryLayerResult`, a
    :class:`rspiv.reference.DNSProfile`, a profile CSV (rspiv's ``profile_<run>.csv`` or the
    columns of the module docstring) or a mapping of columns. ``scalars`` holds ``re_tau``,
    ``u_e_plus`` and ``u_tau_rel`` (u_tau's relative error from the pairs, a header's
    ``u_tau_std_pairs / u_tau``) where known."""
    if isinstance(source, DNSProfile):
        cols = {
            "y_plus": source.y_plus,
            "U_plus": source.u_plus,
            "uu_plus": source.uu_plus,
            "vv_plus": source.vv_plus,
            "uv_plus": source.uv_plus,
        }
        return cols, {"re_tau": source.re_tau, "u_e_plus": source.u_inf_plus}, source.label()
    if hasattr(source, "profile_columns"):  # a BoundaryLayerResult
        cols = source.profile_columns()
        rel = getattr(source, "u_tau_std_pairs", math.nan) / source.u_tau
        scal = {"re_tau": float(source.re_tau), "u_e_plus": source.u_e / source.u_tau,
                "u_tau_rel": rel}  # fmt: skip
        return cols, scal, "the measured profile"
    if isinstance(source, (str, os.PathLike)):
        return _read_csv(pathlib.Path(source))
    if isinstance(source, Mapping):
        cols = {k: np.asarray(v, dtype=np.float64) for k, v in source.items()}
        if "y_plus" not in cols:
            raise InvalidInputError("the given profile: a y_plus column is needed")
        return cols, {}, "the given profile"
    raise InvalidInputError(f"profile: cannot compare a {type(source).__name__}")


def _read_csv(path: pathlib.Path) -> tuple[dict[str, np.ndarray], dict[str, float], str]:
    """A profile CSV (module docstring), refused in one line naming the file."""
    from rspiv.outputs import read_profile_csv  # deferred: the writers' stack only for files

    if not path.is_file():
        raise InvalidInputError(f"{path}: no such file")
    try:
        cols, meta = read_profile_csv(path)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"{path}: not a profile table ({exc})") from None
    if "y_plus" not in cols or not any(q in cols for q in QUANTITIES):
        raise InvalidInputError(
            f"{path}: a profile needs a y_plus column and one of {', '.join(QUANTITIES)}"
        )
    scal: dict[str, float] = {}
    try:
        if "re_tau" in meta:
            scal["re_tau"] = float(meta["re_tau"])
        if "u_e" in meta and "u_tau" in meta:
            scal["u_e_plus"] = float(meta["u_e"]) / float(meta["u_tau"])
        if "u_tau_std_pairs" in meta and "u_tau" in meta:
            scal["u_tau_rel"] = float(meta["u_tau_std_pairs"]) / float(meta["u_tau"])
    except ValueError as exc:
        raise InvalidInputError(f"{path}: a header value is not a number ({exc})") from None
    label = meta.get("label", path.name)
    return cols, scal, f"{label} ({path.name})" if label != path.name else label


def viscous_window(result: Any, window_px: tuple[float, float], m_per_px: float):
    """The window ``window_px`` (px) in wall units of ``result`` (a BoundaryLayerResult) at
    ``m_per_px`` (m per px)."""
    lv_px = result.nu / result.u_tau / m_per_px
    return (window_px[0] / lv_px, window_px[1] / lv_px)


def _window_mean(y: np.ndarray, yr: np.ndarray, ur: np.ndarray, h: float) -> np.ndarray:
    """The reference ``ur(yr)`` (linear between its points) averaged over ``y +- h/2``: the
    exact integral of the interpolant over the window over ``h``; NaN where the window leaves
    the reference's range."""
    slope = np.diff(ur) / np.diff(yr)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (ur[1:] + ur[:-1]) * np.diff(yr))])

    def integral(x: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(yr, x, side="right") - 1, 0, yr.size - 2)
        d = x - yr[i]
        return cum[i] + d * ur[i] + 0.5 * d * d * slope[i]

    lo, hi = y - 0.5 * h, y + 0.5 * h
    out = (integral(hi) - integral(lo)) / h
    return np.where((lo >= yr[0]) & (hi <= yr[-1]), out, np.nan)


def compare_reference(
    profile: Any,
    reference: Any = None,
    *,
    window_plus: tuple[float, float] | None = None,
) -> ReferenceComparison:
    """Hold a measured profile against a reference (module docstring).

    Parameters
    ----------
    profile
        The measurement: a :class:`rspiv.BoundaryLayerResult`, a profile CSV or columns
        (``y_plus``, some of :data:`QUANTITIES`, optionally ``eps_U_plus`` ... and
        ``near_wall``).
    reference : optional
        None: the DNS station nearest the measurement's Re_tau; a DNSProfile, a profile CSV or
        columns.
    window_plus : (float, float), optional
        The final interrogation window (streamwise, wall-normal) in wall units.

    Raises
    ------
    InvalidInputError
        One line: a profile or reference without y+ or any quantity, a DNS reference asked for
        without the measurement's Re_tau, no band with rows in both.
    """
    cols, scal, mlabel = profile_table(profile)
    cols, errors = _judged_errors(cols)
    if reference is None:
        if not math.isfinite(scal.get("re_tau", math.nan)):
            raise InvalidInputError(
                f"{mlabel}: its Re_tau is needed to choose the DNS station (a '# re_tau = ' "
                "header line), or give a reference"
            )
        reference = dns_profile_for_re_tau(scal["re_tau"])
    rcols, rscal, label = profile_table(reference)
    rcols, _ = _judged_errors(rcols)
    y = np.asarray(cols["y_plus"], dtype=np.float64)
    near = np.asarray(cols.get("near_wall", np.zeros_like(y))) > 0.5
    ry = np.asarray(rcols["y_plus"], dtype=np.float64)
    _, order = np.unique(np.where(np.isfinite(ry), ry, np.inf), return_index=True)
    order = order[np.isfinite(ry[order])]
    if order.size < 2 or not np.isfinite(y).any():
        which = label if order.size < 2 else mlabel
        raise InvalidInputError(f"{which}: fewer than two rows with a finite y_plus")
    yr = ry[order]
    re_tau = scal.get("re_tau", math.nan)
    re_ref = rscal.get("re_tau", math.nan)
    known = [r for r in (re_tau, re_ref) if math.isfinite(r)]
    top = LOG_LAYER_TOP * min(known) if known else math.inf
    bands = [*_INNER, ("log layer", 30.0, top)]
    results: list[dict[str, Any]] = []
    inner_ok = yr > 0
    for q in QUANTITIES:
        if q not in cols or q not in rcols:
            continue
        qr = np.asarray(rcols[q], dtype=np.float64)[order]
        eps = np.asarray(cols.get(f"eps_{q}", np.zeros_like(y)), dtype=np.float64)
        reps = np.asarray(rcols.get(f"eps_{q}", np.zeros_like(qr)), dtype=np.float64)[order]
        at = np.interp(np.log(np.maximum(y, 1e-12)), np.log(yr[inner_ok]), qr[inner_ok],
                       left=np.nan, right=np.nan)  # fmt: skip
        at_eps = np.interp(np.log(np.maximum(y, 1e-12)), np.log(yr[inner_ok]), reps[inner_ok])
        if q == "U_plus" and window_plus is not None:
            at = _window_mean(y, yr, qr, float(window_plus[1]))
        # each profile's own u_tau's error (from its pairs) on its wall-unit values
        eps = _with_u_tau(eps, np.asarray(cols[q], dtype=np.float64), q, scal)
        at_eps = _with_u_tau(at_eps, at, q, rscal)
        use = np.isfinite(at) & np.isfinite(np.asarray(cols[q], dtype=np.float64))
        if q != "U_plus":
            use &= ~near
        for name, lo, hi in bands:
            sel = use & (y >= lo) & (y < hi)
            if sel.any():
                results.append(
                    _band(name, q, y[sel], np.asarray(cols[q])[sel], at[sel], eps[sel],
                          at_eps[sel])  # fmt: skip
                )
        outer = _outer(q, cols, scal, rcols, rscal, order, use)
        if outer is not None:
            results.append(outer)
    if not results:
        raise InvalidInputError(
            f"no rows of the profile fall in a band of {label} (y+ {yr[0]:.3g}-{yr[-1]:.3g})"
        )
    return ReferenceComparison(
        reference=label,
        re_tau=float(re_tau),
        reference_re_tau=float(re_ref),
        window_plus=None if window_plus is None else tuple(float(v) for v in window_plus),
        bands=results,
        peak=_peaks(y, cols, yr, rcols, order, near),
        left_out_near_wall=int(np.count_nonzero(near & np.isfinite(y))),
        errors=errors,
    )


def _judged_errors(cols: dict[str, Any]) -> tuple[dict[str, Any], str]:
    """A profile's columns with each ``eps_<q>`` replaced, in the rows of at least
    :data:`VERDICT_PAIRS` pairs, by ``eps_<q>_pairs`` (the rows' scatter between pairs), and
    ``"pairs"`` when any was, else ``"bound"``."""
    if "pairs" not in cols:
        return cols, "bound"
    out, used = dict(cols), False
    for q in QUANTITIES:
        own, bound = cols.get(f"eps_{q}_pairs"), cols.get(f"eps_{q}")
        if own is None or bound is None:
            continue
        out[f"eps_{q}"] = judged_error(bound, own, cols["pairs"])
        used |= bool(pair_rows(own, cols["pairs"]).any())
    return out, "pairs" if used else "bound"


def _band(name, q, y, meas, ref, eps, reps) -> dict[str, Any]:
    d = float(np.mean(meas - ref))
    err = float(np.mean(np.hypot(eps, reps)))
    scale = float(np.mean(np.abs(ref)))
    return {
        "band": name,
        "quantity": q,
        "y_plus": [float(y.min()), float(y.max())],
        "rows": int(y.size),
        "difference": d,
        "error": err,
        "relative": d / scale if scale > 0 else math.nan,
        "relative_error": err / scale if scale > 0 else math.nan,
        "agrees": bool(abs(d) <= AGREE_SIGMAS * err),
    }


def _with_u_tau(eps: np.ndarray, val: np.ndarray, q: str, scal: dict[str, float]) -> np.ndarray:
    """``eps`` and the error a profile's u_tau gives its wall-unit values ``val`` in quadrature:
    ``|val| r`` for U+ and the velocity defect, ``2 |val| r`` for the stresses, ``r`` the
    relative error of u_tau from the pairs (``scal["u_tau_rel"]``; none without it)."""
    rel = scal.get("u_tau_rel", math.nan)
    if not (math.isfinite(rel) and rel > 0):
        return eps
    return np.hypot(eps, (1 if q == "U_plus" else 2) * rel * np.abs(val))


def _outer(q, cols, scal, rcols, rscal, order, use) -> dict[str, Any] | None:
    """The outer layer's band in ``y / delta99`` (the velocity defect for U+), or None where a
    Re_tau or a free stream is missing."""
    need = ("re_tau",) + (("u_e_plus",) if q == "U_plus" else ())
    if not all(math.isfinite(s.get(k, math.nan)) for s in (scal, rscal) for k in need):
        return None
    eta = np.asarray(cols["y_plus"], dtype=np.float64) / scal["re_tau"]
    eta_r = np.asarray(rcols["y_plus"], dtype=np.float64)[order] / rscal["re_tau"]
    meas = np.asarray(cols[q], dtype=np.float64)
    ref = np.asarray(rcols[q], dtype=np.float64)[order]
    if q == "U_plus":
        meas, ref = scal["u_e_plus"] - meas, rscal["u_e_plus"] - ref
    at = np.interp(eta, eta_r, ref, left=np.nan, right=np.nan)
    sel = use & np.isfinite(at) & (eta >= LOG_LAYER_TOP) & (eta <= 1.0)
    if not sel.any():
        return None
    eps = np.asarray(cols.get(f"eps_{q}", np.zeros_like(eta)), dtype=np.float64)
    reps_r = np.asarray(rcols.get(f"eps_{q}", np.zeros(order.size)), dtype=np.float64)[order]
    reps = np.interp(eta, eta_r, reps_r)
    eps, reps = _with_u_tau(eps, meas, q, scal), _with_u_tau(reps, at, q, rscal)
    out = _band("outer layer", q, np.asarray(cols["y_plus"])[sel], meas[sel], at[sel],
                eps[sel], reps[sel])  # fmt: skip
    if q == "U_plus":
        out["quantity"] = "U_e+ - U+"
    return out


def _peaks(y, cols, yr, rcols, order, near) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "uu_plus" not in cols or "uu_plus" not in rcols:
        return out
    uu = np.asarray(cols["uu_plus"], dtype=np.float64)
    sel = np.isfinite(uu) & (y < PEAK_BELOW)
    if sel.any():
        i = np.flatnonzero(sel)[int(np.argmax(uu[sel]))]
        out["measured"] = {
            "uu_plus": float(uu[i]),
            "y_plus": float(y[i]),
            "near_wall": bool(near[i]),
        }
    ur = np.asarray(rcols["uu_plus"], dtype=np.float64)[order]
    sel = np.isfinite(ur) & (yr < PEAK_BELOW)
    if sel.any():
        i = np.flatnonzero(sel)[int(np.argmax(ur[sel]))]
        out["reference"] = {"uu_plus": float(ur[i]), "y_plus": float(yr[i])}
    return out
