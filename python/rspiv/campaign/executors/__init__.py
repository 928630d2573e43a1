"""How a campaign runs: executors behind one interface.

An executor has ``execute(campaign, state, progress) -> (skipped, failed)``: it processes
``state.todo`` (the pairs still to do, after :meth:`rspiv.Campaign.begin_run` resumed the
checkpoint) with :func:`rspiv.campaign.pair.process_pair` wherever it likes, reduces every result
on the client through one :class:`rspiv.campaign.reduce.RunReducer` and keeps the checkpoint;
:meth:`rspiv.Campaign.run` does the rest (prepare, resume, analyse, the run log). An optional
``t_start`` attribute (``time.perf_counter()``) dates the run's start.

- :class:`~rspiv.campaign.executors.local.LocalExecutor`: in this process, pair after pair.
- :class:`~rspiv.campaign.executors.dask.DaskExecutor`: on dask.distributed (the ``dask``
  extra), chunks of pairs as tasks, merged in pair order
  (:func:`~rspiv.campaign.executors.dask.run_dask`).
"""

from __future__ import annotations

from typing import Any, Protocol

from rspiv.campaign.executors.local import LocalExecutor
from rspiv.campaign.state import RunState

__all__ = ["Executor", "LocalExecutor"]


class Executor(Protocol):
    """The interface of a campaign executor (module docstring)."""

    name: str

    def execute(
        self, campaign: Any, state: RunState, progress: Any
    ) -> tuple[dict[int, str], dict[int, str] | None]:
        """Process ``state.todo``; returns the skipped pairs and the failed ones (or None)."""
        ...
