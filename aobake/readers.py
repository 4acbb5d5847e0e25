"""Reading mesh files (and trimesh objects) into a :class:`~aobake.mesh.Surface`.

One reader per format turns a file into :class:`~aobake.mesh.RawPart` records (world
space, polygons kept); :func:`aobake.mesh.assemble_surface` validates and concatenates
them. PLY is parsed by :mod:`aobake.ply` and OBJ here; STL, OFF and glTF go through
trimesh and USD through pxr. This is the only module that imports trimesh; trimesh and
pxr are imported inside the functions that need them, so importing it stays light.
"""

from __future__ import annotations

import json
import logging
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ._types import FloatArray
from .errors import InputError
from .mesh import (
    RawPart,
    Surface,
    assemble_surface,
    check_index_range,
    fan_triangulate,
    normalize_rows,
    reverse_polygons,
    transformed_part,
)
from .ply import PlyList, read_ply

log = logging.getLogger(__name__)

#: Input suffixes and the format name used in messages.
INPUT_FORMATS = {
    ".ply": "PLY",
    ".obj": "OBJ",
    ".stl": "STL",
    ".off": "OFF",
    ".glb": "glTF",
    ".gltf": "glTF",
    ".usd": "USD",
    ".usda": "USD",
    ".usdc": "USD",
    ".usdz": "USD",
}

# Longest foreign error text kept in a one-line message.
_REASON_CHARS = 160


def load_mesh(path: str | Path) -> Surface:
    """Read a mesh file into a :class:`Surface`, keeping its vertices exactly.

    Vertex count and order are the file's: duplicate, unreferenced and degenerate data
    survive (trimesh, used for STL, OFF and glTF, is called with ``process=False``, which
    does not merge vertices). A file holding several meshes
    (glTF nodes, OBJ objects, USD ``Mesh`` prims) becomes one surface whose parts are
    the meshes in file order, with world transforms applied; point clouds and curves are
    ignored.

    Parameters
    ----------
    path : str or Path
        A ``.ply``, ``.obj``, ``.stl``, ``.off``, ``.glb``, ``.gltf``, ``.usd``,
        ``.usda``, ``.usdc`` or ``.usdz`` file.

    Returns
    -------
    Surface
        ``positions`` (n, 3) float64 in world space, ``faces`` (m, 3) int64 (polygons
        fan-triangulated), ``normals`` (n, 3) float64: the file's vertex normals
        (PLY ``nx ny nz``, OBJ ``vn``, glTF ``NORMAL``, USD ``normals`` with vertex or
        varying interpolation) transformed by the inverse transpose of the world
        transform, else angle-weighted face normals; zero rows where no normal exists.

    Raises
    ------
    InputError
        Missing file, directory, unsupported suffix, unreadable or malformed data, empty
        mesh, no faces, NaN/inf coordinates, or indices out of range. The message is one
        line starting with the file name; foreign exceptions are chained.

    Notes
    -----
    Transforms that mirror (negative determinant) and USD ``leftHanded`` meshes get
    their winding reversed, so faces stay counter-clockwise around their normal. PLY
    (parsed by :mod:`aobake.ply`) and OBJ are read by aobake rather than trimesh 5.2,
    which drops trailing unreferenced OBJ vertices, merges OBJ objects, misreads binary
    PLY faces of mixed polygon sizes and accepts truncated ASCII PLY.
    """
    path = Path(path)
    fmt = INPUT_FORMATS.get(path.suffix.lower())
    if not path.exists():
        raise InputError(path, "file not found")
    if path.is_dir():
        raise InputError(path, "is a directory, not a mesh file")
    if fmt is None:
        supported = ", ".join(sorted(INPUT_FORMATS))
        raise InputError(
            path, f"unsupported input suffix {path.suffix or '(none)'!r}; use one of {supported}"
        )
    metadata: dict = {"format": fmt}
    try:
        if fmt == "USD":
            raw = _read_usd(path, metadata)
        else:
            data = path.read_bytes()
            if fmt == "OBJ":
                raw = _read_obj(path, data)
            elif fmt == "PLY":
                raw = _read_ply(path, data)
            else:
                raw = _read_with_trimesh(path, data, fmt, metadata)
    except InputError:
        raise
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or _reason(exc)}") from exc
    except Exception as exc:  # any loader failure becomes a one-line InputError
        raise InputError(path, f"cannot read as {fmt}: {_reason(exc)}") from exc
    return assemble_surface(raw, path, metadata)


