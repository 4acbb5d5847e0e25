"""Mesh connectivity kernels."""

from __future__ import annotations

import numpy as np
from numba import njit

from .rng import mix64


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
    # Squared lengths, and one square root per vertex at the end: sqrt is monotone and
    # correctly rounded, so this is the longest of the rounded lengths, bit for bit.
    out = np.zeros(positions.shape[0])
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = positions[a, 0], positions[a, 1], positions[a, 2]
        bx, by, bz = positions[b, 0], positions[b, 1], positions[b, 2]
        cx, cy, cz = positions[c, 0], positions[c, 1], positions[c, 2]
        ab = (bx - ax) * (bx - ax) + (by - ay) * (by - ay) + (bz - az) * (bz - az)
        bc = (cx - bx) * (cx - bx) + (cy - by) * (cy - by) + (cz - bz) * (cz - bz)
        ca = (ax - cx) * (ax - cx) + (ay - cy) * (ay - cy) + (az - cz) * (az - cz)
        out[a] = max(out[a], ab, ca)
        out[b] = max(out[b], ab, bc)
        out[c] = max(out[c], bc, ca)
    for i in range(out.shape[0]):
        out[i] = np.sqrt(out[i])
    return out


@njit(cache=True)
def shell_faces(faces, shell, n_shells):
    """Faces per shell, and which vertices the faces use.

    Parameters
    ----------
    faces : (m, 3) int64
    shell : (n,) int64
        Shell of each vertex (the three corners of a face share one).
    n_shells : int

    Returns
    -------
    sizes : (S,) int64
        Faces per shell.
    referenced : (n,) bool
        Vertices that are a corner of some face.
    """
    sizes = np.zeros(n_shells, dtype=np.int64)
    referenced = np.zeros(shell.shape[0], dtype=np.bool_)
    for f in range(faces.shape[0]):
        sizes[shell[faces[f, 0]]] += 1
        referenced[faces[f, 0]] = True
        referenced[faces[f, 1]] = True
        referenced[faces[f, 2]] = True
    return sizes, referenced


@njit(cache=True)
def group_faces(positions, faces, shell, referenced, sizes, shell_group, n_groups):
    """Faces sorted by contact group, and each group's bounding box.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    shell : (n,) int64
        Shell of each vertex (the three corners of a face share one).
    referenced, sizes
        From :func:`shell_faces`.
    shell_group : (S,) int64
        Group of each shell, in [0, n_groups) for every shell with faces.
    n_groups : int

    Returns
    -------
    face_order : (m,) int64
        Face ids stably sorted by group.
    group_start : (G + 1,) int64
        Group g's faces are ``face_order[group_start[g]:group_start[g + 1]]``.
    lo, hi : (G, 3) float64
        Lower and upper corners of the triangles of each group (inf, -inf if none),
        found from the vertices the faces use (the same values: only a zero's sign may
        differ from a pass over the faces' corners).
    """
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    for v in range(positions.shape[0]):
        if referenced[v]:
            g = shell_group[shell[v]]
            for d in range(3):
                x = positions[v, d]
                if x < lo[g, d]:
                    lo[g, d] = x
                if x > hi[g, d]:
                    hi[g, d] = x
    group_start = np.zeros(n_groups + 1, dtype=np.int64)
    for s in range(sizes.shape[0]):
        if sizes[s] > 0:
            group_start[shell_group[s] + 1] += sizes[s]
    for g in range(n_groups):
        group_start[g + 1] += group_start[g]
    at = group_start[:-1].copy()
    face_order = np.empty(faces.shape[0], dtype=np.int64)
    for f in range(faces.shape[0]):
        g = shell_group[shell[faces[f, 0]]]
        face_order[at[g]] = f
        at[g] += 1
    return face_order, group_start, lo, hi


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


@njit(cache=True)
def position_keys(positions):
    """(n,) uint64 sort keys that bring equal positions together.

    Parameters
    ----------
    positions : (n, 3) float64, C-contiguous

    Returns
    -------
    keys : (n,) uint64
        High bits: a hash of the three bit patterns, with -0.0 read as 0.0 (they
        compare equal); a position with a NaN (equal to nothing) hashes its index
        instead. Low ``index_bits(n)`` bits: the vertex index, so keys are distinct and
        sorting them (cheaper than an argsort) gives one order on every platform.
    """
    n = positions.shape[0]
    shift = np.uint64(index_bits(n))
    low = (np.uint64(1) << shift) - np.uint64(1)
    bits = positions.view(np.uint64)
    keys = np.empty(n, dtype=np.uint64)
    negative_zero = np.uint64(0x8000000000000000)
    for i in range(n):
        x, y, z = positions[i, 0], positions[i, 1], positions[i, 2]
        if x != x or y != y or z != z:
            h = mix64(np.uint64(i) ^ np.uint64(0x5851F42D4C957F2D))
        else:
            h = np.uint64(0x9E3779B97F4A7C15)
            for c in range(3):
                b = bits[i, c]
                if b == negative_zero:
                    b = np.uint64(0)
                h = mix64(h ^ b)
        keys[i] = (h & ~low) | np.uint64(i)
    return keys


