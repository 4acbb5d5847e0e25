"""USD: UsdLux lights, UsdPreviewSurface albedo and emission, ``displayColor``.

Every light is read as UsdLux defines it (see docs/lights.md): radiance
L = intensity * 2^exposure * color (* the blackbody colour when enabled), divided by the
light's world-space area when ``normalize`` is on; lights and materials are read at the
surface's time code. ``pxr`` is imported inside the functions only.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...shading import DEFAULT_ALBEDO, Light
from ..common import foreign_stderr
from .reading import Reading, check_colour, triangle_corners

#: UsdLux types read as lights, and what aobake makes of them.
AREA_TYPES = ("RectLight", "DiskLight", "SphereLight")
DOME_TYPES = ("DomeLight", "DomeLight_1")
#: Lights that add no light of their own (a portal only guides a dome's sampling).
IGNORED_TYPES = ("PortalLight",)

#: Relative tolerance under which a transformed disk is still a circle, a sphere a sphere.
SHAPE_TOLERANCE = 1e-6


def read_usd(reading: Reading, *, scene_lights: bool, extra_lights: bool = False) -> None:
    """Fill ``reading`` from the USD stage the surface was read from. The materials are
    read only where something may light the scene (its lights, an emissive material, or
    ``extra_lights``: lights given apart, ``--light``)."""
    from pxr import Sdf, Usd

    from ..usd import _open_fresh

    surface = reading.surface
    source = surface.metadata.get("path") or str(reading.path)
    # the mesh reader opened this stage first and reported what USD printed then; opened
    # as it did (fresh from disk when a stale layer is registered), so both read one file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with foreign_stderr(reading.path.name):
            stage = _open_fresh(Path(source), Sdf, Usd)
    if stage is None:
        raise InputError(reading.path, "cannot read as USD: the stage did not open")
    time = surface.metadata.get("time")
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    with foreign_stderr(reading.path.name):
        emissive_meshes = _read_lights(reading, stage, code) if scene_lights else set()
        if not (reading.lights or emissive_meshes or extra_lights or _may_emit(stage)):
            return  # nothing lights the scene: its AO is all a bake computes, skip the materials
        for part in surface.parts:
            if part.prim_path is not None:
                _read_part_colours(reading, stage, part, code, emissive_meshes)


def _may_emit(stage) -> bool:
    """Whether some UsdPreviewSurface of the stage authors ``emissiveColor`` (a value or a
    connection): one pass over the prims, far cheaper than resolving every binding."""
    from pxr import Usd, UsdShade

    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if prim.IsA(UsdShade.Shader):
            attr = prim.GetAttribute("inputs:emissiveColor")
            if attr and (attr.HasAuthoredValue() or attr.HasAuthoredConnections()):
                return True
    return False


# -- lights -------------------------------------------------------------------------------


def _read_lights(reading: Reading, stage, code) -> set[str]:
    """Append every visible UsdLux light; return the prim paths of mesh lights (whose
    emission they set)."""
    from pxr import Usd, UsdGeom, UsdLux

    mesh_lights: set[str] = set()
    found = False
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if not prim.HasAPI(UsdLux.LightAPI):
            continue
        if UsdGeom.Imageable(prim).ComputeVisibility(code) == UsdGeom.Tokens.invisible:
            continue
        found = True
        kind = str(prim.GetTypeName())
        where = str(prim.GetPath())
        if kind in IGNORED_TYPES:
            reading.note(f"{where}: {kind} adds no light of its own; ignored")
            continue
        if prim.IsA(UsdGeom.Mesh):
            _mesh_light(reading, prim, code)
            mesh_lights.add(where)
            continue
        if kind not in AREA_TYPES + DOME_TYPES + ("DistantLight",):
            what = f"a {kind}" if kind else "a prim without a type"
            raise InputError(
                reading.path,
                f"{where}: {what} light is not supported (aobake reads DistantLight, SphereLight, "
                "RectLight, DiskLight, DomeLight and meshes with MeshLightAPI; "
                "--no-scene-lights ignores the file's lights)",
            )
        try:
            reading.lights.append(_light(reading, prim, kind, code))
        except ValueError as exc:  # Light.make's one-line reason names the prim
            raise InputError(reading.path, str(exc)) from None
    if found:
        reading.lights_from = "UsdLux"
    return mesh_lights


def _value(prim, name: str, code, default):
    """An attribute's value at ``code`` (its earliest sample when it has only samples,
    the schema's fallback when unauthored), else ``default``; a connected input gives the
    value of the attribute it is connected to."""
    from pxr import Usd, UsdShade

    attr = prim.GetAttribute(name)
    if name.startswith("inputs:") and not (attr and attr.HasAuthoredValue()):
        legacy = prim.GetAttribute(name[len("inputs:") :])  # UsdLux before 21.02: no prefix
        if legacy and legacy.HasAuthoredValue() and prim.HasAPI(_light_api()):
            attr = legacy
    if not attr:
        return default
    if name.startswith("inputs:") and UsdShade.Input.IsInput(attr):
        producers = UsdShade.Input(attr).GetValueProducingAttributes()
        if producers and producers[0] != attr and not UsdShade.Output.IsOutput(producers[0]):
            attr = producers[0]
    value = attr.Get(code)
    if value is None and attr.GetNumTimeSamples():
        value = attr.Get(Usd.TimeCode.EarliestTime())
    return default if value is None else value


def _light_api():
    from pxr import UsdLux

    return UsdLux.LightAPI


def _scalar(reading: Reading, prim, name: str, code, default: float) -> float:
    value = _value(prim, name, code, default)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(reading.path, f"{prim.GetPath()}: {name} is not a number ({value!r})") from None
    if not math.isfinite(number):
        raise InputError(reading.path, f"{prim.GetPath()}: {name} is {number} (not finite)")
    return number


def _light_colour(reading: Reading, prim, code) -> np.ndarray:
    """intensity * 2^exposure * color (* blackbody) * diffuse, before any normalization."""
    from pxr import UsdLux

    where = str(prim.GetPath())
    intensity = _scalar(reading, prim, "inputs:intensity", code, 1.0)
    exposure = _scalar(reading, prim, "inputs:exposure", code, 0.0)
    diffuse = _scalar(reading, prim, "inputs:diffuse", code, 1.0)
    if intensity < 0:
        raise InputError(reading.path, f"{where}: negative inputs:intensity ({intensity:g})")
    if diffuse < 0:
        raise InputError(reading.path, f"{where}: negative inputs:diffuse ({diffuse:g})")
    color = check_colour(
        np.asarray(_value(prim, "inputs:color", code, (1.0, 1.0, 1.0)), dtype=np.float64).reshape(3),
        reading, where, "inputs:color", albedo=False,
    )
    if bool(_value(prim, "inputs:enableColorTemperature", code, False)):
        kelvin = _scalar(reading, prim, "inputs:colorTemperature", code, 6500.0)
        # the schema: an RGB colour normalised so that 6500 K is exactly white
        white = np.asarray(UsdLux.BlackbodyTemperatureAsRgb(6500.0), dtype=np.float64)
        color = color * np.asarray(UsdLux.BlackbodyTemperatureAsRgb(kelvin), dtype=np.float64) / white
    with np.errstate(over="ignore", invalid="ignore"):
        value = intensity * 2.0**exposure * diffuse * color
    if not np.isfinite(value).all():
        raise InputError(reading.path, f"{where}: intensity * 2^exposure overflows ({intensity:g}, {exposure:g})")
    if bool(np.asarray(_value(prim, "inputs:shaping:focus", code, 0.0)) > 0):
        reading.note(f"{where}: inputs:shaping:focus ignored")
    if _value(prim, "inputs:shaping:ies:file", code, None):
        reading.note(f"{where}: IES profile ignored")
    filters = prim.GetRelationship("light:filters")
    if filters and filters.GetTargets():
        reading.note(f"{where}: light filters ignored")
    return value


def _world(reading: Reading, prim, code) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) linear part (row vectors: world = local @ linear + t) and translation t."""
    from pxr import UsdGeom

    matrix = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code), dtype=np.float64)
    if not np.isfinite(matrix).all():
        raise InputError(reading.path, f"{prim.GetPath()}: its transform is not finite")
    return matrix[:3, :3], matrix[3, :3]


