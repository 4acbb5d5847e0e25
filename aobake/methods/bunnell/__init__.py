"""Bunnell's disk method: oriented disks per vertex, a cluster tree, occlusion passes; no rays.

``elements`` (the disks), ``tree`` (the cluster tree), ``passes`` (the sums per pass),
``scheme`` (the pass scheme's switches and how passes combine), ``estimator`` (the entry
points). Importing this package loads only its options; numpy and the kernels load on
first use.
"""

from __future__ import annotations

from ...lazy import exports
from .options import BunnellOptions

__all__ = ["BunnellOptions", "LitScene", "bunnell_ao", "disk_light", "prepare_light", "run", "run_light"]  # the rest: for tests, the bench, animation

# public and test-facing names -> the module that defines them
_LAZY = {
    "bunnell_ao": "estimator",
    "run": "estimator",
    "estimate": "estimator",
    "variant_ao": "estimator",
    "DiskElements": "elements",
    "build_elements": "elements",
    "ClusterTree": "tree",
    "refit_tree": "tree",
    "Scheme": "scheme",
    "build_tree": "passes",
    "combine_passes": "scheme",
    "combine_sides": "scheme",
    "occlusion_passes": "passes",
    "settings": "scheme",
    "run_light": "light",
    "disk_light": "light",
    "prepare_light": "light",
    "LitScene": "light",
    "emitter_disks": "light",
}


__getattr__ = exports(__name__, _LAZY)
