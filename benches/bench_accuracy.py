"""PIV accuracy you can state (issue 12): rspiv side by side with OpenPIV's windef, in one run.

    python benches/bench_accuracy.py              # everything (a few minutes on 2 cores)
    python benches/bench_accuracy.py --size 2048 1024
    python benches/bench_accuracy.py --only coverage    # items 3 and 5
    python benches/bench_accuracy.py --only accuracy    # items 1, 2 and 4
    python benches/bench_accuracy.py --only weighting   # item 6
    python benches/bench_accuracy.py --only seeding     # item 7
    python benches/bench_accuracy.py --only particle-size  # item 8
    python benches/bench_accuracy.py --only background  # item 9

1. Final windows 32, 16, 12, 8 px and 32 x 8 on one synthetic pair (2.5 px particles, 0.03 ppp,
   5 % noise, 12 bit; a smooth field of a few px, exact truth): RMS error of u and v for 1, 2
   and 3 iterations on the last pass (symmetric deformation, 50 % overlap, extra iterations
   under-relaxed), next to ``openpiv.windef.simple_multipass`` with the same windows (32 x 8
   as windef's ``(8, 32)``, rows by columns). Vectors within 32 px of the border are left out
   of both.
2. The sine response: ``u`` or ``v = 0.5 sin(2 pi y / L)`` recovered amplitude against the
   top-hat window's ``sinc(h / L)`` for L = 4, 6, 8 window heights, 1-3 iterations, and
   windef's with the same passes.
3. The per-vector uncertainty: coverage (fraction with ``|error| <= sigma``) and RMS of
   ``error / sigma`` over 54 image conditions (density 0.01-0.05 ppp, diameter 1.5-4 px, noise
   0-10 %, gradient 0-0.05 px/px), final windows 32, 16 and 32 x 8.
4. Its cost: the paper's passes on the pair with ``uncertainty`` on and off (best of 3,
   interleaved).
5. The uncertainty where the flow varies inside the windows (a random field, the truth its
   top-hat window mean).
6. The weighting windows (top-hat, Gaussian, Blackman): RMS error on the pair of item 1 and the
   sine response against ``rspiv.window_response``.
7. Seeding density: 0.0005-0.03 particles/px (2.5 px particles, a uniform displacement of
   (1.5, -0.7) px), noise-free (a clean background: runs at zero, long ones between sparse
   particle images) and with 5 % noise, 1024 x 512 px: the share of the windows inside the
   grid's two outer rings correlated, replaced by the validation, the RMS error of the valid
   vectors there, and the warning ``rspiv.piv`` gives, for 64 -> 32 and 64 -> 32 -> 32 x 8.
8. Particle image size and peak locking: particle images of 0.8-3 px nominal diameter (e^-2,
   before the pixel's integration), 0.03 particles/px, 5 % noise, 2048 x 1024 px, a ramp of
   0.3-6.3 px along x and 0.2-3.2 px along y (every fractional part equally often), the
   paper's passes; two seeds: the diameter ``PivField.particle_diameter`` reports (against the
   pixel-integrated ``4 sqrt(d^2 / 16 + 1 / 12)``), the locking bias's amplitude ``a`` (the
   error fitted as ``c - a sin(2 pi t) + b cos(2 pi t)`` in the true displacement ``t``, u and
   v pooled), the RMS error, and the warning. Then the remedies and the harm: smoothing both
   frames (``Preprocess(smooth=...)``) and the hot-pixel rule (``Preprocess(hot_pixels=3)``,
   part of ``NEAR_WALL``).
9. A minimum background over a short time-resolved recording (``rspiv.synth.particle_sequence``,
   2.5 px particles, 512 x 256 px, frames k and k + 1 paired, the campaign's background: the
   minimum over the pairs' frames A and over their frames B, subtracted): the RMS error of the
   final 32 x 8 px vectors row by row next to a wall where the flow rises linearly from 0 to 4
   px per frame over 128 px, without and with the background; particles that move less than
   their diameter over the recording stay in it.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np
import rspiv
from rspiv.peak_locking import exact_amplitude
from rspiv.synth import particle_pair

CASES = {
    "32": [(64, 64), (32, 32)],
    "16": [(64, 64), (32, 32), (16, 16)],
    "12": [(64, 64), (32, 32), (16, 16), (12, 12)],
    "8": [(64, 64), (32, 32), (16, 16), (8, 8)],
    "32x8": [(64, 64), (32, 32), (32, 8)],
}


def smooth(shape):
    h, w = shape

    def field(x, y):
        return 4.0 + 1.5 * np.sin(2 * np.pi * y / (h / 2)), 0.8 * np.cos(2 * np.pi * x / (w / 2))

    return field


def errors(x, y, u, v, field, shape, margin=32):
    h, w = shape
    tu, tv = field(x, y)
    ok = np.isfinite(u) & np.isfinite(v)
    ok &= (x > margin) & (x < w - 1 - margin) & (y > margin) & (y < h - 1 - margin)
    return (
        float(np.sqrt(np.mean((u[ok] - tu[ok]) ** 2))),
        float(np.sqrt(np.mean((v[ok] - tv[ok]) ** 2))),
    )


def openpiv_errors(a, b, sizes, field, shape):
    t = time.perf_counter()
    x, y, u, v = openpiv_field(a, b, sizes)
    t = time.perf_counter() - t
    return errors(x, y, u, v, field, shape), t


def windef_sizes(passes):
    """windef's window sizes for rspiv's passes: an int for a square window, ``(rows,
    columns)`` for a rectangular one."""
    return [w if w == h else (h, w) for w, h in passes]


def openpiv_field(a, b, sizes):
    """``windef.simple_multipass`` at 50 % overlap: x, y (rspiv's pixel-centre convention),
    u, v (image axes)."""
    from openpiv import tools, windef

    s = windef.PIVSettings()
    s.windowsizes = tuple(sizes)
    s.overlap = tuple(w // 2 if isinstance(w, int) else (w[0] // 2, w[1] // 2) for w in sizes)
    s.num_iterations = len(sizes)
    s.show_plot = False
    x, y, u, v, _ = windef.simple_multipass(a.astype(np.float64), b.astype(np.float64), s)
    x, y, u, v = tools.transform_coordinates(x, y, u, v)
    return x - 0.5, y - 0.5, u, v


def accuracy_table(shape):
    field = smooth(shape)
    a, b = particle_pair(shape, field, seed=3)
    print(f"\n1. accuracy, {shape[1]} x {shape[0]} pair (RMS error u / v, px)")
    print("| final window | rspiv 1 iteration | 2 iterations | 3 iterations | openpiv windef "
          "| rspiv s | windef s |")
    print("|---|---|---|---|---|---|---|")
    for name, passes in CASES.items():
        cells, t1 = [], 0.0
        for it in (1, 2, 3):
            t = time.perf_counter()
            f = rspiv.piv(
                a, b, passes=passes, overlap=0.5, iterations=[1] * (len(passes) - 1) + [it]
            )
            if it == 1:
                t1 = time.perf_counter() - t
            eu, ev = errors(f.x, f.y, f.u, f.v, field, shape)
            cells.append(f"{eu:.4f} / {ev:.4f}")
        (eu, ev), tw = openpiv_errors(a, b, windef_sizes(passes), field, shape)
        theirs = f"{eu:.4f} / {ev:.4f}"
        print(f"| {name} | {' | '.join(cells)} | {theirs} | {t1:.2f} | {tw:.1f} |", flush=True)


def sine_table():
    shape = (768, 768)
    amp = 0.5
    print("\n2. sine response: recovered amplitude / A of u or v = A sin(2 pi y / L) (top-hat: "
          "sinc(h / L)); windef with the same passes")
    print("| final window | component | L / h | sinc | 1 iteration | 2 | 3 | windef |")
    print("|---|---|---|---|---|---|---|---|")

    def amplitude(y, u, wl):
        ph = 2 * np.pi * y / wl
        m = np.column_stack([np.ones_like(y), np.sin(ph), np.cos(ph)])
        c, *_ = np.linalg.lstsq(m, u, rcond=None)
        return np.hypot(c[1], c[2]) / amp

    def inside(x, y):
        return (y > 40) & (y < shape[0] - 41) & (x > 40) & (x < shape[1] - 41)

    for passes, comp in itertools.product((CASES["32"], CASES["16"], CASES["32x8"]), "uv"):
        h = passes[-1][1]
        for ratio in (4, 6, 8):
            wl = ratio * h

            def field(x, y, wl=wl, comp=comp):
                wave = amp * np.sin(2 * np.pi * y / wl) + 0 * x
                return (2.0 + wave, 0.0 * x) if comp == "u" else (2.0 + 0 * x, wave)

            a, b = particle_pair(shape, field, seed=ratio)
            got = []
            for it in (1, 2, 3):
                f = rspiv.piv(
                    a, b, passes=passes, overlap=0.75, iterations=[1] * (len(passes) - 1) + [it]
                )
                ok = f.valid & inside(f.x, f.y)
                got.append(amplitude(f.y[ok], (f.u if comp == "u" else f.v)[ok], wl))
            x, y, u, v = openpiv_field(a, b, windef_sizes(passes))
            ok = np.isfinite(u) & np.isfinite(v) & inside(x, y)
            theirs = amplitude(y[ok], (u if comp == "u" else v)[ok], wl)
            w = "x".join(map(str, passes[-1]))
            cells = " | ".join(f"{g:.3f}" for g in got)
            print(f"| {w} | {comp} | {ratio} | {np.sinc(1 / ratio):.3f} | {cells} | "
                  f"{theirs:.3f} |", flush=True)


def weighting_table(shape):
    """Item 6: the weighting windows, their RMS error on the accuracy pair and their sine
    response against ``rspiv.window_response``."""
    field = smooth(shape)
    a, b = particle_pair(shape, field, seed=3)
    print(f"\n6. weighting windows, {shape[1]} x {shape[0]} pair (RMS error u / v, px; s)")
    print("| final window | tophat | gaussian | blackman |")
    print("|---|---|---|---|")
    for name in ("32", "16", "32x8"):
        cells = []
        for wt in ("tophat", "gaussian", "blackman"):
            t = time.perf_counter()
            f = rspiv.piv(a, b, passes=CASES[name], overlap=0.5, weighting=wt)
            t = time.perf_counter() - t
            eu, ev = errors(f.x, f.y, f.u, f.v, field, shape)
            cells.append(f"{eu:.4f} / {ev:.4f} ({t:.2f} s)")
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
    n, amp = 768, 0.5
    print("\nsine response u = A sin(2 pi y / L), 768 x 768, 75 % overlap, 1 iteration: "
          "measured (documented H)")
    print("| final window | L / h | tophat | gaussian | blackman |")
    print("|---|---|---|---|---|")
    for passes in (CASES["32"], CASES["32x8"]):
        h = passes[-1][1]
        for ratio in (1, 2, 4, 8):
            wl = ratio * h

            def wave(x, y, wl=wl):
                return 2.0 + amp * np.sin(2 * np.pi * y / wl) + 0 * x, 0.0 * x

            fa, fb = particle_pair((n, n), wave, seed=10 * ratio)
            cells = []
            for wt in ("tophat", "gaussian", "blackman"):
                f = rspiv.piv(fa, fb, passes=passes, overlap=0.75, weighting=wt)
                ok = f.valid & (f.x > 40) & (f.x < n - 41) & (f.y > 40) & (f.y < n - 41)
                ph = 2 * np.pi * f.y[ok] / wl
                m = np.column_stack([np.ones_like(ph), np.sin(ph), np.cos(ph)])
                c, *_ = np.linalg.lstsq(m, f.u[ok], rcond=None)
                got = np.sign(c[1]) * np.hypot(c[1], c[2]) / amp
                cells.append(f"{got:.3f} ({rspiv.window_response(wt, h, wl):.3f})")
            w = "x".join(map(str, passes[-1]))
            print(f"| {w} | {ratio} | {' | '.join(cells)} |", flush=True)


def coverage_table():
    n = 256
    print("\n3. per-vector uncertainty over 54 conditions (256 x 256 pairs); 'noisy' = the 36 "
          "with camera noise")
    print("| final window | conditions | coverage u | coverage v | rms(e/sigma) u | "
          "rms(e/sigma) v | vectors |")
    print("|---|---|---|---|---|---|---|")
    for passes in (CASES["32"], CASES["16"], CASES["32x8"]):
        r = {"u": [], "v": [], "noisy": []}
        seed = 0
        for dens, dia, noise, grad in itertools.product(
            (0.01, 0.03, 0.05), (1.5, 2.5, 4.0), (0.0, 0.05, 0.1), (0.0, 0.05)
        ):
            seed += 1

            def field(x, y, g=grad):
                return 3.3 + g * (y - n / 2), -1.7 + 0.5 * g * (x - n / 2)

            a, b = particle_pair((n, n), field, density=dens, diameter=dia, noise=noise,
                                 seed=seed)  # fmt: skip
            f = rspiv.piv(a, b, passes=passes, overlap=0.5)
            ok = f.valid & np.isfinite(f.sigma_u) & np.isfinite(f.sigma_v)
            tu, tv = field(f.x, f.y)
            r["u"].append((f.u - tu)[ok] / f.sigma_u[ok])
            r["v"].append((f.v - tv)[ok] / f.sigma_v[ok])
            r["noisy"].append(np.full(ok.sum(), noise > 0))
        ru, rv, noisy = (np.concatenate(r[k]) for k in ("u", "v", "noisy"))
        w = "x".join(map(str, passes[-1]))
        for label, sel in (("all 54", np.ones_like(noisy)), ("noisy 36", noisy)):
            cov = [np.mean(np.abs(x[sel]) <= 1) for x in (ru, rv)]
            rms = [np.sqrt(np.mean(x[sel] ** 2)) for x in (ru, rv)]
            print(f"| {w} | {label} | {cov[0]:.3f} | {cov[1]:.3f} | {rms[0]:.3f} | "
                  f"{rms[1]:.3f} | {sel.sum()} |")


def random_field_table():
    """Coverage where the flow varies inside the windows: a random field (Gaussian-filtered
    noise, 0.4 px RMS per component, correlation lengths 8, 16, 32 px) on 512 x 512 pairs, 3
    seeds; the truth a vector is compared with is the field's top-hat mean over the final
    window (the spatial response of ``crates/piv-core/src/multipass/mod.rs``)."""
    from scipy.ndimage import gaussian_filter, map_coordinates, uniform_filter

    n = 512
    print("\n5. per-vector uncertainty in a random field (512 x 512, 0.03 ppp, 5 % noise)")
    print("| correlation length px | final window | coverage u | coverage v | rms(e/sigma) u | "
          "rms(e/sigma) v | rms error px | rms sigma px |")
    print("|---|---|---|---|---|---|---|---|")
    for length in (8, 16, 32):
        rng = np.random.default_rng(length)
        fu, fv = (gaussian_filter(rng.standard_normal((n, n)), length) for _ in range(2))
        fu, fv = 0.4 * fu / fu.std(), 0.4 * fv / fv.std()

        def field(x, y, fu=fu, fv=fv):
            x, y = np.asarray(x, float), np.asarray(y, float)
            c = np.array([np.clip(y, 0, n - 1).ravel(), np.clip(x, 0, n - 1).ravel()])
            return (3.0 + map_coordinates(fu, c, order=1).reshape(x.shape),
                    -1.0 + map_coordinates(fv, c, order=1).reshape(x.shape))  # fmt: skip

        for passes in (CASES["32"], CASES["32x8"]):
            w, h = passes[-1]
            mu, mv = uniform_filter(fu, (h, w)), uniform_filter(fv, (h, w))
            q, e, sg = [], [], []
            for seed in range(3):
                a, b = particle_pair((n, n), field, density=0.03, noise=0.05, seed=seed)
                f = rspiv.piv(a, b, passes=passes, overlap=0.5)
                ok = f.valid & np.isfinite(f.sigma_u) & (f.x > 40) & (f.x < n - 41)
                ok &= (f.y > 40) & (f.y < n - 41)
                c = np.array([f.y[ok], f.x[ok]])
                tu = 3.0 + map_coordinates(mu, c, order=1)
                tv = -1.0 + map_coordinates(mv, c, order=1)
                q.append(np.column_stack([(f.u[ok] - tu) / f.sigma_u[ok],
                                          (f.v[ok] - tv) / f.sigma_v[ok]]))  # fmt: skip
                e.append(f.u[ok] - tu)
                sg.append(f.sigma_u[ok])
            q, e, sg = np.concatenate(q), np.concatenate(e), np.concatenate(sg)
            cov = np.mean(np.abs(q) <= 1, axis=0)
            rms = np.sqrt(np.mean(q**2, axis=0))
            print(f"| {length} | {w}x{h} | {cov[0]:.3f} | {cov[1]:.3f} | {rms[0]:.3f} | "
                  f"{rms[1]:.3f} | {np.sqrt(np.mean(e**2)):.4f} | {np.sqrt(np.mean(sg**2)):.4f} |")


def cost(shape):
    field = smooth(shape)
    a, b = particle_pair(shape, field, seed=5)
    best = {True: np.inf, False: np.inf}
    for _ in range(3):
        for unc in (False, True):
            t = time.perf_counter()
            rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5, uncertainty=unc)
            best[unc] = min(best[unc], time.perf_counter() - t)
    extra = best[True] / best[False] - 1
    print(f"\n4. cost of the uncertainty, {shape[1]} x {shape[0]}, 64 -> 32 -> 32 x 8: "
          f"off {best[False]:.3f} s, on {best[True]:.3f} s: +{100 * extra:.1f} %")


def seeding_table():
    import warnings

    shape = (512, 1024)
    truth = (1.5, -0.7)
    print("\n7. seeding density, 1024 x 512 px, 2.5 px particles, displacement (1.5, -0.7) px: "
          "windows inside the grid's two outer rings")
    print("| particles/px | noise | final window | correlated | replaced | RMS error (valid) px "
          "| warning |")
    print("|---|---|---|---|---|---|---|")
    for density in (0.0005, 0.001, 0.002, 0.004, 0.008, 0.03):
        for noise in (0.0, 0.05):
            a, b = particle_pair(shape, truth, density=density, noise=noise, seed=31)
            for passes in ([(64, 64), (32, 32)], [(64, 64), (32, 32), (32, 8)]):
                with warnings.catch_warnings(record=True) as rec:
                    warnings.simplefilter("always", rspiv.CorrelationWarning)
                    f = rspiv.piv(a, b, passes=passes)
                inner = np.zeros(f.u.shape, bool)
                inner[2:-2, 2:-2] = True
                ok = f.valid & inner
                err = np.hypot(f.u - truth[0], f.v - truth[1])[ok]
                rms = f"{np.sqrt(np.mean(err**2)):.3f}" if err.size else "-"
                said = "; ".join(str(w.message).split(":")[0][:60] for w in rec) or "-"
                w, h = passes[-1]
                print(f"| {density} | {noise:.2f} | {w} x {h} | "
                      f"{100 * (f.peak_ratio[inner] > 0).mean():.1f} % | "
                      f"{100 * f.replaced[inner].mean():.1f} % | {rms} | {said} |")


def _locking(d, seed, preprocess=None):
    """(field, locking amplitude a, RMS error) of item 8's ramp pair."""
    import warnings

    shape = (1024, 2048)

    def disp(x, y):
        return 6 * x / shape[1] + 0.3, 3 * y / shape[0] + 0.2

    a, b = particle_pair(shape, disp, density=0.03, diameter=d, noise=0.05, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = rspiv.piv(a, b, passes=CASES["32x8"], preprocess=preprocess)
    tu, tv = disp(f.x, f.y)
    ok = f.valid & ~f.replaced
    t = np.concatenate([tu[ok], tv[ok]])
    m = np.concatenate([f.u[ok], f.v[ok]])
    return f, exact_amplitude(t, m), float(np.sqrt(np.mean((m - t) ** 2)))


def particle_size_table():
    from rspiv.preprocess import Preprocess

    print("\n8. particle image size and peak locking, 2048 x 1024 px, 0.03 particles/px, 5 % "
          "noise, 64 -> 32 -> 32 x 8, two seeds")
    print("| nominal d px | recorded d px | measured d (x, y) px | locking a px | RMS px "
          "| warned |")
    print("|---|---|---|---|---|---|")
    for d in (0.8, 1.0, 1.2, 1.4, 1.6, 1.8, 2.0, 2.5, 3.0):
        runs = [_locking(d, s) for s in (1, 2)]
        dm = np.mean([r[0].particle_diameter for r in runs], axis=0)
        rec = 4 * np.sqrt(d * d / 16 + 1 / 12)
        warned = "yes" if runs[0][0].peak_locking() else "no"
        print(f"| {d} | {rec:.2f} | {dm[0]:.2f}, {dm[1]:.2f} | "
              f"{np.mean([r[1] for r in runs]):.4f} | {np.mean([r[2] for r in runs]):.3f} "
              f"| {warned} |")
    print("\n| nominal d px | preprocess | locking a px | RMS px |")
    print("|---|---|---|---|")
    for d in (1.0, 1.2, 1.4, 1.6, 2.0, 2.5):
        for name, pre in (("none", None), ("smooth 0.5", Preprocess(smooth=0.5)),
                          ("smooth 0.7", Preprocess(smooth=0.7)),
                          ("smooth 0.9", Preprocess(smooth=0.9)),
                          ("hot_pixels 3", Preprocess(hot_pixels=3.0))):
            runs = [_locking(d, s, pre) for s in (1, 2)]
            print(f"| {d} | {name} | {np.mean([r[1] for r in runs]):.4f} | "
                  f"{np.mean([r[2] for r in runs]):.3f} |", flush=True)


def background_table(frames: int = 20) -> None:
    """Item 9: a minimum background over a short time-resolved recording, at a wall."""
    from rspiv.preprocess import Background, Preprocess, condition
    from rspiv.synth import particle_sequence

    def flow(x, y):
        return 4.0 * np.clip(y / 128.0, 0.0, 1.0), 0.0 * y

    seq = particle_sequence((256, 512), flow, frames, diameter=2.5, seed=3)
    pairs = list(zip(seq[:-1], seq[1:], strict=True))
    bg = (Background("min"), Background("min"))
    for a, b in pairs:
        bg[0].add(a)
        bg[1].add(b)
    pre = Preprocess(background="min")
    err: dict[str, list] = {"none": [], "min": []}
    for a, b in pairs:
        for name in err:
            fa, fb = (a, b) if name == "none" else (
                condition(a, pre, bg[0].value), condition(b, pre, bg[1].value))
            f = rspiv.piv(fa, fb, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5)
            err[name].append(np.where(f.valid, f.u - flow(0.0, f.y)[0], np.nan))
    y = f.y[:, 0]
    rms = {k: np.sqrt(np.nanmean(np.array(v) ** 2, axis=(0, 2))) for k, v in err.items()}
    print(f"\n{frames} frames, pairs k, k + 1; RMS error of u (px) by row")
    print("| y, px | flow, px per frame | without background | minimum background |")
    print("|---:|---:|---:|---:|")
    for i in (0, 1, 2, 3, 4, 8, 16):
        print(f"| {y[i]:.1f} | {flow(0.0, y[i])[0]:.3f} | {rms['none'][i]:.3f} "
              f"| {rms['min'][i]:.3f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(4096, 2048), metavar=("W", "H"))
    ap.add_argument("--only",
                    choices=["accuracy", "coverage", "weighting", "seeding", "particle-size",
                             "background"],
                    help="accuracy: items 1, 2, 4; coverage: the uncertainty, items 3, 5; "
                    "weighting: item 6; seeding: item 7; particle-size: item 8; "
                    "background: item 9")
    args = ap.parse_args()
    shape = (args.size[1], args.size[0])
    if args.only == "coverage":
        coverage_table()
        random_field_table()
        return
    if args.only == "weighting":
        weighting_table(shape)
        return
    if args.only == "seeding":
        seeding_table()
        return
    if args.only == "particle-size":
        particle_size_table()
        return
    if args.only == "background":
        background_table()
        return
    cost(shape)
    accuracy_table(shape)
    sine_table()
    if args.only == "accuracy":
        return
    coverage_table()
    random_field_table()
    weighting_table(shape)
    seeding_table()
    particle_size_table()
    background_table()


if __name__ == "__main__":
    main()
