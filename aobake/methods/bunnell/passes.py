"""The disk method's passes: sums of disk and cell form factors over the cluster tree,
saturated per pass, with later passes removing double shadows.

Numpy-facing: coerces dtypes once and calls the compiled loops in
``aobake.kernels.bunnell`` (``_k.*``) and ``aobake.kernels.treepass`` (``_tp.*``).
Contains no @njit code and never prints. The pass scheme's switches are
:class:`aobake.methods.bunnell.scheme.Scheme`.

References
----------
M. Bunnell, "Dynamic Ambient Occlusion and Indirect Lighting", GPU Gems 2, ch. 14 (2005).
J. Hoberock and Y. Jia, "High-Quality Ambient Occlusion", GPU Gems 3, ch. 12 (2007).
"""

from __future__ import annotations

import math

import numpy as np

from ... import precompile
from ..._types import FloatArray, IndexArray
from ...checks import check_result, numba_threads
from ...constants import MEASURE_CODES, PASS_GATE_WIDTH, PASS_RADII
from ...kernels import bunnell as _k
from ...kernels import hierarchy as _h
from ...kernels import polygon as _poly
from ...kernels import structures as _s
from ...kernels import treepass as _tp
from ...kernels import treewalk as _tw
from ...progress import NullProgress, Progress
from .elements import DiskElements
from .options import BunnellOptions
from .scheme import (
    DEFAULT_BUCKET_SPREAD,
    DEFAULT_LEAF_SIZE,
    DEFAULT_PASS_REACH,
    Scheme,
    combine_sides,
)
from .tree import ClusterTree, node_coherence, pack_nodes, tree_keys
from .tree import build_tree as _build_tree

__all__ = ["build_tree", "occlusion_passes"]

# Passes >= 2 with a tree: passes 2..K are evaluated at one vertex per tree leaf (the one
# nearest its centre), and what they remove is carried over to the leaf's vertices with a
# normal within arccos(SHARE_COS) of its own; the others are evaluated themselves.
SHARE_COS = 0.9
# Buckets per kernel call: only for progress reports and Ctrl-C latency.
CHUNK_BUCKETS = 1 << 12


def build_tree(elements: DiskElements, *, leaf_size: int = DEFAULT_LEAF_SIZE) -> ClusterTree:
    """Cluster tree over the casting disks (:func:`.tree.build_tree`).

    Parameters
    ----------
    elements : DiskElements
        With at least one casting disk.
    leaf_size : int, optional
        Maximum disks per leaf (>= 1).
    """
    if isinstance(leaf_size, bool) or not isinstance(leaf_size, (int, np.integer)) or leaf_size < 1:
        raise ValueError(f"leaf_size must be an integer >= 1, got {leaf_size!r}")
    if elements.n_emitters == 0:
        raise ValueError("build_tree needs at least one casting disk (area > 0 and a normal)")
    return _build_tree(
        elements.positions, elements.areas, elements.emitter_index, leaf_size=leaf_size
    )


