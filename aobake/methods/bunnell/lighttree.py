"""The lit pipeline's passes through cluster trees (docs/bunnell-light.md): a tree over any
set of one-sided disks (the vertex disks that reflect, the triangles that occlude) that
gathers their light at any receivers with the transfer's compiled walk
(``aobake.kernels.transfertree.gather_tree``, disks only), and the occluder tables of the
aimed shadow pass's tree (``aobake.kernels.lightshadowtree``).

Numpy-facing; contains no @njit code. With ``theta = inf`` every cluster is opened and
each gather is the brute-force ``transfer`` (to float32 rounding).
"""

from __future__ import annotations

import math

import numpy as np

from ...kernels import hierarchy as _h
from ...kernels import transfertree as _kt2
from .transfer import TRANSFER_CHUNKS, TRANSFER_LEAF_SIZE, bucketed, near_cell_table, opening_table
from .tree import node_geometry, tree_keys

#: Opening parameter of the lit pipeline's transfer trees (the unshadowed bounce and the
#: shadow passes' subtraction): as the transfer's default (docs/bunnell-light.md).
LIGHT_THETA = 4.0


class DiskTree:
    """A cluster tree over ``k`` one-sided disks (centres, unit normals, areas > 0), the
    opening distances of its nodes for ``theta``, and the disks in tree order. ``near`` >
    0: no node is used whole by a receiver that could be within ``sqrt(near A)`` of one of
    its disks (those take a near field: :meth:`triangle_cells`)."""

    def __init__(self, centres, normals, areas, theta: float, leaf_size: int = TRANSFER_LEAF_SIZE, near: float = 0.0):
        centres = np.ascontiguousarray(centres, dtype=np.float64)
        normals = np.ascontiguousarray(normals, dtype=np.float64)
        areas = np.ascontiguousarray(areas, dtype=np.float64)
        self.size = int(areas.shape[0])
        self.theta = float(theta)
        if self.size == 0:
            return
        perm, start, stop, skip = _h.build_tree(tree_keys(centres), int(leaf_size))
        self.order = np.ascontiguousarray(perm, dtype=np.int64)
        self.position = np.empty(self.size, dtype=np.int64)  # tree position of each disk
        self.position[self.order] = np.arange(self.size)
        self.start, self.stop, self.skip = start, stop, skip
        g = node_geometry(centres, areas, self.order, start, stop)
        self.geometry = g
        self.radius = np.ascontiguousarray(g[:, 3])  # bounding radius about the centre
        self.e_pos = np.ascontiguousarray(centres[self.order])
        self.e_nrm = np.ascontiguousarray(normals[self.order])
        self.e_area = np.ascontiguousarray(areas[self.order])
        coherence = np.empty(skip.shape[0])
        with np.errstate(invalid="ignore", divide="ignore"):
            _h.node_coherence(normals, areas, self.order, start, stop, coherence)
        self.near = float(near)
        self.reach = (g[:, 3] + np.sqrt(self.near * g[:, 5])) * (1.0 + 1e-9) if self.near > 0 else None
        self.table = opening_table(g, coherence, self.theta, self.reach)

    def vertex_cells(self, receivers: Receivers, elements, vertex) -> tuple:
        """``(start, col, val)``: the near field of this tree's disks as the barycentric
        cells of the vertices ``vertex`` (k,) they stand for, of ``elements``, at receivers
        one per vertex (receiver i is vertex i: its own cell is left out;
        ``transfertree.near_cells``, the transfer's near field)."""
        if self.size == 0 or self.near <= 0.0:
            return np.zeros(receivers.n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        vertex = np.ascontiguousarray(np.asarray(vertex, dtype=np.int64)[self.order])
        return near_cell_table(receivers.points, receivers.normals, elements, self.near, self.skip, self.start, self.stop,
                               self.reach, self.geometry, self.e_pos, self.e_area, vertex)  # fmt: skip

    def triangle_cells(self, receivers: Receivers, positions, faces) -> tuple:
        """Two ``(start, col, val)`` tables: the near field of this tree's disks as the
        triangles ``faces`` (rows in the order the disks were given) at ``receivers``, of
        the triangles whose front faces each receiver, then of those whose back does
        (``transfertree.triangle_cells``)."""
        n = receivers.n
        if self.size == 0 or self.near <= 0.0:
            empty = (np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
            return empty, empty
        counts = np.zeros((2, n), dtype=np.int64)
        start = np.zeros((2, n + 1), dtype=np.int64)
        args = (receivers.points, receivers.normals, np.ascontiguousarray(positions, dtype=np.float64),
                np.ascontiguousarray(faces, dtype=np.int64), self.near, self.skip, self.start, self.stop, self.reach,
                np.ascontiguousarray(self.geometry[:, :3]), self.e_pos, self.e_area, self.order)  # fmt: skip
        none = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        _kt2.triangle_cells(*args, counts, start, none, (np.zeros(0), np.zeros(0)), False)
        np.cumsum(counts, axis=1, out=start[:, 1:])
        cols = (np.empty(start[0, -1], dtype=np.int64), np.empty(start[1, -1], dtype=np.int64))
        vals = (np.empty(start[0, -1]), np.empty(start[1, -1]))
        _kt2.triangle_cells(*args, counts, start, cols, vals, True)
        return (np.ascontiguousarray(start[0]), cols[0], vals[0]), (np.ascontiguousarray(start[1]), cols[1], vals[1])

    @property
    def n_nodes(self) -> int:
        return int(self.skip.shape[0]) if self.size else 0


class Receivers:
    """Receiving points and unit normals grouped into buckets for the tree walk."""

    def __init__(self, points, normals):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        self.n = int(self.points.shape[0])
        self.order, self.bucket_start, self.bounds = bucketed(self.points, self.normals)
        self._no_cells = (np.zeros(self.n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))


def tree_gather(tree: DiskTree, receivers: Receivers, radiance, *, flip: bool = False, own=None, cells=None,
                reach: float = math.inf) -> np.ndarray:  # fmt: skip
    """(n, 3) irradiance at ``receivers`` from ``tree``'s disks sending ``radiance`` (k, 3)
    (disk order): the transfer's disk terms through the tree. ``flip``: the disks face the
    other way (their back sides emit). ``own`` (n,) int64: the disk each receiver does not
    take (-1: none). ``cells``: a near field (:meth:`DiskTree.triangle_cells` of the side
    that emits) whose values replace those disks' terms. ``reach``: disks farther from a
    receiver give it nothing (``--max-distance``)."""
    out = np.zeros((receivers.n, 3))
    if tree.size == 0 or receivers.n == 0:
        return out
    radiance = np.ascontiguousarray(np.asarray(radiance, dtype=np.float64)[tree.order])
    e_nrm = -tree.e_nrm if flip else tree.e_nrm
    light = np.empty((tree.n_nodes, _kt2.LIGHT_COLS))
    _kt2.node_light(e_nrm, tree.e_area, radiance, tree.skip, tree.start, tree.stop, light)
    if own is None:
        own_pos = np.full(receivers.n, -1, dtype=np.int64)
    else:
        own = np.asarray(own, dtype=np.int64)
        own_pos = np.where(own >= 0, tree.position[np.maximum(own, 0)], -1).astype(np.int64)
    n_buckets = receivers.bucket_start.shape[0] - 1
    _kt2.gather_tree(
        receivers.points, receivers.normals, receivers.order, receivers.bucket_start, receivers.bounds,
        min(TRANSFER_CHUNKS, n_buckets), tree.skip, tree.start, tree.stop, tree.table, light,
        tree.e_pos, np.ascontiguousarray(e_nrm), tree.e_area, radiance, own_pos, *(cells or receivers._no_cells),
        float(reach), tree.radius, out,
    )  # fmt: skip
    return out


#: Opening parameter of the aimed shadow pass's occluder tree: a cluster is one occluder
#: when the receiver is farther than ``sqrt(AIMED_THETA) b`` from its centre (b its
#: bounding radius). Measured in docs/bunnell-light.md.
AIMED_THETA = 4.0
#: A cluster across the edge of a light patch's cap (as seen from the receiver) is used
#: whole only when its angular radius is at most AIMED_EDGE times the cap's; larger ones
#: are opened (0: always). Measured in docs/bunnell-light.md.
AIMED_EDGE = 0.5


def _range_sums(values, start, stop):
    """(m, c) sums of ``values`` (k, c), tree order, over each node's range (prefix sums)."""
    cum = np.zeros((values.shape[0] + 1, values.shape[1]))
    np.cumsum(values, axis=0, out=cum[1:])
    return cum[stop] - cum[start]


def aimed_nodes(tree: DiskTree, vis, theta: float = AIMED_THETA) -> np.ndarray:
    """Node rows of ``lightshadowtree.aimed_shadow_tree`` for occluder ``tree`` and ``vis``
    (k, 2, G) in tree order: centre, bounding radius, area, opening distance, the
    normals' scaled tensor and each group's visibility sums."""
    from ...kernels import lightshadowtree as _kst

    g = tree.geometry
    m = tree.n_nodes
    n_groups = vis.shape[2]
    a, nrm = tree.e_area, tree.e_nrm
    mm = np.stack([nrm[:, 0] ** 2, nrm[:, 1] ** 2, nrm[:, 2] ** 2, nrm[:, 0] * nrm[:, 1], nrm[:, 0] * nrm[:, 2],
                   nrm[:, 1] * nrm[:, 2]], axis=1)  # fmt: skip
    half_sum = 0.5 * (vis[:, 0] + vis[:, 1])  # (k, G)
    half_diff = 0.5 * (vis[:, 0] - vis[:, 1])
    cols = [a[:, None] * mm, (vis.reshape(vis.shape[0], -1).max(axis=1) > 0.0)[:, None].astype(np.float64)]
    for c in range(n_groups):
        cols.append((a * half_sum[:, c])[:, None])
        cols.append((a * half_diff[:, c])[:, None] * nrm)
    sums = _range_sums(np.concatenate(cols, axis=1), tree.start, tree.stop)
    area = g[:, 4]
    t = sums[:, :6]
    # the spread factor kappa (hierarchy.spread_factor) from rho = tr(T^2) / A^2
    tt = (t[:, :3] ** 2).sum(axis=1) + 2.0 * (t[:, 3:] ** 2).sum(axis=1)
    rho = np.clip(tt / area**2, 1.0 / 3.0, 1.0)
    base = 0.5 * math.sqrt(3.0)
    kappa = base + (1.0 - base) * 0.5 * (3.0 * rho - 1.0)
    nodes = np.zeros((m, _kst.N_G + _kst.N_GROUP_COLS * n_groups))
    nodes[:, _kst.N_C : _kst.N_C + 3] = g[:, :3]
    nodes[:, _kst.N_B] = g[:, 3]
    nodes[:, _kst.N_A] = area
    with np.errstate(over="ignore", invalid="ignore"):
        nodes[:, _kst.N_OPEN_D2] = np.where(np.isfinite(theta), theta * g[:, 3] ** 2, np.inf)
    nodes[:, _kst.N_T : _kst.N_T + 6] = t * (kappa**2 / area)[:, None]
    nodes[:, _kst.N_LIT] = sums[:, 6]
    nodes[:, _kst.N_G :] = sums[:, 7:]
    return nodes


def aimed_shadow_tree(
    points, normals, tree: DiskTree, own, vis, patches, out, theta: float = AIMED_THETA, edge: float = AIMED_EDGE,
    reach: float = math.inf,
) -> None:  # fmt: skip
    """``lightshadow.aimed_shadow`` with the occluders in ``tree`` (``own`` (k,), ``vis``
    (k, 2, G) in disk order), written to ``out`` (n, G); ``theta`` and ``edge`` as in
    ``lightshadowtree.aimed_shadow_tree`` (``theta = inf``: the brute-force kernel's result,
    up to the order of its sums; ``edge = 0``: clusters used whole only away from every
    patch cap's edge, where a flat one adds exactly); occluders farther than ``reach``
    block nothing."""
    from ...kernels import lightshadowtree as _kst

    if tree.size == 0:
        out[:] = 0.0
        return
    occ = np.ascontiguousarray(np.column_stack([tree.e_pos, tree.e_nrm, tree.e_area]))
    vis_t = np.ascontiguousarray(vis[tree.order])
    nodes = aimed_nodes(tree, vis_t, theta)
    _kst.aimed_shadow_tree(np.ascontiguousarray(points), np.ascontiguousarray(normals), tree.skip, tree.start,
                           tree.stop, nodes, occ, np.ascontiguousarray(own[tree.order]), vis_t, patches, float(edge),
                           float(reach) ** 2, out)  # fmt: skip
