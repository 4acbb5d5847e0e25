"""USD: meshes in (every visible ``UsdGeom.Mesh`` in world space), bakes out (one
``UsdGeom.Mesh`` per part with a vertex primvar ``ao``), and ``ao`` read back.

Computes no AO. ``pxr`` is imported inside the functions only, so importing this module
stays cheap.

Layer caching: USD keeps every open layer in a process-wide registry keyed by its
path, and ``Usd.Stage.Open`` returns the registered layer without looking at the disk.
The writer therefore authors on the temporary path, saves, and drops every reference
to the stage (its prims do not keep it alive) before ``atomic_write`` renames the file,
so no layer stays registered under the temporary name. A layer that some caller still
holds for the *output* path is stale after the rename; :func:`read_ao_usd` detects that
case and reads the file through an anonymous layer, so a bake written twice to the same
path in one process is always read back as written.
"""

from __future__ import annotations

import math
import re
import threading
import traceback
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._types import FloatArray
from ..errors import InputError, OutputError
from ..mesh import RawPart, fan_triangulate, reverse_polygons, transformed_part
from .common import (
    atomic_write,
    check_ao,
    check_attributes,
    check_display,
    check_input_file,
    foreign_stderr,
    output_name,
)

#: Largest index a USD ``int[]`` (int32) can hold.
INT32_MAX = int(np.iinfo(np.int32).max)

#: Default prim every aobake USD file has; meshes are its children, in part order.
ROOT_PATH = "/Root"

#: customData key under which the caller's metadata is stored on /Root and each mesh.
CUSTOM_DATA_KEY = "aobake"

#: Primvar name for the per-vertex accessibility.
AO_PRIMVAR = "ao"

UP_AXES = ("Y", "Z")


def write_usd(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: Mapping[str, str | float | int | bool] | None = None,
    attributes: Mapping[str, np.ndarray] | None = None,
    display=None,
) -> None:
    """Write a USD stage with one ``UsdGeom.Mesh`` per part and a vertex primvar ``ao``.

    The stage's default prim is the Xform ``/Root``; each part of ``surface`` becomes a
    Mesh child named after the part (made a valid identifier, de-duplicated with
    ``_1``, ``_2``...). Each mesh has float32 ``points``, its original polygon topology
    (``faceVertexCounts``/``faceVertexIndices``, so quads stay quads), vertex
    ``normals``, ``extent``, ``subdivisionScheme = "none"``, the primvar ``ao``
    (``float[]``, interpolation ``vertex``) and, with ``color``, ``displayColor``
    (vertex, grey = ao). ``upAxis`` and ``metersPerUnit`` are always authored (an
    unauthored ``metersPerUnit`` means centimeters).

    Parameters
    ----------
    path : str or Path
        ``.usda`` (text), ``.usdc`` or ``.usd`` (binary crate). Written atomically:
        on any failure neither it nor a temporary file is left behind.
    surface : aobake.mesh.Surface
        Positions ``(n, 3) float64``, normals ``(n, 3) float64`` and ``parts``; each
        part's vertex range becomes one mesh. Points and normals are stored as float32.
    ao : (n,) float in [0, 1]
        Accessibility 1 - A (1 = fully open) for all parts concatenated; stored float32.
    color : bool
        Also author ``primvars:displayColor`` (vertex interpolation, grey = ao).
    up_axis : {"Y", "Z"}
        Stage ``upAxis``.
    meters_per_unit : float
        Stage ``metersPerUnit`` (> 0); 1.0 means the mesh units are meters.
    custom_data : mapping of str to str, float, int or bool, optional
        Recorded as ``customData["aobake"]`` on ``/Root`` and on every mesh (method,
        parameters, seed, aobake version...), and as the layer's
        ``customLayerData["aobake"]``.
    attributes : mapping of str to array, optional
        Extra per-vertex values (:func:`aobake.io.common.check_attributes`), each a
        vertex primvar of its name (:func:`primvar_value`: ``normal3f[]``,
        ``color3f[]`` or ``float[]``).
    display : (n, 3) float in [0, 1], optional
        Linear colours ``color`` authors as ``displayColor`` instead of grey ``ao``.

    Raises
    ------
    NumericalError
        ``ao``, ``attributes`` or ``display`` is non-finite, out of range, or not one
        value per vertex (checked before anything is opened).
    InputError
        A part's topology is inconsistent (counts < 3, sum of counts different from
        the number of indices, indices outside the part).
    OutputError
        The directory is missing or unwritable, a part has more vertices than int32
        indices address, or USD fails to write the file.
    ValueError
        Bad ``up_axis``, ``meters_per_unit`` or ``custom_data``.
    """
    path = Path(path)
    ao32 = check_ao(ao, n_vertices=surface.n_vertices, where=output_name(path))
    extras = check_attributes(attributes, surface.n_vertices, output_name(path))
    display32 = check_display(display, surface.n_vertices, output_name(path))
    up = str(up_axis).upper()
    if up not in UP_AXES:
        raise ValueError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
    mpu = float(meters_per_unit)
    if not (math.isfinite(mpu) and mpu > 0.0):
        raise ValueError(
            f"meters_per_unit must be a positive finite number, got {meters_per_unit!r}"
        )
    data = _clean_custom_data(custom_data)
    meshes = _mesh_arrays(path, surface, ao32)
    for arrays, part in zip(meshes, surface.parts, strict=True):
        s = slice(part.vertex_start, part.vertex_stop)
        arrays["extras"] = {name: (kind, values[s]) for name, (kind, values) in extras.items()}
        arrays["display"] = None if display32 is None else display32[s]

    try:
        with atomic_write(path) as tmp, foreign_stderr(output_name(path)):
            _author_stage(
                tmp,
                meshes,
                out_name=output_name(path),
                color=color,
                up_axis=up,
                meters_per_unit=mpu,
                custom_data=data,
            )
    except OSError as exc:
        raise OutputError(f"{output_name(path)}: cannot write ({exc.strerror or exc})") from exc


