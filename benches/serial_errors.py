"""The profile's errors for pairs that follow each other in time, against the exact ones.

Run: ``python benches/serial_errors.py [--rows 200] [--cols 8]``. Each row's mean of u follows
a first-order autoregressive process from pair to pair (correlation ``phi``, variance 0.09
px^2: a time-resolved recording's slow scales) under independent noise per vector (variance
0.25 px^2: the small scales and the measurement noise), so the variance of a row's mean over
the run is known exactly. For each ``phi`` and number of pairs it prints the exact factor on
the variance of U (over that of independent pairs), the median factor the rows find
(:meth:`rspiv.row_errors.RowErrors.serial`), the share of rows whose factor is said to be a
lower bound, and the spread of the rows' z scores against the true mean with the errors
:func:`rspiv.profiles.pair_errors` gives (1 when they are right), with the per-vector lag-1
``n_eff`` alone, and for independent pairs.
"""

from __future__ import annotations

import argparse

import numpy as np
from rspiv.profiles import pair_errors
from rspiv.row_errors import RowErrors
from rspiv.stats import FieldAccumulator

SLOW_VAR, NOISE_VAR = 0.09, 0.25


def run(rows: int, cols: int, pairs: int, phi: float, seed: int) -> dict[str, float]:
    """One synthetic run (module docstring) and its figures."""
    rng = np.random.default_rng(seed)
    acc = FieldAccumulator((rows, cols))
    acc.rows = RowErrors(rows)
    a = rng.normal(0.0, np.sqrt(SLOW_VAR), rows)
    for k in range(pairs):
        u = 5.0 + a[:, None] + rng.normal(0.0, np.sqrt(NOISE_VAR), (rows, cols))
        v = rng.normal(0.0, np.sqrt(NOISE_VAR), (rows, cols))
        acc.add(u, v, pair_id=k)
        acc.rows.add(u, v, pair_id=k)
        a = phi * a + np.sqrt(1 - phi * phi) * rng.normal(0.0, np.sqrt(SLOW_VAR), rows)
    lag = np.arange(pairs)
    c = SLOW_VAR * phi**lag
    c[0] += NOISE_VAR / cols
    exact = (pairs * c[0] + 2 * np.sum((pairs - lag[1:]) * c[1:])) / pairs**2
    res = acc.rows.result()
    pe = pair_errors(acc)
    lag1 = acc.n_eff("u").sum(1) / acc.count.sum(1)
    d = res["U"] - 5.0
    return {
        "exact": exact * pairs / c[0],
        "found": float(np.median(res["serial_U"])),
        "open": float(np.mean(res["open_U"])),
        "z": float(np.std(d / pe["U"])),
        "z_lag1": float(np.std(d / (res["se_U"] / np.sqrt(np.minimum(lag1, 1.0))))),
        "z_indep": float(np.std(d / res["se_U"])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=200)
    ap.add_argument("--cols", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print(
        "| phi | pairs | exact factor | found (median) | rows open | z spread | z, lag-1 n_eff "
        "| z, independent |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for phi in (0.0, 0.5, 0.8, 0.95):
        for pairs in (40, 200, 1000):
            r = run(args.rows, args.cols, pairs, phi, args.seed)
            print(
                f"| {phi} | {pairs} | {r['exact']:.2f} | {r['found']:.2f} | "
                f"{100 * r['open']:.0f} % | {r['z']:.2f} | {r['z_lag1']:.2f} | "
                f"{r['z_indep']:.2f} |"
            )


if __name__ == "__main__":
    main()
