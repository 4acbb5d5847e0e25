"""Progress reporting: library code calls ``progress.advance(n)``; the CLI picks the bar.

A bar is drawn on stderr only when stderr is a terminal and ``--quiet`` is off, so logs
and CI output stay clean. ``advance`` is also where an interrupt that was swallowed is
raised again (:func:`install_interrupt_handler`). :class:`CompileWatch` notes numba
compiling kernels (a cold cache: the first run). Imports only the standard library
(numba when a CompileWatch starts).
"""

from __future__ import annotations

import signal
import sys
import time
from typing import Protocol, TextIO

_interrupted = 0  # the signal number of the last interrupt, 0 for none
_previous_hook = sys.unraisablehook  # what install_interrupt_handler's hook defers to


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so every cleanup (temporary files) runs."""


def _on_sigint(signum, frame):
    global _interrupted
    _interrupted = signum
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def install_interrupt_handler() -> None:
    """Ctrl-C raises KeyboardInterrupt as usual (SIGTERM: :class:`Terminated`) and is also remembered, so that every
    later ``advance`` raises it again. A KeyboardInterrupt raised inside a C callback is
    printed with a traceback and dropped by Python ("Exception ignored on calling ctypes
    callback"): numba's compiler calls back into Python, and an aobake interrupted while
    it compiled kernels (a cold cache) went on to the end. That message is silenced for
    interrupts (``sys.unraisablehook``). Main thread only (the CLI); library code that
    never calls this is unaffected."""
    global _interrupted, _previous_hook
    _interrupted = 0
    signal.signal(signal.SIGINT, _on_sigint)
    signal.signal(signal.SIGTERM, _on_sigint)  # a kill is an interrupt: cleanup runs
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
    return bool(_interrupted)


def check_interrupt() -> None:
    """Raise KeyboardInterrupt if Ctrl-C came since :func:`install_interrupt_handler`."""
    if _interrupted:
        raise Terminated if _interrupted == signal.SIGTERM else KeyboardInterrupt


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


COMPILING = "compiling kernels (first run only) ..."


class CompileWatch:
    """While active (``with``), notes numba compiling kernels: a cache miss, so the first
    run or a new kind of input. ``seconds`` is the wall time spent compiling (a kernel's
    callees compiled on the way count once, in its time), ``count`` the
    specialisations compiled. With a ``stream``, says :data:`COMPILING` there once, when
    the first compile starts. Timers subtract ``seconds`` to keep compiling out of
    reported times; watches nest (each registers its own numba listener)."""

    def __init__(self, stream: TextIO | None = None):
        self.stream = stream
        self.seconds = 0.0
        self.count = 0
        self._depth = 0
        self._t0 = 0.0
        self._said = False
        self._listener = None

    def _start(self) -> None:
        if self._depth == 0:
            self._t0 = time.perf_counter()
            self._say()
        self._depth += 1
        self.count += 1

    def _end(self) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._t0

    def _say(self) -> None:
        if self.stream is None or self._said:
            return
        self._said = True
        # on a terminal a progress bar may be drawn on this line: clear it first
        clear = "\r\x1b[K" if getattr(self.stream, "isatty", lambda: False)() else ""
        self.stream.write(f"{clear}{COMPILING}\n")
        self.stream.flush()

    def __enter__(self) -> CompileWatch:
        from numba.core import event  # numba compiles under one lock: events never overlap

        watch = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                watch._start()

            def on_end(self, ev):
                watch._end()

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        self._listener = None
        if self._depth:  # left while compiling (an interrupt): count it up to now
            self.seconds += time.perf_counter() - self._t0
            self._depth = 0


def compile_note(seconds: float) -> str:
    """The summary's mention of compile time, "" when nothing compiled."""
    return f" (+ {seconds:.1f} s compiling kernels, first run only)" if seconds > 0 else ""


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
