"""rspiv's checks of real recordings measured: do the frames correlate, is there a wall?

Run: ``python benches/real_data_checks.py`` (needs the ``openpiv`` package for its sample
recordings; they are read from its installation, not vendored). The paper's passes 64 x 64 ->
32 x 32 -> 32 x 8 (50 % overlap, symmetric deformation).

1. ``rspiv.PivField.warning`` / ``uncorrelated`` (``piv_core::validate::correlation_check``):
   for real recordings, frames that do not correlate and synthetic particle images, the final
   pass's median peak ratio over the correlated windows, the fraction of vectors the median
   test kept as valid, and what rspiv says: the whole field is no measurement, a part of it
   does not correlate, or nothing.
2. ``rspiv.find_wall``: the mirror correlation of the mean profile's stations for recordings
   without a wall (OpenPIV's) and with one (``rspiv.demo``'s synthetic layer), and whether a
   wall is found (``rspiv.wall.MIN_MIRROR_CORRELATION``).
3. The windows too blank to be correlated (``correlation_check``'s count: not masked, inside
   the grid's ``BLANK_EDGE`` outer rings) for OpenPIV's recordings with final windows of 32 x
   32, 32 x 8 and 16 x 16 px, and whether rspiv says so (``_rspiv.MAX_BLANK_FRACTION``); then
   the share of the windows correlated there whose vectors the validation rejected, and
   whether rspiv says so (``_rspiv.MAX_REPLACED_FRACTION``, on the two shares' sum).
4. The particle images' diameter (``PivField.particle_diameter``) of OpenPIV's recordings and
   of PIVlab's example recordings when fetched (``python benches/real_data_checks.py
   particle-size [PIVLAB_DIR]``: ``PIVlab_Karman_01.bmp``/``_02.bmp``, ``PIVlab_0000_A.jpg``/
   ``_B.jpg``, ``Jet_0005A.jpg``/``B.jpg`` from Shrediquette/PIVlab's ``Example_data``, not
   vendored), and whether rspiv warns of peak locking; then the same recordings binned 2 x 2
   (a sensor with pixels twice as large: particle images about half as wide) through windows
   half as large, the locking bias's amplitude measured against the full-resolution field
   (halved, interpolated to the binned grid; the error fitted as ``c - a sin(2 pi t) + b cos(2
   pi t)`` in that reference ``t``, u and v pooled), without and with ``smooth = 0.7``.
5. A time-resolved recording paired sequentially (``python benches/real_data_checks.py
   sequence PIVLAB_DIR``: PIVlab's ``PIVlab_Karman_01.bmp`` .. ``_04.bmp``, four frames of one
   series, not vendored): a campaign (``[images] pairing``) with the pairs 1-2, 3-4, with
   frames k, k + 1 and with frames k, k + 2 (twice the displacement), and, through the API,
   whether the displacement across two frames is the sum of the two across one.
"""

from __future__ import annotations

import pathlib
import warnings

import numpy as np
import rspiv
from rspiv.io import read_image
from rspiv.synth import particle_pair

PASSES = [(64, 64), (32, 32), (32, 8)]


def row(name: str, a: np.ndarray, b: np.ndarray) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = rspiv.piv(a, b, passes=PASSES)
    pr = np.asarray(f.peak_ratio)
    corr = np.isfinite(pr) & (pr > 0)
    med = float(np.median(pr[corr])) if corr.any() else float("nan")
    coef = float(np.median(np.asarray(f.coef)[corr])) if corr.any() else float("nan")
    warned = "whole" if f.uncorrelated() else "in part" if f.warning() is not None else "no"
    print(
        f"| {name} | {pr.size} | {corr.mean():.2f} | {np.mean(f.valid):.2f} | {med:.2f} "
        f"| {coef:.2f} | {100 * local_fraction(pr, np.asarray(f.valid)):.1f} | {warned} |",
        flush=True,
    )


def local_fraction(pr: np.ndarray, valid: np.ndarray) -> float:
    """The fraction of the valid vectors whose 5 x 5 neighbourhood has most of its correlated
    windows under the limit (the local test of ``correlation_check``, recomputed here)."""
    from scipy.ndimage import correlate

    corr = np.isfinite(pr) & (pr > 0)
    weak = corr & (pr < rspiv._rspiv.MIN_MEDIAN_PEAK_RATIO)
    box = np.ones((5, 5))
    count = correlate(corr.astype(float), box, mode="constant")
    low = correlate(weak.astype(float), box, mode="constant")
    return float(np.mean((2 * low > count)[valid])) if valid.any() else 0.0


