"""Boundary-layer figures: U+(y+), the Reynolds stresses uu+, vv+, -uv+ in wall units and the
skewness and flatness of u and v, against the Schlatter & Örlü DNS and against other named runs
(e.g. "uncorrected").

Uses matplotlib's object API with the Agg canvas (no pyplot, no global backend change), writes
PNG files atomically.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_path
from rspiv.profiles import PAIR_ERROR_KEYS, judged_error
from rspiv.reference import DNSProfile, dns_profile_for_re_tau, load_dns

_STYLES = ("o", "s", "^", "v", "D", "<", ">", "p")
_KEYS = ("y_plus", "u_plus", "uu_plus", "vv_plus", "uv_plus")


def _extra(run: Any) -> Mapping[str, Any]:
    """A run's further columns (:attr:`~rspiv.boundary_layer.BoundaryLayerResult.extra`, or a
    mapping's ``"extra"``), empty if none."""
    ex = run.get("extra") if isinstance(run, Mapping) else getattr(run, "extra", None)
    return ex or {}


def _profile(name: str, run: Any) -> dict[str, np.ndarray]:
    """Accept a BoundaryLayerResult or a mapping with the wall-unit columns. The errors are
    those the run is judged by (:func:`rspiv.profiles.judged_error`): a row's scatter between
    pairs (``extra``'s ``eps_U_plus_pairs`` ... and ``pairs``) where it has
    :data:`~rspiv.profiles.VERDICT_PAIRS` pairs or more, else the bound ``eps_u_plus`` ..."""
    out = {}
    for k in _KEYS + ("eps_u_plus", "eps_uu_plus", "eps_vv_plus", "eps_uv_plus"):
        v = run.get(k) if isinstance(run, Mapping) else getattr(run, k, None)
        if v is None and k in _KEYS:
            raise InvalidInputError(f"runs[{name!r}]: missing {k!r}")
        if v is not None:
            out[k] = np.asarray(v, dtype=np.float64)
    ex = _extra(run)
    for key in PAIR_ERROR_KEYS:
        k = f"eps_{key.lower()}_plus"
        if k in out and "pairs" in ex:
            own = ex.get(f"eps_{key}_plus_pairs")
            out[k] = judged_error(out[k], own, ex["pairs"]) if own is not None else out[k]
    if "near_wall" in _extra(run):  # rows the wall shapes (rspiv.campaign.analysis)
        out["near_wall"] = np.asarray(_extra(run)["near_wall"], dtype=np.float64)
    n = out["y_plus"].size
    for k, v in out.items():
        if v.shape != (n,):
            raise InvalidInputError(f"runs[{name!r}].{k}: expected {n} values, got {v.shape}")
    return out


def _draw(ax, i: int, name: str, x, y, err) -> None:
    """Run ``i``'s points: the first run with error bars ``err`` where it has finite ones, the
    others as markers only."""
    mk = _STYLES[i % len(_STYLES)]
    if i == 0 and err is not None and np.isfinite(err).any():
        ax.errorbar(
            x, y, yerr=err, fmt=mk, ms=3, mfc="none", capsize=0, elinewidth=0.6, label=name
        )
    else:
        ax.plot(x, y, mk, ms=3, mfc="none", label=name)


def _save(fig, path: pathlib.Path, dpi: int) -> pathlib.Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path


