"""Compiled loops of the disk method: disk terms and the exact O(n^2) sum (the reference
for the tree pass in ``aobake.kernels.treepass``).

Imports numpy, numba and ``aobake.constants`` only (never trimesh or another aobake module
outside ``kernels``). The pass kernels take the named tuples of
``aobake.kernels.structures``.

Symbols used in every docstring below (same names as the code):

- receiver ``i``: evaluation point ``p`` (the vertex moved NEAR_OFFSET_REL edge lengths
  along its normal, see ``aobake.constants``), unit normal ``n`` (or a zero row);
- emitter ``j``: disk centre ``c`` (the vertex), unit normal ``m``, area ``A``, weight
  ``w`` (1 in pass 1; later, its accessibility from the geometry near it);
- ``d = c - p``, ``r = |d|``; ``cos_e = -m.d / r`` (> 0: the emitter's front side faces
  the receiver), ``cos_r = n.d / r``.

Every kernel returns two unsaturated sums per receiver, ``front`` (emitters whose front
side faces it) and ``back``; the caller combines them (``aobake.methods.bunnell.passes``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import (
    COINCIDENT_REL,
    DIRECTION_SECTORS,
    DIRECTION_WIDE,
    MEASURE_COSINE,
    MEASURE_UNIFORM,
    PASS_RADII,
)

from .polygon import cell_terms
from .warps import frame as tangent_frame

__all__ = [
    "MEASURE_COSINE",
    "MEASURE_UNIFORM",
    "N_BINS",
    "N_LEVELS",
    "add_directions",
    "brute_force_pass",
    "direction_excess",
    "disk_pair32",
    "disk_term",
    "gate_factor",
    "is_near",
    "is_wide",
    "level_of",
    "receiver_at",
    "receiver_factor",
    "sector_coords",
    "tent",
]

# Receiver factor for a vertex without a normal: the mean over all normal directions of
# the receiver's weight, so its occlusion is the normal-averaged one = the occluded
# fraction of the full sphere. Cosine measure: mean of max(cos_r, 0) over the sphere = 1/4.
# Uniform measure: the exact uniform hemisphere weight H(cos_r) averages to 1/2.
NO_NORMAL_COSINE = 0.25
NO_NORMAL_UNIFORM = 0.5

# Distance bins and weight levels (passes >= 2). Every kernel returns its sums split by
# the emitter's distance r from the receiver, when asked to: N_BINS cumulative bins, bin
# b summing the emitters with ``r < PASS_RADII[b]`` (normalised units); pass k >= 2
# weights an emitter at distance r by its weight at level ``#{b : r2 >= weight_r2[b]}``
# (N_LEVELS = N_BINS + 1 levels, level 0 = weight 1), see ``aobake.methods.bunnell.passes``.
N_BINS = len(PASS_RADII)
N_LEVELS = N_BINS + 1

# Per-direction saturation: azimuth sectors per band (aobake.constants.DIRECTION_SECTORS;
# the pseudo-angle of sector_coords makes 8 equal sectors, the vectorised accumulators of
# listsums are written out for 8).
SECTORS = DIRECTION_SECTORS
assert SECTORS == 8, "sector_coords and listsums.dir_add are written for 8 sectors"

PI32 = np.float32(np.pi)
ZERO32 = np.float32(0.0)
HALF32 = np.float32(0.5)


# ---------------------------------------------------------------------------------------
# scalar form factors (float64; the exact sum and the tests)


@njit(cache=True, error_model="numpy", inline="always")
def disk_term(r2, r, proj, area, g, measure):
    """Occlusion of a receiver by one disk.

    Parameters
    ----------
    r2, r : float
        Squared distance and distance from the receiver to the disk centre (r > 0 or
        area > 0, so nothing divides by zero).
    proj : float
        Weighted projected area facing the receiver, ``w A |cos_e|``.
    area : float
        Disk area A (regularises the near field).
    g : float
        Receiver factor: ``max(cos_r, 0)`` (cosine) or ``clamp(4 cos_r, 0, 1)`` (uniform).
    measure : int

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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def is_near(cx, cy, cz, area, px, py, pz, near):
    """The near-field test ``r^2 < near A``, in float32 for every kernel alike (so the exact
    sum and the tree pass take the same emitters as near)."""
    dx = np.float32(cx) - np.float32(px)
    dy = np.float32(cy) - np.float32(py)
    dz = np.float32(cz) - np.float32(pz)
    r2 = dx * dx + dy * dy + dz * dz
    return r2 < np.float32(near) * np.float32(area)