def mesh_from_trimesh(obj: Any, *, source: str = "<memory>") -> Surface:
    """A :class:`Surface` from a ``trimesh.Trimesh`` or ``trimesh.Scene``.

    A scene is flattened like a multi-mesh file: world transforms applied, one part per
    geometry node in graph order, point clouds and paths ignored. Vertices are used
    as they are (no merging).

    Parameters
    ----------
    obj : trimesh.Trimesh or trimesh.Scene
    source : str
        Name used in messages and as :attr:`Surface.source`.

    Returns
    -------
    Surface
        Normals are the mesh's cached ``vertex_normals`` when it has them (loaded from a
        file or assigned), else angle-weighted.

    Raises
    ------
    TypeError
        ``obj`` is neither a Trimesh nor a Scene.
    InputError
        No faces, NaN/inf coordinates or indices out of range.
    """
    import trimesh

    if isinstance(obj, trimesh.Trimesh):
        file_name = obj.metadata.get("file_name")
        name = str(obj.metadata.get("name") or (Path(file_name).stem if file_name else "mesh"))
        raw = [_raw_from_trimesh(name, obj, np.eye(4))]
    elif isinstance(obj, trimesh.Scene):
        raw = _raw_from_scene(obj, _scene_items(obj))
    else:
        raise TypeError(f"expected trimesh.Trimesh or trimesh.Scene, got {type(obj).__name__}")
    return assemble_surface(raw, source)


def _reason(exc: BaseException) -> str:
    """A foreign exception's message on one short line (USD's Tf errors reduced to their text)."""
    text = str(exc)
    tf_messages = re.findall(
        r"Error in '[^']*' at line \d+ in file [^:]* : '(.*?)'(?=\s*(?:Error in|$))", text, re.S
    )
    if tf_messages:
        text = tf_messages[0]
    text = " ".join(text.split()) or type(exc).__name__
    if len(text) > _REASON_CHARS:
        text = text[: _REASON_CHARS - 3] + "..."
    return text


def _decode_text(
    path: Path, data: bytes, fmt: str, problem: str = "binary data, not a text file"
) -> str:
    """Text of a text format, or :class:`InputError` when the bytes are binary."""
    problem = f"cannot read as {fmt}: {problem}"
    if b"\x00" in data:
        raise InputError(path, problem)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # legacy exporters write latin-1 names and comments
    if re.search(r"[\x01-\x08\x0e-\x1f\x7f]", text):
        raise InputError(path, problem)
    return text


# -- trimesh formats: STL, OFF, glTF ---------------------------------------------------


def _read_with_trimesh(path: Path, data: bytes, fmt: str, metadata: dict) -> list[RawPart]:
    import io

    import trimesh

    suffix = path.suffix.lower()[1:]
    kwargs: dict = {"process": False, "validate": False}
    if fmt == "glTF":
        kwargs.update(merge_primitives=False, skip_materials=True)
        metadata.update(up_axis="Y", meters_per_unit=1.0)  # fixed by the glTF specification
    elif fmt == "STL" and not _is_binary_stl(data):
        _decode_text(
            path, data, fmt, "neither binary (size does not match the triangle count) nor text"
        )
    elif fmt == "OFF" and not re.match(
        r"\s*(#[^\n]*\n\s*)*[A-Z]*OFF", _decode_text(path, data, fmt)
    ):
        raise InputError(path, "cannot read as OFF: missing 'OFF' header")
    if fmt == "glTF":
        # glTF may reference buffers next to it: load by path so the resolver finds them
        scene = trimesh.load_scene(str(path), **kwargs)
    else:
        scene = trimesh.load_scene(io.BytesIO(data), file_type=suffix, **kwargs)
    items = _scene_items(scene)
    if fmt == "glTF":
        items = _gltf_file_order(path, data, scene, items)
    elif len(items) == 1:
        _, matrix, geometry, node = items[0]
        items = [(path.stem, matrix, geometry, node)]
    return _raw_from_scene(scene, items)


def _is_binary_stl(data: bytes) -> bool:
    """True when the size matches a binary STL's header (80 bytes, count, 50 per triangle)."""
    return len(data) >= 84 and len(data) == 84 + 50 * struct.unpack("<I", data[80:84])[0]


def _scene_items(scene) -> list[tuple[str, FloatArray, str, str]]:
    """``(part name, world matrix, geometry name, graph node)`` per geometry node, in graph
    order; the part name starts as the node name."""
    items = []
    for node in scene.graph.nodes_geometry:
        matrix, geometry = scene.graph[node]
        items.append((node, np.asarray(matrix, dtype=np.float64), geometry, node))
    return items


