"""Particle tracking at the wall (rspiv.ptv, rspiv.ptv_profile, rspiv.campaign.ptv).

Ground truth: particle images rendered by the generator at known positions, moved by known
displacements (a boundary layer's mean profile plus per-particle fluctuations of known
variances and covariance); the DNS profile for the sublayer fit; a synthetic campaign whose
``u_tau`` is known.
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import re
from types import SimpleNamespace

import numpy as np
import pytest
from campaign_cases import lean
from rspiv import _rspiv
from rspiv.campaign import Campaign
from rspiv.campaign.ptv import _context, campaign_ptv, merge_ptv, report_section
from rspiv.cli import main as cli_main
from rspiv.demo import DEFAULT_SCENE, synth_campaign
from rspiv.errors import InvalidInputError
from rspiv.outputs import read_profile_csv
from rspiv.piv import piv
from rspiv.ptv import detect_particles, predictor_of, track_particles
from rspiv.ptv_profile import TrackProfile, WallLine, sublayer_fit
from rspiv.reference import load_dns
from rspiv.synth.tbl import TBLFlow
from scipy.spatial import cKDTree

H, W, WALL = 384, 768, 330.0
LPLUS, UT = 0.675, 1.0  # y+ per px, u_tau in px per pair
SU, SV, RUV = 0.3, 0.15, -0.4  # the fluctuations' rms (px) and correlation, tapered at the wall
FLOW = TBLFlow()


def _mean_u(h):
    return UT * FLOW.u_plus(np.maximum(h, 0) * LPLUS) * (h > 0)


def _taper(h):
    return np.minimum(np.maximum(h, 0) / 5.0, 1.0)


def _pair(seed, density=0.02, diameter=2.5, noise=0.05, reflection=0.5):
    """A pair above a wall at y = WALL with its reflection: each particle's displacement the
    mean profile at its midpoint plus its own fluctuation; returns the frames and the truth
    (A's positions, u, v)."""
    rng = np.random.default_rng(seed)
    n = rng.poisson(density * (W + 40) * (WALL + 20))
    xm, ym = rng.uniform(-20, W + 20, n), rng.uniform(-20, WALL, n)
    h = WALL - ym
    a, b = rng.normal(size=n), rng.normal(size=n)
    u = _mean_u(h) + SU * _taper(h) * a
    # V (away from the wall) is -v in the pixel frame
    v = -SV * _taper(h) * (RUV * a + np.sqrt(1 - RUV**2) * b)
    peak = 0.8 * 4095 * rng.uniform(0.6, 1.0, n)
    frames = []
    for s, k in ((-0.5, 1), (0.5, 2)):
        x, y, pk = xm + s * u, ym + s * v, peak
        if reflection:
            x, y, pk = np.r_[x, x], np.r_[y, 2 * WALL - y], np.r_[peak, reflection * peak]
        sigma = noise * 0.8 * 4095 * 0.8
        frames.append(
            _rspiv.render_particles(H, W, x, y, pk, np.array([diameter]), sigma, 4095, seed * 7 + k)
        )
    return frames, (xm - 0.5 * u, ym - 0.5 * v, u, v)


def _errors(tracks, truth):
    """Each track's displacement error against the particle it started from."""
    tree = cKDTree(np.c_[truth[0], truth[1]])
    _, i = tree.query(np.c_[tracks.x - 0.5 * tracks.u, tracks.y - 0.5 * tracks.v])
    return tracks.u - truth[2][i], tracks.v - truth[3][i]


def _field(a, b):
    return piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5, deformation="symmetric")


WALL_LINE = WallLine(WALL, 0.0, "above")


def test_particle_images_are_found_where_the_generator_put_them():
    rng = np.random.default_rng(4)
    # isolated particle images on a grid 10 px apart, jittered
    gx, gy = np.meshgrid(np.arange(10, 250, 10.0), np.arange(10, 150, 10.0))
    x = gx.ravel() + rng.uniform(-2, 2, gx.size)
    y = gy.ravel() + rng.uniform(-2, 2, gx.size)
    peak = rng.uniform(1500, 3000, x.size)
    frame = _rspiv.render_particles(160, 260, x, y, peak, np.array([2.5]), 40.0, 4095, 1)
    p = detect_particles(frame)
    assert len(p) == x.size
    d, _ = cKDTree(np.c_[x, y]).query(np.c_[p.x, p.y])
    assert np.sqrt(np.mean(d**2)) < 0.05
    # the diameter: the pixel-integrated image of 2.5 px reads about 2.7 px
    assert 2.4 < p.diameter < 3.0
    # a saturated frame: its particle images flagged
    clipped = np.minimum(frame, 1200).astype(np.uint16)
    q = detect_particles(clipped, full=1200)
    at_full = clipped[np.rint(q.y).astype(int), np.rint(q.x).astype(int)] >= 1200
    assert q.saturated.mean() > 0.5 and np.mean(q.saturated == at_full) > 0.97