def main() -> None:
    import sys

    import openpiv

    data = pathlib.Path(openpiv.__file__).parent / "data"

    def rd(p: str) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # test3 is JPEG
            return read_image(data / p)

    if len(sys.argv) > 2 and sys.argv[1] == "sequence":
        sequence_table(pathlib.Path(sys.argv[2]))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "particle-size":
        pivlab = pathlib.Path(sys.argv[2]) if len(sys.argv) > 2 else None
        particle_table(rd, pivlab)
        return

    rng = np.random.default_rng(3)
    print(
        "| frames | vectors | correlated | valid | median peak ratio | median coef "
        "| valid in uncorrelated neighbourhoods, % | warned |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    t1 = rd("test1/exp1_001_a.bmp"), rd("test1/exp1_001_b.bmp")
    t2 = [(rd(f"test2/2image_{k}0.tif"), rd(f"test2/2image_{k}1.tif")) for k in range(3)]
    row("OpenPIV test1", *t1)
    row("OpenPIV test2, pair 0", *t2[0])
    row("OpenPIV test3 (JPEG, lit on 30 %)", rd("test3/pair_4_frame_0.jpg"),
        rd("test3/pair_4_frame_1.jpg"))  # fmt: skip
    row("OpenPIV test4", rd("test4/Camera1-0101.tif"), rd("test4/Camera1-0102.tif"))
    row("OpenPIV test5, pattern 1", rd("test5/Pattern_1_A.tif"), rd("test5/Pattern_1_B.tif"))
    row("test1, frame A twice", t1[0], t1[0])
    row("test2, A of pair 0 with B of pair 1", t2[0][0], t2[1][1])
    row("test2, A of pair 0 with A of pair 1", t2[0][0], t2[1][0])
    dark = rng.normal(5, 2, t1[0].shape).clip(0).astype(np.uint8)
    row("test1, frame B dark (missing pulse)", t1[0], dark)
    row("test1, frame B shuffled", t1[0], rng.permutation(t1[1].ravel()).reshape(t1[1].shape))
    noise = [rng.integers(0, 4000, (512, 512)).astype(np.uint16) for _ in range(2)]
    row("camera noise only", *noise)
    a, b = particle_pair((512, 512), (40.0, 0.0), seed=5)[:2]
    row("synthetic, 40 px shift (64 px first windows)", a, b)
    a, b = particle_pair((512, 512), (4.0, -2.0), seed=5)[:2]
    a, b = a.copy(), b.copy()
    for f in (a, b):  # the right 40 % unlit: camera noise only
        f[:, 307:] = rng.normal(40.0, 8.0, f[:, 307:].shape).clip(0)
    row("synthetic, right 40 % unlit", a, b)
    for dens, noise_level in ((0.02, 0.05), (0.005, 0.05), (0.05, 0.3), (0.02, 0.45), (0.02, 0.6)):
        a, b = particle_pair((512, 512), (4.0, -2.0), seed=5, density=dens, noise=noise_level)[:2]
        row(f"synthetic, {dens} particles/px, noise {noise_level}", a, b)
    print()
    print("| recording | stations above the limit | median mirror correlation | wall |")
    print("|---|---:|---:|---|")
    for name, a, b in (
        ("OpenPIV test2, pair 0", *t2[0]),
        ("OpenPIV test4", rd("test4/Camera1-0101.tif"), rd("test4/Camera1-0102.tif")),
        ("OpenPIV test5, pattern 1", rd("test5/Pattern_1_A.tif"), rd("test5/Pattern_1_B.tif")),
        ("rspiv.demo's layer, one pair", *demo_pair()),
    ):
        wall_row(name, a, b)
    print()
    finals = [(32, 32), (32, 8), (16, 16)]
    print("| recording | " + " | ".join(f"{w} x {h} blank / rejected" for w, h in finals) + " |")
    print("|---|" + "---|" * len(finals))
    for name, a, b in (
        ("OpenPIV test1", *t1),
        ("OpenPIV test2, pair 0", *t2[0]),
        ("OpenPIV test2, pair 1", *t2[1]),
        ("OpenPIV test3", rd("test3/pair_4_frame_0.jpg"), rd("test3/pair_4_frame_1.jpg")),
        ("OpenPIV test4", rd("test4/Camera1-0101.tif"), rd("test4/Camera1-0102.tif")),
        ("OpenPIV test5, pattern 1", rd("test5/Pattern_1_A.tif"), rd("test5/Pattern_1_B.tif")),
        ("OpenPIV test5, pattern 10", rd("test5/Pattern_10_A.tif"),
         rd("test5/Pattern_10_B.tif")),
        ("OpenPIV test6, 0001 with 1001", rd("test6/Pattern_0001_A.tif"),
         rd("test6/Pattern_1001_B.tif")),
    ):  # fmt: skip
        blank_row(name, a, b, finals)


def _bin2(a: np.ndarray) -> np.ndarray:
    """2 x 2 binning (the mean of each block): a sensor with pixels twice as large."""
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = np.asarray(a[:h, :w], dtype=np.float32)
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def _locking_against(full, f) -> float:
    """The locking amplitude of the binned field ``f`` against the full-resolution ``full``
    (halved, interpolated bilinearly to ``f``'s centres; vectors valid in both, the few off by
    more than half a pixel left out)."""
    from scipy.interpolate import RegularGridInterpolator

    at = np.stack([2 * f.y + 0.5, 2 * f.x + 0.5], -1)
    axes = (full.y[:, 0], full.x[0, :])

    def interp(v):
        return RegularGridInterpolator(axes, v, bounds_error=False)(at)

    good = interp((full.valid & ~full.replaced).astype(float)) > 0.999
    ok = f.valid & ~f.replaced & good
    t = np.concatenate([interp(full.u)[ok] / 2, interp(full.v)[ok] / 2])
    e = np.concatenate([f.u[ok], f.v[ok]]) - t
    keep = np.abs(e) < 0.5
    t, e = t[keep], e[keep]
    x = np.stack([np.ones_like(t), np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)], 1)
    return float(-np.linalg.lstsq(x, e, rcond=None)[0][1])


