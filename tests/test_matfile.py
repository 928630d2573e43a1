"""MAT v5/v7 files read without trusting them (:mod:`rspiv.matfile`).

Ground truth: files written by scipy's ``savemat`` (plain and zlib-compressed) read back to the
arrays written, as scipy's own reader reads them; and damaged copies (bytes overwritten, cut
short), which scipy's reader crashed on with a segmentation fault, read or refused in one line.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from rspiv.errors import InvalidInputError
from rspiv.matfile import read_mat


def _variables():
    rng = np.random.default_rng(2)
    cell = np.empty((3, 1), dtype=object)
    cell[0, 0] = rng.normal(size=(4, 5))
    cell[1, 0] = np.zeros((0, 0))
    cell[2, 0] = np.arange(6, dtype=np.int32).reshape(2, 3)
    nested = np.empty((1, 2), dtype=object)
    nested[0, 0] = cell
    nested[0, 1] = np.float32(1.5) * np.ones((2, 2), np.float32)
    return {
        "x": rng.normal(size=(7, 9)),
        "flags": (rng.random((3, 4)) > 0.5),
        "counts": rng.integers(0, 60000, (5, 2)).astype(np.uint16),
        "scalar": 3.25,
        "u": cell,
        "nested": nested,
        "text": "not numbers",
    }


@pytest.mark.parametrize("compress", [False, True])
def test_files_of_savemat_read_as_scipy_reads_them(tmp_path, compress):
    path = tmp_path / "v.mat"
    scipy.io.savemat(path, _variables(), do_compression=compress)
    ours = read_mat(path)
    theirs = scipy.io.loadmat(path, squeeze_me=False)
    for name in ("x", "flags", "counts", "scalar"):
        np.testing.assert_array_equal(ours[name], theirs[name])
        assert ours[name].shape == theirs[name].shape
    for k in range(3):
        np.testing.assert_array_equal(ours["u"][k, 0], theirs["u"][k, 0])
    np.testing.assert_array_equal(ours["nested"][0, 0][0, 0], theirs["nested"][0, 0][0, 0])
    np.testing.assert_array_equal(ours["nested"][0, 1], theirs["nested"][0, 1])
    assert ours["text"] is None  # characters are not needed by the vector readers


@pytest.mark.parametrize("compress", [False, True])
def test_damaged_files_read_or_refused_in_one_line(tmp_path, compress):
    src = tmp_path / "v.mat"
    scipy.io.savemat(src, _variables(), do_compression=compress)
    data = src.read_bytes()
    rng = np.random.default_rng(11)
    refused = 0
    for k in range(150):
        bad = bytearray(data)
        for pos in rng.integers(128, len(bad), size=6):
            bad[pos] = int(rng.integers(0, 256))
        if k % 5 == 0:
            bad = bad[: int(rng.integers(1, len(bad)))]
        p = tmp_path / "bad.mat"
        p.write_bytes(bytes(bad))
        try:
            read_mat(p)
        except InvalidInputError as exc:
            refused += 1
            assert "\n" not in str(exc) and "bad.mat" in str(exc)
    assert refused > 20  # the damage is seen, not read as numbers


def test_not_a_mat_file(tmp_path, monkeypatch):
    p = tmp_path / "x.mat"
    p.write_bytes(b"MATLAB 5.0" + b" " * 200)
    with pytest.raises(InvalidInputError, match="no endian indicator"):
        read_mat(p)
    bomb = tmp_path / "bomb.mat"
    header = bytearray(b"MATLAB 5.0 MAT-file".ljust(116)) + bytes(8) + b"\x00\x01IM"
    import zlib

    body = zlib.compress(bytes(8 << 20))  # 8 MiB of zeros in 8 KB
    tag = np.array([15, len(body)], "<u4").tobytes()
    bomb.write_bytes(bytes(header) + tag + body)
    monkeypatch.setattr("rspiv.matfile._MAX_INFLATE", 1 << 20)  # the 2 GiB cap, scaled down
    with pytest.raises(InvalidInputError, match="inflating past"):
        read_mat(bomb)