class _Pass:
    """Kernel inputs of one (elements, tree, options) set, reused by every pass.

    ``pass_reach``: weight levels for passes >= 2 (see :func:`occlusion_passes`);
    ``spread``: :func:`receiver_buckets`'.
    """

    def __init__(
        self,
        elements: DiskElements,
        tree: ClusterTree | None,
        theta,
        near,
        code,
        reach,
        inner=None,
        pass_reach=DEFAULT_PASS_REACH,
        gate=PASS_GATE_WIDTH,
        directional=True,
        spread=DEFAULT_BUCKET_SPREAD,
    ):
        self.elements = elements
        self.tree = tree
        bin_r2 = np.asarray(PASS_RADII, dtype=np.float64) ** 2
        with np.errstate(divide="ignore"):
            weight_r2 = np.ascontiguousarray(bin_r2 / pass_reach**2)
        self.options = _s.PassOptions(
            measure=code, max_distance=reach, near=near, binned=False, bin_r2=bin_r2,
            weight_r2=weight_r2, leveled=False, gate=float(gate), directional=bool(directional),
        )
        inner = np.zeros(elements.n_vertices) if inner is None else inner
        self.receivers = _s.Receivers(
            points=elements.points,
            normals=elements.normals,
            inner=np.ascontiguousarray(inner, dtype=np.float64),
            modes=np.full(elements.n_vertices, 2, dtype=np.uint8),
        )
        self.no_fill = _no_fill(elements.n_vertices)
        if tree is None:
            return
        import numba

        order = tree.order
        self.perm, self.cells = _cells_in_tree_order(elements, order)
        self.rows = np.zeros((order.shape[0], _h.EMITTER_COLS), dtype=np.float32)
        _h.emitter_rows(elements.positions, elements.normals, elements.areas, order, self.rows)
        self.occluders = np.zeros((order.shape[0], 3), dtype=np.float32)
        coherence = node_coherence(tree, elements.normals, elements.areas)
        self.nodes = pack_nodes(tree, theta=theta, near=near, coherence=coherence)
        self._levels(1)
        recv_order, bucket_start = receiver_buckets(elements, tree, spread=spread)
        bounds = _bucket_bounds(elements, self.receivers.inner, recv_order, bucket_start)
        slots = numba.config.NUMBA_NUM_THREADS
        k, m = order.shape[0], tree.n_nodes
        self.bucket_start = bucket_start
        self.buckets = _s.Buckets(
            order=recv_order,
            start=bucket_start,
            bounds=bounds,
            near_buf=scratch((slots, _tw.NEAR_ROWS, k), np.float32),
            near_idx=scratch((slots, 2, k), np.int64),
            far_buf=scratch((slots, _tw.FAR_ROWS, m), np.float32),
        )

    def _levels(self, levels: int) -> None:
        """Per-emitter weights and per-node moments for ``levels`` weight levels: 1 while
        every pass so far had equal levels (the kernels then read level 0 only), else
        N_LEVELS (a seventh of the memory in a first pass)."""
        tree, k = self.tree, self.tree.order.shape[0]
        self.weights = np.ones((k, levels), dtype=np.float32)
        self.moments = np.zeros((tree.n_nodes, levels, _h.MOMENT_COLS), dtype=np.float32)
        self.tree_args = _s.TreeArrays(
            skip=tree.skip, start=tree.start, stop=tree.stop, nodes=self.nodes, moments=self.moments
        )
        self.emitters = _s.Emitters(
            rows=self.rows, index=tree.order, weights=self.weights, occluders=self.occluders
        )

    def sums(
        self,
        weights: FloatArray,
        progress: Progress,
        cell_weights=None,
        binned: bool = False,
        cache_mode: int = 0,
        occluders=None,
        modes=None,
        fill=None,
    ) -> tuple[FloatArray, FloatArray]:
        """(n, 2, N_BINS) (front, back) sums, cumulative by distance, when ``binned``; else
        (n, 2, 1): the totals alone (less the direction excess when directional),
        and (n, 4) first moments ``sum (front + back term) (emitter - receiver)`` and the
        summed terms (when ``binned``, cache_mode < 2).

        ``weights``: (n,) per-vertex disk weights, or (n, N_LEVELS) per weight level;
        ``cell_weights``: (n,) near-field cell weights (default: the level-0 weights).
        ``cache_mode`` (tree only): 1 keeps each receiver's cell sums, 2 reuses them (the
        cell weights must not have changed), 0 neither. ``occluders``: (n, 3) occluder
        centroids for gated weights (default: the vertices; unused unless leveled).
        ``modes`` (tree only): (n,) uint8 per receiver, 0 skip (row 0), 1 total only, 2
        binned when ``binned`` (default: all 2). ``fill``: a ``kernels.structures.Fill``, what
        receivers do with their direction bins for later passes
        (``kernels.bunnell.brute_force_pass``; default: nothing).
        """
        e = self.elements
        n = e.n_vertices
        weights = np.ascontiguousarray(weights, dtype=np.float64)
        # (n,) weights are one level: not spread to N_LEVELS unless the exact sum needs them
        leveled = weights.ndim == 2 and bool(np.any(weights != weights[:, :1]))
        level0 = weights if weights.ndim == 1 else weights[:, 0]
        cell_weights = np.ascontiguousarray(level0 if cell_weights is None else cell_weights)
        options = self.options._replace(binned=bool(binned), leveled=leveled)
        occluders = np.ascontiguousarray(e.positions if occluders is None else occluders)
        first = np.zeros((n, 4))
        fill = self.no_fill if fill is None else fill
        if self.tree is None:
            out = np.zeros((n, 2, _k.N_BINS))
            if weights.ndim == 1:
                weights = np.repeat(weights[:, None], _k.N_LEVELS, axis=1)
            disks = _s.Disks(e.positions, e.normals, e.areas, weights, occluders)
            cells = _s.Cells(e.corner_start, e.corners, cell_weights)
            everyone = np.arange(n, dtype=np.int64)
            step = CHUNK_BUCKETS * DEFAULT_LEAF_SIZE
            for lo in range(0, n, step):
                chunk = everyone[lo : lo + step]
                _k.brute_force_pass(
                    disks, cells, e.emitter_index, self.receivers, chunk, options, out, first, fill
                )
                progress.advance(chunk.shape[0])
            return (out if binned else out[:, :, -1:]), first
        # only what this pass reads: level 0 unless leveled, the occluders when gated
        if leveled:
            if self.weights.shape[1] != _k.N_LEVELS:
                self._levels(_k.N_LEVELS)
            self.weights[:] = weights[self.tree.order]
        else:
            self.weights[:, 0] = level0[self.tree.order]
        if leveled and self.options.gate > 0.0:
            self.occluders[:] = occluders[self.tree.order]
        _h.refit_nodes(
            self.rows,
            self.weights,
            self.occluders,
            self.tree.skip,
            self.tree.start,
            self.tree.stop,
            self.nodes,
            self.moments,
            leveled,
        )
        # the tree pass writes the totals alone where nothing reads the bins (every bin
        # of an (n, 2, N_BINS) array would be resident: 96 bytes a vertex, not 16)
        out = np.zeros((n, 2, _k.N_BINS if binned else 1))
        if cache_mode and not hasattr(self, "cache"):
            self.cache = np.zeros((n, 2, _k.N_BINS))
        cache = getattr(self, "cache", np.zeros((0, 2, _k.N_BINS)))
        receivers = self.receivers
        if modes is not None:
            receivers = receivers._replace(modes=np.ascontiguousarray(modes, dtype=np.uint8))
        # the near field in tree order (_cells_in_tree_order)
        positions, corner_start, corners, reach = self.cells
        near_field = _s.NearField(
            positions=positions, weights=cell_weights[self.perm], corner_start=corner_start,
            corners=corners, reach=reach, cache=cache, cache_mode=int(cache_mode),
        )
        buckets = self.buckets
        bucket_start = buckets.start
        n_buckets = bucket_start.shape[0] - 1
        import numba

        threads = numba.get_num_threads()
        precompile.wait("tree-pass")  # a cold cache: a helper may be compiling the kernel
        for b0 in range(0, n_buckets, CHUNK_BUCKETS):
            b1 = min(b0 + CHUNK_BUCKETS, n_buckets)
            _tp.hierarchy_pass(
                self.tree_args,
                self.emitters,
                receivers,
                near_field,
                buckets,
                _s.Span(b0, b1, threads),
                options,
                out,
                first,
                fill,
            )
            progress.advance(int(bucket_start[b1] - bucket_start[b0]))
        return out, first


