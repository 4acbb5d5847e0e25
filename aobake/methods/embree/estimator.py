"""The estimator of :mod:`aobake.methods.embree`: cosine-weighted (or uniform) rays from
contact-safe origins, counted per vertex, in rounds when adaptive.

Numpy-facing; the rays are generated and counted by ``aobake.kernels.rays`` (``_k.*``)
and traced through :mod:`aobake.tracing`. Never prints.
"""

from __future__ import annotations

import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..._types import AOArray, IndexArray
from ...constants import ADAPTIVE_FIRST_ROUND, CHUNK_RAYS, MEASURE_CODES, Z95
from ...contacts import contact_origins, ray_offsets
from ...errors import NumericalError
from ...ground import Ground
from ...kernels import rays as _k
from ...kernels import topology as _topo
from ...mesh import Surface
from ...options import build
from ...progress import NullProgress, Progress
from ...tracing import trace_chunks, tracer_for
from .. import MethodResult
from .options import EmbreeOptions


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
    bent_normals : (n, 3) float64 or None
        With ``bent_normals=True``: the cosine-weighted mean direction of the escaping
        rays, normalised (world space); a vertex whose every ray hit gets its normal.
    """

    ao: AOArray
    rays: IndexArray
    seconds: float
    contacts: int
    bent_normals: np.ndarray | None = None

    @property
    def n_rays(self) -> int:
        return int(self.rays.sum())


def _rounds(n_rays: int, adaptive: bool) -> list[tuple[int, int]]:
    """Sample-index ranges per round; adaptive rounds end on powers of two."""
    if not adaptive:
        return [(0, n_rays)]
    out, j0, j1 = [], 0, min(ADAPTIVE_FIRST_ROUND, n_rays)
    while j0 < n_rays:
        out.append((j0, j1))
        j0, j1 = j1, min(2 * j1, n_rays)
    return out


def ray_chunks(active: np.ndarray, j0: int, j1: int, chunk_rays: int, threads: int):
    """(vertices, ja, jb) work items covering rays j0..j1-1 of every ``active`` vertex.

    At least 4 items per thread so small meshes keep every core busy and ray generation
    overlaps tracing; at most ``chunk_rays`` rays per item (memory): a vertex with more
    rays than that has its sample range cut into pieces. A generator: 2**32 rays per
    vertex on a large mesh are billions of items, made as they are traced.
    """
    per = j1 - j0
    per_chunk = max(1, min(chunk_rays // per, -(-active.size // (4 * threads))))
    step = per if per_chunk > 1 or per <= chunk_rays else max(1, chunk_rays)
    for start in range(0, active.size, per_chunk):
        vertices = active[start : start + per_chunk]
        for ja in range(j0, j1, step):
            yield vertices, ja, min(ja + step, j1)


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
      (bench/accuracy_embree.py and the tests measure it), and at n = 16 this is the plain
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
    options: EmbreeOptions | None = None,
    *,
    progress: Progress | None = None,
    ground: Ground | None = None,
    **changes,
) -> EmbreeAO:
    """Per-vertex ambient occlusion by Monte Carlo ray casting (the reference).

    Parameters
    ----------
    surface : Surface
        Triangles that occlude and vertices that receive.
    options : EmbreeOptions, optional
        ``n_rays``, ``measure``, ``max_distance``, ``bias``, ``tolerance``, ``seed``,
        ``threads`` (see :class:`EmbreeOptions`); keywords override them:
        ``embree_ao(surface, n_rays=64)``.
    progress : Progress, optional
    ground : aobake.ground.Ground, optional
        An infinite occluding plane (:mod:`aobake.ground`): one analytic test per ray,
        no triangles added.

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
    thread count and chunk size. With ``tolerance``, rays are cast in rounds that end on
    powers of two and a vertex stops once :func:`stratified_half_width` is below it.
    """
    return estimate(surface, build(EmbreeOptions, options, **changes), progress, ground=ground)


def run(
    surface: Surface,
    options: EmbreeOptions,
    progress: Progress | None = None,
    vertices: tuple[int, int] | None = None,
    ground: Ground | None = None,
) -> MethodResult:
    """The method interface (:mod:`aobake.methods`); ``vertices``, ``ground``: see :func:`estimate`."""
    result = estimate(surface, options, progress, vertices=vertices, ground=ground)
    extra = {} if result.bent_normals is None else {"bentNormal": result.bent_normals}
    return MethodResult(result.ao, result.n_rays, result.contacts, extra)


def estimate(
    surface: Surface,
    options: EmbreeOptions,
    progress: Progress | None = None,
    *,
    chunk_rays: int = CHUNK_RAYS,
    stratified: bool = True,
    contact_fix: bool = True,
    vertices: tuple[int, int] | None = None,
    ground: Ground | None = None,
) -> EmbreeAO:
    """:func:`embree_ao` with the knobs tests and the bench turn: ``chunk_rays`` rays per
    Embree call at most (memory; no effect on the result), ``stratified=False`` plain
    random numbers instead of the scrambled Sobol points, ``contact_fix=False`` plain
    offset origins (the classic bug, :func:`aobake.contacts.contact_origins`).

    ``vertices=(lo, hi)``: trace only vertices lo..hi-1 against the whole scene and
    return their results alone (``ao`` and ``rays`` of length hi - lo). Every ray is a
    pure function of (seed, vertex, sample), so the pieces of a mesh, concatenated,
    equal the whole bake bit for bit (``aobake batch --split``).

    ``ground``: a ray also counts as a hit where it meets the plane within its reach
    (:func:`aobake.kernels.rays.ground_rays`); without it the result is unchanged."""
    t0 = time.perf_counter()
    n_rays = options.n_rays
    cores = os.cpu_count() or 1
    threads = max(1, min(int(options.threads or cores), cores))  # more: no faster, more memory
    progress = progress or NullProgress()

    n = surface.n_vertices
    lo, hi = (0, n) if vertices is None else (int(vertices[0]), int(vertices[1]))
    if not 0 <= lo <= hi <= n:
        raise ValueError(f"vertex range ({lo}, {hi}) is not within the mesh's {n} vertices")
    tracer = tracer_for(surface.positions, surface.faces, deferred=True)
    edges = _topo.longest_edges(surface.positions, surface.faces)
    offsets = ray_offsets(surface, tracer.magnitude, options.bias, edges)
    if contact_fix:
        origins, contacts = contact_origins(surface, tracer, offsets, edges)
    else:
        origins, contacts = tracer.frame(tracer.local + offsets[:, None] * surface.normals), 0
    del edges, offsets  # freed before the rays (memory)
    tracer.build()  # after the origins: their temporaries are gone before Embree's memory
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    keys = _k.vertex_keys(np.uint64(options.seed), n)
    mode = MEASURE_CODES[options.measure] + (0 if stratified else 2)
    tfar = None if options.max_distance is None else float(options.max_distance)
    tolerance = options.tolerance
    if ground is not None:  # the plane in Embree's frame (recentred, divided by the scale)
        g_axis = int(ground.axis)
        g_height = (float(ground.height) - float(tracer.center[g_axis])) / tracer.scale
        g_reach = math.inf if tfar is None else tfar / tracer.scale

    hits = np.zeros(n, dtype=np.int64)
    cast = np.zeros(n, dtype=np.int64)
    escapes = np.zeros((n, 3), dtype=np.int64) if options.bent_normals else None
    weigh = options.measure != "cosine"
    active = np.arange(lo, hi, dtype=np.int64)
    progress.start(active.size * n_rays, "embree")

    lock = threading.Lock()

    def trace(chunk) -> int:
        vertex_index, j0, j1 = chunk
        k = vertex_index.size * (j1 - j0)
        org = np.zeros((k, 3), dtype=np.float32)
        dirs = np.zeros((k, 3), dtype=np.float32)
        _k.generate_rays(origins, normals, keys, vertex_index, j0, j1, mode, org, dirs)
        if ground is not None:  # the plane first: its hits are not traced
            on_plane = np.empty(k, dtype=np.uint8)
            _k.ground_rays(org, dirs, g_axis, g_height, g_reach, on_plane)
        ids = tracer.occluded(org, dirs, tfar)
        if ground is not None:
            ids = np.where(on_plane != 0, 0, ids)
        with lock:  # a vertex's rays may span chunks: integer sums, any order
            _k.count_hits(ids, j1 - j0, vertex_index, hits)
            if escapes is not None:
                _k.sum_escapes(ids, dirs, j1 - j0, vertex_index, normals, weigh, escapes)
        return k

    pool = ThreadPoolExecutor(max_workers=threads)
    try:
        for j0, j1 in _rounds(n_rays, tolerance is not None):
            before = hits[active] if tolerance is not None else None
            trace_chunks(
                ray_chunks(active, j0, j1, chunk_rays, threads),
                trace,
                threads=threads,
                progress=progress,
                pool=pool,
            )
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
        pool.shutdown(wait=True, cancel_futures=True)
    progress.finish()
    tracer = origins = keys = active = None  # Embree's scene and the ray inputs, freed first

    hits, cast = hits[lo:hi], cast[lo:hi]
    denom = np.maximum(cast, 1)
    ao = 1.0 - hits / denom
    if not np.isfinite(ao).all() or ao.min() < 0.0 or ao.max() > 1.0:
        raise NumericalError(f"{surface.source}: embree produced AO outside [0, 1]")
    bent = None if escapes is None else bent_from_sums(escapes[lo:hi], normals[lo:hi])
    return EmbreeAO(ao=ao, rays=cast, seconds=time.perf_counter() - t0, contacts=contacts, bent_normals=bent)


def bent_from_sums(sums: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit bent normals from the fixed-point escape sums; the normal where no ray
    escaped (a zero row where the vertex has no normal either)."""
    total = sums.astype(np.float64)
    length = np.linalg.norm(total, axis=1)
    open_ = length > 0
    out = np.array(normals, dtype=np.float64)
    out[open_] = total[open_] / length[open_, None]
    return out
