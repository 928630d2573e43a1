"""Reading a series' vector files ahead of their use, in reader processes (for
:mod:`rspiv.vector_statistics`).

A DaVis ``.vc7`` file of a 47 MP camera's grid (183,000 vectors) takes lvpyio about 50 ms to
read, and lvpyio holds the GIL: two reader threads read 24 such files in 1.45 s against 1.44 s
for one. The statistics' own work on a field (the moments to order 8, the lag-1 chains, the
structures' sums) is done in between, so a series read and summed in one process leaves the
second core idle. :class:`ReadAhead` reads the fields in ``readers`` processes of their own, a
few fields ahead, and hands each over in turn: the sums are those of the fields read in the
calling process, bit for bit (``tests/test_vector_readahead.py``).

- The order the fields will be asked for is given (``order``: a pass over the series, the POD's
  snapshots); :meth:`ReadAhead.get` asked for another field than the next one starts reading
  ahead from there (the POD reads its snapshots once per block of rows).
- ``readers=0`` reads in the calling process when asked. :func:`auto_readers` chooses 0 for a
  series shorter than :data:`MIN_FIELDS` (a reader process costs about 1 s to start: numpy,
  lvpyio and rspiv imported) or a single core, else one reader per core (at most 4).
- A field that does not read gives its :class:`rspiv.errors.RspivError`, raised by
  :meth:`ReadAhead.get` as a read in the calling process would raise it.
- A reader process that dies (a damaged file that crashes the reading library, which would
  have taken the calling process down) is replaced, and the field it was reading is read again;
  a field that takes two readers down raises :class:`rspiv.errors.InvalidInputError` saying so,
  and the series goes on without it. Readers that end before they could read (twice: no
  interpreter, rspiv not importable there) leave the reading to the calling process, and
  :attr:`ReadAhead.notes` says so.
- The reader processes are fresh interpreters (``python -c``), not forks: nothing of the
  calling process (its threads, its ``__main__``) is copied or imported again. They end with
  :meth:`ReadAhead.close` (a context manager).

Fields are handed over pickled through a pipe (about 6 MB for 183,000 vectors), which costs
the calling process a copy per field.
"""

from __future__ import annotations

import collections
import itertools
import os
import pathlib
import pickle
import signal
import struct
import subprocess
import sys
import threading
from collections.abc import Sequence
from typing import Any

try:
    import fcntl
except ImportError:  # not POSIX: the pipe keeps its default size
    fcntl = None  # type: ignore[assignment]

from rspiv.errors import InvalidInputError
from rspiv.vector_files import VectorFile
from rspiv.vector_reduction import entry_name, read_entry

__all__ = ["MIN_FIELDS", "ReadAhead", "auto_readers"]

#: Series shorter than this are read in the calling process by :func:`auto_readers`' choice.
MIN_FIELDS = 64

#: Each answer's length before it (bytes, little-endian unsigned 64-bit).
_SIZE = struct.Struct("<Q")

#: ``fcntl``'s F_SETPIPE_SZ (Linux) and the pipe size asked for (the default limit, 1 MiB).
_F_SETPIPE_SZ, _PIPE_BYTES = 1031, 1 << 20

#: The program a reader process runs (``python -c``).
_WORKER = "from rspiv.vector_readahead import serve; serve()"

#: How long :meth:`ReadAhead.get` waits for a reader before it looks whether it is alive, s.
_POLL_S = 2.0


