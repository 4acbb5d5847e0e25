"""Compiled shadow pass of the disk method's emitted light, aimed at the lights: a vertex
disk blocks a light patch's radiance where the two overlap as seen from the receiver,
each patch at most once (brute force over all receiver, occluder and patch triples).

Imports numpy, numba and ``aobake.constants`` only. Receiver ``i`` at ``p`` with unit
normal ``n``; occluding disk ``j`` at ``c`` with unit normal ``m`` and area ``A``; a light
patch ``q`` (a small emitting disk) at ``x`` with unit normal ``l``, area ``A_q``,
radiance ``L``. Each disk, seen from ``p``, is taken as a spherical cap of the solid angle
of a disk facing ``p`` with its projected area; two caps overlap as two circles do.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from aobake.constants import COINCIDENT_REL

# Columns of an occluder's row: centre, unit normal, area.
O_C, O_M, O_A, O_SIZE = 0, 3, 6, 7
# Columns of a light patch's row: centre, unit emitting normal, area, radiance, group.
Q_C, Q_M, Q_A, Q_L, Q_GROUP, Q_SIZE = 0, 3, 6, 7, 10, 11


@njit(cache=True, error_model="numpy", inline="always")
def _cap(dist2, projected):
    """(solid angle, angular radius) of a disk of ``projected`` area facing a point at
    squared distance ``dist2``: 2 pi (1 - r / sqrt(r^2 + a / pi))."""
    cos_a = math.sqrt(dist2 / (dist2 + projected / math.pi))
    return 2.0 * math.pi * (1.0 - cos_a), math.acos(min(1.0, cos_a))


@njit(cache=True, error_model="numpy", inline="always")
def _overlap(a, b, beta):
    """Fraction of the smaller of two circles (radii a, b, centres beta apart) that the
    other covers."""
    if beta >= a + b:
        return 0.0
    small = min(a, b)
    if beta <= abs(a - b) or small <= 0.0:
        return 1.0
    ca = min(1.0, max(-1.0, (beta * beta + a * a - b * b) / (2.0 * beta * a)))
    cb = min(1.0, max(-1.0, (beta * beta + b * b - a * a) / (2.0 * beta * b)))
    k = max(0.0, (-beta + a + b) * (beta + a - b) * (beta - a + b) * (beta + a + b))
    area = a * a * math.acos(ca) + b * b * math.acos(cb) - 0.5 * math.sqrt(k)
    return min(1.0, max(0.0, area / (math.pi * small * small)))


@njit(cache=True, error_model="numpy", parallel=True)
def aimed_shadow(points, normals, occ, own, vis, patches, reach2, out):
    """``out[i, g]``: the fraction of group g's light that the occluders block at receiver
    i, ``sum_q W_q c_q min(1, C_q) / sum_q W_q c_q`` over the group's patches q facing
    the receiver (``W_q`` their caps' solid angle, ``c_q`` cos_r times the patch's summed
    radiance), with ``C_q = sum_j min(W_j, W_q) overlap_jq vis[j, side, g] / W_q`` the
    share of patch q the occluders nearer than it cover: layers over one patch count
    once (per-direction saturation, a patch being a direction). ``overlap`` is the
    fraction of the smaller cap the other covers; side 0 (front) where j's normal points
    away from the receiver (the side the light falls on), else 1.

    Parameters
    ----------
    points, normals : (n, 3) float64
    occ : (k, O_SIZE) float64
    own : (k,) int64
        The receiver each occluder belongs to (skipped for it).
    vis : (k, 2, G) float64
        The fraction of group g's light reaching each side of each occluder.
    patches : (P, Q_SIZE) float64
    reach2 : float
        Occluders whose centre is farther than ``sqrt(reach2)`` block nothing (a max
        distance, squared; inf: none).
    out : (n, G) float64
        Overwritten.
    """
    n = points.shape[0]
    k = occ.shape[0]
    n_patches = patches.shape[0]
    n_groups = out.shape[1]
    for i in prange(n):
        for g in range(n_groups):
            out[i, g] = 0.0
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            continue
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        # each patch seen from the receiver: unit direction, distance^2, cap, weight
        ux_q = np.empty(n_patches)
        uy_q = np.empty(n_patches)
        uz_q = np.empty(n_patches)
        d2_q = np.empty(n_patches)
        w_q = np.zeros(n_patches)
        a_q = np.zeros(n_patches)
        c_q = np.zeros(n_patches)
        cover = np.zeros(n_patches)
        for q in range(n_patches):
            tx, ty, tz = patches[q, Q_C] - px, patches[q, Q_C + 1] - py, patches[q, Q_C + 2] - pz
            d2 = tx * tx + ty * ty + tz * tz
            d = math.sqrt(d2)
            d2_q[q] = d2
            if not d > 0.0:
                continue
            tx, ty, tz = tx / d, ty / d, tz / d
            ux_q[q], uy_q[q], uz_q[q] = tx, ty, tz
            cq = -(patches[q, Q_M] * tx + patches[q, Q_M + 1] * ty + patches[q, Q_M + 2] * tz)
            cos_r = nx * tx + ny * ty + nz * tz
            if cq <= 0.0 or cos_r <= 0.0:
                continue
            w_q[q], a_q[q] = _cap(d2, patches[q, Q_A] * cq)
            c_q[q] = cos_r * (patches[q, Q_L] + patches[q, Q_L + 1] + patches[q, Q_L + 2])
        # the cone holding every patch seen, and the farthest one: occluders outside skip
        ax, ay, az, far2 = 0.0, 0.0, 0.0, 0.0
        for q in range(n_patches):
            if w_q[q] > 0.0:
                ax += ux_q[q]
                ay += uy_q[q]
                az += uz_q[q]
                far2 = max(far2, d2_q[q])
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        if not norm > 0.0:
            continue
        ax, ay, az = ax / norm, ay / norm, az / norm
        spread = 0.0
        for q in range(n_patches):
            if w_q[q] > 0.0:
                cos_q = min(1.0, max(-1.0, ax * ux_q[q] + ay * uy_q[q] + az * uz_q[q]))
                spread = max(spread, math.acos(cos_q) + a_q[q])
        for j in range(k):
            if own[j] == i:
                continue
            dx, dy, dz = occ[j, O_C] - px, occ[j, O_C + 1] - py, occ[j, O_C + 2] - pz
            r2 = dx * dx + dy * dy + dz * dz
            a = occ[j, O_A]
            if r2 <= COINCIDENT_REL * a:
                continue
            if nx * dx + ny * dy + nz * dz <= 0.0:
                continue
            if r2 >= far2 or r2 > reach2:
                continue
            r = math.sqrt(r2)
            ux, uy, uz = dx / r, dy / r, dz / r
            md = occ[j, O_M] * ux + occ[j, O_M + 1] * uy + occ[j, O_M + 2] * uz
            side = 0 if md > 0.0 else 1
            w_j, a_j = _cap(r2, a * abs(md))
            if math.acos(min(1.0, max(-1.0, ax * ux + ay * uy + az * uz))) >= spread + a_j:
                continue
            for q in range(n_patches):
                if w_q[q] <= 0.0 or d2_q[q] <= r2:
                    continue
                cos_b = ux * ux_q[q] + uy * uy_q[q] + uz * uz_q[q]
                if cos_b <= 0.0:
                    continue
                f = _overlap(a_j, a_q[q], math.acos(min(1.0, cos_b)))
                if f > 0.0:
                    cover[q] += min(w_j, w_q[q]) * f * vis[j, side, int(patches[q, Q_GROUP])] / w_q[q]
        for g in range(n_groups):
            total = 0.0
            blocked = 0.0
            for q in range(n_patches):
                if int(patches[q, Q_GROUP]) != g or w_q[q] <= 0.0:
                    continue
                total += w_q[q] * c_q[q]
                blocked += w_q[q] * c_q[q] * min(1.0, cover[q])
            out[i, g] = blocked / total if total > 0.0 else 0.0
