"""Exact occlusion of a receiver point by planar polygons, clipped to its tangent plane.

Imports numpy, numba and ``aobake.constants`` only. Used by the disk method's near field
(``aobake.kernels.bunnell``): close to the receiver, a vertex's disk is replaced by the
exact form factor of the surface it stands for, its barycentric cell.

Conventions (as in ``aobake.kernels.bunnell``): receiver at ``p`` with unit normal ``n``
(a zero normal is not allowed here); polygon corners ``q_k`` in counter-clockwise order
about the polygon's front normal. Only the part of the polygon above the tangent plane,
``n.(x - p) >= 0``, is counted (Sutherland-Hodgman clipping); the caller learns which
side of it faces the receiver (front and back sums, like the disks). Also the small
per-vertex tables the near field needs: disk areas and the triangles around each vertex.

References
----------
J. H. Lambert, Photometria (1760): the point-to-polygon form factor as a contour sum.
A. van Oosterom and J. Strackee, "The solid angle of a plane triangle", IEEE Trans.
Biomed. Eng. 30 (1983).
J. Hoberock and Y. Jia, "High-Quality Ambient Occlusion", GPU Gems 3, ch. 12 (2007).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import MEASURE_COSINE, NEAR_PLANE_REL


@njit(cache=True, error_model="numpy", inline="always")
def _unit(x, y, z):
    inv = 1.0 / np.sqrt(x * x + y * y + z * z)
    return x * inv, y * inv, z * inv


@njit(cache=True, error_model="numpy", inline="always")
def _minus(a, row, x, y, z):
    """``a[row] - (x, y, z)`` as three scalars."""
    return a[row, 0] - x, a[row, 1] - y, a[row, 2] - z


@njit(cache=True, error_model="numpy", inline="always")
def _edge_term(ax, ay, az, bx, by, bz, nx, ny, nz):
    """Lambert's term of one edge between unit directions a and b: ``gamma n.(a x b) / |a x b|``
    with ``gamma`` the angle between them (0 for a zero-length edge)."""
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    s = np.sqrt(cx * cx + cy * cy + cz * cz)
    if s <= 0.0:
        return 0.0
    t = ax * bx + ay * by + az * bz
    return np.arctan2(s, t) / s * (nx * cx + ny * cy + nz * cz)


@njit(cache=True, error_model="numpy", inline="always")
def _fan_term(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Signed solid angle of the spherical triangle of unit directions a, b, c
    (van Oosterom-Strackee): ``2 atan2(a.(b x c), 1 + a.b + b.c + c.a)``."""
    num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    den = 1.0 + ax * bx + ay * by + az * bz + bx * cx + by * cy + bz * cz + cx * ax + cy * ay + cz * az
    return 2.0 * np.arctan2(num, den)


@njit(cache=True, error_model="numpy", inline="always")
def clipped_quad(px, py, pz, nx, ny, nz, q, measure):
    """Occlusion of receiver (p, n) by the planar quad ``q`` clipped to ``n.(x - p) >= 0``.

    Parameters
    ----------
    px, py, pz, nx, ny, nz : float
        Receiver position and unit normal.
    q : (4, 3) float64
        Corners in order around the quad (either winding), in one plane that does not
        pass through the receiver; a triangle repeats a corner.
    measure : int
        MEASURE_COSINE: the form factor ``1/pi int cos`` over the clipped quad, by
        Lambert's contour sum ``|sum_k gamma_k n.(u_k x u_k+1) / |u_k x u_k+1|| / (2 pi)``
        over the unit directions ``u_k`` to its corners (``gamma_k`` the angle between
        them). MEASURE_UNIFORM: its solid angle over 2 pi (a fan of van
        Oosterom-Strackee triangles).

    Returns
    -------
    float >= 0
        The same for both windings: which side faces the receiver is the caller's test.
    """
    acc = 0.0
    count = 0
    fx = fy = fz = 0.0  # first clipped corner (unit direction)
    ax = ay = az = 0.0  # previous clipped corner
    for k in range(4):
        k1 = (k + 1) % 4
        x0, y0, z0 = _minus(q, k, px, py, pz)
        x1, y1, z1 = _minus(q, k1, px, py, pz)
        h0 = nx * x0 + ny * y0 + nz * z0
        h1 = nx * x1 + ny * y1 + nz * z1
        # Sutherland-Hodgman, streamed: emit the corner if kept, then the crossing
        for emit in range(2):
            if emit == 0:
                if h0 < 0.0:
                    continue
                ux, uy, uz = x0, y0, z0
            else:
                if (h0 >= 0.0) == (h1 >= 0.0):
                    continue
                f = h0 / (h0 - h1)
                ux = x0 + f * (x1 - x0)
                uy = y0 + f * (y1 - y0)
                uz = z0 + f * (z1 - z0)
            ux, uy, uz = _unit(ux, uy, uz)
            if count == 0:
                fx, fy, fz = ux, uy, uz
            elif measure == MEASURE_COSINE:
                acc += _edge_term(ax, ay, az, ux, uy, uz, nx, ny, nz)
            elif count >= 2:
                acc += _fan_term(fx, fy, fz, ax, ay, az, ux, uy, uz)
            ax, ay, az = ux, uy, uz
            count += 1
    if count < 3:
        return 0.0
    if measure == MEASURE_COSINE:
        acc += _edge_term(ax, ay, az, fx, fy, fz, nx, ny, nz)
    return abs(acc) / (2.0 * np.pi)