def scratch(shape: tuple, dtype) -> np.ndarray:
    """An uninitialised C-contiguous array on an anonymous mapping of its own: its pages
    become resident only where written. The pass's per-thread lists are rows k (or m)
    entries apart, each written only at its start; numpy asks the kernel for 2 MiB pages
    on large arrays, which made them ~90 MiB resident whatever the mesh's size."""
    import mmap

    dtype = np.dtype(dtype)
    count = math.prod(shape)
    buffer = mmap.mmap(-1, max(count * dtype.itemsize, 1))
    return np.frombuffer(buffer, dtype=dtype, count=count).reshape(shape)


def first_pass_kernel():
    """The tree pass's kernel in a default bake (one pass, cosine measure: the unbinned
    thin loop) and arguments of the types :meth:`_Pass.sums` passes it, for
    :mod:`aobake.precompile` to compile it in a helper process on a cold cache."""
    f32, i64 = np.float32, np.int64

    def z(*shape, dtype=np.float64):
        return np.zeros(shape, dtype=dtype)

    tree = _s.TreeArrays(z(1, dtype=i64), z(1, dtype=i64), z(1, dtype=i64), z(1, _h.NODE_COLS, dtype=f32),
                         z(1, 1, _h.MOMENT_COLS, dtype=f32))  # fmt: skip
    emitters = _s.Emitters(z(1, _h.EMITTER_COLS, dtype=f32), z(1, dtype=i64), z(1, 1, dtype=f32), z(1, 3, dtype=f32))
    receivers = _s.Receivers(z(1, 3), z(1, 3), z(1), z(1, dtype=np.uint8))
    near_field = _s.NearField(z(1, 3), z(1), z(2, dtype=i64), z(0, 2, dtype=np.int32), z(1), z(0, 2, _k.N_BINS), 0)
    buckets = _s.Buckets(z(1, dtype=i64), z(2, dtype=i64), z(1, _tw.BOUND_COLS), z(1, _tw.NEAR_ROWS, 1, dtype=f32),
                         z(1, 2, 1, dtype=i64), z(1, _tw.FAR_ROWS, 1, dtype=f32))  # fmt: skip
    options = _s.PassOptions(
        measure=MEASURE_CODES["cosine"], max_distance=math.inf, near=1.0, binned=False, bin_r2=z(_k.N_BINS),
        weight_r2=z(_k.N_BINS), leveled=False, gate=0.0, directional=True,
    )  # fmt: skip
    args = (tree, emitters, receivers, near_field, buckets, _s.Span(0, 0, 1), options, z(1, 2, 1), z(1, 4), _no_fill(1))
    return _tp.thin_pass_unbinned, args