def read_ao_usd(path: str | Path) -> np.ndarray:
    """Read the ``primvars:ao`` of every mesh in a USD file, concatenated.

    Meshes are visited in stage traversal order (depth first, file order), which is
    the writer's part order, so the result lines up with the baked vertices; invisible
    meshes and guide or proxy purposes are skipped, as the mesh reader skips them.

    Parameters
    ----------
    path : str or Path
        A ``.usda``/``.usdc``/``.usd``/``.usdz`` file.

    Returns
    -------
    ao : (n,) float64
        Flattened (de-indexed) ``ao`` values of all meshes, one per point.

    Raises
    ------
    InputError
        The file is missing or not a USD stage, it has no mesh with an ``ao`` primvar,
        a mesh lacks one while others have it, or the primvar is not one value per
        point.
    """
    path = check_input_file(path, "USD file")
    from pxr import Sdf, Usd, UsdGeom

    stage = _open_fresh(path, Sdf, Usd)
    parts: list[np.ndarray] = []
    missing: list[str] = []
    for prim in baked_meshes(stage, Usd.TimeCode.Default()):
        mesh = UsdGeom.Mesh(prim)
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(AO_PRIMVAR)
        if not primvar or not primvar.HasValue():
            missing.append(str(prim.GetPath()))
            continue
        values = primvar.ComputeFlattened()
        points = _usd_value(mesh.GetPointsAttr(), Usd.TimeCode.Default(), None)
        n_points = 0 if points is None else len(points)
        if values is None:
            missing.append(str(prim.GetPath()))
            continue
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        interp = primvar.GetInterpolation()
        if interp not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) or values.size != n_points:
            raise InputError(
                path,
                f"{prim.GetPath()}: primvar 'ao' has {values.size} {interp} values "
                f"but the mesh has {n_points} points; expected one per vertex",
            )
        parts.append(values)
    if not parts:
        raise InputError(path, "no mesh with a primvar 'ao' in the stage")
    if missing:
        raise InputError(path, f"{len(missing)} meshes have no primvar 'ao' (first: {missing[0]})")
    return np.concatenate(parts)


