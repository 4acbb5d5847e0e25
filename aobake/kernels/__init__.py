"""Every @njit function of aobake lives in this package, and nowhere else.

Rules: kernels take arrays and scalars only (no None, no Python objects), at most ~8
arguments; they import numpy, numba and ``aobake.constants`` only; decorate with
``@njit(cache=True, error_model="numpy")``; ``parallel=True`` only on
outer per-element loops; never ``np.random`` (use ``rng.py``). Numpy-facing wrappers in
the parent package validate, coerce dtypes once and call these.
"""
