"""Fast AO without rays: Bunnell's oriented disks, a cluster tree, and occlusion passes.

Numpy-facing: validates options, coerces dtypes once, and calls the compiled loops in
``aobake.kernels.bunnell`` (``_k.*``; the tree itself is :mod:`aobake.hierarchy`).
Contains no @njit code and never prints.

References
----------
M. Bunnell, "Dynamic Ambient Occlusion and Indirect Lighting", GPU Gems 2, ch. 14 (2005).
J. Hoberock and Y. Jia, "High-Quality Ambient Occlusion", GPU Gems 3, ch. 12 (2007).
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ._types import AOArray, FloatArray, IndexArray
from .constants import NEAR_OFFSET_REL, PASS_GATE_WIDTH, PASS_RADII
from .contacts import contact_points
from .errors import NumericalError
from .hierarchy import ClusterTree, node_coherence, pack_nodes, refit_tree, tree_keys
from .hierarchy import build_tree as _build_tree
from .kernels import bunnell as _k
from .kernels import hierarchy as _h
from .kernels import polygon as _poly
from .kernels import structures as _s
from .kernels import treepass as _tp
from .kernels import treewalk as _tw
from .mesh import Surface
from .progress import NullProgress, Progress

__all__ = [
    "ClusterTree",
    "DiskElements",
    "bunnell_ao",
    "build_elements",
    "build_tree",
    "combine_passes",
    "numba_threads",
    "occlusion_passes",
    "refit_tree",
    "tree_keys",
]

MEASURES = {"cosine": _k.MEASURE_COSINE, "uniform": _k.MEASURE_UNIFORM}
COMBINES = ("last", "bunnell", "hoberock")
SIDES = ("max", "front")

# Opening parameter: a cluster of area A and bounding radius b is used as one emitter when
# every receiver of a bucket is farther than sqrt(theta * max(A, pi b^2)) from its centre.
# Measured in bench/bench_bunnell.py with per-direction saturation (the default): on the
# 700k crevice scene theta 2 / 4 take 2.1 / 2.95 s in all (plain sums at theta 4: 1.7 s)
# at RMSE 0.022 / 0.015 against the reference (plain: 0.061); theta 4 more than halves the
# error of 2 on facing plates (0.007 vs 0.018) and touching spheres. 2 is the default:
# Embree's 16-ray time at the error of ~60 rays; theta 4 for small meshes.
DEFAULT_THETA = 2.0
# The theta of the plain-sum measurements (hybrid's far field, the benchmark's rows
# without saturation).
PLAIN_THETA = 4.0
# Near field: disks closer than sqrt(NEAR * A) to the receiver are replaced by the exact
# form factor of their barycentric cells. Measured in bench/bench_bunnell.py: near 1
# leaves contact errors (sphere on ground 0.046 vs 0.032 RMSE), near 16 gains <= 0.001
# for 1.6x the time.
DEFAULT_NEAR = 4.0
# Passes k >= 2 weight a disk at distance r from the receiver by 1 - DAMPING * A_{k-1}(j; R)
# with A(j; R) its occlusion by geometry closer than R = PASS_REACH * r to it (cells keep
# weight 1). Bunnell's weight (PASS_REACH = inf: all of A_{k-1}) collapses on single
# layers: facing plates, an object's shadow on the floor. Measured in
# bench/bench_bunnell.py (section 1): see the README table.
DEFAULT_DAMPING = 1.0
DEFAULT_PASS_REACH = 0.5
# Passes >= 2 with a tree: passes 2..K are evaluated at one vertex per tree leaf (the one
# nearest its centre), and what they remove is carried over to the leaf's vertices with a
# normal within arccos(SHARE_COS) of its own; the others are evaluated themselves. Measured
# in bench/bench_bunnell.py: 6.7% of the 700k scene evaluated, 4.0 instead of 4.9 s, RMSE
# against the reference within 1e-3 of every vertex evaluated on all eight scenes.
SHARE_COS = 0.9
# Emitters per leaf (and receivers per bucket): measured in bench/bench_bunnell.py (section
# 2): 16, 32 and 64 cost the same CPU time per pass at 700k vertices (+-3%) before the
# back-facing culls, and 32 and 64 were more accurate than 16 (8 was slower); with the
# culls 1.06 / 1.24 / 1.65 s per pass, tree error against the exact sum 0.022 / 0.020 /
# 0.016 (not re-tuned).
DEFAULT_LEAF_SIZE = 32
# Buckets per kernel call: only for progress reports and Ctrl-C latency.
CHUNK_BUCKETS = 1 << 12


@dataclass(frozen=True)
class DiskElements:
    """One oriented disk per vertex: every vertex receives, disks with area and normal cast.

    Coordinates are normalised: ``(input - origin) / scale`` in float64, so the kernels'
    float32 arithmetic sees numbers of order 1 whatever the mesh's size and position.

    Attributes
    ----------
    positions : (n, 3) float64
        Normalised vertex positions (disk centres).
    normals : (n, 3) float64
        Unit normals, zero rows where a vertex has none.
    areas : (n,) float64
        Disk areas (normalised): 1/3 of the adjacent triangle areas (0 when isolated).
    emitter_index : (k,) int64
        Vertices whose disk casts: ``areas > 0`` and a nonzero normal.
    points : (n, 3) float64
        Where each vertex receives: ``positions + NEAR_OFFSET_REL sqrt(A) n``, moved to
        the vertex's own side where another shell touches it
        (:func:`aobake.contacts.contact_points`).
    corner_start, corners : int64
        Triangles around each vertex (``aobake.kernels.polygon.cell_corners``).
    origin : (3,) float64
        Centre of the input's bounding box.
    scale : float
        Largest extent of the input's bounding box (1 when it is a point).
    """

    positions: FloatArray
    normals: FloatArray
    areas: FloatArray
    emitter_index: IndexArray
    points: FloatArray
    corner_start: IndexArray
    corners: IndexArray
    origin: FloatArray
    scale: float

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_emitters(self) -> int:
        return int(self.emitter_index.shape[0])


def build_elements(surface: Surface) -> DiskElements:
    with np.errstate(under="ignore"):  # denormal inputs: flushing to zero is harmless
        return _build_elements(surface)


def _build_elements(surface: Surface) -> DiskElements:
    """Disk elements of a surface (all parts: one element set for the whole scene).

    Parameters
    ----------
    surface : Surface

    Returns
    -------
    DiskElements
        Area ``A_i = sum_f area_f / 3`` over the triangles f around vertex i
        (``0.5 |e1 x e2|``, never Heron).
    """
    positions = np.ascontiguousarray(surface.positions, dtype=np.float64)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64).reshape(-1, 3)
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or normals.shape != positions.shape:
        raise ValueError(
            f"positions and normals must both be (n, 3), got {positions.shape} and {normals.shape}"
        )
    n = positions.shape[0]
    if n:
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        origin = 0.5 * (lo + hi)
        extent = float((hi - lo).max())
    else:
        origin, extent = np.zeros(3), 0.0
    scale = extent if extent > 0.0 and math.isfinite(extent) else 1.0
    local = np.ascontiguousarray((positions - origin) / scale)
    areas = np.zeros(n)
    _poly.vertex_areas(local, faces, areas)
    casts = (areas > 0.0) & normals.any(axis=1)
    # Receivers sit a tiny lift above their vertex, placed like the reference's ray
    # origins: where another shell touches the vertex (a sphere resting on a floor
    # vertex) or the vertex is sunk into it, the lift along n would cross that surface
    # and the receiver would read open; contacts.contact_points keeps it on the vertex's
    # own side. In normalised coordinates, so its float32 probe rounds alike at any scale.
    normalised = dataclasses.replace(surface, positions=local)
    points, _ = contact_points(normalised, local, np.zeros(3), NEAR_OFFSET_REL * np.sqrt(areas))
    points = np.ascontiguousarray(points)
    corner_start, corners = _poly.cell_corners(faces, n)
    return DiskElements(
        local,
        normals,
        areas,
        np.flatnonzero(casts).astype(np.int64),
        points,
        corner_start,
        corners,
        origin,
        scale,
    )


def build_tree(elements: DiskElements, *, leaf_size: int = DEFAULT_LEAF_SIZE) -> ClusterTree:
    """Cluster tree over the casting disks (:func:`aobake.hierarchy.build_tree`).

    Parameters
    ----------
    elements : DiskElements
        With at least one casting disk.
    leaf_size : int, optional
        Maximum disks per leaf (>= 1).
    """
    leaf_size = _check_int("leaf_size", leaf_size, 1)
    if elements.n_emitters == 0:
        raise ValueError("build_tree needs at least one casting disk (area > 0 and a normal)")
    return _build_tree(
        elements.positions, elements.areas, elements.emitter_index, leaf_size=leaf_size
    )


class _Pass:
    """Kernel inputs of one (elements, tree, options) set, reused by every pass.

    ``pass_reach``: weight levels for passes >= 2 (see :func:`occlusion_passes`).
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
        self.weights = np.ones((order.shape[0], _k.N_LEVELS), dtype=np.float32)
        self.occluders = np.zeros((order.shape[0], 3), dtype=np.float32)
        coherence = node_coherence(tree, elements.normals, elements.areas)
        self.nodes = pack_nodes(tree, theta=theta, near=near, coherence=coherence)
        self.moments = np.zeros((tree.n_nodes, _k.N_LEVELS, _h.MOMENT_COLS), dtype=np.float32)
        self.tree_args = _s.TreeArrays(
            skip=tree.skip, start=tree.start, stop=tree.stop, nodes=self.nodes, moments=self.moments
        )
        self.emitters = _s.Emitters(
            rows=self.rows, index=order, weights=self.weights, occluders=self.occluders
        )
        recv_order, bucket_start = receiver_buckets(elements, tree)
        bounds = np.zeros((bucket_start.shape[0] - 1, _tw.BOUND_COLS))
        _tw.bucket_bounds(elements.points, elements.normals, self.receivers.inner, recv_order,
                          bucket_start, bounds)
        slots = numba.config.NUMBA_NUM_THREADS
        k, m = order.shape[0], tree.n_nodes
        self.bucket_start = bucket_start
        self.buckets = _s.Buckets(
            order=recv_order,
            start=bucket_start,
            bounds=bounds,
            near_buf=np.empty((slots, _tw.NEAR_ROWS, k), dtype=np.float32),
            near_idx=np.empty((slots, 2, k), dtype=np.int64),
            far_buf=np.empty((slots, _tw.FAR_ROWS, m), dtype=np.float32),
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
        """(n, 2, N_BINS) (front, back) sums, cumulative by distance when ``binned``
        (else only the last bin, the total, less the direction excess when directional),
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
        weights = np.asarray(weights, dtype=np.float64)
        if weights.ndim == 1:
            weights = np.repeat(weights[:, None], _k.N_LEVELS, axis=1)
        weights = np.ascontiguousarray(weights)
        cell_weights = np.ascontiguousarray(weights[:, 0] if cell_weights is None else cell_weights)
        leveled = bool(np.any(weights != weights[:, :1]))
        options = self.options._replace(binned=bool(binned), leveled=leveled)
        occluders = np.ascontiguousarray(e.positions if occluders is None else occluders)
        out = np.zeros((n, 2, _k.N_BINS))
        first = np.zeros((n, 4))
        fill = self.no_fill if fill is None else fill
        if self.tree is None:
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
            return out, first
        # only what this pass reads: level 0 unless leveled, the occluders when gated
        if leveled:
            self.weights[:] = weights[self.tree.order]
        else:
            self.weights[:, 0] = weights[self.tree.order, 0]
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
    """``(perm, (positions, corner_start, corners))``: the vertices renumbered so that the
    emitters come first in tree order ``order`` (then the others), with their positions
    and cells (``polygon.permute_cells``). A receiver's near-field cells are its
    neighbours' and their corners are near them: in tree order they are near in memory
    too. (Meshes whose vertex order is scattered, a loop-subdivided scan for one, spent
    3x longer on the same cells in mesh order.)"""
    n = elements.n_vertices
    perm = np.concatenate([order, _non_emitters(n, order)]).astype(np.int64)
    inverse = np.empty(n, dtype=np.int64)
    inverse[perm] = np.arange(n, dtype=np.int64)
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.diff(elements.corner_start)[perm], out=start[1:])
    corners = np.empty_like(elements.corners)
    reach = np.empty(n)
    _poly.permute_cells(elements.positions, elements.corner_start, elements.corners, perm,
                        inverse, start, corners, reach)
    return perm, (np.ascontiguousarray(elements.positions[perm]), start, corners, reach)


def pass_representatives(elements: DiskElements, tree: ClusterTree) -> IndexArray:
    """(n,) vertex whose later passes each vertex takes (itself for non-emitters), see
    :func:`aobake.kernels.hierarchy.leaf_representatives` (SHARE_COS)."""
    rep_of = np.arange(elements.n_vertices, dtype=np.int64)
    _h.leaf_representatives(
        elements.positions, elements.normals, elements.areas, tree.order, tree.skip,
        tree.start, tree.stop, SHARE_COS, rep_of,
    )
    return rep_of


def receiver_buckets(elements: DiskElements, tree: ClusterTree) -> tuple[IndexArray, IndexArray]:
    """Receivers grouped into small, compact buckets that walk the tree together.

    The emitters' tree leaves are the first buckets (in tree order, so consecutive
    buckets are neighbours); the other vertices (no area or no normal) get a tree of
    their own, whose leaves are the remaining buckets.

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
        perm, start, _, skip = _h.build_tree(tree_keys(elements.points[rest]), tree.leaf_size)
        rest_leaves = np.flatnonzero(skip == np.arange(1, skip.shape[0] + 1))
        starts.append(start[rest_leaves] + tree.order.shape[0])
        order.append(rest[perm])
    bucket_start = np.append(np.concatenate(starts), elements.n_vertices).astype(np.int64)
    return np.ascontiguousarray(np.concatenate(order), dtype=np.int64), bucket_start


