"""The Dask executor: a campaign on dask.distributed (``rspiv process CAMPAIGN --dask ADDRESS``).

:func:`run_dask` runs the same campaign as :meth:`rspiv.Campaign.run` with the per-pair work
spread over Dask workers (:class:`DaskExecutor`, one of :mod:`rspiv.campaign.executors`; the
results are reduced on the client through the same :class:`~rspiv.campaign.reduce.RunReducer`
as a local run):

1. The client prepares the campaign (calibration, wall pilot: :meth:`Campaign.prepare`) and
   loads the checkpoint, exactly as a local run does.
2. The pairs still to do are cut into contiguous *chunks*; each chunk is one task,
   :func:`process_chunk` ``(context, pairs) -> ChunkResult``, that runs
   :func:`rspiv.campaign.process_pair` on its pairs and returns a partial
   :class:`~rspiv.stats.FieldAccumulator` per run (keyed by pair id) plus the first field it
   added (see below). The context is scattered once to every worker.
3. Results are merged on the client *as they complete*. Chunks next to each other in pair
   order are joined (Chan's merge plus the one lag-1 sample pair that spans the junction), so
   the statistics, including the lag-1 moments behind ``n_eff``, are those of one sequential
   pass over the pairs, equal to a local run to rounding. The contiguous prefix is checkpointed
   in the campaign's own format (``OUT/checkpoint/``): a Dask run resumes a local run and vice
   versa.

Faults
    A pair that cannot be read is skipped and logged with its reason (as in a local run). A
    pair whose processing raises is recorded as *failed* (``event: "failed"`` in the run log,
    with the exception) and left out of the statistics. A worker that dies is replaced by
    Dask and its chunk recomputed elsewhere; a chunk that kills workers repeatedly
    (:class:`distributed.KilledWorker`) is split into single pairs. A single pair whose worker
    died may have been only queued beside the pair that killed it (Dask counts every task on a
    dying worker as suspect), so it is run once more, apart from the other suspects: such
    retries are submitted one at a time (``event: "pair_retry"``), and a pair whose worker dies
    on its retry is recorded as failed. A killed client resumes from the last checkpoint:
    the contiguous prefix is in the campaign's checkpoint, and the segments merged out of order
    beside it are saved in ``OUT/checkpoint/dask_segments*.pkl`` (keyed by their pair ids;
    reused by the next Dask run when they still fit, ignored by a local run), so no pair merged
    at the last checkpoint is recomputed.

Threads
    Every worker process shares one rayon pool among its task threads; rayon's global pool is
    sized from ``RAYON_NUM_THREADS`` when first used, so the variable is set before the first
    task: in the workers' environment for ``--dask local`` (``LocalCluster(env=...)``) and by
    :class:`RayonThreads`, a worker plugin, on an existing cluster. Default: the host's cores
    divided by the workers on that host, so that Dask and rayon do not oversubscribe the cores.

Progress
    Pairs done, pairs skipped or failed and the throughput (pairs per minute) go to the
    progress display and, every ``progress_interval`` seconds and at the end, to the run log
    (``event: "progress"``, ``event: "dask_summary"``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pickle
import socket
import time
import traceback
from collections.abc import Sequence
from typing import Any

import numpy as np

from rspiv.campaign import ensemble as ensemble_work
from rspiv.campaign import pair as pair_work
from rspiv.campaign import screen as screen_work
from rspiv.campaign.fields import FieldWriter
from rspiv.campaign.reduce import RunReducer, add_fields, new_accumulators
from rspiv.campaign.runner import Campaign
from rspiv.campaign.spec import STAGES, PairContext, PairSpec
from rspiv.campaign.state import CampaignResult, RunState
from rspiv.errors import InvalidInputError
from rspiv.memory import numpy_huge_pages
from rspiv.outputs import atomic_write_bytes
from rspiv.stats import FieldAccumulator

__all__ = [
    "ChunkResult",
    "DaskExecutor",
    "local_cluster",
    "process_chunk",
    "run_dask",
]


# ---------------------------------------------------------------------------- worker side
@dataclasses.dataclass
class ChunkResult:
    """What :func:`process_chunk` returns for a contiguous chunk of pairs.

    Attributes
    ----------
    accumulators : dict
        Run name -> FieldAccumulator of the chunk's good pairs (px per pair), pair ids kept.
    first : dict or None
        Run name -> ``(u, v, valid)`` of the first field added (None: no field added); with
        the accumulator's last field it lets adjacent chunks join their lag-1 chains.
    done : list of int
        Ids of the pairs added, in order.
    skipped : dict
        Pair id -> ``(files, reason)`` for unreadable pairs.
    failed : dict
        Pair id -> ``(files, reason)`` for pairs whose processing raised.
    pair_timings : dict
        Pair id -> seconds per stage.
    timings : dict
        Seconds per stage summed over the chunk.
    worker : str
        Host and pid of the worker process.
    warned : dict
        Pair id -> ``(files, warning)`` for pairs added whose frames correlate only in part
        (:attr:`rspiv.campaign.PairResult.warning`).
    pair_quality : dict
        Pair id -> the pair's figures per run (:attr:`rspiv.campaign.PairResult.quality`).
    """

    accumulators: dict[str, FieldAccumulator]
    first: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] | None
    done: list[int]
    skipped: dict[int, tuple[str, str]]
    failed: dict[int, tuple[str, str]]
    pair_timings: dict[int, dict[str, float]]
    timings: dict[str, float]
    worker: str = ""
    warned: dict[int, tuple[str, str]] = dataclasses.field(default_factory=dict)
    pair_quality: dict[int, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)


_CONTEXTS: dict[str, PairContext] = {}


def process_chunk(
    context: PairContext, pairs: Sequence[PairSpec], fields: FieldWriter | None = None
) -> ChunkResult:
    """Process ``pairs`` in order into one partial accumulator per run (a Dask task).

    Pure: reads the frames and writes nothing but, with ``fields``, each pair's field files
    (:mod:`rspiv.campaign.fields`: atomic, and the same again when a task is retried). Bad
    data is skipped (as in :meth:`Campaign.run`); an exception raised by one pair (or by the
    writing of its fields) marks that pair failed and the chunk goes on. numpy's huge pages
    are off while it runs, as in a local run (:mod:`rspiv.memory`).
    """
    with numpy_huge_pages(False):
        return _process_chunk(context, pairs, fields)


def _process_chunk(
    context: PairContext, pairs: Sequence[PairSpec], fields: FieldWriter | None
) -> ChunkResult:
    """:func:`process_chunk`'s work."""
    # one parsed context (mapping, mask) per worker process and campaign
    context = _CONTEXTS.setdefault(context.fingerprint(), context)
    # the same carried sums as the client's (ensemble band, two-point, vorticity): a chunk's
    # part merges whole
    accs = new_accumulators(context)
    screens = context.screens()
    ens = ensemble_work.band_accumulators(accs)
    first = None
    done: list[int] = []
    skipped: dict[int, tuple[str, str]] = {}
    failed: dict[int, tuple[str, str]] = {}
    warned: dict[int, tuple[str, str]] = {}
    quality: dict[int, dict[str, dict[str, float]]] = {}
    pair_timings: dict[int, dict[str, float]] = {}
    timings = {k: 0.0 for k in STAGES}
    cache = pair_work.FrameCache.for_pairs(pairs)  # sequential pairing: frames read once
    shape = tuple(context.image_shape)
    for p in pairs:
        try:
            t0 = time.perf_counter()
            frames = None if cache is None else pair_work.read_ahead(p, shape, cache)
            t_read = time.perf_counter() - t0
            r = pair_work.process_pair(context, p, frames=frames, ensembles=ens)
            if frames is not None:
                r.timings["read"] = t_read
        except Exception as exc:  # noqa: BLE001 - one bad pair must not lose the chunk
            tb = traceback.extract_tb(exc.__traceback__)
            where = f" at {tb[-1].filename}:{tb[-1].lineno}" if tb else ""
            failed[p.pair_id] = (p.describe(), f"{type(exc).__name__}: {exc}{where}")
            continue
        for k, v in r.timings.items():
            timings[k] = timings.get(k, 0.0) + v
        pair_timings[p.pair_id] = {k: round(v, 4) for k, v in r.timings.items()}
        if not r.ok:
            skipped[p.pair_id] = (p.describe(), r.reason)
            continue
        if fields is not None:
            try:
                timings["fields"] = timings.get("fields", 0.0) + fields.write(context, p, r)
            except OSError as exc:
                failed[p.pair_id] = (p.describe(), str(exc))  # "[output] fields: cannot write ..."
                continue
        t0 = time.perf_counter()
        if first is None:  # as the statistics take it: screened
            first = {}
            for n, (u, v, ok, *_) in r.fields.items():
                u, v, ok = screen_work.apply(screens.get(n), u, v, np.asarray(ok, bool))
                first[n] = (u.copy(), v.copy(), np.asarray(ok, bool).copy())
        dt = time.perf_counter() - t0 + add_fields(accs, r, screens)
        timings["statistics"] = timings.get("statistics", 0.0) + dt
        done.append(p.pair_id)
        quality[p.pair_id] = r.quality
        if r.warning:
            warned[p.pair_id] = (p.describe(), r.warning)
    return ChunkResult(
        accs,
        first,
        done,
        skipped,
        failed,
        pair_timings,
        timings,
        f"{socket.gethostname()}:{os.getpid()}",
        warned,
        quality,
    )


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


