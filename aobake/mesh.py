"""Reading meshes into a :class:`Surface`, validating them, and derived per-vertex data.

The only module that imports trimesh (and pxr for USD input); both are imported inside
the functions that need them so that importing this module stays light. Knows nothing
about AO methods.
"""

from __future__ import annotations

import json
import logging
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._types import FloatArray, IndexArray
from .constants import NORMAL_EPS
from .errors import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Part:
    """One output mesh of a :class:`Surface` (a file can hold several).

    Attributes
    ----------
    name : str
        Mesh name (USD prim name, glTF node name, or the file stem).
    vertex_start, vertex_stop : int
        This part's vertices are ``surface.positions[vertex_start:vertex_stop]``.
    face_start, face_stop : int
        This part's triangles are ``surface.faces[face_start:face_stop]`` (global indices).
    face_vertex_counts : (k,) int64
        Original polygon sizes, for writers that keep the input topology (USD).
    face_vertex_indices : (sum(counts),) int64
        Original polygon corners, indices local to the part (0 = ``vertex_start``),
        counter-clockwise about the outside like ``faces`` (corner order reversed where
        the source was a USD ``leftHanded`` mesh or its transform mirrors).
    prim_path : str or None
        Source USD prim path, when the input was USD.
    """

    name: str
    vertex_start: int
    vertex_stop: int
    face_start: int
    face_stop: int
    face_vertex_counts: IndexArray
    face_vertex_indices: IndexArray
    prim_path: str | None = None

    @property
    def n_vertices(self) -> int:
        return self.vertex_stop - self.vertex_start


@dataclass(frozen=True)
class Surface:
    """A triangulated occluding scene whose vertices are the output vertices.

    Attributes
    ----------
    positions : (n, 3) float64
        World-space vertex positions, all parts concatenated in input order.
    faces : (m, 3) int64
        Triangles (global vertex indices) used for tracing and for the disk method.
    normals : (n, 3) float64
        Unit vertex normals (file normals when present, else angle-weighted face
        normals); a vertex without a defined normal has a zero row here.
    parts : tuple of Part
        The output meshes, in file order.
    source : str
        Where the surface came from (file name), used in messages.
    metadata : dict
        Facts read from the file: ``"format"`` (``"PLY"``, ``"USD"``...) and, where the
        format defines them, ``"up_axis"`` (``"Y"``/``"Z"``) and ``"meters_per_unit"``
        (USD stage metrics; glTF is always Y up, meters). Empty for array input.
    """

    positions: FloatArray
    faces: IndexArray
    normals: FloatArray
    parts: tuple[Part, ...]
    source: str = "<memory>"
    metadata: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])