def _no_fill(n: int) -> _s.Fill:
    """The kernels' ``fill`` argument when no receiver keeps or reads its bins."""
    return _s.Fill(np.zeros((0, 2, 2 * _k.SECTORS)), np.full(n, -1, dtype=np.int64), _k.FILL_NONE)


def _fills(n: int, keepers: IndexArray) -> tuple[_s.Fill, _s.Fill]:
    """``fill`` arguments for pass 1 (``keepers`` keep their direction bins) and for the
    later passes (they read them back: ``kernels.bunnell.refill``)."""
    store = np.zeros((keepers.shape[0], 2, 2 * _k.SECTORS))
    slot = np.full(n, -1, dtype=np.int64)
    slot[keepers] = np.arange(keepers.shape[0])
    return _s.Fill(store, slot, _k.FILL_KEEP), _s.Fill(store, slot, _k.FILL_GIVE)


def _non_emitters(n: int, order: IndexArray) -> IndexArray:
    """The vertices that are not in the tree (``order``: the emitters), ascending."""
    casts = np.zeros(n, dtype=bool)
    casts[order] = True
    return np.flatnonzero(~casts)


def _cells_in_tree_order(elements: DiskElements, order: IndexArray):
    """``(perm, (positions, corner_start, corners, reach))``: the vertices renumbered so
    that the emitters come first in tree order ``order`` (then the others), with their
    positions and cells (``polygon.renumbered_cells``, corners int32 below 2^31 vertices,
    and ``polygon.cell_reach``). A receiver's near-field cells are its
    neighbours' and their corners are near them: in tree order they are near in memory
    too, whatever the input's vertex order (a scattered order made the cells slow)."""
    n = elements.n_vertices
    perm = np.concatenate([order, _non_emitters(n, order)]).astype(np.int64)
    index = np.int32 if n < 2**31 else np.int64  # the corners' dtype: half the table
    inverse = np.empty(n, dtype=index)
    inverse[perm] = np.arange(n, dtype=index)
    start, corners = _poly.renumbered_cells(elements.faces, inverse)
    del inverse
    positions = np.ascontiguousarray(elements.positions[perm])
    reach = np.empty(n)
    _poly.cell_reach(positions, start, corners, reach)
    return perm, (positions, start, corners, reach)


def pass_representatives(elements: DiskElements, tree: ClusterTree) -> IndexArray:
    """(n,) vertex whose later passes each vertex takes (itself for non-emitters), see
    :func:`aobake.kernels.hierarchy.leaf_representatives` (SHARE_COS)."""
    rep_of = np.arange(elements.n_vertices, dtype=np.int64)
    _h.leaf_representatives(
        elements.positions, elements.normals, elements.areas, tree.order, tree.skip,
        tree.start, tree.stop, SHARE_COS, rep_of,
    )
    return rep_of


