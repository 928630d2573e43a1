"""Calibration benchmarks, rspiv side by side with a scipy/numpy version of the same loop.

1. Marker detection on the full 47 MP target (8864 x 5288, 91 dots, paper optics and noise):
   rspiv's `detect_markers` (FFT correlation on a block-averaged copy + per-marker Gaussian LM
   fit) against scipy.ndimage (Gaussian filter + maximum filter + scipy.optimize.least_squares
   per marker, the same model) timed in the same run.
2. Monte Carlo N = 500,000 for P3 and for R2 (rspiv, all cores) against the same loop in
   numpy (P3: one lstsq per sample) / scipy (R2: scipy.optimize.least_squares, method "lm",
   analytic Jacobian, warm start from the nominal fit, per sample),
   timed on a subsample and scaled per sample.

Run: python benches/bench_calibration.py [--n 500000] [--quick] [--skip-detect]
"""

from __future__ import annotations

import argparse
import os
import time

# Small per-sample problems: BLAS threads only add contention (fair to the peer).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import rspiv
import scipy.ndimage as ndi
from rspiv import _rspiv
from rspiv.synth import calibration_target
from scipy.optimize import least_squares


def scipy_detect(img: np.ndarray, s: float) -> np.ndarray:
    """The same detection in scipy: smooth, local maxima, Gaussian + plane fit per marker."""
    f = img.astype(np.float32)
    sm = ndi.gaussian_filter(f, s) - ndi.uniform_filter(f, int(8 * s))
    mx = ndi.maximum_filter(sm, size=int(3 * s))
    peaks = np.argwhere((sm == mx) & (sm > 0.25 * sm.max()))
    out = []
    hw = int(np.ceil(2.5 * s))
    for y0, x0 in peaks:
        ys, xs = np.mgrid[y0 - hw : y0 + hw + 1, x0 - hw : x0 + hw + 1]
        z = f[y0 - hw : y0 + hw + 1, x0 - hw : x0 + hw + 1].ravel()
        xw, yw = (xs - x0).ravel() / hw, (ys - y0).ravel() / hw
        xf, yf = xs.ravel().astype(float), ys.ravel().astype(float)

        def res(p, xf=xf, yf=yf, xw=xw, yw=yw, z=z):
            g = np.exp(-((xf - p[1]) ** 2 + (yf - p[2]) ** 2) / (2 * p[3] ** 2))
            return p[4] + p[5] * xw + p[6] * yw + p[0] * g - z

        p0 = [z.max() - np.median(z), x0, y0, s, np.median(z), 0, 0]
        out.append(least_squares(res, p0, method="lm").x[1:3])
    return np.array(out)


def p3_basis(o: np.ndarray) -> np.ndarray:
    x, y = o[:, 0], o[:, 1]
    return np.column_stack([x**a * y**b for a in range(4) for b in range(4 - a)])


def r2_eval(c: np.ndarray, o: np.ndarray) -> np.ndarray:
    x, y = o[:, 0], o[:, 1]
    num = np.column_stack([x, y, np.ones_like(x), x * x, x * y, y * y])
    den = 1 + np.column_stack([x, y, x * x, x * y, y * y]) @ c[12:17]
    return np.column_stack([num @ c[0:6] / den, num @ c[6:12] / den])


