"""Fast AO without rays: Bunnell's oriented disks, a cluster tree, and occlusion passes.

Numpy-facing: validates options, coerces dtypes once, and calls the compiled loops in
``aobake.kernels.bunnell`` (``_k.*``). Contains no @njit code and never prints.

References
----------
M. Bunnell, "Dynamic Ambient Occlusion and Indirect Lighting", GPU Gems 2, ch. 14 (2005).
J. Hoberock and Y. Jia, "High-Quality Ambient Occlusion", GPU Gems 3, ch. 12 (2007).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ._types import AOArray, FloatArray, IndexArray
from .errors import NumericalError
from .kernels import bunnell as _k
from .mesh import Surface, vertex_areas
from .progress import NullProgress, Progress

MEASURES = {"cosine": _k.MEASURE_COSINE, "uniform": _k.MEASURE_UNIFORM}
COMBINES = ("last", "bunnell", "hoberock")

# Opening parameter: a cluster of area A and bounding radius b is used as one emitter when
# d^2 >= theta * max(A, pi b^2). Measured in bench/bench_bunnell.py (pass-1 occlusion
# against the exact sum): theta = 4 costs ~0.6x the time of theta = 8 for an RMSE of
# 0.004-0.014 on the bench scenes, well below the method's own error against ray tracing
# (0.04-0.13), which the hierarchy error barely changes.
DEFAULT_THETA = 4.0
# Emitters per leaf: near-field leaves are summed exactly; 8-16 was fastest on the bench
# scenes (fewer, denser nodes), and larger leaves only lower the error.
DEFAULT_LEAF_SIZE = 16
# Receivers per kernel call: only for progress reports (a call is ~0.1 s on 2 cores).
CHUNK_RECEIVERS = 1 << 16


@dataclass(frozen=True)
class DiskElements:
    """One oriented disk per vertex: every vertex receives, disks with area and normal cast.

    Attributes
    ----------
    positions : (n, 3) float64
        Vertex positions minus ``origin`` (recentred in float64, so a mesh far from the
        origin gives the same result as the same mesh at it).
    normals : (n, 3) float64
        Unit normals, zero rows where a vertex has none.
    areas : (n,) float64
        Disk areas: 1/3 of the adjacent triangle areas (zero for isolated vertices).
    emitter_index : (k,) int64
        Vertices whose disk casts: ``areas > 0`` and a nonzero normal.
    origin : (3,) float64
        Centre of the bounding box, subtracted from the input positions.
    """

    positions: FloatArray
    normals: FloatArray
    areas: FloatArray
    emitter_index: IndexArray
    origin: FloatArray

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_emitters(self) -> int:
        return int(self.emitter_index.shape[0])


@dataclass(frozen=True)
class ClusterTree:
    """A flat binary cluster tree over the casting disks (preorder, skip pointers).

    Attributes
    ----------
    order : (k,) int64
        Vertex index of each emitter in tree order; node ranges index this array.
    start, stop : (m,) int64
        Node ``q`` holds emitters ``order[start[q]:stop[q]]``.
    skip : (m,) int64
        Node after ``q``'s subtree; the first child of an internal node is ``q + 1`` and
        ``skip[q] == q + 1`` marks a leaf.
    centers : (m, 3) float64
        Area-weighted mean disk position (recentred coordinates).
    radii : (m,) float64
        Bounding radius about the centre, disk radii included.
    areas : (m,) float64
        Summed disk area.
    leaf_size : int
        Maximum emitters per leaf.
    """

    order: IndexArray
    start: IndexArray
    stop: IndexArray
    skip: IndexArray
    centers: FloatArray
    radii: FloatArray
    areas: FloatArray
    leaf_size: int

    @property
    def n_nodes(self) -> int:
        return int(self.skip.shape[0])


def build_elements(surface: Surface) -> DiskElements:
    """Disk elements of a surface (all parts: one element set for the whole scene).

    Parameters
    ----------
    surface : Surface

    Returns
    -------
    DiskElements
        Positions recentred on the bounding-box centre; area ``A_i = sum_f area_f / 3``
        over the triangles f around vertex i (``0.5 |e1 x e2|``, never Heron).
    """
    positions = np.ascontiguousarray(surface.positions, dtype=np.float64)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64)
    normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or normals.shape != positions.shape:
        raise ValueError(
            f"positions and normals must both be (n, 3), got {positions.shape} and {normals.shape}"
        )
    origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    local = np.ascontiguousarray(positions - origin)
    areas = vertex_areas(local, faces) if faces.size else np.zeros(positions.shape[0])
    casts = (areas > 0.0) & normals.any(axis=1)
    return DiskElements(local, normals, areas, np.flatnonzero(casts).astype(np.int64), origin)


def build_tree(elements: DiskElements, *, leaf_size: int = DEFAULT_LEAF_SIZE) -> ClusterTree:
    """Cluster tree over the casting disks: median split on the longest axis.

    Parameters
    ----------
    elements : DiskElements
        With at least one casting disk.
    leaf_size : int, optional
        Maximum disks per leaf (>= 1).

    Returns
    -------
    ClusterTree

    Notes
    -----
    Built iteratively in ``_k.build_tree`` (explicit stack, quickselect: O(k log k)) on
    quantised integer keys (:func:`tree_keys`), ties broken by index, so the same mesh
    scaled or translated gets the same tree; a range whose keys all coincide is split by
    index. A node's area is the sum of its disks' areas, its centre their area-weighted
    mean position, its radius bounds every disk. Normal sums and second moments are refit
    per pass (weighted by accessibility) in ``_k.refit_nodes``.
    """
    leaf_size = _check_int("leaf_size", leaf_size, 1)
    if elements.n_emitters == 0:
        raise ValueError("build_tree needs at least one casting disk (area > 0 and a normal)")
    emit = elements.emitter_index
    perm, start, stop, skip = _k.build_tree(tree_keys(elements.positions[emit]), leaf_size)
    order = np.ascontiguousarray(emit[perm])
    geometry = np.zeros((skip.shape[0], 5))
    _k.node_geometry(pack_emitters(elements, order), start, stop, geometry)
    centers = np.ascontiguousarray(geometry[:, :3])
    radii = np.ascontiguousarray(geometry[:, 3])
    areas = np.ascontiguousarray(geometry[:, 4])
    return ClusterTree(order, start, stop, skip, centers, radii, areas, leaf_size)


def occlusion_passes(
    elements: DiskElements,
    tree: ClusterTree | None = None,
    *,
    passes: int = 1,
    theta: float = DEFAULT_THETA,
    measure: str = "cosine",
    max_distance: float | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
) -> FloatArray:
    """Saturated occlusion of every pass: ``A_k = clip(sum_j w_j F(j -> i), 0, 1)``.

    Parameters
    ----------
    elements : DiskElements
    tree : ClusterTree or None
        ``None`` sums every disk exactly (brute force, O(n k): the test reference).
    passes : int
        K >= 1. Pass 1 has ``w_j = 1``; pass k has ``w_j = 1 - A_{k-1}(j)``, so disks
        that are themselves in shadow cast less (Bunnell's double-shadow removal).
    theta : float
        Opening parameter (> 0), ignored without a tree; see :func:`bunnell_ao`.
    measure : {"cosine", "uniform"}
    max_distance : float or None
        Disks farther than this from the receiver are ignored; None = unbounded.
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
    reach = _check_max_distance(max_distance)
    theta = _check_theta(theta)
    _check_threads(threads)
    progress = NullProgress() if progress is None else progress
    n = elements.n_vertices
    occlusion = np.zeros((passes, n))
    progress.start(passes * n, "bunnell")
    if elements.n_emitters == 0:  # nothing casts: every vertex is open
        progress.advance(passes * n)
        progress.finish()
        return occlusion
    order = elements.emitter_index if tree is None else tree.order
    emitters = pack_emitters(elements, order)
    receivers = _k.Receivers(elements.positions, elements.normals)
    # receivers in emitter (tree) order, so neighbouring threads walk similar nodes
    rest = np.setdiff1d(np.arange(n, dtype=np.int64), order, assume_unique=True)
    receiver_order = np.ascontiguousarray(np.concatenate([order, rest]))
    packed_tree = None if tree is None else pack_tree(tree, theta)
    sums = np.zeros(n)
    with numba_threads(threads):
        for k in range(passes):
            if k > 0:
                emitters.data[:, _k.E_WEIGHT] = 1.0 - occlusion[k - 1][order]
            if packed_tree is not None:
                _k.refit_nodes(emitters, packed_tree)
            for lo in range(0, n, CHUNK_RECEIVERS):
                chunk = receiver_order[lo : lo + CHUNK_RECEIVERS]
                if packed_tree is None:
                    _k.brute_force_pass(emitters, receivers, chunk, code, reach, sums)
                else:
                    _k.hierarchy_pass(emitters, packed_tree, receivers, chunk, code, reach, sums)
                progress.advance(chunk.shape[0])
            _check_result(sums, "unsaturated occlusion sum", lower=0.0, upper=np.inf)
            occlusion[k] = np.clip(sums, 0.0, 1.0)
    progress.finish()
    return occlusion


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
    measure: str = "cosine",
    max_distance: float | None = None,
    combine: str = "last",
    exact: bool = False,
    leaf_size: int = DEFAULT_LEAF_SIZE,
    threads: int | None = None,
    progress: Progress | None = None,
) -> AOArray:
    """Per-vertex ambient accessibility from summed disk form factors (no rays).

    Each vertex i is a disk (centre p_i, unit normal n_i, area A_i = 1/3 of its triangles'
    area); disk j occludes receiver i by

    - cosine measure (default, matches the ray-traced reference):
      ``F = A_j cos_e cos_r / (pi r^2 + A_j)``;
    - uniform measure: ``F = (1 - r / sqrt(A_j / pi + r^2)) cos_e clamp(4 cos_r, 0, 1)``,

    with ``d = p_j - p_i``, ``r = |d|``, ``cos_r = max(n_i.d / r, 0)`` and
    ``cos_e = max(-n_j.d / r, 0)``: **front faces cast** (the emitter's front side faces
    the receiver; back faces would ignore single-sided occluders such as a ground plane).
    Pass 1: ``A_1 = clip(sum_j F, 0, 1)``; pass k weights each F by the emitter's
    accessibility ``1 - A_{k-1}(j)``. Far clusters of disks count as one disk.

    Parameters
    ----------
    surface : Surface
        All parts form one scene and occlude each other.
    passes : int, optional
        Number of passes K >= 1. Default 1: measured against Embree (1024 rays) on four
        hard scenes, pass 1 alone was closest everywhere; every later pass and the
        published blends were worse (pass 2 RMSE ~2x pass 1), because where pass 1
        saturates the emitters get weight ~0 (see bench/bench_bunnell.py, section 4).
    theta : float, optional
        Opening parameter > 0: a cluster of summed area A and bounding radius b (disks
        included) at distance d from the receiver is used as one disk iff
        ``d^2 >= theta * max(A, pi b^2)`` and ``d > b``; otherwise it is opened (its
        children, or a leaf's disks, are summed). ``max(A, pi b^2)`` is Bunnell's and
        Hoberock's ``d^2 >= eps A`` for compact clusters and keeps long thin clusters
        (A << b^2) from being merged too close. Larger = more accurate and slower;
        theta -> inf is the exact sum.
    measure : {"cosine", "uniform"}, optional
    max_distance : float or None, optional
        Ignore disks whose centre is farther than this (mesh units); None = unbounded.
        A cluster is skipped when ``d - b > max_distance`` and opened when it straddles
        the limit, so the hierarchy honours it exactly.
    combine : {"last", "bunnell", "hoberock"}, optional
        How passes make the result, see :func:`combine_passes`.
    exact : bool, optional
        Sum every disk (O(n^2), no tree): the reference for the hierarchy.
    leaf_size : int, optional
        Maximum disks per tree leaf.
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
    Skipped without dividing by zero: the receiver's own disk and coincident disks
    (split vertices: ``r^2 <= 1e-12 A_j``). Disks with zero area (isolated vertices,
    degenerate faces) or no normal cast nothing but still receive. A receiver without a
    normal uses the mean of the receiver weight over all normal directions (1/4 for
    cosine, 1/2 for uniform), i.e. its occlusion is the occluded fraction of the full
    sphere. The method is scale and translation invariant (positions are recentred in
    float64; every epsilon is relative).
    """
    passes = _check_int("passes", passes, 1)
    _check_combine(combine, passes)
    elements = build_elements(surface)
    tree = None
    if not exact and elements.n_emitters > 0:
        _check_theta(theta)
        tree = build_tree(elements, leaf_size=leaf_size)
    occlusion = occlusion_passes(
        elements,
        tree,
        passes=passes,
        theta=theta,
        measure=measure,
        max_distance=max_distance,
        threads=threads,
        progress=progress,
    )
    ao = combine_passes(occlusion, combine)
    _check_result(ao, "ao", lower=0.0, upper=1.0)
    return ao


