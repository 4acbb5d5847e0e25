"""Tree walk of the disk method's tree pass: each bucket of receivers walks the cluster
tree once and copies what it meets into per-thread lists (near: emitters of opened
leaves; far: nodes used whole) that its receivers then sum (``listsums``).

Imports numpy, numba and ``aobake.constants`` only. Symbols as in
``aobake.kernels.bunnell``; the tree is ``aobake.kernels.hierarchy``'s.

numba caches each kernel by its own file's time stamp: the ``listterms`` and
``bunnell`` terms inlined here do not invalidate it, so after changing them, touch
this file (or delete ``__pycache__``) or stale machine code keeps running.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .bunnell import N_LEVELS, level_of
from .hierarchy import (
    E_AREA,
    E_MX,
    E_MY,
    E_MZ,
    E_X,
    E_Y,
    E_Z,
    M_NX,
    M_NY,
    M_NZ,
    M_OX,
    M_OY,
    M_OZ,
    M_TXX,
    M_TXY,
    M_TXZ,
    M_TYY,
    M_TYZ,
    M_TZZ,
    M_WA,
    N_OPEN_D2,
    N_RADIUS,
    N_WAREA,
    N_X,
    N_Y,
    N_Z,
)

# Scratch rows per thread (float32): the near list (emitters of opened leaves: centre,
# normal, area, area x weight per level, then the occluder centroid of gated passes) and
# the far list (nodes used whole: centre, the moments of the weight level of their
# distance, and for gated passes the level-0 moments and the occluded area's centroid),
# copied per bucket of receivers so each receiver's sums are contiguous loops.
S_X, S_Y, S_Z, S_MX, S_MY, S_MZ, S_A, S_WA = 0, 1, 2, 3, 4, 5, 6, 7
S_O = S_WA + N_LEVELS
F_X, F_Y, F_Z, F_WA, F_NX, F_NY, F_NZ = 0, 1, 2, 3, 4, 5, 6
F_TXX, F_TYY, F_TZZ, F_TXY, F_TXZ, F_TYZ = 7, 8, 9, 10, 11, 12
# far rows F_WA..F_TYZ hold moment columns M_WA..M_TYZ (row = column + 3); the level-0
# copy of row r is row r + F_LEVEL0 - F_WA
F_LEVEL0 = 13
F_OX, F_OY, F_OZ = 23, 24, 25
FAR_ROWS = 26

# Slack of the bucket-level near-field candidate test (normalised units and relative):
# far above the float32 rounding of coordinates of order 1 (6e-8) in the receivers' test.
CAND_SLACK = 1e-5

# Slack of the bucket-level test that an emitter is behind every receiver's plane
# (normalised units, relative to the distances involved): far above the float32 rounding
# of the receivers' n.d (~1e-7 for coordinates of order 1).
BEHIND_SLACK = 1e-5

# Rows of the near-list scratch: the weight rows are laid out for N_LEVELS levels.
NEAR_ROWS = S_O + 3


# Columns of a bucket's bounds (bucket_bounds): centre, bounding radius and largest
# inner radius of its receivers, then the cone of their normals (unit axis, largest
# deviation |n_i - axis|) and the plane height H = max_i n_i.(centre - p_i), inf when a
# receiver has no normal (see gather: emitters behind every receiver's plane).
B_X, B_Y, B_Z, B_RADIUS, B_INNER, B_NX, B_NY, B_NZ, B_SPREAD, B_HEIGHT = range(10)
BOUND_COLS = 10


@njit(cache=True, error_model="numpy")
def bucket_bounds(points, normals, inner, order, bucket_start, out):
    """Bounds of each bucket's receivers, ``out[b]`` (columns B_X..B_HEIGHT): centre
    (mean), bounding radius, largest inner radius, and the cone of their normals with
    the plane height H: for any point x, ``n_i.(x - p_i) <= axis.(x - c) + spread |x - c|
    + H`` for every receiver i (Cauchy-Schwarz on ``n_i - axis``).

    Parameters
    ----------
    points, normals : (n, 3) float64
    inner : (n,) float64
    order : (n,) int64
        Receivers in bucket order; bucket b is ``order[bucket_start[b]:bucket_start[b + 1]]``.
    bucket_start : (nb + 1,) int64
    out : (nb, BOUND_COLS) float64
    """
    for b in range(bucket_start.shape[0] - 1):
        lo = bucket_start[b]
        hi = bucket_start[b + 1]
        cx = 0.0
        cy = 0.0
        cz = 0.0
        ax = 0.0
        ay = 0.0
        az = 0.0
        normal_less = False
        for q in range(lo, hi):
            i = order[q]
            cx += points[i, 0]
            cy += points[i, 1]
            cz += points[i, 2]
            ax += normals[i, 0]
            ay += normals[i, 1]
            az += normals[i, 2]
            nn = normals[i, 0] ** 2 + normals[i, 1] ** 2 + normals[i, 2] ** 2
            normal_less = normal_less or nn == 0.0
        cx /= hi - lo
        cy /= hi - lo
        cz /= hi - lo
        norm = np.sqrt(ax * ax + ay * ay + az * az)
        if norm > 0.0:
            ax /= norm
            ay /= norm
            az /= norm
        rb = 0.0
        most = 0.0
        spread = 0.0
        height = -np.inf
        for q in range(lo, hi):
            i = order[q]
            most = max(most, inner[i])
            dx = points[i, 0] - cx
            dy = points[i, 1] - cy
            dz = points[i, 2] - cz
            rb = max(rb, np.sqrt(dx * dx + dy * dy + dz * dz))
            ex = normals[i, 0] - ax
            ey = normals[i, 1] - ay
            ez = normals[i, 2] - az
            spread = max(spread, np.sqrt(ex * ex + ey * ey + ez * ez))
            height = max(height, -(normals[i, 0] * dx + normals[i, 1] * dy + normals[i, 2] * dz))
        out[b, B_X] = cx
        out[b, B_Y] = cy
        out[b, B_Z] = cz
        # one float32 ulp of slack per coordinate: the receivers compare in float32
        out[b, B_RADIUS] = rb * (1.0 + 1e-6) + 1e-6 * (abs(cx) + abs(cy) + abs(cz))
        out[b, B_INNER] = most
        out[b, B_NX] = ax
        out[b, B_NY] = ay
        out[b, B_NZ] = az
        out[b, B_SPREAD] = spread
        out[b, B_HEIGHT] = np.inf if normal_less or norm == 0.0 else height


@njit(cache=True, error_model="numpy", inline="always")
def behind(bound, ex, ey, ez, e):
    """Offset (ex, ey, ez) = x - centre, of length e, lies behind every receiver's tangent
    plane of the bucket (``bucket_bounds``), by more than BEHIND_SLACK (relative): every
    receiver's cosine ``max(n.d, 0)``, in float32, is then exactly 0, and so is the term
    (any measure)."""
    h = bound[B_NX] * ex + bound[B_NY] * ey + bound[B_NZ] * ez + bound[B_SPREAD] * e + bound[B_HEIGHT]
    return h < -BEHIND_SLACK * (e + bound[B_RADIUS] + 1.0)


@njit(cache=True, error_model="numpy")
def gather(tree, emitters, bound, options, near_buf, near_idx, far_buf):
    """Interaction lists of one bucket (centre, radius ``bound``): walk the tree once for
    all its receivers (``tree``: ``structures.TreeArrays``, ``emitters``:
    ``structures.Emitters``, ``options``: ``structures.PassOptions``).

    At node q (centre c, bounding radius b, ``dmin = |c - centre| - radius``):

    - skip the subtree when ``dmin - b > max_distance``, or when its weighted area is 0
      and there is no near field (cells have weights of their own);
    - use it whole (append to the far list, with the moments of the weight level of its
      distance from the bucket's centre) when ``dmin > 0``, ``dmin^2 >= open_d2`` (far
      enough for its size and outside its near-field reach for every receiver),
      ``dmin + 2 radius + b <= max_distance`` and ``dmin - b >= inner`` (entirely
      outside every receiver's inner radius);
    - else copy a leaf's emitters to the near list, or descend to q + 1.

    Without ``leveled`` (every weight level equal) only level 0 is copied. With
    ``leveled`` and ``gate > 0`` (gated passes) the near list also gets each emitter's
    occluder centroid, the far list each node's level-0 moments and the centroid of its
    occluded area at the level used (:func:`far_pair_gated`).

    Near-list emitters that may be in the near field of some receiver of the bucket
    (``r^2 < near A`` for ``r`` = their distance to the bucket's sphere, with slack for
    float32 rounding), and those inside the sphere (the receivers' own disks), are also
    listed as cell candidates.

    Returns
    -------
    n_near, n_cand, n_far : int
        Entries written: ``near_buf[:, :n_near]`` and ``near_idx[0, :n_near]`` (tree
        positions), ``near_idx[1, :n_cand]`` (candidates' positions in the near list),
        ``far_buf[:, :n_far]``.
    """
    skip, start, stop, nodes, moments = tree.skip, tree.start, tree.stop, tree.nodes, tree.moments
    rows, weights, occluders = emitters.rows, emitters.weights, emitters.occluders
    max_distance, near, weight_r2 = options.max_distance, options.near, options.weight_r2
    leveled, gate = options.leveled, options.gate
    gated = leveled and gate > 0.0
    bx = bound[B_X]
    by = bound[B_Y]
    bz = bound[B_Z]
    rb = bound[B_RADIUS]
    inner = bound[B_INNER]
    n_nodes = skip.shape[0]
    levels = weights.shape[1] if leveled else 1
    n_near = 0
    n_cand = 0
    n_far = 0
    node = 0
    while node < n_nodes:
        nxt = skip[node]
        if near <= 0.0 and nodes[node, N_WAREA] <= 0.0:
            node = nxt
            continue
        dx = nodes[node, N_X] - bx
        dy = nodes[node, N_Y] - by
        dz = nodes[node, N_Z] - bz
        b = nodes[node, N_RADIUS]
        d2 = dx * dx + dy * dy + dz * dz
        dist = np.sqrt(d2)
        dmin = dist - rb
        if dmin - b > max_distance:
            node = nxt
        elif (
            dmin > 0.0
            and dmin * dmin >= nodes[node, N_OPEN_D2]
            and dmin + 2.0 * rb + b <= max_distance
            and dmin - b >= inner
        ):
            if behind(bound, dx, dy, dz, dist):  # a zero term at every receiver
                node = nxt
                continue
            lv = level_of(d2, weight_r2) if leveled else 0
            far_buf[F_X, n_far] = nodes[node, N_X]
            far_buf[F_Y, n_far] = nodes[node, N_Y]
            far_buf[F_Z, n_far] = nodes[node, N_Z]
            far_buf[F_WA, n_far] = moments[node, lv, M_WA]
            far_buf[F_NX, n_far] = moments[node, lv, M_NX]
            far_buf[F_NY, n_far] = moments[node, lv, M_NY]
            far_buf[F_NZ, n_far] = moments[node, lv, M_NZ]
            far_buf[F_TXX, n_far] = moments[node, lv, M_TXX]
            far_buf[F_TYY, n_far] = moments[node, lv, M_TYY]
            far_buf[F_TZZ, n_far] = moments[node, lv, M_TZZ]
            far_buf[F_TXY, n_far] = moments[node, lv, M_TXY]
            far_buf[F_TXZ, n_far] = moments[node, lv, M_TXZ]
            far_buf[F_TYZ, n_far] = moments[node, lv, M_TYZ]
            if gated:
                for c in range(M_TYZ + 1):
                    far_buf[F_LEVEL0 + c, n_far] = moments[node, 0, c]
                far_buf[F_OX, n_far] = moments[node, lv, M_OX]
                far_buf[F_OY, n_far] = moments[node, lv, M_OY]
                far_buf[F_OZ, n_far] = moments[node, lv, M_OZ]
            n_far += 1
            node = nxt
        elif nxt == node + 1:
            for j in range(start[node], stop[node]):
                # with near = 0 the disks inside the bucket's sphere (its receivers' own
                # disks among them) are still candidates: the receivers remove their own
                ex = rows[j, E_X] - bx
                ey = rows[j, E_Y] - by
                ez = rows[j, E_Z] - bz
                e = np.sqrt(ex * ex + ey * ey + ez * ez)
                gap = e - rb - CAND_SLACK
                cand = gap <= 0.0 or gap * gap < near * rows[j, E_AREA] * (1.0 + CAND_SLACK)
                if not cand and behind(bound, ex, ey, ez, e):
                    continue  # a zero disk term at every receiver, and no cell
                near_buf[S_X, n_near] = rows[j, E_X]
                near_buf[S_Y, n_near] = rows[j, E_Y]
                near_buf[S_Z, n_near] = rows[j, E_Z]
                near_buf[S_MX, n_near] = rows[j, E_MX]
                near_buf[S_MY, n_near] = rows[j, E_MY]
                near_buf[S_MZ, n_near] = rows[j, E_MZ]
                near_buf[S_A, n_near] = rows[j, E_AREA]
                for lv in range(levels):
                    near_buf[S_WA + lv, n_near] = weights[j, lv] * rows[j, E_AREA]
                if gated:
                    near_buf[S_O, n_near] = occluders[j, 0]
                    near_buf[S_O + 1, n_near] = occluders[j, 1]
                    near_buf[S_O + 2, n_near] = occluders[j, 2]
                near_idx[0, n_near] = j
                if cand:
                    near_idx[1, n_cand] = n_near
                    n_cand += 1
                n_near += 1
            node = nxt
        else:
            node += 1
    return n_near, n_cand, n_far
