"""A small progress display on stderr for long jobs (the application's side of
:mod:`scheimpflug.callbacks`: a :class:`Progress` is a ``progress(done, total)``
callback).

Shows ``label  [#####     ] 123/720  4.2 it/s  ETA 0:02:10`` on a terminal,
redrawn in place; when stderr is not a terminal (CI, logs) it prints a plain
line at most every ``log_every_s`` seconds and at the end.  ``quiet=True``
silences it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

__all__ = ["Progress", "progress"]

T = TypeVar("T")


def _fmt_seconds(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Progress:
    """Progress of ``total`` steps of one job; call :meth:`update` per step."""

    def __init__(self, total: int, label: str = "", quiet: bool = False,
                 stream=None, log_every_s: float = 5.0) -> None:
        self.total = max(int(total), 0)
        self.label = label
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.log_every_s = log_every_s
        self.done = 0
        self.t0 = time.perf_counter()
        self._last = -1e9

    def __call__(self, done: int, total: int) -> None:
        """The library's callback convention: ``done`` of ``total`` steps finished."""
        self.total = max(int(total), 0)
        self.update(int(done) - self.done)

    def update(self, n: int = 1) -> None:
        """Count ``n`` more finished steps and redraw when due."""
        self.done += n
        now = time.perf_counter()
        if self.quiet:
            return
        if self.tty and now - self._last > 0.1 or not self.tty and now - self._last > self.log_every_s:
            self._last = now
            self._draw(final=False)

    def close(self) -> None:
        """Draw the final line (unless quiet)."""
        if not self.quiet:
            self._draw(final=True)

    def _draw(self, final: bool) -> None:
        dt = time.perf_counter() - self.t0
        rate = self.done / dt if dt > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else 0.0
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(20 * frac) + " " * (20 - int(20 * frac))
        tail = f"{_fmt_seconds(dt)} total" if final else f"ETA {_fmt_seconds(eta)}"
        line = f"{self.label:<14s} [{bar}] {self.done}/{self.total}  {rate:6.1f} it/s  {tail}"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if final else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def progress(items: Iterable[T], total: int | None = None, label: str = "",
             quiet: bool = False) -> Iterator[T]:
    """Iterate over ``items`` showing a :class:`Progress` bar."""
    if total is None:
        total = len(items)  # type: ignore[arg-type]
    with Progress(total, label=label, quiet=quiet) as bar:
        for item in items:
            yield item
            bar.update()
