"""The ray-traced irradiance reference: direct light by shadow rays, indirect light by
cosine-weighted paths with next-event estimation (docs/light-transport.md).

Numpy-facing; samples are made and summed by ``aobake.kernels.lights`` and traced
through :mod:`aobake.tracing` from the AO's contact-safe origins. Never prints.
"""

from __future__ import annotations

import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ...constants import (
    ADAPTIVE_FIRST_ROUND,
    BLOCK_RAYS,
    CHUNK_RAYS,
    EPS32,
    INFINITE_DISTANCE,
    RAY_OFFSET_ULPS,
    Z95,
)
from ...contacts import contact_origins, ray_offsets
from ...errors import NumericalError
from ...ground import ALBEDO as GROUND_ALBEDO
from ...ground import Ground
from ...kernels import lights as _kl
from ...kernels import rays as _k
from ...kernels import topology as _topo
from ...kernels.lights import light_table
from ...mesh import Surface
from ...options import build
from ...progress import NullProgress, Progress
from ...shading import AREA_KINDS, Light, LightResult, LightStats, Shading, check_shading
from ...tracing import trace_chunks, tracer_for
from .options import LightOptions


def _sampled(light: Light) -> bool:
    """Whether a light's direct term needs many samples (else one is exact)."""
    return light.kind in AREA_KINDS or (light.kind == "distant" and light.angle > 0)


def _rounds(n: int, adaptive: bool) -> list[int]:
    """Sample counts at the end of each round (powers of two from 16, then ``n``)."""
    if not adaptive:
        return [n]
    out, j = [], min(ADAPTIVE_FIRST_ROUND, n)
    while True:
        out.append(j)
        if j >= n:
            return out
        j = min(2 * j, n)


def run_light(
    surface: Surface,
    shading: Shading,
    options,
    progress: Progress | None = None,
    *,
    indirect: bool = True,
    ground: Ground | None = None,
) -> LightResult:
    """The method interface (:func:`aobake.methods.run_light`): :func:`irradiance` with
    the light fields of ``options`` (:class:`~aobake.methods.embree.EmbreeOptions`);
    ``indirect=False`` computes direct light only."""
    changes = {} if indirect else {"bounces": 0}
    return irradiance(surface, shading, options.light(**changes), progress=progress, ground=ground)


