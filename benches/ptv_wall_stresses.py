"""The tracks' stresses at the wall against the planted ones: single-track and two-track.

A synthetic campaign (``rspiv.demo``'s scene at ``--scale``, ``--pairs`` pairs: particle images
with their reflection in the wall, the paper's lens and magnification, the stresses of the
Schlatter & Örlü DNS at Re_theta 4060 planted by correlated random fields), processed with the
field files, then ``rspiv ptv``. For the bins from a particle image's diameter to ``y+ = 12``,
each stress's z-score against the planted one, ``(measured - planted) / SE``: the single-track
stresses (which include the tracks' own error) and the two-track ones (which leave it out,
:mod:`rspiv.ptv_profile`), in px from the truth's viscous length and friction velocity; and
``vv`` bin by bin up to ``y+ = 5``, where the planted value is below the tracks' error.

With ``--openpiv``: OpenPIV's real recordings instead (``test1``, one pair; ``test2``, six;
read from the ``openpiv`` package's installation, not vendored), which have no wall: a line
along the frame's bottom edge serves as one, bins of 2 px. Each pair tracked through its own
PIV field (64 -> 32 px, symmetric deformation), radius 1.5 px; per recording the medians over
the bins of the single-track and two-track stresses and of their difference, the tracks' own
error (isotropic errors: the same in uu and vv, none in uv).

With ``--whole-frame`` the pairs are tracked again searching the whole frames (``rspiv ptv
--whole-frame``): the time of each search, side by side, and the profiles' differences. A
``--dir`` holding a processed campaign is reused.

Run: ``python benches/ptv_wall_stresses.py [--scale 0.25 --pairs 16 --dir DIR --whole-frame |
--openpiv]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import re
import tempfile
import time

import numpy as np
from rspiv.campaign import Campaign
from rspiv.campaign.ptv import campaign_ptv
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.outputs import read_profile_csv
from rspiv.reference import load_dns


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--dir", type=pathlib.Path, default=None)
    ap.add_argument("--openpiv", action="store_true", help="OpenPIV's real recordings")
    ap.add_argument(
        "--whole-frame", action="store_true",
        help="track the pairs again searching the whole frames: the time of each and the profiles",
    )  # fmt: skip
    args = ap.parse_args()
    if args.openpiv:
        openpiv_recordings()
        return
    d = args.dir or pathlib.Path(tempfile.mkdtemp(prefix="rspiv_ptv_"))
    toml = d / "campaign.toml"
    t0 = time.perf_counter()
    if not (d / "out" / "summary.json").is_file():  # a campaign of an earlier run reused
        scene = dataclasses.replace(
            DEFAULT_SCENE, scale=args.scale, pairs=args.pairs, monte_carlo_samples=200
        )
        toml = synth_campaign(d, scene=scene)
        text = re.sub(r"(?m)^fields = \w+", "fields = true", toml.read_text())
        toml.write_text(re.sub(r"(?m)^report = \w+", "report = false", text))
        Campaign.load(toml, progress=False).run()
    t1 = time.perf_counter()
    info = campaign_ptv(Campaign.load(toml, progress=False), resume=False)
    t2 = time.perf_counter()
    truth = json.loads((d / "truth.json").read_text())
    cols, _ = read_profile_csv(info["csv"])
    ut_px = truth["u_tau"] * truth["dt"] * truth["magnification"] * 1e3  # px per pair
    y_plus = cols["h_px"] / truth["viscous_length_px"]
    dns = load_dns(4060)
    planted = {
        "uu": np.interp(y_plus, dns.y_plus, dns.urms_plus**2) * ut_px**2,
        "vv": np.interp(y_plus, dns.y_plus, dns.vrms_plus**2) * ut_px**2,
        "uv": np.interp(y_plus, dns.y_plus, dns.uv_plus) * ut_px**2,
    }
    sel = (cols["near_wall"] == 0) & (y_plus <= 12.0)
    made = f"scale {args.scale}, {args.pairs} pairs" if t1 - t0 > 1 else f"reused {d}"
    print(
        f"{made}: processed in {t1 - t0:.1f} s, tracked in {t2 - t1:.1f} s; {int(sel.sum())} "
        f"bins from y+ {y_plus[sel].min():.2f} to 12"
    )
    print("z-scores against the planted stresses (mean, spread over the bins):")
    for k, want in planted.items():
        row = []
        for kind in ("", "_two"):
            z = ((cols[f"{k}{kind}"] - want) / cols[f"se_{k}{kind}"])[sel]
            z = z[np.isfinite(z)]
            row.append(f"{'two-track' if kind else 'single'} {z.mean():+.2f} {z.std():.2f}")
        print(f"  {k}: " + "; ".join(row))
    print("vv (px^2) up to y+ 5: y+, planted, single +- SE, two-track +- SE")
    for i in np.flatnonzero(sel & (y_plus <= 5.0)):
        print(
            f"  {y_plus[i]:5.2f}  {planted['vv'][i]:.4f}  {cols['vv'][i]:.4f} +- "
            f"{cols['se_vv'][i]:.4f}  {cols['vv_two'][i]:+.4f} +- {cols['se_vv_two'][i]:.4f}"
        )
    e = info["track_error_px2"]
    print(
        f"the tracks' own error (at most): uu {e['uu']:.4f} +- {e['se_uu']:.4f}, vv "
        f"{e['vv']:.4f} +- {e['se_vv']:.4f} px^2"
    )
    s = info["sublayer"]
    if "u_tau" in s:
        print(
            f"u_tau from the sublayer {s['u_tau']:.4f} +- {s['se_u_tau']:.4f} m/s, the flow's "
            f"{truth['u_tau']:.4f}"
        )
    if args.whole_frame:
        whole_frames(toml, info, cols)


def whole_frames(toml: pathlib.Path, band: dict, cb: dict) -> None:
    """The pass again over the whole frames: the pairs' time (``seconds``: the loop over the
    pairs, without writing the outputs and the figure) against the rows near the wall's, the
    particle images searched, and the profiles' differences in their errors."""
    whole = campaign_ptv(Campaign.load(toml, progress=False), resume=False, whole_frame=True)
    cw, _ = read_profile_csv(whole["csv"])
    pairs, tb, tw = band["pairs"], band["seconds"], whole["seconds"]
    print(
        f"the pairs' loop: rows near the wall {tb:.2f} s, whole frames {tw:.2f} s for {pairs} "
        f"pairs ({tb / pairs:.2f} and {tw / pairs:.2f} s a pair): {tw / tb:.1f}x; particle "
        f"images in A {band['counts']['detected_a']} against {whole['counts']['detected_a']}"
    )
    ok = np.isfinite(cb["U"]) & np.isfinite(cw["U"])
    ratio = cb["n"][ok] / cw["n"][ok]
    z = {k: float(np.nanmax(np.abs((cb[k] - cw[k]) / cw[f"se_{k}"])[ok]))
         for k in ("U", "uu", "vv", "uv", "vv_two")}  # fmt: skip
    print(
        f"  {int(ok.sum())} bins: tracks per bin {ratio.min():.3f}-{ratio.max():.3f} of the whole "
        "frames'; largest difference in standard errors: "
        + ", ".join(f"{k} {v:.2f}" for k, v in z.items())
    )
    sb, sw = band["sublayer"], whole["sublayer"]
    if "u_tau" in sb and "u_tau" in sw:
        print(f"  u_tau {sb['u_tau']:.5f} against {sw['u_tau']:.5f} +- {sw['se_u_tau']:.5f} m/s")
    print(f"  warnings: near the wall {list(band['warnings'])}; whole {list(whole['warnings'])}")