def occlusion_passes(
    elements: DiskElements,
    tree: ClusterTree | None = None,
    *,
    passes: int = 1,
    theta: float = DEFAULT_THETA,
    near: float = DEFAULT_NEAR,
    sides: str = "max",
    damping: float = DEFAULT_DAMPING,
    pass_reach: float = DEFAULT_PASS_REACH,
    gate: float = PASS_GATE_WIDTH,
    directional: bool = True,
    pass_fill: bool = True,
    share_passes: bool = True,
    measure: str = "cosine",
    max_distance: float | None = None,
    inner: FloatArray | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
) -> FloatArray:
    """Saturated occlusion of every pass, ``A_k = clip(combine_sides(sums_k), 0, 1)``.

    Parameters
    ----------
    elements : DiskElements
    tree : ClusterTree or None
        ``None`` sums every disk exactly (brute force, O(n k): the test reference).
    passes : int
        K >= 1. Pass 1 has ``w_j = 1``; pass k weights disk j, at distance r from the
        receiver, by ``w_j = 1 - damping A_{k-1}(j; pass_reach r)``: disks that are
        themselves in shadow cast less (Bunnell's double-shadow removal), but only by
        the geometry near them, which can stand between them and the receiver. The
        occlusion of j by emitters closer than R is read off distance bins of the
        previous pass (``PASS_RADII``: R is rounded down to a bin radius); near-field
        cells keep weight 1. Gated (``gate > 0``, the default): the occlusion only counts
        for a receiver that has the centroid o_j of what occludes j (from pass 1's sums)
        in front of its tangent plane, ``w_j = 1 - damping A_{k-1}(j; R) g``,
        ``g = clamp(n.(o_j - p) / (gate r), 0, 1)``: the receiver's own surface (the
        facing plate, the ball over its shadow) does not stand between it and j.
    theta : float
        Opening parameter (> 0), ignored without a tree; see :func:`bunnell_ao`.
    near : float
        Near-field factor (>= 0; 0 = disks only); see :func:`bunnell_ao`.
    sides : {"max", "front"}
        ``"max"``: ``max(front, back)``; ``"front"``: front sums only.
    damping : float
        In (0, 1]. ``damping=1, pass_reach=inf, gate=0, near=0`` is Bunnell's published
        scheme.
    pass_reach : float
        > 0, or inf (weights from the whole previous pass, as published).
    gate : float
        >= 0: the gate's width (``PASS_GATE_WIDTH``); 0 = no gate (as published).
    directional : bool
        Per-direction saturation (cosine measure, receivers with a normal): every pass's
        disk and cluster terms are also spread over DIRECTION_SECTORS azimuth sectors x 2
        elevation bands of the receiver's hemisphere, each of cosine-weighted measure
        ``1 / (2 DIRECTION_SECTORS)``, and the total loses what any bin holds beyond that
        (layers stacked in one direction count once, as far as the bins resolve them);
        the near-field cells are not binned. The distance bins below the total stay
        plain sums. False: the plain sum (as published).
    pass_fill : bool
        With ``directional`` and passes >= 2: a later pass removes occlusion from a
        direction bin only in proportion to how empty pass 1 left it. With v1 and v_k a
        bin's content in pass 1 and pass k, each capped at the bin's measure c, the bin
        counts ``v_k + (v1 - v_k) v1 / c`` (``kernels.bunnell.refill``): a bin pass 1
        filled stays full (that direction is blocked, whatever stands in it; inside an
        enclosure a disk can be in shadow and in plain view of the receiver), an empty
        one loses all the pass removes. False: every bin loses it all (``v_k``).
    share_passes : bool
        With a tree and passes >= 2: evaluate passes 2..K at one vertex per leaf and
        normal group only (:func:`pass_representatives`) and carry what they remove
        over to the others (pass 1 stays at every vertex). False: every vertex.
    measure : {"cosine", "uniform"}
    max_distance : float or None
        In mesh units; disks farther than this from the receiver are ignored.
    inner : (n,) float or None
        Per receiver, in mesh units: disks and cells whose centre is closer than this are
        left out (:func:`aobake.hybrid.hybrid_ao` traces rays inside it). None: 0.
    threads : int or None
        numba threads for this call (restored afterwards); None keeps the current setting.
    progress : Progress or None

    Returns
    -------
    occlusion : (K, n) float64 in [0, 1]
        Row k - 1 is pass k's occlusion A_k (not the accessibility).
    """
    passes = _check_int("passes", passes, 1)
    code = _check_measure(measure)
    reach = _check_max_distance(max_distance) / elements.scale
    theta = _check_theta(theta)
    near = _check_near(near)
    _check_sides(sides)
    damping = _check_damping(damping)
    pass_reach = _check_pass_reach(pass_reach)
    gate = _check_gate(gate)
    _check_threads(threads)
    progress = NullProgress() if progress is None else progress
    n = elements.n_vertices
    occlusion = np.zeros((passes, n))
    if elements.n_emitters == 0:  # nothing casts: every vertex is open
        progress.start(passes * n, "bunnell")
        progress.advance(passes * n)
        progress.finish()
        return occlusion
    share = share_passes and tree is not None and passes > 1
    if share:
        rep_of = pass_representatives(elements, tree)
        # representatives in tree order (neighbours), then the vertices that do not cast
        evaluated = np.concatenate(
            [tree.order[rep_of[tree.order] == tree.order], _non_emitters(n, tree.order)]
        )
    progress.start(passes * n, "bunnell")  # every pass walks every bucket
    with numba_threads(threads), np.errstate(under="ignore"):
        if inner is not None:
            inner = np.asarray(inner, dtype=np.float64) / elements.scale
            if inner.shape != (n,) or not np.all(inner >= 0.0):
                raise ValueError(f"inner must be ({n},) and >= 0")
        job = _Pass(elements, tree, theta, near, code, reach, inner, pass_reach, gate, directional)
        # later passes read pass 1's direction bins at the receivers they evaluate
        keepers = evaluated if share else np.arange(n)
        fills = _fills(n, keepers) if pass_fill and directional and passes > 1 else (None, None)
        if share:
            _shared_passes(job, occlusion, rep_of, evaluated, passes, sides, damping, fills,
                           progress)
        else:
            _all_passes(job, occlusion, passes, sides, damping, fills, progress)
    progress.finish()
    return occlusion