def tree_keys(positions: FloatArray) -> IndexArray:
    """Integer keys for the tree build: positions quantised to ``_k.KEY_STEPS`` steps of
    the largest bounding-box extent (the same step on every axis, so the longest axis is
    still the longest). Returns (k, 3) int64; all zeros when every point coincides.
    """
    positions = np.asarray(positions, dtype=np.float64)
    lo = positions.min(axis=0)
    extent = float((positions.max(axis=0) - lo).max())
    if not extent > 0.0:
        return np.zeros(positions.shape, dtype=np.int64)
    return np.ascontiguousarray(
        np.floor((positions - lo) * (_k.KEY_STEPS / extent) + 0.5), dtype=np.int64
    )


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


def pack_emitters(elements: DiskElements, order: IndexArray) -> _k.Emitters:
    """Kernel rows of the casting disks ``order`` (weights 1), see ``_k.Emitters``."""
    data = np.zeros((order.shape[0], _k.EMITTER_COLS))
    data[:, _k.E_X : _k.E_Z + 1] = elements.positions[order]
    data[:, _k.E_MX : _k.E_MZ + 1] = elements.normals[order]
    data[:, _k.E_AREA] = elements.areas[order]
    data[:, _k.E_WEIGHT] = 1.0
    return _k.Emitters(data, np.ascontiguousarray(order, dtype=np.int64))


