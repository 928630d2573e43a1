"""Method II (PIV on the raw frames, vectors mapped) against Method I (dewarp, then PIV) for one
47 MP pair: wall time per stage, the ratio, and the accuracy of each against the truth.

    python benches/bench_method2.py [--scale 1.0] [--deformation both|offset|symmetric]
                                    [--two-calls] [--iterations2] [--seed 0]

Ground truth: a boundary-layer pair (:func:`rspiv.synth.tbl_pair`, 8864 x 5288 px at scale 1)
rendered through the paper-like lens; the calibration is the P3 mapping fitted to that lens
(no target detection, so only the correction is timed). Both methods use the same passes
(64 x 64 -> 32 x 32 -> 32 x 8 px, 50 % overlap), the same deformation (both by default, one
after the other) and one iteration per pass, and give vectors on the same regular object grid.

Stages. Method I, as ``rspiv.piv(method="images")`` runs it: dewarp A and B (Keys, full
precision), dewarp of a ones-image (the zero-fill mask), PIV of all passes; the first passes
alone are timed separately so that the final pass's share is their difference. Method II:
:func:`rspiv.correction.piv_vectors` without a predictor (one native call: the predictor passes
on the raw frames and the final pass at the images of the object grid on one prepared pair,
then the mapping of the vectors); the predictor passes alone are timed separately (info).
``--two-calls`` also times the final pass alone given the predictor (``piv_at``, the path of
the campaign's comparison run); ``--iterations2`` the one call with two final iterations.

Accuracy: RMS of |d - d_true| (object px) over valid vectors at least 40 px (scaled) from the
wall and 64 px from the frame edges, for each method, and between the methods.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

PASSES = [(64, 64), (32, 32), (32, 8)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--deformation", choices=["offset", "symmetric", "both"], default="both")
    ap.add_argument("--iterations2", action="store_true",
                    help="also time Method II's final pass with 2 iterations")  # fmt: skip
    ap.add_argument("--two-calls", action="store_true",
                    help="also time the final pass alone given the predictor (piv_at)")  # fmt: skip
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import rspiv
    from rspiv.synth import PAPER_OPTICS, paper_lens, tbl_pair

    s = args.scale
    optics = PAPER_OPTICS.scaled(s) if s != 1.0 else PAPER_OPTICS
    lens = paper_lens(optics)
    t0 = time.perf_counter()
    a, b, truth = tbl_pair(scale=s, seed=args.seed, lens=lens)
    h, w = a.shape
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 25), np.linspace(0, h - 1, 17))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    cal = rspiv.fit_mapping(obj, lens.distort(obj), "p3", center_index=len(obj) // 2)
    dfms = ["offset", "symmetric"] if args.deformation == "both" else [args.deformation]
    dt = time.perf_counter() - t0
    print(f"pair {w} x {h} px ({w * h / 1e6:.1f} MP), rendered in {dt:.1f} s; "
          f"passes {PASSES}, deformation {dfms}, 1 iteration per pass")  # fmt: skip

    for dfm in dfms:
        run(a, b, truth, cal, dfm, s, args)


def run(a, b, truth, cal, dfm, s, args) -> None:
    import rspiv
    from rspiv.correction import grid_for_windows, piv_vectors
    from rspiv.dewarp import dewarp

    h, w = a.shape
    times: dict[str, float] = {}

    def timed(name, fn):
        t = time.perf_counter()
        out = fn()
        times[name] = time.perf_counter() - t
        return out

    # Method I, stage by stage as rspiv.piv(method="images") runs it
    dw = [timed("I dewarp A", lambda: dewarp(a, cal)), timed("I dewarp B", lambda: dewarp(b, cal))]
    fill = timed("I dewarp ones (fill mask)",
                 lambda: dewarp(np.ones(a.shape, np.float32), cal) < 0.5)  # fmt: skip
    timed("I first passes (info)",
          lambda: rspiv.piv(*dw, PASSES[:-1], deformation=dfm, mask=fill))  # fmt: skip
    f1 = timed("I PIV, all passes", lambda: rspiv.piv(*dw, PASSES, deformation=dfm, mask=fill))
    dw.clear()
    # Method II: one native call (predictor passes + final pass on one prepared pair)
    timed("II predictor alone (info)", lambda: rspiv.piv(a, b, PASSES[:-1], deformation=dfm))
    f2 = timed("II piv_vectors (one call)",
               lambda: piv_vectors(a, b, cal, PASSES, deformation=dfm))  # fmt: skip
    if args.two_calls:
        pred = rspiv.piv(a, b, PASSES[:-1], deformation=dfm)
        timed("II final pass, given predictor (info)",
              lambda: piv_vectors(a, b, cal, PASSES, predictor=pred, deformation=dfm))  # fmt: skip
    if args.iterations2:
        timed("II one call, final 2 iterations (info)",
              lambda: piv_vectors(a, b, cal, PASSES, deformation=dfm, iterations=2))  # fmt: skip

    t_i = sum(times[k] for k in ("I dewarp A", "I dewarp B", "I dewarp ones (fill mask)",
                                 "I PIV, all passes"))  # fmt: skip
    t_ii = times["II piv_vectors (one call)"]
    final_i = times["I PIV, all passes"] - times["I first passes (info)"]
    final_ii = t_ii - times["II predictor alone (info)"]
    print(f"\n[{dfm}] {'stage':40s} {'wall time [s]':>13s}")
    for k, v in times.items():
        print(f"[{dfm}] {k:40s} {v:13.2f}")
    print(f"[{dfm}] {'I final pass (all - first passes)':40s} {final_i:13.2f}")
    print(f"[{dfm}] {'II final pass + mapping (call - pred.)':40s} {final_ii:13.2f}")
    print(f"[{dfm}] {'Method I total (3 dewarps + PIV)':40s} {t_i:13.2f}")
    print(f"[{dfm}] {'Method II total (one call)':40s} {t_ii:13.2f}")
    print(f"[{dfm}] {'II / I':40s} {t_ii / t_i:13.3f}")

    # Accuracy against the truth on the shared object grid.
    gx, gy = grid_for_windows((h, w), PASSES[-1], 0.5)
    assert np.array_equal(gx, f1.x) and np.array_equal(gx, f2.x)
    tu, tv = truth.displacement(gx, gy)
    far = truth.wall_distance(gx, gy) > 40 * s + 8
    far &= (gx > 64) & (gx < w - 65) & (gy > 64) & (gy < h - 65)

    def rms(f):
        ok = far & f.valid
        e = np.hypot(f.u - tu, f.v - tv)[ok]
        return float(np.sqrt(np.mean(e**2))), int(ok.sum())

    both = far & f1.valid & f2.valid
    d12 = float(np.sqrt(np.mean(((f1.u - f2.u) ** 2 + (f1.v - f2.v) ** 2)[both])))
    (r1, n1), (r2, n2) = rms(f1), rms(f2)
    print(f"[{dfm}] RMS vs truth: Method I {r1:.4f} px ({n1} vectors), Method II {r2:.4f} px "
          f"({n2} vectors); between them {d12:.4f} px")  # fmt: skip


if __name__ == "__main__":
    main()
