"""The disk method's radiance transfer (aobake.methods.bunnell.transfer): the on-axis closed
form, a tessellated disk converging to it, a numpy reference of the kernel, and the
ray-traced reference on an open scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell.elements import build_elements
from aobake.methods.bunnell.transfer import outgoing_radiance, transfer, unshadowed_irradiance
from aobake.shading import default_shading
from aobake.testing.scenes import ground_grid

UP = np.array([[0.0, 0.0, 1.0]])
DOWN = np.array([[0.0, 0.0, -1.0]])


def disk_irradiance(L, R, h):
    """A point on the axis of a Lambertian disk of radiance L, radius R, height h."""
    return L * math.pi * R**2 / (R**2 + h**2)


def polar_disk(R, rings, h):
    """A disk of radius R at height h facing -z: a centre vertex and ``rings`` rings of
    6 rings vertices each, the outer ring pushed out so the polygon's area is pi R^2."""
    m = 6 * rings
    boost = math.sqrt(2 * math.pi / (m * math.sin(2 * math.pi / m)))
    t = 2 * math.pi * np.arange(m) / m
    pos = [[0.0, 0.0, h]]
    for r in range(1, rings + 1):
        rad = R * r / rings * (boost if r == rings else 1.0)
        pos += [[rad * math.cos(a), rad * math.sin(a), h] for a in t]
    k = np.arange(m)
    faces = [np.c_[np.zeros(m, int), 1 + k, 1 + (k + 1) % m]]
    for r in range(rings - 1):
        a, b = 1 + r * m + k, 1 + r * m + (k + 1) % m
        faces += [np.c_[a, a + m, b + m], np.c_[a, b + m, b]]
    return np.array(pos), np.vstack(faces)[:, ::-1]  # wound to face -z


def test_single_disk_on_axis_is_exact():
    L = np.array([[1.0, 2.0, 0.5]])
    for R, h in [(0.7, 1.3), (1.0, 0.1), (0.05, 3.0), (2.0, 2.0)]:
        e = transfer(np.zeros((1, 3)), UP, [[0.0, 0.0, h]], DOWN, [math.pi * R**2], L)
        assert np.allclose(e[0], disk_irradiance(L[0], R, h), rtol=1e-14)
    # tilted receiver and emitter: both cosines, clamped at 0 on the wrong side
    d = np.array([0.6, 0.0, 0.8])
    e = transfer(np.zeros((1, 3)), UP, [2 * d], [[0.0, 0.0, -1.0]], [0.3], L)
    want = math.pi * 0.3 * 0.8 * 0.8 / (math.pi * 4 + 0.3) * L[0]
    assert np.allclose(e[0], want, rtol=1e-14)
    assert np.all(transfer(np.zeros((1, 3)), UP, [2 * d], UP, [0.3], L) == 0)  # emits away
    assert np.all(transfer(np.zeros((1, 3)), DOWN, [2 * d], DOWN, [0.3], L) == 0)  # behind receiver


def test_tessellated_disk_converges_to_the_closed_form():
    R, h, L = 0.7, 1.3, 1.5
    errors = []
    for rings in (2, 4, 8, 16):
        pos, faces = polar_disk(R, rings, h)
        emit = build_elements(surface_from_arrays(pos, faces, np.tile(DOWN, (len(pos), 1))))
        area = emit.areas.sum() * emit.scale**2
        assert area == pytest.approx(math.pi * R**2, rel=1e-12)
        e = transfer(np.zeros((1, 3)), UP, pos, emit.normals, emit.areas * emit.scale**2, np.full((len(pos), 3), L))
        errors.append(abs(e[0, 0] / disk_irradiance(L, R, h) - 1))
    assert errors[-1] < 1e-3
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False))


def _numpy_transfer(points, normals, centres, disk_normals, areas, radiance, own):
    d = centres[None, :, :] - points[:, None, :]
    r2 = (d * d).sum(-1)
    cr = (normals[:, None, :] * d).sum(-1)
    ce = -(disk_normals[None, :, :] * d).sum(-1)
    keep = (cr > 0) & (ce > 0) & (r2 > 1e-12 * areas[None, :]) & (own[None, :] != np.arange(len(points))[:, None])
    keep &= np.any(normals != 0, axis=1)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(keep, math.pi * areas * ce * cr / (r2 * (math.pi * r2 + areas)), 0.0)
    return f @ radiance