@njit(cache=True, error_model="numpy", inline="always")
def level_of(r2, thresholds):
    """Number of ``thresholds`` (ascending squared distances) that ``r2`` reaches."""
    k = 0
    while k < thresholds.shape[0] and r2 >= thresholds[k]:
        k += 1
    return k


@njit(cache=True, error_model="numpy", inline="always")
def gate_factor(ox, oy, oz, px, py, pz, nx, ny, nz, r, gate):
    """How much of an emitter's occlusion counts for a receiver (passes >= 2, gated).

    ``min(1, max(0, h / (gate r)))`` with ``h = n.(o - p)`` the height of the emitter's
    occluder centroid ``o`` above the receiver's tangent plane; 1 for a receiver without
    a normal (``n = 0``: every occluder counts, Bunnell's weight).
    """
    if nx == 0.0 and ny == 0.0 and nz == 0.0:
        return 1.0
    h = nx * (ox - px) + ny * (oy - py) + nz * (oz - pz)
    return min(max(h / (gate * r), 0.0), 1.0)


# ---------------------------------------------------------------------------------------
# per-direction saturation (cosine measure): bins of the receiver's hemisphere


@njit(cache=True, error_model="numpy", inline="always")
def sector_coords(dx, dy, dz, d2, frame, nx, ny, nz):
    """Where direction d falls among the receiver's direction bins: ``(up, low, q, pole)``.

    ``low = clamp(1.5 - 2 cos^2, 0, 1)``, ``up = 1 - low``: the shares of the upper band
    (cos^2 > 1/2) and the band near the horizon, each of cosine-weighted measure 1/2;
    ``q`` in [0, SECTORS): a pseudo-angle of d's tangent part (x, y), ``2 |y| / (|x| +
    |y|)`` per quadrant, monotone in the angle and equal to k at k x 45 degrees, so its
    unit intervals are equal sectors without atan2; ``pole = clamp(1 - 16 sin^2, 0, 1)``:
    the share spread evenly over the sectors, as the azimuth of a direction near the
    normal is ill-conditioned (float32 and float64 disagreed by 0.04 in q on a vertex
    straight above another). Selects only: vectorises.
    """
    # float32 constants: float32 inputs stay float32 (the tree pass), float64 stay float64
    one = np.float32(1.0)
    two = np.float32(2.0)
    four = np.float32(4.0)
    tiny = np.float32(1e-30)  # coincident disks (d = 0) have a zero term: any finite share
    x = frame[0] * dx + frame[1] * dy + frame[2] * dz
    y = frame[3] * dx + frame[4] * dy + frame[5] * dz
    z = nx * dx + ny * dy + nz * dz
    c2 = min(z * z / max(d2, tiny), one)
    low = min(max(np.float32(1.5) - two * c2, ZERO32), one)
    pole = max(one - np.float32(16.0) * (one - c2), ZERO32)
    ax = abs(x)
    ay = abs(y)
    t = two * ay / max(ax + ay, tiny)
    q = (t if y >= ZERO32 else two * four - t) if x >= ZERO32 else (four - t if y >= ZERO32 else four + t)
    return one - low, low, q, pole


@njit(cache=True, error_model="numpy", inline="always")
def tent(q, centre):
    """Share of sector ``centre - 1/2`` for pseudo-angle q: linear between the two
    nearest sector centres (round the circle), so a term on a border is split, not
    snapped (snapping aliased on regular grids)."""
    d = abs(q - centre)
    d = min(d, np.float32(SECTORS) - d)
    return max(np.float32(1.0) - d, ZERO32)