_shared = threading.local()


@contextmanager
def shared_stages():
    """Within the block (on this thread), the stage the mesh reader opened fresh from
    disk is the one :func:`_open_fresh` hands out for that file: a bake reads its meshes
    and then its lights and materials from one open stage, not two. Dropped at the end
    of the block (before anything is written)."""
    outer = getattr(_shared, "stages", None)
    if outer is None:
        _shared.stages = {}
    try:
        yield
    finally:
        if outer is None:
            _shared.stages = None


def _open_fresh(path: Path, Sdf, Usd):
    """Open ``path`` as a stage whose root layer reflects the file on disk now.

    A layer already registered for the path (someone holds a stage on it) may predate
    the file, so it is read through an anonymous layer instead of the registry. Inside
    :func:`shared_stages`, the stage the mesh reader opened from disk for the path.
    """
    stages = getattr(_shared, "stages", None)
    if stages is not None and str(path.resolve()) in stages:
        return stages[str(path.resolve())]
    try:
        with foreign_stderr(path.name):
            if Sdf.Layer.Find(str(path.resolve())) is not None:
                layer = Sdf.Layer.OpenAsAnonymous(str(path.resolve()))
                if layer is not None:
                    # an anonymous layer anchors nothing: sublayers relative to the file (an
                    # aobake overlay's source) are made absolute so they still compose
                    paths = [_anchored(sub, path) for sub in layer.subLayerPaths]
                    del layer.subLayerPaths[:]
                    for sub in paths:
                        layer.subLayerPaths.append(sub)
                stage = None if layer is None else Usd.Stage.Open(layer)
            else:
                stage = Usd.Stage.Open(str(path.resolve()))
    except Exception as exc:  # pxr raises Tf.ErrorException (not importable by name everywhere)
        # Tf errors read "Error in '<C++ function>' at line N in file F : '<what>'"; keep <what>.
        found = re.findall(r"'([^']*)'", str(exc))
        what = found[-1].replace(f"@{path.resolve()}@", "").strip() if found else ""
        raise InputError(path, f"not a readable USD file ({what or type(exc).__name__})") from None
    if stage is None:
        raise InputError(path, "not a readable USD file")
    return stage


def _anchored(asset: str, layer_path: Path) -> str:
    """A layer's relative asset path made absolute against the layer's directory."""
    if asset.startswith(("./", "../")) or not (Path(asset).is_absolute() or ":" in asset):
        return str((layer_path.resolve().parent / asset).resolve())
    return asset


def _clean_custom_data(custom_data) -> dict:
    """Check ``custom_data`` maps str to str, float, int, bool or a list of str; return
    values USD stores (plain Python, lists as ``Vt.StringArray``)."""
    if custom_data is None:
        return {}
    out = {}
    for key, value in dict(custom_data).items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"custom_data keys must be non-empty strings, got {key!r}")
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, bool | str):
            out[key] = value
        elif isinstance(value, int):
            if not -(2**63) <= value < 2**63:
                raise ValueError(f"custom_data[{key!r}] = {value} does not fit in int64")
            out[key] = value
        elif isinstance(value, float):
            out[key] = value
        elif isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
            from pxr import Vt

            out[key] = Vt.StringArray(list(value))  # e.g. the --field files
        else:
            raise ValueError(
                f"custom_data[{key!r}] must be str, float, int, bool or a list of str, "
                f"got {type(value).__name__}"
            )
    return out


