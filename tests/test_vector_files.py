"""Vector fields of other PIV tools read into rspiv's pixel frame (:mod:`rspiv.vector_files`).

Ground truth: files written by the tools' own writers where we have them (OpenPIV's
``tools.save`` and ``transform_coordinates``, LaVision's lvpyio for ``.vc7``), or in the layout
their code writes (PIVlab's MAT exports), from arrays we chose; each reads back to those arrays
at the positions of the windows they describe, in rspiv's conventions. Real files (pivpy's
samples, BSD 3-clause, ``tests/data/real``): an OpenPIV result of OpenPIV's ``exp1_001`` pair
and a PIVlab-structured v7.3 session.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import scipy.io
from rspiv.errors import InvalidInputError
from rspiv.vector_files import read_vectors

REAL = pathlib.Path(__file__).parent / "data" / "real"
NY, NX = 7, 9


def _grid(step=16, w=32):
    """A regular grid of windows w px wide every ``step`` px, as rspiv places them (first
    window from pixel 0: centre (w - 1) / 2)."""
    xs = (w - 1) / 2 + step * np.arange(NX)
    ys = (w - 1) / 2 + step * np.arange(NY)
    return np.meshgrid(xs, ys)


def _values():
    x, y = _grid()
    return 2.0 + 0.01 * x - 0.02 * y, -1.0 + 0.005 * x * 1.0 + 0.03 * y


def test_openpiv_save_reads_back_at_rspivs_positions(tmp_path):
    tools = pytest.importorskip("openpiv.tools", reason="OpenPIV is in the test extra")
    pyprocess = pytest.importorskip("openpiv.pyprocess", reason="OpenPIV is in the test extra")
    shape = (32 + 16 * (NY - 1), 32 + 16 * (NX - 1))
    x, y = pyprocess.get_coordinates(shape, search_area_size=32, overlap=16)
    u, v = _values()
    flags = np.zeros(u.shape, dtype=int)
    flags[2, 3] = 1
    flags[4, 5] = 2
    mask = np.zeros(u.shape, dtype=int)
    mask[6, 8] = 1
    tools.save(tmp_path / "raw.txt", x, y, u, v, flags, mask, fmt="%.9e")
    r = read_vectors(tmp_path / "raw.txt")
    gx, gy = _grid()
    assert r.tool == "OpenPIV"
    np.testing.assert_array_equal(r.x, gx)  # OpenPIV's 16 is rspiv's 15.5
    np.testing.assert_array_equal(r.y, gy)
    np.testing.assert_allclose(r.u[~np.isnan(r.u)], u[mask == 0], rtol=1e-8)
    np.testing.assert_allclose(r.v[~np.isnan(r.v)], v[mask == 0], rtol=1e-8)
    assert not r.valid[2, 3] and not r.postprocessed[2, 3]
    assert r.postprocessed[4, 5] and not r.valid[4, 5]
    assert np.isnan(r.u[6, 8]) and not r.valid[6, 8]
    assert r.valid.sum() == NX * NY - 3
    # OpenPIV's windef pipeline saves after transform_coordinates: y and v upward
    xt, yt, ut, vt = tools.transform_coordinates(x, y, u, v)
    tools.save(tmp_path / "up.txt", xt, yt, ut, vt, flags, mask, fmt="%.9e")
    up = read_vectors(tmp_path / "up.txt", y_up=True)
    np.testing.assert_array_equal(up.y, gy)
    np.testing.assert_allclose(up.v, r.v, rtol=1e-8)
    np.testing.assert_array_equal(up.valid, r.valid)
    assert any("upward" in n for n in up.notes)
    # scaled: mm and mm/s undone with scale and dt
    tools.save(tmp_path / "mm.txt", x * 0.05, y * 0.05, u * 0.05 / 1e-3, v * 0.05 / 1e-3,
               flags, mask, fmt="%.12e")  # fmt: skip
    mm = read_vectors(tmp_path / "mm.txt", scale=0.05, dt=1e-3)
    np.testing.assert_allclose(mm.x, gx, atol=1e-9)
    np.testing.assert_allclose(mm.u, r.u, rtol=1e-8)
    # OpenPIV's own format (%.4e: 5 digits) of mm at 1/34.5 mm per px, far from the origin:
    # nodes up to 0.09 px off their grid in the file, put back on it (a fit) and said
    k = 1 / 34.5345
    tools.save(tmp_path / "e4.txt", (x + 3000) * k, (y + 2000) * k, u * k / 1e-3, v * k / 1e-3,
               flags, mask)  # fmt: skip
    e4 = read_vectors(tmp_path / "e4.txt", scale=k, dt=1e-3)
    np.testing.assert_allclose(e4.x, gx + 3000, atol=0.05)
    np.testing.assert_allclose(e4.y, gy + 2000, atol=0.05)
    assert np.ptp(np.diff(e4.x, axis=1)) < 1e-9 and np.ptp(np.diff(e4.y, axis=0)) < 1e-9
    assert any("off a regular grid (the file's rounding)" in n for n in e4.notes)
    np.testing.assert_allclose(e4.u, r.u, rtol=1e-4)


def test_openpiv_five_columns_flags_or_signal_to_noise(tmp_path):
    x, y = _grid()
    u, v = _values()
    rows = np.column_stack([(x + 0.5).ravel(), (y + 0.5).ravel(), u.ravel(), v.ravel()])
    s2n = np.linspace(1.5, 9.0, rows.shape[0])
    np.savetxt(tmp_path / "s2n.txt", np.column_stack([rows, s2n]))
    r = read_vectors(tmp_path / "s2n.txt")
    np.testing.assert_allclose(r.peak_ratio.ravel(), s2n)
    assert r.valid.all()
    flags = np.zeros(rows.shape[0])
    flags[5] = 1
    np.savetxt(tmp_path / "flags.txt", np.column_stack([rows, flags]))
    f = read_vectors(tmp_path / "flags.txt")
    assert f.peak_ratio is None and f.valid.sum() == NX * NY - 1
    # shuffled rows are placed by their positions
    perm = np.random.default_rng(1).permutation(rows.shape[0])
    np.savetxt(tmp_path / "shuffled.txt", np.column_stack([rows, s2n])[perm])
    np.testing.assert_array_equal(read_vectors(tmp_path / "shuffled.txt").u, r.u)


def _vc7(path, u, v, *, choice=None, enabled=None, extra=None, grid=16, three_c=False):
    lv = pytest.importorskip("lvpyio", reason="the DaVis tests need lvpyio (rspiv[davis])")
    from lvpyio.types.buffer import Buffer
    from lvpyio.types.component import Component, Components
    from lvpyio.types.frame import VectorFrame

    vel = lv.Scale(0.25, 0.0, "m/s", "velocity")
    counts = lv.Scale(1.0, 0.0, "counts", "")
    comps = Components()
    for k in range(4):
        comps[f"U{k}"] = Component(vel, [(u + 10 * k).astype(np.float32)])
        comps[f"V{k}"] = Component(vel, [(v - 10 * k).astype(np.float32)])
        if three_c:
            comps[f"W{k}"] = Component(vel, [np.zeros_like(u, dtype=np.float32)])
    shape = u.shape
    comps["ACTIVE_CHOICE"] = Component(
        counts, [np.zeros(shape, np.int32) if choice is None else choice.astype(np.int32)]
    )
    comps["ENABLED"] = Component(
        counts, [np.ones(shape, np.uint8) if enabled is None else enabled.astype(np.uint8)]
    )
    for name, arr in (extra or {}).items():
        comps[name] = Component(vel if "Uncert" in name else lv.Scale(), [arr.astype(np.float32)])
    scales = lv.Scales(
        lv.Scale(0.05, -10.0, "mm", "position"), lv.Scale(-0.05, 20.0, "mm", "position"),
        lv.Scale(1.0, 0.0, "pixel", ""), vel,
    )  # fmt: skip
    frame = VectorFrame(comps, scales, {"InterrogationWindowSize": "32"}, lv.Grid(grid, grid, 1), 4)
    lv.write_buffer(Buffer([frame], {}), str(path))
    return path


def test_davis_vc7_reads_the_active_choice_at_lvpyios_positions(tmp_path):
    u, v = _values()
    choice = np.zeros(u.shape, int)
    choice[1, 2] = 1  # second peak: valid
    choice[2, 3] = 4  # filled by DaVis
    enabled = np.ones(u.shape, int)
    enabled[0, 0] = 0
    sig = np.full(u.shape, 0.2)
    sig[3, 3] = 0.0  # DaVis' "no estimate"
    peak = np.full(u.shape, 4.0)
    path = _vc7(tmp_path / "B00001.vc7", u, v, choice=choice, enabled=enabled,
                extra={"TS:Uncertainty Vx": sig, "TS:Uncertainty Vy": 2 * sig,
                       "TS:Peak ratio": peak})  # fmt: skip
    r = read_vectors(path)
    assert r.tool == "DaVis" and r.window == (32, 32)
    # vector i at (i + 1/2) * grid from the image's edge: (i + 1/2) * 16 - 1/2 in rspiv's frame
    np.testing.assert_array_equal(r.x[0], 7.5 + 16 * np.arange(NX))
    np.testing.assert_array_equal(r.y[:, 0], 7.5 + 16 * np.arange(NY))
    assert r.dt == pytest.approx(0.05e-3 / 0.25) and r.mm_per_px == pytest.approx(0.05)
    assert r.u[1, 2] == pytest.approx(u[1, 2] + 10, abs=1e-5)  # choice 1 from U1
    assert r.u[2, 3] == pytest.approx(u[2, 3] + 30, abs=1e-5)  # choice 4 from the last, U3
    assert r.valid[1, 2] and r.postprocessed[2, 3] and not r.valid[2, 3]
    assert np.isnan(r.u[0, 0]) and not r.valid[0, 0]
    keep = np.ones(u.shape, bool)
    keep[[0, 1, 2], [0, 2, 3]] = False
    np.testing.assert_allclose(r.u[keep], u[keep], atol=1e-5)
    np.testing.assert_allclose(r.v[keep], v[keep], atol=1e-5)
    assert np.isnan(r.sigma_u[3, 3]) and r.sigma_u[4, 4] == pytest.approx(0.2)
    assert r.sigma_v[4, 4] == pytest.approx(0.4) and r.peak_ratio[4, 4] == 4.0
    assert "DaVis field B00001.vc7: 9 x 7 vectors every 16 x 16 px" in r.describe()
    every = _vc7(tmp_path / "smooth.vc7", u, v, choice=np.full(u.shape, 5), three_c=True)
    s = read_vectors(every)
    assert not s.valid.any() and s.postprocessed.all()
    assert any("3C" in n for n in s.notes) and any("no raw vector" in n for n in s.notes)


def _pivlab_gui(path, u, v, *, tv=None, tvf=None, calv=1.0, calxy=1.0):
    x, y = _grid()
    cell = np.empty((1, 1), dtype=object)

    def c(a):
        out = cell.copy()
        out[0, 0] = a
        return out

    scipy.io.savemat(path, {
        "x": c(x + 1.5), "y": c(y + 1.5), "u_original": c(u), "v_original": c(v * calv),
        "typevector_original": c(np.ones(u.shape) if tv is None else tv),
        "u_filtered": c(u), "v_filtered": c(v * calv),
        "typevector_filtered": c(np.ones(u.shape) if tvf is None else tvf),
        "calxy": calxy, "calu": 1.0, "calv": calv,
    })  # fmt: skip
    return path


def test_pivlab_exports_read_at_the_windows_centres(tmp_path):
    u, v = _values()
    tv = np.ones(u.shape)
    tv[0, 1] = 0  # masked
    tvf = tv.copy()
    tvf[3, 4] = 2  # interpolated by the post-processing
    tvf[5, 5] = 3  # second peak, valid
    r = read_vectors(_pivlab_gui(tmp_path / "gui.mat", u, v, tv=tv, tvf=tvf, calv=-1.0))
    gx, gy = _grid()
    np.testing.assert_array_equal(r.x, gx)  # PIVlab's 17 (1-based, i + w/2) is rspiv's 15.5
    np.testing.assert_array_equal(r.y, gy)
    ok = tv != 0
    np.testing.assert_allclose(r.v[ok], v[ok])  # calv = -1 turned back
    assert np.isnan(r.u[0, 1]) and r.postprocessed[3, 4] and not r.valid[3, 4]
    assert r.valid[5, 5] and r.valid.sum() == NX * NY - 2
    # PIVlab_commandline's variables
    cmd = {"x": gx + 1.5, "y": gy + 1.5, "u": u, "v": v, "typevector": tv, "u_filt": u,
           "v_filt": v, "typevector_filt": tvf}  # fmt: skip
    cells = {}
    for k, a in cmd.items():
        cells[k] = np.empty((2, 1), dtype=object)
        cells[k][0, 0] = a
        cells[k][1, 0] = a + (1.0 if k in ("u", "v") else 0.0)
    scipy.io.savemat(tmp_path / "cmd.mat", cells)
    second = read_vectors(tmp_path / "cmd.mat", frame=1)
    np.testing.assert_allclose(second.u[ok], u[ok] + 1.0)
    np.testing.assert_array_equal(second.valid, r.valid)
    with pytest.raises(InvalidInputError, match="frame 2 out of range"):
        read_vectors(tmp_path / "cmd.mat", frame=2)


def test_a_calibrated_pivlab_export_is_read_back_in_px_up_to_its_offset(tmp_path):
    """A PIVlab export calibrated as PIVlab does it (``calibrate.compute_calibration`` and
    ``apply_xy``: x right, y up, offsets set; ``mat_file_save``: ``u * calu``): u and v are the
    px of the uncalibrated export, the spacing exact, the positions the recording's px plus a
    constant (the offset and the frame's height are not in the file); what needs the
    recording's px refuses it."""
    from rspiv import compare_fields, vector_statistics

    u, v = _values()
    gx, gy = _grid()
    px, py = gx + 1.5, gy + 1.5  # PIVlab's positions in px (1-based, i + w/2)
    calxy, dt, height = 2.5e-5, 1e-3, 1024  # m/px, s, px
    calu, calv = calxy / dt, -calxy / dt  # y increases upward: calv negative
    cell = np.empty((1, 1), dtype=object)

    def c(a):
        out = cell.copy()
        out[0, 0] = a
        return out

    def export(path, cu, cv, units, **extra):
        scipy.io.savemat(path, {
            "x": c(px * calxy - 0.0123), "y": c((height - py) * calxy - 0.0071),
            "u_original": c(u * cu), "v_original": c(v * cv), "typevector_original": c(
                np.ones(u.shape)), "calxy": calxy, "calu": cu, "calv": cv, "units": units,
            **extra,
        })  # fmt: skip
        return path

    r = read_vectors(export(tmp_path / "cal.mat", calu, calv, "[m] respectively [m/s]"))
    np.testing.assert_allclose(r.u, u, rtol=1e-12)
    np.testing.assert_allclose(r.v, v, rtol=1e-12)  # down the image, as in px
    dx, dy = r.x - gx, r.y - gy
    np.testing.assert_allclose(dx, dx[0, 0], atol=1e-9)  # the recording's px up to a constant
    np.testing.assert_allclose(dy, dy[0, 0], atol=1e-9)
    assert r.spacing == pytest.approx((16.0, 16.0), abs=1e-9)
    assert r.dt == pytest.approx(dt, rel=1e-12) and r.mm_per_px == pytest.approx(0.025)
    assert not r.origin_known and any("calibrated export" in n for n in r.notes)
    # displacements only (PIVlab's time step 0): calu = calxy, no pulse separation
    d = read_vectors(export(tmp_path / "d.mat", calxy, -calxy, "[m] respectively [m/frame]"))
    np.testing.assert_allclose(d.u, u, rtol=1e-12)
    assert np.isnan(d.dt) and d.mm_per_px == pytest.approx(0.025)
    # the unknown origin survives rspiv's own file of it
    r.to_xarray().to_netcdf(tmp_path / "r.nc", engine="h5netcdf")
    assert not read_vectors(tmp_path / "r.nc").origin_known
    # refused: what needs the recording's px, an older PIVlab's calibration, a mixed one
    with pytest.raises(InvalidInputError, match="up to its calibration's offset"):
        compare_fields(r, read_vectors(_pivlab_gui(tmp_path / "px.mat", u, v)))
    with pytest.raises(InvalidInputError, match="wall_y in px needs them"):
        vector_statistics([str(tmp_path / "cal.mat")], nu=1e-6, wall="bottom", wall_y=100.0)
    with pytest.raises(InvalidInputError, match="older PIVlab"):
        scipy.io.savemat(tmp_path / "old.mat", {"x": c(px), "y": c(py), "u": c(u), "v": c(v),
                                                 "calxy": calxy, "caluv": calu})  # fmt: skip
        read_vectors(tmp_path / "old.mat")
    with pytest.raises(InvalidInputError, match="cannot undo"):
        read_vectors(export(tmp_path / "mixed.mat", calu, 2 * calv, "[m] respectively [m/s]"))
    # a session (resultslist) holds px whatever its calibration, which gives dt and the scale
    session = np.empty((5, 1), dtype=object)
    for k, a in enumerate((px, py, u, v, np.ones(u.shape))):
        session[k, 0] = a
    scipy.io.savemat(tmp_path / "session.mat", {"resultslist": session, "calxy": calxy,
                                                "calu": calu, "calv": calv})  # fmt: skip
    sr = read_vectors(tmp_path / "session.mat")
    np.testing.assert_array_equal(sr.u, u)
    np.testing.assert_array_equal(sr.v, v)
    np.testing.assert_array_equal(sr.x, gx)
    assert sr.origin_known and sr.dt == pytest.approx(dt) and sr.mm_per_px == pytest.approx(0.025)
    # a v7.3 file's units are UTF-16 codes (h5py reads MATLAB's char as uint16)
    from rspiv.vector_files import _pivlab_units

    codes = np.array([ord(ch) for ch in "[m] respectively [m/frame]"], np.uint16)[:, None]
    got = _pivlab_units(tmp_path / "h.mat", {"calxy": np.array([[calxy]]), "calu": np.array(
        [[calu]]), "calv": np.array([[calv]]), "units": codes})  # fmt: skip
    assert np.isnan(got["dt"]) and got["calxy"] == calxy


def test_real_files_of_openpiv_and_a_pivlab_session():
    op = read_vectors(REAL / "pivpy_openpiv_exp1_001_b.txt")
    assert op.u.shape == (22, 30) and op.valid.all()
    assert op.x[0, 0] == 15.5 and op.spacing == (16.0, 16.0)
    assert op.u[0, 1] == pytest.approx(-0.2141) and op.v[0, 1] == pytest.approx(5.3176)
    assert op.peak_ratio[0, 0] == pytest.approx(51.1181)
    # a v7.3 (HDF5) session: resultslist rows x, y, u, v, typevector by pair; empty cells
    s = read_vectors(REAL / "pivpy_pivlab_session.mat")
    assert s.u.shape == (8, 10) and s.spacing == (3.0, 3.0) and s.x[0, 0] == 2.5
    assert np.isnan(s.u[0, 0]) and not s.valid[0, 0] and s.valid.sum() == 79
    assert s.u[0, 1] == pytest.approx(0.88998443)
    assert read_vectors(REAL / "pivpy_pivlab_session.mat", frame=1).u[0, 1] == pytest.approx(
        3.31806829
    )


def test_insight_vec_in_mm_and_in_pixels(tmp_path):
    """TSI Insight's ``.vec`` (``rspiv.insight``): y up from the header's origin, positions
    half a pixel past the windows' centres, m/s over the header's pulse separation, and the
    choice code: 1-3 valid, 4 filled, 0 and below not counted."""
    from rspiv.compare import compare_fields
    from vector_series_cases import write_insight

    gx, gy = _grid()
    u, v = _values()
    chc = np.ones(u.shape, dtype=int)
    chc[1, 2], chc[2, 3], chc[3, 4], chc[4, 5], chc[5, 6], chc[6, 8] = 2, 3, 4, -1, 0, -3
    mm = read_vectors(
        write_insight(tmp_path / "mm.vec", gx, gy, u, v, chc, mm_per_px=0.01953, dt=2e-3)
    )
    assert mm.tool == "Insight" and mm.frame == "image" and mm.notes == ()
    assert mm.dt == pytest.approx(2e-3, rel=1e-12) and mm.mm_per_px == pytest.approx(0.01953)
    np.testing.assert_allclose(mm.x, gx, atol=1e-6)  # 9 decimals of a mm
    np.testing.assert_allclose(mm.y, gy, atol=1e-6)
    counted = chc >= 1
    np.testing.assert_allclose(mm.u[counted], u[counted], rtol=1e-6)
    np.testing.assert_allclose(mm.v[counted], v[counted], rtol=1e-6)
    np.testing.assert_array_equal(mm.valid, (chc >= 1) & (chc <= 3))
    np.testing.assert_array_equal(mm.postprocessed, chc == 4)
    assert np.isnan(mm.u[~counted]).all() and np.isnan(mm.v[~counted]).all()
    # Insight's own 6 decimals of a mm at a 47 MP camera's scale: the nodes still on the grid
    # (1e-5 px off before rounding: unequal rows to find_wall's 1e-6)
    six = read_vectors(
        write_insight(tmp_path / "six.vec", gx + 1000.0, gy + 500.0, u, v, chc,
                      mm_per_px=1 / 34.5345, dt=2e-3, fmt="%.6f")  # fmt: skip
    )
    # to the file's precision: the header's pixel size has 8 digits (1e-5 px at 1100 px)
    np.testing.assert_allclose(six.x, gx + 1000.0, rtol=0, atol=2e-5)
    np.testing.assert_allclose(six.y, gy + 500.0, rtol=0, atol=2e-5)
    assert np.ptp(np.diff(six.x, axis=1)) < 1e-9 and np.ptp(np.diff(six.y, axis=0)) < 1e-9
    assert six.notes == ()  # 1e-5 px: not worth a word
    np.testing.assert_allclose(six.u[counted], u[counted], atol=1e-4)  # 6 decimals of m/s
    # pixel units, the origin at the bottom row as Insight writes it, images it dewarped
    h = 160
    px = read_vectors(
        write_insight(tmp_path / "px.vec", gx, gy, u, v, chc, origin=(0.0, h - 1.0),
                      dewarped="1", fmt="%.6f")  # fmt: skip
    )
    np.testing.assert_array_equal(px.x, gx)
    np.testing.assert_array_equal(px.y, gy)
    np.testing.assert_allclose(px.u, mm.u, atol=1e-6)
    np.testing.assert_array_equal(px.valid, mm.valid)
    assert px.frame == "object" and np.isnan(px.dt) and np.isnan(px.mm_per_px)
    # the same field as OpenPIV writes it: no difference, no offset
    rows = np.column_stack([(gx + 0.5).ravel(), (gy + 0.5).ravel(), u.ravel(), v.ravel()])
    np.savetxt(tmp_path / "op.txt", rows, fmt="%.9f")
    c = compare_fields(read_vectors(tmp_path / "op.txt"), mm)
    assert c.n_compared == int(mm.valid.sum()) and c.rms < 1e-5
    assert abs(c.bias_u) < 1e-6 and abs(c.bias_v) < 1e-6 and c.warning == ""
    # an OpenPIV .vec file (numbers from the first line) is still OpenPIV's
    np.savetxt(tmp_path / "op.vec", rows)
    assert read_vectors(tmp_path / "op.vec").tool == "OpenPIV"


def test_real_insight_file():
    """pivpy's TSI Insight sample (BSD 3-clause, tests/data/real): a cavity flow in pixel units,
    y up from OriginInImageY 2671, dt 55 ms; choice codes 1 (1500) and -1 (263)."""
    r = read_vectors(REAL / "pivpy_insight_day2a005000.vec")
    assert r.tool == "Insight" and r.u.shape == (43, 41) and r.spacing == (32.0, 32.0)
    assert r.x[0, 0] == 1538.5 and r.y[0, 0] == 2671 - 1546 - 0.5  # its first line's node
    assert r.dt == pytest.approx(0.055) and np.isnan(r.mm_per_px) and r.frame == "image"
    assert r.valid.sum() == 1500 and np.isnan(r.u).sum() == 263
    # its line "1827.000000, 1546.000000, -0.043177, 0.257086, 1": v turned downward
    j = int(np.flatnonzero(r.x[0] == 1826.5)[0])
    assert r.u[0, j] == pytest.approx(-0.043177) and r.v[0, j] == pytest.approx(-0.257086)
    assert r.valid[0, j] and not r.valid[0, 0]


def test_rspiv_files_read_back_exactly(tmp_path):
    import rspiv
    from rspiv.outputs import write_netcdf
    from rspiv.synth import particle_pair

    a, b = particle_pair((160, 224), (1.3, -0.7), seed=2)
    f = rspiv.piv(a, b, passes=[(32, 32)], overlap=0.5)
    write_netcdf(f.to_xarray(), tmp_path / "f.nc")
    rspiv.write_tecplot(f, tmp_path / "f.dat")
    for name in ("f.nc", "f.dat"):
        r = read_vectors(tmp_path / name)
        np.testing.assert_array_equal(r.x, f.x)
        np.testing.assert_allclose(r.u, f.u, atol=1e-6)
        np.testing.assert_array_equal(r.valid, f.valid)
        assert r.tool == "rspiv"
    # rspiv piv's attributes: the final window, and a corrected field's frame
    ds = f.to_xarray()
    ds.attrs["piv_settings"] = rspiv.PivSettings(passes=((32, 32),)).to_json()
    ds.attrs["method"] = "II"
    write_netcdf(ds, tmp_path / "corrected.nc")
    c = read_vectors(tmp_path / "corrected.nc")
    assert c.window == (32, 32) and c.frame == "object"
    assert read_vectors(tmp_path / "f.nc").frame == "image"
    from rspiv.compare import compare_fields

    op = tmp_path / "op.txt"
    rows = np.column_stack([(f.x + 0.5).ravel(), (f.y + 0.5).ravel(), f.u.ravel(), f.v.ravel()])
    np.savetxt(op, rows)
    warning = compare_fields(read_vectors(op), c).warning
    assert "the field is in the object frame and the reference in the image frame" in warning


_INSIGHT_PX = (
    'TITLE="f" VARIABLES="X pixel", "Y pixel", "U pixel", "V pixel", "CHC", DATASETAUXDATA '
    'SourceImageWidth="100" DATASETAUXDATA SourceImageHeight="100" ZONE I=2, J=1, F=POINT\n'
)
_TWO = "16, -16, 0, 0, 1\n48, -16, 0, 0, 1\n"


@pytest.mark.parametrize(
    "name, text, match",
    [
        ("f.txt", "1 2 3\n", "3 columns"),
        ("f.txt", "# x y u v\n", "no vectors"),
        ("f.txt", "16 16 1 2\n32 16 1 2\n16 48 1 2\n", "not one vector per node"),
        ("f.txt", "16 16 1 2\n32 16 1 2\n80 16 1 2\n", "not evenly spaced"),
        ("f.txt", "a b c d\n", "not an OpenPIV text file"),
        ("f.vec", "nan 16 1 2\n", "position that is not a number"),
        ("f.mat", "not a mat file", "not a MAT file"),
        ("f.vc7", "not a buffer", "cannot read the DaVis buffer: 12 bytes only"),
        ("f.tif", "", "not a vector file rspiv reads"),
        ("f.vec", _INSIGHT_PX + "1, 1, 0, 0, 1\n", "1 vectors in a zone of I=2 x J=1"),
        ("f.vec", _INSIGHT_PX.replace("X pixel", "X furlong") + _TWO, "length unit rspiv does"),
        ("f.vec", _INSIGHT_PX.replace("pixel", "mm") + _TWO, "without MicrometersPerPixel"),
        ("f.vec", _INSIGHT_PX.replace("POINT", "BLOCK") + _TWO, "only Insight's F=POINT"),
        ("f.vec", _INSIGHT_PX.replace("U pixel", "U pixel/s") + _TWO, "without Microseconds"),
        ("f.vec", _INSIGHT_PX.replace("100", "10") + _TWO, "2 vectors outside the 10 x 10"),
        ("f.vec", _INSIGHT_PX + _TWO.replace("0, 1", "x, 1"), "not numbers"),
        ("f.vec", _INSIGHT_PX + _TWO.replace(", 1\n", ", 1.5\n"), "not an integer"),
        ("f.vec", 'TITLE="t"\n', "an Insight header without vectors"),
    ],
)
def test_bad_files_refused_in_one_line(tmp_path, name, text, match):
    if name.endswith(".vc7"):
        pytest.importorskip("lvpyio", reason="the DaVis tests need lvpyio (rspiv[davis])")
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(InvalidInputError, match=match) as info:
        read_vectors(p)
    assert "\n" not in str(info.value) and str(p) in str(info.value)


def test_damaged_real_files_read_or_refused(tmp_path):
    import rspiv
    from rspiv.outputs import write_netcdf
    from rspiv.synth import particle_pair

    a, b = particle_pair((96, 128), (1.3, -0.7), seed=2)
    f = rspiv.piv(a, b, passes=[(32, 32)])
    write_netcdf(f.to_xarray(), tmp_path / "own.nc")
    rspiv.write_tecplot(f, tmp_path / "own.dat")
    rng = np.random.default_rng(7)
    sources = [REAL / "pivpy_openpiv_exp1_001_b.txt", REAL / "pivpy_pivlab_session.mat",
               REAL / "pivpy_insight_day2a005000.vec", tmp_path / "own.nc",
               tmp_path / "own.dat"]  # fmt: skip
    for src in sources:
        data = bytearray(src.read_bytes())
        for k in range(40):
            bad = bytearray(data)
            for pos in rng.integers(0, len(bad), size=8):
                bad[pos] = int(rng.integers(0, 256))
            if k % 4 == 0:
                bad = bad[: int(rng.integers(1, len(bad)))]
            p = tmp_path / f"{k}{src.suffix}"
            p.write_bytes(bytes(bad))
            try:
                r = read_vectors(p)
            except InvalidInputError as exc:
                assert "\n" not in str(exc)
            else:
                assert r.u.shape == r.x.shape


def test_a_damaged_global_heap_is_refused_before_hdf5_loops(tmp_path):
    """A field file's string attributes live in an HDF5 global heap, which carries no checksum.
    One object's size changed there (8 -> 111 bytes, found by the damaged-file test above) sent
    HDF5 into an endless loop at 100 % CPU. rspiv walks the heap as HDF5 does first
    (``rspiv.hdf5_check``): each such file is refused in one line, or read."""
    import rspiv
    from rspiv.hdf5_check import global_heap_damage
    from rspiv.outputs import write_netcdf
    from rspiv.synth import particle_pair

    a, b = particle_pair((96, 128), (1.3, -0.7), seed=2)
    write_netcdf(rspiv.piv(a, b, passes=[(32, 32)]).to_xarray(), tmp_path / "own.nc")
    data = (tmp_path / "own.nc").read_bytes()
    assert global_heap_damage(tmp_path / "own.nc") is None
    g = data.find(b"GCOL")
    end = g + int.from_bytes(data[g + 8 : g + 16], "little")
    pos, objects = g + 16, []
    while int.from_bytes(data[pos : pos + 2], "little") != 0:
        size = int.from_bytes(data[pos + 8 : pos + 16], "little")
        objects.append(pos)
        pos += 16 + (size + 7) // 8 * 8
    assert len(objects) > 20 and pos < end
    loops = 0
    for k, at in enumerate(objects):
        bad = bytearray(data)
        bad[at + 8 : at + 16] = (111).to_bytes(8, "little")
        p = tmp_path / f"{k}.nc"
        p.write_bytes(bytes(bad))
        try:
            read_vectors(p)
        except InvalidInputError as exc:
            assert "\n" not in str(exc) and str(p) in str(exc)
            loops += "loop forever" in str(exc)
    assert loops >= 1


def test_damaged_davis_header_refused_before_lvpyio_allocates(tmp_path):
    u, v = _values()
    good = _vc7(tmp_path / "good.vc7", u, v).read_bytes()
    for offset, value in ((8, 1 << 30), (12, 1 << 20), (16, -1), (20, 0)):
        bad = bytearray(good)
        bad[offset : offset + 4] = value.to_bytes(4, "little", signed=True)
        p = tmp_path / f"bad{offset}.vc7"
        p.write_bytes(bytes(bad))
        with pytest.raises(InvalidInputError, match="its header announces") as info:
            read_vectors(p)
        assert "\n" not in str(info.value)


def test_options_only_where_they_apply(tmp_path):
    with pytest.raises(InvalidInputError, match="OpenPIV text files only"):
        read_vectors(REAL / "pivpy_pivlab_session.mat", y_up=True)
    with pytest.raises(InvalidInputError, match="OpenPIV text files only"):
        read_vectors(REAL / "pivpy_insight_day2a005000.vec", dt=1e-3)  # Insight's own .vec
    with pytest.raises(InvalidInputError, match="no such file"):
        read_vectors(tmp_path / "missing.vc7")
    with pytest.raises(InvalidInputError, match="must be positive"):
        read_vectors(REAL / "pivpy_openpiv_exp1_001_b.txt", scale=0.0)
