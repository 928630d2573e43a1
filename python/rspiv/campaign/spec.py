"""What a campaign runs: the pairs, the runs, the frozen per-pair context and results.

:class:`PairSpec` (one image pair), :class:`RunSpec` (one way of processing every pair: Method I,
Method II or no correction), :class:`PairContext` (everything the per-pair work needs, picklable,
fingerprinted for the checkpoints), :class:`PairResult` (what one pair gives), and the shard
arithmetic (:func:`parse_shard`, :func:`shard_slice`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

import numpy as np

from rspiv.correction import final_grid
from rspiv.errors import InvalidInputError
from rspiv.io import read_mask
from rspiv.mapping import Mapping
from rspiv.outlier_screen import ScreenBounds
from rspiv.preprocess import Preprocess, condition_pair
from rspiv.settings import PivSettings

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "STAGES",
    "PairContext",
    "PairResult",
    "PairSpec",
    "RunSpec",
    "parse_shard",
    "shard_slice",
]

CHECKPOINT_FORMAT = "rspiv-checkpoint"
#: 2: the context holds one PivSettings (was loose passes/overlap/... fields)
#: 3: the single-pixel rows' planes are normalised per row and pair (were per segment): their
#: sums do not add to version 2's
CHECKPOINT_VERSION = 3
#: Stages timed per pair (s), in the run log and the report: ``read`` (the wait for the frames
#: when they are read ahead), ``condition`` (the frames' preprocessing), ``dewarp`` (Method I),
#: ``piv`` (with Method II's mapping, the correlation check and the pair's figures,
#: :mod:`rspiv.campaign.pair_quality`), ``statistics``, ``ensemble``.
STAGES = ("read", "condition", "dewarp", "piv", "statistics", "ensemble")


@dataclasses.dataclass(frozen=True)
class PairSpec:
    """One image pair: its id (index in the campaign's full pair list) and its frames.

    ``frame_a``/``frame_b`` are frame indices inside a multi-frame TIFF (``a == b`` is that
    file), None for single-frame files. ``turn``: the orientation given to both frames as they
    are read (``[images] rotate`` and ``mirror``, :func:`rspiv.io.turn_frame`).
    """

    pair_id: int
    a: str
    b: str
    frame_a: int | None = None
    frame_b: int | None = None
    turn: int = 0

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

    @property
    def mapping(self) -> str:
        """Method II's displacement mapping: "full" or "positions"."""
        return "full" if self.map_displacement else "positions"


@dataclasses.dataclass
class PairContext:
    """Everything :func:`rspiv.campaign.pair.process_pair` needs; picklable (plain data, the
    mapping as JSON, the PIV settings as one :class:`rspiv.PivSettings`).

    ``object_shape`` is the (h, w) of the object frame (the dewarped images), ``image_shape``
    the raw frames' (h, w); pairs of another size are skipped.
    """

    runs: tuple[RunSpec, ...]
    image_shape: tuple[int, int]
    object_shape: tuple[int, int]
    mapping_json: str | None
    piv: PivSettings
    mask_path: str | None = None
    preprocess: Preprocess = dataclasses.field(default_factory=Preprocess)
    background_paths: tuple[str, str] | None = None
    #: run name -> the ensemble band of that run (:mod:`rspiv.campaign.ensemble`), or None
    ensemble: dict[str, Any] | None = None
    #: the streamwise spectra's columns and the two-point maps' rows per run, and
    #: ``min_valid`` (:func:`rspiv.campaign.two_point.plan`), or None
    two_point: dict[str, Any] | None = None
    #: the difference scheme of the vorticity statistics (:mod:`rspiv.vorticity`), or None
    vorticity: str | None = None
    #: the run's direction ``(u, v)`` px per pair in the raw frame, from the pairs sampled
    #: before the run (:func:`rspiv.recording_drift.flow_direction`): a pair pointing the other
    #: way is left out (:mod:`rspiv.campaign.pair_quality`); None: not looked for
    reference: tuple[float, float] | None = None
    #: the screen of the statistics (:mod:`rspiv.outlier_screen`): ``sigmas``, the pilot
    #: ``pairs`` and per run the bounds' file and digest (``runs``); None: no screen
    screen: dict[str, Any] | None = None
    #: the orientation of every frame, the target and the mask as read (``[images] rotate``
    #: and ``mirror``, :func:`rspiv.io.turn_frame`); ``image_shape`` is that of the turned
    #: frames
    turn: int = 0
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
            m = Mapping.from_json(self.mapping_json)
            self._cache["mapping"] = m
        return m

    def mask(self):
        """The PIV mask (bool, True = excluded) in the raw frame, or None
        (:func:`rspiv.io.read_mask`: an image or a JSON of polygons)."""
        if self.mask_path is None:
            return None
        if "mask" not in self._cache:
            self._cache["mask"] = read_mask(self.mask_path, tuple(self.image_shape), self.turn)
        return self._cache["mask"]

    def backgrounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The run's backgrounds of frames A and B (float32, loaded once per process)."""
        if self.background_paths is None:
            return None
        if "backgrounds" not in self._cache:
            out = []
            for path in self.background_paths:
                try:
                    out.append(np.load(path))
                except (OSError, ValueError) as exc:
                    raise InvalidInputError(f"{path}: cannot read the background: {exc}") from None
            self._cache["backgrounds"] = (out[0], out[1])
        return self._cache["backgrounds"]

    def screens(self) -> dict[str, Any]:
        """Run name -> its :class:`rspiv.outlier_screen.ScreenBounds` (loaded once per
        process; empty without a screen)."""
        if self.screen is None:
            return {}
        if "screens" not in self._cache:
            self._cache["screens"] = {
                run: ScreenBounds.load(d["path"]) for run, d in self.screen["runs"].items()
            }
        return self._cache["screens"]

    def condition(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frames A and B conditioned by ``preprocess`` with the run's backgrounds (the frames
        themselves when nothing is switched on)."""
        if not self.preprocess.enabled:
            return a, b
        return condition_pair(a, b, self.preprocess, self.backgrounds())

    def ensemble_preprocess(self) -> Preprocess | None:
        """The conditioning of the frames the ensemble bands correlate, when it differs from
        ``preprocess``: the same without the high-pass filter and the smoothing. A high-passed
        particle image's correlation has negative side lobes (the filter removes its mean), so
        the summed cross peak is no longer the auto peak widened by the displacement PDF that
        the Reynolds stresses are read from; each window's mean removal already takes out the
        background. The smoothing is there against peak locking of single peaks, which a
        summed plane does not suffer, and would cost the bands' resolution next to the wall.
        None: the PIV's own conditioned frames serve."""
        pre = self.preprocess
        if not pre.enabled or (pre.high_pass <= 0 and pre.smooth <= 0):
            return None
        return dataclasses.replace(pre, high_pass=0.0, smooth=0.0)

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Window centres (px) of the final pass, shape (ny, nx) each (same for every run)."""
        return final_grid(self.object_shape, self.piv)

    def to_dict(self) -> dict[str, Any]:
        return {
            "image_shape": list(self.image_shape),
            "object_shape": list(self.object_shape),
            "mapping_json": self.mapping_json,
            "piv": self.piv.to_dict(),
            "mask_path": self.mask_path,
            "preprocess": self.preprocess.to_dict(),
            "background_paths": self.background_paths,
            "runs": [dataclasses.asdict(r) for r in self.runs],
            **({} if self.ensemble is None else {"ensemble": self.ensemble}),
            **({} if self.two_point is None else {"two_point": self.two_point}),
            **({} if self.vorticity is None else {"vorticity": self.vorticity}),
            **({} if self.reference is None else {"reference": list(self.reference)}),
            **({} if self.screen is None else {"screen": self.screen}),
            **({"turn": self.turn} if self.turn else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PairContext:
        return cls(
            runs=tuple(RunSpec(**r) for r in d["runs"]),
            image_shape=tuple(d["image_shape"]),
            object_shape=tuple(d["object_shape"]),
            mapping_json=d["mapping_json"],
            piv=PivSettings.from_dict(d["piv"], where="context.json [piv]"),
            mask_path=d["mask_path"],
            preprocess=Preprocess.from_dict(d.get("preprocess", {}), "context.json [preprocess]"),
            background_paths=(
                None if d.get("background_paths") is None else tuple(d["background_paths"])
            ),
            ensemble=d.get("ensemble"),
            two_point=d.get("two_point"),
            vorticity=d.get("vorticity"),
            reference=None if d.get("reference") is None else tuple(d["reference"]),
            screen=d.get("screen"),
            turn=int(d.get("turn", 0)),
        )

    def fingerprint(self) -> str:
        """Hash of everything that changes the per-pair results (checkpoints must match)."""
        return _hash(self.to_dict())

    def fields_fingerprint(self) -> str:
        """Hash of what decides each pair's vector fields and whether the pair is kept: the
        context without the statistics planned beside them (the ensemble bands, the two-point
        sums, the vorticity, the screen of the statistics). Carried by each field file
        (:mod:`rspiv.campaign.fields`) and checkpoint: statistics can be re-reduced from field
        files of the same hash (:mod:`rspiv.campaign.rereduce`)."""
        d = self.to_dict()
        for key in ("ensemble", "two_point", "vorticity", "screen"):
            d.pop(key, None)
        return _hash(d)


def _hash(d: dict[str, Any]) -> str:
    """16 hex digits of the SHA-256 of ``d`` as sorted JSON."""
    text = json.dumps(d, sort_keys=True)
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
        Run name -> ``(u, v, valid, sigma_u, sigma_v)`` arrays of the grid's shape (px per
        pair; the sigmas None when the PIV estimated none).
    timings : dict
        Seconds per stage (:data:`STAGES`; ``statistics`` is the caller's).
    warning : str
        For a pair processed (``ok``) whose frames correlate only in part (a region unlit or
        with too few particle images, :meth:`rspiv.PivField.warning`): the run and the
        warning; its vectors are in the statistics, random ones among them. Empty otherwise.
    quality : dict
        Run name -> the pair's figures (:func:`rspiv.campaign.pair_quality.measure`: the
        valid share, the median peak ratio, the mean displacement; and the frames' as
        recorded, :func:`rspiv.recording_drift.pair_brightness`); empty when the PIV did not
        run to the end.
    """

    pair_id: int
    ok: bool
    reason: str = ""
    #: per run: ``(u, v, valid, sigma_u, sigma_v)`` in px per pair (the sigmas None when the
    #: PIV estimated none)
    fields: dict[
        str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]
    ] = dataclasses.field(default_factory=dict)
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    warning: str = ""
    quality: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)


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