def _weights_from(sums: FloatArray, sides: str, damping: float) -> FloatArray:
    """(n, N_LEVELS) pass weights from binned sums: level 0 is 1, level b + 1 is
    ``1 - damping A(j; R_b)`` (occlusion by emitters closer than bin b's outer radius)."""
    weights = np.ones((sums.shape[0], _k.N_LEVELS))
    for b in range(_k.N_BINS):
        weights[:, b + 1] = 1.0 - damping * np.clip(combine_sides(sums[:, :, b], sides), 0.0, 1.0)
    return weights


def _all_passes(job, occlusion, passes, sides, damping, fills, progress) -> None:
    """Every pass at every vertex (the exact sum's and the reference's way); ``fills``:
    the kernels' ``fill`` for pass 1 and for the later passes (:func:`_fills`)."""
    n = occlusion.shape[1]
    weights = np.ones((n, _k.N_LEVELS))
    cell_weights = np.ones(n)
    occluders = None
    for k in range(passes):
        binned = k + 1 < passes  # the next pass needs occlusion by distance
        # cells keep weight 1 in every pass: evaluate them once
        cache_mode = 0 if passes == 1 else (1 if k == 0 else 2)
        sums, first = job.sums(weights, progress, cell_weights, binned, cache_mode, occluders,
                               fill=fills[min(k, 1)])
        _check_result(sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
        if binned and k == 0:
            occluders = occluder_centroids(job.elements, first)
        occlusion[k] = np.clip(combine_sides(sums[:, :, -1], sides), 0.0, 1.0)
        if binned:
            weights = _weights_from(sums, sides, damping)


def _shared_passes(job, occlusion, rep_of, evaluated, passes, sides, damping, fills,
                   progress) -> None:
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
    first_sums, first = job.sums(np.ones((n, _k.N_LEVELS)), progress, ones, True, 0, fill=fills[0])
    _check_result(first_sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
    base = first_sums[:, :, -1]
    occlusion[0] = np.clip(combine_sides(base, sides), 0.0, 1.0)
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
        _check_result(sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
        shared = sums[rep_of]
        drop = np.maximum(base_rep - shared[:, :, -1], 0.0)  # never above pass 1
        occlusion[k] = np.clip(combine_sides(np.maximum(base - drop, 0.0), sides), 0.0, 1.0)
        if binned:  # passes >= 3: the representatives' weights
            weights = _weights_from(shared, sides, damping)


def combine_sides(sums: FloatArray, sides: str = "max") -> FloatArray:
    """Occlusion from the (front, back) sums of one pass.

    ``"front"``: the front sum (front faces cast, the published method). ``"max"``:
    ``max(front, back)``. Outside every closed object each direction crosses as many back
    faces as front faces, so back = front for exact sums and nothing changes; a receiver
    inside a closed object (sunk into it, or on a face it rests on) gets back =
    front + 1, i.e. fully occluded; behind an open sheet (a floor seen from below) the
    back faces count as the ray-traced reference counts them.
    """
    if sides == "front":
        return sums[:, 0].copy()
    return np.maximum(sums[:, 0], sums[:, 1])


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


def combine_passes(occlusion: FloatArray, combine: str = "last") -> AOArray:
    """Accessibility ``ao = 1 - A`` from the passes' occlusion.

    Parameters
    ----------
    occlusion : (K, n) float64 in [0, 1]
        From :func:`occlusion_passes`.
    combine : {"last", "bunnell", "hoberock"}
        ``"last"``: A_K. ``"bunnell"``: 0.4 A_{K-1} + 0.6 A_K (Bunnell's blend of passes 1
        and 2 when K = 2). ``"hoberock"``: on accessibilities a = 1 - A,
        0.7 min(a_{K-1}, a_K) + 0.3 max(a_{K-1}, a_K), a weighted minimum that leans to the
        darker pass because even passes are too light (Hoberock & Jia). Both blends need
        K >= 2.

    Returns
    -------
    ao : (n,) float64 in [0, 1]
    """
    occlusion = np.asarray(occlusion, dtype=np.float64)
    if occlusion.ndim != 2 or occlusion.shape[0] < 1:
        raise ValueError(f"occlusion must have shape (K, n) with K >= 1, got {occlusion.shape}")
    _check_combine(combine, occlusion.shape[0])
    last = 1.0 - occlusion[-1]
    if combine == "last":
        return last
    prev = 1.0 - occlusion[-2]
    if combine == "bunnell":
        return 1.0 - (0.4 * occlusion[-2] + 0.6 * occlusion[-1])
    return 0.7 * np.minimum(prev, last) + 0.3 * np.maximum(prev, last)


def bunnell_ao(
    surface: Surface,
    *,
    passes: int = 1,
    theta: float = DEFAULT_THETA,
    near: float = DEFAULT_NEAR,
    sides: str = "max",
    damping: float = DEFAULT_DAMPING,
    pass_reach: float = DEFAULT_PASS_REACH,
    gate: float = PASS_GATE_WIDTH,
    directional: bool = True,
    pass_fill: bool = True,
    share_passes: bool = True,
    measure: str = "cosine",
    max_distance: float | None = None,
    combine: str = "last",
    exact: bool = False,
    leaf_size: int = DEFAULT_LEAF_SIZE,
    tree: ClusterTree | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
) -> AOArray:
    """Per-vertex ambient accessibility from summed form factors (no rays).

    Each vertex i is a disk (centre p_i, unit normal n_i, area A_i = 1/3 of its triangles'
    area); disk j occludes receiver i by

    - cosine measure (default, matches the ray-traced reference):
      ``F = A_j |cos_e| cos_r / (pi r^2 + A_j)``;
    - uniform measure: ``F = (1 - r / sqrt(A_j / pi + r^2)) |cos_e| clamp(4 cos_r, 0, 1)``,

    with ``d = p_j - p_i``, ``r = |d|``, ``cos_r = max(n_i.d / r, 0)``, ``cos_e = -n_j.d / r``.
    Disks whose front side faces the receiver (``cos_e > 0``) add to the front sum, the
    others to the back sum. Near the receiver (``r^2 < near A_j``) a disk is replaced by
    the exact form factor (cosine) or solid angle (uniform) of the surface it stands for,
    its barycentric cell, clipped to the receiver's tangent plane (Hoberock & Jia's fix
    for dark pinching and contacts). Far clusters of disks count as one emitter.

    Parameters
    ----------
    surface : Surface
        All parts form one scene and occlude each other.
    passes : int, optional
        Number of passes K >= 1: pass k weights each disk by its accessibility from the
        geometry near it, ``1 - damping A_{k-1}(j; pass_reach r)`` (see
        :func:`occlusion_passes`; near-field cells keep weight 1). Default 1 (see
        bench/bench_bunnell.py for the measurements).
    theta : float, optional
        Opening parameter > 0: a cluster of summed area A and bounding radius b (disks
        included) is used as one emitter only when every receiver of a bucket is at
        ``d^2 >= theta * max(A, pi b^2) (1 + OPEN_COHERENCE (1 - c))`` from its centre (and
        outside the near-field reach of its disks); otherwise it is opened.
        ``max(A, pi b^2)`` is Bunnell's and Hoberock's ``d^2 >= eps A`` for compact
        clusters and keeps long thin clusters (A << b^2) from being merged too close;
        ``c = |sum A m| / sum A`` (:func:`aobake.hierarchy.node_coherence`) opens
        clusters whose normals disagree (facing plates, both sides of a ball) sooner.
        Larger = more accurate and slower; theta -> inf is the exact sum.
    near : float, optional
        Near-field factor >= 0: disks with ``r^2 < near A_j`` are replaced by their cells
        (0: disks only, the published method).
    sides : {"max", "front"}, optional
        How the front and back sums make the occlusion (:func:`combine_sides`):
        ``"max"`` (default) or ``"front"`` (front faces cast).
    damping : float, optional
        Pass weight damping in (0, 1].
    pass_reach : float, optional
        > 0; ``inf`` with ``damping=1``, ``gate=0`` and ``near=0`` is Bunnell's published
        scheme.
    gate : float, optional
        Width of the pass weights' gate (>= 0, 0 = ungated; :func:`occlusion_passes`).
    directional : bool, optional
        Per-direction saturation: what direction bins of the receiver's hemisphere hold
        beyond their measure is dropped (:func:`occlusion_passes`). Cosine measure only.
    pass_fill : bool, optional
        Later passes remove occlusion from a direction bin in proportion to how empty
        pass 1 left it (:func:`occlusion_passes`); with ``directional`` only.
    share_passes : bool, optional
        Passes 2..K at one vertex per leaf and normal group (:func:`occlusion_passes`);
        only with ``combine="last"`` (the blends use the second-to-last pass at every
        vertex).
    measure : {"cosine", "uniform"}, optional
    max_distance : float or None, optional
        Ignore disks whose centre is farther than this (mesh units); None = unbounded.
        A cluster is used whole only when it lies entirely inside the limit for every
        receiver of a bucket, so the hierarchy honours it exactly.
    combine : {"last", "bunnell", "hoberock"}, optional
        How passes make the result, see :func:`combine_passes`.
    exact : bool, optional
        Sum every disk (O(n^2), no tree): the reference for the hierarchy.
    leaf_size : int, optional
        Maximum disks per tree leaf.
    tree : ClusterTree or None, optional
        For animation: the tree of an earlier frame of the same mesh (from
        :func:`build_tree` on its :func:`build_elements`). It is refit to this frame's
        positions (:func:`refit_tree`, no sort) instead of rebuilt; rebuilt anyway when
        the set of casting disks changed. The result stays exact as theta grows; a
        tree whose clusters the motion has scrambled is only slower.
    threads : int or None, optional
        numba threads for this call (restored afterwards).
    progress : Progress or None, optional
        Advanced per chunk of receivers over all passes.

    Returns
    -------
    ao : (n,) float64 in [0, 1]
        Accessibility 1 - A, 1 = fully open, in input vertex order.

    Raises
    ------
    ValueError
        An option is out of range (a programming error; the CLI validates first).
    NumericalError
        The result is not finite or not in [0, 1] (a bug).

    Notes
    -----
    Receivers sit NEAR_OFFSET_REL edge lengths above their vertex along the normal (the
    analogue of a ray origin offset). Skipped without dividing by zero: the receiver's
    own disk and coincident disks (split vertices: ``r^2 <= 1e-12 A_j``); triangles
    through the receiver are seen edge-on. Disks with zero area (isolated vertices,
    degenerate faces) or no normal cast nothing but still receive. A receiver without a
    normal uses disks only and the mean of the receiver weight over all normal
    directions (1/4 for cosine, 1/2 for uniform): the occluded fraction of the full
    sphere. Coordinates are recentred and normalised in float64 before the float32
    kernels, so the method is scale and translation invariant.
    """
    passes = _check_int("passes", passes, 1)
    _check_combine(combine, passes)
    elements = build_elements(surface)
    given, tree = tree, None
    if not exact and elements.n_emitters > 0:
        _check_theta(theta)
        same = given is not None and np.array_equal(np.sort(given.order), elements.emitter_index)
        if same:
            tree = refit_tree(given, elements.positions, elements.areas)
        else:
            tree = build_tree(elements, leaf_size=leaf_size)
    occlusion = occlusion_passes(
        elements,
        tree,
        passes=passes,
        theta=theta,
        near=near,
        sides=sides,
        damping=damping,
        pass_reach=pass_reach,
        gate=gate,
        directional=bool(directional),
        pass_fill=bool(pass_fill),
        share_passes=bool(share_passes) and combine == "last",
        measure=measure,
        max_distance=max_distance,
        threads=threads,
        progress=progress,
    )
    ao = combine_passes(occlusion, combine)
    _check_result(ao, "ao", lower=0.0, upper=1.0)
    return ao


@contextmanager
def numba_threads(threads: int | None):
    """Run the body with ``numba.set_num_threads(threads)``, then restore the old count."""
    if threads is None:
        yield
        return
    import numba

    old = numba.get_num_threads()
    numba.set_num_threads(_check_threads(threads))
    try:
        yield
    finally:
        numba.set_num_threads(old)


# ---------------------------------------------------------------------------------------
# helpers


def _check_result(values: np.ndarray, what: str, *, lower: float, upper: float) -> None:
    bad = ~np.isfinite(values) | (values < lower) | (values > upper)
    if bad.any():
        first = np.unravel_index(int(np.flatnonzero(bad)[0]), values.shape)[0]
        raise NumericalError(
            f"bunnell: {int(bad.sum())} values of {what} outside [{lower}, {upper}] "
            "or non-finite "
            f"(first: vertex {int(first)}, value {values[first]!r})"
        )


def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise ValueError(f"{name} must be an integer >= {lowest}, got {value!r}")
    return int(value)


def _check_measure(measure: str) -> int:
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {sorted(MEASURES)}, got {measure!r}")
    return MEASURES[measure]


def _check_sides(sides: str) -> None:
    if sides not in SIDES:
        raise ValueError(f"sides must be one of {list(SIDES)}, got {sides!r}")


def _check_combine(combine: str, passes: int) -> None:
    if combine not in COMBINES:
        raise ValueError(f"combine must be one of {list(COMBINES)}, got {combine!r}")
    if combine != "last" and passes < 2:
        raise ValueError(
            f"combine={combine!r} blends the last two passes and needs passes >= 2, got {passes}"
        )


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.floating, np.integer))


def _check_theta(theta: float) -> float:
    if not _is_number(theta):
        raise ValueError(f"theta must be a positive number, got {theta!r}")
    if not (theta > 0.0) or math.isnan(theta):
        raise ValueError(f"theta must be > 0, got {theta!r}")
    return float(theta)


def _check_damping(damping: float) -> float:
    if not _is_number(damping) or not (0.0 < damping <= 1.0):
        raise ValueError(f"damping must be in (0, 1], got {damping!r}")
    return float(damping)


def _check_pass_reach(pass_reach: float) -> float:
    if not _is_number(pass_reach) or not (pass_reach > 0.0):
        raise ValueError(f"pass_reach must be > 0 (inf: Bunnell's weights), got {pass_reach!r}")
    return float(pass_reach)


def _check_gate(gate: float) -> float:
    if not _is_number(gate) or not (0.0 <= gate < math.inf):
        raise ValueError(f"gate must be a finite number >= 0 (0 = ungated), got {gate!r}")
    return float(gate)


def _check_near(near: float) -> float:
    if not _is_number(near) or not (0.0 <= near < math.inf):
        raise ValueError(f"near must be a finite number >= 0, got {near!r}")
    return float(near)


def _check_max_distance(max_distance: float | None) -> float:
    if max_distance is None:
        return math.inf
    if not _is_number(max_distance):
        raise ValueError(f"max_distance must be a positive number or None, got {max_distance!r}")
    if not (0.0 < max_distance < math.inf):
        raise ValueError(
            f"max_distance must be finite and > 0 (None = unbounded), got {max_distance!r}"
        )
    return float(max_distance)


def _check_threads(threads: int | None) -> int | None:
    if threads is None:
        return None
    import numba

    top = numba.config.NUMBA_NUM_THREADS
    if (
        isinstance(threads, bool)
        or not isinstance(threads, (int, np.integer))
        or not 1 <= threads <= top
    ):
        raise ValueError(f"threads must be an integer in [1, {top}] or None, got {threads!r}")
    return int(threads)