def plot_boundary_layer(
    out_dir: str | os.PathLike,
    runs: Mapping[str, Any],
    *,
    dns: DNSProfile | None | bool = None,
    prefix: str = "",
    dpi: int = 120,
    with_laws: bool = True,
    moments: bool = True,
) -> dict[str, pathlib.Path]:
    """Write ``mean_velocity.png`` (U+ vs y+) and ``reynolds_stresses.png`` (uu+, vv+, -uv+).

    Parameters
    ----------
    out_dir : path-like
        Folder for the PNG files (created if missing).
    runs : mapping
        Run name -> :class:`~rspiv.boundary_layer.BoundaryLayerResult` (or a mapping with
        ``y_plus, u_plus, uu_plus, vv_plus, uv_plus``, optional ``eps_*`` and ``extra``). The
        first run is drawn with error bars where uncertainties are present (a row's scatter
        between pairs where it has 20 pairs or more, else the bound); the others as
        markers only. Rows flagged ``near_wall`` in ``extra`` (shaped by the wall, not the flow)
        are left out of the stress and moment figures.
    dns : DNSProfile, optional
        Reference profile; default: the vendored station closest in Re_tau to the first run
        (when it has ``re_tau``), else Re_theta = 4060. ``False`` draws none.
    prefix : str
        Prepended to the file names.
    moments : bool
        Also draw the skewness and flatness figure when the first run has them.

    Returns
    -------
    dict
        ``{"mean_velocity": path, "reynolds_stresses": path}``, and ``"higher_moments"``
        (``higher_moments.png``: skewness and flatness) when the first run has them in
        ``extra`` (``S_u``, ... :attr:`~rspiv.boundary_layer.BoundaryLayerResult.extra`).
    """
    from matplotlib.figure import Figure

    if not runs:
        raise InvalidInputError("runs: at least one run is needed")
    profiles = {name: _profile(name, run) for name, run in runs.items()}
    if dns is None:
        first = next(iter(runs.values()))
        re_tau = (
            first.get("re_tau") if isinstance(first, Mapping) else getattr(first, "re_tau", None)
        )
        dns = dns_profile_for_re_tau(float(re_tau)) if re_tau else None
        if dns is None:

            dns = load_dns(4060)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    # --- mean velocity
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.add_subplot()
    if dns:
        m = dns.y_plus > 0
        ax.plot(dns.y_plus[m], dns.u_plus[m], "k-", lw=1.2, label=dns.label())
    if with_laws:
        yl = np.geomspace(0.5, 12, 50)
        ax.plot(yl, yl, "k:", lw=0.8, label="U+ = y+")
        yg = np.geomspace(20, 5e3, 50)
        ax.plot(yg, np.log(yg) / 0.41 + 5.0, "k--", lw=0.8, label="ln(y+)/0.41 + 5.0")
    for i, (name, p) in enumerate(profiles.items()):
        m = p["y_plus"] > 0
        err = p["eps_u_plus"][m] if "eps_u_plus" in p else None
        _draw(ax, i, name, p["y_plus"][m], p["u_plus"][m], err)
    ax.set_xscale("log")
    y_lo = min(float(np.min(p["y_plus"][p["y_plus"] > 0])) for p in profiles.values())
    ax.set_xlim(left=min(1.0, 0.8 * y_lo))
    ax.set_xlabel("$y^+$")
    ax.set_ylabel("$U^+$")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=8)
    paths = {"mean_velocity": _save(fig, out_dir / f"{prefix}mean_velocity.png", dpi)}

    # --- Reynolds stresses
    fig = Figure(figsize=(6.4, 9.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    spec = (
        ("uu_plus", "eps_uu_plus", 1.0, r"$\overline{u'u'}^+$"),
        ("vv_plus", "eps_vv_plus", 1.0, r"$\overline{v'v'}^+$"),
        ("uv_plus", "eps_uv_plus", -1.0, r"$-\overline{u'v'}^+$"),
    )
    for ax, (key, ekey, sign, label) in zip(axes, spec, strict=True):
        if dns:
            m = dns.y_plus > 0
            ref = {"uu_plus": dns.uu_plus, "vv_plus": dns.vv_plus, "uv_plus": dns.uv_plus}[key]
            ax.plot(dns.y_plus[m], sign * ref[m], "k-", lw=1.2, label=dns.label())
        for i, (name, p) in enumerate(profiles.items()):
            m = (p["y_plus"] > 0) & (p.get("near_wall", 0.0) == 0)
            err = p[ekey][m] if ekey in p else None
            _draw(ax, i, name, p["y_plus"][m], sign * p[key][m], err)
        ax.set_ylabel(label)
        ax.set_xscale("log")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0].set_xlim(left=min(1.0, 0.8 * y_lo))
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("$y^+$")
    paths["reynolds_stresses"] = _save(fig, out_dir / f"{prefix}reynolds_stresses.png", dpi)

    # --- skewness and flatness, when the first run has them
    if moments and "S_u" in _extra(next(iter(runs.values()))):
        paths["higher_moments"] = _plot_moments(
            out_dir / f"{prefix}higher_moments.png", profiles, runs, dns, dpi, y_lo
        )
    return paths


def _plot_moments(path, profiles, runs, dns, dpi: int, y_lo: float) -> pathlib.Path:
    """``higher_moments.png``: S and F of u and v against y+ (the DNS's S(u), F(u); the
    Gaussian values 0 and 3 dotted), error bars on the first run (as the stresses': a row's
    scatter between pairs where it has 20 pairs or more); rows flagged ``near_wall`` are left
    out."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.6, 6.4), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    spec = (
        ("S_u", "$S(u)$", 0.0, "skewness_u"),
        ("F_u", "$F(u)$", 3.0, "flatness_u"),
        ("S_v", "$S(v)$", 0.0, None),
        ("F_v", "$F(v)$", 3.0, None),
    )
    y_hi = max(float(np.nanmax(p["y_plus"])) for p in profiles.values())
    for ax, (key, label, gauss, ref) in zip(axes.T.ravel(), spec, strict=True):
        ax.axhline(gauss, color="k", ls=":", lw=0.8)
        # the axis spans the values (the DNS's within the runs' y+) and the typical error bar,
        # not the largest ones (few samples or heavy tails)
        shown = [np.array([gauss])]
        if dns and ref is not None:
            m = dns.y_plus > 0
            ax.plot(dns.y_plus[m], getattr(dns, ref)[m], "k-", lw=1.2, label=dns.label())
            shown.append(getattr(dns, ref)[m & (dns.y_plus <= y_hi)])
        for i, (name, run) in enumerate(runs.items()):
            mom = _extra(run)
            if key not in mom:
                continue
            yp = profiles[name]["y_plus"]
            m = (yp > 0) & (profiles[name].get("near_wall", 0.0) == 0)
            val = np.asarray(mom[key], dtype=np.float64)
            shown.append(val[m])
            err = mom.get(f"eps_{key}")
            if err is not None and "pairs" in mom:  # the rows' scatter between pairs
                err = judged_error(err, mom.get(f"eps_{key}_pairs"), mom["pairs"])
            err = None if err is None else np.asarray(err, dtype=np.float64)[m]
            if i == 0 and err is not None and np.isfinite(err).any():
                # the typical error bar about the Gaussian value stays on the axis
                e = float(np.nanmedian(err))
                shown.append(np.array([gauss - e, gauss + e]))
            _draw(ax, i, name, yp[m], val[m], err)
        vals = np.concatenate(shown)
        vals = vals[np.isfinite(vals)]
        lo, hi = float(vals.min()), float(vals.max())
        pad = 0.08 * (hi - lo) + 0.1
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(label)
        ax.set_xscale("log")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0, 0].set_xlim(left=min(1.0, 0.8 * y_lo))
    axes[0, 0].legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("$y^+$")
    return _save(fig, path, dpi)


__all__ = ["plot_boundary_layer"]