def receiver_buckets(
    elements: DiskElements, tree: ClusterTree, *, spread: float = DEFAULT_BUCKET_SPREAD
) -> tuple[IndexArray, IndexArray]:
    """Receivers grouped into small, compact buckets that walk the tree together.

    The emitters' tree leaves are the first buckets (in tree order, so consecutive
    buckets are neighbours); the other vertices (no area or no normal) get a tree of
    their own, whose leaves are the remaining buckets. A leaf whose receivers lie far
    apart for their disks' area is split (``spread``: :func:`split_spread_buckets`; inf
    keeps the leaves whole).

    Returns
    -------
    order : (n,) int64
        Every vertex once, bucket by bucket.
    bucket_start : (nb + 1,) int64
    """
    leaves = tree.leaves
    starts = [tree.start[leaves]]
    order = [tree.order]
    rest = _non_emitters(elements.n_vertices, tree.order)
    if rest.size:
        perm, start, _, skip = _h.build_tree(tree_keys(elements.points, rest), tree.leaf_size)
        rest_leaves = np.flatnonzero(skip == np.arange(1, skip.shape[0] + 1))
        starts.append(start[rest_leaves] + tree.order.shape[0])
        order.append(rest[perm])
    bucket_start = np.append(np.concatenate(starts), elements.n_vertices).astype(np.int64)
    order = np.ascontiguousarray(np.concatenate(order), dtype=np.int64)
    if not math.isfinite(spread):
        return order, bucket_start
    radii = _bucket_bounds(elements, np.zeros(elements.n_vertices), order, bucket_start)[:, _tw.B_RADIUS]
    return split_spread_buckets(elements.points, elements.areas, order, bucket_start, radii, spread)


def _bucket_bounds(elements, inner, order, bucket_start) -> FloatArray:
    """(nb, BOUND_COLS) ``treewalk.bucket_bounds`` of the buckets."""
    bounds = np.zeros((bucket_start.shape[0] - 1, _tw.BOUND_COLS))
    _tw.bucket_bounds(elements.points, elements.normals, inner, order, bucket_start, bounds)
    return bounds


def split_spread_buckets(
    points: FloatArray, areas: FloatArray, order: IndexArray, bucket_start: IndexArray,
    radii: FloatArray, spread: float,
) -> tuple[IndexArray, IndexArray]:
    """Buckets whose receivers lie far apart, split until they are compact.

    A tree leaf can straddle a gap (its median split counts disks, it does not look at
    space: a ball's underside with the floor below it), and a bucket walks the tree as one
    sphere around all its receivers, so a wide one opens every node near any of them
    for all of them (on a 721k scene 1% of the leaves held a quarter of the near-list
    terms). A bucket of radius r whose cross-section ``pi r^2`` exceeds ``spread`` times
    its disks' summed area (a compact patch: 1-3) is halved at the midpoint of its
    receivers' longest extent, and the halves again, until each is compact or one
    receiver; the pieces keep the leaf's place and order. Buckets without area (vertices
    that do not cast) stay whole. Every piece of a level is cut at once, in numpy: 0.6 s
    for 300k vertices of scattered small triangles, where every leaf splits.

    Parameters
    ----------
    points : (n, 3) float64
    areas : (n,) float64
    order, bucket_start : as :func:`receiver_buckets` returns them
    radii : (nb,) float64
        Each bucket's bounding radius (``treewalk.bucket_bounds``).
    spread : float >= 1

    Returns
    -------
    order, bucket_start
        The same receivers, the wide buckets split.
    """
    area = np.add.reduceat(areas[order], bucket_start[:-1])
    wide = (area > 0.0) & (math.pi * radii**2 > spread * area)
    if not wide.any():
        return order, bucket_start
    order = order.copy()
    n = order.shape[0]
    starts, active = bucket_start[:-1].copy(), wide
    # level by level, every active piece at once (numpy): a piece is halved or kept
    while active.any():
        sizes = np.diff(np.append(starts, n))
        pieces = np.flatnonzero(active)
        count = sizes[pieces]
        first = np.cumsum(count) - count  # each piece's first member among ``at``
        piece = np.repeat(np.arange(pieces.shape[0]), count)
        at = np.repeat(starts[pieces] - first, count) + np.arange(count.sum())
        p = points[order[at]]
        centre = np.add.reduceat(p, first, axis=0) / count[:, None]
        r2 = np.maximum.reduceat(np.sum((p - centre[piece]) ** 2, axis=1), first)
        lo, hi = np.minimum.reduceat(p, first, axis=0), np.maximum.reduceat(p, first, axis=0)
        axis = np.argmax(hi - lo, axis=1)
        rows = np.arange(pieces.shape[0])
        cut = 0.5 * (lo[rows, axis] + hi[rows, axis])
        low = p[np.arange(p.shape[0]), axis[piece]] <= cut[piece]
        n_low = np.add.reduceat(low.astype(np.int64), first)
        halve = (count > 1) & (math.pi * r2 > spread * np.add.reduceat(areas[order[at]], first))
        halve &= n_low < count  # all on one side: every point coincides along the axis
        # the halved pieces' members: low half first, each half in the piece's order
        key = 2 * piece + np.where(halve[piece], ~low, False)
        order[at] = order[at][np.argsort(key, kind="stable")]
        active = active.copy()
        active[pieces[~halve]] = False
        starts = np.append(starts, starts[pieces[halve]] + n_low[halve])
        active = np.append(active, np.ones(int(halve.sum()), dtype=bool))
        by_start = np.argsort(starts, kind="stable")
        starts, active = starts[by_start], active[by_start]
    return np.ascontiguousarray(order), np.append(starts, n).astype(np.int64)


