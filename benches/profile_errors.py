"""How conservative are a campaign profile's standard errors? Measured from its field files.

A campaign's profile averages each row of vectors along the wall over every pair, and its
standard errors (``eps_U = sqrt(uu / n_eff)``, ``eps_uu = uu sqrt(2 / n_eff)``:
:mod:`rspiv.boundary_layer`, :func:`rspiv.profiles.average_along_x`) take the vectors of one
field as fully correlated: a conservative choice. The errors of the row means themselves are
the scatter from pair to pair of each pair's own row mean (the vectors of a row decorrelate
along the wall over a few boundary-layer structures, so a wide frame averages several
independent ones). This script reads the field files of a processed campaign (``[output]
fields = true``) and gives, row by row, both errors of the mean ``U`` and of ``uu`` from the same
files:

- per vector, as the campaign's profile takes them: the standard deviation over the pairs of
  each vector, averaged along the row, over the square root of the pairs (``uu sqrt(2 / n)``
  for ``uu``);
- the pair-to-pair standard error of the row mean: the standard deviation over the pairs of
  each pair's row mean of ``u`` (of ``(u - U_x)^2``, ``U_x`` the vector's mean over the pairs,
  for ``uu``), over the square root of the pairs.

Their ratio is how much larger the profile's errors are than they need be (pairs of a
double-frame campaign are independent; for a time-resolved one both would need the same
correction for serial correlation). With few pairs the pair-to-pair errors are themselves
uncertain (about ``1 / sqrt(2 (n - 1))`` relative): the median over the rows tells.

With ``--openpiv``: OpenPIV's real ``test2`` instead (six pairs read from the ``openpiv``
package's installation, not vendored, each through ``rspiv.piv`` 64 -> 32 px with symmetric
deformation), the bound of the profile (``rspiv.profiles.profile_from_accumulator``) against
:class:`rspiv.row_errors.RowErrors` of the same fields.

With ``--campaigns N``: the ground truth of the errors themselves. N independent synthetic
campaigns (the demo's scene at scale 0.25, 24 pairs each, seeds 100 apart so that no pair is
shared, Method II) give N profiles of one flow; at 120 heights from y+ 30 to 0.9 of the
shortest profile, the spread of the N campaigns' U and uu (each in m/s of its own u_tau, from
its own wall), and of the skewness and flatness of u, against their mean error from pair to
pair (``eps_U_plus_pairs`` ..., ``eps_S_u_pairs`` ...) and against the bound (``eps_U_plus``
..., ``eps_S_u`` ...): 1 where the errors are right; and the spread of their u_tau against its
error from the pairs (the jackknife, ``u_tau_std_pairs``) and the fit's own (``u_tau_std``).

Run: ``python benches/profile_errors.py OUT [--run method_II]`` (``OUT`` a processed campaign's
output folder with field files), ``python benches/profile_errors.py --openpiv`` or ``python
benches/profile_errors.py --campaigns 12 [--dir DIR]``.
"""

from __future__ import annotations

import argparse
import pathlib
import warnings

