"""The disk method's terms (aobake.kernels.bunnell, polygon, warps) against closed forms:
disk and polygon form factors, solid angles, direction bins."""

from __future__ import annotations

import numpy as np
import pytest

from aobake.kernels import bunnell as K
from aobake.kernels import polygon as KP
from aobake.mesh import surface_from_arrays
from aobake.methods import bunnell as B
from aobake.testing.closed_forms import (
    disk_on_axis_cosine,
    disk_on_axis_solid_angle,
    polygon_form_factor,
)
from aobake.testing.disk import (
    DEFAULTS,
    H_DISK,
    R_DISK,
    receiver_under_disk,
    small_scene,
)
from aobake.testing.naive_bunnell import naive_vertex_areas
from aobake.testing.naive_rays import raycast_ao
from aobake.testing.scenes import (
    ground_grid,
)

# --------------------------------------------------------------------------------------
# closed forms


@pytest.mark.parametrize(
    ("measure", "expected", "oracle"),
    [
        (K.MEASURE_COSINE, 0.224771, disk_on_axis_cosine),
        (K.MEASURE_UNIFORM, 0.119529, disk_on_axis_solid_angle),
    ],
)
def test_disk_term_on_axis(measure, expected, oracle):
    area = np.pi * R_DISK**2
    value = K.disk_term(H_DISK**2, H_DISK, area, area, 1.0, measure)
    assert value == pytest.approx(expected, abs=5e-7)
    assert value == pytest.approx(oracle(R_DISK, H_DISK), rel=1e-13)


def test_uniform_term_does_not_cancel_far_away():
    area, r = 1e-6, 1e3
    # 1 - 1 / sqrt(1 + x) with x = A / (pi r^2) ~ 3e-13, without cancellation
    exact = -np.expm1(-0.5 * np.log1p(area / (np.pi * r * r)))
    assert K.disk_term(r * r, r, area, area, 1.0, K.MEASURE_UNIFORM) == pytest.approx(
        exact, rel=1e-12
    )


ORACLE_TRIANGLE = np.array([[-1.0, -1.0, 1.0], [2.0, -1.0, 1.0], [0.0, 2.0, 1.0]])


@pytest.mark.parametrize("winding", [1, -1])
def test_triangle_form_factor_oracle(winding):
    """Closed form: triangle (-1,-1,1), (2,-1,1), (0,2,1) above the origin, n = +z: 0.540025."""
    tri = ORACLE_TRIANGLE[::winding]
    quad = np.vstack([tri, tri[:1]])  # a triangle is a quad with a repeated corner
    value = KP.clipped_quad(0.0, 0.0, 0.0, 0.0, 0.0, 1.0, quad, K.MEASURE_COSINE)
    assert value == pytest.approx(0.540025, abs=5e-7)
    assert value == pytest.approx(polygon_form_factor(tri, np.zeros(3), np.array([0, 0, 1.0])))


def _quadrature(corners, normal, measure, n=1200):
    """Midpoint rule over a planar parallelogram (corners 0, 1, 3 span it) of the
    occlusion integrand cos_e max(cos_r, 0) / (pi r^2) (cosine) or cos_e [cos_r > 0] /
    (2 pi r^2) (uniform) seen from the origin: independent of Lambert and clipping."""
    c0, c1, c3 = corners[0], corners[1], corners[3]
    e1, e2 = c1 - c0, c3 - c0
    m = np.cross(e1, e2)
    da = np.linalg.norm(m) / n**2
    m /= np.linalg.norm(m)
    s = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(s, s, indexing="ij")
    x = c0 + u[..., None] * e1 + v[..., None] * e2
    r2 = (x * x).sum(-1)
    r = np.sqrt(r2)
    cos_e = np.abs(x @ m) / r
    cos_r = x @ normal / r
    if measure == K.MEASURE_COSINE:
        f = cos_e * np.maximum(cos_r, 0) / (np.pi * r2)
    else:
        f = cos_e * (cos_r > 0) / (2 * np.pi * r2)
    return f.sum() * da


@pytest.mark.parametrize("measure", [K.MEASURE_COSINE, K.MEASURE_UNIFORM])
@pytest.mark.parametrize(
    "normal", [(0.0, 0.0, 1.0), (0.0, 0.6, 0.8), (0.0, 1.0, 0.0), (0.48, -0.6, 0.64)]
)
def test_clipped_quad_matches_quadrature(measure, normal):
    """A tilted square crossing the receiver's tangent plane: the clipped exact value
    against brute-force quadrature of the integrand (which clips itself)."""
    normal = np.array(normal) / np.linalg.norm(normal)
    quad = np.array([[-0.7, -0.3, 0.2], [0.9, -0.5, 0.6], [1.0, 0.8, 0.9], [-0.6, 1.0, 0.5]])
    quad[3] = quad[0] + quad[2] - quad[1]  # planar parallelogram
    value = KP.clipped_quad(0.0, 0.0, 0.0, *normal, quad, measure)
    assert value > 0.02
    assert value == pytest.approx(_quadrature(quad, normal, measure), rel=2e-4)


