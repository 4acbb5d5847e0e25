"""Compiled loops of the disk method's cluster tree: build, geometry, per-pass refit.

Imports numpy, numba and ``aobake.constants`` only. The tree is flat: nodes in depth-first
preorder, the first child of an internal node ``q`` is ``q + 1`` and ``skip[q]`` is the
node after ``q``'s subtree, so ``skip[q] == q + 1`` marks a leaf and traversal needs
neither recursion nor a stack. Node ``q`` holds emitters ``start[q]:stop[q]`` (tree order).

Node rows (float32, one 64-byte cache line per node, written by :func:`pack_nodes` and
:func:`refit_nodes`; the traversal reads columns 0-5 before it decides):

- N_X..N_Z: area-weighted mean disk centre; N_RADIUS: bounding radius b (disks included);
- N_OPEN_D2: squared distance from the receivers beyond which the node is used whole;
- N_WAREA: the largest over the weight levels of ``A_w = sum w A`` (w: pass weight);
- N_NX..N_NZ: ``N = sum w A m`` (m: unit disk normal), last weight level;
- N_TXX..N_TYZ: ``kappa^2 T`` with ``T = sum w A m m^T``, last weight level (the traversal
  reads every level from the separate ``moments`` array, see :func:`refit_nodes`);
- N_AREA: summed area A.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import TREE_BUILD_STACK

N_X, N_Y, N_Z, N_RADIUS, N_OPEN_D2, N_WAREA = 0, 1, 2, 3, 4, 5
N_NX, N_NY, N_NZ = 6, 7, 8
N_TXX, N_TYY, N_TZZ, N_TXY, N_TXZ, N_TYZ = 9, 10, 11, 12, 13, 14
N_AREA = 15
NODE_COLS = 16
# per-pass sums per weight level: A_w, N (3), kappa^2 T (6), and the centroid of the
# occluded area, sum (1 - w) A o / sum (1 - w) A (o: the centroid of what occludes the
# emitter; the node's centre where nothing is occluded)
MOMENT_COLS = 13
M_WA, M_NX, M_NY, M_NZ, M_TXX, M_TYY, M_TZZ, M_TXY, M_TXZ, M_TYZ = range(10)
M_OX, M_OY, M_OZ = 10, 11, 12

# Emitter rows (float32): centre, unit normal, area (weights: a separate (k, L) table).
E_X, E_Y, E_Z, E_MX, E_MY, E_MZ, E_AREA = 0, 1, 2, 3, 4, 5, 6
EMITTER_COLS = 8


@njit(cache=True, error_model="numpy")
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
    stack = np.zeros((TREE_BUILD_STACK, 3), dtype=np.int64)
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def key_less(keys, a, b, axis):
    """Strict order on elements: by key along ``axis``, then by index (all pairs distinct)."""
    ka = keys[a, axis]
    kb = keys[b, axis]
    return ka < kb or (ka == kb and a < b)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", parallel=True)
def node_geometry(positions, areas, order, start, stop, out):
    """Per node q (float64 columns of ``out``, shape (m, 6)): 0-2 centre
    ``sum A c / sum A``, 3 radius ``max |c_j - centre| + sqrt(A_j / pi)`` (disks included,
    so every disk of the node lies inside the sphere), 4 area ``sum A``, 5 the largest
    disk area (it bounds the node's near-field reach). Each node reads its own emitter
    range: O(k log k) in all; call again after the positions move (a refit keeps
    ``order``, ``start``, ``stop``).

    Parameters
    ----------
    positions : (n, 3) float64
    areas : (n,) float64
    order : (k,) int64
        Vertex of each emitter in tree order.
    start, stop : (m,) int64
    out : (m, 6) float64
    """
    for q in prange(start.shape[0]):
        total = 0.0
        biggest = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for t in range(start[q], stop[q]):
            j = order[t]
            a = areas[j]
            total += a
            biggest = max(biggest, a)
            sx += a * positions[j, 0]
            sy += a * positions[j, 1]
            sz += a * positions[j, 2]
        cx = sx / total
        cy = sy / total
        cz = sz / total
        rb = 0.0
        for t in range(start[q], stop[q]):
            j = order[t]
            dx = positions[j, 0] - cx
            dy = positions[j, 1] - cy
            dz = positions[j, 2] - cz
            rb = max(rb, np.sqrt(dx * dx + dy * dy + dz * dz) + np.sqrt(areas[j] / np.pi))
        out[q, 0] = cx
        out[q, 1] = cy
        out[q, 2] = cz
        out[q, 3] = rb
        out[q, 4] = total
        out[q, 5] = biggest


@njit(cache=True, error_model="numpy", parallel=True)
def emitter_rows(positions, normals, areas, order, rows):
    """``rows[t]`` = (position, normal, area) of emitter ``order[t]`` in float32 (the
    columns E_X..E_AREA; the others are left alone): the tree-order copy the passes read.

    Parameters
    ----------
    positions, normals : (n, 3) float64
    areas : (n,) float64
    order : (k,) int64
    rows : (k, EMITTER_COLS) float32
    """
    for t in prange(order.shape[0]):
        j = order[t]
        for c in range(3):
            rows[t, E_X + c] = positions[j, c]
            rows[t, E_MX + c] = normals[j, c]
        rows[t, E_AREA] = areas[j]


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy")
def refit_nodes(emitters, weights, occluders, skip, start, stop, nodes, moments, leveled):
    """Per-pass node sums from the emitters' weights, one set per weight level ``l``:
    ``A_w = sum w_l A``, ``N = sum w_l A m``, ``kappa^2 T`` with ``T = sum w_l A m m^T``
    and the centroid ``sum (1 - w_l) A o / sum (1 - w_l) A`` (o: the emitter's occluder
    centroid; computed in float64, as a difference of float32 sums would cancel).

    Bottom-up in reverse preorder (children before parents: O(m L)) in float64; a leaf
    sums its emitters, an internal node q adds its children q + 1 and skip[q + 1]. The
    moments are multiplied by ``kappa^2`` (:func:`spread_factor`) and stored as float32.

    Parameters
    ----------
    emitters : (k, EMITTER_COLS) float32
    weights : (k, L) float32
        Each emitter's weight at each level (see ``aobake.kernels.bunnell``).
    occluders : (k, 3) float32
        Each emitter's occluder centroid o (gated passes; any values else).
    skip, start, stop : (m,) int64
    nodes : (m, NODE_COLS) float32
        Writes N_WAREA (the largest A_w over the levels: 0 means the node casts
        nothing at any distance) and, from level L - 1, N_NX..N_TYZ.
    moments : (m, L, MOMENT_COLS) float32
        Written in full: per level ``(A_w, N (3), kappa^2 T (6), occluded centroid (3))``.
    leveled : bool
        The weights differ between levels. False (every pass 1): only level 0 is read
        and summed, and copied to the other levels (a seventh of the work).
    """
    m = skip.shape[0]
    all_levels = weights.shape[1]
    levels = all_levels if leveled else 1
    hid = MOMENT_COLS  # extra float64 column: sum (1 - w) A
    mom = np.zeros((m, levels, MOMENT_COLS + 1))
    for q in range(m - 1, -1, -1):
        if skip[q] == q + 1:
            for j in range(start[q], stop[q]):
                area = np.float64(emitters[j, E_AREA])
                mx = np.float64(emitters[j, E_MX])
                my = np.float64(emitters[j, E_MY])
                mz = np.float64(emitters[j, E_MZ])
                for lv in range(levels):
                    wa = np.float64(weights[j, lv]) * area
                    mom[q, lv, 0] += wa
                    mom[q, lv, 1] += wa * mx
                    mom[q, lv, 2] += wa * my
                    mom[q, lv, 3] += wa * mz
                    mom[q, lv, 4] += wa * mx * mx
                    mom[q, lv, 5] += wa * my * my
                    mom[q, lv, 6] += wa * mz * mz
                    mom[q, lv, 7] += wa * mx * my
                    mom[q, lv, 8] += wa * mx * mz
                    mom[q, lv, 9] += wa * my * mz
                    hidden = area - wa
                    mom[q, lv, 10] += hidden * np.float64(occluders[j, 0])
                    mom[q, lv, 11] += hidden * np.float64(occluders[j, 1])
                    mom[q, lv, 12] += hidden * np.float64(occluders[j, 2])
                    mom[q, lv, hid] += hidden
        else:
            left = q + 1
            right = skip[left]
            for lv in range(levels):
                for c in range(MOMENT_COLS + 1):
                    mom[q, lv, c] = mom[left, lv, c] + mom[right, lv, c]
    for q in range(m):
        most = 0.0
        for lv in range(levels):
            row = mom[q, lv]
            kappa = spread_factor(row[0], row[4], row[5], row[6], row[7], row[8], row[9])
            k2 = kappa * kappa
            for c in range(4):
                moments[q, lv, c] = row[c]
            for c in range(4, M_OX):
                moments[q, lv, c] = k2 * row[c]
            for c in range(3):
                if row[hid] > 0.0:
                    moments[q, lv, M_OX + c] = row[M_OX + c] / row[hid]
                else:
                    moments[q, lv, M_OX + c] = nodes[q, N_X + c]
            most = max(most, row[0])
        for lv in range(levels, all_levels):
            for c in range(MOMENT_COLS):
                moments[q, lv, c] = moments[q, 0, c]
        nodes[q, N_WAREA] = most
        last = all_levels - 1
        nodes[q, N_NX] = moments[q, last, 1]
        nodes[q, N_NY] = moments[q, last, 2]
        nodes[q, N_NZ] = moments[q, last, 3]
        for c in range(6):
            nodes[q, N_TXX + c] = moments[q, last, 4 + c]


@njit(cache=True, error_model="numpy")
def leaf_representatives(positions, normals, areas, order, skip, start, stop, cos_min, rep_of):
    """Which emitter's later passes each emitter takes: per leaf, the emitter nearest the
    leaf's area-weighted centre (its representative) stands for every emitter of the leaf
    whose normal is within ``arccos(cos_min)`` of its own; the others stand for
    themselves (a crease or a contact splits the leaf).

    Parameters
    ----------
    positions, normals : (n, 3) float64
    areas : (n,) float64
    order, skip, start, stop : int64
        The tree (emitters in tree order; leaves are ``skip[q] == q + 1``).
    cos_min : float
    rep_of : (n,) int64
        Written for the emitters (``order``); other rows untouched.
    """
    for q in range(skip.shape[0]):
        if skip[q] != q + 1:
            continue
        lo = start[q]
        hi = stop[q]
        cx = 0.0
        cy = 0.0
        cz = 0.0
        total = 0.0
        for t in range(lo, hi):
            j = order[t]
            cx += areas[j] * positions[j, 0]
            cy += areas[j] * positions[j, 1]
            cz += areas[j] * positions[j, 2]
            total += areas[j]
        cx /= total
        cy /= total
        cz /= total
        rep = order[lo]
        best = np.inf
        for t in range(lo, hi):
            j = order[t]
            d = (positions[j, 0] - cx) ** 2 + (positions[j, 1] - cy) ** 2 + (positions[j, 2] - cz) ** 2
            if d < best:
                best = d
                rep = j
        for t in range(lo, hi):
            j = order[t]
            c = normals[j, 0] * normals[rep, 0] + normals[j, 1] * normals[rep, 1] + normals[j, 2] * normals[rep, 2]
            rep_of[j] = rep if c >= cos_min else j


@njit(cache=True, error_model="numpy")
def node_coherence(normals, areas, order, start, stop, out):
    """Per node ``out[q] = |sum A m| / sum A`` over its disks (unit normals m), clipped to
    [0, 1], 1 where it is not a number: prefix sums of ``(A m, A)`` in tree order, in
    float64, then one difference per node, O(k + m). The sums and the norm add in the
    order numpy's ``cumsum`` and ``linalg.norm`` did (bit for bit the numpy formulation,
    tests/test_bunnell.py).

    Parameters
    ----------
    normals : (n, 3) float64
    areas : (n,) float64
    order : (k,) int64
    start, stop : (m,) int64
    out : (m,) float64
    """
    k = order.shape[0]
    cum = np.zeros((k + 1, 4))
    for t in range(k):
        j = order[t]
        a = areas[j]
        cum[t + 1, 0] = cum[t, 0] + normals[j, 0] * a
        cum[t + 1, 1] = cum[t, 1] + normals[j, 1] * a
        cum[t + 1, 2] = cum[t, 2] + normals[j, 2] * a
        cum[t + 1, 3] = cum[t, 3] + a
    for q in range(start.shape[0]):
        lo = start[q]
        hi = stop[q]
        x = cum[hi, 0] - cum[lo, 0]
        y = cum[hi, 1] - cum[lo, 1]
        z = cum[hi, 2] - cum[lo, 2]
        c = np.sqrt(x * x + y * y + z * z) / (cum[hi, 3] - cum[lo, 3])
        out[q] = 1.0 if np.isnan(c) else min(max(c, 0.0), 1.0)


@njit(cache=True, error_model="numpy", parallel=True)
def quantised_keys(positions, rows, steps, out):
    """The tree's integer keys: ``out[t] = floor((positions[rows[t]] - lo) * (steps / E)
    + 0.5)`` (int64) with lo the least coordinates of those rows and E their bounding
    box's largest extent, as numpy computed them; all zeros when E is not > 0.

    Parameters
    ----------
    positions : (n, 3) float64
    rows : (k,) int64, k >= 1
    steps : float
    out : (k, 3) int64
    """
    lo = positions[rows[0]].copy()
    hi = lo.copy()
    for t in range(1, rows.shape[0]):
        j = rows[t]
        for c in range(3):
            v = positions[j, c]
            if v < lo[c]:
                lo[c] = v
            if v > hi[c]:
                hi[c] = v
    extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    if not extent > 0.0:
        out[:] = 0
        return
    step = steps / extent
    for t in prange(rows.shape[0]):
        j = rows[t]
        for c in range(3):
            out[t, c] = np.int64(np.floor((positions[j, c] - lo[c]) * step + 0.5))
