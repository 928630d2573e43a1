"""Progress reporting for long runs: a rich progress bar on a terminal, plain log lines otherwise.

:class:`Progress` is a context manager with :meth:`Progress.advance` and :meth:`Progress.log`.
On a terminal (``stream.isatty()``) it draws a rich bar (pairs done, rate, time left) and prints
log messages above it; elsewhere (batch jobs, pipes, CI) it writes one line per message and a
status line at most every ``interval`` seconds::

    [rspiv] 120/34535 pairs (2 skipped), 3.4 pairs/min, ETA 10:09:31

``enabled=False`` silences everything (library use).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


def _fmt_eta(seconds: float) -> str:
    if not seconds == seconds or seconds == float("inf"):
        return "--:--:--"
    s = int(round(seconds))
    return f"{s // 3600:d}:{(s // 60) % 60:02d}:{s % 60:02d}"


class Progress:
    """Progress of ``total`` items.

    Parameters
    ----------
    total : int
        Items to do in this run (already finished ones excluded).
    description : str
        Label of the bar / prefix of the lines.
    stream : file, optional
        Where to write (default ``sys.stderr``).
    enabled : bool
        False: no output at all.
    interval : float
        Seconds between status lines when not on a terminal.
    rich : bool, optional
        Force (True) or forbid (False) the rich bar; default: when ``stream`` is a terminal.
    """

    def __init__(
        self,
        total: int,
        description: str = "pairs",
        *,
        stream: TextIO | None = None,
        enabled: bool = True,
        interval: float = 10.0,
        rich: bool | None = None,
    ) -> None:
        self.total = int(total)
        self.description = description
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.interval = float(interval)
        self.done = 0
        self.skipped = 0
        self._t0 = time.monotonic()
        self._last = self._t0
        if rich is None:
            rich = bool(getattr(self.stream, "isatty", lambda: False)())
        self._use_rich = enabled and rich
        self._bar = None
        self._task = None

    # ------------------------------------------------------------------ context
    def __enter__(self) -> Progress:
        if self._use_rich:
            try:
                from rich.console import Console
                from rich.progress import (
                    BarColumn,
                    MofNCompleteColumn,
                    TextColumn,
                    TimeElapsedColumn,
                    TimeRemainingColumn,
                )
                from rich.progress import Progress as RichProgress
            except ImportError:  # pragma: no cover - rich is a dependency
                self._use_rich = False
            else:
                self._bar = RichProgress(
                    TextColumn("[bold]{task.description}"),
                    BarColumn(),
                    MofNCompleteColumn(),
                    TextColumn("{task.fields[rate]}"),
                    TimeElapsedColumn(),
                    TimeRemainingColumn(),
                    console=Console(file=self.stream),
                    transient=False,
                )
                self._bar.start()
                self._task = self._bar.add_task(self.description, total=self.total, rate="")
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
        elif self.enabled and self.total:
            self._line(final=True)

    # ------------------------------------------------------------------ API
    @property
    def rate_per_min(self) -> float:
        """Items per minute so far."""
        dt = time.monotonic() - self._t0
        return 60.0 * self.done / dt if dt > 0 else 0.0

    def advance(self, n: int = 1, *, skipped: bool = False) -> None:
        """Count ``n`` items as done (``skipped``: they were skipped, still done)."""
        self.done += n
        if skipped:
            self.skipped += n
        if not self.enabled:
            return
        if self._bar is not None:
            rate = f"{self.rate_per_min:.1f}/min" + (
                f", {self.skipped} skipped" if self.skipped else ""
            )
            self._bar.update(self._task, advance=n, rate=rate)
            return
        now = time.monotonic()
        if now - self._last >= self.interval or self.done == self.total:
            self._line()
            self._last = now

    def extend(self, n: int) -> None:
        """Add ``n`` items to the total (work found to be needed while running)."""
        self.total += int(n)
        if self._bar is not None:
            self._bar.update(self._task, total=self.total)

    def log(self, message: str) -> None:
        """Print a message (above the bar on a terminal)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.console.print(message, markup=False, highlight=False)
        else:
            print(f"[rspiv] {message}", file=self.stream, flush=True)

    def _line(self, final: bool = False) -> None:
        rate = self.rate_per_min
        left = self.total - self.done
        eta = 60.0 * left / rate if rate > 0 else float("inf")
        skipped = f" ({self.skipped} skipped)" if self.skipped else ""
        tail = "done" if final and left == 0 else f"ETA {_fmt_eta(eta)}"
        print(
            f"[rspiv] {self.description}: {self.done}/{self.total}{skipped}, "
            f"{rate:.1f}/min, {tail}",
            file=self.stream,
            flush=True,
        )
