"""What a campaign will cost before it runs: time and disk from its first pair on this machine
(``rspiv check campaign.toml``).

The first pair is conditioned as the campaign conditions it (without the run's background,
which only subtracts) and correlated once with the campaign's passes and mask, timed on this
machine with all its cores. The pair loop then costs about that PIV once per run (the main
method, the extra methods and the uncorrected comparison) plus the conditioning. At 47 MP
(``benches/bench_campaign.py``'s pairs, Method II alone) it read 0.83 + 5.81 = 6.6 s per pair
where the pair loop took 6.9 s (``benches/RESULTS.md``, thirty-eighth session).

Not counted: Method I's dewarping of both frames per pair, the preparation (calibration, Monte
Carlo, backgrounds, pilot pairs: about a minute at 47 MP) and the second passes over the field
files. With ``[output] fields`` every pair writes ``u``, ``v``, ``valid`` and the two
uncertainties per vector and run (17 bytes a vector, and the replacements of the rejected ones
and the file's overhead: the demo's files hold 17.4 bytes a vector).

Times in s (hours for the whole run), sizes in GB (10^9 bytes).
"""

from __future__ import annotations

import os
import time
import warnings
from typing import Any

import numpy as np

from rspiv.piv import piv
from rspiv.preprocess import condition_pair

__all__ = ["FIELD_BYTES_PER_VECTOR", "estimate_campaign", "estimate_lines"]

#: Bytes a pair's field file holds per vector and run: u, v, sigma_u, sigma_v (float32) and
#: valid (uint8), before the replacements of the rejected vectors and the file's own overhead.
FIELD_BYTES_PER_VECTOR = 17


def estimate_campaign(camp: Any, a: np.ndarray, b: np.ndarray, mask: Any) -> dict[str, Any]:
    """Time and disk of ``camp`` from its first pair ``a``, ``b`` (module docstring)."""
    cfg = camp.config
    runs = camp.runs()
    pairs = len(camp.pairs())
    t0 = time.perf_counter()
    pre = cfg.preprocess.settings()
    if pre.enabled:
        a, b = condition_pair(a, b, pre)
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the check says what the pair holds
        field = piv(a, b, settings=cfg.piv.settings(), mask=mask)
    t2 = time.perf_counter()
    per_pair = (t1 - t0) + len(runs) * (t2 - t1)
    out: dict[str, Any] = {
        "pairs": pairs,
        "runs": [r.label for r in runs],
        "cores": os.cpu_count(),
        "condition_s": t1 - t0,
        "piv_s": t2 - t1,
        "per_pair_s": per_pair,
        "hours": pairs * per_pair / 3600.0,
        "vectors": int(field.u.size),
    }
    if cfg.output.fields:
        out["fields_gb"] = pairs * len(runs) * field.u.size * FIELD_BYTES_PER_VECTOR / 1e9
    return out


def estimate_lines(est: dict[str, Any]) -> list[str]:
    """The estimate as lines of text."""
    lines = [
        f"the first pair's PIV with the campaign's passes: {est['piv_s']:.2f} s on "
        f"{est['cores']} core(s) ({est['vectors']} vectors), conditioning {est['condition_s']:.2f}"
        f" s; {len(est['runs'])} run(s) ({', '.join(est['runs'])}): about "
        f"{est['per_pair_s']:.1f} s per pair",
        f"{est['pairs']} pair(s): about {est['hours']:.2f} h on this machine (without the "
        "preparation and Method I's dewarping; rspiv process --shard K/N splits it)",
    ]
    if "fields_gb" in est:
        lines.append(f"[output] fields: about {est['fields_gb']:.2f} GB of field files")
    return lines
