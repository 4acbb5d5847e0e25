"""The disk method's tree pass: buckets of receivers walk the cluster tree once
(``treewalk.gather``), then each receiver sums the lists (``listsums``) and swaps its
near-field disks for their cells (``polygon.cell_terms``).

Imports numpy, numba and ``aobake.constants`` only. Symbols as in
``aobake.kernels.bunnell``; the arguments are ``aobake.kernels.structures``'.

numba caches each kernel by its own file's time stamp: the ``listterms`` and
``bunnell`` terms inlined here do not invalidate it, so after changing them, touch
this file (or delete ``__pycache__``) or stale machine code keeps running.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from aobake.constants import FASTMATH, MEASURE_COSINE

from .bunnell import (
    FILL_KEEP_IF,
    SECTORS,
    ZERO32,
    add_directions,
    direction_excess,
    is_near,
    level_of,
    receiver_at,
    settle_fill,
)
from .listsums import (
    binned_sums,
    binned_sums_flat,
    direction_sums,
    direction_sums_flat,
    far_sums,
    far_sums_flat,
    near_disk_sums,
    near_disk_sums_flat,
    site,
)
from .listterms import disk_term
from .polygon import cell_terms
from .treewalk import S_A, S_X, S_Y, S_Z, gather
from .warps import frame as tangent_frame

# Relative slack of the test that a near-field cell lies wholly below the receiver's
# tangent plane (float64, against the rounding of its quads' corners).
CELL_SLACK = 1e-9

# Buckets per block of the tree pass's cyclic schedule (hierarchy_pass): blocks of
# neighbours keep locality, and many blocks per thread even out the threads' shares.
SCHEDULE_BLOCK = 64


@njit(cache=True, error_model="numpy", inline="always")
def add_cumulative(acc, f, b, r2, br2, binned):
    """``acc[:, k] += (f, b)`` for every bin k the distance ``r2`` falls inside (all bins
    from its own on), or the last bin only when not ``binned``."""
    last = br2.shape[0] - 1
    k = min(level_of(r2, br2), last) if binned else last
    for kk in range(k, last + 1):
        acc[0, kk] += f
        acc[1, kk] += b


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
    (``bunnell.direction_excess``). The lists are float32 rows in per-thread scratch;
    each receiver's result depends only on its bucket, so the output is identical for
    any thread count.

    Parameters
    ----------
    tree : structures.TreeArrays
        Refit for this pass.
    emitters : structures.Emitters
    receivers : structures.Receivers
        ``modes``: 0 nothing (the row is left alone), 1 the total only, 2 the sums by
        distance too when ``binned``.
    near_field : structures.NearField
        In tree order (a bucket's cells lie close together in memory); a cell whose
        vertex lies deeper than its reach below the receiver's tangent plane is skipped.
    buckets : structures.Buckets
        Scratch for T >= the number of numba threads.
    span : structures.Span
        Each thread takes every T-th block of SCHEDULE_BLOCK buckets.
    options : structures.PassOptions
        As in ``bunnell.brute_force_pass``; the gate applies only when ``leveled``.
    out : (n, 2, N_BINS) float64
        (front, back) sums, cumulative by distance bin when ``binned`` (else only the
        last bin, the total, is written), as in ``bunnell.brute_force_pass`` (the total
        less the direction excess); each receiver writes its own row.
    first : (n, 4) float64
        When ``binned`` and ``cache_mode != 2``: as in ``bunnell.brute_force_pass``.
    fill : structures.Fill
        As in ``bunnell.brute_force_pass``; a receiver with a slot bins by direction even
        where its sums could not overflow a bin.
    """
    # Compile time (docs/first-run.md): a first pass with the cosine measure (what a
    # default bake runs) takes the thin parallel loop over thread_share, with the list
    # sums compiled apart; the others keep the list sums inlined into one parallel kernel
    # (apart, the uniform measure's branching list loops ran 1.8 times slower).
    if options.measure == MEASURE_COSINE and not options.leveled:
        thin_pass(tree, emitters, receivers, near_field, buckets, span, options, out, first, fill)
    else:
        hierarchy_pass_inlined(tree, emitters, receivers, near_field, buckets, span, options, out,
                               first, fill)


@njit(cache=True, error_model="numpy", parallel=True)
def thin_pass(tree, emitters, receivers, near_field, buckets, span, options, out, first, fill):
    """:func:`hierarchy_pass`'s parallel loop, one :func:`thread_share` per thread: the
    worker compiles once as a plain function (a parallel loop around all of its code
    took ~30 s of CPU to compile, this one ~15 s together)."""
    for w in prange(span.threads):
        # one type for the index: the loop is typed twice (outside and inside the gufunc)
        thread_share(np.int64(w), tree, emitters, receivers, near_field, buckets, span, options,
                     out, first, fill)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def thread_share(w, tree, emitters, receivers, near_field, buckets, span, options, out, first,
                 fill):
    """Thread ``w``'s share of :func:`hierarchy_pass` (:func:`_share`) in a pass without
    levels, the list sums compiled apart (``listsums.*_flat``)."""
    _share(w, tree, emitters, receivers, near_field, buckets, span, options, out, first, fill,
           far_sums_flat, near_disk_sums_flat, binned_sums_flat, direction_sums_flat)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def hierarchy_pass_inlined(tree, emitters, receivers, near_field, buckets, span, options, out,
                           first, fill):
    """:func:`hierarchy_pass` with the list sums inlined (any pass, any measure)."""
    for w in prange(span.threads):
        _share(w, tree, emitters, receivers, near_field, buckets, span, options, out, first, fill,
               far_sums, near_disk_sums, binned_sums, direction_sums)


