"""The disk method's cluster tree (aobake.methods.bunnell.tree, kernels.hierarchy,
treewalk): the exact O(n^2) sum against a numpy reference, the hierarchy against the
exact sum, tree structure, refits and buckets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aobake.constants import DIRECTION_SECTORS
from aobake.kernels import bunnell as K
from aobake.kernels import hierarchy as KH
from aobake.kernels import polygon as KP
from aobake.kernels import treewalk as KTW
from aobake.mesh import surface_from_arrays
from aobake.methods import bunnell as B
from aobake.methods.bunnell import passes as P
from aobake.methods.bunnell import tree as H
from aobake.progress import NullProgress
from aobake.testing.disk import (
    kernel_sums,
    passes_of,
    small_scene,
)
from aobake.testing.naive_bunnell import naive_sums
from aobake.testing.scenes import (
    icosphere,
    sphere_on_plane,
    touching_spheres,
)

# --------------------------------------------------------------------------------------
# exact sum and hierarchy


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
@pytest.mark.parametrize("max_distance", [None, 0.8])
@pytest.mark.parametrize("near", [0.0, 4.0])
@pytest.mark.parametrize("directional", [True, False])
def test_brute_force_kernel_matches_numpy_reference(measure, max_distance, near, directional):
    s = small_scene()
    e = B.build_elements(s)
    rng = np.random.default_rng(1)
    w, wc = rng.random(e.n_vertices), rng.random(e.n_vertices)
    out = kernel_sums(e, None, w, measure=measure, max_distance=max_distance, near=near,
                cell_weights=wc, directional=directional)[:, :, -1]
    reach = None if max_distance is None else max_distance / e.scale
    sectors = DIRECTION_SECTORS if directional else 0
    expected = naive_sums(
        e.positions, e.normals, e.areas, s.faces, e.points, w, measure, reach, near, wc,
        sectors=sectors,
    )
    assert expected.max() > 0.3  # the scene has real occlusion
    # atan2 (kernel) and arccos (reference) angles agree to ~1e-12 in the cells
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-10)


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
@pytest.mark.parametrize("max_distance", [None, 0.8])
@pytest.mark.parametrize("leaf_size", [1, 4, 9])
@pytest.mark.parametrize("directional", [True, False])
def test_hierarchy_with_huge_theta_is_the_exact_sum(measure, max_distance, leaf_size, directional):
    """To float32 tolerance: the tree pass sums in float32 (the cells in float64)."""
    s = small_scene()
    e = B.build_elements(s)
    tree = B.build_tree(e, leaf_size=leaf_size)
    kw = dict(passes=3, measure=measure, max_distance=max_distance, share_passes=False,
              directional=directional)
    exact = passes_of(e, None, **kw)
    for theta in (1e12, np.inf):
        approx = passes_of(e, tree, theta=theta, **kw)
        np.testing.assert_allclose(approx, exact, rtol=0, atol=2e-6)


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
def test_hierarchy_raw_sums_with_weights_match_brute_force(measure):
    """The kernels' unsaturated sums with arbitrary weights (cluster weight refit included)."""
    s = small_scene()
    e = B.build_elements(s)
    tree = B.build_tree(e, leaf_size=3)
    rng = np.random.default_rng(2)
    w, wc = rng.random(e.n_vertices), rng.random(e.n_vertices)
    kw = dict(measure=measure, theta=np.inf, cell_weights=wc)
    np.testing.assert_allclose(
        kernel_sums(e, tree, w, **kw), kernel_sums(e, None, w, **kw), rtol=1e-6, atol=1e-6
    )


