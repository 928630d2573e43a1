"""A series' files read ahead in reader processes (:mod:`rspiv.vector_readahead`, the
``readers=`` of :func:`rspiv.vector_statistics` and ``rspiv statistics --readers``).

Ground truth: the same series reduced with the files read in the calling process. The fields
are the synthetic layer's exact fields at a DaVis grid (``vector_series_cases``), one prograde
Lamb-Oseen vortex planted in each, so that every pass (the statistics, the pilots of the
screen, the second pass's quadrants, conditional averages and vortex population, the POD's
sweeps) reads files; every figure must be the same bit for bit.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np
import pytest
import rspiv.vector_readahead as ra
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.vector_readahead import ReadAhead, auto_readers
from rspiv.vector_reduction import read_entry
from rspiv.vector_statistics import vector_statistics
from vector_series_cases import exact_field, write_vc7

pytest.importorskip("lvpyio", reason="the series are DaVis files (rspiv[davis])")
N = 16


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    folder = tmp_path_factory.mktemp("readahead")
    files = []
    for s in range(N):
        tr, _, _, u, v = exact_field(s, vortices=1, vortex_radius_px=40.0, vortex_swirl_px=8.0)
        files.append(write_vc7(folder / f"B{s:05d}.vc7", u, v, 1.0 / tr.magnification, tr.dt))
    return folder, files, tr.flow.nu


def _same(a, b, where="") -> None:
    """``a`` and ``b`` equal bit for bit (NaN where NaN), through dicts, sequences, arrays;
    the time a step took excepted."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for k in a:
            if k != "seconds":
                _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)) and not isinstance(a, str):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, float, np.floating)):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), where
    else:
        assert a == b, where


def _reduce(files, nu, readers, **kw):
    return vector_statistics(
        files, nu=nu, readers=readers, quadrant=True, conditional=(0.15,), vortices=True,
        pod=True, two_point=True, **kw,
    )  # fmt: skip


def test_read_ahead_gives_the_same_statistics_bit_for_bit(series):
    _, files, nu = series
    here, ahead = _reduce(files, nu, 0), _reduce(files, nu, 2)
    assert here.used == ahead.used == N
    a, b = here.to_xarray(), ahead.to_xarray()
    assert set(a.data_vars) == set(b.data_vars)
    for name in a.data_vars:
        _same(a[name].values, b[name].values, name)
    for what in ("two_point", "quadrant", "conditional", "pod", "vortices"):
        assert getattr(here, what) is not None, what
        _same(getattr(here, what), getattr(ahead, what), what)
    assert len(here.vortices["cores"]["x"]) >= N  # every planted vortex at least
    assert here.warnings == ahead.warnings


def test_fields_in_any_order_are_the_files(series):
    _, files, _ = series
    with ReadAhead(files, {}, readers=2, order=range(N)) as reads:
        for k in (0, 1, 2, 7, 8, 3, 3, 15, 0):  # in order, then jumps, a repeat, back
            got, want = reads.get(k), read_entry(files[k], {})
            for name in ("x", "y", "u", "v", "valid", "postprocessed"):
                _same(getattr(got, name), getattr(want, name), f"{k}.{name}")
        reads.along([5, 4])
        _same(reads.get(4).u, read_entry(files[4], {}).u)  # not next along: read from there
    assert auto_readers(N) == 0  # a short series is read in the calling process
    cpus = len(os.sched_getaffinity(0))
    assert auto_readers(10_000) == (0 if cpus < 2 else min(cpus, 4))


def test_a_file_that_does_not_read_is_named_as_without_readers(series, tmp_path):
    folder, files, nu = series
    bad = tmp_path / "B00005.vc7"
    bad.write_bytes(pathlib.Path(files[5]).read_bytes()[:300])  # truncated
    mixed = [*files[:5], bad, *files[6:]]
    here = vector_statistics(mixed, nu=nu, readers=0)
    ahead = vector_statistics(mixed, nu=nu, readers=2)
    assert here.skipped == ahead.skipped and str(bad) in ahead.skipped
    assert here.used == ahead.used == N - 1
    _same(here.to_xarray()["u"].values, ahead.to_xarray()["u"].values)


