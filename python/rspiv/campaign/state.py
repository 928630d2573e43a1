"""The state of a campaign run and what it returns: the run log, :class:`RunState` (shared by
every executor between :meth:`rspiv.Campaign.open_run` and :meth:`rspiv.Campaign.finish_run`),
:class:`RunAnalysis` and :class:`CampaignResult`.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import pathlib
import tempfile
from typing import Any

import numpy as np

from rspiv.campaign.fields import FieldWriter
from rspiv.campaign.spec import PairContext, PairSpec, RunSpec
from rspiv.errors import InvalidInputError
from rspiv.stats import FieldAccumulator

__all__ = [
    "CampaignResult",
    "RunAnalysis",
    "RunLog",
    "RunState",
    "check_writable",
    "json_default",
]


def check_writable(out: pathlib.Path) -> None:
    """Create the output folder if needed and check a file can be written in it
    (InvalidInputError naming the folder otherwise)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".rspiv-write-test-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise InvalidInputError(
            f"{out}: the output folder is not writable ({exc.strerror or exc})"
        ) from None


def json_default(o: Any) -> Any:
    """JSON encoder fallback: numpy scalars and arrays, paths."""
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, pathlib.Path):
        return str(o)
    raise TypeError(type(o).__name__)


class RunLog:
    """Append-only JSON-lines log of a campaign (``OUT/run_log.jsonl``)."""

    def __init__(self, path: pathlib.Path):
        self.path = path

    def write(self, event: str, **data: Any) -> None:
        rec = {
            "time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "event": event,
            **data,
        }
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(rec, default=json_default) + "\n")

    def events(self, event: str) -> list[dict[str, Any]]:
        """The records of kind ``event``, oldest first (none when the log does not exist; a
        line that is not JSON, e.g. cut short by a crash, is passed over)."""
        try:
            lines = self.path.read_text(encoding="utf-8", errors="replace").splitlines()
        except FileNotFoundError:
            return []
        out = []
        for line in lines:
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and rec.get("event") == event:
                out.append(rec)
        return out


@dataclasses.dataclass
class RunAnalysis:
    """The analysis of one run: wall, profile in SI units and the boundary-layer result."""

    run: RunSpec
    wall: Any
    flow_side: str
    profile: dict[str, Any]
    result: Any
    error: str = ""

    def flow_vectors(self, acc: Any, min_count: int) -> np.ndarray:
        """The vectors the run's analyses use (the profiles' rule): on the flow side of the
        wall (``profile["dist_px"] > 0``) with at least ``min_count`` (and 2) valid samples in
        the run's FieldAccumulator ``acc``."""
        dist = np.asarray(self.profile["dist_px"], np.float64)
        return (acc.count >= max(int(min_count), 2)) & (dist > 0)[:, None]


