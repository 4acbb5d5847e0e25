"""Procedural test scenes: small ones, most with closed-form cosine-weighted AO (derived
in the docstrings), and the large crevice and bunny-on-a-floor scenes of the bench."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from aobake.mesh import Part, Surface, surface_from_arrays


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


def sphere(radius: float = 1.0, subdivisions: int = 3, *, inward: bool = False) -> Surface:
    """Icosphere; with ``inward`` the faces and normals point inside (A = 1 everywhere)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    faces = m.faces[:, ::-1] if inward else m.faces
    return surface_from_arrays(m.vertices, faces)


def box(extents=(1.0, 2.0, 3.0)) -> Surface:
    """A box with split-free corners (8 vertices): convex, A = 0 everywhere."""
    m = trimesh.creation.box(extents=extents)
    return surface_from_arrays(m.vertices, m.faces)


def ground_grid(half: float, cells: int, z: float = 0.0, *, up: bool = True):
    """A square grid of side 2 ``half`` in the plane z, (cells + 1)^2 vertices, facing +z
    (-z without ``up``): positions and faces."""
    t = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    positions = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    b, c, d = a + cells + 1, a + 1, a + cells + 2
    faces = np.vstack([np.c_[a, b, d], np.c_[a, d, c]])
    return positions, (faces if up else faces[:, ::-1])


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