def openpiv_recordings() -> None:
    """The module docstring's ``--openpiv`` table."""
    import openpiv  # the bench extra
    from rspiv.io import read_image
    from rspiv.piv import piv
    from rspiv.ptv import track_particles
    from rspiv.ptv_profile import TrackProfile, WallLine

    data = pathlib.Path(openpiv.__file__).parent / "data"
    recordings = {
        "test1": [(data / "test1" / "exp1_001_a.bmp", data / "test1" / "exp1_001_b.bmp")],
        "test2": [
            (data / "test2" / f"2image_{k}0.tif", data / "test2" / f"2image_{k}1.tif")
            for k in range(6)
        ],
    }
    for name, pairs in recordings.items():
        prof = None
        for pa, pb in pairs:
            a = read_image(pa).astype(np.float32)
            b = read_image(pb).astype(np.float32)
            h = float(a.shape[0])
            prof = prof or TrackProfile(WallLine(h), bin_px=2.0, band_px=h)
            f = piv(a, b, passes=[(64, 64), (32, 32)], overlap=0.5, deformation="symmetric")
            prof.add(track_particles(a, b, f, radius=1.5))
        r = prof.result()
        ok = np.isfinite(r["uu_two"])
        print(
            f"{name}: {len(pairs)} pair(s), {int(ok.sum())} bins, median "
            f"{np.median(r['n'][ok]):.0f} tracks and {np.median(r['n_two'][ok]):.0f} pairs of "
            "tracks per bin"
        )
        for k in ("uu", "vv", "uv"):
            d = (r[k] - r[f"{k}_two"])[ok]
            print(
                f"  {k}: single {np.median(r[k][ok]):.4f}, two-track "
                f"{np.median(r[f'{k}_two'][ok]):.4f}, single - two-track {np.median(d):.4f} "
                f"+- {1.2533 * d.std() / np.sqrt(d.size):.4f} px^2"
            )


if __name__ == "__main__":
    main()
