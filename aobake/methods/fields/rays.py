"""Solid angle and mean occluded direction at points, by Embree rays over the sphere: the
AO field's second sampler.

Numpy-facing; rays are generated and summed by ``aobake.kernels.footprint`` (``_k.*``)
and traced through :mod:`aobake.tracing`.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..._types import FloatArray
from ...constants import CHUNK_RAYS
from ...kernels import footprint as _k
from ...kernels import rays as _rays
from ...progress import NullProgress, Progress
from ...tracing import Tracer, split, trace_chunks
from .options import FieldOptions


def footprint_samples(positions, faces, geometry, *, n_rays, seed, threads, progress) -> FloatArray:
    """(n, 4) Omega and int V w dw from ``n_rays`` rays per point.

    ``geometry`` = (anchors (n, 3), tangents (n, 6), radii (n,), centre (3,)): point p
    sits at centre + radii[p] * unit(anchor), spread over the footprint spanned by the
    tangents (zero tangents: a fixed point; see ``kernels.footprint.footprint_rays``).
    """
    anchors, tangents, radii, centre = geometry
    tracer = Tracer(positions, faces)
    # the kernel writes float32 origins in Embree's frame: lengths divided by its scale
    shift = (np.asarray(centre, dtype=np.float64) - tracer.center) / tracer.scale
    geom = (
        np.ascontiguousarray(anchors, dtype=np.float64),
        np.ascontiguousarray(tangents, dtype=np.float64) / tracer.scale,
        np.ascontiguousarray(radii, dtype=np.float64) / tracer.scale,
        np.ascontiguousarray(shift),
    )
    n = geom[0].shape[0]
    keys = _rays.vertex_keys(np.uint64(seed), n)
    out = np.zeros((n, 4))

    def trace(index: np.ndarray) -> int:
        k = index.size * n_rays
        org = np.zeros((k, 3), dtype=np.float32)
        dirs = np.zeros((k, 3), dtype=np.float32)
        _k.footprint_rays(geom, keys, index, n_rays, org, dirs)
        ids = tracer.occluded(org, dirs)
        _k.accumulate_hits(ids, dirs, n_rays, index, out)
        return index.size

    # each chunk sums its own points' rays in ray order: no dependence on threads
    per_chunk = max(1, CHUNK_RAYS // 4 // n_rays)
    workers = max(1, int(threads or os.cpu_count() or 1))
    trace_chunks(split(np.arange(n, dtype=np.int64), per_chunk), trace, threads=workers, progress=progress)
    out *= 4.0 * math.pi / n_rays
    return out


def embree_occlusion(
    positions,
    faces,
    points,
    *,
    n_rays: int = FieldOptions.n_rays,
    seed: int = 0,
    threads: int | None = None,
    progress: Progress | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Solid angle and occluded vector integral at points, by Embree rays over the sphere.

    Parameters
    ----------
    positions : (nv, 3) float
    faces : (m, 3) int
    points : (n, 3) float
    n_rays : int
        Rays per point: uniform directions on the sphere from an Owen-scrambled Sobol
        sequence keyed by (seed, point index).
    seed : int
    threads : int, optional
    progress : Progress, optional

    Returns
    -------
    omega : (n,) float64
        4 pi hits / n_rays: unbiased for Omega = int V dw.
    vectors : (n, 3) float64
        4 pi / n_rays * sum of the hit directions: unbiased for int V w dw.
    """
    n_rays = int(n_rays)
    if n_rays < 1:
        raise ValueError(f"n_rays must be >= 1, got {n_rays}")
    positions = np.asarray(positions, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    anchors = points - centre
    geometry = (anchors, np.zeros((points.shape[0], 6)), np.linalg.norm(anchors, axis=1), centre)
    progress = progress or NullProgress()
    progress.start(points.shape[0], "embree")
    out = footprint_samples(
        positions,
        np.asarray(faces, dtype=np.int64),
        geometry,
        n_rays=n_rays,
        seed=seed,
        threads=threads,
        progress=progress,
    )
    progress.finish()
    return out[:, 0].copy(), out[:, 1:].copy()
