"""The disk transfer through the cluster tree (aobake.methods.bunnell.transfer.tree_transfer,
prepare_transfer; kernels/transfertree.py) against the brute-force sum
(unshadowed_irradiance): equal with every cluster opened, closer as theta grows, never
negative, the same for any thread count, and a prepared scene re-lit by new radiance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aobake.constants import MEASURE_COSINE
from aobake.kernels.polygon import cell_terms
from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell.elements import build_elements
from aobake.methods.bunnell.passes import build_tree
from aobake.methods.bunnell.transfer import (
    DEFAULT_TRANSFER_THETA,
    prepare_transfer,
    tree_transfer,
    unshadowed_irradiance,
)
from aobake.testing.scenes import ground_grid, sphere_on_plane, spheres_in_block


def rel_rmse(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def lit(elements, direction=(0.3, -0.5, 0.8), colour=(0.8, 0.5, 0.3)):
    """Radiance of a diffuse surface under a distant light, unshadowed: ``max(n.l, 0) rho``
    (half of every ball dark, the floor lit)."""
    d = np.asarray(direction, dtype=np.float64)
    return np.maximum(elements.normals @ (d / np.linalg.norm(d)), 0.0)[:, None] * np.asarray(colour)


@pytest.fixture(scope="module")
def block():
    """Four balls on a floor, 2,329 vertices, lit from one side; its brute-force transfer."""
    el = build_elements(spheres_in_block(2, 40))
    radiance = lit(el)
    return el, radiance, unshadowed_irradiance(el, radiance)


def test_every_cluster_opened_is_the_brute_force_sum(block):
    """The same terms, in float32 (lists relative to each bucket's centre): within float32
    rounding (measured: 5e-7 of the largest value)."""
    el, radiance, want = block
    got = tree_transfer(el, radiance, theta=np.inf, near=0.0)
    assert np.allclose(got, want, rtol=1e-5, atol=2e-6 * want.max())
    # random radiance with dark vertices and a zero-normal vertex
    surface = sphere_on_plane(1, 6)
    normals = surface.normals.copy()
    normals[5] = 0.0
    el = build_elements(dataclasses.replace(surface, normals=normals))
    radiance = np.random.default_rng(2).uniform(0, 1, (el.n_vertices, 3))
    radiance[::3] = 0.0
    want = unshadowed_irradiance(el, radiance)
    got = tree_transfer(el, radiance, theta=np.inf, near=0.0)
    assert np.allclose(got, want, rtol=1e-5, atol=2e-6 * want.max())
    assert np.all(got[5] == 0) and np.count_nonzero(got[:, 0]) > el.n_vertices // 2


def near_field_reference(el, radiance, near):
    """The brute-force sum with the near field, in float64 numpy: a disk j within
    sqrt(near A_j) of receiver i gives pi F L_j, F the form factor of j's cell toward its
    front (polygon.cell_terms), every other disk its disk term
    ``pi A cos_e cos_r / (pi r^2 + A)`` (both sides facing, not i's own, not coincident)."""
    emit = el.emitter_index
    c, m, a = el.positions[emit], el.normals[emit], el.areas[emit]
    d = c[None, :, :] - el.points[:, None, :]
    r2 = (d * d).sum(-1)
    cr = (el.normals[:, None, :] * d).sum(-1)
    ce = -(m[None, :, :] * d).sum(-1)
    has_normal = el.normals.any(axis=1)[:, None]
    own = emit[None, :] == np.arange(el.n_vertices)[:, None]
    is_near = (r2 < near * a) & ~own & has_normal
    keep = (cr > 0) & (ce > 0) & (r2 > 1e-12 * a) & ~own & has_normal & ~is_near
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(keep, np.pi * a * ce * cr / (r2 * (np.pi * r2 + a)), 0.0)
    quad = np.empty((4, 3))
    for i, col in zip(*np.nonzero(is_near), strict=True):
        front, _ = cell_terms(el.positions, el.corner_start, el.corners, emit[col], *el.points[i], *el.normals[i],
                              MEASURE_COSINE, quad)  # fmt: skip
        f[i, col] = np.pi * front
    return f @ radiance[emit]


def test_near_field_is_the_cells_exact_form_factor():
    """With near > 0, every cluster opened: disks near a receiver give their cells' exact
    form factor (the ball's pole touching the floor: the floor beside it sees the ball's
    underside fill most of its sky, where the pole's disk is edge-on)."""
    surface = sphere_on_plane(1, 6)
    el = build_elements(surface)
    radiance = np.random.default_rng(4).uniform(0, 1, (el.n_vertices, 3))
    for near in (1.0, 4.0):
        want = near_field_reference(el, radiance, near)
        got = tree_transfer(el, radiance, theta=np.inf, near=near)
        assert np.allclose(got, want, rtol=1e-5, atol=2e-6 * want.max()), near
    disks = unshadowed_irradiance(el, radiance)
    assert np.max(np.abs(got - disks)) > 0.1 * disks.max()  # the near field changes something


def test_near_field_matches_the_ray_traced_reference_better():
    """A floor beside an emissive wall (an open L: nothing occludes): the near field
    brings the floor's irradiance at the crease to the ray-traced direct irradiance
    (measured relative RMSE: disks 0.086, near 4 0.050, near 16 0.016; 4096 samples)."""
    from aobake.methods.embree.light import irradiance
    from aobake.shading import Shading

    surface, n_floor, n_floor_faces = floor_and_wall(16)
    n = surface.n_vertices
    emission = np.zeros((n, 3))
    emission[n_floor:] = 1.0
    face_emission = np.zeros((surface.n_faces, 3))
    face_emission[n_floor_faces:] = 1.0
    shading = Shading((), np.zeros((surface.n_faces, 3)), face_emission, np.zeros((n, 3)), emission)
    ref = irradiance(surface, shading, n_samples=4096, bounces=0, seed=1).direct[:n_floor]
    el = build_elements(surface)
    err = {near: rel_rmse(tree_transfer(el, emission, near=near)[:n_floor], ref) for near in (0.0, 4.0, 16.0)}
    assert err[16.0] < 0.025 and err[4.0] < 0.06 and err[0.0] > 0.07, err
    assert err[16.0] < err[4.0] < err[0.0], err


def floor_and_wall(cells):
    """A 2 x 2 floor (z = 0, facing up) and a 2 x 2 wall standing on its edge x = -1
    (facing +x): the surface, the floor's vertex and face counts."""
    fp, ff = ground_grid(1.0, cells)
    wp, wf = ground_grid(1.0, cells)
    wp = np.c_[wp[:, 2] - 1.0, wp[:, 1], 1.0 - wp[:, 0]]  # a rotation about y: +z -> +x
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (len(fp), 1)), np.tile([1.0, 0.0, 0.0], (len(wp), 1))])
    surface = surface_from_arrays(np.vstack([fp, wp]), np.vstack([ff, wf + len(fp)]), normals)
    return surface, len(fp), len(ff)