def test_solid_angle_of_a_rectangle():
    """Rectangle a x b centred on the axis at distance d: Omega = 4 asin(ab / sqrt((a^2 +
    4d^2)(b^2 + 4d^2)))."""
    a, b, d = 1.2, 0.5, 0.7
    quad = np.array([[-a / 2, -b / 2, d], [a / 2, -b / 2, d], [a / 2, b / 2, d], [-a / 2, b / 2, d]])
    omega = 4 * np.arcsin(a * b / np.sqrt((a * a + 4 * d * d) * (b * b + 4 * d * d)))
    value = KP.clipped_quad(0.0, 0.0, 0.0, 0.0, 0.0, 1.0, quad, K.MEASURE_UNIFORM)
    assert value == pytest.approx(omega / (2 * np.pi), rel=1e-12)


def test_cells_tile_the_surface():
    """The barycentric cells of all vertices are the triangles: their summed form factors
    equal the triangles' (either side, one plane through no receiver)."""
    p, f = ground_grid(1.0, 6, 0.8, up=False)
    s = surface_from_arrays(p, f)
    e = B.build_elements(s)
    quad = np.empty((4, 3))
    point = np.array([0.1, -0.2, 0.0])
    total = sum(
        KP.cell_terms(s.positions, e.corner_start, e.corners, j, *point, 0.0, 0.0, 1.0, 0, quad)[0]
        for j in range(e.n_vertices)
    )
    tri = s.positions[f]
    direct = sum(polygon_form_factor(t, point, np.array([0, 0, 1.0])) for t in tri)
    assert total == pytest.approx(direct, rel=1e-12)
    assert direct > 0.5


@pytest.mark.parametrize("exact", [True, False])
@pytest.mark.parametrize(
    ("measure", "oracle"), [("cosine", disk_on_axis_cosine), ("uniform", disk_on_axis_solid_angle)]
)
@pytest.mark.parametrize("near", [0.0, DEFAULTS.near])
def test_point_under_disk_mesh(exact, measure, oracle, near):
    """Closed form: a point facing a coaxial disk; many small disks sum to the closed form."""
    ao = B.variant_ao(receiver_under_disk(), measure=measure, exact=exact, near=near)
    # exact sum: discretisation only; default tree (theta 2): plus its (monopole, on-axis)
    # error, 0.013 for the cosine measure (0.004 at theta 4)
    assert 1.0 - ao[-1] == pytest.approx(oracle(R_DISK, H_DISK), abs=2e-3 if exact else 1.5e-2)
    fine = B.variant_ao(receiver_under_disk(), measure=measure, theta=64.0, near=near)
    assert 1.0 - fine[-1] == pytest.approx(oracle(R_DISK, H_DISK), abs=2e-3)


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
def test_receiver_without_normal_sees_full_sphere_fraction(measure):
    """No normal: the occluded fraction of the full sphere, (1 - h / sqrt(R^2 + h^2)) / 2."""
    ao = B.variant_ao(receiver_under_disk(normal=(0, 0, 0)), measure=measure, exact=True)
    assert 1.0 - ao[-1] == pytest.approx(0.5 * disk_on_axis_solid_angle(R_DISK, H_DISK), abs=2e-3)


def test_raycast_reference_matches_closed_form():
    """The numpy ray caster used by these tests agrees with the disk closed form."""
    s = receiver_under_disk()
    ao = raycast_ao(s, n_rays=4096, vertices=[s.n_vertices - 1])
    a = disk_on_axis_cosine(R_DISK, H_DISK)
    assert 1.0 - ao[0] == pytest.approx(a, abs=5 * np.sqrt(a * (1 - a) / 4096) + 2e-3)


def test_vertex_areas_match_naive():
    s = small_scene()
    e = B.build_elements(s)
    np.testing.assert_allclose(
        e.areas, naive_vertex_areas(e.positions, s.faces), rtol=1e-13, atol=0
    )
    tri = e.positions[s.faces]
    total = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert e.areas.sum() == pytest.approx(total.sum(), rel=1e-12)


def test_elements_are_normalised():
    s = small_scene()
    e = B.build_elements(s)
    lo, hi = s.positions.min(0), s.positions.max(0)
    np.testing.assert_allclose(e.origin, 0.5 * (lo + hi))
    assert e.scale == pytest.approx((hi - lo).max())
    np.testing.assert_allclose(e.positions * e.scale + e.origin, s.positions, atol=1e-12)
    offset = np.linalg.norm(e.points - e.positions, axis=1)
    lift = 1e-4 * np.sqrt(e.areas) * np.linalg.norm(s.normals, axis=1)
    same = np.isclose(offset, lift, rtol=1e-7, atol=0)
    # a few receivers touch another shell (the flipped duplicate face, the sheet's edge):
    # contact_points moves them to their own side, a couple of lifts away at most
    assert same.mean() > 0.95
    assert np.all(offset[~same] <= 2.5 * lift[~same])
