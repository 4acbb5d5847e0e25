"""Hybrid AO: short rays resolve the near field, the disk tree carries the far field.

The disk method's error lives near the receiver (contacts, creases, stacked layers seen
through each other) and Monte Carlo's noise comes from every distance alike. Here each
vertex casts a few rays (Embree, the reference's own directions and origins) no longer
than ``reach`` local edge lengths, which see the near field with true visibility, and
the disk tree (:mod:`aobake.bunnell`) sums only the emitters beyond that distance,
where disks are accurate and smooth. Numpy-facing; never prints.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ._types import AOArray, FloatArray, IndexArray
from .bunnell import (
    DEFAULT_LEAF_SIZE,
    PLAIN_THETA,
    build_elements,
    build_tree,
    numba_threads,
    occlusion_passes,
)
from .constants import CHUNK_RAYS
from .errors import NumericalError
from .kernels import rays as _rays
from .mesh import Surface, vertex_edge_lengths
from .progress import NullProgress, Progress
from .raytrace import MEASURES, Scene, contact_origins, ray_offsets

# Rays per vertex and ray length in local edge lengths (the longest edge at the vertex):
# bench/bench_bunnell.py (section 1) and the README. 16 rays match the cost of a disk
# pass; reach 2 or 8 was no better than 4 on the bench scenes (8 spoils facing plates).
DEFAULT_HYBRID_RAYS = 16
DEFAULT_REACH = 4.0
COMBINES = ("product", "sum", "max")


@dataclass(frozen=True)
class HybridAO:
    """Result of :func:`hybrid_ao`.

    Attributes
    ----------
    ao : (n,) float64 in [0, 1]
        Accessibility 1 - A.
    near, far : (n,) float64 in [0, 1]
        Occlusion of the near field (rays) and of the far field (disks).
    reach : (n,) float64
        Ray length per vertex (mesh units).
    n_rays : int
        Rays cast in total.
    seconds : float
    contacts : int
        Vertices whose ray origin was moved off a touching surface (as in embree_ao).
    """

    ao: AOArray
    near: FloatArray
    far: FloatArray
    reach: FloatArray
    n_rays: int
    seconds: float
    contacts: int


def hybrid_ao(
    surface: Surface,
    *,
    n_rays: int = DEFAULT_HYBRID_RAYS,
    reach: float = DEFAULT_REACH,
    theta: float = PLAIN_THETA,
    combine: str = "sum",
    far_sides: str = "front",
    measure: str = "cosine",
    max_distance: float | None = None,
    bias: float | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: Progress | None = None,
) -> HybridAO:
    """Per-vertex accessibility: short rays near the vertex, disks beyond.

    Parameters
    ----------
    surface : Surface
    n_rays : int
        Rays per vertex (>= 1), the same Owen-scrambled Sobol directions and contact-safe
        origins as :func:`aobake.raytrace.embree_ao` with this ``seed``.
    reach : float
        Ray length in local edge lengths (> 0): vertex i's rays stop at
        ``D_i = reach * e_i`` (``e_i`` its longest edge; capped by ``max_distance``).
        Its near-field occlusion is ``A_near = hits / n_rays``.
    theta : float
        Opening parameter of the disk tree for the far field.
    combine : {"product", "sum", "max"}
        ``"product"``: ``A = 1 - (1 - A_near)(1 - A_far)`` (far geometry hidden behind
        near geometry in proportion); ``"sum"``: ``min(1, A_near + A_far)``;
        ``"max"``: ``max(A_near, A_far)``.
    far_sides : {"front", "max"}
        Side rule of the far field's disks (:func:`aobake.bunnell.combine_sides`).
        "front": a closed object cut by the ray ball would show its far side's back
        faces without its near side's front faces, and "max" would count it twice.
    measure : {"cosine", "uniform"}
    max_distance : float or None
        Limit for rays and disks (mesh units).
    bias : float or None
        Ray origin offset, see :func:`aobake.raytrace.ray_offsets`.
    seed : int
    threads : int or None
        Ray threads and numba threads (default: all cores).
    progress : Progress or None

    Returns
    -------
    HybridAO

    Notes
    -----
    The far field sums disks whose centre is at least ``D_i`` from the receiver
    (``inner`` of :func:`aobake.bunnell.occlusion_passes`) with no near-field cells: the
    rays see everything closer. Vertices without edges (isolated) have ``D_i = 0``: disks
    only. Deterministic for a given seed, whatever the thread count.
    """
    t0 = time.perf_counter()
    n_rays = _check_positive_int("n_rays", n_rays)
    if isinstance(reach, bool) or not isinstance(reach, (int, float, np.floating, np.integer)):
        raise ValueError(f"reach must be a positive number, got {reach!r}")
    if not (0.0 < reach < math.inf):
        raise ValueError(f"reach must be finite and > 0, got {reach!r}")
    if combine not in COMBINES:
        raise ValueError(f"combine must be one of {list(COMBINES)}, got {combine!r}")
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {sorted(MEASURES)}, got {measure!r}")
    if max_distance is not None and not (0.0 < max_distance < math.inf):
        raise ValueError(f"max_distance must be finite and > 0 (None = unbounded), got {max_distance!r}")
    progress = NullProgress() if progress is None else progress
    n = surface.n_vertices
    workers = max(1, int(threads or os.cpu_count() or 1))
    progress.start(n * (n_rays + 1), "hybrid")

    distance = reach * vertex_edge_lengths(
        np.asarray(surface.positions, dtype=np.float64), np.asarray(surface.faces, dtype=np.int64)
    )
    if max_distance is not None:
        distance = np.minimum(distance, float(max_distance))
    near, contacts = _near_field(surface, distance, n_rays, measure, bias, seed, workers, progress)

    elements = build_elements(surface)
    far = np.zeros(n)
    if elements.n_emitters > 0:
        with numba_threads(threads):
            tree = build_tree(elements, leaf_size=DEFAULT_LEAF_SIZE)
        far = occlusion_passes(
            elements,
            tree,
            theta=theta,
            near=0.0,
            sides=far_sides,
            directional=False,  # measured with plain sums; not tried with saturation
            measure=measure,
            max_distance=max_distance,
            inner=distance,
            threads=threads,
        )[0]
    progress.advance(n)
    progress.finish()
    if combine == "product":
        occlusion = 1.0 - (1.0 - near) * (1.0 - far)
    elif combine == "sum":
        occlusion = np.minimum(near + far, 1.0)
    else:
        occlusion = np.maximum(near, far)
    ao = np.clip(1.0 - occlusion, 0.0, 1.0)
    if not np.isfinite(ao).all():
        raise NumericalError(f"{surface.source}: hybrid produced non-finite AO")
    return HybridAO(ao, near, far, distance, n * n_rays, time.perf_counter() - t0, contacts)


def _near_field(surface, distance, n_rays, measure, bias, seed, workers, progress):
    """Occlusion by rays of length ``distance`` (per vertex): hits / n_rays, contacts."""
    n = surface.n_vertices
    if surface.n_faces == 0 or n == 0:
        progress.advance(n * n_rays)
        return np.zeros(n), 0
    scene = Scene(surface.positions, surface.faces)
    offsets = ray_offsets(surface, scene, bias)
    origins, contacts = contact_origins(surface, scene, offsets)
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    keys = _rays.vertex_keys(np.uint64(seed), n)
    mode = MEASURES[measure]
    # a ray shorter than its origin offset would start beyond its end: no near field
    traced = np.flatnonzero(distance > 2.0 * offsets).astype(np.int64)
    hits = np.zeros(n, dtype=np.int64)
    tfar32 = distance.astype(np.float32)

    def trace(vertex_index: IndexArray) -> int:
        k = vertex_index.size * n_rays
        org = np.zeros((k, 3), dtype=np.float32)
        dirs = np.zeros((k, 3), dtype=np.float32)
        _rays.generate_rays(origins, normals, keys, vertex_index, 0, n_rays, mode, org, dirs)
        found = scene.intersect(org, dirs, np.repeat(tfar32[vertex_index], n_rays))
        ids = np.where(found["primID"] >= 0, 0, -1).astype(np.int32)
        _rays.count_hits(ids, n_rays, vertex_index, hits)
        return k

    per_chunk = max(1, CHUNK_RAYS // n_rays)
    chunks = [traced[s : s + per_chunk] for s in range(0, traced.size, per_chunk)]
    progress.advance((n - traced.size) * n_rays)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for done in pool.map(trace, chunks):
            progress.advance(done)
    return hits / n_rays, contacts


def _check_positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)