def face_normals_and_areas(
    positions: FloatArray, faces: IndexArray
) -> tuple[FloatArray, FloatArray]:
    """Unit face normals and areas from 0.5 |e1 x e2| (never Heron: it goes NaN on needles).

    Returns
    -------
    normals : (m, 3) float64
        Unit normals; zero rows for zero-area faces.
    areas : (m,) float64
    """
    tri = positions[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(cross)
    ok = length > 0.0
    normals[ok] = cross[ok] / length[ok, None]
    return normals, 0.5 * length


def angle_weighted_normals(positions: FloatArray, faces: IndexArray) -> FloatArray:
    """Vertex normals as face normals weighted by the corner angle at the vertex.

    Returns
    -------
    normals : (n, 3) float64
        Unit normals; a zero row where the weighted sum vanishes (isolated vertices,
        only degenerate faces, or normals that cancel).
    """
    n = positions.shape[0]
    out = np.zeros((n, 3))
    if faces.shape[0] == 0:
        return out
    fn, _ = face_normals_and_areas(positions, faces)
    tri = positions[faces]
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        la = np.linalg.norm(a, axis=1)
        lb = np.linalg.norm(b, axis=1)
        denom = la * lb
        cos = np.divide(
            np.einsum("ij,ij->i", a, b), denom, out=np.zeros_like(denom), where=denom > 0
        )
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(out, faces[:, k], fn * angle[:, None])
    return normalize_rows(out)


def normalize_rows(v: FloatArray) -> FloatArray:
    """Rows scaled to unit length; rows shorter than NORMAL_EPS become zero (never NaN)."""
    length = np.linalg.norm(v, axis=1)
    out = np.zeros_like(v)
    ok = length > NORMAL_EPS
    out[ok] = v[ok] / length[ok, None]
    return out


def vertex_areas(positions: FloatArray, faces: IndexArray) -> FloatArray:
    """One third of the area of the triangles around each vertex (Bunnell's disk area).

    Returns
    -------
    areas : (n,) float64, zero for unreferenced vertices.
    """
    _, fa = face_normals_and_areas(positions, faces)
    out = np.zeros(positions.shape[0])
    for k in range(3):
        np.add.at(out, faces[:, k], fa / 3.0)
    return out


def vertex_edge_lengths(positions: FloatArray, faces: IndexArray) -> FloatArray:
    """Longest edge touching each vertex (zero for unreferenced vertices).

    Used to scale ray-origin offsets to the local triangle size.
    """
    out = np.zeros(positions.shape[0])
    for k in range(3):
        i, j = faces[:, k], faces[:, (k + 1) % 3]
        length = np.linalg.norm(positions[j] - positions[i], axis=1)
        np.maximum.at(out, i, length)
        np.maximum.at(out, j, length)
    return out


def surface_from_arrays(
    positions, faces, normals=None, *, name: str = "mesh", source: str = "<memory>"
) -> Surface:
    """Build a validated one-part :class:`Surface` from arrays (the library entry point).

    Parameters
    ----------
    positions : (n, 3) float
    faces : (m, 3) int
    normals : (n, 3) float, optional
        Vertex normals; computed (angle-weighted) when omitted. Rows that are zero or
        not finite are replaced by the computed normal.
    name, source : str
        Part name and the source name used in error messages.

    Returns
    -------
    Surface
        One part covering all vertices and faces, arrays copied to float64 / int64.

    Raises
    ------
    InputError
        Wrong shapes, non-integer indices, empty mesh, no faces, non-finite
        coordinates, or indices out of range.
    """
    positions = np.array(positions, dtype=np.float64)
    faces_in = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(source, f"positions must have shape (n, 3), got {positions.shape}")
    if faces_in.size == 0:
        faces_in = faces_in.reshape(0, 3)
    if faces_in.ndim != 2 or faces_in.shape[1] != 3:
        raise InputError(source, f"faces must have shape (m, 3), got {faces_in.shape}")
    if not np.issubdtype(faces_in.dtype, np.integer):
        as_float = faces_in.astype(np.float64)
        if not (np.isfinite(as_float).all() and (as_float == np.round(as_float)).all()):
            raise InputError(source, "faces must hold integer vertex indices")
    faces = np.ascontiguousarray(faces_in, dtype=np.int64)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != positions.shape:
            raise InputError(
                source, f"normals have shape {normals.shape}, positions {positions.shape}"
            )
    raw = _RawPart(
        name, positions, faces, normals, np.full(len(faces), 3), faces.reshape(-1).copy()
    )
    return _assemble([raw], source)


def validate_arrays(positions: FloatArray, faces: IndexArray, source: str | Path) -> None:
    """Raise :class:`InputError` for meshes no method can use.

    Degenerate faces, duplicate and unreferenced vertices are legal and pass.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    source : str or Path
        File (or source name) the message starts with.

    Raises
    ------
    InputError
        No vertices, no faces, NaN/inf coordinates, or a face index outside ``[0, n)``.
    """
    n = positions.shape[0]
    if n == 0:
        raise InputError(source, "mesh is empty (no vertices)")
    if faces.shape[0] == 0:
        raise InputError(source, f"mesh has {n} vertices but no faces")
    _check_index_range(n, faces, source)
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            source, f"{int(bad.sum())} vertices have NaN or inf coordinates (first: vertex {first})"
        )