def occlusion_passes(
    elements: DiskElements,
    tree: ClusterTree | None = None,
    options: BunnellOptions | None = None,
    scheme: Scheme | None = None,
    *,
    progress: Progress | None = None,
    plane: tuple | None = None,
) -> FloatArray:
    """Saturated occlusion of every pass, ``A_k = clip(combine_sides(sums_k), 0, 1)``.

    Parameters
    ----------
    elements : DiskElements
    tree : ClusterTree or None
        ``None`` sums every disk exactly (brute force, O(n k): the test reference).
    options : BunnellOptions, optional
        ``passes`` K: pass 1 has ``w_j = 1``; pass k weights disk j, at distance r from
        the receiver, by ``w_j = 1 - damping A_{k-1}(j; pass_reach r)``: disks that are
        themselves in shadow cast less (Bunnell's double-shadow removal), but only by the
        geometry near them, which can stand between them and the receiver. The occlusion
        of j by emitters closer than R is read off distance bins of the previous pass
        (``PASS_RADII``: R is rounded down to a bin radius); near-field cells keep
        weight 1. Gated (``gate > 0``): the occlusion only counts for a receiver that has
        the centroid o_j of what occludes j in front of its tangent plane,
        ``g = clamp(n.(o_j - p) / (gate r), 0, 1)``. With ``directional``, every pass's
        disk and cluster terms are also spread over DIRECTION_SECTORS azimuth sectors x 2
        elevation bands of the receiver's hemisphere, and the total loses what any bin
        holds beyond its measure; with ``pass_fill`` a later pass removes from a bin only
        in proportion to how empty pass 1 left it (``kernels.bunnell.refill``).
    scheme : Scheme, optional
    progress : Progress or None
    plane : (axis, cos_reach, total) or None
        The ground plane (:mod:`aobake.ground`): its up axis, per receiver the cosine
        of the cone in which it is within reach, and its exact occlusion. It joins each
        side's sum like one more term: a binned receiver gets its share of every
        direction bin of pass 1 (:func:`aobake.kernels.bunnell.plane_bins`), capped with
        what the disks put there (directions the mesh already blocks count once); the
        others get ``total``. The plane itself is never in shadow (weight 1 in every pass).

    Returns
    -------
    occlusion : (K, n) float64 in [0, 1]
        Row k - 1 is pass k's occlusion A_k (not the accessibility).
    """
    options = BunnellOptions() if options is None else options
    scheme = Scheme() if scheme is None else scheme
    passes = options.passes
    code = MEASURE_CODES[options.measure]
    reach = (math.inf if options.max_distance is None else options.max_distance) / elements.scale
    progress = NullProgress() if progress is None else progress
    n = elements.n_vertices
    occlusion = np.zeros((passes, n))
    if elements.n_emitters == 0:  # nothing casts: every vertex is open (but for the plane)
        progress.start(passes * n, "bunnell")
        progress.advance(passes * n)
        progress.finish()
        if plane is not None:
            occlusion[:] = np.clip(plane[2], 0.0, 1.0)
        return occlusion
    # the blends read the second-to-last pass at every vertex
    share = scheme.share_passes and scheme.combine == "last" and tree is not None and passes > 1
    if share:
        rep_of = pass_representatives(elements, tree)
        # representatives in tree order (neighbours), then the vertices that do not cast
        evaluated = np.concatenate(
            [tree.order[rep_of[tree.order] == tree.order], _non_emitters(n, tree.order)]
        )
    progress.start(passes * n, "bunnell")  # every pass walks every bucket
    sides, damping = scheme.sides, scheme.damping
    with numba_threads(options.threads), np.errstate(under="ignore"):
        job = _Pass(elements, tree, options.theta, options.near, code, reach, None,
                    scheme.pass_reach, scheme.gate, options.directional, scheme.bucket_spread)
        # later passes read pass 1's direction bins at the receivers they evaluate
        keepers = evaluated if share else np.arange(n)
        fill = scheme.pass_fill and options.directional and passes > 1
        fills = _fills(n, keepers) if fill else (None, None)
        binned_plane = plane is not None and options.directional and code == MEASURE_CODES["cosine"]
        if binned_plane:  # receivers keep their pass-1 bins for the plane's share
            keep, give = _fills(n, np.arange(n))
            if fill:  # later passes read every receiver's bins: all bin
                fills = (keep, give)
            else:  # only those that bin anyway (the others: rows left NaN)
                keep.store[:] = np.nan
                fills = (keep._replace(mode=_k.FILL_KEEP_IF), None)
        settle = None
        if plane is not None:
            def settle(sums_total):
                return _with_plane(sums_total, plane, fills[0] if binned_plane else None, job.elements)
        if share:
            _shared_passes(job, occlusion, rep_of, evaluated, passes, sides, damping, fills,
                           progress, settle)
        else:
            _all_passes(job, occlusion, passes, sides, damping, fills, progress, settle)
    progress.finish()
    return occlusion


