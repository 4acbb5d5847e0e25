"""Numpy-facing access to the sample sets and warps the ray kernels use.

Owns no global RNG: every sample is a pure function of (seed, vertex, sample index).
Wraps ``kernels/rng`` and ``kernels/warps`` for tests, inspection and other methods.
"""

from __future__ import annotations

import numpy as np

from ._types import FloatArray
from .constants import MEASURE_CODES
from .kernels import rays as _k
from .kernels import rng as _rng


def unit_square_samples(seed: int, vertex: int, n: int, *, stratified: bool = True) -> FloatArray:
    """(n, 2) float64 points in [0, 1)^2 used for ``vertex`` under ``seed``.

    ``stratified``: Owen-scrambled Sobol (every power-of-two prefix is a (0, m, 2)-net);
    else independent uniform numbers from the same counter-based hash.
    """
    return _rng.sample_points(np.uint64(seed), np.uint64(vertex), int(n), bool(stratified))


def sample_directions(
    normals: FloatArray,
    n_rays: int,
    *,
    seed: int = 0,
    measure: str = "cosine",
    stratified: bool = True,
    vertices=None,
    start: int = 0,
) -> np.ndarray:
    """The world-space ray directions ``embree_ao`` casts, bit for bit.

    Parameters
    ----------
    normals : (n, 3) float64
        Unit vertex normals (zero rows sample the whole sphere).
    n_rays : int
        Directions per vertex, sample indices ``start .. start + n_rays - 1``.
    seed : int
    measure : {"cosine", "uniform"}
    stratified : bool
    vertices : (k,) int, optional
        Which vertices (default: all). Their keys depend on their index in ``normals``.

    Returns
    -------
    directions : (k, n_rays, 3) float32
    """
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    n = normals.shape[0]
    vertex_index = (
        np.arange(n, dtype=np.int64) if vertices is None else np.asarray(vertices, dtype=np.int64)
    )
    keys = _k.vertex_keys(np.uint64(seed), n)
    k = vertex_index.size * n_rays
    org = np.zeros((k, 3), dtype=np.float32)
    dirs = np.zeros((k, 3), dtype=np.float32)
    origins = np.zeros((n, 3), dtype=np.float32)
    mode = MEASURE_CODES[measure] + (0 if stratified else 2)
    _k.generate_rays(
        origins, normals, keys, vertex_index, int(start), int(start + n_rays), mode, org, dirs
    )
    return dirs.reshape(vertex_index.size, n_rays, 3)