def _raw_from_scene(scene, items) -> list[RawPart]:
    """One part per item whose geometry is a Trimesh; other geometry adds vertices only."""
    import trimesh

    raw = []
    for name, matrix, geometry_name, _ in items:
        geometry = scene.geometry.get(geometry_name)
        if isinstance(geometry, trimesh.Trimesh):
            raw.append(_raw_from_trimesh(str(name), geometry, matrix))
        elif geometry is not None and getattr(geometry, "vertices", None) is not None:
            # point clouds and paths occlude nothing; kept only for the "no faces" count
            raw.append(
                RawPart(
                    str(name),
                    np.zeros((len(geometry.vertices), 3)),
                    np.zeros((0, 3), dtype=np.int64),
                    None,
                    np.zeros(0, dtype=np.int64),
                    np.zeros(0, dtype=np.int64),
                )
            )
    return raw


def _raw_from_trimesh(name: str, mesh, matrix: FloatArray) -> RawPart:
    """A part from a Trimesh under a (4, 4) column-vector transform.

    trimesh keeps normals it read from a file (or that were assigned) in
    ``mesh._cache["vertex_normals"]``; reading the ``vertex_normals`` property instead
    would compute them when absent, so the cache is checked first.
    """
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    normals = None
    if "vertex_normals" in mesh._cache:
        cached = mesh._cache["vertex_normals"]
        if cached is not None and np.shape(cached) == positions.shape:
            normals = np.asarray(cached, dtype=np.float64)
    counts = np.full(len(faces), 3, dtype=np.int64)
    return transformed_part(
        name,
        positions,
        faces,
        normals,
        counts,
        faces.reshape(-1).copy(),
        matrix[:3, :3].T,
        matrix[:3, 3],
    )


def _gltf_file_order(path: Path, data: bytes, scene, items):
    """Reorder trimesh's glTF graph (which it builds depth-first from the last root) into
    the file's node order: depth-first, roots and children as listed, primitives as listed.

    Items whose node cannot be matched keep trimesh's order after the matched ones.
    """
    from trimesh.util import unique_name

    try:
        header = _gltf_json(path, data)
        nodes = header.get("nodes", [])
        scenes = header.get("scenes", [])
        roots = scenes[header.get("scene", 0)].get("nodes", []) if scenes else []
    except Exception:  # the order is a nicety; trimesh already read the file
        log.debug(
            "%s: glTF header not parsed, keeping trimesh's node order", path.name, exc_info=True
        )
        return items
    preorder: dict[int, int] = {}
    stack = list(reversed(roots))
    while stack:
        index = stack.pop()
        if index in preorder or not 0 <= index < len(nodes):
            continue
        preorder[index] = len(preorder)
        stack.extend(reversed(nodes[index].get("children", [])))
    # trimesh's frame names for glTF nodes (same uniquifying rule as its loader)
    name_index: dict[str, int] = {}
    counts: dict = {}
    for i, node in enumerate(nodes):
        name_index[unique_name(node.get("name", str(i)), name_index, counts=counts)] = i
    geometry_rank = {name: i for i, name in enumerate(scene.geometry)}
    parents = scene.graph.transforms.parents
    keyed = []
    for rank, (_, matrix, geometry, node) in enumerate(items):
        name = node
        index = name_index.get(node)
        if index is None and parents.get(node) in name_index:
            # a primitive of a multi-primitive mesh: trimesh names its frame with a random
            # suffix, so the part takes the (deterministic) geometry name instead
            index, name = name_index[parents[node]], geometry
        if index in preorder:
            key = (0, preorder[index], geometry_rank.get(geometry, 0), rank)
        else:
            key = (1, 0, 0, rank)
        keyed.append((key, (name, matrix, geometry, node)))
    keyed.sort(key=lambda pair: pair[0])
    return [item for _, item in keyed]


def _gltf_json(path: Path, data: bytes) -> dict:
    """The JSON document of a .gltf file or of a .glb's first chunk."""
    if data[:4] == b"glTF":
        length, kind = struct.unpack("<II", data[12:20])
        if kind != 0x4E4F534A:  # "JSON"
            raise ValueError("first GLB chunk is not JSON")
        return json.loads(data[20 : 20 + length])
    return json.loads(data)

# -- PLY -------------------------------------------------------------------------------


