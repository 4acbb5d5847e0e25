"""Angle-weighted vertex normals, bit for bit the numpy formulation they replace.

Every product, difference and square root is the one ``numpy`` performed, in the same
order (tests/test_normals_kernel.py compares with that formulation bit for bit) (no fused multiply-adds: numba does not contract without fastmath); the corner
angles' ``arccos`` stays in numpy (its SIMD arccos may differ from libm's in the last
bit), and each vertex sums its corners in the order ``np.add.at`` did: corner k = 0
of every face in face order, then k = 1, then k = 2.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def corner_cosines(positions, faces):
    """Unit face normals (m, 3) (zero rows for zero-area faces) and the clipped cosine of
    each corner angle (3, m), row k for corner k of every face."""
    m = faces.shape[0]
    normals = np.zeros((m, 3))
    cosines = np.zeros((3, m))
    for f in prange(m):
        p = np.empty((3, 3))
        for k in range(3):
            for j in range(3):
                p[k, j] = positions[faces[f, k], j]
        a0, a1, a2 = p[1, 0] - p[0, 0], p[1, 1] - p[0, 1], p[1, 2] - p[0, 2]
        b0, b1, b2 = p[2, 0] - p[0, 0], p[2, 1] - p[0, 1], p[2, 2] - p[0, 2]
        c0 = a1 * b2 - a2 * b1
        c1 = a2 * b0 - a0 * b2
        c2 = a0 * b1 - a1 * b0
        length = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if length > 0.0:
            normals[f, 0] = c0 / length
            normals[f, 1] = c1 / length
            normals[f, 2] = c2 / length
        for k in range(3):
            i, j, o = k, (k + 1) % 3, (k + 2) % 3
            u0, u1, u2 = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
            v0, v1, v2 = p[o, 0] - p[i, 0], p[o, 1] - p[i, 1], p[o, 2] - p[i, 2]
            denom = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2) * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            cos = 0.0
            if denom > 0.0:
                # numpy's einsum("ij,ij->i") summed the three products as (x + z) + y
                cos = (u0 * v0 + u2 * v2 + u1 * v1) / denom
            cosines[k, f] = min(max(cos, -1.0), 1.0)
    return normals, cosines


@njit(cache=True)
def corners_by_vertex(faces, n_vertices):
    """CSR of each vertex's corners (corner id k * m + f), in increasing corner id: a
    stable counting sort, linear in the mesh size."""
    m = faces.shape[0]
    start = np.zeros(n_vertices + 1, dtype=np.int64)
    for k in range(3):
        for f in range(m):
            start[faces[f, k] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    corners = np.empty(3 * m, dtype=np.int64)
    for k in range(3):
        for f in range(m):
            v = faces[f, k]
            corners[fill[v]] = k * m + f
            fill[v] += 1
    return start, corners


@njit(cache=True, parallel=True)
def gather_weighted(face_normals, angles, start, corners):
    """(n, 3): per vertex, the sum over its corners of face normal times corner angle,
    added in the order of ``corners`` starting from 0.0 (as ``np.add.at`` into zeros)."""
    m = face_normals.shape[0]
    n = start.shape[0] - 1
    out = np.zeros((n, 3))
    for v in prange(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for c in range(start[v], start[v + 1]):
            k = corners[c] // m
            f = corners[c] - k * m
            a = angles[k, f]
            s0 += face_normals[f, 0] * a
            s1 += face_normals[f, 1] * a
            s2 += face_normals[f, 2] * a
        out[v, 0] = s0
        out[v, 1] = s1
        out[v, 2] = s2
    return out
