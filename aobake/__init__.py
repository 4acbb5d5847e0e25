"""aobake: bake per-vertex ambient occlusion into meshes.

``ao`` is always accessibility 1 - A (1 = fully open), the factor renderers multiply by.
Importing the package is cheap: numpy, numba, trimesh, embreex and pxr load only when a
function that needs them is first used.
"""

from __future__ import annotations

from .lazy import exports

__version__ = "0.1.0"

__all__ = [
    "bake",
    "bake_file",
    "load_mesh",
    "embree_ao",
    "bunnell_ao",
    "write_ply",
    "write_usd",
    "write_bake",
    "__version__",
]

_LAZY = {
    "bake": "pipeline",
    "bake_file": "pipeline",
    "load_mesh": "io",
    "embree_ao": "methods.embree",
    "bunnell_ao": "methods.bunnell",
    "write_ply": "io",
    "write_usd": "io",
    "write_bake": "io",
}


__getattr__ = exports(__name__, _LAZY)
