"""Every @njit function of aobake lives in this package, and nowhere else.

Rules: kernels take arrays and scalars only (no None, no Python objects), at most ~8
arguments; they import numpy, numba and ``aobake.constants`` only; decorate with
``@njit(cache=True, error_model="numpy")``; ``parallel=True`` only on
outer per-element loops; never ``np.random`` (use ``rng.py``). Numpy-facing wrappers in
the parent package validate, coerce dtypes once and call these.
"""

from __future__ import annotations


def _blas_known_without_scipy() -> None:
    """Let numba learn that scipy's BLAS exists without importing scipy.

    numba's ``arraymath`` (loaded before the first kernel, cached or not) imports
    ``scipy.linalg`` only to decide whether ``np.dot`` may call BLAS: ~0.2 s of every
    process, and no kernel here uses BLAS. Where ``scipy/linalg/cython_blas`` is
    installed, that check is answered yes without the import (numba's answer too); BLAS
    itself still loads scipy when some kernel needs it. Anything unexpected: numba's
    own check."""
    import importlib.util
    import sys
    from pathlib import Path

    if "numba.np.arraymath" in sys.modules:
        return
    try:
        spec = importlib.util.find_spec("scipy")
        from numba.np import linalg
    except (ImportError, ValueError):
        return
    dirs = (spec.submodule_search_locations or []) if spec is not None else []
    if not callable(getattr(linalg, "ensure_blas", None)) or not any(
        any(Path(d, "linalg").glob("cython_blas.*")) for d in dirs
    ):
        return
    real = linalg.ensure_blas
    linalg.ensure_blas = lambda: None
    try:
        from numba.np import arraymath
    finally:
        linalg.ensure_blas = real
    if getattr(arraymath, "ensure_blas", None) is not None:
        arraymath.ensure_blas = real


_blas_known_without_scipy()