def _weights_from(sums: FloatArray, sides: str, damping: float) -> FloatArray:
    """(n, N_LEVELS) pass weights from binned sums: level 0 is 1, level b + 1 is
    ``1 - damping A(j; R_b)`` (occlusion by emitters closer than bin b's outer radius)."""
    weights = np.ones((sums.shape[0], _k.N_LEVELS))
    for b in range(_k.N_BINS):
        weights[:, b + 1] = 1.0 - damping * np.clip(combine_sides(sums[:, :, b], sides), 0.0, 1.0)
    return weights


def _with_plane(total: FloatArray, plane, keep, elements: DiskElements) -> FloatArray:
    """(n, 2) side totals with the ground plane added.

    A receiver that binned (``keep``: the kernels' store of pass 1, a row per receiver,
    NaN where it did not bin) gets, per side, what the plane adds to its direction bins
    beyond what the disks put there, ``sum_k max(v_k, p_k) - v_k`` (v capped at the bin's
    measure, p the plane's share of the bin), less what the sums hold unbinned (near-field
    cells, wide terms): whatever stands between a receiver and the plane is in front of
    it, in its directions, so the mesh's occlusion is taken to lie in the plane's part of
    a bin first (on a sphere resting on a floor at the plane that is exact; counting both
    was 0.035 RMSE against rays, this 0.002). A receiver that did not bin (its sums are
    below one bin's measure) gets ``P (1 - T)``, T its side's sum, P the plane's
    occlusion (bunny: 0.0069 against 0.0090 for ``max(P - T, 0)`` and 0.0067 when every
    receiver bins, at a third of the extra time); one without a normal (or not binning
    at all: ``--no-directional``, the uniform measure) the same ``P (1 - T)`` (bunny,
    uniform measure: 0.0325 against 0.0634 for P and 0.0752 for ``max(P - T, 0)``)."""
    axis, cos_reach, plane_total = plane
    # no bins to settle in: where the sums' occlusion lies is unknown, taken independent
    # of the plane's directions
    out = total + np.asarray(plane_total)[:, None] * (1.0 - np.minimum(total, 1.0))
    if keep is None:
        return out
    normals = np.ascontiguousarray(elements.normals, dtype=np.float64)
    has_normal = np.any(normals != 0.0, axis=1)
    plane_total = np.asarray(plane_total, dtype=np.float64)
    rows = keep.store[keep.slot]  # (n, 2, 2 SECTORS): pass 1's bins, both sides
    binned_rows = has_normal & ~np.isnan(rows[:, 0, 0])
    # a receiver whose sums stayed below one bin (it did not bin) keeps P (1 - T)
    idx = np.flatnonzero(binned_rows & (plane_total > 0.0))
    if idx.size == 0:
        return out
    share = np.zeros((idx.size, 2 * _k.SECTORS))
    _k.plane_bins(normals[idx], np.ascontiguousarray(cos_reach[idx], dtype=np.float64), int(axis), share)
    sums = share.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):  # the exact total, split as the bins say
        scale = np.where(sums > 0.0, plane_total[idx] / sums, 0.0)
    cap = 0.5 / _k.SECTORS
    share = np.minimum(share * scale[:, None], cap)
    bins = np.clip(rows[idx], 0.0, cap)
    gained = (np.maximum(bins, share[:, None, :]) - bins).sum(axis=2)
    gained = np.maximum(gained - np.maximum(total[idx] - bins.sum(axis=2), 0.0), 0.0)
    out[idx] = total[idx] + gained
    return out