@njit(cache=True, error_model="numpy", inline="always")
def is_wide(area, d2):
    """A disk or cluster of area A at squared distance d2 too wide to bin:
    ``A >= DIRECTION_WIDE d2`` (a product and a compare: the same in float32 lanes and
    scalars, so the tree pass routes a term alike when it adds and when it removes it)."""
    return area >= np.float32(DIRECTION_WIDE) * d2


@njit(cache=True, error_model="numpy", inline="always")
def add_directions(dirs, f, b, area, dx, dy, dz, d2, frame, nx, ny, nz):
    """Spread the (front, back) term of an emitter (area A) in direction d over the
    receiver's direction bins ``dirs`` (2, 2 SECTORS + 1): bin k < SECTORS is azimuth
    sector k of the upper band, bin SECTORS + k the same sector near the horizon
    (:func:`sector_coords`: the ``pole`` share evenly, the rest by :func:`tent`); a wide
    emitter (:func:`is_wide`) goes whole to the last column, which is never capped.
    Scalar; ``listsums`` has the vectorised form."""
    if f == 0.0 and b == 0.0 or not d2 > 0.0:  # nothing to add (a coincident disk)
        return
    if is_wide(area, d2):
        dirs[0, 2 * SECTORS] += f
        dirs[1, 2 * SECTORS] += b
        return
    up, low, q, pole = sector_coords(dx, dy, dz, d2, frame, nx, ny, nz)
    even = pole / SECTORS
    for k in range(SECTORS):
        a = (1.0 - pole) * tent(q, k + 0.5) + even
        dirs[0, k] += f * up * a
        dirs[0, SECTORS + k] += f * low * a
        dirs[1, k] += b * up * a
        dirs[1, SECTORS + k] += b * low * a


@njit(cache=True, error_model="numpy", inline="always")
def direction_excess(dirs, side):
    """What side's direction bins hold beyond their measure ``1 / (2 SECTORS)`` each."""
    cap = 0.5 / SECTORS
    e = 0.0
    for k in range(2 * SECTORS):
        e += max(dirs[side, k] - cap, 0.0)
    return e


# what a receiver with a slot (``fill`` arguments: slot[i] >= 0) does with its direction
# bins for later passes; receivers without one (slot -1) do nothing
FILL_NONE = 0  # no receiver has a slot
FILL_KEEP = 1  # pass 1: keep them (store row slot[i])
FILL_GIVE = 2  # a later pass: give back part of what it removes (:func:`refill`)
FILL_KEEP_IF = 3  # keep them where the receiver bins anyway (the ground plane's settling)


@njit(cache=True, error_model="numpy", inline="always")
def keep_bins(dirs, store, row):
    """Pass 1: a receiver's direction bins, both sides, into ``store[row]``."""
    for side in range(2):
        for k in range(2 * SECTORS):
            store[row, side, k] = dirs[side, k]


@njit(cache=True, error_model="numpy", inline="always")
def refill(dirs, store, row, side):
    """What a later pass gives back on ``side``: ``sum_k (v1_k - v_k) v1_k / cap`` with
    ``v = min(bin, cap)`` (cap = one bin's measure), v1 from pass 1 (``store[row]``), v
    this pass's. A later pass removes a bin's occlusion in proportion to how empty pass 1
    left the bin: a full bin stays full (that direction is blocked, whatever stands in
    it), a nearly empty one loses all the pass removes (its layers may hide each other)."""
    cap = 0.5 / SECTORS
    e = 0.0
    for k in range(2 * SECTORS):
        v1 = min(store[row, side, k], cap)
        e += max(v1 - min(dirs[side, k], cap), 0.0) * (v1 / cap)
    return e


@njit(cache=True, error_model="numpy", inline="always")
def settle_fill(dirs, store, row, mode):
    """What a binned receiver does with its direction bins for later passes (both kernels):
    ``(front, back)`` to add to its totals. Row ``row`` of ``store`` (-1: none): pass 1
    (FILL_KEEP) keeps its bins there and adds nothing; a later pass (FILL_GIVE) gets
    :func:`refill` back on each side."""
    if row < 0:
        return 0.0, 0.0
    if mode == FILL_KEEP or mode == FILL_KEEP_IF:
        keep_bins(dirs, store, row)
        return 0.0, 0.0
    return refill(dirs, store, row, 0), refill(dirs, store, row, 1)