def _unit(vector: np.ndarray, reading: Reading, where: str) -> np.ndarray:
    length = float(np.linalg.norm(vector))
    if not length > 0:
        raise InputError(reading.path, f"{where}: its transform collapses the light's axis")
    return vector / length


def _shadow(prim, code) -> bool:
    return bool(_value(prim, "inputs:shadow:enable", code, True))


def _cone(reading: Reading, prim, code) -> tuple[float, float] | None:
    """ShapingAPI's cone as (inner, outer) half-angles in radians, None when it does not
    restrict (no cone, or 180 degrees and more). outer = cone:angle and inner =
    angle * (1 - softness): full intensity inside inner, none outside outer."""
    from pxr import UsdLux

    attr = prim.GetAttribute("inputs:shaping:cone:angle")
    if not (prim.HasAPI(UsdLux.ShapingAPI) or (attr and attr.HasAuthoredValue())):
        return None
    angle = _scalar(reading, prim, "inputs:shaping:cone:angle", code, 90.0)
    if angle >= 180.0:
        return None
    softness = min(max(_scalar(reading, prim, "inputs:shaping:cone:softness", code, 0.0), 0.0), 1.0)
    outer = math.radians(max(angle, 0.0))
    return outer * (1.0 - softness), outer


def _light(reading: Reading, prim, kind: str, code) -> Light:
    """One UsdLux light as a :class:`Light` in world space (see docs/lights.md)."""
    where = str(prim.GetPath())
    value = _light_colour(reading, prim, code)
    normalize = bool(_value(prim, "inputs:normalize", code, False))
    linear, origin = _world(reading, prim, code)
    shadow = _shadow(prim, code)
    cone = _cone(reading, prim, code)
    if kind in DOME_TYPES:
        texture = _value(prim, "inputs:texture:file", code, None)
        if texture is not None and str(getattr(texture, "path", texture)):
            raise InputError(
                reading.path,
                f"{where}: a textured {kind} ({getattr(texture, 'path', texture)}) is not supported: "
                "aobake reads uniform domes only (remove inputs:texture:file, or --no-scene-lights)",
            )
        return Light.make("dome", where, value, shadow=shadow)
    if kind == "DistantLight":
        if cone is not None:
            reading.note(f"{where}: ShapingAPI cone ignored on a DistantLight")
        angle = math.radians(min(max(_scalar(reading, prim, "inputs:angle", code, 0.53), 0.0), 360.0))
        if angle >= math.pi:
            raise InputError(
                reading.path,
                f"{where}: inputs:angle {math.degrees(angle):g} degrees covers a hemisphere or more; "
                "aobake reads distant lights below 180 degrees (use a DomeLight)",
            )
        if angle > 0 and not normalize:
            value = value * math.pi * math.sin(angle / 2.0) ** 2  # radiance over the cone -> E_perp
        towards = _unit(np.array([0.0, 0.0, 1.0]) @ linear, reading, where)
        return Light.make("distant", where, value, direction=towards, angle=angle, shadow=shadow)
    axis = _unit(np.array([0.0, 0.0, -1.0]) @ linear, reading, where)  # the way it shines
    if kind == "SphereLight":
        return _sphere(reading, prim, where, value, normalize, linear, origin, axis, cone, shadow, code)
    if texture := _value(prim, "inputs:texture:file", code, None):
        if str(getattr(texture, "path", texture)):
            reading.note(f"{where}: texture ignored, read as its uniform colour")
    if cone is not None and cone[1] < math.pi / 2:
        reading.note(f"{where}: ShapingAPI cone ignored on an area light")
    if kind == "RectLight":
        width = _scalar(reading, prim, "inputs:width", code, 1.0)
        height = _scalar(reading, prim, "inputs:height", code, 1.0)
        u = linear[0] * (width / 2.0)
        v = linear[1] * (height / 2.0)
        cross = np.cross(u, v)
        area = 4.0 * float(np.linalg.norm(cross))
        if not area > 0:
            raise InputError(reading.path, f"{where}: a RectLight of zero area ({width:g} x {height:g} after its transform)")
        if float(np.dot(cross, axis)) < 0:
            v = -v  # emit along the transformed -Z
        if normalize:
            value = value / area
        return Light.make("rect", where, value, position=origin, u=u, v=v, shadow=shadow)
    # DiskLight
    radius = _scalar(reading, prim, "inputs:radius", code, 0.5)
    a, b = linear[0] * radius, linear[1] * radius
    cross = np.cross(a, b)
    area = math.pi * float(np.linalg.norm(cross))
    if not area > 0:
        raise InputError(reading.path, f"{where}: a DiskLight of zero area (radius {radius:g} after its transform)")
    la, lb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if abs(la - lb) > SHAPE_TOLERANCE * max(la, lb) or abs(float(np.dot(a, b))) > SHAPE_TOLERANCE * la * lb:
        reading.note(f"{where}: its transform makes the disk an ellipse; read as a disk of the same area")
    world_radius = math.sqrt(area / math.pi)
    normal = cross / np.linalg.norm(cross)
    if float(np.dot(normal, axis)) < 0:
        normal = -normal
    if normalize:
        value = value / area
    return Light.make("disk", where, value, position=origin, normal=normal, radius=world_radius, shadow=shadow)


