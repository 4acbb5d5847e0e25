"""Where a ray may start: origin offsets from float precision, and contact-safe points.

A fixed offset along the normal pushes a vertex that touches another surface (an object
resting on a floor) through it, so it reads open where it is buried; these functions
find such vertices with short probe rays and keep their points on the open side. Used
for ray origins and for the disk method's receiver points. Knows nothing about methods.
"""

from __future__ import annotations

import numpy as np

from ._types import FloatArray
from .constants import (
    CONTACT_DEPTH,
    CONTACT_PROBE_SLACK,
    EPS32,
    MAX_CONTACT_GROUPS,
    RAY_OFFSET_ULPS,
)
from .kernels import topology as _topo
from .mesh import Surface
from .tracing import Tracer


def ray_offsets(
    surface: Surface, magnitude: float, bias: float | None = None, edges: FloatArray | None = None
) -> FloatArray:
    """Per-vertex ray-origin offsets along the normal, in mesh units.

    ``RAY_OFFSET_ULPS * EPS32 * (M + e_i)``, with M the largest recentred coordinate and
    e_i the longest edge at vertex i (``magnitude``: :attr:`aobake.tracing.Tracer.magnitude`): the float32 rounding of the origin and of Embree's
    plane-distance term, with margin. Never a fraction of the scene diagonal, which
    pushes vertices that touch another surface through it. ``bias`` overrides it.
    """
    if bias is not None:
        return np.full(surface.n_vertices, float(bias))
    if edges is None:
        edges = _topo.longest_edges(surface.positions, surface.faces)
    return RAY_OFFSET_ULPS * EPS32 * (magnitude + edges)


def shell_labels(surface: Surface) -> np.ndarray:
    """(n,) int64 shell id per vertex (see :func:`aobake.kernels.topology.shells`)."""
    pos = np.ascontiguousarray(surface.positions, dtype=np.float64)
    keys = _topo.position_keys(pos)
    keys.sort()  # distinct keys: the same order from any sort
    order, run_start = _topo.coincident_runs(pos, keys)
    return _topo.shells(surface.faces, order, run_start, np.ascontiguousarray(surface.normals))


def _own_side(surface: Surface, vertices, points, planes) -> np.ndarray:
    """Which side of a plane a vertex's own triangles lie on.

    For each vertex v (with plane point x and unit normal m): the sign of the mean
    signed distance to the plane of the corners of the triangles around v (v itself
    excluded); 0 where that mean is within 1e-3 of their extent (all in the plane, as
    for a two-sided sheet, or balanced).
    """
    pos = surface.positions
    owner, face = _topo.faces_around(surface.faces, vertices, surface.n_vertices)
    corners = surface.faces[face]  # (c, 3) vertex ids of each triangle around v
    d = np.einsum("ckj,cj->ck", pos[corners] - points[owner][:, None, :], planes[owner])
    d[corners == vertices[owner][:, None]] = 0.0
    extent = np.abs(pos[corners] - pos[vertices[owner]][:, None, :]).max(axis=(1, 2))
    total = np.bincount(owner, weights=d.sum(axis=1), minlength=vertices.size)
    scale = np.bincount(owner, weights=3.0 * extent, minlength=vertices.size)
    # The mean signed distance decides, so a vertex sunk slightly below the surface, or
    # next to one that is, still counts its triangles as above it.
    return np.where(total > 1e-3 * scale, 1, np.where(total < -1e-3 * scale, -1, 0))


def contact_origins(
    surface: Surface, tracer: Tracer, offsets: FloatArray, edges: FloatArray | None = None
) -> tuple[np.ndarray, int]:
    """Offset ray origins (float32, in ``tracer``'s frame: :meth:`Tracer.frame`); see
    :func:`contact_points`."""
    points, contacts = contact_points(surface, tracer.local, tracer.center, offsets, edges)
    return tracer.frame(points), contacts


