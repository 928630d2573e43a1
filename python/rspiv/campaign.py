"""The campaign pipeline: a campaign file in, statistics, profiles and a report out.

``rspiv process campaign.toml`` and ``rspiv.Campaign.load(path).run()`` run the same code:

1. **Prepare** (:meth:`Campaign.prepare`): calibrate from the target image (figures, Monte
   Carlo), then a *pilot* over the first few pairs finds the wall in the corrected field and
   its angle; the calibration is rotated by ``-angle`` (paper section 3.2). Everything the
   per-pair work needs is frozen into a picklable :class:`PairContext` (mapping JSON, PIV
   settings, runs) and written to ``OUT/context.json``; shards and restarts reuse it.
2. **Map** over pairs: :func:`process_pair` ``(context, pair) -> PairResult`` is a pure
   function (reads the frames, corrects, runs PIV for every run: the main method, optionally
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
   ``summary.json`` and ``report/report.{md,html}``.

Sharding (``shard=(i, n)``, 1-based, ``rspiv process --shard i/n``) processes the i-th of n
contiguous slices of the pair list and writes the raw accumulators to
``OUT/shards/statistics_<run>.shard-<i>-of-<n>.nc`` (:meth:`FieldAccumulator.to_xarray`, exact
state) for a later merge instead of analysing.

Frames and units: PIV runs in px; the main and comparison runs are in the object frame (object
px, the dewarped frame), the uncorrected run in the raw image frame. Accumulators hold
displacements in px per pair along the pixel axes; outputs are in m, m/s with x streamwise
(direction of the mean flow) and y from the wall into the flow.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import hashlib
import json
import os
import pathlib
import pickle
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rspiv.campaign_config import CampaignConfig, load_campaign_config
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outputs import atomic_write_bytes, atomic_write_text
from rspiv.stats import FieldAccumulator

__all__ = [
    "Campaign",
    "CampaignResult",
    "PairContext",
    "PairResult",
    "PairSpec",
    "RunSpec",
    "process_pair",
    "parse_shard",
]

CHECKPOINT_FORMAT = "rspiv-checkpoint"
CHECKPOINT_VERSION = 1
STAGES = ("read", "dewarp", "piv", "statistics")


# ---------------------------------------------------------------------------- specs
@dataclasses.dataclass(frozen=True)
class PairSpec:
    """One image pair: its id (index in the campaign's full pair list) and its frames.

    ``frame_a``/``frame_b`` are frame indices inside a multi-frame TIFF (``a == b`` is that
    file), None for single-frame files.
    """

    pair_id: int
    a: str
    b: str
    frame_a: int | None = None
    frame_b: int | None = None

    def describe(self) -> str:
        if self.frame_a is not None:
            return f"{self.a}[{self.frame_a}, {self.frame_b}]"
        return f"{self.a}, {self.b}"


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One way of processing every pair.

    Attributes
    ----------
    name : str
        File key (``statistics_<name>.nc``).
    label : str
        Name in the report.
    method : {"I", "II", "none"}
        Dewarp then PIV; PIV then map the vectors; no correction.
    map_displacement : bool
        Method II: map the displacements through the inverse (else positions only).
    """

    name: str
    label: str
    method: str
    map_displacement: bool = True


@dataclasses.dataclass
class PairContext:
    """Everything :func:`process_pair` needs; picklable (plain data, the mapping as JSON).

    ``object_shape`` is the (h, w) of the object frame (the dewarped images), ``image_shape``
    the raw frames' (h, w); pairs of another size are skipped.
    """

    runs: tuple[RunSpec, ...]
    image_shape: tuple[int, int]
    object_shape: tuple[int, int]
    mapping_json: str | None
    passes: tuple[tuple[int, int], ...]
    overlap: float
    subpixel: str = "gauss3"
    median_threshold: float = 2.0
    median_epsilon: float = 0.1
    deform: bool = False
    mask_path: str | None = None
    _cache: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def __getstate__(self):
        d = self.__dict__.copy()
        d["_cache"] = {}
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)

    @property
    def mapping(self):
        """The :class:`rspiv.Mapping` (parsed once per process)."""
        if self.mapping_json is None:
            return None
        m = self._cache.get("mapping")
        if m is None:
            from rspiv.mapping import Mapping

            m = Mapping.from_json(self.mapping_json)
            self._cache["mapping"] = m
        return m

    def mask(self):
        """The PIV mask (bool, True = excluded) in the raw frame, or None."""
        if self.mask_path is None:
            return None
        if "mask" not in self._cache:
            img = _read_frame(self.mask_path, None)
            if img.shape != tuple(self.image_shape):
                raise InvalidInputError(
                    f"{self.mask_path}: mask is {img.shape[1]} x {img.shape[0]} px, the images "
                    f"are {self.image_shape[1]} x {self.image_shape[0]} px"
                )
            self._cache["mask"] = np.asarray(img) > 0
        return self._cache["mask"]

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Window centres (px) of the final pass, shape (ny, nx) each (same for every run)."""
        from rspiv.correction import grid_for_windows

        return grid_for_windows(self.object_shape, self.passes[-1], self.overlap)

    def to_dict(self) -> dict[str, Any]:
        d = {
            k: getattr(self, k)
            for k in (
                "image_shape",
                "object_shape",
                "mapping_json",
                "overlap",
                "subpixel",
                "median_threshold",
                "median_epsilon",
                "deform",
                "mask_path",
            )
        }
        d["image_shape"] = list(self.image_shape)
        d["object_shape"] = list(self.object_shape)
        d["passes"] = [list(p) for p in self.passes]
        d["runs"] = [dataclasses.asdict(r) for r in self.runs]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PairContext:
        return cls(
            runs=tuple(RunSpec(**r) for r in d["runs"]),
            image_shape=tuple(d["image_shape"]),
            object_shape=tuple(d["object_shape"]),
            mapping_json=d["mapping_json"],
            passes=tuple(tuple(p) for p in d["passes"]),
            overlap=float(d["overlap"]),
            subpixel=d["subpixel"],
            median_threshold=float(d["median_threshold"]),
            median_epsilon=float(d["median_epsilon"]),
            deform=bool(d["deform"]),
            mask_path=d["mask_path"],
        )

    def fingerprint(self) -> str:
        """Hash of everything that changes the per-pair results (checkpoints must match)."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclasses.dataclass
class PairResult:
    """What :func:`process_pair` returns for one pair.

    Attributes
    ----------
    pair_id : int
    ok : bool
        False: the pair was skipped (``reason`` says why); ``fields`` is empty.
    reason : str
    fields : dict
        Run name -> ``(u, v, valid)`` arrays of the grid's shape (px per pair).
    timings : dict
        Seconds per stage (``read``, ``dewarp``, ``piv``).
    """

    pair_id: int
    ok: bool
    reason: str = ""
    fields: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = dataclasses.field(
        default_factory=dict
    )
    timings: dict[str, float] = dataclasses.field(default_factory=dict)


