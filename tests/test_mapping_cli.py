"""`rspiv-engine fit-mapping` / `map` and their Python twins `rspiv fit-mapping` / `rspiv map`:
the same files and numbers from both, and one-line errors with a non-zero exit status."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys

import mapping_cases as mc
import numpy as np
import pytest
import rspiv
import rspiv.cli


def _run_engine(engine, *args):
    return subprocess.run([engine, *map(str, args)], capture_output=True, text=True)


def _run_py(*args):
    return subprocess.run(
        [sys.executable, "-m", "rspiv", *map(str, args)], capture_output=True, text=True
    )


def _run_py_inprocess(*args):
    """``rspiv.cli.main`` in this process (no interpreter start-up per call)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = rspiv.cli.main([str(a) for a in args])
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


RUNNERS = ["engine", "python"]


def _runner(kind, engine):
    return (lambda *a: _run_engine(engine, *a)) if kind == "engine" else _run_py_inprocess


@pytest.fixture
def points_csv(tmp_path):
    obj = mc.grid_13x7()
    img = mc.apply_truth("p3", mc.truth_coefficients("p3"), obj)
    img = img + np.random.default_rng(3).normal(0, 0.05, img.shape)
    path = tmp_path / "points.csv"
    np.savetxt(
        path,
        np.column_stack([obj, img]),
        delimiter=",",
        header="x_obj,y_obj,x_img,y_img",
        comments="",
        fmt="%.17g",
    )
    return path, obj, img


@pytest.mark.parametrize("model", ["r1", "r2", "p3"])
def test_both_commands_write_the_same_mapping_as_the_api(engine, points_csv, tmp_path, model):
    path, obj, img = points_csv
    out_e, out_p = tmp_path / "e.json", tmp_path / "p.json"
    r = _run_engine(engine, "fit-mapping", path, "--model", model, "-o", out_e)
    assert r.returncode == 0, r.stderr
    assert model in r.stdout and "91 points" in r.stdout
    r = _run_py("fit-mapping", path, "--model", model, "-o", out_p)
    assert r.returncode == 0, r.stderr
    assert out_e.read_text() == out_p.read_text()
    api = rspiv.fit_mapping(obj, img, model=model)
    loaded = rspiv.Mapping.load(out_e)
    np.testing.assert_array_equal(loaded.coefficients, api.coefficients)


@pytest.mark.parametrize("kind", RUNNERS)
def test_map_forward_and_inverse(engine, points_csv, tmp_path, kind):
    run = _runner(kind, engine)
    path, obj, img = points_csv
    mfile = tmp_path / "m.json"
    m = rspiv.fit_mapping(obj, img, model="p3").rotated(-0.04)
    m.save(mfile)
    pts = mc.sensor_grid(11, 7)
    pfile = tmp_path / "pts.csv"
    np.savetxt(pfile, pts, delimiter=",", header="x,y", comments="", fmt="%.17g")
    r = run("map", mfile, pfile)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "x,y"
    fwd = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    np.testing.assert_array_equal(fwd, m.forward(pts))
    ffile = tmp_path / "fwd.csv"
    np.savetxt(ffile, fwd, delimiter=",", header="x,y", comments="", fmt="%.17g")
    out = tmp_path / "back.csv"
    r = run("map", mfile, ffile, "--inverse", "-o", out)
    assert r.returncode == 0, r.stderr
    back = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.abs(back - pts).max() < 1e-6


@pytest.mark.parametrize("kind", RUNNERS)
def test_errors_exit_nonzero_with_one_line(engine, points_csv, tmp_path, kind):
    run = _runner(kind, engine)
    path, obj, img = points_csv
    good = tmp_path / "m.json"
    rspiv.fit_mapping(obj, img, model="r1").save(good)
    few = tmp_path / "few.csv"
    few.write_text(
        "x_obj,y_obj,x_img,y_img\n" + "".join(f"{i},{i * i},{i},{i * i}\n" for i in range(5))
    )
    badcol = tmp_path / "badcol.csv"
    badcol.write_text("x,y\n1,2\n")
    badnum = tmp_path / "badnum.csv"
    badnum.write_text("x_obj,y_obj,x_img,y_img\n1,2,3,oops\n")
    foreign = tmp_path / "foreign.json"
    foreign.write_text('{"type": "FeatureCollection"}')
    pts = tmp_path / "pts.csv"
    pts.write_text("x,y\n1,2\n")
    doc = json.loads(good.read_text())
    doc["coefficients"] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0]
    pole = tmp_path / "pole.json"
    pole.write_text(json.dumps(doc))
    far = tmp_path / "far.csv"
    far.write_text(f"x,y\n{doc['centre_image'][0] + 2.5 * doc['scale']},{doc['centre_image'][1]}\n")
    cases = [
        (("fit-mapping", few, "--model", "p3", "-o", tmp_path / "o.json"), "at least 11 points"),
        (("fit-mapping", path, "--model", "q9", "-o", tmp_path / "o.json"), "unknown mapping"),
        (("fit-mapping", badcol, "-o", tmp_path / "o.json"), "missing column"),
        (("fit-mapping", badnum, "-o", tmp_path / "o.json"), "line 2: column y_img"),
        (("fit-mapping", tmp_path / "nope.csv", "-o", tmp_path / "o.json"), "nope.csv"),
        (("map", foreign, pts), "not an rspiv mapping"),
        (("map", path, pts), "not valid JSON"),
        (("map", pole, far, "--inverse"), "did not converge"),
    ]
    for args, msg in cases:
        r = run(*args)
        assert r.returncode != 0, args
        err = r.stderr.strip()
        assert len(err.splitlines()) == 1, (args, err)
        assert msg in err, (args, err)
    assert not (tmp_path / "o.json").exists()