def test_rows_are_searched_as_the_whole_frame_searches_them():
    """Rows of whole blocks searched on their own: with the threshold from the noise alone
    (``rel = 0``; the signal's share of it is the rows' own) the same particle images, bit for
    bit, as the whole frame's in those rows, in the whole frame's px; the rows a wall's band
    needs, flow above or below, and mapped from another frame."""
    (a, b), _ = _pair(5)
    whole = detect_particles(a, rel=0.0)
    part = detect_particles(a, rel=0.0, rows=(64, 192))
    assert part.y.min() >= 64 and part.y.max() <= 191
    sel = []
    for p in (whole, part):
        inner = (p.y >= 66) & (p.y <= 189)
        sel.append((inner, np.lexsort((p.x[inner], p.y[inner]))))
    (iw, ow), (ip, op) = sel
    assert iw.sum() > 300 and iw.sum() == ip.sum()
    for k in ("x", "height", "diameter_x", "sigma_y"):
        np.testing.assert_array_equal(getattr(whole, k)[iw][ow], getattr(part, k)[ip][op])
    # y: the rows' own centre plus their first row (to rounding)
    np.testing.assert_allclose(whole.y[iw][ow], part.y[ip][op], rtol=0, atol=1e-12)
    # the default threshold takes the rows' own signal: nearly the same images
    d = detect_particles(a, rows=(64, 192))
    assert abs(len(d) - len(part)) < 0.05 * len(part)
    # the rows of a band: 32 px into the flow, a margin of 10 px, in whole blocks of 32
    from rspiv.ptv import search_rows

    assert search_rows(WallLine(300.0), (1000, 500), 32.0, 10.0) == (256, 320)
    assert search_rows(WallLine(300.0, 0.0, "below"), (1000, 500), 32.0, 10.0) == (288, 352)
    assert search_rows(WallLine(300.0), (1000, 500), 32.0, 10.0, context_px=100.0) == (128, 320)
    # a sloping wall: its whole course across the width
    assert search_rows(WallLine(300.0, 0.05), (1000, 500), 32.0, 10.0) == (256, 352)
    # the wall in another frame, mapped 40 px down
    down = search_rows(WallLine(300.0), (1000, 500), 32.0, 10.0, to_frame=lambda p: p + [0, 40])
    assert down == (288, 352)
    assert search_rows(WallLine(990.0, 0.0, "below"), (1000, 500), 32.0, 10.0) == (960, 1000)
    with pytest.raises(InvalidInputError, match="outside the frame"):
        search_rows(WallLine(-200.0), (1000, 500), 32.0, 10.0)
    # tracks of the rows near the wall: those of the whole frames in the band, to a few
    f = _field(a, b)
    rows = search_rows(WALL_LINE, a.shape, 32.0, 12.0, context_px=64.0)
    assert rows == (192, 352)
    t_rows = track_particles(a, b, f, radius=1.5, wall=WALL_LINE, rows=rows)
    t_all = track_particles(a, b, f, radius=1.5, wall=WALL_LINE)
    assert t_rows.detected[0] < 0.5 * t_all.detected[0]
    in_band = [(WALL - t.y > 0) & (WALL - t.y < 32) for t in (t_rows, t_all)]
    n_rows, n_all = (int(k.sum()) for k in in_band)
    assert n_all > 300 and abs(n_rows - n_all) <= 0.02 * n_all
    assert abs(np.mean(t_rows.u[in_band[0]]) - np.mean(t_all.u[in_band[1]])) < 0.01
    with pytest.raises(InvalidInputError, match="rows"):
        detect_particles(a, rows=(10, 11))
    with pytest.raises(InvalidInputError, match="rows"):
        track_particles(whole, whole, (0.0, 0.0), rows=(0, 64))


def test_tracks_follow_their_particles():
    (a, b), truth = _pair(11)
    t = track_particles(a, b, _field(a, b), radius=1.5, wall=WALL_LINE)
    above = (WALL - t.y) > 3
    eu, ev = _errors(t, truth)
    wrong = (np.abs(eu) + np.abs(ev) > 0.5) & above
    assert wrong.sum() / above.sum() < 0.01, "merged images dropped: under 1 % wrong pairs"
    ok = above & ~wrong
    assert np.sqrt(np.mean(eu[ok] ** 2)) < 0.13 and np.sqrt(np.mean(ev[ok] ** 2)) < 0.13
    assert t.status["matched"] > 0.75 * t.detected[0]
    assert t.status["misshapen"] > 0 and not t.warnings
    assert 0 < t.stray_pairs < 0.02
    # a predictor that misses the flow by 5 px pairs almost nothing, and says so
    miss = track_particles(a, b, (-5.0, 0.0), radius=1.5)
    assert len(miss) < 0.25 * len(t) and any("paired" in w for w in miss.warnings)
    # a uniform predictor with a radius under the fluctuations: the edge is crowded, said
    flat = track_particles(a, b, lambda x, y: (_mean_u(WALL - y), 0 * y), radius=0.4)
    assert flat.edge_share > 0.05 and any("clips" in w for w in flat.warnings)


def test_a_fields_predictor_goes_to_zero_at_the_wall():
    x, y = np.meshgrid(np.arange(16.0, 200, 16), np.arange(4.0, 100, 4))
    field = type("F", (), {})()
    field.x, field.y, field.window = x, y, (32, 8)
    field.u, field.v = 3.0 + 0 * x, 0.5 + 0 * x
    wall = WallLine(90.0, 0.0, "above")
    fn = predictor_of(field, wall)
    # rows at y = 84 (h = 6 >= half the window) and beyond are used; nearer, scaled by h / 6
    u, v = fn(np.array([50.0, 50, 50, 50]), np.array([80.0, 87, 89, 91]))
    np.testing.assert_allclose(u, [3.0, 1.5, 0.5, 0.0])
    np.testing.assert_allclose(v, [0.5, 0.25, 0.5 / 6, 0.0])