import h5py
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=pathlib.Path, nargs="?", help="the campaign's output folder")
    ap.add_argument("--run", default="method_II")
    ap.add_argument("--openpiv", action="store_true", help="OpenPIV's real test2 instead")
    ap.add_argument("--campaigns", type=int, default=0, help="N independent campaigns instead")
    ap.add_argument("--dir", type=pathlib.Path, default=None, help="where the campaigns go")
    args = ap.parse_args()
    if args.openpiv:
        openpiv_test2()
        return
    if args.campaigns:
        campaigns(args.campaigns, args.dir)
        return
    if args.out is None:
        ap.error("give the campaign's output folder, or --openpiv")
    files = sorted((args.out / "fields" / args.run).glob("pair_*.nc"))
    if len(files) < 3:
        raise SystemExit(f"{args.out}: {len(files)} field files of run {args.run}: 3 or more")
    stack = []
    for path in files:
        with h5py.File(path, "r") as f:
            u = np.asarray(f["u"], dtype=np.float64)
            ok = np.asarray(f["valid"]).astype(bool) if "valid" in f else np.isfinite(u)
        stack.append(np.where(ok & np.isfinite(u), u, np.nan))
    s = np.array(stack)  # pairs, rows, columns
    n = s.shape[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rows without valid vectors
        ux = np.nanmean(s, axis=0)  # each vector's mean over the pairs
        sd = np.nanstd(s, axis=0, ddof=1)
        per_vector_u = np.nanmean(sd, axis=1) / np.sqrt(n)
        uu_row = np.nanmean(sd**2, axis=1)
        per_vector_uu = uu_row * np.sqrt(2.0 / n)
        row_u = np.nanmean(s, axis=2)  # each pair's row mean
        row_uu = np.nanmean((s - ux) ** 2, axis=2) * n / (n - 1)
        pair_u = np.nanstd(row_u, axis=0, ddof=1) / np.sqrt(n)
        pair_uu = np.nanstd(row_uu, axis=0, ddof=1) / np.sqrt(n)
    print(f"{args.out} run {args.run}: {n} pairs, {s.shape[1]} rows of {s.shape[2]} vectors")
    for name, a, b in (("U", per_vector_u, pair_u), ("uu", per_vector_uu, pair_uu)):
        r = a / b
        r = r[np.isfinite(r) & (b > 0)]
        q = np.percentile(r, [10, 50, 90])
        print(
            f"  {name}: per-vector error / pair-to-pair error of the row mean over {r.size} "
            f"rows: median {q[1]:.2f} (10-90 %: {q[0]:.2f}-{q[2]:.2f})"
        )


def campaigns(n: int, root: pathlib.Path | None) -> None:
    """The module docstring's ``--campaigns`` figures."""
    import dataclasses
    import re
    import tempfile

    from rspiv.campaign import Campaign
    from rspiv.demo import DEFAULT_SCENE, synth_campaign
    from rspiv.outputs import read_profile_csv

    root = root or pathlib.Path(tempfile.mkdtemp(prefix="rspiv_errors_"))
    prof = []
    for k in range(n):
        d = root / f"seed_{100 * (k + 1)}"
        if not (d / "out" / "profile_method_II.csv").is_file():
            d.mkdir(parents=True, exist_ok=True)
            scene = dataclasses.replace(
                DEFAULT_SCENE, scale=0.25, pairs=24, seed=100 * (k + 1), monte_carlo_samples=200
            )
            toml = synth_campaign(d, scene=scene)
            text = re.sub(r"(?m)^report = \w+", "report = false", toml.read_text())
            text = re.sub(r"(?m)^compare_uncorrected = \w+", "compare_uncorrected = false", text)
            toml.write_text(text)
            Campaign.load(toml, progress=False).run()
        c, meta = read_profile_csv(d / "out" / "profile_method_II.csv")
        ut, y0 = float(meta["u_tau"]), float(meta["y0"])
        prof.append({
            "u_tau": ut, "u_tau_std": float(meta["u_tau_std"]),
            "u_tau_std_pairs": float(meta.get("u_tau_std_pairs", "nan")),
            "y": c["y_m"] + y0, "lv": float(meta["nu"]) / ut,
            "U": c["U_plus"] * ut, "U_pairs": c["eps_U_plus_pairs"] * ut,
            "U_bound": c["eps_U_plus"] * ut, "uu": c["uu_plus"] * ut**2,
            "uu_pairs": c["eps_uu_plus_pairs"] * ut**2, "uu_bound": c["eps_uu_plus"] * ut**2,
            **{f"{m}{s}": c[f"{e}{m}{t}"] for m in ("S_u", "F_u")
               for s, e, t in (("", "", ""), ("_pairs", "eps_", "_pairs"), ("_bound", "eps_", ""))
               if f"eps_{m}_pairs" in c},
        })  # fmt: skip
    lv = float(np.mean([p["lv"] for p in prof]))
    yg = np.linspace(30 * lv, 0.9 * min(float(p["y"].max()) for p in prof), 120)
    print(f"{n} campaigns of 24 pairs, 120 heights from y+ 30 ({root})")
    ut = np.array([p["u_tau"] for p in prof])
    spread = ut.std(ddof=1)
    print(
        f"  u_tau: {ut.mean():.5f} m/s, the spread between the campaigns {spread:.5f} m/s; / "
        f"their error from the pairs (jackknife): median "
        f"{spread / np.median([p['u_tau_std_pairs'] for p in prof]):.2f}; / the fit's own: "
        f"median {spread / np.median([p['u_tau_std'] for p in prof]):.2f}"
    )
    for key in ("U", "uu", "S_u", "F_u"):
        if f"{key}_pairs" not in prof[0]:
            continue
        val, pairs, bound = (
            np.array([np.interp(yg, p["y"], p[f"{key}{s}"]) for p in prof])
            for s in ("", "_pairs", "_bound")
        )
        spread = val.std(axis=0, ddof=1)
        print(
            f"  {key}: the spread between the campaigns / their error from pair to pair: median "
            f"{np.median(spread / pairs.mean(axis=0)):.2f}; / the bound: median "
            f"{np.median(spread / bound.mean(axis=0)):.2f}"
        )


def openpiv_test2() -> None:
    """The module docstring's ``--openpiv`` figures."""
    import openpiv  # the bench extra
    from rspiv.io import read_image
    from rspiv.piv import piv
    from rspiv.profiles import pair_errors, profile_from_accumulator
    from rspiv.row_errors import RowErrors
    from rspiv.stats import FieldAccumulator

    data = pathlib.Path(openpiv.__file__).parent / "data" / "test2"
    acc = None
    for k in range(6):
        a = read_image(data / f"2image_{k}0.tif").astype(np.float32)
        b = read_image(data / f"2image_{k}1.tif").astype(np.float32)
        f = piv(a, b, passes=[(64, 64), (32, 32)], overlap=0.5, deformation="symmetric")
        u, v, ok = np.asarray(f.u), np.asarray(f.v), np.asarray(f.valid)
        if acc is None:
            acc = FieldAccumulator(u.shape)
            acc.rows = RowErrors(u.shape[0])
        acc.add(u, v, ok, pair_id=k)
        acc.rows.add(u, v, ok, pair_id=k)
    prof, pe = profile_from_accumulator(acc), pair_errors(acc)
    bound = {
        "U": np.sqrt(prof["uu"] / prof["n_eff"]["U"]),
        "uu": prof["uu"] * np.sqrt(2 / prof["n_eff"]["uu"]),
    }
    print(f"OpenPIV test2: 6 pairs, {acc.shape[0]} rows of {acc.shape[1]} vectors")
    for key, b in bound.items():
        r = b / pe[key]
        q = np.nanpercentile(r, [10, 50, 90])
        print(
            f"  {key}: the bound / the pairs' error: median {q[1]:.2f} (10-90 %: "
            f"{q[0]:.2f}-{q[2]:.2f})"
        )


if __name__ == "__main__":
    main()