def r2_jac(c: np.ndarray, o: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of the raveled R2 residuals (rows x0, y0, x1, y1, ...)."""
    x, y = o[:, 0], o[:, 1]
    num = np.column_stack([x, y, np.ones_like(x), x * x, x * y, y * y])
    denb = np.column_stack([x, y, x * x, x * y, y * y])
    den = 1 + denb @ c[12:17]
    fx, fy = num @ c[0:6] / den, num @ c[6:12] / den
    j = np.zeros((2 * len(x), 17))
    j[0::2, 0:6] = num / den[:, None]
    j[1::2, 6:12] = num / den[:, None]
    j[0::2, 12:17] = -(fx / den)[:, None] * denb
    j[1::2, 12:17] = -(fy / den)[:, None] * denb
    return j


def numpy_mc(cal, n: int, model: str, si: float, so: float, seed: int = 0) -> float:
    """The Monte Carlo loop in numpy/scipy; returns seconds per sample."""
    mk = cal.markers
    s = cal.mapping.scale
    oh = (mk.object_px - mk.object_px[mk.centre]) / s
    ih = (mk.image_px - mk.image_px[mk.centre]) / s
    rng = np.random.default_rng(seed)
    c0 = np.zeros(17)
    c0[0] = c0[7] = 1.0
    if model == "r2":
        c0 = least_squares(
            lambda c: (r2_eval(c, oh) - ih).ravel(), c0, jac=lambda c: r2_jac(c, oh), method="lm"
        ).x
    t = time.perf_counter()
    acc = np.zeros_like(oh)
    for _ in range(n):
        zo = rng.normal(0, so / s, oh.shape)
        zi = rng.normal(0, si / s, ih.shape)
        zo[mk.centre] = 0
        zi[mk.centre] = 0
        o, i = oh + zo, ih + zi
        if model == "p3":
            phi = p3_basis(o)
            c, *_ = np.linalg.lstsq(phi, i, rcond=None)
            eps = phi @ c - i
        else:
            c = least_squares(
                lambda c, o=o, i=i: (r2_eval(c, o) - i).ravel(),
                c0,
                jac=lambda c, o=o, i=i: r2_jac(c, o),
                method="lm",
            ).x
            eps = r2_eval(c, o) - i
        acc += eps
    return (time.perf_counter() - t) / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=500_000)
    ap.add_argument("--quick", action="store_true", help="smaller N for a smoke run")
    ap.add_argument("--threads", type=int, default=None, help="rspiv threads (default: all)")
    a = ap.parse_args()
    n = 20_000 if a.quick else a.n
    print(f"cores: {os.cpu_count()}, rayon threads: default")
    t = time.perf_counter()
    tg = calibration_target(seed=0)
    print(f"render 47 MP target: {time.perf_counter() - t:.2f} s, shape {tg.image.shape}")
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        det = _rspiv.detect_markers(tg.image)
        best = min(best, time.perf_counter() - t)
    s = det["size_px"]
    print(f"rspiv detect_markers 47 MP: {best:.3f} s ({len(det['image_px'])} markers)")
    t_sp = np.inf
    for _ in range(2):  # best of two, as rspiv's (a first run also pays the peer's warm-up)
        t = time.perf_counter()
        sp = scipy_detect(tg.image, s)
        t_sp = min(t_sp, time.perf_counter() - t)
    print(f"scipy detection 47 MP: {t_sp:.3f} s ({len(sp)} markers); ratio {t_sp / best:.1f}x")
    t = time.perf_counter()
    cal = rspiv.calibrate(tg.image, 19.51, model="p3", compare=False)
    print(f"rspiv.calibrate 47 MP (read, detect, index, fit): {time.perf_counter() - t:.3f} s")
    si, so = 0.057, 0.380
    for model, sub in (("p3", 2000), ("r2", 200)):
        t = time.perf_counter()
        r = rspiv.monte_carlo(
            cal, n=n, sigma_image_px=si, sigma_object_px=so, model=model, threads=a.threads
        )
        t_rs = time.perf_counter() - t
        per = numpy_mc(cal, sub, model, si, so)
        print(
            f"monte carlo {model} N={n}: rspiv {t_rs:.2f} s ({t_rs / n * 1e6:.2f} us/sample, "
            f"{r.n_failed} failed); numpy/scipy {per * 1e6:.1f} us/sample on {sub} samples "
            f"(-> {per * n:.0f} s for N); ratio {per * n / t_rs:.0f}x; "
            f"max 99% radius {r.radius99_px.max():.3f} px"
        )


if __name__ == "__main__":
    main()