def icosphere(subdivisions: int = 2, radius: float = 1.0, center=(0.0, 0.0, 0.0)):
    """Positions and faces of trimesh's icosphere, moved to ``center``."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices) + np.asarray(center), np.asarray(mesh.faces, dtype=np.int64)


def concat(meshes) -> tuple[np.ndarray, np.ndarray]:
    """One (positions, faces) from several, face indices shifted."""
    positions, faces, offset = [], [], 0
    for p, f in meshes:
        positions.append(np.asarray(p, dtype=np.float64))
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(p)
    return np.vstack(positions), np.vstack(faces)


def combine_meshes(*meshes, names=None) -> Surface:
    """One Surface with one Part per (positions, faces) pair; normals angle-weighted."""
    positions, faces, parts = [], [], []
    v0 = f0 = 0
    for k, (p, f) in enumerate(meshes):
        positions.append(p)
        faces.append(f + v0)
        name = f"part{k}" if names is None else names[k]
        counts = np.full(len(f), 3, dtype=np.int64)
        parts.append(Part(name, v0, v0 + len(p), f0, f0 + len(f), counts, f.reshape(-1).copy()))
        v0 += len(p)
        f0 += len(f)
    base = surface_from_arrays(np.concatenate(positions), np.concatenate(faces))
    return Surface(base.positions, base.faces, base.normals, tuple(parts), base.source)


def sphere_on_plane(subdivisions=2, cells=20) -> Surface:
    """Unit sphere resting on a 6 x 6 ground grid (touching at the south pole)."""
    return combine_meshes(icosphere(subdivisions), ground_grid(3.0, cells, -1.0))


def touching_spheres(subdivisions=2) -> Surface:
    return combine_meshes(
        icosphere(subdivisions, center=(-1.0, 0, 0)), icosphere(subdivisions, center=(1.0, 0, 0))
    )


def facing_plates(cells=12, gap=0.5) -> Surface:
    """Two parallel 2 x 2 plates a gap apart, front faces toward each other."""
    return combine_meshes(
        ground_grid(1.0, cells, -gap / 2), ground_grid(1.0, cells, gap / 2, up=False)
    )


def _block_of_balls(subdivisions: int, cells: int) -> list:
    """A ground grid of half-width 3.2, then four unit balls in a 2 x 2 block, 0.1 apart,
    resting on it (the last sunk 0.02 into it, as objects placed by hand often are)."""
    balls = [
        icosphere(subdivisions, 1.0, (x, y, 1.0 - (0.02 if k == 3 else 0.0)))
        for k, (x, y) in enumerate([(-1.05, -1.05), (1.05, -1.05), (-1.05, 1.05), (1.05, 1.05)])
    ]
    return [ground_grid(3.2, cells)] + balls


def spheres_in_block(subdivisions=4, cells=41) -> Surface:
    """The bench's crevice scene at a given size: four balls in a block on a floor, one
    Part per mesh. Crevices and contact rings give occlusion from none to nearly full."""
    return combine_meshes(*_block_of_balls(subdivisions, cells))


def spheres_in_block_arrays(n_vertices: int) -> tuple[np.ndarray, np.ndarray, str]:
    """Positions, faces and a description of :func:`spheres_in_block` at about
    ``n_vertices``: the largest ball subdivision with the balls under 95% of the
    vertices, the floor grid the rest. Deterministic."""
    level = 1
    while 4 * (10 * 4 ** (level + 1) + 2) <= 0.95 * n_vertices and level < 9:
        level += 1
    ball_vertices = 10 * 4**level + 2
    rest = max(81, n_vertices - 4 * ball_vertices)
    cells = max(8, int(round(math.sqrt(rest))) - 1)
    positions, faces = concat(_block_of_balls(level, cells))
    desc = f"4 icospheres (subdivisions={level}) on a {cells}x{cells} ground grid"
    return positions, faces, desc


def bunny_on_ground_arrays(
    positions: np.ndarray, faces: np.ndarray, n_vertices: int
) -> tuple[np.ndarray, np.ndarray, str]:
    """Positions, faces and a description of the bench's second large scene: a mesh (the
    bundled bunny), loop-subdivided to about 70% of ``n_vertices``, scaled one unit tall,
    standing on a square ground grid (y up, 4 units wide) that gets the rest."""
    v, f = np.asarray(positions, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    level = 0
    while len(v) * 4 ** (level + 1) <= 0.7 * n_vertices:
        level += 1
    if level:
        v, f = trimesh.remesh.subdivide_loop(v, f, iterations=level)
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = (v - [0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])]) / (hi[1] - lo[1])
    rest = max(81, n_vertices - len(v))
    cells = max(8, int(round(math.sqrt(rest))) - 1)
    t = np.linspace(-2.0, 2.0, cells + 1)
    x, z = np.meshgrid(t, t, indexing="ij")
    grid_v = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    b, c, d = a + cells + 1, a + 1, a + cells + 2
    grid_f = np.vstack([np.c_[a, d, b], np.c_[a, c, d]])  # faces +y
    out_positions = np.concatenate([v, grid_v])
    out_faces = np.concatenate([f, grid_f + len(v)])
    desc = (
        f"bunny.ply loop-subdivided {level}x ({len(v)} vertices) on a {cells}x{cells} ground grid"
    )
    return out_positions, out_faces, desc


def voxel_surface(filled: np.ndarray, cells: int = 3) -> Surface:
    """Boundary of a set of unit voxels: each exposed face a cells x cells grid of its own.

    Face grids do not share vertices, so every voxel edge carries split vertices (same
    position, different normals). Normals are the faces' outward normals.
    """
    positions, faces, normals = [], [], []
    v0 = 0
    shape = filled.shape
    u = np.linspace(0.0, 1.0, cells + 1)
    s, t = np.meshgrid(u, u, indexing="ij")
    s, t = s.ravel(), t.ravel()
    idx = np.arange(s.size).reshape(cells + 1, cells + 1)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[1:, :-1].ravel(),
        idx[1:, 1:].ravel(),
        idx[:-1, 1:].ravel(),
    )
    quad = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    for x, y, z in zip(*np.nonzero(filled), strict=True):
        for axis in range(3):
            for sign in (-1, 1):
                nb = [x, y, z]
                nb[axis] += sign
                inside = all(0 <= nb[q] < shape[q] for q in range(3))
                if inside and filled[tuple(nb)]:
                    continue
                e1, e2 = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
                base = np.array([x, y, z], dtype=float)
                base[axis] += 1.0 if sign > 0 else 0.0
                p = base + s[:, None] * e1 + t[:, None] * e2
                n = np.zeros(3)
                n[axis] = sign
                f = quad if sign > 0 else quad[:, ::-1]
                positions.append(p)
                faces.append(f + v0)
                normals.append(np.repeat(n[None], len(p), axis=0))
                v0 += len(p)
    return surface_from_arrays(
        np.concatenate(positions), np.concatenate(faces), np.concatenate(normals)
    )


def voxel_sponge(cells: int = 3) -> Surface:
    """Menger sponge level 1: a 3 x 3 x 3 block without its centre cross (concave solid)."""
    i, j, k = np.indices((3, 3, 3))
    filled = ((i == 1).astype(int) + (j == 1) + (k == 1)) < 2
    return voxel_surface(filled, cells)