@njit(cache=True, error_model="numpy", inline="always")
def receiver_at(points, normals, i):
    """``(px, py, pz, nx, ny, nz, has_normal)`` of receiver i (a zero normal row: none)."""
    nx = normals[i, 0]
    ny = normals[i, 1]
    nz = normals[i, 2]
    return points[i, 0], points[i, 1], points[i, 2], nx, ny, nz, nx * nx + ny * ny + nz * nz > 0.0


@njit(cache=True, error_model="numpy", parallel=True)
def brute_force_pass(disks, cells, emitter_index, receivers, receiver_index, options, out, first,
                     fill):
    """Exact O(n k) sums ``out[i] = (front, back)`` for every ``i`` in receiver_index.

    Disk ``j`` at distance r adds ``disk_term(.., w A |cos_e|, ..)`` to ``front`` when
    ``cos_e > 0``, else to ``back``, with ``w = weights[j, l]``, ``l = level_of(r^2,
    weight_r2)``, or when gated ``w = 1 - (1 - weights[j, l]) gate_factor(occluders[j])``;
    skipped: the receiver's own disk, coincident disks (``r^2 <= COINCIDENT_REL A``),
    disks beyond the maximum distance or inside the receiver's inner radius (centre
    distance). Near-field disks (``r^2 < near A``, a receiver with a normal) are replaced
    by their barycentric cells (``polygon.cell_terms``) times the cell weight.

    Parameters
    ----------
    disks : structures.Disks
        float64, per vertex: disk centres (not offset), unit normals, areas,
        weight per level, and the centroid of what occludes the disk (used when gated).
    cells : structures.Cells
        The cell corners (``polygon.cell_terms``) and the cells' pass weights.
    emitter_index : (k,) int64
        Vertices whose disks cast.
    receivers : structures.Receivers
        Evaluation points, normals, and an inner radius: emitters (disks and cells) whose centre is
        closer than it are left out (0: none; the hybrid method's rays cover that ball);
        ``modes`` is for the tree pass (here ``receiver_index`` chooses).
    receiver_index : (q,) int64
        Receivers to compute (a chunk); each writes only ``out[i]``.
    options : structures.PassOptions
        Measure code, centre-distance limit (``inf`` = unbounded), near-field
        factor (0 = disks only), whether to split the sums by distance, the bins' squared
        outer radii (N_BINS,), the weight levels' squared distance thresholds (N_BINS,),
        whether the weights differ between levels (only then are they gated), the gate
        width (0: weights not gated; see :func:`gate_factor`), and whether to saturate
        per direction (cosine measure, receivers with a normal): the disk terms are also
        spread over direction bins (:func:`add_directions`) and the total loses their
        :func:`direction_excess`.
    out : (n, 2, N_BINS) float64
        (front, back) sums, cumulative by distance: bin b sums the emitters with
        ``r^2 < bin_r2[b]`` (the last bin: all of them, less the direction excess); only
        the last bin when not ``binned``. Unsaturated but for that excess.
    first : (n, 4) float64
        When ``binned``: ``sum (front + back term) (c - p)`` over every emitter, and
        ``sum (front + back term)`` (no excess removed), whose ratio locates the centroid
        of what occludes the receiver (the next pass's occluders); untouched otherwise.
    fill : structures.Fill
        With per-direction
        saturation, receiver i with ``slot[i] >= 0`` keeps its direction bins in
        ``store[slot[i]]`` (mode FILL_KEEP: pass 1) or gets :func:`refill` back on each
        side's total (FILL_GIVE: a later pass); :func:`settle_fill`. Slots of -1 (and
        FILL_NONE, when every slot is -1): neither.
    """
    positions, normals, areas = disks.positions, disks.normals, disks.areas
    weights, occluders = disks.weights, disks.occluders
    corner_start, corners, cell_weights = cells.corner_start, cells.corners, cells.weights
    store, slot, fill_mode = fill.store, fill.slot, fill.mode
    points, r_normals, inner = receivers.points, receivers.normals, receivers.inner
    measure, max_distance, near, binned = options.measure, options.max_distance, options.near, options.binned
    bin_r2, weight_r2, leveled, gate = options.bin_r2, options.weight_r2, options.leveled, options.gate
    directional = options.directional
    gate = gate if leveled else 0.0  # gated weights are a later pass's (as in the tree)
    max_d2 = max_distance * max_distance
    last = bin_r2.shape[0] - 1
    for q in prange(receiver_index.shape[0]):
        i = receiver_index[q]
        quad = np.empty((4, 3))
        dirs = np.zeros((2, 2 * SECTORS + 1))
        px, py, pz, nx, ny, nz, has_normal = receiver_at(points, r_normals, i)
        binning = directional and has_normal and measure == MEASURE_COSINE
        frame = tangent_frame(nx, ny, nz) if has_normal else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        min_d2 = inner[i] * inner[i]
        for b in range(last + 1):
            out[i, 0, b] = 0.0
            out[i, 1, b] = 0.0
        if binned:
            for ax in range(4):
                first[i, ax] = 0.0
        for t in range(emitter_index.shape[0]):
            j = emitter_index[t]
            if j == i:
                continue
            dx = positions[j, 0] - px
            dy = positions[j, 1] - py
            dz = positions[j, 2] - pz
            r2 = dx * dx + dy * dy + dz * dz
            area = areas[j]
            if r2 > max_d2 or r2 < min_d2:
                continue
            b = min(level_of(r2, bin_r2), last) if binned else last
            if has_normal and is_near(
                positions[j, 0], positions[j, 1], positions[j, 2], area, px, py, pz, near
            ):
                f, bk = cell_terms(
                    positions, corner_start, corners, j, px, py, pz, nx, ny, nz, measure, quad
                )
                for bb in range(b, last + 1):
                    out[i, 0, bb] += cell_weights[j] * f
                    out[i, 1, bb] += cell_weights[j] * bk
                if binned:
                    both = cell_weights[j] * (f + bk)
                    first[i, 0] += both * dx
                    first[i, 1] += both * dy
                    first[i, 2] += both * dz
                continue
            lv = level_of(r2, weight_r2)
            w = weights[j, lv]
            if gate > 0.0 and w < 1.0:
                g = gate_factor(
                    occluders[j, 0], occluders[j, 1], occluders[j, 2],
                    px, py, pz, nx, ny, nz, np.sqrt(r2), gate,
                )
                w = 1.0 - (1.0 - w) * g
            if r2 <= COINCIDENT_REL * area or w <= 0.0:
                continue
            e = -(normals[j, 0] * dx + normals[j, 1] * dy + normals[j, 2] * dz)
            r = np.sqrt(r2)
            g = receiver_factor(nx * dx + ny * dy + nz * dz, r, has_normal, measure)
            if g <= 0.0 or e == 0.0:
                continue
            term = disk_term(r2, r, w * area * abs(e) / r, area, g, measure)
            for bb in range(b, last + 1):
                out[i, 0 if e > 0.0 else 1, bb] += term
            if binning:
                front = term if e > 0.0 else 0.0
                add_directions(dirs, front, term - front, area, dx, dy, dz, r2, frame, nx, ny, nz)
            if binned:
                first[i, 0] += term * dx
                first[i, 1] += term * dy
                first[i, 2] += term * dz
        if binned:
            first[i, 3] = out[i, 0, last] + out[i, 1, last]
        if binning:
            given = settle_fill(dirs, store, slot[i], fill_mode)
            for side in range(2):
                out[i, side, last] = max(
                    out[i, side, last] - direction_excess(dirs, side) + given[side], 0.0
                )