def _sphere(reading, prim, where, value, normalize, linear, origin, axis, cone, shadow, code) -> Light:
    """A SphereLight: an area sphere, or (``treatAsPoint``, or a ShapingAPI cone) a point
    or spot light of the radiant intensity I = L pi r^2 a sphere of radiance L sends in
    every direction (same total power)."""
    from pxr import UsdLux

    radius = _scalar(reading, prim, "inputs:radius", code, 0.5)
    scales = np.linalg.svd(linear, compute_uv=False)
    if float(scales.max() - scales.min()) > SHAPE_TOLERANCE * float(scales.max()):
        reading.note(f"{where}: its transform makes the sphere an ellipsoid; read as a sphere of the same volume")
    world_radius = abs(radius) * float(np.prod(scales)) ** (1.0 / 3.0)
    area = 4.0 * math.pi * world_radius**2
    as_point = bool(_value(prim, UsdLux.Tokens.treatAsPoint, code, False))
    if as_point or cone is not None:
        if not as_point:
            reading.note(f"{where}: a SphereLight with a cone read as a spot light at its centre (I = L pi r^2)")
        # I = L pi r^2; normalized L = L0 / (4 pi r^2), so I = L0 / 4 for any radius
        intensity = value / 4.0 if normalize else value * math.pi * world_radius**2
        if not (normalize or world_radius > 0):
            raise InputError(reading.path, f"{where}: a SphereLight of radius 0 without normalize emits nothing (zero area)")
        if cone is None:
            return Light.make("point", where, intensity, position=origin, shadow=shadow)
        return Light.make(
            "spot", where, intensity, position=origin, direction=axis,
            cone_inner=cone[0], cone_outer=cone[1], shadow=shadow,
        )
    if not area > 0:
        raise InputError(reading.path, f"{where}: a SphereLight of zero area (radius {radius:g} after its transform)")
    if normalize:
        value = value / area
    return Light.make("sphere", where, value, position=origin, radius=world_radius, shadow=shadow)


