"""Light, albedo and emission of a scene read from its file and ``--light``.

:func:`read_shading` fills a :class:`aobake.shading.Shading` for a surface
:func:`aobake.io.load_mesh` read: UsdLux lights and UsdPreviewSurface / displayColor
(:mod:`.usdlux`), KHR_lights_punctual and glTF materials (:mod:`.punctual`), OBJ/MTL
and PLY colours (:mod:`.mtl`); :func:`parse_light_spec` reads ``--light``. Conventions
and what is approximated: docs/lights.md. Importing it loads numpy only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...mesh import Surface
from ...shading import Light, Shading
from ..common import short_reason
from .reading import Reading
from .spec import SPEC_KINDS, parse_light_spec

__all__ = ["SPEC_KINDS", "parse_light_spec", "read_shading", "welded_shading"]


def read_shading(
    path: str | Path,
    surface: Surface,
    *,
    scene_lights: bool = True,
    cli_lights: Iterable[Light | str] = (),
    dark_materials: bool = True,
) -> Shading:
    """The lights, albedo and emission of ``surface``, read from ``path``.

    Parameters
    ----------
    path : str or Path
        The file ``surface`` was loaded from (named in messages); a USD surface is read
        from its ``metadata["path"]`` at its ``metadata["time"]``, a glTF one from
        ``metadata["gltf_path"]``.
    surface : aobake.mesh.Surface
        As :func:`aobake.io.load_mesh` returned it (before ``--weld``): per-face values
        line up with ``surface.faces``, per-vertex ones with ``surface.positions``.
    scene_lights : bool
        False (``--no-scene-lights``): ignore the file's lights, keep its materials.
    cli_lights : iterable of Light or str
        ``--light`` values (strings are parsed, named ``--light 1``, ``--light 2``...),
        appended after the file's lights.
    dark_materials : bool
        False: skip a USD scene's materials when nothing lights it (no light, no
        emissive material, no ``cli_lights``); its albedo is then the default. A bake
        of such a scene computes AO only and needs none of it.

    Returns
    -------
    Shading
        ``sources`` says where albedo, emission and lights came from; ``notes`` what was
        ignored or approximated (for warnings).

    Raises
    ------
    InputError
        Bad or unsupported light or material data: one line naming the file, the prim
        or node, and the problem.
    ValueError
        A bad ``--light`` string.
    """
    path = Path(path)
    cli_lights = tuple(cli_lights)
    reading = Reading(surface, path)
    fmt = surface.metadata.get("format")
    try:
        if fmt == "USD":
            from .usdlux import read_usd

            read_usd(reading, scene_lights=scene_lights, extra_lights=bool(cli_lights) or dark_materials)
        elif fmt == "glTF":
            from .punctual import read_gltf

            read_gltf(reading, scene_lights=scene_lights)
        elif fmt == "OBJ":
            from .mtl import read_obj

            read_obj(reading)
        elif fmt == "PLY" and (cli_lights or dark_materials):  # a PLY has no lights, emits nothing
            from .mtl import read_ply_colours

            read_ply_colours(reading)
    except InputError:
        raise
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from exc
    except Exception as exc:  # malformed data a reader did not foresee: still one line
        raise InputError(path, f"cannot read its lights and materials: {short_reason(exc)}") from exc
    if not scene_lights:
        reading.lights_from = "none (--no-scene-lights)"
    extra = [
        light if isinstance(light, Light) else parse_light_spec(light, k)
        for k, light in enumerate(cli_lights, 1)
    ]
    if extra:
        reading.lights.extend(extra)
        reading.lights_from = "--light" if reading.lights_from == "none" else f"{reading.lights_from}, --light"
    return reading.shading()


def welded_shading(shading: Shading, inverse) -> Shading:
    """``shading`` of a surface moved onto its welded copy (:func:`aobake.mesh.weld_vertices`
    returns ``inverse``, the welded vertex of each input vertex): triangles are the same,
    in the same order; a welded vertex gets the mean of the values of its copies."""
    inverse = np.asarray(inverse, dtype=np.int64).reshape(-1)
    if len(inverse) != len(shading.vertex_albedo):
        raise ValueError(f"inverse has {len(inverse)} entries for {len(shading.vertex_albedo)} vertices")
    n = int(inverse.max()) + 1 if len(inverse) else 0
    count = np.bincount(inverse, minlength=n).astype(np.float64)[:, None]

    def merged(values):
        total = np.zeros((n, values.shape[1]))
        np.add.at(total, inverse, values)
        return total / np.maximum(count, 1.0)

    return replace(
        shading, vertex_albedo=merged(shading.vertex_albedo), vertex_emission=merged(shading.vertex_emission)
    )
