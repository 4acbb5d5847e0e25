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

from aobake.constants import COINCIDENT_REL, FASTMATH

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


# Rows of a bucket's list buffers (float64, one row per quantity so each receiver's sums
# are contiguous, branch-free loops that LLVM vectorises): near disks (centre, normal,
# area, radiance; the disk's vertex in a separate int64 array) and far nodes (centre,
# power, W per channel, kappa^2 T / A).
B_X, B_Y, B_Z, B_MX, B_MY, B_MZ, B_A, B_L = 0, 1, 2, 3, 4, 5, 6, 7
NEAR_ROWS = 10
F_X, F_Y, F_Z, F_P, F_W, F_T = 0, 1, 2, 3, 6, 15
FAR_ROWS = 21


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def near_sums(buf, own, n_near, i, px, py, pz, nx, ny, nz):
    """RGB sums of the exact disk terms of ``buf[:, :n_near]`` at receiver i (as
    ``transfer.gather``: nothing from its own disk, coincident disks or either side
    facing away)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for t in range(n_near):
        dx = buf[B_X, t] - px
        dy = buf[B_Y, t] - py
        dz = buf[B_Z, t] - pz
        r2 = dx * dx + dy * dy + dz * dz
        a = buf[B_A, t]
        cr = max(nx * dx + ny * dy + nz * dz, 0.0)
        ce = max(-(buf[B_MX, t] * dx + buf[B_MY, t] * dy + buf[B_MZ, t] * dz), 0.0)
        w = np.pi * a * ce * cr / (r2 * (np.pi * r2 + a))
        w = w if (r2 > COINCIDENT_REL * a and own[t] != i) else 0.0
        s0 += w * buf[B_L, t]
        s1 += w * buf[B_L + 1, t]
        s2 += w * buf[B_L + 2, t]
    return s0, s1, s2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_sums(buf, n_far, px, py, pz, nx, ny, nz):
    """RGB sums of the far nodes ``buf[:, :n_far]`` at a receiver: ``F cos_r / d^2`` with
    F the node's power toward the receiver, ``max((P a + s) / 2, s, 0)``, ``s = -W.u``,
    ``a = sqrt(u^T (kappa^2 T / A) u)`` (the mean ``|m.u|``; exact for a flat node, as the
    AO's far term)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for t in range(n_far):
        dx = buf[F_X, t] - px
        dy = buf[F_Y, t] - py
        dz = buf[F_Z, t] - pz
        d2 = dx * dx + dy * dy + dz * dz
        inv = 1.0 / np.sqrt(d2)
        ux = dx * inv
        uy = dy * inv
        uz = dz * inv
        g = max(nx * ux + ny * uy + nz * uz, 0.0) / d2
        quad = (
            buf[F_T, t] * ux * ux
            + buf[F_T + 1, t] * uy * uy
            + buf[F_T + 2, t] * uz * uz
            + 2.0 * (buf[F_T + 3, t] * ux * uy + buf[F_T + 4, t] * ux * uz + buf[F_T + 5, t] * uy * uz)
        )
        a = np.sqrt(max(quad, 0.0))
        p0 = -(buf[F_W, t] * ux + buf[F_W + 1, t] * uy + buf[F_W + 2, t] * uz)
        p1 = -(buf[F_W + 3, t] * ux + buf[F_W + 4, t] * uy + buf[F_W + 5, t] * uz)
        p2 = -(buf[F_W + 6, t] * ux + buf[F_W + 7, t] * uy + buf[F_W + 8, t] * uz)
        s0 += g * max(0.5 * (buf[F_P, t] * a + p0), p0, 0.0)
        s1 += g * max(0.5 * (buf[F_P + 1, t] * a + p1), p1, 0.0)
        s2 += g * max(0.5 * (buf[F_P + 2, t] * a + p2), p2, 0.0)
    return s0, s1, s2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def gather_tree(points, normals, recv_order, bucket_start, n_chunks, skip, start, stop, geometry,
                light, e_pos, e_nrm, e_area, e_rad, e_own, out):
    """``out[i]``: the irradiance of :func:`aobake.kernels.transfer.gather` at every receiver,
    through the tree.

    Receivers walk the tree by buckets (``recv_order[bucket_start[b]:bucket_start[b + 1]]``,
    compact groups): a node whose light is zero is skipped; a node is used whole when the
    bucket's bounding sphere is farther than ``sqrt(G_OPEN_D2)`` from its centre
    (:func:`far_sums`: the disk term ``pi L A cos_e cos_r / (pi r^2 + A)`` summed over its
    disks, without the near-field regularisation); a leaf that is not far lists its lit
    disks for their exact terms (:func:`near_sums`). Each receiver sums its bucket's lists
    in a fixed order and the machine code is the same for any thread count, so the result
    does not depend on it; ``n_chunks`` (fixed by the caller) deals buckets cyclically to
    the threads. fastmath (aobake.constants.FASTMATH): the sums vectorise, so the terms
    add in another order than the brute-force sum (rounding differences only).

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
    k = e_own.shape[0]
    nb = bucket_start.shape[0] - 1
    for chunk in prange(n_chunks):
        near_buf = np.empty((NEAR_ROWS, k))
        near_own = np.empty(k, dtype=np.int64)
        far_buf = np.empty((FAR_ROWS, m))
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
                    for c in range(3):
                        far_buf[F_X + c, n_far] = geometry[node, G_X + c]
                    for c in range(LIGHT_COLS):
                        far_buf[F_P + c, n_far] = light[node, c]
                    for c in range(6):
                        far_buf[F_T + c, n_far] = geometry[node, G_TXX + c]
                    n_far += 1
                    node = nxt
                elif nxt == node + 1:
                    for t in range(start[node], stop[node]):
                        if e_rad[t, 0] <= 0.0 and e_rad[t, 1] <= 0.0 and e_rad[t, 2] <= 0.0:
                            continue  # a dark disk adds nothing
                        for c in range(3):
                            near_buf[B_X + c, n_near] = e_pos[t, c]
                            near_buf[B_MX + c, n_near] = e_nrm[t, c]
                            near_buf[B_L + c, n_near] = e_rad[t, c]
                        near_buf[B_A, n_near] = e_area[t]
                        near_own[n_near] = e_own[t]
                        n_near += 1
                    node = nxt
                else:
                    node += 1
            for s in range(lo, hi):
                i = recv_order[s]
                nx = normals[i, 0]
                ny = normals[i, 1]
                nz = normals[i, 2]
                if nx == 0.0 and ny == 0.0 and nz == 0.0:
                    out[i, 0] = 0.0
                    out[i, 1] = 0.0
                    out[i, 2] = 0.0
                    continue
                px = points[i, 0]
                py = points[i, 1]
                pz = points[i, 2]
                f0, f1, f2 = far_sums(far_buf, n_far, px, py, pz, nx, ny, nz)
                n0, n1, n2 = near_sums(near_buf, near_own, n_near, i, px, py, pz, nx, ny, nz)
                out[i, 0] = f0 + n0
                out[i, 1] = f1 + n1
                out[i, 2] = f2 + n2