@pytest.mark.parametrize("scene", [sphere_on_plane, touching_spheres])
@pytest.mark.parametrize("measure", ["cosine", "uniform"])
def test_error_shrinks_as_theta_grows(scene, measure):
    s = scene()
    e = B.build_elements(s)
    tree = B.build_tree(e, leaf_size=4)  # small leaves: a deep tree on a small scene
    exact = passes_of(e, None, measure=measure)[0]
    errors = []
    for theta in [0.5, 2.0, 8.0, 32.0, 128.0]:
        approx = passes_of(e, tree, theta=theta, measure=measure)[0]
        errors.append(np.sqrt(np.mean((approx - exact) ** 2)))
    # shrinking until the tree is opened everywhere (then float32 rounding)
    assert all(b < a or a < 1e-6 for a, b in zip(errors[:-1], errors[1:], strict=True)), errors
    assert errors[0] > 1e-3 and errors[-1] < 1e-3, errors


@pytest.mark.parametrize("max_distance", [0.3, 1.5])
def test_hierarchy_honours_max_distance(max_distance):
    s = sphere_on_plane()
    exact = B.variant_ao(s, exact=True, max_distance=max_distance)
    huge = B.variant_ao(s, theta=1e12, max_distance=max_distance)
    default = B.variant_ao(s, max_distance=max_distance)
    unbounded = B.variant_ao(s, exact=True)
    np.testing.assert_allclose(huge, exact, rtol=0, atol=2e-6)
    assert np.sqrt(np.mean((default - exact) ** 2)) < 5e-3
    assert np.all(exact >= unbounded - 1e-12)  # less reach, never darker
    assert np.any(exact > unbounded + 1e-3)


def test_max_distance_below_vertex_spacing_sees_nothing():
    s = sphere_on_plane()
    for exact in (True, False):
        ao = B.variant_ao(s, exact=exact, max_distance=1e-3)
        # only the two vertices where sphere and plane touch see anything that close
        assert np.sum(ao < 1.0) <= 2


def test_huge_max_distance_equals_unbounded():
    s = touching_spheres()
    np.testing.assert_array_equal(B.variant_ao(s, max_distance=1e6), B.variant_ao(s))


# --------------------------------------------------------------------------------------
# tree structure


@pytest.mark.parametrize("leaf_size", [1, 2, 5])
def test_tree_invariants(leaf_size):
    s = small_scene()
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=leaf_size)
    np.testing.assert_array_equal(np.sort(t.order), e.emitter_index)
    assert t.start[0] == 0 and t.stop[0] == e.n_emitters and t.skip[0] == t.n_nodes
    leaf = t.skip == np.arange(t.n_nodes) + 1
    np.testing.assert_array_equal(t.leaves, np.flatnonzero(leaf))
    assert np.all(t.stop[leaf] - t.start[leaf] <= leaf_size)
    assert np.all(t.stop[leaf] > t.start[leaf])
    for q in np.flatnonzero(~leaf):
        left, right = q + 1, t.skip[q + 1]
        assert (
            t.start[left] == t.start[q]
            and t.stop[left] == t.start[right]
            and t.stop[right] == t.stop[q]
        )
        assert t.skip[right] == t.skip[q]
    for q in range(t.n_nodes):
        members = t.order[t.start[q] : t.stop[q]]
        a = e.areas[members]
        assert t.areas[q] == pytest.approx(a.sum(), rel=1e-12)
        assert t.geometry[q, 5] == a.max()
        np.testing.assert_allclose(
            t.centers[q], (a[:, None] * e.positions[members]).sum(0) / a.sum(), atol=1e-12
        )
        reach = np.linalg.norm(e.positions[members] - t.centers[q], axis=1) + np.sqrt(a / np.pi)
        assert np.all(reach <= t.radii[q] * (1 + 1e-12))


def test_packed_nodes_are_conservative():
    """float32 opening distances are never below the float64 ones."""
    s = small_scene()
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=2)
    nodes = H.pack_nodes(t, theta=4.0, near=4.0)
    b = t.radii
    exact = np.maximum(4.0 * np.maximum(t.areas, np.pi * b**2), (b + np.sqrt(4.0 * t.geometry[:, 5])) ** 2)
    assert np.all(nodes[:, KH.N_OPEN_D2].astype(np.float64) >= exact)
    assert np.all(np.isinf(H.pack_nodes(t, theta=np.inf, near=4.0)[:, KH.N_OPEN_D2]))


