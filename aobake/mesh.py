"""The :class:`Surface` a bake works on: validation, derived per-vertex data, assembly.

Files are read by :mod:`aobake.io`, which hands each mesh it finds here as a
:class:`RawPart`; :func:`assemble_surface` validates the parts and concatenates them.
Imports numpy and aobake's ``constants``, ``errors`` and ``_types`` only. Knows nothing
about AO methods.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._types import FloatArray, IndexArray
from .constants import MAX_EXTENT, MIN_EXTENT, NORMAL_EPS
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
        (USD stage metrics; glTF is always Y up, meters; PLY: as an aobake PLY records
        them); what writers need to keep the input: ``"ply"`` (the PLY as read),
        ``"gltf_path"`` (the glTF document) and, for USD, ``"path"`` (the resolved
        source the overlay sublayers), ``"time"`` (the time code read, None for the
        default time) and ``"animated"`` (meshes with time-varying points or
        transforms). Empty for array input.
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
    from .kernels import normals as _k  # numba only when needed

    n = positions.shape[0]
    if faces.shape[0] == 0:
        return np.zeros((n, 3))
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if faces.min() < 0 or faces.max() >= n:
        raise ValueError(f"face indices outside 0..{n - 1}")  # the kernels do not bounds-check
    fn, cosines = _k.corner_cosines(positions, faces)
    # arccos in numpy: its SIMD arccos may differ from libm's in the last bit, and these
    # normals are bit for bit those of the numpy formulation (tests/test_normals_kernel.py)
    np.arccos(cosines, out=cosines)
    start, corners = _k.corners_by_vertex(faces, n)
    out = _k.gather_weighted(fn, cosines, start, corners)
    del fn, cosines, start, corners  # 150 bytes per vertex, freed before the next peak
    return _normalize_in_place(out)


def normalize_rows(v: FloatArray) -> FloatArray:
    """Rows scaled to unit length; rows shorter than NORMAL_EPS become zero (never NaN)."""
    return _normalize_in_place(np.array(v, dtype=np.float64))


def _normalize_in_place(v: np.ndarray) -> np.ndarray:
    """:func:`normalize_rows` of a float64 array the caller owns, overwritten (no copy)."""
    length = np.linalg.norm(v, axis=1)
    ok = length > NORMAL_EPS
    np.divide(v, length[:, None], out=v, where=ok[:, None])
    v[~ok] = 0.0
    return v


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

    Scales ray-origin offsets and near-field distances to the local triangle size
    (one pass over the faces in ``kernels.topology.longest_edges``).
    """
    from .kernels.topology import longest_edges  # numba only when needed

    return longest_edges(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
    )


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
    faces = np.array(faces_in, dtype=np.int64)  # a copy: the surface never shares the caller's
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != positions.shape:
            raise InputError(
                source, f"normals have shape {normals.shape}, positions {positions.shape}"
            )
    raw = RawPart(name, positions, faces, normals, np.full(len(faces), 3), faces.reshape(-1))
    return assemble_surface([raw], source)


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
        No vertices, no faces, NaN/inf coordinates, a face index outside ``[0, n)``,
        or a nonzero extent outside what float64 products can hold
        (:func:`check_extent`; the methods refuse a zero extent).
    """
    n = positions.shape[0]
    if n == 0:
        raise InputError(source, "mesh is empty (no vertices)")
    if faces.shape[0] == 0:
        raise InputError(source, f"mesh has {n} vertices but no faces")
    check_index_range(n, faces, source)
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            source, f"{int(bad.sum())} vertices have NaN or inf coordinates (first: vertex {first})"
        )
    check_extent(positions, source, zero=True)


def check_extent(positions: FloatArray, source: str | Path, *, zero: bool = False) -> None:
    """Raise :class:`InputError` unless the bounding box's largest side is in
    ``[MIN_EXTENT, MAX_EXTENT]``: beyond these limits float64 products of coordinates
    (areas, normals) underflow or overflow. ``zero``: an extent of zero (every vertex at
    one point: a file may hold that, but it has no AO) passes."""
    with np.errstate(over="ignore", invalid="ignore"):
        extent = float((positions.max(axis=0) - positions.min(axis=0)).max())
    if extent == 0.0:
        if zero:
            return
        raise InputError(source, "all vertices are at one point (the mesh has zero extent)")
    if not np.isfinite(extent) or extent > MAX_EXTENT:
        raise InputError(
            source, f"coordinates span {extent:.3g}, more than the {MAX_EXTENT:g} aobake supports"
        )
    if extent < MIN_EXTENT:
        raise InputError(
            source, f"coordinates span {extent:.3g}, less than the {MIN_EXTENT:g} aobake supports"
        )


def check_index_range(n: int, faces, source: str | Path, what: str = "faces") -> None:
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
# Assembly: every reader returns RawPart records, assemble_surface validates and concatenates.


@dataclass
class RawPart:
    """One mesh as a reader found it, in world space, before validation.

    Attributes
    ----------
    name : str
        Becomes :attr:`Part.name`.
    positions : (n, 3) float
    faces : (m, 3) int
        Triangles, indices local to the part.
    normals : (n, 3) float or None
        File normals; rows that are zero or not finite are computed instead.
    face_vertex_counts, face_vertex_indices : int arrays
        The original polygons (see :class:`Part`), indices local to the part.
    prim_path : str or None
        Source USD prim path.
    """

    name: str
    positions: FloatArray
    faces: IndexArray
    normals: FloatArray | None
    face_vertex_counts: IndexArray
    face_vertex_indices: IndexArray
    prim_path: str | None = None


def assemble_surface(
    raw: list[RawPart], where: str | Path, metadata: dict | None = None, prepare=None
) -> Surface:
    """Validate parts, compute missing normals, concatenate into one :class:`Surface`.

    Parameters
    ----------
    raw : list of RawPart
        The parts in file order; parts without polygons (point clouds) are dropped
        (logged); parts whose polygons give no triangle are kept (a warning).
    where : str or Path
        What errors name (the path); the surface's ``source`` is its name.
    metadata : dict, optional
        Becomes :attr:`Surface.metadata`.
    prepare : callable, optional
        Called as ``prepare(positions, faces)`` with the surface's own arrays once they
        are checked, before the normals: a caller starts there what needs only those.

    Returns
    -------
    Surface

    Raises
    ------
    InputError
        No vertices, no faces, NaN/inf coordinates, or indices out of range.
    """
    source = Path(where).name if isinstance(where, Path) else str(where)
    if not any(len(p.faces) for p in raw):
        # no part can be traced: report the whole file's vertices and faces
        n = sum(len(p.positions) for p in raw)
        validate_arrays(np.zeros((n, 3)), np.zeros((0, 3), dtype=np.int64), where)
    # A mesh with polygons but no triangle (all of two corners, or all holes) keeps its
    # vertices: they are output vertices (baked, occluding nothing). Point clouds and
    # curves (no polygons at all) are not meshes and are left out.
    with_faces = [p for p in raw if len(p.faces) or len(p.face_vertex_counts)]
    flat = [p.name for p in with_faces if not len(p.faces)]
    if flat:
        log.warning(
            "%s: %d meshes have no triangle (faces of fewer than 3 corners, or holes), "
            "first %r: their vertices are baked but occlude nothing",
            source,
            len(flat),
            flat[0],
        )
    if len(with_faces) < len(raw):
        log.info("%s: %d meshes without faces ignored", source, len(raw) - len(with_faces))
    for p in with_faces:
        check_index_range(len(p.positions), p.faces, where)
        check_index_range(
            len(p.positions), (p.face_vertex_counts, p.face_vertex_indices), where, "polygons"
        )
    offsets = np.cumsum([0] + [len(p.positions) for p in with_faces])
    face_offsets = np.cumsum([0] + [len(p.faces) for p in with_faces])
    if len(with_faces) == 1:  # the part's own arrays: no copies (memory)
        positions = np.ascontiguousarray(with_faces[0].positions, dtype=np.float64)
        faces = np.ascontiguousarray(with_faces[0].faces, dtype=np.int64)
    else:
        positions = np.concatenate([p.positions for p in with_faces]).astype(np.float64, copy=False)
        faces = np.concatenate(
            [p.faces + off for p, off in zip(with_faces, offsets[:-1], strict=True)]
        ).astype(np.int64, copy=False)
    validate_arrays(positions, faces, where)
    positions, faces = np.ascontiguousarray(positions), np.ascontiguousarray(faces)
    if prepare is not None:
        prepare(positions, faces)
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
        positions,
        faces,
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


# -- polygon helpers the readers share -------------------------------------------------


def transformed_part(
    name: str,
    positions: FloatArray,
    faces: IndexArray,
    normals: FloatArray | None,
    counts: IndexArray,
    indices: IndexArray,
    linear: FloatArray,
    translation: FloatArray,
    prim_path: str | None = None,
) -> RawPart:
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
        indices = reverse_polygons(counts, indices)
    return RawPart(name, positions, faces, normals, counts, indices, prim_path)


def reverse_polygons(counts: IndexArray, indices: IndexArray) -> IndexArray:
    """Flat polygon corner lists with each polygon's corner order reversed."""
    counts = np.asarray(counts, dtype=np.int64)
    ends = np.cumsum(counts)
    owner = np.repeat(np.arange(len(counts)), counts)
    position = np.arange(len(indices)) - (ends - counts)[owner]
    return np.asarray(indices)[(ends - 1)[owner] - position]