def irradiance(
    surface: Surface,
    shading: Shading,
    options: LightOptions | None = None,
    *,
    progress: Progress | None = None,
    chunk_rays: int = CHUNK_RAYS,
    ground: Ground | None = None,
    **changes,
) -> LightResult:
    """Per-vertex irradiance (direct and indirect, RGB) of ``surface`` lit by ``shading``.

    Parameters
    ----------
    surface : Surface
        Triangles that occlude and reflect, vertices that receive.
    shading : Shading
        Lights, per-face albedo and emission (:mod:`aobake.shading`).
    options : LightOptions, optional
        ``n_samples``, ``bounces``, ``n_indirect``, ``tolerance``, ``max_distance``,
        ``bias``, ``seed``, ``threads``; keywords override them.
    progress : Progress, optional
    chunk_rays : int
        About this many rays per work item (memory; no effect on the result).
    ground : aobake.ground.Ground, optional
        An infinite plane under the mesh (:mod:`aobake.ground`): it occludes shadow and
        path rays (one test per ray) and reflects the paths that meet it with
        :data:`aobake.ground.ALBEDO`; nothing receives on it.

    Notes
    -----
    Direct light: one shadow ray per point, spot or sharp distant light; ``n_samples``
    stratified (Owen-scrambled Sobol, keyed by seed, vertex and light) per area light,
    angular distant light and for the emitting triangles together; a light without
    shadows adds its unoccluded value without rays. Indirect light and the dome:
    ``n_indirect`` cosine-weighted paths per vertex; a path that escapes sees the dome
    (pi L times its throughput; at the first ray that is direct light), a path that hits
    a face takes its albedo, estimates the light there by one sample per light (pure
    next-event estimation: emission a path hits is never added, so nothing is counted
    twice) and goes on for ``bounces`` hits. Every sample is a pure function of (seed,
    vertex, component, index) and each vertex's sums are made in one order, so results
    are bit-identical for any thread count and chunking.
    """
    options = build(LightOptions, options, **changes)
    check_shading(surface, shading)
    t0 = time.perf_counter()
    progress = progress or NullProgress()
    cores = os.cpu_count() or 1
    threads = max(1, min(int(options.threads or cores), cores))  # more: no faster, more memory
    n = surface.n_vertices
    lights = tuple(light for light in shading.lights)
    n_lights = len(lights)
    n_comp = n_lights + 1

    tracer = tracer_for(surface.positions, surface.faces)
    edges = _topo.longest_edges(surface.positions, surface.faces)
    offsets = ray_offsets(surface, tracer.magnitude, options.bias, edges)
    origins, contacts = contact_origins(surface, tracer, offsets, edges)
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    points = np.ascontiguousarray(tracer.local)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64)
    keys = _k.vertex_keys(np.uint64(options.seed), n)
    scale = float(tracer.scale)
    tmax = math.inf if options.max_distance is None else float(options.max_distance)
    far_cap = min(tmax / scale, INFINITE_DISTANCE)  # the longest ray in Embree's frame

    kinds, params = light_table(lights, tracer.center)
    black = np.array([light.is_black for light in lights], dtype=bool)
    reach = _kl.reach_all(points, normals, kinds, params) if n_lights else np.zeros((n, 0), dtype=np.int8)
    reach[:, black] = _kl.REACH_NONE

    # faces: unit normals, hit-point offsets, the emitters' sampling table
    corner = surface.positions[faces] if faces.size else np.zeros((0, 3, 3))
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]) if faces.size else np.zeros((0, 3))
    length = np.linalg.norm(cross, axis=1)
    face_normals = np.where(length[:, None] > 0, cross / np.where(length > 0, length, 1.0)[:, None], 0.0)
    face_edges = edges[faces].max(axis=1) if faces.size else np.zeros(0)
    face_offsets = RAY_OFFSET_ULPS * EPS32 * (tracer.magnitude + face_edges)
    emission = np.ascontiguousarray(shading.face_emission, dtype=np.float64)
    power = 0.5 * length * emission.sum(axis=1) if faces.size else np.zeros(0)
    tris = np.flatnonzero(power > 0).astype(np.int64)
    has_emitters = tris.size > 0
    cdf = np.cumsum(power[tris]) / power[tris].sum() if has_emitters else np.ones(1)
    if has_emitters:
        cdf[-1] = 1.0
    else:
        tris = np.zeros(1, dtype=np.int64)
    lum_total = float((0.5 * length[tris] * emission[tris].sum(axis=1)).sum()) if has_emitters else 1.0
    albedo = np.ascontiguousarray(shading.face_albedo, dtype=np.float64)
    plane = np.full(_kl.G_SIZE, -1.0)  # the ground plane's row; axis -1: none
    g_axis, g_height = -1, 0.0
    if ground is not None:
        g_axis = int(ground.axis)
        plane[_kl.G_HEIGHT] = float(ground.height) - float(tracer.center[g_axis])
        plane[_kl.G_AXIS] = g_axis
        plane[_kl.G_EPS] = RAY_OFFSET_ULPS * EPS32
        plane[_kl.G_MAGNITUDE] = tracer.magnitude
        plane[_kl.G_ALBEDO : _kl.G_ALBEDO + 3] = GROUND_ALBEDO
        g_height = plane[_kl.G_HEIGHT] / scale  # in Embree's frame

    # samples per component; the dome with shadows comes from the paths
    dome = np.zeros(3)
    exact = np.zeros(n_comp, dtype=bool)
    sampled = np.zeros(n_comp, dtype=bool)
    for c, light in enumerate(lights):
        if light.is_black:
            continue
        if light.kind == "dome" and light.shadow:
            dome += light.value
        elif _sampled(light):
            sampled[c] = True
        else:
            exact[c] = True  # point, spot, sharp distant, a dome without shadows
    sampled[n_lights] = has_emitters
    lit = bool(exact.any() or sampled.any() or np.any(dome > 0))
    bounces = options.bounces if shading.reflects and lit else 0
    sees_dome = bool(np.any(dome > 0))
    use_paths = sees_dome or bounces > 0

    adaptive = options.tolerance is not None
    ends = _rounds(options.n_samples, adaptive)
    path_ends = [max(1, -(-options.n_indirect * j // options.n_samples)) for j in ends]
    per_vertex = int(sampled.sum()) * options.n_samples + int(exact.sum())
    if use_paths:
        per_vertex += options.n_indirect * (bounces * (1 + n_comp) + (1 if sees_dome else 0))
    per_chunk = max(1, min(chunk_rays // max(per_vertex, 1), -(-n // (4 * threads))))

    sums = np.zeros((n, n_comp, 3))
    squares = np.zeros((n, n_comp, 3))
    path_d = np.zeros((n, 3))
    path_i = np.zeros((n, 3))
    path_sq = np.zeros((n, 3))
    shadow_rays = np.zeros(n_comp, dtype=np.int64)
    counts = {"bounce": 0}
    lock = threading.Lock()
    inv_scale = 1.0 / scale

    def _occluded(org, dirs, far, m, on_plane):
        """Shadow rays 0..m-1: -1 where unoccluded by the mesh and the ground plane."""
        if ground is None:
            return tracer.occluded_within(org[:m], dirs[:m], far[:m])
        _kl.ground_shadows(org, dirs, far, m, g_axis, g_height, on_plane)
        ids = tracer.occluded_within(org[:m], dirs[:m], far[:m])
        return np.where(on_plane[:m] != 0, 0, ids)

    def direct(vidx, j_lo, j_hi):
        # Whole vertices in blocks of ~BLOCK_RAYS rays through buffers made once (as paths).
        per = int(np.maximum(j_hi - j_lo, 0).sum())
        if per == 0 or vidx.size == 0:
            return 0
        block = max(1, BLOCK_RAYS // per)
        k = min(block, vidx.size) * per
        org = np.empty((k, 3), dtype=np.float32)
        dirs = np.empty((k, 3), dtype=np.float32)
        far = np.empty(k, dtype=np.float32)
        w = np.empty((k, 3))
        row = np.empty(k, dtype=np.int64)
        comp = np.empty(k, dtype=np.int64)
        on_plane = np.empty(k, dtype=np.uint8)
        local = np.zeros((vidx.size, n_comp, 3))
        local_sq = np.zeros((vidx.size, n_comp, 3))
        cast = np.zeros(n_comp, dtype=np.int64)
        for b in range(0, vidx.size, block):
            sub, here, here_sq = vidx[b : b + block], local[b : b + block], local_sq[b : b + block]
            m = _kl.direct_samples(
                sub, points, origins, normals, keys, kinds, params, j_lo, j_hi, reach,
                points, faces, tris, cdf, emission, lum_total, face_offsets, scale, far_cap, here, here_sq,
                org, dirs, far, w, row, comp,
            )  # fmt: skip
            if m:
                ids = _occluded(org, dirs, far, m, on_plane)
                _kl.add_samples(ids, w, row, comp, m, here, here_sq)
                cast += np.bincount(comp[:m], minlength=n_comp)
        sums[vidx] += local
        squares[vidx] += local_sq
        with lock:
            shadow_rays[:] += cast
        return int(cast.sum())

    def paths(vidx, p0, p1):
        # Whole vertices in blocks of ~BLOCK_RAYS paths through buffers made once: they
        # stay in cache and are not faulted in anew per chunk (each path and each
        # vertex's sums see the same values in the same order as in one block).
        per = p1 - p0
        block = max(1, BLOCK_RAYS // per)
        size = min(block, vidx.size) * per
        hashes = _kl.path_hashes(p0, p1)
        path_org = np.empty((size, 3))
        path_normal = np.empty((size, 3))
        alive = np.empty(size, dtype=bool)
        throughput = np.empty((size, 3))
        value_d = np.empty((size, 3))
        value_i = np.empty((size, 3))
        live = np.empty(size, dtype=np.int64)
        org = np.empty((size, 3), dtype=np.float32)
        dirs = np.empty((size, 3), dtype=np.float32)
        far = np.empty(size, dtype=np.float32)
        k = size * n_comp
        s_org = np.empty((k, 3), dtype=np.float32)
        s_dir = np.empty((k, 3), dtype=np.float32)
        s_far = np.empty(k, dtype=np.float32)
        s_w = np.empty((k, 3))
        s_row = np.empty(k, dtype=np.int64)
        on_plane = np.zeros(max(k, size), dtype=np.uint8)
        sd = np.zeros((vidx.size, 3))
        si = np.zeros((vidx.size, 3))
        sq = np.zeros((vidx.size, 3))
        rays = 0
        for b in range(0, vidx.size, block):
            sub = vidx[b : b + block]
            m = _kl.first_rays(sub, per, p0, origins, normals, keys, alive, throughput, value_d, value_i, live, org, dirs)
            rays += _trace_paths(
                sub, per, hashes, m, path_org, path_normal, alive, throughput, value_d, value_i,
                live, org, dirs, far, s_org, s_dir, s_far, s_w, s_row, on_plane,
            )  # fmt: skip
            _kl.path_sums(value_d, value_i, per, sd[b : b + sub.size], si[b : b + sub.size], sq[b : b + sub.size])
        path_d[vidx] += sd
        path_i[vidx] += si
        path_sq[vidx] += sq
        with lock:
            counts["bounce"] += rays
        return rays

    def _trace_paths(
        sub, per, hashes, m, path_org, path_normal, alive, throughput, value_d, value_i,
        live, org, dirs, far, s_org, s_dir, s_far, s_w, s_row, on_plane,
    ):  # fmt: skip
        """The paths of vertices ``sub`` (``per`` each, the buffers' first rows), their m
        first rays written, to their end; the rays cast."""
        rays = 0
        for depth in range(bounces + 1):
            if depth == bounces and not sees_dome:
                break  # the last ray only looks for the dome: without one it adds nothing
            if depth > 0:
                m = _kl.bounce_directions(path_org, path_normal, alive, keys, sub, per, hashes, depth, inv_scale, live, org, dirs)
            if m == 0:
                break
            if ground is not None:  # Embree looks no farther than the plane
                _kl.ground_clip(org, dirs, m, g_axis, g_height, far_cap, RAY_OFFSET_ULPS * EPS32, far, on_plane)
                if depth == bounces:  # escapes alone matter: Embree's cheaper any-hit query
                    prim = tracer.occluded_within(org[:m], dirs[:m], far[:m])
                else:
                    prim = tracer.first_hits_within(org[:m], dirs[:m], far[:m])
            elif depth == bounces:
                prim = tracer.occluded(org[:m], dirs[:m], options.max_distance)
            else:
                prim = tracer.first_hits(org[:m], dirs[:m], options.max_distance)
            rays += m
            _kl.follow_hits(
                live, m, prim, org, dirs, scale, points, faces, path_org, path_normal, throughput,
                value_d if depth == 0 else value_i, alive, face_normals, albedo, dome, face_offsets,
                depth < bounces, on_plane, plane,
            )  # fmt: skip
            if depth == bounces:
                break
            m = _kl.hit_samples(
                alive, path_org, path_normal, throughput, keys, sub, per, hashes, depth,
                kinds, params, has_emitters, points, faces, tris, cdf, emission, lum_total, face_offsets,
                inv_scale, far_cap, value_i, s_org, s_dir, s_far, s_w, s_row,
            )  # fmt: skip
            if m:
                ids = _occluded(s_org, s_dir, s_far, m, on_plane)
                _kl.add_path_samples(ids, s_w, s_row, m, value_i)
            rays += m
        return rays

    taken = np.zeros(n, dtype=np.int64)
    taken_paths = np.zeros(n, dtype=np.int64)
    active = np.arange(n, dtype=np.int64)
    progress.start(n * per_vertex, "light")
    pool = ThreadPoolExecutor(max_workers=threads)
    j0 = p0 = 0
    try:
        for r, (j1, p1) in enumerate(zip(ends, path_ends, strict=True)):
            j_lo = np.where(sampled, j0, 0).astype(np.int64)
            j_hi = np.where(sampled, j1, 0).astype(np.int64)
            if r == 0:
                j_hi[exact] = 1

            def work(vidx, j_lo=j_lo, j_hi=j_hi, p0=p0, p1=p1):
                done = direct(vidx, j_lo, j_hi)
                if use_paths and p1 > p0:
                    done += paths(vidx, p0, p1)
                return done

            trace_chunks(
                (active[s : s + per_chunk] for s in range(0, active.size, per_chunk)),
                work,
                threads=threads,
                progress=progress,
                pool=pool,
            )
            taken[active] = j1
            taken_paths[active] = p1 if use_paths else 0
            j0, p0 = j1, p1
            if adaptive and j1 < options.n_samples:
                e, err = _estimate(sums, squares, path_d, path_i, path_sq, taken, taken_paths, sampled, exact, active)
                keep = np.max(err, axis=1) > options.tolerance * np.max(e, axis=1)
                active = active[keep]
                if active.size == 0:
                    break
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    progress.finish()

    everyone = np.arange(n, dtype=np.int64)
    direct_e, indirect_e, error = _estimate(
        sums, squares, path_d, path_i, path_sq, taken, taken_paths, sampled, exact, everyone, split=True
    )
    for name, arr in (("direct", direct_e), ("indirect", indirect_e), ("error", error)):
        if not np.isfinite(arr).all() or arr.min() < 0:
            raise NumericalError(f"{surface.source}: the light transport produced a {name} irradiance that is negative or not finite")
    stats = []
    for c in range(n_comp):
        name = lights[c].name if c < n_lights else "emitters"
        if c < n_lights and not lights[c].is_black:
            codes = np.bincount(reach[:, c].astype(np.int64), minlength=5)
            stats.append(LightStats(name, int(codes[1]), int(codes[2]), int(codes[3]), int(codes[4]), int(shadow_rays[c])))
        else:
            stats.append(LightStats(name, shadow_rays=int(shadow_rays[c])))
    return LightResult(
        direct=direct_e,
        indirect=indirect_e,
        error=error,
        n_shadow_rays=int(shadow_rays.sum()),
        n_bounce_rays=int(counts["bounce"]),
        lights=tuple(stats),
        samples=np.where(np.any(normals != 0, axis=1), taken, 0),
        seconds=time.perf_counter() - t0,
        contacts=contacts,
    )


def _estimate(sums, squares, path_d, path_i, path_sq, taken, taken_paths, sampled, exact, rows, split=False):
    """Means and 95% half-widths of ``rows``: (irradiance, error), or with ``split``
    (direct, indirect, error). Each sampled component and the paths add their variance
    of the mean, (sum of squares - n mean^2) / (n (n - 1)); exact ones add none."""
    n_samp = taken[rows].astype(np.float64)[:, None, None]
    s, q = sums[rows], squares[rows]
    weight = sampled.astype(np.float64)[None, :, None]
    safe = np.maximum(n_samp, 1.0)
    mean_sampled = s / safe
    var = np.maximum(q - s * mean_sampled, 0.0) / np.maximum(safe * (safe - 1.0), 1.0)
    direct = (mean_sampled * weight).sum(axis=1) + (s * exact[None, :, None]).sum(axis=1)
    variance = (var * weight).sum(axis=1)
    np_ = taken_paths[rows].astype(np.float64)[:, None]
    safe_p = np.maximum(np_, 1.0)
    d, i = path_d[rows] / safe_p, path_i[rows] / safe_p
    total = path_d[rows] + path_i[rows]
    variance += np.maximum(path_sq[rows] - total * (d + i), 0.0) / np.maximum(safe_p * (safe_p - 1.0), 1.0)
    direct = direct + d
    error = Z95 * np.sqrt(variance)
    if split:
        return direct, i, error
    return direct + i, error
