"""Rays of the AO field's Embree sampler: uniform over the sphere from points spread over
texel footprints, and the per-point sums of their hits.

Imports numpy, numba and other kernels only.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import rng, warps


@njit(cache=True, error_model="numpy", nogil=True)
def footprint_rays(geometry, keys, point_index, per, out_org, out_dir):
    """Fill ``per`` rays of every point in ``point_index``, point-major.

    ``geometry`` = (anchors (n, 3), tangents (n, 6), radii (n,), shift (3,)): ray j of
    point p starts at shift + radii[p] * unit(anchors[p] + (s0 - 1/2) t_u + (s1 - 1/2) t_v)
    with (t_u, t_v) = tangents[p] and (s0, s1) an Owen-scrambled Sobol point (a box
    prefilter over the texel footprint; zero tangents give a fixed point), and goes in a
    uniform direction on the sphere from a second, independently scrambled Sobol
    sequence. keys (n,) uint64; out_org / out_dir (k * per, 3) float32, written in full.
    """
    anchors, tangents, radii, shift = geometry
    for a in range(point_index.shape[0]):
        p = point_index[a]
        key = keys[p]
        key2 = rng.hash2(key, np.uint64(0x5EED))
        for j in range(per):
            u0, u1 = rng.scrambled_sobol2(j, key)
            dx, dy, dz = warps.square_to_uniform_sphere(u0, u1)
            s0, s1 = rng.scrambled_sobol2(j, key2)
            s0 -= 0.5
            s1 -= 0.5
            qx = anchors[p, 0] + s0 * tangents[p, 0] + s1 * tangents[p, 3]
            qy = anchors[p, 1] + s0 * tangents[p, 1] + s1 * tangents[p, 4]
            qz = anchors[p, 2] + s0 * tangents[p, 2] + s1 * tangents[p, 5]
            length = math.sqrt(qx * qx + qy * qy + qz * qz)
            scale = radii[p] / length if length > 0.0 else 0.0
            r = a * per + j
            out_org[r, 0] = shift[0] + scale * qx
            out_org[r, 1] = shift[1] + scale * qy
            out_org[r, 2] = shift[2] + scale * qz
            out_dir[r, 0] = dx
            out_dir[r, 1] = dy
            out_dir[r, 2] = dz


@njit(cache=True, nogil=True)
def accumulate_hits(ids, dirs, per, point_index, out):
    """out[p] += (hits, sum of hit directions) over the ``per`` rays of each point.

    Each point appears once per call with all its rays, summed in ray order, so the
    result does not depend on how points are split into chunks or threads.
    """
    for a in range(point_index.shape[0]):
        p = point_index[a]
        h = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for j in range(per):
            r = a * per + j
            if ids[r] != -1:
                h += 1.0
                sx += dirs[r, 0]
                sy += dirs[r, 1]
                sz += dirs[r, 2]
        out[p, 0] += h
        out[p, 1] += sx
        out[p, 2] += sy
        out[p, 3] += sz
