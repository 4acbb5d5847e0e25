"""Wavefront OBJ meshes in: ``v``, ``vn``, ``f`` and ``o`` lines, polygons kept.

Read here rather than by trimesh 5.2, which drops trailing unreferenced vertices and
merges objects. Imports numpy and aobake's ``errors`` and ``mesh`` only.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .._types import FloatArray
from ..errors import InputError
from ..mesh import RawPart, check_index_range, fan_triangulate, normalize_rows
from .common import decode_text

log = logging.getLogger(__name__)


def read_parts(path: Path, data: bytes) -> list[RawPart]:
    """Parse ``v``, ``vn``, ``f`` and ``o`` lines of a Wavefront OBJ.

    Every ``v`` line is one output vertex, in file order. Faces keep their polygons
    (fan-triangulated for tracing). A vertex's file normal is the ``vn`` its face
    corners reference (the mean when corners disagree). Objects (``o``) become parts
    when each one's faces use only the vertices listed after its ``o`` line; otherwise
    the file is one part, because OBJ indices are global and the order must not change.
    """
    text = decode_text(path, data, "OBJ")
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