def pack_tree(tree: ClusterTree, theta: float) -> _k.Tree:
    """Kernel rows of a tree for one theta: geometry and the opening distance
    ``open_d2 = max(theta max(A, pi b^2), b^2 (1 + ulp))`` (strictly outside the bounding
    sphere whatever theta); the per-pass columns are left to ``_k.refit_nodes``.
    """
    data = np.zeros((tree.n_nodes, _k.NODE_COLS))
    data[:, _k.N_X : _k.N_Z + 1] = tree.centers
    data[:, _k.N_RADIUS] = tree.radii
    data[:, _k.N_OPEN_D2] = np.maximum(
        theta * np.maximum(tree.areas, np.pi * tree.radii**2), np.nextafter(tree.radii**2, np.inf)
    )
    data[:, _k.N_AREA] = tree.areas
    return _k.Tree(tree.skip, tree.start, tree.stop, data)


def _check_result(values: np.ndarray, what: str, *, lower: float, upper: float) -> None:
    bad = ~np.isfinite(values) | (values < lower) | (values > upper)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise NumericalError(
            f"bunnell: {int(bad.sum())} vertices have {what} outside [{lower}, {upper}] "
            "or non-finite "
            f"(first: vertex {first}, value {values[first]!r})"
        )


def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise ValueError(f"{name} must be an integer >= {lowest}, got {value!r}")
    return int(value)


def _check_measure(measure: str) -> int:
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {sorted(MEASURES)}, got {measure!r}")
    return MEASURES[measure]


def _check_combine(combine: str, passes: int) -> None:
    if combine not in COMBINES:
        raise ValueError(f"combine must be one of {list(COMBINES)}, got {combine!r}")
    if combine != "last" and passes < 2:
        raise ValueError(
            f"combine={combine!r} blends the last two passes and needs passes >= 2, got {passes}"
        )


def _check_theta(theta: float) -> float:
    if isinstance(theta, bool) or not isinstance(theta, (int, float, np.floating, np.integer)):
        raise ValueError(f"theta must be a positive number, got {theta!r}")
    if not (theta > 0.0) or math.isnan(theta):
        raise ValueError(f"theta must be > 0, got {theta!r}")
    return float(theta)


def _check_max_distance(max_distance: float | None) -> float:
    if max_distance is None:
        return math.inf
    if isinstance(max_distance, bool) or not isinstance(
        max_distance, (int, float, np.floating, np.integer)
    ):
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