def _check_index_range(n: int, faces, source: str | Path, what: str = "faces") -> None:
    """Raise the one-line out-of-range message if any row of ``faces`` leaves ``[0, n)``.

    ``faces`` is (m, 3), or a list of polygons given as ``(counts, flat_indices)``.
    """
    if isinstance(faces, tuple):
        counts, flat = faces
        out = (flat < 0) | (flat >= n)
        if not out.any():
            return
        # a polygon is bad when any of its corners is; counts may contain zeros
        owner = np.repeat(np.arange(len(counts)), counts)
        n_rows = int(np.unique(owner[out]).size)
        values = flat[out]
    else:
        out = (faces < 0) | (faces >= n)
        if not out.any():
            return
        n_rows = int(out.any(axis=1).sum())
        values = faces[out]
    worst = int(values.max()) if (values >= n).any() else int(values.min())
    raise InputError(
        source, f"{n_rows} {what} reference vertex {worst} but the mesh has {n} vertices"
    )


def warn_missing_normals(
    normals: FloatArray, positions: FloatArray, faces: IndexArray, source: str
) -> None:
    """Log a warning when referenced vertices have no defined normal.

    Such vertices still get a defined AO (see the methods); unreferenced vertices are
    expected to have none and are not reported.
    """
    referenced = np.zeros(positions.shape[0], dtype=bool)
    referenced[faces.reshape(-1)] = True
    missing = referenced & ~normals.any(axis=1)
    if missing.any():
        log.warning(
            "%s: %d vertices have no defined normal (degenerate faces around them)",
            source,
            int(missing.sum()),
        )


# --------------------------------------------------------------------------------------
# Loading: every reader returns _RawPart records, _assemble validates and concatenates.

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


@dataclass
class _RawPart:
    """One mesh as read, in world space, before validation (indices local to the part)."""

    name: str
    positions: FloatArray
    faces: IndexArray
    normals: FloatArray | None
    face_vertex_counts: IndexArray
    face_vertex_indices: IndexArray
    prim_path: str | None = None


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
    their winding reversed, so faces stay counter-clockwise around their normal. PLY and
    OBJ are read by small readers in this module rather than trimesh 5.2, which drops
    trailing unreferenced OBJ vertices, merges OBJ objects, misreads binary PLY faces of
    mixed polygon sizes and accepts truncated ASCII PLY.
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
    return _assemble(raw, path, metadata)


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
    return _assemble(raw, source)


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


def _assemble(raw: list[_RawPart], where: str | Path, metadata: dict | None = None) -> Surface:
    """Validate parts, compute missing normals, concatenate into one :class:`Surface`.

    ``where`` is the path (or name) errors carry; the surface's ``source`` is its name.
    """
    source = Path(where).name if isinstance(where, Path) else str(where)
    with_faces = [p for p in raw if len(p.faces)]
    if not with_faces:
        # no part can be traced: report the whole file's vertices and faces
        n = sum(len(p.positions) for p in raw)
        validate_arrays(np.zeros((n, 3)), np.zeros((0, 3), dtype=np.int64), where)
    if len(with_faces) < len(raw):
        log.info("%s: %d meshes without faces ignored", source, len(raw) - len(with_faces))
    for p in with_faces:
        _check_index_range(len(p.positions), p.faces, where)
        _check_index_range(
            len(p.positions), (p.face_vertex_counts, p.face_vertex_indices), where, "polygons"
        )
    positions = np.concatenate([p.positions for p in with_faces]).astype(np.float64, copy=False)
    offsets = np.cumsum([0] + [len(p.positions) for p in with_faces])
    face_offsets = np.cumsum([0] + [len(p.faces) for p in with_faces])
    faces = np.concatenate(
        [p.faces + off for p, off in zip(with_faces, offsets[:-1], strict=True)]
    ).astype(np.int64, copy=False)
    validate_arrays(positions, faces, where)
    normals = np.concatenate([_vertex_normals(p.positions, p.faces, p.normals) for p in with_faces])
    warn_missing_normals(normals, positions, faces, source)
    parts = tuple(
        Part(
            p.name,
            int(offsets[i]),
            int(offsets[i + 1]),
            int(face_offsets[i]),
            int(face_offsets[i + 1]),
            np.asarray(p.face_vertex_counts, dtype=np.int64),
            np.asarray(p.face_vertex_indices, dtype=np.int64),
            p.prim_path,
        )
        for i, p in enumerate(with_faces)
    )
    return Surface(
        np.ascontiguousarray(positions),
        np.ascontiguousarray(faces),
        normals,
        parts,
        source,
        dict(metadata or {}),
    )


