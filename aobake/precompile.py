"""Compiling on both cores: a cold run's largest kernel compiles in a helper process.

numba compiles one kernel at a time, in one thread, so a first run leaves every other core
idle. When a command that will need a large kernel finds it missing from numba's cache,
:func:`start` runs ``python -m aobake.precompile TARGET`` in the background: the helper
compiles that kernel (and what it calls) for the exact argument types the command will
pass, into the same cache, while the command compiles everything else. When the command
reaches the kernel, :func:`wait` waits for the helper (not compiling it a second time) and
numba loads the kernel from the cache. A helper that fails, or has not finished after
:data:`WAIT_LIMIT` seconds, only costs the time waited: the command then compiles the
kernel itself. The helper ends with the command (it watches its stdin, a pipe from the
command: closed when the command ends, however it ends), and Ctrl-C ends it at once.

Off unless enabled (:func:`enabled`: the CLI's ``bake``): library calls start no
processes. Targets are named in :data:`TARGETS`; each names a function returning the
kernel's dispatcher and a tuple of arguments of the types the command will pass. The
cache is safe to share: numba writes each index and data file to a temporary name and
renames it, and the helper's kernels are ones the command does not compile meanwhile
(docs/first-run.md). Standard library only at import.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib
import os
import sys
import time

#: name -> "module:function" returning (numba dispatcher, example arguments)
TARGETS = {
    "tree-pass": "aobake.methods.bunnell.passes:first_pass_kernel",
    "field-fit": "aobake.methods.fields.fit:fit_kernel",
}

#: Seconds the command waits for a helper still running before compiling itself (a
#: helper compiles the tree pass in ~20 s on an idle 2-core machine, ~150 s under load).
WAIT_LIMIT = 600.0

_enabled = False
_helpers: dict = {}  # target -> subprocess.Popen
_registered = False  # stop_all is an atexit function


def enable(on: bool = True) -> None:
    """Let :func:`start` run helpers in this process (or not)."""
    global _enabled
    _enabled = bool(on)


@contextlib.contextmanager
def enabled():
    """Helpers allowed inside the block (the CLI's ``bake``); any still running at its end
    are ended."""
    before = _enabled
    enable()
    try:
        yield
    finally:
        enable(before)
        stop_all()


def kernel_signature(target: str):
    """``(dispatcher, signature)`` of ``target``: numba's types of its example arguments."""
    import numba

    module, name = TARGETS[target].split(":")
    dispatcher, args = getattr(importlib.import_module(module), name)()
    return dispatcher, tuple(numba.typeof(a) for a in args)


def is_cached(target: str) -> bool | None:
    """Whether numba's cache holds ``target`` for this machine and source (a look at its
    index; nothing is loaded). None when it cannot tell (no cache, another numba)."""
    try:
        dispatcher, sig = kernel_signature(target)
        cache = dispatcher._cache
        index = cache._cache_file._load_index()
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
    except Exception:  # numba's private cache API moved: no helpers
        return None
    return key in index


def start(target: str, *, threads: int | None = None, command: list[str] | None = None) -> bool:
    """Start a helper compiling ``target`` unless helpers are off, one is running, this
    machine has one core or the command may use one (``threads``, as ``--threads``), or
    the kernel is cached (or the cache cannot be read). True when one was started.
    ``command``: the helper's command line (tests)."""
    cores = os.cpu_count() or 1
    if not _enabled or target in _helpers or min(cores, cores if threads is None else threads) < 2:
        return False
    if command is None and is_cached(target) is not False:
        return False
    import subprocess

    if command is None:
        command = [sys.executable, "-m", "aobake.precompile", target]
    env = dict(os.environ)
    # the helper imports this very aobake: numba keys its cache on the source files
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    try:
        _helpers[target] = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
        )  # fmt: skip
    except OSError:
        return False
    global _registered
    if not _registered:
        _registered = True
        atexit.register(stop_all)
    return True


def wait(target: str, limit: float | None = None) -> bool:
    """Before the command calls ``target``'s kernel: wait for its helper (if one runs), at
    most ``limit`` seconds (:data:`WAIT_LIMIT`). The wait counts as compiling (numba's
    ``numba:compile`` event: :class:`aobake.progress.CompileWatch` sees it). True when a
    helper finished successfully; else the command compiles the kernel itself."""
    proc = _helpers.pop(target, None)
    if proc is None:
        return False
    limit = WAIT_LIMIT if limit is None else limit
    code = None
    try:
        code = proc.poll()
        if code is None:
            code = _wait_as_compile(target, proc, limit)
    finally:
        _end(proc)
    return code == 0


def _wait_as_compile(target: str, proc, limit: float):
    """``proc``'s exit code (None after ``limit`` seconds), inside a ``numba:compile``
    event for ``target``'s kernel."""
    import subprocess

    from numba.core import event

    try:
        dispatcher, sig = kernel_signature(target)
    except Exception:
        dispatcher, sig = None, ()
    data = {"dispatcher": dispatcher, "args": sig, "return_type": None}
    with event.trigger_event("numba:compile", data=data):
        try:
            return proc.wait(timeout=limit)
        except subprocess.TimeoutExpired:
            return None


def _end(proc) -> None:
    """Kill ``proc`` if it still runs, and reap it (no zombie)."""
    try:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    finally:
        if proc.stdin is not None:
            proc.stdin.close()


def stop_all() -> None:
    """End every helper still running (at exit, after an interrupt or an error)."""
    while _helpers:
        _end(_helpers.popitem()[1])


def fixed_mmap_threshold() -> None:
    """Have glibc's malloc map every block over 4 MiB on its own and unmap it when freed.
    By default the threshold rises to the largest block freed (up to 32 MiB), so a
    mesh's freed temporaries stay in the heap and the peak memory of a large bake grows
    by ~15 bytes per vertex. 4 MiB, not less: numba's compiler allocates many blocks of
    hundreds of KiB, and mapping each made a cold compile 1.5x slower (docs/process.md).
    Linux with glibc only; elsewhere nothing happens. The CLI and the helpers call it."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(-3, 4 << 20)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass


def _watch_parent() -> None:
    """In the helper: end the process when stdin (the command's pipe) closes."""
    import threading

    def watch():
        try:
            while sys.stdin.buffer.read(1 << 16):
                pass
        except (OSError, ValueError):
            pass
        os._exit(3)

    threading.Thread(target=watch, daemon=True).start()


def main(argv: list[str] | None = None) -> None:
    """The helper: compile each target named in ``argv`` into numba's cache, then end the
    process at once (0: compiled, 1: failed; :func:`_watch_parent`'s thread still reads)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)  # Ctrl-C ends it at once (files are renamed whole)
    _watch_parent()
    fixed_mmap_threshold()  # as the command compiles
    code = 1
    try:
        for target in sys.argv[1:] if argv is None else argv:
            dispatcher, sig = kernel_signature(target)
            t0 = time.perf_counter()
            dispatcher.compile(sig)
            sys.stderr.write(f"{target}: compiled in {time.perf_counter() - t0:.1f} s\n")
        code = 0
    except Exception:
        import traceback

        traceback.print_exc()
    finally:
        sys.stderr.flush()
        os._exit(code)


if __name__ == "__main__":
    main()
