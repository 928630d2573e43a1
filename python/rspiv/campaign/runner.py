"""The campaign: its configuration, pair list and runs, and the run skeleton every executor
shares (open the run, prepare and resume, execute, analyse or write the shard, close the log).
"""

from __future__ import annotations

import gc
import hashlib
import json
import os
import pathlib
import time
from collections.abc import Callable, Sequence
from typing import Any

from rspiv.campaign import checkpoint, rereduce
from rspiv.campaign.analysis import analyse_result, write_report, write_shard
from rspiv.campaign.executors.local import LocalExecutor
from rspiv.campaign.fields import FieldWriter
from rspiv.campaign.prepare import prepare_context
from rspiv.campaign.reduce import logged_warnings, new_accumulators
from rspiv.campaign.spec import STAGES, PairContext, PairSpec, RunSpec, parse_shard, shard_slice
from rspiv.campaign.state import CampaignResult, RunLog, RunState, check_writable
from rspiv.campaign_config import CampaignConfig, load_campaign_config
from rspiv.errors import InvalidInputError
from rspiv.io import (
    DAVIS_SUFFIXES,
    camera_recording,
    davis_frame_dt,
    frame_count,
    recording_rate,
)
from rspiv.memory import numpy_huge_pages
from rspiv.phantom import PhantomRecording
from rspiv.photron import PhotronRecording, photron_header
from rspiv.progress import Progress
from rspiv.stats import FieldAccumulator