def particle_table(rd, pivlab: pathlib.Path | None) -> None:
    """Item 4 of the module docstring."""
    from rspiv.preprocess import Preprocess

    pairs = [
        ("OpenPIV test1", rd("test1/exp1_001_a.bmp"), rd("test1/exp1_001_b.bmp")),
        ("OpenPIV test2, pair 0", rd("test2/2image_00.tif"), rd("test2/2image_01.tif")),
        ("OpenPIV test3 (JPEG)", rd("test3/pair_4_frame_0.jpg"), rd("test3/pair_4_frame_1.jpg")),
        ("OpenPIV test4", rd("test4/Camera1-0101.tif"), rd("test4/Camera1-0102.tif")),
        ("OpenPIV test5, pattern 1", rd("test5/Pattern_1_A.tif"), rd("test5/Pattern_1_B.tif")),
    ]  # fmt: skip (test6's first pair is test5's pattern 1 again)
    if pivlab is not None:
        for name, fa, fb in (
            ("PIVlab Karman 01 / 02", "PIVlab_Karman_01.bmp", "PIVlab_Karman_02.bmp"),
            ("PIVlab 0000 (JPEG)", "PIVlab_0000_A.jpg", "PIVlab_0000_B.jpg"),
            ("PIVlab Jet 0005 (JPEG)", "Jet_0005A.jpg", "Jet_0005B.jpg"),
        ):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                a, b = (read_image(pivlab / f) for f in (fa, fb))
            pairs.append((name, *(x.mean(-1) if x.ndim == 3 else x for x in (a, b))))
    print("| recording | diameter x, y px | warned | binned 2 x 2: diameter x, y px | warned "
          "| locking a px | with smooth 0.7: a px |")
    print("|---|---|---|---|---|---|---|")
    smooth = Preprocess(smooth=0.7)
    for name, a, b in pairs:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            full = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], overlap=0.75)
            fb = rspiv.piv(_bin2(a), _bin2(b), passes=[(32, 32), (16, 16)])
            fs = rspiv.piv(_bin2(a), _bin2(b), passes=[(32, 32), (16, 16)], preprocess=smooth)
        said = [w.message for w in rec if isinstance(w.message, rspiv.ParticleSizeWarning)]
        dx, dy = full.particle_diameter
        bx, by = fb.particle_diameter
        warned = "yes" if full.peak_locking() else "no"
        bwarned = "yes" if fb.peak_locking() else "no"
        assert len(said) == (warned == "yes") + 2 * (bwarned == "yes")
        print(f"| {name} | {dx:.2f}, {dy:.2f} | {warned} | {bx:.2f}, {by:.2f} | {bwarned} "
              f"| {_locking_against(full, fb):.4f} | {_locking_against(full, fs):.4f} |",
              flush=True)  # fmt: skip


