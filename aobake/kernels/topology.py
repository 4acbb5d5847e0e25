"""Mesh connectivity kernels."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]  # path halving
        i = parent[i]
    return i


@njit(cache=True, inline="always")
def _union(parent, a, b):
    a = _find(parent, a)
    b = _find(parent, b)
    if a < b:
        parent[b] = a
    elif b < a:
        parent[a] = b


@njit(cache=True)
def shells(faces, order, run_start, normals):
    """Label vertices by shell: connected through faces, or through coincident positions
    whose normals do not face apart.

    Parameters
    ----------
    faces : (m, 3) int64
    order : (n,) int64
        Vertex indices sorted so coincident positions are consecutive.
    run_start : (r + 1,) int64
        Runs of coincident positions are ``order[run_start[k]:run_start[k + 1]]``.
    normals : (n, 3) float64
        Unit or zero normals.

    Returns
    -------
    labels : (n,) int64
        Shell ids 0..C-1 by first appearance.

    Notes
    -----
    Split vertices (hard edges, UV seams) have normals at most 90 degrees apart and join
    one shell. A vertex of one object resting exactly on a vertex of another (a sphere's
    pole on a floor vertex) has normals facing apart and stays separate, so the contact
    is still found; so do the two sides of a two-sided sheet.
    """
    n = normals.shape[0]
    parent = np.arange(n)
    for f in range(faces.shape[0]):
        _union(parent, faces[f, 0], faces[f, 1])
        _union(parent, faces[f, 0], faces[f, 2])
    for k in range(run_start.shape[0] - 1):
        lo, hi = run_start[k], run_start[k + 1]
        for a in range(lo, hi):
            i = order[a]
            for b in range(a + 1, hi):
                j = order[b]
                d = (
                    normals[i, 0] * normals[j, 0]
                    + normals[i, 1] * normals[j, 1]
                    + normals[i, 2] * normals[j, 2]
                )
                if d >= -1e-6:
                    _union(parent, i, j)
    return _relabel(parent)


@njit(cache=True)
def _relabel(parent):
    n = parent.shape[0]
    labels = np.full(n, -1, dtype=np.int64)
    root_label = np.full(n, -1, dtype=np.int64)
    count = 0
    for i in range(n):
        r = _find(parent, i)
        if root_label[r] < 0:
            root_label[r] = count
            count += 1
        labels[i] = root_label[r]
    return labels


@njit(cache=True)
def longest_edges(positions, faces):
    """(n,) float64: the longest edge touching each vertex (0 for unreferenced ones)."""
    out = np.zeros(positions.shape[0])
    for f in range(faces.shape[0]):
        for k in range(3):
            i = faces[f, k]
            j = faces[f, (k + 1) % 3]
            dx = positions[j, 0] - positions[i, 0]
            dy = positions[j, 1] - positions[i, 1]
            dz = positions[j, 2] - positions[i, 2]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if length > out[i]:
                out[i] = length
            if length > out[j]:
                out[j] = length
    return out


@njit(cache=True)
def group_bounds(positions, faces, group_of_face, n_groups):
    """(G, 3) lower and upper corners of the triangles of each group."""
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    for f in range(faces.shape[0]):
        g = group_of_face[f]
        for k in range(3):
            v = faces[f, k]
            for c in range(3):
                x = positions[v, c]
                if x < lo[g, c]:
                    lo[g, c] = x
                if x > hi[g, c]:
                    hi[g, c] = x
    return lo, hi


@njit(cache=True)
def faces_in_box(positions, faces, face_ids, lo, hi):
    """Those of ``face_ids`` whose bounding box meets the box [lo, hi]."""
    keep = np.zeros(face_ids.shape[0], dtype=np.bool_)
    for a in range(face_ids.shape[0]):
        f = face_ids[a]
        ok = True
        for c in range(3):
            x0 = positions[faces[f, 0], c]
            x1 = positions[faces[f, 1], c]
            x2 = positions[faces[f, 2], c]
            if max(x0, max(x1, x2)) < lo[c] or min(x0, min(x1, x2)) > hi[c]:
                ok = False
                break
        keep[a] = ok
    return face_ids[keep]


@njit(cache=True)
def faces_around(faces, vertices, n):
    """(owner, face) pairs: every triangle around each of ``vertices`` (one pass over
    the faces; ``owner`` indexes ``vertices``)."""
    slot = np.full(n, -1, dtype=np.int64)
    for a in range(vertices.shape[0]):
        slot[vertices[a]] = a
    count = 0
    for f in range(faces.shape[0]):
        for k in range(3):
            if slot[faces[f, k]] >= 0:
                count += 1
    owner = np.zeros(count, dtype=np.int64)
    face = np.zeros(count, dtype=np.int64)
    i = 0
    for f in range(faces.shape[0]):
        for k in range(3):
            a = slot[faces[f, k]]
            if a >= 0:
                owner[i] = a
                face[i] = f
                i += 1
    return owner, face
