"""Monte Carlo ambient occlusion by ray casting with Embree: the reference method.

Importing this package loads only its options; the estimator (numpy, numba, embreex)
loads on first use.
"""

from __future__ import annotations

from .options import EmbreeOptions

__all__ = ["EmbreeAO", "EmbreeOptions", "embree_ao", "run"]


def __getattr__(name: str):
    if name in ("EmbreeAO", "embree_ao", "run", "estimate"):
        from . import estimator

        return getattr(estimator, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
