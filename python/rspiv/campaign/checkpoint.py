"""Checkpoints of a campaign run: the accumulators and the finished pair ids, written atomically
every ``checkpoint_every`` pairs and at the end to ``OUT/checkpoint/``; a restarted run (local or
Dask, either way round) loads them and skips the finished pairs. A checkpoint carries the
fingerprint of the :class:`PairContext` it was written for and is refused for another one.
"""

from __future__ import annotations

import pathlib
import pickle
from typing import Any

from rspiv.campaign.spec import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, PairContext
from rspiv.errors import InvalidInputError
from rspiv.outputs import atomic_write_bytes
from rspiv.stats import FieldAccumulator

__all__ = ["checkpoint_path", "load_checkpoint", "save_checkpoint"]


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
    """
    state = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "fingerprint": ctx.fingerprint(),
        "shard": list(shard),
        "finished": sorted(finished),
        "accumulators": accs,
        "timings": timings,
    }
    atomic_write_bytes(path, pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL))

def load_checkpoint(path: pathlib.Path, ctx: PairContext) -> dict[str, Any] | None:
    """Read the checkpoint ``path`` written by :func:`save_checkpoint`.

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
        The checkpoint is corrupt, of another checkpoint version or belongs to another
        configuration.
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
    if state.get("fingerprint") != ctx.fingerprint():
        raise InvalidInputError(
            f"{path}: checkpoint of a different configuration (calibration, PIV or runs "
            "changed); delete the checkpoint folder or choose another output folder"
        )
    return state

# ------------------------------------------------------------------ run