@pytest.fixture(scope="module")
def near_wall_profile():
    """A profile of 16 pairs and every pair's tracks' errors against the generator."""
    prof = TrackProfile(WALL_LINE, bin_px=0.5, band_px=20.0)
    err = []
    for k in range(16):
        (a, b), truth = _pair(100 + k)
        t = track_particles(a, b, _field(a, b), radius=1.5, wall=WALL_LINE)
        prof.add(t)
        eu, ev = _errors(t, truth)
        keep = ((WALL - t.y) > 3) & (np.abs(eu) + np.abs(ev) < 0.5)
        err.append(np.c_[eu[keep], ev[keep]])
    return prof.result(), np.concatenate(err)


def test_the_binned_profile_is_the_planted_one(near_wall_profile):
    r, err = near_wall_profile
    h = r["h_px"]
    use = ~r["near_wall"] & np.isfinite(r["se_U"])
    assert use.sum() >= 30 and r["near_wall"][:4].all()
    # the mean profile within its standard errors, which are the scatter's
    z = (r["U"] - _mean_u(h))[use] / r["se_U"][use]
    assert np.all(np.abs(z) < 4) and 0.6 < z.std() < 1.6
    z = r["V"][use] / r["se_V"][use]
    assert np.all(np.abs(z) < 4)
    # the stresses: the planted ones plus the tracks' own error (measured against the truth)
    nu, nv = np.var(err[:, 0]), np.var(err[:, 1])
    assert 0.005 < nu < 0.02
    planted = {
        "uu": SU**2 * _taper(h) ** 2 + nu,
        "vv": SV**2 * _taper(h) ** 2 + nv,
        "uv": SU * SV * RUV * _taper(h) ** 2,
    }
    for k, want in planted.items():
        z = (r[k] - want)[use] / r[f"se_{k}"][use]
        assert abs(z.mean()) < 1.0 and z.std() < 2.0, k
        assert np.all(np.abs(z) < 4), k
    # each particle's fluctuation is its own, and the errors of two images 4 px or more apart
    # are independent: the two-track stresses are nil within their errors
    for k in ("uu", "vv", "uv"):
        z = r[f"{k}_two"][use] / r[f"se_{k}_two"][use]
        z = z[np.isfinite(z)]  # 16 pairs of 768 px: some bins hold too few pairs of tracks
        assert z.size >= 15 and abs(z.mean()) < 1.0 and np.all(np.abs(z) < 4), (k, z)
    # in the sublayer the mean changes by 0.34 px across a bin (0.0096 px^2 if it were taken
    # for a fluctuation, a third of uu there): within the errors
    sub = use & (h < 5)
    assert sub.sum() >= 4
    assert np.all(np.abs((r["uu"] - planted["uu"])[sub] / r["se_uu"][sub]) < 3)


def _correlated_tracks(rng, length_px, noise_px, pairs=80, n=3000, width=3000.0):
    """Tracks of ``pairs`` pairs within 6 px of a wall at y = 300 (flow above), whose
    fluctuations are Gaussian random fields along the wall of correlation ``exp(-s^2 / 2
    length^2)`` (random Fourier modes; u' 0.6 px, v' 0.15 px, their correlation -0.5 in the
    wall's frame), each position and displacement also with independent errors of ``noise_px``
    per component: the profiles of the tracks with and without those errors."""
    noisy, clean = (TrackProfile(WallLine(300.0), bin_px=0.5, band_px=6.0) for _ in range(2))

    def field(modes=200):
        k, ph = rng.normal(0, 1 / length_px, modes), rng.uniform(0, 2 * np.pi, modes)
        return lambda x: np.sqrt(2.0 / modes) * np.cos(np.outer(x, k) + ph).sum(1)

    for _ in range(pairs):
        x, h = rng.uniform(0, width, n), rng.uniform(0, 6, n)
        a, b = field()(x), field()(x)
        u = h + 0.6 * a
        v = -(0.02 * h + 0.15 * (0.5 * a + np.sqrt(0.75) * b))  # pixel frame: y towards the wall
        base = {"x": x, "y": 300 - h, "saturated": np.zeros(n, bool), "diameter": 2.5}
        clean.add(SimpleNamespace(u=u, v=v, **base))
        e = rng.normal(0, noise_px, (2, n))
        noisy.add(SimpleNamespace(u=u + e[0], v=v + e[1], **base))
    return noisy.result(), clean.result()


