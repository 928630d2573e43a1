"""MATLAB v5/v7 MAT files (``save -v7``, PIVlab's results) read without trusting them.

scipy's reader trusts the sizes a file states: a damaged file (a few bytes overwritten) made it
crash the Python process with a segmentation fault or a bus error (found by rspiv's damage
tests on PIVlab files, 500 copies with 6 bytes overwritten at random). A vector file must be
read or refused in one line, so rspiv reads the subset of the format its readers need here, in
Python over NumPy, with every size checked against the bytes that hold it:

- the 128-byte header (text, version 0x0100, endian indicator ``IM``/``MI``);
- data elements with their 8-byte tags (and the small-element form), padded to 8 bytes;
- ``miCOMPRESSED`` elements (zlib, inflated to at most ``1024`` times their size and 2 GiB);
- ``miMATRIX`` of numeric classes (double, single, integers; logical) as arrays of their
  dimensions in MATLAB's column-major order (a complex one's real part), and cell arrays as
  object arrays of their elements; characters, structs, objects and sparse matrices are read
  as ``None`` (PIVlab's numbers do not use them).

MAT v7.3 files are HDF5 and are read with h5py (:mod:`rspiv.vector_files`).
Layout: MathWorks, "MAT-File Format", version 7 (the public description of the v5 format).
"""

from __future__ import annotations

import pathlib
import zlib
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = ["read_mat"]

_MI = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8", 13: "u8"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MX_CELL = 1
_MX_NUMERIC = {6: "f8", 7: "f4", 8: "i1", 9: "u1", 10: "i2", 11: "u2", 12: "i4", 13: "u4",
               14: "i8", 15: "u8"}  # fmt: skip
_MAX_INFLATE = 2**31
_MAX_DEPTH = 16


class _Bad(Exception):
    """A structural error; turned into one InvalidInputError line naming the file."""


class _Reader:
    def __init__(self, data: bytes | memoryview, endian: str):
        self.data = memoryview(data)
        self.end = endian

    def tag(self, pos: int, limit: int) -> tuple[int, int, int, int]:
        """(type, nbytes, data start, next element) of the element at ``pos``."""
        if pos + 8 > limit:
            raise _Bad(f"an element tag cut at byte {pos}")
        first = int(np.frombuffer(self.data[pos : pos + 4], self.end + "u4")[0])
        if first >> 16:  # small data element: size and type in one word, data in the next 4
            kind, n = first & 0xFFFF, first >> 16
            if n > 4:
                raise _Bad(f"a small element of {n} bytes at byte {pos}")
            return kind, n, pos + 4, pos + 8
        n = int(np.frombuffer(self.data[pos + 4 : pos + 8], self.end + "u4")[0])
        start = pos + 8
        if start + n > limit:
            raise _Bad(f"an element of {n} bytes at byte {pos} runs past its end")
        nxt = start + n if first == _MI_COMPRESSED else start + ((n + 7) // 8) * 8
        return first, n, start, min(nxt, limit)

    def numbers(self, kind: int, start: int, n: int) -> np.ndarray:
        code = _MI.get(kind)
        if code is None:
            raise _Bad(f"data of type {kind} where numbers are expected")
        size = np.dtype(code).itemsize
        if n % size:
            raise _Bad(f"{n} bytes of {size}-byte numbers")
        return np.frombuffer(self.data[start : start + n], self.end + code)

    def matrix(self, start: int, limit: int, depth: int) -> tuple[str, Any]:
        """(name, value) of the miMATRIX whose data spans ``start`` to ``limit``."""
        if depth > _MAX_DEPTH:
            raise _Bad("cells nested too deep")
        if start == limit:
            return "", None  # an empty element (an empty cell's content)
        kind, n, s, pos = self.tag(start, limit)
        flags = self.numbers(kind, s, n)
        if flags.size < 2:
            raise _Bad("a matrix without its array flags")
        klass, complex_ = int(flags[0]) & 0xFF, bool(int(flags[0]) & 0x800)
        kind, n, s, pos = self.tag(pos, limit)
        dims = self.numbers(kind, s, n).astype(np.int64)
        if dims.size < 2 or dims.size > 32 or (dims < 0).any():
            raise _Bad(f"dimensions {dims.tolist()}")
        count = int(np.prod(dims, dtype=np.float64)) if dims.size else 0
        if count > limit - start and klass != _MX_CELL:
            raise _Bad(f"{count} values announced in {limit - start} bytes")
        kind, n, s, pos = self.tag(pos, limit)
        name = bytes(self.data[s : s + n]).decode("ascii", "replace")
        shape = tuple(int(d) for d in dims)
        if klass == _MX_CELL:
            if count > (limit - pos) // 8 + 1:
                raise _Bad(f"a cell of {count} elements in {limit - pos} bytes")
            cell = np.empty(count, dtype=object)
            for k in range(count):
                kind, n, s, pos = self.tag(pos, limit)
                if kind != _MI_MATRIX:
                    raise _Bad(f"a cell element of type {kind}")
                cell[k] = self.matrix(s, s + n, depth + 1)[1]
            return name, cell.reshape(shape, order="F")
        code = _MX_NUMERIC.get(klass)
        if code is None:
            return name, None  # characters, structs, objects, sparse: not needed here
        kind, n, s, pos = self.tag(pos, limit)
        real = self.numbers(kind, s, n)
        if real.size != count:
            raise _Bad(f"{real.size} values for dimensions {list(shape)}")
        del complex_  # the imaginary part, when present, is not needed
        return name, real.astype(code).reshape(shape, order="F")


def read_mat(path: str | pathlib.Path) -> dict[str, Any]:
    """The variables of a MAT v5/v7 file (module docstring): ``{name: ndarray | object array |
    None}``. InvalidInputError, one line naming the file, for anything it cannot read."""
    p = pathlib.Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InvalidInputError(f"{p}: cannot read: {exc}") from None
    if len(raw) < 128:
        raise InvalidInputError(f"{p}: {len(raw)} bytes: not a MAT file (128-byte header)")
    mark = raw[126:128]
    if mark not in (b"IM", b"MI"):
        raise InvalidInputError(f"{p}: not a MATLAB v5/v7 MAT file (no endian indicator)")
    endian = "<" if mark == b"IM" else ">"
    out: dict[str, Any] = {}
    try:
        top = _Reader(raw, endian)
        pos = 128
        while pos < len(raw):
            kind, n, s, nxt = top.tag(pos, len(raw))
            if kind == _MI_COMPRESSED:
                limit = min(_MAX_INFLATE, 1024 * n + (1 << 20))
                z = zlib.decompressobj()
                try:
                    body = z.decompress(bytes(top.data[s : s + n]), limit)
                except zlib.error as exc:
                    raise _Bad(f"a compressed element that does not inflate ({exc})") from None
                if z.unconsumed_tail:
                    raise _Bad(f"a compressed element inflating past {limit} bytes")
                inner = _Reader(body, endian)
                k2, n2, s2, _ = inner.tag(0, len(body))
                if k2 == _MI_MATRIX:
                    name, val = inner.matrix(s2, s2 + n2, 0)
                    out[name] = val
            elif kind == _MI_MATRIX:
                name, val = top.matrix(s, s + n, 0)
                out[name] = val
            pos = nxt
    except _Bad as exc:
        raise InvalidInputError(f"{p}: a damaged MAT file: {exc}") from None
    except (ValueError, TypeError, IndexError, OverflowError, MemoryError) as exc:
        raise InvalidInputError(f"{p}: a damaged MAT file ({type(exc).__name__}: {exc})") from None
    return out
