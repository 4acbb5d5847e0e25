"""The cube-map rasterizer sampler (aobake.methods.fields.raster): exact texel tables, the sphere, agreement with Embree."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from aobake.methods.fields.raster import cube_texels, raster_occlusion
from aobake.methods.fields.rays import embree_occlusion
from aobake.testing import scenes


def sphere_omega(radius, r):
    """Exact solid angle of a sphere of ``radius`` seen from distance ``r``."""
    return 2.0 * math.pi * (1.0 - np.sqrt(1.0 - (radius / np.asarray(r)) ** 2))


def triangle_solid_angle(a, b, c):
    """Van Oosterom & Strackee (1983): solid angle of a triangle seen from the origin."""
    la, lb, lc = np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(c)
    num = abs(np.dot(a, np.cross(b, c)))
    den = la * lb * lc + np.dot(a, b) * lc + np.dot(a, c) * lb + np.dot(b, c) * la
    return 2.0 * math.atan2(num, den)


def angle_deg(u, v):
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0)))


@pytest.mark.parametrize("size", [1, 3, 16])
def test_texel_tables_are_exact(size):
    weights, vectors = cube_texels(size)
    assert weights.shape == (6, size, size) and vectors.shape == (6, size, size, 3)
    np.testing.assert_allclose(weights.sum(), 4.0 * math.pi, rtol=1e-12)
    np.testing.assert_allclose(vectors.sum(axis=(0, 1, 2)), 0.0, atol=1e-12)
    # each face is a sixth of the sphere
    np.testing.assert_allclose(weights.sum(axis=(1, 2)), 4.0 * math.pi / 6.0, rtol=1e-12)
    # a vector integral is shorter than the solid angle and points into its texel
    assert (np.linalg.norm(vectors, axis=-1) <= weights + 1e-15).all()


def test_texel_vector_matches_quadrature():
    size = 4
    weights, vectors = cube_texels(size)
    # midpoint quadrature of int (u, v, 1) / (1 + u^2 + v^2)^2 du dv on texel (4, 1, 2)
    # of face 4 (+z: u = x, v = y)
    n = 400
    u0, v0 = -1.0 + 2.0 * 1 / size, -1.0 + 2.0 * 2 / size
    t = (np.arange(n) + 0.5) / n * (2.0 / size)
    u, v = np.meshgrid(u0 + t, v0 + t, indexing="ij")
    jac = (2.0 / size / n) ** 2 / (1.0 + u * u + v * v) ** 2
    quad = np.array([(u * jac).sum(), (v * jac).sum(), jac.sum()])
    np.testing.assert_allclose(vectors[4, 1, 2], quad, rtol=1e-5)
    omega = (jac * np.sqrt(1.0 + u * u + v * v)).sum()
    np.testing.assert_allclose(weights[4, 1, 2], omega, rtol=1e-5)
    # texels at a face's corner subtend less than at its centre
    assert weights[4, 0, 0] < weights[4, 1, 1]


@pytest.mark.parametrize("r", [1.02, 1.3, 2.0, 5.0])
def test_sphere_solid_angle_and_direction(r):
    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    inner = np.abs(np.einsum("ij,ij->i", m.face_normals, m.triangles_center)).min()
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(6, 3))
    dirs = np.vstack([dirs, [[1, 1, 1], [1, 0, 0], [0, 0, -1]]])  # cube corner and face centres
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    points = 10.0 + r * dirs  # off the origin: the wrapper recentres
    om, vec = raster_occlusion(m.vertices + 10.0, m.faces, points, size=64)
    # the polyhedron lies between its insphere and the unit sphere; the cube map adds at
    # most the texels along the silhouette (a ring of ~2 pi sin(sigma) / texel angle)
    texel = 2.0 / 64
    ring = 2.0 * math.pi * texel * 1.5
    assert (om >= sphere_omega(inner, r) - ring).all()
    assert (om <= sphere_omega(1.0, r) + ring).all()
    assert (angle_deg(vec, -dirs) < 0.2).all()


def test_single_triangle_exact():
    a, b, c = np.array([-1.0, -1.0, 1.0]), np.array([2.0, -1.0, 1.0]), np.array([0.0, 2.0, 1.0])
    exact = triangle_solid_angle(a, b, c)
    om, _ = raster_occlusion(np.array([a, b, c]), np.array([[0, 1, 2]]), np.zeros((1, 3)), size=256)
    np.testing.assert_allclose(om[0], exact, rtol=5e-3)
    # the triangle straddles several cube faces (it is clipped): coverage still exact
    assert om[0] > 1.0


def test_point_on_a_triangle_gives_finite_values():
    s = scenes.box((1.0, 1.0, 1.0))
    points = np.array([[0.5, 0.0, 0.0], [0.5, 0.5, 0.5], [0.0, 0.0, 0.0]])  # face, corner, inside
    om, vec = raster_occlusion(s.positions, s.faces, points, size=16)
    assert np.isfinite(om).all() and np.isfinite(vec).all()
    np.testing.assert_allclose(om[2], 4.0 * math.pi, rtol=1e-12)  # inside a closed box


def _scenes():
    box = scenes.box((1.0, 2.0, 0.5))
    convex = scenes.random_convex(3, subdivisions=2)
    plate_p, plate_f = scenes.ground_grid(1.0, 4)
    cup = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.6)
    return {
        "box": (box.positions, box.faces),
        "convex": (convex.positions, convex.faces),
        "plate": (plate_p, plate_f),
        "annulus": (np.asarray(cup.vertices), np.asarray(cup.faces)),
    }


@pytest.mark.parametrize("name", ["box", "convex", "plate", "annulus"])
def test_raster_and_embree_agree(name):
    positions, faces = _scenes()[name]
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    extent = np.linalg.norm(positions.max(axis=0) - positions.min(axis=0))
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(24, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dist = extent * np.array([0.6, 0.8, 1.0, 2.0, 4.0, 8.0])[np.arange(24) % 6]
    points = centre + dist[:, None] * dirs
    n_rays = 4096
    om_r, vec_r = raster_occlusion(positions, faces, points, size=128)
    om_e, vec_e = embree_occlusion(positions, faces, points, n_rays=n_rays, seed=3)
    # Monte Carlo: binomial bound (conservative for Sobol points); raster: one ring of
    # texels (128 per edge) around the silhouette, bounded by 4 pi * 2 texels
    p = np.clip(om_e / (4.0 * math.pi), 1e-3, 1.0)
    sigma = 4.0 * math.pi * np.sqrt(p * (1.0 - p) / n_rays)
    tol = 5.0 * sigma + 0.02 * np.maximum(om_r, om_e) + 1e-3
    assert (np.abs(om_r - om_e) <= tol).all(), np.c_[om_r, om_e, tol][np.abs(om_r - om_e) > tol]
    big = (om_r > 0.05) & (om_e > 0.05)
    assert (angle_deg(vec_r[big], vec_e[big]) < 3.0).all()


def test_result_does_not_depend_on_threads():
    positions, faces = _scenes()["annulus"]
    points = np.random.default_rng(2).normal(size=(40, 3)) * 2.0
    a = raster_occlusion(positions, faces, points, size=32, threads=1)
    b = raster_occlusion(positions, faces, points, size=32, threads=2)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_result_does_not_depend_on_chunks(monkeypatch):
    """Points are drawn per chunk on worker threads: one point per call and all in one
    call give the same bits."""
    import aobake.methods.fields.raster as raster_module

    positions, faces = _scenes()["annulus"]
    points = np.random.default_rng(3).normal(size=(40, 3)) * 2.0
    got = []
    for task in (1, 10**6):
        monkeypatch.setattr(raster_module, "_TASK", task)
        got.append(raster_occlusion(positions, faces, points, size=16))
    np.testing.assert_array_equal(got[0][0], got[1][0])
    np.testing.assert_array_equal(got[0][1], got[1][1])