def blank_row(name: str, a: np.ndarray, b: np.ndarray, finals: list[tuple[int, int]]) -> None:
    """The share of the windows too blank to be correlated as ``correlation_check`` counts it,
    and that of the correlated ones whose vectors the validation rejected, per final window
    (passes 64 x 64 -> 32 x 32 -> final), and what rspiv says."""
    e = rspiv._rspiv.BLANK_EDGE
    cells = []
    for final in finals:
        passes = [(64, 64), (32, 32)] + ([final] if final != (32, 32) else [])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = rspiv.piv(a, b, passes=passes)
        pr = np.asarray(f.peak_ratio)[e:-e, e:-e]
        open_ = ~np.asarray(f.masked)[e:-e, e:-e]
        corr = open_ & np.isfinite(pr) & (pr > 0)
        share = 100.0 * float(np.mean(~corr[open_]))
        rejected = 100.0 * float(np.mean(~np.asarray(f.valid)[e:-e, e:-e][corr]))
        said = f.warning() or ""
        tag = (
            " (said: blank)" if "too little signal" in said
            else " (said: interpolated)" if "only interpolated" in said
            else " (other warning)" if said else ""
        )  # fmt: skip
        cells.append(f"{share:.1f} % / {rejected:.1f} %{tag}")
    print(f"| {name} | " + " | ".join(cells) + " |")


def wall_row(name: str, a: np.ndarray, b: np.ndarray) -> None:
    from rspiv.wall import MIN_MIRROR_CORRELATION

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = rspiv.piv(a, b, passes=PASSES)
    try:
        w = rspiv.find_wall(f)
        rho = w.peak_correlation[np.isfinite(w.position_px)]
        seen = f"{rho.size} of {w.position_px.size}"
        median, verdict = float(np.median(rho)), f"found, {w.angle_deg:+.3f} deg"
    except rspiv.InvalidInputError as exc:
        # "... at k of n stations (median m; ..."
        msg = str(exc)
        seen = msg.split(") at ")[1].split(" stations")[0]
        median, verdict = float(msg.split("(median ")[1].split(";")[0]), "refused"
    print(f"| {name} | {seen} | {median:.3f} | {verdict} (limit {MIN_MIRROR_CORRELATION}) |")


def demo_pair() -> tuple[np.ndarray, np.ndarray]:
    """One pair of ``rspiv.demo``'s synthetic boundary layer (a reflecting wall), rendered at
    full scale in a temporary directory."""
    import dataclasses
    import tempfile

    from rspiv.demo import DEFAULT_SCENE, synth_campaign

    d = pathlib.Path(tempfile.mkdtemp(prefix="rspiv-wall-"))
    synth_campaign(d, scene=dataclasses.replace(DEFAULT_SCENE, pairs=1, monte_carlo_samples=0))
    raw = sorted((d / "raw").glob("*.tif"))
    return read_image(raw[0]), read_image(raw[1])



def sequence_table(pivlab: pathlib.Path) -> None:
    """Item 5: PIVlab's Karman series paired as a time-resolved recording."""
    import tempfile

    from rspiv.campaign import Campaign
    from rspiv.campaign_config import CampaignConfig, ImagesConfig

    passes = [(64, 64), (32, 32)]
    glob = str(pivlab / "PIVlab_Karman_0*.bmp")
    print("| pairing | pairs | mean u, px | mean v, px | mean speed, px |")
    print("|---|---:|---:|---:|---:|")
    for name, images in (
        ("pairs 1-2, 3-4", {}),
        ("sequential, frames k, k + 1", {"pairing": "sequential"}),
        ("sequential, frames k, k + 2", {"pairing": "sequential", "frame_gap": 2}),
    ):
        cfg = CampaignConfig()
        cfg.images = ImagesConfig(glob=glob, **images)
        cfg.correction.method = "none"
        cfg.correction.compare_uncorrected = False
        cfg.wall.enabled = False
        cfg.piv.passes = passes
        cfg.output.report = False
        with tempfile.TemporaryDirectory() as out:
            res = Campaign(cfg, progress=False, out_dir=out, log=lambda _: None).run()
        acc = res.accumulators["uncorrected"]
        seen = acc.count > 0
        u, v = acc.mean_u[seen], acc.mean_v[seen]
        print(
            f"| {name} | {res.n_done} | {u.mean():.3f} | {v.mean():.3f} "
            f"| {np.hypot(u, v).mean():.3f} |"
        )
    frames = [read_image(p) for p in sorted(pivlab.glob("PIVlab_Karman_0*.bmp"))]
    f12, f23, f13 = (
        rspiv.piv(frames[i], frames[j], passes=passes, overlap=0.5)
        for i, j in ((0, 1), (1, 2), (0, 2))
    )
    ok = f12.valid & f23.valid & f13.valid
    du = np.abs(f13.u - f12.u - f23.u)[ok]
    dv = np.abs(f13.v - f12.v - f23.v)[ok]
    print(
        f"\nframes 1-3 against 1-2 plus 2-3, {ok.sum()} vectors valid in all three: median "
        f"|du| {np.median(du):.3f} px, |dv| {np.median(dv):.3f} px (|U| 1-3: median "
        f"{np.median(np.hypot(f13.u, f13.v)[ok]):.2f} px)"
    )


if __name__ == "__main__":
    main()
