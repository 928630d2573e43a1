"""The campaign file's vocabulary: every key of every section with the check that turns its TOML
value into the typed value of :mod:`rspiv.campaign_config` (or raises a one-line
:class:`~rspiv.errors.InvalidInputError` naming the file and the key), and the old key names
still read. The sections, their defaults and the loader live in :mod:`rspiv.campaign_config`.
"""

from __future__ import annotations

import os
import pathlib
import re
from typing import Any

from rspiv.derivatives import SCHEMES
from rspiv.errors import InvalidInputError
from rspiv.io import RECORDING_SUFFIXES
from rspiv.settings import (
    DEFORMATIONS,
    INTERPOLATIONS,
    MAPPING_MODES,
    SUBPIXELS,
    WEIGHTINGS,
    parse_method,
    parse_roi,
)

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".bmp", ".jpg", ".jpeg", ".im7", ".imx", ".ims")


class Ctx:
    """The file being read: its name for the messages, its folder for relative paths."""

    def __init__(self, fname: str, base: pathlib.Path):
        self.fname = fname
        self.base = base

    def err(self, where: str, msg: str) -> InvalidInputError:
        return InvalidInputError(f"{self.fname}: {where}: {msg}")

    def path(self, where, v, *, image=False, allow_empty=True, tiff=False, json_ok=False):
        if not isinstance(v, str):
            raise self.err(where, f"expected a path string, got {v!r}")
        if v == "":
            if allow_empty:
                return None
            raise self.err(where, "expected a path, got an empty string")
        pth = pathlib.Path(os.path.expanduser(v))
        suffix = pth.suffix.lower()
        if tiff and suffix not in (".tif", ".tiff") + RECORDING_SUFFIXES:
            raise self.err(
                where, f"expected a multi-frame TIFF (.tif, .tiff) or a high-speed recording "
                f"({', '.join(RECORDING_SUFFIXES)}), got {v!r}"
            )  # fmt: skip
        if image and not tiff and suffix not in IMAGE_SUFFIXES + ((".json",) if json_ok else ()):
            raise self.err(
                where, f"expected an image file ({', '.join(IMAGE_SUFFIXES)}), got {v!r}"
            )
        return pathlib.Path(os.path.normpath(pth if pth.is_absolute() else self.base / pth))


def _number(ctx, where, v, *, integer=False, minimum=None, exclusive_min=False, maximum=None):
    kind = "an integer" if integer else "a number"
    if (
        isinstance(v, bool)
        or not isinstance(v, (int, float))
        or (integer and not isinstance(v, int))
    ):
        raise ctx.err(where, f"expected {kind}, got {v!r}")
    if v != v or v in (float("inf"), float("-inf")):
        raise ctx.err(where, f"expected a finite number, got {v!r}")
    if minimum is not None and (v <= minimum if exclusive_min else v < minimum):
        rel = ">" if exclusive_min else ">="
        raise ctx.err(where, f"expected a value {rel} {minimum}, got {v!r}")
    if maximum is not None and v > maximum:
        raise ctx.err(where, f"expected a value <= {maximum}, got {v!r}")
    return int(v) if integer else float(v)


def _boolean(ctx, where, v):
    if not isinstance(v, bool):
        raise ctx.err(where, f"expected true or false, got {v!r}")
    return v


def _quarter_turn(ctx, where, v):
    """Degrees counter-clockwise, a multiple of 90 from 0 to 270 (``[images] rotate``)."""
    if isinstance(v, bool) or not isinstance(v, int) or v not in (0, 90, 180, 270):
        raise ctx.err(where, f"expected 0, 90, 180 or 270 (degrees counter-clockwise), got {v!r}")
    return v


def _choice(ctx, where, v, options, fold=None):
    """``v`` if it is one of ``options``; with ``fold`` (e.g. ``str.upper``) any case is
    accepted and folded to the options' spelling."""
    if isinstance(v, str) and fold is not None and fold(v) in options:
        return fold(v)
    if not isinstance(v, str) or v not in options:
        raise ctx.err(where, f"expected one of {', '.join(map(repr, options))}, got {v!r}")
    return v