_PLUGIN: list = []


def _rayon_plugin_class():
    """The :class:`RayonThreads` class, built on first use (importing distributed takes about a
    second, which ``rspiv --help`` should not pay)."""
    if _PLUGIN:
        return _PLUGIN[0]
    from distributed.diagnostics.plugin import WorkerPlugin  # deferred: dask (optional extra)

    class RayonThreads(WorkerPlugin):
        """Worker plugin: set ``RAYON_NUM_THREADS`` in each worker before its first task.

        Parameters
        ----------
        threads : int, optional
            Rayon threads per worker process. Default: the worker host's usable cores divided
            by the number of workers on that host (``per_host``), at least 1.
        per_host : dict, optional
            Host -> number of workers there (from the scheduler when the plugin is registered).

        Notes
        -----
        Rayon reads the variable when its global pool is first used; a worker that already ran
        rspiv code keeps its pool, and a variable already set in the worker's environment is
        kept (``worker.rspiv_rayon`` records what was requested and what is set).
        """

        name = "rspiv-rayon-threads"

        def __init__(self, threads: int | None = None, per_host: dict[str, int] | None = None):
            self.threads = threads
            self.per_host = dict(per_host or {})

        def setup(self, worker) -> None:
            n = self.threads
            if n is None:
                host = worker.address.split("://")[-1].rsplit(":", 1)[0]
                n = max(1, _usable_cores() // max(self.per_host.get(host, 1), 1))
            if os.environ.get("RAYON_NUM_THREADS") is None:
                os.environ["RAYON_NUM_THREADS"] = str(int(n))
            worker.rspiv_rayon = {"requested": int(n), "env": os.environ["RAYON_NUM_THREADS"]}

    RayonThreads.__module__ = __name__
    RayonThreads.__qualname__ = "RayonThreads"
    _PLUGIN.append(RayonThreads)
    return RayonThreads


def __getattr__(name: str):
    if name == "RayonThreads":
        return _rayon_plugin_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ---------------------------------------------------------------------------- cluster
def local_cluster(n_workers: int | None = None, rayon_threads: int | None = None, **kwargs: Any):
    """A :class:`distributed.LocalCluster` sized to this machine, loopback only, no dashboard.

    ``n_workers`` processes of one task thread each (default: the usable cores, at most one
    per 3 GB of memory) and ``rayon_threads`` rayon threads per worker (default: cores //
    workers, at least 1), passed to the workers' environment before they start.
    """
    from distributed import LocalCluster  # deferred: dask (optional extra)

    cores = _usable_cores()
    if n_workers is None:
        try:
            import psutil  # comes with distributed

            mem = psutil.virtual_memory().total
            n_workers = max(1, min(cores, int(mem // (3 * 2**30))))
        except ImportError:  # pragma: no cover - psutil comes with distributed
            n_workers = cores
    n_workers = max(1, int(n_workers))
    if rayon_threads is None:
        rayon_threads = max(1, cores // n_workers)
    opts: dict[str, Any] = {
        "n_workers": n_workers,
        "threads_per_worker": 1,
        "processes": True,
        "host": "127.0.0.1",
        "dashboard_address": None,
        "env": {"RAYON_NUM_THREADS": str(int(rayon_threads))},
    }
    opts.update(kwargs)
    return LocalCluster(**opts)


def _workers_per_host(client) -> dict[str, int]:
    info = client.scheduler_info()
    per: dict[str, int] = {}
    for addr in info.get("workers", {}):
        host = addr.split("://")[-1].rsplit(":", 1)[0]
        per[host] = per.get(host, 0) + 1
    return per


# ---------------------------------------------------------------------------- ordered merge
@dataclasses.dataclass
class _Segment:
    """Merged results of the todo positions ``[lo, hi)`` (pair order)."""

    lo: int
    hi: int
    accs: dict[str, FieldAccumulator]
    first: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] | None
    done: list[int]


def _junction(shape, last_u, last_v, has_last, first) -> FieldAccumulator:
    """An accumulator holding only the lag-1 sample pair (last of the left part, first of the
    right part) where both are valid."""
    u1, v1, ok1 = first
    lag = np.asarray(has_last, bool) & ok1
    j = FieldAccumulator(shape)
    n = lag.astype(np.int64)
    for comp, a, b in (("u", last_u, u1), ("v", last_v, v1)):
        setattr(j, f"lag_count_{comp}", n.copy())
        setattr(j, f"lag_mean_a_{comp}", np.where(lag, a, 0.0))
        setattr(j, f"lag_mean_b_{comp}", np.where(lag, b, 0.0))
    return j


def _join(left: _Segment, right: _Segment) -> _Segment:
    """``left`` followed by ``right`` (adjacent): statistics of one pass over both."""
    if left.hi != right.lo:  # pragma: no cover - internal invariant
        raise AssertionError(f"segments [{left.lo}, {left.hi}) and [{right.lo}, {right.hi})")
    if right.first is None:  # nothing added on the right (all skipped)
        return _Segment(left.lo, right.hi, left.accs, left.first, left.done + right.done)
    if left.first is None and all(a.n_fields == 0 for a in left.accs.values()):
        return _Segment(left.lo, right.hi, right.accs, right.first, left.done + right.done)
    accs = {}
    for name, a in left.accs.items():
        b = right.accs[name]
        last = (b._last_u.copy(), b._last_v.copy(), b._has_last.copy())
        if a.n_fields > 0:
            a.merge(_junction(a.shape, a._last_u, a._last_v, a._has_last, right.first[name]))
        a.merge(b)
        a._last_u, a._last_v, a._has_last = last
        accs[name] = a
    return _Segment(left.lo, right.hi, accs, left.first, left.done + right.done)


class _OrderedMerge:
    """Segments of completed chunks, joined with their neighbours as they arrive."""

    def __init__(self, prefix: _Segment):
        self.by_lo: dict[int, _Segment] = {prefix.lo: prefix}
        self.lo_of_hi: dict[int, int] = {prefix.hi: prefix.lo}

    def add(self, seg: _Segment) -> None:
        while seg.lo in self.lo_of_hi:
            left = self.by_lo.pop(self.lo_of_hi.pop(seg.lo))
            seg = _join(left, seg)
        while seg.hi in self.by_lo:
            right = self.by_lo.pop(seg.hi)
            self.lo_of_hi.pop(right.hi)
            seg = _join(seg, right)
        self.by_lo[seg.lo] = seg
        self.lo_of_hi[seg.hi] = seg.lo

    @property
    def prefix(self) -> _Segment:
        return self.by_lo[0]

    def pending(self) -> int:
        return len(self.by_lo) - 1


# ---------------------------------------------------------------------------- run
SEGMENTS_FORMAT = "rspiv-dask-segments"


def _chunks(n: int, size: int) -> list[tuple[int, int]]:
    return [(lo, min(lo + size, n)) for lo in range(0, n, size)]


def _uncovered_chunks(n: int, covered: set[int], size: int) -> list[tuple[int, int]]:
    """Chunks of at most ``size`` positions over the maximal runs of ``range(n)`` not in
    ``covered``."""
    out: list[tuple[int, int]] = []
    k = 0
    while k < n:
        if k in covered:
            k += 1
            continue
        lo = k
        while k < n and k not in covered:
            k += 1
        out += [(a + lo, b + lo) for a, b in _chunks(k - lo, size)]
    return out


def _segments_path(camp: Campaign):
    i, n = camp.shard
    name = "dask_segments.pkl" if n == 1 else f"dask_segments.shard-{i}-of-{n}.pkl"
    return camp.out_dir / "checkpoint" / name


def _save_segments(path, ctx: PairContext, shard, todo: Sequence[PairSpec], merger) -> None:
    """Write the segments merged after the contiguous prefix (atomically), or remove the file
    when there are none; each is keyed by the ids of the pairs it covers."""
    pend = [sg for lo, sg in sorted(merger.by_lo.items()) if lo != 0]
    if not pend:
        path.unlink(missing_ok=True)
        return
    data = {
        "format": SEGMENTS_FORMAT,
        "fingerprint": ctx.fingerprint(),
        "shard": list(shard),
        "segments": [
            {
                "ids": [p.pair_id for p in todo[sg.lo : sg.hi]],
                "accs": sg.accs,
                "first": sg.first,
                "done": list(sg.done),
            }
            for sg in pend
        ],
    }
    atomic_write_bytes(path, pickle.dumps(data, protocol=pickle.HIGHEST_PROTOCOL))


def _load_segments(path, ctx: PairContext, shard, todo: Sequence[PairSpec]) -> list[_Segment]:
    """Segments saved by an interrupted Dask run that still fit the pairs to do: same
    configuration and shard, every covered pair still to do and contiguous in ``todo``.
    Anything else (stale, corrupt, overlapping) is ignored and recomputed."""
    if not path.is_file():
        return []
    try:
        data = pickle.loads(path.read_bytes())
        if data.get("format") != SEGMENTS_FORMAT:
            return []
    except Exception:  # noqa: BLE001 - a damaged file only costs recomputation
        return []
    if data.get("fingerprint") != ctx.fingerprint() or list(data.get("shard", ())) != list(shard):
        return []
    pos = {p.pair_id: k for k, p in enumerate(todo)}
    used: set[int] = set()
    out: list[_Segment] = []
    for sg in data.get("segments", []):
        ids = list(sg["ids"])
        if not ids or ids[0] not in pos:
            continue
        lo = pos[ids[0]]
        hi = lo + len(ids)
        if [p.pair_id for p in todo[lo:hi]] != ids or used & set(range(lo, hi)):
            continue
        used.update(range(lo, hi))
        out.append(_Segment(lo, hi, sg["accs"], sg["first"], list(sg["done"])))
    return out


def run_dask(
    campaign: Campaign,
    address: Any = "local",
    *,
    n_workers: int | None = None,
    rayon_threads: int | None = None,
    chunk_size: int | None = None,
    progress_interval: float = 30.0,
) -> CampaignResult:
    """Run (or resume) ``campaign`` on a Dask cluster; same outputs as :meth:`Campaign.run`.

    Parameters
    ----------
    campaign : Campaign
        Its ``shard``, ``checkpoint_every``, ``out_dir`` and ``show_progress`` apply.
    address : str or distributed.Client
        ``"local"``: a :func:`local_cluster` on this machine (closed at the end); a scheduler
        address (``"tcp://host:8786"``) or a scheduler file (``*.json``); or a connected
        ``Client``.
    n_workers, rayon_threads : int, optional
        ``"local"`` only: workers, and rayon threads per worker (see :func:`local_cluster`).
        On an existing cluster ``rayon_threads`` overrides the per-host default of
        :class:`RayonThreads`.
    chunk_size : int, optional
        Pairs per task. Default: about four tasks per worker, at most
        ``campaign.checkpoint_every`` pairs.
    progress_interval : float
        Seconds between ``progress`` records in the run log.

    Returns
    -------
    CampaignResult
        As :meth:`Campaign.run`; ``info["dask"]`` holds workers, chunks, pairs failed,
        throughput (pairs/min) and wall time of the map.
    """
    try:  # deferred: dask (optional extra)
        from distributed import Client
    except ImportError:  # pragma: no cover - optional extra
        raise InvalidInputError(
            "--dask needs dask.distributed: pip install 'rspiv[dask]'"
        ) from None

    t_start = time.perf_counter()
    own_cluster = None
    own_client = None
    if isinstance(address, Client):
        client = address
    elif address in (None, "local"):
        own_cluster = local_cluster(n_workers, rayon_threads)
        client = own_client = Client(own_cluster)
    else:
        text = str(address)
        own_client = client = (
            Client(scheduler_file=text) if text.endswith(".json") else Client(text)
        )
    try:
        if own_cluster is None:
            client.wait_for_workers(1, timeout=300)
            client.register_plugin(_rayon_plugin_class()(rayon_threads, _workers_per_host(client)))
        executor = DaskExecutor(client, chunk_size, progress_interval, t_start=t_start)
        return campaign.run(executor)
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()


class DaskExecutor:
    """Process the pairs still to do as chunks on a connected ``distributed.Client``, merged on
    the client in pair order (module docstring); see :func:`run_dask` for the parameters."""

    name = "dask"

    def __init__(
        self,
        client: Any,
        chunk_size: int | None = None,
        progress_interval: float = 30.0,
        *,
        t_start: float | None = None,
    ) -> None:
        self.client = client
        self.chunk_size = chunk_size
        self.progress_interval = float(progress_interval)
        self.t_start = t_start

    def execute(
        self, campaign: Campaign, state: RunState, progress: Any
    ) -> tuple[dict[int, str], dict[int, str]]:
        """Process ``state.todo`` on the cluster; returns ``(skipped, failed)`` and records
        ``campaign.info["dask"]``."""
        from distributed import as_completed  # deferred: dask (optional extra)

        client, todo, ctx = self.client, state.todo, state.ctx
        self.campaign, self.state, self.progress = campaign, state, progress
        n_workers = max(len(client.scheduler_info().get("workers", {})), 1)
        chunk_size = self.chunk_size
        if chunk_size is None:
            chunk_size = max(
                1, min(campaign.checkpoint_every, math.ceil(len(todo) / (4 * n_workers)))
            )
        chunk_size = max(1, int(chunk_size))
        campaign.announce_run(
            state,
            progress,
            dask={
                "scheduler": client.scheduler.address,
                "workers": n_workers,
                "chunk_size": chunk_size,
            },
        )
        progress.log(
            f"dask: {n_workers} worker(s) at {client.scheduler.address}, "
            f"{len(todo)} pair(s) in chunks of {chunk_size}"
        )
        self.red = RunReducer(campaign, state, progress)
        self.merger = _OrderedMerge(_Segment(0, 0, state.accs, None, []))
        self.seg_path = _segments_path(campaign)
        stored = _load_segments(self.seg_path, ctx, campaign.shard, todo)
        covered: set[int] = set()
        for sg in stored:
            covered.update(range(sg.lo, sg.hi))
        self.key_of: dict[Any, tuple[int, int]] = {}
        # single pairs whose worker died, waiting to be run alone, one at a time
        self.alone_queue: list[int] = []
        self.alone_key: Any = None
        futures = []
        n_chunks = 0
        for lo, hi in _uncovered_chunks(len(todo), covered, chunk_size):
            futures.append(self._submit(lo, hi))
            n_chunks += 1
        if stored:
            for sg in stored:
                self.merger.add(sg)
            state.log.write("resumed_segments", segments=len(stored), pairs=len(covered))
            progress.log(
                f"resuming: {len(covered)} pair(s) merged out of order before the interruption "
                f"not recomputed ({self.seg_path})"
            )
            progress.advance(len(covered))
        self.n_workers = n_workers
        self.t_map = time.perf_counter()
        self.t_last_log = self.t_map
        self.workers_seen: set[str] = set()
        self.ac = as_completed(futures)
        futures.clear()
        try:
            for fut in self.ac:
                self._handle(fut)
        except BaseException:
            self._checkpoint(force=True)  # the contiguous prefix is always consistent
            raise
        if self.merger.pending():  # pragma: no cover - every chunk joins the prefix at the end
            raise AssertionError(f"{self.merger.pending()} segment(s) not joined")
        t_map = time.perf_counter() - self.t_map
        pre = self.merger.prefix
        state.accs = pre.accs
        state.finished |= set(pre.done)
        self._checkpoint(force=True)
        red = self.red
        dask_info = {
            "workers": n_workers,
            "worker_processes_seen": len(self.workers_seen),
            "chunk_size": chunk_size,
            "chunks": n_chunks,
            "pairs_from_segments": len(covered),
            "pairs_done": red.n_ok,
            "pairs_skipped": len(red.skipped),
            "pairs_failed": len(red.failed),
            "map_seconds": t_map,
            "pairs_per_min": 60.0 * len(todo) / t_map if t_map > 0 else 0.0,
        }
        state.log.write(
            "dask_summary",
            **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in dask_info.items()},
        )
        campaign.info["dask"] = dask_info
        # pairs that failed count as skipped for the campaign (left out of the statistics)
        return red.skipped, red.failed

    def _submit(self, lo: int, hi: int) -> Any:
        """One task: the pairs ``todo[lo:hi]``; the context is small (the mapping as JSON),
        sent with each task and cached per worker."""
        # the field writer only when on: a chunk function of (context, pairs) stays valid
        extra = {} if self.state.fields is None else {"fields": self.state.fields}
        f = self.client.submit(
            process_chunk, self.state.ctx, self.state.todo[lo:hi], pure=False, **extra
        )
        self.key_of[f.key] = (lo, hi)
        return f

    def _next_alone(self) -> None:
        """Submit the next single pair waiting to run alone, unless one is running."""
        if self.alone_key is None and self.alone_queue:
            k = self.alone_queue.pop(0)
            f = self._submit(k, k + 1)
            self.alone_key = f.key
            self.ac.add(f)

    def _checkpoint(self, force: bool = False) -> None:
        """The contiguous prefix in the campaign's checkpoint, the segments merged out of
        order beside it (``dask_segments*.pkl``), every ``checkpoint_every`` pairs."""
        red, st = self.red, self.state
        if not force and red.since < self.campaign.checkpoint_every:
            return
        pre = self.merger.prefix
        fin = st.finished | set(pre.done)
        self.campaign.save_checkpoint(st.ctx, pre.accs, fin, st.timings)
        _save_segments(self.seg_path, st.ctx, self.campaign.shard, st.todo, self.merger)
        red.checkpointed(len(fin), pending_segments=self.merger.pending())

    def _handle(self, fut: Any) -> None:
        """Reduce one finished chunk (or split a chunk that killed its workers)."""
        from distributed.scheduler import KilledWorker  # deferred: dask (optional extra)

        st, prog, red = self.state, self.progress, self.red
        todo = st.todo
        lo, hi = self.key_of.pop(fut.key)
        alone = fut.key == self.alone_key
        if alone:
            self.alone_key = None
        try:
            res: ChunkResult = fut.result()
        except KilledWorker as exc:
            if hi - lo > 1:
                prog.log(
                    f"pairs {todo[lo].pair_id}..{todo[hi - 1].pair_id}: workers died "
                    "on this chunk; retrying pair by pair"
                )
                st.log.write(
                    "chunk_split", pairs=[p.pair_id for p in todo[lo:hi]], reason=str(exc)
                )
                for k in range(lo, hi):
                    self.ac.add(self._submit(k, k + 1))
                return
            p = todo[lo]
            if not alone:
                prog.log(f"pair {p.pair_id}: its worker died; retrying it on its own")
                st.log.write("pair_retry", pair_id=p.pair_id, reason=str(exc))
                self.alone_queue.append(lo)
                self._next_alone()
                return
            gx, _ = st.ctx.grid()
            res = ChunkResult(
                {r.name: FieldAccumulator(gx.shape) for r in st.ctx.runs},
                None,
                [],
                {},
                {p.pair_id: (p.describe(), f"worker died: {exc}")},
                {},
                {},
            )
        self._next_alone()
        fut.release()
        self.workers_seen.add(res.worker)
        red.add_timings(res.timings)
        for pid in res.done:
            red.done(
                pid, res.pair_timings.get(pid, {}), res.pair_quality.get(pid), worker=res.worker
            )
        for pid, (files, warning) in res.warned.items():
            red.warn(pid, files, warning)
        for pid, (files, reason) in res.skipped.items():
            red.skip(pid, files, reason)
        for pid, (files, reason) in res.failed.items():
            red.fail(pid, files, reason)
        if res.done:
            prog.advance(len(res.done))
        nbad = len(res.skipped) + len(res.failed)
        if nbad:
            prog.advance(nbad, skipped=True)
        self.merger.add(_Segment(lo, hi, res.accumulators, res.first, list(res.done)))
        red.count(hi - lo)
        self._checkpoint()
        now = time.perf_counter()
        if now - self.t_last_log >= self.progress_interval:
            dt = now - self.t_map
            st.log.write(
                "progress",
                done=red.n_ok,
                skipped=len(red.skipped),
                failed=len(red.failed),
                remaining=len(todo) - red.n_handled,
                pairs_per_min=round(60.0 * red.n_handled / dt if dt > 0 else 0.0, 3),
                workers=self.n_workers,
            )
            self.t_last_log = now