def _read_ply(path: Path, data: bytes) -> list[RawPart]:
    """Vertices (``x y z``, optional ``nx ny nz``) and polygon faces of a PLY.

    Faces may mix polygon sizes; they keep their polygons (fan-triangulated for tracing).
    Other elements and properties (colours, edges...) are read and ignored.
    """
    ply = read_ply(path, data)
    vertex = ply.elements.get("vertex")
    if vertex is None:
        return []
    columns = vertex.properties
    missing = [axis for axis in "xyz" if not isinstance(columns.get(axis), np.ndarray)]
    if missing:
        raise InputError(path, f"cannot read as PLY: vertex element lacks property {missing[0]!r}")
    positions = np.column_stack([columns[axis] for axis in "xyz"]).astype(np.float64)
    normals = None
    if all(isinstance(columns.get(key), np.ndarray) for key in ("nx", "ny", "nz")):
        normals = np.column_stack([columns[key] for key in ("nx", "ny", "nz")]).astype(np.float64)
    counts, corners = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    face = ply.elements.get("face")
    lists = {} if face is None else face.properties
    lists = {key: value for key, value in lists.items() if isinstance(value, PlyList)}
    if lists:
        key = next((k for k in ("vertex_indices", "vertex_index") if k in lists), next(iter(lists)))
        counts, corners = lists[key]
        if corners.dtype.kind == "f" and not (corners == np.round(corners)).all():
            raise InputError(path, f"cannot read as PLY: face {key!r} holds non-integer indices")
        corners = corners.astype(np.int64)
    faces = fan_triangulate(counts, corners)
    return [RawPart(path.stem, positions, faces, normals, counts, corners)]


# -- OBJ -------------------------------------------------------------------------------


def _read_obj(path: Path, data: bytes) -> list[RawPart]:
    """Parse ``v``, ``vn``, ``f`` and ``o`` lines of a Wavefront OBJ.

    Every ``v`` line is one output vertex, in file order. Faces keep their polygons
    (fan-triangulated for tracing). A vertex's file normal is the ``vn`` its face
    corners reference (the mean when corners disagree). Objects (``o``) become parts
    when each one's faces use only the vertices listed after its ``o`` line; otherwise
    the file is one part, because OBJ indices are global and the order must not change.
    """
    text = _decode_text(path, data, "OBJ")
    vertices: list[tuple[float, float, float]] = []
    vn: list[tuple[float, float, float]] = []
    counts: list[int] = []
    corners: list[int] = []
    corner_normals: list[int] = []
    objects: list[tuple[str, int, int]] = []  # (name, first vertex, first polygon)
    for number, line in enumerate(text.splitlines(), 1):
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0]
        try:
            if key == "v":
                if len(tokens) < 4:
                    raise ValueError("a vertex needs 3 coordinates")
                vertices.append((float(tokens[1]), float(tokens[2]), float(tokens[3])))
            elif key == "vn":
                if len(tokens) < 4:
                    raise ValueError("a normal needs 3 components")
                vn.append((float(tokens[1]), float(tokens[2]), float(tokens[3])))
            elif key == "f":
                counts.append(len(tokens) - 1)
                for corner in tokens[1:]:
                    fields = corner.split("/")
                    corners.append(_obj_index(fields[0], len(vertices)))
                    if len(fields) > 2 and fields[2]:
                        k = _obj_index(fields[2], len(vn))
                        if k < 0:
                            raise ValueError(f"normal index {fields[2]} before the first vn")
                        corner_normals.append(k)
                    else:
                        corner_normals.append(-1)
            elif key == "o":
                objects.append((" ".join(tokens[1:]) or path.stem, len(vertices), len(counts)))
        except ValueError as exc:
            shown = line.strip()[:40]
            raise InputError(path, f"cannot read as OBJ: line {number} ({shown!r}): {exc}") from exc
    positions = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    normal_table = np.array(vn, dtype=np.float64).reshape(-1, 3)
    counts_arr = np.array(counts, dtype=np.int64)
    corners_arr = np.array(corners, dtype=np.int64)
    normal_index = np.array(corner_normals, dtype=np.int64)
    n = len(positions)
    check_index_range(n, (counts_arr, corners_arr), path, "faces")
    bad_normal = normal_index >= len(normal_table)
    if bad_normal.any():
        raise InputError(
            path,
            f"{int(bad_normal.sum())} face corners reference normal {int(normal_index.max()) + 1} "
            f"(1-based) but the file has {len(normal_table)} normals",
        )
    normals = _obj_vertex_normals(n, corners_arr, normal_index, normal_table, path.name)
    faces = fan_triangulate(counts_arr, corners_arr)
    return _obj_parts(path, positions, normals, counts_arr, corners_arr, faces, objects)