@njit(cache=True, error_model="numpy", inline="always")
def disk_pair32(dx, dy, dz, r2, mx, my, mz, wa, a, nx, ny, nz, has_normal, measure):
    """float32 (front, back) disk terms of one emitter (:func:`disk_term` on either side)."""
    e = -(mx * dx + my * dy + mz * dz)
    nd = nx * dx + ny * dy + nz * dz
    if measure == MEASURE_COSINE and has_normal:
        # w A cos_e cos_r / (pi r^2 + A) with cos = dot / r: no square root; the
        # denominator underflows to 0 in float32 for disks ~1e-9 of the scene with the
        # receiver on top (its own disk, nd = 0): that term is 0, never 0 / 0
        den = r2 * (PI32 * r2 + a)
        c = wa * max(nd, ZERO32) / den if den > ZERO32 else ZERO32
    else:
        r = np.sqrt(r2)
        if measure == MEASURE_COSINE:
            c = wa * np.float32(NO_NORMAL_COSINE) / (r * (PI32 * r2 + a))
        else:
            if has_normal:
                g = min(max(np.float32(4.0) * nd / r, ZERO32), np.float32(1.0))
            else:
                g = np.float32(NO_NORMAL_UNIFORM)
            s = np.sqrt(a / PI32 + r2)
            c = wa * g / (r * PI32 * s * (s + r))
    return c * max(e, ZERO32), c * max(-e, ZERO32)