def _mesh_arrays(path: Path, surface, ao32: np.ndarray) -> list[dict]:
    """Per-part arrays ready for USD (float32 points/normals, int32 topology), validated."""
    names = _unique_names([part.name for part in surface.parts])
    positions = np.asarray(surface.positions)
    normals = np.asarray(surface.normals)
    meshes = []
    for part, name in zip(surface.parts, names, strict=True):
        vs, ve = int(part.vertex_start), int(part.vertex_stop)
        k = ve - vs
        if not 0 <= vs <= ve <= surface.n_vertices:
            raise InputError(
                surface.source, f"part {part.name!r}: vertex range [{vs}, {ve}) outside the surface"
            )
        if k > INT32_MAX:
            raise OutputError(
                f"{output_name(path)}: part {part.name!r} has {k} vertices, "
                "more than USD int32 indices address"
            )
        counts = np.asarray(part.face_vertex_counts, dtype=np.int64).reshape(-1)
        indices = np.asarray(part.face_vertex_indices, dtype=np.int64).reshape(-1)
        # faces of fewer than 3 corners are written as the input had them (USD keeps
        # them; renderers skip them); only negative counts are nonsense
        if counts.size and counts.min() < 0:
            raise InputError(
                surface.source, f"part {part.name!r}: {int((counts < 0).sum())} negative face counts"
            )
        if int(counts.sum()) != indices.size:
            raise InputError(
                surface.source,
                f"part {part.name!r}: face counts sum to {int(counts.sum())} "
                f"but there are {indices.size} indices",
            )
        bad = (indices < 0) | (indices >= k)
        if bad.any():
            raise InputError(
                surface.source,
                f"part {part.name!r}: {int(bad.sum())} face corners reference "
                f"a vertex outside its {k} vertices",
            )
        with np.errstate(over="ignore"):
            points = np.ascontiguousarray(positions[vs:ve], dtype=np.float32)
        if not np.isfinite(points).all():
            raise OutputError(
                f"{output_name(path)}: part {part.name!r} has coordinates that overflow float32"
            )
        meshes.append(
            {
                "name": name,
                "points": points,
                "normals": np.ascontiguousarray(normals[vs:ve], dtype=np.float32),
                "counts": counts.astype(np.int32),
                "indices": indices.astype(np.int32),
                "ao": np.ascontiguousarray(ao32[vs:ve]),
            }
        )
    return meshes


def _unique_names(names: list[str]) -> list[str]:
    """Valid, distinct USD prim names for the parts, in order (``mesh``, ``mesh_1``...)."""
    from pxr import Tf

    used: set[str] = set()
    out = []
    for raw in names:
        base = Tf.MakeValidIdentifier(str(raw)) if raw else "mesh"
        name, k = base, 0
        while name in used:
            k += 1
            name = f"{base}_{k}"
        used.add(name)
        out.append(name)
    return out


def _author_stage(
    tmp: Path, meshes: list[dict], *, out_name, color, up_axis, meters_per_unit, custom_data
) -> None:
    """Create, fill and save a new stage at ``tmp``; keep no reference to it afterwards.

    Everything USD lives in this frame, so the stage and its layer are released (and
    leave the layer registry) when it returns or raises, before the rename.
    """
    from pxr import Sdf, Usd, UsdGeom, Vt

    try:
        stage = Usd.Stage.CreateNew(str(tmp))
    except Exception as exc:  # Tf.ErrorException
        found = re.findall(r"'([^']*)'", str(exc))
        what = found[-1] if found else type(exc).__name__
        raise OutputError(f"{out_name}: USD cannot create the layer ({what})") from None
    if stage is None:
        raise OutputError(f"{out_name}: USD cannot create the layer")
    try:
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
        root = UsdGeom.Xform.Define(stage, ROOT_PATH).GetPrim()
        stage.SetDefaultPrim(root)
        if custom_data:
            root.SetCustomDataByKey(CUSTOM_DATA_KEY, custom_data)
            # also on the layer, where overlays and full copies record their source
            stage.GetRootLayer().customLayerData = {CUSTOM_DATA_KEY: custom_data}
        for arrays in meshes:
            _author_mesh(
                stage, f"{ROOT_PATH}/{arrays['name']}", arrays, color, custom_data, Sdf, UsdGeom, Vt
            )
        if not stage.GetRootLayer().Save():
            raise OutputError(f"{out_name}: USD failed to save the layer")
    except BaseException as exc:
        # The frames below this one (_author_mesh, pxr callbacks) hold the stage as an
        # argument, and the traceback keeps them alive; clear their locals so the layer
        # is released now rather than whenever the caller drops the exception.
        if exc.__traceback__ is not None and exc.__traceback__.tb_next is not None:
            traceback.clear_frames(exc.__traceback__.tb_next)
        raise
    finally:
        # Drop the last strong reference here, so the layer leaves the registry and
        # releases its file before atomic_write renames or removes it.
        del stage