def _obj_index(field: str, count: int) -> int:
    """0-based index from an OBJ index field (1-based, or negative = relative to the end)."""
    value = int(field)
    if value > 0:
        return value - 1
    if value < 0:
        return count + value
    raise ValueError("OBJ indices start at 1, got 0")


def _obj_vertex_normals(n: int, corners, normal_index, table, source: str) -> FloatArray | None:
    """Per-vertex normals from per-corner ``vn`` references; NaN rows where none is given."""
    used = normal_index >= 0
    if not used.any():
        return None
    v, k = corners[used], normal_index[used]
    normals = np.zeros((n, 3))
    np.add.at(normals, v, normalize_rows(table[k]))
    hits = np.bincount(v, minlength=n)
    first = np.full(n, -1, dtype=np.int64)
    first[v[::-1]] = k[::-1]
    conflicting = int(
        ((hits > 0) & (np.bincount(v, weights=(k != first[v]), minlength=n) > 0)).sum()
    )
    if conflicting:
        log.info("%s: %d vertices have several vn; their normals are averaged", source, conflicting)
    normals[hits == 0] = np.nan
    return normals


def _obj_parts(path, positions, normals, counts, corners, faces, objects) -> list[RawPart]:
    """Split by ``o`` objects when every object's faces stay inside its own vertex block."""
    n = len(positions)
    whole = [RawPart(path.stem, positions, faces, normals, counts, corners)]
    if len(objects) == 0 or (len(objects) == 1 and objects[0][1] == 0 and objects[0][2] == 0):
        if objects:
            whole[0].name = objects[0][0]
        return whole
    # blocks: vertices/polygons before the first "o" form an implicit first object
    starts = [(path.stem, 0, 0)] if (objects[0][1] > 0 or objects[0][2] > 0) else []
    blocks = starts + objects
    v_bounds = [b[1] for b in blocks] + [n]
    p_bounds = [b[2] for b in blocks] + [len(counts)]
    owner = np.repeat(np.arange(len(counts)), counts)
    corner_block = np.searchsorted(np.array(p_bounds[1:-1]), owner, side="right")
    vertex_block = np.searchsorted(np.array(v_bounds[1:-1]), corners, side="right")
    empty = any(
        v_bounds[i] == v_bounds[i + 1] or p_bounds[i] == p_bounds[i + 1] for i in range(len(blocks))
    )
    if empty or (corner_block != vertex_block).any():
        log.info("%s: OBJ objects share vertices; read as one part", path.name)
        return whole
    corner_bounds = np.concatenate([[0], np.cumsum(counts)])
    raw = []
    for i, (name, _, _) in enumerate(blocks):
        v0, v1, p0, p1 = v_bounds[i], v_bounds[i + 1], p_bounds[i], p_bounds[i + 1]
        local = corners[corner_bounds[p0] : corner_bounds[p1]] - v0
        part_counts = counts[p0:p1]
        part_faces = fan_triangulate(part_counts, local)
        if len(part_faces) == 0:
            return whole  # a part without triangles would be dropped with its vertices
        part_normals = None if normals is None else normals[v0:v1]
        raw.append(RawPart(name, positions[v0:v1], part_faces, part_normals, part_counts, local))
    return raw


# -- USD -------------------------------------------------------------------------------


def _read_usd(path: Path, metadata: dict) -> list[RawPart]:
    """Every visible ``UsdGeom.Mesh`` in world space (instance proxies included; guide and
    proxy purposes skipped)."""
    try:
        from pxr import Usd, UsdGeom
    except ImportError as exc:
        raise InputError(
            path, "reading USD needs the usd-core package (pip install usd-core)"
        ) from exc

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise InputError(path, "cannot read as USD: the stage did not open")
    metadata.update(
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
    )
    time = Usd.TimeCode.Default()
    skipped_purposes = {UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy}
    raw = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        imageable = UsdGeom.Imageable(prim)
        if imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        if imageable.ComputePurpose() in skipped_purposes:
            continue
        raw.append(_usd_mesh_part(path, UsdGeom.Mesh(prim), time))
    if not raw:
        raise InputError(path, "no visible UsdGeom.Mesh in the stage")
    return raw


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