def test_receiver_buckets_cover_every_vertex_once():
    s = small_scene()
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=4)
    order, bucket_start = P.receiver_buckets(e, t)
    np.testing.assert_array_equal(np.sort(order), np.arange(e.n_vertices))
    sizes = np.diff(bucket_start)
    assert bucket_start[0] == 0 and bucket_start[-1] == e.n_vertices
    assert sizes.min() >= 1 and sizes.max() <= 4


def _two_cluster_buckets():
    """Bucket 0: 20 receivers on a patch at the origin and 12 on one 5 units above, mixed
    (a leaf straddling a gap); bucket 1: a compact 4 x 4 patch beside them; disks of area
    h^2 on a grid of step h."""
    h = 0.01
    grid = lambda nx, ny, x0, z: np.array(  # noqa: E731
        [[x0 + i * h, j * h, z] for i in range(nx) for j in range(ny)]
    )
    points = np.vstack([grid(4, 5, 0.0, 0.0), grid(4, 3, 0.0, 5.0), grid(4, 4, 1.0, 0.0)])
    order = np.r_[np.random.default_rng(0).permutation(32), np.arange(32, 48)]
    return points, np.full(points.shape[0], h * h), order, np.array([0, 32, 48])


def test_split_spread_buckets_separates_two_clusters():
    points, areas, order, start = _two_cluster_buckets()
    normals = np.tile([0.0, 0.0, 1.0], (points.shape[0], 1))
    bounds = np.zeros((2, KTW.BOUND_COLS))
    KTW.bucket_bounds(points, normals, np.zeros(48), order, start, bounds)
    new_order, new_start = P.split_spread_buckets(points, areas, order, start,
                                                  bounds[:, KTW.B_RADIUS], 8.0)
    pieces = [new_order[a:b] for a, b in zip(new_start[:-1], new_start[1:], strict=True)]
    # the compact bucket stays whole, in its place; the wide one is cut at the gap
    np.testing.assert_array_equal(pieces[-1], order[32:])
    assert len(pieces) >= 3
    np.testing.assert_array_equal(np.sort(new_order[:32]), np.sort(order[:32]))
    for piece in pieces[:-1]:
        z = points[piece, 2]
        assert np.all(z == z[0])  # one cluster each
        # compact now, and the leaf's order kept within the piece
        r2 = np.max(np.sum((points[piece] - points[piece].mean(axis=0)) ** 2, axis=1))
        assert np.pi * r2 <= 8.0 * areas[piece].sum() or piece.shape[0] == 1
        rank = {v: r for r, v in enumerate(order[:32])}
        assert [rank[v] for v in piece] == sorted(rank[v] for v in piece)
    # a spread no bucket exceeds changes nothing
    same = P.split_spread_buckets(points, areas, order, start, bounds[:, KTW.B_RADIUS], 1e9)
    np.testing.assert_array_equal(same[0], order)
    np.testing.assert_array_equal(same[1], start)


def _halves(points, areas, members, spread):
    """The rule of split_spread_buckets for one bucket, one piece at a time."""
    p = points[members]
    r2 = np.max(np.sum((p - p.mean(axis=0)) ** 2, axis=1))
    axis = np.argmax(p.max(axis=0) - p.min(axis=0))
    low = p[:, axis] <= 0.5 * (p[:, axis].min() + p[:, axis].max())
    if len(members) == 1 or np.pi * r2 <= spread * areas[members].sum() or low.all():
        return [members]
    return _halves(points, areas, members[low], spread) + _halves(points, areas, members[~low], spread)


