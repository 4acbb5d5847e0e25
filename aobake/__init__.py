"""aobake: bake per-vertex ambient occlusion into meshes.

``ao`` is always accessibility 1 - A (1 = fully open), the factor renderers multiply by.
Importing the package is cheap: numpy, numba, trimesh, embreex and pxr load only when a
function that needs them is first used.
"""

from __future__ import annotations

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


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'aobake' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
