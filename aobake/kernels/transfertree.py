"""Compiled disk-to-disk radiance transfer through the cluster tree: far clusters as one
emitter carrying summed RGB power, near pairs exact per disk (the brute-force sum is
``aobake.kernels.transfer.gather``).

Imports numpy, numba and ``aobake.constants`` only. Symbols as in
``aobake.kernels.transfer``: receiver ``i`` at ``p`` with unit normal ``n``; disk ``j`` at
``c`` with unit normal ``m``, area ``A``, radiance ``L`` (RGB). The tree is
``aobake.kernels.hierarchy``'s (preorder, skip pointers, emitters in tree order).

Per node ``q`` two float64 tables: the geometry (fixed while the disks do not move) and
the light (recomputed from the radiance on every call):

- geometry: G_X..G_Z area-weighted centre, G_OPEN_D2 squared distance beyond which the node
  is used whole, G_TXX..G_TYZ ``kappa^2 T / A`` with ``T = sum A m m^T`` (so
  ``sqrt(u^T (kappa^2 T / A) u)`` estimates the mean ``|m.u|`` of the node's disks);
- light: L_P + c the power ``P_c = sum A L_c`` of channel c, L_W + 3 c the vector
  ``W_c = sum A L_c m``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import COINCIDENT_REL

from .hierarchy import spread_factor

G_X, G_Y, G_Z, G_OPEN_D2 = 0, 1, 2, 3
G_TXX, G_TYY, G_TZZ, G_TXY, G_TXZ, G_TYZ = 4, 5, 6, 7, 8, 9
GEOMETRY_COLS = 10
L_P = 0
L_W = 3
LIGHT_COLS = 12


@njit(cache=True, error_model="numpy")
def node_spread(normals, areas, skip, start, stop, geometry):
    """Write G_TXX..G_TYZ of every node: ``kappa^2 T / A`` (``hierarchy.spread_factor``),
    bottom-up in reverse preorder, float64.

    Parameters
    ----------
    normals : (k, 3) float64
        Unit disk normals in tree order.
    areas : (k,) float64
        Disk areas in tree order (> 0).
    skip, start, stop : (m,) int64
    geometry : (m, GEOMETRY_COLS) float64
    """
    m = skip.shape[0]
    mom = np.zeros((m, 7))
    for q in range(m - 1, -1, -1):
        if skip[q] == q + 1:
            for t in range(start[q], stop[q]):
                a = areas[t]
                mx = normals[t, 0]
                my = normals[t, 1]
                mz = normals[t, 2]
                mom[q, 0] += a
                mom[q, 1] += a * mx * mx
                mom[q, 2] += a * my * my
                mom[q, 3] += a * mz * mz
                mom[q, 4] += a * mx * my
                mom[q, 5] += a * mx * mz
                mom[q, 6] += a * my * mz
        else:
            left = q + 1
            right = skip[left]
            for c in range(7):
                mom[q, c] = mom[left, c] + mom[right, c]
    for q in range(m):
        a = mom[q, 0]
        kappa = spread_factor(a, mom[q, 1], mom[q, 2], mom[q, 3], mom[q, 4], mom[q, 5], mom[q, 6])
        f = kappa * kappa / a
        for c in range(6):
            geometry[q, G_TXX + c] = f * mom[q, 1 + c]


@njit(cache=True, error_model="numpy")
def node_light(normals, areas, radiance, skip, start, stop, light):
    """Every node's light table from the disks' radiance: ``P_c = sum A L_c``,
    ``W_c = sum A L_c m``, bottom-up in reverse preorder (O(k + m)), float64.

    Parameters
    ----------
    normals : (k, 3) float64
    areas : (k,) float64
    radiance : (k, 3) float64
        All in tree order.
    skip, start, stop : (m,) int64
    light : (m, LIGHT_COLS) float64
        Overwritten.
    """
    m = skip.shape[0]
    for q in range(m - 1, -1, -1):
        if skip[q] == q + 1:
            for c in range(LIGHT_COLS):
                light[q, c] = 0.0
            for t in range(start[q], stop[q]):
                for ch in range(3):
                    p = areas[t] * radiance[t, ch]
                    light[q, L_P + ch] += p
                    light[q, L_W + 3 * ch] += p * normals[t, 0]
                    light[q, L_W + 3 * ch + 1] += p * normals[t, 1]
                    light[q, L_W + 3 * ch + 2] += p * normals[t, 2]
        else:
            left = q + 1
            right = skip[left]
            for c in range(LIGHT_COLS):
                light[q, c] = light[left, c] + light[right, c]


@njit(cache=True, error_model="numpy", inline="always")
def far_power(geometry, light, q, ux, uy, uz, ch):
    """Power of node q's disks toward unit direction u (node - receiver), channel ch:
    ``max((P a + s) / 2, s, 0)`` with ``s = -W.u`` and ``a = sqrt(u^T (kappa^2 T / A) u)``
    (``sum A L max(-m.u, 0) = (sum A L |m.u| + s) / 2`` with the mean ``|m.u|`` estimated
    by a; exact for a flat node and for uniform radiance on a flat node, as the AO's far
    term)."""
    s = -(light[q, L_W + 3 * ch] * ux + light[q, L_W + 3 * ch + 1] * uy + light[q, L_W + 3 * ch + 2] * uz)
    quad = (
        geometry[q, G_TXX] * ux * ux
        + geometry[q, G_TYY] * uy * uy
        + geometry[q, G_TZZ] * uz * uz
        + 2.0 * (geometry[q, G_TXY] * ux * uy + geometry[q, G_TXZ] * ux * uz + geometry[q, G_TYZ] * uy * uz)
    )
    a = np.sqrt(max(quad, 0.0))
    return max(0.5 * (light[q, L_P + ch] * a + s), s, 0.0)


@njit(cache=True, error_model="numpy", parallel=True)
def gather_tree(points, normals, recv_order, bucket_start, n_chunks, skip, start, stop, geometry,
                light, e_pos, e_nrm, e_area, e_rad, e_own, out):
    """``out[i]``: the irradiance of :func:`aobake.kernels.transfer.gather` at every receiver,
    through the tree.

    Receivers walk the tree by buckets (``recv_order[bucket_start[b]:bucket_start[b + 1]]``,
    compact groups): a node whose light is zero is skipped; a node is used whole when the
    bucket's bounding sphere is farther than ``sqrt(G_OPEN_D2)`` from its centre (term
    ``F cos_r / d^2`` with F from :func:`far_power`: the disk term ``pi L A cos_e cos_r /
    (pi r^2 + A)`` of many disks without the near-field regularisation); a leaf that is
    not far gives its disks' exact terms (skips as ``gather``: own disk ``e_own[t] == i``,
    coincident, either side facing away). Each receiver sums its bucket's far nodes then
    its near disks in tree order, so the result does not depend on the thread count;
    ``n_chunks`` (fixed by the caller) groups buckets cyclically for the threads.

    Parameters
    ----------
    points, normals : (n, 3) float64
    recv_order : (n,) int64
    bucket_start : (nb + 1,) int64
    n_chunks : int >= 1
    skip, start, stop : (m,) int64
    geometry : (m, GEOMETRY_COLS) float64
    light : (m, LIGHT_COLS) float64
    e_pos, e_nrm : (k, 3) float64
    e_area : (k,) float64
    e_rad : (k, 3) float64
    e_own : (k,) int64
        Vertex of each disk; all in tree order.
    out : (n, 3) float64
        Overwritten.
    """
    m = skip.shape[0]
    nb = bucket_start.shape[0] - 1
    for chunk in prange(n_chunks):
        far = np.empty(m, dtype=np.int64)
        near = np.empty(m, dtype=np.int64)
        for b in range(chunk, nb, n_chunks):
            lo = bucket_start[b]
            hi = bucket_start[b + 1]
            bx = 0.0
            by = 0.0
            bz = 0.0
            for s in range(lo, hi):
                i = recv_order[s]
                bx += points[i, 0]
                by += points[i, 1]
                bz += points[i, 2]
            bx /= hi - lo
            by /= hi - lo
            bz /= hi - lo
            rb = 0.0
            for s in range(lo, hi):
                i = recv_order[s]
                rb = max(rb, np.sqrt((points[i, 0] - bx) ** 2 + (points[i, 1] - by) ** 2 + (points[i, 2] - bz) ** 2))
            rb = rb * (1.0 + 1e-12) + 1e-12  # rounding: every receiver inside the sphere
            n_far = 0
            n_near = 0
            node = 0
            while node < m:
                nxt = skip[node]
                if light[node, L_P] <= 0.0 and light[node, L_P + 1] <= 0.0 and light[node, L_P + 2] <= 0.0:
                    node = nxt
                    continue
                dx = geometry[node, G_X] - bx
                dy = geometry[node, G_Y] - by
                dz = geometry[node, G_Z] - bz
                dmin = np.sqrt(dx * dx + dy * dy + dz * dz) - rb
                if dmin > 0.0 and dmin * dmin >= geometry[node, G_OPEN_D2]:
                    far[n_far] = node
                    n_far += 1
                    node = nxt
                elif nxt == node + 1:
                    near[n_near] = node
                    n_near += 1
                    node = nxt
                else:
                    node += 1
            for s in range(lo, hi):
                i = recv_order[s]
                nx = normals[i, 0]
                ny = normals[i, 1]
                nz = normals[i, 2]
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                if nx != 0.0 or ny != 0.0 or nz != 0.0:
                    px = points[i, 0]
                    py = points[i, 1]
                    pz = points[i, 2]
                    for f in range(n_far):
                        q = far[f]
                        dx = geometry[q, G_X] - px
                        dy = geometry[q, G_Y] - py
                        dz = geometry[q, G_Z] - pz
                        nd = nx * dx + ny * dy + nz * dz
                        if nd <= 0.0:
                            continue
                        d2 = dx * dx + dy * dy + dz * dz
                        inv = 1.0 / np.sqrt(d2)
                        ux = dx * inv
                        uy = dy * inv
                        uz = dz * inv
                        g = nd * inv / d2  # cos_r / d^2
                        s0 += g * far_power(geometry, light, q, ux, uy, uz, 0)
                        s1 += g * far_power(geometry, light, q, ux, uy, uz, 1)
                        s2 += g * far_power(geometry, light, q, ux, uy, uz, 2)
                    for f in range(n_near):
                        q = near[f]
                        for t in range(start[q], stop[q]):
                            if e_own[t] == i:
                                continue
                            dx = e_pos[t, 0] - px
                            dy = e_pos[t, 1] - py
                            dz = e_pos[t, 2] - pz
                            r2 = dx * dx + dy * dy + dz * dz
                            a = e_area[t]
                            if r2 <= COINCIDENT_REL * a:
                                continue
                            cr = nx * dx + ny * dy + nz * dz
                            if cr <= 0.0:
                                continue
                            ce = -(e_nrm[t, 0] * dx + e_nrm[t, 1] * dy + e_nrm[t, 2] * dz)
                            if ce <= 0.0:
                                continue
                            w = np.pi * a * ce * cr / (r2 * (np.pi * r2 + a))
                            s0 += w * e_rad[t, 0]
                            s1 += w * e_rad[t, 1]
                            s2 += w * e_rad[t, 2]
                out[i, 0] = s0
                out[i, 1] = s1
                out[i, 2] = s2