# the ground plane's share of the direction bins (aobake.ground), for the pass's settling
PLANE_NODES = (-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526)
PLANE_WEIGHTS = (0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538)


@njit(cache=True, error_model="numpy", parallel=True)
def plane_bins(normals, cos_reach, axis, out):
    """``out[i, k]``: cosine-weighted measure (over pi) of the directions in receiver i's
    direction bin k that meet the ground plane: the cone -d.up >= cos_reach[i] about -up
    (cos_reach 0: the lower half-space). Bin k < SECTORS is azimuth sector k (45 degrees
    of the receiver's tangent frame, as :func:`sector_coords` splits it) of the upper
    band (theta < 45 degrees), bin SECTORS + k the same sector near the horizon. Exact in
    the polar angle (the cone meets a meridian in one arc), 4-point Gauss-Legendre per
    sector in the azimuth. A zero normal: zeros."""
    quarter = 0.25 * np.pi
    half = 0.5 * np.pi
    for i in prange(normals.shape[0]):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        for k in range(2 * SECTORS):
            out[i, k] = 0.0
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            continue
        tx, ty, tz, bx, by, bz = tangent_frame(nx, ny, nz)
        t_up = (tx, ty, tz)[axis]
        b_up = (bx, by, bz)[axis]
        c = -(nx, ny, nz)[axis]  # cos of the angle between the normal and -up
        ca = cos_reach[i]
        for k in range(SECTORS):
            lo_b = 0.0
            hi_b = 0.0
            for g in range(4):
                phi = quarter * (k + 0.5 + 0.5 * PLANE_NODES[g])
                a = -(np.cos(phi) * t_up + np.sin(phi) * b_up)  # -u.up, u the azimuth direction
                rr = np.sqrt(a * a + c * c)
                if rr <= ca or rr == 0.0:
                    continue
                psi = np.arctan2(a, c)
                delta = np.arccos(min(ca / rr, 1.0))
                t0 = max(psi - delta, 0.0)
                t1 = min(psi + delta, half)
                w = 0.5 * PLANE_WEIGHTS[g]  # the sector's azimuth interval is 2 x 0.5 quarter wide
                if t0 < min(t1, quarter):  # upper band
                    s0 = np.sin(t0)
                    s1 = np.sin(min(t1, quarter))
                    hi_b += w * 0.5 * (s1 * s1 - s0 * s0)
                if max(t0, quarter) < t1:  # band near the horizon
                    s0 = np.sin(max(t0, quarter))
                    s1 = np.sin(t1)
                    lo_b += w * 0.5 * (s1 * s1 - s0 * s0)
            # (1/pi) x the sector's width (pi/4) x the mean over the nodes
            out[i, k] = hi_b * 0.25
            out[i, SECTORS + k] = lo_b * 0.25
