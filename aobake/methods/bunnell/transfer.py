"""Bunnell's indirect light, first increment: the unshadowed disk-to-disk transfer of RGB
radiance between the disk method's vertex elements, brute force (docs/bunnell-light.md).

Numpy-facing; the sum is ``aobake.kernels.transfer.gather``.
"""

from __future__ import annotations

import math

import numpy as np

from ...kernels import transfer as _kt
from .elements import DiskElements

_NO_RADIUS = np.zeros(0)  # gather_tree's node radii, read only with a finite reach


def outgoing_radiance(albedo, irradiance, emission=None) -> np.ndarray:
    """(n, 3) radiance a Lambertian vertex sends out: ``albedo irradiance / pi + emission``."""
    out = np.asarray(albedo, dtype=np.float64) * np.asarray(irradiance, dtype=np.float64) / math.pi
    if emission is not None:
        out = out + np.asarray(emission, dtype=np.float64)
    return np.ascontiguousarray(np.broadcast_to(out, np.shape(irradiance)), dtype=np.float64)


def transfer(points, normals, centres, disk_normals, areas, radiance, own=None, reach=math.inf) -> np.ndarray:
    """(n, 3) irradiance at each receiver (point, unit normal) from every emitting disk.

    Each disk of area ``A`` and radiance ``L`` adds ``pi L A cos_e cos_r / (pi r^2 + A)``
    (exact on a disk's axis), nothing from behind either side; no shadowing. ``own[j]``
    names the receiver disk j belongs to, which it does not light (default: none); a disk
    whose centre is farther than ``reach`` from a receiver does not light it.
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    centres = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
    disk_normals = np.ascontiguousarray(disk_normals, dtype=np.float64).reshape(-1, 3)
    areas = np.ascontiguousarray(areas, dtype=np.float64).reshape(-1)
    radiance = np.ascontiguousarray(radiance, dtype=np.float64).reshape(-1, 3)
    k = centres.shape[0]
    if normals.shape != points.shape or disk_normals.shape != centres.shape or areas.shape != (k,) or radiance.shape[0] != k:
        raise ValueError("transfer: receivers need (n, 3) points and normals; disks (k, 3) centres, normals, radiance and (k,) areas")
    own = np.full(k, -1, dtype=np.int64) if own is None else np.ascontiguousarray(own, dtype=np.int64).reshape(k)
    out = np.empty(points.shape)
    _kt.gather(points, normals, centres, disk_normals, areas, radiance, own, float(reach) ** 2, out)
    return out


def unshadowed_irradiance(elements: DiskElements, radiance) -> np.ndarray:
    """(n, 3) irradiance at every vertex from every other vertex's disk, without shadowing
    (the first pass of Bunnell's scheme).

    Parameters
    ----------
    elements : DiskElements
        The disk method's per-vertex elements (normalised coordinates: the transfer is
        dimensionless, so the result is in the radiance's units).
    radiance : (n, 3) float64 >= 0
        Outgoing radiance of each vertex (:func:`outgoing_radiance`).
    """
    radiance = np.asarray(radiance, dtype=np.float64)
    if radiance.shape != (elements.n_vertices, 3):
        raise ValueError(f"radiance must be ({elements.n_vertices}, 3), got {radiance.shape}")
    if not np.all(np.isfinite(radiance)) or np.any(radiance < 0.0):
        raise ValueError("radiance must be finite and >= 0")
    idx = elements.emitter_index
    idx = idx[np.any(radiance[idx] > 0.0, axis=1)]  # dark disks send nothing
    return transfer(
        elements.points,
        elements.normals,
        elements.positions[idx],
        elements.normals[idx],
        elements.areas[idx],
        radiance[idx],
        idx,
    )


# ---------------------------------------------------------------------------------------
# the same transfer through the cluster tree, with a prepare / gather split for re-lighting

# Default opening parameter of the tree transfer: a cluster is used whole only when every
# receiver of a bucket is at d^2 >= theta max(A, pi b^2) (1 + OPEN_COHERENCE (1 - c)) from
# its centre (as the AO's opening). Measured in docs/bunnell-light.md.
DEFAULT_TRANSFER_THETA = 4.0
# Default near-field reach (as the AO's --near): disks within sqrt(near A) of a receiver
# give their cells' exact form factor.
DEFAULT_TRANSFER_NEAR = 4.0
# Buckets are dealt cyclically to this many parallel chunks (any fixed number: the result
# does not depend on it, nor on the thread count).
TRANSFER_CHUNKS = 64
# Receivers per bucket (one tree walk each) and disks per leaf of the transfer's tree.
TRANSFER_BUCKET = 128
TRANSFER_LEAF_SIZE = 8


def opening_table(geometry, coherence, theta: float, reach=None) -> np.ndarray:
    """(m, ``transfertree.GEOMETRY_COLS``) node rows of a transfer tree: each node's centre
    and the squared distance beyond which it is used whole: ``theta`` times its size (its
    area or bounding disk, larger for incoherent normals), and never within its bounding
    radius, or ``reach`` (m,) where given (the near field's)."""
    from ...constants import OPEN_COHERENCE
    from ...kernels import transfertree as _kt2

    b = geometry[:, 3]
    size = np.maximum(geometry[:, 4], math.pi * b**2) * (1.0 + OPEN_COHERENCE * (1.0 - coherence))
    inner = b if reach is None else np.maximum(b, reach)
    with np.errstate(invalid="ignore", over="ignore"):
        open_d2 = np.maximum(theta * size, inner**2)
    table = np.zeros((geometry.shape[0], _kt2.GEOMETRY_COLS))
    table[:, _kt2.G_X : _kt2.G_Z + 1] = geometry[:, :3]
    table[:, _kt2.G_OPEN_D2] = np.where(np.isnan(open_d2), np.inf, open_d2)
    return table


def bucketed(points, normals):
    """``(order, bucket_start, bounds)``: :func:`receiver_buckets` of ``points`` and each
    bucket's ``treewalk.bucket_bounds`` (receivers at the points themselves)."""
    from ...kernels import treewalk as _tw

    order, bucket_start = receiver_buckets(points)
    bounds = np.zeros((bucket_start.shape[0] - 1, _tw.BOUND_COLS))
    _tw.bucket_bounds(points, normals, np.zeros(points.shape[0]), order, bucket_start, bounds)
    return order, bucket_start, bounds


def receiver_buckets(points):
    """``(order, bucket_start)``: every receiver once, grouped into compact buckets of at
    most TRANSFER_BUCKET (the leaves of a median-split tree over ``points``)."""
    from ...kernels import hierarchy as _h
    from .tree import tree_keys

    n = points.shape[0]
    perm, start, _, skip = _h.build_tree(tree_keys(points), TRANSFER_BUCKET)
    leaves = np.flatnonzero(skip == np.arange(1, skip.shape[0] + 1))
    return np.ascontiguousarray(perm, dtype=np.int64), np.append(start[leaves], n).astype(np.int64)


def near_cell_table(points, normals, elements: DiskElements, near, skip, start, stop, reach, geometry, e_pos, e_area,
                    vertex) -> tuple:  # fmt: skip
    """``(start, col, val)``: ``transfertree.near_cells``' sparse table of the barycentric
    cells of ``elements``' vertices ``vertex`` (the disks in tree order) at the receivers
    (receiver i is vertex i), counted in one walk and filled in a second."""
    from ...kernels import transfertree as _kt2

    n = points.shape[0]
    counts = np.zeros(n, dtype=np.int64)
    cell_start = np.zeros(n + 1, dtype=np.int64)
    args = (points, normals, elements.positions, elements.corner_start, elements.corners, near, skip, start, stop,
            reach, np.ascontiguousarray(geometry[:, :3]), e_pos, e_area, vertex)  # fmt: skip
    _kt2.near_cells(*args, counts, cell_start, np.zeros(0, dtype=np.int64), np.zeros(0), False)
    np.cumsum(counts, out=cell_start[1:])
    col = np.empty(cell_start[-1], dtype=np.int64)
    val = np.empty(cell_start[-1])
    _kt2.near_cells(*args, counts, cell_start, col, val, True)
    return cell_start, col, val


class TransferScene:
    """A scene prepared for repeated transfers (:func:`prepare_transfer`): the tree, the
    disks in tree order, the nodes' centres and opening distances, the receivers' buckets
    and the near-field cells are kept; each :meth:`gather` only sums the new radiance up
    the tree and walks it.
    """

    def __init__(self, elements: DiskElements, tree, theta: float, near: float):
        from .tree import node_coherence, refit_tree

        self.n_vertices = elements.n_vertices
        self.theta = float(theta)
        self.near = float(near)
        self._points = np.ascontiguousarray(elements.points, dtype=np.float64)
        self._normals = np.ascontiguousarray(elements.normals, dtype=np.float64)
        self.tree = tree
        if tree is None:
            return
        tree = refit_tree(tree, elements.positions, elements.areas)  # geometry of these disks
        self.tree = tree
        order = tree.order
        self._order = order
        self._e_pos = np.ascontiguousarray(elements.positions[order])
        self._e_nrm = np.ascontiguousarray(elements.normals[order])
        self._e_area = np.ascontiguousarray(elements.areas[order])
        self._own_pos = np.full(self.n_vertices, -1, dtype=np.int64)  # each vertex's disk in tree order
        self._own_pos[order] = np.arange(order.shape[0])
        g = tree.geometry
        # how far from a node's centre a receiver can be in the near field of one of its
        # disks (a hair more, for rounding): such nodes are never used whole
        reach = (g[:, 3] + np.sqrt(self.near * g[:, 5])) * (1.0 + 1e-9)
        coherence = node_coherence(tree, elements.normals, elements.areas)
        self._geometry = opening_table(g, coherence, self.theta, reach)
        self._recv_order, self._bucket_start, self._bounds = bucketed(self._points, self._normals)
        self._cells = self._near_cells(elements, reach)

    def _near_cells(self, elements: DiskElements, reach):
        """The near field's sparse table (``transfertree.near_cells``), empty when near is 0."""
        n = self.n_vertices
        if self.near <= 0.0:
            return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        tree = self.tree
        return near_cell_table(self._points, self._normals, elements, self.near, tree.skip, tree.start, tree.stop,
                               reach, tree.geometry, self._e_pos, self._e_area, self._order)  # fmt: skip

    def gather(self, radiance) -> np.ndarray:
        """(n, 3) irradiance at every vertex from every other vertex's disk, unshadowed
        (:func:`unshadowed_irradiance` through the tree).

        Parameters
        ----------
        radiance : (n, 3) float64 >= 0
            Outgoing radiance of each vertex.
        """
        from ...kernels import transfertree as _kt2

        radiance = np.asarray(radiance, dtype=np.float64)
        if radiance.shape != (self.n_vertices, 3):
            raise ValueError(f"radiance must be ({self.n_vertices}, 3), got {radiance.shape}")
        if not np.all(np.isfinite(radiance)) or np.any(radiance < 0.0):
            raise ValueError("radiance must be finite and >= 0")
        out = np.zeros((self.n_vertices, 3))
        if self.tree is None:
            return out
        tree = self.tree
        e_rad = np.ascontiguousarray(radiance[self._order])
        light = np.empty((tree.n_nodes, _kt2.LIGHT_COLS))  # per call: calls may run concurrently
        _kt2.node_light(self._e_nrm, self._e_area, e_rad, tree.skip, tree.start, tree.stop, light)
        n_buckets = self._bucket_start.shape[0] - 1
        _kt2.gather_tree(
            self._points, self._normals, self._recv_order, self._bucket_start, self._bounds,
            min(TRANSFER_CHUNKS, n_buckets), tree.skip, tree.start, tree.stop, self._geometry,
            light, self._e_pos, self._e_nrm, self._e_area, e_rad, self._own_pos, *self._cells, math.inf, _NO_RADIUS, out,
        )  # fmt: skip
        return out


def prepare_transfer(
    elements: DiskElements,
    *,
    theta: float = DEFAULT_TRANSFER_THETA,
    near: float = DEFAULT_TRANSFER_NEAR,
    tree=None,
    leaf_size: int = TRANSFER_LEAF_SIZE,
) -> TransferScene:
    """Everything of the tree transfer that does not depend on the radiance.

    Parameters
    ----------
    elements : DiskElements
    theta : float > 0, optional
        Opening parameter (larger = slower, closer to the brute-force sum; ``inf`` opens
        every cluster and gives the brute-force sum).
    near : float >= 0, optional
        Disks closer than ``sqrt(near A)`` to a receiver give the exact form factor of
        their barycentric cells (the polygons they stand for), clipped to the receiver's
        tangent plane, instead of the disk term, as the AO's near field; 0 = disks only
        (then ``theta = inf`` is :func:`unshadowed_irradiance`).
    tree : ClusterTree, optional
        A tree over ``elements.emitter_index`` (``aobake.methods.bunnell.passes.build_tree``,
        or an earlier one for moved vertices: it is refitted); default: built here.
    leaf_size : int, optional
        Disks per leaf of the tree built here.
    """
    from .passes import build_tree

    theta = float(theta)
    if not theta > 0.0:
        raise ValueError(f"theta must be > 0, got {theta!r}")
    near = float(near)
    if not (near >= 0.0 and math.isfinite(near)):
        raise ValueError(f"near must be finite and >= 0, got {near!r}")
    if elements.n_emitters == 0:
        return TransferScene(elements, None, theta, near)
    if tree is None:
        tree = build_tree(elements, leaf_size=leaf_size)
    elif not np.array_equal(np.sort(tree.order), elements.emitter_index):
        raise ValueError("tree: built over other disks than these elements' emitters")
    return TransferScene(elements, tree, theta, near)


def tree_transfer(
    elements: DiskElements,
    radiance,
    *,
    theta: float = DEFAULT_TRANSFER_THETA,
    near: float = DEFAULT_TRANSFER_NEAR,
    tree=None,
) -> np.ndarray:
    """(n, 3) :func:`unshadowed_irradiance` through the cluster tree: clusters far enough for
    their size (``theta``) send their summed RGB power from their centre, nearer disks
    their exact terms, and disks within ``sqrt(near A)`` of a receiver the exact form
    factor of their cells. One call of :func:`prepare_transfer` and
    :meth:`TransferScene.gather`.
    """
    return prepare_transfer(elements, theta=theta, near=near, tree=tree).gather(radiance)
