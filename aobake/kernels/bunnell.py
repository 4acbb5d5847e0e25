"""Compiled loops of the disk method: disk form factors, cluster tree build, occlusion passes.

Imports numpy, numba and ``aobake.constants`` only (never trimesh or another aobake module).

Symbols used in every docstring below (same names as the code):

- receiver ``i``: position ``p``, unit normal ``n`` (or a zero row: no normal);
- emitter ``j``: centre ``c``, unit normal ``m``, area ``A``, weight ``w`` (its
  accessibility from the previous pass, 1 in pass 1);
- ``d = c - p``, ``r = |d|``; ``cos_e = -m.d / r`` (front faces cast: the emitter's front
  side faces the receiver), ``cos_r = n.d / r``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from aobake.constants import FASTMATH

MEASURE_COSINE = 0
MEASURE_UNIFORM = 1

# An emitter closer to the receiver than sqrt(COINCIDENT_REL * A) is treated as the same
# point (split vertices share a position) and skipped: relative to the emitter's own size,
# so the test is scale invariant; 1e-12 means r < 1e-6 disk radii, far below any real
# vertex spacing but far above the rounding of recentred float64 coordinates.
COINCIDENT_REL = 1e-12

# Receiver factor for a vertex without a normal: the mean over all normal directions of
# the receiver's weight, so its occlusion is the normal-averaged one = the occluded
# fraction of the full sphere. Cosine measure: mean of max(cos_r, 0) over the sphere = 1/4.
# Uniform measure: the exact uniform hemisphere weight H(cos_r) averages to 1/2.
NO_NORMAL_COSINE = 0.25
NO_NORMAL_UNIFORM = 0.5

# Tree keys: positions quantised to this many steps of the scene's largest extent. Integer
# keys make the tree topology (and so the result) exactly invariant under scaling and
# translation unless a coordinate falls within rounding of a step boundary; 2**20 steps
# keep ~1e-6 of the extent as resolution, far finer than any useful split.
KEY_STEPS = 1 << 20

# Pending-range stack of the iterative tree build. Median splits halve the range, so the
# stack never holds more than ~log2(k) + 2 entries; 128 covers any k < 2**120.
BUILD_STACK = 128


# Packed rows: one emitter or node is one contiguous row, so a traversal step touches one
# or two cache lines instead of one per attribute array.
E_X, E_Y, E_Z, E_MX, E_MY, E_MZ, E_AREA, E_WEIGHT = 0, 1, 2, 3, 4, 5, 6, 7
EMITTER_COLS = 8
# node columns 0-7 are all a visit reads before deciding (first 64 bytes)
N_X, N_Y, N_Z, N_RADIUS, N_OPEN_D2, N_WAREA, N_AREA, N_NX, N_NY, N_NZ = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
N_TXX, N_TYY, N_TZZ, N_TXY, N_TXZ, N_TYZ = 10, 11, 12, 13, 14, 15
NODE_COLS = 16


class Emitters(NamedTuple):
    """Disk elements that cast (area > 0 and a normal), one packed row each.

    data : (k, EMITTER_COLS) float64
        Columns E_X..E_Z centre c, E_MX..E_MZ unit normal m, E_AREA area A > 0,
        E_WEIGHT this pass's weight w in [0, 1].
    index : (k,) int64
        The vertex each disk belongs to (a receiver never sees its own disk).
    """

    data: np.ndarray
    index: np.ndarray


class Receivers(NamedTuple):
    """Every vertex receives.

    positions : (n, 3) float64
    normals : (n, 3) float64, unit or zero rows (no normal)
    """

    positions: np.ndarray
    normals: np.ndarray


class Tree(NamedTuple):
    """A flat binary cluster tree in depth-first preorder, one packed row per node.

    The first child of an internal node ``q`` is ``q + 1``; ``skip[q]`` is the node after
    ``q``'s subtree (its next sibling or an ancestor's), so ``skip[q] == q + 1`` marks a
    leaf and traversal needs neither recursion nor a stack.

    skip : (m,) int64
    start, stop : (m,) int64
        The node's emitters are rows ``start:stop`` of ``Emitters.data`` (tree order).
    data : (m, NODE_COLS) float64
        Geometry (set once): N_X..N_Z area-weighted mean centre, N_RADIUS bounding radius
        b (disks included), N_OPEN_D2 squared distance beyond which the node is used
        whole, N_AREA summed area A. Per pass (:func:`refit_nodes`): N_WAREA
        ``A_w = sum w A``, N_NX..N_NZ ``N = sum w A m``, N_TXX..N_TYZ
        ``kappa^2 T`` with ``T = sum w A m m^T`` (see :func:`cluster_projection`).
    """

    skip: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    data: np.ndarray


# ---------------------------------------------------------------------------------------
# form factors


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def disk_term(r2, r, proj, area, g, measure):
    """Occlusion of a receiver by one disk (or a cluster used as one disk).

    Parameters
    ----------
    r2, r : float
        Squared distance and distance from the receiver to the disk centre (r > 0 or
        area > 0, so nothing divides by zero).
    proj : float
        Weighted projected area facing the receiver, ``w A max(cos_e, 0)``.
    area : float
        Disk area A (regularises the near field).
    g : float
        Receiver factor: ``max(cos_r, 0)`` (cosine) or ``clamp(4 cos_r, 0, 1)`` (uniform).
    measure : int
        MEASURE_COSINE or MEASURE_UNIFORM.

    Returns
    -------
    float
        cosine: ``proj g / (pi r2 + A)`` (the disk form factor A cos_e cos_r / (pi r^2 + A),
        exact on the disk axis: R^2 / (R^2 + r^2));
        uniform: ``(1 - r / s) (proj / A) g`` with ``s = sqrt(A / pi + r2)``, written as
        ``proj g / (pi s (s + r))`` so it does not cancel when r^2 >> A (Bunnell's
        solid-angle term; on the axis it is the disk's solid angle over 2 pi).
    """
    if measure == MEASURE_COSINE:
        return proj * g / (np.pi * r2 + area)
    s = np.sqrt(area / np.pi + r2)
    return proj * g / (np.pi * s * (s + r))


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def receiver_factor(nd, r, has_normal, measure):
    """Receiver weight g from ``nd = n.d`` (``cos_r = nd / r``); see NO_NORMAL_* when n = 0."""
    if not has_normal:
        if measure == MEASURE_COSINE:
            return NO_NORMAL_COSINE
        return NO_NORMAL_UNIFORM
    if nd <= 0.0:
        return 0.0
    if measure == MEASURE_COSINE:
        return nd / r
    return min(4.0 * nd / r, 1.0)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def cluster_projection(row, ux, uy, uz):
    """Weighted front-facing projected area of a node toward unit direction u (emitter -
    receiver): an estimate of ``P = sum_j w_j A_j max(-m_j.u, 0)``.

    With ``c_j = -m_j.u``, ``P = (sum w A |c_j| + sum w A c_j) / 2``. The signed sum is
    exact from the summed normal: ``s = -N.u``. The absolute sum is bounded by
    Cauchy-Schwarz, ``sum w A |c| <= sqrt(A_w u^T T u)``, with equality when the normals
    take at most two opposite directions (a flat patch; two sides of a thin part); for
    spread normals it is scaled by ``kappa`` (stored folded into the moments as
    ``kappa^2 T``), which makes it exact on average for isotropic normals. So a flat
    cluster is exact, a closed sphere shows ~1/4 of its area, and normals that cancel
    need no fallback. Clamped to ``[max(s, 0), inf)``, as the true P is.

    Parameters
    ----------
    row : (NODE_COLS,) float64
        The node's packed row.
    ux, uy, uz : float
    """
    s = -(row[N_NX] * ux + row[N_NY] * uy + row[N_NZ] * uz)
    quad = (
        row[N_TXX] * ux * ux
        + row[N_TYY] * uy * uy
        + row[N_TZZ] * uz * uz
        + 2.0 * (row[N_TXY] * ux * uy + row[N_TXZ] * ux * uz + row[N_TYZ] * uy * uz)
    )
    spread = np.sqrt(max(row[N_WAREA] * quad, 0.0))
    return max(0.5 * (spread + s), s, 0.0)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def spread_factor(area, txx, tyy, tzz, txy, txz, tyz):
    """kappa in [sqrt(3)/2, 1] from the normal moments: with ``rho = tr(T^2) / A_w^2`` in
    [1/3, 1] (1: normals along one axis; 1/3: isotropic),
    ``kappa = sqrt(3)/2 + (1 - sqrt(3)/2) (3 rho - 1) / 2``. Exact for one axis, for
    isotropic normals, and (to 3 digits) for normals on a circle (a cylinder).
    """
    if area <= 0.0:
        return 1.0
    tt = txx * txx + tyy * tyy + tzz * tzz + 2.0 * (txy * txy + txz * txz + tyz * tyz)
    rho = min(max(tt / (area * area), 1.0 / 3.0), 1.0)
    base = 0.5 * np.sqrt(3.0)
    return base + (1.0 - base) * 0.5 * (3.0 * rho - 1.0)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def element_sum(emitters, j0, j1, receivers, i, measure, max_d2):
    """Sum of the disk terms ``w A cos_e g / (...)`` of emitters ``j0:j1`` at receiver
    ``i``, in index order.

    Skips the receiver's own disk, coincident disks (``r2 <= COINCIDENT_REL A``), disks
    beyond the maximum distance (``r2 > max_d2``), zero weights and back faces.
    """
    px = receivers.positions[i, 0]
    py = receivers.positions[i, 1]
    pz = receivers.positions[i, 2]
    nx = receivers.normals[i, 0]
    ny = receivers.normals[i, 1]
    nz = receivers.normals[i, 2]
    has_normal = nx * nx + ny * ny + nz * nz > 0.0
    e_data = emitters.data
    total = 0.0
    for j in range(j0, j1):
        w = e_data[j, E_WEIGHT]
        if w <= 0.0 or emitters.index[j] == i:
            continue
        dx = e_data[j, E_X] - px
        dy = e_data[j, E_Y] - py
        dz = e_data[j, E_Z] - pz
        r2 = dx * dx + dy * dy + dz * dz
        area = e_data[j, E_AREA]
        if r2 <= COINCIDENT_REL * area or r2 > max_d2:
            continue
        e = -(e_data[j, E_MX] * dx + e_data[j, E_MY] * dy + e_data[j, E_MZ] * dz)
        if e <= 0.0:
            continue
        r = np.sqrt(r2)
        g = receiver_factor(nx * dx + ny * dy + nz * dz, r, has_normal, measure)
        if g <= 0.0:
            continue
        total += disk_term(r2, r, w * area * e / r, area, g, measure)
    return total


# ---------------------------------------------------------------------------------------
# passes


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def brute_force_pass(emitters, receivers, receiver_index, measure, max_distance, out):
    """Exact O(n k) sum: ``out[i] = sum_j w_j F(j -> i)`` for every ``i`` in receiver_index.

    Parameters
    ----------
    emitters : Emitters
        Weights w in column E_WEIGHT (1 in pass 1, accessibility 1 - A afterwards).
    receivers : Receivers
    receiver_index : (q,) int64
        Receivers to compute (a chunk); each writes only ``out[i]``.
    measure : int
    max_distance : float
        Emitters with r > max_distance are skipped (``inf`` = unbounded).
    out : (n,) float64
        Unsaturated occlusion sums (the caller clamps to [0, 1]).
    """
    max_d2 = max_distance * max_distance
    k = emitters.data.shape[0]
    for q in prange(receiver_index.shape[0]):
        i = receiver_index[q]
        out[i] = element_sum(emitters, 0, k, receivers, i, measure, max_d2)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def hierarchy_pass(emitters, tree, receivers, receiver_index, measure, max_distance, out):
    """Cluster-tree sum: like :func:`brute_force_pass`, far clusters count as one disk.

    Stackless preorder walk over ``tree``. At node q with centre c, bounding radius b and
    distance d from the receiver:

    - skip the subtree when its weighted area is 0, when ``d - b > max_distance`` (every
      emitter in it is too far) or when ``n.d <= -b`` (every emitter centre is below the
      receiver's tangent plane, where the receiver factor is 0): all exact;
    - use it whole when ``d^2 >= open_d2`` and ``d + b <= max_distance``: one point
      emitter with weighted projected area P toward the receiver
      (:func:`cluster_projection`), i.e. :func:`disk_term` with area 0: ``P g / (pi d^2)``
      (cosine), ``P g / (2 pi d^2)`` (uniform). The disk's ``+ A`` regularisation is
      exact only on a disk's axis; far clusters sit mostly off-axis, where it biases them
      low (measured: dropping it halves the error against the exact sum);
    - else sum a leaf's emitters exactly (:func:`element_sum`), or descend to q + 1.

    Parameters
    ----------
    emitters : Emitters
    tree : Tree
    receivers : Receivers
    receiver_index : (q,) int64
    measure : int
    max_distance : float
    out : (n,) float64
        Unsaturated occlusion sums.
    """
    max_d2 = max_distance * max_distance
    n_nodes = tree.skip.shape[0]
    t_data = tree.data
    for q in prange(receiver_index.shape[0]):
        i = receiver_index[q]
        px = receivers.positions[i, 0]
        py = receivers.positions[i, 1]
        pz = receivers.positions[i, 2]
        nx = receivers.normals[i, 0]
        ny = receivers.normals[i, 1]
        nz = receivers.normals[i, 2]
        has_normal = nx * nx + ny * ny + nz * nz > 0.0
        total = 0.0
        node = 0
        while node < n_nodes:
            nxt = tree.skip[node]
            row = t_data[node]
            if row[N_WAREA] <= 0.0:
                node = nxt
                continue
            dx = row[N_X] - px
            dy = row[N_Y] - py
            dz = row[N_Z] - pz
            d2 = dx * dx + dy * dy + dz * dz
            b = row[N_RADIUS]
            h = nx * dx + ny * dy + nz * dz
            d = np.sqrt(d2)
            if d - b > max_distance or (has_normal and h <= -b):
                node = nxt
                continue
            if d2 >= row[N_OPEN_D2] and d + b <= max_distance:
                g = receiver_factor(h, d, has_normal, measure)
                if g > 0.0:
                    proj = cluster_projection(row, dx / d, dy / d, dz / d)
                    if proj > 0.0:
                        total += disk_term(d2, d, proj, 0.0, g, measure)
                node = nxt
            elif nxt == node + 1:
                total += element_sum(
                    emitters, tree.start[node], tree.stop[node], receivers, i, measure, max_d2
                )
                node = nxt
            else:
                node += 1
        out[i] = total


# ---------------------------------------------------------------------------------------
# tree


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def build_tree(keys, leaf_size):
    """Median-split binary tree over integer point keys, built iteratively (explicit stack).

    Each range longer than ``leaf_size`` is split at its middle index after a quickselect
    on the longest axis of its keys' bounding box, ordering by (key, index) so ties are
    broken by the input order; when all keys coincide (zero extent) the split is by
    index alone, so the build always terminates. Integer keys (positions quantised by the
    caller) make the tree, and so the result, identical under scaling and translation.

    Parameters
    ----------
    keys : (k, 3) int64, k >= 1
    leaf_size : int >= 1

    Returns
    -------
    order : (k,) int64
        Tree order: node ranges index ``order``.
    start, stop, skip : (m,) int64
        Node ranges and skip pointers (preorder, first child = q + 1).
    """
    k = keys.shape[0]
    order = np.arange(k)
    cap = 2 * k
    start = np.zeros(cap, dtype=np.int64)
    stop = np.zeros(cap, dtype=np.int64)
    parent = np.full(cap, -1, dtype=np.int64)
    stack = np.zeros((BUILD_STACK, 3), dtype=np.int64)
    stack[0, 0] = 0
    stack[0, 1] = k
    stack[0, 2] = -1
    sp = 1
    m = 0
    while sp > 0:
        sp -= 1
        lo = stack[sp, 0]
        hi = stack[sp, 1]
        node = m
        m += 1
        start[node] = lo
        stop[node] = hi
        parent[node] = stack[sp, 2]
        if hi - lo <= leaf_size:
            continue
        axis, extent = longest_axis(keys, order, lo, hi)
        mid = (lo + hi) // 2
        if extent > 0:
            select(keys, order, lo, hi, mid, axis)
        # right pushed first so the left child is popped next and gets index node + 1
        stack[sp, 0] = mid
        stack[sp, 1] = hi
        stack[sp, 2] = node
        stack[sp + 1, 0] = lo
        stack[sp + 1, 1] = mid
        stack[sp + 1, 2] = node
        sp += 2
    size = np.ones(m, dtype=np.int64)
    for node in range(m - 1, 0, -1):
        size[parent[node]] += size[node]
    skip = np.arange(m) + size
    return order, start[:m].copy(), stop[:m].copy(), skip


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def longest_axis(keys, order, lo, hi):
    """Axis (0, 1, 2) and extent of the longest side of the bounding box of order[lo:hi]
    (ties go to the lower axis)."""
    j = order[lo]
    lo_x = keys[j, 0]
    lo_y = keys[j, 1]
    lo_z = keys[j, 2]
    hi_x = lo_x
    hi_y = lo_y
    hi_z = lo_z
    for t in range(lo + 1, hi):
        j = order[t]
        lo_x = min(lo_x, keys[j, 0])
        hi_x = max(hi_x, keys[j, 0])
        lo_y = min(lo_y, keys[j, 1])
        hi_y = max(hi_y, keys[j, 1])
        lo_z = min(lo_z, keys[j, 2])
        hi_z = max(hi_z, keys[j, 2])
    ex = hi_x - lo_x
    ey = hi_y - lo_y
    ez = hi_z - lo_z
    if ex >= ey and ex >= ez:
        return 0, ex
    if ey >= ez:
        return 1, ey
    return 2, ez


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def key_less(keys, a, b, axis):
    """Strict order on elements: by key along ``axis``, then by index (all pairs distinct)."""
    ka = keys[a, axis]
    kb = keys[b, axis]
    return ka < kb or (ka == kb and a < b)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def select(keys, order, lo, hi, kth, axis):
    """Reorder order[lo:hi] in place so that order[kth] is the element of rank kth - lo
    under :func:`key_less`, smaller ones left of it and larger ones right.

    Hoare-partition quickselect with a median-of-three pivot; deterministic, and since
    the order is strict (ties broken by index) equal keys cannot make it quadratic.
    """
    left = lo
    right = hi - 1
    while right > left:
        a = order[left]
        b = order[(left + right) // 2]
        c = order[right]
        # median of three under key_less
        if key_less(keys, b, a, axis):
            a, b = b, a
        if key_less(keys, c, b, axis):
            b = c
            if key_less(keys, b, a, axis):
                b = a
        pivot = b
        s = left
        t = right
        while s <= t:
            while key_less(keys, order[s], pivot, axis):
                s += 1
            while key_less(keys, pivot, order[t], axis):
                t -= 1
            if s <= t:
                tmp = order[s]
                order[s] = order[t]
                order[t] = tmp
                s += 1
                t -= 1
        if kth <= t:
            right = t
        elif kth >= s:
            left = s
        else:
            break


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def node_geometry(emitters, start, stop, out):
    """Per node q (columns of ``out``, shape (m, 5)): 0-2 centre ``sum A c / sum A``,
    3 radius ``max |c_j - centre| + sqrt(A_j / pi)`` (disks included, so every disk of
    the node lies inside the sphere), 4 area ``sum A``. Each node reads its own emitter
    range: O(k log k) in all.
    """
    e_data = emitters.data
    for q in prange(start.shape[0]):
        total = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for j in range(start[q], stop[q]):
            a = e_data[j, E_AREA]
            total += a
            sx += a * e_data[j, E_X]
            sy += a * e_data[j, E_Y]
            sz += a * e_data[j, E_Z]
        cx = sx / total
        cy = sy / total
        cz = sz / total
        rb = 0.0
        for j in range(start[q], stop[q]):
            dx = e_data[j, E_X] - cx
            dy = e_data[j, E_Y] - cy
            dz = e_data[j, E_Z] - cz
            rb = max(rb, np.sqrt(dx * dx + dy * dy + dz * dz) + np.sqrt(e_data[j, E_AREA] / np.pi))
        out[q, 0] = cx
        out[q, 1] = cy
        out[q, 2] = cz
        out[q, 3] = rb
        out[q, 4] = total


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def refit_nodes(emitters, tree):
    """Per-pass node columns from the emitters' weights: ``A_w = sum w A``,
    ``N = sum w A m`` and ``kappa^2 T`` with ``T = sum w A m m^T``.

    Bottom-up in reverse preorder (children before parents: O(m)); a leaf sums its
    emitters, an internal node q adds its children q + 1 and skip[q + 1]. The moments are
    summed unscaled and multiplied by ``kappa^2`` (:func:`spread_factor`) in a second
    sweep. Writes every per-pass column of every node.
    """
    skip = tree.skip
    t_data = tree.data
    e_data = emitters.data
    m = skip.shape[0]
    for q in range(m - 1, -1, -1):
        if skip[q] == q + 1:
            for c in range(N_WAREA, NODE_COLS):
                if c != N_AREA:
                    t_data[q, c] = 0.0
            for j in range(tree.start[q], tree.stop[q]):
                wa = e_data[j, E_WEIGHT] * e_data[j, E_AREA]
                mx = e_data[j, E_MX]
                my = e_data[j, E_MY]
                mz = e_data[j, E_MZ]
                t_data[q, N_WAREA] += wa
                t_data[q, N_NX] += wa * mx
                t_data[q, N_NY] += wa * my
                t_data[q, N_NZ] += wa * mz
                t_data[q, N_TXX] += wa * mx * mx
                t_data[q, N_TYY] += wa * my * my
                t_data[q, N_TZZ] += wa * mz * mz
                t_data[q, N_TXY] += wa * mx * my
                t_data[q, N_TXZ] += wa * mx * mz
                t_data[q, N_TYZ] += wa * my * mz
        else:
            left = q + 1
            right = skip[left]
            for c in range(N_WAREA, NODE_COLS):
                if c != N_AREA:
                    t_data[q, c] = t_data[left, c] + t_data[right, c]
    for q in range(m):
        row = t_data[q]
        kappa = spread_factor(
            row[N_WAREA], row[N_TXX], row[N_TYY], row[N_TZZ], row[N_TXY], row[N_TXZ], row[N_TYZ]
        )
        for c in range(N_TXX, NODE_COLS):
            row[c] *= kappa * kappa