@njit(cache=True, error_model="numpy", inline="always")
def _share(w, tree, emitters, receivers, near_field, buckets, span, options, out, first, fill,
           far_fn, near_fn, binned_fn, dir_fn):
    """Thread ``w``'s share of :func:`hierarchy_pass`: every ``span.threads``-th block of
    SCHEDULE_BLOCK buckets, with scratch row ``w`` of ``buckets``; the list sums
    ``far_fn``, ``near_fn``, ``binned_fn``, ``dir_fn`` (:func:`~.listsums.far_sums`,
    ``near_disk_sums``, ``binned_sums``, ``direction_sums``, or their ``*_flat`` twins
    for a pass without levels, compiled apart) are compile-time arguments."""
    positions, cell_weights, reach = near_field.positions, near_field.weights, near_field.reach
    corner_start, corners = near_field.corner_start, near_field.corners
    cache, cache_mode = near_field.cache, near_field.cache_mode
    index = emitters.index
    points, normals, inner, modes = receivers.points, receivers.normals, receivers.inner, receivers.modes
    order, bucket_start, bounds = buckets.order, buckets.start, buckets.bounds
    near_buf, near_idx, far_buf = buckets.near_buf, buckets.near_idx, buckets.far_buf
    measure, max_distance, near, binned = options.measure, options.max_distance, options.near, options.binned
    bin_r2, weight_r2, leveled, gate = options.bin_r2, options.weight_r2, options.leveled, options.gate
    directional = options.directional
    gate_ = np.float32(gate) if leveled else ZERO32
    max_d2 = np.float32(min(max_distance * max_distance, 3.0e38))
    # without levels only level 0 is gathered: thresholds no distance reaches
    wr2 = weight_r2.astype(np.float32) if leveled else np.full(weight_r2.shape[0], np.inf, np.float32)
    br2 = bin_r2.astype(np.float32)
    last = bin_r2.shape[0] - 1
    cap = 0.5 / SECTORS  # one direction bin's measure
    store, slot, fill_mode = fill.store, fill.slot, fill.mode
    # numba gives each thread one contiguous share of the range, and a bucket's cost
    # follows the geometry: each thread takes every T-th block of SCHEDULE_BLOCK
    # neighbouring buckets instead (cyclic), so every share samples the whole span
    b0, b1, n_threads = span.first, span.stop, span.threads
    n_blocks = (b1 - b0 + SCHEDULE_BLOCK - 1) // SCHEDULE_BLOCK
    per_thread = (n_blocks + n_threads - 1) // n_threads * SCHEDULE_BLOCK
    # this thread's scratch, reused for all its buckets (every use overwrites it)
    nb = near_buf[w]
    ni = near_idx[w]
    fb = far_buf[w]
    quad = np.empty((4, 3))
    acc = np.zeros((2, last + 1))
    fst = np.zeros(3)
    dirs = np.zeros((2, 2 * SECTORS + 1))
    for c in range(per_thread):
        bk = b0 + (w + c // SCHEDULE_BLOCK * n_threads) * SCHEDULE_BLOCK + c % SCHEDULE_BLOCK
        if bk >= b1:
            break
        n_near, n_cand, n_far = gather(tree, emitters, bounds[bk], options, nb, ni, fb)
        binned_before = False  # the last receiver of this bucket with a normal had to bin
        for q in range(bucket_start[bk], bucket_start[bk + 1]):
            i = order[q]
            if modes[i] == 0:
                continue
            px, py, pz, nx, ny, nz, has_normal = receiver_at(points, normals, i)
            binned_i = binned and modes[i] == 2
            min_d2 = inner[i] * inner[i]
            px32 = np.float32(px)
            py32 = np.float32(py)
            pz32 = np.float32(pz)
            nx32 = np.float32(nx)
            ny32 = np.float32(ny)
            nz32 = np.float32(nz)
            at = site(px32, py32, pz32, nx32, ny32, nz32, has_normal, measure, gate_, max_d2,
                      np.float32(min_d2), leveled, wr2)
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
                dir_fn(nb, n_near, fb, n_far, px32, py32, pz32, nx32, ny32, nz32, frame,
                               max_d2, np.float32(min_d2), wr2, leveled, gate_, dirs)
                if not binned_i:
                    acc[0, last] = dirs[0].sum()  # the bins and the wide terms
                    acc[1, last] = dirs[1].sum()
            if binned_i:
                binned_fn(nb, n_near, fb, n_far, at, br2, acc, fst)
            elif not binning:
                f1, b1_ = far_fn(fb, n_far, at)
                f2, b2 = near_fn(nb, n_near, at)
                acc[0, last] = np.float64(f1) + np.float64(f2)
                acc[1, last] = np.float64(b1_) + np.float64(b2)
            row = slot[i]  # >= 0: keeps or reads its bins
            keeps = row >= 0 and fill_mode != FILL_KEEP_IF  # FILL_KEEP_IF keeps, never forces
            if can_bin and not binning and (max(acc[0, last], acc[1, last]) > cap or keeps):
                binning = True
                dir_fn(nb, n_near, fb, n_far, px32, py32, pz32, nx32, ny32, nz32, frame,
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
                    df, db = disk_term(nb, t, ex, ey, ez, r2, at)
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
            lo = last + 1 - out.shape[2]  # an out of one bin holds the totals alone
            for k in range(lo, last + 1):
                # the swap can leave -1 ulp where the sum is 0
                out[i, 0, k - lo] = max(acc[0, k], 0.0)
                out[i, 1, k - lo] = max(acc[1, k], 0.0)
