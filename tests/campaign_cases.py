"""Campaign files of ``rspiv.demo.synth_campaign`` cut down to what a test module checks.

The demo's ``campaign.toml`` switches every statistic on (two-point, quadrant, POD, vorticity,
vortices, conditional averages, and so every pair's field files), since the demo shows them
all. A module that checks something else (the ensemble band, the conditioning, the screen)
switches them off with :func:`lean`: the pairs' PIV and the statistics it checks are the same
either way (each statistic is summed on its own), and the run takes a fraction of the time.
"""

from __future__ import annotations

import pathlib
import re

EXTRAS = ("two_point", "quadrant", "pod", "vorticity", "vortices", "conditional")


def switch(text: str, key: str, on: bool) -> str:
    """Set the boolean ``key = ...`` lines (at the start of a line) to ``on``."""
    value = "true" if on else "false"
    new, n = re.subn(rf"^{key} = (true|false)$", f"{key} = {value}", text, flags=re.MULTILINE)
    assert n >= 1, f"no '{key} = ...' line in the campaign file"
    return new


def lean(
    text: str,
    *,
    keep: tuple[str, ...] = (),
    fields: bool = False,
    report: bool = True,
    uncorrected: bool = True,
) -> str:
    """The campaign file ``text`` with the statistics of :data:`EXTRAS` not in ``keep`` off.

    ``fields``: every pair's field files (``[output] fields``); ``report``: the report and its
    figures; ``uncorrected``: the run without correction beside the corrected ones.
    """
    unknown = set(keep) - set(EXTRAS)
    assert not unknown, f"not a statistic of the demo's campaign: {sorted(unknown)}"
    for key in EXTRAS:
        text = switch(text, key, key in keep)
    text = switch(text, "fields", fields)
    text = switch(text, "report", report)
    return switch(text, "compare_uncorrected", uncorrected)


def lean_file(toml: pathlib.Path, **kwargs) -> pathlib.Path:
    """:func:`lean` of the file ``toml``, written in place; returns ``toml``."""
    toml.write_text(lean(toml.read_text(), **kwargs))
    return toml


def lean_config(cfg, *, keep: tuple[str, ...] = (), fields: bool = False):
    """:func:`lean` of a loaded campaign configuration (``rspiv.campaign_config``), in place:
    the statistics of :data:`EXTRAS` not in ``keep`` off, and the field files unless
    ``fields``. Returns ``cfg``."""
    unknown = set(keep) - set(EXTRAS)
    assert not unknown, f"not a statistic of the demo's campaign: {sorted(unknown)}"
    for key in EXTRAS:
        setattr(cfg.statistics, key, key in keep)
    cfg.output.fields = fields
    return cfg


def sequential_config(out: pathlib.Path, dt: float = 0.0, **images):
    """A time-resolved campaign of ``images`` (:class:`rspiv.campaign_config.ImagesConfig`
    keys) paired sequentially, without calibration, wall or report, 32 -> 16 px windows, its
    ``[flow] dt`` and output folder given: the high-speed recordings' tests."""
    from rspiv.campaign_config import CampaignConfig, ImagesConfig

    cfg = CampaignConfig()
    cfg.images = ImagesConfig(pairing="sequential", **images)
    cfg.correction.method = "none"
    cfg.correction.compare_uncorrected = False
    cfg.calibration.monte_carlo_samples = 0
    cfg.wall.enabled = False
    cfg.piv.passes = [(32, 32), (16, 16)]
    cfg.flow.dt = dt
    cfg.output.dir = out
    cfg.output.report = False
    return cfg