def _mesh_light(reading: Reading, prim, code) -> None:
    """A mesh with LightAPI (MeshLightAPI): its triangles emit the light's radiance
    (divided by their world area with ``normalize``), replacing its material's emission."""
    where = str(prim.GetPath())
    part = next((p for p in reading.surface.parts if p.prim_path == where), None)
    if part is None:
        reading.note(f"{where}: a mesh light that is not among the baked meshes; ignored")
        return
    value = _light_colour(reading, prim, code)
    if bool(_value(prim, "inputs:normalize", code, False)):
        faces = reading.surface.faces[part.face_start : part.face_stop]
        tri = reading.surface.positions[faces]
        area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
        if not area > 0:
            raise InputError(reading.path, f"{where}: a mesh light of zero area")
        value = value / area
    reading.face_emission[part.face_start : part.face_stop] = value
    reading.vertex_emission[part.vertex_start : part.vertex_stop] = value
    reading.emission_source("MeshLightAPI")
    if not _shadow(prim, code):
        reading.note(f"{where}: shadow:enable false ignored on a mesh light (an emissive mesh always occludes)")


# -- surfaces -----------------------------------------------------------------------------


def _read_part_colours(reading: Reading, stage, part, code, mesh_lights: set[str]) -> None:
    """Albedo and emission of one baked mesh from its bound materials (GeomSubsets of
    family materialBind: per face), else its displayColor, else the defaults."""
    from pxr import UsdGeom, UsdShade

    prim = stage.GetPrimAtPath(part.prim_path)
    if not prim or not prim.IsA(UsdGeom.Mesh):
        return
    where = part.prim_path
    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(_value(prim, "faceVertexCounts", code, ()), dtype=np.int64).reshape(-1)
    indices = np.asarray(_value(prim, "faceVertexIndices", code, ()), dtype=np.int64).reshape(-1)
    holes = np.asarray(_value(prim, "holeIndices", code, ()), dtype=np.int64).reshape(-1)
    local = reading.surface.faces[part.face_start : part.face_stop] - part.vertex_start
    tri = triangle_corners(counts, indices, local, holes, path=reading.path, where=where)
    binding = UsdShade.MaterialBindingAPI(prim)
    groups = [(None, binding.ComputeBoundMaterial()[0], where)]
    for subset in binding.GetMaterialBindSubsets():
        if subset.GetElementTypeAttr().Get() != UsdGeom.Tokens.face:
            continue
        polygons = np.asarray(_value(subset.GetPrim(), "indices", code, ()), dtype=np.int64).reshape(-1)
        bad = (polygons < 0) | (polygons >= len(counts))
        if bad.any():
            raise InputError(reading.path, f"{subset.GetPath()}: GeomSubset indices outside the mesh's {len(counts)} faces")
        material = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
        if not material:
            continue  # an unbound subset's faces keep the mesh's material
        groups.append((polygons, material, str(subset.GetPath())))
    owner = np.repeat(np.arange(len(counts)), counts)
    # each subset's corners, found once for albedo and emission
    groups = [(None if p is None else np.isin(owner, p), m, name) for p, m, name in groups]
    if len(groups) > 1 and np.logical_or.reduce([mask for mask, _, _ in groups[1:]]).all():
        groups = groups[1:]  # the subsets cover every face: the mesh's own colour is not used
    n_points = part.n_vertices
    for which in ("albedo", "emission"):
        if which == "emission" and where in mesh_lights:
            continue
        corners = np.zeros((len(indices), 3))
        per_vertex = None
        for mask, material, name in groups:
            values, vertex = _group_colour(reading, mesh, material, which, code, counts, indices, n_points, name)
            if mask is None:
                corners[:] = values
                per_vertex = vertex
            else:
                corners[mask] = values[mask]
                per_vertex = None  # a vertex may sit on faces of several materials
        face = corners[tri].mean(axis=1) if len(tri) else np.zeros((0, 3))
        reading.set_part(which, part, face, per_vertex)


