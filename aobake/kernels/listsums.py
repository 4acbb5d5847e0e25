"""Sums of a bucket's lists at one receiver (float32, vectorised loops): the totals,
the totals by direction bin, and the totals by distance bin.

One loop, :func:`sum_list`, serves every case: it takes the term of one entry (a
``listterms.*_term``) and the accumulator update (``add_*``) as compile-time function
arguments, so each case still compiles to a loop of its own without a branch inside
(a branch would stop vectorisation). Accumulators are tuples of scalars for the same
reason. Imports numpy, numba and ``aobake.constants`` only.

numba caches each kernel by its own file's time stamp: the ``listterms`` and
``bunnell`` terms inlined here do not invalidate it, so after changing them, touch
this file (or delete ``__pycache__``) or stale machine code keeps running.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from aobake.constants import FASTMATH, MEASURE_COSINE

from .bunnell import SECTORS, ZERO32, is_wide, sector_coords
from .listterms import (
    disk_term,
    far_node_term,
    flat_cosine_term,
    gated_cosine_term,
    gated_far_term,
    leveled_cosine_term,
    select_cosine_term,
)
from .treewalk import F_WA, F_X, F_Y, F_Z, S_A, S_X, S_Y, S_Z

assert (S_X, S_Y, S_Z) == (F_X, F_Y, F_Z), "sum_list reads both lists' centres from the same rows"


class Site(NamedTuple):
    """One receiver as the list terms see it (built inside the kernels, float32)."""

    px: np.float32
    py: np.float32
    pz: np.float32
    nx: np.float32
    ny: np.float32
    nz: np.float32
    has_normal: bool
    measure: int
    #: gate width, 0 unless the pass is leveled and gated
    gate: np.float32
    max_d2: np.float32
    min_d2: np.float32
    #: the weights differ between levels
    leveled: bool
    #: the N_BINS float32 weight-level thresholds (inf without levels), as scalars: no
    #: array in the loops (a read inside stops vectorisation, a reference costs counting)
    thresholds: tuple


@njit(cache=True, error_model="numpy", inline="always")
def site(px, py, pz, nx, ny, nz, has_normal, measure, gate, max_d2, min_d2, leveled, wr2):
    """:class:`Site` of a receiver (``wr2``: the (N_BINS,) float32 level thresholds)."""
    return Site(px, py, pz, nx, ny, nz, has_normal, measure, gate, max_d2, min_d2, leveled,
                (wr2[0], wr2[1], wr2[2], wr2[3], wr2[4], wr2[5]))


@njit(cache=True, error_model="numpy", inline="always")
def sum_list(buf, n, at, term, add, acc, how):
    """``acc`` after ``add(acc, f, b, buf, j, d, r2, how)`` for the term ``(f, b) =
    term(buf, j, d, r2, at)`` of every list entry j < n (d: entry - receiver). The near
    and far lists keep their centre in the same rows."""
    for j in range(n):
        dx = buf[S_X, j] - at.px
        dy = buf[S_Y, j] - at.py
        dz = buf[S_Z, j] - at.pz
        r2 = dx * dx + dy * dy + dz * dz
        f, b = term(buf, j, dx, dy, dz, r2, at)
        acc = add(acc, f, b, buf, j, dx, dy, dz, r2, how)
    return acc


@njit(cache=True, error_model="numpy", inline="always")
def sum_far(far, n_far, at, add, acc, how):
    """:func:`sum_list` over the far list (gated moments when ``at.gate > 0``)."""
    if at.gate > ZERO32:
        return sum_list(far, n_far, at, gated_far_term, add, acc, how)
    return sum_list(far, n_far, at, far_node_term, add, acc, how)


@njit(cache=True, error_model="numpy", inline="always")
def sum_near(near, n_near, at, add, acc, how):
    """:func:`sum_list` over the near list's disks, near-field ones included (the caller
    swaps those for their cells), with the term of the case: cosine measure at a
    receiver with a normal in selects (pass 1, leveled, gated), else with branches.

    Coincident disks, disks beyond the maximum distance and inside the inner radius
    give 0. The receiver's own disk needs no test of the index: the receiver sits above
    its vertex along n, so its own disk and every disk at the same position have
    ``n.d < 0`` and a zero term (a receiver without a normal sits on its vertex:
    coincident); a receiver moved aside at a contact has its own disk removed with the
    near-field candidates."""
    if at.measure == MEASURE_COSINE and at.has_normal:
        return sum_near_cosine(near, n_near, at, add, acc, how)
    return sum_list(near, n_near, at, disk_term, add, acc, how)


@njit(cache=True, error_model="numpy", inline="always")
def sum_near_cosine(near, n_near, at, add, acc, how):
    """:func:`sum_near` for a receiver with a normal, cosine measure (no loop for the
    other cases: :func:`direction_sums` compiles only these)."""
    if not at.leveled:
        return sum_list(near, n_near, at, flat_cosine_term, add, acc, how)
    if at.gate > ZERO32:
        return sum_list(near, n_near, at, gated_cosine_term, add, acc, how)
    return sum_list(near, n_near, at, leveled_cosine_term, add, acc, how)


# A pass without weight levels (pass 1: ``at.leveled`` false, ``at.gate`` 0) takes only
# these loops; compiled for it alone (``*_flat``), the kernels skip the loops of levels
# and gates, about half of their compile time.


@njit(cache=True, error_model="numpy", inline="always")
def sum_far_flat(far, n_far, at, add, acc, how):
    """:func:`sum_far` without the gate (``at.gate`` 0)."""
    return sum_list(far, n_far, at, far_node_term, add, acc, how)


@njit(cache=True, error_model="numpy", inline="always")
def sum_near_flat(near, n_near, at, add, acc, how):
    """:func:`sum_near` without levels (``at.leveled`` false)."""
    if at.measure == MEASURE_COSINE and at.has_normal:
        return sum_list(near, n_near, at, flat_cosine_term, add, acc, how)
    return sum_list(near, n_near, at, disk_term, add, acc, how)


@njit(cache=True, error_model="numpy", inline="always")
def sum_near_cosine_flat(near, n_near, at, add, acc, how):
    """:func:`sum_near_cosine` without levels (``at.leveled`` false)."""
    return sum_list(near, n_near, at, flat_cosine_term, add, acc, how)


# ---------------------------------------------------------------------------------------
# totals


@njit(cache=True, error_model="numpy", inline="always")
def add_sides(acc, f, b, buf, j, dx, dy, dz, r2, how):
    """(front, back) totals."""
    return acc[0] + f, acc[1] + b


@njit(cache=True, error_model="numpy", inline="always")
def far_sums(far, n_far, at):
    """(front, back) of the far list at receiver ``at``; vectorises."""
    return sum_far(far, n_far, at, add_sides, (ZERO32, ZERO32), ())


@njit(cache=True, error_model="numpy", inline="always")
def near_disk_sums(near, n_near, at):
    """(front, back) of the near list's disks at receiver ``at`` (:func:`sum_near`); the
    loop vectorises (16 float32 lanes with AVX-512)."""
    return sum_near(near, n_near, at, add_sides, (ZERO32, ZERO32), ())


# ---------------------------------------------------------------------------------------
# by direction (per-direction saturation)


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def add_directed(acc, f, b, buf, j, dx, dy, dz, r2, how):
    """``acc = (sf, sb, wf, wb)`` after :func:`dir_term`; ``how = (row, frame, nx, ny,
    nz)``, ``buf[row, j]`` the entry's area."""
    row, frame, nx, ny, nz = how
    return dir_term(acc[0], acc[1], acc[2], acc[3], f, b, buf[row, j], dx, dy, dz, r2, frame,
                    nx, ny, nz)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def direction_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2, wr2,
                   leveled, gate, dirs):
    """The terms of :func:`near_disk_sums` and :func:`far_sums` for a receiver with a
    normal (cosine measure), by direction, into ``dirs`` (2, 17) (:func:`dir_add`, far
    nodes by their centre; wide ones, ``bunnell.is_wide``, whole into column 16). Each
    case has a loop of its own (:func:`sum_list`): one loop with a select on ``leveled``
    was slower."""
    _direction_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2, wr2,
                    leveled, gate, dirs, sum_near_cosine, sum_far)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def direction_sums_flat(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2,
                        wr2, leveled, gate, dirs):
    """:func:`direction_sums` for a pass without levels (``leveled`` false, ``gate`` 0)."""
    _direction_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2, wr2,
                    leveled, gate, dirs, sum_near_cosine_flat, sum_far_flat)


