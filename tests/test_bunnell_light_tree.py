"""The lit passes' trees (aobake.methods.bunnell.lighttree) against the brute-force kernels:
the aimed shadow pass's occluder tree on a plate half across a light patch, and the
transfer tree over any disk set."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from aobake.kernels import lightshadow as _kls
from aobake.methods.bunnell.lighttree import DiskTree, Receivers, aimed_shadow_tree, tree_gather
from aobake.methods.bunnell.transfer import transfer


def _plate(x0, h=0.02):
    """Squares of side h at z = 1 (normal +z) over x in [-1, x0], y in [-1, 1]."""
    xs = np.arange(-1.0, 1.0, h) + h / 2
    x, y = (a.ravel() for a in np.meshgrid(xs, xs, indexing="ij"))
    keep = x < x0
    centres = np.column_stack([x[keep], y[keep], np.ones(keep.sum())])
    return centres, np.tile([0.0, 0.0, 1.0], (len(centres), 1)), np.full(len(centres), h * h)


@pytest.mark.parametrize("x0", [-0.02, 0.0, 0.02])
def test_aimed_tree_on_a_plate_across_a_patch_is_the_brute_force_kernel(x0):
    """A receiver under a patch (area 0.04 at height 2) with a plate at height 1 across part
    of it: the tree at theta 1, 4 and inf gives the brute-force kernel's blocked share with
    ``edge`` 0 (clusters are used whole only away from the patch cap's edge, where they add
    exactly), within 0.02 at the default edge. With a reach (``--max-distance``) only the
    occluders within it block: the kernel on those alone, and the tree alike."""
    centres, normals, areas = _plate(x0)
    occ = np.ascontiguousarray(np.column_stack([centres, normals, areas]))
    patch = np.array([[0.0, 0.0, 2.0, 0.0, 0.0, -1.0, 0.04, 1.0, 1.0, 1.0, 0.0]])
    pts, nrm = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    own = np.full(len(areas), -1, dtype=np.int64)
    vis = np.ones((len(areas), 2, 1))
    want = np.empty((1, 1))
    _kls.aimed_shadow(pts, nrm, occ, own, vis, patch, math.inf, want)
    assert 0.05 < want[0, 0] < 0.95  # the plate's edge crosses the patch
    tree = DiskTree(centres, normals, areas, 4.0)
    for theta in (1.0, 4.0, math.inf):
        got = np.empty((1, 1))
        aimed_shadow_tree(pts, nrm, tree, own, vis, patch, got, theta, edge=0.0)
        assert got[0, 0] == pytest.approx(want[0, 0], rel=1e-9)
        aimed_shadow_tree(pts, nrm, tree, own, vis, patch, got, theta)  # small clusters across the edge whole
        assert got[0, 0] == pytest.approx(want[0, 0], abs=0.02)
    # a reach of sqrt(1 + 0.04^2) from a receiver 1 below the plate: only its disks within it block
    reach = math.sqrt(1 + 0.04**2)
    near = np.empty((1, 1))
    _kls.aimed_shadow(pts, nrm, occ, own, vis, patch, reach**2, near)
    within = np.linalg.norm(centres, axis=1) <= reach
    assert 0 < within.sum() < len(areas) and 0 < near[0, 0] < want[0, 0]
    only = np.empty((1, 1))
    _kls.aimed_shadow(pts, nrm, np.ascontiguousarray(occ[within]), own[within], vis[within], patch, math.inf, only)
    assert near[0, 0] == pytest.approx(only[0, 0], rel=1e-12)
    for theta in (1.0, 4.0, math.inf):
        got = np.empty((1, 1))
        aimed_shadow_tree(pts, nrm, tree, own, vis, patch, got, theta, edge=0.0, reach=reach)
        assert got[0, 0] == pytest.approx(near[0, 0], rel=1e-9)


def test_tree_gather_over_a_disk_set_is_the_brute_force_transfer():
    """Random disks lighting random receivers (both facings, owned disks left out): the
    tree with every cluster opened equals ``transfer`` to float32 rounding; at theta 4
    within 2% relative RMSE; both with and without a reach, where ``transfer`` equals the
    sum over each receiver's disks within it."""
    rng = np.random.default_rng(7)
    k, n = 400, 300
    centres = rng.uniform(-1, 1, (k, 3))
    normals = rng.normal(size=(k, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    areas = rng.uniform(0.001, 0.01, k)
    radiance = rng.uniform(0, 1, (k, 3))
    pts = rng.uniform(-1, 1, (n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    own = np.where(np.arange(n) < 50, np.arange(n), -1)  # receiver i < 50 owns disk i
    own_of_disk = np.where(np.arange(k) < 50, np.arange(k), -1)
    receivers = Receivers(pts, nrm)
    for flip, reach in itertools.product((False, True), (math.inf, 0.8)):
        want = transfer(pts, nrm, centres, -normals if flip else normals, areas, radiance, own_of_disk, reach)
        got = tree_gather(DiskTree(centres, normals, areas, math.inf), receivers, radiance, flip=flip, own=own, reach=reach)
        assert np.abs(got - want).max() < 1e-5 * want.max()
        approx = tree_gather(DiskTree(centres, normals, areas, 4.0), receivers, radiance, flip=flip, own=own, reach=reach)
        assert math.sqrt(((approx - want) ** 2).sum() / (want**2).sum()) < 0.02
    # a reach: only the disks within it, as a numpy sum over each receiver's near disks says
    far = transfer(pts, nrm, centres, normals, areas, radiance, own_of_disk)
    near = transfer(pts, nrm, centres, normals, areas, radiance, own_of_disk, 0.8)
    d = np.linalg.norm(centres[None] - pts[:, None], axis=2)
    for i in (0, 60, 299):
        keep = (d[i] <= 0.8) & (own_of_disk != i)
        one = transfer(pts[i : i + 1], nrm[i : i + 1], centres[keep], normals[keep], areas[keep], radiance[keep])
        np.testing.assert_allclose(near[i], one[0], rtol=1e-12, atol=1e-15)
    assert np.abs(far - near).max() > 0.1 * far.max()


def _subdivided(tri, n):
    """Centroids and areas of the n^2 congruent triangles that split triangle ``tri`` (3, 3)."""
    a, b, c = tri
    u, v = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = u + v < n
    down = u + v < n - 1
    bary = np.concatenate([np.column_stack([u[up] + 1 / 3, v[up] + 1 / 3]), np.column_stack([u[down] + 2 / 3, v[down] + 2 / 3])]) / n
    centres = a + bary[:, :1] * (b - a) + bary[:, 1:] * (c - a)
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a)) / n**2
    return centres, np.full(len(centres), area)


def test_triangle_near_field_is_the_finely_subdivided_triangle():
    """Receivers close to three large triangles (a square and a slanted one, both facings,
    some across a receiver's tangent plane, some in a triangle's plane): the tree gather
    with the near field (``DiskTree.triangle_cells``) equals the disk transfer over each
    triangle split into 96^2 small ones within 0.5% relative RMSE; without it (triangles as
    disks) it misses by more than 10%."""
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1.2, 0, 0.2], [1.2, 1, 0.2], [1.6, 0.5, 0.9]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    tris = positions[faces]
    centres = tris.mean(axis=1)
    m = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    areas = 0.5 * np.linalg.norm(m, axis=1)
    normals = m / (2 * areas[:, None])
    rng = np.random.default_rng(3)
    n = 400
    pts = np.column_stack([rng.uniform(-0.1, 1.4, n), rng.uniform(-0.1, 1.1, n), rng.uniform(-0.4, 0.4, n)])
    pts[:20, 2] = 0.0  # in the square's plane: seen edge-on
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    plane_distance = np.abs(np.einsum("tk,ntk->nt", normals, pts[:, None, :] - tris[:, 0][None]))
    keep = plane_distance.min(axis=1) > 0.05  # where 96^2 small disks stand for the triangles
    keep[:20] = plane_distance[:20, 2] > 0.05
    pts, nrm = pts[keep], nrm[keep]
    radiance = np.array([[1.0, 2.0, 0.5], [0.3, 1.0, 1.0], [2.0, 0.2, 1.0]])
    sub = [_subdivided(t, 96) for t in tris]
    sub_c = np.concatenate([c for c, _ in sub])
    sub_a = np.concatenate([a for _, a in sub])
    sub_n = np.repeat(normals, [len(a) for _, a in sub], axis=0)
    sub_l = np.repeat(radiance, [len(a) for _, a in sub], axis=0)
    receivers = Receivers(pts, nrm)
    tree = DiskTree(centres, normals, areas, 4.0, leaf_size=2, near=4.0)
    tables = tree.triangle_cells(receivers, positions, faces)
    assert min(len(t[1]) for t in tables) > 50  # both facings have near triangles
    for flip, table in ((False, tables[0]), (True, tables[1])):
        want = transfer(pts, nrm, sub_c, -sub_n if flip else sub_n, sub_a, sub_l)
        got = tree_gather(tree, receivers, radiance, flip=flip, cells=table)
        disks = tree_gather(tree, receivers, radiance, flip=flip)
        rel = math.sqrt(((got - want) ** 2).sum() / (want**2).sum())
        assert rel < 0.005
        assert math.sqrt(((disks - want) ** 2).sum() / (want**2).sum()) > 0.1
    assert np.all(np.isfinite(got))