@njit(cache=True, error_model="numpy", inline="always")
def cell_terms(positions, corner_start, corners, j, px, py, pz, nx, ny, nz, measure, quad):
    """Occlusion of receiver (p, n) by the barycentric cell of vertex j, split by side.

    The cell is the union, over the triangles (j, b, c) around j, of the quads
    ``j, (j + b)/2, (j + b + c)/3, (j + c)/2``: the third of each triangle nearest to j,
    so the cells of all vertices tile the surface exactly and each has the area of j's
    disk. A quad whose triangle's plane passes within NEAR_PLANE_REL edge lengths of the
    receiver (the receiver's own triangles, or any it lies on) is seen edge-on and
    counts 0; every other quad counts in ``front`` when the receiver is on its
    triangle's front side, else in ``back``.

    Parameters
    ----------
    positions : (n, 3) float64
    corner_start : (n + 1,) int64
        Vertex j's triangles are rows ``corner_start[j]:corner_start[j + 1]`` of corners.
    corners : (c, 2) int64
        The other two corners (b, c) of each triangle around j, so that (j, b, c) is
        counter-clockwise about the triangle's front.
    j : int
    px, py, pz, nx, ny, nz : float
        Receiver position and unit normal.
    measure : int
    quad : (4, 3) float64
        Scratch.

    Returns
    -------
    front, back : float >= 0
    """
    jx = positions[j, 0]
    jy = positions[j, 1]
    jz = positions[j, 2]
    hj = nx * (jx - px) + ny * (jy - py) + nz * (jz - pz)
    front = 0.0
    back = 0.0
    for t in range(corner_start[j], corner_start[j + 1]):
        b = corners[t, 0]
        c = corners[t, 1]
        # the quad lies in the triangle: nothing to clip to when it is all below the
        # tangent plane (the receiver's own flat or convex neighbourhood)
        hb = nx * (positions[b, 0] - px) + ny * (positions[b, 1] - py) + nz * (positions[b, 2] - pz)
        hc = nx * (positions[c, 0] - px) + ny * (positions[c, 1] - py) + nz * (positions[c, 2] - pz)
        if hj < 0.0 and hb < 0.0 and hc < 0.0:
            continue
        e1x, e1y, e1z = _minus(positions, b, jx, jy, jz)
        e2x, e2y, e2z = _minus(positions, c, jx, jy, jz)
        mx = e1y * e2z - e1z * e2y
        my = e1z * e2x - e1x * e2z
        mz = e1x * e2y - e1y * e2x
        h = mx * (px - jx) + my * (py - jy) + mz * (pz - jz)
        m2 = mx * mx + my * my + mz * mz
        # |h| / |m| > rel * sqrt(|m|), squared (|m| = 2 area ~ an edge length squared)
        if not h * h > NEAR_PLANE_REL * NEAR_PLANE_REL * m2 * np.sqrt(m2):
            continue
        quad[0, 0] = jx
        quad[0, 1] = jy
        quad[0, 2] = jz
        quad[1, 0] = jx + 0.5 * e1x
        quad[1, 1] = jy + 0.5 * e1y
        quad[1, 2] = jz + 0.5 * e1z
        quad[2, 0] = jx + (e1x + e2x) / 3.0
        quad[2, 1] = jy + (e1y + e2y) / 3.0
        quad[2, 2] = jz + (e1z + e2z) / 3.0
        quad[3, 0] = jx + 0.5 * e2x
        quad[3, 1] = jy + 0.5 * e2y
        quad[3, 2] = jz + 0.5 * e2z
        value = clipped_quad(px, py, pz, nx, ny, nz, quad, measure)
        if h > 0.0:
            front += value
        else:
            back += value
    return front, back