def _string(ctx, where, v):
    if not isinstance(v, str):
        raise ctx.err(where, f"expected a string, got {v!r}")
    return v


def _passes(ctx, where, v):
    msg = "expected a list of [w, h] pairs"
    if not isinstance(v, list) or not v:
        raise ctx.err(where, f"{msg}, got {v!r}")
    out = []
    for item in v:
        if (
            not isinstance(item, list)
            or len(item) != 2
            or not all(isinstance(t, int) and not isinstance(t, bool) for t in item)
        ):
            raise ctx.err(where, f"{msg}, got {v!r}")
        w, h = item
        if w < 2 or h < 2:
            raise ctx.err(where, f"window sizes must be >= 2 px, got {item!r}")
        out.append((w, h))
    return out


def _roi(ctx, where, v):
    """``[x0, y0, x1, y1]``: a region of interest of whole px (:func:`rspiv.settings.parse_roi`)."""
    try:
        return list(parse_roi(v))
    except InvalidInputError as exc:
        raise ctx.err(where, str(exc)) from None


def _pair(ctx, where, v, *, integer, minimum):
    """``[a, b]``: two numbers (integers when ``integer``), each >= ``minimum`` (integers) or
    > ``minimum`` (floats)."""
    kind = "integers" if integer else "numbers"
    if not isinstance(v, list) or len(v) != 2:
        raise ctx.err(where, f"expected a list of two {kind}, got {v!r}")
    out = []
    for item in v:
        bad = isinstance(item, bool) or not isinstance(item, (int, float))
        if integer:
            bad = bad or isinstance(item, float)
        if bad or not (item >= minimum if integer else item > minimum):
            rel = ">=" if integer else ">"
            raise ctx.err(where, f"expected two {kind} {rel} {minimum}, got {v!r}")
        out.append(int(item) if integer else float(item))
    return tuple(out)


def _increasing(ctx, where, v, *, positive: bool, min_len: int):
    """A list of ``min_len`` to 8 increasing numbers, > 0 (``positive``) or >= 0."""
    count = "at most 8" if min_len == 0 else f"{min_len} to 8"
    msg = f"expected a list of {count} increasing numbers {'> 0' if positive else '>= 0'}"
    if not isinstance(v, list) or not min_len <= len(v) <= 8:
        raise ctx.err(where, f"{msg}, got {v!r}")
    out = [_number(ctx, where, t, minimum=0, exclusive_min=positive) for t in v]
    if any(b <= a for a, b in zip(out, out[1:], strict=False)):
        raise ctx.err(where, f"{msg}, got {v!r}")
    return tuple(float(t) for t in out)


def _heights(ctx, where, v):
    """The two-point maps' reference heights: at most 8, positive, increasing."""
    return _increasing(ctx, where, v, positive=True, min_len=0)


def _holes(ctx, where, v):
    """The quadrant analysis's hole sizes: 1 to 8, >= 0, increasing."""
    return _increasing(ctx, where, v, positive=False, min_len=1)


def _segment(ctx, where, v):
    """Pairs per Welch segment: an even integer from 8 to 65536."""
    n = _number(ctx, where, v, integer=True, minimum=8, maximum=65536)
    if n % 2:
        raise ctx.err(where, f"expected an even number of pairs, got {v!r}")
    return n


def _pair_ids(ctx, where, v):
    """``[id, ...]``: pair ids (positions in the campaign's pair list, >= 0), sorted, once each."""
    if not isinstance(v, list) or any(
        isinstance(k, bool) or not isinstance(k, int) or k < 0 for k in v
    ):
        raise ctx.err(where, f"expected a list of pair ids (integers >= 0), got {v!r}")
    return sorted(set(v))


