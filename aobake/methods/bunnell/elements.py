"""The disk method's elements: one oriented disk per vertex, in normalised coordinates.

Numpy-facing; the areas and cells come from ``aobake.kernels.polygon`` (``_poly.*``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..._types import FloatArray, IndexArray
from ...constants import NEAR_OFFSET_REL
from ...contacts import contact_points
from ...kernels import polygon as _poly
from ...mesh import Surface


@dataclass(frozen=True)
class DiskElements:
    """One oriented disk per vertex: every vertex receives, disks with area and normal cast.

    Coordinates are normalised: ``(input - origin) / scale`` in float64, so the kernels'
    float32 arithmetic sees numbers of order 1 whatever the mesh's size and position.

    Attributes
    ----------
    positions : (n, 3) float64
        Normalised vertex positions (disk centres).
    normals : (n, 3) float64
        Unit normals, zero rows where a vertex has none.
    areas : (n,) float64
        Disk areas (normalised): 1/3 of the adjacent triangle areas (0 when isolated).
    emitter_index : (k,) int64
        Vertices whose disk casts: ``areas > 0`` and a nonzero normal.
    points : (n, 3) float64
        Where each vertex receives: ``positions + NEAR_OFFSET_REL sqrt(A) n``, moved to
        the vertex's own side where another shell touches it
        (:func:`aobake.contacts.contact_points`).
    faces : (m, 3) int64
        The surface's triangles (not a copy).
    origin : (3,) float64
        Centre of the input's bounding box.
    scale : float
        Largest extent of the input's bounding box (1 when it is a point).
    """

    positions: FloatArray
    normals: FloatArray
    areas: FloatArray
    emitter_index: IndexArray
    points: FloatArray
    faces: IndexArray
    origin: FloatArray
    scale: float

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_emitters(self) -> int:
        return int(self.emitter_index.shape[0])

    @cached_property
    def _cells(self) -> tuple[IndexArray, IndexArray]:
        return _poly.cell_corners(self.faces, self.n_vertices)

    @property
    def corner_start(self) -> IndexArray:
        """(n + 1,) int64: vertex j's triangles are rows ``corner_start[j]:corner_start[j + 1]``
        of :attr:`corners` (``aobake.kernels.polygon.cell_corners``; built on first use: the
        tree pass builds its own table, in tree order)."""
        return self._cells[0]

    @property
    def corners(self) -> IndexArray:
        """(3 m, 2) int64: the other two corners of each triangle around each vertex."""
        return self._cells[1]


def build_elements(surface: Surface) -> DiskElements:
    """Disk elements of a surface (all parts: one element set for the whole scene).

    Parameters
    ----------
    surface : Surface

    Returns
    -------
    DiskElements
        Area ``A_i = sum_f area_f / 3`` over the triangles f around vertex i
        (``0.5 |e1 x e2|``, never Heron).
    """
    with np.errstate(under="ignore"):  # denormal inputs: flushing to zero is harmless
        return _build_elements(surface)


def _build_elements(surface: Surface) -> DiskElements:
    positions = np.ascontiguousarray(surface.positions, dtype=np.float64)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64).reshape(-1, 3)
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or normals.shape != positions.shape:
        raise ValueError(
            f"positions and normals must both be (n, 3), got {positions.shape} and {normals.shape}"
        )
    n = positions.shape[0]
    if n:
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        origin = 0.5 * (lo + hi)
        extent = float((hi - lo).max())
    else:
        origin, extent = np.zeros(3), 0.0
    scale = extent if extent > 0.0 and math.isfinite(extent) else 1.0
    local = positions - origin  # a new array: divided in place
    local /= scale
    areas = np.zeros(n)
    _poly.vertex_areas(local, faces, areas)
    casts = (areas > 0.0) & normals.any(axis=1)
    # Receivers sit a tiny lift above their vertex, placed like the reference's ray
    # origins: where another shell touches the vertex, contacts.contact_points keeps the
    # receiver on the vertex's own side. In normalised coordinates, so its float32 probe
    # rounds alike at any scale.
    normalised = dataclasses.replace(surface, positions=local)
    points, _ = contact_points(normalised, local, np.zeros(3), NEAR_OFFSET_REL * np.sqrt(areas))
    points = np.ascontiguousarray(points)
    return DiskElements(
        local,
        normals,
        areas,
        np.flatnonzero(casts).astype(np.int64),
        points,
        faces,
        origin,
        scale,
    )