@njit(cache=True)
def index_bits(n):
    """Bits that hold a vertex index below ``n`` (at least 1)."""
    b = 1
    while (1 << b) < n:
        b += 1
    return b


@njit(cache=True, inline="always")
def _same_position(positions, i, j):
    return (
        positions[i, 0] == positions[j, 0]
        and positions[i, 1] == positions[j, 1]
        and positions[i, 2] == positions[j, 2]
    )


@njit(cache=True)
def coincident_runs(positions, sorted_keys):
    """Runs of vertices with exactly equal positions.

    Parameters
    ----------
    positions : (n, 3) float64
    sorted_keys : (n,) uint64
        :func:`position_keys` of ``positions``, sorted.

    Returns
    -------
    order : (n,) int64
    run_start : (r + 1,) int64
        Runs of equal positions (``==``: -0.0 equals 0.0; a position with a NaN is a
        run of its own) are ``order[run_start[k]:run_start[k + 1]]``, as :func:`shells`
        takes them.
    """
    n = sorted_keys.shape[0]
    shift = np.uint64(index_bits(n))
    low = (np.uint64(1) << shift) - np.uint64(1)
    order = np.empty(n, dtype=np.int64)
    for a in range(n):
        order[a] = np.int64(sorted_keys[a] & low)
    start = np.empty(n + 1, dtype=np.int64)
    r = 0
    a = 0
    while a < n:
        hash_bits = sorted_keys[a] & ~low
        b = a + 1
        while b < n and (sorted_keys[b] & ~low) == hash_bits:
            b += 1
        # one hash: nearly always one position; otherwise (a collision, or a NaN)
        # gather the copies of each position in turn
        s = a
        while s < b:
            start[r] = s
            r += 1
            i = order[s]
            e = s + 1
            for t in range(s + 1, b):
                j = order[t]
                if _same_position(positions, i, j):
                    order[t] = order[e]
                    order[e] = j
                    e += 1
            s = e
        a = b
    start[r] = n
    return order, start[: r + 1].copy()


@njit(cache=True)
def offset_points(points, offsets, normals):
    """(n, 3) float64 ``points + offsets[:, None] * normals`` (exactly numpy's rounding)."""
    n = points.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        for c in range(3):
            out[i, c] = points[i, c] + offsets[i] * normals[i, c]
    return out


@njit(cache=True)
def group_probes(origins, reach, normals, offsets, shell, shell_group, lo, hi):
    """The vertices to probe against each group of shells, in one pass.

    Parameters
    ----------
    origins : (n, 3) float64
    reach : (n,) float64
        Each vertex's probe box is ``[origins - reach, origins + reach]``.
    normals : (n, 3) float64
    offsets : (n,) float64
    shell : (n,) int64
    shell_group : (S,) int64
        Group of each shell (-1: none).
    lo, hi : (G, 3) float64
        Corners of each group's bounding box; G <= 63.

    Returns
    -------
    start : (G + 1,) int64
    members : (k,) int64
        ``members[start[g]:start[g + 1]]``: in increasing order, the vertices with a
        nonzero normal and a positive offset, not in group g, whose probe box meets the
        box of group g.
    """
    n = origins.shape[0]
    n_groups = lo.shape[0]
    if n_groups > 63:
        raise ValueError("group_probes: at most 63 groups")
    masks = np.zeros(n, dtype=np.int64)  # bit g: probe against group g
    for i in range(n):
        has_normal = normals[i, 0] != 0.0 or normals[i, 1] != 0.0 or normals[i, 2] != 0.0
        if not (has_normal and offsets[i] > 0):
            continue
        own = shell_group[shell[i]]
        m = 0
        for g in range(n_groups):
            if g == own:
                continue
            near = True
            for c in range(3):
                # the box tests of numpy's (origins +- reach >= / <= corner), same rounding
                if not (
                    origins[i, c] + reach[i] >= lo[g, c] and origins[i, c] - reach[i] <= hi[g, c]
                ):
                    near = False
                    break
            if near:
                m |= 1 << g
        masks[i] = m
    start = np.zeros(n_groups + 1, dtype=np.int64)
    for i in range(n):
        m = masks[i]
        for g in range(n_groups):
            if (m >> g) & 1:
                start[g + 1] += 1
    for g in range(n_groups):
        start[g + 1] += start[g]
    fill = start[:-1].copy()
    members = np.empty(start[n_groups], dtype=np.int64)
    for i in range(n):
        m = masks[i]
        for g in range(n_groups):
            if (m >> g) & 1:
                members[fill[g]] = i
                fill[g] += 1
    return start, members
