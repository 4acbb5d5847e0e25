"""Generators of meshes that break AO bakers: contacts, slivers, voxels, bad topology.

Each returns a Surface; :data:`CASES` names them all.
"""

from __future__ import annotations

import numpy as np

from aobake.mesh import Surface, surface_from_arrays

from .scenes import concat, ground_grid, icosphere


def touching_spheres_on_plane() -> Surface:
    """Two unit-diameter spheres touching each other and a floor (no shared vertices)."""
    a = icosphere(3, 0.5, [-0.5, 0.0, 0.5])
    b = icosphere(3, 0.5, [0.5, 0.0, 0.5])
    g = ground_grid(2.0, 9)
    return surface_from_arrays(*concat([a, b, g]))


def menger_voxels(level: int = 2) -> Surface:
    """Boundary quads of a Menger-sponge voxel solid (3^level cells a side).

    Sharp concave corners everywhere, and non-manifold edges where two voxels meet along
    an edge only. Corners are shared grid points, so neighbouring quads share vertices.
    """
    n = 3**level
    idx = np.indices((n, n, n)).reshape(3, -1).T
    filled = np.ones(len(idx), dtype=bool)
    for k in range(level):
        digits = (idx // 3**k) % 3
        filled &= (digits == 1).sum(axis=1) < 2
    grid = np.zeros((n + 2, n + 2, n + 2), dtype=bool)
    grid[1:-1, 1:-1, 1:-1] = filled.reshape(n, n, n)
    corner_id = lambda c: (c[..., 0] * (n + 1) + c[..., 1]) * (n + 1) + c[..., 2]  # noqa: E731
    quads = []
    for axis in range(3):
        for sign in (-1, 1):
            shift = np.zeros(3, dtype=int)
            shift[axis] = sign
            cells = np.argwhere(grid[1:-1, 1:-1, 1:-1])
            nb = cells + 1 + shift
            open_side = ~grid[nb[:, 0], nb[:, 1], nb[:, 2]]
            cells = cells[open_side]
            u, v = [a for a in range(3) if a != axis]
            base = cells.copy()
            if sign > 0:
                base[:, axis] += 1
            du = np.zeros(3, dtype=int)
            du[u] = 1
            dv = np.zeros(3, dtype=int)
            dv[v] = 1
            c = np.stack([base, base + du, base + du + dv, base + dv], axis=1)
            q = corner_id(c)
            # orient outward: (du x dv) points along +axis for the cyclic (u, v) order
            if (np.cross(du, dv)[axis] > 0) != (sign > 0):
                q = q[:, ::-1]
            quads.append(q)
    quads = np.vstack(quads)
    used, inverse = np.unique(quads, return_inverse=True)
    g = np.stack(np.unravel_index(used, (n + 1, n + 1, n + 1)), axis=1).astype(np.float64) / n
    q = inverse.reshape(-1, 4)
    faces = np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return surface_from_arrays(g, faces)


def close_plates(gap: float = 1e-3) -> Surface:
    """Two 1 x 1 grids ``gap`` apart, facing each other."""
    p0, f0 = ground_grid(0.5, 6, 0.0)
    p1, f1 = ground_grid(0.5, 6, gap)
    positions, faces = concat([(p0, f0), (p1, f1[:, ::-1])])
    normals = np.zeros_like(positions)
    normals[: len(p0), 2] = 1.0
    normals[len(p0) :, 2] = -1.0
    return surface_from_arrays(positions, faces, normals)


def needles_and_slivers() -> Surface:
    """A floor with a fan of needle triangles (1e-9 wide), slivers and zero-area faces."""
    p, f = ground_grid(1.0, 4)
    k = len(p)
    t = np.linspace(0.1, 0.9, 9)
    apex = np.array([[0.0, 0.0, 0.8]])
    needles_p = np.vstack(
        [
            apex,
            np.c_[np.cos(t), np.sin(t), np.full(9, 0.3)],
            np.c_[np.cos(t) + 1e-9, np.sin(t), np.full(9, 0.3)],
        ]
    )
    needles_f = np.array([[0, 1 + i, 10 + i] for i in range(9)])
    zero_area = np.array([[1, 2, 3], [4, 4, 5], [6, 6, 6]])  # collinear, repeated index, a point
    positions = np.vstack([p, needles_p])
    faces = np.vstack([f, needles_f + k, zero_area + k])
    return surface_from_arrays(positions, faces)


def far_from_origin(offset: float = 1e6) -> Surface:
    s = touching_spheres_on_plane()
    return surface_from_arrays(s.positions + offset, s.faces, s.normals)


def scaled(factor: float) -> Surface:
    s = touching_spheres_on_plane()
    return surface_from_arrays(s.positions * factor, s.faces, s.normals)


def duplicated_faces() -> Surface:
    p, f = concat([icosphere(2, 0.5, [0, 0, 0.5]), ground_grid(1.5, 6)])
    return surface_from_arrays(p, np.vstack([f, f, f[:10]]))


def inverted_normals() -> Surface:
    """Sphere on a floor whose sphere winding is reversed (normals point inside)."""
    sp, sf = icosphere(2, 0.5, [0, 0, 0.5])
    p, f = concat([(sp, sf[:, ::-1]), ground_grid(1.5, 6)])
    return surface_from_arrays(p, f)


def open_bowl(rings: int = 12, segments: int = 48) -> Surface:
    """The lower half of a unit sphere (open boundary, rim exactly at z = 0), normals
    pointing inside; vertex 0 is the bottom pole, the last ``segments`` vertices the rim."""
    theta = np.pi - 0.5 * np.pi * np.arange(1, rings + 1) / rings  # from near the pole to pi/2
    phi = 2 * np.pi * np.arange(segments) / segments
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring_pts = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(
        -1, 3
    )
    ring_pts[-segments:, 2] = 0.0
    positions = np.vstack([[0.0, 0.0, -1.0], ring_pts])
    j = np.arange(segments)
    faces = [np.c_[np.zeros(segments, dtype=int), 1 + (j + 1) % segments, 1 + j]]
    for r in range(rings - 1):
        a0, a1 = 1 + r * segments, 1 + (r + 1) * segments
        faces.append(np.c_[a0 + j, a0 + (j + 1) % segments, a1 + j])
        faces.append(np.c_[a0 + (j + 1) % segments, a1 + (j + 1) % segments, a1 + j])
    faces = np.vstack(faces)
    s = surface_from_arrays(positions, faces)
    if s.normals[0, 2] < 0:  # make the normals point into the bowl
        s = surface_from_arrays(positions, faces[:, ::-1])
    return s


def non_manifold_fins() -> Surface:
    """Three or four quads sharing one edge (a book with open pages)."""
    angles = np.radians([0, 60, 130, 200])
    positions = [[0, 0, 0], [0, 0, 1]]
    faces = []
    for a in angles:
        k = len(positions)
        positions += [[np.cos(a), np.sin(a), 0], [np.cos(a), np.sin(a), 1]]
        faces += [[0, k, k + 1], [0, k + 1, 1]]
    return surface_from_arrays(np.array(positions, dtype=float), np.array(faces))


CASES = {
    "touching_spheres_on_plane": touching_spheres_on_plane,
    "menger_voxels": menger_voxels,
    "plates_1e-3_apart": close_plates,
    "needles_and_slivers": needles_and_slivers,
    "far_from_origin": far_from_origin,
    "scaled_1e-5": lambda: scaled(1e-5),
    "scaled_1e5": lambda: scaled(1e5),
    "duplicated_faces": duplicated_faces,
    "inverted_normals": inverted_normals,
    "open_bowl": open_bowl,
    "non_manifold_fins": non_manifold_fins,
}
