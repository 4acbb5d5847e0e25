"""Checks shared by the methods: results in range, and the numba thread count for a call.

Imports aobake's ``errors`` only (numba inside :func:`numba_threads`).
"""

from __future__ import annotations

from contextlib import contextmanager

from .constants import SERIAL_VERTICES
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


def mesh_threads(threads: int | None, n_vertices: int) -> int | None:
    """``threads`` for a mesh of ``n_vertices``: one where none is named and the mesh is
    small (``SERIAL_VERTICES``: waking the pool costs more than it saves), else as given."""
    return 1 if threads is None and n_vertices <= SERIAL_VERTICES else threads


@contextmanager
def numba_threads(threads: int | None):
    """Run the body with ``numba.set_num_threads(threads)``, then restore the old count;
    None keeps the current setting. More threads than numba's pool (the core count) run as
    the pool: results do not depend on the count, as with ``--threads`` on the CLI."""
    if threads is None:
        yield
        return
    import numba

    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be an integer >= 1 or None, got {threads!r}")
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        numba.set_num_threads(old)
