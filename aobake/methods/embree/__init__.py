"""Monte Carlo ambient occlusion (and irradiance: :mod:`.light`) by ray casting with
Embree: the reference method.

Importing this package loads only its options; the estimator (numpy, numba, embreex)
loads on first use.
"""

from __future__ import annotations

from ...lazy import exports
from .options import EmbreeOptions, LightOptions

__all__ = ["EmbreeAO", "EmbreeOptions", "LightOptions", "LightResult", "embree_ao", "irradiance", "run", "run_light"]

__getattr__ = exports(
    __name__,
    {
        **{name: "estimator" for name in ("EmbreeAO", "embree_ao", "run", "estimate")},
        **{name: "light" for name in ("irradiance", "run_light", "LightResult", "LightStats")},
    },
)