def contact_points(
    surface: Surface,
    local: FloatArray,
    center: FloatArray,
    offsets: FloatArray,
    edges: FloatArray | None = None,
) -> tuple[FloatArray, int]:
    """Points offset along the normal that stay on the open side at contacts.

    ``local`` are the surface positions minus ``center`` (float64); the result is in
    the same frame. Used for ray origins and for the disk method's receiver points.

    Each origin is p + delta n. Where another shell (a connected component: an object
    resting on a floor, touching it or sunk slightly into it) passes near p along the
    normal, that offset can put the origin behind the other surface, and the vertex
    reads open where it is buried (every peer measured has this bug). Such vertices
    are found with one short probe per vertex along -n, from p + delta n to
    p - L n (L = max(1.25 delta, CONTACT_DEPTH * longest edge)), against scenes that
    hold only the *other* shells, so the vertex's own triangles (which all pass through
    p) cannot mask a surface that also passes through p. Where the vertex's own
    triangles lie on one side of the surface found, the origin is moved to that side
    (by the penetration depth) and the offset direction mirrored to point away from it.

    Shells are sorted by size into at most ``MAX_CONTACT_GROUPS`` groups probed one
    group at a time (only vertices inside a group's padded bounding box are probed);
    contacts between two shells of the same group (only in scenes with more shells than
    groups) and within one shell are not detected.

    Returns
    -------
    points : (n, 3) float64
    contacts : int
        Number of vertices whose point was moved.
    """
    p = np.asarray(local, dtype=np.float64)
    n = surface.normals
    origins = _topo.offset_points(p, offsets, n)
    if surface.n_faces == 0:
        return origins, 0
    shell = shell_labels(surface)
    n_shells = int(shell.max()) + 1
    sizes, referenced = _topo.shell_faces(surface.faces, shell, n_shells)
    with_faces = np.flatnonzero(sizes > 0)
    if with_faces.size < 2:
        return origins, 0
    if edges is None:
        edges = _topo.longest_edges(surface.positions, surface.faces)
    n_groups = min(with_faces.size, MAX_CONTACT_GROUPS)
    rank = np.full(n_shells, -1, dtype=np.int64)
    rank[with_faces[np.argsort(-sizes[with_faces], kind="stable")]] = np.arange(with_faces.size)
    shell_group = np.where(rank >= 0, rank % n_groups, -1)
    face_order, group_start, group_lo, group_hi = _topo.group_faces(
        p, surface.faces, shell, referenced, sizes, shell_group, n_groups
    )
    reach = offsets + np.maximum((1.0 + CONTACT_PROBE_SLACK) * offsets, CONTACT_DEPTH * edges)
    moved = np.zeros(surface.n_vertices, dtype=bool)
    probe_start, probes = _topo.group_probes(
        origins, reach, n, offsets, shell, shell_group, group_lo, group_hi
    )
    for g in range(n_groups):
        idx = probes[probe_start[g] : probe_start[g + 1]]
        idx = idx[~moved[idx]]
        if idx.size == 0:
            continue
        # Only the group's triangles that the probes can reach go into its scene, so a
        # large object resting on a floor costs a BVH over a few triangles, not all.
        qlo = (origins[idx] - reach[idx, None]).min(axis=0)
        qhi = (origins[idx] + reach[idx, None]).max(axis=0)
        ids = _topo.faces_in_box(
            p, surface.faces, face_order[group_start[g] : group_start[g + 1]], qlo, qhi
        )
        group_faces = surface.faces[ids]
        if group_faces.shape[0] == 0:
            continue
        used = np.unique(group_faces)
        local_faces = np.searchsorted(used, group_faces)
        # robust traversal: a probe through a vertex or an edge of the other surface (a
        # float32 corner resting exactly on a floor vertex) must not slip between its
        # triangles, or the contact is missed and the vertex reads open
        other = Tracer(p[used], local_faces, recentred=True, robust=True)
        hit = other.intersect(other.frame(origins[idx]), (-n[idx]).astype(np.float32), reach[idx])
        rows = np.flatnonzero(hit["primID"] >= 0)
        if rows.size == 0:
            continue
        m = hit["Ng"][rows].astype(np.float64)
        m_len = np.linalg.norm(m, axis=1)
        ok = m_len > 0
        rows, m = rows[ok], m[ok] / m_len[ok, None]
        v = idx[rows]
        x = origins[v] - hit["tfar"][rows, None] * n[v]
        side = _own_side(surface, v, x + center, m)
        keep = side != 0
        v, x, m = v[keep], x[keep], m[keep] * side[keep, None]  # m now points to the own side
        dot = np.einsum("ij,ij->i", n[v], m)
        sunk = np.maximum(0.0, -np.einsum("ij,ij->i", p[v] - x, m))
        fix = (dot < 0) | (sunk > 0)
        v, m, dot, sunk = v[fix], m[fix], dot[fix], sunk[fix]
        away = n[v] - 2.0 * np.minimum(dot, 0.0)[:, None] * m
        origins[v] = p[v] + (sunk + offsets[v])[:, None] * m + offsets[v, None] * away
        moved[v] = True
    return origins, int(moved.sum())
