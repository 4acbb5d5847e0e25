"""The disk method's cluster tree, numpy-facing: build, refit after a move, pack for a pass.

Wraps ``aobake.kernels.hierarchy`` (``_k.*``). Contains no @njit code and never prints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..._types import FloatArray, IndexArray
from ...constants import OPEN_COHERENCE, TREE_KEY_STEPS
from ...kernels import hierarchy as _k


@dataclass(frozen=True)
class ClusterTree:
    """A flat binary cluster tree over casting disks (preorder, skip pointers).

    Attributes
    ----------
    order : (k,) int64
        Vertex index of each emitter in tree order; node ranges index this array.
    start, stop : (m,) int64
        Node ``q`` holds emitters ``order[start[q]:stop[q]]``.
    skip : (m,) int64
        Node after ``q``'s subtree; the first child of an internal node is ``q + 1`` and
        ``skip[q] == q + 1`` marks a leaf.
    geometry : (m, 6) float64
        Per node: area-weighted mean disk centre (3), bounding radius (disks included),
        summed area, largest disk area. Positions move: :func:`refit_tree`.
    leaf_size : int
        Maximum emitters per leaf.
    """

    order: IndexArray
    start: IndexArray
    stop: IndexArray
    skip: IndexArray
    geometry: FloatArray
    leaf_size: int

    @property
    def n_nodes(self) -> int:
        return int(self.skip.shape[0])

    @property
    def centers(self) -> FloatArray:
        return self.geometry[:, :3]

    @property
    def radii(self) -> FloatArray:
        return self.geometry[:, 3]

    @property
    def areas(self) -> FloatArray:
        return self.geometry[:, 4]

    @property
    def leaves(self) -> IndexArray:
        """Leaf node indices, in tree order."""
        return np.flatnonzero(self.skip == np.arange(1, self.n_nodes + 1))


def tree_keys(positions: FloatArray, rows: IndexArray | None = None) -> IndexArray:
    """Integer keys for the tree build: positions (the ``rows`` of ``positions``, default
    all) quantised to ``TREE_KEY_STEPS`` steps of the largest bounding-box extent (the same
    step on every axis, so the longest axis is still the longest). Returns (k, 3) int64;
    all zeros when every point coincides.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    if rows is None:
        rows = np.arange(positions.shape[0], dtype=np.int64)
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    if rows.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.int64)
    out = np.empty((rows.shape[0], 3), dtype=np.int64)
    _k.quantised_keys(positions, rows, float(TREE_KEY_STEPS), out)
    return out


def build_tree(
    positions: FloatArray, areas: FloatArray, emitters: IndexArray, *, leaf_size: int
) -> ClusterTree:
    """Cluster tree over the disks ``emitters``: median split on the longest axis.

    Parameters
    ----------
    positions : (n, 3) float64
        Disk centres of every vertex.
    areas : (n,) float64
        Disk areas (> 0 for every emitter).
    emitters : (k,) int64, k >= 1
        Vertices whose disks cast.
    leaf_size : int >= 1

    Returns
    -------
    ClusterTree

    Notes
    -----
    Built iteratively in ``_k.build_tree`` (explicit stack, quickselect: O(k log k)) on
    quantised integer keys (:func:`tree_keys`), ties broken by index, so the same mesh
    scaled or translated gets the same tree; a range whose keys all coincide is split by
    index.
    """
    emitters = np.ascontiguousarray(emitters, dtype=np.int64)
    perm, start, stop, skip = _k.build_tree(tree_keys(positions, emitters), int(leaf_size))
    order = np.ascontiguousarray(emitters[perm])
    geometry = node_geometry(positions, areas, order, start, stop)
    return ClusterTree(order, start, stop, skip, geometry, int(leaf_size))


def refit_tree(tree: ClusterTree, positions: FloatArray, areas: FloatArray) -> ClusterTree:
    """The same tree (order, ranges, skip pointers) with geometry for moved disks.

    For animation: O(k log k) without the sort of a build. The tree stays valid for any
    positions (node spheres bound their disks by construction); it only gets slower,
    not less accurate, as the motion scrambles its clusters, so rebuild when a refit
    pass gets much slower than a fresh one. Every emitter must keep an area > 0.
    """
    geometry = node_geometry(positions, areas, tree.order, tree.start, tree.stop)
    return ClusterTree(tree.order, tree.start, tree.stop, tree.skip, geometry, tree.leaf_size)


def node_geometry(positions, areas, order, start, stop) -> FloatArray:
    """(m, 6) float64 node geometry (``_k.node_geometry``) of emitters ``order``."""
    out = np.zeros((start.shape[0], 6))
    _k.node_geometry(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(areas, dtype=np.float64),
        order,
        start,
        stop,
        out,
    )
    return out


def node_coherence(tree: ClusterTree, normals: FloatArray, areas: FloatArray) -> FloatArray:
    """(m,) float64 in [0, 1]: per node ``|sum A m| / sum A`` over its disks (unit normals
    m): 1 for a flat patch, near 0 for a node whose normals cancel (two facing plates,
    both sides of a ball). Prefix sums in tree order: O(k + m) (``_k.node_coherence``)."""
    out = np.empty(tree.n_nodes)
    with np.errstate(invalid="ignore", divide="ignore"):
        _k.node_coherence(
            np.ascontiguousarray(normals, dtype=np.float64),
            np.ascontiguousarray(areas, dtype=np.float64),
            tree.order,
            tree.start,
            tree.stop,
            out,
        )
    return out


def pack_nodes(
    tree: ClusterTree, *, theta: float, near: float, coherence: FloatArray | None = None
) -> np.ndarray:
    """float32 node rows (``_k.N_*``) for one opening parameter; per-pass columns zero.

    ``open_d2 = max(theta max(A, pi b^2) (1 + OPEN_COHERENCE (1 - c)), (b + sqrt(near
    A_max))^2)``: a node is used whole only when the receivers are farther than this from
    its centre: far for its size (and farther when its normals disagree: ``c`` from
    :func:`node_coherence`, 1 when ``coherence`` is None), and beyond the near-field reach
    ``sqrt(near A_j)`` of every disk in it (which also keeps them outside its bounding
    sphere). The squared distance is rounded up to the next float32 so the float32
    comparison never accepts a node closer than this.
    """
    nodes = np.zeros((tree.n_nodes, _k.NODE_COLS), dtype=np.float32)
    g = tree.geometry
    b = g[:, 3]
    reach = b + np.sqrt(near * g[:, 5]) if near > 0 else b
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        size = np.maximum(g[:, 4], math.pi * b**2)
        if coherence is not None:
            size = size * (1.0 + OPEN_COHERENCE * (1.0 - np.asarray(coherence, dtype=np.float64)))
        open_d2 = np.maximum(theta * size, reach**2)
        open_d2 = np.where(np.isnan(open_d2), np.inf, open_d2)
        open32 = open_d2.astype(np.float32)
        open32 = np.where(open32 < open_d2, np.nextafter(open32, np.float32(np.inf)), open32)
        nodes[:, _k.N_X : _k.N_Z + 1] = g[:, :3]
        nodes[:, _k.N_RADIUS] = b
        nodes[:, _k.N_OPEN_D2] = open32
        nodes[:, _k.N_AREA] = g[:, 4]
    return nodes