def _author_mesh(
    stage, prim_path: str, arrays: dict, color: bool, custom_data: dict, Sdf, UsdGeom, Vt
) -> None:
    """Define one polygonal Mesh with points, topology, normals, extent and the ``ao`` primvar."""
    mesh = UsdGeom.Mesh.Define(stage, prim_path)
    points = Vt.Vec3fArray.FromNumpy(arrays["points"])
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(arrays["counts"]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(arrays["indices"]))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(arrays["normals"]))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if len(points):
        mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(points))
    primvars = UsdGeom.PrimvarsAPI(mesh)
    ao_primvar = primvars.CreatePrimvar(
        AO_PRIMVAR, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex
    )
    ao_primvar.Set(Vt.FloatArray.FromNumpy(arrays["ao"]))
    for name, (kind, values) in arrays.get("extras", {}).items():
        value_type, value = primvar_value(kind, values)
        primvars.CreatePrimvar(name, value_type, UsdGeom.Tokens.vertex).Set(value)
    if color:
        shown = arrays.get("display")
        if shown is None:
            shown = np.repeat(arrays["ao"][:, None], 3, axis=1)
        display = mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
        display.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(shown, dtype=np.float32)))
    if custom_data:
        mesh.GetPrim().SetCustomDataByKey(CUSTOM_DATA_KEY, custom_data)


def primvar_value(kind: str, values: np.ndarray):
    """``(Sdf value type, Vt array)`` of an extra attribute's values: ``normal3f[]`` for
    a normal, ``color3f[]`` (linear) for a colour, ``float[]`` for a float."""
    from pxr import Sdf, Vt

    values = np.ascontiguousarray(values, dtype=np.float32)
    if kind == "float":
        return Sdf.ValueTypeNames.FloatArray, Vt.FloatArray.FromNumpy(values)
    value_type = Sdf.ValueTypeNames.Normal3fArray if kind == "normal" else Sdf.ValueTypeNames.Color3fArray
    return value_type, Vt.Vec3fArray.FromNumpy(values)


# -- reading meshes ---------------------------------------------------------------------


def read_parts(path: Path, metadata: dict, time: float | None = None) -> list[RawPart]:
    """Every visible ``UsdGeom.Mesh`` in world space (instance proxies included; guide and
    proxy purposes skipped), read at ``time``.

    ``time=None`` is USD's default time. Where a baked mesh's points, topology or
    transforms are time-sampled without a default value (nothing to read at the default
    time), the whole scene is read at the earliest such sample instead, so every mesh is
    taken at one instant. ``metadata`` gets ``time`` (the time code read, None for the
    default), ``animated`` (how many meshes have time-varying points or transforms) and
    ``path`` (the resolved source file, for the writers that layer over it).
    """
    try:
        from pxr import Usd, UsdGeom
    except ImportError as exc:
        raise InputError(
            path, "reading USD needs the usd-core package (pip install usd-core)"
        ) from exc

    from pxr import Sdf

    with foreign_stderr(path.name):
        registered = Sdf.Layer.Find(str(Path(path).resolve())) is not None
        stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise InputError(path, "cannot read as USD: the stage did not open")
    stages = getattr(_shared, "stages", None)
    if stages is not None and not registered:  # read from disk now: as fresh as _open_fresh's
        stages[str(Path(path).resolve())] = stage
    metadata.update(
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        path=str(Path(path).resolve()),
    )
    if time is not None and not math.isfinite(time):
        raise InputError(path, f"time {time} is not a finite time code")
    default = Usd.TimeCode.Default()
    meshes = list(baked_meshes(stage, default if time is None else Usd.TimeCode(time)))
    moving: dict = {}  # prim path -> its transform (or an ancestor's) is time-sampled
    animated = [m for m in meshes if _time_varying(m, moving)]
    if time is None:
        first = _first_sample_without_default(animated)
        code = default if first is None else Usd.TimeCode(first)
        if first is not None:  # visibility may differ at that instant
            meshes = list(baked_meshes(stage, code))
        metadata["time"] = first
    else:
        code = Usd.TimeCode(time)
        metadata["time"] = float(time)
    metadata["animated"] = len(animated)
    raw = [_usd_mesh_part(path, UsdGeom.Mesh(prim), code) for prim in meshes]
    if not raw:
        raise InputError(path, "no visible UsdGeom.Mesh in the stage")
    return raw


