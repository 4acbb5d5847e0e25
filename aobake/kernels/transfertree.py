"""Compiled disk-to-disk radiance transfer through the cluster tree: far clusters as one
emitter carrying summed RGB power, near pairs exact per disk, disks in a receiver's near
field replaced by their cells' exact form factor (the brute-force sum is
``aobake.kernels.transfer.gather``).

Imports numpy, numba, ``aobake.constants`` and other kernels only. numba caches each
kernel by its own file's time stamp: after changing the inlined ``treewalk.behind``,
``hierarchy.spread_factor`` or ``polygon.cell_terms``, touch this file. Symbols as in
``aobake.kernels.transfer``: receiver ``i`` at ``p`` with unit normal ``n``; disk ``j`` at
``c`` with unit normal ``m``, area ``A``, radiance ``L`` (RGB). The tree is
``aobake.kernels.hierarchy``'s (preorder, skip pointers, emitters in tree order).

Per node ``q`` two float64 tables: the geometry (fixed while the disks do not move) and
the light (recomputed from the radiance on every call):

- geometry: G_X..G_Z area-weighted centre, G_OPEN_D2 squared distance beyond which the node
  is used whole;
- light: L_P + c the power ``P_c = sum A L_c`` of channel c, L_W + 3 c the vector
  ``W_c = sum A L_c m``, L_T..L_T + 5 ``kappa^2 T / Y`` with ``T = sum A Y m m^T``,
  ``Y = L_0 + L_1 + L_2`` and ``Y`` summed likewise (so ``sqrt(u^T (kappa^2 T / Y) u)``
  estimates the power-weighted mean ``|m.u|`` of the node's disks; kappa:
  ``hierarchy.spread_factor``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import COINCIDENT_REL, FASTMATH, MEASURE_COSINE, NEAR_PLANE_REL

from .hierarchy import spread_factor
from .polygon import cell_terms, clipped_quad, triangle_cross
from .treewalk import B_RADIUS, behind
from .treewalk import B_X as B_CX
from .treewalk import B_Y as B_CY
from .treewalk import B_Z as B_CZ

G_X, G_Y, G_Z, G_OPEN_D2 = 0, 1, 2, 3
GEOMETRY_COLS = 4
L_P = 0
L_W = 3
L_T = 12
LIGHT_COLS = 18

# Slack of the bucket-level test that a disk faces away from every receiver (relative to
# the distances involved, normalised units): far above float64 rounding.
FACING_SLACK = 1e-9

ZERO32 = np.float32(0.0)
HALF32 = np.float32(0.5)
ONE32 = np.float32(1.0)
TWO32 = np.float32(2.0)
PI32 = np.float32(np.pi)
COINCIDENT32 = np.float32(COINCIDENT_REL)


@njit(cache=True, error_model="numpy")
def node_light(normals, areas, radiance, skip, start, stop, light):
    """Every node's light table from the disks' radiance (the module's L_* columns),
    bottom-up in reverse preorder (O(k + m)), float64.

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
                mx = normals[t, 0]
                my = normals[t, 1]
                mz = normals[t, 2]
                for ch in range(3):
                    p = areas[t] * radiance[t, ch]
                    light[q, L_P + ch] += p
                    light[q, L_W + 3 * ch] += p * mx
                    light[q, L_W + 3 * ch + 1] += p * my
                    light[q, L_W + 3 * ch + 2] += p * mz
                y = areas[t] * (radiance[t, 0] + radiance[t, 1] + radiance[t, 2])
                light[q, L_T] += y * mx * mx
                light[q, L_T + 1] += y * my * my
                light[q, L_T + 2] += y * mz * mz
                light[q, L_T + 3] += y * mx * my
                light[q, L_T + 4] += y * mx * mz
                light[q, L_T + 5] += y * my * mz
        else:
            left = q + 1
            right = skip[left]
            for c in range(LIGHT_COLS):
                light[q, c] = light[left, c] + light[right, c]
    for q in range(m):
        y = light[q, L_P] + light[q, L_P + 1] + light[q, L_P + 2]
        if y > 0.0:
            kappa = spread_factor(y, light[q, L_T], light[q, L_T + 1], light[q, L_T + 2], light[q, L_T + 3],
                                  light[q, L_T + 4], light[q, L_T + 5])
            f = kappa * kappa / y
            for c in range(6):
                light[q, L_T + c] *= f



# Rows of a bucket's list buffers (float32, one row per quantity so each receiver's sums
# are contiguous, branch-free loops that LLVM vectorises, 1.65x faster than float64):
# near disks (centre, normal, area, radiance, keep: 1, or 0 while the receiver whose own
# disk or near-field cell it is sums the list) and far nodes (centre, the node's light row). Centres are stored relative to
# the bucket's centre (subtracted in float64), so float32 keeps their small differences.
B_X, B_Y, B_Z, B_MX, B_MY, B_MZ, B_A, B_L, B_KEEP = 0, 1, 2, 3, 4, 5, 6, 7, 10
NEAR_ROWS = 11
F_X, F_Y, F_Z, F_P, F_W, F_T = 0, 1, 2, 3, 6, 15
FAR_ROWS = 21

@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def near_sums(buf, n_near, px, py, pz, nx, ny, nz, reach2):
    """RGB sums of the exact disk terms of ``buf[:, :n_near]`` at a receiver (as
    ``transfer.gather``: nothing from coincident disks, disks farther than
    ``sqrt(reach2)`` or either side facing away), each times its B_KEEP row (the caller
    sets 0 for the receiver's own disk and its near-field cells)."""
    s0 = ZERO32
    s1 = ZERO32
    s2 = ZERO32
    for t in range(n_near):
        dx = buf[B_X, t] - px
        dy = buf[B_Y, t] - py
        dz = buf[B_Z, t] - pz
        r2 = dx * dx + dy * dy + dz * dz
        a = buf[B_A, t]
        cr = max(nx * dx + ny * dy + nz * dz, ZERO32)
        ce = max(-(buf[B_MX, t] * dx + buf[B_MY, t] * dy + buf[B_MZ, t] * dz), ZERO32)
        w = PI32 * a * ce * cr / (r2 * (PI32 * r2 + a))
        w = w * buf[B_KEEP, t] if r2 > COINCIDENT32 * a and r2 <= reach2 else ZERO32
        s0 += w * buf[B_L, t]
        s1 += w * buf[B_L + 1, t]
        s2 += w * buf[B_L + 2, t]
    return s0, s1, s2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_sums(buf, n_far, px, py, pz, nx, ny, nz):
    """RGB sums of the far nodes ``buf[:, :n_far]`` at a receiver: ``F cos_r / d^2`` with
    F the node's power toward the receiver, ``max((P a + s) / 2, s, 0)``, ``s = -W.u``,
    ``a = sqrt(u^T (kappa^2 T / Y) u)`` (the mean ``|m.u|``; exact for a flat node, as the
    AO's far term: ``sum w |m.u| <= sqrt(sum w sum w (m.u)^2)``)."""
    s0 = ZERO32
    s1 = ZERO32
    s2 = ZERO32
    for t in range(n_far):
        dx = buf[F_X, t] - px
        dy = buf[F_Y, t] - py
        dz = buf[F_Z, t] - pz
        d2 = dx * dx + dy * dy + dz * dz
        inv = ONE32 / np.sqrt(d2)
        ux = dx * inv
        uy = dy * inv
        uz = dz * inv
        g = max(nx * ux + ny * uy + nz * uz, ZERO32) / d2
        quad = (
            buf[F_T, t] * ux * ux
            + buf[F_T + 1, t] * uy * uy
            + buf[F_T + 2, t] * uz * uz
            + TWO32 * (buf[F_T + 3, t] * ux * uy + buf[F_T + 4, t] * ux * uz + buf[F_T + 5, t] * uy * uz)
        )
        a = np.sqrt(max(quad, ZERO32))
        p0 = -(buf[F_W, t] * ux + buf[F_W + 1, t] * uy + buf[F_W + 2, t] * uz)
        p1 = -(buf[F_W + 3, t] * ux + buf[F_W + 4, t] * uy + buf[F_W + 5, t] * uz)
        p2 = -(buf[F_W + 6, t] * ux + buf[F_W + 7, t] * uy + buf[F_W + 8, t] * uz)
        s0 += g * max(HALF32 * (buf[F_P, t] * a + p0), p0, ZERO32)
        s1 += g * max(HALF32 * (buf[F_P + 1, t] * a + p1), p1, ZERO32)
        s2 += g * max(HALF32 * (buf[F_P + 2, t] * a + p2), p2, ZERO32)
    return s0, s1, s2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def gather_tree(points, normals, recv_order, bucket_start, bounds, n_chunks, skip, start, stop, geometry,
                light, e_pos, e_nrm, e_area, e_rad, own_pos, cell_start, cell_col, cell_val, reach, node_radius, out):
    """``out[i]``: the irradiance of :func:`aobake.kernels.transfer.gather` at every receiver,
    through the tree.

    Receivers walk the tree by buckets (``recv_order[bucket_start[b]:bucket_start[b + 1]]``,
    compact groups): a node whose light is zero is skipped, and so is a far node, or a
    near disk, behind every receiver's tangent plane (``treewalk.behind``) or a near disk
    facing away from the bucket's sphere (all exact: their terms are 0); a node is used
    whole when the bucket's bounding sphere is farther than ``sqrt(G_OPEN_D2)`` from its
    centre
    (:func:`far_sums`: the disk term ``pi L A cos_e cos_r / (pi r^2 + A)`` summed over its
    disks, without the near-field regularisation); a leaf that is not far lists its lit
    disks for their exact terms (:func:`near_sums`). Each receiver sums its bucket's lists
    in a fixed order and the machine code is the same for any thread count, so the result
    does not depend on it; ``n_chunks`` (fixed by the caller) deals buckets cyclically to
    the threads. float32 and fastmath (aobake.constants.FASTMATH): the sums vectorise,
    so with every node opened the result is the brute-force sum to float32 rounding.

    Parameters
    ----------
    points, normals : (n, 3) float64
    recv_order : (n,) int64
    bucket_start : (nb + 1,) int64
    bounds : (nb, treewalk.BOUND_COLS) float64
        Each bucket's bounding sphere and normal cone (``treewalk.bucket_bounds``).
    n_chunks : int >= 1
    skip, start, stop : (m,) int64
    geometry : (m, GEOMETRY_COLS) float64
    light : (m, LIGHT_COLS) float64
    e_pos, e_nrm : (k, 3) float64
    e_area : (k,) float64
    e_rad : (k, 3) float64
        All in tree order.
    own_pos : (n,) int64
        Tree position of each vertex's own disk (-1: none), which does not light it.
    cell_start, cell_col, cell_val
        The near field (:func:`near_cells`): receiver i's disks ``cell_col[cell_start[i]:
        cell_start[i + 1]]`` (tree positions) give ``cell_val`` times their radiance instead
        of their disk term.
    reach : float > 0
        Disks whose centre is farther than ``reach`` from a receiver give it nothing (a
        max distance; inf: none). A node is skipped when all of it is beyond every
        receiver of the bucket, used whole only when all of it is within reach of each.
    node_radius : (m,) float64
        Each node's bounding radius about its centre (read only with a finite ``reach``).
    out : (n, 3) float64
        Overwritten.
    """
    m = skip.shape[0]
    k = e_area.shape[0]
    nb = bucket_start.shape[0] - 1
    capped = reach < np.inf
    reach2 = np.float32(reach * reach) if capped else np.float32(np.inf)
    for chunk in prange(n_chunks):
        near_buf = np.empty((NEAR_ROWS, k), dtype=np.float32)
        near_t = np.empty(k, dtype=np.int64)
        pos_of = np.zeros(k, dtype=np.int64)
        far_buf = np.empty((FAR_ROWS, m), dtype=np.float32)
        for b in range(chunk, nb, n_chunks):
            lo = bucket_start[b]
            hi = bucket_start[b + 1]
            bound = bounds[b]
            bx = bound[B_CX]
            by = bound[B_CY]
            bz = bound[B_CZ]
            rb = bound[B_RADIUS]
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
                dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                dmin = dist - rb
                whole = True
                if capped:
                    if dmin - node_radius[node] > reach:  # all of it beyond every receiver
                        node = nxt
                        continue
                    whole = dist + rb + node_radius[node] <= reach
                if whole and dmin > 0.0 and dmin * dmin >= geometry[node, G_OPEN_D2]:
                    if behind(bound, dx, dy, dz, dist):  # a zero term at every receiver
                        node = nxt
                        continue
                    far_buf[F_X, n_far] = dx
                    far_buf[F_Y, n_far] = dy
                    far_buf[F_Z, n_far] = dz
                    for c in range(LIGHT_COLS):
                        far_buf[F_P + c, n_far] = light[node, c]
                    n_far += 1
                    node = nxt
                elif nxt == node + 1:
                    for t in range(start[node], stop[node]):
                        if e_rad[t, 0] <= 0.0 and e_rad[t, 1] <= 0.0 and e_rad[t, 2] <= 0.0:
                            continue  # a dark disk adds nothing
                        ex = e_pos[t, 0] - bx
                        ey = e_pos[t, 1] - by
                        ez = e_pos[t, 2] - bz
                        e = np.sqrt(ex * ex + ey * ey + ez * ez)
                        if behind(bound, ex, ey, ez, e) or e - rb > reach:
                            continue  # behind every receiver's tangent plane, or beyond its reach
                        if e_nrm[t, 0] * ex + e_nrm[t, 1] * ey + e_nrm[t, 2] * ez > rb + FACING_SLACK * (e + rb + 1.0):
                            continue  # faces away from every receiver of the bucket
                        near_buf[B_X, n_near] = ex
                        near_buf[B_Y, n_near] = ey
                        near_buf[B_Z, n_near] = ez
                        for c in range(3):
                            near_buf[B_MX + c, n_near] = e_nrm[t, c]
                            near_buf[B_L + c, n_near] = e_rad[t, c]
                        near_buf[B_A, n_near] = e_area[t]
                        near_buf[B_KEEP, n_near] = ONE32
                        near_t[n_near] = t
                        pos_of[t] = n_near
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
                px = np.float32(points[i, 0] - bx)
                py = np.float32(points[i, 1] - by)
                pz = np.float32(points[i, 2] - bz)
                nx = np.float32(nx)
                ny = np.float32(ny)
                nz = np.float32(nz)
                # the receiver's own disk and its near-field disks leave the disk sums (one
                # not listed was culled: its disk term is 0); the latter give their cells'
                # terms instead
                t = own_pos[i]
                if t >= 0 and pos_of[t] < n_near and near_t[pos_of[t]] == t:
                    near_buf[B_KEEP, pos_of[t]] = ZERO32
                for e in range(cell_start[i], cell_start[i + 1]):
                    t = cell_col[e]
                    q = pos_of[t]
                    if q < n_near and near_t[q] == t:
                        near_buf[B_KEEP, q] = ZERO32
                f0, f1, f2 = far_sums(far_buf, n_far, px, py, pz, nx, ny, nz)
                n0, n1, n2 = near_sums(near_buf, n_near, px, py, pz, nx, ny, nz, reach2)
                c0 = 0.0
                c1 = 0.0
                c2 = 0.0
                for e in range(cell_start[i], cell_start[i + 1]):
                    t = cell_col[e]
                    v = cell_val[e]
                    if capped:
                        ex = e_pos[t, 0] - points[i, 0]
                        ey = e_pos[t, 1] - points[i, 1]
                        ez = e_pos[t, 2] - points[i, 2]
                        if ex * ex + ey * ey + ez * ez > reach * reach:
                            v = 0.0
                    c0 += v * e_rad[t, 0]
                    c1 += v * e_rad[t, 1]
                    c2 += v * e_rad[t, 2]
                    q = pos_of[t]
                    if q < n_near and near_t[q] == t:
                        near_buf[B_KEEP, q] = ONE32
                t = own_pos[i]
                if t >= 0 and pos_of[t] < n_near and near_t[pos_of[t]] == t:
                    near_buf[B_KEEP, pos_of[t]] = ONE32
                out[i, 0] = np.float64(f0) + np.float64(n0) + c0
                out[i, 1] = np.float64(f1) + np.float64(n1) + c1
                out[i, 2] = np.float64(f2) + np.float64(n2) + c2


@njit(cache=True, error_model="numpy", inline="always")
def next_near_leaf(node, px, py, pz, skip, node_reach, node_centre):
    """The next leaf, from ``node`` on in the walk (``skip`` order), whose ``node_reach``
    sphere holds the point (a node outside it is skipped whole); ``skip.shape[0]``: none
    left. The near-field tables' walk: ``near_cells`` and ``triangle_cells``."""
    m = skip.shape[0]
    while node < m:
        dx = node_centre[node, 0] - px
        dy = node_centre[node, 1] - py
        dz = node_centre[node, 2] - pz
        if dx * dx + dy * dy + dz * dz >= node_reach[node] * node_reach[node]:
            node = skip[node]
        elif skip[node] != node + 1:
            node += 1
        else:
            return node
    return m


@njit(cache=True, error_model="numpy", parallel=True)
def near_cells(points, normals, positions, corner_start, corners, near, skip, start, stop, node_reach,
               node_centre, e_pos, e_area, e_own, counts, cell_start, cell_col, cell_val, fill):
    """The near field of every receiver, two calls: with ``fill`` False, ``counts[i]`` = the
    number of disks j (tree position t) with ``r^2 < near A_j`` from receiver i, j not its
    own; with ``fill`` True (``cell_start``: the counts' prefix sums), their tree positions
    and ``pi F_j``, F_j the form factor of vertex j's barycentric cell from receiver i
    toward its front side (``polygon.cell_terms``), clipped to i's tangent plane: the
    irradiance per unit radiance of the surface the disk stands for. In tree order per
    receiver; receivers without a normal get none.

    ``node_reach[q]`` bounds how far from node q's centre a receiver can be near one of
    its disks (``b + sqrt(near A_max)``, a little more for rounding): the walk skips
    nodes farther than that.

    Parameters
    ----------
    points, normals : (n, 3) float64
    positions : (n, 3) float64
        Vertex positions (the cells' corners).
    corner_start, corners : the cells (``polygon.cell_corners``).
    near : float > 0
    skip, start, stop : (m,) int64
    node_reach : (m,) float64
    node_centre : (m, 3) float64
    e_pos : (k, 3) float64
    e_area : (k,) float64
    e_own : (k,) int64
        Tree order.
    counts : (n,) int64
    cell_start : (n + 1,) int64
    cell_col : (c,) int64
    cell_val : (c,) float64
    fill : bool
    """
    m = skip.shape[0]
    for i in prange(points.shape[0]):
        nx = normals[i, 0]
        ny = normals[i, 1]
        nz = normals[i, 2]
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            if not fill:
                counts[i] = 0
            continue
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        quad = np.empty((4, 3))
        found = 0
        e = cell_start[i] if fill else 0
        node = next_near_leaf(0, px, py, pz, skip, node_reach, node_centre)
        while node < m:
            for t in range(start[node], stop[node]):
                if e_own[t] == i:
                    continue
                ex = e_pos[t, 0] - px
                ey = e_pos[t, 1] - py
                ez = e_pos[t, 2] - pz
                if ex * ex + ey * ey + ez * ez >= near * e_area[t]:
                    continue
                if fill:
                    front, _ = cell_terms(positions, corner_start, corners, e_own[t], px, py, pz, nx, ny, nz,
                                          MEASURE_COSINE, quad)
                    cell_col[e] = t
                    cell_val[e] = np.pi * front
                    e += 1
                found += 1
            node = next_near_leaf(skip[node], px, py, pz, skip, node_reach, node_centre)
        if not fill:
            counts[i] = found


@njit(cache=True, error_model="numpy", parallel=True)
def triangle_cells(points, normals, positions, faces, near, skip, start, stop, node_reach, node_centre, e_pos, e_area,
                   e_face, counts, cell_start, cell_col, cell_val, fill):  # fmt: skip
    """The near field of occluding triangles, two calls as :func:`near_cells`, one table per
    side (index s: 0 the triangles whose front faces the receiver, 1 their back): receiver
    i's triangles t (tree positions; centroid ``e_pos[t]``, area ``e_area[t]``, row
    ``e_face[t]`` of ``faces``) with ``r^2 < near A_t``, and ``pi F_t``, F_t the triangle's
    exact form factor clipped to i's tangent plane (``polygon.clipped_quad``): with them a
    gather of the triangles as disks (``flip`` for the backs) takes the polygon where the
    disk is poor. A triangle whose plane passes within NEAR_PLANE_REL edge lengths of the
    receiver (its own, or one it lies on) is listed on both sides with 0: seen edge-on.
    Receivers without a normal get none. ``counts`` (2, n), ``cell_start`` (2, n + 1),
    ``cell_col`` and ``cell_val``: a tuple of two arrays each (one per side)."""
    m = skip.shape[0]
    col_f, col_b = cell_col
    val_f, val_b = cell_val
    for i in prange(points.shape[0]):
        nx = normals[i, 0]
        ny = normals[i, 1]
        nz = normals[i, 2]
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            if not fill:
                counts[0, i] = 0
                counts[1, i] = 0
            continue
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        quad = np.empty((4, 3))
        found_f = 0
        found_b = 0
        e_f = cell_start[0, i] if fill else 0
        e_b = cell_start[1, i] if fill else 0
        node = next_near_leaf(0, px, py, pz, skip, node_reach, node_centre)
        while node < m:
            for t in range(start[node], stop[node]):
                ex = e_pos[t, 0] - px
                ey = e_pos[t, 1] - py
                ez = e_pos[t, 2] - pz
                if ex * ex + ey * ey + ez * ez >= near * e_area[t]:
                    continue
                f = e_face[t]
                a = faces[f, 0]
                mx, my, mz = triangle_cross(positions, a, faces[f, 1], faces[f, 2])
                h = mx * (px - positions[a, 0]) + my * (py - positions[a, 1]) + mz * (pz - positions[a, 2])
                m2 = mx * mx + my * my + mz * mz
                edge_on = not h * h > NEAR_PLANE_REL * NEAR_PLANE_REL * m2 * np.sqrt(m2)
                if fill:
                    value = 0.0
                    if not edge_on:
                        for k in range(4):
                            v = faces[f, min(k, 2)]
                            quad[k, 0] = positions[v, 0]
                            quad[k, 1] = positions[v, 1]
                            quad[k, 2] = positions[v, 2]
                        value = np.pi * clipped_quad(px, py, pz, nx, ny, nz, quad, MEASURE_COSINE)
                    if edge_on or h > 0.0:
                        col_f[e_f] = t
                        val_f[e_f] = value
                        e_f += 1
                    if edge_on or h < 0.0:
                        col_b[e_b] = t
                        val_b[e_b] = value
                        e_b += 1
                found_f += edge_on or h > 0.0
                found_b += edge_on or h < 0.0
            node = next_near_leaf(skip[node], px, py, pz, skip, node_reach, node_centre)
        if not fill:
            counts[0, i] = found_f
            counts[1, i] = found_b
