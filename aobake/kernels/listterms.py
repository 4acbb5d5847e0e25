"""Terms of one entry of a bucket's lists at one receiver (float32): far nodes as point
emitters with moments, near-list disks with their pass weights.

The ``*_term`` functions share one signature, ``(buf, j, dx, dy, dz, r2, at)`` with
``at`` a ``listsums.Site``, so one loop (``listsums.sum_list``) sums any of them.
Imports numpy, numba and ``aobake.constants`` only; symbols as in ``aobake.kernels.bunnell``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from aobake.constants import COINCIDENT_REL, MEASURE_COSINE

from .bunnell import HALF32, N_BINS, NO_NORMAL_COSINE, NO_NORMAL_UNIFORM, PI32, ZERO32, disk_pair32
from .treewalk import (
    F_LEVEL0,
    F_NX,
    F_NY,
    F_NZ,
    F_OX,
    F_OY,
    F_OZ,
    F_TXX,
    F_TXY,
    F_TXZ,
    F_TYY,
    F_TYZ,
    F_TZZ,
    F_WA,
    S_A,
    S_MX,
    S_MY,
    S_MZ,
    S_O,
    S_WA,
)

# level_weight spells out the select chain for this many bins
assert N_BINS == 6, "update level_weight and listsums.bin_add for the new PASS_RADII"


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def far_pair(far, j, dx, dy, dz, d2, nx, ny, nz, has_normal, measure):
    """(front, back) of far-list node j (:func:`far_terms` on its moments)."""
    return far_terms(
        far[F_WA, j], far[F_NX, j], far[F_NY, j], far[F_NZ, j], far[F_TXX, j], far[F_TYY, j],
        far[F_TZZ, j], far[F_TXY, j], far[F_TXZ, j], far[F_TYZ, j], dx, dy, dz, d2, nx, ny, nz,
        has_normal, measure,
    )


@njit(cache=True, error_model="numpy", inline="always")
def gate32(ox, oy, oz, px, py, pz, nx, ny, nz, d2, gate, has_normal):
    """float32 ``bunnell.gate_factor`` from the squared distance ``d2``."""
    h = nx * (ox - px) + ny * (oy - py) + nz * (oz - pz)
    g = min(max(h / (gate * np.sqrt(d2)), ZERO32), np.float32(1.0))
    return g if has_normal else np.float32(1.0)


@njit(cache=True, error_model="numpy", inline="always")
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



@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, has_normal, gate):
    """Area x gated weight of near-list emitter j: ``A - (A - wa) g`` (``bunnell.gate_factor``
    of its occluder centroid)."""
    g = gate32(near[S_O, j], near[S_O + 1, j], near[S_O + 2, j], px, py, pz, nx, ny, nz, r2,
               gate, has_normal)
    return near[S_A, j] - (near[S_A, j] - wa) * g


@njit(cache=True, error_model="numpy", inline="always")
def near_weight(near, j, r2, t, px, py, pz, nx, ny, nz, has_normal, gate):
    """Area x weight of near-list emitter j at distance^2 ``r2`` (leveled passes; ``t``:
    the N_BINS float32 level thresholds), gated when ``gate > 0``; branches."""
    wa = level_weight(near, j, r2, t[0], t[1], t[2], t[3], t[4], t[5])
    if gate > ZERO32:
        wa = gated_weight(near, j, r2, wa, px, py, pz, nx, ny, nz, has_normal, gate)
    return wa


@njit(cache=True, error_model="numpy", inline="always")
def near_pair(near, j, dx, dy, dz, r2, t, px, py, pz, nx, ny, nz, has_normal, measure, gate,
              max_d2, min_d2):
    """(front, back) of near-list disk j at the receiver (any measure, with or without a
    normal; weight from :func:`near_weight`); 0 when coincident, beyond the maximum
    distance or inside the inner radius. Branches: for the loops that do not vectorise
    anyway, and the near-field swap."""
    a = near[S_A, j]
    if r2 <= np.float32(COINCIDENT_REL) * a or r2 > max_d2 or r2 < min_d2:
        return ZERO32, ZERO32
    wa = near_weight(near, j, r2, t, px, py, pz, nx, ny, nz, has_normal, gate)
    return disk_pair32(
        dx, dy, dz, r2, near[S_MX, j], near[S_MY, j], near[S_MZ, j], wa, a, nx, ny, nz,
        has_normal, measure,
    )


@njit(cache=True, error_model="numpy", inline="always")
def cosine_pair(near, j, dx, dy, dz, r2, wa, nx, ny, nz, max_d2, min_d2):
    """(front, back) of near-list disk j for a receiver with a normal, cosine measure
    (``disk_pair32`` spelled out with selects: a branch would stop the caller's loop
    from vectorising); 0 when coincident, beyond the maximum distance or inside the
    inner radius."""
    a = near[S_A, j]
    e = -(near[S_MX, j] * dx + near[S_MY, j] * dy + near[S_MZ, j] * dz)
    g = max(nx * dx + ny * dy + nz * dz, ZERO32)
    den = r2 * (PI32 * r2 + a)
    c = wa * g / den
    # den underflows to 0 in float32 for disks ~1e-9 of the scene with the receiver on
    # top (its own disk, g = 0): 0 / 0 must not become NaN
    skip = (r2 <= np.float32(COINCIDENT_REL) * a) | (r2 > max_d2) | (r2 < min_d2) | (den <= ZERO32)
    c = ZERO32 if skip else c
    return c * max(e, ZERO32), c * max(-e, ZERO32)


# ---------------------------------------------------------------------------------------
# one signature for every list term: (buf, j, d, r2, at) -> (front, back)


@njit(cache=True, error_model="numpy", inline="always")
def far_node_term(far, j, dx, dy, dz, r2, at):
    """:func:`far_pair` of far-list node j."""
    return far_pair(far, j, dx, dy, dz, r2, at.nx, at.ny, at.nz, at.has_normal, at.measure)


@njit(cache=True, error_model="numpy", inline="always")
def gated_far_term(far, j, dx, dy, dz, r2, at):
    """:func:`far_pair_gated` of far-list node j."""
    return far_pair_gated(far, j, dx, dy, dz, r2, at.px, at.py, at.pz, at.nx, at.ny, at.nz,
                          at.has_normal, at.measure, at.gate)


@njit(cache=True, error_model="numpy", inline="always")
def disk_term(near, j, dx, dy, dz, r2, at):
    """:func:`near_pair` of near-list disk j (any measure and weights; branches)."""
    return near_pair(near, j, dx, dy, dz, r2, at.thresholds, at.px, at.py, at.pz, at.nx, at.ny, at.nz,
                     at.has_normal, at.measure, at.gate, at.max_d2, at.min_d2)


@njit(cache=True, error_model="numpy", inline="always")
def flat_cosine_term(near, j, dx, dy, dz, r2, at):
    """:func:`cosine_pair` of near-list disk j with its level-0 weight (pass 1)."""
    return cosine_pair(near, j, dx, dy, dz, r2, near[S_WA, j], at.nx, at.ny, at.nz, at.max_d2,
                       at.min_d2)


@njit(cache=True, error_model="numpy", inline="always")
def leveled_cosine_term(near, j, dx, dy, dz, r2, at):
    """:func:`cosine_pair` of near-list disk j with the weight of its level."""
    t0, t1, t2, t3, t4, t5 = at.thresholds
    wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
    return cosine_pair(near, j, dx, dy, dz, r2, wa, at.nx, at.ny, at.nz, at.max_d2, at.min_d2)


@njit(cache=True, error_model="numpy", inline="always")
def gated_cosine_term(near, j, dx, dy, dz, r2, at):
    """:func:`cosine_pair` of near-list disk j with the gated weight of its level."""
    t0, t1, t2, t3, t4, t5 = at.thresholds
    wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5)
    wa = gated_weight(near, j, r2, wa, at.px, at.py, at.pz, at.nx, at.ny, at.nz, at.has_normal,
                      at.gate)
    return cosine_pair(near, j, dx, dy, dz, r2, wa, at.nx, at.ny, at.nz, at.max_d2, at.min_d2)


@njit(cache=True, error_model="numpy", inline="always")
def select_cosine_term(near, j, dx, dy, dz, r2, at):
    """:func:`cosine_pair` of near-list disk j, its level chosen by a select on
    ``at.leveled`` (thresholds are inf without levels: level 0, the loads unused)."""
    t0, t1, t2, t3, t4, t5 = at.thresholds
    wa = level_weight(near, j, r2, t0, t1, t2, t3, t4, t5) if at.leveled else near[S_WA, j]
    return cosine_pair(near, j, dx, dy, dz, r2, wa, at.nx, at.ny, at.nz, at.max_d2, at.min_d2)