__all__ = ["Campaign"]


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
        self._pair_index: dict[int, PairSpec] | None = None

    @classmethod
    def load(cls, path: str | os.PathLike, **kwargs: Any) -> Campaign:
        """Read a campaign file (:func:`rspiv.load_campaign_config`) and build the campaign."""
        return cls(load_campaign_config(path), **kwargs)

    # ------------------------------------------------------------------ pairs
    def pairs(self) -> list[PairSpec]:
        """The campaign's pair list: ids are positions in the full list, the pairs of
        ``[images] exclude_pairs`` left out."""
        im = self.config.images
        t = im.orientation()  # [images] rotate and mirror: every frame oriented as read
        if im.multiframe is not None:
            p = pathlib.Path(im.multiframe)
            if not p.is_file():
                raise InvalidInputError(f"[images].multiframe: {p}: no such file")
            try:
                n = frame_count(p)  # TIFF pages or a high-speed recording's frames
            except InvalidInputError as exc:
                raise InvalidInputError(f"[images].multiframe: {exc}") from None
            except Exception as exc:  # noqa: BLE001
                raise InvalidInputError(f"[images].multiframe: {p}: cannot read ({exc})") from None
            idx = im.frame_pairs(n, f"[images].multiframe {p}", odd_ok=True)
            return self._kept(
                [PairSpec(k, str(p), str(p), i, j, turn=t) for k, (i, j) in enumerate(idx)]
            )
        if im.double_frame is not None:
            files = im.double_frame_files()
            return self._kept(
                [PairSpec(k, str(f), str(f), 0, 1, turn=t) for k, f in enumerate(files)]
            )
        files = im.pair_files()
        return self._kept(
            [PairSpec(k, str(a), str(b), turn=t) for k, (a, b) in enumerate(files)]
        )

    def _kept(self, pairs: list[PairSpec]) -> list[PairSpec]:
        """``pairs`` without those of ``[images] exclude_pairs`` (ids stay positions in the full
        list)."""
        gone = set(self.config.images.exclude_pairs)
        beyond = sorted(k for k in gone if k >= len(pairs))
        if beyond:
            raise InvalidInputError(
                f"[images].exclude_pairs: pair {beyond[0]} is not among the campaign's "
                f"{len(pairs)} pairs (ids are 0-based positions in the pair list)"
            )
        return [p for p in pairs if p.pair_id not in gone] if gone else pairs

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

    def say(self, msg: str) -> None:
        """Send one line to the campaign's log callable (``log_fn``), if any."""
        if self.log_fn is not None:
            self.log_fn(msg)

    def config_hash(self) -> str:
        """Hash of the configuration that the prepared context depends on."""
        d = self.config.to_dict()
        sections = ("calibration", "correction", "piv", "preprocess", "wall", "ensemble")
        keep = {k: d[k] for k in sections if k in d}
        # the statistics that ride on the pairs (planned in the context), not the analysis's
        keep["statistics"] = {
            k: v for k, v in d.get("statistics", {}).items()
            if k.startswith(("two_point", "vorticity", "screen"))
        }  # fmt: skip
        keep["extra"] = list(self.extra_methods)
        keep["pilot"] = self.pilot_pairs
        return hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()[
            :16
        ]

    # ------------------------------------------------------------------ prepare
    def prepare(self, pairs: list[PairSpec] | None = None) -> PairContext:
        """Calibrate, find the wall angle on the pilot pairs, and freeze the context
        (:func:`rspiv.campaign.prepare.prepare_context`; reuses ``OUT/context.json`` when it
        was written for the same configuration); numpy's huge pages off, as in :meth:`run`,
        and what the preparation left in reference cycles collected."""
        with numpy_huge_pages(False):
            ctx = prepare_context(self, pairs)
        # the preparation leaves its target image, backgrounds, pilot pairs' frames and fields
        # in reference cycles until Python's collector runs, which may be inside the pair loop:
        # at 47 MP about 1 GB more at its peak (benches/RESULTS.md, thirty-seventh session)
        gc.collect()
        return ctx

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self) -> pathlib.Path:
        """``OUT/checkpoint/state.pkl``, or ``state.shard-I-of-N.pkl`` for shard I of N."""
        return checkpoint.checkpoint_path(self.out_dir, self.shard)

    def save_checkpoint(
        self,
        ctx: PairContext,
        accs: dict[str, FieldAccumulator],
        finished: set[int],
        timings: dict[str, float],
    ) -> None:
        """Write this shard's checkpoint atomically, with the finished pairs' identities
        (:func:`rspiv.campaign.checkpoint.save_checkpoint`)."""
        checkpoint.save_checkpoint(
            self.checkpoint_path(), self.shard, ctx, accs, finished, timings, self.pair_index()
        )

    def load_checkpoint(self, ctx: PairContext) -> dict[str, Any] | None:
        """This shard's checkpoint, or None (:func:`rspiv.campaign.checkpoint.load_checkpoint`;
        InvalidInputError for a corrupt one, one of another configuration, or one whose
        finished pairs are no longer the same frames)."""
        return checkpoint.load_checkpoint(self.checkpoint_path(), ctx, self.pair_index())

    def pair_index(self) -> dict[int, PairSpec]:
        """The campaign's pairs by id, listed once (:meth:`pairs`) and kept."""
        if self._pair_index is None:
            self._pair_index = {p.pair_id: p for p in self.pairs()}
        return self._pair_index

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
        check_writable(self.out_dir)
        log = RunLog(self.out_dir / "run_log.jsonl")
        self._pair_index = None  # listed afresh for every run
        all_pairs = list(self.pair_index().values())
        if not all_pairs:
            raise InvalidInputError("the campaign has no image pairs")
        sel = [all_pairs[k] for k in shard_slice(len(all_pairs), self.shard)]
        return RunState(log=log, all_pairs=all_pairs, sel=sel, t_start=t_start)

    def begin_run(self, state: RunState, progress) -> None:
        """Prepare the run and resume it from the checkpoint.

        Routes the campaign's messages to ``progress`` (unless a ``log`` callable was given),
        runs :meth:`prepare`, loads the checkpoint (:meth:`load_checkpoint`; one holding pairs
        left out since, or written before the statistics planned beside the fields changed, is
        re-reduced from the field files: :mod:`rspiv.campaign.rereduce`) or starts new
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
        # a checkpoint holding pairs left out since, or written before the statistics planned
        # beside the fields changed: re-reduced from the field files when they are kept
        ckpt = rereduce.resume(self, state, ctx)
        if ckpt is not None:
            state.accs = ckpt["accumulators"]
            state.finished = set(ckpt["finished"])
            state.timings = dict(ckpt.get("timings", {}))
        else:
            state.accs = new_accumulators(ctx)
            state.finished = set()
            state.timings = {k: 0.0 for k in STAGES}
        state.n_resumed = sum(1 for p in state.sel if p.pair_id in state.finished)
        state.todo = [p for p in state.sel if p.pair_id not in state.finished]
        im = self.config.images
        if im.pairing == "sequential":
            dt = f"{self.config.flow.dt:g} s" if self.config.flow.dt else "[flow] dt"
            self.say(
                f"{len(state.sel)} pair(s) of {im.describe_pairing()}: {dt} is the time from "
                f"frame k to frame k + {im.frame_gap}"
            )
        rec = camera_recording(im.multiframe) if im.multiframe is not None else None
        if rec is None and im.glob is not None:  # frames exported beside the camera's header
            rec = exported_recording(self, pathlib.Path(im.glob).parent, ctx.image_shape)
        if rec is not None:  # a high-speed camera's own file: its figures and frame rate
            self.info["recording_file"] = recording_file(self, rec)
        first = pathlib.Path(state.sel[0].a) if state.sel else None
        if im.double_frame is not None and first and first.suffix.lower() in DAVIS_SUFFIXES:
            timing = davis_timing(self, first)  # the files' own pulse separation
            if timing is not None:
                self.info["davis_timing"] = timing
        state.fields = self.field_writer()
        if state.fields is not None:
            first = ctx.runs[0].name
            missing = sum(
                1
                for p in state.sel
                if p.pair_id in state.finished and not state.fields.path(first, p.pair_id).exists()
            )
            if missing:
                self.say(
                    f"WARNING: [output] fields: {missing} pair(s) finished before have no field "
                    f"file in {state.fields.path(first, 0).parent.parent} (processed with "
                    "fields = false, or their files removed); delete the checkpoint to redo them"
                )

    def field_writer(self) -> FieldWriter | None:
        """The writer of each pair's fields (:mod:`rspiv.campaign.fields`) when ``[output]
        fields`` is on, else None; after :meth:`prepare` (the calibration's scale)."""
        cfg = self.config
        if not cfg.output.fields:
            return None
        cal = self.calibration
        return FieldWriter(
            str(self.out_dir),
            cfg.name,
            dt=cfg.flow.dt if cfg.flow.dt > 0 else None,
            m_per_px=1e-3 / cal.magnification if cal is not None else None,
        )

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
        done_ids = {p.pair_id for p in state.sel if p.pair_id in state.finished}
        n_done = len(done_ids)
        result = CampaignResult(
            out_dir=self.out_dir,
            context=state.ctx,
            accumulators=state.accs,
            analyses={},
            n_pairs=len(state.sel),
            n_done=n_done,
            n_resumed=state.n_resumed,
            skipped=all_skipped,
            warned=logged_warnings(state.log, state.ctx.fingerprint(), done_ids),
            timings={**state.timings, "prepare": state.t_prepare},
            files={},
            wall_deviation=dict(self.info.get("wall_deviation", {})),
            info=self.info,
        )
        t0 = time.perf_counter()
        if self.shard[1] > 1:
            write_shard(self, result)
        elif n_done == 0:
            what = "skipped" if failed is None else "skipped or failed"
            raise InvalidInputError(
                f"no image pair could be processed ({len(all_skipped)} {what}; see "
                f"{self.out_dir / 'run_log.jsonl'})"
            )
        else:
            analyse_result(self, result)
        result.timings["analysis"] = time.perf_counter() - t0
        result.timings["total"] = time.perf_counter() - state.t_start
        end: dict[str, Any] = {"done": n_done, "skipped": len(skipped)}
        if failed is not None:
            end["failed"] = len(failed)
        state.log.write("end", **end, timings={k: round(v, 3) for k, v in result.timings.items()})
        return result

    def run(self, executor: Any = None) -> CampaignResult:
        """Run (or resume) the campaign with ``executor`` (default: :class:`LocalExecutor`;
        :class:`rspiv.campaign.executors.dask.DaskExecutor` for dask.distributed): open the
        run, prepare it and load the checkpoint, let the executor process the pairs still to
        do, then analyse (or write the shard) and close the run log."""
        executor = LocalExecutor() if executor is None else executor
        with numpy_huge_pages(False):  # about 1 GB less at 47 MP (rspiv.memory)
            st = self.open_run(getattr(executor, "t_start", None))
            with Progress(len(st.sel), "pairs", enabled=self.show_progress) as prog:
                self.begin_run(st, prog)
                skipped, failed = executor.execute(self, st, prog)
            return self.finish_run(st, skipped, failed=failed)

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
        ids = set().union(*(a.pair_ids for a in accumulators.values()))
        log = RunLog(self.out_dir / "run_log.jsonl")
        res = CampaignResult(
            out_dir=self.out_dir,
            context=ctx,
            accumulators=dict(accumulators),
            analyses={},
            n_pairs=n + len(skipped or {}),
            n_done=n,
            n_resumed=0,
            skipped=dict(skipped or {}),
            warned=logged_warnings(log, ctx.fingerprint(), ids),
            timings={k: 0.0 for k in STAGES},
            files={},
            wall_deviation=dict(self.info.get("wall_deviation", {})),
            info=self.info,
        )
        t0 = time.perf_counter()
        analyse_result(self, res)
        res.timings["analysis"] = time.perf_counter() - t0
        return res

    def write_report(self, res: CampaignResult, extra_sections: Sequence[Any] = ()) -> None:
        """Write the campaign report of ``res`` with ``extra_sections`` appended
        (:func:`rspiv.campaign.analysis.write_report`)."""
        write_report(self, res, extra_sections)


def recording_file(camp: Any, rec: PhotronRecording | PhantomRecording) -> dict[str, Any]:
    """``summary.json``'s ``recording_file``: the figures of an ``[images] multiframe``
    high-speed recording (:func:`rspiv.io.camera_recording`: camera, frames, bit depth, frame
    rate), said in the run log.

    With sequential pairing its frame rate fixes the time between a pair's frames: ``dt_s``
    is ``frame_gap`` frames at that rate, and a ``[flow] dt`` more than 1 % away from it is
    said loudly (``warning``): it scales every velocity. A double-frame recording (pairs) is
    not checked: a camera straddling laser pulses sets dt apart from its frame rate.
    """
    im, dt = camp.config.images, camp.config.flow.dt
    fps = rec.fps if rec.fps > 0 else None
    info: dict[str, Any] = {
        "file": str(rec.source), "camera": rec.camera, "frames": rec.frames,
        "width": rec.width, "height": rec.height, "bits": rec.bits, "depth": rec.depth,
        "fps": fps,
    }  # fmt: skip
    if rec.shutter_s > 0:
        info["shutter_s"] = rec.shutter_s
    rate = recording_rate(rec) + ("" if fps else ": [flow] dt is not checked")
    what = f"{rec.KIND} recording {rec.source.name}"
    exported = getattr(rec, "file_format", "MRaw")
    if exported.lower() != "mraw":
        what = f"{rec.KIND} header {rec.source.name} beside the frames ({exported} files)"
        info["exported_as"] = exported
    camp.say(
        f"{what}: {rec.camera + ', ' if rec.camera else ''}"
        f"{rec.frames} frames of {rec.width} x {rec.height} px, {rec.depth} of {rec.bits} bit, "
        f"{rate}"
    )
    if im.pairing != "sequential" or fps is None:
        return info
    expected = im.frame_gap / fps
    info["dt_s"] = expected
    if dt > 0 and abs(dt / expected - 1) > 0.01:
        info["warning"] = (
            f"[flow] dt = {dt:g} s, but frame k + {im.frame_gap} is {expected:g} s after frame "
            f"k at the recording's frame rate ({rec.fps:g} fps): every velocity reads "
            f"{expected / dt:.3g}x its true value"
        )
        camp.say(f"WARNING: {info['warning']}")
    elif dt <= 0:
        camp.say(
            f"at the recording's frame rate frame k + {im.frame_gap} comes {expected:g} s after "
            f"frame k: [flow] dt = {expected:g} gives velocities per second"
        )
    return info


def davis_timing(camp: Any, path: pathlib.Path) -> dict[str, Any] | None:
    """``summary.json``'s ``davis_timing``: the pulse separation a DaVis double-frame file
    holds (its frames' acquisition times, :func:`rspiv.io.davis_frame_dt`), None when it holds
    none. A ``[flow] dt`` more than 1 % away from it is said loudly (``warning``): it scales
    every velocity."""
    try:
        files_dt = davis_frame_dt(path)
    except InvalidInputError:
        return None  # the pair loop names the file
    if files_dt is None:
        return None
    dt = camp.config.flow.dt
    info: dict[str, Any] = {"file": str(path), "dt_s": files_dt}
    if dt > 0 and abs(dt / files_dt - 1) > 0.01:
        info["warning"] = (
            f"[flow] dt = {dt:g} s, but {path.name}'s frames were acquired {files_dt:g} s apart "
            f"(DaVis' AcqTimeSeries): every velocity reads {files_dt / dt:.3g}x its true value"
        )
        camp.say(f"WARNING: {info['warning']}")
    elif dt <= 0:
        camp.say(
            f"{path.name}: frames acquired {files_dt:g} s apart (DaVis' AcqTimeSeries): "
            f"[flow] dt = {files_dt:g} gives velocities per second"
        )
    return info


def exported_recording(
    camp: Any, folder: pathlib.Path, shape: tuple[int, int]
) -> PhotronRecording | None:
    """The Photron header beside frames exported as image files (PFV writes ``name.cih`` beside
    ``name000001.bmp``, ...): the one ``.cih``/``.cihx`` in the glob's folder, if its frames are
    the frames' size (either way round: ``[images] rotate``), else None. A header that cannot
    be read, or is of another size, is said and not used."""
    heads = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".cih", ".cihx"))
    if len(heads) != 1:
        return None
    try:
        rec = photron_header(heads[0])
    except InvalidInputError as exc:
        camp.say(f"the Photron header beside the frames is not used: {exc}")
        return None
    if sorted((rec.width, rec.height)) != sorted(shape):
        camp.say(
            f"the Photron header {heads[0].name} beside the frames is not used: it describes "
            f"frames of {rec.width} x {rec.height} px, these are {shape[1]} x {shape[0]}"
        )
        return None
    return rec