def test_two_track_stresses_leave_out_the_tracks_own_error():
    """Tracks of turbulence correlated along the wall (30 px), with errors of 0.1 px per
    component: the single-track stresses are the turbulence's plus 0.01 px^2 (vv: 17 standard
    errors too high), the two-track stresses those of the same tracks without their errors
    (measured: z-score means -0.04 to 0.12, spreads 0.35-0.66 against the tracks' own
    turbulence, whose sample they share), and their difference the error's variance (0.0102,
    0.0099, -0.0004 measured)."""
    noisy, clean = _correlated_tracks(np.random.default_rng(2), 30.0, 0.1)
    assert np.all(noisy["n_two"] > 20_000)
    for k in ("uu", "vv", "uv"):
        z = (noisy[f"{k}_two"] - clean[k]) / noisy[f"se_{k}_two"]
        assert abs(z.mean()) < 1.0 and np.all(np.abs(z) < 2.5), (k, z)
    vv_z = (noisy["vv"] - clean["vv"]) / noisy["se_vv"]
    assert vv_z.mean() > 10
    assert abs(np.median(noisy["vv"] - noisy["vv_two"]) - 0.01) < 0.0015
    assert abs(np.median(noisy["uu"] - noisy["uu_two"]) - 0.01) < 0.005
    assert abs(np.median(noisy["uv"] - noisy["uv_two"])) < 0.0015
    # said when the single-track stresses are mostly that error (OpenPIV's test1: 0.22 of
    # 0.29 px^2), not when it is a small part (the noisy tracks here: 0.01 of 0.032)
    from rspiv.campaign.ptv import _error_warning, _track_error

    cols = {**noisy, "near_wall": noisy["near_wall"].astype(float)}
    assert _error_warning(cols, _track_error(cols)) == ""
    said = _error_warning(cols, {"vv": 0.22, "se_vv": 0.014})
    assert "mostly tracking error" in said and "0.22" in said
    with pytest.raises(InvalidInputError, match="separation_px"):
        TrackProfile(WallLine(300.0), separation_px=(4.0, 24.0))
    with pytest.raises(InvalidInputError, match="separation_px"):
        TrackProfile(WallLine(300.0), separation_px=(4.0, 10.0, 8.0))


def test_the_standard_errors_count_pairs_not_tracks():
    # every track of a pair carries the pair's own offset: n tracks are one draw
    prof = TrackProfile(WallLine(100.0), bin_px=2.0, band_px=4.0)
    rng = np.random.default_rng(0)
    offsets = rng.normal(0, 0.5, 40)
    for off in offsets:
        n = 200
        t = type("T", (), {})()
        t.x, t.y = rng.uniform(0, 100, n), 100 - rng.uniform(0, 2, n)
        t.u, t.v = off + rng.normal(0, 0.05, n), np.zeros(n)
        t.saturated, t.diameter = np.zeros(n, bool), 2.5
        prof.add(t)
    r = prof.result()
    want = offsets.std(ddof=1) / np.sqrt(offsets.size)
    np.testing.assert_allclose(r["se_U"][0], want, rtol=0.05)
    assert r["se_U"][0] > 10 * 0.05 / np.sqrt(40 * 200)


def test_the_sublayer_fit_on_the_dns_profile():
    dns = load_dns()
    nu, scale, ut = 1.5e-5, 1e-5, 0.5  # y+ per px = scale ut / nu
    lplus = scale * ut / nu
    dt = 2.0 * scale / ut  # u_tau = 2 px per pair
    h = np.arange(0.25, 20, 0.5)
    U = 2.0 * np.interp(h * lplus, dns.y_plus, dns.u_plus)
    prof = {"h_px": h, "U": U, "se_U": np.full(h.size, 0.01), "near_wall": h < 2}
    lo, hi = 2.0 / lplus, 5.0 / lplus
    line = sublayer_fit(prof, hi, h_min_px=lo)
    assert -0.06 < line.gradient / (2.0 * lplus) - 1 < -0.04  # the curvature: 5 % low
    fit = sublayer_fit(prof, hi, h_min_px=lo, nu=nu, dt=dt, scale_m_per_px=scale)
    assert fit.curvature and abs(fit.gradient / (2.0 * lplus) - 1) < 2e-3
    assert abs(fit.wall_offset_px) < 0.01 and fit.y_plus_range[0] >= 2.0
    u, se = fit.u_tau(nu, dt)
    assert abs(u / ut - 1) < 1e-3 and se > 0
    with pytest.raises(InvalidInputError, match="at least 3"):
        sublayer_fit(prof, 1.0 / lplus)
    with pytest.raises(InvalidInputError, match="go together"):
        sublayer_fit(prof, hi, nu=nu)


def test_bad_input_is_refused():
    (a, b), _ = _pair(1)
    with pytest.raises(InvalidInputError, match="radius"):
        track_particles(a, b, (1.0, 0.0), radius=0)
    with pytest.raises(InvalidInputError, match="different shapes"):
        track_particles(a, b[:-1], (1.0, 0.0))
    with pytest.raises(InvalidInputError, match="predictor"):
        track_particles(a, b, "field")
    with pytest.raises(InvalidInputError, match="not finite"):
        track_particles(a, b, (np.nan, 0.0))
    with pytest.raises(InvalidInputError, match="line"):
        TrackProfile(object())
    with pytest.raises(InvalidInputError, match="flow_side"):
        track_particles(a, b, (1.0, 0.0), wall=WallLine(10.0, 0.0, "left"))
    with pytest.raises(InvalidInputError, match="band_px"):
        TrackProfile(WALL_LINE, bin_px=1.0, band_px=0.5)
    with pytest.raises(InvalidInputError, match="2D"):
        detect_particles(np.zeros(5))
    with pytest.raises(InvalidInputError, match="max_diameter"):
        track_particles(a, b, (1.0, 0.0), max_diameter=0.0)


