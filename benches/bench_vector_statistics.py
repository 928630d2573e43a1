"""Reducing another tool's vector files to statistics: ``rspiv.vector_statistics`` on a series of
DaVis ``.vc7`` files of a 47 MP camera's size, side by side with the floor any tool pays: the
same files read by lvpyio and summed by numpy into the mean and the covariance (Welford), in one
run.

The fields are the synthetic layer's exact fields (``tests/vector_series_cases.py``) on the
grid DaVis gives an 8864 x 5288 px frame with 32 px windows at 50 % overlap (16 px: 553 x 330
vectors), written once; each is a copy of its own (DaVis' buffer is cached per file, so copies
of one file would not be read again). rspiv's figure covers everything its reduction does: the
reading, the screen's bounds from 20 fields and the screen, the accumulator (moments to order
8, the lag-1 chains, the uncertainties' sums), the wall and the boundary-layer analysis; a
second run with the screen off shows the screen's cost (its pilot reads 20 fields more). rspiv
runs as it does by default (from 64 fields, one process per core reads the files ahead,
:mod:`rspiv.vector_readahead`); a third run reads them in the calling process (``readers=0``),
as the vortex case's last row does.

With ``--structures`` it also times the statistics with the streamwise spectra and two-point
correlations and the quadrant analysis (``two_point=True, quadrant=True``: a second pass over
the files), beside numpy's floor for the same work: the first pass's sums plus each row's
real FFT of u and v summed (transforms and their products), and a second reading of every file
whose fluctuations about the first pass's means are sorted into quadrants (``np.bincount`` per
row and quadrant).

With ``--pod`` it also times the statistics with the snapshot POD (``pod=True``: every field
decomposed, 10 modes; the screen off, as the floor has none), beside numpy's floor: the first
pass's means, a second reading of every file into one matrix of fluctuations (float64, the flow
side off the wall), its inner products ``X X^T``, ``np.linalg.eigh`` and the 10 leading modes
``X^T a``.

With ``--vortices`` it also times the vortex population (``vortices=True``: the second pass
that finds every field's cores at 1.5 times the swirl's rms per row, with and without their
Lamb-Oseen fits; the screen off), beside numpy's floor: a first reading whose swirling strength
(central differences of u and v, numpy) gives each row's rms, and a second reading whose cores
``|swirl| >= 1.5 rms`` are labelled by ``scipy.ndimage.label`` with their centroids; and
beside rspiv with the vorticity statistics alone (the first pass the population needs).

With ``--tool insight`` the same fields are TSI Insight ``.vec`` text files (mm, m/s; 8.5 MB
each) and the floor is numpy's ``loadtxt`` of each file with the same sums.

Usage::

    python benches/bench_vector_statistics.py [--fields 200] [--workdir /tmp/rspiv-vstat]
                                              [--tool davis|insight] [--structures]
                                              [--pod] [--vortices]

Prints a Markdown table (fields per second, the ratio to the floor, peak memory) for
``benches/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import pathlib
import resource
import shutil
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))


def _write(workdir: pathlib.Path, n: int, tool: str) -> list[pathlib.Path]:
    from vector_series_cases import exact_field, write_insight, write_vc7

    workdir.mkdir(parents=True, exist_ok=True)
    suffix = ".vc7" if tool == "davis" else ".vec"
    files = sorted(workdir.glob(f"B*{suffix}"))
    if len(files) >= n:
        return files[:n]
    seeds = 4  # four distinct fields at full size, copied: the reading is what is timed
    first = []
    for s in range(seeds):
        tr, x, y, u, v = exact_field(s, scale=1.0)
        path = workdir / f"B{s:05d}{suffix}"
        if tool == "davis":
            first.append(write_vc7(path, u, v, 1 / tr.magnification, tr.dt))
        else:
            first.append(write_insight(path, x, y, u, v, mm_per_px=1 / tr.magnification,
                                       dt=tr.dt, fmt="%.6f"))  # fmt: skip
    for k in range(seeds, n):
        shutil.copyfile(first[k % seeds], workdir / f"B{k:05d}{suffix}")
    return sorted(workdir.glob(f"B*{suffix}"))[:n]


def _read_davis(f: pathlib.Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import lvpyio as lv

    frame = lv.read_buffer(str(f))[0]
    u = np.asarray(frame.components["U0"][0], np.float64)
    v = np.asarray(frame.components["V0"][0], np.float64)
    return u, v, np.asarray(frame.enabled[0]) != 0


def _read_text(f: pathlib.Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a = np.loadtxt(f, delimiter=",", skiprows=1)
    return a[:, 2], a[:, 3], a[:, 4] > 0


def _floor(files: list[pathlib.Path], tool: str) -> float:
    """lvpyio (or numpy's loadtxt) + numpy: the mean and covariance of u, v over the valid
    vectors (Welford)."""
    read = _read_davis if tool == "davis" else _read_text
    t0 = time.perf_counter()
    n = mu = mv = suu = svv = suv = None
    for f in files:
        u, v, ok = read(f)
        if n is None:
            n = np.zeros(u.shape)
            mu, mv, suu, svv, suv = (np.zeros(u.shape) for _ in range(5))
        n += ok
        du = np.where(ok, u - mu, 0.0)
        dv = np.where(ok, v - mv, 0.0)
        mu += du / np.maximum(n, 1)
        mv += dv / np.maximum(n, 1)
        suu += du * np.where(ok, u - mu, 0.0)
        svv += dv * np.where(ok, v - mv, 0.0)
        suv += du * np.where(ok, v - mv, 0.0)
    return time.perf_counter() - t0


def _floor_structures(files: list[pathlib.Path], tool: str) -> float:
    """numpy's floor for the spectra and the quadrant analysis (module docstring)."""
    read = _read_davis if tool == "davis" else _read_text
    t0 = time.perf_counter()
    n = mu = mv = fa = fb = fab = None
    for f in files:
        u, v, ok = read(f)
        if n is None:
            n = np.zeros(u.shape)
            mu, mv = np.zeros(u.shape), np.zeros(u.shape)
        n += ok
        mu += np.where(ok, u - mu, 0.0) / np.maximum(n, 1)
        mv += np.where(ok, v - mv, 0.0) / np.maximum(n, 1)
        a, b = np.fft.rfft(np.nan_to_num(u), axis=1), np.fft.rfft(np.nan_to_num(v), axis=1)
        if fa is None:
            fa, fb, fab = np.zeros(a.shape, complex), np.zeros(a.shape, complex), 0
        fa += a
        fb += b
        fab = fab + (a.conj() * a).real + (b.conj() * b).real + (a.conj() * b).real
    ny = mu.shape[0]
    counts = np.zeros(ny * 4)
    rows = np.repeat(np.arange(ny), mu.shape[1]).reshape(mu.shape)
    for f in files:
        u, v, ok = read(f)
        du, dv = u - mu, v - mv
        q = np.where(du >= 0, np.where(dv >= 0, 0, 3), np.where(dv >= 0, 1, 2))
        idx = (rows * 4 + q)[ok & np.isfinite(du) & np.isfinite(dv)]
        counts += np.bincount(idx, minlength=ny * 4)
    return time.perf_counter() - t0


def _floor_pod(files: list[pathlib.Path], tool: str, rows: np.ndarray) -> float:
    """numpy's floor for the snapshot POD over the grid rows ``rows`` (module docstring)."""
    read = _read_davis if tool == "davis" else _read_text
    t0 = time.perf_counter()
    n = mu = mv = None
    for f in files:
        u, v, ok = read(f)
        if n is None:
            n, mu, mv = np.zeros(u.shape), np.zeros(u.shape), np.zeros(u.shape)
        n += ok
        mu += np.where(ok, u - mu, 0.0) / np.maximum(n, 1)
        mv += np.where(ok, v - mv, 0.0) / np.maximum(n, 1)
    x = np.empty((len(files), 2 * rows.size * mu.shape[1]))
    for i, f in enumerate(files):
        u, v, ok = read(f)
        du = np.where(ok, u - mu, 0.0)[rows].ravel()
        dv = np.where(ok, v - mv, 0.0)[rows].ravel()
        x[i] = np.concatenate([du, dv])
    lam, a = np.linalg.eigh(x @ x.T / len(files))
    modes = x.T @ a[:, ::-1][:, :10]
    assert modes.shape[1] == min(10, len(files)) and lam[-1] > 0
    return time.perf_counter() - t0


def _swirl(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Signed swirling strength by central differences (grid steps of 1; the sign of the
    vorticity): the imaginary part of the velocity gradient's eigenvalues."""
    dudx, dudy = np.gradient(u, axis=1), np.gradient(u, axis=0)
    dvdx, dvdy = np.gradient(v, axis=1), np.gradient(v, axis=0)
    tr, det = dudx + dvdy, dudx * dvdy - dudy * dvdx
    disc = det - 0.25 * tr * tr
    return np.sqrt(np.maximum(disc, 0.0)) * np.sign(dvdx - dudy)


def _floor_vortices(files: list[pathlib.Path], tool: str) -> tuple[float, int]:
    """numpy's and scipy's floor for the vortex population (module docstring); returns the
    seconds and the cores."""
    from scipy import ndimage

    read = _read_davis if tool == "davis" else _read_text
    t0 = time.perf_counter()
    sq = n = None
    for f in files:
        u, v, ok = read(f)
        s = np.where(ok, _swirl(u, v), 0.0)
        sq = s * s if sq is None else sq + s * s
        n = ok.astype(float) if n is None else n + ok
    rms = np.sqrt(sq.sum(axis=1) / np.maximum(n.sum(axis=1), 1))[:, None]
    cores = 0
    for f in files:
        u, v, ok = read(f)
        s = np.where(ok, _swirl(u, v), 0.0)
        for sign in (1.0, -1.0):
            lab, k = ndimage.label(sign * s >= 1.5 * rms)
            if k:
                ndimage.center_of_mass(np.abs(s), lab, np.arange(1, k + 1))
            cores += k
    return time.perf_counter() - t0, cores


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", type=int, default=200)
    ap.add_argument("--workdir", default="/tmp/rspiv-vstat")
    ap.add_argument("--tool", choices=("davis", "insight"), default="davis")
    ap.add_argument("--structures", action="store_true", help="also two-point and quadrant")
    ap.add_argument("--pod", action="store_true", help="also the snapshot POD")
    ap.add_argument("--vortices", action="store_true", help="also the vortex population")
    args = ap.parse_args()
    from rspiv.synth.tbl import TBLFlow
    from rspiv.vector_readahead import auto_readers
    from rspiv.vector_statistics import vector_statistics

    files = _write(pathlib.Path(args.workdir), args.fields, args.tool)
    floor = _floor(files, args.tool)
    t0 = time.perf_counter()
    r = vector_statistics(files, nu=TBLFlow().nu)
    rs = time.perf_counter() - t0
    t0 = time.perf_counter()
    vector_statistics(files, nu=TBLFlow().nu, readers=0)
    here = time.perf_counter() - t0
    t0 = time.perf_counter()
    vector_statistics(files, nu=TBLFlow().nu, screen=0)
    bare = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ny, nx = r.accumulator.shape
    print(f"{len(files)} {r.tool} fields of {nx} x {ny} vectors; u_tau {r.result.u_tau:.4f} m/s; "
          f"{auto_readers(len(files))} reader processes unless readers=0")  # fmt: skip
    print("| | s | fields/s | ratio |")
    print("|---|---|---|---|")
    reader = "lvpyio" if args.tool == "davis" else "np.loadtxt"
    print(f"| {reader} + numpy mean/cov (floor) | {floor:.2f} | {len(files) / floor:.1f} | 1 |")
    print(f"| rspiv.vector_statistics | {rs:.2f} | {len(files) / rs:.1f} | {rs / floor:.2f} |")
    print(
        f"| rspiv, the files read in the calling process (readers=0) | {here:.2f} | "
        f"{len(files) / here:.1f} | {here / floor:.2f} |"
    )
    print(
        f"| rspiv, screen off (no pilot) | {bare:.2f} | {len(files) / bare:.1f} "
        f"| {bare / floor:.2f} |"
    )
    if args.structures:
        floor2 = _floor_structures(files, args.tool)
        t0 = time.perf_counter()
        st = vector_statistics(files, nu=TBLFlow().nu, two_point=True, quadrant=True)
        both = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        n = len(files)
        print(
            f"| {reader} + numpy, row FFTs + a second reading into quadrants (floor) | "
            f"{floor2:.2f} | {n / floor2:.1f} | 1 |"
        )
        print(
            f"| rspiv.vector_statistics, two_point and quadrant | {both:.2f} | {n / both:.1f} "
            f"| {both / floor2:.2f} |"
        )
        print(f"two-point rows {st.two_point['y'].size}, quadrant rows {st.quadrant['y'].size}")
    if args.pod:
        t0 = time.perf_counter()
        pr = vector_statistics(files, nu=TBLFlow().nu, pod=True, screen=0)
        with_pod = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        floor3 = _floor_pod(files, args.tool, np.unique(pr.pod["rows"]))
        n = len(files)
        print(
            f"| {reader} + numpy, means + a second reading into X, X X^T, eigh, 10 modes "
            f"(floor) | {floor3:.2f} | {n / floor3:.1f} | 1 |"
        )
        print(
            f"| rspiv.vector_statistics, pod (10 modes), screen off | {with_pod:.2f} | "
            f"{n / with_pod:.1f} | {with_pod / floor3:.2f} |"
        )
        print(f"POD over {pr.pod['vectors']} vectors, {pr.pod['pairs']} fields: the first mode "
              f"{100 * pr.pod['fraction'][0]:.2f} %")  # fmt: skip
    if args.vortices:
        n = len(files)
        floor4, found = _floor_vortices(files, args.tool)
        times = {}
        for name, kw in (("vorticity", {"vorticity": True}),
                         ("vortices, no fits", {"vortices": True, "vortex_fits": False}),
                         ("vortices with Lamb-Oseen fits", {"vortices": True}),
                         ("vortices with fits, readers=0", {"vortices": True, "readers": 0})
                         ):  # fmt: skip
            t0 = time.perf_counter()
            vr = vector_statistics(files, nu=TBLFlow().nu, screen=0, **kw)
            times[name] = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(
            f"| {reader} + numpy swirl + a second reading labelled by scipy.ndimage (floor) | "
            f"{floor4:.2f} | {n / floor4:.1f} | 1 |"
        )
        for name, t in times.items():
            print(f"| rspiv.vector_statistics, {name}, screen off | {t:.2f} | {n / t:.1f} "
                  f"| {t / floor4:.2f} |")  # fmt: skip
        cores = int(vr.vortices["count"].sum())
        fits = times["vortices with Lamb-Oseen fits"] - times["vortices, no fits"]
        print(f"floor: {found} cores; rspiv: {cores} cores in {vr.vortices['y'].size} rows "
              f"(delta_99), {vr.vortices['fits_kept']} fits kept; the fits "
              f"{1e3 * fits / max(cores, 1):.2f} ms a core")  # fmt: skip
    print(f"peak RSS {peak:.0f} MB (this process; each reader process holds about 140 MB more)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