def auto_readers(n_fields: int) -> int:
    """Reader processes for a series of ``n_fields`` (module docstring): 0 below
    :data:`MIN_FIELDS` fields or on one core, else one per core the process may use (at most
    4)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return 0 if cpus < 2 or n_fields < MIN_FIELDS else min(cpus, 4)


def serve() -> None:
    """A reader process's loop: ``(serial, entry, options)`` requests pickled on stdin, each
    answered on stdout by ``(serial, VectorFile or the exception)`` pickled after its length
    (:data:`_SIZE`), in the order asked, after ``(-1, None)`` once started. What the reading
    libraries print goes to stderr."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the calling process's to handle
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    inp = sys.stdin.buffer
    hello = pickle.dumps((-1, None))  # started: a death from now on is a file's doing
    out.write(_SIZE.pack(len(hello)))
    out.write(hello)
    out.flush()
    while True:
        try:
            serial, entry, options = pickle.load(inp)
        except EOFError:
            return
        try:
            got: Any = read_entry(entry, options)
        except Exception as exc:  # noqa: BLE001 - raised again by the calling process
            got = exc
        try:
            data = pickle.dumps((serial, got), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 - an exception that does not pickle
            data = pickle.dumps((serial, RuntimeError(f"{type(got).__name__}: {got}")))
        out.write(_SIZE.pack(len(data)))
        out.write(data)
        out.flush()


def _read_exactly(f: Any, n: int) -> bytearray:
    """``n`` bytes from the unbuffered pipe ``f`` (the GIL released while the kernel copies).

    Raises
    ------
    EOFError
        The pipe ended first (its process is gone).
    """
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise EOFError
        got += k
    return buf


class _Reader:
    """One reader process, the serials it was asked for in order, and the thread that takes
    its answers."""

    def __init__(self, owner: ReadAhead) -> None:
        env = dict(os.environ)
        root = str(pathlib.Path(__file__).resolve().parents[1])  # where rspiv was imported from
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _WORKER],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, bufsize=0,
        )  # fmt: skip
        try:  # a field in a few large writes rather than a hundred of the default 64 KiB
            fcntl.fcntl(self.proc.stdout.fileno(), _F_SETPIPE_SZ, _PIPE_BYTES)
        except (OSError, AttributeError):  # not Linux, or above the system's limit
            pass
        self.asked: collections.deque[int] = collections.deque()
        self.dead = False
        self.ready = False
        self.owner = owner
        self.thread = threading.Thread(target=self._answers, daemon=True)
        self.thread.start()

    def _answers(self) -> None:
        own, out = self.owner, self.proc.stdout
        try:
            while True:
                serial, got = pickle.loads(_read_exactly(out, _SIZE.unpack(
                    _read_exactly(out, _SIZE.size))[0]))  # fmt: skip
                with own.cond:
                    if serial == -1:
                        self.ready = True
                        continue
                    if self.asked and self.asked[0] == serial:
                        self.asked.popleft()
                    if serial in own.live:
                        own.results[serial] = got
                    own.cond.notify_all()
        except Exception:  # noqa: BLE001 - EOF or a broken pipe: the process is gone
            with own.cond:
                self.dead = True
                own.cond.notify_all()

    def ask(self, serial: int, entry: Any, options: dict[str, Any]) -> None:
        self.asked.append(serial)
        view = memoryview(pickle.dumps((serial, entry, options)))
        try:
            while view:  # an unbuffered pipe may take part of a write
                view = view[self.proc.stdin.write(view) :]
        except (BrokenPipeError, OSError, ValueError):
            self.dead = True

    def close(self, join: bool = True) -> int | None:
        try:
            self.proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            pass
        if self.proc.poll() is None:
            self.proc.kill()
        rc = self.proc.wait()
        if join:  # not while the owner's lock is held: the thread takes it to say it ended
            self.thread.join(timeout=5)
        return rc