@dataclasses.dataclass
class CampaignResult:
    """What :meth:`Campaign.run` returns.

    Attributes
    ----------
    out_dir : pathlib.Path
    context : PairContext
    accumulators : dict
        Run name -> FieldAccumulator (px per pair, pixel axes).
    analyses : dict
        Run name -> RunAnalysis (empty for a shard).
    n_pairs, n_done, n_resumed : int
        Pairs in this shard; processed OK in total; already finished before this run.
    skipped : dict
        Pair id -> reason, for the pairs skipped in this run.
    warned : dict
        Pair id -> warning, for the pairs in the statistics whose frames correlate only in
        part (:meth:`rspiv.PivField.warning`: a region unlit, outside the light sheet or too
        sparsely seeded gives random vectors that pass the median test): from the run log,
        over every run of the output folder with this configuration.
    timings : dict
        Seconds per stage summed over this run's pairs (:data:`rspiv.campaign.STAGES`) and
        ``prepare``, ``analysis``, ``total``.
    files : dict
        Output name -> path.
    wall_deviation : dict
        Condition -> the wall's maximum deviation (px), as in the paper's table.
    ensembles : dict
        Run name -> its ensemble profile near the wall (``[ensemble]``; empty without).
    pixel_profiles : dict
        Run name -> its single-pixel profile at the wall (``[ensemble] single_pixel``; empty
        without).
    two_point : dict
        Run name -> its streamwise spectra and two-point correlations (``[statistics]
        two_point``; empty without).
    quadrant : dict
        Run name -> its quadrant analysis (``[statistics] quadrant``; empty without).
    pod : dict
        Run name -> its proper orthogonal decomposition (``[statistics] pod``; empty without).
    vortices : dict
        Run name -> its vortex population (``[statistics] vortices``; empty without).
    conditional : dict
        Run name -> its conditional averages (``[statistics] conditional``; empty without).
    temporal : dict
        Run name -> its frequency spectra and convection velocities (``[statistics]
        temporal``; empty without).
    spod : dict
        Run name -> its spectral POD (``[statistics] spod``; empty without).
    vorticity : dict
        Run name -> its vorticity profile (``[statistics] vorticity``; empty without).
    """

    out_dir: pathlib.Path
    context: PairContext
    accumulators: dict[str, FieldAccumulator]
    analyses: dict[str, RunAnalysis]
    n_pairs: int
    n_done: int
    n_resumed: int
    skipped: dict[int, str]
    timings: dict[str, float]
    files: dict[str, pathlib.Path]
    wall_deviation: dict[str, float]
    info: dict[str, Any] = dataclasses.field(default_factory=dict)
    warned: dict[int, str] = dataclasses.field(default_factory=dict)
    #: run name -> the ensemble profile (:func:`rspiv.campaign.ensemble.ensemble_profile`)
    ensembles: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> the single-pixel profile (:mod:`rspiv.campaign.ensemble_pixel`)
    pixel_profiles: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its spectra and two-point correlations (:mod:`rspiv.campaign.two_point`)
    two_point: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its quadrant analysis (:mod:`rspiv.campaign.quadrant`)
    quadrant: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its POD (:mod:`rspiv.campaign.pod`)
    pod: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its vortex population (:mod:`rspiv.campaign.vortices`)
    vortices: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its conditional averages (:mod:`rspiv.campaign.conditional`)
    conditional: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its frequency spectra and convection velocities (:mod:`rspiv.campaign.temporal`)
    temporal: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its spectral POD (:mod:`rspiv.campaign.spod`)
    spod: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: run name -> its vorticity profile (:mod:`rspiv.campaign.vorticity`)
    vorticity: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    #: each pair's figures per run and the pairs unlike the main run
    #: (:func:`rspiv.campaign.pair_quality.write_outputs`: ``series``, ``outliers``)
    pair_quality: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def report(self) -> pathlib.Path | None:
        return self.files.get("report_html")

    def result(self, run: str | None = None):
        """The BoundaryLayerResult of ``run`` (default: the main run)."""
        name = run or self.context.runs[0].name
        return self.analyses[name].result


@dataclasses.dataclass
class RunState:
    """The state of a run between :meth:`Campaign.open_run` and :meth:`Campaign.finish_run`.

    Shared by every executor (:mod:`rspiv.campaign.executors`: local, Dask), which differ only
    in how they process ``todo``.

    Attributes
    ----------
    log : RunLog
        The run log (``OUT/run_log.jsonl``).
    all_pairs : list of PairSpec
        The campaign's full pair list.
    sel : list of PairSpec
        The pairs of this shard.
    t_start : float
        ``time.perf_counter()`` at the start of the run, s.
    ctx : PairContext or None
        The prepared context (set by :meth:`Campaign.begin_run`).
    t_prepare : float
        Time spent in :meth:`Campaign.prepare`, s.
    accs : dict of str to FieldAccumulator
        The accumulators per run, from the checkpoint or new; the run loop updates them.
    finished : set of int
        Ids of the pairs in ``accs``.
    timings : dict of str to float
        Time per stage summed over the pairs, s.
    n_resumed : int
        Pairs of ``sel`` already finished at the start (from the checkpoint).
    todo : list of PairSpec
        Pairs of ``sel`` still to process.
    fields : FieldWriter or None
        Writes each processed pair's fields (``[output] fields``), None when off.
    """

    log: RunLog
    all_pairs: list[PairSpec]
    sel: list[PairSpec]
    t_start: float
    ctx: PairContext | None = None
    t_prepare: float = 0.0
    accs: dict[str, FieldAccumulator] = dataclasses.field(default_factory=dict)
    finished: set[int] = dataclasses.field(default_factory=set)
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    n_resumed: int = 0
    todo: list[PairSpec] = dataclasses.field(default_factory=list)
    fields: FieldWriter | None = None
