"""Procedural test scenes, most with closed-form cosine-weighted AO (derived in the docstrings)."""

from __future__ import annotations

import numpy as np
import trimesh

from aobake.mesh import Surface, surface_from_arrays


def regular_polygon(radius: float, sides: int, z: float, *, normal_up: bool = True):
    """Fan-triangulated regular polygon in the plane z, centred on the axis.

    Returns positions (sides + 1, 3) and faces (sides, 3); normals face +z if ``normal_up``.
    """
    t = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    rim = np.c_[radius * np.cos(t), radius * np.sin(t), np.full(sides, z)]
    positions = np.vstack([[0.0, 0.0, z], rim])
    i = np.arange(sides)
    faces = np.c_[np.zeros(sides, dtype=np.int64), 1 + i, 1 + (i + 1) % sides]
    if not normal_up:
        faces = faces[:, ::-1]
    return positions, faces


def receiver_under_disk(radius: float, height: float, sides: int = 256) -> Surface:
    """A disk (polygon) at z = height over a tiny receiver triangle at the origin facing +z.

    Vertex ``sides + 1`` is the receiver at the origin; its normal is +z. The polygon
    faces down (towards the receiver) but either side occludes.
    """
    pos, faces = regular_polygon(radius, sides, height, normal_up=False)
    s = 1e-4 * radius
    receiver = np.array([[0.0, 0.0, 0.0], [s, 0.0, 0.0], [0.0, s, 0.0]])
    positions = np.vstack([pos, receiver])
    k = pos.shape[0]
    faces = np.vstack([faces, [[k, k + 1, k + 2]]])
    normals = np.zeros_like(positions)
    normals[:, 2] = 1.0
    normals[: pos.shape[0], 2] = -1.0
    return surface_from_arrays(positions, faces, normals)


def polygon_form_factor(point, normal, polygon) -> float:
    """Lambert's exact point-to-polygon form factor (cosine-weighted A of a polygon above
    the tangent plane): F = 1/(2 pi) sum_i angle_i * (n . unit(v_i x v_{i+1}))."""
    v = np.asarray(polygon, dtype=np.float64) - np.asarray(point, dtype=np.float64)
    v /= np.linalg.norm(v, axis=1)[:, None]
    total = 0.0
    for i in range(len(v)):
        a, b = v[i], v[(i + 1) % len(v)]
        c = np.cross(a, b)
        angle = np.arccos(np.clip(a @ b, -1.0, 1.0))
        total += angle * (np.asarray(normal) @ (c / np.linalg.norm(c)))
    return abs(total) / (2.0 * np.pi)


def sphere(radius: float = 1.0, subdivisions: int = 3, *, inward: bool = False) -> Surface:
    """Icosphere; with ``inward`` the faces and normals point inside (A = 1 everywhere)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    faces = m.faces[:, ::-1] if inward else m.faces
    return surface_from_arrays(m.vertices, faces)


def box(extents=(1.0, 2.0, 3.0)) -> Surface:
    """A box with split-free corners (8 vertices): convex, A = 0 everywhere."""
    m = trimesh.creation.box(extents=extents)
    return surface_from_arrays(m.vertices, m.faces)


def ground_grid(half: float, cells: int, z: float = 0.0):
    """A square grid in the plane z facing +z: positions and faces."""
    t = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    positions = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    b, c, d = a + cells + 1, a + 1, a + cells + 2
    faces = np.vstack([np.c_[a, b, d], np.c_[a, d, c]])
    return positions, faces


def sphere_on_ground(
    radius: float = 0.5, subdivisions: int = 3, gap: float = 0.0, cells: int = 16
) -> tuple[Surface, int]:
    """An icosphere with a vertex pointing straight down, its lowest point at z = gap,
    over a ground grid at z = 0 (side 8 radius).

    ``gap`` < 0 makes the sphere penetrate the ground slightly, as modelling tools often
    leave it. Returns the surface and the index of the lowest sphere vertex, whose true
    occlusion tends to 1 as gap -> 0 (the ground fills its whole hemisphere).
    """
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = m.vertices.copy()
    low = int(np.argmin(v[:, 2]))
    # rotate so that vertex `low` points exactly down
    a = v[low] / np.linalg.norm(v[low])
    target = np.array([0.0, 0.0, -1.0])
    axis = np.cross(a, target)
    if np.linalg.norm(axis) > 1e-15:
        rot = trimesh.transformations.rotation_matrix(np.arccos(np.clip(a @ target, -1, 1)), axis)[
            :3, :3
        ]
        v = v @ rot.T
    v[low] = [0.0, 0.0, -radius]
    v[:, 2] += radius + gap
    v[low, 2] = gap
    gp, gf = ground_grid(4.0 * radius, cells)
    positions = np.vstack([v, gp])
    faces = np.vstack([m.faces, gf + len(v)])
    return surface_from_arrays(positions, faces), low


def parallel_plates(gap: float, half: float, cells: int = 8) -> Surface:
    """Two square grids a ``gap`` apart, both normals facing the gap.

    With max distance r <= half - |x| at a receiver on the lower plate (r >= gap):
    cosine-weighted A = 1 - (gap / r)^2, so ao = (gap / r)^2.
    """
    p0, f0 = ground_grid(half, cells, 0.0)
    p1, f1 = ground_grid(half, cells, gap)
    positions = np.vstack([p0, p1])
    faces = np.vstack([f0, f1[:, ::-1] + len(p0)])
    normals = np.zeros_like(positions)
    normals[: len(p0), 2] = 1.0
    normals[len(p0) :, 2] = -1.0
    return surface_from_arrays(positions, faces, normals)


def random_convex(seed: int, subdivisions: int = 1, scale: float = 1.0) -> Surface:
    """A random affine image of an icosphere (a convex polyhedron), angle-weighted
    normals: A = 0 at every vertex. Linear maps keep convexity, so no hull is needed."""
    rng = np.random.default_rng(seed)
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    linear = rng.normal(size=(3, 3))
    while abs(np.linalg.det(linear)) < 0.05:
        linear = rng.normal(size=(3, 3))
    positions = m.vertices @ linear.T * scale + rng.normal(size=3) * scale
    faces = m.faces if np.linalg.det(linear) > 0 else m.faces[:, ::-1]
    return surface_from_arrays(positions, faces)