def test_kernel_matches_a_numpy_reference():
    rng = np.random.default_rng(7)
    n, k = 60, 90
    points = rng.normal(size=(n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[3] = 0.0  # a vertex without a normal receives nothing
    centres = rng.normal(size=(k, 3))
    centres[:5] = points[:5]  # coincident with their receivers
    dn = rng.normal(size=(k, 3))
    dn /= np.linalg.norm(dn, axis=1)[:, None]
    areas = rng.uniform(0.001, 0.5, k)
    radiance = rng.uniform(0, 2, (k, 3))
    own = np.full(k, -1)
    own[10:20] = np.arange(10, 20)
    got = transfer(points, normals, centres, dn, areas, radiance, own)
    want = _numpy_transfer(points, normals, centres, dn, areas, radiance, own)
    assert np.allclose(got, want, rtol=1e-12, atol=0)
    assert np.all(got >= 0) and np.all(got[3] == 0)
    assert np.count_nonzero(got[:, 0]) > n // 2


def _plane_under_emissive_quad(cells=8, quad_cells=16, h=0.5, L=(1.0, 0.8, 0.4)):
    gp, gf = ground_grid(1.0, cells)
    qp, qf = ground_grid(0.5, quad_cells, z=h, up=False)
    pos = np.vstack([gp, qp])
    faces = np.vstack([gf, qf + len(gp)])
    normals = np.vstack([np.tile(UP, (len(gp), 1)), np.tile(DOWN, (len(qp), 1))])
    surface = surface_from_arrays(pos, faces, normals)
    vertex_emission = np.zeros((len(pos), 3))
    vertex_emission[len(gp):] = L
    return surface, len(gp), len(gf), np.asarray(L), vertex_emission


def test_open_scene_matches_the_ray_traced_reference():
    """A plane facing an emissive quad (nothing occludes): the unshadowed transfer against the
    ray-traced direct irradiance, 2048 samples."""
    from aobake.methods.embree.light import irradiance
    from aobake.shading import Shading

    surface, ng, nfg, L, vertex_emission = _plane_under_emissive_quad()
    sh = default_shading(surface.n_vertices, surface.n_faces)
    face_emission = np.zeros((surface.n_faces, 3))
    face_emission[nfg:] = L
    sh = Shading((), sh.face_albedo * 0, face_emission, sh.vertex_albedo * 0, vertex_emission)
    ref = irradiance(surface, sh, n_samples=2048, bounces=0, seed=1).direct[:ng]
    radiance = outgoing_radiance(np.zeros((surface.n_vertices, 3)), np.zeros((surface.n_vertices, 3)), vertex_emission)
    got = unshadowed_irradiance(build_elements(surface), radiance)[:ng]
    rel = np.sqrt(np.mean((got - ref) ** 2)) / np.sqrt(np.mean(ref**2))
    assert rel < 0.01, rel
    assert np.max(np.abs(got - ref) / ref.max()) < 0.02
    assert np.all(got >= 0)


def test_outgoing_radiance_and_bad_radiance():
    alb = np.array([[0.5, 0.25, 0.0]])
    e = np.array([[math.pi, 2 * math.pi, 1.0]])
    assert np.allclose(outgoing_radiance(alb, e, [[0.0, 0.0, 0.1]]), [[0.5, 0.5, 0.1]])
    surface, *_ = _plane_under_emissive_quad(cells=2, quad_cells=2)
    el = build_elements(surface)
    with pytest.raises(ValueError, match="radiance"):
        unshadowed_irradiance(el, np.full((el.n_vertices, 3), -1.0))
    with pytest.raises(ValueError, match="radiance"):
        unshadowed_irradiance(el, np.zeros((2, 3)))


def test_same_result_for_any_thread_count():
    import numba

    surface, *_ = _plane_under_emissive_quad(cells=4, quad_cells=4)
    el = build_elements(surface)
    radiance = np.random.default_rng(3).uniform(0, 1, (el.n_vertices, 3))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = unshadowed_irradiance(el, radiance)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = unshadowed_irradiance(el, radiance)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one, two) and np.count_nonzero(one) > 0
