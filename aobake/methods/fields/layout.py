"""Where an AO field samples: the cube map of directions around the occluder's centre,
the exact distance to its convex hull along each, and the radial samples beyond it.

Numpy-facing; hull distances are computed by ``aobake.kernels.hull`` (``_k.*``).
"""

from __future__ import annotations

import numpy as np

from ..._types import FloatArray
from ...kernels import hull as _k
from ...kernels import raster as _cube
from ...mesh import face_normals_and_areas

# Support-plane normals for the hull distance: the centres of a 6 x 32^2 cube map.
SUPPORT_GRID = 32
# First radial sample at r0 + HULL_MARGIN * bounding radius: just outside the hull, so
# a sample never sits on a surface where a triangle through it would project to a line.
HULL_MARGIN = 1e-3
# Quadrature weights q_i = (share of r) * r^Q_POWER make far samples count for the many
# receivers there (Q_POWER = 1: receivers on a plane).
Q_POWER = 1.0


def unit(v: FloatArray) -> FloatArray:
    """Rows of ``v`` scaled to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def face_directions(face: int, u: FloatArray, v: FloatArray) -> FloatArray:
    """Unnormalised directions (k, 3) of face coordinates (u, v) on cube face ``face``."""
    d = np.zeros(np.broadcast(u, v).shape + (3,))
    d[..., _cube.FACE_AXIS[face]] = _cube.FACE_SIGN[face]
    d[..., _cube.FACE_U[face]] = u
    d[..., _cube.FACE_V[face]] = v
    return d


def surface_centre(positions: FloatArray, faces) -> FloatArray:
    """Area-weighted centroid of the triangles (a convex combination of vertices, so it
    lies inside the convex hull); the vertex mean when every face has zero area."""
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    _, areas = face_normals_and_areas(positions, faces)
    total = areas.sum()
    if not total > 0.0:
        return positions[np.unique(faces)].mean(axis=0)
    centroids = positions[faces].mean(axis=1)
    return (areas[:, None] * centroids).sum(axis=0) / total


def support_points(local: FloatArray) -> np.ndarray:
    """Indices of the vertices extreme along 6 K^2 cube-map directions (hull vertices)."""
    grid = (np.arange(SUPPORT_GRID) + 0.5) * (2.0 / SUPPORT_GRID) - 1.0
    u, v = np.meshgrid(grid, grid, indexing="ij")
    planes = np.ascontiguousarray(unit(np.concatenate([face_directions(f, u, v).reshape(-1, 3) for f in range(6)])))
    h = np.zeros(planes.shape[0])
    arg = np.zeros(planes.shape[0], dtype=np.int64)
    _k.support_values(local, planes, h, arg)
    return np.unique(arg).astype(np.int64)


def hull_distance(positions, directions, centre) -> FloatArray:
    """Distance from ``centre`` along unit ``directions`` to the boundary of the convex
    hull of ``positions`` (no hull is built, and scipy is not needed).

    Parameters
    ----------
    positions : (n, 3) float
    directions : (k, 3) float
        Normalised here.
    centre : (3,) float
        Must lie inside the hull (:func:`surface_centre` does).

    Returns
    -------
    r0 : (k,) float64, >= 0

    Notes
    -----
    c + t w lies in the hull iff t w = sum lam_v (v - c) for barycentric weights lam:
    r0 is the largest such t, a linear program with three equality rows (weights sum
    to one, no component across w). It is solved exactly by the simplex method, whose
    basis is a triangle of vertices whose projection along w contains the axis; the
    vertices extreme along 6 x 32^2 directions go first, then all vertices verify the
    optimum. This is the dual of the support-function form r0 = min over m of
    (h(m) - m.c)/(m.w), which a dense set of m only bounds from above.
    """
    local = np.ascontiguousarray(np.asarray(positions, dtype=np.float64) - np.asarray(centre, dtype=np.float64))
    dirs = np.ascontiguousarray(unit(np.asarray(directions, dtype=np.float64).reshape(-1, 3)))
    out = np.zeros(dirs.shape[0])
    _k.hull_distances(dirs, support_points(local), local, out)
    return out


def texel_anchors(resolution: int) -> FloatArray:
    """Unnormalised directions (6, R + 2, R + 2, 3) of the padded texel centres.

    Texel i (0 .. R + 1) of a face has face coordinate u = (2 i - 1) / R - 1: 0 and
    R + 1 are the border texels just past the face's edges.
    """
    u = (2.0 * np.arange(resolution + 2) - 1.0) / resolution - 1.0
    uu, vv = np.meshgrid(u, u, indexing="ij")
    return np.stack([face_directions(f, uu, vv) for f in range(6)])


def face_tangents(resolution: int) -> FloatArray:
    """(6, R + 2, R + 2, 6): the texel's edge vectors t_u, t_v in anchor space (2/R long)."""
    out = np.zeros((6, resolution + 2, resolution + 2, 6))
    for f in range(6):
        out[f, :, :, 0:3] = face_directions(f, 1.0, 0.0) - face_directions(f, 0.0, 0.0)
        out[f, :, :, 3:6] = face_directions(f, 0.0, 1.0) - face_directions(f, 0.0, 0.0)
    return out * (2.0 / resolution)


def radial_layout(r0: FloatArray, r_far: float, radius: float, m: int) -> tuple[FloatArray, float, float]:
    """Sample distances per texel: r0 + d_i, the same d_i for every texel, log-spaced
    from d_min = HULL_MARGIN * radius to d_max = r_far - min(r0).

    Half the samples lie within ~0.1 radius of the hull, where Omega and Y change
    fastest (contacts); log-spacing r itself from r0 would leave nothing between 1e-3
    and ~0.2 radius from the hull. Knots beyond r_far (texels with a large r0) are
    sampled but not fitted.

    Returns
    -------
    radii : (T, M) float64
    d_min, d_max : float
    """
    r0 = np.asarray(r0, dtype=np.float64)
    d_min = HULL_MARGIN * radius
    d_max = max(r_far - float(r0.min(initial=0.0)), 2.0 * d_min)
    d = d_min * (d_max / d_min) ** np.linspace(0.0, 1.0, m)
    return r0[:, None] + d[None, :], d_min, d_max


def quadrature_weights(radii: FloatArray, r_far: float) -> FloatArray:
    """(T, M) share of space each radial sample stands for, normalised per texel: the
    sample's interval in r (half the gaps to its neighbours) times r^Q_POWER; 0 beyond
    r_far."""
    edges = np.concatenate([radii[:, :1], 0.5 * (radii[:, 1:] + radii[:, :-1]), radii[:, -1:]], axis=1)
    q = np.diff(edges, axis=1) * radii**Q_POWER
    q[radii > r_far * (1.0 + 1e-12)] = 0.0
    return q / np.maximum(q.max(axis=1, keepdims=True), 1e-300)
