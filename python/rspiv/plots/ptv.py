"""The particle-tracking profile at the wall (``rspiv ptv``): the mean velocity and the Reynolds
stresses of the tracks' bins, beside the campaign's windowed profile, the viscous sublayer's
fitted line and the Schlatter & Örlü DNS; and ``vv`` within 10 wall units of the wall with and
without the tracks' own error (the two-track stresses of :mod:`rspiv.ptv_profile`).

In wall units when the profile has them (``y_plus``, ``U_plus`` ...: the campaign's ``u_tau``,
``nu``, ``dt`` and calibration), else in px from the wall and px per pair. Error bars are two
standard errors (the bins' pair-to-pair errors, :class:`rspiv.ptv_profile.TrackProfile`). Bins
within a particle image of the wall (``near_wall``: images merged with their reflection) are
drawn hollow and grey and are not in the sublayer fit. Matplotlib's object API with the Agg
canvas; the PNG is written atomically.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.plots.boundary_layer import _save
from rspiv.reference import DNSProfile

__all__ = ["plot_track_profile"]


def _ratio(num: np.ndarray, den: np.ndarray) -> float:
    """The constant factor between a column and its px version (median over finite rows)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = num / den
    r = r[np.isfinite(r) & (r != 0)]
    return float(np.median(r)) if r.size else float("nan")


