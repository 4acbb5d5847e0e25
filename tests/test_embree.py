"""The Embree reference (aobake.methods.embree) against closed forms, a float64
reference tracer and itself; the contact-safe origins it starts from (aobake.contacts)."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aobake.contacts import contact_origins, ray_offsets, shell_labels
from aobake.kernels import topology as _topo
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import EmbreeOptions, embree_ao
from aobake.methods.embree.estimator import estimate, half_width, stratified_half_width
from aobake.sampling import sample_directions
from aobake.testing import scenes
from aobake.testing.closed_forms import polygon_form_factor
from aobake.testing.naive_rays import reference_ao
from aobake.tracing import Tracer


def mc_bound(a: float, n: int) -> float:
    """5 sigma of a binomial estimate (stratified sampling only does better)."""
    return 5.0 * math.sqrt(max(a * (1.0 - a), 1.0 / n) / n)


@pytest.mark.parametrize("radius,height", [(1.0, 0.7), (0.5, 2.0), (3.0, 0.3)])
@pytest.mark.parametrize("n_rays", [64, 1024])
def test_point_under_disk_cosine(radius, height, n_rays):
    s = scenes.receiver_under_disk(radius, height, sides=512)
    receiver = s.n_vertices - 3
    exact_polygon = polygon_form_factor(s.positions[1:513], [0, 0, 0], [0, 0, 1])
    exact_disk = radius**2 / (radius**2 + height**2)
    assert exact_polygon == pytest.approx(exact_disk, rel=1e-4)  # the polygon is a disk
    a = 1.0 - embree_ao(s, n_rays=n_rays, seed=1).ao[receiver]
    assert abs(a - exact_polygon) <= mc_bound(exact_polygon, n_rays)


@pytest.mark.parametrize("radius,height", [(1.0, 0.7), (0.5, 2.0)])
def test_point_under_disk_uniform(radius, height):
    # uniform measure: the solid-angle fraction of the hemisphere, 1 - h / sqrt(h^2 + R^2)
    s = scenes.receiver_under_disk(radius, height, sides=512)
    exact = 1.0 - height / math.hypot(height, radius)
    n = 1024
    a = 1.0 - embree_ao(s, n_rays=n, measure="uniform", seed=3).ao[s.n_vertices - 3]
    assert abs(a - exact) <= mc_bound(exact, n) + 2e-4  # + polygon vs disk


def test_stratified_error_far_below_binomial_bound():
    # 200 seeds of one receiver: the RMS error of the scrambled Sobol estimate sits well
    # under the binomial standard deviation sqrt(A(1 - A) / N) of plain Monte Carlo.
    s = scenes.receiver_under_disk(1.0, 0.7, sides=512)
    exact = polygon_form_factor(s.positions[1:513], [0, 0, 0], [0, 0, 1])
    n = 64
    est = np.array([1.0 - embree_ao(s, n_rays=n, seed=k).ao[-3] for k in range(200)])
    rms = np.sqrt(np.mean((est - exact) ** 2))
    assert rms < 0.5 * math.sqrt(exact * (1 - exact) / n)
    assert abs(est.mean() - exact) < 4 * rms / math.sqrt(200)  # unbiased


def test_inside_closed_sphere_is_fully_occluded():
    s = scenes.sphere(2.0, 3, inward=True)
    np.testing.assert_array_equal(embree_ao(s, n_rays=64).ao, 0.0)


@pytest.mark.parametrize(
    "surface",
    [scenes.sphere(1.0, 3), scenes.box(), scenes.random_convex(0)],
    ids=["sphere", "box", "hull"],
)
@pytest.mark.parametrize("measure", ["cosine", "uniform"])
def test_convex_body_does_not_occlude_itself(surface, measure):
    # Exactly 1: any self-hit from a too-small offset or a leak would show.
    np.testing.assert_array_equal(embree_ao(surface, n_rays=128, measure=measure).ao, 1.0)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([1e-5, 1.0, 1e5]))
def test_random_convex_hulls_open_at_any_scale(seed, scale):
    s = scenes.random_convex(seed, 1, scale)
    np.testing.assert_array_equal(embree_ao(s, n_rays=32).ao, 1.0)


@pytest.mark.parametrize("half,r", [(4.0, 0.5), (4.0, 2.0)])
def test_parallel_plates_with_max_distance(half, r):
    # cosine-weighted: a ray from the lower plate reaches the upper one within r iff
    # cos(theta) >= gap / r, so ao = P(cos < gap / r) = (gap / r)^2.
    gap = 0.25
    s = scenes.parallel_plates(gap, half, cells=8)
    centre = int(np.argmin(np.linalg.norm(s.positions - [0, 0, 0], axis=1)))
    n = 1024
    ao = embree_ao(s, n_rays=n, max_distance=r).ao[centre]
    exact = (gap / r) ** 2
    assert abs(ao - exact) <= mc_bound(exact, n)


def test_matches_independent_float64_tracer():
    # Same origins and directions, Moller-Trumbore in float64 instead of Embree: the
    # estimates agree except for rays grazing an edge within float32 rounding.
    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.05, cells=6)
    n = 32
    result = embree_ao(s, n_rays=n, seed=5)
    scene = Tracer(s.positions, s.faces)
    origins, _ = contact_origins(s, scene, ray_offsets(s, scene.magnitude))
    dirs = sample_directions(s.normals, n, seed=5)
    ref = reference_ao(s, origins.astype(np.float64) * scene.scale + scene.center, dirs)
    assert np.abs(result.ao - ref).max() <= 2.0 / n
    assert np.mean(result.ao != ref) < 0.02


@pytest.mark.parametrize("offset,scale", [(0.0, 1.0), (1e4, 1.0), (0.0, 1e-9)])
def test_buffer_upload_traces_as_triangle_mesh(monkeypatch, offset, scale):
    # Tracer fills Embree's buffers through numpy (tracing._upload) instead of embreex's
    # TriangleMesh: the same float32 triangles, so every query answers bit for bit the same.
    from aobake import tracing

    assert tracing._embree_api(), "embreex's objects are not laid out as tracing expects"
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=12)
    pos = s.positions * scale + offset
    fast = Tracer(pos, s.faces)
    monkeypatch.setattr(tracing, "_api", False)
    slow = Tracer(pos, s.faces)
    assert (fast.center == slow.center).all() and fast.scale == slow.scale
    rng = np.random.default_rng(3)
    org = fast.frame(fast.local[rng.integers(0, len(pos), 20000)] * (1 + 1e-3))
    dirs = rng.normal(size=org.shape).astype(np.float32)
    reach = np.full(len(org), 0.2 * scale)
    for query in ("occluded", "first_hits"):
        a, b = getattr(fast, query)(org, dirs), getattr(slow, query)(org, dirs)
        assert (a == b).all() and 0.05 < (a >= 0).mean() < 0.95
    a, b = fast.intersect(org, dirs, reach), slow.intersect(org, dirs, reach)
    assert all(np.array_equal(a[k], b[k]) for k in ("primID", "tfar", "Ng", "u", "v"))


def test_background_build_answers_as_a_build_now(monkeypatch):
    # Tracer.build(background=True) has Embree build the BVH on a thread of its own (the
    # GIL released) and the first query wait for it: the same triangles, every answer the
    # same bit for bit; a failure in that thread is raised by the query; where the
    # buffers cannot be filled through numpy the build happens at once.
    from aobake import tracing

    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=12)
    now = Tracer(s.positions, s.faces)
    later = Tracer(s.positions, s.faces, deferred=True).build(background=True)
    assert later._building is not None and later._building[0].name == "embree-build"
    rng = np.random.default_rng(5)
    org = now.frame(now.local[rng.integers(0, s.n_vertices, 20000)] * (1 + 1e-3))
    dirs = rng.normal(size=org.shape).astype(np.float32)
    a, b = later.intersect(org, dirs, np.full(len(org), 0.3)), now.intersect(org, dirs, np.full(len(org), 0.3))
    assert later._building is None and all(np.array_equal(a[k], b[k]) for k in ("primID", "tfar", "Ng", "u", "v"))
    assert (later.occluded(org, dirs) == now.occluded(org, dirs)).all() and 0.05 < (a["primID"] >= 0).mean() < 0.95
    assert later.build() is later and (later.occluded(org, dirs) == now.occluded(org, dirs)).all()

    monkeypatch.setattr(tracing, "_commit", lambda scene, device, outcome: outcome.append(MemoryError("no room")))
    failed = Tracer(s.positions, s.faces, deferred=True).build(background=True)
    with pytest.raises(MemoryError, match="no room"):
        failed.occluded(org, dirs)
    monkeypatch.setattr(tracing, "_api", False)  # another embreex build: TriangleMesh, built now
    fallback = Tracer(s.positions, s.faces, deferred=True).build(background=True)
    assert fallback._building is None and (fallback.occluded(org, dirs) == now.occluded(org, dirs)).all()


def _scene_with_variety():
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=12)
    return s


def test_stratified_beats_random_and_converges():
    s = _scene_with_variety()
    ref = embree_ao(s, n_rays=8192, seed=99).ao

    def rmse(n, stratified):
        return np.sqrt(
            np.mean((estimate(s, EmbreeOptions(n_rays=n, seed=1), stratified=stratified).ao - ref) ** 2)
        )

    strat16, strat256 = rmse(16, True), rmse(256, True)
    rand16, rand256 = rmse(16, False), rmse(256, False)
    assert strat16 < 0.8 * rand16
    assert strat256 < 0.6 * rand256
    # 16x the rays: plain MC shrinks ~4x; stratified at least as fast
    assert rand16 / rand256 > 3.0
    assert strat16 / strat256 > 4.0


def test_far_from_origin_matches_origin():
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=12)
    size = np.ptp(s.positions, axis=0).max()
    moved = surface_from_arrays(
        s.positions + 1e4 * size * np.array([1.0, -0.7, 0.3]), s.faces, s.normals
    )
    a = embree_ao(s, n_rays=64).ao
    b = embree_ao(moved, n_rays=64).ao
    # recentring in float64 makes the float32 scene identical up to the last bit of
    # the subtraction, so at most a few rays grazing an edge can differ
    assert np.abs(a - b).max() <= 2.0 / 64
    assert np.mean(a != b) < 0.01


@pytest.mark.parametrize("gap", [0.0, 1e-7, -1e-7, 1e-5, -1e-4, 1e-3])
def test_contact_vertex_stays_occluded(gap):
    # The sphere's lowest vertex faces straight down onto the floor it rests on (or
    # touches, or sinks slightly into): its whole hemisphere is blocked.
    s, low = scenes.sphere_on_ground(0.5, 3, gap=gap)
    r = embree_ao(s, n_rays=256)
    assert r.ao[low] == 0.0
    near = np.flatnonzero((np.arange(s.n_vertices) < 642) & (s.positions[:, 2] - gap < 0.02))
    assert r.ao[near].max() < 0.05


def test_scene_diagonal_bias_without_contact_fix_reproduces_the_peer_bug():
    # What peers do (offset 1e-3 * diagonal, nothing else) reads the contact open: the
    # test above can tell a right answer from this wrong one.
    s, low = scenes.sphere_on_ground(0.5, 3, gap=0.0)
    diag = np.linalg.norm(np.ptp(s.positions, axis=0))
    bad = estimate(s, EmbreeOptions(n_rays=256, bias=1e-3 * diag), contact_fix=False).ao
    assert bad[low] == 1.0
    fixed = embree_ao(s, n_rays=256, bias=1e-3 * diag).ao
    assert fixed[low] == 0.0


def test_cube_on_floor_coplanar_contact():
    # A unit cube whose bottom face lies in the floor plane, sharing no vertices with
    # it. The bottom corner (normal (1, 1, -1)/sqrt 3) sees the floor below its horizon:
    # A = cosine-weighted fraction of its hemisphere with w_z < 0, i.e.
    # 1/2 + (2/pi)(asin(s) + s sqrt(1 - s^2)) / 2 with s = sin(elevation) = 1/sqrt(3)...
    # computed here by quadrature rather than trusted to algebra.
    import trimesh

    cube = trimesh.creation.box(extents=(1, 1, 1))
    cube.apply_translation([0, 0, 0.5])
    gp, gf = scenes.ground_grid(3.0, 5)  # no floor vertex at the cube corners
    s = surface_from_arrays(np.vstack([cube.vertices, gp]), np.vstack([cube.faces, gf + 8]))
    corner = int(
        np.flatnonzero(
            (cube.vertices[:, 2] == 0) & (cube.vertices[:, 0] > 0) & (cube.vertices[:, 1] > 0)
        )[0]
    )
    n = s.normals[corner]
    # quadrature of (1/pi) int_{w.n > 0, w_z < 0} (w.n) dw
    t = (np.arange(400) + 0.5) / 400 * np.pi
    p = (np.arange(800) + 0.5) / 800 * 2 * np.pi
    th, ph = np.meshgrid(t, p, indexing="ij")
    w = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    c = w @ n
    da = np.sin(th) * (np.pi / 400) * (2 * np.pi / 800)
    exact = float(np.sum(c * da * ((c > 0) & (w[..., 2] < 0))) / np.pi)
    nr = 1024
    ao = embree_ao(s, n_rays=nr).ao
    assert abs((1.0 - ao[corner]) - exact) <= mc_bound(exact, nr)
    # without the fix the origin sits under the floor and the answer is the complement
    wrong = estimate(s, EmbreeOptions(n_rays=nr), contact_fix=False).ao
    assert abs((1.0 - wrong[corner]) - exact) > 0.3


def test_two_sided_sheet_is_not_a_contact():
    # Two coincident sheets facing apart: both sides open; the contact fix must not flip them.
    p, f = scenes.ground_grid(1.0, 4)
    positions = np.vstack([p, p])
    faces = np.vstack([f, f[:, ::-1] + len(p)])
    normals = np.zeros_like(positions)
    normals[: len(p), 2] = 1
    normals[len(p) :, 2] = -1
    s = surface_from_arrays(positions, faces, normals)
    r = embree_ao(s, n_rays=64)
    np.testing.assert_array_equal(r.ao, 1.0)
    assert r.contacts == 0


@pytest.mark.parametrize("tolerance", [0.05, 0.02])
def test_adaptive_stops_early_within_tolerance(tolerance):
    # Vertices that stop before the cap have a 95% interval narrower than the
    # tolerance: at least 95% of them must really be within it of a high-ray reference.
    s = _scene_with_variety()
    ref = embree_ao(s, n_rays=8192, seed=7).ao
    adaptive = embree_ao(s, n_rays=1024, seed=1, tolerance=tolerance)
    assert adaptive.n_rays < 0.5 * 1024 * s.n_vertices
    assert adaptive.rays.min() >= 16
    stopped = adaptive.rays < 1024
    assert stopped.mean() > 0.5
    within = np.abs(adaptive.ao[stopped] - ref[stopped]) <= tolerance
    assert within.mean() >= 0.95
    # every round ends on a power of two
    assert set(np.unique(adaptive.rays)) <= {16, 32, 64, 128, 256, 512, 1024}


def test_stratified_half_width_is_tighter_than_binomial_but_not_blind():
    n = 256
    hits = np.array([128, 128, 0])
    first = np.array([64, 20, 0])  # second row: halves disagree badly
    w = stratified_half_width(hits, first, n)
    assert w[0] < 0.6 * half_width(hits[:1], np.array([n]))[0]  # n_eff = 4n at n = 256
    assert w[1] >= 1.959 * 0.5 * abs(20 / 128 - 108 / 128)
    assert w[2] > 0


def test_half_width_never_zero():
    hw = half_width(np.array([0, 16, 8]), np.array([16, 16, 16]))
    assert (hw > 0.05).all()
    assert hw[0] == pytest.approx(hw[1])


def test_vertex_without_normal_samples_sphere():
    # An isolated vertex in the middle of a closed sphere: blocked in every direction.
    s = scenes.sphere(1.0, 2)
    positions = np.vstack([s.positions, [[0.0, 0.0, 0.0]]])
    t = surface_from_arrays(positions, s.faces)
    assert not t.normals[-1].any()
    np.testing.assert_array_equal(embree_ao(t, n_rays=32).ao[-1], 0.0)


def test_degenerate_and_duplicate_geometry_is_finite():
    s = scenes.sphere(1.0, 2)
    positions = np.vstack([s.positions, s.positions[:3], [[5.0, 5.0, 5.0]]])
    n0 = len(s.positions)
    faces = np.vstack([s.faces, [[0, 0, 1], [n0, n0 + 1, n0 + 2], [2, 2, 2]]])
    t = surface_from_arrays(positions, faces)
    ao = embree_ao(t, n_rays=32).ao
    assert np.isfinite(ao).all() and ao.min() >= 0 and ao.max() <= 1


@pytest.mark.parametrize(
    "bad",
    [
        dict(n_rays=0),
        dict(measure="x"),
        dict(max_distance=0.0),
        dict(bias=-1.0),
        dict(tolerance=0.0),
    ],
)
def test_bad_options_rejected(bad):
    with pytest.raises(ValueError):
        embree_ao(scenes.box(), **bad)


# --------------------------------------------------------------------------- topology kernels


def _equal_position_classes(positions):
    """Reference: vertices grouped by ``==`` on all three coordinates (NaN alone)."""
    classes = {}
    for i, p in enumerate(positions):
        if np.isnan(p).any():
            classes[("nan", i)] = [i]
        else:
            classes.setdefault(tuple(float(x) + 0.0 for x in p), []).append(i)  # -0.0 -> 0.0
    return sorted(sorted(c) for c in classes.values())


def _runs(order, run_start):
    return sorted(
        sorted(order[run_start[k] : run_start[k + 1]].tolist()) for k in range(len(run_start) - 1)
    )


def _lexsort_shell_labels(surface):
    """The former shell_labels (lexsort runs), kept as the specification."""
    pos = surface.positions
    order = np.lexsort((pos[:, 2], pos[:, 1], pos[:, 0])).astype(np.int64)
    sp = pos[order]
    new_run = np.r_[True, (sp[1:] != sp[:-1]).any(axis=1), True]
    run_start = np.flatnonzero(new_run).astype(np.int64)
    return _topo.shells(surface.faces, order, run_start, np.ascontiguousarray(surface.normals))


def _awkward_positions(seed, n=300):
    rng = np.random.default_rng(seed)
    values = np.array([0.0, -0.0, 1.0, -1.0, 0.5, np.nan, np.inf, -np.inf, 1e-300, 5e-324])
    positions = rng.choice(values, size=(n, 3))
    copies = rng.integers(0, n, n // 3)
    positions[rng.integers(0, n, n // 3)] = positions[copies] * rng.choice([1.0, -1.0], (n // 3, 1))
    return positions


@pytest.mark.parametrize("seed", range(5))
def test_coincident_runs_are_the_equal_position_classes(seed):
    positions = _awkward_positions(seed)
    keys = _topo.position_keys(positions)
    assert len(set(keys.tolist())) == len(keys)  # the index in the low bits
    order, run_start = _topo.coincident_runs(positions, np.sort(keys))
    assert sorted(order.tolist()) == list(range(len(positions)))
    assert run_start[0] == 0 and run_start[-1] == len(positions)
    runs = _runs(order, run_start)
    assert runs == _equal_position_classes(positions)


def test_coincident_runs_survive_hash_collisions():
    # Keys that keep only the index (every hash equal): the runs must still be exact.
    positions = _awkward_positions(7, n=200)
    keys = np.arange(len(positions), dtype=np.uint64)[::-1].copy()
    order, run_start = _topo.coincident_runs(positions, np.sort(keys))
    runs = _runs(order, run_start)
    assert runs == _equal_position_classes(positions)


def test_position_keys_signed_zero_and_nan():
    positions = np.array(
        [[0.0, 1.0, -0.0], [-0.0, 1.0, 0.0], [np.nan, 0, 0], [np.nan, 0, 0], [0.0, 1.0, 1e-300]]
    )
    keys = _topo.position_keys(positions)
    low = np.uint64((1 << _topo.index_bits(len(positions))) - 1)
    np.testing.assert_array_equal(keys & low, np.arange(len(positions)))
    hashes = keys & ~low
    assert hashes[0] == hashes[1]
    assert hashes[2] != hashes[3] and hashes[4] != hashes[0]
    assert [_topo.index_bits(n) for n in (0, 1, 2, 3, 4, 5, 1 << 20, (1 << 20) + 1)] == [
        1, 1, 1, 2, 2, 3, 20, 21
    ]  # fmt: skip


@pytest.mark.parametrize("seed", range(8))
def test_shell_labels_match_lexsort_runs(seed):
    # Coincident vertices (split normals, -0.0 against 0.0, NaN) joined as before.
    rng = np.random.default_rng(seed)
    positions = _awkward_positions(seed, n=400)
    faces = rng.integers(0, len(positions), size=(int(rng.integers(0, 300)), 3))
    normals = rng.normal(size=positions.shape)
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[rng.random(len(positions)) < 0.2] = 0.0
    s = types.SimpleNamespace(positions=positions, faces=faces, normals=normals)
    np.testing.assert_array_equal(shell_labels(s), _lexsort_shell_labels(s))


def test_shell_labels_on_contact_scenes():
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0)
    labels = shell_labels(s)
    np.testing.assert_array_equal(labels, _lexsort_shell_labels(s))
    assert labels.max() == 1


@pytest.mark.parametrize("seed", range(4))
def test_face_grouping_kernels_match_numpy(seed):
    rng = np.random.default_rng(seed)
    n, m, n_shells = 500, 800, 9
    positions = rng.normal(size=(n, 3))
    positions[rng.random((n, 3)) < 0.05] = -0.0
    shell = rng.integers(0, n_shells, n)
    # faces within one shell each, leaving some vertices and shells without faces
    faces = np.array(
        [rng.choice(np.flatnonzero(shell == shell[v]), 3) for v in rng.integers(0, n, m)]
    )
    faces = faces[shell[faces[:, 0]] != 3]
    sizes, referenced = _topo.shell_faces(faces, shell, n_shells)
    np.testing.assert_array_equal(sizes, np.bincount(shell[faces[:, 0]], minlength=n_shells))
    np.testing.assert_array_equal(referenced, np.isin(np.arange(n), faces))
    rank = np.full(n_shells, -1)
    with_faces = np.flatnonzero(sizes > 0)
    rank[with_faces[np.argsort(-sizes[with_faces], kind="stable")]] = np.arange(with_faces.size)
    n_groups = 3
    shell_group = np.where(rank >= 0, rank % n_groups, -1)
    order, start, lo, hi = _topo.group_faces(
        positions, faces, shell, referenced, sizes, shell_group, n_groups
    )
    group_of_face = shell_group[shell[faces[:, 0]]]
    np.testing.assert_array_equal(order, np.argsort(group_of_face, kind="stable"))
    np.testing.assert_array_equal(start, np.searchsorted(group_of_face[order], np.arange(4)))
    for g in range(n_groups):
        corners = positions[faces[group_of_face == g]].reshape(-1, 3)
        np.testing.assert_array_equal(lo[g], corners.min(axis=0))
        np.testing.assert_array_equal(hi[g], corners.max(axis=0))
    # probes: vertices (with a normal and an offset) whose box meets another group's box
    origins = positions + rng.normal(scale=0.1, size=(n, 3))
    reach = rng.random(n) * 0.5
    normals = rng.normal(size=(n, 3))
    normals[rng.random(n) < 0.1] = 0.0
    offsets = np.where(rng.random(n) < 0.1, 0.0, 1e-3)
    pstart, probes = _topo.group_probes(
        origins, reach, normals, offsets, shell, shell_group, lo, hi
    )
    vlo, vhi = origins - reach[:, None], origins + reach[:, None]
    candidates = normals.any(axis=1) & (offsets > 0)
    for g in range(n_groups):
        near = (vhi >= lo[g]).all(axis=1) & (vlo <= hi[g]).all(axis=1)
        expected = np.flatnonzero(candidates & near & (shell_group[shell] != g))
        np.testing.assert_array_equal(probes[pstart[g] : pstart[g + 1]], expected)


def test_longest_edges_and_offset_points_match_numpy_bit_for_bit():
    rng = np.random.default_rng(3)
    n = 300
    positions = rng.normal(size=(n, 3)) * rng.choice([1e-8, 1.0, 1e8], size=(n, 1))
    faces = rng.integers(0, n - 10, size=(600, 3))  # the last vertices unreferenced
    faces[:5] = faces[:5, :1]  # degenerate
    d = positions[np.roll(faces, -1, axis=1)] - positions[faces]
    lengths = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])
    expected = np.zeros(n)
    np.maximum.at(expected, faces.ravel(), lengths.ravel())
    np.maximum.at(expected, np.roll(faces, -1, axis=1).ravel(), lengths.ravel())
    assert _topo.longest_edges(positions, faces).tobytes() == expected.tobytes()
    normals = rng.normal(size=(n, 3))
    offsets = rng.random(n) * 1e-3
    out = _topo.offset_points(positions, offsets, normals)
    assert out.tobytes() == (positions + offsets[:, None] * normals).tobytes()