@njit(cache=True, error_model="numpy", inline="always")
def _direction_sums(near, n_near, far, n_far, px, py, pz, nx, ny, nz, frame, max_d2, min_d2, wr2,
                    leveled, gate, dirs, near_sum, far_sum):
    """The body of :func:`direction_sums`, the list loops ``near_sum`` and ``far_sum``
    compile-time arguments."""
    at = site(px, py, pz, nx, ny, nz, True, MEASURE_COSINE, gate, max_d2, min_d2, leveled, wr2)
    z = ZERO32
    sf = (z, z, z, z, z, z, z, z, z, z, z, z, z, z, z, z)
    acc = (sf, sf, z, z)  # wide terms (bunnell.is_wide) in the last two: not binned
    acc = near_sum(near, n_near, at, add_directed, acc, (S_A, frame, nx, ny, nz))
    sf, sb, wf, wb = far_sum(far, n_far, at, add_directed, acc, (F_WA, frame, nx, ny, nz))
    for k in range(2 * SECTORS):
        dirs[0, k] = sf[k]
        dirs[1, k] = sb[k]
    dirs[0, 2 * SECTORS] = wf
    dirs[1, 2 * SECTORS] = wb


# ---------------------------------------------------------------------------------------
# by distance


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def add_binned(acc, f, b, buf, j, dx, dy, dz, r2, how):
    """:func:`bin_add`; ``how``: the bins' squared radii but the last."""
    r0, r1, r2_, r3, r4 = how
    return bin_add(acc, f, b, r2, dx, dy, dz, r0, r1, r2_, r3, r4)