def test_real_recording_tracks_agree_with_its_piv():
    """OpenPIV's real test1 pair (OpenPIV is in the test extra): the tracks against the PIV
    field they were predicted from."""
    import pathlib

    openpiv = pytest.importorskip("openpiv")
    from rspiv.io import read_image

    files = sorted((pathlib.Path(openpiv.__file__).parent / "data" / "test1").glob("exp1_001_*"))
    assert len(files) == 2
    a, b = (read_image(f) for f in files)
    field = piv(a, b, passes=[(64, 64), (32, 32)], overlap=0.5, deformation="symmetric")
    t = track_particles(a, b, field, radius=1.5)
    assert len(t) > 0.4 * t.detected[0]
    # a PIV vector is the mean displacement of its window's particle images: the tracks'
    # mean over each 32 px window (at least 10 of them) against it
    diff = []
    for j, i in zip(*np.nonzero(field.valid), strict=True):
        m = (np.abs(t.x - field.x[j, i]) < 16) & (np.abs(t.y - field.y[j, i]) < 16)
        if m.sum() >= 10:
            diff.append((t.u[m].mean() - field.u[j, i], t.v[m].mean() - field.v[j, i]))
    diff = np.array(diff)
    assert len(diff) > 400
    assert np.all(np.median(np.abs(diff), axis=0) < 0.12)
    assert np.all(np.abs(diff.mean(axis=0)) < 0.05)
    # a dense recording (0.036 images per px^2) whose partners are often lost (out of the
    # light sheet): the strays said
    assert t.stray_pairs > 0.05 and any("stray" in w for w in t.warnings)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("ptv")
    scene = dataclasses.replace(DEFAULT_SCENE, scale=0.15, pairs=4, monte_carlo_samples=200)
    toml = synth_campaign(d, scene=scene)
    toml.write_text(lean(toml.read_text(), fields=True, report=False, uncorrected=False))
    Campaign.load(toml, progress=False).run()
    return d, toml


