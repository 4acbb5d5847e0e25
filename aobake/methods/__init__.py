"""The AO methods behind one small interface, and the registry that finds them by name.

Each method is a sub-package ``aobake.methods.<name>`` with a light ``options`` module
(a frozen dataclass of :func:`aobake.options.option` fields: the single home of its
defaults and help text) and a ``run(surface, options, progress) -> MethodResult``.
Methods never import each other. This module loads a method only when it is asked for.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

#: What ``bake --method`` takes, in the order ``--help`` lists them.
METHODS = ("embree", "bunnell")

#: Methods whose vertices are baked independently: ``run`` takes ``vertices=(lo, hi)``
#: and a mesh may be baked in pieces (``aobake batch --split``). Bunnell's passes and
#: cluster tree couple every vertex.
SPLITTABLE = ("embree",)

#: Methods that trace the whole surface through one Embree scene
#: (``tracing.tracer_for(surface.positions, surface.faces)``): a bake may start building
#: it before they run (:func:`aobake.tracing.start_scene`).
WHOLE_SCENE = ("embree",)

#: Methods that compute a lit scene's light (direct and bounced) besides AO:
#: ``run_light(surface, shading, options, progress, indirect=...)``.
LIGHTING = ("embree", "bunnell")


@dataclass(frozen=True)
class MethodResult:
    """What every method returns.

    Attributes
    ----------
    ao : (n,) float64 in [0, 1]
        Accessibility 1 - A per input vertex, in input order.
    n_rays : int
        Rays cast in total (0 for methods that cast none).
    contacts : int
        Vertices whose starting point was moved off a touching surface.
    attributes : dict of str to array
        Extra per-vertex results to write beside ``ao`` (``bentNormal`` (n, 3)), one row
        per vertex baked (:func:`aobake.io.write_bake`).
    """

    ao: Any
    n_rays: int = 0
    contacts: int = 0
    attributes: Any = None


def _check_name(name: str) -> None:
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}")


def options_class(name: str) -> type:
    """The options dataclass of method ``name`` (imports only its light options module)."""
    _check_name(name)
    module = importlib.import_module(f"{__name__}.{name}.options")
    return module.OPTIONS


def make_options(name: str, options=None, **changes):
    """Options of method ``name``: from an instance, a dict and/or keywords, validated."""
    from ..options import build

    return build(options_class(name), options, **changes)


def run(name: str, surface, options=None, progress=None, *, vertices=None, ground=None, **changes) -> MethodResult:
    """Bake ``surface`` with method ``name``; ``options`` as :func:`make_options` takes them.

    ``vertices=(lo, hi)``: bake only those vertices (methods in :data:`SPLITTABLE`);
    the result then holds hi - lo values. ``ground``: an :class:`aobake.ground.Ground`
    every method counts as one more occluder (None: none)."""
    from ..mesh import check_extent

    opts = make_options(name, options, **changes)
    check_extent(surface.positions, surface.source)  # every vertex at one point: no AO
    module = importlib.import_module(f"{__name__}.{name}")
    extra = {} if ground is None else {"ground": ground}
    if vertices is None:
        return module.run(surface, opts, progress, **extra)
    if name not in SPLITTABLE:
        raise ValueError(f"{name} couples all vertices and cannot bake a vertex range")
    return module.run(surface, opts, progress, vertices=vertices, **extra)


def run_light(
    name: str, surface, shading, options=None, progress=None, *, indirect: bool = True, ground=None, **changes
):
    """Irradiance of ``surface`` lit by ``shading`` (:class:`aobake.shading.Shading`) with
    method ``name`` (one of :data:`LIGHTING`): its ``LightResult`` (``direct``,
    ``indirect``, ``error`` (n, 3), ray counts, per-light statistics). ``indirect=False``:
    direct light only, whatever the options' ``bounces``; ``ground``: a resolved
    :class:`aobake.ground.Ground` that occludes and reflects (None: none)."""
    opts = make_options(name, options, **changes)
    if name not in LIGHTING:
        raise ValueError(f"--method {name} computes ambient occlusion only; light needs --method {LIGHTING[0]}")
    module = importlib.import_module(f"{__name__}.{name}")
    return module.run_light(surface, shading, opts, progress, indirect=indirect, ground=ground)