@pytest.mark.parametrize("seed", [0, 1])
def test_split_spread_buckets_is_the_recursive_rule(seed):
    """Scattered clusters of random sizes (some coincident points): the level-by-level
    numpy split gives the pieces, in the order, of halving each bucket recursively."""
    rng = np.random.default_rng(seed)
    n = 600
    points = rng.uniform(-1, 1, (n // 3, 1, 3)) + rng.choice([1e-3, 0.05], (n // 3, 1, 1)) * (
        rng.normal(size=(n // 3, 3, 3)))
    points = points.reshape(n, 3)
    points[5:9] = points[4]
    areas = rng.uniform(1e-6, 1e-4, n)
    order = rng.permutation(n)
    start = np.unique(np.r_[0, rng.choice(np.arange(1, n), 30, replace=False), n])
    centre = np.add.reduceat(points[order], start[:-1]) / np.diff(start)[:, None]
    radii = np.array([np.sqrt(np.max(np.sum((points[order[a:b]] - c) ** 2, axis=1)))
                      for a, b, c in zip(start[:-1], start[1:], centre, strict=True)])
    for spread in (1.0, 8.0, 32.0):
        got_order, got_start = P.split_spread_buckets(points, areas, order, start, radii, spread)
        pieces = []
        for a, b, r in zip(start[:-1], start[1:], radii, strict=True):
            m = order[a:b]
            wide = np.pi * r**2 > spread * areas[m].sum()
            pieces += _halves(points, areas, m, spread) if wide else [m]
        np.testing.assert_array_equal(got_order, np.concatenate(pieces))
        np.testing.assert_array_equal(got_start, np.cumsum([0] + [len(q) for q in pieces]))
    assert len(pieces) > len(start) - 1  # spread 32 still split some


def test_tree_pass_with_split_buckets_matches_the_exact_sum():
    """Buckets split hard (``bucket_spread=1``: nearly every leaf) still walk to the exact
    sum when every cluster opens, stay within the tree's error at the defaults, and give
    the same bits for any thread count."""
    s = sphere_on_plane()
    e = B.build_elements(s)
    tree = B.build_tree(e)
    whole = P.receiver_buckets(e, tree, spread=np.inf)[1].shape[0]
    assert P.receiver_buckets(e, tree, spread=1.0)[1].shape[0] > 2 * whole
    exact = passes_of(e, None)[0]
    huge = passes_of(e, tree, theta=np.inf, bucket_spread=1.0)[0]
    np.testing.assert_allclose(huge, exact, rtol=0, atol=2e-6)
    split = passes_of(e, tree, bucket_spread=1.0)
    unsplit = passes_of(e, tree, bucket_spread=np.inf)
    err = lambda a: np.sqrt(np.mean((a[0] - exact) ** 2))  # noqa: E731
    assert err(split) < 5e-3 and err(unsplit) < 5e-3
    assert not np.array_equal(split, unsplit)
    np.testing.assert_array_equal(
        split, B.occlusion_passes(e, tree, *B.settings(bucket_spread=1.0, threads=1))
    )


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    spread=st.sampled_from([0.0, 1e-3, 0.3, 1.5]),
    normal_less=st.booleans(),
)
def test_bucket_culls_only_emitters_behind_every_receiver(seed, spread, normal_less):
    """The bucket-level cull (treewalk.behind) against each receiver's own float32 n.d:
    whatever it drops has n.d <= 0 at every receiver of the bucket, so its term is an
    exact 0 (flat buckets with equal normals, curved ones, wide normal cones, a receiver
    without a normal, which stops every cull)."""
    rng = np.random.default_rng(seed)
    k = 16
    points = rng.normal(scale=0.01, size=(k, 3)) + rng.uniform(-1, 1, size=3)
    axis = rng.normal(size=3)
    normals = axis / np.linalg.norm(axis) + spread * rng.normal(size=(k, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    if spread == 0.0:  # a flat patch: the receivers in one plane
        points -= np.outer((points - points[0]) @ normals[0], normals[0])
    if normal_less:
        normals[rng.integers(k)] = 0.0
    bounds = np.zeros((1, KTW.BOUND_COLS))
    KTW.bucket_bounds(points, normals, np.zeros(k), np.arange(k), np.array([0, k]), bounds)
    centre = bounds[0, :3]
    # emitters at every scale around the bucket, some in its receivers' planes
    emitters = centre + rng.normal(size=(400, 3)) * rng.choice([1e-3, 1e-2, 0.3], size=(400, 1))
    emitters[:50] = points[rng.integers(k, size=50)] + 1e-3 * np.cross(
        normals[rng.integers(k, size=50)], rng.normal(size=(50, 3))
    )
    emitters = emitters.astype(np.float32)
    offsets = emitters.astype(np.float64) - centre
    culled = np.array([KTW.behind(bounds[0], *e, np.linalg.norm(e)) for e in offsets])
    if normal_less:
        assert not culled.any()
        return
    d = emitters[culled][None, :, :] - points.astype(np.float32)[:, None, :]
    nd = np.einsum("ij,ikj->ik", normals.astype(np.float32), d)
    assert np.all(nd <= 0.0)
    if spread == 0.0:  # flat bucket: everything well below the plane goes
        low = (emitters - points[0].astype(np.float32)) @ normals[0].astype(np.float32)
        assert culled[low < -1e-3].all()


def test_bucket_cull_drops_the_far_side_of_a_ball():
    """A receiver bucket on a ball: its list holds the near side only (the cull is on),
    and the sums still equal the exact ones (test_tree_matches_exact_sum_at_huge_theta)."""
    e = B.build_elements(surface_from_arrays(*icosphere(4)))
    t = B.build_tree(e, leaf_size=8)
    job = P._Pass(e, t, np.inf, 0.0, K.MEASURE_COSINE, np.inf)
    job.sums(np.ones((e.n_vertices, K.N_LEVELS)), NullProgress())
    _, _, bounds, near_buf, near_idx, far_buf = job.buckets
    n_near, _, n_far = KTW.gather(
        job.tree_args, job.emitters, bounds[0],
        job.options._replace(max_distance=np.inf, near=0.0, leveled=False, gate=0.0),
        near_buf[0], near_idx[0], far_buf[0],
    )
    assert n_far == 0  # theta inf: every leaf opened
    assert n_near < 0.6 * e.n_emitters


def test_cells_in_tree_order_are_the_same_cells():
    """The near field's tree-order renumbering (bunnell._cells_in_tree_order) gives every
    receiver the same cell terms, a cell deeper than its reach below the receiver's plane
    has none (the tree pass skips it), and a bake does not depend on the vertex order."""
    s = small_scene()
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=4)
    perm, (positions, start, corners, reach) = P._cells_in_tree_order(e, t.order)
    inverse = np.argsort(perm)
    # the table built in tree order is the input order's (cell_corners), rows moved and
    # corners renumbered, each cell's rows in the same (face) order
    sizes = np.diff(e.corner_start)
    np.testing.assert_array_equal(np.diff(start), sizes[perm])
    rows = np.concatenate([np.arange(e.corner_start[v], e.corner_start[v + 1]) for v in perm])
    np.testing.assert_array_equal(corners, inverse[e.corners[rows]])
    assert corners.dtype == np.int32 and e.corners.dtype == np.int64
    np.testing.assert_array_equal(positions, e.positions[perm])
    quad = np.empty((4, 3))
    rng = np.random.default_rng(0)
    skipped = 0
    for j in rng.choice(e.n_vertices, 60, replace=False):
        # the reach: the farthest corner of the cell's quads from its vertex (numpy)
        b, c = e.positions[e.corners[e.corner_start[j] : e.corner_start[j + 1]]].transpose(1, 0, 2)
        e1, e2 = b - e.positions[j], c - e.positions[j]
        far = [np.linalg.norm(x, axis=1) for x in (e1 / 2, (e1 + e2) / 3, e2 / 2)]
        np.testing.assert_allclose(reach[inverse[j]], np.max(far, initial=0.0), rtol=1e-12)
        for _ in range(3):
            p = e.positions[j] + rng.normal(scale=0.05, size=3)
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            for measure in (K.MEASURE_COSINE, K.MEASURE_UNIFORM):
                want = KP.cell_terms(e.positions, e.corner_start, e.corners, j, *p, *n, measure, quad)
                got = KP.cell_terms(positions, start, corners, inverse[j], *p, *n, measure, quad)
                assert got == want
                if n @ (e.positions[j] - p) < -reach[inverse[j]]:  # the tree pass skips it
                    assert want == (0.0, 0.0)
                    skipped += 1
    assert skipped > 10
    # the same mesh with its vertices shuffled bakes the same values
    big = sphere_on_plane(subdivisions=3, cells=30)
    shuffle = rng.permutation(big.n_vertices)
    back = np.argsort(shuffle)
    shuffled = surface_from_arrays(big.positions[shuffle], back[big.faces], big.normals[shuffle])
    # (theta inf: the two trees may cluster ties differently, the sums may not differ)
    np.testing.assert_allclose(
        B.variant_ao(shuffled, theta=np.inf), B.variant_ao(big, theta=np.inf)[shuffle], atol=1e-6
    )


def test_tree_splits_coincident_centres_by_index():
    """All disks at one point (a fan of split vertices): the build terminates, leaves small."""
    k = 50
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    rim = np.c_[np.cos(ang), np.sin(ang), np.zeros(k)]
    positions = np.vstack([np.zeros((k, 3)), rim])  # k copies of the centre
    faces = np.c_[np.arange(k), k + np.arange(k), k + (np.arange(k) + 1) % k]
    s = surface_from_arrays(positions, faces)
    e = B.build_elements(s)
    hub = e.emitter_index[e.emitter_index < k]
    keys = H.tree_keys(e.positions[hub])
    np.testing.assert_array_equal(keys, 0)
    perm, start, stop, skip = KH.build_tree(keys, 2)
    leaf = skip == np.arange(len(skip)) + 1
    assert np.all(stop - start >= 1) and np.max(stop[leaf] - start[leaf]) <= 2
    np.testing.assert_array_equal(np.sort(perm), np.arange(len(hub)))
    assert np.all(np.isfinite(B.variant_ao(s)))


def test_refit_tree_matches_a_fresh_geometry():
    """Animation: after the vertices move, a refit has the geometry a build would give
    for the same order, and bakes what the exact sum gives at huge theta."""
    s = small_scene()
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=4)
    rng = np.random.default_rng(3)
    moved_s = surface_from_arrays(
        s.positions + 0.02 * rng.normal(size=s.positions.shape), s.faces, s.normals
    )
    moved = B.build_elements(moved_s)
    refit = B.refit_tree(t, moved.positions, moved.areas)
    np.testing.assert_array_equal(refit.order, t.order)
    np.testing.assert_allclose(
        refit.geometry,
        H.node_geometry(moved.positions, moved.areas, t.order, t.start, t.stop),
        rtol=0,
        atol=0,
    )
    np.testing.assert_allclose(
        passes_of(moved, refit, theta=np.inf),
        passes_of(moved, None),
        rtol=0,
        atol=2e-6,
    )


def test_bunnell_ao_refits_a_given_tree():
    """Animation: a tree from frame 0 is refit to frame 1 (same emitters) and gives frame
    1's exact sum at huge theta; with a different emitter set it is rebuilt."""
    s0 = touching_spheres()
    moved = s0.positions.copy()
    moved[: len(moved) // 2] += [-0.05, 0.02, 0.0]  # the first sphere moves away
    s1 = surface_from_arrays(moved, s0.faces)
    tree0 = B.build_tree(B.build_elements(s0), leaf_size=4)
    np.testing.assert_allclose(
        B.variant_ao(s1, tree=tree0, theta=np.inf), B.variant_ao(s1, exact=True), atol=2e-6
    )
    refit = B.variant_ao(s1, tree=tree0)
    assert np.sqrt(np.mean((refit - B.variant_ao(s1)) ** 2)) < 5e-3
    other = B.build_tree(B.build_elements(small_scene()))
    np.testing.assert_array_equal(B.variant_ao(s1, tree=other), B.variant_ao(s1))