def test_a_campaigns_wall_shear_from_its_tracks(campaign, capsys):
    d, toml = campaign
    truth = json.loads((d / "truth.json").read_text())
    assert cli_main(["ptv", str(toml), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "u_tau from the viscous sublayer" in printed
    out = d / "out"
    info = json.loads((out / "ptv_method_II.json").read_text())
    s = info["sublayer"]
    assert info["pairs"] == 4 and s["fitted"] and s["curvature"]
    assert abs(s["u_tau"] - truth["u_tau"]) < max(3 * s["se_u_tau"], 0.03 * truth["u_tau"])
    assert abs(s["wall_offset_px"]) < 1.0
    text = (out / "ptv_method_II.csv").read_text()
    assert "y_plus" in text and "U_plus" in text and "vv_two_plus" in text
    # the tracks' own error at most, from the two-track stresses: finite, with its error
    e = info["track_error_px2"]
    assert set(e) == {"uu", "se_uu", "vv", "se_vv"} and np.isfinite(e["vv"]) and e["se_vv"] > 0
    assert info["figure"] == str(out / "ptv_method_II.png")
    assert (out / "ptv_method_II.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "ptv_method_II.png" in printed and "rspiv process" not in printed  # no report
    # 4 pairs give the campaign's u_tau no error from its pairs; with one (0.004 m/s), the
    # difference is also said in both errors combined
    assert "difference_errors" not in s and "errors)" not in printed
    path = out / "summary.json"
    before = path.read_text()
    summ = json.loads(before)
    summ["runs"]["method_II"]["u_tau_std_pairs"] = 0.004
    try:
        path.write_text(json.dumps(summ))
        assert cli_main(["ptv", str(toml), "-q"]) == 0  # resumed: written again
        s2 = json.loads((out / "ptv_method_II.json").read_text())["sublayer"]
        want = (s2["u_tau"] - s2["campaign_u_tau"]) / np.hypot(s2["se_u_tau"], 0.004)
        assert s2["difference_errors"] == pytest.approx(want, rel=1e-12)
        assert f"{want:+.1f} errors)" in capsys.readouterr().out
    finally:
        path.write_text(before)
        assert cli_main(["ptv", str(toml), "-q"]) == 0
    # resumed from its state: the same answer, no pair tracked again
    st = pickle.loads((out / "ptv" / "method_II.pkl").read_bytes())
    assert st["done"] == [0, 1, 2, 3]
    again = campaign_ptv(Campaign.load(toml, progress=False))
    assert again["sublayer"]["u_tau"] == s["u_tau"] and again["seconds"] < 1.0
    # fewer pairs than the state holds, or other settings: afresh
    fewer = campaign_ptv(Campaign.load(toml, progress=False), max_pairs=2)
    assert fewer["pairs"] == 2
    other = campaign_ptv(Campaign.load(toml, progress=False), radius=1.5, max_pairs=2)
    assert other["pairs"] == 2 and other["settings"]["radius"] == 1.5


def test_a_campaign_without_what_tracking_needs_is_refused(campaign, tmp_path):
    d, toml = campaign
    camp = Campaign.load(toml, progress=False)
    with pytest.raises(InvalidInputError, match="runs are"):
        campaign_ptv(camp, "method_I")
    with pytest.raises(InvalidInputError, match="radius"):
        campaign_ptv(camp, radius=-1.0)
    # not processed
    bare = Campaign.load(toml, progress=False, out_dir=tmp_path / "none")
    with pytest.raises(InvalidInputError, match="process the campaign first"):
        campaign_ptv(bare)
    # processed without the field files the predictor comes from
    lean_out = tmp_path / "no_fields"
    lean_out.mkdir()
    for name in ("summary.json", "context.json"):
        (lean_out / name).write_bytes((d / "out" / name).read_bytes())
    with pytest.raises(InvalidInputError, match="fields = true"):
        campaign_ptv(Campaign.load(toml, progress=False, out_dir=lean_out))
    assert cli_main(["ptv", str(toml), "--run", "nope", "-q"]) == 2


def test_the_report_shows_the_tracks_of_the_fields_as_they_are(campaign, tmp_path):
    """The report's section: the run's wall shear from its tracks as the JSON holds it, the
    figure; a pass over other fields named, not shown; no pass, no section. The figure is also
    drawn in px where the profile has no wall units."""
    from rspiv.plots.ptv import plot_track_profile

    d, toml = campaign
    out = d / "out"
    if not (out / "ptv_method_II.json").is_file():
        assert cli_main(["ptv", str(toml), "-q"]) == 0
    camp = Campaign.load(toml, progress=False)
    ctx, _ = _context(camp)
    info = json.loads((out / "ptv_method_II.json").read_text())
    sec = report_section(camp, ctx)
    (row,) = sec.tables[0].data
    assert row["pairs"] == info["pairs"] and row["tracks"] == info["counts"]["tracks"]
    assert row["u_tau, sublayer (m/s)"] == info["sublayer"]["u_tau"]
    assert row["difference (%)"] == 100 * info["sublayer"]["difference"]
    assert sec.figures == [(info["figure"], "P3 + rotation, Method II: tracks at the wall")]
    assert "Not shown" not in sec.text
    # the pass was over other fields (the campaign processed again since): named, not shown
    other = tmp_path / "other"
    other.mkdir()
    for name in ("summary.json", "context.json"):
        (other / name).write_bytes((out / name).read_bytes())
    (other / "ptv_method_II.json").write_text(json.dumps({**info, "fingerprint": "x"}))
    stale = report_section(Campaign.load(toml, progress=False, out_dir=other), ctx)
    assert not stale.tables and not stale.figures
    assert "Not shown: ptv_method_II.json" in stale.text
    (other / "ptv_method_II.json").unlink()
    assert report_section(Campaign.load(toml, progress=False, out_dir=other), ctx) is None
    # px axes without wall units
    cols, _ = read_profile_csv(out / "ptv_method_II.csv")
    cols = {k: v for k, v in cols.items() if "plus" not in k}
    png = plot_track_profile(tmp_path / "px.png", cols, sublayer=info["sublayer"])
    assert png.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InvalidInputError, match="h_px"):
        plot_track_profile(tmp_path / "no.png", {**cols, "h_px": []})


def test_a_pass_in_shards_merges_to_the_whole(campaign, capsys):
    """Two shards (every other pair), each resumable on its own, merged: the profile of one
    pass to rounding; a merge refused while a shard is missing or unfinished, of other settings
    or fields, or shards of two counts lie side by side."""
    d, toml = campaign
    out = d / "out"
    whole = campaign_ptv(Campaign.load(toml, progress=False), resume=False)
    with pytest.raises(InvalidInputError, match="no shard"):
        merge_ptv(Campaign.load(toml, progress=False))
    assert cli_main(["ptv", str(toml), "--shard", "1/2", "-q"]) == 0
    assert "--merge" in capsys.readouterr().out
    with pytest.raises(InvalidInputError, match="shard 2 of 2 of run method_II is missing"):
        merge_ptv(Campaign.load(toml, progress=False))
    part = campaign_ptv(Campaign.load(toml, progress=False), shard=(2, 2))
    assert part["pairs"] == 2 and part["shard"] == "2/2"
    st = pickle.loads((out / "ptv" / "method_II.shard-2-of-2.pkl").read_bytes())
    assert st["complete"] and st["done"] == [1, 3]
    # the merge takes the shards' settings: one given to it is refused, not ignored
    assert cli_main(["ptv", str(toml), "--merge", "--max-pairs", "2", "-q"]) == 2
    assert "--max-pairs would not apply" in capsys.readouterr().err
    assert cli_main(["ptv", str(toml), "--merge", "-q"]) == 0
    merged = json.loads((out / "ptv_method_II.json").read_text())
    assert merged["pairs"] == whole["pairs"] == 4 and merged["counts"] == whole["counts"]
    for k in ("u_tau", "se_u_tau", "gradient", "wall_offset_px"):
        assert merged["sublayer"][k] == pytest.approx(whole["sublayer"][k], rel=1e-9, abs=1e-12)
    # a shard run with another radius, or written for other fields (the campaign processed
    # again since): refused, naming the file
    campaign_ptv(Campaign.load(toml, progress=False), shard=(2, 2), radius=3.0, resume=False)
    with pytest.raises(InvalidInputError, match=r"shard-2-of-2.pkl: settings .*'radius': 3.0"):
        merge_ptv(Campaign.load(toml, progress=False))
    (out / "ptv" / "method_II.shard-2-of-2.pkl").write_bytes(
        pickle.dumps({**st, "fingerprint": "0123456789abcdef"})
    )
    with pytest.raises(InvalidInputError, match="shard-2-of-2.pkl: written for other fields"):
        merge_ptv(Campaign.load(toml, progress=False))
    # shards whose pairs leave one out (shard 2 without pair 1), an unfinished shard, or
    # shards of two counts
    (out / "ptv" / "method_II.shard-2-of-2.pkl").write_bytes(
        pickle.dumps({**st, "ids": [3], "done": [3]})
    )
    with pytest.raises(InvalidInputError, match="took pairs 0, 2, not 0, 3 .*--max-pairs"):
        merge_ptv(Campaign.load(toml, progress=False))
    (out / "ptv" / "method_II.shard-2-of-2.pkl").write_bytes(
        pickle.dumps({**st, "complete": False, "done": [1]})
    )
    with pytest.raises(InvalidInputError, match="stopped after 1 of 2 pair"):
        merge_ptv(Campaign.load(toml, progress=False))
    (out / "ptv" / "method_II.shard-1-of-3.pkl").write_bytes(b"")
    with pytest.raises(InvalidInputError, match="shards of 2 and of 3"):
        merge_ptv(Campaign.load(toml, progress=False))
    assert cli_main(["ptv", str(toml), "--merge", "-q"]) == 2
    for p in (out / "ptv").glob("method_II.shard-*"):
        p.unlink()
    with pytest.raises(InvalidInputError, match="shard"):
        campaign_ptv(Campaign.load(toml, progress=False), shard=(3, 2))


def test_the_rows_near_the_wall_give_the_whole_frames_profile(campaign):
    """Searched only near the wall (the default) or over the whole frames: the same tracks in
    the band, to a few per cent per bin (the threshold's signal and the shape test's widths
    come from other rows), and the same profile well within its errors."""
    _, toml = campaign
    band = campaign_ptv(Campaign.load(toml, progress=False), resume=False)
    cb = read_profile_csv(band["csv"])[0]
    whole = campaign_ptv(Campaign.load(toml, progress=False), resume=False, whole_frame=True)
    cw = read_profile_csv(whole["csv"])[0]
    assert not band["settings"]["whole_frame"] and whole["settings"]["whole_frame"]
    # the rows searched hold a part of the frames' particle images (at this small scale the
    # band and its 256 px of flow are half the frame; at 47 MP a twelfth)
    assert band["counts"]["detected_a"] < 0.6 * whole["counts"]["detected_a"]
    ok = np.isfinite(cb["U"]) & np.isfinite(cw["U"])
    assert ok.sum() >= 60
    ratio = cb["n"][ok] / cw["n"][ok]
    assert 0.95 < ratio.min() and ratio.max() < 1.05 and abs(np.median(ratio) - 1) < 0.01
    for k in ("U", "V", "uu", "vv", "uv", "vv_two"):
        z = ((cb[k] - cw[k]) / cw[f"se_{k}"])[ok]
        assert np.nanmax(np.abs(z)) < 0.5, k
    sb, sw = band["sublayer"], whole["sublayer"]
    assert abs(sb["u_tau"] - sw["u_tau"]) < 0.05 * sw["se_u_tau"]


def test_the_campaign_file_asks_for_the_tracks(campaign, monkeypatch):
    """``[ptv] enabled``: ``rspiv process`` tracks the first run after its analysis with the
    section's settings and the report shows it; ``rspiv ptv`` takes its defaults from the same
    section; refused without the field files or with bins as high as the band; a pass that
    cannot track is said, and the campaign's outputs stand."""
    from rspiv.campaign import ptv as ptv_mod
    from rspiv.campaign_config import load_campaign_config

    d, toml = campaign
    text = toml.read_text()
    out = d / "out"
    try:
        on, n = re.subn(r"\[ptv\]\nenabled = false\nruns = \[\]\nradius = 2\.0\n",
                        "[ptv]\nenabled = true\nruns = []\nradius = 1.8\n", text)
        assert n == 1  # the campaign file the demo writes has the section, off
        toml.write_text(on)
        said: list[str] = []
        camp = Campaign.load(toml, progress=False, log=said.append)
        camp.run()  # every pair resumed: the analysis, then the tracks (then the report,
        # whose section test_the_report_shows_the_tracks_of_the_fields_as_they_are tests)
        info = json.loads((out / "ptv_method_II.json").read_text())
        assert info["settings"]["radius"] == 1.8 and info["pairs"] == 4
        assert any(m.startswith("ptv method_II: 4 pair(s)") for m in said)
        # rspiv ptv's defaults are the section's: the same settings, so the pass resumes
        assert cli_main(["ptv", str(toml), "-q"]) == 0
        again = json.loads((out / "ptv_method_II.json").read_text())
        assert again["settings"] == info["settings"] and again["seconds"] < 1.0
        # a pass that cannot track: said, nothing raised
        def refuse(*args, **kwargs):
            raise InvalidInputError("run method_II: summary.json holds no wall")

        # runs named: each tracked, one the campaign does not have said and left
        camp.config.ptv = dataclasses.replace(camp.config.ptv, runs=("method_I", "method_II"))
        said.clear()
        (info_b,) = ptv_mod.configured_ptv(camp)  # resumed from the pass above
        assert info_b["run"] == "method_II" and info_b["pairs"] == 4
        assert said[0].startswith("warning: [ptv]: no tracks at the wall: run 'method_I': ")
        monkeypatch.setattr(ptv_mod, "campaign_ptv", refuse)
        said.clear()
        camp.config.ptv = dataclasses.replace(camp.config.ptv, runs=())
        assert ptv_mod.configured_ptv(camp) == []
        assert said == ["warning: [ptv]: no tracks at the wall: run method_II: summary.json "
                        "holds no wall"]  # fmt: skip
    finally:
        toml.write_text(text)
    def parsed(fields: bool = True, **ptv):
        cfg = Campaign.load(toml, progress=False).config
        cfg.output.fields = fields
        cfg.ptv = dataclasses.replace(cfg.ptv, **ptv)
        return load_campaign_config(cfg.save(d / "c.toml"))

    assert parsed(enabled=True).ptv.enabled
    with pytest.raises(InvalidInputError, match=r"\[ptv\].enabled: needs each pair's fields"):
        parsed(False, enabled=True)
    with pytest.raises(InvalidInputError, match=r"\[ptv\].bin_px: must be under band_px"):
        parsed(bin_px=4.0, band_px=4.0)
    with pytest.raises(InvalidInputError, match=r"\[ptv\].radius"):
        parsed(radius=-1.0)
    assert parsed(runs=("uncorrected", "method_II")).ptv.runs == ("uncorrected", "method_II")
    with pytest.raises(InvalidInputError, match=r"\[ptv\].runs: expected a list of 'method_I'"):
        parsed(runs=("method_II", "method_II"))


def _tracks_in_time(rng, pairs, phi, n=400):
    """``pairs`` pairs of tracks within 4 px of a wall at y = 100 whose mean speed follows an
    AR(1) process from pair to pair (correlation ``phi``, 0.3 px rms) under independent track
    fluctuations of 0.5 px: the exact variance of the mean U over the pairs is known."""
    a = rng.normal(0, 0.3)
    for _ in range(pairs):
        t = SimpleNamespace(x=rng.uniform(0, 400, n), y=100 - rng.uniform(0, 4, n),
                            saturated=np.zeros(n, bool), diameter=2.5)  # fmt: skip
        t.u, t.v = 2.0 + a + rng.normal(0, 0.5, n), rng.normal(0, 0.2, n)
        yield t
        a = phi * a + np.sqrt(1 - phi * phi) * rng.normal(0, 0.3)


def test_tracks_of_pairs_that_follow_each_other_take_their_serial_correlation():
    """The tracks' bins, like the PIV profile's rows (tests/test_row_serial.py): pairs whose
    mean speed is correlated at 0.8 from pair to pair (a factor of 8.6 on the variance of U
    over 600 pairs) get it within 15 %, and errors whose z scores against the true mean
    spread by 1 over the bins; independent pairs a factor near 1; given ids or not, the same;
    a pickled profile from before the lags gives none; merged parts keep their own chains."""
    rng = np.random.default_rng(4)
    prof = TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0)
    for k, t in enumerate(_tracks_in_time(rng, 600, 0.8)):
        prof.add(t, pair_id=k)
    r = prof.result()
    lag = np.arange(600)
    c = 0.09 * 0.8**lag
    c[0] += 0.25 / 50  # a bin's 50 tracks' own fluctuations
    exact = (600 * c[0] + 2 * np.sum((600 - lag[1:]) * c[1:])) / 600**2
    se_indep = r["se_U"] / np.sqrt(r["serial_U"])
    factor = exact / np.median(se_indep) ** 2  # the bins' U share the pair's mean: 8.6
    assert 8 < factor < 9.5 and abs(np.median(r["serial_U"]) / factor - 1) < 0.15
    assert not r["open_U"].any() and np.median(r["serial_V"]) < 1.2
    # all bins share the pair's mean, so their z scores are one draw: against the exact error
    assert abs(np.median(r["se_U"]) / np.sqrt(exact) - 1) < 0.1
    indep = TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0)
    same = TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0)
    for k, t in enumerate(_tracks_in_time(np.random.default_rng(5), 200, 0.0)):
        indep.add(t, pair_id=k)
        same.add(t)
    ri = indep.result()
    assert np.median(ri["serial_U"]) < 1.1 and not ri["open_U"].any()
    before = indep.total.copy()
    with pytest.raises(InvalidInputError, match="pair_id: expected an integer id, got 'p7'"):
        indep.add(t, pair_id="p7")
    np.testing.assert_array_equal(indep.total, before)  # refused before anything was added
    np.testing.assert_array_equal(same.result()["se_U"], ri["se_U"])
    old = pickle.loads(pickle.dumps(indep))
    del old.__dict__["lags"], old.__dict__["recent"]
    old = pickle.loads(pickle.dumps(old))
    assert old.lags is None and "serial_U" not in old.result()
    a, b = (TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0) for _ in range(2))
    for k, t in enumerate(_tracks_in_time(np.random.default_rng(6), 60, 0.8)):
        (a if k < 30 else b).add(t, pair_id=k)
    lags = a.lags + b.lags
    a.merge(b)
    np.testing.assert_array_equal(a.lags, lags)
    assert a.recent == []


def test_a_short_time_resolved_ptv_pass_is_said():
    """40 pairs correlated at 0.95: the bins' factor is a lower bound and the pass says so in
    its profile warning, beside its other warning; independent pairs say nothing."""
    from rspiv.campaign.ptv import _serial

    prof = TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0)
    for k, t in enumerate(_tracks_in_time(np.random.default_rng(7), 40, 0.95)):
        prof.add(t, pair_id=k)
    got = _serial(prof.result(), 40)
    assert got["serial_open"] > 0.5 and "lower bounds" in got["serial_warning"]
    indep = TrackProfile(WallLine(100.0), bin_px=0.5, band_px=4.0)
    for k, t in enumerate(_tracks_in_time(np.random.default_rng(7), 40, 0.0)):
        indep.add(t, pair_id=k)
    got = _serial(indep.result(), 40)
    assert "serial_warning" not in got and got["serial_factor_U"] < 1.3