def _group_colour(reading, mesh, material, which, code, counts, indices, n_points, where):
    """Per-corner (k, 3) colours of one material group, and per-vertex ones when they
    come from a vertex-interpolated primvar (else None)."""
    prim = mesh.GetPrim()
    shader = _preview_surface(reading, material)
    if shader is not None:
        name = "diffuseColor" if which == "albedo" else "emissiveColor"
        default = (DEFAULT_ALBEDO,) * 3 if which == "albedo" else (0.0, 0.0, 0.0)
        found = _shader_input(reading, shader, name, code, default)
        label = f"UsdPreviewSurface {name}"
        if found[0] == "primvar":
            _, varname, fallback = found
            got = _primvar_corners(reading, prim, varname, code, counts, indices, n_points)
            if got is not None:
                values, vertex = got
                _record(reading, which, f"{label} <- primvar {varname}")
                return check_colour(values, reading, where, f"{name} (primvar {varname})", albedo=which == "albedo"), (
                    None if vertex is None else check_colour(vertex, reading, where, name, albedo=which == "albedo")
                )
            value = fallback
        else:
            value = found[1]
        value = check_colour(np.asarray(value, dtype=np.float64).reshape(3), reading,
                             f"{where} ({material.GetPath()})", name, albedo=which == "albedo")  # fmt: skip
        if which == "albedo" or bool((value > 0).any()):
            _record(reading, which, label)
        return np.broadcast_to(value, (len(indices), 3)), None
    if which == "emission":
        return np.zeros((len(indices), 3)), None
    got = _primvar_corners(reading, prim, "displayColor", code, counts, indices, n_points)
    if got is None:
        return np.full((len(indices), 3), DEFAULT_ALBEDO), None
    values, vertex = got
    _record(reading, which, "displayColor")
    values = check_colour(values, reading, where, "primvars:displayColor", albedo=True)
    return values, None if vertex is None else check_colour(vertex, reading, where, "primvars:displayColor", albedo=True)