class ReadAhead:
    """The fields of ``entries`` (:func:`rspiv.vector_reduction.series_entries`) read by
    :func:`rspiv.vector_reduction.read_entry` with ``options``, ``readers`` processes reading
    ahead along ``order`` (entry indices; all of them in turn when None), ``depth`` fields
    ahead at most (twice the readers when None). Module docstring."""

    def __init__(
        self,
        entries: Sequence[Any],
        options: dict[str, Any],
        readers: int = 0,
        order: Sequence[int] | None = None,
        depth: int | None = None,
    ) -> None:
        self.entries = entries
        self.options = dict(options)
        self.readers = max(int(readers), 0)
        self.order = list(range(len(entries))) if order is None else [int(k) for k in order]
        self._at = {k: i for i, k in enumerate(self.order)}
        self.depth = max(int(depth), 1) if depth is not None else 2 * self.readers
        self.cond = threading.Condition()
        self.results: dict[int, Any] = {}
        self.live: set[int] = set()
        self._wanted: collections.deque[tuple[int, int]] = collections.deque()  # (serial, k)
        self._serials = itertools.count()
        self._next = 0
        self._slots: list[_Reader] = []
        self._deaths: dict[int, int] = {}
        self._fruitless = 0  # readers that died before they started
        #: What must be said (the reader processes could not start: read in this process).
        self.notes: list[str] = []
        self._kind: dict[int, int] = {}  # serial -> entry index

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def along(self, order: Sequence[int]) -> ReadAhead:
        """Read ahead along ``order`` (entry indices) from now on; returns ``self``, so that
        ``with reads.along(order):`` ends the reader processes after the pass (the next
        :meth:`get` starts them again)."""
        with self.cond:
            self.order = [int(k) for k in order]
            self._at = {k: i for i, k in enumerate(self.order)}
            self._restart(len(self.order))
        return self

    def get(self, k: int) -> VectorFile:
        """Entry ``k``'s field, read ahead when ``k`` is the next one of ``order``.

        Raises
        ------
        RspivError
            The field does not read (as :func:`rspiv.vector_reduction.read_entry` raises it),
            or it took two reader processes down.
        """
        if self.readers == 0 or k not in self._at:
            return read_entry(self.entries[k], self.options)
        with self.cond:
            if not self._wanted or self._wanted[0][1] != k:
                self._restart(self._at[k])
            self._fill()
            serial = self._wanted[0][0] if self._wanted else -1
            while serial not in self.results and self.readers:
                for r in list(self._slots):
                    if r.dead and r in self._slots:  # (a reader given up is not revived)
                        self._revive(r)
                if serial not in self.results and self.readers:
                    self.cond.wait(_POLL_S)
            if serial in self.results:
                got = self.results.pop(serial)
                self.live.discard(serial)
                self._kind.pop(serial, None)
                self._wanted.popleft()
                self._fill()
        if not self.readers:  # the readers could not start: read here from now on
            return read_entry(self.entries[k], self.options)
        if isinstance(got, BaseException):
            raise got
        return got

    def close(self) -> None:
        """End the reader processes (idempotent)."""
        with self.cond:
            slots, self._slots = self._slots, []
            self._wanted.clear()
            self.live.clear()
            self.results.clear()
        for r in slots:
            r.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - at interpreter exit
            pass

    # -- with self.cond held ------------------------------------------------------------------

    def _restart(self, at: int) -> None:
        """Read ahead from ``order[at]`` on; answers to what was asked before are dropped."""
        self._wanted.clear()
        self.live.clear()
        self.results.clear()
        self._next = at

    def _fill(self) -> None:
        while len(self._wanted) < self.depth and self._next < len(self.order):
            reader = self._reader()
            if reader is None:  # given up: read in the calling process
                return
            k = self.order[self._next]
            self._next += 1
            serial = next(self._serials)
            self._wanted.append((serial, k))
            self.live.add(serial)
            self._kind[serial] = k
            reader.ask(serial, self.entries[k], self.options)

    def _reader(self) -> _Reader | None:
        """The reader to ask next (started when fewer are running than asked for), or None
        when a reader process could not be started (then none is used from now on)."""
        if len(self._slots) < self.readers:
            r = self._start()
            if r is not None:
                self._slots.append(r)
            return r
        return min(self._slots, key=lambda r: len(r.asked)) if self._slots else None

    def _start(self) -> _Reader | None:
        try:
            return _Reader(self)
        except OSError as exc:  # no interpreter to run, too many processes
            self._give_up(f"the reader processes could not start ({exc})")
            return None

    def _give_up(self, why: str) -> None:
        """Read in the calling process from now on, and say why."""
        self.notes.append(f"{why}: the files were read in this process")
        self.readers = 0
        for other in self._slots:
            other.close(join=False)
        self._slots = []
        self._restart(len(self.order))

    def _revive(self, r: _Reader) -> None:
        """Replace the dead reader ``r``: the field it was reading is read again by its
        successor, unless it took a reader down before (then it is refused); the others it
        was asked for follow."""
        asked = list(r.asked)
        rc = r.close(join=False)
        if not r.ready:  # not a file's doing: it died before it could read one
            self._fruitless += 1
            if self._fruitless >= 2:
                self._give_up(f"the reader processes ended as they started (exit code {rc}, "
                              "twice)")  # fmt: skip
                return
        new = self._start()
        if new is None:
            return
        self._slots[self._slots.index(r)] = new
        if asked and r.ready:
            first = asked[0]
            k = self._kind.get(first, -1)
            self._deaths[k] = self._deaths.get(k, 0) + 1
            if self._deaths[k] >= 2:
                asked = asked[1:]
                if first in self.live:
                    self.results[first] = InvalidInputError(
                        f"{entry_name(self.entries[k])}: the reader process died reading it "
                        f"twice (exit code {rc}): a file that crashes its reading library"
                    )
        for serial in asked:
            if serial in self.live:
                new.ask(serial, self.entries[self._kind[serial]], self.options)
