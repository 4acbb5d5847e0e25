"""STL, OFF and glTF/GLB meshes in through trimesh, and trimesh objects in memory.

The only module that imports trimesh, and only inside its functions, so importing it
stays light. trimesh is called with ``process=False``, which keeps the vertices as read.
"""

from __future__ import annotations

import json
import logging
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FloatArray
from ..errors import InputError
from ..mesh import RawPart, Surface, assemble_surface, transformed_part
from .common import decode_text

log = logging.getLogger(__name__)


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


def read_parts(path: Path, data: bytes, fmt: str, metadata: dict) -> list[RawPart]:
    """One part per mesh of an STL, OFF or glTF file (``fmt``), in file order, world space.

    glTF fixes the up axis and unit, which go into ``metadata``.
    """
    import io

    import trimesh

    suffix = path.suffix.lower()[1:]
    kwargs: dict = {"process": False, "validate": False}
    if fmt == "glTF":
        kwargs.update(merge_primitives=False, skip_materials=True)
        metadata.update(up_axis="Y", meters_per_unit=1.0)  # fixed by the glTF specification
        metadata["gltf_path"] = str(path.resolve())  # glTF output writes this document back
    elif fmt == "STL" and not _is_binary_stl(data):
        decode_text(
            path, data, fmt, "neither binary (size does not match the triangle count) nor text"
        )
    elif fmt == "OFF":
        check_off_counts(path, decode_text(path, data, fmt))
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


def check_off_counts(path: Path, text: str) -> None:
    """Raise :class:`InputError` unless an OFF file's rows match its header's counts.

    trimesh reads the counts and takes rows as they come: a vertex count too large
    turns face rows into vertices, a truncated file bakes as a smaller mesh. Here every
    vertex row must hold 3 numbers or more, every face row ``k i_1 .. i_k`` (k >= 1, then
    optional colour values), and no row may follow the last face.
    """
    rows = [line.split("#", 1)[0].split() for line in text.splitlines()]
    rows = [r for r in rows if r]
    if not rows or not re.fullmatch(r"[A-Z]*OFF", rows[0][0]):
        raise InputError(path, "cannot read as OFF: missing 'OFF' header")
    tokens = rows[0][1:]
    body = rows[1:]
    if not tokens:
        if not body:
            raise InputError(path, "cannot read as OFF: no counts after the 'OFF' header")
        tokens, body = body[0], body[1:]
    try:
        n_vertices, n_faces = int(tokens[0]), int(tokens[1])
    except (IndexError, ValueError):
        raise InputError(path, f"cannot read as OFF: bad counts line {' '.join(tokens)!r}") from None
    if n_vertices < 0 or n_faces < 0:
        raise InputError(path, f"cannot read as OFF: negative counts {n_vertices} {n_faces}")
    if len(body) < n_vertices + n_faces:
        raise InputError(
            path,
            f"OFF header promises {n_vertices} vertices and {n_faces} faces but the file "
            f"has {len(body)} rows (truncated, or counts wrong)",
        )
    for i, row in enumerate(body[:n_vertices]):
        if len(row) < 3 or not all(_is_number(t) for t in row[:3]):
            raise InputError(path, f"OFF vertex {i} is not 3 numbers: {' '.join(row)[:60]!r} (counts wrong?)")
    for i, row in enumerate(body[n_vertices : n_vertices + n_faces]):
        k = int(row[0]) if row[0].isdigit() else -1
        if k < 1 or len(row) < k + 1 or not all(t.isdigit() for t in row[1 : k + 1]):
            raise InputError(path, f"OFF face {i} is not a polygon row: {' '.join(row)[:60]!r} (counts wrong?)")
    extra = len(body) - n_vertices - n_faces
    if extra:
        raise InputError(
            path,
            f"OFF header promises {n_vertices} vertices and {n_faces} faces but {extra} more "
            "rows follow (counts wrong)",
        )


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


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
