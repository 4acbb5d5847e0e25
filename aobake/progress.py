"""Progress reporting: library code calls ``progress.advance(n)``; the CLI picks the bar.

A bar is drawn on stderr only when stderr is a terminal and ``--quiet`` is off, so logs
and CI output stay clean. ``advance`` is also where an interrupt that was swallowed is
raised again (:func:`install_interrupt_handler`). Imports only the standard library.
"""

from __future__ import annotations

import signal
import sys
import time
from typing import Protocol, TextIO

_interrupted = False
_previous_hook = sys.unraisablehook  # what install_interrupt_handler's hook defers to


def _on_sigint(signum, frame):
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def install_interrupt_handler() -> None:
    """Ctrl-C raises KeyboardInterrupt as usual and is also remembered, so that every
    later ``advance`` raises it again. A KeyboardInterrupt raised inside a C callback is
    printed with a traceback and dropped by Python ("Exception ignored on calling ctypes
    callback"): numba's compiler calls back into Python, and an aobake interrupted while
    it compiled kernels (a cold cache) went on to the end. That message is silenced for
    interrupts (``sys.unraisablehook``). Main thread only (the CLI); library code that
    never calls this is unaffected."""
    global _interrupted, _previous_hook
    _interrupted = False
    signal.signal(signal.SIGINT, _on_sigint)
    if sys.unraisablehook is not _drop_interrupts:
        _previous_hook = sys.unraisablehook
        sys.unraisablehook = _drop_interrupts


def _drop_interrupts(unraisable) -> None:
    """An interrupt dropped in a C callback is remembered (:func:`check_interrupt`), not
    printed with its traceback; anything else goes to the previous hook."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        return
    _previous_hook(unraisable)


def interrupted() -> bool:
    """Whether Ctrl-C came since :func:`install_interrupt_handler`."""
    return _interrupted


def check_interrupt() -> None:
    """Raise KeyboardInterrupt if Ctrl-C came since :func:`install_interrupt_handler`."""
    if _interrupted:
        raise KeyboardInterrupt


class Progress(Protocol):
    """What library functions may call on a progress object."""

    def start(self, total: int, label: str) -> None: ...
    def advance(self, n: int) -> None: ...
    def finish(self) -> None: ...


class NullProgress:
    """Reports nothing (the library default)."""

    def start(self, total: int, label: str) -> None:
        pass

    def advance(self, n: int) -> None:
        check_interrupt()

    def finish(self) -> None:
        pass


class StderrProgress:
    """A one-line bar redrawn on a terminal at most ten times a second."""

    def __init__(self, stream: TextIO | None = None, width: int = 30):
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.total = 0
        self.done = 0
        self.label = ""
        self.t0 = 0.0
        self._last = 0.0

    def start(self, total: int, label: str) -> None:
        self.total = max(int(total), 1)
        self.done = 0
        self.label = label
        self.t0 = self._last = time.perf_counter()
        self._draw()

    def advance(self, n: int) -> None:
        check_interrupt()
        self.done = min(self.done + int(n), self.total)
        now = time.perf_counter()
        if now - self._last >= 0.1 or self.done == self.total:
            self._last = now
            self._draw()

    def finish(self) -> None:
        self.done = self.total
        self._draw()
        self.stream.write("\n")
        self.stream.flush()

    def _draw(self) -> None:
        frac = self.done / self.total
        filled = int(frac * self.width)
        elapsed = time.perf_counter() - self.t0
        eta = elapsed * (1.0 - frac) / frac if frac > 0 else 0.0
        bar = "#" * filled + "-" * (self.width - filled)
        self.stream.write(
            f"\r{self.label} [{bar}] {100 * frac:5.1f}% {elapsed:6.1f}s eta {eta:5.1f}s"
        )
        self.stream.flush()


def make_progress(quiet: bool, stream: TextIO | None = None) -> Progress:
    """A bar on stderr when it is a terminal and not ``quiet``, else :class:`NullProgress`."""
    stream = sys.stderr if stream is None else stream
    if quiet or not getattr(stream, "isatty", lambda: False)():
        return NullProgress()
    return StderrProgress(stream)


class NullBatchBar:
    """Draws nothing (``aobake batch --quiet``, no terminal, Python callers)."""

    def start(self, total: int) -> None:
        pass

    def update(self, done: int, failed: int, skipped: int) -> None:
        pass

    def finish(self) -> None:
        pass


class BatchBar:
    """A one-line bar over the inputs of a batch: done / failed / skipped and ETA (from the
    rate of inputs baked this run), redrawn at most ten times a second."""

    def __init__(self, stream: TextIO | None = None, width: int = 30):
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.total = 1
        self.counts = (0, 0, 0)
        self.t0 = self._last = 0.0

    def start(self, total: int) -> None:
        self.total = max(int(total), 1)
        self.t0 = time.perf_counter()
        self._last = 0.0

    def update(self, done: int, failed: int, skipped: int) -> None:
        self.counts = (done, failed, skipped)
        now = time.perf_counter()
        if now - self._last >= 0.1 or sum(self.counts) == self.total:
            self._last = now
            self._draw()

    def finish(self) -> None:
        self._draw()
        self.stream.write("\n")
        self.stream.flush()

    def text(self) -> str:
        done, failed, skipped = self.counts
        finished = done + failed + skipped
        elapsed = time.perf_counter() - self.t0
        baked = done + failed
        left = self.total - finished
        eta = elapsed * left / baked if baked else float("nan")
        filled = int(self.width * finished / self.total)
        bar = "#" * filled + "-" * (self.width - filled)
        eta_text = f"{eta:6.1f}s" if eta == eta else "     ?"
        return (
            f"batch [{bar}] {finished}/{self.total}: {done} done, {failed} failed, {skipped} skipped,"
            f" {elapsed:6.1f}s eta {eta_text}"
        )

    def _draw(self) -> None:
        self.stream.write("\r" + self.text())
        self.stream.flush()


def make_batch_bar(quiet: bool, stream: TextIO | None = None):
    """A :class:`BatchBar` on stderr when it is a terminal and not ``quiet``, else none."""
    stream = sys.stderr if stream is None else stream
    if quiet or not getattr(stream, "isatty", lambda: False)():
        return NullBatchBar()
    return BatchBar(stream)