#: The names a campaign's runs can have (:meth:`rspiv.campaign.runner.Campaign.runs`).
RUN_NAMES = ("method_I", "method_II", "uncorrected")


def _run_names(ctx, where, v):
    """``["method_II", ...]``: runs of a campaign, once each."""
    if not isinstance(v, list) or any(r not in RUN_NAMES for r in v) or len(set(v)) < len(v):
        raise ctx.err(where, f"expected a list of {', '.join(map(repr, RUN_NAMES))} once each, "
                      f"got {v!r}")  # fmt: skip
    return tuple(v)


def _method(ctx, where, v):
    try:
        return parse_method(v)
    except InvalidInputError:
        raise ctx.err(where, f"expected one of 'I', 'II', 'none', got {v!r}") from None


#: Old keys still read: (section, old key) -> the vocabulary's key (the parser converts).
ALIASES = {
    ("piv", "median_epsilon"): "median_eps",
    ("piv", "deform"): "deformation",
    ("correction", "mapping"): "map_displacement",
}

# per section: key -> parser(ctx, where, value)
PARSERS: dict[str, dict[str, Any]] = {
    "campaign": {"name": _string, "description": _string},
    "calibration": {
        "target": lambda c, w, v: c.path(w, v, image=True),
        "pitch_mm": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "pitch_sigma_mm": lambda c, w, v: _number(c, w, v, minimum=0),
        "model": lambda c, w, v: _choice(c, w, v, ("R1", "R2", "P3"), fold=str.upper),
        "marker": lambda c, w, v: _choice(c, w, v, ("dot", "cross")),
        "marker_size_px": lambda c, w, v: _number(c, w, v, minimum=0),
        "monte_carlo_samples": lambda c, w, v: _number(c, w, v, integer=True, minimum=0),
        "level": lambda c, w, v: _number(c, w, v, integer=True, minimum=0, maximum=2),
    },
    "images": {
        "glob": lambda c, w, v: str(c.path(w, v, image=True, allow_empty=False)),
        "pairs": None,  # special-cased
        "multiframe": lambda c, w, v: c.path(w, v, image=True, allow_empty=False, tiff=True),
        "double_frame": lambda c, w, v: str(c.path(w, v, allow_empty=False)),
        "max_pairs": lambda c, w, v: _number(c, w, v, integer=True, minimum=0),
        "pairing": lambda c, w, v: _choice(c, w, v, ("pairs", "sequential"), fold=str.lower),
        "frame_gap": lambda c, w, v: _number(c, w, v, integer=True, minimum=1),
        "pair_step": lambda c, w, v: _number(c, w, v, integer=True, minimum=1),
        "rotate": lambda c, w, v: _quarter_turn(c, w, v),
        "mirror": _boolean,
        "check_pairs": lambda c, w, v: _number(c, w, v, integer=True, minimum=0),
        "exclude_pairs": _pair_ids,
    },
    "correction": {
        "method": _method,
        "mapping": lambda c, w, v: _choice(c, w, v, MAPPING_MODES, fold=str.lower) == "full",
        "map_displacement": _boolean,
        "compare_uncorrected": _boolean,
    },
    "piv": {
        "passes": _passes,
        "overlap": lambda c, w, v: _number(c, w, v, minimum=0, maximum=0.95),
        "iterations": lambda c, w, v: _number(c, w, v, integer=True, minimum=1),
        "deformation": lambda c, w, v: _choice(c, w, v, DEFORMATIONS, fold=str.lower),
        "interpolation": lambda c, w, v: _choice(c, w, v, INTERPOLATIONS, fold=str.lower),
        "subpixel": lambda c, w, v: _choice(c, w, v, SUBPIXELS, fold=str.lower),
        "weighting": lambda c, w, v: _choice(c, w, v, WEIGHTINGS, fold=str.lower),
        "validate": _boolean,
        "median_threshold": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "median_eps": lambda c, w, v: _number(c, w, v, minimum=0),
        "median_epsilon": lambda c, w, v: _number(c, w, v, minimum=0),
        "min_peak_ratio": lambda c, w, v: _number(c, w, v, minimum=0),
        "peak_candidates": lambda c, w, v: _number(c, w, v, integer=True, minimum=1, maximum=3),
        "uncertainty": _boolean,
        "roi": _roi,
        "deform": lambda c, w, v: "symmetric" if _boolean(c, w, v) else "offset",
        "mask": lambda c, w, v: c.path(w, v, image=True, json_ok=True),
    },
    "preprocess": {
        "background": lambda c, w, v: _choice(c, w, v, ("none", "min", "mean"), fold=str.lower),
        "percentile": lambda c, w, v: _number(c, w, v, minimum=0, maximum=100),
        "hot_pixels": lambda c, w, v: _number(c, w, v, minimum=0),
        "high_pass": lambda c, w, v: _number(c, w, v, minimum=0),
        "smooth": lambda c, w, v: _number(c, w, v, minimum=0, maximum=2),
        "cap": lambda c, w, v: _number(c, w, v, minimum=0),
        "min_max": lambda c, w, v: _number(c, w, v, integer=True, minimum=0),
    },
    "wall": {
        "enabled": _boolean,
        "side": lambda c, w, v: _choice(c, w, v, ("auto", "top", "bottom")),
        "rotate": _boolean,
        "stations": lambda c, w, v: _number(c, w, v, integer=True, minimum=2),
    },
    "flow": {
        "nu": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "dt": lambda c, w, v: _number(c, w, v, minimum=0),
        "u_inf": lambda c, w, v: _number(c, w, v, minimum=0),
    },
    "statistics": {
        "min_count": lambda c, w, v: _number(c, w, v, integer=True, minimum=1),
        "use_n_eff": _boolean,
        "fit_offset": _boolean,
        "reference_re_theta": lambda c, w, v: _number(c, w, v, minimum=0),
        "noise_correction": _boolean,
        "two_point": _boolean,
        "two_point_min_valid": lambda c, w, v: _number(
            c, w, v, minimum=0, exclusive_min=True, maximum=1
        ),
        "two_point_heights": _heights,
        "two_point_height_units": lambda c, w, v: _choice(
            c, w, v, ("delta", "px"), fold=str.lower
        ),
        "quadrant": _boolean,
        "quadrant_holes": _holes,
        "pod": _boolean,
        "pod_modes": lambda c, w, v: _number(c, w, v, integer=True, minimum=1, maximum=200),
        "pod_snapshots": lambda c, w, v: _number(c, w, v, integer=True, minimum=2, maximum=100000),
        "pod_height": lambda c, w, v: _number(c, w, v, minimum=0),
        "vorticity": _boolean,
        "vorticity_scheme": lambda c, w, v: _choice(c, w, v, tuple(SCHEMES), fold=str.lower),
        "vortices": _boolean,
        "vortex_threshold": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "vortex_min_diameter": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "vortex_fits": _boolean,
        "vortex_fit_shear": _boolean,
        "conditional": _boolean,
        "conditional_heights": lambda c, w, v: _increasing(c, w, v, positive=True, min_len=1),
        "conditional_height_units": lambda c, w, v: _choice(
            c, w, v, ("delta", "px"), fold=str.lower
        ),
        "conditional_hole": lambda c, w, v: _number(c, w, v, minimum=0),
        "temporal": _boolean,
        "temporal_heights": lambda c, w, v: _increasing(c, w, v, positive=True, min_len=1),
        "temporal_height_units": lambda c, w, v: _choice(
            c, w, v, ("delta", "px"), fold=str.lower
        ),
        "temporal_segment": _segment,
        "temporal_max_lag": lambda c, w, v: _number(
            c, w, v, integer=True, minimum=1, maximum=4096
        ),
        "spod": _boolean,
        "spod_segment": _segment,
        "spod_modes": lambda c, w, v: _number(c, w, v, integer=True, minimum=1, maximum=50),
        "spod_frequencies": lambda c, w, v: _number(
            c, w, v, integer=True, minimum=1, maximum=64
        ),
        "spod_height": lambda c, w, v: _number(c, w, v, minimum=0),
        "screen": lambda c, w, v: _number(c, w, v, minimum=0),
    },
    "ensemble": {
        "enabled": _boolean,
        "window": lambda c, w, v: _pair(c, w, v, integer=True, minimum=2),
        "step": lambda c, w, v: _pair(c, w, v, integer=False, minimum=0),
        "band": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "band_units": lambda c, w, v: _choice(c, w, v, ("px", "plus"), fold=str.lower),
        "auto_pairs": lambda c, w, v: _number(c, w, v, integer=True, minimum=1),
        "single_pixel": _boolean,
        "pixel_band": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "pixel_step": lambda c, w, v: _number(c, w, v, minimum=0.05),
        "pixel_segment": lambda c, w, v: _number(c, w, v, integer=True, minimum=8),
        "pixel_lags": lambda c, w, v: _pair(c, w, v, integer=True, minimum=1),
    },
    "ptv": {
        "enabled": _boolean,
        "runs": _run_names,
        "radius": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "bin_px": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "band_px": lambda c, w, v: _number(c, w, v, minimum=0, exclusive_min=True),
        "whole_frame": _boolean,
    },
    "output": {
        "dir": lambda c, w, v: c.path(w, v, allow_empty=False),
        "netcdf": _boolean,
        "csv": _boolean,
        "report": _boolean,
        "fields": _boolean,
    },
}


