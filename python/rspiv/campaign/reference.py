"""A campaign's profiles held against the DNS (:mod:`rspiv.reference_comparison`): each run's
entry in ``summary.json`` (``runs.<run>.reference``), its lines in the log and a report section.

The DNS station is the one nearest each run's Re_tau, the final window in wall units that of
the run (its viscous length at the calibration's magnification). The log says whether every
band agrees within three errors, or which differ; the report tabulates every band.
"""

from __future__ import annotations

from typing import Any

from rspiv.errors import RspivError
from rspiv.reference_comparison import (
    REPORT_TEXT,
    ReferenceComparison,
    compare_reference,
    viscous_window,
)
from rspiv.report import ReportSection, ReportTable

#: ``camp.info`` key holding the comparisons of this analysis, by run label.
INFO_KEY = "reference_comparisons"


def run_entry(camp: Any, an: Any, window: tuple[int, int]) -> dict[str, Any] | None:
    """The comparison of run analysis ``an`` (SI profile) with the DNS as a JSON-ready dict,
    kept for the report; None (said in the log) when there is none."""
    res, m_per_px = an.result, an.profile.get("m_per_px")
    if res is None or not m_per_px:
        return None
    try:
        cmp = compare_reference(res, window_plus=viscous_window(res, window, m_per_px))
    except (RspivError, ValueError) as exc:
        camp.say(f"{an.run.label}: no comparison with the DNS: {exc}")
        return None
    camp.info.setdefault(INFO_KEY, {})[an.run.label] = cmp
    camp.say(f"{an.run.label}: {cmp.verdict()}")
    return cmp.to_dict()


def report_section(camp: Any) -> ReportSection | None:
    """The report's section: every run's bands against the DNS."""
    cmps: dict[str, ReferenceComparison] = camp.info.get(INFO_KEY) or {}
    if not cmps:
        return None
    tables = [
        ReportTable(f"{label} against {cmp.reference}", cmp.table_rows())
        for label, cmp in cmps.items()
    ]
    text = REPORT_TEXT + "\n\n" + "\n\n".join(
        f"{label}: " + "; ".join(cmp.lines()[-2:]) for label, cmp in cmps.items()
    )
    return ReportSection("Against the DNS", text=text, tables=tables)