def test_error_shrinks_as_theta_grows(block):
    """Measured: relative RMSE 8.6e-3 / 4.5e-3 / 2.2e-3 / 1.2e-3 / 2.6e-4 at theta
    1 / 2 / 4 / 8 / 16 on this scene (disks only); 2.0e-3 at the defaults (near 4)."""
    el, radiance, want = block
    errors = [rel_rmse(tree_transfer(el, radiance, theta=t, near=0.0), want) for t in (1, 2, 4, 8, 16)]
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[0] < 0.02 and errors[-1] < 1e-3, errors
    assert errors[0] > 1e-3  # the tree is used: theta 1 is not the exact sum
    # the default near field: against the same sum with every cluster opened
    default = rel_rmse(tree_transfer(el, radiance), tree_transfer(el, radiance, theta=np.inf))
    assert default < 4e-3, default


def test_no_negative_light_and_dark_gives_zero(block):
    el, radiance, _ = block
    rng = np.random.default_rng(5)
    for theta in (0.5, DEFAULT_TRANSFER_THETA):
        r = radiance * rng.uniform(0, 2, radiance.shape)
        got = tree_transfer(el, r, theta=theta)
        assert np.all(np.isfinite(got)) and np.all(got >= 0.0) and got.max() > 0
    assert np.all(tree_transfer(el, np.zeros_like(radiance)) == 0.0)


def test_prepared_scene_relit_equals_fresh_transfers(block):
    el, radiance, _ = block
    scene = prepare_transfer(el)
    other = lit(el, direction=(-0.7, 0.2, 0.3), colour=(0.1, 0.9, 0.4))
    first = scene.gather(radiance)
    second = scene.gather(other)
    assert np.array_equal(first, tree_transfer(el, radiance))
    assert np.array_equal(second, tree_transfer(el, other))
    assert not np.allclose(first, second)
    assert np.array_equal(scene.gather(radiance), first)  # nothing left over from a call


def test_refitted_tree_after_a_move():
    """A tree built before the vertices moved is refitted by prepare_transfer: every
    cluster opened it is still the brute-force sum, and at the default theta close to it."""
    surface = sphere_on_plane(1, 8)
    el = build_elements(surface)
    tree = build_tree(el)
    moved = surface.positions.copy()
    moved[surface.positions[:, 2] > -0.99] += [0.4, 0.1, 0.3]  # the ball moves up and aside
    el2 = build_elements(dataclasses.replace(surface, positions=moved))
    radiance = lit(el2)
    want = unshadowed_irradiance(el2, radiance)
    got = tree_transfer(el2, radiance, theta=np.inf, near=0.0, tree=tree)
    assert np.allclose(got, want, rtol=1e-5, atol=2e-6 * want.max())
    assert rel_rmse(tree_transfer(el2, radiance, near=0.0, tree=tree), want) < 0.01


def test_same_result_for_any_thread_count(block):
    import numba

    el, radiance, _ = block
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = tree_transfer(el, radiance, theta=2.0)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = tree_transfer(el, radiance, theta=2.0)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one, two) and np.count_nonzero(one) > 0


def test_bad_input(block):
    el, radiance, _ = block
    scene = prepare_transfer(el)
    with pytest.raises(ValueError, match="radiance"):
        scene.gather(-radiance - 1)
    with pytest.raises(ValueError, match="radiance"):
        scene.gather(radiance[:-1])
    bad = radiance.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="radiance"):
        scene.gather(bad)
    with pytest.raises(ValueError, match="theta"):
        prepare_transfer(el, theta=0.0)
    other = build_elements(sphere_on_plane(1, 4))
    with pytest.raises(ValueError, match="tree"):
        prepare_transfer(el, tree=build_tree(other))


def test_no_casting_disk_gives_zero():
    el = build_elements(sphere_on_plane(1, 4))
    none = dataclasses.replace(el, emitter_index=np.zeros(0, dtype=np.int64))
    got = prepare_transfer(none).gather(np.ones((el.n_vertices, 3)))
    assert got.shape == (el.n_vertices, 3) and np.all(got == 0)
