"""Checks shared by the methods: results in range, and the numba thread count for a call.

Imports aobake's ``errors`` only (numba inside :func:`numba_threads`).
"""

from __future__ import annotations

from contextlib import contextmanager

from .errors import NumericalError


def check_result(values, what: str, *, lower: float, upper: float, method: str) -> None:
    """Raise :class:`NumericalError` naming ``method`` unless every value is finite and in
    ``[lower, upper]`` (the first bad row is named: vertex and value)."""
    import numpy as np

    bad = ~np.isfinite(values) | (values < lower) | (values > upper)
    if bad.any():
        flat = int(np.flatnonzero(bad)[0])
        first = np.unravel_index(flat, values.shape)[0]
        raise NumericalError(
            f"{method}: {int(bad.sum())} values of {what} outside [{lower}, {upper}] "
            "or non-finite "
            f"(first: vertex {int(first)}, value {float(values.flat[flat])!r})"
        )


@contextmanager
def numba_threads(threads: int | None):
    """Run the body with ``numba.set_num_threads(threads)``, then restore the old count;
    None keeps the current setting. ``ValueError`` beyond numba's thread pool."""
    if threads is None:
        yield
        return
    import numba

    top = numba.config.NUMBA_NUM_THREADS
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= top:
        raise ValueError(f"threads must be an integer in [1, {top}] or None, got {threads!r}")
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(old)