def plot_track_profile(
    path: str | os.PathLike,
    cols: Mapping[str, Any],
    *,
    sublayer: Mapping[str, Any] | None = None,
    piv: Mapping[str, Any] | None = None,
    dns: DNSProfile | None = None,
    title: str = "",
    dpi: int = 120,
) -> pathlib.Path:
    """Write the track profile's figure: the mean velocity (left), the stresses (right).

    Parameters
    ----------
    path : path-like
        The PNG file.
    cols : mapping
        The profile's columns as ``rspiv ptv`` writes them: ``h_px``, ``U``, ``se_U``, ``uu``,
        ``vv``, ``uv`` with their ``se_*``, ``near_wall``, optionally ``vv_two`` and
        ``se_vv_two`` (the two-track ``vv``, without the tracks' own error: a third panel,
        ``vv`` at the wall with and without it), and in wall units ``y_plus``,
        ``U_plus``, ``uu_plus``, ``vv_plus``, ``uv_plus`` when known.
    sublayer : mapping, optional
        The sublayer fit (``rspiv ptv``'s JSON ``"sublayer"``: ``fitted``, ``gradient``,
        ``wall_offset_px``, ``h_range_px``, ``u_tau``, ``se_u_tau``): its line over the range
        fitted.
    piv : mapping, optional
        The campaign's windowed profile of the run (``profile_<run>.csv``'s columns ``y_plus``
        and ``U_plus``), drawn in wall units.
    dns : DNSProfile, optional
        The reference, in wall units.
    title : str
        Above the figure.

    Returns
    -------
    pathlib.Path
    """
    from matplotlib.figure import Figure

    h = np.asarray(cols["h_px"], dtype=np.float64)
    if h.ndim != 1 or h.size == 0:
        raise InvalidInputError("cols['h_px']: a profile of at least one bin is needed")
    plus = "y_plus" in cols and np.isfinite(np.asarray(cols["y_plus"], dtype=float)).any()
    fy = _ratio(np.asarray(cols["y_plus"], float), h) if plus else 1.0
    fu = _ratio(np.asarray(cols["U_plus"], float), np.asarray(cols["U"], float)) if plus else 1.0
    plus = plus and np.isfinite(fy) and np.isfinite(fu)
    if not plus:
        fy = fu = 1.0
    y = h * fy
    near = np.asarray(cols.get("near_wall", np.zeros_like(h)), dtype=float) > 0
    two = "vv_two" in cols and np.isfinite(np.asarray(cols["vv_two"], dtype=float)).any()
    fig = Figure(figsize=(15.5 if two else 11, 4.6))
    ax_u, ax_s, *rest = fig.subplots(1, 3 if two else 2)
    ax_v = rest[0] if two else None
    y_top = float(np.nanmax(y)) * 1.05 if np.isfinite(y).any() else 1.0
    y_wall = 10.0 if plus else y_top / 3  # the third panel's reach: y+ 10, or a third

    def bars(ax, key: str, sign: float, fmt: str, label: str, colour: str) -> None:
        v = sign * np.asarray(cols[key], dtype=float) * (fu if key == "U" else fu * fu)
        e = 2.0 * np.asarray(cols[f"se_{key}"], dtype=float) * (fu if key == "U" else fu * fu)
        for sel, kw in ((~near, {"color": colour, "label": label}),
                        (near, {"color": "0.6", "mfc": "none"})):  # fmt: skip
            if sel.any():
                ax.errorbar(y[sel], v[sel], yerr=e[sel], fmt=fmt, ms=3, capsize=0,
                            elinewidth=0.6, **kw)  # fmt: skip

    bars(ax_u, "U", 1.0, "o", "tracks (2 SE)", "C0")
    if near.any():
        ax_u.plot([], [], "o", color="0.6", mfc="none", ms=3,
                  label="within a particle image of the wall")  # fmt: skip
    if plus:
        yy = np.linspace(0.0, y_top, 50)
        ax_u.plot(yy, yy, ":", color="0.3", lw=0.8, label="U+ = y+")
    if sublayer and sublayer.get("fitted"):
        g, h0 = float(sublayer["gradient"]), float(sublayer["wall_offset_px"])
        lo, hi = sublayer["h_range_px"]
        hh = np.linspace(min(0.0, h0), float(hi), 20)
        lab = "sublayer fit"
        if sublayer.get("u_tau") is not None:
            lab += f": u_tau {sublayer['u_tau']:.4g} +- {sublayer['se_u_tau']:.2g} m/s"
        ax_u.plot(hh * fy, g * (hh - h0) * fu, "-", color="C3", lw=1.0, label=lab)
    if plus and dns is not None:
        sel = dns.y_plus <= y_top
        ax_u.plot(dns.y_plus[sel], dns.u_plus[sel], "-", color="k", lw=0.8,
                  label=f"DNS Re_theta {dns.re_theta:g}")  # fmt: skip
        ax_s.plot(dns.y_plus[sel], dns.urms_plus[sel] ** 2, "-", color="C0", lw=0.8)
        ax_s.plot(dns.y_plus[sel], dns.vrms_plus[sel] ** 2, "-", color="C1", lw=0.8)
        ax_s.plot(dns.y_plus[sel], -dns.uv_plus[sel], "-", color="C2", lw=0.8,
                  label="DNS")  # fmt: skip
    if plus and piv is not None:
        yp = np.asarray(piv["y_plus"], dtype=float)
        sel = (yp > 0) & (yp <= y_top)
        ax_u.plot(yp[sel], np.asarray(piv["U_plus"], float)[sel], "s", ms=4, mfc="none",
                  color="C4", label="windows (the campaign)")  # fmt: skip
    bars(ax_s, "uu", 1.0, "o", "uu", "C0")
    bars(ax_s, "vv", 1.0, "^", "vv", "C1")
    bars(ax_s, "uv", -1.0, "s", "-uv", "C2")
    if ax_v is not None:  # vv at the wall, with and without the tracks' own error
        sel = ~near & (y <= y_wall)
        for key, fmt, colour, label in (
            ("vv", "^", "C1", "single tracks (with their error)"),
            ("vv_two", "v", "C3", "two-track (without it)"),
        ):
            v = np.asarray(cols[key], dtype=float)[sel] * fu * fu
            e = 2.0 * np.asarray(cols[f"se_{key}"], dtype=float)[sel] * fu * fu
            ax_v.errorbar(y[sel], v, yerr=e, fmt=fmt, ms=3, capsize=0, elinewidth=0.6,
                          color=colour, label=label)  # fmt: skip
        if plus and dns is not None:
            d = dns.y_plus <= y_wall
            ax_v.plot(dns.y_plus[d], dns.vrms_plus[d] ** 2, "-", color="k", lw=0.8, label="DNS")
        ax_v.set_xlim(0.0, y_wall)
        ax_v.axhline(0.0, color="0.8", lw=0.5)
        ax_v.set_xlabel("y+" if plus else "distance from the wall (px)")
        ax_v.set_ylabel("vv+" if plus else "vv (px^2)")
        ax_v.set_title("vv at the wall (2 SE)")
        ax_v.legend(fontsize=7, loc="upper left")
    unit = "+" if plus else " (px)"
    ax_u.set_xlabel("y+" if plus else "distance from the wall (px)")
    ax_u.set_ylabel("U+" if plus else "U (px per pair)")
    ax_s.set_xlabel(ax_u.get_xlabel())
    ax_s.set_ylabel("uu+, vv+, -uv+" if plus else "uu, vv, -uv (px^2)")
    ax_s.set_title(f"Reynolds stresses{'' if plus else ' (px^2)'} of the tracks")
    ax_u.set_title(f"Mean velocity{unit} of the tracks")
    for ax in (ax_u, ax_s):
        ax.set_xlim(0.0, y_top)
        ax.axhline(0.0, color="0.8", lw=0.5)
        ax.legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, pathlib.Path(path), dpi)
