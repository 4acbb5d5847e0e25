"""Ambient occlusion fields (Kontkanen & Laine 2005): fit one around a rigid occluder,
save it, and evaluate it at receivers anywhere the occluder is placed.

Modules: ``options`` (what a user chooses), ``fit`` (layout, samplers, per-texel fits),
``layout`` (cube map, hull distances, radial samples), ``raster`` and ``rays`` (the two
samplers), ``field`` (the fitted field as data), ``evaluate`` (lookups at receivers),
``fileformat`` (the ``.npz`` format). Importing this package loads only its options;
the rest (numpy, numba, embreex) loads on first use. Never imports another method.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", Proc. I3D 2005, 41-48.
"""

from __future__ import annotations

import importlib

from .options import FieldOptions

__all__ = [
    "AOField",
    "FieldAO",
    "FieldOptions",
    "cap_integral",
    "embree_occlusion",
    "field_ao",
    "fields_ao",
    "fit_field",
    "hull_distance",
    "load_field",
    "raster_occlusion",
    "rigid_transform",
    "save_field",
    "surface_centre",
]

# public name -> the module that defines it
_HOMES = {
    "AOField": "field",
    "FieldAO": "evaluate",
    "cap_integral": "evaluate",
    "embree_occlusion": "rays",
    "field_ao": "evaluate",
    "fields_ao": "evaluate",
    "fit_field": "fit",
    "hull_distance": "layout",
    "load_field": "fileformat",
    "raster_occlusion": "raster",
    "rigid_transform": "evaluate",
    "save_field": "fileformat",
    "surface_centre": "layout",
}


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