def baked_meshes(stage, time):
    """The meshes aobake bakes, in traversal order: visible ``UsdGeom.Mesh`` prims
    (instance proxies included) whose purpose is not guide or proxy."""
    from pxr import Usd, UsdGeom

    skipped_purposes = {UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy}
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        imageable = UsdGeom.Imageable(prim)
        if imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        if imageable.ComputePurpose() in skipped_purposes:
            continue
        yield prim


def _geometry_attributes(prim):
    """The attributes that place a mesh's points: its points and topology, and the
    xformOps of the prim and its ancestors up to a resetXformStack."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    attributes = [
        mesh.GetPointsAttr(),
        mesh.GetFaceVertexCountsAttr(),
        mesh.GetFaceVertexIndicesAttr(),
    ]
    while prim and not prim.IsPseudoRoot():
        xformable = UsdGeom.Xformable(prim)
        if xformable:
            attributes += [op.GetAttr() for op in xformable.GetOrderedXformOps()]
            if xformable.GetResetXformStack():
                break
        prim = prim.GetParent()
    return attributes


def _time_varying(prim, moving: dict) -> bool:
    """Whether a mesh's points, topology or world transform have time samples
    (``moving`` memoizes the transforms per prim, shared by siblings)."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    own = (mesh.GetPointsAttr(), mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr())
    return any(a and a.GetNumTimeSamples() > 0 for a in own) or _transform_moves(prim, moving)


def _transform_moves(prim, moving: dict) -> bool:
    from pxr import UsdGeom

    path = prim.GetPath()
    if path not in moving:
        xformable = UsdGeom.Xformable(prim)
        ops = xformable.GetOrderedXformOps() if xformable else []
        result = any(op.GetAttr().GetNumTimeSamples() > 0 for op in ops)
        parent = prim.GetParent()
        if not result and parent and not parent.IsPseudoRoot():
            if not (xformable and xformable.GetResetXformStack()):
                result = _transform_moves(parent, moving)
        moving[path] = result
    return moving[path]


def _first_sample_without_default(prims) -> float | None:
    """Earliest time sample among geometry attributes that have no default value."""
    from pxr import Usd

    first = None
    for prim in prims:
        for attribute in _geometry_attributes(prim):
            if not attribute or not attribute.GetNumTimeSamples():
                continue
            if attribute.Get(Usd.TimeCode.Default()) is not None:
                continue
            t = attribute.GetTimeSamples()[0]
            first = t if first is None else min(first, t)
    return first


