"""Monte Carlo ambient occlusion by ray casting with Embree: the reference method.

The only module that imports embreex. :class:`Scene` owns the one float32 boundary of
aobake (recentre in float64, then cast); :func:`embree_ao` is the estimator. Writes no
files and prints nothing.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ._types import AOArray, FloatArray, IndexArray
from .constants import (
    ADAPTIVE_FIRST_ROUND,
    CHUNK_RAYS,
    CONTACT_DEPTH,
    CONTACT_PROBE_SLACK,
    DEFAULT_RAYS,
    EPS32,
    INFINITE_DISTANCE,
    MAX_CONTACT_GROUPS,
    RAY_OFFSET_ULPS,
    Z95,
)
from .errors import InputError, NumericalError
from .kernels import rays as _k
from .kernels import topology as _topo
from .mesh import Surface
from .progress import NullProgress, Progress

MEASURES = {"cosine": _k.COSINE, "uniform": _k.UNIFORM}


class Scene:
    """Triangles in Embree, recentred in float64 before the cast to float32.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    robust : bool
        Embree's robust traversal (watertight at shared edges; slower).

    Notes
    -----
    Embree is single precision. A mesh 1e4 units from the origin has float32 spacing
    of ~1e-3 there, enough to move vertices by more than any sensible ray offset;
    subtracting the bounding-box centre in float64 first keeps full precision relative
    to the mesh's own size, so AO does not depend on where the mesh is.
    """

    def __init__(
        self,
        positions: FloatArray,
        faces: IndexArray,
        *,
        robust: bool = False,
        recentred: bool = False,
    ):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        positions = np.asarray(positions, dtype=np.float64)
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        self.center = np.zeros(3) if recentred else 0.5 * (lo + hi)
        self.local = positions - self.center
        #: Largest recentred coordinate: the magnitude that sets float32 rounding.
        self.magnitude = float(np.abs(self.local).max())
        if faces.size and faces.max() > np.iinfo(np.int32).max:
            raise InputError(None, f"{faces.max()} vertices exceed Embree's 32-bit indices")
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, self.local.astype(np.float32), faces.astype(np.int32))
        # Commit now, on this thread: EmbreeScene.run commits lazily and is not safe to
        # commit from two worker threads at once.
        probe = np.zeros((1, 3), dtype=np.float32)
        self._scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")

    def occluded(self, origins, directions, tfar: float) -> np.ndarray:
        """(k,) int32: 0 where a ray (float32 arrays, local frame) hits within ``tfar``, -1 else."""
        return self._scene.run(origins, directions, dists=float(tfar), query="OCCLUDED")

    def intersect(self, origins, directions, tfar: np.ndarray) -> dict:
        """Closest hits: dict with ``primID`` (k,) int32 (-1 = miss), ``tfar``, ``Ng`` (k, 3)."""
        return self._scene.run(
            origins,
            directions,
            dists=np.ascontiguousarray(tfar, dtype=np.float32),
            query="INTERSECT",
            output=True,
        )


@dataclass(frozen=True)
class EmbreeAO:
    """Result of :func:`embree_ao`.

    Attributes
    ----------
    ao : (n,) float64 in [0, 1]
        Accessibility 1 - A (1 = open).
    rays : (n,) int64
        Rays cast per vertex (fewer than requested where adaptive sampling stopped early).
    seconds : float
        Wall time of the estimate (scene build included).
    contacts : int
        Vertices whose origin offset would have crossed another surface and was mirrored.
    """

    ao: AOArray
    rays: IndexArray
    seconds: float
    contacts: int

    @property
    def n_rays(self) -> int:
        return int(self.rays.sum())


def ray_offsets(
    surface: Surface, scene: Scene, bias: float | None = None, edges: FloatArray | None = None
) -> FloatArray:
    """Per-vertex ray-origin offsets along the normal, in mesh units.

    ``RAY_OFFSET_ULPS * EPS32 * (M + e_i)``, with M the largest recentred coordinate and
    e_i the longest edge at vertex i: the float32 rounding of the origin and of Embree's
    plane-distance term, with margin. Never a fraction of the scene diagonal, which
    pushes vertices that touch another surface through it. ``bias`` overrides it.
    """
    if bias is not None:
        return np.full(surface.n_vertices, float(bias))
    if edges is None:
        edges = _topo.longest_edges(surface.positions, surface.faces)
    return RAY_OFFSET_ULPS * EPS32 * (scene.magnitude + edges)


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
    surface: Surface, scene: Scene, offsets: FloatArray, edges: FloatArray | None = None
) -> tuple[np.ndarray, int]:
    """Offset ray origins (float32, in ``scene``'s recentred frame); see :func:`contact_points`."""
    points, contacts = contact_points(surface, scene.local, scene.center, offsets, edges)
    return points.astype(np.float32), contacts


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
        other = Scene(p[used], local_faces, recentred=True)
        hit = other.intersect(
            origins[idx].astype(np.float32), (-n[idx]).astype(np.float32), reach[idx]
        )
        rows = np.flatnonzero(hit["primID"] >= 0)
        if rows.size == 0:
            continue
        m = hit["Ng"][rows].astype(np.float64)
        m_len = np.linalg.norm(m, axis=1)
        ok = m_len > 0
        rows, m = rows[ok], m[ok] / m_len[ok, None]
        v = idx[rows]
        x = origins[v] - hit["tfar"][rows, None].astype(np.float64) * n[v]
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


def _rounds(n_rays: int, adaptive: bool) -> list[tuple[int, int]]:
    """Sample-index ranges per round; adaptive rounds end on powers of two."""
    if not adaptive:
        return [(0, n_rays)]
    out, j0, j1 = [], 0, min(ADAPTIVE_FIRST_ROUND, n_rays)
    while j0 < n_rays:
        out.append((j0, j1))
        j0, j1 = j1, min(2 * j1, n_rays)
    return out


def half_width(hits: np.ndarray, n: np.ndarray) -> np.ndarray:
    """95% Agresti-Coull half-width of a binomial proportion hits/n (independent samples).

    Never zero, so a vertex with no hits after a few rays is not declared exact.
    """
    z2 = Z95 * Z95
    nt = n + z2
    pt = (hits + 0.5 * z2) / nt
    return Z95 * np.sqrt(pt * (1.0 - pt) / nt)


def stratified_half_width(hits: np.ndarray, first_half_hits: np.ndarray, n: int) -> np.ndarray:
    """95% half-width of the estimate hits/n from an Owen-scrambled (0,2)-sequence prefix.

    Two estimates, the larger wins:

    - the binomial (Agresti-Coull) half-width at an effective sample size
      n_eff = n sqrt(n / 16): scrambled nets converge like n^-3/4 on AO integrands
      (measured: bench/accuracy_embree.py, tests), and at n = 16 this is the plain
      binomial bound;
    - Z95 |m1 - m2| / 2 from the two halves of the prefix (each half is itself a
      scrambled net, an unbiased estimate), which catches integrands where
      stratification gains less than assumed.
    """
    n_eff = n * math.sqrt(n / ADAPTIVE_FIRST_ROUND)
    z2 = Z95 * Z95
    p = hits / n
    nt = n_eff + z2
    pt = (p * n_eff + 0.5 * z2) / nt
    binomial = Z95 * np.sqrt(pt * (1.0 - pt) / nt)
    half = n / 2
    m1 = first_half_hits / half
    m2 = (hits - first_half_hits) / half
    return np.maximum(binomial, Z95 * 0.5 * np.abs(m1 - m2))


def embree_ao(
    surface: Surface,
    *,
    n_rays: int = DEFAULT_RAYS,
    measure: str = "cosine",
    max_distance: float | None = None,
    bias: float | None = None,
    seed: int = 0,
    tolerance: float | None = None,
    threads: int | None = None,
    chunk_rays: int = CHUNK_RAYS,
    stratified: bool = True,
    robust: bool = False,
    contact_fix: bool = True,
    progress: Progress | None = None,
) -> EmbreeAO:
    """Per-vertex ambient occlusion by Monte Carlo ray casting (the reference).

    Parameters
    ----------
    surface : Surface
        Triangles that occlude and vertices that receive.
    n_rays : int
        Rays per vertex (the maximum, with ``tolerance``).
    measure : {"cosine", "uniform"}
        Cosine-weighted occlusion 1/pi int V (w.n) dw (default), or the uniform solid-angle
        fraction 1/(2pi) int V dw.
    max_distance : float, optional
        Rays stop at this distance (mesh units); unbounded by default.
    bias : float, optional
        Ray-origin offset along the normal in mesh units; see :func:`ray_offsets`.
    seed : int
        Key of the per-vertex Owen-scrambled Sobol directions.
    tolerance : float, optional
        Adaptive sampling: stop a vertex once its 95% interval half-width is below this
        (see :func:`stratified_half_width`).
    threads : int, optional
        Worker threads (default: all cores). The result does not depend on it.
    chunk_rays : int
        Rays per Embree call (memory bound); the result does not depend on it.
    stratified : bool
        False draws plain random numbers instead (for tests and comparisons).
    robust : bool
        Embree's robust (watertight) traversal.
    contact_fix : bool
        Move ray origins that the offset would push through another surface
        (:func:`contact_origins`). Off only to reproduce the classic bug.
    progress : Progress, optional

    Returns
    -------
    EmbreeAO
        ``ao`` (n,) float64 in [0, 1] = 1 - A, rays per vertex, seconds, contacts.

    Notes
    -----
    Ray j of vertex i uses the j-th point of a 2-D Sobol sequence Owen-scrambled with a
    hash of (seed, i), warped to the cosine-weighted (or uniform) hemisphere about the
    vertex normal, so A_hat = hits / N is unbiased and every power-of-two prefix is
    stratified. A vertex with no defined normal samples the whole sphere uniformly.
    Every ray is a pure function of (seed, i, j): results are bit-identical for any
    thread count and chunk size.
    """
    t0 = time.perf_counter()
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {sorted(MEASURES)}, got {measure!r}")
    n_rays = int(n_rays)
    if n_rays < 1:
        raise ValueError(f"n_rays must be >= 1, got {n_rays}")
    if max_distance is not None and not max_distance > 0:
        raise ValueError(f"max_distance must be > 0, got {max_distance}")
    if bias is not None and not (bias >= 0 and math.isfinite(bias)):
        raise ValueError(f"bias must be finite and >= 0, got {bias}")
    if tolerance is not None and not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    threads = max(1, int(threads or os.cpu_count() or 1))
    progress = progress or NullProgress()

    n = surface.n_vertices
    scene = Scene(surface.positions, surface.faces, robust=robust)
    edges = _topo.longest_edges(surface.positions, surface.faces)
    offsets = ray_offsets(surface, scene, bias, edges)
    if contact_fix:
        origins, contacts = contact_origins(surface, scene, offsets, edges)
    else:
        origins, contacts = (scene.local + offsets[:, None] * surface.normals).astype(np.float32), 0
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    keys = _k.vertex_keys(np.uint64(seed), n)
    mode = MEASURES[measure] + (0 if stratified else 2)
    tfar = INFINITE_DISTANCE if max_distance is None else float(max_distance)

    hits = np.zeros(n, dtype=np.int64)
    cast = np.zeros(n, dtype=np.int64)
    active = np.arange(n, dtype=np.int64)
    progress.start(n * n_rays, "embree")

    def trace(vertex_index: np.ndarray, j0: int, j1: int) -> int:
        k = vertex_index.size * (j1 - j0)
        org = np.zeros((k, 3), dtype=np.float32)
        dirs = np.zeros((k, 3), dtype=np.float32)
        _k.generate_rays(origins, normals, keys, vertex_index, j0, j1, mode, org, dirs)
        ids = scene.occluded(org, dirs, tfar)
        _k.count_hits(ids, j1 - j0, vertex_index, hits)
        return k

    pool = ThreadPoolExecutor(max_workers=threads)
    try:
        for j0, j1 in _rounds(n_rays, tolerance is not None):
            before = hits[active]
            # at least 4 chunks per thread so small meshes keep every core busy and ray
            # generation overlaps tracing; at most chunk_rays rays per chunk (memory)
            per_chunk = max(1, min(chunk_rays // (j1 - j0), -(-active.size // (4 * threads))))
            chunks = [active[s : s + per_chunk] for s in range(0, active.size, per_chunk)]
            for done in pool.map(lambda c, j0=j0, j1=j1: trace(c, j0, j1), chunks):
                progress.advance(done)
            cast[active] = j1
            if tolerance is not None and j1 < n_rays:
                if j0 == 0:
                    width = half_width(hits[active], cast[active])
                else:  # rounds double: this round is the second half of the prefix
                    width = stratified_half_width(hits[active], before, j1)
                keep = width >= tolerance
                progress.advance(int((~keep).sum()) * (n_rays - j1))
                active = active[keep]
                if active.size == 0:
                    break
    finally:
        # On Ctrl-C or any error, drop the queued chunks instead of tracing them all.
        pool.shutdown(wait=True, cancel_futures=True)
    progress.finish()

    denom = np.maximum(cast, 1)
    ao = 1.0 - hits / denom
    if not np.isfinite(ao).all() or ao.min() < 0.0 or ao.max() > 1.0:
        raise NumericalError(f"{surface.source}: embree produced AO outside [0, 1]")
    return EmbreeAO(ao=ao, rays=cast, seconds=time.perf_counter() - t0, contacts=contacts)