def fan_triangulate(counts: IndexArray, indices: IndexArray) -> IndexArray:
    """Triangles (m, 3) fanned from each polygon's first corner (< 3 corners: dropped)."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if counts.size and (counts == 3).all() and indices.size == 3 * counts.size:
        return indices.reshape(-1, 3).copy()  # all triangles: nothing to fan
    starts = np.cumsum(counts) - counts
    n_tri = np.maximum(counts - 2, 0)
    first = np.repeat(starts, n_tri)
    k = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    return np.stack([indices[first], indices[first + k], indices[first + k + 1]], axis=1).reshape(
        -1, 3
    )


def weld_vertices(surface: Surface) -> tuple[Surface, IndexArray]:
    """The surface with bit-identical positions merged within each part, for ``--weld``.

    A triangle soup (STL) or a mesh split at normal or UV seams then bakes as one
    connected surface: fewer vertices to compute, and the copies of a vertex get one
    value. Parts are not welded to each other (touching objects stay separate shells).
    The file's normals are not used, since split copies disagree on them: the welded
    mesh gets angle-weighted normals.

    Returns
    -------
    welded : Surface
        First occurrences in input order; faces and polygons re-indexed.
    inverse : (n,) int64
        ``welded`` vertex of each input vertex: ``ao[inverse]`` is per input vertex.
    """
    raw, inverse, start = [], [], 0
    for part in surface.parts:
        positions = surface.positions[part.vertex_start : part.vertex_stop]
        _, first, local = np.unique(positions, axis=0, return_index=True, return_inverse=True)
        local = local.reshape(-1)
        # renumber in order of first occurrence, so the welded vertices keep the input order
        order = np.argsort(first, kind="stable")
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(len(order))
        local = rank[local]
        faces = surface.faces[part.face_start : part.face_stop] - part.vertex_start
        raw.append(
            RawPart(
                part.name,
                positions[np.sort(first)],
                local[faces],
                None,
                part.face_vertex_counts,
                local[part.face_vertex_indices],
                part.prim_path,
            )
        )
        inverse.append(local + start)
        start += len(order)
    welded = assemble_surface(raw, surface.source, surface.metadata)
    return welded, np.concatenate(inverse)