def _record(reading: Reading, which: str, label: str) -> None:
    (reading.albedo_source if which == "albedo" else reading.emission_source)(label)


def _preview_surface(reading: Reading, material):
    """The UsdPreviewSurface shader behind a material's surface output, or None (no
    material, or another shader: a note, and displayColor is used)."""
    if not material:
        return None
    shader, _, _ = material.ComputeSurfaceSource()
    if not shader:
        return None
    if shader.GetIdAttr().Get() != "UsdPreviewSurface":
        reading.note(f"{material.GetPath()}: surface shader {shader.GetIdAttr().Get()!r} is not UsdPreviewSurface; its colour is not read")
        return None
    return shader


def _shader_input(reading: Reading, shader, name: str, code, default):
    """("value", rgb) or ("primvar", varname, fallback rgb) for a UsdPreviewSurface input,
    following connections (a texture: a note and the default)."""
    from pxr import UsdShade

    shader_input = shader.GetInput(name)
    if not shader_input:
        return ("value", default)
    producers = shader_input.GetValueProducingAttributes()
    if not producers:
        return ("value", default)
    attr = producers[0]
    if not UsdShade.Output.IsOutput(attr):
        value = attr.Get(code)
        return ("value", default if value is None else tuple(value))
    source = UsdShade.Shader(attr.GetPrim())
    kind = str(source.GetIdAttr().Get() or "")
    if kind.startswith("UsdPrimvarReader_float3") or kind == "UsdPrimvarReader_color3":
        varname = _value(attr.GetPrim(), "inputs:varname", code, "")
        fallback = _value(attr.GetPrim(), "inputs:fallback", code, (0.0, 0.0, 0.0))
        return ("primvar", str(varname), tuple(fallback))
    reading.note(
        f"{shader.GetPath()}: {name} comes from {kind or 'a shader'} ({attr.GetPrim().GetPath()}), "
        f"not read; {'the default ' + str(default[0]) if default[0] else 'none'} used"
    )
    return ("value", default)


def _primvar_corners(reading: Reading, prim, name: str, code, counts, indices, n_points):
    """A colour primvar as per-corner values (k, 3) and, when vertex-interpolated,
    per-vertex ones (n, 3); None when the mesh has no such primvar."""
    from pxr import UsdGeom

    primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not primvar or not primvar.HasValue():
        return None
    values = primvar.ComputeFlattened(code)
    if values is None:
        return None
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(reading.path, f"{prim.GetPath()}: primvars:{name} is not a colour (3 values per element)")
    interpolation = primvar.GetInterpolation()
    expected = {
        UsdGeom.Tokens.constant: 1,
        UsdGeom.Tokens.uniform: len(counts),
        UsdGeom.Tokens.vertex: n_points,
        UsdGeom.Tokens.varying: n_points,
        UsdGeom.Tokens.faceVarying: len(indices),
    }.get(interpolation)
    constant = interpolation == UsdGeom.Tokens.constant
    if expected is None or (len(arr) < 1 if constant else len(arr) != expected):
        raise InputError(
            reading.path,
            f"{prim.GetPath()}: primvars:{name} has {len(arr)} {interpolation} values, expected {expected}",
        )
    if constant:
        return np.broadcast_to(arr[0], (len(indices), 3)), None
    if interpolation == UsdGeom.Tokens.uniform:
        return np.repeat(arr, counts, axis=0), None
    if interpolation == UsdGeom.Tokens.faceVarying:
        return arr, None
    return arr[indices], arr