@njit(cache=True, error_model="numpy")
def cell_corners(faces, n_vertices):
    """Corner table of the barycentric cells (counting sort, O(n + m)).

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles, counter-clockwise about their front.
    n_vertices : int

    Returns
    -------
    corner_start : (n + 1,) int64
        Vertex j's triangles are rows ``corner_start[j]:corner_start[j + 1]``.
    corners : (3 m, 2) int64
        The other two corners (b, c) of each triangle around j, in face order, such
        that (j, b, c) keeps the face's winding.
    """
    m = faces.shape[0]
    corner_start = np.zeros(n_vertices + 1, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            corner_start[faces[f, k] + 1] += 1
    for v in range(n_vertices):
        corner_start[v + 1] += corner_start[v]
    fill = corner_start[:-1].copy()
    corners = np.zeros((3 * m, 2), dtype=np.int64)
    for f in range(m):
        for k in range(3):
            v = faces[f, k]
            corners[fill[v], 0] = faces[f, (k + 1) % 3]
            corners[fill[v], 1] = faces[f, (k + 2) % 3]
            fill[v] += 1
    return corner_start, corners


@njit(cache=True, error_model="numpy")
def renumbered_cells(faces, inverse):
    """:func:`cell_corners` of the triangles with every vertex ``v`` renumbered
    ``inverse[v]``, built without the table in the old numbering: vertex ``inverse[v]``'s
    rows are ``v``'s rows of :func:`cell_corners` in the same order (face order), their
    corners renumbered too. The disk method lays the cells out in tree order this way, so
    that the cells a bucket's receivers evaluate, and their corners, lie close together
    in memory.

    Parameters
    ----------
    faces : (m, 3) int64
    inverse : (n,) int32 or int64
        A permutation of the vertices.

    Returns
    -------
    corner_start : (n + 1,) int64
    corners : (3 m, 2), the dtype of ``inverse``
    """
    n = inverse.shape[0]
    m = faces.shape[0]
    corner_start = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            corner_start[inverse[faces[f, k]] + 1] += 1
    for v in range(n):
        corner_start[v + 1] += corner_start[v]
    fill = corner_start[:-1].copy()
    corners = np.empty((3 * m, 2), dtype=inverse.dtype)
    for f in range(m):
        for k in range(3):
            v = inverse[faces[f, k]]
            corners[fill[v], 0] = inverse[faces[f, (k + 1) % 3]]
            corners[fill[v], 1] = inverse[faces[f, (k + 2) % 3]]
            fill[v] += 1
    return corner_start, corners


@njit(cache=True, error_model="numpy", parallel=True)
def cell_reach(positions, corner_start, corners, reach_out):
    """Each cell's reach ``reach_out[j]``: the largest distance from vertex j to a corner
    of its quads (:func:`cell_terms`); a receiver whose tangent plane has the vertex lower
    than ``-reach`` sees no part of the cell.

    Parameters
    ----------
    positions : (n, 3) float64
    corner_start : (n + 1,) int64
    corners : (c, 2) int32 or int64
    reach_out : (n,) float64
    """
    for v in prange(positions.shape[0]):
        reach = 0.0
        for r in range(corner_start[v], corner_start[v + 1]):
            b = corners[r, 0]
            c = corners[r, 1]
            e1 = 0.0
            e2 = 0.0
            e3 = 0.0
            for a in range(3):
                d1 = positions[b, a] - positions[v, a]
                d2 = positions[c, a] - positions[v, a]
                e1 += d1 * d1
                e2 += d2 * d2
                e3 += (d1 + d2) * (d1 + d2)
            # the quad's corners: j + e1 / 2, j + (e1 + e2) / 3, j + e2 / 2
            reach = max(reach, 0.5 * np.sqrt(e1), 0.5 * np.sqrt(e2), np.sqrt(e3) / 3.0)
        reach_out[v] = reach


@njit(cache=True, error_model="numpy", inline="always")
def triangle_cross(positions, a, b, c):
    """``(b - a) x (c - a)`` of the triangle of rows a, b, c of ``positions``: its normal
    times twice its area."""
    e1x = positions[b, 0] - positions[a, 0]
    e1y = positions[b, 1] - positions[a, 1]
    e1z = positions[b, 2] - positions[a, 2]
    e2x = positions[c, 0] - positions[a, 0]
    e2y = positions[c, 1] - positions[a, 1]
    e2z = positions[c, 2] - positions[a, 2]
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x


@njit(cache=True, error_model="numpy")
def vertex_areas(positions, faces, out):
    """Disk areas: a third of each triangle's area ``0.5 |e1 x e2|`` (never Heron's
    formula, which goes NaN on needles) added to each of its corners, in face order.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    out : (n,) float64
        Zeroed by the caller; vertices on no triangle keep 0.
    """
    for f in range(faces.shape[0]):
        a = faces[f, 0]
        b = faces[f, 1]
        c = faces[f, 2]
        mx, my, mz = triangle_cross(positions, a, b, c)
        third = np.sqrt(mx * mx + my * my + mz * mz) / 6.0
        out[a] += third
        out[b] += third
        out[c] += third
