"""Checkpoints of a campaign run: the accumulators and the finished pair ids, written atomically
every ``checkpoint_every`` pairs and at the end to ``OUT/checkpoint/``; a restarted run (local or
Dask, either way round) loads them and skips the finished pairs. A checkpoint carries the
fingerprint of the :class:`PairContext` it was written for and is refused for another one
(unless only the statistics planned beside the fields changed, and the fields are kept: its
statistics are then summed again from the field files, :mod:`rspiv.campaign.rereduce`, as they
are when finished pairs were left out since), and the identity of every finished pair
(:func:`pair_key`: its files' names and frame indices), so that a pair list that changed under
the finished ids (files added, removed or renamed before them, another ``[images] pairing``) is
refused rather than resumed with the wrong frames.
"""

from __future__ import annotations

import hashlib
import pathlib
import pickle
from collections.abc import Mapping
from typing import Any

import numpy as np

from rspiv.campaign.spec import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, PairContext, PairSpec
from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_write_bytes
from rspiv.stats import FieldAccumulator

__all__ = ["checkpoint_path", "load_checkpoint", "pair_key", "save_checkpoint", "stale_error"]


def pair_key(pair: PairSpec) -> int:
    """A 64-bit identity of ``pair``: the names (not the folders: a campaign may move) of its
    files and its frame indices."""
    text = "\0".join(
        str(v)
        for v in (pathlib.Path(pair.a).name, pair.frame_a, pathlib.Path(pair.b).name, pair.frame_b)
    )
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "little")


def checkpoint_path(out_dir: pathlib.Path, shard: tuple[int, int]) -> pathlib.Path:
    """The checkpoint file of a campaign's output folder and shard.

    Returns
    -------
    pathlib.Path
        ``OUT/checkpoint/state.pkl``, or ``state.shard-I-of-N.pkl`` for shard I of N.
    """
    i, n = shard
    name = "state.pkl" if n == 1 else f"state.shard-{i}-of-{n}.pkl"
    return pathlib.Path(out_dir) / "checkpoint" / name

def save_checkpoint(
    path: pathlib.Path,
    shard: tuple[int, int],
    ctx: PairContext,
    accs: dict[str, FieldAccumulator],
    finished: set[int],
    timings: dict[str, float],
    pairs: Mapping[int, PairSpec] | None = None,
) -> None:
    """Write the checkpoint ``path`` (:func:`checkpoint_path`) of ``shard`` atomically.

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
    pairs : mapping of int to PairSpec, optional
        The campaign's pairs by id: the finished ones' :func:`pair_key` are stored.
    """
    ids = sorted(finished)
    keys = None
    if pairs is not None:
        gone = [i for i in ids if i not in pairs]
        if gone:
            raise InvalidInputError(
                f"{path}: finished pair {gone[0]} is not among the campaign's {len(pairs)} "
                "pairs (the pair list changed since it was processed)"
            )
        keys = np.array([pair_key(pairs[i]) for i in ids], np.uint64)
    state = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "fingerprint": ctx.fingerprint(),
        # what decides the pairs' fields: statistics re-reduced from field files of this hash
        "fields_fingerprint": ctx.fields_fingerprint(),
        "shard": list(shard),
        "finished": ids,
        "accumulators": accs,
        "timings": timings,
        # the identity of each pair of "finished", in its order
        **({} if keys is None else {"pair_keys": keys}),
    }
    atomic_write_bytes(path, pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL))

def load_checkpoint(
    path: pathlib.Path,
    ctx: PairContext,
    pairs: Mapping[int, PairSpec] | None = None,
    *,
    stale_ok: bool = False,
) -> dict[str, Any] | None:
    """Read the checkpoint ``path`` written by :func:`save_checkpoint`.

    Parameters
    ----------
    ctx : PairContext
        The prepared context; the checkpoint must have been written for its fingerprint.
    pairs : mapping of int to PairSpec, optional
        The campaign's pairs by id now: every finished pair must still be the same frames
        (checkpoints written without the pairs' identities are not checked).
    stale_ok : bool
        Return a checkpoint of another configuration, or one holding finished pairs that are
        no longer among ``pairs`` (left out by ``[images] exclude_pairs`` or ``max_pairs``),
        rather than refuse it; its ``stale`` entry then says how it is stale (the caller
        re-reduces the statistics without those pairs, :mod:`rspiv.campaign.rereduce`, or
        raises :func:`stale_error`). A finished pair that is now other frames is refused
        either way.

    Returns
    -------
    dict or None
        The state (keys ``accumulators``, ``finished``, ``timings``, ``shard``, ...), or
        None when there is no checkpoint. With ``stale_ok`` also ``stale``: ``{"config":
        bool (written for another fingerprint), "gone": [finished ids no longer among
        pairs]}``.

    Raises
    ------
    InvalidInputError
        The checkpoint is corrupt or of another checkpoint version, a finished pair is no
        longer the same frames, or (without ``stale_ok``) it belongs to another configuration
        or holds a pair no longer in the campaign.
    """
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
    if state.get("version") != CHECKPOINT_VERSION:
        raise InvalidInputError(
            f"{path}: checkpoint of version {state.get('version')}, this rspiv writes version "
            f"{CHECKPOINT_VERSION} (its sums do not add to the old ones); delete the checkpoint "
            "folder or choose another output folder"
        )
    stale = {"config": state.get("fingerprint") != ctx.fingerprint(), "gone": []}
    if pairs is not None:
        stale["gone"] = [i for i in state["finished"] if i not in pairs]
    if not stale_ok and (stale["config"] or stale["gone"]):
        raise stale_error(path, stale, len(pairs or ()))
    if pairs is not None and "pair_keys" in state:
        for i, key in zip(state["finished"], state["pair_keys"].tolist(), strict=True):
            p = pairs.get(i)
            if p is not None and pair_key(p) != key:
                raise InvalidInputError(
                    f"{path}: the pair list changed under the checkpoint: finished pair {i} "
                    f"is now {p.describe()}, other frames than when it was processed (files "
                    "added, removed or renamed before it, or another [images] pairing); delete "
                    "the checkpoint folder or choose another output folder"
                )
    if stale_ok:
        state["stale"] = stale
    return state


def stale_error(
    path: pathlib.Path, stale: dict[str, Any], n_pairs: int, why_not: str = ""
) -> InvalidInputError:
    """The one-line refusal of a stale checkpoint (:func:`load_checkpoint`'s ``stale``):
    another configuration, or finished pairs no longer in the campaign; ``why_not`` says why
    its statistics could not be re-reduced from the field files instead."""
    if stale["config"]:
        what = (
            "checkpoint of a different configuration (calibration, PIV, runs or the statistics "
            "carried with the pairs changed)"
        )
    else:
        gone = stale["gone"]
        what = (
            f"the pair list changed under the checkpoint: finished pair {gone[0]} is not among "
            f"the campaign's {n_pairs} pairs now (left out by [images] exclude_pairs or "
            "max_pairs, or files removed)"
        )
    tail = f"; its statistics cannot be re-reduced from the pairs' field files: {why_not}"
    return InvalidInputError(
        f"{path}: {what}{tail if why_not else ''}; delete the checkpoint folder or choose "
        "another output folder"
    )