@njit(cache=True, error_model="numpy", inline="always")
def binned_sums(near, n_near, far, n_far, at, br2, acc, first):
    """Like :func:`near_disk_sums` plus :func:`far_sums`, but cumulative by distance:
    ``acc[side, b] += term`` for every bin b with ``r^2 < br2[b]`` (the last bin takes
    everything; far nodes by their centre's distance), and ``first += (front + back
    term) d`` (d: emitter - receiver). Gated passes take the near list's branching term
    (a select on the gate would stop vectorisation)."""
    _binned_sums(near, n_near, far, n_far, at, br2, acc, first, sum_far)


@njit(cache=True, error_model="numpy", inline="always")
def _binned_sums(near, n_near, far, n_far, at, br2, acc, first, far_sum):
    """The body of :func:`binned_sums`, the far list's loop ``far_sum`` a compile-time
    argument."""
    radii = (br2[0], br2[1], br2[2], br2[3], br2[4])
    z = ZERO32
    s = (z, z, z, z, z, z, z, z, z, z, z, z, z, z, z)
    if at.measure == MEASURE_COSINE and at.has_normal and at.gate == ZERO32:
        s = sum_list(near, n_near, at, select_cosine_term, add_binned, s, radii)
    else:
        s = sum_list(near, n_near, at, disk_term, add_binned, s, radii)
    s = far_sum(far, n_far, at, add_binned, s, radii)
    for k in range(6):
        acc[0, k] += s[k]
        acc[1, k] += s[6 + k]
    first[0] += s[12]
    first[1] += s[13]
    first[2] += s[14]


# ---------------------------------------------------------------------------------------
# a pass without levels, the list sums compiled apart (treepass.thread_share: a fraction
# of the compile time), with fastmath: their loops vectorise


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def far_sums_flat(far, n_far, at):
    """:func:`far_sums` for a pass without levels, not inlined into its caller."""
    return sum_far_flat(far, n_far, at, add_sides, (ZERO32, ZERO32), ())


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def near_disk_sums_flat(near, n_near, at):
    """:func:`near_disk_sums` for a pass without levels, not inlined into its caller."""
    return sum_near_flat(near, n_near, at, add_sides, (ZERO32, ZERO32), ())


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def binned_sums_flat(near, n_near, far, n_far, at, br2, acc, first):
    """:func:`binned_sums` for a pass without levels, not inlined into its caller."""
    _binned_sums(near, n_near, far, n_far, at, br2, acc, first, sum_far_flat)