def _vertex_normals(
    positions: FloatArray, faces: IndexArray, given: FloatArray | None
) -> FloatArray:
    """Unit normals: ``given`` where finite and non-zero, angle-weighted elsewhere.

    Returns
    -------
    normals : (n, 3) float64
        Zero rows where neither source defines a normal.
    """
    if given is None:
        return angle_weighted_normals(positions, faces)
    given = np.array(given, dtype=np.float64)
    given[~np.isfinite(given).all(axis=1)] = 0.0
    out = normalize_rows(given)
    missing = ~out.any(axis=1)
    if missing.any():
        out[missing] = angle_weighted_normals(positions, faces)[missing]
    return out


def _transformed(
    name: str,
    positions: FloatArray,
    faces: IndexArray,
    normals: FloatArray | None,
    counts: IndexArray,
    indices: IndexArray,
    linear: FloatArray,
    translation: FloatArray,
    prim_path: str | None = None,
) -> _RawPart:
    """A part moved to world space by ``p @ linear + translation`` (row vectors).

    Normals use the inverse transpose of ``linear`` (renormalised later); a mirroring
    transform reverses the winding of triangles and polygons alike.
    """
    positions = np.asarray(positions, dtype=np.float64) @ linear + translation
    det = float(np.linalg.det(linear))
    if normals is not None:
        if det != 0.0 and np.isfinite(det):
            normals = np.asarray(normals, dtype=np.float64) @ np.linalg.inv(linear).T
        else:
            normals = None  # a collapsing transform has no normal transform
    if det < 0.0:
        faces = faces[:, ::-1]
        indices = _reverse_polygons(counts, indices)
    return _RawPart(name, positions, faces, normals, counts, indices, prim_path)


def _reverse_polygons(counts: IndexArray, indices: IndexArray) -> IndexArray:
    """Flat polygon corner lists with each polygon's corner order reversed."""
    counts = np.asarray(counts, dtype=np.int64)
    ends = np.cumsum(counts)
    owner = np.repeat(np.arange(len(counts)), counts)
    position = np.arange(len(indices)) - (ends - counts)[owner]
    return np.asarray(indices)[(ends - 1)[owner] - position]