def parse_pairs(ctx, where, v):
    msg = "expected a list of [frame_a, frame_b] image paths"
    if not isinstance(v, list) or not v:
        raise ctx.err(where, f"{msg}, got {v!r}")
    out = []
    for item in v:
        if not isinstance(item, list) or len(item) != 2:
            raise ctx.err(where, f"{msg}, got {item!r}")
        out.append(
            (
                ctx.path(where, item[0], image=True, allow_empty=False),
                ctx.path(where, item[1], image=True, allow_empty=False),
            )
        )
    return out


def locate_toml_error(text: str, message: str) -> str:
    """``"[section].key: "`` of the line a TOML syntax error points at, or ``""``."""
    m = re.search(r"line (\d+)", message)
    lines = text.splitlines()
    if m:
        lineno = min(int(m.group(1)), len(lines))
    elif "end of document" in message:
        lineno = len(lines)
    else:
        return ""
    section, key = "", ""
    for i, line in enumerate(lines[:lineno]):
        s = line.strip()
        hm = re.match(r"^\[\s*([^\[\]]+?)\s*\]", s)
        if hm:
            section, key = hm.group(1), ""
            if i == lineno - 1:
                key = ""
            continue
        km = re.match(r"^([A-Za-z0-9_\-\.\"']+)\s*=", s)
        if km:
            key = km.group(1).strip("\"'")
    if not key and not section:
        return ""
    if not section:
        return f"{key}: "
    return f"[{section}].{key}: " if key else f"[{section}]: "


# ---------------------------------------------------------------------------- TOML writer
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        r = repr(v)
        return r if any(ch in r for ch in ".en") else r + ".0"
    if isinstance(v, str):
        esc = v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
        return f'"{esc}"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def toml_plain(v):
    """``v`` with every tuple a list, recursively (what TOML gives back for an array)."""
    if isinstance(v, dict):
        return {k: toml_plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [toml_plain(x) for x in v]
    return v


def dump_toml(data: dict[str, dict[str, Any]]) -> str:
    """Minimal TOML writer for the campaign's two-level dict of scalars and lists."""
    lines: list[str] = []
    for section, table in data.items():
        lines.append(f"[{section}]")
        for k, v in table.items():
            lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)
