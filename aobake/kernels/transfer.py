"""Compiled disk-to-disk radiance transfer of the disk method's indirect light (the brute-force
O(n k) gather; the tree comes later).

Imports numpy, numba and ``aobake.constants`` only. Symbols as in ``aobake.kernels.bunnell``:
receiver ``i`` at point ``p`` with unit normal ``n``; emitting disk ``j`` at centre ``c``
with unit normal ``m``, area ``A`` and outgoing radiance ``L`` (RGB); ``d = c - p``,
``r = |d|``, ``cos_e = -m.d / r``, ``cos_r = n.d / r``.
"""

from __future__ import annotations

import math

from numba import njit, prange

from aobake.constants import COINCIDENT_REL


@njit(cache=True, parallel=True)
def gather(points, normals, centres, disk_normals, areas, radiance, own, reach2, out):
    """``out[i] = sum_j pi L_j A_j cos_e cos_r / (pi r^2 + A_j)`` over every disk j.

    ``pi L A cos_e cos_r / (pi r^2 + A)`` is the irradiance a Lambertian disk of radiance
    ``L`` gives a point on its axis exactly (``pi L R^2 / (R^2 + h^2)``). Skipped: a disk
    seen from behind (``cos_e <= 0``) or behind the receiver's tangent plane
    (``cos_r <= 0``), the receiver's own disk (``own[j] == i``), coincident disks
    (``r^2 <= COINCIDENT_REL A``); a receiver with a zero normal gets 0. Each receiver sums
    its disks in index order (same result for any thread count).

    Parameters
    ----------
    points, normals : (n, 3) float64
    centres, disk_normals : (k, 3) float64
    areas : (k,) float64
    radiance : (k, 3) float64
    own : (k,) int64
        The receiver each disk belongs to (-1: none).
    reach2 : float
        Disks farther than ``sqrt(reach2)`` are skipped (a max distance, squared; inf: none).
    out : (n, 3) float64
        Overwritten.
    """
    n = points.shape[0]
    k = centres.shape[0]
    for i in prange(n):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        if nx != 0.0 or ny != 0.0 or nz != 0.0:
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            for j in range(k):
                if own[j] == i:
                    continue
                dx = centres[j, 0] - px
                dy = centres[j, 1] - py
                dz = centres[j, 2] - pz
                r2 = dx * dx + dy * dy + dz * dz
                a = areas[j]
                if r2 <= COINCIDENT_REL * a or r2 > reach2:
                    continue
                cr = nx * dx + ny * dy + nz * dz
                if cr <= 0.0:
                    continue
                ce = -(disk_normals[j, 0] * dx + disk_normals[j, 1] * dy + disk_normals[j, 2] * dz)
                if ce <= 0.0:
                    continue
                # cos_e cos_r = ce cr / r^2
                f = math.pi * a * ce * cr / (r2 * (math.pi * r2 + a))
                s0 += f * radiance[j, 0]
                s1 += f * radiance[j, 1]
                s2 += f * radiance[j, 2]
        out[i, 0] = s0
        out[i, 1] = s1
        out[i, 2] = s2
