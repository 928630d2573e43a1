"""The campaign pipeline: a campaign file in, statistics, profiles and a report out.

What runs is kept apart from how it runs. The package's homes: :mod:`~rspiv.campaign.spec` (pairs,
runs, the frozen :class:`PairContext`), :mod:`~rspiv.campaign.prepare` (calibration, Monte
Carlo, wall pilot), :mod:`~rspiv.campaign.pair` (the per-pair work), :mod:`~rspiv.campaign.reduce`
(the one reduce/log step), :mod:`~rspiv.campaign.checkpoint`, :mod:`~rspiv.campaign.analysis`
(walls, profiles, outputs, report), :mod:`~rspiv.campaign.runner` (:class:`Campaign`, the run
skeleton) and :mod:`~rspiv.campaign.executors` (local, Dask).

``rspiv process campaign.toml`` and ``rspiv.Campaign.load(path).run()`` run the same code:

1. **Prepare** (:meth:`Campaign.prepare`): calibrate from the target image (figures, Monte
   Carlo), then a *pilot* over the first few pairs finds the wall in the corrected field and
   its angle; the calibration is rotated by ``-angle`` (paper section 3.2). Everything the
   per-pair work needs is frozen into a picklable :class:`PairContext` (mapping JSON, PIV
   settings, runs) and written to ``OUT/context.json``; shards and restarts reuse it.
2. **Map** over pairs (an executor): :func:`process_pair` ``(context, pair) -> PairResult`` is
   a pure function (reads the frames, corrects, runs PIV for every run: the main method, optionally
   the uncorrected processing and extra methods). A pair that cannot be read, or whose frames
   differ in size, is *skipped*: recorded with its reason in ``OUT/run_log.jsonl`` and never
   counted in the statistics.
3. **Reduce**: each run's fields go into a :class:`~rspiv.stats.FieldAccumulator` (px per pair,
   object frame), keyed by the pair id (a pair is never counted twice). Every
   ``checkpoint_every`` pairs and at the end the accumulators and the finished ids are written
   atomically to ``OUT/checkpoint/``; a restarted run loads them and skips the finished pairs.
4. **Analyse** (unsharded runs): per run the wall is found from the mean field's mirror
   symmetry, the statistics are averaged along x into profiles from the wall and converted to
   SI units (``M`` from the calibration, ``dt`` and ``nu`` from ``[flow]``), the boundary layer
   is analysed (:func:`rspiv.analyse_profile`) and the outputs are written atomically:
   ``statistics_<run>.nc`` (pivpy names, CF units), ``profile_<run>.nc``, ``profile_<run>.csv``,
   ``summary.json`` and ``report/report.{md,html}``; the profiles carry the skewness and
   flatness of u and v with their errors and the ``near_wall`` flag of the rows the wall
   shapes (:func:`rspiv.campaign.analysis.profile_extra`). With ``[output] fields = true`` each
   pair's vector fields are written as it is processed, in px per pair
   (:mod:`~rspiv.campaign.fields`: ``OUT/fields/<run>/pair_<id>.nc``).

Sharding (``shard=(i, n)``, 1-based, ``rspiv process --shard i/n``) processes the i-th of n
contiguous slices of the pair list and writes the raw accumulators to
``OUT/shards/statistics_<run>.shard-<i>-of-<n>.nc`` (:meth:`FieldAccumulator.to_xarray`, exact
state) for a later merge instead of analysing.

Frames and units: PIV runs in px; the main and comparison runs are in the object frame (object
px, the dewarped frame), the uncorrected run in the raw image frame. Accumulators hold
displacements in px per pair along the pixel axes; outputs are in m, m/s with x streamwise
(direction of the mean flow) and y from the wall into the flow.
"""

from rspiv.campaign.fields import FieldWriter
from rspiv.campaign.pair import process_pair
from rspiv.campaign.runner import Campaign
from rspiv.campaign.spec import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    STAGES,
    PairContext,
    PairResult,
    PairSpec,
    RunSpec,
    parse_shard,
    shard_slice,
)
from rspiv.campaign.state import CampaignResult, RunAnalysis, RunState

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "STAGES",
    "Campaign",
    "CampaignResult",
    "FieldWriter",
    "PairContext",
    "PairResult",
    "PairSpec",
    "RunAnalysis",
    "RunSpec",
    "RunState",
    "process_pair",
    "parse_shard",
    "shard_slice",
]
