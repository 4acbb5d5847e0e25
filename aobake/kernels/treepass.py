"""Compiled tree pass of the disk method: buckets of receivers walk the cluster tree once,
then each receiver sums the interaction lists in vectorised float32 loops.

Imports numpy, numba and ``aobake.constants`` only. Symbols as in
``aobake.kernels.bunnell``; the tree is ``aobake.kernels.hierarchy``'s.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from aobake.constants import COINCIDENT_REL, FASTMATH, MEASURE_COSINE

from .bunnell import (
    HALF32,
    N_BINS,
    N_LEVELS,
    NO_NORMAL_COSINE,
    NO_NORMAL_UNIFORM,
    PI32,
    SECTORS,
    ZERO32,
    add_directions,
    direction_excess,
    disk_pair32,
    is_near,
    is_wide,
    level_of,
    sector_coords,
    settle_fill,
)
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
from .polygon import cell_terms
from .warps import frame as tangent_frame

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

# level_weight spells out the select chain for this many bins
assert N_BINS == 6, "update level_weight and binned_sums for the new PASS_RADII"

# Slack of the bucket-level near-field candidate test (normalised units and relative):
# far above the float32 rounding of coordinates of order 1 (6e-8) in the receivers' test.
CAND_SLACK = 1e-5

# Slack of the bucket-level test that an emitter is behind every receiver's plane
# (normalised units, relative to the distances involved): far above the float32 rounding
# of the receivers' n.d (~1e-7 for coordinates of order 1).
BEHIND_SLACK = 1e-5

# Relative slack of the test that a near-field cell lies wholly below the receiver's
# tangent plane (float64, against the rounding of its quads' corners).
CELL_SLACK = 1e-9


# Buckets per block of the tree pass's cyclic schedule (hierarchy_pass). 700k bunny on a
# floor, 2 threads: the busier thread's sum of bucket times was 2.39 s with one
# contiguous share per thread, where an even split is 1.84 s; per pass (one run, best
# of 4) 2.42 s contiguous, 1.99 s in blocks of 16, 1.95 s in blocks of 64, and 1.25,
# 1.28, 1.26 s on the 700k spheres scene (locality: blocks of neighbours). Another run:
# blocks of 32 / 64 / 256 took 1.28 / 1.34 / 1.52 s (spheres), 2.10 / 2.13 / 2.18 s
# (bunny).
SCHEDULE_BLOCK = 64

# Rows of the near-list scratch: the weight rows are laid out for N_LEVELS levels.
NEAR_ROWS = S_O + 3


# Columns of a bucket's bounds (bucket_bounds): centre, bounding radius and largest
# inner radius of its receivers, then the cone of their normals (unit axis, largest
# deviation |n_i - axis|) and the plane height H = max_i n_i.(centre - p_i), inf when a
# receiver has no normal (see gather: emitters behind every receiver's plane).
B_X, B_Y, B_Z, B_RADIUS, B_INNER, B_NX, B_NY, B_NZ, B_SPREAD, B_HEIGHT = range(10)
BOUND_COLS = 10


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def behind(bound, ex, ey, ez, e):
    """Offset (ex, ey, ez) = x - centre, of length e, lies behind every receiver's tangent
    plane of the bucket (``bucket_bounds``), by more than BEHIND_SLACK (relative): every
    receiver's cosine ``max(n.d, 0)``, in float32, is then exactly 0, and so is the term
    (any measure)."""
    h = bound[B_NX] * ex + bound[B_NY] * ey + bound[B_NZ] * ez + bound[B_SPREAD] * e + bound[B_HEIGHT]
    return h < -BEHIND_SLACK * (e + bound[B_RADIUS] + 1.0)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def gather(tree, emitters, bound, options, near_buf, near_idx, far_buf):
    """Interaction lists of one bucket (centre, radius ``bound``): walk the tree once for
    all its receivers.

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
    skip, start, stop, nodes, moments = tree
    rows, index, weights, occluders = emitters
    max_distance, near, weight_r2, leveled, gate = options
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_terms(wa, mx, my, mz, txx, tyy, tzz, txy, txz, tyz, dx, dy, dz, d2, nx, ny, nz,
              has_normal, measure):
    """(front, back) of a far node with moments ``A_w = wa``, ``N = (mx, my, mz)``,
    ``kappa^2 T = (txx, ..)``: a point emitter with weighted projected area P toward the
    receiver, i.e. the disk term without the ``+ A`` regularisation: ``P g / (pi d^2)``
    (cosine), ``P g / (2 pi d^2)`` (uniform). The regularisation is exact only on a disk's
    axis; far clusters sit mostly off-axis, where it biases them low.

    ``P`` for direction ``u`` (node - receiver) with ``s = -N.u``:
    ``max((sqrt(A_w u^T kappa^2 T u) + s) / 2, s, 0)`` toward the front sides and the
    same with ``-s`` toward the back sides (Cauchy-Schwarz on ``sum w A |m.u|``; exact
    for flat clusters and two-sided sheets, exact on average for isotropic normals).
    """
    s = -(mx * dx + my * dy + mz * dz)
    quad = (
        txx * dx * dx
        + tyy * dy * dy
        + tzz * dz * dz
        + np.float32(2.0) * (txy * dx * dy + txz * dx * dz + tyz * dy * dz)
    )
    spread = np.sqrt(max(wa * quad, ZERO32))
    nd = nx * dx + ny * dy + nz * dz
    if measure == MEASURE_COSINE and has_normal:
        c = max(nd, ZERO32) / (PI32 * d2 * d2)
    else:
        d = np.sqrt(d2)
        if measure == MEASURE_COSINE:
            c = np.float32(NO_NORMAL_COSINE) / (PI32 * d2 * d)
        else:
            if has_normal:
                g = min(max(np.float32(4.0) * nd / d, ZERO32), np.float32(1.0))
            else:
                g = np.float32(NO_NORMAL_UNIFORM)
            c = g / (np.float32(2.0) * PI32 * d2 * d)
    return c * max(HALF32 * (spread + s), max(s, ZERO32)), c * max(HALF32 * (spread - s), max(-s, ZERO32))


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_pair(far, j, dx, dy, dz, d2, nx, ny, nz, has_normal, measure):
    """(front, back) of far-list node j (:func:`far_terms` on its moments)."""
    return far_terms(
        far[F_WA, j], far[F_NX, j], far[F_NY, j], far[F_NZ, j], far[F_TXX, j], far[F_TYY, j],
        far[F_TZZ, j], far[F_TXY, j], far[F_TXZ, j], far[F_TYZ, j], dx, dy, dz, d2, nx, ny, nz,
        has_normal, measure,
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def gate32(ox, oy, oz, px, py, pz, nx, ny, nz, d2, gate, has_normal):
    """float32 ``bunnell.gate_factor`` from the squared distance ``d2``."""
    h = nx * (ox - px) + ny * (oy - py) + nz * (oz - pz)
    g = min(max(h / (gate * np.sqrt(d2)), ZERO32), np.float32(1.0))
    return g if has_normal else np.float32(1.0)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_pair_gated(far, j, dx, dy, dz, d2, px, py, pz, nx, ny, nz, has_normal, measure, gate):
    """:func:`far_pair` with gated weights: the node's moments are ``M_l + (1 - g)
    (M_0 - M_l)`` (level l as listed, level 0 = unweighted), g the gate factor of the
    centroid of its occluded area. Exact for a node of one emitter; for a cluster it
    gates all its emitters by their common centroid."""
    g = gate32(far[F_OX, j], far[F_OY, j], far[F_OZ, j], px, py, pz, nx, ny, nz, d2, gate,
               has_normal)
    u = np.float32(1.0) - g
    k = F_LEVEL0 - F_WA
    return far_terms(
        far[F_WA, j] + u * (far[F_WA + k, j] - far[F_WA, j]),
        far[F_NX, j] + u * (far[F_NX + k, j] - far[F_NX, j]),
        far[F_NY, j] + u * (far[F_NY + k, j] - far[F_NY, j]),
        far[F_NZ, j] + u * (far[F_NZ + k, j] - far[F_NZ, j]),
        far[F_TXX, j] + u * (far[F_TXX + k, j] - far[F_TXX, j]),
        far[F_TYY, j] + u * (far[F_TYY + k, j] - far[F_TYY, j]),
        far[F_TZZ, j] + u * (far[F_TZZ + k, j] - far[F_TZZ, j]),
        far[F_TXY, j] + u * (far[F_TXY + k, j] - far[F_TXY, j]),
        far[F_TXZ, j] + u * (far[F_TXZ + k, j] - far[F_TXZ, j]),
        far[F_TYZ, j] + u * (far[F_TYZ + k, j] - far[F_TYZ, j]),
        dx, dy, dz, d2, nx, ny, nz, has_normal, measure,
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def far_sums(far, n_far, px, py, pz, nx, ny, nz, has_normal, measure, gate):
    """(front, back) of the far list at one receiver (:func:`far_pair`, or
    :func:`far_pair_gated` when ``gate > 0``); vectorises."""
    front = ZERO32
    back = ZERO32
    if gate > ZERO32:
        for j in range(n_far):
            dx = far[F_X, j] - px
            dy = far[F_Y, j] - py
            dz = far[F_Z, j] - pz
            f, b = far_pair_gated(far, j, dx, dy, dz, dx * dx + dy * dy + dz * dz, px, py, pz,
                                  nx, ny, nz, has_normal, measure, gate)
            front += f
            back += b
        return front, back
    for j in range(n_far):
        dx = far[F_X, j] - px
        dy = far[F_Y, j] - py
        dz = far[F_Z, j] - pz
        f, b = far_pair(far, j, dx, dy, dz, dx * dx + dy * dy + dz * dz, nx, ny, nz, has_normal, measure)
        front += f
        back += b
    return front, back


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def level_weight(near, j, r2, t0, t1, t2, t3, t4, t5):
    """Area x weight of near-list emitter j at the weight level of ``r2`` (the N_BINS
    ascending float32 thresholds t0..t5). Written out as a chain of selects on scalars
    so the caller's loop still vectorises (a loop over the levels, or reads of a
    threshold array inside the loop, do not)."""
    wa = near[S_WA, j]
    wa = near[S_WA + 1, j] if r2 >= t0 else wa
    wa = near[S_WA + 2, j] if r2 >= t1 else wa
    wa = near[S_WA + 3, j] if r2 >= t2 else wa
    wa = near[S_WA + 4, j] if r2 >= t3 else wa
    wa = near[S_WA + 5, j] if r2 >= t4 else wa
    wa = near[S_WA + 6, j] if r2 >= t5 else wa
    return wa


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, has_normal, gate):
    """Area x gated weight of near-list emitter j: ``A - (A - wa) g`` (``bunnell.gate_factor``
    of its occluder centroid)."""
    g = gate32(near[S_O, j], near[S_O + 1, j], near[S_O + 2, j], px, py, pz, nx, ny, nz, r2,
               gate, has_normal)
    return near[S_A, j] - (near[S_A, j] - wa) * g


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def near_weight(near, j, r2, wr2, px, py, pz, nx, ny, nz, has_normal, gate):
    """Area x weight of near-list emitter j at distance^2 ``r2`` (leveled passes), gated
    when ``gate > 0``; not for vectorised loops (reads the thresholds array)."""
    wa = level_weight(near, j, r2, wr2[0], wr2[1], wr2[2], wr2[3], wr2[4], wr2[5])
    if gate > ZERO32:
        wa = gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, has_normal, gate)
    return wa


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def near_pair(near, j, dx, dy, dz, r2, wr2, px, py, pz, nx, ny, nz, has_normal, measure, gate,
              max_d2, min_d2):
    """(front, back) of near-list disk j at the receiver (any measure, with or without a
    normal; weight from :func:`near_weight`); 0 when coincident, beyond the maximum
    distance or inside the inner radius. Branches: for the loops that do not vectorise
    anyway, and the near-field swap."""
    a = near[S_A, j]
    if r2 <= np.float32(COINCIDENT_REL) * a or r2 > max_d2 or r2 < min_d2:
        return ZERO32, ZERO32
    wa = near_weight(near, j, r2, wr2, px, py, pz, nx, ny, nz, has_normal, gate)
    return disk_pair32(
        dx, dy, dz, r2, near[S_MX, j], near[S_MY, j], near[S_MZ, j], wa, a, nx, ny, nz,
        has_normal, measure,
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2):
    """(front, back) of near-list disk j for a receiver with a normal, cosine measure
    (``disk_pair32`` spelled out with selects: a branch would stop the caller's loop
    from vectorising); 0 when coincident, beyond the maximum distance or inside the
    inner radius."""
    a = near[S_A, j]
    e = -(near[S_MX, j] * dx + near[S_MY, j] * dy + near[S_MZ, j] * dz)
    g = max(nx * dx + ny * dy + nz * dz, ZERO32)
    c = wa * g / (r2 * (PI32 * r2 + a))
    skip = (r2 <= np.float32(COINCIDENT_REL) * a) | (r2 > max_d2) | (r2 < min_d2)
    c = ZERO32 if skip else c
    return c * max(e, ZERO32), c * max(-e, ZERO32)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def near_disk_sums(near, n_near, px, py, pz, nx, ny, nz, has_normal, measure, max_d2, min_d2, wr2,
                   leveled, gate):
    """(front, back) of the near list's disks at one receiver, near-field ones included
    (the caller swaps those for their cells).

    Skips coincident disks, disks beyond the maximum distance and inside the inner
    radius with selects, not branches. The receiver's own disk needs no test of the
    index: the receiver sits above its vertex along n, so its own disk and every disk at
    the same position have ``n.d < 0`` and a zero term (a receiver without a normal sits
    on its vertex: coincident); a receiver moved aside at a contact has its own disk
    removed with the near-field candidates. The loop vectorises (16 float32 lanes with AVX-512).
    ``leveled``: the weights differ between levels (passes >= 2); ``gate > 0``: they are
    gated (:func:`gated_weight`).
    """
    front = ZERO32
    back = ZERO32
    t0, t1, t2, t3, t4, t5 = wr2[0], wr2[1], wr2[2], wr2[3], wr2[4], wr2[5]
    if measure == MEASURE_COSINE and has_normal and not leveled:
        # pass 1: one weight for every level
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            f, b = cosine_pair(near, j, dx, dy, dz, r2, near[S_WA, j], nx, ny, nz, max_d2, min_d2)
            front += f
            back += b
        return front, back
    if measure == MEASURE_COSINE and has_normal and gate > ZERO32:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
            wa = gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, has_normal, gate)
            f, b = cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2)
            front += f
            back += b
        return front, back
    if measure == MEASURE_COSINE and has_normal:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
            f, b = cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2)
            front += f
            back += b
        return front, back
    for j in range(n_near):
        dx = near[S_X, j] - px
        dy = near[S_Y, j] - py
        dz = near[S_Z, j] - pz
        r2 = dx * dx + dy * dy + dz * dz
        f, b = near_pair(near, j, dx, dy, dz, r2, wr2, px, py, pz, nx, ny, nz, has_normal,
                         measure, gate, max_d2, min_d2)
        front += f
        back += b
    return front, back


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def tents(dx, dy, dz, d2, frame, nx, ny, nz):
    """``(up, low, (a_0 .. a_7))``: the band shares and every sector's share of direction
    d (``bunnell.sector_coords``: the pole share evenly, the rest by ``bunnell.tent``;
    most are 0 away from the normal), as scalars."""
    up, low, q, pole = sector_coords(dx, dy, dz, d2, frame, nx, ny, nz)
    one = np.float32(1.0)
    e = pole * np.float32(1.0 / SECTORS)
    s = one - pole
    # bunnell.tent spelled out: only sectors 0 and 7 wrap round (q in [0, 8))
    a = (
        s * max(one - min(abs(q - np.float32(0.5)), np.float32(8.5) - q), ZERO32) + e,
        s * max(one - abs(q - np.float32(1.5)), ZERO32) + e,
        s * max(one - abs(q - np.float32(2.5)), ZERO32) + e,
        s * max(one - abs(q - np.float32(3.5)), ZERO32) + e,
        s * max(one - abs(q - np.float32(4.5)), ZERO32) + e,
        s * max(one - abs(q - np.float32(5.5)), ZERO32) + e,
        s * max(one - abs(q - np.float32(6.5)), ZERO32) + e,
        s * max(one - min(abs(q - np.float32(7.5)), q + np.float32(0.5)), ZERO32) + e,
    )
    return up, low, a


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def dir_add(acc, v, up, low, a):
    """One side's term v added to its 16 direction accumulators (upper band sectors
    0..7, then the lower band), spread as ``bunnell.add_directions`` spreads it; a tuple
    of scalars, so the callers' loops vectorise."""
    u = v * up
    lo = v * low
    return (
        acc[0] + u * a[0], acc[1] + u * a[1], acc[2] + u * a[2], acc[3] + u * a[3], acc[4] + u * a[4], acc[5] + u * a[5], acc[6] + u * a[6], acc[7] + u * a[7],
        acc[8] + lo * a[0], acc[9] + lo * a[1], acc[10] + lo * a[2], acc[11] + lo * a[3], acc[12] + lo * a[4], acc[13] + lo * a[5], acc[14] + lo * a[6], acc[15] + lo * a[7],
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def dir_term(sf, sb, wf, wb, f, b, area, dx, dy, dz, d2, frame, nx, ny, nz):
    """One (front, back) term of an emitter of area A in direction d added to the
    direction accumulators ``sf``, ``sb`` (:func:`dir_add`), or whole to ``wf``, ``wb``
    when it is too wide to bin (``bunnell.is_wide``); selects only."""
    z = ZERO32
    wide = is_wide(area, d2)
    wf += f if wide else z
    wb += b if wide else z
    f = z if wide else f
    b = z if wide else b
    up, low, a = tents(dx, dy, dz, d2, frame, nx, ny, nz)
    return dir_add(sf, f, up, low, a), dir_add(sb, b, up, low, a), wf, wb


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def direction_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2, wr2,
                   leveled, gate, dirs):
    """The terms of :func:`near_disk_sums` and :func:`far_sums` for a receiver with a
    normal (cosine measure), by direction, into ``dirs`` (2, 17) (:func:`dir_add`, far
    nodes by their centre; wide ones, ``bunnell.is_wide``, whole into column 16). The accumulators are scalars and each case has a loop of its
    own, so they vectorise (one loop with a select on ``leveled`` took 2.7 instead of
    2.25 s per pass at 700k, theta 4)."""
    t0, t1, t2, t3, t4, t5 = wr2[0], wr2[1], wr2[2], wr2[3], wr2[4], wr2[5]
    z = ZERO32
    sf = (z, z, z, z, z, z, z, z, z, z, z, z, z, z, z, z)
    sb = sf
    wf = z  # wide terms (bunnell.is_wide): not binned
    wb = z
    if not leveled:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            f, b = cosine_pair(near, j, dx, dy, dz, r2, near[S_WA, j], nx, ny, nz, max_d2, min_d2)
            sf, sb, wf, wb = dir_term(sf, sb, wf, wb, f, b, near[S_A, j], dx, dy, dz, r2, frame,
                                      nx, ny, nz)
    elif gate > ZERO32:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
            wa = gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, True, gate)
            f, b = cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2)
            sf, sb, wf, wb = dir_term(sf, sb, wf, wb, f, b, near[S_A, j], dx, dy, dz, r2, frame,
                                      nx, ny, nz)
    else:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            r2 = dx * dx + dy * dy + dz * dz
            wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
            f, b = cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2)
            sf, sb, wf, wb = dir_term(sf, sb, wf, wb, f, b, near[S_A, j], dx, dy, dz, r2, frame,
                                      nx, ny, nz)
    if gate > ZERO32:
        for j in range(n_far):
            dx = far[F_X, j] - px
            dy = far[F_Y, j] - py
            dz = far[F_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            f, b = far_pair_gated(far, j, dx, dy, dz, d2, px, py, pz, nx, ny, nz, True,
                                  MEASURE_COSINE, gate)
            sf, sb, wf, wb = dir_term(sf, sb, wf, wb, f, b, far[F_WA, j], dx, dy, dz, d2, frame,
                                      nx, ny, nz)
    else:
        for j in range(n_far):
            dx = far[F_X, j] - px
            dy = far[F_Y, j] - py
            dz = far[F_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            f, b = far_pair(far, j, dx, dy, dz, d2, nx, ny, nz, True, MEASURE_COSINE)
            sf, sb, wf, wb = dir_term(sf, sb, wf, wb, f, b, far[F_WA, j], dx, dy, dz, d2, frame,
                                      nx, ny, nz)
    for k in range(2 * SECTORS):
        dirs[0, k] = sf[k]
        dirs[1, k] = sb[k]
    dirs[0, 2 * SECTORS] = wf
    dirs[1, 2 * SECTORS] = wb


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def bin_add(acc, f, b, d2, dx, dy, dz, r0, r1, r2, r3, r4):
    """One term added to the binned accumulators ``acc`` (15 float32: front per bin,
    back per bin, then the first moment): bin k takes it when ``d2 < r_k`` (the last bin
    always). A tuple of scalars, so the callers' loops still vectorise."""
    m0 = np.float32(d2 < r0)
    m1 = np.float32(d2 < r1)
    m2 = np.float32(d2 < r2)
    m3 = np.float32(d2 < r3)
    m4 = np.float32(d2 < r4)
    t = f + b
    return (
        acc[0] + f * m0, acc[1] + f * m1, acc[2] + f * m2, acc[3] + f * m3, acc[4] + f * m4,
        acc[5] + f,
        acc[6] + b * m0, acc[7] + b * m1, acc[8] + b * m2, acc[9] + b * m3, acc[10] + b * m4,
        acc[11] + b,
        acc[12] + t * dx, acc[13] + t * dy, acc[14] + t * dz,
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def binned_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, has_normal, measure, max_d2,
                min_d2, wr2, br2, leveled, gate, acc, first):
    """Like :func:`near_disk_sums` plus :func:`far_sums`, but cumulative by distance:
    ``acc[side, b] += term`` for every bin b with ``r^2 < br2[b]`` (the last bin takes
    everything; far nodes by their centre's distance), and ``first += (front + back
    term) d`` (d: emitter - receiver). The accumulators are scalars (:func:`bin_add`)
    and each case has a loop of its own, so they vectorise."""
    t0, t1, t2, t3, t4, t5 = wr2[0], wr2[1], wr2[2], wr2[3], wr2[4], wr2[5]
    r0, r1, r2_, r3, r4 = br2[0], br2[1], br2[2], br2[3], br2[4]
    z = ZERO32
    s = (z, z, z, z, z, z, z, z, z, z, z, z, z, z, z)
    if measure == MEASURE_COSINE and has_normal and gate == ZERO32:
        # gated passes take the loop below (a branch in this one stops vectorisation)
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            # thresholds are inf without levels: level 0, and the loads are never used
            wa = level_weight(near, j, d2, t0, t1, t2, t3, t4, t5) if leveled else near[S_WA, j]
            f, b = cosine_pair(near, j, dx, dy, dz, d2, wa, nx, ny, nz, max_d2, min_d2)
            s = bin_add(s, f, b, d2, dx, dy, dz, r0, r1, r2_, r3, r4)
    else:
        for j in range(n_near):
            dx = near[S_X, j] - px
            dy = near[S_Y, j] - py
            dz = near[S_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            f, b = near_pair(near, j, dx, dy, dz, d2, wr2, px, py, pz, nx, ny, nz, has_normal,
                             measure, gate, max_d2, min_d2)
            s = bin_add(s, f, b, d2, dx, dy, dz, r0, r1, r2_, r3, r4)
    # one loop per case: a branch inside would stop vectorisation
    if gate > ZERO32:
        for j in range(n_far):
            dx = far[F_X, j] - px
            dy = far[F_Y, j] - py
            dz = far[F_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            f, b = far_pair_gated(far, j, dx, dy, dz, d2, px, py, pz, nx, ny, nz, has_normal,
                                  measure, gate)
            s = bin_add(s, f, b, d2, dx, dy, dz, r0, r1, r2_, r3, r4)
    else:
        for j in range(n_far):
            dx = far[F_X, j] - px
            dy = far[F_Y, j] - py
            dz = far[F_Z, j] - pz
            d2 = dx * dx + dy * dy + dz * dz
            f, b = far_pair(far, j, dx, dy, dz, d2, nx, ny, nz, has_normal, measure)
            s = bin_add(s, f, b, d2, dx, dy, dz, r0, r1, r2_, r3, r4)
    for k in range(6):
        acc[0, k] += s[k]
        acc[1, k] += s[6 + k]
    first[0] += s[12]
    first[1] += s[13]
    first[2] += s[14]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def add_cumulative(acc, f, b, r2, br2, binned):
    """``acc[:, k] += (f, b)`` for every bin k the distance ``r2`` falls inside (all bins
    from its own on), or the last bin only when not ``binned``."""
    last = br2.shape[0] - 1
    k = min(level_of(r2, br2), last) if binned else last
    for kk in range(k, last + 1):
        acc[0, kk] += f
        acc[1, kk] += b


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def hierarchy_pass(tree, emitters, receivers, near_field, buckets, span, options, out, first,
                   fill):
    """Tree sums for the receivers of buckets ``span[0]:span[1]``: like
    ``bunnell.brute_force_pass``, far clusters count as one emitter.

    Each bucket (a few nearby receivers) walks the tree once (:func:`gather`); then each
    of its receivers sums the far list (:func:`far_sums`), the near list's disks
    (:func:`near_disk_sums`) and, for the near list's emitters with ``r^2 < near A``,
    swaps the disk for its barycentric cell in float64 (``polygon.cell_terms``). With
    per-direction saturation, a receiver whose front or back sum exceeds one direction
    bin's measure also bins the same terms by direction (:func:`direction_sums`; the
    swapped disks leave their bins too) and its total loses the bins' excess
    (``bunnell.direction_excess``). The lists are float32 rows in per-thread scratch; each receiver's result depends only
    on its bucket, so the output is identical for any thread count.

    Parameters
    ----------
    tree : tuple
        ``(skip, start, stop, nodes, moments)`` from ``aobake.kernels.hierarchy`` (nodes
        float32; moments (m, N_LEVELS, MOMENT_COLS) float32, refit for this pass).
    emitters : tuple
        ``(rows (k, EMITTER_COLS) float32, index (k,) int64, weights (k, N_LEVELS)
        float32, occluders (k, 3) float32)`` in tree order (occluder centroids: gated
        passes).
    receivers : tuple
        ``(points (n, 3), normals (n, 3), inner (n,), modes (n,) uint8)``: as in
        ``bunnell.brute_force_pass``, and what each receiver computes: 0 nothing (its
        row is left alone), 1 the total only, 2 the sums by distance too when
        ``binned``.
    near_field : tuple
        ``(positions (n, 3), weights (n,), corner_start, corners, reach (n,), cache (n, 2,
        N_BINS), cache_mode)``: float64 vertex positions, the cells' pass weights, the
        cell corners and reaches renumbered to tree order (row k is the emitter at tree
        position k, the other vertices follow; ``polygon.permute_cells``: a bucket's
        cells lie close together in memory; a cell whose vertex lies deeper than its
        reach below the receiver's tangent plane is skipped), and a cache of each receiver's cell sums (cumulative by distance bin)
        for passes whose cell weights do not change: mode 0 ignores it, 1 writes it,
        2 reads it instead of evaluating the cells again.
    buckets : tuple
        ``(order (n,), bucket_start (nb + 1,), bounds (nb, BOUND_COLS), near_buf, near_idx,
        far_buf)``: receivers in bucket order, bucket ranges and bounds
        (:func:`bucket_bounds`), and scratch ``(T, NEAR_ROWS, k)`` float32,
        ``(T, 2, k)`` int64, ``(T, FAR_ROWS, m)`` float32 for T >= the number of numba
        threads.
    span : tuple
        ``(b0, b1, T)``: compute buckets b0..b1 - 1 on T threads (``numba.get_num_threads()``:
        a call inside the kernel would stop it from being cached), each taking every
        T-th block of SCHEDULE_BLOCK buckets.
    options : tuple
        ``(measure, max_distance, near, binned, bin_r2, weight_r2, leveled, gate,
        directional)`` as in ``bunnell.brute_force_pass``; ``leveled``: the weights differ
        between levels (the gate applies only then).
    out : (n, 2, N_BINS) float64
        (front, back) sums, cumulative by distance bin when ``binned`` (else only the
        last bin, the total, is written), as in ``bunnell.brute_force_pass`` (the total
        less the direction excess); each receiver writes its own row.
    first : (n, 4) float64
        When ``binned`` and ``cache_mode != 2``: as in ``bunnell.brute_force_pass``.
    fill : tuple
        ``(store, slot, mode)`` as in ``bunnell.brute_force_pass``; a receiver with a slot
        bins by direction even where its sums could not overflow a bin.
    """
    positions, cell_weights, corner_start, corners, reach, cache, cache_mode = near_field
    index = emitters[1]
    points, normals, inner, modes = receivers
    order, bucket_start, bounds, near_buf, near_idx, far_buf = buckets
    measure, max_distance, near, binned, bin_r2, weight_r2, leveled, gate, directional = options
    gate_ = np.float32(gate) if leveled else ZERO32
    max_d2 = np.float32(min(max_distance * max_distance, 3.0e38))
    # without levels only level 0 is gathered: thresholds no distance reaches
    wr2 = weight_r2.astype(np.float32) if leveled else np.full(weight_r2.shape[0], np.inf, np.float32)
    br2 = bin_r2.astype(np.float32)
    last = bin_r2.shape[0] - 1
    cap = 0.5 / SECTORS  # one direction bin's measure
    store, slot, fill_mode = fill
    # numba gives each thread one contiguous share of the range, and a bucket's cost
    # follows the geometry: each thread takes every T-th block of SCHEDULE_BLOCK
    # neighbouring buckets instead (cyclic), so every share samples the whole span
    b0, b1, n_threads = span
    n_blocks = (b1 - b0 + SCHEDULE_BLOCK - 1) // SCHEDULE_BLOCK
    per_thread = (n_blocks + n_threads - 1) // n_threads * SCHEDULE_BLOCK
    for w in prange(n_threads):
        # this thread's scratch, reused for all its buckets (every use overwrites it)
        tid = numba.get_thread_id()
        nb = near_buf[tid]
        ni = near_idx[tid]
        fb = far_buf[tid]
        quad = np.empty((4, 3))
        acc = np.zeros((2, last + 1))
        fst = np.zeros(3)
        dirs = np.zeros((2, 2 * SECTORS + 1))
        for c in range(per_thread):
            bk = b0 + (w + c // SCHEDULE_BLOCK * n_threads) * SCHEDULE_BLOCK + c % SCHEDULE_BLOCK
            if bk >= b1:
                break
            n_near, n_cand, n_far = gather(
                tree, emitters, bounds[bk], (max_distance, near, weight_r2, leveled, gate), nb, ni, fb
            )
            binned_before = False  # the last receiver of this bucket with a normal had to bin
            for q in range(bucket_start[bk], bucket_start[bk + 1]):
                i = order[q]
                if modes[i] == 0:
                    continue
                px = points[i, 0]
                py = points[i, 1]
                pz = points[i, 2]
                nx = normals[i, 0]
                ny = normals[i, 1]
                nz = normals[i, 2]
                has_normal = nx * nx + ny * ny + nz * nz > 0.0
                binned_i = binned and modes[i] == 2
                min_d2 = inner[i] * inner[i]
                px32 = np.float32(px)
                py32 = np.float32(py)
                pz32 = np.float32(pz)
                nx32 = np.float32(nx)
                ny32 = np.float32(ny)
                nz32 = np.float32(nz)
                acc[:] = 0.0
                fst[:] = 0.0
                can_bin = directional and has_normal and measure == MEASURE_COSINE
                fr = tangent_frame(nx, ny, nz) if has_normal else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                frame = (np.float32(fr[0]), np.float32(fr[1]), np.float32(fr[2]), np.float32(fr[3]),
                         np.float32(fr[4]), np.float32(fr[5]))
                # per-direction saturation: the binned terms are a subset of the plain sums'
                # (non-negative) terms, so where neither side's sum reaches one bin's measure
                # no bin can overflow and the (costlier) binned loops are skipped: exact. The
                # plain sums that decide it are skipped in turn after a neighbour in the bucket
                # had to bin (the bins then give the totals): the same result either way.
                binning = can_bin and binned_before
                if binning:
                    direction_sums(nb, n_near, fb, n_far, px32, py32, pz32, nx32, ny32, nz32, frame,
                                   max_d2, np.float32(min_d2), wr2, leveled, gate_, dirs)
                    if not binned_i:
                        acc[0, last] = dirs[0].sum()  # the bins and the wide terms
                        acc[1, last] = dirs[1].sum()
                if binned_i:
                    binned_sums(nb, n_near, fb, n_far, px32, py32, pz32, nx32, ny32, nz32, has_normal,
                                measure, max_d2, np.float32(min_d2), wr2, br2, leveled, gate_, acc,
                                fst)
                elif not binning:
                    f1, b1_ = far_sums(fb, n_far, px32, py32, pz32, nx32, ny32, nz32, has_normal, measure,
                                       gate_)
                    f2, b2 = near_disk_sums(
                        nb, n_near, px32, py32, pz32, nx32, ny32, nz32, has_normal, measure, max_d2,
                        np.float32(min_d2), wr2, leveled, gate_,
                    )
                    acc[0, last] = np.float64(f1) + np.float64(f2)
                    acc[1, last] = np.float64(b1_) + np.float64(b2)
                row = slot[i]  # >= 0: keeps or reads its bins
                if can_bin and not binning and (max(acc[0, last], acc[1, last]) > cap or row >= 0):
                    binning = True
                    direction_sums(nb, n_near, fb, n_far, px32, py32, pz32, nx32, ny32, nz32, frame,
                                   max_d2, np.float32(min_d2), wr2, leveled, gate_, dirs)
                if can_bin:
                    binned_before = binning
                if has_normal:
                    # near-field emitters: swap the disk (as summed above) for the cell
                    for u in range(n_cand):
                        t = ni[1, u]
                        j = ni[0, t]  # tree position: the near-field arrays are in tree order
                        # the receiver's own disk: summed above unless the receiver sits
                        # straight above its vertex (a contact moves it aside), removed here
                        own = index[j] == i
                        if not own and not is_near(
                            nb[S_X, t], nb[S_Y, t], nb[S_Z, t], nb[S_A, t], px, py, pz, near
                        ):
                            continue
                        dx = positions[j, 0] - px
                        dy = positions[j, 1] - py
                        dz = positions[j, 2] - pz
                        r2_64 = dx * dx + dy * dy + dz * dz
                        if r2_64 > max_distance * max_distance or r2_64 < min_d2:
                            continue
                        ex = nb[S_X, t] - px32
                        ey = nb[S_Y, t] - py32
                        ez = nb[S_Z, t] - pz32
                        r2 = ex * ex + ey * ey + ez * ez
                        df, db = near_pair(nb, t, ex, ey, ez, r2, wr2, px32, py32, pz32, nx32, ny32,
                                           nz32, has_normal, measure, gate_, max_d2,
                                           np.float32(min_d2))
                        if binning:  # and its share of the direction bins
                            add_directions(dirs, -df, -db, nb[S_A, t], ex, ey, ez, r2, frame, nx32, ny32,
                                           nz32)
                        if binned_i:  # the disk's share of the first moment goes with it
                            both = np.float64(df) + np.float64(db)
                            fst[0] -= both * ex
                            fst[1] -= both * ey
                            fst[2] -= both * ez
                        # a cell wholly below the tangent plane: cell_terms would give 0
                        below = (nx * dx + ny * dy + nz * dz) < -reach[j] * (1.0 + CELL_SLACK)
                        if own or cache_mode == 2 or below:
                            add_cumulative(acc, -np.float64(df), -np.float64(db), r2, br2, binned_i)
                            continue
                        f, bck = cell_terms(
                            positions, corner_start, corners, j, px, py, pz, nx, ny, nz, measure, quad
                        )
                        f *= cell_weights[j]
                        bck *= cell_weights[j]
                        add_cumulative(acc, f - np.float64(df), bck - np.float64(db), r2, br2, binned_i)
                        if binned_i:
                            fst[0] += (f + bck) * dx
                            fst[1] += (f + bck) * dy
                            fst[2] += (f + bck) * dz
                        if cache_mode == 1:
                            add_cumulative(cache[i], f, bck, r2, br2, True)
                    if cache_mode == 2:
                        for k in range(last + 1) if binned_i else range(last, last + 1):
                            acc[0, k] += cache[i, 0, k]
                            acc[1, k] += cache[i, 1, k]
                if binned_i:
                    first[i, 0] = fst[0]
                    first[i, 1] = fst[1]
                    first[i, 2] = fst[2]
                    first[i, 3] = max(acc[0, last], 0.0) + max(acc[1, last], 0.0)
                if binning:
                    acc[0, last] -= direction_excess(dirs, 0)
                    acc[1, last] -= direction_excess(dirs, 1)
                    given = settle_fill(dirs, store, row, fill_mode)
                    acc[0, last] += given[0]
                    acc[1, last] += given[1]
                for k in range(last + 1):
                    # the swap can leave -1 ulp where the sum is 0
                    out[i, 0, k] = max(acc[0, k], 0.0)
                    out[i, 1, k] = max(acc[1, k], 0.0)