def _all_passes(job, occlusion, passes, sides, damping, fills, progress, settle=None) -> None:
    """Every pass at every vertex (the exact sum's and the reference's way); ``fills``:
    the kernels' ``fill`` for pass 1 and for the later passes (:func:`_fills`);
    ``settle``: what adds the ground plane to a pass's (n, 2) totals (None: no plane)."""
    n = occlusion.shape[1]
    cell_weights = np.ones(n)
    weights = cell_weights  # pass 1: every level 1
    occluders = None
    for k in range(passes):
        binned = k + 1 < passes  # the next pass needs occlusion by distance
        # cells keep weight 1 in every pass: evaluate them once
        cache_mode = 0 if passes == 1 else (1 if k == 0 else 2)
        sums, first = job.sums(weights, progress, cell_weights, binned, cache_mode, occluders,
                               fill=fills[min(k, 1)])
        _check_sums(sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
        if binned and k == 0:
            occluders = occluder_centroids(job.elements, first)
        total = sums[:, :, -1]
        if settle is not None:
            if k == 0:
                added = settle(total) - total  # settled against pass 1's bins, for every pass
            total = total + added
        occlusion[k] = np.clip(combine_sides(total, sides), 0.0, 1.0)
        if binned:
            weights = _weights_from(sums, sides, damping)


def _shared_passes(job, occlusion, rep_of, evaluated, passes, sides, damping, fills,
                   progress, settle=None) -> None:
    """Pass 1 at every vertex (split by distance: every vertex's own weights); passes
    2..K at the representatives only, walking the tree from the same buckets as pass 1
    (so pass 1 and pass k share their tree approximations there), carried to the
    vertices they stand for as what pass k removed, side by side:
    ``S_k(i) = S_1(i) - (S_1(rep) - S_k(rep))``. What a later pass removes (occlusion
    by emitters at least 2 PASS_RADII[0] away that are themselves in shadow) varies
    smoothly over a leaf; each vertex keeps its own near field and contacts (a ratio
    S_k(rep) / S_1(rep) would scale them: measured worse at contacts)."""
    n = occlusion.shape[1]
    ones = np.ones(n)
    first_sums, first = job.sums(ones, progress, ones, True, 0, fill=fills[0])
    _check_sums(first_sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
    base = first_sums[:, :, -1]
    # the plane joins every pass's totals as pass 1 settled it (what later passes drop is
    # the disks' alone)
    added = 0.0 if settle is None else settle(base) - base
    occlusion[0] = np.clip(combine_sides(base + added, sides), 0.0, 1.0)
    # every vertex's own weights: occlusion within a few edge lengths (the first bins)
    # changes too fast to share (a contact vertex's leaf-mates are open)
    occluders = occluder_centroids(job.elements, first)
    weights = _weights_from(first_sums, sides, damping)
    base_rep = base[rep_of]
    modes = np.zeros(n, dtype=np.uint8)  # later passes: the representatives only
    modes[evaluated] = 2
    for k in range(1, passes):
        binned = k + 1 < passes
        sums, _ = job.sums(weights, progress, ones, binned, 0, occluders, modes, fill=fills[1])
        _check_sums(sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
        shared = sums[rep_of]
        drop = np.maximum(base_rep - shared[:, :, -1], 0.0)  # never above pass 1
        occlusion[k] = np.clip(combine_sides(np.maximum(base - drop, 0.0) + added, sides), 0.0, 1.0)
        if binned:  # passes >= 3: the representatives' weights
            weights = _weights_from(shared, sides, damping)


def occluder_centroids(elements: DiskElements, first: FloatArray) -> FloatArray:
    """(n, 3) centroid of what occludes each vertex, weighted by its terms in the sums:
    ``p + first[:, :3] / first[:, 3]`` (the moment over the summed terms, no direction
    excess removed; normalised coordinates; the vertex itself where nothing occludes it,
    or where the sums are too small to locate anything)."""
    total = first[:, 3]
    located = total > 1e-9
    out = elements.positions.copy()
    out[located] = elements.points[located] + first[located, :3] / total[located, None]
    bad = ~np.isfinite(out).all(axis=1)
    out[bad] = elements.positions[bad]
    return np.ascontiguousarray(out)


def _check_sums(values, what: str, *, lower: float, upper: float) -> None:
    # the extremes first: no temporaries the size of the sums (the bake's memory peak)
    low, high = values.min(initial=lower), values.max(initial=lower)
    if math.isfinite(low) and math.isfinite(high) and low >= lower and high <= upper:
        return
    check_result(values, what, lower=lower, upper=upper, method="bunnell")
