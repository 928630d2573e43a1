"""One fit of the 91 calibration markers per model: rspiv side by side with scipy and numpy.

Data: the 13 x 7 marker grid over the 8864 x 5288 sensor through a known mapping of each model
(0.33 % pincushion plus decentring/perspective), normalised as rspiv does (centred on the
central marker, divided by x_o_max), then 64 Monte-Carlo perturbations (image sigma 0.057 px,
object sigma 0.380 px, central marker fixed: the paper's section 4).

Timed, per fit, in one run:
- rspiv refit: ``FitWorkspace::fit_normalized`` through the native bench entry
  ``rspiv._rspiv.bench_fit_normalized`` (the Monte Carlo path; R1/R2 warm-started from the
  unperturbed solution, and cold from the linearised solution);
- rspiv fit_mapping: the validating Python API call (pixels in, statistics and covariance out,
  tight tolerances);
- scipy ``least_squares(method="lm")`` with the analytic Jacobian, default tolerances, started
  from the unperturbed solution;
- numpy ``linalg.lstsq``: the P3 solve (the whole fit), and for R1/R2 the linearised start only.

Run: ``python benches/bench_fit.py`` (after ``maturin develop --release``).
"""

from __future__ import annotations

import pathlib
import platform
import sys
import time

import numpy as np
import rspiv
from rspiv import _rspiv
from scipy.optimize import least_squares

# The independent NumPy models and the known coefficients are the tests' ground truth.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from mapping_cases import (  # noqa: E402
    coeff_jacobian,
    eval_model,
    linear_start,
    p3_basis,
    truth_coefficients,
)

S = 8423.924
SIGMA_I, SIGMA_O = 0.057, 0.380
SETS = 64


def truth(model):
    return truth_coefficients(model)


def numpy_linear_fit(model, oh, ih):
    """numpy's fit: P3 in one lstsq with both right-hand sides; R1/R2 the linearised start."""
    if model == "p3":
        x, y = oh[:, 0], oh[:, 1]
        return np.linalg.lstsq(p3_basis(x, y).T, ih, rcond=None)[0].T.ravel()
    return linear_start(model, oh, ih)


def data(model, rng):
    pitch = 19.51 * 34.538 / S
    i, j = np.meshgrid(np.arange(13) - 6.0, np.arange(7) - 3.0)
    oh = np.column_stack([i.ravel() * pitch, j.ravel() * pitch])
    c = truth(model)
    fx, fy = eval_model(model, c, oh[:, 0], oh[:, 1])
    f0 = eval_model(model, c, np.zeros(1), np.zeros(1))
    ih = np.column_stack([fx - f0[0][0], fy - f0[1][0]])
    objs, imgs = [], []
    for _ in range(SETS):
        o = oh + rng.normal(0, SIGMA_O / S, oh.shape)
        m = ih + rng.normal(0, SIGMA_I / S, ih.shape)
        o[45], m[45] = oh[45], ih[45]  # the central marker stays at the origin
        objs.append(o)
        imgs.append(m)
    return oh, ih, objs, imgs


def per_fit(fn, sets, min_time=0.5):
    """Seconds per call of fn(k), cycling over the data sets, best of 3 batches."""
    n, best = 0, np.inf
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 0.05:
        fn(n % sets)
        n += 1
    reps = max(sets, int(n * min_time / 0.05))
    for _ in range(3):
        t = time.perf_counter()
        for k in range(reps):
            fn(k % sets)
        best = min(best, (time.perf_counter() - t) / reps)
    return best


def bench_model(model, rng):
    """Seconds per fit: (rspiv warm, rspiv cold, rspiv.fit_mapping, scipy, numpy)."""
    oh, ih, objs, imgs = data(model, rng)
    obj_stack, img_stack = np.concatenate(objs), np.concatenate(imgs)
    # unperturbed solution (the Monte Carlo warm start)
    m0 = rspiv.fit_mapping(oh * S + 4431.5, ih * S + 2600.0, model=model, center_index=45, scale=S)
    start = m0.coefficients
    reps = 20000 if model == "p3" else 5000
    t_warm = min(
        _rspiv.bench_fit_normalized(model, obj_stack, img_stack, 91, reps, list(start))
        for _ in range(3)
    )
    t_cold = min(
        _rspiv.bench_fit_normalized(model, obj_stack, img_stack, 91, reps, None) for _ in range(3)
    )
    px_o = [o * S + 4431.5 for o in objs]
    px_i = [m * S + 2600.0 for m in imgs]

    def api_fit(k):
        return rspiv.fit_mapping(px_o[k], px_i[k], model=model, center_index=45, scale=S)

    def scipy_fit(k):
        x, y = objs[k][:, 0], objs[k][:, 1]
        im = imgs[k]

        def fun(c):
            fx, fy = eval_model(model, c, x, y)
            return np.concatenate([fx - im[:, 0], fy - im[:, 1]])

        return least_squares(fun, start, jac=lambda c: coeff_jacobian(model, c, x, y), method="lm")

    def numpy_fit(k):
        return numpy_linear_fit(model, objs[k], imgs[k])

    t_api = per_fit(api_fit, SETS)
    t_scipy = per_fit(scipy_fit, SETS, 0.3)
    t_numpy = per_fit(numpy_fit, SETS)
    return t_warm, t_cold, t_api, t_scipy, t_numpy


def main():
    rng = np.random.default_rng(2024)
    rows = [(model, *bench_model(model, rng)) for model in ("p3", "r2", "r1")]
    us = 1e6
    print(f"# fit of 91 markers, one core; {platform.processor() or platform.machine()}")
    print(
        "| model | rspiv refit (warm) | rspiv refit (cold) | rspiv.fit_mapping | "
        "scipy least_squares lm | numpy lstsq | scipy / rspiv refit |"
    )
    print("|---|---|---|---|---|---|---|")
    for model, tw, tc, ta, ts, tn in rows:
        best = tc if model == "p3" else min(tw, tc)
        lin = "(whole fit)" if model == "p3" else "(linear start only)"
        print(
            f"| {model} | {tw * us:.2f} us | {tc * us:.2f} us | {ta * us:.1f} us | "
            f"{ts * us:.0f} us | {tn * us:.1f} us {lin} | {ts / best:.0f}x |"
        )


if __name__ == "__main__":
    main()
