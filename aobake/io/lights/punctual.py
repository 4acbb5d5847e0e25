"""glTF: KHR_lights_punctual lights, albedo baseColorFactor x COLOR_0, emission
emissiveFactor x KHR_materials_emissive_strength, read from the document's JSON
(trimesh's invented default lights are never used). Imports numpy only.
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import InputError, OutputError
from ...shading import DEFAULT_ALBEDO, Light
from ..gltf import Document, accessor_values, as_float, match_parts, read_document, scene_nodes
from .reading import Reading, check_colour

#: KHR_lights_punctual's types and the :class:`Light` kind each becomes.
PUNCTUAL_KINDS = {"directional": "distant", "point": "point", "spot": "spot"}


def read_gltf(reading: Reading, *, scene_lights: bool) -> None:
    """Fill ``reading`` from the glTF document the surface was read from."""
    path = reading.path
    try:
        doc = read_document(reading.surface.metadata.get("gltf_path") or path)
        if scene_lights:
            _lights(reading, doc)
        pairs = match_parts(doc, reading.surface, warn=False)
    except (InputError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(path, f"cannot read as glTF: {exc}") from None
    except OutputError as exc:
        raise InputError(path, str(exc).split(": ", 1)[-1].replace("; cannot write glTF", "")) from None
    except (OSError, KeyError, IndexError, TypeError) as exc:
        raise InputError(path, f"cannot read as glTF: {exc}") from exc
    for slot, part in pairs:
        _primitive_colours(reading, doc, slot, part)


def _number(reading: Reading, where: str, what: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(reading.path, f"{where}: {what} must be a finite number, got {value!r}")
    return float(value)


def _lights(reading: Reading, doc: Document) -> None:
    gl = doc.json
    table = gl.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for index, world in scene_nodes(gl):
        node = gl["nodes"][index]
        ref = node.get("extensions", {}).get("KHR_lights_punctual")
        if ref is None:
            continue
        name = str(node.get("name") or f"node {index}")
        where = f"node {name!r}"
        k = ref.get("light")
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < len(table):
            raise InputError(reading.path, f"{where}: KHR_lights_punctual light {k!r} does not exist ({len(table)} lights)")
        spec = table[k]
        where = f"{where} (light {k}{', ' + repr(spec['name']) if spec.get('name') else ''})"
        kind = PUNCTUAL_KINDS.get(spec.get("type"))
        if kind is None:
            raise InputError(reading.path, f"{where}: unknown light type {spec.get('type')!r} (directional, point or spot)")
        intensity = _number(reading, where, "intensity", spec.get("intensity", 1.0))
        if intensity < 0:
            raise InputError(reading.path, f"{where}: negative intensity ({intensity:g})")
        colour = spec.get("color", [1.0, 1.0, 1.0])
        if not isinstance(colour, list) or len(colour) != 3:
            raise InputError(reading.path, f"{where}: color must be 3 numbers, got {colour!r}")
        colour = check_colour([_number(reading, where, "color", c) for c in colour], reading, where, "color", albedo=False)
        value = intensity * colour
        reach = math.inf
        if "range" in spec and kind != "distant":
            reach = _number(reading, where, "range", spec["range"])
            if not reach > 0:
                raise InputError(reading.path, f"{where}: range must be > 0, got {reach:g}")
        axis = world[:3, :3] @ np.array([0.0, 0.0, -1.0])  # lights shine along local -Z
        if not np.linalg.norm(axis) > 0 or not np.isfinite(world).all():
            raise InputError(reading.path, f"{where}: its node transform is degenerate")
        axis = axis / np.linalg.norm(axis)
        position = world[:3, 3]
        try:
            if kind == "distant":
                light = Light.make("distant", name, value, direction=-axis)
            elif kind == "point":
                light = Light.make("point", name, value, position=position, range=reach)
            else:
                cone = spec.get("spot", {})
                inner = _number(reading, where, "spot.innerConeAngle", cone.get("innerConeAngle", 0.0))
                outer = _number(reading, where, "spot.outerConeAngle", cone.get("outerConeAngle", math.pi / 4))
                if not 0.0 <= inner < outer <= math.pi / 2:
                    raise InputError(
                        reading.path,
                        f"{where}: spot cone angles need 0 <= innerConeAngle < outerConeAngle <= pi/2, "
                        f"got {inner:g}, {outer:g}",
                    )
                light = Light.make(
                    "spot", name, value, position=position, direction=axis,
                    cone_inner=inner, cone_outer=outer, range=reach,
                )
        except ValueError as exc:
            raise InputError(reading.path, f"{where}: {exc}") from None
        reading.lights.append(light)
        reading.lights_from = "KHR_lights_punctual"


def _primitive_colours(reading: Reading, doc: Document, slot, part) -> None:
    gl = doc.json
    primitive = gl["meshes"][slot.mesh]["primitives"][slot.primitive]
    node = gl["nodes"][slot.node]
    where = f"node {node.get('name') or slot.node!r} primitive {slot.primitive}"
    faces = reading.surface.faces[part.face_start : part.face_stop] - part.vertex_start
    n = part.n_vertices
    material, factor = None, None
    emission = np.zeros(3)
    if primitive.get("material") is not None:
        index = primitive["material"]
        material = gl["materials"][index]
        mname = f"material {material.get('name') or index!r}"
        pbr = material.get("pbrMetallicRoughness", {})
        factor = check_colour(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3], reading, mname,
                              "baseColorFactor", albedo=True)  # fmt: skip
        if "baseColorTexture" in pbr:
            reading.note(f"{mname}: baseColorTexture ignored (baseColorFactor used)")
        strength = material.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
        emission = check_colour(material.get("emissiveFactor", [0.0, 0.0, 0.0]), reading, mname, "emissiveFactor", albedo=False)
        emission = emission * check_colour(strength, reading, mname, "emissiveStrength", albedo=False)
        if "emissiveTexture" in material:
            reading.note(f"{mname}: emissiveTexture ignored (emissiveFactor used)")
    colours = None
    if "COLOR_0" in primitive.get("attributes", {}):
        a = primitive["attributes"]["COLOR_0"]
        colours = as_float(accessor_values(doc, a), gl["accessors"][a].get("normalized", False))[:, :3]
        if colours.shape != (n, 3):
            raise InputError(reading.path, f"{where}: COLOR_0 has {len(colours)} values for {n} vertices")
        colours = check_colour(colours, reading, where, "COLOR_0", albedo=True)
    if colours is not None:
        vertex = colours * (1.0 if factor is None else factor)
        reading.albedo_source("COLOR_0" if factor is None else "baseColorFactor x COLOR_0")
        reading.set_part("albedo", part, vertex[faces].mean(axis=1), vertex)
    elif factor is not None:
        reading.albedo_source("baseColorFactor")
        reading.set_part("albedo", part, factor, np.broadcast_to(factor, (n, 3)))
    else:
        reading.set_part("albedo", part, DEFAULT_ALBEDO)
    if (emission > 0).any():
        reading.emission_source("emissiveFactor x emissiveStrength")
    reading.set_part("emission", part, emission, np.broadcast_to(emission, (n, 3)))
