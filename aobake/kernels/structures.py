"""Named arguments of the disk method's pass kernels (``bunnell.brute_force_pass``,
``treepass.hierarchy_pass``): tuples of arrays and scalars with named fields.

numba takes a ``typing.NamedTuple`` as a tuple with attribute access. The wrappers build
these once and vary them per pass with ``._replace``; keep each field's type fixed (a
float stays a float) so that every kernel compiles once. numba's cache index pickles
these classes by name: after renaming or moving one, clear the kernels' ``__pycache__``.

Imports nothing but numpy (the field types).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class PassOptions(NamedTuple):
    """What one pass computes (both kernels)."""

    #: measure code (``aobake.constants.MEASURE_*``)
    measure: int
    #: centre-distance limit (normalised units; ``inf``: unbounded)
    max_distance: float
    #: near-field factor: emitters with ``r^2 < near A`` are replaced by their cells (0: none)
    near: float
    #: split the sums by distance (cumulative bins)
    binned: bool
    #: (N_BINS,) float64 squared outer radii of the distance bins
    bin_r2: np.ndarray
    #: (N_BINS,) float64 squared distance thresholds of the weight levels
    weight_r2: np.ndarray
    #: the weights differ between levels (only then are they gated)
    leveled: bool
    #: gate width (0: weights not gated)
    gate: float
    #: saturate per direction (cosine measure, receivers with a normal)
    directional: bool


class Receivers(NamedTuple):
    """Where the sums are evaluated (both kernels)."""

    #: (n, 3) float64 evaluation points
    points: np.ndarray
    #: (n, 3) float64 unit normals, or zero rows
    normals: np.ndarray
    #: (n,) float64 inner radius: emitters closer than it are left out (0: none)
    inner: np.ndarray
    #: (n,) uint8 for the tree pass: 0 nothing, 1 the total only, 2 binned when ``binned``
    modes: np.ndarray


class Fill(NamedTuple):
    """What receivers do with their direction bins for later passes (both kernels)."""

    #: (m, 2, 2 SECTORS) float64 kept bins
    store: np.ndarray
    #: (n,) int64 receiver's row of ``store`` (-1: none)
    slot: np.ndarray
    #: ``bunnell.FILL_NONE`` / ``FILL_KEEP`` / ``FILL_GIVE`` / ``FILL_KEEP_IF``
    mode: int


class Disks(NamedTuple):
    """Every vertex's disk, float64 (the exact sum)."""

    positions: np.ndarray  #: (n, 3) disk centres (not offset)
    normals: np.ndarray  #: (n, 3) unit normals
    areas: np.ndarray  #: (n,)
    weights: np.ndarray  #: (n, N_LEVELS) weight per level
    occluders: np.ndarray  #: (n, 3) centroid of what occludes the disk (gated passes)


class Cells(NamedTuple):
    """Near-field cells of every vertex (the exact sum): ``polygon.cell_terms``."""

    corner_start: np.ndarray  #: (n + 1,) int64
    corners: np.ndarray  #: (c, 2) int64
    weights: np.ndarray  #: (n,) float64 the cells' pass weights


class TreeArrays(NamedTuple):
    """The cluster tree (``aobake.kernels.hierarchy``), refit for this pass."""

    skip: np.ndarray  #: (m,) int64 node after each subtree
    start: np.ndarray  #: (m,) int64 first emitter of each node (tree order)
    stop: np.ndarray  #: (m,) int64
    nodes: np.ndarray  #: (m, NODE_COLS) float32
    moments: np.ndarray  #: (m, N_LEVELS, MOMENT_COLS) float32


class Emitters(NamedTuple):
    """The casting disks in tree order (tree pass)."""

    rows: np.ndarray  #: (k, EMITTER_COLS) float32
    index: np.ndarray  #: (k,) int64 vertex of each
    weights: np.ndarray  #: (k, N_LEVELS) float32
    occluders: np.ndarray  #: (k, 3) float32 occluder centroids (gated passes)


class NearField(NamedTuple):
    """Near-field cells renumbered to tree order (``polygon.renumbered_cells``): row k is
    the emitter at tree position k, the other vertices follow."""

    positions: np.ndarray  #: (n, 3) float64 vertex positions
    weights: np.ndarray  #: (n,) float64 the cells' pass weights
    corner_start: np.ndarray  #: (n + 1,) int64
    corners: np.ndarray  #: (c, 2) int32 (int64 from 2^31 vertices on)
    reach: np.ndarray  #: (n,) float64 farthest corner from the vertex
    #: (n, 2, N_BINS) float64 each receiver's cell sums, cumulative by distance bin
    cache: np.ndarray
    #: 0 ignore the cache, 1 write it, 2 read it instead of evaluating the cells
    cache_mode: int


class Buckets(NamedTuple):
    """Receivers grouped in buckets that walk the tree together, and per-thread scratch."""

    order: np.ndarray  #: (n,) int64 receivers in bucket order
    start: np.ndarray  #: (nb + 1,) int64 bucket b is ``order[start[b]:start[b + 1]]``
    bounds: np.ndarray  #: (nb, treewalk.BOUND_COLS) float64
    near_buf: np.ndarray  #: (T, treewalk.NEAR_ROWS, k) float32
    near_idx: np.ndarray  #: (T, 2, k) int64
    far_buf: np.ndarray  #: (T, treewalk.FAR_ROWS, m) float32


class Span(NamedTuple):
    """Buckets ``first:stop`` of one kernel call on ``threads`` threads."""

    first: int
    stop: int
    #: ``numba.get_num_threads()`` (a call inside the kernel would stop it from being cached)
    threads: int