def _crashing(monkeypatch, tmp_path, name: str, times: int) -> None:
    """Reader processes that die (exit code 7) reading ``name``, the first ``times`` times
    (counted in a file, across processes)."""
    count = tmp_path / "deaths"
    count.write_text("0")
    code = (
        "import os, rspiv.vector_readahead as m\n"
        "read = m.read_entry\n"
        "def crash(entry, options):\n"
        f"    if {name!r} in str(entry):\n"
        f"        n = int(open({str(count)!r}).read())\n"
        f"        if n < {times}:\n"
        f"            open({str(count)!r}, 'w').write(str(n + 1))\n"
        "            os._exit(7)\n"
        "    return read(entry, options)\n"
        "m.read_entry = crash\n"
        "m.serve()\n"
    )
    monkeypatch.setattr(ra, "_WORKER", code)


def test_a_reader_that_dies_is_replaced_and_its_field_read_again(series, monkeypatch, tmp_path):
    _, files, _ = series
    _crashing(monkeypatch, tmp_path, "B00003", times=1)
    with ReadAhead(files, {}, readers=1) as reads:
        for k in range(N):
            _same(reads.get(k).u, read_entry(files[k], {}).u, str(k))
    assert (tmp_path / "deaths").read_text() == "1"


def test_a_file_that_kills_two_readers_is_skipped_and_said(series, monkeypatch, tmp_path):
    _, files, nu = series
    _crashing(monkeypatch, tmp_path, "B00003", times=100)
    with ReadAhead(files, {}, readers=2) as reads:
        with pytest.raises(InvalidInputError, match="died reading it twice .exit code -?7"):
            for k in range(N):
                reads.get(k)
        _same(reads.get(4).u, read_entry(files[4], {}).u)  # the series goes on
    r = vector_statistics(files, nu=nu, readers=2, screen=0)
    assert r.used == N - 1
    assert "died reading it twice" in r.skipped[str(files[3])]


def test_resumed_with_readers(series, tmp_path):
    _, files, nu = series
    out = tmp_path / "out"

    def stop(done, total):
        if done == 7:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        vector_statistics(files, nu=nu, readers=2, out_dir=out, checkpoint_every=3,
                          progress=stop, quadrant=True)  # fmt: skip
    seen = []
    r = vector_statistics(files, nu=nu, readers=2, out_dir=out, checkpoint_every=3,
                          progress=lambda d, t: seen.append(d), quadrant=True)  # fmt: skip
    assert seen[0] == 7  # after the 6 fields of the last checkpoint
    whole = vector_statistics(files, nu=nu, readers=0, quadrant=True)
    _same(r.to_xarray()["uu"].values, whole.to_xarray()["uu"].values)
    _same(r.quadrant, whole.quadrant)


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2"])
def test_bad_readers_refused(series, bad):
    _, files, nu = series
    with pytest.raises(InvalidInputError, match="readers"):
        vector_statistics(files, nu=nu, readers=bad)


def test_cli_readers(series, tmp_path, capsys):
    folder, _, nu = series
    out = tmp_path / "o"
    args = ["statistics", str(folder), "--nu", str(nu), "-o", str(out), "--readers"]
    assert main([*args, "-1"]) == 2
    assert "readers" in capsys.readouterr().err
    assert not out.exists()
    assert main([*args, "2"]) == 0
    assert (out / "statistics.nc").exists()


def test_readers_that_cannot_start_leave_the_reading_here(series, monkeypatch):
    _, files, nu = series
    monkeypatch.setattr(ra, "_WORKER", "import sys; sys.exit(3)")
    r = vector_statistics(files, nu=nu, readers=2, quadrant=True)
    whole = vector_statistics(files, nu=nu, readers=0, quadrant=True)
    assert r.used == N and not r.skipped
    _same(r.to_xarray()["uu"].values, whole.to_xarray()["uu"].values)
    _same(r.quadrant, whole.quadrant)
    said = [w for w in r.warnings if "reader processes ended as they started" in w]
    assert said == ["the reader processes ended as they started (exit code 3, twice): the "
                    "files were read in this process"]  # fmt: skip


def test_no_interpreter_to_run_the_readers(series, monkeypatch):
    _, files, nu = series
    monkeypatch.setattr(ra.sys, "executable", "/nonexistent/python3")
    r = vector_statistics(files, nu=nu, readers=2)
    assert r.used == N and not r.skipped
    said = [w for w in r.warnings if "reader processes could not start" in w]
    assert len(said) == 1 and "the files were read in this process" in said[0]