# ---------------------------------------------------------------------------- per pair
def _read_frame(path: str, index: int | None) -> np.ndarray:
    """One 2D frame: a file, or frame ``index`` of a multi-frame TIFF (:func:`rspiv.io.read_image`;
    InvalidInputError naming the file when it is missing, unreadable or not 2D)."""
    from rspiv.io import read_image

    return np.ascontiguousarray(read_image(path, 0 if index is None else int(index)))


def _piv_kwargs(ctx: PairContext) -> dict[str, Any]:
    return {
        "subpixel": ctx.subpixel,
        "median_threshold": ctx.median_threshold,
        "median_eps": ctx.median_epsilon,
    }


def _window_positions(context: PairContext, corrected: bool) -> np.ndarray:
    """Raw-image positions (px) of the final windows, shape (ny, nx, 2): the grid itself for
    the uncorrected run, ``F(grid)`` for the corrected ones (cached per process)."""
    key = "image_xy" if corrected else "grid_xy"
    xy = context._cache.get(key)
    if xy is None:
        gx, gy = context.grid()
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        if corrected and context.mapping is not None:
            pts = context.mapping.forward(pts)
        xy = pts.reshape(gx.shape + (2,))
        context._cache[key] = xy
    return xy


def _field_arrays(
    f, context: PairContext, corrected: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, valid) of a field. Besides the PIV's own validation, a vector counts only if its
    two windows (the final window displaced by -d/2 and +d/2, d bounded by the field's 99th
    percentile displacement) lie inside the recorded image: windows reaching past the sensor or
    into the zero fill of a dewarped frame are no measurement."""
    u = np.asarray(f.u, np.float64)
    v = np.asarray(f.v, np.float64)
    valid = np.asarray(f.valid, bool) & ~np.asarray(f.masked, bool)
    valid &= np.isfinite(u) & np.isfinite(v)
    if valid.any():
        du = float(np.percentile(np.abs(u[valid]), 99))
        dv = float(np.percentile(np.abs(v[valid]), 99))
        w, h = context.passes[-1]
        xy = _window_positions(context, corrected)
        height, width = context.image_shape
        mx = 0.5 * w + 0.5 * du
        my = 0.5 * h + 0.5 * dv
        valid &= (xy[..., 0] - mx >= -0.5) & (xy[..., 0] + mx <= width - 0.5)
        valid &= (xy[..., 1] - my >= -0.5) & (xy[..., 1] + my <= height - 0.5)
    return u, v, valid


def process_pair(context: PairContext, pair: PairSpec) -> PairResult:
    """Process one pair for every run of ``context`` (pure: no files written, no state kept
    beyond the context's cache of the parsed mapping).

    Bad data (missing or unreadable frame, frames of different sizes or not of the campaign's
    size) gives ``PairResult(ok=False, reason=...)``; programming errors propagate.
    """
    from rspiv.piv import piv

    t = {k: 0.0 for k in STAGES[:3]}
    t0 = time.perf_counter()
    try:
        a = _read_frame(pair.a, pair.frame_a)
        b = _read_frame(pair.b, pair.frame_b)
    except (RspivError, ValueError, OSError) as exc:
        return PairResult(pair.pair_id, False, str(exc), timings=t)
    t["read"] = time.perf_counter() - t0
    shape = tuple(context.image_shape)
    for name, f in (("frame A", a), ("frame B", b)):
        if f.shape != shape:
            return PairResult(
                pair.pair_id,
                False,
                f"{name} ({pair.describe()}) is {f.shape[1]} x {f.shape[0]} px, the campaign's "
                f"images are {shape[1]} x {shape[0]} px",
                timings=t,
            )
    mask = context.mask()
    kw = _piv_kwargs(context)
    deformation = "symmetric" if context.deform else "offset"
    passes = [tuple(p) for p in context.passes]
    fields: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    raw = None
    try:
        # The uncorrected field first: it also serves as Method II's predictor.
        for run in sorted(context.runs, key=lambda r: r.method != "none"):
            if run.method == "none":
                t0 = time.perf_counter()
                raw = piv(
                    a, b, passes, overlap=context.overlap, deformation=deformation, mask=mask, **kw
                )
                t["piv"] += time.perf_counter() - t0
                fields[run.name] = _field_arrays(raw, context, False)
            elif run.method == "I":
                from rspiv.dewarp import dewarp

                t0 = time.perf_counter()
                m = context.mapping
                da = dewarp(a, m, output_shape=context.object_shape)
                db = dewarp(b, m, output_shape=context.object_shape)
                dmask = None
                if mask is not None:
                    dmask = (
                        dewarp(
                            mask.astype(np.float32), m, output_shape=context.object_shape, fill=1.0
                        )
                        > 0.5
                    )
                t["dewarp"] += time.perf_counter() - t0
                t0 = time.perf_counter()
                f = piv(
                    da,
                    db,
                    passes,
                    overlap=context.overlap,
                    deformation=deformation,
                    mask=dmask,
                    **kw,
                )
                t["piv"] += time.perf_counter() - t0
                fields[run.name] = _field_arrays(f, context, True)
            elif run.method == "II":
                from rspiv.correction import piv_vectors

                t0 = time.perf_counter()
                f = piv_vectors(
                    a,
                    b,
                    context.mapping,
                    passes,
                    context.overlap,
                    mapping="full" if run.map_displacement else "positions",
                    object_shape=context.object_shape,
                    predictor=raw,
                    deformation=deformation,
                    mask=mask,
                    subpixel=context.subpixel,
                    median_threshold=context.median_threshold,
                    median_eps=context.median_epsilon,
                )
                t["piv"] += time.perf_counter() - t0
                fields[run.name] = _field_arrays(f, context, True)
            else:
                raise InvalidInputError(f"run {run.name}: unknown method {run.method!r}")
    except InvalidInputError as exc:  # e.g. frames with NaN: bad data, not a bug
        return PairResult(pair.pair_id, False, f"{pair.describe()}: {exc}", timings=t)
    return PairResult(pair.pair_id, True, "", fields, t)


# ---------------------------------------------------------------------------- helpers
def parse_shard(text: str | tuple[int, int] | None) -> tuple[int, int]:
    """``"i/n"`` (1-based, 1 <= i <= n) -> ``(i, n)``; None -> ``(1, 1)``."""
    if text is None:
        return (1, 1)
    if isinstance(text, tuple):
        i, n = text
    else:
        try:
            i_s, n_s = str(text).split("/")
            i, n = int(i_s), int(n_s)
        except ValueError:
            raise InvalidInputError(f"--shard: expected i/n (e.g. 2/8), got {text!r}") from None
    if not (n >= 1 and 1 <= i <= n):
        raise InvalidInputError(f"--shard: expected 1 <= i <= n, got {i}/{n}")
    return int(i), int(n)


def shard_slice(n_pairs: int, shard: tuple[int, int]) -> range:
    """Indices of the i-th of n contiguous, nearly equal slices of ``range(n_pairs)``."""
    i, n = shard
    lo = (i - 1) * n_pairs // n
    hi = i * n_pairs // n
    return range(lo, hi)


def _check_writable(out: pathlib.Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".rspiv-write-test-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise InvalidInputError(
            f"{out}: the output folder is not writable ({exc.strerror or exc})"
        ) from None


def scaled_accumulator(
    acc: FieldAccumulator, k: float, sign_u: float = 1.0, sign_v: float = 1.0
) -> FieldAccumulator:
    """A copy of ``acc`` with u scaled by ``k * sign_u`` and v by ``k * sign_v`` (unit change
    and axis flips; every moment of the state transforms exactly)."""
    out = copy.deepcopy(acc)
    ku, kv = k * sign_u, k * sign_v
    out.mean_u = acc.mean_u * ku
    out.mean_v = acc.mean_v * kv
    out.m2_uu = acc.m2_uu * ku * ku
    out.m2_vv = acc.m2_vv * kv * kv
    out.c_uv = acc.c_uv * ku * kv
    for comp, kk in (("u", ku), ("v", kv)):
        for part in ("a", "b"):
            name = f"lag_mean_{part}_{comp}"
            setattr(out, name, getattr(acc, name) * kk)
        setattr(out, f"lag_c_{comp}", getattr(acc, f"lag_c_{comp}") * kk * kk)
    return out


def _json_default(o):
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
            f.write(json.dumps(rec, default=_json_default) + "\n")


# ---------------------------------------------------------------------------- results
@dataclasses.dataclass
class RunAnalysis:
    """The analysis of one run: wall, profile in SI units and the boundary-layer result."""

    run: RunSpec
    wall: Any
    flow_side: str
    profile: dict[str, Any]
    result: Any
    error: str = ""


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
    timings : dict
        Seconds per stage summed over this run's pairs (``read``, ``dewarp``, ``piv``,
        ``statistics``) and ``prepare``, ``analysis``, ``total``.
    files : dict
        Output name -> path.
    wall_deviation : dict
        Condition -> the wall's maximum deviation (px), as in the paper's table.
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

    Shared by the local run loop (:meth:`Campaign.run`) and the Dask one
    (:func:`rspiv.scaleout.run_dask`), which differ only in how they process ``todo``.

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


# ---------------------------------------------------------------------------- campaign
class Campaign:
    """A campaign: configuration, pair list, and the run loop.

    Parameters
    ----------
    config : CampaignConfig
    extra_methods : sequence of {"I", "II"}
        Further corrected runs for comparison (e.g. Method I beside a Method II campaign).
    checkpoint_every : int
        Pairs between checkpoints.
    shard : (i, n) or "i/n"
        Process only the i-th of n contiguous slices of the pairs (1-based).
    pilot_pairs : int
        Pairs used to find the wall angle before the main pass.
    progress : bool
        Progress bar / status lines on stderr.
    out_dir : path, optional
        Override ``[output].dir``.
    log : callable, optional
        Receives the campaign's messages (one line each); default: the progress display's
        ``log`` once a run starts. Kept in the attribute ``log_fn``.
    """

    def __init__(
        self,
        config: CampaignConfig,
        *,
        extra_methods: Sequence[str] = (),
        checkpoint_every: int = 25,
        shard: tuple[int, int] | str | None = None,
        pilot_pairs: int = 4,
        progress: bool = True,
        out_dir: str | os.PathLike | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.config = config
        self.extra_methods = tuple(extra_methods)
        for m in self.extra_methods:
            if m not in ("I", "II"):
                raise InvalidInputError(f"extra_methods: expected 'I' or 'II', got {m!r}")
        if int(checkpoint_every) < 1:
            raise InvalidInputError(f"checkpoint_every must be >= 1, got {checkpoint_every!r}")
        self.checkpoint_every = int(checkpoint_every)
        self.shard = parse_shard(shard)
        self.pilot_pairs = max(int(pilot_pairs), 1)
        self.show_progress = progress
        self.out_dir = (
            pathlib.Path(out_dir) if out_dir is not None else pathlib.Path(config.output.dir)
        )
        self.log_fn = log
        self.calibration = None
        self.info: dict[str, Any] = {}

    @classmethod
    def load(cls, path: str | os.PathLike, **kwargs: Any) -> Campaign:
        """Read a campaign file (:func:`rspiv.load_campaign_config`) and build the campaign."""
        return cls(load_campaign_config(path), **kwargs)

    # ------------------------------------------------------------------ pairs
    def pairs(self) -> list[PairSpec]:
        """The campaign's full pair list (ids are positions in it)."""
        im = self.config.images
        if im.multiframe is not None:
            p = pathlib.Path(im.multiframe)
            if not p.is_file():
                raise InvalidInputError(f"[images].multiframe: {p}: no such file")
            import tifffile

            try:
                with tifffile.TiffFile(p) as tf:
                    n = len(tf.pages)
            except Exception as exc:  # noqa: BLE001
                raise InvalidInputError(f"[images].multiframe: {p}: cannot read ({exc})") from None
            out = [PairSpec(k, str(p), str(p), 2 * k, 2 * k + 1) for k in range(n // 2)]
            return out[: im.max_pairs] if im.max_pairs else out
        return [PairSpec(k, str(a), str(b)) for k, (a, b) in enumerate(im.pair_files())]

    def runs(self) -> tuple[RunSpec, ...]:
        """The runs: the main method, the extra methods, and the uncorrected comparison."""
        c = self.config.correction
        model = self.config.calibration.model
        rot = " + rotation" if (self.config.wall.enabled and self.config.wall.rotate) else ""
        out: list[RunSpec] = []

        def corrected(method: str) -> RunSpec:
            return RunSpec(
                f"method_{method}", f"{model}{rot}, Method {method}", method, c.map_displacement
            )

        if c.method == "none":
            out.append(RunSpec("uncorrected", "uncorrected", "none"))
        else:
            out.append(corrected(c.method))
            for m in self.extra_methods:
                if m != c.method:
                    out.append(corrected(m))
            if c.compare_uncorrected:
                out.append(RunSpec("uncorrected", "uncorrected", "none"))
        return tuple(out)

    def _log(self, msg: str) -> None:
        if self.log_fn is not None:
            self.log_fn(msg)

    # ------------------------------------------------------------------ prepare
    def _config_hash(self) -> str:
        d = self.config.to_dict()
        keep = {k: d[k] for k in ("calibration", "correction", "piv", "wall") if k in d}
        keep["extra"] = list(self.extra_methods)
        keep["pilot"] = self.pilot_pairs
        return hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()[
            :16
        ]

    def prepare(self, pairs: list[PairSpec] | None = None) -> PairContext:
        """Calibrate, find the wall angle on the pilot pairs, and freeze the context.

        Reuses ``OUT/context.json`` when it was written for the same configuration.
        """
        out = self.out_dir
        _check_writable(out)
        ctx_path = out / "context.json"
        h = self._config_hash()
        if ctx_path.is_file():
            try:
                saved = json.loads(ctx_path.read_text(encoding="utf-8"))
                if saved.get("config_hash") == h:
                    self.info = saved.get("info", {})
                    cal_path = out / "calibration.json"
                    if cal_path.is_file():
                        from rspiv.calibration import Calibration

                        self.calibration = Calibration.load(cal_path)
                    self._log(f"reusing {ctx_path}")
                    return PairContext.from_dict(saved["context"])
            except (OSError, ValueError, KeyError, TypeError):
                pass  # rebuilt below
        pairs = self.pairs() if pairs is None else pairs
        cfg = self.config
        runs = self.runs()
        figdir = out / "report" / "figures"
        info: dict[str, Any] = {"figures": {}, "wall_deviation": {}}
        mapping_json = None
        cal = None
        image_shape = None
        if cfg.calibration.target is not None:
            from rspiv.calibration import calibrate
            from rspiv.io import read_image

            t0 = time.perf_counter()
            image = read_image(cfg.calibration.target)
            cc = cfg.calibration
            cal = calibrate(
                image,
                cc.pitch_mm,
                model=cc.model.lower(),
                marker=cc.marker,
                pitch_sigma_mm=cc.pitch_sigma_mm if cc.pitch_sigma_mm > 0 else None,
                marker_size_px=cc.marker_size_px if cc.marker_size_px > 0 else None,
            )
            image_shape = tuple(cal.image_shape)
            self._log(f"calibration: {cal!r} ({time.perf_counter() - t0:.1f} s)")
            info["calibration_table"] = _calibration_table(cal)
            try:
                from rspiv.plots.calibration import write_all

                figs = write_all(figdir, cal, image)
                info["figures"]["calibration"] = [str(p) for p in figs]
            except Exception as exc:  # noqa: BLE001 - a figure must not stop a campaign
                self._log(f"calibration figures failed: {exc}")
            if cc.monte_carlo_samples > 0:
                t0 = time.perf_counter()
                info.update(self._monte_carlo(cal, cc.monte_carlo_samples, figdir))
                self._log(
                    f"Monte Carlo: {cc.monte_carlo_samples} samples "
                    f"({time.perf_counter() - t0:.1f} s)"
                )
        if image_shape is None:
            image_shape = self._first_shape(pairs)
        base = PairContext(
            runs=runs,
            image_shape=image_shape,
            object_shape=image_shape,
            mapping_json=None if cal is None else cal.mapping.to_json(),
            passes=tuple(tuple(p) for p in cfg.piv.passes),
            overlap=cfg.piv.overlap,
            subpixel=cfg.piv.subpixel,
            median_threshold=cfg.piv.median_threshold,
            median_epsilon=cfg.piv.median_epsilon,
            deform=cfg.piv.deform,
            mask_path=None if cfg.piv.mask is None else str(cfg.piv.mask),
        )
        main = runs[0]
        if cal is not None and main.method != "none" and cfg.wall.enabled and cfg.wall.rotate:
            t0 = time.perf_counter()
            pilot_ctx = dataclasses.replace(base, runs=(main,), _cache={})
            acc = None
            used = []
            for p in pairs:
                if len(used) >= self.pilot_pairs:
                    break
                r = process_pair(pilot_ctx, p)
                if not r.ok:
                    continue
                u, v, valid = r.fields[main.name]
                if acc is None:
                    acc = FieldAccumulator(u.shape)
                acc.add(u, v, valid)
                used.append(p.pair_id)
            if acc is None:
                raise InvalidInputError("no readable image pair for the wall alignment pilot")
            gx, gy = base.grid()
            wall, side = find_wall_in(
                acc, gx, gy, cfg.wall.stations, cfg.wall.side, cfg.statistics.min_count
            )
            theta = wall.rotation_deg
            cal = cal.with_rotation(theta)
            mapping_json = cal.mapping.to_json()
            model = cfg.calibration.model
            info["wall_deviation"][f"Dewarped by {model}"] = wall.max_deviation_px
            info["pilot"] = {
                "pairs": used,
                "wall_angle_deg": wall.angle_deg,
                "rotation_deg": theta,
                "max_deviation_px": wall.max_deviation_px,
                "flow_side": side,
            }
            info["pilot_wall"] = _wall_dict(wall)
            self._log(
                f"wall alignment on {len(used)} pilot pair(s): angle {wall.angle_deg:.4f} deg, "
                f"max deviation {wall.max_deviation_px:.2f} px; rotating the mapping by "
                f"{theta:.4f} deg ({time.perf_counter() - t0:.1f} s)"
            )
        elif cal is not None:
            mapping_json = cal.mapping.to_json()
        ctx = dataclasses.replace(base, mapping_json=mapping_json, _cache={})
        self.calibration = cal
        if cal is not None:
            cal.save(out / "calibration.json")
        self.info = info
        atomic_write_text(
            ctx_path,
            json.dumps(
                {"config_hash": h, "context": ctx.to_dict(), "info": info},
                indent=1,
                default=_json_default,
            ),
        )
        return ctx

    def _first_shape(self, pairs: list[PairSpec]) -> tuple[int, int]:
        for p in pairs:
            try:
                a = _read_frame(p.a, p.frame_a)
            except (RspivError, ValueError, OSError):
                continue
            return (int(a.shape[0]), int(a.shape[1]))
        raise InvalidInputError("no readable image in the campaign")

    def _monte_carlo(self, cal, n: int, figdir: pathlib.Path) -> dict[str, Any]:
        from rspiv.montecarlo import monte_carlo

        res = monte_carlo(cal, n=int(n), hist_bins=64)
        out: dict[str, Any] = {
            "monte_carlo": {
                "n": res.n,
                "n_failed": res.n_failed,
                "radius99_max_px": float(np.max(res.radius99_px)),
                "radius99_median_px": float(np.median(res.radius99_px)),
                "within1_min": float(np.min(res.within1)),
                "within2_min": float(np.min(res.within2)),
                "summary": res.summary(),
            }
        }
        try:
            from rspiv.plots.calibration import monte_carlo_jpdfs

            figdir.mkdir(parents=True, exist_ok=True)
            p = monte_carlo_jpdfs(res, figdir / f"montecarlo_{res.model}.png")
            out["figures_mc"] = [str(p)]
        except Exception as exc:  # noqa: BLE001
            self._log(f"Monte Carlo figure failed: {exc}")
        return out

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self) -> pathlib.Path:
        """The checkpoint file of this campaign and shard.

        Returns
        -------
        pathlib.Path
            ``OUT/checkpoint/state.pkl``, or ``state.shard-I-of-N.pkl`` for shard I of N.
        """
        i, n = self.shard
        name = "state.pkl" if n == 1 else f"state.shard-{i}-of-{n}.pkl"
        return self.out_dir / "checkpoint" / name

    def save_checkpoint(
        self,
        ctx: PairContext,
        accs: dict[str, FieldAccumulator],
        finished: set[int],
        timings: dict[str, float],
    ) -> None:
        """Write the checkpoint (:meth:`checkpoint_path`) atomically.

        Parameters
        ----------
        ctx : PairContext
            The prepared context; its fingerprint is stored to refuse another configuration.
        accs : dict of str to FieldAccumulator
            The accumulators per run, holding exactly the pairs of ``finished``.
        finished : set of int
            Ids of the pairs in ``accs``.
        timings : dict of str to float
            Time per stage summed over the pairs, s.
        """
        state = {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "fingerprint": ctx.fingerprint(),
            "shard": list(self.shard),
            "finished": sorted(finished),
            "accumulators": accs,
            "timings": timings,
        }
        atomic_write_bytes(
            self.checkpoint_path(), pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
        )

    def load_checkpoint(self, ctx: PairContext) -> dict[str, Any] | None:
        """Read the checkpoint written by :meth:`save_checkpoint`.

        Parameters
        ----------
        ctx : PairContext
            The prepared context; the checkpoint must have been written for its fingerprint.

        Returns
        -------
        dict or None
            The state (keys ``accumulators``, ``finished``, ``timings``, ``shard``, ...), or
            None when there is no checkpoint.

        Raises
        ------
        InvalidInputError
            The checkpoint is corrupt or belongs to another configuration.
        """
        path = self.checkpoint_path()
        if not path.is_file():
            return None
        try:
            state = pickle.loads(path.read_bytes())
            if state.get("format") != CHECKPOINT_FORMAT:
                raise ValueError("not an rspiv checkpoint")
        except Exception as exc:  # noqa: BLE001 - report any corruption the same way
            raise InvalidInputError(
                f"{path}: corrupt checkpoint ({exc}); delete it to start the campaign afresh"
            ) from None
        if state.get("fingerprint") != ctx.fingerprint():
            raise InvalidInputError(
                f"{path}: checkpoint of a different configuration (calibration, PIV or runs "
                "changed); delete the checkpoint folder or choose another output folder"
            )
        return state

    # ------------------------------------------------------------------ run
    def open_run(self, t_start: float | None = None) -> RunState:
        """Start a run: check that the output folder is writable, open the run log and select
        this shard's pairs.

        Parameters
        ----------
        t_start : float, optional
            ``time.perf_counter()`` at which the run started (default: now); the ``total``
            timing is measured from it.

        Returns
        -------
        RunState
            With ``log``, ``all_pairs``, ``sel`` and ``t_start`` set; :meth:`begin_run`
            fills the rest.

        Raises
        ------
        InvalidInputError
            The output folder is not writable, or the campaign has no image pairs.
        """
        if t_start is None:
            t_start = time.perf_counter()
        _check_writable(self.out_dir)
        log = RunLog(self.out_dir / "run_log.jsonl")
        all_pairs = self.pairs()
        if not all_pairs:
            raise InvalidInputError("the campaign has no image pairs")
        sel = [all_pairs[k] for k in shard_slice(len(all_pairs), self.shard)]
        return RunState(log=log, all_pairs=all_pairs, sel=sel, t_start=t_start)

    def begin_run(self, state: RunState, progress) -> None:
        """Prepare the run and resume it from the checkpoint.

        Routes the campaign's messages to ``progress`` (unless a ``log`` callable was given),
        runs :meth:`prepare`, loads the checkpoint (:meth:`load_checkpoint`) or starts new
        accumulators, and lists the pairs still to do.

        Parameters
        ----------
        state : RunState
            From :meth:`open_run`; ``ctx``, ``t_prepare``, ``accs``, ``finished``,
            ``timings``, ``n_resumed`` and ``todo`` are set in place.
        progress : rspiv.progress.Progress
            The run's progress display (entered).
        """
        if self.log_fn is None:
            self.log_fn = progress.log
        t0 = time.perf_counter()
        ctx = self.prepare(state.all_pairs)
        state.t_prepare = time.perf_counter() - t0
        state.ctx = ctx
        gx, _ = ctx.grid()
        ckpt = self.load_checkpoint(ctx)
        if ckpt is not None:
            state.accs = ckpt["accumulators"]
            state.finished = set(ckpt["finished"])
            state.timings = dict(ckpt.get("timings", {}))
        else:
            state.accs = {r.name: FieldAccumulator(gx.shape) for r in ctx.runs}
            state.finished = set()
            state.timings = {k: 0.0 for k in STAGES}
        state.n_resumed = sum(1 for p in state.sel if p.pair_id in state.finished)
        state.todo = [p for p in state.sel if p.pair_id not in state.finished]

    def announce_run(self, state: RunState, progress, **start_extra: Any) -> None:
        """Write the ``start`` record of the run log and report the pairs resumed.

        Parameters
        ----------
        state : RunState
            After :meth:`begin_run`.
        progress : rspiv.progress.Progress
            The run's progress display; advanced by the pairs resumed.
        **start_extra
            Further fields of the ``start`` record (e.g. ``dask={...}``).
        """
        ctx = state.ctx
        state.log.write(
            "start",
            pairs=len(state.sel),
            resumed=state.n_resumed,
            shard=list(self.shard),
            runs=[r.name for r in ctx.runs],
            fingerprint=ctx.fingerprint(),
            **start_extra,
        )
        if state.n_resumed:
            progress.log(
                f"resuming: {state.n_resumed} finished pair(s) skipped "
                f"(checkpoint {self.checkpoint_path()})"
            )
            progress.advance(state.n_resumed)

    def finish_run(
        self,
        state: RunState,
        skipped: dict[int, str],
        *,
        failed: dict[int, str] | None = None,
    ) -> CampaignResult:
        """End a run: write the shard file (sharded run) or analyse and write the outputs,
        then the ``end`` record of the run log.

        Parameters
        ----------
        state : RunState
            After the run loop: ``accs``, ``finished`` and ``timings`` hold the pairs done.
        skipped : dict of int to str
            Pairs that could not be read, with the reason.
        failed : dict of int to str, optional
            Pairs whose processing raised (Dask run), with the reason. They count as skipped
            in the result and are reported separately in the ``end`` record.

        Returns
        -------
        CampaignResult

        Raises
        ------
        InvalidInputError
            No pair of an unsharded run could be processed.
        """
        all_skipped = {**skipped, **failed} if failed is not None else skipped
        n_done = sum(1 for p in state.sel if p.pair_id in state.finished)
        result = CampaignResult(
            out_dir=self.out_dir,
            context=state.ctx,
            accumulators=state.accs,
            analyses={},
            n_pairs=len(state.sel),
            n_done=n_done,
            n_resumed=state.n_resumed,
            skipped=all_skipped,
            timings={**state.timings, "prepare": state.t_prepare},
            files={},
            wall_deviation=dict(self.info.get("wall_deviation", {})),
            info=self.info,
        )
        t0 = time.perf_counter()
        if self.shard[1] > 1:
            self.write_shard(result)
        elif n_done == 0:
            what = "skipped" if failed is None else "skipped or failed"
            raise InvalidInputError(
                f"no image pair could be processed ({len(all_skipped)} {what}; see "
                f"{self.out_dir / 'run_log.jsonl'})"
            )
        else:
            self.analyse_result(result)
        result.timings["analysis"] = time.perf_counter() - t0
        result.timings["total"] = time.perf_counter() - state.t_start
        end: dict[str, Any] = {"done": n_done, "skipped": len(skipped)}
        if failed is not None:
            end["failed"] = len(failed)
        state.log.write("end", **end, timings={k: round(v, 3) for k, v in result.timings.items()})
        return result

    def run(self) -> CampaignResult:
        """Run (or resume) the campaign; see the module docstring."""
        from rspiv.progress import Progress

        st = self.open_run()
        with Progress(len(st.sel), "pairs", enabled=self.show_progress) as prog:
            self.begin_run(st, prog)
            self.announce_run(st, prog)
            ctx, accs, finished, timings, log = st.ctx, st.accs, st.finished, st.timings, st.log
            skipped: dict[int, str] = {}
            since = 0
            consistent = True  # the accumulators hold whole pairs only
            try:
                for p in st.todo:
                    r = process_pair(ctx, p)
                    for k, v in r.timings.items():
                        timings[k] = timings.get(k, 0.0) + v
                    if not r.ok:
                        skipped[p.pair_id] = r.reason
                        log.write("skipped", pair_id=p.pair_id, files=p.describe(), reason=r.reason)
                        prog.log(f"pair {p.pair_id} skipped: {r.reason}")
                        prog.advance(skipped=True)
                        continue
                    t0 = time.perf_counter()
                    consistent = False
                    for name, (u, v, valid) in r.fields.items():
                        accs[name].add(u, v, valid, pair_id=p.pair_id)
                    timings["statistics"] = (
                        timings.get("statistics", 0.0) + time.perf_counter() - t0
                    )
                    finished.add(p.pair_id)
                    consistent = True
                    log.write(
                        "pair",
                        pair_id=p.pair_id,
                        timings={k: round(v, 4) for k, v in r.timings.items()},
                    )
                    prog.advance()
                    since += 1
                    if since >= self.checkpoint_every:
                        self.save_checkpoint(ctx, accs, finished, timings)
                        log.write("checkpoint", finished=len(finished))
                        since = 0
            except KeyboardInterrupt:
                if consistent:  # keep what is done: a restart resumes from here
                    self.save_checkpoint(ctx, accs, finished, timings)
                    log.write("interrupted", finished=len(finished))
                raise
            self.save_checkpoint(ctx, accs, finished, timings)
            log.write("checkpoint", finished=len(finished))
        return self.finish_run(st, skipped)

    # ------------------------------------------------------------------ outputs
    def analyse(
        self,
        accumulators: dict[str, FieldAccumulator],
        *,
        skipped: dict[int, str] | None = None,
    ) -> CampaignResult:
        """Analyse and write the outputs of accumulators gathered elsewhere (e.g. merged shard
        files or Dask partials): the same walls, profiles, NetCDF/CSV files and report as
        :meth:`run`. The context comes from ``OUT/context.json`` (:meth:`prepare`)."""
        ctx = self.prepare()
        missing = [r.name for r in ctx.runs if r.name not in accumulators]
        if missing:
            raise InvalidInputError(f"accumulators: missing the run(s) {', '.join(missing)}")
        n = max(len(a.pair_ids) or a.n_fields for a in accumulators.values())
        res = CampaignResult(
            out_dir=self.out_dir,
            context=ctx,
            accumulators=dict(accumulators),
            analyses={},
            n_pairs=n + len(skipped or {}),
            n_done=n,
            n_resumed=0,
            skipped=dict(skipped or {}),
            timings={k: 0.0 for k in STAGES},
            files={},
            wall_deviation=dict(self.info.get("wall_deviation", {})),
            info=self.info,
        )
        t0 = time.perf_counter()
        self.analyse_result(res)
        res.timings["analysis"] = time.perf_counter() - t0
        return res

    def write_shard(self, res: CampaignResult) -> None:
        """Write the accumulators of a sharded run, one NetCDF file per run.

        Parameters
        ----------
        res : CampaignResult
            The result of this shard; the paths written are added to ``res.files``
            (``shard_<run>``: ``OUT/shards/statistics_<run>.shard-I-of-N.nc``).
        """
        from rspiv.outputs import write_netcdf

        i, n = self.shard
        gx, gy = res.context.grid()
        for name, acc in res.accumulators.items():
            ds = acc.to_xarray(
                x=gx[0],
                y=gy[:, 0],
                velocity_units="pix",
                attrs={
                    "run": name,
                    "shard": f"{i}/{n}",
                    "campaign": self.config.name,
                    "fingerprint": res.context.fingerprint(),
                    "frame": "object px" if name != "uncorrected" else "image px",
                },
            )
            path = self.out_dir / "shards" / f"statistics_{name}.shard-{i}-of-{n}.nc"
            res.files[f"shard_{name}"] = write_netcdf(ds, path)

    def analyse_result(self, res: CampaignResult) -> None:
        """Analyse the accumulators of ``res`` and write the campaign's outputs.

        Finds the walls, fits the profiles, writes the NetCDF/CSV files, figures and report,
        and fills ``res.analyses`` and ``res.files`` in place.

        Parameters
        ----------
        res : CampaignResult
            A result whose ``accumulators`` hold every run of ``res.context``.
        """
        from rspiv.outputs import (
            profile_dataset,
            statistics_dataset,
            write_netcdf,
            write_profile_csv,
        )

        cfg = self.config
        ctx = res.context
        out = self.out_dir
        gx, gy = ctx.grid()
        cal = self.calibration
        mag = cal.magnification if cal is not None else None  # px/mm
        dt = cfg.flow.dt
        model = cfg.calibration.model
        summary: dict[str, Any] = {
            "campaign": cfg.name,
            "runs": {},
            "pairs": res.n_pairs,
            "processed": res.n_done,
            "skipped": res.skipped,
        }
        for run in ctx.runs:
            acc = res.accumulators[run.name]
            try:
                an = analyse_run(run, acc, gx, gy, cfg, mag, dt, ctx.passes[-1])
            except (RspivError, ValueError) as exc:
                self._log(f"{run.label}: analysis failed: {exc}")
                res.analyses[run.name] = RunAnalysis(run, None, "", {}, None, str(exc))
                summary["runs"][run.name] = {"label": run.label, "error": str(exc)}
                continue
            res.analyses[run.name] = an
            if an.wall is not None:
                cond = {"none": "Distorted"}.get(
                    run.method,
                    f"Dewarped by {model}"
                    + (" and rotated" if (cfg.wall.rotate and cal is not None) else ""),
                )
                if run.method != "none" and run.method != ctx.runs[0].method:
                    cond += f" (Method {run.method})"
                res.wall_deviation[cond] = an.wall.max_deviation_px
            si = an.profile.get("si", False)
            k = an.profile.get("k", 1.0)
            ds = statistics_dataset(
                scaled_accumulator(
                    acc, k, an.profile.get("sign_x", 1.0), an.profile.get("sign_y", 1.0)
                ),
                x=an.profile["x_coord"],
                y=an.profile["y_coord"],
                velocity_units="m s-1" if si else "pix",
                dt=dt if dt > 0 else None,
                attrs={
                    "run": run.name,
                    "label": run.label,
                    "method": run.method,
                    "campaign": cfg.name,
                    "n_pairs": int(acc.n_fields),
                    "frame": "object" if run.method != "none" else "raw image",
                },
            )
            if cfg.output.netcdf:
                res.files[f"statistics_{run.name}"] = write_netcdf(
                    ds, out / f"statistics_{run.name}.nc"
                )
            rs: dict[str, Any] = {
                "label": run.label,
                "method": run.method,
                "flow_side": an.flow_side,
            }
            if an.wall is not None:
                rs["wall"] = _wall_dict(an.wall)
            if an.result is not None:
                rs.update(an.result.summary())
                if cfg.output.netcdf:
                    res.files[f"profile_{run.name}_nc"] = write_netcdf(
                        profile_dataset(an.result, attrs={"run": run.name, "label": run.label}),
                        out / f"profile_{run.name}.nc",
                    )
                if cfg.output.csv:
                    res.files[f"profile_{run.name}_csv"] = write_profile_csv(
                        out / f"profile_{run.name}.csv",
                        an.result,
                        metadata={"run": run.name, "label": run.label},
                    )
            elif an.error:
                rs["error"] = an.error
            summary["runs"][run.name] = rs
        summary["wall_deviation_px"] = res.wall_deviation
        summary["timings_s"] = res.timings
        if self.info.get("pilot"):
            summary["pilot"] = self.info["pilot"]
        res.files["summary"] = atomic_write_text(
            out / "summary.json", json.dumps(summary, indent=1, default=_json_default)
        )
        if cfg.output.report:
            self._report(res)

    def _report(self, res: CampaignResult, extra_sections=()) -> None:
        from rspiv.report import ReportSection, ReportTable, campaign_report

        ctx = res.context
        results = {a.run.label: a.result for a in res.analyses.values() if a.result is not None}
        repdir = self.out_dir / "report"
        if not results:
            self._log("no boundary-layer result to report (set [flow].dt and a calibration)")
            return
        wall_figs = []
        try:
            p = _wall_figure(repdir / "figures" / "wall.png", res, self.info.get("pilot_wall"))
            wall_figs.append((p, "Wall position per station (pilot before rotation, final runs)"))
        except Exception as exc:  # noqa: BLE001
            self._log(f"wall figure failed: {exc}")
        main = ctx.runs[0]
        w, h = ctx.passes[-1]
        piv = {"samples N": res.n_done, "final window x (px)": w, "final window y (px)": h}
        r0 = res.analyses.get(main.name)
        if r0 is not None and r0.result is not None and self.calibration is not None:
            lv_px = r0.result.nu / r0.result.u_tau * 1e3 * self.calibration.magnification
            piv["final window x+"] = w / lv_px
            piv["final window y+"] = h / lv_px
        extra = list(extra_sections)
        if res.skipped:
            extra.append(
                ReportSection(
                    "Skipped pairs",
                    text=f"{len(res.skipped)} pair(s) were skipped and left out of the statistics.",
                    tables=[
                        ReportTable(
                            "Skipped pairs",
                            [{"pair": k, "reason": v} for k, v in sorted(res.skipped.items())],
                        )
                    ],
                )
            )
        t = res.timings
        n = max(res.n_done - res.n_resumed, 1)
        extra.append(
            ReportSection(
                "Throughput",
                tables=[
                    ReportTable(
                        "Time per stage (this run)",
                        {
                            k: {"total (s)": t.get(k, 0.0), "per pair (s)": t.get(k, 0.0) / n}
                            for k in (*STAGES, "prepare")
                        },
                    )
                ],
            )
        )
        mc_figs = self.info.get("figures_mc")
        from rspiv import __version__

        paths = campaign_report(
            repdir,
            results,
            calibration=self.info.get("calibration_table"),
            wall_deviation=res.wall_deviation,
            piv_parameters=piv,
            calibration_figures=self.info.get("figures", {}).get("calibration"),
            monte_carlo_figures=mc_figs,
            wall_figures=wall_figs or None,
            extra_sections=extra,
            metadata={
                "campaign": self.config.name,
                "rspiv": __version__,
                "pairs processed": res.n_done,
                "pairs skipped": len(res.skipped),
                "runs": ", ".join(r.label for r in ctx.runs),
            },
            title=f"rspiv campaign report: {self.config.name}",
        )
        res.files["report_md"] = paths["markdown"]
        res.files["report_html"] = paths["html"]


# ---------------------------------------------------------------------------- analysis
def find_wall_in(acc: FieldAccumulator, gx, gy, stations: int, side: str, min_count: int):
    """Find the wall in an accumulator's mean u field; returns ``(Wall, flow_side)``.

    ``flow_side`` is ``"above"`` (flow at smaller y: the wall near the bottom of the image) or
    ``"below"``. The search band is centred on the row of smallest mean |u| (the wall, where
    the particles and their reflections stand still) and as wide as the image allows.
    """
    from rspiv.wall import find_wall

    u = np.where(acc.count >= max(min(min_count, acc.n_fields), 1), acc.mean_u, np.nan)
    ys = gy[:, 0]
    xs = gx[0]
    have = np.isfinite(u).any(axis=1)
    prof = np.full(len(u), np.nan)
    prof[have] = np.nanmean(np.abs(u[have]), axis=1)
    rows = np.flatnonzero(have)
    if rows.size < 5:
        raise InvalidInputError("wall: fewer than 5 rows of the mean field have data")
    # Smallest |u| away from the first/last rows (their windows may be incomplete).
    j = rows[np.argmin(prof[rows])]
    if side == "auto":
        flow_side = "above" if j > (len(ys) - 1) / 2 else "below"
    else:
        flow_side = "above" if side == "bottom" else "below"
    half = min(ys[j] - ys[rows[0]], ys[rows[-1]] - ys[j])
    dy = ys[1] - ys[0] if len(ys) > 1 else 1.0
    half = max(half, 3 * dy)
    st = min(int(stations), u.shape[1])
    wall = find_wall(u, y=ys, x=xs, band=(ys[j] - half, ys[j] + half), stations=st)
    return wall, flow_side


def analyse_run(
    run: RunSpec, acc: FieldAccumulator, gx, gy, cfg: CampaignConfig, mag, dt, window
) -> RunAnalysis:
    """Wall, profile (SI when ``mag`` and ``dt`` are known) and boundary-layer analysis of one
    run's accumulator."""
    from rspiv.boundary_layer import analyse_profile, profile_from_accumulator

    st = cfg.statistics
    xs, ys = gx[0], gy[:, 0]
    wall, side = None, "above"
    if cfg.wall.enabled:
        wall, side = find_wall_in(acc, gx, gy, cfg.wall.stations, cfg.wall.side, st.min_count)
        y_wall = float(wall.line(np.mean(xs)))
    else:
        side = "above" if cfg.wall.side != "top" else "below"
        y_wall = float(ys[-1] + 0.5 * (ys[1] - ys[0])) if side == "above" else float(ys[0])
    sign_y = -1.0 if side == "above" else 1.0  # physical y (into the flow) vs pixel y
    dist_px = sign_y * (ys - y_wall)
    mean_u = np.nanmean(np.where(acc.count > 0, acc.mean_u, np.nan))
    sign_x = -1.0 if mean_u < 0 else 1.0
    si = mag is not None and dt > 0
    m_per_px = 1e-3 / mag if mag is not None else None
    k = (m_per_px / dt) if si else 1.0
    prof_acc = scaled_accumulator(acc, k, sign_x, sign_y)
    prof = profile_from_accumulator(prof_acc, min_count=max(st.min_count, 2))
    profile: dict[str, Any] = {
        "si": si,
        "k": k,
        "sign_x": sign_x,
        "sign_y": sign_y,
        "y_wall_px": y_wall,
        "dist_px": dist_px,
        "U": prof["U"],
        "V": prof["V"],
        "uu": prof["uu"],
        "vv": prof["vv"],
        "uv": prof["uv"],
        "count": prof["count"],
        "x_coord": (xs - xs[0]) * m_per_px if m_per_px else xs,
        "y_coord": dist_px * m_per_px if m_per_px else dist_px,
    }
    if not si:
        return RunAnalysis(
            run,
            wall,
            side,
            profile,
            None,
            "no SI units: a calibration and [flow].dt > 0 are needed",
        )
    n_eff = prof["n_eff"] if st.use_n_eff else prof["count"]
    if isinstance(n_eff, dict):
        n_eff = {kk: vv for kk, vv in n_eff.items() if kk != "V"}
    ok = (dist_px > 0) & np.isfinite(prof["U"]) & (prof["count"] > 0)
    if ok.sum() < 8:
        raise InvalidInputError(f"{run.label}: fewer than 8 profile points above the wall")
    y_m = dist_px[ok] * m_per_px
    sel = (lambda a: a[ok]) if not isinstance(n_eff, dict) else None
    ne = {kk: vv[ok] for kk, vv in n_eff.items()} if isinstance(n_eff, dict) else sel(n_eff)
    # Leave out of the composite fit the windows that reach the wall and its reflection.
    y_min_fit = (0.5 * window[1] + 1.0) * m_per_px
    result = analyse_profile(
        y_m,
        prof["U"][ok],
        prof["uu"][ok],
        prof["vv"][ok],
        prof["uv"][ok],
        cfg.flow.nu,
        ne,
        u_e=cfg.flow.u_inf if cfg.flow.u_inf > 0 else None,
        fit_offset=st.fit_offset,
        y_min_fit=y_min_fit,
    )
    return RunAnalysis(run, wall, side, profile, result)


def _wall_dict(wall) -> dict[str, Any]:
    return {
        "x_px": wall.x_px,
        "position_px": wall.position_px,
        "intercept_px": wall.intercept_px,
        "slope": wall.slope,
        "angle_deg": wall.angle_deg,
        "max_deviation_px": wall.max_deviation_px,
        "straightness_px": wall.straightness_px,
    }


def _calibration_table(cal) -> dict[str, Any]:
    r = cal.report()
    mk = cal.markers
    d = np.hypot(*(mk.image_px - mk.object_px).T)
    rc = np.hypot(*(mk.object_px - mk.object_px[mk.centre]).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(rc > 0, d / rc, 0.0)
    out: dict[str, Any] = {
        "pitch (mm)": f"{r['pitch_mm']:.3f} +/- {r['pitch_sigma_mm']:.3f}",
        "magnification M (px/mm)": f"{r['magnification']:.3f} +/- {r['magnification_sigma']:.3f}",
    }
    for m, s in r["models"].items():
        out[f"max |residual| {m.upper()} (px)"] = tuple(round(v, 3) for v in s["max_abs_px"])
        out[f"RMS residual {m.upper()} (px)"] = tuple(round(v, 3) for v in s["rms_px"])
        out[f"held-out RMS {m.upper()} (px)"] = s["loo_rms_px"]
    out["marker sigma, image (px)"] = r["image_sigma_px"]
    out["marker sigma, object (px)"] = r["object_sigma_px"]
    out["max distortion (px)"] = float(d.max())
    out["max distortion (%)"] = float(100 * rel.max())
    out["markers"] = f"{r['n_markers']} of {r['n_detected']} detected"
    out["model"] = f"{r['model']} ({r['model_reason']})"
    return out


def _wall_figure(path: pathlib.Path, res: CampaignResult, pilot: dict | None) -> pathlib.Path:
    """Wall position per station: pilot (before rotation) and each run, relative to its mean."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rspiv.outputs import atomic_path

    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    curves = []
    if pilot:
        curves.append(("before rotation (pilot)", pilot["x_px"], pilot["position_px"]))
    for a in res.analyses.values():
        if a.wall is not None:
            curves.append((a.run.label, a.wall.x_px, a.wall.position_px))
    for label, x, y in curves:
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        ax.plot(x, y - np.nanmean(y), "o-", ms=3, label=label)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("wall position - mean (px)")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path