def _usd_mesh_part(path: Path, mesh, time) -> RawPart:
    """One USD mesh: world points, fan triangles (holes dropped), original polygons kept
    (corner order reversed for ``leftHanded`` meshes so every part is right-handed)."""
    from pxr import UsdGeom

    prim = mesh.GetPrim()
    where = str(prim.GetPath())
    points = np.asarray(_usd_value(mesh.GetPointsAttr(), time, ()), dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(
        _usd_value(mesh.GetFaceVertexCountsAttr(), time, ()), dtype=np.int64
    ).reshape(-1)
    indices = np.asarray(
        _usd_value(mesh.GetFaceVertexIndicesAttr(), time, ()), dtype=np.int64
    ).reshape(-1)
    if (counts < 0).any() or counts.sum() != len(indices):
        raise InputError(
            path,
            f"{where}: faceVertexCounts sum to {int(counts.sum())} "
            f"but faceVertexIndices has {len(indices)} entries",
        )
    if mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded:
        # kept right-handed from here on, in the traced faces and in the part's topology
        indices = reverse_polygons(counts, indices)
    traced_counts, traced_indices = counts, indices
    holes = np.asarray(_usd_value(mesh.GetHoleIndicesAttr(), time, ()), dtype=np.int64).reshape(-1)
    if len(holes):
        keep = np.ones(len(counts), dtype=bool)
        keep[holes[(holes >= 0) & (holes < len(counts))]] = False
        traced_indices = indices[np.repeat(keep, counts)]
        traced_counts = counts[keep]
    faces = fan_triangulate(traced_counts, traced_indices)
    normals = _usd_normals(mesh, time, len(points))
    matrix = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), dtype=np.float64)
    return transformed_part(
        prim.GetName(),
        points,
        faces,
        normals,
        counts,
        indices,
        matrix[:3, :3],
        matrix[3, :3],
        where,
    )


def _usd_value(attribute, time, default):
    """An attribute's value at ``time``, else its earliest time sample, else ``default``."""
    from pxr import Usd

    value = attribute.Get(time) if attribute else None
    if value is None and attribute and attribute.GetNumTimeSamples():
        value = attribute.Get(Usd.TimeCode.EarliestTime())
    return default if value is None else value


def _usd_normals(mesh, time, n: int) -> FloatArray | None:
    """Per-point normals from ``primvars:normals`` (preferred) or ``normals``, else None.

    Only ``vertex`` / ``varying`` interpolation maps one normal to each point;
    face-varying or uniform normals are left to the angle-weighted computation.
    """
    from pxr import UsdGeom

    primvar = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        values, interpolation = primvar.ComputeFlattened(time), primvar.GetInterpolation()
    else:
        attribute = mesh.GetNormalsAttr()
        if not attribute.HasAuthoredValue():
            return None
        values, interpolation = _usd_value(attribute, time, None), mesh.GetNormalsInterpolation()
    if values is None or interpolation not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        return None
    normals = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    return normals if len(normals) == n else None


def read_colours_usd(path: str | Path) -> np.ndarray:
    """(n, 3) linear ``primvars:displayColor`` of every mesh, in :func:`read_ao_usd`'s
    order (a constant colour repeated for each point)."""
    path = check_input_file(path, "USD file")
    from pxr import Sdf, Usd, UsdGeom

    stage = _open_fresh(path, Sdf, Usd)
    parts: list[np.ndarray] = []
    for prim in baked_meshes(stage, Usd.TimeCode.Default()):
        mesh = UsdGeom.Mesh(prim)
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        values = primvar.ComputeFlattened() if primvar and primvar.HasValue() else None
        if values is None:
            raise InputError(path, f"{prim.GetPath()}: no displayColor to show")
        values = np.asarray(values, dtype=np.float64).reshape(-1, 3)
        points = _usd_value(mesh.GetPointsAttr(), Usd.TimeCode.Default(), None)
        n_points = 0 if points is None else len(points)
        interp = primvar.GetInterpolation()
        if interp == UsdGeom.Tokens.constant and len(values) == 1:
            values = np.repeat(values, n_points, axis=0)
        elif interp not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) or len(values) != n_points:
            raise InputError(
                path,
                f"{prim.GetPath()}: displayColor has {len(values)} {interp} values "
                f"but the mesh has {n_points} points; expected one per vertex",
            )
        parts.append(values)
    if not parts:
        raise InputError(path, "no mesh in the stage")
    return np.concatenate(parts)
