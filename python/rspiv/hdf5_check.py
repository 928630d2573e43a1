"""A damaged HDF5 file's global heaps, found before the HDF5 library reads them.

NetCDF-4 files (rspiv's fields, a campaign's field files) are HDF5 files whose string attributes
(``units``, ``long_name``) live in *global heap collections*. HDF5 checks no checksum there: a
collection whose objects' sizes were damaged can make the library loop forever while it reads an
attribute (seen here: one object's size byte changed in an rspiv field file hung ``h5py`` at 100 %
CPU). rspiv must refuse a damaged file, never hang, so its readers walk the collections first.

The layout walked (HDF5 file format specification, version 2 and later, "Global Heap"): a
collection is the signature ``GCOL``, a version byte (1), three reserved bytes and the
collection's size (8 bytes, little-endian, the 16-byte header included); then its objects, each
an index (2 bytes), a reference count (2), four reserved bytes, the data's size (8) and the data
padded to a multiple of 8 bytes; object 0 is free space, its size counting its header.
"""

from __future__ import annotations

import os

__all__ = ["global_heap_damage"]

_HEADER = 16
#: Files found sound, by (path, mtime_ns, size): a second pass reads a field file a band of rows
#: at a time and is not made to read the whole file again for each band.
_SOUND: dict[tuple[str, int, int], None] = {}
_SOUND_MAX = 200_000


def global_heap_damage(path: str | os.PathLike) -> str | None:
    """What is wrong with the file's global heap collections, or None when every collection's
    objects tile it (or it has none). Reads the whole file once; a sound file is remembered (by
    its path, modification time and size) and not read again."""
    try:
        st = os.stat(path)
        key = (os.fspath(path), st.st_mtime_ns, st.st_size)
        if key in _SOUND:
            return None
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        return f"cannot read: {exc}"
    problem = _collections(data)
    if problem is None:
        if len(_SOUND) >= _SOUND_MAX:
            _SOUND.clear()
        _SOUND[key] = None
    return problem


def _collections(data: bytes) -> str | None:
    n = len(data)
    start = data.find(b"GCOL")
    while start >= 0:
        if start + _HEADER <= n and data[start + 4] == 1:
            size = int.from_bytes(data[start + 8 : start + 16], "little")
            end = start + size
            if size < _HEADER or end > n:
                return (
                    f"a global heap at byte {start} of {size} bytes in a file of {n}: damaged "
                    "or cut short"
                )
            problem = _walk(data, start + _HEADER, end)
            if problem:
                return f"the global heap at byte {start}: {problem}"
        start = data.find(b"GCOL", start + 4)
    return None


def _walk(data: bytes, pos: int, end: int) -> str | None:
    """Walk the objects as HDF5's reader does (``H5HG__cache_heap_deserialize``): each object
    moves on by its header and its padded size, the free space (object 0) by its size; a free
    space of size 0 would not move it, and the library loops there forever."""
    seen: set[int] = set()
    while pos + _HEADER <= end:
        index = int.from_bytes(data[pos : pos + 2], "little")
        size = int.from_bytes(data[pos + 8 : pos + 16], "little")
        if index == 0:
            if size == 0:
                return f"an empty free space at byte {pos}, where HDF5 would loop forever"
            need = size
        else:
            if index in seen:
                return f"object {index} twice"
            seen.add(index)
            need = _HEADER + ((size + 7) // 8) * 8
        if pos + need > end:
            return f"object {index} of {size} bytes overruns it"
        pos += need
    return None