def _fan_triangulate(counts: IndexArray, indices: IndexArray) -> IndexArray:
    """Triangles (m, 3) fanned from each polygon's first corner (< 3 corners: dropped)."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    starts = np.cumsum(counts) - counts
    n_tri = np.maximum(counts - 2, 0)
    first = np.repeat(starts, n_tri)
    k = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    return np.stack([indices[first], indices[first + k], indices[first + k + 1]], axis=1).reshape(
        -1, 3
    )


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


def _read_with_trimesh(path: Path, data: bytes, fmt: str, metadata: dict) -> list[_RawPart]:
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


def _raw_from_scene(scene, items) -> list[_RawPart]:
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
                _RawPart(
                    str(name),
                    np.zeros((len(geometry.vertices), 3)),
                    np.zeros((0, 3), dtype=np.int64),
                    None,
                    np.zeros(0, dtype=np.int64),
                    np.zeros(0, dtype=np.int64),
                )
            )
    return raw


def _raw_from_trimesh(name: str, mesh, matrix: FloatArray) -> _RawPart:
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
    return _transformed(
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
# Read here, not by trimesh: trimesh 5.2 silently misreads binary PLY whose faces mix
# polygon sizes (it takes every list length from the first face) and accepts truncated
# ASCII PLY as a smaller mesh.

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass
class _PlyProperty:
    name: str
    dtype: str  # scalar type, or the item type of a list
    count_dtype: str | None = None  # set for list properties


@dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[_PlyProperty]


def _read_ply(path: Path, data: bytes) -> list[_RawPart]:
    """Vertices (``x y z``, optional ``nx ny nz``) and polygon faces of an ASCII or binary PLY.

    Faces may mix polygon sizes; they keep their polygons (fan-triangulated for tracing).
    """
    fmt, elements, body = _ply_header(path, data)
    values = (
        _ply_ascii(path, data[body:], elements)
        if fmt == "ascii"
        else _ply_binary(path, data, body, elements, fmt)
    )
    vertex = values.get("vertex", {})
    if not vertex:
        return []
    missing = [axis for axis in "xyz" if axis not in vertex]
    if missing:
        raise InputError(path, f"cannot read as PLY: vertex element lacks property {missing[0]!r}")
    positions = np.column_stack(
        [np.asarray(vertex[axis], dtype=np.float64).reshape(-1) for axis in "xyz"]
    )
    normals = None
    if all(key in vertex for key in ("nx", "ny", "nz")):
        normals = np.column_stack(
            [np.asarray(vertex[key], dtype=np.float64).reshape(-1) for key in ("nx", "ny", "nz")]
        )
    counts, corners = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    face = values.get("face", {})
    lists = [key for key, value in face.items() if isinstance(value, tuple)]
    if lists:
        key = next((k for k in ("vertex_indices", "vertex_index") if k in lists), lists[0])
        counts, corners = face[key]
    faces = _fan_triangulate(counts, corners)
    return [_RawPart(path.stem, positions, faces, normals, counts, corners)]


def _ply_header(path: Path, data: bytes) -> tuple[str, list[_PlyElement], int]:
    """Format, elements and the byte offset where the body starts."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(path, "cannot read as PLY: no 'ply' magic or 'end_header' line")
    newline = data.find(b"\n", end)
    body = len(data) if newline < 0 else newline + 1
    fmt = None
    elements: list[_PlyElement] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
                if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise ValueError(f"unknown format {fmt!r}")
            elif words[0] == "element":
                elements.append(_PlyElement(words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                elements[-1].properties.append(
                    _PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
                )
            elif words[0] == "property":
                elements[-1].properties.append(_PlyProperty(words[2], _PLY_TYPES[words[1]]))
            else:
                raise ValueError(f"unexpected header line {line.strip()[:40]!r}")
        except (IndexError, KeyError, ValueError) as exc:
            reason = (
                str(exc)
                if isinstance(exc, ValueError)
                else f"bad header line {line.strip()[:40]!r}"
            )
            raise InputError(path, f"cannot read as PLY: {reason}") from exc
    if fmt is None:
        raise InputError(path, "cannot read as PLY: header has no 'format' line")
    if any(e.count < 0 for e in elements):
        raise InputError(path, "cannot read as PLY: negative element count in header")
    return fmt, elements, body


def _ply_empty(element: _PlyElement) -> dict:
    """Columns of an element with no rows."""
    empty = np.zeros(0, dtype=np.int64)
    return {p.name: (empty, empty) if p.count_dtype else np.zeros(0) for p in element.properties}


def _ply_truncated(path: Path, element: _PlyElement) -> InputError:
    return InputError(
        path,
        f"cannot read as PLY: file ends before its {element.count} {element.name} elements "
        "(truncated)",
    )


def _ply_binary(
    path: Path, data: bytes, offset: int, elements: list[_PlyElement], fmt: str
) -> dict:
    """``{element: {property: array or (counts, flat items)}}`` from a binary body."""
    endian = "<" if fmt == "binary_little_endian" else ">"
    out = {}
    for element in elements:
        values, offset = _ply_binary_element(path, data, offset, element, endian)
        out[element.name] = values
    return out


def _ply_binary_element(path, data, offset, element, endian):
    """One element's columns and the offset after it. Lists: (counts, flat items)."""
    props, count = element.properties, element.count
    if count == 0:
        return _ply_empty(element), offset
    # fast path: every row has the list lengths of the first row (always true for
    # fixed-size rows and for meshes of one polygon size), checked on every row
    fields, lengths, pos = [], [], offset
    for i, prop in enumerate(props):
        if prop.count_dtype is None:
            fields.append((f"s{i}", endian + prop.dtype))
            pos += np.dtype(prop.dtype).itemsize
            continue
        size = np.dtype(prop.count_dtype).itemsize
        n = (
            0
            if pos + size > len(data)
            else int(np.frombuffer(data, endian + prop.count_dtype, 1, pos)[0])
        )
        fields += [(f"c{i}", endian + prop.count_dtype), (f"l{i}", endian + prop.dtype, (n,))]
        lengths.append((i, n))
        pos += size + n * np.dtype(prop.dtype).itemsize
    row = np.dtype(fields)
    if offset + count * row.itemsize <= len(data):
        table = np.frombuffer(data, row, count, offset)
        if all((table[f"c{i}"] == n).all() for i, n in lengths):
            values = {}
            for i, prop in enumerate(props):
                if prop.count_dtype is None:
                    values[prop.name] = table[f"s{i}"]
                else:
                    n = dict(lengths)[i]
                    values[prop.name] = (
                        np.full(count, n, dtype=np.int64),
                        table[f"l{i}"].reshape(-1).astype(np.int64),
                    )
            return values, offset + count * row.itemsize
    elif not lengths:
        raise _ply_truncated(path, element)
    # slow path: rows of varying length, walked one by one
    codes = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}
    columns: list[list] = [[] for _ in props]
    list_counts: list[list[int]] = [[] for _ in props]
    pos = offset
    try:
        for _ in range(count):
            for i, prop in enumerate(props):
                if prop.count_dtype is None:
                    columns[i].append(struct.unpack_from(endian + codes[prop.dtype], data, pos)[0])
                    pos += np.dtype(prop.dtype).itemsize
                else:
                    (n,) = struct.unpack_from(endian + codes[prop.count_dtype], data, pos)
                    pos += np.dtype(prop.count_dtype).itemsize
                    columns[i].extend(
                        struct.unpack_from(f"{endian}{n}{codes[prop.dtype]}", data, pos)
                    )
                    list_counts[i].append(n)
                    pos += n * np.dtype(prop.dtype).itemsize
    except struct.error as exc:
        raise _ply_truncated(path, element) from exc
    values = {}
    for i, prop in enumerate(props):
        if prop.count_dtype is None:
            values[prop.name] = np.array(columns[i], dtype=prop.dtype)
        else:
            values[prop.name] = (
                np.array(list_counts[i], dtype=np.int64),
                np.array(columns[i], dtype=np.int64),
            )
    return values, pos


def _ply_ascii(path: Path, body: bytes, elements: list[_PlyElement]) -> dict:
    """``{element: {property: array or (counts, flat items)}}`` from an ASCII body."""
    tokens = body.split()
    out, pos = {}, 0
    try:
        for element in elements:
            values, pos = _ply_ascii_element(path, tokens, pos, element)
            out[element.name] = values
    except ValueError as exc:
        raise InputError(path, f"cannot read as PLY: {_reason(exc)}") from exc
    return out


def _ply_ascii_element(path, tokens, pos, element):
    props, count = element.properties, element.count
    if count == 0:
        return _ply_empty(element), pos
    lists = [i for i, prop in enumerate(props) if prop.count_dtype is not None]
    # fast path: fixed row width (the first row's list lengths, checked on every row)
    width, starts = 0, []
    for prop in props:
        starts.append(width)
        if prop.count_dtype is None:
            width += 1
        else:
            if pos + width >= len(tokens):
                break
            width += 1 + int(float(tokens[pos + width]))
    if len(starts) == len(props) and pos + count * width <= len(tokens):
        table = np.array(tokens[pos : pos + count * width]).astype(np.float64).reshape(count, width)
        if all((table[:, starts[i]] == table[0, starts[i]]).all() for i in lists):
            values = {}
            for i, prop in enumerate(props):
                if prop.count_dtype is None:
                    values[prop.name] = table[:, starts[i]]
                else:
                    n = int(table[0, starts[i]])
                    items = table[:, starts[i] + 1 : starts[i] + 1 + n]
                    values[prop.name] = (
                        np.full(count, n, dtype=np.int64),
                        items.reshape(-1).astype(np.int64),
                    )
            return values, pos + count * width
    elif not lists:
        raise _ply_truncated(path, element)
    # slow path: rows of varying length
    columns: list[list] = [[] for _ in props]
    list_counts: list[list[int]] = [[] for _ in props]
    for _ in range(count):
        for i, prop in enumerate(props):
            if pos >= len(tokens):
                raise _ply_truncated(path, element)
            if prop.count_dtype is None:
                columns[i].append(tokens[pos])
                pos += 1
            else:
                n = int(float(tokens[pos]))
                if n < 0 or pos + 1 + n > len(tokens):
                    raise _ply_truncated(path, element)
                columns[i].extend(tokens[pos + 1 : pos + 1 + n])
                list_counts[i].append(n)
                pos += 1 + n
    values = {}
    for i, prop in enumerate(props):
        column = np.array(columns[i]).astype(np.float64) if columns[i] else np.zeros(0)
        if prop.count_dtype is None:
            values[prop.name] = column
        else:
            values[prop.name] = (np.array(list_counts[i], dtype=np.int64), column.astype(np.int64))
    return values, pos


# -- OBJ -------------------------------------------------------------------------------


def _read_obj(path: Path, data: bytes) -> list[_RawPart]:
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
    _check_index_range(n, (counts_arr, corners_arr), path, "faces")
    bad_normal = normal_index >= len(normal_table)
    if bad_normal.any():
        raise InputError(
            path,
            f"{int(bad_normal.sum())} face corners reference normal {int(normal_index.max()) + 1} "
            f"(1-based) but the file has {len(normal_table)} normals",
        )
    normals = _obj_vertex_normals(n, corners_arr, normal_index, normal_table, path.name)
    faces = _fan_triangulate(counts_arr, corners_arr)
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


def _obj_parts(path, positions, normals, counts, corners, faces, objects) -> list[_RawPart]:
    """Split by ``o`` objects when every object's faces stay inside its own vertex block."""
    n = len(positions)
    whole = [_RawPart(path.stem, positions, faces, normals, counts, corners)]
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
        part_faces = _fan_triangulate(part_counts, local)
        if len(part_faces) == 0:
            return whole  # a part without triangles would be dropped with its vertices
        part_normals = None if normals is None else normals[v0:v1]
        raw.append(_RawPart(name, positions[v0:v1], part_faces, part_normals, part_counts, local))
    return raw


# -- USD -------------------------------------------------------------------------------


def _read_usd(path: Path, metadata: dict) -> list[_RawPart]:
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


def _usd_mesh_part(path: Path, mesh, time) -> _RawPart:
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
        indices = _reverse_polygons(counts, indices)
    traced_counts, traced_indices = counts, indices
    holes = np.asarray(_usd_value(mesh.GetHoleIndicesAttr(), time, ()), dtype=np.int64).reshape(-1)
    if len(holes):
        keep = np.ones(len(counts), dtype=bool)
        keep[holes[(holes >= 0) & (holes < len(counts))]] = False
        traced_indices = indices[np.repeat(keep, counts)]
        traced_counts = counts[keep]
    faces = _fan_triangulate(traced_counts, traced_indices)
    normals = _usd_normals(mesh, time, len(points))
    matrix = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), dtype=np.float64)
    return _transformed(
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
